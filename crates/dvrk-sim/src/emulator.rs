//! Emulator of the two QLA boards of a Classic PSM1 (board ids 6 and 7, firmware Rev 9; FPGA V2
//! bridging Ethernet to FireWire, or FPGA V3 Ethernet-only as the scenario's `ethernet` field
//! says), driven by the physics.
//!
//! [`Emulator::handle`] takes one host datagram (2-byte control word + FireWire request, reference
//! dvrk-board-protocol.md §3.1) and writes the FPGA's reply (FireWire response + 8 bytes of extra
//! data), built with dvrk-io's wire emitters, so both ends share one implementation of the format.
//!
//! What it answers:
//! - quadlet reads of the board registers (status, PHY, watchdog, hardware version "QLA1",
//!   temperature, digital I/O, firmware version 9, IP, Ethernet status, git description) and of
//!   the per-channel registers (ADC, DAC, encoder preload/position/period, QTR1/QTR5, running
//!   counter, motor config/status), of the query register and of hub memory (§1.2);
//! - block reads of the feedback block at address 0: **each takes a new sample and resets the
//!   board timestamp**, as the FPGA does (§2.3, §8); block reads of hub memory (0x1000) after a
//!   broadcast query (0x1800 write, §3.4); in Ethernet-only mode the query itself is answered
//!   with the hub data, unasked, as the Rev 9 V3 hub does;
//! - quadlet and block writes: control/status, watchdog period, IP, PHY request, DAC/amp enable,
//!   encoder preload, the Rev 8+ command block (single board or broadcast). Writes get no reply
//!   over Ethernet.
//! - broadcast requests (node 0x3F): writes go to both boards; reads are answered by the hub
//!   board (board 6, the one "directly connected"), as in the discovery sequence (§3.3, §9).
//!
//! Node numbers equal board ids (as in Rev 9 Ethernet-only mode). Requests to other nodes get no
//! reply. Malformed datagrams (short, bad tcode, bad header or data CRC, wrong destination bus)
//! get no reply and are counted; a forwarded unicast request whose bus generation does not match
//! gets the 8-byte "packet dropped" reply (§3.1). Nothing here panics on any input.
//!
//! Time: the caller owns the clock. [`Emulator::advance_to`] steps the physics at the scenario's
//! fixed `dt_s` up to the given host time; board timestamps count 49.152 MHz ticks of that same
//! host time.

use dvrk_io::wire::block::{
    ENCODER_MIDRANGE, SYSCLK_HZ, hardware_version as hardware, motor_status_bits as motor_status,
    status_bits as status,
};
use dvrk_io::wire::eth::extra_flags;
use dvrk_io::wire::firewire::{BROADCAST_NODE, LOCAL_BUS, MAX_BLOCK_BYTES, node_id};
use dvrk_io::wire::hub::{HUB_ADDRESS, QUERY_ADDRESS};
use dvrk_io::wire::{
    Adc, BlockLayout, BoardKind, EncoderPeriod, EncoderPosition, EthReply, EthRequest, ExtraData,
    FeedbackBlock, HubHeader, HubLayout, HubView, Quarter, RequestKind, RequestRepr, ResponseKind,
    ResponseRepr, Tcode, Temperature, Timestamp,
};

use dvrk_io::IoConfig;

use crate::SimError;
use crate::measure::{ActuatorScales, Sensors};
use crate::physics::{NUM_JOINTS, SimPsm};
use crate::scenario::{EthernetMode, MotionDriver, Scenario};

/// Firmware version the boards report (register 7).
pub const FIRMWARE_VERSION: u32 = 9;
/// Board ids of a PSM1 (reference §1.1).
pub const BOARD_IDS: [u8; 2] = [6, 7];
/// Axes per QLA.
pub const QLA_AXES: usize = 4;
/// Largest reply datagram: block response header 20 + data + CRC 4 + extra 8.
pub const MAX_REPLY_BYTES: usize = 20 + MAX_BLOCK_BYTES + 4 + 8;
/// The FireWire bus generation the emulated boards report in their extra data.
pub const BUS_GENERATION: u8 = 1;
/// Ethernet-status register (12): bit 31 set = FPGA V2 (100 Mb Ethernet, FireWire bridge).
pub const ETH_STATUS_V2: u32 = 0x8000_0000;
/// Ethernet-status register (12): bits 31:30 = 01 = FPGA V3 (Zynq, Ethernet-only capable).
pub const ETH_STATUS_V3: u32 = 0x4000_0000;
/// Git-description register (15): an arbitrary fixed value.
pub const GIT_DESCRIPTION: u32 = 0x5349_4D39; // "SIM9"
/// Longest stretch of simulated time one `advance_to` call catches up; beyond it the simulation
/// pauses (the physics clock is shifted), so a stalled caller does not cause a long stall here.
pub const MAX_CATCH_UP_NS: u64 = 10_000_000_000;

/// Where an actuator sits and how its bits convert.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorSlot {
    pub board_id: u8,
    pub axis: u8,
    pub scales: ActuatorScales,
}

/// Inverse of the IO configuration: joint space to actuator bits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorMap {
    /// Actuators 1-7 (index 0..7).
    pub actuators: [ActuatorSlot; NUM_JOINTS],
    /// Joint positions 4-7 to actuator positions 4-7 (inverse of `ActuatorToJointPosition`).
    pub joint_to_actuator_position: [[f64; 4]; 4],
    /// Joint efforts 4-7 to actuator efforts 4-7 (transpose of `ActuatorToJointPosition`).
    pub joint_to_actuator_effort: [[f64; 4]; 4],
}

const IDENTITY4: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

