//! The overall strategy against the sequential one on small moves.
//!
//! For a tip move of up to 5% of the reach, the overall solve in local mode (started from
//! theta0) minimizes metric 3 over every pose with the tip on target and the joints within
//! limits. The sequential answer is one such pose whenever it is on target and within the
//! limits, so the overall metric 3 must never exceed it.
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::resolve::sequential::{Sequential, SequentialOptions};
use snakectl::resolve::Resolver;

fn metric3(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn overall_metric3_never_above_sequential(
        seed in 0u64..1_000_000_000,
        n in 2usize..=64,
        limited in proptest::bool::ANY,
        fraction in 0.0f64..=0.05,
        bearing in -3.2f64..3.2,
    ) {
        let mut rng = StdRng::seed_from_u64(seed);
        let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.5..1.5)).collect();
        let base = Vec2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
        let heading = rng.gen_range(-3.0..3.0);
        let spread = 2.0 * std::f64::consts::PI / n as f64;
        let limits: Vec<Option<JointLimit>> = if limited {
            (0..n)
                .map(|_| {
                    let w = rng.gen_range(spread..(2.0 * spread).max(0.6));
                    Some(JointLimit { lo: -w, hi: w })
                })
                .collect()
        } else {
            Vec::new()
        };
        let chain = Chain::new(links, base, heading, limits).unwrap();
        let theta0: Vec<f64> = (0..n)
            .map(|a| {
                let t = rng.gen_range(-spread..spread);
                chain.limits()[a].map_or(t, |l| 0.9 * l.clamp(t))
            })
            .collect();
        let tip = chain.tip(&theta0);
        let target = tip + Vec2::new(bearing.cos(), bearing.sin()) * (fraction * chain.reach());

        // The sequential tip as tight as round-off allows: a pose off target by its default
        // tolerance (1e-11 m) can undercut the true optimum's metric 3 by about 1e-9 relative.
        let mut sequential = Sequential::new(SequentialOptions {
            tolerance_m: 0.0,
            ..SequentialOptions::default()
        });
        let mut seq = vec![0.0; n];
        let s = sequential.solve(&chain, &theta0, target, &mut seq);
        // And the overall tip as tight too: off target by its default 1e-12 of the scale, its
        // metric 3 can sit 1e-9 relative above the optimum's on a tiny move (regression seed).
        let mut overall = Overall::new(OverallOptions {
            tip_tolerance: 1e-14,
            ..OverallOptions::default()
        });
        let mut ovr = vec![0.0; n];
        let o = overall.solve_local(&chain, &theta0, target, &mut ovr);

        prop_assert!(chain.check_limits(&ovr).is_ok());
        let seq_valid = s.converged && s.tip_error <= 1e-9 && chain.check_limits(&seq).is_ok();
        if seq_valid {
            prop_assert!(o.converged && o.reachable, "overall missed a reachable target: {:?}", o);
            let m_seq = metric3(&seq, &theta0);
            let m_ovr = metric3(&ovr, &theta0);
            prop_assert!(
                m_ovr <= m_seq * (1.0 + 1e-9) + 1e-15,
                "overall {} above sequential {}", m_ovr, m_seq
            );
        }
    }
}

/// Regression: a nearly folded two-link arm (elbow at 3.107 rad) moved 4% of its reach. The
/// local path from theta0 stayed on its side of the fold (metric 3 = 0.575) while the mirrored
/// elbow reaches the same tip with 0.447, the sequential answer; the local solve now checks the
/// mirror image of its answer.
#[test]
fn local_solve_near_the_fold_takes_the_cheaper_mirror_branch() {
    // The case the property test found (seed 392964460, n = 2, unlimited, 4.19% of the reach
    // at bearing 2.923), regenerated the same way.
    let mut rng = StdRng::seed_from_u64(392_964_460);
    let links: Vec<f64> = (0..2).map(|_| rng.gen_range(0.5..1.5)).collect();
    let base = Vec2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
    let heading = rng.gen_range(-3.0..3.0);
    let chain = Chain::unlimited(links, base, heading).unwrap();
    let spread = std::f64::consts::PI;
    let theta0 = [
        rng.gen_range(-spread..spread),
        rng.gen_range(-spread..spread),
    ];
    assert!((theta0[1] - 3.107257835059823).abs() < 1e-12, "{theta0:?}");
    let bearing = 2.923_408_310_226_351_5_f64;
    let target = chain.tip(&theta0)
        + Vec2::new(bearing.cos(), bearing.sin()) * (0.041_853_428_445_124_5 * chain.reach());
    let mut seq = [0.0; 2];
    let s = Sequential::new(SequentialOptions {
        tolerance_m: 0.0,
        ..SequentialOptions::default()
    })
    .solve(&chain, &theta0, target, &mut seq);
    assert!(s.converged);
    let mut ovr = [0.0; 2];
    let o = Overall::new(OverallOptions::default()).solve_local(&chain, &theta0, target, &mut ovr);
    assert!(o.converged);
    assert!(
        metric3(&ovr, &theta0) <= metric3(&seq, &theta0) * (1.0 + 1e-9),
        "overall {ovr:?} sequential {seq:?}"
    );
}

/// Regression: a 57-link arm moved 4.8% of its reach to a target 3e-5 of the reach inside its
/// outer edge. The sequential answer converged there; the overall local solve crawled to its
/// iteration cap 7 mm off and called the target unreachable (the property test above found it
/// with seed 928672545; the move here is rounded, and fails the same way).
#[test]
fn local_solve_reaches_a_target_at_the_outer_edge() {
    let n = 57;
    let mut rng = StdRng::seed_from_u64(928_672_545);
    let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.5..1.5)).collect();
    let base = Vec2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
    let heading = rng.gen_range(-3.0..3.0);
    let chain = Chain::unlimited(links, base, heading).unwrap();
    let spread = 2.0 * std::f64::consts::PI / n as f64;
    let theta0: Vec<f64> = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
    let bearing = -0.3763_f64;
    let target =
        chain.tip(&theta0) + Vec2::new(bearing.cos(), bearing.sin()) * (0.0478 * chain.reach());
    let inside = 1.0 - (target - chain.base()).norm() / chain.reach();
    assert!(inside > 0.0 && inside < 4e-5, "{inside}");
    let mut seq = vec![0.0; n];
    let s = Sequential::new(SequentialOptions {
        tolerance_m: 0.0,
        ..SequentialOptions::default()
    })
    .solve(&chain, &theta0, target, &mut seq);
    assert!(s.converged && s.tip_error <= 1e-9, "{s:?}");
    let mut ovr = vec![0.0; n];
    let o = Overall::new(OverallOptions::default()).solve_local(&chain, &theta0, target, &mut ovr);
    assert!(o.converged && o.reachable, "{o:?}");
    assert!((chain.tip(&ovr) - target).norm() <= 1e-9, "{o:?}");
    assert!(
        metric3(&ovr, &theta0) <= metric3(&seq, &theta0) * (1.0 + 1e-9),
        "overall {} sequential {}",
        metric3(&ovr, &theta0),
        metric3(&seq, &theta0)
    );
}
