//! The predictive wait against a real publisher in this process (real shared memory and event
//! socket): what it does when the cycle event comes without a new sample, and when it runs the
//! caller's `prepare` (`Subscription::wait_prepared`; the event wait's, too, for comparison).
//!
//! The sidecar notifies the cycle event after the cycle's last message, so a predictive
//! subscriber that took its sample by polling finds that notification in its next sleep. It
//! must go back to sleep until its timer, not start polling there (which kept it busy for most
//! of each period: 70 % of a core at 1.5 kHz, 2026-11-23).

mod common;

use std::sync::mpsc;
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::config::Config;
use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::port::notifier::Notifier;
use dvrk_ipc::iceoryx2::port::publisher::Publisher;
use dvrk_ipc::iceoryx2::prelude::PortFactory as _;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use dvrk_ipc::iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use dvrk_ipc::{
    JointStateV2, ServiceNames, SubscribeOptions, Subscription, Topic, Update, WaitStrategy,
    create_node, monotonic_ns, open_cycle_event, open_topic,
};

/// A slow period, so that polling through it (the fault) and sleeping through it (the fix)
/// differ by tens of milliseconds of CPU time even on a loaded machine.
const PERIOD_NS: u64 = 50_000_000;
/// Cycles published on the grid before the one under test (the predictor learns 16).
const LEARN: u64 = 20;
/// Cycles on the grid in the `prepare` tests, before the one whose sample is there on entry:
/// a dozen or more predicted waits, so that a few timers late beyond the guard on a loaded
/// machine (those waits have no moment to prepare in) leave most of them to check.
const PREPARED: u64 = LEARN + 10;

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

/// The publishing side of a test: `measured_js` and the cycle event of the test's domain, as
/// the sidecar publishes them.
struct Grid {
    topic: PubSubFactory<ipc::Service, JointStateV2, ()>,
    publisher: Publisher<ipc::Service, JointStateV2, ()>,
    event: EventFactory<ipc::Service>,
    notifier: Notifier<ipc::Service>,
    /// Last, so that the ports and services above go first.
    _node: Node<ipc::Service>,
}

impl Grid {
    fn new(d: &Domain, node_name: &str) -> Self {
        let node = create_node::<ipc::Service>(node_name, Some(&d.config)).unwrap();
        let topic =
            open_topic::<JointStateV2, ipc::Service>(&node, &d.names, Topic::MeasuredJs).unwrap();
        let publisher = topic.publisher_builder().create().unwrap();
        let event = open_cycle_event(&node, &d.names).unwrap();
        let notifier = event.notifier_builder().create().unwrap();
        Self {
            topic,
            publisher,
            event,
            notifier,
            _node: node,
        }
    }

