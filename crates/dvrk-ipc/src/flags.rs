//! Bits of [`Header::flags`](crate::Header::flags): why a sample is invalid and which state the
//! compensation was in. The same values are `DVRK_IPC_FLAG_*` in `dvrk_ipc.h`.
//!
//! | bit | name | set when | `valid` |
//! |---|---|---|---|
//! | 0 | `BOARD_TIMEOUT` | a board did not answer the read in time | 0 |
//! | 1 | `BOARD_ERROR` | a board answered with a bad reply (CRC, label, length, source) | 0 |
//! | 2 | `WATCHDOG_TIMEOUT` | a board reports its watchdog expired (the console stopped talking to it) | as read |
//! | 3 | `POWER_OFF` | motor power is not enabled or the motor supply is not good | as read |
//! | 4 | `ENCODER_ERROR` | an encoder reports an error or an overflow | as read |
//! | 5 | `AMP_FAULT` | an amplifier reports a fault or a current-check trip | as read |
//! | 6 | `INSERTION_CLAMPED` | the insertion used by the model was clamped to its calibrated range | — |
//! | 7 | `CORRECTION_ACTIVE_J1` | the compliance correction of joint 1 (yaw) is active | — |
//! | 8 | `CORRECTION_ACTIVE_J2` | the compliance correction of joint 2 (pitch) is active | — |
//! | 9 | `SIMULATED` | the source is the simulated PSM, not real boards | — |
//! | 10 | `OVERRUN` | the previous cycle took longer than the nominal period | — |
//! | 11 | `IMPLAUSIBLE` | the sample failed a plausibility check (joint limits, jump between cycles, effort, pot/encoder agreement) | 0 |
//! | 12 | `NO_SOURCE` | nothing to read: the passive tap sees no console traffic | 0 |
//! | 13 | `HELD` | positions and poses are those of the last valid sample, held (see `held_sample_age_ns`) | 0 |
//! | 14 | `NOT_HOMED` | the console says the arm is not homed: its encoders are not referenced | 0 |
//! | 15 | `ARM_NOT_ENABLED` | the console says the arm is DISABLED, PAUSED or FAULT: the correction is withheld (compensated = raw) | as read |
//! | 16 | `CONSOLE_UNKNOWN` | `follow_console` is on and nothing was heard from the console (yet, or for 1 s): configured values used | as read |
//! | 17 | `NO_INSTRUMENT` | the console says no instrument is mounted: compensated messages invalid | compensated 0 |
//! | 18 | `INSTRUMENT_UNSUPPORTED` | the console's instrument is ERROR or one the catalog cannot model: compensated messages invalid | compensated 0 |
//! | 19 | `NO_CALIBRATION` | no parameter set for the mounted instrument: compensated = raw | — |
//! | 20 | `BASE_FRAME_STALE` | the base frame from the console is older than 1 s (or none yet): the last one (or the configured one) is used | — |
//! | 21 | `WARMUP` | the estimator is warming up (start, after a gap): correction withheld or partial | — |
//! | 22 | `GAP` | a gap in the samples (or time going back) restarted the estimator | — |
//! | 23 | `TRANSIENT` | an abrupt change of effort or motion: correction withheld, then faded back in | — |
//! | 24 | `ACCEL_OUT_OF_RANGE` | acceleration beyond what the dynamics fit saw: correction scaled down | — |
//! | 25 | `INSERTION_EXTRAPOLATED` | insertion within 12 mm outside the fitted range: stiffness extrapolated, bound widened; corrected in full up to 10 mm, fading out over the last 2 mm | — |
//! | 26 | `INSERTION_OUT_OF_RANGE` | insertion more than 12 mm outside the fitted range: no correction | — |
//! | 27 | `STILL_ONLY` | parameters without a dynamics model: corrected only while the arm is still | — |
//! | 28 | `REDUCED` | the correction applied is less than the model's (evidence weight below 1) | — |
//! | 29 | `POT_MISMATCH` | refused: a potentiometer and its encoder disagree beyond the dVRK's tolerance (a slipped encoder?) | 0 |
//! | 30 | `POSITION_OUT_OF_RANGE` | joint 1 or 2 is outside its torque-offset table: correction faded out over 0.05 rad, none beyond | — |
//!
//! Bit 31 is reserved and 0. Bits 21..28 and 30 are the compensation's own trust flags
//! (`dvrk_compliance::trust`: its bits 0..7 shifted by [`TRUST_SHIFT`], its bit 8 at 30). "as read" means the bit describes the hardware state and does
//! not by itself invalidate the sample; the publisher decides `valid` (0 when no usable
//! position could be read). A consumer that needs a safe robot should still check
//! [`FAULT_MASK`].

