//! Instrument catalog: every instrument of the dVRK's tool index, with the kinematics and the
//! actuator-to-joint coupling of its tool file.
//!
//! Source: jhu-dvrk/sawIntuitiveResearchKit, `share/tool/index.json` and the 54 tool files it
//! names (`share/tool/<FILE>.json`), read at commit 9e535e68 (2026-04-17; `share/tool/` last
//! changed in 9658365). The numbers below are transcribed from those files (facts, not code):
//! the DH rows of the tool joints (`DH.joints`), `tooltip_offset`, `snake-like` and
//! `coupling.ActuatorToJointPosition`; the names, model, version range, generation and
//! description come from the index.
//!
//! # Names
//! An entry's [`Instrument::name`] is its tool file's stem (`LARGE_NEEDLE_DRIVER_400006`,
//! `LARGE_NEEDLE_DRIVER_420006_GEARED`), the project's historical spelling. The console writes
//! `NAME:MODEL[min..max]` (`/PSM1/tool_type`, `"tool"` of a FIXED arm configuration); both are
//! accepted by [`instrument_from_tool_type`], which resolves them as the console's tool list
//! does (`core/components/code/mtsToolList.cpp`, `Find`): any of the index's `names` with the
//! model, or `:MODEL` alone; the bracket is needed only when a model has several entries
//! (the "geared" S instruments), and then its version selects the entry: `[v]` and `[v..]` and
//! `[v..M]` use `v`, `[..M]` uses `M`, `[..]` gives none.
//!
//! # What the chain models
//! The tool joints follow the arm's three links (`kinematic/PSM.json`, `PSM_Si.json`; see
//! [`crate::kinematics`]). Every tool file has one of two shapes, checked entry by entry when
//! this table was written:
//! - 3 links (all 8 mm EndoWrists and the stapler): roll (`alpha = 0, A = 0, theta =
//!   roll_theta_rad, D = roll_d_m`), wrist pitch (`alpha = -1.5708, offset = -1.5708`), wrist
//!   yaw (`alpha = -1.5708, A = yaw_a_m, offset = -1.5708`): [`Wrist::Standard`].
//! - 5 links, `"snake-like": true` (the 5 mm tools 400117, 400143, 420117): roll, then four
//!   wrist links: [`Wrist::Snake`]. The console's kinematic chain then has 8 joints, but the
//!   actuators drive only 3 + 1 (`coupling` is 4x4 over roll, wrist pitch, wrist yaw and jaw, as
//!   the file's comment says): the PSM component sets pitch1 = pitch2 = q5 / 2 and yaw1 = yaw2 =
//!   q6 / 2 (`mtsIntuitiveResearchKitPSM.cpp`, `UpdateStateJointKinematics`). The project's
//!   6 joints are those q5, q6, so [`crate::PsmKinematics`] reproduces the console's tip pose.
//!
//! Only the stapler (`STAPLER_45_410298`) has a non-zero roll `theta` (0.7854).

use std::f64::consts::FRAC_1_SQRT_2;
use std::fmt;

/// The instrument generation, as the dVRK's tool index spells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Generation {
    /// Classic (standard) da Vinci instruments, model numbers 400xxx.
    Classic,
    /// S and Si instruments, model numbers 41xxxx and 42xxxx (longer shaft).
    S,
}

/// The wrist's modified-DH links after the roll joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Wrist {
    /// Two links: wrist pitch (`alpha = -pi/2, offset = -1.5708`) then wrist yaw
    /// (`alpha = -pi/2, A = yaw_a_m, offset = -1.5708`).
    Standard {
        /// `A` of the wrist-yaw link (m): pitch axis to yaw axis.
        yaw_a_m: f64,
    },
    /// 5 mm snake-like wrist (`"snake-like": true`): four links pitch1 (`alpha = -pi/2,
    /// offset = -1.5708`), yaw1 (`alpha = -pi/2, A = link_a_m`), yaw2 (`alpha = 0, A = link_a_m`),
    /// pitch2 (`alpha = +pi/2, A = link_a_m, offset = +1.5708`). As in the dVRK PSM component,
    /// wrist pitch q5 is split equally over pitch1 and pitch2 and wrist yaw q6 over yaw1 and yaw2.
    Snake {
        /// `A` of each of the last three wrist links (m).
        link_a_m: f64,
    },
}

/// An inclusive range of instrument versions (the Dallas chip's version), as the tool index's
/// `version_min` / `version_max`; `None` is unbounded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VersionRange {
    /// Lowest version, inclusive.
    pub min: Option<u32>,
    /// Highest version, inclusive.
    pub max: Option<u32>,
}

/// Every version (`[..]`).
pub const ANY_VERSION: VersionRange = VersionRange {
    min: None,
    max: None,
};

impl VersionRange {
    /// Whether `version` lies in the range.
    pub fn contains(&self, version: u32) -> bool {
        self.min.is_none_or(|m| version >= m) && self.max.is_none_or(|m| version <= m)
    }
}

/// `[min..max]` as the console writes it, with an absent bound left empty (`[..11]`, `[12..]`,
/// `[..]`).
impl fmt::Display for VersionRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("[")?;
        if let Some(m) = self.min {
            write!(f, "{m}")?;
        }
        f.write_str("..")?;
        if let Some(m) = self.max {
            write!(f, "{m}")?;
        }
        f.write_str("]")
    }
}

/// One entry of the dVRK's tool index with its tool file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instrument {
    /// The tool file's stem, e.g. `LARGE_NEEDLE_DRIVER_400006` (`.json` in `share/tool/`).
    pub name: &'static str,
    /// The index's `names`: the console accepts any of them before `:MODEL` and writes the first.
    pub names: &'static [&'static str],
    /// Intuitive Surgical model number.
    pub model: u32,
    /// The versions this entry covers (`version_min`, `version_max` of the index).
    pub versions: VersionRange,
    /// Classic or S/Si.
    pub generation: Generation,
    /// The index's `description`, e.g. `Large Needle Driver (Geared)`.
    pub description: &'static str,
    /// Shaft diameter (mm): 8 for the EndoWrists, 5 for the snake-like tools, 12 for the
    /// stapler (Intuitive's stapler cannula; the dVRK files do not give diameters).
    pub shaft_diameter_mm: u8,
    /// `theta` of the roll link (rad), added to q4: 0 except for the stapler (0.7854).
    pub roll_theta_rad: f64,
    /// `D` of the roll link (m): RCM-side shaft length used by the chain.
    pub roll_d_m: f64,
    /// The wrist links.
    pub wrist: Wrist,
    /// Constant transform after the last link, row-major 4x4 (`tooltip_offset`). For the snake
    /// tools the file's 0.7071 entries are stored as exact 1/sqrt(2) so the rotation is proper.
    pub tooltip_offset: [[f64; 4]; 4],
    /// `coupling.ActuatorToJointPosition`: actuators 4-7 to roll, wrist pitch, wrist yaw and jaw
    /// (rows are joints). Every entry of the index has one; `None` marks an instrument that
    /// cannot be used, and [`Instrument::check`] refuses it.
    pub actuator_to_joint_position: Option<[[f64; 4]; 4]>,
}

