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
//! Status packets are framed here too ([`StatusReader`]), read past the crate from a second
//! handle on the port: the crate's parser trusts a packet's length field, and one damaged on the
//! way (a noisy line) makes it panic (a length below 4) or give the same error on every read
//! until the next instruction (a length beyond its buffer). Here a packet whose length cannot
//! be, or whose CRC fails, costs that packet alone: the search for the next header starts one
//! byte past its header, so the replies behind it are still read. A status packet with an
//! error code names its servo; a damaged one, whose id cannot be trusted, is attributed in a
//! sync read to the first servo not yet heard from, which is exact unless an earlier servo is
//! silent. A reply that arrives after its deadline may still be in flight when the next
//! instruction goes out: a single exchange skips replies from other servos and replies of the
//! wrong length (the same servo's answer to an earlier instruction); a sync read counts the
//! servos listed before a reply's id as missing.
//!
//! Fast Sync Read (0x8A), which the crate does not know, is framed here: the instruction goes
//! out through `write_instruction` (it is laid out as Sync Read), and its one status packet
//! (not byte-stuffed, see [`FastReply`]) is read raw from a second handle on the same port,
//! with its own deadline. A reply cut short or damaged at servo k keeps the blocks before k;
//! a damaged block is reported as a damaged Sync Read reply would be, and the servos from where
//! the reply can no longer be used are asked again in the same call with a Sync Read (which
//! names a silent servo as it always does), so that one silent servo costs no other servo its
//! reading.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use dynamixel2::checksum::calculate_checksum;
use dynamixel2::instructions::instruction_id as ins;
use dynamixel2::serial2::SerialPort;
use dynamixel2::{Bus, WriteError};

use super::lock::PortLock;
use super::sysfs::{Latency, Sysfs};
use super::wire::Adapter;
use super::{
    baud_index, Ack, Goal, PingInfo, ReadKind, Register, ServoBus, ServoError, SyncReadBuf, Value,
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
/// The slot of one id in the replies to a broadcast ping: servos answer in id order, each
/// after 3 ms for every id before its own that did not answer (ROBOTIS' device firmware steps
/// the ids every 3 ms, and their SDK's `broadcastPing` waits 3 ms an id).
pub const BROADCAST_PING_SLOT: Duration = Duration::from_millis(3);
/// How long a Fast Sync Read reply may pause (beyond the wire time of what is missing) before
/// the chain is taken to have broken there: a chain sends its blocks back to back, and a USB
/// adapter with its latency timer at 1 ms passes bytes on at least every millisecond (behind a
/// longer latency timer, one that could not be lowered or a simulated adapter's, the pause
/// allowed is that timer plus 1 ms).
pub const FAST_STALL: Duration = Duration::from_millis(2);
/// How long a Fast Sync Read reply behind `adapter` may pause before the chain is taken to have
/// broken: [`FAST_STALL`], or the adapter's latency timer and 1 ms where that is longer. An
/// FTDI chip sends the reply's full USB packets as they fill and holds the last partial one
/// until its timer runs out, up to a whole timer after the packet before: behind the chip's
/// default 16 ms, a pause of 2 ms would give up on every reply of more than one packet.
fn stall_behind(adapter: Option<Adapter>) -> Duration {
    adapter.map_or(FAST_STALL, |a| {
        FAST_STALL.max(a.latency + Duration::from_millis(1))
    })
}

/// How long before a Fast Sync Read reply is expected whole its read stops sleeping on a timer
/// and waits on the port. A thread blocked on the port for milliseconds lets its core idle
/// deeply, and on a virtual machine the wake-up when the bytes come can take a few hundred
/// microseconds; a timer wakes it about on time, and a short wait on the port after it is woken
/// promptly ([`Arrival`]).
const WAKE_AHEAD: Duration = Duration::from_micros(150);
/// Fast Sync Read's instruction byte (Protocol 2.0; X430/X540 firmware 45+, X330 46+).
pub const FAST_SYNC_READ: u8 = 0x8A;
/// Status packet instruction byte.
const STATUS: u8 = 0x55;
/// The header every packet opens with.
const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// Bytes of a Fast Sync Read reply before the first servo's block: header 4, id, length 2,
/// instruction.
const FAST_HEAD: usize = 8;
/// Bytes of one servo's block besides its data: error, id, CRC 2.
const FAST_BLOCK_OVERHEAD: usize = 4;

/// Bytes of a Fast Sync Read reply for `servos` servos of `len` data bytes each:
/// `8 + servos × (len + 4)` (a Sync Read's replies take `servos × (11 + len)`).
pub fn fast_reply_bytes(servos: usize, len: usize) -> usize {
    FAST_HEAD + servos * (len + FAST_BLOCK_OVERHEAD)
}

/// A Dynamixel Protocol 2.0 bus on a serial port, which it holds the lock of (see
/// [`super::lock`]) until dropped or closed.
#[derive(Debug)]
pub struct DynamixelBus {
    /// The open port; `None` once closed.
    open: Option<Open>,
    baud: u32,
    port: PathBuf,
    latency: Latency,
    /// The adapter the port is taken to be behind where it told none when it opened (a
    /// simulator's FTDI model on a pseudo-terminal; see [`DynamixelBus::assume_adapter`]).
    assumed: Option<Adapter>,
    /// What [`ServoBus::sync_read_into`] sends.
    read_kind: ReadKind,
    /// How long a Fast Sync Read reply may pause before the chain is taken to have broken:
    /// [`FAST_STALL`], or longer behind a longer latency timer ([`stall_behind`]).
    stall: Duration,
    /// The bytes of a Fast Sync Read reply, reused from read to read.
    fast: Vec<u8>,
    /// The status packets received since the last instruction.
    rx: StatusReader,
    /// The Sync Read that asks again the servos after a break in a Fast reply, reused.
    rest: SyncReadBuf,
    /// When the Fast Sync Read replies have been whole.
    arrival: Option<Arrival>,
    /// When the bytes written so far will have left the port, at the baud rate: instructions
    /// written back to back (a burst of Sync Writes) queue in the port and the adapter, and
    /// the reply to the next one cannot begin before they are out. At 57600 baud a dozen
    /// writes of an Indirect Address map are about 0.1 s of wire.
    wire_free: Instant,
}

/// When a Fast Sync Read reply is whole after its instruction was sent, for one shape of read,
/// as learnt from the reads before: the next read of that shape sleeps until [`WAKE_AHEAD`]
/// before then, and only then waits on the port (bytes that come sooner wait in the port's
/// buffer; an adapter's packets before the last are not each waited for). Learnt rather than
/// computed, since the host cannot tell what is still on the wire ahead of the instruction (the
/// goals' Sync Write), nor how long an adapter holds bytes back; a far end that answers at once
/// (a simulator without wire timing) is then never slept for. An earlier arrival is taken at
/// once, a later one an eighth at a time, so that one late wake-up does not make the next reads
/// oversleep.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Arrival {
    servos: usize,
    len: usize,
    baud: u32,
    after: Duration,
}

impl Arrival {
    /// What `last` learnt for this shape of read, if it is of this shape.
    fn of(last: Option<Arrival>, servos: usize, len: usize, baud: u32) -> Option<Duration> {
        last.filter(|a| (a.servos, a.len, a.baud) == (servos, len, baud))
            .map(|a| a.after)
    }

