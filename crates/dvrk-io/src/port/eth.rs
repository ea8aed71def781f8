//! The Ethernet protocol engine over any [`Link`] (reference §3.1).

use super::{Link, Port, PortError};
use crate::wire::eth::{CONTROL_LEN, EXTRA_LEN};
use crate::wire::firewire::{BROADCAST_NODE, LABEL_MASK};
use crate::wire::hub::{HUB_ADDRESS, QUERY_ADDRESS};
use crate::wire::{ControlWord, EthReply, EthRequest, RequestKind, RequestRepr, Tcode, WireError};

/// Largest block read over Ethernet: min(2048, MTU − 36) − 24 = 1440 bytes at MTU 1500 (§3.1).
pub const MAX_READ_BYTES: usize = 1440;
/// Largest block write over Ethernet at MTU 1500 (§3.1).
pub const MAX_WRITE_BYTES: usize = 1446;
const TX_CAP: usize = CONTROL_LEN + 20 + MAX_WRITE_BYTES + 8;
const RX_CAP: usize = 4096;
/// Replies with another label or from another node skipped while waiting for the right one (each
/// costs one receive): the whole 6-bit label space, so a burst of late replies after a stall is
/// read through within one request.
const MAX_STALE: u8 = 64;

/// Per-port counters, read by the binary's 1 Hz summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EthCounters {
    pub requests: u64,
    pub replies_ok: u64,
    pub timeouts: u64,
    /// Quadlet requests sent again after a wait without reply ([`super::QuadletRetry`]).
    pub quadlet_retries: u64,
    /// Replies with another label or from another node (late answers to timed-out requests,
    /// duplicates), skipped.
    pub stale_replies: u64,
    /// Replies whose header or data CRC was nonzero and wrong, or zero from a source that sends
    /// CRCs (the emulator; a real FPGA sends 0, reference §3.1), rejected.
    pub crc_errors: u64,
    /// Times the port resynchronized (drained its link) after a timeout or an unexpected reply.
    pub resyncs: u64,
    /// Datagrams thrown away by those drains.
    pub drained: u64,
    /// Replies rejected by validation (tcode, source, length, flags, malformed).
    pub bad_replies: u64,
    pub dropped: u64,
    pub bus_resets: u64,
    pub internal_errors: u64,
    /// Replies whose extra data carried the Ethernet-error summary flag (not fatal).
    pub ethernet_errors: u64,
    /// Times the FPGA's bus generation differed from ours (we adopt it).
    pub generation_changes: u64,
    pub writes: u64,
}

#[derive(Clone, Copy)]
enum Expect {
    Quadlet,
    Block(u16),
}

/// Ethernet protocol engine: builds requests (control word with NOFORWARD and bus generation,
/// rotating 6-bit labels), validates every reply (length, tcode, label, source node, response
/// code, extra-data flags) into typed errors, and counts. `UdpPort = EthPort<UdpLink>`.
pub struct EthPort<L: Link> {
    link: L,
    next_label: u8,
    bus_generation: u8,
    noforward: bool,
    node_of_board: [u8; 16],
    hub_board: Option<u8>,
    query_allowed: bool,
    query_seq: u16,
    /// The link must be drained before the next request: a timeout or an unexpected reply
    /// means late replies may be queued.
    resync: bool,
    /// The last quadlet read was answered: a lost datagram is asked for again
    /// ([`Link::quadlet_retry`]); after a read without any reply, reads ask once.
    link_answers: bool,
    /// Wait of a repeated quadlet read now: the link's [`QuadletRetry::wait`], doubled each time
    /// a reply to an earlier request of the same read shows that the wait was shorter than the
    /// board's answer, and brought back down by an eighth after 16 reads (a shared-mode cycle) without that.
    retry_wait: Option<std::time::Duration>,
    quiet_reads: u8,
    /// Label of the last reply taken.
    last_label: u8,
    /// The source has sent a nonzero CRC: from now on a zero CRC is an error too.
    crcs_seen: bool,
    counters: EthCounters,
    tx: Box<[u8; TX_CAP]>,
    rx: Box<[u8; RX_CAP]>,
}

