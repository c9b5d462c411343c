//! The control loop ticks at up to 2 kHz: once warm, `Controller::tick` allocates nothing, in
//! every kind of motion (goto, path, velocity, jog, joint moves, stop) and on its harder paths
//! (bisection of an unreachable step, saturation, the joint-speed slow-down, strategy
//! switches, a step cut short where the arm would fold onto itself), among obstacles, and out
//! of one put onto the arm. A counting global allocator checks it, per thread.
#![allow(clippy::unwrap_used)]

use crate::alloc_support;

use std::f64::consts::FRAC_PI_2;

use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::control::{Command, Controller, Limits, Tick};
use snakectl::resolve::Strategy;

use alloc_support::this_thread as allocations;

/// Runs `ticks` ticks of `dt`, counting the allocations they make; returns them and the
/// ticks' flags or-ed together (saturated, slowed, clamped, self_collision).
fn run(c: &mut Controller, ticks: usize, dt: f64) -> (usize, [bool; 4]) {
    let mut flags = [false; 4];
    let mut allocated = 0;
    for _ in 0..ticks {
        let before = allocations();
        let t: Tick = c.tick(dt);
        allocated += allocations() - before;
        flags[0] |= t.saturated;
        flags[1] |= t.slowed;
        flags[2] |= t.clamped;
        flags[3] |= t.self_collision;
    }
    (allocated, flags)
}

#[test]
fn warm_ticks_allocate_nothing_in_any_motion() {
    let n = 12;
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    let chain = Chain::new(vec![0.08; n], Vec2::zeros(), FRAC_PI_2, vec![lim; n]).unwrap();
    let limits = Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 0.6,
        deadman_s: 0.3,
    };
    for strategy in [Strategy::Overall, Strategy::Sequential] {
        let home = vec![0.1; n];
        let mut c = Controller::new(chain.clone(), limits, strategy, home.clone(), &home).unwrap();
        let start = c.tip();
        let mut seen = [false; 4];
        let mut total = 0;
        // The controller sizes every buffer when it is built: not even the first round
        // allocates. Twice, so that the second starts from wherever the first left.
        for _ in 0..2 {
            let mut allocated = 0;
            let mut step = |c: &mut Controller, cmd: Option<Command>, ticks: usize| {
                if let Some(cmd) = cmd {
                    c.command(cmd).unwrap();
                }
                let (a, f) = run(c, ticks, 0.01);
                allocated += a;
                for (s, f) in seen.iter_mut().zip(f) {
                    *s |= f;
                }
            };
            let goto = |p: Vec2| Command::Goto {
                target: p,
                speed: None,
            };
            step(&mut c, Some(goto(start + Vec2::new(0.03, -0.02))), 120);
            let points = vec![start, start + Vec2::new(-0.02, 0.0), start];
            step(
                &mut c,
                Some(Command::Path {
                    points,
                    speed: Some(0.05),
                }),
                300,
            );
            step(
                &mut c,
                Some(Command::Velocity {
                    v: Vec2::new(0.0, -0.05),
                }),
                80,
            );
            c.set_strategy(match strategy {
                Strategy::Overall => Strategy::Sequential,
                Strategy::Sequential => Strategy::Overall,
            });
            step(
                &mut c,
                Some(Command::Velocity {
                    v: Vec2::new(0.05, 0.0),
                }),
                80,
            );
            c.set_strategy(strategy);
            step(
                &mut c,
                Some(Command::Jog {
                    joint: 11,
                    rad_s: 20.0,
                }),
                100,
            );
            step(&mut c, Some(Command::Stop), 40);
            let pose: Vec<f64> = (0..n).map(|i| 0.3 - 0.05 * i as f64).collect();
            step(&mut c, Some(Command::GotoJoints { theta: pose }), 150);
            step(&mut c, Some(Command::Home), 150);
            // Down beside the base and across it: the arm would fold onto itself.
            let points = vec![
                Vec2::new(-0.2, 0.2),
                Vec2::new(-0.1, 0.04),
                Vec2::new(0.1, 0.04),
            ];
            step(
                &mut c,
                Some(Command::Path {
                    points,
                    speed: None,
                }),
                3000,
            );
            step(&mut c, Some(Command::Home), 600);
            // Out of reach: bisection, saturation, the finish.
            step(&mut c, Some(goto(Vec2::new(0.0, 2.0))), 600);
            // A fast move with a slow joint limit: the slow-down and the clamp.
            step(
                &mut c,
                Some(Command::Velocity {
                    v: Vec2::new(-0.1, -0.1),
                }),
                50,
            );
            c.freeze();
            step(&mut c, None, 5);
            c.reseed(&home).unwrap();
            step(&mut c, None, 5);
            total += allocated;
        }
        assert_eq!(total, 0, "{strategy:?}: allocations in warm ticks");
        assert!(seen[0], "{strategy:?}: the run never saturated");
        assert!(
            seen[1],
            "{strategy:?}: the run was never slowed for the joints"
        );
        assert!(seen[3], "{strategy:?}: the run never met a self-collision");
    }
}

