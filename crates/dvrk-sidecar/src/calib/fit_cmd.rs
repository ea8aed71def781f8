//! `dvrk-sidecar fit`: calibration data in, compliance parameter file out.

use std::path::PathBuf;

use anyhow::{Context, bail};
use dvrk_compliance::fit::{self, DataRow, FitOptions, JointFit, TorqueOffsetFit};
use dvrk_compliance::{
    ComplianceConfig, ComplianceParams, DynamicsFit, DynamicsSample, Excitation, HysteresisKind,
    HysteresisParams, JointParams, ModelKind, REGULAR_INTERVAL_BAND, TorqueOffsetParams,
    fit_dynamics_with_gravity, params_to_toml,
};
use serde::Serialize;

use super::data;
use crate::text::num;

/// Which model the written parameter file selects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    Paper,
    Continuous,
}

/// `fit --clamp FILE... [--torque-offset FILE...] [--joint N] --out params.toml [--plots DIR] [--json]`
#[derive(Clone, Debug, clap::Args)]
pub struct FitArgs {
    /// Add this fit to the parameter sets of `--out` (one `[[set]]` per instrument; the set of
    /// the same instrument is replaced, the others kept) instead of replacing the file. The
    /// data files must record their instrument (the procedures write it).
    #[arg(long)]
    pub add: bool,
    /// Clamp-beam data files (project CSV layout or dVRK 2017 clamp layout).
    #[arg(long, num_args = 1.., required = true)]
    pub clamp: Vec<PathBuf>,
    /// Unloaded torque-offset sweep files (project layout or dVRK 2017 torque-offset layout).
    #[arg(long = "torque-offset", num_args = 1..)]
    pub torque_offset: Vec<PathBuf>,
    /// Joint (1 = yaw, 2 = pitch) held by dVRK 2017 files, which do not say: once for all of
    /// them, or once per 2017 file in command-line order (clamp files first).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub joint: Vec<u8>,
    /// Parameter file to write (TOML, the compensation's schema).
    #[arg(long)]
    pub out: PathBuf,
    /// Directory for the figures (SVG and PNG).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Print the fit as JSON on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Model written to the file.
    #[arg(long, value_enum, default_value = "paper")]
    pub model: ModelArg,
    /// Dead band tau_min (N·m) for joints 1 and 2; the paper's empirical values by default.
    #[arg(long = "tau-min-nm", value_delimiter = ',', num_args = 2, default_values_t = [0.1, 0.2])]
    pub tau_min_nm: Vec<f64>,
    /// TTF font for the figure text.
    #[arg(long, default_value = super::plots::DEFAULT_FONT)]
    pub font: PathBuf,
    /// Free-space excitation rows (`calibrate dynamics`): identify the internal-torque model
    /// (inertia, viscous and Coulomb friction) under the written tau_0 table and write it as
    /// `[joint.dynamics]`.
    #[arg(long)]
    pub dynamics: Option<PathBuf>,
    /// The gate in residual standard deviations: a correction needs |tau_ext| > tau_min +
    /// this * the dynamics fit's residual std.
    #[arg(long, default_value_t = 4.0, requires = "dynamics")]
    pub gate_sigmas: f64,
    /// How the clamp rows of a depth are split into the play's two sides: `auto` chooses per
    /// joint from how well each reading explains the rows; `motion` (by direction of motion, the
    /// paper's Fig. 5), `load` (by the sign of the load) or `load-friction` (by the load, with
    /// one motor friction torque in each row's direction) force one.
    #[arg(long, value_enum, default_value = "auto")]
    pub split: SplitArg,
}

/// `fit --split`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitArg {
    Auto,
    Motion,
    Load,
    LoadFriction,
}

/// Everything one `fit` run computed (nothing is written unless all of it succeeded).
pub struct FitOutcome {
    pub clamp_rows: Vec<DataRow>,
    pub sweep_rows: Vec<DataRow>,
    pub joints: Vec<JointFit>,
    pub offsets: Vec<TorqueOffsetFit>,
    pub params: ComplianceParams,
    /// The internal-torque model per joint (with `--dynamics`).
    pub dynamics: Vec<DynamicsFit>,
}

