//! The Ethernet protocol engine over any [`Link`] (reference §3.1).

use std::time::{Duration, Instant};

use super::{Link, Port, PortError, QuadletRetry, UNKNOWN_BOARD, read_quadlets_in_turn};
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

/// Default of [`EthPort::set_quadlet_window`]: quadlet requests a batch keeps outstanding at
/// once. 4 hides the round trips of a cycle's reads and asks a lost datagram again within the
/// cycle (RELIABILITY.md, issue 22 item 7); each request waits the whole reply timeout (at most
/// two from a register's first), as the last attempt of a read on its own does, so a host stall
/// costs no more than one read at a time. The FPGA serves one packet at a time (reference
/// §8.4), so each request queued there may delay the console's next packet by one quadlet's
/// service: a bench that wants its reads strictly one after the other sets 1
/// (`shared_requests_in_flight`).
pub const DEFAULT_QUADLET_WINDOW: u8 = 4;
/// Largest window [`EthPort::set_quadlet_window`] takes.
pub const MAX_QUADLET_WINDOW: u8 = 16;
/// How much wider than its window a batch keeps requests outstanding after a batch in which a
/// datagram was shown lost (a later request's reply came first), up to
/// [`MAX_QUADLET_WINDOW`]; back to the window after a batch without. On a lossy link nearly
/// every shared-mode cycle loses a datagram (1 - 0.9^32 at 10%), and each loss costs a round
/// trip; twice the window halves the round trips of the rest. Through the test's fault proxy
/// at 10% loss, `serve` published 1456-1462 Hz with 8 in flight against 1347-1411 Hz with 4
/// (RELIABILITY.md), and the console stand-in's p99 beside 8 was within the spread of 4
/// (benches/README.md, coexistence). A clean link keeps the configured window, and with it the
/// console's packets' wait at the FPGA. A window of 1 is kept as set.
pub const LOSSY_WINDOW_FACTOR: u8 = 2;
/// Floor of the retry wait a batch estimates from the measured round trip (a loopback board
/// answers in a few µs; the scheduler's timer slack is 50 µs).
pub const MIN_RETRY_WAIT: Duration = Duration::from_micros(50);
/// Entries of one pipelined batch; a longer list is read in batches of this many.
const MAX_BATCH: usize = 32;
/// Labels one batch may use: half the 6-bit label space, so that two consecutive batches never
/// share a label and a late reply of the previous batch is never taken for a register of this
/// one (a quadlet reply carries no address: label and source node are all that tie it to its
/// request).
const MAX_BATCH_LABELS: u8 = 32;
const NO_ENTRY: u8 = u8::MAX;
/// Datagrams one batch reads at most: every label it may use answered four times over (late
/// replies of the cycle before, duplicates). More is a flood, and ends the batch.
const MAX_BATCH_DATAGRAMS: usize = 4 * MAX_BATCH_LABELS as usize;
/// Most doublings of a batch's retry wait while its board stays silent.
const MAX_BACKOFF_SHIFT: u32 = 8;

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
    /// Pipelined batches of quadlet reads ([`Port::read_quadlets`]).
    pub quadlet_batches: u64,
    /// Batches that gave up a register at its deadline (the reply timeout from its first
    /// request, or the batch's budget), leaving it unread.
    pub batch_deadlines: u64,
    /// Requests that had to take a label whose last request, to another register, was never
    /// answered (every other label was in use, quarantined or its own register's): a late
    /// reply of that request could still come and be taken for this one.
    pub labels_reused_unanswered: u64,
}

/// State of one entry of a pipelined batch.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Entry {
    /// Not asked yet.
    Unsent,
    /// Asked; its newest request is outstanding until its due time.
    InFlight,
    /// Asked as often as allowed, presumed lost; a late reply is still taken.
    GivenUp,
    /// Not asked: its board stopped answering in this batch, or the board id is invalid.
    Skipped,
    Done,
}

