//! The pure glue of one cycle: an [`ArmSample`] from dvrk-io in, the compliance model and the
//! kinematics applied, the nine messages of dvrk-ipc out. No clock, no I/O, no allocation.

use dvrk_compliance::{Compensator, ComplianceConfig, Correction, PsmKinematics};
use dvrk_io::ArmSample;
use dvrk_ipc::{
    ArmState, CompensationStatusV4, CycleMessages, Header, JawStateV1, JointStateV2, PoseV2, flags,
};
use nalgebra::Isometry3;

/// Why a read failed, as far as the published flags are concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadOutcome {
    Ok,
    /// No reply within the timeout.
    Timeout,
    /// A reply that failed validation, or any other port error.
    Error,
    /// Nothing to read: the passive tap sees no console traffic.
    NoSource,
    /// The read succeeded but the sample failed a plausibility check.
    Implausible,
    /// The read succeeded but a potentiometer and its encoder disagreed beyond the dVRK's
    /// tolerance for longer than its latency (published `IMPLAUSIBLE | POT_MISMATCH`).
    PotMismatch,
}

/// Everything computed in one cycle, before it is written into messages.
#[derive(Debug, Clone, Copy)]
pub struct CycleResult {
    pub raw_pose: Isometry3<f64>,
    pub correction: Correction,
    /// Joint positions with q1, q2 replaced by the corrected ones.
    pub compensated_position: [f64; 7],
    pub compensated_pose: Isometry3<f64>,
    pub valid: bool,
    /// The compensated messages are valid too (false: no instrument, or one the service cannot
    /// model; the raw messages keep `valid`).
    pub compensated_valid: bool,
    pub flags: u32,
    /// [`dvrk_ipc::CompensationStatusV4::source_state`]: console state, parameter set,
    /// instrument.
    pub source_state: u32,
    /// |tau_ext| minus the threshold at which the correction of joints 1, 2 engages (N·m).
    pub tau_margin_nm: [f64; 2],
}

impl CycleResult {
    /// The correction withheld: compensated = raw (joints and pose), no active flag. The bounds
    /// widen by what was withdrawn: the published sample's error is now the raw one, the
    /// corrected error plus the correction, so the corrected sample's 95% bound plus the
    /// correction's size (per joint, and at the tip the distance between the two tips) bounds
    /// it at least as often (a NaN correction leaves NaN bounds: unknown).
    pub fn withhold_correction(&mut self, raw_position: &[f64; 7]) {
        let moved = self.tip_displacement_m();
        self.correction.tip_bound_m += moved;
        for j in 0..2 {
            let d = self.correction.delta_rad[j].abs();
            self.correction.bound_rad[j] += d;
            self.correction.bound_parts[j].bias += d;
        }
        self.compensated_position = *raw_position;
        self.compensated_pose = self.raw_pose;
        self.correction.position.copy_from_slice(&raw_position[..3]);
        self.correction.delta_rad = [0.0; 2];
        self.correction.active = [false; 2];
        self.flags &= !(flags::CORRECTION_ACTIVE_J1 | flags::CORRECTION_ACTIVE_J2);
    }

    /// Distance between the raw and the compensated tip positions (m).
    pub fn tip_displacement_m(&self) -> f64 {
        (self.raw_pose.translation.vector - self.compensated_pose.translation.vector).norm()
    }
}

/// Health flags of a sample, as dvrk-ipc publishes them.
pub fn health_flags(s: &ArmSample, outcome: ReadOutcome) -> u32 {
    let mut f = 0;
    match outcome {
        ReadOutcome::Ok => {}
        ReadOutcome::Timeout => f |= flags::BOARD_TIMEOUT,
        ReadOutcome::Error => f |= flags::BOARD_ERROR,
        ReadOutcome::NoSource => f |= flags::NO_SOURCE,
        ReadOutcome::Implausible => f |= flags::IMPLAUSIBLE,
        ReadOutcome::PotMismatch => f |= flags::IMPLAUSIBLE | flags::POT_MISMATCH,
    }
    // Hardware bits mean something only for boards whose status was read: an unread board's
    // power bits are unknown, not off (its BOARD_TIMEOUT/BOARD_ERROR says why).
    for b in s.boards.iter().filter(|b| b.read_ok) {
        if b.watchdog_timeout {
            f |= flags::WATCHDOG_TIMEOUT;
        }
        if !b.power_enabled || !b.motor_supply_good || b.motor_supply_fault {
            f |= flags::POWER_OFF;
        }
    }
    for a in &s.axes {
        if a.encoder_error || a.encoder_overflow {
            f |= flags::ENCODER_ERROR;
        }
        if a.amp_fault || a.current_check_trip {
            f |= flags::AMP_FAULT;
        }
    }
    f
}

