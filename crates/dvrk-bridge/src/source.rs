//! The shared-memory side of every bridge: subscribe to the sidecar's compensated topics, wake on
//! its cycle event, and hand every sample to a [`Sink`] in order. A consumer process: nothing
//! here can slow the sidecar's cycle (a full buffer overwrites its oldest sample).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::port::subscriber::Subscriber;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    CompensationStatusV4, JawStateV1, JointStateV2, Message, NOMINAL_PERIOD, PoseV2, ServiceNames,
    Subscription, Topic, Update,
};

use crate::convert::{Decimator, OutTopic, PoseCovariance};
use crate::error::BridgeError;

/// Where the samples go.
pub trait Sink {
    /// A pose of a valid cycle: `topic` is [`OutTopic::LocalMeasuredCp`] (RCM frame),
    /// [`OutTopic::MeasuredCp`] (base frame) or their raw counterparts.
    fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError>;
    /// A compensated pose with the covariance of its error, from the status of the same cycle:
    /// `topic` is [`OutTopic::LocalMeasuredCpWithCovariance`] or
    /// [`OutTopic::MeasuredCpWithCovariance`]. Passed right after the pose itself, for the
    /// same cycles (valid ones, kept by the same decimation) whose status carries a finite bound.
    fn pose_with_covariance(
        &mut self,
        topic: OutTopic,
        p: &PoseV2,
        cov: &PoseCovariance,
    ) -> Result<(), BridgeError>;
    /// Joints of a valid cycle: `topic` is [`OutTopic::MeasuredJs`] (compensated) or
    /// [`OutTopic::RawMeasuredJs`].
    fn joints(&mut self, topic: OutTopic, js: &JointStateV2) -> Result<(), BridgeError>;
    /// The jaw of a valid cycle: [`OutTopic::JawMeasuredJs`] or [`OutTopic::RawJawMeasuredJs`].
    fn jaw(&mut self, topic: OutTopic, jaw: &JawStateV1) -> Result<(), BridgeError>;
    /// The status of every cycle, valid or not.
    fn status(&mut self, s: &CompensationStatusV4) -> Result<(), BridgeError>;
}

/// One sample on its way to a [`Sink`], by value: what a thread that reads one arm hands to the
/// thread that writes every arm's (see [`crate::run_record`]). Fixed size, no heap.
#[derive(Debug, Clone, Copy)]
pub enum Sample {
    Pose(OutTopic, PoseV2),
    PoseWithCovariance(OutTopic, PoseV2, PoseCovariance),
    Joints(OutTopic, JointStateV2),
    Jaw(OutTopic, JawStateV1),
    Status(CompensationStatusV4),
}

impl Sample {
    /// Passes the sample to the [`Sink`] method of its kind.
    pub fn deliver<K: Sink + ?Sized>(&self, sink: &mut K) -> Result<(), BridgeError> {
        match self {
            Sample::Pose(t, p) => sink.pose(*t, p),
            Sample::PoseWithCovariance(t, p, c) => sink.pose_with_covariance(*t, p, c),
            Sample::Joints(t, js) => sink.joints(*t, js),
            Sample::Jaw(t, jaw) => sink.jaw(*t, jaw),
            Sample::Status(s) => sink.status(s),
        }
    }
}

/// Silence after which the run logs that no samples arrive (once per silence).
const SILENCE_REPORT_NS: u64 = 1_000_000_000;

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RunStats {
    /// Cycles whose status was passed on.
    pub cycles: u64,
    /// Poses and joint states not passed on because their cycle was invalid (`valid = 0`: the
    /// sidecar holds the last good values; the status says why).
    pub invalid_skipped: u64,
    /// Cycles left out by `--rate`.
    pub decimated: u64,
    /// Compensated poses passed on without their `..._with_covariance` message: the status of
    /// their cycle carried no finite bound, or was lost in shared memory.
    pub covariance_skipped: u64,
    /// Cycles lost in shared memory before this process took them (its buffer overflowed
    /// because it fell behind by more than the subscriber buffer): the most of any of the three
    /// topics.
    pub shm_seq_gaps: u64,
}

