//! Tests of the controller among obstacles, on the daemon's arm (12 links of 0.08 m, limits
//! +-2 rad, base at the origin heading up, home 0.1 rad at every joint: the tip at about
//! (-0.547, 0.720)). Every clearance is checked with the tests' own exact distance
//! (`world_support`), not the world module's.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::world_support;

use std::f64::consts::PI;

use snakectl::chain::{Chain, Vec2};
use snakectl::control::{
    Activity, Command, Controller, Finish, Limits, Refused, CLEARANCE_ROUNDOFF_M, JOINT_WAY_STEP_M,
};
use snakectl::reach::ReachError;
use snakectl::resolve::Strategy;
use snakectl::world::{Obstacle, Shape, World, MAX_ROUTE_WORK};
use world_support::segment_distance;

/// The least clearance of the pose `theta` of the arm.
fn clearance(w: &World, theta: &[f64]) -> f64 {
    world_support::clearance(&chain(), w, theta)
}

const N: usize = 12;
const LINK_RADIUS: f64 = 0.01;
const KEEP: f64 = 0.005;
/// What the test's distance and the world's may differ by (both exact, up to round-off).
const TOL: f64 = 1e-9;

fn chain() -> Chain {
    world_support::arm()
}

fn limits() -> Limits {
    Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 2.0,
        deadman_s: 0.5,
    }
}

fn home() -> Vec<f64> {
    vec![0.1; N]
}

fn controller(strategy: Strategy, theta: &[f64]) -> Controller {
    Controller::new(chain(), limits(), strategy, home(), theta).unwrap()
}

fn circle(id: &str, x: f64, y: f64, r: f64) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: Vec2::new(x, y),
            radius_m: r,
        },
    }
}

fn rect(id: &str, x0: f64, y0: f64, x1: f64, y1: f64) -> Obstacle {
    Obstacle {
        id: id.into(),
        shape: Shape::Polygon {
            points: vec![
                Vec2::new(x0, y0),
                Vec2::new(x1, y0),
                Vec2::new(x1, y1),
                Vec2::new(x0, y1),
            ],
        },
    }
}

fn world(obstacles: Vec<Obstacle>) -> World {
    World::new(LINK_RADIUS, KEEP, obstacles).unwrap()
}

/// Ticks of 10 ms until the command finishes (at most `max`), checking every goal pose's
/// clearance; returns the finish and the least clearance seen.
fn run_clear(c: &mut Controller, max: usize) -> (Option<Finish>, f64) {
    let w = c.world().clone();
    let mut least = f64::INFINITY;
    for _ in 0..max {
        let t = c.tick(0.01);
        let now = clearance(&w, c.theta());
        least = least.min(now);
        assert!(now >= KEEP - TOL, "a goal pose {now} m from an obstacle");
        let reported = t.min_clearance_m.unwrap();
        assert!((reported - now).abs() < 1e-9, "{reported} vs {now}");
        if t.finished.is_some() {
            return (t.finished, least);
        }
    }
    (None, least)
}

#[test]
fn a_goto_behind_a_post_goes_round_it_and_every_goal_is_clear() {
    let tip = chain().tip(&home());
    let target = tip + Vec2::new(0.0, -0.2);
    // The tip's route turns round the post at 0.05 m/s; the links that follow it turn at about
    // the speed over the route's radius, 0.7 rad/s: within the joint speed limit.
    let w = world(vec![circle("post", tip.x, tip.y - 0.1, 0.055)]);
    for strategy in [Strategy::Sequential, Strategy::Overall] {
        let mut c = controller(strategy, &home());
        assert!(c.set_world(w.clone()).is_none());
        c.command(Command::Goto {
            target,
            speed: Some(0.05),
        })
        .unwrap();
        let (finish, least) = run_clear(&mut c, 3000);
        match strategy {
            Strategy::Overall => {
                assert_eq!(finish, Some(Finish::Arrived), "{strategy:?}");
                assert!((c.tip() - target).norm() < 1e-9, "{:?}", c.tip());
            }
            // The tractrix body trails the tip and may catch: then it holds, clear.
            Strategy::Sequential => assert!(
                matches!(finish, Some(Finish::Arrived | Finish::Blocked { .. })),
                "{finish:?}"
            ),
        }
        assert!(least >= KEEP - TOL);
    }
}

