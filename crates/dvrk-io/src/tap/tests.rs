//! Decoder tests on frames built with the wire emitters: the three read protocols, pairing by
//! host, label and node, and hostile bytes.

use std::net::SocketAddrV4;

use super::*;
use crate::wire::block::status_bits;
use crate::wire::firewire::node_id;
use crate::wire::{
    BoardKind, ControlWord, EncoderPosition, ExtraData, HubLayout, HubView, Timestamp,
};

const PSM_CLASSIC: &str = include_str!("../../../../config/io/psm-classic.toml");

fn cfg() -> IoConfig {
    IoConfig::from_params(toml::from_str(PSM_CLASSIC).unwrap()).unwrap()
}

fn lay() -> BlockLayout {
    BlockLayout::new(9, BoardKind::Qla).unwrap()
}

const CONSOLE: &str = "127.0.0.1:40000";
const OTHER: &str = "127.0.0.1:40001";

fn host(s: &str) -> SocketAddrV4 {
    s.parse().unwrap()
}

/// A board's address; broadcast requests go to the subnet's broadcast address.
fn board_addr(node: u8) -> SocketAddrV4 {
    if node == BROADCAST_NODE {
        return SocketAddrV4::new([127, 255, 255, 255].into(), BOARD_PORT);
    }
    SocketAddrV4::new([127, 0, 0, 1 + node.min(200)].into(), BOARD_PORT)
}

/// A feedback block of `board` whose encoder 0 reads `counts` and timestamp `ts`.
fn block(board: u8, counts: i32, ts: u32) -> Vec<u8> {
    let mut b = vec![0u8; lay().len_bytes()];
    let mut v = FeedbackBlock::new_checked(&mut b[..], lay()).unwrap();
    v.set_timestamp(Timestamp(ts));
    v.set_status(BoardStatus::board_id_bits(board) | status_bits::POWER_ENABLE);
    for e in 0..4 {
        v.set_encoder_position(e, EncoderPosition::from_counts(counts + e as i32))
            .unwrap();
    }
    b
}

fn frame(src: SocketAddrV4, dst: SocketAddrV4, payload: &[u8]) -> Vec<u8> {
    let mut buf = vec![0u8; payload.len() + 64];
    let n = emit_frame(&mut buf, LinkType::Ethernet, src, dst, payload).unwrap();
    buf.truncate(n);
    buf
}

fn request(from: &str, node: u8, label: u8, addr: u16, kind: RequestKind) -> Vec<u8> {
    let req = RequestRepr::host(node, label, u64::from(addr), kind);
    let mut buf = vec![0u8; 64];
    let n = EthRequest::emit(&mut buf, ControlWord::new(true, 0), &req, &[]).unwrap();
    frame(host(from), board_addr(node), &buf[..n])
}

fn block_reply(to: &str, node: u8, label: u8, data: &[u8]) -> Vec<u8> {
    let resp = ResponseRepr {
        dest_id: 0xFFD0,
        src_id: node_id(node),
        label,
        rcode: 0,
        kind: ResponseKind::Block {
            len: data.len() as u16,
        },
    };
    let mut buf = vec![0u8; data.len() + 64];
    let n = EthReply::emit(&mut buf, &resp, data, &ExtraData::default()).unwrap();
    frame(board_addr(node), host(to), &buf[..n])
}

fn hub_data(seq: u16, boards: &[(u8, i32, u32)]) -> Vec<u8> {
    let hl = HubLayout::new(&boards.iter().map(|b| (b.0, lay())).collect::<Vec<_>>()).unwrap();
    let mut mem = vec![0u8; hl.len_bytes()];
    let mut view = HubView::new_checked(&mut mem[..], hl).unwrap();
    for (i, &(id, counts, ts)) in boards.iter().enumerate() {
        view.set_header(i, HubHeader::new(lay().len_quadlets() as u8, seq, false, 0))
            .unwrap();
        let b = block(id, counts, ts);
        view.block_mut(i).unwrap().into_inner().copy_from_slice(&b);
    }
    mem
}

fn push(d: &mut TapDecoder, f: &[u8], out: &mut ArmSample) -> TapEvent {
    d.push(f, LinkType::Ethernet, 7, out)
}

