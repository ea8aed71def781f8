//! `ros2-bridge` and `record`: consumers of the shared memory that carry the compensated topics
//! to ROS 2 (DDS) and to MCAP files. The work is in the dvrk-bridge crate; this is the CLI.

use std::net::IpAddr;
use std::path::PathBuf;

use anyhow::{Context, Result};
use dvrk_bridge::{DdsOptions, QosProfile, RecordOptions, SourceOptions};

use crate::signals::StopFlag;

#[derive(clap::Args, Debug)]
pub struct SourceArgs {
    /// Arm name: the ROS namespace and frame names (topics /<ARM>/compensated/...).
    #[arg(long, default_value = "PSM1")]
    prefix: String,
    /// Shared-memory prefix of the running `serve` (default: <ARM>, as `serve` names it).
    #[arg(long)]
    shm_prefix: Option<String>,
    /// Frame id of measured_cp: the reference frame of the arm's base frame in the console's
    /// configuration (e.g. ECM). Default: <ARM>_base.
    #[arg(long)]
    base_frame_id: Option<String>,
    /// Publish at most this many cycles per second (default: every cycle).
    #[arg(long)]
    rate: Option<f64>,
}

impl SourceArgs {
    fn options(&self) -> SourceOptions {
        SourceOptions {
            arm: self.prefix.clone(),
            shm_prefix: self.shm_prefix.clone(),
            base_frame_id: self.base_frame_id.clone(),
            rate_hz: self.rate,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct Ros2BridgeArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// DDS domain id (ROS_DOMAIN_ID).
    #[arg(long, default_value_t = 0)]
    domain: u16,
    /// Use only the network interface with this address (repeatable), e.g. 127.0.0.1 to stay on
    /// this host. Default: all interfaces.
    #[arg(long = "interface")]
    interfaces: Vec<IpAddr>,
    /// Reliable QoS (ROS 2 default profile) instead of sensor data (best effort).
    #[arg(long)]
    reliable: bool,
}

#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// MCAP file to write.
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

pub fn run_ros2_bridge(args: &Ros2BridgeArgs) -> Result<()> {
    let stop = StopFlag::install()?;
    let dds = DdsOptions {
        domain: args.domain,
        interfaces: args.interfaces.clone(),
        qos: if args.reliable {
            QosProfile::Reliable
        } else {
            QosProfile::SensorData
        },
    };
    let (stats, written) =
        dvrk_bridge::run_ros2_bridge(&args.source.options(), &dds, stop.as_atomic())
            .context("ros2-bridge")?;
    tracing::info!(
        "ros2-bridge stopped: {} cycles, {} DDS samples written, {} invalid skipped, {} decimated, {} lost in shared memory",
        stats.cycles,
        written,
        stats.invalid_skipped,
        stats.decimated,
        stats.shm_seq_gaps
    );
    Ok(())
}

pub fn run_record(args: &RecordArgs) -> Result<()> {
    let stop = StopFlag::install()?;
    let rec = RecordOptions {
        out: args.out.clone(),
        seconds: args.seconds,
        compensated_only: args.compensated_only,
    };
    // The file is created exclusively at its name: one that exists when the run ends was
    // written by this run, and is kept.
    let existed = std::fs::symlink_metadata(&args.out).is_ok();
    let (stats, written) = dvrk_bridge::run_record(&args.source.options(), &rec, stop.as_atomic())
        .with_context(|| match std::fs::metadata(&args.out) {
            Ok(m) if !existed && m.is_file() => format!(
                "recording to {} stopped; the {} bytes written are kept there, readable up to \
                 the last chunk closed (at most {} s before the error) with a streaming MCAP \
                 reader or `mcap recover`",
                args.out.display(),
                m.len(),
                dvrk_bridge::record::CHUNK_INTERVAL.as_secs()
            ),
            _ => format!("recording to {}", args.out.display()),
        })?;
    tracing::info!(
        "record: {} messages of {} cycles written to {} ({} invalid skipped, {} decimated, {} lost in shared memory)",
        written,
        stats.cycles,
        args.out.display(),
        stats.invalid_skipped,
        stats.decimated,
        stats.shm_seq_gaps
    );
    Ok(())
}
