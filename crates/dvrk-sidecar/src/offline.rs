//! Offline tools: `fk` and `correct`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use dvrk_compliance::ArmKind;
use serde::Serialize;

use crate::config;

#[derive(clap::Args)]
pub struct FkArgs {
    /// Instrument, by its dVRK name.
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
    if args.json {
        println!("{}", serde_json::to_string(&out)?);
    } else {
        println!(
            "tool {} on a {} PSM, RCM frame (local/measured_cp)",
            tool.name,
            arm_name(args.arm)
        );
        println!(
            "position_m: [{:.6}, {:.6}, {:.6}]",
            out.position_m[0], out.position_m[1], out.position_m[2]
        );
        println!("rotation:");
        for row in out.rotation {
            println!("  [{:9.6}, {:9.6}, {:9.6}]", row[0], row[1], row[2]);
        }
    }
    Ok(())
}

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
    let model = config::load_compliance(&args.params)?;
    let c = model.correct(&position, &effort);
    let out = CorrectJson {
        position: c.position,
        delta_rad: c.delta_rad,
        tau_ext_nm: c.tau_ext_nm,
        active: c.active,
        insertion_clamped: c.insertion_clamped,
    };
    if args.json {
        println!("{}", serde_json::to_string(&out)?);
    } else {
        println!(
            "corrected position: [{:.6}, {:.6}, {:.6}]",
            c.position[0], c.position[1], c.position[2]
        );
        for j in 0..2 {
            println!(
                "joint {}: tau_ext {:+.4} N·m, delta {:+.6} rad, correction {}",
                j + 1,
                c.tau_ext_nm[j],
                c.delta_rad[j],
                if c.active[j] {
                    "active"
                } else {
                    "inactive (|tau_ext| <= tau_min)"
                }
            );
        }
        if c.insertion_clamped {
            println!(
                "insertion {:.4} m was outside the parameters' range; clamped to {:.4} m",
                position[2], c.insertion_m
            );
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
}
