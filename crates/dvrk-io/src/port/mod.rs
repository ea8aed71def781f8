//! Ports: how bytes reach the boards.
//!
//! - [`Port`]: the read-only interface the reader uses (quadlet read, block read, broadcast
//!   query plus hub read). Writes are not on it.
//! - [`Link`]: one datagram transport. [`EthPort`] is the Ethernet protocol engine (request
//!   building, transaction labels, reply validation, counters) over any link: [`UdpLink`] (a
//!   real UDP socket), dvrk-sim's in-process emulator, [`ReplayLink`] (recorded frames) or a
//!   [`FaultInjector`].
//! - [`WriteAccess`]: the write capability, reachable only through [`EthPort::allow_writes`],
//!   because any accepted register write refreshes the boards' watchdog (reference §4, §8).
//! - `FirewirePort` (feature `firewire`): libraw1394 through FFI, same wire module.

mod discovery;
mod eth;
mod fault;
#[cfg(feature = "firewire")]
pub mod firewire;
mod replay;
mod udp;

pub mod conformance;

pub use discovery::{BoardInfo, BoardProbe, Discovery, EthMode, FpgaGeneration, reg, scan_boards};
pub use eth::{
    DEFAULT_QUADLET_WINDOW, EthCounters, EthPort, MAX_QUADLET_WINDOW, MAX_READ_BYTES,
    MAX_WRITE_BYTES, MIN_RETRY_WAIT, WriteAccess,
};
pub use fault::{FaultConfig, FaultCounters, FaultInjector};
#[cfg(feature = "firewire")]
pub use firewire::{FirewirePort, FirewireWriteAccess};
pub use replay::{
    Frame, FramesParseError, RecordingLink, ReplayLink, ReplayPort, frames_from_text,
    frames_to_text,
};
pub use udp::{
    DEFAULT_BOARD_IP, DEFAULT_TIMEOUT, FPGA_UDP_PORT, MAX_QUADLET_ATTEMPTS, QUADLET_RETRY_WAIT,
    UdpLink, UdpPort, UdpTarget,
};

use crate::wire::WireError;

/// Board value used in errors that a [`Link`] reports before the protocol engine knows which
/// board the datagram belonged to.
pub const UNKNOWN_BOARD: u8 = 0xFF;

/// Read-only access to the boards. Implementations: [`EthPort`] (UDP, in-process emulator,
/// replay), `FirewirePort`, [`FaultInjector`].
pub trait Port {
    /// Quadlet read of `addr` on `board` (board id 0–15).
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, PortError>;
    /// Block read of `out.len()` bytes (a multiple of 4) starting at `addr` on `board`.
    /// A block read of address 0 takes a new sample and resets the board timestamp (§8).
    fn read_block(&mut self, board: u8, addr: u16, out: &mut [u8]) -> Result<(), PortError>;
    /// Broadcast-read query for the boards in `board_mask` (a write of the query register,
    /// which refreshes the watchdog, §4/§8), then a block read of the hub memory into `out`
    /// (reference §3.4). Implementations refuse it unless explicitly enabled.
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), PortError>;
    /// Quadlet reads of several registers, `reqs[i]` = (board, addr) into `out[i]` (`None`: not
    /// read; entries of `out` beyond `reqs` are left alone). Once a read of a board fails, the
    /// board's later entries are not asked (it stopped answering). Ok when every entry was
    /// read, else the first error. The default reads them in turn ([`read_quadlets_in_turn`]);
    /// [`EthPort`] over a lossy link keeps a few requests outstanding at once
    /// ([`EthPort::set_quadlet_window`]).
    fn read_quadlets(
        &mut self,
        reqs: &[(u8, u16)],
        out: &mut [Option<u32>],
    ) -> Result<(), PortError> {
        read_quadlets_in_turn(self, reqs, out)
    }
}

