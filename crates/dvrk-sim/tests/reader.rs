//! The simulator as dvrk-io's `ArmReader` sees it: over real UDP loopback (discovery with the
//! dVRK's sequence, then reads), and in-process in shared and exclusive access modes.

mod common;

use std::net::{Ipv4Addr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use common::*;
use dvrk_io::port::{EthMode, UdpLink, UdpPort};
use dvrk_io::reader::{AccessMode, ArmReader};
use dvrk_io::{ArmSample, EthPort, Port};
use dvrk_sim::server::serve_udp;
use dvrk_sim::{Emulator, sim_port};

#[test]
fn udp_port_discovers_boards_6_and_7_over_loopback() {
    let socket = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).unwrap();
    let addr = socket.local_addr().unwrap();
    let emu = Emulator::new(&scenario("idle.toml"), &io_config()).unwrap();
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let server = s.spawn(|| serve_udp(socket, emu, &stop));
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut link = UdpLink::connect(addr).unwrap();
            link.set_timeout(Duration::from_millis(50)).unwrap();
            let mut port: UdpPort = EthPort::new(link);
            let d = port
                .allow_writes()
                .init_nodes(Ipv4Addr::LOCALHOST, Duration::ZERO)
                .unwrap();
            assert_eq!(d.mode, Some(EthMode::Bridge));
            assert_eq!(d.hub, Some(6));
            d.check(&[6, 7]).unwrap();
            assert_eq!(
                (0..16u8)
                    .filter(|b| d.found(*b).is_some())
                    .collect::<Vec<_>>(),
                vec![6, 7]
            );
            // Then the reader works over the same socket (shared mode: quadlet reads only).
            let mut reader = ArmReader::new(port, io_config(), AccessMode::Shared);
            let mut sample = ArmSample::default();
            reader.read(1, &mut sample).unwrap();
            reader.read(2, &mut sample).unwrap();
            assert!(sample.valid);
            assert!((sample.position[2] - 0.12).abs() < 1e-4, "{sample:?}");
        }));
        stop.store(true, Ordering::Relaxed);
        let (emu, summary) = server.join().unwrap().unwrap();
        if let Err(p) = result {
            std::panic::resume_unwind(p);
        }
        assert!(
            summary.datagrams_in > 16 && summary.datagrams_out > 10,
            "{summary:?}"
        );
        // Discovery writes: IP and PHY request (broadcast, counted once each).
        assert_eq!(emu.counters().writes, 2);
        assert_eq!(emu.counters().block_reads_address0, 0);
    });
}

#[test]
fn shared_mode_never_writes_and_never_samples() {
    let io = io_config();
    let mut port = sim_port(&scenario("free-motion.toml"), &io).unwrap();
    port.link_mut().advance_to(0);
    let mut reader = ArmReader::new(port, io, AccessMode::Shared);
    let mut sample = ArmSample::default();
    let mut t = 0;
    for _ in 0..300 {
        t += NS_PER_MS;
        reader.port_mut().link_mut().advance_to(t);
        reader.read(t, &mut sample).unwrap();
        assert!(sample.valid);
        let truth = reader.port_mut().link().emulator().psm().joint_state();
        for j in 0..7 {
            assert!(
                (sample.position[j] - truth.position[j]).abs() < 2e-4,
                "joint {j}: {sample:?} {truth:?}"
            );
        }
    }
    let c = reader.port_mut().link().emulator().counters();
    assert_eq!(c.writes, 0);
    assert_eq!(c.block_reads_address0, 0);
    assert_eq!(c.samples, 0);
    assert!(c.quadlet_reads > 300);
}

#[test]
fn exclusive_mode_samples_once_per_board_per_cycle_and_reports_physics() {
    let io = io_config();
    let mut port = sim_port(&scenario("free-motion.toml"), &io).unwrap();
    port.link_mut().advance_to(0);
    let mut reader = ArmReader::new(port, io.clone(), AccessMode::Exclusive);
    let mut sample = ArmSample::default();
    let mut t = 0;
    for _ in 0..200 {
        t += NS_PER_MS;
        reader.port_mut().link_mut().advance_to(t);
        reader.read(t, &mut sample).unwrap();
        assert!(sample.valid);
        let js = reader.port_mut().link().emulator().psm().joint_state();
        for j in 0..7 {
            // Encoders: within half a count (wrist joints: coupled counts of 1.34e-4 rad).
            assert!(
                (sample.position[j] - js.position[j]).abs() < 2e-4,
                "joint {j}"
            );
        }
        for j in 0..3 {
            // Efforts: within an ADC bit plus the current noise of the scenario (2 mA, 5 sigma).
            let tol = 5.0 * 0.002 / io.actuators()[j].effort_to_current.scale + 2e-3;
            assert!(
                (sample.effort[j] - js.effort[j]).abs() < tol,
                "joint {j}: {} vs {}",
                sample.effort[j],
                js.effort[j]
            );
        }
        // One ms between samples at 49.152 MHz.
        assert_eq!(sample.board_timestamp[0], 49_152 - 1);
    }
    let c = reader.port_mut().link().emulator().counters();
    assert_eq!(c.block_reads_address0, 400);
    assert_eq!(c.writes, 0);
}

#[test]
fn exclusive_mode_with_broadcast_query() {
    let io = io_config();
    let mut port = sim_port(&scenario("idle.toml"), &io).unwrap();
    port.link_mut().advance_to(0);
    port.allow_writes().enable_broadcast_query();
    let mut reader = ArmReader::new(port, io, AccessMode::Exclusive).with_broadcast_query(true);
    let mut sample = ArmSample::default();
    for k in 1..=50u64 {
        reader.port_mut().link_mut().advance_to(k * NS_PER_MS);
        reader.read(k * NS_PER_MS, &mut sample).unwrap();
        assert!(sample.valid);
    }
    let c = reader.port_mut().link().emulator().counters();
    assert_eq!(
        (c.broadcast_queries, c.writes, c.hub_reads, c.samples),
        (50, 50, 50, 100)
    );
    assert_eq!(c.block_reads_address0, 0);
    let _ = reader.port_mut().read_quadlet(6, 0).unwrap();
}
