//! `[world]` and `[[world.obstacle]]`: parsing, defaults, every refusal naming the file and the
//! field as written (counted from 1), the arm checked against the world, contact detection.

use super::*;

/// `base_text` with `table` appended: a `[world]` table and its obstacles. The base arm runs
/// along +x from the origin, links of 0.1 m: at home its points are about (0, 0), (0.0995,
/// 0.0100), (0.1990, 0.0000), (0.2970, 0.0199).
fn with_world(table: &str) -> String {
    format!("{}\n{table}\n", base_text())
}

const POST_AND_SHELF: &str = r#"
[world]
link_radius_m = 0.012
clearance_m = 0.004

[[world.obstacle]]
id = "post"
circle = { center_m = [0.15, 0.2], radius_m = 0.04 }

[[world.obstacle]]
id = "shelf"
polygon = { points_m = [[-0.3, 0.1], [-0.1, 0.1], [-0.1, 0.14], [-0.3, 0.14]] }
"#;

#[test]
fn a_world_of_a_circle_and_a_polygon_loads() {
    let c = load(&with_world(POST_AND_SHELF)).unwrap();
    let w = c.world();
    assert_eq!(w.link_radius_m(), 0.012);
    assert_eq!(w.clearance_m(), 0.004);
    let ids: Vec<&str> = w.obstacles().iter().map(|o| o.id.as_str()).collect();
    assert_eq!(ids, ["post", "shelf"]);
    assert_eq!(
        w.obstacles()[0].shape,
        Shape::Circle {
            center: Vec2::new(0.15, 0.2),
            radius_m: 0.04
        }
    );
    match &w.obstacles()[1].shape {
        Shape::Polygon { points } => {
            assert_eq!(points.len(), 4);
            assert_eq!(points[2], Vec2::new(-0.1, 0.14));
        }
        other => panic!("a polygon expected, got {other:?}"),
    }
    assert!(c.contact().is_none(), "contact detection is opt-in");
}

#[test]
fn an_absent_world_is_empty_with_the_default_clearance() {
    let c = load(&base_text()).unwrap();
    assert_eq!(c.world(), &World::default());
    assert!(c.world().obstacles().is_empty());
    assert_eq!(c.world().clearance_m(), crate::world::DEFAULT_CLEARANCE_M);
    assert!(c.contact().is_none());
    // An empty [world] table: the same defaults.
    let c = load(&with_world("[world]")).unwrap();
    assert_eq!(c.world(), &World::default());
    assert_eq!(c.world().link_radius_m(), 0.0);
    assert_eq!(c.world().clearance_m(), 0.005);
}

#[test]
fn contact_takes_one_threshold_or_one_per_joint() {
    let c = load(&with_world("[world]\ncontact_load = 60")).unwrap();
    let contact = c.contact().unwrap();
    assert_eq!(contact.load, [60.0, 60.0, 60.0]);
    assert_eq!(
        contact.hold,
        Duration::from_millis(raw::DEFAULT_CONTACT_MS.into())
    );
    assert_eq!(raw::DEFAULT_CONTACT_MS, 100);
    // Joint 1 reads a Present Load (%), joints 2 and 3 a Present Current (A).
    let c = load(&with_world(
        "[world]\ncontact_load = [45.5, 1.2, 0.8]\ncontact_ms = 250",
    ))
    .unwrap();
    let contact = c.contact().unwrap();
    assert_eq!(contact.load, [45.5, 1.2, 0.8]);
    assert_eq!(contact.hold, Duration::from_millis(250));
}

#[test]
fn contact_settings_are_checked() {
    refused(
        &with_world("[world]\ncontact_load = [50.0, 1.0]"),
        &["world.contact_load", "2 entries for 3 joints"],
    );
    refused(
        &with_world("[world]\ncontact_load = [50.0, 0.0, 1.0]"),
        &[
            "world.contact_load[2]: 0 A must be above 0",
            "joint 2",
            "amperes for a Present Current",
        ],
    );
    refused(
        &with_world("[world]\ncontact_load = -5"),
        // Joint 1's servo, an XL430, reports percent.
        &[
            "world.contact_load: -5 % must be above 0 and at most 100 %",
            "joint 1",
        ],
    );
    refused(
        &with_world("[world]\ncontact_load = nan"),
        &["world.contact_load", "NaN"],
    );
    // A Present Load never reads above 100 %: joint 1's servo is an XL430.
    refused(
        &with_world("[world]\ncontact_load = [120.0, 1.0, 1.0]"),
        &[
            "world.contact_load[1]",
            "120 % must be above 0 and at most 100 %",
        ],
    );
    refused(
        &with_world("[world]\ncontact_load = 150"),
        &["world.contact_load:", "150"],
    );
    refused(
        &with_world("[world]\ncontact_ms = 200"),
        &["world.contact_load", "missing", "contact_ms is given"],
    );
    refused(
        &with_world("[world]\ncontact_load = 50\ncontact_ms = 0"),
        &["world.contact_ms", "0 must be at least 1"],
    );
    refused(
        &with_world("[world]\ncontact_load = 50\ncontact_ms = -1"),
        &["-1", "expected u32"],
    );
    refused(
        &with_world("[world]\ncontact_load = \"high\""),
        &["\"high\"", "a number (every joint) or an array"],
    );
}

