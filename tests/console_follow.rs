//! Following the dVRK console (issue 19), end to end with real processes: the console stand-in
//! (`sim --crtk PSM1 --boards ...`: the simulated arm's boards on UDP and its CRTK topics over
//! DDS, in a domain of its own) drives both what `serve` reads and what the console says;
//! `serve` runs with `instrument = "console"`; `echo` reads what it publishes. The test acts as
//! the console's operator through the stand-in's stdin: homing, swap to an instrument with and
//! without parameters, removal, ERROR, base-frame change, disable, and the console gone; and
//! `serve` stopped and continued (Ctrl-Z, fg) still follows.

mod common;

use std::io::Write;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Proc, repo, scratch, sidecar_bin};

fn flags(v: &serde_json::Value) -> Vec<String> {
    v["header"]["flags"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|f| f.as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default()
}

fn latest(topic: &str) -> Option<serde_json::Value> {
    common::echo_json(topic, 1, Duration::from_secs(10))
        .into_iter()
        .next()
}

/// Waits (up to 20 s) for a sample of `topic` that satisfies `ok`; returns it.
fn until(topic: &str, what: &str, ok: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let mut last = None;
    let found = common::eventually(Duration::from_secs(20), || {
        let v = latest(topic)?;
        let good = ok(&v);
        last = Some(v.clone());
        good.then_some(v)
    });
    found.unwrap_or_else(|| panic!("{what}: never seen on {topic}; last sample: {last:?}"))
}

fn position(v: &serde_json::Value) -> [f64; 3] {
    let p = &v["position_m"];
    [0, 1, 2].map(|i| p[i].as_f64().unwrap_or(f64::NAN))
}

/// Parameter sets for two instruments (the layout `fit --add` writes), the large needle driver
/// and the Cadière forceps, each the simulator's file.
fn two_instrument_params(dir: &std::path::Path) -> std::path::PathBuf {
    let params = dir.join("params.toml");
    let text = std::fs::read_to_string(repo().join("config/compliance/sim-psm.toml")).unwrap();
    let body = text
        .replace("[[joint]]", "[[set.joint]]")
        .replace("[joint.", "[set.joint.");
    std::fs::write(
        &params,
        format!(
            "[[set]]\ninstrument = \"LARGE_NEEDLE_DRIVER:400006\"\n{body}\n\
             [[set]]\ninstrument = \"CADIERE_FORCEPS:400049\"\n{body}\n"
        ),
    )
    .unwrap();
    params
}

/// `serve` of the emulated arm at `boards` with `instrument = "console"`, following the console
/// of DDS `domain`, with parameter sets for two instruments (the layout `fit --add` writes):
/// the large needle driver and the Cadière forceps. Returns it and its topics' prefix.
fn follower(dir: &std::path::Path, name: &str, boards: &str, domain: u16) -> (Proc, String) {
    let params = two_instrument_params(dir);
    let prefix = format!("{name}{}/PSM1", std::process::id());
    let cfg = dir.join("sidecar.toml");
    std::fs::write(
        &cfg,
        format!(
            "source = \"udp:{boards}\"\naccess = \"shared\"\nio = \"{}\"\narm = \"classic\"\n\
             instrument = \"console\"\ncompliance = \"{}\"\nrate = 1500\nprefix = \"{prefix}\"\n",
            repo().join("config/io/psm-classic.toml").display(),
            params.display()
        ),
    )
    .unwrap();
    let serve = Proc::spawn(
        "serve",
        Command::new(sidecar_bin())
            .args(["serve", "--config"])
            .arg(&cfg)
            .env("ROS_DOMAIN_ID", domain.to_string())
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    );
    (serve, prefix)
}

#[test]
fn serve_follows_the_consoles_homing_instrument_state_and_base_frame() {
    let test = "console_follow";
    let dir = scratch(test);
    let domain = 100 + (std::process::id() % 40) as u16;
    let port = common::free_udp_port();
    let boards = format!("127.0.0.1:{port}");
    let mut console = Proc::spawn(
        "sim --crtk",
        Command::new(sidecar_bin())
            .args([
                "sim",
                "--crtk",
                "PSM1",
                "--events-stdin",
                "--start",
                "enabled",
                "--scenario",
            ])
            .arg(repo().join("config/sim/clamp.toml"))
            .args(["--boards", &boards])
            .env("ROS_DOMAIN_ID", domain.to_string())
            .env("RUST_LOG", "warn")
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    );
    let mut stdin = console.child.as_mut().unwrap().stdin.take().unwrap();
    let mut say = |line: &str| say_to(&mut stdin, line);

    let (mut serve, prefix) = follower(&dir, "cf", &boards, domain);
    let js = format!("{prefix}/measured_js");
    let cjs = format!("{prefix}/compensated/measured_js");
    let cp = format!("{prefix}/measured_cp");
    let local = format!("{prefix}/local/measured_cp");
    let ccp = format!("{prefix}/compensated/local/measured_cp");
    let status = format!("{prefix}/compensated/status");

    // 1. enabled but not homed: every sample invalid, NOT_HOMED
    until(&js, "not homed", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"NOT_HOMED".to_owned())
    });
    // 2. homed: valid, the instrument from tool_type (the large needle driver, parameters for it)
    say("home");
    let v = until(&cjs, "homed and valid", |v| {
        v["header"]["valid"] == true
            && !flags(v)
                .iter()
                .any(|f| f.contains("HOMED") || f.contains("UNKNOWN"))
    });
    assert!(!flags(&v).contains(&"NO_CALIBRATION".to_owned()), "{v}");
    // 3. a swap to an instrument with parameters of its own: corrected, its kinematics
    say("tool=CADIERE_FORCEPS:400049[..]");
    let st = until(&status, "the forceps' parameter set", |v| {
        v["source"]["instrument"] == "CADIERE_FORCEPS:400049[..]"
    });
    assert_eq!(st["source"]["parameter_set"], 2, "{st}");
    assert_eq!(st["source"]["console_state"], "ENABLED", "{st}");
    assert_eq!(st["source"]["homed"], true, "{st}");
    let v = latest(&ccp).unwrap();
    assert!(!flags(&v).contains(&"NO_CALIBRATION".to_owned()), "{v}");
    // 3b. an instrument without parameters: compensated = raw, NO_CALIBRATION
    say("tool=PROGRASP_FORCEPS:400093[..]");
    let v = until(&ccp, "NO_CALIBRATION", |v| {
        flags(v).contains(&"NO_CALIBRATION".to_owned())
    });
    // its own kinematics: the ProGrasp's tip is 1.6 mm farther than the needle driver's
    assert!(position(&v)[2] < -0.1235 - 0.001, "{v}");
    assert_eq!(v["header"]["valid"], true);
    let raw = latest(&local).unwrap();
    let (a, b) = (position(&v), position(&raw));
    assert!(
        (0..3).all(|i| (a[i] - b[i]).abs() < 1e-4),
        "compensated {a:?} vs raw {b:?}"
    );
    // 4. removed: compensated invalid (NO_INSTRUMENT), raw still valid
    say("tool=");
    until(&ccp, "NO_INSTRUMENT", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"NO_INSTRUMENT".to_owned())
    });
    let raw = until(&js, "raw valid without instrument", |v| {
        v["header"]["valid"] == true
    });
    assert!(flags(&raw).contains(&"NO_INSTRUMENT".to_owned()));
    // 5. ERROR: raw only, INSTRUMENT_UNSUPPORTED
    say("tool=ERROR");
    until(&ccp, "INSTRUMENT_UNSUPPORTED", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"INSTRUMENT_UNSUPPORTED".to_owned())
    });
    // 6. back to the instrument of the parameters: corrected again
    say("tool=LARGE_NEEDLE_DRIVER:400006[..]");
    until(&ccp, "back to a modelled instrument", |v| {
        v["header"]["valid"] == true
            && !flags(v)
                .iter()
                .any(|f| f.contains("INSTRUMENT") || f == "NO_CALIBRATION")
    });
    // 7. the base frame from the console: measured_cp = base x local/measured_cp
    say("base=0.1,0.2,0.3,0.5");
    let base = nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(0.1, 0.2, 0.3),
        nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.5),
    );
    let expect = |l: [f64; 3]| base * nalgebra::Point3::new(l[0], l[1], l[2]);
    let l = position(&latest(&local).unwrap());
    until(&cp, "the console's base frame", |v| {
        let p = position(v);
        let e = expect(l);
        !flags(v).contains(&"BASE_FRAME_STALE".to_owned())
            && (p[0] - e.x).abs() < 1e-3
            && (p[1] - e.y).abs() < 1e-3
            && (p[2] - e.z).abs() < 1e-3
    });
    // 7b. serve stopped and continued (Ctrl-Z then fg): it still follows the console. The stop
    // interrupts RustDDS's event loop, which then ends for good; the follower restarts it.
    serve.signal(libc::SIGSTOP);
    std::thread::sleep(Duration::from_millis(50));
    serve.signal(libc::SIGCONT);
    std::thread::sleep(Duration::from_millis(50));
    say("tool=CADIERE_FORCEPS:400049[..]");
    until(
        &status,
        "an instrument swap after a stop and continue",
        |v| v["source"]["instrument"] == "CADIERE_FORCEPS:400049[..]",
    );
    // 8. disabled: raw valid, the correction withheld (ARM_NOT_ENABLED)
    say("disable");
    let v = until(&ccp, "ARM_NOT_ENABLED", |v| {
        flags(v).contains(&"ARM_NOT_ENABLED".to_owned())
    });
    assert!(
        !flags(&v).iter().any(|f| f.starts_with("CORRECTION_ACTIVE")),
        "{v}"
    );
    // 9. the console gone: CONSOLE_UNKNOWN, the last base frame flagged stale
    drop(stdin);
    console.terminate();
    let v = until(&js, "CONSOLE_UNKNOWN", |v| {
        flags(v).contains(&"CONSOLE_UNKNOWN".to_owned())
    });
    assert!(flags(&v).contains(&"BASE_FRAME_STALE".to_owned()), "{v}");

    let (_, log) = serve.terminate();
    assert!(log.contains("following the dVRK console"), "{log}");
    // the stop and continue, when it ended RustDDS's event loop (most runs; a stop that lands
    // outside its poll leaves it running): silent, its participant restarted, then heard again
    if log.contains("DDS participant restarted") {
        assert!(log.contains("hearing PSM1 again after"), "{log}");
    }
    assert!(
        log.contains("CADIERE_FORCEPS") && log.contains("no instrument"),
        "{log}"
    );
}

