//! The fault suite: `serve` (shared mode, real UDP) reads the board emulator (`dvrk-sidecar sim`,
//! a real process) through a Rust fault proxy on loopback, and a subscriber in this process reads
//! every cycle from shared memory. Faults: datagram loss, bit flips, delayed and duplicated
//! replies, a stall of the emulator (SIGSTOP), an emulator killed and restarted, loss at start-up.
//!
//! What must hold, whatever the fault:
//! - `serve` stays alive;
//! - no sample is published as valid unless it is a plausible reading of the arm: within the
//!   arm's limits plus a margin, and consistent with the previous cycle's valid sample (the
//!   simulated arm moves smoothly, so a corrupted value shows as a jump); an invalid sample
//!   carries the last valid values (flag HELD), never zeros;
//! - the subscriber sees every seq, no gap;
//! - valid samples come back after the fault ends. The recovery time is printed (see
//!   RELIABILITY.md for the figures); the test asserts only a liveness bound, because this
//!   machine is shared and its timing noisy.
//!
//! Run with `--nocapture` to see the figures of each case (`FAULTS ...` lines).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use common::proxy::{FaultProxy, Faults, ProxyCounters};
use common::*;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{CompensationStatusV4, JointStateV2, ServiceNames, Topic, flags, qos};
use dvrk_sidecar::rt::monotonic_ns;

/// A liveness bound for recovery, not a speed claim (the goal, 100 ms, is recorded from the
/// printed figures in RELIABILITY.md).
const RECOVERY_BOUND: Duration = Duration::from_secs(2);

#[derive(Clone, Copy, Debug)]
struct Rec {
    seq: u64,
    valid: bool,
    flags: u32,
    position: [f64; 6],
    sample_t_ns: u64,
}

/// Reads `measured_js` and `compensated/status` of `prefix` in a thread, every cycle.
struct Collector {
    js: Arc<Mutex<Vec<Rec>>>,
    status: Arc<Mutex<Vec<CompensationStatusV4>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Collector {
    fn start(prefix: &str) -> Self {
        let js = Arc::new(Mutex::new(Vec::new()));
        let status = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (j, st, sp, prefix) = (js.clone(), status.clone(), stop.clone(), prefix.to_owned());
        let thread = std::thread::spawn(move || {
            let node = dvrk_ipc::create_node::<Service>("fault-suite", None).unwrap();
            let names = ServiceNames::new(&prefix).unwrap();
            let js_sub =
                dvrk_ipc::open_topic::<JointStateV2, Service>(&node, &names, Topic::MeasuredJs)
                    .unwrap()
                    .subscriber_builder()
                    .buffer_size(qos::SUBSCRIBER_MAX_BUFFER_SIZE)
                    .create()
                    .unwrap();
            let st_sub = dvrk_ipc::open_topic::<CompensationStatusV4, Service>(
                &node,
                &names,
                Topic::CompensatedStatus,
            )
            .unwrap()
            .subscriber_builder()
            .buffer_size(qos::SUBSCRIBER_MAX_BUFFER_SIZE)
            .create()
            .unwrap();
            while !sp.load(Ordering::Relaxed) {
                while let Ok(Some(s)) = js_sub.receive() {
                    let h = s.header;
                    j.lock().unwrap().push(Rec {
                        seq: h.seq,
                        valid: h.valid != 0,
                        flags: h.flags,
                        position: s.position,
                        sample_t_ns: h.sample_t_ns,
                    });
                }
                while let Ok(Some(s)) = st_sub.receive() {
                    st.lock().unwrap().push(*s);
                }
                std::thread::sleep(Duration::from_micros(500));
            }
        });
        Self {
            js,
            status,
            stop,
            thread: Some(thread),
        }
    }

    fn records(&self) -> Vec<Rec> {
        self.js.lock().unwrap().clone()
    }

    /// Host time of the first valid sample read after `t_ns`.
    fn first_valid_after(&self, t_ns: u64, limit: Duration) -> Option<u64> {
        eventually(limit, || {
            self.js
                .lock()
                .unwrap()
                .iter()
                .find(|r| r.valid && r.sample_t_ns > t_ns)
                .map(|r| r.sample_t_ns)
        })
    }

    fn stop(mut self) -> (Vec<Rec>, Vec<CompensationStatusV4>) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().unwrap();
        }
        let js = std::mem::take(&mut *self.js.lock().unwrap());
        let st = std::mem::take(&mut *self.status.lock().unwrap());
        (js, st)
    }
}

