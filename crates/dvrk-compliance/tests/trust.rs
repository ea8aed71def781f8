//! Issue 20: the compensator knows when it does not know. Synthetic samples with known truth:
//! warm-up and gaps, a velocity step, light contact growing from zero, the insertion margin, a
//! file without a dynamics model, and the bound that comes with every sample.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic

mod common;

use dvrk_compliance::dynamics::{DistalGravityParams, DynamicsParams, WINDOW};
use dvrk_compliance::model::{
    CONTACT_CHANGE_HOLD_S, EFFORT_RATE_SAMPLES, FADE_S, INSERTION_FADE_M, INSERTION_MARGIN_M,
    TIP_LEVER_EXTRA_M, TORQUE_OFFSET_MARGIN_RAD, TRANSIENT_HOLD_S, TRANSIENT_RESIDUAL_RAD,
};
use dvrk_compliance::{Compensator, ComplianceConfig, trust};

/// Joint 1: 1/K = 20 N·m/rad, backlash 2 mrad; joint 2: 1/K = 100 L (K = 0.1 at 0.1 m), backlash
/// 1 mrad; range [0.09, 0.22] m; tau_0 = 0.1 N·m; tau_min 0.05 N·m.
const BASE: &str = r#"
model = "paper"
[[joint]]
index = 1
backlash_rad = 0.002
tau_min_nm = 0.05
inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 20.0]
insertion_range_m = [0.09, 0.22]
torque_offset = { position_rad = [0.0], effort_nm = [0.1] }
[[joint]]
index = 2
backlash_rad = 0.001
tau_min_nm = 0.05
inverse_compliance_nm_per_rad = [0.0, 0.0, 100.0, 0.0]
insertion_range_m = [0.09, 0.22]
torque_offset = { position_rad = [0.0], effort_nm = [0.1] }
"#;

const DYN: DynamicsParams = DynamicsParams {
    inertia_kg_m2: [0.05, 0.02],
    viscous_nm_s_per_rad: 0.2,
    coulomb_nm: 0.0,
    stick_velocity_rad_per_s: 0.002,
    residual_std_nm: 0.005,
    gate_sigmas: 4.0,
    max_acceleration_rad_per_s2: Some(4.0),
    distal_gravity: None,
};

fn config(dynamics: bool) -> ComplianceConfig {
    config_with(dynamics.then_some(DYN))
}

/// [`BASE`] with `dynamics` on both joints.
fn config_with(dynamics: Option<DynamicsParams>) -> ComplianceConfig {
    let mut p = common::params(BASE).unwrap();
    for j in &mut p.joint {
        j.dynamics = dynamics;
    }
    ComplianceConfig::from_params(p).unwrap()
}

const DT: f64 = 1.0 / 1500.0;

/// Feeds `n` still samples at insertion `l` with external torque `tau` on both joints, from
/// sample `k0`; returns the last correction.
fn still(
    c: &mut Compensator,
    cfg: &ComplianceConfig,
    k0: usize,
    n: usize,
    l: f64,
    tau: f64,
) -> dvrk_compliance::Correction {
    let mut out = None;
    for k in k0..k0 + n {
        out = Some(c.correct(
            cfg,
            k as f64 * DT,
            &[0.1, -0.1, l],
            &[0.1 + tau, 0.1 + tau, 0.0],
        ));
    }
    out.unwrap()
}

#[test]
fn warm_up_and_gaps_withhold_the_correction_and_say_so() {
    let cfg = config(true);
    let mut c = Compensator::new();
    for k in 0..WINDOW - 1 {
        let r = c.correct(&cfg, k as f64 * DT, &[0.1, -0.1, 0.12], &[0.6, 0.6, 0.0]);
        assert_eq!(r.delta_rad, [0.0, 0.0], "sample {k}");
        assert_ne!(r.flags & trust::WARMUP, 0);
        assert_eq!(r.flags & trust::GAP, 0, "no gap at start");
        assert_eq!(r.weight, [0.0, 0.0]);
    }
    // Held 0.5 N·m long after the window filled: the full correction, no flag.
    let r = still(&mut c, &cfg, WINDOW, 600, 0.12, 0.5);
    assert_eq!(r.flags, 0, "{r:?}");
    assert_eq!(r.weight, [1.0, 1.0]);
    // 0.002 + 0.5 / 20 = 0.027 rad (the play's evidence is complete at 0.5 N·m).
    assert!((r.delta_rad[0] - 0.027).abs() < 1e-6, "{r:?}");
    // A 50 ms gap restarts the filter: warm-up again, with GAP.
    let t = (WINDOW + 600) as f64 * DT + 0.05;
    let r = c.correct(&cfg, t, &[0.1, -0.1, 0.12], &[0.6, 0.6, 0.0]);
    assert_eq!(
        r.flags & (trust::WARMUP | trust::GAP),
        trust::WARMUP | trust::GAP
    );
    assert_eq!(r.delta_rad, [0.0, 0.0]);
}

/// A velocity step in free space (0 to 0.5 rad/s within 2 ms, as a controller makes it), the
/// effort holding the inertia's and the friction's torque: the filter lags, and the correction
/// is withheld instead of taking the lag for contact.
#[test]
fn an_abrupt_start_is_not_taken_for_contact() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let l: f64 = 0.12;
    let j = DYN.inertia(l);
    let (mut q, mut v) = (0.0, 0.0);
    let mut worst: f64 = 0.0;
    let mut transient = 0;
    let n = 3000;
    for k in 0..n {
        let t = k as f64 * DT;
        // Still for 1 s, then a ramp over 3 samples to 0.5 rad/s (acceleration 375 rad/s²).
        let target = if t < 1.0 { 0.0 } else { 0.5 };
        let a = ((target - v) / DT).clamp(-375.0, 375.0);
        v += a * DT;
        q += v * DT;
        let effort = 0.1 + j * a + DYN.viscous_nm_s_per_rad * v;
        let r = c.correct(&cfg, t, &[q, 0.0, l], &[effort, 0.1, 0.0]);
        if t > 0.5 {
            worst = worst.max(r.delta_rad[0].abs());
        }
        if r.flags & trust::TRANSIENT != 0 {
            transient += 1;
        }
    }
    // The play alone would be 2 mrad, a 0.5 N·m false contact 27 mrad.
    assert!(worst < 2e-4, "worst correction {worst} rad");
    assert!(transient > 0, "the step was not flagged");
    // Withheld while the step is in the filter's window, then for the hold and the fade: a few
    // tenths of a second at most, not for the rest of the motion.
    let max_flagged = (2.0 * (TRANSIENT_HOLD_S + FADE_S) / DT) as usize + 2 * WINDOW;
    assert!(transient < max_flagged, "{transient} samples flagged");
}