impl<L: Link> EthPort<L> {
    /// A port over `link`, Ethernet-only addressing (node = board id, NOFORWARD set), labels
    /// starting at 0, bus generation 0. Allocates its two datagram buffers here.
    pub fn new(link: L) -> Self {
        let mut node_of_board = [0u8; 16];
        for (i, n) in node_of_board.iter_mut().enumerate() {
            *n = i as u8;
        }
        Self {
            link,
            next_label: 0,
            bus_generation: 0,
            noforward: true,
            node_of_board,
            hub_board: None,
            query_allowed: false,
            query_seq: 0,
            resync: false,
            link_answers: true,
            retry_wait: None,
            quiet_reads: 0,
            last_label: 0,
            crcs_seen: false,
            counters: EthCounters::default(),
            tx: Box::new([0; TX_CAP]),
            rx: Box::new([0; RX_CAP]),
        }
    }
    /// The explicit write capability. Any register write refreshes the boards' watchdog
    /// (reference §4, §8): use it only where nothing else drives the boards.
    pub fn allow_writes(&mut self) -> WriteAccess<'_, L> {
        WriteAccess { port: self }
    }
    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }
    pub fn link(&self) -> &L {
        &self.link
    }
    pub fn into_link(self) -> L {
        self.link
    }
    pub fn counters(&self) -> EthCounters {
        self.counters
    }
    /// NOFORWARD in the control word (default true: Ethernet-only, handled by the addressed
    /// FPGA; false in bridge mode, where the hub forwards to FireWire), reference §3.1, §3.3.
    pub fn set_noforward(&mut self, noforward: bool) {
        self.noforward = noforward;
    }
    /// Node that answers for `board` (identity in Ethernet-only mode, §3.3).
    pub fn set_node(&mut self, board: u8, node: u8) -> Result<(), PortError> {
        let slot = self
            .node_of_board
            .get_mut(board as usize)
            .ok_or(PortError::BoardOutOfRange { board })?;
        *slot = node & 0x3F;
        Ok(())
    }
    /// Board whose hub memory is read after a broadcast query (default: lowest board in the mask).
    pub fn set_hub_board(&mut self, board: Option<u8>) {
        self.hub_board = board;
    }
    /// The host's bus generation sent in the control word.
    pub fn bus_generation(&self) -> u8 {
        self.bus_generation
    }
    pub fn set_bus_generation(&mut self, generation: u8) {
        self.bus_generation = generation;
    }
    /// Label the next request will carry.
    pub fn next_label(&self) -> u8 {
        self.next_label
    }

    fn node(&self, board: u8) -> Result<u8, PortError> {
        self.node_of_board
            .get(board as usize)
            .copied()
            .ok_or(PortError::BoardOutOfRange { board })
    }

    fn take_label(&mut self) -> u8 {
        let l = self.next_label;
        self.next_label = (l + 1) & LABEL_MASK;
        l
    }

    /// `late`: the reply taken answered an earlier request of the read, so the wait was too
    /// short for this board: double it. Otherwise, after 16 reads, shorten it by an eighth.
    fn adapt_retry_wait(&mut self, retry: Option<super::QuadletRetry>, late: bool) {
        let (Some(r), Some(w)) = (retry, self.retry_wait) else {
            return;
        };
        if late {
            self.retry_wait = Some(w * 2);
            self.quiet_reads = 0;
        } else if self.quiet_reads >= 16 {
            self.retry_wait = Some((w - w / 8).max(r.wait));
            self.quiet_reads = 0;
        } else {
            self.quiet_reads += 1;
        }
    }

    /// Builds and sends one request; returns its label.
    fn send_request(
        &mut self,
        node: u8,
        addr: u16,
        kind: RequestKind,
        payload: &[u8],
        noforward: bool,
    ) -> Result<u8, PortError> {
        if self.resync {
            // Late and duplicate replies of earlier requests may be queued: throw them away
            // before asking again, so that they can never be taken for this request's reply.
            self.resync = false;
            self.counters.resyncs += 1;
            self.counters.drained += self.link.discard_pending(&mut self.rx[..]) as u64;
        }
        let label = self.take_label();
        let req = RequestRepr::host(node, label, u64::from(addr), kind);
        let cw = ControlWord::new(noforward, self.bus_generation);
        let n = EthRequest::emit(&mut self.tx[..], cw, &req, payload)
            .map_err(|error| PortError::Malformed { board: node, error })?;
        self.counters.requests += 1;
        self.link.send(node, &self.tx[..n])?;
        Ok(label)
    }

    /// Waits for the reply to `label`, skipping stale labels; copies block data into `out`.
    fn await_reply(
        &mut self,
        board: u8,
        addr: u16,
        expect_src: Option<u8>,
        label: u8,
        expect: Expect,
        out: &mut [u8],
    ) -> Result<(u32, u8), PortError> {
        self.await_reply_of(
            board,
            addr,
            expect_src,
            label,
            1 << label,
            expect,
            out,
            None,
        )
    }

    /// Waits for a reply to `label` or to any label in the `accept` mask (the earlier
    /// requests of a repeated quadlet read), at most `wait` per receive when given.
    #[allow(clippy::too_many_arguments)]
    fn await_reply_of(
        &mut self,
        board: u8,
        addr: u16,
        expect_src: Option<u8>,
        label: u8,
        accept: u64,
        expect: Expect,
        out: &mut [u8],
        wait: Option<std::time::Duration>,
    ) -> Result<(u32, u8), PortError> {
        let mut stale: Option<PortError> = None;
        for _ in 0..=MAX_STALE {
            let got = match wait {
                Some(w) => self.link.recv_within(&mut self.rx[..], w),
                None => self.link.recv(&mut self.rx[..]),
            };
            let n = match got {
                Ok(n) => n,
                Err(PortError::Timeout { .. }) => {
                    // A short wait of a repeated quadlet read is counted as a retry instead.
                    if wait.is_none() {
                        self.counters.timeouts += 1;
                    }
                    self.resync = true;
                    // A wrong reply followed by silence says more than the silence alone.
                    return Err(stale.unwrap_or(PortError::Timeout { board, addr }));
                }
                Err(e) => {
                    self.resync = true;
                    return Err(e);
                }
            };
            match self.validate(n, board, expect_src, label, accept, expect, out) {
                Ok(v) => {
                    self.counters.replies_ok += 1;
                    return Ok(v);
                }
                Err(e @ (PortError::WrongLabel { .. } | PortError::WrongSource { .. })) => {
                    // Not ours: a late or duplicate reply. Skip it and keep waiting.
                    self.counters.stale_replies += 1;
                    self.resync = true;
                    stale = Some(e);
                }
                Err(e) => {
                    self.counters.bad_replies += 1;
                    self.resync = true;
                    return Err(e);
                }
            }
        }
        self.resync = true;
        Err(stale.unwrap_or(PortError::Timeout { board, addr }))
    }

    /// Validates one reply datagram of `n` bytes in `rx`: its label must be in `accept`
    /// (`label` is the one named in the error). Returns (quadlet data, source node).
    #[allow(clippy::too_many_arguments)]
    fn validate(
        &mut self,
        n: usize,
        board: u8,
        expect_src: Option<u8>,
        label: u8,
        accept: u64,
        expect: Expect,
        out: &mut [u8],
    ) -> Result<(u32, u8), PortError> {
        let dgram = self.rx.get(..n).unwrap_or(&[]);
        let (expected_tcode, fw_len) = match expect {
            Expect::Quadlet => (Tcode::QuadletResponse, 20usize),
            Expect::Block(len) => (
                Tcode::BlockResponse,
                20 + crate::wire::pad4(len as usize) + 4,
            ),
        };
        let expected_len = fw_len + EXTRA_LEN;
        if n == EXTRA_LEN {
            // Only extra data: the FPGA dropped the request (§3.1).
            let flags = dgram.first().copied().unwrap_or(0);
            self.counters.dropped += 1;
            return Err(PortError::PacketDropped { board, flags });
        }
        if n < expected_len.min(20 + EXTRA_LEN) {
            return Err(PortError::Truncated {
                board,
                got: n,
                need: expected_len,
            });
        }
        let reply = EthReply::parse(dgram).map_err(|error| match error {
            WireError::Truncated { got, need } => PortError::Truncated { board, got, need },
            error => PortError::Malformed { board, error },
        })?;
        let x = reply.extra;
        if x.ethernet_error() {
            self.counters.ethernet_errors += 1;
        }
        if x.bus_generation != self.bus_generation {
            self.counters.generation_changes += 1;
            self.bus_generation = x.bus_generation;
        }
        if x.packet_dropped() {
            self.counters.dropped += 1;
            return Err(PortError::PacketDropped {
                board,
                flags: x.flags,
            });
        }
        if x.bus_reset() {
            self.counters.bus_resets += 1;
            return Err(PortError::BusReset {
                board,
                generation: x.bus_generation,
            });
        }
        if x.internal_error() {
            self.counters.internal_errors += 1;
            return Err(PortError::InternalError {
                board,
                flags: x.flags,
            });
        }
        let Some(p) = reply.packet else {
            return Err(PortError::Truncated {
                board,
                got: n,
                need: expected_len,
            });
        };
        // A reply is ours only if both its label and its source node match; anything else is a
        // late or duplicate reply of another request, skipped by the caller.
        if accept & (1u64 << (p.label() & LABEL_MASK)) == 0 {
            return Err(PortError::WrongLabel {
                board,
                expected: label,
                got: p.label(),
            });
        }
        let src = p.src_node();
        self.last_label = p.label();
        if let Some(exp) = expect_src
            && src != exp
        {
            return Err(PortError::WrongSource {
                board,
                expected: exp,
                got: src,
            });
        }
        let crcs = [
            (p.header_crc(), p.computed_header_crc()),
            (p.data_crc(), p.computed_data_crc()),
        ];
        for (carried, computed) in crcs {
            check_crc(
                &mut self.crcs_seen,
                &mut self.counters.crc_errors,
                board,
                carried,
                computed,
            )?;
        }
        let tcode = p.tcode();
        if tcode != expected_tcode {
            return Err(PortError::WrongTcode {
                board,
                expected: expected_tcode as u8,
                got: tcode as u8,
            });
        }
        if p.rcode() != 0 {
            return Err(PortError::ResponseCode {
                board,
                rcode: p.rcode(),
            });
        }
        if let Expect::Block(len) = expect
            && p.data_length() != len
        {
            return Err(PortError::WrongLength {
                board,
                expected: len,
                got: p.data_length(),
            });
        }
        if n != expected_len {
            return Err(PortError::Oversized {
                board,
                got: n,
                expected: expected_len,
            });
        }
        match expect {
            Expect::Quadlet => Ok((p.quadlet_data(), src)),
            Expect::Block(_) => {
                let data = p.payload();
                if data.len() != out.len() {
                    return Err(PortError::WrongLength {
                        board,
                        expected: out.len() as u16,
                        got: data.len() as u16,
                    });
                }
                out.copy_from_slice(data);
                Ok((0, src))
            }
        }
    }

    fn check_block_len(len: usize, max: usize) -> Result<u16, PortError> {
        if len == 0 || !len.is_multiple_of(4) || len > max {
            return Err(PortError::BlockSize { len, max });
        }
        Ok(len as u16)
    }

    /// Quadlet read of `addr` at node 0x3F with NOFORWARD; the directly connected board
    /// answers. Returns (data, source node). Used by discovery (§3.3 step 2).
    pub fn broadcast_read_quadlet(&mut self, addr: u16) -> Result<(u32, u8), PortError> {
        let label = self.send_request(BROADCAST_NODE, addr, RequestKind::QuadletRead, &[], true)?;
        self.await_reply(BROADCAST_NODE, addr, None, label, Expect::Quadlet, &mut [])
    }

    /// Quadlet read addressed to a node number rather than a board id (discovery scan).
    pub fn read_quadlet_node(&mut self, node: u8, addr: u16) -> Result<u32, PortError> {
        let label = self.send_request(node, addr, RequestKind::QuadletRead, &[], self.noforward)?;
        self.await_reply(node, addr, Some(node), label, Expect::Quadlet, &mut [])
            .map(|(v, _)| v)
    }

    fn write_node(
        &mut self,
        node: u8,
        addr: u16,
        kind: RequestKind,
        payload: &[u8],
        noforward: bool,
    ) -> Result<(), PortError> {
        self.send_request(node, addr, kind, payload, noforward)?;
        self.counters.writes += 1;
        Ok(())
    }
}