/// One topic taken without waking: its subscriber and the samples waiting for the rest of their
/// cycle.
struct Pending<T: Message> {
    topic: Topic,
    sub: Subscriber<Service, T, ()>,
    items: Vec<T>,
    /// Last seq seen and seqs skipped.
    gaps: (Option<u64>, u64),
}

impl<T: Message> Pending<T> {
    fn new(node: &Node<Service>, names: &ServiceNames, topic: Topic) -> Result<Self, BridgeError> {
        Ok(Pending {
            topic,
            sub: subscriber::<T>(node, names, topic)?,
            items: Vec::with_capacity(PENDING_CAP + dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE),
            gaps: (None, 0),
        })
    }

    fn take(&mut self, names: &ServiceNames) -> Result<(), BridgeError> {
        take_into(
            &self.sub,
            &mut self.items,
            names,
            self.topic,
            &mut self.gaps,
        )
    }

    fn first_seq(&self) -> Option<u64> {
        self.items.first().map(|m| m.header().seq)
    }

    fn keep_from(&mut self, start: u64) {
        self.items.retain(|m| m.header().seq >= start);
    }
}

/// The four topics of one arm state (compensated or uncompensated), taken without waking.
struct StateSubs {
    local: Pending<PoseV2>,
    base: Pending<PoseV2>,
    joints: Pending<JointStateV2>,
    jaw: Pending<JawStateV1>,
    /// Where each of the four goes, in the order above.
    out: [OutTopic; 4],
}

impl StateSubs {
    fn new(
        node: &Node<Service>,
        names: &ServiceNames,
        compensated: bool,
    ) -> Result<Self, BridgeError> {
        let pick = |raw: Topic, comp: Topic| if compensated { comp } else { raw };
        Ok(StateSubs {
            local: Pending::new(
                node,
                names,
                pick(Topic::LocalMeasuredCp, Topic::CompensatedLocalMeasuredCp),
            )?,
            base: Pending::new(
                node,
                names,
                pick(Topic::MeasuredCp, Topic::CompensatedMeasuredCp),
            )?,
            joints: Pending::new(
                node,
                names,
                pick(Topic::MeasuredJs, Topic::CompensatedMeasuredJs),
            )?,
            jaw: Pending::new(
                node,
                names,
                pick(Topic::JawMeasuredJs, Topic::CompensatedJawMeasuredJs),
            )?,
            out: if compensated {
                [
                    OutTopic::LocalMeasuredCp,
                    OutTopic::MeasuredCp,
                    OutTopic::MeasuredJs,
                    OutTopic::JawMeasuredJs,
                ]
            } else {
                [
                    OutTopic::RawLocalMeasuredCp,
                    OutTopic::RawMeasuredCp,
                    OutTopic::RawMeasuredJs,
                    OutTopic::RawJawMeasuredJs,
                ]
            },
        })
    }

    fn take(&mut self, names: &ServiceNames) -> Result<(), BridgeError> {
        self.local.take(names)?;
        self.base.take(names)?;
        self.joints.take(names)?;
        self.jaw.take(names)
    }

    fn first_seqs(&self) -> [Option<u64>; 4] {
        [
            self.local.first_seq(),
            self.base.first_seq(),
            self.joints.first_seq(),
            self.jaw.first_seq(),
        ]
    }

    /// The newest seq each topic brought.
    fn last_seqs(&self) -> [Option<u64>; 4] {
        [
            self.local.gaps.0,
            self.base.gaps.0,
            self.joints.gaps.0,
            self.jaw.gaps.0,
        ]
    }

    fn keep_from(&mut self, start: u64) {
        self.local.keep_from(start);
        self.base.keep_from(start);
        self.joints.keep_from(start);
        self.jaw.keep_from(start);
    }

    fn clear(&mut self) {
        self.local.items.clear();
        self.base.items.clear();
        self.joints.items.clear();
        self.jaw.items.clear();
    }

    fn gaps(&self) -> u64 {
        [
            self.local.gaps.1,
            self.base.gaps.1,
            self.joints.gaps.1,
            self.jaw.gaps.1,
        ]
        .into_iter()
        .max()
        .unwrap_or(0)
    }

