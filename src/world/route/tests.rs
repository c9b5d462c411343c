//! The tip's route: straight when clear, around posts, walls and pockets, never closer to an
//! obstacle than it promises (checked densely with a distance written apart), refused inside.

#![allow(clippy::unwrap_used)]

use super::super::{Obstacle, Shape};
use super::*;
use proptest::prelude::*;

fn v(x: f64, y: f64) -> Vec2 {
    Vec2::new(x, y)
}

fn circle(id: &str, x: f64, y: f64, r: f64) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: v(x, y),
            radius_m: r,
        },
    }
}

fn polygon(id: &str, points: &[(f64, f64)]) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Polygon {
            points: points.iter().map(|&(x, y)| v(x, y)).collect(),
        },
    }
}

/// Signed distance from a point to an obstacle, written apart from the module: circles by the
/// centre, polygons by each edge's line or nearer end and a winding-number inside test.
pub(in crate::world) fn distance(p: Vec2, o: &Obstacle) -> f64 {
    match &o.shape {
        Shape::Circle { center, radius_m } => (p - center).norm() - radius_m,
        Shape::Polygon { points } => {
            let n = points.len();
            let mut best = f64::INFINITY;
            let mut winding = 0.0;
            for k in 0..n {
                let (u, w) = (points[k], points[(k + 1) % n]);
                let e = w - u;
                let along = (p - u).dot(&e);
                let d = if along > 0.0 && along < e.norm_squared() {
                    cross(e, p - u).abs() / e.norm()
                } else {
                    (p - u).norm().min((p - w).norm())
                };
                best = best.min(d);
                let (a, b) = (u - p, w - p);
                winding += cross(a, b).atan2(a.dot(&b));
            }
            if winding.abs() > PI {
                -best
            } else {
                best
            }
        }
    }
}

/// The least distance from any point of the route (legs sampled every 0.1 mm) to any obstacle.
fn route_clearance(w: &World, route: &Route) -> f64 {
    let mut least = f64::INFINITY;
    for leg in route.waypoints.windows(2) {
        let n = ((leg[1] - leg[0]).norm() / 1e-4).ceil().max(1.0) as usize;
        for k in 0..=n {
            let p = leg[0] + (leg[1] - leg[0]) * (k as f64 / n as f64);
            for o in w.obstacles() {
                least = least.min(distance(p, o));
            }
        }
    }
    least
}

/// What the route promises to keep: `g`, or less at an end already closer.
fn promised(w: &World, a: Vec2, b: Vec2) -> f64 {
    let g = w.route_radius_m() + w.route_margin_m();
    let end = |p: Vec2| {
        w.obstacles()
            .iter()
            .map(|o| distance(p, o))
            .fold(f64::INFINITY, f64::min)
    };
    g.min(end(a)).min(end(b))
}

fn length(points: &[Vec2]) -> f64 {
    points.windows(2).map(|l| (l[1] - l[0]).norm()).sum()
}

fn check(w: &World, a: Vec2, b: Vec2) -> Route {
    let route = w.route(a, b).unwrap();
    assert_eq!(route.waypoints.first(), Some(&a));
    assert_eq!(route.waypoints.last(), Some(&b));
    assert!((route.length_m - length(&route.waypoints)).abs() < 1e-9);
    let keep = promised(w, a, b);
    let got = route_clearance(w, &route);
    assert!(
        got >= keep - 1e-9,
        "route comes within {got} m, promised {keep} m"
    );
    assert!(got >= w.route_radius_m() - 1e-9);
    route
}

#[test]
fn the_margin_is_half_a_millimetre_or_a_tenth_of_the_clearance() {
    let w = World::new(0.02, 0.001, vec![]).unwrap();
    assert_eq!(w.route_margin_m(), 0.5e-3);
    assert!((w.route_radius_m() - 0.021).abs() < 1e-15);
    let w = World::new(0.02, 0.05, vec![]).unwrap();
    assert!((w.route_margin_m() - 0.005).abs() < 1e-15);
}

