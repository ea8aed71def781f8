//! The bad-input suite (issue 22): one probe per class of bad input, each driven through the real
//! binary. Every probe checks the exit status (refused, or a clean exit, never a signal) and that
//! the message names the file and the field (or line) and the value.
//!
//! Classes: a fixed-size array with an extra value, an unphysical stiffness, UDP port 0, a prefix
//! the bridge would refuse, a FIFO as configuration (under a timeout, so the suite itself cannot
//! hang), a huge invalid line, a huge number, stdout a closed pipe, `--out` onto a device or a
//! FIFO.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::os::fd::{FromRawFd, OwnedFd};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use common::*;

fn check_config(cfg: &Path) -> Output {
    Command::new(sidecar_bin())
        .args(["check-config", "--config", cfg.to_str().unwrap()])
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Refused: exit status 1 (an error, not a signal, not a panic's 101).
fn assert_refused(o: &Output, what: &str) -> String {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{what}: {:?}\n{err}", o.status);
    assert!(!err.contains("panicked"), "{what}: {err}");
    err
}

/// A service configuration in `dir` with `line` replacing the one that starts like it.
fn config_with(dir: &Path, name: &str, replace: &[(&str, &str)]) -> PathBuf {
    let c = repo().join("config");
    let mut text = format!(
        "source = \"sim\"\nio = \"{}\"\narm = \"classic\"\ninstrument = \
         \"LARGE_NEEDLE_DRIVER_400006\"\ncompliance = \"{}\"\nprefix = \"PSM1\"\n[sim]\nscenario = \
         \"{}\"\n",
        c.join("io/psm-classic.toml").display(),
        c.join("compliance/paper-psm.toml").display(),
        c.join("sim/idle.toml").display(),
    );
    for (from, to) in replace {
        let start = text.find(from).unwrap_or_else(|| panic!("{from}"));
        let end = start + text[start..].find('\n').unwrap();
        text.replace_range(start..end, to);
    }
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// The paper's compliance file with one line replaced.
fn compliance_with(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
    let text = std::fs::read_to_string(repo().join("config/compliance/paper-psm.toml")).unwrap();
    assert!(text.contains(from), "{from}");
    let p = dir.join(name);
    std::fs::write(&p, text.replacen(from, to, 1)).unwrap();
    p
}

fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: mkfifo(3) with a valid NUL-terminated path.
    assert_eq!(
        unsafe { libc::mkfifo(c.as_ptr(), 0o600) },
        0,
        "{}",
        p.display()
    );
}

#[test]
fn an_extra_array_value_is_refused_naming_field_and_lengths() {
    let d = scratch("bad_extra");
    let comp = compliance_with(
        &d,
        "five.toml",
        "[639.16, -432.35, 136.32, 3.12]",
        "[1.0, 639.16, -432.35, 136.32, 3.12]",
    );
    let cfg = config_with(
        &d,
        "sidecar.toml",
        &[(
            "compliance =",
            &format!("compliance = \"{}\"", comp.display()),
        )],
    );
    let err = assert_refused(&check_config(&cfg), "5-value cubic");
    assert!(
        err.contains("five.toml")
            && err.contains("joint.inverse_compliance_nm_per_rad")
            && err.contains("invalid length 5")
            && err.contains("exactly 4"),
        "{err}"
    );
    // A 4x5 base frame too.
    let cfg = config_with(
        &d,
        "frame.toml",
        &[(
            "prefix =",
            "prefix = \"PSM1\"\nbase_frame = { transform = [[1.0, 0.0, 0.0, 0.0, 9.0], \
             [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]] }",
        )],
    );
    let err = assert_refused(&check_config(&cfg), "4x5 base frame");
    assert!(
        err.contains("frame.toml")
            && err.contains("base_frame.transform")
            && err.contains("invalid length 5"),
        "{err}"
    );
}

#[test]
fn an_unphysical_stiffness_is_refused_naming_file_field_and_value() {
    let d = scratch("bad_stiffness");
    for (name, value, bound) in [
        ("stiff.toml", "1e308", "<= 500"),
        ("soft.toml", "1.0", ">= 2"),
    ] {
        let comp = compliance_with(
            &d,
            name,
            "[639.16, -432.35, 136.32, 3.12]",
            &format!("[0.0, 0.0, 0.0, {value}]"),
        );
        let cfg = config_with(
            &d,
            "sidecar.toml",
            &[(
                "compliance =",
                &format!("compliance = \"{}\"", comp.display()),
            )],
        );
        let err = assert_refused(&check_config(&cfg), name);
        assert!(
            err.contains(name)
                && err.contains("joint 1: inverse_compliance_nm_per_rad")
                && err.contains(&format!("= {value} N·m/rad"))
                && err.contains(bound),
            "{err}"
        );
    }
}

#[test]
fn udp_port_zero_and_a_path_like_prefix_are_refused_at_load() {
    let d = scratch("bad_source");
    let cfg = config_with(
        &d,
        "port0.toml",
        &[("source =", "source = \"udp:127.0.0.1:0\"")],
    );
    let err = assert_refused(&check_config(&cfg), "port 0");
    assert!(
        err.contains("port0.toml") && err.contains("udp:127.0.0.1:0") && err.contains("port 0"),
        "{err}"
    );
    let cfg = config_with(&d, "prefix.toml", &[("prefix =", "prefix = \"../PSM1\"")]);
    let err = assert_refused(&check_config(&cfg), "../PSM1");
    assert!(
        err.contains("prefix.toml") && err.contains("`prefix`") && err.contains("../PSM1"),
        "{err}"
    );
}

#[test]
fn a_fifo_as_configuration_or_parameter_file_is_refused_without_hanging() {
    let d = scratch("bad_fifo");
    let fifo = d.join("fifo.toml");
    mkfifo(&fifo);
    let comp_cfg = config_with(
        &d,
        "sidecar.toml",
        &[(
            "compliance =",
            &format!("compliance = \"{}\"", fifo.display()),
        )],
    );
    let out = d.join("rows.csv");
    let check = |cfg: &Path| -> Vec<String> {
        ["check-config", "--config", cfg.to_str().unwrap()]
            .map(String::from)
            .to_vec()
    };
    // `calibrate record` reads the service's configuration for its prefix: it blocked on a
    // FIFO too (and read /dev/zero until memory ran out) before it used the bounded reader.
    let record: Vec<String> = [
        "calibrate",
        "record",
        "--config",
        fifo.to_str().unwrap(),
        "--joint",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    for (what, args) in [
        ("--config", check(&fifo)),
        ("compliance", check(&comp_cfg)),
        ("calibrate record --config", record),
    ] {
        let mut p = Proc::spawn(
            what,
            Command::new(sidecar_bin())
                .args(&args)
                .stdout(Stdio::null())
                .stderr(Stdio::piped()),
        );
        // Before the fix, the command blocked in open(2) for ever: the guard kills it (Proc's
        // drop) and fails the test instead of hanging the suite.
        let st = p
            .wait_timeout(Duration::from_secs(30))
            .unwrap_or_else(|| panic!("{what}: hangs on a FIFO"));
        let err = p.stderr_text();
        assert_eq!(st.code(), Some(1), "{what}: {st:?} {err}");
        assert!(
            err.contains("fifo.toml") && err.contains("named pipe"),
            "{what}: {err}"
        );
    }
    assert!(!out.exists(), "calibrate record wrote {}", out.display());
}

/// The issue's own command line on the simulator, `calibrate clamp --depths 5.0 --out
/// clamp.csv` over an existing recording (and `--depths nan`, `--settle-s -1`, a sweep step
/// given to the clamp or out of its range): refused before
/// anything is opened, the recording untouched; and `calibrate --out` onto a FIFO refused, the
/// FIFO left as it was. (The same checks through `--robot ros2:ARM` are in
/// tests/console_calibration.rs.)
#[test]
fn calibrate_on_the_simulator_refuses_bad_arguments_and_keeps_the_recording() {
    let d = scratch("bad_calibrate_sim");
    let out = d.join("clamp.csv");
    let earlier = "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n\
                   1,0,0.12,0.01,0.3,0.1,1\n";
    std::fs::write(&out, earlier).unwrap();
    let scenario = repo().join("config/sim/clamp.toml");
    for (procedure, arg, value, expect) in [
        ("clamp", "--depths", "5.0", "--depths 5"),
        ("clamp", "--depths", "nan", "--depths NaN"),
        ("clamp", "--settle-s", "-1", "--settle-s -1"),
        (
            "clamp",
            "--step-deg",
            "1",
            "--step-deg: only for calibrate torque-offset",
        ),
        (
            "torque-offset",
            "--step-deg",
            "0.1",
            "--step-deg 0.1: must be in [0.5, 10]",
        ),
        ("torque-offset", "--step-deg", "inf", "--step-deg inf"),
    ] {
        let o = Command::new(sidecar_bin())
            .args(["calibrate", procedure, "--config"])
            .arg(&scenario)
            .args(["--out", out.to_str().unwrap(), arg, value])
            .output()
            .unwrap();
        let err = stderr(&o);
        assert!(!o.status.success(), "{arg} {value} accepted: {err}");
        assert!(!err.contains("panicked"), "{arg} {value}: {err}");
        assert!(err.contains(expect), "{arg} {value}: {err}");
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            earlier,
            "{arg} {value}"
        );
    }
    let fifo = d.join("out.fifo");
    mkfifo(&fifo);
    let o = Command::new(sidecar_bin())
        .args(["calibrate", "clamp", "--config"])
        .arg(&scenario)
        .args(["--out", fifo.to_str().unwrap()])
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(!o.status.success(), "--out FIFO accepted: {err}");
    assert!(err.contains("out.fifo"), "{err}");
    assert!(
        std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo(),
        "the FIFO was replaced"
    );
}

/// `fit` of the 2017 clamp data of joint 1 with `file` given to `flag`, written beside `file`.
fn fit_with(flag: &str, file: &Path) -> Vec<String> {
    let clamp = repo().join("data/2017/dvrk2017-clamp-joint1.csv");
    let out = file.with_extension("toml");
    ["fit", "--joint", "1", "--clamp"]
        .map(String::from)
        .into_iter()
        .chain([
            clamp.display().to_string(),
            flag.to_owned(),
            file.display().to_string(),
            "--out".to_owned(),
            out.display().to_string(),
        ])
        .collect()
}

/// Numbers no arm can give, in the data files `evaluate` and `fit` read: each refused, naming
/// the file, the line, the column and the value (issue 22 item 4). A divot file whose true tip
/// was 1e308 m gave all-`null` statistics with exit 0 before the tip's bound.
#[test]
fn unphysical_numbers_in_data_files_are_refused_through_the_binary() {
    let d = scratch("bad_data_numbers");
    let params = repo().join("config/compliance/paper-psm.toml");
    let divot_header = "push_index,joint,direction,t_s,position_1_rad,position_2_rad,insertion_m,\
                        position_4_rad,position_5_rad,position_6_rad,effort_1_nm,effort_2_nm,\
                        effort_3_n,true_position_1_rad,true_position_2_rad,true_tip_x_m,\
                        true_tip_y_m,true_tip_z_m";
    let divot_row = |t: &str, tip_x: &str| {
        format!("0,1,1,{t},0.1,-0.2,0.12,0.0,0.1,-0.1,0.2,-0.9,1.0,0.1,-0.19,{tip_x},0.02,-0.12")
    };
    let dynamics_header = "t_s,q1_rad,q2_rad,q3_m,effort1_nm,effort2_nm";
    let mut cases: Vec<(String, Vec<String>, &str)> = Vec::new();
    for (name, row, want) in [
        (
            "divot-tip.csv",
            divot_row("0.5", "1e308"),
            "true_tip_x_m` = 1e308 m",
        ),
        (
            "divot-time.csv",
            divot_row("-1e300", "0.01"),
            "t_s` = -1e300 s",
        ),
    ] {
        let p = d.join(name);
        std::fs::write(&p, format!("{divot_header}\n{row}\n")).unwrap();
        let args = ["evaluate", "--params", params.to_str().unwrap(), "--data"]
            .map(String::from)
            .into_iter()
            .chain([p.display().to_string(), "--json".into()])
            .collect();
        cases.push((name.to_owned(), args, want));
    }
    for (name, row, want) in [
        (
            "dynamics-q1.csv",
            "0.001,1e308,0.1,0.12,0.1,0.2",
            "q1_rad = 1e308 rad",
        ),
        (
            "dynamics-q3.csv",
            "0.001,0.1,0.1,-2,0.1,0.2",
            "q3_m = -2.0 m",
        ),
        (
            "dynamics-effort.csv",
            "0.001,0.1,0.1,0.12,0.1,1e9",
            "effort2_nm = 1000000000.0 N·m",
        ),
    ] {
        let p = d.join(name);
        std::fs::write(&p, format!("{dynamics_header}\n{row}\n")).unwrap();
        cases.push((name.to_owned(), fit_with("--dynamics", &p), want));
    }
    // A torque-offset sweep at 1e308 rad, in the project's layout.
    let sweep = d.join("sweep.csv");
    std::fs::write(
        &sweep,
        "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n\
         1,0,0.12,1e308,0.1,0,1\n",
    )
    .unwrap();
    cases.push((
        "sweep.csv".into(),
        fit_with("--torque-offset", &sweep),
        "position_rad` = 1e308 rad",
    ));
    for (name, args, want) in cases {
        let o = Command::new(sidecar_bin()).args(&args).output().unwrap();
        let err = assert_refused(&o, &name);
        assert!(
            err.contains(&name) && err.contains("line 2") && err.contains(want),
            "{name}: {err}"
        );
        assert!(
            o.stdout.is_empty(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
    // A command rate that is not one, in the provenance line `fit` reads: named with its file.
    let rate = d.join("dynamics-rate.csv");
    std::fs::write(
        &rate,
        format!("# commanded_hz: fast\n{dynamics_header}\n0.001,0.1,0.1,0.12,0.1,0.2\n"),
    )
    .unwrap();
    let o = Command::new(sidecar_bin())
        .args(fit_with("--dynamics", &rate))
        .output()
        .unwrap();
    let err = assert_refused(&o, "dynamics-rate.csv");
    assert!(
        err.contains("dynamics-rate.csv") && err.contains("`# commanded_hz: fast`"),
        "{err}"
    );
}

#[test]
fn a_huge_invalid_line_is_quoted_within_bounds() {
    let d = scratch("bad_huge");
    // 20 MB would be refused by the size bound; 8 MB of one invalid line stays under it.
    let huge = format!("rate = \"{}\"", "f".repeat(8 << 20));
    let cfg = config_with(
        &d,
        "huge.toml",
        &[("prefix =", &format!("prefix = \"PSM1\"\n{huge}"))],
    );
    let err = assert_refused(&check_config(&cfg), "huge line");
    assert!(err.len() < 4096, "{} bytes on stderr", err.len());
    assert!(
        err.contains("huge.toml") && err.contains("line 7") && err.contains("characters cut"),
        "{}",
        &err[..err.len().min(2000)]
    );
    // A file over the 16 MiB bound is refused, saying the bound.
    let big = d.join("big.toml");
    std::fs::write(&big, vec![b'#'; 17 << 20]).unwrap();
    let err = assert_refused(&check_config(&big), "17 MiB");
    assert!(err.contains("big.toml") && err.contains("16 MiB"), "{err}");
}

#[test]
fn a_huge_number_is_echoed_in_scientific_notation() {
    // A command-line value...
    let c = repo().join("config");
    let o = Command::new(sidecar_bin())
        .arg("evaluate")
        .arg("--params")
        .arg(c.join("compliance/sim-psm.toml"))
        .arg("--scenario")
        .arg(c.join("sim/divot-push.toml"))
        .args(["--seconds", "1e308"])
        .output()
        .unwrap();
    let err = assert_refused(&o, "--seconds 1e308");
    assert!(
        err.contains("--seconds 1e308: must be in (0, 3600]"),
        "{err}"
    );
    assert!(err.len() < 200, "{} bytes on stderr: {err}", err.len());
    // ...and a configuration field: named, with its value as written, not as 301 digits.
    let d = scratch("bad_huge_number");
    let cfg = config_with(
        &d,
        "timeout.toml",
        &[("prefix =", "prefix = \"PSM1\"\nreply_timeout_ms = 1e300")],
    );
    let err = assert_refused(&check_config(&cfg), "reply_timeout_ms = 1e300");
    assert!(
        err.contains("timeout.toml") && err.contains("field `reply_timeout_ms` = 1e300:"),
        "{err}"
    );
    assert!(err.len() < 400, "{} bytes on stderr: {err}", err.len());
}

/// Runs the binary with stdout a pipe whose reading end is already closed (as after
/// `| head -1` has read its line).
fn with_closed_stdout(args: &[&str]) -> (std::process::ExitStatus, String) {
    let mut fds = [0; 2];
    // SAFETY: pipe(2) fills two new descriptors; each is owned exactly once below.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    // SAFETY: fresh descriptors from pipe(2), not owned elsewhere.
    let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    drop(read);
    let o = Command::new(sidecar_bin())
        .args(args)
        .current_dir(repo())
        .stdout(Stdio::from(write))
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    (o.status, stderr(&o))
}

#[test]
fn a_closed_stdout_pipe_ends_the_command_cleanly() {
    // Before the fix: "failed printing to stdout: Broken pipe", a panic (SIGABRT in release).
    for args in [
        &["fk", "0.1", "-0.1", "0.12", "0", "0", "0"][..],
        &["fk", "--json", "0.1", "-0.1", "0.12", "0", "0", "0"],
        &["check-config", "--config", "config/sidecar.toml"],
        &[
            "correct",
            "--params",
            "config/compliance/paper-psm.toml",
            "--position",
            "0.1,-0.1,0.12",
            "--effort",
            "0.5,0.5,0",
        ],
    ] {
        let (st, err) = with_closed_stdout(args);
        assert_eq!(st.code(), Some(0), "{args:?}: {st:?} {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

/// The issue's own example, `dvrk-sidecar echo PSM1/measured_js --json | head -1`: `echo` of a
/// live service whose reader has gone ends cleanly at its first write, text and JSON.
#[test]
fn echo_into_a_closed_pipe_ends_cleanly() {
    let prefix = unique_prefix("bad_echo_pipe");
    let cfg = write_config("bad_echo_pipe", "sim", "exclusive", &prefix, "idle.toml");
    let _serve = serve(&cfg);
    let service = format!("{prefix}/measured_js");
    // A liveness bound for the service's start, not a speed claim.
    assert_eq!(
        echo_json(&service, 1, Duration::from_secs(60)).len(),
        1,
        "serve publishes"
    );
    for json in [true, false] {
        let mut args = vec!["echo", service.as_str(), "--count", "100"];
        if json {
            args.push("--json");
        }
        let (st, err) = with_closed_stdout(&args);
        assert_eq!(st.code(), Some(0), "{args:?}: {st:?} {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn out_onto_a_device_or_a_fifo_is_refused_and_leaves_it_alone() {
    let d = scratch("bad_out");
    let fifo = d.join("out.fifo");
    mkfifo(&fifo);
    let mut outs = vec![fifo];
    // As root (where the issue replaced /dev/null), a device node of our own, a copy of
    // /dev/null (char 1:3): never the real one, so a binary without the fix cannot break the
    // machine it is tested on.
    // SAFETY: geteuid(2) has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        let dev = d.join("null-device");
        let c = std::ffi::CString::new(dev.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: mknod(2) with a valid NUL-terminated path, creating a character device.
        let made = unsafe { libc::mknod(c.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) };
        assert_eq!(made, 0, "mknod {}", dev.display());
        outs.push(dev);
    }
    let clamp = repo().join("../shared/data/dvrk2017-clamp-joint1.csv");
    for out in &outs {
        let o = Command::new(sidecar_bin())
            .args(["fit", "--joint", "1", "--clamp"])
            .arg(&clamp)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        let err = stderr(&o);
        // Refused while the arguments are parsed (clap's usage error, status 2), before any work.
        assert_eq!(
            o.status.code(),
            Some(2),
            "{}: {:?} {err}",
            out.display(),
            o.status
        );
        assert!(
            err.contains(&out.display().to_string()) && err.contains("not a regular file"),
            "{err}"
        );
        let ft = std::fs::symlink_metadata(out).unwrap().file_type();
        assert!(
            ft.is_char_device() || ft.is_fifo(),
            "{} replaced",
            out.display()
        );
    }
}

/// A consumer's `DVRK_SIDECAR_SHORT_SLICE` (issue 23's short time slice) that is neither 0 nor
/// 1: `echo` refuses it when it subscribes, naming the variable and the value, instead of
/// waiting without telling.
#[test]
fn a_bad_short_slice_setting_is_refused_by_name_and_value() {
    let out = Command::new(sidecar_bin())
        .args(["echo", "bad_slice/measured_js", "--count", "1"])
        .env("DVRK_SIDECAR_SHORT_SLICE", "off")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = assert_refused(&out, "DVRK_SIDECAR_SHORT_SLICE=off");
    assert!(
        err.contains("DVRK_SIDECAR_SHORT_SLICE=\"off\": expected 0 (no short time slice) or 1"),
        "{err}"
    );
}
