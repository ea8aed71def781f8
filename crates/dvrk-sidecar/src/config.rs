//! The service configuration (`sidecar.toml`): parsed into [`SidecarParams`], then validated and
//! resolved into a [`SidecarConfig`] that holds every file it names, already loaded and checked.
//!
//! Relative paths in the file are resolved against the directory of the file itself, so a copy in
//! `/etc/dvrk-sidecar/` works the same as `config/sidecar.toml` in the repository.

use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use dvrk_compliance::{ArmKind, ComplianceConfig, Instrument, PsmKinematics};
use dvrk_io::IoConfig;
use dvrk_io::reader::AccessMode;
use serde::Deserialize;

/// The FPGA's UDP port (reference dvrk-board-protocol.md section 3.1).
pub const BOARD_UDP_PORT: u16 = 1394;

/// `sidecar.toml` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SidecarParams {
    /// `sim` (built-in simulated PSM, in-process), `udp:IP[:PORT]` or `fw:N`, as the dVRK spells it.
    pub source: String,
    /// `shared` (read-only quadlet reads; the default) or `exclusive` (block reads).
    #[serde(default = "default_access")]
    pub access: AccessMode,
    /// Actuator conversion file: this project's TOML, or the dVRK's sawRobotIO1394 JSON (v6).
    pub io: PathBuf,
    /// `classic` or `si`.
    pub arm: ArmKind,
    /// Instrument, by its dVRK name (e.g. `LARGE_NEEDLE_DRIVER_400006`).
    pub instrument: String,
    /// Compliance parameter file (see config/compliance/).
    pub compliance: PathBuf,
    /// Cycle rate: a number of Hz, or `"follow"` to run as fast as reads complete.
    #[serde(default = "default_rate")]
    pub rate: Rate,
    /// iceoryx2 service prefix, e.g. `dvrk/PSM1`.
    #[serde(default = "default_prefix")]
    pub prefix: String,
    /// How long one board request waits for its reply (ms) before the cycle is published as
    /// invalid with BOARD_TIMEOUT. The dVRK host waits 20 ms; the sidecar, whose period is
    /// 0.67 ms, waits 5 ms by default so that a lost datagram costs few cycles.
    #[serde(default = "default_reply_timeout_ms")]
    pub reply_timeout_ms: f64,
    /// Simulator settings, used when `source = "sim"`.
    pub sim: Option<SimParams>,
    /// Real-time settings (all optional).
    #[serde(default)]
    pub realtime: RealtimeParams,
}

fn default_access() -> AccessMode {
    AccessMode::Shared
}
fn default_rate() -> Rate {
    Rate::Hz(1500.0)
}
fn default_reply_timeout_ms() -> f64 {
    5.0
}
fn default_prefix() -> String {
    "dvrk/PSM1".to_owned()
}

/// How often the loop runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rate {
    /// A fixed rate in Hz (the dVRK console runs its I/O at 1500 Hz).
    Hz(f64),
    /// As fast as reads complete.
    Follow,
}

impl<'de> Deserialize<'de> for Rate {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Num(f64),
            Text(String),
        }
        match Raw::deserialize(d)? {
            Raw::Num(hz) => Ok(Rate::Hz(hz)),
            Raw::Text(t) if t == "follow" => Ok(Rate::Follow),
            Raw::Text(t) => Err(serde::de::Error::custom(format!(
                "rate must be a number of Hz or \"follow\", got \"{t}\""
            ))),
        }
    }
}

impl fmt::Display for Rate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rate::Hz(hz) => write!(f, "{hz} Hz"),
            Rate::Follow => f.write_str("follow"),
        }
    }
}

/// `[sim]`: the built-in simulated PSM.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimParams {
    /// Scenario file (see config/sim/).
    pub scenario: PathBuf,
}

/// `[realtime]`: optional real-time settings for the loop thread.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeParams {
    /// Pin the loop to this CPU.
    pub cpu: Option<usize>,
    /// Run the loop with SCHED_FIFO at this priority (1-99).
    pub fifo_priority: Option<i32>,
    /// Lock all pages in memory (mlockall) so no page fault stalls the loop.
    #[serde(default)]
    pub mlockall: bool,
}

/// Where samples come from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// The built-in simulated PSM, in-process, through the real board protocol.
    Sim,
    /// Controller boards over Ethernet/UDP.
    Udp(SocketAddr),
    /// Controller boards over FireWire (port number), feature `firewire`.
    Firewire(u32),
    /// Passive tap of the console's own traffic on a network interface (`tap:IFACE`, or
    /// `tap:IFACE:PORT` when the boards answer on another port than 1394, as an emulator may).
    Tap { iface: String, port: u16 },
}

