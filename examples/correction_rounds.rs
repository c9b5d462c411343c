//! Fixed-base correction rounds per solve on random poses and targets, for both correction
//! schemes and both propagations: `cargo run --release --example correction_rounds`.
#![allow(clippy::unwrap_used)]

use std::f64::consts::PI;

use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, Vec2};
use snakectl::resolve::sequential::{Correction, Sequential, SequentialOptions};
use snakectl::resolve::tractrix::Propagation;
use snakectl::resolve::Resolver;

const CASES: usize = 400;

fn main() {
    println!("| n | targets | propagation | correction | median | p90 | max | not converged |");
    println!("|---|---|---|---|---|---|---|---|");
    for n in [2usize, 4, 10, 32] {
        let bands = [
            ("1 mm tick", 0.0, 0.0),
            ("5-95% of reach", 0.05, 0.95),
            ("90-95% of reach", 0.90, 0.95),
        ];
        for (label, lo, hi) in bands {
            for propagation in [Propagation::Tractrix, Propagation::Distance] {
                for correction in [Correction::Newton, Correction::Translate] {
                    // The same cases for every scheme: one generator per (n, band).
                    let mut rng = rand::rngs::StdRng::seed_from_u64(7 + n as u64);
                    let chain =
                        Chain::unlimited(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0).unwrap();
                    let mut s = Sequential::new(SequentialOptions {
                        correction,
                        propagation,
                        max_rounds: 2000,
                        ..SequentialOptions::default()
                    });
                    let mut rounds = Vec::new();
                    let mut failed = 0;
                    let mut out = vec![0.0; n];
                    for _ in 0..CASES {
                        let bound = 2.0 * PI / n as f64;
                        let theta0: Vec<f64> =
                            (0..n).map(|_| rng.gen_range(-bound..bound)).collect();
                        let a = rng.gen_range(-PI..PI);
                        let target = if hi == 0.0 {
                            chain.tip(&theta0) + Vec2::new(a.cos(), a.sin()) * 1e-3
                        } else {
                            Vec2::new(a.cos(), a.sin()) * rng.gen_range(lo..hi) * chain.reach()
                        };
                        let o = s.solve(&chain, &theta0, target, &mut out);
                        if o.converged {
                            rounds.push(o.iterations);
                        } else {
                            failed += 1;
                        }
                    }
                    rounds.sort_unstable();
                    let q = |f: f64| {
                        let i = ((rounds.len().max(1) - 1) as f64 * f) as usize;
                        rounds.get(i).copied().unwrap_or(0)
                    };
                    println!(
                        "| {n} | {label} | {} | {} | {} | {} | {} | {failed}/{CASES} |",
                        propagation.name(),
                        correction.name(),
                        q(0.5),
                        q(0.9),
                        q(1.0)
                    );
                }
            }
        }
    }
}
