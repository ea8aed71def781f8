//! Calibration procedures as pure state machines (paper section 3).
//!
//! A [`Runner`] takes the latest measured [`Sample`] (time, joint 1-3 positions and efforts) and
//! returns an [`Output`]: the joint 1-3 setpoint to command now, the status, and, when a step
//! has just finished, its averaged [`Record`]. It never touches a clock or any I/O, so the same
//! code drives the simulator in tests, the `calibrate` command, and any other loop.
//!
//! Three plans run on the runner:
//! - [`SweepPlan`]: the torque-offset sweep. No load; per joint and insertion depth, the joint
//!   goes from the low to the high end of its range in 5-degree steps and back, one averaged row
//!   per step and direction (both directions, so that friction cancels in the tau_0 average).
//! - [`ClampPlan`]: the clamp-beam experiment. Per joint and depth: release, move to the depth,
//!   wait for the clamp, then step the joint by `tip_step_m / L` rad in one direction until
//!   the effort in the direction of motion exceeds `reverse_effort_nm`, reverse until it does
//!   again on the other side, reverse again until past the start; one averaged row per step.
//!   Only the effort on the side the leg moves toward counts: right after a reversal it still
//!   reads past the threshold on the other side, and a motor that sticks for a step, or noise,
//!   may carry it a little further there.
//! - [`DivotPlan`]: the evaluation. With the tip in a divot, per joint and direction, push by
//!   the same steps until |effort| > `push_effort_nm`, then step back to the start.
//!
//! Each step: the setpoint ramps to the step's target at a bounded speed, the joint settles (it
//! moved less than `still_tolerance` over a `settle_s` window), then `samples_per_step` valid
//! samples are averaged. Invalid samples are skipped.
//!
//! Safety, checked on every valid sample and every new target: |effort| of joint 1 or 2 above
//! `effort_limit_nm`, a measured position or a target outside the joint limits, a step that does
//! not settle and average within `step_timeout_s`, or a leg that needs more than `max_steps_per_leg`
//! steps, aborts. After an abort the runner keeps returning the last safe setpoint (the setpoint
//! of the last step that completed without a violation) and the abort reason; every record
//! already returned stays valid, and the caller keeps them.
//!
//! Fixtures (clamp on or off, tip in the divot) are outside the robot's control: the runner
//! returns [`Status::AwaitFixture`] and holds its setpoint until the caller reports the fixture
//! ready with [`Runner::fixture_ready`].

/// Extra values the caller attaches to each sample (for example simulator ground truth). The
/// runner averages them with the sample and never reads them.
pub const AUX: usize = 8;

/// One measured sample of joints 1-3 (index 0..3: yaw, pitch, insertion).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    /// Caller's monotonic time (ns).
    pub t_ns: u64,
    /// A sample from a failed read is skipped (but time still passes for the timeouts).
    pub valid: bool,
    /// rad, rad, m.
    pub position: [f64; 3],
    /// N·m, N·m, N.
    pub effort: [f64; 3],
    /// Averaged alongside, see [`AUX`].
    pub aux: [f64; AUX],
}

/// Mean of the samples of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Averaged {
    /// Time of the last sample averaged (ns).
    pub t_ns: u64,
    pub position: [f64; 3],
    pub effort: [f64; 3],
    pub aux: [f64; AUX],
    /// The setpoint held while averaging.
    pub setpoint: [f64; 3],
    pub samples: u32,
}

/// One recorded step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// Joint under test, 1 or 2.
    pub joint: u8,
    /// Depth index (sweep, clamp) or push index (divot: `2 * (joint - 1)` for +, `+ 1` for -).
    pub depth_index: u32,
    /// Direction of the step that led here: +1, -1, or 0 for the row at the start position.
    pub direction: i8,
    pub averaged: Averaged,
}

/// What the caller must set up before the procedure continues.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fixture {
    /// Nothing touches the instrument (clamp released).
    Free,
    /// Clamp the shaft against the beam where it is now.
    Clamp {
        joint: u8,
        depth_index: u32,
        insertion_m: f64,
    },
    /// The tip is in the divot.
    Divot,
}

/// Why a procedure stopped early. Numbers only (`Copy`).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AbortReason {
    #[error("joint {joint}: |effort| {effort} exceeds the limit {limit}")]
    EffortLimit { joint: u8, effort: f64, limit: f64 },
    #[error("joint {joint}: measured position {position} outside the limits [{min}, {max}]")]
    JointLimit {
        joint: u8,
        position: f64,
        min: f64,
        max: f64,
    },
    #[error("joint {joint}: target {target} outside the limits [{min}, {max}]")]
    TargetLimit {
        joint: u8,
        target: f64,
        min: f64,
        max: f64,
    },
    #[error("step {step}: not settled and averaged after {waited_ns} ns (limit {limit_ns} ns)")]
    Timeout {
        step: u32,
        waited_ns: u64,
        limit_ns: u64,
    },
    #[error(
        "joint {joint} depth {depth_index}: {steps} steps in one leg without reaching the effort threshold"
    )]
    StepLimit {
        joint: u8,
        depth_index: u32,
        steps: u32,
    },
    #[error("sample time went backwards from {previous_ns} ns to {t_ns} ns")]
    TimeWentBack { previous_ns: u64, t_ns: u64 },
}

/// Where the runner is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Status {
    /// Moving, settling or averaging.
    Running,
    /// Holding; call [`Runner::fixture_ready`] once the fixture is set.
    AwaitFixture(Fixture),
    Done,
    Aborted(AbortReason),
}

/// What [`Runner::update`] returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    /// Joint 1-3 setpoint to command now.
    pub setpoint: [f64; 3],
    pub status: Status,
    /// Present on the update that completed a recorded step.
    pub record: Option<Record>,
}

/// Safety and step-execution settings shared by all plans.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunnerConfig {
    /// Abort when |effort| of joint 1 or 2 exceeds this (N·m). Default 1.5.
    pub effort_limit_nm: f64,
    /// `[min, max]` per joint 1-3 (rad, rad, m). Default: Classic PSM-like
    /// `[-1.5, 1.5]`, `[-0.8, 0.8]`, `[0.0, 0.24]`.
    pub joint_limits: [[f64; 2]; 3],
    /// Time allowed to settle and average one step (s). Default 5.
    pub step_timeout_s: f64,
    /// Setpoint speed limit per joint (rad/s, rad/s, m/s). Default 0.2, 0.2, 0.02.
    pub max_speed: [f64; 3],
    /// Length of the stillness window (s). Default 0.2.
    pub settle_s: f64,
    /// The joints moved less than this over a window: settled (rad or m). Default 2e-4.
    pub still_tolerance: f64,
    /// Samples averaged per step. Default 20.
    pub samples_per_step: u32,
    /// The mean effort of joints 1-2 over the second half of the stillness window differs
    /// from the first half's by less than this: the effort has settled too (N·m). A real
    /// controller creeps after a step, and its integrator keeps changing the effort while the
    /// position looks still. Default: infinite (position only).
    pub still_effort_nm: f64,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            effort_limit_nm: 1.5,
            joint_limits: [[-1.5, 1.5], [-0.8, 0.8], [0.0, 0.24]],
            step_timeout_s: 5.0,
            max_speed: [0.2, 0.2, 0.02],
            settle_s: 0.2,
            still_tolerance: 2e-4,
            samples_per_step: 20,
            still_effort_nm: f64::INFINITY,
        }
    }
}

