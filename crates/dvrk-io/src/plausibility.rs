//! Defense in depth for every sample: the checks the dVRK console's I/O layer applies before it
//! trusts a read (reference §5.2, §7), done on the sidecar's side so that a corrupted reply that
//! passed the wire checks (a real FPGA sends CRC 0; the UDP checksum is the only guard) is never
//! published as valid.
//!
//! A [`SampleCheck`] looks at one [`ArmSample`] per cycle, in actuator space (where the soft
//! limits of the I/O configuration live):
//! - every value is finite;
//! - each actuator position lies within its soft limits plus a margin;
//! - no position moved since the previous accepted sample by more than the actuator's maximum
//!   velocity allows over the elapsed host time (plus a small noise margin);
//! - each measured motor current is within the host current-check limit, 1.2·Imax + 50 mA
//!   (reference §7), plus a margin;
//! - where potentiometers are read, pots and encoders agree within the tolerance (§5.2: 5°, 5 mm).
//!
//! A jump that is real (the console re-homed, an encoder was preloaded) would otherwise be refused
//! for ever: after [`RESEED_AFTER`] consecutive samples that agree with each other and with every
//! other check, the new position is accepted as the new reference.
//!
//! Pure: no clock (times come in the samples), no allocation, no logging.

use crate::convert::{ArmSample, IoConfig, JointType, NUM_JOINTS};

/// Consistent samples in a row after which a refused jump is accepted as real.
pub const RESEED_AFTER: u8 = 3;

/// Bounds of one actuator, SI units (rad or m; per second for velocity; A for current).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorBounds {
    /// Soft position limits `[lower, upper]`.
    pub position: [f64; 2],
    /// Allowed excursion beyond the soft limits.
    pub position_margin: f64,
    /// Largest plausible speed.
    pub max_velocity: f64,
    /// Added to `max_velocity · dt` for encoder noise and quantisation.
    pub jump_margin: f64,
    /// Largest plausible |motor current| (A).
    pub max_current_amps: f64,
    /// Largest plausible pot/encoder disagreement, when pots are read.
    pub pot_tolerance: f64,
}

/// Limits of one arm, actuator order as in the I/O configuration.
/// Soft limits of joints 1-3 of a Classic PSM, `[lower, upper]`: yaw ±91°, pitch ±53° (rad),
/// insertion 0-0.24 m (board protocol reference §5.2).
pub const CLASSIC_PSM_SOFT_LIMITS: [[f64; 2]; 3] = [
    [-f64::to_radians(91.0), f64::to_radians(91.0)],
    [-f64::to_radians(53.0), f64::to_radians(53.0)],
    [0.0, 0.24],
];

/// Soft limits of joints 1-3 of an Si PSM: yaw ±2.964, pitch −1.265…+1.301 rad, insertion
/// 0-0.29 m (psm-kinematics reference §1.2).
pub const SI_PSM_SOFT_LIMITS: [[f64; 2]; 3] = [[-2.964, 2.964], [-1.265, 1.301], [0.0, 0.29]];

/// Soft limit of the wrist actuators 4-7 of a PSM, ±174° (board protocol reference §5.2).
pub const WRIST_ACTUATOR_SOFT_LIMIT_RAD: f64 = f64::to_radians(174.0);

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlausibilityLimits {
    pub actuators: [ActuatorBounds; NUM_JOINTS],
}

impl PlausibilityLimits {
    /// Limits of a Classic PSM (reference §5.2: soft limits ±91°, ±53°, 0–0.24 m, ±174° for
    /// actuators 4–7; pot tolerance 5° or 5 mm), with current limits from `cfg`.
    pub fn classic_psm(cfg: &IoConfig) -> Self {
        Self::psm(cfg, CLASSIC_PSM_SOFT_LIMITS)
    }

    /// Limits of an Si PSM (reference psm-kinematics §1.2: yaw ±2.964, pitch −1.265…+1.301,
    /// insertion 0–0.29 m), with current limits from `cfg`.
    pub fn si_psm(cfg: &IoConfig) -> Self {
        Self::psm(cfg, SI_PSM_SOFT_LIMITS)
    }