#[test]
fn every_bad_obstacle_field_is_named_as_in_the_file() {
    let circle = |c: &str| with_world(&format!("[[world.obstacle]]\nid = \"o\"\ncircle = {c}"));
    let polygon = |p: &str| {
        with_world(&format!(
            "[[world.obstacle]]\nid = \"o\"\npolygon = {{ points_m = {p} }}"
        ))
    };
    refused(
        &circle("{ center_m = [0.5, 0.5], radius_m = 0.0 }"),
        &[
            "world.obstacle[1].circle.radius_m",
            "0 must be finite and positive",
        ],
    );
    refused(
        &circle("{ center_m = [0.5, 0.5], radius_m = -0.1 }"),
        &["world.obstacle[1].circle.radius_m", "-0.1"],
    );
    refused(
        &circle("{ center_m = [nan, 0.5], radius_m = 0.1 }"),
        &["world.obstacle[1].circle.center_m[1]", "NaN"],
    );
    refused(
        &circle("{ center_m = [0.5, inf], radius_m = 0.1 }"),
        &["world.obstacle[1].circle.center_m[2]", "inf"],
    );
    refused(
        &polygon("[[0.5, 0.5], [0.6, 0.5]]"),
        &[
            "world.obstacle[1].polygon.points_m:",
            "2 points",
            "at least 3",
        ],
    );
    refused(
        &polygon("[[0.5, 0.5], [0.6, 0.5], [0.6, 0.6], [0.5, 0.5]]"),
        &[
            "world.obstacle[1].polygon.points_m[4]",
            "(0.5, 0.5) repeats points_m[1]",
        ],
    );
    refused(
        &polygon("[[0.5, 0.5], [0.6, nan], [0.6, 0.6]]"),
        &["world.obstacle[1].polygon.points_m[2]", "NaN"],
    );
    // A bow tie: edge 1 (points 1 to 2) crosses edge 3 (points 3 to 4).
    refused(
        &polygon("[[0.5, 0.5], [0.7, 0.7], [0.7, 0.5], [0.5, 0.7]]"),
        &[
            "world.obstacle[1].polygon.points_m:",
            "edges 1 and 3 touch or cross near (0.6, 0.6)",
        ],
    );
    let two = |second_id: &str| {
        with_world(&format!(
            "[[world.obstacle]]\nid = \"a\"\ncircle = {{ center_m = [0.5, 0.5], radius_m = 0.1 }}\n\
             [[world.obstacle]]\nid = \"{second_id}\"\ncircle = {{ center_m = [0.9, 0.5], radius_m = 0.1 }}"
        ))
    };
    assert!(load(&two("b")).is_ok());
    refused(
        &two("a"),
        &[
            "world.obstacle[2].id",
            "\"a\" is already the id of world.obstacle[1]",
        ],
    );
    refused(&two(""), &["world.obstacle[2].id", "needs a non-empty id"]);
    refused(
        &with_world("[world]\nlink_radius_m = -0.01"),
        &["world.link_radius_m", "-0.01", "not negative"],
    );
    refused(
        &with_world("[world]\nclearance_m = nan"),
        &["world.clearance_m", "NaN"],
    );
}

