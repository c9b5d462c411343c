//! The daemon as the end-to-end tests run it: the simulator served in this process on a real
//! pseudo-terminal (so a test can look at the servos), the daemon on a port-0 loopback socket
//! with the test's own shutdown, and a blocking JSON-lines client.
#![allow(dead_code, missing_docs, clippy::unwrap_used, clippy::expect_used)]

pub mod child;

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, ErrorKind, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{DaemonError, Embedded, RunOptions, Summary};
use snakectl::record::RecordOptions;
use snakectl_sim::{RealClock, SimHandle};

/// Bound on waiting for anything; reached only when a test fails.
pub const DEADLINE: Duration = Duration::from_secs(30);

/// The shipped simulator config, with a reply timeout a busy machine can meet, and `edits`
/// applied (`(old, new)` replacements of whole lines, each of which must exist).
pub fn sim_config(edits: &[(&str, &str)]) -> Config {
    sim_config_with(edits, "")
}

/// [`sim_config`] with `sim_tables` (such as `[[sim.fault]]` tables) added to the `[sim]`
/// section.
pub fn sim_config_with(edits: &[(&str, &str)], sim_tables: &str) -> Config {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(path).unwrap();
    let mut all = vec![("reply_timeout_ms = 20 ", "reply_timeout_ms = 100")];
    all.extend_from_slice(edits);
    for (old, new) in all {
        assert!(text.contains(old), "config/sim.toml has no line `{old}`");
        text = text.replace(old, new);
    }
    let seed = text
        .find("\nseed = ")
        .expect("config/sim.toml has a `seed` line");
    let end = seed + 1 + text[seed + 1..].find('\n').unwrap();
    text.insert_str(end + 1, &format!("\n{sim_tables}\n"));
    Config::from_str(&text, path).unwrap()
}

/// `[[bus.ports]]` tables splitting the shipped 12-servo arm over two ports, servos 1 to 6 and
/// 7 to 12 (to append to the `[sim]` tables of [`sim_config_with`]).
pub const TWO_PORTS: &str = "[[bus.ports]]\nids = [1, 2, 3, 4, 5, 6]\n\
                             [[bus.ports]]\nids = [7, 8, 9, 10, 11, 12]\n";

/// A daemon running on its own thread and runtime, on a simulator this process serves (one per
/// port).
pub struct Daemon {
    pub addr: SocketAddr,
    /// The simulator of the (first) port.
    pub sim: SimHandle,
    /// The simulators of the other ports, in order, for a bus of several.
    pub more_sims: Vec<SimHandle>,
    pub config: Config,
    /// Stopped (and joined) when dropped.
    daemon: Option<Embedded>,
}

impl Daemon {
    /// Starts the simulator and the daemon on `config`; returns once the socket listens (the
    /// first reply then waits for bring-up).
    pub fn start(config: Config) -> Self {
        Self::start_with(config, None)
    }

    /// [`Daemon::start`], the run recorded as `record` says.
    pub fn start_with(config: Config, record: Option<RecordOptions>) -> Self {
        let mut sims = connect::spawn_sims(&config, Arc::new(RealClock)).unwrap();
        let options = RunOptions {
            ports: sims.iter().map(|s| s.path().to_path_buf()).collect(),
            record,
        };
        let localhost = SocketAddr::from(([127, 0, 0, 1], 0));
        let daemon = Embedded::start(config.clone(), localhost, options).unwrap();
        let sim = sims.remove(0);
        Self {
            addr: daemon.addr(),
            sim,
            more_sims: sims,
            config,
            daemon: Some(daemon),
        }
    }

    /// A new client connection.
    pub fn client(&self) -> Client {
        Client::connect(self.addr)
    }

    /// Resolves the shutdown future and waits for `run` to return.
    pub fn stop(mut self) -> Result<Summary, DaemonError> {
        self.finish()
    }

    fn finish(&mut self) -> Result<Summary, DaemonError> {
        self.daemon.take().expect("stopped once").stop()
    }

