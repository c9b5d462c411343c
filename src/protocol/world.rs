//! The world on the wire: obstacles as `{"id": "post", "circle": {"center": [x, y], "radius":
//! r}}` or `{"id": "shelf", "polygon": {"points": [[x, y], ...]}}` (exactly one of `circle` and
//! `polygon`), and the world as the `world` reply and event carry it ([`WorldInfo`]).
//!
//! A request's obstacles are read strictly by the parser (unknown keys refused, each number
//! finite and within [`MAX_ARG`](super::MAX_ARG), the field named); whether they make a world
//! (a positive radius, a simple polygon, distinct ids, the limits on their number) is the
//! loop's to decide with [`World::new`], whose refusal [`world_rejection`] words for the wire.
//! A reply or an event is read leniently, as every reply is: a key this version does not know
//! is ignored.

use std::fmt;

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Code, Rejection};
use crate::chain::Vec2;
use crate::world::{Obstacle, Shape, World, WorldError};

/// The world as the `world` reply and the `world` event carry it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct WorldInfo {
    /// Half the width of every link, m (fixed by the daemon's config).
    #[serde(default)]
    pub link_radius_m: f64,
    /// The gap every link keeps from every obstacle, m (fixed by the daemon's config).
    #[serde(default)]
    pub clearance_m: f64,
    /// The obstacles, in the order given.
    #[serde(default, with = "obstacles")]
    pub obstacles: Vec<Obstacle>,
}

impl WorldInfo {
    /// What `world` says of `world`.
    pub fn of(world: &World) -> WorldInfo {
        WorldInfo {
            link_radius_m: world.link_radius_m(),
            clearance_m: world.clearance_m(),
            obstacles: world.obstacles().to_vec(),
        }
    }

    /// The world it describes, validated.
    pub fn to_world(&self) -> Result<World, WorldError> {
        World::new(self.link_radius_m, self.clearance_m, self.obstacles.clone())
    }
}

/// An obstacle as the wire writes and (leniently) reads it.
#[derive(Debug, Serialize, Deserialize)]
struct WireObstacle {
    id: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    circle: Option<WireCircle>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    polygon: Option<WirePolygon>,
}

#[derive(Debug, Serialize, Deserialize)]
struct WireCircle {
    center: [f64; 2],
    radius: f64,
}

#[derive(Debug, Serialize, Deserialize)]
struct WirePolygon {
    points: Vec<[f64; 2]>,
}

impl WireObstacle {
    fn of(o: &Obstacle) -> WireObstacle {
        let (circle, polygon) = match &o.shape {
            Shape::Circle { center, radius_m } => (
                Some(WireCircle {
                    center: [center.x, center.y],
                    radius: *radius_m,
                }),
                None,
            ),
            Shape::Polygon { points } => (
                None,
                Some(WirePolygon {
                    points: points.iter().map(|p| [p.x, p.y]).collect(),
                }),
            ),
        };
        WireObstacle {
            id: o.id.clone(),
            circle,
            polygon,
        }
    }

    fn into_obstacle(self) -> Result<Obstacle, String> {
        let shape = match (self.circle, self.polygon) {
            (Some(c), None) => Shape::Circle {
                center: Vec2::new(c.center[0], c.center[1]),
                radius_m: c.radius,
            },
            (None, Some(p)) => Shape::Polygon {
                points: p.points.iter().map(|q| Vec2::new(q[0], q[1])).collect(),
            },
            (Some(_), Some(_)) => {
                return Err(format!(
                    "obstacle {:?} has both `circle` and `polygon`",
                    self.id
                ))
            }
            (None, None) => {
                return Err(format!(
                    "obstacle {:?} has neither `circle` nor `polygon`",
                    self.id
                ))
            }
        };
        Ok(Obstacle { id: self.id, shape })
    }
}

/// A list of obstacles in their wire shape.
pub(super) mod obstacles {
    use serde::ser::SerializeSeq;

    use super::*;

    pub fn serialize<S: Serializer>(list: &[Obstacle], s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(list.len()))?;
        for o in list {
            seq.serialize_element(&WireObstacle::of(o))?;
        }
        seq.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Obstacle>, D::Error> {
        Vec::<WireObstacle>::deserialize(d)?
            .into_iter()
            .map(|o| o.into_obstacle().map_err(D::Error::custom))
            .collect()
    }
}

/// An obstacle written in its wire shape (`{"id": ..., "circle": {...}}`).
#[derive(Debug, Clone, Copy)]
pub struct Wire<'a>(pub &'a Obstacle);

impl Serialize for Wire<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        WireObstacle::of(self.0).serialize(s)
    }
}

/// The refusal of a world [`World::new`] would not make: `bad_arg`, naming the field as the
/// request spelt it (`obstacles[1].circle.radius`, `obstacles[0].polygon.points[4]`). For
/// `add_obstacle`, `added` is the new obstacle's index in the world tried, which the message
/// calls `obstacle` (the request's argument).
pub fn world_rejection(err: &WorldError, added: Option<usize>) -> Rejection {
    let text = err.to_string();
    let (field, rest) = text
        .split_once(": ")
        .unwrap_or(("obstacles", text.as_str()));
    if added.is_some() && field == "obstacles" {
        // No room for the one added: that is the request's `obstacle`.
        return Rejection::new(
            Code::BadArg,
            format!("`obstacle`: adding it would make {rest}"),
        );
    }
    let mut field = field
        .replace(".circle.radius_m", ".circle.radius")
        .replace(".circle.center.x", ".circle.center[0]")
        .replace(".circle.center.y", ".circle.center[1]");
    if let Some(k) = added {
        let prefix = format!("obstacles[{k}]");
        if let Some(tail) = field.strip_prefix(&prefix) {
            field = format!("obstacle{tail}");
        }
    }
    Rejection::new(Code::BadArg, format!("`{field}`: {rest}"))
}

/// The ids of `world`'s obstacles for a message: `"post", "shelf"`, or `none`.
pub fn world_ids(world: &World) -> impl fmt::Display + '_ {
    struct Ids<'a>(&'a World);
    impl fmt::Display for Ids<'_> {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            if self.0.obstacles().is_empty() {
                return f.write_str("none");
            }
            for (i, o) in self.0.obstacles().iter().enumerate() {
                if i > 0 {
                    f.write_str(", ")?;
                }
                write!(f, "{:?}", o.id)?;
            }
            Ok(())
        }
    }
    Ids(world)
}
