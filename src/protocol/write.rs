//! Writing the lines of the wire format: replies, telemetry, events, and requests (for clients).
//!
//! Each function builds its line in one buffer, the JSON written straight into it, and returns
//! it as a `String` ending in `'\n'`. Serializing these types cannot fail (every map key is a
//! string, no `Serialize` impl refuses); were it ever to, the value would be written as `null`
//! rather than leave a broken line.

use std::borrow::Borrow;

use serde::Serialize;
use serde_json::{Map, Value};

use super::{Answer, Cmd, Event, Fields, Rejection, Status, Telemetry, Wire};

/// An ok reply: `{"id": ID, "ok": true, ...fields}` (`"id": null` without an id).
pub fn ok_line(id: Option<&Value>, fields: &Fields) -> String {
    let fields = fields.to_map();
    let mut line = Line::with_capacity(64 + 32 * fields.len());
    line.field("id", id.unwrap_or(&Value::Null));
    line.field("ok", &true);
    for (key, value) in &fields {
        line.field(key, value);
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

/// The reply line of `answer`: [`ok_line`] or [`error_line`].
pub fn reply_line(id: Option<&Value>, answer: &Answer) -> String {
    match answer {
        Ok(fields) => ok_line(id, fields),
        Err(rejection) => error_line(id, rejection),
    }
}

/// A telemetry line: `{"type": "telemetry", ...}` with every [`Telemetry`] field, and who is in
/// control.
pub fn telemetry_line<T: Borrow<Telemetry> + Serialize>(status: &Status<T>) -> String {
    #[derive(Serialize)]
    struct Tagged<'a, T: Serialize> {
        #[serde(rename = "type")]
        kind: &'static str,
        #[serde(flatten)]
        status: &'a Status<T>,
    }
    let joints = status.theta_cmd.len();
    let mut buf = Vec::with_capacity(800 + 72 * joints);
    put(
        &mut buf,
        &Tagged {
            kind: "telemetry",
            status,
        },
    );
    buf.push(b'\n');
    into_string(buf)
}

/// An event line: `{"type": "event", "event": NAME, ...what it carries, "cmd_id": ID?,
/// "tick": N}` (`cmd_id` only when the event has one).
pub fn event_line(event: &Event) -> String {
    #[derive(Serialize)]
    struct Tagged<'a> {
        #[serde(rename = "type")]
        kind: &'static str,
        #[serde(flatten)]
        event: &'a Event,
    }
    let mut buf = Vec::with_capacity(160);
    put(
        &mut buf,
        &Tagged {
            kind: "event",
            event,
        },
    );
    buf.push(b'\n');
    into_string(buf)
}

/// A request line, as a client sends it: `{"cmd": NAME, "id": ID?, ...args}`. What
/// [`parse`](super::parse()) reads back to the same command.
pub fn request_line(id: Option<&Value>, cmd: &Cmd) -> String {
    let mut line = Line::with_capacity(64);
    line.field("cmd", &cmd.name());
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
        Cmd::Reach { target } => line.field("target", target),
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
        Cmd::SetWorld { obstacles } => {
            let list: Vec<Wire<'_>> = obstacles.iter().map(Wire).collect();
            line.field("obstacles", &list);
        }
        Cmd::AddObstacle { obstacle } => line.field("obstacle", &Wire(obstacle)),
        Cmd::RemoveObstacle { id } => line.field("obstacle", id),
        Cmd::World
        | Cmd::Describe
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
pub(super) mod tests;
