//! `sim --crtk PSM1`: the simulated PSM behind a stand-in of the dVRK 2.x console's CRTK
//! interface over DDS, so the calibration procedures (and anything else that moves an arm
//! through the console) can be tested end to end without a robot and without ROS.
//!
//! What it does as the console does (reference/dvrk-crtk-ros2.md):
//! - topics, types and QoS of the console ([`dvrk_bridge::console::ConsoleServer`]);
//!   `measured_js` and `setpoint_js` at `--rate` (100 Hz), only while a reader is matched;
//! - the operating state machine: DISABLED, ENABLED, FAULT, with `is_homed` and `is_busy`
//!   events; `enable`, `disable`, `home`, `unhome`; from FAULT only `disable` and `unhome`;
//! - `move_jp` planned to a stop within the PSM's speed and acceleration limits scaled by
//!   `trajectory_j/set_ratio`, goals clipped to the joint limits (with a warning); busy at once,
//!   then `goal_reached` and not busy at the end;
//! - `move_jp`/`servo_jp` refused with a warning and no busy event unless ENABLED and homed;
//! - a PID tracking error too large (e.g. pushing on a clamp) faults the arm;
//! - `tool_type` published at start.
//!
//! What the console cannot do but a lab can: `--fixture clamp` plays the operator who clamps
//! the shaft where it is once the arm has been still for 0.5 s after an insertion move, and
//! releases it before the next insertion move; `--fixture divot` holds the tip in a divot from
//! the start. `--fault KIND@SECONDS` injects a fault for the fault tests, and `--command-log`
//! writes every command received and every state change, one JSON object per line.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use dvrk_bridge::cdr::RosTime;
use dvrk_bridge::console::{ConsoleCommand, ConsoleServer, PSM_JOINT_NAMES};
use dvrk_bridge::crtk::{JointStateMsg, OperatingStateMsg};
use dvrk_sim::{Emulator, Environment, Motion, Scenario, SimPsm, SimRng};

use crate::text::num;

/// Classic PSM joint limits of the console (share/kinematic/PSM.json): yaw, pitch, insertion,
/// roll, wrist pitch, wrist yaw.
pub const PSM_LIMITS: [[f64; 2]; 6] = [
    [-1.588, 1.588],
    [-0.925, 0.925],
    [0.0, 0.24],
    [-4.5, 4.5],
    [-1.57, 1.57],
    [-1.57, 1.57],
];

/// `move_jp` speed and acceleration limits at ratio 1: joints 1-2 90 deg/s and 90 deg/s^2,
/// insertion 0.2 m/s and 0.2 m/s^2, wrist 1080 deg/s (and deg/s^2).
pub const PSM_MAX_SPEED: [f64; 6] = [
    std::f64::consts::FRAC_PI_2,
    std::f64::consts::FRAC_PI_2,
    0.2,
    6.0 * std::f64::consts::PI,
    6.0 * std::f64::consts::PI,
    6.0 * std::f64::consts::PI,
];
pub const PSM_MAX_ACCEL: [f64; 6] = PSM_MAX_SPEED;

/// Tracking error that faults the arm (rad, rad, m), the stand-in's choice of the console's
/// PID tolerance.
pub const TRACKING_ERROR_LIMIT: [f64; 3] = [0.1, 0.1, 0.01];

/// A `servo_jp` step larger than this (rad, rad, m) is not what one control cycle reaches: it
/// is logged as such (and executed, as the console would).
pub const SERVO_STEP_WARN: [f64; 3] = [0.02, 0.02, 0.002];

