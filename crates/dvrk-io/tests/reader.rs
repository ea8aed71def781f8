//! ArmReader in both access modes, over the in-process test boards and over UDP.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::Duration;

use approx::assert_relative_eq;
use common::{Boards, Fault, InProcLink, PSM_CLASSIC_TOML, Responder};
use dvrk_io::port::{
    EthPort, FaultConfig, FaultInjector, PortError, RecordingLink, ReplayLink, UdpPort,
};
use dvrk_io::wire::Tcode;
use dvrk_io::wire::block::hardware_version;
use dvrk_io::{AccessMode, ArmReader, ArmSample, IoConfig, ReadError};

const K_YAW: f64 = 2.0 * std::f64::consts::PI / 14400.0 / 56.5;
const K_INS: f64 = 2.0 * std::f64::consts::PI / 14400.0 / 336.6;

fn cfg() -> IoConfig {
    common::io_from_toml(PSM_CLASSIC_TOML).unwrap()
}

/// Boards with actuator 1 at +1000 counts and 40000 current bits, insertion at 50000 counts.
fn posed(fw: u32) -> Boards {
    let mut b = Boards::psm(fw);
    b.board(6).set_axis(0, 1000, 40_000);
    b.board(6).set_axis(2, 50_000, 0x8000);
    b
}

fn check_posed(s: &ArmSample) {
    assert!(s.valid);
    assert_relative_eq!(s.position[0], -1000.0 * K_YAW, epsilon = 1e-12);
    assert_relative_eq!(s.position[2], 50_000.0 * K_INS, epsilon = 1e-12);
    assert_relative_eq!(
        s.effort[0],
        -1.379_394_531_25 * 56.5 * 0.0438,
        epsilon = 1e-9
    );
    assert_eq!(s.boards[0].board_id, 6);
    assert_eq!(s.boards[1].board_id, 7);
    assert!(
        s.boards
            .iter()
            .all(|b| b.read_ok && b.power_enabled && b.motor_supply_good && !b.watchdog_timeout)
    );
}

#[test]
fn shared_mode_over_udp_uses_only_quadlet_reads() {
    let r = Responder::spawn(posed(8));
    let mut port = UdpPort::open_udp(r.addr).unwrap();
    port.link_mut()
        .set_timeout(Duration::from_millis(200))
        .unwrap();
    // One request per quadlet, whatever the machine's load: the count below is exact.
    port.link_mut().set_quadlet_retry_wait(None);
    let mut reader = ArmReader::new(port, cfg(), AccessMode::Shared);
    let mut s = ArmSample::default();
    reader.read(1_000_000, &mut s).unwrap();
    check_posed(&s);
    assert_eq!(s.velocity, [0.0; 7]);
    assert_eq!(s.board_timestamp, [0, 0]);
    // Move actuator 1 by +100 counts; 1 ms later the velocity is the finite difference.
    r.with(|b| b.board(6).set_axis(0, 1100, 40_000));
    reader.read(2_000_000, &mut s).unwrap();
    assert_relative_eq!(s.velocity[0], -100.0 * K_YAW / 1e-3, max_relative = 1e-9);
    assert_eq!(s.velocity[1], 0.0);
    r.with(|b| {
        assert_eq!(
            b.log.len(),
            2 * 16,
            "2 status + 7 x (encoder, ADC) per cycle"
        );
        assert!(b.log.iter().all(|l| l.tcode == Tcode::QuadletRead));
        let addrs: Vec<u64> = b.log.iter().map(|l| l.addr).collect();
        assert!(
            addrs
                .iter()
                .all(|&a| a == 0 || (a & 0xF == 0 || a & 0xF == 5) && (0x10..=0x45).contains(&a))
        );
        assert_eq!(b.count(|l| l.addr == 0x15 && l.node == 6), 2);
    });
}

