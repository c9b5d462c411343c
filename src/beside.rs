//! Who wins a core: the control loop and the threads beside it.
//!
//! Threads beside the control loop (the recorder, the Foxglove view, the Zenoh bridge) step
//! aside for it: each lowers its own scheduling priority when it starts ([`step_aside`]), so
//! that on a machine with few cores the loop, its port threads and the servos' replies win the
//! CPU when they wake, and what the side threads do shows in their own latency, not in the
//! loop's ticks. On Linux the nice value belongs to each thread, and threads a side thread
//! starts (a runtime's workers) inherit it. A thread may always lower its own priority, so this
//! needs no privilege; where it fails or the platform has no per-thread nice, nothing changes.
//!
//! The loop and its port threads go the other way: their timed waits end on time
//! ([`crate::servo::clock::sharp_timers`]), and with `[control] realtime_priority` the loop's
//! thread takes a real-time policy ([`realtime`]) before it opens the bus, so that the threads
//! it starts (each port's, an embedded simulator's, which stands in for the servos) inherit it.
//! Nice values weigh only threads of the normal policy against each other; a real-time thread
//! runs ahead of them all, whatever else the machine runs. The side threads are started
//! elsewhere and keep the normal policy.

use thread_priority::{
    NormalThreadSchedulePolicy, RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue,
    ThreadSchedulePolicy,
};

/// The real-time priorities `SCHED_FIFO` takes on Linux.
pub const REALTIME_PRIORITIES: std::ops::RangeInclusive<u8> = 1..=99;

/// Why the calling thread could not take a real-time policy.
#[derive(Debug, thiserror::Error)]
#[error("cannot run under SCHED_FIFO at priority {priority}: {source}{hint}")]
pub struct RealtimeError {
    /// The priority asked for.
    pub priority: u8,
    /// What the system answered.
    #[source]
    pub source: std::io::Error,
    hint: &'static str,
}

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1 to 99, higher first): it then
/// runs whenever it is ready, ahead of every thread of the normal policy, whatever their nice
/// value. Threads it starts afterwards inherit the policy. Needs root, `CAP_SYS_NICE` or an
/// `RLIMIT_RTPRIO` (`ulimit -r`) of at least `priority`; a refusal says so.
pub fn realtime(priority: u8) -> Result<(), RealtimeError> {
    let refused = |source: std::io::Error| {
        let hint = if source.kind() == std::io::ErrorKind::PermissionDenied {
            " (it needs root, CAP_SYS_NICE, or an RLIMIT_RTPRIO of at least the priority: \
             `ulimit -r`)"
        } else {
            ""
        };
        RealtimeError {
            priority,
            source,
            hint,
        }
    };
    let value = REALTIME_PRIORITIES
        .contains(&priority)
        .then(|| ThreadPriorityValue::try_from(priority).ok())
        .flatten()
        .ok_or_else(|| {
            refused(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "the priority must be 1 to 99",
            ))
        })?;
    thread_priority::set_thread_priority_and_policy(
        thread_priority::thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| {
        refused(match e {
            thread_priority::Error::OS(code) => std::io::Error::from_raw_os_error(code),
            other => std::io::Error::other(other.to_string()),
        })
    })?;
    tracing::info!(
        thread = std::thread::current().name().unwrap_or("a thread"),
        priority,
        "runs under SCHED_FIFO"
    );
    Ok(())
}

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

/// For a thread the loop starts to work beside it (a route's planning, up to tens of
/// milliseconds of CPU): a real-time policy inherited from the loop is left for the normal one
/// at its lowest priority (nice 19), so that it never takes a core from the loop, its ports or
/// the servos' replies; under the normal policy it steps aside as the side threads do
/// ([`step_aside`]). A thread may always lower its own priority: this needs no privilege.
pub fn step_aside_from_the_loop() {
    let native = thread_priority::thread_native_id();
    let inherited = thread_priority::thread_schedule_policy_param(native);
    if !matches!(inherited, Ok((ThreadSchedulePolicy::Realtime(_), _))) {
        step_aside();
        return;
    }
    let normal = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Other);
    if let Err(e) =
        thread_priority::set_thread_priority_and_policy(native, ThreadPriority::Min, normal)
    {
        let thread = std::thread::current();
        let name = thread.name().unwrap_or("a thread beside the loop");
        tracing::warn!("{name}: keeps the loop's real-time policy (could not leave it: {e})");
    }
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

    /// The calling thread's policy and priority.
    fn policy() -> (ThreadSchedulePolicy, i32) {
        let (policy, params) =
            thread_priority::thread_schedule_policy_param(thread_priority::thread_native_id())
                .unwrap();
        (policy, params.sched_priority)
    }

    const FIFO: ThreadSchedulePolicy =
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo);

    #[test]
    fn a_priority_outside_fifos_range_is_refused_whatever_the_privileges() {
        for bad in [0, 100, 255] {
            let e = std::thread::spawn(move || realtime(bad))
                .join()
                .unwrap()
                .unwrap_err();
            assert_eq!(e.source.kind(), std::io::ErrorKind::InvalidInput, "{e}");
            assert!(e.to_string().contains("1 to 99"), "{e}");
        }
    }

    #[test]
    fn a_thread_that_takes_fifo_runs_it_and_so_do_the_threads_it_starts_but_not_its_parent() {
        let before = policy();
        let (took, inside, child) = std::thread::spawn(|| {
            let took = realtime(7);
            let child = std::thread::spawn(policy).join().unwrap();
            (took, policy(), child)
        })
        .join()
        .unwrap();
        match took {
            Ok(()) => {
                assert_eq!(inside, (FIFO, 7));
                assert_eq!(child, (FIFO, 7));
            }
            // Without the privilege: the error says what is missing, and nothing changed.
            Err(e) => {
                assert_eq!(e.source.kind(), std::io::ErrorKind::PermissionDenied, "{e}");
                assert!(e.to_string().contains("CAP_SYS_NICE"), "{e}");
                assert_eq!(inside, before);
            }
        }
        assert_eq!(policy(), before);
    }

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

    #[test]
    fn a_thread_the_loop_starts_to_work_beside_it_leaves_its_real_time_policy() {
        let before = rustix::process::getpriority_process(None).unwrap();
        let (took, after, nice) = std::thread::spawn(|| {
            let took = realtime(7).is_ok();
            step_aside_from_the_loop();
            let tid = rustix::thread::gettid();
            (
                took,
                policy(),
                rustix::process::getpriority_process(Some(tid)).unwrap(),
            )
        })
        .join()
        .unwrap();
        let normal = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Other);
        assert_eq!(after, (normal, 0));
        // From the loop's real-time policy to the lowest normal priority; without the privilege
        // to take it, stepped aside as the side threads do.
        let expected = if took {
            19
        } else {
            (before + STEP_ASIDE_NICE).min(19)
        };
        assert_eq!(nice, expected);
    }
}
