//! The systemd unit is checked by systemd itself, and deploy/install.sh is followed as
//! deploy/README.md writes it, into a scratch root (`--root`): install, the installed default
//! refuses to start and says why, naming the source makes it serve, uninstall removes it.

mod common;

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

use common::*;

#[cfg_attr(
    not(has_systemd_analyze),
    ignore = "needs systemd-analyze (Debian/Ubuntu: apt-get install systemd), then touch build.rs"
)]
#[test]
fn systemd_analyze_verifies_the_unit() {
    let out = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .expect("build.rs found systemd-analyze: it must run now");
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

/// CAP_NET_RAW only in tap mode: the unit grants no capability, the tap drop-in exactly one.
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

    // --tap installs the drop-in, a plain install removes it again.
    let root = scratch("install-tap");
    let dropin_path = root.join("etc/systemd/system/dvrk-sidecar.service.d/tap-mode.conf");
    let out = install(&root, &["--tap", "--binary", bin_arg()]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(dropin_path.exists());
    let out = install(&root, &["--binary", bin_arg()]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        !dropin_path.exists(),
        "a shared-mode install keeps CAP_NET_RAW"
    );
    let _ = std::fs::remove_dir_all(&root);
}

fn bin_arg() -> &'static str {
    static BIN: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    BIN.get_or_init(|| sidecar_bin().to_str().unwrap().to_owned())
}

/// Runs `bash deploy/install.sh --root ROOT ARGS...`, as deploy/README.md writes it, without
/// DESTDIR in the environment.
fn install(root: &Path, args: &[&str]) -> Output {
    Command::new("bash")
        .arg(repo().join("deploy/install.sh"))
        .arg("--root")
        .arg(root)
        .args(args)
        .env_remove("DESTDIR")
        .output()
        .unwrap()
}

