//! Subscribers and publishers in other processes: every wait strategy gets every seq, a killed
//! subscriber stops counting once the publisher reaps it, and a subscriber whose publisher is
//! killed hears it once, without iceoryx2's own log output.

mod common;

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, CycleMessages, Header, JointStateV2, SubscribeOptions, Subscription, Topic,
    Update, WaitStrategy, create_node, monotonic_ns,
};

const PERIOD: Duration = Duration::from_millis(1);

fn node(d: &Domain, name: &str) -> Node<ipc::Service> {
    create_node::<ipc::Service>(name, Some(&d.config)).expect("node")
}

fn publish(p: &ArmPublisher, seq: u64) {
    let t = monotonic_ns();
    let mut c = CycleMessages::default();
    c.set_header(Header {
        seq,
        sample_t_ns: t,
        publish_t_ns: t,
        valid: 1,
        ..Header::default()
    });
    c.compensated.local_measured_cp.position_m[2] = -0.1;
    c.compensated.measured_cp.position_m[2] = -0.1;
    p.publish_cycle(&c).expect("publish");
}

/// Publishes on an absolute 1 ms grid, like the sidecar's loop.
fn publish_grid(p: &ArmPublisher, seqs: std::ops::RangeInclusive<u64>) {
    let t0 = monotonic_ns();
    let start = *seqs.start();
    for seq in seqs {
        let due = t0 + (seq - start) * PERIOD.as_nanos() as u64;
        while monotonic_ns() < due {
            std::thread::sleep(Duration::from_micros(100));
        }
        publish(p, seq);
    }
}

// ---- child processes ---------------------------------------------------------------------

const ENV_ROLE: &str = "DVRK_IPC_LIFECYCLE_ROLE";
const ENV_WAIT: &str = "DVRK_IPC_LIFECYCLE_WAIT";
const ENV_COUNT: &str = "DVRK_IPC_LIFECYCLE_COUNT";

fn spawn(d: &Domain, role: &str, wait: WaitStrategy, count: u64, log: Option<&str>) -> Child {
    let mut cmd = Command::new(std::env::current_exe().expect("test binary"));
    cmd.args([
        "child_role",
        "--exact",
        "--ignored",
        "--nocapture",
        "--test-threads=1",
    ])
    .envs(d.env())
    .env(ENV_ROLE, role)
    .env(ENV_WAIT, wait.name())
    .env(ENV_COUNT, count.to_string())
    .env_remove("IOX2_LOG_LEVEL")
    .stdout(Stdio::piped())
    .stderr(Stdio::piped());
    if let Some(level) = log {
        cmd.env("IOX2_LOG_LEVEL", level);
    }
    cmd.spawn().expect("spawn child")
}

fn lines(child: &mut Child) -> impl Iterator<Item = String> + use<> {
    let out = child.stdout.take().expect("piped stdout");
    BufReader::new(out).lines().map_while(Result::ok)
}

fn wait_for_tag(lines: &mut impl Iterator<Item = String>, tag: &str) -> Option<String> {
    let tag = format!("{tag} ");
    lines.find_map(|l| l.split_once(&tag).map(|(_, rest)| rest.to_owned()))
}

