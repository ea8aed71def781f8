//! Cost of the simulator: one physics step of the simulated PSM, and one emulated reply in
//! process (request parsing, CRC check, register read from the physics, reply emission).
//!
//! Goals: physics step <= 1 µs, emulated quadlet reply <= 1 µs.
//! Run with `cargo bench --bench sim`; results go to benches/README.md.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use dvrk_io::wire::{ControlWord, EthRequest, RequestKind, RequestRepr};
use dvrk_sim::emulator::MAX_REPLY_BYTES;
use dvrk_sim::{Emulator, Environment};

const IDLE: &str = include_str!("../config/sim/idle.toml");
const DIVOT_PUSH: &str = include_str!("../config/sim/divot-push.toml");
const PSM_CLASSIC: &str = include_str!("../config/io/psm-classic.toml");

fn request(node: u8, addr: u16, kind: RequestKind) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let req = RequestRepr::host(node, 1, u64::from(addr), kind);
    let n = EthRequest::emit(&mut buf, ControlWord::new(true, 1), &req, &[]).expect("request fits");
    buf[..n].to_vec()
}

fn physics(c: &mut Criterion) {
    let mut g = c.benchmark_group("sim/physics_step");
    // A pushing controller against a divot: the PID, the shaft dead zone and the plate are all
    // active.
    let sc = dvrk_sidecar::formats::scenario_from_toml(DIVOT_PUSH).expect("scenario");
    let mut psm = sc.build_psm();
    let drv = sc.motion_driver();
    let mut t = 0.0;
    g.bench_function("divot_push", |b| {
        b.iter(|| {
            drv.apply(t, &mut psm);
            psm.step(black_box(1e-4));
            t += 1e-4;
        })
    });
    // The compliant surface runs the quasi-static Newton solve for the shaft.
    let sc = dvrk_sidecar::formats::scenario_from_toml(IDLE).expect("scenario");
    let mut psm = sc.build_psm();
    psm.set_environment(Environment::Surface {
        stiffness_n_per_m: 2000.0,
        gap_m: -0.002,
        tilt_rad: 0.3,
    });
    g.bench_function("surface", |b| b.iter(|| psm.step(black_box(1e-4))));
    g.finish();
}

fn emulator(c: &mut Criterion) {
    let io = dvrk_sidecar::formats::io_from_toml(PSM_CLASSIC).expect("io config");
    let sc = dvrk_sidecar::formats::scenario_from_toml(DIVOT_PUSH).expect("scenario");
    let mut emu = Emulator::new(&sc, &io).expect("emulator");
    emu.advance_to(0);
    emu.advance_to(1_000_000);
    let mut out = vec![0u8; MAX_REPLY_BYTES];
    let mut g = c.benchmark_group("sim/emulated_reply");
    let encoder = request(6, 0x15, RequestKind::QuadletRead);
    g.bench_function("quadlet_encoder_position", |b| {
        b.iter(|| black_box(emu.handle(black_box(&encoder), &mut out)))
    });
    let adc = request(6, 0x10, RequestKind::QuadletRead);
    g.bench_function("quadlet_adc", |b| {
        b.iter(|| black_box(emu.handle(black_box(&adc), &mut out)))
    });
    let block = request(6, 0, RequestKind::BlockRead { len: 128 });
    g.bench_function("block_feedback", |b| {
        b.iter(|| black_box(emu.handle(black_box(&block), &mut out)))
    });
    g.finish();
}

criterion_group!(benches, physics, emulator);
criterion_main!(benches);
