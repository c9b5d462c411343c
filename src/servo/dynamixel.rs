//! [`ServoBus`] over a serial port with `dynamixel2` 0.9.1 (the only module that imports it).
//!
//! Works the same on a U2D2 and on the simulator's pseudo-terminal. Around the crate's known
//! pitfalls: no `bulk_read` (it corrupts packets for more than one servo); sync reads are sent
//! with `write_instruction` and each reply is read with its own deadline and matched by packet
//! id, so a silent servo costs its timeout and the others' data still arrive (the crate's
//! `sync_read_*` hide a missing servo or mislabel the replies after it); the buffers hold a
//! packet for 64 servos (the default 128 bytes cap a sync write at 22); every reply is waited
//! for with the caller's timeout, never the crate's flat 34 ms; the alert bit is a flag
//! reported beside the data, not an error.
//!
//! A status packet with an error code, or a damaged one, does not reveal its id through the
//! crate: in a sync read it is attributed to the first servo not yet heard from, which is
//! exact unless an earlier servo is silent. A reply that arrives after its deadline may still
//! be in flight when the next instruction goes out: a single exchange skips replies from other
//! servos and replies of the wrong length (the same servo's answer to an earlier instruction);
//! a sync read counts the servos listed before a reply's id as missing.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use dynamixel2::instructions::instruction_id as ins;
use dynamixel2::{Bus, InvalidMessage, ReadError, WriteError};

use super::lock::PortLock;
use super::sysfs::{Latency, Sysfs};
use super::{
    baud_index, Ack, Goal, PingInfo, Register, ServoBus, ServoError, SyncReadBuf, Value,
    BROADCAST_ID, MAX_ID,
};

/// Servos one instruction may address: the buffers are sized for this many.
pub const MAX_SERVOS: usize = 64;
/// Read buffer: 64 full-state replies (11 + 21 bytes, stuffed) or a whole scan, with room.
const READ_BUFFER: usize = 4096;
/// Write buffer: a sync write of 4 bytes to 64 servos is 334 bytes before stuffing.
const WRITE_BUFFER: usize = 1024;
/// Bytes of a status packet without parameters: header 4, id, length 2, instruction, error,
/// CRC 2.
const STATUS_OVERHEAD: usize = 11;
/// Bytes of an instruction packet without parameters: header 4, id, length 2, instruction,
/// CRC 2.
const INSTRUCTION_OVERHEAD: usize = 10;

/// A Dynamixel Protocol 2.0 bus on a serial port, which it holds the lock of (see
/// [`super::lock`]) until dropped or closed.
#[derive(Debug)]
pub struct DynamixelBus {
    /// The open port; `None` once closed.
    open: Option<Open>,
    baud: u32,
    port: PathBuf,
    latency: Latency,
}

/// A port open, and the lock that makes this process its one owner. The fields drop in this
/// order: the port is closed before its lock goes.
#[derive(Debug)]
struct Open {
    bus: Bus<Vec<u8>, Vec<u8>>,
    lock: PortLock,
}

/// What every exchange on a closed bus fails with: the port is gone, as when it vanishes.
fn closed() -> ServoError {
    ServoError::Io(std::io::Error::new(
        std::io::ErrorKind::NotConnected,
        "the port was closed",
    ))
}

/// Time `bytes` take on the wire at `baud` (10 bits a byte).
pub fn wire_time(bytes: usize, baud: u32) -> Duration {
    let bits = bytes as u64 * 10;
    Duration::from_nanos(bits.saturating_mul(1_000_000_000) / u64::from(baud.max(1)))
}

fn write_error(e: WriteError) -> ServoError {
    match e {
        WriteError::BufferTooSmall(b) => ServoError::BufferTooSmall {
            needed: b.required_size,
            have: b.total_size,
        },
        WriteError::DiscardBuffer(e) | WriteError::Write(e) => ServoError::Io(e),
    }
}

/// The error a failed read means for servo `id`, waited for `waited`.
fn read_error(id: u8, waited: Duration, e: ReadError) -> ServoError {
    match e {
        ReadError::Io(e) if e.kind() == std::io::ErrorKind::TimedOut => {
            ServoError::Timeout { id, waited }
        }
        ReadError::Io(e) => ServoError::Io(e),
        ReadError::BufferFull(b) => ServoError::BufferTooSmall {
            needed: b.required_size,
            have: b.total_size,
        },
        ReadError::MotorError(m) => ServoError::Status {
            id,
            code: m.error_number(),
            alert: m.alert(),
        },
        ReadError::InvalidMessage(InvalidMessage::InvalidChecksum(c)) => ServoError::Checksum {
            id,
            received: c.message,
            computed: c.computed,
        },
        ReadError::InvalidMessage(m) => ServoError::Malformed {
            id,
            what: format!("{m:?}"),
        },
    }
}

