//! Time for the servo layer's waits (a rebooted servo coming back, a servo switching baud
//! rate) and for the control loop: the workspace's one [`Clock`] trait, passed in by the caller,
//! so tests run those waits on a [`ManualClock`] they advance instead of on wall time. Reply
//! deadlines on the wire stay wall time: the serial port's.
//!
//! The trait lives in the simulator's crate, the lowest of the workspace (it depends on nothing
//! of this one), because the simulated servos take their time from the same clock.

pub use snakectl_sim::clock::{sharp_timers, Clock, ManualClock, RealClock};

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn a_manual_clock_moves_only_when_told() {
        let c = ManualClock::new();
        assert_eq!(c.elapsed(), Duration::ZERO);
        c.sleep(Duration::from_secs(3));
        c.advance(Duration::from_millis(5));
        assert_eq!(c.elapsed(), Duration::from_millis(3005));
    }
}