/// What a plan asks the runner to do next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Op {
    /// Wait for the fixture.
    Fixture(Fixture),
    /// Ramp to `target`, settle, average; `record` says how to label the result, `None` for a
    /// step that is not recorded.
    Move {
        target: [f64; 3],
        record: Option<(u8, u32, i8)>,
    },
    Abort(AbortReason),
    Done,
}

/// Progress for a progress bar: `units` are (joint, depth) blocks of work.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    pub units_done: u32,
    pub units_total: u32,
    pub steps_done: u32,
}

/// A procedure: decides the next operation from the result of the last one.
pub trait Plan {
    /// `start` is the measured position when the run began; `last` is the averaged result of the
    /// step that just completed (`None` at the start and after a fixture).
    fn next(&mut self, start: &[f64; 3], last: Option<&Averaged>) -> Op;
    /// Blocks of work done and total.
    fn units(&self) -> (u32, u32);
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Begin,
    Fixture(Fixture),
    Ramp,
    Settle {
        t_ref: u64,
        q_ref: [f64; 3],
        moved: f64,
        t0: u64,
        /// Effort sums of joints 1-2 over the window's first and second halves, and counts.
        effort: EffortHalves,
    },
    Average {
        t0: u64,
    },
    Finished(Status),
}

/// Effort sums of joints 1-2 over the two halves of a stillness window.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct EffortHalves {
    sum: [[f64; 2]; 2],
    n: [u32; 2],
}

impl EffortHalves {
    fn add(&mut self, half: usize, effort: &[f64; 3]) {
        self.sum[half][0] += effort[0];
        self.sum[half][1] += effort[1];
        self.n[half] += 1;
    }

    /// Largest change of the mean effort from the first half to the second.
    fn drift(&self) -> f64 {
        if self.n[0] == 0 || self.n[1] == 0 {
            return 0.0;
        }
        let (a, b) = (f64::from(self.n[0]), f64::from(self.n[1]));
        (0..2)
            .map(|j| (self.sum[1][j] / b - self.sum[0][j] / a).abs())
            .fold(0.0, f64::max)
    }
}

/// Runs a [`Plan`] one sample at a time. Allocates nothing.
#[derive(Clone, Debug)]
pub struct Runner<P: Plan> {
    plan: P,
    cfg: RunnerConfig,
    phase: Phase,
    start: [f64; 3],
    setpoint: [f64; 3],
    safe_setpoint: [f64; 3],
    target: [f64; 3],
    record: Option<(u8, u32, i8)>,
    last_t_ns: Option<u64>,
    acc: Averaged,
    steps_done: u32,
}

impl<P: Plan> Runner<P> {
    pub fn new(plan: P, cfg: RunnerConfig) -> Self {
        Self {
            plan,
            cfg,
            phase: Phase::Begin,
            start: [0.0; 3],
            setpoint: [0.0; 3],
            safe_setpoint: [0.0; 3],
            target: [0.0; 3],
            record: None,
            last_t_ns: None,
            acc: Averaged::default(),
            steps_done: 0,
        }
    }

    pub fn plan(&self) -> &P {
        &self.plan
    }

    /// The target of the current step; the setpoint ramps to it at `max_speed`.
    pub fn target(&self) -> [f64; 3] {
        self.target
    }

    /// The setpoint is still ramping to the target.
    pub fn ramping(&self) -> bool {
        self.phase == Phase::Ramp
    }

    /// The robot reached the current target by a trajectory of its own (a real arm's console
    /// plans large moves itself, `move_jp`): the setpoint jumps to the target, and the step
    /// goes on with settling on the next sample. No effect unless ramping.
    pub fn target_reached_by_robot(&mut self) {
        if self.phase == Phase::Ramp {
            self.setpoint = self.target;
        }
    }

    pub fn progress(&self) -> Progress {
        let (units_done, units_total) = self.plan.units();
        Progress {
            units_done,
            units_total,
            steps_done: self.steps_done,
        }
    }

    /// The caller has set up the fixture the runner is waiting for. No effect otherwise.
    pub fn fixture_ready(&mut self) {
        if let Phase::Fixture(_) = self.phase {
            self.advance(None);
        }
    }

    fn abort(&mut self, reason: AbortReason) {
        self.setpoint = self.safe_setpoint;
        self.target = self.safe_setpoint;
        self.phase = Phase::Finished(Status::Aborted(reason));
    }

    /// Asks the plan for the next operation and starts it.
    fn advance(&mut self, last: Option<&Averaged>) {
        match self.plan.next(&self.start, last) {
            Op::Fixture(f) => self.phase = Phase::Fixture(f),
            Op::Move { target, record } => {
                for (j, (&t, lim)) in target.iter().zip(self.cfg.joint_limits.iter()).enumerate() {
                    if !(t >= lim[0] && t <= lim[1]) {
                        self.abort(AbortReason::TargetLimit {
                            joint: j as u8 + 1,
                            target: t,
                            min: lim[0],
                            max: lim[1],
                        });
                        return;
                    }
                }
                self.target = target;
                self.record = record;
                self.phase = Phase::Ramp;
            }
            Op::Abort(reason) => self.abort(reason),
            Op::Done => self.phase = Phase::Finished(Status::Done),
        }
    }

    fn output(&self, record: Option<Record>) -> Output {
        let status = match self.phase {
            Phase::Fixture(f) => Status::AwaitFixture(f),
            Phase::Finished(s) => s,
            _ => Status::Running,
        };
        Output {
            setpoint: self.setpoint,
            status,
            record,
        }
    }

    fn check_safety(&self, s: &Sample) -> Option<AbortReason> {
        for j in 0..2 {
            if s.effort[j].abs() > self.cfg.effort_limit_nm || !s.effort[j].is_finite() {
                return Some(AbortReason::EffortLimit {
                    joint: j as u8 + 1,
                    effort: s.effort[j],
                    limit: self.cfg.effort_limit_nm,
                });
            }
        }
        for (j, (&q, lim)) in s
            .position
            .iter()
            .zip(self.cfg.joint_limits.iter())
            .enumerate()
        {
            if !(q >= lim[0] && q <= lim[1]) {
                return Some(AbortReason::JointLimit {
                    joint: j as u8 + 1,
                    position: q,
                    min: lim[0],
                    max: lim[1],
                });
            }
        }
        None
    }