#[test]
fn exclusive_mode_one_block_read_per_board_per_cycle() {
    let mut boards = posed(8);
    let clk = 49.152e6;
    boards.board(6).edit(|b| {
        b.set_encoder_period(0, dvrk_io::wire::EncoderPeriod::from_velocity(-4000.0, clk))
            .unwrap()
    });
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(boards)),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    for cycle in 0..3u64 {
        reader.read(cycle * 1_000_000, &mut s).unwrap();
        check_posed(&s);
    }
    assert_relative_eq!(s.velocity[0], 4000.0 * K_YAW, max_relative = 1e-9);
    assert_eq!(s.board_timestamp, [49_151, 49_151]);
    assert!(
        s.axes
            .iter()
            .all(|a| a.amp_on && !a.amp_fault && !a.encoder_error && !a.encoder_overflow)
    );
    let log = &reader.port_mut().link_mut().boards.log;
    // First cycle learns hardware and firmware versions (2 quadlets per board), then only blocks.
    assert_eq!(
        log.iter().filter(|l| l.tcode == Tcode::QuadletRead).count(),
        4
    );
    assert_eq!(
        log.iter()
            .filter(|l| l.tcode == Tcode::BlockRead && l.addr == 0 && l.len == 128)
            .count(),
        6
    );
    assert_eq!(log.len(), 10);
    assert_eq!(reader.layouts()[0].unwrap().len_quadlets(), 32);
}

#[test]
fn exclusive_mode_rev7_reads_amp_state_from_status() {
    let mut boards = posed(7);
    let st = boards.board(7).status();
    boards.board(7).set_status(st & !(1 << 9)); // amp of axis 1 off
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(boards)),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    reader.read(5, &mut s).unwrap();
    check_posed(&s);
    assert!(!s.axes[5].amp_on && s.axes[4].amp_on);
    assert_eq!(reader.layouts()[1].unwrap().len_quadlets(), 28);
}

#[test]
fn exclusive_broadcast_query_needs_the_write_capability() {
    let mut port = EthPort::new(InProcLink::new(posed(9)));
    let mut reader =
        ArmReader::new(&mut port, cfg(), AccessMode::Exclusive).with_broadcast_query(true);
    let mut s = ArmSample::default();
    assert_eq!(
        reader.read(1, &mut s).unwrap_err(),
        ReadError::Port(PortError::QueryNotAllowed)
    );
    assert!(!s.valid && s.t_ns == 1);
    drop(reader);
    port.allow_writes().enable_broadcast_query();
    let mut reader =
        ArmReader::new(&mut port, cfg(), AccessMode::Exclusive).with_broadcast_query(true);
    reader.read(2, &mut s).unwrap();
    check_posed(&s);
    reader.read(3, &mut s).unwrap();
    drop(reader);
    let log = &port.link_mut().boards.log;
    let writes = log
        .iter()
        .filter(|l| l.tcode == Tcode::QuadletWrite && l.addr == 0x1800 && l.node == 0x3F)
        .count();
    let hub_reads = log
        .iter()
        .filter(|l| l.tcode == Tcode::BlockRead && l.addr == 0x1000)
        .count();
    assert_eq!((writes, hub_reads), (2, 2));
    assert_eq!(
        log.iter()
            .filter(|l| l.tcode == Tcode::BlockRead && l.addr == 0)
            .count(),
        0
    );
}

#[test]
fn a_silent_board_gives_invalid_sample_with_health() {
    let r = Responder::spawn(posed(8));
    let mut port = UdpPort::open_udp(r.addr).unwrap();
    port.link_mut()
        .set_timeout(Duration::from_millis(20))
        .unwrap();
    r.with(|b| b.boards.retain(|x| x.id != 7));
    for mode in [AccessMode::Shared, AccessMode::Exclusive] {
        let mut reader = ArmReader::new(&mut port, cfg(), mode);
        let mut s = ArmSample::default();
        let e = reader.read(77, &mut s).unwrap_err();
        assert!(
            matches!(e, ReadError::Port(PortError::Timeout { board: 7, .. })),
            "{mode:?}: {e:?}"
        );
        assert!(!s.valid);
        assert_eq!(s.t_ns, 77);
        assert!(s.boards[0].read_ok && !s.boards[1].read_ok);
        assert_eq!(s.boards[1].board_id, 7);
        assert_eq!(reader.counters().failed_reads, 1);
    }
}

