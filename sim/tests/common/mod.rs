//! Helpers shared by the integration tests.
#![allow(dead_code, missing_docs, clippy::unwrap_used, clippy::expect_used)]

use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};

use snakectl_sim::protocol::{self, Frame, Parser};
use snakectl_sim::table::ControlTable;
use snakectl_sim::{ManualClock, Model, Reply, ServoSpec, SimConfig, SimHandle, Simulator};

/// A simulator on a manual clock with the given servos and otherwise default settings.
pub fn sim(servos: Vec<ServoSpec>) -> (Simulator, ManualClock) {
    sim_with(SimConfig {
        servos,
        ..SimConfig::default()
    })
}

pub fn sim_with(config: SimConfig) -> (Simulator, ManualClock) {
    let clock = ManualClock::new();
    let sim = Simulator::new(config, Arc::new(clock.clone())).expect("valid config");
    (sim, clock)
}

pub fn xl430(ids: &[u8]) -> Vec<ServoSpec> {
    ids.iter()
        .map(|&id| ServoSpec::new(id, Model::Xl430W250))
        .collect()
}

/// Send one instruction, return the replies.
pub fn send(sim: &mut Simulator, id: u8, instruction: u8, params: &[u8]) -> Vec<Reply> {
    sim.handle_bytes(&protocol::encode_instruction(id, instruction, params))
}

/// A decoded status packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Status {
    pub id: u8,
    pub error: u8,
    pub data: Vec<u8>,
}

pub fn decode(reply: &Reply) -> Status {
    let mut parser = Parser::default();
    let frames = parser.feed(&reply.bytes, Instant::now());
    assert_eq!(frames.len(), 1, "one frame in {:02X?}", reply.bytes);
    match &frames[0].frame {
        Frame::Packet(p) => {
            assert_eq!(p.instruction, protocol::STATUS);
            Status {
                id: p.id,
                error: p.params[0],
                data: p.params[1..].to_vec(),
            }
        }
        other => panic!("not a valid status packet: {other:?}"),
    }
}

/// Send one instruction that must get exactly one reply; return it decoded.
pub fn one(sim: &mut Simulator, id: u8, instruction: u8, params: &[u8]) -> Status {
    let replies = send(sim, id, instruction, params);
    assert_eq!(
        replies.len(),
        1,
        "replies to {instruction:#04x}: {replies:?}"
    );
    decode(&replies[0])
}

pub fn write_params(address: u16, data: &[u8]) -> Vec<u8> {
    let mut p = address.to_le_bytes().to_vec();
    p.extend_from_slice(data);
    p
}

pub fn read_params(address: u16, len: u16) -> Vec<u8> {
    let mut p = address.to_le_bytes().to_vec();
    p.extend_from_slice(&len.to_le_bytes());
    p
}

/// WRITE and return the error byte.
pub fn write(sim: &mut Simulator, id: u8, address: u16, data: &[u8]) -> u8 {
    one(
        sim,
        id,
        protocol::instruction::WRITE,
        &write_params(address, data),
    )
    .error
}

/// READ a little-endian value of `len` bytes (1, 2, 4), sign-extended.
pub fn read(sim: &mut Simulator, id: u8, address: u16, len: u16) -> (u8, i64) {
    let s = one(
        sim,
        id,
        protocol::instruction::READ,
        &read_params(address, len),
    );
    let signed = ControlTable::for_model(Model::Xm430W350)
        .item_at(address)
        .is_none_or(|i| i.signed);
    let v = match s.data.len() {
        1 if signed => i64::from(s.data[0] as i8),
        1 => i64::from(s.data[0]),
        2 if signed => i64::from(i16::from_le_bytes([s.data[0], s.data[1]])),
        2 => i64::from(u16::from_le_bytes([s.data[0], s.data[1]])),
        4 => i64::from(i32::from_le_bytes([
            s.data[0], s.data[1], s.data[2], s.data[3],
        ])),
        _ => 0,
    };
    (s.error, v)
}

pub fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).expect("hex byte"))
        .collect()
}

/// Generous bound on waiting for a condition: the machine may be busy. Reached only on failure.
pub const DEADLINE: Duration = Duration::from_secs(10);

/// Write `bytes` to the simulator's pty and wait until it has taken all of them; returns the
/// good packets it parsed from them and the replies it made. Both are final once the bytes are
/// in (replies are made as packets are parsed), so a silence is checked without waiting one out.
pub fn send_all(port: &mut impl Write, handle: &SimHandle, bytes: &[u8]) -> (u64, u64) {
    let before = handle.with_sim(|s| s.stats());
    port.write_all(bytes).expect("send");
    let want = before.bytes + bytes.len() as u64;
    let deadline = Instant::now() + DEADLINE;
    loop {
        let now = handle.with_sim(|s| s.stats());
        if now.bytes >= want {
            return (now.packets - before.packets, now.replies - before.replies);
        }
        assert!(
            Instant::now() < deadline,
            "the simulator took {} of {} bytes",
            now.bytes - before.bytes,
            bytes.len()
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// A Fast read's reply `bytes` is the undamaged `whole` but for one byte inside the block at
/// `block` (its ERR to its CRC): the running CRC ending just before the block still checks,
/// the one ending the block (through the damaged byte) does not.
pub fn assert_one_block_corrupted(bytes: &[u8], whole: &[u8], block: std::ops::Range<usize>) {
    assert_eq!(bytes.len(), whole.len());
    let differs: Vec<usize> = (0..whole.len()).filter(|&i| bytes[i] != whole[i]).collect();
    assert_eq!(differs.len(), 1, "{differs:?}");
    assert!(block.contains(&differs[0]), "{differs:?} outside {block:?}");
    let crc_at = |end: usize| u16::from_le_bytes([bytes[end - 2], bytes[end - 1]]);
    assert_eq!(
        protocol::crc16(&bytes[..block.start - 2]),
        crc_at(block.start)
    );
    assert_ne!(protocol::crc16(&bytes[..block.end - 2]), crc_at(block.end));
}
