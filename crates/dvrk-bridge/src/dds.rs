//! The DDS shell of the ROS 2 bridge: one RustDDS participant, one writer per arm and output
//! topic, writing the CDR bodies of [`crate::convert::Encoder`] under ROS 2's DDS names and types.

use std::collections::{HashMap, HashSet};
use std::convert::Infallible;
use std::net::IpAddr;

use dvrk_ipc::{CompensationStatusV4, JawStateV1, JointStateV2, PoseV2};
use rustdds::bytes::Bytes;
use rustdds::dds::WriteError;
use rustdds::no_key::{DataWriter, SerializerAdapter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::qos::QosPolicyId;
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, DomainParticipantStatusEvent,
    DomainParticipantStatusListener, GUID, QosPolicies, QosPolicyBuilder, RTPSEntity,
    RepresentationIdentifier, StatusEvented, TopicKind,
};

use crate::convert::{Encoder, OutTopic, PoseCovariance};
use crate::error::BridgeError;
use crate::source::Sink;

/// A CDR body, already serialized (see [`crate::cdr`]).
#[derive(Debug, Clone)]
pub struct CdrBody(pub Bytes);

/// Hands a [`CdrBody`] to RustDDS as it is; RustDDS adds the CDR_LE encapsulation header.
#[derive(Debug)]
pub struct CdrBodyAdapter;

impl SerializerAdapter<CdrBody> for CdrBodyAdapter {
    /// Passing bytes through cannot fail.
    type Error = Infallible;
    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }
    fn to_bytes(value: &CdrBody) -> Result<Bytes, Infallible> {
        Ok(value.0.clone())
    }
}

/// QoS of the published topics: the console's own state publishers' (KEEP_LAST 100, VOLATILE),
/// reliable by default as ROS 2's default subscribers ask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum QosProfile {
    /// RELIABLE, KEEP_LAST [`HISTORY_DEPTH`], VOLATILE: matches ROS 2's default subscribers
    /// (`rclpy`/`rclcpp` with a depth, `ros2 topic echo`, `ros2 bag record`, rviz) and the dVRK
    /// console's own periodic publishers.
    #[default]
    Reliable,
    /// BEST_EFFORT, KEEP_LAST [`HISTORY_DEPTH`], VOLATILE (`--best-effort`): for sensor-data
    /// subscribers on a lossy network; a RELIABLE reader does not match it (reported in the log).
    BestEffort,
}

/// History depth of every writer: the console's (KEEP_LAST 100).
pub const HISTORY_DEPTH: i32 = 100;

impl QosProfile {
    /// The writers' policies. A reliable write never waits for a reader: `max_blocking_time` is
    /// zero, so a write that finds RustDDS's send window full (8192 samples not yet acknowledged
    /// by the slowest reliable reader, or not yet sent) is not sent at all and counted by
    /// [`DdsSink::dropped`]; the bridge goes on with the next cycle.
    pub fn policies(self) -> QosPolicies {
        let reliability = match self {
            QosProfile::Reliable => Reliability::Reliable {
                max_blocking_time: rustdds::Duration::ZERO,
            },
            QosProfile::BestEffort => Reliability::BestEffort,
        };
        QosPolicyBuilder::new()
            .reliability(reliability)
            .history(History::KeepLast {
                depth: HISTORY_DEPTH,
            })
            .durability(Durability::Volatile)
            .build()
    }

    /// The name used in logs: `RELIABLE` or `BEST_EFFORT`.
    pub fn name(self) -> &'static str {
        match self {
            QosProfile::Reliable => "RELIABLE",
            QosProfile::BestEffort => "BEST_EFFORT",
        }
    }
}

/// Settings of a [`DdsParticipant`].
#[derive(Debug, Clone)]
pub struct DdsOptions {
    /// DDS domain id (ROS_DOMAIN_ID), 0..=232.
    pub domain: u16,
    /// Restrict discovery and traffic to the interfaces with these addresses (e.g. 127.0.0.1);
    /// empty: all interfaces.
    pub interfaces: Vec<IpAddr>,
    pub qos: QosProfile,
}

