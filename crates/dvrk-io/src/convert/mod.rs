//! Raw bits to SI: conversion config and the pure per-cycle conversion (reference §5).
//!
//! Per actuator (sawRobotIO1394 pipeline, reference §5.1):
//! - position = `bits_to_position.scale` · counts + offset (rad, or m for prismatic);
//! - current  = `bits_to_current.scale` · ADC current bits + offset (A);
//! - effort   = (current − `effort_to_current.offset`) / `effort_to_current.scale` (N·m, or N);
//! - pot      = `voltage_to_position`(`bits_to_voltage`(pot bits)) (rad or m).
//!
//! Actuator to joint (reference §5.3): joints 1–3 equal actuators 1–3; joints 4–7 = C ·
//! actuators 4–7 with the instrument's 4×4 `ActuatorToJointPosition`; joint effort = C^-T ·
//! actuator effort (the inverse is computed once, when the coupling is set).
//!
//! Config comes from this crate's TOML schema ([`IoParams`], `config/io/*.toml`) or from the
//! dVRK's own sawRobotIO1394 JSON version 6 ([`IoConfig::from_saw_file`]).

mod sample;
mod saw;

pub use sample::{
    ActuatorState, ArmSample, AxisHealth, BoardHealth, SharedRaw, decode_blocks, decode_shared,
    joints_from_actuators,
};
pub use saw::{SawFile, strip_json_comments};

use serde::{Deserialize, Serialize};

use crate::wire::{BlockLayout, BoardKind};

/// Joints (and actuators) of a PSM, in dVRK order: yaw, pitch, insertion, roll, wrist pitch,
/// wrist yaw, jaw.
pub const NUM_JOINTS: usize = 7;
/// Boards of one arm (PSM1: boards 6 and 7 with QLA1, reference §1.1; one with DQLA/dRAC).
pub const MAX_BOARDS: usize = 2;
/// Joints coupled by the instrument (roll, wrist pitch, wrist yaw, jaw), indices 3..7.
pub const COUPLED: std::ops::Range<usize> = 3..7;

/// A linear conversion y = scale · x + offset, as in sawRobotIO1394 (`{scale, offset}`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Conversion {
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
}

impl Conversion {
    pub const fn new(scale: f64, offset: f64) -> Self {
        Self { scale, offset }
    }
    #[inline(always)]
    pub fn apply(&self, x: f64) -> f64 {
        self.scale * x + self.offset
    }
    /// x such that apply(x) = y (scale is nonzero after validation).
    #[inline]
    pub fn invert(&self, y: f64) -> f64 {
        (y - self.offset) / self.scale
    }
}

/// Revolute (rad, N·m) or prismatic (m, N).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JointType {
    Revolute,
    Prismatic,
}

/// Where velocity comes from (sawRobotIO1394 `velocity_source`, reference §5.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VelocitySource {
    /// The board's encoder period (VEL quadlet); needs the feedback block (exclusive mode).
    #[default]
    Firmware,
    /// Change of counts over the time between samples.
    Software,
}

/// Encoder section of one actuator.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EncoderParams {
    /// rad (m) per count.
    pub bits_to_position: Conversion,
    #[serde(default)]
    pub velocity_source: VelocitySource,
}

/// Drive section of one actuator.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveParams {
    /// A per ADC current bit, offset in A.
    pub bits_to_current: Conversion,
    /// A per N·m (A per N for prismatic).
    pub effort_to_current: Conversion,
    /// Sustained maximum current, A (host current check, reference §7).
    pub maximum_current: f64,
}

/// Analog potentiometer section (Classic arms, reference §5.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PotentiometerParams {
    /// V per pot bit (QLA: 4.5/65536, reference §2.3).
    pub bits_to_voltage: Conversion,
    /// rad (m) per V; from the robot's own `.cal` file.
    pub voltage_to_position: Conversion,
    /// How far and how long pot and encoder may disagree. Absent: the dVRK's default for the
    /// arm (`dvrk_io::plausibility`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<PotTolerance>,
}

/// The dVRK's pot/encoder consistency rule for one actuator (sawRobotIO1394
/// `potentiometers.tolerances[]`, same field names and SI units): an error only once
/// |pot − encoder| has stayed above `distance` for longer than `latency`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PotTolerance {
    /// rad, or m for a prismatic actuator.
    pub distance: f64,
    /// s.
    pub latency: f64,
}

