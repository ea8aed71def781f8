//! The Python example (examples/python/subscriber.py, a user of the dvrk_sidecar package in
//! python/) against the real `serve`: the 4x4 pose it prints for a seq must be the pose a Rust
//! subscriber received for the same seq, with the same stamp, validity and flags.

mod common;

use std::collections::BTreeMap;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::*;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{NOMINAL_PERIOD, PoseV2, ServiceNames, Subscription, Topic};

/// The example runs from a checkout without the package installed (it falls back to python/),
/// so it needs only iceoryx2 and numpy.
fn python_has_deps() -> bool {
    Command::new("python3")
        .args(["-c", "import iceoryx2, numpy"])
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
fn python_example_prints_what_serve_publishes() {
    if !python_has_deps() {
        // CI installs the packages (.ci/run, .ci/python-deps), so there this is a failure.
        assert!(
            std::env::var_os("CI").is_none(),
            "python3 with iceoryx2 and numpy is required in CI: python3 -m pip install iceoryx2==0.10.0 numpy"
        );
        eprintln!("skipped: python3 -m pip install iceoryx2==0.10.0 numpy to run this test");
        return;
    }
    let prefix = unique_prefix("python");
    let cfg = write_config("python", "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = serve(&cfg);

    // A Rust subscriber in this process records the same topic by seq.
    let node = dvrk_ipc::create_node::<Service>("e2e-python", None).unwrap();
    let names = ServiceNames::new(&prefix).unwrap();
    let mut rust = Subscription::<PoseV2, Service>::new(
        &node,
        &names,
        Topic::CompensatedLocalMeasuredCp,
        NOMINAL_PERIOD,
    )
    .unwrap();

    let mut py = Proc::spawn(
        "python",
        Command::new("python3")
            .arg(repo().join("examples/python/subscriber.py"))
            .args([
                "--arm",
                &prefix,
                "--count",
                "20",
                "--json",
                "--timeout-s",
                "30",
            ])
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
        "python exited with {st}: {}",
        py.stderr_text()
    );
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
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
        let m: Vec<Vec<f64>> = l["matrix"]
            .as_array()
            .unwrap()
            .iter()
            .map(|row| {
                row.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            })
            .collect();
        for i in 0..3 {
            assert_eq!(m[i][..3], r.rotation[3 * i..3 * i + 3], "seq {seq} row {i}");
            assert_eq!(m[i][3], r.position_m[i], "seq {seq} position {i}");
        }
        assert_eq!(m[3], [0.0, 0.0, 0.0, 1.0], "seq {seq}");
        assert!(flags.contains(&"SIMULATED"), "{flags:?}");
    }
    assert!(
        compared >= 15,
        "only {compared} of 20 Python samples matched a Rust-side seq"
    );
    let (st, log) = serve.terminate();
    assert!(st.success(), "{log}");
}