#[derive(clap::Args, Debug, Clone)]
pub struct CrtkArgs {
    /// Expose the simulated PSM as a dVRK 2.x console's arm of this name over DDS (domain from
    /// ROS_DOMAIN_ID, default 0), instead of emulating its boards.
    #[arg(long = "crtk", value_name = "ARM")]
    pub arm: Option<String>,
    /// Publishing rate of measured_js and setpoint_js (Hz).
    #[arg(long = "crtk-rate", default_value_t = 100.0)]
    pub rate_hz: f64,
    /// Operating state at start: `homed` (ENABLED and homed, as after the operator's power-on
    /// and homing), `enabled` (not homed) or `disabled`.
    #[arg(long, default_value = "homed", value_parser = ["homed", "enabled", "disabled"])]
    pub start: String,
    /// The lab's fixture: `none`, `clamp` (clamped where the arm stops after an insertion move,
    /// released before the next one) or `divot` (the tip held in a divot where it starts).
    #[arg(long, default_value = "none", value_parser = ["none", "clamp", "divot"])]
    pub fixture: String,
    /// Instrument published on tool_type.
    #[arg(long, default_value = "LARGE_NEEDLE_DRIVER:400006[..]")]
    pub tool: String,
    /// Effort noise added to measured_js joints 1-3 (N·m, N·m, N; one sigma).
    #[arg(long, default_value_t = 0.005)]
    pub effort_noise_nm: f64,
    /// Inject a fault at a time after start: `effort@S` (joint 1 effort reads +3 N·m),
    /// `estop@S` (DISABLED), `fault@S` (FAULT), `silence@S` (measured_js stops),
    /// `invalid@S` (measured_js with a zero stamp), `refuse@S` (moves refused with a warning
    /// and no busy event, as the console does when it is not ready), `lose@S` (the next
    /// move_jp, the next state_command and the next set_ratio after S are lost on the way:
    /// never applied, logged as `lost`), `ignore-ratio@S` (every set_ratio from S on is lost).
    #[arg(long, value_name = "KIND@SECONDS")]
    pub fault: Vec<String>,
    /// A change the console makes on its own, at a time after start: `tool@S=NAME` (the
    /// instrument: `tool_type` becomes NAME, e.g. `CADIERE_FORCEPS:400049[..]`, or empty for
    /// a removed one, or ERROR), `base@S=x,y,z[,yaw]` (the base frame: translation in m, rotation
    /// about z in rad), `unhome@S`, `home@S` (homes at once), `enable@S`, `disable@S`.
    #[arg(long, value_name = "KIND@SECONDS[=VALUE]")]
    pub event: Vec<String>,
    /// Also read events from standard input, one `KIND[=VALUE]` per line (the kinds of
    /// --event), applied at once: for tests that act when they are ready.
    #[arg(long)]
    pub events_stdin: bool,
    /// The base frame at start: `x,y,z[,yaw]` (m, rad about z); measured_cp = base frame ×
    /// local/measured_cp.
    #[arg(long, default_value = "0,0,0,0")]
    pub base_frame: String,
    /// Write every command received and every state change as JSON lines to this file.
    #[arg(long)]
    pub command_log: Option<PathBuf>,
    /// Also answer the boards' UDP protocol of the same simulated arm on this address (e.g.
    /// 127.0.0.1:1394), so a sidecar service reads the arm the console stand-in moves.
    #[arg(long, value_name = "ADDR:PORT")]
    pub boards: Option<std::net::SocketAddr>,
}

/// A fault to inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    Effort,
    Estop,
    PidFault,
    Silence,
    Invalid,
    Refuse,
    Lose,
    IgnoreRatio,
}

pub fn parse_fault(s: &str) -> Result<(Fault, f64)> {
    let Some((kind, at)) = s.split_once('@') else {
        bail!("--fault {s:?}: expected KIND@SECONDS, e.g. estop@5");
    };
    let kind = match kind {
        "effort" => Fault::Effort,
        "estop" => Fault::Estop,
        "fault" => Fault::PidFault,
        "silence" => Fault::Silence,
        "invalid" => Fault::Invalid,
        "refuse" => Fault::Refuse,
        "lose" => Fault::Lose,
        "ignore-ratio" => Fault::IgnoreRatio,
        other => bail!(
            "--fault {s:?}: unknown kind {other:?} (effort, estop, fault, silence, invalid, \
             refuse, lose, ignore-ratio)"
        ),
    };
    let at: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .with_context(|| format!("--fault {s:?}: {at:?} is not a time in seconds >= 0"))?;
    Ok((kind, at))
}

/// A console event of `--event`.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    Tool(String),
    Base([f64; 4]),
    Unhome,
    Home,
    Enable,
    Disable,
}

/// `x,y,z[,yaw]`.
pub fn parse_frame(s: &str) -> Result<[f64; 4]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{s:?}: expected x,y,z[,yaw] numbers"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|a| a.is_finite()) => Ok([x, y, z, 0.0]),
        [x, y, z, yaw] if v.iter().all(|a| a.is_finite()) => Ok([x, y, z, yaw]),
        _ => bail!("{s:?}: expected 3 or 4 finite numbers x,y,z[,yaw]"),
    }
}

pub fn parse_event(s: &str) -> Result<(Event, f64)> {
    let (head, value) = match s.split_once('=') {
        Some((h, v)) => (h, Some(v)),
        None => (s, None),
    };
    let Some((kind, at)) = head.split_once('@') else {
        bail!(
            "--event {s:?}: expected KIND@SECONDS[=VALUE], e.g. tool@5=CADIERE_FORCEPS:400049[..]"
        );
    };
    let at: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .with_context(|| format!("--event {s:?}: {at:?} is not a time in seconds >= 0"))?;
    let ev = match (kind, value) {
        ("tool", Some(v)) => Event::Tool(v.to_owned()),
        ("base", Some(v)) => Event::Base(parse_frame(v).with_context(|| format!("--event {s:?}"))?),
        ("unhome", None) => Event::Unhome,
        ("home", None) => Event::Home,
        ("enable", None) => Event::Enable,
        ("disable", None) => Event::Disable,
        _ => bail!(
            "--event {s:?}: kinds are tool@S=NAME, base@S=x,y,z[,yaw], unhome@S, home@S, enable@S, disable@S"
        ),
    };
    Ok((ev, at))
}