/// Not a test on its own: the body of the child processes spawned by the tests below.
#[test]
#[ignore = "child process role; run by the cross-process tests"]
fn child_role() {
    let Ok(role) = std::env::var(ENV_ROLE) else {
        return;
    };
    std::thread::spawn(|| {
        std::thread::sleep(Duration::from_secs(60));
        std::process::exit(3);
    });
    let d = Domain::from_env();
    let wait: WaitStrategy = std::env::var(ENV_WAIT).unwrap().parse().unwrap();
    let count: u64 = std::env::var(ENV_COUNT).unwrap().parse().unwrap();
    let node = node(&d, &format!("child_{role}"));
    match role.as_str() {
        "subscriber" => {
            let options = SubscribeOptions {
                period: PERIOD,
                wait,
                deadline: Some(Duration::from_millis(50)),
                ..SubscribeOptions::default()
            };
            let mut sub = Subscription::<JointStateV2>::with_options(
                &node,
                &d.names,
                Topic::MeasuredJs,
                options,
            )
            .unwrap();
            println!("READY 1");
            let mut seqs = Vec::new();
            let mut announced = false;
            loop {
                match sub.wait_with(|v| seqs.push(v.header.seq)).unwrap() {
                    Update::Fresh(v) => {
                        if !announced {
                            println!("FRESH {}", v.header.seq);
                            announced = true;
                        }
                        if v.header.seq >= count {
                            break;
                        }
                    }
                    Update::Terminated => {
                        // What an application prints: one line naming the service.
                        println!("GONE publisher of {} is gone", sub.service_name());
                        break;
                    }
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
            println!(
                "PREDICTED {} {} {} {}",
                s.predicted_on_time_total,
                s.predicted_late_total,
                s.predicted_missed_total,
                sub.prediction().is_some()
            );
            println!("MODEL {:?}", sub.prediction());
        }
        "publisher" => {
            let publisher = ArmPublisher::create(&node, &d.names).unwrap();
            println!("READY 1");
            for seq in 1.. {
                publish(&publisher, seq);
                std::thread::sleep(PERIOD);
            }
        }
        other => panic!("unknown role {other}"),
    }
}

fn wait_until(mut f: impl FnMut() -> bool) -> bool {
    for _ in 0..2000 {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    false
}

// ---- tests ---------------------------------------------------------------------------------

#[test]
fn every_wait_strategy_gets_every_seq_in_order_from_another_process() {
    for wait in WaitStrategy::ALL {
        let d = Domain::new(&format!("strategy_{wait}"));
        let node = node(&d, "strategy_pub");
        let publisher = ArmPublisher::create(&node, &d.names).unwrap();
        const N: u64 = 600;
        let mut child = spawn(&d, "subscriber", wait, N, None);
        let mut out = lines(&mut child);
        assert!(
            wait_for_tag(&mut out, "READY").is_some(),
            "{wait}: no start"
        );
        assert!(
            wait_until(|| publisher.number_of_subscribers(Topic::MeasuredJs) == 1),
            "{wait}: subscriber not seen"
        );
        let listeners = publisher.subscriber_counts().cycle_listeners;
        assert_eq!(
            listeners,
            usize::from(wait != WaitStrategy::Spin),
            "{wait}: a spinning subscriber opens no listener, the others one"
        );
        publish_grid(&publisher, 1..=N);
        let seqs: Vec<u64> = wait_for_tag(&mut out, "SEQS")
            .expect("SEQS")
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        let gaps: u64 = wait_for_tag(&mut out, "GAPS").unwrap().parse().unwrap();
        let predicted = wait_for_tag(&mut out, "PREDICTED").unwrap();
        let model = wait_for_tag(&mut out, "MODEL").unwrap();
        out.for_each(drop);
        assert!(child.wait().unwrap().success(), "{wait}: child failed");
        assert_eq!(
            seqs,
            (1..=N).collect::<Vec<_>>(),
            "{wait}: every seq, in order"
        );
        assert_eq!(gaps, 0, "{wait}");
        let p: Vec<&str> = predicted.split(' ').collect();
        if wait == WaitStrategy::Predictive {
            assert_eq!(p[3], "true", "the period was learnt: {predicted}");
            // On time, late, or polled in vain and then woken by the event: the prediction was
            // used (how often it is on time is the latency harness's business, not a test's:
            // this publisher is a debug build sleeping in 100 µs steps on a shared machine).
            let used: u64 = p[..3].iter().map(|x| x.parse::<u64>().unwrap()).sum();
            assert!(
                used > 0,
                "most waits used the prediction: {predicted} {model}"
            );
        } else {
            assert_eq!(&p[..3], ["0", "0", "0"], "{wait}: {predicted}");
        }
    }
}

#[test]
fn killed_subscriber_counts_until_the_publisher_reaps_it() {
    let d = Domain::new("reap");
    let node = node(&d, "reap_pub");
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    let mut child = spawn(&d, "subscriber", WaitStrategy::Event, u64::MAX, None);
    let mut out = lines(&mut child);
    assert!(wait_for_tag(&mut out, "READY").is_some());
    assert!(wait_until(
        || publisher.subscriber_counts().cycle_listeners == 1
    ));
    let counts = publisher.subscriber_counts();
    assert_eq!(counts.get(Topic::MeasuredJs), 1);
    assert_eq!(counts.max(), (Topic::MeasuredJs, 1));
    assert_eq!(counts.min().1, 0, "the child subscribes to one topic only");
    publish(&publisher, 1);
    assert!(wait_for_tag(&mut out, "FRESH").is_some());

    child.kill().expect("SIGKILL");
    child.wait().unwrap();
    drop(out);
    // The dead process still counts, and its listener is still notified every cycle.
    for seq in 2..20 {
        publish(&publisher, seq);
    }
    let before = publisher.subscriber_counts();
    assert_eq!(before.get(Topic::MeasuredJs), 1, "dead but not reaped yet");
    assert_eq!(before.cycle_listeners, 1);
    let report = publisher.reap_dead_nodes();
    assert!(report.reaped >= 1, "{report:?}");
    assert_eq!(report.failed, 0);
    let after = publisher.subscriber_counts();
    assert_eq!(after.total(), 0, "{after:?}");
    assert_eq!(after.cycle_listeners, 0);
    // Publishing goes on undisturbed, and a second reap finds nothing.
    publish(&publisher, 20);
    assert_eq!(publisher.reap_dead_nodes().reaped, 0);
}

/// Runs a subscriber child against a publisher child, kills the publisher, and returns the
/// subscriber's GONE line and everything it wrote on stderr.
fn kill_publisher_under_subscriber(d: &Domain, log: Option<&str>) -> (Option<String>, String) {
    let mut publisher = spawn(d, "publisher", WaitStrategy::Event, 0, None);
    let mut pub_out = lines(&mut publisher);
    assert!(wait_for_tag(&mut pub_out, "READY").is_some());
    let mut sub = spawn(d, "subscriber", WaitStrategy::Event, u64::MAX, log);
    let mut err = sub.stderr.take().unwrap();
    let stderr = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let mut out = lines(&mut sub);
    assert!(wait_for_tag(&mut out, "FRESH").is_some(), "samples flow");
    publisher.kill().unwrap();
    publisher.wait().unwrap();
    drop(pub_out);
    let gone = wait_for_tag(&mut out, "GONE");
    out.for_each(drop);
    assert!(sub.wait().unwrap().success());
    (gone, stderr.join().unwrap())
}

#[test]
fn subscriber_of_a_killed_publisher_hears_it_once_without_iceoryx2_logs() {
    let d = Domain::new("gone");
    let start = monotonic_ns();
    let (gone, stderr) = kill_publisher_under_subscriber(&d, None);
    let gone = gone.expect("the subscriber was told");
    assert!(
        gone.contains("publisher of test/gone/measured_js is gone"),
        "{gone}"
    );
    assert!(
        monotonic_ns() - start < 10_000_000_000,
        "told within seconds, not after a long timeout"
    );
    assert!(
        stderr.is_empty(),
        "nothing from iceoryx2 on the terminal, got {} bytes: {stderr:.300}",
        stderr.len()
    );
}

#[test]
fn iceoryx2_logs_come_back_when_asked_for() {
    // The control for the test above: the same run with IOX2_LOG_LEVEL=debug does log, so an
    // empty stderr there means the level was set, not that nothing happened.
    let d = Domain::new("gone_log");
    let (gone, stderr) = kill_publisher_under_subscriber(&d, Some("debug"));
    assert!(gone.is_some());
    assert!(!stderr.is_empty(), "iceoryx2 logs at debug level");
}
