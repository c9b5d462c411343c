//! The one-time settings of a servo, as `snakectl servo` makes them on a raw bus (never through
//! the daemon's [`super::limits::Limited`]): find a servo at its baud rate, give it a new id or
//! baud rate or Return Delay Time, read its settings, clear the calibration registers that
//! bring-up requires neutral. Each procedure is tested against the simulator.

use std::time::Duration;

use super::clock::Clock;
use super::{
    baud_index, units, PingInfo, Register, ServoBus, ServoError, DRIVE_MODE_REVERSE, MAX_ID,
};

/// How long a servo takes to listen at its new baud rate.
const BAUD_SWITCH: Duration = Duration::from_millis(50);

/// Why a procedure did not complete.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AdminError {
    /// The new id is already taken by another servo.
    #[error("id {id} is already taken on this bus at {baud} baud")]
    IdTaken {
        /// The id.
        id: u8,
        /// The baud rate.
        baud: u32,
    },
    /// Servos share the id the procedure would change: it would change every one of them.
    #[error(
        "id {id} answered {answers} times at {baud} baud: servos share it; connect one at a time \
         to give each its own id"
    )]
    Shared {
        /// The id.
        id: u8,
        /// How many replies one ping got.
        answers: usize,
        /// The baud rate.
        baud: u32,
    },
    /// An id outside 0..=252.
    #[error("id {0} is out of range 0..=252")]
    BadId(u8),
    /// A Return Delay Time the register cannot hold.
    #[error("return delay {0} µs: must be even and at most 508")]
    BadReturnDelay(u32),
    /// The servo answers at none of the baud rates tried.
    #[error("servo {id} does not answer at {} baud", list_bauds(bauds))]
    NotFound {
        /// The servo.
        id: u8,
        /// The baud rates tried.
        bauds: Vec<u32>,
    },
    /// After the change, the servo does not answer as it now should.
    #[error("servo {id}: {what}: {source}")]
    NotConfirmed {
        /// The servo (its old id).
        id: u8,
        /// What was expected.
        what: String,
        /// What the check got.
        source: ServoError,
    },
    /// A bus error during the procedure.
    #[error(transparent)]
    Servo(#[from] ServoError),
}

/// Baud rates as a message lists them: "57600, 1000000".
pub fn list_bauds(bauds: &[u32]) -> String {
    bauds
        .iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Find servo `id` by pinging it at each of `bauds` in turn; the bus is left at the rate it
/// answered at. A refusal other than silence or a damaged reply stops the search.
pub fn find<B: ServoBus>(
    bus: &mut B,
    id: u8,
    bauds: &[u32],
    timeout: Duration,
) -> Result<PingInfo, AdminError> {
    if id > MAX_ID {
        return Err(AdminError::BadId(id));
    }
    for &baud in bauds {
        bus.set_baud(baud)?;
        match bus.ping(id, timeout) {
            Ok(info) => return Ok(info),
            Err(e) if e.is_transient() => {}
            Err(e) => return Err(e.into()),
        }
    }
    Err(AdminError::NotFound {
        id,
        bauds: bauds.to_vec(),
    })
}

/// What a procedure that writes EEPROM returns: its own result, and whether it found torque on
/// and switched it off (the joint went limp), which the user must be told.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Written<T> {
    /// The procedure's result.
    pub value: T,
    /// Torque was on and was switched off to write EEPROM.
    pub torque_was_on: bool,
}

/// Torque off, so EEPROM items can be written; returns whether it was on.
fn torque_off<B: ServoBus>(bus: &mut B, id: u8, timeout: Duration) -> Result<bool, AdminError> {
    let on = bus.read(id, Register::TorqueEnable, timeout)?.value != 0;
    if on {
        bus.set_torque(id, false, timeout)?;
    }
    Ok(on)
}

/// Refuses to change servo `id` when more than one servo answers to it.
fn only_one<B: ServoBus>(bus: &mut B, id: u8, timeout: Duration) -> Result<(), AdminError> {
    let (_, answers) = bus.ping_counted(id, timeout)?;
    if answers > 1 {
        return Err(AdminError::Shared {
            id,
            answers,
            baud: bus.baud(),
        });
    }
    Ok(())
}

/// Refuses id `id` when anything answers to it at the bus's present rate.
fn free<B: ServoBus>(bus: &mut B, id: u8, timeout: Duration) -> Result<(), AdminError> {
    match bus.ping(id, timeout) {
        Err(e) if e.is_timeout() => Ok(()),
        Ok(_) => Err(AdminError::IdTaken {
            id,
            baud: bus.baud(),
        }),
        Err(e) => Err(e.into()),
    }
}

/// Give servo `id` the id `new_id` (refused if another servo answers to it, or if servos share
/// `id`); confirmed by a ping at the new id. Returns whether anything changed.
pub fn set_id<B: ServoBus>(
    bus: &mut B,
    id: u8,
    new_id: u8,
    timeout: Duration,
) -> Result<Written<bool>, AdminError> {
    if new_id > MAX_ID {
        return Err(AdminError::BadId(new_id));
    }
    if new_id == id {
        return Ok(Written {
            value: false,
            torque_was_on: false,
        });
    }
    free(bus, new_id, timeout)?;
    only_one(bus, id, timeout)?;
    let torque_was_on = torque_off(bus, id, timeout)?;
    match bus.write(id, Register::Id, i64::from(new_id), timeout) {
        Ok(_) => {}
        // The acknowledgement may already carry the new id: skipped as another servo's.
        Err(ServoError::WrongId { from, .. }) if from == new_id => {}
        Err(ServoError::Timeout { .. }) => {}
        Err(e) => return Err(e.into()),
    }
    bus.ping(new_id, timeout)
        .map_err(|source| AdminError::NotConfirmed {
            id,
            what: format!("does not answer as {new_id}"),
            source,
        })?;
    Ok(Written {
        value: true,
        torque_was_on,
    })
}