/// A post centred on the tip's straight way, in sixteen directions from home: both ways round are
/// equally short, and the route takes the side the body trails (the last link points back
/// along it). Round the other side the last link has to swing across the post, and the move
/// is caught: without the side rule most of these ended `blocked`.
#[test]
fn a_post_on_the_straight_way_is_gone_round_on_the_side_the_body_trails() {
    let tip = chain().tip(&home());
    let (mut caught, mut tried) = (Vec::new(), 0);
    for k in 0..16 {
        let a = PI / 8.0 * f64::from(k) + 0.1;
        let way = Vec2::new(a.cos(), a.sin());
        let target = tip + way * 0.2;
        if target.norm() > 0.9 {
            continue; // out near the reach, where the arm is nearly straight
        }
        let post = tip + way * 0.1;
        let w = world(vec![circle("post", post.x, post.y, 0.025)]);
        if clearance(&w, &home()) < KEEP + 0.01 {
            continue; // the way back along the body: the post would be on the arm
        }
        tried += 1;
        let mut c = controller(Strategy::Overall, &home());
        assert!(c.set_world(w).is_none());
        c.command(Command::Goto {
            target,
            speed: Some(0.05),
        })
        .unwrap();
        let (finish, least) = run_clear(&mut c, 3000);
        assert!(least >= KEEP - TOL);
        if finish != Some(Finish::Arrived) {
            caught.push((k, finish));
        }
    }
    assert!(tried >= 5, "{tried}");
    assert!(caught.is_empty(), "{caught:?}");
}

/// An obstacle from a micrometre down to a nanometre across on the tip's straight way is gone
/// round, a square as a disc of its size is: accepted, and the move arrives clear. (A square of
/// 1e-9 m sides was refused as closed off: its corners read as reflex, so its route had nowhere
/// to turn.) It sits 2 mm left of the way, so that the shorter way round is the right, where
/// the last link trails; round the other side that link has to sweep over it, and the move may
/// be caught, a square or a disc.
#[test]
fn a_goto_past_a_tiny_obstacle_goes_round_it_a_square_as_a_disc() {
    let tip = chain().tip(&home());
    let target = tip + Vec2::new(0.0, -0.2);
    let (x, y) = (tip.x - 2e-3, tip.y - 0.1);
    for side in [1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3] {
        let h = side / 2.0;
        for o in [
            rect("speck", x - h, y - h, x + h, y + h),
            circle("speck", x, y, h),
        ] {
            for strategy in [Strategy::Sequential, Strategy::Overall] {
                let mut c = controller(strategy, &home());
                assert!(c.set_world(world(vec![o.clone()])).is_none());
                let taken = c.command(Command::Goto {
                    target,
                    speed: Some(0.05),
                });
                assert!(taken.is_ok(), "{side} m {o:?} {strategy:?}: {taken:?}");
                let (finish, least) = run_clear(&mut c, 3000);
                assert_eq!(finish, Some(Finish::Arrived), "{side} m {o:?} {strategy:?}");
                assert!((c.tip() - target).norm() < 1e-9, "{:?}", c.tip());
                assert!(least >= KEEP - TOL);
            }
        }
    }
}

#[test]
fn a_target_where_the_tip_can_never_be_clear_is_refused_naming_the_obstacle() {
    let tip = chain().tip(&home());
    let mut c = controller(Strategy::Overall, &home());
    c.set_world(world(vec![circle("post", tip.x, tip.y - 0.1, 0.03)]));
    // 0.035 from the post's centre: within its radius plus the link radius and clearance.
    let err = c
        .command(Command::Goto {
            target: Vec2::new(tip.x + 0.035, tip.y - 0.1),
            speed: None,
        })
        .unwrap_err();
    assert!(
        matches!(&err, Refused::InsideObstacle { obstacle, .. } if obstacle == "post"),
        "{err:?}"
    );
    assert!(err.to_string().contains("\"post\""), "{err}");
    let err = c
        .command(Command::Path {
            points: vec![tip + Vec2::new(0.05, 0.0), Vec2::new(tip.x, tip.y - 0.1)],
            speed: None,
        })
        .unwrap_err();
    assert!(
        matches!(
            err,
            Refused::InsideObstacle {
                what: "path point",
                ..
            }
        ),
        "{err:?}"
    );
    assert_eq!(c.activity(), Activity::Holding);
}

/// From a pose not clear (an obstacle put onto the tip), a target inside another obstacle is
/// still refused up front, naming that obstacle: the tip could never be clear there.
#[test]
fn a_target_inside_an_obstacle_is_refused_from_a_pose_not_clear_too() {
    let tip = chain().tip(&home());
    let mut c = controller(Strategy::Overall, &home());
    let nc = c.set_world(world(vec![
        circle("on_tip", tip.x, tip.y, 0.02),
        circle("post", 0.3, 0.4, 0.03),
    ]));
    assert_eq!(nc.map(|n| n.obstacle), Some("on_tip".to_string()));
    let err = c
        .command(Command::Goto {
            target: Vec2::new(0.3, 0.4),
            speed: None,
        })
        .unwrap_err();
    assert!(
        matches!(&err, Refused::InsideObstacle { obstacle, .. } if obstacle == "post"),
        "{err:?}"
    );
    let err = c
        .command(Command::Path {
            points: vec![Vec2::new(0.31, 0.4)],
            speed: None,
        })
        .unwrap_err();
    assert!(
        matches!(&err, Refused::InsideObstacle { obstacle, .. } if obstacle == "post"),
        "{err:?}"
    );
    // A clear target is taken: the tip leaves the obstacle on the straight line.
    c.command(Command::Goto {
        target: tip + Vec2::new(0.0, -0.1),
        speed: None,
    })
    .unwrap();
}

