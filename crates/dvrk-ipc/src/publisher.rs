//! The publishing side: one publisher per topic and the notifier of the cycle event.

use iceoryx2::node::Node;
use iceoryx2::port::notifier::{Notifier, NotifierCreateError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::service::Service;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

use crate::error::{IpcError, PublishError};
use crate::msg::{CompensationStatusV2, JointStateV1, Message, PoseV1};
use crate::names::{ServiceNames, Topic};
use crate::services::ArmServices;

/// Publishes the five messages of a cycle and notifies the cycle event.
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
    measured_js: Publisher<S, JointStateV1, ()>,
    measured_cp: Publisher<S, PoseV1, ()>,
    compensated_measured_js: Publisher<S, JointStateV1, ()>,
    compensated_measured_cp: Publisher<S, PoseV1, ()>,
    compensated_status: Publisher<S, CompensationStatusV2, ()>,
    cycle: Notifier<S>,
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
        let measured_js = create_publisher(&services.measured_js, names)?;
        let measured_cp = create_publisher(&services.measured_cp, names)?;
        let compensated_measured_js = create_publisher(&services.compensated_measured_js, names)?;
        let compensated_measured_cp = create_publisher(&services.compensated_measured_cp, names)?;
        let compensated_status = create_publisher(&services.compensated_status, names)?;
        let attempt = || services.cycle.notifier_builder().create();
        let cycle = match attempt() {
            Err(NotifierCreateError::ExceedsMaxSupportedNotifiers) => {
                services.cycle.try_cleanup_dead_nodes();
                attempt()
            }
            other => other,
        }
        .map_err(|source| match source {
            NotifierCreateError::ExceedsMaxSupportedNotifiers => IpcError::AlreadyPublishing {
                prefix: names.prefix().to_owned(),
            },
            source => IpcError::CreateNotifier {
                service: names.cycle().as_str().to_owned(),
                source,
            },
        })?;
        Ok(Self {
            services,
            measured_js,
            measured_cp,
            compensated_measured_js,
            compensated_measured_cp,
            compensated_status,
            cycle,
        })
    }

    /// Sends the five messages of one cycle, in [`Topic::ALL`] order, then notifies the cycle
    /// event once. The caller fills the headers (same `seq` in all five).
    ///
    /// No lock, no logging, no allocation of its own; each message is copied once into its
    /// shared-memory slot. iceoryx2 0.10 allocates one small reference-counted handle per loaned
    /// sample (freed again by `send`) on every publishing path of its public API, so a cycle makes
    /// five short-lived heap allocations inside iceoryx2 (pinned by `tests/no_alloc.rs`).
    ///
    /// On error, the messages sent before the failing one are delivered and the event is not
    /// notified.
    pub fn publish_cycle(
        &self,
        measured_js: &JointStateV1,
        measured_cp: &PoseV1,
        compensated_measured_js: &JointStateV1,
        compensated_measured_cp: &PoseV1,
        compensated_status: &CompensationStatusV2,
    ) -> Result<(), PublishError> {
        debug_assert!(
            [
                measured_cp.header.seq,
                compensated_measured_js.header.seq,
                compensated_measured_cp.header.seq,
                compensated_status.header.seq,
            ]
            .iter()
            .all(|s| *s == measured_js.header.seq),
            "all messages of a cycle carry the same seq"
        );
        send(&self.measured_js, Topic::MeasuredJs, measured_js)?;
        send(&self.measured_cp, Topic::MeasuredCp, measured_cp)?;
        send(
            &self.compensated_measured_js,
            Topic::CompensatedMeasuredJs,
            compensated_measured_js,
        )?;
        send(
            &self.compensated_measured_cp,
            Topic::CompensatedMeasuredCp,
            compensated_measured_cp,
        )?;
        send(
            &self.compensated_status,
            Topic::CompensatedStatus,
            compensated_status,
        )?;
        self.cycle
            .notify()
            .map_err(|error| PublishError::Notify { error })?;
        Ok(())
    }

    /// The names this publisher publishes under.
    pub fn names(&self) -> &ServiceNames {
        self.services.names()
    }

    /// The services, e.g. to read `dynamic_config().number_of_subscribers()` for a summary.
    pub fn services(&self) -> &ArmServices<S> {
        &self.services
    }

    /// Subscribers currently connected to `topic` (reads shared memory; no allocation).
    pub fn number_of_subscribers(&self, topic: Topic) -> usize {
        let s = &self.services;
        match topic {
            Topic::MeasuredJs => s.measured_js.dynamic_config().number_of_subscribers(),
            Topic::MeasuredCp => s.measured_cp.dynamic_config().number_of_subscribers(),
            Topic::CompensatedMeasuredJs => s
                .compensated_measured_js
                .dynamic_config()
                .number_of_subscribers(),
            Topic::CompensatedMeasuredCp => s
                .compensated_measured_cp
                .dynamic_config()
                .number_of_subscribers(),
            Topic::CompensatedStatus => s
                .compensated_status
                .dynamic_config()
                .number_of_subscribers(),
        }
    }
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
