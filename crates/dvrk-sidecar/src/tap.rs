//! `source = "tap:IFACE"`: the passive tap. A capture socket on the interface between the
//! console and the boards, and [`TapSource`], which feeds the captured frames to dvrk-io's pure
//! [`TapDecoder`] and hands serve the sample the console read. It sends nothing to the boards.
//!
//! The capture is a Linux `AF_PACKET` socket opened with `libc`, not libpcap: it needs only
//! CAP_NET_RAW (granted to the service in tap mode only, see deploy/), adds no C library or
//! crate to the build, and a `recvfrom` into a buffer allocated at start gives one frame per
//! call with no allocation on the cycle's path. It is `SOCK_DGRAM` ("cooked": frames start at
//! the IPv4 header, whatever the link layer), bound to the interface, with a classic BPF filter
//! that passes only unfragmented UDP of the boards' port. Two such sockets: the boards' replies,
//! the only one the loop waits on, and the console's requests, drained when a reply arrives, so
//! the sidecar wakes once per reply and never for a request or a write (on a 2-vCPU VM each
//! wake-up of another process costs the console tens of µs, benches/README.md).
//!
//! On a loopback interface every packet is seen twice (leaving and arriving): the filter drops
//! the leaving copy there. On a real interface the console's requests are the leaving packets
//! and are kept.
//!
//! Only the boards and the console count (issue 22). dvrk-io takes a reply only from the
//! address its request went to. Here, before that: on a real interface a reply must arrive from
//! the wire (a datagram this host sends is no board's, whoever sent it); a datagram sent by a
//! socket of this host (every one on loopback, the console's requests on a real interface) is
//! taken only if that socket belongs to root or to this service's user, looked up once per
//! source address in /proc/net/udp. An unprivileged local user's forged requests and replies
//! are dropped and counted.

use std::io::{self, Read, Seek};
use std::net::{Ipv4Addr, SocketAddrV4};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

use anyhow::{Context, Result, bail};
use dvrk_io::tap::{LinkType, TapDecoder, TapEvent, parse_frame};
use dvrk_io::{ArmSample, IoConfig, MAX_BOARDS};
use tracing::{info, warn};

use crate::cycle::ReadOutcome;
use crate::rt;
use crate::serve::SampleSource;

/// Largest frame kept (the boards' datagrams are below 1.5 kB; loopback MTU is 64 kB).
const FRAME_CAP: usize = 65_536;
/// How long one read waits for the console's next sample before reporting no source (the dVRK
/// host's own receive timeout, reference §3.1).
pub const NO_SOURCE_AFTER_NS: u64 = 20_000_000;

const ETH_P_IP: u16 = 0x0800;

/// Which half of the traffic a capture socket takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Host to boards: UDP destination port = the boards' port.
    Requests,
    /// Boards to host: UDP source port = the boards' port.
    Replies,
}

/// `sll_pkttype` of a packet leaving this host.
const PACKET_OUTGOING: u32 = 4;

/// Classic BPF on a cooked IPv4 packet: UDP, not a fragment, and the boards' `port` as source
/// (replies) or destination (requests) port. With `drop_outgoing` (loopback, where every packet
/// is seen leaving and arriving) the leaving copy is dropped in the kernel, so it wakes nobody.
fn udp_port_filter(port: u16, dir: Direction, drop_outgoing: bool) -> [libc::sock_filter; 11] {
    let op = |code: u16, jt: u8, jf: u8, k: u32| libc::sock_filter { code, jt, jf, k };
    let field = match dir {
        Direction::Replies => 0,
        Direction::Requests => 2,
    };
    let pkttype = (libc::SKF_AD_OFF + libc::SKF_AD_PKTTYPE) as u32;
    // A packet type that never occurs (types are 0-7) when nothing is to be dropped.
    let dropped_type = if drop_outgoing {
        PACKET_OUTGOING
    } else {
        0xFFFF
    };
    [
        op(0x20, 0, 0, pkttype),         // 0: A = packet type (ancillary data)
        op(0x15, 8, 0, dropped_type),    // 1: leaving copy on loopback? drop
        op(0x30, 0, 0, 9),               // 2: A = ip[9] (protocol)
        op(0x15, 0, 6, 17),              // 3: UDP? else drop
        op(0x28, 0, 0, 6),               // 4: A = ip[6:2] (flags, fragment offset)
        op(0x45, 4, 0, 0x1FFF),          // 5: a fragment? drop
        op(0xB1, 0, 0, 0),               // 6: X = 4 * (ip[0] & 0xF)
        op(0x48, 0, 0, field),           // 7: A = UDP source or destination port
        op(0x15, 0, 1, u32::from(port)), // 8: the boards' port? accept, else drop
        op(0x06, 0, 0, 0x0004_0000),     // 9: accept
        op(0x06, 0, 0, 0),               // 10: drop
    ]
}