/// Reads the files and fits everything; writes nothing.
pub fn compute(args: &FitArgs) -> anyhow::Result<FitOutcome> {
    // one instrument per parameter set: refused before any fitting
    inputs_provenance(args)?;
    let mut legacy_seen = 0;
    let clamp_rows = data::read_files(&args.clamp, &args.joint, &mut legacy_seen)?;
    let sweep_rows = data::read_files(&args.torque_offset, &args.joint, &mut legacy_seen)?;
    if args.joint.len() > 1 && args.joint.len() != legacy_seen {
        bail!(
            "{} --joint values for {legacy_seen} dVRK 2017 files; give one for all or one per file",
            args.joint.len()
        );
    }
    let opts = FitOptions {
        branches: match args.split {
            SplitArg::Auto => fit::BranchRule::Auto,
            SplitArg::Motion => fit::BranchRule::Motion,
            SplitArg::Load => fit::BranchRule::Load,
            SplitArg::LoadFriction => fit::BranchRule::LoadFriction,
        },
        ..FitOptions::default()
    };
    let mut sweep_joints: Vec<u8> = sweep_rows.iter().map(|r| r.joint).collect();
    sweep_joints.sort_unstable();
    sweep_joints.dedup();
    let offsets = sweep_joints
        .iter()
        .map(|&j| fit::fit_torque_offset(&sweep_rows, j, &opts))
        .collect::<Result<Vec<_>, _>>()
        .context("fitting the torque-offset sweep")?;
    // One tau_0 (issue 10): K and delta are fitted under the table this file will carry, not
    // under the clamp file's own torque-offset column (on the 2017 data the two differ by up to
    // 0.14 N·m, enough to move delta by 160%).
    let mut clamp_rows = clamp_rows;
    for r in &mut clamp_rows {
        if let Some(o) = offsets.iter().find(|o| o.joint == r.joint) {
            r.torque_offset_nm = super::calibrate::lookup(o, r.position_rad);
        }
    }
    let joints = fit::fit_clamp(&clamp_rows, &opts).context("fitting the clamp data")?;
    for j in &joints {
        if let Some(warning) = hysteresis_spread_warning(j) {
            tracing::warn!(joint = j.joint, "{warning}");
        }
    }
    for o in &offsets {
        if !joints.iter().any(|j| j.joint == o.joint) {
            tracing::warn!(
                joint = o.joint,
                "torque-offset sweep of joint {} has no clamp data; it is not written",
                o.joint
            );
        }
    }
    let mut joint_params = Vec::new();
    for j in &joints {
        let torque_offset = match offsets.iter().find(|o| o.joint == j.joint) {
            Some(o) => TorqueOffsetParams {
                position_rad: o.position_rad.clone(),
                effort_nm: o.effort_nm.clone(),
            },
            None => {
                tracing::warn!(
                    joint = j.joint,
                    "no torque-offset sweep for joint {}: writing a flat zero tau_0 table; run a sweep and pass --torque-offset",
                    j.joint
                );
                TorqueOffsetParams {
                    position_rad: vec![0.0],
                    effort_nm: vec![0.0],
                }
            }
        };
        let tau_min = args
            .tau_min_nm
            .get(usize::from(j.joint) - 1)
            .copied()
            .unwrap_or(0.1);
        joint_params.push(JointParams {
            index: i64::from(j.joint),
            backlash_rad: j.backlash_rad,
            tau_min_nm: tau_min,
            inverse_compliance_nm_per_rad: j.inverse_compliance_nm_per_rad,
            insertion_range_m: j.insertion_range_m,
            inverse_compliance_rel_sigma: j.rel_sigma,
            // A scatter beyond the file's bound (half the backlash) is written at the bound: the
            // bound then says the backlash is barely known, and the file stays loadable.
            backlash_rel_sigma: j
                .backlash_rel_sigma
                .map(|r| r.min(dvrk_compliance::bounds::MAX_BACKLASH_REL_SIGMA)),
            torque_offset,
            hysteresis: Some(hysteresis_of(j)),
            dynamics: None,
        });
    }
    let params = ComplianceParams {
        model: match args.model {
            ModelArg::Paper => ModelKind::Paper,
            ModelArg::Continuous => ModelKind::Continuous,
        },
        joint: joint_params,
    };
    let mut params = params;
    let config = ComplianceConfig::from_params(params.clone())
        .context("the fitted parameters do not validate; nothing written")?;
    let mut dynamics = Vec::new();
    if let Some(path) = &args.dynamics {
        if !(args.gate_sigmas.is_finite() && (0.0..=10.0).contains(&args.gate_sigmas)) {
            bail!(
                "--gate-sigmas {}: must be within 0..=10",
                num(args.gate_sigmas)
            );
        }
        let rows = super::dynamics_cmd::read(path)?;
        let segments = super::dynamics_cmd::segments(&rows);
        let excitation = excitation_of(path)?;
        if let Some(w) = console_rate_warning(excitation, &rows) {
            tracing::warn!("{}: {w}", path.display());
        }
        if let Some(w) = irregular_rows_warning(excitation, &segments) {
            tracing::warn!("{}: {w}", path.display());
        }
        for jp in &mut params.joint {
            let j0 = (jp.index - 1) as usize;
            let Some(model) = config.joint(j0) else {
                continue;
            };
            let table = model.torque_offset();
            let joint = jp.index as u8;
            // The torque-offset sweep ran in free space, so its table holds the distal weight's
            // reaction at the sweep's depths: their mean is the weight's reference insertion.
            // Without a sweep of this joint the weight is not modelled.
            let reference = mean_insertion(&sweep_rows, joint);
            let fit = fit_segments(
                joint,
                &segments,
                |q| table.lookup(q),
                args.gate_sigmas,
                reference,
                excitation,
            )
            .with_context(|| format!("{}: fitting the dynamics", path.display()))?;
            if let Some(w) = weak_model_warning(&fit) {
                tracing::warn!(joint, "{}: {w}", path.display());
            }
            jp.dynamics = Some(fit.params);
            dynamics.push(fit);
        }
        ComplianceConfig::from_params(params.clone())
            .context("the fitted dynamics do not validate; nothing written")?;
    }
    Ok(FitOutcome {
        clamp_rows,
        sweep_rows,
        joints,
        offsets,
        params,
        dynamics,
    })
}

