//! `echo SERVICE`: prints samples of one of the sidecar's services, like `ros2 topic echo`.

use anyhow::{Context, Result, bail};
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    CompensationStatusV2, Header, JOINT_NAMES, JointStateV1, Message, NOMINAL_PERIOD, PoseV1,
    ServiceNames, Subscription, Topic,
};
use serde_json::{Value, json};

use crate::signals::StopFlag;

#[derive(clap::Args)]
pub struct EchoArgs {
    /// Full service name, e.g. dvrk/PSM1/compensated/measured_cp.
    service: String,
    /// Stop after this many samples (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &EchoArgs) -> Result<()> {
    let Some((prefix, topic)) = ServiceNames::split(&args.service) else {
        bail!(
            "\"{}\" is not a dvrk-sidecar service; expected <prefix>/<topic> with topic one of: {}",
            args.service,
            Topic::ALL
                .iter()
                .map(|t| t.suffix())
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    let names = ServiceNames::new(prefix).map_err(|e| anyhow::anyhow!("{}: {e}", args.service))?;
    let stop = StopFlag::install()?;
    let node = dvrk_ipc::create_node::<Service>("dvrk-sidecar-echo", None)
        .context("creating the iceoryx2 node")?;
    match topic {
        Topic::MeasuredJs | Topic::CompensatedMeasuredJs => {
            echo::<JointStateV1>(&node, &names, topic, args, &stop, joint_json, joint_text)
        }
        Topic::MeasuredCp | Topic::CompensatedMeasuredCp => {
            echo::<PoseV1>(&node, &names, topic, args, &stop, pose_json, pose_text)
        }
        Topic::CompensatedStatus => echo::<CompensationStatusV2>(
            &node,
            &names,
            topic,
            args,
            &stop,
            status_json,
            status_text,
        ),
    }
}

fn echo<T: Message>(
    node: &dvrk_ipc::iceoryx2::node::Node<Service>,
    names: &ServiceNames,
    topic: Topic,
    args: &EchoArgs,
    stop: &StopFlag,
    to_json: fn(&T) -> Value,
    to_text: fn(&T) -> String,
) -> Result<()> {
    let mut sub = Subscription::<T, Service>::new(node, names, topic, NOMINAL_PERIOD)
        .with_context(|| format!("subscribing to {}", names.topic(topic).as_str()))?;
    let mut printed = 0u64;
    let mut silence = crate::watch::SilenceReporter::default();
    let limit = args.count.unwrap_or(u64::MAX);
    while !stop.raised() && printed < limit {
        // Every drained sample is printed, oldest first, so no seq is skipped when this
        // process wakes up late.
        let update = sub
            .wait_with(|msg| {
                if printed < limit {
                    if args.json {
                        println!("{}", to_json(msg));
                    } else {
                        println!("{}", to_text(msg));
                    }
                    printed += 1;
                }
            })
            .context("waiting for samples")?;
        silence.report(&update, names.topic(topic).as_str());
    }
    Ok(())
}

fn header_json(h: &Header) -> Value {
    json!({
        "seq": h.seq,
        "sample_t_ns": h.sample_t_ns,
        "publish_t_ns": h.publish_t_ns,
        "board_timestamp": h.board_timestamp,
        "valid": h.valid != 0,
        "flags": dvrk_ipc::flags::names(h.flags).collect::<Vec<_>>(),
    })
}

fn header_text(h: &Header) -> String {
    let f: Vec<&str> = dvrk_ipc::flags::names(h.flags).collect();
    format!(
        "seq {} t {:.6} s valid {} flags [{}]",
        h.seq,
        h.sample_t_ns as f64 * 1e-9,
        h.valid,
        f.join(" ")
    )
}

fn joint_json(m: &JointStateV1) -> Value {
    json!({ "header": header_json(&m.header), "name": JOINT_NAMES, "position": m.position,
            "velocity": m.velocity, "effort": m.effort })
}

fn joint_text(m: &JointStateV1) -> String {
    let mut s = header_text(&m.header);
    for (i, name) in JOINT_NAMES.iter().enumerate() {
        s.push_str(&format!(
            "\n  {name:<12} position {:+.6}  velocity {:+.6}  effort {:+.4}",
            m.position[i], m.velocity[i], m.effort[i]
        ));
    }
    s
}

fn pose_json(m: &PoseV1) -> Value {
    json!({ "header": header_json(&m.header), "position_m": m.position_m,
            "orientation_xyzw": m.orientation_xyzw, "rotation": m.rotation })
}

fn pose_text(m: &PoseV1) -> String {
    let p = m.position_m;
    let r = m.rotation;
    format!(
        "{}\n  position_m [{:+.6}, {:+.6}, {:+.6}]\n  rotation   [{:+.5}, {:+.5}, {:+.5}; {:+.5}, {:+.5}, {:+.5}; {:+.5}, {:+.5}, {:+.5}]",
        header_text(&m.header),
        p[0],
        p[1],
        p[2],
        r[0],
        r[1],
        r[2],
        r[3],
        r[4],
        r[5],
        r[6],
        r[7],
        r[8]
    )
}

fn status_json(m: &CompensationStatusV2) -> Value {
    json!({ "header": header_json(&m.header), "tau_ext_nm": m.tau_ext_nm, "delta_rad": m.delta_rad,
            "insertion_m": m.insertion_m, "cycle_period_ns": m.cycle_period_ns,
            "cycle_duration_ns": m.cycle_duration_ns, "cycles_total": m.cycles_total,
            "read_failures_total": m.read_failures_total, "overruns_total": m.overruns_total,
            "consecutive_read_failures": m.consecutive_read_failures })
}

fn status_text(m: &CompensationStatusV2) -> String {
    format!(
        "{}\n  tau_ext_nm [{:+.4}, {:+.4}]  delta_rad [{:+.6}, {:+.6}]  insertion_m {:.4}\n  cycle period {:.1} us, duration {:.1} us, read failures {}",
        header_text(&m.header),
        m.tau_ext_nm[0],
        m.tau_ext_nm[1],
        m.delta_rad[0],
        m.delta_rad[1],
        m.insertion_m,
        m.cycle_period_ns as f64 / 1e3,
        m.cycle_duration_ns as f64 / 1e3,
        m.read_failures_total
    )
}