#[test]
fn a_clear_line_is_the_route() {
    let w = World::new(0.01, 0.01, vec![circle("post", 0.0, 1.0, 0.2)]).unwrap();
    let r = check(&w, v(-1.0, 0.0), v(1.0, 0.0));
    assert_eq!(r.waypoints, vec![v(-1.0, 0.0), v(1.0, 0.0)]);
    assert!((r.length_m - 2.0).abs() < 1e-15);
    let empty = World::new(0.0, 0.0, vec![]).unwrap();
    assert_eq!(
        empty
            .route(v(0.0, 0.0), v(1.0, 1.0))
            .unwrap()
            .waypoints
            .len(),
        2
    );
}

#[test]
fn a_post_between_is_passed_on_its_tangents() {
    let w = World::new(0.02, 0.01, vec![circle("post", 0.0, 0.0, 0.2)]).unwrap();
    let (a, b) = (v(-1.0, 0.0), v(1.0, 0.0));
    let r = check(&w, a, b);
    assert!(r.waypoints.len() > 3, "{:?}", r.waypoints);
    // The shortest path around a disc of radius rho: two tangents and the arc between.
    let rho = 0.2 + w.route_radius_m() + w.route_margin_m();
    let d: f64 = 1.0;
    let tangent = (d * d - rho * rho).sqrt();
    let arc = rho * (PI - 2.0 * (rho / d).acos());
    let exact = 2.0 * tangent + arc;
    assert!(
        r.length_m >= exact - 1e-9,
        "{} shorter than {exact}",
        r.length_m
    );
    // The circumscribed polyline adds at most the chord tolerance on the way round.
    assert!(
        r.length_m <= exact + 4.0 * w.route_margin_m(),
        "{} vs {exact}",
        r.length_m
    );
    // A simple alternative: over the top through (0, rho + margin) grown to clear.
    let over = [a, v(-rho, rho * 1.2), v(rho, rho * 1.2), b];
    assert!(r.length_m <= length(&over));
}

/// The length of the shortest way from `(0, -d)` to `(0, d)` round a disc of radius `rho` at the
/// origin: two tangents and the arc between.
fn round_a_disc(d: f64, rho: f64) -> f64 {
    2.0 * (d * d - rho * rho).sqrt() + rho * (PI - 2.0 * (rho / d).acos())
}

#[test]
fn a_tiny_polygon_on_the_way_is_routed_round_as_a_disc_of_its_size_is() {
    // A polygon of 1e-9 m sides on the straight line once made its route "closed off": the
    // sign of its area, summed about the origin, was noise, and its corners read as reflex.
    for side in [1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3] {
        for (x, y) in [(0.2, 0.1), (0.31, -0.17), (-0.547, 0.62), (123.456, -78.9)] {
            let h = side / 2.0;
            let square = [
                (x - h, y - h),
                (x + h, y - h),
                (x + h, y + h),
                (x - h, y + h),
            ];
            let mut clockwise = square;
            clockwise.reverse();
            let shapes = [
                polygon("tiny", &square),
                polygon("tiny", &clockwise),
                circle("tiny", x, y, h),
            ];
            for o in shapes {
                let w = World::new(0.01, 0.005, vec![o.clone()]).unwrap();
                let (a, b) = (v(x, y - 0.1), v(x, y + 0.1));
                let r = check(&w, a, b);
                let g = w.route_radius_m() + w.route_margin_m();
                // No shorter than round the disc of radius g, no longer than round the disc
                // that holds the grown square, with the chord tolerance on the way round.
                let (least, most) = (round_a_disc(0.1, g), round_a_disc(0.1, g + side));
                assert!(
                    r.length_m >= least - 1e-9 && r.length_m <= most + 4.0 * w.route_margin_m(),
                    "{o:?}: {} not within {least} .. {most}",
                    r.length_m
                );
            }
        }
    }
}

