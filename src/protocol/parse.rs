//! Reading one request line: JSON first, then the command and its arguments, each checked
//! against the arm and named in the error when it is wrong.

use std::fmt;
use std::sync::Arc;

use serde_json::{Map, Value};

use super::{
    strategy_named, world_rejection, Cmd, CmdName, Code, Rejection, Request, RequestId, MAX_ARG,
    STRATEGIES,
};
use crate::chain::Num;
use crate::resolve::Strategy;
use crate::world::{CheckedObstacle, Obstacles};

mod obstacle;
mod strict;

/// The most corner points one `path` may have.
pub const MAX_PATH_POINTS: usize = 10_000;

/// The slowest `speed` of a `goto` or `path`, m/s (a micrometre a second). Slower moves are
/// no one's intent, and among obstacles their progress is below what the headway rule can
/// tell from a tip held back: at 1e-12 m/s a goto in free space ended `blocked` at once,
/// naming an obstacle a quarter of a metre away.
pub const MIN_SPEED_M_S: f64 = 1e-6;

/// The most servo ids one `reboot` may name: every id a servo may have (0 to
/// [`MAX_SERVO_ID`]).
const MAX_REBOOT_IDS: usize = MAX_SERVO_ID as usize + 1;

/// The largest id a Protocol 2.0 servo may have (253 is reserved, 254 is the broadcast id).
const MAX_SERVO_ID: u8 = 252;

/// Reads `bytes` as one JSON value, refusing an object with the same key twice at any depth
/// (as [`parse`] does: `serde_json` alone keeps the last of two equal keys). A duplicate key
/// is a data error ([`serde_json::Error::is_data`]) whose message names the key.
pub fn strict_json(bytes: &[u8]) -> serde_json::Result<Value> {
    strict::from_slice(bytes)
}

/// Reads one request line (without its newline) for an arm of `joints` joints.
///
/// # Returns
/// The request, or the id (when the line is an object with an `id`) and why it was refused:
/// [`Code::BadJson`] for a line that is not JSON, not an object, or holds a number JSON cannot
/// hold (`1e999`) or an object with the same key twice (at any depth; the message names the
/// key); [`Code::UnknownCmd`] for a missing or unknown `cmd` (the message lists the
/// known ones); [`Code::BadArg`] for a wrong argument, the message naming the field (`target[1]`)
/// and the value.
///
/// An optional argument given as `null` counts as absent.
///
/// # Example
/// ```
/// use snakectl::protocol::{parse, Cmd, Code};
///
/// let req = parse(br#"{"cmd": "goto", "id": 7, "target": [0.1, 0.2]}"#, 3).unwrap();
/// assert_eq!(req.cmd, Cmd::Goto { target: [0.1, 0.2], speed: None });
/// assert_eq!(req.id.as_deref(), Some(&serde_json::json!(7)));
///
/// let (id, why) = parse(br#"{"cmd": "jog", "id": "a", "joint": 4, "rad_s": 1}"#, 3).unwrap_err();
/// assert_eq!(id.as_deref(), Some(&serde_json::json!("a")));
/// assert_eq!(why.code, Code::BadArg);
/// assert!(why.message.contains("joint"));
/// ```
pub fn parse(line: &[u8], joints: usize) -> Result<Request, (Option<RequestId>, Rejection)> {
    let value = strict::from_slice(line).map_err(|e| {
        // A data error is a duplicate key, the only thing the reader refuses in valid JSON.
        let message = if e.is_data() {
            e.to_string()
        } else {
            format!("not JSON: {e}")
        };
        (None, Rejection::new(Code::BadJson, message))
    })?;
    let Value::Object(mut map) = value else {
        let message = format!("a request is a JSON object, got {}", Shown(&value));
        return Err((None, Rejection::new(Code::BadJson, message)));
    };
    let id = match map.remove("id") {
        None | Some(Value::Null) => None,
        Some(id) => Some(Arc::new(id)),
    };
    match command(map, joints) {
        Ok(cmd) => Ok(Request { id, cmd }),
        Err(why) => Err((id, why)),
    }
}

