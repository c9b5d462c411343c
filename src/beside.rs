//! Threads beside the control loop (the recorder, the Foxglove view, the Zenoh bridge) step
//! aside for it: each lowers its own scheduling priority when it starts, so that on a machine
//! with few cores the loop, its port threads and the servos' replies win the CPU when they
//! wake, and what the side threads do shows in their own latency, not in the loop's ticks.
//!
//! On Linux the nice value belongs to each thread, and threads a side thread starts (a
//! runtime's workers) inherit it. A thread may always lower its own priority, so this needs
//! no privilege; where it fails or the platform has no per-thread nice, nothing changes.
//! Under a real-time policy (`chrt`) nice values do not apply.
//!
//! The loop and its port threads go the other way: their timed waits end on time
//! ([`crate::servo::clock::sharp_timers`]).

/// How much lower than the process a side thread runs, in nice steps: at +10 the scheduler
/// gives a busy side thread about a tenth of what it gives the loop.
pub const STEP_ASIDE_NICE: i32 = 10;

/// Lowers the calling thread's priority by [`STEP_ASIDE_NICE`] (at most to 19, the lowest).
/// Returns the nice value it now runs at, `None` where that could not be done (logged at debug
/// level, naming the thread).
pub fn step_aside() -> Option<i32> {
    let nice = lower_own_priority();
    if nice.is_none() {
        let thread = std::thread::current();
        let name = thread.name().unwrap_or("a side thread");
        tracing::debug!("{name}: runs at the loop's priority (could not lower it)");
    }
    nice
}

fn lower_own_priority() -> Option<i32> {
    #[cfg(target_os = "linux")]
    {
        use rustix::process::{getpriority_process, setpriority_process};
        let tid = rustix::thread::gettid();
        let now = getpriority_process(Some(tid)).ok()?;
        let lower = (now + STEP_ASIDE_NICE).min(19);
        setpriority_process(Some(tid), lower).ok()?;
        Some(lower)
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}

#[cfg(all(test, target_os = "linux"))]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_side_thread_runs_lower_and_the_thread_that_started_it_does_not() {
        let before = rustix::process::getpriority_process(None).unwrap();
        let side = std::thread::spawn(|| {
            let set = step_aside();
            let tid = rustix::thread::gettid();
            (
                set,
                rustix::process::getpriority_process(Some(tid)).unwrap(),
            )
        })
        .join()
        .unwrap();
        let expected = (before + STEP_ASIDE_NICE).min(19);
        assert_eq!(side, (Some(expected), expected));
        let tid = rustix::thread::gettid();
        assert_eq!(
            rustix::process::getpriority_process(Some(tid)).unwrap(),
            before
        );
    }
}
