//! The offline commands through the real binary: exact JSON shapes, values, exit codes and
//! error messages.

use std::path::PathBuf;
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dvrk-sidecar"))
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn run(args: &[&str]) -> Output {
    bin().args(args).current_dir(repo()).output().unwrap()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The top-level keys of a one-line JSON object, in the order they are written.
fn key_order(text: &str, keys: &[&str]) -> Vec<usize> {
    keys.iter()
        .map(|k| {
            text.find(&format!("\"{k}\":"))
                .unwrap_or_else(|| panic!("key {k} missing in {text}"))
        })
        .collect()
}

fn assert_exact_keys(text: &str, keys: &[&str]) {
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    assert_eq!(v.as_object().unwrap().len(), keys.len(), "{text}");
    let pos = key_order(text, keys);
    assert!(
        pos.windows(2).all(|w| w[0] < w[1]),
        "keys out of order in {text}"
    );
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn fk_json_has_the_exact_shape_and_the_reference_values() {
    // Reference psm-kinematics-crtk.md section 1.4, last row.
    let o = run(&[
        "fk", "--json", "--", "0.2", "-0.3", "0.15", "0.4", "0.3", "-0.2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_exact_keys(&stdout(&o), &["orientation_xyzw", "position_m", "rotation"]);
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    let p: Vec<f64> = v["position_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let expected = [0.026278, 0.039921, -0.134903];
    for i in 0..3 {
        assert!(
            (p[i] - expected[i]).abs() < 1e-6,
            "position {p:?} vs {expected:?}"
        );
    }
    let r = v["rotation"].as_array().unwrap();
    assert_eq!(r.len(), 3);
    let r00 = r[0][0].as_f64().unwrap();
    assert!((r00 - 0.36904).abs() < 1e-5, "r00 = {r00}");
}

#[test]
fn fk_text_and_errors() {
    let o = run(&["fk", "--", "0", "0", "0.12", "0", "0", "0"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("-0.113500"), "{}", stdout(&o));
    let o = run(&[
        "fk",
        "--tool",
        "NO_SUCH_TOOL",
        "--",
        "0",
        "0",
        "0.12",
        "0",
        "0",
        "0",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("NO_SUCH_TOOL") && stderr(&o).contains("LARGE_NEEDLE_DRIVER_400006"),
        "{}",
        stderr(&o)
    );
    let o = run(&["fk", "--", "0", "0", "0.12"]);
    assert!(!o.status.success(), "six joints are required");
}

#[test]
fn correct_json_has_the_exact_shape_and_applies_the_paper_model() {
    let params = repo().join("config/compliance/paper-psm.toml");
    let o = run(&[
        "correct",
        "--params",
        params.to_str().unwrap(),
        "--json",
        "--position",
        "0.1,-0.2,0.15",
        "--effort",
        "0.5,-0.05,1.0",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_exact_keys(
        &stdout(&o),
        &[
            "position",
            "delta_rad",
            "tau_ext_nm",
            "active",
            "insertion_clamped",
        ],
    );
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    // Joint 1: tau_ext = 0.5 > 0.1, K1(0.15) = 1/(639.16*0.15^3 - 432.35*0.15^2 + 136.32*0.15 + 3.12)
    let inv_k1 = 639.16 * 0.15f64.powi(3) - 432.35 * 0.15f64.powi(2) + 136.32 * 0.15 + 3.12;
    let d1 = 0.5 / inv_k1; // backlash 0 in the paper file
    let pos: Vec<f64> = v["position"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!((pos[0] - (0.1 - d1)).abs() < 1e-12, "{pos:?}");
    // Joint 2: |tau_ext| = 0.05 < 0.2: unchanged.
    assert_eq!(pos[1], -0.2);
    assert_eq!(pos[2], 0.15);
    assert_eq!(v["active"], serde_json::json!([true, false]));
    assert_eq!(v["insertion_clamped"], serde_json::json!(false));
}

#[test]
fn correct_reports_bad_input_by_name() {
    let params = repo().join("config/compliance/paper-psm.toml");
    let o = run(&[
        "correct",
        "--params",
        params.to_str().unwrap(),
        "--position",
        "0.1,abc,0.1",
        "--effort",
        "0,0,0",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--position item 2"), "{}", stderr(&o));
    let o = run(&[
        "correct",
        "--params",
        "/nonexistent/p.toml",
        "--position",
        "0,0,0.1",
        "--effort",
        "0,0,0",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("/nonexistent/p.toml"), "{}", stderr(&o));
}

#[test]
fn check_config_accepts_the_shipped_configuration() {
    let o = run(&["check-config", "--config", "config/sidecar.toml"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("OK"));
}

#[test]
fn check_config_rejects_every_bad_service_config_with_its_expected_message() {
    // Each tests/data/bad-config/sidecar-*.toml starts with `# expect: <text>`; the error must
    // contain that text.
    let dir = repo().join("tests/data/bad-config");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_owned();
        if !name.starts_with("sidecar-") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let expect = text
            .lines()
            .next()
            .and_then(|l| l.strip_prefix("# expect: "))
            .unwrap_or_else(|| panic!("{name}: first line must be `# expect: ...`"));
        let o = run(&["check-config", "--config", path.to_str().unwrap()]);
        assert!(!o.status.success(), "{name} was accepted");
        let err = stderr(&o);
        assert!(
            err.contains(expect),
            "{name}: expected \"{expect}\" in: {err}"
        );
        assert!(
            err.contains(&name),
            "{name}: the error names the file: {err}"
        );
        n += 1;
    }
    assert!(n >= 6, "only {n} bad service configs found");
}

#[test]
fn check_config_accepts_a_labs_sawrobotio1394_json() {
    let dir = std::env::temp_dir().join(format!("dvrk-cli-saw-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let r = repo();
    let cfg = dir.join("sidecar.toml");
    std::fs::write(
        &cfg,
        format!(
            "source = \"udp:169.254.0.100\"\nio = \"{}\"\narm = \"classic\"\n\
             instrument = \"LARGE_NEEDLE_DRIVER_400006\"\ncompliance = \"{}\"\n",
            r.join("tests/data/io/sawRobotIO1394-PSM1-00000.json")
                .display(),
            r.join("config/compliance/sim-psm.toml").display()
        ),
    )
    .unwrap();
    let o = run(&["check-config", "--config", cfg.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("boards [6, 7]"), "{}", stdout(&o));
    // A broken JSON file is named, with the line of the problem.
    let bad = dir.join("bad.json");
    std::fs::write(
        &bad,
        "{\n  \"$version\": \"6\",\n  \"robots\": [ oops ]\n}\n",
    )
    .unwrap();
    std::fs::write(
        &cfg,
        std::fs::read_to_string(&cfg).unwrap().replace(
            &r.join("tests/data/io/sawRobotIO1394-PSM1-00000.json")
                .display()
                .to_string(),
            bad.to_str().unwrap(),
        ),
    )
    .unwrap();
    let o = run(&["check-config", "--config", cfg.to_str().unwrap()]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("bad.json") && e.contains("line 3"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn negative_numbers_are_option_values_everywhere() {
    // Before: clap read `-1` as an unknown flag ("unexpected argument '-1' found").
    let o = run(&[
        "fit",
        "--clamp",
        "/nonexistent/clamp.csv",
        "--tau-min-nm",
        "-1",
        "0.2",
        "--out",
        "/nonexistent/p.toml",
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(!err.contains("unexpected argument"), "{err}");
    let o = run(&[
        "fk", "--arm", "classic", "-0.1", "-0.2", "0.12", "-0.3", "0", "-0.1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn fk_and_correct_refuse_values_no_psm_can_have() {
    let o = run(&["fk", "--", "0", "0", "-5", "0", "0", "0"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("q3 = -5 m"), "{}", stderr(&o));
    let o = run(&["fk", "--", "0", "1e308", "0.1", "0", "0", "0"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("q2 = 1e308"), "{err}");
    assert!(err.len() < 400, "no 300-digit numbers: {err}");
    let params = repo().join("config/compliance/paper-psm.toml");
    let p = params.to_str().unwrap();
    let o = run(&[
        "correct",
        "--params",
        p,
        "--position",
        "1e308,0,0.1",
        "--effort",
        "0,0,0",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("q1 = 1e308"), "{}", stderr(&o));
    let o = run(&[
        "correct",
        "--params",
        p,
        "--position",
        "0,0,0.1",
        "--effort",
        "0,-40,0",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--effort item 2 = -40"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_output_that_is_a_directory_is_refused_before_any_work() {
    let dir = std::env::temp_dir().join(format!("dvrk-cli-out-{}", std::process::id()));
    let out = dir.join("existing");
    std::fs::create_dir_all(&out).unwrap();
    let sweep = repo().join("config/sim/divot-push.toml");
    for args in [
        vec!["fit", "--clamp", "/nonexistent.csv", "--out"],
        vec![
            "calibrate",
            "divot",
            "--config",
            sweep.to_str().unwrap(),
            "--out",
        ],
    ] {
        let mut a = args.clone();
        a.push(out.to_str().unwrap());
        let o = run(&a);
        assert!(!o.status.success());
        let err = stderr(&o);
        assert!(err.contains("is a directory"), "{args:?}: {err}");
        // Refused at parse time: nothing else (no missing-file error, no procedure) happened.
        assert!(!err.contains("nonexistent"), "{err}");
    }
    // Nothing was written anywhere: not into the directory, not beside it.
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
