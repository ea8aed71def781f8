//! `dvrk-sidecar calibrate torque-offset|clamp|divot`: runs a calibration procedure of
//! dvrk-compliance on the simulated PSM, in process and as fast as the machine allows (simulated
//! time, not wall time), through the same path as the service: emulated boards -> dvrk-io
//! `ArmReader` -> SI samples. The procedure's setpoints go to the simulated controller and its
//! fixture requests (clamp on/off, tip in the divot) become the simulator's environment.
//!
//! A progress bar shows (joint, depth) blocks; Ctrl-C stops cleanly and keeps every row collected
//! so far. An aborted procedure also writes its rows, then exits non-zero with the reason.
//!
//! `calibrate record` is for real robots, where the dVRK console owns the boards and its own tools
//! move the arm: it subscribes to the running service's `<prefix>/measured_js` and turns every
//! still period into an averaged row ([`dvrk_compliance::calibration::Recorder`]), in the same
//! file layout, so `fit` applies unchanged. With `--dynamics` it records every valid sample
//! instead, in the layout of `calibrate dynamics`, while the lab's own excitation moves joints 1
//! and 2 in free space (`fit --dynamics` reads it unchanged).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use dvrk_compliance::calibration::{
    AUX, ClampConfig, ClampPlan, DivotConfig, DivotPlan, Fixture, Plan, Record, Runner,
    RunnerConfig, Sample, Status, SweepConfig, SweepPlan,
};
use dvrk_compliance::fit::{self, DataRow, FitOptions};
use dvrk_io::reader::{AccessMode, ArmReader};
use dvrk_io::{ArmSample, IoConfig};
use dvrk_sim::{Environment, Motion, Scenario, sim_port};

use super::data::{self, DivotRow, DivotTruth};
use crate::text::num;

/// The finest and the coarsest step `calibrate torque-offset --step-deg` takes (degrees): below
/// half a degree the steps are within the joints' settling error of each other, and the sweep
/// runs into the thousands of steps; above 10 the table misses a counterbalance's bend.
const MIN_STEP_DEG: f64 = 0.5;
const MAX_STEP_DEG: f64 = 10.0;

/// Simulator read period: one sample per millisecond, like the dVRK's 1 kHz PID.
const PERIOD_NS: u64 = 1_000_000;

/// `calibrate <procedure> ...`
#[derive(Clone, Debug, clap::Args)]
pub struct CalibrateArgs {
    #[command(subcommand)]
    pub procedure: Procedure,
}

/// The procedures.
#[derive(Clone, Debug, clap::Subcommand)]
pub enum Procedure {
    /// Unloaded sweep of joints 1 and 2 in 5-degree steps (`--step-deg`) at a few depths (tau_0).
    TorqueOffset(SimArgs),
    /// Clamp-beam experiment at 14 depths, joints 1 and 2 (stiffness and backlash).
    Clamp(SimArgs),
    /// Tip in a divot, each joint pushed both ways (evaluation data).
    Divot(SimArgs),
    /// Free-space multi-sine excitation of joints 1 and 2 at a few depths (about a minute): the
    /// rows `fit --dynamics` identifies the internal-torque model from (issue 10).
    Dynamics(super::dynamics_cmd::DynamicsArgs),
    /// Write the `calibrate dynamics` excitation as a trajectory file (time, joint positions and
    /// velocities) for a lab to replay on a real arm with the console (e.g. a crtk servo_jp
    /// script) while `calibrate record --dynamics` records it.
    Trajectory(super::dynamics_cmd::TrajectoryArgs),
    /// Real robot: record from the running sidecar's measured_js while the dVRK's own tools move
    /// the arm. Without --dynamics: averaged rows, one per still step of --joint (clamp or sweep
    /// data for `fit --clamp/--torque-offset`). With --dynamics: one row per valid sample, the
    /// file of `calibrate dynamics`, while a free-space excitation of joints 1-2 runs (e.g. the
    /// `calibrate trajectory` file replayed by a crtk script); for `fit --dynamics`.
    Record(RecordArgs),
}

