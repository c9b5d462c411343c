//! One virtual servo: its control table memory, the write rules, the hardware-error and watchdog
//! logic, and a motor model stepped on `dt`.
//!
//! Rules applied to a write (first failure wins, nothing is written on failure):
//! - the block must start at an item and cover whole items; an undefined address, a read-only
//!   item, or an EEPROM item (below 64) while Torque Enable is 1: access error (7);
//! - a block that ends inside an item: data length error (5);
//! - a value outside the item's own range: data range error (4); outside a limit item (Goal
//!   Position beyond Min/Max Position Limit in position mode, Goal PWM/Current/Velocity beyond
//!   their limits): data limit error (6);
//! - after the Bus Watchdog fired (it reads -1), Goal PWM/Current/Velocity/Position: data range
//!   error until 0 is written to the watchdog;
//! - Torque Enable = 1 while a shutdown error is latched: result fail (1); only REBOOT clears it.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::protocol::error;
use crate::table::{addr, hw, Access, ControlTable, Item, Model, Range};

/// Ticks per second for one unit of velocity (0.229 rev/min, 4096 ticks per revolution).
pub const VELOCITY_UNIT_TICKS_S: f64 = 0.229 * 4096.0 / 60.0;
/// Ticks per second squared for one unit of Profile Acceleration (214.577 rev/min^2).
pub const ACCEL_UNIT_TICKS_S2: f64 = 214.577 * 4096.0 / 3600.0;
/// Largest motor-model integration step.
const MAX_STEP: Duration = Duration::from_millis(1);
/// Time the unloaded motor takes to reach its top speed when no profile acceleration is set.
const PHYSICAL_RISE_S: f64 = 0.05;
/// Present PWM at full effort (100 %), PWM units (0.113 %).
const FULL_PWM: f64 = 885.0;
/// Multi-turn range of Goal Position in extended position modes.
const MULTI_TURN_LIMIT: i64 = 1_048_575;
/// Startup Configuration (60) bit 0: torque on at power-on.
const STARTUP_TORQUE_ON: i64 = 1 << 0;
/// Startup Configuration (60) bit 1: the backed-up RAM items restored at power-on.
const STARTUP_RAM_RESTORE: i64 = 1 << 1;

/// Initial settings of one servo, from the simulator's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoSpec {
    /// Bus id (0..=252).
    pub id: u8,
    /// Model (selects the control table).
    pub model: Model,
    /// Min Position Limit written into EEPROM at start (factory value 0).
    pub min_position_ticks: Option<u32>,
    /// Max Position Limit written into EEPROM at start (factory value 4095).
    pub max_position_ticks: Option<u32>,
    /// Physical position at power-on (default 2048, the middle).
    pub initial_position_ticks: Option<i32>,
    /// Firmware Version (address 6, and the ping's third byte); the model's table value
    /// ([`DEFAULT_FIRMWARE`]) when `None`. Below [`Model::fast_read_firmware`] the servo does not
    /// know Fast Sync Read nor Fast Bulk Read.
    pub firmware: Option<u8>,
}

/// The firmware version a simulated servo reports unless its spec says otherwise: one that
/// answers Fast Sync Read and Fast Bulk Read on every simulated model.
pub const DEFAULT_FIRMWARE: u8 = 48;

impl ServoSpec {
    /// A servo with factory limits, starting at the middle position.
    pub fn new(id: u8, model: Model) -> Self {
        Self {
            id,
            model,
            min_position_ticks: None,
            max_position_ticks: None,
            initial_position_ticks: None,
            firmware: None,
        }
    }
}

/// One virtual servo.
#[derive(Debug, Clone)]
pub struct Servo {
    table: Arc<ControlTable>,
    mem: Vec<u8>,
    /// Physical shaft position, ticks (continuous, multi-turn).
    pos: f64,
    /// Shaft velocity, ticks/s.
    vel: f64,
    /// Last acceleration, ticks/s^2 (for the load estimate).
    acc: f64,
    temperature_c: f64,
    voltage_dv: f64,
    registered: Option<(u16, Vec<u8>)>,
    last_update: Instant,
    last_rx: Instant,
    boot: Instant,
    silent: bool,
    /// Held by an obstacle (a blocked fault): the shaft stays where it is whatever the goal.
    blocked: bool,
    /// How often the Bus Watchdog has fired since the simulator started.
    watchdog_fires: u32,
    /// A hardware error selected by Shutdown switched torque off: it stays off until a reboot,
    /// whatever Shutdown says since.
    shut_down: bool,
    /// Firmware Version.
    firmware: u8,
    /// Booting after REBOOT or a factory reset until this instant: it neither hears nor answers.
    booting_until: Option<Instant>,
    /// The control table as the last Control Table Backup stored it (the servo's flash: it
    /// survives reboots, power cycles and factory resets).
    backup: Option<Vec<u8>>,
}

fn encode_le(value: i64, size: u8) -> [u8; 4] {
    let b = (value as i32).to_le_bytes();
    match size {
        1 => [b[0], 0, 0, 0],
        2 => [b[0], b[1], 0, 0],
        _ => b,
    }
}

