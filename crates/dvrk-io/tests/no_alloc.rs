//! `ArmReader::read` allocates nothing, in either mode (one test per binary: the counting
//! allocator is global).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use common::{Boards, InProcLink, PSM_CLASSIC_TOML};
use dvrk_io::port::{EthPort, RecordingLink, ReplayLink};
use dvrk_io::{AccessMode, ArmReader, ArmSample};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator, only counting.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
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

#[test]
fn read_allocates_nothing() {
    let cfg = common::io_from_toml(PSM_CLASSIC_TOML).unwrap();
    // The counter sees allocations at all (so this test can fail).
    let probe = ALLOCS.load(Ordering::Relaxed);
    std::hint::black_box(vec![0u8; 8]);
    assert!(ALLOCS.load(Ordering::Relaxed) > probe);
    for mode in [AccessMode::Shared, AccessMode::Exclusive] {
        // Record one cycle from the test boards (allocates), then replay it in a loop.
        let mut rec = ArmReader::new(
            EthPort::new(RecordingLink::new(InProcLink::new(Boards::psm(8)))),
            cfg.clone(),
            mode,
        );
        let mut s = ArmSample::default();
        rec.read(0, &mut s).unwrap();
        rec.read(1, &mut s).unwrap();
        let frames = rec.into_port().into_link().into_frames();
        // Keep only the steady-state cycle (the first exclusive cycle also learns the layouts).
        let per_cycle = if mode == AccessMode::Shared { 16 } else { 2 };
        let steady = frames[frames.len() - per_cycle..].to_vec();
        let mut reader = ArmReader::new(
            EthPort::new(ReplayLink::new(steady).looping(true)),
            cfg.clone(),
            mode,
        );
        if mode == AccessMode::Exclusive {
            // Learn layouts from a config that states the firmware, so no discovery reads happen.
            let text = PSM_CLASSIC_TOML.replacen(
                "hardware_version = \"QLA1\"",
                "hardware_version = \"QLA1\"\nfirmware_version = 8",
                1,
            );
            let cfg8 = common::io_from_toml(&text).unwrap();
            let steady = reader.into_port().into_link();
            reader = ArmReader::new(EthPort::new(steady), cfg8, mode);
        }
        reader.read(2, &mut s).unwrap();
        let before = ALLOCS.load(Ordering::Relaxed);
        for i in 0..100 {
            reader.read(3 + i, &mut s).unwrap();
        }
        let after = ALLOCS.load(Ordering::Relaxed);
        assert!(s.valid);
        assert_eq!(
            after - before,
            0,
            "{mode:?}: {} allocations in 100 reads",
            after - before
        );
    }
}
