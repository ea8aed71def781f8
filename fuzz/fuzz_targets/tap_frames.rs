//! The passive tap (`source = "tap:IFACE"`): every frame captured on the console's interface
//! goes through `TapDecoder::push` — link, IPv4 and UDP framing, the console's requests and the
//! boards' replies, their pairing by host, label and node, and the feedback blocks decoded into
//! a sample. Input: records `[len: u16 LE][link: u8, bit 0 = IPv4 without Ethernet][frame]`,
//! fed in order to one decoder of the Classic PSM (QLA boards 6 and 7). Nothing may panic, and
//! the counters must add up.
#![no_main]

#[path = "common.rs"]
mod common;

use dvrk_io::wire::BoardKind;
use dvrk_io::{ArmSample, LinkType, TapDecoder, TapEvent};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut d = TapDecoder::new(common::io_config(BoardKind::Qla).clone());
    let mut out = ArmSample::default();
    let mut rest = data;
    let mut pushed = 0u64;
    let mut samples = 0u64;
    while rest.len() >= 3 {
        let n = usize::from(u16::from_le_bytes([rest[0], rest[1]])).min(rest.len() - 3);
        let link = if rest[2] & 1 == 1 {
            LinkType::Ip
        } else {
            LinkType::Ethernet
        };
        let frame = &rest[3..3 + n];
        rest = &rest[3 + n..];
        pushed += 1;
        if d.push(frame, link, pushed * 666_667, &mut out) == TapEvent::Sample {
            samples += 1;
            assert_eq!(out.t_ns, pushed * 666_667, "a sample carries the time of its frame");
        }
    }
    let c = d.counters();
    assert_eq!(c.frames, pushed);
    assert_eq!(c.samples, samples);
});