/// Largest domain id whose RTPS ports fit in 16 bits (7400 + 250 × id + offsets).
pub const MAX_DOMAIN_ID: u16 = 232;

fn setup(step: &'static str, name: &str, e: &dyn std::fmt::Display) -> BridgeError {
    BridgeError::DdsSetup {
        step,
        name: name.to_owned(),
        reason: e.to_string(),
    }
}

/// One DDS participant and publisher shared by the writers of every arm.
pub struct DdsParticipant {
    qos: QosPolicies,
    profile: QosProfile,
    // Field order is drop order: the publisher before the participant.
    publisher: rustdds::Publisher,
    participant: DomainParticipant,
    threads: crate::DdsThreads,
}

impl core::fmt::Debug for DdsParticipant {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DdsParticipant")
            .field("domain", &self.participant.domain_id())
            .field("qos", &self.profile)
            .finish_non_exhaustive()
    }
}

impl DdsParticipant {
    /// Joins DDS domain `opts.domain`.
    pub fn new(opts: &DdsOptions) -> Result<Self, BridgeError> {
        if opts.domain > MAX_DOMAIN_ID {
            return Err(BridgeError::InvalidArgument {
                what: "DDS domain id",
                value: opts.domain.to_string(),
                reason: "must be 0..=232 (the RTPS port numbers must fit in 16 bits)",
            });
        }
        let mut builder = DomainParticipantBuilder::new(opts.domain);
        if !opts.interfaces.is_empty() {
            builder = builder.with_only_networks(opts.interfaces.iter().copied());
        }
        let (participant, threads) = crate::with_signals_blocked(|| builder.build());
        tracing::debug!("DDS participant: {} threads started", threads.count());
        let participant = participant
            .map_err(|e| setup("participant of domain", &opts.domain.to_string(), &e))?;
        let qos = opts.qos.policies();
        let publisher = participant
            .create_publisher(&qos)
            .map_err(|e| setup("publisher", "", &e))?;
        Ok(DdsParticipant {
            qos,
            profile: opts.qos,
            publisher,
            participant,
            threads,
        })
    }

    /// RustDDS's threads of this participant still run (see [`crate::DdsThreads`]).
    pub fn alive(&self) -> bool {
        self.threads.alive()
    }

    /// The QoS every writer offers.
    pub fn profile(&self) -> QosProfile {
        self.profile
    }

    /// The participant's status events (matched and incompatible readers), see
    /// [`IncompatibleReaders`].
    pub fn status_listener(&self) -> DomainParticipantStatusListener {
        self.participant.status_listener()
    }

    /// Creates the writers of every [`OutTopic::ALL`] of the arm `encoder` encodes for.
    pub fn sink(&self, encoder: Encoder) -> Result<DdsSink, BridgeError> {
        let mut writers = Vec::with_capacity(OutTopic::ALL.len());
        for t in OutTopic::ALL {
            let name = t.dds_name(&encoder.frames.arm);
            let topic = self
                .participant
                .create_topic(
                    name.clone(),
                    t.msg_type().dds_name.to_owned(),
                    &self.qos,
                    TopicKind::NoKey,
                )
                .map_err(|e| setup("topic", &name, &e))?;
            let writer = self
                .publisher
                .create_datawriter_no_key::<CdrBody, CdrBodyAdapter>(&topic, None)
                .map_err(|e| setup("writer", &name, &e))?;
            writers.push((t, name, writer));
        }
        Ok(DdsSink {
            encoder,
            writers,
            written: 0,
            dropped: 0,
        })
    }
}

/// The writers of one arm: one per [`OutTopic::ALL`]. Made by [`DdsParticipant::sink`]; owned by
/// the thread that bridges the arm.
pub struct DdsSink {
    encoder: Encoder,
    writers: Vec<(OutTopic, String, DataWriter<CdrBody, CdrBodyAdapter>)>,
    written: u64,
    dropped: u64,
}