/// Fits the dynamics over every segment (one per depth) at once, so that the `L^2` term is
/// identified across depths; the filter restarts at each segment.
fn fit_segments(
    joint: u8,
    segments: &[&[DynamicsSample]],
    tau_0: impl Fn(f64) -> f64,
    gate_sigmas: f64,
    gravity_reference_m: Option<f64>,
    excitation: Excitation,
) -> anyhow::Result<DynamicsFit> {
    let mut all = Vec::new();
    let mut starts = Vec::new();
    for seg in segments {
        starts.push(all.len());
        all.extend_from_slice(seg);
    }
    Ok(fit_dynamics_with_gravity(
        joint,
        &all,
        &starts,
        tau_0,
        gate_sigmas,
        gravity_reference_m,
        excitation,
    )?)
}

/// A dynamics model that leaves more than this fraction of the effort's rms unexplained is
/// reported: on the simulator's excitation the model leaves 6% (0.149 -> 0.0095 N·m), on rows of
/// a console's 100 Hz `measured_js` of an excitation played through it, 99%.
pub const WEAK_MODEL_RATIO: f64 = 0.5;

/// The warning for a dynamics fit that explains little of the effort, if it does.
pub fn weak_model_warning(fit: &DynamicsFit) -> Option<String> {
    (fit.rms_after_nm > WEAK_MODEL_RATIO * fit.rms_before_nm).then(|| {
        format!(
            "joint {}: the dynamics model explains little of the effort (rms {:.4} N·m before, \
             {:.4} N·m after): check that nothing touched the instrument and that the rows are \
             the boards' (calibrate dynamics --robot --measure sidecar); the file stays safe, its \
             gate grows with the residual, but it corrects little",
            fit.joint, fit.rms_before_nm, fit.rms_after_nm
        )
    })
}

/// The warning for rows no faster than the commands of an excitation played in steps (rows of a
/// console's `measured_js`), if they are.
pub fn console_rate_warning(excitation: Excitation, rows: &[DynamicsSample]) -> Option<String> {
    let Excitation::Stepped { commanded_hz } = excitation else {
        return None;
    };
    let median = dvrk_compliance::median_interval(rows);
    let rate = 1.0 / median;
    (median > 0.0 && excitation.averaging_period(median).is_none()).then(|| {
        format!(
            "rows at {rate:.0} Hz for commands at {commanded_hz:.0} Hz: each row sees the \
             controller's response to a step at the same phase, which biases the model \
             (inertia 40% low on the simulated console); record with calibrate dynamics \
             --robot --measure sidecar"
        )
    })
}

/// The largest share of a recording's intervals outside [`REGULAR_INTERVAL_BAND`] times their
/// median that the sample-by-sample fit is trusted with. On the simulator a service's recording
/// on a quiet machine has 2-4% there and its inertia comes within 1-3%; a CI run's, on a loaded
/// machine, 13% (4% under 0.3 ms, 3% over 2 ms), and the inertia came out 21% (joint 1) and 36%
/// (joint 2) low with ten times the quiet residual, while the same rows fitted as a stepped
/// excitation (averaged over command periods, [`Excitation::Stepped`]) were within 1%.
pub const IRREGULAR_ROWS_LIMIT: f64 = 0.08;

/// The warning for rows too irregular for the sample-by-sample fit, if they are and the fit
/// takes them sample by sample (a stepped excitation's rows are averaged over command periods
/// first, which weighs each stretch by its length).
pub fn irregular_rows_warning(
    excitation: Excitation,
    segments: &[&[DynamicsSample]],
) -> Option<String> {
    let (median, share) = dvrk_compliance::interval_regularity(segments)?;
    let fitted_as_rows = excitation.averaging_period(median).is_none();
    let [lo, hi] = REGULAR_INTERVAL_BAND;
    (fitted_as_rows && share > IRREGULAR_ROWS_LIMIT).then(|| {
        format!(
            "{:.1}% of the intervals between rows are outside {lo}-{hi} times their median \
             ({:.3} ms; at most {:.0}% is trusted): the fit differentiates the rows as they \
             come, and on rows this irregular (a service on a loaded machine) the inertia came \
             out 21-36% low. Check the fitted inertia; record again on a quiet machine, or, if \
             the excitation was commanded in steps (servo_jp), with `calibrate record --dynamics \
             --commanded-hz RATE` so that the fit averages the rows over command periods",
            100.0 * share,
            1e3 * median,
            100.0 * IRREGULAR_ROWS_LIMIT
        )
    })
}

/// How the dynamics file's excitation was commanded: in steps at its provenance's
/// `commanded_hz` (`calibrate dynamics --robot`), or smooth (the simulator's, files without it).
fn excitation_of(path: &std::path::Path) -> anyhow::Result<Excitation> {
    let Some(text) = super::provenance::read(path)?.commanded_hz else {
        return Ok(Excitation::Smooth);
    };
    match text.parse::<f64>() {
        Ok(hz) if hz.is_finite() && hz > 0.0 && hz <= 100_000.0 => {
            Ok(Excitation::Stepped { commanded_hz: hz })
        }
        _ => bail!(
            "{}: provenance line `# commanded_hz: {text}`: expected the command rate in Hz, a \
             number in ]0, 100000]",
            path.display()
        ),
    }
}

/// The mean insertion (m) of the torque-offset sweep's rows of `joint`, if it has any.
fn mean_insertion(sweep_rows: &[DataRow], joint: u8) -> Option<f64> {
    let (sum, n) = sweep_rows
        .iter()
        .filter(|r| r.joint == joint && r.insertion_m.is_finite())
        .fold((0.0, 0usize), |(s, n), r| (s + r.insertion_m, n + 1));
    (n > 0).then(|| sum / n as f64)
}

