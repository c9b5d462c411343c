//! The JSON-lines server over real loopback sockets, against a fake control loop on the other
//! ends of `link::channel`: error codes, ids, ordering, `busy`, telemetry subscriptions (on
//! paused time), events, the client limit, a client that does not read, shutdown, who may
//! command (control taken, refused, released, lost with the connection), the token, and the
//! start-up refusals of `daemon::run` (a token file it cannot use, an address beyond loopback
//! without one, Zenoh enabled in a build without it).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use serde_json::{json, Map, Value};
use snakectl::config::Config;
use snakectl::daemon::access::{AccessError, Token};
use snakectl::daemon::link::{self, Envelope, Handle, COMMAND_QUEUE, STOP_QUEUE};
use snakectl::daemon::server::{serve, ServerOptions, STOPS_IN_FLIGHT};
use snakectl::daemon::{self, DaemonError, RunOptions};
use snakectl::protocol::{
    Applied, CmdName, Code, Describe, Event, EventKind, FaultChange, FaultInfo, FaultKind, Fields,
    LoopCmd, Motion, Rejection, Reply, Status, StopReason, Telemetry, What, MAX_LINE,
    PROTOCOL_VERSION, STRATEGIES,
};
use snakectl::resolve::Strategy;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::task::JoinHandle;
use tokio::time::{self, Instant};

const JOINTS: usize = 3;
const LOOP_HZ: f64 = 100.0;
/// A deadline for things that should happen at once; reaching it fails the test.
const DEADLINE: Duration = Duration::from_secs(20);

fn describe(joints: usize) -> Describe {
    Describe {
        links_m: vec![0.1; joints],
        base: [0.0, 0.0, 0.0],
        min_rad: vec![-2.0; joints],
        max_rad: vec![2.0; joints],
        ids: (1..=joints).map(|i| (i % 250) as u8).collect(),
        models: vec!["XL430-W250".into(); joints],
        home_rad: vec![0.0; joints],
        rate_hz: LOOP_HZ,
        strategies: STRATEGIES.to_vec(),
        protocol_version: PROTOCOL_VERSION,
        ..Describe::default()
    }
}

fn telemetry(tick: u64) -> Telemetry {
    Telemetry {
        tick,
        t_s: tick as f64 / LOOP_HZ,
        strategy: Strategy::Overall,
        theta_cmd: vec![0.0; JOINTS],
        theta_meas: vec![0.0; JOINTS],
        omega_meas: vec![0.0; JOINTS],
        ..Telemetry::default()
    }
}

/// A daemon on a port-0 listener, with a fake loop behind it.
struct Daemon {
    addr: SocketAddr,
    /// The socket side's handle, to fill the command queue from outside.
    handle: Handle,
    /// The loop's telemetry and event ends, driven by the test.
    telemetry: watch::Sender<Telemetry>,
    events: broadcast::Sender<Event>,
    /// Whether the fake loop takes commands.
    draining: watch::Sender<bool>,
    fake: JoinHandle<()>,
    stop: Option<oneshot::Sender<()>>,
    server: Option<JoinHandle<io::Result<()>>>,
}

impl Daemon {
    async fn start(options: ServerOptions, describe: Describe) -> Daemon {
        let (handle, ends) = link::channel(describe, telemetry(0));
        let (draining, draining_rx) = watch::channel(true);
        let fake = tokio::spawn(fake_loop(
            ends.commands,
            ends.stops,
            ends.telemetry.subscribe(),
            ends.events.clone(),
            draining_rx,
        ));
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, stopped) = oneshot::channel::<()>();
        let server = tokio::spawn(serve(listener, handle.clone(), options, async move {
            let _ = stopped.await;
        }));
        Daemon {
            addr,
            handle,
            telemetry: ends.telemetry,
            events: ends.events,
            draining,
            fake,
            stop: Some(stop),
            server: Some(server),
        }
    }

    async fn new() -> Daemon {
        Daemon::start(ServerOptions::new(JOINTS, 8), describe(JOINTS)).await
    }

    async fn client(&self) -> Client {
        Client::connect(self.addr).await
    }

    /// Resolves the shutdown future and waits for `serve` to return.
    async fn shut_down(&mut self) -> io::Result<()> {
        let _ = self.stop.take().unwrap().send(());
        let server = self.server.take().unwrap();
        time::timeout(DEADLINE, server)
            .await
            .expect("serve returns after shutdown")
            .unwrap()
    }
}

/// A stand-in for the control loop: every millisecond it takes the queued commands (`stop` and
/// `estop` from their own queue, merged by arrival) and answers
/// each `{"tick": k, "cmd": NAME, "client": ID}`, k counting the commands it answered; `status`
/// with the telemetry fields; `goto_joints` with an `unreachable` rejection; `reset_stats` by
/// dropping the reply (as a loop that went away mid-command). A `reach` it keeps for later (as
/// the loop does while its way is planned), saying so, until a `stop` comes: that answers the
/// reach as taken, then tells its sender it was `preempted`, then answers the stop.
async fn fake_loop(
    mut commands: mpsc::Receiver<Envelope>,
    mut stops: mpsc::Receiver<Envelope>,
    telemetry: watch::Receiver<Telemetry>,
    events: broadcast::Sender<Event>,
    mut draining: watch::Receiver<bool>,
) {
    let mut tick = 0u64;
    let mut kept: Vec<Envelope> = Vec::new();
    let mut every = time::interval(Duration::from_millis(1));
    loop {
        every.tick().await;
        if !*draining.borrow_and_update() {
            if draining.changed().await.is_err() {
                return;
            }
            continue;
        }
        let mut taken: Vec<Envelope> = std::iter::from_fn(|| stops.try_recv().ok()).collect();
        taken.extend(std::iter::from_fn(|| commands.try_recv().ok()));
        taken.sort_by_key(|e| e.received);
        for mut envelope in taken {
            tick += 1;
            if let LoopCmd::Motion(Motion::Reach { .. }) = envelope.cmd {
                if let Some(later) = envelope.later.take() {
                    let _ = later.send(());
                }
                kept.push(envelope);
                continue;
            }
            if let LoopCmd::Stop = envelope.cmd {
                for reach in kept.drain(..) {
                    let _ = reach
                        .reply
                        .send(Ok(Reply::Applied(Applied { tick }).into()));
                    let _ = events.send(Event {
                        owner: Some(reach.client),
                        cmd_id: reach.id,
                        tick,
                        what: What::Preempted {
                            tip: [0.0, 0.0],
                            reason: CmdName::Stop,
                        },
                    });
                }
            }
            let answer = match envelope.cmd {
                LoopCmd::Status => {
                    let status = Status::of(telemetry.borrow().clone());
                    Ok(Reply::Status(Box::new(status)).into())
                }
                LoopCmd::Motion(Motion::GotoJoints { .. }) => Err(Rejection::new(
                    Code::Unreachable,
                    "outside the joint limits",
                )),
                LoopCmd::ResetStats => continue,
                cmd => {
                    let mut more = Map::new();
                    more.insert("cmd".into(), json!(cmd.name()));
                    more.insert("client".into(), json!(envelope.client));
                    Ok(Fields {
                        reply: Reply::Applied(Applied { tick }),
                        more,
                    })
                }
            };
            let _ = envelope.reply.send(answer);
        }
    }
}

