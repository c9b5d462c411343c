//! Routes and ways planned beside the loop. A `goto` or `path` among obstacles whose routes
//! need more than a tick can spare ([`tick_route_work`]; a large polygon has many corners to
//! thread) is planned on a thread of its own with the whole budget a command may spend
//! ([`MAX_ROUTE_WORK`]), and so is every `reach`'s way in joint space (tens to hundreds of
//! milliseconds, [`crate::reach`]), while the loop ticks on, reading, publishing and serving
//! every command. Only the routes of the command waiting for them are planned: the thread skips a
//! job whose command has ended. The job queue holds two; a command that finds it full (the
//! thread has not run since) is refused `busy`.
//!
//! The thread is started on first use, steps aside for the loop (leaving a real-time policy
//! the loop's thread gave it, [`crate::beside::step_aside_from_the_loop`]), and ends with the
//! loop (its job queue closes).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::sync::Arc;
use std::thread;
use std::time::Duration;

use crate::control::{plan, PlanRequest, Planned, Refused};
use crate::world::MAX_ROUTE_WORK;

/// Most route work the loop spends within a tick, in checks of a segment against an edge or a
/// circle: what a tenth of the period allows at 8 ns a check (2 to 8 ns on a small machine),
/// at most 100,000 (0.8 ms), at least 2,000. A post and a shelf take a few thousand, planned in
/// the tick at 1 kHz and below; routes that need more are planned beside the loop.
pub fn tick_route_work(period: Duration) -> u64 {
    const CHECK_S: f64 = 8e-9;
    ((0.1 * period.as_secs_f64() / CHECK_S) as u64).clamp(2_000, 100_000)
}

/// How often one command's routes are planned again (the tip or the world moved while they
/// were planned) before the command is refused `busy`.
pub const MAX_REPLANS: u32 = 8;

/// A route to plan, numbered.
struct Job {
    serial: u64,
    request: PlanRequest,
}

/// A planned route (or why there is none), numbered as its job.
struct Done {
    serial: u64,
    route: Result<Planned, Refused>,
}

/// The planning thread's ends.
struct Worker {
    jobs: SyncSender<Job>,
    done: Receiver<Done>,
    /// The first serial whose command still waits for it: the thread skips the jobs numbered
    /// below it (their commands ended, or a later job took their place).
    wanted: Arc<AtomicU64>,
}

/// What became of a job.
#[derive(Debug)]
pub enum Polled {
    /// Still being planned.
    Waiting,
    /// Planned, or refused.
    Done(Result<Planned, Refused>),
    /// The thread is gone (it panicked): nothing will come.
    Gone,
}

/// The planning thread, started on first use.
#[derive(Default)]
pub struct Planner {
    worker: Option<Worker>,
    serial: u64,
    /// The last result taken off the queue and not yet asked for.
    ready: Option<Done>,
    gone: bool,
}

impl std::fmt::Debug for Planner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Planner")
            .field("started", &self.worker.is_some())
            .field("serial", &self.serial)
            .finish()
    }
}

impl Planner {
    /// Hands `request` to the thread; its serial for [`Planner::poll`]. The job it hands
    /// over before is no longer waited for. Refused when the thread cannot be started, or has
    /// stopped, or its queue is full; a refused request changes nothing (the job waited for
    /// before still is).
    pub fn send(&mut self, request: PlanRequest) -> Result<u64, String> {
        if self.worker.is_none() {
            self.worker = Some(spawn().map_err(|e| format!("no thread to plan on: {e}"))?);
        }
        let Some(worker) = &self.worker else {
            return Err("no thread to plan on".into());
        };
        let serial = self.serial + 1;
        let job = Job { serial, request };
        match worker.jobs.try_send(job) {
            Ok(()) => {
                self.serial = serial;
                // Stored once queued: the thread may have taken the job already, and skips
                // only jobs below `wanted`, which was at most `serial` until now.
                worker.wanted.store(serial, Ordering::Relaxed);
                Ok(serial)
            }
            Err(TrySendError::Full(_)) => {
                Err("the planner still has the work of earlier commands to do".into())
            }
            Err(TrySendError::Disconnected(_)) => {
                self.gone = true;
                Err("the planner has stopped".into())
            }
        }
    }

    /// No command waits for routes any more: the thread skips the jobs it still holds.
    pub fn cancel(&mut self) {
        if let Some(worker) = &self.worker {
            worker.wanted.store(self.serial + 1, Ordering::Relaxed);
        }
    }

    /// The job `serial`'s result if it has come. Results of other jobs (commands that ended
    /// before their routes came) are dropped.
    pub fn poll(&mut self, serial: u64) -> Polled {
        self.drain();
        match self.ready.take() {
            Some(done) if done.serial == serial => Polled::Done(done.route),
            Some(other) if other.serial > serial => {
                self.ready = Some(other);
                Polled::Waiting
            }
            _ if self.gone => Polled::Gone,
            _ => Polled::Waiting,
        }
    }

    /// Takes what the thread has finished, keeping the newest.
    fn drain(&mut self) {
        let Some(worker) = &self.worker else {
            return;
        };
        loop {
            match worker.done.try_recv() {
                Ok(done) => self.ready = Some(done),
                Err(TryRecvError::Empty) => return,
                Err(TryRecvError::Disconnected) => {
                    self.gone = true;
                    return;
                }
            }
        }
    }

    /// Blocks until the thread has finished its jobs in hand (tests: the loop's own clock is
    /// manual, the planner's work takes real time).
    #[cfg(test)]
    pub fn wait(&mut self, serial: u64, timeout: std::time::Duration) -> bool {
        let Some(worker) = &self.worker else {
            return false;
        };
        while self.ready.as_ref().is_none_or(|d| d.serial < serial) {
            match worker.done.recv_timeout(timeout) {
                Ok(done) => self.ready = Some(done),
                Err(_) => return false,
            }
        }
        true
    }
}

/// The thread: plans each job with the whole budget, until the loop drops its end.
fn spawn() -> std::io::Result<Worker> {
    let (jobs, inbox) = mpsc::sync_channel::<Job>(2);
    let (outbox, done) = mpsc::sync_channel::<Done>(2);
    let wanted = Arc::new(AtomicU64::new(0));
    let wanted_here = Arc::clone(&wanted);
    thread::Builder::new()
        .name("planner".into())
        .spawn(move || {
            // Started by the loop's thread, it would share its real-time policy.
            crate::beside::step_aside_from_the_loop();
            while let Ok(job) = inbox.recv() {
                if job.serial < wanted_here.load(Ordering::Relaxed) {
                    continue;
                }
                let route = plan(&job.request, MAX_ROUTE_WORK);
                if job.serial < wanted_here.load(Ordering::Relaxed) {
                    continue;
                }
                let done = Done {
                    serial: job.serial,
                    route,
                };
                if outbox.send(done).is_err() {
                    return;
                }
            }
        })?;
    Ok(Worker { jobs, done, wanted })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tick_spends_on_routes_a_tenth_of_its_period() {
        let ms = Duration::from_millis;
        assert_eq!(tick_route_work(ms(1)), 12_500);
        assert_eq!(tick_route_work(ms(10)), 100_000);
        assert_eq!(tick_route_work(Duration::from_micros(500)), 6_250);
        assert_eq!(tick_route_work(Duration::from_micros(100)), 2_000);
    }
}