fn decode_le(bytes: &[u8], signed: bool) -> i64 {
    match (bytes.len(), signed) {
        (1, false) => i64::from(bytes[0]),
        (1, true) => i64::from(bytes[0] as i8),
        (2, false) => i64::from(u16::from_le_bytes([bytes[0], bytes[1]])),
        (2, true) => i64::from(i16::from_le_bytes([bytes[0], bytes[1]])),
        (4, false) => i64::from(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])),
        (4, true) => i64::from(i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])),
        _ => 0,
    }
}

impl Servo {
    /// Power on a servo from its spec at `now`. `baud_index` and `return_delay` (2 µs units) are
    /// written into EEPROM so the servo talks at the bus settings.
    pub fn new(spec: &ServoSpec, baud_index: u8, return_delay: u8, now: Instant) -> Self {
        let table = Arc::new(ControlTable::for_model(spec.model));
        let firmware = spec.firmware.unwrap_or(table.firmware_version);
        let mut servo = Self {
            mem: vec![0; usize::from(table.memory_size)],
            table,
            pos: f64::from(spec.initial_position_ticks.unwrap_or(2048)),
            vel: 0.0,
            acc: 0.0,
            temperature_c: 0.0,
            voltage_dv: 0.0,
            registered: None,
            last_update: now,
            last_rx: now,
            watchdog_fires: 0,
            boot: now,
            silent: false,
            blocked: false,
            shut_down: false,
            firmware,
            booting_until: None,
            backup: None,
        };
        servo.load_defaults(true, true);
        servo.put(addr::ID, i64::from(spec.id));
        servo.put(addr::BAUD_RATE, i64::from(baud_index));
        servo.put(addr::RETURN_DELAY_TIME, i64::from(return_delay));
        if let Some(min) = spec.min_position_ticks {
            servo.put(addr::MIN_POSITION_LIMIT, i64::from(min));
        }
        if let Some(max) = spec.max_position_ticks {
            servo.put(addr::MAX_POSITION_LIMIT, i64::from(max));
        }
        servo.power_on(now);
        servo
    }

    /// Reset items to their initial values: RAM always, EEPROM when `eeprom` (keeping the id
    /// unless `id_too`).
    fn load_defaults(&mut self, eeprom: bool, id_too: bool) {
        let items: Vec<Item> = self.table.items.clone();
        for item in items {
            if item.is_eeprom() && !eeprom {
                continue;
            }
            if item.address == addr::ID && !id_too {
                continue;
            }
            self.put(item.address, item.initial);
        }
        self.put(addr::MODEL_NUMBER, i64::from(self.table.model_number));
        self.put(addr::FIRMWARE_VERSION, i64::from(self.firmware));
    }

    /// RAM to initial values, as after power-on or reboot; then Startup Configuration (60) applies:
    /// bit 1 restores the backed-up RAM items, if there is a backup, and bit 0 turns torque on.
    fn power_on(&mut self, now: Instant) {
        self.load_defaults(false, false);
        let startup = self.get(addr::STARTUP_CONFIGURATION);
        if let Some(backup) = self.backup.take() {
            self.put(addr::BACKUP_READY, 1);
            if startup & STARTUP_RAM_RESTORE != 0 {
                for (address, size) in self.backed_up_ram_items() {
                    self.copy_from(&backup, address, size);
                }
            }
            self.backup = Some(backup);
        }
        self.wrap_to_one_turn();
        self.vel = 0.0;
        self.acc = 0.0;
        self.temperature_c = 30.0;
        self.voltage_dv = f64::from(self.table.nominal_voltage);
        self.registered = None;
        self.shut_down = false;
        self.boot = now;
        self.last_update = now;
        self.last_rx = now;
        let present = self.pos.round() as i64;
        self.put(addr::GOAL_POSITION, present);
        if startup & STARTUP_TORQUE_ON != 0 {
            self.put(addr::TORQUE_ENABLE, 1);
        }
        self.refresh(now);
        self.monitor(now);
    }

    /// The RAM items a Control Table Backup keeps, as (address, size): the velocity and position
    /// gains, the feedforward gains, the profiles and every Indirect Address.
    fn backed_up_ram_items(&self) -> Vec<(u16, u8)> {
        self.table
            .items
            .iter()
            .filter(|item| {
                matches!(
                    item.address,
                    addr::VELOCITY_I_GAIN
                        | addr::VELOCITY_P_GAIN
                        | addr::POSITION_D_GAIN
                        | addr::POSITION_I_GAIN
                        | addr::POSITION_P_GAIN
                        | addr::FEEDFORWARD_2ND_GAIN
                        | addr::FEEDFORWARD_1ST_GAIN
                        | addr::PROFILE_ACCELERATION
                        | addr::PROFILE_VELOCITY
                ) || self
                    .table
                    .indirect_blocks
                    .iter()
                    .any(|&(first, _, count)| (first..first + 2 * count).contains(&item.address))
            })
            .map(|item| (item.address, item.size))
            .collect()
    }

    /// Copy the item at `address` of `size` bytes from a memory image.
    fn copy_from(&mut self, image: &[u8], address: u16, size: u8) {
        let range = usize::from(address)..usize::from(address) + usize::from(size);
        if let (Some(src), Some(dst)) = (image.get(range.clone()), self.mem.get_mut(range)) {
            dst.copy_from_slice(src);
        }
    }

