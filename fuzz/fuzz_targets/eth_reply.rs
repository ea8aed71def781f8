//! The response path of the Ethernet engine: reply parsing and validation, and the feedback
//! block view of whatever block data comes back. Nothing may panic.
#![no_main]

use dvrk_io::port::{EthPort, Link, Port, PortError};
use dvrk_io::wire::{
    BlockLayout, BoardKind, EthReply, FeedbackBlock, HubLayout, HubView, ResponseRepr,
};
use libfuzzer_sys::fuzz_target;

struct Canned<'a>(&'a [u8]);

impl Link for Canned<'_> {
    fn send(&mut self, _: u8, _: &[u8]) -> Result<(), PortError> {
        Ok(())
    }
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        let n = self.0.len().min(buf.len());
        buf[..n].copy_from_slice(&self.0[..n]);
        Ok(n)
    }
}

fuzz_target!(|data: &[u8]| {
    if let Ok(r) = EthReply::parse(data)
        && let Some(p) = r.packet
    {
        let _ = ResponseRepr::parse(&p);
        let _ = (
            p.payload(),
            p.computed_header_crc(),
            p.computed_data_crc(),
            r.extra.packet_dropped(),
        );
    }
    let mut port = EthPort::new(Canned(data));
    let _ = port.read_quadlet(6, 0);
    let mut blk = [0u8; 128];
    if port.read_block(6, 0, &mut blk).is_ok()
        && let Ok(l) = BlockLayout::new(8, BoardKind::Qla)
        && let Ok(b) = FeedbackBlock::new_checked(&blk[..], l)
    {
        for i in 0..5 {
            let _ = (
                b.adc(i),
                b.encoder_position(i),
                b.encoder_period(i),
                b.motor_status(i),
            );
        }
    }
    for fw in 7..=9 {
        for kind in [BoardKind::Qla, BoardKind::Dqla, BoardKind::Drac] {
            if let Ok(l) = BlockLayout::new(fw, kind)
                && let Ok(h) = HubLayout::new(&[(6, l), (7, l)])
                && let Ok(v) = HubView::new_checked(data, h)
            {
                let _ = (v.block(0), v.block(1), v.timing());
            }
        }
    }
});
