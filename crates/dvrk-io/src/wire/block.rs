//! The real-time feedback block of one board (block read of address 0), reference §2.
//!
//! Offsets in quadlets, computed once from (firmware, board kind) by [`BlockLayout::new`]:
//! ```text
//!            Rev 7 QLA   Rev 8/9 QLA   Rev 8/9 DQLA   Rev 8/9 dRAC     (M motors, E encoders)
//! timestamp      0            0             0              0
//! status         1            1             1              1
//! digital I/O    2            2             2              2
//! temperature    3            3             3              3
//! ADC  x M     4..8         4..8          4..12          4..14
//! POS  x E     8..12        8..12        12..20         14..21
//! VEL  x E    12..16       12..16        20..28         21..28
//! QTR1 x E    16..20       16..20        28..36         28..35
//! QTR5 x E    20..24       20..24        36..44         35..42
//! RUN  x E    24..28       24..28        44..52         42..49
//! MSTAT x M      -         28..32        52..60         49..59
//! length        28           32            60             59
//! ```

use super::{WireError, get_be32, put_be32};

/// Board clock, 49.152 MHz (reference §2.3 timestamp, §1.2 watchdog).
pub const SYSCLK_HZ: f64 = 49.152e6;
/// Encoder velocity clock of the QLA/DQLA with Rev 7+ (reference §2.3 VEL).
pub const QLA_VELOCITY_CLOCK_HZ: f64 = 49.152e6;
/// Encoder velocity clock of the dRAC. The sources disagree (§2.3 note: 80 MHz in
/// EncoderVelocity.cpp, 40 MHz in `AmpIO::GetEncoderClockPeriod`); the velocity code's value is used.
pub const DRAC_VELOCITY_CLOCK_HZ: f64 = 80.0e6;
/// Mid-range offset of the 24-bit encoder counter (reference §2.3 encoder position).
pub const ENCODER_MIDRANGE: i32 = 0x80_0000;
/// QLA motor current: A = bits·12.5/65536 − 6.25 (reference §2.3 ADC).
pub const QLA_CURRENT_AMPS_PER_BIT: f64 = 12.5 / 65536.0;
/// QLA motor current offset in A (reference §2.3 ADC).
pub const QLA_CURRENT_OFFSET_AMPS: f64 = -6.25;
/// QLA pot: V = bits·4.5/65536 (reference §2.3 ADC).
pub const QLA_POT_VOLTS_PER_BIT: f64 = 4.5 / 65536.0;

/// Hardware-version register values (register 4), reference §1.1.
pub mod hardware_version {
    /// "QLA1"
    pub const QLA1: u32 = 0x514C_4131;
    /// "DQLA"
    pub const DQLA: u32 = 0x4451_4C41;
    /// "dRA1"
    pub const DRA1: u32 = 0x6452_4131;
    /// "BCFG" (board-configuration firmware, no motor I/O)
    pub const BCFG: u32 = 0x4243_4647;
}

/// Board status bits (reference §2.3 status tables; bit positions shared by all kinds unless noted).
pub mod status_bits {
    /// Bits 27–24: board id (rotary switch).
    pub const BOARD_ID_SHIFT: u32 = 24;
    pub const WATCHDOG_TIMEOUT: u32 = 1 << 23;
    /// QLA: quad-DAC type. dRAC: the arm is an ECM.
    pub const BIT22: u32 = 1 << 22;
    /// DQLA: power-enable error.
    pub const DQLA_POWER_ENABLE_ERROR: u32 = 1 << 20;
    pub const MV_GOOD: u32 = 1 << 19;
    pub const POWER_ENABLE: u32 = 1 << 18;
    /// QLA and dRAC (the DQLA has no relay feedback bit).
    pub const RELAY_FEEDBACK: u32 = 1 << 17;
    pub const RELAY_COMMANDED: u32 = 1 << 16;
    /// QLA 1.4+.
    pub const QLA_MOTOR_SUPPLY_FAULT: u32 = 1 << 15;
    pub const QLA_SAFETY_VOLTAGE: u32 = 1 << 14;
    pub const DQLA_MV_GOOD_QLA2: u32 = 1 << 15;
    pub const DQLA_MV_GOOD_QLA1: u32 = 1 << 14;
    pub const QLA_IO_EXPANDER: u32 = 1 << 12;
    /// QLA bits 11–8: amplifier on, one per axis.
    pub const QLA_AMP_ON_SHIFT: u32 = 8;
    /// QLA bits 7–4: firmware current-check trip, one per axis.
    pub const QLA_CURRENT_TRIP_SHIFT: u32 = 4;
    pub const DRAC_PRELOAD_DONE: u32 = 1 << 3;
    pub const DRAC_ESPM_VOLTAGE_OK: u32 = 1 << 2;
    pub const DRAC_ESII_COMM_OK: u32 = 1 << 1;
    pub const DRAC_ESPM_COMM_OK: u32 = 1 << 0;
}

/// Motor-status bits (reference §2.3 motor status, Rev 8+).
pub mod motor_status_bits {
    pub const AMP_ON: u32 = 1 << 29;
    pub const ENABLE_REQUESTED: u32 = 1 << 28;
    pub const MODE_SHIFT: u32 = 24;
    pub const QLA_CURRENT_CONTROL: u32 = 1 << 20;
    pub const QLA_CURRENT_CHECK_TRIP: u32 = 1 << 17;
    pub const QLA_AMP_FAULT: u32 = 1 << 16;
    pub const DRAC_FAULT_SHIFT: u32 = 16;
}

/// Kind of motor board behind the FPGA (reference §1.1, §2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BoardKind {
    /// QLA1: 4 motors, 4 encoders.
    Qla,
    /// DQLA: two QLAs on one V3 FPGA, 8 motors, 8 encoders.
    Dqla,
    /// dRAC (Si arms): 10 motors (7 actuators + 3 brakes), 7 encoders.
    Drac,
}