    /// Whether this servo's firmware knows the Control Table Backup instruction (the e-manual:
    /// X430/X540 from 45, X330 from 46, the versions that bring Fast Sync Read).
    pub fn knows_backup(&self) -> bool {
        self.knows_fast_read()
    }

    /// Control Table Backup, option 0x01: store the control table (the EEPROM area, and in RAM
    /// the gains, the profiles and the Indirect Addresses) and set Backup Ready (147). Refused
    /// with result fail while torque is on, as the e-manual says.
    pub fn store_backup(&mut self) -> Result<(), u8> {
        if self.torque_enabled() {
            return Err(error::RESULT_FAIL);
        }
        self.backup = Some(self.mem.clone());
        self.put(addr::BACKUP_READY, 1);
        Ok(())
    }

    /// Whether Control Table Backup, option 0x02, may restore now: result fail while torque is
    /// on (the e-manual) or without a backup to restore (the e-manual does not say; a servo
    /// cannot carry it out).
    pub fn check_restore_backup(&self) -> Result<(), u8> {
        if self.torque_enabled() || self.backup.is_none() {
            return Err(error::RESULT_FAIL);
        }
        Ok(())
    }

    /// Control Table Backup, option 0x02: the EEPROM area back from the backup (id and baud rate
    /// included), then the servo reboots and boots for `boot_time`, as after REBOOT. Nothing
    /// happens without a backup.
    pub fn restore_backup(&mut self, now: Instant, boot_time: Duration) {
        let Some(backup) = self.backup.clone() else {
            return;
        };
        self.update(now);
        let eeprom: Vec<(u16, u8)> = self
            .table
            .items
            .iter()
            .filter(|item| item.is_eeprom() && item.access == Access::Rw)
            .map(|item| (item.address, item.size))
            .collect();
        for (address, size) in eeprom {
            self.copy_from(&backup, address, size);
        }
        self.power_on(now);
        self.boot(now, boot_time);
    }

    /// The model's control table.
    pub fn table(&self) -> &ControlTable {
        &self.table
    }

    /// The model.
    pub fn model(&self) -> Model {
        self.table.model
    }

    /// Firmware Version (address 6).
    pub fn firmware(&self) -> u8 {
        self.firmware
    }

    /// Whether this servo's firmware answers Fast Sync Read and Fast Bulk Read.
    pub fn knows_fast_read(&self) -> bool {
        self.firmware >= self.table.model.fast_read_firmware()
    }

    /// The current bus id (address 7; it changes when a client writes it).
    pub fn id(&self) -> u8 {
        self.mem.get(usize::from(addr::ID)).copied().unwrap_or(0)
    }

    /// Raw memory image (the whole control table).
    pub fn memory(&self) -> &[u8] {
        &self.mem
    }

    /// The item at `address` as a number (signed items sign-extended), if there is one.
    pub fn value(&self, address: u16) -> Option<i64> {
        let item = self.table.item_at(address)?;
        let a = usize::from(address);
        let bytes = self.mem.get(a..a + usize::from(item.size))?;
        Some(decode_le(bytes, item.signed))
    }

    fn get(&self, address: u16) -> i64 {
        self.value(address).unwrap_or(0)
    }

    /// Store `value` in the item at `address`, bypassing every rule.
    fn put(&mut self, address: u16, value: i64) {
        let Some(item) = self.table.item_at(address).copied() else {
            return;
        };
        let bytes = encode_le(value, item.size);
        let a = usize::from(address);
        let n = usize::from(item.size);
        if let Some(dst) = self.mem.get_mut(a..a + n) {
            dst.copy_from_slice(&bytes[..n]);
        }
    }

    /// Set a register directly, bypassing the write rules (for tests and fault injection).
    pub fn poke(&mut self, address: u16, value: i64) {
        self.put(address, value);
    }

    /// Present Position register, ticks.
    pub fn present_position(&self) -> i32 {
        self.get(addr::PRESENT_POSITION) as i32
    }

    /// Goal Position register, ticks.
    pub fn goal_position(&self) -> i32 {
        self.get(addr::GOAL_POSITION) as i32
    }

    /// Torque Enable.
    pub fn torque_enabled(&self) -> bool {
        self.get(addr::TORQUE_ENABLE) == 1
    }

    /// Hardware Error Status bits.
    pub fn hardware_error_status(&self) -> u8 {
        self.get(addr::HARDWARE_ERROR_STATUS) as u8
    }

    /// Bus Watchdog register (-1 once it fired).
    pub fn watchdog(&self) -> i8 {
        self.get(addr::BUS_WATCHDOG) as i8
    }

    /// How often the Bus Watchdog has fired since the simulator started: each time the arm
    /// stopped for it, as seen on the bench, whether or not the register still reads -1.
    pub fn watchdog_fires(&self) -> u32 {
        self.watchdog_fires
    }

    /// Moving flag.
    pub fn moving(&self) -> bool {
        self.get(addr::MOVING) == 1
    }

    /// Status Return Level (0: ping only, 1: ping and reads, 2: all).
    pub fn status_return_level(&self) -> u8 {
        self.get(addr::STATUS_RETURN_LEVEL) as u8
    }

