//! Obstacles as lines to draw: an obstacle's boundary, the boundary of the obstacle grown by a
//! margin (where the axis of a link of radius `link_radius_m` may come no nearer when it keeps
//! `clearance_m`: grown by their sum), and clipping to a view.
//!
//! The grown boundary of a polygon is found without building the offset polygon: the walk
//! around it made of every edge moved out by the margin and an arc about every convex corner
//! holds the whole boundary, and its points at less than the margin from the polygon (where
//! the moved edges of a concave corner cross, or where two parts of the polygon come near each
//! other) are not on it. Dropping those leaves the boundary as runs of points, exact up to the
//! sampling step, for any simple polygon.

use crate::chain::Vec2;
use crate::world::geometry::{cross, twice_area};
use crate::world::Shape;

/// Most points a circle is drawn with.
const MAX_CIRCLE_POINTS: usize = 720;
/// Fewest points a circle is drawn with.
const MIN_CIRCLE_POINTS: usize = 24;
/// About the most points a grown polygon's walk takes (a longer walk is sampled more coarsely).
const MAX_WALK_POINTS: f64 = 20_000.0;

/// Points on the circle (`center`, `radius`) at most about `step_m` apart, counter-clockwise
/// from angle 0, not repeating the first.
fn circle(center: Vec2, radius: f64, step_m: f64) -> Vec<Vec2> {
    let n = (std::f64::consts::TAU * radius / step_m.max(f64::MIN_POSITIVE))
        .ceil()
        .clamp(MIN_CIRCLE_POINTS as f64, MAX_CIRCLE_POINTS as f64) as usize;
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            center + Vec2::new(a.cos(), a.sin()) * radius
        })
        .collect()
}

/// The shape's boundary as a closed polygon (the last point joins the first, not repeated):
/// a polygon's own points, a circle's points at most about `step_m` apart.
pub fn boundary(shape: &Shape, step_m: f64) -> Vec<Vec2> {
    match shape {
        Shape::Circle { center, radius_m } => circle(*center, *radius_m, step_m),
        Shape::Polygon { points } => points.clone(),
    }
}

/// The boundary of the shape grown by `by_m` (the points at exactly that distance outside it),
/// as open polylines whose points are at most about `step_m` apart; a boundary found whole is
/// one polyline that ends where it starts. Nothing for a negative or non-finite `by_m`.
pub fn grown(shape: &Shape, by_m: f64, step_m: f64) -> Vec<Vec<Vec2>> {
    if !(by_m >= 0.0 && by_m.is_finite()) {
        return Vec::new();
    }
    let walk = match shape {
        Shape::Circle { center, radius_m } => circle(*center, radius_m + by_m, step_m),
        Shape::Polygon { points } => polygon_walk(points, by_m, step_m),
    };
    if walk.is_empty() {
        return Vec::new();
    }
    let tol = 1e-9 * (1.0 + by_m);
    let keep: Vec<bool> = walk
        .iter()
        .map(|&p| shape.point_distance(p) >= by_m - tol)
        .collect();
    runs(&walk, &keep)
}

/// The walk around a polygon moved out by `by_m`: each edge moved along its outward normal,
/// and an arc about each convex corner from one edge's normal to the next, `step_m` apart.
fn polygon_walk(points: &[Vec2], by_m: f64, step_m: f64) -> Vec<Vec2> {
    let n = points.len();
    if n < 3 {
        return Vec::new();
    }
    let perimeter: f64 = (0..n)
        .map(|k| (points[(k + 1) % n] - points[k]).norm())
        .sum::<f64>()
        + std::f64::consts::TAU * by_m;
    let step = step_m
        .max(perimeter / MAX_WALK_POINTS)
        .max(f64::MIN_POSITIVE);
    // Counter-clockwise order: the outward normal is the edge's right-hand side.
    let ccw: Vec<Vec2> = if twice_area(points) >= 0.0 {
        points.to_vec()
    } else {
        points.iter().rev().copied().collect()
    };
    let dir = |k: usize| (ccw[(k + 1) % n] - ccw[k]).try_normalize(0.0);
    let normal = |d: Vec2| Vec2::new(d.y, -d.x);
    let mut walk = Vec::new();
    for k in 0..n {
        let (Some(d_in), Some(d_out)) = (dir((k + n - 1) % n), dir(k)) else {
            continue;
        };
        let (n_in, n_out) = (normal(d_in), normal(d_out));
        let v = ccw[k];
        if by_m > 0.0 && cross(d_in, d_out) > 0.0 {
            // A convex corner: the arc from the incoming edge's normal to the outgoing one's.
            let sweep = cross(n_in, n_out).atan2(n_in.dot(&n_out));
            let a0 = n_in.y.atan2(n_in.x);
            let parts = ((sweep * by_m / step).ceil() as usize).max(1);
            for j in 0..parts {
                let a = a0 + sweep * j as f64 / parts as f64;
                walk.push(v + Vec2::new(a.cos(), a.sin()) * by_m);
            }
        }
        let (a, b) = (v + n_out * by_m, ccw[(k + 1) % n] + n_out * by_m);
        let parts = (((b - a).norm() / step).ceil() as usize).max(1);
        for j in 0..parts {
            walk.push(a + (b - a) * (j as f64 / parts as f64));
        }
    }
    walk
}

