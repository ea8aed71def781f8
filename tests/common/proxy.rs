//! A UDP fault proxy between `serve` and the board emulator: real sockets on loopback, seeded
//! faults that can be changed while it runs (loss, bit flips, delays, duplicates), and counters
//! of what it did. The client (serve) sends its requests to [`FaultProxy::addr`]; the proxy
//! forwards them to the emulator and the emulator's replies back to the client.

use super::Rng;
use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Fault probabilities (0..=1) per datagram.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Faults {
    /// A request or a reply is not forwarded.
    pub loss: f64,
    /// One bit of a reply is flipped.
    pub bit_flip: f64,
    /// A reply is held back for `delay`.
    pub delay_chance: f64,
    pub delay: Duration,
    /// A reply is sent twice.
    pub duplicate: f64,
    /// Zero the header and data CRCs of every reply, as a real FPGA sends them (reference
    /// §3.1), so that a flipped bit can only be caught by the plausibility checks.
    pub strip_crc: bool,
}

/// What the proxy did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProxyCounters {
    pub requests: u64,
    pub replies: u64,
    pub lost: u64,
    pub flipped: u64,
    pub delayed: u64,
    pub duplicated: u64,
}

impl ProxyCounters {
    pub fn injected(&self) -> u64 {
        self.lost + self.flipped + self.delayed + self.duplicated
    }
}

struct Shared {
    faults: Mutex<Faults>,
    counters: Mutex<ProxyCounters>,
    client: Mutex<Option<SocketAddr>>,
    stop: AtomicBool,
}

pub struct FaultProxy {
    pub addr: SocketAddr,
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl FaultProxy {
    /// A proxy on an ephemeral loopback port in front of the emulator at `upstream`.
    pub fn start(upstream: SocketAddr, faults: Faults, seed: u64) -> Self {
        let front = UdpSocket::bind("127.0.0.1:0").unwrap();
        let back = UdpSocket::bind("127.0.0.1:0").unwrap();
        front
            .set_read_timeout(Some(Duration::from_millis(2)))
            .unwrap();
        back.set_read_timeout(Some(Duration::from_millis(1)))
            .unwrap();
        let addr = front.local_addr().unwrap();
        let shared = Arc::new(Shared {
            faults: Mutex::new(faults),
            counters: Mutex::new(ProxyCounters::default()),
            client: Mutex::new(None),
            stop: AtomicBool::new(false),
        });
        let front2 = front.try_clone().unwrap();
        let back2 = back.try_clone().unwrap();
        // Requests: client -> emulator.
        let s = shared.clone();
        let up = std::thread::spawn(move || {
            let mut rng = Rng(seed);
            let mut buf = [0u8; 4096];
            while !s.stop.load(Ordering::Relaxed) {
                let Ok((n, from)) = front.recv_from(&mut buf) else {
                    continue;
                };
                *s.client.lock().unwrap() = Some(from);
                let f = *s.faults.lock().unwrap();
                let mut c = s.counters.lock().unwrap();
                c.requests += 1;
                if rng.chance(f.loss) {
                    c.lost += 1;
                    continue;
                }
                drop(c);
                let _ = back.send_to(&buf[..n], upstream);
            }
        });
        // Replies: emulator -> client, with a queue for delayed ones.
        let s = shared.clone();
        let down = std::thread::spawn(move || {
            let mut rng = Rng(seed ^ 0x5555_5555_5555_5555);
            let mut buf = [0u8; 4096];
            let mut held: VecDeque<(Instant, Vec<u8>)> = VecDeque::new();
            while !s.stop.load(Ordering::Relaxed) {
                let client = *s.client.lock().unwrap();
                while let Some((due, _)) = held.front() {
                    if *due > Instant::now() {
                        break;
                    }
                    let (_, d) = held.pop_front().unwrap();
                    if let Some(c) = client {
                        let _ = front2.send_to(&d, c);
                    }
                }
                let Ok(n) = back2.recv(&mut buf) else {
                    continue;
                };
                let Some(client) = client else { continue };
                let f = *s.faults.lock().unwrap();
                let mut c = s.counters.lock().unwrap();
                c.replies += 1;
                if rng.chance(f.loss) {
                    c.lost += 1;
                    continue;
                }
                let d = &mut buf[..n];
                if f.strip_crc && n >= 28 {
                    // Quadlet response: 20 + 8 extra bytes; block response: 20 + data + data
                    // CRC + 8 extra bytes.
                    d[16..20].fill(0);
                    if n > 28 {
                        d[n - 12..n - 8].fill(0);
                    }
                }
                if rng.chance(f.bit_flip) && n > 0 {
                    let r = rng.next();
                    d[(r % n as u64) as usize] ^= 1 << ((r >> 32) % 8);
                    c.flipped += 1;
                }
                if rng.chance(f.delay_chance) {
                    c.delayed += 1;
                    held.push_back((Instant::now() + f.delay, d.to_vec()));
                    continue;
                }
                let dup = rng.chance(f.duplicate);
                if dup {
                    c.duplicated += 1;
                }
                drop(c);
                let _ = front2.send_to(d, client);
                if dup {
                    let _ = front2.send_to(d, client);
                }
            }
        });
        Self {
            addr,
            shared,
            threads: vec![up, down],
        }
    }

    pub fn set_faults(&self, f: Faults) {
        *self.shared.faults.lock().unwrap() = f;
    }

    pub fn counters(&self) -> ProxyCounters {
        *self.shared.counters.lock().unwrap()
    }
}

impl Drop for FaultProxy {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
