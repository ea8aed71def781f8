//! The UDP port against a responder thread on 127.0.0.1 (real sockets, ephemeral ports).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::net::{Ipv4Addr, UdpSocket};
use std::time::Duration;

use common::{Board, Boards, Fault, Responder};
use dvrk_io::port::{BoardProbe, EthMode, Port, PortError, UdpLink, UdpPort, conformance};
use dvrk_io::wire::Tcode;
use dvrk_io::wire::block::hardware_version;

/// A port that asks once per quadlet read (no retry), so that these tests can count requests
/// exactly whatever the load of the machine; the retry has tests of its own below.
fn port_to(r: &Responder, timeout_ms: u64) -> UdpPort {
    let mut p = UdpPort::open_udp(r.addr).unwrap();
    p.link_mut()
        .set_timeout(Duration::from_millis(timeout_ms))
        .unwrap();
    p.link_mut().set_quadlet_retry_wait(None);
    p
}

#[test]
fn quadlet_and_block_reads() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 200);
    assert_eq!(p.read_quadlet(6, 4).unwrap(), hardware_version::QLA1);
    assert_eq!(p.read_quadlet(7, 7).unwrap(), 8);
    let mut blk = [0u8; 128];
    p.read_block(6, 0, &mut blk).unwrap();
    assert_eq!(&blk[..], &r.with(|b| b.board(6).block.clone())[..]);
    // Labels rotate through 6 bits and wrap.
    for _ in 0..70 {
        p.read_quadlet(6, 0).unwrap();
    }
    assert_eq!(p.next_label(), (3 + 70) % 64);
    let c = p.counters();
    assert_eq!(c.requests, 73);
    assert_eq!(c.replies_ok, 73);
    assert_eq!(c.writes, 0);
    r.with(|b| assert!(b.log.iter().all(|l| l.noforward)));
}

#[test]
fn timeout_names_board_and_address() {
    let r = Responder::spawn(Boards::psm(8));
    r.set_fault(Fault::Silent);
    let mut p = port_to(&r, 20);
    assert_eq!(
        p.read_quadlet(6, 0x15).unwrap_err(),
        PortError::Timeout {
            board: 6,
            addr: 0x15
        }
    );
    assert_eq!(p.counters().timeouts, 1);
    // Absent board: no reply either.
    r.set_fault(Fault::None);
    assert_eq!(
        p.read_quadlet(9, 4).unwrap_err(),
        PortError::Timeout { board: 9, addr: 4 }
    );
}

#[test]
fn every_malformed_reply_is_its_own_error() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 40);
    let mut blk = [0u8; 128];
    type Check = fn(&PortError) -> bool;
    let cases: [(Fault, Check); 10] = [
        (Fault::Truncate, |e| {
            matches!(
                e,
                PortError::Truncated {
                    board: 6,
                    got: 20,
                    need: 28
                }
            )
        }),
        (Fault::Oversize, |e| {
            matches!(
                e,
                PortError::Oversized {
                    board: 6,
                    got: 32,
                    expected: 28
                }
            )
        }),
        (Fault::WrongTcode, |e| {
            matches!(
                e,
                PortError::WrongTcode {
                    board: 6,
                    expected: 6,
                    got: 7
                }
            )
        }),
        (Fault::WrongLabel, |e| {
            matches!(e, PortError::WrongLabel { board: 6, .. })
        }),
        (Fault::WrongSource, |e| {
            matches!(
                e,
                PortError::WrongSource {
                    board: 6,
                    expected: 6,
                    got: 7
                }
            )
        }),
        (
            Fault::Dropped8,
            |e| matches!(e, PortError::PacketDropped { board: 6, flags } if flags & 0x02 != 0),
        ),
        (Fault::DroppedFlag, |e| {
            matches!(e, PortError::PacketDropped { board: 6, .. })
        }),
        (Fault::BusReset, |e| {
            matches!(
                e,
                PortError::BusReset {
                    board: 6,
                    generation: 0
                }
            )
        }),
        (Fault::InternalError, |e| {
            matches!(e, PortError::InternalError { board: 6, .. })
        }),
        (Fault::Rcode, |e| {
            matches!(e, PortError::ResponseCode { board: 6, rcode: 7 })
        }),
    ];
    for (fault, ok) in cases {
        r.set_fault(fault);
        let e = p.read_quadlet(6, 0).unwrap_err();
        assert!(ok(&e), "{fault:?} gave {e:?}");
    }
    r.set_fault(Fault::WrongLength);
    assert_eq!(
        p.read_block(6, 0, &mut blk).unwrap_err(),
        PortError::WrongLength {
            board: 6,
            expected: 128,
            got: 124
        }
    );
    r.set_fault(Fault::WrongTcode);
    assert_eq!(
        p.read_block(6, 0, &mut blk).unwrap_err(),
        PortError::WrongTcode {
            board: 6,
            expected: 7,
            got: 6
        }
    );
    // Nothing above was taken as data, and the port still works.
    r.set_fault(Fault::None);
    assert_eq!(p.read_quadlet(6, 4).unwrap(), hardware_version::QLA1);
    assert!(p.counters().bad_replies >= 10);
}