fn check_id(id: u8) -> Result<(), ServoError> {
    if id > MAX_ID {
        return Err(ServoError::BadId {
            id,
            what: "ids run from 0 to 252",
        });
    }
    Ok(())
}

impl DynamixelBus {
    /// Open `port` at `baud` (one of [`super::BAUD_RATES`]; other rates are refused because no
    /// servo could answer). The device is locked first ([`PortLock::acquire`]): a port another
    /// program has is refused with [`ServoError::InUse`] before anything is written to it. On
    /// an FTDI `ttyUSB` port, the latency timer is set to 1 ms when writable; otherwise a
    /// warning gives the command that does it.
    pub fn open(port: impl AsRef<Path>, baud: u32) -> Result<Self, ServoError> {
        Self::open_with_sysfs(port, baud, &Sysfs::system())
    }

    /// [`DynamixelBus::open`] with the latency timer looked up in `sysfs`.
    pub fn open_with_sysfs(
        port: impl AsRef<Path>,
        baud: u32,
        sysfs: &Sysfs,
    ) -> Result<Self, ServoError> {
        let port = port.as_ref().to_path_buf();
        if baud_index(baud).is_none() {
            return Err(ServoError::Baud(baud));
        }
        let lock = PortLock::acquire(&port)?;
        let bus = Bus::open_with_buffers(&port, baud, vec![0; READ_BUFFER], vec![0; WRITE_BUFFER])
            .map_err(|source| ServoError::Open {
                port: port.clone(),
                source,
            })?;
        let latency = sysfs.ensure_low_latency(&port);
        match &latency {
            Latency::Lowered { from_ms } => {
                tracing::info!(port = %port.display(), from_ms, "FTDI latency timer set to 1 ms")
            }
            Latency::TooHigh { ms, command, error } => tracing::warn!(
                port = %port.display(),
                "FTDI latency timer is {ms} ms and could not be set ({error}): every reply \
                 may wait {ms} ms in the adapter; run: {command}"
            ),
            Latency::Unreadable { path, error } => {
                tracing::warn!(path = %path.display(), %error, "cannot read the latency timer")
            }
            Latency::NotApplicable | Latency::Low => {}
        }
        Ok(Self {
            open: Some(Open { bus, lock }),
            baud,
            port,
            latency,
        })
    }

    /// What was found (and done) about the port's FTDI latency timer when it was opened.
    pub fn latency(&self) -> &Latency {
        &self.latency
    }

    /// The serial port's path.
    pub fn port(&self) -> &Path {
        &self.port
    }

    /// The device locked while the port is open (its path with symlinks resolved); `None` once
    /// closed.
    pub fn device(&self) -> Option<&Path> {
        self.open.as_ref().map(|o| o.lock.device())
    }

    /// The open port, or the error of a closed one.
    fn wire(&mut self) -> Result<&mut Bus<Vec<u8>, Vec<u8>>, ServoError> {
        self.open.as_mut().map(|o| &mut o.bus).ok_or_else(closed)
    }

    /// How long to wait for a reply of `params` parameters: its wire time plus `timeout`.
    fn reply_wait(&self, params: usize, timeout: Duration) -> Duration {
        wire_time(STATUS_OVERHEAD + params, self.baud) + timeout
    }

    /// Send one instruction to `id` and wait for its reply (of `params` parameters) with the
    /// caller's timeout. The instruction's own wire time is added to the wait. A late reply of
    /// another servo (to an earlier instruction that timed out) is skipped.
    fn exchange(
        &mut self,
        id: u8,
        instruction: u8,
        params: &[u8],
        reply_params: usize,
        timeout: Duration,
    ) -> Result<Reply, ServoError> {
        check_id(id)?;
        self.wire()?
            .write_instruction(id, instruction, params.len(), |buf| {
                buf.copy_from_slice(params)
            })
            .map_err(write_error)?;
        let waited = wire_time(INSTRUCTION_OVERHEAD + params.len(), self.baud)
            + self.reply_wait(reply_params, timeout);
        let deadline = Instant::now() + waited;
        let mut skipped = None;
        let mut stale = None;
        loop {
            match self
                .wire()?
                .read_status_response_deadline(poll_deadline(deadline))
            {
                Ok(p) if p.packet_id() != id => {
                    tracing::debug!(
                        id,
                        from = p.packet_id(),
                        "skipping a reply of another servo"
                    );
                    skipped = Some(p.packet_id());
                }
                Ok(p) if p.parameters().len() != reply_params => {
                    // The servo's late reply to an earlier instruction (another length):
                    // skipped like another servo's. A late reply of the same length cannot be
                    // told from this one's (Protocol 2.0 has no sequence number).
                    tracing::debug!(
                        id,
                        bytes = p.parameters().len(),
                        expected = reply_params,
                        "skipping a reply of another length"
                    );
                    stale = Some(p.parameters().len());
                }
                Ok(p) => {
                    let data = p.parameters();
                    let mut reply = Reply {
                        params: [0; 4],
                        alert: p.alert(),
                    };
                    if let Some(slot) = reply.params.get_mut(..data.len()) {
                        slot.copy_from_slice(data);
                    }
                    return Ok(reply);
                }
                Err(ReadError::Io(e)) if e.kind() == std::io::ErrorKind::TimedOut => {
                    return Err(match (skipped, stale) {
                        (Some(from), _) => ServoError::WrongId { id, from },
                        (None, Some(bytes)) => ServoError::Malformed {
                            id,
                            what: format!("{bytes} data bytes, expected {reply_params}"),
                        },
                        (None, None) => ServoError::Timeout { id, waited },
                    })
                }
                Err(e) => return Err(read_error(id, waited, e)),
            }
        }
    }
}