/// The runs of a closed walk's kept points, as polylines; the run through the walk's end
/// joins the one at its start, and a walk kept whole comes back to its first point.
fn runs(walk: &[Vec2], keep: &[bool]) -> Vec<Vec<Vec2>> {
    let Some(first_dropped) = keep.iter().position(|k| !k) else {
        let mut whole = walk.to_vec();
        whole.push(walk[0]);
        return vec![whole];
    };
    // Start just after a dropped point, so that no run is split by the walk's end.
    let n = walk.len();
    let mut out = Vec::new();
    let mut current: Vec<Vec2> = Vec::new();
    for j in 1..=n {
        let k = (first_dropped + j) % n;
        if keep[k] {
            current.push(walk[k]);
        } else if !current.is_empty() {
            out.push(std::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        out.push(current);
    }
    out.retain(|r| r.len() > 1);
    out
}

/// The part of a polygon inside the box `lo..hi` (Sutherland-Hodgman: exact for any polygon
/// against a convex box; the parts a concave polygon leaves apart are joined along the box's
/// edges, which fills the same area). Empty when nothing is inside.
pub fn clip_polygon(points: &[Vec2], lo: Vec2, hi: Vec2) -> Vec<Vec2> {
    // Each side of the box: inside when `f(p) >= 0`.
    let sides: [(usize, f64, f64); 4] = [
        (0, lo.x, 1.0),
        (0, hi.x, -1.0),
        (1, lo.y, 1.0),
        (1, hi.y, -1.0),
    ];
    let mut poly = points.to_vec();
    for (axis, at, sign) in sides {
        if poly.is_empty() {
            break;
        }
        let f = |p: &Vec2| sign * (p[axis] - at);
        let mut next = Vec::with_capacity(poly.len() + 4);
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            let (fa, fb) = (f(&a), f(&b));
            if fa >= 0.0 {
                next.push(a);
            }
            if (fa >= 0.0) != (fb >= 0.0) {
                next.push(a + (b - a) * (fa / (fa - fb)));
            }
        }
        poly = next;
    }
    if poly.len() < 3 {
        Vec::new()
    } else {
        poly
    }
}

/// The parts of a polyline inside the box `lo..hi` (each segment clipped, Liang-Barsky), as
/// polylines.
pub fn clip_polyline(points: &[Vec2], lo: Vec2, hi: Vec2) -> Vec<Vec<Vec2>> {
    let mut out: Vec<Vec<Vec2>> = Vec::new();
    let mut current: Vec<Vec2> = Vec::new();
    for w in points.windows(2) {
        match clip_segment(w[0], w[1], lo, hi) {
            Some((a, b, whole_end)) => {
                if current.last() != Some(&a) {
                    if current.len() > 1 {
                        out.push(std::mem::take(&mut current));
                    }
                    current.clear();
                    current.push(a);
                }
                current.push(b);
                if !whole_end {
                    out.push(std::mem::take(&mut current));
                }
            }
            None => {
                if current.len() > 1 {
                    out.push(std::mem::take(&mut current));
                }
                current.clear();
            }
        }
    }
    if current.len() > 1 {
        out.push(current);
    }
    out
}

/// The part of the segment `a..b` inside the box, and whether it reaches `b`.
fn clip_segment(a: Vec2, b: Vec2, lo: Vec2, hi: Vec2) -> Option<(Vec2, Vec2, bool)> {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-d.x, a.x - lo.x),
        (d.x, hi.x - a.x),
        (-d.y, a.y - lo.y),
        (d.y, hi.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    let start = if t0 == 0.0 { a } else { a + d * t0 };
    let end = if t1 == 1.0 { b } else { a + d * t1 };
    Some((start, end, t1 == 1.0))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64) -> Vec2 {
        Vec2::new(x, y)
    }

    #[test]
    fn a_grown_circle_is_one_closed_ring_at_the_grown_radius() {
        let shape = Shape::Circle {
            center: v(1.0, 2.0),
            radius_m: 0.1,
        };
        let rings = grown(&shape, 0.05, 0.01);
        assert_eq!(rings.len(), 1);
        let ring = &rings[0];
        assert_eq!(ring.first(), ring.last());
        assert!(ring.len() > 90, "{}", ring.len());
        for p in ring {
            assert!(((p - v(1.0, 2.0)).norm() - 0.15).abs() < 1e-12);
        }
        assert_eq!(boundary(&shape, 0.01).len(), 63);
    }

    #[test]
    fn a_grown_convex_polygon_is_whole_and_at_the_margin_everywhere() {
        // Clockwise on purpose.
        let square = Shape::Polygon {
            points: vec![v(0.0, 0.0), v(0.0, 1.0), v(1.0, 1.0), v(1.0, 0.0)],
        };
        let rings = grown(&square, 0.2, 0.05);
        assert_eq!(rings.len(), 1);
        let ring = &rings[0];
        assert_eq!(ring.first(), ring.last());
        for p in ring {
            assert!((square.point_distance(*p) - 0.2).abs() < 1e-12, "{p:?}");
        }
        // It goes round: the four sides and the four rounded corners.
        let length: f64 = ring.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let exact = 4.0 + std::f64::consts::TAU * 0.2;
        assert!((length - exact).abs() < 0.01, "{length} vs {exact}");
    }

    #[test]
    fn a_concave_corner_cuts_the_moved_edges_where_they_cross() {
        // An L: the corner at (1, 1) is concave.
        let l = Shape::Polygon {
            points: vec![
                v(0.0, 0.0),
                v(2.0, 0.0),
                v(2.0, 1.0),
                v(1.0, 1.0),
                v(1.0, 2.0),
                v(0.0, 2.0),
            ],
        };
        let runs = grown(&l, 0.1, 0.01);
        let kept: usize = runs.iter().map(Vec::len).sum();
        assert!(kept > 700, "{kept}");
        for p in runs.iter().flatten() {
            assert!((l.point_distance(*p) - 0.1).abs() < 1e-9, "{p:?}");
        }
        // Nothing drawn inside the concave corner's crossing.
        assert!(runs
            .iter()
            .flatten()
            .all(|p| !(p.x > 1.0 && p.x < 1.1 && p.y > 1.0 && p.y < 1.1)));
        // The crossing at (1.1, 1.1) is reached from both sides within a step.
        let near = runs
            .iter()
            .flatten()
            .filter(|p| (*p - v(1.1, 1.1)).norm() < 0.011)
            .count();
        assert!(near >= 2, "{near}");
    }

    #[test]
    fn a_huge_polygon_is_walked_in_a_bounded_number_of_points() {
        let big = Shape::Polygon {
            points: vec![v(-1e6, -1e6), v(1e6, -1e6), v(0.0, 1e6)],
        };
        let runs = grown(&big, 0.01, 0.001);
        let count: usize = runs.iter().map(Vec::len).sum();
        assert!((1000..=21_000).contains(&count), "{count}");
    }

    #[test]
    fn clipping_keeps_what_is_inside_the_box() {
        let (lo, hi) = (v(0.0, 0.0), v(1.0, 1.0));
        let tri = [v(0.5, 0.5), v(2.0, 0.5), v(0.5, 2.0)];
        let clipped = clip_polygon(&tri, lo, hi);
        assert!(clipped.iter().all(|p| p.x <= 1.0 && p.y <= 1.0));
        assert!((twice_area(&clipped) / 2.0 - 0.25).abs() < 1e-12);
        assert!(clip_polygon(&[v(2.0, 2.0), v(3.0, 2.0), v(3.0, 3.0)], lo, hi).is_empty());
        let line = [
            v(-1.0, 0.5),
            v(0.5, 0.5),
            v(0.5, 3.0),
            v(0.7, 3.0),
            v(0.7, 0.2),
        ];
        let parts = clip_polyline(&line, lo, hi);
        assert_eq!(
            parts,
            vec![
                vec![v(0.0, 0.5), v(0.5, 0.5), v(0.5, 1.0)],
                vec![v(0.7, 1.0), v(0.7, 0.2)]
            ]
        );
    }
}
