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

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

use anyhow::{Context, Result, bail};
use dvrk_io::tap::{LinkType, TapDecoder, TapEvent};
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
        Ok(Some(n as usize))
    }

    /// The frame of the last `recv`.
    pub fn frame(&self, len: usize) -> &[u8] {
        &self.buf[..len.min(self.buf.len())]
    }
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
pub struct TapSource {
    /// The console's requests: drained without waiting, before each reply is decoded.
    requests: Capture,
    /// The boards' replies: the only socket the loop waits on, so the sidecar wakes once per
    /// reply rather than once per packet (writes and requests never wake it).
    cap: Capture,
    dec: TapDecoder,
    port: u16,
    next_report_ns: u64,
    window: Window,
}

impl TapSource {
    pub fn open(iface: &str, port: u16, io: IoConfig) -> Result<Self> {
        let requests = Capture::open(iface, port, Direction::Requests)?;
        let cap = Capture::open(iface, port, Direction::Replies)?;
        info!(
            interface = iface, port, boards = ?io.board_ids(),
            "passive tap: listening to the console's traffic, sending nothing"
        );
        Ok(Self {
            requests,
            cap,
            dec: TapDecoder::new(io).with_board_port(port),
            port,
            next_report_ns: 0,
            window: Window::default(),
        })
    }

    /// Feeds every queued request to the decoder, without waiting.
    fn drain_requests(&mut self, out: &mut ArmSample) {
        let now = rt::monotonic_ns();
        while let Ok(r) = self.requests.recv(true) {
            if let Some(m) = r {
                self.dec
                    .push(self.requests.frame(m), LinkType::Ip, now, out);
            }
        }
    }

    pub fn decoder(&self) -> &TapDecoder {
        &self.dec
    }

    fn report(&mut self, t_ns: u64) {
        if t_ns < self.next_report_ns {
            return;
        }
        let first = self.next_report_ns == 0;
        self.next_report_ns = t_ns + 1_000_000_000;
        let c = self.dec.counters();
        let seen = self.dec.blocks_seen();
        let prev = std::mem::replace(
            &mut self.window,
            Window {
                blocks: seen,
                requests: c.requests,
                samples: c.samples,
            },
        );
        if first {
            return;
        }
        if c.requests == prev.requests {
            warn!(
                interface = self.cap.iface(),
                port = self.port,
                "no console traffic in the last second: publishing valid = 0 with NO_SOURCE"
            );
            return;
        }
        for (slot, id) in self.dec.config().board_ids().iter().enumerate() {
            if seen[slot] == prev.blocks[slot] {
                warn!(
                    board = id,
                    interface = self.cap.iface(),
                    samples = c.samples - prev.samples,
                    "board missing from the console's traffic in the last second"
                );
            }
        }
    }
}

impl SampleSource for TapSource {
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool {
        self.dec.config_mut().set_coupling(*coupling).is_ok()
    }

    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        let mut got = false;
        let start = rt::monotonic_ns();
        loop {
            match self.cap.recv(false) {
                Ok(Some(n)) => {
                    let now = rt::monotonic_ns();
                    // Every request went out before its reply came back, so it is queued by
                    // now: take them first (pairing needs the request's label).
                    self.drain_requests(out);
                    if self.dec.push(self.cap.frame(n), LinkType::Ip, now, out) == TapEvent::Sample
                    {
                        got = true;
                        break;
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
                    self.drain_requests(out);
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
        if got {
            ReadOutcome::Ok
        } else {
            out.t_ns = t_ns;
            out.valid = false;
            ReadOutcome::NoSource
        }
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