/// Planning runs in the control loop's tick, so a command may spend only so much on it: a path
/// whose legs each go round a 256-point star is refused once its legs together need more than
/// that (it held the loop a second and more), naming the point, and nothing moves; a goto
/// round the same star is taken.
#[test]
fn a_path_whose_routes_cost_too_much_to_plan_is_refused() {
    let points: Vec<Vec2> = (0..256)
        .map(|i| {
            let a = 2.0 * PI * f64::from(i) / 256.0;
            let r = if i % 2 == 0 { 0.1 } else { 0.06 };
            Vec2::new(0.45 + r * a.cos(), 0.45 + r * a.sin())
        })
        .collect();
    let star = Obstacle {
        id: "star".into(),
        shape: Shape::Polygon { points },
    };
    let (near, far) = (Vec2::new(0.3, 0.45), Vec2::new(0.6, 0.45));
    let mut c = controller(Strategy::Overall, &home());
    assert!(c.set_world(world(vec![star])).is_none());
    let to_and_fro: Vec<Vec2> = (0..200)
        .map(|i| if i % 2 == 0 { near } else { far })
        .collect();
    let err = c
        .command(Command::Path {
            points: to_and_fro,
            speed: None,
        })
        .unwrap_err();
    assert!(
        matches!(err, Refused::RouteTooLong { what: "path point", limit, .. } if limit == MAX_ROUTE_WORK),
        "{err:?}"
    );
    assert!(err.to_string().contains("fewer path points"), "{err}");
    assert_eq!(c.activity(), Activity::Holding);
    c.command(Command::Path {
        points: vec![near, far],
        speed: None,
    })
    .unwrap();
}

#[test]
fn a_velocity_into_a_wall_slides_along_it() {
    let tip = chain().tip(&home());
    // A wall 0.12 under the tip; the velocity points down and to the left.
    let top = tip.y - 0.12;
    let w = world(vec![rect("wall", -1.0, top - 0.02, tip.x + 0.03, top)]);
    for strategy in [Strategy::Sequential, Strategy::Overall] {
        let mut c = controller(strategy, &home());
        c.set_world(w.clone());
        let v = Vec2::new(-0.03, -0.06);
        let (mut slid, mut held) = (false, false);
        for k in 0..400 {
            if k % 20 == 0 {
                c.command(Command::Velocity { v }).unwrap();
            }
            let t = c.tick(0.01);
            assert!(clearance(&w, c.theta()) >= KEEP - TOL);
            let gap = c.tip().y - top;
            assert!(
                gap >= w.route_radius_m() - TOL,
                "{strategy:?} tick {k}: the tip {gap} m above the wall"
            );
            slid |= gap < 0.02 && c.tip().x < tip.x - 0.1;
            held = t.blocked.is_some();
        }
        match strategy {
            // The whole body keeps clear: the tip slides on.
            Strategy::Overall => assert!(slid, "the tip ended at {:?}", c.tip()),
            // The tractrix body trails the tip and may catch: then the tick says so.
            Strategy::Sequential => assert!(slid || held, "the tip ended at {:?}", c.tip()),
        }
    }
}

#[test]
fn an_obstacle_put_onto_the_arm_holds_it_and_no_link_gets_closer() {
    let p = chain().points(&home());
    let mid = (p[5] + p[6]) * 0.5;
    let w = world(vec![circle("box", mid.x, mid.y, 0.02)]);
    let mut c = controller(Strategy::Overall, &home());
    c.command(Command::Velocity {
        v: Vec2::new(0.05, 0.0),
    })
    .unwrap();
    for _ in 0..10 {
        c.tick(0.01);
    }
    let nc = c.set_world(w.clone()).expect("the arm is not clear");
    assert_eq!((nc.link, nc.obstacle.as_str()), (6, "box"));
    assert!(nc.clearance_m < 0.0, "{}", nc.clearance_m);
    // Per link, its clearance to the box may grow but never shrink.
    let link_clearance = |theta: &[f64]| -> Vec<f64> {
        let q = chain().points(theta);
        (1..q.len())
            .map(|l| segment_distance(q[l - 1], q[l], &w.obstacles()[0].shape) - LINK_RADIUS)
            .collect()
    };
    let mut before = link_clearance(c.theta());
    for k in 0..300 {
        if k % 20 == 0 {
            let _ = c.command(Command::Velocity {
                v: Vec2::new(-0.05, -0.05),
            });
        }
        c.tick(0.01);
        let now = link_clearance(c.theta());
        for (l, (a, b)) in before.iter().zip(&now).enumerate() {
            assert!(
                *b >= a.min(KEEP) - 1e-6,
                "tick {k}: link {} from {a} to {b}",
                l + 1
            );
        }
        before = now;
    }
}

