//! One full cycle in-process, as `serve` runs it: advance the simulated PSM, read its boards
//! through the real protocol (in-process port, shared access mode: 16 quadlet round trips),
//! convert to SI, compensate, FK raw and compensated, publish the nine messages, notify.
//!
//! Publishing uses iceoryx2's `local::Service` so the benchmark measures our code and the
//! iceoryx2 send path, not inter-process wake-ups (benches/latency measures those).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use dvrk_ipc::iceoryx2::service::local;
use dvrk_ipc::{ArmPublisher, ServiceNames};
use dvrk_sidecar::config::SidecarConfig;
use dvrk_sidecar::serve::{Pipeline, SimSource};

fn bench_cycle(c: &mut Criterion) {
    let cfg_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sidecar.toml");
    let cfg = SidecarConfig::load(&cfg_path).expect("config/sidecar.toml loads");
    let node = dvrk_ipc::create_node::<local::Service>("bench-cycle", None).unwrap();
    let names = ServiceNames::new(&format!("bench/p{}/cycle", std::process::id())).unwrap();
    let mut group = c.benchmark_group("cycle");
    for access in [
        dvrk_io::reader::AccessMode::Shared,
        dvrk_io::reader::AccessMode::Exclusive,
    ] {
        let mut cfg_a = SidecarConfig::load(&cfg_path).unwrap();
        cfg_a.access = access;
        let names_a = ServiceNames::new(&format!("{}/{:?}", names.prefix(), access)).unwrap();
        let publisher = ArmPublisher::create(&node, &names_a).unwrap();
        let source = SimSource::new(&cfg_a).unwrap();
        let mut pipe = Pipeline::new(source, &cfg.compliance, &cfg.kinematics, publisher, 666_667);
        let mut t: u64 = 0;
        group.bench_function(format!("full_cycle_{access:?}").to_lowercase(), |b| {
            b.iter(|| {
                t += 666_667;
                black_box(pipe.cycle(black_box(t), || t));
                pipe.finish(t, t);
            })
        });
    }
    // The sidecar's own share of a cycle, without the simulated boards: compensate, FK of raw
    // and compensated joints, fill the nine messages, publish them and notify (no subscriber).
    let mut source = SimSource::new(&cfg).unwrap();
    let mut sample = dvrk_io::ArmSample::default();
    let outcome = dvrk_sidecar::serve::SampleSource::read(&mut source, 1_000_000, &mut sample);
    let names_c = ServiceNames::new(&format!("{}/compute", names.prefix())).unwrap();
    let publisher = ArmPublisher::create(&node, &names_c).unwrap();
    let mut seq = 0u64;
    group.bench_function("compute_and_publish", |b| {
        b.iter(|| {
            seq += 1;
            let r = dvrk_sidecar::cycle::compute(
                &cfg.compliance,
                &cfg.kinematics,
                black_box(&sample),
                outcome,
            );
            let t = dvrk_sidecar::cycle::CycleTiming {
                seq,
                ..Default::default()
            };
            let m = dvrk_sidecar::cycle::messages(&sample, &r, &t, &cfg.base_frame);
            black_box(publisher.publish_cycle(&m))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_cycle);
criterion_main!(benches);
