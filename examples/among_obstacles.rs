//! Both strategies among obstacles, through the controller as the daemon runs it (100 Hz, the
//! daemon's arm of 12 links of 0.08 m, limits +-2 rad, servo ticks of 2 pi / 4096): seeded
//! random worlds of one to six discs and bars near the arm, and a goto from the home pose to a
//! random target behind them. For each strategy: how many arrived, ended blocked or were refused
//! up front, the least clearance of any goal pose, metric 3 summed over the move and the time
//! taken (medians over the moves both strategies completed). Then, for each move a strategy ended
//! blocked, a `reach` to the same target from where the arm was caught (a way in joint space,
//! `snakectl::reach`): how many arrived, ended blocked or were refused, the least clearance of
//! any goal pose, the legs, the time to plan (this machine's clock) and the time to move.
//!
//! `cargo run --release --example among_obstacles [-- CASES]` (default 200).
#![allow(clippy::unwrap_used)]

use std::f64::consts::{FRAC_PI_2, TAU};

use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::control::{Command, Controller, Finish, Limits};
use snakectl::resolve::Strategy;
use snakectl::world::{Obstacle, Shape, World};
use std::time::Instant;

const N: usize = 12;
const DT: f64 = 0.01;
const MAX_TICKS: usize = 3000;

fn chain() -> Chain {
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    Chain::new(vec![0.08; N], Vec2::zeros(), FRAC_PI_2, vec![lim; N]).unwrap()
}

fn limits() -> Limits {
    Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 1.0,
        deadman_s: 0.3,
    }
}

/// One random world clear of the home pose and a target clear of it, or `None` to draw again.
fn case(rng: &mut impl Rng, chain: &Chain, home: &[f64]) -> Option<(World, Vec2)> {
    let tip = chain.tip(home);
    let mut obstacles = Vec::new();
    for k in 0..rng.gen_range(1..=6) {
        let c = tip + Vec2::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.1));
        let shape = if rng.gen_bool(0.5) {
            Shape::Circle {
                center: c,
                radius_m: rng.gen_range(0.01..0.04),
            }
        } else {
            let (w, h) = (rng.gen_range(0.02..0.12), rng.gen_range(0.01..0.03));
            Shape::Polygon {
                points: vec![
                    c + Vec2::new(-w, -h),
                    c + Vec2::new(w, -h),
                    c + Vec2::new(w, h),
                    c + Vec2::new(-w, h),
                ],
            }
        };
        obstacles.push(Obstacle {
            id: format!("o{k}"),
            shape,
        });
    }
    let world = World::new(0.01, 0.005, obstacles).ok()?;
    let clear = world.pose_clearance(chain, home)?.clearance_m > 0.01;
    let target = tip + Vec2::new(rng.gen_range(-0.35..0.35), rng.gen_range(-0.4..-0.1));
    let reachable = target.norm() < 0.9 * chain.reach();
    let far = world.point_distance(target)?.0 > 0.03;
    (clear && reachable && far).then_some((world, target))
}

#[derive(Default)]
struct Tally {
    arrived: usize,
    blocked: usize,
    refused: usize,
    other: usize,
    least: f64,
}

/// One goto: its finish (or `None` when refused), metric 3 summed over its ticks and seconds;
/// when it ended blocked, what a `reach` from there did.
fn run(
    strategy: Strategy,
    world: &World,
    target: Vec2,
    least: &mut f64,
) -> (Option<(Finish, f64, f64)>, Option<Reached>) {
    let home = vec![0.1; N];
    let mut c = Controller::new(chain(), limits(), strategy, home.clone(), &home).unwrap();
    c.set_joint_resolution(&[TAU / 4096.0; N]).unwrap();
    c.set_world(world.clone());
    let goto = Command::Goto {
        target,
        speed: None,
    };
    if c.command(goto).is_err() {
        return (None, None);
    }
    let r = ticks(&mut c, least);
    if !matches!(r, (Finish::Blocked { .. }, ..)) {
        return (Some(r), None);
    }
    // Planned once more on its own, to time it and count its legs.
    let t0 = Instant::now();
    let planned = snakectl::reach::plan(
        &snakectl::reach::ReachRequest {
            chain: &chain(),
            world,
            from: c.theta(),
            target,
            quanta: &[TAU / 4096.0; N],
        },
        &Default::default(),
    );
    let plan_ms = t0.elapsed().as_secs_f64() * 1e3;
    let legs = planned.map_or(0, |w| w.legs.len());
    let mut reach_least = f64::INFINITY;
    let finish = match c.command(Command::Reach { target }) {
        Ok(()) => Some(ticks(&mut c, &mut reach_least)),
        Err(e) => {
            eprintln!("{strategy:?}: reach to {target:?} refused: {e}");
            None
        }
    };
    let reached = Reached {
        finish,
        plan_ms,
        legs,
        least: reach_least,
    };
    (Some(r), Some(reached))
}

