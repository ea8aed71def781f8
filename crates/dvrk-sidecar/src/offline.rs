//! Offline tools: `fk` and `correct`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use dvrk_compliance::ArmKind;
use serde::Serialize;

use crate::config;
use crate::text::num;

#[derive(clap::Args)]
pub struct FkArgs {
    /// Instrument: its dVRK tool file name (LARGE_NEEDLE_DRIVER_400006) or as the console writes
    /// it (LARGE_NEEDLE_DRIVER:420006[12..]). One the project cannot model is refused.
    #[arg(long, default_value = "LARGE_NEEDLE_DRIVER_400006")]
    tool: String,
    /// Arm kind.
    #[arg(long, value_enum, default_value_t = ArmArg::Classic)]
    arm: ArmArg,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Joint positions q1..q6 (rad, rad, m, rad, rad, rad).
    #[arg(
        num_args = 6,
        required = true,
        allow_negative_numbers = true,
        value_name = "Q"
    )]
    q: Vec<f64>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum ArmArg {
    Classic,
    Si,
}

impl From<ArmArg> for ArmKind {
    fn from(a: ArmArg) -> Self {
        match a {
            ArmArg::Classic => ArmKind::Classic,
            ArmArg::Si => ArmKind::Si,
        }
    }
}

#[derive(Serialize)]
struct FkJson {
    position_m: [f64; 3],
    rotation: [[f64; 3]; 3],
}

pub fn fk(args: &FkArgs) -> Result<()> {
    let tool = config::find_instrument(&args.tool).context("option --tool")?;
    let q: [f64; 6] = args
        .q
        .as_slice()
        .try_into()
        .context("expected exactly six joint positions")?;
    if let Some((i, v)) = q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        bail!("joint position q{} = {v} is not a finite number", i + 1);
    }
    check_joint_limits(args.arm.into(), &q)?;
    let kin = dvrk_compliance::PsmKinematics::new(args.arm.into(), tool);
    let pose = kin.forward(&q);
    let t = pose.translation.vector;
    let r = pose.rotation.to_rotation_matrix();
    let m = r.matrix();
    let out = FkJson {
        position_m: [t.x, t.y, t.z],
        rotation: [
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ],
    };
    let mut stdout = std::io::stdout().lock();
    if args.json {
        // The pose body of `echo --json` (crate::shape), without topic and header.
        let q = pose.rotation.coords;
        let flat: [f64; 9] = core::array::from_fn(|i| out.rotation[i / 3][i % 3]);
        let body = crate::shape::pose_body(out.position_m, [q.x, q.y, q.z, q.w], &flat);
        crate::outln!(stdout, "{}", serde_json::to_string(&body)?)?;
    } else {
        crate::outln!(
            stdout,
            "tool {} ({}) on a {} PSM, RCM frame (local/measured_cp)",
            tool.name,
            tool.tool_type(),
            arm_name(args.arm)
        )?;
        crate::outln!(
            stdout,
            "position_m: [{:.6}, {:.6}, {:.6}]",
            out.position_m[0],
            out.position_m[1],
            out.position_m[2]
        )?;
        crate::outln!(stdout, "rotation:")?;
        for row in out.rotation {
            crate::outln!(stdout, "  [{:9.6}, {:9.6}, {:9.6}]", row[0], row[1], row[2])?;
        }
    }
    Ok(())
}