impl Drop for Collector {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// What a run of records shows.
#[derive(Debug, Default)]
struct Report {
    samples: usize,
    valid: usize,
    invalid: usize,
    /// Valid samples that are not a plausible reading of the arm (must be 0).
    wrongly_valid: usize,
    /// Invalid samples whose values are not the last valid sample's (must be 0).
    not_held: usize,
    seq_gaps: usize,
    implausible: usize,
}

/// Joint ranges of the Classic PSM (reference: ±91°, ±53°, 0-0.24 m; wrist joints through the
/// 400006 coupling) plus 5° / 5 mm.
const LIMITS: [[f64; 2]; 6] = [
    [-1.676, 1.676],
    [-1.013, 1.013],
    [-0.005, 0.245],
    [-4.84, 4.84],
    [-3.18, 3.18],
    [-3.23, 3.23],
];
/// Largest change between two consecutive cycles of the simulated arm that is still a real
/// motion: a fixed part, plus a speed no joint of the divot-push scenario reaches times the
/// time between the two reads (a loaded machine can stall `serve` between two cycles while the
/// emulator's arm moves on). A flipped encoder bit above the lowest few shows as a larger jump.
const SMOOTH: [f64; 6] = [5e-3, 5e-3, 5e-4, 5e-3, 5e-3, 5e-3];
const SMOOTH_SPEED: [f64; 6] = [1.0, 1.0, 0.1, 1.0, 1.0, 1.0];

/// Without reply CRCs (a real FPGA), a flipped low bit is indistinguishable from motion; the
/// plausibility checks bound what can pass to the arm's maximum velocity. This oracle, looser
/// than those checks by 2x, catches any corruption beyond that bound (an insertion of 5 m, a wrist
/// at -685 rad, the values seen before the checks existed).
const VMAX_NO_CRC: [f64; 6] = [12.0, 12.0, 1.2, 120.0, 120.0, 120.0];
const MARGIN_NO_CRC: [f64; 6] = [5e-3, 5e-3, 5e-4, 1e-2, 1e-2, 1e-2];

fn analyse(recs: &[Rec]) -> Report {
    analyse_with(recs, true)
}

/// `strict`: the replies carry CRCs, so any corruption must be caught: valid samples change
/// only as much as the simulated arm moves in a cycle ([`SMOOTH`]). Otherwise the bound of
/// [`VMAX_NO_CRC`].
fn analyse_with(recs: &[Rec], strict: bool) -> Report {
    let mut r = Report {
        samples: recs.len(),
        ..Default::default()
    };
    let mut last_valid: Option<&Rec> = None;
    let mut prev: Option<&Rec> = None;
    for s in recs {
        if let Some(p) = prev
            && s.seq != p.seq + 1
        {
            r.seq_gaps += 1;
        }
        if s.flags & flags::IMPLAUSIBLE != 0 {
            r.implausible += 1;
        }
        if s.valid {
            r.valid += 1;
            let in_range = s
                .position
                .iter()
                .zip(LIMITS)
                .all(|(q, [lo, hi])| q.is_finite() && (lo..=hi).contains(q));
            let smooth = match prev {
                Some(p) if p.valid && s.seq == p.seq + 1 => {
                    let dt = s.sample_t_ns.saturating_sub(p.sample_t_ns) as f64 * 1e-9;
                    (0..SMOOTH.len()).all(|j| {
                        let moved = (s.position[j] - p.position[j]).abs();
                        if strict {
                            moved <= SMOOTH[j] + SMOOTH_SPEED[j] * dt
                        } else {
                            moved <= VMAX_NO_CRC[j] * dt + MARGIN_NO_CRC[j]
                        }
                    })
                }
                _ => true,
            };
            if !(in_range && smooth) {
                r.wrongly_valid += 1;
                eprintln!("wrongly valid: {s:?}\n  previous: {prev:?}");
            }
            last_valid = Some(s);
        } else {
            r.invalid += 1;
            let correction = flags::CORRECTION_ACTIVE_J1
                | flags::CORRECTION_ACTIVE_J2
                | flags::INSERTION_CLAMPED;
            let held = s.flags & correction == 0
                && match last_valid {
                    Some(v) => s.flags & flags::HELD != 0 && s.position == v.position,
                    // Held from before this window, or NaN before any valid sample.
                    None => s.flags & flags::HELD != 0 || s.position.iter().all(|q| q.is_nan()),
                };
            if !held {
                if r.not_held == 0 {
                    eprintln!("not held: {s:?}\n  last valid: {last_valid:?}");
                }
                r.not_held += 1;
            }
        }
        prev = Some(s);
    }
    r
}

/// Reads a child's stderr in a thread (a pipe nobody reads fills up after 64 KiB and then
/// blocks the child's logging, and so its loop), keeping the last 256 KiB.
struct LogTail(Arc<Mutex<String>>, Option<JoinHandle<()>>);

impl LogTail {
    fn start(p: &mut Proc) -> Self {
        let mut err = p.child.as_mut().unwrap().stderr.take().unwrap();
        let buf = Arc::new(Mutex::new(String::new()));
        let b = buf.clone();
        let t = std::thread::spawn(move || {
            let mut chunk = [0u8; 4096];
            while let Ok(n) = std::io::Read::read(&mut err, &mut chunk) {
                if n == 0 {
                    break;
                }
                let mut s = b.lock().unwrap();
                s.push_str(&String::from_utf8_lossy(&chunk[..n]));
                if s.len() > 256 * 1024 {
                    let cut = s.len() - 128 * 1024;
                    let cut = (cut..s.len()).find(|i| s.is_char_boundary(*i)).unwrap();
                    s.replace_range(..cut, "");
                }
            }
        });
        Self(buf, Some(t))
    }

