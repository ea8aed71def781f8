//! The passive tap: turns captured frames of the console's own traffic with the boards into
//! [`ArmSample`]s, sending nothing (reference §3.1, §3.4, §8).
//!
//! [`TapDecoder::push`] takes one captured frame (bytes, [`LinkType`]) and the caller's time.
//! It pairs each host request with the boards' reply by host address, transaction label and
//! node, and takes a reply only from the address the request was sent to (a board's address
//! and port; for a broadcast request, a board's port on that broadcast's subnet), so a datagram
//! from another local port or address is never a board's reply. It decodes the feedback blocks the console read, whichever read protocol it uses
//! (§3.4):
//! - `sequential-read-*`: one block read of address 0 per board; a sample is complete when
//!   every board of the arm has been read once since the previous sample, by requests between
//!   the same two writes of the console's (it reads every board, then writes);
//! - `broadcast-query-read-write` in bridge mode: a query write to 0x1800 at node 0x3F, then a
//!   block read of the hub memory at 0x1000;
//! - the Ethernet-only broadcast read (Rev 9, FPGA V3): the same query write, and the hub's
//!   block response arrives unasked, carrying the query's label; the boards' blocks may be in
//!   any order, so each is identified by the board id in its status quadlet.
//!
//! Pure: no socket, no clock, no allocation after [`TapDecoder::new`]. A frame that is not a
//! board transaction is a [`Skip`] (counted), never an error or a panic.

mod frame;

pub use frame::{Datagram, LinkType, Skip, emit_frame, parse_frame};

use std::net::SocketAddrV4;

use crate::convert::{ActuatorState, ArmSample, IoConfig, MAX_BOARDS, NUM_JOINTS, decode_blocks};
use crate::wire::firewire::BROADCAST_NODE;
use crate::wire::hub::{HUB_ADDRESS, HubHeader, QUERY_ADDRESS};
use crate::wire::{
    BlockLayout, BoardStatus, EthReply, EthRequest, FeedbackBlock, RequestKind, RequestRepr,
    ResponseKind, ResponseRepr,
};

/// The boards' UDP port (reference §3.1).
pub const BOARD_PORT: u16 = 1394;
/// Largest feedback block (DQLA, 60 quadlets, reference §2.1).
const BLOCK_CAP: usize = 60 * 4;
/// Outstanding requests remembered (per host address and label; a console has at most a few).
const PENDING: usize = 64;

/// What a pending request asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Asked {
    /// Block read of the feedback block (address 0).
    Feedback,
    /// Block read of hub memory (0x1000).
    Hub,
    /// Broadcast query write (0x1800): in Ethernet-only mode the hub answers it with its data.
    Query { seq: u16 },
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    host: SocketAddrV4,
    /// Where the request went: the reply must come from there.
    board: SocketAddrV4,
    label: u8,
    node: u8,
    asked: Asked,
    /// The host's writes seen before this request (see [`TapDecoder::writes`]).
    cycle: u64,
}

/// Counters for the shell's summaries and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TapCounters {
    pub frames: u64,
    /// Board requests seen (any kind, from any host).
    pub requests: u64,
    /// Board replies seen.
    pub replies: u64,
    /// Replies paired with a request.
    pub paired: u64,
    /// Feedback blocks taken from sequential block reads.
    pub feedback_blocks: u64,
    /// Hub data blocks (read at 0x1000 or sent unasked after a query).
    pub hub_blocks: u64,
    /// Hub replies after a query (Ethernet-only broadcast read).
    pub unsolicited_hub: u64,
    pub samples: u64,
    /// Board-side "packet dropped" replies (8 bytes, reference §3.1).
    pub dropped_replies: u64,
    /// A board was read twice before every board of the arm had been read: a sample was lost
    /// (a board missing from the console's traffic, or the capture lost a frame).
    pub incomplete_cycles: u64,
    /// Hub slots with a sequence error or a size that does not match the layout.
    pub bad_hub_slots: u64,
    pub skipped_truncated: u64,
    pub skipped_other: u64,
    pub skipped_malformed: u64,
    pub skipped_unpaired: u64,
    pub no_feedback: u64,
}

/// Result of one pushed frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TapEvent {
    /// A board transaction was taken in, no sample completed yet.
    Consumed,
    /// A sample completed and was written to `out`.
    Sample,
    /// The frame was not used, and why.
    Skipped(Skip),
}

