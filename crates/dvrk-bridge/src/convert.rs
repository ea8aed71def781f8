//! The pure core of the bridges: which ROS 2 topics exist, how a shared-memory message becomes
//! their CDR payloads, ROS time from the monotonic stamps, and decimation. No I/O, no clock.

use dvrk_ipc::{CompensationStatusV2, JOINT_NAMES, JointStateV1, PoseV1};

use crate::cdr::{self, CdrWriter, RosTime};
use crate::msgdefs::{COMPENSATION_STATUS, JOINT_STATE, MsgType, POSE_STAMPED};

/// Number of kinematic joints in `measured_js` (the 7th joint of the shared-memory message is
/// the jaw, published on `jaw/measured_js`).
pub const ARM_JOINTS: usize = 6;

/// The ROS 2 topics a bridge writes, all under `<arm>/compensated/`. None of them is a name the
/// dVRK console publishes itself, so the bridge can run beside the console's ROS bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OutTopic {
    /// `compensated/local/measured_cp`: tip pose in the RCM frame (frame id `<arm>_base`).
    LocalMeasuredCp,
    /// `compensated/measured_cp`: base frame × local.
    MeasuredCp,
    /// `compensated/measured_js`: the 6 kinematic joints.
    MeasuredJs,
    /// `compensated/jaw/measured_js`: the jaw.
    JawMeasuredJs,
    /// `compensated/status`.
    Status,
}

impl OutTopic {
    pub const ALL: [OutTopic; 5] = [
        OutTopic::LocalMeasuredCp,
        OutTopic::MeasuredCp,
        OutTopic::MeasuredJs,
        OutTopic::JawMeasuredJs,
        OutTopic::Status,
    ];

    /// The part after `<arm>/`.
    pub const fn suffix(self) -> &'static str {
        match self {
            OutTopic::LocalMeasuredCp => "compensated/local/measured_cp",
            OutTopic::MeasuredCp => "compensated/measured_cp",
            OutTopic::MeasuredJs => "compensated/measured_js",
            OutTopic::JawMeasuredJs => "compensated/jaw/measured_js",
            OutTopic::Status => "compensated/status",
        }
    }

    /// The message type.
    pub const fn msg_type(self) -> MsgType {
        match self {
            OutTopic::LocalMeasuredCp | OutTopic::MeasuredCp => POSE_STAMPED,
            OutTopic::MeasuredJs | OutTopic::JawMeasuredJs => JOINT_STATE,
            OutTopic::Status => COMPENSATION_STATUS,
        }
    }

    /// The ROS 2 topic name, e.g. `/PSM1/compensated/local/measured_cp`.
    pub fn ros_name(self, arm: &str) -> String {
        format!("/{arm}/{}", self.suffix())
    }

    /// The DDS topic name under which ROS 2 sees [`OutTopic::ros_name`]
    /// (`rt/PSM1/compensated/local/measured_cp`).
    pub fn dds_name(self, arm: &str) -> String {
        format!("rt/{arm}/{}", self.suffix())
    }
}

/// A rigid transform: translation (m) and unit quaternion (x, y, z, w).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    pub translation_m: [f64; 3],
    pub rotation_xyzw: [f64; 4],
}

impl Transform {
    pub const IDENTITY: Transform = Transform {
        translation_m: [0.0; 3],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
    };

    /// `self × (position, orientation)`: the pose `local` expressed in this transform's
    /// reference frame.
    pub fn apply(&self, position: &[f64; 3], orientation_xyzw: &[f64; 4]) -> ([f64; 3], [f64; 4]) {
        let r = rotate(&self.rotation_xyzw, position);
        let t = self.translation_m;
        (
            [r[0] + t[0], r[1] + t[1], r[2] + t[2]],
            quat_mul(&self.rotation_xyzw, orientation_xyzw),
        )
    }
}

fn quat_mul(a: &[f64; 4], b: &[f64; 4]) -> [f64; 4] {
    let [ax, ay, az, aw] = *a;
    let [bx, by, bz, bw] = *b;
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

fn rotate(q: &[f64; 4], v: &[f64; 3]) -> [f64; 3] {
    // v' = v + 2 w (u × v) + 2 u × (u × v), u = (x, y, z).
    let u = [q[0], q[1], q[2]];
    let w = q[3];
    let c1 = cross(&u, v);
    let c2 = cross(&u, &c1);
    [
        v[0] + 2.0 * (w * c1[0] + c2[0]),
        v[1] + 2.0 * (w * c1[1] + c2[1]),
        v[2] + 2.0 * (w * c1[2] + c2[2]),
    ]
}

fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `CLOCK_REALTIME - CLOCK_MONOTONIC` in nanoseconds, measured once at start: the messages carry
/// monotonic stamps only, so ROS time is `sample_t_ns + offset`. A step of the wall clock
/// (NTP) after start is not followed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockOffset {
    pub realtime_minus_monotonic_ns: i64,
}

