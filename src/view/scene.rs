//! The arm as a Foxglove 3-D scene: a pure builder from the chain, the world and one
//! telemetry snapshot, returning the `foxglove.SceneUpdate` a live view sends and a recorder
//! writes (encode it with [`super::encode`]).
//!
//! Entities (each replaces the one of the same id a client holds, so sending the whole scene
//! again at the publish rate keeps a client that joined late up to date):
//! - `arm_cmd`, `arm_meas`: the links of the commanded and the measured pose as thick lines
//!   (the links' width where the world gives one), with a sphere at each joint;
//! - `tip_cmd`, `tip_meas`: the two tips;
//! - `trail`: where the measured tip has been ([`Trail`], a bounded ring);
//! - `target`: where the active command goes (deleted while there is none);
//! - `reach`: the edge of the reachable ring (an annular sector when the limits confine it);
//! - `obstacles`: discs as flat cylinders, polygons as closed outlines, each with its id.
//!
//! All of it lies in the plane z = 0 of the frame [`super::FRAME_ID`].

use std::collections::VecDeque;
use std::f64::consts::TAU;

use foxglove::schemas::line_primitive::Type as LineType;
use foxglove::schemas::scene_entity_deletion::Type as DeletionType;
use foxglove::schemas::{
    Color, CylinderPrimitive, LinePrimitive, Point3, Pose, Quaternion, SceneEntity,
    SceneEntityDeletion, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector3,
};

use super::FRAME_ID;
use crate::chain::Chain;
use crate::protocol::Telemetry;
use crate::world::{Shape, World};

/// Points a [`Trail`] holds by default: at 30 Hz, the last half minute of motion.
pub const TRAIL_POINTS: usize = 900;

/// Segments of a full circle as drawn (the reachable ring, a disc's outline).
const CIRCLE_SEGMENTS: usize = 96;

/// The commanded arm: translucent blue.
const CMD: Color = rgba(0.25, 0.55, 1.0, 0.45);
/// The measured arm: orange.
const MEAS: Color = rgba(1.0, 0.55, 0.1, 1.0);
/// The trail: green.
const TRAIL: Color = rgba(0.2, 0.8, 0.35, 0.9);
/// The target: red.
const TARGET: Color = rgba(0.95, 0.15, 0.15, 1.0);
/// The reachable ring: grey.
const REACH: Color = rgba(0.6, 0.6, 0.6, 0.7);
/// The obstacles: dark red.
const OBSTACLE: Color = rgba(0.55, 0.12, 0.12, 0.85);

const fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

/// Where the measured tip has been: the newest points, at most a fixed number (the oldest
/// leave first); a point equal to the last is not added, so an arm at rest does not wear
/// the trail away.
#[derive(Debug, Clone, PartialEq)]
pub struct Trail {
    points: VecDeque<[f64; 2]>,
    capacity: usize,
}

impl Default for Trail {
    fn default() -> Self {
        Trail::new(TRAIL_POINTS)
    }
}

