//! `snakectl::reach` from outside: ways found are clear (checked here on their own, with the
//! tests' own distance, by samples finer than a millimetre of the arm's motion, not by the
//! planner's bound), end with the tip on the target, keep the limits, and come out the same for
//! the same request; bad requests are refused in words.

use std::f64::consts::TAU;

use rand::{Rng, SeedableRng};

use snakectl::chain::{Chain, Vec2};
use snakectl::reach::{plan, ReachError, ReachOptions, ReachRequest, Way};
use snakectl::world::{Obstacle, Shape, World};

use crate::world_support::{self, arm as chain, caught_moves as cases, home};

const N: usize = 12;

fn disc(id: &str, x: f64, y: f64, r: f64) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: Vec2::new(x, y),
            radius_m: r,
        },
    }
}

/// [`plan`] with the default options.
fn ask(
    c: &Chain,
    world: &World,
    from: &[f64],
    target: Vec2,
    quanta: &[f64],
) -> Result<Way, ReachError> {
    let req = ReachRequest {
        chain: c,
        world,
        from,
        target,
        quanta,
    };
    plan(&req, &ReachOptions::default())
}

/// The least clearance along the straight leg from `a` to `b`, sampled every 0.2 mm of the
/// arm's motion, and whether every sample keeps the limits and its links apart.
fn along(c: &Chain, w: &World, a: &[f64], b: &[f64]) -> (f64, bool) {
    let steps = ((c.sweep(a, b) / 2e-4).ceil() as usize).max(1);
    let (mut least, mut fine) = (f64::INFINITY, true);
    for k in 0..=steps {
        let f = k as f64 / steps as f64;
        let p: Vec<f64> = a.iter().zip(b).map(|(x, y)| x + f * (y - x)).collect();
        least = least.min(world_support::clearance(c, w, &p));
        fine &= c.check_limits(&p).is_ok() && Chain::self_intersects(&c.points(&p)).is_none();
    }
    (least, fine)
}

/// The way from home to `target`, checked ([`assert_way_is_clear`]); `None` when no clear pose
/// has the tip there, which is said so. Any other refusal fails the test.
fn planned_from_home(c: &Chain, world: &World, target: Vec2, quanta: &[f64]) -> Option<Way> {
    match ask(c, world, &home(), target, quanta) {
        Ok(way) => {
            assert_way_is_clear(c, world, &home(), target, quanta, &way);
            Some(way)
        }
        Err(ReachError::NoClearPose { .. }) => None,
        Err(e) => panic!("{target:?}: {e}"),
    }
}

/// Checks a way found from `from` to `target`: every leg clear by the tests' own sampling,
/// within the limits and untangled; the tip on the target; the goal clear as sent.
fn assert_way_is_clear(
    c: &Chain,
    world: &World,
    from: &[f64],
    target: Vec2,
    quanta: &[f64],
    way: &Way,
) {
    let mut at = from.to_vec();
    for leg in &way.legs {
        let (least, fine) = along(c, world, &at, leg);
        assert!(
            least >= world.clearance_m(),
            "{target:?}: a leg at {least} m"
        );
        assert!(
            fine,
            "{target:?}: a leg leaves the limits or touches itself"
        );
        at.clone_from(leg);
    }
    let goal = way.legs.last().unwrap();
    assert!((c.tip(goal) - target).norm() < 1e-9, "{target:?}");
    // Rounded to whole ticks, as the servos take it, the goal is clear too.
    let sent: Vec<f64> = goal
        .iter()
        .zip(quanta)
        .map(|(t, q)| (t / q).round() * q)
        .collect();
    assert!(world_support::clearance(c, world, &sent) >= world.clearance_m());
}

#[test]
fn ways_round_the_obstacles_are_clear_and_end_on_the_target() {
    let c = chain();
    let quanta = [TAU / 4096.0; N];
    let (mut planned, mut searched) = (0, 0);
    for (world, target) in cases(24) {
        // A target no clear pose reaches is said so; nothing else may fail.
        if let Some(way) = planned_from_home(&c, &world, target, &quanta) {
            planned += 1;
            searched += usize::from(way.nodes > 0);
        }
    }
    // Most of these moves have a pose to reach, and some need the trees (no straight leg).
    assert!(
        planned >= 20 && searched >= 3,
        "{planned} planned, {searched} searched"
    );
}

