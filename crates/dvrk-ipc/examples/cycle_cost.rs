//! Per-cycle cost of `ArmPublisher::publish_cycle` (nine loans + writes + sends, one notify),
//! with 0, 1, 4 and 16 in-process subscriptions of each kind: `spin` (no listener on the cycle
//! event), `event` (a listener and the cycle's wake-up word, as an event or predictive
//! subscription has them: the listener held but never drained, so iceoryx2 sends it no
//! datagram; the word bumped once per cycle, no sleeper here) and `event_datagram` (the listener
//! drained every cycle, as a subscription sleeping on iceoryx2's datagrams drains it before it
//! sleeps: what every event and predictive subscriber cost before the wake-up word).
//!
//! ```text
//! cargo run --release -p dvrk-ipc --example cycle_cost -- [cycles per case, default 100000]
//!     [drain every N cycles, default 1]
//! ```
//! Each cycle is timed on its own with `Instant`; subscriptions drain their event and samples
//! every N cycles (1 = subscribers that keep up, as in production), outside the timed region.
//! Runs in its own iceoryx2 domain under /tmp/iox2t/.

use std::time::{Duration, Instant};

use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, CycleMessages, Header, PoseV2, ServiceNames, SubscribeOptions, Subscription,
    Topic, WaitStrategy, create_node, domain_config,
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
    println!("subscribers | kind | mean ns | p50 ns | p99 ns | p99.9 ns | max ns");
    let cases = [(0usize, WaitStrategy::Event, false)].into_iter().chain(
        [1usize, 4, 16].into_iter().flat_map(|n| {
            [
                (WaitStrategy::Spin, false),
                (WaitStrategy::Event, false),
                (WaitStrategy::Event, true),
            ]
            .into_iter()
            .map(move |(w, d)| (n, w, d))
        }),
    );
    for (n_subs, wait, datagram) in cases {
        let node = create_node::<ipc::Service>("cycle_cost", Some(&config))?;
        let names = ServiceNames::new(&format!("bench/subs{n_subs}/{wait}{datagram}"))?;
        let options = SubscribeOptions {
            period: Duration::from_micros(667),
            wait,
            deadline: None,
            ..SubscribeOptions::default()
        };
        let mut subs = (0..n_subs)
            .map(|_| {
                Subscription::<PoseV2>::with_options(
                    &node,
                    &names,
                    Topic::CompensatedMeasuredCp,
                    options,
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        let publisher = ArmPublisher::create(&node, &names)?;
        let mut cycle = CycleMessages::default();
        let mut samples = Vec::with_capacity(cycles);
        for i in 0..(cycles + 1000) {
            let seq = i as u64 + 1;
            cycle.set_header(Header {
                seq,
                ..Header::default()
            });
            let t0 = Instant::now();
            publisher.publish_cycle(&cycle)?;
            let dt = t0.elapsed();
            if i >= 1000 {
                samples.push(dt.as_nanos() as u64);
            }
            if i % drain_every == 0 {
                for s in &mut subs {
                    if let Some(l) = s.listener().filter(|_| datagram) {
                        l.try_wait(|_| {})?;
                    }
                    s.try_latest()?;
                }
            }
        }
        samples.sort_unstable();
        let q = |p: f64| samples[((samples.len() - 1) as f64 * p) as usize];
        let mean = samples.iter().sum::<u64>() / samples.len() as u64;
        let kind = match (n_subs, datagram) {
            (0, _) => "-",
            (_, true) => "event_datagram",
            _ => wait.name(),
        };
        println!(
            "{n_subs:>11} | {kind:>14} | {mean:>7} | {:>6} | {:>6} | {:>8} | {:>6}",
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
