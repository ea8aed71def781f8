//! Switching instruments at run time allocates nothing: resolving the console's tool type,
//! taking the coupling and building the kinematics, under a counting allocator. (One test in
//! this binary, so no other test allocates meanwhile.)

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use dvrk_compliance::{ArmKind, PsmKinematics, instrument_from_tool_type};

struct CountingAllocator;

static COUNT: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static ON: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: every call goes to the system allocator unchanged; only a counter is added.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ON.with(Cell::get) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

fn allocations<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let before = COUNT.load(Ordering::Relaxed);
    ON.with(|c| c.set(true));
    let out = f();
    ON.with(|c| c.set(false));
    (out, COUNT.load(Ordering::Relaxed) - before)
}

#[test]
fn switching_instruments_does_not_allocate() {
    // The counter works: a Vec allocates.
    let (_, n) = allocations(|| vec![0u8; 8]);
    assert!(n >= 1);

    let tool_types = [
        "LARGE_NEEDLE_DRIVER:400006[..]",
        "LARGE_NEEDLE_DRIVER:420006[12..]",
        "5MM_NEEDLE_DRIVER:400117[..]",
        "STAPLER_45:410298[..]",
        "MEGA_SUTURECUT_NEEDLE_DRIVER:420309[..6]",
        "CADIERE_FORCEPS_400049",
        // Refusals allocate nothing either.
        "",
        "ERROR",
        "LARGE_NEEDLE_DRIVER:420006",
        "BANANA:400000[..]",
        "NOT A TOOL",
    ];
    let (sum, n) = allocations(|| {
        let mut sum = 0.0;
        let mut refused = 0;
        for s in tool_types {
            match instrument_from_tool_type(s) {
                Ok(tool) => {
                    let coupling = tool.coupling().unwrap();
                    let fk = PsmKinematics::new(ArmKind::Si, tool);
                    sum +=
                        coupling[0][0] + fk.forward(&[0.1, 0.2, 0.12, 0.3, 0.2, 0.1]).translation.z;
                }
                Err(_) => refused += 1,
            }
        }
        assert_eq!(refused, 5);
        sum
    });
    assert!(sum.is_finite());
    assert_eq!(n, 0, "switching allocated {n} times");
}
