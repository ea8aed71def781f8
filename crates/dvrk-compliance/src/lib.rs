//! dvrk-compliance: the compliance model of Chrysilla et al. for the dVRK PSM, torque-offset
//! tables, parameter files, PSM and instrument kinematics, calibration procedures and fitting.
//!
//! Pure: no I/O, no clock, no logging, and no allocation per sample
//! ([`ComplianceConfig::correct`] and [`PsmKinematics::forward`] allocate nothing).
//!
//! ```
//! use dvrk_compliance::{ArmKind, ComplianceConfig, ComplianceParams, PsmKinematics, instrument};
//!
//! let text = r#"
//! [[joint]]
//! index = 2
//! backlash_rad = 0.0
//! tau_min_nm = 0.2
//! inverse_compliance_nm_per_rad = [3163.17, -1969.15, 448.92, -6.00]
//! insertion_range_m = [0.09, 0.22]
//! torque_offset = { position_rad = [0.0], effort_nm = [0.0] }
//! "#;
//! // The application parses the file (here with the `toml` crate); this crate validates it.
//! let params: ComplianceParams = toml::from_str(text).unwrap();
//! let config = ComplianceConfig::from_params(params).unwrap();
//! // Pitch pushed with 0.5 N·m at 12 cm insertion.
//! let c = config.correct(&[0.0, 0.1, 0.12], &[0.0, 0.5, 0.0]);
//! assert!(c.active[1] && c.delta_rad[1] > 0.0);
//!
//! let tool = instrument("LARGE_NEEDLE_DRIVER_400006").unwrap();
//! let fk = PsmKinematics::new(ArmKind::Classic, tool);
//! let [q1, q2, q3] = c.position;
//! let t_rcm_tip = fk.forward(&[q1, q2, q3, 0.0, 0.0, 0.0]);
//! assert!(t_rcm_tip.translation.vector.norm() < 0.12);
//! ```

pub mod bounds;
pub mod calibration;
pub mod dynamics;
pub mod exact;
pub mod fit;
pub mod instruments;
pub mod kinematics;
pub mod model;
pub mod params;
pub mod torque_offset;

pub use dynamics::{
    DistalGravityParams, DynamicsFit, DynamicsFitError, DynamicsParams, DynamicsSample, Excitation,
    REGULAR_INTERVAL_BAND, fit_dynamics, fit_dynamics_segmented, fit_dynamics_with_gravity,
    interval_regularity, median_interval,
};
pub use instruments::{
    ANY_VERSION, Generation, Instrument, InstrumentError, ToolType, ToolTypeName, VersionRange,
    Wrist, instrument, instrument_from_tool_type, instruments,
};
pub use kinematics::{ArmKind, PsmKinematics};
pub use model::{
    Compensator, ComplianceConfig, Correction, JointModel, MIN_MOTION_MODEL_RATE_HZ, ModelKind,
    trust,
};
pub use params::{
    ComplianceParams, HysteresisKind, HysteresisParams, INSERTION_LIMITS_M, JointParams,
    MAX_BACKLASH_RAD, MAX_INERTIA_KG_M2, MAX_INVERSE_COMPLIANCE_NM_PER_RAD, MAX_TAU_MIN_NM,
    MIN_INVERSE_COMPLIANCE_NM_PER_RAD, ParamsError, TorqueOffsetParams, params_to_toml,
};
pub use torque_offset::TorqueOffsetTable;
