//! The publishing side: one publisher per topic and the notifier of the cycle event.

use iceoryx2::node::Node;
use iceoryx2::port::notifier::{Notifier, NotifierCreateError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::service::Service;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::service_name::ServiceName;

use crate::error::{IpcError, PublishError};
use crate::msg::{
    ArmState, CompensationStatusV4, CycleMessages, JawStateV1, JointStateV2, Message, PoseV2,
};
use crate::names::{NUM_TOPICS, ServiceNames, Topic};
use crate::services::{ArmServices, StateServices};
use crate::wake::{WakeWord, open_event_word};

/// The four publishers of one arm state (raw or compensated).
#[derive(Debug)]
struct StatePublishers<S: Service> {
    measured_js: Publisher<S, JointStateV2, ()>,
    jaw_measured_js: Publisher<S, JawStateV1, ()>,
    local_measured_cp: Publisher<S, PoseV2, ()>,
    measured_cp: Publisher<S, PoseV2, ()>,
}

impl<S: Service> StatePublishers<S> {
    fn create(services: &StateServices<S>, names: &ServiceNames) -> Result<Self, IpcError> {
        Ok(Self {
            measured_js: create_publisher(&services.measured_js, names)?,
            jaw_measured_js: create_publisher(&services.jaw_measured_js, names)?,
            local_measured_cp: create_publisher(&services.local_measured_cp, names)?,
            measured_cp: create_publisher(&services.measured_cp, names)?,
        })
    }

    /// Sends the four messages of one state, poses first: the tip pose is what a controller
    /// waits for, so it leaves first.
    #[inline]
    fn send(&self, state: &ArmState, compensated: bool) -> Result<(), PublishError> {
        send(
            &self.local_measured_cp,
            if compensated {
                Topic::CompensatedLocalMeasuredCp
            } else {
                Topic::LocalMeasuredCp
            },
            &state.local_measured_cp,
        )?;
        self.send_after_local(state, compensated)
    }

    /// Sends the three messages of one state that follow `local/measured_cp`.
    #[inline]
    fn send_after_local(&self, state: &ArmState, compensated: bool) -> Result<(), PublishError> {
        let pick = |raw: Topic, comp: Topic| if compensated { comp } else { raw };
        send(
            &self.measured_cp,
            pick(Topic::MeasuredCp, Topic::CompensatedMeasuredCp),
            &state.measured_cp,
        )?;
        send(
            &self.measured_js,
            pick(Topic::MeasuredJs, Topic::CompensatedMeasuredJs),
            &state.measured_js,
        )?;
        send(
            &self.jaw_measured_js,
            pick(Topic::JawMeasuredJs, Topic::CompensatedJawMeasuredJs),
            &state.jaw_measured_js,
        )
    }
}

/// A cycle whose first message [`ArmPublisher::start_cycle`] has sent.
#[derive(Debug)]
#[must_use = "a started cycle sends its other eight messages and the cycle event only when finished"]
pub struct CycleStarted<'a, S: Service> {
    publisher: &'a ArmPublisher<S>,
    seq: u64,
    /// The notification of [`ServiceNames::cycle_first`] failed (reported by `finish`).
    first_notify: Option<PublishError>,
}

impl<S: Service> CycleStarted<'_, S> {
    /// Sends the other eight messages of the cycle in [`PUBLISH_ORDER`] and notifies the cycle
    /// event once. `cycle.compensated.local_measured_cp` is not sent again: it is the message
    /// the cycle was started with. Every message carries the started cycle's `seq`.
    ///
    /// On error, the messages sent before the failing one are delivered and the event is not
    /// notified. A failed notification of the first message's event is reported here, after
    /// the rest of the cycle was sent.
    pub fn finish(self, cycle: &CycleMessages) -> Result<(), PublishError> {
        debug_assert!(
            [
                cycle.measured.measured_js.header.seq,
                cycle.measured.jaw_measured_js.header.seq,
                cycle.measured.local_measured_cp.header.seq,
                cycle.measured.measured_cp.header.seq,
                cycle.compensated.measured_js.header.seq,
                cycle.compensated.jaw_measured_js.header.seq,
                cycle.compensated.local_measured_cp.header.seq,
                cycle.compensated.measured_cp.header.seq,
                cycle.status.header.seq,
            ]
            .iter()
            .all(|s| *s == self.seq),
            "all messages of a cycle carry the seq it was started with"
        );
        let p = self.publisher;
        p.compensated.send_after_local(&cycle.compensated, true)?;
        p.measured.send(&cycle.measured, false)?;
        send(
            &p.compensated_status,
            Topic::CompensatedStatus,
            &cycle.status,
        )?;
        // The project's subscriptions first (one futex wake for all), then iceoryx2's
        // listeners (the pure-Python client, C and C++ consumers, WaitSets of applications).
        p.cycle_wake.bump();
        p.cycle
            .notify()
            .map_err(|error| PublishError::Notify { error })?;
        self.first_notify.map_or(Ok(()), Err)
    }
}