fn counts0(cfg: &IoConfig, s: &ArmSample) -> i32 {
    // Joint 1 is actuator 1 (board 6, axis 0), uncoupled.
    cfg.actuators()[0].position_to_counts(s.position[0])
}

#[test]
fn sequential_reads_give_one_sample_per_cycle() {
    let c = cfg();
    let mut d = TapDecoder::new(c.clone());
    let mut out = ArmSample::default();
    let len = lay().len_bytes() as u16;
    for cycle in 0..3u8 {
        let l6 = cycle * 2;
        let l7 = cycle * 2 + 1;
        let e = push(
            &mut d,
            &request(CONSOLE, 6, l6, 0, RequestKind::BlockRead { len }),
            &mut out,
        );
        assert_eq!(e, TapEvent::Consumed);
        let e = push(
            &mut d,
            &block_reply(CONSOLE, 6, l6, &block(6, 100 + i32::from(cycle), 1000)),
            &mut out,
        );
        assert_eq!(e, TapEvent::Consumed);
        push(
            &mut d,
            &request(CONSOLE, 7, l7, 0, RequestKind::BlockRead { len }),
            &mut out,
        );
        let e = push(
            &mut d,
            &block_reply(CONSOLE, 7, l7, &block(7, 5, 2000)),
            &mut out,
        );
        assert_eq!(e, TapEvent::Sample, "cycle {cycle}");
        assert!(out.valid);
        assert_eq!(out.t_ns, 7);
        assert_eq!(counts0(&c, &out), 100 + i32::from(cycle));
        assert_eq!(out.board_timestamp, [1000, 2000]);
    }
    assert_eq!(d.counters().samples, 3);
    assert_eq!(d.blocks_seen(), [3, 3]);
}

#[test]
fn replies_pair_by_host_label_and_node() {
    let c = cfg();
    let mut d = TapDecoder::new(c);
    let mut out = ArmSample::default();
    let len = lay().len_bytes() as u16;
    push(
        &mut d,
        &request(CONSOLE, 6, 5, 0, RequestKind::BlockRead { len }),
        &mut out,
    );
    // Same label, other host: not this request's reply.
    let e = push(&mut d, &block_reply(OTHER, 6, 5, &block(6, 1, 1)), &mut out);
    assert_eq!(e, TapEvent::Skipped(Skip::Unpaired));
    // Right host, wrong label.
    let e = push(
        &mut d,
        &block_reply(CONSOLE, 6, 6, &block(6, 1, 1)),
        &mut out,
    );
    assert_eq!(e, TapEvent::Skipped(Skip::Unpaired));
    // Right host and label, another node answering.
    let e = push(
        &mut d,
        &block_reply(CONSOLE, 7, 5, &block(7, 1, 1)),
        &mut out,
    );
    assert_eq!(e, TapEvent::Skipped(Skip::Unpaired));
    let e = push(
        &mut d,
        &block_reply(CONSOLE, 6, 5, &block(6, 1, 1)),
        &mut out,
    );
    assert_eq!(e, TapEvent::Consumed);
    // A second reply to the same request is not paired again.
    let e = push(
        &mut d,
        &block_reply(CONSOLE, 6, 5, &block(6, 1, 1)),
        &mut out,
    );
    assert_eq!(e, TapEvent::Skipped(Skip::Unpaired));
    assert_eq!(d.counters().skipped_unpaired, 4);
}

#[test]
fn bridge_broadcast_query_then_hub_read() {
    let c = cfg();
    let mut d = TapDecoder::new(c.clone());
    let mut out = ArmSample::default();
    let q = RequestKind::QuadletWrite {
        data: (9 << 16) | 0x00C0,
    };
    assert_eq!(
        push(
            &mut d,
            &request(CONSOLE, 0x3F, 1, QUERY_ADDRESS, q),
            &mut out
        ),
        TapEvent::Consumed
    );
    let hub = hub_data(9, &[(6, 42, 111), (7, 43, 222)]);
    let len = hub.len() as u16;
    push(
        &mut d,
        &request(CONSOLE, 6, 2, HUB_ADDRESS, RequestKind::BlockRead { len }),
        &mut out,
    );
    let e = push(&mut d, &block_reply(CONSOLE, 6, 2, &hub), &mut out);
    assert_eq!(e, TapEvent::Sample);
    assert_eq!(counts0(&c, &out), 42);
    assert_eq!(out.board_timestamp, [111, 222]);
    assert_eq!(d.counters().unsolicited_hub, 0);
}