/// Applies the model and the kinematics to one sample.
pub fn compute(
    model: &ComplianceConfig,
    kin: &PsmKinematics,
    s: &ArmSample,
    outcome: ReadOutcome,
) -> CycleResult {
    let q3 = [s.position[0], s.position[1], s.position[2]];
    let tau3 = [s.effort[0], s.effort[1], s.effort[2]];
    let correction = model.correct(&q3, &tau3);
    finish(kin, s, outcome, correction)
}

/// [`compute`] with the internal-torque estimator (issue 10): friction and inertia are removed
/// from `tau_ext` before the gate, using the sample's own time. Invalid samples are corrected
/// without it and do not enter its filter; the filter bridges the few cycles they leave out and
/// restarts itself after a longer gap ([`dvrk_compliance::dynamics::MAX_GAP_S`]), so one lost
/// read does not blank the correction for a whole filter window. With a parameter file that has
/// no `[joint.dynamics]` the result equals [`compute`]'s.
pub fn compute_dynamic(
    model: &ComplianceConfig,
    compensator: &mut Compensator,
    kin: &PsmKinematics,
    s: &ArmSample,
    outcome: ReadOutcome,
) -> CycleResult {
    let q3 = [s.position[0], s.position[1], s.position[2]];
    let tau3 = [s.effort[0], s.effort[1], s.effort[2]];
    let correction = if outcome == ReadOutcome::Ok && s.valid {
        compensator.correct(model, s.t_ns as f64 * 1e-9, &q3, &tau3)
    } else {
        model.correct(&q3, &tau3)
    };
    finish(kin, s, outcome, correction)
}

/// The compensation's own trust flags (issue 20, `dvrk_compliance::trust`) as header bits: its
/// bits 0..7 in 21..28 ([`flags::TRUST_SHIFT`]), its bit 8 in 30 (bit 29 was taken by then).
fn trust_flags(trust: u32) -> u32 {
    let mut f = (trust & 0xff) << flags::TRUST_SHIFT;
    if trust & dvrk_compliance::trust::POSITION_OUT_OF_RANGE != 0 {
        f |= flags::POSITION_OUT_OF_RANGE;
    }
    f
}

fn finish(
    kin: &PsmKinematics,
    s: &ArmSample,
    outcome: ReadOutcome,
    correction: Correction,
) -> CycleResult {
    let mut compensated_position = s.position;
    compensated_position[..3].copy_from_slice(&correction.position);
    let raw_q6 = first6(&s.position);
    let comp_q6 = first6(&compensated_position);
    let mut f = health_flags(s, outcome);
    if correction.insertion_clamped {
        f |= flags::INSERTION_CLAMPED;
    }
    f |= trust_flags(correction.flags);
    if correction.active[0] {
        f |= flags::CORRECTION_ACTIVE_J1;
    }
    if correction.active[1] {
        f |= flags::CORRECTION_ACTIVE_J2;
    }
    // |tau_ext| minus the gate (tau_min, plus gate_sigmas * residual std with a dynamics
    // model); 0 for a joint without parameters.
    let tau_margin_nm = correction.tau_margin_nm;
    let raw_pose = kin.forward(&raw_q6);
    let mut correction = correction;
    correction.tip_bound_m = tip_bound(kin, &raw_q6, &raw_pose, &correction);
    CycleResult {
        raw_pose,
        correction,
        compensated_position,
        compensated_pose: kin.forward(&comp_q6),
        valid: outcome == ReadOutcome::Ok && s.valid,
        compensated_valid: true,
        flags: f,
        source_state: 0,
        tau_margin_nm,
    }
}

