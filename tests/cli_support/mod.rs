//! Running the `snakectl` binary the way a user does, for the command-line tests.

use std::io::Write;
use std::process::{Command, Output, Stdio};

/// Runs `snakectl ARGS` from the repository root with `stdin` piped in; returns its output.
pub fn snakectl(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    child.wait_with_output().unwrap()
}