    /// Return Delay Time as a duration.
    pub fn return_delay(&self) -> Duration {
        Duration::from_micros(2 * self.get(addr::RETURN_DELAY_TIME) as u64)
    }

    /// Baud Rate register (an index, not bits per second).
    pub fn baud_index(&self) -> u8 {
        self.get(addr::BAUD_RATE) as u8
    }

    /// True once a "silent" fault took the servo off the bus.
    pub fn is_silent(&self) -> bool {
        self.silent
    }

    /// True while the servo boots after REBOOT or a factory reset (see [`Servo::reboot`]): it
    /// neither hears nor answers.
    pub fn is_booting(&self) -> bool {
        self.booting_until.is_some()
    }

    /// Take the servo off the bus (it neither hears nor answers) or put it back.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// True while a "blocked" fault holds the shaft.
    pub fn is_blocked(&self) -> bool {
        self.blocked
    }

    /// Hold the shaft where it is (something in its way stops it, in either direction), or let
    /// it go; the motor model is advanced to `now` first. Blocked, the shaft stands still, and
    /// with torque on the servo pushes: in a position mode its effort grows with the position
    /// error as the Position P Gain makes it (PWM = gain / 128 per tick of error, capped by Goal
    /// PWM and PWM Limit), in velocity mode it is at full effort toward a non-zero Goal Velocity.
    pub fn set_blocked(&mut self, blocked: bool, now: Instant) {
        self.update(now);
        self.blocked = blocked;
        if blocked {
            self.vel = 0.0;
            self.acc = 0.0;
        }
        self.refresh(self.last_update);
    }

    /// The servo loses its power: off the bus (it neither hears nor answers) and limp, until
    /// [`Servo::restore_power`]. The shaft stays where it is.
    pub fn lose_power(&mut self) {
        self.silent = true;
        self.put(addr::TORQUE_ENABLE, 0);
    }

    /// Power comes back at `now`: the servo boots as at power-on, its RAM at the initial values
    /// (Torque Enable 0, Bus Watchdog 0, profiles 0, Status Return Level 2, no hardware error,
    /// Goal Position := present position) unless Startup Configuration (60) asks for torque on
    /// or the backed-up RAM items, its EEPROM kept, and it is back on the bus.
    pub fn restore_power(&mut self, now: Instant) {
        self.power_on(now);
        self.silent = false;
        self.booting_until = None;
    }

    /// The error byte of a status packet: `code` plus the alert bit when a hardware error is
    /// latched.
    pub fn status_error(&self, code: u8) -> u8 {
        if self.hardware_error_status() != 0 {
            code | error::ALERT
        } else {
            code
        }
    }

    /// A packet addressed to this servo arrived at `now` (restarts the bus watchdog period).
    pub fn touch(&mut self, now: Instant) {
        if self.watchdog() >= 0 {
            self.last_rx = now;
        }
    }

    /// Read `len` bytes from `address`. Reading past the end of the table is an access error;
    /// reserved bytes inside it read as 0, Indirect Data reads through Indirect Address.
    pub fn read(&self, address: u16, len: u16) -> Result<Vec<u8>, u8> {
        let end = usize::from(address) + usize::from(len);
        if end > self.mem.len() {
            return Err(error::ACCESS);
        }
        Ok((usize::from(address)..end)
            .map(|a| {
                let a = self.indirect_target(a as u16).unwrap_or(a as u16);
                self.mem.get(usize::from(a)).copied().unwrap_or(0)
            })
            .collect())
    }

    /// The address an Indirect Data byte stands for.
    fn indirect_target(&self, address: u16) -> Option<u16> {
        self.table
            .indirect_blocks
            .iter()
            .find(|(_, data, count)| (*data..*data + *count).contains(&address))
            .map(|(first_addr, first_data, _)| {
                let slot = first_addr + 2 * (address - first_data);
                self.get(slot) as u16
            })
    }

    /// Check a write of `data` at `address` against every rule, without writing.
    pub fn check_write(&self, address: u16, data: &[u8]) -> Result<(), u8> {
        if data.is_empty() {
            return Err(error::DATA_LENGTH);
        }
        for (start, bytes) in self.resolve_indirect(address, data)? {
            self.check_block(start, &bytes)?;
        }
        Ok(())
    }

    /// Split a write into blocks of the real table: Indirect Data bytes are redirected to their
    /// targets, consecutive targets merged.
    fn resolve_indirect(&self, address: u16, data: &[u8]) -> Result<Vec<(u16, Vec<u8>)>, u8> {
        let end = usize::from(address) + data.len();
        if end > self.mem.len() {
            return Err(error::ACCESS);
        }
        let mut blocks: Vec<(u16, Vec<u8>)> = Vec::new();
        for (k, &byte) in data.iter().enumerate() {
            let a = address + k as u16;
            let target = self.indirect_target(a).unwrap_or(a);
            match blocks.last_mut() {
                Some((start, bytes)) if *start + bytes.len() as u16 == target => bytes.push(byte),
                _ => blocks.push((target, vec![byte])),
            }
        }
        Ok(blocks)
    }