    /// How long to sleep after sending a read of this shape; zero when nothing was learnt
    /// for it.
    fn sleep(last: Option<Arrival>, servos: usize, len: usize, baud: u32) -> Duration {
        Self::of(last, servos, len, baud).map_or(Duration::ZERO, |a| a.saturating_sub(WAKE_AHEAD))
    }

    /// What `last` becomes once a read of this shape had its reply whole `after` it was sent.
    fn learn(
        last: Option<Arrival>,
        servos: usize,
        len: usize,
        baud: u32,
        after: Duration,
    ) -> Arrival {
        let after = match Self::of(last, servos, len, baud) {
            Some(before) if after > before => before + (after - before) / 8,
            _ => after,
        };
        Arrival {
            servos,
            len,
            baud,
            after,
        }
    }
}

/// A port open, and the lock that makes this process its one owner. The fields drop in this
/// order: the port is closed before its lock goes.
#[derive(Debug)]
struct Open {
    bus: Bus<Vec<u8>, Vec<u8>>,
    /// A second handle on the same device, with its own read timeout: every reply is read
    /// through it, past the crate's parser ([`StatusReader`], and [`FastReply`], which must not
    /// be unstuffed).
    raw: SerialPort,
    lock: PortLock,
}

/// What every exchange on a closed bus fails with: the port is gone, as when it vanishes.
fn closed() -> ServoError {
    ServoError::Io(std::io::Error::new(
        std::io::ErrorKind::NotConnected,
        "the port was closed",
    ))
}