    /// Feeds the latest sample; returns what to command.
    pub fn update(&mut self, s: &Sample) -> Output {
        if let Phase::Finished(_) = self.phase {
            return self.output(None);
        }
        let dt_s = match self.last_t_ns {
            Some(prev) if s.t_ns < prev => {
                self.abort(AbortReason::TimeWentBack {
                    previous_ns: prev,
                    t_ns: s.t_ns,
                });
                return self.output(None);
            }
            // A long gap (a stalled source) must not turn into one big setpoint jump.
            Some(prev) => ((s.t_ns - prev) as f64 * 1e-9).min(0.05),
            None => 0.0,
        };
        self.last_t_ns = Some(s.t_ns);

        if self.phase == Phase::Begin {
            if !s.valid {
                return self.output(None);
            }
            self.start = s.position;
            self.setpoint = s.position;
            self.safe_setpoint = s.position;
            self.target = s.position;
        }
        if s.valid
            && let Some(reason) = self.check_safety(s)
        {
            self.abort(reason);
            return self.output(None);
        }
        if self.phase == Phase::Begin {
            self.advance(None);
        }

        let mut record = None;
        match self.phase {
            Phase::Ramp => {
                let mut reached = true;
                for j in 0..3 {
                    let step = self.cfg.max_speed[j] * dt_s;
                    let d = self.target[j] - self.setpoint[j];
                    if d.abs() <= step {
                        self.setpoint[j] = self.target[j];
                    } else {
                        self.setpoint[j] += step.copysign(d);
                        reached = false;
                    }
                }
                if reached && s.valid {
                    self.phase = Phase::Settle {
                        t_ref: s.t_ns,
                        q_ref: s.position,
                        moved: 0.0,
                        t0: s.t_ns,
                        effort: EffortHalves::default(),
                    };
                }
            }
            Phase::Settle {
                t_ref,
                q_ref,
                moved,
                t0,
                mut effort,
            } => {
                if let Some(r) = self.timed_out(s.t_ns, t0) {
                    self.abort(r);
                } else if s.valid {
                    // largest excursion from the window's first sample, over every sample
                    let moved = (0..3)
                        .map(|j| (s.position[j] - q_ref[j]).abs())
                        .fold(moved, f64::max);
                    let elapsed_s = s.t_ns.saturating_sub(t_ref) as f64 * 1e-9;
                    if elapsed_s < self.cfg.settle_s {
                        effort.add(usize::from(elapsed_s >= 0.5 * self.cfg.settle_s), &s.effort);
                        self.phase = Phase::Settle {
                            t_ref,
                            q_ref,
                            moved,
                            t0,
                            effort,
                        };
                    } else if moved <= self.cfg.still_tolerance
                        && effort.drift() <= self.cfg.still_effort_nm
                    {
                        self.acc = Averaged {
                            setpoint: self.setpoint,
                            ..Averaged::default()
                        };
                        self.phase = Phase::Average { t0 };
                    } else {
                        self.phase = Phase::Settle {
                            t_ref: s.t_ns,
                            q_ref: s.position,
                            moved: 0.0,
                            t0,
                            effort: EffortHalves::default(),
                        };
                    }
                }
            }
            Phase::Average { t0 } => {
                if let Some(r) = self.timed_out(s.t_ns, t0) {
                    self.abort(r);
                } else if s.valid {
                    let a = &mut self.acc;
                    for j in 0..3 {
                        a.position[j] += s.position[j];
                        a.effort[j] += s.effort[j];
                    }
                    for k in 0..AUX {
                        a.aux[k] += s.aux[k];
                    }
                    a.samples += 1;
                    a.t_ns = s.t_ns;
                    if a.samples >= self.cfg.samples_per_step.max(1) {
                        let n = f64::from(a.samples);
                        a.position.iter_mut().for_each(|v| *v /= n);
                        a.effort.iter_mut().for_each(|v| *v /= n);
                        a.aux.iter_mut().for_each(|v| *v /= n);
                        let done = *a;
                        self.steps_done += 1;
                        self.safe_setpoint = self.setpoint;
                        if let Some((joint, depth_index, direction)) = self.record {
                            record = Some(Record {
                                joint,
                                depth_index,
                                direction,
                                averaged: done,
                            });
                        }
                        self.advance(Some(&done));
                    }
                }
            }
            Phase::Begin | Phase::Fixture(_) | Phase::Finished(_) => {}
        }
        self.output(record)
    }

    fn timed_out(&self, t_ns: u64, t0: u64) -> Option<AbortReason> {
        let waited_ns = t_ns.saturating_sub(t0);
        let limit_ns = (self.cfg.step_timeout_s * 1e9) as u64;
        (waited_ns > limit_ns).then_some(AbortReason::Timeout {
            step: self.steps_done,
            waited_ns,
            limit_ns,
        })
    }
}

/// The paper's 14 clamp depths, 0.09 to 0.22 m.
pub fn default_depths_m() -> Vec<f64> {
    (0..14).map(|i| 0.09 + 0.01 * f64::from(i)).collect()
}

/// Torque-offset sweep settings.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepConfig {
    /// Joints to sweep (1, 2).
    pub joints: Vec<u8>,
    /// `[low, high]` per joint 1 and 2 (rad).
    pub range_rad: [[f64; 2]; 2],
    /// Default 5 degrees.
    pub step_rad: f64,
    /// Insertion depths (m). Default 0.09, 0.155, 0.22.
    pub depths_m: Vec<f64>,
}