/// Whether `iface` is a loopback device (its sysfs flags carry IFF_LOOPBACK).
fn is_loopback(iface: &str) -> bool {
    std::fs::read_to_string(format!("/sys/class/net/{iface}/flags"))
        .ok()
        .and_then(|f| u32::from_str_radix(f.trim().trim_start_matches("0x"), 16).ok())
        .is_some_and(|f| f & libc::IFF_LOOPBACK as u32 != 0)
}

fn errno() -> io::Error {
    io::Error::last_os_error()
}

/// An `AF_PACKET` capture socket bound to one interface.
pub struct Capture {
    fd: OwnedFd,
    iface: String,
    buf: Box<[u8]>,
    /// The last frame was sent by this host (not arrived from the wire).
    outgoing: bool,
}

impl Capture {
    /// Opens the capture on `iface` for the UDP requests to, or the replies from, the boards'
    /// `port`. Needs CAP_NET_RAW.
    pub fn open(iface: &str, port: u16, dir: Direction) -> Result<Self> {
        let cname = std::ffi::CString::new(iface)
            .with_context(|| format!("interface name {iface:?} contains a NUL byte"))?;
        // SAFETY: a valid NUL-terminated string.
        let ifindex = unsafe { libc::if_nametoindex(cname.as_ptr()) };
        if ifindex == 0 {
            bail!("tap:{iface}: no such network interface ({})", errno());
        }
        // SAFETY: plain socket(2) call; the result is checked.
        let raw = unsafe {
            libc::socket(
                libc::AF_PACKET,
                libc::SOCK_DGRAM | libc::SOCK_CLOEXEC,
                i32::from(ETH_P_IP.to_be()),
            )
        };
        if raw < 0 {
            let e = errno();
            if e.kind() == io::ErrorKind::PermissionDenied {
                bail!(
                    "tap:{iface}: opening a packet capture socket needs CAP_NET_RAW ({e}); \
                     run as root, or grant it to the service (deploy/README.md, tap mode)"
                );
            }
            bail!("tap:{iface}: cannot open a packet capture socket: {e}");
        }
        // SAFETY: `raw` is a new, valid descriptor owned by nobody else.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        let filter = udp_port_filter(port, dir, is_loopback(iface));
        let prog = libc::sock_fprog {
            len: filter.len() as u16,
            filter: filter.as_ptr().cast_mut(),
        };
        // SAFETY: `prog` points at `filter`, both alive for the call; the kernel copies them.
        let r = unsafe {
            libc::setsockopt(
                fd.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_ATTACH_FILTER,
                (&prog as *const libc::sock_fprog).cast(),
                std::mem::size_of::<libc::sock_fprog>() as libc::socklen_t,
            )
        };
        if r != 0 {
            bail!("tap:{iface}: cannot attach the capture filter: {}", errno());
        }
        // SAFETY: zeroed sockaddr_ll is a valid value; fields set below.
        let mut sll: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        sll.sll_family = libc::AF_PACKET as u16;
        sll.sll_protocol = ETH_P_IP.to_be();
        sll.sll_ifindex = ifindex as i32;
        // SAFETY: `sll` is a valid sockaddr_ll of the size passed.
        let r = unsafe {
            libc::bind(
                fd.as_raw_fd(),
                (&sll as *const libc::sockaddr_ll).cast(),
                std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t,
            )
        };
        if r != 0 {
            bail!("tap:{iface}: cannot bind the capture socket: {}", errno());
        }
        let tv = libc::timeval {
            tv_sec: 0,
            tv_usec: (NO_SOURCE_AFTER_NS / 1000) as libc::suseconds_t,
        };
        // SAFETY: `tv` is a valid timeval of the size passed.
        let r = unsafe {
            libc::setsockopt(
                fd.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_RCVTIMEO,
                (&tv as *const libc::timeval).cast(),
                std::mem::size_of::<libc::timeval>() as libc::socklen_t,
            )
        };
        if r != 0 {
            bail!("tap:{iface}: cannot set the receive timeout: {}", errno());
        }
        Ok(Self {
            fd,
            iface: iface.to_owned(),
            buf: vec![0u8; FRAME_CAP].into_boxed_slice(),
            outgoing: false,
        })
    }