#[derive(Serialize)]
struct JsonDynamics {
    index: u8,
    samples: usize,
    torque_residual_rms_nm: JsonRms,
    inertia_kg_m2: [f64; 2],
    viscous_nm_s_per_rad: f64,
    coulomb_nm: f64,
    residual_std_nm: f64,
    gate_sigmas: f64,
}

#[derive(Serialize)]
struct JsonRms {
    before: f64,
    after: f64,
}

/// The `dynamics` part of the `--json` document (empty without `--dynamics`).
pub fn dynamics_json(fits: &[DynamicsFit]) -> serde_json::Value {
    let v: Vec<JsonDynamics> = fits
        .iter()
        .map(|f| JsonDynamics {
            index: f.joint,
            samples: f.samples,
            torque_residual_rms_nm: JsonRms {
                before: f.rms_before_nm,
                after: f.rms_after_nm,
            },
            inertia_kg_m2: f.params.inertia_kg_m2,
            viscous_nm_s_per_rad: f.params.viscous_nm_s_per_rad,
            coulomb_nm: f.params.coulomb_nm,
            residual_std_nm: f.params.residual_std_nm,
            gate_sigmas: f.params.gate_sigmas,
        })
        .collect();
    serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
}

/// The kind and signed gap of a joint's clamp hysteresis: the mean over depths of the fit's
/// signed gap `zero(-) - zero(+)`; a play makes it negative (-2 delta), a friction in the
/// transmission positive (the effort leads the motion).
pub fn hysteresis_of(j: &JointFit) -> HysteresisParams {
    let n = j.depths.len().max(1) as f64;
    let gap_rad = j.depths.iter().map(|d| d.hysteresis_gap_rad).sum::<f64>() / n;
    HysteresisParams {
        kind: if gap_rad > 0.0 {
            HysteresisKind::Friction
        } else {
            HysteresisKind::Play
        },
        gap_rad,
    }
}

#[derive(Serialize)]
struct JsonDepth {
    insertion_m: f64,
    stiffness_nm_per_rad: f64,
    backlash_rad: f64,
    slopes: [f64; 2],
    points: usize,
    /// The motor friction the fit took out of the rows (N·m; 0 unless the split says so).
    friction_nm: f64,
}

#[derive(Serialize)]
struct JsonJoint {
    index: u8,
    depths: Vec<JsonDepth>,
    inverse_compliance_nm_per_rad: [f64; 4],
    backlash_rad: f64,
    r_squared: f64,
    hysteresis_kind: &'static str,
    hysteresis_gap_rad: f64,
}

#[derive(Serialize)]
struct JsonFit {
    joints: Vec<JsonJoint>,
}

/// The `--json` document: `{"joints":[{"index":..,"depths":[{"insertion_m":..,
/// "stiffness_nm_per_rad":..,"backlash_rad":..,"slopes":[+,-],"points":..,"friction_nm":..}],
/// "inverse_compliance_nm_per_rad":[c3,c2,c1,c0],"backlash_rad":..,"r_squared":..}]}`.
pub fn to_json(joints: &[JointFit]) -> anyhow::Result<String> {
    let doc = JsonFit {
        joints: joints
            .iter()
            .map(|j| JsonJoint {
                index: j.joint,
                depths: j
                    .depths
                    .iter()
                    .map(|d| JsonDepth {
                        insertion_m: d.insertion_m,
                        stiffness_nm_per_rad: d.stiffness_nm_per_rad,
                        backlash_rad: d.backlash_rad,
                        slopes: [d.lines[0].slope, d.lines[1].slope],
                        points: d.points,
                        friction_nm: d.friction_nm,
                    })
                    .collect(),
                inverse_compliance_nm_per_rad: j.inverse_compliance_nm_per_rad,
                backlash_rad: j.backlash_rad,
                r_squared: j.r_squared,
                hysteresis_kind: match hysteresis_of(j).kind {
                    HysteresisKind::Play => "play",
                    HysteresisKind::Friction => "friction",
                },
                hysteresis_gap_rad: hysteresis_of(j).gap_rad,
            })
            .collect(),
    };
    Ok(serde_json::to_string(&doc)?)
}

/// A warning when a joint's hysteresis is not the same at every depth
/// ([`fit::hysteresis_spread`] over [`fit::HYSTERESIS_SPREAD_LIMIT`]). A play is the shaft's:
/// its width should not move with the depth. A friction in the transmission (a hysteresis of
/// positive gap, as in the 2017 recordings) is a torque: its gap times the stiffness should
/// not. `None` when it holds.
pub fn hysteresis_spread_warning(j: &JointFit) -> Option<String> {
    let gaps: Vec<(f64, f64)> = j
        .depths
        .iter()
        .map(|d| (d.hysteresis_gap_rad, d.stiffness_nm_per_rad))
        .collect();
    let spread = fit::hysteresis_spread(&gaps)?;
    if spread <= fit::HYSTERESIS_SPREAD_LIMIT {
        return None;
    }
    let friction = hysteresis_of(j).kind == HysteresisKind::Friction;
    let (values, what, unit, scale): (Vec<f64>, &str, &str, f64) = if friction {
        let v = j
            .depths
            .iter()
            .map(|d| d.backlash_rad * d.stiffness_nm_per_rad);
        (
            v.collect(),
            "friction hysteresis (gap x stiffness)",
            "N·m",
            1.0,
        )
    } else {
        (
            j.depths.iter().map(|d| d.backlash_rad).collect(),
            "play",
            "mrad",
            1e3,
        )
    };
    let list: Vec<String> = values.iter().map(|v| format!("{:.3}", v * scale)).collect();
    let split = j.depths.first().map_or("-", |d| split_name(d.branches));
    Some(format!(
        "joint {}: the {what} scatters by {:.0}% over the depths ({} {unit}) where the \
         mechanism's is the same at every depth: the split ({split}) may have taken a motor's \
         friction for play or play for friction; compare `--split motion`, `load` and \
         `load-friction`",
        j.joint,
        spread * 100.0,
        list.join(", "),
    ))
}

