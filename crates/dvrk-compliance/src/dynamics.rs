//! The internal-torque model (issue 10): what the joint effort holds besides the external torque.
//!
//! ```text
//! tau_ext = tau_meas - tau_0(q) - tau_f(qd, direction memory) - J(L) qdd        (joints 1, 2)
//! tau_f   = b qd + F_c s,   s = sgn(qd) while |qd| > v_s, else the sign of the last motion
//! J(L)    = J_0 + J_2 L^2                          (motor and arm, plus the distal mass at L)
//! ```
//!
//! The paper's quasi-static model counts every effort above `tau_0(q)` as external; while the arm
//! accelerates and its transmission rubs, that gives false corrections. The velocity and
//! acceleration come from the encoder positions by a causal filter: a least-squares cubic over the
//! samples of the last [`WINDOW_TIME_S`] ([`WINDOW`] at the boards' 1.5 kHz, more at a faster
//! rate, fewer at a slower one but at least [`MIN_WINDOW`]; their own timestamps, so jitter is
//! handled), evaluated two samples before the newest. That is exact for any cubic motion, has a
//! fixed delay of 2 cycles and no look-ahead, and averages the encoder quantization over the
//! window. Below `MIN_MOTION_MODEL_RATE_HZ` (model.rs) the compensator does not use the motion
//! model at all.
//!
//! The distal part's weight (issue 20 item 3) is optional in the model: a weight vector `w`
//! (N, in the RCM frame) lumped at the insertion L, which gives joint j the torque
//! `G_j(q, L) = L w . du/dq_j` on the shaft side of the play (`u` the shaft direction). The
//! torque-offset sweep measured in free space already holds the weight's reaction at its own
//! insertion `L_ref`, so the effort holds `-(L - L_ref) w . du/dq_j` beyond `tau_0(q)`; and
//! without contact the shaft spring carries `J_2 L^2 qdd - G_j`, which sets the side of the play
//! the shaft rests on ([`crate::Compensator`]). See [`DistalGravityParams`].
//!
//! In the parameter file the model is an optional table per joint (a file without it behaves as
//! before: `tau_ext = tau_meas - tau_0(q)`, gating at `tau_min`):
//!
//! ```toml
//! [joint.dynamics]
//! inertia_kg_m2 = [0.05, 0.0]        # J_0, J_2 of J(L) = J_0 + J_2 L^2 (kg·m², kg)
//! viscous_nm_s_per_rad = 0.2         # b
//! coulomb_nm = 0.03                  # F_c
//! stick_velocity_rad_per_s = 0.002   # v_s: below it the friction keeps its last direction
//! residual_std_nm = 0.004            # std of tau_ext in free space after the model (the fit's)
//! gate_sigmas = 4.0                  # correction only where |tau_ext| > tau_min + gate_sigmas * std
//! # optional: the distal part's weight (absent = not modelled)
//! distal_gravity = { weight_n = [0.078, 0.0, -0.162], weight_sigma_n = [0.004, 0.0, 0.02], reference_insertion_m = 0.155 }
//! ```
//!
//! [`JointDynamicsState`] is the stateful estimator: fixed-size ring buffers, no allocation per
//! step.

use crate::model::Quadrature;
use serde::{Deserialize, Serialize};

/// The samples of the filter's window at the boards' 1.5 kHz (and the least it needs to be
/// ready at any faster rate).
pub const WINDOW: usize = 48;
/// The time the filter's window spans (s): 47.5 periods of the boards' 1.5 kHz, so that there
/// the window is [`WINDOW`] samples exactly. At a faster rate (the console's I/O can run at
/// 3 kHz or more, and `serve` with `rate = "follow"` cycles at its pace) the window takes more
/// samples, up to [`WINDOW_CAPACITY`], so that it still spans this long: with 48 samples at
/// 3 kHz (16 ms) the acceleration came out several times noisier, the contact's evidence drowned
/// in it and `i20-free-from-rest` kept 74% of its raw error (14% at 1.5 kHz). At a slower rate
/// it takes fewer, at least [`MIN_WINDOW`]: 48 samples at 500 Hz (96 ms) lagged a start so much
/// that one cycle of `i20-play-crossing` was made 0.78 mm worse than raw (0.07 with 16).
pub const WINDOW_TIME_S: f64 = 47.5 / 1500.0;
/// How far back (s) the friction's direction checks that the joint moved the new way (see
/// [`JointDynamicsState::update`]): 8 ms, two encoder counts at the stick velocity of 2 mrad/s.
pub const DIRECTION_CHECK_S: f64 = 0.008;
/// The fewest samples fitted, however slow the rate (a cubic through fewer is noise).
pub const MIN_WINDOW: usize = 8;
/// The most samples the window holds: [`WINDOW_TIME_S`] at 6 kHz.
pub const WINDOW_CAPACITY: usize = 192;
/// Delay of the filter's estimate, in samples.
pub const DELAY_SAMPLES: usize = 2;
/// A longer gap between two samples restarts the filter (s). Shorter gaps (a few lost or
/// invalid cycles) need no restart: the fit uses the samples' own times.
pub const MAX_GAP_S: f64 = 0.02;

fn default_stick_velocity() -> f64 {
    0.002
}

fn default_gate_sigmas() -> f64 {
    4.0
}

/// `[joint.dynamics]` of a parameter file (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DynamicsParams {
    /// `[J_0, J_2]` of `J(L) = J_0 + J_2 L^2` (kg·m², kg).
    #[serde(deserialize_with = "crate::exact::array")]
    pub inertia_kg_m2: [f64; 2],
    /// Viscous friction `b` (N·m·s/rad).
    pub viscous_nm_s_per_rad: f64,
    /// Coulomb friction `F_c` (N·m).
    pub coulomb_nm: f64,
    /// Speed below which the friction keeps the direction of the last motion (rad/s).
    #[serde(default = "default_stick_velocity")]
    pub stick_velocity_rad_per_s: f64,
    /// Standard deviation of the model's torque residual in free space (N·m).
    pub residual_std_nm: f64,
    /// The gate: a correction needs `|tau_ext| > tau_min + gate_sigmas * residual_std_nm`
    /// (the paper's formula and the continuous ramp; the compensator's evidence weight uses
    /// `residual_std_nm` itself).
    #[serde(default = "default_gate_sigmas")]
    pub gate_sigmas: f64,
    /// The largest |acceleration| (rad/s²) in the fit's data (issue 20): beyond it the inertia
    /// term is an extrapolation, and the compensator shrinks the correction. Absent in files
    /// fitted before it existed; the compensator then assumes [`DEFAULT_MAX_ACCELERATION`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_acceleration_rad_per_s2: Option<f64>,
    /// The distal part's weight (issue 20 item 3). Absent in files fitted before it existed, or
    /// when the excitation could not separate it: not modelled (the shaft's side of the play
    /// then comes from the distal inertia alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distal_gravity: Option<DistalGravityParams>,
}

/// The distal part's weight as the dynamics model holds it (see the module docs): the weight
/// vector `w` lumped at the insertion L, so `G_j(q, L) = L w . du/dq_j`.
///
/// Its assumptions: the mass sits at L (a mass elsewhere along the shaft shows as a wrong `w`
/// where L differs from the excitation's depths), the RCM frame's tilt is fixed (a setup-joint
/// move needs a new fit), and the torque-offset sweep held the other joint near the pose of the
/// excitation (its `tau_0(q_j)` holds the weight at that pose).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistalGravityParams {
    /// `w`: the distal part's weight in the RCM frame (N). A component that joint's excitation
    /// cannot see (joint 1 has no lever for the y axis) is 0 with sigma 0.
    #[serde(deserialize_with = "crate::exact::array")]
    pub weight_n: [f64; 3],
    /// One standard deviation of each component of `w` (N), from the fit's residual with its
    /// correlation in time taken into account.
    #[serde(deserialize_with = "crate::exact::array")]
    pub weight_sigma_n: [f64; 3],
    /// The insertion (m) at which the torque-offset table was measured (the sweep's mean
    /// depth): the table holds the weight's reaction there.
    pub reference_insertion_m: f64,
}

/// `du/dq1` and `du/dq2` of the shaft direction `u = (sin q1 cos q2, -sin q2, -cos q1 cos q2)`
/// (RCM frame, the Classic PSM's modified DH at the zero wrist).
#[inline]
pub fn shaft_direction_derivatives(q1: f64, q2: f64) -> [[f64; 3]; 2] {
    let (s1, c1) = q1.sin_cos();
    let (s2, c2) = q2.sin_cos();
    [[c1 * c2, 0.0, s1 * c2], [-s1 * s2, -c2, c1 * s2]]
}

impl DistalGravityParams {
    /// `G_j` (N·m): the weight's torque on joint `j0` (0 = yaw, 1 = pitch) at joints `q1`, `q2`
    /// and insertion `insertion_m` (at least 0), positive along the joint.
    #[inline]
    pub fn torque_nm(&self, j0: usize, q1: f64, q2: f64, insertion_m: f64) -> f64 {
        let du = shaft_direction_derivatives(q1, q2)[j0.min(1)];
        let w = self.weight_n;
        insertion_m.max(0.0) * (w[0] * du[0] + w[1] * du[1] + w[2] * du[2])
    }

    /// One standard deviation (N·m) of [`DistalGravityParams::torque_nm`] from `weight_sigma_n`.
    #[inline]
    pub fn sigma_nm(&self, j0: usize, q1: f64, q2: f64, insertion_m: f64) -> f64 {
        let du = shaft_direction_derivatives(q1, q2)[j0.min(1)];
        let s = self.weight_sigma_n;
        insertion_m.max(0.0) * (s[0] * du[0]).quad(s[1] * du[1]).quad(s[2] * du[2])
    }

