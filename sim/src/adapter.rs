//! The USB-serial adapter between the bus and the host, as the host sees it.
//!
//! A pseudo-terminal hands every byte over at once; a real adapter does not. An FTDI chip (the
//! one in a U2D2) collects what it receives from the bus and sends it to the host in USB
//! packets of 64 bytes, 2 of them its status: a packet goes out when 62 data bytes are
//! waiting, or when its latency timer runs out. The timer counts from the last packet the chip
//! sent and restarts with every packet; when it runs out the chip sends what it holds (only
//! its 2 status bytes when it holds nothing). So a reply shorter than a packet waits for the
//! next expiry: up to the whole latency timer (16 ms as the chip comes, 1 ms as snakectl sets
//! it on Linux). Source: FTDI's AN232B-04, "Data Throughput, Latency and Handshaking".
//!
//! [`FtdiReceiver`] is that rule, pure: bytes in, each with the instant it came off the wire;
//! packets out, each with the instant it reaches the host. The pty layer holds the replies in
//! it when `[sim] adapter = "ftdi"`.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Data bytes in one USB packet of an FTDI full-speed chip (64, less 2 status bytes).
pub const FTDI_PACKET_DATA: usize = 62;

/// The latency timer as an FTDI chip comes (snakectl sets 1 ms on Linux).
pub const FTDI_DEFAULT_LATENCY: Duration = Duration::from_millis(16);

/// What stands between the simulated bus and the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Adapter {
    /// Nothing: every reply reaches the host as it leaves the bus (the pty alone).
    #[default]
    Direct,
    /// An FTDI chip with this latency timer (1..=255 ms on the chip).
    Ftdi {
        /// The latency timer.
        latency_timer: Duration,
    },
}

/// The receive side of an FTDI chip (see the module docs). Bytes must be given in the order
/// they come off the wire; one given with an earlier instant than one before it is taken as
/// arriving with it.
#[derive(Debug, Clone)]
pub struct FtdiReceiver {
    latency: Duration,
    /// When the latency timer last restarted: the chip's last packet to the host.
    timer_from: Instant,
    /// Bytes the chip holds, not yet sent.
    held: Vec<u8>,
    /// Bytes still on the wire: the instant each reaches the chip, in order.
    incoming: VecDeque<(Instant, u8)>,
    /// The latest instant a byte was given for.
    last_in: Instant,
}

/// One USB packet's data and the instant it reaches the host.
pub type Packet = (Instant, Vec<u8>);

impl FtdiReceiver {
    /// A chip with latency timer `latency` (at least 1 µs), plugged in at `start`.
    pub fn new(latency: Duration, start: Instant) -> Self {
        Self {
            latency: latency.max(Duration::from_micros(1)),
            timer_from: start,
            held: Vec::new(),
            incoming: VecDeque::new(),
            last_in: start,
        }
    }

    /// `bytes` come off the wire one every `byte_time`, the last at `end` (with `byte_time` 0,
    /// all at `end`).
    pub fn receive(&mut self, bytes: &[u8], end: Instant, byte_time: Duration) {
        let n = bytes.len();
        for (k, &b) in bytes.iter().enumerate() {
            let before = u32::try_from(n - 1 - k).unwrap_or(u32::MAX);
            let at = end
                .checked_sub(byte_time.saturating_mul(before))
                .unwrap_or(end)
                .max(self.last_in);
            self.last_in = at;
            self.incoming.push_back((at, b));
        }
    }

    /// The packets the chip has sent by `now`, in order.
    pub fn deliver(&mut self, now: Instant) -> Vec<Packet> {
        let mut out = Vec::new();
        self.run(now, &mut out, false);
        out
    }

    /// When the next packet with data reaches the host, if any byte is held or on its way.
    pub fn next_delivery(&self) -> Option<Instant> {
        if self.held.is_empty() && self.incoming.is_empty() {
            return None;
        }
        let mut ahead = self.clone();
        let mut out = Vec::new();
        let horizon = self.last_in.max(self.timer_from) + 2 * self.latency;
        ahead.run(horizon, &mut out, true);
        out.first().map(|&(at, _)| at)
    }

    /// Forget everything held and on its way (the line went away).
    pub fn clear(&mut self) {
        self.held.clear();
        self.incoming.clear();
    }

