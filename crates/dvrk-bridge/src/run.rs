//! One process for every arm of a service: a thread per arm reads its shared memory, the main
//! thread watches the stop flag (and, for DDS, the readers' QoS; for MCAP, writes the file).
//!
//! Why threads: every arm has its own cycle event, and the wait of one arm must not delay another
//! (an arm whose `serve` is stopped would otherwise hold the others for its whole staleness
//! deadline at each turn). A thread per arm keeps each arm's wait, cycle alignment and counters
//! exactly as for one arm, and shares nothing on the per-cycle path:
//! - the ROS 2 bridge: each arm thread owns its DDS writers (one participant for the process);
//! - `record`: each arm thread hands its samples, by value, to the one writer of the file through
//!   a bounded channel allocated once (no allocation, no lock per sample; a full channel makes
//!   the arm wait, and an arm that falls behind by more than its shared-memory buffer loses
//!   cycles, counted as with one arm).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender};
use std::thread::{self, Scope, ScopedJoinHandle};
use std::time::{Duration, Instant};

use dvrk_ipc::{CompensationStatusV4, JawStateV1, JointStateV2, PoseV2};

use crate::convert::{OutTopic, PoseCovariance};
use crate::dds::{DdsOptions, DdsParticipant, IncompatibleReaders};
use crate::error::BridgeError;
use crate::record::McapSink;
use crate::source::{RunStats, Sample, ShmSource, Sink};
use crate::{ArmSpec, RecordOptions, SourceOptions};

/// How often the main thread looks at the stop flag and the DDS events.
const POLL: Duration = Duration::from_millis(100);

/// How long `record` waits for a first message before it gives up: no `serve` publishes any of
/// its arms.
pub const NOTHING_TIMEOUT: Duration = Duration::from_secs(5);

/// Samples in flight between the arms' threads and the MCAP writer: about 2 s of one arm's
/// cycles at 1.5 kHz with every topic recorded (9 per cycle), allocated once.
const RECORD_QUEUE: usize = 32 * 1024;

/// What one arm's thread did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ArmReport {
    /// ROS name of the arm.
    pub arm: String,
    pub shm_prefix: String,
    pub stats: RunStats,
    /// DDS samples or MCAP messages written.
    pub written: u64,
    /// DDS samples not sent because a reliable writer's send window was full (always 0 for
    /// `record`).
    pub dropped: u64,
}

