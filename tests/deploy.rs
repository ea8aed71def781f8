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
fn systemd_analyze_verifies_both_units() {
    let out = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .expect("build.rs found systemd-analyze: it must run now");
    assert!(out.status.success());
    // systemd-analyze checks that ExecStart's binary exists: point the units at the one built.
    // Both in one directory, so the bridge's After=/Wants= find the sidecar's unit.
    let bin = sidecar_bin();
    let dir = scratch("unit");
    let mut paths = Vec::new();
    for name in ["dvrk-sidecar.service", "dvrk-sidecar-ros2-bridge.service"] {
        let unit = std::fs::read_to_string(repo().join("deploy").join(name)).unwrap();
        assert!(unit.contains("/usr/local/bin/dvrk-sidecar "), "{name}");
        let unit = unit.replace("/usr/local/bin/dvrk-sidecar", bin.to_str().unwrap());
        let path = dir.join(name);
        std::fs::write(&path, unit).unwrap();
        paths.push(path);
    }
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .args(&paths)
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
    let _ = std::fs::remove_dir_all(&dir);
}

/// The bridge is a unit of its own, after the sidecar, as the sidecar's account, with the
/// command the README gives.
#[test]
fn the_bridge_unit_follows_the_sidecar() {
    let unit =
        std::fs::read_to_string(repo().join("deploy/dvrk-sidecar-ros2-bridge.service")).unwrap();
    let set = |key: &str| -> Vec<String> {
        unit.lines()
            .map(str::trim)
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| l.strip_prefix(&format!("{key}=")).map(str::to_owned))
            .collect()
    };
    assert_eq!(
        set("ExecStart"),
        ["/usr/local/bin/dvrk-sidecar ros2-bridge --config /etc/dvrk-sidecar/sidecar.toml"]
    );
    assert!(
        set("After")
            .iter()
            .any(|a| a.contains("dvrk-sidecar.service"))
    );
    assert_eq!(set("PartOf"), ["dvrk-sidecar.service"]);
    assert_eq!(set("WantedBy"), ["dvrk-sidecar.service"]);
    assert_eq!(set("User"), ["dvrk-sidecar"]);
    assert_eq!(set("PrivateTmp"), ["no"]);
    assert_eq!(set("RemoveIPC"), ["no"]);
    assert!(
        set("PrivateDevices").is_empty(),
        "/dev/shm must stay shared"
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
    let out = install(&root, &["--tap", "--system-user", "--binary", bin_arg()]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(dropin_path.exists());
    let out = install(&root, &["--system-user", "--binary", bin_arg()]);
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
/// DESTDIR and SUDO_USER in the environment (the account is then named by the arguments).
fn install(root: &Path, args: &[&str]) -> Output {
    install_env(root, args, None)
}

/// [`install`] as if run by `sudo` from the account `sudo_user`.
fn install_env(root: &Path, args: &[&str], sudo_user: Option<&str>) -> Output {
    let mut cmd = Command::new("bash");
    cmd.arg(repo().join("deploy/install.sh"))
        .arg("--root")
        .arg(root)
        .args(args)
        .env_remove("DESTDIR")
        .env_remove("SUDO_USER");
    if let Some(u) = sudo_user {
        cmd.env("SUDO_USER", u);
    }
    cmd.output().unwrap()
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
    let out = install(
        &root,
        &[
            "--system-user",
            "--binary",
            bin_arg(),
            "--io-json",
            json.to_str().unwrap(),
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
        ("etc/systemd/system/dvrk-sidecar-ros2-bridge.service", 0o644),
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

    // Naming the source (the simulator here) and a prefix of this test makes it start.
    let prefix = unique_prefix("deploy");
    let cfg = cfg
        .replace(r#"source = """#, r#"source = "sim""#)
        .replace(r#"# prefix = "PSM2""#, &format!(r#"prefix = "{prefix}""#));
    assert!(cfg.contains(r#"source = "sim""#) && cfg.contains(&prefix));
    std::fs::write(&cfg_path, &cfg).unwrap();
    let out = check_config(&root);
    assert!(out.status.success(), "{}", text(&out));
    let shown = String::from_utf8_lossy(&out.stdout);
    assert!(
        shown.contains("sawRobotIO1394-PSM1-00000.json"),
        "check-config does not show the lab's IO file: {shown}"
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
    let out = install(&root, &["--system-user", "--binary", bin_arg()]);
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
        "etc/systemd/system/dvrk-sidecar-ros2-bridge.service",
        "var/lib/dvrk-sidecar",
    ] {
        assert!(!root.join(gone).exists(), "{gone} left after --uninstall");
    }
    assert_eq!(std::fs::read_to_string(&cfg_path).unwrap(), cfg);
    let out = install(&root, &["--uninstall", "--purge"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(!etc.exists(), "--purge kept {}", etc.display());
    let _ = std::fs::remove_dir_all(&root);
}

/// One account for the service, the bridge and the consumers: `--user NAME`, by default the
/// account that ran sudo, or the system user; never root, never unsaid. A drop-in per unit,
/// removed by a later install as the system user and by uninstall.
#[test]
fn one_account_for_the_service_the_bridge_and_the_consumers() {
    let root = scratch("install-user");
    let dropins = [
        root.join("etc/systemd/system/dvrk-sidecar.service.d/user.conf"),
        root.join("etc/systemd/system/dvrk-sidecar-ros2-bridge.service.d/user.conf"),
    ];
    let user_of = |p: &Path| {
        let d = std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        d.lines()
            .find_map(|l| l.strip_prefix("User="))
            .map(str::to_owned)
    };
    let out = install(&root, &["--binary", bin_arg(), "--user", "alice"]);
    assert!(out.status.success(), "{}", text(&out));
    for d in &dropins {
        assert_eq!(user_of(d).as_deref(), Some("alice"));
    }
    assert!(text(&out).contains("as alice"), "{}", text(&out));
    // Without --user: the account that ran sudo, and it says so.
    let out = install_env(&root, &["--binary", bin_arg()], Some("bob"));
    assert!(out.status.success(), "{}", text(&out));
    for d in &dropins {
        assert_eq!(user_of(d).as_deref(), Some("bob"));
    }
    assert!(
        text(&out).contains("the account that ran sudo"),
        "{}",
        text(&out)
    );
    // The system user is the units' own User=: no drop-in.
    let out = install(&root, &["--binary", bin_arg(), "--system-user"]);
    assert!(out.status.success(), "{}", text(&out));
    for d in &dropins {
        assert!(!d.exists(), "{} kept after --system-user", d.display());
    }
    // Neither said nor sudo: refused, naming both ways; root is never the account.
    for (args, sudo, msg) in [
        (vec!["--binary", bin_arg()], None, "--system-user"),
        (vec!["--binary", bin_arg()], Some("root"), "--user NAME"),
        (
            vec!["--binary", bin_arg(), "--user", "root"],
            None,
            "never runs as root",
        ),
        (
            vec!["--binary", bin_arg(), "--user", "alice", "--system-user"],
            None,
            "exclude each other",
        ),
    ] {
        let out = install_env(&root, &args, sudo);
        assert!(!out.status.success(), "{args:?} {sudo:?}: {}", text(&out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(msg),
            "{args:?} {sudo:?}: expected {msg:?} in {err}"
        );
    }
    let out = install(&root, &["--uninstall"]);
    assert!(out.status.success(), "{}", text(&out));
    for d in &dropins {
        assert!(!d.exists());
    }
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
    let cases: [(Vec<&str>, &str); 7] = [
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
                "--system-user",
                "--binary",
                bin_arg(),
                "--io-json",
                missing.to_str().unwrap(),
            ],
            "missing.json: not a readable file",
        ),
        (vec!["--purge"], "--purge only goes with --uninstall"),
        (
            vec!["--system-user", "--binary", bin_arg(), "--arms", "PSM1"],
            "--arms PSM1 needs --dvrk-json",
        ),
        (
            vec![
                "--system-user",
                "--binary",
                bin_arg(),
                "--source",
                "tcp:1.2.3.4",
            ],
            "--source tcp:1.2.3.4: not one of",
        ),
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

/// A lab's dVRK directory (tests/data/dvrk-system): the system JSON and the arms' IO files.
fn lab(file: &str) -> PathBuf {
    repo().join("tests/data/dvrk-system").join(file)
}

/// Every file (not directory) under `dir`, relative to it.
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if e.file_type().unwrap().is_dir() {
                todo.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// `--dvrk-json` with a lab's two-PSM system JSON: one [[arm]] per PSM with the boards, kind and
/// IO file of each arm's sawRobotIO1394 JSON, its base frame and the JSON's port; the file
/// passes check-config; `--arms` chooses; an edited file is never overwritten; uninstall
/// --purge leaves no file behind.
#[test]
fn install_from_a_dvrk_system_json_serves_every_psm_then_uninstalls() {
    let root = scratch("install-system");
    let _ = std::fs::remove_dir_all(&root);
    let system = lab("system-PSM1-PSM2.json");
    let etc = root.join("etc/dvrk-sidecar");
    let cfg_path = etc.join("sidecar.toml");

    // The JSON's own port: FireWire port 0 ("fw"); the MTM and the simulated ECM are skipped.
    let out = install(
        &root,
        &[
            "--user",
            "alice",
            "--no-enable",
            "--binary",
            bin_arg(),
            "--dvrk-json",
            system.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("skipped MTML (MTM)"), "{}", text(&out));
    let cfg = std::fs::read_to_string(&cfg_path).unwrap();
    assert!(cfg.lines().any(|l| l == r#"source = "fw:0""#), "{cfg}");
    for (arm, boards, io) in [
        ("PSM1", "[6, 7]", "io/sawRobotIO1394-PSM1-28007.json"),
        ("PSM2", "[8, 9]", "io/sawRobotIO1394-PSM2-27374.json"),
    ] {
        let table = cfg
            .split("[[arm]]")
            .find(|t| t.contains(&format!("name = \"{arm}\"")))
            .unwrap_or_else(|| panic!("no [[arm]] {arm} in {cfg}"));
        for line in [
            format!("boards = {boards}"),
            format!("io = \"{io}\""),
            "kind = \"classic\"".to_owned(),
            "instrument = \"console\"".to_owned(),
            format!("compliance = \"compliance/{arm}.toml\""),
            "dvrk_json = \"dvrk/system-PSM1-PSM2.json\"".to_owned(),
            format!("arm = \"{arm}\""),
        ] {
            assert!(
                table.lines().any(|l| l == line),
                "{arm} lacks {line}: {table}"
            );
        }
        assert_eq!(mode(&etc.join(io)), 0o640, "{io}");
        assert_eq!(
            std::fs::read(etc.join(io)).unwrap(),
            std::fs::read(lab(io.strip_prefix("io/").unwrap())).unwrap()
        );
        // The placeholder says what it is and holds the paper's parameters.
        let c = std::fs::read_to_string(etc.join(format!("compliance/{arm}.toml"))).unwrap();
        assert!(c.starts_with(&format!("# PLACEHOLDER for {arm}")), "{c}");
        assert!(c.contains("model = \"paper\""), "{c}");
    }
    assert!(
        !cfg.contains("MTML") && !cfg.contains("name = \"ECM\""),
        "{cfg}"
    );
    assert_eq!(mode(&etc.join("dvrk/system-PSM1-PSM2.json")), 0o640);

    // On Ethernet instead (--source): the file passes check-config, every arm loaded with its
    // base frame from the copy of the system JSON, and the placeholder warned about.
    let out = install(
        &root,
        &[
            "--user",
            "alice",
            "--no-enable",
            "--binary",
            bin_arg(),
            "--dvrk-json",
            system.to_str().unwrap(),
            "--source",
            "udp:127.0.0.1",
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let cfg = std::fs::read_to_string(&cfg_path).unwrap();
    assert!(
        cfg.lines().any(|l| l == r#"source = "udp:127.0.0.1""#),
        "{cfg}"
    );
    assert!(cfg.contains("(the JSON says fw:0)"), "{cfg}");
    assert!(!text(&out).contains("NOT started"), "{}", text(&out));
    let out = check_config(&root);
    assert!(out.status.success(), "{}", text(&out));
    let shown = String::from_utf8_lossy(&out.stdout);
    assert!(
        shown.contains("system-PSM1-PSM2.json (arm PSM1)") && shown.contains("[6, 7]"),
        "{shown}"
    );
    let warned = String::from_utf8_lossy(&out.stderr);
    assert!(
        warned.contains("PSM1.toml") && warned.contains("torque offset"),
        "the placeholder is not warned about: {warned}"
    );

    // --arms: only PSM2. An edited sidecar.toml is kept; the new one goes next to it.
    let edited = cfg.replace("mlockall = false", "mlockall = true");
    std::fs::write(&cfg_path, &edited).unwrap();
    let out = install(
        &root,
        &[
            "--user",
            "alice",
            "--no-enable",
            "--binary",
            bin_arg(),
            "--dvrk-json",
            system.to_str().unwrap(),
            "--arms",
            "PSM2",
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(std::fs::read_to_string(&cfg_path).unwrap(), edited);
    let new = std::fs::read_to_string(etc.join("sidecar.toml.new")).unwrap();
    assert!(
        new.contains("name = \"PSM2\"") && !new.contains("name = \"PSM1\""),
        "{new}"
    );
    assert!(text(&out).contains("sidecar.toml.new"), "{}", text(&out));

    // Uninstall keeps the configuration (the lab's fits); --purge removes every file.
    let out = install(&root, &["--uninstall"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(cfg_path.exists() && etc.join("compliance/PSM2.toml").exists());
    let out = install(&root, &["--uninstall", "--purge"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(files_under(&root), Vec::<PathBuf>::new());
    let _ = std::fs::remove_dir_all(&root);
}

/// A dVRK 2.2 console JSON: `io.port` and `base-frame`; and --console-unit ties the sidecar to
/// the console's unit (a drop-in and a `.wants` link that uninstall removes).
#[test]
fn install_from_a_console_json_follows_the_console_unit() {
    let root = scratch("install-console");
    let _ = std::fs::remove_dir_all(&root);
    let out = install(
        &root,
        &[
            "--user",
            "alice",
            "--bridge",
            "--console-unit",
            "dvrk-console.service",
            "--binary",
            bin_arg(),
            "--dvrk-json",
            lab("console-PSM2.json").to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let cfg = std::fs::read_to_string(root.join("etc/dvrk-sidecar/sidecar.toml")).unwrap();
    for line in [
        r#"source = "udp:169.254.0.100""#,
        r#"name = "PSM2""#,
        "boards = [8, 9]",
        r#"dvrk_json = "dvrk/console-PSM2.json""#,
    ] {
        assert!(cfg.lines().any(|l| l == line), "lacks {line}: {cfg}");
    }
    let out_check = check_config(&root);
    assert!(out_check.status.success(), "{}", text(&out_check));
    let units = root.join("etc/systemd/system");
    let dropin =
        std::fs::read_to_string(units.join("dvrk-sidecar.service.d/console.conf")).unwrap();
    for line in [
        "After=dvrk-console.service",
        "Requisite=dvrk-console.service",
        "PartOf=dvrk-console.service",
    ] {
        assert!(dropin.lines().any(|l| l == line), "lacks {line}: {dropin}");
    }
    let link = units.join("dvrk-console.service.wants/dvrk-sidecar.service");
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        Path::new("/etc/systemd/system/dvrk-sidecar.service")
    );
    assert!(
        text(&out).contains("systemctl enable --now dvrk-sidecar-ros2-bridge.service"),
        "{}",
        text(&out)
    );
    // A later install without --console-unit unties it.
    let out = install(
        &root,
        &[
            "--user",
            "alice",
            "--binary",
            bin_arg(),
            "--dvrk-json",
            lab("console-PSM2.json").to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    assert!(!units.join("dvrk-sidecar.service.d/console.conf").exists());
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "the .wants link stayed"
    );
    let out = install(&root, &["--uninstall", "--purge"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(files_under(&root), Vec::<PathBuf>::new());
    let _ = std::fs::remove_dir_all(&root);
}

/// What --dvrk-json refuses before installing anything, naming the file, the arm and the field.
#[test]
fn install_refuses_a_dvrk_json_it_cannot_serve() {
    let root = scratch("install-system-bad");
    let src = scratch("install-system-bad-src");
    // A system JSON whose IO files are not next to it.
    let alone = src.join("system-PSM1-PSM2.json");
    std::fs::copy(lab("system-PSM1-PSM2.json"), &alone).unwrap();
    // A system JSON with no PSM.
    let mtms = src.join("system-MTML.json");
    std::fs::write(
        &mtms,
        r#"{ "IOs": [ { "name": "IO1", "port": "fw" } ],
             "arms": [ { "name": "MTML", "type": "MTM", "serial": "22723", "IO": "IO1" } ] }"#,
    )
    .unwrap();
    let system = lab("system-PSM1-PSM2.json");
    let io = lab("sawRobotIO1394-PSM1-28007.json");
    let cases: [(Vec<&str>, &str); 5] = [
        (
            vec!["--dvrk-json", mtms.to_str().unwrap()],
            "no PSM on the boards in \"arms\" (found: MTML (MTM))",
        ),
        (
            vec!["--dvrk-json", alone.to_str().unwrap()],
            "arm PSM1: its IO file",
        ),
        (
            vec![
                "--dvrk-json",
                system.to_str().unwrap(),
                "--arms",
                "PSM1,PSM3",
            ],
            "no arm named \"PSM3\"",
        ),
        (
            vec!["--dvrk-json", system.to_str().unwrap(), "--arms", "MTML"],
            "MTML",
        ),
        (
            vec![
                "--dvrk-json",
                system.to_str().unwrap(),
                "--io-json",
                io.to_str().unwrap(),
            ],
            "--io-json and --dvrk-json exclude each other",
        ),
    ];
    for (args, msg) in cases {
        let mut all = vec!["--user", "alice", "--binary", bin_arg()];
        all.extend(args.iter().copied());
        let out = install(&root, &all);
        assert!(!out.status.success(), "{args:?} succeeded: {}", text(&out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(msg), "{args:?}: expected {msg:?} in: {err}");
        assert!(!root.join("usr").exists(), "{args:?} installed something");
    }
    // The missing IO file is named with the path the dVRK would use.
    let mut args = vec!["--user", "alice", "--binary", bin_arg(), "--dvrk-json"];
    args.push(alone.to_str().unwrap());
    let err = String::from_utf8_lossy(&install(&root, &args).stderr).into_owned();
    assert!(
        err.contains(src.join("sawRobotIO1394-PSM1-28007.json").to_str().unwrap()),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_dir_all(&src);
}
