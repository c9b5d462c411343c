//! The subcommands, one module each, and the error type they share.

pub mod servo;
pub mod sim;
pub mod simulate;
pub mod solve;

/// An error and the exit code it maps to: 2 for bad input (a file, a flag, a config), 1 for
/// anything else (I/O, the operating system).
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
