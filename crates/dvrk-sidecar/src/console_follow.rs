//! Following the dVRK console (issue 19): a thread of its own listens to the arm's
//! `operating_state`, `tool_type`, `measured_cp` and `local/measured_cp` over DDS
//! ([`dvrk_bridge::console::ConsoleWatcher`], read-only) and leaves the newest state in a
//! [`Shared`] seqlock; the cycle reads it at its start without locking, allocating or waiting
//! ([`Shared::read`]), so a silent or slow DDS never delays a cycle.
//!
//! What the cycle makes of it (serve.rs):
//! - instrument: a change of `tool_type` switches kinematics, coupling and parameters at the
//!   next cycle; removed (empty string): compensated samples invalid (`NO_INSTRUMENT`);
//!   `ERROR` or an instrument the catalog cannot model: raw only, compensated invalid
//!   (`INSTRUMENT_UNSUPPORTED`);
//! - operating state: not homed: every sample invalid (`NOT_HOMED`); DISABLED, PAUSED or
//!   FAULT: raw valid, the correction withheld (`ARM_NOT_ENABLED`); nothing heard from the
//!   console (yet, or for [`STALE_NS`]): as configured, flagged `CONSOLE_UNKNOWN`;
//! - base frame: `measured_cp × local/measured_cp⁻¹` of the same stamp (within
//!   [`PAIR_TOLERANCE_NS`]), followed as it changes; older than [`STALE_NS`]: the last one,
//!   flagged `BASE_FRAME_STALE`.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering, fence};
use std::time::Duration;

use dvrk_bridge::console::{ConsoleWatcher, Watched};
use dvrk_bridge::crtk::PoseStampedMsg;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// The console's state older than this (ns) counts as unknown (its poses come at 100 Hz, its
/// events only on change, so "heard" is refreshed by the poses).
pub const STALE_NS: u64 = 1_000_000_000;

/// Silent this long (ns) after it was heard, the console's DDS participant is made anew.
pub const RESTART_AFTER_NS: u64 = 2_000_000_000;

/// When to make the console's DDS participant anew: once silent for [`RESTART_AFTER_NS`]
/// after it was heard, then 5 s after that restart, 15 s, 45 s and every 60 s while the console
/// stays silent; hearing it starts the sequence again.
#[derive(Debug, Clone, Copy)]
struct RestartSchedule {
    wait: Duration,
    next: std::time::Instant,
}

impl RestartSchedule {
    const FIRST_WAIT: Duration = Duration::from_secs(5);
    const LONGEST_WAIT: Duration = Duration::from_secs(60);

    fn new(now: std::time::Instant) -> Self {
        Self {
            wait: Self::FIRST_WAIT,
            next: now,
        }
    }

    /// A restart is due: heard before, silent for `silent_ns`, and the wait since the last one
    /// is over.
    fn due(&self, was_heard: bool, silent_ns: u64, now: std::time::Instant) -> bool {
        was_heard && silent_ns > RESTART_AFTER_NS && now >= self.next
    }

    fn restarted(&mut self, now: std::time::Instant) {
        self.next = now + self.wait;
        self.wait = (self.wait * 3).min(Self::LONGEST_WAIT);
    }

    fn heard(&mut self) {
        self.wait = Self::FIRST_WAIT;
    }
}

/// The console's operating state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum OpState {
    #[default]
    Unknown = 0,
    Disabled = 1,
    Enabled = 2,
    Paused = 3,
    Fault = 4,
}

impl OpState {
    pub fn parse(s: &str) -> Self {
        match s {
            "DISABLED" => OpState::Disabled,
            "ENABLED" => OpState::Enabled,
            "PAUSED" => OpState::Paused,
            "FAULT" => OpState::Fault,
            _ => OpState::Unknown,
        }
    }

    fn from_u8(v: u8) -> Self {
        match v {
            1 => OpState::Disabled,
            2 => OpState::Enabled,
            3 => OpState::Paused,
            4 => OpState::Fault,
            _ => OpState::Unknown,
        }
    }
}

/// The mounted instrument as the console says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mounted {
    /// No `tool_type` heard yet.
    #[default]
    NotYet,
    /// The empty string: no instrument.
    Removed,
    /// `ERROR`, or a name the catalog cannot model.
    Unsupported,
    /// Index in [`dvrk_compliance::instruments()`].
    Catalog(u16),
}

