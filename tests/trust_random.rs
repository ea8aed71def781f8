//! Issue 20's goals on scenarios nobody tuned for: 35 random scenarios (free smooth, multi-sine
//! and start-stop motions, holds, divot push cycles, surfaces pressed 0.5-4 mm at random poses,
//! swept smoothly or in start-stop), each run 30 s through `evaluate --scenario --json` with the
//! default parameter file. Asserts the goals that hold on them (no cycle more than 0.5 mm worse
//! than raw; a bound mean at most 2.5 times the compensated mean + 0.05 mm) and prints every
//! scenario's coverage, which issue 20 wants within 90-99.5% and which is not met on all of them
//! (benches/README.md, "Correction in motion"). Ignored by default (a few minutes); run with
//!
//! ```text
//! cargo test --release --test trust_random -- --ignored --nocapture
//! ```
//!
//! `TRUST_RANDOM_SEED` (default 500) and `TRUST_RANDOM_COUNT` (default 35) pick another set.

mod common;

use std::fmt::Write as _;
use std::process::Command;

use common::*;
use serde_json::Value;

const KINDS: [&str; 7] = [
    "smooth",
    "start-stop",
    "multi-sine",
    "surface",
    "divot",
    "hold",
    "surface-start-stop",
];

fn list(v: &[f64]) -> String {
    let items: Vec<String> = v.iter().map(|x| format!("{x:.4}")).collect();
    format!("[{}]", items.join(", "))
}

