//! `calibrate dynamics` and the file it writes: a free-space excitation of joints 1 and 2 (a
//! multi-sine over part of the joint range at a few insertion depths, about a minute) on the
//! simulator, recorded through the emulated boards and the reader, one row per cycle:
//!
//! ```text
//! t_s,q1_rad,q2_rad,q3_m,effort1_nm,effort2_nm
//! ```
//!
//! `fit --dynamics FILE` identifies the internal-torque model from it
//! ([`dvrk_compliance::fit_dynamics`]). Each depth is a segment of its own; segments are separated
//! by a gap of one second in `t_s`, where the fit restarts its filter.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use dvrk_compliance::DynamicsSample;
use dvrk_io::ArmSample;
use dvrk_io::reader::{AccessMode, ArmReader};
use dvrk_sim::{Environment, Motion, sim_port};

use crate::config::{load_io, load_scenario};
use crate::text::num;

/// The header of a dynamics file.
pub const HEADER: &str = "t_s,q1_rad,q2_rad,q3_m,effort1_nm,effort2_nm";

/// `calibrate dynamics --config S.toml --out dyn.csv [--depths ..] [--seconds-per-depth N]`
#[derive(Clone, Debug, clap::Args)]
pub struct DynamicsArgs {
    /// Simulator scenario (config/sim/*.toml): seed, time step, start pose, noise, transmission.
    /// Its environment and motion are replaced by free space and the excitation. Not with
    /// --robot.
    #[arg(long, required_unless_present = "robot", conflicts_with = "robot")]
    pub config: Option<PathBuf>,
    /// A real arm through the dVRK console's CRTK interface over DDS (`ros2:PSM1`): the
    /// excitation is played through servo_jp at the console's measured_js rate, slowed so its
    /// speed and acceleration stay within 80% of the PSM's move limits (90 deg/s, 90 deg/s²),
    /// and rows are a sidecar service's measured_js or the console's (see --measure).
    #[arg(long, value_name = "ros2:ARM")]
    pub robot: Option<String>,
    /// With --robot: where rows come from. `sidecar`: the 1.5 kHz measured_js of a sidecar
    /// service running for that arm (checked to read the console's arm before anything moves),
    /// which `fit --dynamics` averages over the console's command period (the file records that
    /// rate); `console`: its measured_js (100 Hz), where the effort is seen at one phase of the
    /// controller's response to each servo_jp step, which biases the fit; `auto`: `sidecar`
    /// when such a service publishes within 5 s, else `console`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "console", "sidecar"])]
    pub measure: String,
    /// With --measure sidecar: the service's prefix (default: the arm's name, as `serve` names
    /// its topics).
    #[arg(long)]
    pub sidecar_prefix: Option<String>,
    /// With --robot: the operator prompt and the plan's confirmation are answered (never
    /// enables an arm).
    #[arg(long)]
    pub yes: bool,
    /// With --robot: print the plan and exit without sending anything.
    #[arg(long)]
    pub dry_run: bool,
    /// With --robot: ask the console to enable and home the arm first.
    #[arg(long)]
    pub enable: bool,
    /// With --robot: effort limit of joints 1-2 that aborts (N·m).
    #[arg(long, default_value_t = 1.5)]
    pub effort_limit_nm: f64,
    /// With --robot: trajectory_j/set_ratio for the move_jp to the start.
    #[arg(long, default_value_t = 0.2)]
    pub ratio: f64,
    /// Data file to write (CSV).
    #[arg(long)]
    pub out: PathBuf,
    /// Board conversion config used by the emulator and the reader.
    #[arg(long, default_value = "config/io/psm-classic.toml")]
    pub io: PathBuf,
    /// Insertion depths (m).
    #[arg(long, value_delimiter = ',', default_values_t = [0.10, 0.15, 0.20])]
    pub depths: Vec<f64>,
    /// Excitation time per depth (s).
    #[arg(long, default_value_t = 20.0)]
    pub seconds_per_depth: f64,
    /// Cycle rate of the recording (Hz).
    #[arg(long, default_value_t = 1500.0)]
    pub rate_hz: f64,
}

