//! `serve` and `check-config`: the I/O shell around the pure cycle.
//!
//! Setup allocates everything (ports, buffers, publishers, the histogram). The loop then does,
//! each cycle: wait for the deadline, read the clock once for the sample, read the boards,
//! convert, compensate, compute both tip poses, read the clock once for the publish stamp,
//! publish the nine messages and notify. Nothing in the loop allocates, locks, logs or
//! formats. Once per second it hands a copy of its counters to a housekeeping thread (a
//! lock-free `try_send` into a one-slot channel that the thread polls); that thread logs the
//! summary and removes dead subscriber nodes every 5 s, so neither a slow stderr (journald)
//! nor listing files can stall a cycle.

use std::path::Path;
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};

use anyhow::{Context, Result};
use dvrk_io::plausibility::{PlausibilityLimits, SampleCheck};
use dvrk_io::port::{Port, UdpLink, UdpPort};
use dvrk_io::reader::ArmReader;
use dvrk_io::{ArmSample, IoConfig};
use dvrk_ipc::iceoryx2;
use dvrk_ipc::{ArmPublisher, ServiceNames, SubscriberCounts, flags};
use tracing::{info, warn};

use crate::config::{Rate, ServiceConfig, SidecarConfig, Source};
use crate::cycle::{self, CycleTiming, ReadOutcome};
use crate::rt;
use crate::signals::StopFlag;
use crate::stats::DurationHistogram;

/// Board ids of the arm, as the I/O configuration assigns them.
fn board_ids(cfg: &SidecarConfig) -> Vec<u8> {
    cfg.io.board_ids().to_vec()
}

/// `check-config`: load and validate everything, run every check that `serve` runs before its
/// loop ([`preflight`]) for every arm, print what was found.
pub fn check_config(path: &Path) -> Result<()> {
    let svc = ServiceConfig::load(path)?;
    preflight_service(&svc).with_context(|| format!("{}", path.display()))?;
    let mut out = std::io::stdout().lock();
    crate::outln!(out, "{}: OK", path.display())?;
    let first = &svc.arms[0];
    crate::outln!(
        out,
        "  source      {} (access {:?})",
        first.source,
        first.access
    )?;
    if matches!(first.source, Source::Udp(_)) && first.access == dvrk_io::reader::AccessMode::Shared
    {
        crate::outln!(
            out,
            "  window      {} quadlet requests in flight (shared_requests_in_flight)",
            first.shared_requests_in_flight
        )?;
    }
    crate::outln!(out, "  rate        {}", first.rate)?;
    // Where the service keeps its iceoryx2 state: consumers must see the same (same account,
    // same DVRK_SIDECAR_IPC_ROOT).
    let domain = dvrk_ipc::default_domain()?;
    crate::outln!(
        out,
        "  shm         {} (prefix {})",
        domain.global.root_path(),
        domain.global.prefix
    )?;
    if svc.multi {
        let names: Vec<&str> = svc.arms.iter().map(|a| a.prefix.as_str()).collect();
        crate::outln!(out, "  arms        {} ({})", names.len(), names.join(", "))?;
    }
    for cfg in &svc.arms {
        if svc.multi {
            crate::outln!(out, "  [[arm]] {}", cfg.prefix)?;
        }
        crate::outln!(
            out,
            "  io          {} (boards {:?})",
            cfg.io_path.display(),
            board_ids(cfg)
        )?;
        crate::outln!(
            out,
            "  arm         {:?}, instrument {}",
            cfg.arm,
            cfg.instrument.name
        )?;
        crate::outln!(out, "  compliance  {}", cfg.compliance_path.display())?;
        crate::outln!(out, "  prefix      {}", cfg.prefix)?;
        crate::outln!(out, "  base frame  {}", cfg.base_frame_origin)?;
        if let Some(p) = &cfg.scenario_path {
            crate::outln!(out, "  scenario    {}", p.display())?;
        }
        for w in &cfg.warnings {
            eprintln!("warning: {}: {w}", cfg.prefix);
        }
    }
    Ok(())
}

/// [`preflight`] of the source once, and of every arm's simulator and services.
pub fn preflight_service(svc: &ServiceConfig) -> Result<()> {
    for (i, cfg) in svc.arms.iter().enumerate() {
        let r = if i == 0 {
            preflight(cfg)
        } else {
            preflight_arm(cfg)
        };
        if svc.multi {
            r.with_context(|| format!("[[arm]] \"{}\"", cfg.prefix))?;
        } else {
            r?;
        }
    }
    Ok(())
}

/// Every check `serve` makes before its loop, without starting anything: the real-time
/// settings are permitted, the source can be opened (the simulator starts, the UDP socket binds,
/// FireWire is compiled in and its device exists), the prefix is a valid service name, and this
/// user may create the shared-memory node and open the services. `check-config` and `serve`
/// both call it, so a file that `check-config` accepts does not fail in `serve` for any of these.
pub fn preflight(cfg: &SidecarConfig) -> Result<()> {
    rt::check(&cfg.realtime)?;
    match &cfg.source {
        Source::Sim => {}
        Source::Udp(addr) => {
            UdpLink::connect(*addr).with_context(|| format!("opening a UDP socket to {addr}"))?;
        }
        Source::Firewire(n) => firewire_check(*n)?,
        Source::Tap { iface, port } => {
            // The interface exists and this process may capture on it (CAP_NET_RAW).
            crate::tap::Capture::open(iface, *port, crate::tap::Direction::Replies)?;
        }
    }
    preflight_arm(cfg)
}

/// The checks of [`preflight`] that belong to one arm: its simulator and its services.
fn preflight_arm(cfg: &SidecarConfig) -> Result<()> {
    if cfg.source == Source::Sim {
        let scenario = cfg
            .scenario
            .as_ref()
            .context("source = \"sim\" needs a [sim] scenario")?;
        sim_emulator(cfg, scenario)?;
    }
    let names = ServiceNames::new(&cfg.prefix)
        .map_err(|e| anyhow::anyhow!("prefix \"{}\": {e}", cfg.prefix))?;
    // The service publishes only into a shared-memory directory of its own account: created
    // 0700, refused when it is a link, another account's or writable by others.
    let domain = dvrk_ipc::default_domain()?;
    dvrk_ipc::access::ensure_private_root(&domain)?;
    let root = domain.global.root_path().to_string();
    let node = dvrk_ipc::create_node::<iceoryx2::service::ipc::Service>(
        "dvrk-sidecar-check",
        Some(&domain),
    )
    .context(shm_hint(&root))?;
    dvrk_ipc::ArmServices::open_or_create(&node, &names).with_context(|| {
        format!(
            "opening the services under {}; {}",
            cfg.prefix,
            shm_hint(&root)
        )
    })?;
    Ok(())
}

