//! `evaluate --scenario` through the real binary (issue 10, items 8-10): each of the project's
//! motion scenarios runs through the emulated boards, the reader, the internal-torque model and
//! the kinematics, and the shipped parameter file meets the goals:
//! - fast free motion: compensated mean tip error <= raw + 0.02 mm, false activation < 1%;
//! - divot push: compensated mean <= 10% of raw;
//! - palpation: compensated mean <= 30% of raw.
//!
//! The same file without its `[joint.dynamics]` (the paper's quasi-static model) fails the free
//! motion goal, so the test can tell the two apart. Short runs (8-10 simulated seconds each).

mod common;

use std::process::Command;

use common::*;
use serde_json::Value;

fn evaluate(params: &str, scenario: &str, seconds: &str, plots: Option<&str>) -> Value {
    evaluate_with(params, scenario, seconds, plots, &[])
}

fn evaluate_with(
    params: &str,
    scenario: &str,
    seconds: &str,
    plots: Option<&str>,
    more: &[&str],
) -> Value {
    let mut args = vec![
        "evaluate",
        "--params",
        params,
        "--scenario",
        scenario,
        "--seconds",
        seconds,
        "--json",
    ];
    if let Some(dir) = plots {
        args.extend(["--plots", dir]);
    }
    args.extend(more);
    let out = Command::new(sidecar_bin())
        .args(&args)
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "evaluate {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The shipped file without its `[joint.dynamics]`: the paper's quasi-static model.
fn quasi_static_file(scratch_name: &str) -> std::path::PathBuf {
    let dir = scratch(scratch_name);
    let text = std::fs::read_to_string(repo().join(PARAMS)).unwrap();
    let stripped: String = text
        .lines()
        .filter(|l| !l.starts_with("dynamics ="))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_ne!(
        stripped.len(),
        text.len(),
        "the shipped file has no dynamics model"
    );
    let quasi = dir.join("quasi-static.toml");
    std::fs::write(&quasi, stripped).unwrap();
    quasi
}

fn pair(v: &Value, key: &str) -> [f64; 2] {
    let a = v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} missing in {v}"));
    assert_eq!(a.len(), 2, "{v}");
    [a[0].as_f64().unwrap(), a[1].as_f64().unwrap()]
}

const PARAMS: &str = "config/compliance/sim-psm.toml";

#[test]
fn fast_free_motion_is_not_corrected_falsely() {
    let v = evaluate(PARAMS, "config/sim/fast-free-motion.toml", "8", None);
    // Exactly the keys of issue 10 and of issue 20 (harm, bound, coverage).
    let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
    assert_eq!(
        keys,
        [
            "bound_mm",
            "correction_active_fraction",
            "coverage",
            "false_activation_fraction",
            "harm_mm",
            "tip_error_mm"
        ],
        "{v}"
    );
    for side in ["raw", "compensated"] {
        for stat in ["mean", "p95", "max"] {
            assert!(num(&v, &["tip_error_mm", side, stat]) >= 0.0);
        }
    }
    let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
    let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
    assert!(
        comp <= raw + 0.02,
        "compensated {comp} mm vs raw {raw} mm: {v}"
    );
    // Without contact the correction is active by design since issue 20 item 3 (the play is
    // corrected toward the side the distal weight and inertia set), so the activation without
    // contact is no longer false by itself: what must not happen is a cycle made worse.
    let fa = pair(&v, "false_activation_fraction");
    assert!(fa.iter().all(|f| (0.0..=1.0).contains(f)), "{v}");
    assert!(num(&v, &["harm_mm", "max"]) <= 0.01, "{v}");
    assert!(comp < raw, "the free-space play is not corrected: {v}");

    // The quasi-static model (the same file without [joint.dynamics]) cannot tell motion from
    // contact, so (issue 20, item 8) it corrects only while the arm is still: in fast motion it
    // leaves the raw values, never worse than them.
    let quasi = quasi_static_file("evaluate-motion");
    let q = evaluate(
        quasi.to_str().unwrap(),
        "config/sim/fast-free-motion.toml",
        "8",
        None,
    );
    let q_raw = num(&q, &["tip_error_mm", "raw", "mean"]);
    let q_comp = num(&q, &["tip_error_mm", "compensated", "mean"]);
    let q_fa = pair(&q, "false_activation_fraction");
    assert!(
        q_comp <= q_raw + 0.02 && q_fa[0] < 0.01 && q_fa[1] < 0.01,
        "without a dynamics model the correction must wait for the arm to be still: {q}"
    );
    assert!(num(&q, &["harm_mm", "max"]) <= 0.5, "{q}");
}

