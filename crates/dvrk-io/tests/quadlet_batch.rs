//! The pipelined batch of quadlet reads (`Port::read_quadlets` on a UDP port, issue 22 item 7)
//! against a scripted board thread on 127.0.0.1: each test decides, request by request, what
//! the board answers, so that the batch meets losses, reordering, stale and foreign replies
//! and silence exactly where the test puts them.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use common::Boards;
use dvrk_io::port::{Port, PortError, UdpPort};

/// One request as the board saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Req {
    node: u8,
    addr: u16,
    label: u8,
}

/// Label of a request datagram: control word (2 bytes), then q0 = dest<<16 | tl<<10 | ...
fn request_label(dgram: &[u8]) -> u8 {
    dgram[4] >> 2
}

/// The status of both boards, then encoder position and ADC of each actuator, as shared mode
/// asks them for a Classic PSM (actuators 1-4 on board 6, 5-7 on board 7).
fn shared_cycle() -> Vec<(u8, u16)> {
    let mut reqs = vec![(6u8, 0u16), (7, 0)];
    for (board, axes) in [(6u8, 0..4u16), (7, 0..3)] {
        for a in axes {
            reqs.push((board, ((a + 1) << 4) | 5));
            reqs.push((board, (a + 1) << 4));
        }
    }
    reqs
}

fn expected(boards: &mut Boards, reqs: &[(u8, u16)]) -> Vec<Option<u32>> {
    reqs.iter()
        .map(|&(b, a)| boards.board(b).register(a))
        .collect()
}

/// Gives every axis distinct encoder and current values, changed by `k`.
fn set_values(boards: &mut Boards, k: i32) {
    for (id, n) in [(6u8, 4usize), (7, 3)] {
        for ax in 0..n {
            let c = k * 1000 + i32::from(id) * 10 + ax as i32;
            boards.board(id).set_axis(ax, c, 0x8000 + c as u16);
        }
    }
}

/// A PSM's two boards with [`set_values`]`(k)`.
fn boards_with(k: i32) -> Boards {
    let mut b = Boards::psm(8);
    set_values(&mut b, k);
    b
}

/// A board thread: `script(boards, request, datagram, normal replies, sock, from)` sends what
/// it wants; it runs until `stop` returns true after a receive timeout, and returns the requests
/// it saw.
fn board<F>(mut boards: Boards, mut script: F) -> (SocketAddr, std::thread::JoinHandle<Vec<Req>>)
where
    F: FnMut(&mut Boards, Req, Vec<Vec<u8>>, &UdpSocket, SocketAddr) -> bool + Send + 'static,
{
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let addr = sock.local_addr().unwrap();
    let h = std::thread::spawn(move || {
        let mut seen = Vec::new();
        let mut buf = [0u8; 2048];
        loop {
            let Ok((n, from)) = sock.recv_from(&mut buf) else {
                return seen;
            };
            let replies = boards.handle(&buf[..n]);
            let l = boards.log.last().unwrap();
            let req = Req {
                node: l.node,
                addr: l.addr as u16,
                label: request_label(&buf[..n]),
            };
            seen.push(req);
            if script(&mut boards, req, replies, &sock, from) {
                return seen;
            }
        }
    });
    (addr, h)
}

/// Requests that arrive within `wait` (each answered by `boards` into its replies, not sent).
fn more_requests(
    boards: &mut Boards,
    sock: &UdpSocket,
    wait: Duration,
) -> Vec<(Req, Vec<Vec<u8>>)> {
    let mut got = Vec::new();
    let mut buf = [0u8; 2048];
    sock.set_read_timeout(Some(wait)).unwrap();
    while let Ok((n, _)) = sock.recv_from(&mut buf) {
        let replies = boards.handle(&buf[..n]);
        let l = boards.log.last().unwrap();
        let req = Req {
            node: l.node,
            addr: l.addr as u16,
            label: request_label(&buf[..n]),
        };
        got.push((req, replies));
    }
    sock.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    got
}

fn port(addr: SocketAddr, window: u8) -> UdpPort {
    let mut p = UdpPort::open_udp(addr).unwrap();
    p.link_mut().set_timeout(Duration::from_secs(2)).unwrap();
    p.set_quadlet_window(window);
    // Generous, so that a loaded machine does not end a batch before the script is through.
    p.set_quadlet_batch_budget(Some(Duration::from_secs(1)));
    p
}

/// A port whose registers are given up by their own deadlines only: reply timeout `timeout`,
/// retry wait `retry_wait` (until a round trip is measured, and its cap's base), no budget.
fn timed_port(addr: SocketAddr, window: u8, timeout: Duration, retry_wait: Duration) -> UdpPort {
    let mut p = port(addr, window);
    p.link_mut().set_timeout(timeout).unwrap();
    p.link_mut().set_quadlet_retry_wait(Some(retry_wait));
    p.set_quadlet_batch_budget(None);
    p
}

/// Requests a board holds unanswered, with the replies it will send.
type Pending = Vec<(Req, Vec<Vec<u8>>)>;

/// Adds `req` to what the board holds unanswered, unless its register is held already (a
/// register asked again, presumed lost, is not another outstanding one), and raises `max` to
/// the number held.
fn hold(pending: &mut Pending, max: &std::sync::Mutex<usize>, req: Req, replies: Vec<Vec<u8>>) {
    if !pending
        .iter()
        .any(|(q, _)| (q.node, q.addr) == (req.node, req.addr))
    {
        pending.push((req, replies));
    }
    let mut mx = max.lock().unwrap();
    *mx = (*mx).max(pending.len());
}

