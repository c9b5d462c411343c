//! The tip's route: the shortest polyline from a start to a goal that keeps clear of the
//! obstacles, for a path follower to run as legs.
//!
//! The tip must stay `r = link_radius_m + clearance_m` from every obstacle; the route keeps
//! `g = r + margin`, with `margin = max(0.5 mm, 0.1 clearance_m)` the follower's slack. A start
//! or goal closer than `r` (or touching) is refused, naming the obstacle; one between `r` and
//! `g` is accepted, and the legs that touch it keep only its own distance. So every point of a route is at least
//! `min(g, d(start), d(goal)) >= r` from every obstacle.
//!
//! The straight leg is taken when it clears. Otherwise the route is the shortest path in a
//! visibility graph whose nodes lie on the grown obstacles' convex arcs: around each circle
//! (radius + `g`) and around each convex corner of each polygon (radius `g`: the Minkowski sum of
//! a polygon and a disc is its edges pushed out joined by such arcs; reflex corners add none,
//! as no shortest path bends there). Each arc is replaced by a polyline that circumscribes it,
//! so every leg stays OUTSIDE the true grown shape: with `n` steps over a turn of `a` its `n`
//! corners sit at `g / cos(a / 2n)` in the middle of each step and the polyline lies within
//! `margin` (the chord tolerance) outside the arc, its end legs along the pushed-out edges; a
//! full turn has between 8 and 64 steps. Every leg of the graph is checked against
//! every obstacle with the exact segment distance, so the guarantee does not rest on the
//! construction. Dijkstra runs over at most [`MAX_ROUTE_NODES`] arc nodes (the tolerance
//! doubles until they fit), adjacency computed as nodes are settled.
//!
//! Where the body's way of trailing the tip is known ([`World::route_trailed`]), a route that
//! rounds its first obstacle on the body's side is taken over the shortest when it is at most
//! [`TRAILING_SIDE_SLACK`] longer: with a post on the straight way, both ways round are about
//! as short, and only the one on the body's side lets the last link follow.

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::PI;

use super::geometry::{cross, twice_area};
use super::{Shape, World};
use crate::chain::Vec2;

/// The least margin the route keeps beyond `link_radius_m + clearance_m`, m.
pub const MIN_ROUTE_MARGIN_M: f64 = 0.5e-3;

/// The route's margin as a fraction of `clearance_m`, when larger than the least.
pub const ROUTE_MARGIN_FRACTION: f64 = 0.1;

/// Fewest and most polyline steps for a full turn of an arc.
const MIN_TURN_STEPS: usize = 8;
const MAX_TURN_STEPS: usize = 64;

/// Most arc nodes of a route's graph: past it the chord tolerance doubles until they fit (the
/// legs stay outside, only a little longer), which bounds the search's work.
pub const MAX_ROUTE_NODES: usize = 2048;

/// Most work one route may take, in checks of a segment against an obstacle's edge or circle
/// (and of an arc node against each). It bounds what planning a command costs: past it the
/// route is refused ([`RouteError::TooMuchWork`]), not searched for longer, and a `path`
/// shares it among its legs. On a small 2-core machine a check takes 2 to 8 ns (most are a box
/// apart), so a command plans in at most about 80 ms (the daemon plans what takes longer than
/// a tick can spare beside its loop). Threading a grid of sixteen 64-gons (1024 points) takes
/// 9 million; a 512-point star, 5.6 million; post and shelf, a few thousand.
pub const MAX_ROUTE_WORK: u64 = 10_000_000;

/// How much longer than the shortest route (as a fraction of it) one that sets out on the side
/// the body trails may be and still be taken ([`World::route_trailed`]).
pub const TRAILING_SIDE_SLACK: f64 = 0.05;

/// Nodes sit this fraction further out than the circumscribing radius, so round-off never
/// brings a chord inside.
const OUTSIDE: f64 = 1e-9;

/// Which end of a route.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RouteEnd {
    /// Where the route begins.
    Start,
    /// Where it ends.
    Goal,
}

impl std::fmt::Display for RouteEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            RouteEnd::Start => "start",
            RouteEnd::Goal => "goal",
        })
    }
}

