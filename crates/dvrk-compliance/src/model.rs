//! The compliance model of paper section 2 (Eq. 1-4) applied to joints 1 (yaw) and 2 (pitch).
//!
//! For joint j with measured position q, measured effort tau_meas and insertion L (joint 3, m):
//!
//! ```text
//! tau_ext = tau_meas - tau_0(q)                                  (Table 1: tau_0 used as tau_int)
//! K(L)    = 1 / (c3 L^3 + c2 L^2 + c1 L + c0)                    (Eq. 3 and 4, rad/N·m)
//! paper:      delta_q = delta sgn(tau_ext) + K(L) tau_ext   if |tau_ext| > tau_min, else 0  (Eq. 1, 2)
//! continuous: delta_q = (delta + K(L) |tau_ext|) clamp(tau_ext / tau_min, -1, 1)
//! q_hat   = q - delta_q
//! ```
//!
//! L is first clamped into the parameters' insertion range: the cubics are fits over the
//! calibrated depths only, and outside them they can reach zero (the paper's joint-2 cubic has a
//! root near L = 0.0142 m, where K would be infinite).

use serde::{Deserialize, Serialize};

use crate::torque_offset::TorqueOffsetTable;

/// Which correction formula to apply.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// The paper's Eq. 2: no correction inside the dead band `|tau_ext| <= tau_min`, the full
    /// correction outside it. `q_hat` jumps by `delta + K tau_min` at the band's edge.
    #[default]
    Paper,
    /// For feedback loops: `(delta + K |tau_ext|) * clamp(tau_ext / tau_min, -1, 1)`. Equal to
    /// the paper's formula wherever `|tau_ext| >= tau_min`, continuous everywhere (the paper
    /// notes the dead band makes `q_hat` discontinuous). With `tau_min = 0` it reduces to the
    /// paper's formula, whose backlash term steps at `tau_ext = 0`.
    Continuous,
}

/// The result of [`ComplianceConfig::correct`] for one sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correction {
    /// `q_hat` for joints 1..3 (rad, rad, m). Joint 3 passes through unchanged.
    pub position: [f64; 3],
    /// `q - q_hat` for joints 1 and 2 (rad): the modelled deflection `delta_q`.
    pub delta_rad: [f64; 2],
    /// `tau_ext = tau_meas - tau_0(q)` for joints 1 and 2 (N·m); 0 for a joint without parameters.
    pub tau_ext_nm: [f64; 2],
    /// Whether the correction changed the joint, i.e. `delta_rad != 0`. Paper mode: outside the
    /// dead band. Continuous mode: whenever `tau_ext != 0`. Always false for a joint without
    /// parameters.
    pub active: [bool; 2],
    /// The insertion L (m) used for K(L), after clamping. If joints 1 and 2 have different
    /// insertion ranges this is joint 1's value; with no joint parameters it is the input.
    pub insertion_m: f64,
    /// Whether the measured insertion lay outside a configured joint's insertion range.
    pub insertion_clamped: bool,
}

/// The validated model of one joint: backlash, dead band, inverse compliance cubic, insertion
/// range and torque offset table.
#[derive(Clone, Debug, PartialEq)]
pub struct JointModel {
    pub(crate) backlash_rad: f64,
    pub(crate) tau_min_nm: f64,
    /// `[c3, c2, c1, c0]` of `1/K(L)` in N·m/rad.
    pub(crate) inverse_compliance_nm_per_rad: [f64; 4],
    pub(crate) insertion_range_m: [f64; 2],
    pub(crate) torque_offset: TorqueOffsetTable,
}

impl JointModel {
    /// Backlash `delta` (rad).
    pub fn backlash_rad(&self) -> f64 {
        self.backlash_rad
    }

    /// Dead band `tau_min` (N·m).
    pub fn tau_min_nm(&self) -> f64 {
        self.tau_min_nm
    }

    /// The cubic's coefficients `[c3, c2, c1, c0]` (N·m/rad per power of m).
    pub fn inverse_compliance_coefficients(&self) -> [f64; 4] {
        self.inverse_compliance_nm_per_rad
    }

    /// The insertion range `[min, max]` (m) over which the cubic is valid (positive).
    pub fn insertion_range_m(&self) -> [f64; 2] {
        self.insertion_range_m
    }

    /// The torque offset table `tau_0(q)`.
    pub fn torque_offset(&self) -> &TorqueOffsetTable {
        &self.torque_offset
    }

    /// `1/K(L)` (N·m/rad), the cubic of Eq. 3/4 evaluated at `insertion_m` without clamping.
    pub fn inverse_compliance_nm_per_rad(&self, insertion_m: f64) -> f64 {
        cubic(&self.inverse_compliance_nm_per_rad, insertion_m)
    }