/// Options of `calibrate record`.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// The running service's configuration (its `prefix` names the topics to record).
    #[arg(long, default_value = "config/sidecar.toml")]
    pub config: PathBuf,
    /// Data file to write (CSV), rewritten after every new row.
    #[arg(long)]
    pub out: PathBuf,
    /// Joint under test (1 = yaw, 2 = pitch); not with --dynamics, which records both.
    #[arg(
        long,
        value_parser = clap::value_parser!(u8).range(1..=2),
        required_unless_present = "dynamics",
        conflicts_with = "dynamics"
    )]
    pub joint: Option<u8>,
    /// Torque-offset sweep file(s) whose fitted tau_0 fills the torque_offset_nm column.
    #[arg(long = "torque-offset", conflicts_with = "dynamics")]
    pub torque_offset: Vec<PathBuf>,
    /// Stillness window before a row is averaged (s).
    #[arg(long, default_value_t = 0.3, conflicts_with = "dynamics")]
    pub settle_s: f64,
    /// Stop after this many rows (default: until Ctrl-C or --seconds).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Record dynamics rows (`t_s,q1_rad,q2_rad,q3_m,effort1_nm,effort2_nm`, one per valid
    /// sample, time from the samples' own monotonic stamps) for `fit --dynamics`. Gaps of more
    /// than 0.5 s (the arm stopped publishing valid samples) start a new segment of the fit.
    #[arg(long)]
    pub dynamics: bool,
    /// With --dynamics: stop after this many seconds of samples (default: until Ctrl-C or
    /// --rows). The file is written when the recording ends, Ctrl-C included.
    #[arg(long)]
    pub seconds: Option<f64>,
    /// With --dynamics: the rate (Hz) at which the excitation sends its set points, when it
    /// steps them (e.g. 100 for a crtk `servo_jp` script at a console's `measured_js` rate).
    /// Written into the file as `# commanded_hz:`, so that `fit --dynamics` averages the
    /// controller's ripple at each step over one period. Leave it out for a smooth excitation.
    #[arg(long, requires = "dynamics")]
    pub commanded_hz: Option<f64>,
}

/// Options shared by the procedures, on the simulator (`--config SCENARIO`) or on a real arm
/// through its console (`--robot ros2:PSM1`).
#[derive(Clone, Debug, clap::Args)]
pub struct SimArgs {
    /// Simulator scenario (config/sim/*.toml): seed, time step, start pose, noise, shaft truth.
    /// Its environment and motion are replaced by the procedure's. Not with --robot.
    #[arg(long, required_unless_present = "robot", conflicts_with = "robot")]
    pub config: Option<PathBuf>,
    /// A real arm through the dVRK console's CRTK interface over DDS: `ros2:ARM` (e.g.
    /// `ros2:PSM1`), on the domain of ROS_DOMAIN_ID (default 0).
    #[arg(long, value_name = "ros2:ARM")]
    pub robot: Option<String>,
    /// Data file to write (CSV).
    #[arg(long)]
    pub out: PathBuf,
    /// Board conversion config used by the emulator and the reader (simulator only).
    #[arg(long, default_value = "config/io/psm-classic.toml")]
    pub io: PathBuf,
    /// Joints to run (1 = yaw, 2 = pitch).
    #[arg(long, value_delimiter = ',', default_values_t = [1u8, 2])]
    pub joints: Vec<u8>,
    /// Insertion depths (m); the procedure's default when absent.
    #[arg(long, value_delimiter = ',')]
    pub depths: Vec<f64>,
    /// Clamp only: torque-offset sweep file(s); their fitted tau_0 fills the torque_offset_nm
    /// column. Without it the column is 0 and tau_ext includes tau_0.
    #[arg(long = "torque-offset")]
    pub torque_offset: Vec<PathBuf>,
    /// Torque-offset only: the sweep's step (degrees, 0.5 to 10; default 5, the paper's). A
    /// finer step follows an internal torque that bends sharply (e.g. a counterbalance spring)
    /// at the cost of more steps: 1 degree is five times the 5-degree sweep's.
    #[arg(long)]
    pub step_deg: Option<f64>,
    /// Effort limit that aborts (N·m).
    #[arg(long, default_value_t = 1.5)]
    pub effort_limit_nm: f64,
    /// Stillness window before averaging (s); with --robot the default is 0.3.
    #[arg(long)]
    pub settle_s: Option<f64>,
    /// Hide the progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// With --robot: answer the operator prompts (pausing a few seconds at each) and the plan's
    /// confirmation. It never enables or homes an arm.
    #[arg(long)]
    pub yes: bool,
    /// With --robot: print the plan and exit without sending anything.
    #[arg(long)]
    pub dry_run: bool,
    /// With --robot: ask the console to enable and home the arm first, and wait for it.
    #[arg(long)]
    pub enable: bool,
    /// With --robot: trajectory_j/set_ratio of the console's move_jp (0 < ratio <= 1).
    #[arg(long, default_value_t = 0.2)]
    pub ratio: f64,
    /// With --robot: where rows come from. `console`: its measured_js (100 Hz); `sidecar`: the
    /// 1.5 kHz measured_js of a sidecar service running for that arm (commands still follow the
    /// console's measured_js).
    #[arg(long, default_value = "console", value_parser = ["console", "sidecar"])]
    pub measure: String,
    /// With --measure sidecar: the service's prefix (default: the arm's name, as `serve` names
    /// its topics).
    #[arg(long)]
    pub sidecar_prefix: Option<String>,
    /// With --robot and --yes: the pause after each operator prompt (s).
    #[arg(long, default_value_t = 2.0)]
    pub prompt_pause_s: f64,
}

