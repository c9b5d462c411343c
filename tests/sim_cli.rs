//! `snakectl sim` as a user runs it: it prints the pseudo-terminal, links it, answers Protocol
//! 2.0 there (also after the client closes and reopens the port), and stops cleanly on SIGTERM.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::io::{Read, Write};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use cli_support::DEADLINE;
use snakectl_sim::protocol::{self, Frame, Packet, Parser};

/// The tests of this file run one at a time. Run side by side, one of them was refused its
/// serial port now and then ("Unable to acquire exclusive lock") on a loaded machine, while
/// another test's simulator was unplugging and replugging its pseudo-terminals.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Sends a ping to each of `ids` in turn, in one write, and returns the status packets that
/// came back, read until the last id answered (the last id must be a servo that is there).
/// The simulator answers in order, so a reply to an earlier id would come before it: absence is
/// checked without waiting out a silence.
fn pings(port: &Path, ids: &[u8]) -> Vec<Packet> {
    let last = *ids.last().unwrap();
    let mut p = serialport::new(port.to_str().unwrap(), 1_000_000)
        .timeout(Duration::from_millis(200))
        .open()
        .unwrap();
    let bytes: Vec<u8> = ids
        .iter()
        .flat_map(|&id| protocol::encode_instruction(id, protocol::instruction::PING, &[]))
        .collect();
    p.write_all(&bytes).unwrap();
    let mut parser = Parser::default();
    let mut got = Vec::new();
    let mut buf = [0u8; 64];
    let deadline = Instant::now() + DEADLINE;
    while !got.iter().any(|r: &Packet| r.id == last) {
        assert!(Instant::now() < deadline, "no answer from {last}: {got:?}");
        if let Ok(k) = p.read(&mut buf) {
            for frame in parser.feed(&buf[..k], Instant::now()) {
                match frame.frame {
                    Frame::Packet(packet) => got.push(packet),
                    other => panic!("bad frame from snakectl sim: {other:?}"),
                }
            }
        }
    }
    got
}

