//! The subscribing side: wait for the next sample with the consumer's choice of strategy
//! ([`WaitStrategy`]), drain, return the newest sample, and notice a silent or vanished publisher.

use core::time::Duration;

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::SynchronousMultiplexing;
use iceoryx2::service::Service;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

use crate::error::{IpcError, SubscriptionError};
use crate::msg::Message;
use crate::names::{ServiceNames, Topic};
use crate::predict::Predictor;
use crate::services::{open_event, open_topic};
use crate::sys::{self, Ready, TimerFd};
use crate::wake::{WakeWord, Woken, open_event_word};

/// Periods without a sample after which [`Subscription::wait`] reports staleness, unless that is
/// shorter than [`MIN_DEFAULT_DEADLINE`].
pub const DEADLINE_PERIODS: u32 = 3;

/// The least default staleness deadline. A loaded PC delays the sidecar's cycle by several
/// milliseconds now and then (cycle maxima of 1.4-5.3 ms were seen with other builds running);
/// a 2 ms deadline reported those as silences. A consumer that needs a tighter or looser
/// deadline sets [`SubscribeOptions::deadline`].
pub const MIN_DEFAULT_DEADLINE: Duration = Duration::from_millis(10);

/// Least time between two attempts to reap a dead publisher while stale (each attempt lists the
/// service's nodes on the file system).
pub const DEAD_PUBLISHER_CHECK_INTERVAL: Duration = Duration::from_millis(200);

/// Nominal publishing period of the sidecar (1500 Hz, like the dVRK console).
pub const NOMINAL_PERIOD: Duration = Duration::from_nanos(666_667);

/// The environment variable that turns off (`0`) the short time slice that event and predictive
/// subscriptions ask for their thread ([`Subscription::short_slice`]); `1` or unset: on. Read
/// when a subscription is created, by the Rust and both Python clients; any other value is
/// refused there ([`IpcError::InvalidEnvironment`]).
pub const SHORT_SLICE_ENV: &str = "DVRK_SIDECAR_SHORT_SLICE";

/// Whether event and predictive subscriptions ask for the short slice, for the value of
/// [`SHORT_SLICE_ENV`].
fn short_slice_wanted(env: Option<std::ffi::OsString>) -> Result<bool, IpcError> {
    match env {
        None => Ok(true),
        Some(v) => match v.to_str() {
            Some("1") => Ok(true),
            Some("0") => Ok(false),
            _ => Err(IpcError::InvalidEnvironment {
                name: SHORT_SLICE_ENV,
                value: v.to_string_lossy().into_owned(),
                expected: "0 (no short time slice) or 1 (the default)",
            }),
        },
    }
}

/// How a [`Subscription`] waits for the next sample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum WaitStrategy {
    /// Sleep until the publisher's cycle wakes the process (one futex word per cycle event,
    /// bumped once per cycle, all its sleepers woken by one system call: [`crate::wake`]).
    /// Least CPU; latency is one cross-process wake-up. A subscription of the
    /// cycle's first message, `compensated/local/measured_cp`, waits on the event notified right
    /// after that message ([`ServiceNames::cycle_first`]); the others on the event notified after
    /// the cycle's last message ([`ServiceNames::cycle`]). Asks for a short time slice for the
    /// thread that subscribes ([`Subscription::short_slice`]), so that its wake-up preempts the
    /// service when both share a CPU ([`SHORT_SLICE_ENV`] turns it off).
    #[default]
    Event,
    /// Poll the shared memory without sleeping. Lowest latency, one whole CPU core per
    /// subscription; opens no listener, so it costs the publisher nothing per cycle. Only for a
    /// consumer that owns a core.
    Spin,
    /// Learn the publisher's period and phase from the samples' publish times, sleep until
    /// shortly before the next sample is due (or until the cycle event, whichever comes first),
    /// then poll. Close to `Spin` in latency at a fraction of its CPU, and never later than
    /// `Event`. A cycle event that brings no new sample (the notification of a cycle already
    /// taken by polling) sends it back to sleep. Polling yields the CPU while the cycle event
    /// has at least as many listeners as the process has CPUs. While fewer than a quarter of
    /// recent waits start polling in time (a publisher too irregular to predict), only one wait
    /// in eight polls and the others sleep like `Event`. Sets the calling thread's timer
    /// slack to 1 ns (`PR_SET_TIMERSLACK`) and, as `Event`, asks for a short time slice.
    Predictive,
}

