//! The wire bound: how long one tick's exchanges take on the wire, and so the highest rate a
//! configuration can reach, counted byte by byte from Protocol 2.0's packet layouts.
//!
//! A tick writes the goals (one Sync Write of 4-byte Goal Position) and reads a block of `X`
//! data bytes from every servo, on each port; the ports work in parallel, so the tick lasts as
//! long as its busiest port. Per port of `N` servos (sizes in bytes, 10 bits a byte on the wire):
//! - Sync Write of the goals: `14 + 5N` (header 4, id, length 2, instruction, address 2, data
//!   length 2, CRC 2; then id and 4 bytes per servo);
//! - Sync Read or Fast Sync Read instruction: `14 + N`;
//! - replies, Sync Read: `N (11 + X)` (one status packet each), and `N` Return Delay Times;
//! - replies, Fast Sync Read: `8 + N (X + 4)` (one packet: header 4, id, length 2, instruction;
//!   then error, id, data and CRC per servo), and one Return Delay Time;
//! - with a USB-serial adapter (the FTDI chip of a U2D2), the reply's last partial USB packet
//!   (62 data bytes each) waits for the adapter's latency timer before the host sees it.
//!
//! With `N = 12`, `X = 8` (Present Velocity and Position) at 1 Mbps and no delay: 74 + 26 +
//! 228 = 328 bytes, 3.28 ms, 305 Hz. Pure arithmetic: no I/O, no clock.

use std::time::Duration;

/// Bytes of a Sync Write or Sync Read instruction packet before the per-servo part.
const INSTRUCTION_OVERHEAD: usize = 14;
/// Bytes of one status packet around its data (header 4, id, length 2, instruction, error,
/// CRC 2).
const STATUS_OVERHEAD: usize = 11;
/// Bytes of a Fast Sync Read reply before its blocks (header 4, id, length 2, instruction).
const FAST_HEADER: usize = 8;
/// Bytes of one servo's block in a Fast Sync Read reply around its data (error, id, CRC 2).
const FAST_BLOCK_OVERHEAD: usize = 4;
/// Bytes of one goal in the Sync Write: id and Goal Position (4).
const GOAL_BYTES: usize = 5;
/// Bits on the wire per byte: start, 8 data, stop.
const BITS_PER_BYTE: u64 = 10;
/// Data bytes an FTDI adapter hands the host in one full USB packet (64 minus 2 status bytes).
pub const FTDI_PACKET_BYTES: usize = 62;

pub use super::ReadKind;

/// A USB-serial adapter between the host and the bus: received bytes reach the host in USB
/// packets of `packet_bytes`, or when the latency timer runs out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Adapter {
    /// The latency timer (16 ms by default on an FTDI chip, 1 ms as snakectl sets it).
    pub latency: Duration,
    /// Data bytes per full USB packet ([`FTDI_PACKET_BYTES`] for an FTDI chip).
    pub packet_bytes: usize,
}

impl Adapter {
    /// An FTDI chip with its latency timer at 1 ms, as snakectl sets it.
    pub const FTDI_1MS: Self = Self {
        latency: Duration::from_millis(1),
        packet_bytes: FTDI_PACKET_BYTES,
    };

    /// An FTDI chip (the U2D2's) with its latency timer at `latency`.
    pub fn ftdi(latency: Duration) -> Self {
        Self {
            latency,
            packet_bytes: FTDI_PACKET_BYTES,
        }
    }

    /// How long the host waits beyond the wire for a reply of `bytes`: a partial last packet
    /// waits out the latency timer; a reply of whole packets goes up at once.
    pub fn hold(&self, bytes: usize) -> Duration {
        if bytes == 0 || bytes % self.packet_bytes.max(1) == 0 {
            Duration::ZERO
        } else {
            self.latency
        }
    }
}

