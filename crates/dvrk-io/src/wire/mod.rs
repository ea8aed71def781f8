//! Checked views and emitters for the controller-board protocol (smoltcp style).
//!
//! Every view (`Packet`, `FeedbackBlock`, `HubView`, ...) is built with `new_checked`, which
//! validates the length once; after that no accessor can panic, whatever the bytes are. Every
//! packet kind also has an emitter (`*Repr::emit`, block setters) so that the board emulator in
//! dvrk-sim builds its replies with the same code that parses them here.
//!
//! Quadlets are 32-bit big-endian on the wire (reference, conventions).
//!
//! - [`firewire`]: asynchronous FireWire requests and responses (reference §1.1, §3.1).
//! - [`eth`]: the 2-byte control word before a request and the 8 bytes of extra data after a
//!   response when the FireWire packet travels in a UDP datagram (reference §3.1).
//! - [`block`]: the real-time feedback block of one board and its field decoders (reference §2).
//! - [`hub`]: the hub memory read after a broadcast query (reference §3.4).
//! - [`crc32_bzip2`]: the FireWire CRC-32 (reference §9).

mod crc;

pub mod block;
pub mod eth;
pub mod firewire;
pub mod hub;

pub use block::{
    Adc, BlockLayout, BoardKind, BoardStatus, DigitalIo, EncoderPeriod, EncoderPosition,
    FeedbackBlock, MotorStatus, Quarter, Temperature, Timestamp,
};
pub use crc::crc32_bzip2;
pub use eth::{ControlWord, EthReply, EthRequest, ExtraData};
pub use firewire::{Packet, RequestKind, RequestRepr, ResponseKind, ResponseRepr, Tcode};
pub use hub::{HubHeader, HubLayout, HubView};

/// Errors of the pure wire layer. `Copy`, numbers only: it is returned on the per-cycle path.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WireError {
    /// Fewer bytes than the packet or block needs.
    #[error("truncated: {got} bytes, need {need}")]
    Truncated { got: usize, need: usize },
    /// A transaction code this protocol does not use (reference §1.1 table).
    #[error("unknown FireWire tcode {tcode}")]
    UnknownTcode { tcode: u8 },
    /// A response where a request was expected, or the reverse.
    #[error("tcode {tcode} is not valid here")]
    UnexpectedTcode { tcode: u8 },
    /// An axis, motor or board index past the end of the layout.
    #[error("index {index} out of range (count {count})")]
    IndexOutOfRange { index: usize, count: usize },
    /// Firmware version without a known feedback-block layout (Rev 7, 8 and 9 are supported).
    #[error("firmware version {firmware} is not supported (Rev 7, 8, 9 are)")]
    UnsupportedFirmware { firmware: u32 },
    /// Hardware-version register value that is not QLA1, DQLA or dRA1 (reference §1.1).
    #[error("unknown hardware version 0x{hardware:08x}")]
    UnknownHardware { hardware: u32 },
    /// The board kind does not exist with this firmware (DQLA and dRAC need Rev 8+, §2.1).
    #[error("board kind {kind:?} has no layout for firmware {firmware}")]
    UnsupportedLayout { firmware: u32, kind: BoardKind },
    /// The output buffer cannot hold what is being emitted.
    #[error("buffer too small: {got} bytes, need {need}")]
    BufferTooSmall { got: usize, need: usize },
    /// Payload length does not match the length in the header being emitted.
    #[error("payload length {got} does not match header length {expected}")]
    PayloadLength { got: usize, expected: usize },
    /// A block longer than the 16-bit FireWire data-length field, or the hub's 16 boards.
    #[error("length {len} exceeds the maximum {max}")]
    TooLong { len: usize, max: usize },
    /// A hub header whose block size disagrees with the layout (reference §3.4).
    #[error("hub slot {index}: header says {got} quadlets, layout needs {expected}")]
    HubBlockSize {
        index: usize,
        got: u32,
        expected: u32,
    },
}

/// Reads a big-endian quadlet at byte `off`; 0 if out of range (never reached after a checked
/// constructor, but keeps the accessors panic-free by construction).
#[inline(always)]
pub(crate) fn get_be32(buf: &[u8], off: usize) -> u32 {
    match buf.get(off..off.wrapping_add(4)) {
        Some(&[a, b, c, d]) => u32::from_be_bytes([a, b, c, d]),
        _ => 0,
    }
}

/// Writes a big-endian quadlet at byte `off`; does nothing when out of range.
#[inline(always)]
pub(crate) fn put_be32(buf: &mut [u8], off: usize, v: u32) {
    if let Some(s) = buf.get_mut(off..off.wrapping_add(4)) {
        s.copy_from_slice(&v.to_be_bytes());
    }
}

/// Rounds a byte count up to whole quadlets.
#[inline]
pub(crate) const fn pad4(n: usize) -> usize {
    (n + 3) & !3
}
