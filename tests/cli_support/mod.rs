//! Running the `snakectl` binary the way a user does, for the command-line tests.

use std::io::{ErrorKind, Write};
use std::process::{Command, Output, Stdio};

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