/// Bookkeeping of one pipelined batch ([`Port::read_quadlets`] on [`EthPort`]), on the
/// stack: per entry its node, state, requests sent, when its newest request is presumed lost
/// (`due`) and when the entry is given up (`deadline`: the reply timeout counted from its newest
/// request); per label the entry it asked for, when, and the request's rank in the batch.
struct Batch {
    node: [u8; MAX_BATCH],
    state: [Entry; MAX_BATCH],
    sends: [u8; MAX_BATCH],
    due: [Instant; MAX_BATCH],
    deadline: [Instant; MAX_BATCH],
    /// The latest `deadline` may move to: two reply timeouts after the first request (or the
    /// batch's budget), so that a board that died mid-batch holds the cycle up for a bounded
    /// time.
    limit: [Instant; MAX_BATCH],
    /// Rank (0, 1, ... in the order sent) of each entry's newest request.
    newest: [u8; MAX_BATCH],
    /// The entry's newest request is known lost: a later one to its node was answered.
    lost: [bool; MAX_BATCH],
    /// Some entry's request was known lost in this batch.
    shown_lost: bool,
    /// Label whose reply answered the entry (NO_ENTRY: none yet).
    answered_by: [u8; MAX_BATCH],
    label_entry: [u8; 64],
    label_rank: [u8; 64],
    sent_at: [Instant; 64],
    /// Labels sent in this batch (bit = label).
    accept: u64,
    labels_used: u8,
    taken: u8,
    /// Boards (bit = id) asked, answering, and given up in this batch.
    asked: u16,
    answered: u16,
    failed: u16,
}

impl Batch {
    fn new(start: Instant) -> Self {
        Self {
            node: [0; MAX_BATCH],
            state: [Entry::Unsent; MAX_BATCH],
            sends: [0; MAX_BATCH],
            due: [start; MAX_BATCH],
            deadline: [start; MAX_BATCH],
            limit: [start; MAX_BATCH],
            newest: [0; MAX_BATCH],
            lost: [false; MAX_BATCH],
            shown_lost: false,
            answered_by: [NO_ENTRY; MAX_BATCH],
            label_entry: [NO_ENTRY; 64],
            label_rank: [0; 64],
            sent_at: [start; 64],
            accept: 0,
            labels_used: 0,
            taken: 0,
            asked: 0,
            answered: 0,
            failed: 0,
        }
    }

    /// Sends entry `i`'s request, first or repeated, with a new label, and records it: the
    /// label now answers for entry `i`, the entry is in flight until `due`.
    fn ask<L: Link>(
        &mut self,
        port: &mut EthPort<L>,
        i: usize,
        addr: u16,
        now: Instant,
        due: Instant,
    ) -> Result<(), PortError> {
        port.avoid_labels = self.accept;
        let label = port.send_request(
            self.node[i],
            addr,
            RequestKind::QuadletRead,
            &[],
            port.noforward,
        )?;
        let l = usize::from(label & LABEL_MASK);
        self.label_entry[l] = i as u8;
        self.label_rank[l] = self.labels_used;
        self.sent_at[l] = now;
        self.accept |= 1 << l;
        self.newest[i] = self.labels_used;
        self.lost[i] = false;
        self.labels_used += 1;
        self.sends[i] = self.sends[i].saturating_add(1);
        self.due[i] = due;
        self.state[i] = Entry::InFlight;
        Ok(())
    }

    /// Earliest due time of the entries in flight; None when none is.
    fn next_due(&self, n: usize) -> Option<Instant> {
        (0..n)
            .filter(|&i| self.state[i] == Entry::InFlight)
            .map(|i| self.due[i])
            .min()
    }

    /// A reply of `node` to the request of rank `rank` was taken. A board answers its requests
    /// in the order they arrive (the FPGA serves one packet at a time, reference §8.4), so an
    /// entry of the same node (of any node when one FPGA answers for all, `one_server`) whose
    /// newest request was sent before that one and is still unanswered lost its request or
    /// its reply: it is due now, not after the retry wait.
    fn overtaken(&mut self, n: usize, node: u8, rank: u8, r: QuadletRetry, now: Instant) {
        let attempts = batch_attempts(r);
        for j in 0..n {
            if self.state[j] == Entry::InFlight
                && (r.one_server || self.node[j] == node)
                && self.newest[j] < rank
                && self.sends[j] < attempts
            {
                self.lost[j] = true;
                self.shown_lost = true;
                self.due[j] = self.due[j].min(now);
            }
        }
    }

    /// Another entry of `i`'s node, in flight, past its due time and not known lost, has an
    /// older request than `i`: that one is asked again first.
    fn older_past_due(&self, n: usize, i: usize, now: Instant) -> bool {
        (0..n).any(|j| {
            j != i
                && self.state[j] == Entry::InFlight
                && self.node[j] == self.node[i]
                && !self.lost[j]
                && self.due[j] <= now
                && self.newest[j] < self.newest[i]
        })
    }

