//! Validation of worlds: each bad input refused with its field named and its numbers.

#![allow(clippy::unwrap_used)]

use super::*;

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

fn polygon(id: &str, points: Vec<Vec2>) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Polygon { points },
    }
}

fn square() -> Vec<Vec2> {
    vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)]
}

fn refused(obstacles: Vec<Obstacle>) -> WorldError {
    World::new(0.01, 0.01, obstacles).unwrap_err()
}

#[test]
fn a_good_world_is_accepted_as_given() {
    let obstacles = vec![
        circle("post", 0.3, -0.5, 0.05),
        polygon("shelf", square()),
        // Clockwise and not convex.
        polygon(
            "hook",
            vec![
                v(2.0, 0.0),
                v(2.0, 1.0),
                v(3.0, 1.0),
                v(2.5, 0.5),
                v(3.0, 0.0),
            ],
        ),
    ];
    let w = World::new(0.02, 0.005, obstacles.clone()).unwrap();
    assert_eq!(w.obstacles(), &obstacles[..]);
    assert_eq!((w.link_radius_m(), w.clearance_m()), (0.02, 0.005));
    assert_eq!(w.find("shelf").map(|(i, _)| i), Some(1));
    assert!(w.find("nothing").is_none());
    let (d, k) = w.point_distance(v(0.3, -0.4)).unwrap();
    assert_eq!(k, 0);
    assert!((d - 0.05).abs() < 1e-12);
}

#[test]
fn radii_and_clearance_must_be_finite_and_not_negative() {
    assert_eq!(
        World::new(-0.01, 0.0, vec![]),
        Err(WorldError::Negative {
            field: "link_radius_m".into(),
            value: -0.01
        })
    );
    assert_eq!(
        World::new(0.0, -1.0, vec![]),
        Err(WorldError::Negative {
            field: "clearance_m".into(),
            value: -1.0
        })
    );
    assert!(matches!(
        World::new(0.0, f64::NAN, vec![]),
        Err(WorldError::NotFinite { field, .. }) if field == "clearance_m"
    ));
    assert!(World::new(0.0, 0.0, vec![]).is_ok());
}

#[test]
fn bad_circles_name_the_field() {
    let e = refused(vec![circle("a", 0.0, 0.0, 1.0), circle("b", 0.0, 0.0, 0.0)]);
    assert_eq!(
        e,
        WorldError::NotPositive {
            field: "obstacles[1].circle.radius_m".into(),
            value: 0.0
        }
    );
    assert!(e.to_string().contains("obstacles[1].circle.radius_m"));
    let e = refused(vec![circle("a", f64::INFINITY, 0.0, 1.0)]);
    assert_eq!(
        e,
        WorldError::NotFinite {
            field: "obstacles[0].circle.center.x".into(),
            value: f64::INFINITY
        }
    );
    let e = refused(vec![circle("a", 0.0, 0.0, -2.0)]);
    assert!(matches!(e, WorldError::NotPositive { value, .. } if value == -2.0));
}

