//! Writing the lines of the wire format: replies, telemetry, events, and requests (for clients).
//!
//! Each function builds its line in one buffer, the JSON written straight into it, and returns
//! it as a `String` ending in `'\n'`. Serializing these types cannot fail (every map key is a
//! string, no `Serialize` impl refuses); were it ever to, the value would be written as `null`
//! rather than leave a broken line.

use serde::Serialize;
use serde_json::{Map, Value};

use super::{Cmd, Event, Rejection, Telemetry};

/// An ok reply: `{"id": ID, "ok": true, ...fields}` (`"id": null` without an id). Keys `id`,
/// `ok` and `type` in `fields` are left out: they are the line's own.
pub fn ok_line(id: Option<&Value>, fields: &Map<String, Value>) -> String {
    let mut line = Line::with_capacity(64 + 32 * fields.len());
    line.field("id", id.unwrap_or(&Value::Null));
    line.field("ok", &true);
    for (key, value) in fields {
        if !matches!(key.as_str(), "id" | "ok" | "type") {
            line.field(key, value);
        }
    }
    line.finish()
}

/// An error reply: `{"id": ID, "ok": false, "error": {"code": CODE, "message": TEXT}}`.
pub fn error_line(id: Option<&Value>, rejection: &Rejection) -> String {
    let mut line = Line::with_capacity(96 + rejection.message.len());
    line.field("id", id.unwrap_or(&Value::Null));
    line.field("ok", &false);
    line.field("error", rejection);
    line.finish()
}

/// A telemetry line: `{"type": "telemetry", ...}` with every [`Telemetry`] field.
pub fn telemetry_line(telemetry: &Telemetry) -> String {
    #[derive(Serialize)]
    struct Tagged<'a> {
        #[serde(rename = "type")]
        kind: &'static str,
        #[serde(flatten)]
        telemetry: &'a Telemetry,
    }
    let joints = telemetry.theta_cmd.len();
    let mut buf = Vec::with_capacity(768 + 72 * joints);
    put(
        &mut buf,
        &Tagged {
            kind: "telemetry",
            telemetry,
        },
    );
    buf.push(b'\n');
    into_string(buf)
}

/// An event line: `{"type": "event", "event": KIND, "cmd_id": ID?, "tick": .., "tip": [x, y],
/// "reason": ..?, "fault": {..}?}` (`cmd_id`, `reason` and `fault` only when the event has them).
pub fn event_line(event: &Event) -> String {
    let mut line = Line::with_capacity(128);
    line.field("type", "event");
    line.field("event", &event.kind);
    if let Some(id) = &event.cmd_id {
        line.field("cmd_id", &**id);
    }
    line.field("tick", &event.tick);
    line.field("tip", &event.tip);
    if let Some(reason) = event.reason {
        line.field("reason", reason);
    }
    if let Some(fault) = &event.fault {
        line.field("fault", fault);
    }
    line.finish()
}

/// A request line, as a client sends it: `{"cmd": NAME, "id": ID?, ...args}`. What
/// [`parse`](super::parse) reads back to the same command.
pub fn request_line(id: Option<&Value>, cmd: &Cmd) -> String {
    let mut line = Line::with_capacity(64);
    line.field("cmd", cmd.name());
    if let Some(id) = id {
        line.field("id", id);
    }
    match cmd {
        Cmd::Goto { target, speed } => {
            line.field("target", target);
            if let Some(speed) = speed {
                line.field("speed", speed);
            }
        }
        Cmd::GotoJoints { theta } => line.field("theta", theta),
        Cmd::Path { points, speed } => {
            line.field("points", points);
            if let Some(speed) = speed {
                line.field("speed", speed);
            }
        }
        Cmd::Velocity { v } => line.field("v", v),
        Cmd::Jog { joint, rad_s } => {
            line.field("joint", joint);
            line.field("rad_s", rad_s);
        }
        Cmd::Strategy { name } => line.field("name", name.name()),
        Cmd::Subscribe { rate_hz } => line.field("rate_hz", rate_hz),
        Cmd::Describe
        | Cmd::Status
        | Cmd::Stop
        | Cmd::Estop
        | Cmd::Reset
        | Cmd::Home
        | Cmd::Unsubscribe
        | Cmd::ResetStats
        | Cmd::TakeControl
        | Cmd::Release => {}
        Cmd::Auth { token } => line.field("token", token),
        Cmd::Torque { on } => line.field("on", on),
        Cmd::Reboot { ids } => {
            if let Some(ids) = ids {
                line.field("ids", ids);
            }
        }
    }
    line.finish()
}

