//! The message types published by dvrk-sidecar.
//!
//! Every type is `#[repr(C)]`, contains only `u64`, `u32`, `f64` and fixed arrays of them, and has
//! no implicit padding (every hole is a named `_reserved*` field that the publisher sets to 0).
//! The byte layouts are fixed by the `const` assertions at the bottom of this file and mirrored in
//! `include/dvrk_ipc.h` for C and C++ consumers and in `examples/python/subscriber.py`.
//!
//! iceoryx2 identifies a payload across processes by its type name, size and alignment only: a
//! layout change that keeps the size would not be detected, so any change of a field bumps the
//! `V<n>` suffix of the type name.
//!
//! Units are SI (m, rad, N·m, N); times are host `CLOCK_MONOTONIC` nanoseconds unless the field
//! name says otherwise.

use iceoryx2::prelude::ZeroCopySend;

/// Number of joints in a joint-state message: the six kinematic joints of a PSM, as the dVRK 2.x
/// console publishes them on `measured_js` (the jaw has its own topic, `jaw/measured_js`).
pub const NUM_JOINTS: usize = 6;

/// Joint names in message order (dVRK 2.x names, without the pre-2024 `outer_` prefix).
///
/// Index 0 and 1 are joints "1" and "2" of the compliance paper; index 2 is the insertion
/// (prismatic, metres; its effort is in newtons).
pub const JOINT_NAMES: [&str; NUM_JOINTS] = [
    "yaw",
    "pitch",
    "insertion",
    "roll",
    "wrist_pitch",
    "wrist_yaw",
];

/// Name of the single joint of `jaw/measured_js`.
pub const JAW_NAME: &str = "jaw";

/// Common header of every message. All nine messages of one publisher cycle carry the same
/// header except for anything the publisher chooses to vary per message (normally nothing).
///
/// | offset | field | meaning |
/// |---|---|---|
/// | 0 | `seq` | cycle counter, starts at 1, +1 per cycle, equal in all messages of a cycle |
/// | 8 | `sample_t_ns` | host `CLOCK_MONOTONIC` ns when the board read completed |
/// | 16 | `sample_realtime_ns` | host `CLOCK_REALTIME` ns since the Unix epoch at the same instant: the ROS time of the sample |
/// | 24 | `board_timestamp` | raw board timestamp counters: first board low 32 bits, second board high 32 bits |
/// | 32 | `publish_t_ns` | host `CLOCK_MONOTONIC` ns when the publisher wrote the cycle |
/// | 40 | `valid` | 1 = the values come from a successful read; 0 = do not use them |
/// | 44 | `flags` | reason and state bits, see [`crate::flags`] |
///
/// `sample_realtime_ns` is read right after `sample_t_ns` (two vDSO clock reads, tens of ns
/// apart), so a consumer can put a sample on ROS time without its own clock offset. The realtime
/// clock can jump (NTP, an operator); the monotonic one cannot: order and time intervals by
/// `sample_t_ns`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("dvrk::HeaderV2")]
pub struct Header {
    pub seq: u64,
    pub sample_t_ns: u64,
    pub sample_realtime_ns: u64,
    pub board_timestamp: u64,
    pub publish_t_ns: u64,
    pub valid: u32,
    pub flags: u32,
}

impl Header {
    /// Packs the timestamp counters of up to two boards into [`Header::board_timestamp`]
    /// (first board in the low 32 bits).
    pub const fn pack_board_timestamps(ts: [u32; 2]) -> u64 {
        (ts[0] as u64) | ((ts[1] as u64) << 32)
    }

    /// The two board timestamp counters packed by [`Header::pack_board_timestamps`].
    pub const fn board_timestamps(&self) -> [u32; 2] {
        [
            (self.board_timestamp & 0xffff_ffff) as u32,
            (self.board_timestamp >> 32) as u32,
        ]
    }

    /// `valid != 0`.
    pub const fn is_valid(&self) -> bool {
        self.valid != 0
    }

