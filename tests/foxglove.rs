//! The live Foxglove view, against the simulator on a real pseudo-terminal: a WebSocket client
//! speaking Foxglove's protocol (subprotocol `foxglove.sdk.v1`, JSON control messages, binary
//! message data) sees the server's info and every channel's advertisement, subscribes, and
//! reads the arm; a `Twist` it publishes moves the tip only with `accept_commands`. The view and
//! the recorder run below the loop's priority.
//! Timing is bounded by deadlines, never asserted in wall-clock speed.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::collections::BTreeMap;
use std::net::TcpListener;
use std::time::{Duration, Instant};

use daemon_support::child::DaemonChild;
#[cfg(target_os = "linux")]
use daemon_support::threads_at;
use daemon_support::{dist, floats, sim_config, xy, Daemon, DEADLINE};
use foxglove::schemas::SceneUpdate;
use foxglove::Decode;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use snakectl::config::Config;
use snakectl::ros::{self, JointState};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

/// A port nobody listens on now (the system's pick for port 0, released).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The shipped simulator config with a `[foxglove]` table on `port`.
fn config(port: u16, accept_commands: bool) -> Config {
    let table =
        format!("[foxglove]\nlisten = \"127.0.0.1:{port}\"\naccept_commands = {accept_commands}\n");
    sim_config(&[("max_clients = 4", &format!("max_clients = 4\n\n{table}"))])
}

/// A daemon with the view on, brought up, and the view's port.
fn start_daemon(accept_commands: bool) -> (Daemon, u16) {
    let port = free_port();
    let daemon = Daemon::start(config(port, accept_commands));
    // The first reply waits for bring-up, after which the view serves.
    daemon.client().status();
    (daemon, port)
}

/// One message the server sent on a subscription.
struct Data {
    subscription: u32,
    log_time: u64,
    payload: Vec<u8>,
}

/// A blocking Foxglove client: a WebSocket on a runtime of its own.
struct Fox {
    runtime: tokio::runtime::Runtime,
    ws: WebSocketStream<MaybeTlsStream<TcpStream>>,
    /// Channels advertised: topic -> the advertisement.
    channels: BTreeMap<String, Value>,
    /// Control messages read while waiting for something else.
    control: Vec<Value>,
}

impl Fox {
    /// Connects asking for `subprotocol`; `Err` with the server's refusal.
    fn try_connect(port: u16, subprotocol: &str) -> Result<Fox, String> {
        Fox::try_url(&format!("ws://127.0.0.1:{port}"), subprotocol)
    }

