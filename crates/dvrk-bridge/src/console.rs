//! The dVRK 2.x console's CRTK interface over DDS, both ways:
//!
//! - [`ConsoleClient`]: what a program that watches and moves an arm through the console uses
//!   (the calibration procedures on a real arm): it reads `measured_js`, `operating_state`,
//!   `goal_reached`, `warning`, `error`, `tool_type` and `trajectory_j/ratio` (where the console
//!   publishes it), and writes `move_jp`, `servo_jp`,
//!   `hold`, `state_command` and `trajectory_j/set_ratio`.
//! - [`ConsoleServer`]: the other side of the same topics, for a console stand-in (the simulated
//!   PSM of `dvrk-sidecar sim --crtk PSM1`) that tests run the procedures against.
//!
//! QoS is the console's (reference/dvrk-crtk-ros2.md, cisst-ros): periodic state RELIABLE,
//! KEEP_LAST 100, VOLATILE; events RELIABLE, KEEP_LAST 100, TRANSIENT_LOCAL, so a reader that
//! joins late still learns the current operating state and instrument; commands RELIABLE,
//! depth 1 (a BEST_EFFORT writer would not match the console's readers).
//!
//! Both sides are polled: [`ConsoleClient::poll`] drains every reader without blocking and
//! returns what arrived, in arrival order per topic. Events of all topics carry one sequence
//! number, so a caller can tell what happened after its own command.

use std::collections::VecDeque;
use std::convert::Infallible;
use std::net::IpAddr;
use std::time::{Duration, Instant};

use rustdds::bytes::Bytes;
use rustdds::no_key::{DataReader, DataWriter, DefaultDecoder, DeserializerAdapter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, QosPolicies, QosPolicyBuilder,
    RepresentationIdentifier, TopicKind,
};

use crate::cdr::{CdrWriter, RosTime};
use crate::crtk::{self, JointStateMsg, OperatingStateMsg, PoseStampedMsg, dds_type};
use crate::dds::{CdrBody, CdrBodyAdapter, MAX_DOMAIN_ID};
use crate::error::BridgeError;

/// A received CDR body and its byte order.
#[derive(Debug, Clone)]
pub struct RawBody {
    pub big_endian: bool,
    pub bytes: Vec<u8>,
}

/// Hands the received body over undecoded; [`crate::crtk`] decodes it with checks.
#[derive(Debug)]
pub struct RawAdapter;

const RAW_ENCODINGS: [RepresentationIdentifier; 2] = [
    RepresentationIdentifier::CDR_LE,
    RepresentationIdentifier::CDR_BE,
];

impl DeserializerAdapter<RawBody> for RawAdapter {
    type Error = Infallible;
    type Decoded = RawBody;
    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &RAW_ENCODINGS
    }
    fn transform_decoded(decoded: RawBody) -> RawBody {
        decoded
    }
}

/// The decoder of [`RawAdapter`]: copies the bytes.
#[derive(Debug, Clone, Copy)]
pub struct RawDecoder;

impl<'de> rustdds::no_key::Decode<'de, RawBody> for RawDecoder {
    type Error = Infallible;
    fn decode_bytes(
        self,
        input_bytes: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<RawBody, Infallible> {
        Ok(RawBody {
            big_endian: encoding == RepresentationIdentifier::CDR_BE,
            bytes: input_bytes.to_vec(),
        })
    }
}

impl DefaultDecoder<RawBody> for RawAdapter {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

/// The three QoS of the console's topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConsoleQos {
    /// Periodic state (`measured_js`): RELIABLE, KEEP_LAST 100, VOLATILE.
    State,
    /// Events (`operating_state`, `goal_reached`, `tool_type`, ...): RELIABLE, KEEP_LAST 100,
    /// TRANSIENT_LOCAL.
    Event,
    /// Commands (`move_jp`, `servo_jp`, `state_command`, ...): RELIABLE, KEEP_LAST 1, VOLATILE.
    Command,
    /// A reader of periodic state that must never wait for a repair: BEST_EFFORT, KEEP_LAST
    /// 100, VOLATILE. It matches the console's RELIABLE writers; a lost datagram is skipped
    /// instead of holding back every later sample until the writer's next heartbeat (a
    /// reliable reader delivers in order), which a 0.3 s silence watchdog would take for a
    /// console that fell silent.
    StreamReader,
}

impl ConsoleQos {
    pub fn policies(self) -> QosPolicies {
        let reliable = Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        };
        let (depth, durability) = match self {
            ConsoleQos::State | ConsoleQos::StreamReader => (100, Durability::Volatile),
            ConsoleQos::Event => (100, Durability::TransientLocal),
            ConsoleQos::Command => (1, Durability::Volatile),
        };
        let reliability = if self == ConsoleQos::StreamReader {
            Reliability::BestEffort
        } else {
            reliable
        };
        QosPolicyBuilder::new()
            .reliability(reliability)
            .history(History::KeepLast { depth })
            .durability(durability)
            .build()
    }
}

