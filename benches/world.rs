//! The overall strategy among obstacles: `cargo bench --bench world`.
//!
//! Setup: a 1 m arm of n equal links (n = 12 and 24), base at the origin, relative angles
//! uniform in +-(pi/n) (seeded); links of radius 12 mm keeping 5 mm of clearance. "Obstacles
//! near the arm" (0, 4 or 16): discs of radius 10..30 mm, each beside a link of the start pose
//! (spread along the arm, sides alternating), its gap to the link's capsule 2..40 mm beyond the
//! clearance; a world whose start pose is not clear is drawn again.
//! - `warm_tick`: local mode, continuing: the tip goes round a circle of 20 mm radius through
//!   its start position, 1 mm per tick, each answer the next pose (so the links sweep toward
//!   the discs and lean on them). A tick that does not converge (a target the body cannot
//!   follow to) keeps the pose; how many did is printed.
//! - `cold`: the cold solve (all its starts) to a target 20% of the reach away from the start
//!   pose's tip, 16 seeded cases cycled, each case's discs drawn around its own start pose and
//!   its target kept 3 cm from every disc.
//!
//! - `validate`: [`World::new`] of the most polygon points a world may hold (1024): one star
//!   of 1024 points, and sixteen 64-gons in a grid (what `set_world` checks in a tick).
//!
//! Before each group a probe times every tick (warm, 2000 ticks) or case (cold, median of 3
//! runs each) on its own and prints the median, its ratio to the same n without obstacles
//! (warm: also the 99th percentile and the longest tick), the mean iterations and how many did
//! not converge.
#![allow(missing_docs, clippy::unwrap_used)]

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use snakectl::chain::{Chain, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::world::{Obstacle, Shape, World};

const SIZES: [usize; 2] = [12, 24];
const OBSTACLES: [usize; 3] = [0, 4, 16];
const LINK_RADIUS: f64 = 0.012;
const CLEARANCE: f64 = 0.005;
/// Radius of the warm ticks' circle, m.
const RADIUS: f64 = 0.02;

fn arm(n: usize, rng: &mut StdRng) -> (Chain, Vec<f64>) {
    let chain = Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
    let spread = PI / n as f64;
    let theta = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
    (chain, theta)
}

/// `count` discs beside the links of `theta` (see the module doc); `None` for no obstacles.
fn world_near(chain: &Chain, theta: &[f64], count: usize, rng: &mut StdRng) -> Option<World> {
    if count == 0 {
        return None;
    }
    let pts = chain.points(theta);
    let n = chain.len();
    loop {
        let obstacles: Vec<Obstacle> = (0..count)
            .map(|k| {
                let link = 1 + (k * n) / count + rng.gen_range(0..(n / count).max(1));
                let link = link.min(n);
                let (a, b) = (pts[link - 1], pts[link]);
                let along = a + (b - a) * rng.gen_range(0.2..0.8);
                let dir = (b - a).normalize();
                let side = if k % 2 == 0 { 1.0 } else { -1.0 };
                let normal = Vec2::new(-dir.y, dir.x) * side;
                let radius = rng.gen_range(0.01..0.03);
                let gap = LINK_RADIUS + CLEARANCE + rng.gen_range(0.002..0.04);
                Obstacle {
                    id: format!("d{k}"),
                    shape: Shape::Circle {
                        center: along + normal * (radius + gap),
                        radius_m: radius,
                    },
                }
            })
            .collect();
        let world = World::new(LINK_RADIUS, CLEARANCE, obstacles).unwrap();
        let least = world.pose_clearance(chain, theta).unwrap().clearance_m;
        if least >= CLEARANCE + 0.001 {
            return Some(world);
        }
    }
}

/// The tip going round a 20 mm circle, 1 mm per tick.
struct Walk {
    chain: Chain,
    theta: Vec<f64>,
    out: Vec<f64>,
    solver: Overall,
    centre: Vec2,
    k: usize,
}

impl Walk {
    fn new(n: usize, obstacles: usize, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let (chain, theta) = arm(n, &mut rng);
        let mut solver = Overall::new(OverallOptions::default());
        solver.set_world(world_near(&chain, &theta, obstacles, &mut rng));
        let centre = chain.tip(&theta) - Vec2::new(RADIUS, 0.0);
        Self {
            out: vec![0.0; n],
            chain,
            theta,
            solver,
            centre,
            k: 0,
        }
    }

    /// One tick; returns the iterations and whether it converged.
    fn tick(&mut self) -> (usize, bool) {
        self.k += 1;
        let a = self.k as f64 * (0.001 / RADIUS);
        let target = self.centre + Vec2::new(a.cos(), a.sin()) * RADIUS;
        let o = self
            .solver
            .solve_local(&self.chain, &self.theta, target, &mut self.out);
        if o.converged {
            self.theta.copy_from_slice(&self.out);
        }
        (o.iterations, o.converged)
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn warm(c: &mut Criterion) {
    let mut group = c.benchmark_group("world/warm_tick");
    for n in SIZES {
        let mut base = 0.0;
        for count in OBSTACLES {
            let seed = 500 + n as u64;
            let mut probe = Walk::new(n, count, seed);
            let (mut times, mut its, mut missed) = (Vec::new(), 0, 0);
            for _ in 0..2000 {
                let t = Instant::now();
                let (i, ok) = black_box(probe.tick());
                times.push(t.elapsed().as_secs_f64());
                its += i;
                missed += usize::from(!ok);
            }
            let med = median(&mut times);
            if count == 0 {
                base = med;
            }
            println!(
                "warm tick n = {n}, {count} obstacles: median {:.2} us, {:.2}x without, \
                 p99 {:.1} us, longest {:.1} us, iterations mean {:.2}, {missed} of 2000 not \
                 converged",
                med * 1e6,
                med / base,
                times[1979] * 1e6,
                times[1999] * 1e6,
                its as f64 / 2000.0
            );
            let mut walk = Walk::new(n, count, seed);
            group.bench_with_input(
                BenchmarkId::new(format!("{count}_obstacles"), n),
                &n,
                |b, _| b.iter(|| black_box(walk.tick())),
            );
        }
    }
    group.finish();
}

struct Case {
    chain: Chain,
    theta0: Vec<f64>,
    target: Vec2,
    world: Option<World>,
}

fn cold_cases(n: usize, count: usize, seed: u64) -> Vec<Case> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut cases = Vec::new();
    while cases.len() < 16 {
        let (chain, theta0) = arm(n, &mut rng);
        let tip = chain.tip(&theta0);
        let a: f64 = rng.gen_range(-PI..PI);
        let target = tip + Vec2::new(a.cos(), a.sin()) * (0.2 * chain.reach());
        if target.norm() > 0.95 * chain.reach() {
            continue;
        }
        // The same discs as with 16 obstacles, `count` of them spread along the arm, so that
        // the cases differ only in the obstacles.
        let world = world_near(&chain, &theta0, 16, &mut rng).unwrap();
        let far = world.point_distance(target).is_some_and(|(d, _)| d >= 0.03);
        if !far {
            continue;
        }
        let world = (count > 0).then(|| {
            let some = (0..count)
                .map(|k| world.obstacles()[k * 16 / count].clone())
                .collect();
            World::new(LINK_RADIUS, CLEARANCE, some).unwrap()
        });
        cases.push(Case {
            chain,
            theta0,
            target,
            world,
        });
    }
    cases
}

fn cold(c: &mut Criterion) {
    let mut group = c.benchmark_group("world/cold");
    for n in SIZES {
        let mut base = 0.0;
        for count in OBSTACLES {
            let cases = cold_cases(n, count, 700 + n as u64);
            let mut solvers: Vec<Overall> = cases
                .iter()
                .map(|case| {
                    let mut s = Overall::new(OverallOptions::default());
                    s.set_world(case.world.clone());
                    s
                })
                .collect();
            let mut out = vec![0.0; n];
            let (mut times, mut its, mut missed) = (Vec::new(), 0, 0);
            for (case, solver) in cases.iter().zip(&mut solvers) {
                let mut runs = [0.0; 3];
                for r in &mut runs {
                    let t = Instant::now();
                    let o = solver.solve_cold(&case.chain, &case.theta0, case.target, &mut out);
                    *r = t.elapsed().as_secs_f64();
                    its += o.iterations;
                    missed += usize::from(!o.converged);
                }
                times.push(median(&mut runs));
            }
            let med = median(&mut times);
            if count == 0 {
                base = med;
            }
            println!(
                "cold n = {n}, {count} obstacles: median {:.1} us, {:.2}x without, iterations \
                 mean {:.1}, {} of {} not converged",
                med * 1e6,
                med / base,
                its as f64 / (3 * cases.len()) as f64,
                missed / 3,
                cases.len()
            );
            let mut k = 0;
            group.bench_with_input(
                BenchmarkId::new(format!("{count}_obstacles"), n),
                &n,
                |b, _| {
                    b.iter(|| {
                        let i = k % cases.len();
                        k += 1;
                        let case = &cases[i];
                        black_box(solvers[i].solve_cold(
                            &case.chain,
                            &case.theta0,
                            case.target,
                            &mut out,
                        ))
                    })
                },
            );
        }
    }
    group.finish();
}

/// A star of `n` points round `centre`, radii alternating between `r` and `0.6 r`.
fn star(n: usize, centre: Vec2, r: f64) -> Vec<Vec2> {
    (0..n)
        .map(|k| {
            let a = 2.0 * PI * k as f64 / n as f64;
            let r = if k % 2 == 0 { r } else { 0.6 * r };
            centre + Vec2::new(a.cos(), a.sin()) * r
        })
        .collect()
}

fn validate(c: &mut Criterion) {
    let polygon = |id: String, points| Obstacle {
        id,
        shape: Shape::Polygon { points },
    };
    let one_star = vec![polygon("star".into(), star(1024, Vec2::new(0.0, 0.5), 0.3))];
    let grid: Vec<Obstacle> = (0..16)
        .map(|k| {
            let centre = Vec2::new(-0.6 + 0.4 * (k % 4) as f64, 0.2 + 0.3 * (k / 4) as f64);
            polygon(format!("g{k}"), star(64, centre, 0.1))
        })
        .collect();
    let mut group = c.benchmark_group("world/validate");
    for (name, obstacles) in [("star_1024", one_star), ("grid_16x64", grid)] {
        group.bench_function(name, |b| {
            b.iter(|| World::new(LINK_RADIUS, CLEARANCE, black_box(obstacles.clone())).unwrap())
        });
    }
    group.finish();
}

fn config() -> Criterion {
    Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
}

criterion_group! {
    name = benches;
    config = config();
    targets = warm, cold, validate
}
criterion_main!(benches);
