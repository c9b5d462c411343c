//! Byte-exact checks against the example packets of the ROBOTIS e-manual (Protocol 2.0 page):
//! the encoder reproduces them, and the simulator answers the example instructions with the
//! example status packets wherever the servo state can be made the same.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::*;
use snakectl_sim::protocol::{self, crc16, instruction as ins, Frame, Parser};
use snakectl_sim::{Model, ServoSpec};
use std::time::Instant;

/// (description, id, instruction, params, bytes on the wire).
const INSTRUCTIONS: &[(&str, u8, u8, &[u8], &str)] = &[
    (
        "ping id 1",
        1,
        ins::PING,
        &[],
        "FF FF FD 00 01 03 00 01 19 4E",
    ),
    (
        "broadcast ping",
        0xFE,
        ins::PING,
        &[],
        "FF FF FD 00 FE 03 00 01 31 42",
    ),
    (
        "read present position",
        1,
        ins::READ,
        &[0x84, 0x00, 0x04, 0x00],
        "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    ),
    (
        "write goal position 512",
        1,
        ins::WRITE,
        &[0x74, 0x00, 0x00, 0x02, 0x00, 0x00],
        "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    ),
    (
        "reg write goal velocity 200",
        1,
        ins::REG_WRITE,
        &[0x68, 0x00, 0xC8, 0x00, 0x00, 0x00],
        "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E",
    ),
    (
        "action",
        1,
        ins::ACTION,
        &[],
        "FF FF FD 00 01 03 00 05 02 CE",
    ),
    (
        "factory reset except id",
        1,
        ins::FACTORY_RESET,
        &[0x01],
        "FF FF FD 00 01 04 00 06 01 A1 E6",
    ),
    (
        "reboot",
        1,
        ins::REBOOT,
        &[],
        "FF FF FD 00 01 03 00 08 2F 4E",
    ),
    (
        "clear multi-turn",
        1,
        ins::CLEAR,
        &[0x01, 0x44, 0x58, 0x4C, 0x22],
        "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC",
    ),
    (
        "control table backup",
        1,
        ins::CONTROL_TABLE_BACKUP,
        &[0x01, 0x43, 0x54, 0x52, 0x4C],
        "FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5",
    ),
    (
        "sync read present position of 1, 2",
        0xFE,
        ins::SYNC_READ,
        &[0x84, 0x00, 0x04, 0x00, 0x01, 0x02],
        "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
    ),
    (
        "sync write goal position 150, 170",
        0xFE,
        ins::SYNC_WRITE,
        &[
            0x74, 0x00, 0x04, 0x00, 0x01, 0x96, 0x00, 0x00, 0x00, 0x02, 0xAA, 0x00, 0x00, 0x00,
        ],
        "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
    ),
    (
        "bulk read voltage of 1, temperature of 2",
        0xFE,
        ins::BULK_READ,
        &[0x01, 0x90, 0x00, 0x02, 0x00, 0x02, 0x92, 0x00, 0x01, 0x00],
        "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05",
    ),
    (
        "bulk write max voltage of 1, temperature limit of 2",
        0xFE,
        ins::BULK_WRITE,
        &[
            0x01, 0x20, 0x00, 0x02, 0x00, 0xA0, 0x00, 0x02, 0x1F, 0x00, 0x01, 0x00, 0x50,
        ],
        "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
    ),
];

/// (description, id, error, params, bytes on the wire).
const STATUSES: &[(&str, u8, u8, &[u8], &str)] = &[
    (
        "ping reply: model 1030, firmware 38",
        1,
        0,
        &[0x06, 0x04, 0x26],
        "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D",
    ),
    (
        "ping reply of id 2",
        2,
        0,
        &[0x06, 0x04, 0x26],
        "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D",
    ),
    (
        "read reply: 166",
        1,
        0,
        &[0xA6, 0x00, 0x00, 0x00],
        "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0",
    ),
    (
        "sync read reply of id 2: 2079",
        2,
        0,
        &[0x1F, 0x08, 0x00, 0x00],
        "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE",
    ),
    (
        "write/action/reboot reply",
        1,
        0,
        &[],
        "FF FF FD 00 01 04 00 55 00 A1 0C",
    ),
    (
        "bulk read reply of id 1: 11.9 V",
        1,
        0,
        &[0x77, 0x00],
        "FF FF FD 00 01 06 00 55 00 77 00 C3 69",
    ),
];

#[test]
fn encoder_reproduces_instruction_examples() {
    for (what, id, instruction, params, wire) in INSTRUCTIONS {
        assert_eq!(
            protocol::encode_instruction(*id, *instruction, params),
            hex(wire),
            "{what}"
        );
    }
}

#[test]
fn encoder_reproduces_status_examples() {
    for (what, id, error, params, wire) in STATUSES {
        assert_eq!(
            protocol::encode_status(*id, *error, params),
            hex(wire),
            "{what}"
        );
    }
}

#[test]
fn crc_matches_every_example() {
    for wire in INSTRUCTIONS
        .iter()
        .map(|e| e.4)
        .chain(STATUSES.iter().map(|e| e.4))
    {
        let bytes = hex(wire);
        let n = bytes.len();
        assert_eq!(
            crc16(&bytes[..n - 2]).to_le_bytes(),
            [bytes[n - 2], bytes[n - 1]],
            "{wire}"
        );
    }
}

#[test]
fn parser_decodes_every_example() {
    for (what, id, instruction, params, wire) in INSTRUCTIONS {
        let frames = Parser::default().feed(&hex(wire), Instant::now());
        assert_eq!(frames.len(), 1, "{what}");
        match &frames[0].frame {
            Frame::Packet(p) => {
                assert_eq!(
                    (p.id, p.instruction, p.params.as_slice()),
                    (*id, *instruction, *params),
                    "{what}"
                )
            }
            other => panic!("{what}: {other:?}"),
        }
    }
}

#[test]
fn stuffed_packet_example() {
    // Writing FF FF FD to three consecutive bytes: the body is stuffed, the length counts the
    // stuffing byte, and the CRC covers the stuffed bytes.
    let bytes = protocol::encode_instruction(1, ins::WRITE, &[0xE0, 0x00, 0xFF, 0xFF, 0xFD]);
    assert_eq!(&bytes[..8], &hex("FF FF FD 00 01 09 00 03"));
    assert_eq!(&bytes[8..14], &hex("E0 00 FF FF FD FD"));
    let frames = Parser::default().feed(&bytes, Instant::now());
    match &frames[0].frame {
        Frame::Packet(p) => assert_eq!(p.params, vec![0xE0, 0x00, 0xFF, 0xFF, 0xFD]),
        other => panic!("{other:?}"),
    }
}

fn two_servos() -> (snakectl_sim::Simulator, snakectl_sim::ManualClock) {
    let mut a = ServoSpec::new(1, Model::Xm430W350);
    a.initial_position_ticks = Some(166);
    let mut b = ServoSpec::new(2, Model::Xl430W250);
    b.initial_position_ticks = Some(2079);
    sim(vec![a, b])
}

fn wire_of(what: &str) -> Vec<u8> {
    INSTRUCTIONS
        .iter()
        .chain(std::iter::empty())
        .find(|e| e.0 == what)
        .map(|e| hex(e.4))
        .unwrap_or_else(|| panic!("no example {what}"))
}

fn status_of(what: &str) -> Vec<u8> {
    STATUSES
        .iter()
        .find(|e| e.0 == what)
        .map(|e| hex(e.4))
        .unwrap_or_else(|| panic!("no example {what}"))
}

#[test]
fn simulator_answers_examples_byte_for_byte() {
    let (mut s, clock) = two_servos();
    let ok = status_of("write/action/reboot reply");

    let r = s.handle_bytes(&wire_of("read present position"));
    assert_eq!(r[0].bytes, status_of("read reply: 166"));

    let r = s.handle_bytes(&wire_of("sync read present position of 1, 2"));
    assert_eq!(r.len(), 2);
    assert_eq!(r[0].bytes, status_of("read reply: 166"));
    assert_eq!(r[1].bytes, status_of("sync read reply of id 2: 2079"));

    for what in [
        "write goal position 512",
        "reg write goal velocity 200",
        "action",
        "clear multi-turn",
        "reboot",
    ] {
        let r = s.handle_bytes(&wire_of(what));
        assert_eq!(r.len(), 1, "{what}");
        assert_eq!(r[0].bytes, ok, "{what}");
    }
    // Servo 1 boots after the reboot before it answers again.
    clock.advance(snakectl_sim::DEFAULT_BOOT_TIME);

    // Ping: same framing, the simulated model's number and firmware.
    let r = s.handle_bytes(&wire_of("ping id 1"));
    assert_eq!(r[0].bytes, protocol::encode_status(1, 0, &[0xFC, 0x03, 48]));
    let r = s.handle_bytes(&wire_of("broadcast ping"));
    let ids: Vec<u8> = r.iter().map(|r| r.id).collect();
    assert_eq!(ids, [1, 2]);

    // Factory reset "all but the id" answers, then restores the factory baud rate (57600): like
    // a real servo it no longer hears a 1 Mbps bus.
    let r = s.handle_bytes(&wire_of("factory reset except id"));
    assert_eq!(r[0].bytes, ok);
    assert_eq!(s.servo(1).map(|x| x.baud_index()), Some(1));
    clock.advance(snakectl_sim::DEFAULT_BOOT_TIME);
    assert!(s.handle_bytes(&wire_of("ping id 1")).is_empty());
}

#[test]
fn simulator_executes_sync_and_bulk_write_examples() {
    let (mut s, _clock) = two_servos();
    assert!(s
        .handle_bytes(&wire_of("sync write goal position 150, 170"))
        .is_empty());
    assert_eq!(s.servo(1).map(|x| x.goal_position()), Some(150));
    assert_eq!(s.servo(2).map(|x| x.goal_position()), Some(170));

    assert!(s
        .handle_bytes(&wire_of(
            "bulk write max voltage of 1, temperature limit of 2"
        ))
        .is_empty());
    assert_eq!(s.servo(1).and_then(|x| x.value(32)), Some(160));
    assert_eq!(s.servo(2).and_then(|x| x.value(31)), Some(80));

    // Bulk read: 11.9 V on id 1, 36 °C on id 2, replies in instruction order.
    s.servo_mut(1).expect("id 1").set_input_voltage(119.0);
    s.servo_mut(2).expect("id 2").set_temperature(36.0);
    let r = s.handle_bytes(&wire_of("bulk read voltage of 1, temperature of 2"));
    assert_eq!(r.len(), 2);
    assert_eq!(r[0].bytes, status_of("bulk read reply of id 1: 11.9 V"));
    assert_eq!(r[1].bytes, protocol::encode_status(2, 0, &[0x24]));
    assert_eq!(&r[1].bytes[..10], &hex("FF FF FD 00 02 05 00 55 00 24"));
}

#[test]
fn simulator_answers_the_control_table_backup_examples() {
    // The e-manual's Control Table Backup (0x20) examples: store, then restore (the servo
    // answers, then reboots with its EEPROM from the backup). The restore example is printed
    // with the CRC 92 F5 where its bytes' CRC is 9E F5: as printed it fails its CRC.
    let (mut s, clock) = two_servos();
    let ok = status_of("write/action/reboot reply");
    let r = s.handle_bytes(&wire_of("control table backup"));
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].bytes, ok);
    let printed = hex("FF FF FD 00 01 08 00 20 02 43 54 52 4C 92 F5");
    let r = s.handle_bytes(&printed);
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].bytes, protocol::encode_status(1, 0x03, &[]));
    let restore = hex("FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5");
    let r = s.handle_bytes(&restore);
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].bytes, ok);
    assert!(
        s.handle_bytes(&wire_of("ping id 1")).is_empty(),
        "rebooting"
    );
    clock.advance(snakectl_sim::DEFAULT_BOOT_TIME);
    assert_eq!(s.handle_bytes(&wire_of("ping id 1")).len(), 1);
}
