//! `dvrk-sidecar evaluate`: how much the correction helps while the tip is held in a divot
//! (paper Figs. 7-8).
//!
//! Per pushed joint: the range and standard deviation of the uncorrected and corrected joint
//! position over every row of that joint's pushes (the tip does not move, so a perfect correction
//! is constant), and, on simulator data with ground truth, the tip error in mm against the true
//! tip before (forward kinematics of the measured joints) and after (of the corrected joints).

use std::path::PathBuf;

use anyhow::Context;
use dvrk_compliance::{ArmKind, ComplianceConfig, PsmKinematics, instrument};
use serde::Serialize;

use super::data::{self, DivotRow};
use super::plots::{Kind, Panel, Series, render};

/// Which PSM the kinematics are for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ArmArg {
    Classic,
    Si,
}

/// `evaluate --params P --data divot.csv [--plots DIR] [--json]`, or
/// `evaluate --params P --scenario S.toml --seconds N [--plots DIR] [--json]`.
#[derive(Clone, Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Compliance parameter file (TOML).
    #[arg(long)]
    pub params: PathBuf,
    /// Divot-push data file (from `calibrate divot`, or recorded).
    #[arg(
        long,
        required_unless_present = "scenario",
        conflicts_with = "scenario"
    )]
    pub data: Option<PathBuf>,
    /// Simulator scenario (config/sim/*.toml) to run through emulator, reader, model and
    /// kinematics, judged against the simulator's truth.
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Simulated seconds of the scenario.
    #[arg(long, default_value_t = 30.0, requires = "scenario")]
    pub seconds: f64,
    /// Cycle rate of the evaluation (Hz), as `serve` would read the boards.
    #[arg(long, default_value_t = 1500.0, requires = "scenario")]
    pub rate_hz: f64,
    /// Board conversion config used by the emulator and the reader (with --scenario).
    #[arg(long, default_value = "config/io/psm-classic.toml")]
    pub io: PathBuf,
    /// Directory for the figures (SVG and PNG).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Instrument (dVRK name), for the tip error.
    #[arg(long, default_value = "LARGE_NEEDLE_DRIVER_400006")]
    pub tool: String,
    /// Arm kind, for the tip error.
    #[arg(long, value_enum, default_value = "classic")]
    pub arm: ArmArg,
    /// TTF font for the figure text.
    #[arg(long, default_value = super::plots::DEFAULT_FONT)]
    pub font: PathBuf,
}

/// Spread of one position series.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Spread {
    pub range_rad: f64,
    pub std_rad: f64,
}

/// Tip error against ground truth (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TipError {
    pub before_mean_mm: f64,
    pub before_max_mm: f64,
    pub after_mean_mm: f64,
    pub after_max_mm: f64,
}

/// Result for one pushed joint.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JointEvaluation {
    pub index: u8,
    pub rows: usize,
    pub uncorrected: Spread,
    pub corrected: Spread,
    /// Simulator data only.
    pub tip_error: Option<TipError>,
}

#[derive(Serialize)]
struct JsonEvaluation<'a> {
    joints: &'a [JointEvaluation],
}

fn spread(values: &[f64]) -> Spread {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    Spread {
        range_rad: hi - lo,
        std_rad: var.sqrt(),
    }
}

/// Corrected joint 1-3 positions of a row.
fn corrected(cfg: &ComplianceConfig, r: &DivotRow) -> [f64; 3] {
    cfg.correct(&[r.position[0], r.position[1], r.position[2]], &r.effort)
        .position
}

