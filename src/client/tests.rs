//! The client against a scripted daemon on a loopback socket: typed replies, events and
//! telemetry; lines it cannot read surfaced with the line; unknown fields and events tolerated;
//! how a motion command ends; a daemon that stops reading times a request's write out; the
//! queue of arrivals bounded by bytes, nothing in it lost.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};

use serde_json::json;

use super::*;
use crate::protocol::{Applied, ClientId, Counters, Rebooted};

/// A daemon that answers by script: it reads request lines and writes what the test says.
struct Scripted {
    lines: BufReader<TcpStream>,
    out: TcpStream,
}

impl Scripted {
    /// A listener, a client connected to it, and the daemon's end.
    fn start() -> (Client, Scripted) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let client = Client::connect(&addr, None).unwrap();
        let (stream, _) = listener.accept().unwrap();
        let out = stream.try_clone().unwrap();
        (
            client,
            Scripted {
                lines: BufReader::new(stream),
                out,
            },
        )
    }

    /// The next request line, parsed.
    fn request(&mut self) -> protocol::Request {
        let mut line = String::new();
        self.lines.read_line(&mut line).unwrap();
        protocol::parse(line.trim_end().as_bytes(), 3).unwrap()
    }

    fn send(&mut self, line: &str) {
        self.out.write_all(line.as_bytes()).unwrap();
        if !line.ends_with('\n') {
            self.out.write_all(b"\n").unwrap();
        }
    }
}

const WAIT: Duration = Duration::from_secs(10);

fn sim_describe() -> Describe {
    Describe {
        links_m: vec![1.0, 1.0],
        base: [1.0, 2.0, std::f64::consts::FRAC_PI_2],
        min_rad: vec![f64::MIN, -2.0],
        max_rad: vec![f64::MAX, 2.0],
        ids: vec![1, 2],
        models: vec!["XL430-W250".into(); 2],
        home_rad: vec![0.0, 0.0],
        rate_hz: 100.0,
        strategies: protocol::STRATEGIES.to_vec(),
        protocol_version: protocol::PROTOCOL_VERSION,
        ..Describe::default()
    }
}

#[test]
fn the_arm_draws_with_its_chain() {
    let arm = ArmInfo::new(sim_describe()).unwrap();
    let p = arm.points(&[0.0, -std::f64::consts::FRAC_PI_2]);
    let expected = [[1.0, 2.0], [1.0, 3.0], [2.0, 3.0]];
    assert_eq!(p.len(), 3);
    for (got, want) in p.iter().zip(expected) {
        assert!((got[0] - want[0]).abs() < 1e-12 && (got[1] - want[1]).abs() < 1e-12);
    }
    assert_eq!(arm.reach(), 2.0);
    assert_eq!(arm.inner_radius(), 0.0);
    // Joint 1 is unlimited (written as the extreme floats), joint 2 limited.
    assert_eq!(arm.chain().limits()[0], None);
    assert!(arm.chain().limits()[1].is_some());
    // A pose of the wrong length draws nothing rather than panic.
    assert!(arm.points(&[0.0]).is_empty());
    assert_eq!(arm.rate_hz, 100.0, "an arm reads as its description");
    let mut bad = sim_describe();
    bad.links_m = Vec::new();
    assert!(ArmInfo::new(bad).is_err());
}

#[test]
fn a_refused_connection_says_no_daemon_listens() {
    // Bind and drop: the port is then (almost certainly) closed.
    let addr = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    };
    let err = Client::connect(&addr.to_string(), None)
        .err()
        .unwrap_or_else(|| panic!("connected to a closed port"));
    let text = err.to_string();
    assert!(
        text.contains("no daemon is listening on 127.0.0.1"),
        "{text}"
    );
    assert!(text.contains("--connect"), "{text}");
}