/// The pose of a base frame `[x, y, z, yaw]`.
pub fn frame_pose(f: &[f64; 4]) -> nalgebra::Isometry3<f64> {
    nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(f[0], f[1], f[2]),
        nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), f[3]),
    )
}

fn pose_msg(
    stamp: RosTime,
    frame: &str,
    p: &nalgebra::Isometry3<f64>,
) -> dvrk_bridge::crtk::PoseStampedMsg {
    let t = p.translation.vector;
    let q = p.rotation.coords;
    dvrk_bridge::crtk::PoseStampedMsg {
        stamp,
        frame_id: frame.to_owned(),
        position: [t.x, t.y, t.z],
        orientation_xyzw: [q.x, q.y, q.z, q.w],
    }
}

/// One joint's `move_jp` trajectory: bang-bang to a stop at the goal within the limits.
#[derive(Debug, Clone, Copy, Default)]
struct Axis {
    pos: f64,
    vel: f64,
    goal: f64,
}

impl Axis {
    fn step(&mut self, dt: f64, vmax: f64, amax: f64) -> bool {
        let d = self.goal - self.pos;
        if d.abs() < 1e-9 && self.vel.abs() < amax * dt {
            self.pos = self.goal;
            self.vel = 0.0;
            return true;
        }
        let v_stop = (2.0 * amax * d.abs()).sqrt().min(vmax) * d.signum();
        let dv = (v_stop - self.vel).clamp(-amax * dt, amax * dt);
        self.vel += dv;
        let next = self.pos + self.vel * dt;
        // never overshoot the goal
        if (self.goal - next).signum() != d.signum() && d != 0.0 {
            self.pos = self.goal;
            self.vel = 0.0;
            return true;
        }
        self.pos = next;
        false
    }
}

/// The console's state machine and trajectory generator around a simulated PSM. Pure: time is
/// passed in, outputs are returned.
pub struct ConsoleSim {
    /// The simulated arm and its boards (answered on UDP with `--boards`).
    emu: Emulator,
    /// Physics steps taken, of `dt_ns` each.
    steps: u64,
    dt_ns: u64,
    state: &'static str,
    homed: bool,
    busy: bool,
    homing_until: Option<f64>,
    traj: Option<[Axis; 6]>,
    setpoint: [f64; 6],
    ratio: f64,
    fixture: String,
    clamp_engaged: bool,
    still_since: Option<f64>,
    insertion_moved: bool,
    effort_offset: f64,
    refuse: bool,
    t: f64,
}

/// What the stand-in must publish after a step or a command.
#[derive(Debug, Clone, PartialEq)]
pub enum Out {
    State,
    GoalReached(bool),
    Warning(String),
    Error(String),
    Note(String),
    /// `trajectory_j/ratio`, on each `set_ratio` taken.
    Ratio(f64),
}

impl ConsoleSim {
    pub fn new(
        scenario: &Scenario,
        io: &dvrk_io::IoConfig,
        start: &str,
        fixture: &str,
    ) -> Result<Self> {
        let mut sc = scenario.clone();
        sc.motion = Motion::Hold;
        let divot = match sc.environment {
            e @ Environment::Divot { .. } => e,
            _ => Environment::Divot {
                plate_stiffness_n_per_m: 20_000.0,
                plate_damping_n_s_per_m: 50.0,
                capture_depth_m: 0.001,
            },
        };
        sc.environment = Environment::Free;
        let mut emu = Emulator::new(&sc, io).context("building the emulated boards")?;
        // the first call sets the emulator's epoch; physics steps follow one dt at a time
        emu.advance_to(1);
        let dt_ns = (sc.dt_s * 1e9).round().max(1.0) as u64;
        let psm = emu.psm_mut();
        let q = psm.joint_state().position;
        let setpoint: [f64; 6] = std::array::from_fn(|j| q[j]);
        let enabled = start != "disabled";
        psm.set_amps_enabled(enabled);
        if fixture == "divot" {
            psm.set_environment(divot);
        }
        Ok(Self {
            emu,
            steps: 0,
            dt_ns,
            state: if enabled { "ENABLED" } else { "DISABLED" },
            homed: start == "homed",
            busy: false,
            homing_until: None,
            traj: None,
            setpoint,
            ratio: 1.0,
            fixture: fixture.to_owned(),
            clamp_engaged: false,
            still_since: None,
            insertion_moved: fixture == "clamp",
            effort_offset: 0.0,
            refuse: false,
            t: 0.0,
        })
    }

    fn psm(&self) -> &SimPsm {
        self.emu.psm()
    }

    fn psm_mut(&mut self) -> &mut SimPsm {
        self.emu.psm_mut()
    }

