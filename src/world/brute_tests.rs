//! The world's geometry against brute force: the depth of a link through a polygon's vertices
//! (sampled densely, inside by the winding number), routes against a visibility graph of their
//! own, and the pairs a negative margin lists.

#![allow(clippy::unwrap_used)]

use super::geometry::{cross, segment_polygon};
use super::*;

fn v(x: f64, y: f64) -> Vec2 {
    Vec2::new(x, y)
}

/// Signed distance from `p` to a polygon, brute force (the route tests' own: each edge by its
/// line or nearer end, inside by the winding number).
fn brute_signed(p: Vec2, pts: &[Vec2]) -> f64 {
    super::route::tests::distance(p, &polygon(pts))
}

fn polygon(pts: &[Vec2]) -> Obstacle {
    Obstacle {
        id: String::new(),
        shape: Shape::Polygon {
            points: pts.to_vec(),
        },
    }
}

/// The least signed distance of `samples + 1` points evenly along the segment.
fn least_along(a: Vec2, b: Vec2, pts: &[Vec2], samples: usize) -> f64 {
    let polygon = polygon(pts);
    (0..=samples)
        .map(|k| {
            let p = a + (b - a) * (k as f64 / samples as f64);
            super::route::tests::distance(p, &polygon)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The least signed distance of the segment's points, sampled densely.
fn brute_segment(a: Vec2, b: Vec2, pts: &[Vec2]) -> f64 {
    least_along(a, b, pts, 200_000)
}

#[test]
fn a_link_through_two_vertices_of_a_diamond_is_inside() {
    // A diamond of half-diagonal 1; a long link along the x axis enters at (-1, 0) and leaves
    // at (1, 0), both vertices: it runs through the diamond's middle, 1/sqrt(2) deep.
    let diamond = [v(1.0, 0.0), v(0.0, 1.0), v(-1.0, 0.0), v(0.0, -1.0)];
    let (a, b) = (v(-50.0, 0.0), v(60.0, 0.0));
    let brute = brute_segment(a, b, &diamond);
    assert!((brute + 0.5f64.sqrt()).abs() < 1e-3, "{brute}");
    let got = segment_polygon(a, b, &diamond).distance_m;
    assert!(
        got < -0.5,
        "the link cuts the diamond: {got} (brute force {brute})"
    );
}

fn disc(id: &str, c: Vec2, r: f64) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: c,
            radius_m: r,
        },
    }
}

mod props {
    use super::*;
    use proptest::prelude::*;

    fn brute(a: Vec2, b: Vec2, pts: &[Vec2]) -> f64 {
        least_along(a, b, pts, 20_000)
    }

    /// A star-shaped polygon round the origin: radii per point, either turning sense.
    fn star(radii: &[f64], cw: bool) -> Vec<Vec2> {
        let n = radii.len();
        let mut pts: Vec<Vec2> = radii
            .iter()
            .enumerate()
            .map(|(k, r)| {
                let t = k as f64 * std::f64::consts::TAU / n as f64;
                v(t.cos() * r, t.sin() * r)
            })
            .collect();
        if cw {
            pts.reverse();
        }
        pts
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]

        #[test]
        fn segments_through_vertices_match_brute_force(
            radii in proptest::collection::vec(0.3..1.0f64, 3..9),
            cw in any::<bool>(),
            i in 0usize..8, j in 0usize..8,
            s0 in -3.0..3.0f64, s1 in -3.0..3.0f64,
            mode in 0usize..3,
            ax in -2.0..2.0f64, ay in -2.0..2.0f64,
        ) {
            let pts = star(&radii, cw);
            prop_assume!(World::new(0.0, 0.0, vec![Obstacle { id: "p".into(), shape: Shape::Polygon { points: pts.clone() } }]).is_ok());
            let n = pts.len();
            let (p, q) = (pts[i % n], pts[j % n]);
            let (a, b) = match mode {
                // Along the line through two vertices.
                0 => { prop_assume!(p != q); (p + (q - p) * s0, p + (q - p) * s1) }
                // From a free point through a vertex.
                1 => { let a = v(ax, ay); (a, a + (p - a) * (1.0 + s1.abs())) }
                // From a vertex.
                _ => (p, v(ax, ay)),
            };
            let got = segment_polygon(a, b, &pts).distance_m;
            let br = brute(a, b, &pts);
            let spacing = (b - a).norm() / 20_000.0;
            if br > spacing {
                prop_assert!((got - br).abs() <= spacing + 1e-9, "apart: {got} vs {br}");
            }
            if br < -spacing - 1e-9 {
                prop_assert!(got < 0.0, "inside: {got} vs {br}, {a:?} {b:?} {pts:?}");
            }
            prop_assert!(got >= br - spacing - 1e-9, "deeper than the truth: {got} vs {br}");
        }
    }
}

