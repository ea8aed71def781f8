//! End-to-end tests of one `serve` for several arms: one source read once per cycle for every
//! arm, each arm under its own name, a failing arm marking only its own samples invalid.

mod common;

use std::time::Duration;

use common::*;
use serde_json::Value;

const LIVENESS: Duration = Duration::from_secs(60);

/// A two-arm configuration: `arms` lists (name, boards, scenario), every arm the repository's
/// Classic io file and the paper's parameters.
fn write_arms_config(
    test: &str,
    source: &str,
    access: &str,
    arms: &[(&str, [u8; 2], &str)],
) -> std::path::PathBuf {
    let c = repo().join("config");
    let mut text = format!(
        "source = \"{source}\"\naccess = \"{access}\"\nrate = 1500\n[sim]\nscenario = \"{}\"\n",
        c.join("sim/idle.toml").display()
    );
    for (name, boards, scenario) in arms {
        text.push_str(&format!(
            r#"
[[arm]]
name = "{name}"
boards = [{}, {}]
io = "{io}"
kind = "classic"
instrument = "LARGE_NEEDLE_DRIVER_400006"
compliance = "{comp}"
scenario = "{scen}"
"#,
            boards[0],
            boards[1],
            io = c.join("io/psm-classic.toml").display(),
            comp = c.join("compliance/paper-psm.toml").display(),
            scen = c.join("sim").join(scenario).display(),
        ));
    }
    let path = scratch(test).join("sidecar.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn seqs(samples: &[Value]) -> Vec<u64> {
    samples
        .iter()
        .map(|s| s["header"]["seq"].as_u64().unwrap())
        .collect()
}

fn assert_consecutive(test: &str, seqs: &[u64]) {
    for w in seqs.windows(2) {
        assert_eq!(
            w[1],
            w[0] + 1,
            "{test}: seq jumped from {} to {}",
            w[0],
            w[1]
        );
    }
}

/// PSM2's boards never answer: the service starts with PSM1 after its wait, PSM1's samples are
/// valid (but for a reply lost to a stall of a loaded host, with its reason) and in order, PSM2's are all invalid with BOARD_TIMEOUT, and the log names PSM2.
#[test]
fn an_arm_whose_boards_do_not_answer_leaves_the_other_arm_served() {
    let port = free_udp_port();
    // A one-arm emulator: boards 6 and 7 only.
    let _emu = emulator(port, "idle.toml");
    let p1 = unique_prefix("missing_arm1");
    let p2 = unique_prefix("missing_arm2");
    let cfg = write_arms_config(
        "missing_arm",
        &format!("udp:127.0.0.1:{port}"),
        "shared",
        &[(&p1, [6, 7], "idle.toml"), (&p2, [8, 9], "idle.toml")],
    );
    let mut serve = serve(&cfg);
    let one = echo_json(&format!("{p1}/measured_js"), 1500, LIVENESS);
    assert_mostly_valid("missing_arm PSM1", &one);
    assert_consecutive("missing_arm PSM1", &seqs(&one));
    let two = echo_json(&format!("{p2}/compensated/status"), 50, LIVENESS);
    for s in &two {
        assert_eq!(s["header"]["valid"], Value::Bool(false), "{s}");
        assert!(flag_names(s).iter().any(|f| f == "BOARD_TIMEOUT"), "{s}");
    }
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    assert!(
        log.contains("not answering") && log.contains(&p2) && log.contains("[8, 9]"),
        "the log names the arm without boards: {log}"
    );
}

/// A file's mistakes in one arm are named with the arm, by `check-config` and `serve`, and
/// nothing is served.
#[test]
fn check_config_names_the_arm_at_fault() {
    let cfg = write_arms_config(
        "bad_arm",
        "sim",
        "shared",
        &[("PSM1", [6, 7], "idle.toml"), ("PSM2", [7, 8], "idle.toml")],
    );
    for cmd in ["check-config", "serve"] {
        let out = std::process::Command::new(sidecar_bin())
            .args([cmd, "--config"])
            .arg(&cfg)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{cmd} accepted two arms on board 7");
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(
            e.contains("\"PSM1\" and \"PSM2\" both use board 7") && e.contains("sidecar.toml"),
            "{cmd}: {e}"
        );
    }
}

/// `sim --arms PSM1,PSM2` (boards 6-9, PSM2 palpating while PSM1 pushes in a divot) read by one
/// `serve` of both arms in `access` mode: every cycle of each arm in order and valid, each arm
/// its own.
fn two_arms_every_seq_in_order(test: &str, access: &str) {
    let port = free_udp_port();
    let c = repo().join("config");
    let palpation = format!("PSM2={}", c.join("sim/palpation.toml").display());
    let _emu = emulator_with(
        "127.0.0.1",
        port,
        &[
            "--arms",
            "PSM1,PSM2",
            "--scenario",
            c.join("sim/divot-push.toml").to_str().unwrap(),
            "--arm-scenario",
            &palpation,
        ],
    );
    let p1 = unique_prefix(&format!("{test}1"));
    let p2 = unique_prefix(&format!("{test}2"));
    let cfg = write_arms_config(
        test,
        &format!("udp:127.0.0.1:{port}"),
        access,
        &[(&p1, [6, 7], "idle.toml"), (&p2, [8, 9], "idle.toml")],
    );
    // Shared mode reads each arm's registers in turn through one port: its quadlet window
    // defaults to one arm's (4) per arm.
    let check = std::process::Command::new(sidecar_bin())
        .args(["check-config", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&check.stdout);
    assert!(check.status.success(), "{test}: check-config: {printed}");
    assert_eq!(
        printed.contains("window      8 quadlet requests in flight"),
        access == "shared",
        "{test}: {printed}"
    );
    let mut serve = serve(&cfg);
    let mut last = Vec::new();
    for p in [&p1, &p2] {
        let v = echo_json(&format!("{p}/compensated/measured_js"), 1500, LIVENESS);
        assert_eq!(v.len(), 1500);
        assert_consecutive(&format!("{test} {p}"), &seqs(&v));
        assert_mostly_valid(&format!("{test} {p}"), &v);
        last.push(v[v.len() - 1]["position"].clone());
    }
    assert_ne!(last[0], last[1], "{test}: both names carry the same arm");
    let (st, log) = serve.terminate();
    assert!(st.success(), "{test}: serve exited with {st}: {log}");
    assert!(log.contains("boards of every arm found"), "{log}");
}

#[test]
fn two_arms_from_one_emulator_shared() {
    two_arms_every_seq_in_order("two_shared", "shared");
}

#[test]
fn two_arms_from_one_emulator_exclusive() {
    two_arms_every_seq_in_order("two_exclusive", "exclusive");
}

/// The passive tap with two arms: the console stand-in (`drive --arms PSM1,PSM2`) runs the I/O
/// of both arms against `sim --arms PSM1,PSM2`; one `serve` with `source = "tap:lo:PORT"`
/// publishes both arms from the console's own traffic, each its own, and sends nothing.
#[cfg_attr(
    not(has_root),
    ignore = "needs root: the tap's AF_PACKET capture needs CAP_NET_RAW (sudo -E cargo test --test multi_arm)"
)]
#[test]
fn the_tap_publishes_both_arms_from_the_consoles_traffic() {
    // SAFETY: geteuid has no preconditions.
    assert!(
        unsafe { libc::geteuid() } == 0,
        "the tap needs root; CI runs as root"
    );
    let test = "two_tap";
    let port = free_udp_port();
    let c = repo().join("config");
    let palpation = format!("PSM2={}", c.join("sim/palpation.toml").display());
    let mut sim = emulator_with(
        "0.0.0.0",
        port,
        &[
            "--arms",
            "PSM1,PSM2",
            "--scenario",
            c.join("sim/free-motion.toml").to_str().unwrap(),
            "--arm-scenario",
            &palpation,
        ],
    );
    let p1 = unique_prefix("two_tap1");
    let p2 = unique_prefix("two_tap2");
    let cfg = write_arms_config(
        test,
        &format!("tap:lo:{port}"),
        "shared",
        &[(&p1, [6, 7], "idle.toml"), (&p2, [8, 9], "idle.toml")],
    );
    std::fs::write(
        &cfg,
        std::fs::read_to_string(&cfg)
            .unwrap()
            .replace("rate = 1500", "rate = \"follow\""),
    )
    .unwrap();
    let mut serve = serve(&cfg);
    std::thread::sleep(Duration::from_millis(500));
    let mut drive = Proc::spawn(
        "drive",
        std::process::Command::new(sidecar_bin())
            .args([
                "drive",
                "--boards",
                &format!("127.0.0.1:{port}"),
                "--arms",
                "PSM1,PSM2",
                "--protocol",
                "sequential-read-broadcast-write",
                "--rate",
                "1500",
                "--duration",
                "30",
            ])
            .env("RUST_LOG", "warn")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped()),
    );
    let mut last = Vec::new();
    for p in [&p1, &p2] {
        // The console's reads, once it runs: skip what was published before (NO_SOURCE).
        let valid = eventually(LIVENESS, || {
            let v = echo_json(&format!("{p}/measured_js"), 500, LIVENESS);
            let n = v
                .iter()
                .filter(|s| s["header"]["valid"] == Value::Bool(true))
                .count();
            (n == v.len()).then_some(v)
        })
        .unwrap_or_else(|| panic!("{p}: no run of 500 valid samples from the console's traffic"));
        last.push(valid[valid.len() - 1]["position"].clone());
    }
    drive.signal(libc::SIGTERM);
    let _ = drive.wait_timeout(Duration::from_secs(20));
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    let (_, sim_log) = sim.terminate();
    assert_ne!(last[0], last[1], "both names carry the same arm");
    // Only the stand-in asked the boards anything: one peer in the emulator's log.
    let peers = sim_log
        .split("requests_by_peer=")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .unwrap_or_else(|| panic!("requests_by_peer in the emulator log: {sim_log}"));
    assert_eq!(
        peers.split(',').count(),
        1,
        "requests from more than the stand-in: {peers}"
    );
}
