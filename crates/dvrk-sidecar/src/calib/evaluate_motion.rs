//! `dvrk-sidecar evaluate --params P --scenario S.toml --seconds N [--plots DIR] --json`:
//! the correction judged in motion against the simulator's ground truth (issue 10).
//!
//! The scenario runs through the whole stack as `serve` runs it: the emulated boards answer the
//! real protocol in process (`dvrk_sim::SimPort`), `ArmReader` turns the replies into SI samples,
//! [`crate::cycle::compute_dynamic`] applies the internal-torque model, the gate, Eq. 1 and the
//! kinematics. Each cycle's raw and compensated tip positions are compared with the true tip:
//! the simulator's true joints through the same kinematics (`--tool`, `--arm`), so another
//! instrument or arm kind is judged as if it were mounted on the simulated shaft.
//!
//! `false_activation_fraction[j]`: the share of valid cycles in which joint j's correction was
//! active and moved the joint away from its true angle by more than [`WRONG_WAY_TOLERANCE_RAD`]
//! (a correction the wrong way, or past twice the true deflection). Until issue 20 it counted
//! the cycles corrected without contact; since the free-space play is corrected on purpose
//! (issue 20 item 3), a correction without contact is not false by itself, one that makes the
//! joint worse is.
//!
//! Issue 20 adds, per valid cycle: `harm_mm` {`max`, `p99`}, the compensated tip error minus the
//! raw one (positive: the correction made that cycle worse); `bound_mm` {`mean`, `p95`}, the
//! model's 95% bound on the compensated tip error; and `coverage`, the fraction of cycles whose
//! compensated error is within that bound.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use dvrk_compliance::{Compensator, ComplianceConfig, PsmKinematics};
use dvrk_io::ArmSample;
use dvrk_io::reader::{AccessMode, ArmReader};
use dvrk_sim::sim_port;
use serde::Serialize;

use super::plots::{Kind, Panel, Series, render};
use crate::cycle::{ReadOutcome, compute_dynamic};
use crate::text::num;

/// Mean, 95th percentile and maximum of a tip error (mm).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ErrorStats {
    pub mean: f64,
    pub p95: f64,
    pub max: f64,
}

/// Raw and compensated tip errors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TipErrors {
    pub raw: ErrorStats,
    pub compensated: ErrorStats,
}

/// Per-cycle harm (mm): compensated tip error minus raw tip error.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HarmStats {
    pub max: f64,
    pub p99: f64,
}

/// The model's 95% bound on the compensated tip error (mm).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct BoundStats {
    pub mean: f64,
    pub p95: f64,
}

/// The JSON of `evaluate --scenario`, exactly the issues' (10 and 20).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MotionEvaluation {
    pub tip_error_mm: TipErrors,
    pub correction_active_fraction: [f64; 2],
    pub false_activation_fraction: [f64; 2],
    pub harm_mm: HarmStats,
    pub bound_mm: BoundStats,
    pub coverage: f64,
}

/// One cycle's errors, for the figure.
#[derive(Clone, Copy, Debug)]
pub struct Trace {
    pub t_s: f64,
    pub raw_mm: f64,
    pub compensated_mm: f64,
    /// The model's 95% bound on the compensated error.
    pub bound_mm: f64,
}

fn stats(values: &mut [f64]) -> ErrorStats {
    if values.is_empty() {
        return ErrorStats::default();
    }
    let n = values.len();
    let mean = values.iter().sum::<f64>() / n as f64;
    values.sort_by(f64::total_cmp);
    // Nearest-rank 95th percentile.
    let rank = ((0.95 * n as f64).ceil() as usize).clamp(1, n);
    ErrorStats {
        mean,
        p95: values[rank - 1],
        max: values[n - 1],
    }
}

/// The nearest-rank `p` quantile of sorted `values` (0 for none).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let n = sorted.len();
    sorted[((p * n as f64).ceil() as usize).clamp(1, n) - 1]
}

/// How much worse than raw (rad) a joint must be made to count as a false activation: 1 µrad,
/// below a Classic PSM encoder count (7.7 µrad) and 0.2 µm at the tip.
pub const WRONG_WAY_TOLERANCE_RAD: f64 = 1e-6;