    /// Stops the daemon; returns what `run` returned and, afterwards, every servo's Torque
    /// Enable in the simulator.
    pub fn stop_and_torques(mut self) -> (Result<Summary, DaemonError>, Vec<(u8, bool)>) {
        let result = self.finish();
        let torques = self
            .sims()
            .flat_map(|sim| {
                sim.with_sim(|s| {
                    s.servos()
                        .iter()
                        .map(|s| (s.id(), s.torque_enabled()))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        (result, torques)
    }

    /// Servo `id`'s Torque Enable in the simulator.
    pub fn torque(&self, id: u8) -> bool {
        self.sim_of(id)
            .with_servo(id, |s| s.torque_enabled())
            .unwrap()
    }

    /// Every port's simulator, in port order.
    pub fn sims(&self) -> impl Iterator<Item = &SimHandle> {
        std::iter::once(&self.sim).chain(&self.more_sims)
    }

    /// The simulator of servo `id`'s port.
    pub fn sim_of(&self, id: u8) -> &SimHandle {
        self.sims()
            .find(|s| s.with_servo(id, |_| ()).is_some())
            .expect("a simulator serves the servo")
    }

    /// The link of port `k` (from 0), as fault reports name it.
    pub fn port_path(&self, k: usize) -> String {
        let sim = if k == 0 {
            &self.sim
        } else {
            &self.more_sims[k - 1]
        };
        sim.path().display().to_string()
    }
}

/// A blocking JSON-lines client. Lines that are not the awaited reply (events, telemetry) are
/// kept in arrival order for the `next_*` calls.
pub struct Client {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    next_id: u64,
    backlog: VecDeque<Value>,
}

impl Client {
    pub fn connect(addr: SocketAddr) -> Self {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_nodelay(true).unwrap();
        Self {
            reader: BufReader::new(stream.try_clone().unwrap()),
            writer: stream,
            next_id: 1,
            backlog: VecDeque::new(),
        }
    }

    /// Writes raw bytes.
    pub fn write_raw(&mut self, bytes: &[u8]) {
        self.writer.write_all(bytes).unwrap();
    }

    /// One line read within `timeout`, parsed; `None` when nothing came.
    pub fn read_line(&mut self, timeout: Duration) -> Option<Value> {
        self.reader
            .get_ref()
            .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))
            .unwrap();
        let mut line = String::new();
        match self.reader.read_line(&mut line) {
            Ok(0) => None,
            Ok(_) => Some(
                serde_json::from_str(&line).unwrap_or_else(|e| panic!("not JSON: {line:?}: {e}")),
            ),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => None,
            Err(e) => panic!("reading from the daemon: {e}"),
        }
    }

    /// Sends `request` with a fresh numeric id; returns the id.
    pub fn send(&mut self, mut request: Value) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        request["id"] = json!(id);
        let mut line = serde_json::to_string(&request).unwrap();
        line.push('\n');
        self.write_raw(line.as_bytes());
        id
    }

    /// The reply to request `id`, keeping other lines for later.
    pub fn reply(&mut self, id: &Value) -> Value {
        let deadline = Instant::now() + DEADLINE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "no reply to id {id} within {DEADLINE:?}");
            let Some(line) = self.read_line(left) else {
                continue;
            };
            if line.get("type").is_none() && &line["id"] == id {
                return line;
            }
            self.backlog.push_back(line);
        }
    }

    /// Sends `request` and returns its reply.
    pub fn request(&mut self, request: Value) -> Value {
        let id = self.send(request);
        self.reply(&json!(id))
    }

    /// Sends `request` and returns its reply, which must be `ok`.
    pub fn ok(&mut self, request: Value) -> Value {
        let reply = self.request(request.clone());
        assert_eq!(reply["ok"], json!(true), "{request} -> {reply}");
        reply
    }

    /// The reply's error code, which must be an error.
    pub fn error_code(&mut self, request: Value) -> String {
        let reply = self.request(request.clone());
        assert_eq!(reply["ok"], json!(false), "{request} -> {reply}");
        reply["error"]["code"].as_str().unwrap().to_owned()
    }

    pub fn status(&mut self) -> Value {
        self.ok(json!({"cmd": "status"}))
    }

    /// The next line (from the backlog first) that satisfies `pred`, within `timeout`; lines
    /// skipped on the way are dropped.
    pub fn next_matching(
        &mut self,
        timeout: Duration,
        mut pred: impl FnMut(&Value) -> bool,
    ) -> Option<Value> {
        while let Some(line) = self.backlog.pop_front() {
            if pred(&line) {
                return Some(line);
            }
        }
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            if let Some(line) = self.read_line(left) {
                if pred(&line) {
                    return Some(line);
                }
            }
        }
    }

    /// The next event named `name` (about command `cmd_id` when given), within [`DEADLINE`].
    pub fn event(&mut self, name: &str, cmd_id: Option<u64>) -> Value {
        self.next_matching(DEADLINE, |l| {
            l["type"] == "event"
                && l["event"] == name
                && cmd_id.is_none_or(|id| l["cmd_id"] == json!(id))
        })
        .unwrap_or_else(|| panic!("no `{name}` event within {DEADLINE:?}"))
    }

    /// Events kept so far (for checks that one did not come).
    pub fn drain_events(&mut self, wait: Duration) -> Vec<Value> {
        let mut out: Vec<Value> = self
            .backlog
            .drain(..)
            .filter(|l| l["type"] == "event")
            .collect();
        let deadline = Instant::now() + wait;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return out;
            }
            if let Some(line) = self.read_line(left) {
                if line["type"] == "event" {
                    out.push(line);
                }
            }
        }
    }

    /// Polls `status` until `pred` holds, within [`DEADLINE`].
    pub fn wait_status(&mut self, what: &str, mut pred: impl FnMut(&Value) -> bool) -> Value {
        let deadline = Instant::now() + DEADLINE;
        loop {
            let s = self.status();
            if pred(&s) {
                return s;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: not within {DEADLINE:?}; last {s}"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Telemetry lines until `pred` says stop (it sees each line) or [`DEADLINE`].
    pub fn telemetry_until(&mut self, mut stop: impl FnMut(&Value) -> bool) -> Vec<Value> {
        let mut out = Vec::new();
        let deadline = Instant::now() + DEADLINE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "telemetry: no end within {DEADLINE:?}");
            if let Some(line) = self.read_line(left) {
                if line["type"] == "telemetry" {
                    let done = stop(&line);
                    out.push(line);
                    if done {
                        return out;
                    }
                } else {
                    self.backlog.push_back(line);
                }
            }
        }
    }
}

