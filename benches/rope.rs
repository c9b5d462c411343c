//! Free-rope benchmarks: `cargo bench --bench rope`.
//!
//! A 1,000-link rope (1 m, lying on one period of a sine of amplitude 0.1 m) whose end is pulled
//! 0.3 m sideways in 100 equal steps; one iteration of the benchmark is the whole 100-step pull,
//! so the time per step is the reported time divided by 100. Strategies: sequential tractrix,
//! sequential distance step, and the overall optimizer with each objective.
#![allow(missing_docs, clippy::unwrap_used)]

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use snakectl::chain::Vec2;
use snakectl::resolve::sequential::pull_free;
use snakectl::resolve::tractrix::Propagation;
use snakectl::rope::{Objective, RopeOptimizer};

const LINKS: usize = 1000;
const STEPS: usize = 100;

fn rope() -> (Vec<Vec2>, Vec<f64>) {
    let len = 1.0 / LINKS as f64;
    let mut pts = vec![Vec2::zeros()];
    for k in 0..LINKS {
        let x = k as f64 * len;
        let a = (0.2 * std::f64::consts::PI * (2.0 * std::f64::consts::PI * x).cos()).atan();
        pts.push(pts[k] + Vec2::new(a.cos(), a.sin()) * len);
    }
    (pts, vec![len; LINKS])
}

fn bench(c: &mut Criterion) {
    let (start, links) = rope();
    let target = start[LINKS] + Vec2::new(0.0, 0.3);
    let mut group = c.benchmark_group(format!("rope n={LINKS}, {STEPS} steps"));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(8));
    for prop in [Propagation::Tractrix, Propagation::Distance] {
        let mut scratch = Vec::new();
        group.bench_function(format!("sequential {}", prop.name()), |b| {
            b.iter(|| {
                let mut pts = start.clone();
                pull_free(&mut pts, &links, target, STEPS, prop, &mut scratch);
                black_box(pts[0])
            })
        });
    }
    let objectives = [
        Objective::M1,
        Objective::M2,
        Objective::M3 {
            companion_weight: 1.0,
        },
        Objective::M4,
        Objective::M5 {
            companion_weight: 1.0,
        },
    ];
    for objective in objectives {
        let mut opt = RopeOptimizer::default();
        let mut pts = start.clone();
        let r = opt
            .pull(&mut pts, &links, target, STEPS, objective)
            .unwrap();
        eprintln!(
            "overall {}: {} Newton iterations over {} stages for {STEPS} steps, converged {}",
            objective.name(),
            r.iterations,
            r.stages,
            r.converged
        );
        group.bench_function(format!("overall {}", objective.name()), |b| {
            b.iter(|| {
                let mut pts = start.clone();
                let r = opt.pull(&mut pts, &links, target, STEPS, objective);
                black_box(r.map(|r| r.iterations).unwrap_or(0))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