/// Largest accepted [`PotTolerance::distance`] of a revolute actuator (rad): beyond half a
/// turn the check compares nothing.
pub const MAX_POT_DISTANCE_RAD: f64 = std::f64::consts::PI;
/// Largest accepted [`PotTolerance::distance`] of a prismatic actuator (m): a PSM's whole
/// insertion range (0.24 m Classic, 0.29 m Si).
pub const MAX_POT_DISTANCE_M: f64 = 0.3;
/// Largest accepted [`PotTolerance::latency`] (s). The dVRK generates 0.01 s; its pot
/// debugging guide doubles it up to about 1 s before widening the distance instead.
pub const MAX_POT_LATENCY_S: f64 = 5.0;

/// One actuator in the TOML schema.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorParams {
    pub board_id: u8,
    pub axis_id: u8,
    pub joint_type: JointType,
    pub encoder: EncoderParams,
    pub drive: DriveParams,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub potentiometer: Option<PotentiometerParams>,
}

/// Instrument coupling in the TOML schema (reference §5.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CouplingParams {
    /// Instrument name, for the record (e.g. "LARGE_NEEDLE_DRIVER_400006").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instrument: Option<String>,
    /// Rows = joints 4–7 (roll, wrist pitch, wrist yaw, jaw), columns = actuators 4–7.
    #[serde(deserialize_with = "crate::exact::matrix")]
    pub actuator_to_joint_position: [[f64; 4]; 4],
}

/// Parsed (not yet validated) conversion config: the TOML schema of `config/io/*.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IoParams {
    /// Arm name, e.g. "PSM1".
    pub name: String,
    /// "QLA1", "DQLA" or "dRA1" (sawRobotIO1394 spelling, reference §1.1).
    pub hardware_version: String,
    /// Expected firmware (7, 8, 9). Absent: read from each board at the first exclusive read.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware_version: Option<u32>,
    /// Exactly seven, in joint order.
    pub actuators: Vec<ActuatorParams>,
    /// Absent: identity (no instrument coupling).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coupling: Option<CouplingParams>,
}

/// Setup errors: each names the field, actuator (1-based, as the dVRK counts) and value.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoConfigError {
    #[error("sawRobotIO1394 JSON: $version is {found}, only \"6\" is supported")]
    SawVersion { found: String },
    #[error("sawRobotIO1394 JSON: $id is {found:?}, expected \"saw-robot-io.schema.json\"")]
    SawId { found: String },
    #[error("sawRobotIO1394 JSON: no robot {wanted:?} (robots: {found:?})")]
    SawRobot { wanted: String, found: Vec<String> },
    #[error("sawRobotIO1394 JSON: robot {robot}: actuator {actuator}: {field} is required")]
    SawMissing {
        robot: String,
        actuator: usize,
        field: &'static str,
    },
    #[error("{field}: unknown hardware version {value:?} (QLA1, DQLA or dRA1)")]
    UnknownHardware { field: &'static str, value: String },
    #[error("firmware_version {value} not supported (7, 8 or 9)")]
    UnsupportedFirmware { value: u32 },
    #[error("{got} actuators, expected {expected}")]
    ActuatorCount { got: usize, expected: usize },
    #[error("actuator {actuator}: board_id {value} out of range 0..=15")]
    BoardId { actuator: usize, value: u8 },
    #[error("actuators use {count} boards, at most {max}")]
    TooManyBoards { count: usize, max: usize },
    #[error("actuator {actuator}: axis_id {value} out of range for {hardware} (0..{max})")]
    AxisId {
        actuator: usize,
        value: u8,
        hardware: &'static str,
        max: usize,
    },
    #[error("actuator {actuator}: board {board} axis {axis} already used by actuator {other}")]
    DuplicateAxis {
        actuator: usize,
        board: u8,
        axis: u8,
        other: usize,
    },
    #[error("actuator {actuator}: {field} = {value} must be finite and nonzero")]
    BadScale {
        actuator: usize,
        field: &'static str,
        value: f64,
    },
    #[error("actuator {actuator}: {field} = {value} must be finite")]
    NotFinite {
        actuator: usize,
        field: &'static str,
        value: f64,
    },
    #[error("actuator {actuator}: drive.maximum_current = {value} A must be positive")]
    MaximumCurrent { actuator: usize, value: f64 },
    #[error("actuator {actuator}: {field} = {value} must be finite, positive and at most {max}")]
    PotTolerance {
        actuator: usize,
        field: &'static str,
        value: f64,
        max: f64,
    },
    #[error("coupling.actuator_to_joint_position[{row}][{col}] = {value} is not finite")]
    CouplingNotFinite { row: usize, col: usize, value: f64 },
    #[error("coupling.actuator_to_joint_position is singular (determinant {determinant:e})")]
    SingularCoupling { determinant: f64 },
}

