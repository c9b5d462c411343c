//! Both strategies among obstacles, through the controller as the daemon runs it (100 Hz, the
//! daemon's arm of 12 links of 0.08 m, limits +-2 rad, servo ticks of 2 pi / 4096): seeded
//! random worlds of one to six discs and bars near the arm, and a goto from the home pose to a
//! random target behind them. For each strategy: how many arrived, ended blocked or were refused
//! up front, the least clearance of any goal pose, metric 3 summed over the move and the time
//! taken (medians over the moves both strategies completed). Then, for each move overall ended
//! blocked, a `reach` to the same target from home (a way in joint space, `snakectl::reach`):
//! how many arrived, the legs, the time to plan (this machine's clock) and the time to move.
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

/// One goto (or reach): its finish (or `None` when refused), metric 3 summed over its ticks
/// and seconds.
fn run(
    strategy: Strategy,
    world: &World,
    target: Vec2,
    least: &mut f64,
) -> Option<(Finish, f64, f64)> {
    drive(
        strategy,
        world,
        Command::Goto {
            target,
            speed: None,
        },
        least,
    )
}

fn drive(
    strategy: Strategy,
    world: &World,
    command: Command,
    least: &mut f64,
) -> Option<(Finish, f64, f64)> {
    let home = vec![0.1; N];
    let mut c = Controller::new(chain(), limits(), strategy, home.clone(), &home).unwrap();
    c.set_joint_resolution(&[TAU / 4096.0; N]).unwrap();
    c.set_world(world.clone());
    c.command(command).ok()?;
    let mut m3 = 0.0;
    for k in 1..=MAX_TICKS {
        let t = c.tick(DT);
        m3 += t.m3_rad2;
        if let Some(m) = t.min_clearance_m {
            *least = least.min(m);
        }
        if let Some(f) = t.finished {
            return Some((f, m3, k as f64 * DT));
        }
    }
    Some((Finish::Saturated, m3, MAX_TICKS as f64 * DT))
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
    let (mut plan_ms, mut legs, mut reach_secs) = (Vec::new(), Vec::new(), Vec::new());
    let (mut reach_tries, mut reach_least) = (0, f64::INFINITY);
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
            let r = run(strategy, &world, target, &mut tally[s].least);
            if strategy == Strategy::Overall && matches!(r, Some((Finish::Blocked { .. }, ..))) {
                let t0 = Instant::now();
                let planned = snakectl::reach::plan(
                    &snakectl::reach::ReachRequest {
                        chain: &chain,
                        world: &world,
                        from: &home,
                        target,
                        quanta: &[TAU / 4096.0; N],
                    },
                    &Default::default(),
                );
                plan_ms.push(t0.elapsed().as_secs_f64() * 1e3);
                if let Ok(way) = planned {
                    legs.push(way.legs.len() as f64);
                }
                let reached = drive(
                    strategy,
                    &world,
                    Command::Reach { target },
                    &mut reach_least,
                );
                reach_tries += 1;
                if let Some((Finish::Arrived, _, secs)) = reached {
                    reach_secs.push(secs);
                }
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
    let (fewest, most) = plan_ms
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &t| (a.min(t), b.max(t)));
    println!(
        "\nreach, from home, where overall ended blocked: {} of {reach_tries} arrived; legs (median) {}; \
         planning {:.0} ms median ({:.0} to {:.0} ms); move {:.2} s median; least clearance {:.3} mm",
        reach_secs.len(),
        median(legs),
        median(plan_ms.clone()),
        fewest,
        most,
        median(reach_secs),
        reach_least * 1e3,
    );
}