    /// What the effort holds beyond `tau_0(q)` for the weight (N·m): the reaction of
    /// `G_j` less the reaction the table holds at `reference_insertion_m`,
    /// `-(L - L_ref) w . du/dq_j`.
    #[inline]
    pub fn internal_torque_nm(&self, j0: usize, q1: f64, q2: f64, insertion_m: f64) -> f64 {
        let du = shaft_direction_derivatives(q1, q2)[j0.min(1)];
        let w = self.weight_n;
        -(insertion_m.max(0.0) - self.reference_insertion_m)
            * (w[0] * du[0] + w[1] * du[1] + w[2] * du[2])
    }
}

/// The acceleration range assumed for a dynamics model whose file does not state the fit's
/// (rad/s²): the multi-sine of `calibrate dynamics` reaches 4 rad/s².
pub const DEFAULT_MAX_ACCELERATION: f64 = 4.0;

impl DynamicsParams {
    /// `J(L)` in kg·m².
    #[inline]
    pub fn inertia(&self, insertion_m: f64) -> f64 {
        self.inertia_kg_m2[0] + self.inertia_kg_m2[1] * insertion_m * insertion_m
    }

    /// The friction torque `b qd + F_c s` for velocity `qd` and direction memory `s`.
    #[inline]
    pub fn friction(&self, velocity: f64, direction: f64) -> f64 {
        self.viscous_nm_s_per_rad * velocity + self.coulomb_nm * direction
    }

    /// The part of the dead band the residual adds: `gate_sigmas * residual_std_nm` (N·m).
    #[inline]
    pub fn gate_nm(&self) -> f64 {
        self.gate_sigmas * self.residual_std_nm
    }
}

/// Velocity and acceleration of one joint by the causal least-squares cubic (module docs).
#[derive(Clone, Debug)]
pub struct DerivativeFilter {
    t: [f64; WINDOW_CAPACITY],
    q: [f64; WINDOW_CAPACITY],
    /// Next slot to write.
    head: usize,
    len: usize,
    /// The window is full: [`WINDOW`] samples, or at a slower rate all that span
    /// [`WINDOW_TIME_S`].
    full: bool,
    /// The stream's typical sample interval (s): a running mean over about [`WINDOW`] samples
    /// in which one interval counts for at most twice the mean.
    typical_period_s: f64,
    /// Samples in the last fit.
    fitted: usize,
    /// RMS of the last cubic fit's residual (rad): how far the window's motion is from smooth.
    residual_rad: f64,
    /// Whether the last push restarted the history (a gap, time going back, non-finite input).
    restarted: bool,
}

impl Default for DerivativeFilter {
    fn default() -> Self {
        Self {
            t: [0.0; WINDOW_CAPACITY],
            q: [0.0; WINDOW_CAPACITY],
            head: 0,
            len: 0,
            full: false,
            typical_period_s: f64::INFINITY,
            fitted: 0,
            residual_rad: 0.0,
            restarted: false,
        }
    }
}

impl DerivativeFilter {
    /// Forgets the history (after a gap in the samples).
    pub fn reset(&mut self) {
        self.head = 0;
        self.len = 0;
        self.full = false;
        self.typical_period_s = f64::INFINITY;
        self.fitted = 0;
        self.residual_rad = 0.0;
    }

    /// The newest position minus the newest one at least `time_s` older (rad); 0 without one.
    pub fn recent_displacement(&self, time_s: f64) -> f64 {
        const CAP: usize = WINDOW_CAPACITY;
        if self.len < 2 {
            return 0.0;
        }
        let newest = (self.head + CAP - 1) % CAP;
        (1..self.len)
            .map(|k| (self.head + CAP - 1 - k) % CAP)
            .find(|&i| self.t[newest] - self.t[i] >= time_s)
            .map_or(0.0, |i| self.q[newest] - self.q[i])
    }

    /// How many samples the last estimate was fitted through (0 before the first).
    pub fn fitted_samples(&self) -> usize {
        self.fitted
    }

    /// The stream's typical sample interval (s): a running mean over about [`WINDOW`] samples
    /// in which a gap counts for at most twice the mean, so one gap or a late stamp barely moves
    /// it; `None` before two samples.
    pub fn typical_period_s(&self) -> Option<f64> {
        (self.len >= 2 && self.typical_period_s.is_finite()).then_some(self.typical_period_s)
    }

    /// RMS (rad) of the residual of the last cubic fit over the window: encoder quantization
    /// (a few µrad) while the motion is smooth, far more across a velocity step.
    pub fn residual_rad(&self) -> f64 {
        self.residual_rad
    }

    /// Whether the last [`DerivativeFilter::push`] restarted the history after a gap, a time
    /// that went back or a non-finite input (not at the very first sample).
    pub fn restarted(&self) -> bool {
        self.restarted
    }

    /// Whether the window is full, so the estimates are the filter's own (not start-up zeros).
    pub fn ready(&self) -> bool {
        self.full
    }

    /// Adds a sample at time `t_s` and returns `(velocity, acceleration)` at the sample
    /// [`DELAY_SAMPLES`] before it; zeros until the window holds enough samples for a cubic.
    /// Non-finite inputs reset the filter; a time that does not increase, or one more than
    /// [`MAX_GAP_S`] after the last sample, restarts it at this sample.
    pub fn push(&mut self, t_s: f64, q: f64) -> (f64, f64) {
        self.restarted = false;
        if !(t_s.is_finite() && q.is_finite()) {
            self.restarted = true;
            self.reset();
            return (0.0, 0.0);
        }
        const CAP: usize = WINDOW_CAPACITY;
        if self.len > 0 {
            let gap = t_s - self.t[(self.head + CAP - 1) % CAP];
            if gap.is_nan() || gap <= 0.0 || gap > MAX_GAP_S {
                self.restarted = true;
                self.reset();
            } else if self.len == 1 {
                self.typical_period_s = gap;
            } else {
                // The typical interval: a running mean that a gap moves by twice the mean at
                // most.
                let w = 1.0 / WINDOW as f64;
                self.typical_period_s +=
                    w * (gap.min(2.0 * self.typical_period_s) - self.typical_period_s);
            }
        }
        self.t[self.head] = t_s;
        self.q[self.head] = q;
        self.head = (self.head + 1) % CAP;
        self.len = (self.len + 1).min(CAP);
        if self.len < MIN_WINDOW {
            return (0.0, 0.0);
        }
        // The samples fitted: those within WINDOW_TIME_S of the newest sample, and at least
        // MIN_WINDOW.
        let newest = (self.head + CAP - 1) % CAP;
        let age = |k: usize| self.t[newest] - self.t[(self.head + CAP - 1 - k) % CAP];
        // At least as many samples as WINDOW_TIME_S holds at the stream's typical period: a
        // stamp that came late or a few lost cycles do not shorten the window (around them a
        // shorter cubic's acceleration is noisier, and a dynamics fit of a live recording on a
        // loaded machine came out 25% low with it).
        let typical = (WINDOW_TIME_S / self.typical_period_s + 1e-9).floor() as usize + 1;
        let mut n = self.len.min(typical.clamp(MIN_WINDOW, CAP));
        while n < self.len && age(n) <= WINDOW_TIME_S {
            n += 1;
        }
        self.full = self.len >= WINDOW || (n < self.len && n >= MIN_WINDOW);
        self.fitted = n;
        // The evaluation point: DELAY_SAMPLES before the newest sample; times relative to it,
        // scaled by the window span so the normal equations stay well conditioned.
        let at = (self.head + CAP - 1 - DELAY_SAMPLES) % CAP;
        let oldest = (self.head + CAP - n) % CAP;
        let (t0, q0) = (self.t[at], self.q[at]);
        let span = self.t[newest] - self.t[oldest];
        if span.is_nan() || span <= 0.0 {
            return (0.0, 0.0);
        }
        let points = (0..n).map(|k| {
            let i = (oldest + k) % CAP;
            ((self.t[i] - t0) / span, self.q[i] - q0)
        });
        match cubic_through(points) {
            // q(x) = c0 + c1 x + c2 x^2 + c3 x^3 with x = (t - t0) / span, at x = 0.
            Some(c) => {
                let mut ss = 0.0;
                for k in 0..n {
                    let i = (oldest + k) % CAP;
                    let x = (self.t[i] - t0) / span;
                    let e = self.q[i] - q0 - (((c[3] * x + c[2]) * x + c[1]) * x + c[0]);
                    ss += e * e;
                }
                self.residual_rad = (ss / n as f64).sqrt();
                (c[1] / span, 2.0 * c[2] / (span * span))
            }
            None => (0.0, 0.0),
        }
    }
}

/// Below this sample rate (Hz) the dynamics fit takes its derivatives from a centred cubic over
/// [`CENTRED_HALF_WIDTH_S`] on each side instead of the run-time causal filter: the causal
/// window of [`WINDOW`] samples spans 32 ms at the boards' 1.5 kHz, but 0.48 s at a console's
/// 100 Hz `measured_js`, too long for a cubic through the excitation. The simulator's excitation
/// recorded at 100 Hz was fitted with inertia 37% low, viscous friction 37% low and 4.5 times
/// the residual; centred, within a few %.
pub const CENTRED_BELOW_HZ: f64 = 500.0;
/// Half-width (s) of the centred cubic of [`CENTRED_BELOW_HZ`] (at least 3 samples each side).
pub const CENTRED_HALF_WIDTH_S: f64 = 0.05;

