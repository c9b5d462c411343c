//! The real daemon (simulated servos, loopback socket) where a stop must not wait: a client
//! streaming `velocity` at 400 Hz and then sending `stop` (and later `estop`) on the same
//! connection; `snakectl estop` while every one of `max_clients` places is taken; a subscriber
//! that stops reading. The guarantees are stated in loop ticks, against a second, idle client
//! whose request arrives at the same moment, so a loaded machine does not make them flaky.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread;
use std::time::{Duration, Instant};

use daemon_support::{sim_config, Client, Daemon, DEADLINE};
use serde_json::{json, Value};

/// The flood's period: 400 Hz, four lines per tick of the 100 Hz loop.
const FLOOD_PERIOD: Duration = Duration::from_micros(2_500);
/// How long the flood runs before the stop.
const FLOOD: Duration = Duration::from_secs(2);

/// A connection that streams `velocity` lines from a thread of its own, and reads everything
/// the daemon sends on another, each line with the instant it arrived.
struct Flooder {
    writer: TcpStream,
    lines: mpsc::Receiver<(Instant, Value)>,
    flooding: Arc<AtomicBool>,
    pump: Option<thread::JoinHandle<u64>>,
}

impl Flooder {
    fn connect(addr: std::net::SocketAddr) -> Flooder {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_nodelay(true).unwrap();
        let reader = BufReader::new(stream.try_clone().unwrap());
        let (tx, lines) = mpsc::channel();
        thread::spawn(move || {
            for line in reader.lines() {
                let Ok(line) = line else { return };
                let value: Value = serde_json::from_str(&line).unwrap();
                if tx.send((Instant::now(), value)).is_err() {
                    return;
                }
            }
        });
        Flooder {
            writer: stream,
            lines,
            flooding: Arc::new(AtomicBool::new(false)),
            pump: None,
        }
    }

    fn write(&mut self, request: &Value) {
        let mut line = request.to_string();
        line.push('\n');
        self.writer.write_all(line.as_bytes()).unwrap();
    }

    /// The reply to `id`, skipping everything else.
    fn reply(&self, id: &Value) -> (Instant, Value) {
        let deadline = Instant::now() + DEADLINE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let (at, line) = self.lines.recv_timeout(left).expect("a reply");
            if line.get("type").is_none() && &line["id"] == id {
                return (at, line);
            }
        }
    }

    /// Starts the `velocity` stream: back and forth along x, 2 cm/s, ids `v1`, `v2`, ...
    fn start(&mut self) {
        self.flooding.store(true, Ordering::SeqCst);
        let mut writer = self.writer.try_clone().unwrap();
        let flooding = Arc::clone(&self.flooding);
        self.pump = Some(thread::spawn(move || {
            let mut sent = 0u64;
            let start = Instant::now();
            while flooding.load(Ordering::SeqCst) {
                sent += 1;
                let sign = if (sent / 200) % 2 == 0 { 1.0 } else { -1.0 };
                let line =
                    json!({"cmd": "velocity", "v": [0.02 * sign, 0.0], "id": format!("v{sent}")});
                let mut line = line.to_string();
                line.push('\n');
                if writer.write_all(line.as_bytes()).is_err() {
                    break;
                }
                let next = start + FLOOD_PERIOD * sent as u32;
                thread::sleep(next.saturating_duration_since(Instant::now()));
            }
            sent
        }));
    }

    /// Stops the stream; how many lines it sent.
    fn halt(&mut self) -> u64 {
        self.flooding.store(false, Ordering::SeqCst);
        self.pump.take().unwrap().join().unwrap()
    }
}

/// The loop tick a reply names.
fn tick(reply: &Value) -> u64 {
    reply["tick"]
        .as_u64()
        .unwrap_or_else(|| panic!("no tick in {reply}"))
}

/// Sends `line` on the flooding connection and `status` on the idle one at the same moment;
/// the ticks that applied each.
fn together(flooder: &mut Flooder, line: Value, idle: &mut Client) -> (u64, u64, Value) {
    let id = line["id"].clone();
    let probe = idle.send(json!({"cmd": "status"}));
    flooder.write(&line);
    let (_, reply) = flooder.reply(&id);
    let status = idle.reply(&json!(probe));
    (tick(&reply), tick(&status), reply)
}

