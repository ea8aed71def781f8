//! Real shared memory: publisher, subscriptions in this and in other processes, staleness.
//!
//! Every test runs in its own iceoryx2 domain (file prefix `t<pid>_<n>_`, root `/tmp/iox2t/`)
//! under its own service prefix, so tests run in parallel without cross-talk.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, ArmState, CompensationStatusV4, CycleMessages, Header, IpcError, JawStateV1,
    JointStateV2, Message, PoseV2, Subscription, Topic, Update, create_node, flags,
};

/// Generous period for tests: the deadline is 3 periods. Nothing asserts on elapsed time.
const PERIOD: Duration = Duration::from_millis(20);

fn node(d: &Domain, name: &str) -> Node<ipc::Service> {
    create_node::<ipc::Service>(name, Some(&d.config)).expect("node")
}

/// One cycle's messages with values derived from `seq`, different in every topic, so every
/// field is checked and a mixed-up topic is caught.
fn cycle(seq: u64) -> CycleMessages {
    let s = seq as f64;
    let header = Header {
        seq,
        sample_t_ns: 1_000_000 * seq,
        sample_realtime_ns: 1_763_900_000_000_000_000 + 1_000_000 * seq + 17,
        board_timestamp: Header::pack_board_timestamps([seq as u32, 7]),
        publish_t_ns: 1_000_000 * seq + 500,
        valid: 1,
        flags: flags::SIMULATED | flags::CORRECTION_ACTIVE_J1,
    };
    let js = JointStateV2 {
        header,
        position: core::array::from_fn(|i| s + i as f64 * 0.1),
        velocity: core::array::from_fn(|i| -s - i as f64),
        effort: core::array::from_fn(|i| 100.0 * s + i as f64),
    };
    let cjs = JointStateV2 {
        position: core::array::from_fn(|i| s + i as f64 * 0.1 - 0.01),
        ..js
    };
    let jaw = JawStateV1 {
        header,
        position: 0.3 + s,
        velocity: -s,
        effort: 0.01 * s,
    };
    let cjaw = JawStateV1 {
        effort: 0.02 * s,
        ..jaw
    };
    let pose = |dx: f64| PoseV2 {
        header,
        position_m: [s + dx, 2.0 * s, 3.0 * s],
        orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        rotation: core::array::from_fn(|i| if i % 4 == 0 { 1.0 } else { 0.0 }),
    };
    let status = CompensationStatusV4 {
        header,
        tau_ext_nm: [0.1 * s, -0.2 * s],
        delta_rad: [0.01, -0.02],
        insertion_m: 0.12,
        cycle_period_ns: 666_667,
        cycle_duration_ns: 1_500,
        cycles_total: seq,
        read_failures_total: 3,
        overruns_total: 1,
        consecutive_read_failures: 0,
        source_state: 0,
        ..Default::default()
    };
    CycleMessages {
        measured: ArmState {
            measured_js: js,
            jaw_measured_js: jaw,
            local_measured_cp: pose(0.0),
            measured_cp: pose(1.0),
        },
        compensated: ArmState {
            measured_js: cjs,
            jaw_measured_js: cjaw,
            local_measured_cp: pose(0.5),
            measured_cp: pose(1.5),
        },
        status,
    }
}

fn publish(p: &ArmPublisher, seq: u64) {
    p.publish_cycle(&cycle(seq)).expect("publish");
}

fn expect_fresh<T: Message>(u: Update<T>) -> T {
    match u {
        Update::Fresh(v) => v,
        other => panic!("expected a fresh sample, got {other:?}"),
    }
}