/// The joint step (rad) of the levers' finite difference: far above the rounding of a 0.1 m
/// position (1e-17 m), far below any curvature of the kinematics at the scale of a bound.
const LEVER_STEP_RAD: f64 = 1e-6;

/// The tip bound through the instrument's own levers: how far the tip moves per radian of
/// joints 1 and 2 at this pose (`|dp/dq_j|`, by a forward difference of the kinematics: the
/// wrist's bend brings the tip closer to the RCM than the shaft's length, by 10% in the
/// simulator's free motion). Falls back to the model's lever `L + TIP_LEVER_EXTRA_M` when the
/// pose is not finite. Two forward kinematics per cycle, no allocation.
fn tip_bound(
    kin: &PsmKinematics,
    q6: &[f64; 6],
    raw_pose: &nalgebra::Isometry3<f64>,
    c: &Correction,
) -> f64 {
    let mut levers = [0.0; 2];
    for (j, lever) in levers.iter_mut().enumerate() {
        let mut q = *q6;
        q[j] += LEVER_STEP_RAD;
        let moved = kin.forward(&q).translation.vector - raw_pose.translation.vector;
        *lever = moved.norm() / LEVER_STEP_RAD;
    }
    if levers.iter().all(|l| l.is_finite()) {
        dvrk_compliance::model::tip_bound_with_levers(levers, &c.bound_parts)
    } else {
        c.tip_bound_m
    }
}

/// The last valid cycle, held and republished (with `valid = 0`) while reads fail or samples
/// are rejected, so that no consumer ever sees zeros or a half-read sample as a position.
#[derive(Debug, Clone, Copy)]
pub struct Held {
    pub sample: ArmSample,
    pub result: CycleResult,
    /// Host time of the held sample (ns).
    pub sample_t_ns: u64,
}

/// What an invalid cycle publishes: the last valid sample's values with `valid = 0`, the flags
/// that say why (`reason`, from [`health_flags`] of this cycle's read) plus `HELD`, correction
/// flags cleared. Without any valid sample yet, positions, velocities, efforts and poses are NaN
/// (never zeros, which are a plausible pose), and `HELD` is not set.
///
/// Returns the sample to write into the joint-state messages and the cycle result.
pub fn held(last: Option<&Held>, current: &ArmSample, reason: u32) -> (ArmSample, CycleResult) {
    let keep = flags::SIMULATED | flags::OVERRUN;
    match last {
        Some(h) => {
            let mut sample = h.sample;
            sample.board_timestamp = current.board_timestamp;
            sample.boards = current.boards;
            sample.axes = current.axes;
            sample.valid = false;
            let mut result = h.result;
            result.valid = false;
            result.flags = (h.result.flags & keep) | reason | flags::HELD;
            result.correction.active = [false; 2];
            result.tau_margin_nm = [0.0; 2];
            (sample, result)
        }
        None => {
            let nan_pose = Isometry3::from_parts(
                nalgebra::Translation3::new(f64::NAN, f64::NAN, f64::NAN),
                nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
                    f64::NAN,
                    f64::NAN,
                    f64::NAN,
                    f64::NAN,
                )),
            );
            let sample = ArmSample {
                t_ns: current.t_ns,
                position: [f64::NAN; 7],
                velocity: [f64::NAN; 7],
                effort: [f64::NAN; 7],
                board_timestamp: current.board_timestamp,
                boards: current.boards,
                axes: current.axes,
                valid: false,
            };
            let result = CycleResult {
                raw_pose: nan_pose,
                correction: Correction {
                    position: [f64::NAN; 3],
                    delta_rad: [0.0; 2],
                    tau_ext_nm: [0.0; 2],
                    active: [false; 2],
                    insertion_m: f64::NAN,
                    insertion_clamped: false,
                    tau_margin_nm: [0.0; 2],
                    flags: 0,
                    weight: [0.0; 2],
                    bound_rad: [f64::NAN; 2],
                    bound_parts: Default::default(),
                    tip_bound_m: f64::NAN,
                },
                compensated_position: [f64::NAN; 7],
                compensated_pose: nan_pose,
                valid: false,
                compensated_valid: true,
                flags: reason,
                source_state: 0,
                tau_margin_nm: [0.0; 2],
            };
            (sample, result)
        }
    }
}

