//! Fast Sync Read against hand-written bytes on a pseudo-terminal: the test is the chain. A
//! reply that stops after its first block keeps that block and asks the rest by Sync Read at
//! once; a servo that then stays silent is named by a timeout, as a Sync Read names it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{Read, Write};
use std::path::PathBuf;
use std::time::Duration;

use serialport::{SerialPort, TTYPort};
use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::{Register, ServoError, SyncReadBuf};
use snakectl_sim::protocol::{self, instruction as ins, BROADCAST_ID};

/// The e-manual's Fast Sync Read example: Present Position of servos 3, 7, 4.
const INSTRUCTION: [u8; 17] = [
    0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x0A, 0x00, 0x8A, 0x84, 0x00, 0x04, 0x00, 0x03, 0x07, 0x04, 0x20,
    0xF2,
];
/// Its reply's first 16 bytes: the header and servo 3's block (166).
const FIRST_BLOCK: [u8; 16] = [
    0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00, 0x84, 0x08,
];

fn pair() -> (TTYPort, TTYPort, PathBuf) {
    let (mut master, slave) = TTYPort::pair().unwrap();
    master.set_timeout(Duration::from_secs(5)).unwrap();
    let path = PathBuf::from(slave.name().unwrap());
    (master, slave, path)
}

/// Read exactly `n` bytes the bus sent.
fn sent(master: &mut TTYPort, n: usize) -> Vec<u8> {
    let mut buf = vec![0; n];
    master.read_exact(&mut buf).unwrap();
    buf
}

fn position(out: &SyncReadBuf, i: usize) -> Option<i64> {
    out.get(i)
        .ok()
        .and_then(|(d, _)| Register::PresentPosition.decode(d))
}

/// The chain's side: answer the Fast Sync Read with its first block only, then take the Sync
/// Read of the two others and answer it for the servos in `answering`. The master end comes
/// back, to be kept open until the bus has read the replies (closing it hangs the line up).
fn chain(mut master: TTYPort, answering: &'static [(u8, u32)]) -> std::thread::JoinHandle<TTYPort> {
    std::thread::spawn(move || {
        assert_eq!(sent(&mut master, INSTRUCTION.len()), INSTRUCTION);
        master.write_all(&FIRST_BLOCK).unwrap();
        let sync = protocol::encode_instruction(
            BROADCAST_ID,
            ins::SYNC_READ,
            &[0x84, 0x00, 0x04, 0x00, 7, 4],
        );
        assert_eq!(sent(&mut master, sync.len()), sync);
        for &(id, value) in answering {
            master
                .write_all(&protocol::encode_status(id, 0, &value.to_le_bytes()))
                .unwrap();
        }
        master
    })
}

#[test]
fn a_reply_that_stops_keeps_its_blocks_and_asks_the_rest_by_sync_read() {
    let (master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 1_000_000, &Sysfs::new("/nonexistent")).unwrap();
    let chain = chain(master, &[(7, 2079), (4, 1023)]);
    let mut out = SyncReadBuf::new();
    bus.fast_sync_read_into(&[3, 7, 4], 132, 4, Duration::from_millis(500), &mut out)
        .unwrap();
    let _master = chain.join().unwrap();
    assert_eq!(
        (0..3).map(|i| position(&out, i)).collect::<Vec<_>>(),
        [Some(166), Some(2079), Some(1023)]
    );
}

#[test]
fn a_servo_silent_after_the_break_is_named_by_its_timeout() {
    let (master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 1_000_000, &Sysfs::new("/nonexistent")).unwrap();
    let chain = chain(master, &[(4, 1023)]);
    let mut out = SyncReadBuf::new();
    bus.fast_sync_read_into(&[3, 7, 4], 132, 4, Duration::from_millis(30), &mut out)
        .unwrap();
    let _master = chain.join().unwrap();
    assert_eq!(position(&out, 0), Some(166));
    assert!(
        matches!(out.get(1), Err(ServoError::Timeout { id: 7, .. })),
        "{:?}",
        out.get(1)
    );
    assert_eq!(position(&out, 2), Some(1023));
}