impl core::fmt::Debug for DdsSink {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DdsSink")
            .field("arm", &self.encoder.frames.arm)
            .field("written", &self.written)
            .field("dropped", &self.dropped)
            .finish_non_exhaustive()
    }
}

impl DdsSink {
    /// Samples written since start.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Samples not sent because a reliable writer's send window was full (a reliable reader
    /// that stopped acknowledging, or a network that does not drain): see
    /// [`QosProfile::policies`].
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The GUID and DDS topic name of every writer, to name the topic of a writer's event.
    pub fn writer_topics(&self) -> impl Iterator<Item = (GUID, String)> + '_ {
        self.writers.iter().map(|(_, n, w)| (w.guid(), n.clone()))
    }

    fn write(&mut self, i: usize) -> Result<(), BridgeError> {
        let Some((_, name, writer)) = self.writers.get(i) else {
            return Ok(());
        };
        let body = CdrBody(Bytes::copy_from_slice(self.encoder.last_body()));
        match writer.write(body, None) {
            Ok(()) => self.written += 1,
            // The send window is full: this sample is not sent (the writer never blocks).
            Err(WriteError::WouldBlock { .. }) => self.dropped += 1,
            Err(e) => {
                return Err(BridgeError::DdsWrite {
                    topic: name.clone(),
                    source: Box::new(e),
                });
            }
        }
        Ok(())
    }

    fn index(t: OutTopic) -> usize {
        OutTopic::ALL
            .iter()
            .position(|&x| x == t)
            .unwrap_or(usize::MAX)
    }
}

impl Sink for DdsSink {
    fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError> {
        self.encoder.pose(topic, p);
        self.write(Self::index(topic))
    }

    fn pose_with_covariance(
        &mut self,
        topic: OutTopic,
        p: &PoseV2,
        cov: &PoseCovariance,
    ) -> Result<(), BridgeError> {
        self.encoder.pose_with_covariance(topic, p, cov);
        self.write(Self::index(topic))
    }

    fn joints(&mut self, topic: OutTopic, js: &JointStateV2) -> Result<(), BridgeError> {
        self.encoder.joints(js);
        self.write(Self::index(topic))
    }

    fn jaw(&mut self, topic: OutTopic, jaw: &JawStateV1) -> Result<(), BridgeError> {
        self.encoder.jaw(jaw);
        self.write(Self::index(topic))
    }

    fn status(&mut self, s: &CompensationStatusV4) -> Result<(), BridgeError> {
        self.encoder.status(s);
        self.write(Self::index(OutTopic::Status))
    }
}

/// Reports each reader whose requested QoS this bridge's writers do not offer, once per reader
/// and topic, naming the topic and the policy. RustDDS compares the QoS a reader announces in
/// discovery (SEDP, parsed and checked by RustDDS) with the writer's and sends the participant an
/// event; this turns the events into log lines.
pub struct IncompatibleReaders {
    listener: DomainParticipantStatusListener,
    topics: HashMap<GUID, String>,
    reported: HashSet<(GUID, GUID)>,
}

impl core::fmt::Debug for IncompatibleReaders {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("IncompatibleReaders")
            .field("reported", &self.reported.len())
            .finish_non_exhaustive()
    }
}

impl IncompatibleReaders {
    /// Watches the events of `participant` for the writers `topics` (GUID, DDS topic name).
    pub fn new(
        participant: &DdsParticipant,
        topics: impl IntoIterator<Item = (GUID, String)>,
    ) -> Self {
        IncompatibleReaders {
            listener: participant.status_listener(),
            topics: topics.into_iter().collect(),
            reported: HashSet::new(),
        }
    }

    /// Logs every incompatible reader seen since the last call (once each); returns how many
    /// were new.
    pub fn poll(&mut self) -> usize {
        let mut new = 0;
        while let Some(ev) = self.listener.try_recv_status() {
            if let DomainParticipantStatusEvent::RemoteReaderQosIncompatible {
                local_writer,
                remote_reader,
                requested_qos,
                offered_qos,
            } = ev
                && let Some(topic) = self.topics.get(&local_writer)
                && self.reported.insert((local_writer, remote_reader))
            {
                tracing::warn!(
                    "{} (reader {:?})",
                    incompatibility(topic, &requested_qos, &offered_qos),
                    remote_reader.prefix
                );
                new += 1;
            }
        }
        new
    }
}

