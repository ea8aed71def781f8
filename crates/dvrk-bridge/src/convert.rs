//! The pure core of the bridges: which ROS 2 topics exist, how a shared-memory message becomes
//! their CDR payloads, ROS time from the monotonic stamps, and decimation. No I/O, no clock.

use dvrk_ipc::{CompensationStatusV4, JAW_NAME, JOINT_NAMES, JawStateV1, JointStateV2, PoseV2};

use crate::cdr::{self, CdrWriter, RosTime};
use crate::msgdefs::{
    COMPENSATION_STATUS, JOINT_STATE, MsgType, POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED,
};

/// The ROS 2 topics of the bridges. The ROS 2 bridge publishes only [`OutTopic::ALL`], all under
/// `<arm>/compensated/`: none of them is a name the dVRK console publishes itself, so it can run
/// beside the console's ROS bridge. The recorder also writes [`OutTopic::RAW`], the sidecar's
/// uncompensated topics under the console's names (a file clashes with nobody).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OutTopic {
    /// `compensated/local/measured_cp`: tip pose in the RCM frame (frame id `<arm>_base`).
    LocalMeasuredCp,
    /// `compensated/measured_cp`: base frame × local.
    MeasuredCp,
    /// `compensated/local/measured_cp_with_covariance`: [`OutTopic::LocalMeasuredCp`] with the
    /// covariance of its error ([`PoseCovariance`]).
    LocalMeasuredCpWithCovariance,
    /// `compensated/measured_cp_with_covariance`: [`OutTopic::MeasuredCp`] with the covariance
    /// of its error ([`PoseCovariance`]).
    MeasuredCpWithCovariance,
    /// `compensated/measured_js`: the 6 kinematic joints.
    MeasuredJs,
    /// `compensated/jaw/measured_js`: the jaw.
    JawMeasuredJs,
    /// `compensated/status`.
    Status,
    /// `local/measured_cp`, from the joints as read.
    RawLocalMeasuredCp,
    /// `measured_cp`, from the joints as read.
    RawMeasuredCp,
    /// `measured_js`, as read.
    RawMeasuredJs,
    /// `jaw/measured_js`, as read.
    RawJawMeasuredJs,
}

impl OutTopic {
    /// The compensated topics (what the ROS 2 bridge publishes).
    pub const ALL: [OutTopic; 7] = [
        OutTopic::LocalMeasuredCp,
        OutTopic::MeasuredCp,
        OutTopic::LocalMeasuredCpWithCovariance,
        OutTopic::MeasuredCpWithCovariance,
        OutTopic::MeasuredJs,
        OutTopic::JawMeasuredJs,
        OutTopic::Status,
    ];

    /// The uncompensated topics, under the console's names.
    pub const RAW: [OutTopic; 4] = [
        OutTopic::RawLocalMeasuredCp,
        OutTopic::RawMeasuredCp,
        OutTopic::RawMeasuredJs,
        OutTopic::RawJawMeasuredJs,
    ];

    /// Every topic the recorder can write: [`OutTopic::RAW`] then [`OutTopic::ALL`].
    pub const RECORDED: [OutTopic; 11] = [
        OutTopic::RawLocalMeasuredCp,
        OutTopic::RawMeasuredCp,
        OutTopic::RawMeasuredJs,
        OutTopic::RawJawMeasuredJs,
        OutTopic::LocalMeasuredCp,
        OutTopic::MeasuredCp,
        OutTopic::LocalMeasuredCpWithCovariance,
        OutTopic::MeasuredCpWithCovariance,
        OutTopic::MeasuredJs,
        OutTopic::JawMeasuredJs,
        OutTopic::Status,
    ];

