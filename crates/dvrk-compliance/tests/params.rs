//! Parameter files: every shipped file loads, every bad file fails with the error its first line
//! names, the errors name joint, field and value, and the writer round-trips.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic

mod common;

use std::fs;
use std::path::{Path, PathBuf};

use dvrk_compliance::{
    ComplianceConfig, ComplianceParams, DynamicsParams, HysteresisKind, HysteresisParams,
    JointParams, ModelKind, ParamsError, TorqueOffsetParams, params_to_toml,
};
use proptest::prelude::*;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn toml_files(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| entry.unwrap().path())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with(prefix) && name.ends_with(".toml")
        })
        .collect();
    files.sort();
    files
}

/// The variant's name as `Debug` prints it: `NonFinite { .. }` -> `NonFinite`; parser errors
/// are `Syntax` and `Schema`.
fn variant_name(e: &common::LoadError) -> String {
    let e = match e {
        common::LoadError::Syntax(_) => return "Syntax".to_owned(),
        common::LoadError::Schema(_) => return "Schema".to_owned(),
        common::LoadError::Params(e) => e,
    };
    let debug = format!("{e:?}");
    debug
        .split([' ', '{', '('])
        .next()
        .unwrap_or_default()
        .to_owned()
}

#[test]
fn every_shipped_compliance_file_loads() {
    let files = toml_files(&repo_root().join("config/compliance"), "");
    assert!(!files.is_empty(), "no files in config/compliance");
    for path in files {
        let text = fs::read_to_string(&path).unwrap();
        if let Err(e) = common::config(&text) {
            panic!("{}: {e}", path.display());
        }
    }
}

#[test]
fn every_bad_file_fails_with_its_expected_error() {
    let files = toml_files(&repo_root().join("tests/data/bad-config"), "compliance-");
    let mut seen = Vec::new();
    for path in &files {
        let text = fs::read_to_string(path).unwrap();
        let expected = text
            .lines()
            .next()
            .and_then(|l| l.strip_prefix("# expect: "))
            .unwrap_or_else(|| {
                panic!(
                    "{}: first line must be `# expect: <Variant>`",
                    path.display()
                )
            })
            .trim();
        match common::config(&text) {
            Ok(_) => panic!("{}: loaded, expected {expected}", path.display()),
            Err(e) => {
                assert_eq!(variant_name(&e), expected, "{}: {e}", path.display());
                // Every message says what is wrong in a full sentence, not just a code.
                assert!(e.to_string().len() > 20, "{}: {e}", path.display());
            }
        }
        seen.push(expected.to_owned());
    }
    // Each way a file can be rejected has at least one example.
    for variant in [
        "Syntax",
        "Schema",
        "JointIndex",
        "DuplicateJoint",
        "NonFinite",
        "Negative",
        "InsertionRange",
        "StiffnessTooLow",
        "StiffnessTooHigh",
        "AboveBound",
        "TorqueOffsetLength",
        "TorqueOffsetEmpty",
        "TorqueOffsetNotIncreasing",
        "TorqueOffsetOutOfRange",
    ] {
        assert!(
            seen.iter().any(|s| s == variant),
            "no bad-config file expects {variant}"
        );
    }
}

#[test]
fn paper_file_holds_the_papers_numbers() {
    let text = fs::read_to_string(repo_root().join("config/compliance/paper-psm.toml")).unwrap();
    let p = common::params(&text).unwrap();
    assert_eq!(p.model, ModelKind::Paper);
    assert_eq!(p.joint.len(), 2);
    let (j1, j2) = (&p.joint[0], &p.joint[1]);
    assert_eq!((j1.index, j2.index), (1, 2));
    assert_eq!(
        j1.inverse_compliance_nm_per_rad,
        [639.16, -432.35, 136.32, 3.12]
    ); // Eq. 3
    assert_eq!(
        j2.inverse_compliance_nm_per_rad,
        [3163.17, -1969.15, 448.92, -6.00]
    ); // Eq. 4
    assert_eq!((j1.tau_min_nm, j2.tau_min_nm), (0.1, 0.2));
    for j in [j1, j2] {
        assert_eq!(j.insertion_range_m, [0.09, 0.22]);
        assert_eq!(j.backlash_rad, 0.0);
        assert!(j.torque_offset.effort_nm.iter().all(|&e| e == 0.0));
    }

    let config = ComplianceConfig::from_params(p).unwrap();
    assert_eq!(config.insertion_range_m(0), Some([0.09, 0.22]));
    assert_eq!(config.insertion_range_m(1), Some([0.09, 0.22]));
    assert_eq!(config.insertion_range_m(2), None);
    // Joint 2's cubic is increasing (its derivative's discriminant
    // 4 * 1969.15^2 - 12 * 3163.17 * 448.92 < 0), so its minimum over the range is at 0.09 m:
    // 3163.17 * 0.000729 - 1969.15 * 0.0081 + 448.92 * 0.09 - 6 = 20.7586 N·m/rad.
    let j2 = config.joint(1).unwrap();
    assert!((j2.inverse_compliance_nm_per_rad(0.09) - 20.758_635_93).abs() < 1e-8);
    assert!(4.0 * 1969.15f64.powi(2) - 12.0 * 3163.17 * 448.92 < 0.0);
    for k in 0..=1300 {
        let l = 0.09 + 1e-4 * f64::from(k);
        assert!(j2.inverse_compliance_nm_per_rad(l) >= 20.758, "L = {l}");
    }
}