/// Pairs requests and replies and decodes the console's reads into samples.
pub struct TapDecoder {
    cfg: IoConfig,
    board_port: u16,
    pending: [Option<Pending>; PENDING],
    next_slot: usize,
    blocks: [[u8; BLOCK_CAP]; MAX_BOARDS],
    layouts: [Option<BlockLayout>; MAX_BOARDS],
    fresh: [bool; MAX_BOARDS],
    /// Write requests seen so far. The console reads every board, then writes (reference §3.4):
    /// the reads between two writes are one cycle, so a request is stamped with this count and
    /// the blocks of a sample must carry the same stamp. The stamp is taken in the requests'
    /// own order, whenever their replies are decoded.
    writes: u64,
    /// The stamp of the blocks marked in `fresh`.
    fresh_cycle: u64,
    /// Blocks seen per board slot since construction (the shell names boards that stop).
    seen: [u64; MAX_BOARDS],
    /// Actuator-space values of the last sample (pots included).
    last: ActuatorState,
    counters: TapCounters,
}

impl TapDecoder {
    /// A decoder for the arm of `cfg` (its board ids, board kind and firmware).
    pub fn new(cfg: IoConfig) -> Self {
        Self {
            cfg,
            board_port: BOARD_PORT,
            pending: [None; PENDING],
            next_slot: 0,
            blocks: [[0; BLOCK_CAP]; MAX_BOARDS],
            layouts: [None; MAX_BOARDS],
            fresh: [false; MAX_BOARDS],
            writes: 0,
            fresh_cycle: 0,
            seen: [0; MAX_BOARDS],
            last: ActuatorState::default(),
            counters: TapCounters::default(),
        }
    }

    /// The boards' UDP port, if not 1394 (an emulator on another port, in tests).
    pub fn with_board_port(mut self, port: u16) -> Self {
        self.board_port = port;
        self
    }

    pub fn config(&self) -> &IoConfig {
        &self.cfg
    }
    /// The conversion in use, to change the instrument's coupling between replies.
    pub fn config_mut(&mut self) -> &mut IoConfig {
        &mut self.cfg
    }

    pub fn counters(&self) -> TapCounters {
        self.counters
    }

    /// Actuator-space values of the last sample.
    pub fn last_actuators(&self) -> &ActuatorState {
        &self.last
    }

    /// Potentiometer positions of the last sample, actuator space (rad or m; NaN for an
    /// actuator without pot calibration). None when the io file calibrates no pot.
    pub fn pots(&self) -> Option<&[f64; NUM_JOINTS]> {
        self.cfg
            .has_potentiometers()
            .then_some(&self.last.pot_position)
    }
    /// [`ActuatorState::pot_minus_encoder`] of the last sample; None when the io file calibrates
    /// no pot.
    pub fn pot_minus_encoder(&self) -> Option<[f64; NUM_JOINTS]> {
        self.cfg
            .has_potentiometers()
            .then(|| self.last.pot_minus_encoder())
    }

    /// Feedback blocks seen per board slot (order of `config().board_ids()`).
    pub fn blocks_seen(&self) -> [u64; MAX_BOARDS] {
        self.seen
    }

    /// Takes one captured frame at host time `t_ns`. On [`TapEvent::Sample`], `out` holds the
    /// sample the console read (its `t_ns` is the given time). No allocation.
    pub fn push(
        &mut self,
        frame: &[u8],
        link: LinkType,
        t_ns: u64,
        out: &mut ArmSample,
    ) -> TapEvent {
        self.counters.frames += 1;
        let ev = match parse_frame(frame, link) {
            Ok(d) => self.push_datagram(&d, t_ns, out),
            Err(s) => TapEvent::Skipped(s),
        };
        if let TapEvent::Skipped(s) = ev {
            let c = &mut self.counters;
            match s {
                Skip::Truncated => c.skipped_truncated += 1,
                Skip::Malformed => c.skipped_malformed += 1,
                Skip::Unpaired => c.skipped_unpaired += 1,
                Skip::NoFeedback => c.no_feedback += 1,
                Skip::NotIpv4 | Skip::NotUdp | Skip::Fragment | Skip::OtherPort => {
                    c.skipped_other += 1
                }
            }
        }
        ev
    }

    /// Same as [`TapDecoder::push`] for an already extracted UDP datagram.
    pub fn push_datagram(&mut self, d: &Datagram<'_>, t_ns: u64, out: &mut ArmSample) -> TapEvent {
        let bp = self.board_port;
        if d.dst.port() == bp && d.src.port() != bp {
            self.request(d.src, d.dst, d.payload)
        } else if d.src.port() == bp && d.dst.port() != bp {
            self.reply(d.dst, d.src, d.payload, t_ns, out)
        } else {
            TapEvent::Skipped(Skip::OtherPort)
        }
    }