/// Evaluates `rows` with `cfg`; `fk` is used for the tip error when the rows carry truth.
pub fn evaluate(
    cfg: &ComplianceConfig,
    fk: &PsmKinematics,
    rows: &[DivotRow],
) -> Vec<JointEvaluation> {
    let mut out = Vec::new();
    for joint in [1u8, 2] {
        let mine: Vec<&DivotRow> = rows.iter().filter(|r| r.joint == joint).collect();
        if mine.is_empty() {
            continue;
        }
        let j = usize::from(joint) - 1;
        let raw: Vec<f64> = mine.iter().map(|r| r.position[j]).collect();
        let hat: Vec<f64> = mine.iter().map(|r| corrected(cfg, r)[j]).collect();
        let tip_error = if mine.iter().all(|r| r.truth.is_some()) {
            let (mut b, mut a) = (Vec::new(), Vec::new());
            for r in &mine {
                let Some(t) = r.truth else { continue };
                let truth = nalgebra::Vector3::from(t.tip_m);
                let c = corrected(cfg, r);
                let mut q_hat = r.position;
                q_hat[..3].copy_from_slice(&c);
                let before = fk.forward(&r.position).translation.vector - truth;
                let after = fk.forward(&q_hat).translation.vector - truth;
                b.push(before.norm() * 1e3);
                a.push(after.norm() * 1e3);
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
            let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
            Some(TipError {
                before_mean_mm: mean(&b),
                before_max_mm: max(&b),
                after_mean_mm: mean(&a),
                after_max_mm: max(&a),
            })
        } else {
            None
        };
        out.push(JointEvaluation {
            index: joint,
            rows: mine.len(),
            uncorrected: spread(&raw),
            corrected: spread(&hat),
            tip_error,
        });
    }
    out
}

/// Figures 7 (joint 1) and 8 (joint 2): uncorrected and corrected position against time, one
/// panel per push direction, with the true angle when known.
pub fn divot_figures(
    dir: &std::path::Path,
    font: &std::path::Path,
    cfg: &ComplianceConfig,
    rows: &[DivotRow],
) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for joint in [1u8, 2] {
        let j = usize::from(joint) - 1;
        let mut panels = Vec::new();
        for (dir_name, push) in [
            ("positive", 2 * u32::from(joint) - 2),
            ("negative", 2 * u32::from(joint) - 1),
        ] {
            let mine: Vec<&DivotRow> = rows
                .iter()
                .filter(|r| r.joint == joint && r.push_index == push)
                .collect();
            if mine.is_empty() {
                continue;
            }
            let t0 = mine[0].t_s;
            let mut series = vec![
                Series {
                    label: Some("uncorrected".into()),
                    color: plotters::style::RGBColor(200, 40, 40),
                    kind: Kind::Line,
                    points: mine.iter().map(|r| (r.t_s - t0, r.position[j])).collect(),
                },
                Series {
                    label: Some("corrected".into()),
                    color: plotters::style::RGBColor(30, 80, 200),
                    kind: Kind::Line,
                    points: mine
                        .iter()
                        .map(|r| (r.t_s - t0, corrected(cfg, r)[j]))
                        .collect(),
                },
            ];
            if mine.iter().all(|r| r.truth.is_some()) {
                series.push(Series {
                    label: Some("true shaft angle".into()),
                    color: plotters::style::RGBColor(60, 60, 60),
                    kind: Kind::Rings,
                    points: mine
                        .iter()
                        .filter_map(|r| r.truth.map(|t| (r.t_s - t0, t.position_rad[j])))
                        .collect(),
                });
            }
            panels.push(Panel {
                title: format!("Joint {joint} pushing in the {dir_name} direction"),
                x_label: "time (s)".into(),
                y_label: format!("joint {joint} position (rad)"),
                series,
            });
        }
        if panels.is_empty() {
            continue;
        }
        let fig = if joint == 1 { 7 } else { 8 };
        written.extend(render(
            dir,
            &format!("fig{fig}-divot-joint{joint}"),
            font,
            &panels,
            2,
        )?);
    }
    Ok(written)
}

