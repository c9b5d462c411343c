//! A world of obstacles for the planar arm: circles and polygons that every link keeps clear of.
//!
//! Links are capsules: the segment `p_{i-1} p_i` of a pose grown by the world's
//! `link_radius_m`. This module is the geometry the rest builds on:
//!
//! - [`Obstacle`], [`Shape`] and the validated [`World`] (errors name the field, e.g.
//!   `obstacles[2].polygon.points[4]`, and carry the numbers), whose obstacles can be checked
//!   on their own first ([`Obstacles`], [`CheckedObstacle`]: where a request is read, so that
//!   the control loop makes a world of them without checking a polygon again);
//! - exact distances from a segment to a circle or a polygon, unsigned and signed (a link
//!   inside an obstacle has a negative distance: minus its depth), in [`geometry`];
//! - the clearance of a pose and the pairs of (link, obstacle) near contact, each with the
//!   gradient of its distance with respect to the joint angles, for a solver's constraints
//!   (allocation-free with the caller's buffers), in [`clearance`];
//! - the tip's shortest route around the obstacles grown by the link radius and the clearance,
//!   a polyline of waypoints, in [`route`].
//!
//! Pure: no I/O, clock or threads. Everything is in metres and radians, in the arm's frame.
//!
//! ```
//! use snakectl::chain::{Chain, Vec2};
//! use snakectl::world::{ActivePairs, Obstacle, Shape, World};
//!
//! let post = Obstacle {
//!     id: "post".into(),
//!     shape: Shape::Circle { center: Vec2::new(0.2, 0.1), radius_m: 0.03 },
//! };
//! let world = World::new(0.01, 0.005, vec![post]).unwrap();
//! let arm = Chain::unlimited(vec![0.1, 0.1, 0.1], Vec2::zeros(), 0.0).unwrap();
//!
//! // Straight along x: link 2 passes 0.1 under the post's centre.
//! let least = world.pose_clearance(&arm, &[0.0; 3]).unwrap();
//! assert_eq!((least.link, least.id(&world)), (2, "post"));
//! assert!((least.clearance_m - (0.1 - 0.03 - 0.01)).abs() < 1e-12);
//!
//! // The pairs within 0.1 m of contact, each with d clearance / d theta.
//! let mut pairs = ActivePairs::new();
//! world.active_pairs(&arm.points(&[0.0; 3]), 0.1, &mut pairs);
//! assert!(pairs.gradient(0)[0] < 0.0); // turning joint 1 up brings link 2 toward the post
//! # assert!(pairs.gradient(0)[2] == 0.0);
//!
//! // The tip's route from below the post to above it goes round it.
//! let route = world.route(Vec2::new(0.2, 0.0), Vec2::new(0.2, 0.2)).unwrap();
//! assert!(route.waypoints.len() > 2 && route.length_m > 0.2);
//! ```

pub mod clearance;
pub mod geometry;
pub mod route;

use std::ops::Deref;
use std::sync::Arc;

use crate::chain::{Num, Vec2, MAX_MAGNITUDE};

pub use clearance::{ActivePairs, Pair};
pub use geometry::Contact;
pub use route::{Route, RouteEnd, RouteError, MAX_ROUTE_WORK};

/// Most obstacles a world may hold: bounds every per-tick loop and the route's graph.
pub const MAX_OBSTACLES: usize = 64;

/// The clearance every link keeps when none is given, m.
pub const DEFAULT_CLEARANCE_M: f64 = 0.005;

/// Most polygon points a world may hold, all polygons together.
pub const MAX_POLYGON_POINTS: usize = 1024;

/// Longest obstacle id, in characters: ids go out in every `world` event and telemetry's
/// nearest pair, and name obstacles in messages and on screens.
pub const MAX_ID_CHARS: usize = 64;

/// Where a point stands against an obstacle, as words tell it: four decimals of a metre show a
/// distance below [`ON_EDGE_M`] as 0.0000 (or -0.0000), so that is "on the edge".
enum Place {
    /// Outside, this far, m.
    Outside(f64),
    /// On the edge.
    Edge,
    /// Inside, this deep, m.
    Inside(f64),
}