#[test]
fn an_obstacle_has_exactly_one_shape() {
    refused(
        &with_world(
            "[[world.obstacle]]\nid = \"o\"\ncircle = { center_m = [0.5, 0.5], radius_m = 0.1 }\n\
             polygon = { points_m = [[0.5, 0.5], [0.6, 0.5], [0.6, 0.6]] }",
        ),
        &[
            "world.obstacle[1]:",
            "exactly one of circle and polygon (both",
        ],
    );
    refused(
        &with_world("[[world.obstacle]]\nid = \"o\""),
        &["world.obstacle[1]:", "(neither"],
    );
    // The id is required, and the shapes are tables of known keys.
    refused(
        &with_world("[[world.obstacle]]\ncircle = { center_m = [0.5, 0.5], radius_m = 0.1 }"),
        &["missing field `id`"],
    );
    refused(
        &with_world(
            "[[world.obstacle]]\nid = \"o\"\ncircle = { center_m = [0.5, 0.5, 0.1], radius_m = 0.1 }",
        ),
        &["invalid length 3", "a point [x, y]"],
    );
    refused(
        &with_world(
            "[[world.obstacle]]\nid = \"o\"\npolygon = { points_m = [[0.5, 0.5], [0.6], [0.6, 0.6]] }",
        ),
        &["invalid length 1", "a point [x, y]"],
    );
    for (table, key) in [
        ("[world]\ncontact_s = 1", "contact_s"),
        ("[[world.obstacle]]\nid = \"o\"\nsquare = 1", "square"),
        (
            "[[world.obstacle]]\nid = \"o\"\ncircle = { center = [0.5, 0.5], radius_m = 0.1 }",
            "center",
        ),
        (
            "[[world.obstacle]]\nid = \"o\"\npolygon = { points = [[0.5, 0.5]] }",
            "points",
        ),
    ] {
        let err = load(&with_world(table)).unwrap_err();
        assert!(matches!(err, ConfigError::Syntax { .. }), "{err}");
        let msg = err.to_string();
        assert!(msg.contains(key) && msg.contains("unknown field"), "{msg}");
    }
}

#[test]
fn too_many_obstacles_are_refused() {
    let mut table = String::new();
    for k in 0..=crate::world::MAX_OBSTACLES {
        table.push_str(&format!(
            "[[world.obstacle]]\nid = \"o{k}\"\ncircle = {{ center_m = [{}, 5.0], radius_m = 0.01 }}\n",
            k as f64 * 0.1
        ));
    }
    refused(
        &with_world(&table),
        &["world.obstacle:", "65 obstacles, at most 64"],
    );
}

#[test]
fn an_obstacle_at_the_base_is_refused_naming_it_and_link_one() {
    // 0.0141 m from the base point (its corner at (-0.01, -0.01)), which needs
    // link_radius_m + clearance_m = 0.017.
    let msg = refused(
        &with_world(
            "[world]\nlink_radius_m = 0.012\n\n[[world.obstacle]]\nid = \"far\"\n\
             circle = { center_m = [2.0, 2.0], radius_m = 0.1 }\n\n[[world.obstacle]]\n\
             id = \"wall\"\npolygon = { points_m = [[-0.2, -0.01], [-0.01, -0.01], [-0.01, -0.3]] }",
        ),
        &[
            "world.obstacle[2]:",
            "\"wall\"",
            "base point",
            "link 1",
            "0.017",
        ],
    );
    assert!(msg.contains("0.0141 m"), "{msg}");
    // Further than that, it is not the base that is refused.
    let text = with_world(
        "[world]\nlink_radius_m = 0.012\n\n[[world.obstacle]]\nid = \"wall\"\n\
         polygon = { points_m = [[-0.2, -0.02], [-0.02, -0.02], [-0.02, -0.3]] }",
    );
    assert!(load(&text).is_ok());
}

#[test]
fn a_home_pose_that_is_not_clear_is_refused_naming_the_link_and_the_obstacle() {
    // Link 3 runs from (0.199, 0) to (0.297, 0.0199): a post 0.05 m above the point
    // (0.25, 0.0103) on it, of radius 0.04, leaves it 0.01 m, minus the link's radius.
    let post = |link_radius_m: f64| {
        with_world(&format!(
            "[world]\nlink_radius_m = {link_radius_m}\nclearance_m = 0.005\n\n\
             [[world.obstacle]]\nid = \"post\"\ncircle = {{ center_m = [0.24, 0.06], radius_m = 0.04 }}"
        ))
    };
    let c = load(&post(0.0)).unwrap();
    let least = c.world().pose_clearance(c.chain(), c.home()).unwrap();
    assert_eq!(least.link, 3);
    assert!(
        least.clearance_m > 0.005 && least.clearance_m < 0.02,
        "{}",
        least.clearance_m
    );
    // The same post with links 0.012 m wide: not clear.
    let msg = refused(
        &post(0.012),
        &[
            "world.obstacle[1]:",
            "\"post\"",
            "link 3",
            "home pose",
            "clearance_m = 0.005",
        ],
    );
    // 0.012 m of link radius more than the clearance above takes it into the post.
    let depth = 0.012 - least.clearance_m;
    assert!(depth > 0.0, "{depth}");
    let shown = format!("inside obstacle \"post\", {depth:.4} m deep");
    assert!(msg.contains(&shown), "{shown} not in {msg}");
    // A polygon across link 1: negative clearance, still named.
    refused(
        &with_world(
            "[[world.obstacle]]\nid = \"block\"\n\
             polygon = { points_m = [[0.04, -0.05], [0.06, -0.05], [0.06, 0.05], [0.04, 0.05]] }",
        ),
        &[
            "world.obstacle[1]:",
            "\"block\"",
            "link 1",
            "inside obstacle",
            "m deep",
        ],
    );
}