impl<L: Link> Port for EthPort<L> {
    /// On a lossy link ([`Link::quadlet_retry`]) a request without reply within the retry's
    /// wait is sent again, up to its number of attempts, the last one waiting the link's whole
    /// timeout; a reply to any of them is taken (they read the same register). After a read
    /// that got no reply at all (a stalled or absent board), reads ask once until one is
    /// answered again, so a stall neither multiplies the requests queued at the board nor
    /// costs more than the timeout per read.
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, PortError> {
        let node = self.node(board)?;
        let retry = self.link.quadlet_retry().filter(|_| self.link_answers);
        let attempts = retry.map_or(1, |r| r.attempts.max(1));
        let retry = retry.map(|r| {
            // Between the link's wait and 4 times it (a board slower than its usual answer).
            let w = self.retry_wait.unwrap_or(r.wait).clamp(r.wait, r.wait * 4);
            self.retry_wait = Some(w);
            super::QuadletRetry { wait: w, ..r }
        });
        let mut accept = 0u64;
        let mut attempt = 1;
        loop {
            let label =
                self.send_request(node, addr, RequestKind::QuadletRead, &[], self.noforward)?;
            accept |= 1 << label;
            let wait = retry.filter(|_| attempt < attempts).map(|r| r.wait);
            let r = self.await_reply_of(
                board,
                addr,
                Some(node),
                label,
                accept,
                Expect::Quadlet,
                &mut [],
                wait,
            );
            match r {
                // Silence, or only replies to other requests then silence: ask again.
                Err(
                    PortError::Timeout { .. }
                    | PortError::WrongLabel { .. }
                    | PortError::WrongSource { .. },
                ) if attempt < attempts => {
                    self.counters.quadlet_retries += 1;
                    attempt += 1;
                }
                Err(e @ (PortError::Timeout { .. } | PortError::WrongLabel { .. })) => {
                    self.link_answers = false;
                    return Err(e);
                }
                r => {
                    if r.is_ok() {
                        self.link_answers = true;
                        self.adapt_retry_wait(retry, self.last_label != label);
                    }
                    return r.map(|(v, _)| v);
                }
            }
        }
    }