    /// Answers one board request (the emulator of the same arm).
    pub fn handle_board_request(&mut self, request: &[u8], reply: &mut [u8]) -> Option<usize> {
        self.emu.handle(request, reply)
    }

    pub fn operating_state(&self, stamp: RosTime) -> OperatingStateMsg {
        OperatingStateMsg {
            stamp,
            state: self.state.to_owned(),
            is_homed: self.homed,
            is_busy: self.busy,
        }
    }

    pub fn state(&self) -> &'static str {
        self.state
    }

    fn ready(&self) -> bool {
        self.state == "ENABLED" && self.homed
    }

    fn set_state(&mut self, s: &'static str, out: &mut Vec<Out>) {
        if self.state != s {
            self.state = s;
            if s != "ENABLED" {
                self.traj = None;
                self.busy = false;
                self.homing_until = None;
            }
            self.psm_mut().set_amps_enabled(s == "ENABLED");
            if s == "ENABLED" {
                self.hold_here();
            }
            out.push(Out::State);
        }
    }

    fn hold_here(&mut self) {
        let q = self.psm().joint_state().position;
        self.setpoint = std::array::from_fn(|j| q[j]);
        self.traj = None;
        self.apply_setpoint(&[0.0; 6]);
    }

    fn apply_setpoint(&mut self, vel: &[f64; 6]) {
        let sp = self.setpoint;
        for j in 0..6 {
            self.psm_mut().set_setpoint_with_velocity(j, sp[j], vel[j]);
        }
    }

    fn clip(&self, goal: &[f64], out: &mut Vec<Out>, what: &str) -> Option<[f64; 6]> {
        if goal.len() != 6 || goal.iter().any(|v| !v.is_finite()) {
            out.push(Out::Warning(format!(
                "{what}: expected 6 finite joint positions, got {goal:?}"
            )));
            return None;
        }
        let mut g = [0.0; 6];
        for j in 0..6 {
            g[j] = goal[j].clamp(PSM_LIMITS[j][0], PSM_LIMITS[j][1]);
            if g[j] != goal[j] {
                out.push(Out::Warning(format!(
                    "{what}: joint {} goal {} clipped to the limits [{}, {}]",
                    j + 1,
                    goal[j],
                    PSM_LIMITS[j][0],
                    PSM_LIMITS[j][1]
                )));
            }
        }
        Some(g)
    }

    fn release_for_insertion(&mut self, goal_insertion: f64, out: &mut Vec<Out>) {
        if (goal_insertion - self.setpoint[2]).abs() > 1e-3 {
            if self.clamp_engaged {
                self.clamp_engaged = false;
                self.psm_mut().set_environment(Environment::Free);
                out.push(Out::Note("operator: clamp released".into()));
            }
            self.insertion_moved = true;
            self.still_since = None;
        }
    }

    /// Applies one command.
    pub fn command(&mut self, cmd: &ConsoleCommand, out: &mut Vec<Out>) {
        match cmd {
            ConsoleCommand::MoveJp(js) | ConsoleCommand::ServoJp(js) => {
                let servo = matches!(cmd, ConsoleCommand::ServoJp(_));
                let what = if servo { "servo_jp" } else { "move_jp" };
                if !self.ready() || self.refuse {
                    out.push(Out::Warning(format!(
                        "{what}: arm not ready (state {}, homed {}), command ignored",
                        self.state, self.homed
                    )));
                    return;
                }
                let Some(goal) = self.clip(&js.position, out, what) else {
                    return;
                };
                if self.fixture == "clamp" {
                    self.release_for_insertion(goal[2], out);
                }
                if servo {
                    for j in 0..3 {
                        if (goal[j] - self.setpoint[j]).abs() > SERVO_STEP_WARN[j] {
                            out.push(Out::Note(format!(
                                "servo_jp: joint {} step {} larger than one control cycle reaches",
                                j + 1,
                                goal[j] - self.setpoint[j]
                            )));
                        }
                    }
                    if self.busy {
                        self.busy = false;
                        out.push(Out::GoalReached(false));
                        out.push(Out::State);
                    }
                    self.traj = None;
                    self.setpoint = goal;
                    let vel = if js.velocity.len() == 6 {
                        std::array::from_fn(|j| js.velocity[j])
                    } else {
                        [0.0; 6]
                    };
                    self.apply_setpoint(&vel);
                } else {
                    let mut axes = [Axis::default(); 6];
                    for j in 0..6 {
                        axes[j] = Axis {
                            pos: self.setpoint[j],
                            vel: 0.0,
                            goal: goal[j],
                        };
                    }
                    self.traj = Some(axes);
                    self.busy = true;
                    out.push(Out::State);
                }
            }
            ConsoleCommand::Hold => {
                if self.state == "ENABLED" {
                    if self.busy {
                        self.busy = false;
                        out.push(Out::GoalReached(false));
                        out.push(Out::State);
                    }
                    self.hold_here();
                }
            }
            ConsoleCommand::Free => {
                out.push(Out::Warning("free: not supported by the stand-in".into()))
            }
            ConsoleCommand::SetRatio(r)
            | ConsoleCommand::SetRatioV(r)
            | ConsoleCommand::SetRatioA(r) => {
                if *r > 0.0 && *r <= 1.0 {
                    self.ratio = *r;
                    if matches!(cmd, ConsoleCommand::SetRatio(_)) {
                        out.push(Out::Ratio(*r));
                    }
                } else {
                    out.push(Out::Warning(format!("set_ratio: {r} not in ]0, 1]")));
                }
            }
            ConsoleCommand::StateCommand(c) => {
                let from_fault_ok = matches!(c.as_str(), "disable" | "unhome");
                if self.state == "FAULT" && !from_fault_ok {
                    out.push(Out::Warning(format!(
                        "state_command {c:?} refused in FAULT (only disable, unhome)"
                    )));
                    return;
                }
                match c.as_str() {
                    "enable" => self.set_state("ENABLED", out),
                    "disable" => self.set_state("DISABLED", out),
                    "home" => {
                        if self.state != "ENABLED" {
                            out.push(Out::Warning("home: arm not enabled".into()));
                        } else {
                            self.busy = true;
                            self.homing_until = Some(self.t + 1.0);
                            out.push(Out::State);
                        }
                    }
                    "unhome" => {
                        self.homed = false;
                        out.push(Out::State);
                    }
                    "pause" | "resume" => {}
                    other => out.push(Out::Warning(format!("state_command {other:?} unknown"))),
                }
            }
        }
    }

    /// Applies a console event (the instrument and base frame are kept by the caller).
    pub fn event(&mut self, e: &Event, out: &mut Vec<Out>) {
        match e {
            Event::Unhome => {
                self.homed = false;
                out.push(Out::State);
            }
            Event::Home => {
                self.homed = true;
                out.push(Out::State);
            }
            Event::Enable => self.set_state("ENABLED", out),
            Event::Disable => self.set_state("DISABLED", out),
            Event::Tool(_) | Event::Base(_) => {}
        }
    }

    /// Joint positions 1-6 now (measured).
    pub fn q6(&self) -> [f64; 6] {
        let q = self.psm().joint_state().position;
        std::array::from_fn(|j| q[j])
    }

    /// Injects a fault.
    pub fn fault(&mut self, f: Fault, out: &mut Vec<Out>) {
        match f {
            Fault::Effort => self.effort_offset = 3.0,
            Fault::Estop => self.set_state("DISABLED", out),
            Fault::PidFault => {
                out.push(Out::Error("PSM1: injected fault".into()));
                self.set_state("FAULT", out);
            }
            Fault::Refuse => self.refuse = true,
            Fault::Silence | Fault::Invalid | Fault::Lose | Fault::IgnoreRatio => {}
        }
    }

    /// Advances to `t` (s) in physics steps of `dt` (s).
    pub fn advance(&mut self, t: f64, dt: f64, out: &mut Vec<Out>) {
        while self.t + dt <= t {
            self.t += dt;
            if let Some(until) = self.homing_until
                && self.t >= until
            {
                self.homing_until = None;
                self.homed = true;
                self.busy = false;
                out.push(Out::State);
            }
            if let Some(axes) = &mut self.traj {
                let mut done = true;
                let mut vel = [0.0; 6];
                for (j, a) in axes.iter_mut().enumerate() {
                    done &= a.step(
                        dt,
                        PSM_MAX_SPEED[j] * self.ratio,
                        PSM_MAX_ACCEL[j] * self.ratio,
                    );
                    self.setpoint[j] = a.pos;
                    vel[j] = a.vel;
                }
                self.apply_setpoint(&vel);
                if done {
                    self.traj = None;
                    self.busy = false;
                    out.push(Out::GoalReached(true));
                    out.push(Out::State);
                }
            }
            self.steps += 1;
            self.emu.advance_to(1 + self.steps * self.dt_ns);
            if self.state == "ENABLED" {
                let q = self.psm().joint_state().position;
                for j in 0..3 {
                    let e = (self.setpoint[j] - q[j]).abs();
                    if e > TRACKING_ERROR_LIMIT[j] {
                        out.push(Out::Error(format!(
                            "PSM1: tracking error on joint {} ({e}), arm faulted",
                            j + 1
                        )));
                        self.set_state("FAULT", out);
                        break;
                    }
                }
            }
            self.operator(out);
        }
    }

    /// The lab's operator of `--fixture clamp`.
    fn operator(&mut self, out: &mut Vec<Out>) {
        if self.fixture != "clamp" || self.clamp_engaged || !self.insertion_moved {
            return;
        }
        let js = self.psm().joint_state();
        let still = self.traj.is_none() && (0..3).all(|j| js.velocity[j].abs() < 1e-3);
        match (still, self.still_since) {
            (false, _) => self.still_since = None,
            (true, None) => self.still_since = Some(self.t),
            (true, Some(t0)) if self.t - t0 >= 0.5 => {
                self.psm_mut().set_environment(Environment::Clamp);
                self.clamp_engaged = true;
                self.insertion_moved = false;
                out.push(Out::Note(format!(
                    "operator: shaft clamped at insertion {:.4} m",
                    js.position[2]
                )));
            }
            _ => {}
        }
    }

    /// `measured_js` now.
    pub fn measured(&self, stamp: RosTime, rng: &mut SimRng, noise: f64) -> JointStateMsg {
        let js = self.psm().joint_state();
        let mut effort: Vec<f64> = (0..6).map(|j| js.effort[j]).collect();
        for e in effort.iter_mut().take(3) {
            *e += rng.normal(noise);
        }
        effort[0] += self.effort_offset;
        JointStateMsg {
            stamp,
            frame_id: String::new(),
            name: PSM_JOINT_NAMES.iter().map(|s| (*s).to_owned()).collect(),
            position: js.position[..6].to_vec(),
            velocity: js.velocity[..6].to_vec(),
            effort,
        }
    }

    /// `setpoint_js` now.
    pub fn setpoint_js(&self, stamp: RosTime) -> JointStateMsg {
        JointStateMsg {
            stamp,
            frame_id: String::new(),
            name: PSM_JOINT_NAMES.iter().map(|s| (*s).to_owned()).collect(),
            position: self.setpoint.to_vec(),
            velocity: Vec::new(),
            effort: Vec::new(),
        }
    }

    /// Ground truth of the shaft (for logs): joint 1-2 angles of the shaft.
    pub fn truth_q(&self) -> [f64; 2] {
        let t = self.psm().truth();
        [t.q_true[0], t.q_true[1]]
    }
}