/// The Cyclone DDS console stand-in (`tests/bridge/cyclone_console.py`) on DDS `domain`, for
/// 300 s, with `args`; its stdin (the operator's lines) open.
fn cyclone_console(
    dir: &std::path::Path,
    domain: u16,
    args: &[&str],
) -> (Proc, std::process::ChildStdin) {
    // fails with what to install when cyclonedds is missing (the tests run only where
    // build.rs found it, or under CI, where it must be)
    common::require_python(&["cyclonedds"]);
    let mut console = Proc::spawn(
        "cyclone console",
        Command::new("python3")
            .arg(repo().join("tests/bridge/cyclone_console.py"))
            .args(["--domain", &domain.to_string(), "--seconds", "300"])
            .args(args)
            .env("CYCLONEDDS_URI", common::cyclone_uri(dir))
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    );
    let stdin = console.child.as_mut().unwrap().stdin.take().unwrap();
    (console, stdin)
}

/// One operator line to a console stand-in.
fn say_to(stdin: &mut std::process::ChildStdin, line: &str) {
    writeln!(stdin, "{line}").unwrap();
    stdin.flush().unwrap();
}

/// The same following with a console of another author: `tests/bridge/cyclone_console.py`, the
/// console's CRTK topics written with Cyclone DDS (the DDS under ROS 2's rmw_cyclonedds) and an
/// arm of its own; the arm `serve` reads is the emulator's. Homing, the instrument (a tool_type
/// without the model range), its removal, a base frame of its own (from its `measured_cp` and
/// `local/measured_cp`, stamped microseconds apart) and FAULT are followed.
#[cfg_attr(
    not(has_py_cyclonedds),
    ignore = "needs python3 with cyclonedds: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn serve_follows_a_console_written_with_cyclone_dds() {
    let dir = scratch("console_follow_cyclone");
    let domain = 150 + (std::process::id() % 40) as u16;
    let port = common::free_udp_port();
    let mut emulator = common::emulator(port, "idle.toml");
    let (mut console, mut stdin) = cyclone_console(&dir, domain, &["--start", "enabled"]);
    let mut say = |line: &str| say_to(&mut stdin, line);
    let (mut serve, prefix) = follower(&dir, "cyc", &format!("127.0.0.1:{port}"), domain);
    let js = format!("{prefix}/measured_js");
    let cp = format!("{prefix}/measured_cp");
    let local = format!("{prefix}/local/measured_cp");
    let ccp = format!("{prefix}/compensated/local/measured_cp");
    let status = format!("{prefix}/compensated/status");

    until(&js, "not homed", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"NOT_HOMED".to_owned())
    });
    // not homed, not corrected: the compensated sample says no correction is active
    let v = until(&ccp, "not homed, not corrected", |v| {
        flags(v).contains(&"NOT_HOMED".to_owned())
    });
    assert!(
        !flags(&v).iter().any(|f| f.starts_with("CORRECTION_ACTIVE")),
        "{v}"
    );
    say("home");
    // (the name as the console's index writes it, with its model range)
    let st = until(&status, "homed, the needle driver's parameters", |v| {
        v["source"]["instrument"] == "LARGE_NEEDLE_DRIVER:400006[..]"
            && v["source"]["homed"] == true
    });
    assert_eq!(st["source"]["parameter_set"], 1, "{st}");
    until(&ccp, "valid and corrected", |v| {
        v["header"]["valid"] == true
            && !flags(v)
                .iter()
                .any(|f| f.contains("HOMED") || f.contains("UNKNOWN") || f == "NO_CALIBRATION")
    });
    // its base frame (a translation): measured_cp = local/measured_cp + base
    say("base 0.3 -0.2 0.1");
    let l = position(&latest(&local).unwrap());
    until(&cp, "the console's base frame", |v| {
        let p = position(v);
        !flags(v).contains(&"BASE_FRAME_STALE".to_owned())
            && (p[0] - l[0] - 0.3).abs() < 1e-3
            && (p[1] - l[1] + 0.2).abs() < 1e-3
            && (p[2] - l[2] - 0.1).abs() < 1e-3
    });
    say("tool");
    until(&ccp, "NO_INSTRUMENT", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"NO_INSTRUMENT".to_owned())
    });
    say("tool LARGE_NEEDLE_DRIVER:400006");
    until(&ccp, "the instrument back", |v| {
        v["header"]["valid"] == true
    });
    say("state FAULT");
    let v = until(&ccp, "ARM_NOT_ENABLED", |v| {
        flags(v).contains(&"ARM_NOT_ENABLED".to_owned())
    });
    assert!(
        !flags(&v).iter().any(|f| f.starts_with("CORRECTION_ACTIVE")),
        "{v}"
    );
    drop(stdin);
    console.terminate();
    serve.terminate();
    emulator.terminate();
}

