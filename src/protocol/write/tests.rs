//! The lines as written: their keys, values and escaping.

#![allow(clippy::unwrap_used)]

use std::sync::Arc;

use serde_json::json;

use super::*;
use crate::protocol::{
    Applied, CmdName, Code, CommandInfo, Counters, Describe, FaultChange, FaultInfo, FaultKind,
    LoadUnit, Outcome, Reply, State, Unsubscribed, What, PROTOCOL_VERSION, STRATEGIES,
};
use crate::resolve::Strategy;

fn read(line: &str) -> Value {
    assert!(line.ends_with('\n'), "{line:?} lacks its newline");
    assert_eq!(
        line.matches('\n').count(),
        1,
        "{line:?} is more than one line"
    );
    serde_json::from_str(line).unwrap()
}

pub(crate) fn telemetry() -> Telemetry {
    Telemetry {
        tick: 42,
        t_s: 0.42,
        state: State::Moving,
        strategy: Strategy::Sequential,
        tip_ref: [0.1, 0.2],
        tip: [0.1, 0.25],
        tip_meas: [0.11, 0.2],
        target: Some([0.3, 0.4]),
        theta_cmd: vec![0.1, 0.2, 0.3],
        theta_meas: vec![0.1, 0.2, 0.31],
        omega_meas: vec![0.0, -1.0, 0.5],
        tracking_error_m: 0.01,
        saturated: true,
        self_collision: true,
        min_clearance_m: Some(-0.0125),
        blocked: true,
        command: Some(CommandInfo {
            kind: CmdName::Goto,
            id: Some(Arc::new(json!("g1"))),
            outcome: Outcome::Active,
            peak_joint_speed_rad_s: 1.5,
            m3_rad2: 0.02,
        }),
        solve_us: 12.5,
        loop_hz: 99.9,
        tick_p99_us: 80.0,
        overruns: 3,
        behind: true,
        peak_joint_speed_rad_s: 2.0,
        m3_total_rad2: 0.5,
        faults: vec![FaultInfo {
            id: Some(2),
            joint: Some(2),
            port: None,
            kind: FaultKind::Silent,
            since_tick: 37,
            detail: "no reply".into(),
        }],
        warnings: vec![FaultInfo {
            id: Some(3),
            joint: Some(3),
            port: None,
            kind: FaultKind::Temperature,
            since_tick: 40,
            detail: "hot".into(),
        }],
        torque: true,
        temperature_c: vec![30.0, 31.0, 32.0],
        voltage_v: vec![12.0, 12.0, 11.9],
        load: vec![0.0, 1.5, -0.2],
        load_unit: vec![LoadUnit::Percent, LoadUnit::Percent, LoadUnit::Amps],
        health_tick: 40,
        counters: Counters {
            dropped: 1,
            corrupted: 2,
            retries: 3,
            clamped: 4,
        },
    }
}

