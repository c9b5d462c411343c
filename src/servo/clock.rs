//! Time for the servo layer's waits (a rebooted servo coming back, a servo switching baud
//! rate): a [`Clock`] the caller passes in, so tests run those waits on a clock they advance
//! instead of on wall time. Reply deadlines on the wire stay wall time: the serial port's.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Where the servo layer reads the time and waits.
pub trait Clock {
    /// Time elapsed on this clock since an arbitrary origin.
    fn elapsed(&self) -> Duration;
    /// Let `d` pass.
    fn sleep(&self, d: Duration);
}

/// Wall time.
#[derive(Debug, Clone, Copy)]
pub struct WallClock {
    origin: Instant,
}

impl WallClock {
    /// A wall clock starting now.
    pub fn new() -> Self {
        Self {
            origin: Instant::now(),
        }
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for WallClock {
    fn elapsed(&self) -> Duration {
        self.origin.elapsed()
    }
    fn sleep(&self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// A clock that moves only when slept on or advanced: a wait of any length returns at once.
#[derive(Debug, Default)]
pub struct StepClock {
    nanos: AtomicU64,
}

impl StepClock {
    /// A clock at zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// Move the clock forward by `d`.
    pub fn advance(&self, d: Duration) {
        let n = u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        self.nanos.fetch_add(n, Ordering::SeqCst);
    }
}

impl Clock for StepClock {
    fn elapsed(&self) -> Duration {
        Duration::from_nanos(self.nanos.load(Ordering::SeqCst))
    }
    fn sleep(&self, d: Duration) {
        self.advance(d);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_clock_moves_only_when_told() {
        let c = StepClock::new();
        assert_eq!(c.elapsed(), Duration::ZERO);
        c.sleep(Duration::from_secs(3));
        c.advance(Duration::from_millis(5));
        assert_eq!(c.elapsed(), Duration::from_millis(3005));
    }
}
