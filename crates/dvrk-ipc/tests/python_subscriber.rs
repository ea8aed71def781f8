//! examples/python/subscriber.py (iceoryx2 PyPI package + ctypes) decodes what `ArmPublisher`
//! sends, field by field. Skipped with a printed reason when `python3` or the `iceoryx2` package
//! (`python3 -m pip install iceoryx2==0.10.0`) is missing.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::Domain;
use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{ArmPublisher, CycleMessages, Header, PoseV2, Topic, create_node, flags};

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/python/subscriber.py")
}

fn python_with_iceoryx2() -> Result<(), String> {
    let out = Command::new("python3")
        .args([
            "-c",
            "import iceoryx2, importlib.metadata as m; print(m.version('iceoryx2'))",
        ])
        .output()
        .map_err(|e| format!("python3 not runnable: {e}"))?;
    if !out.status.success() {
        return Err("the python package iceoryx2 is not installed".into());
    }
    let version = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    if version != "0.10.0" {
        return Err(format!("python iceoryx2 is {version}, not 0.10.0"));
    }
    Ok(())
}

fn pose(seq: u64) -> PoseV2 {
    let s = seq as f64;
    PoseV2 {
        header: Header {
            seq,
            sample_t_ns: 10 * seq,
            sample_realtime_ns: 1_700_000_000_000_000_000 + 7 * seq,
            board_timestamp: Header::pack_board_timestamps([seq as u32, 99]),
            publish_t_ns: 10 * seq + 3,
            valid: (seq % 2) as u32,
            flags: flags::SIMULATED | flags::INSERTION_CLAMPED,
        },
        position_m: [s * 0.001, -s * 0.002, 0.125],
        orientation_xyzw: [0.1, 0.2, 0.3, 0.9],
        rotation: core::array::from_fn(|i| i as f64 + s),
    }
}

#[test]
fn python_subscriber_decodes_the_compensated_pose() {
    if let Err(reason) = python_with_iceoryx2() {
        common::skip_unless_ci(&reason);
        return;
    }
    let d = Domain::new("python");
    let node = create_node::<ipc::Service>("py_pub", Some(&d.config)).unwrap();
    let publisher = ArmPublisher::create(&node, &d.names).unwrap();
    const COUNT: usize = 5;
    let mut child = Command::new("python3")
        .arg(script())
        .args(["--prefix", d.names.prefix()])
        .args(["--count", &COUNT.to_string(), "--json"])
        .args(["--domain", &d.domain_prefix, "--root", common::ROOT])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn python3");
    let mut subscribed = false;
    for _ in 0..20_000 {
        if publisher.number_of_subscribers(Topic::CompensatedMeasuredCp) == 1 {
            subscribed = true;
            break;
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(subscribed, "the Python subscriber never connected");
    // Publish until the script has printed COUNT samples and exited.
    let mut seq = 0;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(seq < 10_000, "the Python subscriber did not finish");
        seq += 1;
        let cp = pose(seq);
        let mut cycle = CycleMessages::default();
        cycle.set_header(cp.header);
        // The raw poses differ, so a script reading the wrong topic would fail the checks.
        let raw = PoseV2 {
            position_m: [9.0; 3],
            ..cp
        };
        cycle.measured.local_measured_cp = raw;
        cycle.measured.measured_cp = raw;
        cycle.compensated.local_measured_cp = cp;
        cycle.compensated.measured_cp = cp;
        publisher.publish_cycle(&cycle).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(status.success(), "subscriber.py exited with {status}");
    let lines: Vec<serde_json::Value> = BufReader::new(child.stdout.take().unwrap())
        .lines()
        .map(|l| serde_json::from_str(&l.unwrap()).expect("one JSON object per line"))
        .collect();
    assert_eq!(lines.len(), COUNT);
    let mut last_seq = 0;
    for v in &lines {
        let seq = v["header"]["seq"].as_u64().unwrap();
        assert!(seq > last_seq, "increasing seq");
        last_seq = seq;
        // Every field equals what was published on compensated/measured_cp for that seq.
        let want = pose(seq);
        let h = &v["header"];
        assert_eq!(h["sample_t_ns"], want.header.sample_t_ns);
        assert_eq!(h["board_timestamp"], want.header.board_timestamp);
        assert_eq!(h["publish_t_ns"], want.header.publish_t_ns);
        assert_eq!(h["valid"], want.header.valid);
        assert_eq!(h["flags"], want.header.flags);
        let floats = |k: &str| -> Vec<f64> {
            v[k].as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        assert_eq!(floats("position_m"), want.position_m);
        assert_eq!(floats("orientation_xyzw"), want.orientation_xyzw);
        assert_eq!(floats("rotation"), want.rotation);
        assert_eq!(
            v["flag_names"],
            serde_json::json!(["INSERTION_CLAMPED", "SIMULATED"])
        );
        assert_eq!(
            v["topic"],
            format!("{}/compensated/measured_cp", d.names.prefix())
        );
    }
}

#[test]
fn python_subscriber_waits_every_way() {
    if let Err(reason) = python_with_iceoryx2() {
        common::skip_unless_ci(&reason);
        return;
    }
    for wait in ["event", "spin", "predictive"] {
        let d = Domain::new(&format!("python_{wait}"));
        let node = create_node::<ipc::Service>("py_pub", Some(&d.config)).unwrap();
        let publisher = ArmPublisher::create(&node, &d.names).unwrap();
        const COUNT: usize = 100;
        let mut child = Command::new("python3")
            .arg(script())
            .args(["--prefix", d.names.prefix(), "--wait", wait])
            .args(["--count", &COUNT.to_string(), "--json"])
            .args(["--domain", &d.domain_prefix, "--root", common::ROOT])
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn python3");
        let mut subscribed = false;
        let listeners = usize::from(wait != "spin");
        for _ in 0..20_000 {
            // The script creates its listener (if any) right after its subscriber.
            if publisher.number_of_subscribers(Topic::CompensatedMeasuredCp) == 1
                && publisher.subscriber_counts().cycle_listeners == listeners
            {
                subscribed = true;
                break;
            }
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(subscribed, "{wait}: the Python subscriber never connected");
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(
            publisher.subscriber_counts().cycle_listeners,
            usize::from(wait != "spin"),
            "{wait}: only the spinning subscriber has no listener"
        );
        // Publish on a 1 ms grid with real publish times, as the sidecar does.
        let t0 = dvrk_ipc::monotonic_ns();
        let mut seq = 0;
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break status;
            }
            assert!(seq < 20_000, "{wait}: the Python subscriber did not finish");
            seq += 1;
            while dvrk_ipc::monotonic_ns() < t0 + seq * 1_000_000 {
                std::thread::sleep(Duration::from_micros(200));
            }
            let mut cp = pose(seq);
            cp.header.publish_t_ns = dvrk_ipc::monotonic_ns();
            let mut cycle = CycleMessages::default();
            cycle.set_header(cp.header);
            cycle.compensated.local_measured_cp = cp;
            cycle.compensated.measured_cp = cp;
            publisher.publish_cycle(&cycle).unwrap();
        };
        assert!(
            status.success(),
            "{wait}: subscriber.py exited with {status}"
        );
        let seqs: Vec<u64> = BufReader::new(child.stdout.take().unwrap())
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(&l.unwrap()).unwrap();
                v["header"]["seq"].as_u64().unwrap()
            })
            .collect();
        assert_eq!(seqs.len(), COUNT, "{wait}");
        assert!(
            seqs.windows(2).all(|w| w[0] < w[1]),
            "{wait}: increasing seq {seqs:?}"
        );
    }
}
