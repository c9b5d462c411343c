//! Joint angles in radians <-> X-series position ticks.
//!
//! An X-series servo counts 4096 ticks per turn, 2048 at its mechanical centre. A joint's zero
//! sits `offset_ticks` from that centre (a software zero, calibrated per joint), and `reverse`
//! flips the direction: `ticks = 2048 + offset_ticks + sign * theta * 4096 / (2 pi)`.
//!
//! Also the servo's raw units of velocity, profile acceleration, current/load and voltage. A
//! goal that is not a finite number has no tick value ([`Calibration::goal_ticks`]): it is
//! never written.

use std::f64::consts::TAU;

/// Ticks per full turn of an X-series servo.
pub const TICKS_PER_TURN: f64 = 4096.0;
/// Ticks at the mechanical centre.
pub const CENTRE_TICKS: i32 = 2048;

/// Present/Profile Velocity unit: 0.229 rev/min, in rad/s.
pub const VELOCITY_UNIT_RAD_S: f64 = 0.229 * TAU / 60.0;
/// Profile Acceleration unit: 214.577 rev/min², in rad/s².
pub const ACCELERATION_UNIT_RAD_S2: f64 = 214.577 * TAU / 3600.0;
/// Largest Profile Velocity / Profile Acceleration value the X series accepts.
pub const PROFILE_MAX: i64 = 32_767;

/// A velocity in raw units (Present Velocity) as rad/s.
pub fn velocity_rad_s(raw: i32) -> f64 {
    f64::from(raw) * VELOCITY_UNIT_RAD_S
}

/// Profile Velocity register value for `rad_s` (0 = no profile; a positive speed is at least
/// 1 unit; capped at [`PROFILE_MAX`]).
pub fn profile_velocity(rad_s: f64) -> i64 {
    profile_units(rad_s / VELOCITY_UNIT_RAD_S)
}

/// Profile Acceleration register value for `rad_s2` (same rules as [`profile_velocity`]).
pub fn profile_acceleration(rad_s2: f64) -> i64 {
    profile_units(rad_s2 / ACCELERATION_UNIT_RAD_S2)
}

fn profile_units(units: f64) -> i64 {
    if units.is_finite() && units > 0.0 {
        (units.round() as i64).clamp(1, PROFILE_MAX)
    } else {
        0
    }
}

/// Return Delay Time register value (2 µs units) for `us` microseconds (rounded down, at most
/// 254).
pub fn return_delay(us: u32) -> i64 {
    i64::from((us / 2).min(254))
}

/// What one unit of Present Current / Present Load means, per model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CurrentUnit {
    /// Present Load in 0.1 % of the maximum torque (XL430).
    LoadPermille,
    /// Present Current in this many milliamperes a unit.
    MilliAmps(f64),
}

/// Present Input Voltage (0.1 V units) in volts.
pub fn volts(raw_dv: u16) -> f64 {
    f64::from(raw_dv) / 10.0
}

/// A voltage limit register (Min/Max Voltage Limit, 0.1 V units, read as a register value) in
/// volts.
pub fn limit_volts(raw_dv: i64) -> f64 {
    raw_dv as f64 / 10.0
}

impl CurrentUnit {
    /// Present Current / Load `raw` in this unit's physical value: percent of the maximum
    /// torque for a load, amperes for a current.
    pub fn value(self, raw: i16) -> f64 {
        match self {
            CurrentUnit::LoadPermille => f64::from(raw) * 0.1,
            CurrentUnit::MilliAmps(ma) => f64::from(raw) * ma * 1e-3,
        }
    }
}

/// One unit of the Bus Watchdog register (98), ms.
pub const WATCHDOG_UNIT_MS: u32 = 20;

/// The largest Bus Watchdog value (the register is signed; -1 means it fired).
pub const WATCHDOG_MAX_UNITS: u32 = 127;

/// The Bus Watchdog register value for `ms` (rounded down to its 20 ms units, at most 127
/// units; 0 disables it).
pub fn watchdog_units(ms: u32) -> i64 {
    i64::from((ms / WATCHDOG_UNIT_MS).min(WATCHDOG_MAX_UNITS))
}

/// The period the Bus Watchdog runs with for `ms`, as the register holds it; `None` when off.
pub fn watchdog_period(ms: u32) -> Option<std::time::Duration> {
    let units = watchdog_units(ms);
    (units > 0).then(|| {
        std::time::Duration::from_millis(units.unsigned_abs() * u64::from(WATCHDOG_UNIT_MS))
    })
}

/// Per-joint calibration: software zero and direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Calibration {
    /// Ticks at 0 rad, relative to the centre.
    pub offset_ticks: i32,
    /// A positive angle turns the servo the negative way.
    pub reverse: bool,
}