/// The excitation: three incommensurate sines per joint (periods 0.9-4.4 s, peak speed about
/// 1.5 rad/s), applied by the simulator at every physics step.
const EXCITATION: Motion = Motion::MultiSine {
    amplitude: [[0.25, 0.12, 0.05], [0.18, 0.09, 0.04]],
    angular_frequency: [[1.43, 3.1, 6.9], [1.67, 3.7, 6.1]],
};

/// The depths and the time per depth of an excitation (`calibrate dynamics` and `calibrate
/// trajectory` take the same options).
pub(crate) fn check_schedule(depths: &[f64], seconds_per_depth: f64) -> anyhow::Result<()> {
    if depths.is_empty() {
        bail!("--depths: give at least one insertion depth");
    }
    for &d in depths {
        if !(0.05..=0.23).contains(&d) {
            bail!("--depths {d}: each depth must lie within 0.05..=0.23 m");
        }
    }
    if !(seconds_per_depth.is_finite() && (2.0..=600.0).contains(&seconds_per_depth)) {
        bail!(
            "--seconds-per-depth {}: must be within 2..=600 s",
            num(seconds_per_depth)
        );
    }
    Ok(())
}

/// Runs the excitation and returns the rows (no file written).
pub fn record(a: &DynamicsArgs, stop: &AtomicBool) -> anyhow::Result<Vec<DynamicsSample>> {
    check_schedule(&a.depths, a.seconds_per_depth)?;
    if !(a.rate_hz.is_finite() && (100.0..=20_000.0).contains(&a.rate_hz)) {
        bail!("--rate-hz {}: must be within 100..=20000", num(a.rate_hz));
    }
    let Some(config) = &a.config else {
        bail!("--config SCENARIO (simulator) or --robot ros2:ARM (a real arm): one is needed");
    };
    let base = load_scenario(config)?;
    let period_ns = (1e9 / a.rate_hz).round() as u64;
    let cycles = (a.seconds_per_depth * a.rate_hz).round() as u64;
    let mut rows = Vec::new();
    let mut t_offset = 0.0;
    for &depth in &a.depths {
        let io = load_io(&a.io)?;
        let mut sc = base.clone();
        sc.environment = Environment::Free;
        sc.motion = EXCITATION;
        sc.initial_position = [0.0, 0.0, depth, 0.0, 0.0, 0.0, 0.0];
        let mut port = sim_port(&sc, &io).context("building the simulated PSM")?;
        port.link_mut().advance_to(0);
        let mut reader = ArmReader::new(port, io, AccessMode::Exclusive);
        let mut arm = ArmSample::default();
        let mut t_ns = 0u64;
        for _ in 0..cycles {
            if stop.load(Ordering::Relaxed) {
                bail!("stopped before the excitation finished; nothing written");
            }
            t_ns += period_ns;
            let t = t_ns as f64 * 1e-9;
            reader.port_mut().link_mut().advance_to(t_ns);
            if reader.read(t_ns, &mut arm).is_ok() && arm.valid {
                rows.push(DynamicsSample {
                    t_s: t_offset + t,
                    position: [arm.position[0], arm.position[1], arm.position[2]],
                    effort_nm: [arm.effort[0], arm.effort[1]],
                });
            }
        }
        t_offset += a.seconds_per_depth + 1.0;
    }
    Ok(rows)
}

/// The rows as CSV text.
pub fn to_csv(rows: &[DynamicsSample]) -> String {
    let mut s = String::with_capacity(rows.len() * 80);
    s.push_str(HEADER);
    s.push('\n');
    for r in rows {
        let _ = writeln!(
            s,
            "{:?},{:?},{:?},{:?},{:?},{:?}",
            r.t_s, r.position[0], r.position[1], r.position[2], r.effort_nm[0], r.effort_nm[1]
        );
    }
    s
}