fn first6(q: &[f64; 7]) -> [f64; 6] {
    [q[0], q[1], q[2], q[3], q[4], q[5]]
}

/// Timing and counters of one cycle, from the loop, as the status message carries them.
#[derive(Debug, Clone, Copy, Default)]
pub struct CycleTiming {
    pub seq: u64,
    pub sample_t_ns: u64,
    /// CLOCK_REALTIME (ROS time) of the same instant as `sample_t_ns`.
    pub sample_realtime_ns: u64,
    pub publish_t_ns: u64,
    pub cycle_period_ns: u64,
    pub cycle_duration_ns: u64,
    /// Cycles published since start, this one included.
    pub cycles_total: u64,
    pub read_failures_total: u64,
    pub overruns_total: u64,
    pub consecutive_read_failures: u32,
    /// 0 for a fresh sample; the age of the held sample otherwise (`u64::MAX`: none yet).
    pub held_sample_age_ns: u64,
    /// How late the cycle started after its deadline.
    pub publish_late_ns: u64,
    pub implausible_total: u64,
}

fn pose_msg(header: Header, p: &Isometry3<f64>) -> PoseV2 {
    let t = p.translation.vector;
    let q = p.rotation.coords; // x, y, z, w
    let r = p.rotation.to_rotation_matrix();
    let m = r.matrix();
    PoseV2 {
        header,
        position_m: [t.x, t.y, t.z],
        orientation_xyzw: [q.x, q.y, q.z, q.w],
        rotation: [
            m[(0, 0)],
            m[(0, 1)],
            m[(0, 2)],
            m[(1, 0)],
            m[(1, 1)],
            m[(1, 2)],
            m[(2, 0)],
            m[(2, 1)],
            m[(2, 2)],
        ],
    }
}

/// The four states of one arm from a joint vector (6 joints + jaw), its RCM-frame pose `local`
/// and that pose's message `local_msg` (whose header all four carry).
fn arm_state(
    local_msg: PoseV2,
    position: &[f64; 7],
    s: &ArmSample,
    local: &Isometry3<f64>,
    base_frame: &Isometry3<f64>,
) -> ArmState {
    let header = local_msg.header;
    ArmState {
        measured_js: JointStateV2 {
            header,
            position: first6(position),
            velocity: first6(&s.velocity),
            effort: first6(&s.effort),
        },
        jaw_measured_js: JawStateV1 {
            header,
            position: position[6],
            velocity: s.velocity[6],
            effort: s.effort[6],
        },
        local_measured_cp: local_msg,
        measured_cp: pose_msg(header, &(base_frame * local)),
    }
}

/// The header every message of a cycle carries (the compensated ones say
/// `valid && compensated_valid`).
fn header(s: &ArmSample, r: &CycleResult, t: &CycleTiming) -> Header {
    Header {
        seq: t.seq,
        sample_t_ns: t.sample_t_ns,
        sample_realtime_ns: t.sample_realtime_ns,
        board_timestamp: Header::pack_board_timestamps(s.board_timestamp),
        publish_t_ns: t.publish_t_ns,
        valid: u32::from(r.valid),
        flags: r.flags,
    }
}

/// The first message of a cycle, `compensated/local/measured_cp`, as [`messages`] writes it:
/// `serve` sends it before it writes the other eight.
pub fn compensated_local_measured_cp(s: &ArmSample, r: &CycleResult, t: &CycleTiming) -> PoseV2 {
    let mut h = header(s, r, t);
    h.valid = u32::from(r.valid && r.compensated_valid);
    pose_msg(h, &r.compensated_pose)
}

/// Writes a cycle into its nine messages; every message carries the same header.
/// `base_frame` is the arm's base frame (the pose of its RCM frame in the frame the lab chose,
/// as the dVRK console's `base-frame`): `measured_cp = base_frame × local/measured_cp`.
pub fn messages(
    s: &ArmSample,
    r: &CycleResult,
    t: &CycleTiming,
    base_frame: &Isometry3<f64>,
) -> CycleMessages {
    messages_from_first(compensated_local_measured_cp(s, r, t), s, r, t, base_frame)
}