/// A console whose event writers are VOLATILE (a version, a bridge or a stand-in unlike the
/// dVRK console's TRANSIENT_LOCAL ones) matches no TRANSIENT_LOCAL reader; `serve` hears it
/// through its live companion readers, from its next change on: the instrument swapped and the
/// arm homed and then faulted after `serve` started are followed.
#[cfg_attr(
    not(has_py_cyclonedds),
    ignore = "needs python3 with cyclonedds: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn serve_follows_a_console_with_volatile_events_from_its_next_change() {
    let dir = scratch("console_follow_volatile");
    let domain = 190 + (std::process::id() % 40) as u16;
    let port = common::free_udp_port();
    let mut emulator = common::emulator(port, "idle.toml");
    let (mut console, mut stdin) = cyclone_console(
        &dir,
        domain,
        &["--start", "enabled", "--events-volatile", "--silent-start"],
    );
    let mut say = |line: &str| say_to(&mut stdin, line);
    let (mut serve, prefix) = follower(&dir, "vol", &format!("127.0.0.1:{port}"), domain);
    let ccp = format!("{prefix}/compensated/local/measured_cp");
    let status = format!("{prefix}/compensated/status");
    // heard (its poses), its state not yet (it published none since serve joined): invalid,
    // the state unknown
    until(&status, "the console heard", |v| {
        v["source"]["console_heard"] == true
    });
    let v = until(&format!("{prefix}/measured_js"), "its state unknown", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"CONSOLE_UNKNOWN".to_owned())
    });
    assert!(flags(&v).contains(&"NOT_HOMED".to_owned()), "{v}");
    say("tool CADIERE_FORCEPS:400049");
    say("home");
    let st = until(&status, "the swap and the homing", |v| {
        v["source"]["instrument"] == "CADIERE_FORCEPS:400049[..]" && v["source"]["homed"] == true
    });
    assert_eq!(st["source"]["parameter_set"], 2, "{st}");
    until(&ccp, "valid and corrected", |v| {
        v["header"]["valid"] == true
    });
    say("state FAULT");
    until(&ccp, "ARM_NOT_ENABLED", |v| {
        flags(v).contains(&"ARM_NOT_ENABLED".to_owned())
    });
    drop(stdin);
    console.terminate();
    serve.terminate();
    emulator.terminate();
}

