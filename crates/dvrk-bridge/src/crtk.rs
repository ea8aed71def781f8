//! The CRTK messages of the dVRK 2.x console, as a DDS client sees them: their DDS type names,
//! their CDR encoding (with [`crate::cdr::CdrWriter`]) and a checked CDR decoder that cannot
//! panic on any input (every length is bounded by the bytes that remain).
//!
//! Types (reference/dvrk-crtk-ros2.md): `sensor_msgs/JointState` (`measured_js`, `move_jp`,
//! `servo_jp`), `crtk_msgs/OperatingState` (`operating_state`), `crtk_msgs/StringStamped`
//! (`state_command`), `std_msgs/Bool` (`goal_reached`), `std_msgs/String` (`tool_type`,
//! `warning`, `error`, `status`), `std_msgs/Float64` (`trajectory_j/set_ratio`) and
//! `std_msgs/Empty` (`hold`, `free`).

use crate::cdr::{CdrWriter, RosTime};

/// DDS type names as the ROS 2 rmw layers register them.
pub mod dds_type {
    pub const POSE_STAMPED: &str = "geometry_msgs::msg::dds_::PoseStamped_";
    pub const JOINT_STATE: &str = "sensor_msgs::msg::dds_::JointState_";
    pub const OPERATING_STATE: &str = "crtk_msgs::msg::dds_::OperatingState_";
    pub const STRING_STAMPED: &str = "crtk_msgs::msg::dds_::StringStamped_";
    pub const BOOL: &str = "std_msgs::msg::dds_::Bool_";
    pub const STRING: &str = "std_msgs::msg::dds_::String_";
    pub const FLOAT64: &str = "std_msgs::msg::dds_::Float64_";
    pub const EMPTY: &str = "std_msgs::msg::dds_::Empty_";
}

/// Why a CDR body could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    #[error("{what}: the body ends at byte {len}, {need} more bytes needed at byte {at}")]
    Truncated {
        what: &'static str,
        at: usize,
        need: usize,
        len: usize,
    },
    #[error("{what}: a string without its terminating NUL at byte {at}")]
    Unterminated { what: &'static str, at: usize },
    #[error("{what}: a string that is not UTF-8 at byte {at}")]
    NotUtf8 { what: &'static str, at: usize },
    #[error("{what}: {count} elements announced, more than the {left} bytes left can hold")]
    Count {
        what: &'static str,
        count: u32,
        left: usize,
    },
}

/// A checked reader of a CDR body (XCDR1), little or big endian. Alignment is counted from the
/// start of the body, as the writer counts it.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    buf: &'a [u8],
    pos: usize,
    big_endian: bool,
}

impl<'a> CdrReader<'a> {
    pub fn new(body: &'a [u8], big_endian: bool) -> Self {
        Self {
            buf: body,
            pos: 0,
            big_endian,
        }
    }

    fn take(
        &mut self,
        what: &'static str,
        align: usize,
        n: usize,
    ) -> Result<&'a [u8], DecodeError> {
        let pad = (align - self.pos % align) % align;
        let start = self.pos.saturating_add(pad);
        let end = start.saturating_add(n);
        match self.buf.get(start..end) {
            Some(s) => {
                self.pos = end;
                Ok(s)
            }
            None => Err(DecodeError::Truncated {
                what,
                at: start,
                need: end.saturating_sub(self.buf.len()),
                len: self.buf.len(),
            }),
        }
    }

    fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], DecodeError> {
        let s = self.take(what, N, N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        if self.big_endian {
            a.reverse();
        }
        Ok(a)
    }

    pub fn u32(&mut self, what: &'static str) -> Result<u32, DecodeError> {
        self.array::<4>(what).map(u32::from_le_bytes)
    }

    pub fn i32(&mut self, what: &'static str) -> Result<i32, DecodeError> {
        self.array::<4>(what).map(i32::from_le_bytes)
    }

    pub fn f64(&mut self, what: &'static str) -> Result<f64, DecodeError> {
        self.array::<8>(what).map(f64::from_le_bytes)
    }

    pub fn bool(&mut self, what: &'static str) -> Result<bool, DecodeError> {
        Ok(self.take(what, 1, 1)?[0] != 0)
    }

    pub fn u8(&mut self, what: &'static str) -> Result<u8, DecodeError> {
        Ok(self.take(what, 1, 1)?[0])
    }

    /// A sequence count, refused when the bytes left cannot hold `count` elements of
    /// `min_size` bytes each (so a forged count never makes us allocate).
    fn count(&mut self, what: &'static str, min_size: usize) -> Result<usize, DecodeError> {
        let count = self.u32(what)?;
        let left = self.buf.len().saturating_sub(self.pos);
        let n = count as usize;
        if n.saturating_mul(min_size) > left {
            return Err(DecodeError::Count { what, count, left });
        }
        Ok(n)
    }

    pub fn string(&mut self, what: &'static str) -> Result<String, DecodeError> {
        let n = self.count(what, 1)?;
        let at = self.pos;
        let bytes = self.take(what, 1, n)?;
        let Some((&0, text)) = bytes.split_last() else {
            return Err(DecodeError::Unterminated { what, at });
        };
        // Some writers put a NUL before the end; ROS strings stop at the first one.
        let text = text.split(|&b| b == 0).next().unwrap_or_default();
        std::str::from_utf8(text)
            .map(str::to_owned)
            .map_err(|_| DecodeError::NotUtf8 { what, at })
    }

    pub fn f64_seq(&mut self, what: &'static str) -> Result<Vec<f64>, DecodeError> {
        let n = self.count(what, 8)?;
        (0..n).map(|_| self.f64(what)).collect()
    }

    pub fn string_seq(&mut self, what: &'static str) -> Result<Vec<String>, DecodeError> {
        let n = self.count(what, 5)?;
        (0..n).map(|_| self.string(what)).collect()
    }

    pub fn time(&mut self) -> Result<RosTime, DecodeError> {
        Ok(RosTime {
            sec: self.i32("header.stamp.sec")?,
            nanosec: self.u32("header.stamp.nanosec")?,
        })
    }

    /// `std_msgs/Header`: the stamp and the frame id.
    pub fn header(&mut self) -> Result<(RosTime, String), DecodeError> {
        Ok((self.time()?, self.string("header.frame_id")?))
    }
}

