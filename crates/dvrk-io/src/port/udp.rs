//! UDP link to the boards (reference §3.1, §8.4).

use std::net::{IpAddr, Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::os::fd::AsRawFd;
use std::time::Duration;

use super::eth::EthPort;
use super::{Link, PortError, QuadletRetry};
use crate::wire::firewire::BROADCAST_NODE;

/// FPGA UDP port for requests and replies (reference §3.1).
pub const FPGA_UDP_PORT: u16 = 1394;
/// Default FPGA address (reference §3.1); Rev 9 boards add their board id to the last octet.
pub const DEFAULT_BOARD_IP: Ipv4Addr = Ipv4Addr::new(169, 254, 0, 100);
/// Receive timeout of the dVRK host (reference §3.1, §6).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(20);
/// How long a quadlet read waits for its reply before asking again (see [`QuadletRetry`]): a
/// few round trips of a board on its Ethernet link (tens of µs) and a third of the 1.5 kHz
/// cycle, so that a lost datagram costs part of one cycle. A reply later than this is still
/// taken, as the answer to the repeated request.
pub const QUADLET_RETRY_WAIT: Duration = Duration::from_micros(150);
/// Most requests of one quadlet read (the last one waits the whole reply timeout): at 10% loss
/// of each datagram, a quadlet read fails once in 700.
pub const MAX_QUADLET_ATTEMPTS: u8 = 4;
/// Foreign datagrams skipped within one `recv` before it reports a timeout.
const MAX_FOREIGN_PER_RECV: u32 = 64;

/// The Ethernet protocol engine over a real UDP socket.
pub type UdpPort = EthPort<UdpLink>;

/// Where requests go.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UdpTarget {
    /// Every request to one FPGA (the hub in bridge mode, or a single board; also the loopback
    /// emulator). Replies are accepted only from this address.
    Single(SocketAddr),
    /// Rev 9 Ethernet-only: board `n` at `base + n` (169.254.0.(100+n), §3.1); broadcast
    /// requests go to `broadcast`. Replies are accepted only from a board address.
    PerBoard {
        base: Ipv4Addr,
        port: u16,
        broadcast: Ipv4Addr,
    },
}

impl UdpTarget {
    /// Rev 9 per-board addressing on the link-local network (169.254.0.100 + id, subnet
    /// broadcast 169.254.255.255, §3.1).
    pub const fn rev9_default() -> Self {
        Self::PerBoard {
            base: DEFAULT_BOARD_IP,
            port: FPGA_UDP_PORT,
            broadcast: Ipv4Addr::new(169, 254, 255, 255),
        }
    }
}

/// A UDP socket talking to the boards. Datagrams from any other address are dropped and
/// counted, never parsed.
pub struct UdpLink {
    socket: UdpSocket,
    target: UdpTarget,
    /// Address the current reply must come from (None: any board address, after a broadcast
    /// in per-board mode).
    expect_from: Option<SocketAddr>,
    foreign: u64,
    /// The reply timeout ([`UdpLink::set_timeout`]).
    timeout: Duration,
    /// Wait of a quadlet read before it asks again; `None`: no retry.
    retry_wait: Option<Duration>,
}