/// Runs `calibrate dynamics`: records, then writes the file atomically.
pub fn run(a: &DynamicsArgs, stop: &AtomicBool) -> anyhow::Result<()> {
    if a.out.is_dir() {
        bail!(
            "--out {}: is a directory; give a file name",
            a.out.display()
        );
    }
    super::data::check_output_path(&a.out)?;
    if a.robot.is_none() && (a.measure == "sidecar" || a.sidecar_prefix.is_some()) {
        bail!("--measure sidecar and --sidecar-prefix: only with --robot");
    }
    if let Some(robot) = &a.robot {
        let arm = super::calibrate::robot_arm(robot)?;
        return super::console_run::run_dynamics(a, &arm, stop);
    }
    let rows = record(a, stop)?;
    let prov = super::provenance::Provenance::now(
        &format!(
            "simulator ({})",
            a.config.as_deref().unwrap_or(Path::new("")).display()
        ),
        Some(super::calibrate::SIM_INSTRUMENT),
    );
    let text = prov.lines() + &to_csv(&rows);
    super::data::write_atomically(&a.out, text.as_bytes())?;
    let text = format!("wrote {} rows to {}\n", rows.len(), a.out.display());
    std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
        .context("writing to stdout")
}

/// `calibrate record --dynamics`: subscribes to `<prefix>/measured_js` of the running service
/// and keeps every valid sample as a dynamics row until `--seconds` of samples, `--rows` rows or
/// Ctrl-C; then writes the file atomically. The time of a row is the sample's own monotonic stamp
/// (`sample_t_ns`) from the first kept sample, so the fit's filter sees the true spacing. With
/// `--commanded-hz`, the file starts with its provenance lines, that rate among them.
pub fn record_live(
    a: &super::calibrate::RecordArgs,
    prefix: &str,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    use dvrk_ipc::Topic;

    super::data::check_output_path(&a.out)?;
    let seconds = a.seconds.unwrap_or(f64::INFINITY);
    if seconds.is_nan() || seconds <= 0.0 {
        bail!(
            "--seconds {}: must be a positive number of seconds",
            num(seconds)
        );
    }
    if let Some(hz) = a.commanded_hz
        && !(hz.is_finite() && hz > 0.0 && hz <= 100_000.0)
    {
        bail!(
            "--commanded-hz {}: must be a rate in ]0, 100000] Hz",
            num(hz)
        );
    }
    let limit = a.rows.unwrap_or(usize::MAX);
    let (mut sub, names, node) = super::calibrate::subscribe_measured_js(prefix)?;
    let service = names.topic(Topic::MeasuredJs);
    eprintln!(
        "recording dynamics rows from {}; run the excitation with the dVRK console (free space, \
         joints 1 and 2), Ctrl-C to stop",
        service.as_str()
    );
    let mut rows: Vec<DynamicsSample> = Vec::new();
    let mut t0_ns: Option<u64> = None;
    let mut invalid = 0u64;
    let mut last_t = f64::NEG_INFINITY;
    let mut next_report = 5.0;
    let mut silence = crate::watch::SilenceReporter::for_domain(node.config());
    let mut done = false;
    while !done && !stop.load(Ordering::Relaxed) {
        let update = sub
            .wait_with(|msg| {
                if done {
                    return;
                }
                let h = &msg.header;
                let sample = [
                    msg.position[0],
                    msg.position[1],
                    msg.position[2],
                    msg.effort[0],
                    msg.effort[1],
                ];
                if h.valid == 0 || !sample.iter().all(|v| v.is_finite()) {
                    invalid += 1;
                    return;
                }
                let t0 = *t0_ns.get_or_insert(h.sample_t_ns);
                let t = h.sample_t_ns.saturating_sub(t0) as f64 * 1e-9;
                // A repeated or older stamp (a restarted service) cannot go into one time axis.
                if t <= last_t {
                    return;
                }
                last_t = t;
                rows.push(DynamicsSample {
                    t_s: t,
                    position: [sample[0], sample[1], sample[2]],
                    effort_nm: [sample[3], sample[4]],
                });
                done = t >= seconds || rows.len() >= limit;
            })
            .context("waiting for samples")?;
        silence.report(&update, service.as_str());
        if last_t >= next_report {
            eprintln!(
                "{:.0} s recorded: {} rows, {invalid} invalid samples skipped",
                last_t,
                rows.len()
            );
            next_report += 5.0;
        }
    }
    if rows.is_empty() {
        bail!(
            "no valid sample arrived on {}; nothing written to {}",
            service.as_str(),
            a.out.display()
        );
    }
    let head = match a.commanded_hz {
        Some(hz) => super::provenance::Provenance {
            date: Some(super::provenance::utc_now()),
            command: Some(super::provenance::command_line()),
            commanded_hz: Some(format!("{hz}")),
            ..Default::default()
        }
        .lines(),
        None => String::new(),
    };
    super::data::write_atomically(&a.out, (head + &to_csv(&rows)).as_bytes())?;
    let segments = segments(&rows).len();
    eprintln!(
        "wrote {} rows ({last_t:.1} s, {segments} segment(s), {invalid} invalid samples skipped) \
         to {}",
        rows.len(),
        a.out.display()
    );
    Ok(())
}

