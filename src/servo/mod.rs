//! The servo layer: one blocking [`ServoBus`] trait for a chain of Dynamixel X-series servos,
//! and what is built on it.
//!
//! - [`ServoBus`]: ping, scan, register read/write, sync read/write, reboot, each call with its
//!   own timeout; a sync read goes out as Sync Read or, on a bus set to it ([`ReadKind`]), as
//!   Fast Sync Read; provided on top: [`ServoBus::read_states`] (present position and, when asked,
//!   velocity, current/load, voltage, temperature), [`ServoBus::write_goals`] (one Sync Write),
//!   torque, Hardware Error Status.
//! - [`dynamixel`]: the implementation over a serial port (`dynamixel2`; the only file that
//!   imports it), real hardware or the simulator's pseudo-terminal alike.
//! - [`limits`]: a wrapper implementing the same trait that clamps or refuses goals outside
//!   the joint limits.
//! - [`units`]: radians <-> ticks with per-joint offset and direction; raw units of velocity,
//!   current, voltage.
//! - [`arm`]: the configured joints on a bus: bring-up, pose read/write in radians, shut-down.
//! - [`lock`]: one owner per serial port: the exclusive lock taken before a port is opened.
//! - [`sysfs`]: the FTDI latency timer and the list of serial ports, read from sysfs.
//! - [`ports`]: several serial ports as one bus, each port's exchanges on its own thread.
//! - [`wire`]: the wire bound: a tick's bytes and time on the wire, the best rate.
//! - [`error`]: the typed errors.

pub mod admin;
pub mod arm;
pub mod clock;
pub mod dynamixel;
pub mod error;
pub mod limits;
pub mod lock;
pub mod model;
pub mod ports;
pub mod record;
pub mod sysfs;
pub mod units;
pub mod wire;

use std::time::Duration;

pub use error::{status_meaning, ErrorClass, HardwareErrors, ServoError};
pub use model::{model_name, ServoModel};

/// Broadcast id: every servo hears it.
pub const BROADCAST_ID: u8 = 0xFE;
/// Drive Mode bit 0: reverse direction (the program applies direction in software, so bring-up
/// requires it clear).
pub const DRIVE_MODE_REVERSE: i64 = 0x01;
/// Highest id a servo can have.
pub const MAX_ID: u8 = 252;
/// Baud rates an X-series servo can be set to, indexed by the Baud Rate register value.
pub const BAUD_RATES: [u32; 8] = [
    9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000,
];

/// The Baud Rate register value (0..=7) of a baud rate.
pub fn baud_index(baud: u32) -> Option<u8> {
    BAUD_RATES
        .iter()
        .position(|&b| b == baud)
        .and_then(|i| u8::try_from(i).ok())
}

/// Control table items of the X series this program uses (address and size).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Register {
    /// Model Number (0, 2 bytes).
    ModelNumber,
    /// Firmware Version (6, 1).
    FirmwareVersion,
    /// ID (7, 1; EEPROM).
    Id,
    /// Baud Rate (8, 1; EEPROM): index into [`BAUD_RATES`].
    BaudRate,
    /// Return Delay Time (9, 1; EEPROM): units of 2 µs.
    ReturnDelayTime,
    /// Drive Mode (10, 1; EEPROM).
    DriveMode,
    /// Operating Mode (11, 1; EEPROM): 3 = position.
    OperatingMode,
    /// Homing Offset (20, 4; EEPROM).
    HomingOffset,
    /// Temperature Limit (31, 1; EEPROM): °C; above it the servo raises its overheating error.
    TemperatureLimit,
    /// Max Voltage Limit (32, 2; EEPROM): units of 0.1 V.
    MaxVoltageLimit,
    /// Min Voltage Limit (34, 2; EEPROM): units of 0.1 V.
    MinVoltageLimit,
    /// Velocity Limit (44, 4; EEPROM).
    VelocityLimit,
    /// Max Position Limit (48, 4; EEPROM).
    MaxPositionLimit,
    /// Min Position Limit (52, 4; EEPROM).
    MinPositionLimit,
    /// Shutdown (63, 1; EEPROM): which hardware errors switch torque off.
    Shutdown,
    /// Torque Enable (64, 1).
    TorqueEnable,
    /// LED (65, 1).
    Led,
    /// Status Return Level (68, 1).
    StatusReturnLevel,
    /// Hardware Error Status (70, 1; read-only).
    HardwareErrorStatus,
    /// Bus Watchdog (98, 1, signed): units of 20 ms; -1 once it fired.
    BusWatchdog,
    /// Profile Acceleration (108, 4).
    ProfileAcceleration,
    /// Profile Velocity (112, 4).
    ProfileVelocity,
    /// Goal Position (116, 4, signed).
    GoalPosition,
    /// Moving (122, 1).
    Moving,
    /// Present Current (XM430, XL330) or Present Load (XL430) (126, 2, signed).
    PresentCurrent,
    /// Present Velocity (128, 4, signed).
    PresentVelocity,
    /// Present Position (132, 4, signed).
    PresentPosition,
    /// Present Input Voltage (144, 2): units of 0.1 V.
    PresentInputVoltage,
    /// Present Temperature (146, 1): °C.
    PresentTemperature,
    /// Indirect Address `n` (from 1; 168 + 2(n - 1), 2 bytes; RAM): the control-table address
    /// Indirect Data `n` stands for.
    IndirectAddress(u8),
}