#[test]
fn bad_polygons_name_the_point_or_edges() {
    let e = refused(vec![polygon("p", vec![v(0.0, 0.0), v(1.0, 0.0)])]);
    assert_eq!(
        e,
        WorldError::TooFewPoints {
            field: "obstacles[0].polygon.points".into(),
            count: 2
        }
    );
    let mut pts = square();
    pts[2].y = f64::NAN;
    let e = refused(vec![circle("c", 5.0, 5.0, 1.0), polygon("p", pts)]);
    assert!(
        matches!(&e, WorldError::NotFinite { field, .. } if field == "obstacles[1].polygon.points[2]"),
        "{e:?}"
    );
    // A zero-length edge: the same point twice in a row.
    let mut pts = square();
    pts.insert(2, v(1.0, 0.0));
    assert_eq!(
        refused(vec![polygon("p", pts)]),
        WorldError::RepeatedPoint {
            field: "obstacles[0].polygon.points[2]".into(),
            first: 1,
            x: 1.0,
            y: 0.0
        }
    );
    // A point visited twice, apart.
    let pts = vec![
        v(0.0, 0.0),
        v(1.0, 0.0),
        v(1.0, 1.0),
        v(0.0, 0.0),
        v(-1.0, 1.0),
        v(-1.0, 0.0),
    ];
    assert!(matches!(
        refused(vec![polygon("p", pts)]),
        WorldError::RepeatedPoint { first: 0, .. }
    ));
    // A bow tie: edges 0 and 2 cross at (0.5, 0.5).
    let pts = vec![v(0.0, 0.0), v(1.0, 1.0), v(1.0, 0.0), v(0.0, 1.0)];
    let e = refused(vec![polygon("bow", pts)]);
    assert_eq!(
        e,
        WorldError::SelfIntersecting {
            field: "obstacles[0].polygon.points".into(),
            edge_a: 0,
            edge_b: 2,
            x: 0.5,
            y: 0.5
        }
    );
    // A point touching a non-adjacent edge.
    let pts = vec![
        v(0.0, 0.0),
        v(2.0, 0.0),
        v(2.0, 2.0),
        v(1.0, 0.0),
        v(0.0, 2.0),
    ];
    assert!(matches!(
        refused(vec![polygon("t", pts)]),
        WorldError::SelfIntersecting {
            edge_a: 0,
            edge_b: 2,
            ..
        }
    ));
    // A spike folding back along its own edge, and three points on a line.
    let pts = vec![v(0.0, 0.0), v(2.0, 0.0), v(1.0, 0.0), v(1.0, 1.0)];
    assert!(matches!(
        refused(vec![polygon("s", pts)]),
        WorldError::SelfIntersecting { .. }
    ));
    let pts = vec![v(0.0, 0.0), v(1.0, 0.0), v(2.0, 0.0)];
    assert!(matches!(
        refused(vec![polygon("l", pts)]),
        WorldError::SelfIntersecting { .. }
    ));
    // A triangle of 1e-165 m legs at the origin: its area underflows to none, so which way it
    // turns cannot be told. One of 1e-160 m still has an area (subnormal), and is taken.
    let speck = |s: f64| vec![v(0.0, 0.0), v(s, 0.0), v(0.0, s)];
    let e = refused(vec![
        circle("c", 5.0, 5.0, 1.0),
        polygon("dust", speck(1e-165)),
    ]);
    assert_eq!(
        e,
        WorldError::ZeroArea {
            field: "obstacles[1].polygon.points".into()
        }
    );
    assert!(
        e.to_string().starts_with("obstacles[1].polygon.points: "),
        "{e}"
    );
    assert!(World::new(0.0, 0.0, vec![polygon("speck", speck(1e-160))]).is_ok());
}

#[test]
fn ids_are_short_and_printable() {
    let long = "p".repeat(MAX_ID_CHARS + 1);
    assert_eq!(
        refused(vec![
            circle("a", 0.0, 0.0, 1.0),
            circle(&long, 3.0, 0.0, 1.0)
        ])
        .to_string(),
        "obstacles[1].id: an id of 65 characters, at most 64 allowed"
    );
    assert_eq!(
        refused(vec![circle("post\n", 0.0, 0.0, 1.0)]).to_string(),
        "obstacles[0].id: id \"post\\n\" holds the control character '\\n'"
    );
    // 64 characters, not bytes: ids in any script.
    let ok = "é".repeat(MAX_ID_CHARS);
    assert!(World::new(0.0, 0.0, vec![circle(&ok, 0.0, 0.0, 1.0)]).is_ok());
}

#[test]
fn ids_must_be_given_and_unique() {
    assert_eq!(
        refused(vec![circle("", 0.0, 0.0, 1.0)]),
        WorldError::EmptyId {
            field: "obstacles[0].id".into()
        }
    );
    assert_eq!(
        refused(vec![
            circle("a", 0.0, 0.0, 1.0),
            circle("b", 3.0, 0.0, 1.0),
            polygon("a", square())
        ]),
        WorldError::DuplicateId {
            field: "obstacles[2].id".into(),
            id: "a".into(),
            first: 0
        }
    );
}

