//! Per-cycle cost of the compensation core: the paper's correction of joints 1-2, 6-DOF PSM
//! forward kinematics, and both together (what the sidecar does per sample).
//!
//! Goals on the 2-core target machine: correction <= 50 ns, FK <= 200 ns, both <= 250 ns.
//! Run with `cargo bench --bench compensation`; results go to benches/README.md.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use dvrk_compliance::{
    ArmKind, Compensator, ComplianceConfig, ModelKind, PsmKinematics, instrument,
};

const PAPER_PSM: &str = include_str!("../config/compliance/paper-psm.toml");
const SIM_PSM: &str = include_str!("../config/compliance/sim-psm.toml");
const SAMPLES: usize = 256;

/// Seeded inputs inside the Classic PSM's joint limits (xorshift64*, no extra dependency), so
/// every run sees the same mix of dead-band, active and clamped samples.
fn samples() -> Vec<([f64; 6], [f64; 3])> {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut unit = move || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut span = move |lo: f64, hi: f64| lo + (hi - lo) * unit();
    (0..SAMPLES)
        .map(|_| {
            let q = [
                span(-1.5, 1.5),
                span(-0.9, 0.9),
                span(0.0, 0.24),
                span(-4.5, 4.5),
                span(-1.3, 1.3),
                span(-1.3, 1.3),
            ];
            let effort = [span(-1.0, 1.0), span(-1.0, 1.0), span(-5.0, 5.0)];
            (q, effort)
        })
        .collect()
}

fn compensation(c: &mut Criterion) {
    let paper =
        dvrk_sidecar::formats::compliance_from_toml(PAPER_PSM).expect("paper-psm.toml loads");
    let mut params = paper.to_params();
    params.model = ModelKind::Continuous;
    let continuous = ComplianceConfig::from_params(params).expect("continuous variant loads");
    let tool = instrument("LARGE_NEEDLE_DRIVER_400006").expect("LND 400006 in the catalog");
    let fk = PsmKinematics::new(ArmKind::Classic, tool);
    let inputs = samples();

    let mut group = c.benchmark_group("compensation");
    let mut i = 0;
    group.bench_function("correct_j1_j2_paper", |b| {
        b.iter(|| {
            let (q, e) = &inputs[i % SAMPLES];
            i += 1;
            black_box(paper.correct(black_box(&[q[0], q[1], q[2]]), black_box(e)))
        })
    });
    group.bench_function("correct_j1_j2_continuous", |b| {
        b.iter(|| {
            let (q, e) = &inputs[i % SAMPLES];
            i += 1;
            black_box(continuous.correct(black_box(&[q[0], q[1], q[2]]), black_box(e)))
        })
    });
    // The internal-torque estimator in front of the correction (issue 10): the shipped
    // simulator file has [joint.dynamics] on both joints, so each call runs two 48-sample
    // least-squares filters.
    let dynamic = dvrk_sidecar::formats::compliance_from_toml(SIM_PSM).expect("sim-psm.toml loads");
    let mut compensator = Compensator::new();
    let mut t = 0.0;
    group.bench_function("compensator_j1_j2_dynamics", |b| {
        b.iter(|| {
            let (q, e) = &inputs[i % SAMPLES];
            i += 1;
            t += 1.0 / 1500.0;
            black_box(compensator.correct(
                &dynamic,
                black_box(t),
                black_box(&[q[0], q[1], q[2]]),
                black_box(e),
            ))
        })
    });
    // At a faster cycle the filter's window keeps its time (dynamics::WINDOW_TIME_S), so it
    // holds more samples: about 95 at 3 kHz, 190 at 6 kHz.
    for rate_hz in [3000.0, 6000.0] {
        let mut compensator = Compensator::new();
        let mut t = 0.0;
        let name = format!("compensator_j1_j2_dynamics_{}khz", rate_hz / 1000.0);
        group.bench_function(name, |b| {
            b.iter(|| {
                let (q, e) = &inputs[i % SAMPLES];
                i += 1;
                t += 1.0 / rate_hz;
                black_box(compensator.correct(
                    &dynamic,
                    black_box(t),
                    black_box(&[q[0], q[1], q[2]]),
                    black_box(e),
                ))
            })
        });
    }
    group.bench_function("fk_6dof", |b| {
        b.iter(|| {
            let (q, _) = &inputs[i % SAMPLES];
            i += 1;
            black_box(fk.forward(black_box(q)))
        })
    });
    group.bench_function("correct_then_fk", |b| {
        b.iter(|| {
            let (q, e) = &inputs[i % SAMPLES];
            i += 1;
            let c = paper.correct(black_box(&[q[0], q[1], q[2]]), black_box(e));
            let [q1, q2, q3] = c.position;
            black_box(fk.forward(&[q1, q2, q3, q[3], q[4], q[5]]))
        })
    });
    group.finish();
}

criterion_group!(benches, compensation);
criterion_main!(benches);