struct Client {
    lines: tokio::io::Lines<BufReader<OwnedReadHalf>>,
    writer: OwnedWriteHalf,
}

impl Client {
    async fn connect(addr: SocketAddr) -> Client {
        Client::from_stream(TcpStream::connect(addr).await.unwrap())
    }

    fn from_stream(stream: TcpStream) -> Client {
        let (read, writer) = stream.into_split();
        Client {
            lines: BufReader::new(read).lines(),
            writer,
        }
    }

    async fn send_raw(&mut self, bytes: &[u8]) {
        self.writer.write_all(bytes).await.unwrap();
    }

    async fn send(&mut self, request: &Value) {
        let mut line = request.to_string();
        line.push('\n');
        self.send_raw(line.as_bytes()).await;
    }

    /// The next line, or `None` at the end of the stream.
    async fn next_line(&mut self) -> Option<Value> {
        let line = time::timeout(DEADLINE, self.lines.next_line())
            .await
            .expect("a line within the deadline")
            .unwrap()?;
        Some(serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}")))
    }

    async fn recv(&mut self) -> Value {
        self.next_line().await.expect("a line, not the end")
    }

    /// The next reply, skipping telemetry and event lines.
    async fn reply(&mut self) -> Value {
        loop {
            let line = self.recv().await;
            if line.get("type").is_none() {
                return line;
            }
        }
    }

    async fn request(&mut self, request: Value) -> Value {
        self.send(&request).await;
        self.reply().await
    }

    /// Whether the server closes the connection (end of stream or reset) within the deadline,
    /// reading whatever comes before.
    async fn closed(&mut self) -> bool {
        let read = time::timeout(DEADLINE, async {
            loop {
                match self.lines.next_line().await {
                    Ok(Some(_)) => {}
                    Ok(None) | Err(_) => return,
                }
            }
        });
        read.await.is_ok()
    }
}

fn code(reply: &Value) -> &str {
    assert_eq!(reply["ok"], json!(false), "{reply}");
    reply["error"]["code"].as_str().unwrap()
}

fn message(reply: &Value) -> &str {
    reply["error"]["message"].as_str().unwrap()
}

#[tokio::test]
async fn every_request_error_code_is_answered_and_the_connection_lives() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;

    c.send_raw(b"not json\n").await;
    let reply = c.reply().await;
    assert_eq!((code(&reply), &reply["id"]), ("bad_json", &Value::Null));

    c.send_raw(b"[1,2,3]\n").await;
    assert_eq!(code(&c.reply().await), "bad_json");

    c.send_raw(b"{\"cmd\":\"goto\",\"id\":1,\"target\":[1e999,0]}\n")
        .await;
    let reply = c.reply().await;
    assert_eq!(code(&reply), "bad_json", "{reply}");
    assert_eq!(
        reply["id"],
        Value::Null,
        "the id of a line that is not JSON is unknown"
    );

    let reply = c.request(json!({"cmd": "dance", "id": 2})).await;
    assert_eq!((code(&reply), &reply["id"]), ("unknown_cmd", &json!(2)));
    assert!(message(&reply).contains("goto_joints"), "{reply}");

    let reply = c.request(json!({"id": 3})).await;
    assert_eq!(code(&reply), "unknown_cmd");

    let reply = c
        .request(json!({"cmd": "goto", "id": 4, "target": [0.1, "far"]}))
        .await;
    assert_eq!((code(&reply), &reply["id"]), ("bad_arg", &json!(4)));
    assert!(message(&reply).contains("target[1]"), "{reply}");
    assert!(message(&reply).contains("\"far\""), "{reply}");

    let reply = c
        .request(json!({"cmd": "goto_joints", "id": 5, "theta": [0, 0]}))
        .await;
    assert_eq!(code(&reply), "bad_arg", "theta needs {JOINTS} entries");

    let reply = c
        .request(json!({"cmd": "jog", "id": 6, "joint": JOINTS + 1, "rad_s": 0.1}))
        .await;
    assert_eq!(code(&reply), "bad_arg");
    assert!(message(&reply).contains("joint"), "{reply}");

    // Rejections from the loop, and a reply the loop dropped.
    let reply = c
        .request(json!({"cmd": "goto_joints", "id": 7, "theta": [0, 0, 3]}))
        .await;
    assert_eq!((code(&reply), &reply["id"]), ("unreachable", &json!(7)));
    let reply = c.request(json!({"cmd": "reset_stats", "id": 8})).await;
    assert_eq!((code(&reply), &reply["id"]), ("shutting_down", &json!(8)));

    // The connection still serves.
    let reply = c.request(json!({"cmd": "stop", "id": 9})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(reply["cmd"], json!("stop"));
}

#[tokio::test]
async fn an_over_long_line_is_refused_and_the_next_request_answered() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let mut long = br#"{"cmd":"path","id":1,"points":["#.to_vec();
    while long.len() <= MAX_LINE {
        long.extend_from_slice(b"[0.001,0.002],");
    }
    long.extend_from_slice(b"[0,0]]}\n");
    c.send_raw(&long).await;
    c.send_raw(b"\n   \n").await;
    c.send(&json!({"cmd": "describe", "id": "after"})).await;
    let reply = c.reply().await;
    assert_eq!(code(&reply), "line_too_long", "{reply}");
    assert_eq!(reply["id"], Value::Null);
    let reply = c.reply().await;
    assert_eq!(
        reply["id"],
        json!("after"),
        "blank lines get no reply: {reply}"
    );
    assert_eq!(reply["ok"], json!(true));
}

#[tokio::test]
async fn ids_of_every_kind_are_echoed() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let ids = [
        json!(17),
        json!(-2.5),
        json!(18446744073709551615u64),
        json!("req-1"),
        json!({"seq": 4, "tag": ["a"]}),
        json!([1, null]),
        json!(true),
    ];
    for id in &ids {
        for cmd in ["status", "describe", "stop", "fly"] {
            let reply = c.request(json!({"cmd": cmd, "id": id})).await;
            assert_eq!(&reply["id"], id, "{cmd}: {reply}");
        }
    }
    for cmd in ["status", "describe", "stop", "fly"] {
        let reply = c.request(json!({"cmd": cmd})).await;
        assert_eq!(reply["id"], Value::Null, "{reply}");
        assert!(reply.as_object().unwrap().contains_key("id"), "{reply}");
    }
}