#[test]
fn ok_reply_puts_id_ok_and_the_fields_flat() {
    let mut more = Map::new();
    more.insert("rate_hz".into(), json!(50.0));
    let fields = Fields {
        reply: Reply::Applied(Applied { tick: 17 }),
        more,
    };
    let line = ok_line(Some(&json!({"n": [1, "x"]})), &fields);
    assert_eq!(
        read(&line),
        json!({"id": {"n": [1, "x"]}, "ok": true, "tick": 17, "rate_hz": 50.0})
    );
    assert!(
        line.starts_with(r#"{"id":{"n":[1,"x"]},"ok":true,"#),
        "{line}"
    );
}

#[test]
fn ok_reply_without_id_has_null_and_keeps_its_own_keys() {
    let mut more = Map::new();
    more.insert("id".into(), json!("forged"));
    more.insert("ok".into(), json!(false));
    more.insert("type".into(), json!("telemetry"));
    more.insert("x".into(), json!(1));
    let fields = Fields {
        reply: Reply::Unsubscribed(Unsubscribed {}),
        more,
    };
    assert_eq!(
        read(&ok_line(None, &fields)),
        json!({"id": null, "ok": true, "x": 1})
    );
}

#[test]
fn error_reply_carries_code_and_message() {
    let why = Rejection::new(Code::BadArg, "`target[1]`: expected a number, got \"a\"");
    assert_eq!(
        read(&error_line(Some(&json!(3)), &why)),
        json!({"id": 3, "ok": false, "error": {
            "code": "bad_arg", "message": "`target[1]`: expected a number, got \"a\""}})
    );
    let why = Rejection::new(Code::TooManyClients, "full");
    assert_eq!(
        read(&reply_line(None, &Err(why))),
        json!({"id": null, "ok": false, "error": {"code": "too_many_clients", "message": "full"}})
    );
}

#[test]
fn every_code_is_written_as_its_wire_name() {
    let codes = [
        Code::BadJson,
        Code::UnknownCmd,
        Code::BadArg,
        Code::LineTooLong,
        Code::Estopped,
        Code::Unreachable,
        Code::Busy,
        Code::ShuttingDown,
        Code::NotInControl,
        Code::Unauthorized,
        Code::Fault,
        Code::TooManyClients,
    ];
    for code in codes {
        let line = error_line(None, &Rejection::new(code, ""));
        assert_eq!(read(&line)["error"]["code"], json!(code.as_str()));
    }
}

#[test]
fn telemetry_line_is_tagged_and_status_fields_name_the_same() {
    let t = telemetry();
    let status = Status {
        telemetry: &t,
        controller: Some(3),
        in_control: true,
    };
    let line = read(&telemetry_line(&status));
    let fields = t.to_fields();
    assert_eq!(line["type"], json!("telemetry"));
    let mut expected = fields.clone();
    expected.insert("type".into(), json!("telemetry"));
    expected.insert("controller".into(), json!(3));
    expected.insert("in_control".into(), json!(true));
    assert_eq!(line, Value::Object(expected));
    let names: Vec<&str> = fields.keys().map(String::as_str).collect();
    let mut wanted = vec![
        "tick",
        "t_s",
        "state",
        "strategy",
        "tip_ref",
        "tip",
        "tip_meas",
        "target",
        "theta_cmd",
        "theta_meas",
        "omega_meas",
        "tracking_error_m",
        "saturated",
        "self_collision",
        "min_clearance_m",
        "blocked",
        "command",
        "solve_us",
        "loop_hz",
        "tick_p99_us",
        "overruns",
        "behind",
        "peak_joint_speed_rad_s",
        "m3_total_rad2",
        "faults",
        "warnings",
        "torque",
        "temperature_c",
        "voltage_v",
        "load",
        "load_unit",
        "health_tick",
        "counters",
    ];
    wanted.sort_unstable();
    assert_eq!(names, wanted);
    assert_eq!(fields["state"], json!("moving"));
    assert_eq!(fields["strategy"], json!("sequential"));
    assert_eq!(fields["command"]["id"], json!("g1"));
    assert_eq!(fields["command"]["kind"], json!("goto"));
    assert_eq!(fields["command"]["outcome"], json!("active"));
    assert_eq!(fields["faults"][0]["kind"], json!("silent"));
    assert_eq!(fields["warnings"][0]["kind"], json!("temperature"));
    assert_eq!(fields["load_unit"], json!(["percent", "percent", "A"]));
    assert_eq!(fields["counters"]["clamped"], json!(4));
}

#[test]
fn a_non_finite_telemetry_number_is_written_as_null() {
    let t = Telemetry {
        loop_hz: f64::NAN,
        ..Telemetry::default()
    };
    assert_eq!(
        read(&telemetry_line(&Status::of(&t)))["loop_hz"],
        Value::Null
    );
}

#[test]
fn describe_fields_name_every_field() {
    let d = Describe {
        links_m: vec![0.1, 0.2],
        base: [0.0, 0.0, 1.5],
        min_rad: vec![-1.0, -2.0],
        max_rad: vec![1.0, 2.0],
        ids: vec![1, 2],
        models: vec!["XL430-W250".into(), "XL330-M288".into()],
        home_rad: vec![0.0, 0.1],
        rate_hz: 100.0,
        strategies: STRATEGIES.to_vec(),
        protocol_version: PROTOCOL_VERSION,
        link_radius_m: 0.012,
        clearance_m: 0.005,
        read: "sync".into(),
    };
    assert_eq!(
        Value::Object(d.to_fields()),
        json!({"links_m": [0.1, 0.2], "base": [0.0, 0.0, 1.5], "min_rad": [-1.0, -2.0],
               "max_rad": [1.0, 2.0], "ids": [1, 2], "models": ["XL430-W250", "XL330-M288"],
               "home_rad": [0.0, 0.1], "rate_hz": 100.0,
               "strategies": ["overall", "sequential"], "protocol_version": PROTOCOL_VERSION,
               "link_radius_m": 0.012, "clearance_m": 0.005, "read": "sync"})
    );
}

#[test]
fn event_line_has_cmd_id_and_reason_only_when_given() {
    let mut event = Event {
        owner: Some(3),
        cmd_id: Some(Arc::new(json!(9))),
        tick: 120,
        what: What::Preempted {
            tip: [0.5, -0.25],
            reason: CmdName::Goto,
        },
    };
    assert_eq!(
        read(&event_line(&event)),
        json!({"type": "event", "event": "preempted", "cmd_id": 9, "tick": 120,
               "tip": [0.5, -0.25], "reason": "goto"})
    );
    event.cmd_id = None;
    event.what = What::Estop { tip: [0.5, -0.25] };
    assert_eq!(
        read(&event_line(&event)),
        json!({"type": "event", "event": "estop", "tick": 120, "tip": [0.5, -0.25]})
    );
    event.what = What::Fault {
        tip: [0.5, -0.25],
        reason: FaultChange::Raised,
        fault: FaultInfo {
            id: Some(5),
            joint: Some(5),
            port: None,
            kind: FaultKind::Silent,
            since_tick: 116,
            detail: "no reply".into(),
        },
    };
    assert_eq!(
        read(&event_line(&event)),
        json!({"type": "event", "event": "fault", "tick": 120, "tip": [0.5, -0.25],
               "reason": "raised", "fault": {"id": 5, "joint": 5, "port": null, "kind": "silent",
               "since_tick": 116, "detail": "no reply"}})
    );
    event.what = What::Control {
        holder: Some(4),
        previous: None,
    };
    event.cmd_id = Some(Arc::new(json!("t")));
    assert_eq!(
        read(&event_line(&event)),
        json!({"type": "event", "event": "control", "holder": 4, "previous": null,
               "cmd_id": "t", "tick": 120})
    );
}

#[test]
fn strings_are_escaped_inside_one_line() {
    let why = Rejection::new(Code::BadArg, "a\nb\"c\u{1}");
    let line = error_line(Some(&json!("x\ny")), &why);
    let back = read(&line);
    assert_eq!(back["id"], json!("x\ny"));
    assert_eq!(back["error"]["message"], json!("a\nb\"c\u{1}"));
}