    /// Connects to `url` asking for `subprotocol`; `Err` with the server's refusal.
    fn try_url(url: &str, subprotocol: &str) -> Result<Fox, String> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let mut request = url.into_client_request().unwrap();
        request.headers_mut().insert(
            "sec-websocket-protocol",
            HeaderValue::from_str(subprotocol).unwrap(),
        );
        let ws = runtime
            .block_on(tokio_tungstenite::connect_async(request))
            .map_err(|e| e.to_string())?
            .0;
        Ok(Fox {
            runtime,
            ws,
            channels: BTreeMap::new(),
            control: Vec::new(),
        })
    }

    fn connect(port: u16) -> Fox {
        Fox::try_connect(port, "foxglove.sdk.v1").unwrap()
    }

    /// Its end of the connection: the peer the daemon names in its log.
    fn local_addr(&self) -> std::net::SocketAddr {
        match self.ws.get_ref() {
            MaybeTlsStream::Plain(stream) => stream.local_addr().unwrap(),
            _ => unreachable!("no TLS here"),
        }
    }

    /// The next frame within the deadline.
    fn next(&mut self, deadline: Instant) -> Message {
        let left = deadline.saturating_duration_since(Instant::now());
        let ws = &mut self.ws;
        match self
            .runtime
            .block_on(async { tokio::time::timeout(left, ws.next()).await })
        {
            Ok(Some(Ok(message))) => message,
            Ok(other) => panic!("the connection ended: {other:?}"),
            Err(_) => panic!("nothing from the server within the deadline"),
        }
    }

    /// Reads until a control message with `op` (advertisements are kept as they pass).
    fn next_op(&mut self, op: &str) -> Value {
        let deadline = Instant::now() + DEADLINE;
        loop {
            if let Message::Text(text) = self.next(deadline) {
                let v: Value = serde_json::from_str(text.as_str()).unwrap();
                self.note(&v);
                if v["op"] == op {
                    return v;
                }
                self.control.push(v);
            }
        }
    }

    fn note(&mut self, v: &Value) {
        if v["op"] == "advertise" {
            for c in v["channels"].as_array().unwrap() {
                self.channels
                    .insert(c["topic"].as_str().unwrap().to_owned(), c.clone());
            }
        }
    }

    /// Reads until every topic of `topics` has been advertised.
    fn advertised(&mut self, topics: &[&str]) {
        while !topics.iter().all(|t| self.channels.contains_key(*t)) {
            self.next_op("advertise");
        }
    }

    fn send(&mut self, message: Message) {
        let ws = &mut self.ws;
        self.runtime.block_on(ws.send(message)).unwrap();
    }

    fn send_json(&mut self, v: Value) {
        self.send(Message::text(v.to_string()));
    }

    /// Subscribes to `topics`, subscription ids from 1 in their order.
    fn subscribe(&mut self, topics: &[&str]) {
        self.subscribe_from(1, topics);
    }

    /// Subscribes to `topics`, subscription ids from `first` in their order.
    fn subscribe_from(&mut self, first: usize, topics: &[&str]) {
        let subscriptions: Vec<Value> = topics
            .iter()
            .enumerate()
            .map(|(i, t)| json!({"id": first + i, "channelId": self.channels[*t]["id"]}))
            .collect();
        self.send_json(json!({"op": "subscribe", "subscriptions": subscriptions}));
    }

    /// The next message data frame (op 1: subscription id, log time, payload).
    fn data(&mut self) -> Data {
        let deadline = Instant::now() + DEADLINE;
        loop {
            match self.next(deadline) {
                Message::Binary(bytes) if bytes.first() == Some(&1) => {
                    return Data {
                        subscription: u32::from_le_bytes(bytes[1..5].try_into().unwrap()),
                        log_time: u64::from_le_bytes(bytes[5..13].try_into().unwrap()),
                        payload: bytes[13..].to_vec(),
                    };
                }
                Message::Text(text) => {
                    let v: Value = serde_json::from_str(text.as_str()).unwrap();
                    self.note(&v);
                    self.control.push(v);
                }
                _ => {}
            }
        }
    }

    /// Advertises a `Twist` channel on `topic` (client channel 1) in JSON.
    fn advertise_twist(&mut self, topic: &str) {
        self.send_json(json!({"op": "advertise", "channels": [{
            "id": 1, "topic": topic, "encoding": "json", "schemaName": "geometry_msgs/msg/Twist",
        }]}));
    }

    /// Publishes a `Twist` of linear velocity `v` on client channel 1, as Teleop does.
    fn publish_twist(&mut self, v: [f64; 2]) {
        let twist = json!({"linear": {"x": v[0], "y": v[1], "z": 0.0},
                           "angular": {"x": 0.0, "y": 0.0, "z": 0.0}});
        let mut frame = vec![1u8];
        frame.extend_from_slice(&1u32.to_le_bytes());
        frame.extend_from_slice(twist.to_string().as_bytes());
        self.send(Message::binary(frame));
    }
}

/// Publishes on client channel `id` (advertised in JSON as `schema` on `topic`) the JSON
/// message `message`.
fn publish_on(fox: &mut Fox, id: u32, topic: &str, schema: &str, message: &Value) {
    fox.send_json(json!({"op": "advertise", "channels": [{
        "id": id, "topic": topic, "encoding": "json", "schemaName": schema,
    }]}));
    let mut frame = vec![1u8];
    frame.extend_from_slice(&id.to_le_bytes());
    frame.extend_from_slice(message.to_string().as_bytes());
    fox.send(Message::binary(frame));
}

const TOPICS: [&str; 8] = [
    "/snakectl/joint_states",
    "/snakectl/tip_cmd",
    "/snakectl/tip_meas",
    "/snakectl/target",
    "/snakectl/telemetry",
    "/snakectl/events",
    "/snakectl/log",
    "/snakectl/scene",
];

