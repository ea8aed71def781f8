//! The output of one read and the pure functions that fill it.

use super::{IoConfig, MAX_BOARDS, NUM_JOINTS};
use crate::wire::{Adc, BoardStatus, EncoderPosition, FeedbackBlock};

/// Health of one board in one sample (reference §7, per board).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoardHealth {
    pub board_id: u8,
    /// The board answered this cycle with a well-formed reply.
    pub read_ok: bool,
    /// Status bit 23 (reference §2.3, §4 watchdog).
    pub watchdog_timeout: bool,
    /// Status bit 18.
    pub power_enabled: bool,
    /// mv_good, status bit 19.
    pub motor_supply_good: bool,
    /// QLA status bit 15 (QLA 1.4+).
    pub motor_supply_fault: bool,
    /// Relay feedback (the DQLA echoes the command).
    pub relay_closed: bool,
    /// The raw status quadlet (0 when not read).
    pub status_raw: u32,
}

/// Health of one actuator in one sample (reference §7, per axis).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisHealth {
    /// Motor status bit 29 (Rev 8+), else QLA status bits 11–8.
    pub amp_on: bool,
    /// Motor status bit 16 (QLA) or a nonzero dRAC fault code; needs the feedback block.
    pub amp_fault: bool,
    /// Firmware current-check trip: motor status bit 17 (Rev 8+), else QLA status bits 7–4.
    pub current_check_trip: bool,
    /// Encoder position bit 24 (sticky).
    pub encoder_overflow: bool,
    /// VEL bit 28; needs the feedback block.
    pub encoder_error: bool,
    /// dRAC fault code (motor status bits 19–16), 0 otherwise.
    pub drac_fault_code: u8,
    /// |current| above the host current-check limit 1.2·Imax + 50 mA (reference §7).
    pub current_over_limit: bool,
}

/// One read of an arm, in joint space and SI units (joint order: yaw, pitch, insertion, roll,
/// wrist pitch, wrist yaw, jaw).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ArmSample {
    /// Host CLOCK_MONOTONIC ns passed in by the caller.
    pub t_ns: u64,
    /// rad, m for insertion.
    pub position: [f64; NUM_JOINTS],
    /// rad/s, m/s for insertion.
    pub velocity: [f64; NUM_JOINTS],
    /// N·m, N for insertion.
    pub effort: [f64; NUM_JOINTS],
    /// Raw board timestamps (sysclk ticks since the board's previous sample, minus 1; only
    /// meaningful in exclusive mode, 0 in shared mode), by board slot.
    pub board_timestamp: [u32; MAX_BOARDS],
    pub boards: [BoardHealth; MAX_BOARDS],
    pub axes: [AxisHealth; NUM_JOINTS],
    /// Every board read succeeded and every value was converted.
    pub valid: bool,
}

/// Actuator-space values of one sample (before coupling), SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorState {
    /// rad, m for insertion.
    pub position: [f64; NUM_JOINTS],
    /// rad/s, m/s.
    pub velocity: [f64; NUM_JOINTS],
    /// N·m, N.
    pub effort: [f64; NUM_JOINTS],
    /// Motor current, A.
    pub current_amps: [f64; NUM_JOINTS],
    /// Potentiometer position (ADC bits 31–16 through the io file's `potentiometer` section),
    /// rad or m; NaN where the io file has no pot calibration or the axis was not read.
    pub pot_position: [f64; NUM_JOINTS],
}

impl ActuatorState {
    /// Per actuator, pot minus encoder position of this sample (rad or m; NaN without pot):
    /// what the dVRK's pot/encoder check compares, independent of any instrument coupling a
    /// caller converts joint values back with.
    pub fn pot_minus_encoder(&self) -> [f64; NUM_JOINTS] {
        core::array::from_fn(|i| self.pot_position[i] - self.position[i])
    }
}