/// [`hold`], except for a register in `answered`: the port may ask one again while its reply is
/// on the way (its retry wait, learned from quick replies, can be shorter than a counting
/// board's pauses), and takes the first reply and goes on to its next register, so that re-ask
/// is not outstanding. It is answered at once.
fn hold_unanswered(
    pending: &mut Pending,
    answered: &[(u8, u16)],
    max: &std::sync::Mutex<usize>,
    req: Req,
    replies: Vec<Vec<u8>>,
    sock: &UdpSocket,
    from: SocketAddr,
) {
    if answered.contains(&(req.node, req.addr)) {
        send_all(sock, from, &replies);
    } else {
        hold(pending, max, req, replies);
    }
}

fn send_all(sock: &UdpSocket, from: SocketAddr, replies: &[Vec<u8>]) {
    for r in replies {
        sock.send_to(r, from).unwrap();
    }
}

/// The board holds its replies until it has the window's requests, answers them in reverse
/// order, then answers at once: every value lands in its own register's entry, and no more
/// than the window's registers were ever asked before the first answer.
#[test]
fn replies_out_of_order_are_matched_to_their_registers_and_the_window_holds() {
    let mut truth = boards_with(1);
    let reqs = shared_cycle();
    let want = expected(&mut truth, &reqs);
    let mut held: Vec<Vec<u8>> = Vec::new();
    let mut holding = true;
    let extra = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let ex = extra.clone();
    let (addr, h) = board(boards_with(1), move |boards, _req, replies, sock, from| {
        if holding {
            held.extend(replies);
            if held.len() == 4 {
                // Nothing more may come while the four are unanswered.
                let more = more_requests(boards, sock, Duration::from_millis(20));
                ex.lock().unwrap().extend(more.iter().map(|(q, _)| *q));
                holding = false;
                for r in held.drain(..).rev() {
                    sock.send_to(&r, from).unwrap();
                }
                for (_, r) in more {
                    send_all(sock, from, &r);
                }
            }
        } else {
            send_all(sock, from, &replies);
        }
        false
    });
    let mut p = port(addr, 4);
    // A retry wait longer than the board's hold, so that no register is asked twice meanwhile.
    p.link_mut()
        .set_quadlet_retry_wait(Some(Duration::from_millis(100)));
    let mut out = vec![None; reqs.len()];
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(out, want);
    drop(p);
    let seen = h.join().unwrap();
    // The first four entries, each once, before any answer; each with its own label.
    let first: Vec<(u8, u16)> = seen[..4].iter().map(|r| (r.node, r.addr)).collect();
    assert_eq!(first, reqs[..4].to_vec());
    let mut labels: Vec<u8> = seen.iter().map(|r| r.label).collect();
    labels.sort_unstable();
    labels.dedup();
    assert_eq!(labels.len(), seen.len(), "a label used twice: {seen:?}");
    // A board answers in order (reference §8.4), so the port takes a reply that overtook
    // earlier requests to the same board as the sign that those were lost, and asks them
    // again at once: reversed replies cost at most one more request per register.
    for r in &reqs {
        let asked = seen.iter().filter(|q| (q.node, q.addr) == *r).count();
        assert!(
            (1..=2).contains(&asked),
            "{r:?} asked {asked} times: {seen:?}"
        );
    }
    assert_eq!(*extra.lock().unwrap(), vec![], "asked beyond the window");
}

/// At most `window` registers are asked at a time, whatever the window (here 2 and 6), counted
/// by a board that answers each request only when the next one arrives or after a pause.
#[test]
fn at_most_the_window_is_outstanding() {
    for window in [2u8, 6] {
        let reqs = shared_cycle();
        let mut pending = Pending::new();
        let mut answered: Vec<(u8, u16)> = Vec::new();
        let max = std::sync::Arc::new(std::sync::Mutex::new(0usize));
        let m = max.clone();
        let (addr, h) = board(Boards::psm(8), move |boards, req, replies, sock, from| {
            hold_unanswered(&mut pending, &answered, &m, req, replies, sock, from);
            if pending.len() >= usize::from(window) {
                // Full: whatever else comes in a pause is counted, then the oldest answered.
                for (q, r) in more_requests(boards, sock, Duration::from_millis(5)) {
                    hold_unanswered(&mut pending, &answered, &m, q, r, sock, from);
                }
                let (q, r) = pending.remove(0);
                send_all(sock, from, &r);
                answered.push((q.node, q.addr));
            }
            false
        });
        let mut p = port(addr, window);
        p.link_mut()
            .set_quadlet_retry_wait(Some(Duration::from_millis(200)));
        let mut out = vec![None; reqs.len()];
        // The board answers the last `window - 1` only when the batch gives up: Err.
        let _ = p.read_quadlets(&reqs[..], &mut out);
        drop(p);
        let seen = h.join().unwrap();
        assert!(seen.len() >= usize::from(window), "{seen:?}");
        assert_eq!(
            *max.lock().unwrap(),
            usize::from(window),
            "window {window}: {seen:?}"
        );
    }
}

