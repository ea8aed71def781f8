//! Forward kinematics of the catalog's instruments against the dVRK's own files.
//!
//! 1. Golden vectors: tip poses computed outside this project, by a short script that read the
//!    dVRK's JSON files directly (sawIntuitiveResearchKit 9e535e68: `share/kinematic/PSM.json`,
//!    `PSM_Si.json`, `share/tool/<FILE>.json`) and multiplied the modified-DH 4x4 matrices as
//!    cisst `robModifiedDH::ForwardKinematics` defines them (alpha +-1.5708 snapped to +-pi/2,
//!    theta = theta_DH + offset + q), then `tooltip_offset` as written; snake-like tools get the
//!    PSM component's expansion of q5, q6 into pitch1 = pitch2 = q5/2, yaw1 = yaw2 = q6/2. The
//!    dVRK repository has no q -> pose test vectors of its own (reference psm-kinematics 1.4).
//! 2. For every instrument, the production chain against a plain product of 4x4 DH matrices
//!    written here, independently of `kinematics.rs`.
//! 3. The tooltip offsets, shaft lengths and couplings of several tool files, as written there.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic
#![expect(
    clippy::approx_constant,
    reason = "the dVRK files write 1.5708, 0.7854 and 0.7071 literally"
)]

use std::f64::consts::FRAC_PI_2;

use dvrk_compliance::ArmKind::{self, Classic, Si};
use dvrk_compliance::{Generation, Instrument, PsmKinematics, Wrist, instrument, instruments};
use nalgebra::{Matrix3, Matrix4};
use proptest::prelude::*;

fn tool(name: &str) -> &'static Instrument {
    instrument(name).unwrap_or_else(|| panic!("{name} not in catalog"))
}

