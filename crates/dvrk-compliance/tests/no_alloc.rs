//! The per-sample functions allocate nothing: a counting allocator watches this thread while
//! `correct` and `forward` run. (One test in this binary, so no other test allocates meanwhile.)

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use dvrk_compliance::{
    ArmKind, Compensator, ComplianceConfig, DynamicsParams, ModelKind, PsmKinematics, instrument,
    instruments,
};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static WATCHING: Cell<bool> = const { Cell::new(false) };
}

fn note() {
    if WATCHING.with(Cell::get) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards every call to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn count<R>(f: impl FnOnce() -> R) -> (R, usize) {
    ALLOCATIONS.store(0, Ordering::Relaxed);
    WATCHING.with(|w| w.set(true));
    let r = f();
    WATCHING.with(|w| w.set(false));
    (r, ALLOCATIONS.load(Ordering::Relaxed))
}

#[test]
fn correct_and_forward_do_not_allocate() {
    let text = include_str!("../../../config/compliance/paper-psm.toml");
    let paper = common::config(text).unwrap();
    let mut params = paper.to_params();
    params.model = ModelKind::Continuous;
    params.joint[0].torque_offset.position_rad =
        (0..37).map(|k| -1.6 + 0.09 * f64::from(k)).collect();
    params.joint[0].torque_offset.effort_nm = vec![0.1; 37];
    let continuous = ComplianceConfig::from_params(params.clone()).unwrap();
    for j in &mut params.joint {
        j.dynamics = Some(DynamicsParams {
            inertia_kg_m2: [0.05, 0.5],
            viscous_nm_s_per_rad: 0.2,
            coulomb_nm: 0.03,
            stick_velocity_rad_per_s: 0.002,
            residual_std_nm: 0.005,
            gate_sigmas: 4.0,
            max_acceleration_rad_per_s2: None,
            distal_gravity: None,
        });
    }
    let dynamic = ComplianceConfig::from_params(params).unwrap();
    let mut compensator = Compensator::new();
    let mut fast = Compensator::new();
    let kinematics: Vec<PsmKinematics> = instruments()
        .iter()
        .map(|i| PsmKinematics::new(ArmKind::Classic, i))
        .collect();

    // The counter itself works: a Vec allocates.
    let (_, n) = count(|| vec![1u8; 16]);
    assert!(n >= 1);

    let (sum, n) = count(|| {
        let mut sum = 0.0;
        for k in 0..1000 {
            let x = f64::from(k) * 1e-3;
            let q = [x - 0.5, 0.3 - x, 0.05 + 0.2 * x];
            let e = [2.0 * x - 1.0, 0.5 - x, 0.0];
            for config in [&paper, &continuous] {
                let c = config.correct(&q, &e);
                sum += c.delta_rad[0] + c.delta_rad[1];
            }
            let c = compensator.correct(&dynamic, x, &q, &e);
            sum += c.delta_rad[0] + c.tau_margin_nm[1];
            // At 6 kHz the estimator's windows hold the most samples (their time, not count).
            let c = fast.correct(&dynamic, f64::from(k) / 6000.0, &q, &e);
            sum += c.delta_rad[1];
            for fk in &kinematics {
                let t = fk.forward(&[q[0], q[1], q[2], x, -x, 0.5 * x]);
                sum += t.translation.z;
                sum += fk
                    .forward_base(&[q[0], q[1], q[2], x, -x, 0.5 * x])
                    .translation
                    .x;
            }
        }
        sum
    });
    assert!(sum.is_finite());
    assert_eq!(n, 0, "correct/forward allocated {n} times");
    // Building a catalog lookup does not allocate either.
    let (found, n) = count(|| instrument("LARGE_NEEDLE_DRIVER:400006").is_some());
    assert!(found && n == 0);
}