    /// Whether every bit of `mask` is set in `flags`.
    pub const fn has(&self, mask: u32) -> bool {
        self.flags & mask == mask
    }
}

/// Joint state (CRTK `measured_js`): position (rad, m for insertion), velocity (rad/s, m/s) and
/// effort (N·m, N for insertion) of the six joints in [`JOINT_NAMES`] order.
///
/// Published on `<prefix>/measured_js` (as read from the boards) and on
/// `<prefix>/compensated/measured_js` (joints 1 and 2 corrected by the compliance model; the
/// other joints, velocity and effort are passed through).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("dvrk::JointStateV2")]
pub struct JointStateV2 {
    pub header: Header,
    pub position: [f64; NUM_JOINTS],
    pub velocity: [f64; NUM_JOINTS],
    pub effort: [f64; NUM_JOINTS],
}

/// Jaw state (CRTK `jaw/measured_js`): opening angle (rad), its rate (rad/s) and effort (N·m) of
/// the instrument's jaw ([`JAW_NAME`]), as the dVRK 2.x console publishes it beside
/// `measured_js`.
///
/// Published on `<prefix>/jaw/measured_js` and, unchanged (the compliance model does not touch
/// the jaw), on `<prefix>/compensated/jaw/measured_js`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("dvrk::JawStateV1")]
pub struct JawStateV1 {
    pub header: Header,
    pub position: f64,
    pub velocity: f64,
    pub effort: f64,
}

/// Tool-tip pose (CRTK `measured_cp` / `local/measured_cp`): the instrument tip as the dVRK
/// console computes it from the joints.
///
/// The orientation is given twice, as a unit quaternion (x, y, z, w) and as a row-major 3×3
/// rotation matrix (`rotation[3 * row + col]`), so consumers need no conversion code.
///
/// Published, as the dVRK 2.x console does, on
/// - `<prefix>/local/measured_cp`: in the RCM frame of the PSM (frame id `<arm>`);
/// - `<prefix>/measured_cp`: in the arm's base frame (frame id `<arm>_base`), i.e. the configured
///   base frame × the local pose;
///
/// from the raw joints, and the same two under `<prefix>/compensated/` from the compensated
/// joints.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("dvrk::PoseV2")]
pub struct PoseV2 {
    pub header: Header,
    pub position_m: [f64; 3],
    pub orientation_xyzw: [f64; 4],
    pub rotation: [f64; 9],
}

impl Default for PoseV2 {
    /// The identity pose with a zero header.
    fn default() -> Self {
        Self {
            header: Header::default(),
            position_m: [0.0; 3],
            orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        }
    }
}