/// Velocity, acceleration and the sample they refer to, per sample of joint `j` (`None` where
/// there is no estimate), for the dynamics fit. At the boards' rates (at least
/// [`CENTRED_BELOW_HZ`]), the run-time causal filter, restarted at each of `starts` and after a
/// gap ([`MAX_GAP_S`]), skipping its first window. Below, a centred least-squares cubic over
/// [`CENTRED_HALF_WIDTH_S`] each side (at least 3 samples each side), within a segment and
/// with no gap over 3 times the median sample interval (`median_dt`) inside; `centred` takes the
/// centred cubic at any rate.
fn fit_derivatives(
    samples: &[DynamicsSample],
    j: usize,
    starts: &[usize],
    median_dt: f64,
    centred: bool,
) -> Vec<Option<(f64, f64, usize)>> {
    if !centred && median_dt <= 1.0 / CENTRED_BELOW_HZ {
        let mut filter = DerivativeFilter::default();
        let mut in_segment = 0;
        return samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                if starts.contains(&i) {
                    filter.reset();
                    in_segment = 0;
                }
                in_segment += 1;
                let (v, a) = filter.push(s.t_s, s.position[j]);
                // A gap inside a segment (lost samples of a live recording) restarts it too.
                (in_segment > WINDOW && filter.ready()).then(|| (v, a, i - DELAY_SAMPLES))
            })
            .collect();
    }
    let max_gap = (3.0 * median_dt).max(MAX_GAP_S);
    let half = CENTRED_HALF_WIDTH_S.max(3.0 * median_dt);
    // Segment boundaries: the starts and every gap.
    let mut segment = vec![0usize; samples.len()];
    let mut current = 0;
    for i in 0..samples.len() {
        let gap = i > 0 && samples[i].t_s - samples[i - 1].t_s > max_gap;
        if i > 0 && (starts.contains(&i) || gap) {
            current += 1;
        }
        segment[i] = current;
    }
    (0..samples.len())
        .map(|i| {
            let t0 = samples[i].t_s;
            let q0 = samples[i].position[j];
            let mut lo = i;
            while lo > 0 && segment[lo - 1] == segment[i] && t0 - samples[lo - 1].t_s <= half {
                lo -= 1;
            }
            let mut hi = i;
            while hi + 1 < samples.len()
                && segment[hi + 1] == segment[i]
                && samples[hi + 1].t_s - t0 <= half
            {
                hi += 1;
            }
            if i - lo < 3 || hi - i < 3 {
                return None;
            }
            let points = samples[lo..=hi]
                .iter()
                .map(|s| ((s.t_s - t0) / half, s.position[j] - q0));
            let c = cubic_through(points)?;
            Some((c[1] / half, 2.0 * c[2] / (half * half), i))
        })
        .collect()
}

/// The median interval between neighbouring samples (s; 0 for fewer than 2).
pub fn median_interval(samples: &[DynamicsSample]) -> f64 {
    let dts = sorted_intervals(&[samples]);
    dts.get(dts.len() / 2).copied().unwrap_or(0.0)
}

/// The intervals (s) between neighbouring samples of each segment, sorted.
fn sorted_intervals(segments: &[&[DynamicsSample]]) -> Vec<f64> {
    let mut dts: Vec<f64> = segments
        .iter()
        .flat_map(|seg| seg.windows(2).map(|w| w[1].t_s - w[0].t_s))
        .collect();
    dts.sort_by(f64::total_cmp);
    dts
}

/// The band, in multiples of their median, within which the intervals between a recording's rows
/// count as regular ([`interval_regularity`]).
pub const REGULAR_INTERVAL_BAND: [f64; 2] = [0.5, 1.5];

/// How regularly the rows of a recording come: the median interval (s) between neighbouring
/// rows of each segment (not across the gaps between segments, which are the recording's
/// depth changes) and the share of those intervals outside [`REGULAR_INTERVAL_BAND`] times it.
/// `None` without any interval. A service on a quiet machine leaves 2-4% of its 1.5 kHz
/// cycles' intervals outside the band, one on a loaded machine 13%.
pub fn interval_regularity(segments: &[&[DynamicsSample]]) -> Option<(f64, f64)> {
    let dts = sorted_intervals(segments);
    let median = *dts.get(dts.len() / 2)?;
    let band = REGULAR_INTERVAL_BAND[0] * median..=REGULAR_INTERVAL_BAND[1] * median;
    let outside = dts.iter().filter(|dt| !band.contains(dt)).count();
    Some((median, outside as f64 / dts.len() as f64))
}

/// How the excitation of a dynamics recording was commanded, which decides how the fit reads it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Excitation {
    /// Smooth at the rows' rate: the simulator's excitation applied at every physics step, or
    /// rows taken at the rate of the commands themselves (a console's `measured_js`). The fit
    /// differentiates the rows as they are ([`CENTRED_BELOW_HZ`]).
    #[default]
    Smooth,
    /// Set points held for `1 / commanded_hz` each (`servo_jp` through a console at its
    /// `measured_js` rate) and rows taken faster (a sidecar service at the boards' 1.5 kHz).
    /// The joint controller kicks at every step, so the effort ripples at the command rate and
    /// its harmonics (0.4 N·m for the simulated PSM's kp of 150 N·m/rad at 100 Hz) while the
    /// position barely shows it; fitted sample by sample the ripple biases the model (inertia
    /// 0.015 for 0.05 on the simulated console). The fit first averages every row (position,
    /// effort) over [`STEPPED_AVERAGE_PERIODS`] command periods centred on it, which cancels a
    /// ripple of that period exactly and, being linear, keeps the joint's equation of motion;
    /// then it takes the centred cubic's derivatives of the averaged rows. Rows no faster than
    /// 1.5 times `commanded_hz` are fitted as [`Excitation::Smooth`].
    Stepped { commanded_hz: f64 },
}

/// How many command periods a stepped excitation's rows are averaged over
/// ([`Excitation::Stepped`]). Any whole number cancels the ripple; what one period leaves is
/// the ripple sampled at stamps that are not the instants the boards were read (a service
/// beside a console on a loaded machine: rows 1-7 ms apart, each stamped when its batch of
/// registers completed), which the derivatives take for acceleration and which biases the
/// inertia toward zero. Two periods halve that noise's variance and attenuate the excitation
/// (sines up to 1.1 Hz) by under 0.1%. Measured on rows recorded beside the console stand-in
/// (the simulated arm's inertia 0.0502-0.0508 kg·m² over 0.10-0.20 m): a recording from a CI
/// run, one period 0.037 (the model explaining 45% of the effort's rms), two 0.046-0.050 (59%),
/// three 0.044-0.051, four 0.046-0.051; a quiet machine's, 0.049 / 0.051 / 0.051 / 0.030-0.058
/// (four periods leave too few independent rows to tell `J_2` from `J_0`).
pub const STEPPED_AVERAGE_PERIODS: f64 = 2.0;

impl Excitation {
    /// The time (s) to average rows `median_dt` apart over ([`median_interval`]):
    /// [`STEPPED_AVERAGE_PERIODS`] command periods, or `None` when they are fitted as
    /// [`Excitation::Smooth`].
    pub fn averaging_period(self, median_dt: f64) -> Option<f64> {
        match self {
            Self::Stepped { commanded_hz }
                if commanded_hz.is_finite()
                    && commanded_hz > 0.0
                    && median_dt > 0.0
                    && 1.0 / median_dt > 1.5 * commanded_hz =>
            {
                Some(STEPPED_AVERAGE_PERIODS / commanded_hz)
            }
            _ => None,
        }
    }
}

/// Every sample averaged (position and effort) over the period centred on it, as the time
/// average of the line through neighbouring samples (so irregular rows, a service that lost or
/// delayed a cycle, weigh each stretch by its length), and the segment starts of the result.
/// Samples whose period a segment's start or end (one of `starts`, or a gap over the period)
/// would cut are left out.
fn average_over_period(
    samples: &[DynamicsSample],
    starts: &[usize],
    period: f64,
) -> (Vec<DynamicsSample>, Vec<usize>) {
    let half = 0.5 * period;
    let mut segment = vec![0usize; samples.len()];
    for i in 1..samples.len() {
        let cut = starts.contains(&i) || samples[i].t_s - samples[i - 1].t_s > period;
        segment[i] = segment[i - 1] + usize::from(cut);
    }
    let mut out = Vec::with_capacity(samples.len());
    let mut out_starts = Vec::new();
    let mut last_segment = None;
    let mut lo = 0usize;
    for i in 0..samples.len() {
        let (a, b) = (samples[i].t_s - half, samples[i].t_s + half);
        // lo: the last sample at or before a, in this segment
        while lo + 1 < samples.len() && samples[lo + 1].t_s <= a {
            lo += 1;
        }
        if segment[lo] != segment[i] || samples[lo].t_s > a {
            continue;
        }
        let mut avg = DynamicsSample {
            t_s: samples[i].t_s,
            position: [0.0; 3],
            effort_nm: [0.0; 2],
        };
        let mut k = lo;
        let mut covered = false;
        while k + 1 < samples.len() && segment[k + 1] == segment[i] && samples[k].t_s < b {
            let (p, q) = (&samples[k], &samples[k + 1]);
            let (t0, t1) = (p.t_s.max(a), q.t_s.min(b));
            let span = q.t_s - p.t_s;
            if t1 > t0 && span > 0.0 {
                // the trapezoid of the line through p and q over [t0, t1]
                let w0 = (t0 - p.t_s) / span;
                let w1 = (t1 - p.t_s) / span;
                let weight = (t1 - t0) / period;
                let mid = 0.5 * (w0 + w1);
                for c in 0..3 {
                    avg.position[c] +=
                        weight * (p.position[c] + mid * (q.position[c] - p.position[c]));
                }
                for c in 0..2 {
                    avg.effort_nm[c] +=
                        weight * (p.effort_nm[c] + mid * (q.effort_nm[c] - p.effort_nm[c]));
                }
            }
            k += 1;
            covered = samples[k].t_s >= b;
        }
        if !covered {
            continue;
        }
        if last_segment != Some(segment[i]) {
            out_starts.push(out.len());
            last_segment = Some(segment[i]);
        }
        out.push(avg);
    }
    (out, out_starts)
}

