//! The ROS 2 bridge and the MCAP recorder against independent clients:
//! - Cyclone DDS (the `cyclonedds` Python package, the DDS of ROS 2's rmw_cyclonedds) reads
//!   `rt/PSM1/compensated/local/measured_cp` as `geometry_msgs::msg::dds_::PoseStamped_` and
//!   `rt/PSM1/compensated/jaw/measured_js` as `sensor_msgs::msg::dds_::JointState_` from
//!   `dvrk-sidecar ros2-bridge`, on loopback only, in a DDS domain of its own;
//! - the `mcap` and `mcap-ros2-support` Python packages decode every message of a file written by
//!   `dvrk-sidecar record`.
//!
//! In both, the values must equal what `dvrk-sidecar echo` shows for the same cycle.
//! The Python packages are installed by .ci/python-deps; without them the tests show as ignored
//! (build.rs, cfgs `has_py_cyclonedds` and `has_py_mcap_ros2`), and under CI they run and fail.

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use common::*;
use serde_json::Value;

fn python_has(module: &str) -> bool {
    Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// The modules build.rs found (or CI requires): fails the test when one is missing now.
fn require_python(modules: &[&str]) -> bool {
    let missing: Vec<&str> = modules.iter().copied().filter(|m| !python_has(m)).collect();
    assert!(
        missing.is_empty(),
        "python3 lacks {missing:?}: run .ci/python-deps (pip install cyclonedds mcap \
         mcap-ros2-support), then touch build.rs"
    );
    true
}

/// `realtime - monotonic` of this host in ns, to check the bridge's stamps.
fn clock_offset_ns() -> i64 {
    let read = |id| {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: valid timespec.
        assert_eq!(unsafe { libc::clock_gettime(id, &mut ts) }, 0);
        ts.tv_sec * 1_000_000_000 + ts.tv_nsec
    };
    let m = read(libc::CLOCK_MONOTONIC);
    read(libc::CLOCK_REALTIME) - m
}

/// `echo SERVICE --json --count N` in a thread; the samples arrive on the channel at the end.
fn echo_in_background(service: String, count: u64) -> mpsc::Receiver<Vec<Value>> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let v = echo_json(&service, count, Duration::from_secs(120));
        let _ = tx.send(v);
    });
    rx
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn stamp_ns(header: &Value) -> i64 {
    let h = &header["stamp"];
    let (sec, ns) = if h.is_object() {
        (h["sec"].as_i64().unwrap(), h["nanosec"].as_i64().unwrap())
    } else {
        (
            header["sec"].as_i64().unwrap(),
            header["nanosec"].as_i64().unwrap(),
        )
    };
    sec * 1_000_000_000 + ns
}

/// A per-test DDS domain id (0..=232), so parallel runs do not see each other.
fn unique_domain() -> u16 {
    20 + (std::process::id() % 200) as u16
}

/// Cyclone DDS on the loopback interface only, discovering peers by unicast on 127.0.0.1.
fn cyclone_uri(dir: &Path) -> String {
    let xml = r#"<?xml version="1.0" encoding="UTF-8" ?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain id="any">
    <General>
      <Interfaces><NetworkInterface name="lo"/></Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>
      <Peers><Peer address="127.0.0.1"/></Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
"#;
    let path = dir.join("cyclonedds.xml");
    std::fs::write(&path, xml).unwrap();
    format!("file://{}", path.display())
}

fn bridge_proc(args: &[&str]) -> Proc {
    Proc::spawn(
        "ros2-bridge",
        Command::new(sidecar_bin())
            .arg("ros2-bridge")
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    )
}

