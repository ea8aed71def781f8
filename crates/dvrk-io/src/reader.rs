//! [`ArmReader`]: one call per cycle turns the boards' registers into an [`ArmSample`].
//!
//! Access modes (reference §8):
//! Every mode decodes the potentiometers too, from the ADC quadlet's bits 31–16 that each mode
//! reads anyway (reference §2.3): [`ArmReader::pots`].
//!
//! - [`AccessMode::Shared`] (default on real hardware, beside the dVRK console): only quadlet
//!   reads of the board status (register 0), per-channel ADC (ch<<4 | 0) and encoder position
//!   (ch<<4 | 5), which neither take a new sample nor reset the board timestamp the console
//!   uses for velocity. Never a block read of address 0, never a write. Velocity is the finite
//!   difference of positions over the caller's `t_ns`.
//! - [`AccessMode::Exclusive`] (simulator, bench setups where nothing else reads the boards):
//!   one block read of address 0 per board per cycle, or with
//!   [`ArmReader::with_broadcast_query`] one broadcast query plus one hub read (§3.4; the query
//!   is a register write, so the port must allow it).

use serde::{Deserialize, Serialize};

use crate::convert::{
    ActuatorState, ArmSample, IoConfig, MAX_BOARDS, NUM_JOINTS, SharedRaw, VelocitySource,
    decode_blocks, decode_shared,
};
use crate::port::{Port, PortError, reg};
use crate::wire::{BlockLayout, BoardKind, FeedbackBlock, HubLayout, HubView, WireError};

/// Quadlets of one shared-mode cycle: each board's status, each actuator's encoder position
/// and ADC.
const SHARED_QUADLETS: usize = MAX_BOARDS + 2 * NUM_JOINTS;
/// Largest feedback block (DQLA, 60 quadlets, reference §2.1).
const BLOCK_CAP: usize = 60 * 4;
/// Hub memory for [`MAX_BOARDS`] boards: Σ(Nq + 1) + 1 quadlets (reference §3.4).
const HUB_CAP: usize = MAX_BOARDS * (BLOCK_CAP + 4) + 4;

/// Channel register of an axis (channel = axis + 1, reference §1.2).
const fn channel_reg(axis: u8, offset: u16) -> u16 {
    ((axis as u16 + 1) << 4) | offset
}
/// ADC register offset (reference §1.2 channel registers).
const ADC_OFFSET: u16 = 0;
/// Encoder-position register offset (reference §1.2 channel registers).
const ENCODER_POSITION_OFFSET: u16 = 5;

/// How the reader may touch the boards.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AccessMode {
    /// Quadlet reads of per-channel registers and status only (safe beside the dVRK console).
    #[default]
    Shared,
    /// One block read of address 0 per board per cycle (or broadcast query + hub read).
    Exclusive,
}

/// Why a read failed. `Copy`, numbers only.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("board {board}: {error}")]
    Wire { board: u8, error: WireError },
}

/// Per-reader counters for the binary's 1 Hz summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReaderCounters {
    pub reads: u64,
    pub failed_reads: u64,
    pub quadlet_reads: u64,
    pub block_reads: u64,
    pub hub_reads: u64,
}

/// Reads one arm per call. Everything is allocated in [`ArmReader::new`]; `read` allocates,
/// locks and logs nothing.
pub struct ArmReader<P: Port> {
    port: P,
    cfg: IoConfig,
    mode: AccessMode,
    broadcast: bool,
    layouts: [Option<BlockLayout>; MAX_BOARDS],
    hub: Option<HubLayout>,
    blocks: [[u8; BLOCK_CAP]; MAX_BOARDS],
    hub_buf: [u8; HUB_CAP],
    prev: Option<(u64, [f64; NUM_JOINTS])>,
    last: ActuatorState,
    counters: ReaderCounters,
    /// Shared mode: the host clock read when the port's batch completed; None: the time given
    /// to [`ArmReader::read`].
    completion_clock: Option<fn() -> u64>,
}

impl<P: Port> ArmReader<P> {
    /// A reader of the arm `cfg` describes. When the config names a firmware version, the
    /// feedback-block layouts are fixed here; otherwise exclusive mode reads each board's
    /// hardware and firmware version at its first read.
    pub fn new(port: P, cfg: IoConfig, mode: AccessMode) -> Self {
        let mut layouts = [None; MAX_BOARDS];
        if let Some(fw) = cfg.firmware_version()
            && let Ok(l) = BlockLayout::new(fw, cfg.board_kind())
        {
            for slot in layouts.iter_mut().take(cfg.board_ids().len()) {
                *slot = Some(l);
            }
        }
        Self {
            port,
            cfg,
            mode,
            broadcast: false,
            layouts,
            hub: None,
            blocks: [[0; BLOCK_CAP]; MAX_BOARDS],
            hub_buf: [0; HUB_CAP],
            prev: None,
            last: ActuatorState::default(),
            counters: ReaderCounters::default(),
            completion_clock: None,
        }
    }