/// What to look at when iceoryx2 cannot create its files in the domain whose root path is
/// `root`.
fn shm_hint(root: &str) -> String {
    let mut bad = Vec::new();
    for dir in ["/dev/shm", root] {
        let p = std::path::Path::new(dir);
        if p.exists() && std::fs::metadata(p).is_ok_and(|m| m.permissions().readonly()) {
            bad.push(dir);
        }
    }
    format!(
        "creating iceoryx2 shared memory failed: this user needs write access to /dev/shm and \
         {root}{}",
        if bad.is_empty() {
            String::new()
        } else {
            format!("; read-only: {}", bad.join(", "))
        }
    )
}

#[cfg(feature = "firewire")]
fn firewire_check(n: u32) -> Result<()> {
    // access(2), not open(2): the dVRK console refuses to start while another process holds
    // the device open, so a check must not open it.
    let dev = format!("/dev/fw{n}");
    let c = std::ffi::CString::new(dev.clone())?;
    // SAFETY: `c` is a valid NUL-terminated path.
    if unsafe { libc::access(c.as_ptr(), libc::R_OK | libc::W_OK) } != 0 {
        anyhow::bail!(
            "source fw:{n}: {dev} is not readable and writable by this user: {}",
            std::io::Error::last_os_error()
        );
    }
    Ok(())
}

#[cfg(not(feature = "firewire"))]
fn firewire_check(n: u32) -> Result<()> {
    anyhow::bail!(
        "source fw:{n}: this binary was built without FireWire support; rebuild with \
         `cargo build --release -p dvrk-sidecar --features firewire` (needs libraw1394-dev)"
    )
}

/// One source of samples, read once per cycle.
pub trait SampleSource {
    /// Reads the arm at host time `t_ns` into `out`.
    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome;
    /// Whether the samples come from the simulator.
    fn simulated(&self) -> bool {
        false
    }
    /// Converts with another instrument's actuator-to-joint coupling from the next read on (the
    /// console reported a new instrument). No allocation.
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool;
    /// Per actuator, potentiometer minus encoder position of the last read, both as the source
    /// decoded them (actuator space; NaN where the io file has no pot calibration), for the
    /// pot/encoder check; None: this source reads no pots. A difference, so that it holds
    /// whatever coupling the check converts joints back with; a copy, so that a source behind
    /// a `RefCell` (the tap) can give it too.
    fn pot_minus_encoder(&self) -> Option<[f64; dvrk_io::NUM_JOINTS]> {
        None
    }
}

fn outcome(r: Result<(), dvrk_io::reader::ReadError>) -> ReadOutcome {
    match r {
        Ok(()) => ReadOutcome::Ok,
        Err(dvrk_io::reader::ReadError::Port(dvrk_io::port::PortError::Timeout { .. })) => {
            ReadOutcome::Timeout
        }
        Err(_) => ReadOutcome::Error,
    }
}

impl<P: Port> SampleSource for ArmReader<P> {
    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        outcome(ArmReader::read(self, t_ns, out))
    }
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool {
        self.config_mut().set_coupling(*coupling).is_ok()
    }
    fn pot_minus_encoder(&self) -> Option<[f64; dvrk_io::NUM_JOINTS]> {
        ArmReader::pot_minus_encoder(self)
    }
}

/// The simulated PSM of `cfg` on the arm's own boards (PSM2 of a several-arm file on 8 and 9).
fn sim_emulator(cfg: &SidecarConfig, scenario: &dvrk_sim::Scenario) -> Result<dvrk_sim::Emulator> {
    let ids = cfg.io.board_ids();
    let [a, b] = ids else {
        anyhow::bail!(
            "the simulated PSM has two boards; the io file gives {} ({ids:?})",
            ids.len()
        );
    };
    let map =
        dvrk_sim::ActuatorMap::from_io_config(&cfg.io).context("starting the simulated PSM")?;
    dvrk_sim::Emulator::chain(&[dvrk_sim::ArmSpec {
        scenario,
        map,
        boards: [*a, *b],
    }])
    .context("starting the simulated PSM")
}

/// The simulated PSM in-process: its physics is advanced to the cycle's time, then read
/// through the real board protocol.
pub struct SimSource {
    reader: ArmReader<dvrk_sim::SimPort>,
    start_ns: Option<u64>,
}

impl SimSource {
    pub fn new(cfg: &SidecarConfig) -> Result<Self> {
        let scenario = cfg
            .scenario
            .as_ref()
            .context("source = \"sim\" needs a scenario")?;
        let emulator = sim_emulator(cfg, scenario)?;
        let port = dvrk_sim::SimPort::new(dvrk_sim::SimLink::new(emulator));
        Ok(Self {
            reader: ArmReader::new(port, cfg.io.clone(), cfg.access),
            start_ns: None,
        })
    }

    pub fn emulator(&mut self) -> &mut dvrk_sim::Emulator {
        self.reader.port_mut().link_mut().emulator_mut()
    }
}

impl SampleSource for SimSource {
    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        // The simulator's clock starts at 0 on the first cycle.
        let start = *self.start_ns.get_or_insert(t_ns);
        self.emulator().advance_to(t_ns - start);
        outcome(self.reader.read(t_ns, out))
    }
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool {
        self.reader.config_mut().set_coupling(*coupling).is_ok()
    }
    fn simulated(&self) -> bool {
        true
    }
    fn pot_minus_encoder(&self) -> Option<[f64; dvrk_io::NUM_JOINTS]> {
        self.reader.pot_minus_encoder()
    }
}

/// One port read by every arm of the service in turn: each cycle reads arm after arm on the
/// same socket or FireWire handle. A `RefCell`, not a lock: the loop is one thread and an arm's
/// read ends before the next arm's starts, so a borrow never overlaps another.
pub struct SharedPort<P>(std::rc::Rc<std::cell::RefCell<P>>);

impl<P> SharedPort<P> {
    pub fn new(port: P) -> Self {
        Self(std::rc::Rc::new(std::cell::RefCell::new(port)))
    }
}

impl<P> Clone for SharedPort<P> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<P: Port> Port for SharedPort<P> {
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, dvrk_io::port::PortError> {
        self.0.borrow_mut().read_quadlet(board, addr)
    }
    fn read_block(
        &mut self,
        board: u8,
        addr: u16,
        out: &mut [u8],
    ) -> Result<(), dvrk_io::port::PortError> {
        self.0.borrow_mut().read_block(board, addr, out)
    }
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), dvrk_io::port::PortError> {
        self.0
            .borrow_mut()
            .broadcast_query_hub_read(board_mask, out)
    }
    fn read_quadlets(
        &mut self,
        reqs: &[(u8, u16)],
        out: &mut [Option<u32>],
    ) -> Result<(), dvrk_io::port::PortError> {
        self.0.borrow_mut().read_quadlets(reqs, out)
    }
}

/// Consecutive failed reads of an arm after which its boards are asked less often.
pub const BACKOFF_AFTER_FAILURES: u32 = 3;
/// The longest pause between two attempts on an arm whose boards do not answer, in cycles
/// (0.68 s at 1500 Hz): the longest a returning arm waits to be read again.
pub const BACKOFF_MAX_CYCLES: u32 = 1024;

