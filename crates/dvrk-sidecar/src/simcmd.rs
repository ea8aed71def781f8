//! `sim`: the board emulator of the simulated PSM on a real UDP socket, standalone, so the
//! sidecar (`source = "udp:127.0.0.1"`) or the dVRK's own tools can be pointed at it.
//!
//! With `--listen 0.0.0.0:1394` the dVRK host library (port string `udp:127.0.0.1`) discovers
//! it unchanged: the socket sees the subnet broadcast, the per-board unicast addresses and the
//! multicast group joined on `--multicast-if` (reference §3.3, §10). At exit it logs the
//! requests it received per client as `requests_by_peer=ADDR:PORT/N,...`.
//!
//! Tried on 2026-11-23 with the dVRK host library itself (mechatronics-software @8e6a4f7, its
//! `qlacommand -pudp:127.0.0.1`): in both modes it found "Node 6, BoardId = 6, FPGA_V3 (or
//! FPGA_V2), Hardware = QLA1, Firmware Version = 9" and node 7, and finished initialisation.
//! The library does not choose the multicast interface itself, so on one machine loopback needs
//! `ip link set lo multicast on` and `ip route add 224.0.0.0/4 dev lo` (root); without them its
//! discovery stops at the hub's Ethernet-status read, the first request sent by multicast.

use std::net::{Ipv4Addr, SocketAddr};
use std::path::PathBuf;

use anyhow::{Context, Result};
use dvrk_sim::EthernetMode;
use dvrk_sim::server::{MulticastJoin, bind_boards};
use tracing::{info, warn};

use crate::config;
use crate::signals::StopFlag;

#[derive(clap::Args)]
pub struct SimArgs {
    /// Address to answer on (the boards' UDP port is 1394). 0.0.0.0:1394 lets the dVRK host
    /// library find the boards (broadcast, per-board unicast, multicast).
    #[arg(long, default_value = "127.0.0.1:1394")]
    listen: SocketAddr,
    /// Scenario file (see config/sim/).
    #[arg(long, default_value = "config/sim/idle.toml")]
    scenario: PathBuf,
    /// Actuator conversion file the emulated boards encode with.
    #[arg(long, default_value = "config/io/psm-classic.toml")]
    io: PathBuf,
    /// Override the scenario's `ethernet`: `bridge` (FPGA V2) or `ethernet-only` (FPGA V3,
    /// Rev 9, hub data sent unasked after a broadcast query).
    #[arg(long, value_parser = ["bridge", "ethernet-only"])]
    ethernet: Option<String>,
    /// Address of the interface on which to join the multicast group 224.0.0.100 when
    /// listening on 0.0.0.0 (127.0.0.1 = lo).
    #[arg(long, default_value = "127.0.0.1")]
    multicast_if: Ipv4Addr,
    #[command(flatten)]
    crtk: crate::crtk_standin::CrtkArgs,
}

pub fn run(args: &SimArgs) -> Result<()> {
    let scenario = config::load_scenario(&args.scenario)?;
    if let Some(arm) = &args.crtk.arm {
        let io = config::load_io(&args.io)?;
        return crate::crtk_standin::run(&args.crtk, arm, &scenario, &io);
    }
    let io = config::load_io(&args.io)?;
    let mut emulator = dvrk_sim::Emulator::new(&scenario, &io)
        .with_context(|| format!("{}: cannot start the emulator", args.scenario.display()))?;
    match args.ethernet.as_deref() {
        Some("bridge") => emulator.set_ethernet_mode(EthernetMode::Bridge),
        Some("ethernet-only") => emulator.set_ethernet_mode(EthernetMode::EthernetOnly),
        _ => {}
    }
    let (socket, join) = bind_boards(args.listen, args.multicast_if)
        .with_context(|| format!("binding {}", args.listen))?;
    match join {
        MulticastJoin::Joined(ifa) => {
            info!(group = %dvrk_sim::server::MULTICAST_GROUP, interface = %ifa, "multicast joined")
        }
        MulticastJoin::NotAttempted => {}
        MulticastJoin::Failed(e) => warn!(
            group = %dvrk_sim::server::MULTICAST_GROUP, interface = %args.multicast_if,
            "multicast not joined ({e}); on lo it needs `ip link set lo multicast on` and \
             `ip route add 224.0.0.0/4 dev lo`; broadcast and unicast still work"
        ),
    }
    let stop = StopFlag::install()?;
    info!(
        listen = %args.listen, scenario = %args.scenario.display(),
        ethernet = ?emulator.ethernet_mode(), "emulating boards 6 and 7 of a Classic PSM1"
    );
    let (_, summary) = dvrk_sim::server::serve_udp(socket, emulator, stop.as_atomic())
        .with_context(|| format!("serving on {}", args.listen))?;
    let c = summary.counters;
    info!(
        datagrams_in = summary.datagrams_in,
        datagrams_out = summary.datagrams_out,
        writes = c.writes,
        block_reads_address0 = c.block_reads_address0,
        quadlet_reads = c.quadlet_reads,
        broadcast_queries = c.broadcast_queries,
        hub_reads = c.hub_reads,
        requests_by_peer = %summary.requests_by_peer,
        "emulator stopped"
    );
    Ok(())
}
