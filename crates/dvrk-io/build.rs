//! Build script of dvrk-io: with the `firewire` feature, checks that libraw1394 can be linked
//! before rustc tries, so a machine without it gets one readable sentence ("install
//! libraw1394-dev ...") instead of a linker error pages long.
//!
//! The probe asks pkg-config for `libraw1394` first, then looks for the linkable library
//! (`lib<name>.so` or `lib<name>.a`, which only the -dev package installs) in `RAW1394_LIB_DIR`,
//! `LIBRARY_PATH` and the usual system directories. Environment:
//! - `RAW1394_LIB_DIR`: a directory holding a libraw1394 built elsewhere (added to the link search);
//! - `DVRK_IO_RAW1394_PROBE`: the library name probed (default `raw1394`), so a test can point the
//!   probe at a library that does not exist and see the message.

use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=RAW1394_LIB_DIR");
    println!("cargo::rerun-if-env-changed=DVRK_IO_RAW1394_PROBE");
    println!("cargo::rerun-if-env-changed=LIBRARY_PATH");
    println!("cargo::rerun-if-env-changed=PKG_CONFIG_PATH");
    if std::env::var_os("CARGO_FEATURE_FIREWIRE").is_none() {
        return;
    }
    let name = std::env::var("DVRK_IO_RAW1394_PROBE").unwrap_or_else(|_| "raw1394".to_owned());
    let explicit = std::env::var_os("RAW1394_LIB_DIR").map(PathBuf::from);

    if let Some(dir) = &explicit {
        if has_library(dir, &name) {
            println!("cargo::rustc-link-search=native={}", dir.display());
            return;
        }
        println!(
            "cargo::error=RAW1394_LIB_DIR={}: no lib{name}.so or lib{name}.a in that directory",
            dir.display()
        );
        return;
    }
    if let Some(dirs) = pkg_config_dirs(&name) {
        for d in dirs {
            println!("cargo::rustc-link-search=native={}", d.display());
        }
        return;
    }
    if search_dirs().iter().any(|d| has_library(d, &name)) {
        return;
    }
    println!(
        "cargo::error=the `firewire` feature links lib{name}, which is not installed: install \
         libraw1394-dev (Debian/Ubuntu: sudo apt-get install libraw1394-dev; Fedora: \
         libraw1394-devel), or set RAW1394_LIB_DIR to the directory holding lib{name}.so; or \
         build without --features firewire (Ethernet sources udp: and tap: need no library)"
    );
}

/// `-L` directories pkg-config gives for `lib<name>`, or None when pkg-config is missing or does
/// not know the library.
fn pkg_config_dirs(name: &str) -> Option<Vec<PathBuf>> {
    let out = Command::new(std::env::var("PKG_CONFIG").unwrap_or_else(|_| "pkg-config".to_owned()))
        .args(["--libs-only-L", &format!("lib{name}")])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8_lossy(&out.stdout);
    Some(
        text.split_whitespace()
            .filter_map(|w| w.strip_prefix("-L"))
            .map(PathBuf::from)
            .collect(),
    )
}

/// Where the linker looks by default on Linux, plus `LIBRARY_PATH`.
fn search_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var_os("LIBRARY_PATH")
        .map(|p| std::env::split_paths(&p).collect())
        .unwrap_or_default();
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    let env = std::env::var("CARGO_CFG_TARGET_ENV").unwrap_or_else(|_| "gnu".to_owned());
    let multiarch = match arch.as_str() {
        "arm" => format!("arm-linux-{env}eabihf"),
        _ => format!("{arch}-linux-{env}"),
    };
    for base in ["/usr/local/lib", "/usr/lib", "/lib"] {
        dirs.push(Path::new(base).join(&multiarch));
        dirs.push(PathBuf::from(base));
    }
    dirs.extend(["/usr/lib64", "/lib64"].map(PathBuf::from));
    dirs
}

fn has_library(dir: &Path, name: &str) -> bool {
    ["so", "a"]
        .iter()
        .any(|ext| dir.join(format!("lib{name}.{ext}")).exists())
}