/// One arm of several on a shared port. An arm whose boards stop answering would cost every
/// other arm a reply timeout per cycle; after [`BACKOFF_AFTER_FAILURES`] failed reads in a row
/// its boards are asked again only after 8, 16, ... up to [`BACKOFF_MAX_CYCLES`] cycles, each
/// skipped cycle published as invalid with BOARD_TIMEOUT without any I/O. The first good read
/// ends the pause. Only the several-arm service uses it: one arm alone retries every cycle.
pub struct Backoff<S> {
    inner: S,
    failures: u32,
    pause: u32,
    skipped: u32,
}

impl<S> Backoff<S> {
    pub fn new(inner: S) -> Self {
        Self {
            inner,
            failures: 0,
            pause: 0,
            skipped: 0,
        }
    }
}

impl<S: SampleSource> SampleSource for Backoff<S> {
    fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> ReadOutcome {
        if self.skipped < self.pause {
            self.skipped += 1;
            out.t_ns = t_ns;
            out.valid = false;
            return ReadOutcome::Timeout;
        }
        let r = self.inner.read(t_ns, out);
        match r {
            ReadOutcome::Timeout | ReadOutcome::Error => {
                self.failures = self.failures.saturating_add(1);
                if self.failures >= BACKOFF_AFTER_FAILURES {
                    self.pause = (self.pause * 2).clamp(8, BACKOFF_MAX_CYCLES);
                    self.skipped = 0;
                }
            }
            _ => {
                self.failures = 0;
                self.pause = 0;
                self.skipped = 0;
            }
        }
        r
    }
    fn simulated(&self) -> bool {
        self.inner.simulated()
    }
    fn set_coupling(&mut self, coupling: &[[f64; 4]; 4]) -> bool {
        self.inner.set_coupling(coupling)
    }
    fn pot_minus_encoder(&self) -> Option<[f64; dvrk_io::NUM_JOINTS]> {
        self.inner.pot_minus_encoder()
    }
}

/// `serve`: load, set up, run until SIGTERM/SIGINT.
pub fn run(path: &Path) -> Result<()> {
    let svc = ServiceConfig::load(path)?;
    preflight_service(&svc).with_context(|| format!("{}", path.display()))?;
    for cfg in &svc.arms {
        for w in &cfg.warnings {
            warn!(arm = %cfg.prefix, "{w}");
        }
        info!(
            arm = %cfg.prefix, base_frame = %cfg.base_frame_origin,
            "measured_cp = base frame x local/measured_cp"
        );
    }
    let stop = StopFlag::install()?;
    spawn_shutdown_guard(stop.clone());
    let first = &svc.arms[0];
    match first.source.clone() {
        Source::Sim => {
            let sources = svc
                .arms
                .iter()
                .map(SimSource::new)
                .collect::<Result<Vec<_>>>()?;
            run_loop(&svc, sources, &stop)
        }
        Source::Udp(addr) => {
            let mut link =
                UdpLink::connect(addr).with_context(|| format!("opening UDP socket to {addr}"))?;
            link.set_timeout(first.reply_timeout)
                .context("setting the reply timeout")?;
            let mut port = UdpPort::new(link);
            port.set_quadlet_window(first.shared_requests_in_flight);
            if first.access == dvrk_io::reader::AccessMode::Shared {
                info!(
                    window = first.shared_requests_in_flight,
                    "shared mode: quadlet requests in flight"
                );
            }
            if !discover_arms(&mut port, &svc, &addr.to_string(), &stop)? {
                return Ok(());
            }
            let shared = SharedPort::new(port);
            let port = shared.clone();
            let r = run_readers(&svc, shared, &stop);
            let p = port.0.borrow();
            let c = p.counters();
            info!(
                requests = c.requests,
                replies = c.replies_ok,
                quadlet_retries = c.quadlet_retries,
                stale_replies = c.stale_replies,
                timeouts = c.timeouts,
                batches = c.quadlet_batches,
                batch_deadlines = c.batch_deadlines,
                labels_reused_unanswered = c.labels_reused_unanswered,
                retry_wait_us = p
                    .quadlet_retry_wait()
                    .map_or(0.0, |w| w.as_secs_f64() * 1e6),
                "UDP port at the stop"
            );
            r
        }
        Source::Firewire(n) => firewire(&svc, n, &stop),
        Source::Tap { iface, port } => {
            let ios: Vec<IoConfig> = svc.arms.iter().map(|a| a.io.clone()).collect();
            let sources = crate::tap::TapSource::open_arms(&iface, port, ios)?;
            run_loop(&svc, sources, &stop)
        }
    }
}

/// How far the stop got, for the shutdown guard's message: 0 the cycle loop has not noticed
/// it, 1 the loop ended, 2 the housekeeping thread was joined, 3 the final counters logged.
static STOP_PHASE: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

fn stop_phase(p: u8) {
    STOP_PHASE.store(p, std::sync::atomic::Ordering::Relaxed);
}

/// How long `serve` may take to stop after SIGTERM or SIGINT before it exits anyway.
pub const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(10);