/// Why a reader that requests `requested` receives nothing from a writer of `topic` that offers
/// `offered`, naming the policy, both values and what to change.
pub fn incompatibility(topic: &str, requested: &QosPolicies, offered: &QosPolicies) -> String {
    match offered.compliance_failure_wrt(requested) {
        Some(QosPolicyId::Reliability) => format!(
            "incompatible reader on {topic}: it requests RELIABILITY RELIABLE, this bridge \
             offers BEST_EFFORT (--best-effort), so it receives nothing: run the bridge without \
             --best-effort, or make the reader best effort"
        ),
        Some(QosPolicyId::Durability) => format!(
            "incompatible reader on {topic}: it requests DURABILITY {}, this bridge offers {} \
             (state topics are not kept for late joiners, as the console's are not), so it \
             receives nothing: make the reader VOLATILE",
            durability_name(requested.durability()),
            durability_name(offered.durability()),
        ),
        Some(policy) => format!(
            "incompatible reader on {topic}: its {policy:?} QoS policy is not offered by this \
             bridge (requested {requested:?}, offered {offered:?}), so it receives nothing"
        ),
        None => {
            format!("incompatible reader on {topic}: requested {requested:?}, offered {offered:?}")
        }
    }
}

fn durability_name(d: Option<Durability>) -> &'static str {
    match d.unwrap_or(Durability::Volatile) {
        Durability::Volatile => "VOLATILE",
        Durability::TransientLocal => "TRANSIENT_LOCAL",
        Durability::Transient => "TRANSIENT",
        Durability::Persistent => "PERSISTENT",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reader(rel: Reliability, dur: Durability) -> QosPolicies {
        QosPolicyBuilder::new()
            .reliability(rel)
            .durability(dur)
            .history(History::KeepLast { depth: 10 })
            .build()
    }

    #[test]
    fn the_default_profile_matches_a_default_ros2_subscriber_and_the_console() {
        let offered = QosProfile::default().policies();
        assert_eq!(QosProfile::default(), QosProfile::Reliable);
        assert!(offered.is_reliable());
        assert_eq!(
            offered.history(),
            Some(History::KeepLast {
                depth: HISTORY_DEPTH
            })
        );
        assert_eq!(HISTORY_DEPTH, 100);
        // A reliable write never waits for a reader.
        assert_eq!(
            offered.reliable_max_blocking_time(),
            Some(rustdds::Duration::ZERO)
        );
        let rel = Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        };
        // rclcpp's default (reliable, volatile) and a sensor-data reader both match.
        for r in [
            reader(rel, Durability::Volatile),
            reader(Reliability::BestEffort, Durability::Volatile),
        ] {
            assert_eq!(offered.compliance_failure_wrt(&r), None, "{r:?}");
        }
    }

    #[test]
    fn incompatible_readers_are_named_by_topic_and_policy() {
        let rel = Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        };
        let be = QosProfile::BestEffort.policies();
        let m = incompatibility(
            "rt/PSM2/compensated/measured_js",
            &reader(rel, Durability::Volatile),
            &be,
        );
        assert!(
            m.contains("rt/PSM2/compensated/measured_js")
                && m.contains("RELIABILITY RELIABLE")
                && m.contains("--best-effort"),
            "{m}"
        );
        let m = incompatibility(
            "rt/PSM1/compensated/status",
            &reader(rel, Durability::TransientLocal),
            &QosProfile::Reliable.policies(),
        );
        assert!(
            m.contains("rt/PSM1/compensated/status")
                && m.contains("DURABILITY TRANSIENT_LOCAL")
                && m.contains("offers VOLATILE"),
            "{m}"
        );
    }
}