/// Runs `scenario` for `seconds` at `rate_hz` through emulator, reader, model and kinematics.
pub fn evaluate_scenario(
    cfg: &ComplianceConfig,
    fk: &PsmKinematics,
    scenario: &dvrk_sim::Scenario,
    io: dvrk_io::IoConfig,
    seconds: f64,
    rate_hz: f64,
) -> anyhow::Result<(MotionEvaluation, Vec<Trace>)> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 3600.0) {
        bail!("--seconds {}: must be in (0, 3600]", num(seconds));
    }
    if !(rate_hz.is_finite() && (100.0..=20_000.0).contains(&rate_hz)) {
        bail!("--rate-hz {}: must be within 100..=20000", num(rate_hz));
    }
    let period_ns = (1e9 / rate_hz).round() as u64;
    let cycles = (seconds * rate_hz).round() as u64;
    let mut port = sim_port(scenario, &io).context("building the simulated PSM")?;
    port.link_mut().advance_to(0);
    let mut reader = ArmReader::new(port, io, AccessMode::Exclusive);
    let mut compensator = Compensator::new();
    let mut arm = ArmSample::default();
    let (mut raw, mut comp) = (Vec::new(), Vec::new());
    let (mut harm, mut bound) = (Vec::new(), Vec::new());
    let mut covered = 0u64;
    let mut traces = Vec::new();
    let (mut active, mut false_active) = ([0u64; 2], [0u64; 2]);
    let mut t_ns = 0u64;
    for _ in 0..cycles {
        t_ns += period_ns;
        reader.port_mut().link_mut().advance_to(t_ns);
        let outcome = match reader.read(t_ns, &mut arm) {
            Ok(()) => ReadOutcome::Ok,
            Err(_) => ReadOutcome::Error,
        };
        let r = compute_dynamic(cfg, &mut compensator, fk, &arm, outcome);
        if !r.valid {
            continue;
        }
        let truth = reader.port_mut().link_mut().emulator().psm().truth();
        // The true joints through the same kinematics as the estimates (`--tool`, `--arm`):
        // the simulated shaft's joint errors judged as if that instrument were mounted. The
        // simulator's own tip (`truth.tip_position_m`) is the Classic large needle driver's,
        // which against another instrument's estimate would be tens of mm off by construction.
        let q = &truth.q_true;
        let true_tip = fk
            .forward(&[q[0], q[1], q[2], q[3], q[4], q[5]])
            .translation
            .vector;
        let e_raw = (r.raw_pose.translation.vector - true_tip).norm() * 1e3;
        let e_comp = (r.compensated_pose.translation.vector - true_tip).norm() * 1e3;
        let b = r.correction.tip_bound_m * 1e3;
        raw.push(e_raw);
        comp.push(e_comp);
        harm.push(e_comp - e_raw);
        bound.push(b);
        covered += u64::from(e_comp <= b);
        traces.push(Trace {
            t_s: t_ns as f64 * 1e-9,
            raw_mm: e_raw,
            compensated_mm: e_comp,
            bound_mm: b,
        });
        for j in 0..2 {
            if r.correction.active[j] {
                active[j] += 1;
                let raw_error = (arm.position[j] - truth.q_true[j]).abs();
                let compensated_error = (r.correction.position[j] - truth.q_true[j]).abs();
                if compensated_error > raw_error + WRONG_WAY_TOLERANCE_RAD {
                    false_active[j] += 1;
                }
            }
        }
    }
    let n = raw.len();
    if n == 0 {
        bail!("no valid sample in {cycles} cycles: the emulated boards never answered");
    }
    let frac = |c: [u64; 2]| c.map(|x| x as f64 / n as f64);
    harm.sort_by(f64::total_cmp);
    let bound_mean = bound.iter().sum::<f64>() / n as f64;
    bound.sort_by(f64::total_cmp);
    Ok((
        MotionEvaluation {
            tip_error_mm: TipErrors {
                raw: stats(&mut raw),
                compensated: stats(&mut comp),
            },
            correction_active_fraction: frac(active),
            false_activation_fraction: frac(false_active),
            harm_mm: HarmStats {
                max: harm[n - 1],
                p99: quantile(&harm, 0.99),
            },
            bound_mm: BoundStats {
                mean: bound_mean,
                p95: quantile(&bound, 0.95),
            },
            coverage: covered as f64 / n as f64,
        },
        traces,
    ))
}

/// The tip error over time, raw against compensated (`tip-error.svg` and `.png`).
pub fn tip_error_figure(dir: &Path, font: &Path, traces: &[Trace]) -> anyhow::Result<[PathBuf; 2]> {
    // At most about 4000 points per line.
    let step = (traces.len() / 4000).max(1);
    let line = |f: fn(&Trace) -> f64| -> Vec<(f64, f64)> {
        traces.iter().step_by(step).map(|t| (t.t_s, f(t))).collect()
    };
    let panel = Panel {
        title: "Tip error against the simulator's truth".into(),
        x_label: "time (s)".into(),
        y_label: "tip error (mm)".into(),
        series: vec![
            Series {
                label: Some("raw".into()),
                color: plotters::style::RGBColor(200, 40, 40),
                kind: Kind::Line,
                points: line(|t| t.raw_mm),
            },
            Series {
                label: Some("compensated".into()),
                color: plotters::style::RGBColor(30, 80, 200),
                kind: Kind::Line,
                points: line(|t| t.compensated_mm),
            },
            Series {
                label: Some("95% bound of the compensated error".into()),
                color: plotters::style::RGBColor(120, 120, 120),
                kind: Kind::Line,
                points: line(|t| t.bound_mm),
            },
        ],
    };
    render(dir, "tip-error", font, &[panel], 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_use_the_nearest_rank() {
        let mut v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = stats(&mut v);
        assert_eq!((s.mean, s.p95, s.max), (50.5, 95.0, 100.0));
        assert_eq!(stats(&mut []), ErrorStats::default());
        let mut one = [3.0];
        assert_eq!(stats(&mut one).p95, 3.0);
        let v: Vec<f64> = (1..=200).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.99), 198.0);
        assert_eq!(quantile(&v, 0.95), 190.0);
        assert_eq!(quantile(&[], 0.5), 0.0);
    }
}