    /// Waits (up to 2 s) until the one subscription's subscriber and listener are connected.
    fn wait_for_the_subscriber(&self) {
        for _ in 0..2000 {
            if self.topic.dynamic_config().number_of_subscribers() == 1
                && self.event.dynamic_config().number_of_listeners() == 1
            {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Sends a valid sample `seq`, sampled and published now.
    fn send(&self, seq: u64) {
        let now = monotonic_ns();
        let mut m = JointStateV2::default();
        m.header.seq = seq;
        m.header.sample_t_ns = now;
        m.header.publish_t_ns = now;
        m.header.valid = 1;
        self.publisher.send_copy(m).unwrap();
    }

    fn notify(&self) {
        self.notifier.notify().unwrap();
    }
}

/// A subscription to the grid's `measured_js` on a node of its own (returned after it, to be
/// dropped after it), at the grid's period, with a 5 s deadline.
fn subscribe(
    config: &Config,
    names: &ServiceNames,
    node_name: &str,
    wait: WaitStrategy,
) -> (Subscription<JointStateV2>, Node<ipc::Service>) {
    let node = create_node::<ipc::Service>(node_name, Some(config)).unwrap();
    let options = SubscribeOptions {
        period: Duration::from_nanos(PERIOD_NS),
        wait,
        deadline: Some(Duration::from_secs(5)),
        ..SubscribeOptions::default()
    };
    let sub = Subscription::<JointStateV2>::with_options(&node, names, Topic::MeasuredJs, options)
        .unwrap();
    (sub, node)
}

#[test]
fn a_cycle_event_without_a_new_sample_does_not_start_polling() {
    let d = Domain::new("predictive_bare_event");
    let grid = Grid::new(&d, "pred_pub");

    // The subscription lives on its own thread (its ports are !Send) and reports, for every
    // sample, its seq and the CPU time the wait that returned it used.
    let (tx, rx) = mpsc::channel::<(u64, u64)>();
    let (config, names) = (d.config.clone(), d.names.clone());
    let sub = std::thread::spawn(move || {
        let (mut sub, _node) = subscribe(&config, &names, "pred_sub", WaitStrategy::Predictive);
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
    grid.wait_for_the_subscriber();
    let t0 = monotonic_ns() + PERIOD_NS;
    for seq in 1..=LEARN {
        sleep_until(t0 + (seq - 1) * PERIOD_NS);
        grid.send(seq);
        grid.notify();
    }
    // The cycle under test: the event comes 5 ms into the period without a sample (as after a
    // sample taken by polling), the sample on the grid 45 ms later.
    let t_last = t0 + (LEARN - 1) * PERIOD_NS;
    sleep_until(t_last + 5_000_000);
    grid.notify();
    sleep_until(t_last + PERIOD_NS);
    grid.send(LEARN + 1);
    grid.notify();

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

/// What one wait of [`prepare_runs_once_when_the_sample_is_due`]'s subscriber saw.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    seq: u64,
    /// When the wait began.
    entered_ns: u64,
    /// When `prepare` ran, once per call.
    calls: [Option<u64>; 2],
    /// Whether the predictor was ready when the wait began.
    predicting: bool,
}

/// `wait_prepared` calls `prepare` once per wait, at the moment the strategy expects to be
/// idle until the sample: the predictive wait after its timer (half a period after it began,
/// at least), the event wait before it sleeps; never when the sample is there on entry.
///
/// Returns the waits and the time (monotonic ns) the first sample was due to be sent; sample
/// `seq` was due `(seq - 1)` periods after it.
fn prepare_runs_once_when_the_sample_is_due(wait: WaitStrategy) -> (Vec<Prepared>, u64) {
    let d = Domain::new(&format!("prepare_{}", wait.name()));
    let grid = Grid::new(&d, "prep_pub");

    let (tx, rx) = mpsc::channel::<Prepared>();
    let (config, names) = (d.config.clone(), d.names.clone());
    let sub = std::thread::spawn(move || {
        let (mut sub, _node) = subscribe(&config, &names, "prep_sub", wait);
        tx.send(Prepared {
            seq: 0,
            entered_ns: 0,
            calls: [None; 2],
            predicting: false,
        })
        .unwrap();
        loop {
            let predicting = sub.prediction().is_some();
            let entered_ns = monotonic_ns();
            let mut calls = [None; 2];
            let mut n = 0;
            let update = sub
                .wait_prepared(
                    |_| {},
                    || {
                        if n < calls.len() {
                            calls[n] = Some(monotonic_ns());
                        }
                        n += 1;
                    },
                )
                .unwrap();
            let Update::Fresh(m) = update else {
                panic!("unexpected {update:?}");
            };
            let seq = m.header.seq;
            tx.send(Prepared {
                seq,
                entered_ns,
                calls,
                predicting,
            })
            .unwrap();
            if seq == PREPARED + 2 {
                return;
            }
            if seq == PREPARED {
                // The next sample lands before the next wait begins.
                std::thread::sleep(Duration::from_nanos(PERIOD_NS * 3 / 2));
            }
        }
    });
    assert_eq!(rx.recv().unwrap().seq, 0, "subscriber ready");
    grid.wait_for_the_subscriber();
    let t0 = monotonic_ns() + PERIOD_NS;
    for seq in 1..=PREPARED + 2 {
        sleep_until(t0 + (seq - 1) * PERIOD_NS);
        grid.send(seq);
        grid.notify();
    }
    let got: Vec<Prepared> = rx.iter().collect();
    sub.join().unwrap();
    assert_eq!(
        got.iter().map(|p| p.seq).collect::<Vec<_>>(),
        (1..=PREPARED + 2).collect::<Vec<_>>(),
        "every seq, in order"
    );
    (got, t0)
}

#[test]
fn the_predictive_wait_prepares_after_its_timer() {
    let (got, t0) = prepare_runs_once_when_the_sample_is_due(WaitStrategy::Predictive);
    let predicted: Vec<&Prepared> = got
        .iter()
        .filter(|p| p.predicting && p.seq <= PREPARED)
        .collect();
    assert!(
        predicted.len() >= 8,
        "the predictor was ready for a dozen waits: {got:?}"
    );
    // Only the waits that began at least half a period before their sample was due: on a loaded
    // machine the subscriber thread may come back to its wait late (CI once saw prepare run
    // 4.3 ms into a wait), and then the timer is already past and preparing at once is right.
    let on_time: Vec<&&Prepared> = predicted
        .iter()
        .filter(|p| p.entered_ns + PERIOD_NS / 2 <= t0 + (p.seq - 1) * PERIOD_NS)
        .collect();
    assert!(
        on_time.len() * 2 >= predicted.len(),
        "most waits began on time: {got:?}"
    );
    let mut prepared = 0;
    for p in &on_time {
        let at = match p.calls {
            [Some(at), None] => at,
            // The sample landed while the wait still slept (its timer late beyond the guard,
            // on a loaded machine): no moment to prepare in.
            [None, None] => continue,
            _ => panic!("prepare ran more than once in a wait: {p:?}"),
        };
        prepared += 1;
        // Each wait begins right after the last sample and sleeps until a guard (at most an
        // eighth of the period) before the next: preparing at the start would be within
        // microseconds of it.
        assert!(
            at - p.entered_ns > PERIOD_NS / 2,
            "prepare ran {} µs into the wait for seq {}, before the timer",
            (at - p.entered_ns) / 1000,
            p.seq
        );
    }
    assert!(
        prepared * 2 >= on_time.len(),
        "prepare ran in {prepared} of {} predicted waits begun on time: {got:?}",
        on_time.len()
    );
    let late = got[PREPARED as usize];
    assert_eq!(
        late.calls,
        [None, None],
        "a sample already there: no prepare"
    );
}

#[test]
fn the_event_wait_prepares_before_it_sleeps() {
    let (got, _) = prepare_runs_once_when_the_sample_is_due(WaitStrategy::Event);
    for p in &got[1..PREPARED as usize] {
        let [Some(at), None] = p.calls else {
            panic!("prepare ran once in every wait: {p:?}");
        };
        // The sample comes a period after the last one: well after the sleep began.
        assert!(
            at - p.entered_ns < PERIOD_NS / 2,
            "prepare ran {} µs into the wait for seq {}, after the sleep",
            (at - p.entered_ns) / 1000,
            p.seq
        );
    }
    let late = got[PREPARED as usize];
    assert_eq!(
        late.calls,
        [None, None],
        "a sample already there: no prepare"
    );
}