    pub fn iface(&self) -> &str {
        &self.iface
    }

    /// Receives one frame (waiting up to the receive timeout, or not at all with `nowait`).
    /// `nowait` drains what is queued without blocking.
    /// `Ok(Some(len))` for a frame in [`Capture::frame`], `Ok(None)` for the leaving copy of a
    /// loopback packet (skipped). No allocation.
    pub fn recv(&mut self, nowait: bool) -> io::Result<Option<usize>> {
        // SAFETY: zeroed sockaddr_ll is valid; recvfrom writes at most `len` bytes of it.
        let mut sll: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        let mut len = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
        let flags = if nowait { libc::MSG_DONTWAIT } else { 0 };
        // SAFETY: the buffer and address are valid for the sizes passed.
        let n = unsafe {
            libc::recvfrom(
                self.fd.as_raw_fd(),
                self.buf.as_mut_ptr().cast(),
                self.buf.len(),
                flags,
                (&mut sll as *mut libc::sockaddr_ll).cast(),
                &mut len,
            )
        };
        if n < 0 {
            return Err(errno());
        }
        if sll.sll_hatype == libc::ARPHRD_LOOPBACK && sll.sll_pkttype == libc::PACKET_OUTGOING {
            return Ok(None);
        }
        self.outgoing = sll.sll_pkttype == libc::PACKET_OUTGOING;
        Ok(Some(n as usize))
    }

    /// Whether the frame of the last `recv` was sent by this host.
    pub fn outgoing(&self) -> bool {
        self.outgoing
    }

    /// The frame of the last `recv`.
    pub fn frame(&self, len: usize) -> &[u8] {
        &self.buf[..len.min(self.buf.len())]
    }
}

/// Source addresses seen, and whether their local socket belongs to an allowed user.
const OWNER_CACHE: usize = 32;
/// At most one /proc/net/udp lookup per this many ns: a local user spraying datagrams from new
/// ports cannot make the tap spend its cycles reading /proc (their frames are dropped meanwhile).
const OWNER_LOOKUP_EVERY_NS: u64 = 5_000_000;
/// /proc/net/udp read at most this far (about 2000 sockets).
const PROC_UDP_CAP: usize = 256 * 1024;
/// A cached verdict is looked up again after this many ns: a port the console (or a board's
/// local stand-in) released may be bound by another user, whose datagrams must not inherit the
/// verdict (issue 22). Each address costs one /proc read a second at most.
const OWNER_RECHECK_NS: u64 = 1_000_000_000;

/// Who owns the local sockets that send the console's and the boards' datagrams.
struct Owners {
    /// Address, verdict, and when the verdict was looked up (ns).
    cache: [Option<(SocketAddrV4, bool, u64)>; OWNER_CACHE],
    next: usize,
    euid: u32,
    last_lookup_ns: Option<u64>,
    /// /proc/net/udp, opened once and read again from its start at each lookup (no path, no
    /// allocation per lookup); None where it cannot be opened (no socket is then allowed).
    proc_udp: Option<std::fs::File>,
    buf: Box<[u8]>,
    /// Datagrams dropped: another user's socket, or a reply sent by this host on a real
    /// interface.
    refused: u64,
}

