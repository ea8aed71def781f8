//! End-to-end latency harness.
//!
//! Runs the UDP board emulator (`dvrk-sidecar sim`), `dvrk-sidecar serve` reading it at 1500 Hz,
//! and N subscriber processes (N = 1, 4, 16) per path, each measuring the one-way latency from a
//! sample's time (host CLOCK_MONOTONIC when the board read completed, `header.sample_t_ns`) to
//! its receipt. The shared-memory paths are the wait strategies of `dvrk_ipc::Subscription`:
//! `event`, `predictive`, and `spin` (only while N is below the number of CPUs: a spinning
//! subscriber needs a core of its own), each sleeping on the cycle's futex wake-up word
//! (`dvrk_ipc::wake`); `event_datagram` and `predictive_datagram` are the same strategies
//! sleeping on iceoryx2's per-listener unix datagrams instead, as they did before the word, so
//! that both are measured in one run. In the same run, for comparison, the same state (the
//! compensated tip pose) goes the way the dVRK's existing non-ROS path sends it (`json_udp`): a
//! sawSocketStreamer-style JSON datagram over UDP loopback to N subscriber processes that parse
//! it. The JSON streamer runs the same read + compensate + FK pipeline against the same emulator;
//! its timestamp is taken at the same point, so every path is measured from the same instant to
//! the consumer's hands.
//!
//! In the same run, Python subscribers (`benches/latency/python_sub.py`, one process each, the
//! installed `dvrk_sidecar` package, `python3` or `--python PATH`): `python_native_<wait>` (the
//! compiled module's `Subscription::wait`, GIL released), `python_pure_<wait>` (the pure-Python
//! client) and `python_json_udp` (a Python lab program's sawSocketStreamer receiver: a UDP
//! socket and `json.loads`, fed by the same streamer as `json_udp`). The native Python path
//! times the newest sample of each wait (and counts gaps); the others every sample.
//!
//! ```text
//! cargo build --release -p dvrk-sidecar && cargo bench --bench latency
//! cargo bench --bench latency -- --seconds 5 --subscribers 1,4,16 --json
//! cargo bench --bench latency -- --seconds 2 --subscribers 1,4 --check-lost   # CI: exit 1 on loss
//! cargo bench --bench latency -- --topic measured_js   # another topic (default compensated/local/measured_cp)
//! cargo bench --bench latency -- --paths event,python_native_predictive --python ~/venv/bin/python3
//! ```
//! The shared-memory figures include the publisher's sends of the topics before the measured
//! one in the cycle's publishing order ([`Topic::ALL`]); `--topic` shows what that order costs.
//! Prints a markdown table (with the publisher's own share, `publish_t_ns - sample_t_ns`, and the
//! hand-off, receipt - `publish_t_ns`), or with `--json` one line per case:
//! `{"subscribers":N,"path":"event|predictive|spin|json_udp|python_...","samples":..,"p50_us":..,"p99_us":..,
//! "p999_us":..,"max_us":..,"lost":..,"cpu_percent":..}`, where `lost` counts sequence gaps and
//! `cpu_percent` is the mean CPU use of one subscriber process while it measured.

use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    CompensationStatusV4, JawStateV1, JointStateV2, Message, NOMINAL_PERIOD, PoseV2, ServiceNames,
    SubscribeOptions, Subscription, Topic, Update, WaitStrategy,
};
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
        Some("--sub-shm") => {
            let topic = Topic::from_suffix(&args[4]).ok_or("unknown topic")?;
            let (prefix, seconds) = (&args[1], args[2].parse()?);
            let (wait, datagram) = rust_shm_path(&args[3]).ok_or("unknown wait")?;
            if topic.carries::<PoseV2>() {
                sub_shm::<PoseV2>(prefix, seconds, wait, datagram, topic)
            } else if topic.carries::<JointStateV2>() {
                sub_shm::<JointStateV2>(prefix, seconds, wait, datagram, topic)
            } else if topic.carries::<JawStateV1>() {
                sub_shm::<JawStateV1>(prefix, seconds, wait, datagram, topic)
            } else {
                sub_shm::<CompensationStatusV4>(prefix, seconds, wait, datagram, topic)
            }
        }
        Some("--sub-json") => sub_json(args[1].parse()?),
        Some("--json-streamer") => json_streamer(Path::new(&args[1]), &args[2], args[3].parse()?),
        _ => orchestrate(&args),
    }
}

