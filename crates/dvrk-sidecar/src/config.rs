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
use nalgebra::{Isometry3, UnitQuaternion};
use serde::Deserialize;

use crate::text::num;

/// The most arms one service serves (a console drives two or three PSMs); the loop's per-second
/// summary is a fixed array of this size.
pub const MAX_ARMS: usize = 8;

/// The FPGA's UDP port (reference dvrk-board-protocol.md section 3.1).
pub const BOARD_UDP_PORT: u16 = 1394;

/// `sidecar.toml` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SidecarParams {
    /// `sim` (built-in simulated PSM, in-process), `udp:IP[:PORT]`, `fw:N` or `tap:IFACE`, as the
    /// dVRK spells it. Required: a missing or empty `source` refuses to start (the installed
    /// default configuration leaves it empty, so a lab PC never publishes a simulated arm by
    /// accident).
    #[serde(default)]
    pub source: Option<String>,
    /// `shared` (read-only quadlet reads; the default) or `exclusive` (block reads).
    #[serde(default = "default_access")]
    pub access: AccessMode,
    /// Actuator conversion file: this project's TOML, or the dVRK's sawRobotIO1394 JSON (v6).
    pub io: PathBuf,
    /// `classic` or `si`.
    pub arm: ArmKind,
    /// Instrument: its dVRK tool file name (e.g. `LARGE_NEEDLE_DRIVER_400006`) or the console's
    /// `NAME:MODEL[min..max]` (e.g. `LARGE_NEEDLE_DRIVER:420006[12..]`), or `"console"`: the
    /// one the dVRK console reports on `/<arm>/tool_type` (DDS domain `ROS_DOMAIN_ID`),
    /// followed as it changes (implies `follow_console`).
    pub instrument: String,
    /// Follow the dVRK console over DDS (ROS 2, domain `ROS_DOMAIN_ID`): its operating state
    /// (samples invalid while not homed, no correction while not enabled) and its base frame
    /// (`measured_cp` × `local/measured_cp`⁻¹). Default: on when `instrument = "console"`.
    pub follow_console: Option<bool>,
    /// The arm's name on the console (`PSM1`); default: the last segment of `prefix`.
    pub console_arm: Option<String>,
    /// Compliance parameter file (see config/compliance/).
    pub compliance: PathBuf,
    /// Cycle rate: a number of Hz, or `"follow"` to run as fast as reads complete.
    #[serde(default = "default_rate")]
    pub rate: Rate,
    /// iceoryx2 service prefix: the arm's name as the dVRK console names it (`PSM1`), so topics
    /// are `PSM1/measured_js`, `PSM1/local/measured_cp`, ...
    #[serde(default = "default_prefix")]
    pub prefix: String,
    /// The arm's base frame, for `measured_cp` (`local/measured_cp` is in the RCM frame). Absent:
    /// the identity, so `measured_cp` equals `local/measured_cp`.
    pub base_frame: Option<BaseFrameParams>,
    /// How long one board request waits for its reply (ms) before the cycle is published as
    /// invalid with BOARD_TIMEOUT. The dVRK host waits 20 ms; the sidecar, whose period is
    /// 0.67 ms, waits 5 ms by default so that a lost datagram costs few cycles.
    #[serde(default = "default_reply_timeout_ms")]
    pub reply_timeout_ms: f64,
    /// Shared mode over UDP: how many quadlet requests the sidecar keeps outstanding at the
    /// boards at once (1 to 16, default 4), and twice that (at most 16) in the cycle after one
    /// that lost a datagram. More hides more round trips and lost datagrams within a cycle
    /// (each register waits up to `reply_timeout_ms` from its newest request, at most twice
    /// that from its first), but the FPGA serves one packet at a time, so each request queued
    /// there delays the console's own packets behind it (reference section 8.4;
    /// RELIABILITY.md). 1: one request at a time, never widened (a lost datagram asked again
    /// after 150 µs, the last attempt waiting `reply_timeout_ms`). A file with `[[arm]]` tables
    /// defaults to 4 per arm, at most 16 (`default_requests_in_flight_for`).
    #[serde(default = "default_requests_in_flight")]
    pub shared_requests_in_flight: u8,
    /// The arm's board ids, in the order of the io file's boards (default: the io file's). The
    /// dVRK numbers Classic PSM1 boards 6-7, PSM2 8-9, PSM3 10-11, so one io file can serve
    /// any of them.
    pub boards: Option<Vec<u8>>,
    /// Simulator settings, used when `source = "sim"`.
    pub sim: Option<SimParams>,
    /// Real-time settings (all optional).
    #[serde(default)]
    pub realtime: RealtimeParams,
}

/// A service configuration that serves several arms from one source: the shared keys at the
/// top, one `[[arm]]` table per arm.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MultiArmParams {
    #[serde(default)]
    source: Option<String>,
    #[serde(default = "default_access")]
    access: AccessMode,
    #[serde(default = "default_rate")]
    rate: Rate,
    #[serde(default = "default_reply_timeout_ms")]
    reply_timeout_ms: f64,
    /// Default: [`default_requests_in_flight_for`] the number of arms.
    #[serde(default)]
    shared_requests_in_flight: Option<u8>,
    sim: Option<SimParams>,
    #[serde(default)]
    realtime: RealtimeParams,
    arm: Vec<ArmParams>,
}