/// What a `reach` from a caught pose did.
struct Reached {
    /// Its finish, metric 3 and seconds (`None`: refused).
    finish: Option<(Finish, f64, f64)>,
    plan_ms: f64,
    legs: usize,
    least: f64,
}

/// Ticks until the command finishes: the finish, metric 3 summed and seconds.
fn ticks(c: &mut Controller, least: &mut f64) -> (Finish, f64, f64) {
    let mut m3 = 0.0;
    for k in 1..=MAX_TICKS {
        let t = c.tick(DT);
        m3 += t.m3_rad2;
        if let Some(m) = t.min_clearance_m {
            *least = least.min(m);
        }
        if let Some(f) = t.finished {
            return (f, m3, k as f64 * DT);
        }
    }
    (Finish::Saturated, m3, MAX_TICKS as f64 * DT)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn main() {
    let cases: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(200);
    let chain = chain();
    let home = vec![0.1; N];
    let mut rng = rand::rngs::StdRng::seed_from_u64(22);
    let mut tally = [Tally::default(), Tally::default()];
    for t in &mut tally {
        t.least = f64::INFINITY;
    }
    let (mut m3, mut secs) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    let mut done = 0;
    let mut reach: [Vec<Reached>; 2] = [Vec::new(), Vec::new()];
    while done < cases {
        let Some((world, target)) = case(&mut rng, &chain, &home) else {
            continue;
        };
        done += 1;
        let mut runs = Vec::new();
        for (s, strategy) in [Strategy::Sequential, Strategy::Overall]
            .into_iter()
            .enumerate()
        {
            let (r, reached) = run(strategy, &world, target, &mut tally[s].least);
            if let Some(reached) = reached {
                reach[s].push(reached);
            }
            match r {
                None => tally[s].refused += 1,
                Some((Finish::Arrived, ..)) => tally[s].arrived += 1,
                Some((Finish::Blocked { .. }, ..)) => tally[s].blocked += 1,
                Some(_) => tally[s].other += 1,
            }
            runs.push(r);
        }
        if let [Some((Finish::Arrived, a3, at)), Some((Finish::Arrived, b3, bt))] = runs[..] {
            m3[0].push(a3);
            m3[1].push(b3);
            secs[0].push(at);
            secs[1].push(bt);
        }
    }
    println!("{cases} gotos among random obstacles (link radius 0.01 m, clearance 0.005 m)\n");
    println!(
        "| strategy | arrived | blocked | refused | other | least clearance, mm | metric 3 (median, both arrived), rad² | time (median), s |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (s, name) in ["sequential", "overall"].into_iter().enumerate() {
        let t = &tally[s];
        println!(
            "| {name} | {} | {} | {} | {} | {:.3} | {:.4} | {:.2} |",
            t.arrived,
            t.blocked,
            t.refused,
            t.other,
            t.least * 1e3,
            median(m3[s].clone()),
            median(secs[s].clone()),
        );
    }
    println!("\n({} moves both arrived)", m3[0].len());
    println!(
        "\nA reach to the same target from where each blocked goto was caught:\n\n\
         | strategy | caught | arrived | blocked | refused | least clearance, mm | legs (median) | \
         planning (median, range), ms | move (median), s |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (s, name) in ["sequential", "overall"].into_iter().enumerate() {
        let r = &reach[s];
        let count = |f: fn(&Finish) -> bool| {
            r.iter()
                .filter(|x| x.finish.as_ref().is_some_and(|(fin, ..)| f(fin)))
                .count()
        };
        let arrived = count(|f| matches!(f, Finish::Arrived));
        let blocked = count(|f| matches!(f, Finish::Blocked { .. }));
        let refused = r.iter().filter(|x| x.finish.is_none()).count();
        let ms: Vec<f64> = r.iter().map(|x| x.plan_ms).collect();
        let (lo, hi) = ms
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), &t| (a.min(t), b.max(t)));
        let secs = r
            .iter()
            .filter_map(|x| match x.finish {
                Some((Finish::Arrived, _, s)) => Some(s),
                _ => None,
            })
            .collect();
        println!(
            "| {name} | {} | {arrived} | {blocked} | {refused} | {:.3} | {} | {:.0} ({:.0} to {:.0}) | {:.2} |",
            r.len(),
            r.iter().map(|x| x.least).fold(f64::INFINITY, f64::min) * 1e3,
            median(r.iter().map(|x| x.legs as f64).collect()),
            median(ms.clone()),
            lo,
            hi,
            median(secs),
        );
    }
}
