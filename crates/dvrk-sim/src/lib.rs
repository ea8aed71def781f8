//! dvrk-sim: a simulated Classic PSM with ground truth and an emulator of its two QLA boards.
//!
//! - [`physics`]: pure, deterministic arm physics (PID, counterbalance torque, shaft compliance and
//!   backlash, contacts) with ground truth ([`Truth`]).
//! - [`measure`]: measurement models (encoder quantization, motor-current ADC with noise, pots).
//! - [`scenario`]: config/sim/*.toml: seed, step, pose, environment, motion, noise.

pub mod kinematics;
pub mod measure;
pub mod physics;
pub mod rng;
pub mod scenario;

pub use measure::{ActuatorScales, NoiseParams};
pub use physics::{Environment, JointState, PhysicsParams, ShaftParams, SimPsm, Truth};
pub use rng::SimRng;
pub use scenario::{Motion, MotionDriver, Scenario, ScenarioParams};

/// Errors of dvrk-sim (setup only: the step and the emulator's request handling cannot fail).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// The scenario file is not valid TOML for the schema (the message names the field).
    #[error("scenario: {0}")]
    ScenarioParse(String),
    /// A scenario value is out of range.
    #[error("scenario field `{field}` = {value}: {reason}")]
    InvalidScenario {
        field: String,
        value: String,
        reason: &'static str,
    },
}
