//! The pure part of the virtual-fixture consumer (examples/virtual_fixture.rs): its options and
//! the plane it guards. The example is the I/O shell around it.

use core::time::Duration;

use dvrk_ipc::WaitStrategy;

/// Command-line options of the example.
#[derive(Debug, Clone, PartialEq)]
pub struct Args {
    pub prefix: String,
    /// A point of the plane (m, RCM frame).
    pub point: [f64; 3],
    /// Unit normal of the plane, pointing to the allowed side.
    pub normal: [f64; 3],
    /// Distance to the plane (m) under which the fixture engages.
    pub margin: f64,
    pub count: Option<u64>,
    pub wait: WaitStrategy,
    /// Time without a pose after which the fixture reports a silence; `None`: dvrk-ipc's
    /// default (3 periods, at least 10 ms).
    pub deadline: Option<Duration>,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            prefix: "PSM1".into(),
            point: [0.0, 0.0, -0.12],
            normal: [0.0, 0.0, 1.0],
            margin: 0.001,
            count: None,
            wait: WaitStrategy::Event,
            deadline: None,
        }
    }
}

pub const USAGE: &str = "virtual_fixture [--prefix PSM1] [--point X,Y,Z] [--normal X,Y,Z] \
[--margin M] [--count N] [--wait event|spin|predictive] [--deadline-ms MS]";

fn parse_vec3(name: &str, s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--{name} \"{s}\": expected three comma-separated numbers"))?;
    let v =
        <[f64; 3]>::try_from(v).map_err(|_| format!("--{name} \"{s}\": expected three numbers"))?;
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(format!("--{name} \"{s}\": numbers must be finite"))
    }
}

fn parse_number(name: &str, s: &str) -> Result<f64, String> {
    s.parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| format!("--{name} \"{s}\" is not a number"))
}

/// Parses the options (without the program name).
pub fn parse_args(args: impl IntoIterator<Item = String>) -> Result<Args, String> {
    let mut a = Args::default();
    let mut it = args.into_iter();
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--prefix" => a.prefix = value()?,
            "--point" => a.point = parse_vec3("point", &value()?)?,
            "--normal" => a.normal = parse_vec3("normal", &value()?)?,
            "--margin" => a.margin = parse_number("margin", &value()?)?,
            "--count" => {
                let v = value()?;
                a.count = Some(
                    v.parse()
                        .map_err(|_| format!("--count \"{v}\" is not a count"))?,
                )
            }
            "--wait" => {
                let v = value()?;
                a.wait = v.parse().map_err(|e| format!("--wait: {e}"))?;
            }
            "--deadline-ms" => {
                let v = value()?;
                let ms = parse_number("deadline-ms", &v)?;
                if ms <= 0.0 {
                    return Err(format!("--deadline-ms \"{v}\" must be positive"));
                }
                a.deadline = Some(Duration::from_secs_f64(ms * 1e-3));
            }
            other => return Err(format!("unknown option {other}; usage: {USAGE}")),
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

/// Signed distance (m) of `p` to the plane of `a`; positive on the allowed side.
pub fn signed_distance(a: &Args, p: &[f64; 3]) -> f64 {
    (0..3).map(|i| a.normal[i] * (p[i] - a.point[i])).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Result<Args, String> {
        parse_args(v.iter().map(|s| s.to_string()))
    }

    #[test]
    fn options_parse_and_the_normal_is_normalised() {
        let a = args(&[
            "--normal",
            "0,0,2",
            "--wait",
            "predictive",
            "--deadline-ms",
            "25",
            "--point",
            "0,0,-0.1",
        ])
        .unwrap();
        assert_eq!(a.normal, [0.0, 0.0, 1.0]);
        assert_eq!(a.wait, WaitStrategy::Predictive);
        assert_eq!(a.deadline, Some(Duration::from_millis(25)));
        assert!((signed_distance(&a, &[0.0, 0.0, -0.099]) - 0.001).abs() < 1e-12);
        assert!(signed_distance(&a, &[0.0, 0.0, -0.2]) < 0.0);
    }

    #[test]
    fn bad_options_name_the_option_and_value() {
        for (v, needle) in [
            (&["--wait", "sleepy"][..], "sleepy"),
            (&["--normal", "0,0,0"][..], "--normal"),
            (&["--point", "1,2"][..], "--point \"1,2\""),
            (&["--margin", "inf"][..], "--margin \"inf\""),
            (&["--deadline-ms", "-1"][..], "--deadline-ms \"-1\""),
            (&["--count"][..], "--count needs a value"),
            (&["--bogus"][..], "unknown option --bogus"),
        ] {
            let e = args(v).unwrap_err();
            assert!(e.contains(needle), "{v:?}: {e}");
        }
    }
}