#[test]
fn stale_label_is_skipped_and_counted() {
    let r = Responder::spawn(Boards::psm(8));
    r.set_fault(Fault::StaleThenGood);
    let mut p = port_to(&r, 200);
    assert_eq!(p.read_quadlet(7, 4).unwrap(), hardware_version::QLA1);
    assert_eq!(p.counters().stale_replies, 1);
}

#[test]
fn datagrams_from_other_addresses_are_dropped_unparsed() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 200);
    let me = p.link().local_addr().unwrap();
    let intruder = UdpSocket::bind("127.0.0.1:0").unwrap();
    // A perfectly formed reply for label 0 from the wrong address, sent before the request.
    let forged = r.with(|b| {
        let req = [
            0x01, 0x00, 0xff, 0xc6, 0x00, 0x40, 0xff, 0xd0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
        ];
        b.handle(&req).pop().unwrap()
    });
    intruder.send_to(&forged, me).unwrap();
    intruder.send_to(&forged, me).unwrap();
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(p.read_quadlet(6, 4).unwrap(), hardware_version::QLA1);
    assert_eq!(p.link().foreign_datagrams(), 2);
}

#[test]
fn bad_block_sizes_are_refused_before_sending() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 50);
    assert_eq!(
        p.read_block(6, 0, &mut []).unwrap_err(),
        PortError::BlockSize { len: 0, max: 1440 }
    );
    assert_eq!(
        p.read_block(6, 0, &mut [0; 6]).unwrap_err(),
        PortError::BlockSize { len: 6, max: 1440 }
    );
    assert_eq!(
        p.read_block(6, 0, &mut vec![0; 1444]).unwrap_err(),
        PortError::BlockSize {
            len: 1444,
            max: 1440
        }
    );
    assert_eq!(
        p.read_quadlet(16, 0).unwrap_err(),
        PortError::BoardOutOfRange { board: 16 }
    );
    assert_eq!(p.counters().requests, 0);
}

#[test]
fn read_only_discovery_reports_found_and_missing() {
    let mut boards = Boards::psm(9);
    let mut b8 = Board::qla(8, 8);
    b8.fw = 6; // Rev 6: no supported layout
    boards.boards.push(b8);
    let mut b9 = Board::qla(9, 8);
    b9.hw = hardware_version::BCFG;
    boards.boards.push(b9);
    let r = Responder::spawn(boards);
    let mut p = port_to(&r, 20);
    let d = p.discover(&[6, 7]).unwrap();
    let i = d.found(7).unwrap();
    assert_eq!(
        (i.board_id, i.firmware_version, i.hardware_version),
        (7, 9, hardware_version::QLA1)
    );
    assert_eq!(
        p.discover(&[6, 7, 10]).unwrap_err(),
        PortError::BoardMissing { board: 10 }
    );
    assert_eq!(
        p.discover(&[8]).unwrap_err(),
        PortError::UnsupportedFirmware {
            board: 8,
            firmware: 6
        }
    );
    assert_eq!(
        p.discover(&[9]).unwrap_err(),
        PortError::UnknownHardware {
            board: 9,
            hardware: hardware_version::BCFG
        }
    );
    let d = dvrk_io::port::scan_boards(&mut p, &[6, 10]);
    assert!(matches!(d.boards[6], BoardProbe::Found(_)));
    assert_eq!(d.boards[10], BoardProbe::Missing);
    assert_eq!(p.counters().writes, 0);
    r.with(|b| assert_eq!(b.count(|l| l.tcode != Tcode::QuadletRead), 0));
}