impl WaitStrategy {
    /// All strategies, in the order of their names in [`WaitStrategy::NAMES`].
    pub const ALL: [WaitStrategy; 3] = [Self::Event, Self::Spin, Self::Predictive];
    /// The names accepted by [`WaitStrategy::from_str`](core::str::FromStr).
    pub const NAMES: &'static str = "event, spin, predictive";

    /// The name used on command lines (`--wait event|spin|predictive`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Event => "event",
            Self::Spin => "spin",
            Self::Predictive => "predictive",
        }
    }

    /// Whether this strategy needs a listener on the cycle event.
    pub fn uses_event(self) -> bool {
        !matches!(self, Self::Spin)
    }
}

impl core::fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// A wait strategy name that is none of [`WaitStrategy::NAMES`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown wait strategy {0:?}; expected one of: event, spin, predictive")]
pub struct UnknownWaitStrategy(pub String);

impl core::str::FromStr for WaitStrategy {
    type Err = UnknownWaitStrategy;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|w| w.name() == s)
            .ok_or_else(|| UnknownWaitStrategy(s.to_owned()))
    }
}

/// How a [`Subscription`] waits and when it calls the publisher silent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubscribeOptions {
    /// The publisher's nominal period ([`NOMINAL_PERIOD`] for the sidecar at 1500 Hz); the
    /// predictive strategy starts from it and learns the real one.
    pub period: Duration,
    /// How to wait.
    pub wait: WaitStrategy,
    /// After how long without a sample [`Subscription::wait`] returns [`Update::Stale`].
    /// `None`: [`DEADLINE_PERIODS`] periods, at least [`MIN_DEFAULT_DEADLINE`].
    pub deadline: Option<Duration>,
    /// [`WaitStrategy::Predictive`]: the share of predicted waits (percent) whose timer may wake
    /// after the sample landed ([`crate::PREDICTIVE_LATE_PERCENT`], 10, by default; taken
    /// within [`crate::PREDICTIVE_LATE_PERCENT_RANGE`]). Such a wait hands the sample over as
    /// late as its timer fires (or the cycle's wake-up, whichever comes first); a smaller share
    /// polls longer before each sample and costs more CPU.
    pub predictive_late_percent: u8,
}

impl Default for SubscribeOptions {
    fn default() -> Self {
        Self {
            period: NOMINAL_PERIOD,
            wait: WaitStrategy::Event,
            deadline: None,
            predictive_late_percent: crate::PREDICTIVE_LATE_PERCENT,
        }
    }
}

impl SubscribeOptions {
    /// The staleness deadline these options give.
    pub fn effective_deadline(&self) -> Duration {
        self.deadline.unwrap_or_else(|| {
            self.period
                .saturating_mul(DEADLINE_PERIODS)
                .max(MIN_DEFAULT_DEADLINE)
        })
    }
}

/// The predictive strategy's model of the publisher ([`Subscription::prediction`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Prediction {
    /// The publisher's period as measured from its publish times.
    pub period_ns: u64,
    /// When the next sample is expected at the earliest (CLOCK_MONOTONIC).
    pub next_arrival_ns: u64,
    /// How long before `next_arrival_ns` the timer ends the sleep and polling starts.
    pub guard_ns: u64,
    /// How long after `next_arrival_ns` polling goes on before it sleeps on the event again.
    pub spin_after_ns: u64,
}

/// What [`Subscription::wait`] saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Update<T> {
    /// The newest sample; older samples drained in the same call were passed to the `each`
    /// callback of [`Subscription::wait_with`] and are counted in
    /// [`SubscriptionStats::superseded_total`].
    Fresh(T),
    /// No new sample within the deadline while a publisher is (or may soon be) connected.
    /// `since_ns` is the time since the last fresh sample, or since the subscription was created
    /// if none arrived yet.
    Stale { since_ns: u64 },
    /// The publisher that was connected is gone: stopped (reported at the next deadline), or
    /// died (reported once its node is reaped, checked at most every
    /// [`DEAD_PUBLISHER_CHECK_INTERVAL`] while stale). A new publisher on the same prefix is
    /// picked up by later calls.
    Terminated,
    /// The wait was interrupted by a signal (iceoryx2 signal handling is disabled: the
    /// application's own handler ran). Check the application's stop flag and call again.
    Interrupted,
}

