//! Sequential-strategy benchmarks: `cargo bench --bench resolve`.
//!
//! Setup, fixed so figures compare across n: a 1 m arm of n equal links, relative angles uniform
//! in +-(pi/n) (seeded), and 64 cases cycled per n: a warm tick moves the tip 1 mm in a random
//! direction from its pose; a cold solve moves it to a target 20% of the reach away. Correction
//! rounds per solve are printed before each group.
#![allow(missing_docs, clippy::unwrap_used)]

use std::f64::consts::PI;
use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, Vec2};
use snakectl::resolve::sequential::{Sequential, SequentialOptions};
use snakectl::resolve::Resolver;

pub const SIZES: [usize; 6] = [8, 16, 32, 64, 256, 1024];

/// One benchmark case: a chain, a start pose and a target.
pub struct Case {
    pub theta0: Vec<f64>,
    pub target: Vec2,
}

pub fn cases(n: usize, move_m: f64, seed: u64) -> (Chain, Vec<Case>) {
    let chain = Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut out = Vec::new();
    while out.len() < 64 {
        let bound = PI / n as f64;
        let theta0: Vec<f64> = (0..n).map(|_| rng.gen_range(-bound..bound)).collect();
        let a = rng.gen_range(-PI..PI);
        let target = chain.tip(&theta0) + Vec2::new(a.cos(), a.sin()) * move_m;
        if target.norm() < 0.999 * chain.reach() {
            out.push(Case { theta0, target });
        }
    }
    (chain, out)
}

fn rounds(chain: &Chain, cases: &[Case]) -> (usize, usize) {
    let mut s = Sequential::new(SequentialOptions::default());
    let mut out = vec![0.0; chain.len()];
    let mut r: Vec<usize> = cases
        .iter()
        .map(|c| s.solve(chain, &c.theta0, c.target, &mut out).iterations)
        .collect();
    r.sort_unstable();
    (r[r.len() / 2], r[r.len() - 1])
}

fn bench(c: &mut Criterion) {
    for (label, move_m) in [("warm tick 1 mm", 1e-3), ("cold 20% of reach", 0.2)] {
        let mut group = c.benchmark_group(format!("sequential {label}"));
        for n in SIZES {
            let (chain, cases) = cases(n, move_m, 42 + n as u64);
            let (median, worst) = rounds(&chain, &cases);
            eprintln!("sequential {label} n={n}: correction rounds median {median}, max {worst}");
            let mut s = Sequential::new(SequentialOptions::default());
            let mut out = vec![0.0; n];
            let mut i = 0;
            group.bench_function(BenchmarkId::from_parameter(n), |b| {
                b.iter(|| {
                    let case = &cases[i % cases.len()];
                    i += 1;
                    black_box(s.solve(&chain, &case.theta0, case.target, &mut out))
                })
            });
        }
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = bench
}
criterion_main!(benches);