/// A velocity step at 30 rad/s² with the tip pressed with 0.5 N·m (and without): once the filter's lag
/// is over (`MOTION_LAG_S` after the last abrupt sample), a contact that far beyond the torque's
/// noise and its sway ends the hold, and the correction fades back in before a free motion's
/// hold and fade are over. Free, the hold stays whole.
#[test]
fn an_abrupt_start_in_a_firm_contact_is_corrected_again_after_the_lag() {
    let cfg = config(true);
    let l: f64 = 0.12;
    let j = DYN.inertia(l);
    let mut back_after = [f64::NAN; 2];
    for (i, contact) in [0.0, 0.5].into_iter().enumerate() {
        let mut c = Compensator::new();
        let (mut q, mut v) = (0.0, 0.0);
        let mut last_flagged = f64::NEG_INFINITY;
        for k in 0..3000 {
            let t = k as f64 * DT;
            let target = if t < 1.0 { 0.0 } else { 0.5 };
            let a = ((target - v) / DT).clamp(-30.0, 30.0);
            v += a * DT;
            q += v * DT;
            let effort = 0.1 + contact + j * a + DYN.viscous_nm_s_per_rad * v;
            let r = c.correct(&cfg, t, &[q, 0.0, l], &[effort, 0.1, 0.0]);
            if t > 1.0 && r.flags & trust::TRANSIENT != 0 {
                last_flagged = t;
            }
            if t > 1.0 && contact > 0.0 && r.weight[0] == 1.0 {
                // 0.002 + 0.5 / 20 rad once back, within the bound and most of it corrected.
                let off = (r.delta_rad[0] - 0.027).abs();
                assert!(off <= r.bound_rad[0] && off < 0.1 * 0.027, "{t}: {r:?}");
            }
        }
        back_after[i] = last_flagged - 1.0;
    }
    let [free, firm] = back_after;
    assert!(
        free >= TRANSIENT_HOLD_S + FADE_S,
        "free: back after {free} s"
    );
    // Measured: 0.18 s against 0.24 s (the transient's false contact leaves the torque's sway
    // high for a few of its 30 ms time constants, and the contact must stand out of it).
    assert!(
        firm < free - 0.04,
        "firm: back after {firm} s, free after {free} s"
    );
}

/// Joint 1 slides at 0.05 rad/s pressed with 0.2 N·m of contact, slows to a stop over 0.1 s and
/// stays stuck by its motor's friction while the controller's effort swings across it (as at a
/// turn), then past it. Returns `tau_ext_nm[0]` at the end of the swing and at the end, with
/// `coulomb` N·m of friction in the file and on the arm.
fn stuck_at_a_turn(coulomb: f64, swing: f64, beyond: f64) -> (f64, f64) {
    let dynamics = DynamicsParams {
        coulomb_nm: coulomb,
        ..DYN
    };
    let cfg = config_with(Some(dynamics));
    let mut c = Compensator::new();
    let l: f64 = 0.12;
    let j = DYN.inertia(l);
    let (v0, t_slow, t_stop) = (0.05, 1.0, 1.1);
    let mut q = 0.0;
    let mut end_of_swing = f64::NAN;
    let mut r = None;
    for k in 0..2400 {
        let t = k as f64 * DT;
        // The speed falls as a half cosine over 0.1 s: the model explains every sample of it.
        let (v, a) = if t < t_slow {
            (v0, 0.0)
        } else if t < t_stop {
            let x = std::f64::consts::PI * (t - t_slow) / (t_stop - t_slow);
            (
                0.5 * v0 * (1.0 + x.cos()),
                -0.5 * v0 * x.sin() * std::f64::consts::PI / (t_stop - t_slow),
            )
        } else {
            (0.0, 0.0)
        };
        q += v * DT;
        let moving = 0.1 + 0.2 + j * a + DYN.viscous_nm_s_per_rad * v + coulomb;
        // Stuck: the effort swings by `swing` over 0.1 s, then by `beyond` more over 0.1 s.
        let stuck = t - t_stop - 0.1;
        let effort = moving
            - swing * (stuck / 0.1).clamp(0.0, 1.0)
            - beyond * ((stuck - 0.1) / 0.1).clamp(0.0, 1.0);
        let out = c.correct(&cfg, t, &[q, 0.0, l], &[effort, 0.1, 0.0]);
        if stuck <= 0.1 {
            end_of_swing = out.tau_ext_nm[0];
        }
        r = Some(out);
    }
    (end_of_swing, r.unwrap().tau_ext_nm[0])
}

/// A motor stuck by its friction takes the controller's effort swing on its friction, not on the
/// shaft: as far as the friction reaches (`STUCK_FRICTION_RATIO` times the file's Coulomb
/// friction, from the last motion's side to the other), the external torque stays as it was
/// when the motor stuck; beyond, the rest is the shaft's. Before, the swing was read as contact:
/// 0.65 mm the wrong way at a turn of a simulated arm with 0.08 N·m of friction.
#[test]
fn a_motor_stuck_by_its_friction_does_not_read_the_swing_as_contact() {
    use dvrk_compliance::model::STUCK_FRICTION_RATIO;
    let f = 0.06;
    // Swung from +f to -1.2 f: all of it is friction.
    let (swung, _) = stuck_at_a_turn(f, 2.2 * f, 0.0);
    assert!(
        (swung - 0.2).abs() < 0.01,
        "external torque {swung} N·m, 0.2 expected"
    );
    // And 0.1 N·m further: the friction's reach ends at -1.5 f, the rest loads the shaft.
    let (_, past) = stuck_at_a_turn(f, 2.2 * f, 0.1);
    let expected = 0.2 - (2.2 * f + 0.1 - (1.0 + STUCK_FRICTION_RATIO) * f);
    assert!(
        (past - expected).abs() < 0.01,
        "{past} N·m, {expected} expected"
    );
    // A file without friction: the same swing is the shaft's, all of it.
    let (frictionless, _) = stuck_at_a_turn(0.0, 2.2 * f, 0.0);
    assert!(
        (frictionless - (0.2 - 2.2 * f)).abs() < 0.01,
        "{frictionless} N·m"
    );
}

/// A rubbing arm (0.08 N·m of Coulomb friction in its file) slides at 0.4 rad/s when its
/// controller starts to stop it: the effort falls 0.15 N·m over 8 samples before the motor
/// slows. Far from a reversal the friction cannot step, so the fall is a transient to withhold,
/// not 0.15 N·m of contact. With twice the friction allowed for everywhere, the detector saw
/// nothing until the fall passed 0.195 N·m, and the correction followed it.
#[test]
fn a_stop_on_a_rubbing_arm_is_withheld_from_its_first_samples() {
    let cfg = config_with(Some(DynamicsParams {
        coulomb_nm: 0.08,
        ..DYN
    }));
    let mut c = Compensator::new();
    let l: f64 = 0.12;
    let v = 0.4;
    let moving = 0.1 + DYN.viscous_nm_s_per_rad * v + 0.08;
    let mut before = None;
    let mut worst: f64 = 0.0;
    for k in 0..1500 + 12 {
        let t = k as f64 * DT;
        let fall = 0.15 * ((k as f64 - 1500.0) / 8.0).clamp(0.0, 1.0);
        let r = c.correct(&cfg, t, &[v * t, 0.0, l], &[moving - fall, 0.1, 0.0]);
        if k == 1499 {
            assert_eq!(r.flags & trust::TRANSIENT, 0, "{r:?}");
            before = Some(r.delta_rad[0]);
        } else if k >= 1500 {
            worst = worst.max((r.delta_rad[0] - before.unwrap()).abs());
        }
    }
    // 0.15 N·m through the shaft's 1/K = 20 N·m/rad would be 7.5 mrad.
    assert!(worst < 1e-3, "the correction moved {worst} rad");
}

