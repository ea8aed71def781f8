//! The shared-memory side of every bridge: subscribe to the sidecar's compensated topics, wake on
//! its cycle event, and hand every sample to a [`Sink`] in order. A consumer process: nothing
//! here can slow the sidecar's cycle (a full buffer overwrites its oldest sample).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use dvrk_ipc::iceoryx2::node::Node;
use dvrk_ipc::iceoryx2::port::subscriber::Subscriber;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    CompensationStatusV2, JointStateV1, Message, NOMINAL_PERIOD, PoseV1, ServiceNames,
    Subscription, Topic, Update,
};

use crate::convert::{ClockOffset, Decimator};
use crate::error::BridgeError;

/// Where the samples go.
pub trait Sink {
    /// A compensated pose (RCM frame) of a valid cycle.
    fn pose(&mut self, p: &PoseV1) -> Result<(), BridgeError>;
    /// Compensated joints of a valid cycle.
    fn joints(&mut self, js: &JointStateV1) -> Result<(), BridgeError>;
    /// The status of every cycle, valid or not.
    fn status(&mut self, s: &CompensationStatusV2) -> Result<(), BridgeError>;
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
    /// Cycles lost in shared memory before this process took them (its buffer overflowed
    /// because it fell behind by more than the subscriber buffer): the most of any of the three
    /// topics.
    pub shm_seq_gaps: u64,
}

