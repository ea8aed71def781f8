//! dvrk-ipc: the contract between dvrk-sidecar and its consumers.
//!
//! dvrk-sidecar publishes the joint and tip states of a da Vinci Research Kit PSM, raw and
//! compensated for instrument compliance, through iceoryx2 shared memory. This crate holds
//! everything both sides must agree on:
//!
//! - the `#[repr(C)]` message types ([`JointStateV1`], [`PoseV1`], [`CompensationStatusV2`], all
//!   starting with the common [`Header`]) and the [`flags`] bits, mirrored for C and C++ in
//!   `include/dvrk_ipc.h`;
//! - the service names under a prefix (default `dvrk/PSM1`, see [`ServiceNames`]):
//!
//!   | service | payload |
//!   |---|---|
//!   | `<prefix>/measured_js` | [`JointStateV1`] |
//!   | `<prefix>/measured_cp` | [`PoseV1`] |
//!   | `<prefix>/compensated/measured_js` | [`JointStateV1`] |
//!   | `<prefix>/compensated/measured_cp` | [`PoseV1`] |
//!   | `<prefix>/compensated/status` | [`CompensationStatusV2`] |
//!   | `<prefix>/cycle` | event, notified once per cycle after the five messages |
//!
//! - the QoS ([`qos`]) applied by the one function that opens or creates services
//!   ([`open_topic`], [`open_cycle_event`], [`ArmServices::open_or_create`]);
//! - [`ArmPublisher`] (used by the sidecar; also counts subscribers of every topic and reaps dead
//!   nodes) and [`Subscription`] (for consumers), which waits as the consumer chooses
//!   ([`WaitStrategy`]): `Event` (sleep until notified), `Spin` (poll, a core of its own, no
//!   listener) or `Predictive` (sleep until just before the next sample is due, then poll).
//!
//! ```no_run
//! use dvrk_ipc::{create_node, PoseV1, ServiceNames, Subscription, Topic, Update, NOMINAL_PERIOD};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let node = create_node::<iceoryx2::service::ipc::Service>("fixture", None)?;
//! let names = ServiceNames::new("dvrk/PSM1")?;
//! let mut sub = Subscription::<PoseV1>::new(&node, &names, Topic::CompensatedMeasuredCp, NOMINAL_PERIOD)?;
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
mod error;
pub mod flags;
mod msg;
mod names;
mod predict;
mod publisher;
mod services;
mod subscription;
mod sys;

pub use error::{IpcError, PublishError, SubscriptionError};
pub use msg::{
    COMPENSATION_STATUS_V2_SIZE, CompensationStatusV2, HEADER_SIZE, Header, JOINT_NAMES,
    JOINT_STATE_V1_SIZE, JointStateV1, Message, NUM_JOINTS, POSE_V1_SIZE, PoseV1,
};
pub use names::{CYCLE_SUFFIX, DEFAULT_PREFIX, MAX_PREFIX_LEN, ServiceNames, Topic};
pub use publisher::{ArmPublisher, ReapReport, SubscriberCounts};
pub use services::{
    ArmServices, ICEORYX2_LOG_LEVEL, MAX_DOMAIN_PREFIX_LEN, MAX_ROOT_PATH_LEN, create_node,
    domain_config, open_cycle_event, open_topic, qos,
};
pub use subscription::{
    DEAD_PUBLISHER_CHECK_INTERVAL, DEADLINE_PERIODS, MIN_DEFAULT_DEADLINE, NOMINAL_PERIOD,
    Prediction, SubscribeOptions, Subscription, SubscriptionStats, UnknownWaitStrategy, Update,
    WaitStrategy,
};
pub use sys::monotonic_ns;

/// The iceoryx2 crate this contract is built on (same version in every process).
pub use iceoryx2;