impl ClockOffset {
    /// ROS time of the monotonic instant `monotonic_ns`.
    pub fn ros_time(&self, monotonic_ns: u64) -> RosTime {
        let mono = i64::try_from(monotonic_ns).unwrap_or(i64::MAX);
        RosTime::from_unix_ns(mono.saturating_add(self.realtime_minus_monotonic_ns))
    }
}

/// Names and frames of one arm's output.
#[derive(Debug, Clone)]
pub struct ArmFrames {
    /// Arm name, the ROS namespace (`PSM1`).
    pub arm: String,
    /// Reference frame of `local/measured_cp` (`PSM1_base`, the RCM frame as the dVRK names it).
    pub local_frame_id: String,
    /// Reference frame of `measured_cp` (`PSM1_base` while the base frame is the identity).
    pub base_frame_id: String,
    /// Frame id of the joint states (`PSM1`).
    pub joint_frame_id: String,
    /// The base frame: `measured_cp = base × local/measured_cp`.
    pub base: Transform,
}

impl ArmFrames {
    /// The dVRK's frame names for `arm` with an identity base frame (no base frame is
    /// configured yet, so `measured_cp` equals `local/measured_cp` and shares its frame id).
    pub fn new(arm: &str) -> Self {
        ArmFrames {
            arm: arm.to_owned(),
            local_frame_id: format!("{arm}_base"),
            base_frame_id: format!("{arm}_base"),
            joint_frame_id: arm.to_owned(),
            base: Transform::IDENTITY,
        }
    }
}

/// Turns shared-memory messages into CDR bodies. Holds one reusable buffer.
#[derive(Debug, Clone)]
pub struct Encoder {
    pub frames: ArmFrames,
    pub clock: ClockOffset,
    buf: CdrWriter,
}

impl Encoder {
    pub fn new(frames: ArmFrames, clock: ClockOffset) -> Self {
        Encoder {
            frames,
            clock,
            buf: CdrWriter::new(),
        }
    }

    /// The body written by the most recent encoding call.
    pub fn last_body(&self) -> &[u8] {
        self.buf.body()
    }

    /// The ROS stamp of a message header: its sample time in ROS time.
    pub fn stamp(&self, h: &dvrk_ipc::Header) -> RosTime {
        self.clock.ros_time(h.sample_t_ns)
    }

    /// `local/measured_cp` or `measured_cp` from a compensated pose (RCM frame).
    pub fn pose(&mut self, topic: OutTopic, p: &PoseV1) -> &CdrWriter {
        let stamp = self.stamp(&p.header);
        self.buf.clear();
        match topic {
            OutTopic::MeasuredCp => {
                let (pos, q) = self.frames.base.apply(&p.position_m, &p.orientation_xyzw);
                cdr::pose_stamped(&mut self.buf, stamp, &self.frames.base_frame_id, &pos, &q);
            }
            _ => cdr::pose_stamped(
                &mut self.buf,
                stamp,
                &self.frames.local_frame_id,
                &p.position_m,
                &p.orientation_xyzw,
            ),
        }
        &self.buf
    }

    /// `measured_js` (6 joints) or `jaw/measured_js` (the 7th).
    pub fn joints(&mut self, topic: OutTopic, js: &JointStateV1) -> &CdrWriter {
        let stamp = self.stamp(&js.header);
        let range = match topic {
            OutTopic::JawMeasuredJs => ARM_JOINTS..ARM_JOINTS + 1,
            _ => 0..ARM_JOINTS,
        };
        self.buf.clear();
        cdr::joint_state(
            &mut self.buf,
            stamp,
            &self.frames.joint_frame_id,
            &JOINT_NAMES[range.clone()],
            &js.position[range.clone()],
            &js.velocity[range.clone()],
            &js.effort[range],
        );
        &self.buf
    }

    /// `compensated/status`, field for field ([`crate::msgdefs::COMPENSATION_STATUS`]).
    pub fn status(&mut self, s: &CompensationStatusV2) -> &CdrWriter {
        let stamp = self.stamp(&s.header);
        let w = &mut self.buf;
        w.clear();
        w.header(stamp, &self.frames.local_frame_id);
        w.u64(s.header.seq);
        w.bool(s.header.valid != 0);
        w.u32(s.header.flags);
        for &x in s.tau_ext_nm.iter().chain(&s.delta_rad) {
            w.f64(x);
        }
        w.f64(s.insertion_m);
        for &x in &s.tau_margin_nm {
            w.f64(x);
        }
        for x in [
            s.cycle_period_ns,
            s.cycle_duration_ns,
            s.cycles_total,
            s.read_failures_total,
            s.overruns_total,
        ] {
            w.u64(x);
        }
        w.u32(s.consecutive_read_failures);
        for x in [s.held_sample_age_ns, s.publish_late_ns, s.implausible_total] {
            w.u64(x);
        }
        &self.buf
    }
}