/// One `[[arm]]` of a several-arm configuration: what a single-arm file says at its top level,
/// with `name` for `prefix` and `kind` for `arm`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmParams {
    /// The arm's name as the console names it (`PSM1`): its iceoryx2 prefix and, by default,
    /// its name on the console and in the dVRK JSON.
    pub name: String,
    /// Board ids, in the order of the io file's boards (default: the io file's).
    pub boards: Option<Vec<u8>>,
    pub io: PathBuf,
    /// `classic` or `si`.
    pub kind: ArmKind,
    pub instrument: String,
    pub compliance: PathBuf,
    pub base_frame: Option<BaseFrameParams>,
    pub follow_console: Option<bool>,
    pub console_arm: Option<String>,
    /// This arm's simulator scenario (default: the top-level `[sim]`'s).
    pub scenario: Option<PathBuf>,
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
fn default_requests_in_flight() -> u8 {
    dvrk_io::port::DEFAULT_QUADLET_WINDOW
}
/// The quadlet window of a service that reads `arms` arms over one port when the file does not
/// set `shared_requests_in_flight`: the one-arm default per arm, at most
/// [`dvrk_io::port::MAX_QUADLET_WINDOW`]. Each arm's registers are read in a batch of their own,
/// one arm after the other, so with one arm's window the whole cycle took the sum of the arms'
/// reads: two arms 1.5-1.84 times one arm's cycle p99 on a quiet machine, 1.24-1.45 times with
/// 8 (benches/README.md, two arms). The boards then see as many of the sidecar's requests per
/// cycle as before (16 registers per arm) but up to twice as many queued at once
/// (RELIABILITY.md, the window's trade-off).
fn default_requests_in_flight_for(arms: usize) -> u8 {
    let per_arm = usize::from(dvrk_io::port::DEFAULT_QUADLET_WINDOW);
    let most = dvrk_io::port::MAX_QUADLET_WINDOW;
    u8::try_from(per_arm.saturating_mul(arms))
        .unwrap_or(most)
        .min(most)
}
fn default_prefix() -> String {
    dvrk_ipc::DEFAULT_PREFIX.to_owned()
}

/// `[base_frame]`: either `transform` (a 4×4 homogeneous matrix, rows, metres, as the dVRK
/// writes `base-frame.transform`) or `dvrk_json` (the lab's dVRK console or system JSON, whose
/// entry for the arm carries `base-frame`/`base_frame`), with `arm` naming the entry (default:
/// the last segment of the prefix).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseFrameParams {
    #[serde(default, deserialize_with = "dvrk_compliance::exact::option_matrix")]
    pub transform: Option<[[f64; 4]; 4]>,
    pub dvrk_json: Option<PathBuf>,
    pub arm: Option<String>,
}

/// A 4×4 homogeneous transform (rows) as an isometry; `what` names it in errors. The rotation
/// must be orthonormal to 1e-6 and the last row `[0, 0, 0, 1]`.
pub fn isometry_from_rows(m: &[[f64; 4]; 4], what: &str) -> Result<Isometry3<f64>> {
    if let Some((r, c)) = (0..4)
        .flat_map(|r| (0..4).map(move |c| (r, c)))
        .find(|&(r, c)| !m[r][c].is_finite())
    {
        bail!(
            "{what}: element [{r}][{c}] = {} is not a finite number",
            m[r][c]
        );
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        bail!("{what}: the last row must be [0, 0, 0, 1], got {:?}", m[3]);
    }
    let rot = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
    let err = (rot.transpose() * rot - nalgebra::Matrix3::identity())
        .abs()
        .max();
    if err > 1e-6 || rot.determinant() < 0.0 {
        bail!(
            "{what}: the upper-left 3x3 is not a rotation (|R^T R - I| = {err:.2e}, det = {:.6})",
            rot.determinant()
        );
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix(&rot));
    Ok(Isometry3::from_parts(
        nalgebra::Translation3::new(m[0][3], m[1][3], m[2][3]),
        rotation,
    ))
}

