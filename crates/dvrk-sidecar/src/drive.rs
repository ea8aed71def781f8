//! `drive`: a stand-in for the dVRK console's I/O loop, for tests and benches against the
//! emulator (`sim`). It talks to the boards the way the dVRK host library does over UDP
//! (reference §3.3, §3.4, §10): discovery by subnet broadcast, multicast once the hub reports
//! Rev 9, per-board unicast in Ethernet-only mode (base address + board id) or unicast to the
//! hub in bridge mode; then every cycle it reads all boards with the chosen protocol and writes
//! a zero-current command, which refreshes the watchdog it set at start.
//!
//! It writes to the boards, so it refuses any address that is not loopback: it exists to load
//! the emulator like a console does, never to drive a robot.
//!
//! Which boards: by default every board the node scan finds. With `--arms PSM1,PSM2` it runs
//! the I/O of those arms, as a console configured with them does: exactly their boards (PSM1
//! 6-7, PSM2 8-9, PSM3 10-11) in its reads, query mask and command blocks, and it stops with
//! an error naming any of them that discovery did not find (e.g. against `sim --arms
//! PSM1,PSM2`, the console traffic of both arms).
//!
//! The loop allocates nothing: buffers and the record are reserved before the first cycle.
//! At the end it prints its cycle statistics (`drive: ...` lines on stdout) and, with
//! `--record`, one CSV line per cycle with the board timestamps and encoder counts it read:
//! `cycle,t_start_ns,t_read_ns,ok`, then `ts<i>` per board, then `c<i>_<axis>` per board and
//! axis 0-3, boards in ascending id (two boards: `ts0,ts1,c0_0..c0_3,c1_0..c1_3`).

use std::io::Write;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::os::fd::AsRawFd;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use dvrk_io::wire::firewire::{BROADCAST_NODE, LABEL_MASK};
use dvrk_io::wire::hub::MAX_HUB_BOARDS;
use dvrk_io::wire::hub::{HUB_ADDRESS, QUERY_ADDRESS};
use dvrk_io::wire::{
    BlockLayout, BoardKind, BoardStatus, ControlWord, EthReply, EthRequest, FeedbackBlock,
    HubHeader, RequestKind, RequestRepr, ResponseKind, ResponseRepr,
};
use tracing::info;

use crate::rt;
use crate::signals::StopFlag;
use crate::stats::DurationHistogram;
use crate::text::num;

/// The boards' UDP port (reference §3.1).
const BOARD_PORT: u16 = 1394;
/// The Rev 9 multicast group (reference §3.1).
const MULTICAST: Ipv4Addr = Ipv4Addr::new(224, 0, 0, 100);
/// The dVRK host's receive timeout (reference §3.1).
const RECV_TIMEOUT: Duration = Duration::from_millis(20);
/// Watchdog period written at start: 30 ms in units of 256/49.152 MHz (reference §1.2).
const WATCHDOG_30MS: u32 = 0x1680;
/// QLA DAC code of zero current (reference §4).
const DAC_ZERO: u32 = 0x8000;
/// Register numbers (reference §1.2).
const REG_STATUS: u16 = 0;
const REG_PHY_REQUEST: u16 = 1;
const REG_WATCHDOG: u16 = 3;
const REG_HARDWARE: u16 = 4;
const REG_FIRMWARE: u16 = 7;
const REG_IP: u16 = 11;
const REG_ETH_STATUS: u16 = 12;
const REG_GIT: u16 = 15;

/// The console's read/write protocols (reference §3.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Protocol {
    /// One block read and one block write per board.
    SequentialReadWrite,
    /// One block read per board, one broadcast write (the dVRK default).
    SequentialReadBroadcastWrite,
    /// Broadcast query plus the hub's data (read in bridge mode, sent unasked in
    /// Ethernet-only mode), one broadcast write.
    BroadcastQueryReadWrite,
}