/// The command of a request object whose `id` was taken out.
fn command(mut map: Map<String, Value>, joints: usize) -> Result<Cmd, Rejection> {
    let name = match map.remove("cmd") {
        Some(Value::String(name)) => name,
        None | Some(Value::Null) => return Err(unknown(format_args!("missing `cmd`"))),
        Some(other) => {
            return Err(unknown(format_args!(
                "`cmd` must be a string, got {}",
                Shown(&other)
            )))
        }
    };
    let Some(known) = CmdName::from_name(&name) else {
        let known: Vec<&str> = CmdName::ALL.iter().map(|n| n.as_str()).collect();
        return Err(unknown(format_args!(
            "unknown cmd {}; known: {}",
            Shown(&Value::String(name)),
            known.join(", ")
        )));
    };
    let cmd = match known {
        CmdName::Describe => no_args(map, Cmd::Describe)?,
        CmdName::Status => no_args(map, Cmd::Status)?,
        CmdName::Stop => no_args(map, Cmd::Stop)?,
        CmdName::Estop => no_args(map, Cmd::Estop)?,
        CmdName::Reset => no_args(map, Cmd::Reset)?,
        CmdName::Home => no_args(map, Cmd::Home)?,
        CmdName::Unsubscribe => no_args(map, Cmd::Unsubscribe)?,
        CmdName::ResetStats => no_args(map, Cmd::ResetStats)?,
        CmdName::TakeControl => no_args(map, Cmd::TakeControl)?,
        CmdName::Release => no_args(map, Cmd::Release)?,
        CmdName::Auth => {
            let mut args = Args::new(map, known, &["token"])?;
            let token = string(Field::new("token"), args.required("token")?)?;
            Cmd::Auth { token }
        }
        CmdName::Torque => {
            let mut args = Args::new(map, known, &["on"])?;
            let on = boolean(Field::new("on"), &args.required("on")?)?;
            Cmd::Torque { on }
        }
        CmdName::Reboot => {
            let mut args = Args::new(map, known, &["ids"])?;
            let ids = match args.optional("ids") {
                Some(value) => Some(servo_ids(Field::new("ids"), &value)?),
                None => None,
            };
            Cmd::Reboot { ids }
        }
        CmdName::Goto => {
            let mut args = Args::new(map, known, &["target", "speed"])?;
            let target = point(Field::new("target"), &args.required("target")?)?;
            let speed = args.speed()?;
            Cmd::Goto { target, speed }
        }
        CmdName::Reach => {
            let mut args = Args::new(map, known, &["target"])?;
            let target = point(Field::new("target"), &args.required("target")?)?;
            Cmd::Reach { target }
        }
        CmdName::GotoJoints => {
            let mut args = Args::new(map, known, &["theta"])?;
            let theta = numbers(Field::new("theta"), &args.required("theta")?, joints)?;
            Cmd::GotoJoints { theta }
        }
        CmdName::Path => {
            let mut args = Args::new(map, known, &["points", "speed"])?;
            let points = points(Field::new("points"), &args.required("points")?)?;
            let speed = args.speed()?;
            Cmd::Path { points, speed }
        }
        CmdName::Velocity => {
            let mut args = Args::new(map, known, &["v"])?;
            let v = point(Field::new("v"), &args.required("v")?)?;
            Cmd::Velocity { v }
        }
        CmdName::Jog => {
            let mut args = Args::new(map, known, &["joint", "rad_s"])?;
            let joint = joint(Field::new("joint"), &args.required("joint")?, joints)?;
            let rad_s = number(Field::new("rad_s"), &args.required("rad_s")?)?;
            Cmd::Jog { joint, rad_s }
        }
        CmdName::Strategy => {
            let mut args = Args::new(map, known, &["name"])?;
            let name = strategy(Field::new("name"), &args.required("name")?)?;
            Cmd::Strategy { name }
        }
        CmdName::World => no_args(map, Cmd::World)?,
        CmdName::SetWorld => {
            let mut args = Args::new(map, known, &["obstacles"])?;
            let obstacles = obstacle::obstacles("obstacles", &args.required("obstacles")?)?;
            let obstacles = Obstacles::new(obstacles).map_err(|e| world_rejection(&e, None))?;
            Cmd::SetWorld { obstacles }
        }
        CmdName::AddObstacle => {
            let mut args = Args::new(map, known, &["obstacle"])?;
            let obstacle = obstacle::obstacle("obstacle", &args.required("obstacle")?)?;
            let obstacle = CheckedObstacle::new(obstacle).map_err(|e| world_rejection(&e, None))?;
            Cmd::AddObstacle { obstacle }
        }
        CmdName::RemoveObstacle => {
            let mut args = Args::new(map, known, &["obstacle"])?;
            let id = string(Field::new("obstacle"), args.required("obstacle")?)?;
            Cmd::RemoveObstacle { id }
        }
        CmdName::Subscribe => {
            let mut args = Args::new(map, known, &["rate_hz"])?;
            let rate_hz = positive(Field::new("rate_hz"), &args.required("rate_hz")?)?;
            Cmd::Subscribe { rate_hz }
        }
    };
    Ok(cmd)
}