/// The order in which [`ArmPublisher::publish_cycle`] sends the topics of a cycle: a subscriber
/// of an earlier topic has its sample sooner (each send takes a fraction of a microsecond).
pub const PUBLISH_ORDER: [Topic; NUM_TOPICS] = [
    Topic::CompensatedLocalMeasuredCp,
    Topic::CompensatedMeasuredCp,
    Topic::CompensatedMeasuredJs,
    Topic::CompensatedJawMeasuredJs,
    Topic::LocalMeasuredCp,
    Topic::MeasuredCp,
    Topic::MeasuredJs,
    Topic::JawMeasuredJs,
    Topic::CompensatedStatus,
];

/// Publishes the nine messages of a cycle and notifies the cycle event.
///
/// Only one `ArmPublisher` can exist per prefix and iceoryx2 domain (all processes together):
/// [`ArmPublisher::create`] fails with [`IpcError::AlreadyPublishing`] while another is alive.
/// A crashed publisher's slot is reclaimed on the next attempt.
///
/// `ipc::Service` ports are `!Send`: create and use the publisher on the thread that runs the
/// loop.
#[derive(Debug)]
pub struct ArmPublisher<S: Service = iceoryx2::service::ipc::Service> {
    services: ArmServices<S>,
    measured: StatePublishers<S>,
    compensated: StatePublishers<S>,
    compensated_status: Publisher<S, CompensationStatusV4, ()>,
    cycle: Notifier<S>,
    cycle_first: Notifier<S>,
    /// Wake-up words of the two events ([`crate::wake`]), bumped right before each notify.
    cycle_wake: WakeWord,
    cycle_first_wake: WakeWord,
}

/// The notifier of the event `name` (the only one: a second publisher of the arm is refused).
fn create_notifier<S: Service>(
    factory: &EventFactory<S>,
    names: &ServiceNames,
    name: &ServiceName,
) -> Result<Notifier<S>, IpcError> {
    let attempt = || factory.notifier_builder().create();
    match attempt() {
        // The slot may belong to a publisher whose process died: reap it and try once more.
        Err(NotifierCreateError::ExceedsMaxSupportedNotifiers) => {
            factory.try_cleanup_dead_nodes();
            attempt()
        }
        other => other,
    }
    .map_err(|source| match source {
        NotifierCreateError::ExceedsMaxSupportedNotifiers => IpcError::AlreadyPublishing {
            prefix: names.prefix().to_owned(),
        },
        source => IpcError::CreateNotifier {
            service: name.as_str().to_owned(),
            source,
        },
    })
}

fn create_publisher<S: Service, T: Message>(
    factory: &PubSubFactory<S, T, ()>,
    names: &ServiceNames,
) -> Result<Publisher<S, T, ()>, IpcError> {
    let attempt = || factory.publisher_builder().create();
    let result = match attempt() {
        // The slot may belong to a publisher whose process died: reap it and try once more.
        Err(PublisherCreateError::ExceedsMaxSupportedPublishers) => {
            factory.try_cleanup_dead_nodes();
            attempt()
        }
        other => other,
    };
    result.map_err(|source| match source {
        PublisherCreateError::ExceedsMaxSupportedPublishers => IpcError::AlreadyPublishing {
            prefix: names.prefix().to_owned(),
        },
        source => IpcError::CreatePublisher {
            service: factory.name().as_str().to_owned(),
            source,
        },
    })
}

impl<S: Service> ArmPublisher<S> {
    /// Opens or creates all services under `names` and creates their publishers and the cycle
    /// notifier. All allocation happens here.
    pub fn create(node: &Node<S>, names: &ServiceNames) -> Result<Self, IpcError> {
        let services = ArmServices::open_or_create(node, names)?;
        let measured = StatePublishers::create(&services.measured, names)?;
        let compensated = StatePublishers::create(&services.compensated, names)?;
        let compensated_status = create_publisher(&services.compensated_status, names)?;
        let cycle = create_notifier(&services.cycle, names, names.cycle())?;
        let cycle_first = create_notifier(&services.cycle_first, names, names.cycle_first())?;
        let cycle_wake = open_event_word(node.config(), names.cycle())?;
        let cycle_first_wake = open_event_word(node.config(), names.cycle_first())?;
        cycle_wake.claim();
        cycle_first_wake.claim();
        Ok(Self {
            services,
            measured,
            compensated,
            compensated_status,
            cycle,
            cycle_first,
            cycle_wake,
            cycle_first_wake,
        })
    }