impl Register {
    /// Address in the control table.
    pub fn address(self) -> u16 {
        match self {
            Self::ModelNumber => 0,
            Self::FirmwareVersion => 6,
            Self::Id => 7,
            Self::BaudRate => 8,
            Self::ReturnDelayTime => 9,
            Self::DriveMode => 10,
            Self::OperatingMode => 11,
            Self::HomingOffset => 20,
            Self::TemperatureLimit => 31,
            Self::MaxVoltageLimit => 32,
            Self::MinVoltageLimit => 34,
            Self::VelocityLimit => 44,
            Self::MaxPositionLimit => 48,
            Self::MinPositionLimit => 52,
            Self::Shutdown => 63,
            Self::TorqueEnable => 64,
            Self::Led => 65,
            Self::StatusReturnLevel => 68,
            Self::HardwareErrorStatus => 70,
            Self::BusWatchdog => 98,
            Self::ProfileAcceleration => 108,
            Self::ProfileVelocity => 112,
            Self::GoalPosition => 116,
            Self::Moving => 122,
            Self::PresentCurrent => 126,
            Self::PresentVelocity => 128,
            Self::PresentPosition => 132,
            Self::PresentInputVoltage => 144,
            Self::PresentTemperature => 146,
            Self::IndirectAddress(n) => INDIRECT_ADDRESS_1 + 2 * u16::from(n.saturating_sub(1)),
        }
    }

    /// Size in bytes (1, 2 or 4).
    pub fn size(self) -> u16 {
        match self {
            Self::ModelNumber
            | Self::MaxVoltageLimit
            | Self::MinVoltageLimit
            | Self::PresentCurrent
            | Self::PresentInputVoltage
            | Self::IndirectAddress(_) => 2,
            Self::HomingOffset
            | Self::VelocityLimit
            | Self::MaxPositionLimit
            | Self::MinPositionLimit
            | Self::ProfileAcceleration
            | Self::ProfileVelocity
            | Self::GoalPosition
            | Self::PresentVelocity
            | Self::PresentPosition => 4,
            _ => 1,
        }
    }

    /// Whether the value is signed (two's complement).
    pub fn signed(self) -> bool {
        matches!(
            self,
            Self::HomingOffset
                | Self::BusWatchdog
                | Self::GoalPosition
                | Self::PresentCurrent
                | Self::PresentVelocity
                | Self::PresentPosition
        )
    }

    /// Whether `value` fits the register's size and signedness.
    pub fn fits(self, value: i64) -> bool {
        let bits = u32::from(self.size()) * 8;
        if self.signed() {
            let half = 1i64 << (bits - 1);
            (-half..half).contains(&value)
        } else {
            (0..(1i64 << bits)).contains(&value)
        }
    }

    /// Little-endian bytes of `value` (which must fit): the first [`Register::size`] of them
    /// are the register's.
    pub fn encode(self, value: i64) -> [u8; 4] {
        let b = value.to_le_bytes();
        [b[0], b[1], b[2], b[3]]
    }

    /// The value of little-endian `bytes` (the register's size), sign-extended when signed.
    pub fn decode(self, bytes: &[u8]) -> Option<i64> {
        let n = usize::from(self.size());
        let b = bytes.get(..n)?;
        let mut raw = [0u8; 8];
        raw[..n].copy_from_slice(b);
        let unsigned = i64::from_le_bytes(raw);
        Some(if self.signed() {
            let shift = 64 - 8 * n as u32;
            (unsigned << shift) >> shift
        } else {
            unsigned
        })
    }
}

/// Which instruction reads a block from many servos in one exchange ([`ServoBus::sync_read_into`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ReadKind {
    /// Sync Read (0x82): every servo answers with its own status packet.
    #[default]
    Sync,
    /// Fast Sync Read (0x8A): one status packet carries every servo's block, one turnaround
    /// instead of one per servo (X430/X540 firmware 45 and later, X330 46 and later).
    Fast,
}

impl ReadKind {
    /// The read of a bus whose ports read with `kinds`: Fast Sync Read only when every port
    /// does (none: Sync Read).
    pub fn of_ports(kinds: &[Self]) -> Self {
        if !kinds.is_empty() && kinds.iter().all(|&k| k == Self::Fast) {
            Self::Fast
        } else {
            Self::Sync
        }
    }

