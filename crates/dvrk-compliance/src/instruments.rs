//! Instrument catalog: the DH values of joints 4-6 and the tooltip offset of the dVRK tool files
//! (`share/tool/<NAME>_<MODEL>.json` of sawIntuitiveResearchKit; reference section 1.2).
//!
//! Every entry uses the dVRK's name, `<NAME>_<MODEL>` as in its tool index. Joint 4 (roll) is
//! `alpha = 0, A = 0, D = roll_d_m`; the wrist links are described by [`Wrist`].

use std::f64::consts::FRAC_1_SQRT_2;

/// The instrument generation, as the dVRK's tool index spells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Generation {
    /// Classic (standard) da Vinci instruments, model numbers 400xxx.
    Classic,
    /// S and Si instruments, model numbers 420xxx (longer shaft).
    S,
}

/// The wrist's modified-DH links after the roll joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Wrist {
    /// 8 mm EndoWrist: wrist pitch (`alpha = -pi/2, offset = -1.5708`) then wrist yaw
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

/// One catalog entry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instrument {
    /// The dVRK's name, e.g. `LARGE_NEEDLE_DRIVER_400006`.
    pub name: &'static str,
    /// Intuitive Surgical model number.
    pub model: u32,
    /// Classic or S/Si.
    pub generation: Generation,
    /// Shaft diameter (mm).
    pub shaft_diameter_mm: u8,
    /// `D` of the roll link (m): RCM-side shaft length used by the chain.
    pub roll_d_m: f64,
    /// The wrist links.
    pub wrist: Wrist,
    /// Constant transform after the last link, row-major 4x4 (`tooltip-offset`). For the snake
    /// tools the file's 0.7071 entries are stored as exact 1/sqrt(2) so the rotation is proper.
    pub tooltip_offset: [[f64; 4]; 4],
    /// `coupling.ActuatorToJointPosition` (actuators 4-7 to roll, wrist pitch, wrist yaw, jaw),
    /// given only where the project's reference carries it; `None` otherwise.
    pub actuator_to_joint_position: Option<[[f64; 4]; 4]>,
}

/// Tooltip rotation of the 8 mm tools: matches the ISI tool-frame convention (reference 1.2).
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

/// `ActuatorToJointPosition` of LARGE_NEEDLE_DRIVER_400006 (reference 1.2).
const COUPLING_400006: [[f64; 4]; 4] = [
    [-1.5632, 0.0, 0.0, 0.0],
    [0.0, 1.0186, 0.0, 0.0],
    [0.0, -0.8306, 0.6089, 0.6089],
    [0.0, 0.0, -1.2177, 1.2177],
];

const D_CLASSIC_8MM: f64 = 0.4162;
const D_S_8MM: f64 = 0.4670;
const D_CLASSIC_5MM: f64 = 0.4024;
const D_S_5MM: f64 = 0.4532;
const A_5MM: f64 = 0.0034;

const fn eight_mm(
    name: &'static str,
    model: u32,
    generation: Generation,
    yaw_a_m: f64,
) -> Instrument {
    Instrument {
        name,
        model,
        generation,
        shaft_diameter_mm: 8,
        roll_d_m: match generation {
            Generation::Classic => D_CLASSIC_8MM,
            Generation::S => D_S_8MM,
        },
        wrist: Wrist::Standard { yaw_a_m },
        tooltip_offset: TOOLTIP_8MM,
        actuator_to_joint_position: None,
    }
}

const fn five_mm(
    name: &'static str,
    model: u32,
    generation: Generation,
    tooltip_y_m: f64,
) -> Instrument {
    Instrument {
        name,
        model,
        generation,
        shaft_diameter_mm: 5,
        roll_d_m: match generation {
            Generation::Classic => D_CLASSIC_5MM,
            Generation::S => D_S_5MM,
        },
        wrist: Wrist::Snake { link_a_m: A_5MM },
        tooltip_offset: tooltip_5mm(tooltip_y_m),
        actuator_to_joint_position: None,
    }
}

use Generation::{Classic, S};