impl ActuatorMap {
    /// Classic PSM1 per reference §5.2: actuators 1-4 on board 6 axes 0-3, 5-7 on board 7 axes
    /// 0-2; identity wrist coupling.
    pub fn classic_psm() -> Self {
        let mut actuators = [ActuatorSlot {
            board_id: 6,
            axis: 0,
            scales: ActuatorScales::classic_psm(0),
        }; NUM_JOINTS];
        for (i, a) in actuators.iter_mut().enumerate() {
            let (board_id, axis) = if i < 4 {
                (6, i as u8)
            } else {
                (7, (i - 4) as u8)
            };
            *a = ActuatorSlot {
                board_id,
                axis,
                scales: ActuatorScales::classic_psm(i),
            };
        }
        Self {
            actuators,
            joint_to_actuator_position: IDENTITY4,
            joint_to_actuator_effort: IDENTITY4,
        }
    }

    /// The inverse of an arm's IO configuration: placement, encoder, current and effort scales of
    /// every actuator, the wrist coupling. Potentiometers missing from the config (their gains
    /// are per-robot calibration values) get the defaults of [`ActuatorScales::classic_psm`].
    pub fn from_io_config(io: &IoConfig) -> Result<Self, SimError> {
        if io.board_kind() != BoardKind::Qla {
            return Err(SimError::IoConfig {
                field: "hardware_version",
                value: io.board_kind().name().to_string(),
                reason: "the emulator has QLA1 boards",
            });
        }
        if let Some(fw) = io.firmware_version()
            && fw != FIRMWARE_VERSION
        {
            return Err(SimError::IoConfig {
                field: "firmware_version",
                value: fw.to_string(),
                reason: "the emulated boards run firmware Rev 9",
            });
        }
        let mut map = Self::classic_psm();
        for (i, a) in io.actuators().iter().enumerate() {
            let mut scales = ActuatorScales::classic_psm(i);
            scales.encoder_position_per_count = a.bits_to_position.scale;
            scales.encoder_offset = a.bits_to_position.offset;
            scales.current_amps_per_bit = a.bits_to_current.scale;
            scales.current_offset_amps = a.bits_to_current.offset;
            scales.amps_per_effort = a.effort_to_current.scale;
            scales.effort_offset_amps = a.effort_to_current.offset;
            if let Some(p) = a.potentiometer {
                scales.pot_volts_per_bit = p.bits_to_voltage.scale;
                scales.pot_volts_offset = p.bits_to_voltage.offset;
                scales.pot_position_per_volt = p.voltage_to_position.scale;
                scales.pot_offset = p.voltage_to_position.offset;
            }
            map.actuators[i] = ActuatorSlot {
                board_id: a.board_id,
                axis: a.axis,
                scales,
            };
        }
        map.with_coupling(io.coupling())
    }

    /// Same map with the wrist coupling `actuator_to_joint_position` (rows = joints 4-7).
    pub fn with_coupling(
        mut self,
        actuator_to_joint_position: [[f64; 4]; 4],
    ) -> Result<Self, SimError> {
        let inv = invert4(&actuator_to_joint_position).ok_or(SimError::Coupling)?;
        let mut t = [[0.0; 4]; 4];
        for (r, row) in t.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = actuator_to_joint_position[c][r];
            }
        }
        self.joint_to_actuator_position = inv;
        self.joint_to_actuator_effort = t;
        Ok(self)
    }

    /// Actuator positions, velocities and efforts for joint-space values.
    pub fn to_actuators(
        &self,
        position: &[f64; NUM_JOINTS],
        velocity: &[f64; NUM_JOINTS],
        effort: &[f64; NUM_JOINTS],
    ) -> ([f64; NUM_JOINTS], [f64; NUM_JOINTS], [f64; NUM_JOINTS]) {
        let (mut p, mut v, mut e) = (*position, *velocity, *effort);
        for r in 0..4 {
            let (mut sp, mut sv, mut se) = (0.0, 0.0, 0.0);
            for c in 0..4 {
                sp += self.joint_to_actuator_position[r][c] * position[3 + c];
                sv += self.joint_to_actuator_position[r][c] * velocity[3 + c];
                se += self.joint_to_actuator_effort[r][c] * effort[3 + c];
            }
            p[3 + r] = sp;
            v[3 + r] = sv;
            e[3 + r] = se;
        }
        (p, v, e)
    }
}