    /// Entry `i`'s deadline moves on to `until` (never back), within its limit.
    fn renew(&mut self, i: usize, until: Instant) {
        self.deadline[i] = self.deadline[i].max(until.min(self.limit[i]));
    }

    /// Entry `i` of a node was just asked again for silence: the node's other requests past
    /// their due time (not known lost) wait as long as it does, and are given up with it.
    fn wait_with(&mut self, n: usize, i: usize, now: Instant) {
        if self.lost[i] {
            return;
        }
        for j in 0..n {
            if j != i
                && self.state[j] == Entry::InFlight
                && self.node[j] == self.node[i]
                && !self.lost[j]
                && self.due[j] <= now
            {
                // A silent board is silent for all of them: they are given up together.
                self.renew(j, self.deadline[i]);
                self.due[j] = self.due[i].min(self.deadline[j]);
            }
        }
    }
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
    /// Requests a batch of quadlet reads keeps outstanding ([`EthPort::set_quadlet_window`]).
    window: u8,
    /// The last batch showed a datagram lost: the next one keeps [`LOSSY_WINDOW_FACTOR`] times
    /// the window outstanding.
    widened: bool,
    /// Longest a batch waits in all ([`EthPort::set_quadlet_batch_budget`]); None: no cap but
    /// each register's reply timeout.
    batch_budget: Option<Duration>,
    /// Boards (bit = board id) that answered nothing in their last batch: asked once per batch
    /// until they answer, so a stalled board does not pile up requests.
    silent_boards: u16,
    /// Smoothed round trip of a quadlet read and its mean deviation, in ns (RFC 6298 style);
    /// None before the first reply of a batch.
    srtt_ns: Option<u64>,
    rttvar_ns: u64,
    /// Until when each label is not used again: its request got no reply, which may still
    /// come, late. A quadlet reply carries no address, so a late reply whose label a later
    /// request to the same node reused would be taken for that request's register.
    quarantined_until: [Instant; 64],
    /// Requests sent with each label that got no reply in their batch or read: their replies
    /// may still come, late (a stalled board answers what it queued when it runs again). A
    /// label with some goes to its own register again first ([`Self::take_label`]), where a
    /// late reply can only be an older value of the same register. One less for each reply
    /// with the label that is taken or comes late from its node. Never forgotten by time: a
    /// board stalled for seconds answers its queue when it runs again.
    unanswered: [u16; 64],
    /// The request being sent is the one request to a board that answered nothing in its last
    /// batch or read ([`Self::take_label`]).
    probe: bool,
    /// What each label was last sent for: node, request kind and address ([`label_key`]).
    label_key: [u32; 64],
    /// Labels not to take: those of the batch under way and of the one before it (whose
    /// late replies and duplicates may still come).
    avoid_labels: u64,
    prev_batch_labels: u64,
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
            window: DEFAULT_QUADLET_WINDOW,
            widened: false,
            batch_budget: None,
            silent_boards: 0,
            srtt_ns: None,
            rttvar_ns: 0,
            quarantined_until: [Instant::now(); 64],
            unanswered: [0; 64],
            probe: false,
            label_key: [u32::MAX; 64],
            avoid_labels: 0,
            prev_batch_labels: 0,
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
    /// How many quadlet requests a batch ([`Port::read_quadlets`]) keeps outstanding at once
    /// on a lossy link (1..=[`MAX_QUADLET_WINDOW`], default [`DEFAULT_QUADLET_WINDOW`]). More
    /// hides more round trips and losses within a cycle, but every request queued at the FPGA,
    /// which serves one packet at a time, delays the console's packets behind it (reference
    /// §8.4). 1: the reads one after the other, as [`Port::read_quadlet`] does them (a lost
    /// datagram asked again after [`super::QUADLET_RETRY_WAIT`], the last attempt waiting the
    /// whole reply timeout).
    pub fn set_quadlet_window(&mut self, window: u8) {
        self.window = window.clamp(1, MAX_QUADLET_WINDOW);
    }
    pub fn quadlet_window(&self) -> u8 {
        self.window
    }
    /// The requests the next batch keeps outstanding: the window, or
    /// `LOSSY_WINDOW_FACTOR` times it (at most [`MAX_QUADLET_WINDOW`]) after a batch that
    /// showed a datagram lost. A window of 1 is never widened.
    pub fn quadlet_window_now(&self) -> u8 {
        if self.widened && self.window > 1 {
            self.window
                .saturating_mul(LOSSY_WINDOW_FACTOR)
                .min(MAX_QUADLET_WINDOW)
        } else {
            self.window
        }
    }
    /// Longest one batch waits in all (default None: no cap of its own). Each register waits at
    /// most the link's reply timeout from its newest request (as a read on its own would), and
    /// two from its first; a budget also ends the batch as a whole, leaving the registers still
    /// unanswered unread. A lost datagram never waits for either: its register is asked again
    /// after the retry wait, or as soon as a later request to the same board is answered.
    pub fn set_quadlet_batch_budget(&mut self, budget: Option<Duration>) {
        self.batch_budget = budget;
    }
    /// The retry wait a batch uses now: the measured round trip plus four deviations
    /// (`Self::batch_retry_wait`), or `None` on a link without retry.
    pub fn quadlet_retry_wait(&self) -> Option<Duration> {
        self.link.quadlet_retry().map(|r| self.batch_retry_wait(r))
    }

