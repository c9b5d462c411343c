//! Fast Bulk Read (0x9A): the chain's one status packet, its blocks of different lengths byte for
//! byte, what a silent, damaged or too old servo does to it, its wire time, and the same packet
//! over the pseudo-terminal.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::io::Read;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use serialport::TTYPort;
use snakectl_sim::protocol::{self, crc16, instruction as ins, BROADCAST_ID, HEADER, STATUS};
use snakectl_sim::table::addr;
use snakectl_sim::{spawn_pty, Fault, ManualClock, Model, ServoSpec, SimConfig, Simulator};

/// Fast Bulk Read's instruction code, as the e-manual's instruction table gives it.
const FAST_BULK_READ: u8 = 0x9A;

/// The instruction's parameters: per servo its id, start address and length.
fn params(reads: &[(u8, u16, u16)]) -> Vec<u8> {
    let mut p = Vec::new();
    for &(id, address, len) in reads {
        p.push(id);
        p.extend_from_slice(&address.to_le_bytes());
        p.extend_from_slice(&len.to_le_bytes());
    }
    p
}

/// The reply a chain answering `reads` sends, assembled here from the layout the e-manual
/// gives (header, id 0xFE, LEN, 0x55, then per servo ERR ID DATA and the running CRC of the
/// packet so far), not with the simulator's encoder. `blocks` (error, id, data) may stop short
/// of `reads`: LEN still announces every servo asked.
fn assemble(reads: &[(u8, u16, u16)], blocks: &[(u8, u8, Vec<u8>)]) -> Vec<u8> {
    let len: usize = 1 + reads.iter().map(|r| usize::from(r.2) + 4).sum::<usize>();
    let mut out = HEADER.to_vec();
    out.push(BROADCAST_ID);
    out.extend_from_slice(&u16::try_from(len).unwrap().to_le_bytes());
    out.push(STATUS);
    for (error, id, data) in blocks {
        out.push(*error);
        out.push(*id);
        out.extend_from_slice(data);
        let crc = crc16(&out);
        out.extend_from_slice(&crc.to_le_bytes());
    }
    out
}

fn xl330(id: u8) -> ServoSpec {
    ServoSpec::new(id, Model::Xl330M288)
}

/// The e-manual's example chain on `clock`: XC330-T288s 3, 7 and 4 (XL330s here: same control
/// table addresses, same firmware rule) at Present Position 166, Present PWM 421 and Present
/// Temperature 31 °C.
fn emanual_chain_on(clock: &ManualClock) -> Simulator {
    let mut three = xl330(3);
    three.initial_position_ticks = Some(166);
    let config = SimConfig {
        servos: vec![three, xl330(7), xl330(4)],
        ..SimConfig::default()
    };
    let mut s = Simulator::new(config, Arc::new(clock.clone())).expect("config");
    // The clock stands still, so nothing recomputes these before the read.
    s.servo_mut(7).unwrap().poke(addr::PRESENT_PWM, 421);
    s.servo_mut(4).unwrap().set_temperature(31.0);
    s
}

fn emanual_chain() -> Simulator {
    emanual_chain_on(&ManualClock::new())
}

/// The e-manual's reads: Present Position of 3, Present PWM of 7, Present Temperature of 4.
const EMANUAL_READS: [(u8, u16, u16); 3] = [
    (3, addr::PRESENT_POSITION, 4),
    (7, addr::PRESENT_PWM, 2),
    (4, addr::PRESENT_TEMPERATURE, 1),
];

/// The e-manual's example reply, as printed there.
fn emanual_reply() -> Vec<u8> {
    hex("FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1")
}