/// A validated actuator: where its bits are and how to convert them. Public so that a board
/// emulator can invert the conversion (SI to raw bits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Actuator {
    pub board_id: u8,
    /// Index of `board_id` in [`IoConfig::board_ids`].
    pub board_slot: u8,
    /// Axis on the board, 0-based (channel = axis + 1 in the register map, reference §1.2).
    pub axis: u8,
    pub joint_type: JointType,
    pub bits_to_position: Conversion,
    pub velocity_source: VelocitySource,
    pub bits_to_current: Conversion,
    pub effort_to_current: Conversion,
    pub maximum_current_amps: f64,
    pub potentiometer: Option<PotentiometerParams>,
    /// 1 / `effort_to_current.scale`, precomputed (N·m or N per A).
    pub effort_per_amp: f64,
}

impl Actuator {
    #[inline(always)]
    pub fn counts_to_position(&self, counts: i32) -> f64 {
        self.bits_to_position.apply(f64::from(counts))
    }
    /// Nearest counts for a position (saturating to the 24-bit counter range).
    pub fn position_to_counts(&self, position: f64) -> i32 {
        let c = self.bits_to_position.invert(position).round();
        c.clamp(-8_388_608.0, 8_388_607.0) as i32
    }
    #[inline(always)]
    pub fn current_bits_to_amps(&self, bits: u16) -> f64 {
        self.bits_to_current.apply(f64::from(bits))
    }
    /// Nearest ADC current bits for a current (saturating to 16 bits).
    pub fn amps_to_current_bits(&self, amps: f64) -> u16 {
        self.bits_to_current
            .invert(amps)
            .round()
            .clamp(0.0, 65535.0) as u16
    }
    #[inline(always)]
    pub fn amps_to_effort(&self, amps: f64) -> f64 {
        (amps - self.effort_to_current.offset) * self.effort_per_amp
    }
    pub fn effort_to_amps(&self, effort: f64) -> f64 {
        self.effort_to_current.apply(effort)
    }
    #[inline(always)]
    pub fn current_bits_to_effort(&self, bits: u16) -> f64 {
        self.amps_to_effort(self.current_bits_to_amps(bits))
    }
    pub fn effort_to_current_bits(&self, effort: f64) -> u16 {
        self.amps_to_current_bits(self.effort_to_amps(effort))
    }
    /// Pot position (rad or m, actuator space); None without a potentiometer section.
    pub fn pot_bits_to_position(&self, bits: u16) -> Option<f64> {
        self.potentiometer.map(|p| {
            p.voltage_to_position
                .apply(p.bits_to_voltage.apply(f64::from(bits)))
        })
    }
    /// Nearest pot bits for a position (saturating to 16 bits).
    pub fn position_to_pot_bits(&self, position: f64) -> Option<u16> {
        self.potentiometer.map(|p| {
            p.bits_to_voltage
                .invert(p.voltage_to_position.invert(position))
                .round()
                .clamp(0.0, 65535.0) as u16
        })
    }
    /// Host current-check limit (reference §7): 1.2·Imax + 50 mA with the amplifier enabled.
    pub fn current_limit_amps(&self) -> f64 {
        1.2 * self.maximum_current_amps + 0.05
    }
}

/// Validated conversion config for one arm.
#[derive(Clone, Debug, PartialEq)]
pub struct IoConfig {
    name: String,
    kind: BoardKind,
    firmware: Option<u32>,
    boards: [u8; MAX_BOARDS],
    num_boards: usize,
    actuators: [Actuator; NUM_JOINTS],
    instrument: Option<String>,
    coupling: [[f64; 4]; 4],
    /// C^-1, for joint → actuator position (emulator) and C^-T for efforts.
    coupling_inv: [[f64; 4]; 4],
}