/// The report's name of a split.
fn split_name(b: fit::Branches) -> &'static str {
    match b {
        fit::Branches::Motion => "motion",
        fit::Branches::Load => "load",
        fit::Branches::LoadFriction => "load+fr",
    }
}

/// Human-readable report of the fit.
pub fn report(outcome: &FitOutcome) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    for j in &outcome.joints {
        let _ = writeln!(s, "joint {}", j.joint);
        let _ = writeln!(
            s,
            "  {:>5} {:>9} {:>12} {:>12} {:>9} {:>9} {:>7} {:>6} {:>8}",
            "depth",
            "L_m",
            "K^-1_Nm/rad",
            "backlash_mrad",
            "slope+",
            "slope-",
            "split",
            "points",
            "left_out"
        );
        for d in &j.depths {
            let _ = writeln!(
                s,
                "  {:>5} {:>9.4} {:>12.2} {:>12.2} {:>9.2} {:>9.2} {:>7} {:>6} {:>8}",
                d.depth_index,
                d.insertion_m,
                d.stiffness_nm_per_rad,
                d.backlash_rad * 1e3,
                d.lines[0].slope,
                d.lines[1].slope,
                split_name(d.branches),
                d.points,
                d.excluded + d.dropped_settling
            );
        }
        let c = j.inverse_compliance_nm_per_rad;
        let _ = writeln!(
            s,
            "  1/K(L) = {:.2} L^3 + {:.2} L^2 + {:.2} L + {:.2}   (r^2 {:.4}, L in [{:.4}, {:.4}] m)",
            c[0], c[1], c[2], c[3], j.r_squared, j.insertion_range_m[0], j.insertion_range_m[1]
        );
        let _ = writeln!(
            s,
            "  backlash (mean over depths) = {:.3} mrad",
            j.backlash_rad * 1e3
        );
    }
    for o in &outcome.offsets {
        let _ = writeln!(
            s,
            "torque offset joint {}: {} angles from {} depths; per-angle spread over depths max {:.4} N·m, mean {:.4} N·m",
            o.joint,
            o.position_rad.len(),
            o.depths,
            o.max_depth_spread_nm,
            o.mean_depth_spread_nm
        );
        for (idx, l, bias) in &o.depth_bias_nm {
            let _ = writeln!(
                s,
                "    depth {idx:>3} (L {l:.4} m): mean deviation from the table {bias:+.4} N·m"
            );
        }
    }
    s
}

/// The parameter sets of `out` (if it exists) with `set` (a one-set file's text) filed under
/// `instrument`, replacing a set of the same instrument, as `[[set]]` tables.
pub fn add_set(out: &std::path::Path, instrument: &str, set: &str) -> anyhow::Result<String> {
    let inst = crate::config::find_instrument(instrument)?;
    let mut sets: Vec<toml::Table> = Vec::new();
    if out.exists() {
        let text = crate::files::read_text(out, crate::files::CONFIG_MAX_BYTES)?;
        // checks the file as serve would read it
        let parsed = crate::formats::compliance_sets_from_toml(&text)
            .with_context(|| format!("--add: {} is not a parameter file", out.display()))?;
        let table: toml::Table = crate::files::from_toml(&text)?;
        match table.get("set").and_then(|s| s.as_array()) {
            Some(a) => sets.extend(a.iter().filter_map(|t| t.as_table().cloned())),
            None => {
                let Some(i) = parsed[0].instrument else {
                    bail!(
                        "--add: {} records no instrument (`# instrument:` line): its set cannot \
                         be kept beside another",
                        out.display()
                    );
                };
                let mut t = table;
                t.insert("instrument".into(), toml::Value::String(tool_name(i)));
                sets.push(t);
            }
        }
    }
    let mut new: toml::Table = crate::files::from_toml(set)?;
    new.insert("instrument".into(), toml::Value::String(tool_name(inst)));
    sets.retain(|t| {
        t.get("instrument")
            .and_then(|v| v.as_str())
            .and_then(|n| crate::config::find_instrument(n).ok())
            .is_none_or(|i| i.model != inst.model)
    });
    sets.push(new);
    let mut root = toml::Table::new();
    root.insert(
        "set".into(),
        toml::Value::Array(sets.into_iter().map(toml::Value::Table).collect()),
    );
    Ok(format!(
        "# parameter sets, one per instrument (`fit --add`)\n{}",
        toml::to_string(&root)?
    ))
}

/// An instrument as the console writes it (`NAME:MODEL[range]`).
fn tool_name(i: &dvrk_compliance::Instrument) -> String {
    i.tool_type().to_string()
}

/// Each input file with its provenance.
pub type InputFiles = Vec<(PathBuf, super::provenance::Provenance)>;