/// Every arm of a console in one service, with consoles of another author: two Cyclone DDS
/// stand-ins on one domain (PSM1 homed with the needle driver, PSM2 not homed with the Cadière
/// forceps) and one `serve` of both arms of `sim --arms PSM1,PSM2`, each `instrument =
/// "console"` with its `console_arm`. Each arm follows its own console only: PSM2's homing, its
/// instrument's removal and its FAULT leave PSM1's samples valid and corrected, and PSM1 keeps
/// its own instrument's parameters throughout.
#[cfg_attr(
    not(has_py_cyclonedds),
    ignore = "needs python3 with cyclonedds: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn one_serve_follows_each_arm_of_its_own_cyclone_dds_console() {
    let dir = scratch("console_follow_two_arms");
    let domain = 60 + (std::process::id() % 40) as u16;
    let port = common::free_udp_port();
    let c = repo().join("config");
    let mut emulator = common::emulator_with(
        "127.0.0.1",
        port,
        &[
            "--arms",
            "PSM1,PSM2",
            "--scenario",
            c.join("sim/idle.toml").to_str().unwrap(),
        ],
    );
    let (mut console1, _stdin1) = cyclone_console(&dir, domain, &["--arm", "PSM1"]);
    let (mut console2, mut stdin2) = cyclone_console(
        &dir,
        domain,
        &[
            "--arm",
            "PSM2",
            "--start",
            "enabled",
            "--tool",
            "CADIERE_FORCEPS:400049",
        ],
    );
    let mut say2 = |line: &str| say_to(&mut stdin2, line);
    let params = two_instrument_params(&dir);
    let p1 = common::unique_prefix("two_consoles_1");
    let p2 = common::unique_prefix("two_consoles_2");
    let mut text = format!("source = \"udp:127.0.0.1:{port}\"\naccess = \"shared\"\nrate = 1500\n");
    for (name, boards, console_arm) in [(&p1, "6, 7", "PSM1"), (&p2, "8, 9", "PSM2")] {
        text.push_str(&format!(
            "\n[[arm]]\nname = \"{name}\"\nboards = [{boards}]\nio = \"{}\"\nkind = \"classic\"\n\
             instrument = \"console\"\nconsole_arm = \"{console_arm}\"\ncompliance = \"{}\"\n",
            c.join("io/psm-classic.toml").display(),
            params.display()
        ));
    }
    let cfg = dir.join("sidecar.toml");
    std::fs::write(&cfg, text).unwrap();
    let mut serve = Proc::spawn(
        "serve",
        Command::new(sidecar_bin())
            .args(["serve", "--config"])
            .arg(&cfg)
            .env("ROS_DOMAIN_ID", domain.to_string())
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    );
    let ccp1 = format!("{p1}/compensated/local/measured_cp");
    let ccp2 = format!("{p2}/compensated/local/measured_cp");
    let status1 = format!("{p1}/compensated/status");
    let status2 = format!("{p2}/compensated/status");
    // PSM1 homed with the needle driver (set 1), PSM2 not homed with the forceps (set 2)
    let st = until(&status1, "PSM1 homed, its needle driver", |v| {
        v["source"]["instrument"] == "LARGE_NEEDLE_DRIVER:400006[..]"
            && v["source"]["homed"] == true
    });
    assert_eq!(st["source"]["parameter_set"], 1, "{st}");
    let st = until(&status2, "PSM2 not homed, its forceps", |v| {
        v["source"]["instrument"] == "CADIERE_FORCEPS:400049[..]" && v["source"]["homed"] == false
    });
    assert_eq!(st["source"]["parameter_set"], 2, "{st}");
    until(&ccp1, "PSM1 valid", |v| v["header"]["valid"] == true);
    until(&ccp2, "PSM2 not homed", |v| {
        v["header"]["valid"] == false && flags(v).contains(&"NOT_HOMED".to_owned())
    });
    // PSM1 stays valid and corrected through whatever PSM2's console does
    // PSM1 as before: none of the flags PSM2's changes set on its samples, its own parameter set, and
    // corrected (a loaded host may give it a gap and the estimator's warm-up after it, which
    // withholds the correction for a moment: that is PSM1's own, not PSM2's console)
    let psm1_as_before = || {
        for v in common::echo_json(&ccp1, 300, Duration::from_secs(10)) {
            let f = flags(&v);
            assert!(
                !f.iter().any(
                    |f| ["NOT_HOMED", "NO_INSTRUMENT", "ARM_NOT_ENABLED"].contains(&f.as_str())
                ),
                "PSM1 after a change of PSM2's console: {v}"
            );
        }
        until(&ccp1, "PSM1 valid and corrected", |v| {
            v["header"]["valid"] == true
                && flags(v).iter().any(|f| f.starts_with("CORRECTION_ACTIVE"))
        });
        let st = latest(&status1).expect("PSM1's status");
        assert_eq!(st["source"]["parameter_set"], 1, "{st}");
    };
    say2("home");
    until(&ccp2, "PSM2 homed, valid", |v| v["header"]["valid"] == true);
    psm1_as_before();
    say2("tool");
    until(&ccp2, "PSM2 without an instrument", |v| {
        flags(v).contains(&"NO_INSTRUMENT".to_owned())
    });
    psm1_as_before();
    say2("state FAULT");
    until(&ccp2, "PSM2 faulted", |v| {
        flags(v).contains(&"ARM_NOT_ENABLED".to_owned())
    });
    psm1_as_before();
    console2.terminate();
    console1.terminate();
    serve.terminate();
    emulator.terminate();
}