/// The DDS domain from `ROS_DOMAIN_ID` as ROS 2 reads it: unset or empty is 0; anything but
/// an integer 0..=232 is an error naming the variable and its value.
pub fn ros_domain_id() -> Result<u16, BridgeError> {
    domain_id_from(std::env::var_os("ROS_DOMAIN_ID").as_deref())
}

fn domain_id_from(value: Option<&std::ffi::OsStr>) -> Result<u16, BridgeError> {
    let Some(v) = value else { return Ok(0) };
    let bad = || BridgeError::InvalidArgument {
        what: "ROS_DOMAIN_ID",
        value: v.to_string_lossy().into_owned(),
        reason: "must be an integer 0..=232, as ROS 2 requires (or unset: domain 0)",
    };
    let s = v.to_str().ok_or_else(bad)?.trim();
    if s.is_empty() {
        return Ok(0);
    }
    if !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    match s.parse::<u16>() {
        Ok(d) if d <= MAX_DOMAIN_ID => Ok(d),
        _ => Err(bad()),
    }
}

/// One participant with a publisher and a subscriber, and helpers to make the console's
/// writers and readers under an arm's name.
struct Endpoints {
    arm: String,
    publisher: rustdds::Publisher,
    subscriber: rustdds::Subscriber,
    participant: DomainParticipant,
    threads: crate::DdsThreads,
}

type Writer = DataWriter<CdrBody, CdrBodyAdapter>;
type Reader = DataReader<RawBody, RawAdapter>;

fn setup(step: &'static str, name: &str, e: &dyn std::fmt::Display) -> BridgeError {
    BridgeError::DdsSetup {
        step,
        name: name.to_owned(),
        reason: e.to_string(),
    }
}

impl Endpoints {
    fn new(arm: &str, domain: u16, interfaces: &[IpAddr]) -> Result<Self, BridgeError> {
        crate::validate_arm(arm)?;
        if domain > MAX_DOMAIN_ID {
            return Err(BridgeError::InvalidArgument {
                what: "DDS domain id",
                value: domain.to_string(),
                reason: "must be 0..=232 (the RTPS port numbers must fit in 16 bits)",
            });
        }
        let mut builder = DomainParticipantBuilder::new(domain);
        if !interfaces.is_empty() {
            builder = builder.with_only_networks(interfaces.iter().copied());
        }
        let (participant, threads) = crate::with_signals_blocked(|| builder.build());
        let participant =
            participant.map_err(|e| setup("participant of domain", &domain.to_string(), &e))?;
        let qos = ConsoleQos::State.policies();
        let publisher = participant
            .create_publisher(&qos)
            .map_err(|e| setup("publisher", "", &e))?;
        let subscriber = participant
            .create_subscriber(&qos)
            .map_err(|e| setup("subscriber", "", &e))?;
        Ok(Self {
            arm: arm.to_owned(),
            publisher,
            subscriber,
            participant,
            threads,
        })
    }

    fn topic(
        &self,
        suffix: &str,
        ty: &str,
        qos: ConsoleQos,
    ) -> Result<(String, rustdds::Topic), BridgeError> {
        let name = format!("rt/{}/{suffix}", self.arm);
        let topic = self
            .participant
            .create_topic(
                name.clone(),
                ty.to_owned(),
                &qos.policies(),
                TopicKind::NoKey,
            )
            .map_err(|e| setup("topic", &name, &e))?;
        Ok((name, topic))
    }

    fn writer(
        &self,
        suffix: &str,
        ty: &str,
        qos: ConsoleQos,
    ) -> Result<Named<Writer>, BridgeError> {
        let (name, topic) = self.topic(suffix, ty, qos)?;
        let w = self
            .publisher
            .create_datawriter_no_key::<CdrBody, CdrBodyAdapter>(&topic, Some(qos.policies()))
            .map_err(|e| setup("writer", &name, &e))?;
        Ok(Named {
            name,
            inner: w,
            matched: 0,
        })
    }

