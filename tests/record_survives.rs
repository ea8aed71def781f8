//! `dvrk-sidecar record` keeps what it recorded, however the recording ends (issue 22,
//! "Recordings survive their end"):
//! - killed with SIGKILL, the file at its own name reads with the `mcap` package's streaming
//!   reader up to the last closed chunk, at most about a second before the kill;
//! - stopped with SIGTERM, the file has its footer and the seeking reader opens it;
//! - on a full disk (here: a file size limit, the same write error) it stops with a message
//!   naming the file and keeps it, readable up to the last closed chunk;
//! - an existing file, a device node or a symbolic link at `--out` is refused and left as it is.
//!
//! The readers are the `mcap` and `mcap-ros2-support` Python packages (.ci/python-deps); without
//! them the tests show as ignored (build.rs, cfg `has_py_mcap_ros2`), and under CI they run.

mod common;

use std::os::unix::fs::FileTypeExt;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::*;
use serde_json::Value;

/// `dvrk-sidecar record --shm-prefix PREFIX --out OUT`, stderr captured.
fn record_cmd(prefix: &str, out: &Path) -> Command {
    let mut c = Command::new(sidecar_bin());
    c.args(["record", "--prefix", "PSM1", "--shm-prefix", prefix])
        .arg("--out")
        .arg(out)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

/// What tests/bridge/mcap_stream.py reads: the messages, and its last line (how the file ends).
fn stream_read(out: &Path) -> (Vec<Value>, Value) {
    let dec = Command::new("python3")
        .arg(repo().join("tests/bridge/mcap_stream.py"))
        .arg(out)
        .output()
        .unwrap();
    assert!(
        dec.status.success(),
        "the streaming MCAP reader failed on {}: {}",
        out.display(),
        String::from_utf8_lossy(&dec.stderr)
    );
    let mut lines: Vec<Value> = String::from_utf8(dec.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let end = lines.pop().expect("the reader's last line");
    (lines, end)
}

fn realtime_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid timespec.
    assert_eq!(
        unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) },
        0
    );
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

fn python_mcap() {
    let ok = Command::new("python3")
        .args(["-c", "import mcap, mcap_ros2"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "python3 lacks mcap or mcap_ros2: run .ci/python-deps, then touch build.rs"
    );
}

/// Waits until `out` has grown past its header: the recorder is writing.
fn wait_recording(rec: &mut Proc, out: &Path) {
    let started = eventually(Duration::from_secs(30), || {
        (std::fs::metadata(out).is_ok_and(|m| m.len() > 4096)).then_some(())
    });
    if started.is_none() {
        // Stopped first: its stderr reads to the end only once it has exited.
        rec.signal(libc::SIGKILL);
        let st = rec.wait_timeout(Duration::from_secs(10));
        panic!(
            "record wrote nothing to {} within 30 s (status {st:?}): {}",
            out.display(),
            rec.stderr_text()
        );
    }
}

#[cfg_attr(
    not(has_py_mcap_ros2),
    ignore = "needs python3 with mcap and mcap-ros2-support: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn a_killed_or_stopped_recording_reads_to_its_last_chunk() {
    python_mcap();
    let prefix = unique_prefix("record-kill");
    let cfg = write_config("record-kill", "sim", "shared", &prefix, "divot-push.toml");
    let dir = scratch("record-kill");
    let mut serve = serve(&cfg);

    // SIGKILL after a few seconds: every closed chunk reads, by the streaming reader and by
    // the seeking one (`make_reader` on the file), through the interim footer after the last
    // closed chunk. (A kill while a chunk is being written, a few µs a second here, would
    // leave the streaming reader alone; not at this test's moment.)
    // At 100 cycles/s the data fill a chunk of the writer's size only after about 5 s: what is
    // read then comes from the chunks closed by time.
    let killed = dir.join("killed.mcap");
    let mut rec = Proc::spawn(
        "record",
        record_cmd(&prefix, &killed).args(["--rate", "100"]),
    );
    wait_recording(&mut rec, &killed);
    std::thread::sleep(Duration::from_secs(4));
    let kill_ns = realtime_ns();
    rec.signal(libc::SIGKILL);
    rec.wait_timeout(Duration::from_secs(10))
        .expect("record survived SIGKILL");
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.ends_with(".partial")),
        "a hidden partial file beside the recording: {names:?}"
    );
    let (msgs, end) = stream_read(&killed);
    assert_eq!(
        end["end"], "footer",
        "a killed recording ends with the interim footer: {end}"
    );
    assert_eq!(end["seeking"], true, "after SIGKILL: {end}");
    assert_eq!(
        end["seeking_messages"].as_u64(),
        Some(msgs.len() as u64),
        "the seeking reader reads what the streaming one does: {end}"
    );
    assert!(
        msgs.len() > 1000,
        "only {} messages read from a 4 s recording at 100 Hz killed with SIGKILL ({end})",
        msgs.len()
    );
    let last_ns = msgs
        .iter()
        .filter_map(|m| m["log_time"].as_u64())
        .max()
        .unwrap();
    let before_kill_s = (kill_ns as f64 - last_ns as f64) * 1e-9;
    println!(
        "SIGKILL: {} messages read, the last {before_kill_s:.3} s before the kill; {end}",
        msgs.len()
    );
    assert!(
        before_kill_s < 1.5,
        "the last message read is {before_kill_s:.3} s older than the kill: chunks are not \
         closed every second"
    );
    let topics: std::collections::BTreeSet<&str> =
        msgs.iter().filter_map(|m| m["topic"].as_str()).collect();
    assert!(
        topics.contains("/PSM1/compensated/measured_js")
            && topics.contains("/PSM1/compensated/local/measured_cp"),
        "topics read: {topics:?}"
    );

    // SIGTERM: the footer is written, the seeking reader opens it.
    let stopped = dir.join("stopped.mcap");
    let mut rec = Proc::spawn("record", &mut record_cmd(&prefix, &stopped));
    wait_recording(&mut rec, &stopped);
    std::thread::sleep(Duration::from_secs(1));
    let (st, log) = rec.terminate();
    assert!(st.success(), "record exited with {st} on SIGTERM: {log}");
    let (msgs, end) = stream_read(&stopped);
    assert_eq!(end["end"], "footer", "after SIGTERM: {end}");
    assert_eq!(end["seeking"], true, "after SIGTERM: {end}");
    assert!(!msgs.is_empty());

    // An existing recording is never replaced; a device node or a symbolic link is refused.
    let before = std::fs::read(&stopped).unwrap();
    let out = record_cmd(&prefix, &stopped).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "record onto an existing file ran: {err}"
    );
    assert!(
        err.contains(&stopped.display().to_string()) && err.contains("exists"),
        "the refusal names the file and why: {err}"
    );
    assert_eq!(
        std::fs::read(&stopped).unwrap(),
        before,
        "the recording changed"
    );
    let link = dir.join("link.mcap");
    let _ = std::fs::remove_file(&link);
    std::os::unix::fs::symlink(&stopped, &link).unwrap();
    for target in [Path::new("/dev/null"), link.as_path()] {
        let out = record_cmd(&prefix, target).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "record --out {target:?} ran: {err}");
        assert!(
            err.contains(&target.display().to_string()),
            "the refusal names {target:?}: {err}"
        );
    }
    assert!(
        std::fs::symlink_metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device()
    );
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_eq!(std::fs::read(&stopped).unwrap(), before);

    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
}