/// The fields of a struct that serializes as a JSON object.
pub(super) fn fields_of<T: Serialize>(value: &T) -> Map<String, Value> {
    match serde_json::to_value(value) {
        Ok(Value::Object(fields)) => fields,
        _ => Map::new(),
    }
}

/// One JSON object being written, field by field, into its line.
struct Line {
    buf: Vec<u8>,
}

impl Line {
    fn with_capacity(capacity: usize) -> Self {
        let mut buf = Vec::with_capacity(capacity);
        buf.push(b'{');
        Line { buf }
    }

    fn field<T: Serialize + ?Sized>(&mut self, key: &str, value: &T) {
        if self.buf.len() > 1 {
            self.buf.push(b',');
        }
        put(&mut self.buf, key);
        self.buf.push(b':');
        put(&mut self.buf, value);
    }

    fn finish(mut self) -> String {
        self.buf.extend_from_slice(b"}\n");
        into_string(self.buf)
    }
}

/// Appends `value` as JSON (or `null`, should serializing fail).
fn put<T: Serialize + ?Sized>(buf: &mut Vec<u8>, value: &T) {
    let mark = buf.len();
    if serde_json::to_writer(&mut *buf, value).is_err() {
        buf.truncate(mark);
        buf.extend_from_slice(b"null");
    }
}

