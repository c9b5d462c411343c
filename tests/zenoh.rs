//! The daemon on a Zenoh network (the `zenoh` feature), against the simulator on a real
//! pseudo-terminal. Each test's sessions are peers on explicit `tcp/127.0.0.1` endpoints with
//! multicast scouting off, so which sessions meet does not depend on the machine's network.
//! Timing is asserted in the daemon's ticks, never in wall-clock speed.
#![cfg(feature = "zenoh")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::net::{SocketAddr, TcpListener};
use std::process::Command;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use daemon_support::child::DaemonChild;
use daemon_support::{dist, floats, sim_config, xy, Client, Daemon, DEADLINE};
use serde_json::{json, Value};
use snakectl::config::{Config, Endpoint};
use snakectl::daemon::bridge::{self, Peer, Subscription};
use snakectl::daemon::{DaemonError, Embedded, RunOptions};
use snakectl::ros::rmw::{self, Attachment, EntityKind, Qos};
use snakectl::ros::{self, JointState, PointStamped, Twist, Vector3};

/// The shipped simulator config's limits.
const DEADMAN_S: f64 = 0.5;
const MAX_TIP_ACCEL: f64 = 0.5;
const DT: f64 = 0.01;

/// A port nobody listens on now (the system's pick for port 0, released).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The `[zenoh]` table of a ROS 2 node in `domain` (as well as the plain keys).
fn ros2_table(prefix: &str, port: u16, domain: u32) -> String {
    format!(
        "{}ros2 = true\ndomain_id = {domain}\n",
        zenoh_table(prefix, port, true)
    )
}

/// The `[zenoh]` table text: listening on `port` of loopback, under `prefix`.
fn zenoh_table(prefix: &str, port: u16, accept_commands: bool) -> String {
    format!(
        "[zenoh]\nenabled = true\nlisten = [\"tcp/127.0.0.1:{port}\"]\nprefix = \"{prefix}\"\n\
         accept_commands = {accept_commands}\n"
    )
}

/// The shipped simulator config with `table` added.
fn config_with(table: &str) -> Config {
    sim_config(&[("max_clients = 4", &format!("max_clients = 4\n\n{table}"))])
}

/// A daemon on the Zenoh network, and the port it listens on there.
fn daemon(prefix: &str, accept_commands: bool) -> (Daemon, u16) {
    let port = free_port();
    let daemon = Daemon::start(config_with(&zenoh_table(prefix, port, accept_commands)));
    // The first reply waits for bring-up, after which the bridge serves.
    daemon.client().status();
    (daemon, port)
}

/// A second session: a peer that connects to `port` and listens nowhere.
fn peer(port: u16) -> Peer {
    let endpoint = Endpoint::parse(&format!("tcp/127.0.0.1:{port}")).unwrap();
    Peer::open(&[endpoint], &[]).unwrap()
}

/// A daemon on the network under `prefix`, a socket client of it, and a peer that reaches it.
fn on_network(prefix: &str, accept_commands: bool) -> (Daemon, Client, Peer) {
    let (daemon, port) = daemon(prefix, accept_commands);
    let client = daemon.client();
    (daemon, client, peer(port))
}

/// `client`'s status once the arm holds still.
fn at_rest(client: &mut Client) -> Value {
    client.wait_status("at rest", |s| s["state"] == "holding")
}

/// The next sample of `sub`, within [`DEADLINE`].
fn next_payload(sub: &Subscription, what: &str) -> Vec<u8> {
    sub.recv_timeout(DEADLINE)
        .unwrap_or_else(|| panic!("no `{what}` sample within {DEADLINE:?}"))
        .payload
}

/// The next JSON sample of `sub` that satisfies `pred`, within [`DEADLINE`].
fn next_json(sub: &Subscription, what: &str, mut pred: impl FnMut(&Value) -> bool) -> Value {
    let deadline = Instant::now() + DEADLINE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no `{what}` within {DEADLINE:?}");
        if let Some(sample) = sub.recv_timeout(left) {
            let value: Value = serde_json::from_slice(&sample.payload).unwrap();
            if pred(&value) {
                return value;
            }
        }
    }
}

fn twist(vx: f64, vy: f64) -> Vec<u8> {
    ros::encode(&Twist {
        linear: Vector3 {
            x: vx,
            y: vy,
            z: 0.0,
        },
        angular: Vector3::default(),
    })
    .unwrap()
}

