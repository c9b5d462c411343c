//! Every request, reply, event and telemetry field written and read back by the same types;
//! the one name table; what a newer daemon may add (fields, events) read without error.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use serde_json::{json, Map};

use super::*;
use crate::chain::{Chain, JointLimit, Vec2};
use crate::resolve::Strategy;
use crate::world::{CheckedObstacle, Obstacles};

const JOINTS: usize = 3;

/// A command of each name, every optional argument given.
fn example(name: CmdName) -> Cmd {
    match name {
        CmdName::Describe => Cmd::Describe,
        CmdName::Status => Cmd::Status,
        CmdName::Goto => Cmd::Goto {
            target: [0.25, -0.5],
            speed: Some(0.05),
        },
        CmdName::GotoJoints => Cmd::GotoJoints {
            theta: vec![0.1, -0.2, 0.3],
        },
        CmdName::Reach => Cmd::Reach {
            target: [-0.3, 0.45],
        },
        CmdName::Path => Cmd::Path {
            points: vec![[0.1, 0.2], [-0.3, 0.4]],
            speed: Some(0.02),
        },
        CmdName::Velocity => Cmd::Velocity { v: [0.01, -0.02] },
        CmdName::Jog => Cmd::Jog {
            joint: 3,
            rad_s: -0.5,
        },
        CmdName::Stop => Cmd::Stop,
        CmdName::Estop => Cmd::Estop,
        CmdName::Reset => Cmd::Reset,
        CmdName::Home => Cmd::Home,
        CmdName::Strategy => Cmd::Strategy {
            name: Strategy::Sequential,
        },
        CmdName::Subscribe => Cmd::Subscribe { rate_hz: 25.0 },
        CmdName::Unsubscribe => Cmd::Unsubscribe,
        CmdName::ResetStats => Cmd::ResetStats,
        CmdName::TakeControl => Cmd::TakeControl,
        CmdName::Release => Cmd::Release,
        CmdName::Auth => Cmd::Auth {
            token: "s3cret \"quoted\"".into(),
        },
        CmdName::Torque => Cmd::Torque { on: false },
        CmdName::Reboot => Cmd::Reboot {
            ids: Some(vec![3, 1]),
        },
        CmdName::World => Cmd::World,
        CmdName::SetWorld => Cmd::SetWorld {
            obstacles: Obstacles::new(obstacles()).unwrap(),
        },
        CmdName::AddObstacle => Cmd::AddObstacle {
            obstacle: CheckedObstacle::new(obstacles().remove(1)).unwrap(),
        },
        CmdName::RemoveObstacle => Cmd::RemoveObstacle {
            id: "post \"2\"".into(),
        },
    }
}

/// A circle and a polygon.
fn obstacles() -> Vec<crate::world::Obstacle> {
    use crate::world::{Obstacle, Shape};
    vec![
        Obstacle {
            id: "post".into(),
            shape: Shape::Circle {
                center: Vec2::new(0.15, -0.6),
                radius_m: 0.04,
            },
        },
        Obstacle {
            id: "shelf".into(),
            shape: Shape::Polygon {
                points: vec![
                    Vec2::new(-0.6, 0.3),
                    Vec2::new(-0.4, 0.3),
                    Vec2::new(-0.4, 0.34),
                    Vec2::new(-0.6, 0.34),
                ],
            },
        },
    ]
}

fn world_info() -> WorldInfo {
    WorldInfo {
        link_radius_m: 0.012,
        clearance_m: 0.005,
        obstacles: obstacles(),
    }
}