impl BoardKind {
    /// From the hardware-version register (reference §1.1).
    pub const fn from_hardware_version(hardware: u32) -> Result<Self, WireError> {
        match hardware {
            hardware_version::QLA1 => Ok(Self::Qla),
            hardware_version::DQLA => Ok(Self::Dqla),
            hardware_version::DRA1 => Ok(Self::Drac),
            hardware => Err(WireError::UnknownHardware { hardware }),
        }
    }
    pub const fn hardware_version(self) -> u32 {
        match self {
            Self::Qla => hardware_version::QLA1,
            Self::Dqla => hardware_version::DQLA,
            Self::Drac => hardware_version::DRA1,
        }
    }
    /// The dVRK's name ("QLA1", "DQLA", "dRA1"), as in sawRobotIO1394 `hardware_version`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Qla => "QLA1",
            Self::Dqla => "DQLA",
            Self::Drac => "dRA1",
        }
    }
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "QLA1" => Some(Self::Qla),
            "DQLA" => Some(Self::Dqla),
            "dRA1" => Some(Self::Drac),
            _ => None,
        }
    }
    /// Motors M (reference §2.1).
    pub const fn num_motors(self) -> usize {
        match self {
            Self::Qla => 4,
            Self::Dqla => 8,
            Self::Drac => 10,
        }
    }
    /// Encoders E (reference §2.1).
    pub const fn num_encoders(self) -> usize {
        match self {
            Self::Qla => 4,
            Self::Dqla => 8,
            Self::Drac => 7,
        }
    }
}

/// Feedback-block offsets for one (firmware, board kind); `Copy`, computed once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockLayout {
    firmware: u32,
    kind: BoardKind,
    motors: u8,
    encoders: u8,
    adc: u8,
    pos: u8,
    vel: u8,
    qtr1: u8,
    qtr5: u8,
    run: u8,
    motor_status: u8,
    has_motor_status: bool,
    len: u8,
}

impl BlockLayout {
    /// Oldest and newest firmware versions with a known layout.
    pub const MIN_FIRMWARE: u32 = 7;
    pub const MAX_FIRMWARE: u32 = 9;

    /// Layout for `firmware` (Rev 7, 8, 9) and `kind`; DQLA and dRAC need Rev 8+ (§2.1).
    pub const fn new(firmware: u32, kind: BoardKind) -> Result<Self, WireError> {
        if firmware < Self::MIN_FIRMWARE || firmware > Self::MAX_FIRMWARE {
            return Err(WireError::UnsupportedFirmware { firmware });
        }
        let has_motor_status = firmware >= 8;
        if !has_motor_status && !matches!(kind, BoardKind::Qla) {
            return Err(WireError::UnsupportedLayout { firmware, kind });
        }
        let m = kind.num_motors() as u8;
        let e = kind.num_encoders() as u8;
        let adc = 4;
        let pos = adc + m;
        let vel = pos + e;
        let qtr1 = vel + e;
        let qtr5 = qtr1 + e;
        let run = qtr5 + e;
        let motor_status = run + e;
        let len = if has_motor_status {
            motor_status + m
        } else {
            motor_status
        };
        Ok(Self {
            firmware,
            kind,
            motors: m,
            encoders: e,
            adc,
            pos,
            vel,
            qtr1,
            qtr5,
            run,
            motor_status,
            has_motor_status,
            len,
        })
    }
    pub const fn firmware(&self) -> u32 {
        self.firmware
    }
    pub const fn kind(&self) -> BoardKind {
        self.kind
    }
    pub const fn num_motors(&self) -> usize {
        self.motors as usize
    }
    pub const fn num_encoders(&self) -> usize {
        self.encoders as usize
    }
    pub const fn has_motor_status(&self) -> bool {
        self.has_motor_status
    }
    pub const fn len_quadlets(&self) -> usize {
        self.len as usize
    }
    pub const fn len_bytes(&self) -> usize {
        self.len as usize * 4
    }
    /// Encoder velocity clock for this board (reference §2.3 VEL).
    pub const fn velocity_clock_hz(&self) -> f64 {
        match self.kind {
            BoardKind::Drac => DRAC_VELOCITY_CLOCK_HZ,
            _ => QLA_VELOCITY_CLOCK_HZ,
        }
    }
    /// Byte offset of motor quadlet `m` in the group starting at quadlet `base`.
    #[inline(always)]
    const fn motor_off(&self, base: u8, m: usize) -> Option<usize> {
        if m < self.motors as usize {
            Some((base as usize + m) * 4)
        } else {
            None
        }
    }
    #[inline(always)]
    const fn enc_off(&self, base: u8, e: usize) -> Option<usize> {
        if e < self.encoders as usize {
            Some((base as usize + e) * 4)
        } else {
            None
        }
    }
    /// Byte offsets of the indexed groups (None when out of range).
    pub const fn adc_offset(&self, m: usize) -> Option<usize> {
        self.motor_off(self.adc, m)
    }
    pub const fn encoder_position_offset(&self, e: usize) -> Option<usize> {
        self.enc_off(self.pos, e)
    }
    pub const fn encoder_period_offset(&self, e: usize) -> Option<usize> {
        self.enc_off(self.vel, e)
    }
    pub const fn qtr1_offset(&self, e: usize) -> Option<usize> {
        self.enc_off(self.qtr1, e)
    }
    pub const fn qtr5_offset(&self, e: usize) -> Option<usize> {
        self.enc_off(self.qtr5, e)
    }
    pub const fn running_offset(&self, e: usize) -> Option<usize> {
        self.enc_off(self.run, e)
    }
    pub const fn motor_status_offset(&self, m: usize) -> Option<usize> {
        if self.has_motor_status {
            self.motor_off(self.motor_status, m)
        } else {
            None
        }
    }
}

/// Timestamp quadlet: sysclk ticks since the previous sample, minus 1 (reference §2.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Timestamp(pub u32);

impl Timestamp {
    /// Ticks since the previous sample (the software adds 1).
    pub const fn elapsed_ticks(self) -> u64 {
        self.0 as u64 + 1
    }
    pub fn elapsed_s(self) -> f64 {
        self.elapsed_ticks() as f64 / SYSCLK_HZ
    }
    /// The raw value for an interval of `ticks` (≥ 1) ticks.
    pub const fn from_elapsed_ticks(ticks: u64) -> Self {
        let t = if ticks == 0 { 0 } else { ticks - 1 };
        Self(if t > u32::MAX as u64 {
            u32::MAX
        } else {
            t as u32
        })
    }
}

/// Status quadlet of one board; meaning depends on the board kind (reference §2.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardStatus {
    pub raw: u32,
    pub kind: BoardKind,
}