/// What one port's tick exchanges, as a function of the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wire {
    /// Servos on the port.
    pub servos: usize,
    /// Baud rate, bits/s.
    pub baud: u32,
    /// Sync Read or Fast Sync Read.
    pub read: ReadKind,
    /// Data bytes read from each servo (`X`: 8 for Present Velocity and Position; more when
    /// health values ride along in the same block).
    pub data_bytes: usize,
    /// Return Delay Time of every servo.
    pub return_delay: Duration,
    /// The USB-serial adapter, when its timing is counted (`None`: bytes reach the host as they
    /// arrive, as on a pseudo-terminal).
    pub adapter: Option<Adapter>,
}

/// One port's tick on the wire: its bytes and how long they take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bound {
    /// Bytes the host sends: the Sync Write of the goals and the read instruction.
    pub bytes_out: usize,
    /// Bytes the servos send back.
    pub bytes_in: usize,
    /// The tick's time: bytes on the wire, return delays and the adapter's hold.
    pub tick: Duration,
    /// The adapter's part of `tick`: its latency timer, waited out for the reply's last
    /// partial USB packet (zero without an adapter model).
    pub hold: Duration,
}

impl Bound {
    /// The highest tick rate, Hz (infinite for an empty port).
    pub fn rate_hz(&self) -> f64 {
        1.0 / self.tick.as_secs_f64()
    }

    /// All bytes of the tick.
    pub fn bytes(&self) -> usize {
        self.bytes_out + self.bytes_in
    }
}

impl Wire {
    /// Bytes of the Sync Write of the goals.
    pub fn write_bytes(&self) -> usize {
        if self.servos == 0 {
            return 0;
        }
        INSTRUCTION_OVERHEAD + GOAL_BYTES * self.servos
    }

    /// Bytes of the read instruction.
    pub fn read_instruction_bytes(&self) -> usize {
        if self.servos == 0 {
            return 0;
        }
        INSTRUCTION_OVERHEAD + self.servos
    }

    /// Bytes of the replies to the read.
    pub fn reply_bytes(&self) -> usize {
        let n = self.servos;
        if n == 0 {
            return 0;
        }
        match self.read {
            ReadKind::Sync => n * (STATUS_OVERHEAD + self.data_bytes),
            ReadKind::Fast => FAST_HEADER + n * (self.data_bytes + FAST_BLOCK_OVERHEAD),
        }
    }

    /// Return Delay Times waited in one read: one per reply with Sync Read, one in all with
    /// Fast Sync Read.
    pub fn turnarounds(&self) -> u32 {
        match (self.read, self.servos) {
            (_, 0) => 0,
            (ReadKind::Sync, n) => u32::try_from(n).unwrap_or(u32::MAX),
            (ReadKind::Fast, _) => 1,
        }
    }

    /// This port's tick on the wire.
    pub fn bound(&self) -> Bound {
        let bytes_out = self.write_bytes() + self.read_instruction_bytes();
        let bytes_in = self.reply_bytes();
        let bits = (bytes_out + bytes_in) as u64 * BITS_PER_BYTE;
        let baud = u64::from(self.baud.max(1));
        // Nanoseconds, rounded up: the wire never takes less than its bits.
        let wire = Duration::from_nanos((bits * 1_000_000_000).div_ceil(baud));
        let delays = self.return_delay * self.turnarounds();
        let hold = self.adapter.map_or(Duration::ZERO, |a| a.hold(bytes_in));
        Bound {
            bytes_out,
            bytes_in,
            tick: wire + delays + hold,
            hold,
        }
    }
}