fn valid_joint(index: i64) -> JointParams {
    JointParams {
        index,
        backlash_rad: 0.0,
        tau_min_nm: 0.1,
        inverse_compliance_nm_per_rad: [639.16, -432.35, 136.32, 3.12],
        insertion_range_m: [0.09, 0.22],
        inverse_compliance_rel_sigma: None,
        backlash_rel_sigma: None,
        torque_offset: TorqueOffsetParams {
            position_rad: vec![-1.0, 1.0],
            effort_nm: vec![0.0, 0.0],
        },
        hysteresis: None,
        dynamics: None,
    }
}

fn config_error(joints: Vec<JointParams>) -> ParamsError {
    let p = ComplianceParams {
        model: ModelKind::Paper,
        joint: joints,
    };
    ComplianceConfig::from_params(p).unwrap_err()
}

#[test]
fn errors_name_joint_field_and_value() {
    let mut j = valid_joint(2);
    j.inverse_compliance_nm_per_rad[2] = f64::NAN;
    let e = config_error(vec![j]);
    let ParamsError::NonFinite {
        joint: 2,
        field,
        value,
    } = &e
    else {
        panic!("{e:?}")
    };
    assert_eq!(field, "inverse_compliance_nm_per_rad[2]");
    assert!(value.is_nan());
    assert_eq!(
        e.to_string(),
        "joint 2: inverse_compliance_nm_per_rad[2] = NaN is not a finite number"
    );

    let mut j = valid_joint(1);
    j.backlash_rad = -0.01;
    let e = config_error(vec![j]);
    assert_eq!(
        e.to_string(),
        "joint 1: backlash_rad = -0.01 must not be negative"
    );

    let mut j = valid_joint(1);
    j.torque_offset.position_rad = vec![-1.0, 0.5, 0.2];
    j.torque_offset.effort_nm = vec![0.0; 3];
    let e = config_error(vec![j]);
    assert_eq!(
        e,
        ParamsError::TorqueOffsetNotIncreasing {
            joint: 1,
            element: 2,
            value: 0.2
        }
    );

    let mut j = valid_joint(1);
    j.insertion_range_m = [-0.01, 0.2];
    let e = config_error(vec![j]);
    assert_eq!(
        e,
        ParamsError::InsertionRange {
            joint: 1,
            min_m: -0.01,
            max_m: 0.2
        }
    );

    let e = config_error(vec![valid_joint(0)]);
    assert_eq!(e, ParamsError::JointIndex { joint: 0 });
    let e = config_error(vec![valid_joint(2), valid_joint(1), valid_joint(2)]);
    assert_eq!(e, ParamsError::DuplicateJoint { joint: 2 });
}