fn check_scale(actuator: usize, field: &'static str, c: &Conversion) -> Result<(), IoConfigError> {
    if !c.scale.is_finite() || c.scale == 0.0 {
        return Err(IoConfigError::BadScale {
            actuator,
            field,
            value: c.scale,
        });
    }
    if !c.offset.is_finite() {
        return Err(IoConfigError::NotFinite {
            actuator,
            field,
            value: c.offset,
        });
    }
    Ok(())
}

fn check_pot_tolerance(
    actuator: usize,
    joint_type: JointType,
    t: &PotTolerance,
) -> Result<(), IoConfigError> {
    let max_distance = match joint_type {
        JointType::Revolute => MAX_POT_DISTANCE_RAD,
        JointType::Prismatic => MAX_POT_DISTANCE_M,
    };
    let fields = [
        ("potentiometer.tolerance.distance", t.distance, max_distance),
        (
            "potentiometer.tolerance.latency",
            t.latency,
            MAX_POT_LATENCY_S,
        ),
    ];
    for (field, value, max) in fields {
        if !(value.is_finite() && value > 0.0 && value <= max) {
            return Err(IoConfigError::PotTolerance {
                actuator,
                field,
                value,
                max,
            });
        }
    }
    Ok(())
}

const IDENTITY4: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Inverse of a 4×4 matrix by Gauss-Jordan with partial pivoting; Err(det) when singular.
fn invert4(m: &[[f64; 4]; 4]) -> Result<[[f64; 4]; 4], f64> {
    let mut a = *m;
    let mut inv = IDENTITY4;
    let mut det = 1.0;
    let norm = m.iter().flatten().fold(0.0f64, |acc, v| acc.max(v.abs()));
    for col in 0..4 {
        let mut piv = col;
        for r in col + 1..4 {
            if a[r][col].abs() > a[piv][col].abs() {
                piv = r;
            }
        }
        if a[piv][col].abs() <= 1e-12 * norm.max(f64::MIN_POSITIVE) {
            return Err(0.0);
        }
        if piv != col {
            a.swap(piv, col);
            inv.swap(piv, col);
            det = -det;
        }
        let p = a[col][col];
        det *= p;
        for k in 0..4 {
            a[col][k] /= p;
            inv[col][k] /= p;
        }
        for r in 0..4 {
            if r != col {
                let f = a[r][col];
                for k in 0..4 {
                    a[r][k] -= f * a[col][k];
                    inv[r][k] -= f * inv[col][k];
                }
            }
        }
    }
    if det.abs() < 1e-12 {
        return Err(det);
    }
    Ok(inv)
}