/// A thread that waits for the stop request, then gives the service [`SHUTDOWN_GRACE`] to
/// finish (the loop notices the request within a cycle; then the housekeeping thread is joined
/// and iceoryx2's resources are released) and, if it has not, says so and exits with status 3.
/// A stop that hangs (seen once in CI: a `serve` still alive 20 s after SIGTERM, cause not
/// found) then costs 10 s, not a unit stuck until systemd's SIGKILL. The process ends with
/// `run`, so after a normal stop the thread goes with it.
fn spawn_shutdown_guard(stop: StopFlag) {
    let spawned = std::thread::Builder::new()
        .name("shutdown-guard".into())
        .spawn(move || {
            while !stop.raised() {
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            std::thread::sleep(SHUTDOWN_GRACE);
            let phase = match STOP_PHASE.load(std::sync::atomic::Ordering::Relaxed) {
                0 => "the cycle loop had not noticed the stop",
                1 => "joining the housekeeping thread",
                2 => "logging the final counters",
                _ => "releasing the shared memory",
            };
            tracing::error!(
                grace_s = SHUTDOWN_GRACE.as_secs(),
                "the stop did not finish in time after SIGTERM/SIGINT ({phase}); exiting without it"
            );
            std::process::exit(3);
        });
    if let Err(e) = spawned {
        warn!("no shutdown guard: starting its thread failed: {e}");
    }
}

/// Every arm read through its own [`ArmReader`] on one shared port; with several arms, each
/// behind a [`Backoff`].
fn run_readers<P: Port>(svc: &ServiceConfig, port: SharedPort<P>, stop: &StopFlag) -> Result<()> {
    // Shared-mode samples timed by when the boards answered (a slow read's wait is not motion
    // time), on the loop's own clock.
    let reader = |cfg: &SidecarConfig| {
        ArmReader::new(port.clone(), cfg.io.clone(), cfg.access)
            .with_completion_clock(crate::rt::monotonic_ns)
    };
    if svc.arms.len() > 1 {
        let sources = svc.arms.iter().map(|c| Backoff::new(reader(c))).collect();
        run_loop(svc, sources, stop)
    } else {
        // One arm: retry every cycle, as it always did.
        run_loop(svc, svc.arms.iter().map(reader).collect(), stop)
    }
}

/// How long a several-arm service waits for every arm's boards before it starts with the arms
/// that answered (the others publish invalid samples until their boards answer).
const PARTIAL_START_AFTER: std::time::Duration = std::time::Duration::from_secs(5);

/// Discovery of every arm's boards. One arm: [`discover_until_found`] (waits until they all
/// answer). Several: the same wait, but after [`PARTIAL_START_AFTER`] the service starts once
/// at least one arm's boards all answered, naming the arms whose boards are missing. Returns
/// false when stopped by a signal first.
fn discover_arms<L: dvrk_io::Link>(
    port: &mut dvrk_io::EthPort<L>,
    svc: &ServiceConfig,
    at: &str,
    stop: &StopFlag,
) -> Result<bool> {
    if svc.arms.len() == 1 {
        let ids = board_ids(&svc.arms[0]);
        let found = discover_until_found(port, &ids, at, stop, None)?;
        if found {
            info!(%at, boards = ?ids, "boards found");
        }
        return Ok(found);
    }
    let all: Vec<u8> = svc.arms.iter().flat_map(board_ids).collect();
    let started = std::time::Instant::now();
    loop {
        if discover_until_found(port, &all, at, stop, Some(PARTIAL_START_AFTER))? {
            info!(%at, boards = ?all, "boards of every arm found");
            return Ok(true);
        }
        if stop.raised() {
            return Ok(false);
        }
        // Some board is missing: start with the arms whose boards all answer.
        let mut found = Vec::new();
        let mut missing = Vec::new();
        for cfg in &svc.arms {
            let ids = board_ids(cfg);
            match port.discover(&ids) {
                Ok(_) => found.push(cfg.prefix.as_str()),
                Err(e) if e.is_configuration() => {
                    return Err(e).with_context(|| {
                        format!("[[arm]] \"{}\": boards {ids:?} at {at}", cfg.prefix)
                    });
                }
                Err(e) => missing.push(format!("{} (boards {ids:?}: {e})", cfg.prefix)),
            }
        }
        if !found.is_empty() {
            warn!(
                waited_s = started.elapsed().as_secs_f64(),
                "starting with {}; not answering: {}. Their samples are published invalid \
                 (BOARD_TIMEOUT) until their boards answer",
                found.join(", "),
                missing.join("; ")
            );
            return Ok(true);
        }
    }
}

/// Discovery that waits for the boards: it retries with a backoff (10 ms doubling to 500 ms)
/// until every board answers, logs once a second what it waits for and tells systemd
/// (`STATUS=`). It gives up only on an error that asking again cannot fix (a board of another
/// kind, firmware or id than configured). Returns false when stopped by a signal first.
fn discover_until_found<L: dvrk_io::Link>(
    port: &mut dvrk_io::EthPort<L>,
    ids: &[u8],
    at: &str,
    stop: &StopFlag,
    give_up_after: Option<std::time::Duration>,
) -> Result<bool> {
    let mut backoff = std::time::Duration::from_millis(10);
    let started = std::time::Instant::now();
    let mut next_log = started;
    let mut attempts = 0u64;
    loop {
        if stop.raised() || give_up_after.is_some_and(|g| started.elapsed() >= g) {
            return Ok(false);
        }
        attempts += 1;
        match port.discover(ids) {
            Ok(_) => {
                if attempts > 1 {
                    info!(
                        attempts,
                        waited_s = started.elapsed().as_secs_f64(),
                        "boards answered"
                    );
                }
                return Ok(true);
            }
            Err(e) if e.is_configuration() => {
                return Err(e).with_context(|| format!("boards {ids:?} at {at}"));
            }
            Err(e) => {
                let now = std::time::Instant::now();
                if now >= next_log {
                    let status = format!("waiting for boards {ids:?} at {at}: {e}");
                    warn!(attempts, "{status}");
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
                    next_log = now + std::time::Duration::from_secs(1);
                }
                std::thread::sleep(backoff);
                backoff = (backoff * 2).min(std::time::Duration::from_millis(500));
            }
        }
    }
}

/// FireWire follows the console's life cycle (crate::fw_life): open the port once the console
/// holds it, read until the console lets it go, release it, wait for the console again.
#[cfg(feature = "firewire")]
fn firewire(svc: &ServiceConfig, n: u32, stop: &StopFlag) -> Result<()> {
    let dev = crate::fw_life::device(n);
    loop {
        if !crate::fw_life::wait_for_console(&dev, stop) {
            return Ok(());
        }
        let port = dvrk_io::port::FirewirePort::open(n)
            .with_context(|| format!("opening FireWire port {n}"))?;
        let release = crate::fw_life::watch_release(dev.clone(), stop.clone())
            .context("starting the FireWire release watch")?;
        run_readers(svc, SharedPort::new(port), &release)?;
        if stop.raised() {
            return Ok(());
        }
        // run_readers dropped the port: the console can start again.
    }
}

#[cfg(not(feature = "firewire"))]
fn firewire(_svc: &ServiceConfig, n: u32, _stop: &StopFlag) -> Result<()> {
    // preflight() has refused this already; the one message lives in firewire_check.
    firewire_check(n)
}

/// Counters of the loop, kept for the 1 Hz summary and the status message.
#[derive(Debug, Default, Clone, Copy)]
pub struct Counters {
    pub cycles: u64,
    pub read_failures: u64,
    pub consecutive_read_failures: u64,
    pub overruns: u64,
    pub publish_failures: u64,
    /// Samples that were read but refused by the plausibility checks.
    pub implausible: u64,
    pub window_cycles: u64,
    pub window_read_failures: u64,
    pub window_implausible: u64,
    /// Valid cycles in the current summary window.
    pub window_valid: u64,
    pub window_max_displacement_m: f64,
    /// Tip displacement of the newest valid cycle of the current window (None: no valid cycle
    /// in this window, so there is no fresh figure to print).
    pub window_last_displacement_m: Option<f64>,
}

/// One cycle's work, from the read to the notify: what the loop runs every period and what
/// benches/cycle.rs measures. Owns the source, the sample buffer, the plausibility checker, the
/// last valid cycle (held while reads fail) and the publishers.
pub struct Pipeline<'a, Src: SampleSource, Svc: iceoryx2::service::Service> {
    pub source: Src,
    pub sample: ArmSample,
    pub model: &'a dvrk_compliance::ComplianceConfig,
    /// The mounted instrument's kinematics (switched by [`Follow`] when the console reports
    /// another instrument).
    pub kinematics: dvrk_compliance::PsmKinematics,
    pub publisher: ArmPublisher<Svc>,
    pub counters: Counters,
    pub period_ns: u64,
    /// How late the current cycle started after its deadline; set by the loop before
    /// [`Pipeline::cycle`], published in the status message.
    pub late_ns: u64,
    check: Option<(SampleCheck, &'a IoConfig)>,
    /// The internal-torque estimator (friction and inertia removed from the measured effort);
    /// reset by every invalid sample.
    compensator: dvrk_compliance::Compensator,
    held: Option<cycle::Held>,
    /// The arm's base frame: `measured_cp = base_frame × local/measured_cp`.
    base_frame: nalgebra::Isometry3<f64>,
    last_duration_ns: u64,
    last_sample_t_ns: Option<u64>,
    follow: Option<Follow>,
    /// Parameter sets per instrument (empty: `model` for every instrument).
    sets: &'a [crate::formats::ParamSet],
    /// The set in use (None with `sets`: none for the mounted instrument, NO_CALIBRATION).
    set_idx: Option<usize>,
    /// The configured instrument's code in `source_state` (0: not given).
    instrument_code: u16,
}

/// What the cycle keeps of the console it follows (crate::console_follow).
pub struct Follow {
    shared: std::sync::Arc<crate::console_follow::Shared>,
    view: crate::console_follow::View,
    arm: dvrk_compliance::ArmKind,
    /// Follow `tool_type` (`instrument = "console"`).
    instrument: bool,
    /// The instrument applied (kinematics and coupling).
    mounted: crate::console_follow::Mounted,
    /// The base frame configured, used until the console's arrives.
    configured_base: nalgebra::Isometry3<f64>,
}

impl Follow {
    pub fn new(
        shared: std::sync::Arc<crate::console_follow::Shared>,
        arm: dvrk_compliance::ArmKind,
        instrument: bool,
        configured_base: nalgebra::Isometry3<f64>,
    ) -> Self {
        Self {
            shared,
            view: crate::console_follow::View::default(),
            arm,
            instrument,
            mounted: crate::console_follow::Mounted::NotYet,
            configured_base,
        }
    }
}

impl<'a, Src: SampleSource, Svc: iceoryx2::service::Service> Pipeline<'a, Src, Svc> {
    pub fn new(
        source: Src,
        model: &'a dvrk_compliance::ComplianceConfig,
        kinematics: &'a dvrk_compliance::PsmKinematics,
        publisher: ArmPublisher<Svc>,
        period_ns: u64,
    ) -> Self {
        Self {
            source,
            sample: ArmSample::default(),
            model,
            kinematics: *kinematics,
            publisher,
            counters: Counters::default(),
            period_ns,
            late_ns: 0,
            check: None,
            compensator: dvrk_compliance::Compensator::new(),
            held: None,
            base_frame: nalgebra::Isometry3::identity(),
            last_duration_ns: 0,
            last_sample_t_ns: None,
            follow: None,
            sets: &[],
            set_idx: None,
            instrument_code: 0,
        }
    }

    /// Parameter sets per instrument; `initial` is the set of the configured instrument (None:
    /// none, NO_CALIBRATION until an instrument with a set is mounted).
    pub fn with_sets(
        mut self,
        sets: &'a [crate::formats::ParamSet],
        initial: Option<usize>,
    ) -> Self {
        self.sets = sets;
        self.set_idx = initial;
        self
    }

    /// The parameters in use.
    #[inline]
    fn active_model(&self) -> &'a dvrk_compliance::ComplianceConfig {
        match self.set_idx.and_then(|i| self.sets.get(i)) {
            Some(s) => &s.config,
            None => self.model,
        }
    }

    /// Follows the console (crate::console_follow): its state, base frame and, with
    /// `Follow::instrument`, its instrument, read at the start of every cycle.
    pub fn with_follow(mut self, follow: Follow) -> Self {
        self.follow = Some(follow);
        self
    }

    /// At a cycle's start: the console's newest view; a new instrument switches kinematics and
    /// coupling now, between two reads. No lock, no allocation.
    #[inline]
    fn follow_begin(&mut self) {
        use crate::console_follow::Mounted;
        let Some(f) = self.follow.as_mut() else {
            return;
        };
        if let Some(v) = f.shared.read() {
            f.view = v;
        }
        if f.instrument && f.view.mounted != f.mounted {
            f.mounted = f.view.mounted;
            if let Mounted::Catalog(_) = f.mounted
                && let Some(inst) = f.mounted.instrument()
                && let Ok(c) = inst.coupling()
            {
                self.kinematics = dvrk_compliance::PsmKinematics::new(f.arm, inst);
                self.source.set_coupling(c);
                if !self.sets.is_empty() {
                    let model = inst.model;
                    let idx = self
                        .sets
                        .iter()
                        .position(|s| s.instrument.is_some_and(|i| i.model == model))
                        .or_else(|| self.sets.iter().position(|s| s.instrument.is_none()));
                    if idx != self.set_idx {
                        self.set_idx = idx;
                        // the estimator's history belongs to the other parameters
                        self.compensator.reset();
                    }
                }
            }
        }
        self.base_frame = f.view.base_frame().unwrap_or(f.configured_base);
    }

    /// [`dvrk_ipc::CompensationStatusV4::source_state`] of this cycle.
    #[inline]
    fn source_state(
        follow: Option<&Follow>,
        sets: usize,
        set_idx: Option<usize>,
        instrument_code: u16,
        t_ns: u64,
    ) -> u32 {
        let set = match set_idx {
            Some(i) if sets > 1 => (i + 1).min(255) as u8,
            _ => 0,
        };
        match follow {
            None => dvrk_ipc::pack_source_state(0, false, false, set, instrument_code),
            Some(f) => {
                let v = &f.view;
                let heard = v.heard_ns != 0
                    && t_ns.saturating_sub(v.heard_ns) < crate::console_follow::STALE_NS;
                let instrument = if f.instrument {
                    f.mounted.code().min(u64::from(u16::MAX)) as u16
                } else {
                    instrument_code
                };
                dvrk_ipc::pack_source_state(v.state as u8, v.homed, heard, set, instrument)
            }
        }
    }

    /// The configured instrument, for `source_state` when the console does not name it.
    pub fn with_instrument(mut self, instrument: &'static dvrk_compliance::Instrument) -> Self {
        self.instrument_code = crate::console_follow::Mounted::of(instrument).code() as u16;
        self
    }

    /// After the correction: what the console's state makes of this cycle (see
    /// crate::console_follow).
    #[inline]
    fn follow_end(
        follow: Option<&Follow>,
        sample: &ArmSample,
        result: &mut cycle::CycleResult,
        t_ns: u64,
    ) {
        use crate::console_follow::{Mounted, OpState, STALE_NS};
        let Some(f) = follow else {
            return;
        };
        let v = &f.view;
        let heard = v.heard_ns != 0 && t_ns.saturating_sub(v.heard_ns) < STALE_NS;
        if !heard {
            result.flags |= flags::CONSOLE_UNKNOWN;
        } else {
            if v.state == OpState::Unknown {
                // heard (its poses), but no operating state yet: a console whose events are
                // VOLATILE says it only when it changes
                result.flags |= flags::CONSOLE_UNKNOWN;
            }
            if !v.homed {
                // encoders not referenced: no correction either (nor its flags on the sample)
                result.valid = false;
                result.withhold_correction(&sample.position);
                result.flags |= flags::NOT_HOMED;
            }
            if v.state != OpState::Enabled {
                result.withhold_correction(&sample.position);
                result.flags |= flags::ARM_NOT_ENABLED;
            }
        }
        if v.base_ns == 0 || t_ns.saturating_sub(v.base_ns) >= STALE_NS {
            result.flags |= flags::BASE_FRAME_STALE;
        }
        if f.instrument {
            match f.mounted {
                Mounted::NotYet => {
                    result.compensated_valid = false;
                    result.flags |= flags::CONSOLE_UNKNOWN;
                }
                Mounted::Removed => {
                    result.compensated_valid = false;
                    result.withhold_correction(&sample.position);
                    result.flags |= flags::NO_INSTRUMENT;
                }
                Mounted::Unsupported => {
                    result.compensated_valid = false;
                    result.withhold_correction(&sample.position);
                    result.flags |= flags::INSTRUMENT_UNSUPPORTED;
                }
                Mounted::Catalog(_) => {}
            }
        }
    }

    /// Checks every successfully read sample with `check` (limits, jumps, currents) before it
    /// is published as valid; `io` converts joint values back to actuator space.
    pub fn with_check(mut self, check: SampleCheck, io: &'a IoConfig) -> Self {
        self.check = Some((check, io));
        self
    }

    /// Publishes `measured_cp` (raw and compensated) in `base_frame` (default: identity).
    pub fn with_base_frame(mut self, base_frame: nalgebra::Isometry3<f64>) -> Self {
        self.base_frame = base_frame;
        self
    }

    /// The plausibility checker's counters, when there is one.
    pub fn check_counters(&self) -> Option<dvrk_io::plausibility::PlausibilityCounters> {
        self.check.as_ref().map(|(c, _)| c.counters())
    }

    /// Runs one cycle that starts at `t_start` (the loop's clock reading, passed to the reader
    /// for velocities and to the simulator). `clock` is read twice more: when the board read has
    /// completed (the header's `sample_t_ns`) and just before sending (`publish_t_ns`).
    /// Returns the sample time (ns). No allocation, no lock, no logging.
    ///
    /// A cycle whose read failed, or whose sample the checks refused, publishes `valid = 0`
    /// with the reason, and the last valid cycle's values (flag `HELD`, its age in the status
    /// message); never zeros, never a correction computed from a half-read sample.
    #[inline]
    pub fn cycle(&mut self, t_start: u64, clock: impl Fn() -> u64) -> u64 {
        self.follow_begin();
        let model = self.active_model();
        let c = &mut self.counters;
        let mut read = self.source.read(t_start, &mut self.sample);
        let t_sample = clock();
        // The same instant on the realtime (ROS) clock: one vDSO read, tens of ns later.
        let t_sample_real = dvrk_ipc::clock::realtime_ns();
        if read == ReadOutcome::Ok
            && self.sample.valid
            && let Some((check, io)) = self.check.as_mut()
        {
            let s = &self.sample;
            let actuator_position = io.joint_to_actuator_position(&s.position);
            let actuator_effort = io.joint_to_actuator_effort(&s.effort);
            let amps: [f64; dvrk_io::NUM_JOINTS] =
                core::array::from_fn(|i| io.actuators()[i].effort_to_amps(actuator_effort[i]));
            let pots: Option<[f64; dvrk_io::NUM_JOINTS]> = self
                .source
                .pot_minus_encoder()
                .map(|d| core::array::from_fn(|i| actuator_position[i] + d[i]));
            // Timed by the read's completion, as the header's `sample_t_ns`: a slow read's
            // wait is not motion time for the next cycle's jump check.
            if let Some(e) = check
                .check_at(t_sample, s, &actuator_position, &amps, pots.as_ref())
                .err()
            {
                read = match e {
                    dvrk_io::plausibility::Implausible::PotMismatch { .. } => {
                        ReadOutcome::PotMismatch
                    }
                    _ => ReadOutcome::Implausible,
                };
                c.implausible += 1;
                c.window_implausible += 1;
            }
        }
        if read == ReadOutcome::Ok {
            c.consecutive_read_failures = 0;
        } else if !matches!(read, ReadOutcome::Implausible | ReadOutcome::PotMismatch) {
            c.consecutive_read_failures += 1;
            c.read_failures += 1;
            c.window_read_failures += 1;
        }
        let fresh = cycle::compute_dynamic(
            model,
            &mut self.compensator,
            &self.kinematics,
            &self.sample,
            read,
        );
        let (held_age, (sample, mut result)) = if fresh.valid {
            self.held = Some(cycle::Held {
                sample: self.sample,
                result: fresh,
                sample_t_ns: t_sample,
            });
            (0, (self.sample, fresh))
        } else {
            let age = self
                .held
                .as_ref()
                .map_or(u64::MAX, |h| t_sample.saturating_sub(h.sample_t_ns));
            (
                age,
                cycle::held(
                    self.held.as_ref(),
                    &self.sample,
                    cycle::health_flags(&self.sample, read),
                ),
            )
        };
        Self::follow_end(self.follow.as_ref(), &sample, &mut result, t_sample);
        if !self.sets.is_empty() && self.set_idx.is_none() {
            result.withhold_correction(&sample.position);
            result.flags |= flags::NO_CALIBRATION;
        }
        result.source_state = Self::source_state(
            self.follow.as_ref(),
            self.sets.len(),
            self.set_idx,
            self.instrument_code,
            t_sample,
        );
        if self.source.simulated() {
            result.flags |= flags::SIMULATED;
        }
        if self.period_ns > 0 && self.last_duration_ns > self.period_ns {
            result.flags |= flags::OVERRUN;
        }
        let publish_t_ns = clock();
        let timing = CycleTiming {
            seq: c.cycles,
            sample_t_ns: t_sample,
            sample_realtime_ns: t_sample_real,
            publish_t_ns,
            cycle_period_ns: self
                .last_sample_t_ns
                .map_or(0, |t| t_sample.saturating_sub(t)),
            cycle_duration_ns: self.last_duration_ns,
            cycles_total: c.cycles + 1,
            read_failures_total: c.read_failures,
            overruns_total: c.overruns,
            consecutive_read_failures: c.consecutive_read_failures.min(u64::from(u32::MAX)) as u32,
            held_sample_age_ns: held_age,
            publish_late_ns: self.late_ns,
            implausible_total: c.implausible,
        };
        // The compensated tip pose leaves as soon as it is known; the other eight messages
        // (the uncompensated and base-frame poses, joints, status) are written after it.
        let first = cycle::compensated_local_measured_cp(&sample, &result, &timing);
        let sent = self.publisher.start_cycle(&first).and_then(|started| {
            started.finish(&cycle::messages_from_first(
                first,
                &sample,
                &result,
                &timing,
                &self.base_frame,
            ))
        });
        if sent.is_err() {
            c.publish_failures += 1;
        }
        c.cycles += 1;
        c.window_cycles += 1;
        if result.valid {
            let d = result.tip_displacement_m();
            c.window_valid += 1;
            c.window_last_displacement_m = Some(d);
            c.window_max_displacement_m = c.window_max_displacement_m.max(d);
        }
        self.last_sample_t_ns = Some(t_sample);
        t_sample
    }

    /// Records how long the cycle that started at `t_start` took, ending at `t_end`.
    #[inline]
    pub fn finish(&mut self, t_start: u64, t_end: u64) -> u64 {
        self.last_duration_ns = t_end.saturating_sub(t_start);
        if self.period_ns > 0 && self.last_duration_ns > self.period_ns {
            self.counters.overruns += 1;
        }
        self.last_duration_ns
    }
}