#[test]
fn token_files_are_read_as_the_daemon_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("token");
    std::fs::write(&path, "  s3cret \nsecond line\n").unwrap();
    assert_eq!(read_token(&path).unwrap(), "s3cret");
    std::fs::write(&path, "\n").unwrap();
    let err = read_token(&path)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(err.contains("the token file is empty"), "{err}");
    // A token below a blank first line is not read, and the file is not called empty.
    std::fs::write(&path, "\n s3cret\n").unwrap();
    let err = read_token(&path)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        err.contains("the first line of the token file is blank")
            && err.contains("line 2 is not read"),
        "{err}"
    );
}

#[test]
fn replies_are_typed_by_the_command_they_answer() {
    let (mut client, mut daemon) = Scripted::start();
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        assert_eq!(r.cmd, Cmd::Describe);
        let describe = json!({"id": r.id.as_deref().unwrap(), "ok": true});
        let mut line = describe.as_object().unwrap().clone();
        line.extend(sim_describe().to_fields());
        daemon.send(&Value::Object(line).to_string());
        let r = daemon.request();
        assert_eq!(r.cmd, Cmd::Reboot { ids: None });
        let id = r.id.as_deref().unwrap().clone();
        // A field this version does not know is kept, not refused.
        daemon.send(
            &json!({"id": id, "ok": true, "tick": 7, "rebooted": [1, 2], "later": "x"}).to_string(),
        );
        let r = daemon.request();
        assert_eq!(r.cmd, Cmd::TakeControl);
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(
            &json!({"id": id, "ok": true, "client": 4, "holder": 4, "previous": null}).to_string(),
        );
        let r = daemon.request();
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(
            &json!({"id": id, "ok": false, "error": {"code": "estopped", "message": "latched"}})
                .to_string(),
        );
        daemon
    });
    let arm = client.describe().unwrap();
    assert_eq!(arm.describe(), &sim_describe());
    let fields = client.request(&Cmd::Reboot { ids: None }).unwrap();
    assert_eq!(
        fields.reply,
        Reply::Rebooted(Rebooted {
            tick: 7,
            rebooted: vec![1, 2]
        })
    );
    assert_eq!(fields.more.get("later"), Some(&json!("x")));
    assert_eq!(fields.to_map()["later"], json!("x"));
    let took = client.take_control().unwrap();
    assert_eq!(took.client, 4);
    assert_eq!(client.client_id(), Some(4 as ClientId));
    let err = client
        .request(&Cmd::Goto {
            target: [0.1, 0.2],
            speed: None,
        })
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::Estopped));
    assert!(
        err.to_string()
            .contains("`goto` refused: estopped: latched"),
        "{err}"
    );
    worker.join().unwrap();
}