    /// A reader of `suffix`; for an event topic, with its live companion (see [`TopicReader`]).
    fn reader(
        &self,
        suffix: &str,
        ty: &str,
        qos: ConsoleQos,
    ) -> Result<Named<TopicReader>, BridgeError> {
        let (name, topic) = self.topic(suffix, ty, qos)?;
        let create = |q: QosPolicies| {
            self.subscriber
                .create_datareader_no_key::<RawBody, RawAdapter>(&topic, Some(q))
                .map_err(|e| setup("reader", &name, &e))
        };
        let inner = create(qos.policies())?;
        let live = if qos == ConsoleQos::Event {
            Some(create(
                QosPolicyBuilder::new()
                    .reliability(Reliability::BestEffort)
                    .history(History::KeepLast { depth: 100 })
                    .durability(Durability::Volatile)
                    .build(),
            )?)
        } else {
            None
        };
        Ok(Named {
            name,
            inner: TopicReader {
                reader: inner,
                live,
                incompatible: None,
            },
            matched: 0,
        })
    }
}

/// A reader, and for an event topic a live companion. The console's event writers are
/// TRANSIENT_LOCAL, so a reader that joins late still gets the current state; but a writer
/// must offer at least the durability a reader asks for, and a console (a version, a bridge, a
/// stand-in) whose event writers are VOLATILE (or BEST_EFFORT) would match no TRANSIENT_LOCAL,
/// RELIABLE reader: its state and instrument changes would never arrive. The companion asks for
/// the least, VOLATILE and BEST_EFFORT, so it matches any writer; its samples are taken only
/// while the main reader has matched no writer (a writer of the console's QoS reaches both, and
/// would otherwise be heard twice). On a lossy link a BEST_EFFORT reader may miss an event the
/// writer sent; the console's own writers never come to it.
struct TopicReader {
    reader: Reader,
    live: Option<Reader>,
    /// What the main reader found incompatible in a writer it could not match (the policy),
    /// for the error that says why nothing arrives.
    incompatible: Option<String>,
}

struct Named<T> {
    name: String,
    inner: T,
    /// Readers matched (for a writer), or writers matched (for a reader's main reader), from the
    /// status events.
    matched: i32,
}

impl Named<Writer> {
    fn send(&self, w: &CdrWriter) -> Result<(), BridgeError> {
        self.inner
            .write(CdrBody(Bytes::copy_from_slice(w.body())), None)
            .map_err(|e| BridgeError::DdsWrite {
                topic: self.name.clone(),
                source: Box::new(e),
            })
    }

    fn matched(&mut self) -> bool {
        use rustdds::StatusEvented;
        while let Some(status) = self.inner.try_recv_status() {
            if let rustdds::DataWriterStatus::PublicationMatched { current, .. } = status {
                self.matched = current.count();
            }
        }
        self.matched > 0
    }
}

impl Named<TopicReader> {
    /// Every sample waiting, oldest first. A reader error ends the drain (the next poll tries
    /// again); undecodable samples are counted by the caller.
    fn drain(&mut self, out: &mut Vec<RawBody>) {
        use rustdds::StatusEvented;
        while let Some(status) = self.inner.reader.try_recv_status() {
            match status {
                rustdds::DataReaderStatus::SubscriptionMatched { current, .. } => {
                    self.matched = current.count();
                }
                rustdds::DataReaderStatus::RequestedIncompatibleQos { last_policy_id, .. } => {
                    self.inner.incompatible = Some(format!("{last_policy_id:?}"));
                }
                _ => {}
            }
        }
        while let Ok(Some(s)) = self.inner.reader.take_next_sample() {
            out.push(s.into_value());
        }
        let take_live = self.matched == 0;
        if let Some(live) = &mut self.inner.live {
            while let Ok(Some(s)) = live.take_next_sample() {
                if take_live {
                    out.push(s.into_value());
                }
            }
        }
    }

    /// Why the main reader matched no writer, if a writer's QoS was incompatible:
    /// `"/PSM1/operating_state: Durability"` (the ROS 2 topic name and the policy).
    fn incompatible(&self) -> Option<String> {
        if self.matched != 0 {
            return None;
        }
        let policy = self.inner.incompatible.as_ref()?;
        Some(format!("{}: {policy}", self.name.trim_start_matches("rt")))
    }
}

fn now_stamp() -> RosTime {
    let ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos().min(i64::MAX as u128) as i64);
    RosTime::from_unix_ns(ns)
}

/// What the console said, in the order it was polled.
#[derive(Debug, Clone, PartialEq)]
pub enum ConsoleEvent {
    OperatingState(OperatingStateMsg),
    GoalReached(bool),
    Warning(String),
    Error(String),
    ToolType(String),
    /// `trajectory_j/ratio`: the ratio the console's joint trajectories run at, sent on each
    /// `trajectory_j/set_ratio` it takes (dVRK 2.x; older consoles do not publish it).
    Ratio(f64),
}

/// A console event with its arrival sequence number and time.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamped<T> {
    pub seq: u64,
    pub at: Instant,
    pub value: T,
}

