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
//!   velocity allows over the host time elapsed between the two reads' completions (plus a
//!   small noise margin);
//! - each measured motor current is within the host current-check limit, 1.2·Imax + 50 mA
//!   (reference §7), plus a margin;
//! - where potentiometers are read, pots and encoders agree as the dVRK's own I/O layer requires
//!   (sawRobotIO1394 `mtsRobot1394::CheckState`): a sample is refused only once |pot − encoder|
//!   has stayed above the actuator's `distance` for longer than its `latency`, both from the io
//!   file when it has them (sawRobotIO1394 JSON `potentiometers.tolerances[]`, or this crate's
//!   TOML `potentiometer.tolerance`), else the dVRK's defaults ([`CLASSIC_PSM_POT_TOLERANCE`],
//!   [`SI_PSM_POT_TOLERANCE`]). Pots are noisy: a short excursion within the latency is not
//!   refused. The excursion's time runs from the first sample beyond the distance to the
//!   current one (sawRobotIO1394 also counts the board interval before the first sample: one
//!   I/O period, 0.67 ms at 1.5 kHz, earlier). It restarts on a sample within the distance, on a
//!   sample refused by another check, on a sample without pots and on [`SampleCheck::reset`].
//!
//! A jump that is real (the console re-homed, an encoder was preloaded) would otherwise be refused
//! for ever: after [`RESEED_AFTER`] consecutive samples that agree with each other and with every
//! other check, the new position is accepted as the new reference.
//!
//! Pure: no clock (times come in the samples), no allocation, no logging.

use crate::convert::{ArmSample, IoConfig, JointType, NUM_JOINTS, PotTolerance};

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
    /// Pot/encoder consistency rule; None: this actuator's pot is not checked (the io file has
    /// no pot calibration for it).
    pub pot: Option<PotTolerance>,
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

/// The dVRK's pot/encoder latency for every PSM actuator, 0.01 s (sawIntuitiveResearchKit
/// io-config generator, `potentiometerLatency`, Classic and Si).
pub const PSM_POT_LATENCY_S: f64 = 0.01;

/// The dVRK's pot/encoder tolerance of a Classic PSM, by actuator: 5° (5 mm for the insertion)
/// for 0.01 s (sawIntuitiveResearchKit io-config generator, `ClassicPSM`; board protocol
/// reference §5.2).
pub const CLASSIC_PSM_POT_TOLERANCE: [PotTolerance; NUM_JOINTS] = {
    let deg5 = PotTolerance {
        distance: f64::to_radians(5.0),
        latency: PSM_POT_LATENCY_S,
    };
    let mm5 = PotTolerance {
        distance: 0.005,
        latency: PSM_POT_LATENCY_S,
    };
    [deg5, deg5, mm5, deg5, deg5, deg5, deg5]
};

/// The dVRK's pot/encoder tolerance of an Si PSM, by actuator: 1°, 1°, 2 mm, then 3° for the
/// four instrument actuators, for 0.01 s (sawIntuitiveResearchKit io-config generator,
/// `SiPSM`). Si pots are digital (a lookup table this crate does not read): these apply only
/// where an io file gives an Si actuator an analog pot calibration.
pub const SI_PSM_POT_TOLERANCE: [PotTolerance; NUM_JOINTS] = {
    let deg1 = PotTolerance {
        distance: f64::to_radians(1.0),
        latency: PSM_POT_LATENCY_S,
    };
    let mm2 = PotTolerance {
        distance: 0.002,
        latency: PSM_POT_LATENCY_S,
    };
    let deg3 = PotTolerance {
        distance: f64::to_radians(3.0),
        latency: PSM_POT_LATENCY_S,
    };
    [deg1, deg1, mm2, deg3, deg3, deg3, deg3]
};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlausibilityLimits {
    pub actuators: [ActuatorBounds; NUM_JOINTS],
}

