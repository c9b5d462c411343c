//! Typed errors of the servo layer: every variant names the servo (when one is concerned) and
//! carries the numbers a user needs (the status error code and its meaning, the alert flag, how
//! long the reply was waited for, the checksums, the limits).

use std::path::PathBuf;
use std::time::Duration;

use super::lock::Holder;
use super::Register;

/// The meaning of a Protocol 2.0 status error code (the low 7 bits of the error byte).
pub fn status_meaning(code: u8) -> &'static str {
    match code {
        0 => "no error",
        1 => "result fail: the instruction could not be carried out",
        2 => "instruction error: unknown instruction, or ACTION without REG_WRITE",
        3 => "CRC error: the servo received a damaged packet",
        4 => "data range error: the value is outside the item's own range",
        5 => "data length error: fewer bytes than the item needs",
        6 => "data limit error: the value is outside a limit item (e.g. the position limits)",
        7 => "access error: read-only or undefined address, or EEPROM written with torque on",
        _ => "unknown status error",
    }
}

/// The bits of Hardware Error Status (address 70).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HardwareErrors(pub u8);

impl HardwareErrors {
    /// Input voltage out of the configured range (bit 0).
    pub const INPUT_VOLTAGE: u8 = 0x01;
    /// Overheating (bit 2).
    pub const OVERHEATING: u8 = 0x04;
    /// Motor encoder error (bit 3).
    pub const ENCODER: u8 = 0x08;
    /// Electrical shock (bit 4).
    pub const ELECTRICAL_SHOCK: u8 = 0x10;
    /// Overload (bit 5).
    pub const OVERLOAD: u8 = 0x20;

    const NAMES: [(u8, &'static str); 5] = [
        (Self::INPUT_VOLTAGE, "input voltage"),
        (Self::OVERHEATING, "overheating"),
        (Self::ENCODER, "motor encoder"),
        (Self::ELECTRICAL_SHOCK, "electrical shock"),
        (Self::OVERLOAD, "overload"),
    ];

    /// True when no bit is set.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The names of the bits that are set (unknown bits as `bit N`).
    pub fn names(self) -> Vec<String> {
        let mut out = Vec::new();
        for bit in 0..8 {
            let mask = 1u8 << bit;
            if self.0 & mask == 0 {
                continue;
            }
            match Self::NAMES.iter().find(|(m, _)| *m == mask) {
                Some((_, name)) => out.push((*name).to_string()),
                None => out.push(format!("bit {bit}")),
            }
        }
        out
    }
}

impl std::fmt::Display for HardwareErrors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_empty() {
            write!(f, "none")
        } else {
            write!(f, "{} (0x{:02X})", self.names().join(", "), self.0)
        }
    }
}

/// What [`ServoError::InUse`] says: the port (and the device, when a symlink named it), who has
/// it, and that one program at a time drives a port.
fn in_use_text(
    port: &std::path::Path,
    device: &std::path::Path,
    holder: Option<&Holder>,
) -> String {
    let name = if port == device {
        port.display().to_string()
    } else {
        format!("{} ({})", port.display(), device.display())
    };
    match holder {
        Some(holder) => format!(
            "{name} is in use by {holder}: one program at a time drives a port; stop that one \
             first"
        ),
        None => format!(
            "{name} is in use by another process, one not visible from here (another container \
             or PID namespace): one program at a time drives a port"
        ),
    }
}

fn alert_note(alert: bool) -> &'static str {
    if alert {
        "; alert flag set: read Hardware Error Status"
    } else {
        ""
    }
}