/// A board did not answer the read in time.
pub const BOARD_TIMEOUT: u32 = 1 << 0;
/// A board answered with a bad reply (CRC, label, length or source mismatch).
pub const BOARD_ERROR: u32 = 1 << 1;
/// A board's watchdog expired.
pub const WATCHDOG_TIMEOUT: u32 = 1 << 2;
/// Motor power is not enabled, or the motor supply is not good.
pub const POWER_OFF: u32 = 1 << 3;
/// An encoder reports an error or an overflow.
pub const ENCODER_ERROR: u32 = 1 << 4;
/// An amplifier reports a fault or a current-check trip.
pub const AMP_FAULT: u32 = 1 << 5;
/// The insertion used by the compliance model was clamped to its calibrated range.
pub const INSERTION_CLAMPED: u32 = 1 << 6;
/// The compliance correction of joint 1 (index 0, yaw) is active.
pub const CORRECTION_ACTIVE_J1: u32 = 1 << 7;
/// The compliance correction of joint 2 (index 1, pitch) is active.
pub const CORRECTION_ACTIVE_J2: u32 = 1 << 8;
/// The data comes from the simulated PSM.
pub const SIMULATED: u32 = 1 << 9;
/// The previous cycle took longer than the nominal period.
pub const OVERRUN: u32 = 1 << 10;

/// The sample failed a plausibility check (joint outside its limits plus a margin, a jump
/// between cycles beyond the joint's maximum velocity, an effort beyond the amplifier's maximum
/// current, pots and encoders disagreeing). Published with `valid = 0`.
pub const IMPLAUSIBLE: u32 = 1 << 11;
/// There is nothing to read: the passive tap sees no console traffic. Published with
/// `valid = 0`.
pub const NO_SOURCE: u32 = 1 << 12;
/// The positions, velocities, efforts and poses of this message are those of the last valid
/// sample, held while reads fail or are rejected (never zeros). Published with `valid = 0`.
pub const HELD: u32 = 1 << 13;

/// Issue 19: the console says the arm is not homed: its encoders are not referenced.
pub const NOT_HOMED: u32 = 1 << 14;
/// Issue 19: the console says the arm is DISABLED, PAUSED or FAULT: the correction is withheld (compensated = raw).
pub const ARM_NOT_ENABLED: u32 = 1 << 15;
/// Issue 19: `follow_console` is on and nothing was heard from the console (yet, or for 1 s): configured values used.
pub const CONSOLE_UNKNOWN: u32 = 1 << 16;
/// Issue 19: the console says no instrument is mounted: compensated messages invalid.
pub const NO_INSTRUMENT: u32 = 1 << 17;
/// Issue 19: the console's instrument is ERROR or one the catalog cannot model: compensated messages invalid.
pub const INSTRUMENT_UNSUPPORTED: u32 = 1 << 18;
/// Issue 19: no parameter set for the mounted instrument: compensated = raw.
pub const NO_CALIBRATION: u32 = 1 << 19;
/// Issue 19: the base frame from the console is older than 1 s (or none yet): the last one (or the configured one) is used.
pub const BASE_FRAME_STALE: u32 = 1 << 20;
/// Where the compensation's trust flags (`dvrk_compliance::trust`, 8 bits) sit.
pub const TRUST_SHIFT: u32 = 21;
/// Issue 20: the estimator is warming up (start, after a gap): correction withheld or partial.
pub const WARMUP: u32 = 1 << 21;
/// Issue 20: a gap in the samples (or time going back) restarted the estimator.
pub const GAP: u32 = 1 << 22;
/// Issue 20: an abrupt change of effort or motion: correction withheld, then faded back in.
pub const TRANSIENT: u32 = 1 << 23;
/// Issue 20: acceleration beyond what the dynamics fit saw: correction scaled down.
pub const ACCEL_OUT_OF_RANGE: u32 = 1 << 24;
/// Issue 20: insertion within 12 mm outside the fitted range: stiffness extrapolated, bound
/// widened; corrected in full up to 10 mm, fading out over the last 2 mm.
pub const INSERTION_EXTRAPOLATED: u32 = 1 << 25;
/// Issue 20: insertion more than 12 mm outside the fitted range: no correction.
pub const INSERTION_OUT_OF_RANGE: u32 = 1 << 26;
/// Issue 20: parameters without a dynamics model: corrected only while the arm is still.
pub const STILL_ONLY: u32 = 1 << 27;
/// Issue 20: the correction applied is less than the model's (evidence weight below 1).
pub const REDUCED: u32 = 1 << 28;