/// Why no route was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RouteError {
    /// An end that is not a finite point.
    #[error("{end}: ({x}, {y}) is not a finite point")]
    NotFinite {
        /// Which end.
        end: RouteEnd,
        /// x, m.
        x: f64,
        /// y, m.
        y: f64,
    },
    /// An end closer to an obstacle than `link_radius_m + clearance_m`, on it or inside it.
    #[error(
        "{end} ({x}, {y}) is {}; the tip must keep {needed_m} m",
        super::standing(*distance_m, id)
    )]
    Inside {
        /// Which end.
        end: RouteEnd,
        /// The obstacle.
        id: String,
        /// x, m.
        x: f64,
        /// y, m.
        y: f64,
        /// Its signed distance from the obstacle, m (negative inside).
        distance_m: f64,
        /// What the tip must keep, m.
        needed_m: f64,
    },
    /// The search needed more than the work it was given ([`MAX_ROUTE_WORK`] for one route).
    #[error(
        "the route needs more than {limit} segment checks among these obstacles, the most a \
         command may spend"
    )]
    TooMuchWork {
        /// The work the search was given.
        limit: u64,
    },
    /// The obstacles, grown, separate the start from the goal.
    #[error("no route clears the obstacles by {needed_m} m: the goal is closed off")]
    NoRoute {
        /// The distance the route had to keep, m.
        needed_m: f64,
    },
}

/// A route: waypoints from the start to the goal (both included) and its length.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    /// The polyline's corners, start first, goal last.
    pub waypoints: Vec<Vec2>,
    /// Sum of the legs, m.
    pub length_m: f64,
}

/// A node of the graph on an arc: the point, the arc's centre and half its step, rad.
#[derive(Debug, Clone, Copy)]
struct ArcNode {
    p: Vec2,
    center: Vec2,
    half_step: f64,
}

/// Steps for a full turn of an arc of radius `rho` so the circumscribing polyline stays within
/// `tol` of it.
fn turn_steps(rho: f64, tol: f64) -> usize {
    let half = (rho / (rho + tol)).acos();
    let n = if half > 0.0 {
        (PI / half).ceil()
    } else {
        f64::INFINITY
    };
    if n.is_finite() {
        (n as usize).clamp(MIN_TURN_STEPS, MAX_TURN_STEPS)
    } else {
        MAX_TURN_STEPS
    }
}

/// Pushes the corners of the polyline that circumscribes the arc around `center` of radius `rho`
/// from angle `from` over `turn` (signed, rad): `m` corners at the middles of `m` equal steps,
/// at `rho / cos(step / 2)`, so its first and last legs are tangent at the arc's ends (for a
/// polygon's corner, along its edges pushed out).
fn push_arc(out: &mut Vec<ArcNode>, center: Vec2, rho: f64, from: f64, turn: f64, steps: usize) {
    let per_turn = 2.0 * PI / steps as f64;
    let m = ((turn.abs() / per_turn).ceil() as usize).max(1);
    let step = turn / m as f64;
    let half_step = step.abs() / 2.0;
    let radius = rho / half_step.cos() * (1.0 + OUTSIDE);
    for k in 0..m {
        let a = from + step * (k as f64 + 0.5);
        out.push(ArcNode {
            p: center + Vec2::new(a.cos(), a.sin()) * radius,
            center,
            half_step,
        });
    }
}

/// The work a route search may do and has done.
#[derive(Debug)]
struct Work {
    limit: u64,
    spent: u64,
}

impl Work {
    fn spend(&mut self, n: u64) {
        self.spent = self.spent.saturating_add(n);
    }

    fn over(&self) -> bool {
        self.spent > self.limit
    }
}

/// A cost in the heap, smallest first.
#[derive(Debug, PartialEq)]
struct Open(f64, usize);

impl Eq for Open {}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

impl World {
    /// The distance the tip keeps from every obstacle, m: `link_radius_m + clearance_m`.
    pub fn route_radius_m(&self) -> f64 {
        self.link_radius_m + self.clearance_m
    }

    /// The route's slack beyond [`World::route_radius_m`], m.
    pub fn route_margin_m(&self) -> f64 {
        MIN_ROUTE_MARGIN_M.max(ROUTE_MARGIN_FRACTION * self.clearance_m)
    }

    /// Whether the segment `a..b` keeps at least `floor` from every obstacle; `work` counts the
    /// edges and circles it is checked against.
    fn leg_clear(&self, a: Vec2, b: Vec2, floor: f64, work: &mut Work) -> bool {
        let (lo, hi) = (a.inf(&b), a.sup(&b));
        (0..self.obstacles.len()).all(|k| {
            if self.box_not_below(k, lo, hi, floor) {
                return true;
            }
            work.spend(self.obstacles[k].shape.size());
            self.obstacles[k].shape.segment_clears(a, b, floor)
        })
    }