impl Default for SweepConfig {
    fn default() -> Self {
        Self {
            joints: vec![1, 2],
            range_rad: [[-0.8, 0.8], [-0.5, 0.5]],
            step_rad: 5f64.to_radians(),
            depths_m: vec![0.09, 0.155, 0.22],
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum SweepPhase {
    Release,
    Depth,
    Up(u32),
    Down(u32),
    Home,
}

/// The torque-offset sweep (see the module docs).
#[derive(Clone, Debug)]
pub struct SweepPlan {
    cfg: SweepConfig,
    joint_i: usize,
    depth_i: usize,
    phase: SweepPhase,
    done: bool,
}

impl SweepPlan {
    pub fn new(cfg: SweepConfig) -> Self {
        Self {
            cfg,
            joint_i: 0,
            depth_i: 0,
            phase: SweepPhase::Release,
            done: false,
        }
    }

    fn angles(&self, j: usize) -> u32 {
        let [lo, hi] = self.cfg.range_rad[j];
        if self.cfg.step_rad > 0.0 && hi >= lo {
            ((hi - lo) / self.cfg.step_rad + 1e-9).floor() as u32
        } else {
            0
        }
    }
}

impl Plan for SweepPlan {
    fn next(&mut self, start: &[f64; 3], _last: Option<&Averaged>) -> Op {
        loop {
            let Some(&joint) = self.cfg.joints.get(self.joint_i) else {
                self.done = true;
                return Op::Done;
            };
            let Some(&l) = self.cfg.depths_m.get(self.depth_i) else {
                self.joint_i += 1;
                self.depth_i = 0;
                continue;
            };
            let j = usize::from(joint.clamp(1, 2)) - 1;
            let lo = self.cfg.range_rad[j][0];
            let n = self.angles(j);
            let at = |i: u32| {
                let mut t = [start[0], start[1], l];
                t[j] = lo + f64::from(i) * self.cfg.step_rad;
                t
            };
            let depth = self.depth_i as u32;
            match self.phase {
                SweepPhase::Release => {
                    self.phase = SweepPhase::Depth;
                    return Op::Fixture(Fixture::Free);
                }
                SweepPhase::Depth => {
                    self.phase = SweepPhase::Up(0);
                    return Op::Move {
                        target: [start[0], start[1], l],
                        record: None,
                    };
                }
                SweepPhase::Up(i) => {
                    self.phase = if i >= n {
                        SweepPhase::Down(n)
                    } else {
                        SweepPhase::Up(i + 1)
                    };
                    return Op::Move {
                        target: at(i),
                        record: Some((joint, depth, 1)),
                    };
                }
                SweepPhase::Down(i) => {
                    self.phase = if i == 0 {
                        SweepPhase::Home
                    } else {
                        SweepPhase::Down(i - 1)
                    };
                    return Op::Move {
                        target: at(i),
                        record: Some((joint, depth, -1)),
                    };
                }
                SweepPhase::Home => {
                    self.phase = SweepPhase::Depth;
                    self.depth_i += 1;
                    return Op::Move {
                        target: [start[0], start[1], l],
                        record: None,
                    };
                }
            }
        }
    }

    fn units(&self) -> (u32, u32) {
        let per = self.cfg.depths_m.len() as u32;
        let total = per * self.cfg.joints.len() as u32;
        if self.done {
            (total, total)
        } else {
            (self.joint_i as u32 * per + self.depth_i as u32, total)
        }
    }
}

/// Clamp-beam settings.
#[derive(Clone, Debug, PartialEq)]
pub struct ClampConfig {
    /// Joints to test (1, 2).
    pub joints: Vec<u8>,
    /// Insertion depths (m). Default [`default_depths_m`].
    pub depths_m: Vec<f64>,
    /// Step at the tip (m); the joint step is `tip_step_m / L`. Default 0.25e-3.
    pub tip_step_m: f64,
    /// Reverse when |effort| exceeds this (N·m). Default 1.0.
    pub reverse_effort_nm: f64,
    /// Direction of the first leg, +1 or -1. Default -1 (as the 2017 recordings).
    pub first_direction: i8,
    /// Abort a leg after this many steps. Default 400.
    pub max_steps_per_leg: u32,
}

impl Default for ClampConfig {
    fn default() -> Self {
        Self {
            joints: vec![1, 2],
            depths_m: default_depths_m(),
            tip_step_m: 0.25e-3,
            reverse_effort_nm: 1.0,
            first_direction: -1,
            max_steps_per_leg: 400,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum ClampPhase {
    Release,
    Depth,
    Clamp,
    StartRow,
    Leg { leg: u8, steps: u32 },
}

/// The clamp-beam experiment (see the module docs).
#[derive(Clone, Debug)]
pub struct ClampPlan {
    cfg: ClampConfig,
    joint_i: usize,
    depth_i: usize,
    phase: ClampPhase,
    /// Setpoint of the joint under test at the start of this depth, and the current one.
    q_start: f64,
    q_set: f64,
    done: bool,
}

impl ClampPlan {
    pub fn new(cfg: ClampConfig) -> Self {
        Self {
            cfg,
            joint_i: 0,
            depth_i: 0,
            phase: ClampPhase::Release,
            q_start: 0.0,
            q_set: 0.0,
            done: false,
        }
    }
}

impl Plan for ClampPlan {
    fn next(&mut self, start: &[f64; 3], last: Option<&Averaged>) -> Op {
        loop {
            let Some(&joint) = self.cfg.joints.get(self.joint_i) else {
                if self.phase == ClampPhase::Release {
                    self.phase = ClampPhase::Depth;
                    return Op::Fixture(Fixture::Free);
                }
                self.done = true;
                return Op::Done;
            };
            let Some(&l) = self.cfg.depths_m.get(self.depth_i) else {
                self.joint_i += 1;
                self.depth_i = 0;
                continue;
            };
            let j = usize::from(joint.clamp(1, 2)) - 1;
            let depth = self.depth_i as u32;
            let step = self.cfg.tip_step_m / l.max(1e-3);
            let target = |q: f64| {
                let mut t = [start[0], start[1], l];
                t[j] = q;
                t
            };
            match self.phase {
                ClampPhase::Release => {
                    self.phase = ClampPhase::Depth;
                    return Op::Fixture(Fixture::Free);
                }
                ClampPhase::Depth => {
                    self.phase = ClampPhase::Clamp;
                    return Op::Move {
                        target: [start[0], start[1], l],
                        record: None,
                    };
                }
                ClampPhase::Clamp => {
                    self.phase = ClampPhase::StartRow;
                    self.q_start = start[j];
                    self.q_set = start[j];
                    return Op::Fixture(Fixture::Clamp {
                        joint,
                        depth_index: depth,
                        insertion_m: l,
                    });
                }
                ClampPhase::StartRow => {
                    self.phase = ClampPhase::Leg { leg: 0, steps: 0 };
                    return Op::Move {
                        target: target(self.q_set),
                        record: Some((joint, depth, 0)),
                    };
                }
                ClampPhase::Leg { leg, steps } => {
                    let dir = if leg == 1 {
                        -self.cfg.first_direction.signum()
                    } else {
                        self.cfg.first_direction.signum()
                    };
                    // Decide on the step that just completed (none yet when steps == 0). A leg
                    // ends when the effort passes the threshold on the side it moves toward.
                    // Right after a reversal the effort is still past it on the other side, and
                    // with a motor that sticks the first step back may even push it a little
                    // further there: a test of |effort| against the leg's first effort ended
                    // those legs after one step.
                    if steps > 0
                        && let Some(a) = last
                    {
                        let over = a.effort[j] * f64::from(dir) > self.cfg.reverse_effort_nm;
                        let past_start = (self.q_set - self.q_start) * f64::from(dir) > 0.0;
                        if (leg < 2 && over) || (leg == 2 && past_start) {
                            if leg == 2 {
                                self.depth_i += 1;
                                self.phase = ClampPhase::Release;
                            } else {
                                self.phase = ClampPhase::Leg {
                                    leg: leg + 1,
                                    steps: 0,
                                };
                            }
                            continue;
                        }
                    }
                    if steps >= self.cfg.max_steps_per_leg {
                        return Op::Abort(AbortReason::StepLimit {
                            joint,
                            depth_index: depth,
                            steps,
                        });
                    }
                    self.q_set += f64::from(dir) * step;
                    self.phase = ClampPhase::Leg {
                        leg,
                        steps: steps + 1,
                    };
                    return Op::Move {
                        target: target(self.q_set),
                        record: Some((joint, depth, dir)),
                    };
                }
            }
        }
    }

    fn units(&self) -> (u32, u32) {
        let per = self.cfg.depths_m.len() as u32;
        let total = per * self.cfg.joints.len() as u32;
        if self.done {
            (total, total)
        } else {
            (
                (self.joint_i as u32 * per + self.depth_i as u32).min(total),
                total,
            )
        }
    }
}

/// Divot-push settings.
#[derive(Clone, Debug, PartialEq)]
pub struct DivotConfig {
    pub joints: Vec<u8>,
    /// Step at the tip (m); the joint step is `tip_step_m / L` at the starting insertion.
    pub tip_step_m: f64,
    /// Stop pushing when |effort| exceeds this (N·m). Default 1.0.
    pub push_effort_nm: f64,
    pub max_steps_per_leg: u32,
}

impl Default for DivotConfig {
    fn default() -> Self {
        Self {
            joints: vec![1, 2],
            tip_step_m: 0.25e-3,
            push_effort_nm: 1.0,
            max_steps_per_leg: 400,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum DivotPhase {
    Fixture,
    StartRow,
    Push { steps: u32 },
    Back { steps: u32 },
}

/// The divot evaluation (see the module docs).
#[derive(Clone, Debug)]
pub struct DivotPlan {
    cfg: DivotConfig,
    /// Index over (joint, direction) pushes.
    push_i: usize,
    phase: DivotPhase,
    q_set: f64,
    done: bool,
}

impl DivotPlan {
    pub fn new(cfg: DivotConfig) -> Self {
        Self {
            cfg,
            push_i: 0,
            phase: DivotPhase::Fixture,
            q_set: 0.0,
            done: false,
        }
    }
}

impl Plan for DivotPlan {
    fn next(&mut self, start: &[f64; 3], last: Option<&Averaged>) -> Op {
        loop {
            let Some(&joint) = self.cfg.joints.get(self.push_i / 2) else {
                self.done = true;
                return Op::Done;
            };
            let j = usize::from(joint.clamp(1, 2)) - 1;
            let dir: i8 = if self.push_i.is_multiple_of(2) { 1 } else { -1 };
            let push = 2 * (u32::from(joint) - 1) + (self.push_i % 2) as u32;
            let step = self.cfg.tip_step_m / start[2].max(1e-3);
            let target = |q: f64| {
                let mut t = *start;
                t[j] = q;
                t
            };
            match self.phase {
                DivotPhase::Fixture => {
                    self.phase = DivotPhase::StartRow;
                    return Op::Fixture(Fixture::Divot);
                }
                DivotPhase::StartRow => {
                    self.q_set = start[j];
                    self.phase = DivotPhase::Push { steps: 0 };
                    return Op::Move {
                        target: target(self.q_set),
                        record: Some((joint, push, 0)),
                    };
                }
                DivotPhase::Push { steps } => {
                    if steps > 0
                        && let Some(a) = last
                        && a.effort[j].abs() > self.cfg.push_effort_nm
                    {
                        self.phase = DivotPhase::Back { steps: 0 };
                        continue;
                    }
                    if steps >= self.cfg.max_steps_per_leg {
                        return Op::Abort(AbortReason::StepLimit {
                            joint,
                            depth_index: push,
                            steps,
                        });
                    }
                    self.q_set += f64::from(dir) * step;
                    self.phase = DivotPhase::Push { steps: steps + 1 };
                    return Op::Move {
                        target: target(self.q_set),
                        record: Some((joint, push, dir)),
                    };
                }
                DivotPhase::Back { steps } => {
                    if (self.q_set - start[j]) * f64::from(dir) <= 1e-12 {
                        self.push_i += 1;
                        self.phase = DivotPhase::StartRow;
                        continue;
                    }
                    let remaining = (self.q_set - start[j]).abs();
                    self.q_set -= f64::from(dir) * step.min(remaining);
                    self.phase = DivotPhase::Back { steps: steps + 1 };
                    return Op::Move {
                        target: target(self.q_set),
                        record: Some((joint, push, -dir)),
                    };
                }
            }
        }
    }

    fn units(&self) -> (u32, u32) {
        let total = 2 * self.cfg.joints.len() as u32;
        if self.done {
            (total, total)
        } else {
            ((self.push_i as u32).min(total), total)
        }
    }
}

/// Settings of [`Recorder`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecorderConfig {
    /// Joint under test, 1 or 2: its position and effort make the rows.
    pub joint: u8,
    /// Samples averaged per row. Default 20.
    pub samples_per_step: u32,
    /// Stillness window (s). Default 0.3.
    pub settle_s: f64,
    /// Still: every joint 1-3 stayed within this of the window's first sample. Default 2e-4.
    pub still_tolerance: f64,
    /// A new row needs the joint under test this far from the last row (rad). Default 5e-4.
    pub min_step_rad: f64,
    /// An insertion change beyond this starts a new depth (m). Default 0.002.
    pub depth_tolerance_m: f64,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            joint: 1,
            samples_per_step: 20,
            settle_s: 0.3,
            still_tolerance: 2e-4,
            min_step_rad: 5e-4,
            depth_tolerance_m: 0.002,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum RecPhase {
    Watch {
        t_ref: u64,
        q_ref: [f64; 3],
        moved: f64,
    },
    Average {
        q_ref: [f64; 3],
    },
}

/// Records calibration rows from a robot that something else moves (the dVRK's own tools):
/// whenever the arm has been still for `settle_s`, `samples_per_step` samples are averaged into a
/// row, if the joint under test has moved at least `min_step_rad` since the last row. The row's
/// direction is the sign of that move (0 for the first row of a depth); a change of insertion
/// starts a new depth. Rows are the same as the clamp and sweep procedures produce, so the same
/// fitting applies. Allocates nothing.
#[derive(Clone, Debug)]
pub struct Recorder {
    cfg: RecorderConfig,
    phase: Option<RecPhase>,
    acc: Averaged,
    last_row: Option<(f64, f64)>,
    depth_index: u32,
}

impl Recorder {
    pub fn new(cfg: RecorderConfig) -> Self {
        Self {
            cfg,
            phase: None,
            acc: Averaged::default(),
            last_row: None,
            depth_index: 0,
        }
    }

    fn watch(s: &Sample) -> RecPhase {
        RecPhase::Watch {
            t_ref: s.t_ns,
            q_ref: s.position,
            moved: 0.0,
        }
    }

    /// Feeds the latest sample; returns a row when one was completed.
    pub fn update(&mut self, s: &Sample) -> Option<Record> {
        if !s.valid {
            // a gap in the data restarts the stillness window
            self.phase = None;
            return None;
        }
        let j = usize::from(self.cfg.joint.clamp(1, 2)) - 1;
        let excursion = |q_ref: &[f64; 3]| {
            (0..3)
                .map(|k| (s.position[k] - q_ref[k]).abs())
                .fold(0.0, f64::max)
        };
        match self.phase {
            None => self.phase = Some(Self::watch(s)),
            Some(RecPhase::Watch {
                t_ref,
                q_ref,
                moved,
            }) => {
                let moved = moved.max(excursion(&q_ref));
                if moved > self.cfg.still_tolerance {
                    self.phase = Some(Self::watch(s));
                } else if s.t_ns.saturating_sub(t_ref) as f64 * 1e-9 >= self.cfg.settle_s {
                    self.acc = Averaged::default();
                    self.phase = Some(RecPhase::Average { q_ref });
                } else {
                    self.phase = Some(RecPhase::Watch {
                        t_ref,
                        q_ref,
                        moved,
                    });
                }
            }
            Some(RecPhase::Average { q_ref }) => {
                if excursion(&q_ref) > self.cfg.still_tolerance {
                    self.phase = Some(Self::watch(s));
                    return None;
                }
                let a = &mut self.acc;
                for k in 0..3 {
                    a.position[k] += s.position[k];
                    a.effort[k] += s.effort[k];
                }
                for k in 0..AUX {
                    a.aux[k] += s.aux[k];
                }
                a.samples += 1;
                a.t_ns = s.t_ns;
                if a.samples < self.cfg.samples_per_step.max(1) {
                    return None;
                }
                let n = f64::from(a.samples);
                a.position.iter_mut().for_each(|v| *v /= n);
                a.effort.iter_mut().for_each(|v| *v /= n);
                a.aux.iter_mut().for_each(|v| *v /= n);
                a.setpoint = a.position;
                let avg = *a;
                self.phase = Some(Self::watch(s));
                let (q, l) = (avg.position[j], avg.position[2]);
                let direction = match self.last_row {
                    None => 0,
                    Some((_, l_last)) if (l - l_last).abs() > self.cfg.depth_tolerance_m => {
                        self.depth_index += 1;
                        0
                    }
                    Some((q_last, _)) if (q - q_last).abs() >= self.cfg.min_step_rad => {
                        if q > q_last { 1 } else { -1 }
                    }
                    Some(_) => return None,
                };
                self.last_row = Some((q, l));
                return Some(Record {
                    joint: self.cfg.joint,
                    depth_index: self.depth_index,
                    direction,
                    averaged: avg,
                });
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A joint-space plant: each joint follows its setpoint with a 20 ms time constant; the
    /// efforts are tau0 plus, with a fixture holding the shaft, a spring on joints 1-2.
    struct Plant {
        t_ns: u64,
        q: [f64; 3],
        sp: [f64; 3],
        anchor: Option<[f64; 2]>,
        k: f64,
        tau0: f64,
        /// A motor that sticks: the joint moves only once its setpoint is farther than this
        /// (rad), and then to within it.
        stiction_rad: f64,
        /// Uniform effort noise, deterministic in time (N·m).
        noise_nm: f64,
    }

    impl Plant {
        fn new(q: [f64; 3]) -> Self {
            Self {
                t_ns: 1_000_000_000,
                q,
                sp: q,
                anchor: None,
                k: 20.0,
                tau0: 0.1,
                stiction_rad: 0.0,
                noise_nm: 0.0,
            }
        }

        fn sample(&self) -> Sample {
            let mut effort = [self.tau0, self.tau0, 0.0];
            if let Some(a) = self.anchor {
                for j in 0..2 {
                    effort[j] += self.k * (self.q[j] - a[j]);
                }
            }
            if self.noise_nm > 0.0 {
                // An LCG's high bits: uniform in [-1, 1), the same for a given time.
                let x = self
                    .t_ns
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                effort[0] += self.noise_nm * u;
                effort[1] -= self.noise_nm * u;
            }
            Sample {
                t_ns: self.t_ns,
                valid: true,
                position: self.q,
                effort,
                aux: [self.q[0], 0.0, 0.0, 0.0, 0.0, 7.0, 0.0, 0.0],
            }
        }

        fn step(&mut self, sp: [f64; 3]) {
            self.sp = sp;
            self.t_ns += 1_000_000;
            for j in 0..3 {
                let gap = self.sp[j] - self.q[j];
                let target = if gap.abs() > self.stiction_rad {
                    self.sp[j] - self.stiction_rad.copysign(gap)
                } else {
                    self.q[j]
                };
                self.q[j] += (target - self.q[j]) * (1.0 - (-0.001f64 / 0.02).exp());
            }
        }
    }

    struct Run {
        records: Vec<Record>,
        fixtures: Vec<Fixture>,
        status: Status,
        last_setpoint: [f64; 3],
    }

    fn drive<P: Plan>(runner: &mut Runner<P>, plant: &mut Plant, max: usize) -> Run {
        let mut run = Run {
            records: Vec::new(),
            fixtures: Vec::new(),
            status: Status::Running,
            last_setpoint: plant.q,
        };
        for _ in 0..max {
            let out = runner.update(&plant.sample());
            run.records.extend(out.record);
            run.status = out.status;
            run.last_setpoint = out.setpoint;
            match out.status {
                Status::AwaitFixture(f) => {
                    run.fixtures.push(f);
                    plant.anchor = match f {
                        Fixture::Free => None,
                        Fixture::Clamp { .. } | Fixture::Divot => Some([plant.q[0], plant.q[1]]),
                    };
                    runner.fixture_ready();
                }
                Status::Done | Status::Aborted(_) => break,
                Status::Running => {}
            }
            plant.step(out.setpoint);
        }
        run
    }

    const HOME: [f64; 3] = [0.1, -0.05, 0.12];

    /// A depth's rows as legs: each run of one direction and its length, in order.
    fn legs<R: std::borrow::Borrow<Record>>(rows: &[R]) -> Vec<(i8, usize)> {
        let mut legs: Vec<(i8, usize)> = Vec::new();
        for r in rows {
            let dir = r.borrow().direction;
            match legs.last_mut() {
                Some((d, n)) if *d == dir => *n += 1,
                _ => legs.push((dir, 1)),
            }
        }
        legs
    }

    /// A robot that plans its own large moves: the caller jumps the plant and tells the runner.
    #[test]
    fn a_target_reached_by_the_robot_skips_the_ramp() {
        let cfg = SweepConfig {
            joints: vec![1],
            range_rad: [[-0.2, 0.2], [-0.05, 0.05]],
            step_rad: 0.1,
            depths_m: vec![0.12],
        };
        let ramped = drive(
            &mut Runner::new(SweepPlan::new(cfg.clone()), RunnerConfig::default()),
            &mut Plant::new(HOME),
            2_000_000,
        );
        let mut r = Runner::new(SweepPlan::new(cfg), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        let mut moves = 0;
        let mut records = Vec::new();
        for _ in 0..200_000 {
            let out = r.update(&plant.sample());
            records.extend(out.record);
            match out.status {
                Status::Done => break,
                Status::Aborted(a) => panic!("{a}"),
                Status::AwaitFixture(_) => r.fixture_ready(),
                Status::Running => {}
            }
            if r.ramping() {
                // the robot's own trajectory: arrive at once
                plant.q = r.target();
                plant.sp = r.target();
                r.target_reached_by_robot();
                moves += 1;
            }
            plant.step(r.target());
        }
        assert_eq!(records.len(), ramped.records.len());
        assert!(records.len() >= 8, "{} rows", records.len());
        assert!(moves > records.len(), "{moves} moves");
        for (a, b) in records.iter().zip(&ramped.records) {
            assert!((a.averaged.position[0] - b.averaged.position[0]).abs() < 1e-3);
        }
    }

    /// With an effort tolerance, a creeping effort (a controller's integrator) delays the row
    /// until it has settled; without it, the row is taken as soon as the position is still.
    #[test]
    fn a_creeping_effort_delays_the_row_until_it_settles() {
        let cfg = SweepConfig {
            joints: vec![1],
            range_rad: [[0.1, 0.1], [-0.05, 0.05]],
            step_rad: 0.1,
            depths_m: vec![0.12],
        };
        let first_row_t = |still_effort_nm: f64| {
            let rc = RunnerConfig {
                still_effort_nm,
                ..RunnerConfig::default()
            };
            let mut r = Runner::new(SweepPlan::new(cfg.clone()), rc);
            let mut plant = Plant::new(HOME);
            let t_start = plant.t_ns;
            for _ in 0..100_000 {
                // the effort decays towards tau0 with a 1 s time constant
                let age_s = (plant.t_ns - t_start) as f64 * 1e-9;
                plant.tau0 = 0.1 + 0.5 * (-age_s).exp();
                let out = r.update(&plant.sample());
                if let Some(rec) = out.record {
                    return (rec.averaged.t_ns - t_start) as f64 * 1e-9;
                }
                if let Status::AwaitFixture(_) = out.status {
                    r.fixture_ready();
                }
                plant.step(out.setpoint);
            }
            panic!("no row");
        };
        let loose = first_row_t(f64::INFINITY);
        let strict = first_row_t(0.005);
        assert!(loose < 0.5, "{loose}");
        assert!(strict > loose + 1.0, "strict {strict} loose {loose}");
    }

    #[test]
    fn sweep_visits_every_angle_both_ways() {
        let cfg = SweepConfig {
            joints: vec![1, 2],
            range_rad: [[-0.1, 0.1], [-0.05, 0.05]],
            step_rad: 5f64.to_radians(),
            depths_m: vec![0.1, 0.2],
        };
        let mut r = Runner::new(SweepPlan::new(cfg), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        let run = drive(&mut r, &mut plant, 2_000_000);
        assert_eq!(run.status, Status::Done);
        assert_eq!(run.fixtures, vec![Fixture::Free]);
        // joint 1: 0.2 rad / 5 deg -> 2 steps -> 3 angles; joint 2: 0.1 rad -> 1 step -> 2 angles
        assert_eq!(run.records.len(), 2 * (2 * 3) + 2 * (2 * 2));
        let j1: Vec<&Record> = run.records.iter().filter(|r| r.joint == 1).collect();
        let dirs: Vec<i8> = j1.iter().take(6).map(|r| r.direction).collect();
        assert_eq!(dirs, vec![1, 1, 1, -1, -1, -1]);
        for (i, r) in j1.iter().take(3).enumerate() {
            let want = -0.1 + i as f64 * 5f64.to_radians();
            assert!((r.averaged.setpoint[0] - want).abs() < 1e-12);
            assert!((r.averaged.position[0] - want).abs() < 2e-4, "{r:?}");
            assert!((r.averaged.position[2] - 0.1).abs() < 2e-4);
            // the other joint is held at home
            assert!((r.averaged.position[1] - HOME[1]).abs() < 2e-4);
            assert_eq!(r.averaged.samples, 20);
            assert!((r.averaged.aux[5] - 7.0).abs() < 1e-12);
        }
        assert_eq!(r.progress().units_done, r.progress().units_total);
    }

    fn small_clamp() -> ClampConfig {
        ClampConfig {
            joints: vec![1],
            depths_m: vec![0.1, 0.15],
            ..ClampConfig::default()
        }
    }

    #[test]
    fn clamp_steps_out_back_and_past_the_start() {
        let mut r = Runner::new(ClampPlan::new(small_clamp()), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        let run = drive(&mut r, &mut plant, 5_000_000);
        assert_eq!(run.status, Status::Done);
        assert_eq!(
            run.fixtures,
            vec![
                Fixture::Free,
                Fixture::Clamp {
                    joint: 1,
                    depth_index: 0,
                    insertion_m: 0.1
                },
                Fixture::Free,
                Fixture::Clamp {
                    joint: 1,
                    depth_index: 1,
                    insertion_m: 0.15
                },
                Fixture::Free,
            ]
        );
        let d0: Vec<&Record> = run.records.iter().filter(|r| r.depth_index == 0).collect();
        assert_eq!(d0[0].direction, 0);
        // legs: -1 until |effort| > 1, +1 until |effort| > 1, -1 until past the start
        let legs = legs(&d0[1..]);
        assert_eq!(
            legs.iter().map(|l| l.0).collect::<Vec<_>>(),
            vec![-1, 1, -1]
        );
        let step = 0.25e-3 / 0.1;
        // effort rises by k * step = 0.05 N·m per step from tau0 = 0.1: 23 steps to pass -1
        assert_eq!(legs[0].1, 23);
        let last = d0.last().unwrap();
        assert!(last.averaged.setpoint[0] < HOME[0]);
        assert!(last.averaged.setpoint[0] > HOME[0] - 1.01 * step);
        for r in &d0 {
            let e = r.averaged.effort[0];
            assert!(e.abs() < 1.0 + 0.06, "{e}");
        }
    }

    /// A motor that sticks for the first step after a reversal leaves the effort where the leg
    /// ended, give or take its noise: the leg back must not end there. Judged by |effort|
    /// against the leg's first effort, as before, the legs back at 0.14 and 0.18 m here ended
    /// after one step, and those depths' rows were lost to the fit.
    #[test]
    fn a_motor_that_sticks_at_a_reversal_does_not_end_the_leg_back() {
        let depths_m = vec![0.1, 0.12, 0.14, 0.16, 0.18];
        let cfg = ClampConfig {
            joints: vec![1],
            depths_m: depths_m.clone(),
            ..ClampConfig::default()
        };
        let mut r = Runner::new(ClampPlan::new(cfg), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        plant.stiction_rad = 0.6 * 0.25e-3 / 0.18;
        plant.noise_nm = 0.05;
        let run = drive(&mut r, &mut plant, 20_000_000);
        assert_eq!(run.status, Status::Done);
        for (depth, l) in depths_m.iter().enumerate() {
            let rows: Vec<&Record> = run
                .records
                .iter()
                .filter(|r| r.depth_index as usize == depth)
                .collect();
            let legs = legs(&rows[1..]);
            assert_eq!(
                legs.iter().map(|l| l.0).collect::<Vec<_>>(),
                vec![-1, 1, -1],
                "depth {l} m: {legs:?}"
            );
            // Each leg out crosses the 2 N·m between the thresholds (k = 20 N·m/rad, at most
            // 0.05 N·m a step); the last one goes back to the start.
            assert!(legs[1].1 >= 40, "depth {l} m: {legs:?}");
            let efforts = rows.iter().map(|r| r.averaged.effort[0]);
            let (lo, hi) = efforts.fold((f64::MAX, f64::MIN), |(lo, hi), e| (lo.min(e), hi.max(e)));
            assert!(lo < -1.0 && hi > 1.0, "depth {l} m: effort {lo}..{hi}");
        }
    }

    #[test]
    fn clamp_records_fit_back_to_the_plant_stiffness() {
        use crate::fit::{DataRow, FitOptions, fit_depth};
        let mut r = Runner::new(ClampPlan::new(small_clamp()), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        plant.k = 25.0;
        let run = drive(&mut r, &mut plant, 5_000_000);
        let rows: Vec<DataRow> = run
            .records
            .iter()
            .filter(|r| r.depth_index == 1)
            .map(|r| DataRow {
                joint: r.joint,
                depth_index: r.depth_index,
                insertion_m: r.averaged.position[2],
                position_rad: r.averaged.position[0],
                effort_nm: r.averaged.effort[0],
                torque_offset_nm: 0.1,
                direction: r.direction,
            })
            .collect();
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert!((fit.stiffness_nm_per_rad - 25.0).abs() < 1e-6, "{fit:?}");
        assert!(fit.backlash_rad < 1e-6);
    }

    #[test]
    fn effort_limit_aborts_holding_the_last_safe_setpoint_and_keeping_data() {
        let cfg = ClampConfig {
            reverse_effort_nm: 5.0, // never reverses: the 1.5 N·m limit must stop it
            ..small_clamp()
        };
        let mut r = Runner::new(ClampPlan::new(cfg), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        let run = drive(&mut r, &mut plant, 5_000_000);
        let Status::Aborted(AbortReason::EffortLimit {
            joint: 1,
            effort,
            limit,
        }) = run.status
        else {
            panic!("{:?}", run.status);
        };
        assert!(effort.abs() > 1.5 && limit == 1.5);
        assert!(run.records.len() > 20);
        let last = run.records.last().unwrap();
        assert_eq!(run.last_setpoint, last.averaged.setpoint);
        // it stays aborted and keeps holding
        let out = r.update(&plant.sample());
        assert_eq!(out.status, run.status);
        assert_eq!(out.setpoint, last.averaged.setpoint);
        assert_eq!(out.record, None);
    }

    #[test]
    fn target_outside_joint_limits_aborts_before_moving() {
        let rc = RunnerConfig {
            joint_limits: [[-1.5, 1.5], [-0.8, 0.8], [0.0, 0.12]],
            ..RunnerConfig::default()
        };
        let mut r = Runner::new(ClampPlan::new(small_clamp()), rc);
        let mut plant = Plant::new([0.1, -0.05, 0.05]);
        let run = drive(&mut r, &mut plant, 100_000);
        assert_eq!(
            run.status,
            Status::Aborted(AbortReason::TargetLimit {
                joint: 3,
                target: 0.15,
                min: 0.0,
                max: 0.12
            })
        );
    }

    #[test]
    fn measured_position_outside_limits_aborts() {
        let mut r = Runner::new(ClampPlan::new(small_clamp()), RunnerConfig::default());
        let mut s = Plant::new(HOME).sample();
        assert_eq!(r.update(&s).status, Status::AwaitFixture(Fixture::Free));
        s.position[1] = 0.9;
        s.t_ns += 1000;
        assert!(matches!(
            r.update(&s).status,
            Status::Aborted(AbortReason::JointLimit { joint: 2, .. })
        ));
    }

    #[test]
    fn a_step_that_never_settles_times_out() {
        let mut r = Runner::new(
            SweepPlan::new(SweepConfig {
                joints: vec![1],
                depths_m: vec![0.12],
                ..SweepConfig::default()
            }),
            RunnerConfig::default(),
        );
        let mut plant = Plant::new(HOME);
        let mut status = Status::Running;
        for i in 0..20_000u64 {
            let mut s = plant.sample();
            // a joint that keeps oscillating by 1 mrad
            s.position[0] += if (i / 50) % 2 == 0 { 1e-3 } else { -1e-3 };
            let out = r.update(&s);
            status = out.status;
            if let Status::AwaitFixture(_) = status {
                r.fixture_ready();
            }
            if let Status::Aborted(_) = status {
                break;
            }
            plant.step(out.setpoint);
        }
        let Status::Aborted(AbortReason::Timeout {
            waited_ns,
            limit_ns,
            ..
        }) = status
        else {
            panic!("{status:?}");
        };
        assert_eq!(limit_ns, 5_000_000_000);
        assert!(waited_ns > limit_ns);
    }

    #[test]
    fn invalid_samples_are_not_averaged() {
        let mut r = Runner::new(
            DivotPlan::new(DivotConfig {
                joints: vec![1],
                ..DivotConfig::default()
            }),
            RunnerConfig::default(),
        );
        let mut plant = Plant::new(HOME);
        let mut first = None;
        for i in 0..100_000 {
            let mut s = plant.sample();
            if i % 3 == 0 {
                s.valid = false;
                s.effort = [99.0; 3];
                s.position = [9.0; 3];
            }
            let out = r.update(&s);
            if let Status::AwaitFixture(_) = out.status {
                plant.anchor = Some([plant.q[0], plant.q[1]]);
                r.fixture_ready();
            }
            if let Some(rec) = out.record {
                first = Some(rec);
                break;
            }
            assert!(out.status == Status::Running || matches!(out.status, Status::AwaitFixture(_)));
            plant.step(out.setpoint);
        }
        let rec = first.unwrap();
        assert_eq!(rec.direction, 0);
        assert_eq!(rec.averaged.samples, 20);
        assert!((rec.averaged.effort[0] - 0.1).abs() < 1e-3, "{rec:?}");
    }

    #[test]
    fn time_going_back_aborts() {
        let mut r = Runner::new(
            DivotPlan::new(DivotConfig::default()),
            RunnerConfig::default(),
        );
        let mut s = Plant::new(HOME).sample();
        r.update(&s);
        s.t_ns -= 1;
        assert!(matches!(
            r.update(&s).status,
            Status::Aborted(AbortReason::TimeWentBack { .. })
        ));
    }

    #[test]
    fn clamp_without_a_clamp_hits_the_step_limit() {
        let cfg = ClampConfig {
            max_steps_per_leg: 30,
            ..small_clamp()
        };
        let mut r = Runner::new(ClampPlan::new(cfg), RunnerConfig::default());
        let mut plant = Plant::new(HOME);
        let mut status = Status::Running;
        let mut records = 0;
        for _ in 0..5_000_000 {
            let out = r.update(&plant.sample());
            records += usize::from(out.record.is_some());
            status = out.status;
            match status {
                Status::AwaitFixture(_) => r.fixture_ready(), // but nothing is clamped
                Status::Running => {}
                _ => break,
            }
            plant.step(out.setpoint);
        }
        assert_eq!(
            status,
            Status::Aborted(AbortReason::StepLimit {
                joint: 1,
                depth_index: 0,
                steps: 30
            })
        );
        assert_eq!(records, 31);
    }

    #[test]
    fn divot_pushes_each_way_and_returns() {
        let mut r = Runner::new(
            DivotPlan::new(DivotConfig::default()),
            RunnerConfig::default(),
        );
        let mut plant = Plant::new(HOME);
        let run = drive(&mut r, &mut plant, 5_000_000);
        assert_eq!(run.status, Status::Done);
        assert_eq!(run.fixtures, vec![Fixture::Divot]);
        for push in 0..4u32 {
            let rows: Vec<&Record> = run
                .records
                .iter()
                .filter(|r| r.depth_index == push)
                .collect();
            let joint = 1 + (push / 2) as usize;
            let dir: i8 = if push % 2 == 0 { 1 } else { -1 };
            assert_eq!(rows[0].direction, 0);
            assert!(rows.iter().all(|r| r.joint as usize == joint));
            let peak = rows
                .iter()
                .map(|r| (r.averaged.effort[joint - 1] - 0.1) * f64::from(dir))
                .fold(f64::MIN, f64::max);
            assert!(peak > 0.85, "push {push}: {peak}");
            let last = rows.last().unwrap();
            assert_eq!(last.direction, -dir);
            assert!((last.averaged.setpoint[joint - 1] - HOME[joint - 1]).abs() < 1e-12);
        }
    }

    #[test]
    fn recorder_makes_one_row_per_still_step() {
        let mut rec = Recorder::new(RecorderConfig::default());
        let mut plant = Plant::new(HOME);
        plant.anchor = Some([HOME[0], HOME[1]]);
        let mut rows = Vec::new();
        // someone else steps joint 1: -3 steps, +5 steps, then a new depth, each held 0.6 s
        let mut sp = HOME;
        let mut moves: Vec<[f64; 3]> = vec![HOME];
        for d in [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0] {
            sp[0] += d * 0.0025;
            moves.push(sp);
        }
        sp[2] += 0.01;
        moves.push(sp);
        for target in moves {
            for _ in 0..600 {
                rows.extend(rec.update(&plant.sample()));
                plant.step(target);
            }
        }
        let dirs: Vec<(u32, i8)> = rows.iter().map(|r| (r.depth_index, r.direction)).collect();
        // the first row (at HOME, still) has no direction
        assert_eq!(
            dirs,
            vec![
                (0, 0),
                (0, -1),
                (0, -1),
                (0, -1),
                (0, 1),
                (0, 1),
                (0, 1),
                (0, 1),
                (0, 1),
                (1, 0)
            ]
        );
        assert!((rows[1].averaged.position[0] - (HOME[0] - 0.0025)).abs() < 2e-4);
        assert_eq!(rows[1].averaged.samples, 20);
    }

    #[test]
    fn recorder_skips_moving_and_invalid_data() {
        let mut rec = Recorder::new(RecorderConfig::default());
        let mut plant = Plant::new(HOME);
        let mut n = 0;
        // a joint that never stops moving gives no rows
        for i in 0..5000 {
            plant.step([
                HOME[0] + 0.1 * (f64::from(i) * 0.01).sin(),
                HOME[1],
                HOME[2],
            ]);
            n += usize::from(rec.update(&plant.sample()).is_some());
        }
        assert_eq!(n, 0);
        // every other sample invalid: the window keeps restarting, no row either
        let mut s = plant.sample();
        for i in 0..5000u64 {
            s.t_ns += 1_000_000;
            s.valid = i % 2 == 0;
            n += usize::from(rec.update(&s).is_some());
        }
        assert_eq!(n, 0);
    }
}
