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
//! Iterations per solve are printed before each group from a separate run of the same cases.
#![allow(missing_docs, clippy::unwrap_used)]

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, Vec2};
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

fn config() -> Criterion {
    Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
}

criterion_group! {
    name = benches;
    config = config();
    targets = warm, cold
}
criterion_main!(benches);