#[tokio::test]
async fn replies_keep_the_order_of_the_requests() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    // Loop commands (answered a tick later) between requests answered on the socket side at once.
    let mut burst = String::new();
    for i in 0..60 {
        let request = match i % 4 {
            0 => json!({"cmd": "stop", "id": i}),
            1 => json!({"cmd": "describe", "id": i}),
            2 => json!({"cmd": "goto", "id": i, "target": [0.1, 0.1]}),
            _ => json!({"cmd": "goto", "id": i}),
        };
        burst.push_str(&request.to_string());
        burst.push('\n');
    }
    c.send_raw(burst.as_bytes()).await;
    let mut last_tick = 0;
    for i in 0..60 {
        let reply = c.reply().await;
        assert_eq!(reply["id"], json!(i), "{reply}");
        if let Some(tick) = reply["tick"].as_u64() {
            assert!(tick > last_tick, "{reply} after tick {last_tick}");
            last_tick = tick;
        }
    }
}

/// Regression: a reply the loop keeps for later (a `reach` while its way is planned) held up
/// every reply and event after it on its connection. Those are written meanwhile; the kept
/// reply comes when the loop gives it, before the reply to the `stop` that ended it and
/// before the event about it.
#[tokio::test]
async fn a_reply_the_loop_keeps_for_later_holds_up_nothing_after_it() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let mut burst = String::new();
    for request in [
        json!({"cmd": "reach", "id": "r", "target": [0.1, 0.1]}),
        json!({"cmd": "describe", "id": "d"}),
        json!({"cmd": "status", "id": "s"}),
        json!({"cmd": "goto", "id": "g", "target": [0.1, 0.1]}),
    ] {
        burst.push_str(&request.to_string());
        burst.push('\n');
    }
    c.send_raw(burst.as_bytes()).await;
    for id in ["d", "s", "g"] {
        let reply = c.reply().await;
        assert_eq!(reply["id"], json!(id), "{reply}");
    }
    // An event to everyone comes too (after the `control` event the reach's taking of control
    // sent).
    daemon
        .events
        .send(event(None, EventKind::Reset, 7))
        .unwrap();
    loop {
        let line = c.recv().await;
        assert_eq!(line["type"], json!("event"), "{line}");
        if line["event"] == json!("reset") {
            break;
        }
    }
    c.send(&json!({"cmd": "stop", "id": "x"})).await;
    let lines = [c.recv().await, c.recv().await, c.recv().await];
    assert_eq!(lines[0]["id"], json!("r"), "{lines:?}");
    assert_eq!(lines[0]["ok"], json!(true), "{lines:?}");
    assert_eq!(lines[1]["id"], json!("x"), "{lines:?}");
    assert_eq!(lines[2]["event"], json!("preempted"), "{lines:?}");
    assert_eq!(lines[2]["cmd_id"], json!("r"), "{lines:?}");
    assert_eq!(lines[0]["tick"], lines[2]["tick"], "{lines:?}");
}

#[tokio::test]
async fn describe_is_answered_with_its_fields_flat() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let reply = c.request(json!({"cmd": "describe", "id": 1})).await;
    let mut expected = describe(JOINTS).to_fields();
    expected.insert("id".into(), json!(1));
    expected.insert("ok".into(), json!(true));
    assert_eq!(reply, Value::Object(expected));
}

#[tokio::test]
async fn status_carries_the_telemetry_fields() {
    let daemon = Daemon::new().await;
    daemon.telemetry.send_replace(telemetry(41));
    let mut c = daemon.client().await;
    let reply = c.request(json!({"cmd": "status", "id": 1})).await;
    let mut expected = telemetry(41).to_fields();
    expected.insert("id".into(), json!(1));
    expected.insert("ok".into(), json!(true));
    expected.insert("controller".into(), Value::Null);
    expected.insert("in_control".into(), json!(false));
    assert_eq!(reply, Value::Object(expected));
}

/// Fills the loop's command queue (the fake loop not draining it) with another client's
/// `status` requests; returns their pending answers.
fn fill_the_queue(daemon: &Daemon) -> Vec<oneshot::Receiver<link::Answer>> {
    let mut waiting = Vec::new();
    loop {
        let (reply, answer) = oneshot::channel();
        let envelope = Envelope {
            client: 999,
            id: None,
            cmd: LoopCmd::Status,
            received: std::time::Instant::now(),
            reply,
            later: None,
        };
        if daemon.handle.commands.try_send(envelope).is_err() {
            return waiting;
        }
        waiting.push(answer);
    }
}

#[tokio::test]
async fn a_full_command_queue_is_answered_busy_at_once_but_never_holds_a_stop() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    daemon.draining.send_replace(false);
    let waiting = fill_the_queue(&daemon);
    assert_eq!(waiting.len(), COMMAND_QUEUE);

    let reply = c.request(json!({"cmd": "home", "id": "h1"})).await;
    assert_eq!((code(&reply), &reply["id"]), ("busy", &json!("h1")));
    let reply = c.request(json!({"cmd": "describe", "id": "d"})).await;
    assert_eq!(
        reply["ok"],
        json!(true),
        "the socket side still answers: {reply}"
    );
    // A stop goes through its own queue: it waits for the loop's next tick, not for room.
    c.send(&json!({"cmd": "stop", "id": "s1"})).await;
    c.send(&json!({"cmd": "estop", "id": "e1"})).await;
    time::timeout(DEADLINE, async {
        while daemon.handle.stops.capacity() > STOP_QUEUE - 2 {
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("stop and estop queued beside a full command queue");

    // Once the loop has taken what was queued, the client is served again.
    daemon.draining.send_replace(true);
    for answer in waiting {
        assert!(time::timeout(DEADLINE, answer).await.unwrap().is_ok());
    }
    for id in ["s1", "e1"] {
        let reply = c.reply().await;
        assert_eq!((&reply["ok"], &reply["id"]), (&json!(true), &json!(id)));
    }
    let reply = c.request(json!({"cmd": "home", "id": "h2"})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
}

#[tokio::test]
async fn commands_after_the_loop_ended_are_answered_shutting_down() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    assert_eq!(c.request(json!({"cmd": "stop"})).await["ok"], json!(true));
    daemon.fake.abort();
    let _ = daemon.fake.await;
    let reply = c.request(json!({"cmd": "home", "id": 1})).await;
    assert_eq!((code(&reply), &reply["id"]), ("shutting_down", &json!(1)));
    let reply = c.request(json!({"cmd": "describe", "id": 2})).await;
    assert_eq!(reply["ok"], json!(true));
}

/// The telemetry lines a client receives, each with the paused clock's time it came.
async fn telemetry_lines(c: &mut Client, n: usize) -> Vec<(Instant, Value)> {
    let mut lines = Vec::new();
    while lines.len() < n {
        let line = c.recv().await;
        if line["type"] == json!("telemetry") {
            lines.push((Instant::now(), line));
        }
    }
    lines
}

/// Publishes a new snapshot every millisecond, as a 1 kHz loop would.
fn publish_every_ms(telemetry: watch::Sender<Telemetry>) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut every = time::interval(Duration::from_millis(1));
        for tick in 1.. {
            every.tick().await;
            telemetry.send_modify(|t| {
                t.tick = tick;
                t.t_s = tick as f64 / 1000.0;
            });
        }
    })
}