impl Mounted {
    /// The code of `source_state` (0 not yet, 1 removed, 2 unsupported, 3 + catalog index).
    pub fn code(self) -> u64 {
        match self {
            Mounted::NotYet => 0,
            Mounted::Removed => 1,
            Mounted::Unsupported => 2,
            Mounted::Catalog(i) => 3 + u64::from(i),
        }
    }

    fn from_code(c: u64) -> Self {
        match c {
            0 => Mounted::NotYet,
            1 => Mounted::Removed,
            2 => Mounted::Unsupported,
            c => Mounted::Catalog((c - 3).min(u64::from(u16::MAX)) as u16),
        }
    }

    /// A catalog entry.
    pub fn of(i: &'static dvrk_compliance::Instrument) -> Self {
        dvrk_compliance::instruments()
            .iter()
            .position(|x| std::ptr::eq(x, i))
            .map_or(Mounted::Unsupported, |k| Mounted::Catalog(k as u16))
    }

    /// From the console's `tool_type`.
    pub fn from_tool_type(s: &str) -> Self {
        if s.is_empty() {
            return Mounted::Removed;
        }
        match dvrk_compliance::instrument_from_tool_type(s) {
            Ok(i) => dvrk_compliance::instruments()
                .iter()
                .position(|x| std::ptr::eq(x, i))
                .map_or(Mounted::Unsupported, |k| Mounted::Catalog(k as u16)),
            Err(_) => Mounted::Unsupported,
        }
    }

    /// The catalog entry.
    pub fn instrument(self) -> Option<&'static dvrk_compliance::Instrument> {
        match self {
            Mounted::Catalog(i) => dvrk_compliance::instruments().get(usize::from(i)),
            _ => None,
        }
    }
}

/// What the cycle reads: plain, `Copy`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct View {
    /// Monotonic ns of the last message from the console (0: never).
    pub heard_ns: u64,
    pub state: OpState,
    pub homed: bool,
    pub mounted: Mounted,
    /// Base frame (x, y, z, qx, qy, qz, qw) and the monotonic ns it was derived at (0: none).
    pub base: [f64; 7],
    pub base_ns: u64,
}

impl View {
    /// The base frame, if one was derived.
    pub fn base_frame(&self) -> Option<Isometry3<f64>> {
        (self.base_ns != 0).then(|| {
            let b = &self.base;
            Isometry3::from_parts(
                Translation3::new(b[0], b[1], b[2]),
                UnitQuaternion::from_quaternion(Quaternion::new(b[6], b[3], b[4], b[5])),
            )
        })
    }
}

const WORDS: usize = 11;

/// One writer (the console thread), any number of readers (the cycle): a sequence lock over
/// atomic words. A reader never waits: when the writer is mid-write it retries a few times,
/// then keeps the view it had.
#[derive(Debug, Default)]
pub struct Shared {
    seq: AtomicU64,
    words: [AtomicU64; WORDS],
}