/// After a batch in which a datagram was shown lost, the next batch keeps twice the window
/// outstanding (issue 22 item 7: the re-asks of a lossy link fit the cycle); after a clean
/// batch, the window again. Counted by a board that, in its counting phase, answers the oldest
/// pending request only after a pause in which it collects whatever else the port sends.
#[test]
fn a_lossy_batch_widens_the_next_one_and_a_clean_batch_narrows_it_again() {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    use std::sync::{Arc, Mutex};
    let reqs = shared_cycle();
    // Datagrams the board has taken off its socket, to wait for the last batch's before the
    // phase changes: on a loaded machine a re-ask sent near the end of a batch can still be
    // queued when the next begins, and counted as one more outstanding register.
    let received = Arc::new(AtomicU64::new(0));
    let rx = received.clone();
    // Phase 0: drop the first request of register 5, answer everything else at once.
    // Phase 1: count the outstanding registers, answer none before a pause.
    let phase = Arc::new(Mutex::new(0u8));
    let max = Arc::new(Mutex::new(0usize));
    let (ph, mx) = (phase.clone(), max.clone());
    let drop_once = reqs[5];
    let drop_armed = Arc::new(AtomicBool::new(true));
    let armed = drop_armed.clone();
    let mut pending = Pending::new();
    let (addr, h) = board(boards_with(4), move |boards, req, replies, sock, from| {
        rx.fetch_add(1, Ordering::SeqCst);
        if *ph.lock().unwrap() == 0 {
            if (req.node, req.addr) == drop_once && armed.swap(false, Ordering::SeqCst) {
                // Dropped.
            } else {
                send_all(sock, from, &replies);
            }
            return false;
        }
        // Registers answered in this batch: asked again, they are not outstanding.
        let mut answered: Vec<(u8, u16)> = Vec::new();
        let take = |pending: &mut Pending, answered: &[(u8, u16)], q: Req, r: Vec<Vec<u8>>| {
            hold_unanswered(pending, answered, &mx, q, r, sock, from);
        };
        take(&mut pending, &answered, req, replies);
        let more = more_requests(boards, sock, Duration::from_millis(5));
        rx.fetch_add(more.len() as u64, Ordering::SeqCst);
        for (q, r) in more {
            take(&mut pending, &answered, q, r);
        }
        while !pending.is_empty() {
            let (q, r) = pending.remove(0);
            send_all(sock, from, &r);
            answered.push((q.node, q.addr));
            // The port sends the next request when a reply comes: count it before answering on.
            let more = more_requests(boards, sock, Duration::from_millis(5));
            rx.fetch_add(more.len() as u64, Ordering::SeqCst);
            for (q, r) in more {
                take(&mut pending, &answered, q, r);
            }
        }
        false
    });
    // Waits until the board has taken every datagram the port sent (the port sends only
    // inside a read, so nothing more comes before the next one).
    let settle = |p: &UdpPort| {
        let sent = p.counters().requests;
        let start = Instant::now();
        while received.load(Ordering::SeqCst) < sent {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "the board took {} of {sent} datagrams",
                received.load(Ordering::SeqCst)
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    let mut p = port(addr, 4);
    // Longer than a batch: the lost register is asked again because a later reply came.
    p.link_mut()
        .set_quadlet_retry_wait(Some(Duration::from_millis(400)));
    let mut out = vec![None; reqs.len()];
    assert_eq!(p.quadlet_window_now(), 4);
    // The loss shows when a later reply of the register's board comes before its retry wait
    // ends (once a round trip is measured, the round trip plus four deviations, at least
    // MIN_RETRY_WAIT). On a loaded machine this board's thread can be descheduled past that:
    // the register is then asked again by its timer, which rightly does not widen the window
    // (a slow board is not a lossy link; seen once in ten runs beside three busy loops on two
    // cores). So up to three tries, each with one request dropped; a port that never widens
    // fails all three.
    let mut window_after_loss = 0;
    for _ in 0..3 {
        drop_armed.store(true, Ordering::SeqCst);
        let retries = p.counters().quadlet_retries;
        p.read_quadlets(&reqs, &mut out).unwrap();
        assert!(p.counters().quadlet_retries > retries, "{:?}", p.counters());
        window_after_loss = p.quadlet_window_now();
        if window_after_loss == 8 {
            break;
        }
    }
    assert_eq!(window_after_loss, 8, "after a loss");
    settle(&p);
    *phase.lock().unwrap() = 1;
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(
        *max.lock().unwrap(),
        8,
        "outstanding in the batch after a loss"
    );
    assert_eq!(p.quadlet_window_now(), 4, "after a clean batch");
    settle(&p);
    *max.lock().unwrap() = 0;
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(
        *max.lock().unwrap(),
        4,
        "outstanding in the batch after a clean one"
    );
    drop(p);
    h.join().unwrap();
}

/// A lost request and a lost reply: both registers are asked again with new labels and
/// answered within the batch, every value right.
#[test]
fn a_lost_request_or_reply_is_asked_again_and_answered() {
    let mut truth = boards_with(2);
    let reqs = shared_cycle();
    let want = expected(&mut truth, &reqs);
    let lose_request = reqs[3];
    let lose_reply = reqs[9];
    let mut lost = (false, false);
    let (addr, h) = board(boards_with(2), move |_, req, replies, sock, from| {
        let r = (req.node, req.addr);
        if r == lose_request && !lost.0 {
            lost.0 = true;
        } else if r == lose_reply && !lost.1 {
            lost.1 = true;
        } else {
            send_all(sock, from, &replies);
        }
        false
    });
    let mut p = port(addr, 4);
    let mut out = vec![None; reqs.len()];
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(out, want);
    let c = p.counters();
    assert!(c.quadlet_retries >= 2, "{c:?}");
    assert_eq!(c.replies_ok, reqs.len() as u64, "{c:?}");
    drop(p);
    let seen = h.join().unwrap();
    for r in [lose_request, lose_reply] {
        let asked: Vec<&Req> = seen.iter().filter(|q| (q.node, q.addr) == r).collect();
        assert!(asked.len() >= 2, "{r:?} asked {asked:?}");
        assert_ne!(asked[0].label, asked[1].label);
    }
}

/// The reply to a register of one cycle held back by the board and sent in the next cycle,
/// after that cycle's first request (so after the port's drain), is skipped: the next cycle's
/// values are all the new ones, though the stale reply comes from the right node with a label
/// the port used (in the cycle before).
#[test]
fn a_stale_reply_of_an_earlier_cycle_is_never_taken() {
    let mut truth = boards_with(3);
    let reqs = shared_cycle();
    let n = reqs.len();
    let held_register = reqs[4];
    let mut stale: Option<Vec<u8>> = None;
    let cycle2 = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let c2 = cycle2.clone();
    let mut in_cycle2 = false;
    let (addr, h) = board(boards_with(3), move |boards, req, replies, sock, from| {
        if !in_cycle2 && c2.load(std::sync::atomic::Ordering::SeqCst) {
            // Cycle 2's first request: the values change, this request is answered with the
            // new ones, then the reply held back in cycle 1 arrives.
            in_cycle2 = true;
            set_values(boards, 4);
            let fresh = boards.answer_quadlet_read(req.node, req.addr, req.label);
            send_all(sock, from, &fresh);
            sock.send_to(&stale.take().unwrap(), from).unwrap();
            return false;
        }
        if (req.node, req.addr) == held_register && stale.is_none() {
            // Cycle 1: hold this reply back; the port asks again and gets the next one.
            stale = replies.into_iter().next();
            return false;
        }
        send_all(sock, from, &replies);
        false
    });
    let mut p = port(addr, 4);
    let mut out = vec![None; n];
    let r = p.read_quadlets(&reqs, &mut out);
    assert_eq!(r, Ok(()), "{:?}", p.counters());
    assert_eq!(out, expected(&mut truth, &reqs));
    set_values(&mut truth, 4);
    let want = expected(&mut truth, &reqs);
    assert_ne!(out, want, "the test needs values that change");
    cycle2.store(true, std::sync::atomic::Ordering::SeqCst);
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(out, want);
    assert!(p.counters().stale_replies >= 1, "{:?}", p.counters());
    drop(p);
    h.join().unwrap();
}

/// A reply whose source node is not the board the label was sent to is refused (it would be
/// the right value here, so the proof is that the register is asked again).
#[test]
fn a_reply_from_another_source_is_refused() {
    let mut truth = boards_with(5);
    let reqs = shared_cycle();
    let want = expected(&mut truth, &reqs);
    let wrong = (7u8, 0x15u16);
    let mut done = false;
    let (addr, h) = board(boards_with(5), move |boards, req, replies, sock, from| {
        if (req.node, req.addr) == wrong && !done {
            // Right label and register, source node 8.
            done = true;
            boards.fault = common::Fault::WrongSource;
            let r = boards.answer_quadlet_read(req.node, req.addr, req.label);
            boards.fault = common::Fault::None;
            send_all(sock, from, &r);
            return false;
        }
        send_all(sock, from, &replies);
        false
    });
    let mut p = port(addr, 4);
    let mut out = vec![None; reqs.len()];
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(out, want);
    assert!(p.counters().stale_replies >= 1, "{:?}", p.counters());
    drop(p);
    let seen = h.join().unwrap();
    let asked = seen.iter().filter(|q| (q.node, q.addr) == wrong).count();
    assert!(asked >= 2, "{seen:?}");
}

/// Board 7 never answers: the batch ends at its deadline, well before the 2 s reply timeout,
/// with board 6's registers read and board 7's `None`. The next batch asks the silent board
/// once, not once per register.
#[test]
fn a_silent_board_ends_the_batch_at_its_deadline() {
    let reqs = shared_cycle();
    let (addr, h) = board(Boards::psm(8), move |_, req, replies, sock, from| {
        if req.node != 7 {
            send_all(sock, from, &replies);
        }
        false
    });
    let mut p = port(addr, 4);
    p.set_quadlet_batch_budget(Some(Duration::from_millis(50)));
    let mut out = vec![None; reqs.len()];
    let t0 = Instant::now();
    let r = p.read_quadlets(&reqs, &mut out);
    // A liveness bound (the budget is 50 ms, the reply timeout 2 s), not a speed claim.
    assert!(t0.elapsed() < Duration::from_secs(1), "{:?}", t0.elapsed());
    assert!(
        matches!(r, Err(PortError::Timeout { board: 7, .. })),
        "{r:?}"
    );
    for (i, &(b, _)) in reqs.iter().enumerate() {
        assert_eq!(out[i].is_some(), b == 6, "entry {i} {:?}", reqs[i]);
    }
    let before = p.counters().requests;
    let r = p.read_quadlets(&reqs, &mut out);
    assert!(r.is_err());
    drop(p);
    let seen = h.join().unwrap();
    let to_7_in_second = seen[before as usize..]
        .iter()
        .filter(|q| q.node == 7)
        .count();
    assert_eq!(to_7_in_second, 1, "{seen:?}");
}

/// A window of 1 is today's sequential read: one request at a time, in order.
#[test]
fn a_window_of_one_reads_in_turn() {
    let mut truth = boards_with(6);
    let reqs = shared_cycle();
    let want = expected(&mut truth, &reqs);
    let (addr, h) = board(boards_with(6), move |_, _, replies, sock, from| {
        send_all(sock, from, &replies);
        false
    });
    let mut p = port(addr, 1);
    // Longer than a loaded machine's scheduling delays: no read is asked twice.
    p.link_mut()
        .set_quadlet_retry_wait(Some(Duration::from_millis(100)));
    let mut out = vec![None; reqs.len()];
    p.read_quadlets(&reqs, &mut out).unwrap();
    assert_eq!(out, want);
    assert_eq!(p.counters().quadlet_batches, 0);
    drop(p);
    let seen: Vec<(u8, u16)> = h.join().unwrap().iter().map(|r| (r.node, r.addr)).collect();
    assert_eq!(seen, reqs);
}

/// A board thread that answers every request at once, except the first request of each
/// register in `hold`, answered that long after it arrived; repeats of those registers are
/// lost. It stops after a second without requests and returns the requests it saw.
fn holding_board(
    mut boards: Boards,
    hold: Vec<((u8, u16), Duration)>,
) -> (SocketAddr, std::thread::JoinHandle<Vec<Req>>) {
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let addr = sock.local_addr().unwrap();
    let h = std::thread::spawn(move || {
        let mut seen = Vec::new();
        let mut held: Vec<(Instant, SocketAddr, Vec<Vec<u8>>)> = Vec::new();
        let mut buf = [0u8; 2048];
        let mut last = Instant::now();
        while !held.is_empty() || last.elapsed() < Duration::from_secs(1) {
            let now = Instant::now();
            held.retain(|(due, to, r)| {
                if *due <= now {
                    send_all(&sock, *to, r);
                }
                *due > now
            });
            let Ok((n, from)) = sock.recv_from(&mut buf) else {
                continue;
            };
            last = Instant::now();
            let replies = boards.handle(&buf[..n]);
            let l = boards.log.last().unwrap();
            let req = Req {
                node: l.node,
                addr: l.addr as u16,
                label: request_label(&buf[..n]),
            };
            let first = !seen
                .iter()
                .any(|q: &Req| (q.node, q.addr) == (req.node, req.addr));
            seen.push(req);
            match hold.iter().find(|(r, _)| *r == (req.node, req.addr)) {
                None => send_all(&sock, from, &replies),
                Some((_, d)) if first => held.push((last + *d, from, replies)),
                Some(_) => {}
            }
        }
        seen
    });
    (addr, h)
}

/// Each register's reply timeout counts from its own first request, as a read on its own
/// would wait. With a window of 2, the board holds the first two registers' replies for 0.6 of
/// the reply timeout, so the last register is first asked about 0.6 timeouts into the batch;
/// its reply is held as long, so it arrives 1.2 timeouts after the batch began but 0.6 after
/// its register was asked. It is taken: a deadline shared by the batch would have given the
/// register up (the shared deadline that failed two-arm runs on a loaded machine).
#[test]
fn a_register_waits_its_reply_timeout_from_its_own_first_request() {
    let mut truth = boards_with(7);
    let reqs: Vec<(u8, u16)> = shared_cycle()[..4].to_vec();
    let want = expected(&mut truth, &reqs);
    let timeout = Duration::from_secs(1);
    let hold = timeout * 3 / 5;
    let (addr, h) = holding_board(
        boards_with(7),
        vec![(reqs[0], hold), (reqs[1], hold), (reqs[3], hold)],
    );
    let mut p = timed_port(addr, 2, timeout, Duration::from_millis(100));
    let mut out = vec![None; reqs.len()];
    let r = p.read_quadlets(&reqs, &mut out);
    assert_eq!(r, Ok(()), "{:?}", p.counters());
    assert_eq!(out, want);
    let c = p.counters();
    assert_eq!(c.batch_deadlines, 0, "{c:?}");
    assert!(
        c.quadlet_retries >= 1,
        "the held registers were asked again: {c:?}"
    );
    drop(p);
    let seen = h.join().unwrap();
    // The last register was first asked after the held ones were answered.
    let first_of = |r: (u8, u16)| seen.iter().position(|q| (q.node, q.addr) == r).unwrap();
    assert!(first_of(reqs[3]) > first_of(reqs[1]), "{seen:?}");
}

/// A board stalled for longer than the reply timeout (1.5 T here; a loaded host stalls the emulator
/// that way in CI, failing two-arm shared-mode tests with 4 requests in flight) answers the first
/// request of a register late and its repeats not at all. Each repeat gives the register the whole
/// timeout again (at most two after its first request), as one read at a time gives its last
/// attempt: the late reply is taken. With the deadline counted from the first request only, the
/// register was given up at T.
#[test]
fn a_register_asked_again_waits_the_reply_timeout_from_its_newest_request() {
    let mut truth = boards_with(7);
    let reqs: Vec<(u8, u16)> = shared_cycle()[..4].to_vec();
    let want = expected(&mut truth, &reqs);
    // A slow board (every first reply 20 ms late, so the measured round trip and the repeats'
    // wait are tens of ms, as they are µs against a board's 5 ms timeout in service): reqs[0]
    // is asked again at about 20 ms (overtaken), 80 ms and 140 ms, each repeat moving its
    // deadline to T after it, 2 T = 200 ms at most; its first reply comes at 1.5 T = 150 ms.
    let timeout = Duration::from_millis(100);
    let slow = Duration::from_millis(20);
    let (addr, h) = holding_board(
        boards_with(7),
        vec![
            (reqs[0], timeout * 3 / 2),
            (reqs[1], slow),
            (reqs[2], slow),
            (reqs[3], slow),
        ],
    );
    let mut p = timed_port(addr, 4, timeout, Duration::from_millis(30));
    let mut out = vec![None; reqs.len()];
    let r = p.read_quadlets(&reqs, &mut out);
    let c = p.counters();
    assert_eq!(r, Ok(()), "{c:?}");
    assert_eq!(out, want);
    assert!(
        c.quadlet_retries >= 1,
        "the held register was asked again: {c:?}"
    );
    drop(p);
    h.join().unwrap();
}

/// A register whose reply was lost is asked again as soon as the board answers a request
/// sent after it (a board answers in order), not after the retry wait: with a retry wait
/// longer than the whole test could take, the batch still completes, and the lost register's
/// repeat arrives at the board before the cycle's last register is asked. Behind one address
/// (one FPGA serves every node, here the test board) a reply of another node shows the loss
/// too: board 6's last register is asked again once board 7 answers.
#[test]
fn a_lost_reply_is_asked_again_once_a_later_request_is_answered() {
    let reqs = shared_cycle();
    // reqs[2]: followed by requests to its own board; reqs[9]: board 6's last register.
    for lose in [reqs[2], reqs[9]] {
        let mut truth = boards_with(8);
        let want = expected(&mut truth, &reqs);
        let mut lost = false;
        let (addr, h) = board(boards_with(8), move |_, req, replies, sock, from| {
            if (req.node, req.addr) == lose && !lost {
                lost = true;
                return false;
            }
            send_all(sock, from, &replies);
            false
        });
        let mut p = port(addr, 4);
        // The first requests' retry wait, before a round trip is measured: longer than the
        // batch; the reply timeout is 2 s.
        p.link_mut()
            .set_quadlet_retry_wait(Some(Duration::from_millis(400)));
        let mut out = vec![None; reqs.len()];
        p.read_quadlets(&reqs, &mut out).unwrap();
        assert_eq!(out, want);
        let c = p.counters();
        assert!(c.quadlet_retries >= 1, "{lose:?}: {c:?}");
        drop(p);
        let seen = h.join().unwrap();
        let asked: Vec<usize> = seen
            .iter()
            .enumerate()
            .filter(|(_, q)| (q.node, q.addr) == lose)
            .map(|(k, _)| k)
            .collect();
        // Twice, or more if a loaded machine delayed the repeat's answer past the retry wait.
        assert!(asked.len() >= 2, "{seen:?}");
        // Asked again while the cycle's later registers were still being asked: not left
        // for the retry wait.
        assert!(asked[1] < reqs.len(), "{lose:?}: {seen:?}");
    }
}

/// Not a check: the figures of RELIABILITY.md's probe (issue 22 item 7). A board thread that
/// loses 10% of the requests and 10% of the replies (seeded), 3000 shared-mode cycles per
/// window, reply timeout 5 ms; prints the batch time's p50, mean and p99, the share of cycles
/// read whole and the repeats per cycle. `cargo test -p dvrk-io --test quadlet_batch --
/// --ignored --nocapture probe`.
#[test]
#[ignore]
fn probe_ten_percent_loss() {
    fn chance(state: &mut u64, p: f64) -> bool {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64) < p
    }
    let windows: Vec<u8> = std::env::var("PROBE_WINDOWS")
        .ok()
        .map(|s| s.split(',').filter_map(|w| w.parse().ok()).collect())
        .unwrap_or_else(|| vec![1, 4]);
    // PROBE_PERIOD_US: start the cycles at this period (as `serve` does), else back to back.
    let period = std::env::var("PROBE_PERIOD_US")
        .ok()
        .and_then(|s| s.parse().ok())
        .map(Duration::from_micros);
    let cycles = 3000;
    for window in windows {
        let mut rng = 22u64;
        let (addr, h) = board(boards_with(1), move |_, _, replies, sock, from| {
            if !chance(&mut rng, 0.1) {
                for r in replies {
                    if !chance(&mut rng, 0.1) {
                        sock.send_to(&r, from).unwrap();
                    }
                }
            }
            false
        });
        let mut p = UdpPort::open_udp(addr).unwrap();
        p.link_mut().set_timeout(Duration::from_millis(5)).unwrap();
        p.set_quadlet_window(window);
        let reqs = shared_cycle();
        let mut out = vec![None; reqs.len()];
        let mut times = Vec::with_capacity(cycles);
        let mut whole = 0;
        let start = Instant::now();
        for k in 0..cycles {
            if let Some(period) = period {
                let at = start + period * k as u32;
                std::thread::sleep(at.saturating_duration_since(Instant::now()));
            }
            let t0 = Instant::now();
            whole += usize::from(p.read_quadlets(&reqs, &mut out).is_ok());
            times.push(t0.elapsed());
        }
        times.sort_unstable();
        let mean = times.iter().sum::<Duration>() / cycles as u32;
        let c = p.counters();
        eprintln!(
            "PROBE window={window} p50_us={:.0} mean_us={:.0} p99_us={:.0} whole={:.4} \
             repeats_per_cycle={:.2} stale_per_cycle={:.2} retry_wait_us={:.0} \
             labels_reused_unanswered={}",
            times[cycles / 2].as_secs_f64() * 1e6,
            mean.as_secs_f64() * 1e6,
            times[cycles * 99 / 100].as_secs_f64() * 1e6,
            whole as f64 / cycles as f64,
            c.quadlet_retries as f64 / cycles as f64,
            c.stale_replies as f64 / cycles as f64,
            p.quadlet_retry_wait().unwrap_or_default().as_secs_f64() * 1e6,
            c.labels_reused_unanswered,
        );
        drop(p);
        h.join().unwrap();
    }
}

/// The board's side of a test that counts cycles: `cycle` is the test's cycle, `seen` the last
/// one the board saw. A new cycle gives the boards its values ([`set_values`] of the cycle + 3).
/// Returns the cycle and whether it is new.
fn follow_cycle(
    cycle: &std::sync::atomic::AtomicUsize,
    seen: &mut usize,
    boards: &mut Boards,
) -> (usize, bool) {
    let now = cycle.load(std::sync::atomic::Ordering::SeqCst);
    let new = now != *seen;
    if new {
        *seen = now;
        set_values(boards, now as i32 + 3);
    }
    (now, new)
}

/// The label of the first request for `register` the board saw, and the later requests that
/// carried that label again.
fn label_used_again(seen: &[Req], register: (u8, u16)) -> (u8, Vec<Req>) {
    let at = seen
        .iter()
        .position(|q| (q.node, q.addr) == register)
        .unwrap();
    let label = seen[at].label;
    let again = seen[at + 1..]
        .iter()
        .filter(|q| q.label == label)
        .copied()
        .collect();
    (label, again)
}

/// A reply held back by the board for several cycles (longer than one batch, shorter than the
/// reply timeout) is never taken for another register: the label of a request without reply is
/// not used again within the reply timeout, though 64 labels wrap in four cycles. The held reply
/// arrives in the fifth cycle and is skipped, and that cycle's values are all its own.
#[test]
fn the_label_of_an_unanswered_request_is_not_reused_within_the_reply_timeout() {
    let reqs = shared_cycle();
    let n = reqs.len();
    let held_register = reqs[4];
    let cycle = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(1));
    let c = cycle.clone();
    let mut held: Option<(Req, Vec<u8>)> = None;
    let mut sent_back = false;
    let mut seen_cycle = 1;
    let (addr, h) = board(boards_with(3), move |boards, req, replies, sock, from| {
        let (now_cycle, new) = follow_cycle(&c, &mut seen_cycle, boards);
        if new && now_cycle == 5 && !sent_back {
            // The fifth cycle's first request: answer it, then the reply held since the first
            // cycle arrives.
            sent_back = true;
            let fresh = boards.answer_quadlet_read(req.node, req.addr, req.label);
            send_all(sock, from, &fresh);
            sock.send_to(&held.as_ref().unwrap().1, from).unwrap();
            return false;
        }
        if (req.node, req.addr) == held_register && held.is_none() {
            held = Some((req, replies.into_iter().next().unwrap()));
            return false;
        }
        send_all(sock, from, &replies);
        false
    });
    let mut p = port(addr, 4);
    let mut out = vec![None; n];
    for k in 1..=5usize {
        cycle.store(k, std::sync::atomic::Ordering::SeqCst);
        let mut truth = boards_with(k as i32 + 3);
        if k == 1 {
            truth = boards_with(3);
        }
        let r = p.read_quadlets(&reqs, &mut out);
        assert_eq!(r, Ok(()), "cycle {k}: {:?}", p.counters());
        assert_eq!(out, expected(&mut truth, &reqs), "cycle {k}");
    }
    assert!(p.counters().stale_replies >= 1, "{:?}", p.counters());
    drop(p);
    let seen = h.join().unwrap();
    let (held_label, again) = label_used_again(&seen, held_register);
    // Labels wrap after 64 requests; these cycles made more than that.
    assert!(seen.len() > 64, "{}", seen.len());
    assert!(again.is_empty(), "label {held_label} used again: {seen:?}");
}