/// Sets up one [`Pipeline`] of an arm: its publishers, checks, parameter sets and, when
/// configured, the console it follows.
fn arm_pipeline<'a, Src: SampleSource>(
    cfg: &'a SidecarConfig,
    source: Src,
    node: &iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
    period_ns: u64,
    stop: &StopFlag,
) -> Result<Pipeline<'a, Src, iceoryx2::service::ipc::Service>> {
    let names = ServiceNames::new(&cfg.prefix).map_err(|e| anyhow::anyhow!("prefix: {e}"))?;
    let publisher = ArmPublisher::create(node, &names)
        .with_context(|| format!("creating the publishers under {}", cfg.prefix))?;
    let mut pipe = Pipeline::new(
        source,
        &cfg.compliance,
        &cfg.kinematics,
        publisher,
        period_ns,
    )
    .with_check(SampleCheck::new(plausibility_limits(cfg)), &cfg.io)
    .with_base_frame(cfg.base_frame)
    .with_instrument(cfg.instrument);
    if cfg.compliance_sets.len() > 1 || cfg.compliance_instrument.is_some() {
        let initial = cfg
            .compliance_sets
            .iter()
            .position(|s| {
                s.instrument
                    .is_some_and(|i| i.model == cfg.instrument.model)
            })
            .or_else(|| {
                cfg.compliance_sets
                    .iter()
                    .position(|s| s.instrument.is_none())
            });
        pipe = pipe.with_sets(&cfg.compliance_sets, initial);
    }
    if cfg.follow_console {
        let domain = dvrk_bridge::console::ros_domain_id()?;
        let shared = crate::console_follow::spawn(&cfg.console_arm, domain, stop.clone())?;
        info!(
            arm = %cfg.console_arm, domain,
            instrument_from_console = cfg.instrument_from_console,
            parameters_for = cfg.compliance_instrument.map_or("any instrument", |i| i.name),
            "following the dVRK console over DDS: operating state, base frame{}",
            if cfg.instrument_from_console { ", instrument" } else { "" }
        );
        pipe = pipe.with_follow(Follow::new(
            shared,
            cfg.arm,
            cfg.instrument_from_console,
            cfg.base_frame,
        ));
    }
    Ok(pipe)
}