/// The console's kinematics for its `tool_type` (none for an empty or unknown instrument).
fn tool_kinematics(tool: &str) -> Option<dvrk_compliance::PsmKinematics> {
    dvrk_compliance::instrument_from_tool_type(tool)
        .ok()
        .map(|i| dvrk_compliance::PsmKinematics::new(dvrk_compliance::ArmKind::Classic, i))
}

fn log_line(log: &mut Option<std::fs::File>, t: f64, kind: &str, detail: &str) {
    if let Some(f) = log {
        let line = serde_json::json!({"t_s": t, "kind": kind, "detail": detail});
        let _ = writeln!(f, "{line}");
        let _ = f.flush();
    }
}

fn command_name(c: &ConsoleCommand) -> String {
    match c {
        ConsoleCommand::MoveJp(js) => format!("move_jp {:?}", js.position),
        ConsoleCommand::ServoJp(js) => format!("servo_jp {:?}", js.position),
        ConsoleCommand::Hold => "hold".into(),
        ConsoleCommand::Free => "free".into(),
        ConsoleCommand::StateCommand(s) => format!("state_command {s}"),
        ConsoleCommand::SetRatio(r) => format!("set_ratio {r}"),
        ConsoleCommand::SetRatioV(r) => format!("set_ratio_v {r}"),
        ConsoleCommand::SetRatioA(r) => format!("set_ratio_a {r}"),
    }
}