    /// Smoothed round trip + 4 × its deviation (RFC 6298), between [`MIN_RETRY_WAIT`] and 4
    /// times the link's wait; the link's wait until a round trip was measured.
    fn batch_retry_wait(&self, r: QuadletRetry) -> Duration {
        let hi = r.wait * 4;
        let lo = MIN_RETRY_WAIT.min(hi);
        match self.srtt_ns {
            None => r.wait,
            Some(srtt) => Duration::from_nanos(srtt.saturating_add(4 * self.rttvar_ns))
                .max(lo)
                .min(hi),
        }
    }

    /// One measured round trip. Each reply names its request by label, so even the reply to
    /// an earlier request of a register asked again gives an exact sample (no Karn ambiguity).
    fn rtt_sample(&mut self, rtt: Duration) {
        let r = u64::try_from(rtt.as_nanos())
            .unwrap_or(u64::MAX / 8)
            .min(1 << 40);
        match self.srtt_ns {
            None => {
                self.srtt_ns = Some(r);
                self.rttvar_ns = r / 2;
            }
            Some(srtt) => {
                self.rttvar_ns = (3 * self.rttvar_ns + srtt.abs_diff(r)) / 4;
                self.srtt_ns = Some((7 * srtt + r) / 8);
            }
        }
    }

    fn node(&self, board: u8) -> Result<u8, PortError> {
        self.node_of_board
            .get(board as usize)
            .copied()
            .ok_or(PortError::BoardOutOfRange { board })
    }

    /// The label for a request of `key` ([`label_key`]): never one of the batch under way; of
    /// the others, in this order (the next in turn within a class, or the one whose quarantine
    /// ended or ends first where said):
    /// 0. for the one request to a silent board ([`Self::probe`]), the label of its register's
    ///    last unanswered request, quarantined or not: a stalled board then queues requests
    ///    of one label, whose replies all answer that register when it runs again (before,
    ///    a stall of more than 64 such requests left queued replies under every label);
    /// 1. a label neither quarantined nor of the batch before, whose last request was answered;
    /// 2. one not quarantined whose last request, unanswered, was for this very register: a
    ///    reply of it that still comes is an older value of the register asked, never another
    ///    register's;
    /// 3. one of the batch before that was answered (only a duplicate of its reply may come,
    ///    and the drain before the batch throws away what came by then);
    /// 4. one not quarantined whose last request, unanswered, was for another register (the
    ///    quarantine ended first);
    /// 5. a quarantined one, this register's first, then the one whose quarantine ends first.
    ///
    /// Classes 4 and 5 for another register are counted (`labels_reused_unanswered`).
    fn take_label(&mut self, key: u32) -> u8 {
        let now = Instant::now();
        // (class, quarantine end, label): the best so far.
        let mut best: Option<(u8, Instant, u8)> = None;
        for k in 0..64u8 {
            let l = self.next_label.wrapping_add(k) & LABEL_MASK;
            let bit = 1u64 << l;
            if self.avoid_labels & bit != 0 {
                continue;
            }
            let until = self.quarantined_until[usize::from(l)];
            let unanswered = self.unanswered[usize::from(l)] > 0;
            let own = self.label_key[usize::from(l)] == key;
            // 5 and 6: class 5 of the list, this register's and another's.
            let class = if self.probe && own && unanswered {
                0
            } else if until > now {
                if own { 5 } else { 6 }
            } else if unanswered {
                if own { 2 } else { 4 }
            } else if self.prev_batch_labels & bit != 0 {
                3
            } else {
                1
            };
            // Classes 1-3 take the next in turn; 4-6 the quarantine ended or ending first; 0
            // the one asked last.
            let better = match best {
                None => true,
                Some((c, u, _)) => {
                    class < c
                        || (class == c && class >= 4 && until < u)
                        || (class == c && class == 0 && until > u)
                }
            };
            if better {
                best = Some((class, until, l));
                if class == 1 {
                    break;
                }
            }
        }
        let l = match best {
            Some((class, _, l)) => {
                if matches!(class, 4 | 6) {
                    self.counters.labels_reused_unanswered += 1;
                }
                l
            }
            None => self.next_label,
        };
        self.next_label = (l + 1) & LABEL_MASK;
        self.label_key[usize::from(l)] = key;
        l
    }

