//! Dynamixel Protocol 2.0 framing: CRC-16, byte stuffing, packet encoding and a streaming
//! parser that survives garbage, truncated packets and bad CRCs.
//!
//! Pure code: no I/O, no clock (the parser takes the time of each chunk as an argument).
//!
//! Packet layout (both directions): `FF FF FD 00 | id | len_lo len_hi | instruction | body | crc_lo
//! crc_hi`, where `len` counts the instruction byte, the *stuffed* body and the two CRC bytes, and
//! the CRC covers every byte before it, as transmitted (after stuffing). A status packet is an
//! instruction packet whose instruction is [`STATUS`] and whose body starts with the error byte.

use std::time::{Duration, Instant};

/// The four bytes that open every packet.
pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// The broadcast packet id: every servo executes the instruction.
pub const BROADCAST_ID: u8 = 0xFE;
/// Instruction byte of a status (reply) packet.
pub const STATUS: u8 = 0x55;
/// Largest value of the length field the parser accepts; anything longer is treated as garbage.
/// (The largest legitimate instruction, a bulk write to 253 servos, stays far below it.)
pub const MAX_LENGTH_FIELD: usize = 4096;

/// Instruction codes of Protocol 2.0.
pub mod instruction {
    /// Ping: model number and firmware version.
    pub const PING: u8 = 0x01;
    /// Read a block of the control table.
    pub const READ: u8 = 0x02;
    /// Write a block of the control table.
    pub const WRITE: u8 = 0x03;
    /// Register a write, executed later by ACTION.
    pub const REG_WRITE: u8 = 0x04;
    /// Execute the registered write.
    pub const ACTION: u8 = 0x05;
    /// Reset the control table to its factory values.
    pub const FACTORY_RESET: u8 = 0x06;
    /// Restart the servo.
    pub const REBOOT: u8 = 0x08;
    /// Clear the multi-turn revolution count.
    pub const CLEAR: u8 = 0x10;
    /// Store the control table to the servo's backup, or restore the EEPROM area from it
    /// (X430/X540 firmware 45 and later, X330 46 and later).
    pub const CONTROL_TABLE_BACKUP: u8 = 0x20;
    /// Read the same block from several servos.
    pub const SYNC_READ: u8 = 0x82;
    /// Read the same block from several servos, all answering in one status packet (X430/X540
    /// firmware 45 and later, X330 46 and later).
    pub const FAST_SYNC_READ: u8 = 0x8A;
    /// Write the same block on several servos.
    pub const SYNC_WRITE: u8 = 0x83;
    /// Read a different block from each of several servos.
    pub const BULK_READ: u8 = 0x92;
    /// Write a different block on each of several servos.
    pub const BULK_WRITE: u8 = 0x93;
    /// Read a different block from each of several servos, all answering in one status packet
    /// (the same firmware as Fast Sync Read).
    pub const FAST_BULK_READ: u8 = 0x9A;
}

/// Error numbers of the status packet's error byte (its low 7 bits), per the e-manual.
pub mod error {
    /// No error.
    pub const NONE: u8 = 0x00;
    /// The instruction could not be carried out.
    pub const RESULT_FAIL: u8 = 0x01;
    /// Undefined instruction, or ACTION without a registered write.
    pub const INSTRUCTION: u8 = 0x02;
    /// The CRC of the instruction packet does not match.
    pub const CRC: u8 = 0x03;
    /// The value is outside the item's own range.
    pub const DATA_RANGE: u8 = 0x04;
    /// Fewer bytes than the item (or the instruction) needs.
    pub const DATA_LENGTH: u8 = 0x05;
    /// The value is outside a limit item (e.g. Goal Position beyond the position limits).
    pub const DATA_LIMIT: u8 = 0x06;
    /// Read-only or undefined address, or EEPROM written while torque is on.
    pub const ACCESS: u8 = 0x07;
    /// Alert bit: a hardware error is latched in Hardware Error Status. A flag, not an error.
    pub const ALERT: u8 = 0x80;
}

/// CRC-16 of Protocol 2.0: polynomial 0x8005, initial value 0, no reflection, no final xor.
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

