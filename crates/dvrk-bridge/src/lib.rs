//! dvrk-bridge: carries the compensated topics of dvrk-sidecar to ROS 2 and to MCAP files.
//!
//! Both bridges are consumer processes of the sidecar's shared memory (dvrk-ipc): they wake on
//! the cycle event, so nothing they do can slow the cycle. They need no ROS installation:
//!
//! - [`run_ros2_bridge`] publishes DDS topics that a ROS 2 node sees as
//!   `/PSM1/compensated/local/measured_cp` and `/PSM1/compensated/measured_cp`
//!   (`geometry_msgs/PoseStamped`), `/PSM1/compensated/measured_js` (6 joints) and
//!   `/PSM1/compensated/jaw/measured_js` (`sensor_msgs/JointState`), and
//!   `/PSM1/compensated/status` (`dvrk_sidecar_msgs/CompensationStatus`, see [`msgdefs`]; the ROS 2
//!   interface package is in `ros2/dvrk_sidecar_msgs` for a colcon workspace), with
//!   RustDDS (RTPS in pure Rust) and hand-written CDR ([`cdr`]). QoS is ROS 2's sensor-data
//!   profile by default. It never publishes under the console's own names.
//! - [`run_record`] writes the same topics to an MCAP file (`ros2msg` schemas, CDR payloads),
//!   and the uncompensated ones under the console's names (`/PSM1/measured_js`,
//!   `/PSM1/local/measured_cp`, ...) unless told to keep to the compensated ones.
//!
//! The shared memory already carries the dVRK's names and both clocks: each ROS 2 topic is the
//! sidecar's topic of the same name (`compensated/measured_cp` is in the base frame the sidecar
//! is configured with, `compensated/local/measured_cp` in the RCM frame), and the stamps are the
//! headers' `sample_realtime_ns` (ROS time, read by the sidecar with the sample). Poses and
//! joints of invalid cycles (`valid = 0`) are not published; the status of every cycle is.

pub mod cdr;
pub mod console;
pub mod convert;
pub mod crtk;
pub mod dds;
mod error;
pub mod msgdefs;
pub mod record;
pub mod source;

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

pub use convert::{ArmFrames, Decimator, Encoder, OutTopic, ros_time};
pub use dds::{DdsOptions, DdsSink, QosProfile};
pub use error::BridgeError;
pub use record::McapSink;
pub use source::{RunStats, ShmSource, Sink};

/// What both bridges read.
#[derive(Debug, Clone)]
pub struct SourceOptions {
    /// Arm name: the ROS namespace and frame names (`PSM1`).
    pub arm: String,
    /// Shared-memory prefix of the sidecar's services; `None`: `<arm>`, as `serve` names them.
    pub shm_prefix: Option<String>,
    /// Frame id of `measured_cp` (the console's reference frame of the arm's base frame, e.g.
    /// `ECM`); `None`: `<arm>_base`.
    pub base_frame_id: Option<String>,
    /// Publish at most this many cycles per second; `None`: every cycle.
    pub rate_hz: Option<f64>,
}

impl SourceOptions {
    /// The shared-memory prefix in use.
    pub fn shm_prefix(&self) -> String {
        self.shm_prefix.clone().unwrap_or_else(|| self.arm.clone())
    }

    fn validate(&self) -> Result<Option<u64>, BridgeError> {
        validate_arm(&self.arm)?;
        self.rate_hz
            .map(|hz| {
                Decimator::period_from_rate(hz).map_err(|reason| BridgeError::InvalidArgument {
                    what: "--rate",
                    value: hz.to_string(),
                    reason,
                })
            })
            .transpose()
    }

    fn encoder(&self) -> Result<Encoder, BridgeError> {
        let frames = ArmFrames::new(&self.arm, self.base_frame_id.as_deref());
        tracing::info!(
            "stamps are the samples' ROS time (CLOCK_REALTIME, from the message headers); \
             frames: local/measured_cp in {}, measured_cp in {}",
            frames.local_frame_id,
            frames.base_frame_id
        );
        Ok(Encoder::new(frames))
    }
}

