//! Compliance parameter files: the TOML schema, its validation into a [`ComplianceConfig`], and
//! a writer for the fitter's output.
//!
//! ```toml
//! model = "paper"                  # or "continuous"; default "paper"
//! [[joint]]
//! index = 1                        # 1 = yaw, 2 = pitch
//! backlash_rad = 0.0
//! tau_min_nm = 0.1
//! inverse_compliance_nm_per_rad = [639.16, -432.35, 136.32, 3.12]   # c3, c2, c1, c0
//! insertion_range_m = [0.09, 0.22]
//! torque_offset = { position_rad = [-1.0, 1.0], effort_nm = [0.0, 0.0] }
//! ```
//!
//! Parsing (syntax, then schema) gives [`ComplianceParams`]; [`ComplianceConfig::from_params`]
//! checks the numbers. Every check names the joint, the field and the offending value.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use crate::dynamics::DynamicsParams;
use crate::model::{ComplianceConfig, JointModel, ModelKind, cubic};
use crate::torque_offset::TorqueOffsetTable;

pub use crate::bounds::{
    INSERTION_LIMITS_M, MAX_BACKLASH_RAD, MAX_DISTAL_WEIGHT_N, MAX_INERTIA_KG_M2, MAX_TAU_MIN_NM,
    PSM_JOINT_RANGE,
};

/// The smallest plausible `1/K(L)` (N·m/rad): see [`crate::bounds::INVERSE_COMPLIANCE_NM_PER_RAD`].
pub const MIN_INVERSE_COMPLIANCE_NM_PER_RAD: f64 = crate::bounds::INVERSE_COMPLIANCE_NM_PER_RAD[0];
/// The largest plausible `1/K(L)` (N·m/rad): see [`crate::bounds::INVERSE_COMPLIANCE_NM_PER_RAD`].
pub const MAX_INVERSE_COMPLIANCE_NM_PER_RAD: f64 = crate::bounds::INVERSE_COMPLIANCE_NM_PER_RAD[1];

/// A parameter file as parsed, before validation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComplianceParams {
    /// Correction formula; `"paper"` when absent.
    #[serde(default)]
    pub model: ModelKind,
    /// One entry per corrected joint (at most one each for joints 1 and 2).
    pub joint: Vec<JointParams>,
}

/// The parameters of one joint (`[[joint]]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointParams {
    /// 1 = yaw, 2 = pitch (the paper's joint numbers).
    pub index: i64,
    /// Backlash `delta` (rad), >= 0.
    pub backlash_rad: f64,
    /// Dead band `tau_min` (N·m), >= 0.
    pub tau_min_nm: f64,
    /// `[c3, c2, c1, c0]`: `1/K(L) = c3 L^3 + c2 L^2 + c1 L + c0` (N·m/rad, L in m).
    #[serde(deserialize_with = "crate::exact::array")]
    pub inverse_compliance_nm_per_rad: [f64; 4],
    /// `[min, max]` (m) of the calibrated insertion depths; L is clamped into it.
    #[serde(deserialize_with = "crate::exact::array")]
    pub insertion_range_m: [f64; 2],
    /// The relative scatter (1 sigma) of the calibrated `1/K` of the depths around the cubic, as
    /// `fit` found it: the stiffness's uncertainty in each sample's 95% bound (issue 20). Absent
    /// (older files, the paper's): [`crate::model::STIFFNESS_REL_SIGMA`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inverse_compliance_rel_sigma: Option<f64>,
    /// The relative scatter (1 sigma) of the backlash over the calibrated depths, as `fit` found
    /// it: the backlash's uncertainty in each sample's 95% bound (issue 20). Absent (older
    /// files, the paper's): [`crate::model::BACKLASH_REL_SIGMA`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backlash_rel_sigma: Option<f64>,
    /// The torque offset table `tau_0(q)`.
    pub torque_offset: TorqueOffsetParams,
    /// The kind and signed gap of the clamp hysteresis, as `fit` found it; absent = a play.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hysteresis: Option<HysteresisParams>,
    /// The internal-torque model (`[joint.dynamics]`, see [`crate::dynamics`]); absent =
    /// `tau_ext = tau_meas - tau_0(q)` as in the paper.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dynamics: Option<DynamicsParams>,
}