    fn check_block(&self, address: u16, data: &[u8]) -> Result<(), u8> {
        let end = usize::from(address) + data.len();
        if end > self.mem.len() {
            return Err(error::ACCESS);
        }
        let mut offset = 0usize;
        while offset < data.len() {
            let a = address + offset as u16;
            let item = self.table.item_at(a).ok_or(error::ACCESS)?;
            if item.access == Access::R {
                return Err(error::ACCESS);
            }
            if item.is_eeprom() && self.torque_enabled() {
                return Err(error::ACCESS);
            }
            let size = usize::from(item.size);
            let Some(bytes) = data.get(offset..offset + size) else {
                return Err(error::DATA_LENGTH);
            };
            self.check_value(item, decode_le(bytes, item.signed))?;
            offset += size;
        }
        Ok(())
    }

    fn check_value(&self, item: &Item, value: i64) -> Result<(), u8> {
        let goal = matches!(
            item.address,
            addr::GOAL_PWM | addr::GOAL_CURRENT | addr::GOAL_VELOCITY | addr::GOAL_POSITION
        );
        if goal && self.watchdog() < 0 {
            return Err(error::DATA_RANGE);
        }
        match item.range {
            Range::Any => {}
            Range::Fixed(lo, hi) => {
                if !(lo..=hi).contains(&value) {
                    return Err(error::DATA_RANGE);
                }
            }
            Range::OneOf(values) => {
                if !values.contains(&value) {
                    return Err(error::DATA_RANGE);
                }
            }
            Range::Symmetric(limit_address) => {
                let limit = self.get(limit_address);
                if !(-limit..=limit).contains(&value) {
                    return Err(error::DATA_LIMIT);
                }
            }
            Range::GoalPosition => {
                if !(-MULTI_TURN_LIMIT..=MULTI_TURN_LIMIT).contains(&value) {
                    return Err(error::DATA_RANGE);
                }
                if self.get(addr::OPERATING_MODE) == 3 {
                    let lo = self.get(addr::MIN_POSITION_LIMIT);
                    let hi = self.get(addr::MAX_POSITION_LIMIT);
                    if !(lo..=hi).contains(&value) {
                        return Err(error::DATA_LIMIT);
                    }
                }
            }
            Range::Watchdog => {
                if !(0..=127).contains(&value) {
                    return Err(error::DATA_RANGE);
                }
            }
        }
        if item.address == addr::TORQUE_ENABLE && value == 1 && self.shutdown_latched() {
            return Err(error::RESULT_FAIL);
        }
        Ok(())
    }

    fn shutdown_latched(&self) -> bool {
        self.shut_down || self.hardware_error_status() & (self.get(addr::SHUTDOWN) as u8) != 0
    }

    /// Write `data` at `address` at time `now`, applying every rule. On error nothing changes.
    pub fn write(&mut self, address: u16, data: &[u8], now: Instant) -> Result<(), u8> {
        self.check_write(address, data)?;
        for (start, bytes) in self.resolve_indirect(address, data)? {
            let mode_before = self.get(addr::OPERATING_MODE);
            let a = usize::from(start);
            if let Some(dst) = self.mem.get_mut(a..a + bytes.len()) {
                dst.copy_from_slice(&bytes);
            }
            self.after_write(start, bytes.len(), mode_before, now);
        }
        self.monitor(now);
        Ok(())
    }

    fn after_write(&mut self, address: u16, len: usize, mode_before: i64, now: Instant) {
        let touches = |a: u16| {
            usize::from(address) <= usize::from(a) && usize::from(a) < usize::from(address) + len
        };
        let mode = self.get(addr::OPERATING_MODE);
        if touches(addr::OPERATING_MODE) && mode != mode_before {
            self.mode_changed(mode);
        }
        if touches(addr::TORQUE_ENABLE) && !self.torque_enabled() {
            self.vel = 0.0;
            self.acc = 0.0;
        }
        if touches(addr::BUS_WATCHDOG) {
            self.last_rx = now;
        }
        self.refresh(now);
    }

    /// A new Operating Mode: the gains back to their defaults, Profile Velocity and Profile
    /// Acceleration 0, Goal PWM at PWM Limit (Goal Current at Current Limit); in position mode
    /// the shaft's position within one turn, as the encoder reads it (the e-manual's Operating
    /// Mode and Present Position).
    fn mode_changed(&mut self, mode: i64) {
        for address in [
            addr::VELOCITY_I_GAIN,
            addr::VELOCITY_P_GAIN,
            addr::POSITION_D_GAIN,
            addr::POSITION_I_GAIN,
            addr::POSITION_P_GAIN,
            addr::FEEDFORWARD_2ND_GAIN,
            addr::FEEDFORWARD_1ST_GAIN,
        ] {
            if let Some(initial) = self.table.item_at(address).map(|i| i.initial) {
                self.put(address, initial);
            }
        }
        self.put(addr::PROFILE_VELOCITY, 0);
        self.put(addr::PROFILE_ACCELERATION, 0);
        self.put(addr::GOAL_PWM, self.get(addr::PWM_LIMIT));
        if self.table.has_current {
            self.put(addr::GOAL_CURRENT, self.get(addr::CURRENT_LIMIT));
        }
        if mode == 3 {
            self.wrap_to_one_turn();
        }
    }

