//! dvrk-bridge: carries the compensated topics of dvrk-sidecar to ROS 2 and to MCAP files.
//!
//! Both bridges are consumer processes of the sidecar's shared memory (dvrk-ipc): they wake on
//! the cycle event, so nothing they do can slow the cycle. They need no ROS installation. One
//! process serves every arm of a service ([`SourceOptions::arms`]):
//!
//! - [`run_ros2_bridge`] publishes DDS topics that a ROS 2 node sees as
//!   `/PSM1/compensated/local/measured_cp` and `/PSM1/compensated/measured_cp`
//!   (`geometry_msgs/PoseStamped`), the same poses with the covariance of their error beside
//!   them, `/PSM1/compensated/local/measured_cp_with_covariance` and
//!   `/PSM1/compensated/measured_cp_with_covariance` (`geometry_msgs/PoseWithCovarianceStamped`,
//!   from the 95% bounds of the cycle's status, see [`PoseCovariance`]),
//!   `/PSM1/compensated/measured_js` (6 joints) and
//!   `/PSM1/compensated/jaw/measured_js` (`sensor_msgs/JointState`), and
//!   `/PSM1/compensated/status` (`dvrk_sidecar_msgs/CompensationStatus`, see [`msgdefs`]; the ROS 2
//!   interface package is in `ros2/dvrk_sidecar_msgs` for a colcon workspace), for each arm, with
//!   RustDDS (RTPS in pure Rust) and hand-written CDR ([`cdr`]). QoS is the console's own
//!   (RELIABLE, KEEP_LAST 100, VOLATILE; [`QosProfile`]), at 100 Hz by default ([`Rate`]). It
//!   never publishes under the console's own names.
//! - [`run_record`] writes the same topics of every arm to one MCAP file (`ros2msg` schemas, CDR
//!   payloads), and the uncompensated ones under the console's names (`/PSM1/measured_js`,
//!   `/PSM1/local/measured_cp`, ...) unless told to keep to the compensated ones.
//!
//! The shared memory already carries the dVRK's names and both clocks: each ROS 2 topic is the
//! sidecar's topic of the same name (`compensated/measured_cp` is in the base frame the sidecar
//! is configured with, `compensated/local/measured_cp` in the RCM frame), and the stamps are the
//! headers' `sample_realtime_ns` (ROS time, read by the sidecar with the sample). Poses and
//! joints of invalid cycles (`valid = 0`) are not published; the status of every cycle is. A
//! pose with covariance is published with its pose, from the status of the same cycle, when
//! that status carries a finite bound (never NaN: before the first valid sample it carries none).

pub mod cdr;
pub mod console;
pub mod convert;
pub mod crtk;
pub mod dds;
mod error;
pub mod msgdefs;
pub mod record;
mod run;
pub mod source;

use std::path::PathBuf;

pub use convert::{ArmFrames, CHI2_3_95, Decimator, Encoder, OutTopic, PoseCovariance, ros_time};
pub use dds::{DdsOptions, DdsParticipant, DdsSink, IncompatibleReaders, QosProfile};
pub use error::BridgeError;
pub use record::McapSink;
pub use run::{ArmReport, NOTHING_TIMEOUT, run_record, run_ros2_bridge};
pub use source::{RunStats, Sample, ShmSource, Sink};

/// One arm the bridges carry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ArmSpec {
    /// The ROS namespace and frame names (`PSM1`): one ROS name token.
    pub arm: String,
    /// Shared-memory prefix of the `serve` that publishes the arm (`PSM1`, `lab/PSM1`).
    pub shm_prefix: String,
    /// Frame id of `measured_cp` (the console's reference frame of the arm's base frame, e.g.
    /// `ECM`); `None`: `<arm>_base`.
    pub base_frame_id: Option<String>,
}

impl ArmSpec {
    /// `--prefix ARM [--shm-prefix P] [--base-frame-id F]`: the arm `arm` (a ROS name token),
    /// read under `shm_prefix` (default: `arm`, as `serve` names it).
    pub fn new(
        arm: &str,
        shm_prefix: Option<&str>,
        base_frame_id: Option<&str>,
    ) -> Result<Self, BridgeError> {
        validate_arm(arm)?;
        Ok(ArmSpec {
            arm: arm.to_owned(),
            shm_prefix: shm_prefix.unwrap_or(arm).to_owned(),
            base_frame_id: base_frame_id.map(str::to_owned),
        })
    }

    /// An arm of a service configuration, named by its shared-memory prefix (an arm's `name`
    /// or the single-arm `prefix`: `PSM1`, or a namespaced `lab/PSM1`). Its ROS namespace is the
    /// prefix's last segment: the console's name of the arm.
    pub fn from_service_prefix(prefix: &str) -> Result<Self, BridgeError> {
        let arm = prefix.rsplit('/').next().unwrap_or(prefix);
        if dvrk_ipc::arm_name_problem(arm).is_some() {
            return Err(BridgeError::InvalidArgument {
                what: "arm name of the service configuration",
                value: prefix.to_owned(),
                reason: "its last '/' segment, the ROS namespace, must be one ROS name token \
                         (ASCII letters, digits and '_', not starting with a digit, e.g. PSM1)",
            });
        }
        Ok(ArmSpec {
            arm: arm.to_owned(),
            shm_prefix: prefix.to_owned(),
            base_frame_id: None,
        })
    }