    /// A reply with label `l` was taken (at `now`): its quarantine ends, and one unanswered
    /// request less is counted, none if at most one was (a lost request, or the one this
    /// reply answered). A silent board's label asked many times keeps the rest counted until
    /// their replies come.
    fn label_answered(&mut self, l: u8, now: Instant) {
        let l = usize::from(l & LABEL_MASK);
        self.quarantined_until[l] = self.quarantined_until[l].min(now);
        self.unanswered[l] = self.unanswered[l].saturating_sub(1);
    }

    /// A reply with label `l` came from node `src` outside its batch or read: if its label was
    /// last sent to that node, one of the label's unanswered requests has its answer now, and
    /// with none left its quarantine ends.
    fn late_reply(&mut self, l: u8, src: u8) {
        let l = usize::from(l & LABEL_MASK);
        if self.label_key[l] >> 24 != u32::from(src) {
            return;
        }
        self.unanswered[l] = self.unanswered[l].saturating_sub(1);
        if self.unanswered[l] == 0 {
            self.quarantined_until[l] = self.quarantined_until[l].min(Instant::now());
        }
    }

    /// The labels in `mask` were sent and not answered: they are not used again for the
    /// link's reply timeout, so that their late replies meet no request of another register,
    /// and after it they go to their own register first ([`Self::take_label`]).
    fn quarantine(&mut self, mask: u64) {
        let now = Instant::now();
        let retry = self.link.quadlet_retry();
        for l in 0..64usize {
            if mask & (1u64 << l) != 0 {
                self.unanswered[l] = self.unanswered[l].saturating_add(1);
                if let Some(r) = retry {
                    self.quarantined_until[l] = now + r.reply_timeout;
                }
            }
        }
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
        let label = self.take_label(label_key(node, addr, kind));
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
                    self.label_answered(self.last_label, Instant::now());
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
            let (got, src) = (p.label(), p.src_node());
            self.late_reply(got, src);
            return Err(PortError::WrongLabel {
                board,
                expected: label,
                got,
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

    /// One pipelined batch of at most [`MAX_BATCH`] quadlet reads (see
    /// [`Port::read_quadlets`] on [`EthPort`]).
    fn read_batch(
        &mut self,
        reqs: &[(u8, u16)],
        out: &mut [Option<u32>],
        retry: QuadletRetry,
    ) -> Result<(), PortError> {
        let n = reqs.len().min(out.len()).min(MAX_BATCH);
        let (Some(reqs), Some(out)) = (reqs.get(..n), out.get_mut(..n)) else {
            return Ok(());
        };
        self.counters.quadlet_batches += 1;
        let start = Instant::now();
        // Each register waits at most the reply timeout from its newest request (two from its
        // first), as a read on its own would; an explicit budget also caps the batch as a whole.
        let timeout = retry.reply_timeout;
        let end = self.batch_budget.and_then(|b| start.checked_add(b));
        let attempts = batch_attempts(retry);
        let window = usize::from(self.quadlet_window_now());
        if self.resync {
            // Replies of an earlier cycle may be queued: throw them away before this batch's
            // first request. No drain happens within the batch: it would throw away replies
            // of requests still outstanding.
            self.resync = false;
            self.counters.resyncs += 1;
            self.counters.drained += self.link.discard_pending(&mut self.rx[..]) as u64;
        }
        let mut b = Batch::new(start);
        let mut first_err: Option<PortError> = None;
        let mut last_bad: Option<PortError> = None;
        for (i, (&(board, _), o)) in reqs.iter().zip(out.iter_mut()).enumerate() {
            *o = None;
            match self.node(board) {
                Ok(nd) => b.node[i] = nd,
                Err(e) => {
                    b.state[i] = Entry::Skipped;
                    first_err.get_or_insert(e);
                }
            }
        }
        let mut unexpected = false;
        let mut received = 0usize;
        let mut rto = self.batch_retry_wait(retry);
        // Doublings of the wait after a repeat asked for silence (reset by a reply).
        let mut backoff = 0u32;
        loop {
            let now = Instant::now();
            // Registers known lost (a later request to their board was answered) are asked
            // again now. A request past its due time without that knowledge may be slow
            // rather than lost (a board or host busy for a while): per board only the oldest
            // is asked again, the others wait with it, and each such repeat doubles the wait
            // of the next until a reply comes, so a stall costs a few requests, not a flood.
            // Labels are kept for the registers not asked yet.
            let unsent = (0..n)
                .filter(|&i| b.state[i] == Entry::Unsent && b.failed & board_bit(reqs[i].0) == 0)
                .count();
            for i in 0..n {
                if b.state[i] != Entry::InFlight || now < b.due[i] || now >= b.deadline[i] {
                    continue;
                }
                let (board, addr) = reqs[i];
                let bit = board_bit(board);
                let silent = self.silent_boards & bit & !b.answered != 0;
                if silent || b.failed & bit != 0 {
                    // A board silent in its last batch (one request, its timeout), or one that
                    // gave up on another register: any of its replies is taken until its
                    // deadline.
                    b.due[i] = b.deadline[i];
                    continue;
                }
                if b.sends[i] >= attempts
                    || usize::from(b.labels_used) + unsent >= usize::from(MAX_BATCH_LABELS)
                {
                    // Asked as often as allowed: its last request waits a whole reply timeout
                    // from here, as the last attempt of a read on its own does (within the
                    // register's limit), and any of its replies is taken until then.
                    b.renew(i, now + timeout);
                    b.due[i] = b.deadline[i];
                    continue;
                }
                let wait = if b.lost[i] {
                    rto
                } else if b.older_past_due(n, i, now) {
                    continue;
                } else {
                    let w = rto.saturating_mul(1 << backoff);
                    backoff = (backoff + 1).min(MAX_BACKOFF_SHIFT);
                    w
                };
                // Each request gets the whole reply timeout: the register's deadline counts
                // from its newest request (at most two timeouts after its first, within the
                // batch's budget), so a host or board stall that outlasts the timeout of the
                // first request costs no more than it did one read at a time.
                b.renew(i, now + timeout);
                let due = if b.sends[i] + 1 >= attempts {
                    b.deadline[i]
                } else {
                    now.checked_add(wait)
                        .map_or(b.deadline[i], |t| t.min(b.deadline[i]))
                };
                match b.ask(self, i, addr, now, due) {
                    Ok(()) => {
                        self.counters.quadlet_retries += 1;
                        b.wait_with(n, i, now);
                    }
                    Err(e) => {
                        first_err.get_or_insert(e);
                        b.state[i] = Entry::GivenUp;
                        b.failed |= bit;
                    }
                }
            }
            // New requests, in order, while fewer than `window` are outstanding.
            if end.is_none_or(|e| now < e) {
                let mut in_flight = b.state[..n]
                    .iter()
                    .filter(|s| **s == Entry::InFlight)
                    .count();
                for i in 0..n {
                    if in_flight >= window || b.labels_used >= MAX_BATCH_LABELS {
                        break;
                    }
                    if b.state[i] != Entry::Unsent {
                        continue;
                    }
                    let (board, addr) = reqs[i];
                    let bit = board_bit(board);
                    if b.failed & bit != 0 {
                        b.state[i] = Entry::Skipped;
                        continue;
                    }
                    // A board silent in its last batch gets one request until it answers.
                    let silent = self.silent_boards & bit & !b.answered != 0;
                    if silent && b.asked & bit != 0 {
                        continue;
                    }
                    let deadline = now + timeout;
                    b.deadline[i] = end.map_or(deadline, |e| deadline.min(e));
                    let limit = deadline + timeout;
                    b.limit[i] = end.map_or(limit, |e| limit.min(e));
                    // The one request to a silent board waits until its deadline.
                    let due = if silent || attempts <= 1 {
                        b.deadline[i]
                    } else {
                        (now + rto).min(b.deadline[i])
                    };
                    self.probe = silent;
                    let asked = b.ask(self, i, addr, now, due);
                    self.probe = false;
                    match asked {
                        Ok(()) => {
                            b.asked |= bit;
                            in_flight += 1;
                        }
                        Err(e) => {
                            first_err.get_or_insert(e);
                            b.state[i] = Entry::Skipped;
                            b.failed |= bit;
                        }
                    }
                }
            }
            // Nothing in flight: what is left can not be asked in this batch.
            let Some(next) = b.next_due(n) else {
                break;
            };
            let wait = next.saturating_duration_since(now);
            let got = match self.link.recv_within(&mut self.rx[..], wait) {
                Ok(len) => len,
                Err(PortError::Timeout { .. }) => {
                    // Nothing queued, so no reply is waiting to be read (replies that arrived
                    // while this process was not running, a stall of the host, have been):
                    // the registers past their deadline are given up.
                    let now = Instant::now();
                    for i in 0..n {
                        if b.state[i] == Entry::InFlight && now >= b.deadline[i] {
                            b.state[i] = Entry::GivenUp;
                            b.failed |= board_bit(reqs[i].0);
                        }
                    }
                    continue;
                }
                Err(e) => {
                    first_err.get_or_insert(e);
                    unexpected = true;
                    break;
                }
            };
            received += 1;
            if received > MAX_BATCH_DATAGRAMS {
                // More datagrams than the batch's requests can explain: a flood, not replies.
                unexpected = true;
                break;
            }
            match self.validate(
                got,
                UNKNOWN_BOARD,
                None,
                0,
                b.accept,
                Expect::Quadlet,
                &mut [],
            ) {
                Ok((v, src)) => {
                    let l = usize::from(self.last_label & LABEL_MASK);
                    let i = usize::from(b.label_entry[l]);
                    let fresh = matches!(b.state.get(i), Some(Entry::InFlight | Entry::GivenUp));
                    if !fresh || b.node.get(i) != Some(&src) {
                        // A duplicate, or a reply from a node this label was not sent to.
                        self.counters.stale_replies += 1;
                        unexpected = true;
                        continue;
                    }
                    if let Some(o) = out.get_mut(i) {
                        *o = Some(v);
                    }
                    b.state[i] = Entry::Done;
                    b.answered_by[i] = l as u8;
                    let now = Instant::now();
                    self.label_answered(l as u8, now);
                    b.taken += 1;
                    b.answered |= board_bit(reqs[i].0);
                    self.counters.replies_ok += 1;
                    self.rtt_sample(now.saturating_duration_since(b.sent_at[l]));
                    rto = self.batch_retry_wait(retry);
                    backoff = 0;
                    b.overtaken(n, src, b.label_rank[l], retry, now);
                }
                Err(PortError::WrongLabel { .. } | PortError::WrongSource { .. }) => {
                    // Not of this batch: a late reply of an earlier cycle, skipped.
                    self.counters.stale_replies += 1;
                    unexpected = true;
                }
                Err(e @ (PortError::BusReset { .. } | PortError::InternalError { .. })) => {
                    // The cycle is not trusted, as with a single read.
                    self.counters.bad_replies += 1;
                    unexpected = true;
                    first_err.get_or_insert(e);
                }
                Err(e) => {
                    // A damaged or dropped reply: like a lost one, its register is asked again.
                    self.counters.bad_replies += 1;
                    unexpected = true;
                    last_bad = Some(e);
                }
            }
        }
        // Replies still to come (requests outstanding, lost or late) must not meet the next
        // request unchecked: drain before it.
        self.resync = unexpected || b.labels_used > b.taken;
        let mut answered_labels = 0u64;
        for l in 0..64usize {
            let i = usize::from(b.label_entry[l]);
            if b.accept & (1u64 << l) != 0 && b.answered_by.get(i) == Some(&(l as u8)) {
                answered_labels |= 1u64 << l;
            }
        }
        self.quarantine(b.accept & !answered_labels);
        self.avoid_labels = 0;
        self.prev_batch_labels = b.accept;
        self.silent_boards = (self.silent_boards | b.asked) & !b.answered;
        self.widened = b.shown_lost;
        if b.asked != 0 {
            self.link_answers = b.answered != 0;
        }
        let mut unread = false;
        let mut given_up = false;
        for (i, &(board, addr)) in reqs.iter().enumerate() {
            match b.state[i] {
                Entry::Done => {}
                Entry::Skipped => {
                    // Not asked because its board gave up on another register (whose reply
                    // may still have come late): unread, and the batch says why.
                    unread = true;
                    first_err.get_or_insert(match last_bad {
                        Some(e) => e,
                        None => PortError::Timeout { board, addr },
                    });
                }
                Entry::Unsent | Entry::InFlight | Entry::GivenUp => {
                    unread = true;
                    given_up |= b.state[i] == Entry::GivenUp;
                    self.counters.timeouts += u64::from(b.state[i] != Entry::Unsent);
                    first_err.get_or_insert(match last_bad {
                        Some(e) => e,
                        None => PortError::Timeout { board, addr },
                    });
                }
            }
        }
        if unread && (given_up || end.is_some_and(|e| Instant::now() >= e)) {
            self.counters.batch_deadlines += 1;
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
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
        // After a read without any reply, this one request is a silent board's.
        let probe = !self.link_answers;
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
            self.avoid_labels = accept;
            self.probe = probe;
            let sent = self.send_request(node, addr, RequestKind::QuadletRead, &[], self.noforward);
            self.probe = false;
            self.avoid_labels = 0;
            let label = match sent {
                Ok(l) => l,
                Err(e) => {
                    self.quarantine(accept);
                    return Err(e);
                }
            };
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
                    self.quarantine(accept);
                    return Err(e);
                }
                r => {
                    if r.is_ok() {
                        self.link_answers = true;
                        self.adapt_retry_wait(retry, self.last_label != label);
                        // The other requests of the read may still be answered, late.
                        self.quarantine(accept & !(1u64 << (self.last_label & LABEL_MASK)));
                    } else {
                        self.quarantine(accept);
                    }
                    return r.map(|(v, _)| v);
                }
            }
        }
    }

    /// On a lossy link ([`Link::quadlet_retry`]) with a window above 1
    /// ([`EthPort::set_quadlet_window`]): up to `window` requests outstanding at once, each with
    /// its own label. A reply is taken for the register its label was sent for, and only from
    /// the node it was sent to; a reply whose label is not one of this batch's (a late reply of
    /// an earlier cycle) or that answers a register already read is skipped. A register whose
    /// request or reply was lost is asked again with a new label, up to twice the link's number
    /// of attempts: as soon as a later request to the same node is answered (a board answers in
    /// order), else after the retry wait (the measured round trip + 4 deviations, see
    /// [`EthPort::quadlet_retry_wait`]); a reply to any of its requests is taken. Each register
    /// is given up at its own deadline, the link's reply timeout counted from its newest
    /// request but at most two from its first (or the batch's budget,
    /// [`EthPort::set_quadlet_batch_budget`]), and only when no reply is queued: replies that
    /// arrived while this process was not running are read first. A board whose register was
    /// given up is not asked again in the batch. A board that answered nothing in its last
    /// batch gets one request per batch until it answers (as
    /// [`Port::read_quadlet`] asks once after a read without reply), so a stall does not pile
    /// up requests at it. Otherwise (a window of 1, a link without retry) the reads go one
    /// after the other.
    fn read_quadlets(
        &mut self,
        reqs: &[(u8, u16)],
        out: &mut [Option<u32>],
    ) -> Result<(), PortError> {
        let Some(retry) = self.link.quadlet_retry().filter(|_| self.window > 1) else {
            return read_quadlets_in_turn(self, reqs, out);
        };
        let mut first_err = None;
        for (r, o) in reqs.chunks(MAX_BATCH).zip(out.chunks_mut(MAX_BATCH)) {
            if let Err(e) = self.read_batch(r, o, retry) {
                first_err.get_or_insert(e);
            }
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
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
        let r = self.await_reply(board, addr, Some(node), label, Expect::Block(len), out);
        if r.is_err() {
            self.quarantine(1u64 << (label & LABEL_MASK));
        }
        r.map(|_| ())
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

/// What a label was last sent for ([`EthPort::take_label`]): node, request kind and address.
fn label_key(node: u8, addr: u16, kind: RequestKind) -> u32 {
    let k: u32 = match kind {
        RequestKind::QuadletRead => 0,
        RequestKind::QuadletWrite { .. } => 1,
        RequestKind::BlockRead { .. } => 2,
        RequestKind::BlockWrite { .. } => 3,
    };
    (u32::from(node) << 24) | (k << 16) | u32::from(addr)
}

/// Requests one register of a batch may take: twice a single read's attempts. A register is
/// asked again as soon as its loss is known, so the attempts are cheap (at 10% loss each way a
/// register then fails once in 10^6); the last one waits until the register's deadline.
fn batch_attempts(r: QuadletRetry) -> u8 {
    r.attempts.max(1).saturating_mul(2)
}

/// Bit of `board` in a 16-board mask (0 for an id out of range, refused before it is asked).
fn board_bit(board: u8) -> u16 {
    1u16.checked_shl(u32::from(board)).unwrap_or(0)
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