/// `hysteresis = { kind = "friction", gap_rad = 0.006 }`.
///
/// `gap_rad` is `fit`'s signed gap between the clamp data's two lines, `zero(-) - zero(+)`
/// (where each crosses `tau_ext = 0`): a play gives `-2 delta`, a friction in the
/// transmission a positive gap (the effort leads the motion by the friction); the 2017 data
/// show +3 to +10 mrad.
/// At run time a play is corrected with `backlash_rad` as the paper does; a friction hysteresis
/// is removed from `tau_ext` by the friction of `[joint.dynamics]`, and `backlash_rad` is not
/// added to the joint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HysteresisParams {
    pub kind: HysteresisKind,
    pub gap_rad: f64,
}

/// What causes a joint's clamp hysteresis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HysteresisKind {
    /// A backlash play in the transmission (the paper's `delta`).
    #[default]
    Play,
    /// Friction in the transmission (the 2017 data).
    Friction,
}

/// `torque_offset = { position_rad = [..], effort_nm = [..] }`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorqueOffsetParams {
    /// Joint positions (rad), strictly increasing.
    pub position_rad: Vec<f64>,
    /// Effort with no external load at each position (N·m).
    pub effort_nm: Vec<f64>,
}

/// Why a parameter file was rejected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ParamsError {
    /// `index` is neither 1 (yaw) nor 2 (pitch).
    #[error("joint {joint}: index = {joint} must be 1 (yaw) or 2 (pitch)")]
    JointIndex { joint: i64 },
    /// Two `[[joint]]` entries with the same index.
    #[error("joint {joint}: listed twice")]
    DuplicateJoint { joint: i64 },
    /// A NaN or infinite number.
    #[error("joint {joint}: {field} = {value} is not a finite number")]
    NonFinite {
        joint: i64,
        field: String,
        value: f64,
    },
    /// A negative backlash or dead band.
    #[error("joint {joint}: {field} = {value} must not be negative")]
    Negative {
        joint: i64,
        field: String,
        value: f64,
    },
    /// `insertion_range_m` reversed or outside [0, 0.24] m.
    #[error(
        "joint {joint}: insertion_range_m = [{min_m}, {max_m}] must satisfy 0 <= min <= max <= 0.24 m"
    )]
    InsertionRange { joint: i64, min_m: f64, max_m: f64 },
    /// The cubic `1/K(L)` is below [`MIN_INVERSE_COMPLIANCE_NM_PER_RAD`] (or not finite)
    /// somewhere in the insertion range: no instrument shaft is that soft, so the cubic is a
    /// fit error.
    #[error(
        "joint {joint}: inverse_compliance_nm_per_rad gives 1/K({insertion_m} m) = {value:?} N·m/rad; \
         it must be finite and >= {MIN_INVERSE_COMPLIANCE_NM_PER_RAD} N·m/rad over \
         insertion_range_m (a softer shaft is a fit error; the paper's are 12-31 N·m/rad)"
    )]
    StiffnessTooLow {
        joint: i64,
        insertion_m: f64,
        value: f64,
    },
    /// The cubic `1/K(L)` is above [`MAX_INVERSE_COMPLIANCE_NM_PER_RAD`] somewhere in the
    /// insertion range: a shaft that stiff would need no correction, so the cubic is a fit error.
    #[error(
        "joint {joint}: inverse_compliance_nm_per_rad gives 1/K({insertion_m} m) = {value:?} N·m/rad; \
         it must be <= {MAX_INVERSE_COMPLIANCE_NM_PER_RAD} N·m/rad over insertion_range_m (a \
         stiffer shaft is a fit error; the paper's are 12-31 N·m/rad)"
    )]
    StiffnessTooHigh {
        joint: i64,
        insertion_m: f64,
        value: f64,
    },
    /// A torque offset table position outside the joint's range ([`PSM_JOINT_RANGE`]).
    #[error(
        "joint {joint}: torque_offset.position_rad[{element}] = {value:?} rad is outside the joint's \
         range [{min}, {max}] rad"
    )]
    TorqueOffsetOutOfRange {
        joint: i64,
        element: usize,
        value: f64,
        min: f64,
        max: f64,
    },
    /// A backlash or dead band beyond its physical bound ([`MAX_BACKLASH_RAD`],
    /// [`MAX_TAU_MIN_NM`]).
    #[error("joint {joint}: {field} = {value:?} exceeds its physical bound {max}")]
    AboveBound {
        joint: i64,
        field: String,
        value: f64,
        max: f64,
    },
    /// `torque_offset.position_rad` and `effort_nm` have different lengths.
    #[error(
        "joint {joint}: torque_offset has {positions} position_rad values and {efforts} effort_nm values"
    )]
    TorqueOffsetLength {
        joint: i64,
        positions: usize,
        efforts: usize,
    },
    /// `torque_offset` has no points.
    #[error("joint {joint}: torque_offset.position_rad is empty; give at least one point")]
    TorqueOffsetEmpty { joint: i64 },
    /// `torque_offset.position_rad[element]` is not greater than the previous position.
    #[error(
        "joint {joint}: torque_offset.position_rad[{element}] = {value} is not greater than the previous position"
    )]
    TorqueOffsetNotIncreasing {
        joint: i64,
        element: usize,
        value: f64,
    },
}