    /// The name of the read of a bus whose ports read with `kinds`: the one every port uses,
    /// or `"mixed"` when they differ (a port with a servo that cannot answer Fast Sync Read
    /// reads with Sync Read, the others fast); `describe`'s `read`, and the logs'.
    pub fn name_of_ports(kinds: &[Self]) -> &'static str {
        match kinds {
            [first, rest @ ..] if rest.iter().all(|k| k == first) => first.as_str(),
            [] => Self::Sync.as_str(),
            _ => "mixed",
        }
    }

    /// `"sync"` or `"fast"`, as in the config and the protocol.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Sync => "sync",
            Self::Fast => "fast",
        }
    }
}

impl std::fmt::Display for ReadKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// `[bus] read`: the read kind bring-up is to set on each port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ReadChoice {
    /// Fast Sync Read where every servo of the port supports it, Sync Read otherwise.
    #[default]
    Auto,
    /// Fast Sync Read; bring-up refuses a servo that cannot do it, naming it.
    Fast,
    /// Sync Read always.
    Sync,
}

/// A servo's answer to a ping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PingInfo {
    /// Its id.
    pub id: u8,
    /// Model Number.
    pub model: u16,
    /// Firmware version.
    pub firmware: u8,
    /// The alert flag: a hardware error is latched.
    pub alert: bool,
}

/// A successful reply without data (write, reboot).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ack {
    /// The servo.
    pub id: u8,
    /// The alert flag: a hardware error is latched (the instruction was carried out).
    pub alert: bool,
}

/// A register's value as read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Value {
    /// The value, sign-extended for signed registers.
    pub value: i64,
    /// The alert flag.
    pub alert: bool,
}

/// The bytes one servo returned in a sync read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Block {
    /// The servo.
    pub id: u8,
    /// The bytes read, starting at the requested address.
    pub data: Vec<u8>,
    /// The alert flag.
    pub alert: bool,
}

/// One goal of a sync write: servo and position in ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Goal {
    /// The servo.
    pub id: u8,
    /// Goal Position, ticks.
    pub ticks: i32,
}

/// Which present values to read besides the position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Fields {
    /// Present Velocity.
    pub velocity: bool,
    /// Present Current (or Load, on an XL430).
    pub current: bool,
    /// Present Input Voltage.
    pub voltage: bool,
    /// Present Temperature.
    pub temperature: bool,
}

impl Fields {
    /// Position only.
    pub const POSITION: Fields = Fields {
        velocity: false,
        current: false,
        voltage: false,
        temperature: false,
    };
    /// Everything.
    pub const ALL: Fields = Fields {
        velocity: true,
        current: true,
        voltage: true,
        temperature: true,
    };

    /// The contiguous block (address, length) a sync read of these fields covers.
    pub fn span(self) -> (u16, u16) {
        let mut start = Register::PresentPosition.address();
        let mut end = start + Register::PresentPosition.size();
        for (on, r) in [
            (self.velocity, Register::PresentVelocity),
            (self.current, Register::PresentCurrent),
            (self.voltage, Register::PresentInputVoltage),
            (self.temperature, Register::PresentTemperature),
        ] {
            if on {
                start = start.min(r.address());
                end = end.max(r.address() + r.size());
            }
        }
        (start, end - start)
    }
}

/// Address of Indirect Address 1 on every X-series model (RAM: it resets at power-on and
/// reboot, and can be written with torque on).
pub const INDIRECT_ADDRESS_1: u16 = 168;

/// The registers [`Layout::Indirect`] gathers, in order: every byte of each is mapped to one
/// Indirect Address, so one read of [`INDIRECT_BYTES`] bytes of Indirect Data returns them all.
pub const INDIRECT_REGISTERS: [Register; 5] = [
    Register::PresentCurrent,
    Register::PresentVelocity,
    Register::PresentPosition,
    Register::PresentInputVoltage,
    Register::PresentTemperature,
];

/// Bytes of the indirect block: load/current 2, velocity 4, position 4, voltage 2,
/// temperature 1.
pub const INDIRECT_BYTES: u16 = 13;

/// The Indirect Address just past the block, mapped to Bus Watchdog (98): a read of
/// [`INDIRECT_BYTES`] + 1 bytes (`Layout::Indirect { watchdog: true, .. }`) brings it too,
/// one byte a servo more than the ordinary read.
pub const INDIRECT_WATCHDOG: u8 = 14;

/// Where a read finds a servo's present values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// The present registers themselves: the contiguous span of these fields (position and
    /// velocity are 8 bytes, everything 21).
    Direct(Fields),
    /// Every field, gathered through Indirect Address 1.. into 13 contiguous bytes of Indirect
    /// Data from this address (224 on X430/X540, 208 on XL330): the registers
    /// [`INDIRECT_REGISTERS`] mapped, in order. A servo that lost its RAM (power, reboot)
    /// reads zeros there until mapped again: [`ServoError::Unmapped`].
    Indirect {
        /// Indirect Data 1's address.
        data: u16,
        /// The read extends one byte, to Bus Watchdog (98) mapped through Indirect Address
        /// [`INDIRECT_WATCHDOG`] ([`ServoState::watchdog`]).
        watchdog: bool,
    },
}