/// A command that takes no arguments, when none were given.
fn no_args(map: Map<String, Value>, cmd: Cmd) -> Result<Cmd, Rejection> {
    Args::new(map, cmd.name(), &[])?;
    Ok(cmd)
}

/// A command's arguments: the request object without `id` and `cmd`, its keys checked.
struct Args {
    map: Map<String, Value>,
}

impl Args {
    /// Refuses a key that `cmd` does not take, before any argument is read (so a misspelt key
    /// is reported as such, not as the argument it was meant to be going missing).
    fn new(map: Map<String, Value>, cmd: CmdName, takes: &[&str]) -> Result<Self, Rejection> {
        if let Some(key) = map.keys().find(|key| !takes.contains(&key.as_str())) {
            let takes = if takes.is_empty() {
                "no arguments".to_owned()
            } else {
                takes.join(", ")
            };
            return Err(bad(format_args!(
                "`{key}`: unknown argument of {cmd} (it takes {takes})"
            )));
        }
        Ok(Args { map })
    }

    fn required(&mut self, key: &'static str) -> Result<Value, Rejection> {
        match self.map.remove(key) {
            None | Some(Value::Null) => Err(bad(format_args!("`{key}`: missing"))),
            Some(value) => Ok(value),
        }
    }

    /// An optional argument; `null` counts as absent.
    fn optional(&mut self, key: &'static str) -> Option<Value> {
        self.map.remove(key).filter(|value| !value.is_null())
    }

    /// The optional `speed`, at least [`MIN_SPEED_M_S`] when given.
    fn speed(&mut self) -> Result<Option<f64>, Rejection> {
        match self.map.remove("speed") {
            None | Some(Value::Null) => Ok(None),
            Some(value) => {
                let speed = positive(Field::new("speed"), &value)?;
                if speed < MIN_SPEED_M_S {
                    return Err(bad(format_args!(
                        "`speed`: {speed:e} m/s is below the least, {MIN_SPEED_M_S:e} m/s"
                    )));
                }
                Ok(Some(speed))
            }
        }
    }
}

/// Where an argument is: `target`, `theta[2]`, `points[7][1]`.
#[derive(Clone, Copy)]
struct Field {
    key: &'static str,
    index: [Option<usize>; 2],
}

impl Field {
    fn new(key: &'static str) -> Self {
        Field {
            key,
            index: [None, None],
        }
    }

    /// The entry `i` of this field.
    fn at(self, i: usize) -> Self {
        let mut index = self.index;
        match index {
            [None, _] => index[0] = Some(i),
            _ => index[1] = Some(i),
        }
        Field { index, ..self }
    }
}

impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key)?;
        for i in self.index.iter().flatten() {
            write!(f, "[{i}]")?;
        }
        Ok(())
    }
}

/// A finite number no larger than [`MAX_ARG`] in magnitude.
fn number(field: Field, value: &Value) -> Result<f64, Rejection> {
    let x = match value {
        Value::Number(n) => n.as_f64(),
        _ => None,
    };
    let Some(x) = x else {
        return Err(bad(format_args!(
            "`{field}`: expected a number, got {}",
            Shown(value)
        )));
    };
    in_range(field, x)
}

