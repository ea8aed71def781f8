//! Nodes, domains and the one place where services are opened or created with the project's QoS.
//!
//! iceoryx2 freezes a service's QoS when the first process creates it, and an opener that asks for
//! more than that fails. Every process (the sidecar, `echo`, Rust, C, C++ and Python consumers)
//! therefore builds the services with the values in [`qos`], whichever starts first.

use iceoryx2::config::Config;
use iceoryx2::node::{Node, NodeBuilder};
use iceoryx2::prelude::{FileName, NodeName, Path, SemanticString as _, SignalHandlingMode};
use iceoryx2::service::Service;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::service_name::ServiceName;

use crate::IpcError;
use crate::msg::{CompensationStatusV4, JawStateV1, JointStateV2, Message, PoseV2};
use crate::names::{ServiceNames, Topic};

/// The project's quality of service. The same numbers are `DVRK_IPC_QOS_*` in `dvrk_ipc.h`.
pub mod qos {
    /// One publisher per service: a second sidecar on the same prefix is refused.
    pub const MAX_PUBLISHERS: usize = 1;
    /// Subscribers per service (the latency benchmark runs 16; tools like `echo` come on top).
    pub const MAX_SUBSCRIBERS: usize = 32;
    /// Samples buffered per subscriber; with safe overflow the oldest is overwritten. 256 cycles
    /// at 1.5 kHz is 170 ms: a consumer descheduled that long on a loaded 2-core PC still gets
    /// every cycle (16 lost cycles in the end-to-end tests whenever a process stalled > 10 ms).
    /// Cost: 32 subscribers x 256 x 208 B = 1.7 MB of shared memory per service.
    pub const SUBSCRIBER_MAX_BUFFER_SIZE: usize = 256;
    /// Samples a subscriber may hold at once.
    pub const SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 2;
    /// A late subscriber gets the newest sample, delivered at the publisher's next send.
    pub const HISTORY_SIZE: usize = 1;
    /// Overwrite the oldest sample of a full buffer instead of blocking the publisher.
    pub const ENABLE_SAFE_OVERFLOW: bool = true;
    /// Nodes per service: every subscriber process plus the publisher and some tools.
    pub const MAX_NODES: usize = MAX_SUBSCRIBERS + 4;
    /// Notifiers of the cycle event: the publisher only.
    pub const EVENT_MAX_NOTIFIERS: usize = 1;
    /// Listeners of the cycle event: one per subscription.
    pub const EVENT_MAX_LISTENERS: usize = MAX_SUBSCRIBERS;
}

/// Longest accepted domain root path: the event socket is `<root><prefix><id>.event` and must
/// fit the 108-byte unix socket path (86-byte roots were measured to fail).
pub const MAX_ROOT_PATH_LEN: usize = 48;
/// Longest accepted domain prefix (see [`MAX_ROOT_PATH_LEN`]).
pub const MAX_DOMAIN_PREFIX_LEN: usize = 24;

/// An iceoryx2 configuration for an isolated domain: iceoryx2's built-in defaults with another
/// file-name `prefix` (shm segments `/dev/shm/<prefix>*`, a separate service namespace) and,
/// optionally, another `root_path` (discovery files and event sockets, default `/tmp/iceoryx2/`).
///
/// Processes only see each other when they use the same domain. Tests give every case its own
/// prefix, e.g. `t<pid>_<n>_` under `/tmp/iox2t/`.
pub fn domain_config(prefix: &str, root_path: Option<&str>) -> Result<Config, IpcError> {
    let invalid =
        |field: &'static str, value: &str, reason: &'static str| IpcError::InvalidDomain {
            field,
            value: value.to_owned(),
            reason,
        };
    if prefix.is_empty() || prefix.len() > MAX_DOMAIN_PREFIX_LEN {
        return Err(invalid("prefix", prefix, "must be 1 to 24 bytes"));
    }
    if !prefix
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-' || b == b'.')
    {
        return Err(invalid(
            "prefix",
            prefix,
            "must contain only ASCII letters, digits, '_', '-' and '.'",
        ));
    }
    let mut cfg = Config::default();
    cfg.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|_| invalid("prefix", prefix, "is not a valid file name"))?;
    if let Some(root) = root_path {
        if !root.starts_with('/') || root.len() > MAX_ROOT_PATH_LEN {
            return Err(invalid(
                "root_path",
                root,
                "must be an absolute path of at most 48 bytes",
            ));
        }
        let mut root = root.to_owned();
        if !root.ends_with('/') {
            root.push('/');
        }
        let path = Path::new(root.as_bytes())
            .map_err(|_| invalid("root_path", &root, "is not a valid path"))?;
        cfg.global.set_root_path(&path);
    }
    Ok(cfg)
}