/// (tool file, arm, q, tip position (m), tip rotation rows).
type Golden = (&'static str, ArmKind, [f64; 6], [f64; 3], [[f64; 3]; 3]);

#[rustfmt::skip]
const GOLDEN: [Golden; 27] = [
    ("LARGE_NEEDLE_DRIVER_400006", Classic, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.026278134803, 0.039921255654, -0.134902761695],
     [[0.369036206719, 0.923905213094, -0.101051646938], [0.927954910448, -0.360180065569, 0.095760140675], [0.052076504356, -0.129110331054, -0.990261864412]]),
    ("LARGE_NEEDLE_DRIVER_400006", Classic, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.045136078791, -0.034076417203, -0.072632503243],
     [[-0.481574632370, 0.667053022542, -0.568441851534], [0.495339869122, 0.742237986572, 0.451354833084], [0.722996741013, -0.064210874532, -0.687860942398]]),
    ("LARGE_NEEDLE_DRIVER_400006", Classic, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.147335520729, -0.014430304813, -0.121396293782],
     [[0.738727921283, -0.656325101052, 0.153357164961], [-0.674001174133, -0.718719496390, 0.170776762990], [-0.001864291858, -0.229520472373, -0.973302048276]]),
    ("PROGRASP_FORCEPS_400093", Classic, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.026413363104, 0.039956924797, -0.136496637794],
     [[0.369036206719, 0.923905213094, -0.101051646938], [0.927954910448, -0.360180065569, 0.095760140675], [0.052076504356, -0.129110331054, -0.990261864412]]),
    ("PROGRASP_FORCEPS_400093", Classic, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.046519271008, -0.034289128352, -0.073408088995],
     [[-0.481574632370, 0.667053022542, -0.568441851534], [0.495339869122, 0.742237986572, 0.451354833084], [0.722996741013, -0.064210874532, -0.687860942398]]),
    ("PROGRASP_FORCEPS_400093", Classic, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.147970455664, -0.013730822920, -0.122687642964],
     [[0.738727921283, -0.656325101052, 0.153357164961], [-0.674001174133, -0.718719496390, 0.170776762990], [-0.001864291858, -0.229520472373, -0.973302048276]]),
    ("PERMANENT_CAUTERY_HOOK_400183", Classic, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.026295038341, 0.039925714297, -0.135101996207],
     [[0.369036206719, 0.923905213094, -0.101051646938], [0.927954910448, -0.360180065569, 0.095760140675], [0.052076504356, -0.129110331054, -0.990261864412]]),
    ("PERMANENT_CAUTERY_HOOK_400183", Classic, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.045308977818, -0.034103006097, -0.072729451462],
     [[-0.481574632370, 0.667053022542, -0.568441851534], [0.495339869122, 0.742237986572, 0.451354833084], [0.722996741013, -0.064210874532, -0.687860942398]]),
    ("PERMANENT_CAUTERY_HOOK_400183", Classic, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.147414887596, -0.014342869576, -0.121557712430],
     [[0.738727921283, -0.656325101052, 0.153357164961], [-0.674001174133, -0.718719496390, 0.170776762990], [-0.001864291858, -0.229520472373, -0.973302048276]]),
    ("LARGE_NEEDLE_DRIVER_420006", Si, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.026278134803, 0.039921255654, -0.134902761695],
     [[0.369036206719, 0.923905213094, -0.101051646938], [0.927954910448, -0.360180065569, 0.095760140675], [0.052076504356, -0.129110331054, -0.990261864412]]),
    ("LARGE_NEEDLE_DRIVER_420006", Si, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.045136078791, -0.034076417203, -0.072632503243],
     [[-0.481574632370, 0.667053022542, -0.568441851534], [0.495339869122, 0.742237986572, 0.451354833084], [0.722996741013, -0.064210874532, -0.687860942398]]),
    ("LARGE_NEEDLE_DRIVER_420006", Si, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.147335520729, -0.014430304813, -0.121396293782],
     [[0.738727921283, -0.656325101052, 0.153357164961], [-0.674001174133, -0.718719496390, 0.170776762990], [-0.001864291858, -0.229520472373, -0.973302048276]]),
    ("MEGA_SUTURECUT_NEEDLE_DRIVER_420309_GEARED", Si, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.026354200722, 0.039941319547, -0.135799317000],
     [[0.369036206719, 0.923905213094, -0.101051646938], [0.927954910448, -0.360180065569, 0.095760140675], [0.052076504356, -0.129110331054, -0.990261864412]]),
    ("MEGA_SUTURECUT_NEEDLE_DRIVER_420309_GEARED", Si, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.045914124413, -0.034196067225, -0.073068770228],
     [[-0.481574632370, 0.667053022542, -0.568441851534], [0.495339869122, 0.742237986572, 0.451354833084], [0.722996741013, -0.064210874532, -0.687860942398]]),
    ("MEGA_SUTURECUT_NEEDLE_DRIVER_420309_GEARED", Si, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.147692671630, -0.014036846248, -0.122122677697],
     [[0.738727921283, -0.656325101052, 0.153357164961], [-0.674001174133, -0.718719496390, 0.170776762990], [-0.001864291858, -0.229520472373, -0.973302048276]]),
    ("STAPLER_45_410298", Si, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.015747646636, 0.024519602700, -0.077684114263],
     [[-0.398409221725, 0.902619157202, -0.162937868823], [0.832609126431, 0.430428136127, 0.348559409879], [0.384749443961, 0.003205726592, -0.923015486700]]),
    ("STAPLER_45_410298", Si, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.014558822698, -0.012839011200, -0.026649978857],
     [[-0.982360047977, -0.183460800366, -0.036205950729], [-0.184172127375, 0.915660471438, 0.357276543513], [-0.032393882712, 0.357642329396, -0.933296630545]]),
    ("STAPLER_45_410298", Si, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.103638958417, -0.013274363425, -0.082242194000],
     [[0.830212773751, 0.374783009888, 0.412655359591], [0.085963522452, -0.817479970735, 0.569505724514], [0.550778560864, -0.437337618947, -0.710899981676]]),
    ("NEEDLE_DRIVER_400117", Classic, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.021643000936, 0.039220057704, -0.139813690177],
     [[0.419684715387, -0.902130224575, -0.100034041748], [-0.898866783152, -0.428390293624, 0.092202199153], [-0.126032003145, 0.051221423602, -0.990702753081]]),
    ("NEEDLE_DRIVER_400117", Classic, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.047618522996, -0.019313682845, -0.075810729670],
     [[0.782754890890, 0.004239051080, -0.622306242116], [0.367554245136, -0.810069319069, 0.456811118077], [-0.502174748141, -0.586302437952, -0.635655994564]]),
    ("NEEDLE_DRIVER_400117", Classic, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.140638704797, -0.012927358538, -0.130714046111],
     [[-0.986145735409, 0.068281085968, 0.151114326981], [0.098977781278, 0.973517393028, 0.206031353089], [-0.133044381119, 0.218133901013, -0.966806879229]]),
    ("MARYLAND_DISSECTOR_400143", Classic, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.020662667327, 0.040123639256, -0.149522577157],
     [[0.419684715387, -0.902130224575, -0.100034041748], [-0.898866783152, -0.428390293624, 0.092202199153], [-0.126032003145, 0.051221423602, -0.990702753081]]),
    ("MARYLAND_DISSECTOR_400143", Classic, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.053717124169, -0.014836933888, -0.082040158417],
     [[0.782754890890, 0.004239051080, -0.622306242116], [0.367554245136, -0.810069319069, 0.456811118077], [-0.502174748141, -0.586302437952, -0.635655994564]]),
    ("MARYLAND_DISSECTOR_400143", Classic, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.142119625202, -0.010908251278, -0.140188753527],
     [[-0.986145735409, 0.068281085968, 0.151114326981], [0.098977781278, 0.973517393028, 0.206031353089], [-0.133044381119, 0.218133901013, -0.966806879229]]),
    ("NEEDLE_DRIVER_420117", Si, [0.2, -0.3, 0.15, 0.4, 0.3, -0.2],
     [0.021643000936, 0.039220057704, -0.139813690177],
     [[0.419684715387, -0.902130224575, -0.100034041748], [-0.898866783152, -0.428390293624, 0.092202199153], [-0.126032003145, 0.051221423602, -0.990702753081]]),
    ("NEEDLE_DRIVER_420117", Si, [-0.5, 0.4, 0.1, -1.2, -0.6, 0.7],
     [-0.047618522996, -0.019313682845, -0.075810729670],
     [[0.782754890890, 0.004239051080, -0.622306242116], [0.367554245136, -0.810069319069, 0.456811118077], [-0.502174748141, -0.586302437952, -0.635655994564]]),
    ("NEEDLE_DRIVER_420117", Si, [0.9, 0.1, 0.2, 2.5, 0.7, 0.4],
     [0.140638704797, -0.012927358538, -0.130714046111],
     [[-0.986145735409, 0.068281085968, 0.151114326981], [0.098977781278, 0.973517393028, 0.206031353089], [-0.133044381119, 0.218133901013, -0.966806879229]]),
];