#[test]
fn a_link_whose_axis_is_inside_an_obstacle_never_goes_deeper() {
    // The box off the centre of link 6, its axis inside it (depth 0.012 past the link's own
    // radius): a link can get deeper into it, towards its centre. Per link, its clearance to
    // the box may grow but never shrink below the best it has had (beyond the round-off a
    // constraint is met to, once: not a tick at a time), whichever way the tip is sent.
    let p = chain().points(&home());
    let (a, b) = (p[5], p[6]);
    let normal = Vec2::new(a.y - b.y, b.x - a.x).normalize();
    for (strategy, side) in [
        (Strategy::Overall, -1.0),
        (Strategy::Overall, 1.0),
        (Strategy::Sequential, -1.0),
        (Strategy::Sequential, 1.0),
    ] {
        for v in [(0.05, 0.05), (0.05, -0.05), (-0.05, 0.05), (-0.05, -0.05)] {
            let centre = (a + b) * 0.5 + normal * (0.008 * side);
            let w = world(vec![circle("box", centre.x, centre.y, 0.02)]);
            let mut c = controller(strategy, &home());
            let nc = c.set_world(w.clone()).expect("the arm is not clear");
            assert_eq!(nc.link, 6);
            assert!(nc.clearance_m < -LINK_RADIUS, "{}", nc.clearance_m);
            let links = |theta: &[f64]| -> Vec<f64> {
                let q = chain().points(theta);
                (1..q.len())
                    .map(|l| {
                        segment_distance(q[l - 1], q[l], &w.obstacles()[0].shape) - LINK_RADIUS
                    })
                    .collect()
            };
            let mut best: Vec<f64> = links(c.theta()).iter().map(|&d| d.min(KEEP)).collect();
            for k in 0..200 {
                if k % 20 == 0 {
                    let _ = c.command(Command::Velocity {
                        v: Vec2::new(v.0, v.1),
                    });
                }
                c.tick(0.01);
                let now = links(c.theta());
                for (l, (was, is)) in best.iter_mut().zip(&now).enumerate() {
                    assert!(
                        *is >= *was - CLEARANCE_ROUNDOFF_M - 1e-15,
                        "{strategy:?}, side {side}, velocity {v:?}, tick {k}: link {} at {is}, \
                         its best {was}",
                        l + 1
                    );
                    *was = was.max(is.min(KEEP));
                }
            }
        }
    }
}

#[test]
fn a_joint_move_through_an_obstacle_is_refused_naming_link_and_how_far() {
    let straight = vec![0.0; N];
    // A post where the tip passes halfway home.
    let halfway: Vec<f64> = home().iter().map(|h| 0.5 * h).collect();
    let at = chain().tip(&halfway);
    let w = world(vec![circle("post", at.x, at.y, 0.02)]);
    assert!(clearance(&w, &straight) > KEEP && clearance(&w, &home()) > KEEP);
    let mut c = controller(Strategy::Overall, &straight);
    assert!(c.set_world(w).is_none());
    let err = c.command(Command::Home).unwrap_err();
    let Refused::NotClearOnTheWay {
        link,
        ref obstacle,
        fraction,
        from_fraction,
        clearance_m,
        ..
    } = err
    else {
        panic!("{err:?}");
    };
    // Named at the deepest pose of the way (the tip through the post's centre, halfway), and
    // where the way first loses clearance (before it).
    assert_eq!((link, obstacle.as_str()), (N, "post"));
    assert!(
        from_fraction > 0.2 && from_fraction < 0.5,
        "{from_fraction}"
    );
    assert!((fraction - 0.5).abs() < 0.02, "{fraction}");
    assert!(clearance_m < -0.02, "{clearance_m}");
    let said = err.to_string();
    assert!(
        said.contains(&format!(
            "would be inside obstacle \"post\", {:.4} m deep, 50% of the way there",
            -clearance_m
        )) && said.contains("loses its clearance from"),
        "{said}"
    );
    assert!(c
        .command(Command::GotoJoints {
            theta: home().to_vec()
        })
        .is_err());
    // The same move with the post out of the way is taken.
    c.set_world(world(vec![circle("post", 2.0, 2.0, 0.02)]));
    c.command(Command::Home).unwrap();
}