#[test]
fn a_foxglove_client_sees_every_channel_and_the_arm() {
    let (daemon, port) = start_daemon(false);
    let mut fox = Fox::connect(port);
    let info = fox.next_op("serverInfo");
    let capabilities = info["capabilities"].as_array().unwrap();
    assert!(
        !capabilities.iter().any(|c| c == "clientPublish"),
        "no publishing without accept_commands: {info}"
    );
    fox.advertised(&TOPICS);
    let expect = [
        (
            "/snakectl/joint_states",
            "cdr",
            "sensor_msgs/msg/JointState",
            "ros2msg",
        ),
        (
            "/snakectl/tip_meas",
            "cdr",
            "geometry_msgs/msg/PointStamped",
            "ros2msg",
        ),
        (
            "/snakectl/target",
            "cdr",
            "geometry_msgs/msg/PointStamped",
            "ros2msg",
        ),
        (
            "/snakectl/telemetry",
            "json",
            "snakectl.Telemetry",
            "jsonschema",
        ),
        ("/snakectl/events", "json", "snakectl.Event", "jsonschema"),
        ("/snakectl/log", "protobuf", "foxglove.Log", "protobuf"),
        (
            "/snakectl/scene",
            "protobuf",
            "foxglove.SceneUpdate",
            "protobuf",
        ),
    ];
    for (topic, encoding, schema_name, schema_encoding) in expect {
        let c = &fox.channels[topic];
        assert_eq!(c["encoding"], encoding, "{c}");
        assert_eq!(c["schemaName"], schema_name, "{c}");
        assert_eq!(c["schemaEncoding"], schema_encoding, "{c}");
    }
    let js_schema = fox.channels["/snakectl/joint_states"]["schema"]
        .as_str()
        .unwrap();
    assert!(
        js_schema.contains("MSG: builtin_interfaces/Time"),
        "{js_schema}"
    );

    fox.subscribe(&[
        "/snakectl/joint_states",
        "/snakectl/telemetry",
        "/snakectl/scene",
    ]);
    // One publish sends the three from one snapshot, under one log time.
    let mut by_time: BTreeMap<u64, [Option<Vec<u8>>; 3]> = BTreeMap::new();
    let (joints, telemetry, scene) = loop {
        let d = fox.data();
        let slot = (d.subscription - 1) as usize;
        let entry = by_time.entry(d.log_time).or_default();
        entry[slot] = Some(d.payload);
        if let [Some(j), Some(t), Some(s)] = entry {
            break (j.clone(), t.clone(), s.clone());
        }
    };
    let joints: JointState = ros::decode(&joints).unwrap();
    let telemetry: Value = serde_json::from_slice(&telemetry).unwrap();
    assert_eq!(telemetry["type"], "telemetry");
    let theta = floats(&telemetry["theta_meas"]);
    assert_eq!(
        joints.position, theta,
        "the JointState is the telemetry's angles"
    );
    assert_eq!(joints.name.len(), daemon.config.chain().len());
    assert_eq!(joints.name[0], "joint_1");

    // The scene's measured arm ends at the telemetry's measured tip.
    let scene = SceneUpdate::decode(&scene[..]).unwrap();
    let arm = scene.entities.iter().find(|e| e.id == "arm_meas").unwrap();
    assert_eq!(arm.frame_id, "base");
    let end = arm.lines[0].points.last().unwrap();
    let tip = xy(&telemetry["tip_meas"]);
    assert!(dist([end.x, end.y], tip) < 1e-9, "{end:?} vs {tip:?}");
    for id in [
        "arm_cmd",
        "tip_cmd",
        "tip_meas",
        "trail",
        "reach",
        "obstacles",
    ] {
        assert!(scene.entities.iter().any(|e| e.id == id), "no {id}");
    }

    // At rest, the scene keeps coming: a client that joins late sees the arm.
    let mut late = Fox::connect(port);
    late.advertised(&["/snakectl/scene"]);
    late.subscribe(&["/snakectl/scene"]);
    let d = late.data();
    let scene = SceneUpdate::decode(&d.payload[..]).unwrap();
    assert!(scene.entities.iter().any(|e| e.id == "arm_meas"));

    // Events: as the socket writes them, and as log lines.
    fox.subscribe_from(4, &["/snakectl/events", "/snakectl/log"]);
    // Subscribed once the server has read the request: a status round trip on the socket is
    // not enough to know that, so the move is asked for after the first scene that follows.
    while fox.data().subscription != 3 {}
    let mut client = daemon.client();
    let target = [tip[0] - 0.01, tip[1]];
    client.ok(json!({"cmd": "goto", "target": target}));
    let (mut event, mut log) = (None, None);
    let deadline = Instant::now() + DEADLINE;
    while event.is_none() || log.is_none() {
        assert!(Instant::now() < deadline, "no arrived event and log line");
        let d = fox.data();
        match d.subscription {
            4 => {
                let v: Value = serde_json::from_slice(&d.payload).unwrap();
                if v["event"] == "arrived" {
                    event = Some(v);
                }
            }
            5 => {
                let l = foxglove::schemas::Log::decode(&d.payload[..]).unwrap();
                if l.message.contains("\"arrived\"") {
                    log = Some(l);
                }
            }
            _ => {}
        }
    }
    assert!(event.unwrap()["tick"].is_u64());
    assert_eq!(log.unwrap().name, "snakectl");

    // A world change reaches the scene.
    client.ok(json!({"cmd": "set_world", "obstacles": [
        {"id": "far_post", "circle": {"center": [3.0, 3.0], "radius": 0.05}},
    ]}));
    let deadline = Instant::now() + DEADLINE;
    loop {
        assert!(Instant::now() < deadline, "no scene with the new obstacle");
        let d = fox.data();
        if d.subscription != 3 {
            continue;
        }
        let scene = SceneUpdate::decode(&d.payload[..]).unwrap();
        let obstacles = scene.entities.iter().find(|e| e.id == "obstacles").unwrap();
        if obstacles.texts.iter().any(|t| t.text == "far_post") {
            let disc = obstacles.cylinders[0].pose.unwrap().position.unwrap();
            assert_eq!((disc.x, disc.y), (3.0, 3.0));
            break;
        }
    }

    // An old client's subprotocol alone is refused by the handshake.
    assert!(Fox::try_connect(port, "foxglove.websocket.v1").is_err());
    drop(fox);
    drop(late);
    daemon.stop().unwrap();
}