#[test]
fn watchdog_and_faults_show_in_health_but_sample_stays_valid() {
    let mut boards = posed(8);
    let st = boards.board(6).status();
    boards.board(6).set_status(st | (1 << 23));
    boards.board(7).edit(|b| {
        b.set_motor_status(2, (1 << 29) | (1 << 17) | (1 << 16))
            .unwrap();
        b.set_encoder_position(
            0,
            dvrk_io::wire::EncoderPosition::from_counts(0).with_overflow(true),
        )
        .unwrap();
        b.set_encoder_period(1, dvrk_io::wire::EncoderPeriod(1 << 28))
            .unwrap();
    });
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(boards)),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    reader.read(1, &mut s).unwrap();
    assert!(s.valid);
    assert!(s.boards[0].watchdog_timeout && !s.boards[1].watchdog_timeout);
    assert!(s.axes[6].amp_fault && s.axes[6].current_check_trip);
    assert!(s.axes[4].encoder_overflow && s.axes[5].encoder_error);
}

#[test]
fn wrong_hardware_or_firmware_is_a_typed_error() {
    let mut boards = posed(8);
    boards.board(7).hw = hardware_version::DQLA;
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(boards)),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    let e = reader.read(1, &mut s).unwrap_err();
    assert!(
        matches!(
            e,
            ReadError::Port(PortError::HardwareMismatch { board: 7, .. })
        ),
        "{e:?}"
    );
    assert!(!s.valid && s.boards[0].read_ok && !s.boards[1].read_ok);
    let mut boards = posed(8);
    boards.board(6).fw = 10;
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(boards)),
        cfg(),
        AccessMode::Exclusive,
    );
    assert_eq!(
        reader.read(1, &mut s).unwrap_err(),
        ReadError::Port(PortError::UnsupportedFirmware {
            board: 6,
            firmware: 10
        })
    );
}

#[test]
fn fault_injector_link_never_yields_wrong_valid_data() {
    // Drops, delays (late replies with old labels) and bus-generation changes: every sample the
    // reader calls valid must equal the truth; the others must carry an error.
    let cfgf = FaultConfig {
        seed: 7,
        drop_chance: 0.05,
        corrupt_chance: 0.0,
        delay_chance: 0.05,
        generation_change_chance: 0.02,
    };
    let link = FaultInjector::new(InProcLink::new(posed(8)), cfgf);
    for mode in [AccessMode::Shared, AccessMode::Exclusive] {
        let mut reader = ArmReader::new(
            EthPort::new(FaultInjector::new(InProcLink::new(posed(8)), cfgf)),
            cfg(),
            mode,
        );
        let (mut ok, mut bad) = (0, 0);
        let mut s = ArmSample::default();
        for i in 0..300u64 {
            match reader.read(i * 1_000_000, &mut s) {
                Ok(()) => {
                    check_posed(&s);
                    ok += 1;
                }
                Err(_) => {
                    assert!(!s.valid);
                    bad += 1;
                }
            }
        }
        let fc = reader.port_mut().link_mut().counters();
        assert!(
            fc.dropped > 0 && fc.delayed > 0 && fc.generation_changes > 0,
            "{fc:?}"
        );
        assert!(ok > 0 && bad > 0, "{mode:?}: ok {ok} bad {bad}");
        assert!(reader.port_mut().counters().generation_changes > 0);
    }
    drop(link);
}