    fn text(&mut self) -> String {
        if let Some(t) = self.1.take() {
            let _ = t.join();
        }
        self.0.lock().unwrap().clone()
    }
}

/// One emulator + proxy + serve, with a subscriber.
struct Rig {
    emulator: Proc,
    emulator_port: u16,
    proxy: FaultProxy,
    serve: Proc,
    serve_log: LogTail,
    collector: Collector,
    prefix: String,
}

impl Rig {
    fn start(test: &str, faults: Faults, seed: u64) -> Self {
        Self::start_with(test, faults, seed, "")
    }

    /// [`Rig::start`] with `extra` (top-level keys) at the head of serve's configuration.
    fn start_with(test: &str, faults: Faults, seed: u64, extra: &str) -> Self {
        let emulator_port = free_udp_port();
        let emulator = emulator(emulator_port, "divot-push.toml");
        let upstream: SocketAddr = ([127, 0, 0, 1], emulator_port).into();
        let proxy = FaultProxy::start(upstream, faults, seed);
        let prefix = unique_prefix(test);
        let cfg = write_config(
            test,
            &format!("udp:{}", proxy.addr),
            "shared",
            &prefix,
            "divot-push.toml",
        );
        if !extra.is_empty() {
            let text = std::fs::read_to_string(&cfg).unwrap();
            std::fs::write(&cfg, format!("{extra}\n{text}")).unwrap();
        }
        let collector = Collector::start(&prefix);
        let mut serve = serve(&cfg);
        let serve_log = LogTail::start(&mut serve);
        Self {
            emulator,
            emulator_port,
            proxy,
            serve,
            serve_log,
            collector,
            prefix,
        }
    }

    fn assert_alive(&mut self) {
        let st = self.serve.wait_timeout(Duration::from_millis(1));
        assert!(
            st.is_none(),
            "serve exited ({st:?}) under faults: {}",
            self.serve_log.text()
        );
    }

    /// Stops serve with SIGTERM; returns its exit status and log.
    fn stop_serve(&mut self) -> (std::process::ExitStatus, String) {
        let (st, _) = self.serve.terminate();
        (st, self.serve_log.text())
    }