/// Runs `evaluate`.
pub fn run_evaluate(args: &EvaluateArgs) -> anyhow::Result<()> {
    let cfg = crate::config::load_compliance(&args.params)?;
    let fk = kinematics(args)?;
    let Some(data_path) = &args.data else {
        return run_evaluate_scenario(args, &cfg, &fk);
    };
    let rows = data::read_divot(data_path)?;
    let result = evaluate(&cfg, &fk, &rows);
    if let Some(dir) = &args.plots {
        divot_figures(dir, &args.font, &cfg, &rows)?;
    }
    use std::fmt::Write as _;
    let mut text = String::new();
    if args.json {
        text = serde_json::to_string(&JsonEvaluation { joints: &result })?;
        text.push('\n');
    } else {
        for e in &result {
            let _ = writeln!(
                text,
                "joint {} ({} rows): uncorrected range {:.3} mrad, std {:.3} mrad; corrected range {:.3} mrad, std {:.3} mrad",
                e.index,
                e.rows,
                e.uncorrected.range_rad * 1e3,
                e.uncorrected.std_rad * 1e3,
                e.corrected.range_rad * 1e3,
                e.corrected.std_rad * 1e3
            );
            if let Some(t) = e.tip_error {
                let _ = writeln!(
                    text,
                    "  tip error vs truth: before mean {:.3} mm (max {:.3}), after mean {:.3} mm (max {:.3})",
                    t.before_mean_mm, t.before_max_mm, t.after_mean_mm, t.after_max_mm
                );
            }
        }
    }
    // Written with error handling (not `println!`), so a closed pipe is an error, not a panic.
    std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
        .context("writing to stdout")?;
    Ok(())
}

/// `evaluate --scenario`: see [`super::evaluate_motion`].
fn run_evaluate_scenario(
    args: &EvaluateArgs,
    cfg: &ComplianceConfig,
    fk: &PsmKinematics,
) -> anyhow::Result<()> {
    let Some(path) = &args.scenario else {
        anyhow::bail!("give --data FILE or --scenario FILE");
    };
    let sc = crate::config::load_scenario(path)?;
    let io = crate::config::load_io(&args.io)?;
    let (result, traces) =
        super::evaluate_motion::evaluate_scenario(cfg, fk, &sc, io, args.seconds, args.rate_hz)?;
    if let Some(dir) = &args.plots {
        super::evaluate_motion::tip_error_figure(dir, &args.font, &traces)?;
    }
    let text = if args.json {
        let mut t = serde_json::to_string(&result)?;
        t.push('\n');
        t
    } else {
        let e = &result.tip_error_mm;
        format!(
            "tip error (mm): raw mean {:.3}, p95 {:.3}, max {:.3}; compensated mean {:.3}, p95 {:.3}, max {:.3}\n\
             correction active: joint 1 {:.1}%, joint 2 {:.1}%; false activation: joint 1 {:.2}%, joint 2 {:.2}%\n\
             harm (compensated - raw, mm): max {:.3}, p99 {:.3}; 95% bound (mm): mean {:.3}, p95 {:.3}; coverage {:.1}%\n",
            e.raw.mean,
            e.raw.p95,
            e.raw.max,
            e.compensated.mean,
            e.compensated.p95,
            e.compensated.max,
            100.0 * result.correction_active_fraction[0],
            100.0 * result.correction_active_fraction[1],
            100.0 * result.false_activation_fraction[0],
            100.0 * result.false_activation_fraction[1],
            result.harm_mm.max,
            result.harm_mm.p99,
            result.bound_mm.mean,
            result.bound_mm.p95,
            100.0 * result.coverage,
        )
    };
    std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
        .context("writing to stdout")?;
    Ok(())
}

fn kinematics(args: &EvaluateArgs) -> anyhow::Result<PsmKinematics> {
    let tool = instrument(&args.tool).with_context(|| {
        format!(
            "--tool {}: unknown instrument; use a dVRK name such as LARGE_NEEDLE_DRIVER_400006",
            args.tool
        )
    })?;
    let arm = match args.arm {
        ArmArg::Classic => ArmKind::Classic,
        ArmArg::Si => ArmKind::Si,
    };
    Ok(PsmKinematics::new(arm, tool))
}