/// A steady fast motion whose filter residual stays above the floor (a servo's tracking ripple)
/// is not a transient once the residual's own level has followed it; a velocity step on top of
/// it still is. Before the residual was weighed against its level, such a motion was withheld
/// (and flagged TRANSIENT) for as long as it lasted.
#[test]
fn a_steady_ripple_is_not_a_transient_but_a_step_on_top_of_it_is() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let l: f64 = 0.12;
    let n = 6000;
    let (mut flagged_steady, mut flagged_after_step) = (0, 0);
    for k in 0..n {
        let t = k as f64 * DT;
        // 0.3 rad/s plus a 150 Hz ripple of 80 µrad (residual of a 48-sample cubic about
        // 5e-5 rad, 2.5 times the floor); from 3 s on, a velocity step to 0.6 rad/s.
        let ripple = 8e-5 * (2.0 * std::f64::consts::PI * 150.0 * t).sin();
        let (q, v) = if t < 3.0 {
            (0.3 * t, 0.3)
        } else {
            (0.9 + 0.6 * (t - 3.0), 0.6)
        };
        let effort = 0.1 + DYN.viscous_nm_s_per_rad * v;
        let r = c.correct(&cfg, t, &[q + ripple, 0.0, l], &[effort, 0.1, 0.0]);
        if k == 200 {
            let residual = c.joint_state(0).unwrap().smoothness_residual_rad();
            assert!(
                residual > 1.5 * TRANSIENT_RESIDUAL_RAD,
                "the ripple's residual {residual} must be above the floor for this test"
            );
        }
        let transient = r.flags & trust::TRANSIENT != 0;
        if (2.0..3.0).contains(&t) {
            flagged_steady += usize::from(transient);
        }
        if (3.0..3.1).contains(&t) {
            flagged_after_step += usize::from(transient);
        }
    }
    assert_eq!(
        flagged_steady, 0,
        "the steady ripple was taken for a transient"
    );
    assert!(flagged_after_step > 0, "the velocity step was not flagged");
}

/// The slip of the two tests below: a still arm at 0.12 m settled under 0.3 N·m (samples
/// 0-599), then the torque drops to 0.15 N·m over samples 600-604, each step (0.03 N·m) under
/// the effort step's limit. Returns the settled correction and whether the slip was flagged
/// TRANSIENT; the next sample is 605.
fn settle_then_slip(
    c: &mut Compensator,
    cfg: &ComplianceConfig,
) -> (dvrk_compliance::Correction, bool) {
    let settled = still(c, cfg, 0, 600, 0.12, 0.3);
    let mut flagged = false;
    for i in 1..=5 {
        let r = still(c, cfg, 600 + i - 1, 1, 0.12, 0.3 - 0.03 * i as f64);
        flagged |= r.flags & trust::TRANSIENT != 0;
    }
    (settled, flagged)
}

/// Samples after the slip by which a contact change's hold and fade are over: the change
/// stays in the effort's window for EFFORT_RATE_SAMPLES samples, then the hold and the fade.
const AFTER_CONTACT_CHANGE: usize =
    ((CONTACT_CHANGE_HOLD_S + FADE_S) / DT) as usize + EFFORT_RATE_SAMPLES + 2;

/// A contact's load that changes fast while the arm's motion stays smooth (a tip slipping: the
/// shaft torque drops from 0.3 to 0.15 N·m within 3 ms, each sample's change under the effort
/// step's limit) is withheld for the short hold of a contact change, not for a motion's
/// transient; then the new load is corrected in full. With the motion's hold, a tip sticking and
/// slipping had the correction withheld in about half of its cycles.
#[test]
fn a_fast_contact_change_is_withheld_briefly_not_like_a_motion_transient() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let (settled, flagged) = settle_then_slip(&mut c, &cfg);
    assert_eq!(settled.flags, 0, "{settled:?}");
    assert!(flagged, "the slip was not flagged");
    // The hold and the fade are far shorter than a motion's transient.
    const { assert!(CONTACT_CHANGE_HOLD_S + FADE_S < 0.5 * (TRANSIENT_HOLD_S + FADE_S)) };
    let back = still(&mut c, &cfg, 605, AFTER_CONTACT_CHANGE, 0.12, 0.15);
    assert_eq!(back.flags & trust::TRANSIENT, 0, "{back:?}");
    assert_eq!(back.weight, [1.0, 1.0], "{back:?}");
    // 0.002 + 0.15 / 20 = 0.0095 rad on joint 1.
    assert!(
        (back.delta_rad[0] - 0.0095).abs() < 0.05 * 0.0095,
        "{back:?}"
    );
}

/// A tip pressed ever harder (8 N·m/s, 0.043 N·m over the effort's window, past the contact
/// change's limit in every sample): once the contact is several times its change over the lag,
/// the correction follows it instead of being withheld for as long as the load grows (a random
/// surface scenario kept 90 mrad of joint 1's deflection that way), and the bound takes the lag's
/// change. The same ramp from no contact is held until the contact is sure of its side.
#[test]
fn a_contact_pressed_ever_harder_is_followed_once_its_side_is_sure() {
    const RATE: f64 = 8.0;
    let window_change = RATE * EFFORT_RATE_SAMPLES as f64 * DT;
    assert!(
        window_change > 0.035,
        "the ramp must count as a fast change"
    );
    let cfg = config(true);
    for start in [0.3, 0.0] {
        let mut c = Compensator::new();
        still(&mut c, &cfg, 0, 600, 0.12, start);
        let (mut followed, mut held_early) = (0, 0);
        let n = (1.2 / RATE / DT) as usize;
        // Pressed already: followed once the ramp fills the effort's window. From no contact:
        // held until the 10 ms average is three window changes (about 0.21 N·m, 26 ms), then
        // the hold and the fade.
        let from = if start > 0.0 {
            EFFORT_RATE_SAMPLES
        } else {
            ((0.03 + CONTACT_CHANGE_HOLD_S + FADE_S) / DT) as usize
        };
        for i in 1..=n {
            let tau = start + RATE * i as f64 * DT;
            let r = still(&mut c, &cfg, 599 + i, 1, 0.12, tau);
            let withheld = r.flags & trust::TRANSIENT != 0;
            if tau < 2.0 * window_change {
                held_early += usize::from(withheld);
            }
            if i > from {
                assert!(!withheld, "start {start}, sample {i}: {r:?}");
                assert_eq!(r.weight[0], 1.0, "start {start}, sample {i}: {r:?}");
                // Joint 1: 0.002 + tau / 20 rad; the synthetic effort does not lag.
                let truth = 0.002 + tau / 20.0;
                assert!((r.delta_rad[0] - truth).abs() < 1e-4, "{tau}: {r:?}");
                // The bound holds the lag's change: K times the window's change, 1.96 sigma.
                assert!(
                    r.bound_rad[0] >= 1.9 * window_change / 20.0,
                    "{tau}: bound {} rad: {r:?}",
                    r.bound_rad[0]
                );
                followed += 1;
            }
        }
        assert_eq!(followed, n - from, "start {start}");
        // From no contact the first samples of the ramp are a contact change to be held.
        if start == 0.0 {
            assert!(held_early > 0, "the ramp from no contact was not held");
        }
    }
}