    /// Sends the nine messages of one cycle in [`PUBLISH_ORDER`] (the compensated state first,
    /// poses first, so the compensated tip pose that controllers wait for is the first message
    /// of the cycle; the event [`ServiceNames::cycle_first`] is notified right after it), then
    /// notifies the cycle event once. The caller fills the headers (same
    /// `seq` in all nine, e.g. with [`CycleMessages::set_header`]). The same as
    /// [`ArmPublisher::start_cycle`] with the cycle's first message, then
    /// [`CycleStarted::finish`].
    ///
    /// No lock, no logging, no allocation of its own; each message is copied once into its
    /// shared-memory slot. iceoryx2 0.10 allocates one small reference-counted handle per loaned
    /// sample (freed again by `send`) on every publishing path of its public API, so a cycle makes
    /// nine short-lived heap allocations inside iceoryx2 (pinned by `tests/no_alloc.rs`).
    ///
    /// On error, the messages sent before the failing one are delivered and the event is not
    /// notified.
    pub fn publish_cycle(&self, cycle: &CycleMessages) -> Result<(), PublishError> {
        self.start_cycle(&cycle.compensated.local_measured_cp)?
            .finish(cycle)
    }

    /// Sends the first message of a cycle, `compensated/local/measured_cp`, as soon as it is
    /// known, and notifies the event [`ServiceNames::cycle_first`], on which the subscriptions
    /// of that topic wait: a publisher that still has the other eight to compute (the
    /// uncompensated pose, the base-frame poses, the status) hands the controllers their pose,
    /// and wakes them, before it does. [`CycleStarted::finish`] sends the rest and notifies the
    /// cycle event ([`ServiceNames::cycle`]); a cycle that is never finished delivers only this
    /// message.
    ///
    /// It does not yield the CPU to the subscribers it woke. A woken subscriber that the
    /// scheduler puts on the publisher's CPU waits for the rest of the cycle (about 20 µs of the
    /// one-subscriber hand-off on the development VM), and a `sched_yield` here halved that, but
    /// a consumer busy for 2 ms per sample on the same CPU then took the service from 1.49 to
    /// 0.64 kHz (benches/README.md, latency section).
    pub fn start_cycle(&self, first: &PoseV2) -> Result<CycleStarted<'_, S>, PublishError> {
        send(
            &self.compensated.local_measured_cp,
            Topic::CompensatedLocalMeasuredCp,
            first,
        )?;
        // A failed notification of the first event does not cost the cycle its other eight
        // messages: finish sends them and then reports it.
        self.cycle_first_wake.bump();
        let first_notify = self
            .cycle_first
            .notify()
            .err()
            .map(|error| PublishError::Notify { error });
        Ok(CycleStarted {
            publisher: self,
            seq: first.header.seq,
            first_notify,
        })
    }

    /// The names this publisher publishes under.
    pub fn names(&self) -> &ServiceNames {
        self.services.names()
    }

    /// The services, e.g. to read `dynamic_config().number_of_subscribers()` for a summary.
    pub fn services(&self) -> &ArmServices<S> {
        &self.services
    }

    /// Subscribers of every topic and listeners of the cycle event (reads shared memory; no
    /// allocation). A subscriber process that died still counts until
    /// [`ArmPublisher::reap_dead_nodes`] (or any other process's node creation) removes it.
    pub fn subscriber_counts(&self) -> SubscriberCounts {
        let mut per_topic = [0; NUM_TOPICS];
        for (n, topic) in per_topic.iter_mut().zip(Topic::ALL) {
            *n = self.number_of_subscribers(topic);
        }
        SubscriberCounts {
            per_topic,
            cycle_listeners: self.services.cycle.dynamic_config().number_of_listeners()
                + self
                    .services
                    .cycle_first
                    .dynamic_config()
                    .number_of_listeners(),
        }
    }

    /// Removes the resources of dead nodes (processes that died without cleaning up, e.g. by
    /// SIGKILL) from all eleven services, so they no longer count as subscribers nor cost the
    /// publisher a notification per cycle. Lists the nodes on the file system: call it every few
    /// seconds from outside the cycle, never on the per-cycle path.
    pub fn reap_dead_nodes(&self) -> ReapReport {
        let s = &self.services;
        let states = [
            s.measured.measured_js.try_cleanup_dead_nodes(),
            s.measured.jaw_measured_js.try_cleanup_dead_nodes(),
            s.measured.local_measured_cp.try_cleanup_dead_nodes(),
            s.measured.measured_cp.try_cleanup_dead_nodes(),
            s.compensated.measured_js.try_cleanup_dead_nodes(),
            s.compensated.jaw_measured_js.try_cleanup_dead_nodes(),
            s.compensated.local_measured_cp.try_cleanup_dead_nodes(),
            s.compensated.measured_cp.try_cleanup_dead_nodes(),
            s.compensated_status.try_cleanup_dead_nodes(),
            s.cycle.try_cleanup_dead_nodes(),
            s.cycle_first.try_cleanup_dead_nodes(),
        ];
        ReapReport {
            reaped: states.iter().map(|c| c.cleanups).sum(),
            failed: states.iter().map(|c| c.failed_cleanups).sum(),
        }
    }

    /// Subscribers currently connected to `topic` (reads shared memory; no allocation).
    pub fn number_of_subscribers(&self, topic: Topic) -> usize {
        let s = &self.services;
        let state = if topic.is_compensated() {
            &s.compensated
        } else {
            &s.measured
        };
        match topic {
            Topic::MeasuredJs | Topic::CompensatedMeasuredJs => {
                state.measured_js.dynamic_config().number_of_subscribers()
            }
            Topic::JawMeasuredJs | Topic::CompensatedJawMeasuredJs => state
                .jaw_measured_js
                .dynamic_config()
                .number_of_subscribers(),
            Topic::LocalMeasuredCp | Topic::CompensatedLocalMeasuredCp => state
                .local_measured_cp
                .dynamic_config()
                .number_of_subscribers(),
            Topic::MeasuredCp | Topic::CompensatedMeasuredCp => {
                state.measured_cp.dynamic_config().number_of_subscribers()
            }
            Topic::CompensatedStatus => s
                .compensated_status
                .dynamic_config()
                .number_of_subscribers(),
        }
    }
}