#[test]
fn stiffness_check_reports_where_the_cubic_is_lowest() {
    // Eq. 4 over [0, 0.22]: the cubic is increasing, so the reported point is 0 m where
    // 1/K = c0 = -6.
    let mut j = valid_joint(2);
    j.inverse_compliance_nm_per_rad = [3163.17, -1969.15, 448.92, -6.00];
    j.insertion_range_m = [0.0, 0.22];
    let e = config_error(vec![j]);
    assert_eq!(
        e,
        ParamsError::StiffnessTooLow {
            joint: 2,
            insertion_m: 0.0,
            value: -6.0
        }
    );

    // The narrow dip 1000 (L - 0.155)^2 - 0.001 is found at its bottom, 0.155 m.
    let mut j = valid_joint(1);
    j.inverse_compliance_nm_per_rad = [0.0, 1000.0, -310.0, 24.024];
    let e = config_error(vec![j]);
    let ParamsError::StiffnessTooLow {
        joint: 1,
        insertion_m,
        value,
    } = e
    else {
        panic!("{e:?}")
    };
    assert!((insertion_m - 0.155).abs() < 1e-12 && (value + 0.001).abs() < 1e-9);

    // Touching zero exactly at an end is rejected too: 100 (L - 0.09) on [0.09, 0.22].
    let mut j = valid_joint(1);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 100.0, -9.0];
    assert!(matches!(
        config_error(vec![j]),
        ParamsError::StiffnessTooLow { joint: 1, .. }
    ));

    // A true cubic with an interior local minimum: 1000 (u^3 - 0.0025 u) + c, u = L - 0.15,
    // i.e. 1000 L^3 - 450 L^2 + 65 L - 3 + c. Its minimum on [0.12, 0.22] is at
    // u = sqrt(0.0025 / 3) = 0.02887 (L = 0.17887), value c - 0.04811; the ends give c + 0.048
    // and c + 0.168. With c = 2.06 it stays above the 2 N·m/rad bound, with c = 2.04 it dips
    // below it inside.
    let with_c0 = |c0: f64| {
        let mut j = valid_joint(1);
        j.inverse_compliance_nm_per_rad = [1000.0, -450.0, 65.0, c0];
        j.insertion_range_m = [0.12, 0.22];
        ComplianceConfig::from_params(ComplianceParams {
            model: ModelKind::Paper,
            joint: vec![j],
        })
    };
    assert!(with_c0(-3.0 + 2.06).is_ok());
    let e = with_c0(-3.0 + 2.04).unwrap_err();
    let ParamsError::StiffnessTooLow {
        joint: 1,
        insertion_m,
        value,
    } = e
    else {
        panic!("{e:?}")
    };
    assert!(
        (insertion_m - (0.15 + (0.0025f64 / 3.0).sqrt())).abs() < 1e-9,
        "{insertion_m}"
    );
    assert!((value - (2.04 - 0.048_112_5)).abs() < 1e-6, "{value}");
}

#[test]
fn physical_bounds_name_joint_field_and_value() {
    // Issue 9: a cubic softer than 1 N·m/rad anywhere in the range is a fit error, not a shaft.
    // 0.5 N·m/rad everywhere (a positive constant, accepted before the bound existed).
    let mut j = valid_joint(2);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 0.5];
    let e = config_error(vec![j]);
    assert_eq!(
        e,
        ParamsError::StiffnessTooLow {
            joint: 2,
            insertion_m: 0.09,
            value: 0.5
        }
    );
    assert!(
        e.to_string().contains("joint 2") && e.to_string().contains("0.5"),
        "{e}"
    );
    // Issue 22: exactly 1 N·m/rad (a 0.5 rad correction for 0.5 N·m) is refused; the bounds
    // 2 and 500 N·m/rad themselves pass.
    let mut j = valid_joint(1);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 1.0];
    assert!(matches!(
        config_error(vec![j]),
        ParamsError::StiffnessTooLow { joint: 1, value, .. } if value == 1.0
    ));
    for bound in [2.0, 500.0] {
        let mut j = valid_joint(1);
        j.inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, bound];
        assert!(
            ComplianceConfig::from_params(ComplianceParams {
                model: ModelKind::Paper,
                joint: vec![j],
            })
            .is_ok(),
            "{bound}"
        );
    }
    // Issue 22: 1e308 N·m/rad (no correction at all) is refused, naming where the cubic is
    // highest: a line rising to 600 N·m/rad at the top of [0.09, 0.22] m.
    let mut j = valid_joint(2);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 1e308];
    let e = config_error(vec![j]);
    assert!(
        matches!(e, ParamsError::StiffnessTooHigh { joint: 2, value, .. } if value == 1e308),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("1e308") && e.to_string().contains("<= 500"),
        "{e}"
    );
    let mut j = valid_joint(1);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 4000.0, -280.0];
    let e = config_error(vec![j]);
    let ParamsError::StiffnessTooHigh {
        joint: 1,
        insertion_m,
        value,
    } = e
    else {
        panic!("{e:?}")
    };
    assert_eq!(insertion_m, 0.22);
    assert!((value - 600.0).abs() < 1e-9, "{value}");

    // Issue 22: a torque offset point at 1e308 rad is outside the joint's range.
    let mut j = valid_joint(1);
    j.torque_offset.position_rad = vec![-1.0, 1e308];
    j.torque_offset.effort_nm = vec![0.0, 0.0];
    let e = config_error(vec![j]);
    assert!(
        matches!(
            e,
            ParamsError::TorqueOffsetOutOfRange { joint: 1, element: 1, value, .. } if value == 1e308
        ),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("torque_offset.position_rad[1] = 1e308"),
        "{e}"
    );
    // The range's ends pass (pitch: the Si PSM's -1.265..1.301 rad).
    let mut j = valid_joint(2);
    j.torque_offset.position_rad = vec![-1.265, 1.301];
    j.torque_offset.effort_nm = vec![0.0, 0.0];
    assert!(
        ComplianceConfig::from_params(ComplianceParams {
            model: ModelKind::Paper,
            joint: vec![j],
        })
        .is_ok()
    );
    // The cubic [0, 0, 0, 1e-12] gave 1e12 rad corrections.
    let mut j = valid_joint(1);
    j.inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 1e-12];
    assert!(matches!(
        config_error(vec![j]),
        ParamsError::StiffnessTooLow { joint: 1, value, .. } if value == 1e-12
    ));

    // Backlash above 0.02 rad (the 10.0), and the bound itself passes.
    let mut j = valid_joint(1);
    j.backlash_rad = 10.0;
    let e = config_error(vec![j]);
    assert_eq!(
        e,
        ParamsError::AboveBound {
            joint: 1,
            field: "backlash_rad".to_owned(),
            value: 10.0,
            max: 0.02
        }
    );
    let text = e.to_string();
    assert!(
        text.contains("joint 1") && text.contains("backlash_rad") && text.contains("10"),
        "{text}"
    );
    let mut j = valid_joint(1);
    j.backlash_rad = 0.02;
    j.tau_min_nm = 1.0;
    assert!(
        ComplianceConfig::from_params(ComplianceParams {
            model: ModelKind::Paper,
            joint: vec![j],
        })
        .is_ok()
    );

    // Dead band above 1 N·m.
    let mut j = valid_joint(2);
    j.tau_min_nm = 1.5;
    assert_eq!(
        config_error(vec![valid_joint(1), j]),
        ParamsError::AboveBound {
            joint: 2,
            field: "tau_min_nm".to_owned(),
            value: 1.5,
            max: 1.0
        }
    );
}

