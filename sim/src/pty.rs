//! Serving a [`Simulator`] on a pseudo-terminal.
//!
//! [`spawn_pty`] opens a pty pair, keeps the slave end open for the whole run (so a client may
//! close and reopen the port without the master reading EIO), and serves on its own thread: read
//! what the client wrote, feed the simulator, write each reply when its deadline has come. With
//! wire timing the thread waits for every deadline (a pty itself stores the baud rate but does no
//! timing). Traffic is logged with `tracing` at debug level.
//!
//! The rate the client set on its end (termios, read through the slave end the thread holds) is
//! handed to the simulator with every chunk it wrote, so only servos whose Baud Rate register
//! selects that rate hear and answer, as on a real bus. Where the rate cannot be read, the line
//! is assumed to run at the configured `baud` (logged once at debug level).

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};

use crate::chain::{Reply, Simulator};
use crate::servo::Servo;
use crate::SimError;

/// Longest the serving thread sleeps when no reply is pending: bounds how late it notices a stop
/// request and how often the motor model advances without traffic.
const IDLE_WAIT: Duration = Duration::from_millis(2);
/// How close to a reply's deadline the thread stops sleeping and spins. Only wire timing makes
/// replies due in the future, so only it spins.
const SPIN_WINDOW: Duration = Duration::from_micros(80);

/// A running simulator on a pseudo-terminal. Dropping it stops the serving thread.
#[derive(Debug)]
pub struct SimHandle {
    path: PathBuf,
    sim: Arc<Mutex<Simulator>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), SimError>>>,
}

fn lock(sim: &Mutex<Simulator>) -> MutexGuard<'_, Simulator> {
    sim.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Serve `sim` on a new pseudo-terminal; clients open [`SimHandle::path`] as a serial port.
pub fn spawn_pty(sim: Simulator) -> Result<SimHandle, SimError> {
    // The slave end stays as `pair()` leaves it: no TIOCEXCL and no flock, so any client may
    // open it (serialport's `set_exclusive(false)` would take a shared flock that blocks
    // clients asking for an exclusive one).
    let (master, slave) = TTYPort::pair()?;
    let path = slave
        .name()
        .map(PathBuf::from)
        .ok_or_else(|| std::io::Error::other("the pseudo-terminal has no name"))?;
    let sim = Arc::new(Mutex::new(sim));
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let sim = Arc::clone(&sim);
        let stop = Arc::clone(&stop);
        std::thread::Builder::new()
            .name("snakectl-sim".into())
            .spawn(move || {
                // Held until the thread ends: the slave must stay open while serving; its
                // termios tell the rate the client set.
                serve(master, &slave, &sim, &stop)
            })?
    };
    tracing::info!(path = %path.display(), "simulated servo chain listening");
    Ok(SimHandle {
        path,
        sim,
        stop,
        thread: Some(thread),
    })
}

impl SimHandle {
    /// Path of the pseudo-terminal (e.g. `/dev/pts/3`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Run `f` on the simulator while the serving thread waits.
    pub fn with_sim<R>(&self, f: impl FnOnce(&mut Simulator) -> R) -> R {
        f(&mut lock(&self.sim))
    }

    /// Run `f` on the servo whose current id is `id` (after advancing to the clock's now).
    pub fn with_servo<R>(&self, id: u8, f: impl FnOnce(&mut Servo) -> R) -> Option<R> {
        let mut sim = lock(&self.sim);
        sim.advance();
        sim.servo_mut(id).map(f)
    }

    /// The shared simulator, for callers that want to hold it themselves.
    pub fn simulator(&self) -> Arc<Mutex<Simulator>> {
        Arc::clone(&self.sim)
    }

    /// True until the serving thread ended (stopped, or failed).
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Stop serving and wait for the thread; returns the error that ended it, if any.
    pub fn stop(mut self) -> Result<(), SimError> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Result<(), SimError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| SimError::ThreadPanicked)?,
            None => Ok(()),
        }
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        if let Err(e) = self.shutdown() {
            tracing::warn!(error = %e, "simulator thread ended with an error");
        }
    }
}

/// The rate the client set on the terminal, or `None` (logged once) when it cannot be read.
fn client_baud(slave: &TTYPort, logged: &mut bool) -> Option<u32> {
    match slave.baud_rate() {
        Ok(baud) => Some(baud),
        Err(e) => {
            if !std::mem::replace(logged, true) {
                tracing::debug!(
                    error = %e,
                    "cannot read the client's baud rate: assuming the configured one, whatever the client sets"
                );
            }
            None
        }
    }
}

/// The serving loop: until `stop`, read, feed, and write replies at their deadlines.
fn serve(
    mut port: TTYPort,
    slave: &TTYPort,
    sim: &Mutex<Simulator>,
    stop: &AtomicBool,
) -> Result<(), SimError> {
    let clock = Arc::clone(lock(sim).clock());
    // Replies waiting for their deadline, earliest first. Bounded by what one instruction can
    // ask for (one reply per servo); a client that stops reading only makes writes time out.
    let mut pending: VecDeque<Reply> = VecDeque::new();
    let mut buf = [0u8; 4096];
    let mut baud_unreadable_logged = false;
    while !stop.load(Ordering::Relaxed) {
        let now = clock.now();
        while pending.front().is_some_and(|r| r.at <= now) {
            if let Some(reply) = pending.pop_front() {
                send(&mut port, &reply);
            }
        }
        let wait = match pending
            .front()
            .map(|r| (r.at, r.at.saturating_duration_since(now)))
        {
            None => IDLE_WAIT,
            Some((at, left)) if left <= SPIN_WINDOW => {
                // A timed wait wakes tens of µs late (timer slack): spin the last stretch so
                // replies leave on time. Bounded in real time, in case the clock is manual.
                let give_up = Instant::now() + 2 * SPIN_WINDOW;
                while clock.now() < at && Instant::now() < give_up {
                    std::hint::spin_loop();
                }
                continue;
            }
            Some((_, left)) => (left - SPIN_WINDOW).min(IDLE_WAIT),
        };
        port.set_timeout(wait)?;
        match port.read(&mut buf) {
            Ok(0) => {}
            Ok(n) => {
                let bytes = &buf[..n];
                tracing::debug!("rx {:02X?}", bytes);
                // Read after the bytes arrived: the rate they were sent at.
                let baud = client_baud(slave, &mut baud_unreadable_logged);
                let mut sim = lock(sim);
                sim.set_line_baud(baud);
                let replies = sim.handle_bytes(bytes);
                drop(sim);
                for reply in replies {
                    let at = pending.partition_point(|r| r.at <= reply.at);
                    pending.insert(at, reply);
                }
            }
            Err(e) if e.kind() == ErrorKind::TimedOut || e.kind() == ErrorKind::Interrupted => {
                lock(sim).advance();
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

fn send(port: &mut TTYPort, reply: &Reply) {
    tracing::debug!(id = reply.id, "tx {:02X?}", reply.bytes);
    if port.set_timeout(Duration::from_millis(50)).is_err() {
        return;
    }
    if let Err(e) = port.write_all(&reply.bytes) {
        // Nobody reads (the pty buffer is full): the reply is lost, as on a dead bus.
        tracing::debug!(id = reply.id, error = %e, "reply not written");
    }
}
