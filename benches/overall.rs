//! Overall-strategy benchmarks: `cargo bench --bench overall`.
//!
//! Setup, fixed so figures compare across n: a 1 m arm of n equal links, relative angles uniform
//! in +-(pi/n) (seeded).
//! - `warm_tick`: local mode, continuing: every tick moves the tip 1 mm in a random direction
//!   from the current pose and the answer becomes the next pose (the move is radial, back
//!   toward the middle, when the tip would leave 0.2..0.95 of the reach). The stored multiplier carries over.
//! - `cold`: the cold solve (all its starts) to a target 20% of the reach away from the start
//!   pose's tip, 32 seeded cases cycled.
//!
//! - `cold_limits`: at n = 8 and 16, the same 32 seeded cold problems (start angles uniform in
//!   +-0.3 rad, target the tip of a curled pose with angles of one sign, 0.1..0.35 rad, so reachable within
//!   every variant's limits) solved three ways: without limits, with limits of
//!   +-2 rad (none active at any optimum: checked and printed), and with limits of +-0.35 rad
//!   (active at the optimum: the number of such cases is printed). Before the criterion runs, a
//!   probe times every case on its own (median of 5 runs per case) and prints the median over
//!   the cases, the ratios limited / unlimited, and the mean iterations.
//!
//! Iterations per solve are printed before each group from a separate run of the same cases.
#![allow(missing_docs, clippy::unwrap_used)]

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::time::Instant;

use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};

const SIZES: [usize; 6] = [8, 16, 32, 64, 256, 1024];

fn arm(n: usize, rng: &mut StdRng) -> (Chain, Vec<f64>) {
    let chain = Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
    let spread = PI / n as f64;
    let theta = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
    (chain, theta)
}

/// A continuing 1 mm walk of the tip.
struct Walk {
    chain: Chain,
    theta: Vec<f64>,
    out: Vec<f64>,
    solver: Overall,
    rng: StdRng,
}

impl Walk {
    fn new(n: usize, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let (chain, theta) = arm(n, &mut rng);
        Self {
            out: vec![0.0; n],
            chain,
            theta,
            solver: Overall::new(OverallOptions::default()),
            rng,
        }
    }

    /// One tick; returns the iterations it took.
    fn tick(&mut self) -> usize {
        let tip = self.chain.tip(&self.theta);
        let a: f64 = self.rng.gen_range(-PI..PI);
        let mut target = tip + Vec2::new(a.cos(), a.sin()) * 1e-3;
        let r = target.norm();
        if !(0.2..=0.95).contains(&r) {
            // Head radially back toward the middle of the band.
            let inward = if r > 0.95 { -1.0 } else { 1.0 };
            target = tip + tip.normalize() * (inward * 1e-3);
        }
        let o = self
            .solver
            .solve_local(&self.chain, &self.theta, target, &mut self.out);
        assert!(o.converged, "tick failed: {o:?}");
        self.theta.copy_from_slice(&self.out);
        o.iterations
    }
}

fn cold_cases(n: usize, seed: u64) -> (Chain, Vec<(Vec<f64>, Vec2)>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let (chain, _) = arm(n, &mut rng);
    let mut cases = Vec::new();
    while cases.len() < 32 {
        let (_, theta) = arm(n, &mut rng);
        let tip = chain.tip(&theta);
        let a: f64 = rng.gen_range(-PI..PI);
        let target = tip + Vec2::new(a.cos(), a.sin()) * (0.2 * chain.reach());
        if target.norm() <= 0.95 * chain.reach() {
            cases.push((theta, target));
        }
    }
    (chain, cases)
}

fn summary(label: &str, its: &[usize]) {
    let mut sorted = its.to_vec();
    sorted.sort_unstable();
    let mean = its.iter().sum::<usize>() as f64 / its.len() as f64;
    println!(
        "{label}: iterations per solve mean {mean:.2}, median {}, max {} ({} solves)",
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1],
        its.len()
    );
}

fn warm(c: &mut Criterion) {
    let mut group = c.benchmark_group("overall/warm_tick");
    for n in SIZES {
        let mut probe = Walk::new(n, 100 + n as u64);
        let its: Vec<usize> = (0..500).map(|_| probe.tick()).collect();
        summary(&format!("warm tick n = {n}"), &its);
        let mut walk = Walk::new(n, 100 + n as u64);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| black_box(walk.tick()))
        });
    }
    group.finish();
}

