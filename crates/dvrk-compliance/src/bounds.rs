//! The physical bounds of every number read from a parameter or data file, stated once here
//! (issue 22: finite is not enough; 1e308 rad or a stiffness of 1 N·m/rad passed every check).
//! Parameter files are checked against them in [`crate::params`]; the application checks its
//! data files (calibration CSV) against them too.

/// The band `1/K(L)` (N·m/rad) must lie in over the whole insertion range.
///
/// The paper's cubics give 12 to 31 N·m/rad over 0.09-0.22 m, the 2017 recordings 13 to
/// 29 N·m/rad. The band reaches a factor of 6 below and 16 above, room for other instruments
/// (5 mm shafts are softer, short or stiff tools stiffer) and for a fit at other depths; outside
/// it the cubic is a fit error, not a shaft: at 2 N·m/rad a 0.5 N·m contact would already bend
/// the shaft by 0.25 rad (14°), and above 500 N·m/rad the whole correction stays below 1 mrad,
/// the size of the backlash, so the parameters would correct nothing (1e308 did exactly that).
pub const INVERSE_COMPLIANCE_NM_PER_RAD: [f64; 2] = [2.0, 500.0];

/// The largest plausible backlash (rad): the 2017 data show a few mrad.
pub const MAX_BACKLASH_RAD: f64 = 0.02;

/// The largest plausible dead band (N·m): the paper uses 0.1 and 0.2 N·m. Also the bound of a
/// Coulomb friction and of a residual std in `[joint.dynamics]`.
pub const MAX_TAU_MIN_NM: f64 = 1.0;

/// The largest plausible inertia of joint 1 or 2 (kg·m²): a Classic PSM's arm and reflected
/// motor inertia are well below it.
pub const MAX_INERTIA_KG_M2: f64 = 1.0;

/// Insertion ranges of a parameter file must lie within the Classic PSM's insertion joint
/// limits (reference 1.2).
pub const INSERTION_LIMITS_M: [f64; 2] = [0.0, 0.24];

/// The joint range `[lower, upper]` of joints 1 (yaw, rad), 2 (pitch, rad) and 3 (insertion,
/// m) of any PSM: the widest of the Classic and the Si soft limits. It MUST match
/// `dvrk_io::plausibility::{CLASSIC_PSM_SOFT_LIMITS, SI_PSM_SOFT_LIMITS}` (this crate may not
/// import dvrk-io; a test in dvrk-sidecar, which imports both, checks that it does). Torque
/// offset table positions and the positions of data files must lie in it.
pub const PSM_JOINT_RANGE: [[f64; 2]; 3] = [[-2.964, 2.964], [-1.265, 1.301], [0.0, 0.29]];

/// The largest plausible |effort| (N·m for joints 1-2, N for insertion) in a data file: a PSM's
/// motors saturate far below it (joint torques of a few N·m, insertion forces of tens of N).
pub const MAX_ABS_EFFORT: f64 = 50.0;

/// The largest plausible |coordinate| (m) of an instrument tip in the RCM frame, as a data
/// file's ground truth gives it: the insertion reaches 0.29 m at most (`PSM_JOINT_RANGE`) and
/// the wrist and jaw add a few cm; 1 m is room for any instrument, not a place a tip can be.
pub const MAX_TIP_COORDINATE_M: f64 = 1.0;

/// The largest plausible |time| (s) of a data file's row: a run's elapsed time or a Unix time
/// (1e10 s is the year 2286). Beyond it a time is a corrupt number, not a clock.
pub const MAX_ABS_TIME_S: f64 = 1e10;

/// The largest plausible |component| of the distal part's weight in `[joint.dynamics]`, and of
/// its uncertainty (N): an instrument's shaft and wrist beyond the compliant element weigh tens
/// of grams (0.2 N); 10 N is a kilogram.
pub const MAX_DISTAL_WEIGHT_N: f64 = 10.0;

/// The largest plausible relative scatter of the calibrated `1/K` around its cubic
/// (`inverse_compliance_rel_sigma`): the 2017 recordings scatter by a few percent; 50% is no
/// stiffness model at all.
pub const MAX_STIFFNESS_REL_SIGMA: f64 = 0.5;

/// The largest plausible relative scatter of the calibrated backlash over the depths
/// (`backlash_rel_sigma`): the 2017 recordings and the simulator scatter by a few percent; 50%
/// is no backlash model at all.
pub const MAX_BACKLASH_REL_SIGMA: f64 = 0.5;