/// Publishes `v` every 20 ms until the socket's measured tip has moved `by` m, or the
/// deadline; returns the distance moved.
fn drive(daemon: &Daemon, fox: &mut Fox, v: [f64; 2], by: f64, within: Duration) -> f64 {
    let mut client = daemon.client();
    let start = xy(&client.status()["tip_meas"]);
    let deadline = Instant::now() + within;
    let mut moved = 0.0;
    while Instant::now() < deadline && moved < by {
        fox.publish_twist(v);
        std::thread::sleep(Duration::from_millis(20));
        moved = dist(xy(&client.status()["tip_meas"]), start);
    }
    moved
}

#[test]
fn a_twist_from_foxglove_moves_the_tip_only_with_accept_commands() {
    // Without: nothing to publish to, and nothing moves.
    let (daemon, port) = start_daemon(false);
    let mut fox = Fox::connect(port);
    fox.next_op("serverInfo");
    fox.advertise_twist("/snakectl/cmd_vel");
    let moved = drive(&daemon, &mut fox, [0.05, 0.0], 0.01, Duration::from_secs(2));
    assert!(moved < 1e-3, "the tip moved {moved} m");
    assert_eq!(daemon.client().status()["state"], "holding");
    drop(fox);
    daemon.stop().unwrap();

    // With: the Twist becomes `velocity` through the arbiter, and the tip moves along +x.
    let (daemon, port) = start_daemon(true);
    let mut fox = Fox::connect(port);
    let info = fox.next_op("serverInfo");
    assert!(
        info["capabilities"]
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c == "clientPublish"),
        "{info}"
    );
    assert!(
        info["supportedEncodings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e == "json"),
        "{info}"
    );
    let mut client = daemon.client();
    let start = xy(&client.status()["tip_meas"]);
    fox.advertise_twist("/snakectl/cmd_vel");
    let moved = drive(&daemon, &mut fox, [0.05, 0.0], 0.01, DEADLINE);
    assert!(moved >= 0.01, "the tip moved only {moved} m");
    let status = client.status();
    let now = xy(&status["tip_meas"]);
    assert!(now[0] - start[0] > 0.009, "along +x: {start:?} -> {now:?}");
    assert!(
        status["controller"].is_u64(),
        "the view holds control: {status}"
    );
    // A socket client is refused while the view holds control, as with any other client.
    let refused = client.error_code(json!({"cmd": "velocity", "v": [0.0, 0.01]}));
    assert_eq!(refused, "not_in_control");
    drop(fox);
    daemon.stop().unwrap();
}

/// A `PointStamped` on `goal` or `reach` (as the 3-D panel's click publishes one, with its
/// publish topic set there) sends the tip to the point: a `goto`, or a `reach` round the
/// obstacles.
#[test]
fn a_point_from_foxglove_on_goal_or_reach_takes_the_tip_there() {
    let (daemon, port) = start_daemon(true);
    let mut fox = Fox::connect(port);
    fox.next_op("serverInfo");
    let mut client = daemon.client();
    let schema = "geometry_msgs/msg/PointStamped";
    for (id, topic, target) in [
        (2, "/snakectl/goal", [-0.45, 0.62]),
        (3, "/snakectl/reach", [-0.40, 0.60]),
    ] {
        let point = json!({"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "base"},
                           "point": {"x": target[0], "y": target[1], "z": 0.0}});
        publish_on(&mut fox, id, topic, schema, &point);
        let s = client.wait_status("arrived", |s| {
            s["command"]["outcome"] == "arrived" && dist(xy(&s["tip"]), target) < 1e-6
        });
        let kind = if topic.ends_with("goal") {
            "goto"
        } else {
            "reach"
        };
        assert_eq!(s["command"]["kind"], kind, "{s}");
    }
    drop(fox);
    daemon.stop().unwrap();
}

#[test]
fn behind_the_token_only_a_client_that_presents_it_gets_in() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("token");
    std::fs::write(&file, "correct horse\n").unwrap();
    let port = free_port();
    let line = format!(
        "max_clients = 4\ntoken_file = {:?}\n\n[foxglove]\nlisten = \"127.0.0.1:{port}\"\n",
        file.to_str().unwrap()
    );
    let daemon = Daemon::start(sim_config(&[("max_clients = 4", &line)]));
    let mut owner = daemon.client();
    owner.ok(json!({"cmd": "auth", "token": "correct horse"}));
    owner.status();
    for url in [
        format!("ws://127.0.0.1:{port}"),
        format!("ws://127.0.0.1:{port}/?token=correct"),
        format!("ws://127.0.0.1:{port}/?token=correct%20horse%20"),
    ] {
        let refused = Fox::try_url(&url, "foxglove.sdk.v1").err();
        assert!(
            refused.as_deref().is_some_and(|e| e.contains("401")),
            "{url}: {refused:?}"
        );
    }
    let mut fox = Fox::try_url(
        &format!("ws://127.0.0.1:{port}/?token=correct%20horse"),
        "foxglove.sdk.v1",
    )
    .unwrap();
    let info = fox.next_op("serverInfo");
    assert_eq!(info["name"], "snakectl", "{info}");
}