#[test]
fn ethernet_only_unsolicited_hub_data_in_any_order() {
    let c = cfg();
    let mut d = TapDecoder::new(c.clone());
    let mut out = ArmSample::default();
    let q = RequestKind::QuadletWrite {
        data: (300 << 16) | 0x00C0,
    };
    push(
        &mut d,
        &request(CONSOLE, 0x3F, 33, QUERY_ADDRESS, q),
        &mut out,
    );
    // Board 7 first: the Ethernet-only hub does not order the boards (§3.4).
    let hub = hub_data(300, &[(7, 8, 20), (6, -77, 10)]);
    let e = push(&mut d, &block_reply(CONSOLE, 7, 33, &hub), &mut out);
    assert_eq!(e, TapEvent::Sample);
    assert_eq!(counts0(&c, &out), -77);
    assert_eq!(out.board_timestamp, [10, 20]);
    assert_eq!(d.counters().unsolicited_hub, 1);
}

#[test]
fn hub_slot_with_wrong_sequence_is_not_a_sample() {
    let c = cfg();
    let mut d = TapDecoder::new(c);
    let mut out = ArmSample::default();
    let q = RequestKind::QuadletWrite { data: 4 << 16 };
    push(
        &mut d,
        &request(CONSOLE, 0x3F, 3, QUERY_ADDRESS, q),
        &mut out,
    );
    let hub = hub_data(5, &[(6, 1, 1), (7, 1, 1)]);
    let e = push(&mut d, &block_reply(CONSOLE, 6, 3, &hub), &mut out);
    assert_eq!(e, TapEvent::Consumed);
    assert_eq!(d.counters().bad_hub_slots, 2);
    assert_eq!(d.counters().incomplete_cycles, 1);
}

/// A cycle whose first board's block the tap never saw (the capture dropped the frame, or the
/// console gave the read up) must not pair the other board's block with the next cycle's first:
/// the console reads every board, then writes, and a sample's blocks must come from reads
/// between the same two writes. Before, the phase stayed shifted by one board for the rest of
/// the run (tests/tap.rs saw hundreds of samples mixing two console reads on a busy host). The
/// shell feeds the requests it captured before each reply, so a cycle's writes may reach the
/// decoder before the cycle's replies: the requests' own order decides, not when they are
/// decoded.
#[test]
fn a_cycle_missing_a_block_is_not_paired_with_the_next_cycles_read() {
    let c = cfg();
    let len = lay().len_bytes() as u16;
    for requests_first in [false, true] {
        let mut d = TapDecoder::new(c.clone());
        let mut out = ArmSample::default();
        let mut label = 0u8;
        let mut next_label = || {
            label = (label + 1) & 0x3F;
            label
        };
        let reply = |board: u8, l: u8, cycle: u32| {
            let ts = 1000 * cycle + u32::from(board);
            block_reply(CONSOLE, board, l, &block(board, cycle as i32, ts))
        };
        let mut samples = Vec::new();
        for cycle in 1..=4u32 {
            let (l6, l7) = (next_label(), next_label());
            let reqs = [
                request(CONSOLE, 6, l6, 0, RequestKind::BlockRead { len }),
                request(CONSOLE, 7, l7, 0, RequestKind::BlockRead { len }),
                request(
                    CONSOLE,
                    6,
                    next_label(),
                    8,
                    RequestKind::QuadletWrite { data: 0 },
                ),
                request(
                    CONSOLE,
                    7,
                    next_label(),
                    8,
                    RequestKind::QuadletWrite { data: 0 },
                ),
            ];
            // Cycle 2 loses board 6's block.
            let replies: Vec<Vec<u8>> = [(6, l6), (7, l7)]
                .into_iter()
                .filter(|&(b, _)| !(cycle == 2 && b == 6))
                .map(|(b, l)| reply(b, l, cycle))
                .collect();
            if requests_first {
                // The decoder gets this cycle's requests, writes included, before its replies.
                for r in &reqs {
                    push(&mut d, r, &mut out);
                }
                for r in &replies {
                    if push(&mut d, r, &mut out) == TapEvent::Sample {
                        samples.push(out.board_timestamp);
                    }
                }
            } else {
                let mut rep = replies.iter();
                for (i, r) in reqs.iter().enumerate() {
                    push(&mut d, r, &mut out);
                    let lost = cycle == 2 && i == 0;
                    if i < 2
                        && !lost
                        && push(&mut d, rep.next().unwrap(), &mut out) == TapEvent::Sample
                    {
                        samples.push(out.board_timestamp);
                    }
                }
            }
        }
        let want: Vec<[u32; 2]> = [1u32, 3, 4]
            .iter()
            .map(|c| [1000 * c + 6, 1000 * c + 7])
            .collect();
        assert_eq!(samples, want, "requests first: {requests_first}");
        assert_eq!(
            d.counters().incomplete_cycles,
            1,
            "requests first: {requests_first}"
        );
    }
}