/// What a [`ConsoleClient::poll`] brought.
#[derive(Debug, Default)]
pub struct Polled {
    /// New `measured_js` messages, oldest first (valid or not: see `is_valid`).
    pub measured_js: Vec<JointStateMsg>,
    /// New events, oldest first per topic.
    pub events: Vec<Stamped<ConsoleEvent>>,
    /// Samples that did not decode (counted, never fatal).
    pub undecodable: u64,
}

/// A client of one arm of the console.
pub struct ConsoleClient {
    // Field order is drop order: readers and writers before the endpoints' participant.
    move_jp: Named<Writer>,
    servo_jp: Named<Writer>,
    hold: Named<Writer>,
    state_command: Named<Writer>,
    set_ratio: Named<Writer>,
    measured_js: Named<TopicReader>,
    operating_state: Named<TopicReader>,
    goal_reached: Named<TopicReader>,
    warning: Named<TopicReader>,
    error: Named<TopicReader>,
    tool_type: Named<TopicReader>,
    ratio: Named<TopicReader>,
    ep: Endpoints,
    domain: u16,
    seq: u64,
    buf: Vec<RawBody>,
    w: CdrWriter,
    /// Last values, for callers that only want the current state.
    pub last_operating_state: Option<OperatingStateMsg>,
    pub last_tool_type: Option<String>,
    /// The last `trajectory_j/ratio` the console sent (`None` before any, or from a console
    /// that does not publish it).
    pub last_ratio: Option<f64>,
    pub recent_warnings: VecDeque<String>,
}

impl core::fmt::Debug for ConsoleClient {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ConsoleClient")
            .field("arm", &self.ep.arm)
            .field("domain", &self.domain)
            .finish_non_exhaustive()
    }
}

/// Names of the joints the console's PSM `move_jp` takes (6 joints with an instrument).
pub const PSM_JOINT_NAMES: [&str; 6] = [
    "yaw",
    "pitch",
    "insertion",
    "roll",
    "wrist_pitch",
    "wrist_yaw",
];

impl ConsoleClient {
    /// Joins `domain` and creates the endpoints of `arm` (e.g. `PSM1`).
    pub fn new(arm: &str, domain: u16, interfaces: &[IpAddr]) -> Result<Self, BridgeError> {
        let ep = Endpoints::new(arm, domain, interfaces)?;
        use ConsoleQos::{Command, Event};
        Ok(Self {
            move_jp: ep.writer("move_jp", dds_type::JOINT_STATE, Command)?,
            servo_jp: ep.writer("servo_jp", dds_type::JOINT_STATE, Command)?,
            hold: ep.writer("hold", dds_type::EMPTY, Command)?,
            state_command: ep.writer("state_command", dds_type::STRING_STAMPED, Command)?,
            set_ratio: ep.writer("trajectory_j/set_ratio", dds_type::FLOAT64, Command)?,
            measured_js: ep.reader(
                "measured_js",
                dds_type::JOINT_STATE,
                ConsoleQos::StreamReader,
            )?,
            operating_state: ep.reader("operating_state", dds_type::OPERATING_STATE, Event)?,
            goal_reached: ep.reader("goal_reached", dds_type::BOOL, Event)?,
            warning: ep.reader("warning", dds_type::STRING, Event)?,
            error: ep.reader("error", dds_type::STRING, Event)?,
            tool_type: ep.reader("tool_type", dds_type::STRING, Event)?,
            ratio: ep.reader("trajectory_j/ratio", dds_type::FLOAT64, Event)?,
            ep,
            domain,
            seq: 0,
            buf: Vec::new(),
            w: CdrWriter::new(),
            last_operating_state: None,
            last_tool_type: None,
            last_ratio: None,
            recent_warnings: VecDeque::new(),
        })
    }

    pub fn arm(&self) -> &str {
        &self.ep.arm
    }

    pub fn domain(&self) -> u16 {
        self.domain
    }

    /// RustDDS's threads of this client still run (see [`crate::DdsThreads`]): after they end,
    /// nothing is sent or received.
    pub fn dds_alive(&self) -> bool {
        self.ep.threads.alive()
    }

    /// The console's command readers have matched our writers (a command written before that
    /// would be lost: the readers are VOLATILE).
    pub fn commands_matched(&mut self) -> bool {
        self.move_jp.matched()
            && self.servo_jp.matched()
            && self.state_command.matched()
            && self.hold.matched()
    }

    /// The topics whose writer this client could not match, with the QoS policy at fault
    /// (`"/PSM1/operating_state: Durability"`): a writer that offers less than the console's QoS.
    /// A VOLATILE event writer is still heard through the live companion reader
    /// (`TopicReader`), but only from its next change on.
    pub fn incompatible_writers(&self) -> Vec<String> {
        [
            &self.measured_js,
            &self.operating_state,
            &self.goal_reached,
            &self.warning,
            &self.error,
            &self.tool_type,
        ]
        .iter()
        .filter_map(|r| r.incompatible())
        .collect()
    }

