//! The systemd unit is checked by systemd itself, and the install script by a staged install.

mod common;

use std::process::Command;

use common::*;

#[test]
fn systemd_analyze_verifies_the_unit() {
    let Ok(out) = Command::new("systemd-analyze").arg("--version").output() else {
        eprintln!("skipped: systemd-analyze is not installed on this machine");
        return;
    };
    assert!(out.status.success());
    // systemd-analyze checks that ExecStart's binary exists: point the unit at the one built.
    let unit = std::fs::read_to_string(repo().join("deploy/dvrk-sidecar.service")).unwrap();
    let bin = sidecar_bin();
    let unit = unit.replace("/usr/local/bin/dvrk-sidecar", bin.to_str().unwrap());
    let dir = scratch("unit");
    let path = dir.join("dvrk-sidecar.service");
    std::fs::write(&path, unit).unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    let msgs = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "systemd-analyze verify failed: {msgs}"
    );
    assert!(
        msgs.trim().is_empty(),
        "systemd-analyze verify warned: {msgs}"
    );
}

#[test]
fn the_unit_keeps_what_iceoryx2_and_firewire_need() {
    let unit = std::fs::read_to_string(repo().join("deploy/dvrk-sidecar.service")).unwrap();
    let set = |key: &str| {
        unit.lines()
            .map(str::trim)
            .filter(|l| !l.starts_with('#'))
            .find_map(|l| l.strip_prefix(&format!("{key}=")).map(str::to_owned))
    };
    assert_eq!(set("Type").as_deref(), Some("notify"));
    assert!(set("WatchdogSec").is_some());
    assert_eq!(set("Restart").as_deref(), Some("on-failure"));
    assert!(set("ExecStartPre").unwrap().contains("check-config"));
    for (key, forbidden) in [
        ("PrivateTmp", "yes"),
        ("RemoveIPC", "yes"),
        ("RestrictRealtime", "yes"),
        ("PrivateDevices", "yes"),
    ] {
        assert_ne!(
            set(key).as_deref(),
            Some(forbidden),
            "{key}={forbidden} would break the service"
        );
        assert!(
            unit.contains(&format!("# {key}=yes")),
            "the unit explains why {key} is not set"
        );
    }
}

/// CAP_NET_RAW only in tap mode: the unit grants no capability, the tap drop-in exactly one,
/// and systemd accepts the unit with the drop-in.
#[test]
fn cap_net_raw_only_with_the_tap_drop_in() {
    let unit = std::fs::read_to_string(repo().join("deploy/dvrk-sidecar.service")).unwrap();
    let lines = |text: &str, key: &str| -> Vec<String> {
        text.lines()
            .map(str::trim)
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| l.strip_prefix(&format!("{key}=")).map(str::to_owned))
            .collect()
    };
    assert_eq!(lines(&unit, "CapabilityBoundingSet"), [""]);
    assert_eq!(lines(&unit, "AmbientCapabilities"), [""]);
    assert!(
        !unit.contains("CAP_NET_RAW")
            && !lines(&unit, "RestrictAddressFamilies")[0].contains("AF_PACKET")
    );
    let dropin = std::fs::read_to_string(repo().join("deploy/tap-mode.conf")).unwrap();
    assert_eq!(lines(&dropin, "CapabilityBoundingSet"), ["CAP_NET_RAW"]);
    assert_eq!(lines(&dropin, "AmbientCapabilities"), ["CAP_NET_RAW"]);
    assert_eq!(lines(&dropin, "RestrictAddressFamilies"), ["AF_PACKET"]);

    // Staged: --tap installs the drop-in, a plain install removes it again.
    let dest = scratch("install-tap");
    let dropin_path = dest.join("etc/systemd/system/dvrk-sidecar.service.d/tap-mode.conf");
    let out = Command::new("bash")
        .arg(repo().join("deploy/install.sh"))
        .args(["--tap", "--binary"])
        .arg(sidecar_bin())
        .env("DESTDIR", &dest)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dropin_path.exists());
    assert!(staged_install(&dest).status.success());
    assert!(
        !dropin_path.exists(),
        "a shared-mode install keeps CAP_NET_RAW"
    );
    let _ = std::fs::remove_dir_all(&dest);
}

/// Runs deploy/install.sh with the built binary, staged under `dest` (DESTDIR).
fn staged_install(dest: &std::path::Path) -> std::process::Output {
    Command::new("bash")
        .arg(repo().join("deploy/install.sh"))
        .args(["--binary"])
        .arg(sidecar_bin())
        .env("DESTDIR", dest)
        .output()
        .unwrap()
}

#[test]
fn install_script_stages_binary_config_and_unit() {
    let dest = scratch("install");
    let out = staged_install(&dest);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "usr/local/bin/dvrk-sidecar",
        "etc/dvrk-sidecar/sidecar.toml",
        "etc/dvrk-sidecar/compliance/paper-psm.toml",
        "etc/dvrk-sidecar/io/psm-classic.toml",
        "etc/dvrk-sidecar/sim/divot-push.toml",
        "etc/systemd/system/dvrk-sidecar.service",
    ] {
        assert!(dest.join(f).exists(), "{f} not installed");
    }
    // The installed configuration is valid where it was installed.
    let out = Command::new(dest.join("usr/local/bin/dvrk-sidecar"))
        .args(["check-config", "--config"])
        .arg(dest.join("etc/dvrk-sidecar/sidecar.toml"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A second install keeps a lab's edited configuration.
    std::fs::write(
        dest.join("etc/dvrk-sidecar/sidecar.toml"),
        "# edited by the lab\n",
    )
    .unwrap();
    let out = staged_install(&dest);
    assert!(out.status.success());
    assert_eq!(
        std::fs::read_to_string(dest.join("etc/dvrk-sidecar/sidecar.toml")).unwrap(),
        "# edited by the lab\n"
    );
    let _ = std::fs::remove_dir_all(&dest);
}