/// One standard deviation of the white noise in `y` (sampled at `t`, segments starting at
/// `starts`), from the median distance of each sample from the line through its two
/// neighbours: that cancels the smooth motion and the controller's decay after each command
/// step, and the kicks themselves (one sample in ten or more) move the median a little, upwards
/// (on the safe side for a gate).
fn sample_noise(y: &[f64], t: &[f64], starts: &[usize]) -> f64 {
    let mut d: Vec<f64> = (2..y.len().min(t.len()))
        .filter(|i| !starts.contains(i) && !starts.contains(&(i - 1)))
        .filter_map(|i| {
            let span = t[i] - t[i - 2];
            if span.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return None;
            }
            let w = (t[i] - t[i - 1]) / span;
            let r = y[i - 1] - (w * y[i - 2] + (1.0 - w) * y[i]);
            // for white noise of std s, r has std s * sqrt(1 + w² + (1 - w)²)
            let r = r.abs() / (1.0 + w * w + (1.0 - w) * (1.0 - w)).sqrt();
            r.is_finite().then_some(r)
        })
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    // |N(0, s²)| has median 0.6745 s
    *m / 0.674_5
}

/// The least-squares cubic `c0 + c1 x + c2 x² + c3 x³` through `(x, y)` points, from its normal
/// equations; `None` when they are singular. Allocates nothing (the run-time filter's own fit).
fn cubic_through(points: impl Iterator<Item = (f64, f64)>) -> Option<[f64; 4]> {
    let mut m = [[0.0f64; 4]; 4];
    let mut r = [0.0f64; 4];
    for (x, y) in points {
        let p = [1.0, x, x * x, x * x * x];
        for a in 0..4 {
            r[a] += p[a] * y;
            for b in 0..4 {
                m[a][b] += p[a] * p[b];
            }
        }
    }
    solve4(m, r)
}

/// Solves the symmetric 4x4 system by Gaussian elimination with partial pivoting.
fn solve4(m: [[f64; 4]; 4], r: [f64; 4]) -> Option<[f64; 4]> {
    solve_n(m, r)
}