fn rotation(t: &nalgebra::Isometry3<f64>) -> Matrix3<f64> {
    *t.rotation.to_rotation_matrix().matrix()
}

/// The file's 0.7071 in the snake tools' `tooltip_offset` is stored as 1/sqrt(2) (a proper
/// rotation): their orientations differ from the file's product by up to 7e-6. Positions do
/// not depend on those entries.
fn rotation_tolerance(i: &Instrument) -> f64 {
    if i.is_snake_like() { 1e-5 } else { 1e-9 }
}

#[test]
fn fk_matches_the_dvrk_tool_files() {
    let mut tools = std::collections::BTreeSet::new();
    let mut worst = [0.0f64; 2];
    for (name, arm, q, p, r) in GOLDEN {
        let i = tool(name);
        tools.insert(name);
        let t = PsmKinematics::new(arm, i).forward(&q);
        let dp = (t.translation.vector - nalgebra::Vector3::from(p)).amax();
        let dr = (rotation(&t) - Matrix3::from_fn(|a, b| r[a][b])).amax();
        println!(
            "{name} on {arm:?}, q {q:?}: expected p {p:?} m, got [{:.12}, {:.12}, {:.12}] m; \
             |dp| {dp:.1e} m, |dR| {dr:.1e}",
            t.translation.x, t.translation.y, t.translation.z
        );
        assert!(dp < 1e-9, "{name} {q:?}: position off by {dp:e} m");
        assert!(
            dr < rotation_tolerance(i),
            "{name} {q:?}: rotation off by {dr:e}"
        );
        worst[usize::from(i.is_snake_like())] = worst[usize::from(i.is_snake_like())].max(dr);
        worst[0] = worst[0].max(dp);
    }
    println!(
        "max |dp| {:.1e} m; max |dR| snake-like {:.1e}",
        worst[0], worst[1]
    );
    // Nine instruments: Classic and S/Si, three wrist lengths, the stapler, three snake-like.
    assert_eq!(tools.len(), 9);
}