/// `calibrate trajectory --out traj.csv [--depths ..] [--seconds-per-depth N] [--rate-hz R]
/// [--center q1,q2]`
#[derive(Clone, Debug, clap::Args)]
pub struct TrajectoryArgs {
    /// Trajectory file to write (CSV: t_s,q1_rad,q2_rad,q3_m,v1_rad_per_s,v2_rad_per_s,v3_m_per_s).
    #[arg(long)]
    pub out: PathBuf,
    /// Insertion depths (m), visited in this order.
    #[arg(long, value_delimiter = ',', default_values_t = [0.10, 0.15, 0.20])]
    pub depths: Vec<f64>,
    /// Excitation time per depth (s), fade-in and fade-out included.
    #[arg(long, default_value_t = 20.0)]
    pub seconds_per_depth: f64,
    /// Rows per second.
    #[arg(long, default_value_t = 1500.0)]
    pub rate_hz: f64,
    /// Joints 1 and 2 around which the excitation swings (rad).
    #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [0.0, 0.0])]
    pub center: Vec<f64>,
}

/// The header of a trajectory file.
pub const TRAJECTORY_HEADER: &str = "t_s,q1_rad,q2_rad,q3_m,v1_rad_per_s,v2_rad_per_s,v3_m_per_s";

/// Time the insertion takes to go from one depth to the next (s).
const DEPTH_MOVE_S: f64 = 2.0;

/// `sin^2(pi x / 2)` on [0, 1] (0 before, 1 after) and its derivative.
fn fade(x: f64) -> (f64, f64) {
    use core::f64::consts::PI;
    if x <= 0.0 {
        (0.0, 0.0)
    } else if x >= 1.0 {
        (1.0, 0.0)
    } else {
        let s = (0.5 * PI * x).sin();
        (s * s, 0.5 * PI * (PI * x).sin())
    }
}

/// The excitation of `calibrate dynamics` as one continuous trajectory for a real arm: at each
/// depth the same multi-sine about `center`, faded in over the first second and out over the
/// last, then a smooth 2 s move of the insertion to the next depth with joints 1 and 2 at the
/// centre. Rows `[t, q1, q2, q3, v1, v2, v3]`; it starts and ends still at the first and last
/// depth.
pub fn trajectory(a: &TrajectoryArgs) -> anyhow::Result<Vec<[f64; 7]>> {
    trajectory_scaled(a, 1.0)
}

