//! The pure glue of one cycle: an [`ArmSample`] from dvrk-io in, the compliance model and the
//! kinematics applied, the five messages of dvrk-ipc out. No clock, no I/O, no allocation.

use dvrk_compliance::{ComplianceConfig, Correction, PsmKinematics};
use dvrk_io::ArmSample;
use dvrk_ipc::{CompensationStatusV2, Header, JointStateV1, PoseV1, flags};
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
    pub flags: u32,
    /// |tau_ext| minus the threshold at which the correction of joints 1, 2 engages (N·m).
    pub tau_margin_nm: [f64; 2],
}

impl CycleResult {
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
    let mut compensated_position = s.position;
    compensated_position[..3].copy_from_slice(&correction.position);
    let raw_q6 = first6(&s.position);
    let comp_q6 = first6(&compensated_position);
    let mut f = health_flags(s, outcome);
    if correction.insertion_clamped {
        f |= flags::INSERTION_CLAMPED;
    }
    if correction.active[0] {
        f |= flags::CORRECTION_ACTIVE_J1;
    }
    if correction.active[1] {
        f |= flags::CORRECTION_ACTIVE_J2;
    }
    let tau_margin_nm = core::array::from_fn(|j| {
        model
            .joint(j)
            .map_or(0.0, |m| correction.tau_ext_nm[j].abs() - m.tau_min_nm())
    });
    CycleResult {
        raw_pose: kin.forward(&raw_q6),
        correction,
        compensated_position,
        compensated_pose: kin.forward(&comp_q6),
        valid: outcome == ReadOutcome::Ok && s.valid,
        flags: f,
        tau_margin_nm,
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
                },
                compensated_position: [f64::NAN; 7],
                compensated_pose: nan_pose,
                valid: false,
                flags: reason,
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

/// The five messages of one cycle.
#[derive(Debug, Clone, Copy)]
pub struct Messages {
    pub measured_js: JointStateV1,
    pub measured_cp: PoseV1,
    pub compensated_js: JointStateV1,
    pub compensated_cp: PoseV1,
    pub status: CompensationStatusV2,
}

fn pose_msg(header: Header, p: &Isometry3<f64>) -> PoseV1 {
    let t = p.translation.vector;
    let q = p.rotation.coords; // x, y, z, w
    let r = p.rotation.to_rotation_matrix();
    let m = r.matrix();
    PoseV1 {
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

/// Writes a cycle into its messages; every message carries the same header.
pub fn messages(s: &ArmSample, r: &CycleResult, t: &CycleTiming) -> Messages {
    let header = Header {
        seq: t.seq,
        sample_t_ns: t.sample_t_ns,
        board_timestamp: Header::pack_board_timestamps(s.board_timestamp),
        publish_t_ns: t.publish_t_ns,
        valid: u32::from(r.valid),
        flags: r.flags,
    };
    let measured_js = JointStateV1 {
        header,
        position: s.position,
        velocity: s.velocity,
        effort: s.effort,
    };
    let compensated_js = JointStateV1 {
        position: r.compensated_position,
        ..measured_js
    };
    let status = CompensationStatusV2 {
        header,
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
        ..Default::default()
    };
    Messages {
        measured_js,
        measured_cp: pose_msg(header, &r.raw_pose),
        compensated_js,
        compensated_cp: pose_msg(header, &r.compensated_pose),
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
}