impl Owners {
    fn new() -> Self {
        Self {
            cache: [None; OWNER_CACHE],
            next: 0,
            // SAFETY: geteuid has no preconditions.
            euid: unsafe { libc::geteuid() },
            last_lookup_ns: None,
            proc_udp: std::fs::File::open("/proc/net/udp").ok(),
            buf: vec![0u8; PROC_UDP_CAP].into_boxed_slice(),
            refused: 0,
        }
    }

    /// Whether the local socket `src` belongs to root or to this service's user. No allocation:
    /// a cached answer, or one bounded read of /proc/net/udp into the buffer of [`Owners::new`].
    /// A cached answer older than [`OWNER_RECHECK_NS`] is looked up again when the lookup
    /// budget allows (until then it stands, so the console's datagrams are not dropped while
    /// another address's lookup holds the budget).
    fn allowed(&mut self, src: SocketAddrV4, now_ns: u64) -> bool {
        let cached = self.cache.iter().enumerate().find_map(|(i, e)| match *e {
            Some((a, ok, at)) if a == src => Some((i, ok, at)),
            _ => None,
        });
        let throttled = self
            .last_lookup_ns
            .is_some_and(|t| now_ns.saturating_sub(t) < OWNER_LOOKUP_EVERY_NS);
        let slot = match cached {
            Some((i, ok, at)) => {
                if throttled || now_ns.saturating_sub(at) < OWNER_RECHECK_NS {
                    return ok;
                }
                i
            }
            None if throttled => return false,
            None => {
                let i = self.next;
                self.next = (self.next + 1) % OWNER_CACHE;
                i
            }
        };
        self.last_lookup_ns = Some(now_ns);
        let ok = self
            .owner_uid(src)
            .is_some_and(|uid| uid == 0 || uid == self.euid);
        self.cache[slot] = Some((src, ok, now_ns));
        ok
    }

    /// The uid of the socket bound to `src` (or to its port on 0.0.0.0), from /proc/net/udp.
    fn owner_uid(&mut self, src: SocketAddrV4) -> Option<u32> {
        let f = self.proc_udp.as_mut()?;
        f.rewind().ok()?;
        let mut n = 0;
        while n < self.buf.len() {
            match f.read(&mut self.buf[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => return None,
            }
        }
        proc_udp_owner(self.buf.get(..n)?, src)
    }
}

/// The uid column of the /proc/net/udp line whose local address is `src` or `0.0.0.0` with
/// `src`'s port (the kernel prints the address as the native-endian u32 of its network-order
/// bytes, and the port in hex).
fn proc_udp_owner(text: &[u8], src: SocketAddrV4) -> Option<u32> {
    let text = std::str::from_utf8(text).ok()?;
    for line in text.lines().skip(1) {
        let mut cols = line.split_ascii_whitespace();
        let local = cols.nth(1)?;
        let uid = cols.nth(5)?;
        let (ip, port) = local.split_once(':')?;
        let (Ok(ip), Ok(port)) = (u32::from_str_radix(ip, 16), u16::from_str_radix(port, 16))
        else {
            continue;
        };
        let ip = Ipv4Addr::from(ip.to_ne_bytes());
        if port == src.port() && (ip == *src.ip() || ip.is_unspecified()) {
            return uid.parse().ok();
        }
    }
    None
}

/// What the tap saw in the last second, for its once-per-second report.
#[derive(Clone, Copy, Default)]
struct Window {
    blocks: [u64; MAX_BOARDS],
    requests: u64,
    samples: u64,
}

/// serve's sample source in tap mode: the sample the console read, in the same cycle.
///
/// `read` returns the console's next complete sample, waiting for it if none is queued: with
/// `rate = "follow"` there is one cycle per console read, in order, and the cycle rate follows
/// the console. Frames after that sample stay queued in the socket for the next read, so no
/// console read is skipped while the sidecar keeps up on average. Nothing within
/// [`NO_SOURCE_AFTER_NS`]: [`ReadOutcome::NoSource`] (valid = 0).
/// Once per second it names the boards of the arm missing from the console's traffic.
pub struct TapShared {
    /// The console's requests: drained without waiting, before each reply is decoded.
    requests: Capture,
    /// The boards' replies: the only socket the loop waits on, so the sidecar wakes once per
    /// reply rather than once per packet (writes and requests never wake it).
    cap: Capture,
    /// One decoder per arm, each fed every frame (a decoder keeps only its arm's boards).
    decs: Vec<TapDecoder>,
    /// Per arm: a sample completed while another arm's read was waiting, not yet taken.
    pending: Vec<ArmSample>,
    ready: Vec<bool>,
    port: u16,
    /// The capture is on a loopback interface (every datagram is sent by a local socket).
    loopback: bool,
    owners: Owners,
    next_report_ns: u64,
    window: Vec<Window>,
    refused_at_report: u64,
}

/// One arm's samples from the passive tap. Every arm of the service shares one capture (two
/// sockets, read by one thread): each frame is decoded once per arm, and an arm's read takes
/// the sample the console completed for it, waiting for the next frames only when none is
/// queued. `Rc<RefCell<_>>`: the loop is one thread and reads arm after arm, never two at once.
pub struct TapSource {
    shared: std::rc::Rc<std::cell::RefCell<TapShared>>,
    arm: usize,
}

impl TapSource {
    /// One arm on its own capture.
    pub fn open(iface: &str, port: u16, io: IoConfig) -> Result<Self> {
        Ok(Self::open_arms(iface, port, vec![io])?.remove(0))
    }