/// The provenance of every input file, and the one instrument they name (if any); files of
/// different instruments are refused.
pub fn inputs_provenance(args: &FitArgs) -> anyhow::Result<(InputFiles, Option<String>)> {
    let files = args
        .clamp
        .iter()
        .chain(args.torque_offset.iter())
        .chain(args.dynamics.iter())
        .map(|p| Ok((p.clone(), super::provenance::read(p)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let instrument =
        super::provenance::one_instrument(files.iter().map(|(p, v)| (p.as_path(), v)))?;
    Ok((files, instrument))
}

/// Runs `fit`: computes everything first, then draws the figures, then writes the parameter file
/// atomically, then prints.
pub fn run_fit(args: &FitArgs) -> anyhow::Result<()> {
    let outcome = compute(args)?;
    let (inputs, instrument) = inputs_provenance(args)?;
    let mut text = String::new();
    let mut arms: Vec<&str> = inputs
        .iter()
        .filter_map(|(_, p)| p.arm.as_deref())
        .collect();
    arms.sort_unstable();
    arms.dedup();
    text.push_str(&format!(
        "# arm: {}\n# instrument: {}\n# date: {}\n# command: {}\n",
        if arms.is_empty() {
            "not recorded".to_owned()
        } else {
            arms.join(", ")
        },
        instrument.as_deref().unwrap_or("not recorded"),
        super::provenance::utc_now(),
        super::provenance::command_line()
    ));
    for (p, v) in &inputs {
        if let Some(c) = &v.command {
            text.push_str(&format!(
                "# input {}: recorded {} by `{c}`\n",
                p.display(),
                v.date.as_deref().unwrap_or("at an unknown date")
            ));
        }
    }
    text.push_str("# Fitted by `dvrk-sidecar fit` from:\n");
    for p in args
        .clamp
        .iter()
        .chain(args.torque_offset.iter())
        .chain(args.dynamics.iter())
    {
        text.push_str(&format!("#   {}\n", p.display()));
    }
    for j in &outcome.joints {
        text.push_str(&format!(
            "# joint {}: {} depths, r^2 of 1/K(L) {:.5}, backlash mean {:.3} mrad\n",
            j.joint,
            j.depths.len(),
            j.r_squared,
            j.backlash_rad * 1e3
        ));
    }
    for d in &outcome.dynamics {
        text.push_str(&format!(
            "# joint {} dynamics: torque residual rms {:.4} N·m before, {:.4} N·m after the model\n",
            d.joint, d.rms_before_nm, d.rms_after_nm
        ));
        if let Some(g) = d.params.distal_gravity {
            let w = g.weight_n;
            let sd = g.weight_sigma_n;
            text.push_str(&format!(
                "# joint {} distal weight (RCM frame): [{:.4} ± {:.4}, {:.4} ± {:.4}, {:.4} ± {:.4}] N \
                 (1 sigma), relative to the torque offset at L = {:.3} m\n",
                d.joint,
                w[0],
                sd[0],
                w[1],
                sd[1],
                w[2],
                sd[2],
                g.reference_insertion_m
            ));
        }
    }
    if args.add {
        let Some(inst) = instrument.as_deref() else {
            bail!(
                "--add: the data files record no instrument (`# instrument:` line), so the set \
                 cannot be filed under one; fit without --add"
            );
        };
        text.push_str(&add_set(&args.out, inst, &params_to_toml(&outcome.params))?);
    } else {
        text.push_str(&params_to_toml(&outcome.params));
    }
    // Figures first: a figure that cannot be drawn (no font) fails the command before any
    // parameter file is written.
    if let Some(dir) = &args.plots {
        super::plots::fit_figures(dir, &args.font, &outcome)?;
    }
    data::write_atomically(&args.out, text.as_bytes())?;
    // Written with error handling (not `println!`), so a closed pipe is an error, not a panic.
    let text = if args.json {
        let mut doc: serde_json::Value = serde_json::from_str(&to_json(&outcome.joints)?)?;
        if !outcome.dynamics.is_empty()
            && let Some(obj) = doc.as_object_mut()
        {
            obj.insert("dynamics".into(), dynamics_json(&outcome.dynamics));
        }
        format!("{doc}\n")
    } else {
        format!("{}wrote {}\n", report(&outcome), args.out.display())
    };
    std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
        .context("writing to stdout")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Rows are irregular for the sample-by-sample fit past `IRREGULAR_ROWS_LIMIT`; a stepped
    /// excitation's rows, averaged over command periods first, are not warned of.
    #[test]
    fn irregular_rows_are_warned_of_where_the_fit_takes_them_as_they_come() {
        let rows = |keep: &dyn Fn(u32) -> bool| -> Vec<DynamicsSample> {
            (0..3000u32)
                .filter(|&i| keep(i))
                .map(|i| DynamicsSample {
                    t_s: f64::from(i) / 1500.0,
                    position: [0.0, 0.0, 0.1],
                    effort_nm: [0.0; 2],
                })
                .collect()
        };
        // One row in 20 lost: 5.3% of the intervals doubled, within the limit.
        let few = rows(&|i| i % 20 != 7);
        assert_eq!(irregular_rows_warning(Excitation::Smooth, &[&few]), None);
        // One in 10: 11.1%.
        let many = rows(&|i| i % 10 != 7);
        let w = irregular_rows_warning(Excitation::Smooth, &[&many]).expect("a warning");
        assert!(w.starts_with("11.1% of the intervals between rows"), "{w}");
        assert!(w.contains("(0.667 ms; at most 8% is trusted)"), "{w}");
        assert!(w.contains("--commanded-hz"), "{w}");
        let stepped = Excitation::Stepped {
            commanded_hz: 100.0,
        };
        assert_eq!(irregular_rows_warning(stepped, &[&many]), None);
        // Rows no faster than the commands are fitted as they come, and warned of.
        let slow = Excitation::Stepped {
            commanded_hz: 1500.0,
        };
        assert!(irregular_rows_warning(slow, &[&many]).is_some());
        assert_eq!(irregular_rows_warning(Excitation::Smooth, &[]), None);
    }

    /// The real 2017 recordings, shipped in the repository's `data/2017/`. Missing data fails the
    /// test: it is the acceptance data of the fit.
    pub(crate) fn shared_data(name: &str) -> PathBuf {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../data/2017")
            .join(name);
        assert!(
            p.is_file(),
            "real calibration data {} is missing",
            p.display()
        );
        p
    }

    fn args(clamp: Vec<PathBuf>, sweep: Vec<PathBuf>, joint: Vec<u8>, out: PathBuf) -> FitArgs {
        FitArgs {
            add: false,
            clamp,
            torque_offset: sweep,
            joint,
            out,
            plots: None,
            json: true,
            model: ModelArg::Paper,
            tau_min_nm: vec![0.1, 0.2],
            font: PathBuf::from(super::super::plots::DEFAULT_FONT),
            dynamics: None,
            gate_sigmas: 4.0,
            split: SplitArg::Auto,
        }
    }

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dvrk-calib-fit-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn real_2017_clamp_file_gives_the_published_stiffness_range() {
        let clamp = shared_data("dvrk2017-clamp-joint1.csv");
        let sweep = shared_data("dvrk2017-torque-offset-joint1.csv");
        let out = tmpdir("real").join("params.toml");
        let o = compute(&args(vec![clamp], vec![sweep], vec![1], out)).unwrap();
        assert_eq!(o.joints.len(), 1);
        let j = &o.joints[0];
        assert_eq!(j.joint, 1);
        assert_eq!(j.depths.len(), 14);
        let first = j.depths[0].stiffness_nm_per_rad;
        let last = j.depths[13].stiffness_nm_per_rad;
        // README of the data: about 13 N·m/rad at the first depth, about 29 at the last (10 %).
        assert!((first / 13.0 - 1.0).abs() <= 0.10, "first depth {first}");
        assert!((last / 29.0 - 1.0).abs() <= 0.10, "last depth {last}");
        // rising with depth, and the cubic follows it
        assert!(j.r_squared > 0.95, "{}", j.r_squared);
        for l in [0.1, 0.15, 0.2] {
            assert!(fit::eval_cubic(&j.inverse_compliance_nm_per_rad, l) > 0.0);
        }
        // backlash of the size the README reports (1.3 - 4.5 mrad per depth, order of magnitude)
        assert!(
            j.backlash_rad > 1e-3 && j.backlash_rad < 5e-3,
            "{}",
            j.backlash_rad
        );
        // One tau_0 (issue 10): the clamp rows were refitted under the written table.
        let t = &o.offsets[0];
        for r in &o.clamp_rows {
            let want = super::super::calibrate::lookup(t, r.position_rad);
            assert_eq!(r.torque_offset_nm, want);
        }
        let h = o.params.joint[0].hysteresis.unwrap();
        assert_eq!(h.kind, dvrk_compliance::HysteresisKind::Friction);
        assert!(h.gap_rad > 0.002 && h.gap_rad < 0.02, "{h:?}");
        // the sweep: 14 depths, tau_0 hardly depends on depth (paper Fig. 4)
        assert_eq!(t.depths, 14);
        assert!(t.mean_depth_spread_nm < 0.02, "{}", t.mean_depth_spread_nm);
        // and the parameter file validates with the fitted torque-offset table
        assert_eq!(
            o.params.joint[0].torque_offset.position_rad.len(),
            t.position_rad.len()
        );
    }

    #[test]
    fn missing_joint_for_2017_file_is_an_error() {
        let clamp = shared_data("dvrk2017-clamp-joint1.csv");
        let out = tmpdir("nojoint").join("params.toml");
        let err = format!(
            "{:#}",
            compute(&args(vec![clamp], vec![], vec![], out))
                .err()
                .unwrap()
        );
        assert!(err.contains("--joint"), "{err}");
    }

    /// The 2017 recordings, as the paper reads them (lines by direction of motion): a friction
    /// hysteresis whose gap falls from 9.1 to 3.1 mrad as the shaft stiffens, but whose torque
    /// (gap x stiffness, about 0.094 N·m with the torque-offset sweep) scatters by 9%: no
    /// warning. Read as a play behind a friction (`--split load-friction`), the play scatters
    /// (by 46% with the sweep, 60% without, as here): a warning that names it.
    #[test]
    fn a_hysteresis_that_moves_with_the_depth_is_warned_of() {
        let clamp = shared_data("dvrk2017-clamp-joint1.csv");
        let out = tmpdir("spread").join("params.toml");
        let mut a = args(vec![clamp], vec![], vec![1], out);
        let paper = compute(&a).unwrap();
        assert_eq!(paper.joints[0].depths[0].branches, fit::Branches::Motion);
        assert_eq!(hysteresis_spread_warning(&paper.joints[0]), None);
        a.split = SplitArg::LoadFriction;
        let friction = compute(&a).unwrap();
        let j = &friction.joints[0];
        assert!(
            j.depths
                .iter()
                .all(|d| d.branches == fit::Branches::LoadFriction)
        );
        let w = hysteresis_spread_warning(j).expect("a warning");
        let pct: f64 = w
            .strip_prefix("joint 1: the play scatters by ")
            .and_then(|r| r.split('%').next())
            .and_then(|p| p.parse().ok())
            .expect(&w);
        assert!(pct > 100.0 * fit::HYSTERESIS_SPREAD_LIMIT, "{w}");
        assert!(
            w.contains("(load+fr)") && w.contains("--split motion"),
            "{w}"
        );
    }

    #[test]
    fn json_has_exactly_the_documented_shape() {
        let clamp = shared_data("dvrk2017-clamp-joint1.csv");
        let out = tmpdir("json").join("params.toml");
        let o = compute(&args(vec![clamp], vec![], vec![1], out)).unwrap();
        let v: serde_json::Value = serde_json::from_str(&to_json(&o.joints).unwrap()).unwrap();
        let keys = |v: &serde_json::Value| -> Vec<String> {
            let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
            k.sort();
            k
        };
        assert_eq!(keys(&v), ["joints"]);
        let j = &v["joints"][0];
        assert_eq!(
            keys(j),
            [
                "backlash_rad",
                "depths",
                "hysteresis_gap_rad",
                "hysteresis_kind",
                "index",
                "inverse_compliance_nm_per_rad",
                "r_squared"
            ]
        );
        assert_eq!(j["index"], 1);
        // Issue 10: the 2017 clamp hysteresis has the sign of friction.
        assert_eq!(j["hysteresis_kind"], "friction");
        assert!(j["hysteresis_gap_rad"].as_f64().unwrap() > 0.0, "{j}");
        assert_eq!(
            j["inverse_compliance_nm_per_rad"].as_array().unwrap().len(),
            4
        );
        let d = &j["depths"][0];
        assert_eq!(
            keys(d),
            [
                "backlash_rad",
                "friction_nm",
                "insertion_m",
                "points",
                "slopes",
                "stiffness_nm_per_rad"
            ]
        );
        assert_eq!(d["slopes"].as_array().unwrap().len(), 2);
        // the 2017 recordings keep the lines by direction of motion: no friction taken out
        assert_eq!(d["friction_nm"], 0.0);
        assert!(d["points"].as_u64().unwrap() > 100);
    }

    #[test]
    fn a_failed_fit_writes_nothing() {
        let dir = tmpdir("fail");
        // one depth only: every line fits but no cubic can be drawn through one stiffness
        let clamp = dir.join("one-depth.csv");
        let text = std::fs::read_to_string(shared_data("dvrk2017-clamp-joint1.csv")).unwrap();
        let one: Vec<&str> = text
            .lines()
            .enumerate()
            .filter(|(i, l)| *i == 0 || l.split(',').nth(1) == Some("0"))
            .map(|(_, l)| l)
            .collect();
        std::fs::write(&clamp, one.join("\n")).unwrap();
        let out = dir.join("params.toml");
        let _ = std::fs::remove_file(&out);
        let err = format!(
            "{:#}",
            run_fit(&args(vec![clamp], vec![], vec![1], out.clone())).unwrap_err()
        );
        assert!(err.contains("distinct insertion depths"), "{err}");
        assert!(!out.exists());
    }

    #[test]
    fn missing_font_fails_before_writing_the_parameters() {
        let dir = tmpdir("nofont");
        let out = dir.join("params.toml");
        let _ = std::fs::remove_file(&out);
        let mut a = args(
            vec![shared_data("dvrk2017-clamp-joint1.csv")],
            vec![],
            vec![1],
            out.clone(),
        );
        a.plots = Some(dir.join("plots"));
        a.font = PathBuf::from("/nonexistent/DejaVuSans.ttf");
        let err = format!("{:#}", run_fit(&a).unwrap_err());
        assert!(err.contains("/nonexistent/DejaVuSans.ttf"), "{err}");
        assert!(!out.exists());
    }

    #[test]
    fn written_file_loads_as_a_compliance_config() {
        let dir = tmpdir("write");
        let out = dir.join("params.toml");
        let mut a = args(
            vec![shared_data("dvrk2017-clamp-joint1.csv")],
            vec![shared_data("dvrk2017-torque-offset-joint1.csv")],
            vec![1],
            out.clone(),
        );
        a.json = false;
        a.plots = Some(dir.join("plots"));
        run_fit(&a).unwrap();
        let cfg = crate::config::load_compliance(&out).unwrap();
        let range = cfg.insertion_range_m(0).unwrap();
        assert!(range[0] > 0.09 && range[1] < 0.23);
        assert!(cfg.insertion_range_m(1).is_none());
        for stem in [
            "fig4-torque-offset-joint1",
            "fig5-clamp-joint1",
            "fig6-inverse-compliance-joint1",
        ] {
            for ext in ["svg", "png"] {
                let p = dir.join("plots").join(format!("{stem}.{ext}"));
                assert!(
                    std::fs::metadata(&p).unwrap().len() > 1000,
                    "{}",
                    p.display()
                );
            }
        }
    }
}
