//! `calibrate torque-offset|clamp|divot --robot ros2:PSM1`: the same procedure plans as on the
//! simulator, driving a real arm through the dVRK console's CRTK interface over DDS
//! ([`dvrk_bridge::console::ConsoleClient`]). The console's own safety (PID limits, watchdog,
//! joint limits, e-stop) stays in charge; this adds its own checks on top (ARCHITECTURE.md,
//! "Safety rule for moving a real arm"):
//!
//! - nothing is sent unless the arm is ENABLED and homed (`--enable` asks the console to enable
//!   and home it first; `--yes` never does);
//! - the plan is printed and confirmed before any motion (`--dry-run` prints it and exits);
//! - large moves go through `move_jp`, slowed with `trajectory_j/set_ratio`, and each must show
//!   a busy event and end with `goal_reached` true within its timeout; small steps go through
//!   `servo_jp`, at most the runner's ramp (0.2 rad/s, 0.02 m/s) per `measured_js` period;
//! - a `move_jp` or `--enable`'s `state_command` that the console shows no sign of (no busy
//!   event or warning within 0.5 s; no state event, warning or error within 3 s) is sent again,
//!   once, the same: DDS loses what a writer sends before the reader has matched it;
//! - `trajectory_j/set_ratio` goes out again before every `move_jp`, and where the console
//!   publishes `trajectory_j/ratio`, the move waits until it says it runs that ratio (nothing
//!   moves if it does not within 1.5 s);
//! - every `measured_js` is checked: |effort| of joints 1-2 above `--effort-limit-nm`, a joint
//!   outside the limits, the operating state leaving ENABLED (e-stop, FAULT), `measured_js`
//!   silent or invalid (zero stamp) for 0.3 s, a move not finished in time and Ctrl-C all abort
//!   within one poll (1 ms) of being seen: no motion command follows but `hold` (sent twice,
//!   50 ms apart), the rows collected are written atomically, and the command exits non-zero
//!   with the reason.

use std::io::BufRead;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use dvrk_bridge::console::{ConsoleClient, ConsoleEvent, Polled};
use dvrk_bridge::crtk::JointStateMsg;
use dvrk_compliance::calibration::{
    AUX, Fixture, Plan, Record, Runner, RunnerConfig, Sample, Status,
};

use crate::text::num;

/// Console joint limits of the Classic PSM (yaw, pitch, insertion), used as the runner's.
pub const CONSOLE_JOINT_LIMITS: [[f64; 2]; 3] = [[-1.588, 1.588], [-0.925, 0.925], [0.0, 0.24]];

/// A target farther than this from the last command (rad, rad, m) is a large move: `move_jp`.
pub const LARGE_MOVE: [f64; 3] = [0.03, 0.03, 0.003];

/// `measured_js` silent or invalid this long aborts.
pub const SILENCE_LIMIT: Duration = Duration::from_millis(300);

/// Settings of a console run.
#[derive(Debug, Clone)]
pub struct ConsoleOptions {
    pub arm: String,
    pub yes: bool,
    pub enable: bool,
    /// `trajectory_j/set_ratio` for the `move_jp`s.
    pub ratio: f64,
    /// With `--yes`, the pause after each operator prompt (s).
    pub prompt_pause_s: f64,
}

/// Why a console run stopped early.
#[derive(Debug, Clone, PartialEq)]
pub enum Stop {
    Runner(dvrk_compliance::calibration::AbortReason),
    EffortLimit {
        joint: usize,
        effort: f64,
        limit: f64,
    },
    StateLeft {
        state: String,
        error: Option<String>,
    },
    Silent {
        /// `console` or `sidecar`: whose measured_js.
        source: &'static str,
        for_ms: u128,
        invalid: bool,
    },
    MoveNotStarted {
        waited_s: f64,
        /// How many times the move was sent (a second time when neither busy nor a warning
        /// came).
        sends: usize,
        warning: Option<String>,
    },
    MoveTimeout {
        timeout_s: f64,
    },
    /// The console publishes its trajectory ratio and did not take the one asked for.
    RatioNotTaken {
        asked: f64,
        console: Option<f64>,
    },
    MoveInterrupted,
    Interrupted,
    /// `--measure sidecar`: the service's joint position differs from the console's, at rest.
    OtherArm {
        service: String,
        joint: usize,
        console: f64,
        sidecar: f64,
    },
}

impl std::fmt::Display for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Stop::Runner(r) => write!(f, "{r}"),
            Stop::EffortLimit {
                joint,
                effort,
                limit,
            } => write!(
                f,
                "joint {joint}: measured effort {effort:.3} N·m above --effort-limit-nm {limit}"
            ),
            Stop::StateLeft { state, error } => {
                write!(f, "the arm left ENABLED: operating state {state}")?;
                if let Some(e) = error {
                    write!(f, " (console error: {e})")?;
                }
                Ok(())
            }
            Stop::Silent {
                source,
                for_ms,
                invalid,
            } => write!(
                f,
                "{source} measured_js {} for {for_ms} ms (limit {} ms)",
                if *invalid {
                    "invalid (zero stamp)"
                } else {
                    "silent"
                },
                SILENCE_LIMIT.as_millis()
            ),
            Stop::MoveNotStarted {
                waited_s,
                sends,
                warning,
            } => {
                write!(
                    f,
                    "the console did not start a move_jp within {waited_s:.1} s (refused?)"
                )?;
                if *sends > 1 {
                    write!(f, ", sent {sends} times")?;
                }
                if let Some(w) = warning {
                    write!(f, "; its last warning: {w}")?;
                }
                Ok(())
            }
            Stop::RatioNotTaken { asked, console } => {
                write!(
                    f,
                    "the console did not take trajectory_j/set_ratio {asked} within {} s (its \
                     trajectory_j/ratio: {}): the move was not sent",
                    RATIO_LIMIT.as_secs_f64(),
                    console.map_or("none received".to_owned(), |r| r.to_string())
                )
            }
            Stop::MoveTimeout { timeout_s } => {
                write!(
                    f,
                    "a move_jp did not finish within its timeout of {timeout_s:.1} s"
                )
            }
            Stop::MoveInterrupted => write!(f, "a move_jp ended with goal_reached false"),
            Stop::Interrupted => write!(f, "stopped by Ctrl-C, Ctrl-Z or SIGTERM (signal)"),
            Stop::OtherArm {
                service,
                joint,
                console,
                sidecar,
            } => write!(
                f,
                "{service} reads joint {joint} at {sidecar:.4} where the console's measured_js \
                 reads {console:.4}: that service reads another arm (give this arm's with \
                 --sidecar-prefix)"
            ),
        }
    }
}

/// Result of a console run.
pub struct ConsoleRun {
    pub records: Vec<Record>,
    pub stop: Option<Stop>,
    pub samples: u64,
    pub moves: u32,
    pub servos: u64,
    pub elapsed_s: f64,
    pub tool_type: Option<String>,
}

