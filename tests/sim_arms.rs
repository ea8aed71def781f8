//! Several arms on one emulated chain of boards (issue 21 item 2), end to end through the real
//! binary on loopback: `sim --arms PSM1,PSM2` answers for boards 6-9; dvrk-io's reader reads
//! each arm with its renumbered io file in shared and exclusive modes and finds each arm's own
//! pose; the console stand-in (`drive --arms`) runs the I/O of both arms in every protocol and
//! both Ethernet modes; bad arguments are refused with the value and what is accepted.

mod common;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use common::{emulator_with, free_udp_port, repo, scratch, sidecar_bin};
use dvrk_io::{AccessMode, ArmReader, ArmSample, IoConfig, UdpPort};
use dvrk_sidecar::config::{load_io, renumber_boards};

/// PSM1 holds the idle pose of config/sim/idle.toml; PSM2 holds this one (its own scenario).
const IDLE: [f64; 7] = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0, 0.2];
const PSM2_POSE: [f64; 7] = [0.3, -0.25, 0.15, 0.5, 0.1, -0.1, 0.4];

/// A scenario holding `PSM2_POSE`, written for one test.
fn psm2_scenario(test: &str) -> PathBuf {
    let path = scratch(test).join("psm2-hold.toml");
    let text = format!(
        r#"description = "PSM2 holding another pose"
seed = 2
dt_s = 0.0001
initial_position = {PSM2_POSE:?}
[environment]
kind = "free"
[motion]
kind = "hold"
[noise]
current_noise_amps = 0.002
pot_noise_volts = 0.001
"#
    );
    std::fs::write(&path, text).unwrap();
    path
}

/// config/io/psm-classic.toml on `boards`.
fn io_on(boards: [u8; 2]) -> IoConfig {
    let io = load_io(&repo().join("config/io/psm-classic.toml")).unwrap();
    renumber_boards(io, &boards).unwrap()
}

/// `sim --arms PSM1,PSM2` with idle PSM1 and PSM2 holding `PSM2_POSE`.
fn two_arms(test: &str, ip: &str, port: u16, ethernet: &str) -> common::Proc {
    let own = format!("PSM2={}", psm2_scenario(test).display());
    emulator_with(
        ip,
        port,
        &[
            "--arms",
            "PSM1,PSM2",
            "--scenario",
            "config/sim/idle.toml",
            "--arm-scenario",
            &own,
            "--io",
            "config/io/psm-classic.toml",
            "--ethernet",
            ethernet,
        ],
    )
}

/// Joint tolerance of a held pose: the controller's error under gravity and the quantization.
const HOLD_TOL: [f64; 7] = [2e-3, 2e-3, 5e-4, 2e-3, 2e-3, 2e-3, 2e-3];

fn assert_holds(what: &str, s: &ArmSample, pose: &[f64; 7]) {
    assert!(s.valid, "{what}: invalid sample {s:?}");
    for j in 0..7 {
        assert!(
            (s.position[j] - pose[j]).abs() <= HOLD_TOL[j],
            "{what}: joint {} at {} instead of {} (all: {:?})",
            j + 1,
            s.position[j],
            pose[j],
            s.position
        );
    }
}