#[test]
fn a_wall_with_a_gap_is_crossed_through_the_gap() {
    // A wall along y = 0 from x = -2 to 2, 0.1 thick, with a 0.3 m gap at x = 0.5..0.8.
    let w = World::new(
        0.02,
        0.01,
        vec![
            polygon(
                "left",
                &[(-2.0, -0.05), (0.5, -0.05), (0.5, 0.05), (-2.0, 0.05)],
            ),
            polygon(
                "right",
                &[(0.8, -0.05), (2.0, -0.05), (2.0, 0.05), (0.8, 0.05)],
            ),
        ],
    )
    .unwrap();
    let (a, b) = (v(0.0, -0.6), v(0.0, 0.6));
    let r = check(&w, a, b);
    assert!(r.waypoints.iter().all(|p| p.x.abs() < 1.9));
    let crossing = r
        .waypoints
        .windows(2)
        .find(|l| (l[0].y < 0.0) != (l[1].y < 0.0))
        .unwrap();
    let s = -crossing[0].y / (crossing[1].y - crossing[0].y);
    let x = crossing[0].x + s * (crossing[1].x - crossing[0].x);
    assert!(x > 0.5 && x < 0.8, "crosses the wall at x = {x}");
    // No longer than going through the middle of the gap.
    assert!(r.length_m <= length(&[a, v(0.65, 0.0), b]));
    // A gap narrower than twice the grown radius is closed.
    let narrow = World::new(0.2, 0.01, w.obstacles().to_vec()).unwrap();
    let r = check(&narrow, a, b);
    assert!(
        r.waypoints.iter().any(|p| p.x.abs() > 2.0),
        "around the wall's end"
    );
}

#[test]
fn a_pocket_behind_a_shelf_is_left_by_its_mouth() {
    // A U open to the right: the start sits in the pocket, the goal behind the U's back.
    let u = polygon(
        "pocket",
        &[
            (0.0, 0.0),
            (1.0, 0.0),
            (1.0, 0.2),
            (0.2, 0.2),
            (0.2, 0.8),
            (1.0, 0.8),
            (1.0, 1.0),
            (0.0, 1.0),
        ],
    );
    let w = World::new(0.02, 0.02, vec![u]).unwrap();
    let (a, b) = (v(0.5, 0.5), v(-0.5, 0.5));
    let r = check(&w, a, b);
    // Out of the mouth (x > 1) before going round the back.
    assert!(r.waypoints.iter().any(|p| p.x > 1.0));
    // The way round above: out of the mouth, over the top corner, down the back.
    let g = w.route_radius_m() + w.route_margin_m() + 0.01;
    let above = [
        a,
        v(1.0 + g, 0.8 + g),
        v(1.0 + g, 1.0 + g),
        v(-g, 1.0 + g),
        b,
    ];
    assert!(
        r.length_m <= length(&above),
        "{} vs {}",
        r.length_m,
        length(&above)
    );
}

#[test]
fn ends_too_close_are_refused_with_the_obstacle() {
    let w = World::new(
        0.02,
        0.01,
        vec![circle("a", 5.0, 5.0, 0.1), circle("post", 0.0, 0.0, 0.2)],
    )
    .unwrap();
    let e = w.route(v(0.0, 0.1), v(1.0, 0.0)).unwrap_err();
    assert!(
        matches!(&e, RouteError::Inside { end: RouteEnd::Start, id, distance_m, .. } if id == "post" && (*distance_m + 0.1).abs() < 1e-12),
        "{e:?}"
    );
    assert!(e.to_string().contains("post"));
    // Outside the obstacle but inside its grown radius (0.03).
    let e = w.route(v(1.0, 0.0), v(0.0, 0.22)).unwrap_err();
    assert!(
        matches!(
            e,
            RouteError::Inside {
                end: RouteEnd::Goal,
                ..
            }
        ),
        "{e:?}"
    );
    // Within the margin band but outside the radius: accepted.
    let start = v(-(0.2 + 0.03 + 0.0002), 0.0);
    let r = check(&w, start, v(1.0, 0.0));
    assert!(r.waypoints.len() > 2);
    assert!(matches!(
        w.route(v(f64::NAN, 0.0), v(1.0, 0.0)),
        Err(RouteError::NotFinite {
            end: RouteEnd::Start,
            ..
        })
    ));
}

