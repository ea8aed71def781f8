//! `echo SERVICE`: prints samples of one of the sidecar's services, like `ros2 topic echo`.

use anyhow::{Context, Result, bail};
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    CompensationStatusV4, Header, JAW_NAME, JOINT_NAMES, JawStateV1, JointStateV2, Message,
    NOMINAL_PERIOD, PoseV2, ServiceNames, SubscribeOptions, Subscription, Topic, Update,
    WaitStrategy,
};
use serde_json::Value;

use crate::shape;

use crate::signals::StopFlag;

#[derive(clap::Args)]
pub struct EchoArgs {
    /// Service name as the dVRK names the topic: `PSM1/measured_js`, `/PSM1/local/measured_cp`,
    /// `PSM1/compensated/measured_cp`, ...; or a bare topic (`local/measured_cp`) under --prefix.
    service: String,
    /// Prefix of a bare topic name (the arm's name).
    #[arg(long, default_value = dvrk_ipc::DEFAULT_PREFIX)]
    prefix: String,
    /// Stop after this many samples (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
    /// How to wait for samples: event (sleep until the publisher notifies), spin (poll, one
    /// whole core) or predictive (sleep until just before the next sample is due, then poll).
    #[arg(long, default_value = "event", value_parser = parse_wait)]
    wait: WaitStrategy,
}

fn parse_wait(s: &str) -> Result<WaitStrategy, String> {
    s.parse()
        .map_err(|e: dvrk_ipc::UnknownWaitStrategy| e.to_string())
}