impl IoConfig {
    /// Validates parsed params (the TOML schema of config/io/, deserialised by the application:
    /// this crate reads no text formats itself, ARCHITECTURE.md).
    pub fn from_params(p: IoParams) -> Result<Self, IoConfigError> {
        let kind = BoardKind::from_name(&p.hardware_version).ok_or_else(|| {
            IoConfigError::UnknownHardware {
                field: "hardware_version",
                value: p.hardware_version.clone(),
            }
        })?;
        if let Some(fw) = p.firmware_version
            && BlockLayout::new(fw, kind).is_err()
        {
            return Err(IoConfigError::UnsupportedFirmware { value: fw });
        }
        if p.actuators.len() != NUM_JOINTS {
            return Err(IoConfigError::ActuatorCount {
                got: p.actuators.len(),
                expected: NUM_JOINTS,
            });
        }
        let mut boards = [0u8; MAX_BOARDS];
        let mut num_boards = 0usize;
        let max_axis = kind.num_motors().min(kind.num_encoders());
        let mut out: Vec<Actuator> = Vec::with_capacity(NUM_JOINTS);
        for (i, a) in p.actuators.iter().enumerate() {
            let n = i + 1;
            if a.board_id > 15 {
                return Err(IoConfigError::BoardId {
                    actuator: n,
                    value: a.board_id,
                });
            }
            if usize::from(a.axis_id) >= max_axis {
                return Err(IoConfigError::AxisId {
                    actuator: n,
                    value: a.axis_id,
                    hardware: kind.name(),
                    max: max_axis,
                });
            }
            let slot = match boards[..num_boards].iter().position(|&b| b == a.board_id) {
                Some(s) => s,
                None => {
                    if num_boards == MAX_BOARDS {
                        let mut all: Vec<u8> = p.actuators.iter().map(|a| a.board_id).collect();
                        all.sort_unstable();
                        all.dedup();
                        return Err(IoConfigError::TooManyBoards {
                            count: all.len(),
                            max: MAX_BOARDS,
                        });
                    }
                    boards[num_boards] = a.board_id;
                    num_boards += 1;
                    num_boards - 1
                }
            };
            if let Some(other) = out
                .iter()
                .position(|o| o.board_id == a.board_id && o.axis == a.axis_id)
            {
                return Err(IoConfigError::DuplicateAxis {
                    actuator: n,
                    board: a.board_id,
                    axis: a.axis_id,
                    other: other + 1,
                });
            }
            check_scale(n, "encoder.bits_to_position", &a.encoder.bits_to_position)?;
            check_scale(n, "drive.bits_to_current", &a.drive.bits_to_current)?;
            check_scale(n, "drive.effort_to_current", &a.drive.effort_to_current)?;
            let imax = a.drive.maximum_current;
            if !(imax.is_finite() && imax > 0.0) {
                return Err(IoConfigError::MaximumCurrent {
                    actuator: n,
                    value: imax,
                });
            }
            if let Some(pot) = &a.potentiometer {
                check_scale(n, "potentiometer.bits_to_voltage", &pot.bits_to_voltage)?;
                check_scale(
                    n,
                    "potentiometer.voltage_to_position",
                    &pot.voltage_to_position,
                )?;
                if let Some(t) = &pot.tolerance {
                    check_pot_tolerance(n, a.joint_type, t)?;
                }
            }
            out.push(Actuator {
                board_id: a.board_id,
                board_slot: slot as u8,
                axis: a.axis_id,
                joint_type: a.joint_type,
                bits_to_position: a.encoder.bits_to_position,
                velocity_source: a.encoder.velocity_source,
                bits_to_current: a.drive.bits_to_current,
                effort_to_current: a.drive.effort_to_current,
                maximum_current_amps: imax,
                potentiometer: a.potentiometer,
                effort_per_amp: 1.0 / a.drive.effort_to_current.scale,
            });
        }
        let actuators: [Actuator; NUM_JOINTS] = match out.try_into() {
            Ok(a) => a,
            Err(v) => {
                return Err(IoConfigError::ActuatorCount {
                    got: v.len(),
                    expected: NUM_JOINTS,
                });
            }
        };
        let mut cfg = Self {
            name: p.name,
            kind,
            firmware: p.firmware_version,
            boards,
            num_boards,
            actuators,
            instrument: None,
            coupling: IDENTITY4,
            coupling_inv: IDENTITY4,
        };
        if let Some(c) = p.coupling {
            cfg.set_coupling(c.actuator_to_joint_position)?;
            cfg.instrument = c.instrument;
        }
        Ok(cfg)
    }

    /// Back to the TOML schema (e.g. to write an imported sawRobotIO1394 file as TOML).
    pub fn to_params(&self) -> IoParams {
        IoParams {
            name: self.name.clone(),
            hardware_version: self.kind.name().to_string(),
            firmware_version: self.firmware,
            actuators: self
                .actuators
                .iter()
                .map(|a| ActuatorParams {
                    board_id: a.board_id,
                    axis_id: a.axis,
                    joint_type: a.joint_type,
                    encoder: EncoderParams {
                        bits_to_position: a.bits_to_position,
                        velocity_source: a.velocity_source,
                    },
                    drive: DriveParams {
                        bits_to_current: a.bits_to_current,
                        effort_to_current: a.effort_to_current,
                        maximum_current: a.maximum_current_amps,
                    },
                    potentiometer: a.potentiometer,
                })
                .collect(),
            coupling: if self.coupling == IDENTITY4 && self.instrument.is_none() {
                None
            } else {
                Some(CouplingParams {
                    instrument: self.instrument.clone(),
                    actuator_to_joint_position: self.coupling,
                })
            },
        }
    }

