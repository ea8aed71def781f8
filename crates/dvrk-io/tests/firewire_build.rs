//! The build script's libraw1394 probe (crates/dvrk-io/build.rs), compiled with rustc and run as
//! cargo runs it: a FireWire build without the library must stop with one readable sentence, not
//! a linker error. `cargo check -p dvrk-io --features firewire` with
//! `DVRK_IO_RAW1394_PROBE=raw1394-missing` shows the same sentence through cargo.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dvrk-io-build-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The build script, compiled once per test into `dir`.
fn build_script(dir: &Path) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("build.rs");
    let exe = dir.join("build-script");
    let out = Command::new(std::env::var("RUSTC").unwrap_or_else(|_| "rustc".to_owned()))
        .args(["--edition", "2024", "-o"])
        .arg(&exe)
        .arg(&src)
        .output()
        .expect("running rustc");
    assert!(
        out.status.success(),
        "rustc build.rs: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// Runs the build script with the environment cargo gives it (plus `env`), returns stdout.
fn run(exe: &Path, firewire: bool, env: &[(&str, &str)]) -> String {
    let mut cmd = Command::new(exe);
    cmd.env_remove("RAW1394_LIB_DIR")
        .env_remove("DVRK_IO_RAW1394_PROBE")
        .env("CARGO_CFG_TARGET_ARCH", std::env::consts::ARCH)
        .env("CARGO_CFG_TARGET_ENV", "gnu");
    if firewire {
        cmd.env("CARGO_FEATURE_FIREWIRE", "1");
    } else {
        cmd.env_remove("CARGO_FEATURE_FIREWIRE");
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

fn errors(stdout: &str) -> Vec<&str> {
    stdout
        .lines()
        .filter_map(|l| l.strip_prefix("cargo::error="))
        .collect()
}

#[test]
fn a_missing_library_stops_the_build_with_the_package_to_install() {
    let dir = scratch("missing");
    let exe = build_script(&dir);
    let out = run(&exe, true, &[("DVRK_IO_RAW1394_PROBE", "raw1394-missing")]);
    let errs = errors(&out);
    assert_eq!(errs.len(), 1, "{out}");
    assert!(
        errs[0].contains("libraw1394-missing, which is not installed")
            && errs[0].contains("install libraw1394-dev")
            && errs[0].contains("RAW1394_LIB_DIR"),
        "{}",
        errs[0]
    );
    // Without the feature nothing is probed and nothing fails.
    let out = run(&exe, false, &[("DVRK_IO_RAW1394_PROBE", "raw1394-missing")]);
    assert!(errors(&out).is_empty(), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn raw1394_lib_dir_is_checked_and_added_to_the_link_search() {
    let dir = scratch("libdir");
    let exe = build_script(&dir);
    let lib = dir.join("lib");
    std::fs::create_dir_all(&lib).unwrap();
    // A directory without the library is named in the error.
    let out = run(
        &exe,
        true,
        &[
            ("DVRK_IO_RAW1394_PROBE", "fakeraw"),
            ("RAW1394_LIB_DIR", lib.to_str().unwrap()),
        ],
    );
    let errs = errors(&out);
    assert_eq!(errs.len(), 1, "{out}");
    assert!(errs[0].contains(lib.to_str().unwrap()), "{}", errs[0]);
    // With the library there, it is found and its directory given to the linker.
    std::fs::write(lib.join("libfakeraw.so"), b"").unwrap();
    let out = run(
        &exe,
        true,
        &[
            ("DVRK_IO_RAW1394_PROBE", "fakeraw"),
            ("RAW1394_LIB_DIR", lib.to_str().unwrap()),
        ],
    );
    assert!(errors(&out).is_empty(), "{out}");
    assert!(
        out.lines()
            .any(|l| l == format!("cargo::rustc-link-search=native={}", lib.display())),
        "{out}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