/// The prefix and topic named by `service` (see [`EchoArgs`]).
fn resolve(service: &str, default_prefix: &str) -> Result<(String, Topic)> {
    if let Some(topic) = Topic::from_suffix(service.trim_start_matches('/')) {
        return Ok((default_prefix.to_owned(), topic));
    }
    let Some((prefix, topic)) = ServiceNames::split(service) else {
        bail!(
            "\"{service}\" is not a dvrk-sidecar service; expected <prefix>/<topic> (e.g. \
             PSM1/measured_js) with topic one of: {}",
            Topic::ALL
                .iter()
                .map(|t| t.suffix())
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    Ok((prefix.to_owned(), topic))
}

pub fn run(args: &EchoArgs) -> Result<()> {
    let (prefix, topic) = resolve(&args.service, &args.prefix)?;
    let names = ServiceNames::new(&prefix).map_err(|e| anyhow::anyhow!("{}: {e}", args.service))?;
    let stop = StopFlag::install()?;
    let node = dvrk_ipc::create_node::<Service>("dvrk-sidecar-echo", None)
        .context("creating the iceoryx2 node")?;
    match topic {
        Topic::MeasuredJs | Topic::CompensatedMeasuredJs => echo::<JointStateV2>(
            &node,
            &names,
            topic,
            args,
            &stop,
            shape::joint_state,
            joint_text,
        ),
        Topic::JawMeasuredJs | Topic::CompensatedJawMeasuredJs => echo::<JawStateV1>(
            &node,
            &names,
            topic,
            args,
            &stop,
            shape::jaw_state,
            jaw_text,
        ),
        Topic::LocalMeasuredCp
        | Topic::MeasuredCp
        | Topic::CompensatedLocalMeasuredCp
        | Topic::CompensatedMeasuredCp => {
            echo::<PoseV2>(&node, &names, topic, args, &stop, shape::pose, pose_text)
        }
        Topic::CompensatedStatus => echo::<CompensationStatusV4>(
            &node,
            &names,
            topic,
            args,
            &stop,
            shape::status,
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
    to_json: fn(&str, &T) -> Value,
    to_text: fn(&T) -> String,
) -> Result<()> {
    let options = SubscribeOptions {
        period: NOMINAL_PERIOD,
        wait: args.wait,
        deadline: None,
        ..SubscribeOptions::default()
    };
    let mut sub = Subscription::<T, Service>::with_options(node, names, topic, options)
        .with_context(|| format!("subscribing to {}", names.topic(topic).as_str()))?;
    let mut printed = 0u64;
    let mut silence = crate::watch::SilenceReporter::for_domain(node.config());
    let mut gone = false;
    let limit = args.count.unwrap_or(u64::MAX);
    let mut out = std::io::stdout().lock();
    let mut write_error: Option<anyhow::Error> = None;
    while !stop.raised() && printed < limit {
        // Every drained sample is printed, oldest first, so no seq is skipped when this
        // process wakes up late.
        let update = sub
            .wait_with(|msg| {
                if printed < limit && write_error.is_none() {
                    let written = if args.json {
                        crate::outln!(out, "{}", to_json(names.topic(topic).as_str(), msg))
                    } else {
                        crate::outln!(out, "{}", to_text(msg))
                    };
                    match written {
                        Ok(()) => printed += 1,
                        Err(e) => write_error = Some(e),
                    }
                }
            })
            .context("waiting for samples")?;
        // A reader that closed stdout (`| head -1`) ends echo (main exits 0).
        if let Some(e) = write_error.take() {
            return Err(e);
        }
        // A publisher that stopped or died is said once, in one line; echo then keeps waiting
        // for a new one (like `ros2 topic echo`), until Ctrl-C or --count.
        match update {
            Update::Terminated if !gone => {
                eprintln!(
                    "publisher of {} is gone; waiting for a new one (Ctrl-C to stop)",
                    sub.service_name()
                );
                gone = true;
            }
            Update::Terminated => {}
            Update::Fresh(_) if gone => {
                eprintln!("a publisher of {} is back", sub.service_name());
                gone = false;
            }
            other => silence.report(&other, names.topic(topic).as_str()),
        }
    }
    Ok(())
}

fn header_text(h: &Header) -> String {
    let f: Vec<&str> = dvrk_ipc::flags::names(h.flags).collect();
    format!(
        "seq {} t {:.6} s (ros {:.6} s) valid {} flags [{}]",
        h.seq,
        h.sample_t_ns as f64 * 1e-9,
        h.sample_realtime_ns as f64 * 1e-9,
        h.valid,
        f.join(" ")
    )
}

fn jaw_text(m: &JawStateV1) -> String {
    format!(
        "{}\n  {JAW_NAME:<12} position {:+.6}  velocity {:+.6}  effort {:+.4}",
        header_text(&m.header),
        m.position,
        m.velocity,
        m.effort
    )
}

fn joint_text(m: &JointStateV2) -> String {
    let mut s = header_text(&m.header);
    for (i, name) in JOINT_NAMES.iter().enumerate() {
        s.push_str(&format!(
            "\n  {name:<12} position {:+.6}  velocity {:+.6}  effort {:+.4}",
            m.position[i], m.velocity[i], m.effort[i]
        ));
    }
    s
}

fn pose_text(m: &PoseV2) -> String {
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

fn status_text(m: &CompensationStatusV4) -> String {
    format!(
        "{}\n  tau_ext_nm [{:+.4}, {:+.4}]  delta_rad [{:+.6}, {:+.6}]  insertion_m {:.4}\n  cycle period {:.1} us, duration {:.1} us, started {:.1} us late, read failures {}",
        header_text(&m.header),
        m.tau_ext_nm[0],
        m.tau_ext_nm[1],
        m.delta_rad[0],
        m.delta_rad[1],
        m.insertion_m,
        m.cycle_period_ns as f64 / 1e3,
        m.cycle_duration_ns as f64 / 1e3,
        m.publish_late_ns as f64 / 1e3,
        m.read_failures_total
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn services_resolve_as_a_dvrk_user_types_them() {
        let r = |s: &str| resolve(s, "PSM1").unwrap();
        assert_eq!(r("PSM1/measured_js"), ("PSM1".into(), Topic::MeasuredJs));
        assert_eq!(r("/PSM1/measured_js"), ("PSM1".into(), Topic::MeasuredJs));
        assert_eq!(
            r("PSM2/jaw/measured_js"),
            ("PSM2".into(), Topic::JawMeasuredJs)
        );
        assert_eq!(
            r("local/measured_cp"),
            ("PSM1".into(), Topic::LocalMeasuredCp)
        );
        assert_eq!(
            r("/PSM1/compensated/local/measured_cp"),
            ("PSM1".into(), Topic::CompensatedLocalMeasuredCp)
        );
        let e = resolve("PSM1/setpoint_js", "PSM1").unwrap_err().to_string();
        assert!(
            e.contains("PSM1/setpoint_js") && e.contains("jaw/measured_js"),
            "{e}"
        );
    }
}