/// Why an instrument name cannot be resolved or the instrument cannot be used. `Copy`, no
/// allocation: the service may meet it at run time when the console reports a new instrument.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum InstrumentError {
    /// The empty string: the console publishes it when the instrument is removed.
    #[error("no instrument (empty tool type: the console reports the instrument removed)")]
    Empty,
    /// `ERROR`: the console could not identify the instrument or configure it.
    #[error("the console reports ERROR (instrument unsupported or its chip could not be read)")]
    ConsoleError,
    /// Neither a tool file name of the catalog nor `NAME:MODEL[..]`.
    #[error(
        "neither a dVRK tool file name (e.g. LARGE_NEEDLE_DRIVER_400006) nor the console's \
         NAME:MODEL[min..max] (e.g. LARGE_NEEDLE_DRIVER:400006[..])"
    )]
    UnknownName,
    /// `NAME:MODEL[..]` written wrongly.
    #[error("malformed NAME:MODEL[min..max]: {what}")]
    Syntax {
        /// What is wrong.
        what: &'static str,
    },
    /// No index entry has this model with this name.
    #[error("the dVRK tool index has no instrument {model} by that name")]
    NotInIndex {
        /// The model number asked for.
        model: u32,
    },
    /// The model has several entries and no version was given (the console refuses it too).
    #[error(
        "model {model} has {entries} entries in the dVRK tool index (by instrument version); \
         give the version, e.g. NAME:{model}[12]"
    )]
    VersionNeeded {
        /// The model number.
        model: u32,
        /// How many entries it has.
        entries: u8,
    },
    /// The model has several entries and none covers the version.
    #[error("model {model} has no entry for version {version} in the dVRK tool index")]
    NoSuchVersion {
        /// The model number.
        model: u32,
        /// The version asked for.
        version: u32,
    },
    /// The instrument is known but the project cannot model it.
    #[error("instrument {name} cannot be used: {why}")]
    NotModelled {
        /// The instrument's tool file name.
        name: &'static str,
        /// Why.
        why: &'static str,
    },
}

impl Instrument {
    /// `Ok(self)` if the project can use this instrument: its coupling is given, finite and
    /// invertible, and its kinematic constants are finite. The catalog's entries all pass.
    pub fn check(&self) -> Result<&Self, InstrumentError> {
        let not = |why| InstrumentError::NotModelled {
            name: self.name,
            why,
        };
        let Some(c) = &self.actuator_to_joint_position else {
            return Err(not("its tool file gives no actuator-to-joint coupling"));
        };
        if !c.iter().flatten().all(|x| x.is_finite()) {
            return Err(not("its actuator-to-joint coupling is not finite"));
        }
        if det4(c).abs() < 1e-9 {
            return Err(not("its actuator-to-joint coupling is singular"));
        }
        let lengths = match self.wrist {
            Wrist::Standard { yaw_a_m } => yaw_a_m,
            Wrist::Snake { link_a_m } => link_a_m,
        };
        let constants = [self.roll_theta_rad, self.roll_d_m, lengths];
        if !(constants.iter().chain(self.tooltip_offset.iter().flatten())).all(|x| x.is_finite()) {
            return Err(not("its kinematic constants are not finite"));
        }
        Ok(self)
    }

    /// The coupling, or why the instrument cannot be used.
    pub fn coupling(&self) -> Result<&[[f64; 4]; 4], InstrumentError> {
        match &self.check()?.actuator_to_joint_position {
            Some(c) => Ok(c),
            None => Err(InstrumentError::NotModelled {
                name: self.name,
                why: "its tool file gives no actuator-to-joint coupling",
            }),
        }
    }

    /// Whether the tool file describes a snake-like wrist.
    pub fn is_snake_like(&self) -> bool {
        matches!(self.wrist, Wrist::Snake { .. })
    }

    /// The name the console writes for this entry (`mtsToolList::Name`): the first of `names`,
    /// the model and the version range, e.g. `LARGE_NEEDLE_DRIVER:420006[12..]`.
    pub fn tool_type(&self) -> ToolTypeName<'_> {
        ToolTypeName(self)
    }
}

/// Displays an instrument as the console names it; see [`Instrument::tool_type`].
#[derive(Clone, Copy, Debug)]
pub struct ToolTypeName<'a>(&'a Instrument);

impl fmt::Display for ToolTypeName<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let i = self.0;
        let name = i.names.first().copied().unwrap_or("");
        write!(f, "{name}:{}{}", i.model, i.versions)
    }
}

/// Determinant of a 4x4 matrix (Laplace expansion along the first row).
fn det4(m: &[[f64; 4]; 4]) -> f64 {
    let minor = |c: usize| {
        let cols: [usize; 3] = match c {
            0 => [1, 2, 3],
            1 => [0, 2, 3],
            2 => [0, 1, 3],
            _ => [0, 1, 2],
        };
        let r = |row: usize, k: usize| m[row][cols[k]];
        r(1, 0) * (r(2, 1) * r(3, 2) - r(2, 2) * r(3, 1))
            - r(1, 1) * (r(2, 0) * r(3, 2) - r(2, 2) * r(3, 0))
            + r(1, 2) * (r(2, 0) * r(3, 1) - r(2, 1) * r(3, 0))
    };
    m[0][0] * minor(0) - m[0][1] * minor(1) + m[0][2] * minor(2) - m[0][3] * minor(3)
}

