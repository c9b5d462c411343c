//! The overall free-rope optimizer against hand-computed optima, the sequential strategies and
//! its own promises: exact lengths, the pulled end on target, no drift over long runs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use snakectl::chain::Vec2;
use snakectl::metrics;
use snakectl::resolve::sequential::pull_free;
use snakectl::resolve::tractrix::{distance_step, Propagation};
use snakectl::rope::{residuals, Objective, RopeOptimizer};

fn all_objectives() -> [Objective; 5] {
    [
        Objective::M1,
        Objective::M2,
        Objective::M3 {
            companion_weight: 0.5,
        },
        Objective::M4,
        Objective::M5 {
            companion_weight: 2.0,
        },
    ]
}

/// A rope of n links along a smooth wave, the free end at the origin.
fn wavy(n: usize, seed: u64) -> (Vec<Vec2>, Vec<f64>) {
    let mut pts = vec![Vec2::zeros()];
    let mut links = Vec::new();
    for k in 0..n {
        let a = 0.8 * ((k as f64) * 0.45 + seed as f64).sin();
        let l = 0.1 * (1.0 + 0.3 * ((k * 7 + seed as usize) % 5) as f64 / 5.0);
        pts.push(pts[k] + Vec2::new(a.cos(), a.sin()) * l);
        links.push(l);
    }
    (pts, links)
}

/// One link: the free end's best place is the point of the circle of radius L around the new
/// tip nearest its old place, which is the distance-minimization step, for M1, M2 and M4.
#[test]
fn one_link_optimum_is_the_closest_point_of_the_circle() {
    let old = [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0)];
    let target = Vec2::new(1.3, 0.8);
    let expected = distance_step(old[1], old[0], 1.0, target);
    let mut opt = RopeOptimizer::default();
    for objective in [Objective::M1, Objective::M2, Objective::M4] {
        let mut out = [Vec2::zeros(); 2];
        let r = opt
            .solve(&old, &[1.0], target, objective, &mut out)
            .unwrap();
        assert!(r.converged, "{objective:?} {r:?}");
        assert!(
            (out[0] - expected).norm() < 1e-9,
            "{objective:?}: {:?} vs {expected:?}",
            out[0]
        );
        assert_eq!(out[1], target);
    }
}

/// A straight rope pulled along its own axis by d: each point can move no less than d, so the
/// rigid translation is optimal for every objective: M1 = (n+1) d^2, M2 = Lambda d,
/// M4 = d^2 sum sigma_j, M3 = M5 = 0.
#[test]
fn straight_rope_pulled_along_itself_translates() {
    let n = 6;
    let old: Vec<Vec2> = (0..=n).map(|i| Vec2::new(0.25 * i as f64, 0.0)).collect();
    let links = vec![0.25; n];
    let d = 0.4;
    let target = old[n] + Vec2::new(d, 0.0);
    let sigma_sum: f64 = (0..=n).map(|i| 0.25 * (n - i) as f64).sum();
    let mut opt = RopeOptimizer::default();
    for objective in all_objectives() {
        let mut out = vec![Vec2::zeros(); n + 1];
        let r = opt
            .solve(&old, &links, target, objective, &mut out)
            .unwrap();
        assert!(r.converged, "{objective:?} {r:?}");
        for (p, q) in out.iter().zip(&old) {
            assert!((p - q - Vec2::new(d, 0.0)).norm() < 1e-9, "{objective:?}");
        }
        let m = metrics::rope(&old, &out);
        assert!((m.m1 - (n + 1) as f64 * d * d).abs() < 1e-9, "{m:?}");
        assert!((m.m2 - 1.5 * d).abs() < 1e-9, "{m:?}");
        assert!((m.m4 - d * d * sigma_sum).abs() < 1e-9, "{m:?}");
        assert!(m.m3 < 1e-18 && m.m5 < 1e-18, "{m:?}");
    }
}