/// Starts the Cyclone reader and returns it with a channel of its JSON lines.
fn cyclone_reader(
    uri: &str,
    domain: u16,
    topic: &str,
    kind: &str,
    count: u32,
    reliable: bool,
) -> (Proc, mpsc::Receiver<Value>) {
    let mut p = Proc::spawn(
        "cyclone reader",
        Command::new("python3")
            .arg(repo().join("tests/bridge/cyclone_reader.py"))
            .args(["--domain", &domain.to_string(), "--topic", topic])
            .args(["--type", kind, "--count", &count.to_string()])
            .args(["--timeout-s", "60"])
            .args(reliable.then_some("--reliable"))
            .env("CYCLONEDDS_URI", uri)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    let out = p.child.as_mut().unwrap().stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines() {
            let Ok(l) = l else { break };
            let v: Value = serde_json::from_str(&l).unwrap();
            if tx.send(v).is_err() {
                break;
            }
        }
    });
    (p, rx)
}

fn collect(p: &mut Proc, rx: &mpsc::Receiver<Value>, what: &str) -> Vec<Value> {
    let st = p
        .wait_timeout(Duration::from_secs(90))
        .unwrap_or_else(|| panic!("{what} did not finish"));
    assert!(st.success(), "{what} exited with {st}: {}", p.stderr_text());
    rx.try_iter().filter(|v| v.get("ready").is_none()).collect()
}