/// The other joint's fast effort change holds a joint at rest without contact (a motion's start
/// that the other joint's detector saw first builds on this one as a contact would), not one
/// moving on its own: joint 2 slips (0.3 to 0.15 N·m in 3 ms) while joint 1 is free, either at
/// rest or turning steadily at 0.3 rad/s. Holding a moving joint for the other's changes cost
/// free multi-sine motions up to 13 points of raw.
#[test]
fn the_other_joints_contact_change_holds_a_joint_only_just_after_rest() {
    let cfg = config(true);
    let l = 0.12;
    for speed in [0.0, 0.3] {
        let mut c = Compensator::new();
        // Joint 1 free (its effort is the model's: the offset and the viscous friction), joint 2
        // pressed with 0.3 N·m for 0.4 s, then slipping to 0.15 N·m.
        let step = |c: &mut Compensator, k: usize, tau2: f64| {
            let t = k as f64 * DT;
            let e1 = 0.1 + DYN.viscous_nm_s_per_rad * speed;
            c.correct(&cfg, t, &[0.1 + speed * t, -0.1, l], &[e1, 0.1 + tau2, 0.0])
        };
        let mut r = step(&mut c, 0, 0.3);
        for k in 1..600 {
            r = step(&mut c, k, 0.3);
        }
        assert_eq!(r.weight, [1.0, 1.0], "speed {speed}: {r:?}");
        let mut held = false;
        for i in 1..=5 {
            r = step(&mut c, 599 + i, 0.3 - 0.03 * i as f64);
            held |= r.weight[0] < 1.0;
        }
        for k in 605..615 {
            r = step(&mut c, k, 0.15);
            held |= r.weight[0] < 1.0;
        }
        assert!(
            r.weight[1] < 1.0,
            "speed {speed}: joint 2's slip not held: {r:?}"
        );
        assert_eq!(held, speed == 0.0, "speed {speed}: joint 1 held {held}");
    }
}

/// Without a dynamics model the same fast effort change may be the motion's own (a stop
/// settling): it holds the correction as long as any transient.
#[test]
fn without_a_dynamics_model_a_fast_effort_change_holds_as_long_as_a_transient() {
    let cfg = config(false);
    let mut c = Compensator::new();
    let (settled, _) = settle_then_slip(&mut c, &cfg);
    assert_eq!(settled.weight, [1.0, 1.0], "{settled:?}");
    let n = AFTER_CONTACT_CHANGE;
    let r = still(&mut c, &cfg, 605, n, 0.12, 0.15);
    assert_ne!(r.flags & trust::TRANSIENT, 0, "{r:?}");
    assert!(r.weight[0] < 1.0, "{r:?}");
    // The transient's hold and fade, then the still arm's own fade (STILL_ONLY).
    let rest = ((TRANSIENT_HOLD_S + 2.0 * FADE_S) / DT) as usize + 2;
    let back = still(&mut c, &cfg, 605 + n, rest, 0.12, 0.15);
    assert_eq!(back.weight, [1.0, 1.0], "{back:?}");
}

/// Normal noise of standard deviation 1 (the sum of 12 uniforms less 6), from a fixed seed.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        let mut sum = 0.0;
        for _ in 0..12 {
            // xorshift64
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            sum += (self.0 >> 11) as f64 / (1u64 << 53) as f64;
        }
        sum - 6.0
    }
}

/// An arm whose effort is noisier than the one the file was fitted on (0.0125 N·m, 2.5 times
/// the simulator's 5 mN·m; the file's residual says 5 mN·m): the transient limits follow the
/// noise as measured, so its own sample-to-sample changes are not taken for abrupt ones and a
/// steady contact is corrected. With the fixed limits, eight samples of this noise changed the
/// effort by more than `TRANSIENT_EFFORT_CHANGE_NM` in about one sample in twenty, and the
/// correction was withheld in nearly every cycle.
#[test]
fn an_effort_noisier_than_the_fit_saw_is_measured_not_taken_for_transients() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let mut noise = Noise(0x2545_f491_4f6c_dd1d);
    let (sigma, tau, l) = (0.0125, 0.3, 0.12);
    // The measured noise settles within a few of its time constants (0.5 s); then 3 s.
    let (settle, n) = (3000, 4500);
    let (mut trusted, mut delta) = (0, [0.0; 2]);
    for k in 0..settle + n {
        let e = [
            0.1 + tau + sigma * noise.next(),
            0.1 + tau + sigma * noise.next(),
        ];
        let r = c.correct(&cfg, k as f64 * DT, &[0.1, -0.1, l], &[e[0], e[1], 0.0]);
        if k >= settle {
            trusted += usize::from(r.weight == [1.0, 1.0]);
            delta[0] += r.delta_rad[0] / n as f64;
            delta[1] += r.delta_rad[1] / n as f64;
        }
    }
    assert!(
        trusted as f64 >= 0.9 * n as f64,
        "trusted in {trusted} of {n} samples"
    );
    // The correction: the play and the spring, 0.002 + 0.3 / 20 and 0.001 + 0.3 / 12 rad.
    for (j, want) in [0.017, 0.026].into_iter().enumerate() {
        assert!(
            (delta[j] - want).abs() < 0.05 * want,
            "joint {}: mean correction {} rad, want {want}",
            j + 1,
            delta[j]
        );
    }
}

/// Outside its torque-offset table a joint's `tau_0` is the table's end value, wrong by the
/// counterbalance's slope: the correction fades out over the margin and the flag says why.
#[test]
fn outside_the_torque_offset_table_the_correction_fades_out() {
    let mut p = common::params(BASE).unwrap();
    for j in &mut p.joint {
        j.dynamics = Some(DYN);
        j.torque_offset.position_rad = vec![-0.2, 0.2];
        j.torque_offset.effort_nm = vec![0.1, 0.1];
    }
    let cfg = ComplianceConfig::from_params(p).unwrap();
    let run = |q1: f64| {
        let mut c = Compensator::new();
        let mut out = None;
        for k in 0..1500 {
            out = Some(c.correct(&cfg, k as f64 * DT, &[q1, -0.1, 0.12], &[0.6, 0.6, 0.0]));
        }
        out.unwrap()
    };
    let inside = run(0.2);
    assert_eq!(inside.flags & trust::POSITION_OUT_OF_RANGE, 0, "{inside:?}");
    assert!(inside.delta_rad[0] > 0.02, "{inside:?}");
    let half = run(0.2 + 0.5 * TORQUE_OFFSET_MARGIN_RAD);
    assert_ne!(half.flags & trust::POSITION_OUT_OF_RANGE, 0, "{half:?}");
    assert!((half.weight[0] - 0.5).abs() < 1e-6, "{half:?}");
    assert!((half.delta_rad[0] - 0.5 * inside.delta_rad[0]).abs() < 1e-6);
    // Joint 2 is inside its table: untouched.
    assert_eq!(half.weight[1], 1.0, "{half:?}");
    let beyond = run(-0.2 - TORQUE_OFFSET_MARGIN_RAD - 0.01);
    assert_ne!(beyond.flags & trust::POSITION_OUT_OF_RANGE, 0, "{beyond:?}");
    assert_eq!(beyond.delta_rad[0], 0.0, "{beyond:?}");
    // Withheld, the bound takes the whole play and the spring.
    assert!(beyond.bound_rad[0] > 0.002 + 0.5 / 20.0, "{beyond:?}");
}