/// For every objective, on ropes pulled in several directions: the overall answer is no worse
/// than either sequential one under that objective, keeps every length to 1e-12 and puts the
/// pulled end on target.
#[test]
fn overall_is_no_worse_than_sequential_and_exact() {
    let mut opt = RopeOptimizer::default();
    let mut strict_wins = 0;
    let mut cases = 0;
    for seed in 0..6u64 {
        let (old, links) = wavy(12 + seed as usize * 3, seed);
        let n = links.len();
        for (i, dist) in [0.05, 0.3, 0.9].iter().enumerate() {
            let a = seed as f64 * 1.1 + i as f64 * 2.3;
            let target = old[n] + Vec2::new(a.cos(), a.sin()) * *dist;
            for objective in all_objectives() {
                let mut out = vec![Vec2::zeros(); n + 1];
                let r = opt
                    .solve(&old, &links, target, objective, &mut out)
                    .unwrap();
                assert!(r.converged, "{objective:?} seed {seed}: {r:?}");
                r.check().unwrap();
                let (len_err, tip_err) = residuals(&out, &links, target);
                assert!(
                    len_err <= 1e-12,
                    "{objective:?}: length residual {len_err:e}"
                );
                assert!(tip_err <= 1e-12, "{objective:?}: tip residual {tip_err:e}");
                assert_eq!(r.length_residual, len_err);
                let value = objective.value(&metrics::rope(&old, &out));
                for prop in [Propagation::Tractrix, Propagation::Distance] {
                    let mut seq = old.clone();
                    pull_free(&mut seq, &links, target, 1, prop, &mut Vec::new());
                    let seq_value = objective.value(&metrics::rope(&old, &seq));
                    assert!(
                        value <= seq_value,
                        "{objective:?} seed {seed}: overall {value} > {prop:?} {seq_value}"
                    );
                    if value < seq_value * (1.0 - 1e-6) {
                        strict_wins += 1;
                    }
                }
                cases += 2;
            }
        }
    }
    // The optimum is not just the seed handed back.
    assert!(strict_wins * 10 >= cases * 9, "{strict_wins} of {cases}");
}

/// The Newton iteration converges fast: a handful of iterations per smooth solve.
#[test]
fn iterations_are_few() {
    let (old, links) = wavy(40, 3);
    let n = links.len();
    let target = old[n] + Vec2::new(0.2, 0.3);
    let mut opt = RopeOptimizer::default();
    for objective in all_objectives() {
        let mut out = vec![Vec2::zeros(); n + 1];
        let r = opt
            .solve(&old, &links, target, objective, &mut out)
            .unwrap();
        assert!(r.converged, "{objective:?}: {r:?}");
        let per_stage = r.iterations as f64 / r.stages as f64;
        assert!(per_stage <= 25.0, "{objective:?}: {r:?}");
        if objective == Objective::M2 {
            assert!(r.smoothing > 0.0 && r.smoothing_gap <= 1e-9 * 0.36f64.sqrt() * 5.0);
        } else {
            assert_eq!(r.stages, 1);
        }
    }
}

/// 10^4 small moves along a wandering path: lengths stay exact, for the overall optimizer and
/// the sequential sweep alike.
#[test]
fn no_length_drift_after_ten_thousand_moves() {
    let (start, links) = wavy(8, 1);
    let n = links.len();
    let path = |k: usize| {
        let s = k as f64 * 1e-3;
        start[n] + Vec2::new(0.5 * s.sin() + 0.3 * s, 0.4 * (1.7 * s).sin())
    };
    let mut overall = start.clone();
    let mut seq = start.clone();
    let mut next = start.clone();
    let mut opt = RopeOptimizer::default();
    let mut scratch = Vec::new();
    for k in 1..=10_000 {
        let t = path(k);
        let r = opt
            .solve(&overall, &links, t, Objective::M1, &mut next)
            .unwrap();
        assert!(r.converged, "move {k}: {r:?}");
        overall.copy_from_slice(&next);
        pull_free(&mut seq, &links, t, 1, Propagation::Tractrix, &mut scratch);
    }
    let t = path(10_000);
    let (a, ta) = residuals(&overall, &links, t);
    let (b, tb) = residuals(&seq, &links, t);
    assert!(
        a <= 1e-12 && ta == 0.0,
        "overall: lengths {a:e}, tip {ta:e}"
    );
    assert!(
        b <= 1e-12 && tb == 0.0,
        "sequential: lengths {b:e}, tip {tb:e}"
    );
}

/// Multi-step pulls: the answer after K moves keeps the lengths and reports summed iterations.
#[test]
fn multi_step_pull_reports_summed_iterations() {
    let (old, links) = wavy(15, 2);
    let n = links.len();
    let target = old[n] + Vec2::new(-0.3, 0.5);
    let mut opt = RopeOptimizer::default();
    let mut one = old.clone();
    let r1 = opt
        .pull(&mut one, &links, target, 1, Objective::M2)
        .unwrap();
    let mut many = old.clone();
    let r8 = opt
        .pull(&mut many, &links, target, 8, Objective::M2)
        .unwrap();
    assert!(r1.converged && r8.converged);
    assert!(r8.iterations > r1.iterations);
    assert!(r8.stages >= 8);
    for pts in [&one, &many] {
        let (l, t) = residuals(pts, &links, target);
        assert!(l <= 1e-12 && t <= 1e-12);
    }
    // Path dependence: one step and eight steps end in different places.
    let gap = one
        .iter()
        .zip(&many)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(gap > 1e-6, "{gap:e}");
}