    fn read_block(&mut self, board: u8, addr: u16, out: &mut [u8]) -> Result<(), PortError> {
        let len = Self::check_block_len(out.len(), MAX_READ_BYTES)?;
        let node = self.node(board)?;
        let label = self.send_request(
            node,
            addr,
            RequestKind::BlockRead { len },
            &[],
            self.noforward,
        )?;
        self.await_reply(board, addr, Some(node), label, Expect::Block(len), out)
            .map(|_| ())
    }

    /// Writes (seq<<16 | mask) to the query register 0x1800 at node 0x3F, then block-reads the
    /// hub memory 0x1000 of the hub board (§3.4). Refused with [`PortError::QueryNotAllowed`]
    /// until enabled through [`WriteAccess::enable_broadcast_query`]: the query is a register
    /// write and refreshes the watchdog (§4). In Ethernet-only Rev 9 systems the real hub sends
    /// its data unasked; this engine always reads it explicitly, which the boards also answer.
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), PortError> {
        if !self.query_allowed {
            return Err(PortError::QueryNotAllowed);
        }
        let hub = match self.hub_board {
            Some(h) => h,
            None if board_mask != 0 => board_mask.trailing_zeros() as u8,
            None => return Err(PortError::BoardOutOfRange { board: 16 }),
        };
        self.query_seq = self.query_seq.wrapping_add(1);
        let data = (u32::from(self.query_seq) << 16) | u32::from(board_mask);
        self.write_node(
            BROADCAST_NODE,
            QUERY_ADDRESS,
            RequestKind::QuadletWrite { data },
            &[],
            self.noforward,
        )?;
        self.read_block(hub, HUB_ADDRESS, out)
    }
}