/// How long a scan at `baud` listens after its broadcast ping: the ping's bytes, the reply of
/// every id (0 to [`MAX_ID`]), a [`BROADCAST_PING_SLOT`] for every id after the first, then
/// `timeout`, as ROBOTIS' SDK does (it ends with 16 ms). A servo that answers uses no slot of
/// its own, which covers its Return Delay Time (at most 508 µs). At 1 Mbps with 50 ms that is
/// 842 ms, 1.42 s at 57600 baud.
pub fn scan_window(baud: u32, timeout: Duration) -> Duration {
    let ids = usize::from(MAX_ID) + 1;
    wire_time(INSTRUCTION_OVERHEAD, baud)
        + wire_time((STATUS_OVERHEAD + 3) * ids, baud)
        + BROADCAST_PING_SLOT * u32::from(MAX_ID)
        + timeout
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
        let raw = bus
            .serial_port()
            .try_clone()
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
        let stall = stall_behind(latency.adapter());
        Ok(Self {
            open: Some(Open { bus, raw, lock }),
            baud,
            port,
            latency,
            assumed: None,
            read_kind: ReadKind::Sync,
            stall,
            fast: Vec::with_capacity(READ_BUFFER),
            rx: StatusReader::new(),
            rest: SyncReadBuf::new(),
            arrival: None,
            wire_free: Instant::now(),
        })
    }

    /// What was found (and done) about the port's FTDI latency timer when it was opened.
    pub fn latency(&self) -> &Latency {
        &self.latency
    }

    /// Takes the port to be behind `adapter` where it told none when it opened: a simulator's
    /// FTDI model (`[sim] adapter = "ftdi"`) on a pseudo-terminal, which holds the replies as
    /// the chip would but has no latency timer in sysfs. A Fast Sync Read reply then may pause
    /// for the adapter's timer and 1 ms without being taken for a chain that broke (see
    /// [`FAST_STALL`]), and [`ServoBus::adapters`] names it. A latency timer the port told wins.
    pub fn assume_adapter(&mut self, adapter: Adapter) {
        self.assumed = Some(adapter);
        self.stall = stall_behind(self.adapter());
    }

    /// The adapter the port is behind: the latency timer it told when it opened, else the one
    /// it was taken to be behind.
    fn adapter(&self) -> Option<Adapter> {
        self.latency.adapter().or(self.assumed)
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

    /// Sends one instruction (through the crate, which stuffs it and first throws away what
    /// the port had received); the replies to earlier ones are forgotten with it. Returns when
    /// its last byte leaves the port: once the instructions written before it are out (see
    /// `wire_free`), its own wire time later. Waits for its reply count from then.
    fn send(
        &mut self,
        id: u8,
        instruction: u8,
        params: usize,
        encode: impl FnOnce(&mut [u8]),
    ) -> Result<Instant, ServoError> {
        self.wire()?
            .write_instruction(id, instruction, params, encode)
            .map_err(write_error)?;
        self.rx.clear();
        let begins = self.wire_free.max(Instant::now());
        self.wire_free = begins + wire_time(INSTRUCTION_OVERHEAD + params, self.baud);
        Ok(self.wire_free)
    }

    /// The next status packet received by `deadline` (see [`StatusReader`]). A packet begun
    /// but not whole by then is given up as damaged (its length field may have been damaged
    /// upwards, swallowing the replies behind it, which are then read).
    fn read_status(&mut self, deadline: Instant) -> Result<Got, ServoError> {
        let Some(open) = self.open.as_mut() else {
            return Err(closed());
        };
        let rx = &mut self.rx;
        loop {
            match rx.frame() {
                Framed::Packet { id, error } => return Ok(Got::Packet { id, error }),
                Framed::Damaged { id, damage } => return Ok(Got::Damaged { id, damage }),
                Framed::Pending => {}
            }
            let left = deadline
                .checked_duration_since(Instant::now())
                .filter(|d| !d.is_zero());
            // A full buffer cannot be (a packet that fits is framed once whole), but never
            // spin on it.
            let Some(left) = left.filter(|_| !rx.space().is_empty()) else {
                return Ok(match rx.give_up() {
                    Some((id, damage)) => Got::Damaged { id, damage },
                    None => Got::Nothing,
                });
            };
            // The timeout has whole-millisecond resolution: never ask for 0 (no wait at all).
            open.raw
                .set_read_timeout(left.max(Duration::from_millis(1)))
                .map_err(ServoError::Io)?;
            match open.raw.read(rx.space()) {
                Ok(k) => rx.filled(k),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => return Err(ServoError::Io(e)),
            }
        }
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
        let asked = Instant::now();
        let sent = self.send(id, instruction, params.len(), |buf| {
            buf.copy_from_slice(params)
        })?;
        let deadline = sent + self.reply_wait(reply_params, timeout);
        let waited = deadline.saturating_duration_since(asked);
        let mut skipped = None;
        let mut stale = None;
        loop {
            match self.read_status(poll_deadline(deadline))? {
                Got::Packet { id: from, .. } if from != id => {
                    tracing::debug!(id, from, "skipping a reply of another servo");
                    skipped = Some(from);
                }
                Got::Packet { error, .. } => {
                    let alert = status_error(id, error)?;
                    let data = self.rx.params();
                    if data.len() != reply_params {
                        // The servo's late reply to an earlier instruction (another length):
                        // skipped like another servo's. A late reply of the same length cannot
                        // be told from this one's (Protocol 2.0 has no sequence number).
                        tracing::debug!(
                            id,
                            bytes = data.len(),
                            expected = reply_params,
                            "skipping a reply of another length"
                        );
                        stale = Some(data.len());
                        continue;
                    }
                    let mut reply = Reply {
                        params: [0; 4],
                        alert,
                    };
                    if let Some(slot) = reply.params.get_mut(..data.len()) {
                        slot.copy_from_slice(data);
                    }
                    return Ok(reply);
                }
                Got::Damaged { damage, .. } => return Err(damage.of(id)),
                Got::Nothing => {
                    return Err(match (skipped, stale) {
                        (Some(from), _) => ServoError::WrongId { id, from },
                        (None, Some(bytes)) => ServoError::Malformed {
                            id,
                            what: format!("{bytes} data bytes, expected {reply_params}"),
                        },
                        (None, None) => ServoError::Timeout { id, waited },
                    })
                }
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
        self.send(BROADCAST_ID, ins::SYNC_WRITE, 4 + n * (1 + size), |buf| {
            buf[..2].copy_from_slice(&register.address().to_le_bytes());
            buf[2..4].copy_from_slice(&register.size().to_le_bytes());
            for (chunk, (id, value)) in buf[4..].chunks_exact_mut(1 + size).zip(values) {
                chunk[0] = id;
                chunk[1..].copy_from_slice(&register.encode(value)[..size]);
            }
        })?;
        Ok(())
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

impl DynamixelBus {
    /// One Sync Read (0x82): each reply read with its own deadline and matched by id.
    pub fn plain_sync_read_into(
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
        check_read_ids(ids)?;
        let n = ids.len();
        let sent = self.send(BROADCAST_ID, ins::SYNC_READ, 4 + n, |buf| {
            buf[..2].copy_from_slice(&address.to_le_bytes());
            buf[2..4].copy_from_slice(&len.to_le_bytes());
            buf[4..].copy_from_slice(ids);
        })?;
        // Replies come in the order of `ids`: `next` is the first servo not heard from yet.
        let mut next = 0;
        // The first reply is due a reply's wait after the instruction is out; each later one a
        // reply's wait after the packet before it.
        let mut first = Some(sent + per_reply);
        // Bounds the loop if stray packets keep arriving.
        let mut budget = 2 * n + 8;
        while next < n && budget > 0 {
            budget -= 1;
            let deadline = first.take().unwrap_or_else(|| Instant::now() + per_reply);
            match self.read_status(poll_deadline(deadline))? {
                Got::Packet { id, error } => {
                    let Some(k) = ids[next..].iter().position(|&x| x == id) else {
                        tracing::debug!(id, "sync read: reply from a servo not expected now");
                        continue;
                    };
                    // The servos listed before this one stay marked as missing.
                    let data = self.rx.params();
                    match status_error(id, error) {
                        Err(e) => out.fail(next + k, e),
                        Ok(alert) if data.len() == data_len => out.set(next + k, data, alert),
                        Ok(_) => out.fail(
                            next + k,
                            ServoError::Malformed {
                                id,
                                what: format!("{} data bytes, expected {data_len}", data.len()),
                            },
                        ),
                    }
                    next += k + 1;
                }
                Got::Damaged { damage, .. } => {
                    out.fail(next, damage.of(ids[next]));
                    next += 1;
                }
                Got::Nothing => break,
            }
        }
        Ok(())
    }

    /// One Fast Sync Read (0x8A) of `len` bytes at `address` from every servo in `ids`, into
    /// `out`, whatever [`ServoBus::read_kind`] says. The servos whose blocks arrive whole keep
    /// their data. Where a block fails its CRC (servo k), servo k gets the error a Sync Read
    /// gives a damaged reply and the servos after it are asked again with one Sync Read, once
    /// the rest of the reply (which the chain goes on sending) is through; where
    /// the reply stops (nothing within its wire time plus `timeout`; once it has begun, no byte
    /// for the wire time of what is missing plus [`FAST_STALL`], or `timeout` if shorter), the
    /// servos from there on are asked again with one Sync Read, which finds and names the
    /// silent one as it always does.
    pub fn fast_sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        let data_len = usize::from(len);
        out.reset(ids, len, self.reply_wait(data_len, timeout));
        // The buffers of the Sync Read that may follow a break, sized now: a break later on
        // then allocates nothing (the loop's reads never do once warm).
        self.rest.reset(ids, len, Duration::ZERO);
        if ids.is_empty() {
            return Ok(());
        }
        check_read_ids(ids)?;
        let n = ids.len();
        let total = fast_reply_bytes(n, data_len);
        if total > READ_BUFFER {
            return Err(ServoError::BufferTooSmall {
                needed: total,
                have: READ_BUFFER,
            });
        }
        let out_at = self.send(BROADCAST_ID, FAST_SYNC_READ, 4 + n, |buf| {
            buf[..2].copy_from_slice(&address.to_le_bytes());
            buf[2..4].copy_from_slice(&len.to_le_bytes());
            buf[4..].copy_from_slice(ids);
        })?;
        // The read first sleeps toward the time its replies of this shape have been whole
        // ([`Arrival`]); the port is waited on from then. The first byte is waited for as a Sync
        // Read waits for its first reply: the wire time plus `timeout` (at least
        // [`MIN_POLL_WAIT`] from the wake-up). From then on a chain sends its blocks back to
        // back: the rest is waited for until the wire time of what is still missing plus
        // [`FAST_STALL`] (or `timeout`, if shorter) from the last byte received (an adapter may
        // hand the bytes on in bursts, or all at the end). Once the bytes stop that long, the
        // chain broke there.
        let stall = timeout.min(self.stall);
        let baud = self.baud;
        let sent = Instant::now();
        let asleep = Arrival::sleep(self.arrival, n, data_len, baud);
        if !asleep.is_zero() {
            std::thread::sleep(asleep);
        }
        let mut end = poll_deadline(out_at + wire_time(total, baud) + timeout);
        let Some(open) = self.open.as_mut() else {
            return Err(closed());
        };
        let buf = &mut self.fast;
        buf.resize(READ_BUFFER, 0);
        let mut got = 0;
        let mut reply = FastReply::new(ids, data_len);
        // Where the reply can no longer be used, and the damaged block's error if it was one
        // (a stall has none: the servos from there on are asked again).
        let (index, damaged) = loop {
            match reply.advance(&buf[..got], out) {
                FastState::Pending => {}
                FastState::Complete => {
                    let after = sent.elapsed();
                    self.arrival = Some(Arrival::learn(self.arrival, n, data_len, baud, after));
                    return Ok(());
                }
                FastState::Broken { index, error } => break (index, Some(error)),
            }
            let Some(left) = end
                .checked_duration_since(Instant::now())
                .filter(|d| !d.is_zero())
            else {
                break (reply.intact(), None);
            };
            if got == buf.len() {
                let index = reply.intact();
                let what = "more bytes than a Fast Sync Read reply holds".to_string();
                let id = ids[index];
                break (index, Some(ServoError::Malformed { id, what }));
            }
            // The timeout has whole-millisecond resolution: never ask for 0 (no wait at all).
            open.raw
                .set_read_timeout(left.max(Duration::from_millis(1)))
                .map_err(ServoError::Io)?;
            match open.raw.read(&mut buf[got..]) {
                Ok(k) => {
                    got += k;
                    if k > 0 {
                        let missing = total.saturating_sub(got);
                        end = poll_deadline(Instant::now() + wire_time(missing, baud) + stall);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => return Err(ServoError::Io(e)),
            }
        };
        if damaged.is_some() {
            // The chain does not know a block was damaged on the way: it goes on sending the
            // blocks after it. The Sync Read that asks those servos again waits until they are
            // through (or could be), or it would collide with them on the half-duplex bus.
            let received = reply.start.map_or(0, |s| got.saturating_sub(s));
            let mut left = total.saturating_sub(received);
            let mut quiet = Instant::now() + wire_time(left, baud);
            while left > 0 {
                let Some(wait) = quiet
                    .checked_duration_since(Instant::now())
                    .filter(|d| !d.is_zero())
                else {
                    break;
                };
                open.raw
                    .set_read_timeout(wait.max(Duration::from_millis(1)))
                    .map_err(ServoError::Io)?;
                match open.raw.read(&mut buf[..]) {
                    Ok(k) if k > 0 => {
                        left = left.saturating_sub(k);
                        quiet = Instant::now() + wire_time(left, baud);
                    }
                    Ok(_) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                    Err(e) => return Err(ServoError::Io(e)),
                }
            }
        }
        let from = match damaged {
            Some(error) => {
                tracing::debug!(%error, intact = index, "fast sync read damaged");
                out.fail(index, error);
                index + 1
            }
            None => {
                tracing::debug!(intact = index, "fast sync read stalled");
                index
            }
        };
        let rest = ids.get(from..).unwrap_or_default();
        if rest.is_empty() {
            return Ok(());
        }
        // The servos after the break are asked again, as a Sync Read would have.
        let mut again = std::mem::take(&mut self.rest);
        let result = self.plain_sync_read_into(rest, address, len, timeout, &mut again);
        if result.is_ok() {
            for j in 0..rest.len() {
                match again.take_error(j) {
                    Some(e) => out.fail(from + j, e),
                    None => {
                        if let Ok((data, alert)) = again.get(j) {
                            out.set(from + j, data, alert);
                        }
                    }
                }
            }
        }
        self.rest = again;
        result
    }
}

/// Checks a sync read's ids before anything is sent: each in range, none twice.
fn check_read_ids(ids: &[u8]) -> Result<(), ServoError> {
    for (i, &id) in ids.iter().enumerate() {
        check_id(id)?;
        if ids[..i].contains(&id) {
            return Err(ServoError::BadId {
                id,
                what: "listed twice in one sync read",
            });
        }
    }
    if ids.len() > MAX_SERVOS {
        return Err(ServoError::BufferTooSmall {
            needed: ids.len(),
            have: MAX_SERVOS,
        });
    }
    Ok(())
}

/// The error byte of servo `id`'s status packet: its alert bit, or the error its code means
/// (the instruction was not carried out).
fn status_error(id: u8, error: u8) -> Result<bool, ServoError> {
    let (code, alert) = (error & 0x7F, error & 0x80 != 0);
    if code == 0 {
        Ok(alert)
    } else {
        Err(ServoError::Status { id, code, alert })
    }
}

/// Bytes of a status packet up to its length field: header 4, id, length 2.
const STATUS_HEAD: usize = 7;
/// The least a status packet's length field can say: instruction, error, CRC 2.
const STATUS_LEAST_LENGTH: usize = 4;

/// Why a status packet cannot be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Damage {
    /// Its CRC does not match its bytes.
    Checksum {
        /// CRC in the packet.
        received: u16,
        /// CRC of the bytes received.
        computed: u16,
    },
    /// Its length field cannot be right, it is not a status packet, or it stopped short.
    Malformed(String),
}

impl Damage {
    /// What it means for the reply of servo `id`.
    pub fn of(&self, id: u8) -> ServoError {
        match self {
            Damage::Checksum { received, computed } => ServoError::Checksum {
                id,
                received: *received,
                computed: *computed,
            },
            Damage::Malformed(what) => ServoError::Malformed {
                id,
                what: what.clone(),
            },
        }
    }
}

/// What [`StatusReader::frame`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Framed {
    /// A whole status packet whose CRC checks: its id and error byte; its parameters, unstuffed,
    /// are [`StatusReader::params`].
    Packet {
        /// The replying servo.
        id: u8,
        /// Its error byte (alert bit and code).
        error: u8,
    },
    /// A packet that cannot be used; `id` is the byte where its id sits (which may be damaged
    /// too). The search goes on one byte past its header.
    Damaged {
        /// The id byte of the packet.
        id: u8,
        /// What is wrong with it.
        damage: Damage,
    },
    /// No whole packet yet.
    Pending,
}

/// What [`DynamixelBus::read_status`] got by its deadline.
enum Got {
    Packet { id: u8, error: u8 },
    Damaged { id: u8, damage: Damage },
    Nothing,
}

/// The status packets (Protocol 2.0) in the bytes received since the last instruction, framed
/// without trusting them: a length field below 4 or beyond the buffer, or a CRC that fails,
/// makes that packet [`Framed::Damaged`] and the search for the next header goes on one byte
/// past its header (a header cannot occur inside a packet: byte stuffing breaks every
/// `FF FF FD` in its body), so one damaged byte costs one reply. Bytes before a header (noise
/// on the line, the tail of a damaged packet) are skipped. A packet whose parameters were
/// stuffed (`FF FF FD` followed by an extra `FD`) is unstuffed into [`StatusReader::params`].
/// Sized once: reading allocates nothing.
#[derive(Debug)]
pub struct StatusReader {
    buf: Vec<u8>,
    /// Bytes held, from the start of `buf`.
    len: usize,
    /// Where the next packet is looked for.
    pos: usize,
    /// The parameters of the last packet framed, unstuffed.
    params: Vec<u8>,
}

impl Default for StatusReader {
    fn default() -> Self {
        Self::new()
    }
}

impl StatusReader {
    /// A reader that holds up to 4096 bytes, the longest packet it frames.
    pub fn new() -> Self {
        Self {
            buf: vec![0; READ_BUFFER],
            len: 0,
            pos: 0,
            params: Vec::with_capacity(READ_BUFFER),
        }
    }

    /// Forgets every byte (a new instruction went out).
    pub fn clear(&mut self) {
        self.len = 0;
        self.pos = 0;
    }

    /// Room for bytes to come, after those held (moved to the front first when the packet
    /// being read would not fit behind them).
    pub fn space(&mut self) -> &mut [u8] {
        if self.pos > 0 {
            self.buf.copy_within(self.pos..self.len, 0);
            self.len -= self.pos;
            self.pos = 0;
        }
        &mut self.buf[self.len..]
    }

    /// `k` bytes were written into [`StatusReader::space`].
    pub fn filled(&mut self, k: usize) {
        self.len = (self.len + k).min(self.buf.len());
    }

    /// Adds `bytes` as received (as much as fits).
    pub fn feed(&mut self, bytes: &[u8]) {
        let space = self.space();
        let k = bytes.len().min(space.len());
        space[..k].copy_from_slice(&bytes[..k]);
        self.filled(k);
    }

    /// The parameters of the last [`Framed::Packet`].
    pub fn params(&self) -> &[u8] {
        &self.params
    }

    /// The next packet in the bytes held.
    pub fn frame(&mut self) -> Framed {
        let held = &self.buf[self.pos..self.len];
        let Some(at) = held.windows(HEADER.len()).position(|w| w == HEADER) else {
            // Keep what may be the start of a header.
            self.pos = self.len.saturating_sub(HEADER.len() - 1).max(self.pos);
            return Framed::Pending;
        };
        self.pos += at;
        let p = &self.buf[self.pos..self.len];
        let Some(head) = p.get(..STATUS_HEAD) else {
            return Framed::Pending;
        };
        let id = head[4];
        let length = usize::from(u16::from_le_bytes([head[5], head[6]]));
        if !(STATUS_LEAST_LENGTH..=self.buf.len() - STATUS_HEAD).contains(&length) {
            self.pos += 1;
            let what = format!("a status packet whose length field says {length} bytes");
            return Framed::Damaged {
                id,
                damage: Damage::Malformed(what),
            };
        }
        let total = STATUS_HEAD + length;
        let Some(packet) = p.get(..total) else {
            return Framed::Pending;
        };
        let crc_at = total - 2;
        let computed = calculate_checksum(0, &packet[..crc_at]);
        let received = u16::from_le_bytes([packet[crc_at], packet[crc_at + 1]]);
        if computed != received {
            self.pos += 1;
            let damage = Damage::Checksum { received, computed };
            return Framed::Damaged { id, damage };
        }
        let (instruction, error) = (packet[STATUS_HEAD], packet[STATUS_HEAD + 1]);
        self.params.clear();
        // How much of `FF FF FD` the body has just shown; 3: the next `FD` is stuffing.
        let mut run = 0;
        for &b in &packet[STATUS_HEAD + 2..crc_at] {
            if run == 3 && b == 0xFD {
                run = 0;
                continue;
            }
            self.params.push(b);
            run = match (run, b) {
                (0 | 1, 0xFF) => run + 1,
                (2, 0xFF) => 2,
                (2, 0xFD) => 3,
                _ => 0,
            };
        }
        self.pos += total;
        if instruction != STATUS {
            let what = format!("instruction 0x{instruction:02X} where a status packet has 0x55");
            return Framed::Damaged {
                id,
                damage: Damage::Malformed(what),
            };
        }
        Framed::Packet { id, error }
    }

    /// The wait is over with a packet begun but not whole: it is given up as damaged (its
    /// length field may have been damaged upwards, making it swallow the replies behind it,
    /// which [`StatusReader::frame`] then finds), and the search goes on past its header.
    /// `None` when no packet was begun (its id not yet in).
    pub fn give_up(&mut self) -> Option<(u8, Damage)> {
        let p = &self.buf[self.pos..self.len];
        if !p.starts_with(&HEADER) {
            return None;
        }
        let id = *p.get(4)?;
        let what = match p.get(5..STATUS_HEAD) {
            Some(l) => format!(
                "a status packet cut short: {} of the {} bytes its length field says",
                p.len(),
                STATUS_HEAD + usize::from(u16::from_le_bytes([l[0], l[1]]))
            ),
            None => format!("a status packet cut short after {} bytes", p.len()),
        };
        self.pos += 1;
        Some((id, Damage::Malformed(what)))
    }
}

/// Where a [`FastReply`] stands after the bytes received so far.
#[derive(Debug)]
pub enum FastState {
    /// Every block so far checked; more bytes are needed.
    Pending,
    /// Every servo's block checked.
    Complete,
    /// The reply cannot be trusted from servo `index` (of the ids) on: that servo's block
    /// failed its CRC or named another servo.
    Broken {
        /// The servo (index into the ids) whose block is damaged.
        index: usize,
        /// What its reading is: the error a Sync Read would give for that reply.
        error: ServoError,
    },
}

/// The reader of one Fast Sync Read status packet, fed the bytes received so far.
///
/// Layout (Protocol 2.0, not byte-stuffed): `FF FF FD 00 | FE | LEN (2) | 55 |` then per servo,
/// in the order of the instruction's ids, `ERR ID DATA CRC (2)`: the first ERR sits where a
/// status packet's error byte does, `LEN = 1 + N × (X + 4)`, and each block's CRC is the
/// CRC-16 of the whole packet from its header to that block's last data byte (the last block's
/// CRC is the packet's). So each block is checked as soon as it is in, and a reply cut short
/// or damaged at block k still yields the blocks before k. Bytes before the header (noise on
/// the line) are skipped, and so is a packet whose header does not fit this reply (a late
/// reply to an earlier read, or a header damaged on the way: the read then waits for the real
/// one, and if none comes the servos are asked again); bytes after the last block are ignored.
#[derive(Debug)]
pub struct FastReply<'a> {
    ids: &'a [u8],
    len: usize,
    /// Where the header starts in the bytes, once found.
    start: Option<usize>,
    /// Where to look for the header next (past packets that were not this reply).
    search_from: usize,
    /// Packets passed over before the reply.
    skipped: usize,
    /// Blocks checked.
    done: usize,
    /// CRC of the bytes up to `crc_end`.
    crc: u16,
    crc_end: usize,
}

impl<'a> FastReply<'a> {
    /// The reader of a reply to a Fast Sync Read of `len` bytes from `ids`.
    pub fn new(ids: &'a [u8], len: usize) -> Self {
        Self {
            ids,
            len,
            start: None,
            search_from: 0,
            skipped: 0,
            done: 0,
            crc: 0,
            crc_end: 0,
        }
    }

    /// Servos whose blocks checked so far (the index of the next one).
    pub fn intact(&self) -> usize {
        self.done
    }

    /// Headers passed over because they did not open this reply (wrong id, instruction or
    /// length for these servos and this block length).
    pub fn skipped(&self) -> usize {
        self.skipped
    }

    /// Check the blocks `bytes` (everything received so far, from its first byte) holds beyond
    /// those already checked; each servo's block that checks goes into `out` at its index
    /// (its data and alert flag, or a status error it reported).
    pub fn advance(&mut self, bytes: &[u8], out: &mut SyncReadBuf) -> FastState {
        let n = self.ids.len();
        if n == 0 {
            return FastState::Complete;
        }
        let start = loop {
            if let Some(start) = self.start {
                break start;
            }
            let from = self.search_from.min(bytes.len());
            let Some(at) = bytes[from..]
                .windows(HEADER.len())
                .position(|w| w == HEADER)
            else {
                return FastState::Pending;
            };
            let start = from + at;
            let Some(head) = bytes.get(start..start + FAST_HEAD) else {
                return FastState::Pending;
            };
            let length = usize::from(u16::from_le_bytes([head[5], head[6]]));
            if head[4] == BROADCAST_ID
                && head[7] == STATUS
                && length == fast_reply_bytes(n, self.len) - 7
            {
                self.start = Some(start);
                self.crc_end = start;
            } else {
                // Not this read's reply: a late one to an earlier instruction, another
                // servo's packet, or a header damaged on the way. Look further on.
                self.skipped += 1;
                self.search_from = start + 1;
            }
        };
        let block = self.len + FAST_BLOCK_OVERHEAD;
        while let Some(&id) = self.ids.get(self.done) {
            let from = start + FAST_HEAD + self.done * block;
            let Some(b) = bytes.get(from..from + block) else {
                return FastState::Pending;
            };
            let crc_at = from + block - 2;
            let computed = calculate_checksum(self.crc, &bytes[self.crc_end..crc_at]);
            let received = u16::from_le_bytes([b[block - 2], b[block - 1]]);
            if computed != received {
                return FastState::Broken {
                    index: self.done,
                    error: ServoError::Checksum {
                        id,
                        received,
                        computed,
                    },
                };
            }
            if b[1] != id {
                let what = format!(
                    "the Fast Sync Read block of servo {id} names servo {}",
                    b[1]
                );
                return FastState::Broken {
                    index: self.done,
                    error: ServoError::Malformed { id, what },
                };
            }
            self.crc = calculate_checksum(computed, &b[block - 2..]);
            self.crc_end = from + block;
            let (code, alert) = (b[0] & 0x7F, b[0] & 0x80 != 0);
            if code == 0 {
                out.set(self.done, &b[2..block - 2], alert);
            } else {
                out.fail(self.done, ServoError::Status { id, code, alert });
            }
            self.done += 1;
        }
        debug_assert_eq!(self.done, n);
        FastState::Complete
    }
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

    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        check_id(id)?;
        let asked = Instant::now();
        let sent = self.send(id, ins::PING, 0, |_| {})?;
        // A second servo with the id answers after the first (or over it, damaging both):
        // listen for two replies' time, not stopping at the first.
        let deadline =
            sent + wire_time(STATUS_OVERHEAD + 3, self.baud) + self.reply_wait(3, timeout);
        let waited = deadline.saturating_duration_since(asked);
        let mut first: Option<PingInfo> = None;
        let mut first_error = None;
        let mut count = 0;
        loop {
            match self.read_status(poll_deadline(deadline))? {
                Got::Packet { id: from, error } if from == id => {
                    count += 1;
                    let d = self.rx.params();
                    match status_error(id, error) {
                        Ok(alert) if d.len() == 3 && first.is_none() => {
                            first = Some(PingInfo {
                                id,
                                model: u16::from_le_bytes([d[0], d[1]]),
                                firmware: d[2],
                                alert,
                            });
                        }
                        Ok(_) => {}
                        Err(e) => {
                            first_error.get_or_insert(e);
                        }
                    }
                }
                Got::Packet { id: from, .. } => {
                    tracing::debug!(id, from, "skipping a reply of another servo");
                }
                Got::Damaged { damage, .. } => {
                    count += 1;
                    first_error.get_or_insert(damage.of(id));
                }
                Got::Nothing => break,
            }
        }
        match (first, first_error) {
            (Some(p), _) => Ok((p, count)),
            (None, Some(e)) => Err(e),
            (None, None) => Err(ServoError::Timeout { id, waited }),
        }
    }

    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        let sent = self.send(BROADCAST_ID, ins::PING, 0, |_| {})?;
        // Replies come in id order, but one from a higher id may follow any of them: listen for
        // the whole window, never stopping at a lull.
        let deadline =
            sent - wire_time(INSTRUCTION_OVERHEAD, self.baud) + scan_window(self.baud, timeout);
        let mut found: Vec<PingInfo> = Vec::new();
        loop {
            match self.read_status(poll_deadline(deadline))? {
                Got::Packet { id, error } => {
                    let d = self.rx.params();
                    // Every reply is listed, an id answered twice twice: servos sharing an id
                    // are what a scan must show.
                    match status_error(id, error) {
                        Ok(alert) if d.len() == 3 => found.push(PingInfo {
                            id,
                            model: u16::from_le_bytes([d[0], d[1]]),
                            firmware: d[2],
                            alert,
                        }),
                        Ok(_) => {}
                        // A servo that refused the ping: not listed; keep listening.
                        Err(e) => tracing::debug!(error = %e, "scan: a refused ping"),
                    }
                }
                // A damaged reply: that servo is not listed; keep listening.
                Got::Damaged { id, damage } => {
                    tracing::debug!(error = %damage.of(id), "scan: unusable reply")
                }
                Got::Nothing => break,
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
        match self.read_kind {
            ReadKind::Sync => self.plain_sync_read_into(ids, address, len, timeout, out),
            ReadKind::Fast => self.fast_sync_read_into(ids, address, len, timeout, out),
        }
    }

    fn read_kind(&self) -> ReadKind {
        self.read_kind
    }

    fn adapters(&self) -> Vec<Option<Adapter>> {
        vec![self.adapter()]
    }

    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        self.read_kind = kind;
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The e-manual's Fast Sync Read example (Protocol 2.0 page): Present Position (132, 4
    /// bytes) of servos 3, 7 and 4, reading 166, 2079 and 1023.
    const EMANUAL_INSTRUCTION: [u8; 17] = [
        0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x0A, 0x00, 0x8A, 0x84, 0x00, 0x04, 0x00, 0x03, 0x07, 0x04,
        0x20, 0xF2,
    ];
    const EMANUAL_REPLY: [u8; 32] = [
        0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, // header, id, LEN 25, status
        0x00, 0x03, 0xA6, 0x00, 0x00, 0x00, 0x84, 0x08, // servo 3: 166, CRC 0x0884
        0x00, 0x07, 0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, // servo 7: 2079, CRC 0xCA16
        0x00, 0x04, 0xFF, 0x03, 0x00, 0x00, 0xD1, 0x9E, // servo 4: 1023, CRC 0x9ED1
    ];
    const IDS: [u8; 3] = [3, 7, 4];

    /// A status packet of servo `id` as a servo sends it (stuffed, with its CRC).
    fn status(id: u8, error: u8, params: &[u8]) -> Vec<u8> {
        snakectl_sim::protocol::encode_status(id, error, params)
    }

    /// Every packet `bytes` holds, fed at once, until none is pending.
    fn frame_all(bytes: &[u8]) -> Vec<(Framed, Vec<u8>)> {
        let mut rx = StatusReader::new();
        rx.feed(bytes);
        let mut out = Vec::new();
        loop {
            match rx.frame() {
                Framed::Pending => return out,
                f => out.push((f, rx.params().to_vec())),
            }
        }
    }

    fn packet(id: u8, params: &[u8]) -> (Framed, Vec<u8>) {
        (Framed::Packet { id, error: 0 }, params.to_vec())
    }

    #[test]
    fn status_packets_are_framed_past_noise_and_unstuffed() {
        // Parameters that need stuffing: `FF FF FD` twice, the second followed by a real `FD`.
        let data = [0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFD, 0xFD, 0x00];
        let mut bytes = vec![0x00, 0xFF, 0xFF, 0x12];
        bytes.extend(status(3, 0, &data));
        bytes.extend(status(7, 0x80, &[1, 2, 3, 4]));
        let framed = frame_all(&bytes);
        assert_eq!(framed[0], packet(3, &data));
        assert_eq!(
            framed[1],
            (Framed::Packet { id: 7, error: 0x80 }, vec![1, 2, 3, 4])
        );
        assert_eq!(framed.len(), 2);
    }

    #[test]
    fn a_packet_is_pending_until_its_last_byte_arrives() {
        let bytes = status(5, 0, &[0x24, 0x04, 48]);
        let mut rx = StatusReader::new();
        for (i, &b) in bytes.iter().enumerate() {
            assert_eq!(rx.frame(), Framed::Pending, "after {i} bytes");
            rx.feed(&[b]);
        }
        assert_eq!(rx.frame(), Framed::Packet { id: 5, error: 0 });
        assert_eq!(rx.params(), [0x24, 0x04, 48]);
    }

    #[test]
    fn a_length_field_too_short_costs_that_packet_alone() {
        // Length 2 (no room for the error byte), with a CRC that matches its first 7 bytes:
        // a packet no servo sends, which the crate's parser panics on.
        let mut bytes = vec![0xFF, 0xFF, 0xFD, 0x00, 3, 0x02, 0x00];
        let crc = calculate_checksum(0, &bytes);
        bytes.extend(crc.to_le_bytes());
        bytes.extend(status(7, 0, &[1, 0, 0, 0]));
        let framed = frame_all(&bytes);
        assert!(
            matches!(&framed[0].0, Framed::Damaged { id: 3, damage: Damage::Malformed(w) } if w.contains("says 2 bytes")),
            "{framed:?}"
        );
        assert_eq!(framed[1], packet(7, &[1, 0, 0, 0]));
        assert_eq!(framed.len(), 2);
    }

    #[test]
    fn a_length_field_beyond_the_buffer_costs_that_packet_alone() {
        let mut bytes = status(3, 0, &[166, 0, 0, 0]);
        bytes[6] ^= 0x10; // 0x0008 -> 0x1008
        bytes.extend(status(7, 0, &[31, 8, 0, 0]));
        let framed = frame_all(&bytes);
        assert!(
            matches!(framed[0].0, Framed::Damaged { id: 3, .. }),
            "{framed:?}"
        );
        assert_eq!(framed[1], packet(7, &[31, 8, 0, 0]));
    }

    #[test]
    fn a_damaged_byte_costs_its_packet_and_the_next_is_read() {
        for at in 4..15 {
            let mut bytes = status(3, 0, &[166, 0, 0, 0]);
            bytes[at] ^= 0x04;
            bytes.extend(status(7, 0, &[31, 8, 0, 0]));
            let mut rx = StatusReader::new();
            rx.feed(&bytes);
            let mut found = Vec::new();
            loop {
                match rx.frame() {
                    Framed::Packet { id, .. } => found.push((id, rx.params().to_vec())),
                    Framed::Damaged { .. } => {}
                    // A length damaged upwards (within the buffer) waits for bytes that never
                    // come: the caller gives it up at its deadline.
                    Framed::Pending => {
                        if rx.give_up().is_none() {
                            break;
                        }
                    }
                }
            }
            assert_eq!(found, [(7, vec![31, 8, 0, 0])], "byte {at} damaged");
        }
    }

    #[test]
    fn a_packet_that_is_not_a_status_is_refused() {
        let mut bytes = snakectl_sim::protocol::encode_instruction(1, 0x02, &[0x84, 0, 4, 0]);
        bytes.extend(status(1, 0, &[1, 2, 3, 4]));
        let framed = frame_all(&bytes);
        assert!(
            matches!(&framed[0].0, Framed::Damaged { id: 1, damage: Damage::Malformed(w) } if w.contains("0x02")),
            "{framed:?}"
        );
        assert_eq!(framed[1], packet(1, &[1, 2, 3, 4]));
    }

    #[test]
    fn an_error_code_names_its_servo_and_the_alert_bit_is_a_flag() {
        assert!(matches!(status_error(9, 0x80), Ok(true)));
        assert!(matches!(status_error(9, 0x00), Ok(false)));
        assert!(matches!(
            status_error(9, 0x81),
            Err(ServoError::Status {
                id: 9,
                code: 1,
                alert: true
            })
        ));
    }

    fn parse(bytes: &[u8]) -> (FastState, SyncReadBuf, usize) {
        let mut out = SyncReadBuf::new();
        out.reset(&IDS, 4, Duration::from_millis(1));
        let mut reply = FastReply::new(&IDS, 4);
        let state = reply.advance(bytes, &mut out);
        (state, out, reply.intact())
    }

    fn position(out: &SyncReadBuf, i: usize) -> Option<i64> {
        out.get(i)
            .ok()
            .and_then(|(d, _)| Register::PresentPosition.decode(d))
    }

    #[test]
    fn the_emanual_example_instruction_is_laid_out_as_sync_read() {
        let crc = calculate_checksum(0, &EMANUAL_INSTRUCTION[..15]);
        assert_eq!(crc, 0xF220);
        assert_eq!(
            EMANUAL_INSTRUCTION[5],
            (4 + IDS.len() + 3) as u8,
            "LEN = params + 3"
        );
        assert_eq!(EMANUAL_INSTRUCTION[7], FAST_SYNC_READ);
        assert_eq!(fast_reply_bytes(3, 4), EMANUAL_REPLY.len());
    }

    #[test]
    fn the_emanual_example_reply_reads_all_three_servos() {
        let (state, out, intact) = parse(&EMANUAL_REPLY);
        assert!(matches!(state, FastState::Complete), "{state:?}");
        assert_eq!(intact, 3);
        assert_eq!(
            (0..3).map(|i| position(&out, i)).collect::<Vec<_>>(),
            [Some(166), Some(2079), Some(1023)]
        );
    }

    #[test]
    fn the_reply_is_read_as_it_arrives_byte_by_byte() {
        let mut out = SyncReadBuf::new();
        out.reset(&IDS, 4, Duration::from_millis(1));
        let mut reply = FastReply::new(&IDS, 4);
        let mut intact = Vec::new();
        for end in 0..EMANUAL_REPLY.len() {
            let state = reply.advance(&EMANUAL_REPLY[..end], &mut out);
            assert!(matches!(state, FastState::Pending), "{end}: {state:?}");
            intact.push(reply.intact());
        }
        // Each block counts once its CRC is in: after bytes 16, 24 (and 32).
        assert_eq!(intact[16], 1);
        assert_eq!(intact[15], 0);
        assert_eq!(intact[24], 2);
        assert!(matches!(
            reply.advance(&EMANUAL_REPLY, &mut out),
            FastState::Complete
        ));
        assert_eq!(position(&out, 2), Some(1023));
    }

    #[test]
    fn a_reply_cut_short_keeps_the_blocks_that_arrived_whole() {
        for (cut, whole) in [
            (0, 0),
            (3, 0),
            (7, 0),
            (8, 0),
            (12, 0),
            (15, 0),
            (16, 1),
            (23, 1),
            (31, 2),
        ] {
            let (state, out, intact) = parse(&EMANUAL_REPLY[..cut]);
            assert!(
                matches!(state, FastState::Pending),
                "cut at {cut}: {state:?}"
            );
            assert_eq!(intact, whole, "cut at {cut}");
            for i in 0..3 {
                assert_eq!(out.get(i).is_ok(), i < whole, "cut at {cut}, servo {i}");
            }
        }
    }

    #[test]
    fn a_damaged_byte_breaks_the_reply_from_its_block_on() {
        for (byte, broken) in [
            (10, 0),
            (14, 0),
            (15, 0),
            (19, 1),
            (22, 1),
            (26, 2),
            (31, 2),
        ] {
            let mut bytes = EMANUAL_REPLY;
            bytes[byte] ^= 0x10;
            let (state, out, intact) = parse(&bytes);
            match state {
                FastState::Broken {
                    index,
                    error: ServoError::Checksum { id, .. },
                } => {
                    assert_eq!((index, id), (broken, IDS[broken]), "byte {byte}");
                }
                other => panic!("byte {byte}: {other:?}"),
            }
            assert_eq!(intact, broken);
            assert_eq!(position(&out, 0).is_some(), broken > 0);
        }
    }

    #[test]
    fn a_header_that_does_not_fit_is_passed_over_and_the_reply_waited_for() {
        for (byte, value) in [(4, 0x03), (5, 0x18), (6, 0x01), (7, 0x56)] {
            let mut bytes = EMANUAL_REPLY;
            bytes[byte] = value;
            let mut out = SyncReadBuf::new();
            out.reset(&IDS, 4, Duration::from_millis(1));
            let mut reply = FastReply::new(&IDS, 4);
            let state = reply.advance(&bytes, &mut out);
            assert!(
                matches!(state, FastState::Pending),
                "byte {byte}: {state:?}"
            );
            assert_eq!((reply.intact(), reply.skipped()), (0, 1), "byte {byte}");
            // Nothing taken from it; if the real reply follows, it is read.
            assert!(out.get(0).is_err());
            let mut both = bytes.to_vec();
            both.extend_from_slice(&EMANUAL_REPLY);
            assert!(matches!(
                reply.advance(&both, &mut out),
                FastState::Complete
            ));
            assert_eq!(position(&out, 2), Some(1023));
        }
    }

    #[test]
    fn a_late_reply_to_an_earlier_read_is_passed_over() {
        // A Fast reply of 8 bytes a servo (an earlier read's), then this read's.
        let mut late = vec![0xFF, 0xFF, 0xFD, 0x00, 0xFE];
        late.extend_from_slice(&((1 + 3 * 12) as u16).to_le_bytes());
        late.push(0x55);
        for (i, &id) in IDS.iter().enumerate() {
            late.extend_from_slice(&[0, id]);
            late.extend_from_slice(&[i as u8; 8]);
            let crc = calculate_checksum(0, &late);
            late.extend_from_slice(&crc.to_le_bytes());
        }
        late.extend_from_slice(&EMANUAL_REPLY);
        let (state, out, _) = parse(&late);
        assert!(matches!(state, FastState::Complete), "{state:?}");
        assert_eq!(position(&out, 0), Some(166));
    }

    #[test]
    fn a_block_of_another_servo_is_refused_even_with_a_good_crc() {
        let mut bytes = EMANUAL_REPLY.to_vec();
        bytes[17] = 9;
        // Recompute the running CRCs as a chain with servo 9 second would have sent them.
        for end in [22, 30] {
            let crc = calculate_checksum(0, &bytes[..end]);
            bytes[end..end + 2].copy_from_slice(&crc.to_le_bytes());
        }
        let (state, _, intact) = parse(&bytes);
        assert!(
            matches!(
                state,
                FastState::Broken {
                    index: 1,
                    error: ServoError::Malformed { id: 7, .. }
                }
            ),
            "{state:?}"
        );
        assert_eq!(intact, 1);
    }

    #[test]
    fn noise_before_the_header_and_garbage_after_the_reply_are_ignored() {
        let mut bytes = vec![0x00, 0xFF, 0x13, 0xFF, 0xFF];
        bytes.extend_from_slice(&EMANUAL_REPLY);
        bytes.extend_from_slice(&[0xFF, 0xFF, 0xFD, 0x00, 0x42, 0x42]);
        let (state, out, _) = parse(&bytes);
        assert!(matches!(state, FastState::Complete), "{state:?}");
        assert_eq!(position(&out, 1), Some(2079));
    }

    #[test]
    fn a_status_error_in_a_block_names_that_servo_and_keeps_the_others() {
        let mut bytes = EMANUAL_REPLY.to_vec();
        bytes[16] = 0x87; // servo 7: access error, alert
        for end in [22, 30] {
            let crc = calculate_checksum(0, &bytes[..end]);
            bytes[end..end + 2].copy_from_slice(&crc.to_le_bytes());
        }
        let (state, out, _) = parse(&bytes);
        assert!(matches!(state, FastState::Complete), "{state:?}");
        assert!(matches!(
            out.get(1),
            Err(ServoError::Status {
                id: 7,
                code: 7,
                alert: true
            })
        ));
        assert_eq!(position(&out, 0), Some(166));
        assert_eq!(position(&out, 2), Some(1023));
    }

    #[test]
    fn the_alert_bit_is_a_flag_beside_the_data() {
        let mut bytes = EMANUAL_REPLY.to_vec();
        bytes[8] = 0x80;
        for end in [14, 22, 30] {
            let crc = calculate_checksum(0, &bytes[..end]);
            bytes[end..end + 2].copy_from_slice(&crc.to_le_bytes());
        }
        let (state, out, _) = parse(&bytes);
        assert!(matches!(state, FastState::Complete), "{state:?}");
        assert_eq!(out.get(0).map(|(_, alert)| alert).ok(), Some(true));
        assert_eq!(position(&out, 0), Some(166));
    }

    #[test]
    fn a_fast_reply_may_pause_for_the_latency_timer_of_the_adapter_it_is_behind() {
        let ms = Duration::from_millis;
        assert_eq!(stall_behind(None), FAST_STALL);
        assert_eq!(stall_behind(Some(Adapter::FTDI_1MS)), FAST_STALL);
        // The chip's default timer holds a reply's last partial packet up to 16 ms after the
        // packet before: a pause of 2 ms gave up on every reply of more than one packet.
        assert_eq!(stall_behind(Some(Adapter::ftdi(ms(16)))), ms(17));
        // A timer the port told when it opened, as one it was taken to be behind.
        let too_high = Latency::TooHigh {
            ms: 16,
            command: String::new(),
            error: String::new(),
        };
        assert_eq!(stall_behind(too_high.adapter()), ms(17));
    }

    #[test]
    fn a_fast_read_sleeps_only_toward_an_arrival_learnt_for_its_shape() {
        let us = Duration::from_micros;
        // Nothing learnt yet: wait on the port at once.
        assert_eq!(Arrival::sleep(None, 12, 13, 1_000_000), Duration::ZERO);
        let learnt = Some(Arrival::learn(None, 12, 13, 1_000_000, us(3100)));
        assert_eq!(
            Arrival::sleep(learnt, 12, 13, 1_000_000),
            us(3100) - WAKE_AHEAD
        );
        // Another shape (servos, bytes, baud) has its own arrival, not yet learnt.
        assert_eq!(Arrival::sleep(learnt, 6, 13, 1_000_000), Duration::ZERO);
        assert_eq!(Arrival::sleep(learnt, 12, 8, 1_000_000), Duration::ZERO);
        assert_eq!(Arrival::sleep(learnt, 12, 13, 4_000_000), Duration::ZERO);
        // A far end that answers at once (a simulator without wire timing) is never slept for.
        let at_once = Some(Arrival::learn(None, 12, 13, 1_000_000, us(40)));
        assert_eq!(Arrival::sleep(at_once, 12, 13, 1_000_000), Duration::ZERO);
    }

    #[test]
    fn an_earlier_arrival_is_learnt_at_once_and_a_later_one_an_eighth_at_a_time() {
        let us = Duration::from_micros;
        let learnt = Some(Arrival::learn(None, 12, 13, 1_000_000, us(3100)));
        let earlier = Arrival::learn(learnt, 12, 13, 1_000_000, us(2500));
        assert_eq!(earlier.after, us(2500));
        // One wake-up 8 ms late moves it by 1 ms, so the next reads do not sleep past their
        // replies for long.
        let late = Arrival::learn(learnt, 12, 13, 1_000_000, us(11_100));
        assert_eq!(late.after, us(4100));
        // Another shape starts over from what it saw.
        let other = Arrival::learn(learnt, 6, 13, 1_000_000, us(1800));
        assert_eq!((other.servos, other.after), (6, us(1800)));
    }
}
