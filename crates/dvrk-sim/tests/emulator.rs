//! Emulator conformance: every reply decodes with dvrk-io and equals the physics state converted
//! through config/io/psm-classic.toml; discovery (reference §3.3, §9); timestamps; counters;
//! malformed input.

mod common;

use common::*;
use dvrk_io::port::{EthMode, reg};
use dvrk_io::wire::block::{SYSCLK_HZ, hardware_version};
use dvrk_io::wire::eth::extra_flags;
use dvrk_io::wire::hub::HUB_ADDRESS;
use dvrk_io::wire::{
    Adc, BlockLayout, BoardKind, BoardStatus, ControlWord, EncoderPeriod, EncoderPosition,
    EthReply, EthRequest, FeedbackBlock, HubLayout, HubView, MotorStatus, RequestKind, RequestRepr,
    ResponseKind, ResponseRepr,
};
use dvrk_io::{IoConfig, Port};
use dvrk_sim::emulator::{BUS_GENERATION, MAX_REPLY_BYTES};
use dvrk_sim::{Emulator, Scenario, SimPort, sim_port};

fn hold_scenario() -> &'static Scenario {
    static SC: std::sync::OnceLock<Scenario> = std::sync::OnceLock::new();
    SC.get_or_init(hold)
}

/// A scenario with no measurement noise, so replies can be compared bit for bit.
fn quiet(env: &str, motion: &str) -> Scenario {
    scenario_from_toml(&format!(
        r#"
seed = 11
dt_s = 0.0001
initial_position = [0.1, -0.2, 0.12, 0.3, 0.2, -0.1, 0.4]
[environment]
{env}
[motion]
{motion}
[noise]
current_noise_amps = 0.0
pot_noise_volts = 0.0
"#
    ))
}

fn free_motion() -> Scenario {
    quiet(
        "kind = \"free\"",
        "kind = \"trajectory\"\namplitude = [0.3, 0.2, 0.03, 0.5, 0.4, 0.4, 0.3]\nperiod_s = [3.0, 4.0, 5.0, 2.0, 2.5, 3.5, 1.5]",
    )
}

fn hold() -> Scenario {
    quiet("kind = \"free\"", "kind = \"hold\"")
}

fn emulator(sc: &Scenario) -> Emulator {
    let mut emu = Emulator::new(sc, &io_config()).unwrap();
    emu.advance_to(1_000 * NS_PER_MS);
    emu
}

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// Request datagram as the host builds it.
fn request(
    node: u8,
    label: u8,
    addr: u16,
    kind: RequestKind,
    noforward: bool,
    payload: &[u8],
) -> Vec<u8> {
    let mut buf = vec![0u8; 2100];
    let req = RequestRepr::host(node, label, u64::from(addr), kind);
    let n = EthRequest::emit(
        &mut buf,
        ControlWord::new(noforward, BUS_GENERATION),
        &req,
        payload,
    )
    .unwrap();
    buf.truncate(n);
    buf
}

fn quadlet_reply(emu: &mut Emulator, node: u8, addr: u16) -> (ResponseRepr, u32) {
    let mut out = [0u8; MAX_REPLY_BYTES];
    let n = emu
        .handle(
            &request(node, 5, addr, RequestKind::QuadletRead, true, &[]),
            &mut out,
        )
        .unwrap();
    let r = EthReply::parse(&out[..n]).unwrap();
    assert_eq!(r.excess, 0);
    let resp = ResponseRepr::parse(&r.packet.unwrap()).unwrap();
    let ResponseKind::Quadlet { data } = resp.kind else {
        panic!("{resp:?}")
    };
    (resp, data)
}

