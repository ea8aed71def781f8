//! [`FaultInjector`]: a seeded test double that drops, corrupts and delays traffic and changes
//! the FireWire bus generation, around a [`Link`] (datagram level, exercising the protocol
//! engine's validation) or a [`Port`] (value level). smoltcp's `phy::FaultInjector` is the model.

use super::{Link, Port, PortError};
use crate::wire::eth::{EXTRA_LEN, extra_flags};

/// Probabilities (0..=1) per request, and the seed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FaultConfig {
    pub seed: u64,
    /// Link: the request is not delivered. Port: `Timeout`.
    pub drop_chance: f64,
    /// Link: one bit of the reply datagram is flipped. Port: one bit of the returned data.
    pub corrupt_chance: f64,
    /// Link: the reply is held back and delivered at the next receive (it arrives late, with
    /// an old label). Port: `Timeout`.
    pub delay_chance: f64,
    /// Link: the FPGA bus generation of this and every later reply is incremented and this
    /// reply carries the bus-reset flag. Port: `BusReset`.
    pub generation_change_chance: f64,
}

/// What was injected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultCounters {
    pub dropped: u64,
    pub corrupted: u64,
    pub delayed: u64,
    pub generation_changes: u64,
}

/// Seeded fault injection around a link or a port.
pub struct FaultInjector<T> {
    inner: T,
    cfg: FaultConfig,
    rng: u64,
    counters: FaultCounters,
    held: Box<[u8; 4096]>,
    held_len: Option<usize>,
    generation_offset: u8,
}

impl<T> FaultInjector<T> {
    /// Allocates its hold buffer here.
    pub fn new(inner: T, cfg: FaultConfig) -> Self {
        Self {
            inner,
            cfg,
            rng: cfg.seed ^ 0x9E37_79B9_7F4A_7C15,
            counters: FaultCounters::default(),
            held: Box::new([0; 4096]),
            held_len: None,
            generation_offset: 0,
        }
    }
    pub fn inner_mut(&mut self) -> &mut T {
        &mut self.inner
    }
    pub fn into_inner(self) -> T {
        self.inner
    }
    pub fn counters(&self) -> FaultCounters {
        self.counters
    }
    pub fn set_config(&mut self, cfg: FaultConfig) {
        self.cfg = cfg;
    }
    /// splitmix64
    fn next_u64(&mut self) -> u64 {
        self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64) < p
    }
    fn flip_bit(&mut self, data: &mut [u8]) {
        if data.is_empty() {
            return;
        }
        let r = self.next_u64();
        let i = (r % data.len() as u64) as usize;
        if let Some(b) = data.get_mut(i) {
            *b ^= 1 << ((r >> 32) % 8);
        }
        self.counters.corrupted += 1;
    }
}

impl<T: Link> Link for FaultInjector<T> {
    fn send(&mut self, dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        if self.chance(self.cfg.drop_chance) {
            self.counters.dropped += 1;
            return Ok(());
        }
        self.inner.send(dest_node, datagram)
    }

    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        if let Some(n) = self.held_len.take() {
            let n = n.min(buf.len());
            buf[..n].copy_from_slice(&self.held[..n]);
            return Ok(n);
        }
        let n = self.inner.recv(buf)?;
        let Some(d) = buf.get_mut(..n) else {
            return Ok(n);
        };
        if self.chance(self.cfg.generation_change_chance) {
            self.generation_offset = self.generation_offset.wrapping_add(1);
            self.counters.generation_changes += 1;
            if let Some(f) = n.checked_sub(EXTRA_LEN).and_then(|o| d.get_mut(o)) {
                *f |= extra_flags::BUS_RESET;
            }
        }
        if self.generation_offset != 0
            && let Some(g) = n.checked_sub(EXTRA_LEN - 1).and_then(|o| d.get_mut(o))
        {
            *g = g.wrapping_add(self.generation_offset);
        }
        if self.chance(self.cfg.corrupt_chance) {
            self.flip_bit(&mut buf[..n]);
        }
        if self.chance(self.cfg.delay_chance) && n <= self.held.len() {
            self.held[..n].copy_from_slice(&buf[..n]);
            self.held_len = Some(n);
            self.counters.delayed += 1;
            return Err(PortError::LINK_TIMEOUT);
        }
        Ok(n)
    }

    fn discard_pending(&mut self, buf: &mut [u8]) -> usize {
        // A held (late) reply counts as queued: it has "arrived".
        let held = usize::from(self.held_len.take().is_some());
        held + self.inner.discard_pending(buf)
    }
}

impl<T: Port> FaultInjector<T> {
    fn port_fault(&mut self, board: u8, addr: u16) -> Result<(), PortError> {
        if self.chance(self.cfg.drop_chance) {
            self.counters.dropped += 1;
            return Err(PortError::Timeout { board, addr });
        }
        if self.chance(self.cfg.delay_chance) {
            self.counters.delayed += 1;
            return Err(PortError::Timeout { board, addr });
        }
        if self.chance(self.cfg.generation_change_chance) {
            self.generation_offset = self.generation_offset.wrapping_add(1);
            self.counters.generation_changes += 1;
            return Err(PortError::BusReset {
                board,
                generation: self.generation_offset,
            });
        }
        Ok(())
    }
}

impl<T: Port> Port for FaultInjector<T> {
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, PortError> {
        self.port_fault(board, addr)?;
        let v = self.inner.read_quadlet(board, addr)?;
        if self.chance(self.cfg.corrupt_chance) {
            let mut b = v.to_be_bytes();
            self.flip_bit(&mut b);
            return Ok(u32::from_be_bytes(b));
        }
        Ok(v)
    }
    fn read_block(&mut self, board: u8, addr: u16, out: &mut [u8]) -> Result<(), PortError> {
        self.port_fault(board, addr)?;
        self.inner.read_block(board, addr, out)?;
        if self.chance(self.cfg.corrupt_chance) {
            self.flip_bit(out);
        }
        Ok(())
    }
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), PortError> {
        self.port_fault(super::UNKNOWN_BOARD, crate::wire::hub::HUB_ADDRESS)?;
        self.inner.broadcast_query_hub_read(board_mask, out)?;
        if self.chance(self.cfg.corrupt_chance) {
            self.flip_bit(out);
        }
        Ok(())
    }
}