/// Lets through at most one cycle per period of `--rate`, judged on the sample stamps, so every
/// topic that sees the same headers makes the same choice. A rate of `None` lets every cycle
/// through.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decimator {
    period_ns: Option<u64>,
    last_bucket: Option<u64>,
}

impl Decimator {
    /// `rate_hz` of `None` keeps every cycle. The rate must be finite and > 0 (checked by the
    /// caller's argument parsing, see [`Decimator::period_from_rate`]).
    pub fn new(period_ns: Option<u64>) -> Self {
        Decimator {
            period_ns,
            last_bucket: None,
        }
    }

    /// The period of a rate in Hz, or why the rate is not usable.
    pub fn period_from_rate(rate_hz: f64) -> Result<u64, &'static str> {
        if !rate_hz.is_finite() || rate_hz <= 0.0 {
            return Err("the rate must be a finite number of Hz above 0");
        }
        let ns = (1e9 / rate_hz).round();
        if ns < 1.0 {
            return Err("the rate is above 1 GHz");
        }
        Ok(ns as u64)
    }

    /// Whether the cycle sampled at `sample_t_ns` is to be published: the first cycle of each
    /// period-long slot of the monotonic clock.
    pub fn accept(&mut self, sample_t_ns: u64) -> bool {
        let Some(p) = self.period_ns else {
            return true;
        };
        let bucket = sample_t_ns / p;
        match self.last_bucket {
            Some(b) if bucket <= b => false,
            _ => {
                self.last_bucket = Some(bucket);
                true
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn topic_names_stay_under_compensated() {
        for t in OutTopic::ALL {
            assert!(t.ros_name("PSM1").starts_with("/PSM1/compensated/"));
            assert!(t.dds_name("PSM1").starts_with("rt/PSM1/compensated/"));
        }
        assert_eq!(
            OutTopic::LocalMeasuredCp.dds_name("PSM1"),
            "rt/PSM1/compensated/local/measured_cp"
        );
    }

    #[test]
    fn base_frame_rotates_then_translates() {
        // 90 degrees about z, then +1 m in x.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let base = Transform {
            translation_m: [1.0, 0.0, 0.0],
            rotation_xyzw: [0.0, 0.0, h, h],
        };
        let (p, q) = base.apply(&[1.0, 0.0, 0.5], &[0.0, 0.0, 0.0, 1.0]);
        assert!(
            close(p[0], 1.0) && close(p[1], 1.0) && close(p[2], 0.5),
            "{p:?}"
        );
        assert!(close(q[2], h) && close(q[3], h), "{q:?}");
        let (p, q) = Transform::IDENTITY.apply(&[0.1, 0.2, 0.3], &[0.5, 0.5, 0.5, 0.5]);
        assert_eq!(p, [0.1, 0.2, 0.3]);
        assert_eq!(q, [0.5, 0.5, 0.5, 0.5]);
    }

    #[test]
    fn clock_offset_maps_monotonic_to_ros_time() {
        let c = ClockOffset {
            realtime_minus_monotonic_ns: 1_700_000_000_000_000_000,
        };
        let t = c.ros_time(1_500_000_001);
        assert_eq!((t.sec, t.nanosec), (1_700_000_001, 500_000_001));
    }

    #[test]
    fn decimator_keeps_one_cycle_per_period() {
        let mut d = Decimator::new(Some(Decimator::period_from_rate(100.0).unwrap()));
        // 1.5 kHz for 0.1 s -> 10 slots of 10 ms.
        let kept = (0..150u64)
            .filter(|i| d.accept(1_000_000_000 + i * 666_667))
            .count();
        assert_eq!(kept, 10);
        let mut all = Decimator::new(None);
        assert!((0..5).all(|i| all.accept(i)));
        assert!(Decimator::period_from_rate(0.0).is_err());
        assert!(Decimator::period_from_rate(f64::NAN).is_err());
        assert!(Decimator::period_from_rate(-3.0).is_err());
    }

    #[test]
    fn joints_split_into_arm_and_jaw() {
        let mut js = JointStateV1::default();
        for i in 0..7 {
            js.position[i] = i as f64;
        }
        let mut e = Encoder::new(
            ArmFrames::new("PSM1"),
            ClockOffset {
                realtime_minus_monotonic_ns: 0,
            },
        );
        let arm = e.joints(OutTopic::MeasuredJs, &js).body().to_vec();
        let jaw = e.joints(OutTopic::JawMeasuredJs, &js).body().to_vec();
        let count_at = |b: &[u8], name: &str| {
            let i = b.windows(name.len()).position(|w| w == name.as_bytes());
            i.is_some()
        };
        assert!(count_at(&arm, "wrist_yaw") && !count_at(&arm, "jaw"));
        assert!(count_at(&jaw, "jaw") && !count_at(&jaw, "yaw\0"));
        // The jaw's position is the 7th joint.
        assert!(jaw.windows(8).any(|w| w == 6.0f64.to_le_bytes()));
    }
}