/// Joint limits of a PSM with a Classic 8 mm instrument, `[lower, upper]` in rad (m for the
/// insertion). Joints 1-3: reference psm-kinematics §1.2 and board protocol §5.2 (Classic soft
/// limits ±91°, ±53°, 0-0.24 m; Si ±2.964, -1.265..1.301, 0-0.29 m). Joints 4-6: the ±174°
/// actuator soft limits through the 400006 coupling (roll 1.5632, wrist 1.0186) and ±180° for
/// the wrist yaw, generous bounds for any instrument.
pub fn joint_limits(arm: ArmKind) -> [[f64; 2]; 6] {
    use dvrk_io::plausibility::{
        CLASSIC_PSM_SOFT_LIMITS, SI_PSM_SOFT_LIMITS, WRIST_ACTUATOR_SOFT_LIMIT_RAD,
    };
    let [yaw, pitch, insertion] = match arm {
        ArmKind::Classic => CLASSIC_PSM_SOFT_LIMITS,
        ArmKind::Si => SI_PSM_SOFT_LIMITS,
    };
    let roll = WRIST_ACTUATOR_SOFT_LIMIT_RAD * 1.5632;
    let wrist = WRIST_ACTUATOR_SOFT_LIMIT_RAD * 1.0186;
    let pi = std::f64::consts::PI;
    [
        yaw,
        pitch,
        insertion,
        [-roll, roll],
        [-wrist, wrist],
        [-pi, pi],
    ]
}

/// Margin beyond [`joint_limits`] still accepted: 5° or 5 mm (the dVRK's pot/encoder tolerance,
/// reference §5.2).
pub const LIMIT_MARGIN: [f64; 6] = [0.0873, 0.0873, 0.005, 0.0873, 0.0873, 0.0873];

/// Refuses joint positions outside the arm's limits plus [`LIMIT_MARGIN`], naming the joint,
/// the value and the range.
pub fn check_joint_limits(arm: ArmKind, q: &[f64]) -> Result<()> {
    let limits = joint_limits(arm);
    for (i, (&v, [lo, hi])) in q.iter().zip(limits).enumerate() {
        let m = LIMIT_MARGIN[i];
        if !(lo - m..=hi + m).contains(&v) {
            let unit = if i == 2 { "m" } else { "rad" };
            bail!(
                "joint position q{} = {} {unit} is outside the {arm:?} PSM's range \
                 [{lo:.4}, {hi:.4}] {unit} (plus a margin of {m} {unit})",
                i + 1,
                num(v)
            );
        }
    }
    Ok(())
}

/// Largest |effort| a Classic PSM's amplifiers can produce on joints 1-3, with 25% to spare: the
/// host current-check limit 1.2·Imax + 50 mA (reference §7) over effort_to_current (§5.2):
/// (1.2·1.34 + 0.05)/0.40409 = 4.1 N·m for joints 1, 2; (1.2·0.67 + 0.05)/0.067828 = 12.6 N for
/// the insertion.
pub const MAX_EFFORT: [f64; 3] = [5.2, 5.2, 15.8];

fn arm_name(a: ArmArg) -> &'static str {
    match a {
        ArmArg::Classic => "Classic",
        ArmArg::Si => "Si",
    }
}

#[derive(clap::Args)]
pub struct CorrectArgs {
    /// Compliance parameter file (TOML).
    #[arg(long)]
    params: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Measured q1,q2,q3 (rad, rad, m).
    #[arg(long, allow_hyphen_values = true, value_name = "Q1,Q2,Q3")]
    position: String,
    /// Measured efforts t1,t2,t3 (N·m, N·m, N).
    #[arg(long, allow_hyphen_values = true, value_name = "T1,T2,T3")]
    effort: String,
}

/// Parses `a,b,c` into three finite numbers; the error names the option and the bad item.
fn parse_triple(option: &str, text: &str) -> Result<[f64; 3]> {
    let items: Vec<&str> = text.split(',').map(str::trim).collect();
    if items.len() != 3 {
        bail!(
            "--{option} \"{text}\": expected three comma-separated numbers, got {}",
            items.len()
        );
    }
    let mut out = [0.0; 3];
    for (i, item) in items.iter().enumerate() {
        let v: f64 = item
            .parse()
            .map_err(|_| anyhow::anyhow!("--{option} item {} \"{item}\" is not a number", i + 1))?;
        if !v.is_finite() {
            bail!("--{option} item {} = {v} is not finite", i + 1);
        }
        out[i] = v;
    }
    Ok(out)
}

