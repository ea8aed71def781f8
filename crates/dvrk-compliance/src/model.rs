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

use crate::dynamics::{DynamicsParams, JointDynamicsState};
use crate::params::HysteresisKind;
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
    /// the paper's formula wherever `|tau_ext| > tau_min` (at exactly `tau_min` the paper gives
    /// 0 and this gives the full correction), continuous everywhere (the paper notes the dead
    /// band makes `q_hat` discontinuous). With `tau_min = 0` it reduces to the paper's formula,
    /// whose backlash term steps at `tau_ext = 0`. With a dynamics model, `tau_min` here means
    /// the whole gate `tau_min + gate_sigmas * residual_std`.
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
    /// `|tau_ext| - (tau_min + gate_sigmas * residual_std)` for joints 1 and 2 (N·m): how far
    /// the external torque is past the gate (negative: inside it); 0 for a joint without
    /// parameters. The status message carries it as `tau_margin_nm`.
    pub tau_margin_nm: [f64; 2],
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
    pub(crate) hysteresis_kind: HysteresisKind,
    pub(crate) hysteresis_gap_rad: Option<f64>,
    pub(crate) dynamics: Option<DynamicsParams>,
}

impl JointModel {
    /// The kind of the clamp hysteresis (a play unless the file says friction).
    pub fn hysteresis_kind(&self) -> HysteresisKind {
        self.hysteresis_kind
    }

    /// The internal-torque model, if the file has one.
    pub fn dynamics(&self) -> Option<&DynamicsParams> {
        self.dynamics.as_ref()
    }

    /// The gate: `tau_min + gate_sigmas * residual_std` (N·m); `tau_min` without a dynamics
    /// model.
    pub fn threshold_nm(&self) -> f64 {
        self.tau_min_nm + self.dynamics.map_or(0.0, |d| d.gate_nm())
    }

    /// The backlash added to the joint: `delta` for a play, 0 for a friction hysteresis (it is
    /// removed from `tau_ext` by the friction model instead).
    fn play_rad(&self) -> f64 {
        match self.hysteresis_kind {
            HysteresisKind::Play => self.backlash_rad,
            HysteresisKind::Friction => 0.0,
        }
    }

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
        let threshold = self.threshold_nm();
        let play = self.play_rad();
        match model {
            ModelKind::Paper => {
                if tau_ext_nm.abs() > threshold {
                    // tau_ext != 0 here, so signum is the paper's sgn.
                    play * tau_ext_nm.signum() + k * tau_ext_nm
                } else {
                    0.0
                }
            }
            ModelKind::Continuous => {
                let ramp = if threshold > 0.0 {
                    (tau_ext_nm / threshold).clamp(-1.0, 1.0)
                } else if tau_ext_nm > 0.0 {
                    1.0
                } else if tau_ext_nm < 0.0 {
                    -1.0
                } else {
                    0.0
                };
                (play + k * tau_ext_nm.abs()) * ramp
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
        let mut tau_ext = [0.0; 2];
        for (j, joint) in self.joints.iter().enumerate() {
            if let Some(joint) = joint {
                tau_ext[j] = effort[j] - joint.torque_offset.lookup(position[j]);
            }
        }
        self.correct_external(position, &tau_ext)
    }

    /// Applies the model with external torques already estimated (by [`Compensator`], which
    /// removes friction and inertia): the gate and Eq. 1. Allocates nothing.
    pub fn correct_external(&self, position: &[f64; 3], tau_ext_nm: &[f64; 2]) -> Correction {
        let raw_insertion_m = position[2];
        let mut out = Correction {
            position: *position,
            delta_rad: [0.0; 2],
            tau_ext_nm: [0.0; 2],
            active: [false; 2],
            insertion_m: raw_insertion_m,
            insertion_clamped: false,
            tau_margin_nm: [0.0; 2],
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
            let tau_ext = tau_ext_nm[j];
            let delta = joint.deflection_rad(self.model, tau_ext, insertion_m);
            out.tau_ext_nm[j] = tau_ext;
            out.tau_margin_nm[j] = tau_ext.abs() - joint.threshold_nm();
            out.delta_rad[j] = delta;
            out.active[j] = delta != 0.0;
            out.position[j] = position[j] - delta;
        }
        out
    }
}

/// The model with its state: the internal-torque estimator of [`crate::dynamics`] in front of
/// the paper's correction. For joints whose parameters have no `[joint.dynamics]` it is exactly
/// [`ComplianceConfig::correct`]. Fixed-size state, no allocation per sample.
#[derive(Clone, Debug, Default)]
pub struct Compensator {
    joints: [JointDynamicsState; 2],
}

impl Compensator {
    /// A fresh estimator (no history).
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets the filter history; keeps the friction's direction memory. Not needed for a few
    /// lost or invalid samples: [`Compensator::correct`] restarts the filter by itself after a
    /// gap of more than [`crate::dynamics::MAX_GAP_S`] or a time that goes back.
    pub fn reset(&mut self) {
        for j in &mut self.joints {
            j.reset();
        }
    }

    /// One sample at time `t_s` (s, monotonic): `tau_ext = tau_meas - tau_0(q) - tau_f - J qdd`
    /// for joints with a dynamics model, then the gate and the correction. Until the filter's
    /// window is full (48 samples after start or [`Compensator::reset`]) such a joint reports
    /// `tau_ext = 0` and is not corrected.
    pub fn correct(
        &mut self,
        config: &ComplianceConfig,
        t_s: f64,
        position: &[f64; 3],
        effort: &[f64; 3],
    ) -> Correction {
        let mut tau_ext = [0.0; 2];
        for (j, joint) in config.joints.iter().enumerate() {
            let Some(joint) = joint else { continue };
            let mut tau = effort[j] - joint.torque_offset.lookup(position[j]);
            if let Some(d) = &joint.dynamics {
                let (l, _) = joint.clamp_insertion(position[2]);
                tau -= self.joints[j].update(d, t_s, position[j], l);
                if !self.joints[j].ready() {
                    // The first WINDOW samples (after start or a reset): the motion's torque is
                    // not known yet, so nothing is taken for contact.
                    tau = 0.0;
                }
            }
            tau_ext[j] = tau;
        }
        config.correct_external(position, &tau_ext)
    }

    /// The estimator state of joint `joint_index0` (0 = yaw, 1 = pitch).
    pub fn joint_state(&self, joint_index0: usize) -> Option<&JointDynamicsState> {
        self.joints.get(joint_index0)
    }
}