/// [`trajectory`] with the excitation (its sines and its fades) played `speed` times as fast:
/// its velocities scale by `speed`, its accelerations by `speed²` (a real arm's console limits
/// both). The moves between depths keep their 2 s.
pub fn trajectory_scaled(a: &TrajectoryArgs, speed: f64) -> anyhow::Result<Vec<[f64; 7]>> {
    let Motion::MultiSine {
        amplitude,
        angular_frequency,
    } = EXCITATION
    else {
        bail!("the excitation is not a multi-sine");
    };
    if !(speed.is_finite() && speed > 0.0 && speed <= 1.0) {
        bail!("excitation speed scale {}: must be in ]0, 1]", num(speed));
    }

    check_schedule(&a.depths, a.seconds_per_depth)?;
    if !(a.rate_hz.is_finite() && (10.0..=20_000.0).contains(&a.rate_hz)) {
        bail!("--rate-hz {}: must be within 10..=20000", num(a.rate_hz));
    }
    let limits = dvrk_sim::PhysicsParams::CLASSIC;
    let [c1, c2] = a.center[..] else {
        bail!("--center: give two angles, q1,q2 (rad)");
    };
    for (j, (c, amp)) in [c1, c2].into_iter().zip(amplitude.iter()).enumerate() {
        let reach: f64 = amp.iter().sum();
        let (lo, hi) = (limits.position_min[j], limits.position_max[j]);
        if !(c.is_finite() && c - reach >= lo && c + reach <= hi) {
            bail!(
                "--center {c} (joint {}): the excitation swings ±{reach:.2} rad about it and must \
                 stay within the joint's limits {lo:.3}..{hi:.3} rad",
                j + 1
            );
        }
    }
    let center = [c1, c2];
    let seg = a.seconds_per_depth;
    let n_depths = a.depths.len();
    let total = n_depths as f64 * seg + (n_depths - 1) as f64 * DEPTH_MOVE_S;
    let n = (total * a.rate_hz).round() as usize;
    let mut rows = Vec::with_capacity(n + 1);
    for i in 0..=n {
        let t = i as f64 / a.rate_hz;
        // Which depth (or which move between two depths) the time falls in.
        let k = ((t / (seg + DEPTH_MOVE_S)) as usize).min(n_depths - 1);
        let local = t - k as f64 * (seg + DEPTH_MOVE_S);
        let mut row = [t, center[0], center[1], a.depths[k], 0.0, 0.0, 0.0];
        if local <= seg {
            let (g, dg) = fade((seg - local) * speed);
            let dg = dg * speed;
            for j in 0..2 {
                let (q, v) = dvrk_sim::scenario::multi_sine(
                    &amplitude[j],
                    &angular_frequency[j],
                    local * speed,
                );
                let v = v * speed;
                row[1 + j] = center[j] + g * q;
                row[4 + j] = g * v - dg * q;
            }
        } else if k + 1 < n_depths {
            let x = (local - seg) / DEPTH_MOVE_S;
            let (from, to) = (a.depths[k], a.depths[k + 1]);
            // Half a cosine: still at both ends.
            let s = 0.5 - 0.5 * (core::f64::consts::PI * x).cos();
            let ds = 0.5 * core::f64::consts::PI * (core::f64::consts::PI * x).sin() / DEPTH_MOVE_S;
            row[3] = from + (to - from) * s;
            row[6] = (to - from) * ds;
        }
        rows.push(row);
    }
    Ok(rows)
}

/// Runs `calibrate trajectory`: writes the file atomically.
pub fn run_trajectory(a: &TrajectoryArgs) -> anyhow::Result<()> {
    super::data::check_output_path(&a.out)?;
    let rows = trajectory(a)?;
    let mut s = String::with_capacity(rows.len() * 120);
    s.push_str(TRAJECTORY_HEADER);
    s.push('\n');
    for r in &rows {
        let _ = writeln!(
            s,
            "{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
            r[0], r[1], r[2], r[3], r[4], r[5], r[6]
        );
    }
    super::data::write_atomically(&a.out, s.as_bytes())?;
    let text = format!(
        "wrote {} rows ({:.1} s) to {}; move the arm to q1 = {}, q2 = {}, q3 = {} m first\n",
        rows.len(),
        rows.last().map_or(0.0, |r| r[0]),
        a.out.display(),
        rows[0][1],
        rows[0][2],
        rows[0][3]
    );
    std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
        .context("writing to stdout")
}

