//! Flip starts of a cold solve among obstacles: a pose with the body carried to the other side
//! of one obstacle. The distinct clear optima differ mainly in which side of each obstacle each
//! part of the body passes, and a local solve keeps the side it starts on; a start that puts
//! the part nearest one obstacle across it, the tip on target and the rest of the pose kept
//! close, leads the local solve to the optimum on that side.

use nalgebra::{Matrix4, Vector4};

use super::super::Problem;
use crate::chain::Vec2;
use crate::world::{Shape, World};

/// Gauss-Newton iterations that carry the contact point across: the two point conditions are
/// nearly linear over a move of a few link radii, so a few iterations meet them closely (and a
/// start need not meet them exactly: the local solve takes over).
const FLIP_ITERATIONS: usize = 8;
/// Largest joint move of one of those iterations, rad: keeps each step within the range where
/// the linearization holds when the point must go around a wide obstacle.
const FLIP_MAX_MOVE: f64 = 0.5;
/// Damping of the 4 x 4 normal equations, relative to the squared scale: keeps them solvable
/// when the point and the tip rows are dependent (the point on the last link near the tip),
/// far below their entries otherwise (of the order of the squared scale).
const FLIP_DAMPING: f64 = 1e-9;
/// The iterations stop once both points are within this fraction of the scale of their goals.
const FLIP_TOLERANCE: f64 = 1e-9;

/// The link (1-based) of the pose whose points are `pts` nearest obstacle `k`, with its
/// clearance (m; see [`World::pair`]).
pub(super) fn nearest_link(world: &World, pts: &[Vec2], k: usize) -> (usize, f64) {
    let mut best = (1, f64::INFINITY);
    for link in 1..pts.len() {
        let c = world.pair(pts, link, k).clearance_m;
        if c < best.1 {
            best = (link, c);
        }
    }
    best
}

/// How far the shape reaches from its boundary point `from` in the direction `dir` (its width
/// across, for a disc through its centre), m.
fn extent(shape: &Shape, from: Vec2, dir: Vec2) -> f64 {
    match shape {
        Shape::Circle { center, radius_m } => ((center - from).dot(&dir) + radius_m).max(0.0),
        Shape::Polygon { points } => points
            .iter()
            .map(|v| (v - from).dot(&dir))
            .fold(0.0, f64::max),
    }
}

/// Writes to `out` the pose `src` with the point of the body nearest obstacle `k` carried
/// straight through the obstacle to its far side, clear of it by twice the world's clearance
/// (the clearance, and as much again so that the start is not on the boundary of what is
/// clear), and the tip kept on `p.target`: a few minimum-norm Gauss-Newton steps on those two
/// point conditions, each joint clipped into `lo..hi`, so that the rest of the pose moves
/// little. `pts` is scratch of `n + 1` points.
#[allow(clippy::too_many_arguments)]
pub(super) fn flip_pose(
    world: &World,
    p: &Problem,
    src: &[f64],
    k: usize,
    lo: &[f64],
    hi: &[f64],
    pts: &mut [Vec2],
    out: &mut [f64],
) {
    out.copy_from_slice(src);
    p.chain.points_into(src, pts);
    let (link, _) = nearest_link(world, pts, k);
    let c = world.pair(pts, link, k).contact;
    let across = c.distance_m
        + extent(&world.obstacles()[k].shape, c.on_obstacle, -c.normal)
        + world.link_radius_m()
        + 2.0 * world.clearance_m();
    let goal = c.on_segment - c.normal * across;
    let n = out.len();
    for _ in 0..FLIP_ITERATIONS {
        p.chain.points_into(out, pts);
        let point = pts[link - 1] + (pts[link] - pts[link - 1]) * c.s;
        let tip = pts[n];
        let r = Vector4::new(
            goal.x - point.x,
            goal.y - point.y,
            p.target.x - tip.x,
            p.target.y - tip.y,
        );
        if r.norm() <= FLIP_TOLERANCE * p.scale {
            break;
        }
        // Column `a` of the 4 x n Jacobian: the point's x, y (moved by the joints before it)
        // and the tip's; d/dtheta_a of a point q is perp(q - p_a).
        let column = |a: usize| -> [f64; 4] {
            let (dp, dt) = (point - pts[a], tip - pts[a]);
            let moves = a < link;
            [
                if moves { -dp.y } else { 0.0 },
                if moves { dp.x } else { 0.0 },
                -dt.y,
                dt.x,
            ]
        };
        let mut m = Matrix4::<f64>::identity() * (FLIP_DAMPING * p.scale * p.scale);
        for a in 0..n {
            let g = column(a);
            for i in 0..4 {
                for j in 0..4 {
                    m[(i, j)] += g[i] * g[j];
                }
            }
        }
        let Some(lam) = m.cholesky().map(|ch| ch.solve(&r)) else {
            break;
        };
        // The step is J^T lam, cut so that no joint moves more than FLIP_MAX_MOVE.
        let step = |a: usize| -> f64 {
            let g = column(a);
            (0..4).map(|i| g[i] * lam[i]).sum()
        };
        let big = (0..n).map(step).fold(0.0, |m: f64, d| m.max(d.abs()));
        let cut = if big > FLIP_MAX_MOVE {
            FLIP_MAX_MOVE / big
        } else {
            1.0
        };
        for a in 0..n {
            out[a] = (out[a] + cut * step(a)).clamp(lo[a], hi[a]);
        }
    }
}
