//! End-to-end latency harness.
//!
//! Runs the UDP board emulator (`dvrk-sidecar sim`), `dvrk-sidecar serve` reading it at 1500 Hz,
//! and N subscriber processes (N = 1, 4, 16), each measuring the one-way latency from a
//! sample's time (host CLOCK_MONOTONIC when the board read completed, `header.sample_t_ns`) to
//! its receipt, for 10 s. In the same run, for comparison, the same state (the compensated tip
//! pose) goes the way the dVRK's existing non-ROS path sends it: a sawSocketStreamer-style JSON
//! datagram over UDP loopback to N subscriber processes that parse it. The JSON streamer runs
//! the same read + compensate + FK pipeline against the same emulator; its timestamp is taken at
//! the same point, so both paths are measured from the same instant to the consumer's hands.
//!
//! ```text
//! cargo build --release -p dvrk-sidecar && cargo bench --bench latency
//! cargo bench --bench latency -- --seconds 3 --subscribers 1,4   # shorter
//! ```
//! Prints a markdown table for benches/README.md.

use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{NOMINAL_PERIOD, PoseV1, ServiceNames, Subscription, Topic, Update};
use dvrk_sidecar::config::SidecarConfig;
use dvrk_sidecar::cycle::{self, ReadOutcome};
use dvrk_sidecar::rt;
use dvrk_sidecar::serve::SampleSource;

type Res<T> = Result<T, Box<dyn std::error::Error>>;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn main() -> Res<()> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    match args.first().map(String::as_str) {
        Some("--sub-shm") => sub_shm(&args[1], args[2].parse()?),
        Some("--sub-json") => sub_json(args[1].parse()?, args[2].parse()?),
        Some("--json-streamer") => json_streamer(Path::new(&args[1]), &args[2], args[3].parse()?),
        _ => orchestrate(&args),
    }
}

// ---------------------------------------------------------------------------------------------
// Subscribers (each its own process): record latencies, print one JSON line of stats at the end.