mod route_props {
    use super::*;
    use proptest::prelude::*;

    /// Distance from p to segment u..w, written apart.
    fn pseg(p: Vec2, u: Vec2, w: Vec2) -> f64 {
        let e = w - u;
        let along = (p - u).dot(&e);
        if along > 0.0 && along < e.norm_squared() {
            cross(e, p - u).abs() / e.norm()
        } else {
            (p - u).norm().min((p - w).norm())
        }
    }

    fn seg_seg(a: Vec2, b: Vec2, u: Vec2, w: Vec2) -> f64 {
        let o = |p: Vec2, q: Vec2, r: Vec2| cross(q - p, r - p).signum();
        if o(a, b, u) * o(a, b, w) < 0.0 && o(u, w, a) * o(u, w, b) < 0.0 {
            return 0.0;
        }
        pseg(a, u, w)
            .min(pseg(b, u, w))
            .min(pseg(u, a, b))
            .min(pseg(w, a, b))
    }

    fn leg_distance(a: Vec2, b: Vec2, o: &Obstacle) -> f64 {
        match &o.shape {
            Shape::Circle { center, radius_m } => pseg(*center, a, b) - radius_m,
            Shape::Polygon { points } => {
                if brute_signed(a, points) <= 0.0 {
                    return 0.0;
                }
                let n = points.len();
                (0..n)
                    .map(|k| seg_seg(a, b, points[k], points[(k + 1) % n]))
                    .fold(f64::INFINITY, f64::min)
            }
        }
    }

    /// A visibility graph of its own: 96 points round every circle and every polygon vertex
    /// at g + 2 margins, legs kept at least g from everything.
    fn competitor(w: &World, start: Vec2, goal: Vec2, g: f64, extra: f64) -> Option<f64> {
        let mut nodes = vec![start, goal];
        for o in w.obstacles() {
            let (centres, rad): (Vec<Vec2>, f64) = match &o.shape {
                Shape::Circle { center, radius_m } => (vec![*center], radius_m + g + extra),
                Shape::Polygon { points } => (points.clone(), g + extra),
            };
            for c in centres {
                for k in 0..96 {
                    let t = k as f64 * std::f64::consts::TAU / 96.0;
                    let p = c + v(t.cos(), t.sin()) * rad;
                    if w.obstacles().iter().all(|o| match &o.shape {
                        Shape::Circle { center, radius_m } => (p - center).norm() - radius_m >= g,
                        Shape::Polygon { points } => brute_signed(p, points) >= g,
                    }) {
                        nodes.push(p);
                    }
                }
            }
        }
        let m = nodes.len();
        let mut cost = vec![f64::INFINITY; m];
        let mut done = vec![false; m];
        cost[0] = 0.0;
        loop {
            let u = (0..m)
                .filter(|&i| !done[i])
                .min_by(|&i, &j| cost[i].total_cmp(&cost[j]))?;
            if cost[u].is_infinite() {
                return None;
            }
            if u == 1 {
                return Some(cost[1]);
            }
            done[u] = true;
            for x in 0..m {
                if done[x] {
                    continue;
                }
                let len = (nodes[x] - nodes[u]).norm();
                if cost[u] + len >= cost[x] {
                    continue;
                }
                if w.obstacles()
                    .iter()
                    .all(|o| leg_distance(nodes[u], nodes[x], o) >= g)
                {
                    cost[x] = cost[u] + len;
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(40))]

        #[test]
        fn routes_are_no_longer_than_another_graphs(
            shapes in proptest::collection::vec(
                (-1.0..1.0f64, -1.0..1.0f64, proptest::collection::vec(0.1..0.4f64, 3..8), any::<bool>()), 1..4),
            ay in -1.0..1.0f64, by in -1.0..1.0f64,
        ) {
            let obstacles: Vec<Obstacle> = shapes.iter().enumerate().map(|(i, (x, y, radii, cw))| {
                let n = radii.len();
                let mut points: Vec<Vec2> = radii.iter().enumerate().map(|(k, r)| {
                    let t = k as f64 * std::f64::consts::TAU / n as f64;
                    v(x + t.cos() * r, y + t.sin() * r)
                }).collect();
                if *cw { points.reverse(); }
                Obstacle { id: format!("s{i}"), shape: Shape::Polygon { points } }
            }).collect();
            let w = World::new(0.02, 0.01, obstacles).unwrap();
            let g = w.route_radius_m() + w.route_margin_m();
            let (a, b) = (v(-1.6, ay), v(1.6, by));
            let theirs = competitor(&w, a, b, g, 2.0 * w.route_margin_m());
            match w.route(a, b) {
                Ok(r) => {
                    if let Some(t) = theirs {
                        prop_assert!(r.length_m <= t + 1e-3, "route {} vs {}: {:?}", r.length_m, t, r.waypoints);
                    }
                }
                Err(e) => prop_assert!(theirs.is_none(), "{e} but a route of {theirs:?} exists"),
            }
        }
    }
}

#[test]
fn pairs_deeper_than_a_negative_margin_are_listed() {
    // A link through the middle of a disc of radius 0.1: clearance -0.1 - 0.02.
    let w = World::new(0.02, 0.0, vec![disc("post", v(0.5, 0.0), 0.1)]).unwrap();
    let pts = [v(0.0, 0.0), v(1.0, 0.0)];
    let pair = w.clearance(&pts).unwrap();
    assert!((pair.clearance_m + 0.12).abs() < 1e-12);
    let mut out = Vec::new();
    w.near_pairs(&pts, -0.05, &mut out);
    assert_eq!(
        out.len(),
        1,
        "clearance {} is at most -0.05",
        pair.clearance_m
    );
}

/// The polygon check against a scan of every pair of points and every pair of edges, in
/// order: the same verdict and the same first fault (point, edges, place of contact).
mod polygon_check {
    use super::*;
    use proptest::prelude::*;