/// A joint move's way is judged on a grid of samples [`JOINT_WAY_STEP_M`] of motion apart; the
/// controller passes over the samples it can vouch for from one it looked at (no point can move
/// far enough in between to lose the clearance). Its verdict, where the way first loses its
/// clearance and its deepest pose are those of the tests' own look at every sample, over seeded
/// worlds of discs about the arm and random moves, some taken and some refused.
#[test]
fn a_joint_move_is_judged_as_if_every_sample_were_looked_at() {
    use rand::{Rng, SeedableRng};
    let c = chain();
    let mut rng = rand::rngs::StdRng::seed_from_u64(23);
    let (mut taken, mut refused) = (0, 0);
    for _ in 0..150 {
        let start: Vec<f64> = home()
            .iter()
            .map(|h| h + rng.gen_range(-0.3..0.3))
            .collect();
        let points = c.points(&start);
        let obstacles = (0..rng.gen_range(1..=4))
            .map(|k| {
                let near = points[rng.gen_range(1..=N)];
                let at = near + Vec2::new(rng.gen_range(-0.15..0.15), rng.gen_range(-0.15..0.15));
                circle(&format!("o{k}"), at.x, at.y, rng.gen_range(0.01..0.05))
            })
            .collect();
        let w = world(obstacles);
        if disc_clearance(&w, &start) <= KEEP + 1e-6 {
            continue;
        }
        let goal: Vec<f64> = start.iter().map(|a| a + rng.gen_range(-0.6..0.6)).collect();
        // The tests' own look at every sample.
        let steps = (c.sweep(&start, &goal) / JOINT_WAY_STEP_M).ceil() as usize;
        let (mut first, mut deepest) = (None, (f64::INFINITY, 0.0));
        let mut near_the_line = false;
        for k in 1..=steps {
            let f = k as f64 / steps as f64;
            let pose: Vec<f64> = start
                .iter()
                .zip(&goal)
                .map(|(a, b)| a + f * (b - a))
                .collect();
            let cl = disc_clearance(&w, &pose);
            near_the_line |= (cl - KEEP).abs() < TOL;
            if cl < KEEP {
                first.get_or_insert(f);
                if cl < deepest.0 {
                    deepest = (cl, f);
                }
            }
        }
        if near_the_line {
            continue;
        }
        let mut ctl = controller(Strategy::Overall, &start);
        assert!(ctl.set_world(w.clone()).is_none());
        match ctl.command(Command::GotoJoints {
            theta: goal.clone(),
        }) {
            Ok(()) => {
                assert_eq!(first, None, "a way through an obstacle taken");
                taken += 1;
            }
            Err(Refused::NotClearOnTheWay {
                fraction,
                from_fraction,
                clearance_m,
                ..
            }) => {
                assert_eq!(Some(from_fraction), first);
                assert!(
                    (clearance_m - deepest.0).abs() < TOL,
                    "{clearance_m} vs {deepest:?}"
                );
                let there: Vec<f64> = start
                    .iter()
                    .zip(&goal)
                    .map(|(a, b)| a + fraction * (b - a))
                    .collect();
                assert!((disc_clearance(&w, &there) - deepest.0).abs() < TOL);
                refused += 1;
            }
            // A goal pose whose links meet, say: not this test's business.
            Err(_) => {}
        }
    }
    assert!(
        taken >= 20 && refused >= 20,
        "{taken} taken, {refused} refused"
    );
}

/// The least clearance of the pose `theta` among discs, signed: a link into a disc counts the
/// depth of its deepest point (its axis's distance from the centre, less the radius).
fn disc_clearance(w: &World, theta: &[f64]) -> f64 {
    let p = chain().points(theta);
    let mut least = f64::INFINITY;
    for link in 1..p.len() {
        for o in w.obstacles() {
            let Shape::Circle { center, radius_m } = o.shape else {
                panic!("discs only");
            };
            let d = world_support::point_segment(center, p[link - 1], p[link]);
            least = least.min(d - radius_m - w.link_radius_m());
        }
    }
    least
}