/// A signed distance (m) within this of zero is said to be on an obstacle's edge: it would
/// read 0.0000 m at the tenth of a millimetre the words give.
pub const ON_EDGE_M: f64 = 5e-5;

impl Place {
    /// The place of a signed distance (m, negative inside).
    fn of(distance_m: f64) -> Self {
        if distance_m.abs() < ON_EDGE_M {
            Self::Edge
        } else if distance_m < 0.0 {
            Self::Inside(-distance_m)
        } else {
            Self::Outside(distance_m)
        }
    }
}

/// Where a point (or a link) stands against obstacle `id`, in words, from its signed distance
/// (m, negative inside): "0.0175 m from obstacle \"post\"", "on the edge of ...", or "inside
/// ..., 0.0400 m deep": never a negative distance, nor a "-0.0000".
pub fn standing(distance_m: f64, id: &str) -> String {
    match Place::of(distance_m) {
        Place::Outside(d) => format!("{d:.4} m from obstacle {id:?}"),
        Place::Edge => format!("on the edge of obstacle {id:?}"),
        Place::Inside(depth) => format!("inside obstacle {id:?}, {depth:.4} m deep"),
    }
}

/// What an obstacle does to `point`, in words, from the point's signed distance to it (m,
/// negative inside): "is 0.0020 m from the base point", "touches ...", or "covers ..., 0.0100
/// m deep".
pub fn over_point(distance_m: f64, point: &str) -> String {
    match Place::of(distance_m) {
        Place::Outside(d) => format!("is {d:.4} m from {point}"),
        Place::Edge => format!("touches {point}"),
        Place::Inside(depth) => format!("covers {point}, {depth:.4} m deep"),
    }
}

/// The shape of an obstacle, in the arm's frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A disc.
    Circle {
        /// Centre, m.
        center: Vec2,
        /// Radius, m (positive).
        radius_m: f64,
    },
    /// A closed simple polygon (convex or not), its points in either turning sense; the edge
    /// from the last point back to the first closes it.
    Polygon {
        /// Vertices, m (at least 3; no repeated points, no edges that touch or cross).
        points: Vec<Vec2>,
    },
}

impl Shape {
    /// Signed distance from the point `p` to the shape, m: positive outside, negative inside
    /// (minus the distance to the boundary), 0 on the boundary.
    pub fn point_distance(&self, p: Vec2) -> f64 {
        match self {
            Shape::Circle { center, radius_m } => (p - center).norm() - radius_m,
            Shape::Polygon { points } => geometry::point_polygon(p, points),
        }
    }

    /// Distance from the segment `a..b` to the shape, signed (see [`geometry`]), with the
    /// closest points and the direction that increases it.
    pub fn segment_contact(&self, a: Vec2, b: Vec2) -> Contact {
        match self {
            Shape::Circle { center, radius_m } => {
                geometry::segment_circle(a, b, *center, *radius_m)
            }
            Shape::Polygon { points } => geometry::segment_polygon(a, b, points),
        }
    }

    /// Whether the segment `a..b` keeps at least `floor` from the shape (and does not touch
    /// it): the unsigned distance, with an early way out for far edges (what a route checks its
    /// legs with).
    pub fn segment_clears(&self, a: Vec2, b: Vec2, floor: f64) -> bool {
        match self {
            Shape::Circle { center, radius_m } => {
                let (q, _) = geometry::point_segment(*center, a, b);
                (q - center).norm() - radius_m >= floor
            }
            Shape::Polygon { points } => {
                let (lo, hi) = (a.inf(&b), a.sup(&b));
                let f2 = floor * floor;
                let n = points.len();
                for k in 0..n {
                    let (u, w) = (points[k], points[(k + 1) % n]);
                    if u.x.min(w.x) - hi.x >= floor
                        || lo.x - u.x.max(w.x) >= floor
                        || u.y.min(w.y) - hi.y >= floor
                        || lo.y - u.y.max(w.y) >= floor
                    {
                        continue;
                    }
                    let d2 = geometry::segment_segment(a, b, u, w).0;
                    if d2 < f2 || d2 == 0.0 {
                        return false;
                    }
                }
                // No edge near: either wholly outside or wholly inside.
                !geometry::inside_polygon(a, points)
            }
        }
    }