    /// `insertion_m` clamped into the insertion range, and whether it had to be clamped.
    /// NaN stays NaN and is not reported as clamped.
    pub fn clamp_insertion(&self, insertion_m: f64) -> (f64, bool) {
        let [lo, hi] = self.insertion_range_m;
        if insertion_m < lo {
            (lo, true)
        } else if insertion_m > hi {
            (hi, true)
        } else {
            (insertion_m, false)
        }
    }

    /// `delta_q` for a given `tau_ext` and an already clamped insertion: Eq. 1 gated by Eq. 2
    /// (`Paper`) or the continuous ramp (`Continuous`).
    pub fn deflection_rad(
        &self,
        model: ModelKind,
        tau_ext_nm: f64,
        clamped_insertion_m: f64,
    ) -> f64 {
        let k = 1.0 / cubic(&self.inverse_compliance_nm_per_rad, clamped_insertion_m);
        match model {
            ModelKind::Paper => {
                if tau_ext_nm.abs() > self.tau_min_nm {
                    // tau_ext != 0 here, so signum is the paper's sgn.
                    self.backlash_rad * tau_ext_nm.signum() + k * tau_ext_nm
                } else {
                    0.0
                }
            }
            ModelKind::Continuous => {
                let ramp = if self.tau_min_nm > 0.0 {
                    (tau_ext_nm / self.tau_min_nm).clamp(-1.0, 1.0)
                } else if tau_ext_nm > 0.0 {
                    1.0
                } else if tau_ext_nm < 0.0 {
                    -1.0
                } else {
                    0.0
                };
                (self.backlash_rad + k * tau_ext_nm.abs()) * ramp
            }
        }
    }
}

/// `c3 x^3 + c2 x^2 + c1 x + c0` by Horner's rule.
#[inline]
pub(crate) fn cubic(c: &[f64; 4], x: f64) -> f64 {
    ((c[0] * x + c[1]) * x + c[2]) * x + c[3]
}

/// The validated compliance parameters of one arm; build it with
/// [`ComplianceConfig::from_params`] from parsed [`crate::ComplianceParams`].
#[derive(Clone, Debug, PartialEq)]
pub struct ComplianceConfig {
    pub(crate) model: ModelKind,
    /// Joint 1 (yaw) and joint 2 (pitch); `None` = not corrected.
    pub(crate) joints: [Option<JointModel>; 2],
}

impl ComplianceConfig {
    /// The correction formula in use.
    pub fn model(&self) -> ModelKind {
        self.model
    }

    /// The model of joint `joint_index0` (0 = yaw, 1 = pitch), if it has parameters.
    pub fn joint(&self, joint_index0: usize) -> Option<&JointModel> {
        self.joints.get(joint_index0).and_then(Option::as_ref)
    }

    /// The insertion range (m) of joint `joint_index0` (0 = yaw, 1 = pitch), if configured.
    pub fn insertion_range_m(&self, joint_index0: usize) -> Option<[f64; 2]> {
        self.joint(joint_index0).map(JointModel::insertion_range_m)
    }

    /// Applies the model to one sample: measured positions of joints 1..3 (rad, rad, m) and
    /// measured efforts (N·m, N·m, N; the insertion effort is unused). Allocates nothing.
    ///
    /// Joints without parameters pass through (`active = false`, `tau_ext = 0`). Non-finite
    /// inputs never panic; a NaN effort leaves the joint unchanged in paper mode and gives NaN in
    /// continuous mode, a NaN insertion gives NaN for the corrected joints.
    pub fn correct(&self, position: &[f64; 3], effort: &[f64; 3]) -> Correction {
        let raw_insertion_m = position[2];
        let mut out = Correction {
            position: *position,
            delta_rad: [0.0; 2],
            tau_ext_nm: [0.0; 2],
            active: [false; 2],
            insertion_m: raw_insertion_m,
            insertion_clamped: false,
        };
        let mut insertion_reported = false;
        for (j, joint) in self.joints.iter().enumerate() {
            let Some(joint) = joint else { continue };
            let (insertion_m, clamped) = joint.clamp_insertion(raw_insertion_m);
            if !insertion_reported {
                out.insertion_m = insertion_m;
                insertion_reported = true;
            }
            out.insertion_clamped |= clamped;
            let tau_ext = effort[j] - joint.torque_offset.lookup(position[j]);
            let delta = joint.deflection_rad(self.model, tau_ext, insertion_m);
            out.tau_ext_nm[j] = tau_ext;
            out.delta_rad[j] = delta;
            out.active[j] = delta != 0.0;
            out.position[j] = position[j] - delta;
        }
        out
    }
}
