//! The signals that end a long-running command the way its own quit does (teleop's `q`, the
//! demo's failure path): `kill`, a terminal hung up, and an interrupt. The command looks at
//! [`Signals::received`] in its loop and winds down (the arm brought to rest, the recording
//! closed); a second signal ends the process at once, should that way out be stuck.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

/// The signals caught: SIGTERM, SIGHUP and SIGINT.
pub(crate) const QUIT_SIGNALS: [i32; 3] = [
    signal_hook::consts::SIGTERM,
    signal_hook::consts::SIGHUP,
    signal_hook::consts::SIGINT,
];

/// Which of [`QUIT_SIGNALS`] came, for a loop to end on (clones see the same).
#[derive(Clone)]
pub(crate) struct Signals(Arc<AtomicUsize>);

/// The process ends on a signal ([`stopped_by`] made its failure).
static ENDING_ON_SIGNAL: AtomicBool = AtomicBool::new(false);

impl Signals {
    /// Catches [`QUIT_SIGNALS`]. A second one ends the process at once (exit status 128 plus
    /// its number).
    pub(crate) fn catch() -> std::io::Result<Signals> {
        let which = Arc::new(AtomicUsize::new(0));
        let armed = Arc::new(AtomicBool::new(false));
        for signal in QUIT_SIGNALS {
            // Registered first, so the first signal finds it disarmed.
            signal_hook::flag::register_conditional_shutdown(
                signal,
                128 + signal,
                Arc::clone(&armed),
            )?;
            signal_hook::flag::register(signal, Arc::clone(&armed))?;
            signal_hook::flag::register_usize(signal, Arc::clone(&which), signal as usize)?;
        }
        Ok(Signals(which))
    }

    /// The signal that came, if one did.
    pub(crate) fn received(&self) -> Option<i32> {
        match self.0.load(Ordering::SeqCst) {
            0 => None,
            n => i32::try_from(n).ok(),
        }
    }
}

/// What a command ended by `signal` exits with: 128 plus its number, and its name.
pub(crate) fn stopped_by(signal: i32) -> super::Failure {
    ENDING_ON_SIGNAL.store(true, Ordering::SeqCst);
    super::Failure {
        code: u8::try_from(128 + signal).unwrap_or(1),
        error: anyhow::anyhow!(
            "stopped by {}",
            signal_hook::low_level::signal_name(signal).unwrap_or("a signal")
        ),
    }
}

/// Whether the process ends on a signal: its last line then waits only so long for a terminal
/// that takes no output ([`super::term_out::LAST_LINE_WAIT`]), since the signal asked it to end.
pub(crate) fn ending_on_signal() -> bool {
    ENDING_ON_SIGNAL.load(Ordering::SeqCst)
}

/// Lets a write past the file-size limit (`ulimit -f`, RLIMIT_FSIZE) fail with EFBIG instead
/// of SIGXFSZ ending the process: a recording then stops as on a full disk, and the arm goes
/// on. A handler, not an ignore: signal-hook installs one without unsafe code, and a program
/// this one starts gets the default back.
pub(crate) fn survive_file_size_limit() -> std::io::Result<()> {
    signal_hook::flag::register(
        signal_hook::consts::SIGXFSZ,
        Arc::new(AtomicBool::new(false)),
    )
    .map(drop)
}