#[test]
fn beyond_max_clients_a_client_is_answered_503_until_one_leaves() {
    let port = free_port();
    let table = format!("[foxglove]\nlisten = \"127.0.0.1:{port}\"\nmax_clients = 2\n");
    let daemon = Daemon::start(sim_config(&[(
        "max_clients = 4",
        &format!("max_clients = 4\n\n{table}"),
    )]));
    daemon.client().status();
    let mut first = Fox::connect(port);
    assert_eq!(first.next_op("serverInfo")["name"], "snakectl");
    let mut second = Fox::connect(port);
    second.next_op("serverInfo");
    let refused = Fox::try_connect(port, "foxglove.sdk.v1").err();
    assert!(
        refused.as_deref().is_some_and(|e| e.contains("503")),
        "a third client: {refused:?}"
    );
    drop(second);
    // Its seat is free once the gate has seen the connection end.
    let deadline = Instant::now() + DEADLINE;
    let mut third = loop {
        match Fox::try_connect(port, "foxglove.sdk.v1") {
            Ok(fox) => break fox,
            Err(e) if e.contains("503") && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("the seat did not come free: {e}"),
        }
    };
    assert_eq!(third.next_op("serverInfo")["name"], "snakectl");
    // The clients let in are served all along.
    let joints = "/snakectl/joint_states";
    first.advertised(&[joints]);
    first.subscribe(&[joints]);
    assert_eq!(first.data().subscription, 1);
    drop((first, third));
    daemon.stop().unwrap();
}

/// Connects with a small receive buffer, so that a client that stops reading fills its
/// connection in seconds rather than minutes.
fn connect_with_small_window(port: u16) -> Fox {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let socket = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    socket.connect(&addr.into()).unwrap();
    let stream: std::net::TcpStream = socket.into();
    stream.set_nonblocking(true).unwrap();
    let mut request = format!("ws://127.0.0.1:{port}")
        .into_client_request()
        .unwrap();
    request.headers_mut().insert(
        "sec-websocket-protocol",
        HeaderValue::from_static("foxglove.sdk.v1"),
    );
    let ws = runtime
        .block_on(async {
            let stream = MaybeTlsStream::Plain(TcpStream::from_std(stream).unwrap());
            tokio_tungstenite::client_async(request, stream).await
        })
        .unwrap()
        .0;
    Fox {
        runtime,
        ws,
        channels: BTreeMap::new(),
        control: Vec::new(),
    }
}

/// A Foxglove client on `port` subscribed to every topic that then reads nothing, while a
/// socket client moves the arm to and fro (the trail and so the scene grow) until the daemon
/// logs that the gate's outbox for it overflowed and its oldest messages are dropped (its
/// connection full, the gate's writes to it waiting).
fn stall_a_client(port: u16, daemon: &mut DaemonChild) -> Fox {
    let mut client = daemon_support::Client::connect(daemon.address());
    let start = xy(&client.status()["tip"]);
    let mut stalled = connect_with_small_window(port);
    stalled.next_op("serverInfo");
    stalled.advertised(&TOPICS);
    stalled.subscribe(&TOPICS);
    let deadline = Instant::now() + DEADLINE;
    for k in 0.. {
        assert!(
            Instant::now() < deadline,
            "nothing was dropped for the stalled client"
        );
        let dx = if k % 2 == 0 { 0.06 } else { 0.0 };
        client.ok(json!({"cmd": "goto", "target": [start[0] + dx, start[1]]}));
        if daemon
            .logged(
                "its oldest messages are dropped",
                Duration::from_millis(300),
            )
            .is_some()
        {
            break;
        }
    }
    stalled
}

/// A daemon on the simulated chain in `dir`, its Foxglove view on `port` publishing at the
/// loop's rate (so that a client's connection fills in seconds), started with `args`; its
/// simulator, which must outlive it.
fn publishing_daemon(
    dir: &tempfile::TempDir,
    port: u16,
    args: &[&std::ffi::OsStr],
) -> (snakectl_sim::SimHandle, DaemonChild) {
    let table = format!("[foxglove]\nlisten = \"127.0.0.1:{port}\"\npublish_hz = 100.0\n");
    let config = sim_config(&[("max_clients = 4", &format!("max_clients = 4\n\n{table}"))]);
    let path = dir.path().join("arm.toml");
    std::fs::write(&path, config.text()).unwrap();
    let sim = snakectl::connect::spawn_sim(&config, std::sync::Arc::new(snakectl_sim::RealClock))
        .unwrap();
    let daemon = DaemonChild::spawn_with(&path, sim.path(), args);
    (sim, daemon)
}