impl SimArgs {
    /// Checks every argument before anything is opened or written.
    pub fn validate(&self, name: &str) -> anyhow::Result<()> {
        if let Some(j) = self.joints.iter().find(|&&j| j != 1 && j != 2) {
            bail!("--joints {j}: joints must be 1 (yaw) or 2 (pitch)");
        }
        if self.joints.is_empty() {
            bail!("--joints: give at least one joint (1, 2)");
        }
        let [lo, hi] = super::console_run::CONSOLE_JOINT_LIMITS[2];
        for &d in &self.depths {
            if !(d.is_finite() && d > lo && d <= hi) {
                bail!(
                    "--depths {}: each depth must be a number of metres in ]{lo}, {hi}]",
                    num(d)
                );
            }
        }
        if !(self.effort_limit_nm.is_finite()
            && self.effort_limit_nm > 0.0
            && self.effort_limit_nm <= 3.0)
        {
            bail!(
                "--effort-limit-nm {}: must be in ]0, 3] N·m (the PSM's joints 1-2 effort cap is 3.32)",
                num(self.effort_limit_nm)
            );
        }
        if let Some(s) = self.settle_s
            && !(s.is_finite() && s > 0.0 && s <= 10.0)
        {
            bail!("--settle-s {}: must be in ]0, 10] s", num(s));
        }
        if !(self.ratio > 0.0 && self.ratio <= 1.0) {
            bail!("--ratio {}: must be in ]0, 1]", num(self.ratio));
        }
        if !(self.prompt_pause_s.is_finite() && (0.0..=60.0).contains(&self.prompt_pause_s)) {
            bail!(
                "--prompt-pause-s {}: must be in [0, 60] s",
                num(self.prompt_pause_s)
            );
        }
        if name != "clamp" && !self.torque_offset.is_empty() {
            bail!("--torque-offset: only for calibrate clamp");
        }
        if let Some(step) = self.step_deg {
            if name != "torque-offset" {
                bail!("--step-deg: only for calibrate torque-offset");
            }
            if !(step.is_finite() && (MIN_STEP_DEG..=MAX_STEP_DEG).contains(&step)) {
                bail!(
                    "--step-deg {}: must be in [{MIN_STEP_DEG}, {MAX_STEP_DEG}] degrees",
                    num(step)
                );
            }
        }
        if let Some(r) = &self.robot {
            robot_arm(r)?;
        } else if self.measure != "console" || self.sidecar_prefix.is_some() {
            bail!("--measure sidecar and --sidecar-prefix: only with --robot");
        }
        data::check_output_path(&self.out)?;
        Ok(())
    }
}

/// The arm of `--robot ros2:ARM`.
pub fn robot_arm(robot: &str) -> anyhow::Result<String> {
    let Some(arm) = robot.strip_prefix("ros2:") else {
        bail!("--robot {robot:?}: expected ros2:ARM, e.g. ros2:PSM1");
    };
    dvrk_bridge::validate_arm(arm).with_context(|| format!("--robot {robot:?}"))?;
    Ok(arm.to_owned())
}

/// Result of a simulator run.
pub struct SimRun {
    pub records: Vec<Record>,
    pub status: Status,
    /// Ctrl-C (or the caller's stop flag) ended the run.
    pub stopped: bool,
    pub samples: u64,
}

use crate::config::{load_io, load_scenario};

/// Runs `plan` on the simulated PSM until it is done, aborts, or `stop` is set. `on_progress`
/// is called every 1000 samples.
pub fn run_sim<P: Plan>(
    plan: P,
    rc: RunnerConfig,
    scenario: &Scenario,
    io: IoConfig,
    stop: &AtomicBool,
    mut on_progress: impl FnMut(&Runner<P>),
) -> anyhow::Result<SimRun> {
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
    let mut port = sim_port(&sc, &io).context("building the simulated PSM")?;
    port.link_mut().advance_to(0);
    let mut reader = ArmReader::new(port, io, AccessMode::Exclusive);
    let mut runner = Runner::new(plan, rc);
    let mut arm = ArmSample::default();
    let mut run = SimRun {
        records: Vec::new(),
        status: Status::Running,
        stopped: false,
        samples: 0,
    };
    let mut t_ns = 0u64;
    loop {
        if stop.load(Ordering::Relaxed) {
            run.stopped = true;
            break;
        }
        t_ns += PERIOD_NS;
        reader.port_mut().link_mut().advance_to(t_ns);
        // A failed read leaves `arm.valid` false; the runner skips it and its timeouts run on.
        let _ = reader.read(t_ns, &mut arm);
        let truth = reader.port_mut().link_mut().emulator().psm().truth();
        let mut aux = [0.0; AUX];
        aux[..3].copy_from_slice(&arm.position[3..6]);
        aux[3..6].copy_from_slice(&truth.tip_position_m);
        aux[6..8].copy_from_slice(&truth.q_true[..2]);
        let sample = Sample {
            t_ns,
            valid: arm.valid,
            position: [arm.position[0], arm.position[1], arm.position[2]],
            effort: [arm.effort[0], arm.effort[1], arm.effort[2]],
            aux,
        };
        let out = runner.update(&sample);
        run.samples += 1;
        let psm = reader.port_mut().link_mut().emulator_mut().psm_mut();
        for (j, &sp) in out.setpoint.iter().enumerate() {
            psm.set_setpoint(j, sp);
        }
        run.records.extend(out.record);
        run.status = out.status;
        match out.status {
            Status::AwaitFixture(f) => {
                psm.set_environment(match f {
                    Fixture::Free => Environment::Free,
                    Fixture::Clamp { .. } => Environment::Clamp,
                    Fixture::Divot => divot,
                });
                runner.fixture_ready();
            }
            Status::Done | Status::Aborted(_) => break,
            Status::Running => {}
        }
        if run.samples.is_multiple_of(1000) {
            on_progress(&runner);
        }
    }
    Ok(run)
}

