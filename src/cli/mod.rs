//! The subcommands, one module each, and the error type they share.

pub mod client;
pub mod demo;
pub mod fleet;
pub mod plot;
pub mod run;
pub mod servo;
pub mod signals;
pub mod sim;
pub mod simulate;
pub mod solve;
pub mod teleop;
pub(crate) mod term_out;
pub mod urdf;
pub mod world;

/// `println!` for the subcommands: a closed pipe (`snakectl ... | head`) ends the command quietly
/// instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::cli::write_line(format_args!($($arg)*))
    };
}
pub(crate) use outln;

/// Logs to stderr through `tracing`: info, or debug with `verbose`; `RUST_LOG` overrides.
pub fn init_logs(verbose: bool) {
    let default = if verbose { "debug" } else { "info" };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .init();
}

/// Writes one line to stdout; a closed pipe becomes a quiet [`Failure`] with exit code 0.
pub fn write_line(args: std::fmt::Arguments<'_>) -> Result<(), Failure> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_fmt(args).and_then(|()| out.write_all(b"\n")) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(Failure {
            code: 0,
            error: e.into(),
        }),
        Err(e) => Err(Failure::other(e)),
    }
}

/// An error and the exit code it maps to: 2 for bad input (a file, a flag, a config), 1 for
/// anything else (I/O, the operating system), 0 for a reader that closed the pipe (nothing is
/// printed then).
pub struct Failure {
    /// Process exit code.
    pub code: u8,
    /// What went wrong, printed once as a chain.
    pub error: anyhow::Error,
}

impl Failure {
    /// Bad input: exit code 2.
    pub fn bad_input(error: impl Into<anyhow::Error>) -> Self {
        Self {
            code: 2,
            error: error.into(),
        }
    }

    /// Any other failure: exit code 1.
    pub fn other(error: impl Into<anyhow::Error>) -> Self {
        Self {
            code: 1,
            error: error.into(),
        }
    }
}

/// Refuses an `--out` that exists and is not a directory (a file, `/dev/null`), before any
/// work: the figures and tables go into a directory, made when missing.
pub fn check_out_dir(out: &std::path::Path) -> Result<(), Failure> {
    match std::fs::metadata(out) {
        Ok(m) if !m.is_dir() => Err(Failure::bad_input(anyhow::anyhow!(
            "--out {}: not a directory (it is {}; name a directory, new or existing)",
            out.display(),
            if m.is_file() {
                "a file"
            } else {
                "a device or other special file"
            }
        ))),
        _ => Ok(()),
    }
}