    fn psm(cfg: &IoConfig, [yaw, pitch, insertion]: [[f64; 2]; 3]) -> Self {
        let wrist = [
            -WRIST_ACTUATOR_SOFT_LIMIT_RAD,
            WRIST_ACTUATOR_SOFT_LIMIT_RAD,
        ];
        let actuators = core::array::from_fn(|i| {
            let a = &cfg.actuators()[i];
            let prismatic = a.joint_type == JointType::Prismatic;
            let position = match i {
                0 => yaw,
                1 => pitch,
                2 => insertion,
                _ => wrist,
            };
            ActuatorBounds {
                position,
                position_margin: if prismatic { 0.005 } else { 5f64.to_radians() },
                // Far above what the PSM's motors reach, far below what a flipped high bit of
                // an encoder count produces in one cycle.
                max_velocity: match i {
                    0 | 1 => 6.0,
                    2 => 0.6,
                    _ => 40.0,
                },
                jump_margin: if prismatic { 1e-4 } else { 2e-3 },
                max_current_amps: a.current_limit_amps() + 0.1,
                pot_tolerance: if prismatic { 0.005 } else { 5f64.to_radians() },
            }
        });
        Self { actuators }
    }
}

/// Why a sample was refused. `Copy`, numbers only: made on the per-cycle path.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Implausible {
    #[error("actuator {actuator}: value not finite")]
    NotFinite { actuator: u8 },
    #[error("actuator {actuator}: position {value} outside [{lower}, {upper}] plus margin")]
    OutOfLimits {
        actuator: u8,
        value: f64,
        lower: f64,
        upper: f64,
    },
    #[error("actuator {actuator}: moved {moved} in {dt_s} s, at most {allowed} is plausible")]
    Jump {
        actuator: u8,
        moved: f64,
        dt_s: f64,
        allowed: f64,
    },
    #[error("actuator {actuator}: motor current {amps} A beyond {max_amps} A")]
    Current {
        actuator: u8,
        amps: f64,
        max_amps: f64,
    },
    #[error("actuator {actuator}: pot {pot} and encoder {encoder} disagree")]
    PotMismatch {
        actuator: u8,
        pot: f64,
        encoder: f64,
    },
}

/// Counters by kind of refusal, for the binary's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlausibilityCounters {
    pub accepted: u64,
    pub not_finite: u64,
    pub out_of_limits: u64,
    pub jumps: u64,
    pub currents: u64,
    pub pot_mismatches: u64,
    /// Times a jump was accepted as real after [`RESEED_AFTER`] consistent samples.
    pub reseeds: u64,
}

impl PlausibilityCounters {
    /// Samples refused, all kinds.
    pub fn refused(&self) -> u64 {
        self.not_finite + self.out_of_limits + self.jumps + self.currents + self.pot_mismatches
    }
}

/// The per-arm checker, with the previous accepted sample as its state.
#[derive(Clone, Debug)]
pub struct SampleCheck {
    limits: PlausibilityLimits,
    /// Previous accepted sample: host time and actuator positions.
    reference: Option<(u64, [f64; NUM_JOINTS])>,
    /// A refused jump's position, and how many samples in a row have agreed with it.
    candidate: Option<(u64, [f64; NUM_JOINTS], u8)>,
    counters: PlausibilityCounters,
}

impl SampleCheck {
    pub fn new(limits: PlausibilityLimits) -> Self {
        Self {
            limits,
            reference: None,
            candidate: None,
            counters: PlausibilityCounters::default(),
        }
    }

    pub fn limits(&self) -> &PlausibilityLimits {
        &self.limits
    }

    pub fn counters(&self) -> PlausibilityCounters {
        self.counters
    }

    /// Forgets the previous sample (after a source restart): the next sample is checked against
    /// the static bounds only.
    pub fn reset(&mut self) {
        self.reference = None;
        self.candidate = None;
    }