/// The home pose reaches the servos in whole ticks: one clear only before rounding is refused
/// too, or `home` could never arrive there.
#[test]
fn a_home_pose_clear_only_before_rounding_to_ticks_is_refused() {
    let c = load(&base_text()).unwrap();
    let q = std::f64::consts::TAU / crate::servo::units::TICKS_PER_TURN;
    let rounded: Vec<f64> = c.home().iter().map(|t| (t / q).round() * q).collect();
    let (tip, tip_rounded) = (c.chain().tip(c.home()), c.chain().tip(&rounded));
    // A post on the side rounding moves the tip to, a quarter of that move beyond the
    // clearance from home.
    let centre = tip + (tip_rounded - tip).normalize() * 0.05;
    let beyond = 0.25 * (tip_rounded - tip).norm();
    let post = |r: f64| {
        with_world(&format!(
            "[world]\nclearance_m = 0.005\n\n[[world.obstacle]]\nid = \"post\"\n\
             circle = {{ center_m = [{:?}, {:?}], radius_m = {r:?} }}",
            centre.x, centre.y
        ))
    };
    let probe = load(&post(0.001)).unwrap();
    let least = probe.world().pose_clearance(c.chain(), c.home()).unwrap();
    let r = 0.001 + least.clearance_m - 0.005 - beyond;
    let post_at = |r: f64| {
        World::new(
            0.0,
            0.005,
            vec![Obstacle {
                id: "post".into(),
                shape: Shape::Circle {
                    center: centre,
                    radius_m: r,
                },
            }],
        )
        .unwrap()
    };
    let home = post_at(r).pose_clearance(c.chain(), c.home()).unwrap();
    assert!((home.clearance_m - 0.005 - beyond).abs() < 1e-9, "{home:?}");
    let sent = post_at(r).pose_clearance(c.chain(), &rounded).unwrap();
    assert!(sent.clearance_m < 0.005, "{sent:?}");
    refused(
        &post(r),
        &[
            "world.obstacle[1]:",
            "\"post\"",
            "home pose",
            "whole tick",
            "clearance_m = 0.005",
        ],
    );
}

#[test]
fn world_fields_map_to_the_files_names() {
    for (from, to) in [
        ("obstacles[0].id", "world.obstacle[1].id"),
        (
            "obstacles[2].circle.center.x",
            "world.obstacle[3].circle.center_m[1]",
        ),
        (
            "obstacles[2].circle.center.y",
            "world.obstacle[3].circle.center_m[2]",
        ),
        (
            "obstacles[2].circle.radius_m",
            "world.obstacle[3].circle.radius_m",
        ),
        (
            "obstacles[2].polygon.points",
            "world.obstacle[3].polygon.points_m",
        ),
        (
            "obstacles[2].polygon.points[4]",
            "world.obstacle[3].polygon.points_m[5]",
        ),
        ("obstacles", "world.obstacle"),
        ("link_radius_m", "world.link_radius_m"),
        ("clearance_m", "world.clearance_m"),
    ] {
        assert_eq!(world_field(from), to, "{from}");
    }
}

#[test]
fn a_blocked_fault_parses_and_names_a_servo_of_the_arm() {
    let c = load(&with_fault(
        "kind = \"blocked\"\nid = 2\nat_s = 0.5\nuntil_s = 2.0",
    ))
    .unwrap();
    assert_eq!(
        c.sim().unwrap().faults,
        [Fault {
            kind: FaultKind::Blocked,
            id: Some(2),
            port: None,
            from: Duration::from_millis(500),
            until: Some(Duration::from_secs(2)),
        }]
    );
    // From the start and for good when the times are left out.
    let c = load(&with_fault("kind = \"blocked\"\nid = 3")).unwrap();
    let f = &c.sim().unwrap().faults[0];
    assert_eq!((f.from, f.until), (Duration::ZERO, None));
    refused(
        &with_fault("kind = \"blocked\"\nid = 7"),
        &["sim.fault[1].id", "7 is not the id of any [[joint]]"],
    );
    refused(
        &with_fault("kind = \"blocked\""),
        &["sim.fault[1].id: missing: a kind = \"blocked\" fault needs it"],
    );
    refused(
        &with_fault("kind = \"blocked\"\nid = 1\nat_s = 2.0\nuntil_s = 1.0"),
        &["sim.fault[1].until_s"],
    );
    refused(
        &with_fault("kind = \"blocked\"\nid = 1\nfraction = 0.5"),
        &["sim.fault[1].fraction: not a key of a kind = \"blocked\" fault"],
    );
}