#[test]
fn an_enclosed_goal_has_no_route() {
    // A ring of posts whose grown discs overlap.
    let posts: Vec<Obstacle> = (0..12)
        .map(|k| {
            let a = k as f64 * PI / 6.0;
            circle(&format!("p{k}"), a.cos(), a.sin(), 0.25)
        })
        .collect();
    let w = World::new(0.02, 0.01, posts).unwrap();
    assert_eq!(
        w.route(v(3.0, 0.0), v(0.0, 0.0)),
        Err(RouteError::NoRoute {
            needed_m: w.route_radius_m() + w.route_margin_m()
        })
    );
    // Inside to inside is fine.
    check(&w, v(0.1, 0.1), v(-0.2, 0.0));
}

#[test]
fn a_full_world_is_routed() {
    // The most obstacles allowed: an 8 x 8 grid of posts, the route threading it diagonally.
    let posts: Vec<Obstacle> = (0..64)
        .map(|k| {
            circle(
                &format!("p{k}"),
                (k % 8) as f64 * 0.3,
                (k / 8) as f64 * 0.3,
                0.08,
            )
        })
        .collect();
    let w = World::new(0.02, 0.01, posts).unwrap();
    let r = check(&w, v(-0.3, 0.05), v(2.4, 2.0));
    assert!(r.waypoints.len() > 2);
}

#[test]
fn too_many_arc_nodes_are_coarsened() {
    let posts: Vec<Obstacle> = (0..64)
        .map(|k| {
            circle(
                &format!("p{k}"),
                (k % 8) as f64 * 0.6,
                (k / 8) as f64 * 0.6,
                0.2,
            )
        })
        .collect();
    let w = World::new(0.02, 0.01, posts).unwrap();
    // At the margin's tolerance the posts would make 64 x 34 nodes: coarsened to fit.
    let g = w.route_radius_m() + w.route_margin_m();
    assert_eq!(turn_steps(0.2 + g, w.route_margin_m()), 34);
    let nodes = w.arc_nodes(
        g,
        w.route_margin_m(),
        &mut Work {
            limit: u64::MAX,
            spent: 0,
        },
    );
    assert_eq!(nodes.len(), 64 * 24);
    check(&w, v(-0.4, 0.3), v(4.6, 4.0));
}

#[test]
fn the_most_polygon_points_are_routed() {
    // 16 round 64-gons (1024 points) in a 4 x 4 grid, the route threading it.
    let gons: Vec<Obstacle> = (0..16)
        .map(|k| {
            let c = v((k % 4) as f64 * 0.4, (k / 4) as f64 * 0.4);
            Obstacle {
                id: format!("g{k}"),
                shape: Shape::Polygon {
                    points: (0..64)
                        .map(|j| {
                            let a = j as f64 * 2.0 * PI / 64.0;
                            c + v(a.cos(), a.sin()) * 0.12
                        })
                        .collect(),
                },
            }
        })
        .collect();
    let w = World::new(0.02, 0.01, gons).unwrap();
    let r = check(&w, v(-0.3, 0.1), v(1.5, 1.1));
    assert!(r.waypoints.len() > 2);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn routes_among_random_boxes_keep_their_distance(
        boxes in proptest::collection::vec((-1.0..1.0f64, -1.0..1.0f64, 0.05..0.4f64, 0.05..0.4f64), 1..5),
        ay in -1.0..1.0f64, by in -1.0..1.0f64,
    ) {
        let obstacles: Vec<Obstacle> = boxes
            .iter()
            .enumerate()
            .map(|(i, &(x, y, hx, hy))| {
                polygon(&format!("b{i}"), &[(x - hx, y - hy), (x + hx, y - hy), (x + hx, y + hy), (x - hx, y + hy)])
            })
            .collect();
        let w = World::new(0.02, 0.01, obstacles).unwrap();
        let (a, b) = (v(-1.6, ay), v(1.6, by));
        match w.route(a, b) {
            Ok(route) => {
                let keep = promised(&w, a, b);
                let got = route_clearance(&w, &route);
                prop_assert!(got >= keep - 1e-9, "{got} < {keep}");
                prop_assert!(route.length_m >= (b - a).norm() - 1e-12);
            }
            Err(RouteError::NoRoute { .. }) => {}
            Err(e) => prop_assert!(false, "{e}"),
        }
    }

    #[test]
    fn routes_among_random_posts_keep_their_distance(
        posts in proptest::collection::vec((-1.0..1.0f64, -1.0..1.0f64, 0.05..0.25f64), 1..6),
        ay in -1.0..1.0f64, by in -1.0..1.0f64,
    ) {
        let obstacles: Vec<Obstacle> = posts
            .iter()
            .enumerate()
            .map(|(i, &(x, y, r))| circle(&format!("p{i}"), x, y, r))
            .collect();
        let w = World::new(0.02, 0.01, obstacles).unwrap();
        let (a, b) = (v(-1.6, ay), v(1.6, by));
        prop_assume!(promised(&w, a, b) >= w.route_radius_m());
        match w.route(a, b) {
            Ok(route) => {
                let keep = promised(&w, a, b);
                let got = route_clearance(&w, &route);
                prop_assert!(got >= keep - 1e-9, "{got} < {keep}");
                prop_assert!(route.length_m >= (b - a).norm() - 1e-12);
            }
            // Posts in a row can close the way only if they overlap across the whole span.
            Err(RouteError::NoRoute { .. }) => {}
            Err(e) => prop_assert!(false, "{e}"),
        }
    }
}