impl ComplianceParams {
    /// Writes the parameters as a TOML file that deserialises back (serde + any TOML parser) to
    /// an equal value (bit-for-bit floats; NaN stays NaN). Written by hand so that this crate
    /// needs no TOML library: parsing text is the application's job (ARCHITECTURE.md).
    pub fn to_toml_string(&self) -> String {
        let mut s = String::new();
        // `write!` into a String cannot fail; the results are ignored for that reason.
        let _ = writeln!(
            s,
            "# dvrk-compliance parameters (compliance model of Chrysilla et al., Eq. 1-4)"
        );
        let model = match self.model {
            ModelKind::Paper => "paper",
            ModelKind::Continuous => "continuous",
        };
        let _ = writeln!(s, "model = \"{model}\"");
        if self.joint.is_empty() {
            let _ = writeln!(s, "joint = []");
        }
        for j in &self.joint {
            let _ = writeln!(s, "\n[[joint]]");
            let _ = writeln!(s, "index = {}", j.index);
            let _ = writeln!(s, "backlash_rad = {}", toml_float(j.backlash_rad));
            let _ = writeln!(s, "tau_min_nm = {}", toml_float(j.tau_min_nm));
            let _ = writeln!(
                s,
                "inverse_compliance_nm_per_rad = {}   # c3, c2, c1, c0",
                toml_array(&j.inverse_compliance_nm_per_rad)
            );
            let _ = writeln!(
                s,
                "insertion_range_m = {}",
                toml_array(&j.insertion_range_m)
            );
            if let Some(r) = j.inverse_compliance_rel_sigma {
                let _ = writeln!(s, "inverse_compliance_rel_sigma = {}", toml_float(r));
            }
            if let Some(r) = j.backlash_rel_sigma {
                let _ = writeln!(s, "backlash_rel_sigma = {}", toml_float(r));
            }
            if let Some(h) = &j.hysteresis {
                let kind = match h.kind {
                    HysteresisKind::Play => "play",
                    HysteresisKind::Friction => "friction",
                };
                let _ = writeln!(
                    s,
                    "hysteresis = {{ kind = \"{kind}\", gap_rad = {} }}",
                    toml_float(h.gap_rad)
                );
            }
            if let Some(d) = &j.dynamics {
                let max_acc = d
                    .max_acceleration_rad_per_s2
                    .map(|a| format!(", max_acceleration_rad_per_s2 = {}", toml_float(a)))
                    .unwrap_or_default();
                let gravity = d
                    .distal_gravity
                    .map(|g| {
                        format!(
                            ", distal_gravity = {{ weight_n = {}, weight_sigma_n = {}, \
                             reference_insertion_m = {} }}",
                            toml_array(&g.weight_n),
                            toml_array(&g.weight_sigma_n),
                            toml_float(g.reference_insertion_m)
                        )
                    })
                    .unwrap_or_default();
                let _ = writeln!(
                    s,
                    "dynamics = {{ inertia_kg_m2 = {}, viscous_nm_s_per_rad = {}, coulomb_nm = {}, \
                     stick_velocity_rad_per_s = {}, residual_std_nm = {}, gate_sigmas = {}{max_acc}{gravity} }}",
                    toml_array(&d.inertia_kg_m2),
                    toml_float(d.viscous_nm_s_per_rad),
                    toml_float(d.coulomb_nm),
                    toml_float(d.stick_velocity_rad_per_s),
                    toml_float(d.residual_std_nm),
                    toml_float(d.gate_sigmas)
                );
            }
            let _ = writeln!(s, "[joint.torque_offset]");
            let _ = writeln!(
                s,
                "position_rad = {}",
                toml_array(&j.torque_offset.position_rad)
            );
            let _ = writeln!(s, "effort_nm = {}", toml_array(&j.torque_offset.effort_nm));
        }
        s
    }
}

