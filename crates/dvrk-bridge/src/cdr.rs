//! ROS 2 messages in OMG CDR (XCDR1, little endian), written by hand for the few types the bridge
//! publishes.
//!
//! This is what rmw_cyclonedds and rmw_fastrtps put on the wire and what MCAP's `cdr` message
//! encoding holds: a 4-byte encapsulation header (`00 01 00 00`, CDR little endian) followed by
//! the body, in which every primitive is aligned to its own size counted from the start of the
//! body. Strings are a `u32` length that counts the terminating NUL, the bytes, and the NUL;
//! sequences are a `u32` element count followed by the elements.
//!
//! DDS writers add the encapsulation header themselves, so [`CdrWriter::body`] is what goes to
//! RustDDS and [`CdrWriter::with_encapsulation`] what goes into an MCAP file.

/// The encapsulation header of CDR little endian (`CDR_LE`, representation id 0x0001).
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// `builtin_interfaces/msg/Time`: ROS time (CLOCK_REALTIME) as whole seconds and nanoseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RosTime {
    pub sec: i32,
    pub nanosec: u32,
}

impl RosTime {
    /// The ROS time of `ns` nanoseconds since the Unix epoch. Times outside what an `int32` of
    /// seconds can hold (before 1901 or after 2038) saturate at the nearest end.
    pub fn from_unix_ns(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        let nanosec = ns.rem_euclid(1_000_000_000) as u32;
        match i32::try_from(sec) {
            Ok(sec) => RosTime { sec, nanosec },
            Err(_) if sec < 0 => RosTime {
                sec: i32::MIN,
                nanosec: 0,
            },
            Err(_) => RosTime {
                sec: i32::MAX,
                nanosec: 999_999_999,
            },
        }
    }

    /// Nanoseconds since the Unix epoch.
    pub fn as_unix_ns(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
}

/// A reusable CDR body buffer. `clear` keeps the allocation, so a writer that lives for the
/// whole run allocates only while its first messages grow it.
#[derive(Debug, Default, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl CdrWriter {
    pub fn new() -> Self {
        Self::default()
    }

    /// Empties the buffer (keeps its capacity).
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// The body written so far (no encapsulation header): what a DDS writer sends.
    pub fn body(&self) -> &[u8] {
        &self.buf
    }

    /// The encapsulation header and the body, as an MCAP `cdr` message holds them.
    pub fn with_encapsulation(&self, out: &mut Vec<u8>) {
        out.clear();
        out.extend_from_slice(&ENCAPSULATION_CDR_LE);
        out.extend_from_slice(&self.buf);
    }

    fn align(&mut self, n: usize) {
        let pad = (n - self.buf.len() % n) % n;
        self.buf.extend(core::iter::repeat_n(0u8, pad));
    }

    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A string: length including the NUL, the bytes, the NUL. The caller's strings are ours
    /// (frame ids, joint names) and far below `u32::MAX`; longer input is cut to fit.
    pub fn string(&mut self, s: &str) {
        let bytes = &s.as_bytes()[..s.len().min(u32::MAX as usize - 1)];
        self.u32(bytes.len() as u32 + 1);
        self.buf.extend_from_slice(bytes);
        self.buf.push(0);
    }

    /// A `float64[]` sequence.
    pub fn f64_seq(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.f64(x);
        }
    }

    /// A `string[]` sequence.
    pub fn string_seq(&mut self, v: &[&str]) {
        self.u32(v.len() as u32);
        for s in v {
            self.string(s);
        }
    }

    /// `builtin_interfaces/Time`.
    pub fn time(&mut self, t: RosTime) {
        self.i32(t.sec);
        self.u32(t.nanosec);
    }

    /// `std_msgs/Header`.
    pub fn header(&mut self, stamp: RosTime, frame_id: &str) {
        self.time(stamp);
        self.string(frame_id);
    }
}

/// `geometry_msgs/PoseStamped`: header, position (m), orientation quaternion (x, y, z, w).
pub fn pose_stamped(
    w: &mut CdrWriter,
    stamp: RosTime,
    frame_id: &str,
    position: &[f64; 3],
    orientation_xyzw: &[f64; 4],
) {
    w.header(stamp, frame_id);
    for &x in position {
        w.f64(x);
    }
    for &x in orientation_xyzw {
        w.f64(x);
    }
}

/// `geometry_msgs/PoseWithCovarianceStamped`: header, pose as in [`pose_stamped`], then the
/// `float64[36]` covariance (row-major 6x6: x, y, z, then rotation about X, Y, Z). A fixed-size
/// array has no length in CDR: the 36 doubles follow the pose, already aligned to 8.
pub fn pose_with_covariance_stamped(
    w: &mut CdrWriter,
    stamp: RosTime,
    frame_id: &str,
    position: &[f64; 3],
    orientation_xyzw: &[f64; 4],
    covariance: &[f64; 36],
) {
    pose_stamped(w, stamp, frame_id, position, orientation_xyzw);
    for &x in covariance {
        w.f64(x);
    }
}