#[test]
fn legs_are_checked_against_the_shapes_without_radius() {
    // A thin box between the ends and nothing grown: the route still goes round it, and an
    // end on its boundary is refused.
    let w = World::new(
        0.0,
        0.0,
        vec![polygon(
            "slab",
            &[(0.0, -1.0), (0.01, -1.0), (0.01, 1.0), (0.0, 1.0)],
        )],
    )
    .unwrap();
    let r = check(&w, v(-0.5, 0.0), v(0.5, 0.0));
    assert!(r.waypoints.len() > 2);
    assert!(r.waypoints.iter().any(|p| p.y.abs() > 1.0));
    assert!(matches!(
        w.route(v(0.0, 0.5), v(0.5, 0.0)),
        Err(RouteError::Inside {
            end: RouteEnd::Start,
            ..
        })
    ));
}

#[test]
fn shape_clearance_agrees_with_the_signed_distance() {
    let shapes = [
        circle("c", 0.0, 0.0, 0.3).shape,
        polygon(
            "u",
            &[
                (0.0, 0.0),
                (1.0, 0.0),
                (1.0, 0.2),
                (0.2, 0.2),
                (0.2, 0.8),
                (1.0, 0.8),
                (1.0, 1.0),
                (0.0, 1.0),
            ],
        )
        .shape,
    ];
    let mut seen = [0usize; 2];
    for i in 0..40 {
        for j in 0..40 {
            let a = v(-1.5 + i as f64 * 0.075, -1.0 + j as f64 * 0.07);
            let b = v(1.5 - j as f64 * 0.06, 0.3 + i as f64 * 0.03);
            for shape in &shapes {
                let d = shape.segment_contact(a, b).distance_m.max(0.0);
                for floor in [0.0, 0.05, 0.2] {
                    if (d - floor).abs() > 1e-9 {
                        let clears = shape.segment_clears(a, b, floor);
                        assert_eq!(clears, d >= floor && d > 0.0, "{a:?} {b:?} {floor}: {d}");
                        seen[usize::from(clears)] += 1;
                    }
                }
            }
        }
    }
    assert!(seen[0] > 100 && seen[1] > 100, "{seen:?}");
}

/// A star of 1020 points beside the daemon's arm: the world of 0.012 m links, clearance 0.005 m
/// and the servos' rounding allowance the controller plans in.
fn star(points: usize) -> World {
    let pts: Vec<(f64, f64)> = (0..points)
        .map(|i| {
            let a = 2.0 * PI * i as f64 / points as f64;
            let r = if i % 2 == 0 { 0.1 } else { 0.06 };
            (0.45 + r * a.cos(), 0.45 + r * a.sin())
        })
        .collect();
    World::new(0.012, 0.009786, vec![polygon("star", &pts)]).unwrap()
}

