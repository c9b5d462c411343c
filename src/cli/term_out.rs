//! Writing to a terminal that may stop taking output (the program on its other side stopped
//! reading it, or flow control held it) without being stuck there.
//!
//! A `write(2)` to such a terminal blocks, and a caught signal does not end it (the signal
//! handlers restart it), so a program blocked there would never see the signal that asks it to
//! end. [`TermOut`] writes through a description of the terminal of its own, opened without
//! blocking (standard output's own is shared with the shell, which must not find it changed),
//! and waits for room in `poll(2)`, a little at a time, asking its caller each time whether to
//! give up.

use std::io::{self, Write as _};
use std::os::fd::{AsFd, OwnedFd};
use std::time::{Duration, Instant};

use rustix::event::{poll, PollFd, PollFlags, Timespec};
use rustix::fs::{Mode, OFlags};
use rustix::io::Errno;

/// The longest one wait for room lasts before the caller is asked again whether to give up
/// (20 ms): how late a signal or a deadline may be noticed.
const RECHECK: Timespec = Timespec {
    tv_sec: 0,
    tv_nsec: 20_000_000,
};

/// How long the last line (`snakectl: stopped by SIGTERM`) may wait for a terminal that takes
/// no output, when the process ends on a signal: past it the line is lost and the process
/// exits all the same.
pub(crate) const LAST_LINE_WAIT: Duration = Duration::from_millis(500);

/// A terminal's output, opened anew without blocking.
pub(crate) struct TermOut {
    fd: OwnedFd,
}

impl TermOut {
    /// The terminal `of` is open on, opened again for writing without blocking; `None` when
    /// `of` is not a terminal or it cannot be opened again (then write to `of` itself).
    pub(crate) fn reopen(of: impl AsFd) -> Option<TermOut> {
        let of = of.as_fd();
        if !rustix::termios::isatty(of) {
            return None;
        }
        let path = rustix::termios::ttyname(of, Vec::new()).ok()?;
        let flags = OFlags::WRONLY | OFlags::NONBLOCK | OFlags::NOCTTY | OFlags::CLOEXEC;
        let fd = rustix::fs::open(path.as_c_str(), flags, Mode::empty()).ok()?;
        Some(TermOut { fd })
    }

    /// Writes all of `bytes`. While the terminal takes none of them it waits for room, and
    /// before each wait asks `give_up`: the error it returns ends the write, what is left of
    /// `bytes` unwritten.
    pub(crate) fn write_all(
        &self,
        mut bytes: &[u8],
        mut give_up: impl FnMut() -> Option<io::Error>,
    ) -> io::Result<()> {
        while !bytes.is_empty() {
            match rustix::io::write(&self.fd, bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(Errno::INTR) => {}
                Err(Errno::AGAIN) => {
                    if let Some(e) = give_up() {
                        return Err(e);
                    }
                    let mut fds = [PollFd::new(&self.fd, PollFlags::OUT)];
                    match poll(&mut fds, Some(&RECHECK)) {
                        Ok(_) | Err(Errno::INTR) => {}
                        Err(e) => return Err(e.into()),
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// Writes all of `bytes`, waiting at most until `deadline` for room.
    pub(crate) fn write_all_by(&self, bytes: &[u8], deadline: Instant) -> io::Result<()> {
        self.write_all(bytes, || {
            (Instant::now() >= deadline).then(|| {
                io::Error::new(
                    io::ErrorKind::TimedOut,
                    "the terminal took no output in the time allowed",
                )
            })
        })
    }
}

/// Writes `bytes` to standard error. With `wait`, a terminal there that takes no output is
/// given up on after `wait` (the rest is lost); without, the write waits as long as it takes.
pub(crate) fn to_stderr(bytes: &[u8], wait: Option<Duration>) -> io::Result<()> {
    let stderr = io::stderr();
    match wait.and_then(|wait| Some((TermOut::reopen(&stderr)?, wait))) {
        Some((term, wait)) => term.write_all_by(bytes, Instant::now() + wait),
        None => stderr.lock().write_all(bytes),
    }
}