/// Runs serve, the bridge and two Cyclone DDS readers; checks every value against echo and
/// returns the echo seqs of the cycles in the DDS reader's window that it did not receive, the
/// number of cycles echo saw in that window, and the bridge's log.
fn cyclone_round(test: &str, reliable: bool) -> (Vec<u64>, u64, String) {
    let prefix = unique_prefix(test);
    let cfg = write_config(test, "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);
    // Distinct domains for the two tests of this process.
    let domain = unique_domain() + u16::from(reliable);
    let uri = cyclone_uri(&scratch(test));
    let domain_s = domain.to_string();
    let mut args = vec![
        "--prefix",
        "PSM1",
        "--shm-prefix",
        &prefix,
        "--domain",
        &domain_s,
        "--interface",
        "127.0.0.1",
    ];
    if reliable {
        args.push("--reliable");
    }
    let mut bridge = bridge_proc(&args);

    // echo runs first and long enough (4 s of cycles) to cover what the DDS readers receive.
    let echo_cp = echo_in_background(format!("{prefix}/compensated/local/measured_cp"), 6000);
    let echo_js = echo_in_background(format!("{prefix}/compensated/jaw/measured_js"), 6000);
    let (mut rp, rx_p) = cyclone_reader(
        &uri,
        domain,
        "rt/PSM1/compensated/local/measured_cp",
        "pose",
        300,
        reliable,
    );
    let (mut rj, rx_j) = cyclone_reader(
        &uri,
        domain,
        "rt/PSM1/compensated/jaw/measured_js",
        "joints",
        300,
        reliable,
    );
    let poses = collect(&mut rp, &rx_p, "the Cyclone DDS pose reader");
    let jaws = collect(&mut rj, &rx_j, "the Cyclone DDS joint-state reader");
    let echo_cp = echo_cp.recv().unwrap();
    let echo_js = echo_js.recv().unwrap();
    let (st, bridge_log) = bridge.terminate();
    assert!(st.success(), "ros2-bridge exited with {st}: {bridge_log}");
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    assert_eq!(poses.len(), 300);
    assert_eq!(jaws.len(), 300);

    // The ROS stamp is the header's realtime (ROS) time of the sample, which is the monotonic
    // sample time plus this host's realtime - monotonic.
    let by_t: BTreeMap<u64, &Value> = echo_cp
        .iter()
        .map(|e| (e["header"]["sample_realtime_ns"].as_u64().unwrap(), e))
        .collect();
    let host = clock_offset_ns();
    for e in &echo_cp {
        let h = &e["header"];
        let off = h["sample_realtime_ns"].as_i64().unwrap() - h["sample_t_ns"].as_i64().unwrap();
        assert!(
            (off - host).abs() < 1_000_000_000,
            "sample_realtime_ns - sample_t_ns = {off} ns is not realtime - monotonic ({host} ns)"
        );
    }
    let (lo, hi) = (
        *by_t.keys().next().unwrap(),
        *by_t.keys().next_back().unwrap(),
    );
    let mut compared = 0;
    let mut dds_t = std::collections::BTreeSet::new();
    for p in &poses {
        assert_eq!(p["header"]["frame_id"], "PSM1_base", "{p}");
        let t = stamp_ns(&p["header"]) as u64;
        if t < lo || t > hi {
            continue;
        }
        // echo itself may lose cycles when starved of CPU (it counts them, we do not need it).
        let Some(e) = by_t.get(&t) else { continue };
        assert_eq!(f64s(&p["position"]), f64s(&e["position_m"]), "{p} vs {e}");
        assert_eq!(
            f64s(&p["orientation_xyzw"]),
            f64s(&e["orientation_xyzw"]),
            "{p} vs {e}"
        );
        dds_t.insert(t);
        compared += 1;
    }
    assert!(
        compared >= 100,
        "only {compared} of 300 DDS poses fall in the cycles echo covered"
    );

    // The jaw: compensated/jaw/measured_js, one joint named "jaw".
    let js_by_t: BTreeMap<u64, &Value> = echo_js
        .iter()
        .map(|e| (e["header"]["sample_realtime_ns"].as_u64().unwrap(), e))
        .collect();
    let mut compared = 0;
    for j in &jaws {
        assert_eq!(j["name"], serde_json::json!(["jaw"]));
        assert_eq!(j["header"]["frame_id"], "PSM1");
        let t = stamp_ns(&j["header"]) as u64;
        let Some(e) = js_by_t.get(&t) else { continue };
        for k in ["position", "velocity", "effort"] {
            assert_eq!(f64s(&j[k]), f64s(&e[k]), "{k}: {j} vs {e}");
        }
        compared += 1;
    }
    assert!(compared >= 100, "only {compared} jaw samples matched echo");
    // Every cycle echo saw between the first and the last pose the DDS reader received must have
    // reached the reader, or is reported here.
    let (a, b) = (*dds_t.first().unwrap(), *dds_t.last().unwrap());
    let window: Vec<(&u64, &&Value)> = by_t.range(a..=b).collect();
    let missing = window
        .iter()
        .filter(|(t, _)| !dds_t.contains(*t))
        .map(|(_, e)| e["header"]["seq"].as_u64().unwrap())
        .collect();
    (missing, window.len() as u64, bridge_log)
}

/// `dvrk-sidecar record --prefix PSM1 --shm-prefix PREFIX ARGS --out OUT`, stderr captured.
fn record_proc(prefix: &str, args: &[&str], out: &Path) -> Proc {
    Proc::spawn(
        "record",
        Command::new(sidecar_bin())
            .args(["record", "--prefix", "PSM1", "--shm-prefix", prefix])
            .args(args)
            .arg("--out")
            .arg(out)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    )
}

/// Every message of an MCAP file as tests/bridge/mcap_check.py decodes it (the mcap ROS 2
/// decoder), one JSON object each.
fn decode_mcap(out: &Path) -> Vec<Value> {
    let dec = Command::new("python3")
        .arg(repo().join("tests/bridge/mcap_check.py"))
        .arg(out)
        .output()
        .unwrap();
    assert!(
        dec.status.success(),
        "the mcap ROS 2 decoder failed on {}: {}",
        out.display(),
        String::from_utf8_lossy(&dec.stderr)
    );
    String::from_utf8(dec.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// The "N lost in shared memory" of a bridge or recorder's summary line.
fn bridge_lost(log: &str) -> u64 {
    let line = log
        .lines()
        .find(|l| l.contains("lost in shared memory"))
        .unwrap_or_else(|| panic!("no summary line in the log: {log}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let i = words.iter().position(|w| *w == "lost").unwrap();
    words[i - 1].parse().unwrap()
}

fn missing_cycles(seqs: &[u64]) -> u64 {
    seqs.windows(2).map(|w| w[1] - w[0] - 1).sum()
}

#[cfg_attr(
    not(has_py_cyclonedds),
    ignore = "needs python3 with cyclonedds: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn cyclone_dds_reads_the_compensated_pose_and_jaw_as_echo_shows_them() {
    if !require_python(&["cyclonedds"]) {
        return;
    }
    let (missing, span, log) = cyclone_round("ros2bridge", false);
    // Sensor-data QoS is best effort over UDP: a reader that is starved of CPU misses samples
    // (seen here: 0-30 % of them with the tests of this file in parallel at load 7 on 2 cores),
    // so delivery is not asserted here (the reliable test does). What is asserted: the bridge
    // wrote all five topics of every cycle it took, and lost none in shared memory.
    let missing = missing.len();
    eprintln!("best effort: {missing} of {span} cycles missed by the DDS reader");
    let line = log
        .lines()
        .find(|l| l.contains("ros2-bridge stopped:"))
        .unwrap_or_else(|| panic!("no summary line in the bridge's log: {log}"));
    let nums: Vec<u64> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter_map(|w| w.parse().ok())
        .collect();
    // "... stopped: C cycles, W DDS samples written, I invalid skipped, D decimated, L lost ..."
    let n = nums.len();
    let (cycles, written, lost) = (nums[n - 5], nums[n - 4], nums[n - 1]);
    assert!(cycles > 300, "{line}");
    if lost == 0 {
        assert_eq!(written, 5 * cycles, "{line}");
    } else {
        // The bridge fell behind by more than the shared-memory buffer (a debug build on a
        // loaded machine) and says so; the topics then lose about the same cycles.
        eprintln!("the bridge lost cycles in shared memory: {line}");
        assert!(written.abs_diff(5 * cycles) <= 5 * lost, "{line}");
    }
}

#[cfg_attr(
    not(has_py_cyclonedds),
    ignore = "needs python3 with cyclonedds: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn cyclone_dds_reliable_receives_every_cycle() {
    if !require_python(&["cyclonedds"]) {
        return;
    }
    let (missing, _, log) = cyclone_round("ros2bridge-rel", true);
    // Every cycle the bridge took reached the reader: no cycle is missing unless the bridge
    // itself lost it in shared memory (and reported it).
    let lost = bridge_lost(&log);
    assert!(
        missing.len() as u64 <= lost,
        "cycles echo saw that the DDS reader did not ({lost} lost in shared memory): {missing:?}\nros2-bridge: {log}"
    );
}

#[cfg_attr(
    not(has_py_mcap_ros2),
    ignore = "needs python3 with mcap and mcap-ros2-support: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn record_writes_mcap_that_the_ros2_decoder_reads_back_as_echo_shows() {
    if !require_python(&["mcap", "mcap_ros2"]) {
        return;
    }
    let prefix = unique_prefix("record");
    let cfg = write_config("record", "sim", "shared", &prefix, "divot-push.toml");
    // The simulator's fitted parameters (with a dynamics model): the paper's, without one,
    // correct only a still arm (issue 20), and the push never stops long enough in 2 s.
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("paper-psm.toml", "sim-psm.toml");
    std::fs::write(&cfg, text).unwrap();
    let mut serve = serve(&cfg);
    let out = scratch("record").join("run.mcap");
    let echo_cp = echo_in_background(format!("{prefix}/compensated/local/measured_cp"), 3000);
    let echo_base = echo_in_background(format!("{prefix}/compensated/measured_cp"), 3000);
    let echo_js = echo_in_background(format!("{prefix}/compensated/measured_js"), 3000);
    let echo_jaw = echo_in_background(format!("{prefix}/compensated/jaw/measured_js"), 3000);
    let echo_st = echo_in_background(format!("{prefix}/compensated/status"), 3000);
    let echo_raw = echo_in_background(format!("{prefix}/local/measured_cp"), 3000);
    let mut rec = record_proc(&prefix, &["--seconds", "2"], &out);
    let st = rec
        .wait_timeout(Duration::from_secs(60))
        .expect("record did not stop after --seconds 2");
    let rec_log = rec.stderr_text();
    assert!(st.success(), "record exited with {st}: {rec_log}");
    assert!(
        !out.with_file_name(".run.mcap.partial").exists(),
        "the partial file outlived the recording"
    );
    let lost = bridge_lost(&rec_log);
    let echo_cp = echo_cp.recv().unwrap();
    let echo_base = echo_base.recv().unwrap();
    let echo_js = echo_js.recv().unwrap();
    let echo_jaw = echo_jaw.recv().unwrap();
    let echo_st = echo_st.recv().unwrap();
    let echo_raw = echo_raw.recv().unwrap();
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");

    let msgs = decode_mcap(&out);
    let mut per_topic: BTreeMap<String, Vec<&Value>> = BTreeMap::new();
    for m in &msgs {
        assert_eq!(m["profile"], "ros2");
        assert_eq!(m["encoding"], "cdr");
        assert_eq!(m["schema_encoding"], "ros2msg");
        per_topic
            .entry(m["topic"].as_str().unwrap().to_owned())
            .or_default()
            .push(m);
    }
    let topics: Vec<&str> = per_topic.keys().map(String::as_str).collect();
    assert_eq!(
        topics,
        [
            "/PSM1/compensated/jaw/measured_js",
            "/PSM1/compensated/local/measured_cp",
            "/PSM1/compensated/measured_cp",
            "/PSM1/compensated/measured_js",
            "/PSM1/compensated/status",
            "/PSM1/jaw/measured_js",
            "/PSM1/local/measured_cp",
            "/PSM1/measured_cp",
            "/PSM1/measured_js",
        ]
    );
    // The uncompensated pose is what echo shows on the sidecar's local/measured_cp, and in a
    // divot push the compensated one differs from it.
    let raw_by_seq: BTreeMap<u64, &Value> = echo_raw
        .iter()
        .map(|e| (e["header"]["seq"].as_u64().unwrap(), e))
        .collect();
    let comp_by_seq: BTreeMap<u64, &Value> = per_topic["/PSM1/compensated/local/measured_cp"]
        .iter()
        .map(|m| (m["sequence"].as_u64().unwrap(), *m))
        .collect();
    let (mut raw_compared, mut differ) = (0, 0);
    for m in &per_topic["/PSM1/local/measured_cp"] {
        let seq = m["sequence"].as_u64().unwrap();
        let p = &m["msg"]["pose"]["position"];
        let pos = ["x", "y", "z"].map(|k| p[k].as_f64().unwrap()).to_vec();
        if let Some(e) = raw_by_seq.get(&seq) {
            assert_eq!(pos, f64s(&e["position_m"]), "raw seq {seq}");
            raw_compared += 1;
        }
        if let Some(c) = comp_by_seq.get(&seq) {
            let q = &c["msg"]["pose"]["position"];
            differ += usize::from(["x", "y", "z"].map(|k| q[k].as_f64().unwrap()).to_vec() != pos);
        }
    }
    assert!(
        raw_compared >= 100,
        "only {raw_compared} raw poses matched echo"
    );
    assert!(
        differ > 0,
        "the compensated pose never differs from the raw one"
    );
    let local = &per_topic["/PSM1/compensated/local/measured_cp"];
    assert!(
        local.len() >= 100,
        "only {} poses in 2 s of recording",
        local.len()
    );
    // One message per cycle and topic (every cycle of the simulator is valid), in seq order
    // without gaps.
    // One message per cycle and topic (every cycle of the simulator is valid), in seq order.
    // No cycle is missing unless the recorder fell behind by more than the shared-memory buffer
    // and reported it.
    let local_seqs: Vec<u64> = local
        .iter()
        .map(|m| m["sequence"].as_u64().unwrap())
        .collect();
    for (t, v) in &per_topic {
        let seqs: Vec<u64> = v.iter().map(|m| m["sequence"].as_u64().unwrap()).collect();
        assert!(
            seqs.windows(2).all(|w| w[1] > w[0]),
            "{t}: sequence not increasing"
        );
        assert!(
            missing_cycles(&seqs) <= lost,
            "{t}: {} cycles missing, {lost} reported lost: {rec_log}",
            missing_cycles(&seqs)
        );
        if lost == 0 {
            assert_eq!(seqs, local_seqs, "{t}: not the cycles of local/measured_cp");
        }
    }
    assert_eq!(
        per_topic["/PSM1/compensated/local/measured_cp"][0]["schema"],
        "geometry_msgs/msg/PoseStamped"
    );
    assert_eq!(
        per_topic["/PSM1/compensated/measured_js"][0]["schema"],
        "sensor_msgs/msg/JointState"
    );

    let by_seq = |echo: &[Value]| -> BTreeMap<u64, Value> {
        echo.iter()
            .map(|e| (e["header"]["seq"].as_u64().unwrap(), e.clone()))
            .collect()
    };
    let (cp, js, stt) = (by_seq(&echo_cp), by_seq(&echo_js), by_seq(&echo_st));
    let (base_cp, jaws) = (by_seq(&echo_base), by_seq(&echo_jaw));
    let mut compared = 0;
    for m in local.iter() {
        let seq = m["sequence"].as_u64().unwrap();
        let Some(e) = cp.get(&seq) else { continue };
        let msg = &m["msg"];
        let stamp = stamp_ns(&msg["header"]);
        assert_eq!(m["log_time"].as_i64().unwrap(), stamp);
        assert_eq!(stamp, e["header"]["sample_realtime_ns"].as_i64().unwrap());
        assert_eq!(msg["header"]["frame_id"], "PSM1_base");
        let p = &msg["pose"]["position"];
        let q = &msg["pose"]["orientation"];
        let pos = ["x", "y", "z"].map(|k| p[k].as_f64().unwrap());
        let quat = ["x", "y", "z", "w"].map(|k| q[k].as_f64().unwrap());
        assert_eq!(pos.to_vec(), f64s(&e["position_m"]), "seq {seq}");
        assert_eq!(quat.to_vec(), f64s(&e["orientation_xyzw"]), "seq {seq}");
        // measured_cp is the sidecar's compensated/measured_cp (the base frame of the
        // configuration: the identity here, so it equals local).
        let at = |topic: &str| -> &Value {
            let v = &per_topic[topic];
            let j = v
                .iter()
                .position(|m| m["sequence"].as_u64() == Some(seq))
                .unwrap_or_else(|| panic!("{topic}: no message of seq {seq}"));
            &v[j]["msg"]
        };
        let base = at("/PSM1/compensated/measured_cp");
        assert_eq!(base["pose"], msg["pose"]);
        if let Some(eb) = base_cp.get(&seq) {
            let p = &base["pose"]["position"];
            let pos = ["x", "y", "z"].map(|k| p[k].as_f64().unwrap());
            assert_eq!(pos.to_vec(), f64s(&eb["position_m"]), "seq {seq}");
        }

        let e = &js[&seq];
        let arm = at("/PSM1/compensated/measured_js");
        let jaw = at("/PSM1/compensated/jaw/measured_js");
        assert_eq!(
            arm["name"],
            serde_json::json!([
                "yaw",
                "pitch",
                "insertion",
                "roll",
                "wrist_pitch",
                "wrist_yaw"
            ])
        );
        assert_eq!(jaw["name"], serde_json::json!(["jaw"]));
        for k in ["position", "velocity", "effort"] {
            assert_eq!(f64s(&arm[k]), f64s(&e[k]), "seq {seq} {k}");
            if let Some(ej) = jaws.get(&seq) {
                assert_eq!(f64s(&jaw[k]), f64s(&ej[k]), "seq {seq} {k}");
            }
        }

        let e = &stt[&seq];
        let s = at("/PSM1/compensated/status");
        assert_eq!(s["seq"].as_u64(), Some(seq));
        assert_eq!(s["valid"].as_bool(), e["header"]["valid"].as_bool());
        assert_eq!(f64s(&s["tau_ext_nm"]), f64s(&e["tau_ext_nm"]), "seq {seq}");
        assert_eq!(f64s(&s["delta_rad"]), f64s(&e["delta_rad"]), "seq {seq}");
        assert_eq!(s["insertion_m"].as_f64(), e["insertion_m"].as_f64());
        for k in [
            "cycles_total",
            "read_failures_total",
            "overruns_total",
            "cycle_period_ns",
        ] {
            assert_eq!(s[k].as_u64(), e[k].as_u64(), "seq {seq} {k}");
        }
        compared += 1;
    }
    assert!(
        compared >= 100,
        "only {compared} recorded cycles were also seen by echo"
    );
    let host = clock_offset_ns();
    for e in &echo_cp {
        let h = &e["header"];
        let off = h["sample_realtime_ns"].as_i64().unwrap() - h["sample_t_ns"].as_i64().unwrap();
        assert!(
            (off - host).abs() < 1_000_000_000,
            "stamp offset {off} ns is not realtime - monotonic ({host} ns)"
        );
    }
}

#[cfg_attr(
    not(has_py_mcap_ros2),
    ignore = "needs python3 with mcap and mcap-ros2-support: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn record_rate_keeps_one_cycle_per_period() {
    if !require_python(&["mcap", "mcap_ros2"]) {
        return;
    }
    let prefix = unique_prefix("record-rate");
    let cfg = write_config("record-rate", "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);
    let out = scratch("record-rate").join("rate.mcap");
    let mut rec = record_proc(&prefix, &["--rate", "100", "--seconds", "2"], &out);
    let st = rec
        .wait_timeout(Duration::from_secs(60))
        .expect("record did not stop after --seconds 2");
    let rec_log = rec.stderr_text();
    assert!(st.success(), "record exited with {st}: {rec_log}");
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    let stamps: Vec<i64> = decode_mcap(&out)
        .into_iter()
        .filter(|m| m["topic"] == "/PSM1/compensated/local/measured_cp")
        .map(|m| m["log_time"].as_i64().unwrap())
        .collect();
    // At 1500 Hz a 10 ms slot holds 15 cycles; --rate 100 keeps the first of each slot, so
    // the kept cycles lie in distinct slots: at most (span / 10 ms) + 2 of them.
    let n = stamps.len() as i64;
    assert!(
        n >= 20,
        "only {n} poses kept in 2 s at --rate 100: {rec_log}"
    );
    assert!(stamps.windows(2).all(|w| w[1] > w[0]));
    let span = stamps[stamps.len() - 1] - stamps[0];
    assert!(
        n <= span / 10_000_000 + 2,
        "{n} poses over {span} ns: more than one per 10 ms"
    );
    // Decimation drops whole cycles, and says how many.
    assert!(rec_log.contains(" decimated"), "{rec_log}");
}

#[cfg_attr(
    not(has_py_mcap_ros2),
    ignore = "needs python3 with mcap and mcap-ros2-support: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn record_follows_a_restarted_serve() {
    if !require_python(&["mcap", "mcap_ros2"]) {
        return;
    }
    let prefix = unique_prefix("record-restart");
    let cfg = write_config(
        "record-restart",
        "sim",
        "shared",
        &prefix,
        "divot-push.toml",
    );
    let out = scratch("record-restart").join("restart.mcap");
    let mut first = serve(&cfg);
    let mut rec = record_proc(&prefix, &["--seconds", "8"], &out);
    std::thread::sleep(Duration::from_secs(2));
    let (st, log) = first.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    let mut second = serve(&cfg);
    let st = rec
        .wait_timeout(Duration::from_secs(60))
        .expect("record did not stop after --seconds 8");
    let rec_log = rec.stderr_text();
    assert!(st.success(), "record exited with {st}: {rec_log}");
    let (st, log) = second.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
    let mut per_topic: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for m in decode_mcap(&out) {
        per_topic
            .entry(m["topic"].as_str().unwrap().to_owned())
            .or_default()
            .push(m["sequence"].as_u64().unwrap());
    }
    assert_eq!(per_topic.len(), 9, "{rec_log}");
    for (t, seqs) in &per_topic {
        // The second serve counts from 1 again: the recording goes on after the drop.
        let drop = seqs
            .windows(2)
            .position(|w| w[1] < w[0])
            .unwrap_or_else(|| panic!("{t}: no second run recorded: {rec_log}"));
        let after = seqs.len() - drop - 1;
        assert!(
            after >= 100,
            "{t}: only {after} messages after the restart: {rec_log}"
        );
    }
}
