//! Both strategies on the same commanded moves: metric 3, tip error and time per solve.
//! `cargo run --release --example compare_strategies`
#![allow(clippy::unwrap_used)]

use std::f64::consts::PI;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, Vec2};
use snakectl::metrics;
use snakectl::resolve::overall::{Overall, OverallMode, OverallOptions};
use snakectl::resolve::sequential::Sequential;
use snakectl::resolve::Resolver;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn main() {
    println!(
        "| n | move | strategy | metric 3 (median) | tip error (max) | converged | time (median) |"
    );
    println!("|---|---|---|---|---|---|---|");
    for n in [8usize, 16, 32] {
        let chain = Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
        for (label, frac, mode) in [
            ("1 mm tick", 0.001, OverallMode::Local),
            ("5% of reach", 0.05, OverallMode::Local),
            ("20% of reach", 0.2, OverallMode::Cold),
        ] {
            let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
            let mut cases = Vec::new();
            while cases.len() < 200 {
                let theta0: Vec<f64> = (0..n)
                    .map(|_| rng.gen_range(-2.0 * PI / n as f64..2.0 * PI / n as f64))
                    .collect();
                let a = rng.gen_range(-PI..PI);
                let target = chain.tip(&theta0) + Vec2::new(a.cos(), a.sin()) * frac;
                if target.norm() < 0.95 {
                    cases.push((theta0, target));
                }
            }
            let mut seq = Sequential::default();
            let mut ovr = Overall::new(OverallOptions {
                mode,
                ..OverallOptions::default()
            });
            let resolvers: [(&str, &mut dyn Resolver); 2] =
                [("sequential", &mut seq), ("overall", &mut ovr)];
            for (name, r) in resolvers {
                let mut m3 = Vec::new();
                let mut times = Vec::new();
                let mut worst: f64 = 0.0;
                let mut ok = 0;
                let mut out = vec![0.0; n];
                for (theta0, target) in &cases {
                    let clock = Instant::now();
                    let o = r.solve(&chain, theta0, *target, &mut out);
                    times.push(clock.elapsed().as_secs_f64() * 1e6);
                    m3.push(metrics::arm(&chain, theta0, &out).m3);
                    worst = worst.max(o.tip_error);
                    ok += o.converged as usize;
                }
                println!(
                    "| {n} | {label} | {name} | {:.3e} | {:.1e} m | {ok}/200 | {:.1} µs |",
                    median(m3),
                    worst,
                    median(times)
                );
            }
        }
    }
}