impl UdpLink {
    /// Binds an ephemeral local port (on 127.0.0.1 when the target is loopback, else on all
    /// interfaces), sets the default 20 ms receive timeout.
    pub fn new(target: UdpTarget) -> std::io::Result<Self> {
        let loopback = match target {
            UdpTarget::Single(a) => a.ip().is_loopback(),
            UdpTarget::PerBoard { base, .. } => base.is_loopback(),
        };
        let bind: SocketAddr = if loopback {
            (Ipv4Addr::LOCALHOST, 0).into()
        } else {
            (Ipv4Addr::UNSPECIFIED, 0).into()
        };
        let socket = UdpSocket::bind(bind)?;
        if let UdpTarget::PerBoard { .. } = target {
            socket.set_broadcast(true)?;
        }
        socket.set_read_timeout(Some(DEFAULT_TIMEOUT))?;
        Ok(Self {
            socket,
            target,
            expect_from: None,
            foreign: 0,
            timeout: DEFAULT_TIMEOUT,
            retry_wait: Some(QUADLET_RETRY_WAIT),
        })
    }
    /// One board (or hub) at `addr`.
    pub fn connect(addr: SocketAddr) -> std::io::Result<Self> {
        Self::new(UdpTarget::Single(addr))
    }
    /// The dVRK default, 169.254.0.100:1394.
    pub fn default_board() -> std::io::Result<Self> {
        Self::connect(SocketAddr::V4(SocketAddrV4::new(
            DEFAULT_BOARD_IP,
            FPGA_UDP_PORT,
        )))
    }
    /// From a dVRK port string: `udp:IP` or `udp:IP:PORT` (also `udpfw:`), reference house
    /// style "port strings". `udp:` alone means the default address.
    pub fn from_port_string(s: &str) -> std::io::Result<Self> {
        let bad = || {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("port string {s:?}: expected udp:IP[:PORT]"),
            )
        };
        let rest = s
            .strip_prefix("udpfw:")
            .or_else(|| s.strip_prefix("udp:"))
            .ok_or_else(bad)?;
        if rest.is_empty() {
            return Self::default_board();
        }
        let addr = if let Ok(ip) = rest.parse::<IpAddr>() {
            SocketAddr::new(ip, FPGA_UDP_PORT)
        } else {
            rest.parse::<SocketAddr>().map_err(|_| bad())?
        };
        Self::connect(addr)
    }
    /// Receive timeout per datagram (default 20 ms). Zero is refused by the OS; use ≥ 1 µs.
    pub fn set_timeout(&mut self, timeout: Duration) -> std::io::Result<()> {
        self.socket.set_read_timeout(Some(timeout))?;
        self.timeout = timeout;
        Ok(())
    }
    /// The wait of a quadlet read before it asks again (default [`QUADLET_RETRY_WAIT`]);
    /// `None`: one request per quadlet read, waiting the whole timeout.
    pub fn set_quadlet_retry_wait(&mut self, wait: Option<Duration>) {
        self.retry_wait = wait.filter(|w| !w.is_zero());
    }
    pub fn target(&self) -> UdpTarget {
        self.target
    }
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }
    /// Datagrams received from an address other than the expected board, dropped unparsed.
    pub fn foreign_datagrams(&self) -> u64 {
        self.foreign
    }

    fn dest(&self, node: u8) -> (SocketAddr, Option<SocketAddr>) {
        match self.target {
            UdpTarget::Single(a) => (a, Some(a)),
            UdpTarget::PerBoard {
                base,
                port,
                broadcast,
            } => {
                if node == BROADCAST_NODE {
                    ((broadcast, port).into(), None)
                } else {
                    let ip = Ipv4Addr::from(u32::from(base).wrapping_add(u32::from(node & 0x0F)));
                    let a: SocketAddr = (ip, port).into();
                    (a, Some(a))
                }
            }
        }
    }

    fn accept(&self, from: SocketAddr) -> bool {
        match (self.expect_from, self.target) {
            (Some(a), _) => from == a,
            (None, UdpTarget::PerBoard { base, port, .. }) => match from {
                SocketAddr::V4(v4) => {
                    let off = u32::from(*v4.ip()).wrapping_sub(u32::from(base));
                    v4.port() == port && off < 16
                }
                SocketAddr::V6(_) => false,
            },
            (None, UdpTarget::Single(a)) => from == a,
        }
    }
}

impl EthPort<UdpLink> {
    /// A UDP port to one board or hub at `addr` (e.g. 169.254.0.100:1394, or a loopback emulator).
    pub fn open_udp(addr: SocketAddr) -> Result<Self, PortError> {
        Ok(Self::new(UdpLink::connect(addr)?))
    }
}

impl Link for UdpLink {
    fn send(&mut self, dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        let (to, expect) = self.dest(dest_node);
        self.expect_from = expect;
        self.socket.send_to(datagram, to)?;
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        for _ in 0..MAX_FOREIGN_PER_RECV {
            let (n, from) = self.socket.recv_from(buf)?;
            if self.accept(from) {
                return Ok(n);
            }
            self.foreign += 1;
        }
        Err(PortError::LINK_TIMEOUT)
    }

    fn recv_within(&mut self, buf: &mut [u8], wait: Duration) -> Result<usize, PortError> {
        if wait >= self.timeout {
            return self.recv(buf);
        }
        // The socket's receive timeout counts in scheduler ticks (a 200 µs timeout waits 1 to
        // 4 ms): wait with ppoll, whose timer has µs resolution, then take the datagram, which
        // is there (only this link reads its socket).
        let ts = libc::timespec {
            tv_sec: wait.as_secs() as libc::time_t,
            tv_nsec: libc::c_long::from(wait.subsec_nanos() as i32),
        };
        for _ in 0..MAX_FOREIGN_PER_RECV {
            let mut pfd = libc::pollfd {
                fd: self.socket.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd, a valid timespec, no signal mask.
            let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
            if r == 0 {
                return Err(PortError::LINK_TIMEOUT);
            }
            if r < 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() == std::io::ErrorKind::Interrupted {
                    continue;
                }
                return Err(e.into());
            }
            let (n, from) = self.socket.recv_from(buf)?;
            if self.accept(from) {
                return Ok(n);
            }
            self.foreign += 1;
        }
        Err(PortError::LINK_TIMEOUT)
    }

    fn quadlet_retry(&self) -> Option<QuadletRetry> {
        let wait = self.retry_wait?;
        (wait < self.timeout).then_some(QuadletRetry {
            wait,
            attempts: MAX_QUADLET_ATTEMPTS,
            reply_timeout: self.timeout,
            one_server: matches!(self.target, UdpTarget::Single(_)),
        })
    }

    fn discard_pending(&mut self, buf: &mut [u8]) -> usize {
        // Bounded: a peer flooding the socket cannot keep us here.
        const MAX_DRAIN: usize = 4096;
        if self.socket.set_nonblocking(true).is_err() {
            return 0;
        }
        let mut n = 0;
        while n < MAX_DRAIN && self.socket.recv_from(buf).is_ok() {
            n += 1;
        }
        // If this fails the next recv returns at once with WouldBlock, read as a timeout, and
        // the engine tries again: nothing is lost but one cycle.
        let _ = self.socket.set_nonblocking(false);
        n
    }
}