#[test]
fn full_discovery_sequence_of_reference_3_3() {
    let r = Responder::spawn(Boards::psm(9));
    let mut p = port_to(&r, 10);
    let d = p
        .allow_writes()
        .init_nodes(Ipv4Addr::LOCALHOST, Duration::ZERO)
        .unwrap();
    assert_eq!(d.mode, Some(EthMode::EthernetOnly));
    assert_eq!(d.hub, Some(6));
    assert!(d.found(6).is_some() && d.found(7).is_some());
    assert_eq!(d.found(7).unwrap().git_description, Some(0x1234_5678));
    d.check(&[6, 7]).unwrap();
    r.with(|b| {
        let l = &b.log;
        // 1. broadcast write of the host IP to register 11, as the dVRK byte order (reference 9).
        assert_eq!(
            (l[0].node, l[0].tcode, l[0].addr, l[0].data),
            (0x3F, Tcode::QuadletWrite, 11, 0x0100_007F)
        );
        // 2. broadcast + NOFORWARD read of register 4.
        assert_eq!(
            (l[1].node, l[1].tcode, l[1].addr, l[1].noforward),
            (0x3F, Tcode::QuadletRead, 4, true)
        );
        // 3. broadcast write of 0 to the PHY request register.
        assert_eq!(
            (l[2].node, l[2].tcode, l[2].addr, l[2].data),
            (0x3F, Tcode::QuadletWrite, 1, 0)
        );
        // 4. hub registers 0, 7, 12.
        let hub: Vec<u64> = l[3..6].iter().map(|x| x.addr).collect();
        assert_eq!(hub, vec![0, 7, 12]);
        // 6. every node 0..15 asked for register 4.
        let scanned: Vec<u8> = l
            .iter()
            .skip(6)
            .filter(|x| x.addr == 4)
            .map(|x| x.node)
            .collect();
        assert_eq!(scanned, (0..16).collect::<Vec<u8>>());
    });
    assert_eq!(p.counters().writes, 2);
}

#[test]
fn conformance_suite_passes_on_udp() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 20);
    let rep = conformance::check_port(
        &mut p,
        conformance::ConformanceOptions {
            board: 6,
            allow_block_read: true,
            absent_board: Some(3),
        },
    )
    .unwrap();
    assert_eq!(rep.firmware_version, 8);
    assert_eq!(rep.layout.len_quadlets(), 32);
}

#[test]
fn conformance_suite_catches_a_wrong_board_id() {
    let mut boards = Boards::psm(8);
    let st = boards.board(7).status();
    boards
        .board(7)
        .set_status((st & !0x0F00_0000) | 0x0500_0000);
    let r = Responder::spawn(boards);
    let mut p = port_to(&r, 20);
    let e = conformance::check_port(
        &mut p,
        conformance::ConformanceOptions {
            board: 7,
            allow_block_read: false,
            absent_board: None,
        },
    )
    .unwrap_err();
    assert_eq!(e.check, "status board id");
}

#[test]
fn port_string_parsing() {
    assert!(UdpLink::from_port_string("fw:0").is_err());
    let l = UdpLink::from_port_string("udp:127.0.0.1:1394").unwrap();
    assert_eq!(
        l.target(),
        dvrk_io::port::UdpTarget::Single("127.0.0.1:1394".parse().unwrap())
    );
    let l = UdpLink::from_port_string("udp:127.0.0.1").unwrap();
    assert_eq!(
        l.target(),
        dvrk_io::port::UdpTarget::Single("127.0.0.1:1394".parse().unwrap())
    );
}

#[test]
fn writes_exist_only_behind_allow_writes() {
    let r = Responder::spawn(Boards::psm(8));
    let mut p = port_to(&r, 20);
    let mut hub = [0u8; 4 * (2 * 33 + 1)];
    assert_eq!(
        p.broadcast_query_hub_read(0xC0, &mut hub).unwrap_err(),
        PortError::QueryNotAllowed
    );
    r.with(|b| assert!(b.log.is_empty()));
    {
        let mut w = p.allow_writes();
        w.write_quadlet(6, 3, 0).unwrap();
        w.enable_broadcast_query();
    }
    p.broadcast_query_hub_read(0xC0, &mut hub).unwrap();
    let v = dvrk_io::wire::HubView::new_checked(
        &hub[..],
        dvrk_io::wire::HubLayout::new(&[
            (
                6,
                dvrk_io::wire::BlockLayout::new(8, dvrk_io::wire::BoardKind::Qla).unwrap(),
            ),
            (
                7,
                dvrk_io::wire::BlockLayout::new(8, dvrk_io::wire::BoardKind::Qla).unwrap(),
            ),
        ])
        .unwrap(),
    )
    .unwrap();
    assert_eq!(v.block(1).unwrap().status().board_id(), 7);
    r.with(|b| {
        assert_eq!(b.count(|l| l.tcode == Tcode::QuadletWrite), 2);
        assert_eq!(b.query_mask, 0xC0);
    });
}