impl<S: Service> Drop for ArmPublisher<S> {
    fn drop(&mut self) {
        // Subscriptions go back to their iceoryx2 listeners for whichever publisher comes next.
        self.cycle_wake.unclaim();
        self.cycle_first_wake.unclaim();
    }
}

/// Subscriber counts of every topic of an arm ([`ArmPublisher::subscriber_counts`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscriberCounts {
    /// Subscribers per topic, in [`Topic::ALL`] order.
    pub per_topic: [usize; NUM_TOPICS],
    /// Listeners of the two cycle events (event and predictive subscriptions; spinning ones
    /// have none). Each costs the publisher one notification per cycle.
    pub cycle_listeners: usize,
}

impl SubscriberCounts {
    /// Subscribers of `topic`.
    pub fn get(&self, topic: Topic) -> usize {
        Topic::ALL
            .iter()
            .position(|t| *t == topic)
            .map_or(0, |i| self.per_topic[i])
    }

    /// The topic with the most subscribers (the first of equals) and their number.
    pub fn max(&self) -> (Topic, usize) {
        self.extreme(|a, b| a > b)
    }

    /// The topic with the fewest subscribers (the first of equals) and their number.
    pub fn min(&self) -> (Topic, usize) {
        self.extreme(|a, b| a < b)
    }

    fn extreme(&self, better: impl Fn(usize, usize) -> bool) -> (Topic, usize) {
        let mut best = (Topic::ALL[0], self.per_topic[0]);
        for (t, n) in Topic::ALL.into_iter().zip(self.per_topic).skip(1) {
            if better(n, best.1) {
                best = (t, n);
            }
        }
        best
    }

    /// Subscriptions over all topics.
    pub fn total(&self) -> usize {
        self.per_topic.iter().sum()
    }
}

/// What [`ArmPublisher::reap_dead_nodes`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReapReport {
    /// Dead nodes whose resources were removed (summed over the eleven services).
    pub reaped: u64,
    /// Dead nodes whose removal failed (e.g. resources owned by another user).
    pub failed: u64,
}

#[inline]
fn send<S: Service, T: Message>(
    publisher: &Publisher<S, T, ()>,
    topic: Topic,
    value: &T,
) -> Result<(), PublishError> {
    let sample = publisher
        .loan_uninit()
        .map_err(|error| PublishError::Loan { topic, error })?;
    sample
        .write_payload(*value)
        .send()
        .map_err(|error| PublishError::Send { topic, error })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_publish_order_sends_every_topic_once_compensated_pose_first() {
        let mut seen = PUBLISH_ORDER.to_vec();
        seen.sort_by_key(|t| t.index());
        assert_eq!(seen, Topic::ALL);
        assert_eq!(PUBLISH_ORDER[0], Topic::CompensatedLocalMeasuredCp);
        assert!(PUBLISH_ORDER[..4].iter().all(|t| t.is_compensated()));
    }

    #[test]
    fn counts_name_the_topics_with_most_and_fewest_subscribers() {
        let c = SubscriberCounts {
            per_topic: [2, 1, 1, 0, 5, 1, 5, 1, 1],
            cycle_listeners: 3,
        };
        assert_eq!(c.max(), (Topic::CompensatedMeasuredJs, 5));
        assert_eq!(c.min(), (Topic::MeasuredCp, 0));
        assert_eq!(c.get(Topic::CompensatedStatus), 1);
        assert_eq!(c.total(), 17);
    }
}