/// The side's evidence is taken with its calm width only once it has kept its sign: right after
/// it names the other side, the same torque gets a smaller share of the play (the wrong-way
/// cycles of issue 20 came there), and 0.1 s later (the hold and the fade,
/// `SIDE_FLIP_HOLD_S` each) the share is back to the steady side's. The new side is named only
/// as far as the shaft's slow flight across the play has gone (`FLIGHT_INERTIA_FACTOR`): under
/// a few mN·m the distal part takes tens of ms to cross, so 30 ms after the turn the
/// correction has left the old side but names the new one by little or nothing yet.
#[test]
fn a_side_just_changed_is_corrected_less_than_a_steady_one() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let tau = 0.004; // a few times the averaged torque's noise, below the contact floor
    let steady = still(&mut c, &cfg, 0, 600, 0.12, tau);
    assert!(steady.delta_rad[0] > 0.0 && steady.flags & trust::TRANSIENT == 0);
    // The torque turns to the other side; 30 ms later the 10 ms average has followed it.
    let just = still(&mut c, &cfg, 600, 45, 0.12, -tau);
    assert_eq!(just.flags & trust::TRANSIENT, 0, "{just:?}");
    assert!(just.delta_rad[0] <= 0.0, "{just:?}");
    assert!(
        just.delta_rad[0].abs() < 0.7 * steady.delta_rad[0],
        "{} against {}",
        just.delta_rad[0],
        steady.delta_rad[0]
    );
    // 0.15 s after the change: as steady as before, on the other side.
    let later = still(&mut c, &cfg, 645, 180, 0.12, -tau);
    assert!(
        (later.delta_rad[0] + steady.delta_rad[0]).abs() < 1e-3 * steady.delta_rad[0],
        "{} against {}",
        later.delta_rad[0],
        steady.delta_rad[0]
    );
}

/// Light contact: the correction grows from zero with the torque, without a step, and reaches
/// the paper's formula once the torque is well above the noise.
#[test]
fn light_contact_grows_smoothly_from_zero() {
    let cfg = config(true);
    let mut last = 0.0;
    let mut max_jump: f64 = 0.0;
    let mut at_zero = f64::NAN;
    for i in 0..=200 {
        let tau = f64::from(i) * 0.001; // 0 to 0.2 N·m
        let mut c = Compensator::new();
        let r = still(&mut c, &cfg, 0, 400, 0.12, tau);
        if i == 0 {
            at_zero = r.delta_rad[0];
        }
        max_jump = max_jump.max((r.delta_rad[0] - last).abs());
        assert!(r.delta_rad[0] >= last - 1e-12, "not monotonic at {tau}");
        last = r.delta_rad[0];
    }
    assert_eq!(at_zero, 0.0);
    // The paper's gate would jump by backlash + K tau_min = 0.002 + 0.0025 rad at once; here the
    // play comes in over about the averaged torque's noise (1.37 mrad per mN·m at the steepest,
    // near zero: a still arm's evidence that keeps its sign is taken with one noise's width,
    // `CALM_FREE_EVIDENCE_SIGMAS`; 0.52 mrad per mN·m with three) and the spring over the floor's
    // width.
    assert!(max_jump < 1.6e-3, "largest step {max_jump} rad per mN·m");
    // At 0.2 N·m: the paper's 0.002 + 0.2 / 20 = 0.012 rad.
    assert!((last - 0.012).abs() < 1e-5, "{last}");
}

#[test]
fn insertion_is_extrapolated_within_the_margin_and_refused_beyond() {
    let cfg = config(true);
    let run = |l: f64| {
        let mut c = Compensator::new();
        still(&mut c, &cfg, 0, 400, l, 0.5)
    };
    let inside = run(0.09);
    assert_eq!(inside.flags, 0, "{inside:?}");
    // 5 mm below: joint 2's K = 1 / (100 * 0.085) is used, not the range end's 1 / 9.
    let near = run(0.085);
    assert_eq!(near.flags, trust::INSERTION_EXTRAPOLATED, "{near:?}");
    assert!(
        (near.delta_rad[1] - (0.001 + 0.5 / 8.5)).abs() < 1e-6,
        "{near:?}"
    );
    assert!(near.bound_rad[1] > inside.bound_rad[1]);
    // Beyond the margin: flagged, nothing corrected.
    let far = run(0.09 - INSERTION_MARGIN_M - 0.005);
    assert_ne!(far.flags & trust::INSERTION_OUT_OF_RANGE, 0, "{far:?}");
    assert_eq!(far.delta_rad, [0.0, 0.0]);
    assert!(far.bound_rad[1] > 0.5 / 9.0, "{far:?}");
    let above = run(0.22 + INSERTION_MARGIN_M + INSERTION_FADE_M + 0.001);
    assert_eq!(above.delta_rad, [0.0, 0.0]);
    // Between the margin and the fade's end: part of the correction, flagged as reduced.
    let fading = run(0.22 + INSERTION_MARGIN_M + 0.5 * INSERTION_FADE_M);
    let inside_above = run(0.22);
    for j in 0..2 {
        assert!((fading.weight[j] - 0.5).abs() < 1e-5, "{fading:?}");
        assert!(
            (0.3..0.7).contains(&(fading.delta_rad[j] / inside_above.delta_rad[j])),
            "{fading:?} vs {inside_above:?}"
        );
    }
    assert_eq!(
        fading.flags & (trust::INSERTION_EXTRAPOLATED | trust::REDUCED),
        trust::INSERTION_EXTRAPOLATED | trust::REDUCED
    );
}

/// Without a dynamics model the effort holds the motion's torque: the correction acts only while
/// the arm is still, and the flags say so.
#[test]
fn without_a_dynamics_model_only_a_still_arm_is_corrected() {
    let cfg = config(false);
    let mut c = Compensator::new();
    let mut corrected_moving = 0;
    let mut flagged_moving = 0;
    let n = 3000;
    for k in 0..n {
        let t = k as f64 * DT;
        // Moving (0.3 rad/s sine) for 1 s with 0.5 N·m of effort, then still.
        let q = if t < 1.0 {
            0.05 * (6.0 * t).sin()
        } else {
            0.05 * 6.0f64.sin()
        };
        let r = c.correct(&cfg, t, &[q, 0.0, 0.12], &[0.6, 0.6, 0.0]);
        if t < 1.0 && k >= WINDOW {
            corrected_moving += usize::from(r.delta_rad[0] != 0.0);
            flagged_moving += usize::from(r.flags & trust::STILL_ONLY != 0);
        }
        if t > 1.4 {
            assert_eq!(r.flags & trust::STILL_ONLY, 0, "t {t}: {r:?}");
            assert!(
                (r.delta_rad[0] - (0.002 + 0.5 / 20.0)).abs() < 1e-9,
                "{r:?}"
            );
        }
    }
    assert_eq!(corrected_moving, 0);
    assert_eq!(flagged_moving, 1500 - WINDOW);
}