#[test]
fn a_line_the_client_cannot_read_is_an_error_with_the_line_and_the_rest_goes_on() {
    let (mut client, mut daemon) = Scripted::start();
    let id = client.send(&Cmd::Stop).unwrap();
    let r = daemon.request();
    assert_eq!(r.cmd, Cmd::Stop);
    for garbage in [
        "not json at all",
        "[1, 2]",
        r#"{"type": "gossip", "tick": 1}"#,
        r#"{"type": "telemetry", "tick": "soon"}"#,
        r#"{"type": "event", "event": "arrived", "tick": 3}"#,
        r#"{"id": 9, "nothing": true}"#,
        r#"{"id": null, "ok": false, "error": {"code": "no_such_code", "message": "?"}}"#,
    ] {
        daemon.send(garbage);
        match client.next(WAIT) {
            Err(ClientError::Unreadable { line, .. }) => assert_eq!(line, garbage),
            other => panic!("{garbage}: {other:?}"),
        }
    }
    // An ok reply to an id this client never sent.
    daemon.send(r#"{"id": 12345, "ok": true, "tick": 1}"#);
    assert!(
        matches!(client.next(WAIT), Err(ClientError::Stray { line }) if line.contains("12345"))
    );
    // A reply without the fields of its command.
    daemon.send(&json!({"id": id, "ok": true, "tick": "late"}).to_string());
    match client.next(WAIT) {
        Err(ClientError::BadReply { cmd, line, .. }) => {
            assert_eq!(cmd, CmdName::Stop);
            assert!(line.contains("late"), "{line}");
        }
        other => panic!("{other:?}"),
    }
    // And the connection serves on.
    let id = client.send(&Cmd::Stop).unwrap();
    daemon.request();
    daemon.send(&json!({"id": id, "ok": true, "tick": 8}).to_string());
    match client.next(WAIT).unwrap() {
        Some(Incoming::Reply(Replied {
            cmd: Some(CmdName::Stop),
            result: Ok(fields),
            ..
        })) => assert_eq!(fields.reply, Reply::Applied(Applied { tick: 8 })),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_request_meets_an_unreadable_line_as_an_error_and_its_reply_comes_later() {
    let (mut client, mut daemon) = Scripted::start();
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        daemon.send("{broken");
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(&json!({"id": id, "ok": true, "tick": 5}).to_string());
        daemon
    });
    match client.request(&Cmd::Reset) {
        Err(ClientError::Unreadable { line, .. }) => assert_eq!(line, "{broken"),
        other => panic!("{other:?}"),
    }
    let _daemon = worker.join().unwrap();
    match client.next(WAIT).unwrap() {
        Some(Incoming::Reply(Replied {
            cmd: Some(CmdName::Reset),
            result: Ok(fields),
            ..
        })) => assert_eq!(fields.reply.tick(), Some(5)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn unknown_fields_and_events_are_not_errors() {
    let (mut client, mut daemon) = Scripted::start();
    daemon.send(
        r#"{"type": "event", "event": "arrived", "cmd_id": 1, "tick": 3, "tip": [0.5, 1], "new": {"a": 1}}"#,
    );
    daemon.send(r#"{"type": "event", "event": "sparkle", "tick": 4, "colour": "blue"}"#);
    let mut telemetry = Telemetry::default().to_fields();
    telemetry.insert("type".into(), json!("telemetry"));
    telemetry.insert("tick".into(), json!(77));
    telemetry.insert("controller".into(), json!(2));
    telemetry.insert("brand_new".into(), json!([1, 2, 3]));
    daemon.send(&Value::Object(telemetry).to_string());
    match client.next(WAIT).unwrap() {
        Some(Incoming::Event(event)) => {
            assert_eq!(event.what, What::Arrived { tip: [0.5, 1.0] });
            assert_eq!(event.cmd_id.as_deref(), Some(&json!(1)));
        }
        other => panic!("{other:?}"),
    }
    match client.next(WAIT).unwrap() {
        Some(Incoming::Event(event)) => {
            assert_eq!(
                event.what,
                What::Other {
                    name: "sparkle".into()
                }
            );
            assert_eq!(event.kind(), None);
            assert_eq!(event.tick, 4);
        }
        other => panic!("{other:?}"),
    }
    let line = client.wait_telemetry(WAIT).unwrap().unwrap();
    assert_eq!(line.status.tick, 77);
    assert_eq!(line.status.controller, Some(2));
    assert_eq!(line.status.counters, Counters::default());
    assert!(
        line.line.contains("brand_new"),
        "the line is kept as it came"
    );
}

#[test]
fn a_motion_ends_by_its_own_events_and_by_estops_and_faults_after_it() {
    let motion = Motion {
        id: 7,
        cmd: CmdName::Goto,
        accepted: 100,
    };
    let tip = [0.1, 0.2];
    let event = |cmd_id: Option<u64>, tick: u64, what: What| Event {
        owner: None,
        cmd_id: cmd_id.map(|id| Arc::new(json!(id))),
        tick,
        what,
    };
    let fault = FaultInfo {
        id: Some(3),
        joint: Some(3),
        port: None,
        kind: FaultKind::Silent,
        since_tick: 101,
        detail: "no reply".into(),
    };
    let cases = [
        (event(Some(7), 150, What::Arrived { tip }), Some("arrived at (0.1000, 0.2000) m, tick 150")),
        (event(Some(8), 150, What::Arrived { tip }), None),
        (event(None, 150, What::Arrived { tip }), None),
        (
            event(Some(7), 120, What::Saturated { tip }),
            Some(
                "saturated: the tip stopped short at (0.1000, 0.2000) m, tick 120: the target is out \
                 of reach, or a joint at its limit or the arm's own links held it",
            ),
        ),
        (
            event(Some(7), 120, What::Preempted { tip, reason: CmdName::Stop }),
            Some("preempted by `stop` at (0.1000, 0.2000) m, tick 120"),
        ),
        (
            event(Some(7), 120, What::Stopped { tip, reason: StopReason::Fault }),
            Some("stopped (fault) at (0.1000, 0.2000) m, tick 120"),
        ),
        (event(None, 100, What::Estop { tip }), Some("estop: emergency stop at (0.1000, 0.2000) m, tick 100")),
        (event(None, 99, What::Estop { tip }), None),
        (
            event(None, 101, What::Fault { tip, reason: FaultChange::Raised, fault: fault.clone() }),
            Some("fault: servo 3 (joint 3): silent (no reply), at (0.1000, 0.2000) m, tick 101"),
        ),
        (event(None, 101, What::Fault { tip, reason: FaultChange::Cleared, fault }), None),
        (
            event(Some(7), 140, What::Blocked { tip, link: 4, obstacle: "post".into() }),
            Some("blocked: link 4 cannot follow past obstacle \"post\" without losing its clearance; the arm holds at (0.1000, 0.2000) m, tick 140"),
        ),
        (event(Some(8), 140, What::Blocked { tip, link: 4, obstacle: "post".into() }), None),
        (event(None, 140, What::NotClear { tip, link: 4, obstacle: "post".into(), clearance_m: -0.01, keep_m: 0.005 }), None),
        (event(Some(7), 130, What::Reset { tip }), None),
        (event(Some(7), 130, What::Other { name: "new".into() }), None),
    ];
    for (event, expected) in cases {
        let got = motion.ending(&event).map(|e| e.to_string());
        assert_eq!(got.as_deref(), expected, "{event:?}");
    }
}

#[test]
fn wait_ending_shows_everything_before_the_ending() {
    let (mut client, mut daemon) = Scripted::start();
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        let id = r.id.as_deref().unwrap().clone();
        // An event before the reply: its order against it is not fixed.
        daemon.send(&json!({"type": "event", "event": "preempted", "cmd_id": "other", "tick": 10, "tip": [0, 0], "reason": "goto"}).to_string());
        daemon.send(&json!({"id": id, "ok": true, "tick": 10}).to_string());
        let mut t = Telemetry::default().to_fields();
        t.insert("type".into(), json!("telemetry"));
        t.insert("tick".into(), json!(11));
        daemon.send(&Value::Object(t).to_string());
        std::thread::sleep(Duration::from_millis(50));
        daemon.send(&json!({"type": "event", "event": "arrived", "cmd_id": id, "tick": 30, "tip": [0.3, 0.4]}).to_string());
        daemon
    });
    let motion = client
        .start_motion(&Cmd::Goto {
            target: [0.3, 0.4],
            speed: None,
        })
        .unwrap();
    assert_eq!(motion.accepted, 10);
    let mut seen = Vec::new();
    let ending = client
        .wait_ending(&motion, WAIT, |what| -> Result<(), ClientError> {
            seen.push(match what {
                Seen::Telemetry(t) => format!("telemetry {}", t.status.tick),
                Seen::Event(e) => format!("event {}", e.what.name()),
                Seen::Reply(_) => "reply".into(),
            });
            Ok(())
        })
        .unwrap();
    assert_eq!(
        ending,
        Some(Ending::Arrived {
            tick: 30,
            tip: [0.3, 0.4]
        })
    );
    assert_eq!(seen, ["event preempted", "telemetry 11", "event arrived"]);
    worker.join().unwrap();
}

#[test]
fn a_closed_connection_names_the_last_refusal() {
    let (mut client, mut daemon) = Scripted::start();
    daemon.send(
        r#"{"id": null, "ok": false, "error": {"code": "too_many_clients", "message": "full"}}"#,
    );
    drop(daemon);
    match client.next(WAIT).unwrap() {
        Some(Incoming::Reply(Replied { result: Err(r), .. })) => {
            assert_eq!(r.code, Code::TooManyClients)
        }
        other => panic!("{other:?}"),
    }
    let err = client.next(WAIT).unwrap_err();
    assert!(err.is_closed());
    assert_eq!(err.code(), Some(Code::TooManyClients));
    assert!(err.to_string().contains("too_many_clients: full"), "{err}");
}

#[test]
fn the_world_commands_are_sent_in_the_sockets_shape_and_the_reply_is_typed() {
    use crate::chain::Vec2;

    let post = Obstacle {
        id: "post".into(),
        shape: Shape::Circle {
            center: Vec2::new(0.15, 0.6),
            radius_m: 0.04,
        },
    };
    let (mut client, mut daemon) = Scripted::start();
    let sent = post.clone();
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        assert_eq!(r.cmd, Cmd::World);
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(
            &json!({"id": id, "ok": true, "link_radius_m": 0.012, "clearance_m": 0.005,
                    "obstacles": [{"id": "post", "circle": {"center": [0.15, 0.6], "radius": 0.04}}]})
            .to_string(),
        );
        let r = daemon.request();
        assert_eq!(
            r.cmd,
            Cmd::SetWorld {
                obstacles: Obstacles::new(vec![sent.clone()]).unwrap()
            }
        );
        daemon.send(&json!({"id": r.id.as_deref().unwrap(), "ok": true, "tick": 3}).to_string());
        let r = daemon.request();
        assert_eq!(
            r.cmd,
            Cmd::AddObstacle {
                obstacle: CheckedObstacle::new(sent).unwrap()
            }
        );
        daemon.send(&json!({"id": r.id.as_deref().unwrap(), "ok": true, "tick": 4}).to_string());
        let r = daemon.request();
        assert_eq!(r.cmd, Cmd::RemoveObstacle { id: "post".into() });
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(
            &json!({"id": id, "ok": false,
                    "error": {"code": "bad_arg", "message": "`obstacle`: no obstacle has the id \"post\""}})
            .to_string(),
        );
        daemon
    });
    let world = client.world().unwrap();
    assert_eq!(
        world,
        WorldInfo {
            link_radius_m: 0.012,
            clearance_m: 0.005,
            obstacles: vec![post.clone()],
        }
    );
    assert_eq!(client.set_world(vec![post.clone()]).unwrap(), 3);
    assert_eq!(client.add_obstacle(post).unwrap(), 4);
    let err = client.remove_obstacle("post").unwrap_err();
    assert_eq!(err.code(), Some(Code::BadArg));
    worker.join().unwrap();
}

#[test]
fn a_timeout_of_duration_max_waits_as_long_as_it_takes() {
    let (mut client, mut daemon) = Scripted::start();
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(&json!({"id": id, "ok": true, "tick": 5}).to_string());
        daemon.send(
            &json!({"type": "event", "event": "reset", "tick": 6, "tip": [0, 0]}).to_string(),
        );
        let mut t = Telemetry::default().to_fields();
        t.insert("type".into(), json!("telemetry"));
        t.insert("tick".into(), json!(7));
        daemon.send(&Value::Object(t).to_string());
        daemon
    });
    let fields = client.request_within(&Cmd::Reset, Duration::MAX).unwrap();
    assert_eq!(fields.reply.tick(), Some(5));
    match client.next(Duration::MAX).unwrap() {
        Some(Incoming::Event(event)) => assert_eq!(event.tick, 6),
        other => panic!("{other:?}"),
    }
    let telemetry = client.wait_telemetry(Duration::MAX).unwrap().unwrap();
    assert_eq!(telemetry.status.tick, 7);
    // Once the daemon has gone, the longest wait ends at once with the closed connection.
    drop(worker.join().unwrap());
    assert!(client.next(Duration::MAX).unwrap_err().is_closed());
    assert!(client
        .wait_telemetry(Duration::MAX)
        .unwrap_err()
        .is_closed());
}