#[tokio::test(start_paused = true)]
async fn subscribe_sends_telemetry_at_the_rate_asked() {
    let daemon = Daemon::new().await;
    let publisher = publish_every_ms(daemon.telemetry.clone());
    let mut c = daemon.client().await;
    let reply = c
        .request(json!({"cmd": "subscribe", "id": 1, "rate_hz": 10}))
        .await;
    assert_eq!(
        (&reply["ok"], &reply["rate_hz"]),
        (&json!(true), &json!(10.0))
    );
    let lines = telemetry_lines(&mut c, 11).await;
    let span = lines[10].0 - lines[0].0;
    assert!(
        (0.95..=1.05).contains(&span.as_secs_f64()),
        "11 lines at 10 Hz over {span:?}"
    );
    let ticks: Vec<u64> = lines
        .iter()
        .map(|(_, l)| l["tick"].as_u64().unwrap())
        .collect();
    assert!(ticks.windows(2).all(|w| w[1] > w[0]), "{ticks:?}");
    let fields = telemetry(0).to_fields();
    let mut expected: Vec<&str> = fields.keys().map(String::as_str).collect();
    expected.extend(["type", "controller", "in_control"]);
    expected.sort_unstable();
    let mut got: Vec<&str> = lines[0]
        .1
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    got.sort_unstable();
    assert_eq!(got, expected);
    publisher.abort();
}

#[tokio::test(start_paused = true)]
async fn subscribe_is_capped_at_the_loop_rate() {
    let daemon = Daemon::new().await;
    let publisher = publish_every_ms(daemon.telemetry.clone());
    let mut c = daemon.client().await;
    let reply = c
        .request(json!({"cmd": "subscribe", "id": 1, "rate_hz": 1000}))
        .await;
    assert_eq!(reply["rate_hz"], json!(LOOP_HZ), "{reply}");
    let lines = telemetry_lines(&mut c, 21).await;
    let span = lines[20].0 - lines[0].0;
    assert!(
        (0.19..=0.21).contains(&span.as_secs_f64()),
        "21 lines at {LOOP_HZ} Hz over {span:?}"
    );
    publisher.abort();
}

#[tokio::test(start_paused = true)]
async fn unchanged_telemetry_is_not_sent_again() {
    let daemon = Daemon::new().await;
    daemon.telemetry.send_replace(telemetry(5));
    let mut c = daemon.client().await;
    c.request(json!({"cmd": "subscribe", "rate_hz": 50})).await;
    let first = c.recv().await;
    assert_eq!(
        (&first["type"], &first["tick"]),
        (&json!("telemetry"), &json!(5))
    );
    let quiet = time::timeout(Duration::from_secs(2), c.lines.next_line()).await;
    assert!(quiet.is_err(), "a line though nothing changed: {quiet:?}");
    daemon.telemetry.send_replace(telemetry(6));
    let next = c.recv().await;
    assert_eq!(
        (&next["type"], &next["tick"]),
        (&json!("telemetry"), &json!(6))
    );
}

#[tokio::test(start_paused = true)]
async fn unsubscribe_stops_telemetry() {
    let daemon = Daemon::new().await;
    let publisher = publish_every_ms(daemon.telemetry.clone());
    let mut c = daemon.client().await;
    c.request(json!({"cmd": "subscribe", "rate_hz": 100})).await;
    telemetry_lines(&mut c, 5).await;
    c.send(&json!({"cmd": "unsubscribe", "id": "u"})).await;
    let reply = c.reply().await;
    assert_eq!((&reply["ok"], &reply["id"]), (&json!(true), &json!("u")));
    let quiet = time::timeout(Duration::from_secs(2), c.lines.next_line()).await;
    assert!(quiet.is_err(), "telemetry after unsubscribe: {quiet:?}");
    // Another client's subscription is its own.
    let mut other = daemon.client().await;
    other
        .request(json!({"cmd": "subscribe", "rate_hz": 100}))
        .await;
    telemetry_lines(&mut other, 3).await;
    let quiet = time::timeout(Duration::from_secs(1), c.lines.next_line()).await;
    assert!(quiet.is_err(), "{quiet:?}");
    publisher.abort();
}

fn event(owner: Option<u64>, kind: EventKind, tick: u64) -> Event {
    let tip = [0.25, -0.5];
    let fault = FaultInfo {
        id: Some(1),
        joint: Some(1),
        port: None,
        kind: FaultKind::Silent,
        since_tick: tick,
        detail: "no reply".into(),
    };
    let what = match kind {
        EventKind::Arrived => What::Arrived { tip },
        EventKind::Saturated => What::Saturated { tip },
        EventKind::Preempted => What::Preempted {
            tip,
            reason: CmdName::Goto,
        },
        EventKind::Stopped => What::Stopped {
            tip,
            reason: StopReason::Deadman,
        },
        EventKind::Estop => What::Estop { tip },
        EventKind::Reset => What::Reset { tip },
        EventKind::Fault => What::Fault {
            tip,
            reason: FaultChange::Raised,
            fault,
        },
        EventKind::Warning => What::Warning {
            tip,
            reason: FaultChange::Raised,
            fault,
        },
        EventKind::Control => What::Control {
            holder: None,
            previous: None,
        },
        EventKind::ShuttingDown => What::ShuttingDown { tip },
        EventKind::World => What::World {
            by: 1,
            world: Box::default(),
        },
        EventKind::NotClear => What::NotClear {
            tip,
            link: 2,
            obstacle: "post".into(),
            clearance_m: -0.01,
            keep_m: 0.005,
        },
        EventKind::Clear => What::Clear {
            tip,
            min_clearance_m: None,
        },
        EventKind::Blocked => What::Blocked {
            tip,
            link: 2,
            obstacle: "post".into(),
        },
    };
    Event {
        owner,
        cmd_id: owner.map(|o| Arc::new(json!(format!("cmd-of-{o}")))),
        tick,
        what,
    }
}

