//! Fast Sync Read (0x8A): the chain's one status packet, byte for byte, and what a silent,
//! damaged or too old servo does to it.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;

use std::time::Duration;

use common::*;
use snakectl_sim::protocol::{self, instruction as ins, FastBlock, BROADCAST_ID};
use snakectl_sim::table::addr;
use snakectl_sim::{Fault, Model, ServoSpec, SimConfig};

fn params(ids: &[u8]) -> Vec<u8> {
    let mut p = read_params(addr::PRESENT_POSITION, 4);
    p.extend_from_slice(ids);
    p
}

fn at(id: u8, ticks: i32) -> ServoSpec {
    let mut s = ServoSpec::new(id, Model::Xl330M288);
    s.initial_position_ticks = Some(ticks);
    s
}

fn block(id: u8, ticks: u32) -> FastBlock {
    FastBlock {
        error: 0,
        id,
        data: ticks.to_le_bytes().to_vec(),
    }
}

#[test]
fn the_emanual_example_comes_back_byte_for_byte() {
    // XC330s at 166, 2079 and 1023 in the e-manual; XL330s here (same firmware rule, same
    // Present Position).
    let (mut s, _) = sim(vec![at(3, 166), at(7, 2079), at(4, 1023)]);
    let r = send(
        &mut s,
        BROADCAST_ID,
        ins::FAST_SYNC_READ,
        &params(&[3, 7, 4]),
    );
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].id, BROADCAST_ID);
    assert_eq!(
        r[0].bytes,
        [
            0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00,
            0x84, 0x08, 0x00, 0x07, 0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, 0x00, 0x04, 0xFF, 0x03,
            0x00, 0x00, 0xD1, 0x9E
        ]
    );
}

fn config(firmware: [Option<u8>; 3], faults: Vec<Fault>) -> SimConfig {
    let servos = [1u8, 2, 3]
        .iter()
        .zip(firmware)
        .map(|(&id, fw)| {
            let mut s = at(id, 1000 * i32::from(id));
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

fn fast(config: SimConfig) -> Vec<u8> {
    let (mut s, _) = sim_with(config);
    let r = send(
        &mut s,
        BROADCAST_ID,
        ins::FAST_SYNC_READ,
        &params(&[1, 2, 3]),
    );
    assert!(r.len() <= 1);
    r.into_iter().next().map(|r| r.bytes).unwrap_or_default()
}

#[test]
fn a_silent_servo_in_the_middle_ends_the_packet_after_the_blocks_before_it() {
    let whole =
        protocol::encode_fast_status(3, 4, &[block(1, 1000), block(2, 2000), block(3, 3000)]);
    assert_eq!(fast(config([None; 3], vec![])), whole);
    let silent = fast(config(
        [None; 3],
        vec![Fault::Silent {
            id: 2,
            at: Duration::ZERO,
        }],
    ));
    assert_eq!(silent, whole[..16]);
    let dropped = fast(config(
        [None; 3],
        vec![Fault::DropReplies {
            id: Some(2),
            fraction: 1.0,
        }],
    ));
    assert_eq!(dropped, whole[..16]);
    // The first servo silent: nothing at all.
    let first = fast(config(
        [None; 3],
        vec![Fault::Silent {
            id: 1,
            at: Duration::ZERO,
        }],
    ));
    assert!(first.is_empty());
}

#[test]
fn a_servo_too_old_for_the_instruction_does_not_answer_it() {
    // XL330: Fast Sync Read from firmware 46. Servo 2 at 45 breaks the chain after servo 1.
    let bytes = fast(config([None, Some(45), Some(46)], vec![]));
    assert_eq!(bytes, protocol::encode_fast_status(3, 4, &[block(1, 1000)]));
    // It still answers a plain Sync Read, and its ping tells its firmware.
    let (mut s, _) = sim_with(config([None, Some(45), None], vec![]));
    let r = send(&mut s, BROADCAST_ID, ins::SYNC_READ, &params(&[1, 2, 3]));
    assert_eq!(r.iter().map(|r| r.id).collect::<Vec<_>>(), [1, 2, 3]);
    let ping = send(&mut s, 2, ins::PING, &[]);
    assert_eq!(decode(&ping[0]).data, [0xB0, 0x04, 45]);
}

#[test]
fn a_corrupted_block_fails_the_running_crc_from_there_on() {
    let whole =
        protocol::encode_fast_status(3, 4, &[block(1, 1000), block(2, 2000), block(3, 3000)]);
    let bytes = fast(config(
        [None; 3],
        vec![Fault::CorruptReplies {
            id: Some(2),
            fraction: 1.0,
        }],
    ));
    // Block 2 spans bytes 16..24: block 1's CRC still checks; block 2's (the running CRC
    // through it) does not.
    assert_one_block_corrupted(&bytes, &whole, 16..24);
}

#[test]
fn wire_timing_counts_one_turnaround_and_the_shorter_packet() {
    for n in [1u8, 4, 12] {
        let ids: Vec<u8> = (1..=n).collect();
        let (mut s, clock) = sim_with(SimConfig {
            servos: xl430(&ids),
            baud: 1_000_000,
            return_delay_us: 20,
            wire_timing: true,
            ..SimConfig::default()
        });
        let t0 = snakectl_sim::Clock::now(&clock);
        let r = send(&mut s, BROADCAST_ID, ins::FAST_SYNC_READ, &params(&ids));
        let n = usize::from(n);
        // Instruction 14 + n bytes, one return delay, reply 8 + n × 8 bytes.
        let expected = Duration::from_micros((14 + n + 8 + 8 * n) as u64 * 10 + 20);
        assert_eq!(r[0].at - t0, expected, "n = {n}");
    }
}
