//! The board emulator's network input (`dvrk-sidecar sim` answers whoever sends it UDP): host
//! requests parsed by `EthRequest`/`RequestRepr` and answered by `Emulator::handle`. The input
//! is a sequence of datagrams, each prefixed by its length (one byte), so that writes can change
//! what later reads see. Each datagram is sent as it is, and, when it parses, once more as
//! re-emitted by the request emitter (valid CRCs, so the request reaches the emulator's logic).
//! Checks: the request emitter round-trips, and every reply is a well-formed response to the
//! request's label with correct CRCs (what the host's CRC check relies on).
#![no_main]

#[path = "common.rs"]
mod common;

use std::sync::OnceLock;

use dvrk_io::wire::{EthReply, EthRequest, RequestKind, RequestRepr, ResponseRepr};
use dvrk_sim::Emulator;
use libfuzzer_sys::fuzz_target;

fn emulator() -> &'static Emulator {
    static E: OnceLock<Emulator> = OnceLock::new();
    E.get_or_init(|| {
        let repo = common::repo();
        let scenario = dvrk_sidecar::config::load_scenario(&repo.join("config/sim/idle.toml"))
            .expect("config/sim/idle.toml loads");
        let io = dvrk_sidecar::config::load_io(&repo.join("config/io/psm-classic.toml"))
            .expect("config/io/psm-classic.toml loads");
        Emulator::new(&scenario, &io).expect("the emulator starts")
    })
}

fn send(emu: &mut Emulator, datagram: &[u8], label: Option<u8>) {
    let mut reply = [0u8; 2048];
    let Some(n) = emu.handle(datagram, &mut reply) else {
        return;
    };
    assert!(n <= reply.len());
    let r = EthReply::parse(&reply[..n]).expect("the emulator's reply parses");
    assert_eq!(
        r.excess, 0,
        "no bytes between the response and the extra data"
    );
    let Some(p) = r.packet else {
        return;
    };
    let resp = ResponseRepr::parse(&p).expect("the emulator answers with a response");
    if let Some(l) = label {
        assert_eq!(resp.label, l, "the reply carries the request's label");
    }
    assert_eq!(p.header_crc(), p.computed_header_crc(), "reply header CRC");
    if !p.payload().is_empty() {
        assert_eq!(p.data_crc(), p.computed_data_crc(), "reply data CRC");
    }
}

fuzz_target!(|data: &[u8]| {
    let mut emu = emulator().clone();
    let mut rest = data;
    let mut t_ns = 1_000_000_000u64;
    emu.advance_to(t_ns);
    while let Some((&len, tail)) = rest.split_first() {
        let (dgram, tail) = tail.split_at(usize::from(len).min(tail.len()));
        rest = tail;
        t_ns += 700_000;
        emu.advance_to(t_ns);
        send(&mut emu, dgram, None);

        let Ok(req) = EthRequest::parse(dgram) else {
            continue;
        };
        let Ok(repr) = RequestRepr::parse(&req.packet) else {
            continue;
        };
        let payload = match repr.kind {
            RequestKind::BlockWrite { len } => {
                let p = req.packet.payload();
                &p[..usize::from(len).min(p.len())]
            }
            _ => &[][..],
        };
        let mut buf = [0u8; 2048];
        let Ok(n) = EthRequest::emit(&mut buf, req.control, &repr, payload) else {
            continue;
        };
        let again = EthRequest::parse(&buf[..n]).expect("an emitted request parses");
        assert_eq!(again.control, req.control);
        assert_eq!(RequestRepr::parse(&again.packet).ok(), Some(repr));
        assert_eq!(again.packet.payload(), payload);
        assert_eq!(again.trailing(), 0);
        send(&mut emu, &buf[..n], Some(repr.label));
    }
});
