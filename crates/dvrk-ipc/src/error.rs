//! Errors. [`IpcError`] covers setup (names, nodes, services, ports) and may allocate; the
//! per-cycle errors [`PublishError`] and [`SubscriptionError`] are `Copy` and carry no strings.

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::port::listener::{ListenerCreateError, ListenerWaitError};
use iceoryx2::port::notifier::{NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::port::subscriber::SubscriberCreateError;
use iceoryx2::port::{LoanError, ReceiveError, SendError};
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError;

use crate::names::Topic;

/// Setup errors of this crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IpcError {
    /// The service prefix is not usable.
    #[error("invalid service prefix {prefix:?}: {reason}")]
    InvalidPrefix {
        prefix: String,
        reason: &'static str,
    },

    /// A field of the iceoryx2 domain settings ([`crate::domain_config`]) is not usable.
    #[error("invalid iceoryx2 {field} {value:?}: {reason}")]
    InvalidDomain {
        field: &'static str,
        value: String,
        reason: &'static str,
    },

    /// The node name is not a valid iceoryx2 node name.
    #[error("invalid iceoryx2 node name {name:?}")]
    InvalidNodeName { name: String },

    /// The iceoryx2 node could not be created (permissions on /dev/shm or the root path, ...).
    #[error("creating the iceoryx2 node {name:?} failed: {source}")]
    Node {
        name: String,
        #[source]
        source: NodeCreationFailure,
    },

    /// A publish-subscribe service could not be opened or created, e.g. because another process
    /// created it with a different payload type (`IncompatibleTypes`) or smaller QoS limits.
    #[error("opening or creating service {service:?} failed: {source}")]
    OpenService {
        service: String,
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },

    /// The cycle event service could not be opened or created.
    #[error("opening or creating event service {service:?} failed: {source}")]
    OpenEvent {
        service: String,
        #[source]
        source: EventOpenOrCreateError,
    },

    /// The type parameter does not match the payload type of the topic.
    #[error("topic {topic} carries {expected}, not {requested}")]
    TopicTypeMismatch {
        topic: Topic,
        expected: &'static str,
        requested: &'static str,
    },

    /// Another publisher (normally another dvrk-sidecar) is alive on this prefix.
    #[error("another dvrk-sidecar is already publishing under {prefix}")]
    AlreadyPublishing { prefix: String },

    /// The publisher port could not be created.
    #[error("creating the publisher of {service:?} failed: {source}")]
    CreatePublisher {
        service: String,
        #[source]
        source: PublisherCreateError,
    },

    /// The notifier of the cycle event could not be created.
    #[error("creating the notifier of {service:?} failed: {source}")]
    CreateNotifier {
        service: String,
        #[source]
        source: NotifierCreateError,
    },

    /// The subscriber port could not be created (e.g. `ExceedsMaxSupportedSubscribers`).
    #[error("creating a subscriber of {service:?} failed: {source}")]
    CreateSubscriber {
        service: String,
        #[source]
        source: SubscriberCreateError,
    },

    /// The listener of the cycle event could not be created (a root path that is too long makes
    /// the unix socket path exceed 108 bytes).
    #[error("creating a listener of {service:?} failed: {source}")]
    CreateListener {
        service: String,
        #[source]
        source: ListenerCreateError,
    },

    /// This process may not use a file of the iceoryx2 domain, which another user created
    /// (iceoryx2 0.10 opens what it creates to its owner only): see [`crate::access`].
    #[error(
        "permission denied on the shared memory of the dVRK sidecar while {during}: {} belongs \
         to user {owner} (mode {mode:04o}) and iceoryx2 0.10 lets only its owner use it. {hint}",
        path.display()
    )]
    PermissionDenied {
        during: String,
        path: std::path::PathBuf,
        owner: String,
        mode: u32,
        /// What to do, in a sentence (see [`crate::access::hint`]).
        hint: String,
        #[source]
        source: Box<IpcError>,
    },

    /// This process runs as root while the domain's root path belongs to another account (the
    /// service's): what root would create there (node files, segments) only root could use
    /// again, locking the service and its consumers out. Refused before anything is created.
    #[error(
        "you are root, but the dVRK sidecar's shared memory {} belongs to user {owner}: files \
         created as root would lock the service and its consumers out. Run as {owner}: \
         sudo -u {owner} <command>",
        path.display()
    )]
    RootWouldLockOut {
        path: std::path::PathBuf,
        owner: String,
    },

    /// The root directory of the project's default domain is not this account's alone (see
    /// [`crate::access::ensure_private_root`]): whoever else can write it controls what
    /// consumers find there (it can hide the service from them). Refused before iceoryx2 uses it.
    #[error("{message}")]
    RootNotPrivate {
        path: std::path::PathBuf,
        problem: RootProblem,
        /// The owner's user name (or `uid N`).
        owner: String,
        /// Permission bits (e.g. 0o777).
        mode: u32,
        /// The whole sentence: the path, what is wrong, its owner and mode, this process's
        /// account, and what to do.
        message: String,
    },

    /// The root directory of the project's default domain could not be created or examined
    /// (its parent is missing or not writable by this account).
    #[error(
        "creating the dVRK sidecar's shared-memory directory {} failed: {source}. Set {} to a \
         directory this account may create (an absolute path of at most 48 bytes)",
        path.display(),
        crate::IPC_ROOT_ENV
    )]
    RootDirectory {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The wake-up word of a cycle event ([`crate::wake`]) could not be opened or created, or
    /// was refused (a symbolic link, another account's file, or one others may write).
    #[error("opening the wake-up word {} failed: {source}", path.display())]
    Wake {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// An environment variable of the project holds a value it does not take.
    #[error("{name}={value:?}: expected {expected}")]
    InvalidEnvironment {
        name: &'static str,
        value: String,
        expected: &'static str,
    },

    /// The timer of a predictive subscription could not be set up.
    #[error("{what} failed: {source}")]
    Timer {
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
}

/// Why the root directory of the default domain is refused ([`IpcError::RootNotPrivate`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum RootProblem {
    /// A symbolic link (iceoryx2 would follow it wherever it points).
    Symlink,
    /// Something else than a directory.
    NotADirectory,
    /// A directory of another account.
    OtherOwner,
    /// A directory that group or others may write.
    WritableByOthers,
    /// Its parent lets another account rename or replace it (writable by another user, no
    /// sticky bit).
    UnsafeParent,
}

/// Per-cycle publishing errors (`Copy`, no allocation).
///
/// Messages of the cycle sent before the failing one are already delivered; the cycle event is
/// not notified after a failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PublishError {
    #[error("loaning a sample of {topic} failed: {error}")]
    Loan { topic: Topic, error: LoanError },
    #[error("sending {topic} failed: {error}")]
    Send { topic: Topic, error: SendError },
    #[error("notifying the cycle event failed: {error}")]
    Notify { error: NotifierNotifyError },
}

/// Errors of [`crate::Subscription::wait`] (`Copy`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SubscriptionError {
    #[error("receiving a sample failed: {0}")]
    Receive(ReceiveError),
    #[error("draining the cycle event failed: {0}")]
    ListenerWait(ListenerWaitError),
    /// `ppoll` on the cycle event (and timer) failed; the errno.
    #[error("waiting for the cycle event failed: {}", std::io::Error::from_raw_os_error(*.0))]
    Poll(i32),
    /// Arming the predictive timer failed; the errno.
    #[error("arming the wake-up timer failed: {}", std::io::Error::from_raw_os_error(*.0))]
    Timer(i32),
    /// A wait that needs the cycle event on a subscription without a listener (internal).
    #[error("this subscription has no listener on the cycle event")]
    NoListener,
    /// Sleeping on the cycle's wake-up word failed; the errno.
    #[error("waiting for the cycle's wake-up failed: {}", std::io::Error::from_raw_os_error(*.0))]
    Wake(i32),
    /// A predictive wait on a subscription without a timer (internal).
    #[error("this subscription has no wake-up timer")]
    NoTimer,
}