/// Issue 22: the sample was refused (with [`IMPLAUSIBLE`]) because a potentiometer and its
/// encoder disagreed beyond the dVRK's tolerance for longer than its latency: an encoder may
/// have slipped, the check the dVRK console itself relies on.
pub const POT_MISMATCH: u32 = 1 << 29;

/// Issue 20: joint 1 or 2 is outside its torque-offset table, where `tau_0` is held at the
/// table's end: the correction fades out over 0.05 rad and is withheld beyond
/// (`dvrk_compliance::trust::POSITION_OUT_OF_RANGE`).
pub const POSITION_OUT_OF_RANGE: u32 = 1 << 30;

/// Every defined bit.
pub const ALL: u32 = (1 << 31) - 1;

/// Bits that report a hardware or communication fault.
pub const FAULT_MASK: u32 =
    BOARD_TIMEOUT | BOARD_ERROR | WATCHDOG_TIMEOUT | POWER_OFF | ENCODER_ERROR | AMP_FAULT;

/// `(bit, name)` of every defined flag, in bit order (for printing; no allocation).
pub const TABLE: [(u32, &str); 31] = [
    (BOARD_TIMEOUT, "BOARD_TIMEOUT"),
    (BOARD_ERROR, "BOARD_ERROR"),
    (WATCHDOG_TIMEOUT, "WATCHDOG_TIMEOUT"),
    (POWER_OFF, "POWER_OFF"),
    (ENCODER_ERROR, "ENCODER_ERROR"),
    (AMP_FAULT, "AMP_FAULT"),
    (INSERTION_CLAMPED, "INSERTION_CLAMPED"),
    (CORRECTION_ACTIVE_J1, "CORRECTION_ACTIVE_J1"),
    (CORRECTION_ACTIVE_J2, "CORRECTION_ACTIVE_J2"),
    (SIMULATED, "SIMULATED"),
    (OVERRUN, "OVERRUN"),
    (IMPLAUSIBLE, "IMPLAUSIBLE"),
    (NO_SOURCE, "NO_SOURCE"),
    (HELD, "HELD"),
    (NOT_HOMED, "NOT_HOMED"),
    (ARM_NOT_ENABLED, "ARM_NOT_ENABLED"),
    (CONSOLE_UNKNOWN, "CONSOLE_UNKNOWN"),
    (NO_INSTRUMENT, "NO_INSTRUMENT"),
    (INSTRUMENT_UNSUPPORTED, "INSTRUMENT_UNSUPPORTED"),
    (NO_CALIBRATION, "NO_CALIBRATION"),
    (BASE_FRAME_STALE, "BASE_FRAME_STALE"),
    (WARMUP, "WARMUP"),
    (GAP, "GAP"),
    (TRANSIENT, "TRANSIENT"),
    (ACCEL_OUT_OF_RANGE, "ACCEL_OUT_OF_RANGE"),
    (INSERTION_EXTRAPOLATED, "INSERTION_EXTRAPOLATED"),
    (INSERTION_OUT_OF_RANGE, "INSERTION_OUT_OF_RANGE"),
    (STILL_ONLY, "STILL_ONLY"),
    (REDUCED, "REDUCED"),
    (POT_MISMATCH, "POT_MISMATCH"),
    (POSITION_OUT_OF_RANGE, "POSITION_OUT_OF_RANGE"),
];

/// Names of the bits set in `flags`, in bit order; reserved bits are skipped.
pub fn names(flags: u32) -> impl Iterator<Item = &'static str> {
    TABLE
        .iter()
        .filter(move |(bit, _)| flags & bit != 0)
        .map(|(_, name)| *name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_covers_all_bits_once_in_order() {
        let mut acc = 0u32;
        for (i, (bit, _)) in TABLE.iter().enumerate() {
            assert_eq!(*bit, 1 << i);
            acc |= bit;
        }
        assert_eq!(acc, ALL);
    }

    #[test]
    fn names_lists_set_bits() {
        let v: Vec<_> = names(BOARD_TIMEOUT | CORRECTION_ACTIVE_J2 | (1 << 31)).collect();
        assert_eq!(v, ["BOARD_TIMEOUT", "CORRECTION_ACTIVE_J2"]);
        assert_eq!(names(0).count(), 0);
    }
}