/// The search is bounded: past its work it is refused, naming the limit, rather than
/// searched on; a small world's route costs a sliver of it, and legs share what is left.
#[test]
fn a_route_past_its_work_is_refused_and_legs_share_the_work() {
    let (from, to) = (v(0.3, 0.45), v(0.6, 0.45));
    let e = star(1020).route(from, to).unwrap_err();
    assert_eq!(
        e,
        RouteError::TooMuchWork {
            limit: MAX_ROUTE_WORK
        }
    );
    assert!(e.to_string().contains("segment checks"), "{e}");
    let w = star(64);
    let mut left = MAX_ROUTE_WORK;
    let r = w.route_within(from, to, &mut left).unwrap();
    assert!(r.waypoints.len() > 2);
    let spent = MAX_ROUTE_WORK - left;
    assert!(spent > 0 && spent < MAX_ROUTE_WORK / 50, "{spent}");
    // With less left than that, the same route is refused and nothing is left.
    let mut left = spent - 1;
    assert_eq!(
        w.route_within(from, to, &mut left),
        Err(RouteError::TooMuchWork { limit: spent - 1 })
    );
    assert_eq!(left, 0);
}

/// Which side of the line from `a` to `b` the route's corners lie on: +1 left, -1 right.
fn side_of(route: &Route, a: Vec2, b: Vec2) -> f64 {
    let c = route.waypoints[1..route.waypoints.len() - 1]
        .iter()
        .map(|&w| cross(b - a, w - a))
        .sum::<f64>();
    c.signum()
}

#[test]
fn a_post_on_the_straight_way_is_rounded_on_the_side_the_body_trails() {
    let (a, b) = (v(0.0, 0.0), v(0.4, 0.0));
    let world = World::new(0.01, 0.005, vec![circle("post", 0.2, 0.0, 0.03)]).unwrap();
    let shortest = world.route(a, b).unwrap();
    for (trailing, side) in [(v(-0.5, 1.0), 1.0), (v(-0.5, -1.0), -1.0)] {
        let mut left = MAX_ROUTE_WORK;
        let r = world.route_trailed(a, b, trailing, &mut left).unwrap();
        assert_eq!(side_of(&r, a, b), side, "{:?}", r.waypoints);
        assert!((r.length_m - shortest.length_m).abs() < 1e-3 * shortest.length_m);
    }
    // No preference: the shortest as it is.
    let mut left = MAX_ROUTE_WORK;
    assert_eq!(
        world.route_trailed(a, b, v(0.0, 0.0), &mut left).unwrap(),
        shortest
    );
    let mut left = MAX_ROUTE_WORK;
    assert_eq!(
        world.route_trailed(a, b, v(-1.0, 0.0), &mut left).unwrap(),
        shortest
    );
}

#[test]
fn the_body_side_is_not_taken_when_much_longer() {
    // The post 35 mm below the way: round its top is short, round its bottom 8% longer.
    let (a, b) = (v(0.0, 0.0), v(0.4, 0.0));
    let world = World::new(0.01, 0.005, vec![circle("post", 0.2, -0.035, 0.03)]).unwrap();
    let shortest = world.route(a, b).unwrap();
    assert_eq!(side_of(&shortest, a, b), 1.0);
    let mut left = MAX_ROUTE_WORK;
    let r = world.route_trailed(a, b, v(-0.5, -1.0), &mut left).unwrap();
    assert_eq!(r, shortest, "the way below is {} m", r.length_m);
    // Slightly off the way, the body's side costs little more and is taken.
    let world = World::new(0.01, 0.005, vec![circle("post", 0.2, 0.002, 0.03)]).unwrap();
    let shortest = world.route(a, b).unwrap();
    assert_eq!(side_of(&shortest, a, b), -1.0);
    let mut left = MAX_ROUTE_WORK;
    let r = world.route_trailed(a, b, v(-0.5, 1.0), &mut left).unwrap();
    assert_eq!(side_of(&r, a, b), 1.0);
    assert!(r.length_m <= shortest.length_m * (1.0 + TRAILING_SIDE_SLACK));
}
