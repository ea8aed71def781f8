//! The standalone UDP shell around the [`Emulator`]: answers the dVRK protocol on a socket
//! (default 127.0.0.1:1394), so the sidecar's UdpPort and the dVRK's own tools can talk to it.
//!
//! For the dVRK host library to find the boards, [`bind_boards`] on `0.0.0.0:1394`: that socket
//! sees the subnet broadcast of discovery, every per-board unicast address (127.0.0.(1+id) on
//! loopback, reference §10) and, with the group joined, the multicast 224.0.0.100 of Rev 9.
//! Replies go to the requesting socket's address, whatever address the request was sent to.
//! Requests are counted per client ([`PeerCounts`]) so a test or a bench can tell who loaded the
//! boards.
//!
//! The loop owns the clock: before answering each datagram it reads `CLOCK_MONOTONIC` (through
//! `std::time::Instant`) and advances the physics to that time. Between datagrams it also keeps
//! the physics up to date, polling with a short receive timeout so that `stop` is seen quickly.

use std::fmt;
use std::io;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::emulator::{Emulator, EmulatorCounters, MAX_REPLY_BYTES};

/// Default address of the emulated boards.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:1394";
/// Receive timeout of the polling loop.
pub const POLL_INTERVAL: Duration = Duration::from_millis(5);

/// The Rev 9 boards' UDP multicast group (reference §3.1).
pub const MULTICAST_GROUP: Ipv4Addr = Ipv4Addr::new(224, 0, 0, 100);
/// Clients told apart by [`PeerCounts`]; more are summed in `others`.
pub const MAX_PEERS: usize = 16;

/// Requests received per client address, without allocation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeerCounts {
    peers: [Option<(SocketAddr, u64)>; MAX_PEERS],
    /// Requests from clients beyond the first [`MAX_PEERS`].
    pub others: u64,
}

impl PeerCounts {
    /// Counts one request from `peer`.
    pub fn record(&mut self, peer: SocketAddr) {
        for slot in self.peers.iter_mut() {
            match slot {
                Some((a, n)) if *a == peer => {
                    *n += 1;
                    return;
                }
                None => {
                    *slot = Some((peer, 1));
                    return;
                }
                Some(_) => {}
            }
        }
        self.others += 1;
    }
    /// Requests from `peer`.
    pub fn get(&self, peer: SocketAddr) -> u64 {
        self.iter().find(|(a, _)| *a == peer).map_or(0, |(_, n)| n)
    }
    /// (client, requests) in order of first appearance.
    pub fn iter(&self) -> impl Iterator<Item = (SocketAddr, u64)> + '_ {
        self.peers.iter().flatten().copied()
    }
}

/// `ADDR:PORT/N,ADDR:PORT/N` (empty when nothing was received), the `requests_by_peer` value of
/// the emulator's exit log.
impl fmt::Display for PeerCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut first = true;
        for (a, n) in self.iter() {
            if !first {
                f.write_str(",")?;
            }
            first = false;
            write!(f, "{a}/{n}")?;
        }
        if self.others > 0 {
            if !first {
                f.write_str(",")?;
            }
            write!(f, "others/{}", self.others)?;
        }
        Ok(())
    }
}

/// How the multicast group was joined by [`bind_boards`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MulticastJoin {
    /// Joined on the interface with this address.
    Joined(Ipv4Addr),
    /// Not attempted (the socket listens on one unicast address).
    NotAttempted,
    /// The join failed (e.g. `lo` without the MULTICAST flag); the error text.
    Failed(String),
}

/// Binds the boards' socket at `listen`. When `listen` is the unspecified address (0.0.0.0),
/// also joins [`MULTICAST_GROUP`] on the interface with address `interface`
/// (127.0.0.1 = `lo`). A failed join is reported, not an error: broadcast and unicast still work.
pub fn bind_boards(
    listen: SocketAddr,
    interface: Ipv4Addr,
) -> io::Result<(UdpSocket, MulticastJoin)> {
    let socket = UdpSocket::bind(listen)?;
    let join = match listen.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => {
            match socket.join_multicast_v4(&MULTICAST_GROUP, &interface) {
                Ok(()) => MulticastJoin::Joined(interface),
                Err(e) => MulticastJoin::Failed(e.to_string()),
            }
        }
        _ => MulticastJoin::NotAttempted,
    };
    Ok((socket, join))
}