    /// `PSM1`, or `PSM1 (shared memory lab/PSM1)` when the prefix differs from the name.
    pub fn describe(&self) -> String {
        if self.shm_prefix == self.arm {
            self.arm.clone()
        } else {
            format!("{} (shared memory {})", self.arm, self.shm_prefix)
        }
    }

    fn encoder(&self) -> Encoder {
        let frames = ArmFrames::new(&self.arm, self.base_frame_id.as_deref());
        tracing::info!(
            "{}: stamps are the samples' ROS time (CLOCK_REALTIME, from the message headers); \
             frames: local/measured_cp in {}, measured_cp in {}",
            self.arm,
            frames.local_frame_id,
            frames.base_frame_id
        );
        Encoder::new(frames)
    }
}

/// How many cycles per second the bridges pass on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rate {
    /// Every cycle of the sidecar (1.5 kHz on a dVRK).
    EveryCycle,
    /// At most this many cycles per second: the first cycle of each 1/rate slot of the
    /// sample clock (see [`Decimator`]).
    Hz(f64),
}

impl Rate {
    /// The ROS 2 bridge's default: the rate of the console's own state topics (100 Hz), what
    /// rqt, rviz, `ros2 topic echo` and `ros2 bag record` cope with.
    pub const ROS2_DEFAULT: Rate = Rate::Hz(100.0);
    /// `record`'s default: every cycle, all a logger is for.
    pub const RECORD_DEFAULT: Rate = Rate::EveryCycle;

    /// The decimation period, `None` for every cycle; or why the rate is not usable.
    pub fn period_ns(self) -> Result<Option<u64>, BridgeError> {
        match self {
            Rate::EveryCycle => Ok(None),
            Rate::Hz(hz) => Decimator::period_from_rate(hz).map(Some).map_err(|reason| {
                BridgeError::InvalidArgument {
                    what: "--rate",
                    value: hz.to_string(),
                    reason,
                }
            }),
        }
    }
}

impl core::fmt::Display for Rate {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Rate::EveryCycle => f.write_str("every cycle"),
            Rate::Hz(hz) => write!(f, "{hz} Hz"),
        }
    }
}

impl core::str::FromStr for Rate {
    type Err = BridgeError;

    /// `all` (every cycle) or a number of Hz above 0.
    fn from_str(s: &str) -> Result<Self, BridgeError> {
        if s == "all" {
            return Ok(Rate::EveryCycle);
        }
        let bad = |reason| BridgeError::InvalidArgument {
            what: "--rate",
            value: s.to_owned(),
            reason,
        };
        let hz: f64 = s
            .parse()
            .map_err(|_| bad("expected a number of Hz, or `all` for every cycle"))?;
        let rate = Rate::Hz(hz);
        rate.period_ns()
            .map_err(|_| bad("the rate must be a finite number of Hz above 0"))?;
        Ok(rate)
    }
}

/// What both bridges read.
#[derive(Debug, Clone)]
pub struct SourceOptions {
    /// The arms, each in a thread of its own.
    pub arms: Vec<ArmSpec>,
    pub rate: Rate,
}

impl SourceOptions {
    /// Checks the options; returns the decimation period.
    fn validate(&self) -> Result<Option<u64>, BridgeError> {
        if self.arms.is_empty() {
            return Err(BridgeError::InvalidArgument {
                what: "arms",
                value: String::new(),
                reason: "no arm to bridge",
            });
        }
        for (i, a) in self.arms.iter().enumerate() {
            validate_arm(&a.arm)?;
            if self.arms[..i].iter().any(|b| b.arm == a.arm) {
                return Err(BridgeError::InvalidArgument {
                    what: "arm name",
                    value: a.arm.clone(),
                    reason: "two arms would publish under the same ROS namespace",
                });
            }
            if self.arms[..i].iter().any(|b| b.shm_prefix == a.shm_prefix) {
                return Err(BridgeError::InvalidArgument {
                    what: "shared-memory prefix",
                    value: a.shm_prefix.clone(),
                    reason: "two arms read the same shared memory",
                });
            }
        }
        self.rate.period_ns()
    }