    /// The shaft's position within one turn (0..4096), as the absolute encoder reads it once
    /// the multi-turn count is lost.
    fn wrap_to_one_turn(&mut self) {
        self.pos = self.pos.round().rem_euclid(4096.0);
    }

    /// Store a REG WRITE: checked now, executed by ACTION.
    pub fn reg_write(&mut self, address: u16, data: &[u8]) -> Result<(), u8> {
        self.check_write(address, data)?;
        self.registered = Some((address, data.to_vec()));
        self.put(addr::REGISTERED_INSTRUCTION, 1);
        Ok(())
    }

    /// Execute the registered write (instruction error when there is none).
    pub fn action(&mut self, now: Instant) -> Result<(), u8> {
        let (address, data) = self.registered.take().ok_or(error::INSTRUCTION)?;
        self.put(addr::REGISTERED_INSTRUCTION, 0);
        self.write(address, &data, now)
    }

    /// Restart at `now`: RAM back to initial values, torque off, hardware errors cleared; then
    /// the servo boots for `boot_time`, neither hearing nor answering, as a real one does after
    /// answering REBOOT.
    pub fn reboot(&mut self, now: Instant, boot_time: Duration) {
        self.update(now);
        self.power_on(now);
        self.boot(now, boot_time);
    }

    /// Off the bus from `now` for `boot_time` (none when zero).
    fn boot(&mut self, now: Instant, boot_time: Duration) {
        self.booting_until = (!boot_time.is_zero())
            .then(|| now.checked_add(boot_time))
            .flatten();
    }

    /// Factory reset with the protocol's option byte (0xFF all, 0x01 all but the id, 0x02 all
    /// but id and baud rate), then restart and boot for `boot_time` (the e-manual: the device
    /// reboots).
    pub fn factory_reset(&mut self, option: u8, now: Instant, boot_time: Duration) {
        self.update(now);
        let id = self.get(addr::ID);
        let baud = self.get(addr::BAUD_RATE);
        self.load_defaults(true, true);
        if option != 0xFF {
            self.put(addr::ID, id);
        }
        if option == 0x02 {
            self.put(addr::BAUD_RATE, baud);
        }
        self.power_on(now);
        self.boot(now, boot_time);
    }

    /// CLEAR: bring the multi-turn position back within one turn. Fails while moving.
    pub fn clear_multi_turn(&mut self, now: Instant) -> Result<(), u8> {
        self.update(now);
        if self.moving() || self.vel != 0.0 {
            return Err(error::RESULT_FAIL);
        }
        self.pos = self.pos.rem_euclid(4096.0);
        let present = self.pos.round() as i64;
        self.put(addr::GOAL_POSITION, present);
        self.refresh(now);
        Ok(())
    }

    /// Latch hardware error `bits` (see [`crate::table::hw`]); those selected by Shutdown switch
    /// torque off until reboot. The physical reading that goes with each error follows it.
    pub fn raise_hardware_error(&mut self, bits: u8, now: Instant) {
        self.update(now);
        if bits & hw::OVERHEATING != 0 {
            self.temperature_c = (self.get(addr::TEMPERATURE_LIMIT) + 3) as f64;
        }
        if bits & hw::INPUT_VOLTAGE != 0 {
            self.voltage_dv = (self.get(addr::MIN_VOLTAGE_LIMIT) - 5).max(0) as f64;
        }
        self.latch(bits);
        self.refresh(now);
    }

    /// Set `bits` in Hardware Error Status; when Shutdown selects one of the latched errors,
    /// torque goes off until a reboot.
    fn latch(&mut self, bits: u8) {
        let status = self.hardware_error_status() | bits;
        self.put(addr::HARDWARE_ERROR_STATUS, i64::from(status));
        if self.shutdown_latched() {
            self.shut_down = true;
            self.put(addr::TORQUE_ENABLE, 0);
            self.vel = 0.0;
            self.acc = 0.0;
        }
    }

    /// The servo's own monitoring (the e-manual's Temperature Limit and Min/Max Voltage Limit):
    /// Present Temperature above Temperature Limit latches an overheating error, Present Input
    /// Voltage outside the voltage limits an input voltage error. Checked whenever a reading or
    /// a limit changes (a write of the limits, a fault, power-on).
    fn monitor(&mut self, now: Instant) {
        let mut bits = 0;
        if self.get(addr::PRESENT_TEMPERATURE) > self.get(addr::TEMPERATURE_LIMIT) {
            bits |= hw::OVERHEATING;
        }
        let volts = self.get(addr::PRESENT_INPUT_VOLTAGE);
        if volts < self.get(addr::MIN_VOLTAGE_LIMIT) || volts > self.get(addr::MAX_VOLTAGE_LIMIT) {
            bits |= hw::INPUT_VOLTAGE;
        }
        if bits & !self.hardware_error_status() != 0 {
            self.latch(bits);
            self.refresh(now);
        }
    }

    /// When the armed watchdog fires if nothing arrives before.
    fn watchdog_deadline(&self) -> Option<Instant> {
        let wd = self.watchdog();
        (wd > 0 && self.torque_enabled())
            .then(|| self.last_rx + Duration::from_millis(20 * wd as u64))
    }