/// The port's read timeout has whole-millisecond resolution, truncated: a wait of 0.99 ms polls
/// for 0 ms and gives up at once, however soon the reply would come. So every wait for a reply
/// is given a deadline at least [`MIN_POLL_WAIT`] away, which makes the first poll last a whole
/// millisecond: a reply that comes within it is taken as soon as it arrives, one that does not
/// costs about a millisecond, even where the caller asked for less.
const MIN_POLL_WAIT: Duration = Duration::from_millis(2);

/// `deadline`, or [`MIN_POLL_WAIT`] from now if that is later.
fn poll_deadline(deadline: Instant) -> Instant {
    deadline.max(Instant::now() + MIN_POLL_WAIT)
}

impl DynamixelBus {
    /// One Sync Write of `register`, encoded straight into the bus's write buffer: nothing is
    /// allocated, nothing is sent if an id or value is refused.
    fn send_sync_write(
        &mut self,
        register: Register,
        values: impl Iterator<Item = (u8, i64)> + Clone,
    ) -> Result<(), ServoError> {
        let n = check_sync_write(register, values.clone())?;
        if n == 0 {
            return Ok(());
        }
        let size = usize::from(register.size());
        self.wire()?
            .write_instruction(BROADCAST_ID, ins::SYNC_WRITE, 4 + n * (1 + size), |buf| {
                buf[..2].copy_from_slice(&register.address().to_le_bytes());
                buf[2..4].copy_from_slice(&register.size().to_le_bytes());
                for (chunk, (id, value)) in buf[4..].chunks_exact_mut(1 + size).zip(values) {
                    chunk[0] = id;
                    chunk[1..].copy_from_slice(&register.encode(value)[..size]);
                }
            })
            .map_err(write_error)
    }
}

/// A status reply's data (at most 4 bytes: a register or a ping), copied out of the bus.
struct Reply {
    params: [u8; 4],
    alert: bool,
}

/// Checks a sync write's ids and values before anything is sent; returns how many there are.
fn check_sync_write(
    register: Register,
    values: impl Iterator<Item = (u8, i64)> + Clone,
) -> Result<usize, ServoError> {
    let mut n = 0;
    for (i, (id, value)) in values.clone().enumerate() {
        check_id(id)?;
        if values.clone().take(i).any(|(other, _)| other == id) {
            return Err(ServoError::BadId {
                id,
                what: "listed twice in one sync write",
            });
        }
        if !register.fits(value) {
            return Err(ServoError::ValueRange {
                id,
                register,
                value,
            });
        }
        n += 1;
    }
    if n > MAX_SERVOS {
        return Err(ServoError::BufferTooSmall {
            needed: n,
            have: MAX_SERVOS,
        });
    }
    Ok(n)
}