#[test]
fn a_board_missing_from_the_traffic_gives_no_sample_and_is_counted() {
    let mut d = TapDecoder::new(cfg());
    let mut out = ArmSample::default();
    let len = lay().len_bytes() as u16;
    for l in 0..4u8 {
        push(
            &mut d,
            &request(CONSOLE, 6, l, 0, RequestKind::BlockRead { len }),
            &mut out,
        );
        let e = push(
            &mut d,
            &block_reply(CONSOLE, 6, l, &block(6, 1, 1)),
            &mut out,
        );
        assert_eq!(e, TapEvent::Consumed);
    }
    assert_eq!(d.blocks_seen(), [4, 0]);
    assert_eq!(d.counters().incomplete_cycles, 3);
    assert_eq!(d.counters().samples, 0);
}

#[test]
fn quadlet_traffic_and_writes_are_not_feedback() {
    let mut d = TapDecoder::new(cfg());
    let mut out = ArmSample::default();
    let e = push(
        &mut d,
        &request(CONSOLE, 6, 1, 0x15, RequestKind::QuadletRead),
        &mut out,
    );
    assert_eq!(e, TapEvent::Skipped(Skip::NoFeedback));
    let e = push(
        &mut d,
        &request(CONSOLE, 6, 2, 0, RequestKind::QuadletWrite { data: 1 }),
        &mut out,
    );
    assert_eq!(e, TapEvent::Skipped(Skip::NoFeedback));
}

#[test]
fn hostile_bytes_never_panic() {
    let mut d = TapDecoder::new(cfg());
    let mut out = ArmSample::default();
    let len = lay().len_bytes() as u16;
    let good_req = request(CONSOLE, 6, 1, 0, RequestKind::BlockRead { len });
    let good_rep = block_reply(CONSOLE, 6, 1, &block(6, 1, 1));
    // Every truncation and a sweep of single-byte corruptions of a request and its reply.
    for f in [&good_req, &good_rep] {
        for cut in 0..f.len() {
            d.push(&f[..cut], LinkType::Ethernet, 0, &mut out);
            d.push(&f[..cut], LinkType::Ip, 0, &mut out);
        }
        for i in 0..f.len() {
            for v in [0u8, 0xFF, 0x3F, 0x80] {
                let mut g = f.clone();
                g[i] = v;
                d.push(&g, LinkType::Ethernet, 0, &mut out);
            }
        }
    }
    // Hub data whose header sizes point past the end, or are huge.
    let q = RequestKind::QuadletWrite { data: 0 };
    push(
        &mut d,
        &request(CONSOLE, 0x3F, 9, QUERY_ADDRESS, q),
        &mut out,
    );
    let bad = [0xFFu8; 64];
    push(&mut d, &block_reply(CONSOLE, 6, 9, &bad), &mut out);
}

/// The fuzz target `tap_frames` reads records `[len: u16 LE][link: u8][frame: len bytes]`.
fn fuzz_record(out: &mut Vec<u8>, link: LinkType, frame: &[u8]) {
    out.extend_from_slice(&(frame.len() as u16).to_le_bytes());
    out.push(u8::from(link == LinkType::Ip));
    out.extend_from_slice(frame);
}