/// A shelf left of the arm, below the tip, with a lip hanging from its far end (an L: a
/// polygon that is not convex), and a target under it: the arm goes round the shelf's near end
/// and in beneath it, the straight way from home passing through it.
#[test]
fn a_way_under_a_shelf_that_is_not_convex_is_clear() {
    let c = chain();
    let quanta = [TAU / 4096.0; N];
    let tip = c.tip(&home());
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    let (mut planned, mut searched) = (0, 0);
    for _ in 0..8 {
        // The shelf's near end, clear of the home pose's arc.
        let (x, top) = (
            tip.x + rng.gen_range(0.08..0.12),
            tip.y - rng.gen_range(0.22..0.28),
        );
        let (long, lip) = (rng.gen_range(0.25..0.32), rng.gen_range(0.06..0.1));
        let v = |dx: f64, dy: f64| Vec2::new(x + dx, top + dy);
        let shelf = Obstacle {
            id: "shelf".into(),
            shape: Shape::Polygon {
                points: vec![
                    v(0.0, 0.0),
                    v(-long, 0.0),
                    v(-long, -lip),
                    v(-long + 0.03, -lip),
                    v(-long + 0.03, -0.03),
                    v(0.0, -0.03),
                ],
            },
        };
        let world = World::new(0.01, 0.005, vec![shelf]).unwrap();
        let target = v(-0.5 * long, -0.1);
        if let Some(way) = planned_from_home(&c, &world, target, &quanta) {
            planned += 1;
            searched += usize::from(way.nodes > 0);
        }
    }
    assert!(
        planned >= 6 && searched >= 6,
        "{planned} of 8 planned, {searched} of them by the trees"
    );
}

/// A target on the edge of the reach (the arm straight) with an obstacle far off: reached,
/// as a `goto` reaches it.
#[test]
fn a_target_on_the_edge_of_the_reach_is_reached() {
    let c = chain();
    let world = World::new(0.01, 0.005, vec![disc("far", 0.5, 0.2, 0.03)]).unwrap();
    let target = Vec2::new(0.0, c.reach());
    let quanta = [TAU / 4096.0; N];
    let way = ask(&c, &world, &home(), target, &quanta).unwrap();
    assert_way_is_clear(&c, &world, &home(), target, &quanta, &way);
}

#[test]
fn the_same_request_gives_the_same_way() {
    let c = chain();
    let (world, target) = cases(3).pop().unwrap();
    let from = home();
    let a = ask(&c, &world, &from, target, &[]).unwrap();
    let b = ask(&c, &world, &from, target, &[]).unwrap();
    assert_eq!(a, b);
}