/// Inverse of a 4x4 matrix by Gauss-Jordan with partial pivoting; `None` if singular.
fn invert4(m: &[[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let mut a = *m;
    let mut inv = IDENTITY4;
    for col in 0..4 {
        let mut piv = col;
        for r in col + 1..4 {
            if a[r][col].abs() > a[piv][col].abs() {
                piv = r;
            }
        }
        if a[piv][col].abs() <= 1e-12 || !a[piv][col].is_finite() {
            return None;
        }
        a.swap(col, piv);
        inv.swap(col, piv);
        let d = a[col][col];
        for c in 0..4 {
            a[col][c] /= d;
            inv[col][c] /= d;
        }
        for r in 0..4 {
            if r != col {
                let f = a[r][col];
                for c in 0..4 {
                    a[r][c] -= f * a[col][c];
                    inv[r][c] -= f * inv[col][c];
                }
            }
        }
    }
    Some(inv)
}

/// What the emulator has seen and done, for tests and the binary's summaries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EmulatorCounters {
    /// Datagrams passed to `handle`.
    pub requests: u64,
    /// Replies written (including 8-byte dropped replies).
    pub replies: u64,
    /// Every write received (quadlet or block, unicast or broadcast, any address).
    pub writes: u64,
    pub quadlet_writes: u64,
    pub block_writes: u64,
    /// Quadlet reads answered.
    pub quadlet_reads: u64,
    /// Block reads of address 0 (each triggers a sample).
    pub block_reads_address0: u64,
    /// Block reads of hub memory (0x1000).
    pub hub_reads: u64,
    /// Broadcast queries (writes to 0x1800).
    pub broadcast_queries: u64,
    /// Hub data sent unasked after a query (Ethernet-only mode, reference §3.4).
    pub unsolicited_hub_replies: u64,
    /// Samples taken by the boards (block reads of address 0 and queries, per board).
    pub samples: u64,
    /// Datagrams that could not be parsed or failed a check (no reply).
    pub malformed: u64,
    /// Requests to a node that does not exist (no reply).
    pub unknown_node: u64,
    /// Forwarded requests with a stale bus generation (8-byte dropped reply).
    pub generation_mismatch: u64,
    /// Physics steps taken.
    pub physics_steps: u64,
    /// Times `advance_to` hit [`MAX_CATCH_UP_NS`] and paused the simulation.
    pub time_skips: u64,
}

#[derive(Clone, Debug)]
struct Board {
    id: u8,
    /// Actuator index (0..7) on each axis.
    axis_actuator: [Option<usize>; QLA_AXES],
    ip: u32,
    watchdog_period: u32,
    last_write_ns: u64,
    watchdog_timeout: bool,
    power: bool,
    relay: bool,
    amp_enable: [bool; QLA_AXES],
    dac: [u16; QLA_AXES],
    dout: u32,
    /// Added to the physical counts (encoder preload).
    preload_offset: [i32; QLA_AXES],
    last_sample_ns: u64,
    block: [u8; 128],
}

impl Board {
    fn new(id: u8, map: &ActuatorMap) -> Self {
        let mut axis_actuator = [None; QLA_AXES];
        for (i, a) in map.actuators.iter().enumerate() {
            if a.board_id == id && usize::from(a.axis) < QLA_AXES {
                axis_actuator[usize::from(a.axis)] = Some(i);
            }
        }
        let amp_enable = [
            axis_actuator[0].is_some(),
            axis_actuator[1].is_some(),
            axis_actuator[2].is_some(),
            axis_actuator[3].is_some(),
        ];
        Self {
            id,
            axis_actuator,
            ip: 0xFFFF_FFFF,
            watchdog_period: 0,
            last_write_ns: 0,
            watchdog_timeout: false,
            power: true,
            relay: true,
            amp_enable,
            dac: [0x8000; QLA_AXES],
            dout: 0,
            preload_offset: [0; QLA_AXES],
            last_sample_ns: 0,
            block: [0; 128],
        }
    }

    fn amp_on(&self, axis: usize) -> bool {
        self.power && !self.watchdog_timeout && self.amp_enable.get(axis).copied().unwrap_or(false)
    }

    fn status(&self) -> u32 {
        let mut s = u32::from(self.id & 0x0F) << status::BOARD_ID_SHIFT;
        if self.watchdog_timeout {
            s |= status::WATCHDOG_TIMEOUT;
        }
        if self.power {
            s |= status::MV_GOOD | status::POWER_ENABLE | status::QLA_SAFETY_VOLTAGE;
        }
        if self.relay {
            s |= status::RELAY_COMMANDED | status::RELAY_FEEDBACK;
        }
        for axis in 0..QLA_AXES {
            if self.amp_on(axis) {
                s |= 1 << (status::QLA_AMP_ON_SHIFT + axis as u32);
                s |= 1 << axis;
            }
        }
        s
    }

    fn motor_status(&self, axis: usize) -> u32 {
        let mut m = motor_status::QLA_CURRENT_CONTROL
            | u32::from(self.dac.get(axis).copied().unwrap_or(0x8000));
        if self.amp_on(axis) {
            m |= motor_status::AMP_ON;
        }
        if self.amp_enable.get(axis).copied().unwrap_or(false) {
            m |= motor_status::ENABLE_REQUESTED;
        }
        m
    }

    /// A host write: refreshes the watchdog (reference §4).
    fn touch(&mut self, now_ns: u64) {
        self.last_write_ns = now_ns;
    }

    /// Control/status write bits (reference §4): power, relay, amp enable masks.
    fn write_control(&mut self, v: u32) {
        if v & (1 << 19) != 0 {
            self.power = v & (1 << 18) != 0;
            if self.power {
                self.watchdog_timeout = false;
            }
        }
        if v & (1 << 17) != 0 {
            self.relay = v & (1 << 16) != 0;
        }
        for axis in 0..QLA_AXES {
            if v & (1 << (8 + axis)) != 0 {
                self.amp_enable[axis] = v & (1 << axis) != 0 && self.axis_actuator[axis].is_some();
                if self.amp_enable[axis] {
                    self.watchdog_timeout = false;
                }
            }
        }
    }

    /// A motor quadlet of the command block or a DAC register write: bits 31 valid, 29 enable
    /// mask, 28 enable, 15-0 DAC.
    fn write_motor(&mut self, axis: usize, v: u32, require_valid: bool) {
        if axis >= QLA_AXES || (require_valid && v & (1 << 31) == 0) {
            return;
        }
        self.dac[axis] = v as u16;
        if v & (1 << 29) != 0 {
            self.amp_enable[axis] = v & (1 << 28) != 0 && self.axis_actuator[axis].is_some();
            if self.amp_enable[axis] {
                self.watchdog_timeout = false;
            }
        }
    }
}

/// The two emulated boards and the physics behind them.
#[derive(Clone, Debug)]
pub struct Emulator {
    psm: SimPsm,
    driver: MotionDriver,
    sensors: Sensors,
    map: ActuatorMap,
    layout: BlockLayout,
    hub_layout: HubLayout,
    ethernet: EthernetMode,
    boards: [Board; 2],
    hub: [u8; 512],
    hub_sequence: u16,
    epoch_ns: Option<u64>,
    now_ns: u64,
    sim_ns: u64,
    dt_ns: u64,
    dt_s: f64,
    counters: EmulatorCounters,
    scratch: [u8; MAX_BLOCK_BYTES],
}

impl Emulator {
    /// Boards 6 and 7 driven by the scenario's arm, converting SI to bits through the inverse of
    /// `io` (normally config/io/psm-classic.toml).
    pub fn new(scenario: &Scenario, io: &IoConfig) -> Result<Self, SimError> {
        Self::with_map(scenario, ActuatorMap::from_io_config(io)?)
    }

    /// Boards 6 and 7 driven by the scenario's arm, with the bit conversions of `map`.
    pub fn with_map(scenario: &Scenario, map: ActuatorMap) -> Result<Self, SimError> {
        for (i, a) in map.actuators.iter().enumerate() {
            if !BOARD_IDS.contains(&a.board_id) || usize::from(a.axis) >= QLA_AXES {
                return Err(SimError::ActuatorPlacement {
                    actuator: i + 1,
                    board_id: a.board_id,
                    axis: a.axis,
                });
            }
        }
        let layout = BlockLayout::new(FIRMWARE_VERSION, BoardKind::Qla).map_err(SimError::Wire)?;
        let hub_layout = HubLayout::new(&[(BOARD_IDS[0], layout), (BOARD_IDS[1], layout)])
            .map_err(SimError::Wire)?;
        let dt_ns = (scenario.dt_s * 1e9).round().max(1.0) as u64;
        let mut emu = Self {
            psm: scenario.build_psm(),
            driver: scenario.motion_driver(),
            sensors: Sensors::new(scenario.noise, scenario.seed),
            map,
            layout,
            hub_layout,
            ethernet: scenario.ethernet,
            boards: [
                Board::new(BOARD_IDS[0], &map),
                Board::new(BOARD_IDS[1], &map),
            ],
            hub: [0; 512],
            hub_sequence: 0,
            epoch_ns: None,
            now_ns: 0,
            sim_ns: 0,
            dt_ns,
            dt_s: dt_ns as f64 * 1e-9,
            counters: EmulatorCounters::default(),
            scratch: [0; MAX_BLOCK_BYTES],
        };
        emu.sync_amps();
        Ok(emu)
    }

    /// The arm physics.
    pub fn psm(&self) -> &SimPsm {
        &self.psm
    }

    /// The arm physics, to command setpoints or change the environment.
    pub fn psm_mut(&mut self) -> &mut SimPsm {
        &mut self.psm
    }

    /// Replace the scenario's motion (e.g. [`MotionDriver::HOLD`] before commanding setpoints by
    /// hand in a calibration procedure).
    pub fn set_motion(&mut self, driver: MotionDriver) {
        self.driver = driver;
    }

    pub fn counters(&self) -> EmulatorCounters {
        self.counters
    }

    /// FPGA V2 bridge (default) or V3 Ethernet-only, as the scenario chose.
    pub fn ethernet_mode(&self) -> EthernetMode {
        self.ethernet
    }

    /// Present the boards as FPGA V2 bridge or V3 Ethernet-only from now on.
    pub fn set_ethernet_mode(&mut self, mode: EthernetMode) {
        self.ethernet = mode;
    }

    pub fn actuator_map(&self) -> &ActuatorMap {
        &self.map
    }

    /// Simulated time since the first `advance_to`, ns (a multiple of the physics step).
    pub fn sim_time_ns(&self) -> u64 {
        self.sim_ns
    }

    /// The latest host time given to `advance_to`.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Physics step, s.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    /// Step the physics at its fixed step up to host time `t_ns` (CLOCK_MONOTONIC or any
    /// monotonic clock the caller owns). The first call only sets the epoch. Earlier times are
    /// ignored. No allocation.
    pub fn advance_to(&mut self, t_ns: u64) {
        let epoch = match self.epoch_ns {
            Some(e) => e,
            None => {
                self.epoch_ns = Some(t_ns);
                self.now_ns = t_ns;
                for b in &mut self.boards {
                    b.last_sample_ns = t_ns;
                    b.last_write_ns = t_ns;
                }
                return;
            }
        };
        if t_ns <= self.now_ns {
            return;
        }
        self.now_ns = t_ns;
        let mut target = t_ns - epoch;
        if target > self.sim_ns + MAX_CATCH_UP_NS {
            let skip = target - self.sim_ns - MAX_CATCH_UP_NS;
            self.epoch_ns = Some(epoch + skip);
            target -= skip;
            self.counters.time_skips += 1;
        }
        while self.sim_ns + self.dt_ns <= target {
            self.check_watchdogs(epoch + self.sim_ns);
            self.driver.apply(self.sim_ns as f64 * 1e-9, &mut self.psm);
            self.psm.step(self.dt_s);
            self.sim_ns += self.dt_ns;
            self.counters.physics_steps += 1;
        }
        self.check_watchdogs(t_ns);
    }

    fn check_watchdogs(&mut self, now_ns: u64) {
        let mut changed = false;
        for b in &mut self.boards {
            if b.watchdog_period != 0 && !b.watchdog_timeout {
                // Units of 256 / 49.152 MHz = 5.208 µs (reference §1.2, register 3).
                let period_ns =
                    u64::from(b.watchdog_period & 0xFFFF) * 256 * 1_000_000_000 / 49_152_000;
                if now_ns.saturating_sub(b.last_write_ns) > period_ns {
                    b.watchdog_timeout = true;
                    changed = true;
                }
            }
        }
        if changed {
            self.sync_amps();
        }
    }

    /// The arm's motors turn only while the amplifiers of joints 1-3 are on.
    fn sync_amps(&mut self) {
        let mut on = true;
        for a in &self.map.actuators[..3] {
            let Some(b) = self.boards.iter().find(|b| b.id == a.board_id) else {
                on = false;
                continue;
            };
            on &= b.amp_on(usize::from(a.axis));
        }
        if on != self.psm.amps_enabled() {
            self.psm.set_amps_enabled(on);
        }
    }

    fn board_index_for_node(&self, node: u8) -> Option<usize> {
        self.boards.iter().position(|b| b.id == node)
    }

    /// Handle one host datagram; write the reply into `reply` and return its length, or `None`
    /// when the FPGA would not answer (writes, malformed requests, unknown nodes). Never panics;
    /// no allocation.
    pub fn handle(&mut self, request: &[u8], reply: &mut [u8]) -> Option<usize> {
        self.counters.requests += 1;
        let n = self.handle_inner(request, reply);
        if n.is_some() {
            self.counters.replies += 1;
        }
        n
    }

    fn handle_inner(&mut self, request: &[u8], reply: &mut [u8]) -> Option<usize> {
        let Ok(req) = EthRequest::parse(request) else {
            self.counters.malformed += 1;
            return None;
        };
        let p = req.packet;
        let repr = match RequestRepr::parse(&p) {
            Ok(r) => r,
            Err(_) => {
                self.counters.malformed += 1;
                return None;
            }
        };
        if p.header_crc() != p.computed_header_crc()
            || (p.tcode() == Tcode::BlockWrite && p.data_crc() != p.computed_data_crc())
            || repr.dest_id & LOCAL_BUS != LOCAL_BUS
        {
            self.counters.malformed += 1;
            return None;
        }
        let node = p.dest_node();
        let broadcast = node == BROADCAST_NODE;
        let noforward = req.control.noforward();
        let hub = 0usize;
        let target = if broadcast {
            Some(hub)
        } else {
            self.board_index_for_node(node)
        };
        let Some(target) = target else {
            self.counters.unknown_node += 1;
            return None;
        };
        let mut extra = ExtraData {
            bus_generation: BUS_GENERATION,
            ..Default::default()
        };
        if noforward {
            extra.flags |= extra_flags::NOFORWARD;
        }
        // A unicast request forwarded over the (virtual) FireWire bus must carry the current bus
        // generation; the hub drops it otherwise (reference §3.1, §7).
        if !broadcast && !noforward && target != hub && req.control.bus_generation != BUS_GENERATION
        {
            self.counters.generation_mismatch += 1;
            extra.flags |= extra_flags::PACKET_DROPPED;
            return EthReply::emit_dropped(reply, &extra).ok();
        }
        let addr = (repr.offset & 0xFFFF) as u16;
        let now = self.now_ns;
        match repr.kind {
            RequestKind::QuadletRead => {
                self.counters.quadlet_reads += 1;
                let data = self.read_register(target, addr);
                let resp = ResponseRepr {
                    dest_id: repr.src_id,
                    src_id: node_id(self.boards[target].id),
                    label: repr.label,
                    rcode: 0,
                    kind: ResponseKind::Quadlet { data },
                };
                EthReply::emit(reply, &resp, &[], &extra).ok()
            }
            RequestKind::BlockRead { len } => {
                let len_usize = usize::from(len);
                if len_usize > MAX_BLOCK_BYTES || len_usize % 4 != 0 {
                    self.counters.malformed += 1;
                    return None;
                }
                self.fill_block(target, addr, len_usize);
                let resp = ResponseRepr {
                    dest_id: repr.src_id,
                    src_id: node_id(self.boards[target].id),
                    label: repr.label,
                    rcode: 0,
                    kind: ResponseKind::Block { len },
                };
                let payload = self.scratch.get(..len_usize)?;
                EthReply::emit(reply, &resp, payload, &extra).ok()
            }
            RequestKind::QuadletWrite { data } => {
                self.counters.writes += 1;
                self.counters.quadlet_writes += 1;
                if broadcast {
                    for i in 0..self.boards.len() {
                        self.write_register(i, addr, data, now);
                    }
                    if addr == QUERY_ADDRESS {
                        self.broadcast_query(data, now);
                        if self.ethernet == EthernetMode::EthernetOnly {
                            // Rev 9 Ethernet-only: the hub sends the data unasked, as a block
                            // response carrying the query's label (reference §3.4).
                            self.sync_amps();
                            return self.unsolicited_hub_reply(&repr, &extra, reply);
                        }
                    }
                } else {
                    self.write_register(target, addr, data, now);
                    if addr == QUERY_ADDRESS {
                        self.broadcast_query(data, now);
                    }
                }
                self.sync_amps();
                None
            }
            RequestKind::BlockWrite { .. } => {
                self.counters.writes += 1;
                self.counters.block_writes += 1;
                let payload = p.payload();
                if addr == 0 {
                    self.command_block(if broadcast { None } else { Some(target) }, payload, now);
                } else {
                    let targets = if broadcast {
                        0..self.boards.len()
                    } else {
                        target..target + 1
                    };
                    for i in targets {
                        self.boards[i].touch(now);
                    }
                }
                self.sync_amps();
                None
            }
        }
    }

    /// Current raw values of one actuator, computed from the physics now (no sampling latch):
    /// ADC, encoder position, period, QTR1, QTR5, running counter. The ADC (and its noise draw)
    /// only when `want_adc`.
    fn actuator_raw(
        &mut self,
        board: usize,
        axis: usize,
        want_adc: bool,
    ) -> (u32, u32, u32, u32, u32, u32) {
        let b = &self.boards[board];
        let Some(act) = b.axis_actuator.get(axis).copied().flatten() else {
            // Unused axis: encoder at mid-range, zero current, pot at 0 V, no motion.
            let idle = EncoderPeriod::from_velocity(0.0, SYSCLK_HZ).0;
            return (
                Adc::new(0, 0x8000).0,
                EncoderPosition::from_counts(b.preload_offset[axis.min(QLA_AXES - 1)]).0,
                idle,
                idle,
                idle,
                0x8000_0000,
            );
        };
        let js = self.psm.joint_state();
        let (pos, vel, eff) = self
            .map
            .to_actuators(&js.position, &js.velocity, &js.effort);
        let s = self.map.actuators[act].scales;
        let counts_f = (pos[act] - s.encoder_offset) / s.encoder_position_per_count;
        let counts = s
            .encoder_counts(pos[act])
            .wrapping_add(b.preload_offset[axis]);
        let overflow = i64::from(counts).abs() >= i64::from(ENCODER_MIDRANGE);
        let enc =
            EncoderPosition::from_counts(counts.clamp(-ENCODER_MIDRANGE, ENCODER_MIDRANGE - 1))
                .with_overflow(overflow);
        let v_counts = s.encoder_velocity_counts_per_s(vel[act]);
        let period = EncoderPeriod::from_velocity(v_counts, SYSCLK_HZ);
        // Quarter periods: a quarter of the full cycle each, same direction and overflow bits.
        let q_ticks = (period.ticks() / 4).max(1);
        let quarter = (period.0 & 0xC000_0000)
            | if period.overflow() {
                EncoderPeriod::TICKS_MASK
            } else {
                q_ticks
            };
        // Running counter: time since the last count edge (edges at half counts, as rounded).
        let running = if v_counts.abs() > 1e-9 && !period.overflow() {
            let frac = (counts_f + 0.5).rem_euclid(1.0);
            let since = if v_counts > 0.0 { frac } else { 1.0 - frac };
            let ticks = since / v_counts.abs() * SYSCLK_HZ;
            if ticks >= f64::from(0x7FFF_FFFFu32) {
                0x8000_0000 | 0x7FFF_FFFF
            } else {
                ticks as u32
            }
        } else {
            0x8000_0000 | 0x7FFF_FFFF
        };
        let effort = if b.amp_on(axis) { eff[act] } else { 0.0 };
        let adc = if want_adc {
            self.sensors.adc_quadlet(&s, pos[act], effort)
        } else {
            0
        };
        (adc, enc.0, period.0, quarter, quarter, running)
    }

    fn read_register(&mut self, board: usize, addr: u16) -> u32 {
        let space = addr >> 12;
        if space == 1 {
            if addr & 0x0800 != 0 {
                return if addr <= QUERY_ADDRESS + 3 {
                    u32::from(self.hub_sequence) << 16
                } else {
                    0
                };
            }
            let off = usize::from(addr - HUB_ADDRESS) * 4;
            return self
                .hub
                .get(off..off + 4)
                .map_or(0, |q| u32::from_be_bytes([q[0], q[1], q[2], q[3]]));
        }
        if space != 0 {
            return 0;
        }
        let ch = usize::from((addr >> 4) & 0xF);
        let reg = addr & 0xF;
        let b = &self.boards[board];
        if ch == 0 {
            return match reg {
                0 => b.status(),
                1 | 2 => 0,
                3 => b.watchdog_period,
                4 => hardware::QLA1,
                5 => Temperature::from_celsius(35.0, 34.5).0,
                6 => b.dout,
                7 => FIRMWARE_VERSION,
                10 => 0,
                11 => b.ip,
                12 => match self.ethernet {
                    EthernetMode::Bridge => ETH_STATUS_V2,
                    EthernetMode::EthernetOnly => ETH_STATUS_V3,
                },
                15 => GIT_DESCRIPTION,
                _ => 0,
            };
        }
        let axis = ch - 1;
        if axis >= QLA_AXES {
            return 0;
        }
        match reg {
            0 => self.actuator_raw(board, axis, true).0,
            1 => {
                let b = &self.boards[board];
                (u32::from(b.amp_enable[axis]) << 29) | u32::from(b.dac[axis])
            }
            4 => {
                let b = &self.boards[board];
                (b.preload_offset[axis].wrapping_add(ENCODER_MIDRANGE) as u32) & 0x00FF_FFFF
            }
            5 => self.actuator_raw(board, axis, false).1,
            6 => self.actuator_raw(board, axis, false).2,
            7 => self.actuator_raw(board, axis, false).3,
            9 => self.actuator_raw(board, axis, false).4,
            10 => self.actuator_raw(board, axis, false).5,
            11 => 0,
            12 => self.boards[board].motor_status(axis),
            _ => 0,
        }
    }

    fn write_register(&mut self, board: usize, addr: u16, data: u32, now: u64) {
        let physical_counts = |emu: &Self, axis: usize| -> i32 {
            emu.boards[board].axis_actuator[axis].map_or(0, |act| {
                let js = emu.psm.joint_state();
                let (pos, _, _) = emu.map.to_actuators(&js.position, &js.velocity, &js.effort);
                emu.map.actuators[act].scales.encoder_counts(pos[act])
            })
        };
        self.boards[board].touch(now);
        if addr >> 12 != 0 {
            return;
        }
        let ch = usize::from((addr >> 4) & 0xF);
        let reg = addr & 0xF;
        if ch == 0 {
            let b = &mut self.boards[board];
            match reg {
                0 => b.write_control(data),
                3 => b.watchdog_period = data,
                6 => b.dout = data,
                11 => b.ip = data,
                _ => {}
            }
            return;
        }
        let axis = ch - 1;
        if axis >= QLA_AXES {
            return;
        }
        match reg {
            1 => self.boards[board].write_motor(axis, data, false),
            4 => {
                let want = ((data & 0x00FF_FFFF) as i32) - ENCODER_MIDRANGE;
                let phys = physical_counts(self, axis);
                self.boards[board].preload_offset[axis] = want.wrapping_sub(phys);
            }
            _ => {}
        }
    }

    /// Rev 8+ command block(s): per board, header id<<8 | (M+2), M motor quadlets, control word.
    fn command_block(&mut self, target: Option<usize>, payload: &[u8], now: u64) {
        const WORDS: usize = QLA_AXES + 2;
        for i in 0..self.boards.len() {
            if target.is_none() || target == Some(i) {
                self.boards[i].touch(now);
            }
        }
        for chunk in payload.chunks_exact(WORDS * 4) {
            let q = |k: usize| {
                u32::from_be_bytes([
                    chunk[4 * k],
                    chunk[4 * k + 1],
                    chunk[4 * k + 2],
                    chunk[4 * k + 3],
                ])
            };
            let header = q(0);
            let id = ((header >> 8) & 0xF) as u8;
            if (header & 0xFF) as usize != WORDS {
                continue;
            }
            let Some(i) = self.board_index_for_node(id) else {
                continue;
            };
            if target.is_some_and(|t| t != i) {
                continue;
            }
            for axis in 0..QLA_AXES {
                self.boards[i].write_motor(axis, q(1 + axis), true);
            }
            self.boards[i].write_control(q(WORDS - 1));
            if target.is_some() {
                break;
            }
        }
    }

    /// Take a new sample of `board` into its block buffer (resets its timestamp).
    fn sample(&mut self, board: usize) {
        let now = self.now_ns;
        let elapsed_ns = now.saturating_sub(self.boards[board].last_sample_ns);
        let ticks = (elapsed_ns as f64 * SYSCLK_HZ * 1e-9).round() as u64;
        self.boards[board].last_sample_ns = now;
        self.counters.samples += 1;
        let mut raw = [(0u32, 0u32, 0u32, 0u32, 0u32, 0u32); QLA_AXES];
        for (axis, r) in raw.iter_mut().enumerate() {
            *r = self.actuator_raw(board, axis, true);
        }
        let status = self.boards[board].status();
        let motor: [u32; QLA_AXES] = core::array::from_fn(|a| self.boards[board].motor_status(a));
        let layout = self.layout;
        let Ok(mut blk) = FeedbackBlock::new_checked(&mut self.boards[board].block[..], layout)
        else {
            return;
        };
        blk.clear();
        blk.set_timestamp(Timestamp::from_elapsed_ticks(ticks.max(1)));
        blk.set_status(status);
        blk.set_digital_io(dvrk_io::wire::DigitalIo(0));
        blk.set_temperature(Temperature::from_celsius(35.0, 34.5));
        for (axis, r) in raw.iter().enumerate() {
            let _ = blk.set_adc(axis, Adc(r.0));
            let _ = blk.set_encoder_position(axis, EncoderPosition(r.1));
            let _ = blk.set_encoder_period(axis, EncoderPeriod(r.2));
            let _ = blk.set_qtr1(axis, Quarter(r.3));
            let _ = blk.set_qtr5(axis, Quarter(r.4));
            let _ = blk.set_running(axis, r.5);
            let _ = blk.set_motor_status(axis, motor[axis]);
        }
    }

    /// Broadcast query `seq<<16 | board_mask`: every board in the mask samples into hub memory.
    fn broadcast_query(&mut self, data: u32, _now: u64) {
        self.counters.broadcast_queries += 1;
        let mask = data as u16;
        let seq = (data >> 16) as u16;
        self.hub_sequence = seq;
        let nq = self.layout.len_quadlets() as u8;
        for i in 0..self.boards.len() {
            let id = self.boards[i].id;
            let slot = i;
            if mask & (1 << id) == 0 {
                continue;
            }
            self.sample(i);
            let block = self.boards[i].block;
            let lay = self.hub_layout;
            let Some(mem) = self.hub.get_mut(..lay.len_bytes()) else {
                continue;
            };
            let Ok(mut view) = HubView::new_checked(mem, lay) else {
                continue;
            };
            let _ = view.set_header(slot, HubHeader::new(nq, seq, false, 0));
            if let Ok(b) = view.block_mut(slot) {
                let dst = b.into_inner();
                let n = dst.len().min(block.len());
                dst[..n].copy_from_slice(&block[..n]);
            }
        }
    }

    /// The hub's block response to a broadcast query in Ethernet-only mode: hub memory for
    /// every board plus the timing quadlet, from the hub board's node, with the query's label.
    fn unsolicited_hub_reply(
        &mut self,
        query: &RequestRepr,
        extra: &ExtraData,
        reply: &mut [u8],
    ) -> Option<usize> {
        let n = self.hub_layout.len_bytes().min(self.hub.len());
        let len = u16::try_from(n).ok()?;
        self.counters.unsolicited_hub_replies += 1;
        self.counters.hub_reads += 1;
        let resp = ResponseRepr {
            dest_id: query.src_id,
            src_id: node_id(self.boards[0].id),
            label: query.label,
            rcode: 0,
            kind: ResponseKind::Block { len },
        };
        EthReply::emit(reply, &resp, self.hub.get(..n)?, extra).ok()
    }

    /// Fill `self.scratch[..len]` for a block read of `addr` on `board`.
    fn fill_block(&mut self, board: usize, addr: u16, len: usize) {
        let len = len.min(self.scratch.len());
        if addr == 0 {
            self.counters.block_reads_address0 += 1;
            self.sample(board);
            let n = self.layout.len_bytes().min(len);
            let block = self.boards[board].block;
            self.scratch[..n].copy_from_slice(&block[..n]);
            self.scratch[n..len].fill(0);
            return;
        }
        if addr == HUB_ADDRESS {
            self.counters.hub_reads += 1;
            let n = self.hub_layout.len_bytes().min(len).min(self.hub.len());
            self.scratch[..n].copy_from_slice(&self.hub[..n]);
            self.scratch[n..len].fill(0);
            return;
        }
        // Other addresses: consecutive quadlet registers (space 0) or zeros.
        for k in 0..len / 4 {
            let v = if addr >> 12 == 0 {
                self.read_register(board, addr.wrapping_add(k as u16))
            } else {
                0
            };
            self.scratch[4 * k..4 * k + 4].copy_from_slice(&v.to_be_bytes());
        }
    }
}

#[cfg(test)]
mod ethernet_mode_tests {
    //! FPGA V2 bridge vs V3 Ethernet-only: the Ethernet-status register and the broadcast read.
    use super::*;
    use dvrk_io::wire::ControlWord;

    const IO: &str = include_str!("../../../config/io/psm-classic.toml");
    const IDLE: &str = include_str!("../../../config/sim/idle.toml");

    fn emulator(mode: EthernetMode) -> Emulator {
        let io = IoConfig::from_params(toml::from_str(IO).unwrap()).unwrap();
        let mut scenario = Scenario::from_params(toml::from_str(IDLE).unwrap()).unwrap();
        scenario.ethernet = mode;
        let mut e = Emulator::new(&scenario, &io).unwrap();
        e.advance_to(1_000_000);
        e.advance_to(2_000_000);
        e
    }

    fn request(node: u8, label: u8, addr: u16, kind: RequestKind) -> Vec<u8> {
        let req = RequestRepr::host(node, label, u64::from(addr), kind);
        let mut buf = vec![0u8; 64];
        let n = EthRequest::emit(&mut buf, ControlWord::new(true, 0), &req, &[]).unwrap();
        buf.truncate(n);
        buf
    }

    fn quadlet(e: &mut Emulator, addr: u16) -> u32 {
        let mut reply = [0u8; MAX_REPLY_BYTES];
        let n = e
            .handle(&request(6, 1, addr, RequestKind::QuadletRead), &mut reply)
            .unwrap();
        EthReply::parse(&reply[..n])
            .unwrap()
            .packet
            .unwrap()
            .quadlet_data()
    }

    #[test]
    fn ethernet_status_says_v2_or_v3() {
        assert_eq!(
            quadlet(&mut emulator(EthernetMode::Bridge), 12),
            ETH_STATUS_V2
        );
        let mut e = emulator(EthernetMode::EthernetOnly);
        assert_eq!(quadlet(&mut e, 12), ETH_STATUS_V3);
        assert_eq!(
            quadlet(&mut e, 12) >> 30,
            0b01,
            "bits 31:30 = 01 is V3 (reference §1.1)"
        );
        assert_eq!(quadlet(&mut e, 7), 9);
    }

    #[test]
    fn bridge_query_gets_no_reply_ethernet_only_query_gets_the_hub_data() {
        let q = RequestKind::QuadletWrite {
            data: (0x0123 << 16) | 0x00C0,
        };
        let mut reply = [0u8; MAX_REPLY_BYTES];
        let mut b = emulator(EthernetMode::Bridge);
        assert_eq!(
            b.handle(&request(0x3F, 17, QUERY_ADDRESS, q), &mut reply),
            None
        );
        assert_eq!(b.counters().unsolicited_hub_replies, 0);

        let mut e = emulator(EthernetMode::EthernetOnly);
        let n = e
            .handle(&request(0x3F, 17, QUERY_ADDRESS, q), &mut reply)
            .expect("the Ethernet-only hub answers the query with its data");
        let r = EthReply::parse(&reply[..n]).unwrap();
        let p = r.packet.unwrap();
        assert_eq!(p.tcode(), Tcode::BlockResponse);
        assert_eq!(p.label(), 17, "the query's label");
        assert_eq!(p.src_node(), 6, "from the hub board");
        // Two QLA Rev 9 blocks of 32 quadlets, a header each, and the timing quadlet: 67.
        assert_eq!(usize::from(p.data_length()), 67 * 4);
        let lay = BlockLayout::new(9, BoardKind::Qla).unwrap();
        let hl = HubLayout::new(&[(6, lay), (7, lay)]).unwrap();
        let hub = HubView::new_checked(p.payload(), hl).unwrap();
        for (i, id) in [6u8, 7].into_iter().enumerate() {
            let h = hub.header(i).unwrap();
            assert_eq!(h.sequence_lsb(), 0x23);
            assert!(!h.sequence_mismatch());
            assert_eq!(hub.block(i).unwrap().status().board_id(), id);
        }
        assert_eq!(e.counters().unsolicited_hub_replies, 1);
    }
}
