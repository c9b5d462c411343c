//! One owner per serial port, as users meet it: while `snakectl run` drives a port, a second
//! program on it (another `run`, `scan`, `servo`) is refused at once, naming the port and the
//! daemon's process, before it writes a single byte; the daemon goes on undisturbed; once the
//! daemon has exited, however it exited, the port opens again.
//!
//! Real processes on a real pseudo-terminal: the simulator is served by this test (so it sees
//! every byte and every servo), the daemon and the refused programs are the binary.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::time::Duration;

use daemon_support::child::{wait_within, DaemonChild};
use daemon_support::Client;
use serde_json::{json, Value};
use snakectl::config::Config;
use snakectl::connect;
use snakectl_sim::{RealClock, SimHandle};

/// Runs `snakectl ARGS` to its end; its exit status and stderr.
fn snakectl(args: &[&str]) -> (ExitStatus, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = wait_within(&mut child, &format!("snakectl {}", args.join(" ")));
    let mut stdout = String::new();
    let mut stderr = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    (status, stdout, stderr)
}

/// A daemon on a simulated chain, started on the simulator's link (a symlink in a private
/// directory, as `/dev/serial/by-id/...` is to a USB adapter).
struct Rig {
    _dir: tempfile::TempDir,
    config_path: PathBuf,
    config: Config,
    sim: SimHandle,
    daemon: DaemonChild,
    client: Client,
}

impl Rig {
    fn start() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
        let mut text = std::fs::read_to_string(shipped).unwrap();
        // A Bus Watchdog far longer than the pauses below (the daemon is stopped while a refused
        // program runs), and replies a busy machine can meet.
        for (old, new) in [
            ("watchdog_ms = 100\n", "watchdog_ms = 2000\n"),
            ("reply_timeout_ms = 20 ", "reply_timeout_ms = 100 "),
        ] {
            assert!(text.contains(old), "no `{old}` in config/sim.toml");
            text = text.replace(old, new);
        }
        let config_path = dir.path().join("arm.toml");
        std::fs::write(&config_path, &text).unwrap();
        let config = Config::load(&config_path).unwrap();
        let sim = connect::spawn_sim(&config, Arc::new(RealClock)).unwrap();
        let daemon = DaemonChild::spawn(&config_path, sim.path());
        let mut client = Client::connect(daemon.address());
        // The first reply waits for bring-up.
        let s = client.status();
        assert_eq!(s["state"], "holding", "{s}");
        Self {
            _dir: dir,
            config_path,
            config,
            sim,
            daemon,
            client,
        }
    }

    /// The link the daemon opened.
    fn link(&self) -> String {
        self.sim.path().to_str().unwrap().to_owned()
    }

    /// The pseudo-terminal the link points at: another name for the same device.
    fn pty(&self) -> String {
        self.sim.pty_path().unwrap().to_str().unwrap().to_owned()
    }

    /// The bytes the simulator has received so far.
    fn bytes(&self) -> u64 {
        self.sim.with_sim(|s| s.stats().bytes)
    }

    /// Runs `snakectl ARGS` while the daemon is stopped (SIGSTOP), so that every byte the
    /// simulator receives meanwhile would be that program's; asserts it sent none and was
    /// refused (exit `code`) naming `port` and the daemon's process. Returns its stderr.
    fn refused(&self, args: &[&str], port: &str, code: i32) -> String {
        self.daemon.signal("-STOP");
        // Quiet: what the daemon wrote before it stopped has reached the simulator.
        let mut before = self.bytes();
        loop {
            std::thread::sleep(Duration::from_millis(30));
            let now = self.bytes();
            if now == before {
                break;
            }
            before = now;
        }
        let (status, stdout, stderr) = snakectl(args);
        let after = self.bytes();
        self.daemon.signal("-CONT");
        assert_eq!(after, before, "the refused program wrote to the port");
        assert_eq!(status.code(), Some(code), "{stdout}{stderr}");
        let holder = format!("process {} (snakectl)", self.daemon.pid());
        assert!(
            stderr.contains(&format!("{port} ")) && stderr.contains(&holder),
            "the refusal names neither {port} nor {holder}:\n{stderr}"
        );
        assert!(stderr.contains("in use"), "{stderr}");
        stderr
    }

    /// The daemon is undisturbed: no fault, no missed or damaged reply since `before` (its
    /// counters then), every servo's torque on; and it still moves the arm to a target.
    fn assert_undisturbed(&mut self, before: &Value) {
        let s = self.client.status();
        assert_eq!(s["faults"], json!([]), "{s}");
        assert_eq!(s["state"], "holding", "{s}");
        for counter in ["dropped", "corrupted", "retries"] {
            assert_eq!(
                s["counters"][counter], before[counter],
                "{counter} changed: {s}"
            );
        }
        assert_eq!(self.sim.with_sim(|s| s.stats().crc_errors), 0);
        for id in self.config.arm().unwrap().ids() {
            assert!(
                self.sim.with_servo(id, |s| s.torque_enabled()).unwrap(),
                "servo {id}: torque off"
            );
        }
        let tip = [s["tip"][0].as_f64().unwrap(), s["tip"][1].as_f64().unwrap()];
        let target = [tip[0] - 0.03, tip[1] - 0.02];
        let id = self.client.send(json!({"cmd": "goto", "target": target}));
        assert_eq!(self.client.reply(&json!(id))["ok"], json!(true));
        self.client.event("arrived", Some(id));
        self.client.wait_status("the servos follow", |s| {
            let m = [
                s["tip_meas"][0].as_f64().unwrap(),
                s["tip_meas"][1].as_f64().unwrap(),
            ];
            (m[0] - target[0]).hypot(m[1] - target[1]) < 2e-3
        });
    }

    fn counters(&mut self) -> Value {
        self.client.status()["counters"].clone()
    }
}