/// Runner settings for the simulator: defaults, the simulator's joint limits, and the options.
fn runner_config(sc: &Scenario, args: &SimArgs) -> RunnerConfig {
    let p = &sc.physics;
    let limits: [[f64; 2]; 3] = std::array::from_fn(|j| [p.position_min[j], p.position_max[j]]);
    RunnerConfig {
        effort_limit_nm: args.effort_limit_nm,
        joint_limits: limits,
        settle_s: args.settle_s.unwrap_or(0.1),
        ..RunnerConfig::default()
    }
}

/// tau_0(q) in a fitted table, read as the parameter file's table is
/// ([`dvrk_compliance::torque_offset::interpolate`]), so that the clamp rows are fitted under the
/// tau_0 the compensator will subtract.
pub(crate) fn lookup(table: &fit::TorqueOffsetFit, q: f64) -> f64 {
    dvrk_compliance::torque_offset::interpolate(&table.position_rad, &table.effort_nm, q)
}

/// Clamp or sweep records as calibration rows; `offsets` fill the torque-offset column.
pub fn to_rows(records: &[Record], offsets: &[fit::TorqueOffsetFit]) -> Vec<DataRow> {
    records
        .iter()
        .map(|r| {
            let j = usize::from(r.joint.clamp(1, 2)) - 1;
            let q = r.averaged.position[j];
            DataRow {
                joint: r.joint,
                depth_index: r.depth_index,
                insertion_m: r.averaged.position[2],
                position_rad: q,
                effort_nm: r.averaged.effort[j],
                torque_offset_nm: offsets
                    .iter()
                    .find(|t| t.joint == r.joint)
                    .map_or(0.0, |t| lookup(t, q)),
                direction: r.direction,
            }
        })
        .collect()
}

/// Divot records as divot rows, with the simulator's truth.
pub fn to_divot_rows(records: &[Record]) -> Vec<DivotRow> {
    records
        .iter()
        .map(|r| {
            let a = &r.averaged;
            DivotRow {
                push_index: r.depth_index,
                joint: r.joint,
                direction: r.direction,
                t_s: a.t_ns as f64 * 1e-9,
                position: [
                    a.position[0],
                    a.position[1],
                    a.position[2],
                    a.aux[0],
                    a.aux[1],
                    a.aux[2],
                ],
                effort: a.effort,
                truth: Some(DivotTruth {
                    position_rad: [a.aux[6], a.aux[7]],
                    tip_m: [a.aux[3], a.aux[4], a.aux[5]],
                }),
            }
        })
        .collect()
}

fn progress_bar(quiet: bool, what: &str) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(1);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{prefix} [{bar:30}] {pos}/{len} blocks, {msg} ({elapsed})",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(what.to_owned());
    bar
}

/// Runs `calibrate`.
pub fn run_calibrate(args: &CalibrateArgs) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    // Ctrl-Z (SIGTSTP) aborts as Ctrl-C does: a calibration moving an arm is never suspended
    // in mid-motion (its last servo_jp would stay with the console, and the stop would end
    // RustDDS's event loop, so no hold could follow).
    for sig in [
        signal_hook::consts::SIGINT,
        signal_hook::consts::SIGTERM,
        signal_hook::consts::SIGTSTP,
    ] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .context("installing the Ctrl-C and Ctrl-Z handlers")?;
    }
    run_procedure(&args.procedure, &stop)
}

/// The `prefix` of a sidecar configuration file (default `PSM1` when absent).
fn config_prefix(path: &Path) -> anyhow::Result<String> {
    // Bounded and never blocking, as every configuration read (a FIFO without a writer hung
    // here, and /dev/zero read until memory ran out).
    let text = crate::config::read_file(path)?;
    let table: toml::Table = text
        .parse()
        .with_context(|| format!("parsing {}", path.display()))?;
    match table.get("prefix") {
        None => Ok(dvrk_ipc::DEFAULT_PREFIX.to_owned()),
        Some(toml::Value::String(p)) => Ok(p.clone()),
        Some(other) => bail!(
            "{}: prefix = {other}; expected a string such as \"PSM1\"",
            path.display()
        ),
    }
}