impl Source {
    /// Parses the dVRK's port strings: `sim`, `udp:IP`, `udp:IP:PORT`, `fw:N`.
    pub fn parse(s: &str) -> Result<Self> {
        if s == "sim" {
            return Ok(Source::Sim);
        }
        if let Some(rest) = s.strip_prefix("udp:") {
            if let Ok(ip) = rest.parse::<IpAddr>() {
                return Ok(Source::Udp(SocketAddr::new(ip, BOARD_UDP_PORT)));
            }
            return rest.parse::<SocketAddr>().map(Source::Udp).map_err(|_| {
                anyhow::anyhow!("source \"{s}\": \"{rest}\" is not an IP address or IP:PORT")
            });
        }
        if let Some(rest) = s.strip_prefix("fw:") {
            return rest
                .parse::<u32>()
                .map(Source::Firewire)
                .map_err(|_| anyhow::anyhow!("source \"{s}\": \"{rest}\" is not a port number"));
        }
        if let Some(rest) = s.strip_prefix("tap:") {
            let (iface, port) = match rest.rsplit_once(':') {
                Some((i, p)) => (
                    i,
                    p.parse::<u16>().map_err(|_| {
                        anyhow::anyhow!("source \"{s}\": \"{p}\" is not a UDP port number")
                    })?,
                ),
                None => (rest, BOARD_UDP_PORT),
            };
            // Linux interface names: 1-15 bytes, no '/', ':' or whitespace.
            if iface.is_empty()
                || iface.len() > 15
                || iface.contains(['/', ':'])
                || iface.chars().any(char::is_whitespace)
            {
                bail!("source \"{s}\": \"{iface}\" is not a network interface name");
            }
            return Ok(Source::Tap {
                iface: iface.to_owned(),
                port,
            });
        }
        bail!("source \"{s}\" is not one of sim, udp:IP[:PORT], fw:N, tap:IFACE")
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Sim => f.write_str("sim"),
            Source::Udp(a) => write!(f, "udp:{a}"),
            Source::Firewire(n) => write!(f, "fw:{n}"),
            Source::Tap { iface, port } if *port == BOARD_UDP_PORT => write!(f, "tap:{iface}"),
            Source::Tap { iface, port } => write!(f, "tap:{iface}:{port}"),
        }
    }
}

/// The validated configuration with every referenced file loaded.
pub struct SidecarConfig {
    pub path: PathBuf,
    pub source: Source,
    pub access: AccessMode,
    pub io_path: PathBuf,
    pub io: IoConfig,
    pub arm: ArmKind,
    pub instrument: &'static Instrument,
    pub kinematics: PsmKinematics,
    pub compliance_path: PathBuf,
    pub compliance: ComplianceConfig,
    pub rate: Rate,
    pub prefix: String,
    pub reply_timeout: std::time::Duration,
    pub scenario_path: Option<PathBuf>,
    pub scenario: Option<dvrk_sim::Scenario>,
    pub realtime: RealtimeParams,
}

/// Reads a file with an error that names it.
pub fn read_file(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// Loads an actuator conversion file, TOML or the dVRK's JSON, chosen by extension.
pub fn load_io(path: &Path) -> Result<IoConfig> {
    let text = read_file(path)?;
    let parsed = match path.extension().and_then(|e| e.to_str()) {
        Some("json") => crate::formats::io_from_saw_json(&text),
        _ => crate::formats::io_from_toml(&text),
    };
    parsed.with_context(|| format!("{}: invalid I/O conversion file", path.display()))
}

/// Loads a compliance parameter file.
pub fn load_compliance(path: &Path) -> Result<ComplianceConfig> {
    let text = read_file(path)?;
    crate::formats::compliance_from_toml(&text)
        .with_context(|| format!("{}: invalid compliance parameters", path.display()))
}

/// Loads a simulator scenario file.
pub fn load_scenario(path: &Path) -> Result<dvrk_sim::Scenario> {
    let text = read_file(path)?;
    crate::formats::scenario_from_toml(&text)
        .with_context(|| format!("{}: invalid simulator scenario", path.display()))
}

/// Looks an instrument up by its dVRK name, listing the known ones when it is not found.
pub fn find_instrument(name: &str) -> Result<&'static Instrument> {
    dvrk_compliance::instrument(name).ok_or_else(|| {
        let known: Vec<&str> = dvrk_compliance::instruments()
            .iter()
            .map(|i| i.name)
            .collect();
        anyhow::anyhow!("unknown instrument \"{name}\"; known: {}", known.join(", "))
    })
}

impl SidecarConfig {
    /// Loads `path` and everything it names; every error names the file and the field.
    pub fn load(path: &Path) -> Result<Self> {
        let text = read_file(path)?;
        let params: SidecarParams = toml::from_str(&text)
            .with_context(|| format!("{}: invalid service configuration", path.display()))?;
        Self::from_params(path, params)
    }