#[test]
fn a_velocity_flood_never_holds_back_a_stop_or_an_estop_on_its_own_connection() {
    let daemon = Daemon::start(sim_config(&[]));
    let mut idle = daemon.client();
    let mut flooder = Flooder::connect(daemon.addr);
    flooder.write(&json!({"cmd": "take_control", "id": "tc"}));
    assert_eq!(flooder.reply(&json!("tc")).1["ok"], json!(true));

    // 400 Hz of velocity, then a stop on the same connection, right behind the last one.
    flooder.start();
    thread::sleep(FLOOD);
    let sent = flooder.halt();
    let (stop_tick, probe_tick, reply) = together(
        &mut flooder,
        json!({"cmd": "stop", "id": "stop"}),
        &mut idle,
    );
    assert_eq!(reply["ok"], json!(true), "{reply}");
    println!("stop applied at tick {stop_tick}, the idle client's status at {probe_tick}, after {sent} velocity lines");
    assert!(
        stop_tick <= probe_tick + 1,
        "the stop waited behind the flood: applied at tick {stop_tick}, a request that arrived \
         with it at tick {probe_tick}"
    );

    // At rest within the deceleration: from 2 cm/s at the configured tip acceleration.
    let c = daemon.config.control();
    let decel_ticks = (0.02 / c.max_tip_accel_m_s2 * c.rate_hz).ceil() as u64;
    let at_rest = idle.wait_status("the arm at rest", |s| s["state"] == json!("holding"));
    assert!(
        tick(&at_rest) <= stop_tick + decel_ticks + 5,
        "at rest at tick {}, the stop at {stop_tick}, deceleration {decel_ticks} ticks",
        tick(&at_rest)
    );
    // Nothing the flood sent before the stop moves the arm after it.
    let later = idle.status();
    assert_eq!(later["state"], json!("holding"), "{later}");
    assert_eq!(later["theta_cmd"], at_rest["theta_cmd"]);

    // The same with an estop.
    flooder.start();
    thread::sleep(FLOOD);
    flooder.halt();
    let (estop_tick, probe_tick, reply) = together(
        &mut flooder,
        json!({"cmd": "estop", "id": "estop"}),
        &mut idle,
    );
    assert_eq!(reply["ok"], json!(true), "{reply}");
    println!("estop applied at tick {estop_tick}, the idle client's status at {probe_tick}");
    assert!(
        estop_tick <= probe_tick + 1,
        "the estop waited behind the flood: applied at tick {estop_tick}, a request that \
         arrived with it at tick {probe_tick}"
    );
    let held = idle.status();
    assert_eq!(held["state"], json!("estop"), "{held}");
    thread::sleep(Duration::from_millis(200));
    assert_eq!(idle.status()["theta_cmd"], held["theta_cmd"], "frozen");
    drop(flooder);
    daemon.stop().unwrap();
}

#[test]
fn snakectl_estop_gets_through_while_every_place_is_taken() {
    let daemon = Daemon::start(sim_config(&[("max_clients = 4", "max_clients = 2")]));
    // Two places taken: one by a silent-but-subscribed client, one by a client that moves.
    let mut watcher = daemon.client();
    watcher.ok(json!({"cmd": "subscribe", "rate_hz": 10}));
    let mut mover = daemon.client();
    mover.ok(json!({"cmd": "velocity", "v": [0.01, 0.0]}));

    // Anything but a stop is refused at the door, answered first.
    let mut third = Client::connect(daemon.addr);
    assert_eq!(
        third.error_code(json!({"cmd": "status"})),
        "too_many_clients"
    );

    let addr = daemon.addr.to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["estop", "--connect", &addr])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "snakectl estop: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let status = mover.status();
    assert_eq!(status["state"], json!("estop"), "{status}");
    // The places it did not take are still the two clients'.
    assert_eq!(watcher.status()["state"], json!("estop"));
    daemon.stop().unwrap();
}

#[test]
fn a_subscriber_that_stops_reading_is_cut_off_and_never_handed_much_stale_telemetry() {
    let daemon = Daemon::start(sim_config(&[]));
    let mut clock = daemon.client();
    let stream = TcpStream::connect(daemon.addr).unwrap();
    let mut stalled = BufReader::new(stream.try_clone().unwrap());
    (&stream)
        .write_all(b"{\"cmd\":\"subscribe\",\"rate_hz\":1000,\"id\":1}\n")
        .unwrap();
    let mut first = String::new();
    stalled.read_line(&mut first).unwrap();
    assert!(first.contains("\"ok\":true"), "{first}");

    // Not a byte read for five seconds, while the daemon publishes at 100 Hz.
    thread::sleep(Duration::from_secs(5));
    let now = clock.status();
    let rate_hz = daemon.config.control().rate_hz;
    let old_before = tick(&now).saturating_sub(rate_hz as u64);

    // Everything that waited for it, to the end of the connection.
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut stale_bytes = 0usize;
    let mut lines = 0usize;
    let mut rest = Vec::new();
    let ended = loop {
        let mut line = String::new();
        match stalled.read_line(&mut line) {
            Ok(0) => break true,
            Ok(_) => {
                lines += 1;
                let value: Value = serde_json::from_str(&line).unwrap();
                if value["type"] == json!("telemetry") && tick(&value) < old_before {
                    stale_bytes += line.len();
                }
            }
            Err(_) => break false,
        }
    };
    let _ = stalled.read_to_end(&mut rest);
    println!("after the stall: {lines} lines, {stale_bytes} bytes over 1 s old");
    assert!(ended, "a reader that stalled for 5 s is disconnected");
    assert!(
        stale_bytes <= 256 * 1024,
        "{stale_bytes} bytes of telemetry over 1 s old"
    );
    // The others go on.
    assert!(tick(&clock.status()) > tick(&now));
    daemon.stop().unwrap();
}