/// Writes the seed corpus of the `tap_frames` fuzz target (two cycles of block reads of both
/// boards) into `$TAP_FUZZ_SEEDS`. Run by hand when the framing changes:
/// `TAP_FUZZ_SEEDS=fuzz/corpus/tap_frames cargo test -p dvrk-io write_tap_fuzz_seeds -- --ignored`
#[test]
#[ignore = "writes the fuzz seed corpus; run by hand"]
fn write_tap_fuzz_seeds() {
    let dir = std::path::PathBuf::from(std::env::var("TAP_FUZZ_SEEDS").expect("TAP_FUZZ_SEEDS"));
    std::fs::create_dir_all(&dir).unwrap();
    let len = lay().len_bytes() as u16;
    let mut seq = Vec::new();
    for cycle in 0..2u8 {
        for (node, label) in [(6u8, cycle * 2), (7, cycle * 2 + 1)] {
            let req = request(CONSOLE, node, label, 0, RequestKind::BlockRead { len });
            fuzz_record(&mut seq, LinkType::Ethernet, &req);
            let rep = block_reply(CONSOLE, node, label, &block(node, 100, 1000));
            fuzz_record(&mut seq, LinkType::Ethernet, &rep);
        }
    }
    // The decoder must turn the seed into samples, or the seed explores nothing.
    let mut d = TapDecoder::new(cfg());
    let mut out = ArmSample::default();
    let mut rest = &seq[..];
    while rest.len() >= 3 {
        let n = usize::from(u16::from_le_bytes([rest[0], rest[1]]));
        let f = &rest[3..3 + n];
        d.push(f, LinkType::Ethernet, 1, &mut out);
        rest = &rest[3 + n..];
    }
    assert_eq!(d.counters().samples, 2);
    std::fs::write(dir.join("two-cycles-block-reads"), &seq).unwrap();
    // The IPv4-only framing of the same first request.
    let req = request(CONSOLE, 6, 0, 0, RequestKind::BlockRead { len });
    let mut ip = Vec::new();
    fuzz_record(&mut ip, LinkType::Ip, &req[14..]);
    std::fs::write(dir.join("ip-request"), &ip).unwrap();
}

/// Issue 22: a reply is taken only from the address its request was sent to; one from another
/// local address or port (a forger's socket) pairs with nothing, even with the right host,
/// label and node.
#[test]
fn a_reply_from_another_address_than_the_request_went_to_is_not_taken() {
    let cfg = cfg();
    let mut d = TapDecoder::new(cfg.clone());
    let mut out = ArmSample::default();
    let resp = |label: u8, data: &[u8]| {
        let r = ResponseRepr {
            dest_id: 0xFFD0,
            src_id: node_id(6),
            label,
            rcode: 0,
            kind: ResponseKind::Block {
                len: data.len() as u16,
            },
        };
        let mut buf = vec![0u8; data.len() + 64];
        let n = EthReply::emit(&mut buf, &r, data, &ExtraData::default()).unwrap();
        buf.truncate(n);
        buf
    };
    let forgers = [
        SocketAddrV4::new([10, 0, 0, 99].into(), BOARD_PORT),
        SocketAddrV4::new([127, 0, 0, 7].into(), BOARD_PORT + 1),
    ];
    for (label, forger) in forgers.into_iter().enumerate() {
        let label = label as u8;
        let req = request(CONSOLE, 6, label, 0, RequestKind::BlockRead { len: 64 });
        assert_eq!(push(&mut d, &req, &mut out), TapEvent::Consumed);
        let f = frame(forger, host(CONSOLE), &resp(label, &block(6, 1000, 1)));
        let ev = push(&mut d, &f, &mut out);
        assert!(
            matches!(
                ev,
                TapEvent::Skipped(Skip::Unpaired) | TapEvent::Skipped(Skip::OtherPort)
            ),
            "reply from {forger}: {ev:?}"
        );
    }
    assert_eq!(d.counters().paired, 0);
    // From the board's own address the same reply is taken.
    let req = request(CONSOLE, 6, 9, 0, RequestKind::BlockRead { len: 64 });
    push(&mut d, &req, &mut out);
    let f = frame(board_addr(6), host(CONSOLE), &resp(9, &block(6, 1000, 1)));
    assert_ne!(
        push(&mut d, &f, &mut out),
        TapEvent::Skipped(Skip::Unpaired)
    );
    assert_eq!(d.counters().paired, 1);
    assert!(replies_for(
        "169.254.255.255:1394".parse().unwrap(),
        "169.254.0.106:1394".parse().unwrap()
    ));
    assert!(!replies_for(
        "169.254.255.255:1394".parse().unwrap(),
        "10.0.0.6:1394".parse().unwrap()
    ));
    assert!(!replies_for(
        "169.254.0.106:1394".parse().unwrap(),
        "169.254.0.107:1394".parse().unwrap()
    ));
}