#[test]
fn per_board_addressing_of_rev9_ethernet_only_boards() {
    // 127.0.0.0/8 is all loopback on Linux: board n answers at 127.0.0.(100+n), as Rev 9 boards
    // do at 169.254.0.(100+n) (reference 3.1).
    let mut only6 = Boards::psm(9);
    only6.boards.retain(|b| b.id == 6);
    let r6 = Responder::spawn_at(only6, "127.0.0.106:0".parse().unwrap()).unwrap();
    let port = r6.addr.port();
    let mut only7 = Boards::psm(9);
    only7.boards.retain(|b| b.id == 7);
    let Ok(r7) = Responder::spawn_at(only7, format!("127.0.0.107:{port}").parse().unwrap()) else {
        return; // that port is taken on 127.0.0.107; nothing to test with
    };
    let target = dvrk_io::port::UdpTarget::PerBoard {
        base: Ipv4Addr::new(127, 0, 0, 100),
        port,
        broadcast: Ipv4Addr::new(127, 255, 255, 255),
    };
    let mut p = UdpPort::new(UdpLink::new(target).unwrap());
    p.link_mut()
        .set_timeout(Duration::from_millis(200))
        .unwrap();
    p.link_mut().set_quadlet_retry_wait(None);
    assert_eq!(p.read_quadlet(6, 0).unwrap() >> 24 & 0xF, 6);
    assert_eq!(p.read_quadlet(7, 0).unwrap() >> 24 & 0xF, 7);
    r6.with(|b| assert_eq!(b.log.len(), 1));
    r7.with(|b| assert_eq!(b.log.len(), 1));
}

/// A board that stops answering for longer than the whole label space, then answers every queued
/// request at once (what a SIGSTOPped emulator or a stalled switch does): the late replies must
/// never be taken for the answers to new requests, and the port answers right again at once.
#[test]
fn late_replies_after_a_stall_are_drained_and_never_taken_for_new_answers() {
    let board = UdpSocket::bind("127.0.0.1:0").unwrap();
    board
        .set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut boards = Boards::psm(8);
    let mut p = UdpPort::open_udp(board.local_addr().unwrap()).unwrap();
    p.link_mut().set_timeout(Duration::from_millis(2)).unwrap();
    p.link_mut().set_quadlet_retry_wait(None);
    // 100 requests for the hardware version go unanswered...
    let mut queued = Vec::new();
    let mut buf = [0u8; 2048];
    let mut from = None;
    for _ in 0..100 {
        assert!(p.read_quadlet(6, 4).is_err());
        let (n, f) = board.recv_from(&mut buf).unwrap();
        from = Some(f);
        queued.extend(boards.handle(&buf[..n]));
    }
    // ...then are all answered late, before the next request is even sent.
    let from = from.unwrap();
    for r in &queued {
        board.send_to(r, from).unwrap();
    }
    std::thread::sleep(Duration::from_millis(20));
    // From now on the board answers at once. Ask for the firmware version (8): an old reply
    // with the same label would carry the hardware version instead.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let s2 = stop.clone();
    let answering = std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        while !s2.load(std::sync::atomic::Ordering::Relaxed) {
            if let Ok((n, f)) = board.recv_from(&mut buf) {
                for r in boards.handle(&buf[..n]) {
                    board.send_to(&r, f).unwrap();
                }
            }
        }
    });
    p.link_mut()
        .set_timeout(Duration::from_millis(200))
        .unwrap();
    for _ in 0..200 {
        assert_eq!(p.read_quadlet(6, 7).unwrap(), 8);
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    answering.join().unwrap();
    let c = p.counters();
    assert!(c.resyncs >= 1, "{c:?}");
    assert_eq!(
        c.drained + c.stale_replies,
        100,
        "every late reply is drained or skipped: {c:?}"
    );
}

