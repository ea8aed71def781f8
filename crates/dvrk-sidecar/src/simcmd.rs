//! `sim`: the board emulator of the simulated PSM on a real UDP socket, standalone, so the
//! sidecar (`source = "udp:127.0.0.1"`) or the dVRK's own tools can be pointed at it.
//!
//! `sim --arms PSM1,PSM2` emulates several Classic PSMs as one chain of boards on the board ids
//! the dVRK gives them (PSM1 6-7, PSM2 8-9, PSM3 10-11), so the host library sees every board:
//! `--io` is renumbered for each arm, `--scenario` drives every arm unless
//! `--arm-scenario PSM2=FILE` gives one arm its own. Without `--arms` it is PSM1 on 6-7.
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
//! Tried again on 2026-11-26 with `sim --arms PSM1,PSM2 --listen 0.0.0.0:1394` (in a private
//! network namespace, `unshare -n`, with the two settings above): `qlacommand` found nodes 6, 7,
//! 8 and 9 (BoardId = node, QLA1, Rev 9) as FPGA_V2 and as FPGA_V3, and `qladisp 8 9 -br` ran
//! the broadcast query, read and write on PSM2's boards with the hub on board 6, about 2000
//! cycles per mode with StateError 0 and PacketError 0.

use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use dvrk_sim::server::{MulticastJoin, bind_boards};
use dvrk_sim::{ActuatorMap, ArmSpec, CLASSIC_PSM_BOARDS, EthernetMode, Scenario};
use tracing::{info, warn};

use crate::config;
use crate::signals::StopFlag;