impl PlausibilityLimits {
    /// Limits of a Classic PSM (reference §5.2: soft limits ±91°, ±53°, 0–0.24 m, ±174° for
    /// actuators 4–7), with current limits and pot tolerances from `cfg` (pot tolerance
    /// default [`CLASSIC_PSM_POT_TOLERANCE`]; no pot check where `cfg` has no pot calibration).
    pub fn classic_psm(cfg: &IoConfig) -> Self {
        Self::psm(cfg, CLASSIC_PSM_SOFT_LIMITS, CLASSIC_PSM_POT_TOLERANCE)
    }

    /// Limits of an Si PSM (reference psm-kinematics §1.2: yaw ±2.964, pitch −1.265…+1.301,
    /// insertion 0–0.29 m), with current limits and pot tolerances from `cfg` (default
    /// [`SI_PSM_POT_TOLERANCE`]).
    pub fn si_psm(cfg: &IoConfig) -> Self {
        Self::psm(cfg, SI_PSM_SOFT_LIMITS, SI_PSM_POT_TOLERANCE)
    }

    fn psm(
        cfg: &IoConfig,
        [yaw, pitch, insertion]: [[f64; 2]; 3],
        pot_default: [PotTolerance; NUM_JOINTS],
    ) -> Self {
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
                pot: a
                    .potentiometer
                    .map(|p| p.tolerance.unwrap_or(pot_default[i])),
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
    #[error(
        "actuator {actuator}: pot {pot} and encoder {encoder} disagree by more than {distance} \
         for {for_s} s (latency {latency} s)"
    )]
    PotMismatch {
        actuator: u8,
        pot: f64,
        encoder: f64,
        distance: f64,
        /// How long the disagreement has lasted (0 for a pot that is not a number).
        for_s: f64,
        latency: f64,
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
    /// Per actuator: host time of the first sample of the current pot/encoder disagreement.
    pot_over_since: [Option<u64>; NUM_JOINTS],
    counters: PlausibilityCounters,
}

