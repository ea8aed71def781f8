//! dvrk-sim: a simulated Classic PSM with ground truth and an emulator of its two QLA boards.
//!
//! - [`physics`]: pure, deterministic arm physics (PID, counterbalance torque, shaft compliance and
//!   backlash, contacts) with ground truth ([`Truth`]).
//! - [`measure`]: measurement models (encoder quantization, motor-current ADC with noise, pots).
//! - [`scenario`]: config/sim/*.toml: seed, step, pose, environment, motion, noise.
//! - [`emulator`]: boards 6 and 7 (QLA1, Rev 9) answering the real Ethernet/FireWire protocol,
//!   or one chain of boards for several arms (PSM1 6-7, PSM2 8-9, PSM3 10-11).
//! - [`link`]: [`SimLink`], the emulator as an in-process `dvrk_io::Link`; [`SimPort`].
//! - [`server`]: `serve_udp`, the standalone UDP shell (the only place that reads a clock).

// Joint-indexed loops (`for j in 0..3`) read like the equations they implement and often touch
// several arrays at once; iterator chains would obscure that.
#![allow(clippy::needless_range_loop)]

pub mod emulator;
pub mod kinematics;
pub mod link;
pub mod measure;
pub mod physics;
pub mod rng;
pub mod scenario;
pub mod server;

pub use emulator::{
    ActuatorMap, ActuatorSlot, ArmSpec, CLASSIC_PSM_BOARDS, Emulator, EmulatorCounters,
    classic_psm_boards,
};
pub use link::{SimLink, SimPort, sim_port};
pub use measure::{ActuatorScales, NoiseParams};
pub use physics::{
    DistalParams, Environment, FrictionParams, JointState, PhysicsParams, ShaftParams, SimPsm,
    Truth,
};
pub use rng::SimRng;
pub use scenario::{EthernetMode, Motion, MotionDriver, Scenario, ScenarioParams};

/// Errors of dvrk-sim (setup only: the step and the emulator's request handling cannot fail).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// A scenario value is out of range.
    #[error("scenario field `{field}` = {value}: {reason}")]
    InvalidScenario {
        field: String,
        value: String,
        reason: &'static str,
    },
    /// An actuator of the IO config is not on its arm's boards (6 and 7 for one arm), axis 0..3.
    #[error(
        "io config: actuator {actuator} on board {board_id} axis {axis}: the emulator has boards {} and {} with axes 0-3",
        boards[0], boards[1]
    )]
    ActuatorPlacement {
        actuator: usize,
        board_id: u8,
        axis: u8,
        /// The arm's boards.
        boards: [u8; 2],
    },
    /// The arms of a chain cannot share one set of boards ([`Emulator::chain`]).
    #[error("chain of boards{}: {reason}", board.map(|b| format!(", board {b}")).unwrap_or_default())]
    Chain {
        board: Option<u8>,
        reason: &'static str,
    },
    /// The IO config does not describe what the emulator emulates.
    #[error("io config field `{field}` = {value}: {reason}")]
    IoConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// The wrist coupling matrix cannot be inverted.
    #[error("io config: the actuator-to-joint coupling of joints 4-7 is singular")]
    Coupling,
    /// The feedback-block layout could not be built.
    #[error("wire layout: {0}")]
    Wire(#[from] dvrk_io::wire::WireError),
}