    /// The console's `trajectory_j/set_ratio` reader has matched.
    pub fn ratio_matched(&mut self) -> bool {
        self.set_ratio.matched()
    }

    /// The console publishes `trajectory_j/ratio` (a writer of it matched, as of the last
    /// [`poll`](Self::poll)): it says which ratio it takes.
    pub fn ratio_published(&self) -> bool {
        self.ratio.matched > 0
    }

    /// Drains every reader without blocking.
    pub fn poll(&mut self, out: &mut Polled) {
        let now = Instant::now();
        let mut buf = std::mem::take(&mut self.buf);

        buf.clear();
        self.measured_js.drain(&mut buf);
        for b in &buf {
            match JointStateMsg::decode(&b.bytes, b.big_endian) {
                Ok(m) => out.measured_js.push(m),
                Err(_) => out.undecodable += 1,
            }
        }

        buf.clear();
        self.operating_state.drain(&mut buf);
        for b in &buf {
            match OperatingStateMsg::decode(&b.bytes, b.big_endian) {
                Ok(m) => {
                    self.last_operating_state = Some(m.clone());
                    self.push(out, now, ConsoleEvent::OperatingState(m));
                }
                Err(_) => out.undecodable += 1,
            }
        }

        buf.clear();
        self.goal_reached.drain(&mut buf);
        for b in &buf {
            match crtk::decode_bool(&b.bytes, b.big_endian) {
                Ok(v) => self.push(out, now, ConsoleEvent::GoalReached(v)),
                Err(_) => out.undecodable += 1,
            }
        }

        buf.clear();
        self.ratio.drain(&mut buf);
        for b in &buf {
            match crtk::decode_f64(&b.bytes, b.big_endian) {
                Ok(v) => {
                    self.last_ratio = Some(v);
                    self.push(out, now, ConsoleEvent::Ratio(v));
                }
                Err(_) => out.undecodable += 1,
            }
        }

        for (which, kind) in [(0, "warning"), (1, "error"), (2, "tool_type")] {
            buf.clear();
            match which {
                0 => self.warning.drain(&mut buf),
                1 => self.error.drain(&mut buf),
                _ => self.tool_type.drain(&mut buf),
            }
            for b in &buf {
                match crtk::decode_string(&b.bytes, b.big_endian) {
                    Ok(s) => {
                        let ev = match kind {
                            "warning" => {
                                if self.recent_warnings.len() >= 16 {
                                    self.recent_warnings.pop_front();
                                }
                                self.recent_warnings.push_back(s.clone());
                                ConsoleEvent::Warning(s)
                            }
                            "error" => ConsoleEvent::Error(s),
                            _ => {
                                self.last_tool_type = Some(s.clone());
                                ConsoleEvent::ToolType(s)
                            }
                        };
                        self.push(out, now, ev);
                    }
                    Err(_) => out.undecodable += 1,
                }
            }
        }
        self.buf = buf;
    }

    fn push(&mut self, out: &mut Polled, at: Instant, value: ConsoleEvent) {
        self.seq += 1;
        out.events.push(Stamped {
            seq: self.seq,
            at,
            value,
        });
    }

    /// Sequence number of the last event received: events after a command have a larger one.
    pub fn last_seq(&self) -> u64 {
        self.seq
    }

    fn joints(&mut self, position: &[f64], velocity: &[f64]) {
        self.w.clear();
        let n = position.len().min(PSM_JOINT_NAMES.len());
        JointStateMsg {
            stamp: now_stamp(),
            frame_id: String::new(),
            name: PSM_JOINT_NAMES[..n]
                .iter()
                .map(|s| (*s).to_owned())
                .collect(),
            position: position.to_vec(),
            velocity: velocity.to_vec(),
            effort: Vec::new(),
        }
        .encode(&mut self.w);
    }

    /// `move_jp` to `position` (all the arm's joints, SI units).
    pub fn move_jp(&mut self, position: &[f64]) -> Result<(), BridgeError> {
        self.joints(position, &[]);
        self.move_jp.send(&self.w)
    }

    /// `servo_jp` to `position` (a step the console's controller reaches in one cycle).
    pub fn servo_jp(&mut self, position: &[f64]) -> Result<(), BridgeError> {
        self.joints(position, &[]);
        self.servo_jp.send(&self.w)
    }

    /// `servo_jp` with a velocity feed-forward (same length as `position`).
    pub fn servo_jp_with_velocity(
        &mut self,
        position: &[f64],
        velocity: &[f64],
    ) -> Result<(), BridgeError> {
        self.joints(position, velocity);
        self.servo_jp.send(&self.w)
    }