impl Layout {
    /// The block (address, length) one read covers.
    pub fn span(self) -> (u16, u16) {
        match self {
            Layout::Direct(fields) => fields.span(),
            Layout::Indirect { data, watchdog } => (data, INDIRECT_BYTES + u16::from(watchdog)),
        }
    }

    /// This layout, its read extended to Bus Watchdog (`watchdog`) or not; a
    /// [`Layout::Direct`] has no such extension and is returned as it is.
    pub fn with_watchdog(self, watchdog: bool) -> Layout {
        match self {
            Layout::Indirect { data, .. } => Layout::Indirect { data, watchdog },
            direct => direct,
        }
    }

    /// The fields a read brings.
    pub fn fields(self) -> Fields {
        match self {
            Layout::Direct(fields) => fields,
            Layout::Indirect { .. } => Fields::ALL,
        }
    }

    /// The value of Indirect Address `n` (1-based) in the indirect layout: the control-table
    /// address of the block's `n`-th byte, Bus Watchdog's for [`INDIRECT_WATCHDOG`]. `None`
    /// past that.
    pub fn indirect_target(n: u8) -> Option<u16> {
        if n == INDIRECT_WATCHDOG {
            return Some(Register::BusWatchdog.address());
        }
        let mut k = u16::from(n).checked_sub(1)?;
        for r in INDIRECT_REGISTERS {
            if k < r.size() {
                return Some(r.address() + k);
            }
            k -= r.size();
        }
        None
    }

    /// Decode servo `id`'s bytes of this layout.
    pub fn decode(self, id: u8, data: &[u8], alert: bool) -> Result<ServoState, ServoError> {
        match self {
            Layout::Direct(fields) => ServoState::decode(id, data, alert, fields),
            Layout::Indirect { .. } => {
                let (_, len) = self.span();
                if data.len() != usize::from(len) {
                    return Err(ServoError::Malformed {
                        id,
                        what: format!("{} data bytes, expected {len}", data.len()),
                    });
                }
                let mut at = 0;
                let mut values = [0i64; 5];
                for (value, r) in values.iter_mut().zip(INDIRECT_REGISTERS) {
                    let size = usize::from(r.size());
                    *value = data
                        .get(at..at + size)
                        .and_then(|b| r.decode(b))
                        .unwrap_or(0);
                    at += size;
                }
                let [current, velocity, position, voltage, temperature] = values;
                // A powered servo never reads 0 V: its Indirect Addresses are back at their
                // defaults (each Indirect Data reads itself, 0).
                if voltage == 0 && temperature == 0 {
                    return Err(ServoError::Unmapped { id });
                }
                Ok(ServoState {
                    id,
                    position_ticks: i32::try_from(position).unwrap_or_default(),
                    velocity: i32::try_from(velocity).ok(),
                    current: i16::try_from(current).ok(),
                    voltage_dv: u16::try_from(voltage).ok(),
                    temperature_c: u8::try_from(temperature).ok(),
                    // The byte past the block, signed (-1: fired).
                    watchdog: data
                        .get(usize::from(INDIRECT_BYTES))
                        .map(|&b| i8::from_le_bytes([b])),
                    alert,
                })
            }
        }
    }
}

impl From<Fields> for Layout {
    fn from(fields: Fields) -> Self {
        Layout::Direct(fields)
    }
}

/// Present values of one servo, in the servo's raw units (see [`units`] for conversions).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServoState {
    /// The servo.
    pub id: u8,
    /// Present Position, ticks.
    pub position_ticks: i32,
    /// Present Velocity, units of 0.229 rev/min.
    pub velocity: Option<i32>,
    /// Present Current (XM430 2.69 mA, XL330 1 mA units) or Load (XL430, 0.1 %).
    pub current: Option<i16>,
    /// Present Input Voltage, units of 0.1 V.
    pub voltage_dv: Option<u16>,
    /// Present Temperature, °C.
    pub temperature_c: Option<u8>,
    /// Bus Watchdog (98), when the read brought it: -1 once it fired (the servo stopped and
    /// refuses goals until 0 is written there), else the period it is armed with (20 ms units;
    /// 0: off).
    pub watchdog: Option<i8>,
    /// The alert flag: a hardware error is latched.
    pub alert: bool,
}

impl ServoState {
    /// Decode a sync-read block of `fields` (as laid out by [`Fields::span`]).
    pub fn from_block(block: &Block, fields: Fields) -> Result<Self, ServoError> {
        Self::decode(block.id, &block.data, block.alert, fields)
    }

