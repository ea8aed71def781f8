//! Several-arm harness (issue 21): what a second arm costs the service.
//!
//! The board emulator serves two Classic PSMs on one UDP port (`dvrk-sidecar sim --arms
//! PSM1,PSM2`, boards 6-9). `serve` reads it at 1500 Hz, in rounds that alternate two cases so
//! that the shared machine's load drifts hit both alike:
//! - `one`: a single-arm configuration (PSM1, boards 6-7);
//! - `two`: one configuration with both arms (`[[arm]]` PSM1 on 6-7, PSM2 on 8-9).
//!
//! Both with the service's defaults: in shared mode a quadlet window of 4 per arm (4, 8).
//!
//! Per case it reads `serve`'s own once-a-second summary lines (skipping the first two
//! seconds): cycles per second and missed reads per arm, the per-arm cycle p99 and, for two
//! arms, the p99 of the whole cycle (every arm's read, correction and publish). The goal: two
//! arms at 1500 Hz each with no more missed reads than one, whole-cycle p99 at most 1.5x one
//! arm's.
//!
//! ```text
//! cargo build --release -p dvrk-sidecar && cargo bench --bench arms
//! cargo bench --bench arms -- --seconds 10 --rounds 3 --access exclusive
//! ```
//! Prints markdown rows for benches/README.md.

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

type Res<T> = Result<T, Box<dyn std::error::Error>>;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn bin() -> Res<PathBuf> {
    let b = repo().join("target/release/dvrk-sidecar");
    if !b.exists() {
        return Err(format!(
            "{} is missing: run `cargo build --release -p dvrk-sidecar` first",
            b.display()
        )
        .into());
    }
    Ok(b)
}

fn free_port() -> Res<u16> {
    Ok(UdpSocket::bind("127.0.0.1:0")?.local_addr()?.port())
}

fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_owned))
        .unwrap_or_else(|| "?".into())
}

/// The value of `key=` in a log line (tracing's key=value format), without quotes.
fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let pat = format!(" {key}=");
    let start = text.find(&pat)? + pat.len();
    Some(text[start..].split_whitespace().next()?.trim_matches('"'))
}

fn stop(c: Child) -> Res<String> {
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
    let out = c.wait_with_output()?;
    Ok(String::from_utf8_lossy(&out.stderr).into_owned())
}

fn arm_table(name: &str, boards: [u8; 2], c: &Path) -> String {
    format!(
        "[[arm]]\nname = \"{name}\"\nboards = [{}, {}]\nio = \"{}\"\nkind = \"classic\"\n\
         instrument = \"LARGE_NEEDLE_DRIVER_400006\"\ncompliance = \"{}\"\n",
        boards[0],
        boards[1],
        c.join("io/psm-classic.toml").display(),
        c.join("compliance/sim-psm.toml").display()
    )
}

/// What one run of `serve` logged, seconds 3.. of the run.
#[derive(Default, Debug)]
struct Run {
    /// Per arm: cycles per second, missed reads, cycle p99 (µs) of each second.
    rate: Vec<Vec<f64>>,
    missed: Vec<u64>,
    arm_p99_us: Vec<Vec<f64>>,
    /// Whole-cycle p99 per second (two arms; for one arm, the arm's).
    cycle_p99_us: Vec<f64>,
}

