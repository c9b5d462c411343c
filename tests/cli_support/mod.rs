//! Running the `snakectl` binary the way a user does, for the command-line tests.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Runs `snakectl ARGS` from the repository root with `stdin` piped in; returns its output.
///
/// The input is written from its own thread while the output is collected, so a child that
/// prints a lot before reading cannot deadlock the test, and one that exits without reading
/// (a refused argument) is not an error here: its exit status and stderr tell the test.
pub fn snakectl(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut pipe = child.stdin.take().unwrap();
    let input = stdin.to_owned();
    let writer = std::thread::spawn(move || match pipe.write_all(input.as_bytes()) {
        Err(e) if e.kind() != ErrorKind::BrokenPipe => Err(e),
        _ => Ok(()),
    });
    let output = child.wait_with_output().unwrap();
    writer.join().unwrap().unwrap();
    output
}

/// Generous bound on waiting for the child: the machine may be busy. Reached only on failure.
pub const DEADLINE: Duration = Duration::from_secs(30);

/// A running `snakectl sim`. Dropping it (also when a test fails or panics) kills the process
/// if it still runs, reaps it and removes the link it may have left, so nothing leaks.
pub struct SimChild {
    /// The process.
    pub child: Child,
    /// The `--link` it was given.
    pub link: PathBuf,
}

impl SimChild {
    /// Waits for the process to exit by itself, up to [`DEADLINE`].
    pub fn wait_exit(&mut self) -> ExitStatus {
        let deadline = Instant::now() + DEADLINE;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            assert!(
                Instant::now() < deadline,
                "snakectl sim still runs {DEADLINE:?} after SIGTERM"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for SimChild {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if self.link.symlink_metadata().is_ok() {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}

/// Starts `snakectl sim --config CONFIG --link LINK` from the repository root; returns the
/// guard and the pseudo-terminal it printed (read with [`DEADLINE`], so a silent child fails).
pub fn spawn_sim(config: &str, link: &Path) -> (SimChild, String) {
    let mut sim = SimChild {
        child: Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["sim", "--config", config, "--link"])
            .arg(link)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn snakectl sim"),
        link: link.to_path_buf(),
    };
    let stdout = sim.child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let line = rx
        .recv_timeout(DEADLINE)
        .expect("snakectl sim printed its pty");
    (sim, line.trim().to_string())
}