/// A register given up at its deadline makes its board's registers not asked yet unread; if
/// its reply then comes late (while the batch still waits for another board), the batch still
/// says why they are unread: an invalid sample always carries its reason. (Before, the late
/// reply turned the given-up register into a read one and the batch returned Ok with the
/// skipped registers empty: `serve` published them invalid with no reason but HELD.)
#[test]
fn registers_skipped_after_a_give_up_are_reported_even_if_the_late_reply_comes() {
    // Board 7's first encoder moved up to third, so that board 7 keeps the window's second
    // place while board 6 is given up.
    let mut reqs = shared_cycle();
    let enc7 = reqs.remove(10);
    reqs.insert(2, enc7);
    let timeout = Duration::from_millis(300);
    // Two at a time. Board 6's status (reqs[0]) is held past its last deadline (2 T after its
    // first request at the latest; its repeats get no reply) and answers at 2.1 T. Board 7's
    // status answers at 0.5 T; board 7's first encoder (reqs[2]), asked then and held 1.8 T,
    // answers at 2.3 T, before its own last deadline (2.5 T). So board 6 is given up (by 2 T)
    // with its other registers not asked yet, they are skipped, and reqs[0]'s late reply comes
    // while the batch still waits for reqs[2]: every register but the skipped ones is read.
    let (addr, h) = holding_board(
        boards_with(8),
        vec![
            (reqs[0], timeout * 21 / 10),
            (reqs[1], timeout / 2),
            (reqs[2], timeout * 9 / 5),
        ],
    );
    // A retry wait well below T: the held registers are asked again (for silence, with a
    // doubling wait), which moves their deadlines on.
    let mut p = timed_port(addr, 2, timeout, Duration::from_millis(10));
    let mut out = vec![None; reqs.len()];
    let r = p.read_quadlets(&reqs, &mut out);
    let unread: Vec<(u8, u16)> = reqs
        .iter()
        .zip(&out)
        .filter(|(_, v)| v.is_none())
        .map(|(r, _)| *r)
        .collect();
    assert!(!unread.is_empty(), "nothing was left unread: {out:?}");
    assert!(
        matches!(r, Err(PortError::Timeout { board: 6, .. })),
        "{r:?} with {unread:?} unread"
    );
    drop(p);
    h.join().unwrap();
}

