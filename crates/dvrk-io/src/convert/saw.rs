//! Import of the dVRK's own sawRobotIO1394 JSON, `"$version": "6"` (reference §5.1), so a lab
//! reuses its calibrated file.
//!
//! This is a foreign format: unknown keys (brakes, digital inputs, Dallas chips, limits, ...)
//! are ignored, unlike this crate's own TOML. The fields used are read strictly:
//! `robots[].{name, hardware_version, actuators[].{board_id, axis_id, joint_type,
//! drive.{bits_to_current, effort_to_current, maximum_current}, encoder.{bits_to_position,
//! velocity_source}, potentiometer.{bits_to_voltage, voltage_to_position}},
//! potentiometers.tolerances[].{distance, latency}}`. The tolerances are taken in actuator
//! order, as sawRobotIO1394 applies them (its `axis_id` is not used for the pairing); a distance
//! of 0 is the dVRK's "no check for this actuator", and such an actuator is imported without
//! its pot. The instrument
//! coupling is not in this file (it comes from the tool file): it stays identity until
//! [`IoConfig::set_coupling`]. `//` and `/* */` comments, which the dVRK's JSON reader accepts,
//! are stripped first.

use serde::Deserialize;

use super::{
    ActuatorParams, Conversion, DriveParams, EncoderParams, IoConfig, IoConfigError, IoParams,
    JointType, PotTolerance, PotentiometerParams, VelocitySource,
};

/// A sawRobotIO1394 JSON file as deserialised by the application (e.g. with `serde_json`,
/// after [`strip_json_comments`]); [`IoConfig::from_saw_file`] validates it.
#[derive(Deserialize)]
pub struct SawFile {
    #[serde(rename = "$id")]
    id: Option<String>,
    #[serde(rename = "$version")]
    version: Option<SawVersionValue>,
    #[serde(default)]
    robots: Vec<SawRobot>,
}

/// `$version`, written as a string ("6") or a number (6) in the wild.
#[derive(Deserialize)]
#[serde(untagged)]
enum SawVersionValue {
    Text(String),
    Integer(i64),
    Other(serde::de::IgnoredAny),
}

#[derive(Deserialize)]
struct SawRobot {
    name: String,
    hardware_version: Option<String>,
    #[serde(default)]
    actuators: Vec<SawActuator>,
    potentiometers: Option<SawPots>,
}

#[derive(Deserialize)]
struct SawPots {
    tolerances: Option<Vec<SawTolerance>>,
}

#[derive(Deserialize)]
struct SawTolerance {
    distance: Option<f64>,
    latency: Option<f64>,
}

#[derive(Deserialize)]
struct SawActuator {
    board_id: u8,
    axis_id: u8,
    joint_type: String,
    drive: Option<SawDrive>,
    encoder: Option<SawEncoder>,
    potentiometer: Option<SawPot>,
}

#[derive(Deserialize)]
struct SawDrive {
    bits_to_current: Option<Conversion>,
    effort_to_current: Option<Conversion>,
    maximum_current: Option<f64>,
}

#[derive(Deserialize)]
struct SawEncoder {
    bits_to_position: Option<Conversion>,
    velocity_source: Option<String>,
}

#[derive(Deserialize)]
struct SawPot {
    bits_to_voltage: Option<Conversion>,
    voltage_to_position: Option<Conversion>,
}

/// Removes `//` line comments and `/* */` block comments outside strings.
/// Removes the `//` and `/* */` comments that the dVRK's JSON reader accepts, so a standard
/// JSON parser can read the file (string contents are kept as they are).
pub fn strip_json_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars().peekable();
    let mut in_str = false;
    while let Some(c) = chars.next() {
        if in_str {
            out.push(c);
            if c == '\\' {
                if let Some(n) = chars.next() {
                    out.push(n);
                }
            } else if c == '"' {
                in_str = false;
            }
            continue;
        }
        match (c, chars.peek()) {
            ('"', _) => {
                in_str = true;
                out.push(c);
            }
            ('/', Some('/')) => {
                for n in chars.by_ref() {
                    if n == '\n' {
                        out.push('\n');
                        break;
                    }
                }
            }
            ('/', Some('*')) => {
                chars.next();
                let mut prev = ' ';
                for n in chars.by_ref() {
                    if prev == '*' && n == '/' {
                        break;
                    }
                    prev = n;
                }
                out.push(' ');
            }
            _ => out.push(c),
        }
    }
    out
}