#[test]
fn answers_the_discovery_bytes_of_reference_section_9() {
    let mut emu = emulator(&hold());
    let mut out = [0u8; MAX_REPLY_BYTES];
    // Datagram 1: broadcast-node quadlet write of register 11 (IP), NOFORWARD. No reply.
    let d1 = hex("0100 ffff0400 ffd00000 0000000b 0100007f 11c036d8");
    assert_eq!(emu.handle(&d1, &mut out), None);
    assert_eq!(emu.counters().writes, 1);
    for node in [6, 7] {
        assert_eq!(
            quadlet_reply(&mut emu, node, reg::IP_ADDRESS).1,
            0x0100_007F
        );
    }
    // Datagram 2: broadcast + NOFORWARD read of register 4, answered by the hub board.
    let d2 = hex("0100 ffff0840 ffd00000 00000004 58ffb182");
    let n = emu.handle(&d2, &mut out).expect("the hub board answers");
    let reply = EthReply::parse(&out[..n]).unwrap();
    let resp = ResponseRepr::parse(&reply.packet.unwrap()).unwrap();
    assert_eq!(
        resp.kind,
        ResponseKind::Quadlet {
            data: hardware_version::QLA1
        }
    );
    assert_eq!(resp.label, 2);
    assert_eq!(resp.dest_id, 0xFFD0);
    assert_eq!(resp.src_id, 0xFFC0 | 6);
    assert!(reply.extra.noforward() && !reply.extra.packet_dropped());
    assert_eq!(reply.extra.bus_generation, BUS_GENERATION);
    // PHY request write (broadcast, forwarded): accepted, no reply.
    let phy = request(
        0x3F,
        3,
        reg::PHY_REQUEST,
        RequestKind::QuadletWrite { data: 0 },
        false,
        &[],
    );
    assert_eq!(emu.handle(&phy, &mut out), None);
    // Node scan: exactly boards 6 and 7 answer, each with its own id in the status register.
    let mut found = Vec::new();
    for node in 0..16u8 {
        let req = request(
            node,
            node,
            reg::HARDWARE_VERSION,
            RequestKind::QuadletRead,
            false,
            &[],
        );
        if let Some(n) = emu.handle(&req, &mut out) {
            let reply = EthReply::parse(&out[..n]).unwrap();
            let resp = ResponseRepr::parse(&reply.packet.unwrap()).unwrap();
            assert_eq!(
                resp.kind,
                ResponseKind::Quadlet {
                    data: hardware_version::QLA1
                }
            );
            let (_, st) = quadlet_reply(&mut emu, node, reg::STATUS);
            assert_eq!(BoardStatus::new(st, BoardKind::Qla).board_id(), node);
            assert_eq!(quadlet_reply(&mut emu, node, reg::FIRMWARE_VERSION).1, 9);
            found.push(node);
        }
    }
    assert_eq!(found, vec![6, 7]);
    assert_eq!(emu.counters().writes, 2);
    assert_eq!(emu.counters().block_reads_address0, 0);
}

#[test]
fn write_ip_then_read_before_write_is_unassigned() {
    let mut emu = emulator(&hold());
    assert_eq!(quadlet_reply(&mut emu, 6, reg::IP_ADDRESS).1, 0xFFFF_FFFF);
}

#[test]
fn sim_port_discovers_boards_6_and_7_through_dvrk_io() {
    let mut port: SimPort = sim_port(&hold(), &io_config()).unwrap();
    port.link_mut().advance_to(0);
    let d = port
        .allow_writes()
        .init_nodes(std::net::Ipv4Addr::LOCALHOST, std::time::Duration::ZERO)
        .unwrap();
    assert_eq!(d.mode, Some(EthMode::Bridge));
    assert_eq!(d.hub, Some(6));
    for b in [6u8, 7] {
        let info = d
            .found(b)
            .unwrap_or_else(|| panic!("board {b}: {:?}", d.boards[b as usize]));
        assert_eq!(info.node, b);
        assert_eq!(info.firmware_version, 9);
        assert_eq!(info.hardware_version, hardware_version::QLA1);
    }
    d.check(&[6, 7]).unwrap();
    // Only these two boards exist.
    assert_eq!((0..16u8).filter(|b| d.found(*b).is_some()).count(), 2);
    // The read-only discovery (quadlet reads only) finds them too.
    let d = port.discover(&[6, 7]).unwrap();
    assert!(d.found(6).is_some() && d.found(7).is_some());
}