impl BoardStatus {
    pub const fn new(raw: u32, kind: BoardKind) -> Self {
        Self { raw, kind }
    }
    #[inline]
    const fn bit(&self, mask: u32) -> bool {
        self.raw & mask != 0
    }
    /// Rotary-switch board id, bits 27–24.
    pub const fn board_id(&self) -> u8 {
        ((self.raw >> status_bits::BOARD_ID_SHIFT) & 0x0F) as u8
    }
    pub const fn watchdog_timeout(&self) -> bool {
        self.bit(status_bits::WATCHDOG_TIMEOUT)
    }
    /// Motor supply present (bit 19; both QLAs on a DQLA; 48 V on a dRAC).
    pub const fn mv_good(&self) -> bool {
        self.bit(status_bits::MV_GOOD)
    }
    pub const fn power_enabled(&self) -> bool {
        self.bit(status_bits::POWER_ENABLE)
    }
    pub const fn relay_commanded(&self) -> bool {
        self.bit(status_bits::RELAY_COMMANDED)
    }
    /// Relay contacts closed. The DQLA has no feedback bit and echoes the command (§2.3, §7).
    pub const fn relay_feedback(&self) -> bool {
        match self.kind {
            BoardKind::Dqla => self.bit(status_bits::RELAY_COMMANDED),
            _ => self.bit(status_bits::RELAY_FEEDBACK),
        }
    }
    /// Motor supply fault (QLA 1.4+ bit 15; other kinds have no such bit and report false).
    pub const fn motor_supply_fault(&self) -> bool {
        matches!(self.kind, BoardKind::Qla) && self.bit(status_bits::QLA_MOTOR_SUPPLY_FAULT)
    }
    /// QLA: the safety line has voltage (bit 14).
    pub const fn safety_voltage(&self) -> bool {
        matches!(self.kind, BoardKind::Qla) && self.bit(status_bits::QLA_SAFETY_VOLTAGE)
    }
    /// DQLA: power-enable error (bit 20).
    pub const fn power_enable_error(&self) -> bool {
        matches!(self.kind, BoardKind::Dqla) && self.bit(status_bits::DQLA_POWER_ENABLE_ERROR)
    }
    /// QLA: amplifier on for `axis` (bits 11–8). None for other kinds or axis ≥ 4.
    pub const fn amp_on(&self, axis: usize) -> Option<bool> {
        if matches!(self.kind, BoardKind::Qla) && axis < 4 {
            Some(self.raw & (1 << (status_bits::QLA_AMP_ON_SHIFT + axis as u32)) != 0)
        } else {
            None
        }
    }
    /// QLA: firmware current-check trip for `axis` (bits 7–4). None for other kinds or axis ≥ 4.
    pub const fn current_check_trip(&self, axis: usize) -> Option<bool> {
        if matches!(self.kind, BoardKind::Qla) && axis < 4 {
            Some(self.raw & (1 << (status_bits::QLA_CURRENT_TRIP_SHIFT + axis as u32)) != 0)
        } else {
            None
        }
    }
    /// dRAC: the arm is an ECM (bit 22).
    pub const fn drac_is_ecm(&self) -> bool {
        matches!(self.kind, BoardKind::Drac) && self.bit(status_bits::BIT22)
    }
    /// "Fully powered" as sawRobotIO1394 defines it (reference §7): mv_good, no supply fault,
    /// relay commanded and closed, no watchdog timeout.
    pub const fn fully_powered(&self) -> bool {
        self.mv_good()
            && !self.motor_supply_fault()
            && self.relay_commanded()
            && self.relay_feedback()
            && !self.watchdog_timeout()
    }
    /// Raw bits for a board id (to build a status quadlet).
    pub const fn board_id_bits(board_id: u8) -> u32 {
        ((board_id & 0x0F) as u32) << status_bits::BOARD_ID_SHIFT
    }
}

/// Digital I/O quadlet (reference §2.3; QLA layout, the DQLA puts the second QLA in the upper half).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DigitalIo(pub u32);

impl DigitalIo {
    pub const fn bit(self, n: u32) -> bool {
        n < 32 && self.0 & (1 << n) != 0
    }
    pub const fn encoder_supply_fault(self) -> bool {
        self.bit(31)
    }
    pub const fn motor_supply_comparator(self) -> bool {
        self.bit(28)
    }
    pub const fn home(self, axis: u32) -> bool {
        axis < 4 && self.bit(axis)
    }
    pub const fn positive_limit(self, axis: u32) -> bool {
        axis < 4 && self.bit(4 + axis)
    }
    pub const fn negative_limit(self, axis: u32) -> bool {
        axis < 4 && self.bit(8 + axis)
    }
}

/// Temperature quadlet: 0.5 °C per bit, 0xFF invalid (reference §2.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Temperature(pub u32);

impl Temperature {
    /// Sensor `i`: 0 = axes 1–2 (bits 15–8), 1 = axes 3–4 (bits 7–0); on a DQLA 2 and 3 are
    /// bits 31–24 and 23–16. None when the sensor reads 0xFF or `i` > 3.
    pub fn sensor_celsius(self, i: usize) -> Option<f64> {
        let shift = match i {
            0 => 8,
            1 => 0,
            2 => 24,
            3 => 16,
            _ => return None,
        };
        let v = (self.0 >> shift) & 0xFF;
        if v == 0xFF {
            None
        } else {
            Some(f64::from(v) * 0.5)
        }
    }
    /// Raw bits of sensors 0 and 1 for temperatures in °C (clamped to 0..=127 °C).
    pub fn from_celsius(axes12: f64, axes34: f64) -> Self {
        let enc = |c: f64| (c * 2.0).round().clamp(0.0, 254.0) as u32;
        Self((enc(axes12) << 8) | enc(axes34))
    }
}

/// ADC quadlet of one motor: pot in bits 31–16, current in bits 15–0 (reference §2.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Adc(pub u32);

impl Adc {
    pub const fn new(pot_bits: u16, current_bits: u16) -> Self {
        Self(((pot_bits as u32) << 16) | current_bits as u32)
    }
    pub const fn pot_bits(self) -> u16 {
        (self.0 >> 16) as u16
    }
    pub const fn current_bits(self) -> u16 {
        self.0 as u16
    }
    /// QLA formula, A = bits·12.5/65536 − 6.25 (before any per-robot direction and offset).
    pub fn qla_current_amps(self) -> f64 {
        f64::from(self.current_bits()) * QLA_CURRENT_AMPS_PER_BIT + QLA_CURRENT_OFFSET_AMPS
    }
    /// QLA formula, V = bits·4.5/65536.
    pub fn qla_pot_volts(self) -> f64 {
        f64::from(self.pot_bits()) * QLA_POT_VOLTS_PER_BIT
    }
}