impl Calibration {
    /// +1, or -1 for a reversed servo: the joint angle's sign in the servo's frame.
    pub fn sign(self) -> f64 {
        if self.reverse {
            -1.0
        } else {
            1.0
        }
    }

    /// Position in ticks (not rounded) for a joint angle.
    pub fn ticks(self, theta_rad: f64) -> f64 {
        f64::from(CENTRE_TICKS + self.offset_ticks) + self.sign() * theta_rad * TICKS_PER_TURN / TAU
    }

    /// Joint angle for a position in ticks.
    pub fn radians(self, ticks: f64) -> f64 {
        (ticks - f64::from(CENTRE_TICKS + self.offset_ticks)) * self.sign() * TAU / TICKS_PER_TURN
    }

    /// The Goal Position for a joint angle, rounded to the nearest tick; `None` for an angle
    /// that is not finite or beyond the register's range.
    pub fn goal_ticks(self, theta_rad: f64) -> Option<i32> {
        let t = self.ticks(theta_rad).round();
        (t.is_finite() && t >= f64::from(i32::MIN) && t <= f64::from(i32::MAX)).then_some(t as i32)
    }

    /// The tick interval `[min, max]` covering the joint interval `[lo, hi]` (rounded inward,
    /// so every tick in it maps inside the joint limits).
    pub fn tick_range(self, lo_rad: f64, hi_rad: f64) -> (f64, f64) {
        let (a, b) = (self.ticks(lo_rad), self.ticks(hi_rad));
        (a.min(b).ceil(), a.max(b).floor())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 4096 ticks a turn: 651.899 ticks a radian, 2048 at 0 rad (e-manual, X series).
    #[test]
    fn known_points_by_hand() {
        let plain = Calibration::default();
        assert_eq!(plain.ticks(0.0), 2048.0);
        assert_eq!(plain.ticks(std::f64::consts::PI), 4096.0);
        assert_eq!(plain.ticks(-std::f64::consts::FRAC_PI_2), 1024.0);
        assert!((plain.ticks(1.0) - 2_699.898_7).abs() < 1e-4);
        assert!((plain.radians(3072.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        let rev = Calibration {
            offset_ticks: 100,
            reverse: true,
        };
        // 2148 - 0.5 * 651.899 = 1822.051.
        assert_eq!(rev.ticks(0.0), 2148.0);
        assert!((rev.ticks(0.5) - 1_822.050_7).abs() < 1e-4);
        assert!((rev.radians(2148.0 - 1024.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        // [-1, 1] rad reversed around 2148: ticks 1496.10..2799.90, rounded inward.
        assert_eq!(rev.tick_range(-1.0, 1.0), (1497.0, 2799.0));
    }

    #[test]
    fn goals_are_finite_ticks_or_nothing() {
        let cal = Calibration {
            offset_ticks: 12,
            reverse: false,
        };
        assert_eq!(cal.goal_ticks(0.0), Some(2060));
        assert_eq!(cal.goal_ticks(-std::f64::consts::FRAC_PI_2), Some(1036));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e12] {
            assert_eq!(cal.goal_ticks(bad), None, "{bad}");
        }
        for raw in [-2000, -1, 0, 1, 2047] {
            let theta = cal.radians(f64::from(raw) + 2060.0);
            assert_eq!(cal.goal_ticks(theta), Some(raw + 2060));
        }
    }

    /// Units from the e-manual: velocity 0.229 rev/min = 0.023981 rad/s, acceleration
    /// 214.577 rev/min^2 = 0.374507 rad/s^2, voltage 0.1 V; Return Delay Time 2 µs.
    #[test]
    fn raw_units_by_hand() {
        assert!((velocity_rad_s(100) - 2.398_082).abs() < 1e-6);
        assert_eq!(profile_velocity(0.0), 0);
        assert_eq!(profile_velocity(f64::NAN), 0);
        assert_eq!(profile_velocity(1e-6), 1);
        // 3 / 0.023981 = 125.1; 1 / 0.023981 = 41.7.
        assert_eq!(profile_velocity(3.0), 125);
        assert_eq!(profile_velocity(1.0), 42);
        // 20 / 0.374507 = 53.4.
        assert_eq!(profile_acceleration(20.0), 53);
        assert_eq!(profile_acceleration(1e9), PROFILE_MAX);
        assert_eq!(return_delay(500), 250);
        assert_eq!(return_delay(3), 1);
        assert_eq!(return_delay(600), 254);
        assert_eq!(volts(111), 11.1);
    }
}