#[test]
fn goals_rounded_to_the_servos_resolution_stay_clear() {
    let tip = chain().tip(&home());
    let q = 2.0 * PI / 4096.0;
    let top = tip.y - 0.12;
    let w = world(vec![rect("wall", -1.0, top - 0.02, tip.x + 0.03, top)]);
    let mut c = controller(Strategy::Overall, &home());
    c.set_joint_resolution(&[q; N]).unwrap();
    c.set_world(w.clone());
    for k in 0..400 {
        if k % 20 == 0 {
            c.command(Command::Velocity {
                v: Vec2::new(-0.03, -0.06),
            })
            .unwrap();
        }
        c.tick(0.01);
        let rounded: Vec<f64> = c.theta().iter().map(|t| (t / q).round() * q).collect();
        assert!(clearance(&w, &rounded) >= KEEP - TOL, "tick {k}");
    }
    assert!(c.set_joint_resolution(&[q; N - 1]).is_err());
    assert!(c.set_joint_resolution(&[f64::NAN; N]).is_err());
}

/// A joint move whose goal is clear but not as the servos receive it (each joint rounded to a
/// whole tick) is refused up front, naming the link and the obstacle: taken, it could only end
/// blocked short of its goal.
#[test]
fn a_joint_move_whose_goal_rounded_to_ticks_is_not_clear_is_refused() {
    let q = 2.0 * PI / 4096.0;
    let rounded: Vec<f64> = home().iter().map(|t| (t / q).round() * q).collect();
    let (tip, tip_rounded) = (chain().tip(&home()), chain().tip(&rounded));
    // A post on the side rounding moves the tip to, 0.1 mm beyond the clearance from home.
    let centre = tip + (tip_rounded - tip).normalize() * 0.05;
    let post = |r: f64| world(vec![circle("post", centre.x, centre.y, r)]);
    let r = 0.001 + clearance(&post(0.001), &home()) - KEEP - 1e-4;
    let w = post(r);
    assert!((clearance(&w, &home()) - (KEEP + 1e-4)).abs() < 1e-9);
    assert!(
        clearance(&w, &rounded) < KEEP,
        "{}",
        clearance(&w, &rounded)
    );
    let start: Vec<f64> = home().iter().map(|t| 1.5 * t).collect();
    let mut c = controller(Strategy::Overall, &start);
    c.set_joint_resolution(&[q; N]).unwrap();
    assert!(c.set_world(w).is_none());
    let err = c.command(Command::Home).unwrap_err();
    assert!(
        matches!(&err, Refused::GoalNotClearAsSent { obstacle, clearance_m, .. }
            if obstacle == "post" && *clearance_m < KEEP),
        "{err:?}"
    );
    assert!(err.to_string().contains("whole tick"), "{err}");
    assert!(c.command(Command::GotoJoints { theta: home() }).is_err());
    assert_eq!(c.activity(), Activity::Holding);
    // With the post 5 mm further off, the same move is taken and arrives.
    assert!(c.set_world(post(r - 0.005)).is_none());
    c.command(Command::Home).unwrap();
    let (finish, _) = run_clear(&mut c, 1000);
    assert_eq!(finish, Some(Finish::Arrived));
}

#[test]
fn a_goto_the_arm_cannot_keep_up_with_ends_blocked_within_the_headway_time() {
    let slow = Limits {
        max_joint_speed_rad_s: 1e-3,
        ..limits()
    };
    let mut c = Controller::new(chain(), slow, Strategy::Overall, home(), &home()).unwrap();
    let tip = chain().tip(&home());
    c.set_world(world(vec![circle("post", 2.0, 2.0, 0.02)]));
    c.command(Command::Goto {
        target: tip + Vec2::new(0.0, -0.1),
        speed: None,
    })
    .unwrap();
    let mut ended = None;
    for k in 1..=60 {
        if let Some(f) = c.tick(0.01).finished {
            ended = Some((f, k));
            break;
        }
    }
    let (finish, k) = ended.expect("the goto ends");
    assert!(matches!(finish, Finish::Blocked { .. }), "{finish:?}");
    assert!((50..=52).contains(&k), "after {k} ticks");
    assert_eq!(c.activity(), Activity::Holding);
}

#[test]
fn without_obstacles_nothing_changes() {
    let mut a = controller(Strategy::Overall, &home());
    let mut b = controller(Strategy::Overall, &home());
    b.set_world(World::default());
    let target = chain().tip(&home()) + Vec2::new(0.05, -0.05);
    for c in [&mut a, &mut b] {
        c.command(Command::Goto {
            target,
            speed: None,
        })
        .unwrap();
    }
    for _ in 0..200 {
        let (ta, tb) = (a.tick(0.01), b.tick(0.01));
        assert_eq!(ta, tb);
        assert_eq!(ta.min_clearance_m, None);
    }
    assert_eq!(a.theta(), b.theta());
}