/// Solves the N x N system by Gaussian elimination with partial pivoting.
#[allow(clippy::needless_range_loop)] // matrix indices read clearer than iterator chains
fn solve_n<const N: usize>(mut m: [[f64; N]; N], mut r: [f64; N]) -> Option<[f64; N]> {
    for col in 0..N {
        let mut piv = col;
        for row in col + 1..N {
            if m[row][col].abs() > m[piv][col].abs() {
                piv = row;
            }
        }
        if m[piv][col].is_nan() || m[piv][col].abs() <= 1e-300 {
            return None;
        }
        m.swap(col, piv);
        r.swap(col, piv);
        for row in col + 1..N {
            let f = m[row][col] / m[col][col];
            for k in col..N {
                m[row][k] -= f * m[col][k];
            }
            r[row] -= f * r[col];
        }
    }
    let mut x = [0.0; N];
    for row in (0..N).rev() {
        let mut s = r[row];
        for k in row + 1..N {
            s -= m[row][k] * x[k];
        }
        x[row] = s / m[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The estimator state of one joint: its filter and its friction direction memory.
#[derive(Clone, Debug, Default)]
pub struct JointDynamicsState {
    filter: DerivativeFilter,
    direction: f64,
    velocity: f64,
    acceleration: f64,
}

impl JointDynamicsState {
    /// Feeds one sample; returns the torque `tau_f + J qdd` the model attributes to the motion
    /// (N·m).
    pub fn update(&mut self, p: &DynamicsParams, t_s: f64, q: f64, insertion_m: f64) -> f64 {
        let (v, a) = self.filter.push(t_s, q);
        self.velocity = v;
        self.acceleration = a;
        // The direction turns only once the joint has moved that way over the last
        // DIRECTION_CHECK_S as well: a stop's kink swings the cubic's velocity past the stick
        // velocity the other way for a few ms while the encoder stands still.
        let moved = self.filter.recent_displacement(DIRECTION_CHECK_S);
        if v > p.stick_velocity_rad_per_s && moved > 0.0 {
            self.direction = 1.0;
        } else if v < -p.stick_velocity_rad_per_s && moved < 0.0 {
            self.direction = -1.0;
        }
        p.friction(v, self.direction) + p.inertia(insertion_m) * a
    }

    /// Feeds one sample to the filter alone (a joint without a dynamics model: its velocity
    /// and acceleration still tell whether the arm is still).
    pub fn observe(&mut self, t_s: f64, q: f64) {
        let (v, a) = self.filter.push(t_s, q);
        self.velocity = v;
        self.acceleration = a;
    }

    /// Whether the filter has a full window: until then the motion's torque is unknown.
    pub fn ready(&self) -> bool {
        self.filter.ready()
    }

    /// See [`DerivativeFilter::typical_period_s`].
    pub fn typical_period_s(&self) -> Option<f64> {
        self.filter.typical_period_s()
    }

    /// See [`DerivativeFilter::residual_rad`].
    pub fn smoothness_residual_rad(&self) -> f64 {
        self.filter.residual_rad()
    }

    /// See [`DerivativeFilter::restarted`].
    pub fn restarted(&self) -> bool {
        self.filter.restarted()
    }

    /// The filtered velocity (rad/s) of the last update.
    pub fn velocity(&self) -> f64 {
        self.velocity
    }

    /// The filtered acceleration (rad/s²) of the last update.
    pub fn acceleration(&self) -> f64 {
        self.acceleration
    }

    /// The friction's direction memory: +1, -1, or 0 before any motion.
    pub fn direction(&self) -> f64 {
        self.direction
    }

    /// Forgets the history (after invalid samples).
    pub fn reset(&mut self) {
        self.filter.reset();
        self.velocity = 0.0;
        self.acceleration = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pushes `samples` of a cubic at `rate_hz` from t = 1 s, checks `ready()` against
    /// `ready_from` (the sample count it turns ready at) if given, and that the last estimate
    /// is the cubic's velocity and acceleration two samples back. Returns the filter.
    fn assert_cubic_differentiated_exactly(
        rate_hz: f64,
        samples: i32,
        ready_from: Option<i32>,
    ) -> DerivativeFilter {
        let mut f = DerivativeFilter::default();
        let dt = 1.0 / rate_hz;
        let q = |t: f64| 0.1 + 0.5 * t - 2.0 * t * t + 3.0 * t * t * t;
        let mut out = (0.0, 0.0);
        for i in 0..samples {
            let t = 1.0 + f64::from(i) * dt;
            out = f.push(t, q(t));
            if let Some(from) = ready_from {
                assert_eq!(f.ready(), i + 1 >= from, "{rate_hz} Hz, {i}");
            }
        }
        let t = 1.0 + f64::from(samples - 3) * dt;
        let v = 0.5 - 4.0 * t + 9.0 * t * t;
        let a = -4.0 + 18.0 * t;
        assert!((out.0 - v).abs() < 1e-6, "{rate_hz} Hz: {out:?} {v}");
        assert!((out.1 - a).abs() < 1e-3, "{rate_hz} Hz: {out:?} {a}");
        f
    }

    #[test]
    fn cubic_motion_is_differentiated_exactly_two_samples_back() {
        assert_cubic_differentiated_exactly(1500.0, 100, None);
    }

    #[test]
    fn short_gaps_keep_the_window_and_long_ones_restart_it() {
        let mut f = DerivativeFilter::default();
        let dt = 1.0 / 1500.0;
        let q = |t: f64| 0.2 * t - 1.5 * t * t + 0.7 * t * t * t;
        let mut out = (0.0, 0.0);
        let mut last_t = 0.0;
        for i in 0..200 {
            // Three cycles lost at i = 120 (a few invalid samples).
            if (120..123).contains(&i) {
                continue;
            }
            last_t = 2.0 + f64::from(i) * dt;
            out = f.push(last_t, q(last_t));
            assert!(i < 60 || f.ready(), "{i}");
        }
        let t = last_t - 2.0 * dt;
        assert!(
            (out.0 - (0.2 - 3.0 * t + 2.1 * t * t)).abs() < 1e-6,
            "{out:?}"
        );
        assert!((out.1 - (-3.0 + 4.2 * t)).abs() < 1e-3, "{out:?}");
        // A gap longer than MAX_GAP_S, or time going back, starts over.
        f.push(last_t + 0.05, 0.0);
        assert!(!f.ready());
        for i in 0..WINDOW {
            f.push(10.0 + i as f64 * dt, 0.0);
        }
        assert!(f.ready());
        f.push(9.0, 0.0);
        assert!(!f.ready());
    }

    #[test]
    fn quantized_rest_gives_small_estimates_and_nan_resets() {
        let mut f = DerivativeFilter::default();
        let dt = 1.0 / 1500.0;
        let count = 7.7e-6;
        let mut worst: (f64, f64) = (0.0, 0.0);
        for i in 0..3000 {
            let t = f64::from(i) * dt;
            // A slow drift through the encoder's steps.
            let q = ((0.001 * t) / count).round() * count;
            let (v, a) = f.push(t, q);
            if i > WINDOW as i32 {
                worst = (worst.0.max((v - 0.001).abs()), worst.1.max(a.abs()));
            }
        }
        assert!(worst.0 < 0.01 && worst.1 < 2.0, "{worst:?}");
        assert_eq!(f.push(f64::NAN, 0.0), (0.0, 0.0));
        assert_eq!(f.push(1.0, 0.0), (0.0, 0.0));
    }

    /// RMS acceleration estimate of a quantized constant-velocity motion sampled at `rate_hz`.
    fn acceleration_noise_at(rate_hz: f64) -> f64 {
        let mut f = DerivativeFilter::default();
        let count = 7.7e-6;
        let (mut sum, mut n) = (0.0, 0.0);
        // 2 s, judged after the first 0.1 s.
        let samples = (2.0 * rate_hz) as i32;
        for i in 0..samples {
            let t = f64::from(i) / rate_hz;
            let q = ((0.0137 * t) / count).round() * count;
            let (_, a) = f.push(t, q);
            if t > 0.1 {
                sum += a * a;
                n += 1.0;
            }
        }
        (sum / n).sqrt()
    }

    #[test]
    fn the_window_spans_the_same_time_at_a_faster_rate() {
        // 48 samples at 1.5 kHz; at 3 and 6 kHz the window keeps WINDOW_TIME_S, so the
        // quantization's effect on the acceleration does not grow (with 48 samples at 3 kHz the
        // window would be half as long and the noise about 4 times as large).
        let base = acceleration_noise_at(1500.0);
        for rate in [3000.0, 6000.0] {
            let noise = acceleration_noise_at(rate);
            assert!(
                noise < 1.3 * base,
                "{rate} Hz: {noise} against {base} at 1.5 kHz"
            );
        }
        // A cubic is still differentiated exactly with the longer window.
        assert_cubic_differentiated_exactly(6000.0, 400, Some(WINDOW as i32));
    }

    #[test]
    fn at_a_slower_rate_the_window_spans_its_time_with_at_least_eight_samples() {
        // 500 Hz: ready once a sample older than WINDOW_TIME_S is kept (the 17th), fitting 16;
        // a cubic is still exact.
        let f = assert_cubic_differentiated_exactly(500.0, 40, Some(17));
        assert!((f.typical_period_s().unwrap() - 1.0 / 500.0).abs() < 1e-12);
        // 100 Hz: MIN_WINDOW samples (70 ms) at least.
        let mut f = DerivativeFilter::default();
        for i in 0..MIN_WINDOW as i32 {
            f.push(f64::from(i) / 100.0, 0.0);
            assert_eq!(f.ready(), i + 1 > MIN_WINDOW as i32, "{i}");
        }
        f.push(0.08, 0.0);
        assert!(f.ready());
        // The displacement over the last 8 ms or more.
        let mut f = DerivativeFilter::default();
        assert_eq!(f.recent_displacement(DIRECTION_CHECK_S), 0.0);
        for i in 0..20 {
            f.push(f64::from(i) * 1e-3, f64::from(i) * 1e-4);
        }
        assert!((f.recent_displacement(DIRECTION_CHECK_S) - 8e-4).abs() < 1e-12);
    }

    #[test]
    fn a_late_stamp_or_lost_cycles_do_not_shorten_the_window() {
        let mut f = DerivativeFilter::default();
        let dt = 1.0 / 1500.0;
        let mut t = 0.0;
        for _ in 0..300 {
            t += dt;
            f.push(t, 0.1 * t);
        }
        assert_eq!(f.fitted_samples(), WINDOW);
        // 15 cycles lost (10 ms): the window still fits about the typical 48 samples (47: the
        // gap moved the typical interval by 2%), over 41 ms, not the 33 of the last 31.7 ms.
        t += 16.0 * dt;
        f.push(t, 0.1 * t);
        assert!(f.fitted_samples() >= WINDOW - 1, "{}", f.fitted_samples());
        // At 500 Hz, the typical count there.
        let mut f = DerivativeFilter::default();
        for i in 0..100 {
            f.push(f64::from(i) / 500.0, 0.0);
        }
        assert_eq!(f.fitted_samples(), 16);
        // At 3 kHz, 95 periods (96 samples) to within rounding.
        let mut f = DerivativeFilter::default();
        for i in 0..300 {
            f.push(f64::from(i) / 3000.0, 0.0);
        }
        assert!(
            (95..=96).contains(&f.fitted_samples()),
            "{}",
            f.fitted_samples()
        );
    }

    #[test]
    fn friction_remembers_the_last_direction() {
        let p = DynamicsParams {
            inertia_kg_m2: [0.0, 0.0],
            viscous_nm_s_per_rad: 0.0,
            coulomb_nm: 0.05,
            stick_velocity_rad_per_s: 0.002,
            residual_std_nm: 0.0,
            gate_sigmas: 0.0,
            max_acceleration_rad_per_s2: None,
            distal_gravity: None,
        };
        let mut s = JointDynamicsState::default();
        let dt = 1e-3;
        let mut q = 0.0;
        let mut tau = 0.0;
        for i in 0..200 {
            q += 0.01 * dt;
            tau = s.update(&p, f64::from(i) * dt, q, 0.1);
        }
        assert_eq!(tau, 0.05);
        // Stopped: the friction keeps the sign of the last motion.
        for i in 200..400 {
            tau = s.update(&p, f64::from(i) * dt, q, 0.1);
        }
        assert_eq!(tau, 0.05);
        for i in 400..600 {
            q -= 0.01 * dt;
            tau = s.update(&p, f64::from(i) * dt, q, 0.1);
        }
        assert_eq!(tau, -0.05);
    }
}

/// One sample of a free-space excitation (`calibrate dynamics`, or recorded from a live robot).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicsSample {
    /// Time (s), increasing.
    pub t_s: f64,
    /// Joints 1-3 (rad, rad, m).
    pub position: [f64; 3],
    /// Efforts of joints 1 and 2 (N·m).
    pub effort_nm: [f64; 2],
}

/// The identified model of one joint and how much of the effort it explains.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicsFit {
    /// 1 = yaw, 2 = pitch.
    pub joint: u8,
    pub params: DynamicsParams,
    /// RMS of `tau_meas - tau_0(q)` over the samples used (N·m): the paper's `tau_ext` in free
    /// space, all of it false.
    pub rms_before_nm: f64,
    /// RMS of the model's `tau_ext` over the same samples (N·m).
    pub rms_after_nm: f64,
    /// Samples used (after the filter's window filled).
    pub samples: usize,
}

/// Why a dynamics fit failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DynamicsFitError {
    /// Too few samples, or a time that does not increase.
    #[error("joint {joint}: {reason}")]
    Data { joint: u8, reason: &'static str },
    /// The excitation does not separate inertia, viscous and Coulomb friction.
    #[error(
        "joint {joint}: the excitation does not separate inertia and friction (singular system); \
         move the joint over its range at several speeds and depths"
    )]
    Singular { joint: u8 },
}

/// Identifies `J_0, J_2, b, F_c` of joint `joint` (1 or 2) by linear least squares of
/// `tau_meas - tau_0(q) = J_0 qdd + J_2 L^2 qdd + b qd + F_c s` over free-space samples, with the
/// same filter and direction memory as at run time; `tau_0` is the parameter file's own table.
/// Negative estimates (not physical) are set to 0 and the rest refitted. `gate_sigmas` goes into
/// the result unchanged.
pub fn fit_dynamics(
    joint: u8,
    samples: &[DynamicsSample],
    tau_0: impl Fn(f64) -> f64,
    gate_sigmas: f64,
) -> Result<DynamicsFit, DynamicsFitError> {
    fit_dynamics_segmented(joint, samples, &[0], tau_0, gate_sigmas)
}

/// [`fit_dynamics`] over samples made of segments (one excitation per depth) starting at the
/// indices `starts`: the filter and the direction memory restart at each, and only samples with
/// a full window inside their segment are used.
pub fn fit_dynamics_segmented(
    joint: u8,
    samples: &[DynamicsSample],
    starts: &[usize],
    tau_0: impl Fn(f64) -> f64,
    gate_sigmas: f64,
) -> Result<DynamicsFit, DynamicsFitError> {
    fit_dynamics_with_gravity(
        joint,
        samples,
        starts,
        tau_0,
        gate_sigmas,
        None,
        Excitation::Smooth,
    )
}

/// Regressors of the fit: `[qdd, L^2 qdd, qd, s, -(L - L_ref) du/dq_j (3)]`.
const FIT_COLUMNS: usize = 7;
/// The first weight column.
const GRAVITY_COLUMN: usize = 4;
/// The inertia's depth term's column (`L^2 qdd`).
const INERTIA_DEPTH_COLUMN: usize = 1;
/// The inertia's depth term `J_2` is kept only when it is at least this many standard errors
/// from zero; otherwise the fit is done again with the inertia constant over the depths
/// recorded. Depths a few centimetres apart change `J_2 L^2` by little (the simulated arm's
/// 0.02 kg·m² changes its 0.05 by 1.2% from 0.10 to 0.20 m), and an unresolved `J_2` trades
/// with the weight's terms, which also grow with the depth: on rows recorded beside the console
/// stand-in it came out 0.076 ± 0.075, taking `J(0.10)` 5% low where the constant inertia is
/// 2.5% low.
pub const INERTIA_DEPTH_MIN_T: f64 = 2.0;
/// The weight needs this much spread of insertion (m) to be told from the torque offset.
const GRAVITY_MIN_DEPTH_SPREAD_M: f64 = 0.02;