#[test]
fn a_way_that_needs_more_work_than_allowed_says_how_much_was_done() {
    let c = chain();
    let from = home();
    // The first case whose straight leg is not clear, with a single random pose allowed.
    for (world, target) in cases(24) {
        let req = ReachRequest {
            chain: &c,
            world: &world,
            from: &from,
            target,
            quanta: &[],
        };
        let Ok(way) = plan(&req, &ReachOptions::default()) else {
            continue;
        };
        if way.nodes == 0 {
            continue;
        }
        let tight = ReachOptions {
            max_samples: 1,
            ..ReachOptions::default()
        };
        let err = plan(&req, &tight).unwrap_err();
        assert!(
            matches!(err, ReachError::NoWay { samples: 1, .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("1 random poses drawn"), "{err}");
        return;
    }
    panic!("no case needed the trees");
}

#[test]
fn bad_requests_are_refused_in_words() {
    let c = chain();
    let tip = c.tip(&home());
    let world = World::new(
        0.01,
        0.005,
        vec![disc("post", tip.x - 0.1, tip.y - 0.2, 0.03)],
    )
    .unwrap();
    let refused = |from: &[f64], target: Vec2, quanta: &[f64]| {
        ask(&c, &world, from, target, quanta)
            .unwrap_err()
            .to_string()
    };
    let below = tip - Vec2::new(0.0, 0.2);
    let said = refused(&[0.1; 3], below, &[]);
    assert!(said.contains("3 angles for 12 joints"), "{said}");
    let said = refused(&home(), Vec2::new(f64::NAN, 0.0), &[]);
    assert!(said.contains("not a finite point"), "{said}");
    let said = refused(&home(), below, &[0.1; 2]);
    assert!(said.contains("2 joint resolutions for 12 joints"), "{said}");
    let mut out = home();
    out[3] = 2.5;
    let said = refused(&out, below, &[]);
    assert!(said.contains("the arm's pose"), "{said}");
    // Beyond the arm's reach (0.96 m): refused up front, with the numbers.
    let err = ask(&c, &world, &home(), Vec2::new(1.2, 0.5), &[]).unwrap_err();
    let ReachError::OutOfReach {
        distance_m,
        r_max_m,
        bearing,
        ..
    } = err
    else {
        panic!("{err:?}");
    };
    assert!((distance_m - 1.3).abs() < 1e-12 && (r_max_m - 0.96).abs() < 1e-12);
    assert!(!bearing);
    let said = err.to_string();
    assert!(
        said.contains("out of the arm's reach: 1.3000 m from the base, where the tip can be from 0.0000 to 0.9600 m"),
        "{said}"
    );
    // The tip on the base itself: the last link would meet the first, whatever the world.
    let err = ask(&c, &world, &home(), c.base(), &[TAU / 4096.0; N]).unwrap_err();
    assert!(
        matches!(err, ReachError::GoalFolded { a: 1, b: 12 }),
        "{err:?}"
    );
    let said = err.to_string();
    assert!(
        said.contains("folds the arm onto itself: links 1 and 12 touch"),
        "{said}"
    );
    // A target inside the post: no clear pose has the tip there.
    let said = refused(&home(), Vec2::new(tip.x - 0.1, tip.y - 0.2), &[]);
    assert!(said.starts_with("no pose found with the tip on"), "{said}");
    // An arm that stands inside an obstacle round its base has no way out: it is told so.
    let on_base = World::new(0.01, 0.005, vec![disc("drop", 0.0, 0.02, 0.03)]).unwrap();
    let said = ask(&c, &on_base, &home(), below, &[])
        .unwrap_err()
        .to_string();
    assert!(
        said.contains("link 1 is inside obstacle \"drop\"")
            && said.contains("no way out")
            && said.contains("move it out first"),
        "{said}"
    );
}

/// An obstacle put onto the arm: a `reach` first takes the arm out of it, with no link ever
/// closer to an obstacle than it has been (each pair below the clearance may only gain, one
/// at or above it keeps it: what the controller carries out), then round to the target. Checked
/// along every leg by the tests' own signed distance, every 0.2 mm of the arm's motion.
#[test]
fn an_arm_an_obstacle_was_put_onto_gets_out_first_with_no_link_closer() {
    let c = chain();
    let quanta = [TAU / 4096.0; N];
    let (mut planned, mut deep) = (0, 0);
    for (world, target) in world_support::dropped_onto(40) {
        let start = world_support::disc_pairs(&c, &world, &home());
        let least = start.iter().copied().fold(f64::INFINITY, f64::min);
        deep += usize::from(least < -0.01);
        let way = match ask(&c, &world, &home(), target, &quanta) {
            Ok(way) => way,
            Err(ReachError::NoClearPose { .. }) => continue,
            Err(e) => panic!("{least} m deep, to {target:?}: {e}"),
        };
        planned += 1;
        let keep = world.clearance_m();
        let mut best: Vec<f64> = start.iter().map(|&x| x.min(keep)).collect();
        let mut at = home();
        for leg in &way.legs {
            let steps = ((c.sweep(&at, leg) / 2e-4).ceil() as usize).max(1);
            for k in 1..=steps {
                let f = k as f64 / steps as f64;
                let p: Vec<f64> = at.iter().zip(leg).map(|(x, y)| x + f * (y - x)).collect();
                for (pair, (b, now)) in best
                    .iter_mut()
                    .zip(world_support::disc_pairs(&c, &world, &p))
                    .enumerate()
                {
                    assert!(
                        now.min(keep) >= *b - 1e-9,
                        "link {} from {b} to {now} m",
                        pair + 1
                    );
                    *b = b.max(now.min(keep));
                }
                assert!(c.check_limits(&p).is_ok());
                assert!(Chain::self_intersects(&c.points(&p)).is_none());
            }
            at.clone_from(leg);
        }
        // Out, and on the target, clear as the servos take it.
        assert!(best.iter().all(|&b| b >= keep), "{best:?}");
        assert!((c.tip(&at) - target).norm() < 1e-9, "{target:?}");
        let sent: Vec<f64> = at
            .iter()
            .zip(&quanta)
            .map(|(t, q)| (t / q).round() * q)
            .collect();
        assert!(world_support::clearance(&c, &world, &sent) >= keep);
    }
    assert!(
        planned >= 36 && deep >= 20,
        "{planned} of 40 planned, {deep} deep"
    );
}