    /// Checks one sample. `actuator_position` and `current_amps` are in actuator space (the
    /// reader's [`crate::reader::ArmReader::last_actuators`]); `pots`, when read, too.
    pub fn check(
        &mut self,
        s: &ArmSample,
        actuator_position: &[f64; NUM_JOINTS],
        current_amps: &[f64; NUM_JOINTS],
        pots: Option<&[f64; NUM_JOINTS]>,
    ) -> Result<(), Implausible> {
        let r = self.static_checks(s, actuator_position, current_amps, pots);
        if let Err(e) = r {
            self.count(&e);
            return r;
        }
        let Some((t_ref, p_ref)) = self.reference else {
            self.accept(s.t_ns, actuator_position);
            return Ok(());
        };
        match self.jump(t_ref, &p_ref, s.t_ns, actuator_position) {
            Ok(()) => {
                self.accept(s.t_ns, actuator_position);
                Ok(())
            }
            Err(e) => {
                // Does it agree with the previous refused sample? Then it may be real.
                let agrees = self.candidate.is_some_and(|(t_c, p_c, _)| {
                    self.jump(t_c, &p_c, s.t_ns, actuator_position).is_ok()
                });
                let n = if agrees {
                    self.candidate.map_or(1, |(_, _, n)| n.saturating_add(1))
                } else {
                    1
                };
                if n >= RESEED_AFTER {
                    self.counters.reseeds += 1;
                    self.accept(s.t_ns, actuator_position);
                    return Ok(());
                }
                self.candidate = Some((s.t_ns, *actuator_position, n));
                self.count(&e);
                Err(e)
            }
        }
    }

    fn accept(&mut self, t_ns: u64, p: &[f64; NUM_JOINTS]) {
        self.reference = Some((t_ns, *p));
        self.candidate = None;
        self.counters.accepted += 1;
    }

    fn count(&mut self, e: &Implausible) {
        let c = &mut self.counters;
        match e {
            Implausible::NotFinite { .. } => c.not_finite += 1,
            Implausible::OutOfLimits { .. } => c.out_of_limits += 1,
            Implausible::Jump { .. } => c.jumps += 1,
            Implausible::Current { .. } => c.currents += 1,
            Implausible::PotMismatch { .. } => c.pot_mismatches += 1,
        }
    }

    fn static_checks(
        &self,
        s: &ArmSample,
        p: &[f64; NUM_JOINTS],
        amps: &[f64; NUM_JOINTS],
        pots: Option<&[f64; NUM_JOINTS]>,
    ) -> Result<(), Implausible> {
        for (i, b) in self.limits.actuators.iter().enumerate() {
            let actuator = i as u8;
            let finite = p[i].is_finite()
                && amps[i].is_finite()
                && s.position[i].is_finite()
                && s.velocity[i].is_finite()
                && s.effort[i].is_finite();
            if !finite {
                return Err(Implausible::NotFinite { actuator });
            }
            let [lower, upper] = b.position;
            if p[i] < lower - b.position_margin || p[i] > upper + b.position_margin {
                return Err(Implausible::OutOfLimits {
                    actuator,
                    value: p[i],
                    lower,
                    upper,
                });
            }
            if amps[i].abs() > b.max_current_amps {
                return Err(Implausible::Current {
                    actuator,
                    amps: amps[i],
                    max_amps: b.max_current_amps,
                });
            }
            if let Some(pots) = pots
                && (!pots[i].is_finite() || (pots[i] - p[i]).abs() > b.pot_tolerance)
            {
                return Err(Implausible::PotMismatch {
                    actuator,
                    pot: pots[i],
                    encoder: p[i],
                });
            }
        }
        Ok(())
    }