/// Counters of a [`Subscription`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscriptionStats {
    /// Samples taken out of the buffer.
    pub received_total: u64,
    /// Samples drained but not returned as [`Update::Fresh`] because a newer one was there.
    pub superseded_total: u64,
    /// `seq` values skipped between consecutive received samples (lost to buffer overflow, or
    /// cycles the publisher did not publish).
    pub seq_gaps_total: u64,
    /// Calls that returned [`Update::Stale`].
    pub stale_total: u64,
    /// Predictive waits that were already polling when the sample landed.
    pub predicted_on_time_total: u64,
    /// Predictive waits where the sample landed before polling started (the cycle event or
    /// the late timer delivered it).
    pub predicted_late_total: u64,
    /// Predictive waits that polled until the spin window closed without a sample and went
    /// back to sleep on the cycle event.
    pub predicted_missed_total: u64,
    /// Predictive waits that did not poll at all, because most recent ones started polling
    /// too late (an unpredictable publisher): they slept on the wake-up as `Event` does.
    pub predicted_skipped_total: u64,
}

/// A subscriber to one topic of an arm, waiting with the consumer's [`WaitStrategy`].
///
/// [`Subscription::wait`] returns as soon as a sample is there, after draining every buffered
/// sample; with [`WaitStrategy::Event`] and [`WaitStrategy::Predictive`] it consumes the cycle
/// event's notifications before it sleeps, never between a wake-up and the sample (the sample
/// comes first).
///
/// History: a subscriber created after the publisher's last send receives that sample (history
/// of 1) only when the publisher sends again, together with the new sample. Use
/// [`Subscription::try_latest`] to poll without waiting.
///
/// Like every `ipc::Service` port, a `Subscription` is `!Send`.
#[derive(Debug)]
pub struct Subscription<T: Message, S: Service = iceoryx2::service::ipc::Service> {
    topic: Topic,
    service_name: String,
    service: PubSubFactory<S, T, ()>,
    subscriber: Subscriber<S, T, ()>,
    /// Held, never drained: it counts the subscription as a listener of the cycle event (to
    /// the publisher, [`Subscription::crowded`], the reaping of dead nodes) and is there for
    /// applications that run their own WaitSet. The wait sleeps on `wake`.
    listener: Option<Listener<S>>,
    /// The cycle event's wake-up word (`None` for `Spin`).
    wake: Option<WakeWord>,
    /// The word's value before the last look at the buffer.
    seen: u32,
    /// Whether the next sleep is on the word (a publisher bumps it), else on the listener:
    /// decided by [`Subscription::take_pending`].
    on_word: bool,
    /// Sleep on the listener's unix datagrams (and a timerfd) as before the wake-up word: only
    /// for the latency harness's comparison ([`Subscription::use_datagram_wake`]).
    datagram: bool,
    timer: Option<TimerFd>,
    predictor: Predictor,
    wait: WaitStrategy,
    deadline_ns: u64,
    last_fresh_ns: u64,
    last_seq: Option<u64>,
    latest: Option<T>,
    publisher_seen: bool,
    last_dead_check_ns: Option<u64>,
    stats: SubscriptionStats,
    /// The cycle event's service, to count its listeners (`None` for `Spin`).
    event: Option<EventFactory<S>>,
    /// CPUs this process may run on, read once at creation.
    cores: usize,
    /// Whether creating it gave the calling thread the short time slice.
    short_slice: bool,
}

/// The caller's `prepare` of [`Subscription::wait_prepared`], until it has run.
type Prepare<'a> = Option<&'a mut dyn FnMut()>;

/// Runs `prepare` if it has not run yet in this wait.
fn run_once(prepare: &mut Prepare<'_>) {
    if let Some(p) = prepare.take() {
        p();
    }
}