/// Reads a dynamics file; every error names the file, line and column.
pub fn read(path: &Path) -> anyhow::Result<Vec<DynamicsSample>> {
    let text = crate::files::read_text(path, crate::files::DATA_MAX_BYTES)?;
    // the provenance block (`# arm: ...`) comes first
    let mut lines = text
        .lines()
        .enumerate()
        .skip_while(|(_, l)| l.starts_with('#'));
    match lines.next() {
        Some((_, h)) if h.trim() == HEADER => {}
        Some((i, h)) => bail!(
            "{} line {}: header `{}`; a dynamics file starts with `{HEADER}`",
            path.display(),
            i + 1,
            crate::files::quote(h.trim())
        ),
        None => bail!("{}: empty file", path.display()),
    }
    let names: Vec<&str> = HEADER.split(',').collect();
    let mut rows = Vec::new();
    for (i, line) in lines {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let mut v = [0.0; 6];
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != 6 {
            bail!(
                "{} line {}: {} fields; a dynamics row has 6 ({HEADER})",
                path.display(),
                i + 1,
                fields.len()
            );
        }
        for (k, f) in fields.iter().enumerate() {
            v[k] = f
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .with_context(|| {
                    format!(
                        "{} line {}: {} = `{}` is not a finite number",
                        path.display(),
                        i + 1,
                        names[k],
                        crate::files::quote(f.trim())
                    )
                })?;
        }
        // Physical bounds (issue 22: one rule for every number read): a time, joints 1-2 and
        // the insertion within any PSM's range, efforts within what a PSM's motors can give.
        let range = dvrk_compliance::bounds::PSM_JOINT_RANGE;
        let (t, e) = (
            dvrk_compliance::bounds::MAX_ABS_TIME_S,
            dvrk_compliance::bounds::MAX_ABS_EFFORT,
        );
        let bounds = [
            ([-t, t], "s"),
            (range[0], "rad"),
            (range[1], "rad"),
            (range[2], "m"),
            ([-e, e], "N·m"),
            ([-e, e], "N·m"),
        ];
        for (k, (range, unit)) in bounds.into_iter().enumerate() {
            let line = i as u64 + 1;
            super::data::within(v[k], range, unit, path, line, format_args!("{}", names[k]))?;
        }
        rows.push(DynamicsSample {
            t_s: v[0],
            position: [v[1], v[2], v[3]],
            effort_nm: [v[4], v[5]],
        });
    }
    if rows.is_empty() {
        bail!("{}: no data rows after the header", path.display());
    }
    Ok(rows)
}