/// State of the compliance compensation and of the publishing loop (`<prefix>/compensated/status`).
///
/// | field | meaning |
/// |---|---|
/// | `tau_ext_nm` | estimated external torque on joints 1, 2 (N·m) |
/// | `delta_rad` | correction `q - q_hat` of joints 1, 2 (rad); the compensated joint is `q - delta` |
/// | `insertion_m` | insertion L used by the model, after clamping to the calibrated range |
/// | `cycle_period_ns` | time between this cycle's sample and the previous cycle's sample |
/// | `cycle_duration_ns` | work time of the most recent completed cycle (read start to notify); the current cycle is not finished when this message is written |
/// | `cycles_total` | cycles published since the publisher started (= `seq` when none was skipped) |
/// | `read_failures_total` | cycles whose read failed (published with `valid = 0`) since start |
/// | `overruns_total` | cycles that took longer than the nominal period since start |
/// | `consecutive_read_failures` | failed reads in a row up to and including this cycle (0 when this read succeeded) |
/// | `source_state` | what produced the sample (issue 19), packed: bits 0-3 the console's operating state (0 unknown, 1 DISABLED, 2 ENABLED, 3 PAUSED, 4 FAULT), bit 4 homed, bit 5 the console heard (the service follows it), bits 8-15 the parameter set in use (its index in the file + 1; 0: the only set, or none), bits 16-31 the instrument (0 not known yet, 1 removed, 2 not modelled, 3 + its index in the catalog, `dvrk_compliance::instruments()`); 0 when the service does not follow a console |
/// | `tau_margin_nm` | how far \|tau_ext\| of joints 1, 2 is above (> 0) or below (< 0) the threshold at which the correction engages (N·m); 0 when the sample is invalid |
/// | `held_sample_age_ns` | 0 when this cycle's read succeeded; otherwise the age of the last valid sample whose positions and poses are held in the messages (`u64::MAX` when there was none yet) |
/// | `publish_late_ns` | how late this cycle started after its scheduled deadline (0 in `follow` mode and when on time) |
/// | `implausible_total` | samples rejected by the plausibility checks since start (published with `valid = 0` and `IMPLAUSIBLE`) |
/// | `bound_rad` | 95% bound on the error of the compensated joints 1, 2 (rad): how far the true shaft angle may be from `compensated/measured_js` (NaN before the first valid sample) |
/// | `tip_bound_m` | 95% bound on the compensated tip position's error from joints 1, 2 (m): widen a virtual fixture's margin by it, or distrust a sample when it exceeds the task's tolerance |
/// | `weight` | share of the model's correction applied to joints 1, 2 (0 to 1; below 1 with `REDUCED`) |
/// | `_reserved` | 0 |
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("dvrk::CompensationStatusV4")]
pub struct CompensationStatusV4 {
    pub header: Header,
    pub tau_ext_nm: [f64; 2],
    pub delta_rad: [f64; 2],
    pub insertion_m: f64,
    pub cycle_period_ns: u64,
    pub cycle_duration_ns: u64,
    pub cycles_total: u64,
    pub read_failures_total: u64,
    pub overruns_total: u64,
    pub consecutive_read_failures: u32,
    pub source_state: u32,
    pub tau_margin_nm: [f64; 2],
    pub held_sample_age_ns: u64,
    pub publish_late_ns: u64,
    pub implausible_total: u64,
    pub bound_rad: [f64; 2],
    pub tip_bound_m: f64,
    pub weight: [f64; 2],
    pub _reserved: u64,
}

/// Packs [`CompensationStatusV4::source_state`]: the console's operating state (0 unknown,
/// 1 DISABLED, 2 ENABLED, 3 PAUSED, 4 FAULT), homed, heard, the parameter set (index + 1, 0:
/// the only one or none) and the instrument code (0 not known yet, 1 removed, 2 not modelled,
/// 3 + its catalog index).
pub const fn pack_source_state(
    console_state: u8,
    homed: bool,
    heard: bool,
    parameter_set: u8,
    instrument: u16,
) -> u32 {
    (console_state as u32 & 0xf)
        | ((homed as u32) << 4)
        | ((heard as u32) << 5)
        | ((parameter_set as u32) << 8)
        | ((instrument as u32) << 16)
}

impl CompensationStatusV4 {
    /// The console's operating state as the console names it (`UNKNOWN` when not followed or
    /// not heard).
    pub fn console_state(&self) -> &'static str {
        match self.source_state & 0xf {
            1 => "DISABLED",
            2 => "ENABLED",
            3 => "PAUSED",
            4 => "FAULT",
            _ => "UNKNOWN",
        }
    }
    /// The console says the arm is homed.
    pub fn console_homed(&self) -> bool {
        self.source_state & (1 << 4) != 0
    }
    /// The service hears the console.
    pub fn console_heard(&self) -> bool {
        self.source_state & (1 << 5) != 0
    }
    /// The parameter set in use (its index in the file + 1; 0: the file's only set, or none).
    pub fn parameter_set(&self) -> u8 {
        ((self.source_state >> 8) & 0xff) as u8
    }
    /// The instrument: 0 not known yet, 1 removed, 2 not modelled, 3 + its index in
    /// `dvrk_compliance::instruments()`.
    pub fn instrument_code(&self) -> u16 {
        (self.source_state >> 16) as u16
    }
}

