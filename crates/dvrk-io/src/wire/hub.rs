//! Hub memory after a broadcast query (reference §3.4): a block read of 0x1000 on the hub board.
//!
//! ```text
//! for each board in the query mask, in ascending board id:
//!     header quadlet: [31:24] block size (Nq + 1) | [23:16] sequence LSB | [15] sequence
//!                     mismatch | [14:0] update time
//!     that board's feedback block (Nq quadlets, §2)
//! then one timing quadlet: read start [31:16] | read finish [15:0]
//! total = Σ(Nq + 1) + 1 quadlets
//! ```
//! The host discards a board on a sequence error, a size mismatch or a zero status (§3.4).

use super::block::{BlockLayout, FeedbackBlock};
use super::{WireError, get_be32, put_be32};

/// Hub memory base address (reference §1.2: space 1, hub memory at 0x1000+i).
pub const HUB_ADDRESS: u16 = 0x1000;
/// Broadcast-read query register, Rev 7+ (reference §1.1, §3.4).
pub const QUERY_ADDRESS: u16 = 0x1800;
/// At most 16 boards (4-bit board id).
pub const MAX_HUB_BOARDS: usize = 16;

/// Header quadlet before each board's block.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HubHeader(pub u32);

impl HubHeader {
    pub const fn new(
        block_quadlets: u8,
        sequence: u16,
        sequence_mismatch: bool,
        update_time: u16,
    ) -> Self {
        let size = (block_quadlets as u32 + 1) & 0xFF;
        Self(
            (size << 24)
                | ((sequence as u32 & 0xFF) << 16)
                | ((sequence_mismatch as u32) << 15)
                | (update_time as u32 & 0x7FFF),
        )
    }
    /// Quadlets of this slot including the header (Nq + 1).
    pub const fn size_quadlets(self) -> u32 {
        self.0 >> 24
    }
    pub const fn sequence_lsb(self) -> u8 {
        (self.0 >> 16) as u8
    }
    pub const fn sequence_mismatch(self) -> bool {
        self.0 & (1 << 15) != 0
    }
    pub const fn update_time(self) -> u16 {
        (self.0 & 0x7FFF) as u16
    }
}

/// Where each board sits in the hub memory, computed once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HubLayout {
    count: u8,
    board_ids: [u8; MAX_HUB_BOARDS],
    layouts: [Option<BlockLayout>; MAX_HUB_BOARDS],
    /// Byte offset of each slot's header quadlet.
    offsets: [u16; MAX_HUB_BOARDS],
    len: u16,
}

impl HubLayout {
    /// `boards` = (board id, layout) in the order the hub stores them (ascending board id).
    pub fn new(boards: &[(u8, BlockLayout)]) -> Result<Self, WireError> {
        Self::from_boards(boards.iter().copied())
    }
    /// Same as [`HubLayout::new`] from an iterator (no allocation).
    pub fn from_boards(
        boards: impl IntoIterator<Item = (u8, BlockLayout)>,
    ) -> Result<Self, WireError> {
        let mut s = Self {
            count: 0,
            board_ids: [0; MAX_HUB_BOARDS],
            layouts: [None; MAX_HUB_BOARDS],
            offsets: [0; MAX_HUB_BOARDS],
            len: 0,
        };
        let mut off = 0usize;
        let mut count = 0usize;
        for (id, lay) in boards {
            if count == MAX_HUB_BOARDS {
                return Err(WireError::TooLong {
                    len: count + 1,
                    max: MAX_HUB_BOARDS,
                });
            }
            s.board_ids[count] = id;
            s.layouts[count] = Some(lay);
            s.offsets[count] = off as u16;
            off += 4 + lay.len_bytes();
            count += 1;
        }
        s.count = count as u8;
        s.len = (off + 4) as u16;
        Ok(s)
    }
    /// Mask of the boards (bit = board id), as written to the query register.
    pub fn board_mask(&self) -> u16 {
        self.board_ids[..self.count as usize]
            .iter()
            .fold(0u16, |m, id| m | (1u16 << (id & 0x0F)))
    }
    pub fn num_boards(&self) -> usize {
        self.count as usize
    }
    pub fn board_id(&self, i: usize) -> Option<u8> {
        if i < self.count as usize {
            self.board_ids.get(i).copied()
        } else {
            None
        }
    }
    pub fn len_bytes(&self) -> usize {
        self.len as usize
    }
    pub fn len_quadlets(&self) -> usize {
        self.len as usize / 4
    }
    fn slot(&self, i: usize) -> Option<(usize, BlockLayout)> {
        if i >= self.count as usize {
            return None;
        }
        match (self.offsets.get(i), self.layouts.get(i)) {
            (Some(o), Some(Some(l))) => Some((*o as usize, *l)),
            _ => None,
        }
    }
}

/// Checked view of hub memory.
#[derive(Clone, Copy, Debug)]
pub struct HubView<T: AsRef<[u8]>> {
    buf: T,
    lay: HubLayout,
}

impl<T: AsRef<[u8]>> HubView<T> {
    pub fn new_checked(buf: T, lay: HubLayout) -> Result<Self, WireError> {
        let (got, need) = (buf.as_ref().len(), lay.len_bytes());
        if got < need {
            return Err(WireError::Truncated { got, need });
        }
        Ok(Self { buf, lay })
    }
    pub fn layout(&self) -> HubLayout {
        self.lay
    }
    pub fn header(&self, i: usize) -> Option<HubHeader> {
        self.lay
            .slot(i)
            .map(|(o, _)| HubHeader(get_be32(self.buf.as_ref(), o)))
    }
    /// Slot `i`'s block, after checking its header's size against the layout.
    pub fn block(&self, i: usize) -> Result<FeedbackBlock<&[u8]>, WireError> {
        slot_block(self.buf.as_ref(), &self.lay, i)
    }
    /// Final timing quadlet: (read start, read finish) in ticks.
    pub fn timing(&self) -> (u16, u16) {
        let t = get_be32(self.buf.as_ref(), self.lay.len_bytes() - 4);
        ((t >> 16) as u16, t as u16)
    }
}

