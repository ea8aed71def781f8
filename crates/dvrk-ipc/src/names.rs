//! Service names: `<prefix>/<topic>` for the nine pub-sub services and `<prefix>/cycle` for the
//! event service notified once per cycle. The topics carry the names the dVRK 2.x console uses
//! under its arm's namespace (`/PSM1/measured_js`, `/PSM1/local/measured_cp`, ...); the prefix is
//! the arm's name.

use core::fmt;

use iceoryx2::prelude::ServiceName;

use crate::IpcError;
use crate::msg::{CompensationStatusV4, JawStateV1, JointStateV2, Message, PoseV2};

/// Default service prefix: the arm's name, as the dVRK console names its ROS namespace.
pub const DEFAULT_PREFIX: &str = "PSM1";

/// Suffix of the event service, notified once per cycle after all nine messages are sent.
pub const CYCLE_SUFFIX: &str = "cycle";
/// Suffix of the event service notified once per cycle as soon as its first message,
/// `compensated/local/measured_cp`, is sent (before the other eight are written).
pub const CYCLE_FIRST_SUFFIX: &str = "cycle/first";

/// Longest accepted prefix in bytes. iceoryx2 service names are limited to 255 bytes; the longest
/// suffix is `/compensated/local/measured_cp` (30 bytes).
pub const MAX_PREFIX_LEN: usize = 200;

/// Number of pub-sub topics of an arm.
pub const NUM_TOPICS: usize = 9;

/// One of the nine pub-sub services of an arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Topic {
    /// `measured_js`, [`JointStateV2`]: the six joints as read.
    MeasuredJs,
    /// `jaw/measured_js`, [`JawStateV1`]: the jaw as read.
    JawMeasuredJs,
    /// `local/measured_cp`, [`PoseV2`]: tip pose in the RCM frame, from the raw joints.
    LocalMeasuredCp,
    /// `measured_cp`, [`PoseV2`]: tip pose in the base frame, from the raw joints.
    MeasuredCp,
    /// `compensated/measured_js`, [`JointStateV2`]: joints 1, 2 corrected.
    CompensatedMeasuredJs,
    /// `compensated/jaw/measured_js`, [`JawStateV1`]: the jaw (not corrected; same values).
    CompensatedJawMeasuredJs,
    /// `compensated/local/measured_cp`, [`PoseV2`]: tip pose in the RCM frame, from the
    /// corrected joints.
    CompensatedLocalMeasuredCp,
    /// `compensated/measured_cp`, [`PoseV2`]: tip pose in the base frame, from the corrected
    /// joints.
    CompensatedMeasuredCp,
    /// `compensated/status`, [`CompensationStatusV4`].
    CompensatedStatus,
}

impl Topic {
    /// All topics, raw first (the order of the service names, subscriber counts and the C
    /// header). The order in which a cycle sends them is [`crate::PUBLISH_ORDER`].
    pub const ALL: [Topic; NUM_TOPICS] = [
        Topic::MeasuredJs,
        Topic::JawMeasuredJs,
        Topic::LocalMeasuredCp,
        Topic::MeasuredCp,
        Topic::CompensatedMeasuredJs,
        Topic::CompensatedJawMeasuredJs,
        Topic::CompensatedLocalMeasuredCp,
        Topic::CompensatedMeasuredCp,
        Topic::CompensatedStatus,
    ];

