//! Coexistence harness (issue 13, item 4): what the sidecar costs the console.
//!
//! The console stand-in (`dvrk-sidecar drive`, 1500 Hz) drives the UDP board emulator
//! (`dvrk-sidecar sim --listen 0.0.0.0:PORT`) four ways: alone, beside `serve` in shared mode
//! (quadlet reads of its own at 1500 Hz) with a window of 4 requests in flight (issue 22, the
//! default) and one at a time (`shared_requests_in_flight = 1`), beside `serve`
//! in tap mode
//! (`tap:lo:PORT`, rate follow). The cases run interleaved, round after round, so slow drifts of the shared
//! machine's load hit them alike; the load average is noted with every run.
//!
//! Per run: the stand-in's cycle time (p50, p99, max of read + write), its missed cycles
//! (overran the period or failed a read), the requests each client made (the emulator's
//! `requests_by_peer`), and in tap mode the sidecar's sample age relative to the console's read
//! (`sample_t_ns` and `publish_t_ns` of each published sample minus the time the stand-in's
//! read of the same board data completed; matched by board timestamps and encoder counts).
//!
//! ```text
//! cargo build --release -p dvrk-sidecar && cargo bench --bench coexist
//! cargo bench --bench coexist -- --seconds 5 --rounds 3 --protocol sequential-read-write
//! ```
//! Needs root (the tap's AF_PACKET capture). Prints markdown rows for benches/README.md.

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{JointStateV2, NOMINAL_PERIOD, ServiceNames, Subscription, Topic};

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

fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let pat = format!("{key}=");
    let start = text.find(&pat)? + pat.len();
    Some(text[start..].split_whitespace().next()?.trim_matches('"'))
}

fn stop(c: Child) -> Res<String> {
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
    let out = c.wait_with_output()?;
    Ok(String::from_utf8_lossy(&out.stderr).into_owned())
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Case {
    Alone,
    /// Shared mode with 4 requests in flight (`shared_requests_in_flight = 4`, the default).
    Shared,
    /// Shared mode one request at a time (`shared_requests_in_flight = 1`).
    SharedOneAtATime,
    Tap,
}

impl Case {
    fn name(self) -> &'static str {
        match self {
            Case::Alone => "alone",
            Case::Shared => "beside serve, shared (4 in flight)",
            Case::SharedOneAtATime => "beside serve, shared (1 in flight)",
            Case::Tap => "beside serve, tap",
        }
    }
}

fn serve_config(dir: &Path, case: Case, port: u16, prefix: &str) -> Res<PathBuf> {
    let c = repo().join("config");
    let (source, access, rate) = match case {
        Case::Shared | Case::SharedOneAtATime => {
            (format!("udp:127.0.0.1:{port}"), "shared", "1500")
        }
        _ => (format!("tap:lo:{port}"), "shared", "\"follow\""),
    };
    let window = match case {
        Case::Shared => "shared_requests_in_flight = 4\n",
        Case::SharedOneAtATime => "shared_requests_in_flight = 1\n",
        _ => "",
    };
    let text = format!(
        "source = \"{source}\"\naccess = \"{access}\"\nio = \"{}\"\narm = \"classic\"\n\
         instrument = \"LARGE_NEEDLE_DRIVER_400006\"\ncompliance = \"{}\"\nrate = {rate}\n\
         prefix = \"{prefix}\"\n{window}",
        c.join("io/psm-classic.toml").display(),
        c.join("compliance/paper-psm.toml").display(),
    );
    let p = dir.join(format!("{prefix}.toml").replace('/', "_"));
    std::fs::write(&p, text)?;
    Ok(p)
}