    /// What checking a segment against the shape costs, in edges (1 for a circle).
    pub fn size(&self) -> u64 {
        match self {
            Shape::Circle { .. } => 1,
            Shape::Polygon { points } => points.len() as u64,
        }
    }

    /// The smallest axis-aligned box that holds the shape: `(min, max)`.
    pub fn bounds(&self) -> (Vec2, Vec2) {
        match self {
            Shape::Circle { center, radius_m } => {
                let r = Vec2::new(*radius_m, *radius_m);
                (center - r, center + r)
            }
            Shape::Polygon { points } => {
                let mut lo = Vec2::new(f64::INFINITY, f64::INFINITY);
                let mut hi = -lo;
                for p in points {
                    lo = lo.inf(p);
                    hi = hi.sup(p);
                }
                (lo, hi)
            }
        }
    }
}

/// One obstacle: a name the user gave it and its shape.
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    /// Unique, non-empty name (how errors, replies and the clearance name it).
    pub id: String,
    /// Where it is.
    pub shape: Shape,
}

/// Why a world was refused. `field` is the path of the offending value, as
/// `obstacles[2].polygon.points[4]` (indices from 0, as in a list).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum WorldError {
    /// A coordinate or length that is not finite or beyond [`MAX_MAGNITUDE`].
    #[error("{field}: {} must be finite and at most {MAX_MAGNITUDE} in magnitude", Num(*.value))]
    NotFinite {
        /// Path of the value.
        field: String,
        /// The value given.
        value: f64,
    },
    /// A length that must be positive and is not.
    #[error("{field}: {} m must be positive", Num(*.value))]
    NotPositive {
        /// Path of the value.
        field: String,
        /// The value given.
        value: f64,
    },
    /// A length that must not be negative and is.
    #[error("{field}: {} m must not be negative", Num(*.value))]
    Negative {
        /// Path of the value.
        field: String,
        /// The value given.
        value: f64,
    },
    /// An empty id.
    #[error("{field}: an obstacle needs a non-empty id")]
    EmptyId {
        /// Path of the id.
        field: String,
    },
    /// An id longer than [`MAX_ID_CHARS`] characters, or with a control character (a line
    /// break, a tab, an escape) that would garble the messages and screens that name it.
    #[error("{field}: {why}")]
    BadId {
        /// Path of the id.
        field: String,
        /// What is wrong with it.
        why: String,
    },
    /// Two obstacles with the same id.
    #[error("{field}: id {id:?} is already used by obstacles[{first}]")]
    DuplicateId {
        /// Path of the second id.
        field: String,
        /// The id.
        id: String,
        /// Index of the obstacle that has it first.
        first: usize,
    },
    /// A polygon with fewer than 3 points.
    #[error("{field}: {count} points, a polygon needs at least 3")]
    TooFewPoints {
        /// Path of the point list.
        field: String,
        /// Points given.
        count: usize,
    },
    /// A point given twice (consecutive ones make a zero-length edge).
    #[error("{field}: point ({x}, {y}) repeats points[{first}]")]
    RepeatedPoint {
        /// Path of the second point.
        field: String,
        /// Index of its first occurrence in the same polygon.
        first: usize,
        /// x, m.
        x: f64,
        /// y, m.
        y: f64,
    },
    /// Two edges of a polygon that touch or cross (other than neighbours meeting at their
    /// shared point), or neighbours that fold back onto each other. Edge `k` runs from
    /// `points[k]` to the next point.
    #[error("{field}: edges {edge_a} and {edge_b} touch or cross near ({x}, {y})")]
    SelfIntersecting {
        /// Path of the point list.
        field: String,
        /// The first edge (from its start point's index).
        edge_a: usize,
        /// The second edge.
        edge_b: usize,
        /// Where, x m.
        x: f64,
        /// Where, y m.
        y: f64,
    },
    /// A polygon whose area is zero as computed: points so close together (a hair apart near
    /// the origin) that the products of their distances underflow, so which way it turns, and
    /// so which side is outside, cannot be told.
    #[error(
        "{field}: the polygon's area is zero as computed: its points are too close together \
         to tell its inside from its outside"
    )]
    ZeroArea {
        /// Path of the point list.
        field: String,
    },
    /// More obstacles than [`MAX_OBSTACLES`].
    #[error("obstacles: {count} obstacles, at most {max} allowed")]
    TooManyObstacles {
        /// Obstacles given.
        count: usize,
        /// The limit.
        max: usize,
    },
    /// More polygon points in all than [`MAX_POLYGON_POINTS`].
    #[error("obstacles: {count} polygon points in all, at most {max} allowed")]
    TooManyPoints {
        /// Points given, all polygons.
        count: usize,
        /// The limit.
        max: usize,
    },
}