#[test]
fn fault_injector_corruption_never_panics() {
    let cfgf = FaultConfig {
        seed: 11,
        corrupt_chance: 0.5,
        ..Default::default()
    };
    let mut reader = ArmReader::new(
        EthPort::new(FaultInjector::new(InProcLink::new(posed(8)), cfgf)),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    for i in 0..300 {
        let _ = reader.read(i, &mut s);
    }
    assert!(reader.port_mut().link_mut().counters().corrupted > 0);
    // Port-level corruption too.
    let port = FaultInjector::new(EthPort::new(InProcLink::new(posed(8))), cfgf);
    let mut reader = ArmReader::new(port, cfg(), AccessMode::Shared);
    for i in 0..100 {
        let _ = reader.read(i, &mut s);
    }
}

const FRAMES: &str = include_str!("../../../tests/data/io/psm1-qla-rev8-exclusive.frames");

#[test]
fn replay_of_recorded_frames() {
    let link = ReplayLink::from_text(FRAMES).unwrap();
    let n = link.len();
    let mut reader = ArmReader::new(EthPort::new(link), cfg(), AccessMode::Exclusive);
    let mut s = ArmSample::default();
    for i in 0..3 {
        reader.read(i, &mut s).unwrap();
        check_posed(&s);
    }
    assert_eq!(reader.port_mut().link().position(), n);
    assert_eq!(
        reader.read(9, &mut s).unwrap_err(),
        ReadError::Port(PortError::ReplayExhausted { frames: n as u32 })
    );
    // A reader asking something else than what was recorded is told so.
    let mut reader = ArmReader::new(
        EthPort::new(ReplayLink::from_text(FRAMES).unwrap()),
        cfg(),
        AccessMode::Shared,
    );
    assert_eq!(
        reader.read(0, &mut s).unwrap_err(),
        ReadError::Port(PortError::ReplayMismatch { index: 0 })
    );
}

/// Regenerates tests/data/io/psm1-qla-rev8-exclusive.frames from the test boards.
#[test]
#[ignore = "writes the recorded-frames fixture"]
fn regenerate_replay_frames() {
    let mut reader = ArmReader::new(
        EthPort::new(RecordingLink::new(InProcLink::new(posed(8)))),
        cfg(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    for i in 0..3 {
        reader.read(i, &mut s).unwrap();
    }
    let text = format!(
        "# Three exclusive-mode cycles of ArmReader on PSM1 (QLA1 boards 6 and 7, Rev 8), recorded with\n\
         # RecordingLink from the test boards in crates/dvrk-io/tests/common (synthetic: no hardware).\n\
         # Actuator 1 at +1000 counts and 40000 current bits, insertion at +50000 counts.\n{}",
        reader.port_mut().link().to_text()
    );
    std::fs::write(
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/data/io/psm1-qla-rev8-exclusive.frames"
        ),
        text,
    )
    .unwrap();
}

#[test]
fn udp_fault_replies_in_shared_mode_are_errors_not_data() {
    let r = Responder::spawn(posed(8));
    let mut port = UdpPort::open_udp(r.addr).unwrap();
    port.link_mut()
        .set_timeout(Duration::from_millis(20))
        .unwrap();
    let mut reader = ArmReader::new(port, cfg(), AccessMode::Shared);
    let mut s = ArmSample::default();
    for f in [
        Fault::WrongSource,
        Fault::Dropped8,
        Fault::Truncate,
        Fault::BusReset,
    ] {
        r.set_fault(f);
        assert!(reader.read(1, &mut s).is_err(), "{f:?}");
        assert!(!s.valid);
    }
    r.set_fault(Fault::None);
    reader.read(2, &mut s).unwrap();
    check_posed(&s);
}

#[test]
fn exclusive_software_velocity_uses_the_board_sample_interval() {
    // Actuator 1 with velocity_source = software: velocity = change of position over the board
    // timestamp interval ((49151 + 1) ticks at 49.152 MHz = 1 ms), reference 5.1.
    let text = PSM_CLASSIC_TOML.replacen(
        "velocity_source = \"firmware\"",
        "velocity_source = \"software\"",
        1,
    );
    let cfg = common::io_from_toml(&text).unwrap();
    let mut reader = ArmReader::new(
        EthPort::new(InProcLink::new(posed(8))),
        cfg,
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    reader.read(0, &mut s).unwrap();
    reader
        .port_mut()
        .link_mut()
        .boards
        .board(6)
        .set_axis(0, 1010, 40_000);
    reader.read(123, &mut s).unwrap();
    assert_relative_eq!(s.velocity[0], -10.0 * K_YAW / 1e-3, max_relative = 1e-9);
    assert_relative_eq!(
        reader.last_actuators().velocity[0],
        10.0 * -K_YAW / 1e-3,
        max_relative = 1e-9
    );
}

const SAW_JSON: &str = include_str!("../../../tests/data/io/sawRobotIO1394-PSM1-00000.json");
/// Pot bits per actuator, all different.
const POT_BITS: [u16; 7] = [11_000, 22_000, 33_000, 44_000, 5_000, 15_000, 25_000];

/// Rev 9 boards whose ADC quadlets carry [`POT_BITS`] (bits 31-16) beside mid-range currents.
fn boards_with_pots(io: &IoConfig) -> Boards {
    let mut b = posed(9);
    for (i, a) in io.actuators().iter().enumerate() {
        b.board(a.board_id).edit(|blk| {
            let current = blk.adc(a.axis as usize).unwrap().current_bits();
            blk.set_adc(
                a.axis as usize,
                dvrk_io::wire::Adc::new(POT_BITS[i], current),
            )
            .unwrap()
        });
    }
    b
}

fn check_pots(io: &IoConfig, s: &ArmSample, pots: Option<&[f64; 7]>) {
    assert!(s.valid);
    // The encoders and currents of the same reads are what they were without pots.
    assert_relative_eq!(s.position[0], -1000.0 * K_YAW, max_relative = 1e-6);
    assert_relative_eq!(s.position[2], 50_000.0 * K_INS, max_relative = 1e-6);
    assert_relative_eq!(
        s.effort[0],
        -1.379_394_531_25 * 56.5 * 0.0438,
        max_relative = 1e-5
    );
    let pots = pots.expect("the io file calibrates the pots");
    for (i, a) in io.actuators().iter().enumerate() {
        let want = a.pot_bits_to_position(POT_BITS[i]).unwrap();
        assert_eq!(pots[i], want, "actuator {}", i + 1);
    }
    // Actuator 1 by hand: V = bits * 4.5/65536, position = V * -1.54737778 + 3.5 (the JSON's).
    assert_relative_eq!(
        pots[0],
        11_000.0 * 4.5 / 65536.0 * -1.547_377_78 + 3.5,
        epsilon = 1e-12
    );
}

#[test]
fn pots_are_read_in_shared_exclusive_and_hub_modes() {
    let io = common::io_from_saw_json(SAW_JSON).unwrap();
    let mut s = ArmSample::default();
    // Shared: the ADC quadlet (ch<<4 | 0) it reads anyway, no extra request.
    let mut shared = ArmReader::new(
        EthPort::new(InProcLink::new(boards_with_pots(&io))),
        io.clone(),
        AccessMode::Shared,
    );
    shared.read(1, &mut s).unwrap();
    check_pots(&io, &s, shared.pots());
    // The difference the pot/encoder check looks at, from the same read.
    let d = shared.pot_minus_encoder().unwrap();
    let last = shared.last_actuators();
    for (i, d) in d.iter().enumerate() {
        assert_eq!(*d, last.pot_position[i] - last.position[i]);
    }
    assert_relative_eq!(
        shared.pot_minus_encoder().unwrap()[0],
        11_000.0 * 4.5 / 65536.0 * -1.547_377_78 + 3.5 + 1000.0 * K_YAW,
        epsilon = 1e-9
    );
    assert_eq!(
        shared.port_mut().link_mut().boards.log.len(),
        16,
        "2 status + 7 x (encoder, ADC)"
    );
    // Exclusive: the feedback block.
    let mut exclusive = ArmReader::new(
        EthPort::new(InProcLink::new(boards_with_pots(&io))),
        io.clone(),
        AccessMode::Exclusive,
    );
    exclusive.read(1, &mut s).unwrap();
    check_pots(&io, &s, exclusive.pots());
    // Broadcast query + hub read.
    let mut port = EthPort::new(InProcLink::new(boards_with_pots(&io)));
    port.allow_writes().enable_broadcast_query();
    let mut hub =
        ArmReader::new(&mut port, io.clone(), AccessMode::Exclusive).with_broadcast_query(true);
    hub.read(1, &mut s).unwrap();
    check_pots(&io, &s, hub.pots());
    assert_eq!(hub.counters().hub_reads, 1);
    // An io file without pot calibration: no pots.
    let mut none = ArmReader::new(
        EthPort::new(InProcLink::new(boards_with_pots(&io))),
        cfg(),
        AccessMode::Exclusive,
    );
    none.read(1, &mut s).unwrap();
    assert!(none.pots().is_none() && none.pot_minus_encoder().is_none());
    assert!(
        none.last_actuators()
            .pot_position
            .iter()
            .all(|p| p.is_nan())
    );
}
