//! Scenarios: what the simulated PSM is doing (config/sim/*.toml).
//!
//! A scenario fixes the seed and step of the physics, the starting pose, the environment at the
//! tip, a motion (the setpoints the stand-in console commands over time) and the measurement
//! noise; optionally the shaft's true compliance and backlash (`[shaft]`), the transmission's
//! friction (`[transmission]`), the distal part's inertia (`[distal]`) and its weight
//! (`[distal_gravity]`). Files are parsed into
//! [`ScenarioParams`] (`deny_unknown_fields`) and validated into a [`Scenario`]; every error names
//! the field and the value.
//!
//! ```toml
//! description = "tip in a divot, pushing with a slow ±1.5 N·m cycle"
//! seed = 7
//! dt_s = 0.0001
//! initial_position = [0.05, -0.1, 0.13, 0.0, 0.0, 0.0, 0.3]
//!
//! [environment]
//! kind = "divot"                 # free | clamp | divot | surface
//! plate_stiffness_n_per_m = 20000.0
//! plate_damping_n_s_per_m = 50.0
//! capture_depth_m = 0.001
//!
//! [motion]
//! kind = "push_cycle"            # hold | push_cycle | trajectory | multi_sine | start_stop
//! effort_amplitude_nm = [1.5, 1.5]
//! period_s = 20.0
//! insertion_force_n = 2.0
//!
//! [noise]
//! current_noise_amps = 0.002
//! pot_noise_volts = 0.001
//! ```

use serde::Deserialize;

use crate::SimError;
use crate::measure::NoiseParams;
use crate::physics::{
    DistalGravity, DistalParams, Environment, FrictionParams, NUM_JOINTS, PhysicsParams,
    ShaftParams, SimPsm,
};

/// Environment section, as written in the file.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum EnvironmentParams {
    // Empty struct variants (not unit variants) so that deny_unknown_fields applies to them.
    Free {},
    Clamp {},
    Divot {
        plate_stiffness_n_per_m: f64,
        plate_damping_n_s_per_m: f64,
        capture_depth_m: f64,
    },
    Surface {
        stiffness_n_per_m: f64,
        gap_m: f64,
        tilt_rad: f64,
    },
}

/// Motion section, as written in the file.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MotionParams {
    /// Setpoints stay where they are (at the initial pose unless a caller changes them).
    Hold {},
    /// Push against what holds the tip with a slow sinusoidal effort on joints 1 and 2 (joint 2 a
    /// quarter period later): the setpoint moves by `(delta + K(L)·A)·sin`, so the controller
    /// pushes with peak effort `A` once the play is taken up. With a divot, the insertion setpoint
    /// goes `insertion_force_n / plate stiffness` past the plate to keep the tip seated.
    PushCycle {
        #[serde(deserialize_with = "dvrk_compliance::exact::array")]
        effort_amplitude_nm: [f64; 2],
        period_s: f64,
        insertion_force_n: f64,
    },
    /// Smooth sinusoids around the initial pose, one per joint (amplitude 0 = still).
    Trajectory {
        #[serde(deserialize_with = "dvrk_compliance::exact::array")]
        amplitude: [f64; NUM_JOINTS],
        #[serde(deserialize_with = "dvrk_compliance::exact::array")]
        period_s: [f64; NUM_JOINTS],
    },
    /// The identification excitation of `calibrate dynamics` ([`Motion::MultiSine`]): per joint
    /// 1 and 2 three sines around the initial pose (rad, rad/s), faded in over the first second.
    MultiSine {
        #[serde(deserialize_with = "dvrk_compliance::exact::matrix")]
        amplitude: [[f64; 3]; 2],
        #[serde(deserialize_with = "dvrk_compliance::exact::matrix")]
        angular_frequency: [[f64; 3]; 2],
    },
    /// Repeated abrupt starts and stops of joints 1 and 2 ([`Motion::StartStop`]).
    StartStop {
        #[serde(deserialize_with = "dvrk_compliance::exact::array")]
        speed_rad_per_s: [f64; 2],
        move_s: f64,
        still_s: f64,
        #[serde(default)]
        ramp_s: f64,
        #[serde(default)]
        start_s: f64,
    },
}

/// Noise section.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NoiseSection {
    pub current_noise_amps: f64,
    pub pot_noise_volts: f64,
}

/// Optional shaft section (default: the paper's values).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ShaftSection {
    /// `[a, b, c, d]` of `1/K1(L) = a L^3 + b L^2 + c L + d`, N·m/rad.
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub inverse_compliance_j1: [f64; 4],
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub inverse_compliance_j2: [f64; 4],
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub backlash_rad: [f64; 2],
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub insertion_range_m: [f64; 2],
}

/// Optional transmission section (default: no Coulomb friction, the built-in viscous friction):
/// motor-side friction of joints 1 and 2 (issue 10, "a transmission that rubs").
///
/// ```toml
/// [transmission]
/// coulomb_nm = [0.03, 0.03]       # Coulomb friction while moving, N·m
/// stiction_nm = [0.04, 0.04]      # break-away torque, >= coulomb_nm
/// viscous_nm_s_per_rad = [0.2, 0.2]   # optional; default 0.2
/// ```
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TransmissionSection {
    #[serde(default)]
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub coulomb_nm: [f64; 2],
    #[serde(default)]
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub stiction_nm: [f64; 2],
    #[serde(default = "default_viscous")]
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub viscous_nm_s_per_rad: [f64; 2],
}

fn default_viscous() -> [f64; 2] {
    [
        PhysicsParams::CLASSIC.viscous[0],
        PhysicsParams::CLASSIC.viscous[1],
    ]
}