/// One modified-DH link as cisst defines it: Rx(alpha) Tx(a) Rz(theta) Tz(d).
fn dh(alpha: f64, a: f64, theta: f64, d: f64) -> Matrix4<f64> {
    let (sa, ca) = alpha.sin_cos();
    let (st, ct) = theta.sin_cos();
    Matrix4::new(
        ct,
        -st,
        0.0,
        a, //
        st * ca,
        ct * ca,
        -sa,
        -sa * d, //
        st * sa,
        ct * sa,
        ca,
        ca * d, //
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

/// The whole chain by matrix products: the arm's three links, then the tool file's rows
/// rebuilt from the catalog entry, then `tooltip_offset`.
fn chain(arm: ArmKind, i: &Instrument, q: &[f64; 6]) -> Matrix4<f64> {
    let offset = 1.5708;
    let insertion = match arm {
        Classic => -0.4318,
        Si => -0.4826,
    };
    let mut m = dh(FRAC_PI_2, 0.0, q[0] + offset, 0.0)
        * dh(-FRAC_PI_2, 0.0, q[1] - offset, 0.0)
        * dh(FRAC_PI_2, 0.0, 0.0, q[2] + insertion)
        * dh(0.0, 0.0, i.roll_theta_rad + q[3], i.roll_d_m);
    match i.wrist {
        Wrist::Standard { yaw_a_m } => {
            m *= dh(-FRAC_PI_2, 0.0, q[4] - offset, 0.0);
            m *= dh(-FRAC_PI_2, yaw_a_m, q[5] - offset, 0.0);
        }
        Wrist::Snake { link_a_m } => {
            let (pitch, yaw) = (q[4] / 2.0, q[5] / 2.0);
            m *= dh(-FRAC_PI_2, 0.0, pitch - offset, 0.0);
            m *= dh(-FRAC_PI_2, link_a_m, yaw, 0.0);
            m *= dh(0.0, link_a_m, yaw, 0.0);
            m *= dh(FRAC_PI_2, link_a_m, pitch + offset, 0.0);
        }
    }
    m * Matrix4::from_fn(|r, c| i.tooltip_offset[r][c])
}

proptest! {
    #[test]
    fn every_instrument_equals_the_dh_matrix_product(
        index in 0..instruments().len(),
        si in any::<bool>(),
        q in (-1.5..1.5f64, -0.9..0.9f64, 0.0..0.24f64, -4.5..4.5f64, -1.3..1.3f64, -1.3..1.3f64),
    ) {
        let i = &instruments()[index];
        let arm = if si { Si } else { Classic };
        let q = [q.0, q.1, q.2, q.3, q.4, q.5];
        let t = PsmKinematics::new(arm, i).forward(&q).to_homogeneous();
        let want = chain(arm, i, &q);
        let err = (t - want).amax();
        prop_assert!(err < 1e-12, "{} on {:?} at {:?}: {:e}", i.name, arm, q, err);
    }
}

/// Numbers as written in the tool files (sawIntuitiveResearchKit 9e535e68, `share/tool/`).
#[test]
fn tooltip_offsets_shafts_and_couplings_as_in_the_tool_files() {
    // tooltip_offset translations: the snake tools' y, zero elsewhere.
    assert_eq!(tool("NEEDLE_DRIVER_400117").tooltip_offset[1][3], -0.0171);
    assert_eq!(tool("NEEDLE_DRIVER_420117").tooltip_offset[1][3], -0.0171);
    assert_eq!(
        tool("MARYLAND_DISSECTOR_400143").tooltip_offset[1][3],
        -0.0269
    );
    for i in instruments().iter().filter(|i| !i.is_snake_like()) {
        let t = i.tooltip_offset;
        assert_eq!([t[0][3], t[1][3], t[2][3]], [0.0; 3], "{}", i.name);
    }
    // Rotations: the ISI convention of the EndoWrists, the stapler's own.
    assert_eq!(
        tool("LARGE_NEEDLE_DRIVER_420006_GEARED").tooltip_offset[2],
        [-1.0, 0.0, 0.0, 0.0]
    );
    assert_eq!(
        tool("STAPLER_45_410298").tooltip_offset[2],
        [0.0, -1.0, 0.0, 0.0]
    );
    let snake = tool("MARYLAND_DISSECTOR_400143").tooltip_offset;
    assert!((snake[0][0] - 0.7071).abs() < 1e-4 && (snake[2][0] + 0.7071).abs() < 1e-4);
    // Roll D and theta, wrist A.
    assert_eq!(tool("STAPLER_45_410298").roll_d_m, 0.41557);
    assert_eq!(tool("STAPLER_45_410298").roll_theta_rad, 0.7854);
    assert_eq!(tool("MARYLAND_DISSECTOR_400143").roll_d_m, 0.4024);
    assert_eq!(tool("CADIERE_FORCEPS_420049").roll_d_m, 0.467);
    assert_eq!(
        tool("PERMANENT_CAUTERY_SPATULA_420184").wrist,
        Wrist::Standard { yaw_a_m: 0.0093 }
    );
    assert_eq!(
        tool("MEGA_SUTURECUT_NEEDLE_DRIVER_400309").wrist,
        Wrist::Standard { yaw_a_m: 0.01 }
    );
    assert_eq!(
        tool("NEEDLE_DRIVER_420117").wrist,
        Wrist::Snake { link_a_m: 0.0034 }
    );
    // Couplings (ActuatorToJointPosition rows).
    let c = |name: &str| tool(name).actuator_to_joint_position.unwrap();
    assert_eq!(
        c("LARGE_NEEDLE_DRIVER_400006")[3],
        [0.0, 0.0, -1.2177, 1.2177]
    );
    assert_eq!(
        c("LARGE_NEEDLE_DRIVER_420006_GEARED")[0],
        [1.5333, 0.0, 0.0, 0.0]
    );
    assert_eq!(c("LARGE_NEEDLE_DRIVER_420006")[0], [-1.5632, 0.0, 0.0, 0.0]);
    assert_eq!(
        c("SMALL_CLIP_APPLIER_400003")[2],
        [0.0, -0.8349, -0.5956, -0.5956]
    );
    assert_eq!(c("NEEDLE_DRIVER_400117")[1], [0.0, 0.0, -0.1929, -0.1929]);
    assert_eq!(c("NEEDLE_DRIVER_400117")[3], [0.0, -1.258, 0.0, 0.0]);
    assert_eq!(
        c("PERMANENT_CAUTERY_HOOK_400183")[2],
        [0.0, 0.7827, -1.0582, 0.0]
    );
    assert_eq!(
        c("STAPLER_45_410298")[3],
        [0.0, 0.157832, -0.035139, -0.035139]
    );
    assert_eq!(
        c("LARGE_CLIP_APPLIER_420230")[3],
        [0.0, 0.0, 0.527898, -0.52789]
    );
    assert_eq!(
        c("MEGA_SUTURECUT_NEEDLE_DRIVER_420309")[2],
        [0.0, -0.579399, 0.467811, 0.467811]
    );
    assert_eq!(
        c("MARYLAND_BIPOLAR_FORCEPS_420172")[0],
        [-1.563233, 0.0, 0.0, 0.0]
    );
}

/// The console's index: 54 entries, of which 3 snake-like and 5 models split by version.
#[test]
fn the_whole_index_is_in_the_catalog() {
    let all = instruments();
    assert_eq!(all.len(), 54);
    assert_eq!(all.iter().filter(|i| i.is_snake_like()).count(), 3);
    let split = all
        .iter()
        .filter(|i| i.versions.min.is_some())
        .map(|i| i.model)
        .collect::<Vec<_>>();
    assert_eq!(split, [420006, 420093, 420183, 420194, 420309]);
    // 27 Classic (40xxxx), 27 S/Si (41xxxx stapler and 42xxxx, geared entries included).
    let classic = all.iter().filter(|i| i.generation == Generation::Classic);
    assert_eq!(classic.count(), 27);
}
