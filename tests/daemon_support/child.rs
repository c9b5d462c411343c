//! `snakectl run` as a child process: its log read line by line, the address it listens on,
//! signals, its exit.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::DEADLINE;

/// A `snakectl run` child; continued if stopped, killed and reaped when dropped.
pub struct DaemonChild {
    child: Child,
    stderr: mpsc::Receiver<String>,
}

impl DaemonChild {
    /// `snakectl run` on `config` and `port`, listening on a port-0 loopback socket.
    pub fn spawn(config: &Path, port: &Path) -> Self {
        Self::spawn_with(config, port, &[])
    }

    /// [`DaemonChild::spawn`] with more arguments (`--record FILE`, say).
    pub fn spawn_with(config: &Path, port: &Path, more: &[&std::ffi::OsStr]) -> Self {
        let child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["run", "--listen", "127.0.0.1:0", "--config"])
            .arg(config)
            .arg("--port")
            .arg(port)
            .args(more)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        Self::from_child(child)
    }

    /// A `snakectl run` spawned otherwise (under a shell's `ulimit`, say), its stderr piped.
    pub fn from_child(mut child: Child) -> Self {
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self { child, stderr: rx }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// The address from the "listening on ADDR ..." log line.
    pub fn address(&self) -> SocketAddr {
        let deadline = Instant::now() + DEADLINE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let line = self
                .stderr
                .recv_timeout(left)
                .expect("snakectl run logged where it listens");
            if let Some(at) = line.find("listening on ") {
                let rest = &line[at + "listening on ".len()..];
                let addr = rest.split_whitespace().next().unwrap_or(rest);
                return addr.parse().unwrap();
            }
        }
    }

    /// The next line logged that contains `text`, waiting up to `wait` (the lines before it are
    /// let go); `None` when none came in time.
    pub fn logged(&self, text: &str, wait: Duration) -> Option<String> {
        let deadline = Instant::now() + wait;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.stderr.recv_timeout(left) {
                Ok(line) if line.contains(text) => return Some(line),
                Ok(_) => {}
                Err(_) => return None,
            }
        }
    }

    /// Sends `signal` (`-TERM`, `-STOP`, ...) with kill(1).
    pub fn signal(&self, signal: &str) {
        let ok = Command::new("kill")
            .args([signal, &self.pid().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill {signal}");
    }

    /// SIGKILL, and the process reaped: a crash, as the servos see it.
    pub fn kill(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// Its exit status and everything it logged, waited for up to [`DEADLINE`].
    pub fn wait(&mut self) -> (ExitStatus, String) {
        let status = wait_within(&mut self.child, "snakectl run");
        // The pipe closes with the process: every line logged is here.
        let log: Vec<String> = self.stderr.iter().collect();
        (status, log.join("\n"))
    }
}

impl Drop for DaemonChild {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // A stopped daemon (a test that failed while it was) is continued, then killed.
            let _ = Command::new("kill")
                .args(["-CONT", &self.pid().to_string()])
                .status();
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `child`'s exit status, waited for up to [`DEADLINE`] (a generous bound, reached only when
/// the program did not exit).
pub fn wait_within(child: &mut Child, what: &str) -> ExitStatus {
    let deadline = Instant::now() + DEADLINE;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} still runs after {DEADLINE:?}");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}