    /// Advance the motor model and the watchdog to `now`; a boot that is over by then ends.
    pub fn update(&mut self, now: Instant) {
        if self.booting_until.is_some_and(|until| until <= now) {
            self.booting_until = None;
        }
        if now <= self.last_update {
            return;
        }
        if let Some(deadline) = self.watchdog_deadline() {
            if deadline <= now {
                if deadline > self.last_update {
                    self.step(deadline - self.last_update);
                    self.last_update = deadline;
                }
                // Fired: stop where it is and refuse goals until 0 is written. The goal
                // becomes "here" in a position mode, "still" in velocity mode, and the
                // profiles 0 (the e-manual's Bus Watchdog example: "When it stops, the Profile
                // Acceleration(108) and Profile Velocity(112) are set to '0'").
                self.put(addr::BUS_WATCHDOG, -1);
                self.watchdog_fires += 1;
                self.put(addr::PROFILE_ACCELERATION, 0);
                self.put(addr::PROFILE_VELOCITY, 0);
                let present = self.pos.round() as i64;
                self.put(addr::GOAL_POSITION, present);
                if self.get(addr::OPERATING_MODE) == 1 {
                    self.put(addr::GOAL_VELOCITY, 0);
                }
                self.pos = present as f64;
                self.vel = 0.0;
                self.acc = 0.0;
            }
        }
        self.step(now - self.last_update);
        self.last_update = now;
        self.refresh(now);
    }

    /// Top speed (ticks/s) and acceleration (ticks/s^2) the profile allows now.
    fn profile_limits(&self) -> (f64, f64) {
        let physical_v = self.table.no_load_rpm / 0.229 * VELOCITY_UNIT_TICKS_S;
        // The no-load speed goes with the voltage the motor gets: its share of full PWM.
        let mut vmax = physical_v * self.pwm_share();
        let limit = self.get(addr::VELOCITY_LIMIT);
        if limit > 0 {
            vmax = vmax.min(limit as f64 * VELOCITY_UNIT_TICKS_S);
        }
        let profile = self.get(addr::PROFILE_VELOCITY);
        if profile > 0 {
            vmax = vmax.min(profile as f64 * VELOCITY_UNIT_TICKS_S);
        }
        let physical_a = physical_v / PHYSICAL_RISE_S;
        let profile_a = self.get(addr::PROFILE_ACCELERATION);
        let amax = if profile_a > 0 {
            physical_a.min(profile_a as f64 * ACCEL_UNIT_TICKS_S2)
        } else {
            physical_a
        };
        (vmax, amax)
    }

    /// Where the position loop drives the shaft: Goal Position, held within Min/Max Position
    /// Limit in position mode (3), whose range they bound even when they changed after the goal
    /// was written.
    fn target_position(&self) -> i64 {
        let goal = self.get(addr::GOAL_POSITION);
        let lo = self.get(addr::MIN_POSITION_LIMIT);
        let hi = self.get(addr::MAX_POSITION_LIMIT);
        if self.get(addr::OPERATING_MODE) == 3 && lo <= hi {
            goal.clamp(lo, hi)
        } else {
            goal
        }
    }

    /// The share of full PWM (0..=1) the servo may drive its motor with in every mode: Goal PWM,
    /// capped by PWM Limit.
    fn pwm_share(&self) -> f64 {
        let cap = self
            .get(addr::PWM_LIMIT)
            .min(self.get(addr::GOAL_PWM).abs());
        (cap as f64 / FULL_PWM).clamp(0.0, 1.0)
    }

    fn step(&mut self, dt: Duration) {
        if !self.torque_enabled() || self.blocked {
            self.vel = 0.0;
            self.acc = 0.0;
            return;
        }
        let mode = self.get(addr::OPERATING_MODE);
        let (vmax, amax) = self.profile_limits();
        let mut left = dt.as_secs_f64();
        let h_max = MAX_STEP.as_secs_f64();
        match mode {
            3..=5 => {
                let goal = self.target_position() as f64;
                while left > 0.0 {
                    if (self.pos == goal || vmax <= 0.0) && self.vel == 0.0 {
                        self.acc = 0.0;
                        break;
                    }
                    let h = left.min(h_max);
                    left -= h;
                    let d = goal - self.pos;
                    let wanted = d.signum() * vmax.min((2.0 * amax * d.abs()).sqrt());
                    let dv = (wanted - self.vel).clamp(-amax * h, amax * h);
                    self.vel += dv;
                    self.acc = dv / h;
                    let stepped = self.vel * h;
                    if d.abs() <= stepped.abs().max(0.5) && stepped.signum() == d.signum()
                        || d.abs() < 0.5
                    {
                        self.pos = goal;
                        self.vel = 0.0;
                    } else {
                        self.pos += stepped;
                    }
                }
            }
            1 => {
                let target = self.get(addr::GOAL_VELOCITY) as f64 * VELOCITY_UNIT_TICKS_S;
                let target = target.clamp(-vmax, vmax);
                while left > 0.0 {
                    let h = left.min(h_max);
                    left -= h;
                    let dv = (target - self.vel).clamp(-amax * h, amax * h);
                    self.vel += dv;
                    self.acc = dv / h;
                    self.pos += self.vel * h;
                    if self.vel == target && dv == 0.0 {
                        self.pos += self.vel * left;
                        break;
                    }
                }
            }
            // Current and PWM control: the simulated shaft holds still.
            _ => {
                self.vel = 0.0;
                self.acc = 0.0;
            }
        }
    }

