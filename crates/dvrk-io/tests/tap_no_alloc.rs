//! `TapDecoder::push` allocates nothing (one test per binary: the counting allocator is
//! global). The frames are a real exclusive-mode cycle of the test boards, recorded through the
//! Ethernet engine and wrapped in IPv4/UDP as a capture would see them.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::net::SocketAddrV4;
use std::sync::atomic::{AtomicUsize, Ordering};

use common::{Boards, InProcLink, PSM_CLASSIC_TOML};
use dvrk_io::port::{EthPort, RecordingLink};
use dvrk_io::tap::{LinkType, TapDecoder, TapEvent, emit_frame};
use dvrk_io::{AccessMode, ArmReader, ArmSample};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Only this test's thread is counted: the test harness's own threads may allocate at any
    /// time (output capture, timing), which would make a global count flaky.
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: forwards to the system allocator, only counting.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTED.with(Cell::get) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn wrap(src: &str, dst: &str, payload: &[u8]) -> Vec<u8> {
    let mut buf = vec![0u8; payload.len() + 64];
    let src: SocketAddrV4 = src.parse().unwrap();
    let dst: SocketAddrV4 = dst.parse().unwrap();
    let n = emit_frame(&mut buf, LinkType::Ip, src, dst, payload).unwrap();
    buf.truncate(n);
    buf
}

#[test]
fn push_allocates_nothing() {
    COUNTED.with(|c| c.set(true));
    let cfg = common::io_from_toml(PSM_CLASSIC_TOML).unwrap();
    let probe = ALLOCS.load(Ordering::Relaxed);
    std::hint::black_box(vec![0u8; 8]);
    assert!(
        ALLOCS.load(Ordering::Relaxed) > probe,
        "the counter sees allocations"
    );

    let mut rec = ArmReader::new(
        EthPort::new(RecordingLink::new(InProcLink::new(Boards::psm(9)))),
        cfg.clone(),
        AccessMode::Exclusive,
    );
    let mut s = ArmSample::default();
    rec.read(0, &mut s).unwrap();
    rec.read(1, &mut s).unwrap();
    let recorded = rec.into_port().into_link().into_frames();
    // The last cycle: one block read per board, each with its reply.
    let mut frames = Vec::new();
    for f in &recorded[recorded.len() - 2..] {
        frames.push(wrap("127.0.0.1:40000", "127.0.0.7:1394", &f.request));
        frames.push(wrap(
            "127.0.0.7:1394",
            "127.0.0.1:40000",
            f.reply.as_ref().unwrap(),
        ));
    }
    let mut dec = TapDecoder::new(cfg);
    let mut out = ArmSample::default();
    let before = ALLOCS.load(Ordering::Relaxed);
    let mut samples = 0;
    for i in 0..100u64 {
        for f in &frames {
            if dec.push(f, LinkType::Ip, i, &mut out) == TapEvent::Sample {
                samples += 1;
            }
        }
    }
    let after = ALLOCS.load(Ordering::Relaxed);
    assert_eq!(samples, 100, "{:?}", dec.counters());
    assert!(out.valid);
    assert_eq!(
        after - before,
        0,
        "{} allocations in 100 cycles",
        after - before
    );
}