/// The reply to a command of each name, every field set to something other than its default.
fn reply_to(name: CmdName) -> Reply {
    match name {
        CmdName::Describe => Reply::Describe(Arc::new(describe())),
        CmdName::Status => Reply::Status(Box::new(Status {
            telemetry: write::tests::telemetry(),
            controller: Some(7),
            in_control: true,
        })),
        CmdName::Subscribe => Reply::Subscribed(Subscribed { rate_hz: 12.5 }),
        CmdName::Unsubscribe => Reply::Unsubscribed(Unsubscribed {}),
        CmdName::TakeControl => Reply::TookControl(TookControl {
            client: 4,
            holder: Some(4),
            previous: Some(2),
        }),
        CmdName::Release => Reply::Released(Released {
            client: 4,
            holder: Some(9),
        }),
        CmdName::Auth => Reply::Admitted(Admitted { client: 5 }),
        CmdName::Reboot => Reply::Rebooted(Rebooted {
            tick: 99,
            rebooted: vec![1, 9],
        }),
        CmdName::World => Reply::World(Box::new(world_info())),
        CmdName::Estop | CmdName::Torque => Reply::TorqueOff(TorqueOff {
            tick: 62,
            unconfirmed: vec![Unconfirmed {
                joint: 3,
                id: 7,
                why: "did not confirm torque off in the time allowed".into(),
            }],
        }),
        CmdName::Goto
        | CmdName::GotoJoints
        | CmdName::Reach
        | CmdName::Path
        | CmdName::Velocity
        | CmdName::Jog
        | CmdName::Stop
        | CmdName::Reset
        | CmdName::Home
        | CmdName::Strategy
        | CmdName::ResetStats => Reply::Applied(Applied { tick: 61 }),
        CmdName::SetWorld | CmdName::AddObstacle | CmdName::RemoveObstacle => {
            Reply::WorldChanged(WorldChanged {
                tick: 63,
                not_clear: Some(PoseNotClear {
                    link: 4,
                    obstacle: "post".into(),
                    clearance_m: -0.0125,
                    keep_m: 0.017,
                }),
            })
        }
    }
}

fn describe() -> Describe {
    Describe {
        links_m: vec![0.1, 0.2, 0.15],
        base: [0.5, -0.25, 1.5],
        min_rad: vec![f64::MIN, -2.0, -1.0],
        max_rad: vec![f64::MAX, 2.0, 1.5],
        ids: vec![1, 2, 7],
        models: vec![
            "XL430-W250".into(),
            "XM430-W350".into(),
            "XL330-M288".into(),
        ],
        home_rad: vec![0.1, 0.2, 0.3],
        rate_hz: 250.0,
        strategies: STRATEGIES.to_vec(),
        protocol_version: PROTOCOL_VERSION,
        link_radius_m: 0.012,
        clearance_m: 0.004,
        read: "fast".into(),
    }
}

fn fault() -> FaultInfo {
    FaultInfo::servo(
        9,
        9,
        Some("/dev/ttyUSB0".into()),
        FaultKind::HardwareError,
        300,
        "overload (0x20)".into(),
    )
}

/// An event of each name, everything it carries set.
fn event_of(kind: EventKind) -> What {
    let tip = [0.25, -0.75];
    match kind {
        EventKind::Arrived => What::Arrived { tip },
        EventKind::Saturated => What::Saturated { tip },
        EventKind::Preempted => What::Preempted {
            tip,
            reason: CmdName::Velocity,
        },
        EventKind::Stopped => What::Stopped {
            tip,
            reason: StopReason::Deadman,
        },
        EventKind::Estop => What::Estop { tip },
        EventKind::Reset => What::Reset { tip },
        EventKind::Fault => What::Fault {
            tip,
            reason: FaultChange::Recovered,
            fault: fault(),
        },
        EventKind::Warning => What::Warning {
            tip,
            reason: FaultChange::Cleared,
            fault: FaultInfo {
                kind: FaultKind::Voltage,
                ..fault()
            },
        },
        EventKind::Control => What::Control {
            holder: None,
            previous: Some(3),
        },
        EventKind::ShuttingDown => What::ShuttingDown { tip },
        EventKind::World => What::World {
            by: 4,
            world: Box::new(world_info()),
        },
        EventKind::NotClear => What::NotClear {
            tip,
            link: 7,
            obstacle: "post".into(),
            clearance_m: -0.02,
            keep_m: 0.005,
        },
        EventKind::Clear => What::Clear {
            tip,
            min_clearance_m: Some(0.0125),
        },
        EventKind::Blocked => What::Blocked {
            tip,
            link: 3,
            obstacle: "shelf".into(),
        },
    }
}

fn object(line: &str) -> Map<String, Value> {
    match serde_json::from_str(line).unwrap() {
        Value::Object(map) => map,
        other => panic!("{other}"),
    }
}

