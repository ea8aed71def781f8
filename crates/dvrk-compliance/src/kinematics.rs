//! PSM forward kinematics as the dVRK computes it (reference section 1.1-1.3).
//!
//! Modified (Craig) DH, one transform per link: `Rx(alpha) · Tx(a) · Rz(theta) · Tz(d)`, with
//! `theta = theta_DH + offset + q` (revolute) or `d = D_DH + offset + q` (prismatic). The chain is
//! the arm's three links (yaw, pitch, insertion), the instrument's roll link and wrist links
//! ([`Wrist`]), then the instrument's constant `tooltip_offset`. As in cisst, `alpha` = ±1.5708
//! is snapped to exactly ±pi/2 while the joint offsets stay 1.5708, so results match the dVRK
//! to the last digit (the offsets leave residues below 1e-5 in the rotation).
//!
//! The result is the CRTK `local/measured_cp`: the tip pose relative to the remote centre of
//! motion (RCM). [`PsmKinematics::forward_base`] adds an optional base frame (`measured_cp`).
//! The compensated tip pose is `forward(q_hat)`.

use std::f64::consts::FRAC_PI_2;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::instruments::{Instrument, Wrist};

/// The joint offsets exactly as written in the dVRK's DH files (not pi/2).
#[expect(
    clippy::approx_constant,
    reason = "the dVRK uses 1.5708 literally (reference 1.1)"
)]
const OFFSET_RAD: f64 = 1.5708;

/// Which PSM: selects the insertion joint's offset (`share/kinematic/PSM.json`, `PSM_Si.json`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ArmKind {
    /// Classic PSM: insertion offset -0.4318 m.
    #[default]
    Classic,
    /// Si PSM: insertion offset -0.4826 m (-0.4318 plus the longer S/Si shaft).
    Si,
}

impl ArmKind {
    /// The `offset` of the insertion joint (m).
    pub fn insertion_offset_m(self) -> f64 {
        match self {
            ArmKind::Classic => -0.4318,
            ArmKind::Si => -0.4826,
        }
    }
}

/// A 3x3 rotation stored as three columns (`m[c][r]`), so right-multiplying by an elementary
/// rotation mixes two columns and a translation along a frame axis adds one column.
type Cols = [[f64; 3]; 3];

/// `m = m · Rx(alpha)` given `(sin alpha, cos alpha)`.
#[inline(always)]
fn rot_x(m: &mut Cols, (s, c): (f64, f64)) {
    let (y, z) = (m[1], m[2]);
    for r in 0..3 {
        m[1][r] = c * y[r] + s * z[r];
        m[2][r] = c * z[r] - s * y[r];
    }
}

/// `m = m · Rz(theta)` given `(sin theta, cos theta)`.
#[inline(always)]
fn rot_z(m: &mut Cols, (s, c): (f64, f64)) {
    let (x, y) = (m[0], m[1]);
    for r in 0..3 {
        m[0][r] = c * x[r] + s * y[r];
        m[1][r] = c * y[r] - s * x[r];
    }
}

/// `p += k · v`.
#[inline(always)]
fn add_scaled(p: &mut [f64; 3], k: f64, v: &[f64; 3]) {
    for r in 0..3 {
        p[r] += k * v[r];
    }
}

/// Forward kinematics of one PSM with one instrument. Cheap to copy; all constants are
/// computed in [`PsmKinematics::new`] and [`PsmKinematics::forward`] allocates nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PsmKinematics {
    insertion_offset_m: f64,
    roll_theta_rad: f64,
    roll_d_m: f64,
    wrist: Wrist,
    /// `(sin, cos)` of alpha = +pi/2 (cos is 6.1e-17, as in cisst).
    alpha_90: (f64, f64),
    /// Tooltip rotation (columns) and translation.
    tool_rotation: Cols,
    tool_translation: [f64; 3],
    t_base_rcm: Isometry3<f64>,
}

impl PsmKinematics {
    /// The chain of `arm` carrying `tool`, with the base frame at the RCM.
    pub fn new(arm: ArmKind, tool: &Instrument) -> Self {
        let t = &tool.tooltip_offset;
        Self {
            insertion_offset_m: arm.insertion_offset_m(),
            roll_theta_rad: tool.roll_theta_rad,
            roll_d_m: tool.roll_d_m,
            wrist: tool.wrist,
            alpha_90: FRAC_PI_2.sin_cos(),
            tool_rotation: [
                [t[0][0], t[1][0], t[2][0]],
                [t[0][1], t[1][1], t[2][1]],
                [t[0][2], t[1][2], t[2][2]],
            ],
            tool_translation: [t[0][3], t[1][3], t[2][3]],
            t_base_rcm: Isometry3::identity(),
        }
    }

