//! Property tests among obstacles: random worlds near the arm and random command sequences,
//! under both strategies. Every tick's goal pose keeps the clearance (by the tests' own exact
//! distance, `world_support`, not the library's), and so does that pose rounded to whole servo
//! ticks; the joint limits and the joint-speed bound hold; nothing is non-finite.
#![allow(clippy::unwrap_used)]

use crate::world_support;

use std::f64::consts::TAU;

use proptest::prelude::*;
use snakectl::chain::{Chain, Vec2};
use snakectl::control::{Command, Controller, Limits};
use snakectl::resolve::Strategy;
use snakectl::world::{Obstacle, Shape, World};

const N: usize = 12;
const DT: f64 = 0.01;
/// One servo tick of a 4096-step servo, rad.
const TICK: f64 = TAU / 4096.0;
/// Round-off allowed below the clearance, m.
const TOL: f64 = 1e-9;

fn chain() -> Chain {
    world_support::arm()
}

fn limits() -> Limits {
    Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 1.0,
        deadman_s: 0.3,
    }
}

/// An obstacle drawn from `(kind, x, y, size, aspect)`: a disc, or a rectangle turned by
/// `aspect` radians (a convex polygon), or an L (a non-convex one).
fn obstacle(k: usize, (kind, x, y, size, turn): (u8, f64, f64, f64, f64)) -> Obstacle {
    let c = Vec2::new(x, y);
    let rot = |p: Vec2| {
        let (s, co) = turn.sin_cos();
        c + Vec2::new(co * p.x - s * p.y, s * p.x + co * p.y)
    };
    let shape = match kind % 3 {
        0 => Shape::Circle {
            center: c,
            radius_m: size,
        },
        1 => Shape::Polygon {
            points: [(-1.0, -0.3), (1.0, -0.3), (1.0, 0.3), (-1.0, 0.3)]
                .iter()
                .map(|&(a, b)| rot(Vec2::new(a * size, b * size)))
                .collect(),
        },
        _ => Shape::Polygon {
            points: [
                (0.0, 0.0),
                (2.0, 0.0),
                (2.0, 0.6),
                (0.6, 0.6),
                (0.6, 2.0),
                (0.0, 2.0),
            ]
            .iter()
            .map(|&(a, b)| rot(Vec2::new(a * size, b * size)))
            .collect(),
        },
    };
    Obstacle {
        id: format!("o{k}"),
        shape,
    }
}

/// A command drawn from `(kind, a, b)` with the arm's tip at `tip`.
fn command(tip: Vec2, (kind, a, b): (u8, f64, f64)) -> Command {
    match kind % 6 {
        0 => Command::Goto {
            target: tip + Vec2::new(a, b) * 0.3,
            speed: None,
        },
        1 => Command::Path {
            points: vec![tip + Vec2::new(a, 0.0) * 0.2, tip + Vec2::new(a, b) * 0.2],
            speed: None,
        },
        2 | 3 => Command::Velocity {
            v: Vec2::new(a, b) * 0.1,
        },
        4 => Command::GotoJoints {
            theta: (0..N)
                .map(|i| 0.1 + 0.3 * a * (i as f64 * b).sin())
                .collect(),
        },
        _ => Command::Home,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    #[test]
    fn every_goal_pose_keeps_clear_within_the_limits(
        shapes in prop::collection::vec(
            (0u8..3, -0.9f64..0.9, 0.0f64..1.0, 0.01f64..0.06, 0.0f64..3.2), 1..8),
        commands in prop::collection::vec((0u8..6, -1.0f64..1.0, -1.0f64..1.0), 1..6),
        overall in any::<bool>(),
        link_radius in 0.0f64..0.015,
        keep in 0.0f64..0.01,
    ) {
        let chain = chain();
        let home = vec![0.1; N];
        // Only obstacles clear of the home pose, where the arm starts, and of its goal as sent
        // (rounded to whole ticks).
        let sent: Vec<f64> = home.iter().map(|t| (t / TICK).round() * TICK).collect();
        let candidates: Vec<Obstacle> =
            shapes.into_iter().enumerate().map(|(k, s)| obstacle(k, s)).collect();
        let mut kept = Vec::new();
        for o in candidates {
            let one = World::new(link_radius, keep, vec![o.clone()]).unwrap();
            if world_support::clearance(&chain, &one, &home) > keep + 1e-3
                && world_support::clearance(&chain, &one, &sent) > keep + 1e-3
                && one.point_distance(Vec2::zeros()).is_some_and(|(d, _)| d > link_radius + keep)
            {
                kept.push(o);
            }
        }
        let world = World::new(link_radius, keep, kept).unwrap();
        let strategy = if overall { Strategy::Overall } else { Strategy::Sequential };
        let mut c = Controller::new(chain.clone(), limits(), strategy, home.clone(), &home).unwrap();
        c.set_joint_resolution(&[TICK; N]).unwrap();
        prop_assert!(c.set_world(world.clone()).is_none());
        let bound = limits().max_joint_speed_rad_s * DT * (1.0 + 1e-9);
        let mut before = c.theta().to_vec();
        for cmd in commands {
            // A refusal (a target inside an obstacle, a joint move through one) is fine.
            let _ = c.command(command(c.tip(), cmd));
            for _ in 0..120 {
                let t = c.tick(DT);
                let theta = c.theta();
                prop_assert!(theta.iter().all(|x| x.is_finite()));
                prop_assert!(t.tip.x.is_finite() && t.tip.y.is_finite());
                prop_assert!(chain.check_limits(theta).is_ok());
                for (a, b) in before.iter().zip(theta) {
                    prop_assert!((a - b).abs() <= bound, "joint step {} rad", (a - b).abs());
                }
                let clear = world_support::clearance(&chain, &world, theta);
                prop_assert!(clear >= keep - TOL, "goal pose {clear} m from an obstacle");
                let rounded: Vec<f64> = theta.iter().map(|x| (x / TICK).round() * TICK).collect();
                let clear = world_support::clearance(&chain, &world, &rounded);
                prop_assert!(clear >= keep - TOL, "rounded goal pose {clear} m from an obstacle");
                before.copy_from_slice(theta);
            }
        }
    }
}
