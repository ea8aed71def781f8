//! Service names: `<prefix>/<topic>` for the five pub-sub services and `<prefix>/cycle` for the
//! event service notified once per cycle.

use core::fmt;

use iceoryx2::prelude::ServiceName;

use crate::IpcError;
use crate::msg::{CompensationStatusV2, JointStateV1, Message, PoseV1};

/// Default service prefix.
pub const DEFAULT_PREFIX: &str = "dvrk/PSM1";

/// Suffix of the event service, notified once per cycle after all five messages are sent.
pub const CYCLE_SUFFIX: &str = "cycle";

/// Longest accepted prefix in bytes. iceoryx2 service names are limited to 255 bytes; the longest
/// suffix is `/compensated/measured_js` (24 bytes).
pub const MAX_PREFIX_LEN: usize = 200;

/// One of the five pub-sub services of an arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Topic {
    /// `measured_js`, [`JointStateV1`]: joints as read.
    MeasuredJs,
    /// `measured_cp`, [`PoseV1`]: tip pose from the raw joints.
    MeasuredCp,
    /// `compensated/measured_js`, [`JointStateV1`]: joints 1, 2 corrected.
    CompensatedMeasuredJs,
    /// `compensated/measured_cp`, [`PoseV1`]: tip pose from the corrected joints.
    CompensatedMeasuredCp,
    /// `compensated/status`, [`CompensationStatusV2`].
    CompensatedStatus,
}

impl Topic {
    /// All topics, in publishing order.
    pub const ALL: [Topic; 5] = [
        Topic::MeasuredJs,
        Topic::MeasuredCp,
        Topic::CompensatedMeasuredJs,
        Topic::CompensatedMeasuredCp,
        Topic::CompensatedStatus,
    ];

    /// The part of the service name after `<prefix>/`.
    pub const fn suffix(self) -> &'static str {
        match self {
            Topic::MeasuredJs => "measured_js",
            Topic::MeasuredCp => "measured_cp",
            Topic::CompensatedMeasuredJs => "compensated/measured_js",
            Topic::CompensatedMeasuredCp => "compensated/measured_cp",
            Topic::CompensatedStatus => "compensated/status",
        }
    }

    /// The iceoryx2 type name of the payload published on this topic.
    pub const fn type_name(self) -> &'static str {
        match self {
            Topic::MeasuredJs | Topic::CompensatedMeasuredJs => JointStateV1::TYPE_NAME,
            Topic::MeasuredCp | Topic::CompensatedMeasuredCp => PoseV1::TYPE_NAME,
            Topic::CompensatedStatus => CompensationStatusV2::TYPE_NAME,
        }
    }

    /// Whether `T` is the payload type of this topic.
    pub fn carries<T: Message>(self) -> bool {
        self.type_name() == T::TYPE_NAME
    }

    /// The topic whose suffix is `suffix` (e.g. `"compensated/measured_cp"`).
    pub fn from_suffix(suffix: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.suffix() == suffix)
    }

    fn index(self) -> usize {
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
    topics: [ServiceName; 5],
    cycle: ServiceName,
}

impl ServiceNames {
    /// Builds the names under `prefix` (e.g. `dvrk/PSM1`).
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
        let topics = [
            make(Topic::MeasuredJs.suffix())?,
            make(Topic::MeasuredCp.suffix())?,
            make(Topic::CompensatedMeasuredJs.suffix())?,
            make(Topic::CompensatedMeasuredCp.suffix())?,
            make(Topic::CompensatedStatus.suffix())?,
        ];
        Ok(Self {
            prefix: prefix.to_owned(),
            topics,
            cycle: make(CYCLE_SUFFIX)?,
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

    /// The event service notified once per cycle.
    pub fn cycle(&self) -> &ServiceName {
        &self.cycle
    }

    /// Splits a full service name such as `dvrk/PSM1/compensated/measured_cp` into its prefix
    /// and topic (for tools like `dvrk-sidecar echo`). The prefix is not validated here: pass it
    /// to [`ServiceNames::new`].
    pub fn split(full: &str) -> Option<(&str, Topic)> {
        // Longest suffixes first: `compensated/measured_js` also ends with `/measured_js`.
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_names() {
        let n = ServiceNames::default();
        assert_eq!(n.prefix(), "dvrk/PSM1");
        assert_eq!(n.topic(Topic::MeasuredJs).as_str(), "dvrk/PSM1/measured_js");
        assert_eq!(n.topic(Topic::MeasuredCp).as_str(), "dvrk/PSM1/measured_cp");
        assert_eq!(
            n.topic(Topic::CompensatedMeasuredJs).as_str(),
            "dvrk/PSM1/compensated/measured_js"
        );
        assert_eq!(
            n.topic(Topic::CompensatedMeasuredCp).as_str(),
            "dvrk/PSM1/compensated/measured_cp"
        );
        assert_eq!(
            n.topic(Topic::CompensatedStatus).as_str(),
            "dvrk/PSM1/compensated/status"
        );
        assert_eq!(n.cycle().as_str(), "dvrk/PSM1/cycle");
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
    fn error_message_names_the_prefix() {
        let err = ServiceNames::new("bad prefix").unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid service prefix \"bad prefix\": the prefix must be printable ASCII without spaces"
        );
    }

    #[test]
    fn split_full_names() {
        assert_eq!(
            ServiceNames::split("dvrk/PSM1/compensated/measured_cp"),
            Some(("dvrk/PSM1", Topic::CompensatedMeasuredCp))
        );
        assert_eq!(
            ServiceNames::split("dvrk/PSM1/compensated/measured_js"),
            Some(("dvrk/PSM1", Topic::CompensatedMeasuredJs))
        );
        assert_eq!(
            ServiceNames::split("dvrk/PSM2/measured_js"),
            Some(("dvrk/PSM2", Topic::MeasuredJs))
        );
        assert_eq!(
            ServiceNames::split("x/compensated/status"),
            Some(("x", Topic::CompensatedStatus))
        );
        assert_eq!(ServiceNames::split("measured_js"), None);
        assert_eq!(ServiceNames::split("/measured_js"), None);
        assert_eq!(ServiceNames::split("dvrk/PSM1/cycle"), None);
        assert_eq!(ServiceNames::split("dvrk/PSM1measured_js"), None);
    }

    #[test]
    fn topic_payload_types() {
        assert_eq!(Topic::MeasuredJs.type_name(), "dvrk::JointStateV1");
        assert_eq!(Topic::CompensatedMeasuredCp.type_name(), "dvrk::PoseV1");
        assert_eq!(
            Topic::CompensatedStatus.type_name(),
            "dvrk::CompensationStatusV2"
        );
        assert!(Topic::MeasuredCp.carries::<PoseV1>());
        assert!(!Topic::MeasuredJs.carries::<PoseV1>());
    }
}
