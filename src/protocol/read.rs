//! Reading what the daemon sends a client: a reply, a telemetry line or an event line
//! ([`read_line`]), each by the same types the daemon writes it with.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;

use super::{Event, Rejection, ReplyLine, Status};

/// One line from the daemon, read.
#[derive(Debug, Clone, PartialEq)]
pub enum ServerLine {
    /// A reply; its fields are typed with the command it answers ([`super::Fields::read`]).
    Reply(ReplyLine),
    /// A telemetry line.
    Telemetry(Box<Status>),
    /// An event line.
    Event(Event),
}

/// Why a line from the daemon could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// Not JSON.
    #[error("not JSON: {0}")]
    NotJson(#[source] serde_json::Error),
    /// JSON, but not an object.
    #[error("not a JSON object")]
    NotObject,
    /// A `type` this version does not know.
    #[error("a line of unknown type {0}")]
    UnknownType(String),
    /// Neither `type` nor a boolean `ok`.
    #[error("neither a reply (no boolean `ok`) nor a telemetry or event line")]
    NotReply,
    /// An error reply whose `error` is not `{"code", "message"}` with a known code.
    #[error("an error reply that does not read: {0}")]
    Refusal(#[source] serde_json::Error),
    /// A telemetry line with a field of the wrong type.
    #[error("a telemetry line that does not read: {0}")]
    Telemetry(#[source] serde_json::Error),
    /// An event line with a field of the wrong type (a known event missing one).
    #[error("an event line that does not read: {0}")]
    Event(#[source] serde_json::Error),
}

/// Reads one line the daemon sent (without its newline).
///
/// A field this version does not know is ignored, and an event name it does not know reads as
/// [`super::What::Other`]; a line that is not JSON, not an object, of an unknown `type`, or with
/// a field of the wrong type is an error.
pub fn read_line(line: &str) -> Result<ServerLine, ReadError> {
    let value: Value = serde_json::from_str(line).map_err(ReadError::NotJson)?;
    let Value::Object(mut map) = value else {
        return Err(ReadError::NotObject);
    };
    match map.get("type") {
        None => {}
        Some(Value::String(kind)) if kind == "telemetry" => {
            return Status::deserialize(Value::Object(map))
                .map(|status| ServerLine::Telemetry(Box::new(status)))
                .map_err(ReadError::Telemetry)
        }
        Some(Value::String(kind)) if kind == "event" => {
            return Event::deserialize(Value::Object(map))
                .map(ServerLine::Event)
                .map_err(ReadError::Event)
        }
        Some(other) => return Err(ReadError::UnknownType(other.to_string())),
    }
    let ok = match map.remove("ok") {
        Some(Value::Bool(ok)) => ok,
        _ => return Err(ReadError::NotReply),
    };
    let id = match map.remove("id") {
        None | Some(Value::Null) => None,
        Some(id) => Some(Arc::new(id)),
    };
    let result = if ok {
        Ok(map)
    } else {
        let error = map.remove("error").unwrap_or(Value::Null);
        Err(Rejection::deserialize(error).map_err(ReadError::Refusal)?)
    };
    Ok(ServerLine::Reply(ReplyLine { id, result }))
}