/// Continue a CRC-16 computation over more bytes.
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &byte in data {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x8005
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Byte stuffing: every `FF FF FD` in `data` gets an extra `FD` after it.
pub fn stuff(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + data.len() / 3);
    let mut run = 0usize; // how much of FF FF FD has just been seen
    for &byte in data {
        out.push(byte);
        run = match (run, byte) {
            (0, 0xFF) | (1, 0xFF) => run + 1,
            (2, 0xFF) => 2,
            (2, 0xFD) => {
                out.push(0xFD);
                0
            }
            _ => 0,
        };
    }
    out
}

/// Undo byte stuffing: every `FF FF FD FD` becomes `FF FF FD`.
pub fn unstuff(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len());
    let mut run = 0usize;
    let mut iter = data.iter().copied().peekable();
    while let Some(byte) = iter.next() {
        out.push(byte);
        run = match (run, byte) {
            (0, 0xFF) | (1, 0xFF) => run + 1,
            (2, 0xFF) => 2,
            (2, 0xFD) => {
                if iter.peek() == Some(&0xFD) {
                    iter.next();
                }
                0
            }
            _ => 0,
        };
    }
    out
}

/// Encode a packet: header, id, length, `instruction`, the stuffed `body`, CRC.
fn encode(id: u8, instruction: u8, body: &[u8]) -> Vec<u8> {
    let stuffed = stuff(body);
    let length = stuffed.len() + 3;
    let mut out = Vec::with_capacity(stuffed.len() + 10);
    out.extend_from_slice(&HEADER);
    out.push(id);
    // Lengths beyond u16 cannot be framed; callers build packets far smaller than that.
    let length = u16::try_from(length).unwrap_or(u16::MAX);
    out.extend_from_slice(&length.to_le_bytes());
    out.push(instruction);
    out.extend_from_slice(&stuffed);
    let crc = crc16(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Encode an instruction packet (what a client sends).
pub fn encode_instruction(id: u8, instruction: u8, params: &[u8]) -> Vec<u8> {
    encode(id, instruction, params)
}

/// Encode a status packet (what a servo answers): `error` then `params`.
pub fn encode_status(id: u8, error: u8, params: &[u8]) -> Vec<u8> {
    let mut body = Vec::with_capacity(params.len() + 1);
    body.push(error);
    body.extend_from_slice(params);
    encode(id, STATUS, &body)
}

/// One servo's part of a Fast Sync Read or Fast Bulk Read reply: its error byte, its id, its
/// data.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FastBlock {
    /// The status error byte (alert bit included).
    pub error: u8,
    /// The servo.
    pub id: u8,
    /// The bytes read.
    pub data: Vec<u8>,
}

/// Encode a Fast Sync Read reply as a chain of `servos` servos sends it, `len` data bytes
/// each: [`encode_fast_reply`] with every length `len`.
pub fn encode_fast_status(servos: usize, len: usize, blocks: &[FastBlock]) -> Vec<u8> {
    encode_fast_reply(&vec![len; servos], blocks)
}

/// Encode a Fast Sync Read or Fast Bulk Read reply as the chain sends it, the k-th servo of the
/// instruction reading `lengths[k]` bytes: `FF FF FD 00 | FE | LEN | 55 |` then, per servo,
/// `ERR ID DATA CRC`, where `LEN = 1 + Σ (lengths[k] + 4)` and each CRC is the CRC-16 of
/// everything before it from the header on. Not byte-stuffed. `blocks` may be fewer than
/// `lengths` (the chain broke off after them): the packet then ends after the last block given.
/// Block k's data is cut or padded to `lengths[k]`.
pub fn encode_fast_reply(lengths: &[usize], blocks: &[FastBlock]) -> Vec<u8> {
    if blocks.is_empty() {
        return Vec::new();
    }
    let total: usize = lengths.iter().map(|len| len + 4).sum();
    let length = u16::try_from(1 + total).unwrap_or(u16::MAX);
    let mut out = Vec::with_capacity(8 + total);
    out.extend_from_slice(&HEADER);
    out.push(BROADCAST_ID);
    out.extend_from_slice(&length.to_le_bytes());
    out.push(STATUS);
    for (block, &len) in blocks.iter().zip(lengths) {
        out.push(block.error);
        out.push(block.id);
        let start = out.len();
        out.extend(block.data.iter().copied().take(len));
        out.resize(start + len, 0);
        let crc = crc16(&out);
        out.extend_from_slice(&crc.to_le_bytes());
    }
    out
}

/// A packet whose CRC checked, with its body unstuffed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// Packet id (a servo id or [`BROADCAST_ID`]).
    pub id: u8,
    /// Instruction byte ([`STATUS`] for a reply).
    pub instruction: u8,
    /// Parameters after unstuffing (for a status packet: the error byte, then the data).
    pub params: Vec<u8>,
}

