//! Emulator of the two QLA boards of a Classic PSM1 (board ids 6 and 7, firmware Rev 9; FPGA V2
//! bridging Ethernet to FireWire, or FPGA V3 Ethernet-only as the scenario's `ethernet` field
//! says), driven by the physics; or, built by [`Emulator::chain`], of one chain of boards for
//! several arms (PSM1 6-7, PSM2 8-9, PSM3 10-11), each arm with its own physics and scenario,
//! answering on one port as one FireWire chain behind one hub does.
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
//! - broadcast requests (node 0x3F): writes go to every board; reads are answered by the hub
//!   board (the lowest id, board 6 for PSM1, the one "directly connected"), as in the discovery
//!   sequence (§3.3, §9). The hub memory holds, after a query, the blocks of the boards of its
//!   mask in ascending board id (§3.4), and any board returns it.
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
use dvrk_io::wire::hub::{HUB_ADDRESS, MAX_HUB_BOARDS, QUERY_ADDRESS};
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
    /// Index of the arm (in [`Emulator::chain`]'s order) whose actuators this board drives.
    arm: usize,
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
    fn new(id: u8, arm: usize, map: &ActuatorMap) -> Self {
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
            arm,
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

/// One arm of the chain: the physics and measurement models behind its two boards.
#[derive(Clone, Debug)]
struct Arm {
    psm: SimPsm,
    driver: MotionDriver,
    sensors: Sensors,
    map: ActuatorMap,
    boards: [u8; 2],
    /// Simulated time of this arm since the first `advance_to`, ns (a multiple of `dt_ns`).
    sim_ns: u64,
    dt_ns: u64,
    dt_s: f64,
}

/// One arm of a chain given to [`Emulator::chain`]: its scenario (physics, motion, noise, seed),
/// the bit conversions of its boards, and its two board ids (the dVRK numbers Classic PSM1
/// boards 6-7, PSM2 8-9, PSM3 10-11; [`CLASSIC_PSM_BOARDS`]).
#[derive(Clone, Copy, Debug)]
pub struct ArmSpec<'a> {
    pub scenario: &'a Scenario,
    pub map: ActuatorMap,
    pub boards: [u8; 2],
}

/// The dVRK's board ids of the Classic PSMs (reference §1.1): actuators 1-4 on the first board,
/// 5-7 on the second.
pub const CLASSIC_PSM_BOARDS: [(&str, [u8; 2]); 3] =
    [("PSM1", [6, 7]), ("PSM2", [8, 9]), ("PSM3", [10, 11])];

/// The board ids of the Classic PSM named `name` (`PSM1`, `PSM2`, `PSM3`, as the console names
/// them), or `None`.
pub fn classic_psm_boards(name: &str) -> Option<[u8; 2]> {
    CLASSIC_PSM_BOARDS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, b)| *b)
}

/// Hub memory: one header and one Rev 9 QLA block (32 quadlets) per board of a full chain (16
/// boards), plus the timing quadlet.
const HUB_MEMORY_BYTES: usize = MAX_HUB_BOARDS * (4 + 128) + 4;