/// Decodes one board's feedback block and checks it against the physics converted through the
/// IO config: encoders within half a count, efforts within half an ADC bit.
fn check_block_against_physics(emu: &Emulator, io: &IoConfig, board: u8, block: &[u8]) {
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let blk = FeedbackBlock::new_checked(block, lay).unwrap();
    assert_eq!(blk.status().board_id(), board);
    assert!(blk.status().fully_powered());
    let js = emu.psm().joint_state();
    let act_pos = io.joint_to_actuator_position(&js.position);
    let act_eff = io.joint_to_actuator_effort(&js.effort);
    let act_vel = io.joint_to_actuator_position(&js.velocity);
    for (i, a) in io.actuators().iter().enumerate() {
        if a.board_id != board {
            continue;
        }
        let axis = a.axis as usize;
        let pos = blk.encoder_position(axis).unwrap();
        assert!(!pos.overflow());
        let decoded = a.counts_to_position(pos.counts());
        assert!(
            (decoded - act_pos[i]).abs() <= 0.5 * a.bits_to_position.scale.abs() + 1e-12,
            "actuator {}: {decoded} vs {}",
            i + 1,
            act_pos[i]
        );
        let adc: Adc = blk.adc(axis).unwrap();
        let effort = a.current_bits_to_effort(adc.current_bits());
        let bit = a.bits_to_current.scale.abs() / a.effort_to_current.scale;
        assert!(
            (effort - act_eff[i]).abs() <= 0.5 * bit + 1e-12,
            "actuator {}: {effort} vs {}",
            i + 1,
            act_eff[i]
        );
        let period: EncoderPeriod = blk.encoder_period(axis).unwrap();
        let v = period.velocity_counts_per_s(SYSCLK_HZ) * a.bits_to_position.scale;
        if !period.overflow() {
            assert!(
                (v - act_vel[i]).abs() <= 0.01 * act_vel[i].abs() + 1e-9,
                "actuator {}: {v} vs {}",
                i + 1,
                act_vel[i]
            );
        }
        let ms: MotorStatus = blk.motor_status(axis).unwrap();
        assert!(ms.amp_on());
    }
}

#[test]
fn feedback_blocks_equal_the_physics_through_the_io_config() {
    let io = io_config();
    let mut port = sim_port(&free_motion(), &io).unwrap();
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let mut block = vec![0u8; lay.len_bytes()];
    let mut t = 0;
    for _ in 0..40 {
        t += 37 * NS_PER_MS;
        port.link_mut().advance_to(t);
        for board in [6u8, 7] {
            port.read_block(board, 0, &mut block).unwrap();
            check_block_against_physics(port.link().emulator(), &io, board, &block);
        }
    }
    let c = port.link().emulator().counters();
    assert_eq!(c.block_reads_address0, 80);
    assert_eq!(c.samples, 80);
    assert_eq!(c.writes, 0);
}

#[test]
fn quadlet_registers_equal_the_block_fields() {
    let io = io_config();
    let mut port = sim_port(&free_motion(), &io).unwrap();
    port.link_mut().advance_to(0);
    port.link_mut().advance_to(1234 * NS_PER_MS);
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let mut block = vec![0u8; lay.len_bytes()];
    port.read_block(6, 0, &mut block).unwrap();
    let blk = FeedbackBlock::new_checked(&block[..], lay).unwrap();
    for axis in 0..4u16 {
        let ch = (axis + 1) << 4;
        let pos = port.read_quadlet(6, ch | 5).unwrap();
        assert_eq!(
            EncoderPosition(pos),
            blk.encoder_position(axis as usize).unwrap()
        );
        let adc = port.read_quadlet(6, ch).unwrap();
        assert_eq!(Adc(adc), blk.adc(axis as usize).unwrap());
        assert_eq!(
            port.read_quadlet(6, ch | 6).unwrap(),
            blk.encoder_period(axis as usize).unwrap().0
        );
        assert_eq!(
            port.read_quadlet(6, ch | 12).unwrap(),
            blk.motor_status(axis as usize).unwrap().raw
        );
    }
    assert_eq!(port.read_quadlet(6, reg::STATUS).unwrap(), blk.status().raw);
    assert_eq!(port.read_quadlet(7, reg::ETHERNET_STATUS).unwrap() >> 31, 1);
    // Quadlet reads take no sample.
    assert_eq!(port.link().emulator().counters().block_reads_address0, 1);
    assert_eq!(port.link().emulator().counters().samples, 1);
}