/// `sensor_msgs/JointState`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JointStateMsg {
    /// A zero stamp means "no valid data" (the console publishes invalid data that way).
    pub stamp: RosTime,
    pub frame_id: String,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

impl JointStateMsg {
    pub fn decode(body: &[u8], big_endian: bool) -> Result<Self, DecodeError> {
        let mut r = CdrReader::new(body, big_endian);
        let (stamp, frame_id) = r.header()?;
        Ok(Self {
            stamp,
            frame_id,
            name: r.string_seq("name")?,
            position: r.f64_seq("position")?,
            velocity: r.f64_seq("velocity")?,
            effort: r.f64_seq("effort")?,
        })
    }

    pub fn encode(&self, w: &mut CdrWriter) {
        let names: Vec<&str> = self.name.iter().map(String::as_str).collect();
        crate::cdr::joint_state(
            w,
            self.stamp,
            &self.frame_id,
            &names,
            &self.position,
            &self.velocity,
            &self.effort,
        );
    }

    /// The stamp is not zero.
    pub fn is_valid(&self) -> bool {
        self.stamp != RosTime::default()
    }
}

/// `geometry_msgs/PoseStamped`: position (m) and orientation quaternion (x, y, z, w).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseStampedMsg {
    pub stamp: RosTime,
    pub frame_id: String,
    pub position: [f64; 3],
    pub orientation_xyzw: [f64; 4],
}

impl PoseStampedMsg {
    pub fn decode(body: &[u8], big_endian: bool) -> Result<Self, DecodeError> {
        let mut r = CdrReader::new(body, big_endian);
        let (stamp, frame_id) = r.header()?;
        let mut position = [0.0; 3];
        for v in &mut position {
            *v = r.f64("pose.position")?;
        }
        let mut orientation_xyzw = [0.0; 4];
        for v in &mut orientation_xyzw {
            *v = r.f64("pose.orientation")?;
        }
        Ok(Self {
            stamp,
            frame_id,
            position,
            orientation_xyzw,
        })
    }

    pub fn encode(&self, w: &mut CdrWriter) {
        crate::cdr::pose_stamped(
            w,
            self.stamp,
            &self.frame_id,
            &self.position,
            &self.orientation_xyzw,
        );
    }
}

/// `crtk_msgs/OperatingState`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct OperatingStateMsg {
    pub stamp: RosTime,
    pub state: String,
    pub is_homed: bool,
    pub is_busy: bool,
}

impl OperatingStateMsg {
    pub fn decode(body: &[u8], big_endian: bool) -> Result<Self, DecodeError> {
        let mut r = CdrReader::new(body, big_endian);
        let (stamp, _) = r.header()?;
        Ok(Self {
            stamp,
            state: r.string("state")?,
            is_homed: r.bool("is_homed")?,
            is_busy: r.bool("is_busy")?,
        })
    }

    pub fn encode(&self, w: &mut CdrWriter) {
        w.header(self.stamp, "");
        w.string(&self.state);
        w.bool(self.is_homed);
        w.bool(self.is_busy);
    }
}

