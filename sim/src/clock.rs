//! Time source, the one clock of the whole workspace. The simulator's motor model, watchdog and
//! faults advance on a [`Clock`], and so do the controller's waits and its control loop, so tests
//! drive time by hand ([`ManualClock`]) while the binaries use [`RealClock`]. It lives in this
//! crate, the lowest of the workspace, because both the simulator and the controller take time
//! from it.

use std::fmt::Debug;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

/// A source of "now".
pub trait Clock: Send + Sync + Debug {
    /// The current instant.
    fn now(&self) -> Instant;

    /// Let `d` pass on this clock: wall time sleeps, a manual clock moves forward at once.
    fn sleep(&self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// Wall-clock time (`Instant::now()`).
#[derive(Debug, Clone, Copy, Default)]
pub struct RealClock;

impl Clock for RealClock {
    fn now(&self) -> Instant {
        Instant::now()
    }
}

/// A clock that only moves when told to. Clones share the same time.
#[derive(Debug, Clone)]
pub struct ManualClock {
    origin: Instant,
    now: Arc<Mutex<Instant>>,
}

impl Default for ManualClock {
    fn default() -> Self {
        Self::new()
    }
}

impl ManualClock {
    /// A clock frozen at the moment of creation.
    pub fn new() -> Self {
        let origin = Instant::now();
        Self {
            origin,
            now: Arc::new(Mutex::new(origin)),
        }
    }

    /// How far this clock has moved since it was made.
    pub fn elapsed(&self) -> Duration {
        self.now().saturating_duration_since(self.origin)
    }

    /// Move time forward by `dt`.
    pub fn advance(&self, dt: Duration) {
        let mut now = self.now.lock().unwrap_or_else(PoisonError::into_inner);
        *now += dt;
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Instant {
        *self.now.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn sleep(&self, d: Duration) {
        self.advance(d);
    }
}

/// Shared handle to a clock, as the simulator holds it.
pub type SharedClock = Arc<dyn Clock>;