    /// Shared mode only: time each sample (its `t_ns`, and the interval of its software
    /// velocity) by `clock` read when the port's batch of quadlet reads has completed, instead of
    /// by the time given to [`ArmReader::read`]. The boards latch each register when they
    /// answer, so a read that waited (a register asked again, the host preempted before its
    /// request) has its values from late in that wait: timed from the call, one cycle's
    /// velocity would come out too small and the next one's too large. `clock` must be the
    /// clock of the times given to `read` (never earlier than them). Exclusive mode times its
    /// velocities by the boards' own timestamps and does not need it.
    pub fn with_completion_clock(mut self, clock: fn() -> u64) -> Self {
        self.completion_clock = Some(clock);
        self
    }
    /// Exclusive mode only: use one broadcast query plus one hub read per cycle instead of one
    /// block read per board. The port must allow the query (a register write).
    pub fn with_broadcast_query(mut self, on: bool) -> Self {
        self.broadcast = on;
        self
    }
    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }
    pub fn into_port(self) -> P {
        self.port
    }
    pub fn config(&self) -> &IoConfig {
        &self.cfg
    }
    /// The conversion in use, to change the instrument's coupling between reads (the mounted
    /// instrument changed).
    pub fn config_mut(&mut self) -> &mut IoConfig {
        &mut self.cfg
    }
    pub fn mode(&self) -> AccessMode {
        self.mode
    }
    pub fn counters(&self) -> ReaderCounters {
        self.counters
    }
    /// Feedback-block layouts in use (exclusive mode), by board slot.
    pub fn layouts(&self) -> [Option<BlockLayout>; MAX_BOARDS] {
        self.layouts
    }
    /// Actuator-space values of the last read.
    pub fn last_actuators(&self) -> &ActuatorState {
        &self.last
    }
    /// Potentiometer positions of the last read, actuator space (rad or m; NaN for an
    /// actuator without pot calibration), for the pot/encoder check
    /// ([`crate::plausibility::SampleCheck::check`]). None when the io file calibrates no pot.
    pub fn pots(&self) -> Option<&[f64; NUM_JOINTS]> {
        self.cfg
            .has_potentiometers()
            .then_some(&self.last.pot_position)
    }
    /// [`ActuatorState::pot_minus_encoder`] of the last read; None when the io file calibrates
    /// no pot.
    pub fn pot_minus_encoder(&self) -> Option<[f64; NUM_JOINTS]> {
        self.cfg
            .has_potentiometers()
            .then(|| self.last.pot_minus_encoder())
    }

    /// Reads all boards of the arm and converts. On failure `out` still carries `t_ns`,
    /// `valid = false` and the health flags that explain why, and the first error is returned.
    pub fn read(&mut self, t_ns: u64, out: &mut ArmSample) -> Result<(), ReadError> {
        self.counters.reads += 1;
        let r = match self.mode {
            AccessMode::Shared => self.read_shared(t_ns, out),
            AccessMode::Exclusive if self.broadcast => self.read_hub(t_ns, out),
            AccessMode::Exclusive => self.read_blocks(t_ns, out),
        };
        if r.is_err() || !out.valid {
            self.counters.failed_reads += 1;
            out.valid = false;
        }
        r
    }

    fn read_shared(&mut self, t_ns: u64, out: &mut ArmSample) -> Result<(), ReadError> {
        // One batch: every board's status, then each actuator's encoder position and ADC. The
        // port may keep several of them outstanding at once (Port::read_quadlets), so a lost
        // datagram is asked again while the others are answered.
        let mut reqs = [(0u8, 0u16); SHARED_QUADLETS];
        let mut vals = [None; SHARED_QUADLETS];
        let boards = self.cfg.board_ids();
        let n_boards = boards.len().min(MAX_BOARDS);
        for (r, &board) in reqs.iter_mut().zip(boards.iter()) {
            *r = (board, reg::STATUS);
        }
        let mut n = n_boards;
        for a in self.cfg.actuators().iter() {
            if let Some([enc, adc]) = reqs.get_mut(n..n + 2) {
                *enc = (a.board_id, channel_reg(a.axis, ENCODER_POSITION_OFFSET));
                *adc = (a.board_id, channel_reg(a.axis, ADC_OFFSET));
                n += 2;
            }
        }
        self.counters.quadlet_reads += n as u64;
        let mut first_err: Option<ReadError> = self
            .port
            .read_quadlets(&reqs[..n], &mut vals[..n])
            .err()
            .map(ReadError::from);
        let t_ns = self
            .completion_clock
            .map_or(t_ns, |clock| clock().max(t_ns));
        // A port that leaves a register unread must say why; if it did not, the cycle is a
        // timeout of that register (an invalid sample always carries its reason).
        if first_err.is_none()
            && let Some(&(board, addr)) = reqs[..n]
                .iter()
                .zip(&vals[..n])
                .find(|(_, v)| v.is_none())
                .map(|(r, _)| r)
        {
            first_err = Some(ReadError::from(crate::port::PortError::Timeout {
                board,
                addr,
            }));
        }
        let mut raw = SharedRaw::default();
        raw.status[..n_boards].copy_from_slice(&vals[..n_boards]);
        for (i, a) in self.cfg.actuators().iter().enumerate() {
            let slot = a.board_slot as usize;
            if raw.status.get(slot).copied().flatten().is_none() {
                // Its board's status was not read: the actuator is not decoded.
                continue;
            }
            let k = n_boards + 2 * i;
            match (
                vals.get(k).copied().flatten(),
                vals.get(k + 1).copied().flatten(),
            ) {
                (Some(enc), Some(adc)) => {
                    raw.encoder_position[i] = Some(enc);
                    raw.adc[i] = Some(adc);
                }
                _ => {
                    // Not read in time: the board's status says "not read" for this cycle.
                    if let Some(s) = raw.status.get_mut(slot) {
                        *s = None;
                    }
                }
            }
        }
        let mut st = decode_shared(&self.cfg, &raw, t_ns, out);
        if out.valid {
            if let Some((t_prev, p_prev)) = self.prev
                && t_ns > t_prev
            {
                let dt = (t_ns - t_prev) as f64 * 1e-9;
                for i in 0..NUM_JOINTS {
                    st.velocity[i] = (st.position[i] - p_prev[i]) / dt;
                }
            }
            out.velocity = self.cfg.actuator_to_joint_position(&st.velocity);
            self.prev = Some((t_ns, st.position));
        } else {
            self.prev = None;
        }
        self.last = st;
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Reads hardware and firmware version of the board in `slot` and fixes its layout.
    fn ensure_layout(&mut self, slot: usize) -> Result<BlockLayout, ReadError> {
        if let Some(Some(l)) = self.layouts.get(slot) {
            return Ok(*l);
        }
        let board = self.cfg.board_ids().get(slot).copied().unwrap_or(0);
        self.counters.quadlet_reads += 2;
        let hw = self.port.read_quadlet(board, reg::HARDWARE_VERSION)?;
        let kind =
            BoardKind::from_hardware_version(hw).map_err(|_| PortError::UnknownHardware {
                board,
                hardware: hw,
            })?;
        if kind != self.cfg.board_kind() {
            return Err(PortError::HardwareMismatch {
                board,
                expected: self.cfg.board_kind(),
                got: kind,
            }
            .into());
        }
        let fw = self.port.read_quadlet(board, reg::FIRMWARE_VERSION)?;
        let l = BlockLayout::new(fw, kind).map_err(|_| PortError::UnsupportedFirmware {
            board,
            firmware: fw,
        })?;
        if let Some(s) = self.layouts.get_mut(slot) {
            *s = Some(l);
        }
        Ok(l)
    }

    fn finish_exclusive(
        &mut self,
        t_ns: u64,
        mut st: ActuatorState,
        out: &mut ArmSample,
        first_err: Option<ReadError>,
    ) -> Result<(), ReadError> {
        // Software velocity (reference §5.1): change of position over the board's own
        // sample interval, which in exclusive mode is the time since our previous read.
        let soft = self
            .cfg
            .actuators()
            .iter()
            .any(|a| a.velocity_source == VelocitySource::Software);
        if soft
            && out.valid
            && let Some((_, p_prev)) = self.prev
        {
            {
                for (i, a) in self.cfg.actuators().iter().enumerate() {
                    if a.velocity_source != VelocitySource::Software {
                        continue;
                    }
                    let dt = crate::wire::Timestamp(out.board_timestamp[a.board_slot as usize])
                        .elapsed_s();
                    st.velocity[i] = (st.position[i] - p_prev[i]) / dt;
                }
                out.velocity = self.cfg.actuator_to_joint_position(&st.velocity);
            }
        }
        self.prev = if out.valid {
            Some((t_ns, st.position))
        } else {
            None
        };
        self.last = st;
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    fn read_blocks(&mut self, t_ns: u64, out: &mut ArmSample) -> Result<(), ReadError> {
        let mut first_err: Option<ReadError> = None;
        let mut ok = [false; MAX_BOARDS];
        let n_boards = self.cfg.board_ids().len();
        for (slot, okay) in ok.iter_mut().enumerate().take(n_boards) {
            let lay = match self.ensure_layout(slot) {
                Ok(l) => l,
                Err(e) => {
                    first_err.get_or_insert(e);
                    continue;
                }
            };
            let board = self.cfg.board_ids().get(slot).copied().unwrap_or(0);
            let Some(buf) = self
                .blocks
                .get_mut(slot)
                .and_then(|b| b.get_mut(..lay.len_bytes()))
            else {
                continue;
            };
            self.counters.block_reads += 1;
            match self.port.read_block(board, 0, buf) {
                Ok(()) => *okay = true,
                Err(e) => {
                    first_err.get_or_insert(e.into());
                }
            }
        }
        let mut views: [Option<FeedbackBlock<&[u8]>>; MAX_BOARDS] = [None; MAX_BOARDS];
        for (slot, v) in views.iter_mut().enumerate() {
            if let (true, Some(Some(l)), Some(b)) =
                (ok[slot], self.layouts.get(slot), self.blocks.get(slot))
            {
                *v = FeedbackBlock::new_checked(&b[..], *l).ok();
            }
        }
        let st = decode_blocks(&self.cfg, &views, t_ns, out);
        self.finish_exclusive(t_ns, st, out, first_err)
    }

    fn read_hub(&mut self, t_ns: u64, out: &mut ArmSample) -> Result<(), ReadError> {
        let mut first_err: Option<ReadError> = None;
        if self.hub.is_none() {
            let n = self.cfg.board_ids().len();
            let mut pairs: [Option<(u8, BlockLayout)>; MAX_BOARDS] = [None; MAX_BOARDS];
            for slot in 0..n {
                match self.ensure_layout(slot) {
                    Ok(l) => pairs[slot] = self.cfg.board_ids().get(slot).map(|&b| (b, l)),
                    Err(e) => {
                        first_err.get_or_insert(e);
                    }
                }
            }
            if first_err.is_none() {
                // The hub stores boards in ascending id order (reference §3.4).
                pairs.sort_unstable_by_key(|p| p.map_or(u8::MAX, |(b, _)| b));
                let hub = HubLayout::from_boards(pairs.iter().flatten().copied())
                    .map_err(|error| ReadError::Wire { board: 0, error })?;
                self.hub = Some(hub);
            }
        }
        let mut views: [Option<FeedbackBlock<&[u8]>>; MAX_BOARDS] = [None; MAX_BOARDS];
        if let Some(hub) = self.hub {
            self.counters.hub_reads += 1;
            let len = hub.len_bytes();
            let r = match self.hub_buf.get_mut(..len) {
                Some(buf) => self
                    .port
                    .broadcast_query_hub_read(hub.board_mask(), buf)
                    .map_err(ReadError::from),
                None => Err(ReadError::Wire {
                    board: 0,
                    error: WireError::BufferTooSmall {
                        got: HUB_CAP,
                        need: len,
                    },
                }),
            };
            match r {
                Ok(()) => {
                    if let Ok(view) = HubView::new_checked(&self.hub_buf[..], hub) {
                        for i in 0..hub.num_boards() {
                            let Some(id) = hub.board_id(i) else { continue };
                            let Some(slot) = self.cfg.board_slot(id) else {
                                continue;
                            };
                            match view.block_of(i) {
                                Ok(b) if b.status().raw != 0 => {
                                    if let Some(v) = views.get_mut(slot) {
                                        *v = Some(b);
                                    }
                                }
                                Ok(_) => {
                                    first_err.get_or_insert(ReadError::Wire {
                                        board: id,
                                        error: WireError::Truncated { got: 0, need: 4 },
                                    });
                                }
                                Err(error) => {
                                    first_err.get_or_insert(ReadError::Wire { board: id, error });
                                }
                            }
                        }
                    }
                }
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        let st = decode_blocks(&self.cfg, &views, t_ns, out);
        self.finish_exclusive(t_ns, st, out, first_err)
    }
}