#[test]
fn block_read_resets_the_timestamp_and_quadlet_reads_do_not() {
    let io = io_config();
    let mut port = sim_port(&hold(), &io).unwrap();
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let mut block = vec![0u8; lay.len_bytes()];
    let stamp = |b: &[u8]| {
        FeedbackBlock::new_checked(b, lay)
            .unwrap()
            .timestamp()
            .elapsed_ticks()
    };
    let t0 = 5_000 * NS_PER_MS;
    port.link_mut().advance_to(t0);
    port.link_mut().advance_to(t0 + 2 * NS_PER_MS);
    port.read_block(6, 0, &mut block).unwrap();
    assert_eq!(stamp(&block), 98_304); // 2 ms at 49.152 MHz since the epoch
    // Quadlet reads in between do not reset it.
    port.link_mut().advance_to(t0 + 3 * NS_PER_MS);
    for _ in 0..5 {
        port.read_quadlet(6, 0x15).unwrap();
        port.read_quadlet(6, reg::STATUS).unwrap();
    }
    port.link_mut().advance_to(t0 + 4 * NS_PER_MS);
    port.read_block(6, 0, &mut block).unwrap();
    assert_eq!(stamp(&block), 98_304);
    // Immediately again: one tick.
    port.read_block(6, 0, &mut block).unwrap();
    assert_eq!(stamp(&block), 1);
    // Board 7 keeps its own timestamp: 4 ms since the epoch.
    port.read_block(7, 0, &mut block).unwrap();
    assert_eq!(stamp(&block), 196_608);
    assert_eq!(port.link().emulator().counters().block_reads_address0, 4);
}

#[test]
fn broadcast_query_fills_hub_memory_and_counts_as_a_write() {
    let io = io_config();
    let mut port = sim_port(&free_motion(), &io).unwrap();
    port.link_mut().advance_to(0);
    port.link_mut().advance_to(500 * NS_PER_MS);
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let hub_lay = HubLayout::new(&[(6, lay), (7, lay)]).unwrap();
    let mut hub = vec![0u8; hub_lay.len_bytes()];
    // A read-only port refuses the query; the write capability enables it.
    assert!(
        port.broadcast_query_hub_read(hub_lay.board_mask(), &mut hub)
            .is_err()
    );
    assert_eq!(port.link().emulator().counters().writes, 0);
    port.allow_writes().enable_broadcast_query();
    port.broadcast_query_hub_read(hub_lay.board_mask(), &mut hub)
        .unwrap();
    let view = HubView::new_checked(&hub[..], hub_lay).unwrap();
    for (i, board) in [6u8, 7].iter().enumerate() {
        let h = view.header(i).unwrap();
        assert_eq!(h.size_quadlets(), 33);
        assert_eq!(h.sequence_lsb(), 1);
        let blk = view.block(i).unwrap();
        check_block_against_physics(port.link().emulator(), &io, *board, blk.as_bytes());
    }
    let c = port.link().emulator().counters();
    assert_eq!(
        (
            c.writes,
            c.broadcast_queries,
            c.samples,
            c.hub_reads,
            c.block_reads_address0
        ),
        (1, 1, 2, 1, 0)
    );
    // Hub memory is also readable by quadlets.
    let q0 = port.read_quadlet(6, HUB_ADDRESS).unwrap();
    assert_eq!(q0, view.header(0).unwrap().0);
}