impl IoConfig {
    /// Imports robot `name` (or the first robot) of a deserialised sawRobotIO1394 JSON v6 file.
    pub fn from_saw_file(file: SawFile, name: Option<&str>) -> Result<Self, IoConfigError> {
        let version = match &file.version {
            Some(SawVersionValue::Text(s)) => s.clone(),
            Some(SawVersionValue::Integer(n)) => n.to_string(),
            Some(SawVersionValue::Other(_)) => "not a string or an integer".to_string(),
            None => "missing".to_string(),
        };
        if version != "6" {
            return Err(IoConfigError::SawVersion { found: version });
        }
        if let Some(id) = &file.id
            && id != "saw-robot-io.schema.json"
        {
            return Err(IoConfigError::SawId { found: id.clone() });
        }
        let names = || {
            file.robots
                .iter()
                .map(|r| r.name.clone())
                .collect::<Vec<_>>()
        };
        let robot = match name {
            Some(n) => file.robots.iter().find(|r| r.name == n),
            None => file.robots.first(),
        }
        .ok_or_else(|| IoConfigError::SawRobot {
            wanted: name.unwrap_or("(first)").to_string(),
            found: names(),
        })?;
        let missing = |actuator: usize, field: &'static str| IoConfigError::SawMissing {
            robot: robot.name.clone(),
            actuator,
            field,
        };
        let mut actuators = Vec::with_capacity(robot.actuators.len());
        for (i, a) in robot.actuators.iter().enumerate() {
            let n = i + 1;
            let joint_type = match a.joint_type.to_ascii_uppercase().as_str() {
                "REVOLUTE" => JointType::Revolute,
                "PRISMATIC" => JointType::Prismatic,
                _ => return Err(missing(n, "joint_type (REVOLUTE or PRISMATIC)")),
            };
            let drive = a.drive.as_ref().ok_or_else(|| missing(n, "drive"))?;
            let encoder = a.encoder.as_ref().ok_or_else(|| missing(n, "encoder"))?;
            let velocity_source = match encoder
                .velocity_source
                .as_deref()
                .map(str::to_ascii_uppercase)
                .as_deref()
            {
                None | Some("FIRMWARE") => VelocitySource::Firmware,
                Some("SOFTWARE") => VelocitySource::Software,
                Some(_) => {
                    return Err(missing(n, "encoder.velocity_source (FIRMWARE or SOFTWARE)"));
                }
            };
            let tolerance = match robot
                .potentiometers
                .as_ref()
                .and_then(|p| p.tolerances.as_ref())
            {
                None => None,
                Some(all) => {
                    let t = all
                        .get(i)
                        .ok_or_else(|| missing(n, "potentiometers.tolerances[actuator - 1]"))?;
                    Some(PotTolerance {
                        distance: t.distance.ok_or_else(|| {
                            missing(n, "potentiometers.tolerances[actuator - 1].distance")
                        })?,
                        latency: t.latency.ok_or_else(|| {
                            missing(n, "potentiometers.tolerances[actuator - 1].latency")
                        })?,
                    })
                }
            };
            let potentiometer = match &a.potentiometer {
                // distance 0: sawRobotIO1394 skips the check of this actuator.
                _ if tolerance.is_some_and(|t| t.distance == 0.0) => None,
                Some(SawPot {
                    bits_to_voltage: Some(b),
                    voltage_to_position: Some(v),
                }) => Some(PotentiometerParams {
                    bits_to_voltage: *b,
                    voltage_to_position: *v,
                    tolerance,
                }),
                _ => None,
            };
            actuators.push(ActuatorParams {
                board_id: a.board_id,
                axis_id: a.axis_id,
                joint_type,
                encoder: EncoderParams {
                    bits_to_position: encoder
                        .bits_to_position
                        .ok_or_else(|| missing(n, "encoder.bits_to_position"))?,
                    velocity_source,
                },
                drive: DriveParams {
                    bits_to_current: drive
                        .bits_to_current
                        .ok_or_else(|| missing(n, "drive.bits_to_current"))?,
                    effort_to_current: drive
                        .effort_to_current
                        .ok_or_else(|| missing(n, "drive.effort_to_current"))?,
                    maximum_current: drive
                        .maximum_current
                        .ok_or_else(|| missing(n, "drive.maximum_current"))?,
                },
                potentiometer,
            });
        }
        IoConfig::from_params(IoParams {
            name: robot.name.clone(),
            hardware_version: robot
                .hardware_version
                .clone()
                .unwrap_or_else(|| "QLA1".to_string()),
            firmware_version: None,
            actuators,
            coupling: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::strip_json_comments;

    #[test]
    fn comments_are_stripped_outside_strings() {
        let t = "{\"a\": \"x//y\", // c\n \"b\": /* z */ 1}";
        let v: serde_json::Value = serde_json::from_str(&strip_json_comments(t)).unwrap();
        assert_eq!(v["a"], "x//y");
        assert_eq!(v["b"], 1);
    }
}