#[test]
fn round_trip_of_all_nine_topics() {
    let d = Domain::new("round_trip");
    let node = node(&d, "rt");
    let js = |t| Subscription::<JointStateV2>::new(&node, &d.names, t, PERIOD).expect("sub js");
    let jaw = |t| Subscription::<JawStateV1>::new(&node, &d.names, t, PERIOD).expect("sub jaw");
    let cp = |t| Subscription::<PoseV2>::new(&node, &d.names, t, PERIOD).expect("sub cp");
    let mut subs_js = [js(Topic::MeasuredJs), js(Topic::CompensatedMeasuredJs)];
    let mut subs_jaw = [
        jaw(Topic::JawMeasuredJs),
        jaw(Topic::CompensatedJawMeasuredJs),
    ];
    let mut subs_cp = [
        cp(Topic::LocalMeasuredCp),
        cp(Topic::MeasuredCp),
        cp(Topic::CompensatedLocalMeasuredCp),
        cp(Topic::CompensatedMeasuredCp),
    ];
    let mut st = Subscription::<CompensationStatusV4>::new(
        &node,
        &d.names,
        Topic::CompensatedStatus,
        PERIOD,
    )
    .expect("sub status");
    let publisher = ArmPublisher::create(&node, &d.names).expect("publisher");
    for t in Topic::ALL {
        assert_eq!(publisher.number_of_subscribers(t), 1, "{t}");
    }

    for seq in 1..=3 {
        publish(&publisher, seq);
        let want = cycle(seq);
        assert_eq!(
            expect_fresh(subs_js[0].wait().unwrap()),
            want.measured.measured_js
        );
        assert_eq!(
            expect_fresh(subs_js[1].wait().unwrap()),
            want.compensated.measured_js
        );
        assert_eq!(
            expect_fresh(subs_jaw[0].wait().unwrap()),
            want.measured.jaw_measured_js
        );
        assert_eq!(
            expect_fresh(subs_jaw[1].wait().unwrap()),
            want.compensated.jaw_measured_js
        );
        assert_eq!(
            expect_fresh(subs_cp[0].wait().unwrap()),
            want.measured.local_measured_cp
        );
        assert_eq!(
            expect_fresh(subs_cp[1].wait().unwrap()),
            want.measured.measured_cp
        );
        assert_eq!(
            expect_fresh(subs_cp[2].wait().unwrap()),
            want.compensated.local_measured_cp
        );
        assert_eq!(
            expect_fresh(subs_cp[3].wait().unwrap()),
            want.compensated.measured_cp
        );
        assert_eq!(expect_fresh(st.wait().unwrap()), want.status);
    }
    assert_eq!(subs_js[0].stats().received_total, 3);
    assert_eq!(subs_js[0].stats().seq_gaps_total, 0);
    assert_eq!(subs_js[0].latest().map(|v| v.header.seq), Some(3));
}

#[test]
fn a_started_cycle_delivers_its_first_message_at_once_and_the_rest_when_finished() {
    let d = Domain::new("start_cycle");
    let node = node(&d, "sc");
    let mut first =
        Subscription::<PoseV2>::new(&node, &d.names, Topic::CompensatedLocalMeasuredCp, PERIOD)
            .expect("sub first");
    let mut base =
        Subscription::<PoseV2>::new(&node, &d.names, Topic::CompensatedMeasuredCp, PERIOD)
            .expect("sub base");
    let mut status = Subscription::<CompensationStatusV4>::new(
        &node,
        &d.names,
        Topic::CompensatedStatus,
        PERIOD,
    )
    .expect("sub status");
    let publisher = ArmPublisher::create(&node, &d.names).expect("publisher");
    let want = cycle(7);
    let started = publisher
        .start_cycle(&want.compensated.local_measured_cp)
        .expect("start");
    // The first message is there before the cycle is finished; the others are not, and no
    // cycle event was sent.
    assert_eq!(
        first.try_latest().unwrap(),
        Some(want.compensated.local_measured_cp)
    );
    assert_eq!(base.try_latest().unwrap(), None);
    assert_eq!(status.try_latest().unwrap(), None);
    let listener = status.listener().expect("an event subscription listens");
    let mut events = 0;
    listener.try_wait(|_| events += 1).unwrap();
    assert_eq!(
        events, 0,
        "the cycle event came before the cycle was finished"
    );

    started.finish(&want).expect("finish");
    assert_eq!(expect_fresh(status.wait().unwrap()), want.status);
    assert_eq!(
        expect_fresh(base.wait().unwrap()),
        want.compensated.measured_cp
    );
    // The first message was sent once.
    assert_eq!(first.try_latest().unwrap(), None);
    assert_eq!(first.stats().received_total, 1);
}