/// The tick of several ports working in parallel: the busiest port's (`None`: no port).
pub fn bound_of_ports(ports: &[Wire]) -> Option<Bound> {
    ports.iter().map(Wire::bound).max_by_key(|b| b.tick)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wire(servos: usize, baud: u32, read: ReadKind, data_bytes: usize) -> Wire {
        Wire {
            servos,
            baud,
            read,
            data_bytes,
            return_delay: Duration::ZERO,
            adapter: None,
        }
    }

    #[test]
    fn twelve_servos_at_1_mbps_sync_read_of_velocity_and_position_is_328_bytes() {
        let w = wire(12, 1_000_000, ReadKind::Sync, 8);
        assert_eq!(w.write_bytes(), 74);
        assert_eq!(w.read_instruction_bytes(), 26);
        assert_eq!(w.reply_bytes(), 12 * 19);
        let b = w.bound();
        assert_eq!(b.bytes(), 328);
        assert_eq!(b.tick, Duration::from_micros(3280));
        assert!((b.rate_hz() - 304.878).abs() < 0.01, "{}", b.rate_hz());
    }

    #[test]
    fn four_data_bytes_give_the_older_count_of_28_plus_21_n() {
        let b = wire(12, 1_000_000, ReadKind::Sync, 4).bound();
        assert_eq!(b.bytes(), 28 + 21 * 12);
        assert_eq!(b.tick, Duration::from_micros(2800));
    }

    #[test]
    fn fast_sync_read_replies_in_one_packet_of_8_plus_n_blocks() {
        let w = wire(12, 1_000_000, ReadKind::Fast, 8);
        assert_eq!(w.reply_bytes(), 8 + 12 * 12);
        // The e-manual's example: three servos, 4 data bytes each, LEN 0x19 = 25 (the
        // packet less header, id and length).
        assert_eq!(
            wire(3, 1_000_000, ReadKind::Fast, 4).reply_bytes() - 7,
            0x19
        );
        let b = w.bound();
        assert_eq!(b.bytes(), 74 + 26 + 152);
        assert_eq!(b.tick, Duration::from_micros(2520));
    }

    #[test]
    fn health_in_the_block_reads_13_bytes_a_servo() {
        let sync = wire(12, 1_000_000, ReadKind::Sync, 13).bound();
        assert_eq!(sync.bytes_in, 12 * 24);
        assert_eq!(sync.tick, Duration::from_micros(3880));
        let fast = wire(12, 1_000_000, ReadKind::Fast, 13).bound();
        assert_eq!(fast.bytes_in, 8 + 12 * 17);
    }

    #[test]
    fn return_delay_counts_once_per_reply_with_sync_read_and_once_with_fast() {
        let mut w = wire(12, 1_000_000, ReadKind::Sync, 8);
        w.return_delay = Duration::from_micros(20);
        assert_eq!(w.bound().tick, Duration::from_micros(3280 + 12 * 20));
        w.read = ReadKind::Fast;
        assert_eq!(w.bound().tick, Duration::from_micros(2520 + 20));
    }

    #[test]
    fn the_adapter_holds_a_partial_last_packet_for_its_latency_timer() {
        let a = Adapter::ftdi(Duration::from_millis(1));
        assert_eq!(a.hold(19), Duration::from_millis(1));
        assert_eq!(a.hold(124), Duration::ZERO);
        let mut w = wire(12, 1_000_000, ReadKind::Sync, 8);
        w.adapter = Some(a);
        assert_eq!(w.bound().tick, Duration::from_micros(4280));
    }

    #[test]
    fn faster_baud_and_more_ports_shorten_the_tick() {
        let one = wire(24, 1_000_000, ReadKind::Sync, 8);
        let half = wire(12, 1_000_000, ReadKind::Sync, 8);
        let fast = wire(24, 4_000_000, ReadKind::Sync, 8);
        assert_eq!(one.bound().bytes(), 28 + 25 * 24);
        assert_eq!(fast.bound().tick * 4, one.bound().tick);
        let two = bound_of_ports(&[half, wire(11, 1_000_000, ReadKind::Sync, 8)]);
        assert_eq!(two, Some(half.bound()));
        assert!(half.bound().tick < one.bound().tick);
        assert_eq!(bound_of_ports(&[]), None);
    }
}