    /// Decode servo `id`'s sync-read bytes of `fields` (as laid out by [`Fields::span`]).
    pub fn decode(id: u8, data: &[u8], alert: bool, fields: Fields) -> Result<Self, ServoError> {
        let (start, len) = fields.span();
        if data.len() != usize::from(len) {
            return Err(ServoError::Malformed {
                id,
                what: format!("{} data bytes, expected {len}", data.len()),
            });
        }
        let get = |r: Register| -> Option<i64> {
            let off = usize::from(r.address().checked_sub(start)?);
            r.decode(data.get(off..)?)
        };
        let want = |on: bool, r: Register| if on { get(r) } else { None };
        Ok(Self {
            id,
            position_ticks: get(Register::PresentPosition)
                .and_then(|v| i32::try_from(v).ok())
                .unwrap_or_default(),
            velocity: want(fields.velocity, Register::PresentVelocity)
                .and_then(|v| i32::try_from(v).ok()),
            current: want(fields.current, Register::PresentCurrent)
                .and_then(|v| i16::try_from(v).ok()),
            voltage_dv: want(fields.voltage, Register::PresentInputVoltage)
                .and_then(|v| u16::try_from(v).ok()),
            temperature_c: want(fields.temperature, Register::PresentTemperature)
                .and_then(|v| u8::try_from(v).ok()),
            watchdog: None,
            alert,
        })
    }
}

/// The result of reading one servo in a sync read: its values, or what went wrong with it.
pub type Reading = Result<ServoState, ServoError>;

/// Caller-owned buffers of one Sync Read: the data of every servo side by side and, per servo,
/// its alert flag or its error. Reused from call to call, so a warm read allocates nothing.
#[derive(Debug, Default)]
pub struct SyncReadBuf {
    len: usize,
    data: Vec<u8>,
    status: Vec<Result<bool, ServoError>>,
}

impl SyncReadBuf {
    /// Empty buffers (they grow to the first read's size).
    pub fn new() -> Self {
        Self::default()
    }

    /// Make room for `servos` blocks of `len` bytes, every one marked as not yet heard from
    /// (a timeout of `waited` naming its id in `ids`).
    pub fn reset(&mut self, ids: &[u8], len: u16, waited: Duration) {
        self.len = usize::from(len);
        self.data.clear();
        self.data.resize(ids.len() * self.len, 0);
        self.status.clear();
        self.status.extend(
            ids.iter()
                .map(|&id| Err(ServoError::Timeout { id, waited })),
        );
    }

    /// Servos in the last read.
    pub fn servos(&self) -> usize {
        self.status.len()
    }

    /// Store servo `index`'s reply: its bytes (exactly the block's length) and alert flag.
    pub fn set(&mut self, index: usize, data: &[u8], alert: bool) {
        if let (Some(slot), Some(status)) = (
            self.data.get_mut(index * self.len..(index + 1) * self.len),
            self.status.get_mut(index),
        ) {
            if slot.len() == data.len() {
                slot.copy_from_slice(data);
                *status = Ok(alert);
            }
        }
    }

    /// Store what went wrong with servo `index`.
    pub fn fail(&mut self, index: usize, error: ServoError) {
        if let Some(status) = self.status.get_mut(index) {
            *status = Err(error);
        }
    }

    /// Servo `index`'s bytes and alert flag, or its error.
    pub fn get(&self, index: usize) -> Result<(&[u8], bool), &ServoError> {
        match self.status.get(index) {
            Some(Ok(alert)) => Ok((
                self.data
                    .get(index * self.len..(index + 1) * self.len)
                    .unwrap_or_default(),
                *alert,
            )),
            Some(Err(e)) => Err(e),
            None => Ok((&[], false)),
        }
    }

    /// Servo `index`'s error, moved out (its slot then reads as an empty reply).
    fn take_error(&mut self, index: usize) -> Option<ServoError> {
        match self.status.get_mut(index) {
            Some(slot @ Err(_)) => std::mem::replace(slot, Ok(false)).err(),
            _ => None,
        }
    }
}

/// Caller-owned buffers of [`ServoBus::read_states_into`]: the raw sync read and the decoded
/// readings, reused from call to call.
#[derive(Debug, Default)]
pub struct States {
    raw: SyncReadBuf,
    readings: Vec<Reading>,
}

impl States {
    /// Empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// The readings of the last read, in the order of its ids.
    pub fn readings(&self) -> &[Reading] {
        &self.readings
    }

    /// The readings, to move them out.
    pub fn readings_mut(&mut self) -> &mut Vec<Reading> {
        &mut self.readings
    }
}

/// A blocking bus of Dynamixel Protocol 2.0 servos.
///
/// Every call that waits for a reply takes a `timeout`: how long to wait for each reply beyond
/// its wire time (a servo that stays silent costs exactly that). Errors name the servo.
/// Implementations: [`dynamixel::DynamixelBus`] (a serial port: hardware or the simulator),
/// [`limits::Limited`] (a safety wrapper around another bus), [`record::Recording`] (logs every
/// instruction). The `_into` calls fill caller-owned buffers and allocate nothing once warm:
/// they are the control loop's; the others are conveniences built on them.
pub trait ServoBus {
    /// The bus baud rate.
    fn baud(&self) -> u32;