impl Shared {
    /// Publishes a new view (the single writer).
    pub fn write(&self, v: &View) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        let w0 = u64::from(v.state as u8) | (u64::from(v.homed) << 8) | (v.mounted.code() << 16);
        self.words[0].store(w0, Ordering::Relaxed);
        self.words[1].store(v.heard_ns, Ordering::Relaxed);
        self.words[2].store(v.base_ns, Ordering::Relaxed);
        for (k, x) in v.base.iter().enumerate() {
            self.words[3 + k].store(x.to_bits(), Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// The newest consistent view, or `None` while the writer was busy on every try (the
    /// caller keeps the previous one). No lock, no allocation, at most 4 tries.
    pub fn read(&self) -> Option<View> {
        for _ in 0..4 {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let w: [u64; WORDS] = std::array::from_fn(|k| self.words[k].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) != s1 {
                continue;
            }
            let mut base = [0.0; 7];
            for (k, b) in base.iter_mut().enumerate() {
                *b = f64::from_bits(w[3 + k]);
            }
            return Some(View {
                state: OpState::from_u8((w[0] & 0xff) as u8),
                homed: (w[0] >> 8) & 1 == 1,
                mounted: Mounted::from_code(w[0] >> 16),
                heard_ns: w[1],
                base_ns: w[2],
                base,
            });
        }
        None
    }
}

/// A pose's stamp in ns (a negative second, which no console sends, counts as 0).
fn stamp_ns(p: &PoseStampedMsg) -> u64 {
    u64::try_from(p.stamp.sec).unwrap_or(0) * 1_000_000_000 + u64::from(p.stamp.nanosec)
}

/// How far apart (ns) the stamps of a `measured_cp` and a `local/measured_cp` may be to count as
/// one instant. The dVRK console stamps both with the time of the joint reading they come from,
/// so they are equal; a console that stamps each message as it writes it (a stand-in, a bridge)
/// puts microseconds between them. Half a period of a 1 kHz console: poses of two cycles never
/// pair, and the tip moves little in that time (50 µm at 0.1 m/s at most).
pub const PAIR_TOLERANCE_NS: u64 = 500_000;

/// `measured_cp × local/measured_cp⁻¹` for the newest `measured_cp` that has a
/// `local/measured_cp` within [`PAIR_TOLERANCE_NS`] of its stamp (the closest one).
pub fn base_from_pairs(cp: &[PoseStampedMsg], local: &[PoseStampedMsg]) -> Option<[f64; 7]> {
    let iso = |p: &PoseStampedMsg| {
        let q = p.orientation_xyzw;
        let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        (n.is_finite() && n > 0.5 && p.position.iter().all(|v| v.is_finite())).then(|| {
            Isometry3::from_parts(
                Translation3::new(p.position[0], p.position[1], p.position[2]),
                UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
            )
        })
    };
    for c in cp.iter().rev() {
        if c.stamp == Default::default() {
            continue; // a zero stamp is invalid data
        }
        let t = stamp_ns(c);
        let closest = local
            .iter()
            .rev()
            .filter(|l| l.stamp != Default::default())
            .map(|l| (stamp_ns(l).abs_diff(t), l))
            .filter(|(d, _)| *d <= PAIR_TOLERANCE_NS)
            .min_by_key(|(d, _)| *d);
        if let Some((_, l)) = closest
            && let (Some(ci), Some(li)) = (iso(c), iso(l))
        {
            let b = ci * li.inverse();
            let t = b.translation.vector;
            let q = b.rotation.coords;
            return Some([t.x, t.y, t.z, q.x, q.y, q.z, q.w]);
        }
    }
    None
}

/// Starts the thread that follows `arm` on DDS `domain`; it runs until `stop` is raised.
pub fn spawn(
    arm: &str,
    domain: u16,
    stop: crate::signals::StopFlag,
) -> anyhow::Result<Arc<Shared>> {
    let mut watcher = ConsoleWatcher::new(arm, domain, &[]).map_err(|e| {
        anyhow::anyhow!("following the console's {arm} on DDS domain {domain}: {e}")
    })?;
    let shared = Arc::new(Shared::default());
    let out = Arc::clone(&shared);
    let arm = arm.to_owned();
    std::thread::Builder::new()
        .name("console".into())
        .spawn(move || {
            let mut view = View::default();
            let mut w = Watched::default();
            let (mut cp, mut local) = (Vec::new(), Vec::new());
            let started = std::time::Instant::now();
            let mut next_wait_log = started + Duration::from_secs(2);
            let mut last_tool: Option<String> = None;
            let mut was_heard = false;
            let mut restarts = RestartSchedule::new(started);
            while !stop.raised() {
                w = Watched {
                    undecodable: w.undecodable,
                    ..Watched::default()
                };
                // keep a few unpaired poses from earlier polls
                let keep = |v: &mut Vec<PoseStampedMsg>| {
                    let n = v.len();
                    if n > 8 {
                        v.drain(..n - 8);
                    }
                };
                keep(&mut cp);
                keep(&mut local);
                watcher.poll(&mut w, &mut cp, &mut local);
                let now = dvrk_ipc::clock::monotonic_ns();
                let mut changed = false;
                if w.heard {
                    let silent_ns = now.saturating_sub(view.heard_ns);
                    if !was_heard {
                        tracing::info!("console: hearing {arm} on DDS domain {domain}");
                        was_heard = true;
                    } else if silent_ns > STALE_NS {
                        tracing::info!(
                            "console: hearing {arm} again after {:.1} s of silence",
                            silent_ns as f64 * 1e-9
                        );
                    }
                    view.heard_ns = now;
                    changed = true;
                }
                if let Some(s) = &w.operating_state {
                    let (st, homed) = (OpState::parse(&s.state), s.is_homed);
                    if (st, homed) != (view.state, view.homed) {
                        tracing::info!(
                            "console: {arm} is {} ({}homed)",
                            s.state,
                            if homed { "" } else { "not " }
                        );
                    }
                    view.state = st;
                    view.homed = homed;
                }
                if let Some(t) = &w.tool_type
                    && last_tool.as_deref() != Some(t.as_str())
                {
                    let m = Mounted::from_tool_type(t);
                    match m {
                        Mounted::Removed => {
                            tracing::warn!("console: {arm} has no instrument: compensated samples invalid (NO_INSTRUMENT)")
                        }
                        Mounted::Unsupported => tracing::warn!(
                            "console: {arm} instrument {t:?} cannot be modelled: raw only, compensated invalid (INSTRUMENT_UNSUPPORTED)"
                        ),
                        _ => tracing::info!(
                            "console: {arm} instrument {t}: kinematics, coupling and parameters switch at the next cycle"
                        ),
                    }
                    view.mounted = m;
                    last_tool = Some(t.clone());
                }
                if let Some(b) = base_from_pairs(&cp, &local) {
                    view.base = b;
                    view.base_ns = now;
                }
                if changed {
                    out.write(&view);
                }
                // Heard before, silent now: a new DDS participant. RustDDS's event loop ends
                // for good when its poll is interrupted (EINTR), which a stop and continue of
                // this process (Ctrl-Z then fg, SIGSTOP/SIGCONT) does; nothing else reports it.
                if restarts.due(
                    was_heard,
                    now.saturating_sub(view.heard_ns),
                    std::time::Instant::now(),
                ) {
                    let silent_s = now.saturating_sub(view.heard_ns) as f64 * 1e-9;
                    match ConsoleWatcher::new(&arm, domain, &[]) {
                        Ok(fresh) => {
                            watcher = fresh;
                            (cp, local) = (Vec::new(), Vec::new());
                            tracing::warn!(
                                "console: nothing heard from {arm} for {silent_s:.0} s; DDS participant restarted (samples flagged CONSOLE_UNKNOWN until it is heard again)"
                            );
                        }
                        Err(e) => tracing::warn!(
                            "console: nothing heard from {arm} for {silent_s:.0} s; restarting the DDS participant failed: {e}"
                        ),
                    }
                    restarts.restarted(std::time::Instant::now());
                }
                if w.heard {
                    restarts.heard();
                }
                if !was_heard && std::time::Instant::now() >= next_wait_log {
                    tracing::warn!(
                        "console: nothing heard from {arm} on DDS domain {domain} (ROS_DOMAIN_ID) \
                         for {:.0} s; waiting (samples flagged CONSOLE_UNKNOWN)",
                        started.elapsed().as_secs_f64()
                    );
                    next_wait_log = std::time::Instant::now() + Duration::from_secs(10);
                }
                // 0.5 ms: a change reaches the cycle within one period of arriving
                std::thread::sleep(Duration::from_micros(500));
            }
        })?;
    Ok(shared)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn restarts_come_after_2_s_of_silence_then_5_15_45_and_every_60_s() {
        let t0 = std::time::Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let mut r = RestartSchedule::new(t0);
        // never heard: never restarted; heard, silent 1 s: not yet
        assert!(!r.due(false, 10_000_000_000, at(10)));
        assert!(!r.due(true, 1_000_000_000, at(10)));
        // silent from t = 10 s (more than 2 s at 13 s): restarts at 13, 18, 33, 78, 138, 198 s
        let mut times = Vec::new();
        for s in 12..200u64 {
            if r.due(true, (s - 10) * 1_000_000_000, at(s)) {
                times.push(s);
                r.restarted(at(s));
            }
        }
        assert_eq!(times, [13, 18, 33, 78, 138, 198]);
        // heard again: the next silence starts the sequence over
        r.heard();
        assert!(r.due(true, 2_100_000_000, at(300)));
        r.restarted(at(300));
        assert!(!r.due(true, 6_000_000_000, at(304)));
        assert!(r.due(true, 7_000_000_000, at(305)));
    }

    #[test]
    fn a_view_round_trips_through_the_seqlock() {
        let s = Shared::default();
        assert_eq!(s.read(), Some(View::default()));
        let v = View {
            heard_ns: 42,
            state: OpState::Fault,
            homed: true,
            mounted: Mounted::Catalog(17),
            base: [0.1, 0.2, 0.3, 0.0, 0.0, 0.6, 0.8],
            base_ns: 40,
        };
        s.write(&v);
        assert_eq!(s.read(), Some(v));
        for m in [Mounted::NotYet, Mounted::Removed, Mounted::Unsupported] {
            s.write(&View { mounted: m, ..v });
            assert_eq!(s.read().unwrap().mounted, m);
        }
    }

    #[test]
    fn readers_see_whole_views_while_a_writer_writes() {
        let s = Arc::new(Shared::default());
        let w = Arc::clone(&s);
        let writer = std::thread::spawn(move || {
            for i in 1..200_000u64 {
                let x = i as f64;
                w.write(&View {
                    heard_ns: i,
                    base: [x; 7],
                    base_ns: i,
                    ..View::default()
                });
            }
        });
        let mut seen = 0;
        while !writer.is_finished() {
            if let Some(v) = s.read() {
                // every word of one view comes from the same write
                assert!(v.base.iter().all(|b| *b == v.heard_ns as f64), "{v:?}");
                assert_eq!(v.base_ns, v.heard_ns);
                seen += 1;
            }
        }
        writer.join().unwrap();
        assert!(seen > 0);
    }

    #[test]
    fn tool_types_map_to_the_catalog() {
        assert_eq!(Mounted::from_tool_type(""), Mounted::Removed);
        assert_eq!(Mounted::from_tool_type("ERROR"), Mounted::Unsupported);
        assert_eq!(
            Mounted::from_tool_type("NO_SUCH_TOOL:123456"),
            Mounted::Unsupported
        );
        let m = Mounted::from_tool_type("LARGE_NEEDLE_DRIVER:400006[..]");
        assert_eq!(m.instrument().unwrap().model, 400006);
        let c = Mounted::from_tool_type("CADIERE_FORCEPS:400049[..]");
        assert_eq!(c.instrument().unwrap().model, 400049);
    }

    #[test]
    fn the_base_frame_is_derived_from_poses_of_the_same_stamp() {
        use dvrk_bridge::cdr::RosTime;
        let base = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.4),
        );
        let local = Isometry3::from_parts(
            Translation3::new(0.01, 0.02, -0.12),
            UnitQuaternion::from_axis_angle(&nalgebra::Vector3::x_axis(), 0.3),
        );
        let msg = |p: &Isometry3<f64>, sec| PoseStampedMsg {
            stamp: RosTime { sec, nanosec: 0 },
            frame_id: String::new(),
            position: [p.translation.x, p.translation.y, p.translation.z],
            orientation_xyzw: [
                p.rotation.coords.x,
                p.rotation.coords.y,
                p.rotation.coords.z,
                p.rotation.coords.w,
            ],
        };
        // the newest cp has no local of its stamp yet: the older pair is used
        let cp = vec![msg(&(base * local), 5), msg(&(base * local), 6)];
        let lo = vec![msg(&local, 5)];
        let b = base_from_pairs(&cp, &lo).unwrap();
        let v = View {
            base: b,
            base_ns: 1,
            ..View::default()
        };
        let got = v.base_frame().unwrap();
        assert!((got.translation.vector - base.translation.vector).norm() < 1e-12);
        assert!(got.rotation.angle_to(&base.rotation) < 1e-12);
        assert!(base_from_pairs(&cp[1..], &lo).is_none());
    }