/// [`messages`] for a cycle whose first message, `first` (from
/// [`compensated_local_measured_cp`] with the same arguments), is already written: reuses it
/// and its header instead of computing them again.
pub fn messages_from_first(
    first: PoseV2,
    s: &ArmSample,
    r: &CycleResult,
    t: &CycleTiming,
    base_frame: &Isometry3<f64>,
) -> CycleMessages {
    let comp_header = first.header;
    let header = Header {
        valid: u32::from(r.valid),
        ..comp_header
    };
    let status = CompensationStatusV4 {
        header: comp_header,
        tau_ext_nm: r.correction.tau_ext_nm,
        delta_rad: r.correction.delta_rad,
        insertion_m: r.correction.insertion_m,
        cycle_period_ns: t.cycle_period_ns,
        cycle_duration_ns: t.cycle_duration_ns,
        cycles_total: t.cycles_total,
        read_failures_total: t.read_failures_total,
        overruns_total: t.overruns_total,
        consecutive_read_failures: t.consecutive_read_failures,
        tau_margin_nm: r.tau_margin_nm,
        held_sample_age_ns: t.held_sample_age_ns,
        publish_late_ns: t.publish_late_ns,
        implausible_total: t.implausible_total,
        source_state: r.source_state,
        bound_rad: r.correction.bound_rad,
        tip_bound_m: r.correction.tip_bound_m,
        weight: r.correction.weight,
        _reserved: 0,
    };
    CycleMessages {
        measured: arm_state(
            pose_msg(header, &r.raw_pose),
            &s.position,
            s,
            &r.raw_pose,
            base_frame,
        ),
        compensated: arm_state(
            first,
            &r.compensated_position,
            s,
            &r.compensated_pose,
            base_frame,
        ),
        status,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvrk_io::BoardHealth;

    fn powered(board_id: u8) -> BoardHealth {
        BoardHealth {
            board_id,
            read_ok: true,
            power_enabled: true,
            motor_supply_good: true,
            ..Default::default()
        }
    }

    /// Every trust bit lands on the header bit of its own name, and on nothing else: a trust
    /// bit added without its header bit fails here instead of being dropped.
    #[test]
    fn every_trust_flag_is_published_under_its_own_name() {
        for (bit, name) in dvrk_compliance::trust::TABLE {
            let published: Vec<_> = flags::names(trust_flags(bit)).collect();
            assert_eq!(published, [name.to_uppercase()], "trust bit {bit:#x}");
        }
    }

    #[test]
    fn an_unread_board_is_reported_by_its_read_error_not_as_powered_off() {
        let mut s = ArmSample {
            boards: [
                powered(6),
                BoardHealth {
                    board_id: 7,
                    ..Default::default()
                },
            ],
            ..Default::default()
        };
        assert_eq!(health_flags(&s, ReadOutcome::Timeout), flags::BOARD_TIMEOUT);
        // A board that was read and reports power off is flagged.
        s.boards[1] = BoardHealth {
            power_enabled: false,
            ..powered(7)
        };
        assert_eq!(health_flags(&s, ReadOutcome::Ok), flags::POWER_OFF);
        s.boards[1].watchdog_timeout = true;
        s.boards[1].power_enabled = true;
        assert_eq!(health_flags(&s, ReadOutcome::Ok), flags::WATCHDOG_TIMEOUT);
    }

    #[test]
    fn messages_carry_six_joints_the_jaw_and_both_frames() {
        let mut s = ArmSample {
            valid: true,
            ..Default::default()
        };
        s.position = [0.1, -0.2, 0.12, 0.3, 0.05, -0.05, 0.4];
        s.velocity = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        s.effort = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1];
        let kin = PsmKinematics::new(
            dvrk_compliance::ArmKind::Classic,
            dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        let model = crate::formats::compliance_from_toml(include_str!(
            "../../../config/compliance/paper-psm.toml"
        ))
        .unwrap();
        let r = compute(&model, &kin, &s, ReadOutcome::Ok);
        let base = Isometry3::from_parts(
            nalgebra::Translation3::new(0.1, -0.2, 0.3),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        let t = CycleTiming {
            seq: 5,
            sample_t_ns: 100,
            sample_realtime_ns: 1_700_000_000_000_000_100,
            ..Default::default()
        };
        let m = messages(&s, &r, &t, &base);
        // What serve sends first is the message `messages` writes for that topic.
        assert_eq!(
            compensated_local_measured_cp(&s, &r, &t),
            m.compensated.local_measured_cp
        );
        // What serve writes after it, reusing that first message, is the same cycle.
        assert_eq!(
            messages_from_first(compensated_local_measured_cp(&s, &r, &t), &s, &r, &t, &base),
            m
        );
        assert_eq!(
            m.measured.measured_js.position,
            [0.1, -0.2, 0.12, 0.3, 0.05, -0.05]
        );
        assert_eq!(m.measured.measured_js.velocity[5], 6.0);
        assert_eq!(m.measured.jaw_measured_js.position, 0.4);
        assert_eq!(m.measured.jaw_measured_js.velocity, 7.0);
        assert_eq!(m.measured.jaw_measured_js.effort, 1.1);
        assert_eq!(m.compensated.jaw_measured_js, m.measured.jaw_measured_js);
        assert_eq!(
            m.status.header.sample_realtime_ns,
            1_700_000_000_000_000_100
        );
        // measured_cp = base x local: a point check of the composition.
        let local = m.measured.local_measured_cp.position_m;
        let want = base * nalgebra::Point3::new(local[0], local[1], local[2]);
        let got = m.measured.measured_cp.position_m;
        for i in 0..3 {
            assert!((got[i] - want[i]).abs() < 1e-12, "{got:?} vs {want:?}");
        }
        // Rotated 90° about z: x_base = -y_local + 0.1.
        assert!((got[0] - (-local[1] + 0.1)).abs() < 1e-12);
        // With the identity base frame both poses are equal.
        let m = messages(&s, &r, &t, &Isometry3::identity());
        assert_eq!(m.measured.measured_cp, m.measured.local_measured_cp);
        assert_eq!(m.compensated.measured_cp, m.compensated.local_measured_cp);
    }

    #[test]
    fn the_tip_bound_takes_the_instruments_levers() {
        let kin = PsmKinematics::new(
            dvrk_compliance::ArmKind::Classic,
            dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        // A bent wrist and a pitched shaft: the tip is nearer the RCM than L, and a yaw error
        // moves it by cos(pitch) of that.
        let q6 = [0.2, -0.5, 0.12, 0.3, 0.5, -0.4];
        let pose = kin.forward(&q6);
        let mut c = Correction {
            position: [q6[0], q6[1], q6[2]],
            delta_rad: [0.0; 2],
            tau_ext_nm: [0.0; 2],
            active: [false; 2],
            insertion_m: q6[2],
            insertion_clamped: false,
            tau_margin_nm: [0.0; 2],
            flags: 0,
            weight: [1.0; 2],
            bound_rad: [0.0; 2],
            bound_parts: Default::default(),
            tip_bound_m: f64::NAN,
        };
        // A systematic error of 3 mrad on one joint at a time: the bound is how far the tip
        // moves when that joint is turned by 3 mrad (an independent check, by the kinematics).
        for j in 0..2 {
            c.bound_parts = Default::default();
            c.bound_parts[j].bias = 3e-3;
            let mut q = q6;
            q[j] += 3e-3;
            let moved = (kin.forward(&q).translation.vector - pose.translation.vector).norm();
            let b = tip_bound(&kin, &q6, &pose, &c);
            assert!(
                (b - moved).abs() < 1e-3 * moved,
                "joint {}: {b} vs {moved}",
                j + 1
            );
            // ... and below the model's own lever, L + TIP_LEVER_EXTRA_M.
            let lever = q6[2] + dvrk_compliance::model::TIP_LEVER_EXTRA_M;
            assert!(b < lever * 3e-3, "joint {}: {b} vs {}", j + 1, lever * 3e-3);
        }
        // A pose that is not finite falls back to the model's bound.
        c.tip_bound_m = 0.25e-3;
        let nan = [f64::NAN; 6];
        assert_eq!(tip_bound(&kin, &nan, &kin.forward(&nan), &c), 0.25e-3);
    }

    /// The default parameter file and the Classic large needle driver's kinematics.
    fn default_model_and_kinematics() -> (ComplianceConfig, PsmKinematics) {
        let model = crate::formats::compliance_from_toml(include_str!(
            "../../../config/compliance/sim-psm.toml"
        ))
        .unwrap();
        let kin = PsmKinematics::new(
            dvrk_compliance::ArmKind::Classic,
            dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006").unwrap(),
        );
        (model, kin)
    }

    /// A withheld correction publishes the raw sample, whose error the corrected sample's bound
    /// does not cover: the bounds grow by the correction withdrawn, and a second withholding
    /// (nothing left to withdraw) leaves them.
    #[test]
    fn a_withheld_correction_widens_the_bounds_by_what_it_withdrew() {
        let (model, kin) = default_model_and_kinematics();
        let mut comp = Compensator::new();
        let mut s = ArmSample {
            valid: true,
            ..Default::default()
        };
        s.position[..3].copy_from_slice(&[0.1, -0.2, 0.15]);
        // Still, pressed: 0.4 / 0.3 N·m beyond the torque offset on joints 1 and 2.
        for j in 0..2 {
            let offset = model
                .joint(j)
                .unwrap()
                .torque_offset()
                .lookup(s.position[j]);
            s.effort[j] = offset + [0.4, 0.3][j];
        }
        let mut r = compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Ok);
        for i in 1..3000u64 {
            s.t_ns = i * 666_667;
            r = compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Ok);
        }
        let before = r;
        assert!(before.correction.active.iter().all(|&a| a), "{before:?}");
        let moved = before.tip_displacement_m();
        assert!(moved > 1e-4, "the correction moves the tip: {moved}");
        r.withhold_correction(&s.position);
        assert_eq!(r.compensated_position, s.position);
        assert_eq!(r.tip_displacement_m(), 0.0);
        assert_eq!(
            r.correction.tip_bound_m,
            before.correction.tip_bound_m + moved
        );
        for j in 0..2 {
            let d = before.correction.delta_rad[j].abs();
            assert!(d > 0.0, "joint {}: {before:?}", j + 1);
            assert_eq!(
                r.correction.bound_rad[j],
                before.correction.bound_rad[j] + d
            );
            assert_eq!(
                r.correction.bound_parts[j].bias,
                before.correction.bound_parts[j].bias + d
            );
        }
        let once = r;
        r.withhold_correction(&s.position);
        assert_eq!(r.correction.tip_bound_m, once.correction.tip_bound_m);
        assert_eq!(r.correction.bound_rad, once.correction.bound_rad);
    }

    #[test]
    fn one_invalid_sample_does_not_restart_the_estimator() {
        let (model, kin) = default_model_and_kinematics();
        let mut comp = Compensator::new();
        let mut s = ArmSample {
            valid: true,
            ..Default::default()
        };
        s.position[2] = 0.12;
        let period_ns = 666_667;
        let ready = |c: &Compensator| c.joint_state(0).is_some_and(|j| j.ready());
        for i in 0..100u64 {
            s.t_ns = 1_000_000_000 + i * period_ns;
            s.position[0] = 0.1 * (i as f64 * 0.01).sin();
            compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Ok);
        }
        assert!(ready(&comp), "a full window after 100 samples");
        // One read times out...
        s.t_ns += period_ns;
        compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Timeout);
        // ...and the next valid sample is estimated at once, not after another window.
        s.t_ns += period_ns;
        compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Ok);
        assert!(ready(&comp), "one lost cycle restarted the estimator");
        // A stall longer than the filter's gap restarts it (the motion is unknown across it).
        s.t_ns += 50_000_000;
        compute_dynamic(&model, &mut comp, &kin, &s, ReadOutcome::Ok);
        assert!(!ready(&comp));
    }
}