/// The event lines a client receives up to the one at `last_tick`.
async fn events_until(c: &mut Client, last_tick: u64) -> Vec<Value> {
    let mut events = Vec::new();
    loop {
        let line = c.recv().await;
        assert_eq!(line["type"], json!("event"), "{line}");
        let done = line["tick"] == json!(last_tick);
        events.push(line);
        if done {
            return events;
        }
    }
}

#[tokio::test]
async fn events_go_to_their_owner_or_to_everyone() {
    let daemon = Daemon::new().await;
    let mut a = daemon.client().await;
    let mut b = daemon.client().await;
    let id_a = a.request(json!({"cmd": "stop"})).await["client"]
        .as_u64()
        .unwrap();
    let id_b = b.request(json!({"cmd": "stop"})).await["client"]
        .as_u64()
        .unwrap();
    assert_ne!(id_a, id_b);
    assert!(id_a >= 1 && id_b >= 1);

    for e in [
        event(Some(id_a), EventKind::Arrived, 1),
        event(Some(id_b), EventKind::Stopped, 2),
        event(None, EventKind::Estop, 3),
        event(Some(id_a + id_b + 100), EventKind::Preempted, 4),
        event(None, EventKind::Reset, 5),
    ] {
        daemon.events.send(e).unwrap();
    }
    let seen_a = events_until(&mut a, 5).await;
    let seen_b = events_until(&mut b, 5).await;
    let ticks = |seen: &[Value]| {
        seen.iter()
            .map(|e| e["tick"].as_u64().unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(ticks(&seen_a), [1, 3, 5]);
    assert_eq!(ticks(&seen_b), [2, 3, 5]);
    assert_eq!(
        seen_a[0],
        json!({"type": "event", "event": "arrived", "cmd_id": format!("cmd-of-{id_a}"),
               "tick": 1, "tip": [0.25, -0.5]})
    );
    assert_eq!(seen_b[0]["reason"], json!("deadman"));
    assert_eq!(
        seen_b[1],
        json!({"type": "event", "event": "estop", "tick": 3, "tip": [0.25, -0.5]})
    );
}

#[tokio::test]
async fn a_client_behind_on_events_continues() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    c.request(json!({"cmd": "stop"})).await;
    // While the client waits for the loop, more events come than its receiver holds.
    daemon.draining.send_replace(false);
    c.send(&json!({"cmd": "stop", "id": "held"})).await;
    let flood = link::EVENT_QUEUE as u64 * 2;
    // The request reaches the queue before the flood, so the client task is waiting on it.
    time::timeout(DEADLINE, async {
        while daemon.handle.stops.capacity() == STOP_QUEUE {
            tokio::task::yield_now().await;
        }
    })
    .await
    .unwrap();
    for tick in 1..=flood {
        daemon
            .events
            .send(event(None, EventKind::Fault, tick))
            .unwrap();
    }
    daemon.draining.send_replace(true);
    let reply = c.reply().await;
    assert_eq!((&reply["ok"], &reply["id"]), (&json!(true), &json!("held")));
    let seen = events_until(&mut c, flood).await;
    assert!(
        seen.len() <= link::EVENT_QUEUE,
        "{} events kept of {flood}",
        seen.len()
    );
    daemon
        .events
        .send(event(None, EventKind::Control, flood + 1))
        .unwrap();
    assert_eq!(events_until(&mut c, flood + 1).await.len(), 1);
}

#[tokio::test]
async fn over_the_limit_only_a_stop_or_an_estop_is_taken() {
    let options = ServerOptions {
        auth_grace: Duration::from_millis(300),
        ..ServerOptions::new(JOINTS, 2)
    };
    let daemon = Daemon::start(options, describe(JOINTS)).await;
    let mut a = daemon.client().await;
    let mut b = daemon.client().await;
    assert_eq!(
        a.request(json!({"cmd": "describe"})).await["ok"],
        json!(true)
    );
    assert_eq!(
        b.request(json!({"cmd": "describe"})).await["ok"],
        json!(true)
    );

    // Anything else is refused, answering its id, and the connection closed.
    let mut c = daemon.client().await;
    let refused = c.request(json!({"cmd": "describe", "id": "d3"})).await;
    assert_eq!(
        (code(&refused), &refused["id"]),
        ("too_many_clients", &json!("d3"))
    );
    assert!(message(&refused).contains('2'), "{refused}");
    assert!(c.closed().await);
    // A stop and an estop are carried out and answered; then the connection closes.
    for cmd in ["stop", "estop"] {
        let mut c = daemon.client().await;
        let reply = c.request(json!({"cmd": cmd, "id": cmd})).await;
        assert_eq!(
            (&reply["ok"], &reply["id"]),
            (&json!(true), &json!(cmd)),
            "{reply}"
        );
        assert_eq!(reply["cmd"], json!(cmd), "the loop applied it: {reply}");
        assert!(c.closed().await);
    }
    // Silence past the first-line deadline is refused too.
    let mut silent = daemon.client().await;
    let refused = silent.recv().await;
    assert_eq!(code(&refused), "too_many_clients");
    assert_eq!(refused["id"], Value::Null);
    assert!(silent.closed().await);

    // The others go on; one leaving makes room.
    assert_eq!(a.request(json!({"cmd": "stop"})).await["ok"], json!(true));
    drop(b);
    let served = time::timeout(DEADLINE, async {
        loop {
            let mut d = daemon.client().await;
            d.send(&json!({"cmd": "describe", "id": "d"})).await;
            if d.recv().await["ok"] == json!(true) {
                return;
            }
            tokio::task::yield_now().await;
        }
    })
    .await;
    assert!(served.is_ok(), "no room after a client left");
}

#[tokio::test]
async fn a_client_that_does_not_read_is_dropped_and_the_others_go_on() {
    // A long describe makes every reply large, so the flood outgrows the socket buffers fast.
    let options = ServerOptions {
        client_queue: 16,
        ..ServerOptions::new(JOINTS, 8)
    };
    let daemon = Daemon::start(options, describe(2000)).await;
    let mut good = daemon.client().await;
    let socket = TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let stuck = socket.connect(daemon.addr).await.unwrap();
    let (stuck_read, mut stuck_write) = stuck.into_split();
    // Requests until writing fails: the server closed the connection. Nothing is ever read.
    let flood = tokio::spawn(async move {
        let lines = b"{\"cmd\":\"describe\"}\n".repeat(50);
        let mut sent = 0usize;
        while stuck_write.write_all(&lines).await.is_ok() {
            sent += 50;
        }
        sent
    });

    // Meanwhile the other client is served.
    for i in 0..20 {
        let reply = good.request(json!({"cmd": "stop", "id": i})).await;
        assert_eq!(reply["id"], json!(i), "{reply}");
    }
    let sent = time::timeout(DEADLINE, flood)
        .await
        .expect("the server closes the connection of a client that does not read")
        .unwrap();
    assert!(sent > 16, "{sent} requests");
    drop(stuck_read);
    let reply = good.request(json!({"cmd": "status", "id": "after"})).await;
    assert_eq!(reply["id"], json!("after"));
}

#[tokio::test]
async fn a_connection_that_says_nothing_is_closed_after_the_first_line_deadline() {
    let options = ServerOptions {
        auth_grace: Duration::from_millis(300),
        ..ServerOptions::new(JOINTS, 8)
    };
    let daemon = Daemon::start(options, describe(JOINTS)).await;
    let mut silent = daemon.client().await;
    let mut talker = daemon.client().await;
    assert_eq!(
        talker.request(json!({"cmd": "describe"})).await["ok"],
        json!(true)
    );
    let started = Instant::now();
    assert!(silent.closed().await, "closed without a word");
    assert!(started.elapsed() >= Duration::from_millis(200));
    // One line is enough: a client that spoke may listen as long as it likes.
    time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        talker.request(json!({"cmd": "describe"})).await["ok"],
        json!(true)
    );
}