/// What went wrong talking to a servo.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServoError {
    /// No (complete) reply before the deadline.
    #[error("servo {id}: no reply within {:.1} ms", waited.as_secs_f64() * 1e3)]
    Timeout {
        /// The servo.
        id: u8,
        /// How long the reply was waited for.
        waited: Duration,
    },
    /// A reply arrived damaged.
    #[error(
        "servo {id}: damaged reply (CRC 0x{received:04X} received, 0x{computed:04X} computed)"
    )]
    Checksum {
        /// The servo the reply was expected from.
        id: u8,
        /// CRC in the packet.
        received: u16,
        /// CRC of the bytes received.
        computed: u16,
    },
    /// The servo answered with a status error: the instruction was not carried out.
    #[error("servo {id}: status error {code}: {}{}", status_meaning(*code), alert_note(*alert))]
    Status {
        /// The servo.
        id: u8,
        /// Error code (low 7 bits of the error byte).
        code: u8,
        /// The alert bit (a hardware error is latched), a flag beside the code.
        alert: bool,
    },
    /// A reply that is not what the instruction asks for (length, instruction, id).
    #[error("servo {id}: unexpected reply: {what}")]
    Malformed {
        /// The servo the reply was expected from.
        id: u8,
        /// What was wrong.
        what: String,
    },
    /// A reply from another servo than the one addressed.
    #[error("servo {id}: the reply came from servo {from}")]
    WrongId {
        /// The servo addressed.
        id: u8,
        /// The id in the reply.
        from: u8,
    },
    /// A value that does not fit the register.
    #[error("servo {id}: {value} does not fit {register:?} ({} bytes)", register.size())]
    ValueRange {
        /// The servo.
        id: u8,
        /// The register.
        register: Register,
        /// The refused value.
        value: i64,
    },
    /// A goal outside the joint's limits, refused by the limits wrapper.
    #[error("servo {id}: goal {ticks} ticks is outside the limits {min}..={max}: refused")]
    OutsideLimits {
        /// The servo.
        id: u8,
        /// The refused goal.
        ticks: i32,
        /// Lowest allowed goal.
        min: i32,
        /// Highest allowed goal.
        max: i32,
    },
    /// A register only bring-up may set (position limits, Homing Offset, Operating Mode, Drive
    /// Mode, ID, Baud Rate), written through the limits wrapper.
    #[error("servo {id}: {register:?} is set by bring-up alone: raw write refused")]
    Protected {
        /// The servo.
        id: u8,
        /// The register.
        register: Register,
    },
    /// A goal for a servo the limits wrapper has no limits for.
    #[error("servo {id}: no limits are known for it: goal refused")]
    UnknownServo {
        /// The servo.
        id: u8,
    },
    /// A non-finite joint angle (NaN or infinite): never written.
    #[error("joint {joint} (servo {id}): goal {value} rad is not finite: refused")]
    NotFinite {
        /// 1-based joint index.
        joint: usize,
        /// The servo.
        id: u8,
        /// The refused value.
        value: f64,
    },
    /// A pose with the wrong number of angles.
    #[error("a pose of {got} angles for {expected} joints")]
    PoseLength {
        /// Joints on the bus.
        expected: usize,
        /// Angles given.
        got: usize,
    },
    /// An id outside 0..=252, or listed twice in one instruction.
    #[error("servo id {id}: {what}")]
    BadId {
        /// The id.
        id: u8,
        /// Why it is refused.
        what: &'static str,
    },
    /// A packet larger than the bus buffers.
    #[error("packet of {needed} bytes exceeds the {have}-byte buffer")]
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Buffer size.
        have: usize,
    },
    /// A baud rate no X-series servo can use.
    #[error("baud rate {0} is not a Dynamixel baud rate")]
    Baud(u32),
    /// Something this bus cannot do (e.g. Fast Sync Read on a bus that does not frame it).
    #[error("unsupported: {what}")]
    Unsupported {
        /// What is not supported.
        what: &'static str,
    },
    /// Opening the serial port failed.
    #[error("opening {}: {source}", port.display())]
    Open {
        /// The port.
        port: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// Another program has the serial port (holds its lock, or has it in exclusive mode):
    /// refused before anything was written to it.
    #[error("{}", in_use_text(port, device, holder.as_ref()))]
    InUse {
        /// The port as given.
        port: PathBuf,
        /// The device it names, symlinks resolved (what is locked).
        device: PathBuf,
        /// The process that holds it, when this process can see it.
        holder: Option<Holder>,
    },
    /// Reading from or writing to the serial port failed.
    #[error("serial port i/o: {0}")]
    Io(#[from] std::io::Error),
    /// The servo answered, but its Indirect Addresses are back at their defaults (it lost its
    /// RAM: a power loss or a reboot), so the indirect block reads zeros.
    #[error("servo {id}: its Indirect Address mapping is reset (the servo lost its RAM)")]
    Unmapped {
        /// The servo.
        id: u8,
    },
    /// One port of a bus of several failed (an error of class [`ErrorClass::Bus`]): which, and
    /// how.
    #[error("port {port}: {source}")]
    OnPort {
        /// The port's path.
        port: String,
        /// What failed on it.
        source: Box<ServoError>,
    },
}

impl ServoError {
    /// The servo the error names, if any.
    pub fn id(&self) -> Option<u8> {
        match self {
            Self::Timeout { id, .. }
            | Self::Checksum { id, .. }
            | Self::Status { id, .. }
            | Self::Malformed { id, .. }
            | Self::WrongId { id, .. }
            | Self::ValueRange { id, .. }
            | Self::OutsideLimits { id, .. }
            | Self::Protected { id, .. }
            | Self::UnknownServo { id }
            | Self::NotFinite { id, .. }
            | Self::BadId { id, .. }
            | Self::Unmapped { id } => Some(*id),
            _ => None,
        }
    }

    /// True for a missing reply.
    pub fn is_timeout(&self) -> bool {
        matches!(self, Self::Timeout { .. })
    }

    /// What kind of failure this is, so a caller decides in one match whether to retry, give
    /// up on the command, or treat the servo as faulted.
    pub fn class(&self) -> ErrorClass {
        match self {
            Self::Timeout { .. }
            | Self::Checksum { .. }
            | Self::Malformed { .. }
            | Self::WrongId { .. }
            | Self::Unmapped { .. } => ErrorClass::Transient,
            Self::Status { alert: true, .. } => ErrorClass::Hardware,
            Self::Status { .. }
            | Self::ValueRange { .. }
            | Self::OutsideLimits { .. }
            | Self::Protected { .. }
            | Self::UnknownServo { .. }
            | Self::NotFinite { .. }
            | Self::PoseLength { .. }
            | Self::BadId { .. }
            | Self::Baud(_)
            | Self::Unsupported { .. } => ErrorClass::Refused,
            Self::BufferTooSmall { .. } | Self::Open { .. } | Self::InUse { .. } | Self::Io(_) => {
                ErrorClass::Bus
            }
            Self::OnPort { source, .. } => source.class(),
        }
    }

    /// The port a bus of several names in its error ([`ServoError::OnPort`]).
    pub fn port(&self) -> Option<&str> {
        match self {
            Self::OnPort { port, .. } => Some(port),
            _ => None,
        }
    }

    /// True for an error worth retrying: the exchange failed, not the request.
    pub fn is_transient(&self) -> bool {
        self.class() == ErrorClass::Transient
    }
}

/// The four kinds of [`ServoError`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorClass {
    /// The exchange failed on the wire (no reply in time, a damaged or misaddressed reply): the
    /// same request may succeed if sent again; count it against an error budget.
    Transient,
    /// The request itself was refused, by this program (limits, a bad value) or by the servo
    /// (a status error without the alert flag): sending it again gives the same answer.
    Refused,
    /// The servo refused with its alert flag set: a hardware error is latched (overload,
    /// overheating, ...), torque may be off; only a reboot clears it.
    Hardware,
    /// The serial port itself failed (open, in use by another program, i/o, a packet too large
    /// for the buffers).
    Bus,
}
