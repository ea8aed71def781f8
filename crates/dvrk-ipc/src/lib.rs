//! dvrk-ipc: the contract between dvrk-sidecar and its consumers.
//!
//! dvrk-sidecar publishes the joint and tip states of a da Vinci Research Kit PSM, raw and
//! compensated for instrument compliance, through iceoryx2 shared memory. This crate holds
//! everything both sides must agree on:
//!
//! - the `#[repr(C)]` message types ([`JointStateV2`], [`JawStateV1`], [`PoseV2`],
//!   [`CompensationStatusV4`], all starting with the common [`Header`], which carries both the
//!   `CLOCK_MONOTONIC` and the `CLOCK_REALTIME` (ROS) time of the sample) and the [`flags`] bits,
//!   mirrored for C and C++ in `include/dvrk_ipc.h`;
//! - the service names under a prefix, the arm's name (default `PSM1`, see [`ServiceNames`]),
//!   as the dVRK 2.x console names its topics:
//!
//!   | service | payload |
//!   |---|---|
//!   | `<prefix>/measured_js` | [`JointStateV2`]: six joints |
//!   | `<prefix>/jaw/measured_js` | [`JawStateV1`] |
//!   | `<prefix>/local/measured_cp` | [`PoseV2`]: tip in the RCM frame |
//!   | `<prefix>/measured_cp` | [`PoseV2`]: tip in the base frame |
//!   | `<prefix>/compensated/measured_js` | [`JointStateV2`] |
//!   | `<prefix>/compensated/jaw/measured_js` | [`JawStateV1`] |
//!   | `<prefix>/compensated/local/measured_cp` | [`PoseV2`] |
//!   | `<prefix>/compensated/measured_cp` | [`PoseV2`] |
//!   | `<prefix>/compensated/status` | [`CompensationStatusV4`] |
//!   | `<prefix>/cycle` | event, notified once per cycle after the nine messages |
//!   | `<prefix>/cycle/first` | event, notified once per cycle right after its first message, `compensated/local/measured_cp` ([`PUBLISH_ORDER`]) |
//!
//! - the domain every process of the project meets in ([`default_domain`], what
//!   [`create_node`] with `None` uses): root path `/tmp/dvrk-sidecar-<euid>/` (or
//!   `$DVRK_SIDECAR_IPC_ROOT`, [`IPC_ROOT_ENV`]), created 0700 and refused when another account
//!   could write it ([`access::ensure_private_root`]), and the prefix `dvrk_<euid>_`;
//! - the QoS ([`qos`]) applied by the functions that open or create services
//!   ([`open_topic`], [`open_event`], [`open_cycle_event`], [`ArmServices::open_or_create`]);
//! - [`ArmPublisher`] (used by the sidecar; also counts subscribers of every topic and reaps dead
//!   nodes) and [`Subscription`] (for consumers), which waits as the consumer chooses
//!   ([`WaitStrategy`]): `Event` (sleep until notified), `Spin` (poll, a core of its own, no
//!   listener) or `Predictive` (sleep until just before the next sample is due, then poll);
//! - the cycle's wake-up ([`wake`]): beside each cycle event, a futex word in a 0600 file of the
//!   domain's root (`<root><prefix><event name>.wake`) that the publisher bumps once per cycle,
//!   waking every sleeping subscription with one system call instead of iceoryx2's one unix
//!   datagram per listener.
//!
//! ```no_run
//! use dvrk_ipc::{create_node, PoseV2, ServiceNames, Subscription, Topic, Update, NOMINAL_PERIOD};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let node = create_node::<iceoryx2::service::ipc::Service>("fixture", None)?;
//! let names = ServiceNames::new("PSM1")?;
//! let mut sub = Subscription::<PoseV2>::new(&node, &names, Topic::CompensatedLocalMeasuredCp, NOMINAL_PERIOD)?;
//! loop {
//!     match sub.wait()? {
//!         Update::Fresh(p) if p.header.valid == 1 => println!("{:?}", p.position_m),
//!         Update::Fresh(_) => {} // invalid cycle: see p.header.flags
//!         Update::Stale { since_ns } => eprintln!("publisher silent for {since_ns} ns"),
//!         Update::Terminated => break,
//!         Update::Interrupted => {}
//!     }
//! }
//! # Ok(()) }
//! ```
//!
//! Everything is generic over the iceoryx2 service variant `S` (default `ipc::Service`, across
//! processes; `local::Service` works inside one process, e.g. for benchmarks).

pub mod access;
pub mod clock;
mod error;
pub mod flags;
mod msg;
mod names;
mod predict;
mod publisher;
mod services;
mod subscription;
mod sys;
pub mod wake;

pub use clock::monotonic_ns;
pub use error::{IpcError, PublishError, RootProblem, SubscriptionError};
pub use msg::{
    ArmState, COMPENSATION_STATUS_V4_SIZE, CompensationStatusV4, CycleMessages, HEADER_SIZE,
    Header, JAW_NAME, JAW_STATE_V1_SIZE, JOINT_NAMES, JOINT_STATE_V2_SIZE, JawStateV1,
    JointStateV2, Message, NUM_JOINTS, POSE_V2_SIZE, PoseV2, pack_source_state,
};
pub use names::{
    CYCLE_FIRST_SUFFIX, CYCLE_SUFFIX, DEFAULT_PREFIX, MAX_PREFIX_LEN, NUM_TOPICS, ServiceNames,
    Topic, arm_name_problem,
};
pub use predict::{PREDICTIVE_LATE_PERCENT, PREDICTIVE_LATE_PERCENT_RANGE};
pub use publisher::{ArmPublisher, CycleStarted, PUBLISH_ORDER, ReapReport, SubscriberCounts};
pub use services::{
    ArmServices, ICEORYX2_LOG_LEVEL, IPC_ROOT_ENV, MAX_DOMAIN_PREFIX_LEN, MAX_ROOT_PATH_LEN,
    StateServices, create_node, default_domain, default_domain_prefix, default_root_path,
    domain_config, is_default_root, open_cycle_event, open_event, open_topic, qos,
};
pub use subscription::{
    DEAD_PUBLISHER_CHECK_INTERVAL, DEADLINE_PERIODS, MIN_DEFAULT_DEADLINE, NOMINAL_PERIOD,
    Prediction, SHORT_SLICE_ENV, SubscribeOptions, Subscription, SubscriptionStats,
    UnknownWaitStrategy, Update, WaitStrategy,
};

/// The iceoryx2 crate this contract is built on (same version in every process).
pub use iceoryx2;
