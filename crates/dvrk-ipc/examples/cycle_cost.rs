//! Per-cycle cost of `ArmPublisher::publish_cycle` (five loans + writes + sends, one notify),
//! with 0, 1, 4 and 16 in-process subscriptions to every topic's cycle event.
//!
//! ```text
//! cargo run --release -p dvrk-ipc --example cycle_cost -- [cycles per case, default 100000]
//!     [drain every N cycles, default 1]
//! ```
//! Each cycle is timed on its own with `Instant`; subscriptions drain their event and samples
//! every N cycles (1 = subscribers that keep up, as in production), outside the timed region. Runs in its own iceoryx2 domain under /tmp/iox2t/.

use std::time::{Duration, Instant};

use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, CompensationStatusV2, JointStateV1, PoseV1, ServiceNames, Subscription, Topic,
    create_node, domain_config,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cycles: usize = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 100_000,
    };
    let drain_every: usize = match std::env::args().nth(2) {
        Some(s) => s.parse::<usize>()?.max(1),
        None => 1,
    };
    let domain = format!("cc{}_", std::process::id());
    let config = domain_config(&domain, Some("/tmp/iox2t/"))?;
    println!("{cycles} cycles per case, subscribers drain every {drain_every} cycle(s)");
    println!("subscribers | mean ns | p50 ns | p99 ns | p99.9 ns | max ns");
    for n_subs in [0usize, 1, 4, 16] {
        let node = create_node::<ipc::Service>("cycle_cost", Some(&config))?;
        let names = ServiceNames::new(&format!("bench/subs{n_subs}"))?;
        let mut subs = (0..n_subs)
            .map(|_| {
                Subscription::<PoseV1>::new(
                    &node,
                    &names,
                    Topic::CompensatedMeasuredCp,
                    Duration::from_millis(2),
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        let publisher = ArmPublisher::create(&node, &names)?;
        let mut js = JointStateV1::default();
        let mut cp = PoseV1::default();
        let mut st = CompensationStatusV2::default();
        let mut samples = Vec::with_capacity(cycles);
        for i in 0..(cycles + 1000) {
            let seq = i as u64 + 1;
            js.header.seq = seq;
            cp.header.seq = seq;
            st.header.seq = seq;
            let t0 = Instant::now();
            publisher.publish_cycle(&js, &cp, &js, &cp, &st)?;
            let dt = t0.elapsed();
            if i >= 1000 {
                samples.push(dt.as_nanos() as u64);
            }
            if i % drain_every == 0 {
                for s in &mut subs {
                    s.listener().try_wait(|_| {})?;
                    s.try_latest()?;
                }
            }
        }
        samples.sort_unstable();
        let q = |p: f64| samples[((samples.len() - 1) as f64 * p) as usize];
        let mean = samples.iter().sum::<u64>() / samples.len() as u64;
        println!(
            "{n_subs:>11} | {mean:>7} | {:>6} | {:>6} | {:>8} | {:>6}",
            q(0.5),
            q(0.99),
            q(0.999),
            samples[samples.len() - 1]
        );
    }
    // Remove this run's shared-memory files and discovery entries.
    for dir in [
        "/dev/shm",
        "/tmp/iox2t",
        "/tmp/iox2t/services",
        "/tmp/iox2t/nodes",
    ] {
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                let path = e.path();
                if e.file_name().to_string_lossy().starts_with(&domain) {
                    let _ = std::fs::remove_file(&path);
                } else if dir == "/tmp/iox2t/nodes" && path.is_dir() {
                    if let Ok(inner) = std::fs::read_dir(&path) {
                        for f in inner.flatten() {
                            if f.file_name().to_string_lossy().starts_with(&domain) {
                                let _ = std::fs::remove_file(f.path());
                            }
                        }
                    }
                    let _ = std::fs::remove_dir(&path);
                }
            }
        }
    }
    Ok(())
}