/// Puts `cmd_vel` = (vx, vy) on `prefix` at 20 Hz for `seconds`, as a teleop node would.
fn stream_cmd_vel(peer: &Peer, prefix: &str, v: [f64; 2], seconds: f64) {
    let key = format!("{prefix}/cmd_vel");
    let n = (seconds * 20.0).round() as usize;
    for _ in 0..n {
        peer.put(&key, twist(v[0], v[1])).unwrap();
        // The stream's own pace, not a wait for anything.
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn joint_states_carry_the_measured_pose_in_cdr() {
    let (daemon, mut client, peer) = on_network("snakectl", false);
    let joint_states = peer.subscribe("snakectl/joint_states").unwrap();
    let tips = peer.subscribe("snakectl/tip").unwrap();

    // Away from home first, so that the pose checked is not the config's home pose.
    let id = client.ok(json!({"cmd": "goto", "target": [-0.45, 0.70]}))["id"].as_u64();
    client.event("arrived", id);
    let status = client.wait_status("at rest", |s| {
        s["state"] == "holding" && floats(&s["omega_meas"]).iter().all(|w| *w == 0.0)
    });
    let theta_meas = floats(&status["theta_meas"]);
    let home = daemon.config.home().to_vec();
    assert!(
        theta_meas
            .iter()
            .zip(&home)
            .any(|(a, b)| (a - b).abs() > 0.01),
        "the goto left the arm at home: {theta_meas:?}"
    );

    // Samples published before the arm came to rest are skipped: at rest they match exactly.
    let deadline = Instant::now() + DEADLINE;
    let message = loop {
        let m: JointState = ros::decode(&next_payload(&joint_states, "joint_states")).unwrap();
        if m.position == theta_meas {
            break m;
        }
        assert!(
            Instant::now() < deadline,
            "joint_states never showed the measured pose {theta_meas:?}; last {:?}",
            m.position
        );
    };
    let names: Vec<String> = (1..=12).map(|i| format!("joint_{i}")).collect();
    assert_eq!(message.name, names);
    assert_eq!(message.velocity, floats(&status["omega_meas"]));
    assert!(message.effort.is_empty());
    // The stamp is wall-clock time (ROS's), not the daemon's time since start.
    let now = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
    let stamp = message.header.stamp.as_secs_f64();
    assert!(
        (now.as_secs_f64() - stamp).abs() < 60.0,
        "stamp {stamp} s is not near the wall clock {} s",
        now.as_secs_f64()
    );

    let deadline = Instant::now() + DEADLINE;
    let tip_meas = xy(&status["tip_meas"]);
    loop {
        let tip: PointStamped = ros::decode(&next_payload(&tips, "tip")).unwrap();
        if [tip.point.x, tip.point.y] == tip_meas {
            assert_eq!(tip.point.z, 0.0);
            break;
        }
        assert!(Instant::now() < deadline, "tip never showed {tip_meas:?}");
    }
    daemon.stop().unwrap();
}

#[test]
fn the_status_query_answers_the_sockets_status_reply() {
    let (daemon, mut client, peer) = on_network("lab/arm_1", false);
    let status = at_rest(&mut client);

    let replies = peer.get("lab/arm_1/status", DEADLINE).unwrap();
    assert_eq!(replies.len(), 1, "one arm, one answer");
    assert_eq!(replies[0].key, "lab/arm_1/status");
    let reply: Value = serde_json::from_slice(&replies[0].payload).unwrap();
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(reply["state"], json!("holding"));
    assert_eq!(reply["tip_meas"], status["tip_meas"]);
    assert_eq!(reply["controller"], Value::Null);
    assert_eq!(reply["in_control"], json!(false));
    // Every field of the socket's reply is there.
    for key in status.as_object().unwrap().keys() {
        assert!(reply.get(key).is_some(), "`{key}` missing from {reply}");
    }

    let describe = peer.get("lab/arm_1/describe", DEADLINE).unwrap();
    let describe: Value = serde_json::from_slice(&describe[0].payload).unwrap();
    assert_eq!(describe["links_m"].as_array().unwrap().len(), 12);
    // Another prefix is another arm: nobody answers.
    assert!(peer
        .get("lab/arm_2/status", Duration::from_millis(300))
        .unwrap()
        .is_empty());
    daemon.stop().unwrap();
}

#[test]
fn cmd_vel_moves_the_tip_and_stops_within_the_deadman_then_lets_go() {
    let (daemon, mut client, peer) = on_network("snakectl", true);
    let events = peer.subscribe("snakectl/events").unwrap();
    let start = at_rest(&mut client);
    let v = [0.04, 0.0];

    stream_cmd_vel(&peer, "snakectl", v, 1.5);
    let last = client.status();
    let moved = dist(xy(&last["tip"]), xy(&start["tip"]));
    assert!(
        xy(&last["tip"])[0] - xy(&start["tip"])[0] > 0.5 * v[0] * 1.0,
        "1.5 s of cmd_vel at {v:?} moved the tip {moved} m"
    );
    assert_eq!(last["controller"], json!(1), "the network holds control");

    // The stream stopped: the deadman runs out, the tip comes to rest.
    let stopped = next_json(&events, "stopped", |e| e["event"] == "stopped");
    let rest = at_rest(&mut client);
    let after = dist(xy(&rest["tip"]), xy(&last["tip"]));
    // At most the deadman at full speed, the braking, and a tick's latency each way.
    let bound = v[0] * (DEADMAN_S + 2.0 * DT) + v[0] * v[0] / (2.0 * MAX_TIP_ACCEL);
    assert!(
        after <= bound,
        "{after} m after the last cmd_vel, over {bound} m"
    );
    let ticks = stopped["tick"].as_u64().unwrap() - last["tick"].as_u64().unwrap();
    let within_s = ticks as f64 * DT;
    assert!(
        within_s <= DEADMAN_S + v[0] / MAX_TIP_ACCEL + 0.1,
        "stopped {within_s} s after the last cmd_vel"
    );

    // After the deadman's silence, control is free: a socket client moves without asking.
    client.wait_status("control let go", |s| s["controller"].is_null());
    let id = client.ok(json!({"cmd": "goto", "target": xy(&start["tip"])}))["id"].as_u64();
    client.event("arrived", id);
    daemon.stop().unwrap();
}

/// `goal` and `reach` take the tip to their targets (`goto` along its route, `reach` along a
/// way in joint space planned beside the loop); a `reach` sample that is no point is refused,
/// naming the topic.
#[test]
fn goal_and_reach_take_the_tip_to_their_targets() {
    let (daemon, mut client, peer) = on_network("snakectl", true);
    let events = peer.subscribe("snakectl/events").unwrap();
    at_rest(&mut client);
    for (key, target) in [
        ("snakectl/goal", [-0.45, 0.62]),
        ("snakectl/reach", [-0.40, 0.60]),
    ] {
        let point = ros::encode(&ros::point_stamped(target, 0.0, "")).unwrap();
        peer.put(key, point).unwrap();
        let arrived = next_json(&events, "arrived", |e| e["event"] == "arrived");
        let tip = xy(&arrived["tip"]);
        assert!(
            dist(tip, target) < 1e-6,
            "{key}: arrived at {tip:?}, not {target:?}"
        );
    }
    peer.put("snakectl/reach", twist(0.1, 0.2)).unwrap();
    let refused = next_json(&events, "a refusal", |e| e["ok"] == json!(false));
    assert_eq!(refused["error"]["code"], json!("bad_arg"), "{refused}");
    let message = refused["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("reach is not a geometry_msgs/msg/PointStamped"),
        "{message}"
    );
    assert!(dist(xy(&client.status()["tip"]), [-0.40, 0.60]) < 1e-6);
    daemon.stop().unwrap();
}

#[test]
fn without_accept_commands_cmd_vel_and_goal_are_ignored() {
    let (daemon, mut client, peer) = on_network("snakectl", false);
    // The link works: the daemon's samples reach this peer.
    let joint_states = peer.subscribe("snakectl/joint_states").unwrap();
    next_payload(&joint_states, "joint_states");
    let start = at_rest(&mut client);

    let goal = ros::encode(&ros::point_stamped([-0.40, 0.60], 0.0, "")).unwrap();
    peer.put("snakectl/goal", goal).unwrap();
    stream_cmd_vel(&peer, "snakectl", [0.05, 0.0], 1.0);
    let end = client.status();
    assert_eq!(end["tip_ref"], start["tip_ref"], "the arm moved");
    assert_eq!(end["state"], json!("holding"));
    assert_eq!(end["controller"], Value::Null);
    daemon.stop().unwrap();
}

#[test]
fn network_commands_meet_the_arbiter_and_the_estop() {
    let (daemon, mut client, peer) = on_network("snakectl", true);
    let events = peer.subscribe("snakectl/events").unwrap();
    let start = at_rest(&mut client);

    // A socket client holds control: the network's cmd_vel is refused, and says so.
    client.ok(json!({"cmd": "take_control"}));
    peer.put("snakectl/cmd_vel", twist(0.05, 0.0)).unwrap();
    let refused = next_json(&events, "a refusal", |e| e["ok"] == json!(false));
    assert_eq!(
        refused["error"]["code"],
        json!("not_in_control"),
        "{refused}"
    );
    stream_cmd_vel(&peer, "snakectl", [0.05, 0.0], 0.5);
    assert_eq!(client.status()["tip_ref"], start["tip_ref"]);

    // Estop latched: released control does not let the network past it.
    client.ok(json!({"cmd": "estop"}));
    client.ok(json!({"cmd": "release"}));
    let goal = ros::encode(&ros::point_stamped([-0.40, 0.60], 0.0, "")).unwrap();
    peer.put("snakectl/goal", goal).unwrap();
    let refused = next_json(&events, "a refusal", |e| {
        e["ok"] == json!(false) && e["error"]["code"] != json!("not_in_control")
    });
    assert_eq!(refused["error"]["code"], json!("estopped"), "{refused}");
    let end = client.status();
    assert_eq!(end["state"], json!("estop"));
    assert_eq!(end["tip_ref"], start["tip_ref"]);

    // Not a ROS message at all, or not finite: refused, named.
    peer.put("snakectl/cmd_vel", b"{\"v\": [1, 2]}".to_vec())
        .unwrap();
    let refused = next_json(&events, "a refusal", |e| e["error"]["code"] == "bad_arg");
    let message = refused["error"]["message"].as_str().unwrap();
    assert!(message.contains("geometry_msgs/msg/Twist"), "{message}");
    peer.put("snakectl/cmd_vel", twist(f64::NAN, 0.0)).unwrap();
    let refused = next_json(&events, "a refusal", |e| {
        e["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("not finite"))
    });
    assert_eq!(refused["error"]["code"], json!("bad_arg"));
    daemon.stop().unwrap();
}

#[test]
fn a_flood_of_garbage_is_told_in_few_events_and_telemetry_keeps_its_pace() {
    let (daemon, port) = daemon("flooded", true);
    let mut client = daemon.client();
    let peer = peer(port);
    let start = at_rest(&mut client);
    let events = peer.subscribe("flooded/events").unwrap();
    let telemetry = peer.subscribe("flooded/telemetry").unwrap();
    // About 20,000 a second, in bursts of 20 a millisecond, from a session of its own:
    // hostile, yet leaving the other tests of this binary some of the machine.
    let began = Instant::now();
    let flooder = std::thread::spawn(move || {
        let attacker = self::peer(port);
        let mut sent = 0u64;
        while began.elapsed() < Duration::from_secs(2) {
            for _ in 0..20 {
                attacker.put("flooded/cmd_vel", b"x".to_vec()).unwrap();
            }
            sent += 20;
            std::thread::sleep(Duration::from_millis(1));
        }
        sent
    });
    // Queries are still answered meanwhile.
    std::thread::sleep(Duration::from_millis(500));
    let status = peer.get("flooded/status", Duration::from_secs(1)).unwrap();
    assert_eq!(status.len(), 1, "no status answer under the flood");
    let sent = flooder.join().unwrap();
    let flooded = began.elapsed();
    // What arrived while the flood lasted.
    let mut ticks = Vec::new();
    while let Some(sample) = telemetry.recv_timeout(Duration::ZERO) {
        let t: Value = serde_json::from_slice(&sample.payload).unwrap();
        ticks.push(t["tick"].as_u64().unwrap());
    }
    // Every tick's end is seen: a publication every rate_hz / publish_hz = 2 ticks.
    let span = ticks.last().unwrap() - ticks.first().unwrap();
    let expected = span as f64 / 2.0;
    println!(
        "{sent} garbage samples in {flooded:?}: {} telemetry samples over {span} ticks",
        ticks.len()
    );
    assert!(
        ticks.len() as f64 >= 0.5 * expected,
        "{} telemetry samples over {span} ticks",
        ticks.len()
    );
    // Refusals: at most one event per 100 ms, the last with the count of those folded in.
    // (The daemon may still be working through samples queued when the flood stopped.)
    let mut told = Vec::new();
    let mut last = began;
    while let Some(sample) = events.recv_timeout(Duration::from_millis(500)) {
        let e: Value = serde_json::from_slice(&sample.payload).unwrap();
        if e["ok"] == json!(false) {
            told.push(e["error"]["message"].as_str().unwrap().to_owned());
            last = Instant::now();
        }
    }
    let bound = (last - began).as_secs_f64() / 0.1 + 3.0;
    assert!(
        !told.is_empty() && told.len() as f64 <= bound,
        "{} events",
        told.len()
    );
    assert!(
        told.iter()
            .any(|m| m.contains("refusals: at most one is told per 100 ms")),
        "{told:?}"
    );
    assert_eq!(
        client.status()["tip_ref"],
        start["tip_ref"],
        "the arm moved"
    );
    daemon.stop().unwrap();
}

#[test]
fn fleet_lists_two_arms_by_prefix() {
    let (a, port_a) = daemon("lab/arm_a", false);
    let (b, port_b) = daemon("lab/arm_b", false);
    let tip_a = xy(&at_rest(&mut a.client())["tip_meas"]);

    // The library: one peer that reaches both.
    let endpoints: Vec<Endpoint> = [port_a, port_b]
        .iter()
        .map(|p| Endpoint::parse(&format!("tcp/127.0.0.1:{p}")).unwrap())
        .collect();
    let peer = Peer::open(&endpoints, &[]).unwrap();
    let arms = bridge::fleet(&peer, Duration::from_secs(2)).unwrap();
    let prefixes: Vec<&str> = arms.iter().map(|a| a.prefix.as_str()).collect();
    assert_eq!(prefixes, ["lab/arm_a", "lab/arm_b"]);
    let status_a = arms[0].status.as_ref().unwrap();
    assert_eq!(xy(&status_a["tip_meas"]), tip_a);

    // The command: one line each, state and measured tip.
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["fleet", "--wait-ms", "2000"])
        .args(["--connect", &format!("tcp/127.0.0.1:{port_a}")])
        .args(["--connect", &format!("tcp/127.0.0.1:{port_b}")])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 2, "{stdout}");
    assert!(lines[0].starts_with("lab/arm_a "), "{stdout}");
    assert!(lines[1].starts_with("lab/arm_b "), "{stdout}");
    assert!(lines.iter().all(|l| l.contains("holding")), "{stdout}");
    let tip = format!("tip ({:+.3}, {:+.3}) m", tip_a[0], tip_a[1]);
    assert!(lines[0].contains(&tip), "{stdout} lacks {tip}");

    // Through a config file: what the daemon listens on is connected to.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("arm_b.toml");
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    std::fs::write(
        &path,
        format!("{text}\n{}", zenoh_table("lab/arm_b", port_b, false)),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["fleet", "--wait-ms", "2000", "--json", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // arm_b, and any arm it knows of (Zenoh's peers tell each other of the peers they meet).
    let arms: Vec<Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let arm_b = arms.iter().find(|a| a["prefix"] == "lab/arm_b");
    let arm_b = arm_b.unwrap_or_else(|| panic!("no lab/arm_b in {stdout}"));
    assert_eq!(arm_b["status"]["state"], json!("holding"));
    a.stop().unwrap();
    b.stop().unwrap();
}

#[test]
fn fleet_with_nothing_up_says_so() {
    let port = free_port();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["fleet", "--wait-ms", "300", "--connect"])
        .arg(format!("tcp/127.0.0.1:{port}"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no arm seen within 300 ms"), "{stderr}");
    assert!(
        stderr.contains(&format!("tcp/127.0.0.1:{port}")),
        "{stderr}"
    );

    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["fleet", "--connect", "udp/127.0.0.1:7447"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("only tcp is built into snakectl"),
        "{stderr}"
    );
}

#[cfg(target_os = "linux")]
#[test]
fn the_bridge_runs_below_the_loop() {
    let (daemon, _) = daemon("aside", false);
    // Thread names are cut to 15 bytes: the bridge's thread, its runtime's worker. Zenoh's own
    // threads, started from there, inherit their priority but are not checked: the plain Zenoh
    // peers of the other tests in this binary, at the test's priority, carry the same names.
    daemon_support::threads_at(&["snakectl-loop"], &["snakectl-zenoh", "snakectl-zenoh-"]);
    daemon.stop().unwrap();
}

#[test]
fn start_up_stops_before_the_arm_moves_when_the_zenoh_endpoint_is_taken() {
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let config = config_with(&zenoh_table("snakectl", port, false));
    // Nothing is asked of the servos: every torque stays as the simulator started.
    let message = refused_at_start_up(config);
    assert!(message.contains("config/sim.toml: [zenoh]"), "{message}");
    assert!(message.contains("opening the Zenoh session"), "{message}");
    drop(taken);
}

/// Starts an embedded daemon on `config` against a simulator, expects start-up to be refused
/// with a Zenoh error, and checks that nothing was asked of the servos; returns the message.
fn refused_at_start_up(config: Config) -> String {
    let sim = snakectl::connect::spawn_sim(&config, std::sync::Arc::new(snakectl_sim::RealClock))
        .unwrap();
    let options = RunOptions::port(sim.path().to_path_buf());
    let daemon = Embedded::start(config, SocketAddr::from(([127, 0, 0, 1], 0)), options).unwrap();
    let e = daemon.stop().unwrap_err();
    assert!(matches!(e, DaemonError::Zenoh { .. }), "{e}");
    let torques: Vec<bool> =
        sim.with_sim(|s| s.servos().iter().map(|s| s.torque_enabled()).collect());
    assert!(torques.iter().all(|on| !on), "{torques:?}");
    e.to_string()
}

/// Zenoh's access control: denied by default, everything allowed on the loopback interface.
const LOOPBACK_ACL: &str = r#"{
  access_control: {
    enabled: true,
    default_permission: "deny",
    rules: [{
      id: "all",
      messages: ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
      flows: ["ingress", "egress"],
      permission: "allow",
      key_exprs: ["**"],
    }],
    subjects: [{ id: "loopback", interfaces: ["lo"] }],
    policies: [{ rules: ["all"], subjects: ["loopback"] }],
  },
}"#;

#[test]
fn a_token_file_refuses_zenoh_commands_without_access_control() {
    let dir = tempfile::tempdir().unwrap();
    let token = dir.path().join("token");
    std::fs::write(&token, "s3cret\n").unwrap();
    let server = format!(
        "max_clients = 4\ntoken_file = {:?}",
        token.to_str().unwrap()
    );
    let table = zenoh_table("snakectl", free_port(), true);
    let config = sim_config(&[("max_clients = 4", &format!("{server}\n\n{table}"))]);
    let message = refused_at_start_up(config);
    assert!(message.contains("config/sim.toml: [zenoh]"), "{message}");
    assert!(message.contains("accept_commands"), "{message}");
    assert!(message.contains(token.to_str().unwrap()), "{message}");

    // Zenoh's access control, denying by default, is what may stand in for the token.
    let acl = dir.path().join("zenoh.json5");
    std::fs::write(&acl, LOOPBACK_ACL).unwrap();
    let table = format!("{table}config_file = {:?}\n", acl.to_str().unwrap());
    let config = sim_config(&[("max_clients = 4", &format!("{server}\n\n{table}"))]);
    let daemon = Daemon::start(config);
    let mut client = daemon.client();
    client.ok(json!({"cmd": "auth", "token": "s3cret"}));
    client.status();
    daemon.stop().unwrap();
}

#[test]
fn a_config_file_that_leaves_listen_open_refuses_commands() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("zenoh.json5");
    std::fs::write(&file, r#"{ listen: { endpoints: ["tcp/0.0.0.0:0"] } }"#).unwrap();
    let table = format!(
        "[zenoh]\nenabled = true\naccept_commands = true\nconfig_file = {:?}\n",
        file.to_str().unwrap()
    );
    let message = refused_at_start_up(config_with(&table));
    assert!(message.contains("tcp/0.0.0.0:0"), "{message}");
    assert!(message.contains("accept_commands"), "{message}");
}

/// `snakectl run` on the shipped simulator config with `table` added, in `dir`: its exit
/// status and standard error, once it has ended by itself.
fn run_to_end(dir: &std::path::Path, table: &str) -> (Option<i32>, String) {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let path = dir.join("arm.toml");
    std::fs::write(&path, format!("{text}\n{table}")).unwrap();
    let config = Config::load(&path).unwrap();
    let sim = snakectl::connect::spawn_sim(&config, std::sync::Arc::new(snakectl_sim::RealClock))
        .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", "127.0.0.1:0", "--config"])
        .arg(&path)
        .arg("--port")
        .arg(sim.path())
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_zenoh_session_that_cannot_open_refuses_start_up_with_exit_code_2() {
    let dir = tempfile::tempdir().unwrap();
    // A taken listen endpoint.
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let (code, stderr) = run_to_end(dir.path(), &zenoh_table("snakectl", port, false));
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("opening the Zenoh session"), "{stderr}");
    // A client with no router to reach.
    let table = format!(
        "[zenoh]\nenabled = true\nmode = \"client\"\nconnect = [\"tcp/127.0.0.1:{}\"]\n",
        free_port()
    );
    let (code, stderr) = run_to_end(dir.path(), &table);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("opening the Zenoh session"), "{stderr}");
    drop(taken);
}

#[test]
fn a_second_daemon_on_a_live_prefix_refuses_start_up() {
    let (first, port) = daemon("twin", true);
    // Reaching the first: a peer that connects to it.
    let table = format!(
        "[zenoh]\nenabled = true\nconnect = [\"tcp/127.0.0.1:{port}\"]\nprefix = \"twin\"\n"
    );
    let message = refused_at_start_up(config_with(&table));
    assert!(message.contains("\"twin\""), "{message}");
    assert!(message.contains("holds the prefix"), "{message}");
    // Commanding or not: two publishers on one prefix mix their telemetry as well.
    let message = refused_at_start_up(config_with(&format!("{table}accept_commands = true\n")));
    assert!(message.contains("holds the prefix"), "{message}");
    // Another prefix on the same network is another arm.
    let table = table.replace("\"twin\"", "\"twin_b\"");
    let second = Daemon::start(config_with(&table));
    second.client().status();
    second.stop().unwrap();
    first.stop().unwrap();
}

#[test]
fn commands_through_a_connect_endpoint_are_warned_of() {
    let dir = tempfile::tempdir().unwrap();
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let path = dir.path().join("arm.toml");
    // A router on loopback, as ROS2.md's recipe has it: it may listen on every interface.
    // A port held but never served: no other test's daemon can take it meanwhile.
    let router = TcpListener::bind("127.0.0.1:0").unwrap();
    let table = format!(
        "[zenoh]\nenabled = true\nconnect = [\"tcp/127.0.0.1:{}\"]\nprefix = \"warned\"\n\
         accept_commands = true\n",
        router.local_addr().unwrap().port()
    );
    std::fs::write(&path, format!("{text}\n{table}")).unwrap();
    let config = Config::load(&path).unwrap();
    let sim = snakectl::connect::spawn_sim(&config, std::sync::Arc::new(snakectl_sim::RealClock))
        .unwrap();
    let daemon = DaemonChild::spawn(&path, sim.path());
    let line = daemon.logged(
        "accept_commands through a Zenoh session the daemon connects to",
        DEADLINE,
    );
    let line = line.expect("no warning of the commands' way in");
    assert!(line.contains("WARN"), "{line}");
    drop(daemon);
    // Without commands, nothing to warn of.
    let path = dir.path().join("watch.toml");
    let table = table.replace("accept_commands = true", "accept_commands = false");
    std::fs::write(&path, format!("{text}\n{table}")).unwrap();
    let watcher = DaemonChild::spawn(&path, sim.path());
    assert!(watcher
        .logged("accept_commands through", Duration::from_secs(2))
        .is_none());
    drop(router);
}

/// A subscriber as rmw_zenoh's: a sample whose attachment is not rmw_zenoh's is dropped.
/// Returns the next kept sample's payload and attachment, and how many were dropped before it.
fn next_ros_sample(sub: &Subscription, what: &str) -> (Vec<u8>, Attachment, usize) {
    let deadline = Instant::now() + DEADLINE;
    let mut dropped = 0;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(
            !left.is_zero(),
            "no `{what}` with an attachment within {DEADLINE:?}"
        );
        let Some(sample) = sub.recv_timeout(left) else {
            continue;
        };
        match Attachment::decode(sample.attachment.as_deref().unwrap_or_default()) {
            Ok(attachment) => return (sample.payload, attachment, dropped),
            Err(_) => dropped += 1,
        }
    }
}

fn ns_now() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64
}