    /// Passes the released samples of the four topics to `sink`, poses first, through their
    /// decimators `dec` (same order). A compensated pose is followed by its covariance variant,
    /// from the status of the same cycle among `statuses` (the statuses waiting for release,
    /// in seq order).
    fn pass<K: Sink>(
        &mut self,
        out: &mut Outlet<'_>,
        dec: &mut [Decimator; 4],
        statuses: &[CompensationStatusV4],
        sink: &mut K,
    ) {
        let [t0, t1, t2, t3] = self.out;
        let [d0, d1, d2, d3] = dec;
        let mut skipped = 0;
        let mut pose = |t: OutTopic, p: &PoseV2| {
            sink.pose(t, p)?;
            let Some(tc) = t.with_covariance() else {
                return Ok(());
            };
            match covariance_of(p, statuses) {
                Some(cov) => sink.pose_with_covariance(tc, p, &cov),
                None => {
                    skipped += 1;
                    Ok(())
                }
            }
        };
        out.pass(&mut self.local.items, d0, |p| pose(t0, p));
        out.pass(&mut self.base.items, d1, |p| pose(t1, p));
        out.stats.covariance_skipped += skipped;
        out.pass(&mut self.joints.items, d2, |js| sink.joints(t2, js));
        out.pass(&mut self.jaw.items, d3, |jaw| sink.jaw(t3, jaw));
    }
}

/// Subscriptions to the sidecar's topics of one arm: `compensated/status`, the last message of
/// a cycle (woken by the event notified after it, so a wake normally finds whole cycles) and,
/// taken at the same wake, `compensated/local/measured_cp`, `compensated/measured_cp`,
/// `compensated/measured_js`, `compensated/jaw/measured_js` and, when asked for, the four
/// uncompensated topics.
pub struct ShmSource {
    names: ServiceNames,
    compensated: StateSubs,
    status: Subscription<CompensationStatusV4, Service>,
    raw: Option<StateSubs>,
    /// Statuses waiting for the rest of their cycle.
    statuses: Vec<CompensationStatusV4>,
    /// Seq of the newest status taken.
    last_status_seq: Option<u64>,
    /// Statuses dropped because the other topics stopped bringing their cycles.
    statuses_dropped: u64,
    /// First cycle passed on (see [`ShmSource::run`]).
    start_seq: Option<u64>,
    // Kept last: the ports above borrow nothing from it, but are dropped before it.
    _node: Node<Service>,
}

impl core::fmt::Debug for ShmSource {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ShmSource")
            .field("prefix", &self.names.prefix())
            .finish_non_exhaustive()
    }
}

fn subscriber<T: Message>(
    node: &Node<Service>,
    names: &ServiceNames,
    topic: Topic,
) -> Result<Subscriber<Service, T, ()>, BridgeError> {
    dvrk_ipc::open_topic::<T, Service>(node, names, topic)?
        .subscriber_builder()
        .create()
        .map_err(|source| BridgeError::Subscribe {
            service: names.topic(topic).as_str().to_owned(),
            source,
        })
}

impl ShmSource {
    /// Subscribes under the shared-memory prefix `shm_prefix` (e.g. `PSM1`) with an iceoryx2
    /// node named `node_name`; `raw`: also the uncompensated topics ([`OutTopic::RAW`]).
    pub fn new(shm_prefix: &str, node_name: &str, raw: bool) -> Result<Self, BridgeError> {
        let names = ServiceNames::new(shm_prefix)?;
        let node = dvrk_ipc::create_node::<Service>(node_name, None)?;
        let status = Subscription::<CompensationStatusV4, Service>::new(
            &node,
            &names,
            Topic::CompensatedStatus,
            NOMINAL_PERIOD,
        )?;
        Ok(ShmSource {
            compensated: StateSubs::new(&node, &names, true)?,
            raw: if raw {
                Some(StateSubs::new(&node, &names, false)?)
            } else {
                None
            },
            names,
            status,
            statuses: Vec::with_capacity(PENDING_CAP + dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE),
            last_status_seq: None,
            statuses_dropped: 0,
            start_seq: None,
            _node: node,
        })
    }

    fn clear_pending(&mut self) {
        self.statuses.clear();
        self.compensated.clear();
        if let Some(r) = &mut self.raw {
            r.clear();
        }
    }