/// A tool type as the console writes it, `NAME:MODEL`, `NAME:MODEL[..]`, `NAME:MODEL[v]` or
/// `NAME:MODEL[min..max]` (either bound may be empty), or `:MODEL[..]` without a name. Borrows
/// the input; parsing allocates nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ToolType<'a> {
    /// The part before the colon; `None` for `:MODEL`.
    pub name: Option<&'a str>,
    /// The model number.
    pub model: u32,
    /// The bracket, if any: `[v]` is `v..=v`, `[..]` is [`ANY_VERSION`].
    pub versions: Option<VersionRange>,
}

impl<'a> ToolType<'a> {
    /// Parses `NAME:MODEL[min..max]`; the bracket is optional.
    pub fn parse(s: &'a str) -> Result<Self, InstrumentError> {
        let syntax = |what| InstrumentError::Syntax { what };
        let (name_model, versions) = match s.split_once('[') {
            None => (s, None),
            Some((before, rest)) => {
                let Some(inside) = rest.strip_suffix(']') else {
                    return Err(syntax("the version bracket does not end the name with `]`"));
                };
                let range = match inside.split_once("..") {
                    None => {
                        let v = parse_number(inside)
                            .ok_or(syntax("the version in [..] is not a number"))?;
                        VersionRange {
                            min: Some(v),
                            max: Some(v),
                        }
                    }
                    Some((lo, hi)) => {
                        let bound = |t: &str| match t {
                            "" => Ok(None),
                            t => parse_number(t)
                                .map(Some)
                                .ok_or(syntax("a version bound in [min..max] is not a number")),
                        };
                        VersionRange {
                            min: bound(lo)?,
                            max: bound(hi)?,
                        }
                    }
                };
                if let (Some(lo), Some(hi)) = (range.min, range.max)
                    && lo > hi
                {
                    return Err(syntax("the version range [min..max] has min > max"));
                }
                (before, Some(range))
            }
        };
        let Some((name, model)) = name_model.split_once(':') else {
            return Err(syntax("no `:` between NAME and MODEL"));
        };
        let model = parse_number(model).ok_or(syntax("MODEL is not a number"))?;
        let name = match name {
            "" => None,
            n if n.bytes().all(|b| {
                b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_' || b == b'-'
            }) =>
            {
                Some(n)
            }
            _ => {
                return Err(syntax(
                    "NAME has characters other than A-Z, 0-9, `_` and `-`",
                ));
            }
        };
        Ok(ToolType {
            name,
            model,
            versions,
        })
    }

    /// The version the console selects an entry with (`mtsToolList::Find`): the lower bound if
    /// given, else the upper bound; `None` for no bracket or `[..]`.
    pub fn version(&self) -> Option<u32> {
        self.versions.and_then(|r| r.min.or(r.max))
    }

    fn matches(&self, i: &Instrument) -> bool {
        i.model == self.model && self.name.is_none_or(|n| i.names.contains(&n))
    }

    /// The catalog entry this tool type names, chosen as the console does.
    pub fn resolve(&self) -> Result<&'static Instrument, InstrumentError> {
        let mut candidates = CATALOG.iter().filter(|i| self.matches(i));
        let Some(first) = candidates.next() else {
            return Err(InstrumentError::NotInIndex { model: self.model });
        };
        let entries = 1 + candidates.count();
        if entries == 1 {
            return Ok(first);
        }
        let Some(version) = self.version() else {
            return Err(InstrumentError::VersionNeeded {
                model: self.model,
                entries: u8::try_from(entries).unwrap_or(u8::MAX),
            });
        };
        CATALOG
            .iter()
            .find(|i| self.matches(i) && i.versions.contains(version))
            .ok_or(InstrumentError::NoSuchVersion {
                model: self.model,
                version,
            })
    }
}

/// ASCII digits only (no sign, no spaces), as a `u32`.
fn parse_number(s: &str) -> Option<u32> {
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

/// The catalog entry for `s`, checked: a tool file name (`LARGE_NEEDLE_DRIVER_400006`,
/// `LARGE_NEEDLE_DRIVER_420006_GEARED`) or the console's tool type (`LARGE_NEEDLE_DRIVER:400006`,
/// `LARGE_NEEDLE_DRIVER:420006[12..]`, `:420006[7]`). Case-sensitive, as the console.
///
/// This is the run-time switch: when `/PSM1/tool_type` changes, the returned entry carries the
/// tool's kinematics ([`crate::PsmKinematics::new`]) and its coupling
/// ([`Instrument::coupling`]) together. It scans the 54 entries and allocates nothing.
pub fn instrument_from_tool_type(s: &str) -> Result<&'static Instrument, InstrumentError> {
    let found = match s {
        "" => return Err(InstrumentError::Empty),
        "ERROR" => return Err(InstrumentError::ConsoleError),
        s if s.contains(':') || s.contains('[') => ToolType::parse(s)?.resolve()?,
        s => CATALOG
            .iter()
            .find(|i| i.name == s)
            .ok_or(InstrumentError::UnknownName)?,
    };
    found.check()
}

/// Every instrument in the catalog, in the index's order.
pub fn instruments() -> &'static [Instrument] {
    &CATALOG
}

/// [`instrument_from_tool_type`] without the reason: `None` for an unknown name and for an
/// instrument the project cannot use.
pub fn instrument(name: &str) -> Option<&'static Instrument> {
    instrument_from_tool_type(name).ok()
}

