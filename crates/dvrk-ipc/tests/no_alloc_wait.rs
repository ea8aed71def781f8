//! The consumer's per-cycle path allocates nothing: `Subscription::wait` with every strategy,
//! while a publisher on another thread sends on a 1 ms grid, under a counting global allocator
//! that watches the subscriber's thread only.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, CycleMessages, Header, PoseV2, SubscribeOptions, Subscription, Topic, Update,
    WaitStrategy, create_node, monotonic_ns,
};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    static WATCH: Cell<bool> = const { Cell::new(false) };
}

fn note() {
    if WATCH.try_with(Cell::get).unwrap_or(false) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn waiting_allocates_nothing_with_any_strategy() {
    // One test in this binary: the counter is global. It must be able to fail:
    WATCH.with(|w| w.set(true));
    drop(std::hint::black_box(vec![1u8; 64]));
    WATCH.with(|w| w.set(false));
    assert_eq!(ALLOCATIONS.swap(0, Ordering::Relaxed), 1);
    for wait in WaitStrategy::ALL {
        let d = Domain::new(&format!("na_{wait}"));
        let node = create_node::<ipc::Service>("na_sub", Some(&d.config)).unwrap();
        let options = SubscribeOptions {
            period: Duration::from_millis(1),
            wait,
            deadline: Some(Duration::from_millis(200)),
            ..SubscribeOptions::default()
        };
        let mut sub = Subscription::<PoseV2>::with_options(
            &node,
            &d.names,
            Topic::CompensatedMeasuredCp,
            options,
        )
        .unwrap();
        let config = d.config.clone();
        let names = d.names.clone();
        const N: u64 = 400;
        let publisher = std::thread::spawn(move || {
            let node = create_node::<ipc::Service>("na_pub", Some(&config)).unwrap();
            let p = ArmPublisher::create(&node, &names).unwrap();
            let t0 = monotonic_ns();
            for seq in 1..=N {
                while monotonic_ns() < t0 + seq * 1_000_000 {
                    std::thread::sleep(Duration::from_micros(100));
                }
                let mut c = CycleMessages::default();
                c.set_header(Header {
                    seq,
                    publish_t_ns: monotonic_ns(),
                    ..Header::default()
                });
                p.publish_cycle(&c).unwrap();
            }
            // Keep the publisher alive until the subscriber is done.
            std::thread::sleep(Duration::from_millis(300));
        });
        let mut last = 0;
        let mut watched_waits = 0;
        ALLOCATIONS.store(0, Ordering::Relaxed);
        while last < N {
            // The first samples connect the subscriber and teach the predictor: setup.
            let watch = last >= 50;
            WATCH.with(|w| w.set(watch));
            let update = sub.wait().unwrap();
            WATCH.with(|w| w.set(false));
            watched_waits += u64::from(watch);
            match update {
                Update::Fresh(v) => last = v.header.seq,
                // The publisher thread may take a while to start on a loaded machine.
                Update::Stale { .. } if last == 0 => {}
                other => panic!("{wait}: {other:?} after seq {last}"),
            }
        }
        publisher.join().unwrap();
        assert!(watched_waits > 100, "{wait}: {watched_waits}");
        if wait == WaitStrategy::Predictive {
            assert!(sub.prediction().is_some(), "the prediction was in use");
        }
        assert_eq!(
            ALLOCATIONS.load(Ordering::Relaxed),
            0,
            "{wait}: allocations in {watched_waits} waits"
        );
        assert_eq!(sub.stats().seq_gaps_total, 0, "{wait}");
    }
}