#[test]
fn the_name_table_is_one() {
    assert_eq!(COMMANDS.len(), CmdName::ALL.len());
    for (name, text) in CmdName::ALL.into_iter().zip(COMMANDS) {
        assert_eq!(name.as_str(), text);
        assert_eq!(name, text);
        assert_eq!(CmdName::from_name(text), Some(name));
        assert_eq!(serde_json::to_value(name).unwrap(), json!(text));
        assert_eq!(
            serde_json::from_value::<CmdName>(json!(text)).unwrap(),
            name
        );
        assert_eq!(example(name).name(), name, "{text}");
    }
    assert_eq!(CmdName::from_name("dance"), None);
    let mut sorted = COMMANDS.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    assert_eq!(sorted.len(), COMMANDS.len(), "names are distinct");
}

#[test]
fn every_request_round_trips_with_every_argument() {
    for name in CmdName::ALL {
        let cmd = example(name);
        for id in [None, Some(json!(17)), Some(json!({"k": ["x", null]}))] {
            let line = request_line(id.as_ref(), &cmd);
            let back = parse(line.trim_end().as_bytes(), JOINTS)
                .unwrap_or_else(|(_, why)| panic!("{line}: {why}"));
            assert_eq!(back.cmd, cmd, "{line}");
            assert_eq!(back.id.as_deref(), id.as_ref(), "{line}");
        }
    }
    // Optional arguments left out are written as absent, and read back so.
    for cmd in [
        Cmd::Goto {
            target: [0.0, 0.1],
            speed: None,
        },
        Cmd::Path {
            points: vec![[0.0, 0.1]],
            speed: None,
        },
        Cmd::Reboot { ids: None },
    ] {
        let line = request_line(None, &cmd);
        assert!(!line.contains("speed") && !line.contains("ids"), "{line}");
        assert_eq!(parse(line.trim_end().as_bytes(), JOINTS).unwrap().cmd, cmd);
    }
}

#[test]
fn every_command_is_routed_once_keeping_its_name_and_need() {
    for name in CmdName::ALL {
        let cmd = example(name);
        assert_eq!(cmd.need(), name.need());
        assert_eq!(Need::of(&cmd), name.need());
        match cmd.clone().route() {
            Route::Session(session) => {
                assert_eq!(session.name(), name);
                // What the socket side answers never needs control.
                assert_eq!(name.need(), Need::Nothing, "{name}");
            }
            Route::Loop(loop_cmd) => {
                assert_eq!(loop_cmd.name(), name);
                assert_eq!(CmdName::from(&loop_cmd), name);
                assert_eq!(Cmd::from(loop_cmd), cmd, "back to the same command");
            }
        }
    }
    let session: Vec<CmdName> = CmdName::ALL
        .into_iter()
        .filter(|&n| matches!(example(n).route(), Route::Session(_)))
        .collect();
    assert_eq!(
        session,
        [
            CmdName::Describe,
            CmdName::Subscribe,
            CmdName::Unsubscribe,
            CmdName::TakeControl,
            CmdName::Release,
            CmdName::Auth
        ]
    );
    let motions: Vec<CmdName> = CmdName::ALL
        .into_iter()
        .filter(|&n| matches!(example(n).route(), Route::Loop(LoopCmd::Motion(_))))
        .collect();
    assert_eq!(
        motions,
        [
            CmdName::Goto,
            CmdName::GotoJoints,
            CmdName::Reach,
            CmdName::Path,
            CmdName::Velocity,
            CmdName::Jog,
            CmdName::Home
        ]
    );
}

#[test]
fn every_reply_round_trips_for_the_command_it_answers() {
    for name in CmdName::ALL {
        let fields = Fields::from(reply_to(name));
        for id in [None, Some(json!("r1"))] {
            let line = ok_line(id.as_ref(), &fields);
            let ServerLine::Reply(ReplyLine { id: back, result }) =
                read_line(line.trim_end()).unwrap()
            else {
                panic!("{line} is not a reply");
            };
            assert_eq!(back.as_deref(), id.as_ref());
            let read = Fields::read(name, result.unwrap()).unwrap();
            assert_eq!(read, fields, "{name}: {line}");
            assert!(read.more.is_empty(), "{name}: every field is named");
            assert_eq!(read.reply.tick(), fields.reply.tick());
        }
    }
    // A refusal, of any code.
    let why = Rejection::new(Code::NotInControl, "client 3 holds it");
    let line = reply_line(Some(&json!(4)), &Err(why.clone()));
    assert_eq!(
        read_line(line.trim_end()).unwrap(),
        ServerLine::Reply(ReplyLine {
            id: Some(Arc::new(json!(4))),
            result: Err(why)
        })
    );
}

