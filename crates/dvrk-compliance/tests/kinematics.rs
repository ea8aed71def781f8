//! Forward kinematics against reference section 1.4, frame properties, the Si arm and the
//! instrument families.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic

use std::f64::consts::FRAC_PI_2;

use approx::assert_relative_eq;
use dvrk_compliance::{ArmKind, Instrument, PsmKinematics, instrument, instruments};
use dvrk_compliance::{Generation, Wrist};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn tool(name: &str) -> &'static Instrument {
    instrument(name).unwrap_or_else(|| panic!("{name} not in catalog"))
}

fn lnd_classic() -> PsmKinematics {
    PsmKinematics::new(ArmKind::Classic, tool("LARGE_NEEDLE_DRIVER_400006"))
}

fn rotation(t: &Isometry3<f64>) -> Matrix3<f64> {
    *t.rotation.to_rotation_matrix().matrix()
}

/// One test vector: q, tip position (mm), rotation rows rounded to 5 digits.
type Vector = ([f64; 6], [f64; 3], [[f64; 3]; 3]);

/// Reference section 1.4: Classic PSM + LARGE_NEEDLE_DRIVER_400006, tooltip included.
#[rustfmt::skip]
const VECTORS: [Vector; 9] = [
    ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 6.5],
     [[0.0, 1.0, 0.0], [1.0, 0.0, 1e-5], [1e-5, 0.0, -1.0]]),
    ([0.0, 0.0, 0.12, 0.0, 0.0, 0.0], [0.0, 0.0, -113.5],
     [[0.0, 1.0, 0.0], [1.0, 0.0, 1e-5], [1e-5, 0.0, -1.0]]),
    ([0.5, 0.0, 0.12, 0.0, 0.0, 0.0], [54.415, 0.0, -99.605],
     [[0.0, 0.87758, 0.47943], [1.0, 0.0, 1e-5], [1e-5, 0.47943, -0.87758]]),
    ([0.0, 0.5, 0.12, 0.0, 0.0, 0.0], [0.0, -54.414, -99.606],
     [[0.0, 1.0, 0.0], [0.87759, 0.0, -0.47942], [-0.47942, 0.0, -0.87759]]),
    ([0.3, -0.2, 0.15, 0.0, 0.0, 0.0], [41.562, 28.510, -134.358],
     [[-0.05871, 0.95534, 0.28963], [0.98007, 0.0, 0.19868], [0.1898, 0.29552, -0.93629]]),
    ([0.0, 0.0, 0.12, FRAC_PI_2, 0.0, 0.0], [0.0, 0.0, -113.5],
     [[1.0, 0.0, 1e-5], [0.0, -1.0, 1e-5], [1e-5, -1e-5, -1.0]]),
    ([0.0, 0.0, 0.12, 0.0, 0.5, 0.0], [0.0, -4.362, -112.386],
     [[0.0, 1.0, 0.0], [0.87759, 0.0, -0.47942], [-0.47942, 0.0, -0.87759]]),
    ([0.0, 0.0, 0.12, 0.0, 0.0, 0.5], [0.0, 0.0, -113.5],
     [[0.0, 0.87758, 0.47943], [1.0, 0.0, 1e-5], [1e-5, 0.47943, -0.87758]]),
    ([0.2, -0.3, 0.15, 0.4, 0.3, -0.2], [26.278, 39.921, -134.903],
     [[0.36904, 0.92391, -0.10105], [0.92795, -0.36018, 0.09576], [0.05208, -0.12911, -0.99026]]),
];

#[test]
fn reference_vectors() {
    let fk = lnd_classic();
    for (q, p_mm, rows) in VECTORS {
        let t = fk.forward(&q);
        let p = t.translation.vector * 1000.0;
        for r in 0..3 {
            // 1 µm = 0.001 mm (the reference prints 3 decimals of mm).
            assert!(
                (p[r] - p_mm[r]).abs() <= 1.0e-3,
                "q {q:?}: p {p:?} vs {p_mm:?}"
            );
        }
        let rot = rotation(&t);
        for r in 0..3 {
            for c in 0..3 {
                let (got, want) = (rot[(r, c)], rows[r][c]);
                assert!(
                    (got - want).abs() <= 1e-5,
                    "q {q:?}: R[{r}][{c}] = {got} vs {want}"
                );
            }
        }
    }
}

/// Joint limits of the Classic PSM and the 8 mm instruments (reference 1.2).
fn classic_q() -> impl Strategy<Value = [f64; 6]> {
    (
        -1.588..=1.588f64,
        -0.925025..=0.925025f64,
        0.0..=0.24f64,
        -4.53786..=4.53786f64,
        -1.39626..=1.39626f64,
        -1.39626..=1.39626f64,
    )
        .prop_map(|(a, b, c, d, e, f)| [a, b, c, d, e, f])
}

