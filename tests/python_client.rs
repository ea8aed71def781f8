//! The Python client (python/, the `dvrk_sidecar` package as installed by pip) against the Rust
//! side: its ctypes layouts against the Rust message types, its `echo --json` against
//! `dvrk-sidecar echo --json` of the same seq, its `Arm` (every wait strategy) against the same,
//! and its handling of invalid samples and of a silent arm.
//!
//! Needs `python3 -m pip install ./python` (CI: .ci/python-deps). Without iceoryx2, numpy or the
//! package the tests skip outside CI and fail in CI; an installed package that differs from this
//! checkout's python/ fails (reinstall it).

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::*;
use dvrk_ipc::iceoryx2::prelude::ZeroCopySend;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    ArmPublisher, CompensationStatusV4, CycleMessages, Header, JawStateV1, JointStateV2, Message,
    PoseV2, ServiceNames, create_node, domain_config, flags,
};
use serde_json::Value;

const ROOT: &str = "/tmp/iox2t/";

/// Whether python3 can import the installed client; panics in CI when it cannot, and when the
/// installed package is not this checkout's python/.
fn python_client_ready() -> bool {
    let out = Command::new("python3")
        .args([
            "-c",
            "import iceoryx2, numpy, os, dvrk_sidecar; print(os.path.dirname(dvrk_sidecar.__file__))",
        ])
        .current_dir(std::env::temp_dir())
        .output();
    let installed = match out {
        Ok(o) if o.status.success() => PathBuf::from(String::from_utf8_lossy(&o.stdout).trim()),
        other => {
            let why = match other {
                Ok(o) => String::from_utf8_lossy(&o.stderr).into_owned(),
                Err(e) => e.to_string(),
            };
            // The build script saw the package (or CI requires it): it must import now.
            panic!(
                "python3 with iceoryx2, numpy and the dvrk_sidecar package is required \
                 (bash .ci/python-deps, or python3 -m pip install ./python; then `touch build.rs` \
                 if the test should be ignored instead): {why}"
            );
        }
    };
    let src = repo().join("python/dvrk_sidecar");
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "py") {
            let name = path.file_name().unwrap();
            let theirs = std::fs::read(installed.join(name)).unwrap_or_default();
            assert!(
                std::fs::read(&path).unwrap() == theirs,
                "the installed dvrk_sidecar ({}) differs from {} in {}: reinstall it with \
                 `python3 -m pip install --force-reinstall --no-deps ./python`",
                installed.display(),
                src.display(),
                name.to_string_lossy()
            );
        }
    }
    true
}

/// `python3 ARGS` run from a scratch directory (so only the installed package is importable).
fn python(test: &str, args: &[&str]) -> Command {
    let mut c = Command::new("python3");
    c.args(args)
        .current_dir(scratch(test))
        .env("PYTHONDONTWRITEBYTECODE", "1");
    c
}

/// A child whose stdout lines arrive on a channel as they are printed.
struct LineProc {
    proc: Proc,
    lines: mpsc::Receiver<String>,
}

impl LineProc {
    fn spawn(name: &str, cmd: &mut Command) -> LineProc {
        let mut proc = Proc::spawn(name, cmd.stdout(Stdio::piped()).stderr(Stdio::piped()));
        let stdout = proc.child.as_mut().unwrap().stdout.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(stdout).lines() {
                let Ok(l) = l else { break };
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        LineProc { proc, lines }
    }

    /// Waits for the process to exit on its own; returns its lines as JSON.
    fn finish(mut self, limit: Duration) -> Vec<Value> {
        let st = self.proc.wait_timeout(limit);
        let name = self.proc.name.clone();
        let st = st.unwrap_or_else(|| panic!("{name} did not finish within {limit:?}"));
        assert!(
            st.success(),
            "{name} exited with {st}: {}",
            self.proc.stderr_text()
        );
        self.json()
    }

    /// Stops the process with SIGTERM; returns its lines as JSON.
    fn stop(mut self) -> Vec<Value> {
        let (st, err) = self.proc.terminate();
        assert!(st.success(), "{} exited with {st}: {err}", self.proc.name);
        self.json()
    }

    fn json(&self) -> Vec<Value> {
        // The reader thread ends at EOF, after the process exited.
        let mut out = Vec::new();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(10)) {
            out.push(
                serde_json::from_str(&l)
                    .unwrap_or_else(|e| panic!("{}: not JSON ({e}): {l}", self.proc.name)),
            );
        }
        out
    }