/// Encoder position quadlet (reference §2.3): bit 30 index, 29 B, 28 A, 24 overflow (sticky),
/// 23–0 counter with mid-range offset 0x800000.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EncoderPosition(pub u32);

impl EncoderPosition {
    pub const OVERFLOW: u32 = 1 << 24;
    /// Signed counts = (raw & 0xFFFFFF) − 0x800000.
    #[inline]
    pub const fn counts(self) -> i32 {
        (self.0 & 0x00FF_FFFF) as i32 - ENCODER_MIDRANGE
    }
    pub const fn overflow(self) -> bool {
        self.0 & Self::OVERFLOW != 0
    }
    pub const fn channel_a(self) -> bool {
        self.0 & (1 << 28) != 0
    }
    pub const fn channel_b(self) -> bool {
        self.0 & (1 << 29) != 0
    }
    pub const fn index(self) -> bool {
        self.0 & (1 << 30) != 0
    }
    /// Raw value for signed `counts` (wrapped to 24 bits, as the counter does).
    pub const fn from_counts(counts: i32) -> Self {
        Self((counts.wrapping_add(ENCODER_MIDRANGE) as u32) & 0x00FF_FFFF)
    }
    pub const fn with_overflow(self, overflow: bool) -> Self {
        if overflow {
            Self(self.0 | Self::OVERFLOW)
        } else {
            Self(self.0 & !Self::OVERFLOW)
        }
    }
}

/// Encoder period (VEL) quadlet, Rev 7+ (reference §2.3): 31 overflow, 30 direction (1 =
/// positive), 29 direction changed, 28 encoder error, 27 partial cycle, 25–0 ticks per full
/// quadrature cycle (4 counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EncoderPeriod(pub u32);

impl EncoderPeriod {
    pub const OVERFLOW: u32 = 1 << 31;
    pub const DIRECTION_POSITIVE: u32 = 1 << 30;
    pub const DIRECTION_CHANGED: u32 = 1 << 29;
    pub const ENCODER_ERROR: u32 = 1 << 28;
    pub const PARTIAL_CYCLE: u32 = 1 << 27;
    pub const TICKS_MASK: u32 = 0x03FF_FFFF;

    pub const fn overflow(self) -> bool {
        self.0 & Self::OVERFLOW != 0
    }
    pub const fn direction_positive(self) -> bool {
        self.0 & Self::DIRECTION_POSITIVE != 0
    }
    pub const fn direction_changed(self) -> bool {
        self.0 & Self::DIRECTION_CHANGED != 0
    }
    pub const fn encoder_error(self) -> bool {
        self.0 & Self::ENCODER_ERROR != 0
    }
    pub const fn partial_cycle(self) -> bool {
        self.0 & Self::PARTIAL_CYCLE != 0
    }
    pub const fn ticks(self) -> u32 {
        self.0 & Self::TICKS_MASK
    }
    /// Velocity = ±4·clock/ticks counts/s; 0 on overflow, direction change or zero ticks.
    #[inline]
    pub fn velocity_counts_per_s(self, clock_hz: f64) -> f64 {
        let t = self.ticks();
        if self.overflow() || self.direction_changed() || t == 0 {
            return 0.0;
        }
        let v = 4.0 * clock_hz / f64::from(t);
        if self.direction_positive() { v } else { -v }
    }
    /// The quadlet a board would report while moving at `counts_per_s` (overflow when too slow
    /// for 26 bits of ticks, or at rest).
    pub fn from_velocity(counts_per_s: f64, clock_hz: f64) -> Self {
        let dir = if counts_per_s >= 0.0 {
            Self::DIRECTION_POSITIVE
        } else {
            0
        };
        let speed = counts_per_s.abs();
        let usable = speed > 0.0 && speed.is_finite() && clock_hz > 0.0;
        if !usable {
            return Self(Self::OVERFLOW | dir | Self::TICKS_MASK);
        }
        let ticks = (4.0 * clock_hz / speed).round();
        if ticks > f64::from(Self::TICKS_MASK) {
            Self(Self::OVERFLOW | dir | Self::TICKS_MASK)
        } else {
            Self(dir | (ticks.max(1.0) as u32))
        }
    }
    pub const fn with_encoder_error(self, error: bool) -> Self {
        if error {
            Self(self.0 | Self::ENCODER_ERROR)
        } else {
            Self(self.0 & !Self::ENCODER_ERROR)
        }
    }
}

/// QTR1 / QTR5 quadlet (reference §2.3): 31 overflow, 30 direction, 29–26 edge mask, 25–0 ticks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Quarter(pub u32);

impl Quarter {
    pub const fn overflow(self) -> bool {
        self.0 & (1 << 31) != 0
    }
    pub const fn direction_positive(self) -> bool {
        self.0 & (1 << 30) != 0
    }
    pub const fn edge_mask(self) -> u8 {
        ((self.0 >> 26) & 0x0F) as u8
    }
    pub const fn ticks(self) -> u32 {
        self.0 & 0x03FF_FFFF
    }
}

/// Motor-status quadlet, Rev 8+ (reference §2.3 motor status).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotorStatus {
    pub raw: u32,
    pub kind: BoardKind,
}

impl MotorStatus {
    pub const fn new(raw: u32, kind: BoardKind) -> Self {
        Self { raw, kind }
    }
    pub const fn amp_on(&self) -> bool {
        self.raw & motor_status_bits::AMP_ON != 0
    }
    pub const fn enable_requested(&self) -> bool {
        self.raw & motor_status_bits::ENABLE_REQUESTED != 0
    }
    /// 0 = current, 1 = voltage.
    pub const fn mode(&self) -> u8 {
        ((self.raw >> motor_status_bits::MODE_SHIFT) & 0x0F) as u8
    }
    /// QLA/DQLA amp fault (bit 16); on a dRAC, any nonzero fault code.
    pub const fn amp_fault(&self) -> bool {
        match self.kind {
            BoardKind::Drac => self.drac_fault_code() != 0,
            _ => self.raw & motor_status_bits::QLA_AMP_FAULT != 0,
        }
    }
    /// QLA/DQLA firmware current-check trip (bit 17); false on a dRAC.
    pub const fn current_check_trip(&self) -> bool {
        !matches!(self.kind, BoardKind::Drac)
            && self.raw & motor_status_bits::QLA_CURRENT_CHECK_TRIP != 0
    }
    /// QLA/DQLA: current control (bit 20).
    pub const fn current_control(&self) -> bool {
        !matches!(self.kind, BoardKind::Drac)
            && self.raw & motor_status_bits::QLA_CURRENT_CONTROL != 0
    }
    /// dRAC fault code, bits 19–16: 1 ADC saturated, 2 current deviation, 3 hardware
    /// over-current, 4 over-temperature. 0 for other kinds.
    pub const fn drac_fault_code(&self) -> u8 {
        match self.kind {
            BoardKind::Drac => ((self.raw >> motor_status_bits::DRAC_FAULT_SHIFT) & 0x0F) as u8,
            _ => 0,
        }
    }
    /// QLA/DQLA: last DAC command (bits 15–0).
    pub const fn dac(&self) -> u16 {
        self.raw as u16
    }
    /// dRAC: duty cycle (bits 15–0 >> 5).
    pub const fn drac_duty_cycle(&self) -> u16 {
        (self.raw as u16) >> 5
    }
}