impl<'a> HubView<&'a [u8]> {
    /// Like [`HubView::block`], borrowing from the underlying buffer rather than the view.
    pub fn block_of(&self, i: usize) -> Result<FeedbackBlock<&'a [u8]>, WireError> {
        slot_block(self.buf, &self.lay, i)
    }
}

fn slot_block<'a>(
    buf: &'a [u8],
    lay: &HubLayout,
    i: usize,
) -> Result<FeedbackBlock<&'a [u8]>, WireError> {
    let Some((o, l)) = lay.slot(i) else {
        return Err(WireError::IndexOutOfRange {
            index: i,
            count: lay.num_boards(),
        });
    };
    let h = HubHeader(get_be32(buf, o));
    let expected = l.len_quadlets() as u32 + 1;
    if h.size_quadlets() != expected {
        return Err(WireError::HubBlockSize {
            index: i,
            got: h.size_quadlets(),
            expected,
        });
    }
    let b = buf.get(o + 4..o + 4 + l.len_bytes()).unwrap_or(&[]);
    FeedbackBlock::new_checked(b, l)
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> HubView<T> {
    pub fn set_header(&mut self, i: usize, h: HubHeader) -> Result<(), WireError> {
        let Some((o, _)) = self.lay.slot(i) else {
            return Err(WireError::IndexOutOfRange {
                index: i,
                count: self.lay.num_boards(),
            });
        };
        put_be32(self.buf.as_mut(), o, h.0);
        Ok(())
    }
    /// Mutable view of slot `i`'s block, to fill it with the block setters.
    pub fn block_mut(&mut self, i: usize) -> Result<FeedbackBlock<&mut [u8]>, WireError> {
        let count = self.lay.num_boards();
        let Some((o, l)) = self.lay.slot(i) else {
            return Err(WireError::IndexOutOfRange { index: i, count });
        };
        let b = self
            .buf
            .as_mut()
            .get_mut(o + 4..o + 4 + l.len_bytes())
            .unwrap_or(&mut []);
        FeedbackBlock::new_checked(b, l)
    }
    pub fn set_timing(&mut self, read_start: u16, read_finish: u16) {
        let off = self.lay.len_bytes() - 4;
        put_be32(
            self.buf.as_mut(),
            off,
            (u32::from(read_start) << 16) | u32::from(read_finish),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::super::block::BoardKind;
    use super::*;

    #[test]
    fn sizes_match_reference_3_4() {
        let l8 = BlockLayout::new(8, BoardKind::Qla).unwrap();
        let boards: Vec<(u8, BlockLayout)> = (0..8).map(|i| (i, l8)).collect();
        let h = HubLayout::new(&boards).unwrap();
        assert_eq!(h.len_quadlets(), 265);
        assert_eq!(h.len_bytes(), 1060);
        assert_eq!(h.board_mask(), 0x00FF);
        let l7 = BlockLayout::new(7, BoardKind::Qla).unwrap();
        let h7 = HubLayout::new(&[(6, l7), (7, l7)]).unwrap();
        assert_eq!(h7.len_quadlets(), 2 * 29 + 1);
        assert_eq!(h7.board_mask(), 0x00C0);
        assert!(HubLayout::new(&[(0, l8); 17]).is_err());
    }

    #[test]
    fn header_fields() {
        let h = HubHeader::new(32, 0x1234, true, 0x7ABC);
        assert_eq!(h.size_quadlets(), 33);
        assert_eq!(h.sequence_lsb(), 0x34);
        assert!(h.sequence_mismatch());
        assert_eq!(h.update_time(), 0x7ABC);
        assert_eq!(h.0, 0x2134_FABC);
    }

    #[test]
    fn build_and_read_back() {
        let l = BlockLayout::new(9, BoardKind::Qla).unwrap();
        let lay = HubLayout::new(&[(6, l), (7, l)]).unwrap();
        let mut buf = vec![0u8; lay.len_bytes()];
        let mut v = HubView::new_checked(&mut buf[..], lay).unwrap();
        for i in 0..2 {
            v.set_header(i, HubHeader::new(32, 5, false, 10)).unwrap();
            let mut b = v.block_mut(i).unwrap();
            b.set_status(0x0600_0000 + (i as u32) * 0x0100_0000);
        }
        v.set_timing(3, 40);
        assert!(v.set_header(2, HubHeader(0)).is_err());
        let v = HubView::new_checked(&buf[..], lay).unwrap();
        assert_eq!(v.block(1).unwrap().status().board_id(), 7);
        assert_eq!(v.timing(), (3, 40));
        assert_eq!(v.header(0).unwrap().sequence_lsb(), 5);
        let mut bad = buf.clone();
        bad[0] = 30;
        let v = HubView::new_checked(&bad[..], lay).unwrap();
        assert_eq!(
            v.block(0).unwrap_err(),
            WireError::HubBlockSize {
                index: 0,
                got: 30,
                expected: 33
            }
        );
        assert!(HubView::new_checked(&buf[..100], lay).is_err());
    }
}