/// [`Port::read_quadlets`] one request after the other through [`Port::read_quadlet`].
pub fn read_quadlets_in_turn<P: Port + ?Sized>(
    port: &mut P,
    reqs: &[(u8, u16)],
    out: &mut [Option<u32>],
) -> Result<(), PortError> {
    let mut first_err = None;
    // Boards (bit = id) whose read failed in this batch.
    let mut failed = 0u32;
    for (&(board, addr), o) in reqs.iter().zip(out.iter_mut()) {
        *o = None;
        let bit = 1u32.checked_shl(u32::from(board)).unwrap_or(0);
        if failed & bit != 0 {
            continue;
        }
        match port.read_quadlet(board, addr) {
            Ok(v) => *o = Some(v),
            Err(e) => {
                failed |= bit;
                first_err.get_or_insert(e);
            }
        }
    }
    match first_err {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl<P: Port + ?Sized> Port for &mut P {
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, PortError> {
        (**self).read_quadlet(board, addr)
    }
    fn read_block(&mut self, board: u8, addr: u16, out: &mut [u8]) -> Result<(), PortError> {
        (**self).read_block(board, addr, out)
    }
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), PortError> {
        (**self).broadcast_query_hub_read(board_mask, out)
    }
    fn read_quadlets(
        &mut self,
        reqs: &[(u8, u16)],
        out: &mut [Option<u32>],
    ) -> Result<(), PortError> {
        (**self).read_quadlets(reqs, out)
    }
}

/// One datagram transport under [`EthPort`], so the UDP socket and dvrk-sim's in-process
/// emulator share all request building and reply validation code.
pub trait Link {
    /// Sends one request datagram (control word + FireWire request) meant for `dest_node`
    /// (0x3F = broadcast).
    fn send(&mut self, dest_node: u8, datagram: &[u8]) -> Result<(), PortError>;
    /// Receives one reply datagram into `buf`; `Err(PortError::Timeout { .. })` when nothing
    /// arrives in time (board [`UNKNOWN_BOARD`]; the engine fills in board and address).
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError>;
    /// Throws away every datagram already queued, without waiting, using `buf` as scratch;
    /// returns how many. Called by the engine before a request after a timeout or an
    /// unexpected reply, so late replies cannot pile up. Links that cannot hold a late reply
    /// (a synchronous in-process emulator) keep the default, which does nothing.
    fn discard_pending(&mut self, buf: &mut [u8]) -> usize {
        let _ = buf;
        0
    }
    /// Receives like [`Link::recv`], but waits at most `wait` (the quadlet retry of
    /// [`EthPort`]). The default waits the link's own timeout.
    fn recv_within(
        &mut self,
        buf: &mut [u8],
        wait: std::time::Duration,
    ) -> Result<usize, PortError> {
        let _ = wait;
        self.recv(buf)
    }
    /// How [`EthPort`] asks again for a quadlet whose request or reply was lost; `None` (the
    /// default, for links that cannot lose a datagram or replay a recording): one request per
    /// quadlet read, waiting the link's timeout.
    fn quadlet_retry(&self) -> Option<QuadletRetry> {
        None
    }
}

/// The quadlet retry of a lossy link (UDP): a quadlet read waits `wait` for its reply, then asks
/// again, `attempts` requests in all, the last one waiting the link's whole timeout; a reply to
/// any of them is taken (they read the same register, so each is as fresh as the others). A
/// datagram lost at 1.5 kHz then costs `wait`, not the whole reply timeout and so the cycle
/// (issue 22). In a batch of quadlet reads ([`Port::read_quadlets`]) each register waits at
/// most `reply_timeout` from its first request, and the retry wait follows the measured round
/// trip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QuadletRetry {
    pub wait: std::time::Duration,
    pub attempts: u8,
    /// The link's whole reply timeout.
    pub reply_timeout: std::time::Duration,
    /// Every reply comes from one FPGA (a single board, or the hub that forwards to the others),
    /// which serves one packet at a time (reference §8.4): replies come in the order of the
    /// requests whatever node they name. False when each board answers on its own (Rev 9
    /// per-board addresses): only one board's replies are in order.
    pub one_server: bool,
}

impl<L: Link + ?Sized> Link for &mut L {
    fn recv_within(
        &mut self,
        buf: &mut [u8],
        wait: std::time::Duration,
    ) -> Result<usize, PortError> {
        (**self).recv_within(buf, wait)
    }
    fn quadlet_retry(&self) -> Option<QuadletRetry> {
        (**self).quadlet_retry()
    }
    fn send(&mut self, dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        (**self).send(dest_node, datagram)
    }
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        (**self).recv(buf)
    }
    fn discard_pending(&mut self, buf: &mut [u8]) -> usize {
        (**self).discard_pending(buf)
    }
}

