//! dvrk-compliance: the compliance model of Chrysilla et al. for the dVRK PSM, torque-offset
//! tables, parameter files, PSM and instrument kinematics, calibration procedures and fitting.
//!
//! Pure: no I/O, no clock, no logging, and no allocation per sample.

pub mod calibration;
pub mod fit;