/// [`fit_dynamics_segmented`] that also identifies the distal part's weight
/// ([`DistalGravityParams`]) when `gravity_reference_m` is the insertion at which `tau_0` was
/// measured: three more regressors `-(L - L_ref) du/dq_j` (see the module docs). The weight is
/// found from how the free-space effort changes with the insertion, so it needs depths that
/// differ by 2 cm or more; otherwise, or without a reference, it is not modelled (`None`). A
/// component the joint has no lever for (joint 1, the y axis) is 0.
///
/// Its uncertainty (`weight_sigma_n`) is the least-squares standard error with the residual's
/// correlation in time taken into account: the residual follows the motion, so neighbouring
/// samples are not independent, and the variance is scaled by the integrated autocorrelation
/// time of the residual (in samples, summed until the autocorrelation first falls below 0.05).
///
/// The inertia's depth term `J_2` is kept only when the depths recorded resolve it, at least
/// [`INERTIA_DEPTH_MIN_T`] standard errors (taken the same way) from zero; otherwise the fit is
/// done again with `J_2 = 0`, the inertia constant over those depths.
///
/// `excitation` says how the motion was commanded ([`Excitation`]). With
/// [`Excitation::Stepped`] the regression runs on rows averaged over whole command periods; the
/// residual std it reports is that fit's with the effort's sample noise (which the averaging
/// hides and the run-time estimator sees on every sample) added in quadrature.
#[allow(clippy::needless_range_loop)] // the regressors index parallel arrays
pub fn fit_dynamics_with_gravity(
    joint: u8,
    samples: &[DynamicsSample],
    starts: &[usize],
    tau_0: impl Fn(f64) -> f64,
    gate_sigmas: f64,
    gravity_reference_m: Option<f64>,
    excitation: Excitation,
) -> Result<DynamicsFit, DynamicsFitError> {
    const N: usize = FIT_COLUMNS;
    let j = usize::from(joint.clamp(1, 2) - 1);
    if samples.len() < 4 * WINDOW {
        return Err(DynamicsFitError::Data {
            joint,
            reason: "too few samples for a dynamics fit (need a few seconds of motion)",
        });
    }
    if samples
        .windows(2)
        .any(|w| w[1].t_s.is_nan() || w[1].t_s <= w[0].t_s)
    {
        return Err(DynamicsFitError::Data {
            joint,
            reason: "sample times must increase",
        });
    }
    if let Some(r) = gravity_reference_m
        && !(r.is_finite() && (0.0..=1.0).contains(&r))
    {
        return Err(DynamicsFitError::Data {
            joint,
            reason: "the torque offset's reference insertion must be within 0..1 m",
        });
    }
    // Rows commanded in steps: averaged over whole command periods first (Excitation::Stepped).
    let raw_median_dt = median_interval(samples);
    let period = excitation.averaging_period(raw_median_dt);
    let raw_noise = period.map(|_| {
        let y: Vec<f64> = samples
            .iter()
            .map(|s| s.effort_nm[j] - tau_0(s.position[j]))
            .collect();
        let t: Vec<f64> = samples.iter().map(|s| s.t_s).collect();
        sample_noise(&y, &t, starts)
    });
    let averaged = period.map(|p| average_over_period(samples, starts, p));
    let (samples, starts, median_dt) = match &averaged {
        Some((s, st)) => (s.as_slice(), st.as_slice(), median_interval(s)),
        None => (samples, starts, raw_median_dt),
    };
    if samples.len() < 4 * WINDOW {
        return Err(DynamicsFitError::Data {
            joint,
            reason: "too few samples for a dynamics fit (need a few seconds of motion)",
        });
    }
    // Regressors and target y, aligned with the filter's delay: the estimate of sample i refers
    // to sample i - DELAY_SAMPLES. `segment` marks where the residual's correlation restarts.
    let stick = default_stick_velocity();
    let mut direction = 0.0;
    let mut rows: Vec<([f64; N], f64)> = Vec::with_capacity(samples.len());
    let mut row_starts: Vec<usize> = Vec::new();
    let mut max_acc = 0.0f64;
    let l_ref = gravity_reference_m.unwrap_or(0.0);
    for (i, d) in fit_derivatives(samples, j, starts, median_dt, period.is_some())
        .into_iter()
        .enumerate()
    {
        if starts.contains(&i) {
            direction = 0.0;
            row_starts.push(rows.len());
        }
        let Some((v, a, k)) = d else { continue };
        if v > stick {
            direction = 1.0;
        } else if v < -stick {
            direction = -1.0;
        }
        let at = &samples[k];
        let l = at.position[2];
        let y = at.effort_nm[j] - tau_0(at.position[j]);
        let du = shaft_direction_derivatives(at.position[0], at.position[1])[j];
        let lever = -(l.max(0.0) - l_ref);
        if y.is_finite() && v.is_finite() && a.is_finite() && du.iter().all(|d| d.is_finite()) {
            max_acc = max_acc.max(a.abs());
            rows.push((
                [
                    a,
                    l * l * a,
                    v,
                    direction,
                    lever * du[0],
                    lever * du[1],
                    lever * du[2],
                ],
                y,
            ));
        }
    }
    // J_2 and the weight need depths that differ: with less than 2 cm of spread the L^2 column
    // is a multiple of the J_0 column (J_0 then holds the inertia at that depth), and the weight
    // cannot be told from the torque offset.
    let (l_lo, l_hi) = samples
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
            (lo.min(s.position[2]), hi.max(s.position[2]))
        });
    let gravity = gravity_reference_m.is_some() && l_hi - l_lo >= GRAVITY_MIN_DEPTH_SPREAD_M;
    let mut active = [
        true,
        l_hi - l_lo >= 0.02,
        true,
        true,
        gravity,
        gravity,
        gravity,
    ];
    // Columns scaled to unit rms, so the normal equations are well conditioned; a column that is
    // (nearly) zero throughout is left out.
    let mut scale = [0.0f64; N];
    for (x, _) in &rows {
        for a in 0..N {
            scale[a] += x[a] * x[a];
        }
    }
    let largest = scale.iter().cloned().fold(0.0f64, f64::max);
    for (a, sc) in scale.iter_mut().enumerate() {
        let small = a >= GRAVITY_COLUMN && *sc <= 1e-12 * largest;
        *sc = (*sc / rows.len().max(1) as f64).sqrt();
        if sc.is_nan() || *sc <= 0.0 || small {
            active[a] = false;
            *sc = 1.0;
        }
    }
    for (x, _) in rows.iter_mut() {
        for a in 0..N {
            x[a] /= scale[a];
        }
    }
    let normal = |active: &[bool; N]| {
        let mut m = [[0.0; N]; N];
        let mut r = [0.0; N];
        for (x, y) in &rows {
            for a in 0..N {
                if !active[a] {
                    continue;
                }
                r[a] += x[a] * y;
                for b in 0..N {
                    if active[b] {
                        m[a][b] += x[a] * x[b];
                    }
                }
            }
        }
        for a in 0..N {
            if !active[a] {
                m[a] = [0.0; N];
                m[a][a] = 1.0;
                r[a] = 0.0;
            }
        }
        (m, r)
    };
    let n = rows.len().max(1) as f64;
    let mut coef = [0.0; N];
    let mut m = [[0.0; N]; N];
    let (mut before, mut after, mut var) = (0.0, 0.0, 0.0);
    let mut residuals = Vec::with_capacity(rows.len());
    // At most twice: once more without the inertia's depth term when the depths do not resolve
    // it (below).
    for _ in 0..2 {
        for _ in 0..N {
            let (mm, r) = normal(&active);
            m = mm;
            coef = solve_n(m, r).ok_or(DynamicsFitError::Singular { joint })?;
            // Negative inertia or friction is not physical: set to 0 and refit. The weight's
            // components may have either sign.
            let mut changed = false;
            for a in 0..GRAVITY_COLUMN {
                if active[a] && coef[a] < 0.0 {
                    active[a] = false;
                    coef[a] = 0.0;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let mut mean_after = 0.0;
        (before, after) = (0.0, 0.0);
        residuals.clear();
        for (x, y) in &rows {
            let fit: f64 = (0..N).map(|a| coef[a] * x[a]).sum();
            let e = y - fit;
            before += y * y;
            after += e * e;
            mean_after += e;
            residuals.push(e);
        }
        mean_after /= n;
        var = (after / n - mean_after * mean_after).max(0.0);
        if !active[INERTIA_DEPTH_COLUMN] {
            break;
        }
        let tau_int = autocorrelation_time(&residuals, &row_starts);
        let sigma = coefficient_sigma(m, INERTIA_DEPTH_COLUMN, var, tau_int)
            .ok_or(DynamicsFitError::Singular { joint })?;
        if coef[INERTIA_DEPTH_COLUMN].abs() >= INERTIA_DEPTH_MIN_T * sigma {
            break;
        }
        active[INERTIA_DEPTH_COLUMN] = false;
        coef[INERTIA_DEPTH_COLUMN] = 0.0;
    }
    // what the averaging hid from the residual: the effort's own noise, which the run-time
    // estimator sees on every sample
    let residual_var = var + raw_noise.map_or(0.0, |s| s * s);
    let distal_gravity = if gravity {
        // Covariance of the weight's (scaled) coefficients: sigma^2 (X^T X)^-1, times the
        // residual's integrated autocorrelation time.
        let tau_int = autocorrelation_time(&residuals, &row_starts);
        let mut weight = [0.0; 3];
        let mut sigma = [0.0; 3];
        for k in 0..3 {
            let a = GRAVITY_COLUMN + k;
            if !active[a] {
                continue;
            }
            weight[k] = coef[a] / scale[a];
            sigma[k] = coefficient_sigma(m, a, var, tau_int)
                .ok_or(DynamicsFitError::Singular { joint })?
                / scale[a];
        }
        Some(DistalGravityParams {
            weight_n: weight,
            weight_sigma_n: sigma,
            reference_insertion_m: l_ref,
        })
    } else {
        None
    };
    for a in 0..N {
        coef[a] /= scale[a];
    }
    Ok(DynamicsFit {
        joint,
        params: DynamicsParams {
            inertia_kg_m2: [coef[0], coef[1]],
            viscous_nm_s_per_rad: coef[2],
            coulomb_nm: coef[3],
            stick_velocity_rad_per_s: stick,
            residual_std_nm: residual_var.sqrt(),
            gate_sigmas,
            max_acceleration_rad_per_s2: Some(max_acc),
            distal_gravity,
        },
        rms_before_nm: (before / n).sqrt(),
        rms_after_nm: (after / n).sqrt(),
        samples: rows.len(),
    })
}

/// The standard error of (scaled) coefficient `a` of a least-squares fit with normal matrix
/// `m` and residual variance `var`: `sqrt(var (M^-1)_aa tau_int)`, with `tau_int` the
/// residual's integrated autocorrelation time ([`autocorrelation_time`]). `None` when `m` is
/// singular.
fn coefficient_sigma<const N: usize>(
    m: [[f64; N]; N],
    a: usize,
    var: f64,
    tau_int: f64,
) -> Option<f64> {
    let mut e = [0.0; N];
    e[a] = 1.0;
    let inv = solve_n(m, e)?;
    Some((var * inv[a] * tau_int).max(0.0).sqrt())
}

/// The integrated autocorrelation time (samples, at least 1) of `e`, made of segments starting
/// at `starts`: `1 + 2 sum_k rho_k` up to the first lag whose autocorrelation is below 0.05 (at
/// most 3000 lags, 2 s at 1.5 kHz).
fn autocorrelation_time(e: &[f64], starts: &[usize]) -> f64 {
    let n = e.len();
    if n < 2 {
        return 1.0;
    }
    let mean = e.iter().sum::<f64>() / n as f64;
    let var = e.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
    if var.partial_cmp(&0.0) != Some(core::cmp::Ordering::Greater) {
        return 1.0;
    }
    let mut bounds: Vec<(usize, usize)> = Vec::new();
    for (i, &s) in starts.iter().enumerate() {
        let end = starts.get(i + 1).copied().unwrap_or(n).min(n);
        if s < end {
            bounds.push((s, end));
        }
    }
    if bounds.is_empty() {
        bounds.push((0, n));
    }
    let mut tau = 1.0;
    for lag in 1..=3000usize {
        let (mut sum, mut count) = (0.0, 0usize);
        for &(s, end) in &bounds {
            if end - s <= lag {
                continue;
            }
            for i in s..end - lag {
                sum += (e[i] - mean) * (e[i + lag] - mean);
            }
            count += end - s - lag;
        }
        if count == 0 {
            break;
        }
        let rho = sum / count as f64 / var;
        if rho < 0.05 {
            break;
        }
        tau += 2.0 * rho;
    }
    tau
}

#[cfg(test)]
mod fit_tests {
    use super::*;

    fn rows_at(times: impl IntoIterator<Item = f64>) -> Vec<DynamicsSample> {
        times
            .into_iter()
            .map(|t_s| DynamicsSample {
                t_s,
                position: [0.0, 0.0, 0.1],
                effort_nm: [0.0; 2],
            })
            .collect()
    }

    /// The share counts intervals within each segment only: the gap between two depths is not
    /// an irregular cycle. Every tenth row lost leaves one interval in nine at twice the median.
    #[test]
    fn interval_regularity_counts_the_intervals_outside_the_band_within_segments() {
        let regular = rows_at((0..1000).map(|i| f64::from(i) / 1500.0));
        let later = rows_at((0..1000).map(|i| 5.0 + f64::from(i) / 1500.0));
        let (median, share) = interval_regularity(&[&regular, &later]).unwrap();
        assert!((median - 1.0 / 1500.0).abs() < 1e-12, "{median}");
        assert_eq!(share, 0.0);
        let lossy = rows_at(
            (0..1000)
                .filter(|i| i % 10 != 5)
                .map(|i| f64::from(i) / 1500.0),
        );
        let (median, share) = interval_regularity(&[&lossy]).unwrap();
        assert!((median - 1.0 / 1500.0).abs() < 1e-12, "{median}");
        assert!((share - 100.0 / 899.0).abs() < 1e-12, "{share}");
        assert_eq!(interval_regularity(&[&lossy[..1]]), None);
        assert_eq!(interval_regularity(&[]), None);
    }

    #[test]
    fn recovers_inertia_and_friction_of_a_multisine() {
        recovers_a_multisine_sampled_at(1500.0);
    }

    /// A console's `measured_js` at 100 Hz (jittered by up to 2 ms): the run-time filter's 48
    /// samples would span 0.48 s there; the fit's centred cubic recovers the same model.
    #[test]
    fn recovers_inertia_and_friction_of_a_multisine_at_a_consoles_100_hz() {
        recovers_a_multisine_sampled_at(100.0);
    }

    fn recovers_a_multisine_sampled_at(rate_hz: f64) {
        let truth = DynamicsParams {
            inertia_kg_m2: [0.05, 0.4],
            viscous_nm_s_per_rad: 0.2,
            coulomb_nm: 0.03,
            stick_velocity_rad_per_s: 0.002,
            residual_std_nm: 0.0,
            gate_sigmas: 4.0,
            max_acceleration_rad_per_s2: None,
            distal_gravity: None,
        };
        let dt = 1.0 / rate_hz;
        let n = (10.0 * rate_hz) as usize;
        let mut samples = Vec::new();
        let mut dir = 0.0;
        for (d, l) in [0.1, 0.15, 0.2].into_iter().enumerate() {
            for i in 0..n {
                // below 500 Hz, a console's stamps: up to 2 ms late, deterministically
                let jitter = if rate_hz < 500.0 {
                    0.002 * ((i * 7919 % 13) as f64 / 12.0)
                } else {
                    0.0
                };
                let t = (d * n + i) as f64 * dt + jitter;
                let w = [2.0, 3.7, 5.3];
                let amp = [0.2, 0.08, 0.03];
                let (mut q, mut v, mut a) = (0.0, 0.0, 0.0);
                for k in 0..3 {
                    q += amp[k] * (w[k] * t).sin();
                    v += amp[k] * w[k] * (w[k] * t).cos();
                    a -= amp[k] * w[k] * w[k] * (w[k] * t).sin();
                }
                if v > 0.002 {
                    dir = 1.0;
                } else if v < -0.002 {
                    dir = -1.0;
                }
                let tau = 0.1 + truth.inertia(l) * a + truth.friction(v, dir);
                samples.push(DynamicsSample {
                    t_s: t,
                    position: [q, q, l],
                    effort_nm: [tau, tau],
                });
            }
        }
        let fit = fit_dynamics(1, &samples, |_| 0.1, 4.0).unwrap();
        let p = fit.params;
        assert!((p.inertia_kg_m2[0] - 0.05).abs() < 2e-3, "{fit:?}");
        assert!((p.inertia_kg_m2[1] - 0.4).abs() < 0.1, "{fit:?}");
        assert!((p.viscous_nm_s_per_rad - 0.2).abs() < 0.01, "{fit:?}");
        assert!((p.coulomb_nm - 0.03).abs() < 0.005, "{fit:?}");
        assert!(fit.rms_after_nm < 0.1 * fit.rms_before_nm, "{fit:?}");
        // Too little data is an error naming the joint.
        let e = fit_dynamics(2, &samples[..10], |_| 0.0, 4.0).unwrap_err();
        assert!(e.to_string().starts_with("joint 2"), "{e}");
        // No weight asked for: not modelled.
        assert_eq!(p.distal_gravity, None);
    }

    /// A depth term the depths recorded cannot resolve is left out (`J_2 = 0`, the inertia
    /// constant), one they resolve is kept: the same noisy multisine at 0.10, 0.15 and 0.20 m
    /// with `J_2` = 0 and 0.4 kg·m².
    #[test]
    fn the_inertias_depth_term_is_kept_only_when_the_depths_resolve_it() {
        let fit_with = |j2: f64| {
            let mut samples = Vec::new();
            let mut state = 0x2545_f491_4f6c_dd1du64;
            let mut noise = move || {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            let n = 15_000;
            for (d, l) in [0.1, 0.15, 0.2].into_iter().enumerate() {
                for i in 0..n {
                    let t = (d * n + i) as f64 / 1500.0;
                    let (mut q, mut a) = (0.0, 0.0);
                    for (w, amp) in [(2.0, 0.2), (3.7, 0.08), (5.3, 0.03)] {
                        q += amp * f64::sin(w * t);
                        a -= amp * w * w * f64::sin(w * t);
                    }
                    let v: f64 = [(2.0, 0.2), (3.7, 0.08), (5.3, 0.03)]
                        .iter()
                        .map(|(w, amp)| amp * w * f64::cos(w * t))
                        .sum();
                    // 0.02 N·m of effort noise
                    let tau = (0.05 + j2 * l * l) * a + 0.2 * v + 0.07 * noise();
                    samples.push(DynamicsSample {
                        t_s: t,
                        position: [q, q, l],
                        effort_nm: [tau, tau],
                    });
                }
            }
            fit_dynamics(1, &samples, |_| 0.0, 4.0).unwrap().params
        };
        let constant = fit_with(0.0);
        assert_eq!(constant.inertia_kg_m2[1], 0.0, "{constant:?}");
        assert!(
            (constant.inertia_kg_m2[0] - 0.05).abs() < 1e-3,
            "{constant:?}"
        );
        let deep = fit_with(0.4);
        assert!((deep.inertia_kg_m2[1] - 0.4).abs() < 0.1, "{deep:?}");
        assert!((deep.inertia_kg_m2[0] - 0.05).abs() < 2e-3, "{deep:?}");
    }

    /// Issue 20 item 3: the distal weight, as the effort shows it beyond a torque-offset table
    /// taken at `L_ref`, is recovered with an uncertainty that covers its error; the component
    /// joint 1 has no lever for stays 0.
    #[test]
    #[allow(clippy::needless_range_loop)] // three parallel arrays
    fn recovers_the_distal_weight_with_its_uncertainty() {
        let w = [0.078, 0.078, -0.162];
        let truth = DistalGravityParams {
            weight_n: w,
            weight_sigma_n: [0.0; 3],
            reference_insertion_m: 0.155,
        };
        let dt = 1.0 / 1500.0;
        let mut samples = Vec::new();
        let mut starts = Vec::new();
        let mut noise = 0x2545_f491_4f6c_dd1du64;
        for (d, l) in [0.1, 0.15, 0.2].into_iter().enumerate() {
            starts.push(samples.len());
            for i in 0..15_000 {
                let t = (d * 15_000 + i) as f64 * dt;
                let q1 = 0.25 * (1.43 * t).sin() + 0.05 * (6.9 * t).sin();
                let q2 = 0.18 * (1.67 * t).sin() + 0.04 * (6.1 * t).sin();
                let mut effort = [0.0; 2];
                for (j, e) in effort.iter_mut().enumerate() {
                    // xorshift: a small white torque noise.
                    noise ^= noise << 13;
                    noise ^= noise >> 7;
                    noise ^= noise << 17;
                    let n = (noise as f64 / u64::MAX as f64 - 0.5) * 0.01;
                    *e = 0.1 + truth.internal_torque_nm(j, q1, q2, l) + n;
                }
                samples.push(DynamicsSample {
                    t_s: t,
                    position: [q1, q2, l],
                    effort_nm: effort,
                });
            }
        }
        for joint in [1u8, 2] {
            let fit = fit_dynamics_with_gravity(
                joint,
                &samples,
                &starts,
                |_| 0.1,
                4.0,
                Some(0.155),
                Excitation::Smooth,
            )
            .unwrap();
            let g = fit.params.distal_gravity.expect("the weight is modelled");
            assert_eq!(g.reference_insertion_m, 0.155);
            for k in 0..3 {
                if joint == 1 && k == 1 {
                    assert_eq!((g.weight_n[k], g.weight_sigma_n[k]), (0.0, 0.0), "{g:?}");
                    continue;
                }
                let err = (g.weight_n[k] - w[k]).abs();
                assert!(
                    err < 4.0 * g.weight_sigma_n[k] + 1e-4,
                    "joint {joint} {k}: {g:?}"
                );
                assert!(err < 0.02, "joint {joint} {k}: {g:?}");
            }
            // One depth cannot tell the weight from the torque offset: not modelled.
            let one = fit_dynamics_with_gravity(
                joint,
                &samples[..15_000],
                &[0],
                |_| 0.1,
                4.0,
                Some(0.155),
                Excitation::Smooth,
            )
            .unwrap();
            assert_eq!(one.params.distal_gravity, None);
        }
    }

    /// The excitation played through a console: set points held for about 10 ms each (a
    /// `servo_jp` per console period) and followed by a PD controller of the simulated PSM's
    /// gains, rows at the boards' 1.5 kHz with one in five lost. The controller kicks at every
    /// step; the per-sample fit reads the ripple as a model it cannot place, the averaging of
    /// [`Excitation::Stepped`] recovers the joint's inertia and friction, and its residual std
    /// keeps the effort's sample noise.
    #[test]
    fn recovers_a_multisine_played_in_steps_through_a_controller() {
        let (j0, j2, b, f) = (0.05, 0.4, 0.2, 0.03);
        let (kp, kd) = (150.0, 6.0);
        // a servo_jp every 151 physics steps (99.3 Hz): not locked to the rows' phase, as a
        // console's clock is not to the boards'
        const STEPS: usize = 151;
        let physics_dt = 1.0 / 15_000.0;
        let mut samples = Vec::new();
        let mut starts = Vec::new();
        let mut noise = 0x9e37_79b9_7f4a_7c15u64;
        // nearly Gaussian, std 1: the sum of 12 uniforms in [-0.5, 0.5)
        let mut white = move || {
            (0..12)
                .map(|_| {
                    noise ^= noise << 13;
                    noise ^= noise >> 7;
                    noise ^= noise << 17;
                    noise as f64 / u64::MAX as f64 - 0.5
                })
                .sum::<f64>()
        };
        let noise_std = 0.003;
        for (d, l) in [0.1, 0.15, 0.2].into_iter().enumerate() {
            starts.push(samples.len());
            let inertia = j0 + j2 * l * l;
            let target = |t: f64| -> (f64, f64) {
                let (w, amp) = ([2.0, 3.7, 5.3], [0.2, 0.08, 0.03]);
                (0..3).fold((0.0, 0.0), |(q, v), k| {
                    (
                        q + amp[k] * (w[k] * t).sin(),
                        v + amp[k] * w[k] * (w[k] * t).cos(),
                    )
                })
            };
            let (mut q, mut v) = target(0.0);
            let mut set = (q, v);
            let t_seg = d as f64 * 12.0;
            for step in 0..150_000usize {
                let t = step as f64 * physics_dt;
                if step % STEPS == 0 {
                    set = target(t);
                }
                let tau = kp * (set.0 - q) + kd * (set.1 - v);
                // rows at 1.5 kHz, one in five lost (a service that missed cycles)
                if step % 10 == 0 && (step / 10) % 5 != 3 {
                    samples.push(DynamicsSample {
                        t_s: t_seg + t,
                        position: [q, q, l],
                        effort_nm: [0.1 + tau + noise_std * white(), 0.0],
                    });
                }
                let acc = (tau - b * v - f * (v / 0.001).tanh()) / inertia;
                v += acc * physics_dt;
                q += v * physics_dt;
            }
        }
        let fit = |excitation| {
            fit_dynamics_with_gravity(1, &samples, &starts, |_| 0.1, 4.0, None, excitation).unwrap()
        };
        let stepped = fit(Excitation::Stepped {
            commanded_hz: 15_000.0 / 151.0,
        });
        let p = stepped.params;
        assert!((p.inertia_kg_m2[0] - j0).abs() < 0.05 * j0, "{stepped:?}");
        assert!((p.inertia_kg_m2[1] - j2).abs() < 0.25 * j2, "{stepped:?}");
        assert!((p.viscous_nm_s_per_rad - b).abs() < 0.05 * b, "{stepped:?}");
        assert!((p.coulomb_nm - f).abs() < 0.3 * f, "{stepped:?}");
        // the effort's noise is in the residual the run time gates with, though the averaging
        // hid it from the fit: measured through the controller's ripple and the lost rows, on
        // the safe side (the kicks touch 3 samples' lines in 15 and raise the median)
        let y: Vec<f64> = samples.iter().map(|s| s.effort_nm[0]).collect();
        let t: Vec<f64> = samples.iter().map(|s| s.t_s).collect();
        let noise = sample_noise(&y, &t, &starts);
        assert!(
            (0.9 * noise_std..1.5 * noise_std).contains(&noise),
            "{noise} for {noise_std}"
        );
        assert!(p.residual_std_nm >= noise, "{stepped:?}");
        assert!(p.residual_std_nm < 0.02, "{stepped:?}");
        // the per-sample fit of the same rows
        let smooth = fit(Excitation::Smooth);
        let s = smooth.params;
        assert!((s.inertia_kg_m2[0] - j0).abs() > 0.1 * j0, "{smooth:?}");
        assert!(s.residual_std_nm > 5.0 * p.residual_std_nm, "{smooth:?}");
        // rows at the command rate itself (a console's measured_js) are fitted as smooth ones
        let console: Vec<_> = samples.iter().step_by(15).copied().collect();
        let console_starts: Vec<_> = starts.iter().map(|s| s / 15).collect();
        let a = fit_dynamics_with_gravity(
            1,
            &console,
            &console_starts,
            |_| 0.1,
            4.0,
            None,
            Excitation::Stepped {
                commanded_hz: 15_000.0 / 151.0,
            },
        )
        .unwrap();
        let b2 = fit_dynamics_with_gravity(
            1,
            &console,
            &console_starts,
            |_| 0.1,
            4.0,
            None,
            Excitation::Smooth,
        )
        .unwrap();
        assert_eq!(a.params, b2.params);
    }
}
