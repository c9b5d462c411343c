//! Joint angles in radians <-> X-series position ticks.
//!
//! An X-series servo counts 4096 ticks per turn, 2048 at its mechanical centre. A joint's zero
//! sits `offset_ticks` from that centre (a software zero, calibrated per joint), and `reverse`
//! flips the direction: `ticks = 2048 + offset_ticks + sign * theta * 4096 / (2 pi)`.

use std::f64::consts::TAU;

/// Ticks per full turn of an X-series servo.
pub const TICKS_PER_TURN: f64 = 4096.0;
/// Ticks at the mechanical centre.
pub const CENTRE_TICKS: i32 = 2048;

/// Per-joint calibration: software zero and direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Calibration {
    /// Ticks at 0 rad, relative to the centre.
    pub offset_ticks: i32,
    /// A positive angle turns the servo the negative way.
    pub reverse: bool,
}

impl Calibration {
    fn sign(self) -> f64 {
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

    #[test]
    fn round_trips_and_known_points() {
        for cal in [
            Calibration::default(),
            Calibration {
                offset_ticks: -300,
                reverse: true,
            },
        ] {
            for theta in [-2.0, -0.1, 0.0, 0.7, 3.0] {
                assert!((cal.radians(cal.ticks(theta)) - theta).abs() < 1e-12);
            }
        }
        let plain = Calibration::default();
        assert_eq!(plain.ticks(0.0), 2048.0);
        assert_eq!(plain.ticks(std::f64::consts::PI), 4096.0);
        let rev = Calibration {
            offset_ticks: 100,
            reverse: true,
        };
        assert_eq!(rev.ticks(0.0), 2148.0);
        assert!(rev.ticks(0.5) < rev.ticks(0.0));
        let (lo, hi) = rev.tick_range(-1.0, 1.0);
        assert!(lo <= hi && rev.radians(lo) <= 1.0 && rev.radians(hi) >= -1.0);
    }
}
