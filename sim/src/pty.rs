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
//!
//! With `adapter` set to an FTDI chip ([`Adapter::Ftdi`]) the replies are not written as they
//! leave the bus but as the chip would hand them to the host: in USB packets of 62 data bytes,
//! or when its latency timer runs out (see [`crate::adapter`]).
//!
//! [`spawn_pty_linked`] also keeps a symlink ([`Link`]) pointing at the pseudo-terminal: the one
//! stable path while a [`Fault::Disconnect`](crate::Fault::Disconnect) unplugs the line. When
//! such a window opens, the thread closes both ends of the pty (a client's reads and writes then
//! fail, as with a USB adapter pulled out) and removes the link; when it closes, the chain comes
//! back on a new pseudo-terminal (a different `/dev/pts/N`: the next one is opened before the
//! old one is closed, so the kernel cannot hand the old number back) and the link points at it.
//! The simulator, and so every servo's state, lives on through the window.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};

use crate::adapter::{Adapter, FtdiReceiver};
use crate::chain::{Reply, Simulator};
use crate::servo::Servo;
use crate::SimError;

/// Longest the serving thread sleeps when no reply is pending: bounds how late it notices a stop
/// request and how often the motor model advances without traffic.
const IDLE_WAIT: Duration = Duration::from_millis(2);
/// Longest the serving thread sleeps at a time with wire timing, a reply pending or not: a
/// thread that sleeps for milliseconds lets its core idle deeply, and on a virtual machine it
/// then wakes a few hundred microseconds after the host's bytes come, which would start the
/// instruction's wire time that much late (a servo listens all the time), or after a reply's
/// deadline. Short sleeps wake promptly.
const LISTEN_WAIT: Duration = Duration::from_micros(150);
/// How close to a reply's deadline the thread stops sleeping and spins. Only wire timing makes
/// replies due in the future, so only it spins.
const SPIN_WINDOW: Duration = Duration::from_micros(80);
/// File name of the link inside a [`Link::Private`] directory.
const PRIVATE_LINK_NAME: &str = "port";

/// A symlink the handle keeps pointing at its current pseudo-terminal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Link {
    /// No link: clients open the pseudo-terminal itself ([`SimHandle::path`]).
    None,
    /// This path: created, or replaced when it is already a symlink that points at no open
    /// terminal (a symlink to one still served, or any other file, is an error); removed when
    /// the handle stops if it still points at the handle's pseudo-terminal.
    At(PathBuf),
    /// `port` in a new directory of its own (mode 0700) under [`std::env::temp_dir`]; both are
    /// removed when the handle stops.
    Private,
}

/// A running simulator on a pseudo-terminal. Dropping it stops the serving thread and removes
/// its link.
#[derive(Debug)]
pub struct SimHandle {
    path: PathBuf,
    link: Option<PathBuf>,
    owned: Option<Owned>,
    pty: Arc<Mutex<Option<PathBuf>>>,
    sim: Arc<Mutex<Simulator>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), SimError>>>,
}

