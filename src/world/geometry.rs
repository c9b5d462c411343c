//! Exact distances between a segment (a link's axis) and an obstacle, unsigned and signed.
//!
//! **Unsigned** (DESIGN 4.1): circle `max(0, |c - proj(c)| - r)`; polygon 0 when an end point is
//! inside (even-odd) or the segment touches or crosses an edge, else the least segment-to-edge
//! distance. The [`Contact`] of a shape carries the **signed** distance, whose positive part is
//! the unsigned one:
//!
//! - **circle**: `|c - q| - r` with `q` the segment's point nearest the centre. Exact: inside,
//!   it is minus the depth of the segment's deepest point.
//! - **polygon**, when the segment meets it: minus the largest depth (distance to the boundary)
//!   of the segment's points sampled at `s = k / DEPTH_SAMPLES`, `k = 0..=DEPTH_SAMPLES`, and at
//!   the middle of each stretch between the places where the boundary meets it (an edge
//!   crossed, or a vertex on it), so a segment that enters the polygon at all, even between two
//!   vertices, is negative; points outside count 0. The depth of a point is
//!   1-Lipschitz, so this is never deeper than the true deepest point, shallower by at most
//!   `|b - a| / (2 DEPTH_SAMPLES)`, and exact when the deepest point is an end point (or any
//!   sample). It is continuous in the segment except where two stretches inside merge (the
//!   segment sweeping over a reflex corner), where the middles jump, never across 0. A segment
//!   that only touches the boundary gets 0.
//!
//! The contact's `normal` is the gradient of the signed distance with respect to the contact
//! point on the segment (held at its parameter `s`): the direction that moves the segment out.
//! Where `s` is the minimizer (apart, circles) or a fixed sample (`k / DEPTH_SAMPLES`), the
//! envelope argument makes it also the exact gradient with respect to any motion of the
//! segment, which is what a solver needs. At a stretch's middle, whose parameter moves with the
//! crossings, it is the direction that pushes that point out, not the exact derivative.

use crate::chain::Vec2;
pub use crate::chain::{cross, point_segment};

/// Pieces the segment is cut into to find the depth of a polygon it enters.
pub const DEPTH_SAMPLES: usize = 16;

/// The nearest approach of a segment `a..b` and an obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Signed distance, m: positive apart, negative inside (minus the depth).
    pub distance_m: f64,
    /// The segment's point that realizes it.
    pub on_segment: Vec2,
    /// The obstacle's boundary point nearest `on_segment`.
    pub on_obstacle: Vec2,
    /// Where `on_segment` sits along the segment, 0 at `a` to 1 at `b`.
    pub s: f64,
    /// Unit gradient of `distance_m` with respect to `on_segment`.
    pub normal: Vec2,
}

/// Squared distance between the segments `a0..a1` and `b0..b1`, the nearest points on each and
/// the parameter of the one on `a`. Crossing or touching segments are at 0.
pub fn segment_segment(a0: Vec2, a1: Vec2, b0: Vec2, b1: Vec2) -> (f64, Vec2, Vec2, f64) {
    if let Some(s) = crossing(a0, a1, b0, b1) {
        let p = a0 + (a1 - a0) * s;
        return (0.0, p, p, s);
    }
    let mut best = {
        let (q, _) = point_segment(a0, b0, b1);
        ((a0 - q).norm_squared(), a0, q, 0.0)
    };
    let (q, _) = point_segment(a1, b0, b1);
    let d2 = (a1 - q).norm_squared();
    if d2 < best.0 {
        best = (d2, a1, q, 1.0);
    }
    for b in [b0, b1] {
        let (q, s) = point_segment(b, a0, a1);
        let d2 = (b - q).norm_squared();
        if d2 < best.0 {
            best = (d2, q, b, s);
        }
    }
    best
}

/// Where the segment `a0..a1` properly crosses `b0..b1`, as a parameter along `a0..a1`.
///
/// An end point within round-off of the other segment's line counts as on it, not on a side:
/// on two collinear segments every side is round-off, and its signs alone would make two
/// disjoint segments cross. The end points' distances, which [`segment_segment`] takes
/// otherwise, see a touch as one.
fn crossing(a0: Vec2, a1: Vec2, b0: Vec2, b1: Vec2) -> Option<f64> {
    let (da, db) = (a1 - a0, b1 - b0);
    let (s0, s1) = (cross(db, a0 - b0), cross(db, a1 - b0));
    let (t0, t1) = (cross(da, b0 - a0), cross(da, b1 - a0));
    let off_s = SIDE_ROUND_OFF * db.norm() * ((a0 - b0).norm() + (a1 - b0).norm());
    let off_t = SIDE_ROUND_OFF * da.norm() * ((b0 - a0).norm() + (b1 - a0).norm());
    let apart = |x: f64, y: f64, off: f64| x.abs() > off && y.abs() > off && (x < 0.0) != (y < 0.0);
    (apart(s0, s1, off_s) && apart(t0, t1, off_t)).then(|| s0 / (s0 - s1))
}

