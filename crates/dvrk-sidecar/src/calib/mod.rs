//! Calibration and evaluation commands (paper sections 3-4): data files, the `fit` and
//! `evaluate` commands, figures, and the `calibrate` procedures.

pub mod calibrate;
pub mod console_run;
pub mod data;
pub mod dynamics_cmd;
pub mod evaluate;
pub mod evaluate_motion;
pub mod fit_cmd;
pub mod plots;
pub mod provenance;

pub use calibrate::{CalibrateArgs, run_calibrate};
pub use evaluate::{EvaluateArgs, run_evaluate};
pub use fit_cmd::{FitArgs, run_fit};