fn parse(log: &str, arms: &[String]) -> Run {
    let n = arms.len();
    let mut r = Run {
        rate: vec![Vec::new(); n],
        missed: vec![0; n],
        arm_p99_us: vec![Vec::new(); n],
        cycle_p99_us: Vec::new(),
    };
    let mut seen = vec![0usize; n];
    let mut whole_seen = 0usize;
    for line in log.lines() {
        if line.contains("summary of the whole cycle") {
            whole_seen += 1;
            if whole_seen > 2
                && let Some(v) = field(line, "cycle_p99_us").and_then(|v| v.parse().ok())
            {
                r.cycle_p99_us.push(v);
            }
            continue;
        }
        if !line.contains(" summary") {
            continue;
        }
        let Some(i) = field(line, "arm").and_then(|a| arms.iter().position(|x| x == a)) else {
            continue;
        };
        seen[i] += 1;
        if seen[i] <= 2 {
            continue;
        }
        if let Some(v) = field(line, "rate_hz").and_then(|v| v.parse().ok()) {
            r.rate[i].push(v);
        }
        if let Some(v) = field(line, "missed_reads").and_then(|v| v.parse::<u64>().ok()) {
            r.missed[i] += v;
        }
        if let Some(v) = field(line, "cycle_p99_us").and_then(|v| v.parse().ok()) {
            r.arm_p99_us[i].push(v);
            if n == 1 {
                r.cycle_p99_us.push(v);
            }
        }
    }
    r
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run_case(bin: &Path, port: u16, arms: usize, access: &str, seconds: f64) -> Res<Run> {
    let c = repo().join("config");
    let dir = std::env::temp_dir().join(format!("dvrk-bench-arms-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let names: Vec<String> = ["PSM1", "PSM2"][..arms]
        .iter()
        .map(|a| format!("bench/arms{}/{a}", std::process::id()))
        .collect();
    let mut text =
        format!("source = \"udp:127.0.0.1:{port}\"\naccess = \"{access}\"\nrate = 1500\n\n");
    for (i, name) in names.iter().enumerate() {
        text.push_str(&arm_table(name, [6 + 2 * i as u8, 7 + 2 * i as u8], &c));
    }
    let cfg = dir.join(format!("arms{arms}.toml"));
    std::fs::write(&cfg, text)?;
    let serve = Command::new(bin)
        .args(["serve", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()?;
    std::thread::sleep(Duration::from_secs_f64(seconds + 2.5));
    let log = stop(serve)?;
    let r = parse(&log, &names);
    if r.cycle_p99_us.is_empty() {
        return Err(format!("no summary from serve ({arms} arm(s)): {log}").into());
    }
    Ok(r)
}

fn main() -> Res<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let opt = |k: &str| {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1).cloned())
    };
    let seconds: f64 = opt("--seconds").map_or(Ok(8.0), |s| s.parse())?;
    let rounds: usize = opt("--rounds").map_or(Ok(2), |s| s.parse())?;
    let access = opt("--access").unwrap_or_else(|| "shared".into());
    let bin = bin()?;
    let port = free_port()?;
    let c = repo().join("config");
    let mut emu = Command::new(&bin)
        .args(["sim", "--arms", "PSM1,PSM2", "--listen"])
        .arg(format!("127.0.0.1:{port}"))
        .arg("--scenario")
        .arg(c.join("sim/free-motion.toml"))
        .arg("--io")
        .arg(c.join("io/psm-classic.toml"))
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    std::thread::sleep(Duration::from_millis(500));
    let load_before = loadavg();
    let mut one = Vec::new();
    let mut two = Vec::new();
    for _ in 0..rounds {
        one.push(run_case(&bin, port, 1, &access, seconds)?);
        two.push(run_case(&bin, port, 2, &access, seconds)?);
    }
    let _ = emu.kill();
    let _ = emu.wait();
    let cat = |runs: &[Run], f: &dyn Fn(&Run) -> Vec<f64>| -> Vec<f64> {
        runs.iter().flat_map(f).collect()
    };
    let p99_one = median(&cat(&one, &|r| r.cycle_p99_us.clone()));
    let p99_two = median(&cat(&two, &|r| r.cycle_p99_us.clone()));
    let rate_one = median(&cat(&one, &|r| r.rate[0].clone()));
    let missed_one: u64 = one.iter().map(|r| r.missed[0]).sum();
    println!(
        "arms: {rounds} rounds x {seconds} s per case, access {access}, load {load_before} -> {}",
        loadavg()
    );
    println!(
        "| case | arm | rate (Hz, median s) | missed reads | arm cycle p99 (µs, median s) | whole cycle p99 (µs) |"
    );
    println!("|---|---|---|---|---|---|");
    println!(
        "| one arm | PSM1 | {rate_one:.0} | {missed_one} | {:.1} | {p99_one:.1} |",
        median(&cat(&one, &|r| r.arm_p99_us[0].clone()))
    );
    for (i, arm) in ["PSM1", "PSM2"].iter().enumerate() {
        let missed: u64 = two.iter().map(|r| r.missed[i]).sum();
        println!(
            "| two arms | {arm} | {:.0} | {missed} | {:.1} | {} |",
            median(&cat(&two, &|r| r.rate[i].clone())),
            median(&cat(&two, &|r| r.arm_p99_us[i].clone())),
            if i == 0 {
                format!("{p99_two:.1}")
            } else {
                String::new()
            }
        );
    }
    println!(
        "whole-cycle p99, two arms / one arm: {:.2}x (goal <= 1.5x)",
        p99_two / p99_one
    );
    Ok(())
}