    fn jump(
        &self,
        t_ref: u64,
        p_ref: &[f64; NUM_JOINTS],
        t_ns: u64,
        p: &[f64; NUM_JOINTS],
    ) -> Result<(), Implausible> {
        let dt_s = t_ns.saturating_sub(t_ref) as f64 * 1e-9;
        for (i, b) in self.limits.actuators.iter().enumerate() {
            let moved = (p[i] - p_ref[i]).abs();
            let allowed = b.max_velocity * dt_s + b.jump_margin;
            if moved > allowed {
                return Err(Implausible::Jump {
                    actuator: i as u8,
                    moved,
                    dt_s,
                    allowed,
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bounds() -> ActuatorBounds {
        ActuatorBounds {
            position: [-1.0, 1.0],
            position_margin: 0.1,
            max_velocity: 2.0,
            jump_margin: 0.001,
            max_current_amps: 1.0,
            pot_tolerance: 0.05,
        }
    }

    fn checker() -> SampleCheck {
        SampleCheck::new(PlausibilityLimits {
            actuators: [bounds(); NUM_JOINTS],
        })
    }

    fn sample(t_ms: u64) -> ArmSample {
        ArmSample {
            t_ns: t_ms * 1_000_000,
            valid: true,
            ..Default::default()
        }
    }

    const ZERO: [f64; NUM_JOINTS] = [0.0; NUM_JOINTS];

    fn at(i: usize, v: f64) -> [f64; NUM_JOINTS] {
        let mut p = ZERO;
        p[i] = v;
        p
    }

    #[test]
    fn a_position_beyond_the_limits_plus_margin_is_refused_and_named() {
        let mut c = checker();
        assert!(c.check(&sample(0), &at(2, 1.09), &ZERO, None).is_ok());
        let e = c
            .check(&sample(1000), &at(2, 1.2), &ZERO, None)
            .unwrap_err();
        assert!(
            matches!(e, Implausible::OutOfLimits { actuator: 2, .. }),
            "{e}"
        );
        assert_eq!(c.counters().out_of_limits, 1);
    }

    #[test]
    fn a_jump_faster_than_the_maximum_velocity_is_refused() {
        let mut c = checker();
        c.check(&sample(0), &ZERO, &ZERO, None).unwrap();
        // 10 ms at 2 rad/s: 0.02 + 0.001 allowed.
        assert!(c.check(&sample(10), &at(0, 0.02), &ZERO, None).is_ok());
        let e = c.check(&sample(20), &at(0, 0.5), &ZERO, None).unwrap_err();
        assert!(matches!(e, Implausible::Jump { actuator: 0, .. }), "{e}");
        // The next sample back where the arm was is fine: the reference was kept.
        assert!(c.check(&sample(30), &at(0, 0.03), &ZERO, None).is_ok());
    }

    #[test]
    fn an_isolated_bad_sample_never_becomes_the_reference() {
        let mut c = checker();
        c.check(&sample(0), &ZERO, &ZERO, None).unwrap();
        for k in 1..100u64 {
            let p = if k % 2 == 0 { at(1, 0.9) } else { ZERO };
            let r = c.check(&sample(k), &p, &ZERO, None);
            assert_eq!(r.is_ok(), k % 2 == 1, "sample {k}");
        }
        assert_eq!(c.counters().reseeds, 0);
    }

    #[test]
    fn a_real_jump_is_accepted_after_consistent_samples() {
        let mut c = checker();
        c.check(&sample(0), &ZERO, &ZERO, None).unwrap();
        assert!(c.check(&sample(1), &at(0, 0.8), &ZERO, None).is_err());
        assert!(c.check(&sample(2), &at(0, 0.8), &ZERO, None).is_err());
        assert!(c.check(&sample(3), &at(0, 0.8), &ZERO, None).is_ok());
        assert_eq!(c.counters().reseeds, 1);
        assert!(c.check(&sample(4), &at(0, 0.8), &ZERO, None).is_ok());
    }

    #[test]
    fn currents_pots_and_non_finite_values_are_checked() {
        let mut c = checker();
        let e = c.check(&sample(0), &ZERO, &at(4, -1.5), None).unwrap_err();
        assert!(matches!(e, Implausible::Current { actuator: 4, .. }), "{e}");
        let e = c
            .check(&sample(0), &ZERO, &ZERO, Some(&at(3, 0.2)))
            .unwrap_err();
        assert!(
            matches!(e, Implausible::PotMismatch { actuator: 3, .. }),
            "{e}"
        );
        let e = c
            .check(&sample(0), &at(5, f64::NAN), &ZERO, None)
            .unwrap_err();
        assert!(matches!(e, Implausible::NotFinite { actuator: 5 }), "{e}");
        let mut s = sample(0);
        s.effort[6] = f64::INFINITY;
        assert!(c.check(&s, &ZERO, &ZERO, None).is_err());
        assert_eq!(c.counters().refused(), 4);
        assert_eq!(c.counters().accepted, 0);
    }

    #[test]
    fn the_classic_psm_limits_follow_the_reference() {
        let params = toml::from_str(include_str!("../../../config/io/psm-classic.toml")).unwrap();
        let cfg = IoConfig::from_params(params).unwrap();
        let l = PlausibilityLimits::classic_psm(&cfg);
        assert!((l.actuators[0].position[1] - 91f64.to_radians()).abs() < 1e-12);
        assert_eq!(l.actuators[2].position, [0.0, 0.24]);
        assert!((l.actuators[0].max_current_amps - (1.2 * 1.34 + 0.05 + 0.1)).abs() < 1e-12);
    }
}
