//! The client's baud rate on the pseudo-terminal: servos hear and answer only when it equals
//! their Baud Rate register, as on a real bus.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{Read, Write};
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

/// Ids of the servos answering a broadcast ping, until `n` have or `window` has passed.
fn ping_all(port: &mut TTYPort, n: usize, window: Duration) -> Vec<u8> {
    port.write_all(&protocol::encode_instruction(
        protocol::BROADCAST_ID,
        ins::PING,
        &[],
    ))
    .expect("send");
    let deadline = Instant::now() + window;
    let mut parser = Parser::default();
    let mut ids = Vec::new();
    let mut buf = [0u8; 512];
    while Instant::now() < deadline && ids.len() < n {
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

/// Generous for an answer (the machine may be busy); a silence is awaited for less.
const ANSWER: Duration = Duration::from_secs(1);
const SILENCE: Duration = Duration::from_millis(60);

#[test]
fn servos_answer_only_at_their_rate() {
    let handle = serve(1_000_000);
    let mut port = open(&handle, 57_600);
    assert_eq!(ping_all(&mut port, 1, SILENCE), Vec::<u8>::new());
    // The simulator read the rate the client set on the terminal.
    assert_eq!(handle.with_sim(|s| s.line_baud()), 57_600);
    port.set_baud_rate(1_000_000).expect("set baud");
    assert_eq!(ping_all(&mut port, 3, ANSWER), [1, 2, 3]);
    assert_eq!(handle.with_sim(|s| s.line_baud()), 1_000_000);
    // A rate that is no Dynamixel rate at all: nobody hears.
    port.set_baud_rate(38_400).expect("set baud");
    assert_eq!(ping_all(&mut port, 1, SILENCE), Vec::<u8>::new());
}

#[test]
fn a_non_standard_termios_rate_is_read_exactly() {
    // 4.5 Mbps has no B-constant: the client sets it through BOTHER.
    let handle = serve(4_500_000);
    let mut port = open(&handle, 4_500_000);
    assert_eq!(ping_all(&mut port, 3, ANSWER), [1, 2, 3]);
    assert_eq!(handle.with_sim(|s| s.line_baud()), 4_500_000);
    port.set_baud_rate(4_000_000).expect("set baud");
    assert_eq!(ping_all(&mut port, 1, SILENCE), Vec::<u8>::new());
}

#[test]
fn a_servo_moved_to_another_rate_answers_there_only() {
    let handle = serve(1_000_000);
    let mut port = open(&handle, 1_000_000);
    // Baud Rate 1 = 57600, written with torque off (EEPROM).
    port.write_all(&protocol::encode_instruction(
        2,
        ins::WRITE,
        &[addr::BAUD_RATE as u8, 0, 1],
    ))
    .expect("send");
    // The acknowledgement may or may not come; wait until the register took the value.
    let deadline = Instant::now() + ANSWER;
    while handle.with_servo(2, |s| s.baud_index()) != Some(1) && Instant::now() < deadline {
        let _ = port.read(&mut [0u8; 64]);
    }
    let _ = port.clear(serialport::ClearBuffer::Input);
    assert_eq!(ping_all(&mut port, 2, ANSWER), [1, 3]);
    port.set_baud_rate(57_600).expect("set baud");
    assert_eq!(ping_all(&mut port, 1, ANSWER), [2]);
}
