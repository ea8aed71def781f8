//! Build script of the root package (dvrk-sidecar-e2e, never a dependency of anything): probes
//! what some end-to-end tests need and cannot get from cargo, and sets a cfg per prerequisite,
//! so that a test that cannot run here shows as `ignored` with the reason and how to get it
//! (`#[cfg_attr(not(has_py_iceoryx2), ignore = "...")]`), instead of passing as `ok`.
//!
//! | cfg | probe | tests |
//! |---|---|---|
//! | `has_root` | effective uid 0 | tests/tap.rs (AF_PACKET capture) |
//! | `has_systemd_analyze` | `systemd-analyze --version` runs | tests/deploy.rs |
//! | `has_py_iceoryx2` | `python3 -c 'import iceoryx2'` | tests/python.rs |
//! | `has_py_cyclonedds` | `import cyclonedds` | tests/ros2_bridge.rs (DDS reader) |
//! | `has_py_mcap_ros2` | `import mcap` and `import mcap_ros2` | tests/ros2_bridge.rs (MCAP) |
//! | `has_py_dvrk_sidecar` | `import iceoryx2, numpy, dvrk_sidecar` (python/, `pip install ./python`) | tests/python_client.rs, the Arm example in tests/python.rs |
//!
//! Under CI (`CI` set and not `0`/`false`, as .ci/run sets it) every cfg except
//! `has_systemd_analyze` is set whatever the probe says: there the tests must run, and a missing
//! prerequisite fails them with their own message instead of hiding as ignored.
//!
//! Probes run when this script runs: after installing a prerequisite, `touch build.rs` (or set
//! `DVRK_E2E_REPROBE` to a new value) so cargo probes again.

use std::process::{Command, Stdio};

const CFGS: [&str; 6] = [
    "has_root",
    "has_systemd_analyze",
    "has_py_iceoryx2",
    "has_py_cyclonedds",
    "has_py_mcap_ros2",
    "has_py_dvrk_sidecar",
];

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=DVRK_E2E_REPROBE");
    for cfg in CFGS {
        println!("cargo::rustc-check-cfg=cfg({cfg})");
    }
    let ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "0" && v != "false");

    let found = |cfg: &str| -> bool {
        match cfg {
            "has_root" => euid_is_root(),
            "has_systemd_analyze" => runs("systemd-analyze", &["--version"]),
            "has_py_iceoryx2" => python_imports(&["iceoryx2"]),
            "has_py_cyclonedds" => python_imports(&["cyclonedds"]),
            "has_py_mcap_ros2" => python_imports(&["mcap", "mcap_ros2"]),
            "has_py_dvrk_sidecar" => python_imports(&["iceoryx2", "numpy", "dvrk_sidecar"]),
            _ => false,
        }
    };
    for cfg in CFGS {
        let forced = ci && cfg != "has_systemd_analyze";
        if forced || found(cfg) {
            println!("cargo::rustc-cfg={cfg}");
        }
    }
}

/// The effective uid from /proc/self/status (`Uid: real effective saved fs`).
fn euid_is_root() -> bool {
    std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|ids| ids.split_whitespace().nth(1))
            == Some("0")
    })
}

fn runs(program: &str, args: &[&str]) -> bool {
    Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn python_imports(modules: &[&str]) -> bool {
    let code = modules
        .iter()
        .map(|m| format!("import {m}"))
        .collect::<Vec<_>>()
        .join("; ");
    runs("python3", &["-c", &code])
}