    /// The arc nodes of every obstacle grown by `g` with the chord tolerance `tol`, or coarser
    /// when there would be more than [`MAX_ROUTE_NODES`]; those at least `g` from all obstacles.
    fn arc_nodes(&self, g: f64, tol: f64, work: &mut Work) -> Vec<ArcNode> {
        let mut tol = tol;
        let mut nodes = Vec::new();
        // At the coarsest (8 steps a turn) 64 circles and 1024 corners make at most 2560.
        for _ in 0..64 {
            self.push_arc_nodes(g, tol, &mut nodes);
            if nodes.len() <= MAX_ROUTE_NODES {
                break;
            }
            tol *= 2.0;
        }
        let sizes: u64 = self.obstacles.iter().map(|o| o.shape.size()).sum();
        work.spend(sizes.saturating_mul(nodes.len() as u64));
        if work.over() {
            return Vec::new();
        }
        nodes.retain(|a| {
            self.obstacles
                .iter()
                .all(|o| o.shape.point_distance(a.p) >= g)
        });
        nodes
    }

    /// Fills `nodes` with the arc nodes of every obstacle grown by `g`, chord tolerance `tol`.
    fn push_arc_nodes(&self, g: f64, tol: f64, nodes: &mut Vec<ArcNode>) {
        nodes.clear();
        for o in self.obstacles() {
            match &o.shape {
                Shape::Circle { center, radius_m } => {
                    let rho = radius_m + g;
                    push_arc(nodes, *center, rho, 0.0, 2.0 * PI, turn_steps(rho, tol));
                }
                Shape::Polygon { points } => {
                    let n = points.len();
                    let sense = if twice_area(points) > 0.0 { 1.0 } else { -1.0 };
                    let steps = turn_steps(g, tol);
                    for k in 0..n {
                        let (prev, v, next) =
                            (points[(k + n - 1) % n], points[k], points[(k + 1) % n]);
                        let (e_in, e_out) = (v - prev, next - v);
                        let turn = cross(e_in, e_out).atan2(e_in.dot(&e_out));
                        if turn * sense <= 0.0 {
                            continue; // reflex or straight
                        }
                        let normal_in = Vec2::new(e_in.y, -e_in.x) * sense;
                        let from = normal_in.y.atan2(normal_in.x);
                        push_arc(nodes, v, g, from, turn, steps);
                    }
                }
            }
        }
    }

    /// The shortest route for the tip from `start` to `goal` (see the module doc), within
    /// [`MAX_ROUTE_WORK`].
    ///
    /// The goal is checked before the start, so a start refused as [`RouteError::Inside`]
    /// means the goal is one the tip can be at: a caller that leaves a start not clear on a
    /// straight line still refuses a goal inside an obstacle.
    pub fn route(&self, start: Vec2, goal: Vec2) -> Result<Route, RouteError> {
        let mut left = MAX_ROUTE_WORK;
        self.route_within(start, goal, &mut left)
    }

    /// [`World::route`] with at most `left` work (in checks of a segment against an edge or a
    /// circle), less what it spent on return: legs of one command share one budget.
    pub fn route_within(
        &self,
        start: Vec2,
        goal: Vec2,
        left: &mut u64,
    ) -> Result<Route, RouteError> {
        self.route_trailed(start, goal, Vec2::zeros(), left)
    }

    /// [`World::route_within`] for a tip whose body trails it in direction `trailing` (from the
    /// tip toward the joint behind it; zero: no preference). When the shortest route bends
    /// round its first obstacle on the other side of the straight line than the body, and the
    /// shortest route that keeps to the body's side of that line is at most
    /// [`TRAILING_SIDE_SLACK`] longer, that one is taken: a body dragged round an obstacle from
    /// the far side is caught on it (its last link swings across), one led round its own side
    /// follows. The work counts both searches.
    pub fn route_trailed(
        &self,
        start: Vec2,
        goal: Vec2,
        trailing: Vec2,
        left: &mut u64,
    ) -> Result<Route, RouteError> {
        let mut work = Work {
            limit: *left,
            spent: 0,
        };
        let found = self
            .search(start, goal, 0.0, &mut work)
            .and_then(|shortest| {
                let ahead = goal - start;
                let lean = cross(ahead, trailing);
                let first = match shortest.waypoints.get(1) {
                    Some(&w) if shortest.waypoints.len() > 2 && lean != 0.0 => w,
                    _ => return Ok(shortest),
                };
                let body = lean.signum();
                if cross(ahead, first - start) * body > 0.0 {
                    return Ok(shortest);
                }
                match self.search(start, goal, body, &mut work) {
                    Ok(side)
                        if side.length_m <= shortest.length_m * (1.0 + TRAILING_SIDE_SLACK) =>
                    {
                        Ok(side)
                    }
                    Ok(_) | Err(RouteError::NoRoute { .. }) => Ok(shortest),
                    Err(e) => Err(e),
                }
            });
        *left = left.saturating_sub(work.spent);
        if work.over() {
            return Err(RouteError::TooMuchWork { limit: work.limit });
        }
        found
    }

