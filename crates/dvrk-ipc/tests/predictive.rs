//! The predictive wait against a real publisher in this process (real shared memory and event
//! socket): what it does when the cycle event comes without a new sample.
//!
//! The sidecar notifies the cycle event after the cycle's last message, so a predictive
//! subscriber that took its sample by polling finds that notification in its next sleep. It
//! must go back to sleep until its timer, not start polling there (which kept it busy for most
//! of each period: 70 % of a core at 1.5 kHz, 2026-11-23).

mod common;

use std::sync::mpsc;
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::prelude::PortFactory as _;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    JointStateV2, SubscribeOptions, Subscription, Topic, Update, WaitStrategy, create_node,
    monotonic_ns, open_cycle_event, open_topic,
};

/// A slow period, so that polling through it (the fault) and sleeping through it (the fix)
/// differ by tens of milliseconds of CPU time even on a loaded machine.
const PERIOD_NS: u64 = 50_000_000;
/// Cycles published on the grid before the one under test (the predictor learns 16).
const LEARN: u64 = 20;

fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid, writable timespec; the clock exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

fn sleep_until(t_ns: u64) {
    let now = monotonic_ns();
    if t_ns > now {
        std::thread::sleep(Duration::from_nanos(t_ns - now));
    }
}

#[test]
fn a_cycle_event_without_a_new_sample_does_not_start_polling() {
    let d = Domain::new("predictive_bare_event");
    let node = create_node::<ipc::Service>("pred_pub", Some(&d.config)).unwrap();
    let topic =
        open_topic::<JointStateV2, ipc::Service>(&node, &d.names, Topic::MeasuredJs).unwrap();
    let publisher = topic.publisher_builder().create().unwrap();
    let event = open_cycle_event(&node, &d.names).unwrap();
    let notifier = event.notifier_builder().create().unwrap();

    // The subscription lives on its own thread (its ports are !Send) and reports, for every
    // sample, its seq and the CPU time the wait that returned it used.
    let (tx, rx) = mpsc::channel::<(u64, u64)>();
    let (config, names) = (d.config.clone(), d.names.clone());
    let sub = std::thread::spawn(move || {
        let node = create_node::<ipc::Service>("pred_sub", Some(&config)).unwrap();
        let options = SubscribeOptions {
            period: Duration::from_nanos(PERIOD_NS),
            wait: WaitStrategy::Predictive,
            deadline: Some(Duration::from_secs(5)),
        };
        let mut sub =
            Subscription::<JointStateV2>::with_options(&node, &names, Topic::MeasuredJs, options)
                .unwrap();
        tx.send((0, 0)).unwrap();
        loop {
            let c0 = thread_cpu_ns();
            let update = sub.wait().unwrap();
            let cpu = thread_cpu_ns() - c0;
            match update {
                Update::Fresh(m) => {
                    tx.send((m.header.seq, cpu)).unwrap();
                    if m.header.seq == LEARN + 1 {
                        return sub.stats();
                    }
                }
                other => panic!("unexpected {other:?}"),
            }
        }
    });
    assert_eq!(rx.recv().unwrap(), (0, 0), "subscriber ready");
    for _ in 0..2000 {
        if topic.dynamic_config().number_of_subscribers() == 1
            && event.dynamic_config().number_of_listeners() == 1
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let send = |seq: u64| {
        let now = monotonic_ns();
        let mut m = JointStateV2::default();
        m.header.seq = seq;
        m.header.sample_t_ns = now;
        m.header.publish_t_ns = now;
        m.header.valid = 1;
        publisher.send_copy(m).unwrap();
    };
    let t0 = monotonic_ns() + PERIOD_NS;
    for seq in 1..=LEARN {
        sleep_until(t0 + (seq - 1) * PERIOD_NS);
        send(seq);
        notifier.notify().unwrap();
    }
    // The cycle under test: the event comes 5 ms into the period without a sample (as after a
    // sample taken by polling), the sample on the grid 45 ms later.
    let t_last = t0 + (LEARN - 1) * PERIOD_NS;
    sleep_until(t_last + 5_000_000);
    notifier.notify().unwrap();
    sleep_until(t_last + PERIOD_NS);
    send(LEARN + 1);
    notifier.notify().unwrap();

    let got: Vec<(u64, u64)> = rx.iter().collect();
    let stats = sub.join().unwrap();
    let seqs: Vec<u64> = got.iter().map(|(s, _)| *s).collect();
    assert_eq!(
        seqs,
        (1..=LEARN + 1).collect::<Vec<_>>(),
        "every seq, in order"
    );
    assert_eq!(stats.seq_gaps_total, 0);
    // Polling from the bare event to the sample would take 45 ms of CPU (at least a third of
    // that on a machine loaded 3 times over its cores); sleeping until the timer (guard at most
    // an eighth of the period) takes a few hundred µs.
    let (_, cpu) = got[LEARN as usize];
    assert!(
        cpu < PERIOD_NS / 10,
        "the wait for seq {} used {} µs of CPU: it polled after the bare event ({stats:?})",
        LEARN + 1,
        cpu / 1000
    );
}