// ---------------------------------------------------------------------------------------------
// Subscribers (each its own process): record latencies, print one JSON line of stats at the end.

/// CPU time (user + system) of this process, ns.
fn cpu_ns() -> u64 {
    // SAFETY: getrusage fills the zeroed struct it is given.
    let ru = unsafe {
        let mut ru: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut ru);
        ru
    };
    let tv = |t: libc::timeval| t.tv_sec as u64 * 1_000_000_000 + t.tv_usec as u64 * 1_000;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// What one subscriber process measured: latencies (ns) of every sample, the publisher's share
/// of each (`publish_t_ns - sample_t_ns`), the sequence gaps and its CPU use.
fn report(
    lat: Vec<u64>,
    publisher: Vec<u64>,
    lost: u64,
    cpu_percent: f64,
    on_time: Option<(u64, u64)>,
) -> serde_json::Value {
    serde_json::json!({ "all": lat, "publisher": publisher, "lost": lost,
                        "cpu_percent": cpu_percent, "on_time": on_time })
}

/// Measures CPU use over the measuring window: from the first sample to the end.
struct CpuWindow {
    start: Option<(u64, u64)>,
}
impl CpuWindow {
    fn mark(&mut self, now: u64) {
        self.start.get_or_insert_with(|| (now, cpu_ns()));
    }
    fn elapsed_s(&self, now: u64) -> f64 {
        self.start.map_or(0.0, |(t, _)| (now - t) as f64 * 1e-9)
    }
    fn percent(&self, now: u64) -> f64 {
        match self.start {
            Some((t, c)) if now > t => 100.0 * (cpu_ns() - c) as f64 / (now - t) as f64,
            _ => 0.0,
        }
    }
}

fn sub_shm<T: Message>(
    prefix: &str,
    seconds: f64,
    wait: WaitStrategy,
    datagram: bool,
    topic: Topic,
) -> Res<()> {
    let node = dvrk_ipc::create_node::<Service>("latency-sub", None)?;
    let names = ServiceNames::new(prefix)?;
    let options = SubscribeOptions {
        period: NOMINAL_PERIOD,
        wait,
        deadline: None,
        ..SubscribeOptions::default()
    };
    let mut sub = Subscription::<T, Service>::with_options(&node, &names, topic, options)?;
    if datagram {
        sub.use_datagram_wake();
    }
    let capacity = (seconds * 2000.0) as usize;
    let mut lat = Vec::with_capacity(capacity);
    let mut publisher = Vec::with_capacity(capacity);
    let mut window = CpuWindow { start: None };
    let mut first_gaps = None;
    loop {
        let update = sub.wait_with(|m| {
            let now = rt::monotonic_ns();
            window.mark(now);
            let h = m.header();
            lat.push(now.saturating_sub(h.sample_t_ns));
            publisher.push(h.publish_t_ns.saturating_sub(h.sample_t_ns));
        })?;
        if window.start.is_some() {
            // Gaps before the first sample (joining mid-stream) are not losses.
            first_gaps.get_or_insert(sub.stats().seq_gaps_total);
        }
        let now = rt::monotonic_ns();
        if window.elapsed_s(now) > seconds {
            break;
        }
        if matches!(update, Update::Terminated) && window.start.is_some() {
            break;
        }
    }
    let now = rt::monotonic_ns();
    let lost = sub.stats().seq_gaps_total - first_gaps.unwrap_or(0);
    let st = sub.stats();
    let on_time = (wait == WaitStrategy::Predictive).then_some((
        st.predicted_on_time_total,
        st.predicted_on_time_total
            + st.predicted_late_total
            + st.predicted_missed_total
            + st.predicted_skipped_total,
    ));
    println!(
        "{}",
        report(lat, publisher, lost, window.percent(now), on_time)
    );
    Ok(())
}