    /// The part of the service name after `<prefix>/`.
    pub const fn suffix(self) -> &'static str {
        match self {
            Topic::MeasuredJs => "measured_js",
            Topic::JawMeasuredJs => "jaw/measured_js",
            Topic::LocalMeasuredCp => "local/measured_cp",
            Topic::MeasuredCp => "measured_cp",
            Topic::CompensatedMeasuredJs => "compensated/measured_js",
            Topic::CompensatedJawMeasuredJs => "compensated/jaw/measured_js",
            Topic::CompensatedLocalMeasuredCp => "compensated/local/measured_cp",
            Topic::CompensatedMeasuredCp => "compensated/measured_cp",
            Topic::CompensatedStatus => "compensated/status",
        }
    }

    /// The iceoryx2 type name of the payload published on this topic.
    pub const fn type_name(self) -> &'static str {
        match self {
            Topic::MeasuredJs | Topic::CompensatedMeasuredJs => JointStateV2::TYPE_NAME,
            Topic::JawMeasuredJs | Topic::CompensatedJawMeasuredJs => JawStateV1::TYPE_NAME,
            Topic::LocalMeasuredCp
            | Topic::MeasuredCp
            | Topic::CompensatedLocalMeasuredCp
            | Topic::CompensatedMeasuredCp => PoseV2::TYPE_NAME,
            Topic::CompensatedStatus => CompensationStatusV4::TYPE_NAME,
        }
    }

    /// Whether the topic is under `compensated/`.
    pub const fn is_compensated(self) -> bool {
        matches!(
            self,
            Topic::CompensatedMeasuredJs
                | Topic::CompensatedJawMeasuredJs
                | Topic::CompensatedLocalMeasuredCp
                | Topic::CompensatedMeasuredCp
                | Topic::CompensatedStatus
        )
    }

    /// Whether `T` is the payload type of this topic.
    pub fn carries<T: Message>(self) -> bool {
        self.type_name() == T::TYPE_NAME
    }

    /// The topic whose suffix is `suffix` (e.g. `"compensated/local/measured_cp"`).
    pub fn from_suffix(suffix: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.suffix() == suffix)
    }

    /// Position in [`Topic::ALL`].
    pub const fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Topic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.suffix())
    }
}

/// The validated names of all services of one arm.
#[derive(Debug, Clone)]
pub struct ServiceNames {
    prefix: String,
    topics: [ServiceName; NUM_TOPICS],
    cycle: ServiceName,
    cycle_first: ServiceName,
}

impl ServiceNames {
    /// Builds the names under `prefix` (e.g. `PSM1`).
    ///
    /// The prefix must be 1..=[`MAX_PREFIX_LEN`] bytes of printable ASCII without spaces, must
    /// not start or end with `/`, must not contain `//`, and must not start with `iox2://`.
    pub fn new(prefix: &str) -> Result<Self, IpcError> {
        validate_prefix(prefix)?;
        let make = |suffix: &str| -> Result<ServiceName, IpcError> {
            let full = format!("{prefix}/{suffix}");
            ServiceName::new(&full).map_err(|e| IpcError::InvalidPrefix {
                prefix: prefix.to_owned(),
                reason: match e {
                    iceoryx2::service::service_name::ServiceNameError::ExceedsMaximumLength => {
                        "the service name exceeds 255 bytes"
                    }
                    _ => "iceoryx2 rejects the service name",
                },
            })
        };
        let mut topics = Vec::with_capacity(NUM_TOPICS);
        for t in Topic::ALL {
            topics.push(make(t.suffix())?);
        }
        let topics: [ServiceName; NUM_TOPICS] = match topics.try_into() {
            Ok(t) => t,
            Err(_) => unreachable!("one name per topic"),
        };
        Ok(Self {
            prefix: prefix.to_owned(),
            topics,
            cycle: make(CYCLE_SUFFIX)?,
            cycle_first: make(CYCLE_FIRST_SUFFIX)?,
        })
    }

    /// The prefix these names were built from.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The service name of `topic`.
    pub fn topic(&self, topic: Topic) -> &ServiceName {
        &self.topics[topic.index()]
    }

    /// The event service notified once per cycle, after its last message.
    pub fn cycle(&self) -> &ServiceName {
        &self.cycle
    }

    /// The event service notified once per cycle, after its first message
    /// ([`crate::PUBLISH_ORDER`]`[0]`).
    pub fn cycle_first(&self) -> &ServiceName {
        &self.cycle_first
    }

    /// The event service that announces `topic`'s message of a cycle: [`Self::cycle_first`]
    /// for the first message of the publishing order, [`Self::cycle`] for the others.
    pub fn event_for(&self, topic: Topic) -> &ServiceName {
        if topic == crate::PUBLISH_ORDER[0] {
            &self.cycle_first
        } else {
            &self.cycle
        }
    }

    /// Splits a full service name such as `PSM1/compensated/local/measured_cp` into its prefix
    /// and topic (for tools like `dvrk-sidecar echo`). A leading `/`, as in the ROS topic
    /// `/PSM1/measured_js`, is ignored. The prefix is not validated here: pass it to
    /// [`ServiceNames::new`].
    pub fn split(full: &str) -> Option<(&str, Topic)> {
        let full = full.strip_prefix('/').unwrap_or(full);
        // Longest suffixes first: `local/measured_cp` also ends with `/measured_cp`.
        let mut order = Topic::ALL;
        order.sort_by_key(|t| core::cmp::Reverse(t.suffix().len()));
        order.into_iter().find_map(|t| {
            let prefix = full.strip_suffix(t.suffix())?.strip_suffix('/')?;
            (!prefix.is_empty()).then_some((prefix, t))
        })
    }
}