/// Where the least joint motion of each tick wraps the body round an obstacle on the side the
/// tip's route led it to, a `goto` ends `blocked`; a `reach` to the same target, sent from where
/// the arm was caught, goes there in straight joint-space legs round the obstacles instead,
/// every goal pose clear, and arrives. Under both strategies: the sequential strategy's body is
/// caught leaning on the clearance itself, where each joint rounded to a whole servo tick can
/// bring a link closer than the exact pose (the legs are checked as sent there).
#[test]
fn a_reach_gets_there_where_a_goto_is_caught() {
    let quanta = [std::f64::consts::TAU / 4096.0; N];
    for strategy in [Strategy::Overall, Strategy::Sequential] {
        let mut rescued = 0;
        for (w, target) in world_support::caught_moves(60) {
            let mut c = controller(strategy, &home());
            c.set_joint_resolution(&quanta).unwrap();
            assert!(c.set_world(w.clone()).is_none());
            c.command(Command::Goto {
                target,
                speed: None,
            })
            .unwrap();
            let (finish, _) = run_clear(&mut c, 3000);
            if !matches!(finish, Some(Finish::Blocked { .. })) {
                continue;
            }
            c.command(Command::Reach { target }).unwrap();
            assert_eq!(c.activity(), Activity::Moving);
            let (finish, least) = run_clear(&mut c, 6000);
            assert_eq!(finish, Some(Finish::Arrived), "{strategy:?} {target:?}");
            assert!(least >= KEEP - TOL);
            assert!((c.tip() - target).norm() < 1e-9, "{:?} {target:?}", c.tip());
            // Arrived, it has no target left.
            assert_eq!(c.target(), None);
            // A tip command from there starts with the body still: the goal keeps what the
            // overall strategy keeps (the clearance and what rounding may take).
            let at = c.theta().to_vec();
            c.command(Command::Velocity { v: Vec2::zeros() }).unwrap();
            for _ in 0..5 {
                c.tick(0.01);
            }
            let moved = at
                .iter()
                .zip(c.theta())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(
                moved < 1e-9,
                "{strategy:?} {target:?}: a joint moved {moved} rad"
            );
            rescued += 1;
            if rescued == 6 {
                break;
            }
        }
        assert_eq!(
            rescued, 6,
            "{strategy:?}: {rescued} caught gotos in 60 moves"
        );
    }
}

/// An obstacle put onto the arm: a `reach` takes the arm out (no link ever closer to the disc
/// than it has been, by the tests' own distance at every tick) and round to its target, under
/// both strategies, with the servos' resolution set.
#[test]
fn a_reach_from_an_obstacle_put_onto_the_arm_gets_out_and_arrives() {
    let quanta = [std::f64::consts::TAU / 4096.0; N];
    for strategy in [Strategy::Overall, Strategy::Sequential] {
        let mut arrived = 0;
        for (w, target) in world_support::dropped_onto(8) {
            let mut c = controller(strategy, &home());
            c.set_joint_resolution(&quanta).unwrap();
            assert!(c.set_world(w.clone()).is_some(), "the drop is on the arm");
            match c.command(Command::Reach { target }) {
                Ok(()) => {}
                Err(Refused::Reach(ReachError::NoClearPose { .. })) => continue,
                Err(e) => panic!("{target:?}: {e}"),
            }
            let pairs = |theta: &[f64]| world_support::disc_pairs(&chain(), &w, theta);
            let mut best: Vec<f64> = pairs(c.theta()).iter().map(|&d| d.min(KEEP)).collect();
            let mut finish = None;
            for _ in 0..6000 {
                let t = c.tick(0.01);
                for (l, (b, now)) in best.iter_mut().zip(pairs(c.theta())).enumerate() {
                    assert!(now.min(KEEP) >= *b - 1e-6, "link {}: {b} to {now}", l + 1);
                    *b = b.max(now.min(KEEP));
                }
                if t.finished.is_some() {
                    finish = t.finished;
                    break;
                }
            }
            assert_eq!(finish, Some(Finish::Arrived), "{strategy:?} {target:?}");
            assert!((c.tip() - target).norm() < 1e-9, "{:?} {target:?}", c.tip());
            assert!(c.is_clear());
            arrived += 1;
        }
        assert!(arrived >= 6, "{strategy:?}: {arrived} of 8 arrived");
    }
}

/// The caught moves ([`world_support::caught_moves`]) whose way from home, planned with exact
/// joints, has `legs` legs or more: each world, target and way.
fn planned_ways(legs: usize) -> impl Iterator<Item = (World, Vec2, snakectl::reach::Way)> {
    let (c0, from) = (chain(), home());
    world_support::caught_moves(60)
        .into_iter()
        .filter_map(move |(w, target)| {
            let req = snakectl::reach::ReachRequest {
                chain: &c0,
                world: &w,
                from: &from,
                target,
                quanta: &[],
            };
            let way = snakectl::reach::plan(&req, &Default::default()).ok()?;
            (way.legs.len() >= legs).then_some((w, target, way))
        })
}