#[tokio::test]
async fn shutdown_closes_the_connections_and_returns() {
    let mut daemon = Daemon::new().await;
    let mut quiet = daemon.client().await;
    let mut subscribed = daemon.client().await;
    assert_eq!(
        quiet.request(json!({"cmd": "stop"})).await["ok"],
        json!(true)
    );
    subscribed
        .request(json!({"cmd": "subscribe", "rate_hz": 100}))
        .await;
    daemon.shut_down().await.unwrap();
    assert!(quiet.closed().await);
    assert!(subscribed.closed().await);
    assert!(
        TcpStream::connect(daemon.addr).await.is_err(),
        "still accepting after shutdown"
    );
    // The socket side let go of the loop's command queue.
    assert_eq!(Arc::strong_count(&daemon.handle.describe), 1);
}

#[tokio::test]
async fn shutdown_returns_while_the_loop_holds_a_command() {
    let mut daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    assert_eq!(c.request(json!({"cmd": "stop"})).await["ok"], json!(true));
    daemon.draining.send_replace(false);
    c.send(&json!({"cmd": "home", "id": "never answered"}))
        .await;
    time::timeout(DEADLINE, async {
        while daemon.handle.commands.capacity() == COMMAND_QUEUE {
            tokio::task::yield_now().await;
        }
    })
    .await
    .unwrap();
    daemon.shut_down().await.unwrap();
    assert!(c.closed().await);
}