    /// Every arm (one io configuration each, in order) on one capture of `iface`.
    pub fn open_arms(iface: &str, port: u16, ios: Vec<IoConfig>) -> Result<Vec<Self>> {
        let requests = Capture::open(iface, port, Direction::Requests)?;
        let cap = Capture::open(iface, port, Direction::Replies)?;
        let boards: Vec<&[u8]> = ios.iter().map(|io| io.board_ids()).collect();
        info!(
            interface = iface, port, boards = ?boards,
            "passive tap: listening to the console's traffic, sending nothing"
        );
        let n = ios.len();
        let shared = std::rc::Rc::new(std::cell::RefCell::new(TapShared {
            requests,
            cap,
            decs: ios
                .into_iter()
                .map(|io| TapDecoder::new(io).with_board_port(port))
                .collect(),
            pending: vec![ArmSample::default(); n],
            ready: vec![false; n],
            port,
            loopback: is_loopback(iface),
            owners: Owners::new(),
            next_report_ns: 0,
            window: vec![Window::default(); n],
            refused_at_report: 0,
        }));
        Ok((0..n)
            .map(|arm| Self {
                shared: shared.clone(),
                arm,
            })
            .collect())
    }
}

impl TapShared {
    /// Whether a captured frame may come from the console (`reply` false) or a board:
    /// on a real interface a reply must arrive from the wire; a datagram sent by a socket of
    /// this host must come from one of root's or this service's user.
    fn admit(&mut self, frame_len: usize, reply: bool, now_ns: u64) -> bool {
        let cap = if reply { &self.cap } else { &self.requests };
        let outgoing = cap.outgoing();
        let ok = if !self.loopback && reply && outgoing {
            false
        } else if !self.loopback && !outgoing {
            // From the wire: a board, or a console on another host.
            true
        } else {
            match parse_frame(cap.frame(frame_len), LinkType::Ip) {
                // Not a datagram: the decoders skip it anyway.
                Err(_) => true,
                Ok(d) => self.owners.allowed(d.src, now_ns),
            }
        };
        if !ok {
            self.owners.refused += 1;
        }
        ok
    }

    /// Feeds every queued request to every decoder, without waiting.
    fn drain_requests(&mut self) {
        let now = rt::monotonic_ns();
        while let Ok(r) = self.requests.recv(true) {
            if let Some(m) = r
                && self.admit(m, false, now)
            {
                for (dec, out) in self.decs.iter_mut().zip(self.pending.iter_mut()) {
                    dec.push(self.requests.frame(m), LinkType::Ip, now, out);
                }
            }
        }
    }

