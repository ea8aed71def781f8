//! A virtual-fixture consumer of dvrk-sidecar: waits for every compensated tip pose and computes
//! the signed distance of the tip to a forbidden-region plane, printing when the tip would cross
//! it. It also reads the raw (uncompensated) pose of the same cycle, to show how far the two
//! disagree while the instrument pushes on something.
//!
//! ```text
//! cargo run --release --example virtual_fixture -- --prefix dvrk/PSM1 \
//!     --point 0,0,-0.12 --normal 0,0,1 --margin 0.001 --count 3000
//! ```
//! The plane is given in the RCM frame (CRTK local/measured_cp) by a point and a normal pointing
//! to the allowed side. Depends on dvrk-ipc and iceoryx2 only.

use std::process::ExitCode;

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{NOMINAL_PERIOD, PoseV1, ServiceNames, Subscription, Topic, Update, create_node};

struct Args {
    prefix: String,
    point: [f64; 3],
    normal: [f64; 3],
    margin: f64,
    count: Option<u64>,
}

fn parse_vec3(name: &str, s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--{name} \"{s}\": expected three comma-separated numbers"))?;
    <[f64; 3]>::try_from(v).map_err(|_| format!("--{name} \"{s}\": expected three numbers"))
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        prefix: "dvrk/PSM1".into(),
        point: [0.0, 0.0, -0.12],
        normal: [0.0, 0.0, 1.0],
        margin: 0.001,
        count: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--prefix" => a.prefix = value()?,
            "--point" => a.point = parse_vec3("point", &value()?)?,
            "--normal" => a.normal = parse_vec3("normal", &value()?)?,
            "--margin" => {
                let v = value()?;
                a.margin = v
                    .parse()
                    .map_err(|_| format!("--margin \"{v}\" is not a number"))?
            }
            "--count" => {
                let v = value()?;
                a.count = Some(
                    v.parse()
                        .map_err(|_| format!("--count \"{v}\" is not a count"))?,
                )
            }
            other => return Err(format!("unknown option {other}")),
        }
    }
    let n = a.normal;
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if !(len.is_finite() && len > 0.0) {
        return Err("--normal must be a non-zero vector".into());
    }
    a.normal = [n[0] / len, n[1] / len, n[2] / len];
    Ok(a)
}

/// Signed distance (m) of `p` to the plane; positive on the allowed side.
fn signed_distance(a: &Args, p: &[f64; 3]) -> f64 {
    (0..3).map(|i| a.normal[i] * (p[i] - a.point[i])).sum()
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let node = create_node::<Service>("virtual-fixture", None)?;
    let names = ServiceNames::new(&args.prefix)?;
    let mut tip = Subscription::<PoseV1, Service>::new(
        &node,
        &names,
        Topic::CompensatedMeasuredCp,
        NOMINAL_PERIOD,
    )?;
    let mut raw =
        Subscription::<PoseV1, Service>::new(&node, &names, Topic::MeasuredCp, NOMINAL_PERIOD)?;
    let mut seen = 0u64;
    let mut inside_margin = false;
    // Report a silent publisher once per episode, not at every missed deadline.
    let mut stale_reported = false;
    while args.count.is_none_or(|n| seen < n) {
        match tip.wait()? {
            Update::Fresh(p) if p.header.valid == 1 => {
                seen += 1;
                if stale_reported {
                    eprintln!("seq {}: poses flow again", p.header.seq);
                    stale_reported = false;
                }
                let d = signed_distance(args, &p.position_m);
                let raw_d = raw
                    .try_latest()?
                    .filter(|r| r.header.seq == p.header.seq)
                    .map(|r| signed_distance(args, &r.position_m));
                let now_inside = d < args.margin;
                if now_inside != inside_margin {
                    let raw_txt = raw_d.map_or(String::new(), |r| {
                        format!(" (uncompensated says {:+.3} mm)", r * 1e3)
                    });
                    if now_inside {
                        println!(
                            "seq {}: tip {:+.3} mm from the plane: would cross, fixture engages{raw_txt}",
                            p.header.seq,
                            d * 1e3
                        );
                    } else {
                        println!(
                            "seq {}: tip {:+.3} mm from the plane: clear again{raw_txt}",
                            p.header.seq,
                            d * 1e3
                        );
                    }
                    inside_margin = now_inside;
                }
            }
            Update::Fresh(p) => eprintln!(
                "seq {}: invalid sample (flags {:#x}), fixture holds",
                p.header.seq, p.header.flags
            ),
            Update::Stale { since_ns } if !stale_reported => {
                eprintln!(
                    "no pose for {:.1} ms: fixture holds until poses flow again",
                    since_ns as f64 / 1e6
                );
                stale_reported = true;
            }
            Update::Stale { .. } => {}
            Update::Terminated if !stale_reported => {
                eprintln!("publisher gone: fixture holds until it comes back");
                stale_reported = true;
            }
            Update::Terminated => {}
            Update::Interrupted => {}
        }
    }
    println!("{seen} compensated poses received");
    Ok(())
}