    fn request(&mut self, host: SocketAddrV4, board: SocketAddrV4, payload: &[u8]) -> TapEvent {
        let Ok(req) = EthRequest::parse(payload) else {
            return TapEvent::Skipped(Skip::Malformed);
        };
        let Ok(repr) = RequestRepr::parse(&req.packet) else {
            return TapEvent::Skipped(Skip::Malformed);
        };
        self.counters.requests += 1;
        let addr = (repr.offset & 0xFFFF) as u16;
        let node = req.packet.dest_node();
        let asked = match repr.kind {
            RequestKind::BlockRead { .. } if addr == 0 => Some(Asked::Feedback),
            RequestKind::BlockRead { .. } if addr == HUB_ADDRESS => Some(Asked::Hub),
            RequestKind::QuadletWrite { data } if addr == QUERY_ADDRESS => Some(Asked::Query {
                seq: (data >> 16) as u16,
            }),
            _ => None,
        };
        if asked.is_none()
            && matches!(
                repr.kind,
                RequestKind::BlockWrite { .. } | RequestKind::QuadletWrite { .. }
            )
        {
            self.writes = self.writes.wrapping_add(1);
        }
        // A new request with this label from this host replaces any older one.
        let label = repr.label;
        for p in self.pending.iter_mut() {
            if p.is_some_and(|p| p.host == host && p.label == label) {
                *p = None;
            }
        }
        match asked {
            Some(asked) => {
                self.pending[self.next_slot] = Some(Pending {
                    host,
                    board,
                    label,
                    node,
                    asked,
                    cycle: self.writes,
                });
                self.next_slot = (self.next_slot + 1) % PENDING;
                TapEvent::Consumed
            }
            None => TapEvent::Skipped(Skip::NoFeedback),
        }
    }

    fn take_pending(
        &mut self,
        host: SocketAddrV4,
        from: SocketAddrV4,
        label: u8,
        src_node: u8,
    ) -> Option<Pending> {
        let slot = self.pending.iter_mut().find(|p| {
            p.is_some_and(|p| {
                p.host == host
                    && p.label == label
                    && (p.node == BROADCAST_NODE || p.node == src_node)
                    && replies_for(p.board, from)
            })
        })?;
        slot.take()
    }

    fn reply(
        &mut self,
        host: SocketAddrV4,
        from: SocketAddrV4,
        payload: &[u8],
        t_ns: u64,
        out: &mut ArmSample,
    ) -> TapEvent {
        let Ok(reply) = EthReply::parse(payload) else {
            return TapEvent::Skipped(Skip::Malformed);
        };
        self.counters.replies += 1;
        let Some(p) = reply.packet else {
            self.counters.dropped_replies += 1;
            return TapEvent::Skipped(Skip::NoFeedback);
        };
        let Ok(resp) = ResponseRepr::parse(&p) else {
            return TapEvent::Skipped(Skip::Malformed);
        };
        let ResponseKind::Block { len } = resp.kind else {
            // Quadlet responses carry no feedback block; their requests were never kept.
            return TapEvent::Skipped(Skip::NoFeedback);
        };
        let Some(pending) = self.take_pending(host, from, resp.label, p.src_node()) else {
            return TapEvent::Skipped(Skip::Unpaired);
        };
        self.counters.paired += 1;
        if resp.rcode != 0 {
            return TapEvent::Skipped(Skip::NoFeedback);
        }
        let data = p.payload();
        let data = data.get(..usize::from(len)).unwrap_or(data);
        let completed = match pending.asked {
            Asked::Feedback => self.feedback(data, pending.cycle),
            Asked::Hub => self.hub(data, None, pending.cycle),
            Asked::Query { seq } => {
                self.counters.unsolicited_hub += 1;
                self.hub(data, Some(seq), pending.cycle)
            }
        };
        if completed {
            self.emit(t_ns, out);
            TapEvent::Sample
        } else {
            TapEvent::Consumed
        }
    }

    /// Layout of a block of `len_bytes` of this arm's board kind (firmware from the config,
    /// else the one whose length matches, §2.1).
    fn layout_for(&self, len_bytes: usize) -> Option<BlockLayout> {
        let kind = self.cfg.board_kind();
        let candidates = match self.cfg.firmware_version() {
            Some(fw) => [Some(fw), None],
            None => [Some(9), Some(7)],
        };
        candidates
            .into_iter()
            .flatten()
            .filter_map(|fw| BlockLayout::new(fw, kind).ok())
            .find(|l| l.len_bytes() == len_bytes)
    }