#[test]
fn writes_are_counted_and_command_the_boards() {
    let io = io_config();
    let mut port = sim_port(&hold(), &io).unwrap();
    port.link_mut().advance_to(0);
    port.link_mut().advance_to(10 * NS_PER_MS);
    {
        let mut w = port.allow_writes();
        // Rev 8+ command block for board 6: header, four motor quadlets (valid | DAC), control.
        let mut data = Vec::new();
        for q in [
            (6u32 << 8) | 6,
            0x8000_1234,
            0x8000_2345,
            0x0000_3456,
            0x8000_4567,
            0,
        ] {
            data.extend_from_slice(&u32::to_be_bytes(q));
        }
        w.write_block(6, 0, &data).unwrap();
        w.write_quadlet(7, reg::STATUS, 0).unwrap();
    }
    let c = port.link().emulator().counters();
    assert_eq!((c.writes, c.block_writes, c.quadlet_writes), (2, 1, 1));
    let dac = |port: &mut SimPort, axis: u16| {
        port.read_quadlet(6, ((axis + 1) << 4) | 12).unwrap() & 0xFFFF
    };
    assert_eq!(dac(&mut port, 0), 0x1234);
    assert_eq!(dac(&mut port, 1), 0x2345);
    assert_eq!(
        dac(&mut port, 2),
        0x8000,
        "quadlet without the valid bit is ignored"
    );
    assert_eq!(dac(&mut port, 3), 0x4567);
    // Power off board 6 (mask bit 19, value 0): amplifiers off, the arm's motors stop.
    port.allow_writes()
        .write_quadlet(6, reg::STATUS, 1 << 19)
        .unwrap();
    let st = BoardStatus::new(port.read_quadlet(6, reg::STATUS).unwrap(), BoardKind::Qla);
    assert!(!st.power_enabled() && st.amp_on(0) == Some(false));
    assert!(!port.link().emulator().psm().amps_enabled());
    port.allow_writes()
        .write_quadlet(6, reg::STATUS, (1 << 19) | (1 << 18) | 0x0F0F)
        .unwrap();
    assert!(port.link().emulator().psm().amps_enabled());
    assert_eq!(port.link().emulator().counters().writes, 4);
}

#[test]
fn broadcast_command_block_reaches_both_boards() {
    let io = io_config();
    let mut port = sim_port(&hold(), &io).unwrap();
    port.link_mut().advance_to(0);
    let mut data = Vec::new();
    for board in [6u32, 7] {
        for q in [
            (board << 8) | 6,
            0x8000_0100 | board,
            0x8000_0200 | board,
            0x8000_0300 | board,
            0x8000_0400 | board,
            0,
        ] {
            data.extend_from_slice(&u32::to_be_bytes(q));
        }
    }
    port.allow_writes().broadcast_write_block(0, &data).unwrap();
    for board in [6u8, 7] {
        for axis in 0..4u16 {
            let dac = port.read_quadlet(board, ((axis + 1) << 4) | 12).unwrap() & 0xFFFF;
            assert_eq!(dac, u32::from(axis + 1) << 8 | u32::from(board));
        }
    }
    let c = port.link().emulator().counters();
    assert_eq!((c.writes, c.block_writes), (1, 1));
}

#[test]
fn watchdog_times_out_without_writes() {
    let io = io_config();
    let mut port = sim_port(&hold(), &io).unwrap();
    port.link_mut().advance_to(0);
    // 0x1680 = 30 ms (reference §1.2).
    port.allow_writes().write_quadlet(6, 3, 0x1680).unwrap();
    port.link_mut().advance_to(20 * NS_PER_MS);
    assert!(!BoardStatus::new(port.read_quadlet(6, 0).unwrap(), BoardKind::Qla).watchdog_timeout());
    port.link_mut().advance_to(40 * NS_PER_MS);
    let st = BoardStatus::new(port.read_quadlet(6, 0).unwrap(), BoardKind::Qla);
    assert!(st.watchdog_timeout() && st.amp_on(0) == Some(false));
    assert!(!port.link().emulator().psm().amps_enabled());
    // Board 7 has no watchdog period set.
    assert!(!BoardStatus::new(port.read_quadlet(7, 0).unwrap(), BoardKind::Qla).watchdog_timeout());
}

#[test]
fn stale_generation_on_a_forwarded_request_is_dropped() {
    let mut emu = emulator(&hold());
    let mut out = [0u8; MAX_REPLY_BYTES];
    let mut buf = [0u8; 64];
    let req = RequestRepr::host(7, 1, 4, RequestKind::QuadletRead);
    let n = EthRequest::emit(
        &mut buf,
        ControlWord::new(false, BUS_GENERATION + 1),
        &req,
        &[],
    )
    .unwrap();
    let m = emu.handle(&buf[..n], &mut out).unwrap();
    assert_eq!(m, 8);
    let r = EthReply::parse(&out[..m]).unwrap();
    assert!(r.packet.is_none() && r.extra.flags & extra_flags::PACKET_DROPPED != 0);
    assert_eq!(emu.counters().generation_mismatch, 1);
}