#[test]
fn every_sample_carries_a_bound_that_holds_the_tip_lever() {
    let cfg = config(true);
    let mut c = Compensator::new();
    for tau in [0.0, 0.02, 0.5] {
        let r = still(&mut c, &cfg, 0, 400, 0.15, tau);
        for j in 0..2 {
            assert!(r.bound_rad[j] > 0.0 && r.bound_rad[j].is_finite(), "{r:?}");
        }
        let lever = 0.15 + TIP_LEVER_EXTRA_M;
        let norm = r.bound_rad[0].hypot(r.bound_rad[1]);
        // The joints' systematic parts add as a vector, their noise as a 2-D normal: between
        // the joint bounds' norm with one-sided and with 2-D quantiles of the noise.
        assert!(
            r.tip_bound_m > 0.8 * lever * norm && r.tip_bound_m <= 1.25 * lever * norm,
            "tip {} lever {lever} norm {norm}: {r:?}",
            r.tip_bound_m
        );
        c.reset();
    }
    // With the side of the play unknown (no torque) the bound spans the play; in firm contact
    // it shrinks to the elastic part's uncertainty.
    let free = still(&mut Compensator::new(), &cfg, 0, 400, 0.15, 0.0);
    let firm = still(&mut Compensator::new(), &cfg, 0, 400, 0.15, 0.5);
    assert!(free.bound_rad[0] >= 0.95 * 0.002, "{free:?}");
    assert!(firm.bound_rad[0] < free.bound_rad[0], "{firm:?} {free:?}");
}

#[test]
fn the_tip_bound_adds_the_biases_as_a_vector_and_the_noise_as_a_2d_normal() {
    use dvrk_compliance::model::{BoundParts, tip_bound_from_parts};
    let lever = 0.1 + TIP_LEVER_EXTRA_M;
    // Systematic parts only: their norm through the lever (pitch 0: both joints' full lever).
    let biased = [
        BoundParts {
            bias: 3e-3,
            sigma: 0.0,
        },
        BoundParts {
            bias: 4e-3,
            sigma: 0.0,
        },
    ];
    let b = tip_bound_from_parts(0.1, 0.0, &biased);
    assert!((b - lever * 5e-3).abs() < 1e-12, "{b}");
    // A yaw error moves the tip by cos(pitch) of the lever.
    let b = tip_bound_from_parts(0.1, 1.0, &biased);
    let expected = lever * (1.0f64.cos() * 3e-3).hypot(4e-3);
    assert!((b - expected).abs() < 1e-12, "{b} {expected}");
    // Noise only: the 2-D 95% radius, sqrt(chi2_2(0.95)) = 2.4477 sigma (wider than the 1.96
    // this one joint's noise needs; see `R95_2D`).
    let noisy = [
        BoundParts {
            bias: 0.0,
            sigma: 1e-3,
        },
        BoundParts {
            bias: 0.0,
            sigma: 0.0,
        },
    ];
    let b = tip_bound_from_parts(0.1, 0.0, &noisy);
    assert!((b / (lever * 1e-3) - 2.447_747).abs() < 1e-6, "{b}");
    // Bias far above the noise: the noise's one-sided 95% quantile on top.
    let both = [
        BoundParts {
            bias: 1e-2,
            sigma: 1e-4,
        },
        BoundParts::default(),
    ];
    let b = tip_bound_from_parts(0.1, 0.0, &both);
    assert!((b / lever - (1e-2 + 1.644_854e-4)).abs() < 1e-9, "{b}");
    // A non-finite insertion or pitch never gives a bound below the data's.
    assert!(tip_bound_from_parts(0.1, f64::NAN, &biased) >= lever * 5e-3 - 1e-15);
    // Each joint's own 95% bound is the bias plus 1.96 sigma.
    assert!((both[0].joint_bound() - (1e-2 + 1.959_964e-4)).abs() < 1e-9);
}

#[test]
fn the_fitted_stiffness_scatter_sets_the_bound_and_grows_outside_the_range() {
    // Two files that differ only in the stiffness scatter the fit measured: 0.5% and 3%.
    let with = |rel: f64| {
        let mut p = common::params(BASE).unwrap();
        for j in &mut p.joint {
            j.inverse_compliance_rel_sigma = Some(rel);
        }
        ComplianceConfig::from_params(p).unwrap()
    };
    let (tight, loose) = (with(0.005), with(0.03));
    assert!((tight.joint(0).unwrap().stiffness_rel_sigma() - 0.005).abs() < 1e-15);
    // A scatter below the floor is taken for the floor.
    assert!(
        (with(1e-5).joint(0).unwrap().stiffness_rel_sigma()
            - dvrk_compliance::model::STIFFNESS_REL_SIGMA_FLOOR)
            .abs()
            < 1e-15
    );
    // Firm contact (the elastic part dominates): the looser fit gives the wider bound.
    let rt = still(&mut Compensator::new(), &tight, 0, 400, 0.15, 0.5);
    let rl = still(&mut Compensator::new(), &loose, 0, 400, 0.15, 0.5);
    assert!(rl.bound_rad[0] > rt.bound_rad[0], "{rl:?} {rt:?}");
    // Within the extrapolation margin the bound grows with the distance from the range.
    let [lo, _] = tight.insertion_range_m(0).unwrap();
    let inside = still(&mut Compensator::new(), &tight, 0, 400, lo, 0.5);
    let half = still(
        &mut Compensator::new(),
        &tight,
        0,
        400,
        lo - 0.5 * INSERTION_MARGIN_M,
        0.5,
    );
    assert!(half.flags & trust::INSERTION_EXTRAPOLATED != 0, "{half:?}");
    let k_ratio = |r: &dvrk_compliance::Correction| r.bound_rad[0] / r.delta_rad[0].abs();
    assert!(k_ratio(&half) > k_ratio(&inside), "{half:?} {inside:?}");
}

#[test]
fn the_fitted_backlash_scatter_sets_the_bound() {
    // Two files with a dynamics model that differ only in the backlash scatter the fit measured.
    let with = |rel: Option<f64>| {
        let mut p = common::params(BASE).unwrap();
        for j in &mut p.joint {
            j.dynamics = Some(DYN);
            j.backlash_rel_sigma = rel;
        }
        ComplianceConfig::from_params(p).unwrap()
    };
    let (tight, loose, absent) = (with(Some(0.04)), with(Some(0.2)), with(None));
    assert!((tight.joint(0).unwrap().backlash_rel_sigma() - 0.04).abs() < 1e-15);
    assert_eq!(
        absent.joint(0).unwrap().backlash_rel_sigma(),
        dvrk_compliance::model::BACKLASH_REL_SIGMA
    );
    // A scatter below the floor is taken for the floor.
    assert_eq!(
        with(Some(1e-6)).joint(0).unwrap().backlash_rel_sigma(),
        dvrk_compliance::model::BACKLASH_REL_SIGMA_FLOOR
    );
    // A free arm at rest (the play dominates its bound): the looser fit gives the wider bound.
    let rt = still(&mut Compensator::new(), &tight, 0, 400, 0.15, 0.0);
    let rl = still(&mut Compensator::new(), &loose, 0, 400, 0.15, 0.0);
    assert!(
        rl.bound_parts[0].sigma > rt.bound_parts[0].sigma,
        "{rl:?} {rt:?}"
    );
    assert!(rl.bound_rad[0] > rt.bound_rad[0], "{rl:?} {rt:?}");
}