#[test]
fn a_daemon_that_stops_reading_fails_the_send_with_a_write_timeout_and_the_connection_closes() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let mut client = Client::connect(&addr, None).unwrap();
    // Accepted, and never read.
    let (_daemon, _) = listener.accept().unwrap();
    let timeout = Duration::from_millis(100);
    client.set_write_timeout(timeout);
    let (done, outcome) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        // The longest requests fill the socket's buffers, on both sides, in a few sends.
        let path = Cmd::Path {
            points: vec![
                [-0.512_345_678_901_234, 0.712_345_678_901_234];
                protocol::MAX_PATH_POINTS
            ],
            speed: None,
        };
        let failed = loop {
            if let Err(e) = client.send(&path) {
                break e;
            }
        };
        let after = client.send(&Cmd::Stop);
        let _ = done.send((failed, after));
    });
    let (failed, after) = outcome
        .recv_timeout(WAIT)
        .expect("a send still blocks on a daemon that stopped reading");
    match &failed {
        ClientError::WriteTimeout {
            addr: at,
            cmd,
            timeout: waited,
        } => {
            assert_eq!(at, &addr);
            assert_eq!(*cmd, CmdName::Path);
            assert_eq!(*waited, timeout);
        }
        other => panic!("not a write timeout: {other}"),
    }
    let text = failed.to_string();
    assert!(
        text.contains(&format!(
            "the daemon at {addr} took no `path` request within 100 ms"
        )),
        "{text}"
    );
    assert!(failed.is_closed(), "{failed:?}");
    // A line may be half sent: the connection is closed, and the next request is told so.
    assert!(after.unwrap_err().is_closed());
}