#[test]
fn the_emanual_example_comes_back_byte_for_byte() {
    assert_eq!(ins::FAST_BULK_READ, FAST_BULK_READ);
    let instruction =
        protocol::encode_instruction(BROADCAST_ID, FAST_BULK_READ, &params(&EMANUAL_READS));
    // The e-manual prints this instruction with CRC 20 F2, the CRC of its Fast Sync Read
    // example; the CRC of these bytes is 2DDA.
    let printed = hex("FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 20 F2");
    assert_eq!(instruction[..23], printed[..23]);
    assert_eq!(instruction[23..], [0xDA, 0x2D]);

    let mut s = emanual_chain();
    let r = s.handle_bytes(&instruction);
    assert_eq!(r.len(), 1, "{r:?}");
    assert_eq!(r[0].id, BROADCAST_ID);
    assert_eq!(r[0].bytes, emanual_reply());
    // And the independent assembly agrees with the printed packet.
    let data = vec![
        (0, 3, 166u32.to_le_bytes().to_vec()),
        (0, 7, 421u16.to_le_bytes().to_vec()),
        (0, 4, vec![31]),
    ];
    assert_eq!(assemble(&EMANUAL_READS, &data), emanual_reply());

    // The instruction exactly as printed fails its CRC: nobody answers a broadcast.
    let mut s = emanual_chain();
    assert!(s.handle_bytes(&printed).is_empty());
    assert_eq!(s.stats().crc_errors, 1);
}

/// Three XL430s at 1000, 2000 and 3000 ticks, each asked something of another length.
const READS: [(u8, u16, u16); 3] = [
    (1, addr::MODEL_NUMBER, 2),
    (2, addr::PRESENT_POSITION, 4),
    (3, addr::PRESENT_TEMPERATURE, 1),
];

fn chain(firmware: [Option<u8>; 3], faults: Vec<Fault>) -> SimConfig {
    let servos = [1u8, 2, 3]
        .iter()
        .zip(firmware)
        .map(|(&id, fw)| {
            let mut s = ServoSpec::new(id, Model::Xl430W250);
            s.initial_position_ticks = Some(1000 * i32::from(id));
            s.firmware = fw;
            s
        })
        .collect();
    SimConfig {
        servos,
        faults,
        ..SimConfig::default()
    }
}

/// The blocks the three servos of [`chain`] send for [`READS`], all of them healthy.
fn blocks() -> Vec<(u8, u8, Vec<u8>)> {
    vec![
        (0, 1, 1060u16.to_le_bytes().to_vec()),
        (0, 2, 2000u32.to_le_bytes().to_vec()),
        (0, 3, vec![30]),
    ]
}

fn fast(config: SimConfig, reads: &[(u8, u16, u16)]) -> Vec<u8> {
    let (mut s, _) = sim_with(config);
    let r = send(&mut s, BROADCAST_ID, FAST_BULK_READ, &params(reads));
    assert!(r.len() <= 1, "{r:?}");
    r.into_iter().next().map(|r| r.bytes).unwrap_or_default()
}

#[test]
fn blocks_of_different_lengths_each_end_with_the_running_crc() {
    let bytes = fast(chain([None; 3], vec![]), &READS);
    assert_eq!(bytes, assemble(&READS, &blocks()));
    // Its structure: 8 bytes before the first block, then 2 + X + 2 a servo.
    assert_eq!(bytes.len(), 8 + (2 + 4) + (4 + 4) + (1 + 4));
    assert_eq!(
        usize::from(u16::from_le_bytes([bytes[5], bytes[6]])),
        bytes.len() - 7
    );
    for end in [14, 22, 27] {
        let crc = u16::from_le_bytes([bytes[end - 2], bytes[end - 1]]);
        assert_eq!(crc, crc16(&bytes[..end - 2]), "block ending at {end}");
    }
    // The ids come in the order of the instruction, not of the bus.
    let reversed: Vec<_> = READS.iter().rev().copied().collect();
    let mut expected = blocks();
    expected.reverse();
    assert_eq!(
        fast(chain([None; 3], vec![]), &reversed),
        assemble(&reversed, &expected)
    );
}