#[test]
fn a_status_reply_and_a_telemetry_line_carry_every_telemetry_field() {
    let status = Status {
        telemetry: write::tests::telemetry(),
        controller: Some(7),
        in_control: true,
    };
    // Every field of the sample differs from its default, so each one is seen to come back.
    let sample = status.telemetry.to_fields();
    let default = Telemetry::default().to_fields();
    for (key, value) in &sample {
        assert_ne!(
            Some(value),
            default.get(key),
            "`{key}` is its default in the sample"
        );
    }
    let line = telemetry_line(&Status {
        telemetry: &status.telemetry,
        controller: status.controller,
        in_control: status.in_control,
    });
    assert_eq!(
        read_line(line.trim_end()).unwrap(),
        ServerLine::Telemetry(Box::new(status.clone()))
    );
    let reply = ok_line(None, &Reply::Status(Box::new(status.clone())).into());
    let mut reply_keys: Vec<String> = object(&reply).keys().cloned().collect();
    let mut line_keys: Vec<String> = object(&line).keys().cloned().collect();
    reply_keys.retain(|k| k != "id" && k != "ok");
    line_keys.retain(|k| k != "type");
    reply_keys.sort();
    line_keys.sort();
    assert_eq!(
        reply_keys, line_keys,
        "a status reply names what a telemetry line does"
    );
    assert_eq!(reply_keys.len(), sample.len() + 2);
}

#[test]
fn every_event_round_trips() {
    for kind in EventKind::ALL {
        let what = event_of(kind);
        assert_eq!(what.kind(), Some(kind));
        assert_eq!(what.name(), kind.as_str());
        for cmd_id in [None, Some(Arc::new(json!({"seq": 3})))] {
            let event = Event {
                owner: Some(12),
                cmd_id: cmd_id.clone(),
                tick: 812,
                what: what.clone(),
            };
            let line = event_line(&event);
            let map = object(&line);
            assert_eq!(map["event"], json!(kind.as_str()));
            assert_eq!(map.contains_key("cmd_id"), cmd_id.is_some(), "{line}");
            assert!(
                !map.contains_key("owner"),
                "the owner is the daemon's: {line}"
            );
            assert_eq!(
                read_line(line.trim_end()).unwrap(),
                ServerLine::Event(Event {
                    owner: None,
                    ..event
                }),
                "{line}"
            );
        }
    }
}

#[test]
fn what_a_newer_daemon_adds_is_not_an_error() {
    // A field this version does not know, in each kind of line.
    let mut telemetry = object(&telemetry_line(&Status::of(&write::tests::telemetry())));
    telemetry.insert("battery_v".into(), json!(11.1));
    let line = Value::Object(telemetry).to_string();
    let ServerLine::Telemetry(status) = read_line(&line).unwrap() else {
        panic!("{line}");
    };
    assert_eq!(status.telemetry, write::tests::telemetry());

    let mut event = object(&event_line(&Event {
        owner: None,
        cmd_id: None,
        tick: 5,
        what: event_of(EventKind::Stopped),
    }));
    event.insert("severity".into(), json!("low"));
    let line = Value::Object(event).to_string();
    assert!(
        matches!(read_line(&line).unwrap(), ServerLine::Event(e) if e.what == event_of(EventKind::Stopped))
    );

    let mut reply = object(&ok_line(None, &reply_to(CmdName::Goto).into()));
    reply.insert("queued_ms".into(), json!(3));
    let line = Value::Object(reply).to_string();
    let ServerLine::Reply(ReplyLine {
        result: Ok(fields), ..
    }) = read_line(&line).unwrap()
    else {
        panic!("{line}");
    };
    let fields = Fields::read(CmdName::Goto, fields).unwrap();
    assert_eq!(fields.reply, reply_to(CmdName::Goto));
    assert_eq!(
        fields.more.get("queued_ms"),
        Some(&json!(3)),
        "kept, not lost"
    );
    assert_eq!(fields.to_map()["queued_ms"], json!(3));

    // An event this version does not know, by name.
    let line = r#"{"type":"event","event":"battery_low","cmd_id":2,"tick":9,"volts":10.9}"#;
    let ServerLine::Event(event) = read_line(line).unwrap() else {
        panic!("{line}");
    };
    assert_eq!(
        event.what,
        What::Other {
            name: "battery_low".into()
        }
    );
    assert_eq!(event.kind(), None);
    assert_eq!((event.tick, event.cmd_id.as_deref()), (9, Some(&json!(2))));
    // And written back by name.
    assert_eq!(object(&event_line(&event))["event"], json!("battery_low"));
}