#[test]
fn subscriber_that_fell_behind_gets_the_newest_and_counts_the_rest() {
    let d = Domain::new("behind");
    let node = node(&d, "behind");
    let mut sub =
        Subscription::<PoseV2>::new(&node, &d.names, Topic::CompensatedMeasuredCp, PERIOD).unwrap();
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    for seq in 1..=5 {
        publish(&publisher, seq);
    }
    let mut seen = Vec::new();
    let newest = expect_fresh(sub.wait_with(|v| seen.push(v.header.seq)).unwrap());
    assert_eq!(newest.header.seq, 5);
    assert_eq!(seen, [1, 2, 3, 4, 5]);
    assert_eq!(sub.stats().superseded_total, 4);
    // The five notifications were coalesced and drained with the samples: the next call sees
    // no sample and reports staleness instead of returning an old value.
    assert!(matches!(sub.wait().unwrap(), Update::Stale { .. }));
}

#[test]
fn buffer_overflow_shows_up_as_seq_gaps() {
    let d = Domain::new("overflow");
    let node = node(&d, "overflow");
    let mut sub =
        Subscription::<JointStateV2>::new(&node, &d.names, Topic::MeasuredJs, PERIOD).unwrap();
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    let n = dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE as u64 + 10;
    publish(&publisher, 1);
    assert_eq!(expect_fresh(sub.wait().unwrap()).header.seq, 1);
    for seq in 2..=n {
        publish(&publisher, seq);
    }
    let mut seen = Vec::new();
    let newest = expect_fresh(sub.wait_with(|v| seen.push(v.header.seq)).unwrap());
    assert_eq!(newest.header.seq, n);
    // Safe overflow kept the newest SUBSCRIBER_MAX_BUFFER_SIZE samples, in order.
    assert_eq!(seen.len(), dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE);
    assert!(seen.windows(2).all(|w| w[1] == w[0] + 1));
    assert_eq!(sub.stats().seq_gaps_total, seen[0] - 2);
}

#[test]
fn invalid_cycles_carry_valid_zero_and_the_reason() {
    let d = Domain::new("invalid");
    let node = node(&d, "invalid");
    let mut sub = Subscription::<CompensationStatusV4>::new(
        &node,
        &d.names,
        Topic::CompensatedStatus,
        PERIOD,
    )
    .unwrap();
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    let mut c = cycle(9);
    let mut h = c.status.header;
    h.valid = 0;
    h.flags = flags::BOARD_TIMEOUT;
    c.set_header(h);
    c.status.consecutive_read_failures = 4;
    publisher.publish_cycle(&c).unwrap();
    let got = expect_fresh(sub.wait().unwrap());
    assert!(!got.header.is_valid());
    assert!(got.header.has(flags::BOARD_TIMEOUT));
    assert_eq!(got.consecutive_read_failures, 4);
}

#[test]
fn late_subscriber_gets_the_latest_sample_at_the_next_send() {
    let d = Domain::new("late");
    let node = node(&d, "late");
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    for seq in 1..=5 {
        publish(&publisher, seq);
    }
    let mut sub = Subscription::<PoseV2>::new(&node, &d.names, Topic::MeasuredCp, PERIOD).unwrap();
    // iceoryx2 0.10 connects a new subscriber, and delivers its history, inside the publisher's
    // next send: nothing is there before it.
    assert_eq!(sub.try_latest().unwrap(), None);
    publish(&publisher, 6);
    let mut seen = Vec::new();
    let newest = expect_fresh(sub.wait_with(|v| seen.push(v.header.seq)).unwrap());
    assert_eq!(seen, [5, 6], "history of 1 (seq 5) then the new sample");
    assert_eq!(newest.header.seq, 6);
}