#[test]
fn a_client_that_stopped_reading_does_not_hold_the_daemon_at_exit() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let recording = dir.path().join("run.mcap");
    let (_sim, mut daemon) =
        publishing_daemon(&dir, port, &["--record".as_ref(), recording.as_os_str()]);
    let stalled = stall_a_client(port, &mut daemon);
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    let bytes = std::fs::read(&recording).unwrap();
    assert!(
        bytes.ends_with(b"\x89MCAP0\r\n"),
        "the recording was closed, its summary written"
    );
    drop(stalled);
}

/// Wall-clock time now, ns since the Unix epoch: the clock of the messages' log times.
fn now_ns() -> u64 {
    let since = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    u64::try_from(since.as_nanos()).unwrap()
}

#[test]
fn a_client_that_stopped_reading_reads_fresh_data_again_after_a_bounded_backlog() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (_sim, mut daemon) = publishing_daemon(&dir, port, &[]);
    let mut stalled = stall_a_client(port, &mut daemon);
    // It reads again: what was published before is what waited for it. The gate's outbox
    // (256 kB), its send buffer and this client's small receive buffer hold well under 1 MB;
    // without the bound, the loopback connections behind the gate held about 8 MB.
    let resumed = now_ns();
    let mut stale = 0;
    loop {
        let data = stalled.data();
        if data.log_time >= resumed {
            break;
        }
        stale += data.payload.len() + 13;
    }
    assert!(
        stale > 0 && stale < 1 << 20,
        "{stale} bytes of messages published before the client read again"
    );
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
}

#[cfg(target_os = "linux")]
#[test]
fn the_view_and_the_recorder_run_below_the_loop() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let daemon = Daemon::start_with(
        config(port, false),
        Some(snakectl::record::RecordOptions::to(
            dir.path().join("run.mcap"),
        )),
    );
    daemon.client().status();
    // Thread names are cut to 15 bytes.
    threads_at(&["snakectl-loop"], &["snakectl-record", "snakectl-foxglo"]);
    daemon.stop().unwrap();
}

/// A token file holding `correct horse` in `dir`, and the `[server]` lines that ask for it.
fn token_lines(dir: &tempfile::TempDir) -> String {
    let file = dir.path().join("token");
    std::fs::write(&file, "correct horse\n").unwrap();
    format!(
        "max_clients = 4\ntoken_file = {:?}\n",
        file.to_str().unwrap()
    )
}

/// `snakectl run` in `dir` on `config` (its simulator started here, returned to outlive it),
/// with more `args`.
fn spawn_daemon(
    dir: &tempfile::TempDir,
    config: &Config,
    args: &[&std::ffi::OsStr],
) -> (snakectl_sim::SimHandle, DaemonChild) {
    let path = dir.path().join("arm.toml");
    std::fs::write(&path, config.text()).unwrap();
    let sim =
        snakectl::connect::spawn_sim(config, std::sync::Arc::new(snakectl_sim::RealClock)).unwrap();
    let daemon = DaemonChild::spawn_with(&path, sim.path(), args);
    (sim, daemon)
}

/// The TCP ports process `pid` listens on: its sockets (`/proc/PID/fd`) in the state LISTEN in
/// `/proc/PID/net/tcp` and `tcp6`.
#[cfg(target_os = "linux")]
fn listening_ports(pid: u32) -> std::collections::BTreeSet<u16> {
    let inodes: std::collections::BTreeSet<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .filter_map(|entry| std::fs::read_link(entry.ok()?.path()).ok())
        .filter_map(|link| {
            let link = link.to_string_lossy().into_owned();
            let inode = link.strip_prefix("socket:[")?.strip_suffix(']')?;
            Some(inode.to_owned())
        })
        .collect();
    let mut ports = std::collections::BTreeSet::new();
    for table in ["tcp", "tcp6"] {
        let text = std::fs::read_to_string(format!("/proc/{pid}/net/{table}")).unwrap();
        for line in text.lines().skip(1) {
            let fields: Vec<&str> = line.split_whitespace().collect();
            // local_address is fields[1] (ADDR:PORT, hex), st fields[3], inode fields[9].
            if fields[3] == "0A" && inodes.contains(fields[9]) {
                let port = fields[1].rsplit(':').next().unwrap();
                ports.insert(u16::from_str_radix(port, 16).unwrap());
            }
        }
    }
    ports
}