    /// The newest cycle that every topic has brought or gone past (the least of their newest
    /// seqs), if each has brought one.
    fn complete_upto(&self) -> Option<u64> {
        let raw = self.raw.as_ref().map(StateSubs::last_seqs);
        self.compensated
            .last_seqs()
            .into_iter()
            .chain([self.last_status_seq])
            .chain(raw.into_iter().flatten())
            .try_fold(u64::MAX, |m, s| s.map(|s| m.min(s)))
    }

    /// Passes every cycle to `sink` until `stop` is raised or `until` passes. `rate_period_ns`
    /// decimates (see [`Decimator`]).
    pub fn run<K: Sink>(
        &mut self,
        sink: &mut K,
        rate_period_ns: Option<u64>,
        stop: &AtomicBool,
        until: Option<Instant>,
    ) -> Result<RunStats, BridgeError> {
        let mut stats = RunStats::default();
        // One decimator per published topic.
        let mut dec_compensated = [Decimator::new(rate_period_ns); 4];
        let mut dec_raw = dec_compensated;
        let mut dec_status = Decimator::new(rate_period_ns);
        let mut silent_since: Option<Instant> = None;
        while !stop.load(Ordering::Relaxed) && until.is_none_or(|u| Instant::now() < u) {
            let before = self.statuses.len();
            let statuses = &mut self.statuses;
            let update = self
                .status
                .wait_with(|st| statuses.push(*st))
                .map_err(|source| BridgeError::Wait {
                    service: self
                        .names
                        .topic(Topic::CompensatedStatus)
                        .as_str()
                        .to_owned(),
                    source,
                })?;
            match update {
                Update::Fresh(_) => {
                    if let Some(t) = silent_since.take() {
                        tracing::info!(
                            "{}: samples again after {:.1} s",
                            self.names.prefix(),
                            t.elapsed().as_secs_f64()
                        );
                    }
                }
                Update::Stale { since_ns } if since_ns < SILENCE_REPORT_NS => {}
                Update::Stale { .. } | Update::Terminated => {
                    if update == Update::Terminated {
                        // A new serve starts its seq at 1 again: align anew.
                        self.start_seq = None;
                        self.last_status_seq = None;
                    }
                    if silent_since.is_none() {
                        tracing::warn!(
                            "{}: no samples for 1 s (is `dvrk-sidecar serve` running?)",
                            self.names.prefix()
                        );
                        silent_since = Some(Instant::now());
                    }
                }
                Update::Interrupted => {}
            }
            // Take all topics together, before any (slow) sink call, so that a bridge that falls
            // behind loses the same cycles on all of them.
            self.compensated.take(&self.names)?;
            if let Some(r) = &mut self.raw {
                r.take(&self.names)?;
            }
            // A serve that restarted before the subscription noticed starts its seq at 1 again:
            // drop this wake's samples (they may mix both runs) and align anew.
            if let (Some(st), Some(last)) = (self.statuses.get(before), self.last_status_seq)
                && st.header.seq <= last
            {
                self.start_seq = None;
                self.clear_pending();
            }
            if let Some(st) = self.statuses.last() {
                self.last_status_seq = Some(st.header.seq);
            }
            cap_pending(&mut self.statuses, &mut self.statuses_dropped);
            // The subscribers connect one after the other, so the first samples of one topic
            // may be older than those of the others: start at the first cycle all of them have.
            if self.start_seq.is_none() {
                let [f0, f1, f2, f3] = self.compensated.first_seqs();
                let firsts = [
                    f0,
                    f1,
                    f2,
                    f3,
                    self.statuses.first().map(|st| st.header.seq),
                ];
                let raw_firsts = self.raw.as_ref().map(StateSubs::first_seqs);
                let raw_ok = raw_firsts.is_none_or(|f| f.iter().all(Option::is_some));
                if firsts.iter().all(Option::is_some) && raw_ok {
                    self.start_seq = firsts
                        .iter()
                        .chain(raw_firsts.iter().flatten())
                        .flatten()
                        .max()
                        .copied();
                } else {
                    self.clear_pending();
                }
            }
            let start = self.start_seq.unwrap_or(u64::MAX);
            self.statuses.retain(|st| st.header.seq >= start);
            self.compensated.keep_from(start);
            if let Some(r) = &mut self.raw {
                r.keep_from(start);
            }
            // A cycle is passed on once every topic has brought its message (or gone past it,
            // when shared memory lost it): a wake can come while the publisher is still sending
            // the cycle, and a run that stops between two wakes must write whole cycles only.
            let upto = self.complete_upto();
            let mut err = None;
            let mut out = Outlet {
                upto,
                stats: &mut stats,
                err: &mut err,
            };
            self.compensated
                .pass(&mut out, &mut dec_compensated, &self.statuses, sink);
            if let Some(r) = &mut self.raw {
                r.pass(&mut out, &mut dec_raw, &self.statuses, sink);
            }
            release(&mut self.statuses, upto, |st| {
                if err.is_some() {
                    return;
                }
                if !dec_status.accept(st.header.sample_t_ns) {
                    stats.decimated += 1;
                    return;
                }
                err = sink.status(st).err();
                stats.cycles += 1;
            });
            if let Some(e) = err {
                return Err(e);
            }
            stats.shm_seq_gaps = [
                self.compensated.gaps(),
                self.status.stats().seq_gaps_total + self.statuses_dropped,
                self.raw.as_ref().map_or(0, StateSubs::gaps),
            ]
            .into_iter()
            .max()
            .unwrap_or(0);
        }
        Ok(stats)
    }
}

