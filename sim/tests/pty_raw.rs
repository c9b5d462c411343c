//! A raw serial port on the pseudo-terminal: a multi-servo bulk read (which dynamixel2 0.9.1
//! encodes wrongly), malformed packets, garbage and bad CRCs.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::Read;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::hex;
use serialport::TTYPort;
use snakectl_sim::protocol::{self, error, instruction as ins, Frame, Packet, Parser};
use snakectl_sim::{spawn_pty, ManualClock, Model, ServoSpec, SimConfig, SimHandle, Simulator};

fn serve(ids: &[u8]) -> (SimHandle, ManualClock) {
    let clock = ManualClock::new();
    let config = SimConfig {
        servos: ids
            .iter()
            .map(|&id| ServoSpec::new(id, Model::Xm430W350))
            .collect(),
        ..SimConfig::default()
    };
    let sim = Simulator::new(config, Arc::new(clock.clone())).expect("config");
    (spawn_pty(sim).expect("pty"), clock)
}

fn open(handle: &SimHandle) -> TTYPort {
    let path = handle.path().to_string_lossy().into_owned();
    serialport::new(path, 1_000_000)
        .timeout(Duration::from_millis(20))
        .open_native()
        .expect("open raw port")
}

use common::DEADLINE;

/// Status packets arriving until `n` have come or `window` has passed.
fn collect_n(port: &mut TTYPort, n: usize, window: Duration) -> Vec<Packet> {
    let deadline = Instant::now() + window;
    let mut parser = Parser::default();
    let mut out = Vec::new();
    let mut buf = [0u8; 512];
    while Instant::now() < deadline && out.len() < n {
        if let Ok(k) = port.read(&mut buf) {
            for p in parser.feed(&buf[..k], Instant::now()) {
                match p.frame {
                    Frame::Packet(packet) => out.push(packet),
                    other => panic!("bad frame from the simulator: {other:?}"),
                }
            }
        }
    }
    out
}

/// Wait (generously: the machine may be busy) for exactly `n` replies.
fn expect(port: &mut TTYPort, n: usize) -> Vec<Packet> {
    let r = collect_n(port, n, DEADLINE);
    assert_eq!(r.len(), n, "{r:?}");
    r
}

/// Write `bytes` and wait until the simulator has taken all of them; returns how many replies
/// they produced.
fn send(port: &mut TTYPort, handle: &SimHandle, bytes: &[u8]) -> u64 {
    common::send_all(port, handle, bytes).1
}

#[test]
fn bulk_read_of_several_servos_in_instruction_order() {
    let (handle, _clock) = serve(&[1, 2, 3]);
    let mut port = open(&handle);
    // Id 3: Present Position (4 bytes); id 1: Model Number (2); id 2: Present Temperature (1).
    let params = [3, 132, 0, 4, 0, 1, 0, 0, 2, 0, 2, 146, 0, 1, 0];
    let n = send(
        &mut port,
        &handle,
        &protocol::encode_instruction(0xFE, ins::BULK_READ, &params),
    );
    assert_eq!(n, 3);
    let replies = expect(&mut port, 3);
    let got: Vec<(u8, Vec<u8>)> = replies.iter().map(|p| (p.id, p.params.clone())).collect();
    assert_eq!(
        got,
        [
            (3, vec![0, 0x00, 0x08, 0, 0]),
            (1, vec![0, 0xFC, 0x03]),
            (2, vec![0, 30]),
        ]
    );
}

#[test]
fn malformed_packets() {
    let (handle, clock) = serve(&[1, 2]);
    let mut port = open(&handle);
    let ping = protocol::encode_instruction(1, ins::PING, &[]);

    // Garbage before a packet is skipped.
    let mut bytes = hex("00 13 FF FF 42 FF FD");
    bytes.extend_from_slice(&ping);
    assert_eq!(send(&mut port, &handle, &bytes), 1);
    let r = expect(&mut port, 1);
    assert_eq!(r[0].params[0], error::NONE);

    // A bad CRC is never acted on: the addressed servo answers with the CRC error.
    let mut bad = protocol::encode_instruction(1, ins::WRITE, &[65, 0, 1]);
    let n = bad.len();
    bad[n - 1] ^= 0x55;
    assert_eq!(send(&mut port, &handle, &bad), 1);
    let r = expect(&mut port, 1);
    assert_eq!((r[0].id, r[0].params.as_slice()), (1, &[error::CRC][..]));
    assert_eq!(handle.with_servo(1, |s| s.value(65)), Some(Some(0)));
    // Broadcast with a bad CRC: nobody answers.
    let mut bad = protocol::encode_instruction(0xFE, ins::PING, &[]);
    bad[8] ^= 1;
    assert_eq!(send(&mut port, &handle, &bad), 0);

    // A packet cut short and immediately followed by another: the second one is recovered.
    let read = protocol::encode_instruction(2, ins::READ, &[132, 0, 4, 0]);
    let mut bytes = read[..9].to_vec();
    bytes.extend_from_slice(&ping);
    assert_eq!(
        send(&mut port, &handle, &bytes),
        1,
        "only the ping is answered"
    );
    let r = expect(&mut port, 1);
    assert_eq!(r[0].id, 1);

    // A packet cut short, then silence longer than the inter-byte timeout: it is dropped.
    // The simulator has the first bytes before the clock moves, so the gap is seen.
    assert_eq!(send(&mut port, &handle, &read[..6]), 0);
    clock.advance(Duration::from_millis(100));
    assert_eq!(send(&mut port, &handle, &ping), 1);
    assert_eq!(
        expect(&mut port, 1)[0].params,
        [error::NONE, 0xFC, 0x03, 48]
    );

    // An absurd length field, an unknown instruction, a sync read not sent to broadcast.
    assert_eq!(send(&mut port, &handle, &hex("FF FF FD 00 01 FF FF 02")), 0);
    assert_eq!(send(&mut port, &handle, &ping), 1);
    expect(&mut port, 1);
    assert_eq!(
        send(
            &mut port,
            &handle,
            &protocol::encode_instruction(2, 0x77, &[1, 2])
        ),
        1
    );
    let r = expect(&mut port, 1);
    assert_eq!(r[0].params, [error::INSTRUCTION]);
    let unicast_sync_read = protocol::encode_instruction(1, ins::SYNC_READ, &[132, 0, 4, 0, 1]);
    assert_eq!(send(&mut port, &handle, &unicast_sync_read), 0);
    // Status packets on the bus (another device's replies) are ignored.
    assert_eq!(
        send(&mut port, &handle, &protocol::encode_status(1, 0, &[])),
        0
    );
    // Every reply was counted and read: nothing else is on its way.
    assert_eq!(send(&mut port, &handle, &ping), 1);
    assert_eq!(expect(&mut port, 1)[0].id, 1);
}