/// With a token, nothing reaches the view without it: the daemon listens on the socket's port
/// and the view's, and on no other (no server of the view on a port of its own, where no token
/// would be asked for).
#[cfg(target_os = "linux")]
#[test]
fn a_daemon_with_a_token_listens_on_the_socket_and_the_view_only() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let lines = format!(
        "{}\n[foxglove]\nlisten = \"127.0.0.1:{port}\"\naccept_commands = true\n",
        token_lines(&dir)
    );
    let config = sim_config(&[("max_clients = 4", &lines)]);
    let (_sim, mut daemon) = spawn_daemon(&dir, &config, &[]);
    let socket = daemon.address();
    daemon
        .logged("the Foxglove view serves", DEADLINE)
        .expect("the view serves");
    // A client in, with the token: the view serves it from the port asked for.
    let mut fox = Fox::try_url(
        &format!("ws://127.0.0.1:{port}/?token=correct%20horse"),
        "foxglove.sdk.v1",
    )
    .unwrap();
    fox.next_op("serverInfo");
    let ports = listening_ports(daemon.pid());
    assert_eq!(
        ports,
        [socket.port(), port].into_iter().collect(),
        "the socket is on {}, the view on {port}",
        socket.port()
    );
    drop(fox);
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
}

/// `snakectl run` listening on `listen` with `config`; its exit status and log.
fn run_to_exit(config: &Config, listen: &str) -> (std::process::ExitStatus, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("arm.toml");
    std::fs::write(&path, config.text()).unwrap();
    let sim =
        snakectl::connect::spawn_sim(config, std::sync::Arc::new(snakectl_sim::RealClock)).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", listen, "--config"])
        .arg(&path)
        .arg("--port")
        .arg(sim.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let status = daemon_support::child::wait_within(&mut child, "snakectl run");
    let mut log = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut log).unwrap();
    (status, log)
}

/// A `[foxglove] listen` address taken refuses start-up as a taken `[server] listen` does: exit
/// code 2, naming the address. So does one equal to `[server] listen`.
#[test]
fn a_taken_foxglove_address_refuses_start_up_with_exit_code_2() {
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let (status, log) = run_to_exit(&config(port, false), "127.0.0.1:0");
    assert_eq!(status.code(), Some(2), "log:\n{log}");
    assert!(log.contains(&format!("127.0.0.1:{port}")), "{log}");
    drop(taken);

    let port = free_port();
    let (status, log) = run_to_exit(&config(port, false), &format!("127.0.0.1:{port}"));
    assert_eq!(status.code(), Some(2), "log:\n{log}");
    assert!(log.contains("[foxglove]"), "{log}");
}

/// Publishes the JSON text `message` on client channel `id` (advertised already).
fn publish_raw(fox: &mut Fox, id: u32, message: &str) {
    let mut frame = vec![1u8];
    frame.extend_from_slice(&id.to_le_bytes());
    frame.extend_from_slice(message.as_bytes());
    fox.send(Message::binary(frame));
}

/// Lines of `log` that contain every one of `parts`.
fn lines_with<'a>(log: &'a str, parts: &[&str]) -> Vec<&'a str> {
    log.lines()
        .filter(|l| parts.iter().all(|p| l.contains(p)))
        .collect()
}

/// A refused Foxglove command is logged once per run of the same refusal on the same topic,
/// the run's end saying how many more there were; a refusal on another topic, or for another
/// reason, is logged.
#[test]
fn refused_foxglove_commands_are_logged_once_per_run_with_a_count() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (_sim, mut daemon) = spawn_daemon(&dir, &config(port, true), &[]);
    let mut client = daemon_support::Client::connect(daemon.address());
    client.status();
    let mut fox = Fox::connect(port);
    fox.next_op("serverInfo");
    fox.send_json(json!({"op": "advertise", "channels": [
        {"id": 1, "topic": "/snakectl/cmd_vel", "encoding": "json",
         "schemaName": "geometry_msgs/msg/Twist"},
        {"id": 2, "topic": "/snakectl/goal", "encoding": "json",
         "schemaName": "geometry_msgs/msg/PointStamped"},
    ]}));
    // Not a point on goal, then not a Twist on cmd_vel: both bad_arg, each logged.
    publish_raw(&mut fox, 2, "{}");
    let goal = daemon.logged("a Foxglove command was refused", DEADLINE);
    assert!(
        goal.as_deref()
            .is_some_and(|l| l.contains("topic=\"goal\"") && l.contains("bad_arg")),
        "{goal:?}"
    );
    publish_raw(&mut fox, 1, "{}");
    let cmd_vel = daemon.logged("a Foxglove command was refused", DEADLINE);
    assert!(
        cmd_vel
            .as_deref()
            .is_some_and(|l| l.contains("topic=\"cmd_vel\"") && l.contains("bad_arg")),
        "{cmd_vel:?}"
    );
    // A Teleop panel publishing during an estop: 25 refusals, one line, and a count.
    client.ok(json!({"cmd": "estop"}));
    const TWISTS: usize = 25;
    for _ in 0..TWISTS {
        fox.publish_twist([0.01, 0.0]);
        std::thread::sleep(Duration::from_millis(20));
    }
    // The estop's refusals logged (the first of them), and the socket's round trip after the
    // view's last command: all of them answered by the loop.
    daemon
        .logged("code=\"estopped\"", DEADLINE)
        .expect("the first refusal logged");
    client.status();
    drop(fox);
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    let refused = lines_with(
        &log,
        &["a Foxglove command was refused", "code=\"estopped\""],
    );
    assert!(refused.is_empty(), "logged again: {refused:?}");
    let more = lines_with(&log, &["refused alike", "code=\"estopped\""]);
    assert_eq!(more.len(), 1, "{log}");
    assert!(
        more[0].contains(&format!("count={}", TWISTS - 1)),
        "{}",
        more[0]
    );
}