/// Optional distal section (default: [`DistalParams::CLASSIC_8MM`], field by field): the inertia
/// and damping of the shaft beyond the compliant element.
///
/// ```toml
/// [distal]
/// inertia_kg_m2 = 5.0e-5          # I_0 of I_d(L) = I_0 + m L^2
/// mass_kg = 0.02                  # m
/// damping_nm_s_per_rad = 0.007    # damper in parallel with the play and spring
/// ```
///
/// All three 0 give the massless, quasi-static shaft of the paper.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DistalSection {
    #[serde(default = "default_distal_inertia")]
    pub inertia_kg_m2: f64,
    #[serde(default = "default_distal_mass")]
    pub mass_kg: f64,
    #[serde(default = "default_distal_damping")]
    pub damping_nm_s_per_rad: f64,
}

fn default_distal_inertia() -> f64 {
    DistalParams::CLASSIC_8MM.inertia_kg_m2
}

fn default_distal_mass() -> f64 {
    DistalParams::CLASSIC_8MM.mass_kg
}

fn default_distal_damping() -> f64 {
    DistalParams::CLASSIC_8MM.damping_nm_s_per_rad
}

/// Optional distal gravity section (default: [`DistalGravity::CLASSIC_8MM`], field by field):
/// the weight the shaft carries beyond the compliant element (issue 20 item 3).
///
/// ```toml
/// [distal_gravity]
/// mass_kg = 0.02                                  # 0 for no weight
/// lever_offset_m = 0.0                            # the mass sits at L + lever_offset_m
/// direction_rcm = [0.3993, 0.3993, -0.8253]       # gravity in the RCM frame (normalised)
/// ```
///
/// A weight needs a distal inertia (`[distal]`): the massless shaft of the paper carries none.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DistalGravitySection {
    #[serde(default = "default_gravity_mass")]
    pub mass_kg: f64,
    #[serde(default)]
    pub lever_offset_m: f64,
    #[serde(
        default = "default_gravity_direction",
        deserialize_with = "dvrk_compliance::exact::array"
    )]
    pub direction_rcm: [f64; 3],
}

fn default_gravity_mass() -> f64 {
    DistalGravity::CLASSIC_8MM.mass_kg
}

fn default_gravity_direction() -> [f64; 3] {
    DistalGravity::CLASSIC_8MM.direction_rcm
}

/// A scenario file as parsed.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ScenarioParams {
    #[serde(default)]
    pub description: String,
    pub seed: u64,
    pub dt_s: f64,
    #[serde(deserialize_with = "dvrk_compliance::exact::array")]
    pub initial_position: [f64; NUM_JOINTS],
    pub environment: EnvironmentParams,
    pub motion: MotionParams,
    pub noise: NoiseSection,
    #[serde(default)]
    pub shaft: Option<ShaftSection>,
    #[serde(default)]
    pub transmission: Option<TransmissionSection>,
    #[serde(default)]
    pub distal: Option<DistalSection>,
    #[serde(default)]
    pub distal_gravity: Option<DistalGravitySection>,
    /// How the emulated boards present themselves on Ethernet (default `bridge`).
    #[serde(default)]
    pub ethernet: EthernetMode,
}

/// How the emulated boards present themselves on Ethernet (reference §3.3 step 5, §3.4).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum EthernetMode {
    /// FPGA V2 (100 Mb Ethernet) bridging to FireWire: the host talks to the hub, and reads
    /// hub memory explicitly after a broadcast query.
    #[default]
    Bridge,
    /// FPGA V3 with firmware Rev 9: the host unicasts to each board, and the hub sends the
    /// broadcast-read data unasked after the query.
    EthernetOnly,
}

/// What the stand-in console commands over time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    Hold,
    PushCycle {
        effort_amplitude_nm: [f64; 2],
        period_s: f64,
        insertion_force_n: f64,
    },
    Trajectory {
        amplitude: [f64; NUM_JOINTS],
        period_s: [f64; NUM_JOINTS],
    },
    /// Identification excitation of joints 1 and 2 (`calibrate dynamics`): per joint a sum of
    /// three sines around the anchor, faded in over the first second (`sin^2`) so the setpoint
    /// starts still. File kind `multi_sine` (a live service on the simulator then runs the same
    /// excitation, e.g. for `calibrate record --dynamics`).
    MultiSine {
        amplitude: [[f64; 3]; 2],
        angular_frequency: [[f64; 3]; 2],
    },
    /// Still-move-still of joints 1 and 2 (issue 20): still until `start_s`, then moves of
    /// `move_s` at `speed_rad_per_s` separated by `still_s` of rest, each move the opposite way
    /// of the last, so the joint goes back and forth from the initial pose. The speed rises and
    /// falls over `ramp_s` (`sin^2`, peak acceleration `pi/2 * speed / ramp_s`); `ramp_s = 0` is
    /// a velocity step, an abrupt start and stop that only the controller smooths. File kind
    /// `start_stop`.
    StartStop {
        speed_rad_per_s: [f64; 2],
        move_s: f64,
        still_s: f64,
        ramp_s: f64,
        start_s: f64,
    },
}