    /// `hold`: the arm stays where it is.
    pub fn hold(&mut self) -> Result<(), BridgeError> {
        self.w.clear();
        crtk::encode_empty(&mut self.w);
        self.hold.send(&self.w)
    }

    /// `hold`, then waits up to `max_wait` for the console's readers to acknowledge it (for a
    /// participant about to be dropped); `Ok(false)` when they did not in time (or the wait
    /// failed).
    pub fn hold_acknowledged(&mut self, max_wait: Duration) -> Result<bool, BridgeError> {
        self.hold()?;
        Ok(self
            .hold
            .inner
            .wait_for_acknowledgments(max_wait)
            .unwrap_or(false))
    }

    /// `state_command` (`enable`, `disable`, `home`, `unhome`, `pause`, `resume`).
    pub fn state_command(&mut self, command: &str) -> Result<(), BridgeError> {
        self.w.clear();
        crtk::encode_string_stamped(&mut self.w, now_stamp(), command);
        self.state_command.send(&self.w)
    }

    /// `trajectory_j/set_ratio` in ]0, 1].
    pub fn set_ratio(&mut self, ratio: f64) -> Result<(), BridgeError> {
        if !(ratio > 0.0 && ratio <= 1.0) {
            return Err(BridgeError::InvalidArgument {
                what: "trajectory_j/set_ratio",
                value: ratio.to_string(),
                reason: "must be in ]0, 1]",
            });
        }
        self.w.clear();
        self.w.f64(ratio);
        self.set_ratio.send(&self.w)
    }
}

/// What a [`ConsoleWatcher`] poll brought: the newest of each.
#[derive(Debug, Default)]
pub struct Watched {
    pub operating_state: Option<OperatingStateMsg>,
    pub tool_type: Option<String>,
    /// `measured_cp` (base frame) and `local/measured_cp` (RCM frame), newest of each.
    pub measured_cp: Option<PoseStampedMsg>,
    pub local_measured_cp: Option<PoseStampedMsg>,
    /// Anything at all arrived (the console is alive).
    pub heard: bool,
    pub undecodable: u64,
}

/// A read-only client of one arm of the console: its state events, its instrument and its two
/// tip poses. It writes nothing (a service that follows the console never commands it).
pub struct ConsoleWatcher {
    operating_state: Named<TopicReader>,
    tool_type: Named<TopicReader>,
    measured_cp: Named<TopicReader>,
    local_measured_cp: Named<TopicReader>,
    ep: Endpoints,
    buf: Vec<RawBody>,
}

impl core::fmt::Debug for ConsoleWatcher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ConsoleWatcher")
            .field("arm", &self.ep.arm)
            .finish_non_exhaustive()
    }
}

impl ConsoleWatcher {
    pub fn new(arm: &str, domain: u16, interfaces: &[IpAddr]) -> Result<Self, BridgeError> {
        let ep = Endpoints::new(arm, domain, interfaces)?;
        use ConsoleQos::{Event, StreamReader};
        Ok(Self {
            operating_state: ep.reader("operating_state", dds_type::OPERATING_STATE, Event)?,
            tool_type: ep.reader("tool_type", dds_type::STRING, Event)?,
            measured_cp: ep.reader("measured_cp", dds_type::POSE_STAMPED, StreamReader)?,
            local_measured_cp: ep.reader(
                "local/measured_cp",
                dds_type::POSE_STAMPED,
                StreamReader,
            )?,
            ep,
            buf: Vec::new(),
        })
    }

    /// Drains every reader without blocking; keeps the newest of each (poses are paired by the
    /// caller through their stamps).
    pub fn poll(
        &mut self,
        out: &mut Watched,
        cp: &mut Vec<PoseStampedMsg>,
        local: &mut Vec<PoseStampedMsg>,
    ) {
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        self.operating_state.drain(&mut buf);
        for b in &buf {
            out.heard = true;
            match OperatingStateMsg::decode(&b.bytes, b.big_endian) {
                Ok(m) => out.operating_state = Some(m),
                Err(_) => out.undecodable += 1,
            }
        }
        buf.clear();
        self.tool_type.drain(&mut buf);
        for b in &buf {
            out.heard = true;
            match crtk::decode_string(&b.bytes, b.big_endian) {
                Ok(m) => out.tool_type = Some(m),
                Err(_) => out.undecodable += 1,
            }
        }
        for (reader, dst) in [
            (&mut self.measured_cp, &mut *cp),
            (&mut self.local_measured_cp, &mut *local),
        ] {
            buf.clear();
            reader.drain(&mut buf);
            for b in &buf {
                out.heard = true;
                match PoseStampedMsg::decode(&b.bytes, b.big_endian) {
                    Ok(m) => dst.push(m),
                    Err(_) => out.undecodable += 1,
                }
            }
        }
        out.measured_cp = cp.last().cloned();
        out.local_measured_cp = local.last().cloned();
        self.buf = buf;
    }
}