/// Set servo `id`'s baud rate to `new_baud`, then the port's, and confirm with a ping (after
/// the servo's switch-over time, waited on `clock`). Refused if servos share `id`, or if
/// anything answers to `id` at the new rate already (two servos would then share it there).
pub fn set_baud<B: ServoBus>(
    bus: &mut B,
    id: u8,
    new_baud: u32,
    timeout: Duration,
    clock: &dyn Clock,
) -> Result<Written<()>, AdminError> {
    let index = baud_index(new_baud).ok_or(ServoError::Baud(new_baud))?;
    only_one(bus, id, timeout)?;
    let old_baud = bus.baud();
    if new_baud != old_baud {
        bus.set_baud(new_baud)?;
        let there = free(bus, id, timeout);
        bus.set_baud(old_baud)?;
        there?;
    }
    let torque_was_on = torque_off(bus, id, timeout)?;
    // The servo may answer at either rate, or not at all, as it switches.
    match bus.write(id, Register::BaudRate, i64::from(index), timeout) {
        Ok(_) | Err(ServoError::Timeout { .. }) | Err(ServoError::Checksum { .. }) => {}
        Err(e) => return Err(e.into()),
    }
    bus.set_baud(new_baud)?;
    clock.sleep(BAUD_SWITCH);
    bus.ping(id, timeout)
        .map_err(|source| AdminError::NotConfirmed {
            id,
            what: format!("does not answer at {new_baud} baud"),
            source,
        })?;
    Ok(Written {
        value: (),
        torque_was_on,
    })
}

/// Set servo `id`'s Return Delay Time to `us` µs (even, at most 508); returns the value read
/// back, µs.
pub fn set_return_delay<B: ServoBus>(
    bus: &mut B,
    id: u8,
    us: u32,
    timeout: Duration,
) -> Result<Written<u32>, AdminError> {
    if us > 508 || us % 2 != 0 {
        return Err(AdminError::BadReturnDelay(us));
    }
    let torque_was_on = torque_off(bus, id, timeout)?;
    bus.write(
        id,
        Register::ReturnDelayTime,
        units::return_delay(us),
        timeout,
    )?;
    let back = bus.read(id, Register::ReturnDelayTime, timeout)?.value;
    Ok(Written {
        value: u32::try_from(back).unwrap_or_default() * 2,
        torque_was_on,
    })
}

/// Zero servo `id`'s Homing Offset and clear Drive Mode's reverse bit (keeping its other
/// bits), as bring-up requires. Returns the values found before (offset, drive mode); torque
/// is only switched off when there is something to clear.
pub fn clear_calibration<B: ServoBus>(
    bus: &mut B,
    id: u8,
    timeout: Duration,
) -> Result<Written<(i64, i64)>, AdminError> {
    let offset = bus.read(id, Register::HomingOffset, timeout)?.value;
    let drive = bus.read(id, Register::DriveMode, timeout)?.value;
    let mut torque_was_on = false;
    if offset != 0 || drive & DRIVE_MODE_REVERSE != 0 {
        torque_was_on = torque_off(bus, id, timeout)?;
        if offset != 0 {
            bus.write(id, Register::HomingOffset, 0, timeout)?;
        }
        if drive & DRIVE_MODE_REVERSE != 0 {
            bus.write(
                id,
                Register::DriveMode,
                drive & !DRIVE_MODE_REVERSE,
                timeout,
            )?;
        }
    }
    Ok(Written {
        value: (offset, drive),
        torque_was_on,
    })
}

/// A servo's settings and state, as `snakectl servo info` prints them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Info {
    /// Present Position, ticks.
    pub position: i64,
    /// Baud Rate register.
    pub baud_register: i64,
    /// Return Delay Time, µs.
    pub return_delay_us: i64,
    /// Operating Mode.
    pub operating_mode: i64,
    /// Min and Max Position Limit, ticks.
    pub limits: (i64, i64),
    /// Homing Offset, ticks.
    pub homing_offset: i64,
    /// Drive Mode.
    pub drive_mode: i64,
    /// Torque Enable.
    pub torque: bool,
    /// Bus Watchdog (-1: fired).
    pub watchdog: i64,
    /// Hardware Error Status.
    pub errors: super::HardwareErrors,
}

/// Read servo `id`'s settings.
pub fn info<B: ServoBus>(bus: &mut B, id: u8, timeout: Duration) -> Result<Info, AdminError> {
    let mut read = |r: Register| bus.read(id, r, timeout).map(|v| v.value);
    let info = Info {
        position: read(Register::PresentPosition)?,
        baud_register: read(Register::BaudRate)?,
        return_delay_us: read(Register::ReturnDelayTime)? * 2,
        operating_mode: read(Register::OperatingMode)?,
        limits: (
            read(Register::MinPositionLimit)?,
            read(Register::MaxPositionLimit)?,
        ),
        homing_offset: read(Register::HomingOffset)?,
        drive_mode: read(Register::DriveMode)?,
        torque: read(Register::TorqueEnable)? != 0,
        watchdog: read(Register::BusWatchdog)?,
        errors: bus.hardware_errors(id, timeout)?,
    };
    Ok(info)
}