/// The relative scatters `fit` writes (`inverse_compliance_rel_sigma`, `backlash_rel_sigma`):
/// one rule for both, and what the fitter writes reads back as written.
#[test]
fn the_fitted_scatters_are_checked_and_round_trip() {
    type Field = fn(&mut JointParams) -> &mut Option<f64>;
    let fields: [(&str, f64, Field); 2] = [
        (
            "inverse_compliance_rel_sigma",
            dvrk_compliance::bounds::MAX_STIFFNESS_REL_SIGMA,
            |j| &mut j.inverse_compliance_rel_sigma,
        ),
        (
            "backlash_rel_sigma",
            dvrk_compliance::bounds::MAX_BACKLASH_REL_SIGMA,
            |j| &mut j.backlash_rel_sigma,
        ),
    ];
    for (field, max, slot) in fields {
        let with = |index: i64, value: Option<f64>| {
            let mut j = valid_joint(index);
            *slot(&mut j) = value;
            j
        };
        assert_eq!(
            config_error(vec![with(1, Some(-0.01))]),
            ParamsError::Negative {
                joint: 1,
                field: field.to_owned(),
                value: -0.01,
            }
        );
        assert_eq!(
            config_error(vec![with(1, Some(0.6))]),
            ParamsError::AboveBound {
                joint: 1,
                field: field.to_owned(),
                value: 0.6,
                max,
            }
        );
        for bad in [f64::NAN, f64::INFINITY] {
            assert!(matches!(
                config_error(vec![with(1, Some(bad))]),
                ParamsError::NonFinite { joint: 1, field: ref f, .. } if f == field
            ));
        }
        // Written by the fitter and read back as written; absent stays absent.
        let p = ComplianceParams {
            model: ModelKind::Paper,
            joint: vec![with(1, Some(0.0123)), valid_joint(2)],
        };
        let text = dvrk_compliance::params_to_toml(&p);
        assert!(text.contains(&format!("{field} = 0.0123")), "{text}");
        let mut back = common::config(&text).unwrap().to_params();
        assert_eq!(*slot(&mut back.joint[0]), Some(0.0123), "{field}");
        assert_eq!(*slot(&mut back.joint[1]), None, "{field}");
    }
}

#[test]
fn model_defaults_to_paper_and_joints_may_be_absent() {
    let c = common::config("joint = []").unwrap();
    assert_eq!(c.model(), ModelKind::Paper);
    assert!(c.joint(0).is_none() && c.joint(1).is_none());
    let c = common::config("model = \"continuous\"\njoint = []").unwrap();
    assert_eq!(c.model(), ModelKind::Continuous);
}