/// Five reads of one arm; the last sample.
fn read_arm(port: UdpPort, io: IoConfig, mode: AccessMode, broadcast: bool) -> ArmSample {
    let mut reader = ArmReader::new(port, io, mode).with_broadcast_query(broadcast);
    let start = Instant::now();
    let mut s = ArmSample::default();
    for _ in 0..5 {
        let t_ns = start.elapsed().as_nanos() as u64 + 1;
        reader.read(t_ns, &mut s).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    s
}

fn udp_port(port: u16, exclusive: bool) -> UdpPort {
    let addr: SocketAddr = ([127, 0, 0, 1], port).into();
    let mut p = UdpPort::open_udp(addr).unwrap();
    // A liveness bound for a loaded machine, not a speed claim.
    p.link_mut().set_timeout(Duration::from_secs(2)).unwrap();
    if exclusive {
        p.allow_writes().enable_broadcast_query();
    }
    p
}

#[test]
fn the_reader_finds_each_arm_on_its_own_boards_in_shared_and_exclusive_modes() {
    let test = "sim_arms_reader";
    for ethernet in ["bridge", "ethernet-only"] {
        let port = free_udp_port();
        let mut sim = two_arms(test, "127.0.0.1", port, ethernet);
        let arms = [("PSM1", [6u8, 7], IDLE), ("PSM2", [8, 9], PSM2_POSE)];
        for (name, boards, pose) in arms {
            for (mode, broadcast) in [
                (AccessMode::Shared, false),
                (AccessMode::Exclusive, false),
                (AccessMode::Exclusive, true),
            ] {
                let what = format!("{ethernet} {name} {mode:?} broadcast={broadcast}");
                let s = read_arm(
                    udp_port(port, mode == AccessMode::Exclusive),
                    io_on(boards),
                    mode,
                    broadcast,
                );
                assert_holds(&what, &s, &pose);
                assert_eq!(
                    [s.boards[0].board_id, s.boards[1].board_id],
                    boards,
                    "{what}"
                );
                assert!(s.boards[..2].iter().all(|b| b.read_ok), "{what}");
                if mode == AccessMode::Exclusive {
                    // Block reads and hub data carry the board timestamps.
                    assert!(s.board_timestamp[..2].iter().all(|&t| t > 0), "{what}");
                }
            }
        }
        let (_, log) = sim.terminate();
        assert!(
            log.contains(
                "emulating 4 boards of 2 Classic PSMs as one chain: PSM1 on boards 6 and 7, \
                 PSM2 on boards 8 and 9"
            ),
            "{log}"
        );
        assert!(log.contains("arms=PSM1,PSM2"), "{log}");
    }
}

/// `drive` output's `key=value`.
fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let pat = format!("{key}=");
    let start = text.find(&pat)? + pat.len();
    text[start..].split_whitespace().next()
}

/// Runs `drive --arms ARMS` for `secs` against 127.0.0.1:`port`; (stdout, record).
fn drive(port: u16, arms: &str, protocol: &str, secs: f64, record: &PathBuf) -> (String, String) {
    let out = Command::new(sidecar_bin())
        .args([
            "drive",
            "--boards",
            &format!("127.0.0.1:{port}"),
            "--arms",
            arms,
            "--protocol",
            protocol,
            "--duration",
            &secs.to_string(),
            "--record",
        ])
        .arg(record)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "drive --arms {arms} --protocol {protocol} failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (stdout, std::fs::read_to_string(record).unwrap())
}

#[test]
fn drive_runs_the_console_io_of_both_arms_in_every_protocol() {
    let test = "sim_arms_drive";
    let psm1 = io_on([6, 7]);
    let psm2 = io_on([8, 9]);
    for (ethernet, protocol) in [
        ("bridge", "sequential-read-write"),
        ("bridge", "broadcast-query-read-write"),
        ("ethernet-only", "sequential-read-broadcast-write"),
        ("ethernet-only", "broadcast-query-read-write"),
    ] {
        let what = format!("{ethernet} {protocol}");
        let port = free_udp_port();
        // 0.0.0.0: in Ethernet-only mode the stand-in unicasts to 127.0.0.(1 + board id).
        let mut sim = two_arms(test, "0.0.0.0", port, ethernet);
        let record = scratch(test).join("drive.csv");
        let (out, rec) = drive(port, "PSM1,PSM2", protocol, 0.5, &record);
        let (_, sim_log) = sim.terminate();
        assert!(out.contains("boards=[6, 7, 8, 9] hub=6"), "{what}: {out}");
        assert_eq!(
            field(&out, "mode"),
            Some(ethernet),
            "{what}: discovery found the other mode: {out}"
        );
        // Only the stand-in talked to the boards.
        let local_port = field(&out, "local_port").unwrap();
        let peers = log_field(&sim_log, "requests_by_peer");
        assert!(
            peers.starts_with(&format!("127.0.0.1:{local_port}/")) && !peers.contains(','),
            "{what}: {peers}"
        );
        // The record has every board; each arm's boards carry its own pose.
        let mut lines = rec.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        assert_eq!(header.len(), 4 + 4 + 16, "{what}: {header:?}");
        assert_eq!(&header[4..8], ["ts0", "ts1", "ts2", "ts3"]);
        let rows: Vec<Vec<i64>> = lines
            .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
            .collect();
        let ok: Vec<&Vec<i64>> = rows.iter().filter(|r| r[3] == 1).collect();
        assert!(
            ok.len() * 2 >= rows.len() && !ok.is_empty(),
            "{what}: {} of {} cycles read every board: {out}",
            ok.len(),
            rows.len()
        );
        let first = ok[0];
        assert!(first[4..8].iter().all(|&t| t > 0), "{what}: {first:?}");
        // Board slot b, axis a -> column 8 + 4b + a. Actuators 1-3 are joints 1-3.
        for (slot0, io, pose) in [(0usize, &psm1, IDLE), (2, &psm2, PSM2_POSE)] {
            for j in 0..3 {
                let a = &io.actuators()[j];
                let got = a.counts_to_position(first[8 + 4 * slot0 + j] as i32);
                assert!(
                    (got - pose[j]).abs() <= HOLD_TOL[j],
                    "{what}: board {} axis {j} at {got} instead of {}",
                    a.board_id,
                    pose[j]
                );
            }
        }
    }
}