/// A validated world: the links' radius, the clearance every link keeps, and the obstacles.
/// Cloning one is cheap: the obstacles are shared.
#[derive(Debug, Clone, PartialEq)]
pub struct World {
    link_radius_m: f64,
    clearance_m: f64,
    obstacles: Obstacles,
}

/// Obstacles checked on their own and together (ids, shapes, how many): all a [`World`] asks
/// of them but its link radius and clearance. A request's obstacles are checked where it is
/// read, so that the control loop makes a world of them without checking a polygon again
/// (a 1024-point polygon takes a millisecond or two). Cloning is cheap: the list is shared.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Obstacles {
    list: Arc<[Obstacle]>,
    /// Each obstacle's bounding box.
    bounds: Arc<[(Vec2, Vec2)]>,
}

/// One obstacle whose id and shape are checked (as [`Obstacles`] checks each of its own), to be
/// added to a world ([`Obstacles::with`]): what remains is whether the world has room for it
/// and whether its id is free.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedObstacle(Obstacle);

fn finite(field: impl FnOnce() -> String, value: f64) -> Result<(), WorldError> {
    if value.is_finite() && value.abs() <= MAX_MAGNITUDE {
        Ok(())
    } else {
        Err(WorldError::NotFinite {
            field: field(),
            value,
        })
    }
}

fn non_negative(field: &str, value: f64) -> Result<(), WorldError> {
    finite(|| field.to_string(), value)?;
    if value < 0.0 {
        return Err(WorldError::Negative {
            field: field.to_string(),
            value,
        });
    }
    Ok(())
}

/// Checks one polygon's points: count, finiteness, repeats, edges that touch or cross, an area.
///
/// The first fault in the order of a plain scan is reported (the lowest point repeating an
/// earlier one; the lowest pair of edges, an edge folding back onto the next counted with
/// that next), found in O(n log n) plus the pairs whose boxes overlap: a polygon of the
/// most points a world allows is checked in well under a millisecond, not the tens of
/// milliseconds every pair would take.
fn check_polygon(at: &str, points: &[Vec2]) -> Result<(), WorldError> {
    let field = format!("{at}.points");
    if points.len() < 3 {
        return Err(WorldError::TooFewPoints {
            field,
            count: points.len(),
        });
    }
    for (j, p) in points.iter().enumerate() {
        for v in [p.x, p.y] {
            finite(|| format!("{field}[{j}]"), v)?;
        }
    }
    if let Some((j, first)) = first_repeat(points) {
        return Err(WorldError::RepeatedPoint {
            field: format!("{field}[{j}]"),
            first,
            x: points[j].x,
            y: points[j].y,
        });
    }
    if let Some((edge_a, edge_b, p)) = first_touch(points) {
        return Err(WorldError::SelfIntersecting {
            field,
            edge_a,
            edge_b,
            x: p.x,
            y: p.y,
        });
    }
    // A simple polygon has an area; one that computes to none has underflowed, and its turning
    // sense, which the route and the outward normals take, would be a guess.
    if geometry::twice_area(points) == 0.0 {
        return Err(WorldError::ZeroArea { field });
    }
    Ok(())
}

/// The lowest index `j` whose point equals an earlier one, with that earlier one's index.
fn first_repeat(points: &[Vec2]) -> Option<(usize, usize)> {
    // `+ 0.0` makes -0 and 0 one key, as `==` takes them.
    let key = |k: usize| (points[k].x + 0.0, points[k].y + 0.0);
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_unstable_by(|&i, &j| {
        let (a, b) = (key(i), key(j));
        a.0.total_cmp(&b.0)
            .then(a.1.total_cmp(&b.1))
            .then(i.cmp(&j))
    });
    let mut group = order[0];
    let mut found: Option<(usize, usize)> = None;
    for w in order.windows(2) {
        if key(w[0]) != key(w[1]) {
            group = w[1];
        } else if found.is_none_or(|(j, _)| w[1] < j) {
            found = Some((w[1], group));
        }
    }
    found
}