fn sweep_offsets(paths: &[PathBuf], joints: &[u8]) -> anyhow::Result<Vec<fit::TorqueOffsetFit>> {
    let mut seen = 0;
    let sweep = data::read_files(paths, &[], &mut seen)?;
    let offsets = joints
        .iter()
        .filter(|j| sweep.iter().any(|r| r.joint == **j))
        .map(|&j| fit::fit_torque_offset(&sweep, j, &FitOptions::default()))
        .collect::<Result<Vec<_>, _>>()
        .context("fitting the torque-offset sweep")?;
    if offsets.is_empty() {
        tracing::warn!(
            "no --torque-offset sweep: the torque_offset_nm column is 0, so tau_ext includes tau_0"
        );
    }
    Ok(offsets)
}

/// A subscription to `<prefix>/measured_js` of the running service, for both `calibrate record`
/// modes; the node is returned to be kept alive as long as the subscription.
pub(super) fn subscribe_measured_js(
    prefix: &str,
) -> anyhow::Result<(
    dvrk_ipc::Subscription<dvrk_ipc::JointStateV2, dvrk_ipc::iceoryx2::service::ipc::Service>,
    dvrk_ipc::ServiceNames,
    dvrk_ipc::iceoryx2::node::Node<dvrk_ipc::iceoryx2::service::ipc::Service>,
)> {
    use dvrk_ipc::iceoryx2::service::ipc::Service;
    use dvrk_ipc::{JointStateV2, NOMINAL_PERIOD, ServiceNames, Subscription, Topic};
    let names = ServiceNames::new(prefix).with_context(|| format!("prefix {prefix}"))?;
    let node = dvrk_ipc::create_node::<Service>("dvrk-sidecar-calibrate-record", None)
        .context("creating the iceoryx2 node")?;
    let sub = Subscription::<JointStateV2, Service>::new(
        &node,
        &names,
        Topic::MeasuredJs,
        NOMINAL_PERIOD,
    )
    .with_context(|| format!("subscribing to {prefix}/measured_js"))?;
    Ok((sub, names, node))
}