/// What the parser found in the byte stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame {
    /// A well-formed packet.
    Packet(Packet),
    /// A complete frame whose CRC did not match. The id and instruction bytes are reported as
    /// received, unverified: a servo answers a CRC error only to a frame addressed to it.
    BadCrc {
        /// The id byte as received.
        id: u8,
        /// The instruction byte as received.
        instruction: u8,
        /// CRC carried by the frame.
        received: u16,
        /// CRC computed over the frame.
        computed: u16,
    },
}

/// A frame and where it ended in the chunk that completed it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Parsed {
    /// The frame.
    pub frame: Frame,
    /// Index, within the chunk passed to [`Parser::feed`], of the frame's last byte.
    pub end_in_chunk: usize,
}

/// Streaming Protocol 2.0 parser.
///
/// Feed it chunks as they arrive; it returns the complete frames. Bytes that cannot start a
/// packet are skipped; a partial packet older than the inter-byte timeout is dropped (as a
/// servo does when a transmission breaks off); a frame whose CRC fails but that contains another
/// header is treated as a truncated packet followed by a new one, and parsing restarts there.
#[derive(Debug, Clone)]
pub struct Parser {
    buf: Vec<u8>,
    last_byte: Option<Instant>,
    timeout: Duration,
    skipped: u64,
}

impl Default for Parser {
    fn default() -> Self {
        Self::new(Duration::from_millis(50))
    }
}

impl Parser {
    /// A parser that drops a partial packet when no byte arrived for `timeout`.
    pub fn new(timeout: Duration) -> Self {
        Self {
            buf: Vec::new(),
            last_byte: None,
            timeout,
            skipped: 0,
        }
    }

    /// Bytes discarded so far as garbage or broken packets.
    pub fn skipped_bytes(&self) -> u64 {
        self.skipped
    }

    /// Bytes held back waiting for the rest of a packet.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Add a chunk received at `now`; return every frame it completed, in order.
    pub fn feed(&mut self, chunk: &[u8], now: Instant) -> Vec<Parsed> {
        if let Some(last) = self.last_byte {
            if !self.buf.is_empty() && now.saturating_duration_since(last) > self.timeout {
                self.skipped += self.buf.len() as u64;
                self.buf.clear();
            }
        }
        if !chunk.is_empty() {
            self.last_byte = Some(now);
        }
        // Bytes of `buf` that came before this chunk: frame ends are reported relative to it.
        let before = self.buf.len();
        self.buf.extend_from_slice(chunk);
        let mut out = Vec::new();
        let mut consumed = 0usize; // bytes of the original buf (incl. chunk) already removed
        loop {
            // Skip to the first header candidate.
            let start = find_header(&self.buf);
            if start > 0 {
                self.skipped += start as u64;
                self.buf.drain(..start);
                consumed += start;
            }
            if self.buf.len() < 7 {
                // Keep at most a possible header prefix.
                break;
            }
            let length = usize::from(u16::from_le_bytes([self.buf[5], self.buf[6]]));
            if !(3..=MAX_LENGTH_FIELD).contains(&length) {
                // Not a plausible packet: drop the first header byte and rescan.
                self.skipped += 1;
                self.buf.drain(..1);
                consumed += 1;
                continue;
            }
            let total = 7 + length;
            if self.buf.len() < total {
                break;
            }
            let received = u16::from_le_bytes([self.buf[total - 2], self.buf[total - 1]]);
            let computed = crc16(&self.buf[..total - 2]);
            if received != computed {
                // A header inside the frame means this one was cut short: restart there.
                if let Some(inner) = find_inner_header(&self.buf[4..total]) {
                    let cut = 4 + inner;
                    self.skipped += cut as u64;
                    self.buf.drain(..cut);
                    consumed += cut;
                    continue;
                }
                let frame = Frame::BadCrc {
                    id: self.buf[4],
                    instruction: self.buf[7],
                    received,
                    computed,
                };
                out.push(Parsed {
                    frame,
                    end_in_chunk: (consumed + total - 1).saturating_sub(before),
                });
                self.buf.drain(..total);
                consumed += total;
                continue;
            }
            let packet = Packet {
                id: self.buf[4],
                instruction: self.buf[7],
                params: unstuff(&self.buf[8..total - 2]),
            };
            out.push(Parsed {
                frame: Frame::Packet(packet),
                end_in_chunk: (consumed + total - 1).saturating_sub(before),
            });
            self.buf.drain(..total);
            consumed += total;
        }
        out
    }
}