/// Connects to the console's arm: waits for its operating state and `measured_js`, and for its
/// command readers to match ours. Fails with what is missing.
pub fn connect(arm: &str) -> anyhow::Result<ConsoleClient> {
    let domain = dvrk_bridge::console::ros_domain_id()?;
    let mut c = ConsoleClient::new(arm, domain, &[])
        .with_context(|| format!("DDS endpoints for {arm} on domain {domain}"))?;
    let mut polled = Polled::default();
    let end = Instant::now() + Duration::from_secs(10);
    let mut have_js = false;
    while Instant::now() < end {
        c.poll(&mut polled);
        have_js |= polled.measured_js.iter().any(|m| m.is_valid());
        polled.measured_js.clear();
        if have_js && c.last_operating_state.is_some() && c.commands_matched() {
            // the console's trajectory_j/ratio writer, where it has one, matched too, so the
            // first move already waits for the console's ratio (an older console has none)
            let grace = Instant::now() + RATIO_DISCOVERY_WAIT;
            while !c.ratio_published() && Instant::now() < grace {
                std::thread::sleep(Duration::from_millis(5));
                polled.measured_js.clear();
                polled.events.clear();
                c.poll(&mut polled);
            }
            return Ok(c);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let missing = [
        (c.last_operating_state.is_none(), "operating_state"),
        (!have_js, "valid measured_js"),
        (
            !c.commands_matched(),
            "readers of move_jp/servo_jp/hold/state_command",
        ),
    ]
    .iter()
    .filter(|(m, _)| *m)
    .map(|(_, w)| *w)
    .collect::<Vec<_>>()
    .join(", ");
    let incompatible = c.incompatible_writers();
    if !incompatible.is_empty() {
        bail!(
            "the console of {arm} on DDS domain {domain} answers, but with writers whose QoS \
             this client cannot match: {} (the dVRK console's events are RELIABLE and \
             TRANSIENT_LOCAL, so that a program started later learns the current state). No \
             {missing} within 10 s. Heard from a VOLATILE writer, the state arrives only when it \
             changes: change it in the console (e.g. disable, then enable and home) while this \
             command waits, or give the console's event writers TRANSIENT_LOCAL durability",
            incompatible.join(", ")
        );
    }
    bail!(
        "no dVRK console answers for {arm} on DDS domain {domain} (ROS_DOMAIN_ID) within 10 s: \
         no {missing}. Is `dvrk_system` running with this arm, on this domain, reachable from \
         this machine?"
    )
}

/// Checks (and with `enable`, brings) the arm to ENABLED and homed.
pub fn ensure_ready(c: &mut ConsoleClient, enable: bool) -> anyhow::Result<()> {
    let arm = c.arm().to_owned();
    let state = |c: &ConsoleClient| {
        c.last_operating_state
            .as_ref()
            .map(|s| (s.state.clone(), s.is_homed, s.is_busy))
            .unwrap_or_default()
    };
    let (s, homed, _) = state(c);
    if s == "ENABLED" && homed {
        return Ok(());
    }
    if !enable {
        bail!(
            "{arm} is {s}{}: nothing was sent. Enable and home it in the console (or pass \
             --enable to have this command ask the console to), then run again",
            if homed { "" } else { " and not homed" }
        );
    }
    let mut polled = Polled::default();
    // Sends `cmd` and waits up to `secs` for `ok`; sent again, once, if the console shows no
    // sign of it (no state event, no warning) within STATE_RESEND_AFTER.
    let mut command = |c: &mut ConsoleClient,
                       cmd: &str,
                       what: &str,
                       secs: u64,
                       ok: &dyn Fn(&str, bool, bool) -> bool| {
        let mut seq = c.last_seq();
        c.state_command(cmd)?;
        let start = Instant::now();
        let mut heard = false;
        let mut resent = false;
        while start.elapsed() < Duration::from_secs(secs) {
            polled.events.clear();
            c.poll(&mut polled);
            polled.measured_js.clear();
            heard |= polled.events.iter().any(|e| {
                e.seq > seq
                    && matches!(
                        e.value,
                        ConsoleEvent::OperatingState(_)
                            | ConsoleEvent::Warning(_)
                            | ConsoleEvent::Error(_)
                    )
            });
            let (s, h, b) = state(c);
            if ok(&s, h, b) {
                return Ok(());
            }
            if s == "FAULT" {
                bail!("{arm} went to FAULT while {what}");
            }
            if !heard && !resent && start.elapsed() > STATE_RESEND_AFTER {
                eprintln!(
                    "--enable: the console showed no sign of state_command {cmd:?} after {} s: \
                     sending it again, once",
                    STATE_RESEND_AFTER.as_secs()
                );
                seq = c.last_seq();
                c.state_command(cmd)?;
                resent = true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let (s, h, _) = state(c);
        bail!(
            "{arm} not {what} after {secs} s (state {s}, homed {h}{})",
            if heard {
                ""
            } else {
                "; the console showed no sign of the command, sent twice"
            }
        )
    };
    if s != "ENABLED" {
        eprintln!("--enable: asking the console to enable {arm}");
        command(c, "enable", "enabled", 30, &|s, _, _| s == "ENABLED")?;
    }
    if !state(c).1 {
        eprintln!("--enable: asking the console to home {arm}");
        command(c, "home", "homed", 120, &|s, h, b| {
            s == "ENABLED" && h && !b
        })?;
    }
    Ok(())
}

/// How long `--enable` waits for a sign of its `state_command` before sending it again, once.
const STATE_RESEND_AFTER: Duration = Duration::from_secs(3);

fn sample_of(m: &JointStateMsg, t_ns: u64) -> Sample {
    let ok = m.is_valid()
        && m.position.len() >= 3
        && m.effort.len() >= 3
        && m.position[..3]
            .iter()
            .chain(&m.effort[..3])
            .all(|v| v.is_finite());
    let mut s = Sample {
        t_ns,
        valid: ok,
        ..Sample::default()
    };
    if ok {
        s.position.copy_from_slice(&m.position[..3]);
        s.effort.copy_from_slice(&m.effort[..3]);
        let mut aux = [0.0; AUX];
        for (k, v) in m.position.iter().skip(3).take(3).enumerate() {
            aux[k] = *v;
        }
        s.aux = aux;
    }
    s
}

/// What the operator must do, word for word.
pub fn fixture_prompt(f: &Fixture) -> String {
    match f {
        Fixture::Free => "Release the clamp: nothing may touch the instrument shaft or tip.".into(),
        Fixture::Clamp {
            joint, insertion_m, ..
        } => format!(
            "Clamp the instrument shaft to the beam at the tip, where it is now (insertion \
             {insertion_m:.3} m); joint {joint} will then be pushed against it."
        ),
        Fixture::Divot => {
            "Place the instrument tip in the divot (it stays there while each joint pushes).".into()
        }
    }
}

struct MoveWait {
    cmd_seq: u64,
    /// The goal sent, all six joints: sent again if the console shows no sign of it.
    q6: [f64; 6],
    /// `trajectory_j/set_ratio`, sent again before each send of the move.
    ratio: f64,
    /// Waiting for the console to say it runs `ratio` before the move is sent: since when, and
    /// whether the ratio was sent again (`None` once the move is sent).
    ratio_wait: Option<(Instant, bool)>,
    /// When the move was first sent, and when last sent.
    first_sent: Instant,
    sent: Instant,
    resent: bool,
    saw_busy: bool,
    /// A console warning after the command: it was read and refused, never sent again.
    warned: bool,
    ended: bool,
    goal: Option<bool>,
    timeout_s: f64,
}

/// What a running `move_jp` needs next.
#[derive(Debug, Clone, Copy, PartialEq)]
enum MoveStatus {
    Running,
    Done,
    /// No busy event and no warning [`MOVE_RESEND_AFTER`] after the command: send it again,
    /// once (a command written before the console's reader has matched this writer can be lost).
    Resend,
    /// The console now runs the ratio: send the move.
    SendMove,
    /// The console has not said it runs the ratio [`MOVE_RESEND_AFTER`] after it was sent: send
    /// the ratio again, once.
    ResendRatio,
}

/// How long [`connect`] waits, once everything else is there, for the console's
/// `trajectory_j/ratio` writer to match (a console that publishes no ratio costs this once).
const RATIO_DISCOVERY_WAIT: Duration = Duration::from_secs(1);

/// How long a move waits for the console's `trajectory_j/ratio` to say it runs the ratio asked
/// for (where the console publishes it) before the run stops with nothing moved.
const RATIO_LIMIT: Duration = Duration::from_millis(1500);

/// How long a `move_jp` may go without a busy event before it is sent again, once.
const MOVE_RESEND_AFTER: Duration = Duration::from_millis(500);
/// How long a `move_jp` (each send of it) may go without a busy event before the run stops.
const MOVE_START_LIMIT: Duration = Duration::from_secs(1);

/// Planned duration of a `move_jp` of `d` (rad, rad, m) at `ratio`, with the PSM's limits.
pub fn move_duration_s(d: &[f64; 3], ratio: f64) -> f64 {
    let vmax = [
        std::f64::consts::FRAC_PI_2,
        std::f64::consts::FRAC_PI_2,
        0.2,
    ];
    (0..3)
        .map(|j| {
            let (v, a) = (vmax[j] * ratio, vmax[j] * ratio);
            let d = d[j].abs();
            if d < v * v / a {
                2.0 * (d / a).sqrt()
            } else {
                d / v + v / a
            }
        })
        .fold(0.0, f64::max)
}

/// The checks made on everything the console sends, shared by the procedures and the
/// excitation: events (state, errors, the current move's busy and goal_reached), every
/// `measured_js` (validity, effort limit) and silence.
struct Watch {
    effort_limit_nm: f64,
    heard: Heard,
    last_error: Option<String>,
    last_t_ns: u64,
    tool_type: Option<String>,
}

impl Watch {
    fn new(effort_limit_nm: f64, tool_type: Option<String>) -> Self {
        Self {
            effort_limit_nm,
            heard: Heard::new(Instant::now()),
            last_error: None,
            last_t_ns: 0,
            tool_type,
        }
    }

    /// Applies the events of one poll; a state other than ENABLED stops the run.
    fn events(&mut self, polled: &Polled, mut moving: Option<&mut MoveWait>) -> Result<(), Stop> {
        for ev in &polled.events {
            match &ev.value {
                ConsoleEvent::OperatingState(s) => {
                    if s.state != "ENABLED" {
                        return Err(Stop::StateLeft {
                            state: s.state.clone(),
                            error: self.last_error.clone(),
                        });
                    }
                    if let Some(m) = moving.as_deref_mut()
                        && ev.seq > m.cmd_seq
                    {
                        if s.is_busy {
                            m.saw_busy = true;
                        } else if m.saw_busy {
                            m.ended = true;
                        }
                    }
                }
                ConsoleEvent::GoalReached(v) => {
                    if let Some(m) = moving.as_deref_mut()
                        && ev.seq > m.cmd_seq
                    {
                        m.goal = Some(*v);
                    }
                }
                ConsoleEvent::Error(e) => {
                    tracing::warn!("console error: {e}");
                    self.last_error = Some(e.clone());
                }
                ConsoleEvent::Warning(w) => {
                    tracing::warn!("console warning: {w}");
                    if let Some(m) = moving.as_deref_mut()
                        && ev.seq > m.cmd_seq
                    {
                        m.warned = true;
                    }
                }
                ConsoleEvent::Ratio(_) => {}
                ConsoleEvent::ToolType(t) => {
                    if self.tool_type.as_deref().is_some_and(|old| old != t) {
                        tracing::warn!("instrument changed during the run: {t:?}");
                    }
                    self.tool_type = Some(t.clone());
                }
            }
        }
        Ok(())
    }

    /// One `measured_js`: `Ok(None)` for an invalid one (zero stamp, short, not finite).
    fn sample(&mut self, m: &JointStateMsg, now: Instant) -> Result<Option<Sample>, Stop> {
        let stamp_ns =
            u64::try_from(i64::from(m.stamp.sec) * 1_000_000_000 + i64::from(m.stamp.nanosec))
                .unwrap_or(0);
        let t_ns = stamp_ns.max(self.last_t_ns);
        let s = sample_of(m, t_ns);
        self.heard.sample(s.valid, now);
        if !s.valid {
            return Ok(None);
        }
        self.last_t_ns = t_ns;
        effort_within(&s, self.effort_limit_nm)?;
        Ok(Some(s))
    }

    /// No valid `measured_js` for [`SILENCE_LIMIT`] stops the run.
    fn silence(&self, now: Instant) -> Result<(), Stop> {
        self.heard.silence("console", now)
    }
}

/// What a source of `measured_js` (the console, a sidecar service) was last heard to send.
#[derive(Clone, Copy, Debug)]
struct Heard {
    /// When the last valid sample arrived.
    last_valid: Instant,
    /// When the last sample (valid or not) arrived.
    last_any: Instant,
    /// An invalid sample arrived since the last valid one.
    saw_invalid: bool,
}

impl Heard {
    /// Nothing heard yet: the silence is counted from `now`.
    fn new(now: Instant) -> Self {
        Self {
            last_valid: now,
            last_any: now,
            saw_invalid: false,
        }
    }

    /// A sample, valid or not, arrived at `now`.
    fn sample(&mut self, valid: bool, now: Instant) {
        self.last_any = now;
        if valid {
            self.last_valid = now;
        }
        self.saw_invalid = !valid;
    }

    /// The stop of `source` once its last valid sample is more than [`SILENCE_LIMIT`] ago:
    /// "invalid" while invalid ones still arrive, "silent" once nothing does (a console or a
    /// service that stopped or died).
    fn silence(&self, source: &'static str, now: Instant) -> Result<(), Stop> {
        let since_valid = now.duration_since(self.last_valid);
        if since_valid > SILENCE_LIMIT {
            return Err(Stop::Silent {
                source,
                for_ms: since_valid.as_millis(),
                invalid: self.saw_invalid && now.duration_since(self.last_any) <= SILENCE_LIMIT,
            });
        }
        Ok(())
    }
}

/// |effort| of joint 1 or 2 of `s` above `limit_nm` stops the run.
fn effort_within(s: &Sample, limit_nm: f64) -> Result<(), Stop> {
    match (0..2).find(|&j| s.effort[j].abs() > limit_nm) {
        None => Ok(()),
        Some(j) => Err(Stop::EffortLimit {
            joint: j + 1,
            effort: s.effort[j],
            limit: limit_nm,
        }),
    }
}

impl MoveWait {
    /// A `move_jp` to `q6` (the first three joints `d` away from where the arm is), with
    /// `trajectory_j/set_ratio` sent again first: a ratio lost on its way would leave the move
    /// at the console's own speed. Where the console publishes `trajectory_j/ratio`, the move is
    /// sent only once it says it runs `ratio` ([`MoveStatus::SendMove`]); elsewhere at once.
    fn start(
        client: &mut ConsoleClient,
        now: Instant,
        d: &[f64; 3],
        ratio: f64,
        q6: [f64; 6],
    ) -> Result<Self, dvrk_bridge::BridgeError> {
        let mut m = MoveWait {
            cmd_seq: client.last_seq(),
            q6,
            ratio,
            ratio_wait: None,
            first_sent: now,
            sent: now,
            resent: false,
            saw_busy: false,
            warned: false,
            ended: false,
            goal: None,
            timeout_s: 2.0 * move_duration_s(d, ratio) + 3.0,
        };
        m.send_ratio(client)?;
        if client.ratio_published() && !ratio_taken(client, ratio) {
            m.ratio_wait = Some((now, false));
        } else {
            m.send_move(client, now)?;
        }
        Ok(m)
    }

    /// What [`check`](Self::check) asked for: the move, or the ratio or the move again.
    fn act(
        &mut self,
        status: MoveStatus,
        client: &mut ConsoleClient,
        now: Instant,
    ) -> Result<(), dvrk_bridge::BridgeError> {
        match status {
            MoveStatus::SendMove => {
                self.ratio_wait = None;
                self.send_move(client, now)
            }
            MoveStatus::ResendRatio => {
                if let Some((_, resent)) = &mut self.ratio_wait {
                    *resent = true;
                }
                eprintln!(
                    "the console does not yet say it runs trajectory_j ratio {}: sending \
                     set_ratio again, once",
                    self.ratio
                );
                client.set_ratio(self.ratio)
            }
            MoveStatus::Resend => {
                tracing::warn!(
                    "the console showed no sign of a move_jp after {:.1} s: sending it again",
                    now.duration_since(self.sent).as_secs_f64()
                );
                eprintln!("the console did not start the move_jp: sending it again, once");
                self.resent = true;
                self.send_ratio(client)?;
                self.send_move(client, now)
            }
            MoveStatus::Running | MoveStatus::Done => Ok(()),
        }
    }

    /// `trajectory_j/set_ratio`, where the console reads it (the procedure's start said so once
    /// where it does not).
    fn send_ratio(&self, client: &mut ConsoleClient) -> Result<(), dvrk_bridge::BridgeError> {
        if client.ratio_matched() {
            client.set_ratio(self.ratio)?;
        }
        Ok(())
    }

    /// Sends the goal (an identical `move_jp` only restarts the console's trajectory to the
    /// same place); busy events count from here.
    fn send_move(
        &mut self,
        client: &mut ConsoleClient,
        now: Instant,
    ) -> Result<(), dvrk_bridge::BridgeError> {
        self.cmd_seq = client.last_seq();
        if !self.resent {
            self.first_sent = now;
        }
        self.sent = now;
        client.move_jp(&self.q6)
    }

    fn check(&self, client: &ConsoleClient, now: Instant) -> Result<MoveStatus, Stop> {
        if let Some((asked, resent)) = self.ratio_wait {
            if ratio_taken(client, self.ratio) {
                return Ok(MoveStatus::SendMove);
            }
            let waited = now.duration_since(asked);
            if !resent && waited > MOVE_RESEND_AFTER {
                return Ok(MoveStatus::ResendRatio);
            }
            if waited > RATIO_LIMIT {
                return Err(Stop::RatioNotTaken {
                    asked: self.ratio,
                    console: client.last_ratio,
                });
            }
            return Ok(MoveStatus::Running);
        }
        let since = now.duration_since(self.sent);
        if self.goal == Some(false) {
            return Err(Stop::MoveInterrupted);
        }
        if self.ended && self.goal == Some(true) {
            return Ok(MoveStatus::Done);
        }
        if !self.saw_busy {
            if !self.warned && !self.resent && since > MOVE_RESEND_AFTER {
                return Ok(MoveStatus::Resend);
            }
            if since > MOVE_START_LIMIT {
                return Err(Stop::MoveNotStarted {
                    waited_s: now.duration_since(self.first_sent).as_secs_f64(),
                    sends: 1 + usize::from(self.resent),
                    warning: client.recent_warnings.back().cloned(),
                });
            }
        }
        if since.as_secs_f64() > self.timeout_s {
            return Err(Stop::MoveTimeout {
                timeout_s: self.timeout_s,
            });
        }
        Ok(MoveStatus::Running)
    }
}

/// The console's last `trajectory_j/ratio` is `ratio`.
fn ratio_taken(client: &ConsoleClient, ratio: f64) -> bool {
    client.last_ratio.is_some_and(|r| (r - ratio).abs() <= 1e-9)
}

/// After an abort: `hold` where the arm is (twice, see below), unless the arm already left
/// ENABLED (a hold would be refused); nothing else follows.
///
/// If this process's DDS has stopped (RustDDS ends its event loop when a stop and continue,
/// SIGSTOP then SIGCONT, interrupts its poll), the hold goes through a new participant, once the
/// console's command readers match it (up to [`HOLD_MATCH_WAIT`]).
fn hold_after(client: &mut ConsoleClient, reason: Option<&Stop>) {
    let Some(r) = reason else { return };
    if matches!(r, Stop::StateLeft { .. }) {
        return;
    }
    if client.dds_alive() {
        if !hold_acknowledged(client) {
            eprintln!(
                "the hold was sent but the console did not acknowledge it within {} s: it may keep \
                 the last command; hold the arm from the console",
                HOLD_ACK_WAIT.as_secs()
            );
        }
        return;
    }
    eprintln!(
        "this process's DDS has stopped (RustDDS's event loop ended: was the process stopped and \
         continued?); joining DDS domain {} anew to send the hold",
        client.domain()
    );
    let fresh = ConsoleClient::new(client.arm(), client.domain(), &[]);
    let sent = fresh.is_ok_and(|mut c| {
        let matched =
            dvrk_bridge::console::wait_until(HOLD_MATCH_WAIT, Duration::from_millis(5), || {
                c.commands_matched()
            });
        matched && hold_acknowledged(&mut c)
    });
    if sent {
        eprintln!("hold sent and acknowledged by the console");
    } else {
        eprintln!(
            "the hold could not be sent: the console keeps the last command; hold the arm from the \
             console"
        );
    }
}

/// `hold`, [`HOLD_REPEATS`] times [`HOLD_REPEAT_GAP`] apart, each acknowledged (the process exits
/// next): whether every one was. Sent more than once because in the first seconds after
/// connecting, the wait for the acknowledgement of the first hold (RustDDS) returned at once and
/// the console stand-in never saw that hold: half of the holds of runs stopped 2 s into the
/// excitation were lost, none 6 s in. A second hold 50 ms later arrived every time; holding
/// twice where the arm is changes nothing on a console.
fn hold_acknowledged(client: &mut ConsoleClient) -> bool {
    let mut acked = true;
    for i in 0..HOLD_REPEATS {
        if i > 0 {
            std::thread::sleep(HOLD_REPEAT_GAP);
        }
        acked &= client.hold_acknowledged(HOLD_ACK_WAIT).unwrap_or(false);
    }
    acked
}

/// How long a new participant may take to meet the console's command readers for the hold.
const HOLD_MATCH_WAIT: Duration = Duration::from_secs(5);
/// How long the console's readers may take to acknowledge the hold.
const HOLD_ACK_WAIT: Duration = Duration::from_secs(1);
/// How many holds an abort sends, and how far apart (see [`hold_after`]).
const HOLD_REPEATS: usize = 2;
const HOLD_REPEAT_GAP: Duration = Duration::from_millis(50);

fn set_ratio(client: &mut ConsoleClient, ratio: f64) -> anyhow::Result<()> {
    if client.ratio_matched() {
        client.set_ratio(ratio)?;
    } else {
        tracing::warn!(
            "the console has no reader of trajectory_j/set_ratio: move_jp runs at its own speed"
        );
    }
    Ok(())
}

/// Prints the operator's prompt; returns when to go on (`--yes`) or the channel of the Enter.
fn ask_operator(
    f: &Fixture,
    opts: &ConsoleOptions,
    now: Instant,
) -> (Option<Instant>, Option<mpsc::Receiver<()>>) {
    eprintln!("\n>>> {}", fixture_prompt(f));
    if opts.yes {
        eprintln!("    (--yes: continuing in {:.1} s)", opts.prompt_pause_s);
        (
            Some(now + Duration::from_secs_f64(opts.prompt_pause_s)),
            None,
        )
    } else {
        eprintln!("    Press Enter when done (Ctrl-C aborts).");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            if std::io::stdin().lock().read_line(&mut line).is_ok() {
                let _ = tx.send(());
            }
        });
        (None, Some(rx))
    }
}

/// The 1.5 kHz samples of a sidecar service that reads the same arm (`--measure sidecar`).
pub struct SidecarSource {
    sub: dvrk_ipc::Subscription<dvrk_ipc::JointStateV2, dvrk_ipc::iceoryx2::service::ipc::Service>,
    _node: dvrk_ipc::iceoryx2::node::Node<dvrk_ipc::iceoryx2::service::ipc::Service>,
    service: String,
    heard: Heard,
    /// The service was found to read the console's arm ([`same_arm`]).
    checked: bool,
}

impl SidecarSource {
    /// Subscribes to `<prefix>/measured_js` of a running service; fails when none publishes.
    pub fn open(prefix: &str) -> anyhow::Result<Self> {
        let (sub, names, node) = super::calibrate::subscribe_measured_js(prefix)?;
        let service = names.topic(dvrk_ipc::Topic::MeasuredJs).as_str().to_owned();
        let ok = dvrk_bridge::console::wait_until(
            Duration::from_secs(5),
            Duration::from_millis(10),
            || sub.number_of_publishers() > 0,
        );
        if !ok {
            bail!(
                "--measure sidecar: no sidecar service publishes {service}; start `dvrk-sidecar \
                 serve` for this arm (or give its prefix with --sidecar-prefix), or use \
                 --measure console"
            );
        }
        Ok(Self {
            sub,
            _node: node,
            service,
            heard: Heard::new(Instant::now()),
            checked: false,
        })
    }

    /// Whether a valid sample arrives within `timeout` (those received meanwhile are dropped).
    fn publishes_within(&mut self, timeout: Duration) -> anyhow::Result<bool> {
        let start = Instant::now();
        let mut scratch = Vec::new();
        while start.elapsed() < timeout {
            scratch.clear();
            self.drain(&mut scratch, Instant::now())?;
            if scratch.iter().any(|s| s.valid) {
                return Ok(true);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(false)
    }

    /// No valid sample for [`SILENCE_LIMIT`] stops the run.
    fn silence(&self, now: Instant) -> Result<(), Stop> {
        self.heard.silence("sidecar", now)
    }

    /// Every sample waiting, oldest first (invalid ones as `valid = false`).
    fn drain(&mut self, out: &mut Vec<Sample>, now: Instant) -> anyhow::Result<()> {
        while let Some(sample) = self
            .sub
            .subscriber()
            .receive()
            .map_err(|e| anyhow::anyhow!("receiving from {}: {e:?}", self.service))?
        {
            let m = *sample;
            drop(sample);
            let valid = m.header.valid != 0
                && m.position[..3]
                    .iter()
                    .chain(&m.effort[..3])
                    .all(|v| v.is_finite());
            self.heard.sample(valid, now);
            out.push(Sample {
                t_ns: m.header.sample_t_ns,
                valid,
                position: [m.position[0], m.position[1], m.position[2]],
                effort: [m.effort[0], m.effort[1], m.effort[2]],
                aux: [0.0; AUX],
            });
        }
        Ok(())
    }
}

/// How far the sidecar's joint positions may be from the console's (rad, rad, m) for the two
/// to read one arm: the same encoders, at most a console period apart.
const SAME_ARM_TOLERANCE: [f64; 3] = [0.02, 0.02, 0.005];

/// Checks that the sidecar service's sample and the console's read the same arm.
fn same_arm(service: &str, console: &[f64; 3], sidecar: &[f64; 3]) -> Result<(), Stop> {
    match (0..3).find(|&j| (console[j] - sidecar[j]).abs() > SAME_ARM_TOLERANCE[j]) {
        None => Ok(()),
        Some(j) => Err(Stop::OtherArm {
            service: service.to_owned(),
            joint: j + 1,
            console: console[j],
            sidecar: sidecar[j],
        }),
    }
}

/// Runs `plan` on the console's arm until done, aborted, or stopped. Rows come from the
/// console's `measured_js`, or from `sidecar` when given; commands are decided at each
/// console `measured_js` (the console's rate) either way.
pub fn run_console<P: Plan>(
    plan: P,
    rc: RunnerConfig,
    client: &mut ConsoleClient,
    opts: &ConsoleOptions,
    mut sidecar: Option<&mut SidecarSource>,
    stop: &AtomicBool,
    mut on_progress: impl FnMut(&Runner<P>),
) -> anyhow::Result<ConsoleRun> {
    let start = Instant::now();
    let mut runner = Runner::new(plan, rc);
    let mut run = ConsoleRun {
        records: Vec::new(),
        stop: None,
        samples: 0,
        moves: 0,
        servos: 0,
        elapsed_s: 0.0,
        tool_type: client.last_tool_type.clone(),
    };
    set_ratio(client, opts.ratio)?;
    let mut polled = Polled::default();
    let mut watch = Watch::new(rc.effort_limit_nm, client.last_tool_type.clone());
    let mut last_cmd: Option<[f64; 3]> = None;
    let mut last_position: Option<[f64; 3]> = None;
    let mut setpoint: Option<[f64; 3]> = None;
    let mut wrist: Option<[f64; 3]> = None;
    let mut moving: Option<MoveWait> = None;
    // operator prompt: Some(deadline) with --yes, or a channel to stdin
    let mut prompt: Option<(Option<Instant>, Option<mpsc::Receiver<()>>)> = None;
    let mut polls = 0u64;
    let mut side: Vec<Sample> = Vec::new();
    let reason = 'run: loop {
        if stop.load(Ordering::Relaxed) {
            break 'run Some(Stop::Interrupted);
        }
        polled.measured_js.clear();
        polled.events.clear();
        client.poll(&mut polled);
        let now = Instant::now();
        if let Err(r) = watch.events(&polled, moving.as_mut()) {
            break 'run Some(r);
        }
        // the samples the runner averages: the console's, or the sidecar's
        side.clear();
        let mut tick = false;
        for m in &polled.measured_js {
            run.samples += 1;
            let s = match watch.sample(m, now) {
                Err(r) => break 'run Some(r),
                Ok(None) => continue,
                Ok(Some(s)) => s,
            };
            tick = true;
            last_position = Some(s.position);
            if wrist.is_none() {
                wrist = Some([s.aux[0], s.aux[1], s.aux[2]]);
            }
            if sidecar.is_none() {
                side.push(s);
            }
        }
        if let Some(src) = sidecar.as_deref_mut() {
            src.drain(&mut side, now)?;
            if !src.checked
                && let (Some(pos), Some(first)) = (last_position, side.iter().find(|s| s.valid))
            {
                if let Err(r) = same_arm(&src.service, &pos, &first.position) {
                    break 'run Some(r);
                }
                src.checked = true;
            }
            if !src.checked {
                side.clear(); // nothing from the service until it is known to read this arm
            }
            if let Err(r) = src.silence(now) {
                break 'run Some(r);
            }
        }
        for s in &side {
            if !s.valid {
                continue;
            }
            if let Err(r) = effort_within(s, rc.effort_limit_nm) {
                break 'run Some(r);
            }
            if moving.is_some() || prompt.is_some() {
                continue; // the console moves (or the operator acts); the runner waits
            }
            let out = runner.update(s);
            run.records.extend(out.record);
            setpoint = Some(out.setpoint);
            match out.status {
                Status::Done => break 'run None,
                Status::Aborted(r) => break 'run Some(Stop::Runner(r)),
                Status::AwaitFixture(f) => {
                    prompt = Some(ask_operator(&f, opts, now));
                    break;
                }
                Status::Running => {}
            }
        }
        // commands, at the console's rate
        if tick
            && moving.is_none()
            && prompt.is_none()
            && let (Some(w), Some(sp), Some(pos)) = (wrist, setpoint, last_position)
        {
            let full = |q: &[f64; 3]| [q[0], q[1], q[2], w[0], w[1], w[2]];
            let base = last_cmd.unwrap_or(pos);
            let target = runner.target();
            let d: [f64; 3] = std::array::from_fn(|j| target[j] - base[j]);
            if runner.ramping() && (0..3).any(|j| d[j].abs() > LARGE_MOVE[j]) {
                moving = Some(MoveWait::start(client, now, &d, opts.ratio, full(&target))?);
                run.moves += 1;
                last_cmd = Some(target);
            } else if last_cmd != Some(sp) {
                client.servo_jp(&full(&sp))?;
                run.servos += 1;
                last_cmd = Some(sp);
            }
        }
        if let Err(r) = watch.silence(now) {
            break 'run Some(r);
        }
        if let Some(m) = &mut moving {
            match m.check(client, now) {
                Err(r) => break 'run Some(r),
                Ok(MoveStatus::Done) => {
                    runner.target_reached_by_robot();
                    setpoint = Some(runner.target());
                    moving = None;
                }
                Ok(other) => m.act(other, client, now)?,
            }
        }
        if let Some((deadline, rx)) = &prompt {
            let done = match (deadline, rx) {
                (Some(d), _) => now >= *d,
                (None, Some(rx)) => rx.try_recv().is_ok(),
                (None, None) => true,
            };
            if done {
                prompt = None;
                runner.fixture_ready();
            }
        }
        polls += 1;
        if polls.is_multiple_of(100) {
            on_progress(&runner);
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    run.tool_type = watch.tool_type.clone();
    hold_after(client, reason.as_ref());
    run.stop = reason;
    run.elapsed_s = start.elapsed().as_secs_f64();
    Ok(run)
}

/// `calibrate <procedure> --robot ros2:ARM`: the shell around [`run_console`].
pub fn run_procedure(
    kind: super::calibrate::SimKind,
    a: &super::calibrate::SimArgs,
    arm: &str,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    use super::calibrate::SimKind;
    let name = match kind {
        SimKind::Sweep => "torque-offset",
        SimKind::Clamp => "clamp",
        SimKind::Divot => "divot",
    };
    let (plan, text) = super::calibrate::plan_for(kind, a);
    let settle_s = a.settle_s.unwrap_or(0.3);
    // rows average 0.2 s of samples: 20 of the console's 100 Hz, 300 of the sidecar's 1.5 kHz
    let samples_per_step = if a.measure == "sidecar" { 300 } else { 20 };
    let rc = RunnerConfig {
        samples_per_step,
        effort_limit_nm: a.effort_limit_nm,
        joint_limits: CONSOLE_JOINT_LIMITS,
        settle_s,
        // a real controller creeps: the effort must have settled too
        still_effort_nm: 0.02,
        step_timeout_s: 10.0,
        ..RunnerConfig::default()
    };
    let domain = dvrk_bridge::console::ros_domain_id()?;
    eprintln!("calibrate {name} on {arm} through the dVRK console (DDS domain {domain})");
    eprintln!("plan: {text}");
    eprintln!(
        "safety: effort limit {} N·m on joints 1-2; joint limits {:?}; move_jp at set_ratio {} \
         for moves above {:?} (rad, rad, m), servo_jp steps at most {:?} per second; rows \
         averaged over {} measured_js once still for {settle_s} s (position and effort); \
         aborts on an effort above the limit, the arm leaving ENABLED, measured_js silent for \
         {} ms, a move not finished in time, Ctrl-C",
        a.effort_limit_nm,
        CONSOLE_JOINT_LIMITS,
        a.ratio,
        LARGE_MOVE,
        rc.max_speed,
        rc.samples_per_step,
        SILENCE_LIMIT.as_millis()
    );
    eprintln!("output: {}", a.out.display());
    if a.dry_run {
        eprintln!("--dry-run: nothing was sent");
        return Ok(());
    }
    // the sidecar's samples, if asked for: opened before anything moves
    let mut sidecar = match a.measure.as_str() {
        "sidecar" => Some(SidecarSource::open(
            a.sidecar_prefix.as_deref().unwrap_or(arm),
        )?),
        _ => None,
    };
    let mut client = prepare(arm, a.enable, a.yes)?;
    let opts = ConsoleOptions {
        arm: arm.to_owned(),
        yes: a.yes,
        enable: a.enable,
        ratio: a.ratio,
        prompt_pause_s: a.prompt_pause_s,
    };
    let bar = if a.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(1)
    };
    let run = run_console(plan, rc, &mut client, &opts, sidecar.as_mut(), stop, |r| {
        let p = r.progress();
        bar.set_length(u64::from(p.units_total));
        bar.set_position(u64::from(p.units_done));
    })?;
    bar.finish_and_clear();
    let prov = super::provenance::Provenance::now(arm, run.tool_type.as_deref());
    let written = super::calibrate::write_console_records(kind, a, &run.records, &prov)?;
    eprintln!(
        "{name}: {} rows{} in {:.1} s ({} measured_js, {} move_jp, {} servo_jp)",
        run.records.len(),
        if written {
            format!(" written to {}", a.out.display())
        } else {
            String::new()
        },
        run.elapsed_s,
        run.samples,
        run.moves,
        run.servos
    );
    match run.stop {
        None => Ok(()),
        Some(Stop::Interrupted) => bail!(
            "{name} stopped by Ctrl-C, Ctrl-Z or SIGTERM; the {} rows collected are kept",
            run.records.len()
        ),
        Some(reason) => bail!(
            "{name} aborted: {reason}; motion commands stopped (a hold sent where the arm \
             was still ENABLED); the {} rows collected are kept",
            run.records.len()
        ),
    }
}

/// Connects, checks the instrument and the arm's state (enabling it only with `enable`), and
/// asks the operator to confirm unless `yes`.
fn prepare(arm: &str, enable: bool, yes: bool) -> anyhow::Result<ConsoleClient> {
    let mut client = connect(arm)?;
    match client.last_tool_type.as_deref() {
        Some("") => {
            bail!("{arm}: no instrument mounted (tool_type is empty): mount one and run again")
        }
        Some("ERROR") => {
            bail!("{arm}: the console reports tool_type ERROR: fix the instrument first")
        }
        Some(t) => eprintln!("instrument: {t}"),
        None => eprintln!("instrument: not reported by the console (no tool_type)"),
    }
    ensure_ready(&mut client, enable)?;
    if !yes {
        eprint!("The arm will move. Type yes and Enter to start: ");
        let mut line = String::new();
        std::io::stdin().lock().read_line(&mut line)?;
        if line.trim() != "yes" {
            bail!("not confirmed: nothing was sent");
        }
    }
    Ok(client)
}

/// Share of the PSM's move limits the excitation may use.
pub const EXCITATION_LIMIT_SHARE: f64 = 0.8;

/// Peak |velocity| and |acceleration| of joints 1-2 of trajectory rows `[t, q1, q2, q3, v1,
/// v2, v3]` (acceleration by finite differences of the velocity).
pub fn peaks(rows: &[[f64; 7]]) -> (f64, f64) {
    let mut v: f64 = 0.0;
    let mut a: f64 = 0.0;
    for w in rows.windows(2) {
        let dt = w[1][0] - w[0][0];
        for (now, before) in w[1][4..6].iter().zip(&w[0][4..6]) {
            v = v.max(now.abs());
            if dt > 0.0 {
                a = a.max(((now - before) / dt).abs());
            }
        }
    }
    (v, a)
}

/// The excitation slowed until its peak velocity and acceleration of joints 1-2 are within
/// [`EXCITATION_LIMIT_SHARE`] of the PSM's move limits (1.57 rad/s, 1.57 rad/s²); returns the
/// speed scale and the trajectory.
///
/// Slowing is not an exact time scaling: each depth keeps its duration, so a slower excitation
/// plays an earlier part of the multi-sine and fades it out at another point of it, and its peaks
/// do not fall steadily with the scale. The peaks are measured on each slowed trajectory, from a
/// first guess (the full-speed peaks, 10% above) down in steps of 1%, and the first scale whose
/// peaks hold is taken.
pub fn excitation_within_limits(
    targs: &super::dynamics_cmd::TrajectoryArgs,
) -> anyhow::Result<(f64, Vec<[f64; 7]>)> {
    use super::dynamics_cmd::trajectory_scaled;
    let limit = std::f64::consts::FRAC_PI_2 * EXCITATION_LIMIT_SHARE;
    let (v1, a1) = peaks(&trajectory_scaled(targs, 1.0)?);
    let guess = (limit / v1).min((limit / a1).sqrt());
    let mut scale = (1.1 * guess).min(1.0);
    while scale > 0.05 {
        let traj = trajectory_scaled(targs, scale)?;
        let (v, a) = peaks(&traj);
        if v <= limit && a <= limit {
            return Ok((scale, traj));
        }
        scale *= 0.99;
    }
    bail!("the excitation could not be slowed within the PSM's move limits")
}

/// The excitation's time, advanced once per `servo_jp` by the wall time since the last one but
/// never by more than 1.5 console periods (the interval between two consecutive `measured_js`
/// stamps, each taken within 1..=50 ms, averaged with a weight of 0.1 for the newest so a
/// jittery publisher does not slow the excitation; 10 ms until two are seen). A stall of this
/// process pauses the excitation instead of making the console jump the setpoint by the time
/// lost.
#[derive(Debug, Default)]
struct ExcitationClock {
    t_s: f64,
    last_sent: Option<Instant>,
    last_stamp_ns: Option<u64>,
    period_s: Option<f64>,
}

impl ExcitationClock {
    /// One valid `measured_js`'s stamp (ns, non-decreasing).
    fn stamp(&mut self, t_ns: u64) {
        if let Some(prev) = self.last_stamp_ns
            && t_ns > prev
        {
            let d = ((t_ns - prev) as f64 * 1e-9).clamp(1e-3, 0.05);
            self.period_s = Some(self.period_s.map_or(d, |p| p + 0.1 * (d - p)));
        }
        self.last_stamp_ns = Some(t_ns);
    }

    /// The excitation time (s) of the `servo_jp` sent at `now`.
    fn advance(&mut self, now: Instant) -> f64 {
        if let Some(last) = self.last_sent {
            let cap = 1.5 * self.period_s.unwrap_or(0.01);
            self.t_s += now.duration_since(last).as_secs_f64().min(cap);
        }
        self.last_sent = Some(now);
        self.t_s
    }
}

/// `calibrate dynamics --robot ros2:ARM`: the excitation through `servo_jp`, rows from the
/// console's `measured_js` or, with `--measure sidecar`, from a sidecar service's. The file's
/// provenance records the rate the console's `measured_js` (and so the commands) came at, as
/// `commanded_hz`, for `fit --dynamics`.
pub fn run_dynamics(
    a: &super::dynamics_cmd::DynamicsArgs,
    arm: &str,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    use super::dynamics_cmd::{TrajectoryArgs, to_csv};
    super::dynamics_cmd::check_schedule(&a.depths, a.seconds_per_depth)?;
    if !(a.effort_limit_nm.is_finite() && a.effort_limit_nm > 0.0 && a.effort_limit_nm <= 3.0) {
        bail!(
            "--effort-limit-nm {}: must be in ]0, 3] N·m",
            num(a.effort_limit_nm)
        );
    }
    if !(a.ratio > 0.0 && a.ratio <= 1.0) {
        bail!("--ratio {}: must be in ]0, 1]", num(a.ratio));
    }
    let targs = TrajectoryArgs {
        out: a.out.clone(),
        depths: a.depths.clone(),
        seconds_per_depth: a.seconds_per_depth,
        rate_hz: 1000.0,
        center: vec![0.0, 0.0],
    };
    let (scale, traj) = excitation_within_limits(&targs)?;
    let (vp, ap) = peaks(&traj);
    let duration = traj.last().map_or(0.0, |r| r[0]);
    let domain = dvrk_bridge::console::ros_domain_id()?;
    eprintln!("calibrate dynamics on {arm} through the dVRK console (DDS domain {domain})");
    eprintln!(
        "plan: free space (nothing may touch the instrument); move_jp to q1 = {:.3}, q2 = {:.3} \
         rad, q3 = {:.3} m, then the multi-sine excitation of joints 1-2 at depths {:?} m, {} s \
         each, through servo_jp at every measured_js; slowed to {scale:.2} of its simulator \
         speed: peak {vp:.2} rad/s and {ap:.2} rad/s² (PSM limits 1.57 rad/s and 1.57 rad/s²); \
         {duration:.0} s in all; effort limit {} N·m",
        traj[0][1], traj[0][2], traj[0][3], a.depths, a.seconds_per_depth, a.effort_limit_nm
    );
    eprintln!(
        "rows: {}",
        match a.measure.as_str() {
            "sidecar" => "the sidecar service's measured_js (1.5 kHz)",
            "auto" =>
                "a sidecar service's measured_js (1.5 kHz) if one runs for this arm, else the \
                 console's",
            _ =>
                "the console's measured_js (at 100 Hz the effort is seen at one phase of the \
                 controller's response to each step: --measure sidecar is the better record)",
        }
    );
    eprintln!("output: {}", a.out.display());
    if a.dry_run {
        eprintln!("--dry-run: nothing was sent");
        return Ok(());
    }
    // the sidecar's samples, if asked for or (auto) if a service runs: opened before anything
    // moves
    let prefix = a.sidecar_prefix.as_deref().unwrap_or(arm);
    let mut sidecar = match a.measure.as_str() {
        "sidecar" => Some(SidecarSource::open(prefix)?),
        "auto" => match SidecarSource::open(prefix)
            .and_then(|mut src| Ok(src.publishes_within(Duration::from_secs(1))?.then_some(src)))
        {
            Ok(Some(src)) => {
                eprintln!("rows: {} (a sidecar service runs for {arm})", src.service);
                Some(src)
            }
            Ok(None) | Err(_) => {
                eprintln!(
                    "rows: the console's measured_js: no sidecar service publishes valid \
                     {prefix}/measured_js (start `dvrk-sidecar serve` for this arm to record at \
                     the boards' rate; fit will warn)"
                );
                None
            }
        },
        _ => None,
    };
    let mut side: Vec<Sample> = Vec::new();
    let mut side_last: Option<[f64; 3]> = None;
    let mut console_stamps: Vec<u64> = Vec::new();
    let mut client = prepare(arm, a.enable, a.yes)?;
    set_ratio(&mut client, a.ratio)?;
    let mut polled = Polled::default();
    let mut watch = Watch::new(a.effort_limit_nm, client.last_tool_type.clone());
    let mut rows: Vec<dvrk_compliance::DynamicsSample> = Vec::new();
    let mut t0_ns: Option<u64> = None;
    let mut wrist: Option<[f64; 3]> = None;
    let mut moving: Option<MoveWait> = None;
    let mut started: Option<Instant> = None;
    let mut clock = ExcitationClock::default();
    let mut servos = 0u64;
    let t_start = Instant::now();
    let reason = 'run: loop {
        if stop.load(Ordering::Relaxed) {
            break 'run Some(Stop::Interrupted);
        }
        polled.measured_js.clear();
        polled.events.clear();
        client.poll(&mut polled);
        let now = Instant::now();
        if let Err(r) = watch.events(&polled, moving.as_mut()) {
            break 'run Some(r);
        }
        let mut fresh = false;
        for m in &polled.measured_js {
            let s = match watch.sample(m, now) {
                Err(r) => break 'run Some(r),
                Ok(None) => continue,
                Ok(Some(s)) => s,
            };
            let w = *wrist.get_or_insert([s.aux[0], s.aux[1], s.aux[2]]);
            clock.stamp(s.t_ns);
            match (started, &moving) {
                (None, None) => {
                    // with the sidecar's rows: nothing moves before the service is known to
                    // read this arm
                    if let Some(src) = sidecar.as_mut()
                        && !src.checked
                    {
                        let Some(p) = side_last else { continue };
                        if let Err(r) = same_arm(&src.service, &s.position, &p) {
                            break 'run Some(r);
                        }
                        src.checked = true;
                    }
                    // the move to the start of the excitation
                    let first = &traj[0];
                    let d = [
                        first[1] - s.position[0],
                        first[2] - s.position[1],
                        first[3] - s.position[2],
                    ];
                    moving = Some(MoveWait::start(
                        &mut client,
                        now,
                        &d,
                        a.ratio,
                        [first[1], first[2], first[3], w[0], w[1], w[2]],
                    )?);
                }
                (Some(_), _) => {
                    console_stamps.push(s.t_ns);
                    if sidecar.is_none() {
                        let t0n = *t0_ns.get_or_insert(s.t_ns);
                        rows.push(dvrk_compliance::DynamicsSample {
                            t_s: s.t_ns.saturating_sub(t0n) as f64 * 1e-9,
                            position: s.position,
                            effort_nm: [s.effort[0], s.effort[1]],
                        });
                    }
                    fresh = true;
                }
                (None, Some(_)) => {}
            }
        }
        if let Some(src) = sidecar.as_mut() {
            side.clear();
            src.drain(&mut side, now)?;
            if let Err(r) = src.silence(now) {
                break 'run Some(r);
            }
            for s in side.iter().filter(|s| s.valid) {
                side_last = Some(s.position);
                if let Err(r) = effort_within(s, a.effort_limit_nm) {
                    break 'run Some(r);
                }
                // rows from the excitation's first servo_jp on, on one time axis (a repeated
                // or older stamp, from a restarted service, is left out)
                if started.is_some() && servos > 0 {
                    let t0n = *t0_ns.get_or_insert(s.t_ns);
                    let t = s.t_ns.saturating_sub(t0n) as f64 * 1e-9;
                    if rows.last().is_none_or(|r| t > r.t_s) {
                        rows.push(dvrk_compliance::DynamicsSample {
                            t_s: t,
                            position: s.position,
                            effort_nm: [s.effort[0], s.effort[1]],
                        });
                    }
                }
            }
        }
        // one servo_jp per poll that brought a measured_js: however many came at once (after
        // this process was starved), the trajectory moves on by at most one console period
        if fresh && let Some(w) = wrist {
            let i = (clock.advance(now) * 1000.0) as usize;
            let Some(r) = traj.get(i) else {
                break 'run None;
            };
            client.servo_jp_with_velocity(
                &[r[1], r[2], r[3], w[0], w[1], w[2]],
                &[r[4], r[5], r[6], 0.0, 0.0, 0.0],
            )?;
            servos += 1;
        }
        if let Err(r) = watch.silence(now) {
            break 'run Some(r);
        }
        if let Some(m) = &mut moving {
            match m.check(&client, now) {
                Err(r) => break 'run Some(r),
                Ok(MoveStatus::Done) => {
                    moving = None;
                    started = Some(now);
                    eprintln!("at the start: excitation running for {duration:.0} s");
                }
                Ok(other) => m.act(other, &mut client, now)?,
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    hold_after(&mut client, reason.as_ref());
    let written = if rows.is_empty() && std::fs::symlink_metadata(&a.out).is_ok() {
        eprintln!("no row collected: {} is left as it was", a.out.display());
        false
    } else {
        let mut prov = super::provenance::Provenance::now(arm, watch.tool_type.as_deref());
        prov.commanded_hz = commanded_hz(&console_stamps).map(|hz| format!("{hz:.2}"));
        let text = prov.lines() + &to_csv(&rows);
        super::data::write_atomically(&a.out, text.as_bytes())?;
        true
    };
    eprintln!(
        "dynamics: {} rows{} in {:.1} s ({servos} servo_jp)",
        rows.len(),
        if written {
            format!(" written to {}", a.out.display())
        } else {
            String::new()
        },
        t_start.elapsed().as_secs_f64()
    );
    match reason {
        None => Ok(()),
        Some(r) => bail!(
            "dynamics aborted: {r}; motion commands stopped; the {} rows collected are kept",
            rows.len()
        ),
    }
}

/// The rate (Hz) of the console's `measured_js` from their stamps (ns): the mean interval over
/// those shorter than twice the median (a stall, this process starved, is not a period; the
/// jitter of the others cancels in the mean); `None` for fewer than 10 stamps.
fn commanded_hz(stamps: &[u64]) -> Option<f64> {
    let dt: Vec<u64> = stamps
        .windows(2)
        .map(|w| w[1].saturating_sub(w[0]))
        .filter(|&d| d > 0)
        .collect();
    if dt.len() < 9 {
        return None;
    }
    let mut sorted = dt.clone();
    let mid = sorted.len() / 2;
    let (_, median, _) = sorted.select_nth_unstable(mid);
    let limit = 2 * *median;
    let (sum, n) = dt
        .iter()
        .filter(|&&d| d < limit)
        .fold((0u64, 0u64), |(s, n), &d| (s.saturating_add(d), n + 1));
    (sum > 0).then(|| 1e9 * n as f64 / sum as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::dynamics_cmd::TrajectoryArgs;

    #[test]
    fn the_command_rate_is_the_consoles_period_without_stalls() {
        // 100 Hz with up to 3 ms of jitter, a stall of 200 ms and a repeated stamp
        let mut stamps: Vec<u64> = (0..200u64)
            .map(|i| i * 10_000_000 + (i * 7919 % 7) * 500_000)
            .collect();
        stamps[100] = stamps[99];
        for s in &mut stamps[150..] {
            *s += 200_000_000;
        }
        let hz = commanded_hz(&stamps).unwrap();
        assert!((hz - 100.0).abs() < 3.0, "{hz}");
        assert_eq!(commanded_hz(&stamps[..5]), None);
    }

    #[test]
    fn a_source_that_stops_is_silent_and_one_that_sends_invalid_samples_is_invalid() {
        let t0 = Instant::now();
        let ms = |m: u64| t0 + Duration::from_millis(m);
        let kind = |r: Result<(), Stop>| match r {
            Ok(()) => None,
            Err(Stop::Silent {
                source, invalid, ..
            }) => Some((source, invalid)),
            Err(other) => panic!("{other}"),
        };
        // valid samples up to 0 ms, then (for the invalid cases) invalid ones up to `last` ms
        let heard = |last: Option<u64>| {
            let mut h = Heard::new(ms(0));
            h.sample(true, ms(0));
            if let Some(last) = last {
                h.sample(false, ms(last / 2));
                h.sample(false, ms(last));
            }
            h
        };
        // within the limit of the last valid sample: nothing to say
        assert_eq!(kind(heard(Some(250)).silence("sidecar", ms(250))), None);
        // a service killed after valid samples: nothing arrives any more
        assert_eq!(
            kind(heard(None).silence("sidecar", ms(400))),
            Some(("sidecar", false))
        );
        // invalid samples still arriving
        assert_eq!(
            kind(heard(Some(390)).silence("console", ms(400))),
            Some(("console", true))
        );
        // invalid ones that stopped as well: silent
        assert_eq!(
            kind(heard(Some(50)).silence("console", ms(400))),
            Some(("console", false))
        );
        // a valid sample after invalid ones clears them
        let mut h = heard(Some(100));
        h.sample(true, ms(110));
        h.sample(false, ms(150)); // one more invalid, then nothing
        h.sample(true, ms(160));
        assert_eq!(
            kind(h.silence("sidecar", ms(500))),
            Some(("sidecar", false))
        );
    }

    #[test]
    fn a_stall_pauses_the_excitation_instead_of_jumping_it() {
        let t0 = Instant::now();
        let ms = |m: u64| t0 + Duration::from_millis(m);
        let mut c = ExcitationClock::default();
        // measured_js every 10 ms of console time, a servo_jp after each
        let mut t = Vec::new();
        for k in 0..5u64 {
            c.stamp(1_000_000_000 + k * 10_000_000);
            t.push(c.advance(ms(10 * k)));
        }
        assert_eq!(t[0], 0.0);
        for w in t.windows(2) {
            assert!((w[1] - w[0] - 0.010).abs() < 1e-9, "{t:?}");
        }
        // this process starved for 200 ms: the queued measured_js come at once, one servo_jp
        for k in 5..25u64 {
            c.stamp(1_000_000_000 + k * 10_000_000);
        }
        let after = c.advance(ms(240));
        assert!((after - t[4] - 0.015).abs() < 1e-9, "{after}");
        // then on at the console's pace again
        c.stamp(1_250_000_000);
        let back = c.advance(ms(250));
        assert!((back - after - 0.010).abs() < 1e-9);
        // stamps 5 and 15 ms apart (a jittery publisher), received every 10 ms: the cap stays
        // near 1.5 x 10 ms, so the excitation keeps the wall clock's pace
        let mut t_ns = 1_250_000_000;
        let mut last = back;
        for k in 0..40u64 {
            t_ns += if k % 2 == 0 { 5_000_000 } else { 15_000_000 };
            c.stamp(t_ns);
            let now = c.advance(ms(260 + 10 * k));
            assert!(
                (now - last - 0.010).abs() < 1e-9,
                "step {k}: {}",
                now - last
            );
            last = now;
        }
    }

    #[test]
    fn the_console_excitation_stays_within_the_move_limits_at_any_schedule() {
        let limit = std::f64::consts::FRAC_PI_2 * EXCITATION_LIMIT_SHARE;
        for seconds in [2.0, 4.0, 6.0, 8.0, 12.0, 20.0, 30.0, 60.0] {
            let targs = TrajectoryArgs {
                out: "unused.csv".into(),
                depths: vec![0.1, 0.15],
                seconds_per_depth: seconds,
                rate_hz: 1000.0,
                center: vec![0.0, 0.0],
            };
            let (scale, traj) = excitation_within_limits(&targs).unwrap();
            let (v, a) = peaks(&traj);
            assert!(scale > 0.2 && scale <= 1.0, "{seconds} s: scale {scale}");
            assert!(
                v <= limit && a <= limit,
                "{seconds} s: {v} rad/s, {a} rad/s²"
            );
            // not slowed more than needed: one of the two peaks is near its limit
            eprintln!("{seconds} s: scale {scale:.3}, {v:.3} rad/s, {a:.3} rad/s²");
            assert!(v > 0.7 * limit || a > 0.7 * limit, "{seconds} s: {v}, {a}");
        }
    }
}