/// Splits the rows into segments at time gaps over 0.5 s (one per depth).
pub fn segments(rows: &[DynamicsSample]) -> Vec<&[DynamicsSample]> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..rows.len() {
        if rows[i].t_s - rows[i - 1].t_s > 0.5 {
            out.push(&rows[start..i]);
            start = i;
        }
    }
    if start < rows.len() {
        out.push(&rows[start..]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trips_and_bad_numbers_are_named() {
        let rows = vec![
            DynamicsSample {
                t_s: 0.001,
                position: [0.1, -0.2, 0.12],
                effort_nm: [0.3, -0.05],
            },
            DynamicsSample {
                t_s: 2.5,
                position: [0.11, -0.21, 0.15],
                effort_nm: [0.31, -0.06],
            },
        ];
        let p = std::env::temp_dir().join(format!("dvrk-dynamics-{}.csv", std::process::id()));
        std::fs::write(&p, to_csv(&rows)).unwrap();
        assert_eq!(read(&p).unwrap(), rows);
        assert_eq!(segments(&rows).len(), 2);
        std::fs::write(&p, format!("{HEADER}\n0.1,0.2,nan,0.1,0,0\n")).unwrap();
        let e = format!("{:#}", read(&p).unwrap_err());
        assert!(
            e.contains("line 2") && e.contains("q2_rad") && e.contains("nan"),
            "{e}"
        );
        std::fs::write(&p, "t,q\n").unwrap();
        assert!(format!("{:#}", read(&p).unwrap_err()).contains("header"));
        let _ = std::fs::remove_file(&p);
    }

    fn traj_args() -> TrajectoryArgs {
        TrajectoryArgs {
            out: PathBuf::from("unused.csv"),
            depths: vec![0.10, 0.15, 0.20],
            seconds_per_depth: 20.0,
            rate_hz: 1500.0,
            center: vec![0.1, -0.05],
        }
    }

    #[test]
    fn trajectory_is_smooth_still_at_the_ends_and_the_excitation_inside() {
        let a = traj_args();
        let rows = trajectory(&a).unwrap();
        let dt = 1.0 / a.rate_hz;
        assert!((rows.last().unwrap()[0] - (3.0 * 20.0 + 2.0 * DEPTH_MOVE_S)).abs() < 1e-9);
        for r in [rows[0], *rows.last().unwrap()] {
            assert_eq!(&r[4..], &[0.0, 0.0, 0.0], "{r:?}");
        }
        assert_eq!(&rows[0][1..4], &[0.1, -0.05, 0.10]);
        assert_eq!(rows.last().unwrap()[3], 0.20);
        let lim = dvrk_sim::PhysicsParams::CLASSIC;
        for w in rows.windows(3) {
            let (a0, b, c) = (w[0], w[1], w[2]);
            for k in 1..4 {
                // The velocity column is the derivative of the position (central difference),
                // so the positions never jump.
                let d = (c[k] - a0[k]) / (2.0 * dt);
                assert!(
                    (d - b[k + 3]).abs() < 1e-3 * (1.0 + b[k + 3].abs()),
                    "{b:?} {d}"
                );
            }
            for j in 0..2 {
                assert!(b[1 + j] > lim.position_min[j] && b[1 + j] < lim.position_max[j]);
            }
        }
        // Inside a depth, after the fade-in and before the fade-out: the excitation itself.
        let Motion::MultiSine {
            amplitude,
            angular_frequency,
        } = EXCITATION
        else {
            panic!("not a multi-sine")
        };
        let i = (25.0 * a.rate_hz) as usize; // 3 s into the second depth
        let local = rows[i][0] - 22.0;
        let (q, _) = dvrk_sim::scenario::multi_sine(&amplitude[0], &angular_frequency[0], local);
        assert!((rows[i][1] - 0.1 - q).abs() < 1e-12);
        assert_eq!(rows[i][3], 0.15);
        // A centre too close to a limit is refused, naming the joint.
        let mut bad = traj_args();
        bad.center = vec![1.5, 0.0];
        let e = format!("{:#}", trajectory(&bad).unwrap_err());
        assert!(e.contains("--center 1.5") && e.contains("joint 1"), "{e}");
    }

    #[test]
    fn excitation_starts_still_and_its_velocity_is_the_derivative() {
        let Motion::MultiSine {
            amplitude,
            angular_frequency,
        } = EXCITATION
        else {
            panic!("not a multi-sine")
        };
        for j in 0..2 {
            let f = |t| dvrk_sim::scenario::multi_sine(&amplitude[j], &angular_frequency[j], t);
            assert_eq!(f(0.0), (0.0, 0.0));
            for t in [0.3, 0.8, 1.5, 7.0] {
                let h = 1e-6;
                let d = (f(t + h).0 - f(t - h).0) / (2.0 * h);
                assert!((d - f(t).1).abs() < 1e-6, "{j} {t}");
            }
        }
    }
}