impl Default for ServiceNames {
    fn default() -> Self {
        // DEFAULT_PREFIX passes validation (tested in `default_names`).
        match Self::new(DEFAULT_PREFIX) {
            Ok(n) => n,
            Err(e) => unreachable!("default prefix is valid: {e}"),
        }
    }
}

fn validate_prefix(prefix: &str) -> Result<(), IpcError> {
    let fail = |reason: &'static str| {
        Err(IpcError::InvalidPrefix {
            prefix: prefix.to_owned(),
            reason,
        })
    };
    if prefix.is_empty() {
        return fail("the prefix is empty");
    }
    if prefix.len() > MAX_PREFIX_LEN {
        return fail("the prefix is longer than 200 bytes");
    }
    if !prefix.bytes().all(|b| b.is_ascii_graphic()) {
        return fail("the prefix must be printable ASCII without spaces");
    }
    if prefix.starts_with('/') || prefix.ends_with('/') {
        return fail("the prefix must not start or end with '/'");
    }
    if prefix.starts_with("iox2://") {
        return fail("the prefix must not start with 'iox2://' (reserved by iceoryx2)");
    }
    if prefix.contains("//") {
        return fail("the prefix must not contain an empty segment ('//')");
    }
    if prefix.split('/').any(|s| arm_name_problem(s).is_some()) {
        return fail(
            "each '/'-separated segment of the prefix must be a ROS name token: ASCII letters, \
             digits and '_', not starting with a digit (the last one is the arm's name, as \
             ros2-bridge --prefix takes it)",
        );
    }
    Ok(())
}