impl Default for ActuatorState {
    fn default() -> Self {
        Self {
            position: [0.0; NUM_JOINTS],
            velocity: [0.0; NUM_JOINTS],
            effort: [0.0; NUM_JOINTS],
            current_amps: [0.0; NUM_JOINTS],
            pot_position: [f64::NAN; NUM_JOINTS],
        }
    }
}

/// Raw per-cycle values of shared mode (quadlet reads only): the status of each board slot and
/// the ADC and encoder-position quadlets of each actuator. `None` = not read this cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SharedRaw {
    pub status: [Option<u32>; MAX_BOARDS],
    pub adc: [Option<u32>; NUM_JOINTS],
    pub encoder_position: [Option<u32>; NUM_JOINTS],
}

fn board_health(cfg: &IoConfig, slot: usize, status: Option<u32>) -> BoardHealth {
    let board_id = cfg.board_ids().get(slot).copied().unwrap_or(0);
    match status {
        None => BoardHealth {
            board_id,
            ..Default::default()
        },
        Some(raw) => {
            let s = BoardStatus::new(raw, cfg.board_kind());
            BoardHealth {
                board_id,
                read_ok: true,
                watchdog_timeout: s.watchdog_timeout(),
                power_enabled: s.power_enabled(),
                motor_supply_good: s.mv_good(),
                motor_supply_fault: s.motor_supply_fault(),
                relay_closed: s.relay_feedback(),
                status_raw: raw,
            }
        }
    }
}

/// Maps actuator-space values to joint space into `out` (position, velocity, effort).
#[inline]
pub fn joints_from_actuators(
    cfg: &IoConfig,
    pos: &[f64; NUM_JOINTS],
    vel: &[f64; NUM_JOINTS],
    eff: &[f64; NUM_JOINTS],
    out: &mut ArmSample,
) {
    out.position = cfg.actuator_to_joint_position(pos);
    out.velocity = cfg.actuator_to_joint_position(vel);
    out.effort = cfg.actuator_to_joint_effort(eff);
}

/// Converts the feedback blocks of the arm's boards (by slot; `None` = read failed) into `out`.
/// Velocity is the firmware velocity (encoder period) for every actuator; a caller that wants
/// software velocity overrides it. Pure and allocation-free. Returns the actuator-space values.
pub fn decode_blocks<T: AsRef<[u8]>>(
    cfg: &IoConfig,
    blocks: &[Option<FeedbackBlock<T>>; MAX_BOARDS],
    t_ns: u64,
    out: &mut ArmSample,
) -> ActuatorState {
    out.t_ns = t_ns;
    let mut all_ok = true;
    for (slot, block) in blocks.iter().enumerate() {
        let used = slot < cfg.board_ids().len();
        let b = if used { block.as_ref() } else { None };
        out.boards[slot] = board_health(cfg, slot, b.map(|b| b.status().raw));
        out.board_timestamp[slot] = b.map_or(0, |b| b.timestamp().0);
        all_ok &= !used || b.is_some();
    }
    let mut pos = [0.0; NUM_JOINTS];
    let mut vel = [0.0; NUM_JOINTS];
    let mut eff = [0.0; NUM_JOINTS];
    let mut cur = [0.0; NUM_JOINTS];
    let mut pot = [f64::NAN; NUM_JOINTS];
    for (i, a) in cfg.actuators().iter().enumerate() {
        let axis = a.axis as usize;
        let Some(b) = blocks.get(a.board_slot as usize).and_then(|b| b.as_ref()) else {
            out.axes[i] = AxisHealth::default();
            all_ok = false;
            continue;
        };
        let (Some(enc), Some(period), Some(adc)) = (
            b.encoder_position(axis),
            b.encoder_period(axis),
            b.adc(axis),
        ) else {
            out.axes[i] = AxisHealth::default();
            all_ok = false;
            continue;
        };
        let clk = b.layout().velocity_clock_hz();
        pos[i] = a.counts_to_position(enc.counts());
        vel[i] = a.bits_to_position.scale * period.velocity_counts_per_s(clk);
        let amps = a.current_bits_to_amps(adc.current_bits());
        cur[i] = amps;
        eff[i] = a.amps_to_effort(amps);
        pot[i] = a.pot_bits_to_position(adc.pot_bits()).unwrap_or(f64::NAN);
        let status = b.status();
        let mut h = AxisHealth {
            encoder_overflow: enc.overflow(),
            encoder_error: period.encoder_error(),
            current_over_limit: amps.abs() > a.current_limit_amps(),
            ..Default::default()
        };
        match b.motor_status(axis) {
            Some(ms) => {
                h.amp_on = ms.amp_on();
                h.amp_fault = ms.amp_fault();
                h.current_check_trip = ms.current_check_trip();
                h.drac_fault_code = ms.drac_fault_code();
            }
            None => {
                h.amp_on = status.amp_on(axis).unwrap_or(false);
                h.current_check_trip = status.current_check_trip(axis).unwrap_or(false);
            }
        }
        out.axes[i] = h;
    }
    joints_from_actuators(cfg, &pos, &vel, &eff, out);
    out.valid = all_ok;
    ActuatorState {
        position: pos,
        velocity: vel,
        effort: eff,
        current_amps: cur,
        pot_position: pot,
    }
}

