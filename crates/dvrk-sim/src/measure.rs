//! Measurement models: what the QLA's encoders, current ADCs and potentiometers report for a
//! given actuator state. Pure functions of their inputs plus a seeded [`SimRng`] for noise.
//!
//! Conversions are the inverses of sawRobotIO1394's (reference dvrk-board-protocol.md §5.1):
//! `pos = offset + counts·scale`, `I = bits·scale + offset`, `tau = I / effort_to_current`,
//! `V = bits·bits_to_voltage`, `pos = V·scale + offset`. The scales normally come from the arm's
//! IO config (`dvrk_io::IoConfig`); [`ActuatorScales::classic_psm`] holds the Classic PSM values of
//! reference §5.2 for tests that run without one.

use crate::rng::SimRng;

/// Encoder counter range: 24-bit counter started at mid-range (reference §2.3).
pub const ENCODER_MIDRANGE: i32 = 0x80_0000;

/// Conversion constants of one actuator, SI on one side and raw register bits on the other.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorScales {
    /// `encoder.bits_to_position` scale: rad (or m) per count, signed by direction.
    pub encoder_position_per_count: f64,
    /// `encoder.bits_to_position` offset (usually 0).
    pub encoder_offset: f64,
    /// `drive.bits_to_current` scale, A per ADC bit.
    pub current_amps_per_bit: f64,
    /// `drive.bits_to_current` offset, A.
    pub current_offset_amps: f64,
    /// `drive.effort_to_current` scale, A per N·m (A per N for insertion).
    pub amps_per_effort: f64,
    /// `drive.effort_to_current` offset, A (0 in the dVRK configs).
    pub effort_offset_amps: f64,
    /// `potentiometer.bits_to_voltage` scale, V per bit.
    pub pot_volts_per_bit: f64,
    /// `potentiometer.bits_to_voltage` offset, V.
    pub pot_volts_offset: f64,
    /// `potentiometer.voltage_to_position` scale, rad (m) per V.
    pub pot_position_per_volt: f64,
    /// `potentiometer.voltage_to_position` offset, rad (m).
    pub pot_offset: f64,
}

impl ActuatorScales {
    /// Classic PSM actuator `index0` (0..7) per reference §5.2. Potentiometer gains and offsets are
    /// per-robot calibration values; these put the pot's 0-4.5 V around the joint range.
    pub fn classic_psm(index0: usize) -> Self {
        const CPT: f64 = 14400.0;
        const WRIST_CPT: f64 = 4000.0;
        let i_fs = 6.25;
        let (dir, cpt, gear, kt): (f64, f64, f64, f64) = match index0 {
            0 | 1 => (-1.0, CPT, 56.50, 0.0438),
            2 => (1.0, CPT, 336.6, 0.0438),
            3 | 4 => (-1.0, WRIST_CPT, 11.71, 0.0438),
            _ => (1.0, WRIST_CPT, 11.71, 0.0438),
        };
        let revolute_scale = core::f64::consts::TAU / cpt / gear;
        let encoder = if index0 == 2 {
            // Insertion: 2π/CPT/gear turns into metres with the drive's lead; the dVRK value is
            // 1.2963e-6 m per count (reference §5.2).
            dir * 1.2963e-6
        } else {
            dir * revolute_scale
        };
        let current_to_bits = dir * 32768.0 / i_fs;
        let (pot_gain, pot_offset) = if index0 == 2 {
            (0.06, 0.0)
        } else {
            (1.0, -2.25)
        };
        Self {
            encoder_position_per_count: encoder,
            encoder_offset: 0.0,
            current_amps_per_bit: 1.0 / current_to_bits,
            current_offset_amps: -dir * i_fs,
            amps_per_effort: 1.0 / (gear * kt),
            effort_offset_amps: 0.0,
            pot_volts_per_bit: 4.5 / 65536.0,
            pot_volts_offset: 0.0,
            pot_position_per_volt: pot_gain,
            pot_offset,
        }
    }

    /// Signed encoder counts (relative to mid-range) nearest to `position`, saturated to the
    /// 24-bit counter.
    #[inline]
    pub fn encoder_counts(&self, position: f64) -> i32 {
        let c = ((position - self.encoder_offset) / self.encoder_position_per_count).round();
        if c.is_finite() {
            c.clamp(
                -f64::from(ENCODER_MIDRANGE),
                f64::from(ENCODER_MIDRANGE - 1),
            ) as i32
        } else {
            0
        }
    }

    /// Position that `counts` decodes to (what the sidecar computes).
    #[inline]
    pub fn encoder_position(&self, counts: i32) -> f64 {
        self.encoder_offset + f64::from(counts) * self.encoder_position_per_count
    }

    /// Encoder velocity in counts per second for an actuator velocity in SI units.
    #[inline]
    pub fn encoder_velocity_counts_per_s(&self, velocity: f64) -> f64 {
        velocity / self.encoder_position_per_count
    }

    /// 16-bit ADC reading of the motor current for `effort` (N·m or N) plus `noise_amps`.
    #[inline]
    pub fn current_bits(&self, effort: f64, noise_amps: f64) -> u16 {
        let amps = effort * self.amps_per_effort + self.effort_offset_amps + noise_amps;
        adc16((amps - self.current_offset_amps) / self.current_amps_per_bit)
    }

    /// Effort that ADC `bits` decode to.
    #[inline]
    pub fn effort_from_current_bits(&self, bits: u16) -> f64 {
        (f64::from(bits) * self.current_amps_per_bit + self.current_offset_amps)
            / self.amps_per_effort
    }