/// What the handle created and removes when it stops.
#[derive(Debug)]
struct Owned {
    link: PathBuf,
    dir: Option<PathBuf>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Both ends of one pseudo-terminal and the slave's name.
struct Line {
    master: TTYPort,
    /// Held while serving: the slave must stay open, and its termios tell the client's rate.
    slave: TTYPort,
    path: PathBuf,
}

impl Line {
    fn open() -> Result<Self, SimError> {
        // The slave end stays as `pair()` leaves it: no TIOCEXCL and no flock, so any client may
        // open it (serialport's `set_exclusive(false)` would take a shared flock that blocks
        // clients asking for an exclusive one).
        let (master, slave) = TTYPort::pair()?;
        let path = slave
            .name()
            .map(PathBuf::from)
            .ok_or_else(|| std::io::Error::other("the pseudo-terminal has no name"))?;
        Ok(Self {
            master,
            slave,
            path,
        })
    }
}

/// Serve `sim` on a new pseudo-terminal; clients open [`SimHandle::path`] as a serial port.
pub fn spawn_pty(sim: Simulator) -> Result<SimHandle, SimError> {
    spawn_pty_linked(sim, Link::None)
}

/// Serve `sim` on a new pseudo-terminal with `link` kept pointing at it (see [`Link`]); clients
/// open [`SimHandle::path`], which is the link when there is one.
pub fn spawn_pty_linked(sim: Simulator, link: Link) -> Result<SimHandle, SimError> {
    let line = Line::open()?;
    let owned = match link {
        Link::None => None,
        Link::At(path) => Some(Owned {
            link: path,
            dir: None,
        }),
        Link::Private => {
            let dir = private_dir()?;
            Some(Owned {
                link: dir.join(PRIVATE_LINK_NAME),
                dir: Some(dir),
            })
        }
    };
    if let Some(owned) = &owned {
        if let Err(e) = create_link(&owned.link, &line.path) {
            remove_owned(owned, Some(&line.path));
            return Err(e);
        }
    }
    let link = owned.as_ref().map(|o| o.link.clone());
    let path = link.clone().unwrap_or_else(|| line.path.clone());
    let line_path = line.path.clone();
    let pty = Arc::new(Mutex::new(Some(line.path.clone())));
    let sim = Arc::new(Mutex::new(sim));
    let stop = Arc::new(AtomicBool::new(false));
    tracing::info!(pty = %line.path.display(), path = %path.display(), "simulated servo chain listening");
    let spawned = {
        let sim = Arc::clone(&sim);
        let stop = Arc::clone(&stop);
        let pty = Arc::clone(&pty);
        let link = link.clone();
        std::thread::Builder::new()
            .name("snakectl-sim".into())
            .spawn(move || serve(line, &sim, &stop, link.as_deref(), &pty))
    };
    let thread = match spawned {
        Ok(t) => t,
        Err(e) => {
            if let Some(owned) = &owned {
                remove_owned(owned, Some(&line_path));
            }
            return Err(e.into());
        }
    };
    Ok(SimHandle {
        path,
        link,
        owned,
        pty,
        sim,
        stop,
        thread: Some(thread),
    })
}

/// A new directory of this process's own under the temporary directory.
fn private_dir() -> std::io::Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let base = std::env::temp_dir();
    loop {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = base.join(format!("snakectl-sim-{}-{n}", std::process::id()));
        match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
            Ok(()) => return Ok(dir),
            // Left by an earlier process that had the same id: take the next name.
            Err(e) if e.kind() == ErrorKind::AlreadyExists && n < 1000 => {}
            Err(e) => return Err(e),
        }
    }
}

fn is_symlink(path: &Path) -> bool {
    path.symlink_metadata()
        .is_ok_and(|m| m.file_type().is_symlink())
}

/// What is at `path` when something other than a symlink is: "a regular file", "a directory",
/// ... (`None` when nothing is there, or a symlink).
fn not_a_symlink(path: &Path) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    let t = path.symlink_metadata().ok()?.file_type();
    if t.is_symlink() {
        return None;
    }
    Some(if t.is_file() {
        "a regular file"
    } else if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else {
        "something else"
    })
}

/// Where the symlink `link` points, when that is a terminal still open (a pseudo-terminal
/// exists while its master end is: another simulator serves it) and not `ours`, the one this
/// simulator has just opened. The kernel hands out the lowest free number, so a simulator
/// started again after one was killed usually gets the very `/dev/pts/N` its old link names:
/// that terminal is this one, and the link is stale.
fn live_target(link: &Path, ours: &Path) -> Option<PathBuf> {
    use std::os::unix::fs::{FileTypeExt, MetadataExt};
    let target = std::fs::read_link(link).ok()?;
    let meta = std::fs::metadata(link).ok()?;
    if !meta.file_type().is_char_device() {
        return None;
    }
    let is_ours = std::fs::metadata(ours).is_ok_and(|m| m.rdev() == meta.rdev());
    (!is_ours).then_some(target)
}

/// Make `link` a symlink to `target`, replacing an old symlink (one left dangling, or naming
/// `target` itself) but no other file, nor a symlink to a terminal still served.
fn create_link(link: &Path, target: &Path) -> Result<(), SimError> {
    let named =
        |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", link.display()));
    if let Some(what) = not_a_symlink(link) {
        return Err(SimError::LinkTaken {
            link: link.to_path_buf(),
            what,
        });
    }
    if is_symlink(link) {
        if let Some(live) = live_target(link, target) {
            return Err(SimError::LinkInUse {
                link: link.to_path_buf(),
                target: live,
            });
        }
        std::fs::remove_file(link).map_err(named)?;
    }
    std::os::unix::fs::symlink(target, link).map_err(named)?;
    Ok(())
}

/// Point the existing (or absent) symlink `link` at `target` in one step: clients never find
/// the path missing or half made.
fn repoint_link(link: &Path, target: &Path) -> std::io::Result<()> {
    let name = link
        .file_name()
        .map_or_else(Default::default, |n| n.to_string_lossy());
    let temp = link.with_file_name(format!(".{name}.{}.new", std::process::id()));
    if is_symlink(&temp) {
        std::fs::remove_file(&temp)?;
    }
    std::os::unix::fs::symlink(target, &temp)?;
    std::fs::rename(&temp, link).inspect_err(|_| {
        let _ = std::fs::remove_file(&temp);
    })
}