/// Relative slack added to each edge's box, so that round-off in the exact distance never
/// finds a touch between edges whose boxes were taken as apart.
const BOX_SLACK: f64 = 64.0 * f64::EPSILON;

/// The first pair of edges `(a, b)` that touch, by `a` then `b` (edge `k` runs from point `k`
/// to the next), with a point of contact: two neighbours when they fold back onto each other
/// (at their shared point), others when their distance is zero. Edges are swept in the order
/// of their boxes' left sides; only pairs whose boxes overlap are measured.
fn first_touch(points: &[Vec2]) -> Option<(usize, usize, Vec2)> {
    let n = points.len();
    let edge = |k: usize| (points[k], points[(k + 1) % n]);
    // Keys (a, b) in the order of a scan over `a`, then `b`; a fold of `a` onto its next
    // comes first among `a`'s pairs, keyed `a + 1` (`n` for the closing one).
    let mut found: Option<((usize, usize), usize, Vec2)> = None;
    let offer = |found: &mut Option<_>, key: (usize, usize), b: usize, p: Vec2| {
        if found.as_ref().is_none_or(|(k, _, _)| key < *k) {
            *found = Some((key, b, p));
        }
    };
    for a in 0..n {
        let ((a0, a1), (_, a2)) = (edge(a), edge((a + 1) % n));
        let (u, v) = (a1 - a0, a2 - a1);
        if geometry::cross(u, v) == 0.0 && u.dot(&v) < 0.0 {
            offer(&mut found, (a, a + 1), (a + 1) % n, a1);
        }
    }
    let boxes: Vec<[f64; 4]> = (0..n)
        .map(|k| {
            let (a, b) = edge(k);
            let slack = BOX_SLACK * (1.0 + a.abs().max().max(b.abs().max()));
            [
                a.x.min(b.x) - slack,
                a.x.max(b.x) + slack,
                a.y.min(b.y) - slack,
                a.y.max(b.y) + slack,
            ]
        })
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by(|&i, &j| boxes[i][0].total_cmp(&boxes[j][0]));
    let mut open: Vec<usize> = Vec::new();
    for &k in &order {
        let [left, _, bottom, top] = boxes[k];
        open.retain(|&o| boxes[o][1] >= left);
        for &o in &open {
            let (a, b) = (k.min(o), k.max(o));
            if b == a + 1 || (a == 0 && b == n - 1) {
                continue; // neighbours: they meet at a point, and only a fold is wrong
            }
            if boxes[o][3] < bottom || boxes[o][2] > top {
                continue;
            }
            if found.as_ref().is_some_and(|(key, _, _)| *key <= (a, b)) {
                continue;
            }
            let ((a0, a1), (b0, b1)) = (edge(a), edge(b));
            if one_side(a0, a1, b0, b1) || one_side(b0, b1, a0, a1) {
                continue; // apart for certain: most pairs of a spiky polygon, cheaply
            }
            let (d2, p, _, _) = geometry::segment_segment(a0, a1, b0, b1);
            if d2 == 0.0 {
                offer(&mut found, (a, b), b, p);
            }
        }
        open.push(k);
    }
    found.map(|((a, _), b, p)| (a, b, p))
}

/// Shewchuk's bound on the rounding error of an orientation determinant, relative to the sum
/// of its two products' magnitudes ("Adaptive precision floating-point arithmetic and fast
/// robust geometric predicates", 1997: `ccwerrboundA`).
const ORIENT_BOUND: f64 = (3.0 + 16.0 * f64::EPSILON) * f64::EPSILON;