fn subscribe(prefix: String, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<Vec<JointStateV2>> {
    std::thread::spawn(move || {
        let Ok(node) = dvrk_ipc::create_node::<Service>("coexist", None) else {
            return Vec::new();
        };
        let Ok(names) = ServiceNames::new(&prefix) else {
            return Vec::new();
        };
        let mut got = Vec::new();
        let mut sub = None;
        while !stop.load(Ordering::Relaxed) {
            if sub.is_none() {
                sub = Subscription::<JointStateV2, Service>::new(
                    &node,
                    &names,
                    Topic::MeasuredJs,
                    NOMINAL_PERIOD,
                )
                .ok();
                if sub.is_none() {
                    std::thread::sleep(Duration::from_millis(20));
                    continue;
                }
            }
            if let Some(s) = sub.as_mut() {
                let _ = s.wait_with(|m| got.push(*m));
            }
        }
        got
    })
}

/// (ok, t_read_ns, board timestamps, counts of actuators 1-3) per cycle of the stand-in.
type Rec = (bool, u64, [u32; 2], [i32; 3]);

fn parse_record(text: &str) -> Vec<Rec> {
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<i64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
            (f.len() >= 9).then(|| {
                (
                    f[3] == 1,
                    f[2] as u64,
                    [f[4] as u32, f[5] as u32],
                    [f[6] as i32, f[7] as i32, f[8] as i32],
                )
            })
        })
        .collect()
}

fn quantiles(mut v: Vec<i64>) -> String {
    if v.is_empty() {
        return "n/a".into();
    }
    v.sort_unstable();
    let q = |p: f64| v[((p * v.len() as f64) as usize).min(v.len() - 1)] as f64 / 1e3;
    format!(
        "p50 {:.1} / p99 {:.1} / max {:.1}",
        q(0.5),
        q(0.99),
        *v.last().unwrap_or(&0) as f64 / 1e3
    )
}

struct Run {
    case: Case,
    load: String,
    drive: String,
    peers: String,
    sample_age: String,
    publish_age: String,
    published: String,
}