/// A client that sends what the view does not take, over and over, is logged once, with the
/// count, and is still served.
#[test]
fn a_client_sending_garbage_is_logged_once_with_a_count() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (_sim, mut daemon) = spawn_daemon(&dir, &config(port, false), &[]);
    daemon_support::Client::connect(daemon.address()).status();
    let mut fox = Fox::connect(port);
    fox.next_op("serverInfo");
    const GARBAGE: usize = 300;
    for _ in 0..GARBAGE {
        fox.send(Message::binary(&b"\xff garbage"[..]));
        fox.send(Message::text("garbage"));
    }
    // Told once, with a status message.
    let status = fox.next_op("status");
    assert_eq!(status["level"], 2, "{status}");
    // Still served: what it sent after the garbage is taken.
    fox.advertised(&["/snakectl/joint_states"]);
    fox.subscribe(&["/snakectl/joint_states"]);
    assert_eq!(fox.data().subscription, 1);
    drop(fox);
    let line = daemon
        .logged("messages the view does not take", DEADLINE)
        .expect("the client's garbage logged when it left");
    assert!(line.contains(&format!("count={}", 2 * GARBAGE)), "{line}");
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    let errors = lines_with(&log, &["ERROR"]);
    assert!(errors.is_empty(), "{errors:?}");
    assert!(lines_with(&log, &["does not take"]).is_empty(), "{log}");
}

/// What is not a `Twist` on cmd_vel (no `linear` object) is refused: it does not stop a
/// `goto` the view's own click started, as a zero velocity would.
#[test]
fn json_that_is_not_a_twist_on_cmd_vel_does_not_preempt_a_goto() {
    let (daemon, port) = start_daemon(true);
    let mut client = daemon.client();
    let start = xy(&client.status()["tip_meas"]);
    let target = [start[0] - 0.05, start[1]];
    let mut fox = Fox::connect(port);
    fox.next_op("serverInfo");
    fox.advertise_twist("/snakectl/cmd_vel");
    let point = json!({"point": {"x": target[0], "y": target[1], "z": 0.0}});
    publish_on(
        &mut fox,
        2,
        "/snakectl/goal",
        "geometry_msgs/msg/PointStamped",
        &point,
    );
    client.wait_status("the goto", |s| s["command"]["kind"] == "goto");
    for message in ["[]", "{}", r#"{"data":"hi"}"#, r#"{"linear":[0.1,0]}"#] {
        publish_raw(&mut fox, 1, message);
    }
    let s = client.wait_status("the goto's end", |s| s["command"]["outcome"] != "active");
    assert_eq!(s["command"]["kind"], "goto", "{s}");
    assert_eq!(s["command"]["outcome"], "arrived", "{s}");
    assert!(dist(xy(&s["tip"]), target) < 1e-6, "{s}");
    drop(fox);
    daemon.stop().unwrap();
}

/// A message over the view's limit (64 KiB) ends that client's connection alone: it is sent a
/// close with code 1009 (Message Too Big) that names the limit, and the daemon logs one warning
/// naming it; another client connected meanwhile is served all along.
#[test]
fn a_message_over_the_limit_is_closed_with_1009_and_other_clients_are_served() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (_sim, mut daemon) = spawn_daemon(&dir, &config(port, false), &[]);
    daemon_support::Client::connect(daemon.address()).status();
    let joints = "/snakectl/joint_states";
    let mut other = Fox::connect(port);
    other.next_op("serverInfo");
    other.advertised(&[joints]);
    other.subscribe(&[joints]);
    assert_eq!(other.data().subscription, 1);

    let mut big = Fox::connect(port);
    big.next_op("serverInfo");
    let peer = big.local_addr();
    big.send(Message::text("x".repeat(70 * 1024)));
    let deadline = Instant::now() + DEADLINE;
    let close = loop {
        if let Message::Close(close) = big.next(deadline) {
            break close.expect("a close with a code");
        }
    };
    assert_eq!(u16::from(close.code), 1009, "{close}");
    assert!(close.reason.contains("65536 bytes"), "{close}");

    // The other client reads what the view logs after the close.
    let closed = now_ns();
    while other.data().log_time < closed {}
    let warned = daemon
        .logged("over the size limit", DEADLINE)
        .expect("the closed client logged");
    assert!(
        warned.contains("WARN")
            && warned.contains(&peer.to_string())
            && warned.contains("limit=65536"),
        "{warned}"
    );
    drop((big, other));
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    let again = lines_with(&log, &["over the size limit"]);
    assert!(again.is_empty(), "logged more than once: {again:?}");
}