    fn scan(points: &[Vec2]) -> Result<(), WorldError> {
        let field = "p.points".to_string();
        for (j, p) in points.iter().enumerate() {
            if let Some(first) = points[..j].iter().position(|q| q == p) {
                return Err(WorldError::RepeatedPoint {
                    field: format!("{field}[{j}]"),
                    first,
                    x: p.x,
                    y: p.y,
                });
            }
        }
        let n = points.len();
        let edge = |k: usize| (points[k], points[(k + 1) % n]);
        for a in 0..n {
            let ((a0, a1), (_, a2)) = (edge(a), edge((a + 1) % n));
            let (u, w) = (a1 - a0, a2 - a1);
            if cross(u, w) == 0.0 && u.dot(&w) < 0.0 {
                let (x, y) = (a1.x, a1.y);
                let (edge_a, edge_b) = (a, (a + 1) % n);
                return Err(WorldError::SelfIntersecting {
                    field,
                    edge_a,
                    edge_b,
                    x,
                    y,
                });
            }
            for b in a + 2..n {
                if a == 0 && b == n - 1 {
                    continue;
                }
                let (b0, b1) = edge(b);
                let (d2, p, _, _) = geometry::segment_segment(a0, a1, b0, b1);
                if d2 == 0.0 {
                    let (x, y) = (p.x, p.y);
                    return Err(WorldError::SelfIntersecting {
                        field,
                        edge_a: a,
                        edge_b: b,
                        x,
                        y,
                    });
                }
            }
        }
        Ok(())
    }

    fn checked(points: &[Vec2]) -> Result<(), WorldError> {
        super::super::check_polygon("p", points)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// Points on a coarse grid: repeats, folds, collinear overlaps and edges through
        /// vertices are common, crossings more so.
        #[test]
        fn grid_polygons_get_the_scans_verdict(
            cells in proptest::collection::vec((-3i32..=3, -3i32..=3), 3..14),
            signed_zero in any::<bool>(),
        ) {
            let pts: Vec<Vec2> = cells
                .iter()
                .map(|&(x, y)| {
                    let x = f64::from(x) * 0.5;
                    v(if signed_zero && x == 0.0 { -0.0 } else { x }, f64::from(y) * 0.25)
                })
                .collect();
            prop_assert_eq!(checked(&pts), scan(&pts));
        }

        /// Stars round the origin, some of their points then moved anywhere: mostly simple,
        /// some crossing.
        #[test]
        fn stars_get_the_scans_verdict(
            radii in proptest::collection::vec(0.2..1.0f64, 3..40),
            moved in proptest::collection::vec((0usize..40, -1.0..1.0f64, -1.0..1.0f64), 0..3),
        ) {
            let n = radii.len();
            let mut pts: Vec<Vec2> = radii
                .iter()
                .enumerate()
                .map(|(k, r)| {
                    let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
                    v(r * a.cos(), r * a.sin())
                })
                .collect();
            for (k, x, y) in moved {
                pts[k % n] = v(x, y);
            }
            prop_assert_eq!(checked(&pts), scan(&pts));
        }
    }

    #[test]
    fn the_first_fault_of_a_long_polygon_is_the_scans() {
        // A 1000-point star, then its last point pulled across the first edges.
        let n = 1000;
        let mut pts: Vec<Vec2> = (0..n)
            .map(|k| {
                let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
                let r = if k % 2 == 0 { 1.0 } else { 0.6 };
                v(r * a.cos(), r * a.sin())
            })
            .collect();
        assert_eq!(checked(&pts), Ok(()));
        pts[n - 1] = v(0.9, 0.3);
        let e = checked(&pts);
        assert!(
            matches!(e, Err(WorldError::SelfIntersecting { .. })),
            "{e:?}"
        );
        assert_eq!(e, scan(&pts));
    }
}
