//! `ros2-bridge` and `record`: consumers of the shared memory that carry the compensated topics
//! to ROS 2 (DDS) and to MCAP files. The work is in the dvrk-bridge crate; this is the CLI.
//!
//! Both serve every arm of a service in one process (`--config`, the service's configuration),
//! or one arm (`--prefix`).
//!
//! The argument structs' doc comments are clap's `--help` text, which names placeholders the
//! command-line way (`<ARM>`); rustdoc would read those as HTML tags.
#![allow(rustdoc::invalid_html_tags)]

use std::net::IpAddr;
use std::path::PathBuf;

use anyhow::{Context, Result};
use dvrk_bridge::{ArmReport, ArmSpec, DdsOptions, QosProfile, Rate, RecordOptions, SourceOptions};

use crate::signals::StopFlag;

#[derive(clap::Args, Debug)]
pub struct ArmArgs {
    /// The service's configuration (the file `serve --config` runs): carry every arm it serves,
    /// its `prefix` or each [[arm]]'s `name` (ROS namespace: the name's last '/' segment).
    #[arg(long, conflicts_with_all = ["prefix", "shm_prefix", "base_frame_id"])]
    config: Option<PathBuf>,
    /// One arm, by name: the ROS namespace and frame names (topics /<ARM>/compensated/...).
    /// Default without --config: PSM1.
    #[arg(long)]
    prefix: Option<String>,
    /// With --prefix: shared-memory prefix of the running `serve` (default: <ARM>, as `serve`
    /// names it).
    #[arg(long)]
    shm_prefix: Option<String>,
    /// With --prefix: frame id of measured_cp, the reference frame of the arm's base frame in
    /// the console's configuration (e.g. ECM). Default: <ARM>_base.
    #[arg(long)]
    base_frame_id: Option<String>,
}

impl ArmArgs {
    fn arms(&self) -> Result<Vec<ArmSpec>> {
        match &self.config {
            Some(path) => {
                let names = crate::config::arm_names(path)?;
                names
                    .iter()
                    .map(|n| {
                        ArmSpec::from_service_prefix(n)
                            .with_context(|| format!("{}: arm \"{n}\"", path.display()))
                    })
                    .collect()
            }
            None => Ok(vec![ArmSpec::new(
                self.prefix.as_deref().unwrap_or("PSM1"),
                self.shm_prefix.as_deref(),
                self.base_frame_id.as_deref(),
            )?]),
        }
    }
}

fn rate(s: &str) -> Result<Rate, String> {
    s.parse::<Rate>().map_err(|e| e.to_string())
}

#[derive(clap::Args, Debug)]
pub struct Ros2BridgeArgs {
    #[command(flatten)]
    arms: ArmArgs,
    /// Cycles per second published on each topic, or `all` for every cycle of the sidecar
    /// (1.5 kHz). The default is the console's own rate, which rqt, rviz and ros2 bag keep up with.
    #[arg(long, default_value = "100", value_parser = rate)]
    rate: Rate,
    /// DDS domain id, 0-232. Default: ROS_DOMAIN_ID (0 when unset), as ROS 2 does.
    #[arg(long, value_parser = clap::value_parser!(u16).range(0..=232))]
    domain: Option<u16>,
    /// Use only the network interface with this address (repeatable), e.g. 127.0.0.1 to stay on
    /// this host. Default: all interfaces.
    #[arg(long = "interface")]
    interfaces: Vec<IpAddr>,
    /// BEST_EFFORT instead of RELIABLE (for sensor-data subscribers on a lossy network). A
    /// RELIABLE subscriber (ROS 2's default) then receives nothing; the log says so.
    #[arg(long, conflicts_with = "reliable")]
    best_effort: bool,
    /// RELIABLE: the default (kept for command lines written when best effort was).
    #[arg(long)]
    reliable: bool,
}

#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    #[command(flatten)]
    arms: ArmArgs,
    /// Cycles per second recorded on each topic (e.g. 100), or `all`: every cycle, the default.
    #[arg(long, default_value = "all", value_parser = rate)]
    rate: Rate,
    /// MCAP file to write; it must not exist.
    #[arg(long)]
    out: PathBuf,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Record only the compensated topics (by default the uncompensated ones are recorded too,
    /// as /<ARM>/measured_js, /<ARM>/local/measured_cp, ...).
    #[arg(long)]
    compensated_only: bool,
}

fn log_reports(what: &str, reports: &[ArmReport], unit: &str) {
    for r in reports {
        tracing::info!(
            "{what} stopped: {}: {} cycles, {} {unit} written, {} invalid skipped, {} decimated, {} dropped for slow reliable readers, {} lost in shared memory",
            r.arm,
            r.stats.cycles,
            r.written,
            r.stats.invalid_skipped,
            r.stats.decimated,
            r.dropped,
            r.stats.shm_seq_gaps
        );
    }
}

pub fn run_ros2_bridge(args: &Ros2BridgeArgs) -> Result<()> {
    let src = SourceOptions {
        arms: args.arms.arms()?,
        rate: args.rate,
    };
    let domain = match args.domain {
        Some(d) => d,
        None => dvrk_bridge::console::ros_domain_id()?,
    };
    let stop = StopFlag::install()?;
    let dds = DdsOptions {
        domain,
        interfaces: args.interfaces.clone(),
        qos: if args.best_effort {
            QosProfile::BestEffort
        } else {
            QosProfile::Reliable
        },
    };
    let reports =
        dvrk_bridge::run_ros2_bridge(&src, &dds, stop.as_atomic()).context("ros2-bridge")?;
    log_reports("ros2-bridge", &reports, "DDS samples");
    Ok(())
}

pub fn run_record(args: &RecordArgs) -> Result<()> {
    let src = SourceOptions {
        arms: args.arms.arms()?,
        rate: args.rate,
    };
    let stop = StopFlag::install()?;
    let rec = RecordOptions {
        out: args.out.clone(),
        seconds: args.seconds,
        compensated_only: args.compensated_only,
    };
    // The file is created exclusively at its name: one that exists when the run ends was
    // written by this run, and is kept if it holds a message.
    let existed = std::fs::symlink_metadata(&args.out).is_ok();
    let reports = dvrk_bridge::run_record(&src, &rec, stop.as_atomic()).with_context(|| {
        match std::fs::metadata(&args.out) {
            Ok(m) if !existed && m.is_file() => format!(
                "recording to {} stopped; the {} bytes written are kept there, readable by \
                 any MCAP reader up to the last chunk closed (at most {} s before the error)",
                args.out.display(),
                m.len(),
                dvrk_bridge::record::CHUNK_INTERVAL.as_secs()
            ),
            _ => format!("recording to {}", args.out.display()),
        }
    })?;
    log_reports("record", &reports, "messages");
    let total: u64 = reports.iter().map(|r| r.written).sum();
    tracing::info!("record: {total} messages written to {}", args.out.display());
    Ok(())
}