#[test]
fn lines_that_do_not_read_are_errors() {
    for line in [
        "",
        "not json",
        "[1]",
        r#"{"type": 3}"#,
        r#"{"type": "weather"}"#,
        r#"{"id": 1}"#,
        r#"{"id": 1, "ok": "yes"}"#,
        r#"{"id": 1, "ok": false}"#,
        r#"{"id": 1, "ok": false, "error": {"code": "tired", "message": ""}}"#,
        r#"{"type": "telemetry", "state": "dancing"}"#,
        r#"{"type": "telemetry", "strategy": "greedy"}"#,
        r#"{"type": "event", "tick": 1}"#,
        r#"{"type": "event", "event": "estop"}"#,
        r#"{"type": "event", "event": "stopped", "tick": 1, "tip": [0, 0], "reason": "tired"}"#,
    ] {
        assert!(read_line(line).is_err(), "{line} was read");
    }
    // A reply with its `ok` but not the fields of the command it answers.
    let ServerLine::Reply(ReplyLine {
        result: Ok(fields), ..
    }) = read_line(r#"{"id": 1, "ok": true, "rate_hz": "fast"}"#).unwrap()
    else {
        panic!();
    };
    assert!(Fields::read(CmdName::Subscribe, fields.clone()).is_err());
    assert!(Fields::read(CmdName::Stop, fields).is_err(), "no tick");
}

#[test]
fn numbers_written_as_null_read_back_as_nan() {
    let t = Telemetry {
        loop_hz: f64::NAN,
        tip: [f64::INFINITY, 1.0],
        theta_meas: vec![0.5, f64::NAN],
        ..Telemetry::default()
    };
    let line = telemetry_line(&Status::of(&t));
    let ServerLine::Telemetry(back) = read_line(line.trim_end()).unwrap() else {
        panic!("{line}");
    };
    assert!(back.loop_hz.is_nan());
    assert!(back.tip[0].is_nan() && back.tip[1] == 1.0);
    assert!(back.theta_meas[0] == 0.5 && back.theta_meas[1].is_nan());
}

#[test]
fn closed_sets_are_written_as_the_strings_they_always_were() {
    fn wire<T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug>(
        value: T,
        text: &str,
    ) {
        assert_eq!(serde_json::to_value(&value).unwrap(), json!(text));
        assert_eq!(serde_json::from_value::<T>(json!(text)).unwrap(), value);
    }
    for (state, text) in [
        (State::Moving, "moving"),
        (State::Holding, "holding"),
        (State::Stopping, "stopping"),
        (State::Estop, "estop"),
        (State::Fault, "fault"),
        (State::TorqueOff, "torque_off"),
    ] {
        wire(state, text);
        assert_eq!(state.as_str(), text);
    }
    for (outcome, text) in [
        (Outcome::Active, "active"),
        (Outcome::Arrived, "arrived"),
        (Outcome::Saturated, "saturated"),
        (Outcome::Preempted, "preempted"),
        (Outcome::Stopped, "stopped"),
        (Outcome::Estop, "estop"),
        (Outcome::Fault, "fault"),
    ] {
        wire(outcome, text);
    }
    for (kind, text) in [
        (FaultKind::Silent, "silent"),
        (FaultKind::HardwareError, "hardware_error"),
        (FaultKind::Port, "port"),
        (FaultKind::Watchdog, "watchdog"),
        (FaultKind::PowerLoss, "power_loss"),
        (FaultKind::Contact, "contact"),
        (FaultKind::Temperature, "temperature"),
        (FaultKind::Voltage, "voltage"),
    ] {
        wire(kind, text);
        assert_eq!(kind.as_str(), text);
        assert_eq!(kind.is_warning(), matches!(text, "temperature" | "voltage"));
    }
    for (reason, text) in [
        (StopReason::Stop, "stop"),
        (StopReason::Deadman, "deadman"),
        (StopReason::Fault, "fault"),
        (StopReason::Torque, "torque"),
        (StopReason::Reboot, "reboot"),
        (StopReason::Shutdown, "shutdown"),
        (StopReason::NotClear, "not_clear"),
    ] {
        wire(reason, text);
        assert_eq!(reason.as_str(), text);
    }
    for (change, text) in [
        (FaultChange::Raised, "raised"),
        (FaultChange::Cleared, "cleared"),
        (FaultChange::Recovered, "recovered"),
    ] {
        wire(change, text);
        assert_eq!(change.as_str(), text);
    }
    for kind in EventKind::ALL {
        wire(kind, kind.as_str());
        assert_eq!(EventKind::from_name(kind.as_str()), Some(kind));
    }
    wire(LoadUnit::Percent, "percent");
    wire(LoadUnit::Amps, "A");
    for (i, strategy) in STRATEGIES.into_iter().enumerate() {
        assert_eq!(values::strategy_index(strategy), i);
        assert_eq!(strategy_named(strategy.name()), Some(strategy));
    }
    assert_eq!(strategy_named("greedy"), None);
}

#[test]
fn a_fault_or_a_warning_event_follows_the_kind() {
    let tip = [0.0, 1.0];
    assert!(matches!(
        What::alarm(tip, FaultChange::Raised, fault()),
        What::Fault { .. }
    ));
    let warm = FaultInfo {
        kind: FaultKind::Temperature,
        ..fault()
    };
    assert!(matches!(
        What::alarm(tip, FaultChange::Raised, warm),
        What::Warning { .. }
    ));
}

#[test]
fn a_description_gives_back_the_chain_it_was_made_from() {
    let chain = Chain::new(
        vec![0.1, 0.2, 0.15],
        Vec2::new(0.5, -0.25),
        1.5,
        vec![
            None,
            Some(JointLimit { lo: -2.0, hi: 2.0 }),
            Some(JointLimit { lo: -1.0, hi: 1.5 }),
        ],
    )
    .unwrap();
    let d = Describe::of_chain(
        &chain,
        vec![1, 2, 7],
        vec![
            "XL430-W250".into(),
            "XM430-W350".into(),
            "XL330-M288".into(),
        ],
        vec![0.1, 0.2, 0.3],
        250.0,
    );
    assert_eq!(
        (d.link_radius_m, d.clearance_m),
        (0.0, 0.0),
        "no world given"
    );
    let world = crate::world::World::new(0.012, 0.004, vec![]).unwrap();
    let d = d.with_world(&world);
    assert_eq!(d.read, "", "the read is the daemon's to say");
    let d = Describe {
        read: "fast".into(),
        ..d
    };
    assert_eq!(d, describe());
    assert_eq!(d.chain().unwrap(), chain);
    let unlimited = Describe {
        min_rad: Vec::new(),
        max_rad: Vec::new(),
        ..describe()
    };
    assert!(!unlimited.chain().unwrap().is_limited());
}

#[test]
fn a_port_fault_names_the_port_with_id_and_joint_null() {
    let port = FaultInfo::port(Some("/dev/ttyUSB0".into()), 12, "gone".into());
    let wire = serde_json::to_value(&port).unwrap();
    assert_eq!(wire["id"], Value::Null, "{wire}");
    assert_eq!(wire["joint"], Value::Null, "{wire}");
    assert_eq!(wire["port"], json!("/dev/ttyUSB0"));
    assert_eq!(wire["kind"], json!("port"));
    assert_eq!(serde_json::from_value::<FaultInfo>(wire).unwrap(), port);
    assert_eq!(port.to_string(), "port /dev/ttyUSB0: port (gone)");
    // A servo's fault carries its id, joint and the port it is on.
    let servo = serde_json::to_value(fault()).unwrap();
    assert_eq!(
        (&servo["id"], &servo["joint"], &servo["port"]),
        (&json!(9), &json!(9), &json!("/dev/ttyUSB0"))
    );
    assert_eq!(
        fault().to_string(),
        "servo 9 (joint 9): hardware_error (overload (0x20))"
    );
    // An older daemon's line without `port` still reads.
    let old: FaultInfo = serde_json::from_value(json!({
        "id": 3, "joint": 3, "kind": "silent", "since_tick": 4, "detail": "quiet"
    }))
    .unwrap();
    assert_eq!((old.id, old.joint, old.port), (Some(3), Some(3), None));
}