/// The position offset and velocity of a [`Motion::StartStop`] joint with cruise speed `v` at
/// time `t` (s): see there.
pub fn start_stop(
    v: f64,
    move_s: f64,
    still_s: f64,
    ramp_s: f64,
    start_s: f64,
    t: f64,
) -> (f64, f64) {
    use core::f64::consts::PI;
    let t = t - start_s;
    if t < 0.0 {
        return (0.0, 0.0);
    }
    let period = move_s + still_s;
    let k = (t / period).floor();
    let u = t - k * period;
    // Moves alternate direction: after an odd number of moves the joint sits at +D.
    let r = ramp_s;
    let dist = v * (move_s - r);
    let odd = (k as i64) % 2 == 1;
    let (base, dir) = if odd { (dist, -1.0) } else { (0.0, 1.0) };
    // Displacement and speed (as fractions of v) `u` into a move.
    let rise = |x: f64| {
        if r <= 0.0 {
            x
        } else {
            0.5 * x - r / (2.0 * PI) * (PI * x / r).sin()
        }
    };
    let (p, s) = if u >= move_s {
        (move_s - r, 0.0)
    } else if u < r {
        (rise(u), (0.5 * PI * u / r).sin().powi(2))
    } else if u <= move_s - r {
        (0.5 * r + (u - r), 1.0)
    } else {
        let w = move_s - u;
        (move_s - r - rise(w), (0.5 * PI * w / r).sin().powi(2))
    };
    (base + dir * v * p, dir * v * s)
}

/// The position offset and velocity of a [`Motion::MultiSine`] joint at time `t` (s).
pub fn multi_sine(amplitude: &[f64; 3], angular_frequency: &[f64; 3], t: f64) -> (f64, f64) {
    use core::f64::consts::PI;
    let (fade, dfade) = if t < 0.0 {
        (0.0, 0.0)
    } else if t < 1.0 {
        // sin^2(pi t / 2): 0 at t = 0, 1 at t = 1, flat at both ends.
        let s = (0.5 * PI * t).sin();
        (s * s, 0.5 * PI * (PI * t).sin())
    } else {
        (1.0, 0.0)
    };
    let (mut q, mut v) = (0.0, 0.0);
    for k in 0..3 {
        let (s, c) = (angular_frequency[k] * t).sin_cos();
        q += amplitude[k] * s;
        v += amplitude[k] * angular_frequency[k] * c;
    }
    (fade * q, fade * v + dfade * q)
}

/// A validated scenario.
#[derive(Clone, Debug, PartialEq)]
pub struct Scenario {
    pub description: String,
    pub seed: u64,
    pub dt_s: f64,
    pub initial_position: [f64; NUM_JOINTS],
    pub environment: Environment,
    pub motion: Motion,
    pub noise: NoiseParams,
    pub physics: PhysicsParams,
    pub ethernet: EthernetMode,
}

fn invalid(
    field: impl Into<String>,
    value: impl std::fmt::Display,
    reason: &'static str,
) -> SimError {
    SimError::InvalidScenario {
        field: field.into(),
        value: value.to_string(),
        reason,
    }
}

fn check_finite(field: &str, v: f64) -> Result<f64, SimError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(invalid(field, v, "must be a finite number"))
    }
}

fn check_positive(field: &str, v: f64) -> Result<f64, SimError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(invalid(field, v, "must be a finite number > 0"))
    }
}

fn check_non_negative(field: &str, v: f64) -> Result<f64, SimError> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(invalid(field, v, "must be a finite number >= 0"))
    }
}