/// Why `name` cannot be an arm's name, or `None` when it can: one ROS name token (`PSM1`), ASCII
/// letters, digits and `_`, not starting with a digit. The one rule for the arm name of
/// `ros2-bridge --prefix` and for every segment of a service prefix (`serve`'s `prefix`), so
/// that a prefix `serve` accepts, such as `lab/PSM1`, names an arm the bridge accepts too, and
/// `../PSM1` is refused by both (issue 22).
pub fn arm_name_problem(name: &str) -> Option<&'static str> {
    let Some(first) = name.chars().next() else {
        return Some("is empty");
    };
    if first.is_ascii_digit() {
        return Some("must not start with a digit (ROS names)");
    }
    if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Some("must be ASCII letters, digits and '_' only (one ROS name token, e.g. PSM1)");
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_names_are_the_consoles() {
        let n = ServiceNames::default();
        assert_eq!(n.prefix(), "PSM1");
        let all: Vec<&str> = Topic::ALL.iter().map(|t| n.topic(*t).as_str()).collect();
        assert_eq!(
            all,
            [
                "PSM1/measured_js",
                "PSM1/jaw/measured_js",
                "PSM1/local/measured_cp",
                "PSM1/measured_cp",
                "PSM1/compensated/measured_js",
                "PSM1/compensated/jaw/measured_js",
                "PSM1/compensated/local/measured_cp",
                "PSM1/compensated/measured_cp",
                "PSM1/compensated/status",
            ]
        );
        assert_eq!(n.cycle().as_str(), "PSM1/cycle");
        assert_eq!(n.cycle_first().as_str(), "PSM1/cycle/first");
        assert_eq!(
            n.event_for(Topic::CompensatedLocalMeasuredCp).as_str(),
            "PSM1/cycle/first"
        );
        for t in &crate::PUBLISH_ORDER[1..] {
            assert_eq!(n.event_for(*t).as_str(), "PSM1/cycle", "{t}");
        }
        assert_eq!(Topic::ALL.iter().filter(|t| t.is_compensated()).count(), 5);
    }

    #[test]
    fn topic_indices_follow_all() {
        for (i, t) in Topic::ALL.into_iter().enumerate() {
            assert_eq!(t.index(), i);
            assert_eq!(Topic::from_suffix(t.suffix()), Some(t));
        }
        assert_eq!(Topic::from_suffix("cycle"), None);
    }

    #[test]
    fn invalid_prefixes_name_the_reason() {
        let cases: [(&str, &str); 7] = [
            ("", "empty"),
            ("dvrk/PSM 1", "printable ASCII"),
            ("dvrk/PSMé", "printable ASCII"),
            ("/dvrk/PSM1", "start or end"),
            ("dvrk/PSM1/", "start or end"),
            ("dvrk//PSM1", "empty segment"),
            ("iox2://x", "iox2://"),
        ];
        for (prefix, reason) in cases {
            match ServiceNames::new(prefix) {
                Err(IpcError::InvalidPrefix {
                    prefix: p,
                    reason: r,
                }) => {
                    assert_eq!(p, prefix);
                    assert!(r.contains(reason), "{prefix:?}: {r}");
                }
                other => panic!("{prefix:?}: expected InvalidPrefix, got {other:?}"),
            }
        }
        let long = "a".repeat(MAX_PREFIX_LEN + 1);
        let err = ServiceNames::new(&long).unwrap_err();
        assert!(err.to_string().contains("longer than 200"), "{err}");
        assert!(ServiceNames::new(&"a".repeat(MAX_PREFIX_LEN)).is_ok());
    }

    #[test]
    fn every_segment_follows_the_arm_name_rule() {
        // Issue 22: `../PSM1` was accepted by serve and refused by ros2-bridge.
        for bad in ["../PSM1", "./PSM1", "lab/PSM-1", "lab/1PSM", "lab.x/PSM1"] {
            let err = ServiceNames::new(bad).unwrap_err().to_string();
            assert!(
                err.contains(&format!("{bad:?}")) && err.contains("ROS name token"),
                "{bad}: {err}"
            );
        }
        for good in ["PSM1", "lab/PSM1", "test/p123/record_rate", "psm_2"] {
            assert!(ServiceNames::new(good).is_ok(), "{good}");
        }
        assert_eq!(arm_name_problem("PSM1"), None);
        assert_eq!(arm_name_problem(""), Some("is empty"));
        assert!(arm_name_problem("1PSM").is_some_and(|r| r.contains("digit")));
        assert!(arm_name_problem("PSM/1").is_some_and(|r| r.contains("letters")));
    }

    #[test]
    fn error_message_names_the_prefix() {
        let err = ServiceNames::new("bad prefix").unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid service prefix \"bad prefix\": the prefix must be printable ASCII without spaces"
        );
    }

    #[test]
    fn split_full_names() {
        for t in Topic::ALL {
            for prefix in ["PSM1", "dvrk/PSM2", "a/b/c"] {
                let full = format!("{prefix}/{}", t.suffix());
                assert_eq!(ServiceNames::split(&full), Some((prefix, t)), "{full}");
                let ros = format!("/{full}");
                assert_eq!(ServiceNames::split(&ros), Some((prefix, t)), "{ros}");
            }
        }
        assert_eq!(ServiceNames::split("measured_js"), None);
        assert_eq!(ServiceNames::split("/measured_js"), None);
        assert_eq!(ServiceNames::split("PSM1/cycle"), None);
        assert_eq!(ServiceNames::split("PSM1/cycle/first"), None);
        assert_eq!(ServiceNames::split("PSM1measured_js"), None);
        // A bare suffix with a slash reads as prefix + topic: `echo` handles bare topics first.
        assert_eq!(
            ServiceNames::split("local/measured_cp"),
            Some(("local", Topic::MeasuredCp))
        );
    }

    #[test]
    fn topic_payload_types() {
        assert_eq!(Topic::MeasuredJs.type_name(), "dvrk::JointStateV2");
        assert_eq!(
            Topic::CompensatedJawMeasuredJs.type_name(),
            "dvrk::JawStateV1"
        );
        assert_eq!(Topic::CompensatedMeasuredCp.type_name(), "dvrk::PoseV2");
        assert_eq!(Topic::LocalMeasuredCp.type_name(), "dvrk::PoseV2");
        assert_eq!(
            Topic::CompensatedStatus.type_name(),
            "dvrk::CompensationStatusV4"
        );
        assert!(Topic::MeasuredCp.carries::<PoseV2>());
        assert!(!Topic::MeasuredJs.carries::<PoseV2>());
    }
}