/// Converts shared-mode quadlets into `out`. Velocity is left to the caller (finite difference
/// of positions over its own time base); this sets it to 0. Pure and allocation-free.
/// Returns the actuator-space values (velocity 0), whose positions the caller differentiates.
pub fn decode_shared(
    cfg: &IoConfig,
    raw: &SharedRaw,
    t_ns: u64,
    out: &mut ArmSample,
) -> ActuatorState {
    out.t_ns = t_ns;
    let mut all_ok = true;
    for slot in 0..MAX_BOARDS {
        let used = slot < cfg.board_ids().len();
        let st = if used { raw.status[slot] } else { None };
        out.boards[slot] = board_health(cfg, slot, st);
        out.board_timestamp[slot] = 0;
        all_ok &= !used || st.is_some();
    }
    let mut pos = [0.0; NUM_JOINTS];
    let mut eff = [0.0; NUM_JOINTS];
    let mut cur = [0.0; NUM_JOINTS];
    let mut pot = [f64::NAN; NUM_JOINTS];
    for (i, a) in cfg.actuators().iter().enumerate() {
        let (Some(enc), Some(adc)) = (raw.encoder_position[i], raw.adc[i]) else {
            out.axes[i] = AxisHealth::default();
            all_ok = false;
            continue;
        };
        let enc = EncoderPosition(enc);
        let adc = Adc(adc);
        pos[i] = a.counts_to_position(enc.counts());
        let amps = a.current_bits_to_amps(adc.current_bits());
        cur[i] = amps;
        eff[i] = a.amps_to_effort(amps);
        pot[i] = a.pot_bits_to_position(adc.pot_bits()).unwrap_or(f64::NAN);
        let status = raw
            .status
            .get(a.board_slot as usize)
            .copied()
            .flatten()
            .map(|s| BoardStatus::new(s, cfg.board_kind()));
        let axis = a.axis as usize;
        out.axes[i] = AxisHealth {
            amp_on: status.and_then(|s| s.amp_on(axis)).unwrap_or(false),
            amp_fault: false,
            current_check_trip: status
                .and_then(|s| s.current_check_trip(axis))
                .unwrap_or(false),
            encoder_overflow: enc.overflow(),
            encoder_error: false,
            drac_fault_code: 0,
            current_over_limit: amps.abs() > a.current_limit_amps(),
        };
    }
    joints_from_actuators(cfg, &pos, &[0.0; NUM_JOINTS], &eff, out);
    out.valid = all_ok;
    ActuatorState {
        position: pos,
        velocity: [0.0; NUM_JOINTS],
        effort: eff,
        current_amps: cur,
        pot_position: pot,
    }
}