/// Binds a port of its own (a port picked by the orchestrator could be taken by another process
/// before the subscriber binds it) and prints it as its first line.
fn sub_json(seconds: f64) -> Res<()> {
    let sock = UdpSocket::bind(("127.0.0.1", 0))?;
    println!("PORT {}", sock.local_addr()?.port());
    sock.set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut buf = [0u8; 2048];
    let capacity = (seconds * 2000.0) as usize;
    let mut lat = Vec::with_capacity(capacity);
    let mut window = CpuWindow { start: None };
    let mut last_seq: Option<u64> = None;
    let mut lost = 0;
    let mut idle = 0;
    loop {
        match sock.recv(&mut buf) {
            Ok(n) => {
                idle = 0;
                let now = rt::monotonic_ns();
                window.mark(now);
                // A consumer of sawSocketStreamer parses the JSON to get at the values.
                let v: serde_json::Value = serde_json::from_slice(&buf[..n])?;
                let ts = v["measured_cp"]["Timestamp"]
                    .as_f64()
                    .ok_or("datagram without Timestamp")?;
                lat.push(now.saturating_sub((ts * 1e9) as u64));
                let seq = v["seq"].as_u64().ok_or("datagram without seq")?;
                if let Some(prev) = last_seq
                    && seq > prev + 1
                {
                    lost += seq - prev - 1;
                }
                last_seq = Some(seq);
            }
            Err(_) => {
                idle += 1;
                if window.start.is_some() && idle > 5 {
                    break;
                }
            }
        }
        if window.elapsed_s(rt::monotonic_ns()) > seconds {
            break;
        }
    }
    let now = rt::monotonic_ns();
    println!(
        "{}",
        report(lat, Vec::new(), lost, window.percent(now), None)
    );
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
    let mut seq = 0u64;
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
        seq += 1;
        // `seq` (not part of sawSocketStreamer's message) lets the subscribers count losses.
        let json = serde_json::json!({ "seq": seq, "measured_cp": {
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

/// What the N subscriber processes of one case measured together.
#[derive(Default)]
struct Case {
    all: Vec<u64>,
    publisher: Vec<u64>,
    lost: u64,
    cpu_percent: f64,
    /// Predictive waits that were polling when the sample landed, of all predictive waits.
    on_time: (u64, u64),
}

/// A subscriber process and its standard output.
type Sub = (Child, BufReader<ChildStdout>);

fn sub_process(mut c: Child) -> Res<Sub> {
    let out = c.stdout.take().ok_or("no stdout")?;
    Ok((c, BufReader::new(out)))
}

fn collect(children: Vec<Sub>) -> Res<Case> {
    let mut case = Case::default();
    let n = children.len();
    for (mut c, out) in children {
        let line = out.lines().next().ok_or("subscriber printed nothing")??;
        let v: serde_json::Value = serde_json::from_str(&line)?;
        let nums = |key: &str| -> Vec<u64> {
            v[key]
                .as_array()
                .map(|a| a.iter().filter_map(|x| x.as_u64()).collect())
                .unwrap_or_default()
        };
        case.all.extend(nums("all"));
        case.publisher.extend(nums("publisher"));
        case.lost += v["lost"].as_u64().ok_or("no lost")?;
        if let Some(a) = v["on_time"].as_array() {
            case.on_time.0 += a[0].as_u64().unwrap_or(0);
            case.on_time.1 += a[1].as_u64().unwrap_or(0);
        }
        case.cpu_percent += v["cpu_percent"].as_f64().ok_or("no cpu_percent")? / n as f64;
        let status = c.wait()?;
        if !status.success() {
            return Err(format!("a subscriber failed: {status}").into());
        }
    }
    case.all.sort_unstable();
    case.publisher.sort_unstable();
    Ok(case)
}

fn q(v: &[u64], p: f64) -> f64 {
    v.get(((p * v.len() as f64) as usize).min(v.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0) as f64
        / 1e3
}

struct Options {
    seconds: f64,
    counts: Vec<usize>,
    json: bool,
    check_lost: bool,
    paths: Vec<String>,
    /// The topic the shared-memory subscribers take (the JSON path always carries the
    /// compensated pose).
    topic: Topic,
    /// The interpreter of the Python paths.
    python: String,
    /// Seconds per Python case (default: `seconds`).
    python_seconds: Option<f64>,
}

/// The default paths: every Rust and Python path (spinning ones only while subscribers < CPUs).
const DEFAULT_PATHS: [&str; 10] = [
    "event",
    "event_datagram",
    "predictive",
    "predictive_datagram",
    "spin",
    "json_udp",
    "python_native_predictive",
    "python_native_event",
    "python_pure_event",
    "python_json_udp",
];

/// A Rust shared-memory path: its wait strategy, and whether it sleeps on the iceoryx2
/// listener's unix datagrams (`event_datagram`, `predictive_datagram`: the wait before the
/// futex word, `Subscription::use_datagram_wake`) instead of the cycle's wake-up word.
fn rust_shm_path(p: &str) -> Option<(WaitStrategy, bool)> {
    match p.strip_suffix("_datagram") {
        Some(w) => Some((
            w.parse().ok().filter(|w: &WaitStrategy| w.uses_event())?,
            true,
        )),
        None => Some((p.parse().ok()?, false)),
    }
}

/// A Python shared-memory path: (`native`|`pure`, its wait strategy).
fn python_shm_path(p: &str) -> Option<(&'static str, WaitStrategy)> {
    let (backend, wait) = if let Some(w) = p.strip_prefix("python_native_") {
        ("native", w)
    } else {
        ("pure", p.strip_prefix("python_pure_")?)
    };
    Some((backend, wait.parse().ok()?))
}

fn python_script() -> PathBuf {
    repo().join("benches/latency/python_sub.py")
}

fn parse_options(args: &[String]) -> Res<Options> {
    let mut o = Options {
        seconds: 10.0,
        counts: vec![1, 4, 16],
        json: false,
        check_lost: false,
        paths: DEFAULT_PATHS.map(String::from).to_vec(),
        topic: Topic::CompensatedLocalMeasuredCp,
        python: "python3".to_owned(),
        python_seconds: None,
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--seconds" => o.seconds = it.next().ok_or("--seconds S")?.parse()?,
            "--subscribers" => {
                o.counts = it
                    .next()
                    .ok_or("--subscribers 1,4,16")?
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()?
            }
            "--paths" => {
                o.paths = it
                    .next()
                    .ok_or("--paths event,predictive,spin,json_udp")?
                    .split(',')
                    .map(String::from)
                    .collect()
            }
            "--topic" => {
                let t = it.next().ok_or("--topic compensated/local/measured_cp")?;
                o.topic = Topic::from_suffix(t).ok_or_else(|| format!("unknown topic {t:?}"))?;
            }
            "--python" => o.python = it.next().ok_or("--python PATH")?.clone(),
            "--python-seconds" => {
                o.python_seconds = Some(it.next().ok_or("--python-seconds S")?.parse()?)
            }
            "--json" => o.json = true,
            "--check-lost" => o.check_lost = true,
            // cargo bench passes filters and flags of its own; ignore them.
            _ => {}
        }
    }
    for p in &o.paths {
        let known = p == "json_udp"
            || p == "python_json_udp"
            || python_shm_path(p).is_some()
            || rust_shm_path(p).is_some();
        if !known {
            return Err(format!(
                "unknown path {p:?}: expected event, predictive, spin, event_datagram, \
                 predictive_datagram, json_udp, \
                 python_native_<wait>, python_pure_<wait> or python_json_udp"
            )
            .into());
        }
    }
    Ok(o)
}

/// Fails unless `python` imports the installed package with its native module (only when a
/// Python path is asked for).
fn check_python(o: &Options) -> Res<()> {
    if !o.paths.iter().any(|p| p.starts_with("python_")) {
        return Ok(());
    }
    let out = Command::new(&o.python)
        .args(["-c", "import dvrk_sidecar._native, numpy, iceoryx2"])
        .current_dir(std::env::temp_dir())
        .output()
        .map_err(|e| format!("running {}: {e}", o.python))?;
    if !out.status.success() {
        return Err(format!(
            "the Python paths need {} with the dvrk_sidecar package and its native module \
             (python3 -m pip install ./python, or bash .ci/python-deps; or leave them out with \
             --paths): {}",
            o.python,
            String::from_utf8_lossy(&out.stderr).trim()
        )
        .into());
    }
    Ok(())
}

fn orchestrate(args: &[String]) -> Res<()> {
    let o = parse_options(args)?;
    check_python(&o)?;
    let py_seconds = o.python_seconds.unwrap_or(o.seconds).to_string();
    let cores = std::thread::available_parallelism()?.get();
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
    if !o.json {
        println!(
            "# latency, {} s per case, 1500 Hz, {cores} CPUs ({cpu}), shared memory: {} ({} of {} messages per cycle)\n",
            o.seconds,
            o.topic,
            o.topic.index() + 1,
            Topic::ALL.len()
        );
        println!(
            "| subscribers | path | samples | p50 µs | p99 µs | p99.9 µs | max µs | lost | CPU % per subscriber | publisher's share p50 µs | hand-off p50 µs | predicted on time |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    }
    let mut total_lost = 0;
    let mut ratios = Vec::new();
    for &n in &o.counts {
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
        let mut results: Vec<(String, Case)> = Vec::new();
        // Shared memory: one serve, then n subscriber processes per wait strategy in turn.
        let shm_paths: Vec<(&str, WaitStrategy)> = o
            .paths
            .iter()
            .filter_map(|p| rust_shm_path(p).map(|(w, _)| (p.as_str(), w)))
            .filter(|(_, w)| *w != WaitStrategy::Spin || n < cores)
            .collect();
        let py_shm: Vec<(&str, &'static str, WaitStrategy)> = o
            .paths
            .iter()
            .filter_map(|p| python_shm_path(p).map(|(b, w)| (p.as_str(), b, w)))
            .filter(|(_, _, w)| *w != WaitStrategy::Spin || n < cores)
            .collect();
        if !shm_paths.is_empty() || !py_shm.is_empty() {
            let serve = Killer(
                Command::new(&bin)
                    .args(["serve", "--config"])
                    .arg(&cfg)
                    .env("RUST_LOG", "warn")
                    .spawn()?,
            );
            for (path, _) in shm_paths {
                let subs: Vec<Sub> = (0..n)
                    .map(|_| {
                        sub_process(
                            Command::new(&me)
                                .args(["--sub-shm", &prefix, &o.seconds.to_string(), path])
                                .arg(o.topic.suffix())
                                .stdout(Stdio::piped())
                                .spawn()?,
                        )
                    })
                    .collect::<Res<_>>()?;
                results.push((path.to_owned(), collect(subs)?));
            }
            for &(path, backend, wait) in &py_shm {
                let subs: Vec<Sub> = (0..n)
                    .map(|_| {
                        sub_process(
                            Command::new(&o.python)
                                .arg(python_script())
                                .args(["shm", backend, wait.name(), &prefix])
                                .args([o.topic.suffix(), &py_seconds])
                                .current_dir(&dir)
                                .stdout(Stdio::piped())
                                .spawn()?,
                        )
                    })
                    .collect::<Res<_>>()?;
                results.push((path.to_owned(), collect(subs)?));
            }
            drop(serve);
        }
        for json_path in ["json_udp", "python_json_udp"] {
            if !o.paths.iter().any(|p| p == json_path) {
                continue;
            }
            // JSON over UDP: the streamer + n subscriber processes (Rust or Python).
            let seconds = if json_path == "json_udp" {
                o.seconds.to_string()
            } else {
                py_seconds.clone()
            };
            let mut subs: Vec<Sub> = (0..n)
                .map(|_| {
                    let mut cmd = if json_path == "json_udp" {
                        let mut c = Command::new(&me);
                        c.args(["--sub-json", &seconds]);
                        c
                    } else {
                        let mut c = Command::new(&o.python);
                        c.arg(python_script()).args(["json", &seconds]);
                        c
                    };
                    sub_process(cmd.stdout(Stdio::piped()).spawn()?)
                })
                .collect::<Res<_>>()?;
            let mut ports = Vec::with_capacity(n);
            for (_, out) in &mut subs {
                let mut line = String::new();
                out.read_line(&mut line)?;
                let port: u16 = line
                    .strip_prefix("PORT ")
                    .ok_or_else(|| format!("JSON subscriber printed {line:?}, not its port"))?
                    .trim()
                    .parse()?;
                ports.push(port);
            }
            let targets = ports
                .iter()
                .map(u16::to_string)
                .collect::<Vec<_>>()
                .join(",");
            let streamer_s: f64 = seconds.parse::<f64>()? + 1.0;
            let streamer = Killer(
                Command::new(&me)
                    .args(["--json-streamer"])
                    .arg(&cfg)
                    .args([&targets, &streamer_s.to_string()])
                    .spawn()?,
            );
            results.push((json_path.to_owned(), collect(subs)?));
            drop(streamer);
        }
        for (path, r) in &results {
            let v = &r.all;
            total_lost += r.lost;
            if o.json {
                println!(
                    "{}",
                    serde_json::json!({
                        "subscribers": n, "path": path, "samples": v.len(),
                        "p50_us": q(v, 0.5), "p99_us": q(v, 0.99), "p999_us": q(v, 0.999),
                        "max_us": q(v, 1.0), "lost": r.lost,
                        "cpu_percent": (r.cpu_percent * 10.0).round() / 10.0,
                    })
                );
            } else {
                let share = if r.publisher.is_empty() {
                    "".to_owned()
                } else {
                    format!("{:.1}", q(&r.publisher, 0.5))
                };
                let handoff = if r.publisher.is_empty() {
                    "".to_owned()
                } else {
                    // Per-sample hand-off is latency minus the publisher's share; its p50 is
                    // close to the difference of the p50s.
                    format!("{:.1}", q(v, 0.5) - q(&r.publisher, 0.5))
                };
                let on_time = if r.on_time.1 > 0 {
                    format!(
                        "{:.1} % of {}",
                        100.0 * r.on_time.0 as f64 / r.on_time.1 as f64,
                        r.on_time.1
                    )
                } else {
                    "".to_owned()
                };
                println!(
                    "| {n} | {path} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {:.1} | {share} | {handoff} | {on_time} |",
                    v.len(),
                    q(v, 0.5),
                    q(v, 0.99),
                    q(v, 0.999),
                    q(v, 1.0),
                    r.lost,
                    r.cpu_percent
                );
            }
        }
        // Rust paths against the Rust JSON receiver, Python paths against the Python one.
        for (json_path, python) in [("json_udp", false), ("python_json_udp", true)] {
            let Some((_, json)) = results.iter().find(|(p, _)| p == json_path) else {
                continue;
            };
            for (path, r) in results
                .iter()
                .filter(|(p, _)| !p.ends_with("json_udp") && p.starts_with("python_") == python)
            {
                ratios.push((
                    n,
                    path.clone(),
                    q(&json.all, 0.5) / q(&r.all, 0.5),
                    q(&json.all, 0.99) / q(&r.all, 0.99),
                ));
            }
        }
    }
    if !o.json && !ratios.is_empty() {
        println!(
            "\npython_* paths against python_json_udp, the others against json_udp:\n\n| subscribers | path | JSON/path p50 | JSON/path p99 |\n|---|---|---|---|"
        );
        for (n, path, r50, r99) in ratios {
            println!("| {n} | {path} | {r50:.2}x | {r99:.2}x |");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    if o.check_lost && total_lost > 0 {
        return Err(format!("{total_lost} samples lost (sequence gaps) over all cases").into());
    }
    Ok(())
}