/// Subscriptions to `compensated/measured_cp` (woken by the cycle event),
/// `compensated/measured_js` and `compensated/status` of one arm.
pub struct ShmSource {
    names: ServiceNames,
    pose: Subscription<PoseV1, Service>,
    joints: Subscriber<Service, JointStateV1, ()>,
    status: Subscriber<Service, CompensationStatusV2, ()>,
    poses: Vec<PoseV1>,
    pending_joints: Vec<JointStateV1>,
    pending_status: Vec<CompensationStatusV2>,
    upto_seq: Option<u64>,
    /// First cycle passed on (see [`ShmSource::run`]).
    start_seq: Option<u64>,
    /// Last seq and seqs skipped, of joints and status.
    gaps: [(Option<u64>, u64); 2],
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
    /// Subscribes under the shared-memory prefix `shm_prefix` (e.g. `dvrk/PSM1`) with an
    /// iceoryx2 node named `node_name`.
    pub fn new(shm_prefix: &str, node_name: &str) -> Result<Self, BridgeError> {
        let names = ServiceNames::new(shm_prefix)?;
        let node = dvrk_ipc::create_node::<Service>(node_name, None)?;
        let pose = Subscription::<PoseV1, Service>::new(
            &node,
            &names,
            Topic::CompensatedMeasuredCp,
            NOMINAL_PERIOD,
        )?;
        let joints = subscriber::<JointStateV1>(&node, &names, Topic::CompensatedMeasuredJs)?;
        let status = subscriber::<CompensationStatusV2>(&node, &names, Topic::CompensatedStatus)?;
        Ok(ShmSource {
            names,
            pose,
            joints,
            status,
            poses: Vec::with_capacity(dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE),
            pending_joints: Vec::with_capacity(
                PENDING_CAP + dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
            ),
            pending_status: Vec::with_capacity(
                PENDING_CAP + dvrk_ipc::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
            ),
            upto_seq: None,
            start_seq: None,
            gaps: [(None, 0); 2],
            _node: node,
        })
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
        let mut dec = [Decimator::new(rate_period_ns); 3];
        let mut silent_since: Option<Instant> = None;
        while !stop.load(Ordering::Relaxed) && until.is_none_or(|u| Instant::now() < u) {
            self.poses.clear();
            let poses = &mut self.poses;
            let update =
                self.pose
                    .wait_with(|p| poses.push(*p))
                    .map_err(|source| BridgeError::Wait {
                        service: self
                            .names
                            .topic(Topic::CompensatedMeasuredCp)
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
                        self.upto_seq = None;
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
            // Take the three topics together, before any (slow) sink call, so that a bridge that
            // falls behind loses the same cycles on all of them.
            take_into(
                &self.joints,
                &mut self.pending_joints,
                &self.names,
                Topic::CompensatedMeasuredJs,
                &mut self.gaps[0],
            )?;
            take_into(
                &self.status,
                &mut self.pending_status,
                &self.names,
                Topic::CompensatedStatus,
                &mut self.gaps[1],
            )?;
            // A serve that restarted before the subscription noticed starts its seq at 1 again:
            // drop this wake's samples (they may mix both runs) and align anew.
            if let (Some(p), Some(u)) = (self.poses.first(), self.upto_seq)
                && p.header.seq <= u
            {
                self.start_seq = None;
                self.upto_seq = None;
                self.poses.clear();
                self.pending_joints.clear();
                self.pending_status.clear();
            }
            // The three subscribers connect one after the other, so the first samples of the pose
            // may be older than those of the others: start at the first cycle all three have.
            if self.start_seq.is_none() {
                match (
                    self.poses.first(),
                    self.pending_joints.first(),
                    self.pending_status.first(),
                ) {
                    (Some(p), Some(j), Some(s)) => {
                        self.start_seq = Some(p.header.seq.max(j.header.seq).max(s.header.seq));
                    }
                    _ => {
                        self.poses.clear();
                        self.pending_joints.clear();
                        self.pending_status.clear();
                    }
                }
            }
            let start = self.start_seq.unwrap_or(u64::MAX);
            self.pending_joints.retain(|m| m.header.seq >= start);
            self.pending_status.retain(|m| m.header.seq >= start);
            for p in self.poses.iter().filter(|p| p.header.seq >= start) {
                if !dec[0].accept(p.header.sample_t_ns) {
                    continue;
                }
                if p.header.valid != 0 {
                    sink.pose(p)?;
                } else {
                    stats.invalid_skipped += 1;
                }
            }
            // Joints and status of a cycle are passed on once its pose was taken, so that a run
            // that stops between two drains writes whole cycles only.
            if let Some(p) = self.poses.last().filter(|p| p.header.seq >= start) {
                self.upto_seq = Some(p.header.seq);
            }
            let upto = self.upto_seq;
            let mut err = None;
            release(&mut self.pending_joints, upto, |js| {
                if err.is_some() || !dec[1].accept(js.header.sample_t_ns) {
                    return;
                }
                if js.header.valid != 0 {
                    err = sink.joints(js).err();
                } else {
                    stats.invalid_skipped += 1;
                }
            });
            release(&mut self.pending_status, upto, |st| {
                if err.is_some() {
                    return;
                }
                if !dec[2].accept(st.header.sample_t_ns) {
                    stats.decimated += 1;
                    return;
                }
                err = sink.status(st).err();
                stats.cycles += 1;
            });
            if let Some(e) = err {
                return Err(e);
            }
            stats.shm_seq_gaps = self
                .pose
                .stats()
                .seq_gaps_total
                .max(self.gaps[0].1)
                .max(self.gaps[1].1);
        }
        Ok(stats)
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
    // Normally only the samples of the few cycles newer than the last pose wait here; the cap
    // only matters if the pose topic stops while this one goes on. Dropped samples count as lost.
    let cap = PENDING_CAP;
    if pending.len() > cap {
        let excess = pending.len() - cap;
        pending.drain(..excess);
        *gaps += excess as u64;
    }
    Ok(())
}

/// Calls `f` for the samples of `pending` whose cycle's pose was taken (`seq <= upto`), oldest
/// first, and keeps the others.
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

/// Measures `CLOCK_REALTIME - CLOCK_MONOTONIC`: the tightest of a few back-to-back readings
/// (monotonic, realtime, monotonic), taking the midpoint of the monotonic pair.
pub fn measure_clock_offset() -> Result<ClockOffset, BridgeError> {
    let mut best: Option<(i64, i64)> = None; // (window ns, offset ns)
    for _ in 0..16 {
        let m0 = read_clock(libc::CLOCK_MONOTONIC, "CLOCK_MONOTONIC")?;
        let r = read_clock(libc::CLOCK_REALTIME, "CLOCK_REALTIME")?;
        let m1 = read_clock(libc::CLOCK_MONOTONIC, "CLOCK_MONOTONIC")?;
        let window = m1 - m0;
        let offset = r - (m0 + window / 2);
        if best.is_none_or(|(w, _)| window < w) {
            best = Some((window, offset));
        }
    }
    let (_, offset) = best.unwrap_or((0, 0));
    Ok(ClockOffset {
        realtime_minus_monotonic_ns: offset,
    })
}

fn read_clock(id: libc::clockid_t, name: &'static str) -> Result<i64, BridgeError> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec.
    let rc = unsafe { libc::clock_gettime(id, &mut ts) };
    if rc != 0 {
        return Err(BridgeError::Clock {
            clock: name,
            source: std::io::Error::last_os_error(),
        });
    }
    Ok(ts.tv_sec * 1_000_000_000 + ts.tv_nsec)
}