/// A command the console stand-in received.
#[derive(Debug, Clone, PartialEq)]
pub enum ConsoleCommand {
    MoveJp(JointStateMsg),
    ServoJp(JointStateMsg),
    Hold,
    Free,
    StateCommand(String),
    SetRatio(f64),
    SetRatioV(f64),
    SetRatioA(f64),
}

impl ConsoleCommand {
    /// A command that moves the arm (what a fault test counts).
    pub fn is_motion(&self) -> bool {
        matches!(
            self,
            ConsoleCommand::MoveJp(_) | ConsoleCommand::ServoJp(_) | ConsoleCommand::Free
        )
    }
}

/// The console's side of one arm, for a stand-in.
pub struct ConsoleServer {
    measured_js: Named<Writer>,
    measured_cp: Named<Writer>,
    local_measured_cp: Named<Writer>,
    setpoint_js: Named<Writer>,
    operating_state: Named<Writer>,
    goal_reached: Named<Writer>,
    warning: Named<Writer>,
    error: Named<Writer>,
    status: Named<Writer>,
    tool_type: Named<Writer>,
    ratio: Named<Writer>,
    readers: Vec<(usize, Named<TopicReader>)>,
    ep: Endpoints,
    buf: Vec<RawBody>,
    w: CdrWriter,
}

impl core::fmt::Debug for ConsoleServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ConsoleServer")
            .field("arm", &self.ep.arm)
            .finish_non_exhaustive()
    }
}

const CMD_TOPICS: [(&str, &str); 8] = [
    ("move_jp", dds_type::JOINT_STATE),
    ("servo_jp", dds_type::JOINT_STATE),
    ("hold", dds_type::EMPTY),
    ("free", dds_type::EMPTY),
    ("state_command", dds_type::STRING_STAMPED),
    ("trajectory_j/set_ratio", dds_type::FLOAT64),
    ("trajectory_j/set_ratio_v", dds_type::FLOAT64),
    ("trajectory_j/set_ratio_a", dds_type::FLOAT64),
];

impl ConsoleServer {
    pub fn new(arm: &str, domain: u16, interfaces: &[IpAddr]) -> Result<Self, BridgeError> {
        let ep = Endpoints::new(arm, domain, interfaces)?;
        use ConsoleQos::{Command, Event, State};
        let mut readers = Vec::new();
        for (i, (suffix, ty)) in CMD_TOPICS.iter().enumerate() {
            readers.push((i, ep.reader(suffix, ty, Command)?));
        }
        Ok(Self {
            measured_js: ep.writer("measured_js", dds_type::JOINT_STATE, State)?,
            measured_cp: ep.writer("measured_cp", dds_type::POSE_STAMPED, State)?,
            local_measured_cp: ep.writer("local/measured_cp", dds_type::POSE_STAMPED, State)?,
            setpoint_js: ep.writer("setpoint_js", dds_type::JOINT_STATE, State)?,
            operating_state: ep.writer("operating_state", dds_type::OPERATING_STATE, Event)?,
            goal_reached: ep.writer("goal_reached", dds_type::BOOL, Event)?,
            warning: ep.writer("warning", dds_type::STRING, Event)?,
            error: ep.writer("error", dds_type::STRING, Event)?,
            status: ep.writer("status", dds_type::STRING, Event)?,
            tool_type: ep.writer("tool_type", dds_type::STRING, Event)?,
            ratio: ep.writer("trajectory_j/ratio", dds_type::FLOAT64, Event)?,
            readers,
            ep,
            buf: Vec::new(),
            w: CdrWriter::new(),
        })
    }

    /// Every command received since the last poll, per topic in arrival order; undecodable
    /// ones are counted in the return value.
    pub fn poll(&mut self, out: &mut Vec<ConsoleCommand>) -> u64 {
        let mut bad = 0;
        let mut buf = std::mem::take(&mut self.buf);
        for (i, r) in &mut self.readers {
            buf.clear();
            r.drain(&mut buf);
            for b in &buf {
                let (bytes, be) = (&b.bytes[..], b.big_endian);
                let cmd = match *i {
                    0 => JointStateMsg::decode(bytes, be).map(ConsoleCommand::MoveJp),
                    1 => JointStateMsg::decode(bytes, be).map(ConsoleCommand::ServoJp),
                    2 => Ok(ConsoleCommand::Hold),
                    3 => Ok(ConsoleCommand::Free),
                    4 => crtk::decode_string_stamped(bytes, be).map(ConsoleCommand::StateCommand),
                    5 => crtk::decode_f64(bytes, be).map(ConsoleCommand::SetRatio),
                    6 => crtk::decode_f64(bytes, be).map(ConsoleCommand::SetRatioV),
                    _ => crtk::decode_f64(bytes, be).map(ConsoleCommand::SetRatioA),
                };
                match cmd {
                    Ok(c) => out.push(c),
                    Err(_) => bad += 1,
                }
            }
        }
        self.buf = buf;
        bad
    }