impl SampleCheck {
    pub fn new(limits: PlausibilityLimits) -> Self {
        Self {
            limits,
            reference: None,
            candidate: None,
            pot_over_since: [None; NUM_JOINTS],
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
        self.pot_over_since = [None; NUM_JOINTS];
    }

    /// Checks one sample at its own time, `s.t_ns` ([`SampleCheck::check_at`]).
    pub fn check(
        &mut self,
        s: &ArmSample,
        actuator_position: &[f64; NUM_JOINTS],
        current_amps: &[f64; NUM_JOINTS],
        pots: Option<&[f64; NUM_JOINTS]>,
    ) -> Result<(), Implausible> {
        self.check_at(s.t_ns, s, actuator_position, current_amps, pots)
    }

    /// Checks one sample read at host time `t_ns`. `actuator_position` and `current_amps` are in
    /// actuator space (the reader's [`crate::reader::ArmReader::last_actuators`]); `pots`, when
    /// read, too ([`crate::reader::ArmReader::pots`]; NaN for an actuator without pot
    /// calibration).
    ///
    /// `t_ns` should be when the read completed, not when it was asked: the boards latch the
    /// encoders when they answer, and a read that waited (a register asked again, the host
    /// preempted between its clock reading and the request) has its values from late in that
    /// wait. Timed from the requests, the cycle after a slow read would be granted the slow
    /// read's wait as motion time: at 40 rad/s, 1 ms more lets 0.04 rad of a flipped encoder bit
    /// through.
    pub fn check_at(
        &mut self,
        t_ns: u64,
        s: &ArmSample,
        actuator_position: &[f64; NUM_JOINTS],
        current_amps: &[f64; NUM_JOINTS],
        pots: Option<&[f64; NUM_JOINTS]>,
    ) -> Result<(), Implausible> {
        let r = self
            .static_checks(s, actuator_position, current_amps)
            .and_then(|()| self.pot_check(t_ns, actuator_position, pots));
        if let Err(e) = r {
            if !matches!(e, Implausible::PotMismatch { .. }) {
                // The pots of a sample refused for another reason prove nothing either way.
                self.pot_over_since = [None; NUM_JOINTS];
            }
            self.count(&e);
            return r;
        }
        let Some((t_ref, p_ref)) = self.reference else {
            self.accept(t_ns, actuator_position);
            return Ok(());
        };
        match self.jump(t_ref, &p_ref, t_ns, actuator_position) {
            Ok(()) => {
                self.accept(t_ns, actuator_position);
                Ok(())
            }
            Err(e) => {
                // Does it agree with the previous refused sample? Then it may be real.
                let agrees = self.candidate.is_some_and(|(t_c, p_c, _)| {
                    self.jump(t_c, &p_c, t_ns, actuator_position).is_ok()
                });
                let n = if agrees {
                    self.candidate.map_or(1, |(_, _, n)| n.saturating_add(1))
                } else {
                    1
                };
                if n >= RESEED_AFTER {
                    self.counters.reseeds += 1;
                    self.accept(t_ns, actuator_position);
                    return Ok(());
                }
                self.candidate = Some((t_ns, *actuator_position, n));
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
        }
        Ok(())
    }

    /// The dVRK's pot/encoder rule at host time `t_ns`: every checked actuator's disagreement
    /// is followed (no early return), the first one older than its latency is the error.
    fn pot_check(
        &mut self,
        t_ns: u64,
        p: &[f64; NUM_JOINTS],
        pots: Option<&[f64; NUM_JOINTS]>,
    ) -> Result<(), Implausible> {
        let Some(pots) = pots else {
            self.pot_over_since = [None; NUM_JOINTS];
            return Ok(());
        };
        let mut first: Option<Implausible> = None;
        for (i, b) in self.limits.actuators.iter().enumerate() {
            let since = &mut self.pot_over_since[i];
            let Some(tol) = b.pot else {
                *since = None;
                continue;
            };
            let (pot, encoder, actuator) = (pots[i], p[i], i as u8);
            let mismatch = |for_s| Implausible::PotMismatch {
                actuator,
                pot,
                encoder,
                distance: tol.distance,
                for_s,
                latency: tol.latency,
            };
            if !pot.is_finite() {
                // A calibrated pot that converts to no number: a broken reading, not noise.
                *since = None;
                first.get_or_insert(mismatch(0.0));
                continue;
            }
            if (pot - encoder).abs() <= tol.distance {
                *since = None;
                continue;
            }
            let start = *since.get_or_insert(t_ns);
            let for_s = t_ns.saturating_sub(start) as f64 * 1e-9;
            if for_s > tol.latency {
                first.get_or_insert(mismatch(for_s));
            }
        }
        match first {
            Some(e) => Err(e),
            None => Ok(()),
        }
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
            pot: Some(PotTolerance {
                distance: 0.05,
                latency: 0.01,
            }),
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

    /// A read asked at 0 ms that completed at 10 ms (a register asked again), then one asked at
    /// 10 ms that completed at 11 ms: 1 ms of motion, not 10, between the two samples' values.
    #[test]
    fn a_slow_reads_wait_is_not_motion_time_for_the_next_sample() {
        let jump = at(0, 0.02);
        // Timed by the requests, the flip passes: 0.021 allowed over 10 ms.
        let mut asked = checker();
        asked.check(&sample(0), &ZERO, &ZERO, None).unwrap();
        assert!(asked.check(&sample(10), &jump, &ZERO, None).is_ok());
        // Timed by the completions, it does not: 0.003 allowed over 1 ms.
        let mut done = checker();
        done.check_at(10_000_000, &sample(0), &ZERO, &ZERO, None)
            .unwrap();
        let e = done
            .check_at(11_000_000, &sample(10), &jump, &ZERO, None)
            .unwrap_err();
        assert!(
            matches!(e, Implausible::Jump { actuator: 0, dt_s, .. } if (dt_s - 1e-3).abs() < 1e-9),
            "{e:?}"
        );
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
            .check(&sample(0), &ZERO, &ZERO, Some(&at(3, f64::NAN)))
            .unwrap_err();
        assert!(
            matches!(e, Implausible::PotMismatch { actuator: 3, .. }),
            "a calibrated pot that is not a number is refused at once: {e}"
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

    /// Samples every millisecond with actuator 3's pot `offset` away from its encoder.
    fn pot_run(c: &mut SampleCheck, ms: std::ops::Range<u64>, offset: f64) -> Vec<bool> {
        ms.map(|t| {
            c.check(&sample(t), &ZERO, &ZERO, Some(&at(3, offset)))
                .is_ok()
        })
        .collect()
    }

    #[test]
    fn a_pot_excursion_shorter_than_the_latency_is_not_refused() {
        let mut c = checker();
        // Latency 10 ms: one sample, then 9 ms, beyond the 0.05 distance, then back.
        assert_eq!(pot_run(&mut c, 0..1, 0.2), [true]);
        assert_eq!(pot_run(&mut c, 1..2, 0.0), [true]);
        assert!(pot_run(&mut c, 2..12, 0.2).iter().all(|ok| *ok));
        // Back within the distance: the next excursion starts from zero again.
        assert!(pot_run(&mut c, 12..13, 0.04).iter().all(|ok| *ok));
        assert!(pot_run(&mut c, 13..23, -0.2).iter().all(|ok| *ok));
        assert_eq!(c.counters().pot_mismatches, 0);
    }

    #[test]
    fn a_persistent_pot_disagreement_is_refused_after_the_latency_and_recovers() {
        let mut c = checker();
        assert!(
            pot_run(&mut c, 0..10, 0.2).iter().all(|ok| *ok),
            "within 9 ms"
        );
        let e = c
            .check(&sample(11), &ZERO, &ZERO, Some(&at(3, 0.2)))
            .unwrap_err();
        match e {
            Implausible::PotMismatch {
                actuator: 3,
                pot,
                encoder,
                distance,
                for_s,
                latency,
            } => {
                assert_eq!((pot, encoder, distance, latency), (0.2, 0.0, 0.05, 0.01));
                assert!((for_s - 0.011).abs() < 1e-12, "{for_s}");
            }
            e => panic!("{e}"),
        }
        // Refused for as long as it lasts, however long.
        assert!(pot_run(&mut c, 12..500, 0.2).iter().all(|ok| !ok));
        assert_eq!(c.counters().pot_mismatches, 489);
        // Agreeing again: accepted at once, and a new excursion has its latency again.
        assert_eq!(pot_run(&mut c, 500..501, 0.01), [true]);
        assert!(pot_run(&mut c, 501..510, 0.2).iter().all(|ok| *ok));
        assert_eq!(c.counters().accepted, 10 + 1 + 9);
    }

    #[test]
    fn other_refusals_a_reset_and_missing_pots_restart_the_pot_latency() {
        let mut c = checker();
        assert!(pot_run(&mut c, 0..8, 0.2).iter().all(|ok| *ok));
        // Refused for its current: its pots say nothing, the excursion restarts.
        assert!(
            c.check(&sample(8), &ZERO, &at(0, 5.0), Some(&at(3, 0.2)))
                .is_err()
        );
        assert!(pot_run(&mut c, 9..19, 0.2).iter().all(|ok| *ok));
        c.reset();
        assert!(pot_run(&mut c, 19..29, 0.2).iter().all(|ok| *ok));
        assert!(c.check(&sample(29), &ZERO, &ZERO, None).is_ok());
        assert!(pot_run(&mut c, 30..40, 0.2).iter().all(|ok| *ok));
        assert_eq!(c.counters().pot_mismatches, 0);
        assert!(
            !pot_run(&mut c, 41..42, 0.2)[0],
            "and then the latency has passed"
        );
    }

    #[test]
    fn an_actuator_without_pot_calibration_is_not_checked() {
        // Only actuator 5 has a pot (the reader gives NaN for the others).
        let mut b = [bounds(); NUM_JOINTS];
        for (i, a) in b.iter_mut().enumerate() {
            if i != 4 {
                a.pot = None;
            }
        }
        let mut c = SampleCheck::new(PlausibilityLimits { actuators: b });
        let mut pots = [f64::NAN; NUM_JOINTS];
        pots[4] = 0.01;
        for t in 0..100 {
            pots[3] = 3.0;
            assert!(
                c.check(&sample(t), &ZERO, &ZERO, Some(&pots)).is_ok(),
                "{t}"
            );
        }
        pots[4] = 0.3;
        assert!(pot_run_with(&mut c, 100..110, &pots).iter().all(|ok| *ok));
        assert!(pot_run_with(&mut c, 111..112, &pots).iter().all(|ok| !ok));
    }

    fn pot_run_with(
        c: &mut SampleCheck,
        ms: std::ops::Range<u64>,
        pots: &[f64; NUM_JOINTS],
    ) -> Vec<bool> {
        ms.map(|t| c.check(&sample(t), &ZERO, &ZERO, Some(pots)).is_ok())
            .collect()
    }

    #[test]
    fn the_classic_psm_limits_follow_the_reference() {
        let params = toml::from_str(include_str!("../../../config/io/psm-classic.toml")).unwrap();
        let cfg = IoConfig::from_params(params).unwrap();
        let l = PlausibilityLimits::classic_psm(&cfg);
        assert!((l.actuators[0].position[1] - 91f64.to_radians()).abs() < 1e-12);
        assert_eq!(l.actuators[2].position, [0.0, 0.24]);
        assert!((l.actuators[0].max_current_amps - (1.2 * 1.34 + 0.05 + 0.1)).abs() < 1e-12);
        // The file calibrates no pot: none is checked.
        assert!(l.actuators.iter().all(|a| a.pot.is_none()));
    }

    #[test]
    fn pot_tolerances_come_from_the_io_file_else_the_dvrk_defaults() {
        let mut params: crate::convert::IoParams =
            toml::from_str(include_str!("../../../config/io/psm-classic.toml")).unwrap();
        let pot = |tolerance| crate::convert::PotentiometerParams {
            bits_to_voltage: crate::convert::Conversion::new(4.5 / 65536.0, 0.0),
            voltage_to_position: crate::convert::Conversion::new(1.0, -2.25),
            tolerance,
        };
        let own = PotTolerance {
            distance: 0.02,
            latency: 0.05,
        };
        params.actuators[0].potentiometer = Some(pot(Some(own)));
        params.actuators[2].potentiometer = Some(pot(None));
        params.actuators[4].potentiometer = Some(pot(None));
        let cfg = IoConfig::from_params(params).unwrap();
        let l = PlausibilityLimits::classic_psm(&cfg);
        assert_eq!(l.actuators[0].pot, Some(own));
        // 5 mm for the insertion, 5° for a wrist actuator, 0.01 s (dVRK io-config generator).
        assert_eq!(
            l.actuators[2].pot,
            Some(PotTolerance {
                distance: 0.005,
                latency: 0.01
            })
        );
        let wrist = l.actuators[4].pot.unwrap();
        assert!((wrist.distance - 5f64.to_radians()).abs() < 1e-15);
        assert_eq!(wrist.latency, 0.01);
        assert!(l.actuators[1].pot.is_none() && l.actuators[6].pot.is_none());
        let si = PlausibilityLimits::si_psm(&cfg);
        assert!((si.actuators[4].pot.unwrap().distance - 3f64.to_radians()).abs() < 1e-15);
        assert_eq!(si.actuators[2].pot.unwrap().distance, 0.002);
    }
}