#[test]
fn shipped_file_round_trips_through_the_writer() {
    let text = fs::read_to_string(repo_root().join("config/compliance/paper-psm.toml")).unwrap();
    let config = common::config(&text).unwrap();
    let written = params_to_toml(&config.to_params());
    let again = common::config(&written).unwrap();
    assert_eq!(again, config);
    assert_eq!(again.to_params(), config.to_params());
    // serde's own serializer agrees with the schema, too.
    let via_serde = toml::to_string(&config.to_params()).unwrap();
    assert_eq!(common::params(&via_serde).unwrap(), config.to_params());
}

/// Issue 20 item 3: the default file carries the distal weight, the writer keeps it, and a
/// file without it (fitted before it existed) still loads with the weight not modelled.
#[test]
fn distal_gravity_round_trips_and_old_files_load_without_it() {
    let text = fs::read_to_string(repo_root().join("config/compliance/sim-psm.toml")).unwrap();
    let config = common::config(&text).unwrap();
    for j in 0..2 {
        let g = config.joint(j).unwrap().dynamics().unwrap().distal_gravity;
        assert!(g.is_some(), "joint {j} has no distal weight");
    }
    let again = common::config(&params_to_toml(&config.to_params())).unwrap();
    assert_eq!(again, config);
    // Without the field: loads, not modelled.
    let old: String = text
        .lines()
        .map(|l| match l.find(", distal_gravity = {") {
            Some(i) => format!("{} }}", &l[..i]),
            None => l.to_owned(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let old = common::config(&old).unwrap();
    assert_eq!(
        old.joint(0).unwrap().dynamics().unwrap().distal_gravity,
        None
    );
    // Unknown fields inside it and bad values are refused, naming the field.
    let bad = text.replacen("reference_insertion_m", "reference_depth_m", 1);
    assert!(common::config(&bad).is_err());
    let bad = text.replacen("weight_sigma_n = [", "weight_sigma_n = [-", 1);
    let e = common::config(&bad).unwrap_err().to_string();
    assert!(e.contains("dynamics.distal_gravity.weight_sigma_n"), "{e}");
}

/// Any float, including NaN, infinities, subnormals and -0.0.
fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<f64>(),
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(-0.0),
        -1.0e3..1.0e3,
    ]
}

fn any_joint() -> impl Strategy<Value = JointParams> {
    (
        any::<i64>(),
        any_f64(),
        any_f64(),
        prop::array::uniform4(any_f64()),
        prop::array::uniform2(any_f64()),
        prop::collection::vec((any_f64(), any_f64()), 0..6),
        prop::option::of((any::<bool>(), any_f64())),
        prop::option::of((
            prop::array::uniform2(any_f64()),
            prop::array::uniform4(any_f64()),
            any_f64(),
        )),
    )
        .prop_map(
            |(index, backlash_rad, tau_min_nm, c, range, table, hysteresis, dynamics)| {
                JointParams {
                    index,
                    backlash_rad,
                    tau_min_nm,
                    inverse_compliance_nm_per_rad: c,
                    inverse_compliance_rel_sigma: None,
                    backlash_rel_sigma: None,
                    insertion_range_m: range,
                    torque_offset: TorqueOffsetParams {
                        position_rad: table.iter().map(|t| t.0).collect(),
                        effort_nm: table.iter().map(|t| t.1).collect(),
                    },
                    hysteresis: hysteresis.map(|(friction, gap_rad)| HysteresisParams {
                        kind: if friction {
                            HysteresisKind::Friction
                        } else {
                            HysteresisKind::Play
                        },
                        gap_rad,
                    }),
                    dynamics: dynamics.map(|(inertia, [b, fc, vs, std], k)| DynamicsParams {
                        inertia_kg_m2: inertia,
                        viscous_nm_s_per_rad: b,
                        coulomb_nm: fc,
                        stick_velocity_rad_per_s: vs,
                        residual_std_nm: std,
                        gate_sigmas: k,
                        max_acceleration_rad_per_s2: None,
                        distal_gravity: None,
                    }),
                }
            },
        )
}

/// Equality that treats NaN as equal to NaN: compare the written text of both sides.
fn bits(p: &ComplianceParams) -> String {
    format!("{p:?}")
}

proptest! {
    #[test]
    fn writer_round_trips_any_params(
        continuous in any::<bool>(),
        joints in prop::collection::vec(any_joint(), 0..3),
    ) {
        let model = if continuous { ModelKind::Continuous } else { ModelKind::Paper };
        let p = ComplianceParams { model, joint: joints };
        let text = params_to_toml(&p);
        let back = common::params(&text)
            .map_err(|e| TestCaseError::fail(format!("{e}\n{text}")))?;
        prop_assert_eq!(bits(&back), bits(&p));
    }
}