/// The arm of the tests among obstacles: twelve 0.08 m links within +-2 rad, its limits and
/// home pose.
fn arm_among_obstacles() -> (Chain, Limits, Vec<f64>) {
    let n = 12;
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    let chain = Chain::new(vec![0.08; n], Vec2::zeros(), FRAC_PI_2, vec![lim; n]).unwrap();
    let limits = Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 0.6,
        deadman_s: 0.3,
    };
    (chain, limits, vec![0.1; n])
}

#[test]
fn warm_ticks_among_obstacles_allocate_nothing() {
    use snakectl::world::{Obstacle, Shape, World};
    let (chain, limits, home) = arm_among_obstacles();
    let n = chain.len();
    let tip = chain.tip(&home);
    let top = tip.y - 0.12;
    let world = World::new(
        0.01,
        0.005,
        vec![
            Obstacle {
                id: "post".into(),
                shape: Shape::Circle {
                    center: tip + Vec2::new(0.1, -0.05),
                    radius_m: 0.02,
                },
            },
            Obstacle {
                id: "wall".into(),
                shape: Shape::Polygon {
                    points: vec![
                        Vec2::new(-1.0, top - 0.02),
                        Vec2::new(tip.x + 0.05, top - 0.02),
                        Vec2::new(tip.x + 0.05, top),
                        Vec2::new(-1.0, top),
                    ],
                },
            },
        ],
    )
    .unwrap();
    for strategy in [Strategy::Overall, Strategy::Sequential] {
        let mut c = Controller::new(chain.clone(), limits, strategy, home.clone(), &home).unwrap();
        c.set_joint_resolution(&vec![std::f64::consts::TAU / 4096.0; n])
            .unwrap();
        c.set_world(world.clone());
        // The first round sizes the solver's buffers for the pairs near contact; the second
        // must allocate nothing.
        let mut allocated = Vec::new();
        for _ in 0..2 {
            let mut a = 0;
            c.command(Command::Goto {
                target: tip + Vec2::new(0.15, -0.08),
                speed: None,
            })
            .unwrap();
            a += run(&mut c, 300, 0.01).0;
            c.command(Command::Velocity {
                v: Vec2::new(-0.03, -0.06),
            })
            .unwrap();
            a += run(&mut c, 25, 0.01).0;
            // Home may be refused where its way would pass the post; the ticks run either way.
            let _ = c.command(Command::Home);
            a += run(&mut c, 300, 0.01).0;
            allocated.push(a);
        }
        assert_eq!(allocated[1], 0, "{strategy:?}: {allocated:?}");
    }
}

/// Ticks from a pose an obstacle was put onto, the overall solver asking the links not clear
/// only to come no closer: none allocates, the first included (the world's buffers are sized
/// when it is set, or by the solve before).
#[test]
fn ticks_out_of_an_obstacle_put_onto_the_arm_allocate_nothing() {
    use snakectl::world::{Obstacle, Shape, World};
    let (chain, limits, home) = arm_among_obstacles();
    let n = chain.len();
    let p = chain.points(&home);
    let disc = |center: Vec2| Obstacle {
        id: "drop".into(),
        shape: Shape::Circle {
            center,
            radius_m: 0.02,
        },
    };
    let mut c = Controller::new(
        chain.clone(),
        limits,
        Strategy::Overall,
        home.clone(),
        &home,
    )
    .unwrap();
    c.set_joint_resolution(&vec![std::f64::consts::TAU / 4096.0; n])
        .unwrap();
    // A clear world of one obstacle first: the solver sized for it.
    let clear = World::new(0.012, 0.005, vec![disc(Vec2::new(1.5, 1.5))]).unwrap();
    c.set_world(clear);
    c.command(Command::Goto {
        target: c.tip() + Vec2::new(0.01, 0.0),
        speed: None,
    })
    .unwrap();
    run(&mut c, 100, 0.01);
    // The disc dropped on link 6, 20 mm radius: 28 mm deep.
    let on_arm = World::new(
        0.012,
        0.005,
        vec![disc((p[5] + p[6]) * 0.5 + Vec2::new(0.0, 0.004))],
    )
    .unwrap();
    assert!(c.set_world(on_arm).is_some());
    c.command(Command::Goto {
        target: c.tip() + Vec2::new(0.08, 0.0),
        speed: None,
    })
    .unwrap();
    let (mut allocated, mut finished) = (0, None);
    for _ in 0..600 {
        let before = allocations();
        let t = c.tick(0.01);
        allocated += allocations() - before;
        if t.finished.is_some() {
            finished = t.finished;
            break;
        }
    }
    assert_eq!(allocated, 0);
    assert_eq!(finished, Some(snakectl::control::Finish::Arrived));
    assert!(c.is_clear(), "the goto took the arm out");
}
