//! A synthetic arm publisher for trying consumers (the Python subscriber, `echo`, C/C++ code)
//! without the sidecar: it publishes all nine topics and the cycle event like `serve` does, with
//! made-up joint motion.
//!
//! ```text
//! cargo run -p dvrk-ipc --example publisher -- [--prefix PSM1] [--rate-hz 200]
//!     [--count 0 (forever)] [--domain PREFIX --root /tmp/iox2t/] [--wait-subscribers N]
//! ```
//! `--domain`/`--root` select an isolated iceoryx2 domain (see `dvrk_ipc::domain_config`);
//! `--wait-subscribers N` waits until N subscribers are connected to
//! `compensated/local/measured_cp` before the first cycle.

use std::time::Duration;

use dvrk_ipc::iceoryx2::service::ipc;
use dvrk_ipc::{
    ArmPublisher, ArmState, CompensationStatusV4, CycleMessages, Header, JawStateV1, JointStateV2,
    PoseV2, ServiceNames, Topic, create_node, domain_config, flags, monotonic_ns,
};

struct Args {
    prefix: String,
    rate_hz: f64,
    count: u64,
    domain: Option<String>,
    root: Option<String>,
    wait_subscribers: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        prefix: dvrk_ipc::DEFAULT_PREFIX.to_owned(),
        rate_hz: 200.0,
        count: 0,
        domain: None,
        root: None,
        wait_subscribers: 0,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--prefix" => a.prefix = value()?,
            "--rate-hz" => a.rate_hz = value()?.parse().map_err(|e| format!("--rate-hz: {e}"))?,
            "--count" => a.count = value()?.parse().map_err(|e| format!("--count: {e}"))?,
            "--domain" => a.domain = Some(value()?),
            "--root" => a.root = Some(value()?),
            "--wait-subscribers" => {
                a.wait_subscribers = value()?
                    .parse()
                    .map_err(|e| format!("--wait-subscribers: {e}"))?
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if !(a.rate_hz > 0.0 && a.rate_hz <= 100_000.0) {
        return Err(format!("--rate-hz {} out of (0, 100000]", a.rate_hz));
    }
    Ok(a)
}

/// Rotation about z by `a` rad as (row-major matrix, quaternion xyzw).
fn rot_z(a: f64) -> ([f64; 9], [f64; 4]) {
    let (s, c) = a.sin_cos();
    let (hs, hc) = (a / 2.0).sin_cos();
    ([c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0], [0.0, 0.0, hs, hc])
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    let config = match &args.domain {
        Some(d) => Some(domain_config(d, args.root.as_deref())?),
        None => None,
    };
    let node = create_node::<ipc::Service>("example_publisher", config.as_ref())?;
    let names = ServiceNames::new(&args.prefix)?;
    let publisher = ArmPublisher::create(&node, &names)?;
    while publisher.number_of_subscribers(Topic::CompensatedLocalMeasuredCp) < args.wait_subscribers
    {
        std::thread::sleep(Duration::from_millis(1));
    }
    eprintln!("publishing under {} at {} Hz", names.prefix(), args.rate_hz);
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let period_ns = period.as_nanos() as u64;
    let mut seq = 0u64;
    let mut next = std::time::Instant::now();
    let mut last_sample_t_ns = 0u64;
    while args.count == 0 || seq < args.count {
        seq += 1;
        let t = seq as f64 / args.rate_hz;
        let sample_t_ns = monotonic_ns();
        let mut header = Header {
            seq,
            sample_t_ns,
            sample_realtime_ns: dvrk_ipc::clock::realtime_at(sample_t_ns),
            board_timestamp: Header::pack_board_timestamps([seq as u32, seq as u32]),
            publish_t_ns: 0,
            valid: 1,
            flags: flags::SIMULATED,
        };
        let q = [
            0.3 * (0.5 * t).sin(),
            0.2 * (0.3 * t).cos(),
            0.12 + 0.02 * (0.2 * t).sin(),
            0.1 * t.sin(),
            0.0,
            0.0,
        ];
        let jaw = JawStateV1 {
            header,
            position: 0.2,
            velocity: 0.0,
            effort: 0.0,
        };
        let delta = [0.004 * (0.5 * t).cos(), -0.003];
        let mut qc = q;
        qc[0] -= delta[0];
        qc[1] -= delta[1];
        if delta[0].abs() > 0.001 {
            header.flags |= flags::CORRECTION_ACTIVE_J1;
        }
        header.flags |= flags::CORRECTION_ACTIVE_J2;
        header.publish_t_ns = monotonic_ns();
        let js = JointStateV2 {
            header,
            position: q,
            velocity: [0.0; 6],
            effort: [0.05, -0.08, 0.5, 0.0, 0.0, 0.0],
        };
        let cjs = JointStateV2 { position: qc, ..js };
        // A crude "tip": insertion along a direction set by yaw and pitch (not PSM kinematics).
        let tip = |q: &[f64; 6]| -> PoseV2 {
            let (rotation, orientation_xyzw) = rot_z(q[3]);
            PoseV2 {
                header,
                position_m: [
                    q[2] * q[0].sin(),
                    -q[2] * q[1].sin(),
                    -q[2] * q[0].cos() * q[1].cos(),
                ],
                orientation_xyzw,
                rotation,
            }
        };
        let status = CompensationStatusV4 {
            header,
            tau_ext_nm: [0.05, -0.08],
            delta_rad: delta,
            insertion_m: q[2],
            cycle_period_ns: if last_sample_t_ns == 0 {
                period_ns
            } else {
                sample_t_ns - last_sample_t_ns
            },
            cycle_duration_ns: 0,
            cycles_total: seq,
            read_failures_total: 0,
            overruns_total: 0,
            consecutive_read_failures: 0,
            ..Default::default()
        };
        last_sample_t_ns = sample_t_ns;
        // The example's base frame is the identity: measured_cp equals local/measured_cp.
        let cycle = CycleMessages {
            measured: ArmState {
                measured_js: js,
                jaw_measured_js: jaw,
                local_measured_cp: tip(&q),
                measured_cp: tip(&q),
            },
            compensated: ArmState {
                measured_js: cjs,
                jaw_measured_js: jaw,
                local_measured_cp: tip(&qc),
                measured_cp: tip(&qc),
            },
            status,
        };
        publisher.publish_cycle(&cycle)?;
        next += period;
        let now = std::time::Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    eprintln!("published {seq} cycles");
    Ok(())
}