    /// Change the port's baud rate (after the servos were told to change theirs, or to scan).
    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError>;

    /// Ping one servo: model number and firmware.
    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError>;

    /// Ping one servo and listen on for a second reply: the first good reply, and how many
    /// replies (damaged ones included) `id` got. More than one means servos share the id, which
    /// a plain [`ServoBus::ping`] cannot tell. A bus that cannot tell counts one.
    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        self.ping(id, timeout).map(|p| (p, 1))
    }

    /// Broadcast ping: every reply, in id order; an id listed twice was answered twice (servos
    /// sharing it). Listens for every id's slot and
    /// reply, up to id 252, plus `timeout` (see [`dynamixel::scan_window`]): under a second
    /// at 1 Mbps, whatever the ids.
    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError>;

    /// Read one register.
    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError>;

    /// Write one register and wait for the servo's acknowledgement.
    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError>;

    /// One Sync Read (or Fast Sync Read, see [`ServoBus::read_kind`]) of `len` bytes at
    /// `address` from every servo in `ids` (no repeats), into `out`. The error is the bus's (the
    /// instruction could not be sent); each servo's own outcome is in `out`, in the order of
    /// `ids`: a silent servo costs its `timeout`, the others' data still arrive.
    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError>;

    /// One Sync Write of `register` to every servo in `values` (id, value); servos do not reply.
    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError>;

    /// Goal positions for every servo in `goals`, in one Sync Write.
    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError>;

    /// Reboot one servo (clears a latched hardware error; torque comes back off).
    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError>;

    /// The instruction [`ServoBus::sync_read_into`] sends: Sync Read unless the bus was set to
    /// Fast Sync Read.
    fn read_kind(&self) -> ReadKind {
        ReadKind::Sync
    }

    /// Make [`ServoBus::sync_read_into`] send `kind` from now on (bring-up decides, from every
    /// servo's model and firmware). A bus that cannot frame Fast Sync Read refuses it with
    /// [`ServoError::Unsupported`] (the default).
    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        match kind {
            ReadKind::Sync => Ok(()),
            ReadKind::Fast => Err(ServoError::Unsupported {
                what: "this bus does not speak Fast Sync Read",
            }),
        }
    }

    /// Each port's USB-serial adapter, where the bus knows it (an FTDI latency timer found when
    /// the port opened), in the order of [`ServoBus::read_kinds`]: for the wire bound.
    fn adapters(&self) -> Vec<Option<wire::Adapter>> {
        vec![None]
    }

    /// Which of the bus's ports servo `id` is on, from 0 in the order of
    /// [`ServoBus::read_kinds`] (always 0 on a bus of one port).
    fn port_index(&self, _id: u8) -> usize {
        0
    }

    /// Port `port` (as [`ServoBus::port_index`] counts) of a bus of several failed and is not
    /// open again yet, so its servos cannot be reached while the others can. Always false on a
    /// bus of one port, whose failure its caller sees in every exchange.
    fn port_failed(&self, _port: usize) -> bool {
        false
    }

    /// Each port's [`ServoBus::read_kind`], in port order: one entry on a bus of one port.
    fn read_kinds(&self) -> Vec<ReadKind> {
        vec![self.read_kind()]
    }

    /// [`ServoBus::set_read_kind`] port by port, `kinds` in the order of
    /// [`ServoBus::read_kinds`]; a bus of one port takes one kind (or several all alike).
    fn set_read_kinds(&mut self, kinds: &[ReadKind]) -> Result<(), ServoError> {
        match kinds {
            [first, rest @ ..] if rest.iter().all(|k| k == first) => self.set_read_kind(*first),
            _ => Err(ServoError::Unsupported {
                what: "a bus of one port reads one way",
            }),
        }
    }

    /// [`ServoBus::sync_read_into`] into fresh buffers: one result per servo of `ids`.
    fn sync_read(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
    ) -> Result<Vec<Result<Block, ServoError>>, ServoError> {
        let mut buf = SyncReadBuf::new();
        self.sync_read_into(ids, address, len, timeout, &mut buf)?;
        Ok(ids
            .iter()
            .enumerate()
            .map(|(i, &id)| match buf.take_error(i) {
                Some(e) => Err(e),
                None => buf.get(i).map_or_else(
                    |_| {
                        Err(ServoError::Timeout {
                            id,
                            waited: timeout,
                        })
                    },
                    |(data, alert)| {
                        Ok(Block {
                            id,
                            data: data.to_vec(),
                            alert,
                        })
                    },
                ),
            })
            .collect())
    }

    /// Present position (and the asked `fields`) of every servo in `ids`, in one Sync Read,
    /// into `out` (see [`States::readings`]).
    fn read_states_into(
        &mut self,
        ids: &[u8],
        fields: Fields,
        timeout: Duration,
        out: &mut States,
    ) -> Result<(), ServoError> {
        self.read_block_into(ids, Layout::Direct(fields), timeout, out)
    }

    /// The present values `layout` says where to find, of every servo in `ids`, in one Sync
    /// Read, into `out` (see [`States::readings`]).
    fn read_block_into(
        &mut self,
        ids: &[u8],
        layout: Layout,
        timeout: Duration,
        out: &mut States,
    ) -> Result<(), ServoError> {
        let (address, len) = layout.span();
        out.readings.clear();
        self.sync_read_into(ids, address, len, timeout, &mut out.raw)?;
        for (i, &id) in ids.iter().enumerate() {
            let reading = match out.raw.take_error(i) {
                Some(e) => Err(e),
                None => match out.raw.get(i) {
                    Ok((data, alert)) => layout.decode(id, data, alert),
                    Err(_) => Err(ServoError::Timeout {
                        id,
                        waited: timeout,
                    }),
                },
            };
            out.readings.push(reading);
        }
        Ok(())
    }

    /// Present position (and the asked `fields`) of every servo in `ids`, in one Sync Read.
    fn read_states(
        &mut self,
        ids: &[u8],
        fields: Fields,
        timeout: Duration,
    ) -> Result<Vec<Reading>, ServoError> {
        let mut out = States::new();
        self.read_states_into(ids, fields, timeout, &mut out)?;
        Ok(out.readings)
    }

    /// Torque on or off for one servo.
    fn set_torque(&mut self, id: u8, on: bool, timeout: Duration) -> Result<Ack, ServoError> {
        self.write(id, Register::TorqueEnable, i64::from(on), timeout)
    }

    /// Hardware Error Status of one servo.
    fn hardware_errors(&mut self, id: u8, timeout: Duration) -> Result<HardwareErrors, ServoError> {
        let v = self.read(id, Register::HardwareErrorStatus, timeout)?;
        Ok(HardwareErrors(u8::try_from(v.value).unwrap_or(u8::MAX)))
    }

    /// Close the port for good, its lock included, so that it can be opened again after it
    /// failed: every exchange afterwards fails as on a vanished port. A bus without a port of
    /// its own has nothing to give up (the default).
    fn close(&mut self) {}
}