/// Runs the stand-in until SIGINT/SIGTERM.
pub fn run(args: &CrtkArgs, arm: &str, scenario: &Scenario, io: &dvrk_io::IoConfig) -> Result<()> {
    if !(args.rate_hz > 0.0 && args.rate_hz <= 2000.0) {
        bail!("--crtk-rate {}: must be in ]0, 2000] Hz", num(args.rate_hz));
    }
    if !(args.effort_noise_nm >= 0.0 && args.effort_noise_nm < 1.0) {
        bail!(
            "--effort-noise-nm {}: must be in [0, 1)",
            num(args.effort_noise_nm)
        );
    }
    let mut faults: Vec<(Fault, f64)> = args
        .fault
        .iter()
        .map(|s| parse_fault(s))
        .collect::<Result<_>>()?;
    faults.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut events: Vec<(Event, f64)> = args
        .event
        .iter()
        .map(|s| parse_event(s))
        .collect::<Result<_>>()?;
    events.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut base = frame_pose(&parse_frame(&args.base_frame).context("--base-frame")?);
    let mut tool = args.tool.clone();
    let mut kin = tool_kinematics(&tool);
    let stdin_events = if args.events_stdin {
        let (tx, rx) = std::sync::mpsc::channel::<String>();
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Some(rx)
    } else {
        None
    };
    let mut log = match &args.command_log {
        Some(p) => {
            Some(std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?)
        }
        None => None,
    };
    let domain = dvrk_bridge::console::ros_domain_id()?;
    let mut server = ConsoleServer::new(arm, domain, &[])
        .with_context(|| format!("DDS endpoints of {arm} on domain {domain}"))?;
    let stop = crate::signals::StopFlag::install()?;
    let mut sim = ConsoleSim::new(scenario, io, &args.start, &args.fixture)?;
    let boards = match args.boards {
        Some(addr) => {
            let s = std::net::UdpSocket::bind(addr)
                .with_context(|| format!("--boards {addr}: binding the boards' UDP socket"))?;
            s.set_read_timeout(Some(Duration::from_micros(200)))?;
            tracing::info!(%addr, "answering the boards' protocol for the same arm");
            Some(s)
        }
        None => None,
    };
    let mut rx = vec![0u8; 4096];
    let mut tx = vec![0u8; 8192];
    let mut rng = SimRng::new(scenario.seed ^ 0x5eed);
    let dt = scenario.dt_s;
    let start = Instant::now();
    let stamp = dvrk_bridge::console::ros_now;
    server.publish_operating_state(&sim.operating_state(stamp()))?;
    server.publish_ratio(sim.ratio)?;
    server.publish_tool_type(&args.tool)?;
    tracing::info!(
        arm, domain, start = %args.start, fixture = %args.fixture, tool = %args.tool,
        "console stand-in: {arm} over DDS (CRTK), measured_js at {} Hz",
        args.rate_hz
    );
    log_line(&mut log, 0.0, "start", sim.state());
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let mut next_pub = start;
    let mut cmds = Vec::new();
    let mut outs = Vec::new();
    let mut silent = false;
    let mut invalid = false;
    // `lose@S`: the next move_jp, state_command, set_ratio
    let mut lose = [false; 3];
    let mut ignore_ratio = false;
    while !stop.raised() {
        let now = start.elapsed().as_secs_f64();
        while let Some(&(f, at)) = faults.first()
            && at <= now
        {
            faults.remove(0);
            log_line(&mut log, now, "fault", &format!("{f:?}"));
            match f {
                Fault::Silence => silent = true,
                Fault::Invalid => invalid = true,
                Fault::Lose => lose = [true; 3],
                Fault::IgnoreRatio => ignore_ratio = true,
                _ => sim.fault(f, &mut outs),
            }
        }
        if let Some(rx) = &stdin_events {
            while let Ok(line) = rx.try_recv() {
                let line = line.trim();
                let spec = match line.split_once('=') {
                    Some((k, v)) => format!("{k}@0={v}"),
                    None => format!("{line}@0"),
                };
                match parse_event(&spec) {
                    Ok((e, _)) => events.insert(0, (e, 0.0)),
                    Err(e) => tracing::warn!("stdin event {line:?}: {e:#}"),
                }
            }
        }
        while let Some((e, at)) = events.first().cloned()
            && at <= now
        {
            events.remove(0);
            log_line(&mut log, now, "event", &format!("{e:?}"));
            match &e {
                Event::Tool(t) => {
                    tool = t.clone();
                    kin = tool_kinematics(&tool);
                    server.publish_tool_type(&tool)?;
                }
                Event::Base(f) => base = frame_pose(f),
                _ => sim.event(&e, &mut outs),
            }
        }
        cmds.clear();
        let bad = server.poll(&mut cmds);
        if bad > 0 {
            log_line(&mut log, now, "undecodable", &bad.to_string());
        }
        for c in &cmds {
            let lost = match c {
                ConsoleCommand::MoveJp(_) => Some(0),
                ConsoleCommand::StateCommand(_) => Some(1),
                ConsoleCommand::SetRatio(_) => Some(2),
                _ => None,
            }
            .filter(|&i| std::mem::take(&mut lose[i]));
            let ignored = ignore_ratio && matches!(c, ConsoleCommand::SetRatio(_));
            if lost.is_some() || ignored {
                log_line(&mut log, now, "lost", &command_name(c));
                continue;
            }
            let kind = if c.is_motion() { "motion" } else { "command" };
            log_line(&mut log, now, kind, &command_name(c));
            sim.command(c, &mut outs);
        }
        sim.advance(now, dt, &mut outs);
        for o in outs.drain(..) {
            match o {
                Out::State => {
                    let s = sim.operating_state(stamp());
                    log_line(
                        &mut log,
                        now,
                        "state",
                        &format!("{} homed={} busy={}", s.state, s.is_homed, s.is_busy),
                    );
                    server.publish_operating_state(&s)?;
                }
                Out::GoalReached(v) => {
                    log_line(&mut log, now, "goal_reached", &v.to_string());
                    server.publish_goal_reached(v)?;
                }
                Out::Ratio(r) => server.publish_ratio(r)?,
                Out::Warning(w) => {
                    log_line(&mut log, now, "warning", &w);
                    tracing::warn!("{w}");
                    server.publish_warning(&format!("{arm}: {w}"))?;
                }
                Out::Error(e) => {
                    log_line(&mut log, now, "error", &e);
                    tracing::warn!("{e}");
                    server.publish_error(&e)?;
                }
                Out::Note(n) => {
                    log_line(&mut log, now, "note", &n);
                    tracing::info!("{n}");
                }
            }
        }
        let wall = Instant::now();
        if wall >= next_pub {
            next_pub += period;
            if next_pub < wall {
                next_pub = wall + period;
            }
            let st = if invalid { RosTime::default() } else { stamp() };
            if !silent && server.has_state_reader() {
                let m = sim.measured(st, &mut rng, args.effort_noise_nm);
                server.publish_js(&m, Some(&sim.setpoint_js(st)))?;
            }
            if !silent
                && server.has_pose_reader()
                && let Some(k) = &kin
            {
                let local = k.forward(&sim.q6());
                server.publish_cp(
                    &pose_msg(st, &format!("{arm}_base"), &(base * local)),
                    &pose_msg(st, &format!("{arm}_rcm"), &local),
                )?;
            }
        }
        match &boards {
            Some(sock) => {
                // the loop waits on the boards' socket: a request is answered at once
                if let Ok((n, from)) = sock.recv_from(&mut rx) {
                    sim.advance(start.elapsed().as_secs_f64(), dt, &mut outs);
                    if let Some(m) = sim.handle_board_request(&rx[..n], &mut tx) {
                        let _ = sock.send_to(&tx[..m], from);
                    }
                }
            }
            None => std::thread::sleep(Duration::from_micros(500)),
        }
    }
    let q = sim.truth_q();
    tracing::info!(
        "console stand-in stopped (shaft at {:.5}, {:.5} rad)",
        q[0],
        q[1]
    );
    log_line(&mut log, start.elapsed().as_secs_f64(), "stop", sim.state());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn new_sim(start: &str, fixture: &str) -> ConsoleSim {
        let io = crate::config::load_io(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../config/io/psm-classic.toml"),
        )
        .unwrap();
        ConsoleSim::new(&scenario(), &io, start, fixture).unwrap()
    }

    fn scenario() -> Scenario {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sim/clamp.toml");
        crate::config::load_scenario(&path).unwrap()
    }

    fn js(q: [f64; 6]) -> JointStateMsg {
        JointStateMsg {
            position: q.to_vec(),
            ..JointStateMsg::default()
        }
    }

    #[test]
    fn move_jp_is_busy_then_reaches_its_goal_within_the_limits() {
        let mut sim = new_sim("homed", "none");
        let mut out = Vec::new();
        let mut goal = sim.setpoint;
        goal[0] += 0.3;
        sim.command(&ConsoleCommand::MoveJp(js(goal)), &mut out);
        assert_eq!(out, [Out::State]);
        assert!(sim.busy);
        out.clear();
        // 0.3 rad at 90 deg/s and 90 deg/s^2: about 0.87 s
        sim.advance(0.5, 1e-4, &mut out);
        assert!(sim.busy && out.is_empty(), "{out:?}");
        sim.advance(1.5, 1e-4, &mut out);
        assert_eq!(out, [Out::GoalReached(true), Out::State]);
        assert!((sim.psm().joint_state().position[0] - goal[0]).abs() < 2e-3);
    }

    #[test]
    fn moves_are_refused_unless_enabled_and_homed() {
        for start in ["disabled", "enabled"] {
            let mut sim = new_sim(start, "none");
            let mut out = Vec::new();
            sim.command(&ConsoleCommand::MoveJp(js(sim.setpoint)), &mut out);
            assert!(
                matches!(&out[..], [Out::Warning(w)] if w.contains("not ready")),
                "{out:?}"
            );
            assert!(!sim.busy);
        }
    }

    #[test]
    fn fault_accepts_only_disable_and_unhome() {
        let mut sim = new_sim("homed", "none");
        let mut out = Vec::new();
        sim.fault(Fault::PidFault, &mut out);
        assert_eq!(sim.state(), "FAULT");
        out.clear();
        sim.command(&ConsoleCommand::StateCommand("enable".into()), &mut out);
        assert!(matches!(&out[..], [Out::Warning(_)]));
        sim.command(&ConsoleCommand::StateCommand("disable".into()), &mut out);
        assert_eq!(sim.state(), "DISABLED");
    }

    #[test]
    fn the_operator_clamps_after_an_insertion_move_and_releases_before_the_next() {
        let mut sim = new_sim("homed", "clamp");
        let mut out = Vec::new();
        sim.advance(1.0, 1e-4, &mut out);
        assert!(sim.clamp_engaged, "{out:?}");
        let mut goal = sim.setpoint;
        goal[2] += 0.02;
        sim.command(&ConsoleCommand::MoveJp(js(goal)), &mut out);
        assert!(!sim.clamp_engaged);
        sim.advance(1.3, 1e-4, &mut out);
        assert!(!sim.clamp_engaged, "still moving or settling");
        sim.advance(3.0, 1e-4, &mut out);
        assert!(sim.clamp_engaged);
    }
}