    /// 16-bit potentiometer reading for `position` plus `noise_volts`.
    #[inline]
    pub fn pot_bits(&self, position: f64, noise_volts: f64) -> u16 {
        let volts = (position - self.pot_offset) / self.pot_position_per_volt + noise_volts;
        adc16((volts - self.pot_volts_offset) / self.pot_volts_per_bit)
    }
}

#[inline]
fn adc16(v: f64) -> u16 {
    if v.is_finite() {
        v.round().clamp(0.0, 65535.0) as u16
    } else {
        0
    }
}

/// Measurement noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseParams {
    /// Standard deviation of the motor-current measurement, A.
    pub current_noise_amps: f64,
    /// Standard deviation of the potentiometer voltage, V.
    pub pot_noise_volts: f64,
}

impl NoiseParams {
    pub const NONE: NoiseParams = NoiseParams {
        current_noise_amps: 0.0,
        pot_noise_volts: 0.0,
    };
}

/// The analog side of one sample: ADC words with fresh noise.
#[derive(Clone, Debug)]
pub struct Sensors {
    noise: NoiseParams,
    rng: SimRng,
}

impl Sensors {
    pub fn new(noise: NoiseParams, seed: u64) -> Self {
        Self {
            noise,
            rng: SimRng::new(seed),
        }
    }

    pub fn noise(&self) -> NoiseParams {
        self.noise
    }

    /// ADC quadlet (pot in bits 31-16, current in bits 15-0) for one actuator.
    #[inline]
    pub fn adc_quadlet(&mut self, s: &ActuatorScales, position: f64, effort: f64) -> u32 {
        let cur = s.current_bits(effort, self.rng.normal(self.noise.current_noise_amps));
        let pot = s.pot_bits(position, self.rng.normal(self.noise.pot_noise_volts));
        (u32::from(pot) << 16) | u32::from(cur)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_scales_match_reference_5_2() {
        let a1 = ActuatorScales::classic_psm(0);
        assert!((a1.encoder_position_per_count + 7.7227e-6).abs() < 1e-9);
        assert!((a1.current_amps_per_bit + 1.90735e-4).abs() < 1e-9);
        assert!((a1.current_offset_amps - 6.25).abs() < 1e-12);
        assert!((a1.amps_per_effort - 0.40409).abs() < 1e-5);
        let a3 = ActuatorScales::classic_psm(2);
        assert!((a3.encoder_position_per_count - 1.2963e-6).abs() < 1e-15);
        assert!((a3.amps_per_effort - 0.067828).abs() < 1e-6);
        assert!((a3.current_offset_amps + 6.25).abs() < 1e-12);
        let a4 = ActuatorScales::classic_psm(3);
        assert!((a4.encoder_position_per_count + 1.34141e-4).abs() < 1e-8);
        assert!((a4.amps_per_effort - 1.94970).abs() < 1e-4);
        assert!(ActuatorScales::classic_psm(5).encoder_position_per_count > 0.0);
    }

    #[test]
    fn encoder_round_trip_is_within_half_a_count() {
        let s = ActuatorScales::classic_psm(0);
        for i in -1000..1000 {
            let q = f64::from(i) * 1.234e-4;
            let back = s.encoder_position(s.encoder_counts(q));
            assert!((back - q).abs() <= 0.5 * s.encoder_position_per_count.abs() + 1e-15);
        }
        assert_eq!(s.encoder_counts(f64::NAN), 0);
        assert_eq!(s.encoder_counts(1e12), -ENCODER_MIDRANGE);
    }

    #[test]
    fn zero_current_is_midscale_and_effort_round_trips() {
        let s = ActuatorScales::classic_psm(0);
        assert_eq!(s.current_bits(0.0, 0.0), 32768);
        for tau in [-3.0, -1.5, -0.1, 0.0, 0.2, 1.5, 3.3] {
            let back = s.effort_from_current_bits(s.current_bits(tau, 0.0));
            // One bit is 0.19 mA, i.e. 0.47 mN·m on joint 1.
            assert!(
                (back - tau).abs() < 0.5 * 1.90735e-4 / 0.40409 + 1e-12,
                "{tau} -> {back}"
            );
        }
        // Saturation, not wrap-around.
        assert_eq!(s.current_bits(100.0, 0.0), 0);
        assert_eq!(s.current_bits(-100.0, 0.0), 65535);
    }

    #[test]
    fn noise_is_seeded_and_has_the_configured_size() {
        let s = ActuatorScales::classic_psm(0);
        let noise = NoiseParams {
            current_noise_amps: 0.002,
            pot_noise_volts: 0.0,
        };
        let mut a = Sensors::new(noise, 5);
        let mut b = Sensors::new(noise, 5);
        let n = 20_000;
        let mut sum2 = 0.0;
        for _ in 0..n {
            let qa = a.adc_quadlet(&s, 0.1, 0.5);
            assert_eq!(qa, b.adc_quadlet(&s, 0.1, 0.5));
            let amps = f64::from(qa as u16) * s.current_amps_per_bit + s.current_offset_amps;
            let e = amps - 0.5 * s.amps_per_effort;
            sum2 += e * e;
        }
        let sigma = (sum2 / f64::from(n)).sqrt();
        assert!((sigma - 0.002).abs() < 0.0002, "{sigma}");
    }
}