    fn from_params(path: &Path, p: SidecarParams) -> Result<Self> {
        let base = path.parent().unwrap_or(Path::new("."));
        let resolve = |q: &Path| -> PathBuf {
            if q.is_absolute() {
                q.to_path_buf()
            } else {
                base.join(q)
            }
        };
        let here = path.display();
        let source = Source::parse(&p.source).with_context(|| format!("{here}: field `source`"))?;
        if let Rate::Hz(hz) = p.rate
            && !(hz.is_finite() && (1.0..=20_000.0).contains(&hz))
        {
            bail!("{here}: field `rate` = {hz}: must be between 1 and 20000 Hz, or \"follow\"");
        }
        if let Some(prio) = p.realtime.fifo_priority
            && !(1..=99).contains(&prio)
        {
            bail!("{here}: field `realtime.fifo_priority` = {prio}: must be 1..=99");
        }
        if !(p.reply_timeout_ms.is_finite() && (0.05..=1000.0).contains(&p.reply_timeout_ms)) {
            bail!(
                "{here}: field `reply_timeout_ms` = {}: must be between 0.05 and 1000 ms",
                p.reply_timeout_ms
            );
        }
        dvrk_ipc::ServiceNames::new(&p.prefix)
            .map_err(|e| anyhow::anyhow!("{here}: field `prefix` = \"{}\": {e}", p.prefix))?;

        let io_path = resolve(&p.io);
        let mut io = load_io(&io_path).with_context(|| format!("{here}: field `io`"))?;
        let instrument = find_instrument(&p.instrument)
            .with_context(|| format!("{here}: field `instrument`"))?;
        if let Some(coupling) = instrument.actuator_to_joint_position {
            io.set_coupling(coupling)
                .with_context(|| format!("{here}: coupling of instrument {}", instrument.name))?;
        }
        let kinematics = PsmKinematics::new(p.arm, instrument);
        let compliance_path = resolve(&p.compliance);
        let compliance = load_compliance(&compliance_path)
            .with_context(|| format!("{here}: field `compliance`"))?;

        let (scenario_path, scenario) = match (&source, p.sim) {
            (Source::Sim, Some(sim)) => {
                let sp = resolve(&sim.scenario);
                let sc =
                    load_scenario(&sp).with_context(|| format!("{here}: field `sim.scenario`"))?;
                (Some(sp), Some(sc))
            }
            (Source::Sim, None) => {
                bail!("{here}: source = \"sim\" needs a [sim] table with `scenario`")
            }
            (_, _) => (None, None),
        };
        Ok(SidecarConfig {
            path: path.to_path_buf(),
            source,
            access: p.access,
            io_path,
            io,
            arm: p.arm,
            instrument,
            kinematics,
            compliance_path,
            compliance,
            rate: p.rate,
            prefix: p.prefix,
            reply_timeout: std::time::Duration::from_secs_f64(p.reply_timeout_ms * 1e-3),
            scenario_path,
            scenario,
            realtime: p.realtime,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn source_strings_follow_the_dvrk_spelling() {
        assert_eq!(Source::parse("sim").unwrap(), Source::Sim);
        assert_eq!(
            Source::parse("udp:169.254.0.100").unwrap(),
            Source::Udp("169.254.0.100:1394".parse().unwrap())
        );
        assert_eq!(
            Source::parse("udp:127.0.0.1:4000").unwrap(),
            Source::Udp("127.0.0.1:4000".parse().unwrap())
        );
        assert_eq!(Source::parse("fw:0").unwrap(), Source::Firewire(0));
        for bad in ["", "udp:", "udp:nohost", "fw:x", "tcp:1.2.3.4", "SIM"] {
            let e = Source::parse(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "error for {bad:?} names it: {e}");
        }
    }

    #[test]
    fn tap_source_names_an_interface() {
        let tap = |i: &str, port| Source::Tap {
            iface: i.to_owned(),
            port,
        };
        assert_eq!(Source::parse("tap:eth1").unwrap(), tap("eth1", 1394));
        assert_eq!(Source::parse("tap:lo:15394").unwrap(), tap("lo", 15394));
        assert_eq!(tap("lo", 1394).to_string(), "tap:lo");
        assert_eq!(tap("lo", 15394).to_string(), "tap:lo:15394");
        for bad in [
            "tap:",
            "tap:lo:x",
            "tap:a/b",
            "tap:sixteen-chars-xy",
            "tap:lo:70000",
        ] {
            let e = Source::parse(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "error for {bad:?} names it: {e}");
        }
    }

    #[test]
    fn rate_is_hz_or_follow() {
        #[derive(Deserialize)]
        struct T {
            rate: Rate,
        }
        assert_eq!(
            toml::from_str::<T>("rate = 1500").unwrap().rate,
            Rate::Hz(1500.0)
        );
        assert_eq!(
            toml::from_str::<T>("rate = 999.5").unwrap().rate,
            Rate::Hz(999.5)
        );
        assert_eq!(
            toml::from_str::<T>("rate = \"follow\"").unwrap().rate,
            Rate::Follow
        );
        let e = toml::from_str::<T>("rate = \"fast\"")
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("fast"), "{e}");
    }
}