    /// The shortest route; with `side` +1 or -1, the shortest that keeps to that side of the
    /// line from `start` to `goal` (left, right of it): every corner on it or beyond.
    fn search(
        &self,
        start: Vec2,
        goal: Vec2,
        side: f64,
        work: &mut Work,
    ) -> Result<Route, RouteError> {
        let r = self.route_radius_m();
        let g = r + self.route_margin_m();
        let mut ends = [0.0; 2];
        for (slot, (end, p)) in [(1, (RouteEnd::Goal, goal)), (0, (RouteEnd::Start, start))] {
            if !(p.x.is_finite() && p.y.is_finite()) {
                return Err(RouteError::NotFinite {
                    end,
                    x: p.x,
                    y: p.y,
                });
            }
            let (d, k) = self.point_distance(p).unwrap_or((f64::INFINITY, 0));
            if d < r || d <= 0.0 {
                return Err(RouteError::Inside {
                    end,
                    id: self.obstacles[k].id.clone(),
                    x: p.x,
                    y: p.y,
                    distance_m: d,
                    needed_m: r,
                });
            }
            ends[slot] = d.min(g);
        }
        if self.leg_clear(start, goal, ends[0].min(ends[1]), work) {
            return Ok(Route {
                waypoints: vec![start, goal],
                length_m: (goal - start).norm(),
            });
        }
        let arcs = self.arc_nodes(g, self.route_margin_m(), work);
        // Node 0 the start, 1 the goal, then the arcs.
        let count = arcs.len() + 2;
        let point = |i: usize| match i {
            0 => start,
            1 => goal,
            _ => arcs[i - 2].p,
        };
        // A leg between arc nodes never heads into either's own arc (a quick test before the
        // exact one; an end inside the margin band may lie behind an arc, so its legs skip it).
        let leaves = |i: usize, j: usize, to: Vec2| -> bool {
            if i < 2 || j < 2 {
                return true;
            }
            let a = &arcs[i - 2];
            let (e, d) = (to - a.p, a.p - a.center);
            e.dot(&d) >= -(a.half_step.sin() + 1e-9) * e.norm() * d.norm()
        };
        let floor = |i: usize, j: usize| {
            let mut f = g;
            for end in [i, j] {
                if end < 2 {
                    f = f.min(ends[end]);
                }
            }
            f
        };
        let mut cost = vec![f64::INFINITY; count];
        let mut from = vec![usize::MAX; count];
        let mut done = vec![false; count];
        let mut open = BinaryHeap::new();
        cost[0] = 0.0;
        open.push(Open(0.0, 0));
        while let Some(Open(c, u)) = open.pop() {
            if done[u] {
                continue;
            }
            done[u] = true;
            if u == 1 {
                break;
            }
            let pu = point(u);
            for w in 1..count {
                if done[w] {
                    continue;
                }
                let pw = point(w);
                if w > 1 && side * cross(goal - start, pw - start) < 0.0 {
                    continue;
                }
                let len = (pw - pu).norm();
                if c + len >= cost[w] || !leaves(u, w, pw) || !leaves(w, u, pu) {
                    continue;
                }
                if self.leg_clear(pu, pw, floor(u, w), work) {
                    cost[w] = c + len;
                    from[w] = u;
                    open.push(Open(c + len, w));
                }
                if work.over() {
                    return Err(RouteError::TooMuchWork { limit: work.limit });
                }
            }
        }
        if !done[1] {
            return Err(RouteError::NoRoute { needed_m: g });
        }
        let mut waypoints = vec![goal];
        let mut i = 1;
        while i != 0 {
            i = from[i];
            waypoints.push(point(i));
        }
        waypoints.reverse();
        Ok(Route {
            waypoints,
            length_m: cost[1],
        })
    }
}

#[cfg(test)]
pub(super) mod tests;