fn assert_proper_rotation(r: &Matrix3<f64>) {
    let should_be_identity = r.transpose() * r;
    assert_relative_eq!(should_be_identity, Matrix3::identity(), epsilon = 1e-12);
    assert_relative_eq!(r.determinant(), 1.0, epsilon = 1e-12);
}

proptest! {
    #[test]
    fn rotations_are_orthonormal_with_determinant_one(
        q in classic_q(),
        tool_index in 0..instruments().len(),
        si in any::<bool>(),
    ) {
        let arm = if si { ArmKind::Si } else { ArmKind::Classic };
        let fk = PsmKinematics::new(arm, &instruments()[tool_index]);
        let t = fk.forward(&q);
        assert_proper_rotation(&rotation(&t));
        prop_assert!(t.translation.vector.iter().all(|x| x.is_finite()));
    }

    /// Reference 1.3: with the wrist at zero the point lies on the shaft axis at distance
    /// q3 - 0.0065 m from the RCM: p = (q3 - 0.0065) (sin q1 cos q2, -sin q2, -cos q1 cos q2),
    /// whatever the roll. (0.0065 = 0.4318 - 0.4162 - 0.0091.)
    #[test]
    fn wrist_at_zero_matches_the_closed_form(q in classic_q()) {
        let [q1, q2, q3, q4, _, _] = q;
        let t = lnd_classic().forward(&[q1, q2, q3, q4, 0.0, 0.0]);
        let r = q3 - 0.0065;
        let expected = Vector3::new(q1.sin() * q2.cos(), -q2.sin(), -q1.cos() * q2.cos()) * r;
        // The 1.5708 offsets tilt the axis by < 4e-6 rad: under 1 µm at 0.24 m.
        assert_relative_eq!(t.translation.vector, expected, epsilon = 1e-6);
    }

    /// Si PSM + S/Si instrument: -0.4826 + 0.4670 + 0.0091 = -0.0065, the same geometry as a
    /// Classic PSM + Classic instrument (reference 1.3), so the two chains agree everywhere.
    #[test]
    fn si_arm_with_s_tool_equals_classic_arm_with_classic_tool(q in classic_q()) {
        let si = PsmKinematics::new(ArmKind::Si, tool("LARGE_NEEDLE_DRIVER_420006"));
        let (a, b) = (si.forward(&q), lnd_classic().forward(&q));
        assert_relative_eq!(a.translation.vector, b.translation.vector, epsilon = 1e-12);
        assert_relative_eq!(rotation(&a), rotation(&b), epsilon = 1e-12);
    }

    #[test]
    fn base_frame_is_applied_on_the_left(
        q in classic_q(),
        xyz in prop::array::uniform3(-1.0..1.0f64),
        rpy in prop::array::uniform3(-3.0..3.0f64),
    ) {
        let t_base_rcm = Isometry3::from_parts(
            Translation3::new(xyz[0], xyz[1], xyz[2]),
            UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
        );
        let fk = lnd_classic().with_base_frame(t_base_rcm);
        assert_eq!(fk.base_frame(), t_base_rcm);
        let want = t_base_rcm * fk.forward(&q);
        let got = fk.forward_base(&q);
        assert_relative_eq!(got.translation.vector, want.translation.vector, epsilon = 1e-12);
        assert_relative_eq!(rotation(&got), rotation(&want), epsilon = 1e-12);
        // forward() itself stays relative to the RCM.
        assert_eq!(fk.forward(&q), lnd_classic().forward(&q));
    }
}

#[test]
fn si_insertion_offset() {
    assert_eq!(ArmKind::Classic.insertion_offset_m(), -0.4318);
    assert_eq!(ArmKind::Si.insertion_offset_m(), -0.4826);
    let q = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0];
    // Si + Si tool at q = 0: 6.5 mm on the robot side of the RCM, like the Classic pair.
    let si = PsmKinematics::new(ArmKind::Si, tool("LARGE_NEEDLE_DRIVER_420006"));
    let z0 = si.forward(&[0.0; 6]).translation.z;
    assert_relative_eq!(z0, 0.0065, epsilon = 1e-9);
    // The same Classic tool on the Si arm sits 0.4826 - 0.4318 = 50.8 mm shallower.
    let classic_tool_on_si = PsmKinematics::new(ArmKind::Si, tool("LARGE_NEEDLE_DRIVER_400006"));
    let dz = classic_tool_on_si.forward(&q).translation.z - lnd_classic().forward(&q).translation.z;
    assert_relative_eq!(dz, 0.0508, epsilon = 1e-9);
}