/// Starts `f` for every arm in a thread of its own, named after the arm; `halt` stops them.
fn spawn_arms<'scope, 'env, T, F>(
    scope: &'scope Scope<'scope, 'env>,
    arms: &'env [ArmSpec],
    halt: &'env AtomicBool,
    mut per_arm: impl FnMut(usize) -> F,
) -> Result<Vec<ScopedJoinHandle<'scope, Result<T, BridgeError>>>, BridgeError>
where
    T: Send + 'scope,
    F: FnOnce(&'env ArmSpec) -> Result<T, BridgeError> + Send + 'scope,
{
    let mut handles = Vec::with_capacity(arms.len());
    for (i, a) in arms.iter().enumerate() {
        let f = per_arm(i);
        let h = thread::Builder::new()
            .name(format!("arm {}", a.arm))
            .spawn_scoped(scope, move || f(a))
            .map_err(|source| {
                // The threads already started stop at once.
                halt.store(true, Ordering::Relaxed);
                BridgeError::Thread {
                    arm: a.arm.clone(),
                    source,
                }
            })?;
        handles.push(h);
    }
    Ok(handles)
}

/// Joins every arm's thread; returns their results in order, or the first error.
fn join_arms<T>(
    handles: Vec<ScopedJoinHandle<'_, Result<T, BridgeError>>>,
) -> Result<Vec<T>, BridgeError> {
    let mut out = Vec::with_capacity(handles.len());
    let mut first_err = None;
    for h in handles {
        match h.join() {
            Ok(Ok(r)) => out.push(r),
            Ok(Err(e)) => {
                first_err.get_or_insert(e);
            }
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
    match first_err {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

/// Says, at the end of an arm's run, how many compensated poses went without their
/// `..._with_covariance` message (a status without a finite bound while its pose was valid, or a
/// status lost in shared memory); nothing when none did.
fn log_covariance_skipped(what: &str, a: &ArmSpec, stats: &RunStats) {
    if stats.covariance_skipped > 0 {
        tracing::info!(
            "{what}: {}: {} compensated poses published without their covariance (their \
             cycle's status carried no finite bound, or was lost in shared memory)",
            a.arm,
            stats.covariance_skipped
        );
    }
}

/// Runs the ROS 2 bridge for every arm of `src` until `stop` is raised or an arm fails; reports
/// each reader whose QoS does not match (once per reader and topic).
pub fn run_ros2_bridge(
    src: &SourceOptions,
    dds: &DdsOptions,
    stop: &AtomicBool,
) -> Result<Vec<ArmReport>, BridgeError> {
    let period = src.validate()?;
    let participant = DdsParticipant::new(dds)?;
    let mut sinks = Vec::with_capacity(src.arms.len());
    for a in &src.arms {
        sinks.push(Some(participant.sink(a.encoder())?));
    }
    let mut readers = IncompatibleReaders::new(
        &participant,
        sinks.iter().flatten().flat_map(|s| s.writer_topics()),
    );
    tracing::info!(
        "ros2-bridge: {} -> DDS domain {}, topics rt/<arm>/compensated/..., {} KEEP_LAST {} \
         VOLATILE, {}",
        src.describe_arms(),
        dds.domain,
        dds.qos.name(),
        crate::dds::HISTORY_DEPTH,
        src.rate
    );
    let halt = AtomicBool::new(false);
    let reports = thread::scope(|scope| {
        let handles = spawn_arms(scope, &src.arms, &halt, |i| {
            let sink = sinks[i].take();
            let halt = &halt;
            move |a: &ArmSpec| {
                let Some(mut sink) = sink else {
                    return Err(BridgeError::WriterStopped);
                };
                let mut source = ShmSource::new(&a.shm_prefix, "dvrk-sidecar-ros2-bridge", false)?;
                let stats = source.run(&mut sink, period, halt, None)?;
                log_covariance_skipped("ros2-bridge", a, &stats);
                Ok(ArmReport {
                    arm: a.arm.clone(),
                    shm_prefix: a.shm_prefix.clone(),
                    stats,
                    written: sink.written(),
                    dropped: sink.dropped(),
                })
            }
        })?;
        let mut dds_stopped = false;
        while !stop.load(Ordering::Relaxed) && !handles.iter().any(|h| h.is_finished()) {
            readers.poll();
            if !participant.alive() {
                dds_stopped = true;
                break;
            }
            thread::sleep(POLL);
        }
        halt.store(true, Ordering::Relaxed);
        readers.poll();
        let reports = join_arms(handles)?;
        if dds_stopped {
            return Err(BridgeError::DdsStopped);
        }
        Ok(reports)
    })?;
    Ok(reports)
}

/// Hands an arm's samples to the MCAP writer's thread, by value.
struct ToWriter {
    arm: usize,
    tx: SyncSender<(usize, Sample)>,
}

impl ToWriter {
    fn send(&mut self, s: Sample) -> Result<(), BridgeError> {
        self.tx
            .send((self.arm, s))
            .map_err(|_| BridgeError::WriterStopped)
    }
}

impl Sink for ToWriter {
    fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError> {
        self.send(Sample::Pose(topic, *p))
    }
    fn pose_with_covariance(
        &mut self,
        topic: OutTopic,
        p: &PoseV2,
        cov: &PoseCovariance,
    ) -> Result<(), BridgeError> {
        self.send(Sample::PoseWithCovariance(topic, *p, *cov))
    }
    fn joints(&mut self, topic: OutTopic, js: &JointStateV2) -> Result<(), BridgeError> {
        self.send(Sample::Joints(topic, *js))
    }
    fn jaw(&mut self, topic: OutTopic, jaw: &JawStateV1) -> Result<(), BridgeError> {
        self.send(Sample::Jaw(topic, *jaw))
    }
    fn status(&mut self, s: &CompensationStatusV4) -> Result<(), BridgeError> {
        self.send(Sample::Status(*s))
    }
}

/// Records every arm of `src` to one MCAP file until `stop` is raised or `--seconds` pass;
/// returns each arm's counters and messages.
///
/// Nothing to record is an error ([`BridgeError::NothingRecorded`]): no message within
/// [`NOTHING_TIMEOUT`], or a run that ends with none. Then the file, which this run created and
/// which holds no message, is removed.
pub fn run_record(
    src: &SourceOptions,
    rec: &RecordOptions,
    stop: &AtomicBool,
) -> Result<Vec<ArmReport>, BridgeError> {
    let period = src.validate()?;
    let started = Instant::now();
    let until = match rec.seconds {
        None => None,
        Some(s) if s.is_finite() && s > 0.0 && s < 1e9 => {
            Some(started + Duration::from_secs_f64(s))
        }
        Some(s) => {
            return Err(BridgeError::InvalidArgument {
                what: "--seconds",
                value: s.to_string(),
                reason: "must be a finite number of seconds above 0",
            });
        }
    };
    let raw = !rec.compensated_only;
    let encoders = src.arms.iter().map(ArmSpec::encoder).collect();
    let mut sink = McapSink::create(encoders, &rec.out, raw)?;
    tracing::info!(
        "record: {} -> {}, {}",
        src.describe_arms(),
        rec.out.display(),
        src.rate
    );
    let halt = AtomicBool::new(false);
    let (tx, rx) = mpsc::sync_channel::<(usize, Sample)>(RECORD_QUEUE);
    let mut write_err = None;
    let arms = thread::scope(|scope| {
        let handles = spawn_arms(scope, &src.arms, &halt, |i| {
            let mut to_writer = ToWriter {
                arm: i,
                tx: tx.clone(),
            };
            let halt = &halt;
            move |a: &ArmSpec| {
                let mut source = ShmSource::new(&a.shm_prefix, "dvrk-sidecar-record", raw)?;
                let stats = source.run(&mut to_writer, period, halt, None)?;
                log_covariance_skipped("record", a, &stats);
                Ok((a, stats))
            }
        });
        // Only the arms' threads hold a sender now: the channel ends when the last one ends.
        drop(tx);
        let handles = match handles {
            Ok(h) => h,
            Err(e) => {
                // The threads started see the halt; take what they send until they end.
                while rx.recv().is_ok() {}
                return Err(e);
            }
        };
        let mut halted = false;
        loop {
            match rx.recv_timeout(POLL) {
                Ok((arm, s)) => {
                    if write_err.is_none()
                        && let Err(e) = sink.write(arm, &s)
                    {
                        // The arms go on until they see the halt; what they send is dropped.
                        write_err = Some(e);
                        halt.store(true, Ordering::Relaxed);
                        halted = true;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            if !halted {
                let now = Instant::now();
                let nothing = sink.written() == 0 && now.duration_since(started) >= NOTHING_TIMEOUT;
                if stop.load(Ordering::Relaxed)
                    || until.is_some_and(|u| now >= u)
                    || nothing
                    || handles.iter().any(|h| h.is_finished())
                {
                    halt.store(true, Ordering::Relaxed);
                    halted = true;
                }
            }
        }
        join_arms(handles)
    });
    if sink.written() == 0 {
        // Nothing recorded: the file this run created holds no message and goes, whatever
        // ended the run.
        let waited = started.elapsed();
        let removed = match sink.discard() {
            Ok(true) => format!(
                "; {}, which held no message, was removed",
                rec.out.display()
            ),
            Ok(false) => String::new(),
            Err(e) => format!("; {} could not be removed: {e}", rec.out.display()),
        };
        if let Some(e) = write_err {
            return Err(e);
        }
        arms?;
        return Err(BridgeError::NothingRecorded {
            arms: src.describe_arms(),
            waited_s: waited.as_secs_f64(),
            removed,
        });
    }
    let result = match (write_err, arms) {
        (Some(e), _) | (None, Err(e)) => Err(e),
        (None, Ok(arms)) => Ok(arms),
    };
    let arms = match result {
        Ok(arms) => arms,
        Err(e) => {
            // Nothing recorded is deleted: the index is written if the file still takes it
            // (an error of the source), otherwise (a full disk) the file keeps every chunk
            // closed before the error.
            if let Err(f) = sink.finish() {
                tracing::warn!("record: no index written ({f}); the closed chunks are kept");
            }
            return Err(e);
        }
    };
    let reports = arms
        .into_iter()
        .enumerate()
        .map(|(i, (a, stats))| ArmReport {
            arm: a.arm.clone(),
            shm_prefix: a.shm_prefix.clone(),
            stats,
            written: sink.written_of(i),
            dropped: 0,
        })
        .collect();
    sink.finish()?;
    Ok(reports)
}