/// The side of the line through `a` and `b` on which `p` lies, when rounding cannot have
/// decided it: 1 left, -1 right, 0 on it or too near to tell.
fn side(a: Vec2, b: Vec2, p: Vec2) -> i8 {
    let left = (a.x - p.x) * (b.y - p.y);
    let right = (a.y - p.y) * (b.x - p.x);
    let det = left - right;
    let bound = ORIENT_BOUND * (left.abs() + right.abs());
    // Far above the subnormal range, where the bound no longer holds.
    if det.abs() <= bound || det.abs() < 1e-280 {
        0
    } else if det > 0.0 {
        1
    } else {
        -1
    }
}

/// Whether the segment `c d` lies strictly on one side of the line through `a` and `b`, for
/// certain: then it cannot touch the segment `a b`.
fn one_side(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let s = side(a, b, c);
    s != 0 && s == side(a, b, d)
}

/// Checks an obstacle's id at `at` (not whether another obstacle has it).
fn check_id(at: &str, o: &Obstacle) -> Result<(), WorldError> {
    if o.id.is_empty() {
        return Err(WorldError::EmptyId {
            field: format!("{at}.id"),
        });
    }
    match label_fault("id", &o.id, MAX_ID_CHARS) {
        Some(why) => Err(WorldError::BadId {
            field: format!("{at}.id"),
            why,
        }),
        None => Ok(()),
    }
}

/// What is wrong with `text`, a one-line label a user gave (an obstacle id, a scenario's
/// title) that is called `noun` in the message: more than `max_chars` characters, or a control
/// character (a line break, a tab, an escape), which garbles the messages, screens and
/// figures that show it (and is not allowed in XML at all). `None` when it is fine.
pub fn label_fault(noun: &str, text: &str, max_chars: usize) -> Option<String> {
    let chars = text.chars().count();
    if chars > max_chars {
        let article = if noun.starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        };
        return Some(format!(
            "{article} {noun} of {chars} characters, at most {max_chars} allowed"
        ));
    }
    text.chars()
        .find(|c| c.is_control())
        .map(|c| format!("{noun} {text:?} holds the control character {c:?}"))
}

/// Checks an obstacle's shape at `at`.
fn check_shape(at: &str, o: &Obstacle) -> Result<(), WorldError> {
    match &o.shape {
        Shape::Circle { center, radius_m } => {
            finite(|| format!("{at}.circle.center.x"), center.x)?;
            finite(|| format!("{at}.circle.center.y"), center.y)?;
            finite(|| format!("{at}.circle.radius_m"), *radius_m)?;
            if *radius_m <= 0.0 {
                return Err(WorldError::NotPositive {
                    field: format!("{at}.circle.radius_m"),
                    value: *radius_m,
                });
            }
            Ok(())
        }
        Shape::Polygon { points } => check_polygon(&format!("{at}.polygon"), points),
    }
}

/// Points of the obstacles' polygons, all together.
fn polygon_points<'a>(obstacles: impl IntoIterator<Item = &'a Obstacle>) -> usize {
    obstacles
        .into_iter()
        .map(|o| match &o.shape {
            Shape::Polygon { points } => points.len(),
            Shape::Circle { .. } => 0,
        })
        .sum()
}

/// Whether `count` obstacles with `points` polygon points in all fit in a world.
fn check_room(count: usize, points: usize) -> Result<(), WorldError> {
    if count > MAX_OBSTACLES {
        return Err(WorldError::TooManyObstacles {
            count,
            max: MAX_OBSTACLES,
        });
    }
    if points > MAX_POLYGON_POINTS {
        return Err(WorldError::TooManyPoints {
            count: points,
            max: MAX_POLYGON_POINTS,
        });
    }
    Ok(())
}

impl Obstacles {
    /// Checks obstacles; the first fault is reported, fields named `obstacles[i]...`: how
    /// many there are and their polygons' points in all, then in order each one's id
    /// (non-empty, at most [`MAX_ID_CHARS`] characters, no control character, not used by an
    /// earlier one) and shape.
    pub fn new(obstacles: Vec<Obstacle>) -> Result<Self, WorldError> {
        check_room(obstacles.len(), polygon_points(&obstacles))?;
        for (i, o) in obstacles.iter().enumerate() {
            let at = format!("obstacles[{i}]");
            check_id(&at, o)?;
            if let Some(first) = obstacles[..i].iter().position(|p| p.id == o.id) {
                return Err(WorldError::DuplicateId {
                    field: format!("{at}.id"),
                    id: o.id.clone(),
                    first,
                });
            }
            check_shape(&at, o)?;
        }
        Ok(Self::of_checked(obstacles))
    }