    /// Blocks until the first line arrives (the subscriber is connected and receiving).
    fn first_line(&self, limit: Duration) -> Value {
        let l = self
            .lines
            .recv_timeout(limit)
            .unwrap_or_else(|_| panic!("{} printed nothing within {limit:?}", self.proc.name));
        serde_json::from_str(&l).unwrap()
    }
}

/// `dvrk-sidecar echo SERVICE --json` until stopped.
fn rust_echo(service: &str) -> LineProc {
    LineProc::spawn(
        "rust echo",
        Command::new(sidecar_bin()).args(["echo", service, "--json"]),
    )
}

fn by_seq(lines: Vec<Value>) -> BTreeMap<u64, Value> {
    lines
        .into_iter()
        .map(|v| (v["header"]["seq"].as_u64().expect("header.seq"), v))
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Layouts

/// (name, offset, size) of every field, in declaration order.
macro_rules! fields {
    ($ty:ty; $($f:ident),+ $(,)?) => {{
        fn size_of_field<T, F>(_: fn(&T) -> &F) -> usize { core::mem::size_of::<F>() }
        vec![$( (stringify!($f), core::mem::offset_of!($ty, $f), size_of_field(|m: &$ty| &m.$f)) ),+]
    }};
}

fn rust_layout<T: ZeroCopySend>(type_name: &str, fields: Vec<(&str, usize, usize)>) -> Value {
    // SAFETY: `type_name` is unsafe only because implementors promise a unique name.
    let declared = unsafe { <T as ZeroCopySend>::type_name() };
    assert_eq!(declared, type_name, "Message::TYPE_NAME vs the derive");
    serde_json::json!({
        "type_name": type_name,
        "size": core::mem::size_of::<T>(),
        "align": core::mem::align_of::<T>(),
        "fields": fields.iter().map(|(n, o, s)| serde_json::json!({"name": n, "offset": o, "size": s})).collect::<Vec<_>>(),
    })
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_layouts_match_the_rust_types() {
    if !python_client_ready() {
        return;
    }
    let out = python("layout", &["-m", "dvrk_sidecar", "layout"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut py: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    // The field types are Python's description; names, offsets and sizes are compared.
    for t in &mut py {
        for f in t["fields"].as_array_mut().unwrap() {
            f.as_object_mut().unwrap().remove("type");
        }
    }
    let rust = vec![
        rust_layout::<Header>(
            "dvrk::HeaderV2",
            fields!(Header; seq, sample_t_ns, sample_realtime_ns, board_timestamp, publish_t_ns, valid, flags),
        ),
        rust_layout::<JointStateV2>(
            JointStateV2::TYPE_NAME,
            fields!(JointStateV2; header, position, velocity, effort),
        ),
        rust_layout::<JawStateV1>(
            JawStateV1::TYPE_NAME,
            fields!(JawStateV1; header, position, velocity, effort),
        ),
        rust_layout::<PoseV2>(
            PoseV2::TYPE_NAME,
            fields!(PoseV2; header, position_m, orientation_xyzw, rotation),
        ),
        rust_layout::<CompensationStatusV4>(
            CompensationStatusV4::TYPE_NAME,
            fields!(CompensationStatusV4; header, tau_ext_nm, delta_rad, insertion_m,
                cycle_period_ns, cycle_duration_ns, cycles_total, read_failures_total,
                overruns_total, consecutive_read_failures, source_state, tau_margin_nm,
                held_sample_age_ns, publish_late_ns, implausible_total, bound_rad, tip_bound_m,
                weight, _reserved),
        ),
    ];
    assert_eq!(py.len(), rust.len(), "message types: {py:#?}");
    for (p, r) in py.iter().zip(&rust) {
        assert_eq!(p, r, "layout of {}", r["type_name"]);
    }
    // The flag names, bit by bit.
    let out = python(
        "layout",
        &[
            "-c",
            "import json, dvrk_sidecar; print(json.dumps(dvrk_sidecar.FLAG_NAMES))",
        ],
    )
    .output()
    .unwrap();
    let names: Vec<String> = serde_json::from_slice(&out.stdout).unwrap();
    for (bit, name) in names.iter().enumerate() {
        let rust: Vec<&str> = flags::names(1 << bit).collect();
        assert_eq!(rust, [name.as_str()], "flag bit {bit}");
    }
    assert_eq!(
        flags::names(u32::MAX).count(),
        names.len(),
        "flags defined in Rust but not in Python"
    );
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_package_tests_pass() {
    if !python_client_ready() {
        return;
    }
    let tests = repo().join("python/tests");
    let t = tests.to_str().unwrap();
    let out = python(
        "unittest",
        &["-m", "unittest", "discover", "-s", t, "-t", t, "-v"],
    )
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "the Python package tests failed:\n{err}"
    );
    // `discover` passes when it finds nothing: make sure it ran them.
    assert!(err.contains("\nOK"), "{err}");
    let ran = err
        .lines()
        .find_map(|l| {
            l.strip_prefix("Ran ")?
                .split(' ')
                .next()?
                .parse::<u32>()
                .ok()
        })
        .unwrap_or(0);
    assert!(ran >= 20, "only {ran} Python tests ran:\n{err}");
}

// ---------------------------------------------------------------------------------------------
// Against serve

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_echo_prints_what_rust_echo_prints() {
    if !python_client_ready() {
        return;
    }
    let prefix = unique_prefix("pyecho");
    let cfg = write_config("pyecho", "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);
    let topics = [
        "measured_js",
        "jaw/measured_js",
        "local/measured_cp",
        "measured_cp",
        "compensated/measured_js",
        "compensated/jaw/measured_js",
        "compensated/local/measured_cp",
        "compensated/measured_cp",
        "compensated/status",
    ];
    let waits = ["event", "spin", "predictive"];
    for (i, topic) in topics.iter().enumerate() {
        let wait = waits[i % waits.len()];
        let service = format!("{prefix}/{topic}");
        // The Rust echo runs from before the Python one starts until after it ends.
        let rust = rust_echo(&service);
        let first = rust.first_line(Duration::from_secs(30));
        let py = LineProc::spawn(
            "python echo",
            &mut python(
                "pyecho",
                &[
                    "-m",
                    "dvrk_sidecar",
                    "echo",
                    &service,
                    "--json",
                    "--count",
                    "400",
                    "--wait",
                    wait,
                    "--timeout-s",
                    "30",
                ],
            ),
        );
        let py = py.finish(Duration::from_secs(60));
        let mut rust = by_seq(rust.stop());
        rust.insert(first["header"]["seq"].as_u64().unwrap(), first);
        assert_eq!(py.len(), 400, "{service}");
        let mut same = 0;
        for p in &py {
            let seq = p["header"]["seq"].as_u64().unwrap();
            if let Some(r) = rust.get(&seq) {
                assert_eq!(p, r, "{service} seq {seq} (python wait {wait})");
                same += 1;
            }
        }
        // Both print every sample; a process stalled for longer than its 256-sample buffer
        // (170 ms) on this loaded machine loses some.
        assert!(
            same >= 300,
            "{service}: only {same} of 400 Python samples had a Rust echo of the same seq"
        );
        // The sim publishes valid samples of a simulated arm.
        assert_eq!(py[0]["header"]["valid"], Value::Bool(true), "{service}");
        assert!(
            py[0]["header"]["flags"]
                .as_array()
                .unwrap()
                .contains(&Value::from("SIMULATED")),
            "{service}"
        );
    }
    let (st, log) = serve.terminate();
    assert!(st.success(), "{log}");
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// The matrix is [[R p], [0 0 0 1]] with R a rotation (orthonormal, det +1).
fn assert_rigid(m: &Value, what: &str) {
    let rows: Vec<Vec<f64>> = m.as_array().unwrap().iter().map(floats).collect();
    assert_eq!(rows.len(), 4, "{what}");
    assert!(rows.iter().all(|r| r.len() == 4), "{what}");
    assert_eq!(rows[3], [0.0, 0.0, 0.0, 1.0], "{what}: last row");
    let r = nalgebra::Matrix3::from_fn(|i, j| rows[i][j]);
    let err = (r.transpose() * r - nalgebra::Matrix3::identity())
        .abs()
        .max();
    assert!(err < 1e-9, "{what}: R^T R differs from I by {err}");
    let det = r.determinant();
    assert!((det - 1.0).abs() < 1e-9, "{what}: det R = {det}");
}

/// The 4x4 equals the pose message: rotation rows and position_m.
fn assert_matrix_is_pose(m: &Value, pose: &Value, what: &str) {
    let rows: Vec<Vec<f64>> = m.as_array().unwrap().iter().map(floats).collect();
    let rot: Vec<Vec<f64>> = pose["rotation"]
        .as_array()
        .unwrap()
        .iter()
        .map(floats)
        .collect();
    let p = floats(&pose["position_m"]);
    for i in 0..3 {
        assert_eq!(rows[i][..3], rot[i][..], "{what}: rotation row {i}");
        assert_eq!(rows[i][3], p[i], "{what}: position {i}");
    }
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_arm_reads_what_serve_publishes_with_every_wait_strategy() {
    if !python_client_ready() {
        return;
    }
    let prefix = unique_prefix("pyarm");
    let cfg = write_config("pyarm", "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);
    let compared = [
        "measured_js",
        "jaw/measured_js",
        "compensated/local/measured_cp",
    ];
    let echoes: Vec<LineProc> = compared
        .iter()
        .map(|t| rust_echo(&format!("{prefix}/{t}")))
        .collect();
    for e in &echoes {
        e.first_line(Duration::from_secs(30));
    }
    let probe = repo().join("python/tests/arm_probe.py");
    let mut records = Vec::new();
    // Both clients: the native module (dvrk_sidecar._native) and the pure-Python one.
    for backend in ["native", "pure"] {
        for wait in ["event", "spin", "predictive"] {
            let p = LineProc::spawn(
                "arm_probe",
                &mut python(
                    "pyarm",
                    &[
                        probe.to_str().unwrap(),
                        "cycles",
                        &prefix,
                        wait,
                        "40",
                        "--backend",
                        backend,
                    ],
                ),
            );
            let lines = p.finish(Duration::from_secs(60));
            assert_eq!(lines.len(), 40, "wait {wait}, backend {backend}");
            assert!(lines.iter().all(|l| l["backend"] == backend), "{backend}");
            records.extend(lines);
        }
    }
    let seen: Vec<BTreeMap<u64, Value>> = echoes.into_iter().map(|e| by_seq(e.stop())).collect();
    let (st, log) = serve.terminate();
    assert!(st.success(), "{log}");

    let mut matched = 0;
    let mut total = 0;
    let mut snapshots = 0;
    for rec in &records {
        let wait = rec["wait"].as_str().unwrap();
        assert_rigid(
            &rec["compensated/local/measured_cp"]["matrix"],
            &format!("local/measured_cp ({wait})"),
        );
        assert_rigid(
            &rec["compensated/measured_cp"]["matrix"],
            &format!("measured_cp ({wait})"),
        );
        for (topic, echo) in compared.iter().zip(&seen) {
            let got = &rec[*topic];
            let seq = got["header"]["seq"].as_u64().unwrap();
            total += 1;
            let Some(want) = echo.get(&seq) else { continue };
            matched += 1;
            let what = format!("{topic} seq {seq} (wait {wait})");
            // The header: every field, valid a boolean, flags as names.
            let mut h = got["header"].clone();
            h.as_object_mut().unwrap().remove("stamp");
            assert_eq!(h, want["header"], "{what}: header");
            if topic.ends_with("measured_js") {
                for k in ["position", "velocity", "effort"] {
                    assert_eq!(floats(&got[k]), floats(&want[k]), "{what}: {k}");
                }
            } else {
                assert_matrix_is_pose(&got["matrix"], want, &what);
            }
        }
        // read_cycle: joints and compensated RCM pose of one and the same cycle.
        let snap = &rec["read_cycle"];
        let seq = snap["seq"].as_u64().unwrap();
        if let (Some(js), Some(cp)) = (seen[0].get(&seq), seen[2].get(&seq)) {
            snapshots += 1;
            assert_eq!(
                floats(&snap["position"]),
                floats(&js["position"]),
                "read_cycle seq {seq}"
            );
            assert_matrix_is_pose(&snap["matrix"], cp, &format!("read_cycle seq {seq}"));
        }
        // The stamp is the ROS time of the sample, in seconds.
        let ns = rec["measured_js"]["header"]["sample_realtime_ns"]
            .as_u64()
            .unwrap();
        let stamp = rec["stamp"].as_f64().unwrap();
        assert!(
            (stamp - ns as f64 * 1e-9).abs() < 1e-6,
            "stamp {stamp} vs {ns} ns"
        );
    }
    assert!(
        matched * 10 >= total * 8,
        "only {matched} of {total} Python reads had a Rust echo of the same seq"
    );
    assert!(
        snapshots * 10 >= records.len() * 8,
        "only {snapshots} of {} read_cycle results had Rust echoes of the same seq",
        records.len()
    );
}

// ---------------------------------------------------------------------------------------------
// Invalid samples and silence, in an isolated iceoryx2 domain with a Rust publisher

/// Removes the files of an iceoryx2 domain (shared memory and under the root path).
struct DomainFiles(String);

impl Drop for DomainFiles {
    fn drop(&mut self) {
        fn sweep(dir: &Path, prefix: &str) {
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for e in entries.flatten() {
                let path = e.path();
                if e.file_name().to_string_lossy().starts_with(prefix) {
                    let _ = std::fs::remove_file(&path);
                } else if path.is_dir() {
                    sweep(&path, prefix);
                }
            }
        }
        sweep(Path::new("/dev/shm"), &self.0);
        sweep(Path::new(ROOT), &self.0);
    }
}

fn invalid_cycle(seq: u64) -> CycleMessages {
    let header = Header {
        seq,
        sample_t_ns: dvrk_ipc::monotonic_ns(),
        valid: 0,
        flags: flags::BOARD_TIMEOUT | flags::HELD,
        ..Header::default()
    };
    let mut cycle = CycleMessages::default();
    cycle.set_header(header);
    // The value an InvalidSample carries for whoever wants it anyway.
    cycle.measured.measured_js.position = [0.1, -0.2, 0.15, 0.3, -0.4, 0.5];
    cycle
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_arm_raises_on_invalid_samples_and_names_a_missing_publisher() {
    if !python_client_ready() {
        return;
    }
    let domain = format!("py{}_", std::process::id());
    let _files = DomainFiles(domain.clone());
    let config = domain_config(&domain, Some(ROOT)).unwrap();
    let node = create_node::<Service>("py-client-test", Some(&config)).unwrap();
    let publisher = ArmPublisher::create(&node, &ServiceNames::new("PSM1").unwrap()).unwrap();
    let probe = repo().join("python/tests/arm_probe.py");
    let mut seq = 0;
    for backend in ["native", "pure"] {
        let mut p = LineProc::spawn(
            "arm_probe invalid",
            &mut python(
                "pyinvalid",
                &[
                    probe.to_str().unwrap(),
                    "invalid",
                    "PSM1",
                    "--domain",
                    &domain,
                    "--root",
                    ROOT,
                    "--backend",
                    backend,
                ],
            ),
        );
        // Publish a cycle every millisecond until the probe is done (ports are !Send: this thread).
        let start = Instant::now();
        while p.proc.wait_timeout(Duration::ZERO).is_none() {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "the probe did not finish"
            );
            seq += 1;
            publisher.publish_cycle(&invalid_cycle(seq)).unwrap();
            std::thread::sleep(Duration::from_millis(1));
        }
        let st = p.proc.wait_timeout(Duration::ZERO).unwrap();
        assert!(st.success(), "probe: {}", p.proc.stderr_text());
        let lines = p.json();
        assert_eq!(lines.len(), 1, "{lines:?}");
        let e = &lines[0];
        assert_eq!(e["header"]["valid"], Value::Bool(false));
        assert_eq!(
            e["header"]["flags"],
            serde_json::json!(["BOARD_TIMEOUT", "HELD"])
        );
        assert_eq!(floats(&e["position"]), [0.1, -0.2, 0.15, 0.3, -0.4, 0.5]);
        let msg = e["error"].as_str().unwrap();
        assert!(
            msg.contains("PSM1/measured_js") && msg.contains("BOARD_TIMEOUT, HELD"),
            "{msg}"
        );
    }
    drop(publisher);

    // Nobody publishes in this domain under another arm name: NoSample says so.
    let silent = python(
        "pyinvalid",
        &[
            probe.to_str().unwrap(),
            "silent",
            "PSM2",
            "--domain",
            &domain,
            "--root",
            ROOT,
        ],
    )
    .output()
    .unwrap();
    assert!(
        silent.status.success(),
        "{}",
        String::from_utf8_lossy(&silent.stderr)
    );
    let e: Value = serde_json::from_slice(&silent.stdout).unwrap();
    let msg = e["error"].as_str().unwrap();
    assert!(
        msg.contains("PSM2/measured_js") && msg.contains("no publisher is connected"),
        "{msg}"
    );
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2, numpy and this package: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_native_wait_releases_the_gil() {
    if !python_client_ready() {
        return;
    }
    let domain = format!("pg{}_", std::process::id());
    let _files = DomainFiles(domain.clone());
    let probe = repo().join("python/tests/arm_probe.py");
    let mut counted = BTreeMap::new();
    for backend in ["native", "pure"] {
        let out = python(
            "pygil",
            &[
                probe.to_str().unwrap(),
                "gil",
                "PSM3",
                "--domain",
                &domain,
                "--root",
                ROOT,
                "--backend",
                backend,
            ],
        )
        .output()
        .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["backend"], backend);
        assert!(v["waited_s"].as_f64().unwrap() >= 0.25, "{v}");
        counted.insert(backend, v["counted"].as_u64().unwrap());
    }
    // While the native wait sleeps in compiled code the other thread has the interpreter to
    // itself: it counts at least tens of thousands in 0.3 s (millions on an idle core).
    assert!(counted["native"] > 10_000, "{counted:?}");
}