fn run_loop<Src: SampleSource>(
    svc: &ServiceConfig,
    sources: Vec<Src>,
    stop: &StopFlag,
) -> Result<()> {
    let first = &svc.arms[0];
    let node = dvrk_ipc::create_node::<iceoryx2::service::ipc::Service>("dvrk-sidecar", None)
        .context("creating the iceoryx2 node")?;
    let period_ns = match first.rate {
        Rate::Hz(hz) => (1e9 / hz).round() as u64,
        Rate::Follow => 0,
    };
    let mut pipes = Vec::with_capacity(svc.arms.len());
    for (cfg, source) in svc.arms.iter().zip(sources) {
        pipes.push(arm_pipeline(cfg, source, &node, period_ns, stop)?);
    }
    rt::apply(&first.realtime)?;

    let watchdog_ns = sd_notify::watchdog_enabled().map(|d| (d.as_nanos() / 2) as u64);
    // One histogram per arm (its read to its notify) and one of the whole cycle (every arm).
    let mut hists: Vec<DurationHistogram> =
        pipes.iter().map(|_| DurationHistogram::new()).collect();
    let mut loop_hist = DurationHistogram::new();
    let (summaries, summary_rx) = sync_channel::<Summary>(1);
    let names: Vec<String> = svc.arms.iter().map(|a| a.prefix.clone()).collect();
    let housekeeping = spawn_housekeeping(summary_rx, names, stop.clone())?;

    for cfg in &svc.arms {
        // With the instrument from the console, the configured one holds only until it is heard.
        let instrument = if cfg.instrument_from_console {
            format!("from the console (until heard: {})", cfg.instrument.name)
        } else {
            cfg.instrument.name.to_owned()
        };
        info!(
            source = %cfg.source, access = ?cfg.access, rate = %cfg.rate, prefix = %cfg.prefix,
            instrument, "serving"
        );
    }
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);

    let t0 = rt::monotonic_ns();
    let mut deadline = t0;
    let mut next_summary = t0 + 1_000_000_000;
    let mut next_watchdog = t0;

    while !stop.raised() {
        if period_ns > 0 {
            rt::sleep_until_ns(deadline);
        }
        let t_cycle = rt::monotonic_ns();
        for (pipe, hist) in pipes.iter_mut().zip(hists.iter_mut()) {
            let t_start = rt::monotonic_ns();
            pipe.late_ns = if period_ns > 0 {
                t_start.saturating_sub(deadline)
            } else {
                0
            };
            pipe.cycle(t_start, rt::monotonic_ns);
            let t_end = rt::monotonic_ns();
            hist.record(pipe.finish(t_start, t_end));
        }
        let t_end = rt::monotonic_ns();
        loop_hist.record(t_end.saturating_sub(t_cycle));

        if period_ns > 0 {
            deadline += period_ns;
            if t_end > deadline + period_ns {
                // Fell more than a whole period behind (a stall, or reads slowed by a lossy
                // link): restart the schedule from now instead of bursting to catch up, and
                // start the next cycle at once. Waiting a whole period first left the loop idle
                // after every long cycle: under 10% loss (tests/faults.rs, default window,
                // release) 0.93-1.03 kHz against 1.10-1.22 kHz starting at once.
                deadline = t_end;
            }
        }
        if let Some(w) = watchdog_ns
            && t_end >= next_watchdog
        {
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            next_watchdog = t_end + w;
        }
        if t_end >= next_summary {
            let mut s = Summary {
                arms: [ArmSummary::default(); crate::config::MAX_ARMS],
                n: pipes.len().min(crate::config::MAX_ARMS),
                cycle_p99_ns: loop_hist.quantile_ns(0.99).unwrap_or(0),
                cycle_max_ns: loop_hist.max_ns(),
            };
            loop_hist.reset();
            for ((slot, pipe), hist) in s
                .arms
                .iter_mut()
                .zip(pipes.iter_mut())
                .zip(hists.iter_mut())
            {
                *slot = ArmSummary {
                    counters: pipe.counters,
                    cycle_p99_ns: hist.quantile_ns(0.99).unwrap_or(0),
                    cycle_max_ns: hist.max_ns(),
                    subscribers: pipe.publisher.subscriber_counts(),
                };
                hist.reset();
                let c = &mut pipe.counters;
                c.window_cycles = 0;
                c.window_read_failures = 0;
                c.window_implausible = 0;
                c.window_valid = 0;
                c.window_max_displacement_m = 0.0;
                c.window_last_displacement_m = None;
            }
            // A full slot (the thread has not taken the last one) drops this second's summary:
            // the loop never waits for logging.
            let _ = summaries.try_send(s);
            next_summary += 1_000_000_000;
            if next_summary < t_end {
                next_summary = t_end + 1_000_000_000;
            }
        }
    }
    stop_phase(1);
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    drop(summaries);
    if housekeeping.join().is_err() {
        warn!("the housekeeping thread panicked");
    }
    stop_phase(2);
    for (pipe, cfg) in pipes.iter().zip(&svc.arms) {
        let c = pipe.counters;
        info!(
            arm = %cfg.prefix,
            cycles = c.cycles,
            read_failures = c.read_failures,
            implausible = c.implausible,
            overruns = c.overruns,
            publish_failures = c.publish_failures,
            "stopped"
        );
    }
    stop_phase(3);
    Ok(())
}

