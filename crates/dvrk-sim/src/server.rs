//! The standalone UDP shell around the [`Emulator`]: answers the dVRK protocol on a socket
//! (default 127.0.0.1:1394), so the sidecar's UdpPort and the dVRK's own tools can talk to it.
//!
//! The loop owns the clock: before answering each datagram it reads `CLOCK_MONOTONIC` (through
//! `std::time::Instant`) and advances the physics to that time. Between datagrams it also keeps
//! the physics up to date, polling with a short receive timeout so that `stop` is seen quickly.

use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::emulator::{Emulator, EmulatorCounters, MAX_REPLY_BYTES};

/// Default address of the emulated boards.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:1394";
/// Receive timeout of the polling loop.
pub const POLL_INTERVAL: Duration = Duration::from_millis(5);

/// What `serve_udp` did, returned when it stops.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServeSummary {
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