    /// Write the present values (position, velocity, load, ...) into the table.
    fn refresh(&mut self, now: Instant) {
        let physical_v = self.table.no_load_rpm / 0.229 * VELOCITY_UNIT_TICKS_S;
        let physical_a = physical_v / PHYSICAL_RISE_S;
        let present = self.pos.round() as i64;
        let vel_units = (self.vel / VELOCITY_UNIT_TICKS_S).round() as i64;
        let torque = self.torque_enabled();
        let goal = self.target_position();
        let mode = self.get(addr::OPERATING_MODE);
        let profiling = torque && (self.vel != 0.0 || ((3..=5).contains(&mode) && goal != present));
        let moving = profiling || vel_units.abs() > self.get(addr::MOVING_THRESHOLD);
        // Effort: a share for speed (friction) plus one for acceleration; nothing at rest.
        // Blocked, the stall effort of the position or velocity loop instead.
        let effort = if !torque {
            0.0
        } else if self.blocked {
            self.stall_effort()
        } else {
            let share = self.pwm_share();
            (0.15 * self.vel / physical_v + 0.35 * self.acc / physical_a).clamp(-share, share)
        };
        self.put(addr::PRESENT_POSITION, present);
        self.put(addr::POSITION_TRAJECTORY, present);
        self.put(addr::PRESENT_VELOCITY, vel_units);
        self.put(addr::VELOCITY_TRAJECTORY, vel_units);
        self.put(addr::MOVING, i64::from(moving));
        let in_position = (goal - present).abs() <= 1;
        let profile_type = match (
            self.get(addr::PROFILE_VELOCITY) > 0,
            self.get(addr::PROFILE_ACCELERATION) > 0,
        ) {
            (true, true) => 3,
            (true, false) => 1,
            (false, true) => 2,
            (false, false) => 0,
        };
        let status = i64::from(in_position) | (i64::from(profiling) << 1) | (profile_type << 4);
        self.put(addr::MOVING_STATUS, status);
        self.put(addr::PRESENT_PWM, (effort * FULL_PWM).round() as i64);
        let load_or_current = if self.table.has_current {
            let ma = if torque {
                self.table.idle_current_ma + effort.abs() * 900.0
            } else {
                0.0
            };
            (effort.signum() * ma / self.table.current_unit_ma).round() as i64
        } else {
            (effort * 1000.0).round() as i64
        };
        self.put(addr::PRESENT_LOAD_OR_CURRENT, load_or_current);
        self.put(addr::PRESENT_INPUT_VOLTAGE, self.voltage_dv.round() as i64);
        self.put(addr::PRESENT_TEMPERATURE, self.temperature_c.round() as i64);
        let tick = now.saturating_duration_since(self.boot).as_millis() % 32768;
        self.put(addr::REALTIME_TICK, tick as i64);
    }

    /// The effort (share of full PWM, -1..=1) of a blocked shaft: in a position mode the
    /// position loop's P term on the error from the held shaft to Goal Position (Position P
    /// Gain / 128 PWM units per tick), capped by Goal PWM and PWM Limit; in velocity mode full
    /// effort (as much as they allow) toward Goal Velocity; in current and PWM modes nothing (the
    /// shaft holds still there anyway).
    fn stall_effort(&self) -> f64 {
        let cap = self.pwm_share() * FULL_PWM;
        let pwm = match self.get(addr::OPERATING_MODE) {
            3..=5 => {
                // On the encoder's reading, whole ticks, as the servo's own loop sees it.
                let error = self.target_position() as f64 - self.pos.round();
                self.get(addr::POSITION_P_GAIN) as f64 / 128.0 * error
            }
            1 => (self.get(addr::GOAL_VELOCITY) as f64).signum() * cap,
            _ => 0.0,
        };
        pwm.clamp(-cap, cap) / FULL_PWM
    }

    /// Set the supply voltage the servo measures (0.1 V units), e.g. a sagging supply; outside
    /// the voltage limits it latches an input voltage error.
    pub fn set_input_voltage(&mut self, decivolts: f64) {
        self.voltage_dv = decivolts;
        self.refresh(self.last_update);
        self.monitor(self.last_update);
    }

    /// Set the internal temperature the servo measures (°C); above Temperature Limit it latches
    /// an overheating error.
    pub fn set_temperature(&mut self, celsius: f64) {
        self.temperature_c = celsius;
        self.refresh(self.last_update);
        self.monitor(self.last_update);
    }

    /// Turn the shaft to `ticks` as a hand would, at rest there (for tests: a servo moved
    /// while its torque is off; one with torque on drives back to its goal from there).
    pub fn turn_by_hand(&mut self, ticks: f64) {
        self.pos = ticks;
        self.vel = 0.0;
        self.acc = 0.0;
        self.refresh(self.last_update);
    }

    /// Physical shaft position in ticks (unrounded), for tests.
    pub fn shaft_position(&self) -> f64 {
        self.pos
    }
}
