//! The client's baud rate on the pseudo-terminal: servos hear and answer only when it equals
//! their Baud Rate register, as on a real bus.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::Read;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use snakectl_sim::protocol::{self, instruction as ins, Frame, Parser};
use snakectl_sim::table::addr;
use snakectl_sim::{spawn_pty, ManualClock, Model, ServoSpec, SimConfig, SimHandle, Simulator};

fn serve(baud: u32) -> SimHandle {
    let config = SimConfig {
        servos: (1..=3)
            .map(|id| ServoSpec::new(id, Model::Xl430W250))
            .collect(),
        baud,
        ..SimConfig::default()
    };
    spawn_pty(Simulator::new(config, Arc::new(ManualClock::new())).expect("config")).expect("pty")
}

fn open(handle: &SimHandle, baud: u32) -> TTYPort {
    serialport::new(handle.path().to_string_lossy(), baud)
        .timeout(Duration::from_millis(20))
        .open_native()
        .expect("open raw port")
}

use common::DEADLINE;

use common::send_all as send;

fn broadcast_ping() -> Vec<u8> {
    protocol::encode_instruction(protocol::BROADCAST_ID, ins::PING, &[])
}

/// Ids of the servos answering a broadcast ping, in the order they answer; as many as the
/// simulator made replies, each awaited with a generous deadline.
fn ping_all(port: &mut TTYPort, handle: &SimHandle) -> Vec<u8> {
    let (packets, n) = send(port, handle, &broadcast_ping());
    assert_eq!(packets, 1, "the simulator parsed the ping");
    read_ids(port, n as usize)
}

/// The ids of the next `n` status packets on the port.
fn read_ids(port: &mut TTYPort, n: usize) -> Vec<u8> {
    let deadline = Instant::now() + DEADLINE;
    let mut parser = Parser::default();
    let mut ids = Vec::new();
    let mut buf = [0u8; 512];
    while ids.len() < n {
        assert!(
            Instant::now() < deadline,
            "{} of {n} replies came",
            ids.len()
        );
        if let Ok(k) = port.read(&mut buf) {
            for p in parser.feed(&buf[..k], Instant::now()) {
                if let Frame::Packet(packet) = p.frame {
                    ids.push(packet.id);
                }
            }
        }
    }
    ids
}

#[test]
fn servos_answer_only_at_their_rate() {
    let handle = serve(1_000_000);
    let mut port = open(&handle, 57_600);
    assert_eq!(ping_all(&mut port, &handle), Vec::<u8>::new());
    // The simulator read the rate the client set on the terminal.
    assert_eq!(handle.with_sim(|s| s.line_baud()), 57_600);
    port.set_baud_rate(1_000_000).expect("set baud");
    assert_eq!(ping_all(&mut port, &handle), [1, 2, 3]);
    assert_eq!(handle.with_sim(|s| s.line_baud()), 1_000_000);
    // A rate that is no Dynamixel rate at all: nobody hears.
    port.set_baud_rate(38_400).expect("set baud");
    assert_eq!(ping_all(&mut port, &handle), Vec::<u8>::new());
}

#[test]
fn a_non_standard_termios_rate_is_read_exactly() {
    // 4.5 Mbps has no B-constant: the client sets it through BOTHER.
    let handle = serve(4_500_000);
    let mut port = open(&handle, 4_500_000);
    assert_eq!(ping_all(&mut port, &handle), [1, 2, 3]);
    assert_eq!(handle.with_sim(|s| s.line_baud()), 4_500_000);
    port.set_baud_rate(4_000_000).expect("set baud");
    assert_eq!(ping_all(&mut port, &handle), Vec::<u8>::new());
}

#[test]
fn a_servo_moved_to_another_rate_answers_there_only() {
    let handle = serve(1_000_000);
    let mut port = open(&handle, 1_000_000);
    // Baud Rate 1 = 57600, written with torque off (EEPROM).
    let write = protocol::encode_instruction(2, ins::WRITE, &[addr::BAUD_RATE as u8, 0, 1]);
    let (_, acks) = send(&mut port, &handle, &write);
    assert_eq!(handle.with_servo(2, |s| s.baud_index()), Some(1));
    // Whether the acknowledgement comes is not the point here; read it if it was made, so it
    // is not taken for an answer to the pings below.
    assert_eq!(read_ids(&mut port, acks as usize), vec![2; acks as usize]);
    assert_eq!(ping_all(&mut port, &handle), [1, 3]);
    port.set_baud_rate(57_600).expect("set baud");
    assert_eq!(ping_all(&mut port, &handle), [2]);
}