/// `calibrate record`: subscribes to `<prefix>/measured_js` of the running service and turns
/// still periods into rows ([`dvrk_compliance::calibration::Recorder`]).
pub fn run_record(a: &RecordArgs, stop: &AtomicBool) -> anyhow::Result<()> {
    use dvrk_compliance::calibration::{Recorder, RecorderConfig};
    use dvrk_ipc::Topic;

    if a.dynamics {
        return super::dynamics_cmd::record_live(a, &config_prefix(&a.config)?, stop);
    }
    if let Some(s) = a.seconds {
        bail!(
            "--seconds {}: only with --dynamics (still-period rows stop with --rows or Ctrl-C)",
            num(s)
        );
    }
    let Some(joint) = a.joint else {
        bail!("--joint: give the joint under test (1 or 2), or --dynamics");
    };
    let prefix = config_prefix(&a.config)?;
    let offsets = sweep_offsets(&a.torque_offset, &[joint])?;
    let (mut sub, names, node) = subscribe_measured_js(&prefix)?;
    let mut rec = Recorder::new(RecorderConfig {
        joint,
        settle_s: a.settle_s,
        ..RecorderConfig::default()
    });
    let mut records: Vec<Record> = Vec::new();
    let limit = a.rows.unwrap_or(usize::MAX);
    let mut silence = crate::watch::SilenceReporter::for_domain(node.config());
    eprintln!(
        "recording joint {} from {prefix}/measured_js; move the arm with the dVRK tools, Ctrl-C to stop",
        joint
    );
    while !stop.load(Ordering::Relaxed) && records.len() < limit {
        let before = records.len();
        let update = sub
            .wait_with(|msg| {
                let s = Sample {
                    t_ns: msg.header.sample_t_ns,
                    valid: msg.header.valid != 0,
                    position: [msg.position[0], msg.position[1], msg.position[2]],
                    effort: [msg.effort[0], msg.effort[1], msg.effort[2]],
                    aux: [0.0; AUX],
                };
                records.extend(rec.update(&s));
            })
            .context("waiting for samples")?;
        silence.report(&update, names.topic(Topic::MeasuredJs).as_str());
        if records.len() > before {
            let mut buf = super::provenance::Provenance::now(&prefix, None)
                .lines()
                .into_bytes();
            data::write_rows(&mut buf, &to_rows(&records, &offsets))?;
            data::write_atomically(&a.out, &buf)?;
            let r = records[records.len() - 1];
            eprintln!(
                "row {}: depth {} direction {:+} q {:.5} rad effort {:.3} N·m",
                records.len(),
                r.depth_index,
                r.direction,
                r.averaged.position[usize::from(joint) - 1],
                r.averaged.effort[usize::from(joint) - 1]
            );
        }
    }
    eprintln!("{} rows in {}", records.len(), a.out.display());
    Ok(())
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum SimKind {
    Sweep,
    Clamp,
    Divot,
}

/// Runs one procedure with an external stop flag (the command passes its Ctrl-C flag).
pub fn run_procedure(procedure: &Procedure, stop: &AtomicBool) -> anyhow::Result<()> {
    match procedure {
        Procedure::TorqueOffset(a) => run_sim_procedure(SimKind::Sweep, a, stop),
        Procedure::Clamp(a) => run_sim_procedure(SimKind::Clamp, a, stop),
        Procedure::Divot(a) => run_sim_procedure(SimKind::Divot, a, stop),
        Procedure::Record(r) => run_record(r, stop),
        Procedure::Dynamics(a) => super::dynamics_cmd::run(a, stop),
        Procedure::Trajectory(a) => super::dynamics_cmd::run_trajectory(a),
    }
}

/// One of the three plans, so a caller builds it once for either robot.
pub enum AnyPlan {
    Sweep(SweepPlan),
    Clamp(ClampPlan),
    Divot(DivotPlan),
}

impl Plan for AnyPlan {
    fn next(
        &mut self,
        start: &[f64; 3],
        last: Option<&dvrk_compliance::calibration::Averaged>,
    ) -> dvrk_compliance::calibration::Op {
        match self {
            AnyPlan::Sweep(p) => p.next(start, last),
            AnyPlan::Clamp(p) => p.next(start, last),
            AnyPlan::Divot(p) => p.next(start, last),
        }
    }
    fn units(&self) -> (u32, u32) {
        match self {
            AnyPlan::Sweep(p) => p.units(),
            AnyPlan::Clamp(p) => p.units(),
            AnyPlan::Divot(p) => p.units(),
        }
    }
}

fn build_plan(kind: SimKind, a: &SimArgs) -> (AnyPlan, String) {
    match kind {
        SimKind::Sweep => {
            let mut cfg = SweepConfig {
                joints: a.joints.clone(),
                ..SweepConfig::default()
            };
            if !a.depths.is_empty() {
                cfg.depths_m = a.depths.clone();
            }
            if let Some(step) = a.step_deg {
                cfg.step_rad = step.to_radians();
            }
            let text = format!(
                "torque-offset sweep: joints {:?}, depths {:?} m; each joint from {:?} rad in \
                 {:.4} rad steps, up and back down, one row per step; nothing may touch the \
                 instrument",
                cfg.joints, cfg.depths_m, cfg.range_rad, cfg.step_rad
            );
            (AnyPlan::Sweep(SweepPlan::new(cfg)), text)
        }
        SimKind::Clamp => {
            let mut cfg = ClampConfig {
                joints: a.joints.clone(),
                ..ClampConfig::default()
            };
            if !a.depths.is_empty() {
                cfg.depths_m = a.depths.clone();
            }
            let text = format!(
                "clamp: joints {:?}, depths {:?} m; per joint and depth the shaft is clamped, \
                 then the joint steps {:.2} mm at the tip (tip_step / L rad) until |effort| > \
                 {} N·m, reverses to the same effort on the other side, and returns past the \
                 start (at most {} steps per leg)",
                cfg.joints,
                cfg.depths_m,
                cfg.tip_step_m * 1e3,
                cfg.reverse_effort_nm,
                cfg.max_steps_per_leg
            );
            (AnyPlan::Clamp(ClampPlan::new(cfg)), text)
        }
        SimKind::Divot => {
            let cfg = DivotConfig {
                joints: a.joints.clone(),
                ..DivotConfig::default()
            };
            let text = format!(
                "divot: joints {:?} pushed each way by {:.2} mm at the tip per step until \
                 |effort| > {} N·m, then back to the start; the tip stays in the divot",
                cfg.joints,
                cfg.tip_step_m * 1e3,
                cfg.push_effort_nm
            );
            (AnyPlan::Divot(DivotPlan::new(cfg)), text)
        }
    }
}

/// The instrument the simulated PSM carries (its kinematics are the large needle driver's).
pub const SIM_INSTRUMENT: &str = "LARGE_NEEDLE_DRIVER:400006";

/// Writes the rows of a run after its provenance block; an existing file is left as it is when
/// there is no row.
fn write_records(
    kind: SimKind,
    a: &SimArgs,
    records: &[Record],
    prov: &super::provenance::Provenance,
) -> anyhow::Result<bool> {
    let with_truth = a.robot.is_none();
    if records.is_empty() && std::fs::symlink_metadata(&a.out).is_ok() {
        eprintln!("no row collected: {} is left as it was", a.out.display());
        return Ok(false);
    }
    let mut buf = prov.lines().into_bytes();
    match kind {
        SimKind::Divot => {
            let mut rows = to_divot_rows(records);
            if !with_truth {
                rows.iter_mut().for_each(|r| r.truth = None);
            }
            data::write_divot(&mut buf, &rows)?
        }
        SimKind::Clamp => {
            let offsets = sweep_offsets(&a.torque_offset, &a.joints)?;
            data::write_rows(&mut buf, &to_rows(records, &offsets))?
        }
        SimKind::Sweep => data::write_rows(&mut buf, &to_rows(records, &[]))?,
    }
    data::write_atomically(&a.out, &buf)?;
    Ok(true)
}

fn run_sim_procedure(kind: SimKind, a: &SimArgs, stop: &AtomicBool) -> anyhow::Result<()> {
    let name = match kind {
        SimKind::Sweep => "torque-offset",
        SimKind::Clamp => "clamp",
        SimKind::Divot => "divot",
    };
    a.validate(name)?;
    if kind == SimKind::Clamp {
        // read before moving anything: a bad sweep file must not cost a run
        sweep_offsets(&a.torque_offset, &a.joints)?;
    }
    if let Some(robot) = &a.robot {
        return super::console_run::run_procedure(kind, a, &robot_arm(robot)?, stop);
    }
    let Some(config) = &a.config else {
        bail!("--config SCENARIO (simulator) or --robot ros2:ARM (a real arm): one is needed");
    };
    let sc = load_scenario(config)?;
    let io = load_io(&a.io)?;
    let rc = runner_config(&sc, a);
    let bar = progress_bar(a.quiet, name);
    let tick = |done: u32, total: u32, steps: u32| {
        bar.set_length(u64::from(total));
        bar.set_position(u64::from(done));
        bar.set_message(format!("{steps} steps"));
    };
    let (plan, _) = build_plan(kind, a);
    let run = run_sim(plan, rc, &sc, io, stop, |r| {
        let p = r.progress();
        tick(p.units_done, p.units_total, p.steps_done)
    })?;
    bar.finish_and_clear();

    let prov = super::provenance::Provenance::now(
        &format!("simulator ({})", config.display()),
        Some(SIM_INSTRUMENT),
    );
    write_records(kind, a, &run.records, &prov)?;
    let simulated_s = run.samples as f64 * PERIOD_NS as f64 * 1e-9;
    eprintln!(
        "{name}: {} rows written to {} ({simulated_s:.1} s simulated)",
        run.records.len(),
        a.out.display()
    );
    match run.status {
        Status::Aborted(reason) => bail!(
            "{name} aborted: {reason}; the {} rows collected before are in {}",
            run.records.len(),
            a.out.display()
        ),
        _ if run.stopped => {
            eprintln!("{name}: stopped by signal; the data so far is kept");
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Builds the plan of `kind` and its description (for the console shell).
pub fn plan_for(kind: SimKind, a: &SimArgs) -> (AnyPlan, String) {
    build_plan(kind, a)
}

/// Writes the rows (for the console shell): no truth columns.
pub fn write_console_records(
    kind: SimKind,
    a: &SimArgs,
    records: &[Record],
    prov: &super::provenance::Provenance,
) -> anyhow::Result<bool> {
    write_records(kind, a, records, prov)
}

#[cfg(test)]
mod tests {
    use super::super::evaluate::evaluate;
    use super::*;
    use dvrk_compliance::{ArmKind, ComplianceConfig, PsmKinematics, instrument};

    fn repo_file(rel: &str) -> PathBuf {
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
        manifest
            .ancestors()
            .map(|d| d.join(rel))
            .find(|p| p.is_file())
            .unwrap_or_else(|| panic!("{rel} not found above {}", manifest.display()))
    }

    fn args(out: PathBuf, depths: Vec<f64>, sweep: Vec<PathBuf>) -> SimArgs {
        SimArgs {
            config: Some(repo_file("config/sim/clamp.toml")),
            robot: None,
            out,
            io: repo_file("config/io/psm-classic.toml"),
            joints: vec![2],
            depths,
            torque_offset: sweep,
            step_deg: None,
            effort_limit_nm: 1.5,
            settle_s: Some(0.1),
            quiet: true,
            yes: false,
            dry_run: false,
            enable: false,
            ratio: 0.2,
            measure: "console".into(),
            sidecar_prefix: None,
            prompt_pause_s: 2.0,
        }
    }

    /// Collect -> fit -> evaluate on the simulator, joint 2 at 4 depths (the full 14-depth,
    /// two-joint run is the `calibrate` command; this keeps the test to seconds).
    #[test]
    fn simulator_end_to_end_recovers_the_truth_and_improves_the_tip() {
        let dir = std::env::temp_dir().join(format!("dvrk-calib-e2e-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let stop = AtomicBool::new(false);
        let sweep = dir.join("sweep.csv");
        run_procedure(
            &Procedure::TorqueOffset(args(sweep.clone(), vec![0.13], vec![])),
            &stop,
        )
        .unwrap();
        let clamp = dir.join("clamp.csv");
        let depths = vec![0.09, 0.13, 0.17, 0.22];
        run_procedure(
            &Procedure::Clamp(args(clamp.clone(), depths, vec![sweep.clone()])),
            &stop,
        )
        .unwrap();

        let mut seen = 0;
        let rows = data::read_files(&[clamp], &[], &mut seen).unwrap();
        let sweep_rows = data::read_files(&[sweep], &[], &mut seen).unwrap();
        let opts = FitOptions::default();
        let j = fit::fit_joint(&rows, 2, &opts).unwrap();
        let sc = load_scenario(&repo_file("config/sim/clamp.toml")).unwrap();
        let truth = sc.physics.shaft;
        for i in 0..=26 {
            let l = 0.09 + 0.005 * f64::from(i);
            let rel = fit::eval_cubic(&j.inverse_compliance_nm_per_rad, l)
                / truth.stiffness_nm_per_rad(1, l);
            assert!((rel - 1.0).abs() < 0.05, "1/K at {l}: {rel}");
        }
        let delta = truth.backlash_rad[1];
        assert!(
            (j.backlash_rad / delta - 1.0).abs() < 0.2,
            "backlash {} vs {delta}",
            j.backlash_rad
        );

        let t0 = fit::fit_torque_offset(&sweep_rows, 2, &opts).unwrap();
        let params = dvrk_compliance::ComplianceParams {
            model: dvrk_compliance::ModelKind::Paper,
            joint: vec![dvrk_compliance::JointParams {
                index: 2,
                backlash_rad: j.backlash_rad,
                tau_min_nm: 0.2,
                inverse_compliance_nm_per_rad: j.inverse_compliance_nm_per_rad,
                insertion_range_m: j.insertion_range_m,
                inverse_compliance_rel_sigma: None,
                backlash_rel_sigma: None,
                torque_offset: dvrk_compliance::TorqueOffsetParams {
                    position_rad: t0.position_rad,
                    effort_nm: t0.effort_nm,
                },
                hysteresis: None,
                dynamics: None,
            }],
        };
        let cfg = ComplianceConfig::from_params(params).unwrap();

        let divot = dir.join("divot.csv");
        run_procedure(
            &Procedure::Divot(args(divot.clone(), vec![], vec![])),
            &stop,
        )
        .unwrap();
        let rows = data::read_divot(&divot).unwrap();
        let fk = PsmKinematics::new(
            ArmKind::Classic,
            instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        let e = evaluate(&cfg, &fk, &rows);
        let t = e[0].tip_error.unwrap();
        // 25%, as in tests/calibration.rs: since the simulator's distal part has weight
        // (issue 20 item 3), the divot holds it too, and the stateless evaluation (one joint per
        // row, no dynamics) counts that weight as spring torque.
        assert!(
            t.after_mean_mm <= 0.25 * t.before_mean_mm,
            "tip error before {} mm, after {} mm",
            t.before_mean_mm,
            t.after_mean_mm
        );
        assert!(e[0].corrected.std_rad < 0.2 * e[0].uncorrected.std_rad);
    }

    #[test]
    fn stop_flag_keeps_the_rows_collected_so_far() {
        let dir = std::env::temp_dir().join(format!("dvrk-calib-stop-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let sc = load_scenario(&repo_file("config/sim/clamp.toml")).unwrap();
        let io = load_io(&repo_file("config/io/psm-classic.toml")).unwrap();
        let stop = AtomicBool::new(false);
        let plan = DivotPlan::new(DivotConfig::default());
        let run = run_sim(plan, RunnerConfig::default(), &sc, io, &stop, |r| {
            if r.progress().steps_done >= 5 {
                stop.store(true, Ordering::Relaxed);
            }
        })
        .unwrap();
        assert!(run.stopped);
        assert_eq!(run.status, Status::Running);
        assert!(run.records.len() >= 5);
    }

    #[test]
    fn effort_limit_abort_writes_the_data_and_fails() {
        let dir = std::env::temp_dir().join(format!("dvrk-calib-abort-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("divot.csv");
        let mut a = args(out.clone(), vec![], vec![]);
        a.effort_limit_nm = 0.6; // below the 1.0 N·m push: must abort
        let err = format!(
            "{:#}",
            run_procedure(&Procedure::Divot(a), &AtomicBool::new(false)).unwrap_err()
        );
        assert!(
            err.contains("aborted") && err.contains("exceeds the limit"),
            "{err}"
        );
        let rows = data::read_divot(&out).unwrap();
        assert!(rows.len() > 3);
    }
}