#[test]
fn a_silent_dropped_mute_or_too_old_servo_ends_the_packet_after_the_blocks_before_it() {
    let whole = assemble(&READS, &blocks());
    let first_only = assemble(&READS, &blocks()[..1]);
    let silent = Fault::Silent {
        id: 2,
        at: Duration::ZERO,
    };
    assert_eq!(fast(chain([None; 3], vec![silent]), &READS), first_only);
    let dropped = Fault::DropReplies {
        id: Some(2),
        fraction: 1.0,
    };
    assert_eq!(fast(chain([None; 3], vec![dropped]), &READS), first_only);
    // X430: Fast reads from firmware 45; servo 2 at 44 does not know the instruction.
    assert_eq!(
        fast(chain([None, Some(44), None], vec![]), &READS),
        first_only
    );
    assert_eq!(fast(chain([None, Some(45), None], vec![]), &READS), whole);
    // Status Return Level 0: a servo that answers pings only.
    let (mut s, _) = sim_with(chain([None; 3], vec![]));
    assert_eq!(write(&mut s, 2, addr::STATUS_RETURN_LEVEL, &[0]), 0);
    let r = send(&mut s, BROADCAST_ID, FAST_BULK_READ, &params(&READS));
    assert_eq!(r[0].bytes, first_only);
    // The first servo silent: nothing at all.
    let first = Fault::Silent {
        id: 1,
        at: Duration::ZERO,
    };
    assert!(fast(chain([None; 3], vec![first]), &READS).is_empty());
}

#[test]
fn a_corrupted_block_fails_the_running_crc_from_there_on() {
    let whole = assemble(&READS, &blocks());
    let corrupt = Fault::CorruptReplies {
        id: Some(2),
        fraction: 1.0,
    };
    let bytes = fast(chain([None; 3], vec![corrupt]), &READS);
    // Block 2 spans bytes 14..22 (ERR, ID, 4 data bytes, CRC).
    assert_one_block_corrupted(&bytes, &whole, 14..22);
}

#[test]
fn a_malformed_instruction_is_not_answered() {
    let p = params(&READS);
    let (mut s, _) = sim_with(chain([None; 3], vec![]));
    // Not sent to the broadcast id, a parameter cut short, an id asked twice, nothing asked.
    assert!(send(&mut s, 1, FAST_BULK_READ, &p).is_empty());
    assert!(send(&mut s, BROADCAST_ID, FAST_BULK_READ, &p[..p.len() - 1]).is_empty());
    let twice = params(&[READS[0], READS[1], READS[0]]);
    assert!(send(&mut s, BROADCAST_ID, FAST_BULK_READ, &twice).is_empty());
    assert!(send(&mut s, BROADCAST_ID, FAST_BULK_READ, &[]).is_empty());
    // A good one afterwards is answered.
    let r = send(&mut s, BROADCAST_ID, FAST_BULK_READ, &p);
    assert_eq!(r[0].bytes, assemble(&READS, &blocks()));
}

#[test]
fn wire_timing_counts_one_turnaround_and_the_one_packet() {
    let (mut s, clock) = sim_with(SimConfig {
        return_delay_us: 20,
        wire_timing: true,
        ..chain([None; 3], vec![])
    });
    let t0 = snakectl_sim::Clock::now(&clock);
    let r = send(&mut s, BROADCAST_ID, FAST_BULK_READ, &params(&READS));
    // Instruction 10 + 5 × 3 bytes, the first servo's return delay, reply 8 + (6 + 8 + 5).
    let expected = Duration::from_micros((25 + 27) * 10 + 20);
    assert_eq!(r[0].at - t0, expected);
}

#[test]
fn the_packet_comes_whole_over_the_pseudo_terminal() {
    let clock = ManualClock::new();
    let handle = spawn_pty(emanual_chain_on(&clock)).expect("pty");
    let path = handle.path().to_string_lossy().into_owned();
    let mut port: TTYPort = serialport::new(path, 1_000_000)
        .timeout(Duration::from_millis(20))
        .open_native()
        .expect("open raw port");
    let instruction =
        protocol::encode_instruction(BROADCAST_ID, FAST_BULK_READ, &params(&EMANUAL_READS));
    let (packets, replies) = send_all(&mut port, &handle, &instruction);
    assert_eq!((packets, replies), (1, 1));
    let expected = emanual_reply();
    let mut got = Vec::new();
    let deadline = Instant::now() + DEADLINE;
    let mut buf = [0u8; 64];
    while got.len() < expected.len() && Instant::now() < deadline {
        if let Ok(k) = port.read(&mut buf) {
            got.extend_from_slice(&buf[..k]);
        }
    }
    assert_eq!(got, expected);
    // Nothing follows the one packet.
    let mut rest = [0u8; 8];
    assert!(!matches!(port.read(&mut rest), Ok(k) if k > 0));
    handle.stop().expect("clean stop");
}