#[test]
fn a_second_run_on_the_port_of_a_running_daemon_is_refused_and_the_first_runs_on() {
    let mut rig = Rig::start();
    let before = rig.counters();
    // The daemon opened the link; the second one names the pseudo-terminal itself.
    let pty = rig.pty();
    let config = rig.config_path.to_str().unwrap().to_owned();
    let args = [
        "run",
        "--listen",
        "127.0.0.1:0",
        "--config",
        &config,
        "--port",
        &pty,
    ];
    // `run` refused at start-up: exit 2.
    rig.refused(&args, &pty, 2);
    rig.assert_undisturbed(&before);

    // Once the daemon has exited, the port is free: a scan finds the chain.
    rig.daemon.signal("-TERM");
    let (status, log) = rig.daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    let link = rig.link();
    let (status, stdout, stderr) = snakectl(&[
        "scan",
        "--port",
        &link,
        "--baud",
        "1000000",
        "--timeout-ms",
        "300",
    ]);
    assert!(status.success(), "{stderr}");
    let n = rig.config.arm().unwrap().ids().len();
    assert!(
        stdout.starts_with(&format!("1000000 baud: {n} servo(s)")),
        "{stdout}"
    );
}

#[test]
fn a_scan_during_a_run_is_refused_and_faults_no_servo() {
    let mut rig = Rig::start();
    let before = rig.counters();
    let link = rig.link();
    // Without --baud, scan would try every common rate: refused before the first.
    let stderr = rig.refused(&["scan", "--port", &link, "--timeout-ms", "300"], &link, 1);
    // Named by the link, with the device it points at.
    assert!(stderr.contains(&format!("({})", rig.pty())), "{stderr}");
    rig.assert_undisturbed(&before);
}

#[test]
fn a_servo_command_during_a_run_is_refused_and_changes_nothing() {
    let mut rig = Rig::start();
    let before = rig.counters();
    let link = rig.link();
    let args = [
        "servo", "--port", &link, "--baud", "1000000", "--id", "3", "set-id", "20",
    ];
    rig.refused(&args, &link, 1);
    assert!(rig.sim.with_servo(3, |_| ()).is_some());
    assert!(rig.sim.with_servo(20, |_| ()).is_none());
    rig.assert_undisturbed(&before);
}

#[test]
fn a_daemon_killed_outright_leaves_no_lock_behind() {
    let mut rig = Rig::start();
    rig.daemon.kill();
    // A new daemon takes the port at once and brings the arm up.
    let daemon = DaemonChild::spawn(&rig.config_path, rig.sim.path());
    let mut client = Client::connect(daemon.address());
    let s = client.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]), "{s}");
    rig.daemon = daemon;
    rig.client = client;
    let before = rig.counters();
    rig.assert_undisturbed(&before);
}