#[test]
fn a_ros2_node_on_rmw_zenohs_keys_with_its_graph_and_attachments() {
    let port = free_port();
    let domain = 7;
    let daemon = Daemon::start(config_with(&ros2_table("snakectl", port, domain)));
    let mut client = daemon.client();
    let start = at_rest(&mut client);
    let peer = peer(port);

    // The graph: one node token, whose session id names every other token.
    let tokens = peer
        .alive(&format!("@ros2_lv/{domain}/**"), Duration::from_secs(2))
        .unwrap();
    let nodes: Vec<&String> = tokens.iter().filter(|t| t.contains("/NN/")).collect();
    assert_eq!(nodes.len(), 1, "{tokens:#?}");
    let zid = nodes[0].split('/').nth(2).unwrap();
    let node = rmw::Node::snakectl(domain, zid, "snakectl");
    let qos = Qos::DEFAULT;
    let joint_states_token =
        node.entity_token::<JointState>(1, EntityKind::Publisher, "/snakectl/joint_states", &qos);
    let mut expected = vec![
        node.token(),
        joint_states_token.clone(),
        node.entity_token::<PointStamped>(2, EntityKind::Publisher, "/snakectl/tip_cmd", &qos),
        node.entity_token::<PointStamped>(3, EntityKind::Publisher, "/snakectl/tip_meas", &qos),
        node.entity_token::<PointStamped>(4, EntityKind::Publisher, "/snakectl/target", &qos),
        node.entity_token::<Twist>(5, EntityKind::Subscription, "/snakectl/cmd_vel", &qos),
        node.entity_token::<PointStamped>(6, EntityKind::Subscription, "/snakectl/goal", &qos),
        node.entity_token::<PointStamped>(7, EntityKind::Subscription, "/snakectl/reach", &qos),
    ];
    expected.sort();
    assert_eq!(tokens, expected);
    assert_eq!(
        node.token(),
        format!("@ros2_lv/7/{zid}/0/0/NN/%/%snakectl/snakectl")
    );

    // joint_states on the ROS 2 key, every sample attached: the publisher's GID, a sequence
    // that counts up, the wall clock.
    let key = rmw::data_key::<JointState>(domain, "/snakectl/joint_states");
    assert_eq!(
        key,
        "7/snakectl/joint_states/sensor_msgs::msg::dds_::JointState_/\
         RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    );
    let joint_states = peer.subscribe(&key).unwrap();
    let (payload, first, dropped) = next_ros_sample(&joint_states, "joint_states");
    assert_eq!(
        dropped, 0,
        "a joint_states sample without rmw_zenoh's attachment"
    );
    let message: JointState = ros::decode(&payload).unwrap();
    let names: Vec<String> = (1..=12).map(|i| format!("joint_{i}")).collect();
    assert_eq!(message.name, names);
    assert_eq!(message.position.len(), 12);
    assert_eq!(first.gid, rmw::gid(&joint_states_token));
    assert!(
        (ns_now() - first.source_timestamp_ns).abs() < 60_000_000_000,
        "the source timestamp {} ns is not the wall clock",
        first.source_timestamp_ns
    );
    let (_, second, dropped) = next_ros_sample(&joint_states, "joint_states");
    assert_eq!(dropped, 0);
    assert!(
        second.sequence > first.sequence,
        "{second:?} after {first:?}"
    );

    // The measured tip, in the frame the URDF calls base.
    let tips = peer
        .subscribe(&rmw::data_key::<PointStamped>(domain, "/snakectl/tip_meas"))
        .unwrap();
    let (payload, _, dropped) = next_ros_sample(&tips, "tip_meas");
    assert_eq!(dropped, 0);
    let tip: PointStamped = ros::decode(&payload).unwrap();
    assert_eq!(tip.header.frame_id, "base");

    // A Twist with rmw_zenoh's attachment on the ROS 2 cmd_vel key moves the tip.
    let cmd_vel = rmw::data_key::<Twist>(domain, "/snakectl/cmd_vel");
    let teleop = rmw::Node {
        domain,
        zid: "1234abcd".into(),
        id: 0,
        enclave: "/".into(),
        namespace: "/".into(),
        name: "teleop_twist_keyboard".into(),
    };
    let teleop_gid = rmw::gid(&teleop.entity_token::<Twist>(
        1,
        EntityKind::Publisher,
        "/snakectl/cmd_vel",
        &qos,
    ));
    let v = [0.04, 0.0];
    for sequence in 1..=30 {
        let attachment = Attachment {
            sequence,
            source_timestamp_ns: ns_now(),
            gid: teleop_gid,
        };
        peer.put_attached(&cmd_vel, twist(v[0], v[1]), attachment.encode().to_vec())
            .unwrap();
        // The stream's own pace (20 Hz), not a wait for anything.
        std::thread::sleep(Duration::from_millis(50));
    }
    let moved = client.status();
    assert!(
        xy(&moved["tip"])[0] - xy(&start["tip"])[0] > 0.5 * v[0] * 1.0,
        "1.5 s of cmd_vel at {v:?} moved the tip from {} to {}",
        start["tip"],
        moved["tip"]
    );
    assert_eq!(moved["controller"], json!(1), "the network holds control");
    daemon.stop().unwrap();
}

#[test]
fn a_sample_on_a_ros2_key_without_the_attachment_is_refused_and_said_so() {
    let port = free_port();
    let daemon = Daemon::start(config_with(&ros2_table("snakectl", port, 0)));
    let mut client = daemon.client();
    let start = at_rest(&mut client);
    let peer = peer(port);
    let events = peer.subscribe("snakectl/events").unwrap();

    // What rmw_zenoh would drop: refused, naming the attachment and the plain key.
    let cmd_vel = rmw::data_key::<Twist>(0, "/snakectl/cmd_vel");
    peer.put(&cmd_vel, twist(0.05, 0.0)).unwrap();
    let refused = next_json(&events, "a refusal", |e| e["ok"] == json!(false));
    assert_eq!(refused["error"]["code"], json!("bad_arg"), "{refused}");
    let message = refused["error"]["message"].as_str().unwrap();
    assert!(message.contains("attachment"), "{message}");
    assert!(message.contains("snakectl/cmd_vel"), "{message}");
    // A keyed attachment of rmw_zenoh before 0.2.4 is not this one either.
    let mut keyed = vec![15u8];
    keyed.extend_from_slice(b"sequence_number");
    keyed.extend_from_slice(&[0; 40]);
    peer.put_attached(&cmd_vel, twist(0.05, 0.0), keyed)
        .unwrap();
    next_json(&events, "a refusal", |e| e["ok"] == json!(false));
    let end = client.status();
    assert_eq!(end["tip_ref"], start["tip_ref"], "the arm moved");
    assert_eq!(end["controller"], Value::Null);

    // The plain key takes plain samples.
    stream_cmd_vel(&peer, "snakectl", [0.04, 0.0], 1.0);
    let moved = client.status();
    assert_ne!(
        moved["tip_ref"], start["tip_ref"],
        "the plain cmd_vel did not move the arm"
    );
    daemon.stop().unwrap();
}