#[derive(Serialize)]
struct CorrectJson {
    position: [f64; 3],
    delta_rad: [f64; 2],
    tau_ext_nm: [f64; 2],
    active: [bool; 2],
    insertion_clamped: bool,
}

pub fn correct(args: &CorrectArgs) -> Result<()> {
    let position = parse_triple("position", &args.position)?;
    let effort = parse_triple("effort", &args.effort)?;
    // No --arm here: the widest arm's range (Si) bounds what any PSM can report.
    check_joint_limits(ArmKind::Si, &position).context("option --position")?;
    for (i, (&t, max)) in effort.iter().zip(MAX_EFFORT).enumerate() {
        if t.abs() > max {
            let unit = if i == 2 { "N" } else { "N·m" };
            bail!(
                "--effort item {} = {} {unit} is beyond what a PSM's amplifiers can produce \
                 (|effort| <= {max} {unit})",
                i + 1,
                num(t)
            );
        }
    }
    let model = config::load_compliance(&args.params)?;
    let c = model.correct(&position, &effort);
    let out = CorrectJson {
        position: c.position,
        delta_rad: c.delta_rad,
        tau_ext_nm: c.tau_ext_nm,
        active: c.active,
        insertion_clamped: c.insertion_clamped,
    };
    let mut stdout = std::io::stdout().lock();
    if args.json {
        crate::outln!(stdout, "{}", serde_json::to_string(&out)?)?;
    } else {
        crate::outln!(
            stdout,
            "corrected position: [{:.6}, {:.6}, {:.6}]",
            c.position[0],
            c.position[1],
            c.position[2]
        )?;
        for j in 0..2 {
            crate::outln!(
                stdout,
                "joint {}: tau_ext {:+.4} N·m, delta {:+.6} rad, correction {}",
                j + 1,
                c.tau_ext_nm[j],
                c.delta_rad[j],
                if c.active[j] {
                    "active"
                } else {
                    "inactive (|tau_ext| <= tau_min)"
                }
            )?;
        }
        if c.insertion_clamped {
            crate::outln!(
                stdout,
                "insertion {:.4} m was outside the parameters' range; clamped to {:.4} m",
                position[2],
                c.insertion_m
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triples_parse_and_errors_name_the_item() {
        assert_eq!(
            parse_triple("position", "0.1, -0.2,0.15").unwrap(),
            [0.1, -0.2, 0.15]
        );
        let e = parse_triple("effort", "1,x,3").unwrap_err().to_string();
        assert!(e.contains("--effort item 2") && e.contains("\"x\""), "{e}");
        let e = parse_triple("effort", "1,2").unwrap_err().to_string();
        assert!(e.contains("got 2"), "{e}");
        let e = parse_triple("position", "1,inf,2").unwrap_err().to_string();
        assert!(e.contains("not finite"), "{e}");
    }

    #[test]
    fn joint_values_outside_the_arm_are_refused_with_their_name_and_value() {
        check_joint_limits(ArmKind::Classic, &[0.0, 0.0, 0.12, 0.0, 0.0, 0.0]).unwrap();
        // Just inside the margin.
        check_joint_limits(
            ArmKind::Classic,
            &[1.588 + 0.08, 0.0, 0.2449, 0.0, 0.0, 0.0],
        )
        .unwrap();
        let e = check_joint_limits(ArmKind::Classic, &[0.0, 0.0, -5.0, 0.0, 0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("q3 = -5 m"), "{e}");
        let e = check_joint_limits(ArmKind::Classic, &[0.0, 1e308, 0.1, 0.0, 0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("q2 = 1e308 rad"), "{e}");
        // The Si PSM reaches deeper.
        check_joint_limits(ArmKind::Si, &[0.0, 0.0, 0.28, 0.0, 0.0, 0.0]).unwrap();
        assert!(check_joint_limits(ArmKind::Classic, &[0.0, 0.0, 0.28, 0.0, 0.0, 0.0]).is_err());
    }
}