/// The emulated boards and the physics behind them: one chain of boards on one Ethernet port,
/// the boards of one arm ([`Emulator::new`]) or of several ([`Emulator::chain`]), each arm with
/// its own physics and scenario.
#[derive(Clone, Debug)]
pub struct Emulator {
    /// At least one; `arms[0]` is the arm of the single-arm accessors (`psm`, `set_motion`, ...).
    arms: Vec<Arm>,
    layout: BlockLayout,
    ethernet: EthernetMode,
    /// Ascending board id; `boards[0]` is the hub (the board the host is connected to).
    boards: Vec<Board>,
    hub: [u8; HUB_MEMORY_BYTES],
    /// Bytes of hub data of the last broadcast query (every board before the first).
    hub_len: usize,
    hub_sequence: u16,
    epoch_ns: Option<u64>,
    now_ns: u64,
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
        Self::chain(&[ArmSpec {
            scenario,
            map,
            boards: BOARD_IDS,
        }])
    }

    /// One chain of boards for several arms, answering on one Ethernet port as the real
    /// hardware does: every board answers its own requests (per-board unicast, node = board
    /// id), broadcast writes reach every board, the broadcast query samples every board of its
    /// mask into the hub memory, which any board returns, and the lowest board id is the hub
    /// (it answers the broadcast reads of discovery and, in Ethernet-only mode, sends the hub
    /// data after a query). Each arm has its own physics, motion, noise and seed; the hub's
    /// (lowest-board) arm's scenario sets the Ethernet mode of the chain.
    ///
    /// Errors: no arm, a board id above 15 or on two arms, an arm whose two boards are one, an
    /// actuator not on its arm's boards (axes 0-3).
    pub fn chain(arms: &[ArmSpec<'_>]) -> Result<Self, SimError> {
        if arms.is_empty() {
            return Err(SimError::Chain {
                board: None,
                reason: "no arm to emulate",
            });
        }
        let mut boards: Vec<Board> = Vec::with_capacity(2 * arms.len());
        for (k, spec) in arms.iter().enumerate() {
            if spec.boards[0] == spec.boards[1] {
                return Err(SimError::Chain {
                    board: Some(spec.boards[0]),
                    reason: "an arm has two boards with distinct ids",
                });
            }
            for &id in &spec.boards {
                if usize::from(id) >= MAX_HUB_BOARDS {
                    return Err(SimError::Chain {
                        board: Some(id),
                        reason: "board ids are 0-15",
                    });
                }
                if boards.iter().any(|b| b.id == id) {
                    return Err(SimError::Chain {
                        board: Some(id),
                        reason: "the board is on two arms",
                    });
                }
                boards.push(Board::new(id, k, &spec.map));
            }
            for (i, a) in spec.map.actuators.iter().enumerate() {
                if !spec.boards.contains(&a.board_id) || usize::from(a.axis) >= QLA_AXES {
                    return Err(SimError::ActuatorPlacement {
                        actuator: i + 1,
                        board_id: a.board_id,
                        axis: a.axis,
                        boards: spec.boards,
                    });
                }
            }
        }
        boards.sort_by_key(|b| b.id);
        let layout = BlockLayout::new(FIRMWARE_VERSION, BoardKind::Qla).map_err(SimError::Wire)?;
        let hub_len = HubLayout::from_boards(boards.iter().map(|b| (b.id, layout)))
            .map_err(SimError::Wire)?
            .len_bytes();
        let ethernet = arms[boards[0].arm].scenario.ethernet;
        let arms: Vec<Arm> = arms
            .iter()
            .map(|spec| {
                let sc = spec.scenario;
                let dt_ns = (sc.dt_s * 1e9).round().max(1.0) as u64;
                Arm {
                    psm: sc.build_psm(),
                    driver: sc.motion_driver(),
                    sensors: Sensors::new(sc.noise, sc.seed),
                    map: spec.map,
                    boards: spec.boards,
                    sim_ns: 0,
                    dt_ns,
                    dt_s: dt_ns as f64 * 1e-9,
                }
            })
            .collect();
        let mut emu = Self {
            arms,
            layout,
            ethernet,
            boards,
            hub: [0; HUB_MEMORY_BYTES],
            hub_len,
            hub_sequence: 0,
            epoch_ns: None,
            now_ns: 0,
            counters: EmulatorCounters::default(),
            scratch: [0; MAX_BLOCK_BYTES],
        };
        emu.sync_amps();
        Ok(emu)
    }

    /// The arm physics (of the first arm of a chain).
    pub fn psm(&self) -> &SimPsm {
        &self.arms[0].psm
    }

    /// The arm physics, to command setpoints or change the environment (first arm of a chain).
    pub fn psm_mut(&mut self) -> &mut SimPsm {
        &mut self.arms[0].psm
    }

    /// Replace the scenario's motion (e.g. [`MotionDriver::HOLD`] before commanding setpoints by
    /// hand in a calibration procedure); first arm of a chain.
    pub fn set_motion(&mut self, driver: MotionDriver) {
        self.arms[0].driver = driver;
    }

    /// Number of arms (1 unless built by [`Emulator::chain`]).
    pub fn arm_count(&self) -> usize {
        self.arms.len()
    }

    /// Physics of arm `k` (in [`Emulator::chain`]'s order).
    pub fn arm_psm(&self, k: usize) -> Option<&SimPsm> {
        self.arms.get(k).map(|a| &a.psm)
    }

    /// Physics of arm `k`, to command setpoints or change the environment.
    pub fn arm_psm_mut(&mut self, k: usize) -> Option<&mut SimPsm> {
        self.arms.get_mut(k).map(|a| &mut a.psm)
    }

    /// Replace the motion of arm `k`; `false` when there is no such arm.
    pub fn set_arm_motion(&mut self, k: usize, driver: MotionDriver) -> bool {
        self.arms.get_mut(k).map(|a| a.driver = driver).is_some()
    }

    /// Board ids of arm `k`.
    pub fn arm_boards(&self, k: usize) -> Option<[u8; 2]> {
        self.arms.get(k).map(|a| a.boards)
    }

    /// Bit conversions of arm `k`.
    pub fn arm_actuator_map(&self, k: usize) -> Option<&ActuatorMap> {
        self.arms.get(k).map(|a| &a.map)
    }

    /// Board ids of the whole chain, ascending (the first is the hub).
    pub fn board_ids(&self) -> impl Iterator<Item = u8> + '_ {
        self.boards.iter().map(|b| b.id)
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

    /// Bit conversions (of the first arm of a chain).
    pub fn actuator_map(&self) -> &ActuatorMap {
        &self.arms[0].map
    }

    /// Simulated time since the first `advance_to`, ns (a multiple of the physics step; of the
    /// first arm of a chain).
    pub fn sim_time_ns(&self) -> u64 {
        self.arms[0].sim_ns
    }

    /// The latest host time given to `advance_to`.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Physics step, s (of the first arm of a chain).
    pub fn dt_s(&self) -> f64 {
        self.arms[0].dt_s
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
        let behind = self.arms.iter().map(|a| a.sim_ns).min().unwrap_or(0);
        let mut epoch = epoch;
        if target > behind + MAX_CATCH_UP_NS {
            let skip = target - behind - MAX_CATCH_UP_NS;
            epoch += skip;
            self.epoch_ns = Some(epoch);
            target -= skip;
            self.counters.time_skips += 1;
        }
        for k in 0..self.arms.len() {
            while self.arms[k].sim_ns + self.arms[k].dt_ns <= target {
                self.check_watchdogs(Some(k), epoch + self.arms[k].sim_ns);
                let a = &mut self.arms[k];
                a.driver.apply(a.sim_ns as f64 * 1e-9, &mut a.psm);
                a.psm.step(a.dt_s);
                a.sim_ns += a.dt_ns;
                self.counters.physics_steps += 1;
            }
        }
        self.check_watchdogs(None, t_ns);
    }

    /// Watchdog timeouts at host time `now_ns` of the boards of arm `arm` (every board: `None`).
    fn check_watchdogs(&mut self, arm: Option<usize>, now_ns: u64) {
        let mut changed = false;
        for b in &mut self.boards {
            if arm.is_some_and(|k| k != b.arm) {
                continue;
            }
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

    /// An arm's motors turn only while the amplifiers of its joints 1-3 are on.
    fn sync_amps(&mut self) {
        for arm in &mut self.arms {
            let mut on = true;
            for a in &arm.map.actuators[..3] {
                let Some(b) = self.boards.iter().find(|b| b.id == a.board_id) else {
                    on = false;
                    continue;
                };
                on &= b.amp_on(usize::from(a.axis));
            }
            if on != arm.psm.amps_enabled() {
                arm.psm.set_amps_enabled(on);
            }
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
        let arm = &mut self.arms[b.arm];
        let js = arm.psm.joint_state();
        let (pos, vel, eff) = arm.map.to_actuators(&js.position, &js.velocity, &js.effort);
        let s = arm.map.actuators[act].scales;
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
            arm.sensors.adc_quadlet(&s, pos[act], effort)
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
            let b = &emu.boards[board];
            b.axis_actuator[axis].map_or(0, |act| {
                let arm = &emu.arms[b.arm];
                let js = arm.psm.joint_state();
                let (pos, _, _) = arm.map.to_actuators(&js.position, &js.velocity, &js.effort);
                arm.map.actuators[act].scales.encoder_counts(pos[act])
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

    /// Broadcast query `seq<<16 | board_mask`: every board of the chain in the mask samples
    /// into hub memory, in ascending board id (reference §3.4); bits of absent boards are
    /// ignored.
    fn broadcast_query(&mut self, data: u32, _now: u64) {
        self.counters.broadcast_queries += 1;
        let mask = data as u16;
        let seq = (data >> 16) as u16;
        self.hub_sequence = seq;
        let nq = self.layout.len_quadlets() as u8;
        let layout = self.layout;
        let in_mask = |b: &Board| mask & (1 << (b.id & 0x0F)) != 0;
        let Ok(lay) = HubLayout::from_boards(
            self.boards
                .iter()
                .filter(|b| in_mask(b))
                .map(|b| (b.id, layout)),
        ) else {
            return;
        };
        self.hub_len = lay.len_bytes().min(self.hub.len());
        let mut slot = 0;
        for i in 0..self.boards.len() {
            if !in_mask(&self.boards[i]) {
                continue;
            }
            self.sample(i);
            let block = self.boards[i].block;
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
            slot += 1;
        }
        // The timing quadlet (not modelled) ends the data.
        if let Some(t) = self
            .hub
            .get_mut(self.hub_len.saturating_sub(4)..self.hub_len)
        {
            t.fill(0);
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
        let n = self.hub_len.min(self.hub.len());
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
            let n = self.hub_len.min(len).min(self.hub.len());
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

#[cfg(test)]
mod chain_tests {
    //! Two arms on one chain (PSM1 boards 6-7, PSM2 boards 8-9): every board answers, the hub
    //! data carries every board of the query's mask, each arm follows its own scenario, and no
    //! datagram makes it panic.
    use super::*;
    use crate::rng::SimRng;
    use dvrk_io::wire::ControlWord;

    const IO: &str = include_str!("../../../config/io/psm-classic.toml");

    fn io(boards: [u8; 2]) -> IoConfig {
        let text = IO
            .replace("board_id = 6", &format!("board_id = {}", boards[0]))
            .replace("board_id = 7", &format!("board_id = {}", boards[1]));
        IoConfig::from_params(toml::from_str(&text).unwrap()).unwrap()
    }

    /// A noise-free arm holding `q` (so replies can be compared with the physics exactly).
    fn holding(q: [f64; 7], mode: &str) -> Scenario {
        let text = format!(
            r#"
seed = 3
dt_s = 0.0001
ethernet = "{mode}"
initial_position = {q:?}
[environment]
kind = "free"
[motion]
kind = "hold"
[noise]
current_noise_amps = 0.0
pot_noise_volts = 0.0
"#
        );
        Scenario::from_params(toml::from_str(&text).unwrap()).unwrap()
    }

    const Q1: [f64; 7] = [0.1, -0.2, 0.12, 0.3, 0.2, -0.1, 0.4];
    const Q2: [f64; 7] = [-0.3, 0.15, 0.08, -0.5, -0.2, 0.25, 0.6];

    fn two_arms(mode: &str) -> (Emulator, [IoConfig; 2]) {
        let (s1, s2) = (holding(Q1, mode), holding(Q2, mode));
        let ios = [io([6, 7]), io([8, 9])];
        let mut e = Emulator::chain(&[
            ArmSpec {
                scenario: &s1,
                map: ActuatorMap::from_io_config(&ios[0]).unwrap(),
                boards: [6, 7],
            },
            ArmSpec {
                scenario: &s2,
                map: ActuatorMap::from_io_config(&ios[1]).unwrap(),
                boards: [8, 9],
            },
        ])
        .unwrap();
        e.advance_to(1_000_000);
        e.advance_to(50_000_000);
        (e, ios)
    }

    fn request(node: u8, label: u8, addr: u16, kind: RequestKind, payload: &[u8]) -> Vec<u8> {
        let req = RequestRepr::host(node, label, u64::from(addr), kind);
        let mut buf = vec![0u8; 2100];
        let n = EthRequest::emit(
            &mut buf,
            ControlWord::new(false, BUS_GENERATION),
            &req,
            payload,
        )
        .unwrap();
        buf.truncate(n);
        buf
    }

    /// (source node, quadlet data or block payload) of the reply to `req`.
    fn ask(e: &mut Emulator, req: &[u8]) -> Option<(u8, u32, Vec<u8>)> {
        let mut reply = [0u8; MAX_REPLY_BYTES];
        let n = e.handle(req, &mut reply)?;
        let p = EthReply::parse(&reply[..n]).unwrap().packet.unwrap();
        let r = ResponseRepr::parse(&p).unwrap();
        Some(match r.kind {
            ResponseKind::Quadlet { data } => (p.src_node(), data, Vec::new()),
            ResponseKind::Block { .. } => (p.src_node(), 0, p.payload().to_vec()),
        })
    }

    fn lay() -> BlockLayout {
        BlockLayout::new(FIRMWARE_VERSION, BoardKind::Qla).unwrap()
    }

    /// Encoder counts of actuator `i` (0-based) of an arm holding `q`, through `io`.
    fn counts(io: &IoConfig, q: &[f64; 7], i: usize) -> i32 {
        io.actuators()[i].position_to_counts(io.joint_to_actuator_position(q)[i])
    }

    #[test]
    fn every_board_of_both_arms_answers_for_itself() {
        let (mut e, _) = two_arms("bridge");
        assert_eq!(e.arm_count(), 2);
        assert_eq!(e.board_ids().collect::<Vec<_>>(), [6, 7, 8, 9]);
        // Discovery's node scan: boards 6-9 answer, each with its own id; no other node does.
        let mut found = Vec::new();
        for node in 0..16u8 {
            let hw = ask(&mut e, &request(node, 1, 4, RequestKind::QuadletRead, &[]));
            if let Some((src, hw, _)) = hw {
                assert_eq!(src, node);
                assert_eq!(hw, hardware::QLA1);
                let (_, st, _) =
                    ask(&mut e, &request(node, 2, 0, RequestKind::QuadletRead, &[])).unwrap();
                assert_eq!((st >> 24) & 0xF, u32::from(node));
                found.push(node);
            }
        }
        assert_eq!(found, [6, 7, 8, 9]);
        assert_eq!(e.counters().unknown_node, 12);
        // Broadcast reads are answered by the hub, the lowest board.
        let (src, _, _) = ask(
            &mut e,
            &request(BROADCAST_NODE, 3, 0, RequestKind::QuadletRead, &[]),
        )
        .unwrap();
        assert_eq!(src, 6);
        // Block reads of address 0: each board its own block, with its id.
        for id in [6u8, 7, 8, 9] {
            let len = lay().len_bytes() as u16;
            let (src, _, data) = ask(
                &mut e,
                &request(id, 4, 0, RequestKind::BlockRead { len }, &[]),
            )
            .unwrap();
            assert_eq!(src, id);
            let b = FeedbackBlock::new_checked(&data[..], lay()).unwrap();
            assert_eq!(b.status().board_id(), id);
        }
        assert_eq!(e.counters().block_reads_address0, 4);
    }

    #[test]
    fn each_arm_encoders_follow_its_own_scenario() {
        let (mut e, ios) = two_arms("bridge");
        let mut seen = [[0i32; 7]; 2];
        for (k, (q, io)) in [(Q1, &ios[0]), (Q2, &ios[1])].into_iter().enumerate() {
            let js = e.arm_psm(k).unwrap().joint_state();
            for (i, a) in io.actuators().iter().enumerate() {
                // Per-channel quadlet read of the encoder position (address ch<<4 | 5).
                let addr = ((u16::from(a.axis) + 1) << 4) | 5;
                let (_, raw, _) = ask(
                    &mut e,
                    &request(a.board_id, 9, addr, RequestKind::QuadletRead, &[]),
                )
                .unwrap();
                let got = EncoderPosition(raw).counts();
                assert_eq!(got, counts(io, &js.position, i), "arm {k} actuator {i}");
                // Holding its own initial pose (within the controller's small error).
                assert!(
                    (got - counts(io, &q, i)).abs() <= 200,
                    "arm {k} actuator {i}"
                );
                seen[k][i] = got;
            }
        }
        assert_ne!(seen[0], seen[1], "the two arms read the same encoders");
        // A setpoint for arm 2 moves arm 2 only.
        let before1 = e.arm_psm(0).unwrap().joint_state().position;
        let mut sp = Q2;
        sp[0] += 0.2;
        e.set_arm_motion(1, MotionDriver::HOLD);
        e.arm_psm_mut(1).unwrap().set_setpoints(&sp);
        e.advance_to(1_050_000_000);
        // Arm 1 holds (to rounding: its shaft carries the distal weight, issue 20 item 3).
        let after1 = e.arm_psm(0).unwrap().joint_state().position;
        for (a, b) in after1.iter().zip(&before1) {
            assert!((a - b).abs() < 1e-9, "{after1:?} {before1:?}");
        }
        assert!((e.arm_psm(1).unwrap().joint_state().position[0] - sp[0]).abs() < 0.02);
    }

    fn hub_boards(data: &[u8], seq: u8) -> Vec<u8> {
        let mut ids = Vec::new();
        let mut off = 0;
        while let Some(h) = data.get(off..off + 4) {
            let h = HubHeader(u32::from_be_bytes([h[0], h[1], h[2], h[3]]));
            if h.size_quadlets() as usize != lay().len_quadlets() + 1 {
                break;
            }
            assert_eq!(h.sequence_lsb(), seq);
            let b = FeedbackBlock::new_checked(&data[off + 4..], lay()).unwrap();
            ids.push(b.status().board_id());
            off += 4 + lay().len_bytes();
        }
        assert_eq!(off + 4, data.len(), "the timing quadlet ends the data");
        ids
    }

    #[test]
    fn hub_data_carries_every_board_of_the_mask() {
        let (mut e, ios) = two_arms("bridge");
        let query = |seq: u32, mask: u32| RequestKind::QuadletWrite {
            data: (seq << 16) | mask,
        };
        let read = |len: usize| RequestKind::BlockRead { len: len as u16 };
        let full = 4 * (lay().len_bytes() + 4) + 4;
        // All four boards, read from the hub or from any board of the chain.
        assert!(
            ask(
                &mut e,
                &request(BROADCAST_NODE, 1, QUERY_ADDRESS, query(0x11, 0x3C0), &[])
            )
            .is_none()
        );
        for node in [6u8, 9] {
            let (src, _, data) =
                ask(&mut e, &request(node, 2, HUB_ADDRESS, read(full), &[])).unwrap();
            assert_eq!(src, node);
            assert_eq!(hub_boards(&data, 0x11), [6, 7, 8, 9]);
        }
        // The slots of PSM2 carry PSM2's encoders.
        let (_, _, data) = ask(&mut e, &request(6, 3, HUB_ADDRESS, read(full), &[])).unwrap();
        let hl = HubLayout::new(&[(6, lay()), (7, lay()), (8, lay()), (9, lay())]).unwrap();
        let hub = HubView::new_checked(&data[..], hl).unwrap();
        let js2 = e.arm_psm(1).unwrap().joint_state();
        let enc = hub.block(2).unwrap().encoder_position(0).unwrap().counts();
        assert_eq!(enc, counts(&ios[1], &js2.position, 0));
        // Only PSM2's boards: the hub data holds boards 8 and 9, first (ascending id).
        ask(
            &mut e,
            &request(BROADCAST_NODE, 4, QUERY_ADDRESS, query(0x12, 0x300), &[]),
        );
        let half = 2 * (lay().len_bytes() + 4) + 4;
        let (_, _, data) = ask(&mut e, &request(8, 5, HUB_ADDRESS, read(half), &[])).unwrap();
        assert_eq!(hub_boards(&data, 0x12), [8, 9]);
        // Bits of boards that are not on the chain are ignored.
        ask(
            &mut e,
            &request(BROADCAST_NODE, 6, QUERY_ADDRESS, query(0x13, 0xFFFF), &[]),
        );
        let (_, _, data) = ask(&mut e, &request(6, 7, HUB_ADDRESS, read(full), &[])).unwrap();
        assert_eq!(hub_boards(&data, 0x13), [6, 7, 8, 9]);
        assert_eq!(e.counters().broadcast_queries, 3);
    }

    #[test]
    fn ethernet_only_hub_sends_every_board_of_the_mask_unasked() {
        let (mut e, _) = two_arms("ethernet-only");
        let q = RequestKind::QuadletWrite {
            data: (0x21 << 16) | 0x3C0,
        };
        let (src, _, data) = ask(&mut e, &request(BROADCAST_NODE, 9, QUERY_ADDRESS, q, &[]))
            .expect("the Ethernet-only hub answers the query with its data");
        assert_eq!(src, 6, "from the hub");
        assert_eq!(hub_boards(&data, 0x21), [6, 7, 8, 9]);
        assert_eq!(e.counters().unsolicited_hub_replies, 1);
    }

    #[test]
    fn broadcast_command_reaches_every_board_and_watchdogs_are_per_arm() {
        let (mut e, _) = two_arms("bridge");
        // Watchdog of 30 ms on PSM2's boards only (quadlet writes of register 3).
        for id in [8u8, 9] {
            let w = RequestKind::QuadletWrite { data: 0x1680 };
            assert!(ask(&mut e, &request(id, 1, 3, w, &[])).is_none());
        }
        e.advance_to(200_000_000);
        assert!(e.arm_psm(0).unwrap().amps_enabled());
        assert!(!e.arm_psm(1).unwrap().amps_enabled(), "PSM2's watchdog");
        // A broadcast command block for the four boards (zero current, enable all, power on)
        // clears the timeout and sets every DAC.
        let mut cmd = Vec::new();
        for id in [6u32, 7, 8, 9] {
            cmd.extend_from_slice(&((id << 8) | 6).to_be_bytes());
            for _ in 0..4 {
                cmd.extend_from_slice(&(0xB000_8123u32).to_be_bytes());
            }
            cmd.extend_from_slice(&(0x000C_0000u32).to_be_bytes());
        }
        let len = cmd.len() as u16;
        let b = request(BROADCAST_NODE, 2, 0, RequestKind::BlockWrite { len }, &cmd);
        assert!(ask(&mut e, &b).is_none());
        assert!(e.arm_psm(1).unwrap().amps_enabled());
        for id in [6u8, 7, 8, 9] {
            let (_, dac, _) =
                ask(&mut e, &request(id, 3, 0x11, RequestKind::QuadletRead, &[])).unwrap();
            assert_eq!(dac & 0xFFFF, 0x8123, "board {id}");
        }
    }

    #[test]
    fn bad_datagrams_to_any_board_do_not_panic() {
        let (mut e, _) = two_arms("ethernet-only");
        let mut rng = SimRng::new(21);
        let mut reply = [0u8; MAX_REPLY_BYTES];
        let mut sent = 0u64;
        for id in [6u8, 7, 8, 9, BROADCAST_NODE] {
            let len = lay().len_bytes() as u16;
            let goods = [
                request(id, 1, 0, RequestKind::BlockRead { len }, &[]),
                request(
                    id,
                    2,
                    HUB_ADDRESS,
                    RequestKind::BlockRead { len: 2020 },
                    &[],
                ),
                request(id, 3, 0x15, RequestKind::QuadletRead, &[]),
                request(
                    id,
                    4,
                    QUERY_ADDRESS,
                    RequestKind::QuadletWrite { data: 0xFFFF_FFFF },
                    &[],
                ),
                request(id, 5, 0, RequestKind::BlockWrite { len: 8 }, &[0xFF; 8]),
            ];
            for good in &goods {
                // Every truncation, then random byte flips (CRCs recomputed or not).
                for n in 0..good.len() {
                    e.handle(&good[..n], &mut reply);
                    sent += 1;
                }
                for _ in 0..300 {
                    let mut d = good.clone();
                    let k = (rng.next_u64() % d.len() as u64) as usize;
                    d[k] ^= (rng.next_u64() as u8) | 1;
                    e.handle(&d, &mut reply);
                    sent += 1;
                }
            }
        }
        // Random garbage of every length up to 64 bytes.
        for n in 0..64 {
            let d: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            e.handle(&d, &mut reply);
            sent += 1;
        }
        let c = e.counters();
        assert_eq!(c.requests, sent);
        assert!(c.malformed > sent / 2, "{c:?}");
        // Still answering: each board its own status.
        for id in [6u8, 7, 8, 9] {
            let (_, st, _) =
                ask(&mut e, &request(id, 7, 0, RequestKind::QuadletRead, &[])).unwrap();
            assert_eq!((st >> 24) & 0xF, u32::from(id));
        }
    }

    #[test]
    fn a_chain_refuses_shared_or_misplaced_boards() {
        let s = holding(Q1, "bridge");
        let m1 = ActuatorMap::from_io_config(&io([6, 7])).unwrap();
        let spec = |boards| ArmSpec {
            scenario: &s,
            map: m1,
            boards,
        };
        let e = Emulator::chain(&[spec([6, 7]), spec([6, 7])]).unwrap_err();
        assert!(matches!(e, SimError::Chain { board: Some(6), .. }), "{e}");
        let e = Emulator::chain(&[spec([6, 7]), spec([8, 9])]).unwrap_err();
        assert!(
            matches!(
                e,
                SimError::ActuatorPlacement {
                    boards: [8, 9],
                    board_id: 6,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("boards 8 and 9"), "{e}");
        assert!(matches!(
            Emulator::chain(&[]).unwrap_err(),
            SimError::Chain { board: None, .. }
        ));
        assert!(matches!(
            Emulator::chain(&[spec([16, 7])]).unwrap_err(),
            SimError::Chain {
                board: Some(16),
                ..
            }
        ));
        assert_eq!(classic_psm_boards("PSM2"), Some([8, 9]));
        assert_eq!(classic_psm_boards("psm2"), None);
    }
}