    /// Play the chip forward to `until`, collecting the packets with data it sends into `out`
    /// (only the first one when `first`).
    fn run(&mut self, until: Instant, out: &mut Vec<Packet>, first: bool) {
        loop {
            if first && !out.is_empty() {
                return;
            }
            let expiry = self.timer_from + self.latency;
            let byte = self.incoming.front().map(|&(at, _)| at);
            match byte {
                Some(at) if at <= expiry && at <= until => {
                    if let Some((_, b)) = self.incoming.pop_front() {
                        self.held.push(b);
                    }
                    if self.held.len() >= FTDI_PACKET_DATA {
                        out.push((at, std::mem::take(&mut self.held)));
                        self.timer_from = at;
                    }
                }
                _ if expiry <= until => {
                    if self.held.is_empty() {
                        // Status bytes alone: skip the whole periods before the next byte.
                        let horizon = byte.map_or(until, |at| at.min(until));
                        let periods = horizon
                            .saturating_duration_since(self.timer_from)
                            .as_nanos()
                            / self.latency.as_nanos().max(1);
                        let skip = u64::try_from(periods.max(1) * self.latency.as_nanos())
                            .unwrap_or(u64::MAX);
                        self.timer_from += Duration::from_nanos(skip);
                    } else {
                        out.push((expiry, std::mem::take(&mut self.held)));
                        self.timer_from = expiry;
                    }
                }
                _ => return,
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);
    const US: Duration = Duration::from_micros(1);

    #[test]
    fn a_short_reply_waits_for_the_next_expiry_of_the_timer() {
        let t0 = Instant::now();
        let mut chip = FtdiReceiver::new(16 * MS, t0);
        // 14 bytes ending 3 ms in, at 1 Mbps (10 µs a byte).
        chip.receive(&[7; 14], t0 + 3 * MS, 10 * US);
        assert_eq!(chip.next_delivery(), Some(t0 + 16 * MS));
        assert!(chip.deliver(t0 + 15 * MS).is_empty());
        let packets = chip.deliver(t0 + 16 * MS);
        assert_eq!(packets, vec![(t0 + 16 * MS, vec![7; 14])]);
        assert_eq!(chip.next_delivery(), None);
    }

    #[test]
    fn the_timer_runs_from_the_last_packet_even_an_empty_one() {
        let t0 = Instant::now();
        let mut chip = FtdiReceiver::new(MS, t0);
        // Nothing for 10.3 ms: the chip sent its status bytes every 1 ms; a reply ending then
        // goes out at the next whole millisecond.
        chip.receive(&[1, 2, 3], t0 + 10 * MS + 300 * US, 10 * US);
        assert_eq!(
            chip.deliver(t0 + 20 * MS),
            vec![(t0 + 11 * MS, vec![1, 2, 3])]
        );
    }

    #[test]
    fn a_full_packet_goes_at_once_and_restarts_the_timer() {
        let t0 = Instant::now();
        let mut chip = FtdiReceiver::new(16 * MS, t0);
        let bytes: Vec<u8> = (0..100).collect();
        // 100 bytes at 10 µs each, the last at 2 ms: the 62nd arrives 380 µs before the end.
        let end = t0 + 2 * MS;
        chip.receive(&bytes, end, 10 * US);
        let full_at = end - 38 * 10 * US;
        assert_eq!(chip.next_delivery(), Some(full_at));
        let packets = chip.deliver(t0 + 40 * MS);
        assert_eq!(packets.len(), 2);
        assert_eq!(packets[0], (full_at, bytes[..62].to_vec()));
        // The rest waits a whole latency timer from the full packet.
        assert_eq!(packets[1], (full_at + 16 * MS, bytes[62..].to_vec()));
    }

    #[test]
    fn bytes_that_come_before_the_expiry_join_the_same_packet() {
        let t0 = Instant::now();
        let mut chip = FtdiReceiver::new(4 * MS, t0);
        chip.receive(&[1; 10], t0 + MS, 10 * US);
        chip.receive(&[2; 10], t0 + 3 * MS, 10 * US);
        let packets = chip.deliver(t0 + 5 * MS);
        assert_eq!(packets.len(), 1);
        assert_eq!(packets[0].0, t0 + 4 * MS);
        assert_eq!(packets[0].1.len(), 20);
        chip.receive(&[3; 5], t0 + 9 * MS, 10 * US);
        chip.clear();
        assert_eq!(chip.next_delivery(), None);
        assert!(chip.deliver(t0 + 20 * MS).is_empty());
    }

    #[test]
    fn a_sync_read_of_twelve_replies_costs_up_to_one_latency_timer_more() {
        // Twelve 24-byte replies back to back at 1 Mbps (288 bytes, 2.88 ms), the first
        // starting at t0 + 0.5 ms: four full packets go as they fill, the last 40 bytes at the
        // next expiry, at most 1 ms after the last byte.
        let t0 = Instant::now();
        let mut chip = FtdiReceiver::new(MS, t0);
        let mut end = t0 + 500 * US;
        for id in 0..12u8 {
            end += 240 * US;
            chip.receive(&[id; 24], end, 10 * US);
        }
        let packets = chip.deliver(t0 + 10 * MS);
        let sizes: Vec<usize> = packets.iter().map(|p| p.1.len()).collect();
        assert_eq!(sizes.iter().sum::<usize>(), 288);
        let last = packets.last().unwrap().0;
        assert!(last >= end && last <= end + MS, "{:?}", last - end);
        assert!(packets.windows(2).all(|w| w[0].0 <= w[1].0));
    }
}