#[derive(clap::Args)]
pub struct SimArgs {
    /// Address to answer on (the boards' UDP port is 1394). 0.0.0.0:1394 lets the dVRK host
    /// library find the boards (broadcast, per-board unicast, multicast).
    #[arg(long, default_value = "127.0.0.1:1394")]
    listen: SocketAddr,
    /// Classic PSMs to emulate as one chain of boards, comma-separated: PSM1 (boards 6-7),
    /// PSM2 (8-9), PSM3 (10-11). Default: PSM1.
    #[arg(long, value_name = "ARM,ARM")]
    arms: Option<String>,
    /// Scenario file (see config/sim/), for every arm.
    #[arg(long, default_value = "config/sim/idle.toml")]
    scenario: PathBuf,
    /// One arm's own scenario, `ARM=FILE` (e.g. `PSM2=config/sim/free-motion.toml`);
    /// repeatable, once per arm.
    #[arg(long, value_name = "ARM=FILE")]
    arm_scenario: Vec<String>,
    /// Actuator conversion file the emulated boards encode with; its boards are renumbered
    /// for each arm.
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

/// The accepted arm names with their boards, for messages: `PSM1 (boards 6-7), ...`.
fn accepted_arms() -> String {
    CLASSIC_PSM_BOARDS
        .iter()
        .map(|(n, b)| format!("{n} (boards {}-{})", b[0], b[1]))
        .collect::<Vec<_>>()
        .join(", ")
}

/// `--arms`: Classic PSM names, each once, with their boards. `None` is PSM1.
pub fn parse_arms(arms: Option<&str>) -> Result<Vec<(&'static str, [u8; 2])>> {
    let Some(text) = arms else {
        return Ok(vec![CLASSIC_PSM_BOARDS[0]]);
    };
    let mut out: Vec<(&'static str, [u8; 2])> = Vec::new();
    for name in text.split(',').map(str::trim) {
        let Some(&arm) = CLASSIC_PSM_BOARDS.iter().find(|(n, _)| *n == name) else {
            bail!(
                "--arms \"{text}\": \"{name}\" is not an arm the simulator emulates; accepted: {}",
                accepted_arms()
            );
        };
        if out.iter().any(|(n, _)| *n == name) {
            bail!("--arms \"{text}\": {name} is listed twice; give each arm once");
        }
        out.push(arm);
    }
    Ok(out)
}

/// `--arm-scenario ARM=FILE` values: (arm, file), each arm once and one of `arms`.
fn parse_arm_scenarios<'a>(
    values: &'a [String],
    arms: &[(&'static str, [u8; 2])],
) -> Result<Vec<(&'a str, &'a Path)>> {
    let mut out: Vec<(&str, &Path)> = Vec::new();
    for v in values {
        let Some((name, file)) = v
            .split_once('=')
            .filter(|(n, f)| !n.is_empty() && !f.is_empty())
        else {
            bail!("--arm-scenario \"{v}\": expected ARM=FILE, e.g. PSM2=config/sim/idle.toml");
        };
        if !arms.iter().any(|(n, _)| *n == name) {
            let list: Vec<&str> = arms.iter().map(|(n, _)| *n).collect();
            bail!(
                "--arm-scenario \"{v}\": {name} is not an emulated arm (--arms gives {})",
                list.join(",")
            );
        }
        if out.iter().any(|(n, _)| *n == name) {
            bail!("--arm-scenario \"{v}\": {name} has a scenario already; give each arm one");
        }
        out.push((name, Path::new(file)));
    }
    Ok(out)
}

/// `emulating boards 6 and 7 of a Classic PSM1` for one arm; the arms and their boards for more.
fn emulating(arms: &[(&'static str, [u8; 2])]) -> String {
    match arms {
        [(name, b)] => format!("emulating boards {} and {} of a Classic {name}", b[0], b[1]),
        _ => {
            let each: Vec<String> = arms
                .iter()
                .map(|(n, b)| format!("{n} on boards {} and {}", b[0], b[1]))
                .collect();
            format!(
                "emulating {} boards of {} Classic PSMs as one chain: {}",
                2 * arms.len(),
                arms.len(),
                each.join(", ")
            )
        }
    }
}

pub fn run(args: &SimArgs) -> Result<()> {
    if let Some(arm) = &args.crtk.arm {
        if args.arms.is_some() || !args.arm_scenario.is_empty() {
            bail!(
                "--crtk {arm} with --arms or --arm-scenario: the console stand-in (--crtk) \
                 serves one arm; run one `sim --crtk ARM` per arm, or drop --crtk to emulate \
                 the boards of several arms"
            );
        }
        let scenario = config::load_scenario(&args.scenario)?;
        let io = config::load_io(&args.io)?;
        return crate::crtk_standin::run(&args.crtk, arm, &scenario, &io);
    }
    let arms = parse_arms(args.arms.as_deref())?;
    let own = parse_arm_scenarios(&args.arm_scenario, &arms)?;
    let scenario = config::load_scenario(&args.scenario)?;
    let io = config::load_io(&args.io)?;
    let mut scenarios: Vec<(PathBuf, Scenario)> = Vec::with_capacity(arms.len());
    let mut maps: Vec<ActuatorMap> = Vec::with_capacity(arms.len());
    for (name, boards) in &arms {
        let s = match own.iter().find(|(n, _)| n == name) {
            Some((_, file)) => (file.to_path_buf(), config::load_scenario(file)?),
            None => (args.scenario.clone(), scenario.clone()),
        };
        let arm_io = config::renumber_boards(io.clone(), boards)
            .with_context(|| format!("{}: boards of {name} ({boards:?})", args.io.display()))?;
        let map = ActuatorMap::from_io_config(&arm_io)
            .with_context(|| format!("{}: cannot emulate {name}", args.io.display()))?;
        scenarios.push(s);
        maps.push(map);
    }
    let specs: Vec<ArmSpec<'_>> = arms
        .iter()
        .zip(&scenarios)
        .zip(&maps)
        .map(|(((_, boards), (_, scenario)), map)| ArmSpec {
            scenario,
            map: *map,
            boards: *boards,
        })
        .collect();
    let mut emulator = dvrk_sim::Emulator::chain(&specs).with_context(|| {
        let files: Vec<String> = scenarios
            .iter()
            .map(|(f, _)| f.display().to_string())
            .collect();
        format!("{}: cannot start the emulator", files.join(", "))
    })?;
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
    let names: Vec<&str> = arms.iter().map(|(n, _)| *n).collect();
    let files: Vec<String> = arms
        .iter()
        .zip(&scenarios)
        .map(|((n, _), (f, _))| format!("{n}={}", f.display()))
        .collect();
    info!(
        listen = %args.listen, arms = %names.join(","),
        scenario = %if arms.len() == 1 { scenarios[0].0.display().to_string() } else { files.join(",") },
        ethernet = ?emulator.ethernet_mode(), "{}", emulating(&arms)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arms_are_classic_psms_each_once() {
        assert_eq!(parse_arms(None).unwrap(), [("PSM1", [6, 7])]);
        assert_eq!(
            parse_arms(Some("PSM1,PSM2")).unwrap(),
            [("PSM1", [6, 7]), ("PSM2", [8, 9])]
        );
        assert_eq!(
            parse_arms(Some("PSM3, PSM1")).unwrap(),
            [("PSM3", [10, 11]), ("PSM1", [6, 7])]
        );
        let e = parse_arms(Some("PSM1,ECM")).unwrap_err().to_string();
        assert!(
            e.contains("\"ECM\"")
                && e.contains("PSM1 (boards 6-7), PSM2 (boards 8-9), PSM3 (boards 10-11)"),
            "{e}"
        );
        let e = parse_arms(Some("PSM2,PSM2")).unwrap_err().to_string();
        assert!(e.contains("PSM2 is listed twice"), "{e}");
        assert!(parse_arms(Some("")).is_err());
        assert!(parse_arms(Some("psm1")).is_err());
    }

    #[test]
    fn an_arm_scenario_names_an_emulated_arm_once() {
        let arms = parse_arms(Some("PSM1,PSM2")).unwrap();
        let v = vec!["PSM2=a.toml".to_owned()];
        assert_eq!(
            parse_arm_scenarios(&v, &arms).unwrap(),
            [("PSM2", Path::new("a.toml"))]
        );
        let bad = |v: &str| {
            parse_arm_scenarios(&[v.to_owned()], &arms)
                .unwrap_err()
                .to_string()
        };
        assert!(bad("PSM3=a.toml").contains("PSM3 is not an emulated arm"));
        assert!(bad("PSM2").contains("expected ARM=FILE"));
        assert!(bad("=a.toml").contains("expected ARM=FILE"));
        let twice = vec!["PSM1=a.toml".to_owned(), "PSM1=b.toml".to_owned()];
        let e = parse_arm_scenarios(&twice, &arms).unwrap_err().to_string();
        assert!(e.contains("PSM1 has a scenario already"), "{e}");
    }

    #[test]
    fn the_start_up_line_names_the_arms_and_boards() {
        assert_eq!(
            emulating(&parse_arms(None).unwrap()),
            "emulating boards 6 and 7 of a Classic PSM1"
        );
        assert_eq!(
            emulating(&parse_arms(Some("PSM1,PSM2")).unwrap()),
            "emulating 4 boards of 2 Classic PSMs as one chain: PSM1 on boards 6 and 7, PSM2 on \
             boards 8 and 9"
        );
    }
}