#[derive(clap::Args)]
pub struct DriveArgs {
    /// The boards' base address as the dVRK port string has it (`udp:IP`): IP or IP:PORT.
    /// Loopback only.
    #[arg(long, default_value = "127.0.0.1")]
    boards: String,
    /// Read/write protocol (reference §3.4).
    #[arg(long, value_enum, default_value_t = Protocol::SequentialReadBroadcastWrite)]
    protocol: Protocol,
    /// Cycle rate, Hz (the dVRK console's I/O runs at 1500).
    #[arg(long, default_value_t = 1500.0)]
    rate: f64,
    /// Stop after this many seconds (default: at SIGTERM/SIGINT).
    #[arg(long)]
    duration: Option<f64>,
    /// Write one CSV line per cycle: the read's time, board timestamps and encoder counts.
    #[arg(long)]
    record: Option<PathBuf>,
    /// The console's arms, comma-separated Classic PSMs (PSM1 boards 6-7, PSM2 8-9, PSM3
    /// 10-11): read and write exactly their boards, and fail if one is not found. Default:
    /// every board discovery finds.
    #[arg(long, value_name = "ARM,ARM")]
    arms: Option<String>,
}

/// What discovery found.
#[derive(Clone, Debug)]
struct Found {
    hub: u8,
    hub_firmware: u32,
    ethernet_only: bool,
    /// Board ids, ascending.
    boards: Vec<u8>,
}

/// One cycle's read, as recorded (boards in the order driven, at most a full chain).
#[derive(Clone, Copy, Debug, Default)]
struct CycleRecord {
    t_start_ns: u64,
    t_read_ns: u64,
    ok: bool,
    timestamp: [u32; MAX_HUB_BOARDS],
    counts: [[i32; 4]; MAX_HUB_BOARDS],
}

/// The stand-in's UDP engine: addressing like the dVRK host library, labels, generation.
struct Console {
    sock: UdpSocket,
    base: Ipv4Addr,
    port: u16,
    broadcast: Ipv4Addr,
    hub: u8,
    hub_firmware: u32,
    ethernet_only: bool,
    /// Before the mode is known the library sets NOFORWARD on everything (reference §9).
    mode_known: bool,
    generation: u8,
    label: u8,
    tx: Vec<u8>,
    rx: Vec<u8>,
    requests: u64,
    timeouts: u64,
}

/// Subnet broadcast derived from the address class, as the host library does (reference §10).
fn class_broadcast(ip: Ipv4Addr) -> Ipv4Addr {
    let o = ip.octets();
    match o[0] {
        0..128 => Ipv4Addr::new(o[0], 255, 255, 255),
        128..192 => Ipv4Addr::new(o[0], o[1], 255, 255),
        192..224 => Ipv4Addr::new(o[0], o[1], o[2], 255),
        _ => Ipv4Addr::BROADCAST,
    }
}

fn plus(base: Ipv4Addr, n: u8) -> Ipv4Addr {
    let o = base.octets();
    Ipv4Addr::new(o[0], o[1], o[2], o[3].wrapping_add(n))
}

