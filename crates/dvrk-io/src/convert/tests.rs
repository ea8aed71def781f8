use approx::assert_relative_eq;

use super::*;
use crate::wire::block::motor_status_bits as msb;
use crate::wire::{Adc, BlockLayout, BoardKind, EncoderPeriod, EncoderPosition, FeedbackBlock};

const PSM_CLASSIC: &str = include_str!("../../../../config/io/psm-classic.toml");
const SAW_JSON: &str = include_str!("../../../../tests/data/io/sawRobotIO1394-PSM1-00000.json");

/// What reading a config file can fail with in a test: the parser (the application's job) or
/// this crate's validation.
#[derive(Debug, thiserror::Error)]
enum Load {
    #[error("{0}")]
    Toml(#[from] toml::de::Error),
    #[error("{0}")]
    Json(#[from] serde_json::Error),
    #[error("{0}")]
    Config(#[from] IoConfigError),
}

impl Load {
    /// The validation error; a parse error here is a broken test fixture.
    fn config(&self) -> &IoConfigError {
        match self {
            Load::Config(e) => e,
            other => panic!("expected a validation error, got a parse error: {other}"),
        }
    }
}

fn from_toml_str(text: &str) -> Result<IoConfig, Load> {
    Ok(IoConfig::from_params(toml::from_str(text)?)?)
}

fn from_saw_json_robot(text: &str, name: Option<&str>) -> Result<IoConfig, Load> {
    let file: SawFile = serde_json::from_str(&strip_json_comments(text))?;
    Ok(IoConfig::from_saw_file(file, name)?)
}

fn from_saw_json_str(text: &str) -> Result<IoConfig, Load> {
    from_saw_json_robot(text, None)
}

fn cfg() -> IoConfig {
    from_toml_str(PSM_CLASSIC).unwrap()
}

#[test]
fn shipped_toml_matches_reference_5_2() {
    let c = cfg();
    assert_eq!(c.name(), "PSM1");
    assert_eq!(c.board_kind(), BoardKind::Qla);
    assert_eq!(c.board_ids(), &[6, 7]);
    assert_eq!(c.board_mask(), 0b1100_0000);
    let a = c.actuators();
    let where_: Vec<(u8, u8)> = a.iter().map(|a| (a.board_id, a.axis)).collect();
    assert_eq!(
        where_,
        vec![(6, 0), (6, 1), (6, 2), (6, 3), (7, 0), (7, 1), (7, 2)]
    );
    // Table of reference 5.2, to its printed precision.
    assert_relative_eq!(a[0].bits_to_position.scale, -7.7227e-6, max_relative = 1e-4);
    assert_relative_eq!(a[2].bits_to_position.scale, 1.2963e-6, max_relative = 1e-4);
    assert_relative_eq!(
        a[3].bits_to_position.scale,
        -1.34141e-4,
        max_relative = 1e-5
    );
    assert_relative_eq!(a[6].bits_to_position.scale, 1.34141e-4, max_relative = 1e-5);
    assert_relative_eq!(a[0].bits_to_current.scale, -1.90735e-4, max_relative = 1e-5);
    assert_eq!(a[0].bits_to_current.offset, 6.25);
    assert_eq!(a[2].bits_to_current.offset, -6.25);
    assert_relative_eq!(a[0].effort_to_current.scale, 0.40409, max_relative = 1e-4);
    assert_relative_eq!(a[2].effort_to_current.scale, 0.067828, max_relative = 1e-4);
    assert_relative_eq!(a[4].effort_to_current.scale, 1.94970, max_relative = 1e-5);
    assert_eq!(a[2].joint_type, JointType::Prismatic);
    assert_eq!(c.instrument(), Some("LARGE_NEEDLE_DRIVER_400006"));
}

#[test]
fn actuator_conversions_hand_computed() {
    let c = cfg();
    let a = c.actuators();
    // Actuator 1: 10000 counts * (-2*pi / 14400 / 56.5) rad.
    assert_relative_eq!(
        a[0].counts_to_position(10_000),
        -10_000.0 * 2.0 * std::f64::consts::PI / 14400.0 / 56.5,
        epsilon = 1e-12
    );
    // Current bits 0x8000 are 0 A for either direction.
    assert_relative_eq!(a[0].current_bits_to_amps(0x8000), 0.0, epsilon = 1e-12);
    assert_relative_eq!(a[2].current_bits_to_amps(0x8000), 0.0, epsilon = 1e-12);
    // Actuator 1, 40000 bits: I = -40000/5242.88 + 6.25 = -1.37939453125 A;
    // effort = I * gear * Kt = I * 56.5 * 0.0438 N*m.
    assert_relative_eq!(
        a[0].current_bits_to_amps(40_000),
        -1.379_394_531_25,
        epsilon = 1e-12
    );
    assert_relative_eq!(
        a[0].current_bits_to_effort(40_000),
        -1.379_394_531_25 * 56.5 * 0.0438,
        epsilon = 1e-9
    );
    // Insertion: 100000 counts = 100000 * 2*pi/14400/336.6 m; 36000 bits = 0.616455078125 A = N / (336.6*0.0438).
    assert_relative_eq!(
        a[2].counts_to_position(100_000),
        100_000.0 * 2.0 * std::f64::consts::PI / 14400.0 / 336.6,
        epsilon = 1e-12
    );
    assert_relative_eq!(
        a[2].current_bits_to_effort(36_000),
        0.616_455_078_125 * 336.6 * 0.0438,
        epsilon = 1e-9
    );
    // Inverses used by the emulator.
    for (i, act) in a.iter().enumerate() {
        let c = 12_345 * if i % 2 == 0 { 1 } else { -1 };
        assert_eq!(act.position_to_counts(act.counts_to_position(c)), c);
        assert_eq!(
            act.effort_to_current_bits(act.current_bits_to_effort(30_000)),
            30_000
        );
    }
    assert!(a[0].pot_bits_to_position(100).is_none());
}

#[test]
fn coupling_hand_computed_lnd_400006() {
    let c = cfg();
    let a = [0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.4];
    let q = c.actuator_to_joint_position(&a);
    assert_relative_eq!(q[3], -1.5632 * 0.1, epsilon = 1e-12);
    assert_relative_eq!(q[4], 1.0186 * 0.2, epsilon = 1e-12);
    assert_relative_eq!(q[5], -0.8306 * 0.2 + 0.6089 * (0.3 + 0.4), epsilon = 1e-12);
    assert_relative_eq!(q[6], 1.2177 * (0.4 - 0.3), epsilon = 1e-12);
    let back = c.joint_to_actuator_position(&q);
    for i in 0..7 {
        assert_relative_eq!(back[i], a[i], epsilon = 1e-12);
    }
    // Joints 1-3 pass through.
    let q = c.actuator_to_joint_position(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(&q[..3], &[1.0, 2.0, 3.0]);
    // Power equivalence: tau_j . qdot == tau_a . adot.
    let adot = [0.3, -0.2, 0.01, 0.5, -0.7, 0.2, 0.9];
    let tau_a = [0.1, 0.2, 3.0, -0.04, 0.05, 0.06, -0.07];
    let qdot = c.actuator_to_joint_position(&adot);
    let tau_j = c.actuator_to_joint_effort(&tau_a);
    let pj: f64 = tau_j.iter().zip(&qdot).map(|(t, v)| t * v).sum();
    let pa: f64 = tau_a.iter().zip(&adot).map(|(t, v)| t * v).sum();
    assert_relative_eq!(pj, pa, epsilon = 1e-12);
    let ta = c.joint_to_actuator_effort(&tau_j);
    for i in 0..7 {
        assert_relative_eq!(ta[i], tau_a[i], epsilon = 1e-12);
    }
    // Roll effort by hand: C^-T for a diagonal element is 1/C.
    assert_relative_eq!(tau_j[3], -0.04 / -1.5632, epsilon = 1e-12);
}

#[test]
fn saw_json_v6_import_matches_toml() {
    let j = from_saw_json_str(SAW_JSON).unwrap();
    let t = cfg();
    assert_eq!(j.name(), "PSM1");
    assert_eq!(j.board_ids(), t.board_ids());
    assert_eq!(
        j.coupling(),
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0]
        ]
    );
    for (a, b) in j.actuators().iter().zip(t.actuators()) {
        assert_eq!(
            (a.board_id, a.axis, a.joint_type),
            (b.board_id, b.axis, b.joint_type)
        );
        // The generator prints 9-15 decimals.
        assert_relative_eq!(
            a.bits_to_position.scale,
            b.bits_to_position.scale,
            max_relative = 1e-6
        );
        assert_relative_eq!(
            a.bits_to_current.scale,
            b.bits_to_current.scale,
            max_relative = 1e-5
        );
        assert_eq!(a.bits_to_current.offset, b.bits_to_current.offset);
        assert_relative_eq!(
            a.effort_to_current.scale,
            b.effort_to_current.scale,
            max_relative = 1e-8
        );
        assert_eq!(a.maximum_current_amps, b.maximum_current_amps);
    }
    // Pot: V = bits * 4.5/65536; actuator 1 position = V * (-0.0017*4096/4.5) + 3.5 (sample values).
    let p = j.actuators()[0].pot_bits_to_position(32768).unwrap();
    assert_relative_eq!(p, 2.25 * -1.547_377_78 + 3.5, epsilon = 1e-9);
    let bits = j.actuators()[0].position_to_pot_bits(p).unwrap();
    assert_eq!(bits, 32768);
    let mut j2 = j.clone();
    j2.set_coupling(t.coupling()).unwrap();
    assert_eq!(j2.coupling(), t.coupling());
}

#[test]
fn saw_json_rejects_wrong_version_and_names_robot() {
    let v5 = SAW_JSON.replacen("\"$version\": \"6\"", "\"$version\": \"5\"", 1);
    let e = from_saw_json_str(&v5).unwrap_err();
    assert!(
        matches!(*e.config(), IoConfigError::SawVersion { ref found } if found == "5"),
        "{e}"
    );
    let num = SAW_JSON.replacen("\"$version\": \"6\"", "\"$version\": 6", 1);
    assert!(from_saw_json_str(&num).is_ok());
    let e = from_saw_json_robot(SAW_JSON, Some("PSM2")).unwrap_err();
    assert!(
        e.to_string().contains("PSM2") && e.to_string().contains("PSM1"),
        "{e}"
    );
    let no_enc = SAW_JSON.replacen("\"bits_to_position\"", "\"bits_to_pos\"", 1);
    let e = from_saw_json_str(&no_enc).unwrap_err();
    assert!(
        e.to_string().contains("actuator 1") && e.to_string().contains("encoder.bits_to_position"),
        "{e}"
    );
}

fn toml_with(from: &str, to: &str) -> String {
    assert!(
        PSM_CLASSIC.contains(from),
        "fixture text {from:?} not found"
    );
    PSM_CLASSIC.replacen(from, to, 1)
}

#[test]
fn toml_errors_name_field_actuator_value() {
    let e =
        from_toml_str(&toml_with("name = \"PSM1\"", "name = \"PSM1\"\ncolour = 3")).unwrap_err();
    assert!(e.to_string().contains("colour"), "{e}");
    let e = from_toml_str(&toml_with(
        "hardware_version = \"QLA1\"",
        "hardware_version = \"QLA2\"",
    ))
    .unwrap_err();
    assert!(e.to_string().contains("QLA2"), "{e}");
    let e = from_toml_str(&toml_with("axis_id = 3", "axis_id = 4")).unwrap_err();
    assert!(
        matches!(
            *e.config(),
            IoConfigError::AxisId {
                actuator: 4,
                value: 4,
                ..
            }
        ),
        "{e}"
    );
    let e = from_toml_str(&toml_with("axis_id = 1", "axis_id = 0")).unwrap_err();
    assert!(
        matches!(
            *e.config(),
            IoConfigError::DuplicateAxis {
                actuator: 2,
                board: 6,
                axis: 0,
                other: 1
            }
        ),
        "{e}"
    );
    let e = from_toml_str(&toml_with("scale = 0.4040893845718673", "scale = 0.0")).unwrap_err();
    assert!(
        matches!(
            *e.config(),
            IoConfigError::BadScale {
                actuator: 1,
                field: "drive.effort_to_current",
                ..
            }
        ),
        "{e}"
    );
    let e = from_toml_str(&toml_with(
        "maximum_current = 1.34",
        "maximum_current = -1.0",
    ))
    .unwrap_err();
    assert!(
        e.to_string().contains("actuator 1") && e.to_string().contains("-1"),
        "{e}"
    );
    let e = from_toml_str(&toml_with(
        "[-1.5632, 0.0, 0.0, 0.0]",
        "[0.0, 0.0, 0.0, 0.0]",
    ))
    .unwrap_err();
    assert!(
        matches!(*e.config(), IoConfigError::SingularCoupling { .. }),
        "{e}"
    );
    let e = from_toml_str(&toml_with(
        "board_id = 7\naxis_id = 2",
        "board_id = 8\naxis_id = 2",
    ))
    .unwrap_err();
    assert!(
        matches!(
            *e.config(),
            IoConfigError::TooManyBoards { count: 3, max: 2 }
        ),
        "{e}"
    );
    let e = from_toml_str(&toml_with(
        "hardware_version = \"QLA1\"",
        "hardware_version = \"QLA1\"\nfirmware_version = 6",
    ))
    .unwrap_err();
    assert!(
        matches!(*e.config(), IoConfigError::UnsupportedFirmware { value: 6 }),
        "{e}"
    );
    let mut p = cfg().to_params();
    p.actuators.pop();
    assert!(matches!(
        IoConfig::from_params(p).unwrap_err(),
        IoConfigError::ActuatorCount {
            got: 6,
            expected: 7
        }
    ));
    let mut c = cfg();
    assert!(matches!(
        c.set_coupling([[f64::NAN; 4]; 4]).unwrap_err(),
        IoConfigError::CouplingNotFinite { row: 0, col: 0, .. }
    ));
}

#[test]
fn params_round_trip() {
    let c = cfg();
    let c2 = IoConfig::from_params(c.to_params()).unwrap();
    assert_eq!(c, c2);
    let text = toml::to_string(&c.to_params()).unwrap();
    assert_eq!(from_toml_str(&text).unwrap(), c);
}

fn block_bytes(
    lay: BlockLayout,
    board: u8,
    counts: [i32; 4],
    current_bits: [u16; 4],
    amp_fault_axis: Option<usize>,
) -> Vec<u8> {
    let mut v = vec![0u8; lay.len_bytes()];
    let mut b = FeedbackBlock::new_checked(&mut v[..], lay).unwrap();
    b.set_timestamp(crate::wire::Timestamp(1000));
    b.set_status(crate::wire::BoardStatus::board_id_bits(board) | 0x000F_0F00);
    for ax in 0..4 {
        b.set_encoder_position(ax, EncoderPosition::from_counts(counts[ax]))
            .unwrap();
        b.set_encoder_period(
            ax,
            EncoderPeriod::from_velocity(4000.0, lay.velocity_clock_hz()),
        )
        .unwrap();
        b.set_adc(ax, Adc::new(0x8000, current_bits[ax])).unwrap();
        let fault = if amp_fault_axis == Some(ax) {
            msb::QLA_AMP_FAULT
        } else {
            0
        };
        let _ = b.set_motor_status(ax, msb::AMP_ON | fault);
    }
    v
}

#[test]
fn decode_blocks_hand_computed() {
    let c = cfg();
    let lay = BlockLayout::new(8, BoardKind::Qla).unwrap();
    let b6 = block_bytes(
        lay,
        6,
        [10_000, -10_000, 100_000, 0],
        [40_000, 0x8000, 36_000, 0x8000],
        None,
    );
    let b7 = block_bytes(lay, 7, [0, 0, 0, 0], [0x8000; 4], Some(1));
    let blocks = [
        Some(FeedbackBlock::new_checked(&b6[..], lay).unwrap()),
        Some(FeedbackBlock::new_checked(&b7[..], lay).unwrap()),
    ];
    let mut s = ArmSample::default();
    decode_blocks(&c, &blocks, 42, &mut s);
    assert!(s.valid);
    assert_eq!(s.t_ns, 42);
    assert_eq!(s.board_timestamp, [1000, 1000]);
    let k = 2.0 * std::f64::consts::PI / 14400.0 / 56.5;
    assert_relative_eq!(s.position[0], -10_000.0 * k, epsilon = 1e-12);
    assert_relative_eq!(s.position[1], 10_000.0 * k, epsilon = 1e-12);
    assert_relative_eq!(
        s.position[2],
        100_000.0 * 2.0 * std::f64::consts::PI / 14400.0 / 336.6,
        epsilon = 1e-12
    );
    assert_relative_eq!(
        s.effort[0],
        -1.379_394_531_25 * 56.5 * 0.0438,
        epsilon = 1e-9
    );
    assert_relative_eq!(s.effort[1], 0.0, epsilon = 1e-12);
    assert_relative_eq!(
        s.effort[2],
        0.616_455_078_125 * 336.6 * 0.0438,
        epsilon = 1e-9
    );
    // Firmware velocity: 4000 counts/s * scale.
    assert_relative_eq!(s.velocity[0], -4000.0 * k, max_relative = 1e-9);
    assert_eq!(s.boards[0].board_id, 6);
    assert!(s.boards[1].read_ok && s.boards[1].power_enabled && s.boards[1].motor_supply_good);
    assert!(s.axes[0].amp_on && !s.axes[0].amp_fault);
    assert!(s.axes[5].amp_fault, "board 7 axis 1 = actuator 6");
    // Actuator 1 at -1.38 A is above 1.2*1.34+0.05 = 1.658 A? No.
    assert!(!s.axes[0].current_over_limit);
    // Missing board 7: invalid, health explains it.
    let blocks = [
        Some(FeedbackBlock::new_checked(&b6[..], lay).unwrap()),
        None,
    ];
    decode_blocks(&c, &blocks, 43, &mut s);
    assert!(!s.valid);
    assert!(s.boards[0].read_ok && !s.boards[1].read_ok);
    assert_eq!(s.boards[1].board_id, 7);
    assert_eq!(s.t_ns, 43);
}

#[test]
fn decode_shared_hand_computed() {
    let c = cfg();
    let mut raw = SharedRaw {
        status: [Some(0x060F_0F00), Some(0x078F_0F00)],
        ..Default::default()
    };
    for i in 0..7 {
        raw.encoder_position[i] = Some(EncoderPosition::from_counts(1000 * i as i32).0);
        raw.adc[i] = Some(Adc::new(0, 0x8000).0);
    }
    let mut s = ArmSample::default();
    let pos = decode_shared(&c, &raw, 7, &mut s).position;
    assert!(s.valid);
    assert_relative_eq!(
        pos[1],
        -1000.0 * 2.0 * std::f64::consts::PI / 14400.0 / 56.5,
        epsilon = 1e-12
    );
    assert!(s.boards[1].watchdog_timeout && !s.boards[0].watchdog_timeout);
    assert!(s.axes[0].amp_on);
    raw.adc[3] = None;
    decode_shared(&c, &raw, 8, &mut s);
    assert!(!s.valid);
}

/// The shipped TOML with actuator 1 given a pot calibration and `extra` inside its
/// `potentiometer` table.
fn toml_with_pot(extra: &str) -> String {
    toml_with(
        "maximum_current = 1.34 }\n",
        &format!(
            "maximum_current = 1.34 }}\npotentiometer = {{ bits_to_voltage = {{ scale = \
             6.866455078125e-05 }}, voltage_to_position = {{ scale = 1.0, offset = -2.25 }}{extra} }}\n"
        ),
    )
}

#[test]
fn toml_pot_tolerance_is_optional_and_validated() {
    let c = from_toml_str(&toml_with_pot("")).unwrap();
    assert!(c.has_potentiometers() && !cfg().has_potentiometers());
    assert_eq!(c.actuators()[0].potentiometer.unwrap().tolerance, None);
    let c = from_toml_str(&toml_with_pot(
        ", tolerance = { distance = 0.0873, latency = 0.02 }",
    ))
    .unwrap();
    assert_eq!(
        c.actuators()[0].potentiometer.unwrap().tolerance,
        Some(PotTolerance {
            distance: 0.0873,
            latency: 0.02
        })
    );
    assert_eq!(IoConfig::from_params(c.to_params()).unwrap(), c);
    let bad = [
        ("distance = 0.0, latency = 0.01", "distance", 0.0),
        ("distance = -0.1, latency = 0.01", "distance", -0.1),
        ("distance = 4.0, latency = 0.01", "distance", 4.0),
        ("distance = nan, latency = 0.01", "distance", f64::NAN),
        ("distance = 0.1, latency = 0.0", "latency", 0.0),
        ("distance = 0.1, latency = 60.0", "latency", 60.0),
        ("distance = 0.1, latency = inf", "latency", f64::INFINITY),
    ];
    for (t, field, value) in bad {
        let e = from_toml_str(&toml_with_pot(&format!(", tolerance = {{ {t} }}"))).unwrap_err();
        match e.config() {
            IoConfigError::PotTolerance {
                actuator: 1,
                field: f,
                value: v,
                ..
            } => {
                assert_eq!(*f, format!("potentiometer.tolerance.{field}"), "{t}");
                assert!(v == &value || (v.is_nan() && value.is_nan()), "{t}: {v}");
            }
            other => panic!("{t}: {other}"),
        }
        let text = e.to_string();
        assert!(
            text.contains("actuator 1") && text.contains(field),
            "{text}"
        );
    }
    // The insertion's distance is in metres: 0.3 m at most.
    let ins = toml_with(
        "maximum_current = 0.67 }\n",
        "maximum_current = 0.67 }\npotentiometer = { bits_to_voltage = { scale = 1e-4 }, \
         voltage_to_position = { scale = 0.06 }, tolerance = { distance = 0.5, latency = 0.01 } }\n",
    );
    let e = from_toml_str(&ins).unwrap_err();
    assert!(
        matches!(
            e.config(),
            IoConfigError::PotTolerance { actuator: 3, max, .. } if *max == MAX_POT_DISTANCE_M
        ),
        "{e}"
    );
    let e = from_toml_str(&toml_with_pot(
        ", tolerance = { distance = 0.1, latency = 0.01, unit = \"deg\" }",
    ))
    .unwrap_err();
    assert!(e.to_string().contains("unit"), "{e}");
}

#[test]
fn saw_json_pot_tolerances_are_imported_in_actuator_order() {
    let j = from_saw_json_str(SAW_JSON).unwrap();
    let tol = |i: usize| j.actuators()[i].potentiometer.unwrap().tolerance.unwrap();
    assert_eq!(tol(0).distance, 0.087_266_462_599_716_47);
    assert_eq!(tol(2).distance, 0.005);
    assert!((0..7).all(|i| tol(i).latency == 0.01));
    // distance 0: the dVRK checks nothing for that actuator, so neither pot nor check.
    let off = SAW_JSON.replacen("\"distance\": 0.005", "\"distance\": 0.0", 1);
    let j = from_saw_json_str(&off).unwrap();
    assert!(j.actuators()[2].potentiometer.is_none());
    assert!(j.actuators()[3].potentiometer.is_some());
    let neg = SAW_JSON.replacen("\"distance\": 0.005", "\"distance\": -0.005", 1);
    let e = from_saw_json_str(&neg).unwrap_err();
    assert!(
        matches!(e.config(), IoConfigError::PotTolerance { actuator: 3, .. }),
        "{e}"
    );
    let no_latency = SAW_JSON.replacen("\"latency\": 0.01", "\"latency_s\": 0.01", 1);
    let e = from_saw_json_str(&no_latency).unwrap_err();
    assert!(
        e.to_string().contains("actuator 1") && e.to_string().contains("latency"),
        "{e}"
    );
    // Six tolerances for seven actuators: the seventh is missing, and named.
    let start = SAW_JSON.find("\"axis_id\": 6,\n").unwrap();
    let open = SAW_JSON[..start].rfind(",").unwrap();
    let close = start + SAW_JSON[start..].find('}').unwrap();
    let six = format!("{}{}", &SAW_JSON[..open], &SAW_JSON[close + 1..]);
    let e = from_saw_json_str(&six).unwrap_err();
    assert!(e.to_string().contains("actuator 7"), "{e}");
}

#[test]
fn pots_are_decoded_from_the_adc_quadlet_in_both_decoders() {
    let saw = from_saw_json_str(SAW_JSON).unwrap();
    let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
    let mut b6 = block_bytes(lay, 6, [0; 4], [0x8000; 4], None);
    let b7 = block_bytes(lay, 7, [0; 4], [0x8000; 4], None);
    {
        let mut v = FeedbackBlock::new_checked(&mut b6[..], lay).unwrap();
        v.set_adc(0, Adc::new(10_000, 0x8000)).unwrap();
        v.set_adc(2, Adc::new(50_000, 0x8123)).unwrap();
    }
    let blocks = [
        Some(FeedbackBlock::new_checked(&b6[..], lay).unwrap()),
        Some(FeedbackBlock::new_checked(&b7[..], lay).unwrap()),
    ];
    let mut s = ArmSample::default();
    let st = decode_blocks(&saw, &blocks, 1, &mut s);
    let v = |bits: f64| bits * 4.5 / 65536.0;
    // Actuator 1: V * -1.54737778 + 3.5; actuator 3: V * 0.25486222 - 0.01 (the JSON's values).
    assert_relative_eq!(
        st.pot_position[0],
        v(10_000.0) * -1.547_377_78 + 3.5,
        epsilon = 1e-12
    );
    assert_relative_eq!(
        st.pot_position[2],
        v(50_000.0) * 0.254_862_22 - 0.01,
        epsilon = 1e-12
    );
    // Board 7 axis 0 is actuator 5, its pot at mid-range.
    assert_eq!(
        st.pot_position[4],
        saw.actuators()[4].pot_bits_to_position(0x8000).unwrap()
    );
    // The current bits of the same quadlet are unaffected by the pot bits.
    assert_relative_eq!(
        st.current_amps[2],
        saw.actuators()[2].current_bits_to_amps(0x8123),
        epsilon = 1e-12
    );
    // Without pot calibration: NaN.
    let st = decode_blocks(&cfg(), &blocks, 1, &mut s);
    assert!(st.pot_position.iter().all(|p| p.is_nan()));

    let mut raw = SharedRaw {
        status: [Some(0x060F_0F00), Some(0x070F_0F00)],
        ..Default::default()
    };
    for i in 0..7 {
        raw.encoder_position[i] = Some(EncoderPosition::from_counts(0).0);
        raw.adc[i] = Some(Adc::new(1000 * (i as u16 + 1), 0x8000).0);
    }
    let st = decode_shared(&saw, &raw, 2, &mut s);
    for (i, a) in saw.actuators().iter().enumerate() {
        let want = a.pot_bits_to_position(1000 * (i as u16 + 1)).unwrap();
        assert_eq!(st.pot_position[i], want, "actuator {}", i + 1);
    }
    assert_relative_eq!(
        st.pot_position[0],
        v(1000.0) * -1.547_377_78 + 3.5,
        epsilon = 1e-12
    );
    // An axis not read has no pot either.
    raw.adc[5] = None;
    let st = decode_shared(&saw, &raw, 3, &mut s);
    assert!(st.pot_position[5].is_nan() && !st.pot_position[4].is_nan());
}