/// The base frame of `arm` in a dVRK console (2.1-2.2: `base-frame`, `reference-frame`) or
/// system (2.3: `base_frame`, `reference_frame`) JSON, comments allowed as the dVRK allows them.
/// `Ok(None)`: the arm is there without a base frame (the console then uses the identity).
pub fn base_frame_from_dvrk_json(
    text: &str,
    arm: &str,
    file: &str,
) -> Result<Option<Isometry3<f64>>> {
    let v: serde_json::Value = serde_json::from_str(&dvrk_io::convert::strip_json_comments(text))
        .map_err(|e| anyhow::anyhow!("{}", crate::files::quote(&e.to_string())))
        .with_context(|| format!("{file}: not valid JSON"))?;
    let arms = v
        .get("arms")
        .and_then(|a| a.as_array())
        .ok_or_else(|| anyhow::anyhow!("{file}: no `arms` list (is this a dVRK console JSON?)"))?;
    let entry = arms
        .iter()
        .find(|a| a.get("name").and_then(|n| n.as_str()) == Some(arm))
        .ok_or_else(|| {
            let names: Vec<&str> = arms
                .iter()
                .filter_map(|a| a.get("name").and_then(|n| n.as_str()))
                .collect();
            anyhow::anyhow!(
                "{file}: no arm named \"{arm}\" in `arms` (found: {})",
                names.join(", ")
            )
        })?;
    let Some((key, frame)) = ["base-frame", "base_frame"]
        .into_iter()
        .find_map(|k| entry.get(k).map(|f| (k, f)))
    else {
        return Ok(None);
    };
    let t = frame
        .get("transform")
        .ok_or_else(|| anyhow::anyhow!("{file}: arm {arm}: `{key}` has no `transform`"))?;
    let m: [[f64; 4]; 4] = serde_json::from_value(t.clone()).with_context(|| {
        format!("{file}: arm {arm}: `{key}.transform` is not a 4x4 array of numbers")
    })?;
    isometry_from_rows(&m, &format!("{file}: arm {arm}: `{key}.transform`")).map(Some)
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
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimParams {
    /// Scenario file (see config/sim/).
    pub scenario: PathBuf,
}

/// `[realtime]`: optional real-time settings for the loop thread.
#[derive(Debug, Clone, Default, Deserialize)]
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
            let addr = rest.parse::<SocketAddr>().map_err(|_| {
                anyhow::anyhow!("source \"{s}\": \"{rest}\" is not an IP address or IP:PORT")
            })?;
            // Port 0 is no board's port: every send fails, and serve would retry it for ever as
            // a transient socket error (issue 22).
            if addr.port() == 0 {
                bail!(
                    "source \"{s}\": port 0 is not a UDP port a board answers on; give the \
                     boards' port (1394, the default when no port is given)"
                );
            }
            return Ok(Source::Udp(addr));
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
            if port == 0 {
                bail!(
                    "source \"{s}\": port 0 is not a UDP port boards answer on; give the \
                     boards' port (1394, the default when no port is given)"
                );
            }
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
    /// Every parameter set of the compliance file, one per instrument (see
    /// [`crate::formats::compliance_sets_from_toml`]); `compliance` is the one for `instrument`.
    pub compliance_sets: Vec<crate::formats::ParamSet>,
    /// The instrument the first set was fitted for (None: not recorded, used for any).
    pub compliance_instrument: Option<&'static Instrument>,
    /// The configured instrument has no parameter set: compensated = raw, NO_CALIBRATION.
    pub no_calibration: bool,
    /// `instrument = "console"`.
    pub instrument_from_console: bool,
    /// Follow the console's state and base frame (and instrument when `instrument_from_console`).
    pub follow_console: bool,
    /// The arm's name on the console.
    pub console_arm: String,
    pub rate: Rate,
    pub prefix: String,
    /// `measured_cp = base_frame × local/measured_cp`.
    pub base_frame: Isometry3<f64>,
    /// Where the base frame came from, for the start-up log and `check-config`.
    pub base_frame_origin: String,
    /// What `check-config` and `serve` warn about (see [`compliance_warnings`]).
    pub warnings: Vec<String>,
    pub reply_timeout: std::time::Duration,
    /// `shared_requests_in_flight`: the quadlet window of shared mode over UDP.
    pub shared_requests_in_flight: u8,
    pub scenario_path: Option<PathBuf>,
    pub scenario: Option<dvrk_sim::Scenario>,
    pub realtime: RealtimeParams,
}

/// Reads a configuration file with an error that names it: a regular file only, at most
/// [`crate::files::CONFIG_MAX_BYTES`], never blocking (see [`crate::files`]).
pub fn read_file(path: &Path) -> Result<String> {
    crate::files::read_text(path, crate::files::CONFIG_MAX_BYTES)
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
    load_compliance_text(path).map(|(c, _)| c)
}

/// [`load_compliance`], also returning the file's text (for [`compliance_warnings`]).
fn load_compliance_text(path: &Path) -> Result<(ComplianceConfig, String)> {
    let text = read_file(path)?;
    let c = crate::formats::compliance_from_toml(&text)
        .with_context(|| format!("{}: invalid compliance parameters", path.display()))?;
    Ok((c, text))
}

/// Loads a simulator scenario file.
pub fn load_scenario(path: &Path) -> Result<dvrk_sim::Scenario> {
    let text = read_file(path)?;
    crate::formats::scenario_from_toml(&text)
        .with_context(|| format!("{}: invalid simulator scenario", path.display()))
}

/// Warnings about a compliance parameter file used with a real source (`udp:`, `fw:`, `tap:`):
/// parameters fitted on the simulator, or without a calibrated torque offset tau_0(q) (all zero,
/// as in the paper's file), make every gravity and friction torque look like contact. `text` is
/// the file's content, `file` its name for the message. Empty for the simulator.
pub fn compliance_warnings(source: &Source, text: &str, file: &str) -> Vec<String> {
    if *source == Source::Sim {
        return Vec::new();
    }
    let mut w = Vec::new();
    if text.contains("Compliance parameters of the built-in simulated PSM") {
        w.push(format!(
            "{file} was fitted on the built-in simulator, not on this robot: its torque offsets, \
             backlash and stiffness describe the simulated arm. Calibrate this arm (calibrate record, \
             fit) and point `compliance` at the result"
        ));
    }
    let zero_offsets = text
        .parse::<toml::Table>()
        .ok()
        .and_then(|t| t.get("joint").and_then(|j| j.as_array()).cloned())
        .is_some_and(|joints| {
            !joints.is_empty()
                && joints.iter().all(|j| {
                    j.get("torque_offset")
                        .and_then(|o| o.get("effort_nm"))
                        .and_then(|e| e.as_array())
                        .is_some_and(|e| e.iter().all(|v| v.as_float() == Some(0.0)))
                })
        });
    if zero_offsets {
        w.push(format!(
            "{file} has no calibrated torque offset (tau_0 is zero for every joint, as in the \
             paper's published parameters): on a real arm gravity and friction torques then count \
             as contact and the correction moves the tip. Measure tau_0 with `calibrate record` \
             (torque-offset sweep) and `fit`"
        ));
    }
    w
}