/// Sends multicast out of the interface with address `ifa` (IP_MULTICAST_IF).
fn set_multicast_if(sock: &UdpSocket, ifa: Ipv4Addr) -> std::io::Result<()> {
    let addr = libc::in_addr {
        s_addr: u32::from_ne_bytes(ifa.octets()),
    };
    // SAFETY: a valid socket fd and a pointer to a live in_addr of the size passed.
    let r = unsafe {
        libc::setsockopt(
            sock.as_raw_fd(),
            libc::IPPROTO_IP,
            libc::IP_MULTICAST_IF,
            (&addr as *const libc::in_addr).cast(),
            std::mem::size_of::<libc::in_addr>() as libc::socklen_t,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Dest {
    /// Discovery before the hub's firmware is known: subnet broadcast, then multicast.
    EthBroadcast,
    /// A request to a node (0x3F = every board).
    Node(u8),
}

impl Console {
    fn open(base: Ipv4Addr, port: u16) -> Result<Self> {
        let sock = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0)).context("binding a UDP socket")?;
        sock.set_broadcast(true)?;
        sock.set_read_timeout(Some(RECV_TIMEOUT))?;
        set_multicast_if(&sock, base).context("setting the multicast interface")?;
        Ok(Self {
            sock,
            base,
            port,
            broadcast: class_broadcast(base),
            hub: 0,
            hub_firmware: 0,
            ethernet_only: false,
            mode_known: false,
            generation: 0,
            label: 0,
            tx: vec![0; 2048],
            rx: vec![0; 4096],
            requests: 0,
            timeouts: 0,
        })
    }

    fn destination(&self, dest: Dest) -> Ipv4Addr {
        match dest {
            Dest::EthBroadcast if self.hub_firmware >= 9 => MULTICAST,
            Dest::EthBroadcast => self.broadcast,
            Dest::Node(_) if !self.ethernet_only => {
                if self.hub_firmware >= 9 {
                    plus(self.base, self.hub)
                } else {
                    self.base
                }
            }
            Dest::Node(n) if n < 16 => plus(self.base, n),
            Dest::Node(_) => MULTICAST,
        }
    }

    fn send(
        &mut self,
        dest: Dest,
        noforward: bool,
        offset: u16,
        kind: RequestKind,
        payload: &[u8],
    ) -> Result<u8> {
        let node = match dest {
            Dest::EthBroadcast => BROADCAST_NODE,
            Dest::Node(n) => n,
        };
        // Incremented before use, as the host library does (its first request has label 1, §9).
        self.label = (self.label + 1) & LABEL_MASK;
        let label = self.label;
        let nf = noforward || !self.mode_known || self.ethernet_only;
        let req = RequestRepr::host(node, label, u64::from(offset), kind);
        let n = EthRequest::emit(
            &mut self.tx,
            ControlWord::new(nf, self.generation),
            &req,
            payload,
        )
        .map_err(|e| anyhow::anyhow!("building a request: {e}"))?;
        let to = SocketAddrV4::new(self.destination(dest), self.port);
        self.sock
            .send_to(&self.tx[..n], to)
            .with_context(|| format!("sending to {to}"))?;
        self.requests += 1;
        Ok(label)
    }

    /// Waits for the response with `label`; returns (source node, quadlet data, block range in
    /// `rx`). Stale labels are skipped. `None` on timeout.
    fn recv(&mut self, label: u8) -> Option<(u8, u32, std::ops::Range<usize>)> {
        loop {
            let n = match self.sock.recv(&mut self.rx) {
                Ok(n) => n,
                Err(_) => {
                    self.timeouts += 1;
                    return None;
                }
            };
            let Ok(reply) = EthReply::parse(&self.rx[..n]) else {
                continue;
            };
            self.generation = reply.extra.bus_generation;
            let Some(p) = reply.packet else { continue };
            let Ok(resp) = ResponseRepr::parse(&p) else {
                continue;
            };
            if resp.label != label {
                continue;
            }
            return Some(match resp.kind {
                ResponseKind::Quadlet { data } => (p.src_node(), data, 0..0),
                ResponseKind::Block { len } => (p.src_node(), 0, 20..20 + usize::from(len)),
            });
        }
    }

    fn read_quadlet(&mut self, dest: Dest, noforward: bool, addr: u16) -> Option<(u8, u32)> {
        let label = self
            .send(dest, noforward, addr, RequestKind::QuadletRead, &[])
            .ok()?;
        self.recv(label).map(|(src, v, _)| (src, v))
    }

    fn write_quadlet(&mut self, dest: Dest, addr: u16, data: u32) -> Result<u8> {
        self.send(dest, false, addr, RequestKind::QuadletWrite { data }, &[])
    }

    /// Reference §3.3 with the host library's order (EthUdpPort::InitNodes, ScanNodes).
    fn discover(&mut self) -> Result<Found> {
        let ip = u32::from_le_bytes(self.base.octets());
        self.write_quadlet(Dest::EthBroadcast, REG_IP, ip)?;
        std::thread::sleep(Duration::from_millis(200));
        let (_, hw) = self
            .read_quadlet(Dest::EthBroadcast, true, REG_HARDWARE)
            .context("no reply to the broadcast read of the hub's hardware version")?;
        BoardKind::from_hardware_version(hw).map_err(|e| anyhow::anyhow!("hub board: {e}"))?;
        self.write_quadlet(Dest::EthBroadcast, REG_PHY_REQUEST, 0)?;
        std::thread::sleep(Duration::from_millis(10));
        let (_, status) = self
            .read_quadlet(Dest::EthBroadcast, true, REG_STATUS)
            .context("hub board: no reply to its status read")?;
        self.hub = BoardStatus::new(status, BoardKind::Qla).board_id();
        let (_, fw) = self
            .read_quadlet(Dest::EthBroadcast, true, REG_FIRMWARE)
            .context("hub board: no reply to its firmware-version read")?;
        self.hub_firmware = fw;
        let (_, eth) = self
            .read_quadlet(Dest::EthBroadcast, true, REG_ETH_STATUS)
            .context("hub board: no reply to its Ethernet-status read")?;
        let v3 = eth >> 30 == 0b01;
        self.ethernet_only = v3 && fw >= 9;
        self.mode_known = true;
        let mut boards = Vec::new();
        for node in 0u8..16 {
            let Some((_, hw)) = self.read_quadlet(Dest::Node(node), false, REG_HARDWARE) else {
                continue;
            };
            if BoardKind::from_hardware_version(hw).is_err() {
                continue;
            }
            let fw = self.read_quadlet(Dest::Node(node), false, REG_FIRMWARE);
            let _eth = self.read_quadlet(Dest::Node(node), false, REG_ETH_STATUS);
            let st = self.read_quadlet(Dest::Node(node), false, REG_STATUS);
            let _git = self.read_quadlet(Dest::Node(node), false, REG_GIT);
            let (Some((_, fw)), Some((_, st))) = (fw, st) else {
                bail!("node {node}: answered its hardware version but not its firmware or status");
            };
            if fw != 9 && fw != 8 {
                bail!("node {node}: firmware Rev {fw}; the stand-in drives Rev 8/9 boards");
            }
            let id = BoardStatus::new(st, BoardKind::Qla).board_id();
            if id != node {
                bail!("node {node} reports board id {id}; the stand-in expects node = board id");
            }
            boards.push(id);
        }
        if boards.is_empty() {
            bail!("no board answered the node scan");
        }
        Ok(Found {
            hub: self.hub,
            hub_firmware: self.hub_firmware,
            ethernet_only: self.ethernet_only,
            boards,
        })
    }
}

fn parse_boards(s: &str) -> Result<(Ipv4Addr, u16)> {
    let (ip, port) = match s.parse::<SocketAddr>() {
        Ok(a) => (a.ip(), a.port()),
        Err(_) => (
            s.parse::<IpAddr>()
                .map_err(|_| anyhow::anyhow!("--boards \"{s}\": not an IP address or IP:PORT"))?,
            BOARD_PORT,
        ),
    };
    let IpAddr::V4(ip) = ip else {
        bail!("--boards \"{s}\": the boards speak IPv4");
    };
    if !ip.is_loopback() {
        bail!(
            "--boards \"{s}\": drive writes to the boards (zero current, watchdog); it runs only \
             against the emulator on loopback (127.0.0.0/8), never against a robot"
        );
    }
    Ok((ip, port))
}

/// Command block of one QLA (Rev 8+, reference §4): header, 4 motor quadlets (valid, zero
/// current, amplifiers untouched), control word 0.
fn command_block(id: u8, out: &mut [u8]) {
    let words: [u32; 6] = [
        (u32::from(id) << 8) | 6,
        (1 << 31) | DAC_ZERO,
        (1 << 31) | DAC_ZERO,
        (1 << 31) | DAC_ZERO,
        (1 << 31) | DAC_ZERO,
        0,
    ];
    for (k, w) in words.iter().enumerate() {
        if let Some(s) = out.get_mut(4 * k..4 * k + 4) {
            s.copy_from_slice(&w.to_be_bytes());
        }
    }
}

/// Decodes one board's feedback block into the record slot `slot`.
fn take_block(rec: &mut CycleRecord, slot: usize, data: &[u8], lay: BlockLayout) -> bool {
    let Ok(b) = FeedbackBlock::new_checked(data, lay) else {
        return false;
    };
    let (Some(ts), Some(counts)) = (rec.timestamp.get_mut(slot), rec.counts.get_mut(slot)) else {
        return true;
    };
    *ts = b.timestamp().0;
    for (axis, c) in counts.iter_mut().enumerate() {
        *c = b.encoder_position(axis).map_or(0, |e| e.counts());
    }
    true
}

/// The boards to drive: those of `--arms` (ascending id), all of which discovery must have
/// found, or every board found.
fn boards_to_drive(arms: Option<&str>, found: &[u8]) -> Result<Vec<u8>> {
    let Some(text) = arms else {
        return Ok(found.to_vec());
    };
    let mut want: Vec<u8> = crate::simcmd::parse_arms(Some(text))?
        .iter()
        .flat_map(|(_, b)| *b)
        .collect();
    want.sort_unstable();
    let missing: Vec<u8> = want
        .iter()
        .copied()
        .filter(|b| !found.contains(b))
        .collect();
    if !missing.is_empty() {
        bail!("--arms {text}: board(s) {missing:?} did not answer the node scan (found {found:?})");
    }
    Ok(want)
}

/// The record's CSV header for `n` boards.
fn record_header(n: usize) -> String {
    use std::fmt::Write as _;
    let mut h = String::from("cycle,t_start_ns,t_read_ns,ok");
    for i in 0..n {
        let _ = write!(h, ",ts{i}");
    }
    for i in 0..n {
        for a in 0..4 {
            let _ = write!(h, ",c{i}_{a}");
        }
    }
    h.push('\n');
    h
}

pub fn run(args: &DriveArgs) -> Result<()> {
    let (base, port) = parse_boards(&args.boards)?;
    if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 20_000.0) {
        bail!("--rate {}: must be in (0, 20000] Hz", num(args.rate));
    }
    if let Some(a) = &args.arms {
        crate::simcmd::parse_arms(Some(a))?;
    }
    let stop = StopFlag::install()?;
    let mut c = Console::open(base, port)?;
    let mut found = c
        .discover()
        .with_context(|| format!("discovering the boards at {base}:{port}"))?;
    found.boards = boards_to_drive(args.arms.as_deref(), &found.boards)?;
    if found.boards.len() > MAX_HUB_BOARDS {
        bail!(
            "{} boards: a chain has at most {MAX_HUB_BOARDS}",
            found.boards.len()
        );
    }
    let local = c.sock.local_addr()?;
    info!(
        boards = ?found.boards, hub = found.hub, firmware = found.hub_firmware,
        mode = if found.ethernet_only { "ethernet-only" } else { "bridge" },
        protocol = ?args.protocol, local = %local, "console stand-in ready"
    );
    println!(
        "drive: local_port={} boards={:?} hub={} mode={}",
        local.port(),
        found.boards,
        found.hub,
        if found.ethernet_only {
            "ethernet-only"
        } else {
            "bridge"
        }
    );
    let _ = std::io::stdout().flush();

    let lay = BlockLayout::new(9, BoardKind::Qla).map_err(|e| anyhow::anyhow!("{e}"))?;
    let nb = found.boards.len();
    let mask: u16 = found.boards.iter().fold(0, |m, id| m | (1 << id));
    // Watchdog on, as the console does at start (reference §4).
    for &id in &found.boards {
        c.write_quadlet(Dest::Node(id), REG_WATCHDOG, WATCHDOG_30MS)?;
    }
    let period_ns = (1e9 / args.rate).round() as u64;
    let cycles_cap = args
        .duration
        .map_or(0, |d| (d * args.rate * 1.1) as usize + 16)
        .min(10_000_000);
    let mut records: Vec<CycleRecord> =
        Vec::with_capacity(if args.record.is_some() { cycles_cap } else { 0 });
    let mut cmd = vec![0u8; 24 * nb];
    for (i, &id) in found.boards.iter().enumerate() {
        command_block(id, &mut cmd[24 * i..24 * (i + 1)]);
    }
    let hub_len = nb * (lay.len_bytes() + 4) + 4;
    let mut hist = DurationHistogram::new();
    let (mut cycles, mut overruns, mut read_failures, mut late_starts) = (0u64, 0u64, 0u64, 0u64);
    let mut seq: u16 = 0;
    let t0 = rt::monotonic_ns();
    let end = args.duration.map(|d| t0 + (d * 1e9) as u64);
    let mut deadline = t0 + period_ns;
    let requests_before = c.requests;

    while !stop.raised() && end.is_none_or(|e| deadline < e) {
        rt::sleep_until_ns(deadline);
        let t_start = rt::monotonic_ns();
        if t_start > deadline + period_ns / 2 {
            late_starts += 1;
        }
        let mut rec = CycleRecord {
            t_start_ns: t_start,
            ok: true,
            ..Default::default()
        };
        match args.protocol {
            Protocol::SequentialReadWrite | Protocol::SequentialReadBroadcastWrite => {
                for (slot, &id) in found.boards.iter().enumerate() {
                    let len = lay.len_bytes() as u16;
                    let got = c
                        .send(
                            Dest::Node(id),
                            false,
                            0,
                            RequestKind::BlockRead { len },
                            &[],
                        )
                        .ok()
                        .and_then(|l| c.recv(l));
                    match got {
                        Some((src, _, r)) if src == id && r.len() == lay.len_bytes() => {
                            let data = &c.rx[r];
                            rec.ok &= take_block(&mut rec, slot, data, lay);
                        }
                        _ => rec.ok = false,
                    }
                }
            }
            Protocol::BroadcastQueryReadWrite => {
                seq = seq.wrapping_add(1);
                let q = (u32::from(seq) << 16) | u32::from(mask);
                let ql = c.write_quadlet(Dest::Node(BROADCAST_NODE), QUERY_ADDRESS, q);
                let got = if found.ethernet_only {
                    // The hub sends its data unasked, with the query's label (reference §3.4).
                    ql.ok().and_then(|l| c.recv(l))
                } else {
                    // Bridge: wait 10 + 10·(Nb−1) µs, then read the hub memory (reference §3.4).
                    std::thread::sleep(Duration::from_micros(10 + 10 * (nb as u64 - 1)));
                    c.send(
                        Dest::Node(found.hub),
                        false,
                        HUB_ADDRESS,
                        RequestKind::BlockRead {
                            len: hub_len as u16,
                        },
                        &[],
                    )
                    .ok()
                    .and_then(|l| c.recv(l))
                };
                match got {
                    Some((_, _, r)) if r.len() == hub_len => {
                        let data = &c.rx[r];
                        let mut off = 0;
                        let mut seen = 0;
                        while let Some(h) = data.get(off..off + 4) {
                            let h = HubHeader(u32::from_be_bytes([h[0], h[1], h[2], h[3]]));
                            let size = h.size_quadlets() as usize;
                            if size != lay.len_quadlets() + 1 || h.sequence_lsb() != seq as u8 {
                                break;
                            }
                            let Some(blk) = data.get(off + 4..off + size * 4) else {
                                break;
                            };
                            let id = FeedbackBlock::new_checked(blk, lay)
                                .map(|b| b.status().board_id())
                                .unwrap_or(0xFF);
                            if let Some(slot) = found.boards.iter().position(|&b| b == id) {
                                rec.ok &= take_block(&mut rec, slot, blk, lay);
                                seen += 1;
                            }
                            off += size * 4;
                        }
                        rec.ok &= seen == nb;
                    }
                    _ => rec.ok = false,
                }
            }
        }
        rec.t_read_ns = rt::monotonic_ns();
        match args.protocol {
            Protocol::SequentialReadWrite => {
                for (i, &id) in found.boards.iter().enumerate() {
                    let _ = c.send(
                        Dest::Node(id),
                        false,
                        0,
                        RequestKind::BlockWrite { len: 24 },
                        &cmd[24 * i..24 * (i + 1)],
                    );
                }
            }
            _ => {
                let len = cmd.len() as u16;
                let _ = c.send(
                    Dest::Node(BROADCAST_NODE),
                    false,
                    0,
                    RequestKind::BlockWrite { len },
                    &cmd,
                );
            }
        }
        let t_end = rt::monotonic_ns();
        hist.record(t_end - t_start);
        cycles += 1;
        if !rec.ok {
            read_failures += 1;
        }
        if t_end > deadline + period_ns {
            overruns += 1;
        }
        if records.len() < records.capacity() {
            records.push(rec);
        }
        deadline += period_ns;
        if t_end > deadline + period_ns {
            deadline = t_end + period_ns;
        }
    }
    let elapsed_s = (rt::monotonic_ns() - t0) as f64 * 1e-9;
    let q = |p: f64| hist.quantile_ns(p).unwrap_or(0) as f64 / 1e3;
    println!(
        "drive: protocol={:?} rate_hz={} cycles={} elapsed_s={:.3} cycle_p50_us={:.1} cycle_p99_us={:.1} cycle_max_us={:.1} overruns={} read_failures={} late_starts={} missed={} requests={} timeouts={}",
        args.protocol,
        args.rate,
        cycles,
        elapsed_s,
        q(0.5),
        q(0.99),
        hist.max_ns() as f64 / 1e3,
        overruns,
        read_failures,
        late_starts,
        overruns + read_failures,
        c.requests - requests_before,
        c.timeouts
    );
    if let Some(path) = &args.record {
        let mut out = String::with_capacity(records.len() * (48 + 60 * nb) + 128);
        out.push_str(&record_header(nb));
        for (i, r) in records.iter().enumerate() {
            use std::fmt::Write as _;
            let _ = write!(
                out,
                "{i},{},{},{}",
                r.t_start_ns,
                r.t_read_ns,
                u8::from(r.ok)
            );
            for ts in &r.timestamp[..nb] {
                let _ = write!(out, ",{ts}");
            }
            for c in r.counts[..nb].iter().flatten() {
                let _ = write!(out, ",{c}");
            }
            out.push('\n');
        }
        // Through the checked writer: never onto a device, FIFO or symbolic link (issue 22).
        crate::calib::data::write_atomically(path, out.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broadcast_address_follows_the_address_class() {
        assert_eq!(
            class_broadcast(Ipv4Addr::new(127, 0, 0, 1)),
            Ipv4Addr::new(127, 255, 255, 255)
        );
        assert_eq!(
            class_broadcast(Ipv4Addr::new(169, 254, 0, 100)),
            Ipv4Addr::new(169, 254, 255, 255)
        );
        assert_eq!(
            class_broadcast(Ipv4Addr::new(192, 168, 1, 5)),
            Ipv4Addr::new(192, 168, 1, 255)
        );
    }

    #[test]
    fn only_loopback_boards_are_driven() {
        assert!(parse_boards("127.0.0.1").is_ok());
        assert_eq!(
            parse_boards("127.0.0.1:5000").unwrap(),
            (Ipv4Addr::LOCALHOST, 5000)
        );
        let e = parse_boards("169.254.0.100").unwrap_err().to_string();
        assert!(e.contains("169.254.0.100") && e.contains("loopback"), "{e}");
        assert!(parse_boards("nonsense").is_err());
    }

    #[test]
    fn arms_choose_the_boards_and_name_the_missing_ones() {
        assert_eq!(boards_to_drive(None, &[6, 7, 8, 9]).unwrap(), [6, 7, 8, 9]);
        assert_eq!(
            boards_to_drive(Some("PSM2,PSM1"), &[6, 7, 8, 9]).unwrap(),
            [6, 7, 8, 9]
        );
        assert_eq!(
            boards_to_drive(Some("PSM2"), &[6, 7, 8, 9]).unwrap(),
            [8, 9]
        );
        let e = boards_to_drive(Some("PSM1,PSM2"), &[6, 7])
            .unwrap_err()
            .to_string();
        assert!(e.contains("[8, 9] did not answer"), "{e}");
        assert!(boards_to_drive(Some("PSM9"), &[6, 7]).is_err());
    }

    #[test]
    fn the_record_header_has_every_board() {
        assert_eq!(
            record_header(2),
            "cycle,t_start_ns,t_read_ns,ok,ts0,ts1,c0_0,c0_1,c0_2,c0_3,c1_0,c1_1,c1_2,c1_3\n"
        );
        let h4 = record_header(4);
        assert!(h4.starts_with("cycle,t_start_ns,t_read_ns,ok,ts0,ts1,ts2,ts3,c0_0,"));
        assert!(h4.ends_with(",c3_3\n"));
        assert_eq!(h4.split(',').count(), 4 + 4 + 16);
    }

    #[test]
    fn command_block_is_zero_current_with_the_board_header() {
        let mut b = [0u8; 24];
        command_block(7, &mut b);
        assert_eq!(&b[0..4], &[0, 0, 7, 6]);
        assert_eq!(u32::from_be_bytes([b[4], b[5], b[6], b[7]]), 0x8000_8000);
        assert_eq!(&b[20..24], &[0, 0, 0, 0]);
    }
}