    fn of_checked(list: Vec<Obstacle>) -> Self {
        let bounds = list.iter().map(|o| o.shape.bounds()).collect();
        Self {
            list: list.into(),
            bounds,
        }
    }

    /// These and `more` after them, when its id is free and a world has room for it (in that
    /// order: an id in use is the fault to tell whatever the room); a refusal names it
    /// `obstacles[k]`, `k` the place it would have taken.
    pub fn with(&self, more: &CheckedObstacle) -> Result<Self, WorldError> {
        let o = &more.0;
        let k = self.list.len();
        if let Some(first) = self.list.iter().position(|p| p.id == o.id) {
            return Err(WorldError::DuplicateId {
                field: format!("obstacles[{k}].id"),
                id: o.id.clone(),
                first,
            });
        }
        check_room(k + 1, polygon_points(self.list.iter().chain([o])))?;
        let mut bounds = self.bounds.to_vec();
        bounds.push(o.shape.bounds());
        Ok(Self {
            list: self.list.iter().chain([o]).cloned().collect(),
            bounds: bounds.into(),
        })
    }

    /// These but the one at index `k` (all of them when there is none there).
    pub fn without(&self, k: usize) -> Self {
        let list: Vec<Obstacle> = self
            .list
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .map(|(_, o)| o.clone())
            .collect();
        let bounds = self
            .bounds
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .map(|(_, b)| *b)
            .collect();
        Self {
            list: list.into(),
            bounds,
        }
    }
}

impl Deref for Obstacles {
    type Target = [Obstacle];

    fn deref(&self) -> &[Obstacle] {
        &self.list
    }
}

impl CheckedObstacle {
    /// Checks one obstacle's id and shape, fields named `obstacle...`.
    pub fn new(obstacle: Obstacle) -> Result<Self, WorldError> {
        check_id("obstacle", &obstacle)?;
        check_shape("obstacle", &obstacle)?;
        Ok(Self(obstacle))
    }
}

impl Deref for CheckedObstacle {
    type Target = Obstacle;

    fn deref(&self) -> &Obstacle {
        &self.0
    }
}

impl Default for World {
    /// No obstacles, no link radius, the default clearance ([`DEFAULT_CLEARANCE_M`]).
    fn default() -> Self {
        Self {
            link_radius_m: 0.0,
            clearance_m: DEFAULT_CLEARANCE_M,
            obstacles: Obstacles::default(),
        }
    }
}

impl World {
    /// Validates a world. Obstacles are checked in order; the first fault is reported.
    ///
    /// `link_radius_m`: half the width of every link (the capsule's radius), `clearance_m`: the
    /// gap every link keeps from every obstacle, both finite and not negative.
    pub fn new(
        link_radius_m: f64,
        clearance_m: f64,
        obstacles: Vec<Obstacle>,
    ) -> Result<Self, WorldError> {
        non_negative("link_radius_m", link_radius_m)?;
        non_negative("clearance_m", clearance_m)?;
        Ok(Self {
            link_radius_m,
            clearance_m,
            obstacles: Obstacles::new(obstacles)?,
        })
    }

    /// The same link radius and clearance round other obstacles, already checked.
    pub fn with_obstacles(&self, obstacles: Obstacles) -> Self {
        Self {
            obstacles,
            ..self.clone()
        }
    }

    /// The same obstacles and link radius with another clearance, without checking the
    /// obstacles again.
    pub fn with_clearance(&self, clearance_m: f64) -> Result<Self, WorldError> {
        non_negative("clearance_m", clearance_m)?;
        Ok(Self {
            clearance_m,
            ..self.clone()
        })
    }

    /// Half the width of every link, m.
    pub fn link_radius_m(&self) -> f64 {
        self.link_radius_m
    }

    /// The gap every link keeps from every obstacle, m.
    pub fn clearance_m(&self) -> f64 {
        self.clearance_m
    }