    /// Sets the instrument's 4×4 actuator-to-joint position matrix for joints 4–7 (rows =
    /// joints, columns = actuators; reference §5.3) and precomputes its inverse.
    pub fn set_coupling(
        &mut self,
        actuator_to_joint_position: [[f64; 4]; 4],
    ) -> Result<(), IoConfigError> {
        for (row, r) in actuator_to_joint_position.iter().enumerate() {
            for (col, v) in r.iter().enumerate() {
                if !v.is_finite() {
                    return Err(IoConfigError::CouplingNotFinite {
                        row,
                        col,
                        value: *v,
                    });
                }
            }
        }
        let inv = invert4(&actuator_to_joint_position)
            .map_err(|determinant| IoConfigError::SingularCoupling { determinant })?;
        self.coupling = actuator_to_joint_position;
        self.coupling_inv = inv;
        Ok(())
    }

    /// Same as [`IoConfig::set_coupling`], recording the instrument's name.
    pub fn set_instrument_coupling(
        &mut self,
        instrument: &str,
        actuator_to_joint_position: [[f64; 4]; 4],
    ) -> Result<(), IoConfigError> {
        self.set_coupling(actuator_to_joint_position)?;
        self.instrument = Some(instrument.to_string());
        Ok(())
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn board_kind(&self) -> BoardKind {
        self.kind
    }
    /// Firmware the config expects, if it says.
    pub fn firmware_version(&self) -> Option<u32> {
        self.firmware
    }
    /// Board ids in slot order (order of first use by the actuators).
    pub fn board_ids(&self) -> &[u8] {
        self.boards.get(..self.num_boards).unwrap_or(&[])
    }
    /// Slot of a board id in [`IoConfig::board_ids`].
    pub fn board_slot(&self, board_id: u8) -> Option<usize> {
        self.board_ids().iter().position(|&b| b == board_id)
    }
    /// Query-register mask of the arm's boards (bit = board id).
    pub fn board_mask(&self) -> u16 {
        self.board_ids().iter().fold(0, |m, &b| m | (1 << b))
    }
    pub fn actuators(&self) -> &[Actuator; NUM_JOINTS] {
        &self.actuators
    }
    /// Whether any actuator has a pot calibration (its pots are decoded and checked).
    pub fn has_potentiometers(&self) -> bool {
        self.actuators.iter().any(|a| a.potentiometer.is_some())
    }
    pub fn instrument(&self) -> Option<&str> {
        self.instrument.as_deref()
    }
    /// The 4×4 actuator-to-joint position matrix of joints 4–7.
    pub fn coupling(&self) -> [[f64; 4]; 4] {
        self.coupling
    }
    /// Its inverse (joint-to-actuator position).
    pub fn coupling_inverse(&self) -> [[f64; 4]; 4] {
        self.coupling_inv
    }

    /// q = C · a (identity for joints 1–3).
    #[inline]
    pub fn actuator_to_joint_position(&self, a: &[f64; NUM_JOINTS]) -> [f64; NUM_JOINTS] {
        mul_coupled(&self.coupling, a, false)
    }
    /// a = C^-1 · q.
    pub fn joint_to_actuator_position(&self, q: &[f64; NUM_JOINTS]) -> [f64; NUM_JOINTS] {
        mul_coupled(&self.coupling_inv, q, false)
    }
    /// τ_joint = C^-T · τ_actuator (power equivalence, reference §5.3).
    #[inline]
    pub fn actuator_to_joint_effort(&self, e: &[f64; NUM_JOINTS]) -> [f64; NUM_JOINTS] {
        mul_coupled(&self.coupling_inv, e, true)
    }
    /// τ_actuator = C^T · τ_joint.
    pub fn joint_to_actuator_effort(&self, tau: &[f64; NUM_JOINTS]) -> [f64; NUM_JOINTS] {
        mul_coupled(&self.coupling, tau, true)
    }
}

/// Applies `m` (or its transpose) to elements 3..7, passing 0..3 through.
#[inline(always)]
fn mul_coupled(m: &[[f64; 4]; 4], x: &[f64; NUM_JOINTS], transpose: bool) -> [f64; NUM_JOINTS] {
    let mut y = *x;
    for r in 0..4 {
        let mut s = 0.0;
        for c in 0..4 {
            let mrc = if transpose { m[c][r] } else { m[r][c] };
            s += mrc * x[3 + c];
        }
        y[3 + r] = s;
    }
    y
}

#[cfg(test)]
mod tests;
