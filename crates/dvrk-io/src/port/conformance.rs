//! A generic conformance check any [`Port`] implementation (UDP, FireWire, dvrk-sim's
//! in-process port, replay) can be run against from tests, written once as iceoryx2 writes its
//! conformance tests once per service.
//!
//! It uses only quadlet reads unless `allow_block_read` is set (a block read of address 0 takes a
//! new sample on real boards, reference §8).

use super::{Port, PortError, reg};
use crate::wire::{BlockLayout, BoardKind, BoardStatus, FeedbackBlock};

/// What to check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConformanceOptions {
    pub board: u8,
    /// Also block-read address 0 and compare it with the quadlet registers.
    pub allow_block_read: bool,
    /// A board id with nothing behind it, which must give an error (not a panic, not data).
    pub absent_board: Option<u8>,
}

/// What the port reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConformanceReport {
    pub kind: BoardKind,
    pub firmware_version: u32,
    pub status: u32,
    pub layout: BlockLayout,
}

/// A failed check, with what was expected and found.
#[derive(Debug, thiserror::Error)]
#[error("port conformance: {check}: {detail}")]
pub struct ConformanceError {
    pub check: &'static str,
    pub detail: String,
}

fn fail(check: &'static str, detail: impl Into<String>) -> ConformanceError {
    ConformanceError {
        check,
        detail: detail.into(),
    }
}

/// Runs the checks against `port`:
/// 1. hardware version is QLA1, DQLA or dRA1 and firmware is Rev 7–9;
/// 2. the status register's board id is the board asked for;
/// 3. every encoder-position and ADC channel register of the layout answers;
/// 4. a block of 0 bytes, or not a multiple of 4, is refused with `BlockSize`, without traffic
///    results leaking into the next read (the next quadlet read still returns the right value);
/// 5. optionally, a block read of address 0 has the layout's size and the same board id;
/// 6. optionally, an absent board gives an error.
pub fn check_port<P: Port>(
    port: &mut P,
    opts: ConformanceOptions,
) -> Result<ConformanceReport, ConformanceError> {
    let b = opts.board;
    let hw = port
        .read_quadlet(b, reg::HARDWARE_VERSION)
        .map_err(|e| fail("hardware version", e.to_string()))?;
    let kind = BoardKind::from_hardware_version(hw)
        .map_err(|e| fail("hardware version", e.to_string()))?;
    let fw = port
        .read_quadlet(b, reg::FIRMWARE_VERSION)
        .map_err(|e| fail("firmware version", e.to_string()))?;
    let layout = BlockLayout::new(fw, kind).map_err(|e| fail("firmware version", e.to_string()))?;
    let status = port
        .read_quadlet(b, reg::STATUS)
        .map_err(|e| fail("status", e.to_string()))?;
    let id = BoardStatus::new(status, kind).board_id();
    if id != b {
        return Err(fail(
            "status board id",
            format!("asked board {b}, status says {id}"),
        ));
    }
    for axis in 0..layout.num_encoders().min(layout.num_motors()) {
        let ch = ((axis as u16) + 1) << 4;
        port.read_quadlet(b, ch | 5)
            .map_err(|e| fail("encoder position register", format!("axis {axis}: {e}")))?;
        port.read_quadlet(b, ch)
            .map_err(|e| fail("ADC register", format!("axis {axis}: {e}")))?;
    }
    for len in [0usize, 6] {
        let mut buf = [0u8; 8];
        match port.read_block(b, 0, &mut buf[..len]) {
            Err(PortError::BlockSize { .. }) => {}
            other => {
                return Err(fail(
                    "block size check",
                    format!("{len}-byte block read gave {other:?}, expected BlockSize"),
                ));
            }
        }
    }
    let again = port
        .read_quadlet(b, reg::HARDWARE_VERSION)
        .map_err(|e| fail("read after refused block", e.to_string()))?;
    if again != hw {
        return Err(fail(
            "read after refused block",
            format!("hardware version 0x{again:08x}, first read 0x{hw:08x}"),
        ));
    }
    if opts.allow_block_read {
        let mut buf = [0u8; 256];
        let n = layout.len_bytes();
        let blk = buf
            .get_mut(..n)
            .ok_or_else(|| fail("block read", "layout larger than 256 bytes"))?;
        port.read_block(b, 0, blk)
            .map_err(|e| fail("block read", e.to_string()))?;
        let view = FeedbackBlock::new_checked(&*blk, layout)
            .map_err(|e| fail("block read", e.to_string()))?;
        if view.status().board_id() != b {
            return Err(fail(
                "block status board id",
                format!("asked board {b}, block says {}", view.status().board_id()),
            ));
        }
    }
    if let Some(absent) = opts.absent_board
        && let Ok(v) = port.read_quadlet(absent, reg::HARDWARE_VERSION)
    {
        return Err(fail(
            "absent board",
            format!("board {absent} answered 0x{v:08x}"),
        ));
    }
    Ok(ConformanceReport {
        kind,
        firmware_version: fw,
        status,
        layout,
    })
}