/// How often `serve` removes the shared-memory resources of dead subscriber processes (in the
/// housekeeping thread; it lists files).
const REAP_PERIOD: std::time::Duration = std::time::Duration::from_secs(5);

/// Plausibility limits of the configured arm (reference §5.2 and the kinematics reference).
pub fn plausibility_limits(cfg: &SidecarConfig) -> PlausibilityLimits {
    match cfg.arm {
        dvrk_compliance::ArmKind::Classic => PlausibilityLimits::classic_psm(&cfg.io),
        dvrk_compliance::ArmKind::Si => PlausibilityLimits::si_psm(&cfg.io),
    }
}

/// One second of one arm, copied out of the loop for the housekeeping thread.
#[derive(Debug, Clone, Copy, Default)]
struct ArmSummary {
    counters: Counters,
    cycle_p99_ns: u64,
    cycle_max_ns: u64,
    subscribers: SubscriberCounts,
}

/// One second of the loop: every arm's, and the whole cycle's durations (all arms). A fixed
/// array, so the loop hands it over without allocating.
#[derive(Debug, Clone, Copy)]
struct Summary {
    arms: [ArmSummary; crate::config::MAX_ARMS],
    n: usize,
    cycle_p99_ns: u64,
    cycle_max_ns: u64,
}