#[test]
fn a_bus_closed_after_a_failure_frees_its_port_for_this_process_to_open_again() {
    use snakectl::connect::ConnectError;
    use snakectl::servo::{ErrorClass, ServoBus, ServoError};
    let config = Config::load(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let sim = connect::spawn_sim(&config, Arc::new(RealClock)).unwrap();
    let baud = config.bus().unwrap().baud;
    let t = Duration::from_millis(100);
    let mut bus = connect::open_port(sim.path(), baud).unwrap();
    bus.ping(1, t).unwrap();
    // While it is open, even this process cannot open the device a second time.
    match connect::open_port(&sim.pty_path().unwrap(), baud) {
        Err(ConnectError::InUse(ServoError::InUse {
            holder: Some(holder),
            ..
        })) => assert_eq!(holder.pid, std::process::id()),
        other => panic!("a second opening: {other:?}"),
    }
    // What the daemon does before it reopens a failed port: the closed bus fails as a vanished
    // port does, and the same device opens again.
    bus.close();
    assert_eq!(bus.ping(1, t).unwrap_err().class(), ErrorClass::Bus);
    let mut again = connect::open_port(sim.path(), baud).unwrap();
    again.ping(1, t).unwrap();
}

/// A two-port config (servos 1 to 6, 7 to 12) in `dir`, `[bus] kind` as given, each port's
/// path from `paths` (none: no `port` keys).
fn two_port_config(dir: &std::path::Path, kind: &str, paths: &[&str]) -> PathBuf {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(shipped).unwrap();
    let old = "kind = \"sim\"";
    assert!(text.contains(old), "no `{old}` in config/sim.toml");
    text = text.replacen(old, &format!("kind = \"{kind}\""), 1);
    for (k, ids) in ["[1, 2, 3, 4, 5, 6]", "[7, 8, 9, 10, 11, 12]"]
        .iter()
        .enumerate()
    {
        text.push_str(&format!("\n[[bus.ports]]\nids = {ids}\n"));
        if let Some(path) = paths.get(k) {
            text.push_str(&format!("port = \"{path}\"\n"));
        }
    }
    let path = dir.join(format!("two-{kind}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn ports_given_out_of_order_are_refused_once_per_port_saying_so() {
    let dir = tempfile::tempdir().unwrap();
    let file = two_port_config(dir.path(), "sim", &[]);
    let config = Config::load(&file).unwrap();
    let sims = connect::spawn_sims(&config, Arc::new(RealClock)).unwrap();
    let (one, two) = (
        sims[0].path().display().to_string(),
        sims[1].path().display().to_string(),
    );
    let args = [
        "run",
        "--config",
        file.to_str().unwrap(),
        "--listen",
        "127.0.0.1:0",
        "--port",
        &two,
        "--port",
        &one,
    ];
    let (status, _, stderr) = snakectl(&args);
    assert_eq!(status.code(), Some(2), "{stderr}");
    for says in [
        "no servo on port 1 answers (servos 1, 2, 3, 4, 5, 6;",
        "no servo on port 2 answers (servos 7, 8, 9, 10, 11, 12;",
        "the ports are given in the order of [[bus.ports]]",
    ] {
        assert!(stderr.contains(says), "not `{says}`:\n{stderr}");
    }
    assert!(
        !stderr.contains("joint 1: servo 1 does not answer"),
        "{stderr}"
    );
}

#[test]
fn one_device_given_as_two_ports_is_refused_before_the_socket_is_bound() {
    let config = Config::load(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let sim = connect::spawn_sim(&config, Arc::new(RealClock)).unwrap();
    let link = sim.path().display().to_string();
    let pty = sim.pty_path().unwrap().display().to_string();
    let dir = tempfile::tempdir().unwrap();
    // The address is taken: a daemon that bound it first would fail on it instead.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let listen = taken.local_addr().unwrap().to_string();
    let expect = |stderr: &str, path: &str| {
        let says = format!("port 2 ({path}) is the same device as port 1");
        assert!(stderr.contains(&says), "not `{says}`:\n{stderr}");
    };
    // The same flag twice, and a link beside the device it points to.
    let flags = two_port_config(dir.path(), "sim", &[]);
    let flags = flags.to_str().unwrap();
    for second in [&link, &pty] {
        let args = [
            "run", "--config", flags, "--listen", &listen, "--port", &link, "--port", second,
        ];
        let (status, _, stderr) = snakectl(&args);
        assert_eq!(status.code(), Some(2), "{stderr}");
        expect(&stderr, second);
    }
    // Two spellings of one path in the file.
    let dotted = sim
        .path()
        .parent()
        .unwrap()
        .join(".")
        .join(sim.path().file_name().unwrap());
    let dotted = dotted.display().to_string();
    let file = two_port_config(dir.path(), "dynamixel", &[&link, &dotted]);
    let args = [
        "run",
        "--config",
        file.to_str().unwrap(),
        "--listen",
        &listen,
    ];
    let (status, _, stderr) = snakectl(&args);
    assert_eq!(status.code(), Some(2), "{stderr}");
    // Named as the config's errors name its fields.
    let says = format!(
        "{}: bus.ports[2].port: {dotted:?} is the same device as bus.ports[1].port ({link:?})",
        file.display()
    );
    assert!(stderr.contains(&says), "not `{says}`:\n{stderr}");
    // One `--port` for two ports: refused the same way, before it says it listens.
    let args = [
        "run", "--config", flags, "--listen", &listen, "--port", &link,
    ];
    let (status, _, stderr) = snakectl(&args);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("1 --port given for the 2 ports of [bus]"),
        "{stderr}"
    );
    assert!(!stderr.contains("listening"), "{stderr}");
    // Nothing was written to the device.
    assert_eq!(sim.with_sim(|s| s.stats().bytes), 0);
}