/// One random scenario file of the given kind.
fn scenario(seed: u64, kind: &str) -> String {
    let mut r = Rng(seed);
    let l = r.in_range(0.09, 0.21);
    let q1 = r.in_range(-0.4, 0.4);
    let q2 = r.in_range(-0.4, 0.3);
    let mut s = String::new();
    let _ = writeln!(s, "description = \"random {kind}, seed {seed}\"");
    let _ = writeln!(s, "seed = {seed}\ndt_s = 0.0001");
    let _ = writeln!(
        s,
        "initial_position = {}\n",
        list(&[q1, q2, l, 0.0, 0.0, 0.0, 0.0])
    );
    let surface = kind.starts_with("surface");
    if surface {
        let _ = writeln!(
            s,
            "[environment]\nkind = \"surface\"\nstiffness_n_per_m = {:.1}\ngap_m = {:.5}\ntilt_rad = {:.3}\n",
            r.in_range(300.0, 3000.0),
            -r.in_range(0.0005, 0.004),
            r.in_range(0.0, 0.8)
        );
    } else if kind == "divot" {
        s.push_str(
            "[environment]\nkind = \"divot\"\nplate_stiffness_n_per_m = 20000.0\n\
             plate_damping_n_s_per_m = 50.0\ncapture_depth_m = 0.001\n\n",
        );
    } else {
        s.push_str("[environment]\nkind = \"free\"\n\n");
    }
    match kind {
        "smooth" | "surface" => {
            let insertion = if surface { 0.0 } else { r.in_range(0.0, 0.02) };
            let a = [r.in_range(0.03, 0.25), r.in_range(0.03, 0.2), insertion];
            let p = [
                r.in_range(0.8, 4.0),
                r.in_range(0.8, 4.0),
                r.in_range(1.0, 4.0),
            ];
            let _ = writeln!(
                s,
                "[motion]\nkind = \"trajectory\"\namplitude = {}\nperiod_s = {}\n",
                list(&[a[0], a[1], a[2], 0.0, 0.0, 0.0, 0.0]),
                list(&[p[0], p[1], p[2], 1.0, 1.0, 1.0, 1.0])
            );
        }
        "start-stop" | "surface-start-stop" => {
            let _ = writeln!(
                s,
                "[motion]\nkind = \"start_stop\"\nspeed_rad_per_s = {}\nmove_s = {:.3}\nstill_s = {:.3}\nramp_s = {:.4}\nstart_s = {:.3}\n",
                list(&[r.in_range(0.1, 0.8), r.in_range(0.1, 0.6)]),
                r.in_range(0.2, 0.9),
                r.in_range(0.2, 0.9),
                r.in_range(0.006, 0.06),
                r.in_range(0.0, 1.0)
            );
        }
        "multi-sine" => {
            let a: Vec<f64> = (0..6).map(|_| r.in_range(0.01, 0.08)).collect();
            let w: Vec<f64> = (0..6).map(|_| r.in_range(1.0, 12.0)).collect();
            let _ = writeln!(
                s,
                "[motion]\nkind = \"multi_sine\"\namplitude = [{}, {}]\nangular_frequency = [{}, {}]\n",
                list(&a[..3]),
                list(&a[3..]),
                list(&w[..3]),
                list(&w[3..])
            );
        }
        "divot" => {
            let _ = writeln!(
                s,
                "[motion]\nkind = \"push_cycle\"\neffort_amplitude_nm = {}\nperiod_s = {:.2}\ninsertion_force_n = {:.2}\n",
                list(&[r.in_range(0.2, 1.5), r.in_range(0.2, 1.5)]),
                r.in_range(5.0, 20.0),
                r.in_range(0.5, 3.0)
            );
        }
        _ => s.push_str("[motion]\nkind = \"hold\"\n\n"),
    }
    s.push_str("[noise]\ncurrent_noise_amps = 0.002\npot_noise_volts = 0.001\n");
    s
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[test]
#[ignore = "a few minutes: run with --ignored"]
fn random_scenarios_keep_the_goals() {
    let first = env_u64("TRUST_RANDOM_SEED", 500);
    let count = env_u64("TRUST_RANDOM_COUNT", 35);
    let dir = scratch("trust-random");
    let mut failures = Vec::new();
    let (mut over, mut under, mut refused) = (0, 0, 0);
    println!("| seed | kind | raw mm | compensated mm | harm max mm | bound mean mm | coverage |");
    println!("|---|---|---|---|---|---|---|");
    for (i, seed) in (first..first + count).enumerate() {
        let kind = KINDS[i % KINDS.len()];
        let path = dir.join(format!("random-{seed}.toml"));
        std::fs::write(&path, scenario(seed, kind)).unwrap();
        let out = Command::new(sidecar_bin())
            .args(["evaluate", "--params", "config/compliance/sim-psm.toml"])
            .arg("--scenario")
            .arg(&path)
            .args(["--seconds", "30", "--json"])
            .current_dir(repo())
            .output()
            .unwrap();
        if !out.status.success() {
            // The scenario check refuses a motion that leaves the joint limits: not a result.
            let why = String::from_utf8_lossy(&out.stderr);
            assert!(
                why.contains("scenario"),
                "evaluate failed on {}: {why}",
                path.display()
            );
            println!("| {seed} | {kind} | refused: {} |", why.trim());
            refused += 1;
            continue;
        }
        let v: Value = serde_json::from_slice(&out.stdout).unwrap();
        let raw = num(&v, &["tip_error_mm", "raw", "mean"]);
        let comp = num(&v, &["tip_error_mm", "compensated", "mean"]);
        let harm = num(&v, &["harm_mm", "max"]);
        let bound = num(&v, &["bound_mm", "mean"]);
        let coverage = num(&v, &["coverage"]);
        println!(
            "| {seed} | {kind} | {raw:.3} | {comp:.3} | {harm:.3} | {bound:.3} | {:.2}% |",
            100.0 * coverage
        );
        if harm > 0.5 {
            failures.push(format!("{seed} ({kind}): harm_mm.max {harm} > 0.5"));
        }
        if bound > 2.5 * comp + 0.05 {
            failures.push(format!(
                "{seed} ({kind}): bound mean {bound} > 2.5 x {comp} + 0.05"
            ));
        }
        over += usize::from(coverage > 0.995);
        under += usize::from(coverage < 0.90);
    }
    println!(
        "\n{count} scenarios from seed {first}: {refused} refused by the scenario check; \
         coverage over 99.5% in {over}, under 90% in {under} (reported, not asserted)"
    );
    assert!(
        refused < count,
        "every scenario was refused: the generator is broken"
    );
    assert!(failures.is_empty(), "{failures:#?}");
}