/// The four states of one arm in one cycle, as the dVRK 2.x console names them: what
/// [`CycleMessages`] carries twice, raw (`<prefix>/...`) and compensated
/// (`<prefix>/compensated/...`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ArmState {
    /// `measured_js`.
    pub measured_js: JointStateV2,
    /// `jaw/measured_js`.
    pub jaw_measured_js: JawStateV1,
    /// `local/measured_cp`: the tip in the RCM frame.
    pub local_measured_cp: PoseV2,
    /// `measured_cp`: the tip in the base frame.
    pub measured_cp: PoseV2,
}

impl ArmState {
    /// Sets the header of all four messages.
    pub fn set_header(&mut self, header: Header) {
        self.measured_js.header = header;
        self.jaw_measured_js.header = header;
        self.local_measured_cp.header = header;
        self.measured_cp.header = header;
    }
}

/// Everything published in one cycle ([`crate::ArmPublisher::publish_cycle`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CycleMessages {
    /// As read from the boards.
    pub measured: ArmState,
    /// Joints 1 and 2 corrected by the compliance model, and the poses computed from them.
    pub compensated: ArmState,
    /// `compensated/status`.
    pub status: CompensationStatusV4,
}

impl CycleMessages {
    /// Sets the header of all nine messages.
    pub fn set_header(&mut self, header: Header) {
        self.measured.set_header(header);
        self.compensated.set_header(header);
        self.status.header = header;
    }
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for super::JointStateV2 {}
    impl Sealed for super::JawStateV1 {}
    impl Sealed for super::PoseV2 {}
    impl Sealed for super::CompensationStatusV4 {}
}

/// The message types of this crate (sealed): what [`crate::Subscription`] and
/// [`crate::open_topic`] accept.
pub trait Message:
    sealed::Sealed + Copy + core::fmt::Debug + Default + ZeroCopySend + 'static
{
    /// The iceoryx2 type name (same string as the `#[type_name]` attribute).
    const TYPE_NAME: &'static str;
    /// Size in bytes (also in `dvrk_ipc.h`).
    const SIZE: usize = core::mem::size_of::<Self>();
    /// The common header.
    fn header(&self) -> &Header;
    /// The common header, mutable.
    fn header_mut(&mut self) -> &mut Header;
}

macro_rules! impl_message {
    ($ty:ty, $name:literal) => {
        impl Message for $ty {
            const TYPE_NAME: &'static str = $name;
            fn header(&self) -> &Header {
                &self.header
            }
            fn header_mut(&mut self) -> &mut Header {
                &mut self.header
            }
        }
    };
}

impl_message!(JointStateV2, "dvrk::JointStateV2");
impl_message!(JawStateV1, "dvrk::JawStateV1");
impl_message!(PoseV2, "dvrk::PoseV2");
impl_message!(CompensationStatusV4, "dvrk::CompensationStatusV4");

/// Sizes in bytes, identical in `dvrk_ipc.h`.
pub const HEADER_SIZE: usize = 48;
pub const JOINT_STATE_V2_SIZE: usize = 192;
pub const JAW_STATE_V1_SIZE: usize = 72;
pub const POSE_V2_SIZE: usize = 176;
pub const COMPENSATION_STATUS_V4_SIZE: usize = 224;

// Compile-time layout checks: size, alignment and every field offset. Each offset equals the end of
// the previous field, so there is no implicit padding anywhere (the checks fail to compile if a
// field is added, removed, reordered or resized without updating them).
macro_rules! assert_layout {
    ($ty:ty, size = $size:expr, $( $field:ident : $fty:ty ),+ $(,)?) => {
        const _: () = {
            use core::mem::{align_of, offset_of, size_of};
            let mut end = 0usize;
            $(
                assert!(offset_of!($ty, $field) == end, "implicit padding before a field");
                end += size_of::<$fty>();
            )+
            assert!(end == size_of::<$ty>(), "implicit trailing padding");
            assert!(size_of::<$ty>() == $size, "size changed: bump the V<n> type name");
            assert!(align_of::<$ty>() == 8);
        };
    };
}

