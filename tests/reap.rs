//! `serve` removes the shared-memory resources of a subscriber process killed with SIGKILL, from
//! its housekeeping thread, while its summaries go on.
//!
//! Its own test binary: cargo runs test binaries one after the other, and any other process that
//! creates an iceoryx2 node meanwhile (every other end-to-end test does) would also clean up the
//! dead node, so in a shared binary the test could not tell who reaped it.

mod common;

use std::process::{Command, Stdio};
use std::time::Duration;

use common::*;
use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::iceoryx2::service::port_factory::PortFactory as _;
use dvrk_ipc::{JointStateV2, ServiceNames, Topic};

const LIVENESS: Duration = Duration::from_secs(60);

#[test]
fn a_killed_subscriber_is_reaped_and_summaries_go_on() {
    let prefix = unique_prefix("reap");
    let cfg = write_config("reap", "sim", "shared", &prefix, "idle.toml");
    let mut serve = serve(&cfg);
    assert_eq!(
        echo_json(&format!("{prefix}/measured_js"), 5, LIVENESS).len(),
        5,
        "serve never published"
    );
    // This process's node and service exist before the kill, so this process is not the one
    // that reaps (creating a node or opening a service can also clean up dead nodes).
    let node = dvrk_ipc::create_node::<Service>("e2e-reap", None).unwrap();
    let names = ServiceNames::new(&prefix).unwrap();
    let service =
        dvrk_ipc::open_topic::<JointStateV2, Service>(&node, &names, Topic::MeasuredJs).unwrap();
    let subscribers = || service.dynamic_config().number_of_subscribers();
    let mut echo = Proc::spawn(
        "echo",
        // A spinning subscriber has no listener: a dead listener's socket would make the
        // publisher's notifier find the dead node by itself.
        Command::new(sidecar_bin())
            .args(["echo", "--wait", "spin", &format!("{prefix}/measured_js")])
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    );
    assert!(
        eventually(LIVENESS, || (subscribers() == 1).then_some(())).is_some(),
        "echo never subscribed"
    );
    echo.signal(libc::SIGKILL);
    echo.wait_timeout(Duration::from_secs(10)).unwrap();
    assert!(
        eventually(Duration::from_secs(60), || (subscribers() == 0)
            .then_some(()))
        .is_some(),
        "the killed subscriber was never reaped"
    );
    let (st, log) = serve.terminate();
    assert!(st.success(), "{log}");
    assert!(log.contains("removed dead subscriber nodes"), "{log}");
    // The summaries come once a second from the housekeeping thread.
    assert!(log.matches("summary").count() >= 2, "{log}");
}
