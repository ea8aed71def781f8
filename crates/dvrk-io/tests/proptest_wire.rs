//! Random bytes into every parser: nothing panics. Random fields through every emitter: parse
//! gives them back.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use dvrk_io::port::{EthPort, Link, Port, PortError, frames_from_text};
use dvrk_io::wire::{
    BlockLayout, BoardKind, ControlWord, EthReply, EthRequest, ExtraData, FeedbackBlock, HubLayout,
    HubView, Packet, RequestKind, RequestRepr, ResponseKind, ResponseRepr,
};
use proptest::prelude::*;

fn touch_packet(p: &Packet<&[u8]>) -> u64 {
    let mut acc = u64::from(p.tcode() as u8)
        ^ u64::from(p.dest_id())
        ^ u64::from(p.label())
        ^ u64::from(p.retry())
        ^ u64::from(p.priority())
        ^ u64::from(p.src_id())
        ^ p.offset()
        ^ u64::from(p.rcode())
        ^ u64::from(p.quadlet_data())
        ^ u64::from(p.data_length())
        ^ u64::from(p.extended_tcode())
        ^ u64::from(p.header_crc())
        ^ u64::from(p.computed_header_crc())
        ^ u64::from(p.data_crc())
        ^ u64::from(p.computed_data_crc())
        ^ p.total_len() as u64;
    acc ^= p.payload().len() as u64 ^ p.as_bytes().len() as u64;
    let _ = RequestRepr::parse(p);
    let _ = ResponseRepr::parse(p);
    acc
}

fn layouts() -> Vec<BlockLayout> {
    let mut v = Vec::new();
    for fw in 7..=9 {
        for k in [BoardKind::Qla, BoardKind::Dqla, BoardKind::Drac] {
            if let Ok(l) = BlockLayout::new(fw, k) {
                v.push(l);
            }
        }
    }
    v
}

fn touch_block(b: &FeedbackBlock<&[u8]>) -> u64 {
    let mut acc =
        u64::from(b.timestamp().0) ^ u64::from(b.status().raw) ^ u64::from(b.digital_io().0);
    let s = b.status();
    acc ^= u64::from(s.board_id())
        ^ u64::from(s.fully_powered())
        ^ u64::from(s.motor_supply_fault())
        ^ u64::from(s.relay_feedback());
    for i in 0..4 {
        acc ^= b.temperature().sensor_celsius(i).map_or(0, |t| t as u64);
    }
    let clk = b.layout().velocity_clock_hz();
    for i in 0..12 {
        acc ^= b.adc(i).map_or(0, |a| {
            u64::from(a.pot_bits()) ^ a.qla_current_amps().to_bits()
        });
        acc ^= b
            .encoder_position(i)
            .map_or(0, |e| e.counts() as u64 ^ u64::from(e.overflow()));
        acc ^= b.encoder_period(i).map_or(0, |e| {
            e.velocity_counts_per_s(clk).to_bits() ^ u64::from(e.encoder_error())
        });
        acc ^= b
            .qtr1(i)
            .map_or(0, |q| u64::from(q.ticks()) ^ u64::from(q.edge_mask()));
        acc ^= b.qtr5(i).map_or(0, |q| u64::from(q.ticks()));
        acc ^= b.running(i).map_or(0, u64::from);
        acc ^= b.motor_status(i).map_or(0, |m| {
            u64::from(m.amp_fault()) ^ u64::from(m.drac_fault_code()) ^ u64::from(m.dac())
        });
    }
    acc
}

/// A link that answers every request with the given bytes.
struct Garbage(Vec<u8>);
impl Link for Garbage {
    fn send(&mut self, _: u8, _: &[u8]) -> Result<(), PortError> {
        Ok(())
    }
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        let n = self.0.len().min(buf.len());
        buf[..n].copy_from_slice(&self.0[..n]);
        Ok(n)
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