/// A bus borrowed is the bus: every call, provided ones included, goes to the implementation's
/// own (a wrapper that overrides [`ServoBus::write_goals`] is not bypassed by a reference).
impl<B: ServoBus + ?Sized> ServoBus for &mut B {
    fn baud(&self) -> u32 {
        (**self).baud()
    }
    fn close(&mut self) {
        (**self).close()
    }
    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        (**self).set_baud(baud)
    }
    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        (**self).ping(id, timeout)
    }
    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        (**self).ping_counted(id, timeout)
    }
    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        (**self).scan(timeout)
    }
    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError> {
        (**self).read(id, register, timeout)
    }
    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError> {
        (**self).write(id, register, value, timeout)
    }
    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        (**self).sync_read_into(ids, address, len, timeout, out)
    }
    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        (**self).sync_write(register, values)
    }
    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        (**self).write_goals(goals)
    }
    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        (**self).reboot(id, timeout)
    }
    fn read_kind(&self) -> ReadKind {
        (**self).read_kind()
    }
    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        (**self).set_read_kind(kind)
    }
    fn port_index(&self, id: u8) -> usize {
        (**self).port_index(id)
    }
    fn port_failed(&self, port: usize) -> bool {
        (**self).port_failed(port)
    }
    fn adapters(&self) -> Vec<Option<wire::Adapter>> {
        (**self).adapters()
    }
    fn read_kinds(&self) -> Vec<ReadKind> {
        (**self).read_kinds()
    }
    fn set_read_kinds(&mut self, kinds: &[ReadKind]) -> Result<(), ServoError> {
        (**self).set_read_kinds(kinds)
    }
    fn sync_read(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
    ) -> Result<Vec<Result<Block, ServoError>>, ServoError> {
        (**self).sync_read(ids, address, len, timeout)
    }
    fn read_states_into(
        &mut self,
        ids: &[u8],
        fields: Fields,
        timeout: Duration,
        out: &mut States,
    ) -> Result<(), ServoError> {
        (**self).read_states_into(ids, fields, timeout, out)
    }
    fn read_states(
        &mut self,
        ids: &[u8],
        fields: Fields,
        timeout: Duration,
    ) -> Result<Vec<Reading>, ServoError> {
        (**self).read_states(ids, fields, timeout)
    }
    fn read_block_into(
        &mut self,
        ids: &[u8],
        layout: Layout,
        timeout: Duration,
        out: &mut States,
    ) -> Result<(), ServoError> {
        (**self).read_block_into(ids, layout, timeout, out)
    }
    fn set_torque(&mut self, id: u8, on: bool, timeout: Duration) -> Result<Ack, ServoError> {
        (**self).set_torque(id, on, timeout)
    }
    fn hardware_errors(&mut self, id: u8, timeout: Duration) -> Result<HardwareErrors, ServoError> {
        (**self).hardware_errors(id, timeout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bus_whose_ports_read_differently_reads_mixed_and_fast_only_when_all_do() {
        use ReadKind::{Fast, Sync};
        assert_eq!(ReadKind::name_of_ports(&[Fast, Fast]), "fast");
        assert_eq!(ReadKind::name_of_ports(&[Sync]), "sync");
        assert_eq!(ReadKind::name_of_ports(&[Fast, Sync]), "mixed");
        assert_eq!(ReadKind::name_of_ports(&[]), "sync");
        assert_eq!(ReadKind::of_ports(&[Fast, Sync]), Sync);
        assert_eq!(ReadKind::of_ports(&[Fast, Fast]), Fast);
    }

    #[test]
    fn registers_encode_decode_and_fit() {
        assert_eq!(
            Register::GoalPosition.decode(&(-5i32).to_le_bytes()),
            Some(-5)
        );
        assert_eq!(Register::BusWatchdog.decode(&[0xFF]), Some(-1));
        assert_eq!(Register::ModelNumber.decode(&[0x24, 0x04]), Some(1060));
        assert_eq!(Register::GoalPosition.encode(-2), [0xFE, 0xFF, 0xFF, 0xFF]);
        assert_eq!(Register::ProfileVelocity.encode(300), [0x2C, 0x01, 0, 0]);
        assert!(Register::ReturnDelayTime.fits(254) && !Register::ReturnDelayTime.fits(256));
        assert!(Register::BusWatchdog.fits(-1) && !Register::BusWatchdog.fits(128));
        assert!(!Register::TorqueEnable.fits(-1));
    }

    #[test]
    fn the_indirect_block_is_thirteen_bytes_of_five_registers() {
        let targets: Vec<u16> = (1..=13).filter_map(Layout::indirect_target).collect();
        assert_eq!(
            targets,
            [126, 127, 128, 129, 130, 131, 132, 133, 134, 135, 144, 145, 146]
        );
        assert_eq!(Layout::indirect_target(0), None);
        assert_eq!(Layout::indirect_target(INDIRECT_WATCHDOG), Some(98));
        assert_eq!(Layout::indirect_target(15), None);
        assert_eq!(Register::IndirectAddress(1).address(), 168);
        assert_eq!(Register::IndirectAddress(13).address(), 192);
        let layout = Layout::Indirect {
            data: 224,
            watchdog: false,
        };
        assert_eq!(layout.span(), (224, 13));
        assert_eq!(layout.fields(), Fields::ALL);
        // Load -5, velocity 300, position -7, 12.0 V, 41 °C.
        let mut data = Vec::new();
        data.extend_from_slice(&(-5i16).to_le_bytes());
        data.extend_from_slice(&300i32.to_le_bytes());
        data.extend_from_slice(&(-7i32).to_le_bytes());
        data.extend_from_slice(&120u16.to_le_bytes());
        data.push(41);
        let s = layout
            .decode(3, &data, true)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (s.current, s.velocity, s.position_ticks),
            (Some(-5), Some(300), -7)
        );
        assert_eq!(
            (s.voltage_dv, s.temperature_c, s.watchdog, s.alert),
            (Some(120), Some(41), None, true)
        );
        // Extended by one byte, the read brings Bus Watchdog: -1 once it fired.
        let extended = layout.with_watchdog(true);
        assert_eq!(extended.span(), (224, 14));
        data.push(0xFF);
        let s = extended
            .decode(3, &data, false)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((s.watchdog, s.position_ticks), (Some(-1), -7));
        assert!(matches!(
            layout.decode(3, &data, false),
            Err(ServoError::Malformed { id: 3, .. })
        ));
        data.pop();
        // A servo whose RAM was reset reads its Indirect Data as 0: not a pose at -180°.
        assert!(matches!(
            layout.decode(3, &[0; 13], false),
            Err(ServoError::Unmapped { id: 3 })
        ));
        assert!(matches!(
            layout.decode(3, &data[..12], false),
            Err(ServoError::Malformed { id: 3, .. })
        ));
        // Every known model maps its Indirect Data where the e-manual puts it.
        let data_of = |name| ServoModel::from_name(name).and_then(ServoModel::indirect_data);
        assert_eq!(data_of("XM430-W350"), Some(224));
        assert_eq!(data_of("XL330-M288"), Some(208));
    }

    #[test]
    fn field_spans_are_contiguous() {
        assert_eq!(Fields::POSITION.span(), (132, 4));
        let with_velocity = Fields {
            velocity: true,
            ..Fields::POSITION
        };
        assert_eq!(with_velocity.span(), (128, 8));
        assert_eq!(Fields::ALL.span(), (126, 21));
        let block = Block {
            id: 3,
            data: (0..21).collect(),
            alert: true,
        };
        let s = ServoState::from_block(&block, Fields::ALL).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.position_ticks, i32::from_le_bytes([6, 7, 8, 9]));
        assert_eq!(s.temperature_c, Some(20));
        assert!(s.alert);
    }
}