#[cfg(test)]
mod tests {
    use super::data::DivotTruth;
    use super::*;
    use dvrk_compliance::{ComplianceParams, JointParams, ModelKind, TorqueOffsetParams};

    fn model(backlash: f64) -> ComplianceConfig {
        let joint = (1..=2)
            .map(|index| JointParams {
                index,
                backlash_rad: backlash,
                tau_min_nm: 0.05,
                inverse_compliance_nm_per_rad: [0.0, 0.0, 0.0, 20.0],
                insertion_range_m: [0.09, 0.22],
                inverse_compliance_rel_sigma: None,
                backlash_rel_sigma: None,
                torque_offset: TorqueOffsetParams {
                    position_rad: vec![0.0],
                    effort_nm: vec![0.1],
                },
                hysteresis: None,
                dynamics: None,
            })
            .collect();
        ComplianceConfig::from_params(ComplianceParams {
            model: ModelKind::Paper,
            joint,
        })
        .unwrap()
    }

    /// A tip held at the true angle 0.05 rad while joint `joint` pushes: the encoder reads the
    /// true angle plus delta*sgn + tau/20.
    fn push_rows(joint: u8, backlash: f64, fk: &PsmKinematics) -> Vec<DivotRow> {
        let j = usize::from(joint) - 1;
        let q_true = [0.05, -0.02, 0.12, 0.0, 0.0, 0.0];
        let tip = fk.forward(&q_true).translation.vector;
        let mut rows = Vec::new();
        for (k, tau) in [0.0, 0.3, 0.6, 0.9, 1.1, -0.3, -0.6, -1.0]
            .into_iter()
            .enumerate()
        {
            let mut q = q_true;
            if tau != 0.0 {
                q[j] += backlash * f64::signum(tau) + tau / 20.0;
            }
            let mut effort = [0.1, 0.1, 0.0];
            effort[j] += tau;
            rows.push(DivotRow {
                push_index: 2 * (u32::from(joint) - 1) + u32::from(tau < 0.0),
                joint,
                direction: tau.signum() as i8,
                t_s: k as f64,
                position: q,
                effort,
                truth: Some(DivotTruth {
                    position_rad: [q_true[0], q_true[1]],
                    tip_m: [tip.x, tip.y, tip.z],
                }),
            });
        }
        rows
    }

    #[test]
    fn exact_model_removes_the_drift_and_the_tip_error() {
        let fk = PsmKinematics::new(
            ArmKind::Classic,
            instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        let mut rows = push_rows(1, 0.002, &fk);
        rows.extend(push_rows(2, 0.002, &fk));
        let result = evaluate(&model(0.002), &fk, &rows);
        assert_eq!(result.len(), 2);
        for e in &result {
            assert_eq!(e.rows, 8);
            // uncorrected drifts by delta*2 + 2.1/20 rad
            assert!((e.uncorrected.range_rad - (0.004 + 2.1 / 20.0)).abs() < 1e-12);
            assert!(e.corrected.range_rad < 1e-12, "{e:?}");
            let t = e.tip_error.unwrap();
            assert!(t.before_max_mm > 5.0, "{t:?}");
            assert!(t.after_max_mm < 1e-9, "{t:?}");
        }
        // a model that ignores the backlash leaves 2 delta of drift
        let partial = evaluate(&model(0.0), &fk, &rows);
        assert!((partial[0].corrected.range_rad - 0.004).abs() < 1e-12);
    }

    #[test]
    fn real_data_has_no_tip_error() {
        let fk = PsmKinematics::new(
            ArmKind::Classic,
            instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        let mut rows = push_rows(1, 0.0, &fk);
        rows.iter_mut().for_each(|r| r.truth = None);
        let e = &evaluate(&model(0.0), &fk, &rows)[0];
        assert!(e.tip_error.is_none());
        assert_eq!(e.index, 1);
    }
}