#[test]
fn a_free_arm_whose_torque_is_its_noise_gets_no_unseen_contact_in_its_bound() {
    // A still arm with no external torque: the averaged torque is zero, so the only random
    // parts are the backlash's scatter and the stiffness's (the torque noise does not enter a
    // correction made without contact evidence). The earlier bound took a contact of up to a
    // quarter of tau_min as possible in every such cycle (K floor / 3 = 2e-4 rad here).
    let mut p = common::params(BASE).unwrap();
    for j in &mut p.joint {
        j.dynamics = Some(DYN);
        j.backlash_rel_sigma = Some(0.01);
    }
    let cfg = ComplianceConfig::from_params(p).unwrap();
    let r = still(&mut Compensator::new(), &cfg, 0, 400, 0.15, 0.0);
    assert_eq!(r.weight, [1.0, 1.0], "{r:?}");
    // joint 1: play 2 mrad, its scatter taken at the floor (2.5%: 5e-5 rad); K = 1/20 rad/N·m.
    let backlash_part = dvrk_compliance::model::BACKLASH_REL_SIGMA_FLOOR * 0.002;
    assert!(r.bound_parts[0].sigma < 1.2 * backlash_part, "{r:?}");
    // A light contact below the evidence floor is in the bound at its measured size.
    let light = still(&mut Compensator::new(), &cfg, 0, 400, 0.15, 0.01);
    assert!(light.bound_parts[0].sigma > 0.5 * 0.01 / 20.0, "{light:?}");
}

#[test]
fn a_withheld_bound_takes_the_free_load_once() {
    // A still arm whose distal weight loads the shaft (no contact), then one abrupt effort
    // sample: the correction is withheld for the hold, and the bound says the shaft rests
    // against its play under the weight's torque, once. The earlier bound added the torque the
    // shaft carried when last trusted (the weight's) to the weight's again: twice the elastic
    // part.
    let gravity = DistalGravityParams {
        weight_n: [2.0, 0.0, 0.0],
        weight_sigma_n: [0.0; 3],
        reference_insertion_m: 0.15,
    };
    let cfg = config_with(Some(DynamicsParams {
        distal_gravity: Some(gravity),
        ..DYN
    }));
    let (q, l) = ([0.1, -0.1], 0.15);
    let g = gravity.torque_nm(0, q[0], q[1], l);
    assert!(g.abs() > 0.2, "the weight's torque on joint 1: {g}");
    let mut c = Compensator::new();
    let sample = |c: &mut Compensator, k: usize, extra: f64| {
        c.correct(
            &cfg,
            k as f64 * DT,
            &[q[0], q[1], l],
            &[0.1 + extra, 0.1, 0.0],
        )
    };
    let mut last = None;
    for k in 0..600 {
        last = Some(sample(&mut c, k, 0.0));
    }
    let trusted = last.unwrap();
    assert_eq!(trusted.weight[0], 1.0, "{trusted:?}");
    sample(&mut c, 600, 0.3);
    let withheld = sample(&mut c, 601, 0.0);
    assert_eq!(withheld.weight[0], 0.0, "{withheld:?}");
    assert!(withheld.flags & trust::TRANSIENT != 0, "{withheld:?}");
    // Joint 1: play 2 mrad, K = 1/20 rad/N·m; the stiffness's scatter widens K by a few %.
    let elastic = withheld.bound_parts[0].bias - 0.002;
    let once = g.abs() / 20.0;
    assert!(
        elastic > 0.9 * once && elastic < 1.2 * once,
        "elastic part of the withheld bias {elastic} rad, the weight's deflection {once} rad"
    );
}

mod every_output_finite {
    //! Whatever the samples' timing and values (repeated or backward time stamps, gaps of any
    //! length, nanosecond steps, positions at the joint limits, efforts at the amplifier's
    //! limit), every finite input gives a finite correction, weight and bound: a NaN in a valid
    //! sample would reach a virtual fixture as a pose.
    use super::*;
    use proptest::prelude::*;

    fn default_file() -> ComplianceConfig {
        common::config(include_str!("../../../config/compliance/sim-psm.toml")).unwrap()
    }

    /// One step: a time increment (s; 0, negative, tiny or a gap), the joint 1-3 positions and
    /// joint 1-2 efforts.
    fn step() -> impl Strategy<Value = (f64, [f64; 3], [f64; 3])> {
        let dt = prop_oneof![
            8 => Just(DT),
            1 => Just(0.0),
            1 => Just(-DT),
            1 => Just(1e-9),
            1 => 0.0f64..0.2,
        ];
        let q = prop_oneof![
            6 => (-0.01f64..0.01, -0.01f64..0.01, -0.001f64..0.001),
            1 => (-1.6f64..1.6, -0.8f64..0.8, -0.05f64..0.3),
        ];
        let e = prop_oneof![
            6 => (-0.05f64..0.05, -0.05f64..0.05),
            1 => (-3.0f64..3.0, -3.0f64..3.0),
        ];
        (dt, q, e).prop_map(|(dt, (a, b, c), (e1, e2))| (dt, [a, b, c], [e1, e2, 0.0]))
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
        #[test]
        fn any_timing_gives_finite_outputs(steps in proptest::collection::vec(step(), 1..400)) {
            let cfg = default_file();
            let mut c = Compensator::new();
            let (mut t, mut q) = (100.0, [0.0, 0.0, 0.12]);
            for (k, (dt, dq, e)) in steps.iter().enumerate() {
                t += dt;
                // Small steps walk; large ones jump.
                for j in 0..3 {
                    q[j] = if dq[j].abs() > 0.01 { dq[j] } else { q[j] + dq[j] };
                }
                let out = c.correct(&cfg, t, &q, e);
                let all = [
                    out.delta_rad[0], out.delta_rad[1], out.weight[0], out.weight[1],
                    out.bound_rad[0], out.bound_rad[1], out.tip_bound_m, out.position[0],
                    out.position[1], out.tau_ext_nm[0], out.tau_ext_nm[1],
                ];
                prop_assert!(
                    all.iter().all(|v| v.is_finite()),
                    "step {k}: t {t}, q {q:?}, effort {e:?}: {out:?}"
                );
            }
        }
    }
}