/// The round-off of a cross product `cross(u, v)`, relative to `|u| |v|`.
const SIDE_ROUND_OFF: f64 = 16.0 * f64::EPSILON;

/// Whether `p` is inside the polygon by the even-odd rule (boundary points either way).
pub fn inside_polygon(p: Vec2, points: &[Vec2]) -> bool {
    let n = points.len();
    let mut inside = false;
    for k in 0..n {
        let (u, v) = (points[k], points[(k + 1) % n]);
        if (u.y > p.y) != (v.y > p.y) {
            let x = u.x + (p.y - u.y) * (v.x - u.x) / (v.y - u.y);
            if p.x < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// Distance from `p` to the polygon's boundary, the nearest boundary point and its edge.
pub fn boundary_nearest(p: Vec2, points: &[Vec2]) -> (f64, Vec2, usize) {
    let n = points.len();
    let mut best = (f64::INFINITY, p, 0);
    for k in 0..n {
        let (q, _) = point_segment(p, points[k], points[(k + 1) % n]);
        let d2 = (p - q).norm_squared();
        if d2 < best.0 {
            best = (d2, q, k);
        }
    }
    (best.0.sqrt(), best.1, best.2)
}

/// Signed distance from `p` to the polygon: negative inside.
pub fn point_polygon(p: Vec2, points: &[Vec2]) -> f64 {
    let (d, _, _) = boundary_nearest(p, points);
    if inside_polygon(p, points) {
        -d
    } else {
        d
    }
}

/// Twice the polygon's signed area: positive when its points turn counter-clockwise.
///
/// Summed about the first point, not the origin, so that the round-off scales with the
/// polygon's size rather than with its distance from the origin: about the origin, the terms
/// of a square of 1e-9 m sides 0.5 m away are 1e9 times its area, and their sum's sign is
/// noise (which turned the polygon inside out for whatever asks which way it turns).
pub fn twice_area(points: &[Vec2]) -> f64 {
    let Some(&o) = points.first() else {
        return 0.0;
    };
    points.windows(2).map(|w| cross(w[0] - o, w[1] - o)).sum()
}

/// The unit normal of edge `k` pointing out of the polygon.
fn outward_normal(points: &[Vec2], k: usize) -> Vec2 {
    let e = points[(k + 1) % points.len()] - points[k];
    let right = Vec2::new(e.y, -e.x);
    let n = if twice_area(points) > 0.0 {
        right
    } else {
        -right
    };
    n.try_normalize(0.0).unwrap_or(Vec2::x())
}

/// Signed distance from the segment `a..b` to the circle (`center`, `radius`), exact.
pub fn segment_circle(a: Vec2, b: Vec2, center: Vec2, radius: f64) -> Contact {
    let (q, s) = point_segment(center, a, b);
    let v = q - center;
    let d = v.norm();
    let normal = if d > 0.0 {
        v / d
    } else {
        // The centre lies on the segment: out sideways.
        let ab = b - a;
        Vec2::new(-ab.y, ab.x)
            .try_normalize(0.0)
            .unwrap_or(Vec2::x())
    };
    Contact {
        distance_m: d - radius,
        on_segment: q,
        on_obstacle: center + normal * radius,
        s,
        normal,
    }
}

/// Relative rounding allowed for a squared distance against the gap between two boxes.
const BOX_ROUND_OFF: f64 = 1e-9;
/// Boxes this far apart, relative to the coordinates' magnitude, are apart whatever the
/// rounding of the tests that would otherwise say so.
const BOX_APART: f64 = 1e-12;

/// The squared gap between the boxes `alo..ahi` and `blo..bhi` (0 when they overlap).
fn box_gap2(alo: Vec2, ahi: Vec2, blo: Vec2, bhi: Vec2) -> f64 {
    let gx = (blo.x - ahi.x).max(alo.x - bhi.x).max(0.0);
    let gy = (blo.y - ahi.y).max(alo.y - bhi.y).max(0.0);
    gx * gx + gy * gy
}

/// Signed distance from the segment `a..b` to the polygon (see the module doc for the depth).
pub fn segment_polygon(a: Vec2, b: Vec2, points: &[Vec2]) -> Contact {
    let n = points.len();
    let (slo, shi) = (a.inf(&b), a.sup(&b));
    let mut best = (f64::INFINITY, a, a, 0.0, 0);
    let (mut plo, mut phi) = (points[0], points[0]);
    for k in 0..n {
        let (u, w) = (points[k], points[(k + 1) % n]);
        let (elo, ehi) = (u.inf(&w), u.sup(&w));
        (plo, phi) = (plo.inf(&elo), phi.sup(&ehi));
        // The gap between the boxes bounds the distance from below: an edge whose box is
        // farther than the nearest so far (by more than rounding) cannot be nearer.
        if box_gap2(slo, shi, elo, ehi) > best.0 * (1.0 + BOX_ROUND_OFF) {
            continue;
        }
        let (d2, pa, pb, s) = segment_segment(a, b, u, w);
        if d2 < best.0 {
            best = (d2, pa, pb, s, k);
        }
    }
    let (d2, pa, pb, s, edge) = best;
    // Where the boundary meets the segment: proper crossings, and vertices on it (which no
    // proper crossing sees, and rounding may leave a hair off it, so `d2` may not be 0).
    let ab = b - a;
    let l2 = ab.norm_squared();
    let meet = |k: usize| -> Option<f64> {
        let (u, w) = (points[k], points[(k + 1) % n]);
        let (su, sw) = (cross(ab, u - a), cross(ab, w - a));
        let x = if su == 0.0 {
            u
        } else if sw != 0.0 && (su < 0.0) != (sw < 0.0) {
            u + (w - u) * (su / (su - sw))
        } else {
            return None;
        };
        let t = (x - a).dot(&ab) / l2;
        (t > 0.0 && t < 1.0).then_some(t)
    };
    let outside = || {
        let d = d2.sqrt();
        Contact {
            distance_m: d,
            on_segment: pa,
            on_obstacle: pb,
            s,
            normal: (pa - pb) / d,
        }
    };
    // A segment whose box lies clear of the polygon's (by more than rounding) is outside it
    // and meets no edge: the passes below would find the same.
    let scale = 1.0
        + slo
            .abs()
            .max()
            .max(shi.abs().max())
            .max(plo.abs().max())
            .max(phi.abs().max());
    if d2 > 0.0 && box_gap2(slo, shi, plo, phi).sqrt() > BOX_APART * scale {
        return outside();
    }
    let apart = d2 > 0.0 && !inside_polygon(a, points) && !inside_polygon(b, points);
    if apart && (0..n).all(|k| meet(k).is_none()) {
        return outside();
    }
    let mut deep = (0.0, a, a, 0.0);
    let mut consider = |t: f64| {
        let x = a + (b - a) * t;
        if inside_polygon(x, points) {
            let (d, q, _) = boundary_nearest(x, points);
            if d > deep.0 {
                deep = (d, x, q, t);
            }
        }
    };
    for k in 0..=DEPTH_SAMPLES {
        consider(k as f64 / DEPTH_SAMPLES as f64);
    }
    // The middle of each stretch between two places where the boundary meets the segment
    // (or an end): each is wholly inside or wholly outside.
    for t in std::iter::once(0.0).chain((0..n).filter_map(meet)) {
        let next = (0..n)
            .filter_map(meet)
            .filter(|&u| u > t)
            .fold(1.0, f64::min);
        consider(0.5 * (t + next));
    }
    let (depth, x, q, t) = deep;
    if depth <= 0.0 && apart {
        // It only grazes vertices from outside.
        return outside();
    }
    if depth > 0.0 {
        Contact {
            distance_m: -depth,
            on_segment: x,
            on_obstacle: q,
            s: t,
            normal: (q - x) / depth,
        }
    } else {
        Contact {
            distance_m: 0.0,
            on_segment: pa,
            on_obstacle: pb,
            s,
            normal: outward_normal(points, edge),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn collinear_segments_apart_are_apart() {
        // A segment on the line of a triangle's edge, beyond its vertex: the sides of its end
        // points are round-off, and once made it cross the edge (distance 0, not 0.105).
        let pts = [
            Vec2::new(-0.4620621495420264, -0.8003151192612773),
            Vec2::new(-0.26795772610624985, 0.4641163958966503),
            Vec2::new(0.3, 0.0),
        ];
        let (p, q) = (pts[0], pts[1]);
        let a = p + (q - p) * -0.08230470735384633;
        let b = p + (q - p) * -1.278993834039326;
        let want = (a - p).norm();
        let got = segment_polygon(a, b, &pts).distance_m;
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        let (d2, ..) = segment_segment(a, b, p, q);
        assert!((d2.sqrt() - want).abs() < 1e-12);
        // Collinear and overlapping: touching.
        let (d2, ..) = segment_segment(p + (q - p) * -0.5, p + (q - p) * 0.5, p, q);
        assert!(d2 < 1e-24, "{d2}");
        // Crossing at a small angle still crosses.
        let (d2, ..) = segment_segment(
            Vec2::new(0.0, -1e-6),
            Vec2::new(1.0, 1e-6),
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
        );
        assert_eq!(d2, 0.0);
    }

    /// Brute force, independent of the code above: the segment sampled densely, each sample's
    /// signed distance to the shape from its own point test and boundary distance.
    fn brute_min(a: Vec2, b: Vec2, f: impl Fn(Vec2) -> f64) -> f64 {
        let n = 5_000;
        (0..=n)
            .map(|k| f(a + (b - a) * (k as f64 / n as f64)))
            .fold(f64::INFINITY, f64::min)
    }

    /// Distance from a point to the boundary of a polygon: each edge by its line when the
    /// foot falls on it, else by its nearer end (written apart from `point_segment`).
    fn brute_boundary(p: Vec2, pts: &[Vec2]) -> f64 {
        let n = pts.len();
        let mut best = f64::INFINITY;
        for k in 0..n {
            let (u, w) = (pts[k], pts[(k + 1) % n]);
            let e = w - u;
            let along = (p - u).dot(&e);
            let d = if along > 0.0 && along < e.norm_squared() {
                cross(e, p - u).abs() / e.norm()
            } else {
                (p - u).norm().min((p - w).norm())
            };
            best = best.min(d);
        }
        best
    }

    /// Point in polygon by winding number (another rule than the crossing count; equal for a
    /// simple polygon).
    fn winding_inside(p: Vec2, pts: &[Vec2]) -> bool {
        let n = pts.len();
        let mut total = 0.0;
        for k in 0..n {
            let (u, v) = (pts[k] - p, pts[(k + 1) % n] - p);
            total += cross(u, v).atan2(u.dot(&v));
        }
        total.abs() > std::f64::consts::PI
    }

    fn brute_polygon_signed(p: Vec2, pts: &[Vec2]) -> f64 {
        let d = brute_boundary(p, pts);
        if winding_inside(p, pts) {
            -d
        } else {
            d
        }
    }

    fn v(x: f64, y: f64) -> Vec2 {
        Vec2::new(x, y)
    }

    /// A non-convex "C": a square with a notch.
    fn notched() -> Vec<Vec2> {
        vec![
            v(0.0, 0.0),
            v(2.0, 0.0),
            v(2.0, 0.8),
            v(1.0, 0.8),
            v(1.0, 1.2),
            v(2.0, 1.2),
            v(2.0, 2.0),
            v(0.0, 2.0),
        ]
    }

    #[test]
    fn circle_outside_and_inside_hand_computed() {
        let c = segment_circle(v(-1.0, 2.0), v(1.0, 2.0), v(0.0, 0.0), 0.5);
        assert!((c.distance_m - 1.5).abs() < 1e-15);
        assert!((c.on_segment - v(0.0, 2.0)).norm() < 1e-15);
        assert!((c.on_obstacle - v(0.0, 0.5)).norm() < 1e-15);
        assert!((c.normal - v(0.0, 1.0)).norm() < 1e-15);
        // Through the circle 0.2 from the centre: the deepest point is 0.3 deep.
        let c = segment_circle(v(-1.0, 0.2), v(1.0, 0.2), v(0.0, 0.0), 0.5);
        assert!((c.distance_m + 0.3).abs() < 1e-15);
        // The centre on the segment: the full radius deep, pushed sideways.
        let c = segment_circle(v(-1.0, 0.0), v(1.0, 0.0), v(0.0, 0.0), 0.5);
        assert!((c.distance_m + 0.5).abs() < 1e-15);
        assert!(c.normal.x.abs() < 1e-15 && (c.normal.norm() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn polygon_cases_hand_computed() {
        let sq = [v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)];
        // Above, parallel: 0.5 away.
        let c = segment_polygon(v(-1.0, 1.5), v(2.0, 1.5), &sq);
        assert!((c.distance_m - 0.5).abs() < 1e-15);
        assert!((c.normal - v(0.0, 1.0)).norm() < 1e-15);
        // Corner to corner: a vertex against the segment's interior.
        let c = segment_polygon(v(2.0, 1.0), v(1.0, 2.0), &sq);
        assert!((c.distance_m - 0.5f64.sqrt()).abs() < 1e-15);
        assert!((c.on_obstacle - v(1.0, 1.0)).norm() < 1e-15);
        // Through the middle: the deepest point is the centre, 0.5 deep (a sample).
        let c = segment_polygon(v(-1.0, 0.5), v(2.0, 0.5), &sq);
        assert!(c.distance_m < 0.0 && (c.distance_m + 0.5).abs() <= 3.0 / 32.0);
        // Wholly inside, deepest at an end: exact there, pushed out through the nearest edge.
        let c = segment_polygon(v(0.3, 0.4), v(0.35, 0.45), &sq);
        assert!((c.distance_m + 0.35).abs() < 1e-12, "{}", c.distance_m);
        assert_eq!(c.s, 1.0);
        assert!((c.normal - v(-1.0, 0.0)).norm() < 1e-12, "{:?}", c.normal);
        // Ending on an edge: touching, 0.
        let c = segment_polygon(v(-1.0, 0.5), v(0.0, 0.5), &sq);
        assert_eq!(c.distance_m, 0.0);
        assert!((c.normal - v(-1.0, 0.0)).norm() < 1e-15, "{:?}", c.normal);
        // Into the notch of the C without touching it.
        let c = segment_polygon(v(3.0, 1.0), v(1.1, 1.0), &notched());
        assert!((c.distance_m - 0.1).abs() < 1e-12);
    }

    #[test]
    fn a_long_link_cutting_a_corner_between_samples_is_inside() {
        let sq = [v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)];
        // Along x + y = 1.98: inside only for 0.98 < x < 1, which no fixed sample hits.
        let (a, b) = (v(9.3, -7.32), v(-6.72, 8.7));
        let c = segment_polygon(a, b, &sq);
        assert!((c.distance_m + 0.01).abs() < 1e-12, "{}", c.distance_m);
        assert!((c.on_segment - v(0.99, 0.99)).norm() < 1e-12);
        // Pushed out along its normal, the segment comes out.
        let out = c.normal * 0.03;
        assert!(segment_polygon(a + out, b + out, &sq).distance_m > 0.0);
    }

    #[test]
    fn clockwise_polygons_push_out_too() {
        let cw = [v(0.0, 0.0), v(0.0, 1.0), v(1.0, 1.0), v(1.0, 0.0)];
        let c = segment_polygon(v(-1.0, 0.5), v(0.0, 0.5), &cw);
        assert_eq!(c.distance_m, 0.0);
        assert!((c.normal - v(-1.0, 0.0)).norm() < 1e-15);
    }

    /// A square of side `side` centred on `c`, counter-clockwise (or clockwise, reversed).
    fn tiny_square(c: Vec2, side: f64, ccw: bool) -> Vec<Vec2> {
        let h = side / 2.0;
        let mut sq = vec![c + v(-h, -h), c + v(h, -h), c + v(h, h), c + v(-h, h)];
        if !ccw {
            sq.reverse();
        }
        sq
    }

    /// Places a tiny obstacle is put, near the arm and far out (where a 1e-9 m side spans a
    /// few hundred units of the last place).
    const TINY_PLACES: [(f64, f64); 5] = [
        (0.2, 0.1),
        (0.31, -0.17),
        (-0.547, 0.62),
        (0.7, -0.71),
        (123.456, -78.9),
    ];

    #[test]
    fn a_tiny_polygon_turns_its_own_way_and_pushes_out() {
        // About the origin the terms of the area of a square of 1e-9 m sides 0.2 m away are
        // 1e9 times its area: their sum's sign was noise, and a segment touching the square
        // was pushed in.
        for side in [1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3] {
            for (x, y) in TINY_PLACES {
                let c = v(x, y);
                for ccw in [true, false] {
                    let sq = tiny_square(c, side, ccw);
                    let a = twice_area(&sq);
                    // Far out the points themselves round by up to 1e-5 of the side.
                    let want = if ccw { 2.0 } else { -2.0 } * side * side;
                    assert!(
                        (a - want).abs() < 1e-3 * side * side,
                        "side {side} at {c:?}: {a} against {want}"
                    );
                    // Ending on the top edge's middle, from above: touching, pushed up.
                    let top = c + v(0.0, side / 2.0);
                    let t = segment_polygon(top + v(0.0, 0.05), top, &sq);
                    assert_eq!(t.distance_m, 0.0, "side {side} at {c:?}");
                    assert!(
                        (t.normal - v(0.0, 1.0)).norm() < 1e-9,
                        "side {side} at {c:?} ccw {ccw}: {:?}",
                        t.normal
                    );
                }
            }
        }
    }

    fn arb_point() -> impl Strategy<Value = Vec2> {
        (-3.0..3.0f64, -3.0..3.0f64).prop_map(|(x, y)| v(x, y))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn circle_matches_brute_force(a in arb_point(), b in arb_point(), c in arb_point(),
                                      r in 0.05..1.5f64) {
            let got = segment_circle(a, b, c, r);
            let brute = brute_min(a, b, |p| (p - c).norm() - r);
            // Dense sampling: within a sample spacing (at most 6e-4 m here).
            prop_assert!((got.distance_m - brute).abs() < 1e-3, "{} vs {}", got.distance_m, brute);
            prop_assert!(got.distance_m <= brute + 1e-12);
            prop_assert!(((got.on_segment - c).norm() - r - got.distance_m).abs() < 1e-12);
        }

        #[test]
        fn polygon_unsigned_and_signed_match_brute_force(a in arb_point(), b in arb_point(),
                                                         dx in -1.0..1.0f64, dy in -1.0..1.0f64) {
            let pts: Vec<Vec2> = notched().iter().map(|p| p + v(dx - 1.0, dy - 1.0)).collect();
            let got = segment_polygon(a, b, &pts);
            let brute = brute_min(a, b, |p| brute_polygon_signed(p, &pts));
            if brute > 1e-3 {
                // Apart: the exact distance.
                prop_assert!((got.distance_m - brute).abs() < 2e-3, "{} vs {}", got.distance_m, brute);
                prop_assert!(((got.on_segment - got.on_obstacle).norm() - got.distance_m).abs() < 1e-12);
            } else if brute < -1e-3 {
                // Inside: never deeper than the truth, and within the sampling bound.
                let bound = (b - a).norm() / (2.0 * DEPTH_SAMPLES as f64) + 2e-3;
                prop_assert!(got.distance_m >= brute - 2e-3, "{} vs {}", got.distance_m, brute);
                prop_assert!(got.distance_m <= brute + bound, "{} vs {}", got.distance_m, brute);
                prop_assert!(got.distance_m <= 0.0);
            }
            // Unsigned: zero exactly when the brute force says the segment meets it.
            if brute < -1e-3 {
                prop_assert!(got.distance_m <= 0.0);
            }
        }

        #[test]
        fn signed_polygon_distance_is_continuous(a in arb_point(), b in arb_point(),
                                                 d in arb_point()) {
            let pts = notched();
            let step = d * 1e-7;
            let c0 = segment_polygon(a, b, &pts);
            let c1 = segment_polygon(a + step, b + step, &pts);
            let (g0, g1) = (c0.distance_m, c1.distance_m);
            let fixed = |c: &Contact| {
                let k = c.s * DEPTH_SAMPLES as f64;
                c.distance_m >= 0.0 || k == k.round()
            };
            if fixed(&c0) && fixed(&c1) {
                // Apart or at fixed samples: 1-Lipschitz under translation.
                prop_assert!((g0 - g1).abs() <= step.norm() * (1.0 + 1e-6) + 1e-12, "{g0} {g1}");
            } else {
                // A stretch's middle moves with the crossings, faster where they are shallow.
                prop_assert!((g0 - g1).abs() <= 1e-4, "{g0} {g1}");
            }
        }

        #[test]
        fn crossing_count_agrees_with_winding(p in arb_point()) {
            let pts = notched();
            prop_assume!(brute_boundary(p, &pts) > 1e-6);
            prop_assert_eq!(inside_polygon(p, &pts), winding_inside(p, &pts));
        }
    }
}