    /// The part after `<arm>/`.
    pub const fn suffix(self) -> &'static str {
        match self {
            OutTopic::LocalMeasuredCp => "compensated/local/measured_cp",
            OutTopic::MeasuredCp => "compensated/measured_cp",
            OutTopic::LocalMeasuredCpWithCovariance => {
                "compensated/local/measured_cp_with_covariance"
            }
            OutTopic::MeasuredCpWithCovariance => "compensated/measured_cp_with_covariance",
            OutTopic::MeasuredJs => "compensated/measured_js",
            OutTopic::JawMeasuredJs => "compensated/jaw/measured_js",
            OutTopic::Status => "compensated/status",
            OutTopic::RawLocalMeasuredCp => "local/measured_cp",
            OutTopic::RawMeasuredCp => "measured_cp",
            OutTopic::RawMeasuredJs => "measured_js",
            OutTopic::RawJawMeasuredJs => "jaw/measured_js",
        }
    }

    /// Whether this is one of the uncompensated topics.
    pub const fn is_raw(self) -> bool {
        matches!(
            self,
            OutTopic::RawLocalMeasuredCp
                | OutTopic::RawMeasuredCp
                | OutTopic::RawMeasuredJs
                | OutTopic::RawJawMeasuredJs
        )
    }

    /// The message type.
    pub const fn msg_type(self) -> MsgType {
        match self {
            OutTopic::LocalMeasuredCp
            | OutTopic::MeasuredCp
            | OutTopic::RawLocalMeasuredCp
            | OutTopic::RawMeasuredCp => POSE_STAMPED,
            OutTopic::LocalMeasuredCpWithCovariance | OutTopic::MeasuredCpWithCovariance => {
                POSE_WITH_COVARIANCE_STAMPED
            }
            OutTopic::MeasuredJs
            | OutTopic::JawMeasuredJs
            | OutTopic::RawMeasuredJs
            | OutTopic::RawJawMeasuredJs => JOINT_STATE,
            OutTopic::Status => COMPENSATION_STATUS,
        }
    }

    /// The topic that carries this compensated pose with its covariance: `Some` for
    /// [`OutTopic::LocalMeasuredCp`] and [`OutTopic::MeasuredCp`] only (the bound is on the
    /// compensated pose; the raw pose has none).
    pub const fn with_covariance(self) -> Option<OutTopic> {
        match self {
            OutTopic::LocalMeasuredCp => Some(OutTopic::LocalMeasuredCpWithCovariance),
            OutTopic::MeasuredCp => Some(OutTopic::MeasuredCpWithCovariance),
            _ => None,
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

/// ROS time of a message header: its `sample_realtime_ns`, the CLOCK_REALTIME time of the
/// sample, which the sidecar reads together with the CLOCK_MONOTONIC one.
pub fn ros_time(h: &dvrk_ipc::Header) -> RosTime {
    RosTime::from_unix_ns(i64::try_from(h.sample_realtime_ns).unwrap_or(i64::MAX))
}

/// Names and frames of one arm's output.
#[derive(Debug, Clone)]
pub struct ArmFrames {
    /// Arm name, the ROS namespace (`PSM1`).
    pub arm: String,
    /// Reference frame of `local/measured_cp` (`PSM1_base`, the RCM frame as the dVRK names it).
    pub local_frame_id: String,
    /// Reference frame of `measured_cp`: the reference frame of the arm's base frame (the
    /// console's `reference-frame`, e.g. `ECM`); `PSM1_base` when no base frame is configured.
    pub base_frame_id: String,
    /// Frame id of the joint states (`PSM1`).
    pub joint_frame_id: String,
}

impl ArmFrames {
    /// The dVRK's frame names for `arm`; `measured_cp` in `base_frame_id` (default
    /// `<arm>_base`, right when the sidecar's base frame is the identity).
    pub fn new(arm: &str, base_frame_id: Option<&str>) -> Self {
        ArmFrames {
            arm: arm.to_owned(),
            local_frame_id: format!("{arm}_base"),
            base_frame_id: base_frame_id.map_or_else(|| format!("{arm}_base"), str::to_owned),
            joint_frame_id: arm.to_owned(),
        }
    }

    /// The frame of a pose topic: the base frame's reference for `measured_cp` (and its
    /// covariance variant), the RCM frame for the `local/` ones.
    pub fn pose_frame_id(&self, topic: OutTopic) -> &str {
        match topic {
            OutTopic::MeasuredCp | OutTopic::RawMeasuredCp | OutTopic::MeasuredCpWithCovariance => {
                &self.base_frame_id
            }
            _ => &self.local_frame_id,
        }
    }
}

/// `chi2_3(0.95)`, the 95% quantile of the chi-squared distribution with 3 degrees of freedom:
/// an isotropic 3-D normal error with standard deviation `sigma` per axis has a norm below
/// `sigma * sqrt(CHI2_3_95)` (2.7955 sigma) in 95% of the samples.
pub const CHI2_3_95: f64 = 7.814_727_903_251_178;

/// The covariance of the error of a compensated pose, from the 95% bounds of its cycle's status
/// (`compensated/status`: `tip_bound_m`, `bound_rad`), as a `geometry_msgs/PoseWithCovariance`
/// carries it: the diagonal of a row-major 6x6 (x, y, z in m², rotation about X, Y, Z in rad²),
/// off-diagonals 0.
///
/// The model (an approximation, documented as such):
/// - position: `tip_bound_m` bounds the norm of the tip's position error in 95% of the cycles.
///   It is taken as an isotropic 3-D normal whose 95% norm is that bound: variance
///   `(tip_bound_m / sqrt(chi2_3(0.95)))²` on x, y, z. So `2.7955 * sqrt(variance)` gives the
///   bound back, and the 95% ellipsoid of the covariance is the ball of radius `tip_bound_m`.
///   The error the bound describes lies in the plane across the shaft (joints 1 and 2 swing the
///   shaft about the RCM): the model spreads it over the shaft's axis too, and gives each axis
///   across the shaft 0.77 of the variance of the 2-D normal behind the bound, while the 95%
///   radius is the same. Projecting each joint's bound through the Jacobian would keep that
///   shape, but needs the directions of the joints' axes and of the shaft in the pose's frame,
///   from joints 1 and 2 through the PSM's kinematics (dvrk-compliance), which a consumer of
///   dvrk-ipc does not link; and the isotropic matrix needs no frame at all (below).
/// - rotation: joints 1 and 2 rotate the tool about two axes across the shaft; the norm of
///   `bound_rad` is taken the same way, variance `(|bound_rad| / sqrt(chi2_3(0.95)))²` about X,
///   Y, Z (so the rotation about the shaft, which joints 1 and 2 do not make, gets it too).
///
/// Both parts are isotropic, hence the same in every frame: the covariance of
/// `local/measured_cp` (RCM frame) and of `measured_cp` (base frame) is the same matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance {
    /// Variance of x, y and z (m²).
    pub position_var_m2: f64,
    /// Variance of the rotation about X, Y and Z (rad²).
    pub rotation_var_rad2: f64,
}

impl PoseCovariance {
    /// The covariance of the compensated pose of the cycle of `s`, or `None` when the status
    /// carries no usable bound (NaN before the first valid sample, or anything not finite or
    /// negative): no covariance message is published then, as no pose is for an invalid cycle.
    /// A finite bound is used as it is, also for a sample the estimator left uncorrected (its
    /// bound then covers the whole correction it withheld).
    pub fn from_status(s: &CompensationStatusV4) -> Option<Self> {
        let usable = |x: f64| x.is_finite() && x >= 0.0;
        let [b1, b2] = s.bound_rad;
        if !(usable(s.tip_bound_m) && usable(b1) && usable(b2)) {
            return None;
        }
        let sigma = |bound_95: f64| bound_95 / CHI2_3_95.sqrt();
        let variance = |bound_95: f64| sigma(bound_95) * sigma(bound_95);
        Some(PoseCovariance {
            position_var_m2: variance(s.tip_bound_m),
            rotation_var_rad2: variance(b1.hypot(b2)),
        })
    }

    /// The row-major 6x6 of `geometry_msgs/PoseWithCovariance`.
    pub fn row_major(&self) -> [f64; 36] {
        let mut c = [0.0; 36];
        for i in 0..3 {
            c[i * 7] = self.position_var_m2;
            c[(i + 3) * 7] = self.rotation_var_rad2;
        }
        c
    }
}

/// Turns shared-memory messages into CDR bodies. Holds one reusable buffer.
#[derive(Debug, Clone)]
pub struct Encoder {
    pub frames: ArmFrames,
    buf: CdrWriter,
}

impl Encoder {
    pub fn new(frames: ArmFrames) -> Self {
        Encoder {
            frames,
            buf: CdrWriter::new(),
        }
    }

    /// The body written by the most recent encoding call.
    pub fn last_body(&self) -> &[u8] {
        self.buf.body()
    }

    /// A `local/measured_cp` (RCM frame) or `measured_cp` (already in the base frame) pose,
    /// compensated or raw as `topic` says.
    pub fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> &CdrWriter {
        let stamp = ros_time(&p.header);
        let frame = self.frames.pose_frame_id(topic);
        self.buf.clear();
        cdr::pose_stamped(
            &mut self.buf,
            stamp,
            frame,
            &p.position_m,
            &p.orientation_xyzw,
        );
        &self.buf
    }

    /// A `compensated/local/measured_cp_with_covariance` (RCM frame) or
    /// `compensated/measured_cp_with_covariance` (base frame) pose: `p` as [`Encoder::pose`]
    /// writes it, with `cov`, the covariance of its error. Same stamp and frame as the pose.
    pub fn pose_with_covariance(
        &mut self,
        topic: OutTopic,
        p: &PoseV2,
        cov: &PoseCovariance,
    ) -> &CdrWriter {
        let stamp = ros_time(&p.header);
        let frame = self.frames.pose_frame_id(topic);
        self.buf.clear();
        cdr::pose_with_covariance_stamped(
            &mut self.buf,
            stamp,
            frame,
            &p.position_m,
            &p.orientation_xyzw,
            &cov.row_major(),
        );
        &self.buf
    }

    /// `measured_js`: the 6 joints.
    pub fn joints(&mut self, js: &JointStateV2) -> &CdrWriter {
        let stamp = ros_time(&js.header);
        self.buf.clear();
        cdr::joint_state(
            &mut self.buf,
            stamp,
            &self.frames.joint_frame_id,
            &JOINT_NAMES,
            &js.position,
            &js.velocity,
            &js.effort,
        );
        &self.buf
    }

    /// `jaw/measured_js`: one joint, `jaw`.
    pub fn jaw(&mut self, jaw: &JawStateV1) -> &CdrWriter {
        let stamp = ros_time(&jaw.header);
        self.buf.clear();
        cdr::joint_state(
            &mut self.buf,
            stamp,
            &self.frames.joint_frame_id,
            &[JAW_NAME],
            &[jaw.position],
            &[jaw.velocity],
            &[jaw.effort],
        );
        &self.buf
    }

    /// `compensated/status`, field for field ([`crate::msgdefs::COMPENSATION_STATUS`]).
    pub fn status(&mut self, s: &CompensationStatusV4) -> &CdrWriter {
        let stamp = ros_time(&s.header);
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
        w.u32(s.source_state);
        for &x in &s.bound_rad {
            w.f64(x);
        }
        w.f64(s.tip_bound_m);
        for &x in &s.weight {
            w.f64(x);
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

    #[test]
    fn topic_names_stay_under_compensated() {
        for t in OutTopic::ALL {
            assert!(t.ros_name("PSM1").starts_with("/PSM1/compensated/"));
            assert!(t.dds_name("PSM1").starts_with("rt/PSM1/compensated/"));
            assert!(!t.is_raw());
        }
        for t in OutTopic::RAW {
            assert!(t.is_raw() && !t.suffix().starts_with("compensated/"));
            assert_eq!(t.msg_type().ros_name, {
                let comp = OutTopic::ALL
                    .into_iter()
                    .find(|c| c.suffix() == format!("compensated/{}", t.suffix()))
                    .unwrap();
                comp.msg_type().ros_name
            });
        }
        assert_eq!(&OutTopic::RECORDED[4..], &OutTopic::ALL);
        assert_eq!(
            OutTopic::LocalMeasuredCp.dds_name("PSM1"),
            "rt/PSM1/compensated/local/measured_cp"
        );
    }

    #[test]
    fn stamps_are_the_headers_realtime() {
        let h = dvrk_ipc::Header {
            sample_t_ns: 5,
            sample_realtime_ns: 1_700_000_001_500_000_001,
            ..Default::default()
        };
        let t = ros_time(&h);
        assert_eq!((t.sec, t.nanosec), (1_700_000_001, 500_000_001));
    }

    #[test]
    fn poses_keep_their_frames() {
        let mut e = Encoder::new(ArmFrames::new("PSM1", Some("ECM")));
        let p = PoseV2::default();
        let local = e.pose(OutTopic::LocalMeasuredCp, &p).body().to_vec();
        let base = e.pose(OutTopic::MeasuredCp, &p).body().to_vec();
        let has = |b: &[u8], s: &str| b.windows(s.len()).any(|w| w == s.as_bytes());
        assert!(has(&local, "PSM1_base\0") && !has(&local, "ECM"));
        assert!(has(&base, "ECM\0") && !has(&base, "PSM1_base"));
        assert_eq!(ArmFrames::new("PSM2", None).base_frame_id, "PSM2_base");
    }

    fn status_with_bounds(tip_bound_m: f64, bound_rad: [f64; 2]) -> CompensationStatusV4 {
        CompensationStatusV4 {
            tip_bound_m,
            bound_rad,
            ..Default::default()
        }
    }

    #[test]
    fn covariance_is_the_95_percent_bound_as_an_isotropic_normal() {
        // 2 mm at 95%: sigma = 2 mm / sqrt(chi2_3(0.95)) = 0.715 mm per axis.
        let s = status_with_bounds(2e-3, [3e-3, 4e-3]);
        let c = PoseCovariance::from_status(&s).unwrap();
        let pos_sigma = 2e-3 / 7.814_727_903_251_178f64.sqrt();
        let rot_sigma = 5e-3 / 7.814_727_903_251_178f64.sqrt();
        assert!((c.position_var_m2 / (pos_sigma * pos_sigma) - 1.0).abs() < 1e-14);
        assert!((c.rotation_var_rad2 / (rot_sigma * rot_sigma) - 1.0).abs() < 1e-14);
        // sqrt(variance) times 2.7955 gives the 95% bound back.
        assert!((c.position_var_m2.sqrt() * 2.795_483 - 2e-3).abs() < 1e-9);
        // CHI2_3_95 is the 95% quantile of chi2_3: its density integrated up to it (Simpson,
        // over u = sqrt(x), where the density sqrt(x / 2pi) e^(-x/2) dx is smooth) is 0.95.
        let density =
            |u: f64| 2.0 * u * u / (2.0 * core::f64::consts::PI).sqrt() * (-u * u / 2.0).exp();
        let n = 2_000;
        let h = CHI2_3_95.sqrt() / n as f64;
        let cdf = (0..=n)
            .map(|i| {
                let w = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                w * density(i as f64 * h)
            })
            .sum::<f64>()
            * h
            / 3.0;
        assert!((cdf - 0.95).abs() < 1e-12, "P(chi2_3 <= CHI2_3_95) = {cdf}");

        let m = c.row_major();
        for r in 0..6 {
            for k in 0..6 {
                let want = match (r == k, r < 3) {
                    (false, _) => 0.0,
                    (true, true) => c.position_var_m2,
                    (true, false) => c.rotation_var_rad2,
                };
                assert_eq!(m[r * 6 + k], want, "row {r} column {k}");
            }
        }
    }

    #[test]
    fn no_covariance_without_a_finite_bound() {
        for (tip, rad) in [
            (f64::NAN, [f64::NAN; 2]),
            (f64::NAN, [1e-3, 1e-3]),
            (1e-3, [f64::NAN, 1e-3]),
            (f64::INFINITY, [1e-3, 1e-3]),
            (1e-3, [1e-3, f64::NEG_INFINITY]),
            (-1e-3, [1e-3, 1e-3]),
        ] {
            assert_eq!(
                PoseCovariance::from_status(&status_with_bounds(tip, rad)),
                None,
                "{tip} {rad:?}"
            );
        }
        // A bound of 0 (no parameters for the joints: nothing corrected, nothing bounded) is
        // what the status says, and is published as it is.
        let zero = PoseCovariance::from_status(&status_with_bounds(0.0, [0.0; 2])).unwrap();
        assert_eq!(zero.row_major(), [0.0; 36]);
    }

    #[test]
    fn poses_with_covariance_are_the_pose_and_the_matrix() {
        let mut e = Encoder::new(ArmFrames::new("PSM1", Some("ECM")));
        let p = PoseV2 {
            position_m: [0.1, -0.2, 0.3],
            ..Default::default()
        };
        let cov = PoseCovariance::from_status(&status_with_bounds(1e-3, [2e-3, 0.0])).unwrap();
        for (pose_topic, frame) in [
            (OutTopic::MeasuredCp, "ECM"),
            (OutTopic::LocalMeasuredCp, "PSM1_base"),
        ] {
            let topic = pose_topic.with_covariance().unwrap();
            assert_eq!(
                topic.suffix(),
                format!("{}_with_covariance", pose_topic.suffix())
            );
            assert_eq!(
                topic.msg_type().ros_name,
                "geometry_msgs/msg/PoseWithCovarianceStamped"
            );
            let pose = e.pose(pose_topic, &p).body().to_vec();
            let with = e.pose_with_covariance(topic, &p, &cov).body().to_vec();
            // The pose's own bytes (header with its frame, pose), then the 36 doubles.
            assert_eq!(&with[..pose.len()], &pose[..], "{topic:?}");
            assert!(pose.windows(frame.len()).any(|w| w == frame.as_bytes()));
            let m: Vec<f64> = with[pose.len()..]
                .chunks(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                .collect();
            assert_eq!(m, cov.row_major());
        }
        for t in OutTopic::ALL.into_iter().chain(OutTopic::RAW) {
            let has = matches!(t, OutTopic::LocalMeasuredCp | OutTopic::MeasuredCp);
            assert_eq!(t.with_covariance().is_some(), has, "{t:?}");
        }
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
    fn joints_and_jaw_have_their_names() {
        let mut js = JointStateV2::default();
        for i in 0..6 {
            js.position[i] = i as f64;
        }
        let jaw = JawStateV1 {
            position: 6.0,
            ..Default::default()
        };
        let mut e = Encoder::new(ArmFrames::new("PSM1", None));
        let arm = e.joints(&js).body().to_vec();
        let jaw = e.jaw(&jaw).body().to_vec();
        let has = |b: &[u8], name: &str| b.windows(name.len()).any(|w| w == name.as_bytes());
        assert!(has(&arm, "wrist_yaw") && !has(&arm, "jaw"));
        assert!(has(&jaw, "jaw") && !has(&jaw, "yaw\0"));
        assert!(jaw.windows(8).any(|w| w == 6.0f64.to_le_bytes()));
    }
}