/// Writes `p` as TOML (see [`ComplianceParams::to_toml_string`]); used by `dvrk-sidecar fit`.
pub fn params_to_toml(p: &ComplianceParams) -> String {
    p.to_toml_string()
}

/// A TOML float that parses back to exactly `x`: Rust's shortest round-trip form always has a
/// fraction or an exponent, which TOML requires; NaN and the infinities use TOML's spelling.
fn toml_float(x: f64) -> String {
    if x.is_nan() {
        "nan".to_owned()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.to_owned()
    } else {
        format!("{x:?}")
    }
}

fn toml_array(xs: &[f64]) -> String {
    let items: Vec<String> = xs.iter().map(|&x| toml_float(x)).collect();
    format!("[{}]", items.join(", "))
}

impl ComplianceConfig {
    /// Validates parsed parameters. The checks, each reported with joint, field and value:
    /// index 1 or 2 and not repeated; every number finite; `0 <= backlash <= 0.02` rad and
    /// `0 <= tau_min <= 1` N·m; `0 <= min <= max <= 0.24` m; a non-empty torque offset table
    /// with equal lengths and strictly increasing positions within the joint's range; `1/K(L)`
    /// within `2..=500` N·m/rad on the whole insertion range (the bounds are stated once, in
    /// [`crate::bounds`]).
    pub fn from_params(p: ComplianceParams) -> Result<Self, ParamsError> {
        let mut joints: [Option<JointModel>; 2] = [None, None];
        for jp in p.joint {
            let joint = jp.index;
            let slot = match joint {
                1 => &mut joints[0],
                2 => &mut joints[1],
                _ => return Err(ParamsError::JointIndex { joint }),
            };
            if slot.is_some() {
                return Err(ParamsError::DuplicateJoint { joint });
            }
            *slot = Some(validate_joint(jp)?);
        }
        Ok(Self {
            model: p.model,
            joints,
        })
    }

    /// The parameters this configuration was built from (round trip for the fitter's output).
    pub fn to_params(&self) -> ComplianceParams {
        let joint = self
            .joints
            .iter()
            .zip([1_i64, 2])
            .filter_map(|(j, index)| {
                j.as_ref().map(|j| JointParams {
                    index,
                    backlash_rad: j.backlash_rad,
                    tau_min_nm: j.tau_min_nm,
                    inverse_compliance_nm_per_rad: j.inverse_compliance_nm_per_rad,
                    insertion_range_m: j.insertion_range_m,
                    inverse_compliance_rel_sigma: j.stiffness_rel_sigma_from_file,
                    backlash_rel_sigma: j.backlash_rel_sigma_from_file,
                    torque_offset: TorqueOffsetParams {
                        position_rad: j.torque_offset.position_rad().to_vec(),
                        effort_nm: j.torque_offset.effort_nm().to_vec(),
                    },
                    hysteresis: j.hysteresis_gap_rad.map(|gap_rad| HysteresisParams {
                        kind: j.hysteresis_kind,
                        gap_rad,
                    }),
                    dynamics: j.dynamics,
                })
            })
            .collect();
        ComplianceParams {
            model: self.model,
            joint,
        }
    }
}

fn check_finite(joint: i64, field: &str, values: &[f64], indexed: bool) -> Result<(), ParamsError> {
    for (i, &value) in values.iter().enumerate() {
        if !value.is_finite() {
            let field = if indexed {
                format!("{field}[{i}]")
            } else {
                field.to_owned()
            };
            return Err(ParamsError::NonFinite {
                joint,
                field,
                value,
            });
        }
    }
    Ok(())
}