    /// Feeds one reply to every decoder; an arm whose sample it completes becomes ready.
    fn push_reply(&mut self, n: usize, now: u64) {
        for ((dec, out), ready) in self
            .decs
            .iter_mut()
            .zip(self.pending.iter_mut())
            .zip(self.ready.iter_mut())
        {
            if dec.push(self.cap.frame(n), LinkType::Ip, now, out) == TapEvent::Sample {
                *ready = true;
            }
        }
    }

    /// Once a second: what is missing from the console's traffic (in the loop's thread, but
    /// once a second and without allocating).
    fn report(&mut self, t_ns: u64) {
        if t_ns < self.next_report_ns {
            return;
        }
        let first = self.next_report_ns == 0;
        self.next_report_ns = t_ns + 1_000_000_000;
        let refused_before = std::mem::replace(&mut self.refused_at_report, self.owners.refused);
        let no_traffic = match (self.decs.first(), self.window.first()) {
            (Some(d), Some(w)) => d.counters().requests == w.requests,
            _ => true,
        };
        if !first && self.owners.refused > refused_before {
            warn!(
                interface = self.cap.iface(),
                port = self.port,
                dropped = self.owners.refused - refused_before,
                "datagrams of the boards' port from another user's socket, or replies sent by \
                 this host, dropped in the last second"
            );
        }
        if !first && no_traffic {
            warn!(
                interface = self.cap.iface(),
                port = self.port,
                "no console traffic in the last second: publishing valid = 0 with NO_SOURCE"
            );
        }
        for (dec, w) in self.decs.iter().zip(self.window.iter_mut()) {
            let c = dec.counters();
            let seen = dec.blocks_seen();
            if !first && !no_traffic {
                for (slot, id) in dec.config().board_ids().iter().enumerate() {
                    if seen[slot] == w.blocks[slot] {
                        warn!(
                            board = id,
                            interface = self.cap.iface(),
                            samples = c.samples - w.samples,
                            "board missing from the console's traffic in the last second"
                        );
                    }
                }
            }
            *w = Window {
                blocks: seen,
                requests: c.requests,
                samples: c.samples,
            };
        }
    }

    fn read(&mut self, arm: usize, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        let start = rt::monotonic_ns();
        loop {
            if self.ready.get(arm).copied().unwrap_or(false) {
                break;
            }
            match self.cap.recv(false) {
                Ok(Some(n)) => {
                    let now = rt::monotonic_ns();
                    // Every request went out before its reply came back, so it is queued by
                    // now: take them first (pairing needs the request's label).
                    self.drain_requests();
                    if self.admit(n, true, now) {
                        self.push_reply(n, now);
                    }
                }
                Ok(None) => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => break,
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    // No reply: still count the console's requests (boards that do not answer
                    // are then named, not reported as "no traffic").
                    self.drain_requests();
                    break;
                }
                Err(_) => {
                    self.report(t_ns);
                    out.valid = false;
                    return ReadOutcome::Error;
                }
            }
            if rt::monotonic_ns().saturating_sub(start) > NO_SOURCE_AFTER_NS {
                break;
            }
        }
        self.report(t_ns);
        match (self.ready.get_mut(arm), self.pending.get(arm)) {
            (Some(ready), Some(sample)) if *ready => {
                *ready = false;
                *out = *sample;
                ReadOutcome::Ok
            }
            _ => {
                out.t_ns = t_ns;
                out.valid = false;
                ReadOutcome::NoSource
            }
        }
    }
}