/// A bit flipped anywhere in a reply's FireWire packet is caught by its CRC (the emulator and
/// this responder send CRCs); a source that sent CRCs cannot switch them off.
#[test]
fn corrupted_replies_fail_their_crc() {
    let board = UdpSocket::bind("127.0.0.1:0").unwrap();
    board
        .set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut boards = Boards::psm(8);
    let mut p = UdpPort::open_udp(board.local_addr().unwrap()).unwrap();
    p.link_mut()
        .set_timeout(Duration::from_millis(200))
        .unwrap();
    let mut buf = [0u8; 2048];
    let mut blk = [0u8; 128];
    // One good block read first: the port learns that this source sends CRCs.
    let mut exchange = |p: &mut UdpPort,
                        edit: &(dyn Fn(&mut Vec<u8>) + Sync),
                        blk: &mut [u8; 128]|
     -> Result<(), PortError> {
        std::thread::scope(|s| {
            let h = s.spawn(|| {
                let (n, f) = board.recv_from(&mut buf).unwrap();
                for mut r in boards.handle(&buf[..n]) {
                    edit(&mut r);
                    board.send_to(&r, f).unwrap();
                }
            });
            let r = p.read_block(6, 0, blk);
            h.join().unwrap();
            r
        })
    };
    exchange(&mut p, &|_| {}, &mut blk).unwrap();
    // Flip each bit of the data (after the 20-byte header) in turn: never accepted.
    for bit in [0usize, 7, 100, 511, 1000] {
        let e = exchange(
            &mut p,
            &move |r| r[20 + bit / 8] ^= 1 << (bit % 8),
            &mut blk,
        )
        .unwrap_err();
        assert!(
            matches!(e, PortError::CrcMismatch { board: 6, .. }),
            "{e:?}"
        );
    }
    // A zeroed CRC from this source is refused too.
    let e = exchange(&mut p, &|r| r[16..20].copy_from_slice(&[0; 4]), &mut blk).unwrap_err();
    assert!(
        matches!(e, PortError::CrcMismatch { board: 6, .. }),
        "{e:?}"
    );
    assert_eq!(p.counters().crc_errors, 6);
    exchange(&mut p, &|_| {}, &mut blk).unwrap();
}

/// A lost request or reply (issue 22): the quadlet read asks again after the retry's short wait
/// and takes the answer, well within the reply timeout; a board that stops answering costs one
/// retried read, then one request per read.
#[test]
fn a_lost_quadlet_is_asked_for_again_within_the_timeout() {
    let board = UdpSocket::bind("127.0.0.1:0").unwrap();
    board
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut p = UdpPort::open_udp(board.local_addr().unwrap()).unwrap();
    p.link_mut().set_timeout(Duration::from_secs(2)).unwrap();
    // Longer than a loaded machine keeps the board thread from running (the default 150 µs
    // is not: the answered request was asked again meanwhile), far below the timeout.
    p.link_mut()
        .set_quadlet_retry_wait(Some(Duration::from_millis(5)));
    let t = std::thread::spawn(move || {
        let mut boards = Boards::psm(8);
        let mut buf = [0u8; 2048];
        // The first request is lost; the second is answered.
        board.recv_from(&mut buf).unwrap();
        let (n, from) = board.recv_from(&mut buf).unwrap();
        for r in boards.handle(&buf[..n]) {
            board.send_to(&r, from).unwrap();
        }
        board
    });
    let t0 = std::time::Instant::now();
    assert_eq!(p.read_quadlet(6, 4).unwrap(), hardware_version::QLA1);
    // Far below the 2 s timeout the read would have waited without the retry.
    assert!(t0.elapsed() < Duration::from_secs(1), "{:?}", t0.elapsed());
    let c = p.counters();
    assert_eq!((c.requests, c.replies_ok, c.timeouts), (2, 1, 0), "{c:?}");
    assert!(c.quadlet_retries >= 1, "{c:?}");
    let board = t.join().unwrap();

    // Silent board: 4 requests for the first read, then 1 per read.
    p.link_mut().set_timeout(Duration::from_millis(20)).unwrap();
    let before = p.counters().requests;
    assert!(p.read_quadlet(6, 4).is_err());
    assert_eq!(p.counters().requests - before, 4);
    assert!(p.read_quadlet(6, 4).is_err());
    assert_eq!(p.counters().requests - before, 5);
    assert_eq!(p.counters().timeouts, 2);
    drop(board);
}

/// A reply slower than the retry's wait is still taken, as the answer to the read it belongs
/// to (its label is one of the read's requests).
#[test]
fn a_late_reply_answers_its_read_and_lengthens_the_wait() {
    let board = UdpSocket::bind("127.0.0.1:0").unwrap();
    board
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut p = UdpPort::open_udp(board.local_addr().unwrap()).unwrap();
    p.link_mut().set_timeout(Duration::from_secs(2)).unwrap();
    let t = std::thread::spawn(move || {
        let mut boards = Boards::psm(8);
        let mut buf = [0u8; 2048];
        // Answer the first request only after its retry came in.
        let (n, from) = board.recv_from(&mut buf).unwrap();
        let first = boards.handle(&buf[..n]);
        board.recv_from(&mut buf).unwrap();
        for r in first {
            board.send_to(&r, from).unwrap();
        }
    });
    assert_eq!(p.read_quadlet(6, 4).unwrap(), hardware_version::QLA1);
    t.join().unwrap();
    let c = p.counters();
    assert!(
        c.requests >= 2 && c.replies_ok == 1 && c.timeouts == 0,
        "{c:?}"
    );
}