fn run_case(case: Case, protocol: &str, ethernet: &str, secs: f64, dir: &Path) -> Res<Run> {
    let b = bin()?;
    let port = free_port()?;
    let load = loadavg();
    let sim = Command::new(&b)
        .args([
            "sim",
            "--listen",
            &format!("0.0.0.0:{port}"),
            "--ethernet",
            ethernet,
        ])
        .arg("--scenario")
        .arg(repo().join("config/sim/free-motion.toml"))
        .arg("--io")
        .arg(repo().join("config/io/psm-classic.toml"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()?;
    for _ in 0..500 {
        if UdpSocket::bind(("0.0.0.0", port)).is_err() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let prefix = format!("coexist/p{}/port{port}", std::process::id());
    let stop_sub = Arc::new(AtomicBool::new(false));
    let (serve, sub) = if case == Case::Alone {
        (None, None)
    } else {
        let cfg = serve_config(dir, case, port, &prefix)?;
        let s = Command::new(&b)
            .args(["serve", "--config"])
            .arg(cfg)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()?;
        let h = subscribe(prefix.clone(), stop_sub.clone());
        std::thread::sleep(Duration::from_millis(800));
        (Some(s), Some(h))
    };
    let record = dir.join(format!("drive-{port}.csv"));
    let out = Command::new(&b)
        .args([
            "drive",
            "--boards",
            &format!("127.0.0.1:{port}"),
            "--protocol",
            protocol,
            "--rate",
            "1500",
            "--duration",
            &secs.to_string(),
            "--record",
        ])
        .arg(&record)
        .env("RUST_LOG", "warn")
        .output()?;
    let drive_out = String::from_utf8_lossy(&out.stdout).into_owned();
    std::thread::sleep(Duration::from_millis(200));
    stop_sub.store(true, Ordering::Relaxed);
    let published = match sub {
        Some(h) => h.join().unwrap_or_default(),
        None => Vec::new(),
    };
    if let Some(s) = serve {
        stop(s)?;
    }
    let sim_log = stop(sim)?;
    let drive_port = field(&drive_out, "local_port").unwrap_or("?").to_owned();
    let peers = field(&sim_log, "requests_by_peer")
        .unwrap_or("")
        .split(',')
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (addr, n) = p.rsplit_once('/').unwrap_or((p, "?"));
            if addr.ends_with(&format!(":{drive_port}")) {
                format!("console {n}")
            } else {
                format!("sidecar {n}")
            }
        })
        .collect::<Vec<_>>()
        .join(", ");
    let recs = parse_record(&std::fs::read_to_string(&record).unwrap_or_default());
    let (mut sample_age, mut publish_age) = (Vec::new(), Vec::new());
    let valid: Vec<&JointStateV2> = published.iter().filter(|m| m.header.valid == 1).collect();
    // Matches are looked for at most 200 reads (~130 ms) ahead of the last one: while the arm
    // stands still (e.g. its watchdog tripped during a stall of the stand-in) identical counts
    // and near-identical timestamps could otherwise match a read far ahead and hide the rest.
    if case == Case::Tap {
        let io = dvrk_sidecar::config::load_io(&repo().join("config/io/psm-classic.toml"))
            .map_err(|e| format!("{e:#}"))?;
        let mut next = 0;
        for m in &valid {
            let ts = m.header.board_timestamps();
            let counts: [i32; 3] =
                std::array::from_fn(|j| io.actuators()[j].position_to_counts(m.position[j]));
            if let Some(i) =
                (next..recs.len().min(next + 200)).find(|&i| recs[i].2 == ts && recs[i].3 == counts)
            {
                sample_age.push(m.header.sample_t_ns as i64 - recs[i].1 as i64);
                publish_age.push(m.header.publish_t_ns as i64 - recs[i].1 as i64);
                next = i + 1;
            }
        }
    }
    let field_of = |k: &str| field(&drive_out, k).unwrap_or("?").to_owned();
    Ok(Run {
        case,
        load,
        drive: format!(
            "{} | {} | {} | {} | {} / {}",
            field_of("cycles"),
            field_of("cycle_p50_us"),
            field_of("cycle_p99_us"),
            field_of("cycle_max_us"),
            field_of("missed"),
            field_of("late_starts"),
        ),
        peers,
        sample_age: quantiles(sample_age.clone()),
        publish_age: quantiles(publish_age),
        published: if case == Case::Alone {
            "-".into()
        } else if case == Case::Tap {
            format!("{} valid, {} matched", valid.len(), sample_age.len())
        } else {
            format!("{} valid", valid.len())
        },
    })
}

fn main() -> Res<()> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let get = |k: &str, d: &str| -> String {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1))
            .cloned()
            .unwrap_or_else(|| d.to_owned())
    };
    let secs: f64 = get("--seconds", "10").parse()?;
    let rounds: usize = get("--rounds", "3").parse()?;
    let protocol = get("--protocol", "sequential-read-broadcast-write");
    let ethernet = get("--ethernet", "ethernet-only");
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Err("the tap case needs root (AF_PACKET); run as root".into());
    }
    let dir = std::env::temp_dir().join(format!("dvrk-coexist-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    println!(
        "protocol {protocol}, emulator {ethernet}, 1500 Hz, {secs} s per run, {rounds} rounds\n"
    );
    println!(
        "| round | case | load | cycles | p50 µs | p99 µs | max µs | missed / late starts | requests | published | sample age µs | publish age µs |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for round in 1..=rounds {
        for case in [Case::Alone, Case::Shared, Case::SharedOneAtATime, Case::Tap] {
            let r = run_case(case, &protocol, &ethernet, secs, &dir)?;
            let (sa, pa) = if r.case == Case::Tap {
                (r.sample_age.as_str(), r.publish_age.as_str())
            } else {
                ("-", "-")
            };
            println!(
                "| {round} | {} | {} | {} | {} | {} | {sa} | {pa} |",
                r.case.name(),
                r.load,
                r.drive,
                r.peers,
                r.published
            );
        }
    }
    Ok(())
}
