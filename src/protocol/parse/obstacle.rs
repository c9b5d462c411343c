//! Reading the obstacles of a request strictly: every key known, exactly one shape, every
//! number finite and within [`MAX_ARG`], the field named in the refusal
//! (`obstacles[1].circle.radius`). Whether they make a world is the loop's to decide.

use serde_json::{Map, Value};

use super::{bad, Num, Shown};
use crate::chain::Vec2;
use crate::protocol::{Rejection, MAX_ARG};
use crate::world::{Obstacle, Shape};

/// The obstacles of `set_world` (or of a file in the same shape): an array of obstacles, the
/// refusal naming `field[i]...`.
pub fn obstacles(field: &str, value: &Value) -> Result<Vec<Obstacle>, Rejection> {
    let Value::Array(items) = value else {
        return Err(bad(format_args!(
            "`{field}`: expected an array of obstacles, got {}",
            Shown(value)
        )));
    };
    items
        .iter()
        .enumerate()
        .map(|(i, item)| obstacle(&format!("{field}[{i}]"), item))
        .collect()
}

/// One obstacle at `field`: `{"id": ..., "circle": {"center": [x, y], "radius": r}}` or
/// `{"id": ..., "polygon": {"points": [[x, y], ...]}}`.
pub fn obstacle(field: &str, value: &Value) -> Result<Obstacle, Rejection> {
    let map = object(field, value, &["id", "circle", "polygon"])?;
    let id = match map.get("id") {
        Some(Value::String(id)) => id.clone(),
        None | Some(Value::Null) => return Err(bad(format_args!("`{field}.id`: missing"))),
        Some(other) => {
            return Err(bad(format_args!(
                "`{field}.id`: expected a string, got {}",
                Shown(other)
            )))
        }
    };
    let circle = map.get("circle").filter(|v| !v.is_null());
    let polygon = map.get("polygon").filter(|v| !v.is_null());
    let shape = match (circle, polygon) {
        (Some(c), None) => {
            let at = format!("{field}.circle");
            let c = object(&at, c, &["center", "radius"])?;
            let center = point(&format!("{at}.center"), required(&at, c, "center")?)?;
            let radius_m = number(&format!("{at}.radius"), required(&at, c, "radius")?)?;
            Shape::Circle { center, radius_m }
        }
        (None, Some(p)) => {
            let at = format!("{field}.polygon");
            let p = object(&at, p, &["points"])?;
            let list = required(&at, p, "points")?;
            let at = format!("{at}.points");
            let Value::Array(items) = list else {
                return Err(bad(format_args!(
                    "`{at}`: expected an array of [x, y] points, got {}",
                    Shown(list)
                )));
            };
            let points = items
                .iter()
                .enumerate()
                .map(|(j, item)| point(&format!("{at}[{j}]"), item))
                .collect::<Result<Vec<_>, _>>()?;
            Shape::Polygon { points }
        }
        (Some(_), Some(_)) => {
            return Err(bad(format_args!(
                "`{field}`: give `circle` or `polygon`, not both"
            )))
        }
        (None, None) => {
            return Err(bad(format_args!(
                "`{field}`: missing its shape: `circle` or `polygon`"
            )))
        }
    };
    Ok(Obstacle { id, shape })
}

/// An object whose keys are all among `takes`.
fn object<'a>(
    field: &str,
    value: &'a Value,
    takes: &[&str],
) -> Result<&'a Map<String, Value>, Rejection> {
    let Value::Object(map) = value else {
        return Err(bad(format_args!(
            "`{field}`: expected an object, got {}",
            Shown(value)
        )));
    };
    if let Some(key) = map.keys().find(|k| !takes.contains(&k.as_str())) {
        return Err(bad(format_args!(
            "`{field}.{key}`: unknown key (it takes {})",
            takes.join(", ")
        )));
    }
    Ok(map)
}

/// The value of `key` in `map` at `field`, not null.
fn required<'a>(
    field: &str,
    map: &'a Map<String, Value>,
    key: &str,
) -> Result<&'a Value, Rejection> {
    map.get(key)
        .filter(|v| !v.is_null())
        .ok_or_else(|| bad(format_args!("`{field}.{key}`: missing")))
}

/// A finite number within [`MAX_ARG`].
fn number(field: &str, value: &Value) -> Result<f64, Rejection> {
    let Some(x) = value.as_f64().filter(|_| value.is_number()) else {
        return Err(bad(format_args!(
            "`{field}`: expected a number, got {}",
            Shown(value)
        )));
    };
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

/// An `[x, y]` pair of numbers.
fn point(field: &str, value: &Value) -> Result<Vec2, Rejection> {
    match value {
        Value::Array(items) if items.len() == 2 => Ok(Vec2::new(
            number(&format!("{field}[0]"), &items[0])?,
            number(&format!("{field}[1]"), &items[1])?,
        )),
        Value::Array(items) => Err(bad(format_args!(
            "`{field}`: expected 2 entries, got {}",
            items.len()
        ))),
        _ => Err(bad(format_args!(
            "`{field}`: expected an array of 2 numbers, got {}",
            Shown(value)
        ))),
    }
}