/// Every instrument with a two-link wrist, on both arms: with q1 = q2 = q4 = q6 = 0 the wrist pitch swings the
/// wrist link A in the y-z plane: p = (0, -A sin q5, -(q3 + offset + D + A cos q5)).
/// For LND 400006 at q3 = 0.12, q5 = 0.5 that is (0, -4.363, -112.386) mm, reference vector 7.
#[test]
fn standard_wrist_geometry_per_family() {
    for arm in [ArmKind::Classic, ArmKind::Si] {
        for i in instruments() {
            let Wrist::Standard { yaw_a_m: a } = i.wrist else {
                continue;
            };
            // The stapler 410298 has its own shaft: D = 0.41557, no wrist offset (A = 0).
            let expected_d = match i.generation {
                _ if i.model == 410298 => 0.41557,
                Generation::Classic => 0.4162,
                Generation::S => 0.4670,
            };
            assert_eq!(i.roll_d_m, expected_d, "{}", i.name);
            // Wrist A of the tool files: 0.0093 cautery hook/spatula, 0.01 Mega SutureCut.
            let known_a = [0.0, 0.0091, 0.0093, 0.01, 0.0107, 0.0112];
            assert!(known_a.contains(&a), "{}", i.name);
            let fk = PsmKinematics::new(arm, i);
            for (q3, q5) in [(0.12, 0.5), (0.2, -1.2), (0.05, 0.0)] {
                let p = fk.forward(&[0.0, 0.0, q3, 0.0, q5, 0.0]).translation.vector;
                let along = q3 + arm.insertion_offset_m() + i.roll_d_m + a * q5.cos();
                let want = Vector3::new(0.0, -a * q5.sin(), -along);
                assert_relative_eq!(p, want, epsilon = 1e-6);
            }
        }
    }
}

/// The 5 mm snake wrists: with the wrist at zero the tip lies on the shaft at
/// q3 + offset + D + 3 A + |tooltip y| (e.g. 0.12 - 0.4318 + 0.4024 + 0.0102 + 0.0171 =
/// 0.1179 m for NEEDLE_DRIVER_400117) with the tool z axis along the shaft; the two pitch links
/// (two yaw links) together bend the tool axis by q5 (q6).
#[test]
fn snake_wrist_geometry() {
    let mut seen = 0;
    for i in instruments() {
        let Wrist::Snake { link_a_m: a } = i.wrist else {
            continue;
        };
        seen += 1;
        assert_eq!(i.shaft_diameter_mm, 5);
        let fk = PsmKinematics::new(ArmKind::Classic, i);
        let t = fk.forward(&[0.0, 0.0, 0.12, 0.7, 0.0, 0.0]);
        let tip_y = i.tooltip_offset[1][3];
        let along = 0.12 - 0.4318 + i.roll_d_m + 3.0 * a - tip_y;
        assert_relative_eq!(
            t.translation.vector,
            Vector3::new(0.0, 0.0, -along),
            epsilon = 1e-6
        );
        let z_axis = rotation(&t).column(2).into_owned();
        assert_relative_eq!(z_axis, Vector3::new(0.0, 0.0, -1.0), epsilon = 1e-5);
        for (q5, q6) in [(0.4, 0.0), (0.0, 0.4), (-0.3, 0.0), (0.0, -0.7)] {
            let t = fk.forward(&[0.0, 0.0, 0.12, 0.0, q5, q6]);
            let z_axis = rotation(&t).column(2).into_owned();
            let bend = z_axis.angle(&Vector3::new(0.0, 0.0, -1.0));
            assert_relative_eq!(bend, f64::abs(q5 + q6), epsilon = 1e-5);
        }
    }
    assert_eq!(seen, 3);
}

#[test]
fn catalog_covers_the_reference_families() {
    for name in [
        "LARGE_NEEDLE_DRIVER_400006",
        "CADIERE_FORCEPS_400049",
        "PROGRASP_FORCEPS_400093",
        "MEGA_NEEDLE_DRIVER_400194",
        "LARGE_NEEDLE_DRIVER_420006",
        "NEEDLE_DRIVER_400117",
        "NEEDLE_DRIVER_420117",
        "MARYLAND_DISSECTOR_400143",
    ] {
        assert!(instrument(name).is_some(), "{name}");
    }
    let lnd = tool("LARGE_NEEDLE_DRIVER_400006");
    assert_eq!(lnd.wrist, Wrist::Standard { yaw_a_m: 0.0091 });
    assert_eq!(
        lnd.actuator_to_joint_position.map(|m| m[2]),
        Some([0.0, -0.8306, 0.6089, 0.6089])
    );
    assert_eq!(
        tool("PROGRASP_FORCEPS_400093").wrist,
        Wrist::Standard { yaw_a_m: 0.0107 }
    );
    assert_eq!(
        tool("MEGA_NEEDLE_DRIVER_420194").wrist,
        Wrist::Standard { yaw_a_m: 0.0112 }
    );
    assert_eq!(tool("NEEDLE_DRIVER_420117").roll_d_m, 0.4532);
}