/// Looks an instrument up by its tool file name (`LARGE_NEEDLE_DRIVER_400006`) or as the console
/// writes it (`LARGE_NEEDLE_DRIVER:400006[..]`), and refuses one the project cannot use (no
/// usable actuator-to-joint coupling), so neither `serve` nor `fk` runs with a wrong tip pose.
pub fn find_instrument(name: &str) -> Result<&'static Instrument> {
    use dvrk_compliance::InstrumentError;
    match dvrk_compliance::instrument_from_tool_type(name) {
        Ok(i) => Ok(i),
        Err(e @ (InstrumentError::UnknownName | InstrumentError::NotInIndex { .. })) => {
            let known: Vec<&str> = dvrk_compliance::instruments()
                .iter()
                .map(|i| i.name)
                .collect();
            Err(anyhow::anyhow!(
                "unknown instrument \"{name}\": {e}; known (or as the console writes them, \
                 NAME:MODEL[..]): {}",
                known.join(", ")
            ))
        }
        Err(e) => Err(anyhow::anyhow!("instrument \"{name}\" is refused: {e}")),
    }
}

/// Every arm of a service configuration, each resolved as a [`SidecarConfig`] that shares the
/// file's source, access, rate, timeout, simulator and real-time settings.
pub struct ServiceConfig {
    pub path: PathBuf,
    /// At least one; in the file's order.
    pub arms: Vec<SidecarConfig>,
    /// Whether the file lists `[[arm]]` tables (false: a single-arm file).
    pub multi: bool,
}

/// The parameters of each arm of the file at `path` (text `text`), unresolved.
fn arm_params(path: &Path, text: &str) -> Result<(Vec<SidecarParams>, bool)> {
    let table: toml::Table = crate::files::from_toml(text)
        .with_context(|| format!("{}: invalid service configuration", path.display()))?;
    if !table.get("arm").is_some_and(|a| a.is_array()) {
        let params: SidecarParams = crate::files::from_toml(text)
            .with_context(|| format!("{}: invalid service configuration", path.display()))?;
        return Ok((vec![params], false));
    }
    let m: MultiArmParams = crate::files::from_toml(text).with_context(|| {
        format!(
            "{}: invalid service configuration (with [[arm]] tables, the arm's own keys - \
             name, boards, io, kind, instrument, compliance, base_frame, follow_console, \
             console_arm, scenario - go in each [[arm]])",
            path.display()
        )
    })?;
    if m.arm.is_empty() {
        bail!("{}: `arm` lists no arm", path.display());
    }
    if m.arm.len() > MAX_ARMS {
        bail!(
            "{}: {} [[arm]] tables: one service serves at most {MAX_ARMS}",
            path.display(),
            m.arm.len()
        );
    }
    let window = m
        .shared_requests_in_flight
        .unwrap_or_else(|| default_requests_in_flight_for(m.arm.len()));
    let params = m
        .arm
        .into_iter()
        .map(|a| SidecarParams {
            source: m.source.clone(),
            access: m.access,
            io: a.io,
            arm: a.kind,
            instrument: a.instrument,
            follow_console: a.follow_console,
            console_arm: a.console_arm,
            compliance: a.compliance,
            rate: m.rate,
            prefix: a.name,
            base_frame: a.base_frame,
            reply_timeout_ms: m.reply_timeout_ms,
            shared_requests_in_flight: window,
            boards: a.boards,
            sim: match a.scenario {
                Some(scenario) => Some(SimParams { scenario }),
                None => m.sim.clone(),
            },
            realtime: m.realtime.clone(),
        })
        .collect();
    Ok((params, true))
}

/// The names (iceoryx2 prefixes) of the arms the service configuration at `path` serves, in
/// its order, without loading the files it names: what `ros2-bridge --config` and
/// `record --config` need.
pub fn arm_names(path: &Path) -> Result<Vec<String>> {
    let text = read_file(path)?;
    let (params, _) = arm_params(path, &text)?;
    let names: Vec<String> = params.into_iter().map(|p| p.prefix).collect();
    check_distinct_names(path, &names)?;
    for n in &names {
        dvrk_ipc::ServiceNames::new(n)
            .map_err(|e| anyhow::anyhow!("{}: arm name \"{n}\": {e}", path.display()))?;
    }
    Ok(names)
}

fn check_distinct_names(path: &Path, names: &[String]) -> Result<()> {
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            bail!(
                "{}: two arms are named \"{n}\": each arm publishes under its own name",
                path.display()
            );
        }
    }
    Ok(())
}

impl ServiceConfig {
    /// Loads `path` and everything every arm names; every error names the file, the arm and
    /// the field. Arms must have distinct names, boards and console arms.
    pub fn load(path: &Path) -> Result<Self> {
        let text = read_file(path)?;
        let (params, multi) = arm_params(path, &text)?;
        let names: Vec<String> = params.iter().map(|p| p.prefix.clone()).collect();
        check_distinct_names(path, &names)?;
        let mut arms = Vec::with_capacity(params.len());
        for p in params {
            let name = p.prefix.clone();
            let cfg = SidecarConfig::from_params(path, p);
            arms.push(if multi {
                cfg.with_context(|| format!("{}: [[arm]] \"{name}\"", path.display()))?
            } else {
                cfg?
            });
        }
        for (i, a) in arms.iter().enumerate() {
            for b in &arms[..i] {
                if let Some(id) =
                    a.io.board_ids()
                        .iter()
                        .find(|id| b.io.board_ids().contains(id))
                {
                    bail!(
                        "{}: arms \"{}\" and \"{}\" both use board {id}: give each arm its \
                         own `boards` (the dVRK numbers PSM1 6-7, PSM2 8-9, PSM3 10-11)",
                        path.display(),
                        b.prefix,
                        a.prefix
                    );
                }
                if a.follow_console && b.follow_console && a.console_arm == b.console_arm {
                    bail!(
                        "{}: arms \"{}\" and \"{}\" both follow console arm \"{}\"",
                        path.display(),
                        b.prefix,
                        a.prefix,
                        a.console_arm
                    );
                }
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            arms,
            multi,
        })
    }
}