/// `key=value` of the emulator's log (values may be quoted).
fn log_field(text: &str, key: &str) -> String {
    field(text, key)
        .unwrap_or_else(|| panic!("no {key} in {text}"))
        .trim_matches('"')
        .to_owned()
}

#[test]
fn three_arms_answer_on_boards_6_to_11() {
    let port = free_udp_port();
    let mut sim = emulator_with("0.0.0.0", port, &["--arms", "PSM1,PSM2,PSM3"]);
    let record = scratch("sim_arms_three").join("drive.csv");
    let (out, _) = drive(
        port,
        "PSM3,PSM1,PSM2",
        "sequential-read-broadcast-write",
        0.2,
        &record,
    );
    let (_, log) = sim.terminate();
    assert!(out.contains("boards=[6, 7, 8, 9, 10, 11] hub=6"), "{out}");
    assert!(log.contains("PSM3 on boards 10 and 11"), "{log}");
    // PSM3 through the reader as well.
    let port2 = free_udp_port();
    let mut sim = emulator_with("127.0.0.1", port2, &["--arms", "PSM3,PSM1"]);
    let s = read_arm(
        udp_port(port2, false),
        io_on([10, 11]),
        AccessMode::Shared,
        false,
    );
    assert_holds("PSM3", &s, &IDLE);
    sim.terminate();
}

/// `sidecar ARGS` must fail before binding anything, saying `want` on stderr.
fn refused(args: &[&str], want: &[&str]) {
    let out = Command::new(sidecar_bin())
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} was accepted: {err}");
    for w in want {
        assert!(err.contains(w), "{args:?}: {w:?} not in: {err}");
    }
}

#[test]
fn bad_arm_arguments_are_refused_with_what_is_accepted() {
    let listen = format!("127.0.0.1:{}", free_udp_port());
    let accepted = "PSM1 (boards 6-7), PSM2 (boards 8-9), PSM3 (boards 10-11)";
    refused(
        &["sim", "--listen", &listen, "--arms", "PSM1,ECM"],
        &["\"ECM\"", accepted],
    );
    refused(
        &["sim", "--listen", &listen, "--arms", "psm1"],
        &["\"psm1\"", accepted],
    );
    refused(
        &["sim", "--listen", &listen, "--arms", "PSM2,PSM1,PSM2"],
        &["PSM2 is listed twice"],
    );
    refused(
        &[
            "sim",
            "--listen",
            &listen,
            "--arms",
            "PSM1,PSM2",
            "--crtk",
            "PSM1",
        ],
        &["--crtk", "one arm"],
    );
    refused(
        &[
            "sim",
            "--listen",
            &listen,
            "--arms",
            "PSM1,PSM2",
            "--arm-scenario",
            "PSM3=config/sim/idle.toml",
        ],
        &["PSM3 is not an emulated arm"],
    );
    refused(
        &[
            "sim",
            "--listen",
            &listen,
            "--arm-scenario",
            "PSM1=config/sim/idle.toml",
            "--arm-scenario",
            "PSM1=config/sim/free-motion.toml",
        ],
        &["PSM1 has a scenario already"],
    );
    refused(
        &["sim", "--listen", &listen, "--arm-scenario", "PSM1"],
        &["expected ARM=FILE"],
    );
    refused(
        &["drive", "--boards", &listen, "--arms", "MTML"],
        &["\"MTML\"", accepted],
    );
    // A console configured for PSM2 against a PSM1-only emulator names the missing boards.
    let port = free_udp_port();
    let mut sim = emulator_with("0.0.0.0", port, &[]);
    refused(
        &[
            "drive",
            "--boards",
            &format!("127.0.0.1:{port}"),
            "--arms",
            "PSM1,PSM2",
            "--duration",
            "0.1",
        ],
        &["[8, 9] did not answer"],
    );
    let (_, log) = sim.terminate();
    assert!(
        log.contains("emulating boards 6 and 7 of a Classic PSM1"),
        "{log}"
    );
}