static CATALOG: [Instrument; 16] = [
    // Classic 8 mm: D = 0.4162; wrist A = 0.0091, 0.0107 for graspers and clip appliers,
    // 0.0112 for the Mega needle driver.
    Instrument {
        actuator_to_joint_position: Some(COUPLING_400006),
        ..eight_mm("LARGE_NEEDLE_DRIVER_400006", 400006, Classic, 0.0091)
    },
    eight_mm("CADIERE_FORCEPS_400049", 400049, Classic, 0.0091),
    eight_mm("PROGRASP_FORCEPS_400093", 400093, Classic, 0.0107),
    eight_mm("CURVED_SCISSORS_400178", 400178, Classic, 0.0091),
    eight_mm("MONOPOLAR_CURVED_SCISSORS_400179", 400179, Classic, 0.0091),
    eight_mm("MEGA_NEEDLE_DRIVER_400194", 400194, Classic, 0.0112),
    eight_mm("LARGE_CLIP_APPLIER_400230", 400230, Classic, 0.0107),
    // S/Si 8 mm: D = 0.4670 (longer shaft), wrist as the Classic counterpart.
    eight_mm("LARGE_NEEDLE_DRIVER_420006", 420006, S, 0.0091),
    eight_mm("CADIERE_FORCEPS_420049", 420049, S, 0.0091),
    eight_mm("PROGRASP_FORCEPS_420093", 420093, S, 0.0107),
    eight_mm("CURVED_SCISSORS_420178", 420178, S, 0.0091),
    eight_mm("MEGA_NEEDLE_DRIVER_420194", 420194, S, 0.0112),
    eight_mm("LARGE_CLIP_APPLIER_420230", 420230, S, 0.0107),
    // 5 mm snake-like: D = 0.4024 (Classic) / 0.4532 (S), wrist links A = 0.0034.
    five_mm("NEEDLE_DRIVER_400117", 400117, Classic, -0.0171),
    five_mm("MARYLAND_DISSECTOR_400143", 400143, Classic, -0.0269),
    five_mm("NEEDLE_DRIVER_420117", 420117, S, -0.0171),
];

/// Every instrument in the catalog.
pub fn instruments() -> &'static [Instrument] {
    &CATALOG
}

/// Looks an instrument up by its dVRK name, either `LARGE_NEEDLE_DRIVER_400006` or the arm
/// configuration's form `LARGE_NEEDLE_DRIVER:400006`. Case-sensitive.
pub fn instrument(name: &str) -> Option<&'static Instrument> {
    CATALOG.iter().find(|i| {
        i.name == name
            || name.split_once(':').is_some_and(|(base, model)| {
                i.name
                    .strip_suffix(model)
                    .and_then(|rest| rest.strip_suffix('_'))
                    .is_some_and(|b| b == base)
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_end_with_their_model_number() {
        for i in instruments() {
            assert!(i.name.ends_with(&format!("_{}", i.model)), "{}", i.name);
            let s_generation = i.model / 1000 == 420;
            assert_eq!(s_generation, i.generation == S, "{}", i.name);
        }
    }

    #[test]
    fn names_are_unique() {
        let all = instruments();
        for (k, i) in all.iter().enumerate() {
            assert!(all[k + 1..].iter().all(|j| j.name != i.name), "{}", i.name);
        }
    }

    #[test]
    fn lookup_by_both_spellings() {
        let lnd = instrument("LARGE_NEEDLE_DRIVER_400006").map(|i| i.model);
        assert_eq!(lnd, Some(400006));
        let colon = instrument("LARGE_NEEDLE_DRIVER:400006").map(|i| i.model);
        assert_eq!(colon, Some(400006));
        assert!(instrument("LARGE_NEEDLE_DRIVER").is_none());
        assert!(instrument("LARGE_NEEDLE_DRIVER:400007").is_none());
        assert!(instrument("large_needle_driver_400006").is_none());
        assert!(instrument("").is_none());
        assert!(instrument(":").is_none());
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

    #[test]
    fn coupling_only_where_the_reference_gives_it() {
        for i in instruments() {
            assert_eq!(
                i.actuator_to_joint_position.is_some(),
                i.model == 400006,
                "{}",
                i.name
            );
        }
    }
}