/// Rotation to the ISI tool-frame convention of the 8 mm tools (reference 1.2).
const TOOLTIP_8MM: [[f64; 4]; 4] = [
    [0.0, -1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [-1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Tooltip of the 5 mm snake tools: a rotation and `y_m` along the last frame's y axis.
const fn tooltip_5mm(y_m: f64) -> [[f64; 4]; 4] {
    [
        [FRAC_1_SQRT_2, FRAC_1_SQRT_2, 0.0, 0.0],
        [0.0, 0.0, -1.0, y_m],
        [-FRAC_1_SQRT_2, FRAC_1_SQRT_2, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Tooltip of `STAPLER_45_410298`.
const TOOLTIP_STAPLER: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// `theta` of the stapler's roll link, written 0.7854 in `STAPLER_45_410298.json` (cisst adds
/// it to q4 as is, so it stays 0.7854 rather than pi/4).
#[expect(
    clippy::approx_constant,
    reason = "the tool file writes 0.7854 literally"
)]
const STAPLER_ROLL_THETA_RAD: f64 = 0.7854;

const fn standard(yaw_a_m: f64) -> Wrist {
    Wrist::Standard { yaw_a_m }
}

const fn snake(link_a_m: f64) -> Wrist {
    Wrist::Snake { link_a_m }
}

const fn up_to(max: u32) -> VersionRange {
    VersionRange {
        min: None,
        max: Some(max),
    }
}

const fn from(min: u32) -> VersionRange {
    VersionRange {
        min: Some(min),
        max: None,
    }
}

#[expect(
    clippy::too_many_arguments,
    reason = "one argument per column of the table"
)]
const fn tool(
    name: &'static str,
    model: u32,
    versions: VersionRange,
    generation: Generation,
    names: &'static [&'static str],
    description: &'static str,
    roll_d_m: f64,
    wrist: Wrist,
    tooltip_offset: [[f64; 4]; 4],
    coupling: [[f64; 4]; 4],
) -> Instrument {
    Instrument {
        name,
        names,
        model,
        versions,
        generation,
        description,
        shaft_diameter_mm: match wrist {
            Wrist::Snake { .. } => 5,
            Wrist::Standard { .. } => 8,
        },
        roll_theta_rad: 0.0,
        roll_d_m,
        wrist,
        tooltip_offset,
        actuator_to_joint_position: Some(coupling),
    }
}

// `coupling.ActuatorToJointPosition` of the tool files, one constant per distinct matrix, named
// after the first model using it. Rows: roll, wrist pitch, wrist yaw, jaw; columns: actuators
// 4-7. Numbers as written in the files (including LARGE_CLIP_APPLIER's 0.527898 / -0.52789).

/// Used by `POTTS_SCISSORS_400001`, `LARGE_NEEDLE_DRIVER_400006`, `ROUND_TIP_SCISSORS_400007`,
/// `MICRO_FORCEPS_400033`, `ROUND_TOOTH_FORCEPS_400035`, `DEBAKEY_FORCEPS_400036`,
/// `LONG_TIP_FORCEPS_400048`, `CADIERE_FORCEPS_400049`, `CURVED_SCISSORS_400178`,
/// `MONOPOLAR_CURVED_SCISSORS_400179`, `RESANO_FORCEPS_400181`,
/// `LRG_SUTURECUT_NEEDLE_DRIVER_400296`, `POTTS_SCISSORS_420001`, `LARGE_NEEDLE_DRIVER_420006`,
/// `ROUND_TIP_SCISSORS_420007`, `MICRO_FORCEPS_420033`, `DEBAKEY_FORCEPS_420036`,
/// `LONG_TIP_FORCEPS_420048`, `CADIERE_FORCEPS_420049`, `CURVED_SCISSORS_420178`,
/// `MONOPOLAR_CURVED_SCISSORS_420179`, `RESANO_FORCEPS_420181`,
/// `LARGE_SUTURECUT_NEEDLEDRIVER_420296`.
const C_400006: [[f64; 4]; 4] = [
    [-1.5632, 0.0, 0.0, 0.0],
    [0.0, 1.0186, 0.0, 0.0],
    [0.0, -0.8306, 0.6089, 0.6089],
    [0.0, 0.0, -1.2177, 1.2177],
];

/// Used by `SMALL_CLIP_APPLIER_400003`.
const C_400003: [[f64; 4]; 4] = [
    [-1.5632, 0.0, 0.0, 0.0],
    [0.0, 1.0186, 0.0, 0.0],
    [0.0, -0.8349, -0.5956, -0.5956],
    [0.0, 0.0, 1.1913, -1.1913],
];

/// Used by `PROGRASP_FORCEPS_400093`, `PROGRASP_FORCEPS_420093`.
const C_400093: [[f64; 4]; 4] = [
    [-1.5631, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.5068, -0.5135, -0.5135],
    [0.0, 0.0, -0.5279, 0.5279],
];

/// Used by `NEEDLE_DRIVER_400117`, `MARYLAND_DISSECTOR_400143`, `NEEDLE_DRIVER_420117`.
const C_400117: [[f64; 4]; 4] = [
    [-1.5, 0.0, 0.0, 0.0],
    [0.0, 0.0, -0.1929, -0.1929],
    [0.0, 0.0, -0.1929, 0.1929],
    [0.0, -1.258, 0.0, 0.0],
];

/// Used by `BOWEL_GRASPER_400127`, `DOUBLE_FENESTRATED_GRASPER_400189`,
/// `TENACULUM_FORCEPS_400207`, `THORACIC_GRASPER_400208`.
const C_400127: [[f64; 4]; 4] = [
    [-1.5575, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.5, 0.368243, 0.368243],
    [0.0, 0.0, -0.736486, 0.736486],
];

/// Used by `MARYLAND_BIPOLAR_FORCEPS_400172`, `FENESTRATED_BIPOLAR_FORCEPS_400205`,
/// `MARYLAND_BIPOLAR_FORCEPS_420172`, `FENESTRATED_BIPOLAR_FORCEPS_420205`.
const C_400172: [[f64; 4]; 4] = [
    [-1.563233, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.630273, 0.457982, 0.457982],
    [0.0, 0.0, -0.915964, 0.915964],
];

/// Used by `PERMANENT_CAUTERY_HOOK_400183`, `PERMANENT_CAUTERY_SPATULA_400184`,
/// `PERMANENT_CAUTERY_HOOK_420183`, `PERMANENT_CAUTERY_SPATULA_420184`.
const C_400183: [[f64; 4]; 4] = [
    [-1.5632, 0.0, 0.0, 0.0],
    [0.0, 1.1353, 0.0, 0.0],
    [0.0, 0.7827, -1.0582, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Used by `MEGA_NEEDLE_DRIVER_400194`, `MEGA_NEEDLE_DRIVER_420194`.
const C_400194: [[f64; 4]; 4] = [
    [-1.5575, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.456081, 0.368243, 0.368243],
    [0.0, 0.0, -0.736486, 0.736486],
];

/// Used by `LARGE_CLIP_APPLIER_400230`, `LARGE_CLIP_APPLIER_420230`, `MEDIUM-
/// LARGE_CLIP_APPLIER_420327`.
const C_400230: [[f64; 4]; 4] = [
    [-1.563131, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.506756, 0.513513, 0.513513],
    [0.0, 0.0, 0.527898, -0.52789],
];

/// Used by `MEGA_SUTURECUT_NEEDLE_DRIVER_400309`, `MEGA_SUTURECUT_NEEDLE_DRIVER_420309`.
const C_400309: [[f64; 4]; 4] = [
    [-1.5575, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.579399, 0.467811, 0.467811],
    [0.0, 0.0, -0.935622, 0.935622],
];

/// Used by `STAPLER_45_410298`.
const C_410298: [[f64; 4]; 4] = [
    [-1.529411, 0.0, 0.0, 0.0],
    [0.0, 0.0, 0.3, 0.0],
    [0.0, 0.0, 0.0, 0.3],
    [0.0, 0.157832, -0.035139, -0.035139],
];

/// Used by `LARGE_NEEDLE_DRIVER_420006_GEARED`.
const C_420006_GEARED: [[f64; 4]; 4] = [
    [1.5333, 0.0, 0.0, 0.0],
    [0.0, 1.0186, 0.0, 0.0],
    [0.0, -0.8306, 0.6089, 0.6089],
    [0.0, 0.0, -1.2177, 1.2177],
];

/// Used by `PROGRASP_FORCEPS_420093_GEARED`.
const C_420093_GEARED: [[f64; 4]; 4] = [
    [1.5333, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.5068, -0.5135, -0.5135],
    [0.0, 0.0, -0.5279, 0.5279],
];

/// Used by `PERMANENT_CAUTERY_HOOK_420183_GEARED`.
const C_420183_GEARED: [[f64; 4]; 4] = [
    [1.5333, 0.0, 0.0, 0.0],
    [0.0, 1.1353, 0.0, 0.0],
    [0.0, 0.7827, -1.0582, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Used by `MEGA_NEEDLE_DRIVER_420194_GEARED`.
const C_420194_GEARED: [[f64; 4]; 4] = [
    [1.5333, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.456081, 0.368243, 0.368243],
    [0.0, 0.0, -0.736486, 0.736486],
];

/// Used by `MEGA_SUTURECUT_NEEDLE_DRIVER_420309_GEARED`.
const C_420309_GEARED: [[f64; 4]; 4] = [
    [1.5333, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -0.579399, 0.467811, 0.467811],
    [0.0, 0.0, -0.935622, 0.935622],
];

use Generation::{Classic, S};

/// The dVRK's tool index, in its order (sorted by generation and model). Per entry: tool file,
/// model, versions, generation; the index's names and description; then the tool file's roll
/// `D` (m), wrist (`standard(A of wrist yaw)` or `snake(A of the wrist links)`, m), tooltip and
/// coupling.
#[rustfmt::skip]
static CATALOG: [Instrument; 54] = [
    tool("POTTS_SCISSORS_400001", 400001, ANY_VERSION, Classic,
         &["POTTS_SCISSORS"], "Potts Scissors",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("SMALL_CLIP_APPLIER_400003", 400003, ANY_VERSION, Classic,
         &["SMALL_CLIP_APPLIER"], "Small Clip Applier",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400003),
    tool("LARGE_NEEDLE_DRIVER_400006", 400006, ANY_VERSION, Classic,
         &["LARGE_NEEDLE_DRIVER"], "Large Needle Driver",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("ROUND_TIP_SCISSORS_400007", 400007, ANY_VERSION, Classic,
         &["ROUND_TIP_SCISSORS"], "Round Tip Scissors",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MICRO_FORCEPS_400033", 400033, ANY_VERSION, Classic,
         &["MICRO_FORCEPS", "BLACK_DIAMOND_MICRO_FORCEPS"], "Black Diamond Micro Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("ROUND_TOOTH_FORCEPS_400035", 400035, ANY_VERSION, Classic,
         &["ROUND_TOOTH_FORCEPS"], "Round Tooth Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("DEBAKEY_FORCEPS_400036", 400036, ANY_VERSION, Classic,
         &["DEBAKEY_FORCEPS"], "DeBakey Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("LONG_TIP_FORCEPS_400048", 400048, ANY_VERSION, Classic,
         &["LONG_TIP_FORCEPS"], "Long Tip Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("CADIERE_FORCEPS_400049", 400049, ANY_VERSION, Classic,
         &["CADIERE_FORCEPS"], "Cadiere Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("PROGRASP_FORCEPS_400093", 400093, ANY_VERSION, Classic,
         &["PROGRASP_FORCEPS"], "Prograsp Forceps",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400093),
    tool("NEEDLE_DRIVER_400117", 400117, ANY_VERSION, Classic,
         &["NEEDLE_DRIVER", "5MM_NEEDLE_DRIVER"], "5mm Needle Driver",
         0.4024, snake(0.0034), tooltip_5mm(-0.0171), C_400117),
    tool("BOWEL_GRASPER_400127", 400127, ANY_VERSION, Classic,
         &["BOWEL_GRASPER"], "Bowel Grasper",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400127),
    tool("MARYLAND_DISSECTOR_400143", 400143, ANY_VERSION, Classic,
         &["MARYLAND_DISSECTOR", "5MM_MARYLAND_DISSECTOR"], "5mm Maryland Dissector",
         0.4024, snake(0.0034), tooltip_5mm(-0.0269), C_400117),
    tool("MARYLAND_BIPOLAR_FORCEPS_400172", 400172, ANY_VERSION, Classic,
         &["MARYLAND_BIPOLAR_FORCEPS", "BIPOLAR_MARYLAND_FORCEPS"], "Maryland Bipolar Forceps",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400172),
    tool("CURVED_SCISSORS_400178", 400178, ANY_VERSION, Classic,
         &["CURVED_SCISSORS"], "Curved Scissors",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MONOPOLAR_CURVED_SCISSORS_400179", 400179, ANY_VERSION, Classic,
         &["MONOPOLAR_CURVED_SCISSORS", "MONOPOLAR_CURVED_SCISSOR"], "Monopolar Curved Scissors",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("RESANO_FORCEPS_400181", 400181, ANY_VERSION, Classic,
         &["RESANO_FORCEPS"], "Resano Forceps",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("PERMANENT_CAUTERY_HOOK_400183", 400183, ANY_VERSION, Classic,
         &["PERMANENT_CAUTERY_HOOK"], "Permanent Cautery Hook",
         0.4162, standard(0.0093), TOOLTIP_8MM, C_400183),
    tool("PERMANENT_CAUTERY_SPATULA_400184", 400184, ANY_VERSION, Classic,
         &["PERMANENT_CAUTERY_SPATULA"], "Permanent Cautery Spatula",
         0.4162, standard(0.0093), TOOLTIP_8MM, C_400183),
    tool("DOUBLE_FENESTRATED_GRASPER_400189", 400189, ANY_VERSION, Classic,
         &["DOUBLE_FENESTRATED_GRASPER"], "Double Fenestrated Grasper",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400127),
    tool("MEGA_NEEDLE_DRIVER_400194", 400194, ANY_VERSION, Classic,
         &["MEGA_NEEDLE_DRIVER"], "Mega Needle Driver",
         0.4162, standard(0.0112), TOOLTIP_8MM, C_400194),
    tool("FENESTRATED_BIPOLAR_FORCEPS_400205", 400205, ANY_VERSION, Classic,
         &["FENESTRATED_BIPOLAR_FORCEPS"], "Fenestrated Bipolar Forceps",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400172),
    tool("TENACULUM_FORCEPS_400207", 400207, ANY_VERSION, Classic,
         &["TENACULUM_FORCEPS"], "Tenaculum Forceps",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400127),
    tool("THORACIC_GRASPER_400208", 400208, ANY_VERSION, Classic,
         &["THORACIC_GRASPER"], "Thoracic Grasper",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400127),
    tool("LARGE_CLIP_APPLIER_400230", 400230, ANY_VERSION, Classic,
         &["LARGE_CLIP_APPLIER"], "Large Clip Applier",
         0.4162, standard(0.0107), TOOLTIP_8MM, C_400230),
    tool("LRG_SUTURECUT_NEEDLE_DRIVER_400296", 400296, ANY_VERSION, Classic,
         &["LRG_SUTURECUT_NEEDLE_DRIVER"], "Large Suturecut Needle Driver",
         0.4162, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MEGA_SUTURECUT_NEEDLE_DRIVER_400309", 400309, ANY_VERSION, Classic,
         &["MEGA_SUTURECUT_NEEDLE_DRIVER"], "Mega Suturecut Needle Driver",
         0.4162, standard(0.01), TOOLTIP_8MM, C_400309),
    Instrument { roll_theta_rad: STAPLER_ROLL_THETA_RAD, shaft_diameter_mm: 12, ..
    tool("STAPLER_45_410298", 410298, ANY_VERSION, S,
         &["STAPLER_45"], "Stapler 45",
         0.41557, standard(0.0), TOOLTIP_STAPLER, C_410298) },
    tool("POTTS_SCISSORS_420001", 420001, ANY_VERSION, S,
         &["POTTS_SCISSORS"], "Potts Scissors",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("LARGE_NEEDLE_DRIVER_420006", 420006, up_to(11), S,
         &["LARGE_NEEDLE_DRIVER"], "Large Needle Driver",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("LARGE_NEEDLE_DRIVER_420006_GEARED", 420006, from(12), S,
         &["LARGE_NEEDLE_DRIVER"], "Large Needle Driver (Geared)",
         0.467, standard(0.0091), TOOLTIP_8MM, C_420006_GEARED),
    tool("ROUND_TIP_SCISSORS_420007", 420007, ANY_VERSION, S,
         &["ROUND_TIP_SCISSORS"], "Round Tip Scissors",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MICRO_FORCEPS_420033", 420033, ANY_VERSION, S,
         &["MICRO_FORCEPS", "BLACK_DIAMOND_MICRO_FORCEPS"], "Black Diamond Micro Forceps",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("DEBAKEY_FORCEPS_420036", 420036, ANY_VERSION, S,
         &["DEBAKEY_FORCEPS"], "DeBakey Forceps",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("LONG_TIP_FORCEPS_420048", 420048, ANY_VERSION, S,
         &["LONG_TIP_FORCEPS"], "Long Tip Forceps",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("CADIERE_FORCEPS_420049", 420049, ANY_VERSION, S,
         &["CADIERE_FORCEPS"], "Cadiere Forceps",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("PROGRASP_FORCEPS_420093", 420093, up_to(13), S,
         &["PROGRASP_FORCEPS"], "Prograsp Forceps",
         0.467, standard(0.0107), TOOLTIP_8MM, C_400093),
    tool("PROGRASP_FORCEPS_420093_GEARED", 420093, from(14), S,
         &["PROGRASP_FORCEPS"], "Prograsp Forceps",
         0.467, standard(0.0107), TOOLTIP_8MM, C_420093_GEARED),
    tool("NEEDLE_DRIVER_420117", 420117, ANY_VERSION, S,
         &["NEEDLE_DRIVER"], "5mm Needle Driver",
         0.4532, snake(0.0034), tooltip_5mm(-0.0171), C_400117),
    tool("MARYLAND_BIPOLAR_FORCEPS_420172", 420172, ANY_VERSION, S,
         &["MARYLAND_BIPOLAR_FORCEPS"], "Maryland Bipolar Forceps",
         0.467, standard(0.0107), TOOLTIP_8MM, C_400172),
    tool("CURVED_SCISSORS_420178", 420178, ANY_VERSION, S,
         &["CURVED_SCISSORS"], "Curved Scissors",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MONOPOLAR_CURVED_SCISSORS_420179", 420179, ANY_VERSION, S,
         &["MONOPOLAR_CURVED_SCISSORS"], "Monopolar Curved Scissors",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("RESANO_FORCEPS_420181", 420181, ANY_VERSION, S,
         &["RESANO_FORCEPS"], "Resano Forceps",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("PERMANENT_CAUTERY_HOOK_420183", 420183, up_to(10), S,
         &["PERMANENT_CAUTERY_HOOK"], "Permanent Cautery Hook",
         0.467, standard(0.0093), TOOLTIP_8MM, C_400183),
    tool("PERMANENT_CAUTERY_HOOK_420183_GEARED", 420183, from(11), S,
         &["PERMANENT_CAUTERY_HOOK"], "Permanent Cautery Hook (Geared)",
         0.467, standard(0.0093), TOOLTIP_8MM, C_420183_GEARED),
    tool("PERMANENT_CAUTERY_SPATULA_420184", 420184, ANY_VERSION, S,
         &["PERMANENT_CAUTERY_SPATULA"], "Permanent Cautery Spatula",
         0.467, standard(0.0093), TOOLTIP_8MM, C_400183),
    tool("MEGA_NEEDLE_DRIVER_420194", 420194, up_to(11), S,
         &["MEGA_NEEDLE_DRIVER"], "Mega Needle Driver",
         0.467, standard(0.0112), TOOLTIP_8MM, C_400194),
    tool("MEGA_NEEDLE_DRIVER_420194_GEARED", 420194, from(12), S,
         &["MEGA_NEEDLE_DRIVER"], "Mega Needle Driver (Geared)",
         0.467, standard(0.0112), TOOLTIP_8MM, C_420194_GEARED),
    tool("FENESTRATED_BIPOLAR_FORCEPS_420205", 420205, ANY_VERSION, S,
         &["FENESTRATED_BIPOLAR_FORCEPS"], "Fenestrated Bipolar Forceps",
         0.467, standard(0.0107), TOOLTIP_8MM, C_400172),
    tool("LARGE_CLIP_APPLIER_420230", 420230, ANY_VERSION, S,
         &["LARGE_CLIP_APPLIER"], "Large Clip Applier",
         0.467, standard(0.0107), TOOLTIP_8MM, C_400230),
    tool("LARGE_SUTURECUT_NEEDLEDRIVER_420296", 420296, ANY_VERSION, S,
         &["LARGE_SUTURECUT_NEEDLEDRIVER"], "Large Suturecut Needle Driver",
         0.467, standard(0.0091), TOOLTIP_8MM, C_400006),
    tool("MEGA_SUTURECUT_NEEDLE_DRIVER_420309", 420309, up_to(6), S,
         &["MEGA_SUTURECUT_NEEDLE_DRIVER"], "Mega Suturecut Needle Driver",
         0.467, standard(0.01), TOOLTIP_8MM, C_400309),
    tool("MEGA_SUTURECUT_NEEDLE_DRIVER_420309_GEARED", 420309, from(7), S,
         &["MEGA_SUTURECUT_NEEDLE_DRIVER"], "Mega Suturecut Needle Driver (Geared)",
         0.467, standard(0.01), TOOLTIP_8MM, C_420309_GEARED),
    tool("MEDIUM-LARGE_CLIP_APPLIER_420327", 420327, ANY_VERSION, S,
         &["MEDIUM-LARGE_CLIP_APPLIER"], "Medium-large Clip Applier",
         0.467, standard(0.0107), TOOLTIP_8MM, C_400230),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_carry_the_model_and_a_console_name() {
        for i in instruments() {
            let model = i.model.to_string();
            assert!(i.name.contains(&model), "{}", i.name);
            assert!(i.names.iter().any(|n| i.name.contains(n)), "{}", i.name);
            // mtsToolList::Load's own check: 40xxxx Classic, 41xxxx/42xxxx S.
            let s_generation = matches!(i.model / 10_000, 41 | 42);
            assert_eq!(s_generation, i.generation == S, "{}", i.name);
            assert_eq!(
                i.model / 10_000 == 40,
                i.generation == Classic,
                "{}",
                i.name
            );
        }
    }

    #[test]
    fn names_are_unique_and_versions_do_not_overlap() {
        let all = instruments();
        for (k, i) in all.iter().enumerate() {
            for j in &all[k + 1..] {
                assert_ne!(j.name, i.name);
                if j.model == i.model {
                    // Same model: the ranges must be disjoint, as the console picks the first.
                    let (a, b) = (i.versions, j.versions);
                    let disjoint = matches!((a.max, b.min), (Some(x), Some(y)) if x < y)
                        || matches!((b.max, a.min), (Some(x), Some(y)) if x < y);
                    assert!(disjoint, "{} {}", i.name, j.name);
                }
            }
        }
    }

    #[test]
    fn every_catalog_entry_is_usable() {
        for i in instruments() {
            assert_eq!(i.check(), Ok(i), "{}", i.name);
            assert!(i.coupling().is_ok(), "{}", i.name);
        }
        assert_eq!(instruments().len(), 54);
    }

    static NO_COUPLING: Instrument = Instrument {
        actuator_to_joint_position: None,
        ..CATALOG[2]
    };
    static SINGULAR: Instrument = Instrument {
        actuator_to_joint_position: Some([[1.0, 0.0, 0.0, 0.0]; 4]),
        ..CATALOG[2]
    };
    static NOT_FINITE: Instrument = Instrument {
        roll_d_m: f64::NAN,
        ..CATALOG[2]
    };

    #[test]
    fn an_instrument_without_usable_coupling_is_refused() {
        let why = |i: &Instrument| match i.check() {
            Err(InstrumentError::NotModelled { name, why }) => {
                assert_eq!(name, "LARGE_NEEDLE_DRIVER_400006");
                why
            }
            other => panic!("{other:?}"),
        };
        assert!(why(&NO_COUPLING).contains("no actuator-to-joint coupling"));
        assert!(why(&SINGULAR).contains("singular"));
        assert!(why(&NOT_FINITE).contains("not finite"));
        assert!(NO_COUPLING.coupling().is_err());
        let text = NO_COUPLING.check().unwrap_err().to_string();
        assert!(text.contains("LARGE_NEEDLE_DRIVER_400006"), "{text}");
    }

    #[test]
    fn determinant() {
        let m = [
            [2.0, 0.0, 0.0, 1.0],
            [0.0, 3.0, 0.0, 0.0],
            [0.0, 0.0, 4.0, 0.0],
            [1.0, 0.0, 0.0, 5.0],
        ];
        // 3 * 4 * (2 * 5 - 1 * 1) = 108.
        assert_eq!(det4(&m), 108.0);
        let swapped = [m[1], m[0], m[2], m[3]];
        assert_eq!(det4(&swapped), -108.0);
    }

    fn model_of(s: &str) -> Result<(u32, &'static str), InstrumentError> {
        instrument_from_tool_type(s).map(|i| (i.model, i.name))
    }

    #[test]
    fn project_names_keep_working() {
        for i in instruments() {
            assert_eq!(model_of(i.name), Ok((i.model, i.name)));
        }
        assert_eq!(
            instrument("LARGE_NEEDLE_DRIVER_400006").map(|i| i.model),
            Some(400006)
        );
        assert!(instrument("large_needle_driver_400006").is_none());
        assert!(instrument("LARGE_NEEDLE_DRIVER").is_none());
        assert_eq!(model_of("BANANA_400000"), Err(InstrumentError::UnknownName));
    }

    #[test]
    fn console_names_resolve_to_their_entry() {
        // What the console writes (mtsToolList::Name) resolves back to the same entry.
        for i in instruments() {
            let written = i.tool_type().to_string();
            assert_eq!(model_of(&written), Ok((i.model, i.name)), "{written}");
            for n in i.names {
                let versioned = format!("{n}:{}{}", i.model, i.versions);
                assert_eq!(model_of(&versioned), Ok((i.model, i.name)), "{versioned}");
            }
        }
        assert_eq!(
            CATALOG[2].tool_type().to_string(),
            "LARGE_NEEDLE_DRIVER:400006[..]"
        );
        let geared = instrument("LARGE_NEEDLE_DRIVER_420006_GEARED").unwrap();
        assert_eq!(
            geared.tool_type().to_string(),
            "LARGE_NEEDLE_DRIVER:420006[12..]"
        );
        let old = instrument("LARGE_NEEDLE_DRIVER_420006").unwrap();
        assert_eq!(
            old.tool_type().to_string(),
            "LARGE_NEEDLE_DRIVER:420006[..11]"
        );
    }

    #[test]
    fn console_lookup_rules() {
        let lnd = Ok((400006, "LARGE_NEEDLE_DRIVER_400006"));
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:400006"), lnd);
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:400006[..]"), lnd);
        // One entry: the version is not needed and not checked (mtsToolList::Find).
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:400006[3]"), lnd);
        assert_eq!(model_of(":400006"), lnd);
        // Aliases of the index.
        assert_eq!(
            model_of("5MM_NEEDLE_DRIVER:400117").map(|m| m.1),
            Ok("NEEDLE_DRIVER_400117")
        );
        assert_eq!(
            model_of("BLACK_DIAMOND_MICRO_FORCEPS:420033").map(|m| m.1),
            Ok("MICRO_FORCEPS_420033")
        );
        // Several entries: the version chooses; lower bound first, else upper bound.
        let old = Ok((420006, "LARGE_NEEDLE_DRIVER_420006"));
        let geared = Ok((420006, "LARGE_NEEDLE_DRIVER_420006_GEARED"));
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:420006[11]"), old);
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:420006[12]"), geared);
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:420006[..11]"), old);
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:420006[12..]"), geared);
        assert_eq!(model_of("LARGE_NEEDLE_DRIVER:420006[3..40]"), old);
        assert_eq!(model_of(":420006[40]"), geared);
        for ambiguous in [
            "LARGE_NEEDLE_DRIVER:420006",
            "LARGE_NEEDLE_DRIVER:420006[..]",
            ":420006",
        ] {
            assert_eq!(
                model_of(ambiguous),
                Err(InstrumentError::VersionNeeded {
                    model: 420006,
                    entries: 2
                }),
                "{ambiguous}"
            );
        }
        // Wrong name for the model, unknown model.
        assert_eq!(
            model_of("CADIERE_FORCEPS:400006"),
            Err(InstrumentError::NotInIndex { model: 400006 })
        );
        assert_eq!(
            model_of("LARGE_NEEDLE_DRIVER:400007"),
            Err(InstrumentError::NotInIndex { model: 400007 })
        );
        assert_eq!(model_of(""), Err(InstrumentError::Empty));
        assert_eq!(model_of("ERROR"), Err(InstrumentError::ConsoleError));
    }

    #[test]
    fn malformed_tool_types_are_refused() {
        for bad in [
            ":",
            "LARGE_NEEDLE_DRIVER:",
            "LARGE_NEEDLE_DRIVER:4OOOO6",
            "LARGE_NEEDLE_DRIVER:+400006",
            "LARGE_NEEDLE_DRIVER:400006[",
            "LARGE_NEEDLE_DRIVER:400006[12",
            "LARGE_NEEDLE_DRIVER:400006[12]x",
            "LARGE_NEEDLE_DRIVER:420006[a..]",
            "LARGE_NEEDLE_DRIVER:420006[-1]",
            "LARGE_NEEDLE_DRIVER:420006[13..12]",
            "LARGE_NEEDLE_DRIVER:420006[...]",
            "large_needle_driver:400006",
            " LARGE_NEEDLE_DRIVER:400006",
            "LARGE_NEEDLE_DRIVER400006[..]",
            "LARGE_NEEDLE_DRIVER:99999999999",
        ] {
            let e = model_of(bad).unwrap_err();
            assert!(
                matches!(e, InstrumentError::Syntax { .. }),
                "{bad:?}: {e:?}"
            );
        }
    }

    #[test]
    fn tool_type_parse_keeps_the_bracket() {
        let t = ToolType::parse("LARGE_NEEDLE_DRIVER:420006[12..20]").unwrap();
        assert_eq!(t.name, Some("LARGE_NEEDLE_DRIVER"));
        assert_eq!(t.model, 420006);
        assert_eq!(
            t.versions,
            Some(VersionRange {
                min: Some(12),
                max: Some(20)
            })
        );
        assert_eq!(t.version(), Some(12));
        let t = ToolType::parse(":420006[..11]").unwrap();
        assert_eq!((t.name, t.version()), (None, Some(11)));
        let t = ToolType::parse("X:1[..]").unwrap();
        assert_eq!((t.versions, t.version()), (Some(ANY_VERSION), None));
        let t = ToolType::parse("X:1").unwrap();
        assert_eq!((t.versions, t.version()), (None, None));
        assert_eq!(
            VersionRange {
                min: Some(7),
                max: None
            }
            .to_string(),
            "[7..]"
        );
        assert!(from(7).contains(7) && !from(7).contains(6));
        assert!(up_to(11).contains(0) && !up_to(11).contains(12));
    }

    #[test]
    fn tooltip_rotations_are_proper() {
        for i in instruments() {
            let t = i.tooltip_offset;
            let r = |a: usize, b: usize| t[a][b];
            let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1))
                - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
                + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
            assert!((det - 1.0).abs() < 1e-15, "{}: det {det}", i.name);
            assert_eq!(t[3], [0.0, 0.0, 0.0, 1.0], "{}", i.name);
        }
    }
}