impl SampleSource for TapSource {
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool {
        self.shared
            .borrow_mut()
            .decs
            .get_mut(self.arm)
            .is_some_and(|d| d.config_mut().set_coupling(*coupling).is_ok())
    }

    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        self.shared.borrow_mut().read(self.arm, t_ns, out)
    }

    fn pot_minus_encoder(&self) -> Option<[f64; dvrk_io::NUM_JOINTS]> {
        self.shared
            .borrow()
            .decs
            .get(self.arm)
            .and_then(|d| d.pot_minus_encoder())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter's jumps stay inside the program and end on a return.
    #[test]
    fn filter_jumps_land_inside_the_program() {
        for (dir, field) in [(Direction::Replies, 0), (Direction::Requests, 2)] {
            let f = udp_port_filter(1394, dir, true);
            assert_eq!(f[1].k, PACKET_OUTGOING);
            assert_eq!(udp_port_filter(1394, dir, false)[1].k, 0xFFFF);
            for (i, ins) in f.iter().enumerate() {
                let is_jump = ins.code & 0x07 == 0x05;
                if is_jump {
                    assert!(i + 1 + usize::from(ins.jt) < f.len(), "insn {i} jt");
                    assert!(i + 1 + usize::from(ins.jf) < f.len(), "insn {i} jf");
                }
            }
            assert_eq!(f[f.len() - 1].code, 0x06);
            assert_eq!(f[7].k, field);
            assert_eq!(f[8].k, 1394);
        }
    }

    #[test]
    fn proc_net_udp_owner_is_read() {
        let text = b"   sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode ref pointer drops\n\
  123: 0100007F:9C40 00000000:0000 07 00000000:00000000 00:00000000 00000000  1000        0 1 2 0000000000000000 0\n\
  124: 00000000:0572 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 1 2 0000000000000000 0\n";
        let a = |s: &str| s.parse::<SocketAddrV4>().unwrap();
        if cfg!(target_endian = "little") {
            assert_eq!(proc_udp_owner(text, a("127.0.0.1:40000")), Some(1000));
        }
        assert_eq!(proc_udp_owner(text, a("127.0.0.5:1394")), Some(0));
        assert_eq!(proc_udp_owner(text, a("127.0.0.1:40001")), None);
        // This test's own socket is found, owned by this user.
        let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let std::net::SocketAddr::V4(me) = s.local_addr().unwrap() else {
            unreachable!()
        };
        let mut o = Owners::new();
        assert_eq!(o.owner_uid(me), Some(o.euid));
        assert!(o.allowed(me, 0));
        // Read again from its start: the same answer.
        assert_eq!(o.owner_uid(me), Some(o.euid));
    }

    #[test]
    fn a_cached_verdict_is_looked_up_again_after_a_second() {
        // /proc/net/udp opened before the socket exists: each lookup reads it afresh.
        let mut o = Owners::new();
        let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let std::net::SocketAddr::V4(me) = s.local_addr().unwrap() else {
            unreachable!()
        };
        // A verdict from when the port was someone else's (here: put in by hand).
        o.cache[0] = Some((me, false, 0));
        assert!(!o.allowed(me, 1), "a fresh verdict stands");
        assert!(
            !o.allowed(me, OWNER_RECHECK_NS - 1),
            "until the recheck is due"
        );
        assert!(
            o.allowed(me, OWNER_RECHECK_NS),
            "looked up again: this user's socket"
        );
        // Within the lookup budget of that lookup, another stale verdict stands for now.
        let other = SocketAddrV4::new(Ipv4Addr::LOCALHOST, 9);
        o.cache[1] = Some((other, true, 0));
        assert!(o.allowed(other, OWNER_RECHECK_NS + 1));
        // Once the budget allows, it is looked up: no socket on port 9 here, refused.
        assert!(!o.allowed(other, OWNER_RECHECK_NS + OWNER_LOOKUP_EVERY_NS));
        // The cache held one entry per address.
        let n = o
            .cache
            .iter()
            .flatten()
            .filter(|(a, _, _)| *a == me)
            .count();
        assert_eq!(n, 1);
    }

    #[test]
    fn lo_is_loopback() {
        assert!(is_loopback("lo"));
        assert!(!is_loopback("nosuchif0"));
    }

    #[test]
    fn a_missing_interface_is_named() {
        let e = Capture::open("nosuchif0", 1394, Direction::Replies)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("nosuchif0"), "{e}");
    }
}