/// A disc put on a `reach`'s second leg while the first goes (clear of the first): the reach
/// ends `blocked` when the first arrives, naming the disc that stops the second, not the
/// obstacle the arm is nearest there.
#[test]
fn a_reach_whose_next_leg_a_new_obstacle_stops_is_blocked_naming_it() {
    let c0 = chain();
    for (w, target, way) in planned_ways(2) {
        // Poses along a leg, every 1% of it.
        let along = |a: &[f64], b: &[f64]| -> Vec<Vec<Vec2>> {
            (0..=100)
                .map(|k| {
                    let f = k as f64 / 100.0;
                    let p: Vec<f64> = a.iter().zip(b).map(|(x, y)| x + f * (y - x)).collect();
                    c0.points(&p)
                })
                .collect()
        };
        let first = along(&home(), &way.legs[0]);
        // A joint of the second leg's middle pose, 5 cm from every point of the first leg and
        // from every obstacle: a disc of 1 cm there stops the second leg only.
        let middle = along(&way.legs[0], &way.legs[1])[50].clone();
        let Some(&spot) = middle.iter().skip(2).find(|q| {
            first.iter().flatten().all(|p| (*p - **q).norm() > 0.05)
                && w.point_distance(**q).is_none_or(|(d, _)| d > 0.05)
        }) else {
            continue;
        };
        let mut more = w.obstacles().to_vec();
        more.push(circle("new", spot.x, spot.y, 0.01));
        let more = world(more);
        // Where the first leg ends, another obstacle is nearer than the new disc.
        let nearest = more.pose_clearance(&c0, &way.legs[0]).unwrap();
        if nearest.id(&more) == "new" {
            continue;
        }
        let mut c = controller(Strategy::Overall, &home());
        assert!(c.set_world(w.clone()).is_none());
        c.command(Command::Reach { target }).unwrap();
        assert!(c.set_world(more).is_none(), "the first leg's pose is clear");
        let (finish, _) = run_clear(&mut c, 3000);
        let Some(Finish::Blocked { obstacle, .. }) = finish else {
            panic!("{finish:?}");
        };
        assert_eq!(c.world().obstacles()[obstacle].id, "new");
        return;
    }
    panic!("no way of two legs with room for a disc on the second");
}

/// A `reach` that finds no clear pose with the tip on its target is refused in words and
/// nothing moves.
#[test]
fn a_reach_with_nowhere_to_go_is_refused_and_nothing_moves() {
    let tip = chain().tip(&home());
    let w = world(vec![circle("post", tip.x, tip.y - 0.2, 0.03)]);
    let mut c = controller(Strategy::Overall, &home());
    c.set_world(w);
    let err = c
        .command(Command::Reach {
            target: Vec2::new(tip.x, tip.y - 0.2),
        })
        .unwrap_err();
    assert!(matches!(err, Refused::Reach(_)), "{err:?}");
    assert!(
        err.to_string().starts_with("no pose found with the tip on"),
        "{err}"
    );
    assert_eq!(c.activity(), Activity::Holding);
    let err = c
        .command(Command::Reach {
            target: Vec2::new(f64::NAN, 0.0),
        })
        .unwrap_err();
    assert!(err.to_string().contains("target"), "{err}");
}

/// A `reach` stopped on its first leg ends there: the legs left are dropped, and a joint move
/// sent next arrives and holds instead of going on with them.
#[test]
fn a_stopped_reach_leaves_no_legs_behind() {
    let (w, target, _) = planned_ways(3)
        .next()
        .expect("a reach of three legs or more in 60 moves");
    let mut c = controller(Strategy::Overall, &home());
    c.set_world(w);
    c.command(Command::Reach { target }).unwrap();
    for _ in 0..10 {
        assert!(c.tick(0.01).finished.is_none());
        // Its target is told while it goes (telemetry's `target`).
        assert_eq!(c.target(), Some(target));
    }
    c.command(Command::Stop).unwrap();
    let (finish, _) = run_clear(&mut c, 500);
    assert!(matches!(finish, Some(Finish::Stopped { .. })), "{finish:?}");
    assert_eq!(c.target(), None);
    let mut near = c.theta().to_vec();
    near[N - 1] += 0.01;
    c.command(Command::GotoJoints {
        theta: near.clone(),
    })
    .unwrap();
    let (finish, _) = run_clear(&mut c, 500);
    assert_eq!(finish, Some(Finish::Arrived));
    for _ in 0..50 {
        assert!(c.tick(0.01).finished.is_none());
    }
    assert_eq!(c.activity(), Activity::Holding);
    assert_eq!(c.theta(), &near[..]);
}