#[test]
fn sim_serves_the_config_chain_on_a_linked_pty_and_stops_on_sigterm() {
    let _one_at_a_time = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("snake-bus");
    // The first line names the pty.
    let (mut sim, pty) = cli_support::spawn_sim("config/sim.toml", &link);
    assert!(pty.starts_with("/dev/pts/"), "{pty}");
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new(&pty));

    // Servo 12 (the last of config/sim.toml) answers as an XL430-W250 (model 1060, firmware
    // 48), without error.
    let reply = pings(&link, &[12]);
    assert_eq!(reply.len(), 1, "{reply:?}");
    assert_eq!(reply[0].id, 12);
    assert_eq!(reply[0].instruction, protocol::STATUS);
    assert_eq!(reply[0].params, [0, 0x24, 0x04, 48]);
    // The port closed above; a new client gets an answer too. No servo 13: only 1 answers.
    let ids: Vec<u8> = pings(&link, &[13, 1]).iter().map(|p| p.id).collect();
    assert_eq!(ids, [1]);

    let status = Command::new("kill")
        .args(["-TERM", &sim.child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let code = sim.wait_exit();
    assert!(code.success(), "{code:?}");
    assert!(link.symlink_metadata().is_err(), "the link is removed");
}

#[test]
fn sim_serves_one_pty_per_port_each_with_its_servos() {
    let _one_at_a_time = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("two-ports.toml");
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"));
    std::fs::write(
        &config,
        shipped.unwrap()
            + "\n[[bus.ports]]\nids = [1, 2, 3, 4, 5, 6]\n"
            + "\n[[bus.ports]]\nids = [7, 8, 9, 10, 11, 12]\n",
    )
    .unwrap();
    let links = [dir.path().join("bus-1"), dir.path().join("bus-2")];
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config"])
        .arg(&config)
        .arg("--link")
        .arg(&links[0])
        .arg("--link")
        .arg(&links[1])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut ptys = Vec::new();
    for _ in 0..2 {
        let mut line = String::new();
        std::io::BufRead::read_line(&mut stdout, &mut line).unwrap();
        ptys.push(line.trim().to_string());
    }
    for (link, pty) in links.iter().zip(&ptys) {
        assert!(pty.starts_with("/dev/pts/"), "{pty}");
        assert_eq!(std::fs::read_link(link).unwrap(), Path::new(pty));
    }
    // Each port answers for its own servos only (the other port's servo, asked first, is
    // silent here).
    let answered =
        |k: usize, ids: &[u8]| -> Vec<u8> { pings(&links[k], ids).iter().map(|p| p.id).collect() };
    assert_eq!(answered(0, &[9, 3]), [3]);
    assert_eq!(answered(1, &[3, 9]), [9]);
    let _ = child.kill();
    let _ = child.wait();
    // One --link for two ports: refused, naming the flag and the counts.
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config"])
        .arg(&config)
        .arg("--link")
        .arg(dir.path().join("only"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("1 --link given for the 2 ports of [bus]"),
        "{err}"
    );
    // One link for both ports (once through `.`): refused, naming the flags, nothing made.
    let same = dir.path().join("same");
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config"])
        .arg(&config)
        .arg("--link")
        .arg(&same)
        .arg("--link")
        .arg(dir.path().join(".").join("same"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("is the same path as --link 1"), "{err}");
    assert!(err.contains("--link 2 ("), "{err}");
    assert!(same.symlink_metadata().is_err(), "a link was made");
}

#[test]
fn sim_refuses_a_config_without_servos_naming_the_joint() {
    let _one_at_a_time = one_at_a_time();
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

/// `config/sim.toml` with `extra` appended, written into `dir`.
fn config_with(dir: &Path, extra: &str) -> String {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"))
        .unwrap()
        + extra;
    let file = dir.join("sim.toml");
    std::fs::write(&file, text).unwrap();
    file.to_str().unwrap().to_string()
}

#[test]
fn sim_with_a_disconnect_fault_points_its_link_at_a_new_pty_after_the_window() {
    let _one_at_a_time = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let config = config_with(
        dir.path(),
        "\n[[sim.fault]]\nkind = \"disconnect\"\nat_s = 1.0\nuntil_s = 2.0\n",
    );
    let link = dir.path().join("snake-bus");
    let (_sim, pty) = cli_support::spawn_sim(&config, &link);
    assert!(pty.starts_with("/dev/pts/"), "{pty}");
    assert_eq!(pings(&link, &[3])[0].id, 3);
    // The link vanishes with the pty, then comes back pointing at another one.
    let deadline = Instant::now() + DEADLINE;
    let mut seen_gone = false;
    let new = loop {
        assert!(Instant::now() < deadline, "the link never moved");
        match std::fs::read_link(&link) {
            Ok(target) if target != Path::new(&pty) => break target,
            Ok(_) => {}
            Err(_) => seen_gone = true,
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(seen_gone, "the link was removed during the window");
    assert!(new.starts_with("/dev/pts/"), "{}", new.display());
    assert_eq!(pings(&link, &[12])[0].id, 12);
}

#[test]
fn sim_refuses_to_replace_a_file_that_is_not_a_symlink() {
    let _one_at_a_time = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "keep me").unwrap();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    // A file, kept as it was; nor a directory, empty or not.
    for (path, what) in [(&file, "a regular file"), (&sub, "a directory")] {
        let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["sim", "--config", "config/sim.toml", "--link"])
            .arg(path)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        let says = format!("{}: {what}, not a symlink", path.display());
        assert!(err.contains(&says), "{err}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
    assert!(sub.is_dir());
}

#[test]
fn a_second_sim_is_refused_a_link_the_first_serves_and_a_sim_removes_only_its_own_link() {
    let _one_at_a_time = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("snake-bus");
    let (mut first, pty) = cli_support::spawn_sim("config/sim.toml", &link);
    // The second is refused: the link still points at the first's pty, which still answers.
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["sim", "--config", "config/sim.toml", "--link"])
        .arg(&link)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!("points at {pty}, a terminal still open")),
        "{err}"
    );
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new(&pty));
    assert_eq!(pings(&link, &[12])[0].id, 12);
    // Pointed elsewhere meanwhile, the link is not the first's to remove when it stops.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::remove_file(&link).unwrap();
    std::os::unix::fs::symlink(&elsewhere, &link).unwrap();
    let status = Command::new("kill")
        .args(["-TERM", &first.child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    assert!(first.wait_exit().success());
    assert_eq!(std::fs::read_link(&link).unwrap(), elsewhere);
    // A link left dangling is replaced.
    let (_second, pty) = cli_support::spawn_sim("config/sim.toml", &link);
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new(&pty));
}