/// iceoryx2's own log level when `IOX2_LOG_LEVEL` is not set: iceoryx2 logs its failures
/// (e.g. a publisher that died under a subscriber) with a debug dump of its internal state,
/// several KB per line, on the terminal; every one of them also comes back to this crate as an
/// error or an [`crate::Update`] that the application reports in one line.
pub const ICEORYX2_LOG_LEVEL: iceoryx2::prelude::LogLevel = iceoryx2::prelude::LogLevel::Fatal;

/// Creates an iceoryx2 node with signal handling disabled (the application owns SIGINT/SIGTERM).
///
/// Also sets iceoryx2's process-wide log level to `IOX2_LOG_LEVEL` if set, else
/// [`ICEORYX2_LOG_LEVEL`].
///
/// `config: None` uses iceoryx2's built-in defaults, not a config file looked up relative to the
/// working directory, so every process of the project agrees regardless of where it runs.
pub fn create_node<S: Service>(name: &str, config: Option<&Config>) -> Result<Node<S>, IpcError> {
    let node_name = NodeName::new(name).map_err(|_| IpcError::InvalidNodeName {
        name: name.to_owned(),
    })?;
    iceoryx2::prelude::set_log_level_from_env_or(ICEORYX2_LOG_LEVEL);
    let default_config;
    let config = match config {
        Some(c) => c,
        None => {
            default_config = Config::default();
            &default_config
        }
    };
    crate::access::refuse_root_in_anothers_domain(config)?;
    NodeBuilder::new()
        .name(&node_name)
        .config(config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<S>()
        .map_err(|source| IpcError::Node {
            name: name.to_owned(),
            source,
        })
        .map_err(|e| crate::access::explain(e, config, format!("creating the node {name:?}")))
}

/// Opens or creates the pub-sub service of `topic` with the project's QoS.
///
/// Fails with [`IpcError::TopicTypeMismatch`] when `T` is not the topic's payload type.
pub fn open_topic<T: Message, S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
    topic: Topic,
) -> Result<PubSubFactory<S, T, ()>, IpcError> {
    if !topic.carries::<T>() {
        return Err(IpcError::TopicTypeMismatch {
            topic,
            expected: topic.type_name(),
            requested: T::TYPE_NAME,
        });
    }
    let name = names.topic(topic);
    node.service_builder(name)
        .publish_subscribe::<T>()
        .max_publishers(qos::MAX_PUBLISHERS)
        .max_subscribers(qos::MAX_SUBSCRIBERS)
        .max_nodes(qos::MAX_NODES)
        .subscriber_max_buffer_size(qos::SUBSCRIBER_MAX_BUFFER_SIZE)
        .subscriber_max_borrowed_samples(qos::SUBSCRIBER_MAX_BORROWED_SAMPLES)
        .history_size(qos::HISTORY_SIZE)
        .enable_safe_overflow(qos::ENABLE_SAFE_OVERFLOW)
        .open_or_create()
        .map_err(|source| IpcError::OpenService {
            service: name.as_str().to_owned(),
            source,
        })
        .map_err(|e| crate::access::explain(e, node.config(), format!("opening {name}")))
}

/// Opens or creates the cycle event service with the project's QoS.
pub fn open_cycle_event<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<EventFactory<S>, IpcError> {
    open_event(node, names.cycle())
}

/// Opens or creates the event service `name` (one of [`ServiceNames::cycle`],
/// [`ServiceNames::cycle_first`]) with the project's QoS.
pub fn open_event<S: Service>(
    node: &Node<S>,
    name: &ServiceName,
) -> Result<EventFactory<S>, IpcError> {
    node.service_builder(name)
        .event()
        .max_notifiers(qos::EVENT_MAX_NOTIFIERS)
        .max_listeners(qos::EVENT_MAX_LISTENERS)
        .max_nodes(qos::MAX_NODES)
        .open_or_create()
        .map_err(|source| IpcError::OpenEvent {
            service: name.as_str().to_owned(),
            source,
        })
        .map_err(|e| crate::access::explain(e, node.config(), format!("opening {name}")))
}

