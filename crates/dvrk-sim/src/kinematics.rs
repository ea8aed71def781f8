//! Tip geometry of the Classic PSM used by the physics (contacts) and the ground truth.
//!
//! With the wrist at zero, the control point lies on the shaft axis at `q3 - 0.0065` m beyond the
//! RCM: `p = (q3 - 0.0065)·(sin q1 cos q2, -sin q2, -cos q1 cos q2)` (reference
//! psm-kinematics-crtk.md §1.3, checked there against the full modified-DH chain to 1 µm).
//! Contacts act on the shaft, so the physics uses this closed form; the reported true tip position
//! uses the full chain of `dvrk_compliance::PsmKinematics` (Classic PSM, Large Needle Driver
//! 400006) so it equals what the sidecar computes from perfectly corrected joints.

use std::sync::OnceLock;

use dvrk_compliance::{ArmKind, PsmKinematics};

/// Distance from the RCM back to the control point at `q3 = 0`: 0.4318 - 0.4162 - 0.0091 m.
pub const TIP_OFFSET_M: f64 = 0.0065;

/// Unit vector along the shaft (toward the tip) at yaw `q1`, pitch `q2`.
#[inline]
pub fn shaft_direction(q1: f64, q2: f64) -> [f64; 3] {
    let (s1, c1) = q1.sin_cos();
    let (s2, c2) = q2.sin_cos();
    [s1 * c2, -s2, -c1 * c2]
}

/// Point of the shaft axis at insertion `q3` (the control point with the wrist at zero), RCM frame.
#[inline]
pub fn tip_position(q1: f64, q2: f64, q3: f64) -> [f64; 3] {
    let r = q3 - TIP_OFFSET_M;
    let u = shaft_direction(q1, q2);
    [r * u[0], r * u[1], r * u[2]]
}

/// Partial derivatives of [`tip_position`] with respect to `q1` and `q2` (orthogonal vectors).
#[inline]
pub fn tip_lateral_jacobian(q1: f64, q2: f64, q3: f64) -> ([f64; 3], [f64; 3]) {
    let r = q3 - TIP_OFFSET_M;
    let (s1, c1) = q1.sin_cos();
    let (s2, c2) = q2.sin_cos();
    (
        [r * c1 * c2, 0.0, r * s1 * c2],
        [-r * s1 * s2, -r * c2, r * c1 * s2],
    )
}

/// The Classic PSM with a Large Needle Driver 400006, built once.
fn classic_lnd() -> Option<&'static PsmKinematics> {
    static KIN: OnceLock<Option<PsmKinematics>> = OnceLock::new();
    KIN.get_or_init(|| {
        dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006")
            .map(|tool| PsmKinematics::new(ArmKind::Classic, tool))
    })
    .as_ref()
}

/// Tool-tip position (`local/measured_cp` translation) at joint positions `q` (first six joints),
/// from dvrk-compliance's full PSM chain; the closed form if the instrument were missing from the
/// catalog.
pub fn tool_tip_position(q: &[f64; 7]) -> [f64; 3] {
    match classic_lnd() {
        Some(kin) => {
            let t = kin
                .forward(&[q[0], q[1], q[2], q[3], q[4], q[5]])
                .translation
                .vector;
            [t.x, t.y, t.z]
        }
        None => tip_position(q[0], q[1], q[2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|i| (a[i] - b[i]).abs() < tol)
    }

    #[test]
    fn closed_form_matches_reference_vectors() {
        // Reference §1.4 (mm): wrist at zero.
        assert!(close(
            tip_position(0.0, 0.0, 0.12),
            [0.0, 0.0, -0.1135],
            1e-9
        ));
        assert!(close(
            tip_position(0.5, 0.0, 0.12),
            [0.054415, 0.0, -0.099605],
            1e-6
        ));
        assert!(close(
            tip_position(0.3, -0.2, 0.15),
            [0.041562, 0.028510, -0.134358],
            1e-6
        ));
    }

    #[test]
    fn full_chain_matches_reference_vectors_and_the_closed_form() {
        let q = [0.2, -0.3, 0.15, 0.4, 0.3, -0.2, 0.0];
        let p = tool_tip_position(&q);
        assert!(close(p, [0.026278, 0.039921, -0.134903], 2e-6), "{p:?}");
        let q = [0.3, -0.2, 0.15, 0.0, 0.0, 0.0, 0.0];
        assert!(close(
            tool_tip_position(&q),
            tip_position(0.3, -0.2, 0.15),
            2e-6
        ));
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let (q1, q2, q3) = (0.3, -0.2, 0.15);
        let (d1, d2) = tip_lateral_jacobian(q1, q2, q3);
        let h = 1e-7;
        let p = tip_position(q1, q2, q3);
        let p1 = tip_position(q1 + h, q2, q3);
        let p2 = tip_position(q1, q2 + h, q3);
        for i in 0..3 {
            assert!(((p1[i] - p[i]) / h - d1[i]).abs() < 1e-6);
            assert!(((p2[i] - p[i]) / h - d2[i]).abs() < 1e-6);
        }
        let dot = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2];
        assert!(dot.abs() < 1e-15);
    }
}
