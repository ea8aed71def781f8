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

/// The environment variable that moves the project's default root path (e.g. to a runtime
/// directory of the unit, `/run/dvrk-sidecar`): an absolute path of at most
/// [`MAX_ROOT_PATH_LEN`] bytes, read by every process of the project (Rust and Python), so the
/// service and its consumers must all see the same value.
pub const IPC_ROOT_ENV: &str = "DVRK_SIDECAR_IPC_ROOT";

/// The effective uid of this process.
pub(crate) fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// The root path of the project's default domain: `$DVRK_SIDECAR_IPC_ROOT` when set, else
/// `/tmp/dvrk-sidecar-<euid>/`, always with a trailing `/`.
///
/// Why not iceoryx2's `/tmp/iceoryx2/`: whoever creates that directory first owns it, and a
/// local user who creates it before the service can hide the service from its consumers. The
/// uid makes the directory one account's own and the same for every process of that account,
/// whatever its environment (a login shell, a systemd unit, sudo -u): a consumer started before
/// or after the service finds it. [`access::ensure_private_root`](crate::access::ensure_private_root)
/// creates it 0700 and refuses it when another account could have it.
pub fn default_root_path() -> Result<String, IpcError> {
    root_path_for(std::env::var_os(IPC_ROOT_ENV), euid())
}

/// [`default_root_path`] for the value of [`IPC_ROOT_ENV`] and the uid given.
fn root_path_for(env: Option<std::ffi::OsString>, uid: u32) -> Result<String, IpcError> {
    match env {
        None => Ok(format!("/tmp/dvrk-sidecar-{uid}/")),
        Some(v) => {
            let Some(root) = v.to_str() else {
                return Err(IpcError::InvalidDomain {
                    field: "root_path",
                    value: v.to_string_lossy().into_owned(),
                    reason: "DVRK_SIDECAR_IPC_ROOT is not UTF-8",
                });
            };
            check_root_path(root)?;
            Ok(with_slash(root))
        }
    }
}

/// The file-name prefix of the project's default domain: `dvrk_<euid>_`. The project's own (its
/// segments in `/dev/shm` and its service namespace are not iceoryx2's default `iox2_` ones),
/// and one per account: two accounts running a sidecar on one machine do not collide in
/// `/dev/shm`, where iceoryx2 derives a service's segment names from the prefix and the service
/// name alone.
pub fn default_domain_prefix() -> String {
    format!("dvrk_{}_", euid())
}

/// The project's default domain, where `dvrk-sidecar serve` publishes and every consumer looks
/// by default: [`default_domain_prefix`] under [`default_root_path`]. [`create_node`] with
/// `None` uses it.
pub fn default_domain() -> Result<Config, IpcError> {
    domain_config(&default_domain_prefix(), None)
}

/// `true` when `config`'s root path is the project's default one (then [`create_node`] checks
/// that it is private to this account before iceoryx2 uses it).
pub fn is_default_root(config: &Config) -> bool {
    default_root_path().is_ok_and(|r| r.as_bytes() == config.global.root_path().as_bytes())
}

fn check_root_path(root: &str) -> Result<(), IpcError> {
    if !root.starts_with('/') || root.len() > MAX_ROOT_PATH_LEN {
        return Err(IpcError::InvalidDomain {
            field: "root_path",
            value: root.to_owned(),
            reason: "must be an absolute path of at most 48 bytes",
        });
    }
    Ok(())
}

fn with_slash(root: &str) -> String {
    if root.ends_with('/') {
        root.to_owned()
    } else {
        format!("{root}/")
    }
}