fn validate_joint(jp: JointParams) -> Result<JointModel, ParamsError> {
    let joint = jp.index;
    let JointParams {
        backlash_rad,
        tau_min_nm,
        inverse_compliance_nm_per_rad: coeffs,
        insertion_range_m: [min_m, max_m],
        inverse_compliance_rel_sigma,
        backlash_rel_sigma,
        torque_offset,
        hysteresis,
        dynamics,
        ..
    } = jp;
    for (field, value, max) in [
        (
            "inverse_compliance_rel_sigma",
            inverse_compliance_rel_sigma,
            crate::bounds::MAX_STIFFNESS_REL_SIGMA,
        ),
        (
            "backlash_rel_sigma",
            backlash_rel_sigma,
            crate::bounds::MAX_BACKLASH_REL_SIGMA,
        ),
    ] {
        let Some(r) = value else { continue };
        check_finite(joint, field, &[r], false)?;
        if r < 0.0 {
            return Err(ParamsError::Negative {
                joint,
                field: field.to_owned(),
                value: r,
            });
        }
        if r > max {
            return Err(ParamsError::AboveBound {
                joint,
                field: field.to_owned(),
                value: r,
                max,
            });
        }
    }

    check_finite(joint, "backlash_rad", &[backlash_rad], false)?;
    check_finite(joint, "tau_min_nm", &[tau_min_nm], false)?;
    check_finite(joint, "inverse_compliance_nm_per_rad", &coeffs, true)?;
    check_finite(joint, "insertion_range_m", &[min_m, max_m], true)?;
    check_finite(
        joint,
        "torque_offset.position_rad",
        &torque_offset.position_rad,
        true,
    )?;
    check_finite(
        joint,
        "torque_offset.effort_nm",
        &torque_offset.effort_nm,
        true,
    )?;

    for (field, value) in [("backlash_rad", backlash_rad), ("tau_min_nm", tau_min_nm)] {
        if value < 0.0 {
            let field = field.to_owned();
            return Err(ParamsError::Negative {
                joint,
                field,
                value,
            });
        }
    }

    for (field, value, max) in [
        ("backlash_rad", backlash_rad, MAX_BACKLASH_RAD),
        ("tau_min_nm", tau_min_nm, MAX_TAU_MIN_NM),
    ] {
        if value > max {
            let field = field.to_owned();
            return Err(ParamsError::AboveBound {
                joint,
                field,
                value,
                max,
            });
        }
    }

    let [lim_lo, lim_hi] = INSERTION_LIMITS_M;
    if !(lim_lo <= min_m && min_m <= max_m && max_m <= lim_hi) {
        return Err(ParamsError::InsertionRange {
            joint,
            min_m,
            max_m,
        });
    }

    let (positions, efforts) = (
        torque_offset.position_rad.len(),
        torque_offset.effort_nm.len(),
    );
    if positions != efforts {
        return Err(ParamsError::TorqueOffsetLength {
            joint,
            positions,
            efforts,
        });
    }
    if positions == 0 {
        return Err(ParamsError::TorqueOffsetEmpty { joint });
    }
    // Joint 1 or 2 here (the index was checked by the caller).
    let [min, max] = PSM_JOINT_RANGE[usize::from(joint == 2)];
    if let Some((element, &value)) = torque_offset
        .position_rad
        .iter()
        .enumerate()
        .find(|&(_, &q)| !(min..=max).contains(&q))
    {
        return Err(ParamsError::TorqueOffsetOutOfRange {
            joint,
            element,
            value,
            min,
            max,
        });
    }
    for (i, w) in torque_offset.position_rad.windows(2).enumerate() {
        if w[1] <= w[0] {
            let (element, value) = (i + 1, w[1]);
            return Err(ParamsError::TorqueOffsetNotIncreasing {
                joint,
                element,
                value,
            });
        }
    }

    let (insertion_m, value) = cubic_minimum(&coeffs, [min_m, max_m]);
    if !(value >= MIN_INVERSE_COMPLIANCE_NM_PER_RAD && value.is_finite()) {
        return Err(ParamsError::StiffnessTooLow {
            joint,
            insertion_m,
            value,
        });
    }
    // The maximum of the cubic is the minimum of its negation.
    let (insertion_m, negated) = cubic_minimum(&coeffs.map(|c| -c), [min_m, max_m]);
    let value = -negated;
    if value > MAX_INVERSE_COMPLIANCE_NM_PER_RAD {
        return Err(ParamsError::StiffnessTooHigh {
            joint,
            insertion_m,
            value,
        });
    }

    if let Some(h) = &hysteresis {
        check_finite(joint, "hysteresis.gap_rad", &[h.gap_rad], false)?;
    }
    if let Some(d) = &dynamics {
        check_finite(joint, "dynamics.inertia_kg_m2", &d.inertia_kg_m2, true)?;
        for (field, value, max) in [
            (
                "dynamics.inertia_kg_m2[0]",
                d.inertia_kg_m2[0],
                MAX_INERTIA_KG_M2,
            ),
            (
                "dynamics.inertia_kg_m2[1]",
                d.inertia_kg_m2[1],
                MAX_INERTIA_KG_M2 / 0.01,
            ),
            (
                "dynamics.viscous_nm_s_per_rad",
                d.viscous_nm_s_per_rad,
                10.0,
            ),
            ("dynamics.coulomb_nm", d.coulomb_nm, MAX_TAU_MIN_NM),
            (
                "dynamics.stick_velocity_rad_per_s",
                d.stick_velocity_rad_per_s,
                1.0,
            ),
            (
                "dynamics.residual_std_nm",
                d.residual_std_nm,
                MAX_TAU_MIN_NM,
            ),
            ("dynamics.gate_sigmas", d.gate_sigmas, 10.0),
            (
                "dynamics.max_acceleration_rad_per_s2",
                d.max_acceleration_rad_per_s2.unwrap_or(0.0),
                1000.0,
            ),
        ] {
            check_finite(joint, field, &[value], false)?;
            if value < 0.0 {
                let field = field.to_owned();
                return Err(ParamsError::Negative {
                    joint,
                    field,
                    value,
                });
            }
            if value > max {
                let field = field.to_owned();
                return Err(ParamsError::AboveBound {
                    joint,
                    field,
                    value,
                    max,
                });
            }
        }
        if let Some(g) = &d.distal_gravity {
            check_finite(joint, "dynamics.distal_gravity.weight_n", &g.weight_n, true)?;
            check_finite(
                joint,
                "dynamics.distal_gravity.weight_sigma_n",
                &g.weight_sigma_n,
                true,
            )?;
            check_finite(
                joint,
                "dynamics.distal_gravity.reference_insertion_m",
                &[g.reference_insertion_m],
                false,
            )?;
            // An instrument's distal part weighs grams: 10 N is a kilogram, far beyond it.
            for (k, (&w, &sd)) in g.weight_n.iter().zip(&g.weight_sigma_n).enumerate() {
                let checks = [
                    (format!("dynamics.distal_gravity.weight_n[{k}]"), w.abs(), w),
                    (
                        format!("dynamics.distal_gravity.weight_sigma_n[{k}]"),
                        sd,
                        sd,
                    ),
                ];
                for (field, magnitude, value) in checks {
                    if value < 0.0 && field.contains("sigma") {
                        return Err(ParamsError::Negative {
                            joint,
                            field,
                            value,
                        });
                    }
                    if magnitude > MAX_DISTAL_WEIGHT_N {
                        return Err(ParamsError::AboveBound {
                            joint,
                            field,
                            value,
                            max: MAX_DISTAL_WEIGHT_N,
                        });
                    }
                }
            }
            let r = g.reference_insertion_m;
            if r < 0.0 {
                return Err(ParamsError::Negative {
                    joint,
                    field: "dynamics.distal_gravity.reference_insertion_m".to_owned(),
                    value: r,
                });
            }
            if r > 1.0 {
                return Err(ParamsError::AboveBound {
                    joint,
                    field: "dynamics.distal_gravity.reference_insertion_m".to_owned(),
                    value: r,
                    max: 1.0,
                });
            }
        }
    }

    Ok(JointModel {
        hysteresis_kind: hysteresis.map(|h| h.kind).unwrap_or_default(),
        hysteresis_gap_rad: hysteresis.map(|h| h.gap_rad),
        dynamics,
        backlash_rad,
        tau_min_nm,
        inverse_compliance_nm_per_rad: coeffs,
        insertion_range_m: [min_m, max_m],
        stiffness_rel_sigma_from_file: inverse_compliance_rel_sigma,
        backlash_rel_sigma_from_file: backlash_rel_sigma,
        torque_offset: TorqueOffsetTable::from_validated(
            torque_offset.position_rad,
            torque_offset.effort_nm,
        ),
    })
}

