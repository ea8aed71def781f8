//! [`SimLink`]: the emulator as an in-process `dvrk_io` [`Link`], so that `EthPort<SimLink>`
//! ([`SimPort`]) is a real `Port` exercising dvrk-io's request building and reply validation.
//!
//! A sent datagram is handled at once; its reply (if any) waits in a small queue for `recv`, like
//! a socket buffer. `recv` with nothing queued is a timeout, immediately (no waiting).
//! Time does not pass by itself: call [`SimLink::advance_to`] (or
//! `port.link_mut().advance_to(t_ns)`) with the caller's clock before reading.

use dvrk_io::{EthPort, IoConfig, Link, PortError};

use crate::SimError;
use crate::emulator::{Emulator, MAX_REPLY_BYTES};
use crate::scenario::Scenario;

/// `EthPort` over the in-process emulator.
pub type SimPort = EthPort<SimLink>;

/// Replies held between `send` and `recv`.
const QUEUE: usize = 4;

/// In-process datagram link to an [`Emulator`]. Allocates only at construction.
pub struct SimLink {
    emu: Emulator,
    bufs: Box<[[u8; MAX_REPLY_BYTES]; QUEUE]>,
    lens: [usize; QUEUE],
    head: usize,
    queued: usize,
    overflowed: u64,
}

impl SimLink {
    pub fn new(emu: Emulator) -> Self {
        Self {
            emu,
            bufs: Box::new([[0; MAX_REPLY_BYTES]; QUEUE]),
            lens: [0; QUEUE],
            head: 0,
            queued: 0,
            overflowed: 0,
        }
    }

    pub fn emulator(&self) -> &Emulator {
        &self.emu
    }

    pub fn emulator_mut(&mut self) -> &mut Emulator {
        &mut self.emu
    }

    pub fn into_emulator(self) -> Emulator {
        self.emu
    }

    /// Step the physics up to host time `t_ns` ([`Emulator::advance_to`]).
    pub fn advance_to(&mut self, t_ns: u64) {
        self.emu.advance_to(t_ns);
    }

    /// Replies discarded because the queue was full (the caller sent without receiving).
    pub fn overflowed(&self) -> u64 {
        self.overflowed
    }
}

impl Link for SimLink {
    fn send(&mut self, _dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        if self.queued == QUEUE {
            // Like a full socket buffer: the oldest reply is lost.
            self.head = (self.head + 1) % QUEUE;
            self.queued -= 1;
            self.overflowed += 1;
        }
        let slot = (self.head + self.queued) % QUEUE;
        if let Some(n) = self.emu.handle(datagram, &mut self.bufs[slot]) {
            self.lens[slot] = n;
            self.queued += 1;
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        if self.queued == 0 {
            return Err(PortError::LINK_TIMEOUT);
        }
        let slot = self.head;
        self.head = (self.head + 1) % QUEUE;
        self.queued -= 1;
        let n = self.lens[slot].min(buf.len());
        buf[..n].copy_from_slice(&self.bufs[slot][..n]);
        Ok(n)
    }
}

/// An in-process [`SimPort`] for `scenario`, its bits converted through `io`.
pub fn sim_port(scenario: &Scenario, io: &IoConfig) -> Result<SimPort, SimError> {
    Ok(EthPort::new(SimLink::new(Emulator::new(scenario, io)?)))
}
