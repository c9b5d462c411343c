//! Replies against hand-written bytes on a pseudo-terminal: the test is the chain.
//!
//! - Fast Sync Read: a reply that stops after its first block keeps that block and asks the
//!   rest by Sync Read at once; a servo that then stays silent is named by a timeout, as a Sync
//!   Read names it; after a damaged block the Sync Read waits until the rest of the reply is
//!   through.
//! - Behind an adapter the bus was told of (a simulated FTDI chip's 16 ms latency timer), a
//!   reply that pauses while the chip holds its last partial USB packet is waited for, not
//!   taken for a chain that broke and asked again.
//! - Status packets damaged on the way (a length field that lies, too short or too long) cost
//!   one reading, never the replies behind them or a panic, and a scan still ends.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{Read, Write};
use std::path::PathBuf;
use std::time::Duration;

use serialport::{SerialPort, TTYPort};
use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::wire::Adapter;
use snakectl::servo::{Register, ServoBus, ServoError, SyncReadBuf};
use snakectl_sim::protocol::{self, instruction as ins, FastBlock, BROADCAST_ID};

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

/// An FTDI chip hands a reply's full USB packets on as they fill and holds the last partial
/// one for its latency timer: the chain here sends the first block, then, after a pause longer
/// than a bare chain's [`FAST_STALL`](snakectl::servo::dynamixel::FAST_STALL) but well inside
/// the 16 ms timer the bus was told of, the rest. The read keeps every block and sends nothing
/// more (before the bus heeded its adapter, it gave up at the pause and asked servos 7 and 4
/// again with a Sync Read, which nobody answers here).
#[test]
fn a_reply_held_by_the_adapter_s_latency_timer_is_waited_for_not_asked_again() {
    let (mut master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 1_000_000, &Sysfs::new("/nonexistent")).unwrap();
    assert_eq!(bus.adapters(), [None]);
    let ftdi = Adapter::ftdi(Duration::from_millis(16));
    bus.assume_adapter(ftdi);
    assert_eq!(bus.adapters(), [Some(ftdi)]);
    let blocks: Vec<FastBlock> = [(3u8, 166u32), (7, 2079), (4, 1023)]
        .iter()
        .map(|&(id, value)| FastBlock {
            error: 0,
            id,
            data: value.to_le_bytes().to_vec(),
        })
        .collect();
    let reply = protocol::encode_fast_status(3, 4, &blocks);
    assert_eq!(reply[..FIRST_BLOCK.len()], FIRST_BLOCK);
    let chain = std::thread::spawn(move || {
        assert_eq!(sent(&mut master, INSTRUCTION.len()), INSTRUCTION);
        master.write_all(&FIRST_BLOCK).unwrap();
        std::thread::sleep(Duration::from_millis(6));
        master.write_all(&reply[FIRST_BLOCK.len()..]).unwrap();
        master
    });
    let mut out = SyncReadBuf::new();
    bus.fast_sync_read_into(&[3, 7, 4], 132, 4, Duration::from_millis(100), &mut out)
        .unwrap();
    let master = chain.join().unwrap();
    assert_eq!(
        (0..3).map(|i| position(&out, i)).collect::<Vec<_>>(),
        [Some(166), Some(2079), Some(1023)]
    );
    assert_eq!(master.bytes_to_read().unwrap(), 0, "the bus asked again");
}

/// A Sync Read of Present Position from servos 3, 7 and 4 whose replies come as `first` (what
/// stands for servo 3's) followed by servo 7's (2079) and servo 4's (1023), intact.
fn sync_read_after(first: Vec<u8>) -> SyncReadBuf {
    let (mut master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 1_000_000, &Sysfs::new("/nonexistent")).unwrap();
    let chain = std::thread::spawn(move || {
        let sync = protocol::encode_instruction(
            BROADCAST_ID,
            ins::SYNC_READ,
            &[0x84, 0x00, 0x04, 0x00, 3, 7, 4],
        );
        assert_eq!(sent(&mut master, sync.len()), sync);
        let mut bytes = first;
        for (id, value) in [(7u8, 2079u32), (4, 1023)] {
            bytes.extend_from_slice(&protocol::encode_status(id, 0, &value.to_le_bytes()));
        }
        master.write_all(&bytes).unwrap();
        master
    });
    let mut out = SyncReadBuf::new();
    bus.plain_sync_read_into(&[3, 7, 4], 132, 4, Duration::from_millis(30), &mut out)
        .unwrap();
    let _master = chain.join().unwrap();
    out
}

/// A status packet whose length field lies (2: no error byte, no data) and whose CRC, where the
/// instruction and error bytes would sit, matches its first 7 bytes (a chance of 1 in 65536 on
/// a noisy line, certain here): the Sync Read counts it against the first servo not yet heard
/// from and reads the others; it must not panic.
#[test]
fn a_status_packet_whose_length_field_is_too_short_costs_one_reading_not_a_panic() {
    let mut lying = vec![0xFF, 0xFF, 0xFD, 0x00, 3, 0x02, 0x00];
    let crc = protocol::crc16(&lying);
    lying.extend_from_slice(&crc.to_le_bytes());
    let out = sync_read_after(lying);
    assert!(out.get(0).is_err(), "{:?}", out.get(0));
    assert_eq!(position(&out, 1), Some(2079));
    assert_eq!(position(&out, 2), Some(1023));
}