impl Scenario {
    /// Validate parsed parameters (a scenario file deserialised by the application: this crate
    /// reads no text formats itself, like the pure crates it builds on).
    pub fn from_params(p: ScenarioParams) -> Result<Self, SimError> {
        let mut physics = PhysicsParams::CLASSIC;
        if !(p.dt_s.is_finite() && p.dt_s > 0.0 && p.dt_s <= 0.001) {
            return Err(invalid("dt_s", p.dt_s, "must be in (0, 0.001] s"));
        }
        if let Some(s) = p.shaft {
            for (i, c) in s.inverse_compliance_j1.iter().enumerate() {
                check_finite(&format!("shaft.inverse_compliance_j1[{i}]"), *c)?;
            }
            for (i, c) in s.inverse_compliance_j2.iter().enumerate() {
                check_finite(&format!("shaft.inverse_compliance_j2[{i}]"), *c)?;
            }
            for (i, b) in s.backlash_rad.iter().enumerate() {
                check_non_negative(&format!("shaft.backlash_rad[{i}]"), *b)?;
                if *b > 0.05 {
                    return Err(invalid(
                        format!("shaft.backlash_rad[{i}]"),
                        b,
                        "must be at most 0.05 rad",
                    ));
                }
            }
            let [lo, hi] = s.insertion_range_m;
            check_non_negative("shaft.insertion_range_m[0]", lo)?;
            if !(hi.is_finite() && hi > lo) {
                return Err(invalid(
                    "shaft.insertion_range_m[1]",
                    hi,
                    "must be finite and above insertion_range_m[0]",
                ));
            }
            let shaft = ShaftParams {
                inverse_compliance_cubic: [s.inverse_compliance_j1, s.inverse_compliance_j2],
                backlash_rad: s.backlash_rad,
                insertion_range_m: s.insertion_range_m,
            };
            let kmin = shaft.min_stiffness_nm_per_rad();
            if kmin[0].is_nan() || kmin[0] < 0.5 {
                return Err(invalid(
                    "shaft.inverse_compliance_j1",
                    format!("{:?} (min {:.3} N·m/rad)", s.inverse_compliance_j1, kmin[0]),
                    "1/K(L) must stay >= 0.5 N·m/rad over insertion_range_m",
                ));
            }
            if kmin[1].is_nan() || kmin[1] < 0.5 {
                return Err(invalid(
                    "shaft.inverse_compliance_j2",
                    format!("{:?} (min {:.3} N·m/rad)", s.inverse_compliance_j2, kmin[1]),
                    "1/K(L) must stay >= 0.5 N·m/rad over insertion_range_m",
                ));
            }
            physics.shaft = shaft;
        }
        if let Some(t) = p.transmission {
            for j in 0..2 {
                let c =
                    check_non_negative(&format!("transmission.coulomb_nm[{j}]"), t.coulomb_nm[j])?;
                let s = check_non_negative(
                    &format!("transmission.stiction_nm[{j}]"),
                    t.stiction_nm[j],
                )?;
                let v = check_non_negative(
                    &format!("transmission.viscous_nm_s_per_rad[{j}]"),
                    t.viscous_nm_s_per_rad[j],
                )?;
                if c > 1.0 {
                    return Err(invalid(
                        format!("transmission.coulomb_nm[{j}]"),
                        c,
                        "must be at most 1 N·m",
                    ));
                }
                if s < c || s > 1.0 {
                    return Err(invalid(
                        format!("transmission.stiction_nm[{j}]"),
                        s,
                        "must lie between coulomb_nm and 1 N·m",
                    ));
                }
                if v > 10.0 {
                    return Err(invalid(
                        format!("transmission.viscous_nm_s_per_rad[{j}]"),
                        v,
                        "must be at most 10 N·m·s/rad",
                    ));
                }
                physics.friction[j] = FrictionParams {
                    coulomb: c,
                    stiction: s,
                };
                physics.viscous[j] = v;
            }
        }
        if let Some(d) = p.distal {
            let i0 = check_non_negative("distal.inertia_kg_m2", d.inertia_kg_m2)?;
            let m = check_non_negative("distal.mass_kg", d.mass_kg)?;
            let c = check_non_negative("distal.damping_nm_s_per_rad", d.damping_nm_s_per_rad)?;
            if i0 > 0.01 {
                return Err(invalid(
                    "distal.inertia_kg_m2",
                    i0,
                    "must be at most 0.01 kg·m² (an instrument, not an arm)",
                ));
            }
            if m > 1.0 {
                return Err(invalid("distal.mass_kg", m, "must be at most 1 kg"));
            }
            if c > 1.0 {
                return Err(invalid(
                    "distal.damping_nm_s_per_rad",
                    c,
                    "must be at most 1 N·m·s/rad",
                ));
            }
            if i0 > 0.0 && c == 0.0 {
                return Err(invalid(
                    "distal.damping_nm_s_per_rad",
                    c,
                    "must be > 0 with a distal inertia (undamped, the shaft rattles in the play \
                     forever)",
                ));
            }
            if i0 == 0.0 && (m > 0.0 || c > 0.0) {
                return Err(invalid(
                    "distal.inertia_kg_m2",
                    i0,
                    "must be > 0 when mass_kg or damping_nm_s_per_rad is (the inertia at zero \
                     insertion); set all three to 0 for a massless shaft",
                ));
            }
            physics.distal = DistalParams {
                inertia_kg_m2: i0,
                mass_kg: m,
                damping_nm_s_per_rad: c,
            };
        }
        if let Some(g) = p.distal_gravity {
            let m = check_non_negative("distal_gravity.mass_kg", g.mass_kg)?;
            if m > 1.0 {
                return Err(invalid("distal_gravity.mass_kg", m, "must be at most 1 kg"));
            }
            let off = check_finite("distal_gravity.lever_offset_m", g.lever_offset_m)?;
            if off.abs() > 0.1 {
                return Err(invalid(
                    "distal_gravity.lever_offset_m",
                    off,
                    "must be within ±0.1 m (the mass sits on the instrument's distal part)",
                ));
            }
            for (i, v) in g.direction_rcm.iter().enumerate() {
                check_finite(&format!("distal_gravity.direction_rcm[{i}]"), *v)?;
            }
            let [x, y, z] = g.direction_rcm;
            let norm = (x * x + y * y + z * z).sqrt();
            if norm < 1e-6 {
                return Err(invalid(
                    "distal_gravity.direction_rcm",
                    format!("[{x}, {y}, {z}]"),
                    "must not be zero (a direction, normalised on loading)",
                ));
            }
            if m > 0.0 && !physics.distal.is_dynamic() {
                return Err(invalid(
                    "distal_gravity.mass_kg",
                    m,
                    "must be 0 with a massless shaft ([distal] all 0): the quasi-static shaft \
                     carries no weight",
                ));
            }
            physics.gravity = DistalGravity {
                mass_kg: m,
                lever_offset_m: off,
                direction_rcm: [x / norm, y / norm, z / norm],
            };
        } else if !physics.distal.is_dynamic() {
            physics.gravity = DistalGravity::NONE;
        }
        for (j, v) in p.initial_position.iter().enumerate() {
            let field = format!("initial_position[{j}]");
            check_finite(&field, *v)?;
            if *v < physics.position_min[j] || *v > physics.position_max[j] {
                return Err(invalid(
                    field,
                    v,
                    "outside the joint limits of a Classic PSM",
                ));
            }
        }
        let environment = match p.environment {
            EnvironmentParams::Free {} => Environment::Free,
            EnvironmentParams::Clamp {} => Environment::Clamp,
            EnvironmentParams::Divot {
                plate_stiffness_n_per_m,
                plate_damping_n_s_per_m,
                capture_depth_m,
            } => {
                check_positive(
                    "environment.plate_stiffness_n_per_m",
                    plate_stiffness_n_per_m,
                )?;
                if plate_stiffness_n_per_m > 1.0e6 {
                    return Err(invalid(
                        "environment.plate_stiffness_n_per_m",
                        plate_stiffness_n_per_m,
                        "must be at most 1e6 N/m (stability of the explicit step)",
                    ));
                }
                check_non_negative(
                    "environment.plate_damping_n_s_per_m",
                    plate_damping_n_s_per_m,
                )?;
                check_non_negative("environment.capture_depth_m", capture_depth_m)?;
                Environment::Divot {
                    plate_stiffness_n_per_m,
                    plate_damping_n_s_per_m,
                    capture_depth_m,
                }
            }
            EnvironmentParams::Surface {
                stiffness_n_per_m,
                gap_m,
                tilt_rad,
            } => {
                check_positive("environment.stiffness_n_per_m", stiffness_n_per_m)?;
                if stiffness_n_per_m > 1.0e6 {
                    return Err(invalid(
                        "environment.stiffness_n_per_m",
                        stiffness_n_per_m,
                        "must be at most 1e6 N/m (stability of the explicit step)",
                    ));
                }
                check_finite("environment.gap_m", gap_m)?;
                check_finite("environment.tilt_rad", tilt_rad)?;
                if tilt_rad.abs() > 1.2 {
                    return Err(invalid(
                        "environment.tilt_rad",
                        tilt_rad,
                        "must be within ±1.2 rad",
                    ));
                }
                Environment::Surface {
                    stiffness_n_per_m,
                    gap_m,
                    tilt_rad,
                }
            }
        };
        let motion = match p.motion {
            MotionParams::Hold {} => Motion::Hold,
            MotionParams::PushCycle {
                effort_amplitude_nm,
                period_s,
                insertion_force_n,
            } => {
                for (i, a) in effort_amplitude_nm.iter().enumerate() {
                    let field = format!("motion.effort_amplitude_nm[{i}]");
                    check_non_negative(&field, *a)?;
                    if *a > physics.pid[i].effort_limit {
                        return Err(invalid(
                            field,
                            a,
                            "exceeds the joint's effort limit (3.316 N·m)",
                        ));
                    }
                }
                check_positive("motion.period_s", period_s)?;
                check_non_negative("motion.insertion_force_n", insertion_force_n)?;
                if insertion_force_n > physics.pid[2].effort_limit {
                    return Err(invalid(
                        "motion.insertion_force_n",
                        insertion_force_n,
                        "exceeds the insertion effort limit (9.878 N)",
                    ));
                }
                Motion::PushCycle {
                    effort_amplitude_nm,
                    period_s,
                    insertion_force_n,
                }
            }
            MotionParams::Trajectory {
                amplitude,
                period_s,
            } => {
                for j in 0..NUM_JOINTS {
                    check_non_negative(&format!("motion.amplitude[{j}]"), amplitude[j])?;
                    check_positive(&format!("motion.period_s[{j}]"), period_s[j])?;
                    let (lo, hi) = (physics.position_min[j], physics.position_max[j]);
                    let c = p.initial_position[j];
                    if c - amplitude[j] < lo || c + amplitude[j] > hi {
                        return Err(invalid(
                            format!("motion.amplitude[{j}]"),
                            amplitude[j],
                            "initial_position ± amplitude leaves the joint limits",
                        ));
                    }
                }
                Motion::Trajectory {
                    amplitude,
                    period_s,
                }
            }
            MotionParams::MultiSine {
                amplitude,
                angular_frequency,
            } => {
                for j in 0..2 {
                    let mut reach = 0.0;
                    for k in 0..3 {
                        reach += check_non_negative(
                            &format!("motion.amplitude[{j}][{k}]"),
                            amplitude[j][k],
                        )?;
                        let w = angular_frequency[j][k];
                        let field = format!("motion.angular_frequency[{j}][{k}]");
                        check_positive(&field, w)?;
                        if w > 100.0 {
                            return Err(invalid(field, w, "must be at most 100 rad/s"));
                        }
                    }
                    let (lo, hi) = (physics.position_min[j], physics.position_max[j]);
                    let c = p.initial_position[j];
                    if c - reach < lo || c + reach > hi {
                        return Err(invalid(
                            format!("motion.amplitude[{j}]"),
                            format!("{:?}", amplitude[j]),
                            "initial_position ± the sum of the amplitudes leaves the joint limits",
                        ));
                    }
                }
                Motion::MultiSine {
                    amplitude,
                    angular_frequency,
                }
            }
            MotionParams::StartStop {
                speed_rad_per_s,
                move_s,
                still_s,
                ramp_s,
                start_s,
            } => {
                check_positive("motion.move_s", move_s)?;
                check_non_negative("motion.still_s", still_s)?;
                check_non_negative("motion.ramp_s", ramp_s)?;
                check_non_negative("motion.start_s", start_s)?;
                if 2.0 * ramp_s > move_s {
                    return Err(invalid(
                        "motion.ramp_s",
                        ramp_s,
                        "must be at most half of move_s (a rise and a fall per move)",
                    ));
                }
                for j in 0..2 {
                    let field = format!("motion.speed_rad_per_s[{j}]");
                    let v = check_finite(&field, speed_rad_per_s[j])?;
                    if v.abs() > 3.0 {
                        return Err(invalid(field, v, "must be within ±3 rad/s"));
                    }
                    let (lo, hi) = (physics.position_min[j], physics.position_max[j]);
                    let end = p.initial_position[j] + v * (move_s - ramp_s);
                    if !(lo..=hi).contains(&end) {
                        return Err(invalid(
                            field,
                            v,
                            "initial_position + speed * (move_s - ramp_s) leaves the joint limits",
                        ));
                    }
                }
                Motion::StartStop {
                    speed_rad_per_s,
                    move_s,
                    still_s,
                    ramp_s,
                    start_s,
                }
            }
        };
        let noise = NoiseParams {
            current_noise_amps: check_non_negative(
                "noise.current_noise_amps",
                p.noise.current_noise_amps,
            )?,
            pot_noise_volts: check_non_negative("noise.pot_noise_volts", p.noise.pot_noise_volts)?,
        };
        Ok(Self {
            description: p.description,
            seed: p.seed,
            dt_s: p.dt_s,
            initial_position: p.initial_position,
            environment,
            motion,
            noise,
            physics,
            ethernet: p.ethernet,
        })
    }