/// A reply later than the reply timeout (a board that stalled and then answers what it had
/// queued, a reply held in a switch) is never taken for another register. The label of its
/// request is free again once the timeout has passed, but goes to other labels' registers only
/// when nothing else is left: here, with no other loss, it is not used again at all. The board
/// sends the held reply just before its answer to any later request that carries the label
/// (the worst moment), or else at the last cycle; every cycle reads its own values.
#[test]
fn a_reply_later_than_the_reply_timeout_is_never_taken_for_another_register() {
    // Board 6 only: its status, and encoder position and ADC of its four actuators.
    let reqs: Vec<(u8, u16)> = shared_cycle().into_iter().filter(|r| r.0 == 6).collect();
    let n = reqs.len();
    let held_register = reqs[3];
    let timeout = Duration::from_millis(20);
    // At most 28 ([`set_values`] keeps each current below 0x10000).
    let cycles = 25usize;
    let cycle = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(1));
    let c = cycle.clone();
    let mut held: Option<(Req, Vec<u8>)> = None;
    let mut sent_back = false;
    let mut seen_cycle = 1;
    let (addr, h) = board(boards_with(4), move |boards, req, replies, sock, from| {
        let (now_cycle, _) = follow_cycle(&c, &mut seen_cycle, boards);
        if (req.node, req.addr) == held_register && held.is_none() {
            held = Some((req, replies.into_iter().next().unwrap()));
            return false;
        }
        if let Some((q, r)) = &held
            && !sent_back
            && (q.label == req.label || now_cycle == cycles)
        {
            sent_back = true;
            if q.label == req.label {
                sock.send_to(r, from).unwrap();
                send_all(sock, from, &replies);
            } else {
                send_all(sock, from, &replies);
                sock.send_to(r, from).unwrap();
            }
            return false;
        }
        send_all(sock, from, &replies);
        false
    });
    let mut p = timed_port(addr, 4, timeout, Duration::from_millis(2));
    let mut out = vec![None; n];
    let t0 = Instant::now();
    for k in 1..=cycles {
        cycle.store(k, std::sync::atomic::Ordering::SeqCst);
        let mut truth = boards_with(k as i32 + 3);
        let r = p.read_quadlets(&reqs, &mut out);
        assert_eq!(r, Ok(()), "cycle {k}: {:?}", p.counters());
        assert_eq!(
            out,
            expected(&mut truth, &reqs),
            "cycle {k}: {:?}",
            p.counters()
        );
        std::thread::sleep(Duration::from_millis(4));
    }
    // The cycles outlasted the timeout (and its quarantine) several times over.
    assert!(t0.elapsed() > timeout * 4, "{:?}", t0.elapsed());
    assert!(p.counters().stale_replies >= 1, "{:?}", p.counters());
    assert_eq!(
        p.counters().labels_reused_unanswered,
        0,
        "{:?}",
        p.counters()
    );
    drop(p);
    let seen = h.join().unwrap();
    let (held_label, again) = label_used_again(&seen, held_register);
    let reused_for_another: Vec<_> = again
        .iter()
        .filter(|q| (q.node, q.addr) != held_register)
        .collect();
    assert!(seen.len() > 2 * 64, "{}", seen.len());
    assert!(
        reused_for_another.is_empty(),
        "label {held_label} used again for another register: {reused_for_another:?}"
    );
}