/// The covariance of the pose `p` from the status of its cycle (same seq and sample time) among
/// `statuses` (in seq order), if that status is there and carries a finite bound.
fn covariance_of(p: &PoseV2, statuses: &[CompensationStatusV4]) -> Option<PoseCovariance> {
    let i = statuses
        .binary_search_by_key(&p.header.seq, |s| s.header.seq)
        .ok()?;
    let st = &statuses[i];
    if st.header.sample_t_ns != p.header.sample_t_ns {
        return None;
    }
    PoseCovariance::from_status(st)
}

/// Where the samples of one wake go once their cycle is complete: the cycle limit,
/// the run's counters and the first sink error (after which nothing more is passed on).
struct Outlet<'a> {
    upto: Option<u64>,
    stats: &'a mut RunStats,
    err: &'a mut Option<BridgeError>,
}

impl Outlet<'_> {
    /// Passes the released samples of `pending` that `dec` keeps to `f` if they are valid;
    /// counts the invalid ones (not published: the status says why).
    fn pass<T: Message>(
        &mut self,
        pending: &mut Vec<T>,
        dec: &mut Decimator,
        mut f: impl FnMut(&T) -> Result<(), BridgeError>,
    ) {
        release(pending, self.upto, |m| {
            let h = m.header();
            if self.err.is_some() || !dec.accept(h.sample_t_ns) {
                return;
            }
            if h.valid != 0 {
                *self.err = f(m).err();
            } else {
                self.stats.invalid_skipped += 1;
            }
        });
    }
}

/// Most samples of one topic held back waiting for their cycle's pose: 4 shared-memory buffers.
const PENDING_CAP: usize = 4 * dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE;

/// Takes every buffered sample of `sub` into `pending`, keeping at most [`PENDING_CAP`] (the
/// oldest go first, as in shared memory).
/// `gaps` counts the seqs skipped between consecutive samples (`last` is the previous seq).
fn take_into<T: Message>(
    sub: &Subscriber<Service, T, ()>,
    pending: &mut Vec<T>,
    names: &ServiceNames,
    topic: Topic,
    (last, gaps): &mut (Option<u64>, u64),
) -> Result<(), BridgeError> {
    while let Some(s) = sub.receive().map_err(|source| BridgeError::Receive {
        service: names.topic(topic).as_str().to_owned(),
        source,
    })? {
        let v: T = *s;
        drop(s);
        let seq = v.header().seq;
        if let Some(prev) = *last
            && seq > prev + 1
        {
            *gaps += seq - prev - 1;
        }
        *last = Some(seq);
        pending.push(v);
    }
    cap_pending(pending, gaps);
    Ok(())
}