/// What `serve_udp` did, returned when it stops.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServeSummary {
    /// Requests received per client address.
    pub requests_by_peer: PeerCounts,
    pub datagrams_in: u64,
    pub datagrams_out: u64,
    /// Receive errors other than timeouts (e.g. ICMP port unreachable after a client left).
    pub receive_errors: u64,
    pub send_errors: u64,
    pub counters: EmulatorCounters,
}

/// Serve `emu` on `socket` until `stop` is set; returns the emulator (for its ground truth and
/// counters) and a summary. Replies go to the sender's address. Only a failure to configure the
/// socket is an error; per-datagram errors are counted and serving goes on.
pub fn serve_udp(
    socket: UdpSocket,
    mut emu: Emulator,
    stop: &AtomicBool,
) -> io::Result<(Emulator, ServeSummary)> {
    socket.set_read_timeout(Some(POLL_INTERVAL))?;
    let start = Instant::now();
    let now_ns = |start: Instant| u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
    emu.advance_to(now_ns(start));
    let mut rx = vec![0u8; 4096];
    let mut tx = vec![0u8; MAX_REPLY_BYTES];
    let mut summary = ServeSummary::default();
    while !stop.load(Ordering::Relaxed) {
        let received: Option<(usize, SocketAddr)> = match socket.recv_from(&mut rx) {
            Ok(v) => Some(v),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                None
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => None,
            Err(_) => {
                summary.receive_errors += 1;
                None
            }
        };
        emu.advance_to(now_ns(start));
        let Some((n, from)) = received else { continue };
        summary.datagrams_in += 1;
        summary.requests_by_peer.record(from);
        if let Some(m) = emu.handle(&rx[..n], &mut tx) {
            match socket.send_to(&tx[..m], from) {
                Ok(_) => summary.datagrams_out += 1,
                Err(_) => summary.send_errors += 1,
            }
        }
    }
    summary.counters = emu.counters();
    Ok((emu, summary))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_counted_per_peer_in_order_of_arrival() {
        let a: SocketAddr = "127.0.0.1:40000".parse().unwrap();
        let b: SocketAddr = "127.0.0.1:40001".parse().unwrap();
        let mut p = PeerCounts::default();
        assert_eq!(p.to_string(), "");
        p.record(a);
        p.record(b);
        p.record(a);
        assert_eq!(p.to_string(), "127.0.0.1:40000/2,127.0.0.1:40001/1");
        assert_eq!(p.get(a), 2);
        assert_eq!(p.get("127.0.0.1:1".parse().unwrap()), 0);
    }

    #[test]
    fn clients_beyond_the_table_are_summed() {
        let mut p = PeerCounts::default();
        for port in 0..(MAX_PEERS as u16 + 3) {
            p.record(SocketAddr::from(([127, 0, 0, 1], 30000 + port)));
        }
        assert_eq!(p.iter().count(), MAX_PEERS);
        assert_eq!(p.others, 3);
        assert!(p.to_string().ends_with(",others/3"));
    }

    #[test]
    fn listening_on_any_address_joins_the_multicast_group_or_says_why_not() {
        let (s, join) = bind_boards("0.0.0.0:0".parse().unwrap(), Ipv4Addr::LOCALHOST).unwrap();
        assert!(s.local_addr().unwrap().ip().is_unspecified());
        assert!(matches!(
            join,
            MulticastJoin::Joined(_) | MulticastJoin::Failed(_)
        ));
        let (_, join) = bind_boards("127.0.0.1:0".parse().unwrap(), Ipv4Addr::LOCALHOST).unwrap();
        assert_eq!(join, MulticastJoin::NotAttempted);
    }
}