/// The smallest value of the cubic `c` on `[lo, hi]` and where it occurs (a non-finite value
/// wins, so it is reported).
///
/// A continuous function's minimum on a closed interval lies at an end or where the derivative
/// vanishes, so evaluating the ends and the real roots of `3 c3 L^2 + 2 c2 L + c1` inside the
/// interval finds it exactly, however narrow a dip below zero is. (Any root of the cubic inside
/// the range makes that minimum <= 0, so roots need no separate search.)
pub(crate) fn cubic_minimum(c: &[f64; 4], [lo, hi]: [f64; 2]) -> (f64, f64) {
    let mut best = (lo, cubic(c, lo));
    let mut consider = |x: f64| {
        if (lo..=hi).contains(&x) {
            let v = cubic(c, x);
            if !v.is_finite() || v < best.1 {
                best = (x, v);
            }
        }
    };
    consider(hi);
    // Derivative a x^2 + b x + k with a = 3 c3, b = 2 c2, k = c1.
    let (a, b, k) = (3.0 * c[0], 2.0 * c[1], c[2]);
    if a == 0.0 {
        if b != 0.0 {
            consider(-k / b);
        }
    } else {
        let disc = b * b - 4.0 * a * k;
        if disc >= 0.0 {
            // Numerically stable pair of roots: q = -(b + sgn(b) sqrt(disc)) / 2, x = q/a, k/q.
            let q = -0.5 * (b + disc.sqrt().copysign(b));
            if q != 0.0 {
                consider(q / a);
                consider(k / q);
            } else {
                // b = 0 and disc = 0, so k = 0: a double root at 0.
                consider(0.0);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_minimum_finds_interior_minimum_of_a_quadratic() {
        // 1000 (L - 0.155)^2 - 0.001 = 1000 L^2 - 310 L + 24.024: minimum -0.001 at 0.155.
        let c = [0.0, 1000.0, -310.0, 24.024];
        let (x, v) = cubic_minimum(&c, [0.09, 0.22]);
        assert!((x - 0.155).abs() < 1e-12, "{x}");
        assert!((v + 0.001).abs() < 1e-9, "{v}");
    }

    #[test]
    fn cubic_minimum_uses_the_end_when_monotonic() {
        // The paper's joint-2 cubic has no real critical point: the minimum is at the lower end.
        let c = [3163.17, -1969.15, 448.92, -6.00];
        let (x, _) = cubic_minimum(&c, [0.09, 0.22]);
        assert_eq!(x, 0.09);
        // Decreasing line: minimum at the upper end.
        let (x, v) = cubic_minimum(&[0.0, 0.0, -10.0, 5.0], [0.1, 0.2]);
        assert_eq!(x, 0.2);
        assert!((v - 3.0).abs() < 1e-12);
    }

    #[test]
    fn cubic_minimum_with_a_local_minimum_of_a_true_cubic() {
        // (L - 0.1)(L - 0.2)(L - 0.3) * 1000 + 0.1: local minimum inside [0.1, 0.3] at
        // L = 0.2 + 0.1/sqrt(3) = 0.25774, value 1000 * (-0.0003849) + 0.1 = -0.2849.
        // Coefficients: 1000 L^3 - 600 L^2 + 110 L - 6 + 0.1.
        let c = [1000.0, -600.0, 110.0, -5.9];
        let (x, v) = cubic_minimum(&c, [0.1, 0.3]);
        assert!((x - (0.2 + 0.1 / 3f64.sqrt())).abs() < 1e-9, "{x}");
        assert!((v + 0.284_900_2).abs() < 1e-6, "{v}");
    }

    #[test]
    fn toml_float_spellings_parse_back() {
        for x in [
            0.0,
            -0.0,
            1.0,
            0.1,
            1e-7,
            1.5e300,
            -2.5e-300,
            3.0e16,
            f64::MIN_POSITIVE,
        ] {
            let s = toml_float(x);
            let v: toml::Table = format!("x = {s}")
                .parse()
                .unwrap_or_else(|e| panic!("{s}: {e}"));
            assert_eq!(
                v["x"].as_float().map(f64::to_bits),
                Some(x.to_bits()),
                "{s}"
            );
        }
        assert_eq!(toml_float(f64::NAN), "nan");
        assert_eq!(toml_float(f64::NEG_INFINITY), "-inf");
    }
}