#[test]
fn divot_push_error_is_at_most_ten_percent_of_raw() {
    let dir = scratch("evaluate-motion-divot");
    let plots = dir.join("plots");
    let v = evaluate(
        PARAMS,
        "config/sim/divot-push.toml",
        "10",
        Some(plots.to_str().unwrap()),
    );
    let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
    let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
    assert!(raw > 1.0, "the push does not load the shaft: {v}");
    assert!(comp <= 0.1 * raw, "{v}");
    assert!(pair(&v, "correction_active_fraction")[0] > 0.5, "{v}");
    for ext in ["svg", "png"] {
        let f = plots.join(format!("tip-error.{ext}"));
        assert!(
            f.metadata().map(|m| m.len() > 1000).unwrap_or(false),
            "{}",
            f.display()
        );
    }
}

#[test]
fn palpation_error_is_at_most_thirty_percent_of_raw() {
    let v = evaluate(PARAMS, "config/sim/palpation.toml", "8", None);
    let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
    let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
    assert!(raw > 0.5, "the surface does not load the shaft: {v}");
    assert!(comp <= 0.3 * raw, "{v}");
}

/// `--tool` and `--arm` judge the simulated shaft as if that instrument or arm kind were
/// mounted: the true tip comes from the simulator's true joints through the same kinematics as
/// the estimates. It used to be the simulator's own (Classic, large needle driver) tip, so any
/// other choice read about 50 mm of raw error and a coverage of 0.
#[test]
fn another_instrument_or_arm_is_judged_as_if_mounted() {
    let scenario = "config/sim/palpation.toml";
    let lnd = evaluate(PARAMS, scenario, "8", None);
    let lnd_raw = num(&lnd, &["tip_error_mm", "raw", "mean"]);
    for more in [
        &["--tool", "PROGRASP_FORCEPS_420093"][..],
        &["--arm", "si"][..],
    ] {
        let v = evaluate_with(PARAMS, scenario, "8", None, more);
        let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
        let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
        // The same joint errors through another chain: the same order of tip error.
        assert!(
            raw > 0.3 * lnd_raw && raw < 3.0 * lnd_raw,
            "{more:?}: raw {raw} mm against {lnd_raw} with the default tool: {v}"
        );
        assert!(comp <= 0.3 * raw, "{more:?}: {v}");
        let coverage = num(&v, &["coverage"]);
        assert!(coverage >= 0.9, "{more:?}: coverage {coverage}: {v}");
    }
}

/// Without a dynamics model a joint is corrected only while the whole arm is still: the other
/// joint's start loads it through the distal part's inertia before its own filter sees any
/// motion, and an effort changing faster than its noise is a start or a changing contact. While
/// each joint judged only itself, the noisier arm's start-stop motion was made up to 1.35 mm
/// worse than raw in a cycle and the start-stop slide 0.72 mm (now 0.26 and 0).
#[test]
fn without_a_dynamics_model_a_start_is_not_taken_for_contact() {
    let quasi = quasi_static_file("evaluate-motion-starts");
    for scenario in [
        "config/sim/i20-noisy-start-stop.toml",
        "config/sim/i20-start-stop-slide.toml",
    ] {
        let v = evaluate(quasi.to_str().unwrap(), scenario, "30", None);
        let harm = num(&v, &["harm_mm", "max"]);
        assert!(harm <= 0.5, "{scenario}: harm_mm.max {harm}: {v}");
        let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
        let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
        assert!(comp <= raw + 0.02, "{scenario}: {v}");
    }
}

#[test]
fn bad_evaluate_arguments_are_named() {
    let run = |args: &[&str]| {
        let out = Command::new(sidecar_bin())
            .args(args)
            .current_dir(repo())
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = run(&[
        "evaluate",
        "--params",
        PARAMS,
        "--scenario",
        "config/sim/palpation.toml",
        "--seconds",
        "0",
    ]);
    assert!(e.contains("--seconds 0"), "{e}");
    let e = run(&["evaluate", "--params", PARAMS]);
    assert!(e.contains("--scenario") || e.contains("--data"), "{e}");
}