impl Trail {
    /// An empty trail of at most `capacity` points (at least 2).
    pub fn new(capacity: usize) -> Trail {
        let capacity = capacity.max(2);
        Trail {
            points: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Adds `p` (dropping the oldest when full), unless it is the last point already or not
    /// finite.
    pub fn push(&mut self, p: [f64; 2]) {
        if !(p[0].is_finite() && p[1].is_finite()) || self.points.back() == Some(&p) {
            return;
        }
        if self.points.len() == self.capacity {
            self.points.pop_front();
        }
        self.points.push_back(p);
    }

    /// The points, oldest first.
    pub fn points(&self) -> impl ExactSizeIterator<Item = &[f64; 2]> {
        self.points.iter()
    }

    /// How many points it holds.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

fn p3(x: f64, y: f64) -> Point3 {
    Point3 { x, y, z: 0.0 }
}

fn at(x: f64, y: f64) -> Option<Pose> {
    Some(Pose {
        position: Some(Vector3 { x, y, z: 0.0 }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    })
}

fn line(kind: LineType, points: Vec<Point3>, thickness: f64, color: Color) -> LinePrimitive {
    LinePrimitive {
        r#type: kind as i32,
        pose: at(0.0, 0.0),
        thickness,
        scale_invariant: false,
        points,
        color: Some(color),
        colors: Vec::new(),
        indices: Vec::new(),
    }
}

fn sphere(p: [f64; 2], diameter: f64, color: Color) -> SpherePrimitive {
    SpherePrimitive {
        pose: at(p[0], p[1]),
        size: Some(Vector3 {
            x: diameter,
            y: diameter,
            z: diameter,
        }),
        color: Some(color),
    }
}

fn entity(id: &str, stamp: Timestamp) -> SceneEntity {
    SceneEntity {
        timestamp: Some(stamp),
        frame_id: FRAME_ID.to_owned(),
        id: id.to_owned(),
        frame_locked: true,
        ..SceneEntity::default()
    }
}

/// Points of an arc of radius `r` about `c` from bearing `lo` to `hi` (rad), both ends
/// included.
fn arc(c: [f64; 2], r: f64, lo: f64, hi: f64) -> Vec<Point3> {
    let steps = ((hi - lo).abs() / TAU * CIRCLE_SEGMENTS as f64)
        .ceil()
        .max(1.0) as usize;
    (0..=steps)
        .map(|i| {
            let a = lo + (hi - lo) * i as f64 / steps as f64;
            p3(c[0] + r * a.cos(), c[1] + r * a.sin())
        })
        .collect()
}

/// A whole circle as a closed loop's points (the last joins the first).
fn circle(c: [f64; 2], r: f64) -> Vec<Point3> {
    let mut points = arc(c, r, 0.0, TAU);
    points.pop();
    points
}

/// The links of `theta` as one entity: the chain's points as a line of the links' width, a
/// sphere at each joint. `None` when `theta` does not fit the chain.
fn arm(
    id: &str,
    chain: &Chain,
    theta: &[f64],
    width: f64,
    color: Color,
    stamp: Timestamp,
) -> Option<SceneEntity> {
    if theta.len() != chain.len() {
        return None;
    }
    let points = chain.checked_points(theta)?;
    let mut e = entity(id, stamp);
    e.lines.push(line(
        LineType::LineStrip,
        points.iter().map(|p| p3(p.x, p.y)).collect(),
        width,
        color,
    ));
    // The joints (the base is the first point; the tip is not a joint).
    e.spheres = points[..points.len() - 1]
        .iter()
        .map(|p| sphere([p.x, p.y], 1.4 * width, color))
        .collect();
    Some(e)
}

/// The edge of the reachable ring of `chain`.
fn reach(chain: &Chain, width: f64, stamp: Timestamp) -> SceneEntity {
    let ws = chain.workspace();
    let base = chain.base();
    let c = [base.x, base.y];
    let mut e = entity("reach", stamp);
    let thin = 0.25 * width;
    match ws.bearing {
        Some((lo, hi)) => {
            // An annular sector: the outer arc one way, the inner arc back.
            let mut points = arc(c, ws.r_max, lo, hi);
            if ws.r_min > 0.0 {
                points.extend(arc(c, ws.r_min, hi, lo));
            } else {
                points.push(p3(c[0], c[1]));
            }
            e.lines.push(line(LineType::LineLoop, points, thin, REACH));
        }
        None => {
            e.lines
                .push(line(LineType::LineLoop, circle(c, ws.r_max), thin, REACH));
            if ws.r_min > 0.0 {
                e.lines
                    .push(line(LineType::LineLoop, circle(c, ws.r_min), thin, REACH));
            }
        }
    }
    e
}

/// The obstacles of `world`, with their ids above them.
fn obstacles(world: &World, width: f64, stamp: Timestamp) -> SceneEntity {
    let mut e = entity("obstacles", stamp);
    for o in world.obstacles() {
        let label = match &o.shape {
            Shape::Circle { center, radius_m } => {
                e.cylinders.push(CylinderPrimitive {
                    pose: at(center.x, center.y),
                    size: Some(Vector3 {
                        x: 2.0 * radius_m,
                        y: 2.0 * radius_m,
                        z: width,
                    }),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color: Some(OBSTACLE),
                });
                [center.x, center.y]
            }
            Shape::Polygon { points } => {
                e.lines.push(line(
                    LineType::LineLoop,
                    points.iter().map(|p| p3(p.x, p.y)).collect(),
                    0.5 * width,
                    OBSTACLE,
                ));
                let n = points.len().max(1) as f64;
                let (sx, sy) = points
                    .iter()
                    .fold((0.0, 0.0), |(x, y), p| (x + p.x, y + p.y));
                [sx / n, sy / n]
            }
        };
        e.texts.push(TextPrimitive {
            pose: at(label[0], label[1]),
            billboard: true,
            font_size: 12.0,
            scale_invariant: true,
            color: Some(rgba(1.0, 1.0, 1.0, 1.0)),
            text: o.id.clone(),
        });
    }
    e
}

/// The scene of `telemetry` for the arm of `chain` among `world`'s obstacles, with the tip's
/// `trail`, stamped `stamp`.
///
/// # Returns
/// The entities listed in the module's documentation; `arm_cmd` and `arm_meas` are left out
/// when the snapshot's angles do not fit the chain (before the first tick), and `target`
/// is deleted while no command has one.
pub fn scene(
    chain: &Chain,
    world: &World,
    telemetry: &Telemetry,
    trail: &Trail,
    stamp: Timestamp,
) -> SceneUpdate {
    let width = match world.link_radius_m() {
        r if r > 0.0 => 2.0 * r,
        // No width given: thin links, in proportion to the arm.
        _ => 0.015 * chain.reach(),
    };
    let mut entities = Vec::with_capacity(8);
    entities.extend(arm(
        "arm_cmd",
        chain,
        &telemetry.theta_cmd,
        width,
        CMD,
        stamp,
    ));
    entities.extend(arm(
        "arm_meas",
        chain,
        &telemetry.theta_meas,
        0.6 * width,
        MEAS,
        stamp,
    ));
    for (id, p, color) in [
        ("tip_cmd", telemetry.tip, CMD),
        ("tip_meas", telemetry.tip_meas, MEAS),
    ] {
        let mut e = entity(id, stamp);
        e.spheres.push(sphere(p, 1.8 * width, color));
        entities.push(e);
    }
    let mut e = entity("trail", stamp);
    e.lines.push(line(
        LineType::LineStrip,
        trail.points().map(|p| p3(p[0], p[1])).collect(),
        0.3 * width,
        TRAIL,
    ));
    entities.push(e);
    let mut deletions = Vec::new();
    match telemetry.target {
        Some(target) => {
            let mut e = entity("target", stamp);
            e.spheres.push(sphere(target, 2.0 * width, TARGET));
            entities.push(e);
        }
        None => deletions.push(SceneEntityDeletion {
            timestamp: Some(stamp),
            r#type: DeletionType::MatchingId as i32,
            id: "target".to_owned(),
        }),
    }
    entities.push(reach(chain, width, stamp));
    entities.push(obstacles(world, width, stamp));
    SceneUpdate {
        deletions,
        entities,
    }
}