/// `x` if finite and no larger than [`MAX_ARG`] in magnitude.
fn in_range(field: Field, x: f64) -> Result<f64, Rejection> {
    if !x.is_finite() {
        return Err(bad(format_args!("`{field}`: {x} is not finite")));
    }
    if x.abs() > MAX_ARG {
        return Err(bad(format_args!(
            "`{field}`: {} is over {MAX_ARG} in magnitude",
            Num(x)
        )));
    }
    Ok(x)
}

/// A point that came by another way than a request line (a network message), held to the
/// same rule as a request's numbers: finite, and no larger than the parser allows. `field`
/// names it in the refusal (`v`, `target`).
pub fn checked_point(field: &'static str, p: [f64; 2]) -> Result<[f64; 2], Rejection> {
    let field = Field::new(field);
    Ok([in_range(field.at(0), p[0])?, in_range(field.at(1), p[1])?])
}

/// Obstacles in the socket's shape (what `set_world` takes as `obstacles`), read as strictly
/// as a request's: for a client that reads them from elsewhere (a file) and wants the same
/// refusals, naming `obstacles[i]...`.
///
/// # Example
/// ```
/// use snakectl::protocol::{parse_obstacles, Code};
///
/// let post = serde_json::json!([{"id": "post", "circle": {"center": [0.1, 0.2], "radius": 0.03}}]);
/// assert_eq!(parse_obstacles(&post).unwrap()[0].id, "post");
///
/// let bad = serde_json::json!([{"id": "post", "circle": {"center": [0.1, 0.2], "r": 0.03}}]);
/// let why = parse_obstacles(&bad).unwrap_err();
/// assert_eq!(why.code, Code::BadArg);
/// assert!(why.message.starts_with("`obstacles[0].circle.r`"));
/// ```
pub fn parse_obstacles(value: &Value) -> Result<Vec<crate::world::Obstacle>, Rejection> {
    obstacle::obstacles("obstacles", value)
}

/// A [`number`] above zero.
fn positive(field: Field, value: &Value) -> Result<f64, Rejection> {
    let x = number(field, value)?;
    if x > 0.0 {
        Ok(x)
    } else {
        Err(bad(format_args!("`{field}`: must be positive, got {x}")))
    }
}

/// An array of exactly `len` entries.
fn array(field: Field, value: &Value, len: usize) -> Result<&[Value], Rejection> {
    match value {
        Value::Array(items) if items.len() == len => Ok(items),
        Value::Array(items) => Err(bad(format_args!(
            "`{field}`: expected {len} entries, got {}",
            items.len()
        ))),
        _ => Err(bad(format_args!(
            "`{field}`: expected an array of {len} numbers, got {}",
            Shown(value)
        ))),
    }
}

/// An `[x, y]` pair of [`number`]s.
fn point(field: Field, value: &Value) -> Result<[f64; 2], Rejection> {
    let items = array(field, value, 2)?;
    Ok([
        number(field.at(0), &items[0])?,
        number(field.at(1), &items[1])?,
    ])
}

/// `len` [`number`]s.
fn numbers(field: Field, value: &Value, len: usize) -> Result<Vec<f64>, Rejection> {
    let items = array(field, value, len)?;
    items
        .iter()
        .enumerate()
        .map(|(i, item)| number(field.at(i), item))
        .collect()
}

/// From 1 to [`MAX_PATH_POINTS`] [`point`]s.
fn points(field: Field, value: &Value) -> Result<Vec<[f64; 2]>, Rejection> {
    let Value::Array(items) = value else {
        return Err(bad(format_args!(
            "`{field}`: expected an array of [x, y] points, got {}",
            Shown(value)
        )));
    };
    if items.is_empty() || items.len() > MAX_PATH_POINTS {
        return Err(bad(format_args!(
            "`{field}`: expected 1 to {MAX_PATH_POINTS} points, got {}",
            items.len()
        )));
    }
    items
        .iter()
        .enumerate()
        .map(|(i, item)| point(field.at(i), item))
        .collect()
}