/// Keeps at most [`PENDING_CAP`] of `pending`, dropping the oldest and counting them in
/// `dropped`. Normally only the samples of the cycle being published wait; the cap only matters
/// if one topic stops while the others go on. Dropped samples count as lost.
fn cap_pending<T>(pending: &mut Vec<T>, dropped: &mut u64) {
    if pending.len() > PENDING_CAP {
        let excess = pending.len() - PENDING_CAP;
        pending.drain(..excess);
        *dropped += excess as u64;
    }
}

/// Calls `f` for the samples of `pending` whose cycle is complete (`seq <= upto`), oldest first,
/// and keeps the others.
fn release<T: Message>(pending: &mut Vec<T>, upto: Option<u64>, mut f: impl FnMut(&T)) {
    let Some(upto) = upto else { return };
    pending.retain(|m| {
        if m.header().seq <= upto {
            f(m);
            false
        } else {
            true
        }
    });
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, HashMap};
    use std::time::Duration;

    use dvrk_ipc::iceoryx2::port::notifier::Notifier;
    use dvrk_ipc::iceoryx2::port::publisher::Publisher;
    use dvrk_ipc::{PUBLISH_ORDER, Topic};

    use super::*;

    /// The seqs each topic reached the sink with.
    #[derive(Default)]
    struct Seen(BTreeMap<String, Vec<u64>>);

    impl Seen {
        fn add(&mut self, topic: OutTopic, seq: u64) -> Result<(), BridgeError> {
            self.0.entry(format!("{topic:?}")).or_default().push(seq);
            Ok(())
        }
    }

    impl Sink for Seen {
        fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError> {
            self.add(topic, p.header.seq)
        }
        fn pose_with_covariance(
            &mut self,
            topic: OutTopic,
            p: &PoseV2,
            cov: &PoseCovariance,
        ) -> Result<(), BridgeError> {
            // The test's statuses carry tip_bound_m = seq mm.
            let want = PoseCovariance::from_status(&status_of(p.header.seq)).unwrap();
            assert_eq!(
                cov, &want,
                "{topic:?} {}: not its cycle's bound",
                p.header.seq
            );
            self.add(topic, p.header.seq)
        }
        fn joints(&mut self, topic: OutTopic, js: &JointStateV2) -> Result<(), BridgeError> {
            self.add(topic, js.header.seq)
        }
        fn jaw(&mut self, topic: OutTopic, jaw: &JawStateV1) -> Result<(), BridgeError> {
            self.add(topic, jaw.header.seq)
        }
        fn status(&mut self, s: &CompensationStatusV4) -> Result<(), BridgeError> {
            self.add(OutTopic::Status, s.header.seq)
        }
    }

    fn publisher<T: Message>(
        node: &Node<Service>,
        names: &ServiceNames,
        topic: Topic,
    ) -> Publisher<Service, T, ()> {
        dvrk_ipc::open_topic::<T, Service>(node, names, topic)
            .unwrap()
            .publisher_builder()
            .create()
            .unwrap()
    }

    fn send<T: Message>(p: &Publisher<Service, T, ()>, seq: u64) {
        let mut m = T::default();
        let h = m.header_mut();
        h.seq = seq;
        h.valid = 1;
        h.sample_t_ns = seq * 666_667;
        p.send_copy(m).unwrap();
    }

    /// The status the test sends for cycle `seq`: a bound of `seq` mm (`bound_rad` `seq` mrad
    /// each), NaN for cycle 2 (a cycle without a usable bound).
    fn status_of(seq: u64) -> CompensationStatusV4 {
        let mut m = CompensationStatusV4::default();
        m.header.seq = seq;
        m.header.valid = 1;
        m.header.sample_t_ns = seq * 666_667;
        let b = if seq == 2 {
            f64::NAN
        } else {
            seq as f64 * 1e-3
        };
        m.tip_bound_m = b;
        m.bound_rad = [b; 2];
        m
    }

    /// A publisher that can stop in the middle of a cycle, as `serve` can be seen doing by a
    /// consumer woken by the previous cycle's event.
    struct HalfPublisher {
        poses: HashMap<Topic, Publisher<Service, PoseV2, ()>>,
        joints: HashMap<Topic, Publisher<Service, JointStateV2, ()>>,
        jaws: HashMap<Topic, Publisher<Service, JawStateV1, ()>>,
        status: Publisher<Service, CompensationStatusV4, ()>,
        cycle: Notifier<Service>,
        _node: Node<Service>,
    }

    impl HalfPublisher {
        fn new(names: &ServiceNames) -> Self {
            let node = dvrk_ipc::create_node::<Service>("bridge-source-test-pub", None).unwrap();
            let mut p = HalfPublisher {
                poses: Default::default(),
                joints: Default::default(),
                jaws: Default::default(),
                status: publisher(&node, names, Topic::CompensatedStatus),
                cycle: dvrk_ipc::open_cycle_event::<Service>(&node, names)
                    .unwrap()
                    .notifier_builder()
                    .create()
                    .unwrap(),
                _node: node,
            };
            for t in PUBLISH_ORDER {
                if t.carries::<PoseV2>() {
                    p.poses.insert(t, publisher(&p._node, names, t));
                } else if t.carries::<JointStateV2>() {
                    p.joints.insert(t, publisher(&p._node, names, t));
                } else if t.carries::<JawStateV1>() {
                    p.jaws.insert(t, publisher(&p._node, names, t));
                }
            }
            p
        }

        /// Sends the topics `PUBLISH_ORDER[from..to]` of cycle `seq`, and the cycle event if
        /// `notify`.
        fn send(&self, seq: u64, from: usize, to: usize, notify: bool) {
            for t in &PUBLISH_ORDER[from..to] {
                if let Some(p) = self.poses.get(t) {
                    send(p, seq);
                } else if let Some(p) = self.joints.get(t) {
                    send(p, seq);
                } else if let Some(p) = self.jaws.get(t) {
                    send(p, seq);
                } else {
                    self.status.send_copy(status_of(seq)).unwrap();
                }
            }
            if notify {
                self.cycle.notify().unwrap();
            }
        }
    }

    #[test]
    fn a_cycle_is_passed_on_only_once_all_its_topics_arrived() {
        let prefix = format!("BRIDGETEST{}", std::process::id());
        let names = ServiceNames::new(&prefix).unwrap();
        let mut source = ShmSource::new(&prefix, "bridge-source-test", true).unwrap();
        let publisher = HalfPublisher::new(&names);
        let n = PUBLISH_ORDER.len();
        for seq in 1..=3 {
            publisher.send(seq, 0, n, true);
        }
        // Cycle 4 stops after its first message (the compensated local pose), as a consumer
        // woken by cycle 3's event can find it; then the run ends.
        publisher.send(4, 0, 1, false);
        let stop = AtomicBool::new(false);
        let mut seen = Seen::default();
        let run = |source: &mut ShmSource, seen: &mut Seen| {
            let until = Instant::now() + Duration::from_millis(300);
            source.run(seen, None, &stop, Some(until)).unwrap()
        };
        let stats = run(&mut source, &mut seen);
        // Every topic, and the two compensated poses with their covariance.
        assert_eq!(
            seen.0.len(),
            n + 2,
            "every topic reached the sink: {:?}",
            seen.0
        );
        for (topic, seqs) in &seen.0 {
            if topic.ends_with("WithCovariance") {
                // Cycle 2's status has no finite bound: its poses go without covariance.
                assert_eq!(seqs, &[1, 3], "{topic}: with their own cycle's bound only");
            } else {
                assert_eq!(seqs, &[1, 2, 3], "{topic}: whole cycles only");
            }
        }
        assert_eq!(stats.cycles, 3);
        assert_eq!(stats.shm_seq_gaps, 0);
        assert_eq!(stats.covariance_skipped, 2);

        // The rest of cycle 4 arrives: the next run passes it on, its pose included, on every
        // topic.
        publisher.send(4, 1, n, true);
        let stats = run(&mut source, &mut seen);
        for (topic, seqs) in &seen.0 {
            if topic.ends_with("WithCovariance") {
                assert_eq!(seqs, &[1, 3, 4], "{topic}");
            } else {
                assert_eq!(seqs, &[1, 2, 3, 4], "{topic}");
            }
        }
        assert_eq!(stats.cycles, 1);
        assert_eq!(stats.covariance_skipped, 0);
    }
}