/// Index of the first byte that may start a header (a full header, or a prefix of one at the
/// end of the buffer). Returns `buf.len()` when there is none.
fn find_header(buf: &[u8]) -> usize {
    for start in 0..buf.len() {
        let rest = &buf[start..];
        let n = rest.len().min(HEADER.len());
        if rest[..n] == HEADER[..n] {
            return start;
        }
    }
    buf.len()
}

/// Offset of a complete header strictly inside `body` (which starts after a header).
fn find_inner_header(body: &[u8]) -> Option<usize> {
    body.windows(HEADER.len()).position(|w| w == HEADER)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fast_sync_read_reply_is_the_emanuals_example() {
        // Protocol 2.0 page: servos 3, 7, 4 at 166, 2079, 1023 (Present Position, 4 bytes).
        let block = |id, value: u32| FastBlock {
            error: 0,
            id,
            data: value.to_le_bytes().to_vec(),
        };
        let bytes = encode_fast_status(3, 4, &[block(3, 166), block(7, 2079), block(4, 1023)]);
        assert_eq!(
            bytes,
            [
                0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00,
                0x84, 0x08, 0x00, 0x07, 0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, 0x00, 0x04, 0xFF, 0x03,
                0x00, 0x00, 0xD1, 0x9E
            ]
        );
        // And the instruction that asks for it.
        assert_eq!(
            encode_instruction(
                BROADCAST_ID,
                instruction::FAST_SYNC_READ,
                &[0x84, 0x00, 0x04, 0x00, 3, 7, 4]
            ),
            [
                0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x0A, 0x00, 0x8A, 0x84, 0x00, 0x04, 0x00, 0x03, 0x07,
                0x04, 0x20, 0xF2
            ]
        );
        // A chain that broke off after two servos sends their blocks under the full length.
        let short = encode_fast_status(3, 4, &[block(3, 166), block(7, 2079)]);
        assert_eq!(short[..], bytes[..24]);
        assert!(encode_fast_status(3, 4, &[]).is_empty());
    }

    #[test]
    fn the_fast_bulk_read_reply_is_the_emanuals_example() {
        // Protocol 2.0 page: servo 3's Present Position 166 (4 bytes), servo 7's Present PWM
        // 421 (2), servo 4's Present Temperature 31 (1).
        let blocks = [
            FastBlock {
                error: 0,
                id: 3,
                data: 166u32.to_le_bytes().to_vec(),
            },
            FastBlock {
                error: 0,
                id: 7,
                data: 421u16.to_le_bytes().to_vec(),
            },
            FastBlock {
                error: 0,
                id: 4,
                data: vec![31],
            },
        ];
        assert_eq!(
            encode_fast_reply(&[4, 2, 1], &blocks),
            [
                0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x14, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00,
                0x67, 0xA4, 0x00, 0x07, 0xA5, 0x01, 0x24, 0x74, 0x00, 0x04, 0x1F, 0xD9, 0xC1
            ]
        );
    }

    #[test]
    fn stuffing_round_trip() {
        let data = [0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFF, 0xFD, 0xFD, 0x00];
        let stuffed = stuff(&data);
        assert_eq!(
            stuffed,
            [0xFF, 0xFF, 0xFD, 0xFD, 0x01, 0xFF, 0xFF, 0xFF, 0xFD, 0xFD, 0xFD, 0x00]
        );
        assert_eq!(unstuff(&stuffed), data);
    }

    #[test]
    fn parser_skips_garbage_and_splits_chunks() {
        let now = Instant::now();
        let ping = encode_instruction(1, instruction::PING, &[]);
        let mut stream = vec![0x00, 0xFF, 0x13, 0xFF, 0xFF];
        stream.extend_from_slice(&ping);
        let mut parser = Parser::default();
        let mut frames = Vec::new();
        for byte in &stream {
            frames.extend(parser.feed(std::slice::from_ref(byte), now));
        }
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].end_in_chunk, 0);
        assert_eq!(
            frames[0].frame,
            Frame::Packet(Packet {
                id: 1,
                instruction: instruction::PING,
                params: vec![]
            })
        );
    }
}