/// How often the housekeeping thread looks for a summary (and for a stop).
const HOUSEKEEPING_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Starts the thread that logs the loop's summaries and reaps dead subscriber nodes with its own
/// iceoryx2 node. It polls the channel (`try_recv`) instead of blocking on it, so the loop's
/// `try_send` never has a waiter to wake and never takes the channel's internal lock. It ends
/// when the loop drops its sender or on a stop request.
fn spawn_housekeeping(
    summaries: Receiver<Summary>,
    names: Vec<String>,
    stop: StopFlag,
) -> Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("housekeeping".into())
        .spawn(move || {
            let node = dvrk_ipc::create_node::<iceoryx2::service::ipc::Service>(
                "dvrk-sidecar-reaper",
                None,
            );
            if let Err(e) = &node {
                warn!("no dead-node cleanup: creating the housekeeping node failed: {e}");
            }
            let mut next_reap = std::time::Instant::now() + REAP_PERIOD;
            loop {
                match summaries.try_recv() {
                    Ok(s) => {
                        for (a, name) in s.arms.iter().take(s.n).zip(&names) {
                            summary(a, name);
                        }
                        if s.n > 1 {
                            info!(
                                arms = s.n,
                                cycle_p99_us = format_args!("{:.1}", s.cycle_p99_ns as f64 / 1e3),
                                cycle_max_us = format_args!("{:.1}", s.cycle_max_ns as f64 / 1e3),
                                "summary of the whole cycle (every arm)"
                            );
                        }
                    }
                    Err(TryRecvError::Disconnected) => return,
                    Err(TryRecvError::Empty) if stop.raised() => return,
                    Err(TryRecvError::Empty) => {}
                }
                if let Ok(node) = &node
                    && std::time::Instant::now() >= next_reap
                {
                    // Subscribers killed without cleaning up (SIGKILL) would otherwise count,
                    // and cost a notification per cycle, until another process reaped them.
                    let r = node.try_cleanup_dead_nodes();
                    if r.cleanups > 0 || r.failed_cleanups > 0 {
                        info!(
                            reaped = r.cleanups,
                            failed = r.failed_cleanups,
                            "removed dead subscriber nodes"
                        );
                    }
                    next_reap = std::time::Instant::now() + REAP_PERIOD;
                }
                std::thread::sleep(HOUSEKEEPING_POLL);
            }
        })
        .context("starting the housekeeping thread")
}

fn summary(s: &ArmSummary, arm: &str) {
    let c = &s.counters;
    let p99_us = s.cycle_p99_ns as f64 / 1e3;
    let max_us = s.cycle_max_ns as f64 / 1e3;
    let counts = s.subscribers;
    let (most_topic, most) = counts.max();
    let (fewest_topic, fewest) = counts.min();
    let subscribers = format_args!(
        "{most} (most, {}), {fewest} (fewest, {}), {} listening to the cycle events",
        most_topic.suffix(),
        fewest_topic.suffix(),
        counts.cycle_listeners
    );
    if c.window_read_failures > 0 || c.window_implausible > 0 {
        warn!(
            arm,
            rate_hz = c.window_cycles,
            missed_reads = c.window_read_failures,
            missed_reads_total = c.read_failures,
            implausible = c.window_implausible,
            implausible_total = c.implausible,
            "samples published as invalid in the last second"
        );
    }
    // Displacements only from valid cycles of this window: a second without any prints none.
    // (This runs in the housekeeping thread, so formatting here costs the loop nothing.)
    let (tip_mm, tip_max_mm) = match c.window_last_displacement_m {
        Some(last) => (
            format!("{:.3}", last * 1e3),
            format!("{:.3}", c.window_max_displacement_m * 1e3),
        ),
        None => ("n/a (no valid sample)".to_owned(), "n/a".to_owned()),
    };
    info!(
        arm,
        rate_hz = c.window_cycles,
        valid = c.window_valid,
        cycle_p99_us = format_args!("{p99_us:.1}"),
        cycle_max_us = format_args!("{max_us:.1}"),
        missed_reads = c.window_read_failures,
        implausible = c.window_implausible,
        tip_displacement_mm = %tip_mm,
        tip_displacement_max_mm = %tip_max_mm,
        subscribers = %subscribers,
        "summary"
    );
}
