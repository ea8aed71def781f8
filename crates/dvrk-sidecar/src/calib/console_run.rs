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
//! - every `measured_js` is checked: |effort| of joints 1-2 above `--effort-limit-nm`, a joint
//!   outside the limits, the operating state leaving ENABLED (e-stop, FAULT), `measured_js`
//!   silent or invalid (zero stamp) for 0.3 s, a move not finished in time and Ctrl-C all abort
//!   within one poll (1 ms) of being seen: no motion command follows but at most one `hold`, the
//!   rows collected are written atomically, and the command exits non-zero with the reason.

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
        for_ms: u128,
        invalid: bool,
    },
    MoveNotStarted {
        waited_s: f64,
        warning: Option<String>,
    },
    MoveTimeout {
        timeout_s: f64,
    },
    MoveInterrupted,
    Interrupted,
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
            Stop::Silent { for_ms, invalid } => write!(
                f,
                "measured_js {} for {for_ms} ms (limit {} ms)",
                if *invalid {
                    "invalid (zero stamp)"
                } else {
                    "silent"
                },
                SILENCE_LIMIT.as_millis()
            ),
            Stop::MoveNotStarted { waited_s, warning } => {
                write!(
                    f,
                    "the console did not start a move_jp within {waited_s:.1} s (refused?)"
                )?;
                if let Some(w) = warning {
                    write!(f, "; its last warning: {w}")?;
                }
                Ok(())
            }
            Stop::MoveTimeout { timeout_s } => {
                write!(
                    f,
                    "a move_jp did not finish within its timeout of {timeout_s:.1} s"
                )
            }
            Stop::MoveInterrupted => write!(f, "a move_jp ended with goal_reached false"),
            Stop::Interrupted => write!(f, "stopped by Ctrl-C (signal)"),
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
    let mut wait_for =
        |c: &mut ConsoleClient, what: &str, secs: u64, ok: &dyn Fn(&str, bool, bool) -> bool| {
            let end = Instant::now() + Duration::from_secs(secs);
            while Instant::now() < end {
                c.poll(&mut polled);
                polled.measured_js.clear();
                let (s, h, b) = state(c);
                if ok(&s, h, b) {
                    return Ok(());
                }
                if s == "FAULT" {
                    bail!("{arm} went to FAULT while {what}");
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let (s, h, _) = state(c);
            bail!("{arm} not {what} after {secs} s (state {s}, homed {h})")
        };
    if s != "ENABLED" {
        eprintln!("--enable: asking the console to enable {arm}");
        c.state_command("enable")?;
        wait_for(c, "enabled", 30, &|s, _, _| s == "ENABLED")?;
    }
    if !state(c).1 {
        eprintln!("--enable: asking the console to home {arm}");
        c.state_command("home")?;
        wait_for(c, "homed", 120, &|s, h, b| s == "ENABLED" && h && !b)?;
    }
    Ok(())
}

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
    sent: Instant,
    saw_busy: bool,
    ended: bool,
    goal: Option<bool>,
    timeout_s: f64,
}

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