    /// Sets the base frame: the RCM frame's pose in the base (e.g. camera) frame.
    pub fn with_base_frame(self, t_base_rcm: Isometry3<f64>) -> Self {
        Self { t_base_rcm, ..self }
    }

    /// The base frame set by [`PsmKinematics::with_base_frame`] (identity by default).
    pub fn base_frame(&self) -> Isometry3<f64> {
        self.t_base_rcm
    }

    /// The tip pose relative to the RCM (`local/measured_cp`) for joints
    /// `[yaw, pitch, insertion, roll, wrist_pitch, wrist_yaw]` (rad, rad, m, rad, rad, rad).
    pub fn forward(&self, q: &[f64; 6]) -> Isometry3<f64> {
        let (s90, c90) = self.alpha_90;
        let plus_90 = (s90, c90);
        let minus_90 = (-s90, c90);
        let mut m: Cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut p = [0.0; 3];

        // 1 yaw: alpha +pi/2, theta = q1 + 1.5708.
        rot_x(&mut m, plus_90);
        rot_z(&mut m, (q[0] + OFFSET_RAD).sin_cos());
        // 2 pitch: alpha -pi/2, theta = q2 - 1.5708.
        rot_x(&mut m, minus_90);
        rot_z(&mut m, (q[1] - OFFSET_RAD).sin_cos());
        // 3 insertion (prismatic): alpha +pi/2, d = q3 + insertion offset.
        rot_x(&mut m, plus_90);
        add_scaled(&mut p, q[2] + self.insertion_offset_m, &m[2]);
        // 4 roll: alpha 0, theta = q4 + theta_DH (0 except for the stapler), D = shaft length.
        rot_z(&mut m, (q[3] + self.roll_theta_rad).sin_cos());
        add_scaled(&mut p, self.roll_d_m, &m[2]);

        match self.wrist {
            Wrist::Standard { yaw_a_m } => {
                // 5 wrist pitch: alpha -pi/2, theta = q5 - 1.5708.
                rot_x(&mut m, minus_90);
                rot_z(&mut m, (q[4] - OFFSET_RAD).sin_cos());
                // 6 wrist yaw: alpha -pi/2, A = yaw_a_m, theta = q6 - 1.5708.
                add_scaled(&mut p, yaw_a_m, &m[0]);
                rot_x(&mut m, minus_90);
                rot_z(&mut m, (q[5] - OFFSET_RAD).sin_cos());
            }
            Wrist::Snake { link_a_m } => {
                let half_pitch = 0.5 * q[4];
                let half_yaw = 0.5 * q[5];
                // pitch1: alpha -pi/2, theta = q5/2 - 1.5708.
                rot_x(&mut m, minus_90);
                rot_z(&mut m, (half_pitch - OFFSET_RAD).sin_cos());
                // yaw1: alpha -pi/2, A, theta = q6/2.
                let yaw = half_yaw.sin_cos();
                add_scaled(&mut p, link_a_m, &m[0]);
                rot_x(&mut m, minus_90);
                rot_z(&mut m, yaw);
                // yaw2: alpha 0, A, theta = q6/2.
                add_scaled(&mut p, link_a_m, &m[0]);
                rot_z(&mut m, yaw);
                // pitch2: alpha +pi/2, A, theta = q5/2 + 1.5708.
                add_scaled(&mut p, link_a_m, &m[0]);
                rot_x(&mut m, plus_90);
                rot_z(&mut m, (half_pitch + OFFSET_RAD).sin_cos());
            }
        }

        // Tooltip: p += R t, R = R R_tool.
        for (c, &k) in self.tool_translation.iter().enumerate() {
            add_scaled(&mut p, k, &m[c]);
        }
        let r = &self.tool_rotation;
        let mut out: Cols = [[0.0; 3]; 3];
        for (oc, rc) in out.iter_mut().zip(r) {
            for (k, &w) in rc.iter().enumerate() {
                add_scaled(oc, w, &m[k]);
            }
        }

        let rotation = Rotation3::from_matrix_unchecked(Matrix3::new(
            out[0][0], out[1][0], out[2][0], //
            out[0][1], out[1][1], out[2][1], //
            out[0][2], out[1][2], out[2][2],
        ));
        Isometry3::from_parts(
            Translation3::new(p[0], p[1], p[2]),
            UnitQuaternion::from_rotation_matrix(&rotation),
        )
    }

    /// The tip pose in the base frame (`measured_cp`): `base_frame · forward(q)`.
    pub fn forward_base(&self, q: &[f64; 6]) -> Isometry3<f64> {
        self.t_base_rcm * self.forward(q)
    }
}