/// stdout and stderr of a finished process.
fn text(out: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn mode(p: &Path) -> u32 {
    std::fs::metadata(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .permissions()
        .mode()
        & 0o7777
}

fn check_config(root: &Path) -> Output {
    Command::new(root.join("usr/local/bin/dvrk-sidecar"))
        .args(["check-config", "--config"])
        .arg(root.join("etc/dvrk-sidecar/sidecar.toml"))
        .output()
        .unwrap()
}

/// The whole life of an installation in a scratch root, step by step as deploy/README.md
/// writes it.
#[test]
fn install_refuses_until_the_source_is_named_then_serves_then_uninstalls() {
    let root = scratch("install-life");
    let _ = std::fs::remove_dir_all(&root);
    let json = repo().join("tests/data/io/sawRobotIO1394-PSM1-00000.json");
    // A lab's console JSON with the arm's base frame (a translation of 0.1, 0.2, 0.3 m).
    let console = scratch("install-life-src").join("console-PSM1.json");
    std::fs::write(
        &console,
        r#"{ "arms": [ { "name": "PSM1", "type": "PSM",
             "base-frame": { "reference-frame": "ECM",
                             "transform": [[1.0, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, 0.2],
                                           [0.0, 0.0, 1.0, 0.3], [0.0, 0.0, 0.0, 1.0]] } } ] }"#,
    )
    .unwrap();
    let out = install(
        &root,
        &[
            "--binary",
            bin_arg(),
            "--io-json",
            json.to_str().unwrap(),
            "--dvrk-json",
            console.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let log = text(&out);
    // No systemctl, user or group in a scratch root, and it says so.
    assert!(
        log.contains("skipped under --root: systemctl daemon-reload"),
        "{log}"
    );
    assert!(log.contains("NOT started"), "{log}");

    let etc = root.join("etc/dvrk-sidecar");
    let installed: [(&str, u32); 10] = [
        ("usr/local/bin/dvrk-sidecar", 0o755),
        ("etc/dvrk-sidecar", 0o750),
        ("etc/dvrk-sidecar/sidecar.toml", 0o640),
        ("etc/dvrk-sidecar/io/sawRobotIO1394-PSM1-00000.json", 0o640),
        ("etc/dvrk-sidecar/io/psm-classic.toml", 0o640),
        ("etc/dvrk-sidecar/compliance/paper-psm.toml", 0o640),
        ("etc/dvrk-sidecar/compliance/sim-psm.toml", 0o640),
        ("etc/dvrk-sidecar/sim/divot-push.toml", 0o640),
        ("etc/dvrk-sidecar/dvrk/console-PSM1.json", 0o640),
        ("etc/systemd/system/dvrk-sidecar.service", 0o644),
    ];
    for (f, m) in installed {
        assert_eq!(mode(&root.join(f)), m, "mode of {f}");
    }
    // The installed binary is the one given, the unit the repository's.
    assert_eq!(
        std::fs::read(root.join("usr/local/bin/dvrk-sidecar")).unwrap(),
        std::fs::read(sidecar_bin()).unwrap()
    );
    let unit =
        std::fs::read_to_string(root.join("etc/systemd/system/dvrk-sidecar.service")).unwrap();
    assert_eq!(
        unit,
        std::fs::read_to_string(repo().join("deploy/dvrk-sidecar.service")).unwrap()
    );
    for line in [
        "User=dvrk-sidecar",
        "Group=dvrk",
        "ExecStart=/usr/local/bin/dvrk-sidecar serve --config /etc/dvrk-sidecar/sidecar.toml",
    ] {
        assert!(unit.lines().any(|l| l == line), "unit lacks {line}");
    }
    // --io-json pointed the fresh config at the copy of the lab's JSON.
    let cfg_path = etc.join("sidecar.toml");
    let cfg = std::fs::read_to_string(&cfg_path).unwrap();
    assert!(
        cfg.lines()
            .any(|l| l == r#"io = "io/sawRobotIO1394-PSM1-00000.json""#),
        "{cfg}"
    );

    // The installed default refuses to start, naming the file, the field and the accepted forms.
    let out = check_config(&root);
    assert!(
        !out.status.success(),
        "the default config started: {}",
        text(&out)
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    for needle in [
        cfg_path.to_str().unwrap(),
        "source",
        "sim",
        "udp:",
        "fw:",
        "tap:",
    ] {
        assert!(
            err.contains(needle),
            "the refusal does not mention {needle:?}: {err}"
        );
    }

    // --dvrk-json pointed it at the copy of the console JSON.
    assert!(
        cfg.ends_with("[base_frame]\ndvrk_json = \"dvrk/console-PSM1.json\"\n"),
        "{cfg}"
    );

    // Naming the source (the simulator here) and a prefix of this test makes it start; the
    // prefix is not the arm's name, so the base frame's entry is named.
    let prefix = unique_prefix("deploy");
    let cfg = cfg
        .replace(r#"source = """#, r#"source = "sim""#)
        .replace(r#"# prefix = "PSM2""#, &format!(r#"prefix = "{prefix}""#))
        + "arm = \"PSM1\"\n";
    assert!(cfg.contains(r#"source = "sim""#) && cfg.contains(&prefix));
    std::fs::write(&cfg_path, &cfg).unwrap();
    let out = check_config(&root);
    assert!(out.status.success(), "{}", text(&out));
    let shown = String::from_utf8_lossy(&out.stdout);
    assert!(
        shown.contains("console-PSM1.json") && !shown.contains("identity"),
        "check-config does not show the console's base frame: {shown}"
    );
    let mut serve = Proc::spawn(
        "installed serve",
        Command::new(root.join("usr/local/bin/dvrk-sidecar"))
            .args(["serve", "--config"])
            .arg(&cfg_path)
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped()),
    );
    let samples = echo_json(&format!("{prefix}/measured_js"), 3, Duration::from_secs(60));
    assert_eq!(samples.len(), 3);
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve of the installed config: {st}: {log}");

    // A second install keeps the lab's edited configuration.
    let out = install(&root, &["--binary", bin_arg()]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(std::fs::read_to_string(&cfg_path).unwrap(), cfg);
    assert!(text(&out).contains("keeping existing"));

    // Uninstall removes what install added and keeps /etc/dvrk-sidecar; --purge removes it.
    let out = install(&root, &["--uninstall"]);
    assert!(out.status.success(), "{}", text(&out));
    for gone in [
        "usr/local/bin/dvrk-sidecar",
        "etc/systemd/system/dvrk-sidecar.service",
        "etc/systemd/system/dvrk-sidecar.service.d",
        "var/lib/dvrk-sidecar",
    ] {
        assert!(!root.join(gone).exists(), "{gone} left after --uninstall");
    }
    assert_eq!(std::fs::read_to_string(&cfg_path).unwrap(), cfg);
    let out = install(&root, &["--uninstall", "--purge"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(!etc.exists(), "--purge kept {}", etc.display());
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_file(&console);
}

/// `--user NAME` runs the unit as the lab's account through a drop-in that uninstall removes.
#[test]
fn user_drop_in_is_installed_and_removed() {
    let root = scratch("install-user");
    let out = install(&root, &["--binary", bin_arg(), "--user", "alice"]);
    assert!(out.status.success(), "{}", text(&out));
    let dropin = root.join("etc/systemd/system/dvrk-sidecar.service.d/user.conf");
    let d = std::fs::read_to_string(&dropin).unwrap();
    assert!(d.lines().any(|l| l == "User=alice"), "{d}");
    let out = install(&root, &["--binary", bin_arg()]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        !dropin.exists(),
        "a later install without --user keeps User=alice"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// Wrong arguments stop the script before it installs anything, with a message naming what is
/// wrong.
#[test]
fn install_refuses_bad_arguments_before_installing_anything() {
    let root = scratch("install-bad");
    let not_exec: PathBuf = root.join("not-executable");
    std::fs::write(&not_exec, "#!/bin/sh\n").unwrap();
    std::fs::set_permissions(&not_exec, std::fs::Permissions::from_mode(0o644)).unwrap();
    let missing = root.join("missing.json");
    let cases: [(Vec<&str>, &str); 5] = [
        (vec![], "--binary PATH is required"),
        (
            vec!["--binary", "/nonexistent/dvrk-sidecar"],
            "/nonexistent/dvrk-sidecar: no such file",
        ),
        (
            vec!["--binary", not_exec.to_str().unwrap()],
            "not an executable file",
        ),
        (
            vec![
                "--binary",
                bin_arg(),
                "--io-json",
                missing.to_str().unwrap(),
            ],
            "missing.json: not a readable file",
        ),
        (vec!["--purge"], "--purge only goes with --uninstall"),
    ];
    for (args, msg) in cases {
        let out = install(&root, &args);
        assert!(!out.status.success(), "{args:?} succeeded: {}", text(&out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(msg), "{args:?}: expected {msg:?} in: {err}");
        assert!(!root.join("usr").exists(), "{args:?} installed something");
    }
    // The missing --binary message tells how to build without cargo as root.
    let err = String::from_utf8_lossy(&install(&root, &[]).stderr).into_owned();
    assert!(
        err.contains("cargo build --release -p dvrk-sidecar"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&root);
}
