//! Time source, the one clock of the whole workspace. The simulator's motor model, watchdog and
//! faults advance on a [`Clock`], and so do the controller's waits and its control loop, so tests
//! drive time by hand ([`ManualClock`]) while the binaries use [`RealClock`]. It lives in this
//! crate, the lowest of the workspace, because both the simulator and the controller take time
//! from it. The threads whose waits make up a control tick wait sharply: [`sharp_timers`] and
//! [`Clock::sleep_until`]'s spin tail ([`SPIN_TAIL`]).

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

    /// Let time pass until `deadline` (at once when it has passed), as close to it as the
    /// clock can: a control loop's wait for its next period.
    fn sleep_until(&self, deadline: Instant) {
        self.sleep(deadline.saturating_duration_since(self.now()));
    }
}

/// How close to a deadline [`RealClock::sleep_until`] stops sleeping and spins: a sleep wakes
/// tens of microseconds late at the median and over a hundred at the 99th percentile (timer
/// slack, the scheduler), which a loop's period cannot spare. At most this much CPU time a
/// wait, 10% of a core at 1 kHz.
pub const SPIN_TAIL: Duration = Duration::from_micros(100);

/// The timer slack [`sharp_timers`] asks for: the kernel may end a timed wait this much late
/// to merge wake-ups (1 ns, the least it takes; the default is 50 µs).
pub const SHARP_TIMER_SLACK_NS: u64 = 1;

/// Sets the calling thread's timer slack to [`SHARP_TIMER_SLACK_NS`], so that its sleeps and
/// read timeouts end when asked: for the threads whose waits make up a control tick (the loop,
/// its port threads, a simulator's serving thread, whose replies are due to the microsecond).
/// With the default slack a 500 µs sleep on the development machine woke 84 µs late at the
/// median, with 1 ns 34 µs (`loop_rate --jitter`). Costs nothing but wake-ups that are not
/// merged with others. Returns whether it was set (logged at debug level otherwise).
pub fn sharp_timers() -> bool {
    #[cfg(target_os = "linux")]
    let set =
        rustix::thread::set_current_timer_slack(std::num::NonZeroU64::new(SHARP_TIMER_SLACK_NS))
            .is_ok();
    #[cfg(not(target_os = "linux"))]
    let set = false;
    if !set {
        let thread = std::thread::current();
        let name = thread.name().unwrap_or("a thread");
        tracing::debug!("{name}: keeps the default timer slack (could not set it)");
    }
    set
}

/// Wall-clock time (`Instant::now()`).
#[derive(Debug, Clone, Copy, Default)]
pub struct RealClock;

impl Clock for RealClock {
    fn now(&self) -> Instant {
        Instant::now()
    }

    /// Sleeps to [`SPIN_TAIL`] before `deadline`, then spins to it.
    fn sleep_until(&self, deadline: Instant) {
        let left = deadline.saturating_duration_since(Instant::now());
        if left > SPIN_TAIL {
            std::thread::sleep(left - SPIN_TAIL);
        }
        while Instant::now() < deadline {
            std::hint::spin_loop();
        }
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn a_thread_sharpens_its_own_timers_and_no_other_thread_s() {
        let before = rustix::thread::current_timer_slack().unwrap();
        let sharp = std::thread::spawn(|| {
            let set = sharp_timers();
            (set, rustix::thread::current_timer_slack().unwrap())
        })
        .join()
        .unwrap();
        assert_eq!(sharp, (true, SHARP_TIMER_SLACK_NS));
        assert_eq!(rustix::thread::current_timer_slack().unwrap(), before);
    }

    #[test]
    fn the_real_clock_sleeps_until_its_deadline_through_the_spin_tail() {
        let c = RealClock;
        for wait in [Duration::ZERO, SPIN_TAIL / 2, 3 * SPIN_TAIL] {
            let deadline = Instant::now() + wait;
            c.sleep_until(deadline);
            assert!(
                Instant::now() >= deadline,
                "woke before the deadline ({wait:?})"
            );
        }
    }

    #[test]
    fn a_deadline_past_returns_at_once_and_a_manual_clock_jumps_to_its_deadline() {
        let past = Instant::now();
        std::thread::sleep(Duration::from_millis(1));
        // Past the deadline the real clock neither sleeps nor spins: no panic, no wait to speak of.
        RealClock.sleep_until(past);

        let m = ManualClock::new();
        let deadline = m.now() + Duration::from_millis(7);
        m.sleep_until(deadline);
        assert_eq!(m.now(), deadline);
        m.sleep_until(deadline - Duration::from_millis(1));
        assert_eq!(m.now(), deadline, "a manual clock never goes back");
    }
}