/// `io` with its boards renumbered: the i-th board of the file becomes `boards[i]`.
pub fn renumber_boards(io: IoConfig, boards: &[u8]) -> Result<IoConfig> {
    let old = io.board_ids().to_vec();
    if boards.len() != old.len() {
        bail!(
            "gives {} board(s) {boards:?}, but the io file has {} ({old:?})",
            boards.len(),
            old.len()
        );
    }
    if let Some(b) = boards.iter().find(|&&b| b > 15) {
        bail!("board {b} is not a board id (0-15)");
    }
    for (i, b) in boards.iter().enumerate() {
        if boards[..i].contains(b) {
            bail!("board {b} is listed twice");
        }
    }
    if boards == old.as_slice() {
        return Ok(io);
    }
    let mut p = io.to_params();
    for a in &mut p.actuators {
        if let Some(i) = old.iter().position(|&o| o == a.board_id) {
            a.board_id = boards[i];
        }
    }
    IoConfig::from_params(p).map_err(|e| anyhow::anyhow!("renumbering the boards: {e}"))
}

impl SidecarConfig {
    /// Loads a single-arm file, or the first arm of a several-arm file.
    pub fn load(path: &Path) -> Result<Self> {
        let mut s = ServiceConfig::load(path)?;
        Ok(s.arms.swap_remove(0))
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
        let source = match p.source.as_deref().map(str::trim) {
            None | Some("") => bail!(
                "{here}: field `source` is not set. Name where the samples come from: \
                 \"udp:169.254.0.100\" (boards over Ethernet), \"fw:0\" (FireWire port 0), \
                 \"tap:eth1\" (passive tap of the console's traffic) or \"sim\" (the built-in \
                 simulated PSM)"
            ),
            Some(s) => Source::parse(s).with_context(|| format!("{here}: field `source`"))?,
        };
        if let Rate::Hz(hz) = p.rate
            && !(hz.is_finite() && (1.0..=20_000.0).contains(&hz))
        {
            bail!(
                "{here}: field `rate` = {}: must be between 1 and 20000 Hz, or \"follow\"",
                num(hz)
            );
        }
        if let Some(prio) = p.realtime.fifo_priority
            && !(1..=99).contains(&prio)
        {
            bail!("{here}: field `realtime.fifo_priority` = {prio}: must be 1..=99");
        }
        if !(p.reply_timeout_ms.is_finite() && (0.05..=1000.0).contains(&p.reply_timeout_ms)) {
            bail!(
                "{here}: field `reply_timeout_ms` = {}: must be between 0.05 and 1000 ms",
                num(p.reply_timeout_ms)
            );
        }
        let max_in_flight = dvrk_io::port::MAX_QUADLET_WINDOW;
        if !(1..=max_in_flight).contains(&p.shared_requests_in_flight) {
            bail!(
                "{here}: field `shared_requests_in_flight` = {}: must be 1..={max_in_flight}",
                p.shared_requests_in_flight
            );
        }
        dvrk_ipc::ServiceNames::new(&p.prefix)
            .map_err(|e| anyhow::anyhow!("{here}: field `prefix` = \"{}\": {e}", p.prefix))?;

        let io_path = resolve(&p.io);
        let mut io = load_io(&io_path).with_context(|| format!("{here}: field `io`"))?;
        if let Some(b) = &p.boards {
            io = renumber_boards(io, b).with_context(|| format!("{here}: field `boards`"))?;
        }
        let compliance_path = resolve(&p.compliance);
        let compliance_text =
            read_file(&compliance_path).with_context(|| format!("{here}: field `compliance`"))?;
        // One set per instrument (fit's `# instrument:` line, or `[[set]]` tables).
        let compliance_sets = crate::formats::compliance_sets_from_toml(&compliance_text)
            .with_context(|| {
                format!(
                    "{here}: field `compliance`: {}: invalid compliance parameters",
                    compliance_path.display()
                )
            })?;
        let compliance_instrument = compliance_sets.first().and_then(|s| s.instrument);
        let instrument_from_console = p.instrument == "console";
        let instrument = if instrument_from_console {
            // Until the console says: the parameters' instrument (flagged meanwhile).
            match compliance_instrument {
                Some(i) => i,
                None => find_instrument("LARGE_NEEDLE_DRIVER_400006")?,
            }
        } else {
            find_instrument(&p.instrument)
                .with_context(|| format!("{here}: field `instrument` = \"{}\"", p.instrument))?
        };
        let follow_console = p.follow_console.unwrap_or(instrument_from_console);
        if instrument_from_console && !follow_console {
            bail!(
                "{here}: `instrument = \"console\"` needs `follow_console` (it is how the instrument is known)"
            );
        }
        let console_arm = p
            .console_arm
            .clone()
            .unwrap_or_else(|| p.prefix.rsplit('/').next().unwrap_or("PSM1").to_owned());
        if follow_console {
            dvrk_bridge::validate_arm(&console_arm)
                .with_context(|| format!("{here}: field `console_arm` = \"{console_arm}\""))?;
        }
        // find_instrument checked the coupling; an instrument without one never gets here.
        let coupling = instrument
            .coupling()
            .with_context(|| format!("{here}: field `instrument` = \"{}\"", p.instrument))?;
        io.set_coupling(*coupling)
            .with_context(|| format!("{here}: coupling of instrument {}", instrument.name))?;
        let kinematics = PsmKinematics::new(p.arm, instrument);
        // The set for the configured instrument (or one for any instrument).
        let chosen = compliance_sets
            .iter()
            .position(|s| s.instrument.is_some_and(|i| i.model == instrument.model))
            .or_else(|| compliance_sets.iter().position(|s| s.instrument.is_none()));
        let no_calibration = chosen.is_none() && !instrument_from_console;
        let compliance = compliance_sets[chosen.unwrap_or(0)].config.clone();
        let mut warnings = compliance_warnings(
            &source,
            &compliance_text,
            &compliance_path.display().to_string(),
        );
        if no_calibration {
            warnings.push(format!(
                "{}: no parameter set for instrument {}: compensated = raw, flagged NO_CALIBRATION",
                compliance_path.display(),
                instrument.name
            ));
        }

        let (base_frame, base_frame_origin) = match &p.base_frame {
            None => (
                Isometry3::identity(),
                "identity (no [base_frame])".to_owned(),
            ),
            Some(BaseFrameParams {
                transform: Some(m),
                dvrk_json: None,
                arm: None,
            }) => (
                isometry_from_rows(m, &format!("{here}: field `base_frame.transform`"))?,
                format!("base_frame.transform of {here}"),
            ),
            Some(BaseFrameParams {
                transform: None,
                dvrk_json: Some(json),
                arm,
            }) => {
                let json = resolve(json);
                let arm = arm
                    .clone()
                    .unwrap_or_else(|| p.prefix.rsplit('/').next().unwrap_or("").to_owned());
                let text = read_file(&json)
                    .with_context(|| format!("{here}: field `base_frame.dvrk_json`"))?;
                let f = base_frame_from_dvrk_json(&text, &arm, &json.display().to_string())
                    .with_context(|| format!("{here}: field `base_frame.dvrk_json`"))?;
                match f {
                    Some(f) => (f, format!("{} (arm {arm})", json.display())),
                    None => (
                        Isometry3::identity(),
                        format!(
                            "identity: arm {arm} in {} has no base frame",
                            json.display()
                        ),
                    ),
                }
            }
            Some(_) => bail!(
                "{here}: [base_frame] takes either `transform` (a 4x4 matrix) or `dvrk_json` \
                 (with an optional `arm`), not both and not neither"
            ),
        };

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
            compliance_sets,
            compliance_instrument,
            no_calibration,
            instrument_from_console,
            follow_console,
            console_arm,
            rate: p.rate,
            prefix: p.prefix,
            base_frame,
            base_frame_origin,
            warnings,
            reply_timeout: std::time::Duration::from_secs_f64(p.reply_timeout_ms * 1e-3),
            shared_requests_in_flight: p.shared_requests_in_flight,
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
    fn instruments_by_file_name_or_console_tool_type() {
        let by_file = find_instrument("LARGE_NEEDLE_DRIVER_400006").unwrap();
        let by_console = find_instrument("LARGE_NEEDLE_DRIVER:400006[..]").unwrap();
        assert!(std::ptr::eq(by_file, by_console));
        let geared = find_instrument("MEGA_NEEDLE_DRIVER:420194[12..]").unwrap();
        assert_eq!(geared.name, "MEGA_NEEDLE_DRIVER_420194_GEARED");
        // Every instrument the config accepts has a coupling (it goes to the io conversion).
        assert!(
            find_instrument("CADIERE_FORCEPS_400049")
                .unwrap()
                .actuator_to_joint_position
                .is_some()
        );
        // Refusals name the instrument and why.
        let e = find_instrument("BANANA_400000").unwrap_err().to_string();
        assert!(e.contains("unknown instrument \"BANANA_400000\""), "{e}");
        let e = find_instrument("MEGA_NEEDLE_DRIVER:420194")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("MEGA_NEEDLE_DRIVER:420194") && e.contains("version"),
            "{e}"
        );
        let e = find_instrument("ERROR").unwrap_err().to_string();
        assert!(e.contains("ERROR"), "{e}");
    }

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
        for bad in [
            "",
            "udp:",
            "udp:nohost",
            "fw:x",
            "tcp:1.2.3.4",
            "SIM",
            "udp:127.0.0.1:0",
            "udp:[::1]:0",
        ] {
            let e = Source::parse(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "error for {bad:?} names it: {e}");
        }
        let e = Source::parse("udp:127.0.0.1:0").unwrap_err().to_string();
        assert!(e.contains("port 0"), "{e}");
    }

    #[test]
    fn the_compliance_crates_joint_range_matches_dvrk_io_soft_limits() {
        // dvrk-compliance may not import dvrk-io, so it states the range again: the widest of
        // the Classic and Si PSM soft limits.
        use dvrk_io::plausibility::{CLASSIC_PSM_SOFT_LIMITS, SI_PSM_SOFT_LIMITS};
        for j in 0..3 {
            let lo = CLASSIC_PSM_SOFT_LIMITS[j][0].min(SI_PSM_SOFT_LIMITS[j][0]);
            let hi = CLASSIC_PSM_SOFT_LIMITS[j][1].max(SI_PSM_SOFT_LIMITS[j][1]);
            assert_eq!(
                dvrk_compliance::bounds::PSM_JOINT_RANGE[j],
                [lo, hi],
                "joint {}",
                j + 1
            );
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
            "tap:lo:0",
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

    #[test]
    fn base_frame_from_a_matrix_is_checked() {
        let ok = [
            [1.0, 0.0, 0.0, -0.2],
            [0.0, -0.866025404, 0.5, 0.0],
            [0.0, -0.5, -0.866025404, 0.1],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let f = isometry_from_rows(&ok, "t").unwrap();
        assert!((f.translation.vector - nalgebra::Vector3::new(-0.2, 0.0, 0.1)).norm() < 1e-15);
        let p = f * nalgebra::Point3::new(0.0, 1.0, 0.0);
        assert!(
            (p - nalgebra::Point3::new(-0.2, -0.866025404, -0.4)).norm() < 1e-8,
            "{p}"
        );
        let mut bad = ok;
        bad[1][1] = 0.5;
        let e = isometry_from_rows(&bad, "file.toml: field `base_frame.transform`")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("base_frame.transform") && e.contains("not a rotation"),
            "{e}"
        );
        let mut bad = ok;
        bad[3][0] = 1.0;
        assert!(
            isometry_from_rows(&bad, "t")
                .unwrap_err()
                .to_string()
                .contains("last row")
        );
        let mut bad = ok;
        bad[0][3] = f64::NAN;
        assert!(
            isometry_from_rows(&bad, "t")
                .unwrap_err()
                .to_string()
                .contains("[0][3]")
        );
        // A reflection is orthonormal but not a rotation.
        let mut bad = ok;
        bad[0][0] = -1.0;
        assert!(isometry_from_rows(&bad, "t").is_err());
    }

    #[test]
    fn base_frame_from_dvrk_console_and_system_json() {
        let console = r#"{
            // dVRK 2.1 console file, with comments
            "arms": [
                { "name": "PSM2", "type": "PSM" },
                { "name": "PSM1", "type": "PSM", "serial": "28007",
                  "base-frame": { "reference-frame": "ECM",
                                  "transform": [[1.0, 0.0, 0.0, 0.1],
                                                [0.0, 1.0, 0.0, 0.2],
                                                [0.0, 0.0, 1.0, 0.3],
                                                [0.0, 0.0, 0.0, 1.0]] } }
            ]
        }"#;
        let f = base_frame_from_dvrk_json(console, "PSM1", "c.json")
            .unwrap()
            .unwrap();
        assert_eq!(f.translation.vector, nalgebra::Vector3::new(0.1, 0.2, 0.3));
        assert_eq!(
            base_frame_from_dvrk_json(console, "PSM2", "c.json").unwrap(),
            None
        );
        let e = base_frame_from_dvrk_json(console, "PSM3", "c.json")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("PSM3") && e.contains("PSM2, PSM1") && e.contains("c.json"),
            "{e}"
        );
        let system = console
            .replace("base-frame", "base_frame")
            .replace("reference-frame", "reference_frame");
        let f = base_frame_from_dvrk_json(&system, "PSM1", "s.json")
            .unwrap()
            .unwrap();
        assert_eq!(f.translation.vector, nalgebra::Vector3::new(0.1, 0.2, 0.3));
        let broken = console.replace("[0.0, 0.0, 0.0, 1.0]]", "[0.0, 0.0, 0.0]]");
        let e = base_frame_from_dvrk_json(&broken, "PSM1", "c.json").unwrap_err();
        assert!(format!("{e:#}").contains("base-frame.transform"), "{e:#}");
        let e = base_frame_from_dvrk_json("{}", "PSM1", "x.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("arms"), "{e}");
    }

    #[test]
    fn real_sources_with_simulator_or_paper_parameters_are_warned_about() {
        let sim = include_str!("../../../config/compliance/sim-psm.toml");
        let paper = include_str!("../../../config/compliance/paper-psm.toml");
        let udp = Source::parse("udp:169.254.0.100").unwrap();
        assert!(compliance_warnings(&Source::Sim, sim, "sim-psm.toml").is_empty());
        assert!(compliance_warnings(&Source::Sim, paper, "paper-psm.toml").is_empty());
        let w = compliance_warnings(&udp, sim, "sim-psm.toml");
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("sim-psm.toml") && w[0].contains("simulator"),
            "{w:?}"
        );
        let w = compliance_warnings(&Source::Firewire(0), paper, "paper-psm.toml");
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("torque offset"), "{w:?}");
        // A lab's own fit (non-zero offsets, no simulator header) passes.
        let own = paper.replace("effort_nm = [0.0, 0.0]", "effort_nm = [0.1, -0.2]");
        assert!(compliance_warnings(&udp, &own, "lab.toml").is_empty());
    }

    /// The repository's config directory, for test files that name its io and parameter files.
    fn repo_config() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
    }

    fn write_config(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("dvrk-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        let c = repo_config().canonicalize().unwrap();
        std::fs::write(&p, text.replace("CONFIG", &c.display().to_string())).unwrap();
        p
    }

    const TWO_ARMS: &str = r#"
source = "udp:127.0.0.1:9"
[[arm]]
name = "PSM1"
io = "CONFIG/io/psm-classic.toml"
kind = "classic"
instrument = "LARGE_NEEDLE_DRIVER_400006"
compliance = "CONFIG/compliance/sim-psm.toml"
[[arm]]
name = "PSM2"
boards = [8, 9]
io = "CONFIG/io/psm-classic.toml"
kind = "si"
instrument = "LARGE_NEEDLE_DRIVER_400006"
compliance = "CONFIG/compliance/paper-psm.toml"
[arm.base_frame]
transform = [[1.0, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
"#;

    #[test]
    fn the_shipped_two_arm_example_loads_with_the_dvrk_board_numbers() {
        let path = repo_config().join("psm1-psm2.toml");
        let svc = ServiceConfig::load(&path).unwrap();
        assert!(svc.multi);
        let names: Vec<&str> = svc.arms.iter().map(|a| a.prefix.as_str()).collect();
        assert_eq!(names, ["PSM1", "PSM2"]);
        assert_eq!(svc.arms[0].io.board_ids(), &[6, 7]);
        assert_eq!(svc.arms[1].io.board_ids(), &[8, 9]);
        assert!(svc.arms.iter().all(|a| a.source == Source::Sim));
        assert!(
            svc.arms[1]
                .scenario_path
                .as_ref()
                .unwrap()
                .ends_with("sim/palpation.toml")
        );
        assert_eq!(arm_names(&path).unwrap(), ["PSM1", "PSM2"]);
        // A single-arm file is one arm, named by its prefix.
        let single = repo_config().join("sidecar.toml");
        let svc = ServiceConfig::load(&single).unwrap();
        assert!(!svc.multi);
        assert_eq!(svc.arms.len(), 1);
        assert_eq!(arm_names(&single).unwrap(), ["PSM1"]);
    }

    #[test]
    fn the_quadlet_window_defaults_to_four_per_arm_unless_the_file_sets_it() {
        let window = |name: &str, text: &str| {
            let svc = ServiceConfig::load(&write_config(name, text)).unwrap();
            let w: Vec<u8> = svc
                .arms
                .iter()
                .map(|a| a.shared_requests_in_flight)
                .collect();
            w
        };
        assert_eq!(window("w2.toml", TWO_ARMS), [8, 8]);
        let set = format!("shared_requests_in_flight = 3\n{TWO_ARMS}");
        assert_eq!(window("w2-set.toml", &set), [3, 3]);
        // One [[arm]] table, and a single-arm file, keep one arm's window.
        let one = TWO_ARMS
            .split("[[arm]]")
            .take(2)
            .collect::<Vec<_>>()
            .join("[[arm]]");
        assert_eq!(window("w1.toml", &one), [4]);
        assert_eq!(
            ServiceConfig::load(&repo_config().join("sidecar.toml"))
                .unwrap()
                .arms[0]
                .shared_requests_in_flight,
            4
        );
        // Many arms stop at the port's largest window.
        assert_eq!(default_requests_in_flight_for(3), 12);
        assert_eq!(default_requests_in_flight_for(5), 16);
        assert_eq!(default_requests_in_flight_for(usize::MAX), 16);
        // A set window is still checked.
        let bad = format!("shared_requests_in_flight = 17\n{TWO_ARMS}");
        let e = ServiceConfig::load(&write_config("w-bad.toml", &bad))
            .err()
            .unwrap();
        assert!(
            format!("{e:#}").contains("shared_requests_in_flight` = 17"),
            "{e:#}"
        );
    }

    #[test]
    fn each_arm_keeps_its_own_kind_parameters_boards_and_base_frame() {
        let p = write_config("two.toml", TWO_ARMS);
        let svc = ServiceConfig::load(&p).unwrap();
        let (a, b) = (&svc.arms[0], &svc.arms[1]);
        assert_eq!((a.arm, b.arm), (ArmKind::Classic, ArmKind::Si));
        assert_eq!(b.io.board_ids(), &[8, 9]);
        assert!(
            b.io.actuators()
                .iter()
                .all(|x| x.board_id == 8 || x.board_id == 9)
        );
        // Same actuators as the file, only the board numbers moved.
        assert_eq!(
            a.io.actuators().map(|x| x.axis),
            b.io.actuators().map(|x| x.axis)
        );
        assert_eq!(a.base_frame, Isometry3::identity());
        assert!((b.base_frame.translation.vector.x - 0.1).abs() < 1e-12);
        assert!(b.compliance_path.ends_with("paper-psm.toml"));
        assert_eq!(a.source, b.source);
    }

    #[test]
    fn several_arm_mistakes_are_named() {
        let cases: &[(&str, String, &str)] = &[
            (
                "dup-name",
                TWO_ARMS.replace("name = \"PSM2\"", "name = \"PSM1\""),
                "two arms are named \"PSM1\"",
            ),
            (
                "dup-boards",
                TWO_ARMS.replace("boards = [8, 9]", "boards = [7, 8]"),
                "both use board 7",
            ),
            (
                "boards-count",
                TWO_ARMS.replace("boards = [8, 9]", "boards = [8, 9, 10]"),
                "field `boards`",
            ),
            (
                "board-range",
                TWO_ARMS.replace("boards = [8, 9]", "boards = [8, 16]"),
                "board 16 is not a board id",
            ),
            (
                "top-level-io",
                format!("io = \"x.toml\"\n{TWO_ARMS}"),
                "go in each [[arm]]",
            ),
            (
                "unknown-arm-key",
                TWO_ARMS.replace("kind = \"si\"", "kind = \"si\"\nprefix = \"X\""),
                "unknown field `prefix`",
            ),
            (
                "bad-io",
                TWO_ARMS.replace(
                    "boards = [8, 9]\nio = \"CONFIG/io/psm-classic.toml\"",
                    "boards = [8, 9]\nio = \"CONFIG/io/missing.toml\"",
                ),
                "[[arm]] \"PSM2\"",
            ),
        ];
        for (name, text, want) in cases {
            let p = write_config(&format!("{name}.toml"), text);
            let e = format!("{:#}", ServiceConfig::load(&p).err().unwrap());
            assert!(e.contains(want), "{name}: {e}");
            assert!(e.contains(&p.display().to_string()), "{name}: {e}");
        }
        let many: String = (0..=MAX_ARMS)
            .map(|i| format!("[[arm]]\nname = \"PSM{i}\"\nio = \"a\"\nkind = \"classic\"\ninstrument = \"x\"\ncompliance = \"c\"\n"))
            .collect();
        let p = write_config("many.toml", &format!("source = \"sim\"\n{many}"));
        let e = format!("{:#}", ServiceConfig::load(&p).err().unwrap());
        assert!(e.contains("at most"), "{e}");
    }
}