#[test]
fn malformed_requests_get_no_reply() {
    let mut emu = emulator(&hold());
    let mut out = [0u8; MAX_REPLY_BYTES];
    let good = request(6, 1, 4, RequestKind::QuadletRead, true, &[]);
    assert!(emu.handle(&good, &mut out).is_some());
    // Header CRC broken.
    let mut bad = good.clone();
    bad[17] ^= 1;
    assert_eq!(emu.handle(&bad, &mut out), None);
    // Truncated, empty, response tcode, wrong bus.
    assert_eq!(emu.handle(&good[..10], &mut out), None);
    assert_eq!(emu.handle(&[], &mut out), None);
    let mut resp = vec![0u8; 2];
    let mut tmp = [0u8; 64];
    let r = ResponseRepr {
        dest_id: 0xFFC6,
        src_id: 0xFFD0,
        label: 0,
        rcode: 0,
        kind: ResponseKind::Quadlet { data: 0 },
    };
    let n = r.emit(&mut tmp, &[]).unwrap();
    resp.extend_from_slice(&tmp[..n]);
    assert_eq!(emu.handle(&resp, &mut out), None);
    // Reply buffer too small for the reply: no reply, no panic.
    assert_eq!(emu.handle(&good, &mut out[..10]), None);
    // Block read longer than the FPGA allows.
    let long = request(6, 1, 0, RequestKind::BlockRead { len: 4000 }, true, &[]);
    assert_eq!(emu.handle(&long, &mut out), None);
    // Block write with a broken data CRC.
    let mut bw = request(
        6,
        1,
        0x10,
        RequestKind::BlockWrite { len: 8 },
        true,
        &[1, 2, 3, 4, 5, 6, 7, 8],
    );
    let last = bw.len() - 1;
    bw[last] ^= 0xFF;
    assert_eq!(emu.handle(&bw, &mut out), None);
    assert_eq!(emu.counters().writes, 0);
    assert!(emu.counters().malformed >= 6);
    // Still serving.
    assert!(emu.handle(&good, &mut out).is_some());
}

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let mut emu = emulator(hold_scenario());
            let mut out = [0u8; MAX_REPLY_BYTES];
            if let Some(n) = emu.handle(&bytes, &mut out) {
                prop_assert!(n <= MAX_REPLY_BYTES);
                prop_assert!(EthReply::parse(&out[..n]).is_ok());
            }
        }

        #[test]
        fn valid_headers_with_random_fields_never_panic(
            node in 0u8..64, label in 0u8..64, addr in any::<u16>(), kind in 0u8..4,
            data in any::<u32>(), len in 0u16..3000, noforward in any::<bool>(),
        ) {
            let mut emu = emulator(hold_scenario());
            let mut out = [0u8; MAX_REPLY_BYTES];
            let payload: Vec<u8> = (0..len.min(1446)).map(|i| i as u8).collect();
            let kind = match kind {
                0 => RequestKind::QuadletRead,
                1 => RequestKind::QuadletWrite { data },
                2 => RequestKind::BlockRead { len },
                _ => RequestKind::BlockWrite { len: payload.len() as u16 },
            };
            let body = if matches!(kind, RequestKind::BlockWrite { .. }) { &payload[..] } else { &[][..] };
            let req = request(node, label, addr, kind, noforward, body);
            if let Some(n) = emu.handle(&req, &mut out) {
                let r = EthReply::parse(&out[..n]).unwrap();
                if let Some(p) = r.packet {
                    let resp = ResponseRepr::parse(&p).unwrap();
                    prop_assert_eq!(resp.label, label);
                }
            }
            emu.advance_to(1_010 * NS_PER_MS);
            prop_assert!(emu.psm().joint_state().position.iter().all(|v| v.is_finite()));
        }
    }
}