impl ServoBus for DynamixelBus {
    fn baud(&self) -> u32 {
        self.baud
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        if baud_index(baud).is_none() {
            return Err(ServoError::Baud(baud));
        }
        self.wire()?.set_baud_rate(baud)?;
        self.baud = baud;
        Ok(())
    }

    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        let r = self.exchange(id, ins::PING, &[], 3, timeout)?;
        let d = r.params;
        Ok(PingInfo {
            id,
            model: u16::from_le_bytes([d[0], d[1]]),
            firmware: d[2],
            alert: r.alert,
        })
    }

    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        self.wire()?
            .write_instruction(BROADCAST_ID, ins::PING, 0, |_| {})
            .map_err(write_error)?;
        let baud = self.baud;
        // Every id may answer, one after the other.
        let window = wire_time(INSTRUCTION_OVERHEAD, baud)
            + wire_time((STATUS_OVERHEAD + 3) * (usize::from(MAX_ID) + 1), baud)
            + timeout;
        let deadline = Instant::now() + window;
        let mut found: Vec<PingInfo> = Vec::new();
        loop {
            match self
                .wire()?
                .read_status_response_deadline(poll_deadline(deadline))
            {
                Ok(p) => {
                    let d = p.parameters();
                    if d.len() == 3 && !found.iter().any(|f| f.id == p.packet_id()) {
                        found.push(PingInfo {
                            id: p.packet_id(),
                            model: u16::from_le_bytes([d[0], d[1]]),
                            firmware: d[2],
                            alert: p.alert(),
                        });
                    }
                }
                Err(ReadError::Io(e)) if e.kind() == std::io::ErrorKind::TimedOut => break,
                Err(ReadError::Io(e)) => return Err(ServoError::Io(e)),
                // A damaged or refused reply: that servo is not listed; keep listening.
                Err(e) => tracing::debug!(error = ?e, "scan: unusable reply"),
            }
        }
        found.sort_by_key(|f| f.id);
        Ok(found)
    }

    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError> {
        let size = register.size();
        let [a0, a1] = register.address().to_le_bytes();
        let [s0, s1] = size.to_le_bytes();
        let r = self.exchange(id, ins::READ, &[a0, a1, s0, s1], usize::from(size), timeout)?;
        let value = register
            .decode(&r.params)
            .ok_or_else(|| ServoError::Malformed {
                id,
                what: "short data".into(),
            })?;
        Ok(Value {
            value,
            alert: r.alert,
        })
    }

    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError> {
        if !register.fits(value) {
            return Err(ServoError::ValueRange {
                id,
                register,
                value,
            });
        }
        let mut params = [0u8; 6];
        params[..2].copy_from_slice(&register.address().to_le_bytes());
        params[2..].copy_from_slice(&register.encode(value));
        let len = 2 + usize::from(register.size());
        let r = self.exchange(id, ins::WRITE, &params[..len], 0, timeout)?;
        Ok(Ack { id, alert: r.alert })
    }

    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        let data_len = usize::from(len);
        let per_reply = self.reply_wait(data_len, timeout);
        out.reset(ids, len, per_reply);
        if ids.is_empty() {
            return Ok(());
        }
        for (i, &id) in ids.iter().enumerate() {
            check_id(id)?;
            if ids[..i].contains(&id) {
                return Err(ServoError::BadId {
                    id,
                    what: "listed twice in one sync read",
                });
            }
        }
        let n = ids.len();
        self.wire()?
            .write_instruction(BROADCAST_ID, ins::SYNC_READ, 4 + n, |buf| {
                buf[..2].copy_from_slice(&address.to_le_bytes());
                buf[2..4].copy_from_slice(&len.to_le_bytes());
                buf[4..].copy_from_slice(ids);
            })
            .map_err(write_error)?;
        // Replies come in the order of `ids`: `next` is the first servo not heard from yet.
        let mut next = 0;
        let mut wait = wire_time(INSTRUCTION_OVERHEAD + 4 + n, self.baud) + per_reply;
        // Bounds the loop if stray packets keep arriving.
        let mut budget = 2 * n + 8;
        while next < n && budget > 0 {
            budget -= 1;
            let deadline = Instant::now() + wait;
            match self
                .wire()?
                .read_status_response_deadline(poll_deadline(deadline))
            {
                Ok(p) => {
                    let id = p.packet_id();
                    let Some(k) = ids[next..].iter().position(|&x| x == id) else {
                        tracing::debug!(id, "sync read: reply from a servo not expected now");
                        continue;
                    };
                    // The servos listed before this one stay marked as missing.
                    let data = p.parameters();
                    if data.len() == data_len {
                        out.set(next + k, data, p.alert());
                    } else {
                        out.fail(
                            next + k,
                            ServoError::Malformed {
                                id,
                                what: format!("{} data bytes, expected {data_len}", data.len()),
                            },
                        );
                    }
                    next += k + 1;
                }
                Err(ReadError::Io(e)) if e.kind() == std::io::ErrorKind::TimedOut => break,
                Err(ReadError::Io(e)) => return Err(ServoError::Io(e)),
                Err(e) => {
                    out.fail(next, read_error(ids[next], wait, e));
                    next += 1;
                }
            }
            wait = per_reply;
        }
        Ok(())
    }

    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        self.send_sync_write(register, values.iter().copied())
    }

    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        self.send_sync_write(
            Register::GoalPosition,
            goals.iter().map(|g| (g.id, i64::from(g.ticks))),
        )
    }

    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        let r = self.exchange(id, ins::REBOOT, &[], 0, timeout)?;
        Ok(Ack { id, alert: r.alert })
    }

    fn close(&mut self) {
        if self.open.take().is_some() {
            tracing::debug!(port = %self.port.display(), "port closed, lock released");
        }
    }
}