/// [`block`] with pot bits `1000 * (board + axis + 1)` in every ADC quadlet.
fn block_with_pots(board: u8, counts: i32, ts: u32) -> Vec<u8> {
    let mut b = block(board, counts, ts);
    let mut v = FeedbackBlock::new_checked(&mut b[..], lay()).unwrap();
    for ax in 0..4 {
        let pot = 1000 * (u16::from(board) + ax as u16 + 1);
        v.set_adc(ax, crate::wire::Adc::new(pot, 0x8000)).unwrap();
    }
    b
}

fn saw_cfg() -> IoConfig {
    let text = include_str!("../../../../tests/data/io/sawRobotIO1394-PSM1-00000.json");
    let file: crate::convert::SawFile =
        serde_json::from_str(&crate::convert::strip_json_comments(text)).unwrap();
    IoConfig::from_saw_file(file, None).unwrap()
}

fn expect_tap_pots(c: &IoConfig, d: &TapDecoder) {
    let pots = d.pots().expect("the io file calibrates the pots");
    for (i, a) in c.actuators().iter().enumerate() {
        let bits = 1000 * (u16::from(a.board_id) + u16::from(a.axis) + 1);
        assert_eq!(
            pots[i],
            a.pot_bits_to_position(bits).unwrap(),
            "actuator {}",
            i + 1
        );
    }
}

#[test]
fn the_tap_decodes_the_pots_of_the_consoles_reads() {
    let c = saw_cfg();
    let mut d = TapDecoder::new(c.clone());
    let mut out = ArmSample::default();
    assert!(
        d.pots().unwrap().iter().all(|p| p.is_nan()),
        "nothing seen yet"
    );
    // Sequential block reads.
    let len = lay().len_bytes() as u16;
    push(
        &mut d,
        &request(CONSOLE, 6, 1, 0, RequestKind::BlockRead { len }),
        &mut out,
    );
    push(
        &mut d,
        &block_reply(CONSOLE, 6, 1, &block_with_pots(6, 10, 1)),
        &mut out,
    );
    push(
        &mut d,
        &request(CONSOLE, 7, 2, 0, RequestKind::BlockRead { len }),
        &mut out,
    );
    let e = push(
        &mut d,
        &block_reply(CONSOLE, 7, 2, &block_with_pots(7, 10, 1)),
        &mut out,
    );
    assert_eq!(e, TapEvent::Sample);
    expect_tap_pots(&c, &d);
    assert_eq!(
        d.last_actuators().position[0],
        c.actuators()[0].counts_to_position(10)
    );
    let diff = d.pot_minus_encoder().unwrap();
    assert_eq!(
        diff[0],
        d.pots().unwrap()[0] - c.actuators()[0].counts_to_position(10)
    );
    // A broadcast query and its hub data.
    let mut d = TapDecoder::new(c.clone());
    let q = RequestKind::QuadletWrite {
        data: (5 << 16) | 0x00C0,
    };
    push(
        &mut d,
        &request(CONSOLE, 0x3F, 3, QUERY_ADDRESS, q),
        &mut out,
    );
    let mut hub = hub_data(5, &[(6, 0, 1), (7, 0, 1)]);
    let q_len = lay().len_quadlets() * 4;
    for (slot, board) in [6u8, 7].into_iter().enumerate() {
        let at = 4 + slot * (q_len + 4);
        hub[at..at + q_len].copy_from_slice(&block_with_pots(board, 0, 1));
    }
    assert_eq!(
        push(&mut d, &block_reply(CONSOLE, 6, 3, &hub), &mut out),
        TapEvent::Sample
    );
    expect_tap_pots(&c, &d);
    // No pot calibration, no pots.
    let no_pots = TapDecoder::new(cfg());
    assert!(no_pots.pots().is_none() && no_pots.pot_minus_encoder().is_none());
}
