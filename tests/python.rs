//! The Python examples (examples/python/, users of the dvrk_sidecar package in python/) against
//! the real `serve`: what they print for a seq must be what a Rust subscriber received for the
//! same seq. subscriber.py prints the raw fields, so its ctypes layouts must match the Rust ones;
//! arm.py prints the crtk-like API's 4x4 pose.

mod common;

use std::collections::BTreeMap;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::*;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{NOMINAL_PERIOD, PoseV2, ServiceNames, Subscription, Topic};
use serde_json::Value;

/// The examples run from a checkout without the package installed (they fall back to
/// python/): subscriber.py needs the iceoryx2 package, arm.py numpy too.
/// The build script saw the modules (or CI requires them): they must import now.
fn require_python(modules: &str) {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "python3 with {modules} is required: python3 -m pip install iceoryx2==0.10.0 numpy \
         (then `touch build.rs` if the test should be ignored instead)"
    );
}

/// Runs the example with `args` against a fresh `serve` while a Rust subscriber records
/// `compensated/local/measured_cp`; returns the example's JSON lines and the Rust samples by seq.
fn run_example(test: &str, script: &str, args: &[&str]) -> (Vec<Value>, BTreeMap<u64, PoseV2>) {
    let prefix = unique_prefix(test);
    let cfg = write_config(test, "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);
    let node = dvrk_ipc::create_node::<Service>("e2e-python", None).unwrap();
    let names = ServiceNames::new(&prefix).unwrap();
    let mut rust = Subscription::<PoseV2, Service>::new(
        &node,
        &names,
        Topic::CompensatedLocalMeasuredCp,
        NOMINAL_PERIOD,
    )
    .unwrap();
    let prefix_flag = if script == "arm.py" {
        "--arm"
    } else {
        "--prefix"
    };
    let mut py = Proc::spawn(
        "python",
        Command::new("python3")
            .arg(repo().join("examples/python").join(script))
            .args([prefix_flag, &prefix])
            .args(args)
            .args(["--count", "20", "--json", "--timeout-s", "30"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    let mut seen = BTreeMap::new();
    let st = loop {
        rust.wait_with(|m| {
            seen.insert(m.header.seq, *m);
        })
        .unwrap();
        if let Some(st) = py.wait_timeout(Duration::from_millis(1)) {
            break st;
        }
    };
    // Drain what is still buffered for the Rust side.
    for _ in 0..10 {
        rust.wait_with(|m| {
            seen.insert(m.header.seq, *m);
        })
        .unwrap();
    }
    let mut out = String::new();
    std::io::Read::read_to_string(
        &mut py.child.as_mut().unwrap().stdout.take().unwrap(),
        &mut out,
    )
    .unwrap();
    assert!(
        st.success(),
        "{script} exited with {st}: {}",
        py.stderr_text()
    );
    let (st, log) = serve.terminate();
    assert!(st.success(), "{log}");
    let lines = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    (lines, seen)
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[cfg_attr(
    not(has_py_iceoryx2),
    ignore = "needs python3 with iceoryx2: python3 -m pip install iceoryx2==0.10.0, then touch build.rs"
)]
#[test]
fn python_subscriber_decodes_what_serve_publishes() {
    require_python("iceoryx2");
    let (lines, seen) = run_example(
        "python",
        "subscriber.py",
        &["--topic", "compensated/local/measured_cp"],
    );
    assert_eq!(lines.len(), 20);
    let mut compared = 0;
    for l in &lines {
        let seq = l["header"]["seq"].as_u64().unwrap();
        let Some(r) = seen.get(&seq) else { continue };
        compared += 1;
        let h = &l["header"];
        assert_eq!(h["sample_t_ns"].as_u64().unwrap(), r.header.sample_t_ns);
        assert_eq!(
            h["sample_realtime_ns"].as_u64().unwrap(),
            r.header.sample_realtime_ns
        );
        assert_eq!(
            h["board_timestamp"].as_u64().unwrap(),
            r.header.board_timestamp
        );
        assert_eq!(h["publish_t_ns"].as_u64().unwrap(), r.header.publish_t_ns);
        assert_eq!(h["valid"].as_u64().unwrap(), u64::from(r.header.valid));
        assert_eq!(h["flags"].as_u64().unwrap(), u64::from(r.header.flags));
        assert_eq!(floats(&l["position_m"]), r.position_m, "seq {seq}");
        assert_eq!(
            floats(&l["orientation_xyzw"]),
            r.orientation_xyzw,
            "seq {seq}"
        );
        assert_eq!(floats(&l["rotation"]), r.rotation, "seq {seq}");
        let names: Vec<&str> = dvrk_ipc::flags::names(r.header.flags).collect();
        assert_eq!(l["flag_names"], serde_json::json!(names), "seq {seq}");
        assert!(names.contains(&"SIMULATED"), "{names:?}");
    }
    assert!(
        compared >= 15,
        "only {compared} of 20 Python samples matched a Rust-side seq"
    );
}

#[cfg_attr(
    not(has_py_dvrk_sidecar),
    ignore = "needs python3 with iceoryx2 and numpy: python3 -m pip install ./python, then touch build.rs"
)]
#[test]
fn python_arm_example_prints_what_serve_publishes() {
    require_python("iceoryx2, numpy");
    let (lines, seen) = run_example("pyarmex", "arm.py", &["--frame", "local"]);
    assert_eq!(lines.len(), 20);
    let mut compared = 0;
    for l in &lines {
        let seq = l["seq"].as_u64().unwrap();
        let Some(r) = seen.get(&seq) else { continue };
        compared += 1;
        assert_eq!(
            l["sample_realtime_ns"].as_u64().unwrap(),
            r.header.sample_realtime_ns,
            "seq {seq}"
        );
        assert_eq!(l["valid"].as_bool().unwrap(), r.header.valid != 0);
        let flags: Vec<&str> = dvrk_ipc::flags::names(r.header.flags).collect();
        assert_eq!(l["flags"], serde_json::json!(flags), "seq {seq}");
        let m: Vec<Vec<f64>> = l["matrix"].as_array().unwrap().iter().map(floats).collect();
        for (i, row) in m.iter().take(3).enumerate() {
            assert_eq!(row[..3], r.rotation[3 * i..3 * i + 3], "seq {seq} row {i}");
            assert_eq!(row[3], r.position_m[i], "seq {seq} position {i}");
        }
        assert_eq!(m[3], [0.0, 0.0, 0.0, 1.0], "seq {seq}");
    }
    assert!(
        compared >= 15,
        "only {compared} of 20 Python samples matched a Rust-side seq"
    );
}