    /// The arm at its initial pose with the environment placed there.
    pub fn build_psm(&self) -> SimPsm {
        let mut psm = SimPsm::new(self.physics, self.initial_position);
        psm.set_environment(self.environment);
        psm
    }

    /// The driver of this scenario's motion, anchored at the initial pose.
    pub fn motion_driver(&self) -> MotionDriver {
        let plate = match self.environment {
            Environment::Divot {
                plate_stiffness_n_per_m,
                ..
            } => Some(plate_stiffness_n_per_m),
            _ => None,
        };
        MotionDriver {
            motion: self.motion,
            anchor: self.initial_position,
            plate_stiffness_n_per_m: plate,
        }
    }
}

/// Turns a [`Motion`] into setpoints over time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionDriver {
    motion: Motion,
    anchor: [f64; NUM_JOINTS],
    plate_stiffness_n_per_m: Option<f64>,
}

impl MotionDriver {
    /// A driver that never touches the setpoints.
    pub const HOLD: MotionDriver = MotionDriver {
        motion: Motion::Hold,
        anchor: [0.0; NUM_JOINTS],
        plate_stiffness_n_per_m: None,
    };

    pub fn motion(&self) -> Motion {
        self.motion
    }

    /// Set the setpoints for time `t_s` (no-op for `Hold`). No allocation.
    pub fn apply(&self, t_s: f64, psm: &mut SimPsm) {
        use core::f64::consts::TAU;
        match self.motion {
            Motion::Hold => {}
            Motion::PushCycle {
                effort_amplitude_nm,
                period_s,
                insertion_force_n,
            } => {
                let w = TAU / period_s;
                let l = self.anchor[2];
                let shaft = psm.params().shaft;
                for j in 0..2 {
                    // Joint 2 starts a quarter period later (no setpoint jump at t = 0).
                    let t = t_s - 0.25 * period_s * j as f64;
                    if t < 0.0 {
                        continue;
                    }
                    let reach = shaft.backlash_rad[j]
                        + shaft.compliance_rad_per_nm(j, l) * effort_amplitude_nm[j];
                    let (s, c) = (w * t).sin_cos();
                    psm.set_setpoint_with_velocity(j, self.anchor[j] + reach * s, reach * w * c);
                }
                if let Some(k) = self.plate_stiffness_n_per_m {
                    psm.set_setpoint(2, l + insertion_force_n / k);
                }
            }
            Motion::MultiSine {
                amplitude,
                angular_frequency,
            } => {
                for j in 0..2 {
                    let (q, v) = multi_sine(&amplitude[j], &angular_frequency[j], t_s);
                    psm.set_setpoint_with_velocity(j, self.anchor[j] + q, v);
                }
            }
            Motion::StartStop {
                speed_rad_per_s,
                move_s,
                still_s,
                ramp_s,
                start_s,
            } => {
                for (j, &v) in speed_rad_per_s.iter().enumerate() {
                    let (q, qd) = start_stop(v, move_s, still_s, ramp_s, start_s, t_s);
                    psm.set_setpoint_with_velocity(j, self.anchor[j] + q, qd);
                }
            }
            Motion::Trajectory {
                amplitude,
                period_s,
            } => {
                for j in 0..NUM_JOINTS {
                    if amplitude[j] == 0.0 {
                        continue;
                    }
                    let w = TAU / period_s[j];
                    let (s, c) = (w * t_s).sin_cos();
                    psm.set_setpoint_with_velocity(
                        j,
                        self.anchor[j] + amplitude[j] * s,
                        amplitude[j] * w * c,
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config_dir() -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sim")
    }

    const BASE: &str = r#"
seed = 1
dt_s = 0.0001
initial_position = [0.05, -0.1, 0.13, 0.0, 0.0, 0.0, 0.3]
[environment]
kind = "clamp"
[motion]
kind = "hold"
[noise]
current_noise_amps = 0.0
pot_noise_volts = 0.0
"#;

    /// Reads a scenario as the application does: TOML parsed outside this crate, then
    /// validated by [`Scenario::from_params`]. Parse errors come back as text.
    fn from_toml_str(text: &str) -> Result<Scenario, String> {
        let p: ScenarioParams = toml::from_str(text).map_err(|e| e.to_string())?;
        Scenario::from_params(p).map_err(|e| e.to_string())
    }

    #[test]
    fn every_config_sim_file_loads() {
        let mut names = Vec::new();
        for entry in std::fs::read_dir(config_dir()).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().and_then(|e| e.to_str()) != Some("toml") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let sc = from_toml_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            // Each one runs for a simulated second without leaving the limits.
            let mut psm = sc.build_psm();
            let drv = sc.motion_driver();
            for i in 0..(1.0 / sc.dt_s) as usize {
                drv.apply(i as f64 * sc.dt_s, &mut psm);
                psm.step(sc.dt_s);
            }
            assert!(psm.joint_state().position.iter().all(|v| v.is_finite()));
            names.push(path.file_name().unwrap().to_string_lossy().into_owned());
        }
        names.sort();
        for want in [
            "clamp.toml",
            "divot-push.toml",
            "free-motion.toml",
            "idle.toml",
        ] {
            assert!(
                names.iter().any(|n| n == want),
                "missing {want} in {names:?}"
            );
        }
    }

    #[test]
    fn base_scenario_parses() {
        let sc = from_toml_str(BASE).unwrap();
        assert_eq!(sc.environment, Environment::Clamp);
        assert_eq!(sc.motion, Motion::Hold);
        assert_eq!(sc.physics.shaft, ShaftParams::PAPER);
    }

    fn err_of(text: &str) -> String {
        from_toml_str(text).unwrap_err().to_string()
    }

    #[test]
    fn unknown_fields_are_rejected_with_their_name() {
        let e = err_of(&format!("{BASE}\nspeed = 3\n"));
        assert!(e.contains("speed"), "{e}");
        let e = err_of(&BASE.replace(
            "kind = \"clamp\"",
            "kind = \"clamp\"\nstiffness_n_per_m = 3.0",
        ));
        assert!(e.contains("stiffness_n_per_m"), "{e}");
        let e = err_of(&BASE.replace("kind = \"clamp\"", "kind = \"vice\""));
        assert!(e.contains("vice"), "{e}");
    }

    #[test]
    fn bad_values_name_field_and_value() {
        let e = err_of(&BASE.replace("dt_s = 0.0001", "dt_s = 0.5"));
        assert!(e.contains("dt_s") && e.contains("0.5"), "{e}");
        let e = err_of(&BASE.replace("0.13, 0.0, 0.0", "0.3, 0.0, 0.0"));
        assert!(
            e.contains("initial_position[2]") && e.contains("0.3"),
            "{e}"
        );
        let e = err_of(&BASE.replace("current_noise_amps = 0.0", "current_noise_amps = -1.0"));
        assert!(
            e.contains("noise.current_noise_amps") && e.contains("-1"),
            "{e}"
        );
        let e = err_of(&BASE.replace(
            "kind = \"clamp\"",
            "kind = \"surface\"\nstiffness_n_per_m = 0.0\ngap_m = 0.0\ntilt_rad = 0.0",
        ));
        assert!(
            e.contains("environment.stiffness_n_per_m") && e.contains('0'),
            "{e}"
        );
        let e = err_of(&BASE.replace(
            "kind = \"hold\"",
            "kind = \"push_cycle\"\neffort_amplitude_nm = [5.0, 1.0]\nperiod_s = 10.0\ninsertion_force_n = 1.0",
        ));
        assert!(
            e.contains("motion.effort_amplitude_nm[0]") && e.contains('5'),
            "{e}"
        );
        let shaft = "\n[shaft]\ninverse_compliance_j1 = [0.0, 0.0, 0.0, -1.0]\ninverse_compliance_j2 = [0.0, 0.0, 0.0, 20.0]\nbacklash_rad = [0.003, 0.0017]\ninsertion_range_m = [0.05, 0.24]\n";
        let e = err_of(&format!("{BASE}{shaft}"));
        assert!(
            e.contains("shaft.inverse_compliance_j1") && e.contains("-1"),
            "{e}"
        );
    }

    #[test]
    fn custom_shaft_is_used() {
        let shaft = "\n[shaft]\ninverse_compliance_j1 = [0.0, 0.0, 0.0, 20.0]\ninverse_compliance_j2 = [0.0, 0.0, 0.0, 30.0]\nbacklash_rad = [0.001, 0.002]\ninsertion_range_m = [0.05, 0.24]\n";
        let sc = from_toml_str(&format!("{BASE}{shaft}")).unwrap();
        assert_eq!(sc.physics.shaft.stiffness_nm_per_rad(0, 0.1), 20.0);
        assert_eq!(sc.physics.shaft.backlash_rad, [0.001, 0.002]);
    }

    #[test]
    fn distal_gravity_defaults_field_by_field_is_normalised_and_checked() {
        // Absent: the Classic 8 mm instrument's weight; absent with a massless shaft: none.
        assert_eq!(
            from_toml_str(BASE).unwrap().physics.gravity,
            DistalGravity::CLASSIC_8MM
        );
        let massless =
            "\n[distal]\ninertia_kg_m2 = 0.0\nmass_kg = 0.0\ndamping_nm_s_per_rad = 0.0\n";
        assert_eq!(
            from_toml_str(&format!("{BASE}{massless}"))
                .unwrap()
                .physics
                .gravity,
            DistalGravity::NONE
        );
        let sc = from_toml_str(&format!(
            "{BASE}\n[distal_gravity]\nmass_kg = 0.03\ndirection_rcm = [0.0, 0.0, -2.0]\n"
        ))
        .unwrap();
        assert_eq!(sc.physics.gravity.mass_kg, 0.03);
        assert_eq!(sc.physics.gravity.direction_rcm, [0.0, 0.0, -1.0]);
        assert_eq!(sc.physics.gravity.lever_offset_m, 0.0);
        let e = err_of(&format!(
            "{BASE}\n[distal_gravity]\ndirection_rcm = [0.0, 0.0, 0.0]\n"
        ));
        assert!(e.contains("distal_gravity.direction_rcm"), "{e}");
        let e = err_of(&format!("{BASE}\n[distal_gravity]\nmass_kg = -0.5\n"));
        assert!(
            e.contains("distal_gravity.mass_kg") && e.contains("-0.5"),
            "{e}"
        );
        let e = err_of(&format!(
            "{BASE}{massless}\n[distal_gravity]\nmass_kg = 0.02\n"
        ));
        assert!(
            e.contains("distal_gravity.mass_kg") && e.contains("massless"),
            "{e}"
        );
        let e = err_of(&format!("{BASE}\n[distal_gravity]\nmass = 0.1\n"));
        assert!(e.contains("mass"), "{e}");
    }

    #[test]
    fn distal_section_defaults_field_by_field_and_is_checked() {
        // Absent: the Classic 8 mm instrument.
        assert_eq!(
            from_toml_str(BASE).unwrap().physics.distal,
            DistalParams::CLASSIC_8MM
        );
        let sc = from_toml_str(&format!("{BASE}\n[distal]\nmass_kg = 0.05\n")).unwrap();
        assert_eq!(sc.physics.distal.mass_kg, 0.05);
        assert_eq!(
            sc.physics.distal.inertia_kg_m2,
            DistalParams::CLASSIC_8MM.inertia_kg_m2
        );
        let massless =
            "\n[distal]\ninertia_kg_m2 = 0.0\nmass_kg = 0.0\ndamping_nm_s_per_rad = 0.0\n";
        let sc = from_toml_str(&format!("{BASE}{massless}")).unwrap();
        assert_eq!(sc.physics.distal, DistalParams::MASSLESS);
        let e = err_of(&format!("{BASE}\n[distal]\ninertia_kg_m2 = 0.0\n"));
        assert!(
            e.contains("distal.inertia_kg_m2") && e.contains("> 0"),
            "{e}"
        );
        let e = err_of(&format!("{BASE}\n[distal]\nmass_kg = -1.0\n"));
        assert!(e.contains("distal.mass_kg") && e.contains("-1"), "{e}");
        let e = err_of(&format!("{BASE}\n[distal]\nmass = 0.1\n"));
        assert!(e.contains("mass"), "{e}");
    }

    #[test]
    fn multi_sine_is_a_file_kind_and_stays_in_the_limits() {
        let ms = "kind = \"multi_sine\"\namplitude = [[0.25, 0.12, 0.05], [0.18, 0.09, 0.04]]\nangular_frequency = [[1.43, 3.1, 6.9], [1.67, 3.7, 6.1]]";
        let sc = from_toml_str(&BASE.replace("kind = \"hold\"", ms)).unwrap();
        assert!(matches!(sc.motion, Motion::MultiSine { .. }));
        let wide = ms.replace("0.25, 0.12", "1.5, 0.12");
        let e = err_of(&BASE.replace("kind = \"hold\"", &wide));
        assert!(e.contains("motion.amplitude[0]"), "{e}");
        let fast = ms.replace("6.9", "-6.9");
        let e = err_of(&BASE.replace("kind = \"hold\"", &fast));
        assert!(e.contains("motion.angular_frequency[0][2]"), "{e}");
    }

    #[test]
    fn push_cycle_reaches_the_requested_effort_in_a_divot() {
        let text = BASE
            .replace(
                "kind = \"clamp\"",
                "kind = \"divot\"\nplate_stiffness_n_per_m = 20000.0\nplate_damping_n_s_per_m = 50.0\ncapture_depth_m = 0.001",
            )
            .replace(
                "kind = \"hold\"",
                "kind = \"push_cycle\"\neffort_amplitude_nm = [1.5, 1.0]\nperiod_s = 8.0\ninsertion_force_n = 2.0",
            );
        let sc = from_toml_str(&text).unwrap();
        let mut psm = sc.build_psm();
        let drv = sc.motion_driver();
        let (mut lo, mut hi) = ([0.0f64; 2], [0.0f64; 2]);
        let tip0 = psm.truth().tip_position_m;
        let mut max_tip_move: f64 = 0.0;
        for i in 0..(16.0 / sc.dt_s) as usize {
            drv.apply(i as f64 * sc.dt_s, &mut psm);
            psm.step(sc.dt_s);
            let t = psm.truth();
            for j in 0..2 {
                lo[j] = lo[j].min(t.tau_ext_nm[j]);
                hi[j] = hi[j].max(t.tau_ext_nm[j]);
            }
            let d = ((t.tip_position_m[0] - tip0[0]).powi(2)
                + (t.tip_position_m[1] - tip0[1]).powi(2))
            .sqrt();
            max_tip_move = max_tip_move.max(d);
        }
        assert!(
            (hi[0] - 1.5).abs() < 0.1 && (lo[0] + 1.5).abs() < 0.1,
            "{lo:?} {hi:?}"
        );
        assert!(
            (hi[1] - 1.0).abs() < 0.1 && (lo[1] + 1.0).abs() < 0.1,
            "{lo:?} {hi:?}"
        );
        // The tip stays in the divot (axial compression only, 0.1 mm).
        assert!(max_tip_move < 2e-4, "{max_tip_move}");
    }

    #[test]
    fn start_stop_is_continuous_and_its_speed_is_the_derivative() {
        for ramp in [0.0, 0.01, 0.1] {
            let f = |t: f64| start_stop(0.4, 0.6, 0.5, ramp, 1.0, t);
            let h = 1e-6;
            let mut t: f64 = 0.0;
            let mut last = f(0.0).0;
            while t < 6.0 {
                t += 1e-3;
                let (q, v) = f(t);
                assert!((q - last).abs() <= 0.4e-3 + 1e-12, "{ramp} {t}");
                last = q;
                let num = (f(t + h).0 - f(t - h).0) / (2.0 * h);
                // A velocity step (ramp 0) has no derivative at the step itself.
                if ramp > 0.0 || (num - v).abs() < 1e-3 {
                    assert!((num - v).abs() < 1e-3, "{ramp} {t}: {num} {v}");
                }
                assert!(q > -1e-12 && q < 0.4 * 0.6 + 1e-12, "{ramp} {t}: {q}");
            }
            // Back at the start after every second move; still before start_s.
            assert!(f(1.0 + 2.0 * 1.1 - 0.2).0.abs() < 1e-12);
            assert_eq!(f(0.5), (0.0, 0.0));
        }
    }
}