/// Checked view of one board's feedback block.
#[derive(Clone, Copy, Debug)]
pub struct FeedbackBlock<T: AsRef<[u8]>> {
    buf: T,
    lay: BlockLayout,
}

impl<T: AsRef<[u8]>> FeedbackBlock<T> {
    /// Checks that `buf` holds at least the layout's bytes.
    pub fn new_checked(buf: T, lay: BlockLayout) -> Result<Self, WireError> {
        let (got, need) = (buf.as_ref().len(), lay.len_bytes());
        if got < need {
            return Err(WireError::Truncated { got, need });
        }
        Ok(Self { buf, lay })
    }
    pub fn layout(&self) -> BlockLayout {
        self.lay
    }
    pub fn into_inner(self) -> T {
        self.buf
    }
    #[inline(always)]
    fn at(&self, off: usize) -> u32 {
        get_be32(self.buf.as_ref(), off)
    }
    #[inline(always)]
    fn at_opt(&self, off: Option<usize>) -> Option<u32> {
        off.map(|o| self.at(o))
    }
    pub fn timestamp(&self) -> Timestamp {
        Timestamp(self.at(0))
    }
    pub fn status(&self) -> BoardStatus {
        BoardStatus::new(self.at(4), self.lay.kind)
    }
    pub fn digital_io(&self) -> DigitalIo {
        DigitalIo(self.at(8))
    }
    pub fn temperature(&self) -> Temperature {
        Temperature(self.at(12))
    }
    #[inline]
    pub fn adc(&self, m: usize) -> Option<Adc> {
        self.at_opt(self.lay.adc_offset(m)).map(Adc)
    }
    #[inline]
    pub fn encoder_position(&self, e: usize) -> Option<EncoderPosition> {
        self.at_opt(self.lay.encoder_position_offset(e))
            .map(EncoderPosition)
    }
    #[inline]
    pub fn encoder_period(&self, e: usize) -> Option<EncoderPeriod> {
        self.at_opt(self.lay.encoder_period_offset(e))
            .map(EncoderPeriod)
    }
    pub fn qtr1(&self, e: usize) -> Option<Quarter> {
        self.at_opt(self.lay.qtr1_offset(e)).map(Quarter)
    }
    pub fn qtr5(&self, e: usize) -> Option<Quarter> {
        self.at_opt(self.lay.qtr5_offset(e)).map(Quarter)
    }
    /// Ticks since the last encoder edge; bit 31 = overflow.
    pub fn running(&self, e: usize) -> Option<u32> {
        self.at_opt(self.lay.running_offset(e))
    }
    /// None for Rev 7 (no motor status) or `m` out of range.
    #[inline]
    pub fn motor_status(&self, m: usize) -> Option<MotorStatus> {
        let kind = self.lay.kind;
        self.at_opt(self.lay.motor_status_offset(m))
            .map(|r| MotorStatus::new(r, kind))
    }
    /// The block's own bytes.
    pub fn as_bytes(&self) -> &[u8] {
        let b = self.buf.as_ref();
        b.get(..self.lay.len_bytes()).unwrap_or(b)
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> FeedbackBlock<T> {
    fn put(&mut self, off: usize, v: u32) {
        put_be32(self.buf.as_mut(), off, v);
    }
    fn put_opt(
        &mut self,
        off: Option<usize>,
        index: usize,
        count: usize,
        v: u32,
    ) -> Result<(), WireError> {
        match off {
            Some(o) => {
                self.put(o, v);
                Ok(())
            }
            None => Err(WireError::IndexOutOfRange { index, count }),
        }
    }
    /// Zeroes the whole block.
    pub fn clear(&mut self) {
        let n = self.lay.len_bytes();
        if let Some(b) = self.buf.as_mut().get_mut(..n) {
            b.fill(0);
        }
    }
    pub fn set_timestamp(&mut self, v: Timestamp) {
        self.put(0, v.0);
    }
    pub fn set_status(&mut self, raw: u32) {
        self.put(4, raw);
    }
    pub fn set_digital_io(&mut self, v: DigitalIo) {
        self.put(8, v.0);
    }
    pub fn set_temperature(&mut self, v: Temperature) {
        self.put(12, v.0);
    }
    pub fn set_adc(&mut self, m: usize, v: Adc) -> Result<(), WireError> {
        self.put_opt(self.lay.adc_offset(m), m, self.lay.num_motors(), v.0)
    }
    pub fn set_encoder_position(&mut self, e: usize, v: EncoderPosition) -> Result<(), WireError> {
        self.put_opt(
            self.lay.encoder_position_offset(e),
            e,
            self.lay.num_encoders(),
            v.0,
        )
    }
    pub fn set_encoder_period(&mut self, e: usize, v: EncoderPeriod) -> Result<(), WireError> {
        self.put_opt(
            self.lay.encoder_period_offset(e),
            e,
            self.lay.num_encoders(),
            v.0,
        )
    }
    pub fn set_qtr1(&mut self, e: usize, v: Quarter) -> Result<(), WireError> {
        self.put_opt(self.lay.qtr1_offset(e), e, self.lay.num_encoders(), v.0)
    }
    pub fn set_qtr5(&mut self, e: usize, v: Quarter) -> Result<(), WireError> {
        self.put_opt(self.lay.qtr5_offset(e), e, self.lay.num_encoders(), v.0)
    }
    pub fn set_running(&mut self, e: usize, raw: u32) -> Result<(), WireError> {
        self.put_opt(self.lay.running_offset(e), e, self.lay.num_encoders(), raw)
    }
    /// Errors for Rev 7 (no motor status) as index out of range with count 0.
    pub fn set_motor_status(&mut self, m: usize, raw: u32) -> Result<(), WireError> {
        let count = if self.lay.has_motor_status() {
            self.lay.num_motors()
        } else {
            0
        };
        self.put_opt(self.lay.motor_status_offset(m), m, count, raw)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_sizes_match_reference_2_1() {
        let q = |fw, k| BlockLayout::new(fw, k).unwrap().len_quadlets();
        assert_eq!(q(7, BoardKind::Qla), 28);
        assert_eq!(q(8, BoardKind::Qla), 32);
        assert_eq!(q(9, BoardKind::Qla), 32);
        assert_eq!(q(8, BoardKind::Dqla), 60);
        assert_eq!(q(9, BoardKind::Drac), 59);
        assert_eq!(
            BlockLayout::new(6, BoardKind::Qla).unwrap_err(),
            WireError::UnsupportedFirmware { firmware: 6 }
        );
        assert_eq!(
            BlockLayout::new(10, BoardKind::Qla).unwrap_err(),
            WireError::UnsupportedFirmware { firmware: 10 }
        );
        assert_eq!(
            BlockLayout::new(7, BoardKind::Dqla).unwrap_err(),
            WireError::UnsupportedLayout {
                firmware: 7,
                kind: BoardKind::Dqla
            }
        );
    }

    #[test]
    fn drac_offsets_match_reference_2_2() {
        let l = BlockLayout::new(9, BoardKind::Drac).unwrap();
        assert_eq!(l.adc_offset(0), Some(16));
        assert_eq!(l.adc_offset(9), Some(13 * 4));
        assert_eq!(l.adc_offset(10), None);
        assert_eq!(l.encoder_position_offset(0), Some(14 * 4));
        assert_eq!(l.encoder_position_offset(6), Some(20 * 4));
        assert_eq!(l.encoder_position_offset(7), None);
        assert_eq!(l.encoder_period_offset(0), Some(21 * 4));
        assert_eq!(l.qtr1_offset(0), Some(28 * 4));
        assert_eq!(l.qtr5_offset(0), Some(35 * 4));
        assert_eq!(l.running_offset(0), Some(42 * 4));
        assert_eq!(l.motor_status_offset(0), Some(49 * 4));
        assert_eq!(l.motor_status_offset(9), Some(58 * 4));
    }

    #[test]
    fn hardware_versions() {
        assert_eq!(
            BoardKind::from_hardware_version(u32::from_be_bytes(*b"QLA1")).unwrap(),
            BoardKind::Qla
        );
        assert_eq!(
            BoardKind::from_hardware_version(u32::from_be_bytes(*b"DQLA")).unwrap(),
            BoardKind::Dqla
        );
        assert_eq!(
            BoardKind::from_hardware_version(u32::from_be_bytes(*b"dRA1")).unwrap(),
            BoardKind::Drac
        );
        assert_eq!(
            BoardKind::from_hardware_version(hardware_version::BCFG).unwrap_err(),
            WireError::UnknownHardware {
                hardware: 0x4243_4647
            }
        );
        for k in [BoardKind::Qla, BoardKind::Dqla, BoardKind::Drac] {
            assert_eq!(BoardKind::from_name(k.name()), Some(k));
            assert_eq!(
                BoardKind::from_hardware_version(k.hardware_version()),
                Ok(k)
            );
        }
    }

    #[test]
    fn encoder_position_decoding() {
        assert_eq!(EncoderPosition(0x0080_0000).counts(), 0);
        assert_eq!(EncoderPosition(0x0080_0001).counts(), 1);
        assert_eq!(EncoderPosition(0x007F_FFFF).counts(), -1);
        assert_eq!(EncoderPosition(0x0000_0000).counts(), -0x80_0000);
        assert_eq!(EncoderPosition(0x00FF_FFFF).counts(), 0x7F_FFFF);
        let p = EncoderPosition(0x7180_0010);
        assert_eq!(p.counts(), 16);
        assert!(p.overflow() && p.channel_a() && p.channel_b() && p.index());
        for c in [-0x80_0000, -12345, -1, 0, 1, 777, 0x7F_FFFF] {
            assert_eq!(EncoderPosition::from_counts(c).counts(), c);
        }
        assert!(
            EncoderPosition::from_counts(5)
                .with_overflow(true)
                .overflow()
        );
    }

    #[test]
    fn encoder_period_decoding() {
        // 49152 ticks at 49.152 MHz per 4 counts = 4000 counts/s.
        let p = EncoderPeriod(EncoderPeriod::DIRECTION_POSITIVE | 49_152);
        assert_eq!(p.velocity_counts_per_s(QLA_VELOCITY_CLOCK_HZ), 4000.0);
        let n = EncoderPeriod(49_152);
        assert_eq!(n.velocity_counts_per_s(QLA_VELOCITY_CLOCK_HZ), -4000.0);
        assert_eq!(
            EncoderPeriod(EncoderPeriod::OVERFLOW | 5).velocity_counts_per_s(1e6),
            0.0
        );
        assert_eq!(
            EncoderPeriod(EncoderPeriod::DIRECTION_CHANGED | 5).velocity_counts_per_s(1e6),
            0.0
        );
        assert_eq!(EncoderPeriod(0).velocity_counts_per_s(1e6), 0.0);
        let e = EncoderPeriod(0x1000_0000);
        assert!(e.encoder_error() && !e.overflow() && !e.partial_cycle());
        let v = EncoderPeriod::from_velocity(-4000.0, QLA_VELOCITY_CLOCK_HZ);
        assert_eq!(v.velocity_counts_per_s(QLA_VELOCITY_CLOCK_HZ), -4000.0);
        assert!(EncoderPeriod::from_velocity(0.0, QLA_VELOCITY_CLOCK_HZ).overflow());
        assert!(EncoderPeriod::from_velocity(1e-6, QLA_VELOCITY_CLOCK_HZ).overflow());
    }

    #[test]
    fn status_decoding_per_kind() {
        let raw = BoardStatus::board_id_bits(6)
            | status_bits::MV_GOOD
            | status_bits::POWER_ENABLE
            | status_bits::RELAY_FEEDBACK
            | status_bits::RELAY_COMMANDED
            | (0b0101 << 8)
            | (0b0010 << 4);
        let s = BoardStatus::new(raw, BoardKind::Qla);
        assert_eq!(s.board_id(), 6);
        assert!(s.mv_good() && s.power_enabled() && s.relay_feedback() && s.relay_commanded());
        assert!(!s.watchdog_timeout() && !s.motor_supply_fault());
        assert!(s.fully_powered());
        assert_eq!(s.amp_on(0), Some(true));
        assert_eq!(s.amp_on(1), Some(false));
        assert_eq!(s.amp_on(2), Some(true));
        assert_eq!(s.amp_on(4), None);
        assert_eq!(s.current_check_trip(1), Some(true));
        let wd = BoardStatus::new(
            raw | status_bits::WATCHDOG_TIMEOUT | status_bits::QLA_MOTOR_SUPPLY_FAULT,
            BoardKind::Qla,
        );
        assert!(wd.watchdog_timeout() && wd.motor_supply_fault() && !wd.fully_powered());
        // Bit 15 on a DQLA is mv_good of QLA2, not a fault.
        let d = BoardStatus::new(
            status_bits::DQLA_MV_GOOD_QLA2 | status_bits::RELAY_COMMANDED,
            BoardKind::Dqla,
        );
        assert!(!d.motor_supply_fault());
        assert!(d.relay_feedback());
        assert_eq!(d.amp_on(0), None);
    }

    #[test]
    fn motor_status_decoding() {
        let q = MotorStatus::new((1 << 29) | (1 << 17) | (1 << 16) | 0x8000, BoardKind::Qla);
        assert!(q.amp_on() && q.current_check_trip() && q.amp_fault());
        assert_eq!(q.dac(), 0x8000);
        let d = MotorStatus::new((1 << 29) | (3 << 16) | (100 << 5), BoardKind::Drac);
        assert_eq!(d.drac_fault_code(), 3);
        assert!(d.amp_fault());
        assert!(!d.current_check_trip());
        assert_eq!(d.drac_duty_cycle(), 100);
    }

    #[test]
    fn adc_and_temperature() {
        let a = Adc::new(0x8000, 0x8000);
        assert_eq!(a.0, 0x8000_8000);
        assert_eq!(a.qla_current_amps(), 0.0);
        assert_eq!(a.qla_pot_volts(), 2.25);
        assert_eq!(Adc::new(0, 0).qla_current_amps(), -6.25);
        let t = Temperature(0x0000_50FF);
        assert_eq!(t.sensor_celsius(0), Some(40.0));
        assert_eq!(t.sensor_celsius(1), None);
        assert_eq!(Temperature::from_celsius(40.0, 35.5).0, 0x50_47);
        assert_eq!(Timestamp(0).elapsed_ticks(), 1);
        assert_eq!(Timestamp::from_elapsed_ticks(49_152).0, 49_151);
    }

    /// Board 6, QLA, Rev 8: a PSM at rest with power on, all four amps on, axis 2 with an
    /// encoder error, axis 3 with a current-check trip.
    static BLOCK_FW8_QLA: [u32; 32] = [
        0x0000_C000, // timestamp: 49153 ticks since the previous sample
        0x060F_0F00, // status: board 6, mv_good, power, relay fb+cmd, amps on 0-3
        0x0000_000F, // digital I/O: home switches
        0x0000_5048, // temperature: 40 C, 36 C
        0x8000_8000,
        0x7000_9000,
        0x0001_FFFF,
        0xFFFF_0000, // ADC x4 (pot | current)
        0x0080_0000,
        0x0080_0064,
        0x007F_FF9C,
        0x0180_0000, // POS x4: 0, +100, -100, overflow
        0x4000_C000,
        0x0000_C000,
        0x5000_C000,
        0x8000_0000, // VEL x4: +, -, +error, overflow
        0x0000_0001,
        0x0000_0002,
        0x0000_0003,
        0x0000_0004, // QTR1
        0x0000_0005,
        0x0000_0006,
        0x0000_0007,
        0x0000_0008, // QTR5
        0x0000_0010,
        0x0000_0020,
        0x0000_0030,
        0x8000_0000, // RUN
        0x2000_8000,
        0x2000_8000,
        0x2000_8000,
        0x2002_8000, // motor status: amp on, trip on 3
    ];

    fn be_bytes(q: &[u32]) -> Vec<u8> {
        q.iter().flat_map(|v| v.to_be_bytes()).collect()
    }

    #[test]
    fn deconstruct_block_fw8_qla() {
        let bytes = be_bytes(&BLOCK_FW8_QLA);
        let b =
            FeedbackBlock::new_checked(&bytes[..], BlockLayout::new(8, BoardKind::Qla).unwrap())
                .unwrap();
        assert_eq!(b.timestamp().elapsed_ticks(), 49_153);
        let s = b.status();
        assert_eq!(s.board_id(), 6);
        assert!(s.fully_powered());
        assert_eq!(s.amp_on(3), Some(true));
        assert!(b.digital_io().home(0) && !b.digital_io().positive_limit(0));
        assert_eq!(b.temperature().sensor_celsius(0), Some(40.0));
        assert_eq!(b.temperature().sensor_celsius(1), Some(36.0));
        assert_eq!(b.adc(0).unwrap().qla_current_amps(), 0.0);
        assert_eq!(b.adc(1).unwrap().pot_bits(), 0x7000);
        assert_eq!(b.adc(3).unwrap().current_bits(), 0);
        assert_eq!(b.adc(4), None);
        assert_eq!(b.encoder_position(1).unwrap().counts(), 100);
        assert_eq!(b.encoder_position(2).unwrap().counts(), -100);
        assert!(b.encoder_position(3).unwrap().overflow());
        let clk = b.layout().velocity_clock_hz();
        assert_eq!(
            b.encoder_period(0).unwrap().velocity_counts_per_s(clk),
            4000.0
        );
        assert_eq!(
            b.encoder_period(1).unwrap().velocity_counts_per_s(clk),
            -4000.0
        );
        assert!(b.encoder_period(2).unwrap().encoder_error());
        assert_eq!(b.encoder_period(3).unwrap().velocity_counts_per_s(clk), 0.0);
        assert_eq!(b.qtr1(3).unwrap().ticks(), 4);
        assert_eq!(b.qtr5(0).unwrap().ticks(), 5);
        assert_eq!(b.running(3), Some(0x8000_0000));
        assert!(b.motor_status(0).unwrap().amp_on());
        assert!(!b.motor_status(0).unwrap().current_check_trip());
        assert!(b.motor_status(3).unwrap().current_check_trip());
        assert_eq!(b.motor_status(4), None);
        assert_eq!(b.as_bytes(), &bytes[..]);
    }

    #[test]
    fn construct_block_fw8_qla() {
        let lay = BlockLayout::new(8, BoardKind::Qla).unwrap();
        let mut buf = vec![0xAAu8; lay.len_bytes()];
        let mut b = FeedbackBlock::new_checked(&mut buf[..], lay).unwrap();
        b.clear();
        b.set_timestamp(Timestamp::from_elapsed_ticks(49_153));
        b.set_status(BoardStatus::board_id_bits(6) | 0x000F_0F00);
        b.set_digital_io(DigitalIo(0xF));
        b.set_temperature(Temperature::from_celsius(40.0, 36.0));
        for (m, a) in [
            Adc::new(0x8000, 0x8000),
            Adc(0x7000_9000),
            Adc::new(1, 0xFFFF),
            Adc::new(0xFFFF, 0),
        ]
        .into_iter()
        .enumerate()
        {
            b.set_adc(m, a).unwrap();
        }
        b.set_encoder_position(0, EncoderPosition::from_counts(0))
            .unwrap();
        b.set_encoder_position(1, EncoderPosition::from_counts(100))
            .unwrap();
        b.set_encoder_position(2, EncoderPosition::from_counts(-100))
            .unwrap();
        b.set_encoder_position(3, EncoderPosition::from_counts(0).with_overflow(true))
            .unwrap();
        b.set_encoder_period(
            0,
            EncoderPeriod::from_velocity(4000.0, QLA_VELOCITY_CLOCK_HZ),
        )
        .unwrap();
        b.set_encoder_period(
            1,
            EncoderPeriod::from_velocity(-4000.0, QLA_VELOCITY_CLOCK_HZ),
        )
        .unwrap();
        b.set_encoder_period(
            2,
            EncoderPeriod::from_velocity(4000.0, QLA_VELOCITY_CLOCK_HZ).with_encoder_error(true),
        )
        .unwrap();
        b.set_encoder_period(3, EncoderPeriod(EncoderPeriod::OVERFLOW))
            .unwrap();
        for e in 0..4 {
            b.set_qtr1(e, Quarter(e as u32 + 1)).unwrap();
            b.set_qtr5(e, Quarter(e as u32 + 5)).unwrap();
            b.set_running(
                e,
                if e == 3 {
                    0x8000_0000
                } else {
                    0x10 * (e as u32 + 1)
                },
            )
            .unwrap();
            let trip = if e == 3 {
                motor_status_bits::QLA_CURRENT_CHECK_TRIP
            } else {
                0
            };
            b.set_motor_status(e, motor_status_bits::AMP_ON | trip | 0x8000)
                .unwrap();
        }
        assert_eq!(
            b.set_adc(4, Adc(0)).unwrap_err(),
            WireError::IndexOutOfRange { index: 4, count: 4 }
        );
        assert_eq!(buf, be_bytes(&BLOCK_FW8_QLA));
    }

    /// Every quadlet tagged with its group per the reference §2.2 table (literal ranges, not
    /// computed by the code under test): each accessor must land in its own group.
    fn check_groups(fw: u32, kind: BoardKind, groups: &[(u32, std::ops::Range<usize>)]) {
        let lay = BlockLayout::new(fw, kind).unwrap();
        let n = groups.last().unwrap().1.end;
        assert_eq!(lay.len_quadlets(), n);
        let mut q = vec![0u32; n];
        for (tag, r) in groups {
            for (k, i) in r.clone().enumerate() {
                q[i] = (tag << 24) | k as u32;
            }
        }
        let bytes = be_bytes(&q);
        let b = FeedbackBlock::new_checked(&bytes[..], lay).unwrap();
        assert_eq!(b.timestamp().0, 0);
        assert_eq!(b.status().raw, 1 << 24);
        for m in 0..lay.num_motors() {
            assert_eq!(b.adc(m).unwrap().0, (4 << 24) | m as u32);
            if let Some(ms) = b.motor_status(m) {
                assert_eq!(ms.raw, (10 << 24) | m as u32);
            }
        }
        for e in 0..lay.num_encoders() {
            assert_eq!(b.encoder_position(e).unwrap().0, (5 << 24) | e as u32);
            assert_eq!(b.encoder_period(e).unwrap().0, (6 << 24) | e as u32);
            assert_eq!(b.qtr1(e).unwrap().0, (7 << 24) | e as u32);
            assert_eq!(b.qtr5(e).unwrap().0, (8 << 24) | e as u32);
            assert_eq!(b.running(e).unwrap(), (9 << 24) | e as u32);
        }
        assert!(FeedbackBlock::new_checked(&bytes[..n * 4 - 1], lay).is_err());
    }

    #[test]
    fn group_offsets_every_layout() {
        check_groups(
            7,
            BoardKind::Qla,
            &[
                (0, 0..1),
                (1, 1..2),
                (2, 2..3),
                (3, 3..4),
                (4, 4..8),
                (5, 8..12),
                (6, 12..16),
                (7, 16..20),
                (8, 20..24),
                (9, 24..28),
            ],
        );
        let qla8 = [
            (0, 0..1),
            (1, 1..2),
            (2, 2..3),
            (3, 3..4),
            (4, 4..8),
            (5, 8..12),
            (6, 12..16),
            (7, 16..20),
            (8, 20..24),
            (9, 24..28),
            (10, 28..32),
        ];
        check_groups(8, BoardKind::Qla, &qla8);
        check_groups(9, BoardKind::Qla, &qla8);
        check_groups(
            8,
            BoardKind::Dqla,
            &[
                (0, 0..1),
                (1, 1..2),
                (2, 2..3),
                (3, 3..4),
                (4, 4..12),
                (5, 12..20),
                (6, 20..28),
                (7, 28..36),
                (8, 36..44),
                (9, 44..52),
                (10, 52..60),
            ],
        );
        check_groups(
            9,
            BoardKind::Drac,
            &[
                (0, 0..1),
                (1, 1..2),
                (2, 2..3),
                (3, 3..4),
                (4, 4..14),
                (5, 14..21),
                (6, 21..28),
                (7, 28..35),
                (8, 35..42),
                (9, 42..49),
                (10, 49..59),
            ],
        );
    }
}
