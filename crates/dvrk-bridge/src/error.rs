//! The one error enum of this crate.

use std::path::PathBuf;

use dvrk_ipc::IpcError;
use dvrk_ipc::iceoryx2::port::ReceiveError;
use dvrk_ipc::iceoryx2::port::subscriber::SubscriberCreateError;

use crate::dds::CdrBody;

/// Errors of the bridges. Setup errors name what was being set up; run-time errors name the
/// topic.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BridgeError {
    /// An argument is not usable (`--rate 0`, an arm name that is not a ROS name, ...).
    #[error("invalid {what} {value:?}: {reason}")]
    InvalidArgument {
        what: &'static str,
        value: String,
        reason: &'static str,
    },

    /// Opening the sidecar's shared-memory services failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),

    /// A subscriber port could not be created.
    #[error("subscribing to {service:?} failed: {source}")]
    Subscribe {
        service: String,
        #[source]
        source: SubscriberCreateError,
    },

    /// Taking a sample out of shared memory failed.
    #[error("receiving from {service:?} failed: {source:?}")]
    Receive {
        service: String,
        source: ReceiveError,
    },

    /// Waiting for the sidecar's cycle failed.
    #[error("waiting for the cycle of {service:?} failed: {source}")]
    Wait {
        service: String,
        #[source]
        source: dvrk_ipc::SubscriptionError,
    },

    /// Setting up DDS (participant, publisher, topic, writer) failed.
    #[error("DDS setup failed at {step} {name:?}: {reason}")]
    DdsSetup {
        step: &'static str,
        name: String,
        reason: String,
    },

    /// Writing a DDS sample failed.
    #[error("writing DDS topic {topic:?} failed: {source}")]
    DdsWrite {
        topic: String,
        #[source]
        source: Box<rustdds::dds::WriteError<CdrBody>>,
    },

    /// Creating or writing the MCAP file failed.
    #[error("MCAP file {path}: {source}")]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },

    /// Creating the output file failed.
    #[error("creating {path}: {source}")]
    CreateFile {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// Reading the clocks failed.
    #[error("reading {clock} failed: {source}")]
    Clock {
        clock: &'static str,
        #[source]
        source: std::io::Error,
    },

    /// `record` got no message from any of its arms: no `serve` published them.
    #[error(
        "nothing recorded: no message from {arms} within {waited_s:.1} s (is `dvrk-sidecar serve` \
         running with these prefixes?){removed}"
    )]
    NothingRecorded {
        /// The arms waited for, with their shared-memory prefixes.
        arms: String,
        waited_s: f64,
        /// What became of the file (`; run.mcap, which held no message, was removed`).
        removed: String,
    },

    /// The thread that writes the recording stopped before an arm's thread (it failed: its
    /// error is the one reported).
    #[error("the recording's writer stopped")]
    WriterStopped,
    #[error(
        "DDS stopped: RustDDS's event loop has ended (an interrupted poll, e.g. after this \
         process was stopped and continued: Ctrl-Z then fg, SIGSTOP/SIGCONT); nothing more \
         would reach ROS 2, so the bridge exits (under systemd it is restarted)"
    )]
    DdsStopped,

    /// A thread could not be started.
    #[error("starting the thread of {arm}: {source}")]
    Thread {
        arm: String,
        #[source]
        source: std::io::Error,
    },
}