/// `[x, y]` of a JSON pair.
pub fn xy(v: &Value) -> [f64; 2] {
    [v[0].as_f64().unwrap(), v[1].as_f64().unwrap()]
}

/// A JSON array of numbers.
pub fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

pub fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The tip error that rounding every joint to whole ticks can cause at pose `theta`:
/// the sum over joints of half a tick times the joint's lever arm to the tip.
pub fn rounding_bound(config: &Config, theta: &[f64]) -> f64 {
    let chain = config.chain();
    let points = chain.points(theta);
    let tip = points[points.len() - 1];
    let half_tick = std::f64::consts::TAU / 4096.0 / 2.0;
    points[..points.len() - 1]
        .iter()
        .map(|p| (tip - p).norm() * half_tick)
        .sum()
}

/// The nice value of each of this process's threads, by name (cut to 15 bytes, as the kernel
/// keeps it; Linux: `/proc/self/task`).
#[cfg(target_os = "linux")]
fn thread_nice() -> std::collections::BTreeMap<String, Vec<i64>> {
    let mut out: std::collections::BTreeMap<String, Vec<i64>> = Default::default();
    for task in std::fs::read_dir("/proc/self/task").unwrap() {
        let dir = task.unwrap().path();
        let (Ok(comm), Ok(stat)) = (
            std::fs::read_to_string(dir.join("comm")),
            std::fs::read_to_string(dir.join("stat")),
        ) else {
            continue; // the thread ended meanwhile
        };
        out.entry(comm.trim().to_string())
            .or_default()
            .push(nice_in(&stat));
    }
    out
}

/// The threads named `loop_side` run at the calling thread's priority, and those named
/// `beside` at [`snakectl::beside::STEP_ASIDE_NICE`] below it: every thread of each name (the
/// other tests' daemons may run too), and at least one.
#[cfg(target_os = "linux")]
pub fn threads_at(loop_side: &[&str], beside: &[&str]) {
    let threads = thread_nice();
    let ours = own_nice();
    let lower = (ours + i64::from(snakectl::beside::STEP_ASIDE_NICE)).min(19);
    for (names, nice) in [(loop_side, ours), (beside, lower)] {
        for name in names {
            let found = threads.get(*name).map_or(&[][..], |v| &v[..]);
            assert!(
                !found.is_empty() && found.iter().all(|&n| n == nice),
                "{name} not all at {nice}: {threads:?}"
            );
        }
    }
}

/// The calling thread's nice value.
#[cfg(target_os = "linux")]
fn own_nice() -> i64 {
    nice_in(&std::fs::read_to_string("/proc/thread-self/stat").unwrap())
}

/// The nice value in a thread's `stat` line: its 19th field (the 17th after the name, which is
/// in brackets and may hold spaces).
#[cfg(target_os = "linux")]
fn nice_in(stat: &str) -> i64 {
    let after = &stat[stat.rfind(')').unwrap() + 2..];
    after.split(' ').nth(16).unwrap().parse().unwrap()
}
