//! The subscribing side: wait for the cycle event, drain, return the newest sample, and notice a
//! silent or vanished publisher.

use core::time::Duration;
use std::time::Instant;

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{
    CallbackProgression, SignalHandlingMode, SynchronousMultiplexing, WaitSet, WaitSetBuilder,
};
use iceoryx2::service::Service;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::waitset::WaitSetRunResult;

use crate::error::{IpcError, SubscriptionError};
use crate::msg::Message;
use crate::names::{ServiceNames, Topic};
use crate::services::{open_cycle_event, open_topic};

/// Periods without a cycle event after which [`Subscription::wait`] reports staleness.
pub const DEADLINE_PERIODS: u32 = 3;

/// Least time between two attempts to reap a dead publisher while stale (each attempt lists the
/// service's nodes on the file system).
pub const DEAD_PUBLISHER_CHECK_INTERVAL: Duration = Duration::from_millis(200);

/// Nominal publishing period of the sidecar (1500 Hz, like the dVRK console).
pub const NOMINAL_PERIOD: Duration = Duration::from_nanos(666_667);

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
}

/// A subscriber to one topic of an arm plus a listener on its cycle event.
///
/// [`Subscription::wait`] sleeps in a WaitSet (signal handling disabled) until the publisher
/// notifies the cycle event or the deadline of [`DEADLINE_PERIODS`] periods passes, then drains
/// the event and every buffered sample and returns the newest.
///
/// History: a subscriber created after the publisher's last send receives that sample (history
/// of 1) only when the publisher sends again, together with the new sample. Use
/// [`Subscription::try_latest`] to poll without waiting.
///
/// Like every `ipc::Service` port, a `Subscription` is `!Send`.
#[derive(Debug)]
pub struct Subscription<T: Message, S: Service = iceoryx2::service::ipc::Service> {
    topic: Topic,
    service: PubSubFactory<S, T, ()>,
    subscriber: Subscriber<S, T, ()>,
    listener: Listener<S>,
    waitset: WaitSet<S>,
    deadline: Duration,
    last_fresh: Instant,
    last_seq: Option<u64>,
    latest: Option<T>,
    publisher_seen: bool,
    last_dead_check: Option<Instant>,
    stats: SubscriptionStats,
}

impl<T: Message, S: Service> Subscription<T, S>
where
    Listener<S>: SynchronousMultiplexing,
{
    /// Subscribes to `topic` under `names` (opening or creating the services with the project's
    /// QoS). `period` is the publisher's nominal period ([`NOMINAL_PERIOD`] for the sidecar at
    /// 1500 Hz); the staleness deadline is [`DEADLINE_PERIODS`] times it.
    pub fn new(
        node: &Node<S>,
        names: &ServiceNames,
        topic: Topic,
        period: Duration,
    ) -> Result<Self, IpcError> {
        let service = open_topic::<T, S>(node, names, topic)?;
        let event = open_cycle_event(node, names)?;
        let subscriber =
            service
                .subscriber_builder()
                .create()
                .map_err(|source| IpcError::CreateSubscriber {
                    service: names.topic(topic).as_str().to_owned(),
                    source,
                })?;
        let listener =
            event
                .listener_builder()
                .create()
                .map_err(|source| IpcError::CreateListener {
                    service: names.cycle().as_str().to_owned(),
                    source,
                })?;
        let waitset = WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<S>()
            .map_err(|source| IpcError::CreateWaitSet { source })?;
        let publisher_seen = service.dynamic_config().number_of_publishers() > 0;
        Ok(Self {
            topic,
            service,
            subscriber,
            listener,
            waitset,
            deadline: period.saturating_mul(DEADLINE_PERIODS),
            last_fresh: Instant::now(),
            last_seq: None,
            latest: None,
            publisher_seen,
            last_dead_check: None,
            stats: SubscriptionStats::default(),
        })
    }

    /// Waits for the next cycle and returns the newest sample, or why there is none.
    pub fn wait(&mut self) -> Result<Update<T>, SubscriptionError> {
        self.wait_with(|_| {})
    }

    /// Like [`Subscription::wait`], and calls `each` for every sample drained, oldest first,
    /// including the one returned (for consumers that need every `seq`).
    pub fn wait_with<F: FnMut(&T)>(&mut self, mut each: F) -> Result<Update<T>, SubscriptionError> {
        let start = Instant::now();
        // Samples may already be waiting if the caller was slower than the publisher.
        if let Some(v) = self.drain(&mut each)? {
            return Ok(Update::Fresh(v));
        }
        loop {
            let remaining = self.deadline.saturating_sub(start.elapsed());
            if remaining.is_zero() {
                return Ok(self.stale_or_terminated());
            }
            let mut missed = false;
            let mut wait_error = None;
            let result = {
                let listener = &self.listener;
                let guard = self
                    .waitset
                    .attach_deadline(listener, remaining)
                    .map_err(SubscriptionError::Attach)?;
                self.waitset
                    .wait_and_process_once(|id| {
                        if id.has_event_from(&guard) {
                            // The WaitSet is level-triggered: consume every pending notification.
                            if let Err(e) = listener.try_wait(|_| {}) {
                                wait_error = Some(e);
                            }
                        } else if id.has_missed_deadline(&guard) {
                            missed = true;
                        }
                        CallbackProgression::Continue
                    })
                    .map_err(SubscriptionError::Wait)?
            };
            if let Some(e) = wait_error {
                return Err(SubscriptionError::ListenerWait(e));
            }
            if let Some(v) = self.drain(&mut each)? {
                return Ok(Update::Fresh(v));
            }
            match result {
                WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest => {
                    return Ok(Update::Interrupted);
                }
                WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
            }
            if missed {
                return Ok(self.stale_or_terminated());
            }
            // An event without a sample: a notification of a cycle already drained, or a late
            // subscriber whose connection (and history) comes with the publisher's next send.
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

    /// The staleness deadline ([`DEADLINE_PERIODS`] × period).
    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    /// Publishers currently registered on the topic's service.
    pub fn number_of_publishers(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }

    /// The listener of the cycle event, for applications that run their own WaitSet.
    pub fn listener(&self) -> &Listener<S> {
        &self.listener
    }

    /// The subscriber port, for applications that run their own WaitSet.
    pub fn subscriber(&self) -> &Subscriber<S, T, ()> {
        &self.subscriber
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
            let seq = v.header().seq;
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
            self.latest = Some(v);
            self.last_fresh = Instant::now();
            self.publisher_seen = true;
        }
        Ok(newest)
    }

    fn stale_or_terminated(&mut self) -> Update<T> {
        // A publisher whose process died still counts until its node is cleaned up.
        let due = self
            .last_dead_check
            .is_none_or(|t| t.elapsed() >= DEAD_PUBLISHER_CHECK_INTERVAL);
        if due {
            self.last_dead_check = Some(Instant::now());
            self.service.try_cleanup_dead_nodes();
        }
        if self.service.dynamic_config().number_of_publishers() > 0 {
            self.publisher_seen = true;
        } else if self.publisher_seen {
            return Update::Terminated;
        }
        self.stats.stale_total += 1;
        let since = self.last_fresh.elapsed();
        Update::Stale {
            since_ns: u64::try_from(since.as_nanos()).unwrap_or(u64::MAX),
        }
    }
}
