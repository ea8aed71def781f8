//! The DDS shell of the ROS 2 bridge: a RustDDS participant with one writer per output topic,
//! writing the CDR bodies of [`crate::convert::Encoder`] under ROS 2's DDS names and types.

use std::convert::Infallible;
use std::net::IpAddr;

use dvrk_ipc::{CompensationStatusV4, JawStateV1, JointStateV2, PoseV2};
use rustdds::bytes::Bytes;
use rustdds::no_key::{DataWriter, SerializerAdapter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, QosPolicies, QosPolicyBuilder,
    RepresentationIdentifier, TopicKind,
};

use crate::convert::{Encoder, OutTopic};
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

/// QoS of the published topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum QosProfile {
    /// ROS 2's sensor-data profile: best effort, keep last 5, volatile.
    #[default]
    SensorData,
    /// ROS 2's default profile: reliable, keep last 10, volatile (for `ros2 bag record` across a
    /// lossy network).
    Reliable,
}

impl QosProfile {
    pub fn policies(self) -> QosPolicies {
        match self {
            QosProfile::SensorData => QosPolicyBuilder::new()
                .reliability(Reliability::BestEffort)
                .history(History::KeepLast { depth: 5 })
                .durability(Durability::Volatile)
                .build(),
            QosProfile::Reliable => QosPolicyBuilder::new()
                .reliability(Reliability::Reliable {
                    max_blocking_time: rustdds::Duration::from_millis(100),
                })
                .history(History::KeepLast { depth: 10 })
                .durability(Durability::Volatile)
                .build(),
        }
    }
}

/// Settings of a [`DdsSink`].
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

/// One writer per [`OutTopic`].
pub struct DdsSink {
    encoder: Encoder,
    // Field order is drop order: writers before the participant.
    writers: Vec<(OutTopic, String, DataWriter<CdrBody, CdrBodyAdapter>)>,
    _publisher: rustdds::Publisher,
    participant: DomainParticipant,
    written: u64,
}

impl core::fmt::Debug for DdsSink {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DdsSink")
            .field("domain", &self.participant.domain_id())
            .field("written", &self.written)
            .finish_non_exhaustive()
    }
}

impl DdsSink {
    /// Joins DDS domain `opts.domain` and creates the writers of every [`OutTopic`].
    pub fn new(encoder: Encoder, opts: &DdsOptions) -> Result<Self, BridgeError> {
        if opts.domain > MAX_DOMAIN_ID {
            return Err(BridgeError::InvalidArgument {
                what: "DDS domain id",
                value: opts.domain.to_string(),
                reason: "must be 0..=232 (the RTPS port numbers must fit in 16 bits)",
            });
        }
        let setup =
            |step: &'static str, name: &str, e: &dyn std::fmt::Display| BridgeError::DdsSetup {
                step,
                name: name.to_owned(),
                reason: e.to_string(),
            };
        let mut builder = DomainParticipantBuilder::new(opts.domain);
        if !opts.interfaces.is_empty() {
            builder = builder.with_only_networks(opts.interfaces.iter().copied());
        }
        let participant = builder
            .build()
            .map_err(|e| setup("participant of domain", &opts.domain.to_string(), &e))?;
        let qos = opts.qos.policies();
        let publisher = participant
            .create_publisher(&qos)
            .map_err(|e| setup("publisher", "", &e))?;
        let mut writers = Vec::with_capacity(OutTopic::ALL.len());
        for t in OutTopic::ALL {
            let name = t.dds_name(&encoder.frames.arm);
            let topic = participant
                .create_topic(
                    name.clone(),
                    t.msg_type().dds_name.to_owned(),
                    &qos,
                    TopicKind::NoKey,
                )
                .map_err(|e| setup("topic", &name, &e))?;
            let writer = publisher
                .create_datawriter_no_key::<CdrBody, CdrBodyAdapter>(&topic, None)
                .map_err(|e| setup("writer", &name, &e))?;
            writers.push((t, name, writer));
        }
        Ok(DdsSink {
            encoder,
            writers,
            _publisher: publisher,
            participant,
            written: 0,
        })
    }

    /// Samples written since start.
    pub fn written(&self) -> u64 {
        self.written
    }

    fn write(&mut self, i: usize) -> Result<(), BridgeError> {
        let (_, name, writer) = &self.writers[i];
        let body = CdrBody(Bytes::copy_from_slice(self.encoder_body()));
        writer
            .write(body, None)
            .map_err(|e| BridgeError::DdsWrite {
                topic: name.clone(),
                source: Box::new(e),
            })?;
        self.written += 1;
        Ok(())
    }

    fn encoder_body(&self) -> &[u8] {
        self.encoder.last_body()
    }

    fn index(t: OutTopic) -> usize {
        OutTopic::ALL.iter().position(|&x| x == t).unwrap_or(0)
    }
}

impl Sink for DdsSink {
    fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError> {
        self.encoder.pose(topic, p);
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