/// Errors of ports and links. `Copy`, numbers only: returned on the per-cycle path.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PortError {
    #[error("board {board}: no reply to address 0x{addr:04x} in time")]
    Timeout { board: u8, addr: u16 },
    #[error("board {board}: reply truncated, {got} bytes, need {need}")]
    Truncated { board: u8, got: usize, need: usize },
    #[error("board {board}: reply oversized, {got} bytes, expected {expected}")]
    Oversized {
        board: u8,
        got: usize,
        expected: usize,
    },
    #[error("board {board}: reply tcode {got}, expected {expected}")]
    WrongTcode { board: u8, expected: u8, got: u8 },
    #[error("board {board}: reply label {got}, expected {expected}")]
    WrongLabel { board: u8, expected: u8, got: u8 },
    #[error("board {board}: reply from node {got}, expected node {expected}")]
    WrongSource { board: u8, expected: u8, got: u8 },
    #[error("board {board}: block reply of {got} bytes, requested {expected}")]
    WrongLength { board: u8, expected: u16, got: u16 },
    #[error("board {board}: response code {rcode}")]
    ResponseCode { board: u8, rcode: u8 },
    #[error("board {board}: packet dropped by the FPGA (extra-data flags 0x{flags:02x})")]
    PacketDropped { board: u8, flags: u8 },
    #[error("board {board}: FireWire bus reset (FPGA bus generation {generation})")]
    BusReset { board: u8, generation: u8 },
    #[error("board {board}: FPGA internal error (extra-data flags 0x{flags:02x})")]
    InternalError { board: u8, flags: u8 },
    #[error("board {board}: reply CRC 0x{carried:08x}, computed 0x{computed:08x}")]
    CrcMismatch {
        board: u8,
        carried: u32,
        computed: u32,
    },
    #[error("board {board}: malformed reply: {error}")]
    Malformed { board: u8, error: WireError },
    #[error("block of {len} bytes not allowed (multiple of 4, at most {max})")]
    BlockSize { len: usize, max: usize },
    #[error("board id {board} out of range 0..=15")]
    BoardOutOfRange { board: u8 },
    #[error("board {board}: unknown hardware version 0x{hardware:08x}")]
    UnknownHardware { board: u8, hardware: u32 },
    #[error("board {board}: firmware version {firmware} not supported (Rev 7, 8, 9 are)")]
    UnsupportedFirmware { board: u8, firmware: u32 },
    #[error("board {board}: hardware is {got:?}, configuration expects {expected:?}")]
    HardwareMismatch {
        board: u8,
        expected: crate::wire::BoardKind,
        got: crate::wire::BoardKind,
    },
    #[error("board {board} missing: no reply at discovery")]
    BoardMissing { board: u8 },
    #[error("node {node}: status reports board id {got}, expected {expected}")]
    BoardIdMismatch { node: u8, expected: u8, got: u8 },
    #[error("broadcast query is a register write; enable it through allow_writes()")]
    QueryNotAllowed,
    #[error("socket error: {kind}")]
    Io { kind: std::io::ErrorKind },
    #[error("replay: request {index} does not match the recording")]
    ReplayMismatch { index: u32 },
    #[error("replay: recording exhausted after {frames} frames")]
    ReplayExhausted { frames: u32 },
    #[error("operation not supported by this port")]
    Unsupported,
}

impl PortError {
    /// Whether the error says the configuration does not match the hardware (a board of another
    /// kind, firmware or id, an id out of range, a block size the protocol cannot carry), so
    /// that asking again cannot help. Every other error (timeouts, missing boards, bad or
    /// dropped replies, socket errors) may pass.
    pub fn is_configuration(&self) -> bool {
        matches!(
            self,
            Self::UnknownHardware { .. }
                | Self::UnsupportedFirmware { .. }
                | Self::HardwareMismatch { .. }
                | Self::BoardIdMismatch { .. }
                | Self::BoardOutOfRange { .. }
                | Self::BlockSize { .. }
                | Self::QueryNotAllowed
                | Self::Unsupported
        )
    }

    /// The timeout a [`Link`] reports.
    pub const LINK_TIMEOUT: Self = Self::Timeout {
        board: UNKNOWN_BOARD,
        addr: 0,
    };
}

impl From<std::io::Error> for PortError {
    fn from(e: std::io::Error) -> Self {
        match e.kind() {
            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => Self::LINK_TIMEOUT,
            kind => Self::Io { kind },
        }
    }
}