/// A reply whose length field was damaged upwards past what the read buffer holds (0x0008 to
/// 0x1008): that reply is lost, the two intact replies after it must still be read.
#[test]
fn a_length_field_damaged_past_the_buffer_costs_one_reading_not_all() {
    let mut damaged = protocol::encode_status(3, 0, &166u32.to_le_bytes());
    damaged[6] ^= 0x10;
    let out = sync_read_after(damaged);
    assert!(out.get(0).is_err());
    assert_eq!(position(&out, 1), Some(2079), "{:?}", out.get(1));
    assert_eq!(position(&out, 2), Some(1023), "{:?}", out.get(2));
}

/// A reply whose length field was damaged upwards but within what a read holds (0x0008 to
/// 0x0108): it would swallow the replies behind it; once its wait is over it is given up and
/// the two intact replies after it are read.
#[test]
fn a_length_field_damaged_upwards_is_given_up_and_the_replies_behind_it_read() {
    let mut damaged = protocol::encode_status(3, 0, &166u32.to_le_bytes());
    damaged[6] ^= 0x01;
    let out = sync_read_after(damaged);
    assert!(out.get(0).is_err());
    assert_eq!(position(&out, 1), Some(2079), "{:?}", out.get(1));
    assert_eq!(position(&out, 2), Some(1023), "{:?}", out.get(2));
}

/// A block that fails its CRC at 57600 baud: the chain does not know and goes on sending the
/// two blocks after it (16 bytes, 2.78 ms on the wire), so the Sync Read that asks those
/// servos again must not leave before they are through (on a half-duplex bus it would collide
/// with them).
#[test]
fn the_sync_read_after_a_damaged_block_waits_for_the_rest_of_the_reply() {
    let (mut master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 57_600, &Sysfs::new("/nonexistent")).unwrap();
    let chain = std::thread::spawn(move || {
        assert_eq!(sent(&mut master, INSTRUCTION.len()), INSTRUCTION);
        let mut block = FIRST_BLOCK;
        block[10] ^= 0x10;
        master.write_all(&block).unwrap();
        let at = std::time::Instant::now();
        let sync = protocol::encode_instruction(
            BROADCAST_ID,
            ins::SYNC_READ,
            &[0x84, 0x00, 0x04, 0x00, 7, 4],
        );
        assert_eq!(sent(&mut master, sync.len()), sync);
        let gap = at.elapsed();
        for (id, value) in [(7u8, 2079u32), (4, 1023)] {
            master
                .write_all(&protocol::encode_status(id, 0, &value.to_le_bytes()))
                .unwrap();
        }
        (master, gap)
    });
    let mut out = SyncReadBuf::new();
    bus.fast_sync_read_into(&[3, 7, 4], 132, 4, Duration::from_millis(200), &mut out)
        .unwrap();
    let (_master, gap) = chain.join().unwrap();
    assert!(matches!(
        out.get(0),
        Err(ServoError::Checksum { id: 3, .. })
    ));
    assert_eq!(position(&out, 1), Some(2079));
    assert_eq!(position(&out, 2), Some(1023));
    let rest = Duration::from_nanos(16 * 10 * 1_000_000_000 / 57_600);
    assert!(gap >= rest, "the Sync Read left {gap:?} after the damaged block, before the {rest:?} the rest of the reply takes");
}

/// A broadcast ping answered by a reply whose length field was damaged past the read buffer
/// (0x0007 to 0x1007): the scan must still end once its window is over.
#[test]
fn a_scan_ends_after_a_reply_whose_length_field_is_damaged() {
    use snakectl::servo::ServoBus;
    let (mut master, _slave, path) = pair();
    let mut bus =
        DynamixelBus::open_with_sysfs(&path, 1_000_000, &Sysfs::new("/nonexistent")).unwrap();
    let chain = std::thread::spawn(move || {
        let ping = protocol::encode_instruction(BROADCAST_ID, ins::PING, &[]);
        assert_eq!(sent(&mut master, ping.len()), ping);
        let mut bytes = protocol::encode_status(3, 0, &[0x24, 0x04, 48]);
        bytes[6] ^= 0x10;
        bytes.extend_from_slice(&protocol::encode_status(5, 0, &[0x24, 0x04, 48]));
        master.write_all(&bytes).unwrap();
        master
    });
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let found = bus.scan(Duration::from_millis(30));
        let _ = tx.send(found.map(|f| f.len()));
    });
    let _master = chain.join().unwrap();
    let found = rx.recv_timeout(Duration::from_secs(3));
    assert!(found.is_ok(), "the scan did not end: {found:?}");
}
