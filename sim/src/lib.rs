//! Virtual Dynamixel X-series servos speaking Protocol 2.0 over a pseudo-terminal.
//!
//! A chain of simulated XL430-W250, XM430-W350 and XL330-M288 servos that a Protocol 2.0 client
//! cannot tell from hardware: same packets, same CRCs, same error codes, same control tables,
//! with a motor model, optional wire timing and seeded fault injection. It takes plain data
//! ([`SimConfig`]) and depends on nothing of the controller.
//!
//! Layout, lowest layer first:
//! - [`protocol`]: CRC-16, byte stuffing, packet encoding, a streaming parser (pure);
//! - [`table`]: the per-model control tables (address, size, access, range, initial value);
//! - [`servo`]: one servo: memory, write rules, hardware errors, watchdog, motor model;
//! - [`chain`]: the bus: dispatch, reply order, Status Return Level, wire timing, faults;
//! - [`adapter`]: the USB-serial adapter between bus and host (an FTDI chip's USB packets and
//!   latency timer), pure;
//! - [`clock`]: the injectable time source ([`RealClock`], [`ManualClock`]);
//! - [`rng`]: the seeded generator behind the random faults;
//! - [`pty`]: serving a [`Simulator`] on a pseudo-terminal, on its own thread, with an optional
//!   link that survives a disconnect fault.
//!
//! ```
//! use std::sync::Arc;
//! use snakectl_sim::{protocol, ManualClock, Model, ServoSpec, SimConfig, Simulator};
//!
//! let config = SimConfig {
//!     servos: vec![ServoSpec::new(1, Model::Xl430W250)],
//!     ..SimConfig::default()
//! };
//! let mut sim = Simulator::new(config, Arc::new(ManualClock::new())).unwrap();
//! let replies = sim.handle_bytes(&protocol::encode_instruction(1, protocol::instruction::PING, &[]));
//! // Model number 1060 (0x0424), firmware 48.
//! assert_eq!(replies[0].bytes, protocol::encode_status(1, 0, &[0x24, 0x04, 48]));
//! ```

#![forbid(unsafe_code)]

pub mod adapter;
pub mod chain;
pub mod clock;
pub mod protocol;
pub mod pty;
pub mod rng;
pub mod servo;
pub mod table;

pub use adapter::{Adapter, FtdiReceiver, FTDI_DEFAULT_LATENCY, FTDI_PACKET_DATA};
pub use chain::{
    Fault, HardwareErrorKind, Reply, SimConfig, Simulator, Stats, UnknownHardwareError, Window,
    BAUD_RATES, DEFAULT_BOOT_TIME, MAX_BOOT_TIME,
};
pub use clock::{Clock, ManualClock, RealClock, SharedClock};
pub use pty::{spawn_pty, spawn_pty_linked, Link, SimHandle};
pub use servo::{Servo, ServoSpec};
pub use table::{Model, UnknownModel};

/// Errors of the simulator: configuration and pseudo-terminal.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// The baud rate is not one an X-series servo can be set to.
    #[error("baud rate {0} is not a Dynamixel baud rate (one of {BAUD_RATES:?})")]
    Baud(u32),
    /// Return Delay Time beyond the register's range or odd.
    #[error("return delay {0} µs: must be even and at most 508")]
    ReturnDelay(u32),
    /// A boot time beyond [`chain::MAX_BOOT_TIME`].
    #[error("boot time {0:?} exceeds 60 s")]
    BootTime(std::time::Duration),
    /// A servo id above 252.
    #[error("servo id {0} is out of range 0..=252")]
    BadId(u8),
    /// Two servos with the same id.
    #[error("servo id {0} appears twice")]
    DuplicateId(u8),
    /// Position limits out of order or beyond one turn.
    #[error("servo {id}: position limits {min}..={max} must satisfy min <= max <= 4095")]
    PositionLimits {
        /// Servo id.
        id: u8,
        /// Min Position Limit.
        min: u32,
        /// Max Position Limit.
        max: u32,
    },
    /// A fault names a servo that is not configured.
    #[error("fault names servo {0}, which is not on the bus")]
    FaultId(u8),
    /// An extra latency beyond [`chain::MAX_LATENCY`].
    #[error("fault latency {0:?} exceeds 60 s")]
    Latency(std::time::Duration),
    /// A fault window that closes before (or when) it opens.
    #[error("fault window {start:?}..{end:?}: the end must come after the start")]
    Window {
        /// Opening.
        start: std::time::Duration,
        /// Closing.
        end: std::time::Duration,
    },
    /// A hardware error inside a window: it latches at one instant.
    #[error("a hardware error fault latches at its `at` and cannot have a window")]
    WindowedHardwareError,
    /// A fault probability outside [0, 1].
    #[error("fault fraction {0} is outside [0, 1]")]
    Fraction(f64),
    /// The link asked for points at a pseudo-terminal still served (another simulator's, most
    /// likely): replacing it would strand that simulator's clients.
    #[error(
        "{} points at {}, a terminal still open (another `snakectl sim`?): stop that one, or \
         remove the link if it is not a simulator's", link.display(), target.display()
    )]
    LinkInUse {
        /// The link.
        link: std::path::PathBuf,
        /// Where it points.
        target: std::path::PathBuf,
    },
    /// The link's path holds something that is not a symlink (a file, a directory): it is
    /// made only where there is nothing or an old symlink, never in place of anything else.
    #[error(
        "{}: {what}, not a symlink: the link is made only where there is nothing or an old \
         symlink; give another path", link.display()
    )]
    LinkTaken {
        /// The link.
        link: std::path::PathBuf,
        /// What is there, e.g. "a regular file".
        what: &'static str,
    },
    /// Opening or configuring the pseudo-terminal failed.
    #[error("pseudo-terminal: {0}")]
    Pty(#[from] serialport::Error),
    /// Reading, writing or linking failed.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// The serving thread panicked.
    #[error("the serving thread panicked")]
    ThreadPanicked,
}