/// Latency statistics in ns over all samples.
fn stats(mut v: Vec<u64>) -> serde_json::Value {
    v.sort_unstable();
    let q = |p: f64| {
        v.get(((p * v.len() as f64) as usize).min(v.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0)
    };
    serde_json::json!({ "n": v.len(), "p50": q(0.5), "p99": q(0.99), "p999": q(0.999),
                        "max": v.last().copied().unwrap_or(0), "all": v })
}

fn sub_shm(prefix: &str, seconds: f64) -> Res<()> {
    let node = dvrk_ipc::create_node::<Service>("latency-sub", None)?;
    let names = ServiceNames::new(prefix)?;
    let mut sub = Subscription::<PoseV1, Service>::new(
        &node,
        &names,
        Topic::CompensatedMeasuredCp,
        NOMINAL_PERIOD,
    )?;
    let mut lat = Vec::with_capacity((seconds * 2000.0) as usize);
    let mut start = None;
    loop {
        let update = sub.wait_with(|m| {
            let now = rt::monotonic_ns();
            start.get_or_insert(now);
            lat.push(now.saturating_sub(m.header.sample_t_ns));
        })?;
        if let Some(s) = start
            && rt::monotonic_ns() - s > (seconds * 1e9) as u64
        {
            break;
        }
        if matches!(update, Update::Terminated) && start.is_some() {
            break;
        }
    }
    println!("{}", stats(lat));
    Ok(())
}

fn sub_json(port: u16, seconds: f64) -> Res<()> {
    let sock = UdpSocket::bind(("127.0.0.1", port))?;
    sock.set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut buf = [0u8; 2048];
    let mut lat = Vec::with_capacity((seconds * 2000.0) as usize);
    let mut start = None;
    let mut idle = 0;
    loop {
        match sock.recv(&mut buf) {
            Ok(n) => {
                idle = 0;
                let now = rt::monotonic_ns();
                start.get_or_insert(now);
                // A consumer of sawSocketStreamer parses the JSON to get at the values.
                let v: serde_json::Value = serde_json::from_slice(&buf[..n])?;
                let ts = v["measured_cp"]["Timestamp"]
                    .as_f64()
                    .ok_or("datagram without Timestamp")?;
                lat.push(now.saturating_sub((ts * 1e9) as u64));
            }
            Err(_) => {
                idle += 1;
                if start.is_some() && idle > 5 {
                    break;
                }
            }
        }
        if let Some(s) = start
            && rt::monotonic_ns() - s > (seconds * 1e9) as u64
        {
            break;
        }
    }
    println!("{}", stats(lat));
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The JSON streamer: same reader, model and kinematics as serve, then JSON over UDP.

fn json_streamer(cfg_path: &Path, targets: &str, seconds: f64) -> Res<()> {
    let cfg = SidecarConfig::load(cfg_path)?;
    let dvrk_sidecar::config::Source::Udp(addr) = cfg.source else {
        return Err("the JSON streamer reads the UDP emulator".into());
    };
    let link = dvrk_io::port::UdpLink::connect(addr)?;
    let port = dvrk_io::port::UdpPort::new(link);
    let mut reader = dvrk_io::reader::ArmReader::new(port, cfg.io.clone(), cfg.access);
    let targets: Vec<String> = targets
        .split(',')
        .map(|p| format!("127.0.0.1:{p}"))
        .collect();
    let sock = UdpSocket::bind("127.0.0.1:0")?;
    let mut sample = dvrk_io::ArmSample::default();
    let period = 666_667u64;
    let t0 = rt::monotonic_ns();
    let mut deadline = t0;
    while rt::monotonic_ns() - t0 < (seconds * 1e9) as u64 {
        rt::sleep_until_ns(deadline);
        deadline += period;
        let t_start = rt::monotonic_ns();
        let outcome = SampleSource::read(&mut reader, t_start, &mut sample);
        let t_sample = rt::monotonic_ns();
        let r = cycle::compute(&cfg.compliance, &cfg.kinematics, &sample, outcome);
        let t = r.compensated_pose.translation.vector;
        let m = r.compensated_pose.rotation.to_rotation_matrix();
        let m = m.matrix();
        // sawSocketStreamer's prmPositionCartesianGet serialisation (reference section 2.3),
        // with the timestamp in seconds of the host monotonic clock.
        let json = serde_json::json!({ "measured_cp": {
            "AutomaticTimestamp": false,
            "MovingFrame": "PSM1",
            "Position": {
                "Rotation": [[m[(0,0)], m[(0,1)], m[(0,2)]], [m[(1,0)], m[(1,1)], m[(1,2)]], [m[(2,0)], m[(2,1)], m[(2,2)]]],
                "Translation": [t.x, t.y, t.z],
            },
            "ReferenceFrame": "PSM1_base",
            "Timestamp": t_sample as f64 * 1e-9,
            "Valid": outcome == ReadOutcome::Ok,
        }});
        let bytes = serde_json::to_vec(&json)?;
        for target in &targets {
            let _ = sock.send_to(&bytes, target);
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The orchestrator.

/// A child process stopped with SIGTERM (so iceoryx2 nodes are removed cleanly), then killed if
/// it has not exited within 5 s.
struct Killer(Child);
impl Drop for Killer {
    fn drop(&mut self) {
        // SAFETY: kill(2) on our own child.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        for _ in 0..500 {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .unwrap_or(0)
}

fn collect(children: Vec<Child>) -> Res<Vec<u64>> {
    let mut all = Vec::new();
    for mut c in children {
        let out = c.stdout.take().ok_or("no stdout")?;
        let line = BufReader::new(out)
            .lines()
            .next()
            .ok_or("subscriber printed nothing")??;
        let v: serde_json::Value = serde_json::from_str(&line)?;
        all.extend(
            v["all"]
                .as_array()
                .ok_or("no samples")?
                .iter()
                .filter_map(|x| x.as_u64()),
        );
        c.wait()?;
    }
    all.sort_unstable();
    Ok(all)
}

fn q(v: &[u64], p: f64) -> f64 {
    v.get(((p * v.len() as f64) as usize).min(v.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0) as f64
        / 1e3
}

fn orchestrate(args: &[String]) -> Res<()> {
    let mut seconds = 10.0;
    let mut counts = vec![1usize, 4, 16];
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--seconds" => seconds = it.next().ok_or("--seconds N")?.parse()?,
            "--subscribers" => {
                counts = it
                    .next()
                    .ok_or("--subscribers 1,4")?
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()?
            }
            _ => {}
        }
    }
    let me = std::env::current_exe()?;
    let bin = me
        .parent()
        .and_then(Path::parent)
        .ok_or("exe dir")?
        .join("dvrk-sidecar");
    if !bin.exists() {
        return Err(format!(
            "{} not found: run `cargo build --release -p dvrk-sidecar` first",
            bin.display()
        )
        .into());
    }
    let c = repo().join("config");
    let emu_port = free_port();
    let _emu = Killer(
        Command::new(&bin)
            .args([
                "sim",
                "--listen",
                &format!("127.0.0.1:{emu_port}"),
                "--scenario",
            ])
            .arg(c.join("sim/divot-push.toml"))
            .arg("--io")
            .arg(c.join("io/psm-classic.toml"))
            .env("RUST_LOG", "warn")
            .spawn()?,
    );
    std::thread::sleep(Duration::from_millis(300));
    let dir = std::env::temp_dir().join(format!("dvrk-latency-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_owned())
        })
        .unwrap_or_default();
    println!(
        "# latency, {} s per case, 1500 Hz, {} CPUs ({cpu})\n",
        seconds,
        std::thread::available_parallelism()?.get()
    );
    println!("| subscribers | path | samples | p50 µs | p99 µs | p99.9 µs | max µs |");
    println!("|---|---|---|---|---|---|---|");
    let mut ratios = Vec::new();
    for &n in &counts {
        let prefix = format!("latency/p{}/n{n}", std::process::id());
        let cfg = dir.join(format!("sidecar-{n}.toml"));
        std::fs::write(
            &cfg,
            format!(
                "source = \"udp:127.0.0.1:{emu_port}\"\naccess = \"exclusive\"\nio = \"{}\"\narm = \"classic\"\n\
                 instrument = \"LARGE_NEEDLE_DRIVER_400006\"\ncompliance = \"{}\"\nrate = 1500\nprefix = \"{prefix}\"\n",
                c.join("io/psm-classic.toml").display(),
                c.join("compliance/paper-psm.toml").display()
            ),
        )?;
        // Shared memory: serve + n subscriber processes.
        let serve = Killer(
            Command::new(&bin)
                .args(["serve", "--config"])
                .arg(&cfg)
                .env("RUST_LOG", "warn")
                .spawn()?,
        );
        let subs: Vec<Child> = (0..n)
            .map(|_| {
                Command::new(&me)
                    .args(["--sub-shm", &prefix, &seconds.to_string()])
                    .stdout(Stdio::piped())
                    .spawn()
            })
            .collect::<Result<_, _>>()?;
        let shm = collect(subs)?;
        drop(serve);
        // JSON over UDP: the streamer + n subscriber processes.
        let ports: Vec<u16> = (0..n).map(|_| free_port()).collect();
        let subs: Vec<Child> = ports
            .iter()
            .map(|p| {
                Command::new(&me)
                    .args(["--sub-json", &p.to_string(), &seconds.to_string()])
                    .stdout(Stdio::piped())
                    .spawn()
            })
            .collect::<Result<_, _>>()?;
        std::thread::sleep(Duration::from_millis(200));
        let targets = ports
            .iter()
            .map(u16::to_string)
            .collect::<Vec<_>>()
            .join(",");
        let streamer = Killer(
            Command::new(&me)
                .args(["--json-streamer"])
                .arg(&cfg)
                .args([&targets, &(seconds + 1.0).to_string()])
                .spawn()?,
        );
        let json = collect(subs)?;
        drop(streamer);
        for (name, v) in [("iceoryx2 shm", &shm), ("JSON/UDP", &json)] {
            println!(
                "| {n} | {name} | {} | {:.1} | {:.1} | {:.1} | {:.1} |",
                v.len(),
                q(v, 0.5),
                q(v, 0.99),
                q(v, 0.999),
                q(v, 1.0)
            );
        }
        ratios.push((
            n,
            q(&json, 0.5) / q(&shm, 0.5),
            q(&json, 0.99) / q(&shm, 0.99),
        ));
    }
    println!("\n| subscribers | JSON/shm p50 | JSON/shm p99 |\n|---|---|---|");
    for (n, r50, r99) in ratios {
        println!("| {n} | {r50:.2}x | {r99:.2}x |");
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