/// Where a predictive wait started polling, to grade the prediction when the sample comes.
#[derive(Debug, Clone, Copy)]
enum Polling {
    /// The timer fired at this time (ns) and the cycle event had not come yet.
    OnTimer(u64),
    /// The sample came another way (event first, or already there): the prediction was late.
    Late,
}

impl<T: Message, S: Service> Subscription<T, S>
where
    Listener<S>: SynchronousMultiplexing,
{
    /// Subscribes to `topic` under `names` with the [`WaitStrategy::Event`] strategy and the
    /// default deadline for `period` (see [`SubscribeOptions::effective_deadline`]).
    pub fn new(
        node: &Node<S>,
        names: &ServiceNames,
        topic: Topic,
        period: Duration,
    ) -> Result<Self, IpcError> {
        Self::with_options(
            node,
            names,
            topic,
            SubscribeOptions {
                period,
                ..SubscribeOptions::default()
            },
        )
    }

    /// Subscribes to `topic` under `names` (opening or creating the services with the project's
    /// QoS), waiting as `options` says. A [`WaitStrategy::Spin`] subscription opens no listener
    /// on the cycle event. [`WaitStrategy::Event`] and [`WaitStrategy::Predictive`] ones ask
    /// for a short time slice for the calling thread ([`Subscription::short_slice`]); a
    /// predictive one also opens a timer and sets the calling thread's timer slack to 1 ns.
    pub fn with_options(
        node: &Node<S>,
        names: &ServiceNames,
        topic: Topic,
        options: SubscribeOptions,
    ) -> Result<Self, IpcError> {
        let service = open_topic::<T, S>(node, names, topic)?;
        let service_name = names.topic(topic).as_str().to_owned();
        let subscriber =
            service
                .subscriber_builder()
                .create()
                .map_err(|source| IpcError::CreateSubscriber {
                    service: service_name.clone(),
                    source,
                })?;
        let (listener, event, wake) =
            if options.wait.uses_event() {
                // The first message of a cycle has an event of its own, notified right after
                // it is sent; the other topics wait for the end of the cycle.
                let event_name = names.event_for(topic);
                let event = open_event(node, event_name)?;
                let listener = event.listener_builder().create().map_err(|source| {
                    IpcError::CreateListener {
                        service: event_name.as_str().to_owned(),
                        source,
                    }
                })?;
                let wake = open_event_word(node.config(), event_name)?;
                (Some(listener), Some(event), Some(wake))
            } else {
                (None, None, None)
            };
        // A woken subscriber preempts a longer-slice task on its CPU (the service itself, when
        // the scheduler wakes it there) instead of waiting for it: `sys::request_short_slice`.
        // Best effort: a thread whose scheduling may not be changed (a seccomp filter) waits
        // as before, and `short_slice()` says so.
        let short_slice = options.wait.uses_event()
            && short_slice_wanted(std::env::var_os(SHORT_SLICE_ENV))?
            && matches!(sys::request_short_slice(), Ok(true));
        let timer = if options.wait == WaitStrategy::Predictive {
            sys::minimise_timer_slack().map_err(|source| IpcError::Timer {
                what: "prctl(PR_SET_TIMERSLACK, 1)",
                source,
            })?;
            Some(TimerFd::new().map_err(|source| IpcError::Timer {
                what: "timerfd_create(CLOCK_MONOTONIC)",
                source,
            })?)
        } else {
            None
        };
        let publisher_seen = service.dynamic_config().number_of_publishers() > 0;
        let period_ns = u64::try_from(options.period.as_nanos()).unwrap_or(u64::MAX);
        let deadline_ns =
            u64::try_from(options.effective_deadline().as_nanos()).unwrap_or(u64::MAX);
        Ok(Self {
            topic,
            service_name,
            service,
            subscriber,
            listener,
            wake,
            seen: 0,
            on_word: false,
            datagram: false,
            timer,
            predictor: Predictor::with_late_percent(period_ns, options.predictive_late_percent),
            wait: options.wait,
            deadline_ns,
            last_fresh_ns: sys::monotonic_ns(),
            last_seq: None,
            latest: None,
            publisher_seen,
            last_dead_check_ns: None,
            stats: SubscriptionStats::default(),
            event,
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            short_slice,
        })
    }

    /// Whether creating this subscription gave the calling thread a short time slice
    /// (0.1 ms, `sched_setattr`): event and predictive subscriptions ask for it
    /// for the thread that creates them, which should be the thread that waits. `false` for
    /// `Spin`, for a thread under a real-time or other non-normal policy (left as it is), where
    /// the kernel refused, and when [`SHORT_SLICE_ENV`] is `0`.
    pub fn short_slice(&self) -> bool {
        self.short_slice
    }

    /// Waits for the next sample and returns the newest one, or why there is none.
    pub fn wait(&mut self) -> Result<Update<T>, SubscriptionError> {
        self.wait_with(|_| {})
    }

    /// Like [`Subscription::wait`], and calls `each` for every sample drained, oldest first,
    /// including the one returned (for consumers that need every `seq`).
    pub fn wait_with<F: FnMut(&T)>(&mut self, each: F) -> Result<Update<T>, SubscriptionError> {
        self.wait_prepared(each, || {})
    }

    /// Like [`Subscription::wait_with`], and calls `prepare` at most once, when the sample is
    /// due but not there yet: the work a consumer must do before each sample (making the
    /// buffer it is handed over in, say) then costs no latency, its own or, with more
    /// subscribers than cores, the others'. The predictive strategy calls it once its timer
    /// has woken it, before it polls (its guard learns the time `prepare` takes, as it learns
    /// the timer's lateness); the event strategy, and the predictive one while it waits as the
    /// event path does, before sleeping; spinning, before it polls. Not called when a sample
    /// is already there on entry, nor when the sample lands while the predictive wait still
    /// sleeps (a timer late beyond its guard).
    pub fn wait_prepared<F: FnMut(&T), P: FnMut()>(
        &mut self,
        mut each: F,
        mut prepare: P,
    ) -> Result<Update<T>, SubscriptionError> {
        let mut prepare = Some(&mut prepare as &mut dyn FnMut());
        match self.wait {
            WaitStrategy::Event => self.wait_event(&mut each, &mut prepare),
            WaitStrategy::Spin => self.wait_spin(&mut each, &mut prepare),
            WaitStrategy::Predictive => self.wait_predictive(&mut each, &mut prepare),
        }
    }

    /// Drains the buffer without waiting and returns the newest sample, if any arrived since the
    /// last call. Does not consume cycle events.
    pub fn try_latest(&mut self) -> Result<Option<T>, SubscriptionError> {
        self.drain(&mut |_| {})
    }

    /// The newest sample ever received.
    pub fn latest(&self) -> Option<&T> {
        self.latest.as_ref()
    }

    /// Counters since creation.
    pub fn stats(&self) -> SubscriptionStats {
        self.stats
    }

    /// The subscribed topic.
    pub fn topic(&self) -> Topic {
        self.topic
    }

    /// The full name of the subscribed service, e.g. `PSM1/compensated/local/measured_cp`.
    pub fn service_name(&self) -> &str {
        &self.service_name
    }

    /// The wait strategy.
    pub fn wait_strategy(&self) -> WaitStrategy {
        self.wait
    }

    /// The staleness deadline.
    pub fn deadline(&self) -> Duration {
        Duration::from_nanos(self.deadline_ns)
    }

    /// The predictive strategy's current model of the publisher; `None` until it has learnt
    /// enough samples. (Every strategy learns it; only [`WaitStrategy::Predictive`] uses it.)
    pub fn prediction(&self) -> Option<Prediction> {
        let p = &self.predictor;
        p.ready().then(|| Prediction {
            period_ns: p.period_ns(),
            next_arrival_ns: p.next_arrival_ns(),
            guard_ns: p.guard_ns(),
            spin_after_ns: p.spin_after_ns(),
        })
    }

    /// Publishers currently registered on the topic's service.
    pub fn number_of_publishers(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }

    /// The listener of the cycle event, for applications that run their own WaitSet (`None`
    /// for a [`WaitStrategy::Spin`] subscription, which has none). The subscription itself
    /// sleeps on the cycle's wake-up word ([`crate::wake`]) and never drains this listener:
    /// an application that watches it drains it (`try_wait`) after every wake-up.
    pub fn listener(&self) -> Option<&Listener<S>> {
        self.listener.as_ref()
    }

    /// The subscriber port, for applications that run their own WaitSet.
    pub fn subscriber(&self) -> &Subscriber<S, T, ()> {
        &self.subscriber
    }

    /// Makes an event or predictive subscription sleep as it did before the wake-up word: on
    /// its listener's unix datagrams (consumed before every sleep) and, predictive, a timerfd.
    /// Only for the latency harness, which measures both in one run; call it before the first
    /// wait.
    #[doc(hidden)]
    pub fn use_datagram_wake(&mut self) {
        self.datagram = self.listener.is_some();
    }

    // ---- strategies ------------------------------------------------------------------------

    fn wait_event(
        &mut self,
        each: &mut dyn FnMut(&T),
        prepare: &mut Prepare<'_>,
    ) -> Result<Update<T>, SubscriptionError> {
        let stale_at = sys::monotonic_ns().saturating_add(self.deadline_ns);
        loop {
            if let Some(v) = self.take_pending(each)? {
                return Ok(Update::Fresh(v));
            }
            run_once(prepare);
            match self.sleep(stale_at, None)? {
                Ready::Interrupted => return Ok(Update::Interrupted),
                Ready::TimedOut => return Ok(self.stale_or_terminated()),
                Ready::Event | Ready::Timer => {}
            }
            // Woken: the sample is there in all but rare cases; take it before anything else.
            if let Some(v) = self.drain(each)? {
                return Ok(Update::Fresh(v));
            }
            // A wake-up without a sample: the bump of a cycle already drained, or a late
            // subscriber whose connection (and history) comes with the publisher's next send.
        }
    }

    fn wait_spin(
        &mut self,
        each: &mut dyn FnMut(&T),
        prepare: &mut Prepare<'_>,
    ) -> Result<Update<T>, SubscriptionError> {
        let stale_at = sys::monotonic_ns().saturating_add(self.deadline_ns);
        loop {
            if let Some(v) = self.drain(each)? {
                return Ok(Update::Fresh(v));
            }
            run_once(prepare);
            if sys::monotonic_ns() >= stale_at {
                return Ok(self.stale_or_terminated());
            }
            core::hint::spin_loop();
        }
    }

    fn wait_predictive(
        &mut self,
        each: &mut dyn FnMut(&T),
        prepare: &mut Prepare<'_>,
    ) -> Result<Update<T>, SubscriptionError> {
        let now = sys::monotonic_ns();
        let stale_at = now.saturating_add(self.deadline_ns);
        if let Some(v) = self.take_pending(each)? {
            // The caller came back after the sample landed: nothing to grade.
            return Ok(Update::Fresh(v));
        }
        if !self.predictor.ready() {
            // Still learning: behave like the event path; arrivals teach the predictor.
            return self.wait_event(each, prepare);
        }
        if !self.predictor.poll_this_wait() {
            // Most recent waits started polling too late to matter: sleep on the wake-up as
            // the event path does (the arrival still teaches the predictor).
            self.stats.predicted_skipped_total += 1;
            return self.wait_event(each, prepare);
        }
        let arrival = self.predictor.next_arrival_ns();
        let wake_at = arrival.saturating_sub(self.predictor.guard_ns());
        let spin_until = arrival
            .saturating_add(self.predictor.spin_after_ns())
            .min(stale_at);
        if wake_at > sys::monotonic_ns() {
            loop {
                match self.sleep(stale_at, Some(wake_at))? {
                    Ready::Interrupted => return Ok(Update::Interrupted),
                    Ready::TimedOut => return Ok(self.stale_or_terminated()),
                    Ready::Timer => break,
                    Ready::Event => {}
                }
                // The wake-up came first: the sample is there (the timer was late), or this is
                // the bump of the cycle already taken by polling, which comes after the cycle's
                // messages. Then sleep again until the same wake-up time.
                if let Some(v) = self.take_pending(each)? {
                    self.grade(&v, Polling::Late);
                    return Ok(Update::Fresh(v));
                }
            }
        }
        // Polling starts after `prepare` (called after the wake-up point, too): graded from
        // then, the guard covers its time.
        run_once(prepare);
        let polling = Polling::OnTimer(sys::monotonic_ns());
        let crowded = self.crowded();
        // The first look tells whether the sample was already there when polling started.
        if let Some(v) = self.drain(each)? {
            self.grade(&v, Polling::Late);
            return Ok(Update::Fresh(v));
        }
        loop {
            if let Some(v) = self.drain(each)? {
                self.grade(&v, polling);
                return Ok(Update::Fresh(v));
            }
            if sys::monotonic_ns() >= spin_until {
                break;
            }
            if crowded {
                // More pollers than cores: give the CPU to whatever else is runnable on it (the
                // publisher about to send, the other subscribers), else they wait for this
                // one's time slice to end. Returns at once when nothing else is runnable.
                std::thread::yield_now();
            } else {
                core::hint::spin_loop();
            }
        }
        // The sample is later than the spin window allows (a publisher overrun or stall): sleep
        // until the wake-up for the rest of the deadline. Its arrival still teaches the predictor.
        self.stats.predicted_missed_total += 1;
        self.predictor.missed();
        loop {
            if let Some(v) = self.take_pending(each)? {
                return Ok(Update::Fresh(v));
            }
            match self.sleep(stale_at, None)? {
                Ready::Interrupted => return Ok(Update::Interrupted),
                Ready::TimedOut => return Ok(self.stale_or_terminated()),
                Ready::Event | Ready::Timer => {}
            }
            if let Some(v) = self.drain(each)? {
                return Ok(Update::Fresh(v));
            }
        }
    }

    /// The samples already buffered, taken so that the next [`Subscription::sleep`] returns
    /// at the next wake-up after them: the wake-up word is read before the buffer is (a sample
    /// sent after that read comes with a bump, which ends the sleep at once). In datagram mode,
    /// the buffer, then the listener's pending notifications consumed, then the buffer again.
    fn take_pending(&mut self, each: &mut dyn FnMut(&T)) -> Result<Option<T>, SubscriptionError> {
        self.on_word = !self.datagram && self.wake.as_ref().is_some_and(|w| w.has_publisher());
        if self.on_word {
            if let Some(w) = &self.wake {
                self.seen = w.load();
            }
            return self.drain(each);
        }
        if let Some(v) = self.drain(each)? {
            return Ok(Some(v));
        }
        if let Some(listener) = &self.listener {
            listener
                .try_wait(|_| {})
                .map_err(SubscriptionError::ListenerWait)?;
            return self.drain(each);
        }
        Ok(None)
    }

    /// Sleeps until the wake-up after the last [`Subscription::take_pending`] (`Event`), until
    /// `timer_at` if given (`Timer`), until `until_ns` (`TimedOut`), or a signal.
    fn sleep(&self, until_ns: u64, timer_at: Option<u64>) -> Result<Ready, SubscriptionError> {
        if !self.on_word {
            let timer = match timer_at {
                Some(t) => {
                    let timer = self.timer.as_ref().ok_or(SubscriptionError::NoTimer)?;
                    timer.arm_at(t).map_err(SubscriptionError::Timer)?;
                    Some(timer.fd())
                }
                None => None,
            };
            return sys::wait_readable(self.listener_fd()?, timer, until_ns)
                .map_err(SubscriptionError::Poll);
        }
        let wake = self.wake.as_ref().ok_or(SubscriptionError::NoListener)?;
        let timer_first = timer_at.is_some_and(|t| t < until_ns);
        let deadline = if timer_first {
            timer_at.unwrap_or(until_ns)
        } else {
            until_ns
        };
        Ok(
            match wake
                .wait(self.seen, deadline)
                .map_err(SubscriptionError::Wake)?
            {
                Woken::Bumped => Ready::Event,
                Woken::Interrupted => Ready::Interrupted,
                Woken::TimedOut if timer_first => Ready::Timer,
                Woken::TimedOut => Ready::TimedOut,
            },
        )
    }

    /// Whether this subscription's cycle event has at least as many listeners (event and
    /// predictive subscribers of the same event, of every process) as this process has CPUs:
    /// then polling must yield. Reads shared memory; no system call.
    fn crowded(&self) -> bool {
        self.event
            .as_ref()
            .is_some_and(|e| e.dynamic_config().number_of_listeners() >= self.cores)
    }

    fn listener_fd(&self) -> Result<i32, SubscriptionError> {
        use iceoryx2::prelude::FileDescriptorBased as _;
        self.listener
            .as_ref()
            // SAFETY: the raw descriptor is only passed to ppoll while the listener (its owner)
            // is alive, and never closed or duplicated here.
            .map(|l| unsafe { l.file_descriptor().native_handle() })
            .ok_or(SubscriptionError::NoListener)
    }

    /// Tells the predictor whether it started polling in time for `v`.
    fn grade(&mut self, v: &T, polling: Polling) {
        let landed = v.header().publish_t_ns;
        let on_time = match polling {
            Polling::OnTimer(started) => landed != 0 && started <= landed,
            Polling::Late => false,
        };
        if on_time {
            self.stats.predicted_on_time_total += 1;
        } else {
            self.stats.predicted_late_total += 1;
        }
        self.predictor.graded(on_time);
    }

    fn drain(&mut self, each: &mut dyn FnMut(&T)) -> Result<Option<T>, SubscriptionError> {
        let mut newest: Option<T> = None;
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(SubscriptionError::Receive)?
        {
            let v: T = *sample;
            drop(sample);
            let h = v.header();
            let seq = h.seq;
            if let Some(prev) = self.last_seq
                && seq > prev + 1
            {
                self.stats.seq_gaps_total += seq - prev - 1;
            }
            self.last_seq = Some(seq);
            self.stats.received_total += 1;
            if newest.is_some() {
                self.stats.superseded_total += 1;
            }
            each(&v);
            newest = Some(v);
        }
        if let Some(v) = newest {
            let now = sys::monotonic_ns();
            let h = v.header();
            // The publisher stamps publish_t_ns on the same CLOCK_MONOTONIC just before it
            // sends; a publisher that leaves it 0 is learnt from the receive time instead.
            let landed = if h.publish_t_ns != 0 && h.publish_t_ns <= now {
                h.publish_t_ns
            } else {
                now
            };
            self.predictor.observe(h.seq, landed);
            self.latest = Some(v);
            self.last_fresh_ns = now;
            self.publisher_seen = true;
        }
        Ok(newest)
    }

    /// Maps the wake-up word again when its file was removed or replaced under this
    /// subscription (a cleanup of the root directory while it ran): a publisher started since
    /// bumps the new file. Checked while stale, at most every [`DEAD_PUBLISHER_CHECK_INTERVAL`].
    fn reopen_wake_if_replaced(&mut self) {
        let Some(w) = &self.wake else { return };
        if !w.replaced() {
            return;
        }
        // Best effort: until it can be opened again, the timeouts still report staleness.
        if let Ok(new) = w.reopen() {
            self.wake = Some(new);
        }
    }

    fn stale_or_terminated(&mut self) -> Update<T> {
        // A publisher whose process died still counts until its node is cleaned up.
        let now = sys::monotonic_ns();
        let interval = DEAD_PUBLISHER_CHECK_INTERVAL.as_nanos() as u64;
        let due = self
            .last_dead_check_ns
            .is_none_or(|t| now.saturating_sub(t) >= interval);
        if due {
            self.last_dead_check_ns = Some(now);
            self.service.try_cleanup_dead_nodes();
            self.reopen_wake_if_replaced();
            if let Some(w) = &self.wake {
                w.forget_dead_publisher();
            }
        }
        if self.service.dynamic_config().number_of_publishers() > 0 {
            self.publisher_seen = true;
        } else if self.publisher_seen {
            return Update::Terminated;
        }
        self.stats.stale_total += 1;
        Update::Stale {
            since_ns: now.saturating_sub(self.last_fresh_ns),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_short_slice_is_on_unless_the_environment_says_0() {
        use std::ffi::OsString;
        assert!(short_slice_wanted(None).unwrap());
        assert!(short_slice_wanted(Some(OsString::from("1"))).unwrap());
        assert!(!short_slice_wanted(Some(OsString::from("0"))).unwrap());
        let e = short_slice_wanted(Some(OsString::from("off"))).unwrap_err();
        assert_eq!(
            e.to_string(),
            "DVRK_SIDECAR_SHORT_SLICE=\"off\": expected 0 (no short time slice) or 1 (the default)"
        );
    }
}