fn cold(c: &mut Criterion) {
    let mut group = c.benchmark_group("overall/cold");
    for n in SIZES {
        let (chain, cases) = cold_cases(n, 200 + n as u64);
        let mut solver = Overall::new(OverallOptions::default());
        let mut out = vec![0.0; n];
        let mut its = Vec::new();
        let mut missed = 0;
        for (theta0, target) in &cases {
            let o = solver.solve_cold(&chain, theta0, *target, &mut out);
            missed += usize::from(!o.converged);
            its.push(o.iterations);
        }
        summary(
            &format!("cold n = {n} (all starts, {missed} not converged)"),
            &its,
        );
        let mut k = 0;
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let (theta0, target) = &cases[k % cases.len()];
                k += 1;
                black_box(solver.solve_cold(&chain, theta0, *target, &mut out))
            })
        });
    }
    group.finish();
}

/// The three variants of `cold_limits`: name and joint limit (none, inactive, active).
const VARIANTS: [(&str, Option<f64>); 3] = [
    ("unlimited", None),
    ("inactive_2rad", Some(2.0)),
    ("active_0.35rad", Some(0.35)),
];

/// Seeded problems for `cold_limits`: start poses and targets, shared by the three variants.
fn limit_cases(n: usize, seed: u64) -> Vec<(Vec<f64>, Vec2)> {
    let mut rng = StdRng::seed_from_u64(seed);
    let chain = Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
    let mut cases = Vec::new();
    while cases.len() < 32 {
        let theta: Vec<f64> = (0..n).map(|_| rng.gen_range(-0.3..0.3)).collect();
        // A curled goal (one sign, 0.1..0.35 rad per joint) pushes the optimum onto limits.
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        let goal: Vec<f64> = (0..n).map(|_| sign * rng.gen_range(0.1..0.35)).collect();
        cases.push((theta, chain.tip(&goal)));
    }
    cases
}

fn limited_arm(n: usize, limit: Option<f64>) -> Chain {
    let limits = limit.map_or(Vec::new(), |l| vec![Some(JointLimit { lo: -l, hi: l }); n]);
    Chain::new(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0, limits).unwrap()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn cold_limits(c: &mut Criterion) {
    let mut group = c.benchmark_group("overall/cold_limits");
    for n in [8usize, 16] {
        let cases = limit_cases(n, 300 + n as u64);
        let mut base_median = 0.0;
        for (name, limit) in VARIANTS {
            let chain = limited_arm(n, limit);
            let mut solver = Overall::new(OverallOptions::default());
            let mut out = vec![0.0; n];
            let (mut its, mut times) = (Vec::new(), Vec::new());
            let (mut missed, mut active) = (0, 0);
            for (theta0, target) in &cases {
                let mut runs = [0.0; 5];
                for r in &mut runs {
                    let t = Instant::now();
                    black_box(solver.solve_cold(&chain, theta0, *target, &mut out));
                    *r = t.elapsed().as_secs_f64();
                }
                times.push(median(&mut runs));
                let o = solver.solve_cold(&chain, theta0, *target, &mut out);
                missed += usize::from(!o.converged);
                its.push(o.iterations);
                let at_limit = limit.is_some_and(|l| out.iter().any(|t| t.abs() >= l - 1e-12));
                active += usize::from(at_limit);
            }
            let med = median(&mut times);
            if limit.is_none() {
                base_median = med;
            }
            let mean = its.iter().sum::<usize>() as f64 / its.len() as f64;
            println!(
                "cold_limits n = {n} {name}: median {:.1} us, {:.2}x unlimited, iterations mean \
                 {mean:.1}, {active} of {} with a limit active, {missed} not converged",
                med * 1e6,
                med / base_median,
                cases.len()
            );
            let mut k = 0;
            group.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| {
                    let (theta0, target) = &cases[k % cases.len()];
                    k += 1;
                    black_box(solver.solve_cold(&chain, theta0, *target, &mut out))
                })
            });
        }
    }
    group.finish();
}

fn config() -> Criterion {
    Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
}

criterion_group! {
    name = benches;
    config = config();
    targets = warm, cold, cold_limits
}
criterion_main!(benches);