/// The four pub-sub services of one arm state (raw or compensated).
#[derive(Debug)]
pub struct StateServices<S: Service = iceoryx2::service::ipc::Service> {
    pub measured_js: PubSubFactory<S, JointStateV2, ()>,
    pub jaw_measured_js: PubSubFactory<S, JawStateV1, ()>,
    pub local_measured_cp: PubSubFactory<S, PoseV2, ()>,
    pub measured_cp: PubSubFactory<S, PoseV2, ()>,
}

impl<S: Service> StateServices<S> {
    fn open_or_create(
        node: &Node<S>,
        names: &ServiceNames,
        compensated: bool,
    ) -> Result<Self, IpcError> {
        let pick = |raw: Topic, comp: Topic| if compensated { comp } else { raw };
        Ok(Self {
            measured_js: open_topic(
                node,
                names,
                pick(Topic::MeasuredJs, Topic::CompensatedMeasuredJs),
            )?,
            jaw_measured_js: open_topic(
                node,
                names,
                pick(Topic::JawMeasuredJs, Topic::CompensatedJawMeasuredJs),
            )?,
            local_measured_cp: open_topic(
                node,
                names,
                pick(Topic::LocalMeasuredCp, Topic::CompensatedLocalMeasuredCp),
            )?,
            measured_cp: open_topic(
                node,
                names,
                pick(Topic::MeasuredCp, Topic::CompensatedMeasuredCp),
            )?,
        })
    }
}

/// All eleven services of one arm (nine pub-sub and the two cycle events), opened or created
/// with the project's QoS.
///
/// Ports keep their service alive, so dropping this after creating ports is fine.
#[derive(Debug)]
pub struct ArmServices<S: Service = iceoryx2::service::ipc::Service> {
    names: ServiceNames,
    /// `<prefix>/...`.
    pub measured: StateServices<S>,
    /// `<prefix>/compensated/...`.
    pub compensated: StateServices<S>,
    pub compensated_status: PubSubFactory<S, CompensationStatusV4, ()>,
    /// Notified after the last message of a cycle.
    pub cycle: EventFactory<S>,
    /// Notified after the first message of a cycle.
    pub cycle_first: EventFactory<S>,
}

impl<S: Service> ArmServices<S> {
    /// Opens the services under `names`, creating those that do not exist yet.
    pub fn open_or_create(node: &Node<S>, names: &ServiceNames) -> Result<Self, IpcError> {
        Ok(Self {
            names: names.clone(),
            measured: StateServices::open_or_create(node, names, false)?,
            compensated: StateServices::open_or_create(node, names, true)?,
            compensated_status: open_topic(node, names, Topic::CompensatedStatus)?,
            cycle: open_cycle_event(node, names)?,
            cycle_first: open_event(node, names.cycle_first())?,
        })
    }

    /// The names these services were opened under.
    pub fn names(&self) -> &ServiceNames {
        &self.names
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domain_config_sets_prefix_and_root() {
        let cfg = domain_config("t1_x_", Some("/tmp/iox2t")).unwrap();
        assert_eq!(cfg.global.prefix.as_bytes(), b"t1_x_");
        assert_eq!(cfg.global.root_path().as_bytes(), b"/tmp/iox2t/");
        let cfg = domain_config("abc", None).unwrap();
        assert_eq!(
            cfg.global.root_path().as_bytes(),
            Config::default().global.root_path().as_bytes()
        );
    }

    #[test]
    fn domain_config_rejects_bad_values_by_field() {
        for (prefix, root, field) in [
            ("", None, "prefix"),
            ("a/b", None, "prefix"),
            ("a b", None, "prefix"),
            ("0123456789012345678901234", None, "prefix"),
            ("ok", Some("relative/"), "root_path"),
            (
                "ok",
                Some("/tmp/a-very-long-root-path-that-breaks-unix-socket-names/"),
                "root_path",
            ),
        ] {
            match domain_config(prefix, root) {
                Err(IpcError::InvalidDomain { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{prefix:?} {root:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn node_name_is_validated() {
        let long = "n".repeat(2000);
        match create_node::<iceoryx2::service::local::Service>(&long, None) {
            Err(IpcError::InvalidNodeName { name }) => assert_eq!(name, long),
            other => panic!("{other:?}"),
        }
    }
}