#[test]
fn second_publisher_on_the_same_prefix_is_refused_with_a_clear_error() {
    let d = Domain::new("second");
    let node_a = node(&d, "first");
    let node_b = node(&d, "second");
    let _first = ArmPublisher::create(&node_a, &d.names).expect("first publisher");
    let err = ArmPublisher::create(&node_b, &d.names).expect_err("second publisher must fail");
    assert!(
        matches!(&err, IpcError::AlreadyPublishing { prefix } if prefix == "test/second"),
        "{err:?}"
    );
    assert_eq!(
        err.to_string(),
        "another dvrk-sidecar is already publishing under test/second"
    );
    // Another prefix in the same domain is independent.
    let other = dvrk_ipc::ServiceNames::new("test/second_other").unwrap();
    ArmPublisher::create(&node_b, &other).expect("other prefix");
}

#[test]
fn after_a_clean_stop_a_new_publisher_can_take_over() {
    let d = Domain::new("takeover");
    let node = node(&d, "takeover");
    let mut sub =
        Subscription::<JointStateV2>::new(&node, &d.names, Topic::MeasuredJs, PERIOD).unwrap();
    let first = ArmPublisher::create(&node, &d.names).unwrap();
    publish(&first, 1);
    assert_eq!(expect_fresh(sub.wait().unwrap()).header.seq, 1);
    drop(first);
    assert_eq!(sub.wait().unwrap(), Update::Terminated);
    let second = ArmPublisher::create(&node, &d.names).expect("restart");
    publish(&second, 1);
    assert_eq!(expect_fresh(sub.wait().unwrap()).header.seq, 1);
}

#[test]
fn silent_publisher_is_stale_and_a_dropped_one_is_terminated() {
    let d = Domain::new("stale");
    let node = node(&d, "stale");
    let mut sub =
        Subscription::<PoseV2>::new(&node, &d.names, Topic::CompensatedMeasuredCp, PERIOD).unwrap();
    // No publisher yet: waiting for one is staleness, not termination.
    assert!(matches!(sub.wait().unwrap(), Update::Stale { .. }));
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    publish(&publisher, 1);
    expect_fresh(sub.wait().unwrap());
    let first = match sub.wait().unwrap() {
        Update::Stale { since_ns } => since_ns,
        other => panic!("expected Stale, got {other:?}"),
    };
    let second = match sub.wait().unwrap() {
        Update::Stale { since_ns } => since_ns,
        other => panic!("expected Stale, got {other:?}"),
    };
    assert!(
        second > first,
        "since_ns grows while silent: {first} then {second}"
    );
    assert!(
        first >= sub.deadline().as_nanos() as u64,
        "staleness is reported after the deadline, not before"
    );
    assert_eq!(sub.stats().stale_total, 3);
    drop(publisher);
    assert_eq!(sub.wait().unwrap(), Update::Terminated);
}

#[test]
fn topic_and_type_must_match() {
    let d = Domain::new("mismatch");
    let node = node(&d, "mismatch");
    let err = Subscription::<PoseV2>::new(&node, &d.names, Topic::MeasuredJs, PERIOD)
        .expect_err("PoseV2 on measured_js");
    assert_eq!(
        err.to_string(),
        "topic measured_js carries dvrk::JointStateV2, not dvrk::PoseV2"
    );
}

