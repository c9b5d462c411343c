//! `snakectl sim` as a user runs it: it prints the pseudo-terminal, links it, answers Protocol
//! 2.0 there (also after the client closes and reopens the port), and stops cleanly on SIGTERM.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use snakectl_sim::protocol;

/// Sends a ping to `id` and returns the raw status packet.
fn ping(port: &Path, id: u8) -> Vec<u8> {
    let mut p = serialport::new(port.to_str().unwrap(), 1_000_000)
        .timeout(Duration::from_millis(200))
        .open()
        .unwrap();
    p.write_all(&protocol::encode_instruction(
        id,
        protocol::instruction::PING,
        &[],
    ))
    .unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 64];
    let deadline = Instant::now() + Duration::from_millis(500);
    // A ping status is 14 bytes: header 4, id, length 2, 0x55, error, model 2, firmware, CRC 2.
    while got.len() < 14 && Instant::now() < deadline {
        if let Ok(k) = p.read(&mut buf) {
            got.extend_from_slice(&buf[..k]);
        }
    }
    got
}

#[test]
fn sim_serves_the_config_chain_on_a_linked_pty_and_stops_on_sigterm() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("snake-bus");
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config", "config/sim.toml", "--link"])
        .arg(&link)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let pty = line.trim().to_string();
    assert!(pty.starts_with("/dev/pts/"), "{pty}");
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new(&pty));

    // Servo 12 (the last of config/sim.toml) answers as an XL430-W250 (model 1060).
    let reply = ping(&link, 12);
    assert_eq!(reply.len(), 14, "{reply:02X?}");
    assert_eq!(reply[4], 12);
    assert_eq!(reply[8], 0, "no error");
    assert_eq!(u16::from_le_bytes([reply[9], reply[10]]), 1060);
    // The port closed above; a new client gets an answer too.
    assert_eq!(ping(&link, 1)[4], 1);
    // No servo 13.
    assert!(ping(&link, 13).is_empty());

    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let code = child.wait().unwrap();
    assert!(code.success(), "{code:?}");
    assert!(link.symlink_metadata().is_err(), "the link is removed");
}

#[test]
fn sim_refuses_a_config_without_servos_naming_the_joint() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("geometry.toml");
    std::fs::write(
        &file,
        "[arm]\n[[joint]]\nlink_m = 0.1\nmin_rad = -1.0\nmax_rad = 1.0\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("geometry.toml") && err.contains("joint[1]"),
        "{err}"
    );
}