/// Runs `plan` on the console's arm until done, aborted, or stopped.
pub fn run_console<P: Plan>(
    plan: P,
    rc: RunnerConfig,
    client: &mut ConsoleClient,
    opts: &ConsoleOptions,
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
    if client.ratio_matched() {
        client.set_ratio(opts.ratio)?;
    } else {
        tracing::warn!(
            "the console has no reader of trajectory_j/set_ratio: move_jp runs at its own speed"
        );
    }
    let mut polled = Polled::default();
    let mut last_valid = Instant::now();
    let mut last_any = Instant::now();
    let mut saw_invalid = false;
    let mut last_cmd: Option<[f64; 3]> = None;
    let mut wrist: Option<[f64; 3]> = None;
    let mut last_t_ns = 0u64;
    let mut moving: Option<MoveWait> = None;
    let mut last_error: Option<String> = None;
    // operator prompt: Some(deadline) with --yes, or a channel to stdin
    let mut prompt: Option<(Option<Instant>, Option<mpsc::Receiver<()>>)> = None;
    let reason = 'run: loop {
        if stop.load(Ordering::Relaxed) {
            break 'run Some(Stop::Interrupted);
        }
        polled.measured_js.clear();
        polled.events.clear();
        client.poll(&mut polled);
        let now = Instant::now();
        for ev in &polled.events {
            match &ev.value {
                ConsoleEvent::OperatingState(s) => {
                    if s.state != "ENABLED" {
                        break 'run Some(Stop::StateLeft {
                            state: s.state.clone(),
                            error: last_error.clone(),
                        });
                    }
                    if let Some(m) = &mut moving
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
                    if let Some(m) = &mut moving
                        && ev.seq > m.cmd_seq
                    {
                        m.goal = Some(*v);
                    }
                }
                ConsoleEvent::Error(e) => {
                    tracing::warn!("console error: {e}");
                    last_error = Some(e.clone());
                }
                ConsoleEvent::Warning(w) => tracing::warn!("console warning: {w}"),
                ConsoleEvent::ToolType(t) => {
                    if run.tool_type.as_deref().is_some_and(|old| old != t) {
                        tracing::warn!("instrument changed during the run: {t:?}");
                    }
                    run.tool_type = Some(t.clone());
                }
            }
        }
        if !polled.measured_js.is_empty() {
            last_any = now;
        }
        for m in &polled.measured_js {
            let stamp_ns =
                u64::try_from(i64::from(m.stamp.sec) * 1_000_000_000 + i64::from(m.stamp.nanosec))
                    .unwrap_or(0);
            let t_ns = stamp_ns.max(last_t_ns);
            let s = sample_of(m, t_ns);
            run.samples += 1;
            if !s.valid {
                saw_invalid = true;
                continue;
            }
            last_t_ns = t_ns;
            last_valid = now;
            if wrist.is_none() {
                wrist = Some([s.aux[0], s.aux[1], s.aux[2]]);
            }
            for j in 0..2 {
                if s.effort[j].abs() > rc.effort_limit_nm {
                    break 'run Some(Stop::EffortLimit {
                        joint: j + 1,
                        effort: s.effort[j],
                        limit: rc.effort_limit_nm,
                    });
                }
            }
            if moving.is_some() || prompt.is_some() {
                continue; // the console moves (or the operator acts); the runner waits
            }
            let out = runner.update(&s);
            run.records.extend(out.record);
            match out.status {
                Status::Done => break 'run None,
                Status::Aborted(r) => break 'run Some(Stop::Runner(r)),
                Status::AwaitFixture(f) => {
                    eprintln!("\n>>> {}", fixture_prompt(&f));
                    if opts.yes {
                        eprintln!("    (--yes: continuing in {:.1} s)", opts.prompt_pause_s);
                        prompt = Some((
                            Some(now + Duration::from_secs_f64(opts.prompt_pause_s)),
                            None,
                        ));
                    } else {
                        eprintln!("    Press Enter when done (Ctrl-C aborts).");
                        let (tx, rx) = mpsc::channel();
                        std::thread::spawn(move || {
                            let mut line = String::new();
                            if std::io::stdin().lock().read_line(&mut line).is_ok() {
                                let _ = tx.send(());
                            }
                        });
                        prompt = Some((None, Some(rx)));
                    }
                    continue;
                }
                Status::Running => {}
            }
            let Some(w) = wrist else { continue };
            let full = |q: &[f64; 3]| [q[0], q[1], q[2], w[0], w[1], w[2]];
            let base = last_cmd.unwrap_or(s.position);
            if runner.ramping() {
                let target = runner.target();
                let d: [f64; 3] = std::array::from_fn(|j| target[j] - base[j]);
                if (0..3).any(|j| d[j].abs() > LARGE_MOVE[j]) {
                    moving = Some(MoveWait {
                        cmd_seq: client.last_seq(),
                        sent: now,
                        saw_busy: false,
                        ended: false,
                        goal: None,
                        timeout_s: 2.0 * move_duration_s(&d, opts.ratio) + 3.0,
                    });
                    client.move_jp(&full(&target))?;
                    run.moves += 1;
                    last_cmd = Some(target);
                    continue;
                }
            }
            if last_cmd != Some(out.setpoint) {
                client.servo_jp(&full(&out.setpoint))?;
                run.servos += 1;
                last_cmd = Some(out.setpoint);
            }
        }
        // silence: no valid measured_js for too long
        let since_valid = now.duration_since(last_valid);
        if since_valid > SILENCE_LIMIT {
            break 'run Some(Stop::Silent {
                for_ms: since_valid.as_millis(),
                invalid: saw_invalid && now.duration_since(last_any) <= SILENCE_LIMIT,
            });
        }
        if let Some(m) = &moving {
            let waited = now.duration_since(m.sent).as_secs_f64();
            if m.goal == Some(false) {
                break 'run Some(Stop::MoveInterrupted);
            }
            if m.ended && m.goal == Some(true) {
                runner.target_reached_by_robot();
                moving = None;
            } else if !m.saw_busy && waited > 1.0 {
                break 'run Some(Stop::MoveNotStarted {
                    waited_s: waited,
                    warning: client.recent_warnings.back().cloned(),
                });
            } else if waited > m.timeout_s {
                break 'run Some(Stop::MoveTimeout {
                    timeout_s: m.timeout_s,
                });
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
        if run.samples % 100 == 0 {
            on_progress(&runner);
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    if let Some(r) = &reason {
        let state_ok = !matches!(r, Stop::StateLeft { .. });
        if state_ok {
            // One hold where the arm is; nothing else follows.
            let _ = client.hold();
        }
    }
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
    let rc = RunnerConfig {
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
    let mut client = connect(arm)?;
    let tool = client.last_tool_type.clone();
    match tool.as_deref() {
        Some("") => {
            bail!("{arm}: no instrument mounted (tool_type is empty): mount one and run again")
        }
        Some("ERROR") => {
            bail!("{arm}: the console reports tool_type ERROR: fix the instrument first")
        }
        Some(t) => eprintln!("instrument: {t}"),
        None => eprintln!("instrument: not reported by the console (no tool_type)"),
    }
    ensure_ready(&mut client, a.enable)?;
    if !a.yes {
        eprint!("The arm will move. Type yes and Enter to start: ");
        let mut line = String::new();
        std::io::stdin().lock().read_line(&mut line)?;
        if line.trim() != "yes" {
            bail!("not confirmed: nothing was sent");
        }
    }
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
    let run = run_console(plan, rc, &mut client, &opts, stop, |r| {
        let p = r.progress();
        bar.set_length(u64::from(p.units_total));
        bar.set_position(u64::from(p.units_done));
    })?;
    bar.finish_and_clear();
    let written = super::calibrate::write_console_records(kind, a, &run.records)?;
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
            "{name} stopped by Ctrl-C; the {} rows collected are kept",
            run.records.len()
        ),
        Some(reason) => bail!(
            "{name} aborted: {reason}; motion commands stopped (one hold sent where the arm \
             was still ENABLED); the {} rows collected are kept",
            run.records.len()
        ),
    }
}