/// An iceoryx2 configuration for a domain: iceoryx2's built-in defaults with the file-name
/// `prefix` (shm segments `/dev/shm/<prefix>*`, a separate service namespace) under the root
/// path `root_path` (discovery files and event sockets), by default the project's
/// ([`default_root_path`]).
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
    let root = match root_path {
        Some(root) => {
            check_root_path(root)?;
            with_slash(root)
        }
        None => default_root_path()?,
    };
    let path = Path::new(root.as_bytes())
        .map_err(|_| invalid("root_path", &root, "is not a valid path"))?;
    cfg.global.set_root_path(&path);
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
/// `config: None` uses the project's default domain ([`default_domain`]): iceoryx2's built-in
/// defaults with the project's root path and prefix, never a config file looked up relative to
/// the working directory, so every process of the project agrees regardless of where it runs.
///
/// In a domain whose root path is the project's default one, the root directory is created
/// 0700 if missing, and refused ([`IpcError::RootNotPrivate`]) when it is a symbolic link, not
/// a directory, another account's, or writable by others
/// ([`access::ensure_private_root`](crate::access::ensure_private_root)). Once the node exists,
/// the domain's global management segment, which iceoryx2 0.10 leaves world-writable, is made
/// owner-only ([`access::restrict_global_segment`](crate::access::restrict_global_segment)).
pub fn create_node<S: Service>(name: &str, config: Option<&Config>) -> Result<Node<S>, IpcError> {
    let node_name = NodeName::new(name).map_err(|_| IpcError::InvalidNodeName {
        name: name.to_owned(),
    })?;
    iceoryx2::prelude::set_log_level_from_env_or(ICEORYX2_LOG_LEVEL);
    let default_config;
    let config = match config {
        Some(c) => c,
        None => {
            default_config = default_domain()?;
            &default_config
        }
    };
    if is_default_root(config) {
        crate::access::ensure_private_root(config)?;
    }
    crate::access::refuse_root_in_anothers_domain(config)?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .config(config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<S>()
        .map_err(|source| IpcError::Node {
            name: name.to_owned(),
            source,
        })
        .map_err(|e| crate::access::explain(e, config, format!("creating the node {name:?}")))?;
    // The node's creation made the domain's management segment, world-writable in iceoryx2
    // 0.10: only this account may write it from now on.
    crate::access::restrict_global_segment(config);
    Ok(node)
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
            cfg.global.root_path().to_string(),
            default_root_path().unwrap()
        );
    }

    #[test]
    fn the_default_domain_is_the_accounts_own_not_iceoryx2s() {
        let uid = euid();
        let cfg = default_domain().unwrap();
        assert_eq!(cfg.global.prefix.to_string(), format!("dvrk_{uid}_"));
        assert!(cfg.global.prefix.len() <= MAX_DOMAIN_PREFIX_LEN);
        assert!(is_default_root(&cfg));
        if std::env::var_os(IPC_ROOT_ENV).is_none() {
            let root = format!("/tmp/dvrk-sidecar-{uid}/");
            assert_eq!(cfg.global.root_path().to_string(), root);
            // The longest uid still fits the root path limit.
            assert!("/tmp/dvrk-sidecar-4294967295/".len() <= MAX_ROOT_PATH_LEN);
        }
        assert_ne!(
            cfg.global.root_path().to_string(),
            Config::default().global.root_path().to_string()
        );
        assert!(!is_default_root(
            &domain_config("t_", Some("/tmp/iox2t/")).unwrap()
        ));
    }

    #[test]
    fn the_root_variable_moves_the_default_root_and_is_checked() {
        assert_eq!(
            root_path_for(None, 1000).unwrap(),
            "/tmp/dvrk-sidecar-1000/"
        );
        assert_eq!(
            root_path_for(Some("/run/dvrk-sidecar".into()), 1000).unwrap(),
            "/run/dvrk-sidecar/"
        );
        assert_eq!(
            root_path_for(Some("/run/dvrk-sidecar/".into()), 0).unwrap(),
            "/run/dvrk-sidecar/"
        );
        for bad in [
            "",
            "run/dvrk-sidecar",
            "/tmp/a-very-long-root-path-that-breaks-unix-socket-names/",
        ] {
            match root_path_for(Some(bad.into()), 0) {
                Err(IpcError::InvalidDomain { field, .. }) => assert_eq!(field, "root_path"),
                other => panic!("{bad:?}: {other:?}"),
            }
        }
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