    /// `PSM1, PSM2 (shared memory lab/PSM2)`.
    pub fn describe_arms(&self) -> String {
        self.arms
            .iter()
            .map(ArmSpec::describe)
            .collect::<Vec<_>>()
            .join(", ")
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

/// Runs `f` (which builds a DDS participant) with every blockable signal blocked in this thread,
/// so the threads RustDDS starts there (event loop, discovery) inherit that mask and a handled
/// signal (Ctrl-C, SIGTERM, the calibration's Ctrl-Z) is always delivered to one of the
/// program's own threads. RustDDS's event loop ends for good when its poll is interrupted
/// (EINTR), and a handled signal delivered to it would do that: DDS then goes silent, and a
/// calibration's last `hold` is never sent. A stop and continue (SIGSTOP/SIGCONT, an unhandled
/// Ctrl-Z then `fg`) interrupts every thread whatever its mask; `serve` restarts its participant
/// after a silence for that.
pub(crate) fn with_signals_blocked<T>(f: impl FnOnce() -> T) -> (T, DdsThreads) {
    let before = task_ids();
    // SAFETY: both sets are initialised by sigfillset/pthread_sigmask before they are read;
    // pthread_sigmask only changes this thread's mask, restored below whatever `f` returns.
    let mut old: libc::sigset_t = unsafe { std::mem::zeroed() };
    unsafe {
        let mut all: libc::sigset_t = std::mem::zeroed();
        libc::sigfillset(&mut all);
        libc::pthread_sigmask(libc::SIG_BLOCK, &all, &mut old);
    }
    let out = f();
    // SAFETY: `old` holds the mask read above.
    unsafe {
        libc::pthread_sigmask(libc::SIG_SETMASK, &old, std::ptr::null_mut());
    }
    let tids = task_ids()
        .into_iter()
        .filter(|t| !before.contains(t))
        .collect();
    (out, DdsThreads { tids })
}

/// The threads that building a DDS participant started (RustDDS's event loop and discovery),
/// by thread id, to tell whether they still run: RustDDS ends its event loop on an interrupted
/// poll without a word, after which nothing is sent or received. Built where no other thread
/// of the program starts at the same time (the bridge builds its participant before its arms'
/// threads).
#[derive(Debug, Clone, Default)]
pub struct DdsThreads {
    tids: Vec<u32>,
}

impl DdsThreads {
    /// Every thread the build started still runs (true where /proc is not there to tell).
    pub fn alive(&self) -> bool {
        self.tids
            .iter()
            .all(|t| std::path::Path::new(&format!("/proc/self/task/{t}")).exists())
    }

    /// How many threads the build started.
    pub fn count(&self) -> usize {
        self.tids.len()
    }
}

/// This process's thread ids (empty without /proc).
fn task_ids() -> Vec<u32> {
    std::fs::read_dir("/proc/self/task")
        .map(|d| {
            d.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
                .collect()
        })
        .unwrap_or_default()
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
            assert!(ArmSpec::new(bad, None, None).is_err());
        }
    }

    #[test]
    fn a_service_prefix_publishes_under_its_last_segment() {
        let a = ArmSpec::from_service_prefix("PSM2").unwrap();
        assert_eq!((a.arm.as_str(), a.shm_prefix.as_str()), ("PSM2", "PSM2"));
        assert_eq!(a.describe(), "PSM2");
        let a = ArmSpec::from_service_prefix("lab/left/PSM1").unwrap();
        assert_eq!(
            (a.arm.as_str(), a.shm_prefix.as_str()),
            ("PSM1", "lab/left/PSM1")
        );
        assert_eq!(a.describe(), "PSM1 (shared memory lab/left/PSM1)");
        for bad in ["lab/1x", "", "lab/"] {
            let e = ArmSpec::from_service_prefix(bad).unwrap_err().to_string();
            assert!(
                e.contains("last '/' segment") && e.contains(&format!("{bad:?}")),
                "{e}"
            );
        }
    }

    #[test]
    fn rates_parse_as_hz_or_all() {
        assert_eq!("all".parse::<Rate>().unwrap(), Rate::EveryCycle);
        assert_eq!("100".parse::<Rate>().unwrap(), Rate::Hz(100.0));
        assert_eq!(
            "12.5".parse::<Rate>().unwrap().period_ns().unwrap(),
            Some(80_000_000)
        );
        assert_eq!(Rate::EveryCycle.period_ns().unwrap(), None);
        assert_eq!(Rate::ROS2_DEFAULT.period_ns().unwrap(), Some(10_000_000));
        for bad in ["0", "-3", "NaN", "inf", "fast", ""] {
            let e = bad.parse::<Rate>().unwrap_err().to_string();
            assert!(
                e.contains("--rate") && e.contains(&format!("{bad:?}")),
                "{e}"
            );
        }
    }

    #[test]
    fn arms_must_not_collide() {
        let mut s = SourceOptions {
            arms: vec![
                ArmSpec::from_service_prefix("PSM1").unwrap(),
                ArmSpec::from_service_prefix("lab/PSM2").unwrap(),
            ],
            rate: Rate::Hz(100.0),
        };
        assert_eq!(s.validate().unwrap(), Some(10_000_000));
        assert_eq!(s.describe_arms(), "PSM1, PSM2 (shared memory lab/PSM2)");
        s.arms
            .push(ArmSpec::from_service_prefix("other/PSM1").unwrap());
        let e = s.validate().unwrap_err().to_string();
        assert!(
            e.contains("PSM1") && e.contains("same ROS namespace"),
            "{e}"
        );
        s.arms.pop();
        s.arms
            .push(ArmSpec::new("PSM3", Some("PSM1"), None).unwrap());
        let e = s.validate().unwrap_err().to_string();
        assert!(e.contains("same shared memory"), "{e}");
        s.arms.clear();
        assert!(s.validate().is_err());
    }
}