assert_layout!(Header, size = HEADER_SIZE,
    seq: u64, sample_t_ns: u64, sample_realtime_ns: u64, board_timestamp: u64, publish_t_ns: u64,
    valid: u32, flags: u32);
assert_layout!(JointStateV2, size = JOINT_STATE_V2_SIZE,
    header: Header, position: [f64; NUM_JOINTS], velocity: [f64; NUM_JOINTS],
    effort: [f64; NUM_JOINTS]);
assert_layout!(JawStateV1, size = JAW_STATE_V1_SIZE,
    header: Header, position: f64, velocity: f64, effort: f64);
assert_layout!(PoseV2, size = POSE_V2_SIZE,
    header: Header, position_m: [f64; 3], orientation_xyzw: [f64; 4], rotation: [f64; 9]);
assert_layout!(CompensationStatusV4, size = COMPENSATION_STATUS_V4_SIZE,
    header: Header, tau_ext_nm: [f64; 2], delta_rad: [f64; 2], insertion_m: f64,
    cycle_period_ns: u64, cycle_duration_ns: u64, cycles_total: u64, read_failures_total: u64,
    overruns_total: u64, consecutive_read_failures: u32, source_state: u32, tau_margin_nm: [f64; 2],
    held_sample_age_ns: u64, publish_late_ns: u64, implausible_total: u64, bound_rad: [f64; 2],
    tip_bound_m: f64, weight: [f64; 2], _reserved: u64);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_match_the_derive_attribute() {
        // SAFETY: `type_name` is only `unsafe` because implementors promise uniqueness.
        unsafe {
            assert_eq!(
                <JointStateV2 as ZeroCopySend>::type_name(),
                JointStateV2::TYPE_NAME
            );
            assert_eq!(
                <JawStateV1 as ZeroCopySend>::type_name(),
                JawStateV1::TYPE_NAME
            );
            assert_eq!(<PoseV2 as ZeroCopySend>::type_name(), PoseV2::TYPE_NAME);
            assert_eq!(
                <CompensationStatusV4 as ZeroCopySend>::type_name(),
                CompensationStatusV4::TYPE_NAME
            );
            assert_eq!(<Header as ZeroCopySend>::type_name(), "dvrk::HeaderV2");
        }
    }

    #[test]
    fn board_timestamps_round_trip() {
        let h = Header {
            board_timestamp: Header::pack_board_timestamps([0xdead_beef, 0x0123_4567]),
            ..Header::default()
        };
        assert_eq!(h.board_timestamp, 0x0123_4567_dead_beef);
        assert_eq!(h.board_timestamps(), [0xdead_beef, 0x0123_4567]);
    }

    #[test]
    fn default_pose_is_identity() {
        let p = PoseV2::default();
        assert_eq!(p.orientation_xyzw, [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(p.rotation[0] + p.rotation[4] + p.rotation[8], 3.0);
    }

    #[test]
    fn joint_names_are_the_dvrk_2_names() {
        assert_eq!(
            JOINT_NAMES,
            [
                "yaw",
                "pitch",
                "insertion",
                "roll",
                "wrist_pitch",
                "wrist_yaw"
            ]
        );
        assert_eq!(JAW_NAME, "jaw");
    }

    #[test]
    fn set_header_reaches_all_nine_messages() {
        let mut c = CycleMessages::default();
        let h = Header {
            seq: 7,
            sample_realtime_ns: 11,
            ..Header::default()
        };
        c.set_header(h);
        for got in [
            c.measured.measured_js.header,
            c.measured.jaw_measured_js.header,
            c.measured.local_measured_cp.header,
            c.measured.measured_cp.header,
            c.compensated.measured_js.header,
            c.compensated.jaw_measured_js.header,
            c.compensated.local_measured_cp.header,
            c.compensated.measured_cp.header,
            c.status.header,
        ] {
            assert_eq!(got, h);
        }
    }
}