/// A contact that swings faster than the side's evidence averages (a tip sticking and slipping:
/// 40 ms swings of the shaft torque across zero) weakens that evidence instead of being
/// corrected on the side the average still names. Still arm, torque `0.02 + 0.04 sin(2 pi t /
/// 0.04)` N·m (its change over 5 ms stays below the transient detector's), deflection `play
/// sgn(tau) + K tau` as the correction's own model has it.
#[test]
fn a_swinging_contact_weakens_the_side_instead_of_pushing_the_wrong_way() {
    let cfg = config(true);
    let mut c = Compensator::new();
    let _ = still(&mut c, &cfg, 0, 400, 0.12, 0.02);
    let (play, k) = (0.002, 1.0 / 20.0);
    let mut worst_harm: f64 = 0.0;
    let mut covered = 0;
    for i in 400..400 + 1500 {
        let t = i as f64 * DT;
        let tau = 0.02 + 0.04 * (2.0 * std::f64::consts::PI * (t - 400.0 * DT) / 0.04).sin();
        let r = c.correct(&cfg, t, &[0.1, -0.1, 0.12], &[0.1 + tau, 0.1 + tau, 0.0]);
        assert_eq!(
            r.flags & trust::TRANSIENT,
            0,
            "taken for a transient at {t}"
        );
        let truth = play * tau.signum() + k * tau;
        let harm = (truth - r.delta_rad[0]).abs() - truth.abs();
        worst_harm = worst_harm.max(harm);
        covered += usize::from((truth - r.delta_rad[0]).abs() <= r.bound_rad[0]);
    }
    // Without the sway the average's side was applied through the swing's negative part: 2.14
    // mrad worse than no correction (the whole play and more). With it, 1.28 mrad at the zero
    // crossings, where the average lags the swing by 57 degrees.
    assert!(
        worst_harm < 0.75 * play,
        "{worst_harm} rad worse than no correction"
    );
    // The 95% bound over the swing: 83% covered (71% while the side's probability left the
    // sway out). Below the issue's 90% in this synthetic case, where the shaft jumps across its
    // whole play at each zero crossing; the simulator's stick-slip scenario (the shaft crossing
    // in a few ms) is covered in 95% of its cycles (tests/trust_scenarios.rs, 12 s).
    let coverage = covered as f64 / 1500.0;
    assert!((0.8..=0.995).contains(&coverage), "coverage {coverage}");
}

/// Position, velocity and acceleration of `amplitude * sin(omega * t)`.
fn sinusoid(amplitude: f64, omega: f64, t: f64) -> (f64, f64, f64) {
    let (s, c) = (omega * t).sin_cos();
    (
        amplitude * s,
        amplitude * omega * c,
        -amplitude * omega * omega * s,
    )
}

/// A fast free motion whose file has the motor's inertia 1% low: the torque left over is the
/// motion model's error on the motor side, which the shaft does not carry, and it must not name
/// the side of the play against the predicted free load (here a distal weight of 2 mN·m that
/// the inertial load never outweighs). Taken whole, as it was, the leftover named the wrong side
/// whenever the acceleration was below -2.5 rad/s² (31% of the corrected samples here).
#[test]
fn a_fast_motions_model_error_does_not_name_the_side_of_the_play() {
    let (l, amplitude, omega) = (0.12, 0.19, 4.5); // peak 3.8 rad/s², within the fit's 4
    let gravity = DistalGravityParams {
        weight_n: [-0.002 / l, 0.0, 0.0],
        weight_sigma_n: [0.0; 3],
        reference_insertion_m: l,
    };
    let dynamics = DynamicsParams {
        distal_gravity: Some(gravity),
        ..DYN
    };
    let cfg = config_with(Some(dynamics));
    let true_inertia = dynamics.inertia(l) + 0.01 * dynamics.inertia_kg_m2[0];
    let mut c = Compensator::new();
    let (mut corrected, mut wrong) = (0, 0);
    for k in 0..6000 {
        let t = k as f64 * DT;
        let (q, v, a) = sinusoid(amplitude, omega, t);
        let effort = 0.1 + true_inertia * a + dynamics.viscous_nm_s_per_rad * v;
        let r = c.correct(&cfg, t, &[q, 0.0, l], &[effort, 0.1, 0.0]);
        // The predicted free load on the shaft: the distal inertia's and the weight's reaction.
        let distal = dynamics.inertia_kg_m2[1] * l * l * a - gravity.torque_nm(0, q, 0.0, l);
        assert!(distal > 0.0, "the weight sets the side at {t} s: {distal}");
        if t > 1.0 && r.delta_rad[0].abs() > 1e-6 {
            corrected += 1;
            if r.delta_rad[0] < 0.0 {
                wrong += 1;
            }
        }
    }
    assert!(corrected > 3000, "{corrected} samples corrected");
    assert!(
        wrong * 100 <= corrected,
        "{wrong} of {corrected} corrected samples on the wrong side"
    );
}

/// Joint 1 swept at three times the fit's largest acceleration (12 against 4 rad/s²): without
/// contact the correction shrinks to nothing past twice it, as before; pressed with 0.8 N·m, far
/// beyond the torque estimate's uncertainty there (5% of `J a`, 30 mN·m, and the extrapolated
/// 10% more, 60 mN·m), the contact is corrected in full, still flagged ACCEL_OUT_OF_RANGE, with
/// the extrapolated part in its bound.
#[test]
fn a_sure_contact_beyond_the_fits_accelerations_is_corrected_not_shrunk() {
    let (l, amplitude, omega) = (0.12, 0.12, 10.0); // peak 12 rad/s²
    let cfg = config(true);
    for contact in [0.0, 0.8] {
        let mut c = Compensator::new();
        let (mut past_cutoff, mut full) = (0, 0);
        let mut widest = 0.0f64;
        for k in 0..4500 {
            let t = k as f64 * DT;
            let (q, v, a) = sinusoid(amplitude, omega, t);
            let effort = 0.1 + DYN.inertia(l) * a + DYN.viscous_nm_s_per_rad * v + contact;
            let r = c.correct(&cfg, t, &[q, 0.0, l], &[effort, 0.1, 0.0]);
            if t < 0.5 || a.abs() < 2.2 * 4.0 {
                continue;
            }
            past_cutoff += 1;
            assert_ne!(r.flags & trust::ACCEL_OUT_OF_RANGE, 0, "{t}: {r:?}");
            if contact == 0.0 {
                assert_eq!(r.weight[0], 0.0, "{t}: free, past the cutoff: {r:?}");
                continue;
            }
            // 0.002 + 0.8 / 20 rad, the model's deflection of the contact.
            assert_eq!(r.weight[0], 1.0, "{t}: {r:?}");
            assert!((r.delta_rad[0] - 0.042).abs() < 1e-3, "{t}: {r:?}");
            full += 1;
            widest = widest.max(r.bound_parts[0].sigma);
        }
        assert!(past_cutoff > 500, "{past_cutoff}");
        if contact > 0.0 {
            assert_eq!(full, past_cutoff);
            // K times the extrapolated inertia's uncertainty at 12 rad/s² at least.
            let extrapolated = 2.0 * 0.05 * DYN.inertia(l) * 12.0 * 0.95;
            assert!(widest >= extrapolated / 20.0, "{widest} rad");
        }
    }
}