    fn wait_first_valid(&self) -> u64 {
        self.collector
            .first_valid_after(0, Duration::from_secs(60))
            .unwrap_or_else(|| panic!("{}: no valid sample within 60 s", self.prefix))
    }
}

fn print(case: &str, injected: &ProxyCounters, r: &Report, recovery_ms: Option<f64>) {
    eprintln!(
        "FAULTS case={case} injected={} (lost {}, flipped {}, delayed {}, duplicated {}) \
         samples={} valid={} invalid={} implausible={} wrongly_valid={} not_held={} seq_gaps={} \
         recovery_ms={}",
        injected.injected(),
        injected.lost,
        injected.flipped,
        injected.delayed,
        injected.duplicated,
        r.samples,
        r.valid,
        r.invalid,
        r.implausible,
        r.wrongly_valid,
        r.not_held,
        r.seq_gaps,
        recovery_ms.map_or("-".to_owned(), |v| format!("{v:.1}"))
    );
}

fn assert_trustworthy(case: &str, r: &Report) {
    assert_eq!(
        r.wrongly_valid, 0,
        "{case}: a wrong sample was published as valid"
    );
    assert_eq!(
        r.not_held, 0,
        "{case}: an invalid sample did not hold the last valid one"
    );
    assert_eq!(r.seq_gaps, 0, "{case}: the subscriber missed cycles");
    assert!(r.samples > 0, "{case}: nothing published");
}

/// Each fault of the issue in turn, then all together, on one running service: loss, bit
/// flips, 5 ms delays, duplicates.
#[test]
fn steady_faults_never_publish_a_wrong_sample_as_valid() {
    let mut rig = Rig::start("steady-faults", Faults::default(), 1);
    rig.wait_first_valid();
    let cases = [
        (
            "loss-10%",
            Faults {
                loss: 0.10,
                ..Default::default()
            },
        ),
        (
            "bit-flip-1%",
            Faults {
                bit_flip: 0.01,
                ..Default::default()
            },
        ),
        (
            "delay-5ms",
            Faults {
                delay_chance: 0.02,
                delay: Duration::from_millis(5),
                ..Default::default()
            },
        ),
        (
            "duplicate-2%",
            Faults {
                duplicate: 0.02,
                ..Default::default()
            },
        ),
        (
            "all-together",
            Faults {
                loss: 0.10,
                bit_flip: 0.01,
                delay_chance: 0.02,
                delay: Duration::from_millis(5),
                duplicate: 0.02,
                strip_crc: false,
            },
        ),
    ];
    for (case, faults) in cases {
        let before_recs = rig.collector.records().len();
        let before = rig.proxy.counters();
        rig.proxy.set_faults(faults);
        std::thread::sleep(Duration::from_secs(3));
        rig.proxy.set_faults(Faults::default());
        let t_clear = monotonic_ns();
        let back = rig
            .collector
            .first_valid_after(t_clear, Duration::from_secs(30))
            .unwrap_or_else(|| panic!("{case}: no valid sample after the faults stopped"));
        rig.assert_alive();
        let recs = rig.collector.records();
        let r = analyse(&recs[before_recs..]);
        let after = rig.proxy.counters();
        let injected = ProxyCounters {
            requests: after.requests - before.requests,
            replies: after.replies - before.replies,
            lost: after.lost - before.lost,
            flipped: after.flipped - before.flipped,
            delayed: after.delayed - before.delayed,
            duplicated: after.duplicated - before.duplicated,
        };
        print(case, &injected, &r, Some((back - t_clear) as f64 / 1e6));
        assert!(injected.injected() > 0, "{case}: nothing injected");
        assert_trustworthy(case, &r);
        assert!(r.valid > 0, "{case}: no valid sample at all");
        // A flipped bit fails its CRC and the cycle. A lost datagram is asked again within
        // the cycle (issue 22 item 7), so loss alone may leave every sample valid.
        if injected.flipped > 0 {
            assert!(
                r.invalid > 0,
                "{case}: faults without a single invalid sample"
            );
        }

        assert!(
            Duration::from_nanos(back - t_clear) < RECOVERY_BOUND,
            "{case}: valid samples came back only after {} ms",
            (back - t_clear) / 1_000_000
        );
    }
    let (st, err) = rig.stop_serve();
    assert!(st.success(), "{err}");
    // The summary counted what the checks refused and the port's CRC check caught.
    assert!(err.contains("samples published as invalid"), "{err}");
    // The lost datagrams were asked again.
    assert!(
        err.contains("UDP port at the stop") && !err.contains("quadlet_retries=0 "),
        "{err}"
    );
}

/// Replies without CRCs, as a real FPGA sends them (the UDP checksum protects the wire, but the
/// proxy flips bits after it): every valid sample still lies within the arm's limits and
/// within what its maximum velocity allows since the previous one, and the plausibility checks
/// report what they refused.
#[test]
fn flipped_bits_without_crcs_are_caught_by_the_plausibility_checks() {
    let faults = Faults {
        bit_flip: 0.02,
        strip_crc: true,
        ..Default::default()
    };
    let mut rig = Rig::start("no-crc", faults, 5);
    rig.wait_first_valid();
    let n0 = rig.collector.records().len();
    std::thread::sleep(Duration::from_secs(4));
    rig.assert_alive();
    let recs = rig.collector.records();
    let r = analyse_with(&recs[n0..], false);
    let injected = rig.proxy.counters();
    print("bit-flip-2%-without-crc", &injected, &r, None);
    assert_trustworthy("bit-flip-2%-without-crc", &r);
    assert!(r.valid > r.invalid, "most samples stay valid");
    assert!(r.implausible > 0, "the plausibility checks caught nothing");
    let (st, err) = rig.stop_serve();
    assert!(st.success(), "{err}");
    assert!(err.contains("implausible"), "{err}");
}

/// The emulator stops (SIGSTOP) for 2 s, every request queued, then continues and answers them
/// all at once: the late replies are drained and valid samples resume.
#[test]
fn a_stall_of_the_boards_is_recovered() {
    let mut rig = Rig::start("stall", Faults::default(), 2);
    rig.wait_first_valid();
    std::thread::sleep(Duration::from_millis(300));
    for stall in [Duration::from_secs(2), Duration::from_millis(150)] {
        let n0 = rig.collector.records().len();
        rig.emulator.signal(libc::SIGSTOP);
        std::thread::sleep(stall);
        rig.emulator.signal(libc::SIGCONT);
        let t_cont = monotonic_ns();
        let back = rig
            .collector
            .first_valid_after(t_cont, Duration::from_secs(30))
            .expect("no valid sample after the stall");
        std::thread::sleep(Duration::from_millis(500));
        rig.assert_alive();
        let recs = rig.collector.records();
        let r = analyse(&recs[n0..]);
        let case = format!("stall-{}ms", stall.as_millis());
        print(
            &case,
            &ProxyCounters::default(),
            &r,
            Some((back - t_cont) as f64 / 1e6),
        );
        assert_trustworthy(&case, &r);
        assert!(r.invalid > 0, "{case}: the stall did not show");
        // After recovery every sample is valid again (no stale reply left to fail on).
        let tail: Vec<_> = recs[n0..].iter().filter(|s| s.sample_t_ns > back).collect();
        assert_recovered(&case, &tail);
        assert!(
            Duration::from_nanos(back - t_cont) < RECOVERY_BOUND,
            "{case}: recovery took {} ms",
            (back - t_cont) / 1_000_000
        );
    }
    rig.stop_serve();
    let (_, st) = rig.collector.stop();
    // The status message told the age of the held sample while the boards were silent.
    let max_age = st.iter().map(|s| s.held_sample_age_ns).max().unwrap();
    assert!(max_age >= 1_500_000_000, "held age at most {max_age} ns");
}

/// The samples after a recovery (`tail`) are valid again. A reply left over from the stall
/// would fail a read for a wrong reply (`BOARD_ERROR`, `IMPLAUSIBLE`) or keep failing it; a
/// starved emulator (this test's processes with other tests' and builds' on two cores) misses
/// a 5 ms reply timeout now and then, a lone cycle between valid ones. So: no invalid sample
/// for any other reason than a timeout, and at most 1% of the tail invalid, or at most 3% if
/// each is a lone cycle (the reason is printed either way).
fn assert_recovered(case: &str, tail: &[&Rec]) {
    let timeout_only = flags::BOARD_TIMEOUT | flags::HELD | flags::OVERRUN;
    let invalid: Vec<(usize, &&Rec)> = tail.iter().enumerate().filter(|(_, s)| !s.valid).collect();
    let shown: Vec<String> = invalid
        .iter()
        .take(20)
        .map(|(i, s)| format!("#{i} {:#x}", s.flags))
        .collect();
    eprintln!(
        "FAULTS case={case} tail={} invalid_in_tail={} {shown:?}",
        tail.len(),
        invalid.len()
    );
    for (i, s) in &invalid {
        assert!(
            s.flags & !timeout_only == 0 && s.flags & flags::BOARD_TIMEOUT != 0,
            "{case}: sample {i} after the recovery failed for another reason than a timeout: \
             flags {:#x}",
            s.flags
        );
    }
    let lone = invalid
        .iter()
        .all(|(i, _)| tail.get(i + 1).is_none_or(|s| s.valid) && (*i == 0 || tail[i - 1].valid));
    let share = invalid.len() as f64 / tail.len().max(1) as f64;
    assert!(
        share <= 0.01 || (lone && share <= 0.03),
        "{case}: reads keep failing after the stall: {} of {} samples invalid{}",
        invalid.len(),
        tail.len(),
        if lone { "" } else { ", some in a row" }
    );
}

/// The emulator is killed and a new one started on the same port.
#[test]
fn an_emulator_restart_is_recovered() {
    let mut rig = Rig::start("restart", Faults::default(), 3);
    rig.wait_first_valid();
    let n0 = rig.collector.records().len();
    rig.emulator.signal(libc::SIGKILL);
    rig.emulator.wait_timeout(Duration::from_secs(5));
    std::thread::sleep(Duration::from_millis(500));
    rig.emulator = emulator(rig.emulator_port, "divot-push.toml");
    let t_up = monotonic_ns();
    let back = rig
        .collector
        .first_valid_after(t_up, Duration::from_secs(30))
        .expect("no valid sample after the emulator restarted");
    std::thread::sleep(Duration::from_millis(300));
    rig.assert_alive();
    let recs = rig.collector.records();
    let r = analyse(&recs[n0..]);
    print(
        "emulator-restart",
        &ProxyCounters::default(),
        &r,
        Some((back - t_up) as f64 / 1e6),
    );
    assert_trustworthy("emulator-restart", &r);
    assert!(
        Duration::from_nanos(back - t_up) < RECOVERY_BOUND,
        "recovery took {} ms",
        (back - t_up) / 1_000_000
    );
    rig.stop_serve();
}

/// Shared mode under 10% datagram loss (issue 22): a lost quadlet is asked again within the
/// cycle, so at least 90% of the samples stay valid, and a lost datagram costs a fraction of a
/// cycle, not a reply timeout. Counted over 5 s (thousands of cycles) so that the share is not
/// noise. The published rate is compared with the same service's rate without loss, measured
/// just before on the same (shared, noisy) machine: a liveness bound, not a speed claim.
#[test]
fn shared_mode_keeps_ninety_percent_valid_under_ten_percent_loss() {
    // The default configuration (issue 22 item 7): 4 requests in flight, a lost datagram asked
    // again within the cycle.
    let mut rig = Rig::start("shared-loss", Faults::default(), 7);
    rig.wait_first_valid();
    let window = |rig: &Rig, secs: u64| {
        let before_recs = rig.collector.records().len();
        let before = rig.proxy.counters();
        std::thread::sleep(Duration::from_secs(secs));
        let recs = rig.collector.records();
        let after = rig.proxy.counters();
        let injected = ProxyCounters {
            requests: after.requests - before.requests,
            replies: after.replies - before.replies,
            lost: after.lost - before.lost,
            ..Default::default()
        };
        (analyse(&recs[before_recs..]), injected)
    };
    let (clean, _) = window(&rig, 3);
    let clean_hz = clean.samples as f64 / 3.0;
    rig.proxy.set_faults(Faults {
        loss: 0.10,
        ..Default::default()
    });
    // Let the first lost datagrams pass, then count.
    std::thread::sleep(Duration::from_millis(500));
    let (r, injected) = window(&rig, 5);
    rig.proxy.set_faults(Faults::default());
    rig.assert_alive();
    print("shared-loss-10%", &injected, &r, None);
    let share = r.valid as f64 / r.samples.max(1) as f64;
    let rate_hz = r.samples as f64 / 5.0;
    let lost_share = injected.lost as f64 / (injected.requests + injected.replies).max(1) as f64;
    eprintln!(
        "FAULTS case=shared-loss-10% valid_share={share:.3} published_hz={rate_hz:.0} \
         without_loss_hz={clean_hz:.0} datagrams_lost={lost_share:.3}"
    );
    assert!(
        lost_share > 0.05,
        "the proxy lost only {lost_share:.3} of the datagrams"
    );
    assert_trustworthy("shared-loss-10%", &r);
    assert!(
        share >= 0.9,
        "shared mode under 10% loss: only {:.1}% of {} samples valid",
        share * 100.0,
        r.samples
    );
    // The rate under loss (`published_hz` against `without_loss_hz` above) depends on the
    // machine's load: it is a benchmark figure (issue 22 item 7, RELIABILITY.md), not asserted.
    let (st, err) = rig.stop_serve();
    if std::env::var_os("SHOW_SERVE_LOG").is_some() {
        eprintln!("{err}");
    }
    assert!(st.success(), "{err}");
}

/// Ten starts of `serve` with 10% of the datagrams lost from the first one: discovery waits
/// and retries, every start publishes valid samples.
#[test]
fn starts_under_loss_ten_of_ten() {
    let emulator_port = free_udp_port();
    let _emulator = emulator(emulator_port, "divot-push.toml");
    let upstream: SocketAddr = ([127, 0, 0, 1], emulator_port).into();
    let mut started = 0;
    let mut times_ms = Vec::new();
    for seed in 0..10u64 {
        let proxy = FaultProxy::start(
            upstream,
            Faults {
                loss: 0.10,
                ..Default::default()
            },
            100 + seed,
        );
        let test = format!("start-loss-{seed}");
        let prefix = unique_prefix(&test);
        let cfg = write_config(
            &test,
            &format!("udp:{}", proxy.addr),
            "shared",
            &prefix,
            "divot-push.toml",
        );
        let collector = Collector::start(&prefix);
        let t0 = monotonic_ns();
        let mut serve = serve(&cfg);
        let first = collector.first_valid_after(0, Duration::from_secs(30));
        let alive = serve.wait_timeout(Duration::from_millis(1)).is_none();
        assert!(
            alive,
            "start {seed}: serve exited under loss: {}",
            serve.stderr_text()
        );
        let first = first.unwrap_or_else(|| panic!("start {seed}: no valid sample in 30 s"));
        times_ms.push((first.saturating_sub(t0)) as f64 / 1e6);
        let (st, err) = serve.terminate();
        assert!(st.success(), "start {seed}: {err}");
        let (recs, _) = collector.stop();
        assert_trustworthy(&test, &analyse(&recs));
        started += 1;
    }
    eprintln!(
        "FAULTS case=start-under-10%-loss starts={started}/10 first_valid_ms={:?}",
        times_ms
            .iter()
            .map(|t| format!("{t:.0}"))
            .collect::<Vec<_>>()
    );
    assert_eq!(started, 10);
}

fn rss_kib(pid: i32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

/// Ten minutes under all faults, then idle: the service's memory stays flat and, idle, it
/// misses no cycle. `cargo test --release --test faults -- --ignored --nocapture soak`.
#[test]
#[ignore = "10-minute soak; run by hand, results in RELIABILITY.md"]
fn soak_ten_minutes() {
    let minutes: u64 = std::env::var("SOAK_MINUTES")
        .ok()
        .and_then(|m| m.parse().ok())
        .unwrap_or(10);
    let mut rig = Rig::start(
        "soak",
        Faults {
            loss: 0.02,
            bit_flip: 0.01,
            delay_chance: 0.01,
            delay: Duration::from_millis(5),
            duplicate: 0.02,
            strip_crc: false,
        },
        4,
    );
    rig.wait_first_valid();
    std::thread::sleep(Duration::from_secs(5));
    let rss0 = rss_kib(rig.serve.pid());
    let t_end = Instant::now() + Duration::from_secs(60 * minutes);
    let mut checked = 0;
    while Instant::now() < t_end {
        std::thread::sleep(Duration::from_secs(10));
        rig.assert_alive();
        // Analyse and drop what was collected so far, so the test's own memory stays flat.
        let recs = std::mem::take(&mut *rig.collector.js.lock().unwrap());
        rig.collector.status.lock().unwrap().clear();
        let r = analyse(&recs);
        assert_trustworthy("soak", &r);
        checked += r.samples;
    }
    let rss1 = rss_kib(rig.serve.pid());
    // Idle: no faults for 20 s, count the cycles published.
    rig.proxy.set_faults(Faults::default());
    std::thread::sleep(Duration::from_secs(2));
    rig.collector.js.lock().unwrap().clear();
    std::thread::sleep(Duration::from_secs(20));
    let idle = std::mem::take(&mut *rig.collector.js.lock().unwrap());
    let r = analyse(&idle);
    eprintln!(
        "FAULTS case=soak-{minutes}min samples_checked={checked} rss_kib_start={rss0} \
         rss_kib_end={rss1} idle_samples_20s={} idle_invalid={}",
        r.samples, r.invalid
    );
    assert_trustworthy("soak-idle", &r);
    assert_eq!(r.invalid, 0, "idle cycles failed");
    assert!(rss1 <= rss0 + 1024, "RSS grew from {rss0} to {rss1} KiB");
    rig.stop_serve();
}