/// Checks that `arm` is one ROS name token (`PSM1`): ASCII letters, digits and `_`, not starting
/// with a digit. The rule is [`dvrk_ipc::arm_name_problem`], the one `serve`'s prefix follows.
pub fn validate_arm(arm: &str) -> Result<(), BridgeError> {
    match dvrk_ipc::arm_name_problem(arm) {
        None => Ok(()),
        Some(reason) => Err(BridgeError::InvalidArgument {
            what: "arm name (--prefix)",
            value: arm.to_owned(),
            reason,
        }),
    }
}

/// Runs the ROS 2 bridge until `stop` is raised.
pub fn run_ros2_bridge(
    src: &SourceOptions,
    dds: &DdsOptions,
    stop: &AtomicBool,
) -> Result<(RunStats, u64), BridgeError> {
    let period = src.validate()?;
    let mut sink = DdsSink::new(src.encoder()?, dds)?;
    let mut source = ShmSource::new(&src.shm_prefix(), "dvrk-sidecar-ros2-bridge", false)?;
    tracing::info!(
        "ros2-bridge: {} -> DDS domain {} topics rt/{}/compensated/...",
        src.shm_prefix(),
        dds.domain,
        src.arm
    );
    let stats = source.run(&mut sink, period, stop, None)?;
    Ok((stats, sink.written()))
}

/// What [`run_record`] writes.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    pub out: PathBuf,
    /// Stop after this long; `None`: until `stop`.
    pub seconds: Option<f64>,
    /// Only the compensated topics; by default the uncompensated ones are recorded too, under
    /// the console's names (`/PSM1/measured_js`, ...), so a recording holds both sides.
    pub compensated_only: bool,
}

/// Records to an MCAP file until `stop` is raised or `--seconds` pass; returns the counters and
/// the number of messages written.
pub fn run_record(
    src: &SourceOptions,
    rec: &RecordOptions,
    stop: &AtomicBool,
) -> Result<(RunStats, u64), BridgeError> {
    let period = src.validate()?;
    let until = match rec.seconds {
        None => None,
        Some(s) if s.is_finite() && s > 0.0 && s < 1e9 => {
            Some(Instant::now() + Duration::from_secs_f64(s))
        }
        Some(s) => {
            return Err(BridgeError::InvalidArgument {
                what: "--seconds",
                value: s.to_string(),
                reason: "must be a finite number of seconds above 0",
            });
        }
    };
    let raw = !rec.compensated_only;
    let mut source = ShmSource::new(&src.shm_prefix(), "dvrk-sidecar-record", raw)?;
    let mut sink = McapSink::create(src.encoder()?, &rec.out, raw)?;
    tracing::info!("record: {} -> {}", src.shm_prefix(), rec.out.display());
    match source.run(&mut sink, period, stop, until) {
        Ok(stats) => Ok((stats, sink.finish()?)),
        Err(e) => {
            // Nothing recorded is deleted: the footer is written if the file still takes it
            // (an error of the source), otherwise (a full disk) the file keeps every chunk
            // closed before the error.
            if let Err(f) = sink.finish() {
                tracing::warn!("record: no footer written ({f}); the closed chunks are kept");
            }
            Err(e)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arm_names_are_ros_tokens() {
        assert!(validate_arm("PSM1").is_ok());
        assert!(validate_arm("psm_2").is_ok());
        for bad in ["", "1PSM", "PSM 1", "PSM1/x", "/PSM1", "PSM-1"] {
            let e = validate_arm(bad).unwrap_err().to_string();
            assert!(
                e.contains("--prefix") && e.contains(&format!("{bad:?}")),
                "{e}"
            );
        }
    }

    #[test]
    fn rate_and_prefix_are_checked() {
        let mut s = SourceOptions {
            arm: "PSM1".into(),
            shm_prefix: None,
            base_frame_id: None,
            rate_hz: Some(0.0),
        };
        let e = s.validate().unwrap_err().to_string();
        assert!(e.contains("--rate") && e.contains('0'), "{e}");
        s.rate_hz = Some(100.0);
        assert_eq!(s.validate().unwrap(), Some(10_000_000));
        assert_eq!(s.shm_prefix(), "PSM1");
    }
}