    #[test]
    fn poses_stamped_microseconds_apart_pair_and_those_of_two_cycles_do_not() {
        use dvrk_bridge::cdr::RosTime;
        let msg = |x: f64, nanosec| PoseStampedMsg {
            stamp: RosTime { sec: 7, nanosec },
            frame_id: String::new(),
            position: [x, 0.0, 0.0],
            orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        };
        // a console that stamps each message as it writes it: 40 µs apart, either order
        let cp = vec![msg(0.25, 1_000_040)];
        let b = base_from_pairs(&cp, &[msg(0.05, 1_000_000)]).unwrap();
        assert!((b[0] - 0.2).abs() < 1e-12, "{b:?}");
        let b = base_from_pairs(&cp, &[msg(0.05, 1_000_080)]).unwrap();
        assert!((b[0] - 0.2).abs() < 1e-12, "{b:?}");
        // the closest local wins
        let b = base_from_pairs(&cp, &[msg(0.05, 1_000_000), msg(0.04, 1_400_000)]).unwrap();
        assert!((b[0] - 0.2).abs() < 1e-12, "{b:?}");
        // two cycles of a 1 kHz console (1 ms apart) do not pair
        assert!(base_from_pairs(&cp, &[msg(0.05, 2_000_040)]).is_none());
        // a zero stamp is invalid data, on either side
        let zero = PoseStampedMsg {
            stamp: RosTime::default(),
            ..msg(0.05, 0)
        };
        assert!(base_from_pairs(&cp, std::slice::from_ref(&zero)).is_none());
    }
}