/// `sensor_msgs/JointState`: header, names, and position, velocity, effort of the same length.
pub fn joint_state(
    w: &mut CdrWriter,
    stamp: RosTime,
    frame_id: &str,
    names: &[&str],
    position: &[f64],
    velocity: &[f64],
    effort: &[f64],
) {
    w.header(stamp, frame_id);
    w.string_seq(names);
    w.f64_seq(position);
    w.f64_seq(velocity);
    w.f64_seq(effort);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_time_splits_and_round_trips() {
        let t = RosTime::from_unix_ns(1_700_000_000_123_456_789);
        assert_eq!(t.sec, 1_700_000_000);
        assert_eq!(t.nanosec, 123_456_789);
        assert_eq!(t.as_unix_ns(), 1_700_000_000_123_456_789);
        let neg = RosTime::from_unix_ns(-1);
        assert_eq!((neg.sec, neg.nanosec), (-1, 999_999_999));
        assert_eq!(RosTime::from_unix_ns(i64::MAX).sec, i32::MAX);
        assert_eq!(RosTime::from_unix_ns(i64::MIN).sec, i32::MIN);
    }

    #[test]
    fn string_counts_the_nul_and_doubles_align_to_eight() {
        let mut w = CdrWriter::new();
        w.string("ab");
        w.f64(1.0);
        // 4 length + "ab\0" = 7 bytes, 1 byte of padding, 8 bytes of double.
        assert_eq!(
            w.body(),
            &[3, 0, 0, 0, b'a', b'b', 0, 0, 0, 0, 0, 0, 0, 0, 0xf0, 0x3f]
        );
    }

    #[test]
    fn pose_stamped_has_the_layout_of_the_idl() {
        let mut w = CdrWriter::new();
        let stamp = RosTime { sec: 7, nanosec: 9 };
        pose_stamped(
            &mut w,
            stamp,
            "PSM1_base",
            &[1.0, 2.0, 3.0],
            &[0.0, 0.0, 0.0, 1.0],
        );
        let b = w.body();
        // sec, nanosec, string length 10 + "PSM1_base\0" = 22 bytes, padded to 24, 7 doubles.
        assert_eq!(b.len(), 24 + 7 * 8);
        assert_eq!(&b[0..4], &7i32.to_le_bytes());
        assert_eq!(&b[4..8], &9u32.to_le_bytes());
        assert_eq!(&b[8..12], &10u32.to_le_bytes());
        assert_eq!(&b[12..22], b"PSM1_base\0");
        assert_eq!(&b[22..24], &[0, 0]);
        assert_eq!(&b[24..32], &1.0f64.to_le_bytes());
        assert_eq!(&b[72..80], &1.0f64.to_le_bytes());
    }

    #[test]
    fn pose_with_covariance_stamped_has_the_layout_of_the_idl() {
        let mut w = CdrWriter::new();
        let mut cov = [0.0; 36];
        for (i, c) in cov.iter_mut().enumerate() {
            *c = i as f64 + 0.5;
        }
        // A frame id that leaves the body unaligned: the pose's first double starts on 8.
        pose_with_covariance_stamped(
            &mut w,
            RosTime { sec: 7, nanosec: 9 },
            "PSM1",
            &[1.0, 2.0, 3.0],
            &[0.0, 0.0, 0.0, 1.0],
            &cov,
        );
        let b = w.body();
        // sec, nanosec, length 5 + "PSM1\0" = 17 bytes, padded to 24; 7 doubles of pose, then
        // 36 of covariance with no length in front.
        assert_eq!(b.len(), 24 + 7 * 8 + 36 * 8);
        assert_eq!(&b[8..12], &5u32.to_le_bytes());
        assert_eq!(&b[12..17], b"PSM1\0");
        assert_eq!(&b[17..24], &[0; 7]);
        assert_eq!(&b[24..32], &1.0f64.to_le_bytes());
        assert_eq!(&b[48..56], &0.0f64.to_le_bytes());
        assert_eq!(&b[72..80], &1.0f64.to_le_bytes());
        for i in 0..36 {
            let at = 80 + 8 * i;
            assert_eq!(
                &b[at..at + 8],
                &(i as f64 + 0.5).to_le_bytes(),
                "element {i}"
            );
        }
        // The same as a PoseStamped followed by the array.
        let mut p = CdrWriter::new();
        pose_stamped(
            &mut p,
            RosTime { sec: 7, nanosec: 9 },
            "PSM1",
            &[1.0, 2.0, 3.0],
            &[0.0, 0.0, 0.0, 1.0],
        );
        assert_eq!(&b[..p.body().len()], p.body());
    }

    #[test]
    fn joint_state_sequences_carry_their_counts() {
        let mut w = CdrWriter::new();
        joint_state(
            &mut w,
            RosTime::default(),
            "",
            &["jaw"],
            &[0.5],
            &[0.25],
            &[-1.0],
        );
        let b = w.body();
        // time 8, frame "" = 4 + 1 -> 13, pad to 16: count 1, "jaw\0" (4 + 4) -> 28,
        // count 1 -> 32, double -> 40, count -> 44, pad 48, double -> 56, count 60, pad 64, 72.
        assert_eq!(b.len(), 72);
        assert_eq!(&b[8..12], &1u32.to_le_bytes());
        assert_eq!(&b[16..20], &1u32.to_le_bytes());
        assert_eq!(&b[20..24], &4u32.to_le_bytes());
        assert_eq!(&b[24..28], b"jaw\0");
        assert_eq!(&b[28..32], &1u32.to_le_bytes());
        assert_eq!(&b[32..40], &0.5f64.to_le_bytes());
        assert_eq!(&b[64..72], &(-1.0f64).to_le_bytes());
    }

    #[test]
    fn encapsulation_prefixes_the_body() {
        let mut w = CdrWriter::new();
        w.u32(5);
        let mut out = vec![0xff; 3];
        w.with_encapsulation(&mut out);
        assert_eq!(out, [0, 1, 0, 0, 5, 0, 0, 0]);
    }
}