#[test]
fn domain_files_are_removed_on_drop() {
    let d = Domain::new("cleanup");
    {
        let node = node(&d, "cleanup");
        let p = ArmPublisher::create(&node, &d.names).unwrap();
        publish(&p, 1);
        assert!(!d.leftovers().is_empty(), "the domain created files");
    }
    let prefix = d.domain_prefix.clone();
    drop(d);
    let mut left = Vec::new();
    for dir in ["/dev/shm", common::ROOT] {
        if let Ok(entries) = std::fs::read_dir(dir) {
            left.extend(
                entries
                    .flatten()
                    .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
                    .map(|e| e.path()),
            );
        }
    }
    assert!(left.is_empty(), "left behind: {left:?}");
}

// ---- other processes -------------------------------------------------------------------------

const ENV_ROLE: &str = "DVRK_IPC_TEST_ROLE";
const ENV_COUNT: &str = "DVRK_IPC_TEST_COUNT";

/// Runs this test binary again as a child that executes only `child_process_role`.
fn spawn_child(d: &Domain, role: &str, count: u64) -> Child {
    Command::new(std::env::current_exe().expect("test binary"))
        .args([
            "child_process_role",
            "--exact",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .envs(d.env())
        .env(ENV_ROLE, role)
        .env(ENV_COUNT, count.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn child")
}

/// The child's stdout, line by line (the test harness prints its own lines too).
fn child_lines(child: &mut Child) -> impl Iterator<Item = String> + use<> {
    let out = child.stdout.take().expect("piped stdout");
    BufReader::new(out).lines().map_while(Result::ok)
}

/// Reads lines until one contains `tag `; returns the rest of that line. (The harness writes
/// `test child_process_role ... ` without a newline before the child's first line.)
fn wait_for_tag(lines: &mut impl Iterator<Item = String>, tag: &str) -> Option<String> {
    let tag = format!("{tag} ");
    lines.find_map(|l| l.split_once(&tag).map(|(_, rest)| rest.to_owned()))
}

/// Upper bound on a child's life, so a broken test fails instead of hanging: the parent's reads
/// see end-of-file when the child exits.
const CHILD_LIFETIME: Duration = Duration::from_secs(60);

/// Not a test on its own: the body of the child processes spawned by the tests below.
#[test]
#[ignore = "child process role; run by the cross-process tests"]
fn child_process_role() {
    let Ok(role) = std::env::var(ENV_ROLE) else {
        return;
    };
    std::thread::spawn(|| {
        std::thread::sleep(CHILD_LIFETIME);
        std::process::exit(3);
    });
    let d = Domain::from_env();
    let count: u64 = std::env::var(ENV_COUNT).unwrap().parse().unwrap();
    let node = node(&d, &format!("child_{role}"));
    match role.as_str() {
        "subscriber" => {
            let mut sub =
                Subscription::<JointStateV2>::new(&node, &d.names, Topic::MeasuredJs, PERIOD)
                    .unwrap();
            println!("READY 1");
            let mut seqs = Vec::new();
            loop {
                match sub.wait_with(|v| seqs.push(v.header.seq)).unwrap() {
                    Update::Fresh(v) if v.header.seq >= count => break,
                    Update::Terminated => break,
                    _ => {}
                }
            }
            let s = sub.stats();
            println!(
                "SEQS {}",
                seqs.iter()
                    .map(u64::to_string)
                    .collect::<Vec<_>>()
                    .join(",")
            );
            println!("GAPS {}", s.seq_gaps_total);
        }
        "publisher" => {
            let publisher = ArmPublisher::create(&node, &d.names).unwrap();
            println!("READY 1");
            // Publishes until killed by the parent.
            for seq in 1.. {
                publish(&publisher, seq);
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        other => panic!("unknown role {other}"),
    }
}

#[test]
fn subscriber_in_another_process_receives_every_seq_in_order() {
    let d = Domain::new("xproc_sub");
    let node = node(&d, "xproc_pub");
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    const N: u64 = 100;
    let mut child = spawn_child(&d, "subscriber", N);
    let mut lines = child_lines(&mut child);
    assert!(
        wait_for_tag(&mut lines, "READY").is_some(),
        "child did not start"
    );
    // READY is printed after the subscription exists; the publisher sees it in shared memory.
    for _ in 0..1000 {
        if publisher.number_of_subscribers(Topic::MeasuredJs) == 1 {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(publisher.number_of_subscribers(Topic::MeasuredJs), 1);
    for seq in 1..=N {
        publish(&publisher, seq);
        // ~200 Hz: the 16-sample buffer absorbs child stalls of up to 80 ms.
        std::thread::sleep(Duration::from_millis(5));
    }
    let seqs: Vec<u64> = wait_for_tag(&mut lines, "SEQS")
        .expect("child printed SEQS")
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    let gaps: u64 = wait_for_tag(&mut lines, "GAPS")
        .expect("child printed GAPS")
        .parse()
        .unwrap();
    // Read to the end: closing the pipe early would fail the child's last writes (EPIPE).
    lines.for_each(drop);
    let status = child.wait().expect("child exit");
    assert!(status.success(), "child failed: {status:?}");
    assert_eq!(seqs, (1..=N).collect::<Vec<_>>(), "every seq, in order");
    assert_eq!(gaps, 0);
}

#[test]
fn killed_publisher_process_is_reported_terminated_and_can_be_replaced() {
    let d = Domain::new("xproc_kill");
    let node = node(&d, "xproc_kill_sub");
    let mut sub =
        Subscription::<JointStateV2>::new(&node, &d.names, Topic::MeasuredJs, PERIOD).unwrap();
    let mut child = spawn_child(&d, "publisher", 0);
    let mut lines = child_lines(&mut child);
    assert!(
        wait_for_tag(&mut lines, "READY").is_some(),
        "child did not start"
    );
    // Samples arrive from the other process.
    let mut fresh = 0;
    for _ in 0..1000 {
        if let Update::Fresh(v) = sub.wait().unwrap() {
            assert!(v.header.seq >= 1);
            fresh += 1;
            if fresh == 5 {
                break;
            }
        }
    }
    assert_eq!(fresh, 5, "samples from the child publisher");
    assert_eq!(sub.number_of_publishers(), 1);
    child.kill().expect("SIGKILL");
    child.wait().expect("reap child");
    drop(lines);
    // Drain what the child sent before dying, then the dead node is cleaned up.
    let mut outcome = None;
    for _ in 0..1000 {
        match sub.wait().unwrap() {
            Update::Fresh(_) => continue,
            u => {
                outcome = Some(u);
                if u == Update::Terminated {
                    break;
                }
            }
        }
    }
    assert_eq!(outcome, Some(Update::Terminated));
    // The dead publisher's slot is free again: a restarted sidecar can publish.
    let publisher = ArmPublisher::create(&node, &d.names).expect("replacement publisher");
    publish(&publisher, 1);
    assert_eq!(expect_fresh(sub.wait().unwrap()).header.seq, 1);
}

#[test]
fn in_process_local_service_variant_works() {
    use dvrk_ipc::iceoryx2::service::local;
    // local::Service keeps everything in this process (benchmarks of the whole cycle use it).
    let d = Domain::new("local");
    let node = create_node::<local::Service>("local", Some(&d.config)).unwrap();
    let service = dvrk_ipc::open_topic::<PoseV2, local::Service>(
        &node,
        &d.names,
        Topic::CompensatedMeasuredCp,
    )
    .unwrap();
    let subscriber = service.subscriber_builder().create().unwrap();
    let mut sub = Subscription::<PoseV2, local::Service>::new(
        &node,
        &d.names,
        Topic::CompensatedMeasuredCp,
        PERIOD,
    )
    .unwrap();
    let publisher = ArmPublisher::<local::Service>::create(&node, &d.names).unwrap();
    let c = cycle(4);
    publisher.publish_cycle(&c).unwrap();
    let ccp = c.compensated.measured_cp;
    assert_eq!(*subscriber.receive().unwrap().expect("a sample"), ccp);
    assert_eq!(expect_fresh(sub.wait().unwrap()), ccp);
}

/// iceoryx2 0.10 creates the domain's global management segment world-writable (0666), so any
/// local user could write into it and stop every new node of the account (issue 22). Creating a
/// node leaves it owner-only.
#[test]
fn the_domains_management_segment_is_owner_only_once_a_node_exists() {
    use std::os::unix::fs::MetadataExt;
    let d = Domain::new("global_mgmt");
    let _node = node(&d, "gm");
    let segments: Vec<_> = d
        .leftovers()
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".global_mgmt"))
        .collect();
    assert_eq!(segments.len(), 1, "{:?}", d.leftovers());
    let mode = std::fs::metadata(&segments[0]).unwrap().mode() & 0o777;
    assert_eq!(mode, 0o600, "{}: {mode:o}", segments[0].display());
    // A second node of the account still opens it.
    let _second = node(&d, "gm2");
}

/// The calling thread's EEVDF slice as the kernel reports it in `/proc/thread-self/sched`
/// (`se.slice`, ns), independently of the library's own system calls.
fn reported_slice_ns() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/thread-self/sched").ok()?;
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("se.slice"))?;
    let value = line.split(':').nth(1)?.trim();
    // Printed as an integer, or as "ms.ns" by kernels with SCHED_DEBUG's split format.
    match value.split_once('.') {
        Some((ms, frac)) => Some(ms.parse::<u64>().ok()? * 1_000_000 + frac.parse::<u64>().ok()?),
        None => value.parse().ok(),
    }
}

/// Whether the running kernel takes a normal task's `sched_runtime` as its slice (6.12+).
fn kernel_has_custom_slices() -> bool {
    let release = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap_or_default();
    let mut parts = release
        .trim()
        .split(['.', '-'])
        .map(|p| p.parse::<u32>().unwrap_or(0));
    let (major, minor) = (parts.next().unwrap_or(0), parts.next().unwrap_or(0));
    (major, minor) >= (6, 12)
}

#[test]
fn event_and_predictive_subscriptions_give_their_thread_a_short_slice_spin_does_not() {
    use dvrk_ipc::{SubscribeOptions, WaitStrategy};
    let d = Domain::new("slice");
    for wait in WaitStrategy::ALL {
        let config = d.config.clone();
        let names = d.names.clone();
        // A thread of its own per case: the slice is the thread's, and stays with it.
        let (asked, before, after) = std::thread::spawn(move || {
            let node = create_node::<ipc::Service>("slice", Some(&config)).expect("node");
            let before = reported_slice_ns();
            let options = SubscribeOptions {
                period: PERIOD,
                wait,
                deadline: None,
                ..SubscribeOptions::default()
            };
            let sub =
                Subscription::<PoseV2>::with_options(&node, &names, Topic::MeasuredCp, options)
                    .expect("subscription");
            (sub.short_slice(), before, reported_slice_ns())
        })
        .join()
        .expect("subscribing thread");
        if wait == WaitStrategy::Spin {
            assert!(
                !asked,
                "a spinning subscription never sleeps: no slice asked"
            );
            assert_eq!(after, before, "spin leaves the thread's slice as it was");
            continue;
        }
        assert!(asked, "{wait:?}: a normal thread is given the short slice");
        match after {
            Some(slice) if kernel_has_custom_slices() => {
                assert_eq!(slice, 100_000, "{wait:?}: se.slice after subscribing");
                assert_ne!(
                    before,
                    Some(100_000),
                    "the default slice is not already 0.1 ms"
                );
            }
            _ => eprintln!(
                "skipped: this kernel has no per-task slice to read back (se.slice {after:?})"
            ),
        }
    }
}