/// One obstacle checked alone is named `obstacle`; added to a world, only its room and its id
/// are left to check, and the world is the one `World::new` makes of the whole list.
#[test]
fn an_obstacle_is_checked_alone_then_added_or_removed_as_a_world_would_be() {
    assert_eq!(
        CheckedObstacle::new(circle("a", 0.0, 0.0, -1.0)).unwrap_err(),
        WorldError::NotPositive {
            field: "obstacle.circle.radius_m".into(),
            value: -1.0
        }
    );
    assert!(matches!(
        CheckedObstacle::new(polygon("bow", vec![v(0.0, 0.0), v(1.0, 1.0), v(1.0, 0.0), v(0.0, 1.0)])),
        Err(WorldError::SelfIntersecting { field, .. }) if field == "obstacle.polygon.points"
    ));
    assert!(matches!(
        CheckedObstacle::new(circle("", 0.0, 0.0, 1.0)),
        Err(WorldError::EmptyId { field }) if field == "obstacle.id"
    ));
    let two = vec![circle("a", 0.0, 0.0, 1.0), polygon("b", square())];
    let world = World::new(0.01, 0.002, two.clone()).unwrap();
    let third = polygon("c", square().iter().map(|p| p + v(5.0, 0.0)).collect());
    let added = world
        .checked_obstacles()
        .with(&CheckedObstacle::new(third.clone()).unwrap())
        .unwrap();
    let mut three = two.clone();
    three.push(third);
    assert_eq!(
        world.with_obstacles(added.clone()),
        World::new(0.01, 0.002, three).unwrap()
    );
    assert_eq!(
        world
            .checked_obstacles()
            .with(&CheckedObstacle::new(circle("b", 9.0, 9.0, 1.0)).unwrap()),
        Err(WorldError::DuplicateId {
            field: "obstacles[2].id".into(),
            id: "b".into(),
            first: 1
        })
    );
    assert_eq!(
        world.with_obstacles(added.without(0)),
        World::new(0.01, 0.002, added[1..].to_vec()).unwrap()
    );
    assert_eq!(added.without(3), added, "no obstacle at index 3");
    // No room for one more, by count and by points.
    let full: Vec<Obstacle> = (0..MAX_OBSTACLES)
        .map(|i| circle(&format!("c{i}"), i as f64 * 3.0, 0.0, 1.0))
        .collect();
    let full = Obstacles::new(full).unwrap();
    assert_eq!(
        full.with(&CheckedObstacle::new(circle("one more", -5.0, 0.0, 1.0)).unwrap()),
        Err(WorldError::TooManyObstacles {
            count: MAX_OBSTACLES + 1,
            max: MAX_OBSTACLES
        })
    );
    let many_points: Vec<Vec2> = (0..MAX_POLYGON_POINTS)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / MAX_POLYGON_POINTS as f64;
            v(a.cos(), a.sin())
        })
        .collect();
    // An id in use is told before the lack of room.
    assert!(matches!(
        full.with(&CheckedObstacle::new(circle("c3", -5.0, 0.0, 1.0)).unwrap()),
        Err(WorldError::DuplicateId { first: 3, .. })
    ));
    let ring = Obstacles::new(vec![polygon("ring", many_points)]).unwrap();
    assert_eq!(
        ring.with(&CheckedObstacle::new(polygon("tri", square()[..3].to_vec())).unwrap()),
        Err(WorldError::TooManyPoints {
            count: MAX_POLYGON_POINTS + 3,
            max: MAX_POLYGON_POINTS
        })
    );
}

#[test]
fn the_world_is_bounded() {
    let many: Vec<Obstacle> = (0..=MAX_OBSTACLES)
        .map(|i| circle(&format!("c{i}"), i as f64 * 3.0, 0.0, 1.0))
        .collect();
    assert_eq!(
        refused(many),
        WorldError::TooManyObstacles {
            count: MAX_OBSTACLES + 1,
            max: MAX_OBSTACLES
        }
    );
    let at_most: Vec<Obstacle> = (0..MAX_OBSTACLES)
        .map(|i| circle(&format!("c{i}"), i as f64 * 3.0, 0.0, 1.0))
        .collect();
    assert!(World::new(0.0, 0.0, at_most).is_ok());
    // 1025 points in all: 41 polygons of 25 points.
    let ring = |i: usize| -> Vec<Vec2> {
        (0..25)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 25.0;
                v(i as f64 * 3.0 + a.cos(), a.sin())
            })
            .collect()
    };
    let big: Vec<Obstacle> = (0..41)
        .map(|i| polygon(&format!("p{i}"), ring(i)))
        .collect();
    assert_eq!(
        refused(big),
        WorldError::TooManyPoints {
            count: 1025,
            max: MAX_POLYGON_POINTS
        }
    );
    let fits: Vec<Obstacle> = (0..40)
        .map(|i| polygon(&format!("p{i}"), ring(i)))
        .collect();
    assert!(World::new(0.0, 0.0, fits).is_ok());
}

/// A point's place against an obstacle reads as a distance outside it, "on the edge" within what
/// four decimals show, and a depth inside: never a negative distance.
#[test]
fn where_a_point_stands_is_said_without_negative_distances() {
    use super::standing;
    assert_eq!(standing(0.0175, "post"), "0.0175 m from obstacle \"post\"");
    assert_eq!(standing(0.0, "post"), "on the edge of obstacle \"post\"");
    assert_eq!(standing(-0.0, "post"), "on the edge of obstacle \"post\"");
    assert_eq!(standing(-4e-5, "post"), "on the edge of obstacle \"post\"");
    assert_eq!(
        standing(-0.04, "post"),
        "inside obstacle \"post\", 0.0400 m deep"
    );
    use super::over_point;
    let base = "the base point";
    assert_eq!(over_point(0.002, base), "is 0.0020 m from the base point");
    assert_eq!(over_point(-0.0, base), "touches the base point");
    assert_eq!(
        over_point(-0.01, base),
        "covers the base point, 0.0100 m deep"
    );
}