/// Checks one CRC of a reply (header, or data of a block reply; both are 0 = 0 for the kinds
/// without data). A real FPGA sends 0 (reference §3.1; the UDP checksum protects the wire); a
/// source that has once sent a right nonzero CRC must always send a right one.
fn check_crc(
    crcs_seen: &mut bool,
    crc_errors: &mut u64,
    board: u8,
    carried: u32,
    computed: u32,
) -> Result<(), PortError> {
    if carried == computed {
        // Learn only from a right CRC: a flipped bit in a zero CRC field must not switch the
        // check on for a source that sends none.
        *crcs_seen |= carried != 0;
        return Ok(());
    }
    if carried == 0 && !*crcs_seen {
        return Ok(());
    }
    *crc_errors += 1;
    Err(PortError::CrcMismatch {
        board,
        carried,
        computed,
    })
}

/// The write capability of an [`EthPort`]. Exists only through [`EthPort::allow_writes`].
/// Writes are sent without waiting for a reply, as the dVRK host does over Ethernet.
pub struct WriteAccess<'a, L: Link> {
    pub(super) port: &'a mut EthPort<L>,
}

impl<L: Link> WriteAccess<'_, L> {
    pub fn port(&mut self) -> &mut EthPort<L> {
        self.port
    }
    pub fn write_quadlet(&mut self, board: u8, addr: u16, data: u32) -> Result<(), PortError> {
        let node = self.port.node(board)?;
        let nf = self.port.noforward;
        self.port
            .write_node(node, addr, RequestKind::QuadletWrite { data }, &[], nf)
    }
    pub fn write_block(&mut self, board: u8, addr: u16, data: &[u8]) -> Result<(), PortError> {
        let len = EthPort::<L>::check_block_len(data.len(), MAX_WRITE_BYTES)?;
        let node = self.port.node(board)?;
        let nf = self.port.noforward;
        self.port
            .write_node(node, addr, RequestKind::BlockWrite { len }, data, nf)
    }
    /// Quadlet write to node 0x3F (every board).
    pub fn broadcast_write_quadlet(&mut self, addr: u16, data: u32) -> Result<(), PortError> {
        let nf = self.port.noforward;
        self.port.write_node(
            BROADCAST_NODE,
            addr,
            RequestKind::QuadletWrite { data },
            &[],
            nf,
        )
    }
    /// Block write to node 0x3F (every board).
    pub fn broadcast_write_block(&mut self, addr: u16, data: &[u8]) -> Result<(), PortError> {
        let len = EthPort::<L>::check_block_len(data.len(), MAX_WRITE_BYTES)?;
        let nf = self.port.noforward;
        self.port.write_node(
            BROADCAST_NODE,
            addr,
            RequestKind::BlockWrite { len },
            data,
            nf,
        )
    }
    /// Lets [`Port::broadcast_query_hub_read`] write the query register from now on.
    pub fn enable_broadcast_query(&mut self) {
        self.port.query_allowed = true;
    }
}
