//! What `ArmPublisher::publish_cycle` allocates: a counting global allocator watches the calling
//! thread while cycles are published to a connected subscriber and listener.
//!
//! Our code and `Notifier::notify` allocate nothing. iceoryx2 0.10 itself allocates one small
//! reference-counted handle per loaned sample (`SampleMutUninit::new` -> `ChunkMutSharedState::new`
//! -> `Rc::new`, freed again by `send`), on every publishing path of its public API (`loan`,
//! `loan_uninit`, `send_copy`). So a cycle makes exactly one short-lived allocation per topic; the
//! test pins that number so any further allocation, ours or upstream's, fails it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, CycleMessages, Header, PoseV2, Subscription, Topic, Update, create_node,
};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    static WATCH: Cell<bool> = const { Cell::new(false) };
}

fn note() {
    // `try_with`: the allocator may run while thread-locals are being torn down.
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

fn watched<R>(f: impl FnOnce() -> R) -> R {
    WATCH.with(|w| w.set(true));
    let r = f();
    WATCH.with(|w| w.set(false));
    r
}

#[test]
fn publish_cycle_allocates_only_iceoryx2s_per_sample_handle() {
    let d = Domain::new("no_alloc");
    let node = create_node::<ipc::Service>("no_alloc", Some(&d.config)).unwrap();
    let mut sub = Subscription::<PoseV2>::new(
        &node,
        &d.names,
        Topic::CompensatedLocalMeasuredCp,
        Duration::from_millis(20),
    )
    .unwrap();
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    let mut cycle = CycleMessages::default();

    // The first send connects the subscriber (setup work, may allocate).
    publisher.publish_cycle(&cycle).unwrap();
    assert!(matches!(sub.wait().unwrap(), Update::Fresh(_)));

    // The check must be able to fail: the counter sees allocations on this thread.
    watched(|| drop(std::hint::black_box(vec![1u8; 64])));
    assert_eq!(ALLOCATIONS.swap(0, Ordering::Relaxed), 1);

    const FIRST: u64 = 2;
    const LAST: u64 = 2000;
    for seq in FIRST..=LAST {
        cycle.set_header(Header {
            seq,
            ..Header::default()
        });
        watched(|| publisher.publish_cycle(&cycle)).unwrap();
        if seq % 100 == 0 {
            // Drain now and then, so both the normal and the overflowing buffer are exercised.
            assert!(matches!(sub.wait().unwrap(), Update::Fresh(_)));
        }
    }
    let cycles = LAST - FIRST + 1;
    let per_sample_handles = cycles * Topic::ALL.len() as u64;
    assert_eq!(
        ALLOCATIONS.load(Ordering::Relaxed),
        per_sample_handles,
        "publish_cycle allocated more than iceoryx2's one handle per loaned sample"
    );
    assert_eq!(sub.latest().map(|p| p.header.seq), Some(2000));
}