    #[test]
    fn firewire_parser_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..96)) {
        if let Ok(p) = Packet::new_checked(&bytes[..]) {
            touch_packet(&p);
            prop_assert!(p.total_len() <= bytes.len());
        }
    }

    #[test]
    fn ethernet_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..96)) {
        if let Ok(r) = EthRequest::parse(&bytes) {
            touch_packet(&r.packet);
            let _ = r.trailing();
        }
        if let Ok(r) = EthReply::parse(&bytes) {
            if let Some(p) = r.packet { touch_packet(&p); }
            let _ = (r.extra.packet_dropped(), r.extra.source_port(), r.excess);
        }
        let _ = ControlWord::parse(&bytes);
        let _ = ExtraData::parse(&bytes);
    }

    #[test]
    fn block_and_hub_views_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        for l in layouts() {
            if let Ok(b) = FeedbackBlock::new_checked(&bytes[..], l) {
                touch_block(&b);
            }
            let hub = HubLayout::new(&[(6, l), (7, l)]).unwrap();
            if let Ok(h) = HubView::new_checked(&bytes[..], hub) {
                for i in 0..3 {
                    let _ = h.header(i);
                    if let Ok(b) = h.block(i) { touch_block(&b); }
                }
                let _ = h.timing();
            }
        }
    }

    #[test]
    fn eth_port_rejects_random_replies_without_panicking(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let mut p = EthPort::new(Garbage(bytes));
        let _ = p.read_quadlet(6, 0);
        let mut blk = [0u8; 128];
        let _ = p.read_block(6, 0, &mut blk);
    }

    #[test]
    fn text_parsers_never_panic(s in "\\PC{0,200}") {
        let _ = common::io_from_toml(&s);
        let _ = common::io_from_saw_json(&s);
        let _ = frames_from_text(&s);
    }

    #[test]
    fn request_emit_parse_round_trip(node in 0u8..64, label in 0u8..64, addr in 0u64..(1 << 48), data in any::<u32>(), len in 1u16..400, which in 0u8..4) {
        let kind = match which {
            0 => RequestKind::QuadletRead,
            1 => RequestKind::QuadletWrite { data },
            2 => RequestKind::BlockRead { len },
            _ => RequestKind::BlockWrite { len },
        };
        let payload: Vec<u8> = match kind { RequestKind::BlockWrite { len } => (0..len).map(|i| i as u8).collect(), _ => vec![] };
        let r = RequestRepr::host(node, label, addr, kind);
        let mut buf = vec![0u8; r.buffer_len()];
        let n = EthRequest::emit(&mut vec![0u8; r.buffer_len() + 2], ControlWord::new(true, 3), &r, &payload).unwrap();
        prop_assert_eq!(n, r.buffer_len() + 2);
        r.emit(&mut buf, &payload).unwrap();
        let p = Packet::new_checked(&buf[..]).unwrap();
        prop_assert_eq!(RequestRepr::parse(&p).unwrap(), r);
        prop_assert_eq!(p.payload(), &payload[..]);
        prop_assert_eq!(p.header_crc(), p.computed_header_crc());
        prop_assert_eq!(p.data_crc(), p.computed_data_crc());
    }

    #[test]
    fn response_emit_parse_round_trip(src in 0u8..64, label in 0u8..64, rcode in 0u8..16, data in any::<u32>(), len in 1u16..400, block in any::<bool>()) {
        let kind = if block { ResponseKind::Block { len } } else { ResponseKind::Quadlet { data } };
        let payload: Vec<u8> = if block { (0..len).map(|i| (i * 7) as u8).collect() } else { vec![] };
        let r = ResponseRepr { dest_id: 0xFFD0, src_id: 0xFFC0 | u16::from(src), label, rcode, kind };
        let mut buf = vec![0u8; r.buffer_len() + 8];
        let n = EthReply::emit(&mut buf, &r, &payload, &ExtraData::default()).unwrap();
        let reply = EthReply::parse(&buf[..n]).unwrap();
        let p = reply.packet.unwrap();
        prop_assert_eq!(ResponseRepr::parse(&p).unwrap(), r);
        prop_assert_eq!(p.payload(), &payload[..]);
        prop_assert_eq!(reply.excess, 0);
    }

    #[test]
    fn encoder_counts_round_trip(c in -0x80_0000i32..0x80_0000) {
        prop_assert_eq!(dvrk_io::wire::EncoderPosition::from_counts(c).counts(), c);
    }
}