    /// Stores one board's block (identified by the board id in its status quadlet), read by a
    /// request of the console's cycle `cycle` (its writes before the request). Returns true when
    /// every board of the arm has a fresh block of that cycle.
    fn store(&mut self, block: &[u8], lay: BlockLayout, cycle: u64) -> bool {
        let Ok(view) = FeedbackBlock::new_checked(block, lay) else {
            return false;
        };
        let id = BoardStatus::new(view.status().raw, lay.kind()).board_id();
        let Some(slot) = self.cfg.board_slot(id) else {
            return false;
        };
        let (Some(dst), Some(src)) = (
            self.blocks
                .get_mut(slot)
                .and_then(|b| b.get_mut(..lay.len_bytes())),
            block.get(..lay.len_bytes()),
        ) else {
            return false;
        };
        if cycle != self.fresh_cycle {
            // A block of another cycle of the console's: the blocks kept are of a cycle that
            // never completed (a frame the capture dropped, a read the console gave up). Without
            // this, that cycle's last board would be paired with the next cycle's first, and
            // every cycle after it the same way.
            if self.fresh.iter().any(|f| *f) {
                self.counters.incomplete_cycles += 1;
            }
            self.fresh = [false; MAX_BOARDS];
            self.fresh_cycle = cycle;
        }
        if self.fresh[slot] {
            // Read again before the others: the previous cycle never completed.
            self.counters.incomplete_cycles += 1;
            self.fresh = [false; MAX_BOARDS];
        }
        dst.copy_from_slice(src);
        self.layouts[slot] = Some(lay);
        self.fresh[slot] = true;
        self.seen[slot] += 1;
        let n = self.cfg.board_ids().len();
        self.fresh[..n].iter().all(|f| *f)
    }

    fn feedback(&mut self, data: &[u8], cycle: u64) -> bool {
        let Some(lay) = self.layout_for(data.len()) else {
            self.counters.skipped_malformed += 1;
            return false;
        };
        self.counters.feedback_blocks += 1;
        self.store(data, lay, cycle)
    }

    /// Hub memory: per board a header quadlet (size Nq + 1, sequence LSB, mismatch bit) and
    /// the board's block, in any order; a zero header ends it (§3.4).
    fn hub(&mut self, data: &[u8], seq: Option<u16>, cycle: u64) -> bool {
        self.counters.hub_blocks += 1;
        // A hub read is one cycle of its own: it starts from nothing.
        self.fresh = [false; MAX_BOARDS];
        let mut off = 0usize;
        let mut complete = false;
        while let Some(h) = data.get(off..off + 4) {
            let h = HubHeader(u32::from_be_bytes([h[0], h[1], h[2], h[3]]));
            let size = h.size_quadlets() as usize;
            if size < 2 {
                break;
            }
            let body = off + 4;
            let end = off + size * 4;
            let Some(block) = data.get(body..end) else {
                self.counters.bad_hub_slots += 1;
                break;
            };
            off = end;
            let seq_ok = seq.is_none_or(|s| h.sequence_lsb() == s as u8);
            let Some(lay) = self.layout_for(block.len()) else {
                self.counters.bad_hub_slots += 1;
                continue;
            };
            if h.sequence_mismatch() || !seq_ok {
                self.counters.bad_hub_slots += 1;
                continue;
            }
            complete = self.store(block, lay, cycle);
        }
        if !complete {
            self.fresh = [false; MAX_BOARDS];
            self.counters.incomplete_cycles += 1;
        }
        complete
    }

    fn emit(&mut self, t_ns: u64, out: &mut ArmSample) {
        let blocks: [Option<FeedbackBlock<&[u8]>>; MAX_BOARDS] = core::array::from_fn(|slot| {
            let lay = self.layouts[slot]?;
            FeedbackBlock::new_checked(&self.blocks[slot][..], lay).ok()
        });
        self.last = decode_blocks(&self.cfg, &blocks, t_ns, out);
        self.fresh = [false; MAX_BOARDS];
        self.counters.samples += 1;
    }
}

/// Whether a reply from `from` can answer a request sent to `to`: the same address and port,
/// or, for a request to a broadcast address (all ones in its last octets, as 169.254.255.255 or
/// 255.255.255.255; the Ethernet-only broadcast query, reference §3.4), the same port from an
/// address of that subnet, or for a request to a multicast group, the same port from a
/// unicast address. On loopback (emulators, tests) any loopback address with the same
/// port: an emulator reached at 127.0.0.7 answers from 127.0.0.1; who owns a loopback socket
/// is the shell's check.
fn replies_for(to: SocketAddrV4, from: SocketAddrV4) -> bool {
    if to == from {
        return true;
    }
    let t = to.ip().octets();
    if to.port() != from.port() {
        return false;
    }
    if to.ip().is_loopback() && from.ip().is_loopback() {
        return true;
    }
    if to.ip().is_multicast() {
        // The broadcast query of FPGA V3 boards goes to their multicast group (reference §10):
        // the hub answers from its own address.
        return !from.ip().is_multicast() && !from.ip().is_broadcast();
    }
    if t[3] != 255 {
        return false;
    }
    let f = from.ip().octets();
    t.iter().zip(f).all(|(&t, f)| t == 255 || t == f)
}

#[cfg(test)]
mod tests;
