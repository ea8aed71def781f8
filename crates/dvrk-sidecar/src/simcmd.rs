//! `sim`: the board emulator of the simulated PSM on a real UDP socket, standalone, so the
//! sidecar (`source = "udp:127.0.0.1"`) or the dVRK's own tools can be pointed at it.

use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;

use anyhow::{Context, Result};
use tracing::info;

use crate::config;
use crate::signals::StopFlag;

#[derive(clap::Args)]
pub struct SimArgs {
    /// Address to answer on (the boards' UDP port is 1394).
    #[arg(long, default_value = "127.0.0.1:1394")]
    listen: SocketAddr,
    /// Scenario file (see config/sim/).
    #[arg(long, default_value = "config/sim/idle.toml")]
    scenario: PathBuf,
    /// Actuator conversion file the emulated boards encode with.
    #[arg(long, default_value = "config/io/psm-classic.toml")]
    io: PathBuf,
}

pub fn run(args: &SimArgs) -> Result<()> {
    let scenario = config::load_scenario(&args.scenario)?;
    let io = config::load_io(&args.io)?;
    let emulator = dvrk_sim::Emulator::new(&scenario, &io)
        .with_context(|| format!("{}: cannot start the emulator", args.scenario.display()))?;
    let socket =
        UdpSocket::bind(args.listen).with_context(|| format!("binding {}", args.listen))?;
    let stop = StopFlag::install()?;
    info!(listen = %args.listen, scenario = %args.scenario.display(), "emulating boards 6 and 7 of a Classic PSM1");
    let (_, summary) = dvrk_sim::server::serve_udp(socket, emulator, stop.as_atomic())
        .with_context(|| format!("serving on {}", args.listen))?;
    let c = summary.counters;
    info!(
        datagrams_in = summary.datagrams_in,
        datagrams_out = summary.datagrams_out,
        writes = c.writes,
        block_reads_address0 = c.block_reads_address0,
        quadlet_reads = c.quadlet_reads,
        "emulator stopped"
    );
    Ok(())
}