/// serde_json writes UTF-8 only; the lossy path is never taken.
fn into_string(buf: Vec<u8>) -> String {
    String::from_utf8(buf).unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use std::sync::Arc;

    use serde_json::json;

    use super::*;
    use crate::protocol::{
        Code, CommandInfo, Counters, Describe, EventKind, FaultInfo, State, PROTOCOL_VERSION,
    };

    fn read(line: &str) -> Value {
        assert!(line.ends_with('\n'), "{line:?} lacks its newline");
        assert_eq!(
            line.matches('\n').count(),
            1,
            "{line:?} is more than one line"
        );
        serde_json::from_str(line).unwrap()
    }

    fn telemetry() -> Telemetry {
        Telemetry {
            tick: 42,
            t_s: 0.42,
            state: State::Moving,
            strategy: "overall",
            tip_ref: [0.1, 0.2],
            tip: [0.1, 0.25],
            tip_meas: [0.11, 0.2],
            target: Some([0.3, 0.4]),
            theta_cmd: vec![0.1, 0.2, 0.3],
            theta_meas: vec![0.1, 0.2, 0.31],
            omega_meas: vec![0.0, -1.0, 0.5],
            tracking_error_m: 0.01,
            saturated: true,
            self_collision: false,
            command: Some(CommandInfo {
                kind: "goto",
                id: Some(Arc::new(json!("g1"))),
                outcome: "active",
                peak_joint_speed_rad_s: 1.5,
                m3_rad2: 0.02,
            }),
            solve_us: 12.5,
            loop_hz: 99.9,
            tick_p99_us: 80.0,
            overruns: 3,
            peak_joint_speed_rad_s: 2.0,
            m3_total_rad2: 0.5,
            faults: vec![FaultInfo {
                id: 2,
                joint: 2,
                kind: "silent",
                since_tick: 37,
                detail: "no reply".into(),
            }],
            warnings: Vec::new(),
            torque: true,
            temperature_c: vec![30.0, 31.0, 32.0],
            voltage_v: vec![12.0, 12.0, 11.9],
            load: vec![0.0, 1.5, -0.2],
            load_unit: vec!["percent", "percent", "A"],
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
        let mut fields = Map::new();
        fields.insert("tick".into(), json!(17));
        fields.insert("rate_hz".into(), json!(50.0));
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
        let mut fields = Map::new();
        fields.insert("id".into(), json!("forged"));
        fields.insert("ok".into(), json!(false));
        fields.insert("type".into(), json!("telemetry"));
        fields.insert("x".into(), json!(1));
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
            read(&error_line(None, &why)),
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
        let line = read(&telemetry_line(&t));
        let fields = t.to_fields();
        assert_eq!(line["type"], json!("telemetry"));
        let mut expected = fields.clone();
        expected.insert("type".into(), json!("telemetry"));
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
            "command",
            "solve_us",
            "loop_hz",
            "tick_p99_us",
            "overruns",
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
        assert_eq!(fields["command"]["id"], json!("g1"));
        assert_eq!(fields["faults"][0]["kind"], json!("silent"));
        assert_eq!(fields["counters"]["clamped"], json!(4));
    }

    #[test]
    fn a_non_finite_telemetry_number_is_written_as_null() {
        let t = Telemetry {
            loop_hz: f64::NAN,
            ..Telemetry::default()
        };
        assert_eq!(read(&telemetry_line(&t))["loop_hz"], Value::Null);
    }

    #[test]
    fn describe_fields_name_every_field() {
        let d = Describe {
            links_m: vec![0.1, 0.2],
            base: [0.0, 0.0, 1.5],
            min_rad: vec![-1.0, -2.0],
            max_rad: vec![1.0, 2.0],
            ids: vec![1, 2],
            models: vec!["XL430-W250", "XL330-M288"],
            home_rad: vec![0.0, 0.1],
            rate_hz: 100.0,
            strategies: vec!["overall", "sequential"],
            protocol_version: PROTOCOL_VERSION,
        };
        assert_eq!(
            Value::Object(d.to_fields()),
            json!({"links_m": [0.1, 0.2], "base": [0.0, 0.0, 1.5], "min_rad": [-1.0, -2.0],
                   "max_rad": [1.0, 2.0], "ids": [1, 2], "models": ["XL430-W250", "XL330-M288"],
                   "home_rad": [0.0, 0.1], "rate_hz": 100.0,
                   "strategies": ["overall", "sequential"], "protocol_version": PROTOCOL_VERSION})
        );
    }

    #[test]
    fn event_line_has_cmd_id_and_reason_only_when_given() {
        let mut event = Event {
            owner: Some(3),
            cmd_id: Some(Arc::new(json!(9))),
            kind: EventKind::Preempted,
            tick: 120,
            tip: [0.5, -0.25],
            reason: Some("goto"),
            fault: None,
        };
        assert_eq!(
            read(&event_line(&event)),
            json!({"type": "event", "event": "preempted", "cmd_id": 9, "tick": 120,
                   "tip": [0.5, -0.25], "reason": "goto"})
        );
        event.cmd_id = None;
        event.reason = None;
        event.kind = EventKind::Estop;
        assert_eq!(
            read(&event_line(&event)),
            json!({"type": "event", "event": "estop", "tick": 120, "tip": [0.5, -0.25]})
        );
        event.kind = EventKind::Fault;
        event.reason = Some("raised");
        event.fault = Some(FaultInfo {
            id: 5,
            joint: 5,
            kind: "silent",
            since_tick: 116,
            detail: "no reply".into(),
        });
        assert_eq!(
            read(&event_line(&event)),
            json!({"type": "event", "event": "fault", "tick": 120, "tip": [0.5, -0.25],
                   "reason": "raised", "fault": {"id": 5, "joint": 5, "kind": "silent",
                   "since_tick": 116, "detail": "no reply"}})
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
}