    /// Publishes `measured_js` (and `setpoint_js` when given).
    pub fn publish_js(
        &mut self,
        measured: &JointStateMsg,
        setpoint: Option<&JointStateMsg>,
    ) -> Result<(), BridgeError> {
        self.w.clear();
        measured.encode(&mut self.w);
        self.measured_js.send(&self.w)?;
        if let Some(sp) = setpoint {
            self.w.clear();
            sp.encode(&mut self.w);
            self.setpoint_js.send(&self.w)?;
        }
        Ok(())
    }

    /// Publishes `measured_cp` (base frame) and `local/measured_cp` (RCM frame) of one instant.
    pub fn publish_cp(
        &mut self,
        measured_cp: &PoseStampedMsg,
        local_measured_cp: &PoseStampedMsg,
    ) -> Result<(), BridgeError> {
        self.w.clear();
        local_measured_cp.encode(&mut self.w);
        self.local_measured_cp.send(&self.w)?;
        self.w.clear();
        measured_cp.encode(&mut self.w);
        self.measured_cp.send(&self.w)
    }

    pub fn publish_operating_state(&mut self, s: &OperatingStateMsg) -> Result<(), BridgeError> {
        self.w.clear();
        s.encode(&mut self.w);
        self.operating_state.send(&self.w)
    }

    pub fn publish_goal_reached(&mut self, v: bool) -> Result<(), BridgeError> {
        self.w.clear();
        self.w.bool(v);
        self.goal_reached.send(&self.w)
    }

    /// `trajectory_j/ratio`, as the dVRK 2.x console sends it on each ratio it takes.
    pub fn publish_ratio(&mut self, ratio: f64) -> Result<(), BridgeError> {
        self.w.clear();
        self.w.f64(ratio);
        self.ratio.send(&self.w)
    }

    fn string(&mut self, which: u8, s: &str) -> Result<(), BridgeError> {
        self.w.clear();
        self.w.string(s);
        match which {
            0 => self.warning.send(&self.w),
            1 => self.error.send(&self.w),
            2 => self.status.send(&self.w),
            _ => self.tool_type.send(&self.w),
        }
    }

    pub fn publish_warning(&mut self, s: &str) -> Result<(), BridgeError> {
        self.string(0, s)
    }

    pub fn publish_error(&mut self, s: &str) -> Result<(), BridgeError> {
        self.string(1, s)
    }

    pub fn publish_status(&mut self, s: &str) -> Result<(), BridgeError> {
        self.string(2, s)
    }

    pub fn publish_tool_type(&mut self, s: &str) -> Result<(), BridgeError> {
        self.string(3, s)
    }

    /// A reader of `measured_js` has matched (the console publishes state only then).
    pub fn has_state_reader(&mut self) -> bool {
        self.measured_js.matched()
    }

    /// A reader of `measured_cp` or `local/measured_cp` has matched.
    pub fn has_pose_reader(&mut self) -> bool {
        self.measured_cp.matched() | self.local_measured_cp.matched()
    }
}

/// Waits up to `timeout` for `f` to hold, polling every `step`.
pub fn wait_until(timeout: Duration, step: Duration, mut f: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    loop {
        if f() {
            return true;
        }
        if Instant::now() >= end {
            return false;
        }
        std::thread::sleep(step);
    }
}

/// The current time as a ROS stamp (CLOCK_REALTIME).
pub fn ros_now() -> RosTime {
    now_stamp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_domain_id_is_read_as_ros_2_does() {
        use std::ffi::OsStr;
        let d = |v: &str| domain_id_from(Some(OsStr::new(v)));
        assert_eq!(domain_id_from(None).unwrap(), 0);
        assert_eq!(d("").unwrap(), 0);
        assert_eq!(d("42").unwrap(), 42);
        assert_eq!(d(" 7 ").unwrap(), 7);
        assert_eq!(d("232").unwrap(), 232);
        for bad in ["233", "-1", "+5", "abc", "1e3", "65536"] {
            let e = d(bad).unwrap_err().to_string();
            assert!(
                e.contains("ROS_DOMAIN_ID")
                    && e.contains(&format!("{bad:?}"))
                    && e.contains("0..=232"),
                "{e}"
            );
        }
    }
}
