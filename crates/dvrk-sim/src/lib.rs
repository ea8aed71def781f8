//! dvrk-sim: a simulated Classic PSM with ground truth and an emulator of its two QLA boards.
//!
//! - [`physics`]: pure, deterministic arm physics (PID, counterbalance torque, shaft compliance and
//!   backlash, contacts) with ground truth.
//! - [`measure`]: measurement models (encoder quantization, motor current ADC with noise, pots).

pub mod kinematics;
pub mod physics;
pub mod rng;

pub use physics::{Environment, JointState, PhysicsParams, ShaftParams, SimPsm, Truth};
pub use rng::SimRng;