/// A tip on an axis reads 0.0000 there, not -0.0000 (a round-off below zero is no place).
#[test]
fn an_ending_on_an_axis_shows_no_negative_zero() {
    let e = Ending::Arrived {
        tick: 41783,
        tip: [-1.7e-17, 0.85],
    };
    assert_eq!(e.to_string(), "arrived at (0.0000, 0.8500) m, tick 41783");
    let e = Ending::Arrived {
        tick: 7,
        tip: [-0.00006, -0.0],
    };
    assert_eq!(e.to_string(), "arrived at (-0.0001, 0.0000) m, tick 7");
}

/// An event line of a little over 1 MiB (a field this client does not know pads it), with its
/// newline: ticks of two digits give every such line the same length.
fn big_event(tick: usize) -> String {
    let pad = "x".repeat(1 << 20);
    format!(
        "{}\n",
        json!({"type": "event", "event": "sparkle", "tick": tick, "pad": pad})
    )
}

/// The ticks of the events read with `next` until it errs, and the error.
fn events_until_error(client: &mut Client) -> (Vec<u64>, ClientError) {
    let mut ticks = Vec::new();
    loop {
        match client.next(WAIT) {
            Ok(Some(Incoming::Event(event))) => ticks.push(event.tick),
            Err(e) => return (ticks, e),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn a_caller_that_reads_nothing_holds_at_most_queue_bytes_of_lines_and_loses_none() {
    let (mut client, daemon) = Scripted::start();
    const LINES: usize = 40;
    let len = big_event(10).len();
    let (told, blocked) = std::sync::mpsc::channel();
    let writer = std::thread::spawn(move || {
        let mut out = daemon.out;
        let all: String = (10..10 + LINES).map(big_event).collect();
        let all = all.as_bytes();
        // A write that takes nothing for a second: the client has stopped reading.
        out.set_write_timeout(Some(Duration::from_secs(1))).unwrap();
        let (mut sent, mut waited) = (0, false);
        while sent < all.len() {
            match out.write(&all[sent..]) {
                Ok(n) => sent += n,
                Err(e)
                    if !waited
                        && matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                {
                    waited = true;
                    told.send(Some(sent)).unwrap();
                    out.set_write_timeout(None).unwrap();
                }
                Err(e) => panic!("{e}"),
            }
        }
        if !waited {
            told.send(None).unwrap();
        }
        out
    });
    // Some 40 MiB sent at a caller that reads nothing: the client holds some, the socket's
    // buffers some, and the daemon's writes wait.
    let sent = blocked.recv().unwrap();
    assert!(
        sent.is_some(),
        "the client took all {LINES} lines of {len} bytes while its caller read none"
    );
    let queued = client.shared.inbox().queue.len();
    assert!(
        queued > 0 && queued * len <= QUEUE_BYTES,
        "{queued} lines of {len} bytes queued"
    );
    // Nothing is lost: every line comes, in order.
    for tick in 10..10 + LINES {
        match client.next(WAIT).unwrap() {
            Some(Incoming::Event(event)) => assert_eq!(event.tick, tick as u64),
            other => panic!("{other:?}"),
        }
    }
    let _out = writer.join().unwrap();
}

#[test]
fn a_request_behind_a_queue_full_of_bytes_gets_its_reply() {
    let (mut client, mut daemon) = Scripted::start();
    // 12 MiB of events, more than the queue holds for a caller that reads nothing, then the
    // reply: the request lets the queue grow to find it.
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        for tick in 10..22 {
            daemon.send(&big_event(tick));
        }
        let id = r.id.as_deref().unwrap().clone();
        daemon.send(&json!({"id": id, "ok": true, "tick": 5}).to_string());
        daemon
    });
    let fields = client.request(&Cmd::Stop).unwrap();
    assert_eq!(fields.reply.tick(), Some(5));
    let _daemon = worker.join().unwrap();
    for tick in 10..22 {
        match client.next(WAIT).unwrap() {
            Some(Incoming::Event(event)) => assert_eq!(event.tick, tick),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn a_request_behind_more_than_max_queue_bytes_closes_the_connection_and_keeps_what_came() {
    let (mut client, mut daemon) = Scripted::start();
    let len = big_event(10).len();
    // 40 MiB of events before the reply: more than the client holds for a request.
    let worker = std::thread::spawn(move || {
        let r = daemon.request();
        for tick in 10..50 {
            if daemon.out.write_all(big_event(tick).as_bytes()).is_err() {
                return;
            }
        }
        let id = r.id.as_deref().unwrap().clone();
        let reply = json!({"id": id, "ok": true, "tick": 5}).to_string() + "\n";
        let _ = daemon.out.write_all(reply.as_bytes());
    });
    let err = client.request(&Cmd::Stop).unwrap_err();
    assert!(
        matches!(
            err,
            ClientError::Backlog {
                max: MAX_QUEUE_BYTES,
                ..
            }
        ),
        "{err:?}"
    );
    assert!(err.is_closed());
    assert!(
        err.to_string().contains(&format!(
            "sent over {MAX_QUEUE_BYTES} bytes of replies and events"
        )),
        "{err}"
    );
    // What came before the bound is read, in order, then the same error.
    let (ticks, after) = events_until_error(&mut client);
    assert!(matches!(after, ClientError::Backlog { .. }), "{after:?}");
    assert_eq!(ticks, (10..10 + ticks.len() as u64).collect::<Vec<_>>());
    assert!(
        ticks.len() * len > QUEUE_BYTES && ticks.len() * len <= MAX_QUEUE_BYTES,
        "{} lines of {len} bytes",
        ticks.len()
    );
    // Gone, the client's socket no longer takes the daemon's writes.
    drop(client);
    worker.join().unwrap();
}

/// A line over the cap closes the connection: every read after it says so, as a closed
/// connection, so that a loop that reads on past errors that leave it open (`watch`) stops.
#[test]
fn a_line_over_the_cap_is_a_closed_connection() {
    let (mut client, mut daemon) = Scripted::start();
    daemon.send(&"A".repeat(MAX_REPLY_LINE + 1));
    for _ in 0..2 {
        let err = client.next(WAIT).unwrap_err();
        assert!(matches!(err, ClientError::LineTooLong { .. }), "{err:?}");
        assert!(err.is_closed(), "{err}");
    }
    assert!(client.wait_telemetry(WAIT).unwrap_err().is_closed());
}
