//! Measures fixed-base correction rounds per solve on random poses and targets, for both
#![allow(clippy::unwrap_used)]
//! correction schemes: `cargo run --release --example correction_rounds`.
use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, Vec2};
use snakectl::resolve::sequential::{Correction, Sequential, SequentialOptions};
use snakectl::resolve::tractrix::Propagation;
use snakectl::resolve::Resolver;
use std::f64::consts::PI;

fn main() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    for n in [2usize, 4, 10, 32] {
        for (label, lo, hi) in [
            ("tick 1 mm", 0.0, 0.0),
            ("ring 5-95%", 0.05, 0.95),
            ("ring 90-95%", 0.90, 0.95),
        ] {
            for correction in [Correction::Newton, Correction::Translate] {
                let mut rounds = Vec::new();
                let mut failed = 0;
                for _ in 0..400 {
                    let links = vec![1.0 / n as f64; n];
                    let chain = Chain::unlimited(links, Vec2::zeros(), 0.0).unwrap();
                    let theta0: Vec<f64> = (0..n)
                        .map(|_| rng.gen_range(-PI / n as f64..PI / n as f64) * 2.0)
                        .collect();
                    let target = if hi == 0.0 {
                        let a = rng.gen_range(-PI..PI);
                        chain.tip(&theta0) + Vec2::new(a.cos(), a.sin()) * 1e-3
                    } else {
                        let r = rng.gen_range(lo..hi) * chain.reach();
                        let a = rng.gen_range(-PI..PI);
                        Vec2::new(r * a.cos(), r * a.sin())
                    };
                    let mut s = Sequential::new(SequentialOptions {
                        correction,
                        propagation: Propagation::Tractrix,
                        max_rounds: 2000,
                        ..Default::default()
                    });
                    let mut out = vec![0.0; n];
                    let o = s.solve(&chain, &theta0, target, &mut out);
                    if o.converged {
                        rounds.push(o.iterations)
                    } else {
                        failed += 1
                    }
                }
                rounds.sort();
                let q = |f: f64| {
                    rounds
                        .get(((rounds.len() as f64 - 1.0) * f) as usize)
                        .copied()
                        .unwrap_or(0)
                };
                println!(
                    "n={n:3} {label:12} {:9}: median {:4} p90 {:4} max {:4} failed {failed}/400",
                    correction.name(),
                    q(0.5),
                    q(0.9),
                    q(1.0)
                );
            }
        }
    }
}
