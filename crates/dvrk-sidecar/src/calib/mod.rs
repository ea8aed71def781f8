//! Calibration and evaluation commands (paper sections 3-4): data files, the `fit` and
//! `evaluate` commands, figures, and the `calibrate` procedures.

pub mod data;
pub mod fit_cmd;
pub mod plots;

pub use fit_cmd::{FitArgs, run_fit};