    /// The obstacles, in the order given.
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    /// The obstacles as checked, to make another world of (see [`Obstacles::with`] and
    /// [`Obstacles::without`]).
    pub fn checked_obstacles(&self) -> &Obstacles {
        &self.obstacles
    }

    /// The obstacle whose id is `id`, with its index.
    pub fn find(&self, id: &str) -> Option<(usize, &Obstacle)> {
        self.obstacles.iter().enumerate().find(|(_, o)| o.id == id)
    }

    /// Signed distance from `p` to the nearest obstacle, m, and that obstacle's index; `None`
    /// for an empty world.
    pub fn point_distance(&self, p: Vec2) -> Option<(f64, usize)> {
        let mut best: Option<(f64, usize)> = None;
        for (k, o) in self.obstacles.iter().enumerate() {
            let d = o.shape.point_distance(p);
            if best.is_none_or(|(b, _)| d < b) {
                best = Some((d, k));
            }
        }
        best
    }

    /// Moves the point `p` out to at least `radius_m` from every obstacle, each time along the
    /// nearest one's outward normal (a few rounds, for a point between two); returns the point
    /// and the last obstacle that pushed it, or `None` when `p` was already that far from all.
    /// What a tip velocity slides along: the part of its step into an obstacle is removed.
    pub fn push_out(&self, p: Vec2, radius_m: f64) -> Option<(Vec2, usize)> {
        const ROUNDS: usize = 4;
        let mut q = p;
        let mut pushed = None;
        for _ in 0..ROUNDS {
            let Some((d, k)) = self.point_distance(q) else {
                break;
            };
            if d >= radius_m {
                break;
            }
            let normal = match &self.obstacles[k].shape {
                Shape::Circle { center, .. } => {
                    let e = q - center;
                    let n = e.norm();
                    if n > 0.0 {
                        e / n
                    } else {
                        Vec2::new(1.0, 0.0)
                    }
                }
                Shape::Polygon { points } => {
                    let (_, b, edge) = geometry::boundary_nearest(q, points);
                    let e = q - b;
                    let n = e.norm();
                    if n > 0.0 && d > 0.0 {
                        e / n
                    } else if n > 0.0 {
                        -e / n
                    } else {
                        // On the boundary: the edge's outward normal.
                        let m = points.len();
                        let t = points[(edge + 1) % m] - points[edge];
                        let sense = if geometry::twice_area(points) > 0.0 {
                            1.0
                        } else {
                            -1.0
                        };
                        Vec2::new(t.y, -t.x).normalize() * sense
                    }
                }
            };
            // Signed distance grows at unit rate along the normal, outside and (nearly) inside.
            q += normal * (radius_m - d) * (1.0 + 1e-9);
            pushed = Some((q, k));
        }
        pushed
    }

    /// Whether no point of the box `lo..hi` can be nearer than `d` to obstacle `k`: the gap
    /// between the boxes bounds their distance from below (compared squared, no root taken).
    /// Signed: with `d <= 0` only a box apart from the obstacle's is, since a segment inside
    /// an obstacle has a negative distance (minus its depth), below any `d`.
    fn box_not_below(&self, k: usize, lo: Vec2, hi: Vec2, d: f64) -> bool {
        let (blo, bhi) = self.obstacles.bounds[k];
        let dx = (blo.x - hi.x).max(lo.x - bhi.x).max(0.0);
        let dy = (blo.y - hi.y).max(lo.y - bhi.y).max(0.0);
        let gap2 = dx * dx + dy * dy;
        if d > 0.0 {
            gap2 >= d * d
        } else {
            gap2 > 0.0
        }
    }

    /// Whether that gap is more than `d` (with `d < 0`: whether the boxes are apart, since a
    /// segment inside an obstacle has a negative distance).
    fn box_beyond(&self, k: usize, lo: Vec2, hi: Vec2, d: f64) -> bool {
        let (blo, bhi) = self.obstacles.bounds[k];
        let dx = (blo.x - hi.x).max(lo.x - bhi.x).max(0.0);
        let dy = (blo.y - hi.y).max(lo.y - bhi.y).max(0.0);
        let gap2 = dx * dx + dy * dy;
        if d < 0.0 {
            gap2 > 0.0
        } else {
            gap2 > d * d
        }
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod brute_tests;