/// A joint number, an integer from 1 to `joints` (written as a whole number such as `4.0` too,
/// as encoders that hold every number as a double write it).
fn joint(field: Field, value: &Value, joints: usize) -> Result<usize, Rejection> {
    let Value::Number(n) = value else {
        return Err(bad(format_args!(
            "`{field}`: expected a joint number, got {}",
            Shown(value)
        )));
    };
    let whole = if n.is_f64() {
        match n.as_f64() {
            Some(x) if x.fract() == 0.0 => {
                (0.0..=f64::from(u32::MAX)).contains(&x).then_some(x as u64)
            }
            _ => {
                return Err(bad(format_args!(
                    "`{field}`: expected an integer joint number, got {n}"
                )))
            }
        }
    } else {
        n.as_u64()
    };
    match whole.and_then(|k| usize::try_from(k).ok()) {
        Some(k) if (1..=joints).contains(&k) => Ok(k),
        _ => Err(bad(format_args!(
            "`{field}`: {n} is out of range 1..={joints}"
        ))),
    }
}

/// A string, taken out of its value.
fn string(field: Field, value: Value) -> Result<String, Rejection> {
    match value {
        Value::String(text) => Ok(text),
        other => Err(bad(format_args!(
            "`{field}`: expected a string, got {}",
            Shown(&other)
        ))),
    }
}

/// `true` or `false`.
fn boolean(field: Field, value: &Value) -> Result<bool, Rejection> {
    value.as_bool().ok_or_else(|| {
        bad(format_args!(
            "`{field}`: expected true or false, got {}",
            Shown(value)
        ))
    })
}

/// From 1 to [`MAX_REBOOT_IDS`] distinct servo ids, each an integer from 0 to
/// [`MAX_SERVO_ID`]. Whether the arm has them is the loop's to check.
fn servo_ids(field: Field, value: &Value) -> Result<Vec<u8>, Rejection> {
    let Value::Array(items) = value else {
        return Err(bad(format_args!(
            "`{field}`: expected an array of servo ids, got {}",
            Shown(value)
        )));
    };
    if items.is_empty() || items.len() > MAX_REBOOT_IDS {
        return Err(bad(format_args!(
            "`{field}`: expected 1 to {MAX_REBOOT_IDS} servo ids, got {}",
            items.len()
        )));
    }
    let mut seen = [false; MAX_REBOOT_IDS];
    let mut ids = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let at = field.at(i);
        let id = match item {
            Value::Number(n) if !n.is_f64() => n.as_u64().and_then(|k| u8::try_from(k).ok()),
            Value::Number(n) => {
                return Err(bad(format_args!(
                    "`{at}`: expected an integer servo id, got {n}"
                )))
            }
            other => {
                return Err(bad(format_args!(
                    "`{at}`: expected a servo id, got {}",
                    Shown(other)
                )))
            }
        };
        let Some(id) = id.filter(|&id| id <= MAX_SERVO_ID) else {
            return Err(bad(format_args!(
                "`{at}`: {item} is out of range 0..={MAX_SERVO_ID}"
            )));
        };
        let slot = &mut seen[usize::from(id)];
        if *slot {
            return Err(bad(format_args!("`{at}`: servo id {id} is given twice")));
        }
        *slot = true;
        ids.push(id);
    }
    Ok(ids)
}

/// A strategy by name.
fn strategy(field: Field, value: &Value) -> Result<Strategy, Rejection> {
    match value.as_str().and_then(strategy_named) {
        Some(strategy) => Ok(strategy),
        None => {
            let names: Vec<String> = STRATEGIES
                .iter()
                .map(|s| format!("\"{}\"", s.name()))
                .collect();
            Err(bad(format_args!(
                "`{field}`: expected {}, got {}",
                names.join(" or "),
                Shown(value)
            )))
        }
    }
}

fn bad(message: fmt::Arguments<'_>) -> Rejection {
    Rejection::new(Code::BadArg, message.to_string())
}

fn unknown(message: fmt::Arguments<'_>) -> Rejection {
    Rejection::new(Code::UnknownCmd, message.to_string())
}

/// A value as JSON for a message, cut short when long (a request line may be 1 MiB).
struct Shown<'a>(&'a Value);

impl fmt::Display for Shown<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        const MAX: usize = 40;
        let text = self.0.to_string();
        if text.len() <= MAX {
            return f.write_str(&text);
        }
        let mut end = MAX;
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        write!(f, "{}...", &text[..end])
    }
}

#[cfg(test)]
mod tests;