/// `crtk_msgs/StringStamped` (`state_command`).
pub fn decode_string_stamped(body: &[u8], big_endian: bool) -> Result<String, DecodeError> {
    let mut r = CdrReader::new(body, big_endian);
    r.header()?;
    r.string("string")
}

pub fn encode_string_stamped(w: &mut CdrWriter, stamp: RosTime, s: &str) {
    w.header(stamp, "");
    w.string(s);
}

/// `std_msgs/String`.
pub fn decode_string(body: &[u8], big_endian: bool) -> Result<String, DecodeError> {
    CdrReader::new(body, big_endian).string("data")
}

/// `std_msgs/Bool`.
pub fn decode_bool(body: &[u8], big_endian: bool) -> Result<bool, DecodeError> {
    CdrReader::new(body, big_endian).bool("data")
}

/// `std_msgs/Float64`.
pub fn decode_f64(body: &[u8], big_endian: bool) -> Result<f64, DecodeError> {
    CdrReader::new(body, big_endian).f64("data")
}

/// `std_msgs/Empty`: one placeholder byte (rosidl's `structure_needs_at_least_one_field`).
pub fn encode_empty(w: &mut CdrWriter) {
    w.u8(0);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn js() -> JointStateMsg {
        JointStateMsg {
            stamp: RosTime {
                sec: 12,
                nanosec: 5,
            },
            frame_id: String::new(),
            name: vec!["yaw".into(), "pitch".into(), "insertion".into()],
            position: vec![0.1, -0.2, 0.12],
            velocity: vec![0.0; 3],
            effort: vec![0.5, -0.25, 1.0],
        }
    }

    #[test]
    fn joint_state_round_trips() {
        let mut w = CdrWriter::new();
        js().encode(&mut w);
        assert_eq!(JointStateMsg::decode(w.body(), false).unwrap(), js());
    }

    #[test]
    fn pose_stamped_round_trips() {
        let p = PoseStampedMsg {
            stamp: RosTime { sec: 3, nanosec: 4 },
            frame_id: "ECM".into(),
            position: [0.1, 0.2, 0.3],
            orientation_xyzw: [0.0, 0.0, 0.6, 0.8],
        };
        let mut w = CdrWriter::new();
        p.encode(&mut w);
        assert_eq!(PoseStampedMsg::decode(w.body(), false).unwrap(), p);
    }

    #[test]
    fn operating_state_round_trips() {
        let s = OperatingStateMsg {
            stamp: RosTime { sec: 1, nanosec: 2 },
            state: "ENABLED".into(),
            is_homed: true,
            is_busy: false,
        };
        let mut w = CdrWriter::new();
        s.encode(&mut w);
        assert_eq!(OperatingStateMsg::decode(w.body(), false).unwrap(), s);
    }

    #[test]
    fn big_endian_bodies_decode() {
        // std_msgs/Float64 1.5, big endian.
        let b = 1.5f64.to_be_bytes();
        assert_eq!(decode_f64(&b, true).unwrap(), 1.5);
        // std_msgs/String "ab": length 3 (BE), bytes, NUL.
        let s = [0, 0, 0, 3, b'a', b'b', 0];
        assert_eq!(decode_string(&s, true).unwrap(), "ab");
    }

    #[test]
    fn every_truncation_is_an_error_not_a_panic() {
        let mut w = CdrWriter::new();
        js().encode(&mut w);
        let full = w.body().to_vec();
        for n in 0..full.len() {
            assert!(JointStateMsg::decode(&full[..n], false).is_err(), "{n}");
        }
    }

    #[test]
    fn forged_counts_are_refused_before_allocating() {
        let mut w = CdrWriter::new();
        w.header(RosTime::default(), "");
        w.u32(u32::MAX); // names
        let e = JointStateMsg::decode(w.body(), false).unwrap_err();
        assert!(matches!(e, DecodeError::Count { what: "name", .. }), "{e}");
    }

    #[test]
    fn garbage_never_panics() {
        // A deterministic byte soup of many lengths.
        let mut x = 0x2545_f491_u32;
        for len in 0..400 {
            let bytes: Vec<u8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as u8
                })
                .collect();
            let _ = JointStateMsg::decode(&bytes, false);
            let _ = OperatingStateMsg::decode(&bytes, true);
            let _ = decode_string_stamped(&bytes, false);
        }
    }

    #[test]
    fn a_string_without_nul_is_refused() {
        let b = [2, 0, 0, 0, b'a', b'b'];
        assert!(matches!(
            decode_string(&b, false),
            Err(DecodeError::Unterminated { .. })
        ));
    }
}