/// Remove the symlink `link` if it still points at `ours` (none: the link was removed already);
/// one pointing elsewhere is another simulator's now, and kept.
fn remove_link(link: &Path, ours: Option<&Path>) {
    let Some(ours) = ours else { return };
    if std::fs::read_link(link).is_ok_and(|t| t == ours) {
        if let Err(e) = std::fs::remove_file(link) {
            tracing::warn!(link = %link.display(), error = %e, "cannot remove the link");
        }
    }
}

fn remove_owned(owned: &Owned, ours: Option<&Path>) {
    remove_link(&owned.link, ours);
    if let Some(dir) = &owned.dir {
        if let Err(e) = std::fs::remove_dir(dir) {
            tracing::warn!(dir = %dir.display(), error = %e, "cannot remove the link's directory");
        }
    }
}

impl SimHandle {
    /// The path clients open: the link when there is one (stable across disconnects), else the
    /// pseudo-terminal served at the start (e.g. `/dev/pts/3`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The link kept pointing at the pseudo-terminal, if one was asked for.
    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }

    /// The pseudo-terminal served now; `None` while a disconnect fault has the line unplugged.
    /// A new one after every disconnect window.
    pub fn pty_path(&self) -> Option<PathBuf> {
        lock(&self.pty).clone()
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

    /// Stop serving, wait for the thread and remove the link; returns the error that ended the
    /// thread, if any.
    pub fn stop(mut self) -> Result<(), SimError> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Result<(), SimError> {
        self.stop.store(true, Ordering::Relaxed);
        let ended = match self.thread.take() {
            Some(t) => t.join().map_err(|_| SimError::ThreadPanicked)?,
            None => Ok(()),
        };
        if let Some(owned) = self.owned.take() {
            // The pseudo-terminal served last; none while unplugged (the link went with it).
            let ours = lock(&self.pty).clone();
            remove_owned(&owned, ours.as_deref());
        }
        ended
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

/// The serving loop: until `stop`, read, feed, and write replies at their deadlines; unplug
/// and plug back the line as disconnect faults say.
fn serve(
    line: Line,
    sim: &Mutex<Simulator>,
    stop: &AtomicBool,
    link: Option<&Path>,
    pty: &Mutex<Option<PathBuf>>,
) -> Result<(), SimError> {
    // The default slack (50 µs) would eat most of the spin window.
    crate::clock::sharp_timers();
    let clock = Arc::clone(lock(sim).clock());
    let mut line = Some(line);
    // The pseudo-terminal opened when the line went away, served when it comes back.
    let mut spare: Option<Line> = None;
    // Replies waiting for their deadline. Bounded by what one instruction can ask for (one
    // reply per servo); a client that stops reading only makes writes time out.
    let (mut pending, longest) = {
        let sim = lock(sim);
        let outbox = Outbox::new(sim.config().adapter, clock.now());
        let longest = if sim.config().wire_timing {
            LISTEN_WAIT
        } else {
            IDLE_WAIT
        };
        (outbox, longest)
    };
    let mut buf = [0u8; 4096];
    let mut baud_unreadable_logged = false;
    while !stop.load(Ordering::Relaxed) {
        let down = lock(sim).disconnected();
        if down == line.is_some() {
            if down {
                // Opened before the old one closes, so it gets another number.
                spare = Some(Line::open()?);
                let old = line.take();
                if let Some(old) = &old {
                    tracing::info!(pty = %old.path.display(), "fault: the line is unplugged");
                }
                pending.clear();
                lock(sim).line_lost();
                if let Some(link) = link {
                    remove_link(link, old.as_ref().map(|l| l.path.as_path()));
                }
                drop(old);
                *lock(pty) = None;
            } else {
                let new = match spare.take() {
                    Some(l) => l,
                    None => Line::open()?,
                };
                if let Some(link) = link {
                    if let Some(other) = live_target(link, &new.path) {
                        // Taken by another simulator while this line was unplugged: theirs now.
                        tracing::warn!(link = %link.display(), other = %other.display(), "the link points at another terminal now: left as it is");
                    } else if let Err(e) = repoint_link(link, &new.path) {
                        tracing::warn!(link = %link.display(), error = %e, "cannot point the link at the new pseudo-terminal");
                    }
                }
                tracing::info!(pty = %new.path.display(), "fault over: the line is back");
                *lock(pty) = Some(new.path.clone());
                line = Some(new);
            }
            continue;
        }
        let Some(Line { master, slave, .. }) = line.as_mut() else {
            // Unplugged: the servos live on.
            lock(sim).advance();
            std::thread::sleep(IDLE_WAIT);
            continue;
        };
        let now = clock.now();
        for (id, bytes) in pending.due(now) {
            send(master, id, &bytes);
        }
        let wait = match pending
            .next_at()
            .map(|at| (at, at.saturating_duration_since(now)))
        {
            None => longest,
            Some((at, left)) if left <= SPIN_WINDOW => {
                // A timed wait wakes tens of µs late (timer slack): spin the last stretch so
                // replies leave on time. Bounded in real time, in case the clock is manual.
                let give_up = Instant::now() + 2 * SPIN_WINDOW;
                while clock.now() < at && Instant::now() < give_up {
                    std::hint::spin_loop();
                }
                continue;
            }
            Some((_, left)) => (left - SPIN_WINDOW).min(longest),
        };
        master.set_timeout(wait)?;
        match master.read(&mut buf) {
            Ok(0) => {}
            Ok(n) => {
                let bytes = &buf[..n];
                tracing::debug!("rx {:02X?}", bytes);
                // Read after the bytes arrived: the rate they were sent at.
                let baud = client_baud(slave, &mut baud_unreadable_logged);
                let mut sim = lock(sim);
                sim.set_line_baud(baud);
                let replies = sim.handle_bytes(bytes);
                let byte_time = if sim.config().wire_timing {
                    sim.byte_time()
                } else {
                    Duration::ZERO
                };
                drop(sim);
                for reply in replies {
                    pending.push(reply, byte_time);
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

/// Bytes on their way to the host: the replies themselves, or an FTDI chip's packets.
enum Outbox {
    /// Replies waiting for their deadline, earliest first.
    Direct(VecDeque<Reply>),
    /// The chip that holds them.
    Ftdi(FtdiReceiver),
}

impl Outbox {
    fn new(adapter: Adapter, now: Instant) -> Self {
        match adapter {
            Adapter::Direct => Outbox::Direct(VecDeque::new()),
            Adapter::Ftdi { latency_timer } => Outbox::Ftdi(FtdiReceiver::new(latency_timer, now)),
        }
    }

    /// A reply of the bus, its bytes `byte_time` apart on the wire.
    fn push(&mut self, reply: Reply, byte_time: Duration) {
        match self {
            Outbox::Direct(pending) => {
                let at = pending.partition_point(|r| r.at <= reply.at);
                pending.insert(at, reply);
            }
            Outbox::Ftdi(chip) => chip.receive(&reply.bytes, reply.at, byte_time),
        }
    }

    /// What reaches the host by `now` (the replying servo's id, or 0xFE for an adapter's
    /// packet), in order.
    fn due(&mut self, now: Instant) -> Vec<(u8, Vec<u8>)> {
        match self {
            Outbox::Direct(pending) => {
                let mut out = Vec::new();
                while pending.front().is_some_and(|r| r.at <= now) {
                    if let Some(reply) = pending.pop_front() {
                        out.push((reply.id, reply.bytes));
                    }
                }
                out
            }
            Outbox::Ftdi(chip) => chip
                .deliver(now)
                .into_iter()
                .map(|(_, bytes)| (crate::protocol::BROADCAST_ID, bytes))
                .collect(),
        }
    }

    /// When the next bytes are due.
    fn next_at(&self) -> Option<Instant> {
        match self {
            Outbox::Direct(pending) => pending.front().map(|r| r.at),
            Outbox::Ftdi(chip) => chip.next_delivery(),
        }
    }

    fn clear(&mut self) {
        match self {
            Outbox::Direct(pending) => pending.clear(),
            Outbox::Ftdi(chip) => chip.clear(),
        }
    }
}

fn send(port: &mut TTYPort, id: u8, bytes: &[u8]) {
    tracing::debug!(id, "tx {:02X?}", bytes);
    if port.set_timeout(Duration::from_millis(50)).is_err() {
        return;
    }
    if let Err(e) = port.write_all(bytes) {
        // Nobody reads (the pty buffer is full): the reply is lost, as on a dead bus.
        tracing::debug!(id, error = %e, "reply not written");
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_link_left_naming_the_terminal_just_opened_is_replaced() {
        // A simulator killed with its link in place, then started again: the kernel gives the
        // new one the freed `/dev/pts/N`, so the old link names the new simulator's own terminal.
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("bus");
        let line = Line::open().unwrap();
        std::os::unix::fs::symlink(&line.path, &link).unwrap();
        create_link(&link, &line.path).unwrap();
        assert_eq!(std::fs::read_link(&link).unwrap(), line.path);
    }

    #[test]
    fn a_link_to_a_terminal_another_simulator_serves_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("bus");
        let other = Line::open().unwrap();
        let ours = Line::open().unwrap();
        std::os::unix::fs::symlink(&other.path, &link).unwrap();
        let err = create_link(&link, &ours.path).unwrap_err();
        assert!(matches!(err, SimError::LinkInUse { .. }), "{err}");
        assert_eq!(std::fs::read_link(&link).unwrap(), other.path);
    }
}