/// The boards stall for 40 cycles (each cycle then asks each board once and gives up at the
/// reply timeout: more requests queued than there are labels), then run again and answer every
/// request they queued, at once, while the port reads on. No value of one register is ever
/// taken for another: every value read is one its own register had. (Before the one request
/// to a silent board kept its label, the first cycle after read board 6's status as its first
/// encoder position.)
#[test]
fn a_stall_longer_than_the_label_space_leaves_no_reply_for_another_register() {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let reqs = shared_cycle();
    let n = reqs.len();
    // Values of cycles 1..=20 (the board's values follow the cycle modulo 20).
    let values_of = |k: usize| boards_with((k % 20) as i32 + 1);
    let mut own: Vec<std::collections::HashSet<u32>> = vec![Default::default(); n];
    for k in 0..20 {
        for (i, v) in expected(&mut values_of(k), &reqs).into_iter().enumerate() {
            own[i].insert(v.unwrap());
        }
    }
    for i in 0..n {
        for j in 0..n {
            if i != j && reqs[i] != reqs[j] {
                assert!(
                    own[i].is_disjoint(&own[j]),
                    "{:?} and {:?}",
                    reqs[i],
                    reqs[j]
                );
            }
        }
    }
    let cycle = std::sync::Arc::new(AtomicUsize::new(0));
    let stalled = std::sync::Arc::new(AtomicBool::new(false));
    let (c, st) = (cycle.clone(), stalled.clone());
    let mut queued: Vec<Req> = Vec::new();
    let (addr, h) = board(values_of(0), move |boards, req, replies, sock, from| {
        *boards = {
            let mut b = values_of(c.load(Ordering::SeqCst));
            b.log = std::mem::take(&mut boards.log);
            b
        };
        if st.load(Ordering::SeqCst) {
            queued.push(req);
            return false;
        }
        // Running again: what was queued is answered first, with the values of now.
        for q in queued.drain(..) {
            let r = boards.answer_quadlet_read(q.node, q.addr, q.label);
            send_all(sock, from, &r);
        }
        send_all(sock, from, &replies);
        false
    });
    let mut p = timed_port(addr, 4, Duration::from_millis(5), Duration::from_millis(1));
    let mut out = vec![None; n];
    let check = |p: &mut UdpPort, k: usize, out: &mut Vec<Option<u32>>| {
        cycle.store(k, Ordering::SeqCst);
        out.fill(None);
        let r = p.read_quadlets(&reqs, out);
        for (i, v) in out.iter().enumerate() {
            if let Some(v) = v {
                assert!(
                    own[i].contains(v),
                    "cycle {k}: {:?} read {v:#x}, not one of its values ({r:?}, {:?})",
                    reqs[i],
                    p.counters()
                );
            }
        }
        r
    };
    for k in 0..5 {
        assert_eq!(check(&mut p, k, &mut out), Ok(()));
    }
    // 40 cycles, each asking each of the two boards at least once: more requests queued than
    // there are labels.
    stalled.store(true, Ordering::SeqCst);
    let mut k = 5;
    for _ in 0..40 {
        assert!(
            check(&mut p, k, &mut out).is_err(),
            "cycle {k} read the stalled boards"
        );
        k += 1;
    }
    stalled.store(false, Ordering::SeqCst);
    let mut whole_after = 0;
    for _ in 0..40 {
        whole_after += usize::from(check(&mut p, k, &mut out).is_ok());
        k += 1;
    }
    assert!(
        whole_after >= 30,
        "{whole_after} of 40 cycles whole after the stall"
    );
    eprintln!("stall: then {whole_after} of 40 whole; {:?}", p.counters());
    drop(p);
    h.join().unwrap();
}