/// This client's id, from a `release` (which changes nothing when it holds no control).
async fn client_id(c: &mut Client) -> u64 {
    let reply = c.request(json!({"cmd": "release"})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    reply["client"].as_u64().unwrap()
}

/// The next `control` event line, skipping other lines.
async fn next_control(c: &mut Client) -> Value {
    loop {
        let line = c.recv().await;
        if line["type"] == json!("event") && line["event"] == json!("control") {
            return line;
        }
    }
}

/// Sends `request`; its reply and the `control` event it causes, in whichever order they come.
async fn request_and_control(c: &mut Client, request: Value) -> (Value, Value) {
    c.send(&request).await;
    let (mut reply, mut event) = (None, None);
    while reply.is_none() || event.is_none() {
        let line = c.recv().await;
        if line.get("type").is_none() {
            reply = Some(line);
        } else if line["event"] == json!("control") {
            event = Some(line);
        }
    }
    (reply.unwrap(), event.unwrap())
}

fn control_event(holder: Option<u64>, previous: Option<u64>, cmd_id: Option<&str>) -> Value {
    let mut event = json!({"type": "event", "event": "control", "holder": holder,
                           "previous": previous, "tick": 0});
    if let Some(id) = cmd_id {
        event["cmd_id"] = json!(id);
    }
    event
}

#[tokio::test]
async fn the_first_motion_takes_control_and_the_others_must_take_it() {
    let daemon = Daemon::new().await;
    let mut a = daemon.client().await;
    let mut b = daemon.client().await;
    let id_a = client_id(&mut a).await;
    let id_b = client_id(&mut b).await;

    // Nobody holds control: a's goto takes it, and everyone is told.
    let (reply, event) = request_and_control(
        &mut a,
        json!({"cmd": "goto", "id": "g1", "target": [0.1, 0.1]}),
    )
    .await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(event, control_event(Some(id_a), None, Some("g1")));
    assert_eq!(
        next_control(&mut b).await,
        control_event(Some(id_a), None, Some("g1"))
    );

    // b is refused, told who holds control and how to take it; stopping is never refused.
    let reply = b
        .request(json!({"cmd": "velocity", "id": "v", "v": [0.01, 0.0]}))
        .await;
    assert_eq!(
        (code(&reply), &reply["id"]),
        ("not_in_control", &json!("v"))
    );
    assert!(
        message(&reply).contains(&format!("client {id_a}")),
        "{reply}"
    );
    assert!(message(&reply).contains("take_control"), "{reply}");
    for cmd in ["stop", "estop", "describe", "status"] {
        let reply = b.request(json!({"cmd": cmd})).await;
        assert_ne!(reply["ok"], json!(false), "{cmd}: {reply}");
    }
    let status_a = a.request(json!({"cmd": "status"})).await;
    let status_b = b.request(json!({"cmd": "status"})).await;
    assert_eq!(
        (&status_a["controller"], &status_a["in_control"]),
        (&json!(id_a), &json!(true))
    );
    assert_eq!(
        (&status_b["controller"], &status_b["in_control"]),
        (&json!(id_a), &json!(false))
    );

    // b takes control: both hear of it, and a is refused from then on.
    let (reply, event) =
        request_and_control(&mut b, json!({"cmd": "take_control", "id": "t"})).await;
    assert_eq!(
        reply,
        json!({"id": "t", "ok": true, "client": id_b, "holder": id_b, "previous": id_a})
    );
    assert_eq!(event, control_event(Some(id_b), Some(id_a), Some("t")));
    assert_eq!(
        next_control(&mut a).await,
        control_event(Some(id_b), Some(id_a), Some("t"))
    );
    let reply = a.request(json!({"cmd": "home", "id": 5})).await;
    assert_eq!(code(&reply), "not_in_control");
    assert!(
        message(&reply).contains(&format!("client {id_b}")),
        "{reply}"
    );
    // Taking what one holds, or releasing what one does not, changes nothing.
    let reply = b.request(json!({"cmd": "take_control"})).await;
    assert_eq!(
        (&reply["holder"], &reply["previous"]),
        (&json!(id_b), &json!(id_b))
    );
    let reply = a.request(json!({"cmd": "release"})).await;
    assert_eq!(reply["holder"], json!(id_b), "{reply}");

    // b releases: control is free, and a's next motion takes it.
    let (reply, event) = request_and_control(&mut b, json!({"cmd": "release", "id": "r"})).await;
    assert_eq!(
        reply,
        json!({"id": "r", "ok": true, "client": id_b, "holder": null})
    );
    assert_eq!(event, control_event(None, Some(id_b), Some("r")));
    assert_eq!(
        next_control(&mut a).await,
        control_event(None, Some(id_b), Some("r"))
    );
    let (reply, _) = request_and_control(&mut a, json!({"cmd": "home", "id": "h"})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(
        next_control(&mut b).await,
        control_event(Some(id_a), None, Some("h"))
    );

    // The holder leaving frees control.
    drop(a);
    assert_eq!(
        next_control(&mut b).await,
        control_event(None, Some(id_a), None)
    );
    let (reply, event) = request_and_control(&mut b, json!({"cmd": "reset", "id": 1})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(event["holder"], json!(id_b));
}

#[tokio::test]
async fn a_refused_command_never_reaches_the_loop() {
    let daemon = Daemon::new().await;
    let mut holder = daemon.client().await;
    let mut other = daemon.client().await;
    holder.request(json!({"cmd": "take_control"})).await;
    let before = holder.request(json!({"cmd": "stop"})).await["tick"]
        .as_u64()
        .unwrap();
    let needs_control = [
        json!({"cmd": "goto", "target": [0.1, 0.1]}),
        json!({"cmd": "goto_joints", "theta": [0, 0, 0]}),
        json!({"cmd": "path", "points": [[0.1, 0.1]]}),
        json!({"cmd": "velocity", "v": [0.0, 0.01]}),
        json!({"cmd": "jog", "joint": 1, "rad_s": 0.1}),
        json!({"cmd": "home"}),
        json!({"cmd": "strategy", "name": "sequential"}),
        json!({"cmd": "reset"}),
        json!({"cmd": "torque", "on": false}),
        json!({"cmd": "reboot", "ids": [1]}),
        json!({"cmd": "reboot"}),
    ];
    for request in &needs_control {
        let reply = other.request(request.clone()).await;
        assert_eq!(code(&reply), "not_in_control", "{request}: {reply}");
    }
    // The fake loop counts what it answers: nothing of the other client's came.
    let after = holder.request(json!({"cmd": "stop"})).await["tick"]
        .as_u64()
        .unwrap();
    assert_eq!(after, before + 1);
    // The holder's own are served.
    for request in needs_control {
        let reply = holder.request(request.clone()).await;
        assert_ne!(code_or_ok(&reply), "not_in_control", "{request}: {reply}");
    }
}

fn code_or_ok(reply: &Value) -> &str {
    reply["error"]["code"].as_str().unwrap_or("ok")
}

#[tokio::test]
async fn a_command_answered_busy_takes_no_control() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let mut other = daemon.client().await;
    daemon.draining.send_replace(false);
    let waiting = fill_the_queue(&daemon);
    let reply = c.request(json!({"cmd": "home", "id": 1})).await;
    assert_eq!(code(&reply), "busy");
    assert_eq!(
        c.request(json!({"cmd": "release"})).await["holder"],
        Value::Null
    );
    daemon.draining.send_replace(true);
    for answer in waiting {
        assert!(time::timeout(DEADLINE, answer).await.unwrap().is_ok());
    }
    let reply = other.request(json!({"cmd": "home", "id": 2})).await;
    assert_eq!(reply["ok"], json!(true), "control was free: {reply}");
}

#[tokio::test]
async fn telemetry_tells_each_client_who_is_in_control() {
    let daemon = Daemon::new().await;
    let publisher = publish_every_ms(daemon.telemetry.clone());
    let mut a = daemon.client().await;
    let mut b = daemon.client().await;
    let id_a = client_id(&mut a).await;
    for c in [&mut a, &mut b] {
        c.request(json!({"cmd": "subscribe", "rate_hz": 100})).await;
        let line = c.recv().await;
        assert_eq!(line["type"], json!("telemetry"), "{line}");
        assert_eq!(
            (&line["controller"], &line["in_control"]),
            (&Value::Null, &json!(false))
        );
    }
    a.request(json!({"cmd": "take_control"})).await;
    for (c, mine) in [(&mut a, true), (&mut b, false)] {
        let line = loop {
            let line = c.recv().await;
            if line["type"] == json!("telemetry") && line["controller"] == json!(id_a) {
                break line;
            }
        };
        assert_eq!(line["in_control"], json!(mine), "{line}");
    }
    publisher.abort();
}

fn with_token(token: &str) -> ServerOptions {
    ServerOptions {
        auth_grace: Duration::from_millis(300),
        ..ServerOptions::new(JOINTS, 8).with_token(Token::new(token))
    }
}

/// Every line until the server closes the connection.
async fn lines_until_closed(c: &mut Client) -> Vec<Value> {
    let mut lines = Vec::new();
    while let Ok(Some(line)) = time::timeout(DEADLINE, c.lines.next_line())
        .await
        .expect("closed within the deadline")
    {
        lines.push(serde_json::from_str(&line).unwrap());
    }
    lines
}

#[tokio::test]
async fn with_a_token_the_first_line_must_be_auth_with_it() {
    let daemon = Daemon::start(with_token("s3cret"), describe(JOINTS)).await;

    // A silent client is told after the grace and closed; it hears no event meanwhile.
    let mut silent = daemon.client().await;
    // One that asks for something else first.
    let mut eager = daemon.client().await;
    eager.send(&json!({"cmd": "status", "id": 1})).await;
    // One with the wrong token.
    let mut wrong = daemon.client().await;
    wrong
        .send(&json!({"cmd": "auth", "id": "a", "token": "s3creT"}))
        .await;
    // One that sends garbage.
    let mut garbage = daemon.client().await;
    garbage.send_raw(b"{\"cmd\":\n").await;

    // The right token, after a blank line, is admitted; later lines are served.
    let mut good = daemon.client().await;
    good.send_raw(b"\n").await;
    let reply = good
        .request(json!({"cmd": "auth", "id": "ok", "token": "s3cret"}))
        .await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert!(reply["client"].as_u64().is_some(), "{reply}");
    let reply = good.request(json!({"cmd": "stop"})).await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    daemon
        .events
        .send(event(None, EventKind::Estop, 9))
        .unwrap();
    assert_eq!(events_until(&mut good, 9).await.len(), 1);

    for (c, id, words) in [
        (&mut eager, json!(1), &["`auth`", "`status`"][..]),
        (&mut wrong, json!("a"), &["wrong token"][..]),
        (&mut garbage, Value::Null, &["`auth`"][..]),
        (&mut silent, Value::Null, &["`auth`", "0.3 s"][..]),
    ] {
        let lines = lines_until_closed(c).await;
        assert_eq!(lines.len(), 1, "one line, then closed: {lines:?}");
        assert_eq!(code(&lines[0]), "unauthorized", "{lines:?}");
        assert_eq!(lines[0]["id"], id);
        for word in words {
            assert!(message(&lines[0]).contains(word), "{lines:?} lacks {word}");
        }
    }

    // A later `auth` with a wrong token closes an admitted connection too.
    let reply = good
        .request(json!({"cmd": "auth", "token": "s3cret"}))
        .await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    good.send(&json!({"cmd": "auth", "id": 2, "token": "guess"}))
        .await;
    let lines = lines_until_closed(&mut good).await;
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert_eq!(code(&lines[0]), "unauthorized");
}

#[tokio::test]
async fn without_a_token_auth_is_answered_ok() {
    let daemon = Daemon::new().await;
    let mut c = daemon.client().await;
    let reply = c
        .request(json!({"cmd": "auth", "id": 1, "token": "anything"}))
        .await;
    assert_eq!(reply["ok"], json!(true), "{reply}");
    let id = reply["client"].as_u64().unwrap();
    assert_eq!(client_id(&mut c).await, id);
}

/// The shipped simulator config as if read from its place, with `edits` applied.
fn sim_config(edits: &[(&str, &str)]) -> Config {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(path).unwrap();
    for (old, new) in edits {
        assert!(text.contains(old), "config/sim.toml has no `{old}`");
        text = text.replace(old, new);
    }
    Config::from_str(&text, path).unwrap()
}

/// `daemon::run`'s error for `config` on `listener`, which must come before the bus is opened.
async fn refused_at_start(config: Config, listener: TcpListener) -> DaemonError {
    let run = daemon::run(
        config,
        listener,
        RunOptions::port("/nonexistent/port/never/opened"),
        std::future::pending(),
    );
    match time::timeout(DEADLINE, run).await.expect("refused at once") {
        Ok(summary) => panic!("ran: {summary:?}"),
        Err(e) => e,
    }
}

#[tokio::test]
async fn start_up_refuses_an_unusable_token_file_naming_it() {
    let dir = std::env::temp_dir().join(format!("snakectl-server-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let empty = dir.join("empty-token");
    std::fs::write(&empty, "\n\nsecond\n").unwrap();
    let missing = dir.join("missing-token");
    for (file, word) in [(&empty, "empty"), (&missing, "cannot read")] {
        let line = format!("max_clients = 4\ntoken_file = {:?}", file.to_str().unwrap());
        let config = sim_config(&[("max_clients = 4", &line)]);
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let e = refused_at_start(config, listener).await;
        assert!(matches!(e, DaemonError::Access(_)), "{e}");
        let message = e.to_string();
        assert!(message.contains(file.to_str().unwrap()), "{message}");
        assert!(message.contains(word), "{message}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn start_up_refuses_to_listen_beyond_loopback_without_a_token() {
    let listener = TcpListener::bind("0.0.0.0:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let e = refused_at_start(sim_config(&[]), listener).await;
    assert!(
        matches!(e, DaemonError::Access(AccessError::Exposed { addr: a }) if a == addr),
        "{e}"
    );
    let message = e.to_string();
    assert!(message.contains("token_file"), "{message}");
    assert!(message.contains("loopback"), "{message}");
}

#[cfg(not(feature = "zenoh"))]
#[tokio::test]
async fn start_up_refuses_zenoh_enabled_in_a_build_without_it() {
    let config = sim_config(&[(
        "max_clients = 4",
        "max_clients = 4\n\n[zenoh]\nenabled = true\nlisten = [\"tcp/127.0.0.1:0\"]",
    )]);
    assert!(config.zenoh().enabled);
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let e = refused_at_start(config, listener).await;
    assert!(matches!(e, DaemonError::ZenohNotBuilt { .. }), "{e}");
    let message = e.to_string();
    assert!(message.contains("config/sim.toml"), "{message}");
    assert!(message.contains("[zenoh] enabled = true"), "{message}");
    assert!(message.contains("--features zenoh"), "{message}");
}

#[tokio::test(start_paused = true)]
async fn unsubscribe_after_subscribe_behind_a_loop_reply_leaves_no_telemetry() {
    let daemon = Daemon::new().await;
    let publisher = publish_every_ms(daemon.telemetry.clone());
    let mut c = daemon.client().await;
    // The loop holds the `status`, so the `subscribe` reply waits behind it.
    daemon.draining.send_replace(false);
    let mut burst = String::new();
    for request in [
        json!({"cmd": "status", "id": 1}),
        json!({"cmd": "subscribe", "id": 2, "rate_hz": 100}),
        json!({"cmd": "unsubscribe", "id": 3}),
    ] {
        burst.push_str(&request.to_string());
        burst.push('\n');
    }
    c.send_raw(burst.as_bytes()).await;
    time::sleep(Duration::from_millis(100)).await;
    daemon.draining.send_replace(true);
    for id in 1..=3 {
        let reply = c.reply().await;
        assert_eq!((&reply["ok"], &reply["id"]), (&json!(true), &json!(id)));
    }
    let quiet = time::timeout(Duration::from_secs(2), c.lines.next_line()).await;
    assert!(quiet.is_err(), "telemetry after unsubscribe: {quiet:?}");
    publisher.abort();
}

#[tokio::test]
async fn a_stop_is_not_refused_busy_for_stops_the_loop_has_answered() {
    // Large replies and a small receive buffer: a client slow to read holds its replies back.
    let options = ServerOptions {
        client_queue: 16,
        ..ServerOptions::new(JOINTS, 8)
    };
    let daemon = Daemon::start(options, describe(2000)).await;
    let socket = TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut c = Client::from_stream(socket.connect(daemon.addr).await.unwrap());
    let mut burst = "{\"cmd\":\"describe\"}\n".repeat(30);
    for i in 0..STOPS_IN_FLIGHT {
        burst.push_str(&json!({"cmd": "stop", "id": i}).to_string());
        burst.push('\n');
    }
    // A motion after those stops, applied by the loop: the arm moves.
    burst.push_str(&json!({"cmd": "goto", "id": "go", "target": [0.1, 0.1]}).to_string());
    burst.push('\n');
    c.send_raw(burst.as_bytes()).await;
    // The loop answers those commands within a few milliseconds; their replies wait behind the
    // describes the client has not read yet. No stop waits for the loop any more.
    time::sleep(Duration::from_millis(200)).await;
    c.send(&json!({"cmd": "stop", "id": "late"})).await;
    time::sleep(Duration::from_millis(100)).await;
    let late = loop {
        let reply = c.reply().await;
        if reply["id"] == json!("late") {
            break reply;
        }
    };
    assert_eq!(late["ok"], json!(true), "{late}");
}