#[cfg_attr(
    not(has_py_mcap_ros2),
    ignore = "needs python3 with mcap and mcap-ros2-support: bash .ci/python-deps, then touch build.rs"
)]
#[test]
fn a_full_disk_stops_the_recording_and_keeps_it() {
    python_mcap();
    let prefix = unique_prefix("record-full");
    let cfg = write_config("record-full", "sim", "shared", &prefix, "divot-push.toml");
    let out = scratch("record-full").join("full.mcap");
    let mut serve = serve(&cfg);
    // A file size limit gives the same write error as a full disk, without root or a small
    // file system: SIGXFSZ ignored (the disposition survives exec), writes past 3 MB fail.
    let mut cmd = record_cmd(&prefix, &out);
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit {
                rlim_cur: 3_000_000,
                rlim_max: 3_000_000,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut rec = Proc::spawn("record", &mut cmd);
    let st = rec
        .wait_timeout(Duration::from_secs(120))
        .expect("record did not stop on a full disk");
    let log = rec.stderr_text();
    assert!(!st.success(), "record succeeded on a full disk: {log}");
    assert!(
        log.contains(&out.display().to_string()) && log.contains("kept"),
        "the message names the file and says it is kept: {log}"
    );
    let len = std::fs::metadata(&out)
        .unwrap_or_else(|e| panic!("the recording is gone after a full disk ({e}): {log}"))
        .len();
    let (msgs, end) = stream_read(&out);
    println!(
        "full disk: {len} bytes kept, {} messages read; {end}",
        msgs.len()
    );
    assert!(
        msgs.len() > 1000,
        "only {} messages read from {len} bytes kept after a full disk ({end})",
        msgs.len()
    );
    // Cut back to the last closed chunk and its interim footer: the seeking reader opens it.
    assert_eq!(end["end"], "footer", "after a full disk: {end}");
    assert_eq!(end["seeking"], true, "after a full disk: {end}");
    assert_eq!(
        end["seeking_messages"].as_u64(),
        Some(msgs.len() as u64),
        "after a full disk: {end}"
    );
    let (st, log) = serve.terminate();
    assert!(st.success(), "serve exited with {st}: {log}");
}
