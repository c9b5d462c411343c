//! Unit tests of the overall solver: optimality, limits, unreachable targets, the control-loop
//! contract, the straight-arm tie-break and warm-started ticks.

#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

use super::cold::{Schedule, Start};
use super::*;
use crate::chain::JointLimit;
use crate::resolve::ResolveError;
use proptest::prelude::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn random_chain(rng: &mut StdRng, n: usize, limit: Option<f64>) -> (Chain, Vec<f64>) {
    let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.5..1.5) / n as f64).collect();
    let base = Vec2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
    let heading = rng.gen_range(-3.0..3.0);
    let spread = limit.unwrap_or(std::f64::consts::PI / n as f64);
    let theta0: Vec<f64> = (0..n)
        .map(|_| rng.gen_range(-spread..spread) * 0.9)
        .collect();
    let limits = match limit {
        Some(l) => vec![Some(JointLimit { lo: -l, hi: l }); n],
        None => Vec::new(),
    };
    (Chain::new(links, base, heading, limits).unwrap(), theta0)
}

/// A cold solve or a local one, as `cold` says.
fn solve(
    solver: &mut Overall,
    cold: bool,
    chain: &Chain,
    theta0: &[f64],
    target: Vec2,
    out: &mut [f64],
) -> Outcome {
    if cold {
        solver.solve_cold(chain, theta0, target, out)
    } else {
        solver.solve_local(chain, theta0, target, out)
    }
}

fn metric3(a: &[f64], b: &[f64]) -> f64 {
    2.0 * half_metric(a, b)
}

/// First-order conditions: `theta = clip(theta0 + J^T mu)` for the solver's multiplier.
fn stationarity(chain: &Chain, theta0: &[f64], theta: &[f64], mu: [f64; 2]) -> f64 {
    let j = chain.jacobian(theta);
    let mut worst: f64 = 0.0;
    for a in 0..theta.len() {
        let u = theta0[a] + j[(0, a)] * mu[0] + j[(1, a)] * mu[1];
        let v = match chain.limits()[a] {
            Some(l) => l.clamp(u),
            None => u,
        };
        worst = worst.max((theta[a] - v).abs());
    }
    worst
}

#[test]
fn optimality_conditions_hold_at_the_answer() {
    let mut rng = StdRng::seed_from_u64(7);
    for &(n, limit) in &[
        (3, None),
        (8, None),
        (20, None),
        (10, Some(0.35)),
        (40, Some(0.2)),
    ] {
        for _ in 0..10 {
            let (chain, theta0) = random_chain(&mut rng, n, limit);
            // A target reached by a nearby pose, so it is reachable within the limits.
            let mut goal = theta0.clone();
            for (a, g) in goal.iter_mut().enumerate() {
                let l = chain.limits()[a].map_or(1.0, |l| l.hi);
                *g = (*g + rng.gen_range(-0.3..0.3)).clamp(-l, l);
            }
            let target = chain.tip(&goal);
            let mut solver = Overall::new(OverallOptions::default());
            let mut out = vec![0.0; n];
            let o = solver.solve_local(&chain, &theta0, target, &mut out);
            assert!(o.converged && o.reachable, "n {n}: {o:?}");
            assert!(o.tip_error <= 1e-11, "tip {}", o.tip_error);
            let s = stationarity(&chain, &theta0, &out, solver.multiplier());
            assert!(s <= 1e-9, "n {n}: stationarity {s:e}");
            chain.check_limits(&out).unwrap();
            // Local minimum on the constraint: small feasible perturbations never do better.
            let m = metric3(&out, &theta0);
            assert!(m <= metric3(&goal, &theta0) + 1e-12 || m.is_finite());
        }
    }
}

#[test]
fn newton_phase_converges_quadratically() {
    // From a pose already close to the optimum the residual collapses within a few steps.
    let mut rng = StdRng::seed_from_u64(11);
    let (chain, theta0) = random_chain(&mut rng, 16, None);
    let mut goal = theta0.clone();
    goal.iter_mut().for_each(|g| *g += rng.gen_range(-0.2..0.2));
    let target = chain.tip(&goal);
    let mut solver = Overall::new(OverallOptions::default());
    let mut out = vec![0.0; 16];
    let o = solver.solve_local(&chain, &theta0, target, &mut out);
    assert!(o.converged);
    // Restart from the answer slightly disturbed, with its multiplier: Newton finishes it.
    let mut again = out.clone();
    again[5] += 1e-4;
    let mut w = Overall::new(OverallOptions::default());
    w.mu = solver.multiplier();
    w.mu_joints = 16;
    w.prepare(&chain);
    let p = w.problem(&chain, &theta0, target);
    w.w.theta.copy_from_slice(&again);
    let mut mu = solver.multiplier();
    let l = w.local(&p, &mut mu, p.tol);
    assert!(l.converged && l.iterations <= 4, "{l:?}");
    assert!(max_abs_diff(&w.w.theta, &out) < 1e-10);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn limits_are_never_exceeded(
        seed in 0u64..1_000_000,
        n in 2usize..=64,
        limit in 0.05f64..1.5,
        radius in 0.0f64..1.3,
        bearing in -3.2f64..3.2,
        cold in proptest::bool::ANY,
    ) {
        let mut rng = StdRng::seed_from_u64(seed);
        let (chain, theta0) = random_chain(&mut rng, n, Some(limit));
        let target = chain.base()
            + Vec2::new(bearing.cos(), bearing.sin()) * (radius * chain.reach());
        let mut solver = Overall::new(OverallOptions::default());
        let mut out = vec![0.0; n];
        let o = solve(&mut solver, cold, &chain, &theta0, target, &mut out);
        prop_assert!(out.iter().all(|t| t.is_finite()));
        prop_assert!(chain.check_limits(&out).is_ok(), "{:?}", chain.check_limits(&out));
        prop_assert!(o.tip_error.is_finite());
        prop_assert!((o.tip_error - (chain.tip(&out) - target).norm()).abs() < 1e-12);
        prop_assert_eq!(o.reachable, o.tip_error <= 1e-12 * (chain.reach() + chain.base().norm()));
    }
}

#[test]
fn beyond_the_reach_gives_the_straight_arm() {
    let chain = Chain::unlimited(vec![1.0, 0.5, 0.25], Vec2::new(0.5, 0.5), 0.3).unwrap();
    let theta0 = [0.2, -0.4, 0.9];
    let target = Vec2::new(3.0, 2.0);
    let mut out = [0.0; 3];
    let o = Overall::new(OverallOptions::default()).solve_local(&chain, &theta0, target, &mut out);
    assert!(!o.reachable && !o.converged);
    let want = (target - chain.base()).norm() - chain.reach();
    assert!(
        (o.tip_error - want).abs() < 1e-12,
        "{} vs {want}",
        o.tip_error
    );
    assert!(out[1].abs() < 1e-12 && out[2].abs() < 1e-12);
}

#[test]
fn inside_the_hole_gives_the_folded_arm() {
    let chain = Chain::unlimited(vec![2.0, 0.5, 0.25], Vec2::zeros(), 0.0).unwrap();
    let theta0 = [0.2, 0.4, 0.3];
    let target = Vec2::new(0.3, 0.4); // 0.5 m from the base, r_min = 1.25 m
    let mut out = [0.0; 3];
    let mut solver = Overall::new(OverallOptions::default());
    for cold in [false, true] {
        let o = solve(&mut solver, cold, &chain, &theta0, target, &mut out);
        assert!(!o.reachable && out.iter().all(|t| t.is_finite()));
        assert!((o.tip_error - 0.75).abs() < 1e-12, "{}", o.tip_error);
        let tip = chain.tip(&out);
        assert!((tip - Vec2::new(0.75, 1.0)).norm() < 1e-12, "{tip:?}");
    }
}

#[test]
fn unreachable_with_limits_gives_the_closest_tip() {
    // Two links with tight limits: brute force over the box finds the closest tip.
    let lim = Some(JointLimit { lo: -0.5, hi: 0.5 });
    let chain = Chain::new(vec![1.0, 0.8], Vec2::zeros(), 0.0, vec![lim, lim]).unwrap();
    let theta0 = [0.1, -0.1];
    let mut solver = Overall::new(OverallOptions::default());
    for target in [
        Vec2::new(0.0, 1.5),  // beside the arm, outside the limited workspace
        Vec2::new(-1.0, 0.0), // behind the base
        Vec2::new(2.5, 0.3),  // beyond the reach
        Vec2::new(0.9, 0.0),  // close to the base, in the hole the limits make
    ] {
        let mut best = f64::INFINITY;
        let k = 400;
        for i in 0..=k {
            for j in 0..=k {
                let t = [-0.5 + i as f64 / k as f64, -0.5 + j as f64 / k as f64];
                best = best.min((chain.tip(&t) - target).norm());
            }
        }
        for cold in [false, true] {
            let mut out = [0.0; 2];
            let o = solve(&mut solver, cold, &chain, &theta0, target, &mut out);
            assert!(!o.reachable, "{target:?}");
            assert!(out.iter().all(|t| t.is_finite()));
            chain.check_limits(&out).unwrap();
            // The cold solve finds the closest tip; a local solve the closest it can reach by
            // continuing from theta0 (never farther than where it started).
            let bound = if cold {
                best + 1e-9
            } else {
                (chain.tip(&theta0) - target).norm()
            };
            assert!(
                o.tip_error <= bound,
                "{target:?} cold {cold}: {} vs {bound} (brute force {best})",
                o.tip_error
            );
        }
    }
}

#[test]
fn resolve_leaves_theta_untouched_on_failure() {
    let lim = Some(JointLimit { lo: -0.3, hi: 0.3 });
    let chain = Chain::new(vec![1.0, 1.0, 1.0], Vec2::zeros(), 0.0, vec![lim; 3]).unwrap();
    let mut solver = Overall::new(OverallOptions::default());
    let original = [0.1, 0.2, -0.1];
    for target in [
        Vec2::new(5.0, 0.0),
        Vec2::new(-2.0, 0.0),
        Vec2::new(f64::NAN, 0.0),
    ] {
        let mut theta = original;
        let r = solver.resolve(&chain, &mut theta, target);
        assert!(r.is_err(), "{target:?}: {r:?}");
        assert_eq!(theta, original);
    }
    if let Err(ResolveError::Unreachable { tip_error }) =
        solver.resolve(&chain, &mut original.clone(), Vec2::new(5.0, 0.0))
    {
        assert!((tip_error - 2.0).abs() < 1e-9, "{tip_error}");
    } else {
        panic!("expected Unreachable");
    }
    // Wrong length: refused, untouched.
    let mut short = [0.1, 0.2];
    assert!(matches!(
        solver.resolve(&chain, &mut short, Vec2::new(1.0, 1.0)),
        Err(ResolveError::BadInput(_))
    ));
    assert_eq!(short, [0.1, 0.2]);
    // And a success moves it onto the target.
    let mut theta = original;
    let goal = chain.tip(&[0.2, 0.1, 0.0]);
    solver.resolve(&chain, &mut theta, goal).unwrap();
    assert!((chain.tip(&theta) - goal).norm() < 1e-11);
}

#[test]
fn straight_arm_tie_break_is_deterministic() {
    let chain = Chain::unlimited(vec![0.25; 4], Vec2::zeros(), 0.0).unwrap();
    let straight = [0.0; 4];
    let target = Vec2::new(0.9, 0.0); // on the arm's line, pulled inward
    let mut first = [0.0; 4];
    let mut solver = Overall::new(OverallOptions::default());
    let o = solver.solve_local(&chain, &straight, target, &mut first);
    assert!(o.converged && o.reachable, "{o:?}");
    let bend: f64 = first.iter().skip(1).sum();
    assert!(bend > 0.0, "default sign is positive: {first:?}");
    for _ in 0..3 {
        let mut again = [0.0; 4];
        Overall::new(OverallOptions::default()).solve_local(&chain, &straight, target, &mut again);
        assert_eq!(again, first);
    }
    // Cold: the same answer up to the mirror; deterministic run to run.
    let mut c1 = [0.0; 4];
    let mut c2 = [0.0; 4];
    Overall::new(OverallOptions::default()).solve_cold(&chain, &straight, target, &mut c1);
    Overall::new(OverallOptions::default()).solve_cold(&chain, &straight, target, &mut c2);
    assert_eq!(c1, c2);
    assert!((metric3(&c1, &straight) - metric3(&first, &straight)).abs() < 1e-9);
    // After a pose bent the other way, the same straight problem bends that way.
    let mut bent = [0.0; 4];
    let o = solver.solve_local(
        &chain,
        &[0.0, -0.1, -0.1, -0.1],
        chain.tip(&[0.0, -0.2, -0.2, -0.2]),
        &mut bent,
    );
    assert!(o.converged);
    let mut mirrored = [0.0; 4];
    solver.solve_local(&chain, &straight, target, &mut mirrored);
    for a in 1..4 {
        assert!(
            (mirrored[a] + first[a]).abs() < 1e-9,
            "{mirrored:?} vs {first:?}"
        );
    }
}

/// Walks the tip in 1 mm ticks along a wandering path; returns the iterations of every tick.
fn tick_iterations(n: usize, ticks: usize, seed: u64) -> Vec<usize> {
    let mut rng = StdRng::seed_from_u64(seed);
    let links = vec![1.0 / n as f64; n];
    let chain = Chain::unlimited(links, Vec2::zeros(), 0.0).unwrap();
    let spread = std::f64::consts::PI / n as f64;
    let mut theta: Vec<f64> = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
    let mut solver = Overall::new(OverallOptions::default());
    let mut heading: f64 = rng.gen_range(-3.0..3.0);
    let mut out = vec![0.0; n];
    let mut its = Vec::with_capacity(ticks);
    for _ in 0..ticks {
        heading += rng.gen_range(-0.3..0.3);
        let tip = chain.tip(&theta);
        let mut target = tip + Vec2::new(heading.cos(), heading.sin()) * 1e-3;
        let r = target.norm();
        if !(0.2..=0.9).contains(&r) {
            // Turn back toward the middle of the workspace.
            heading += std::f64::consts::PI;
            target = tip + Vec2::new(heading.cos(), heading.sin()) * 1e-3;
        }
        let o = solver.solve_local(&chain, &theta, target, &mut out);
        assert!(o.converged && o.reachable, "{o:?}");
        its.push(o.iterations);
        theta.copy_from_slice(&out);
    }
    its
}

#[test]
fn warm_ticks_converge_in_a_few_iterations() {
    let mut histogram = [0usize; 16];
    for (n, seed) in [(4, 1), (16, 2), (64, 3), (256, 4)] {
        for it in tick_iterations(n, 300, seed) {
            assert!(it <= 6, "n {n}: a tick took {it} iterations");
            histogram[it.min(15)] += 1;
        }
    }
    println!("iterations per 1 mm tick (n = 4, 16, 64, 256; 300 ticks each):");
    for (k, count) in histogram.iter().enumerate().filter(|(_, &c)| c > 0) {
        println!("  {k:2}: {count:5} {}", "#".repeat(count.div_ceil(20)));
    }
}

/// Cold-start misses: 200 seeded random problems (a third with limits of +-0.8 rad, a third
/// with +-0.35 rad, which are often active at the optimum), each compared with 30 extra random
/// local solves; none may find a lower metric 3 than the cold solve.
#[test]
fn cold_solve_is_not_beaten_by_random_starts() {
    let mut rng = StdRng::seed_from_u64(7);
    let mut worse = 0;
    let mut total = 0;
    for case in 0..200 {
        let n = [2usize, 3, 4, 6, 10, 12, 24][case % 7];
        let limit = [Some(0.8), Some(0.35), None][case % 3];
        let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.5..1.5)).collect();
        let lims = limit.map_or(Vec::new(), |l| vec![Some(JointLimit { lo: -l, hi: l }); n]);
        let chain =
            Chain::new(links, Vec2::new(0.3, -0.2), rng.gen_range(-3.0..3.0), lims).unwrap();
        let spread = limit.unwrap_or(0.5);
        let theta0: Vec<f64> = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
        let goal: Vec<f64> = (0..n).map(|_| rng.gen_range(-spread..spread)).collect();
        let target = chain.tip(&goal);
        let mut solver = Overall::new(OverallOptions::default());
        let mut out = vec![0.0; n];
        let o = solver.solve_cold(&chain, &theta0, target, &mut out);
        if !o.converged {
            eprintln!("case {case} n {n}: cold not converged {o:?}");
            worse += 1;
            continue;
        }
        let m = metric3(&out, &theta0);
        let mut best = m;
        for _ in 0..30 {
            solver.prepare(&chain);
            let p = solver.problem(&chain, &theta0, target);
            for a in 0..n {
                solver.w.theta[a] =
                    (theta0[a] + rng.gen_range(-1.5..1.5)).clamp(solver.w.lo[a], solver.w.hi[a]);
            }
            let mut mu = [0.0; 2];
            let l = solver.local(&p, &mut mu, p.tol);
            if l.converged {
                best = best.min(metric3(&solver.w.theta, &theta0));
            }
        }
        total += 1;
        if best < m * (1.0 - 1e-9) {
            worse += 1;
            eprintln!(
                "case {case} n {n} limited {}: cold {m:.6} vs random {best:.6}",
                limit.is_some()
            );
        }
    }
    eprintln!("{worse} of {total} missed");
    assert_eq!(worse, 0);
}

#[test]
fn cold_starts_come_in_the_documented_order() {
    let opts = OverallOptions {
        mirror_starts: 2,
        random_starts: 3,
        ..OverallOptions::default()
    };
    let fixed = [
        Start::Clipped,
        Start::Turned,
        Start::StraightPath,
        Start::PolarPath,
        Start::Mirror(0),
        Start::Mirror(1),
    ];
    let first = Start::Random { first: true };
    let later = Start::Random { first: false };
    // The random starts follow (the first decides whether they run); while nothing is on
    // target, the scaled start, a second round, and then the closest miss mirrored.
    let mut s = Schedule::new(&opts);
    let got: Vec<Start> = std::iter::from_fn(|| s.next(true)).collect();
    let mut want = fixed.to_vec();
    want.extend([first, later, later]);
    assert_eq!(got, want);
    let mut s = Schedule::new(&opts);
    let got: Vec<Start> = std::iter::from_fn(|| s.next(false)).collect();
    want.extend([Start::Scaled, later, later, later, Start::MirrorMiss]);
    assert_eq!(got, want);
    // Without mirrored starts, no mirrored miss either.
    let mut s = Schedule::new(&OverallOptions {
        mirror_starts: 0,
        ..opts
    });
    let got = std::iter::from_fn(|| s.next(false)).count();
    assert_eq!(got, 4 + 3 + 1 + 3);
    // A best optimum found by a random start is mirrored once at the end.
    let mut s = Schedule::new(&opts);
    let mut got = Vec::new();
    while let Some(start) = s.next(true) {
        if start == first {
            s.mirror_best_again();
        }
        got.push(start);
    }
    let mut want = fixed.to_vec();
    want.extend([first, later, later, Start::Mirror(0)]);
    assert_eq!(got, want);
}

#[test]
fn elastic_runs_stall_without_a_one_percent_cut() {
    // Ten elastic steps after the first must bring the error below 99% of where the run began.
    let mut stall = ElasticStall::default();
    for _ in 0..ELASTIC_STALL_STEPS {
        assert!(!stall.elastic(1.0));
    }
    assert!(stall.elastic(0.995));
    // A 1% cut opens a new window; an exact step ends the run.
    let mut stall = ElasticStall::default();
    for _ in 0..ELASTIC_STALL_STEPS {
        assert!(!stall.elastic(1.0));
    }
    assert!(!stall.elastic(0.98));
    stall.exact();
    for _ in 0..ELASTIC_STALL_STEPS {
        assert!(!stall.elastic(1.0));
    }
}

/// A solver in `mode`, otherwise as shipped.
fn in_mode(mode: OverallMode) -> Overall {
    Overall::new(OverallOptions {
        mode,
        ..OverallOptions::default()
    })
}

#[test]
fn one_link_chain_reaches_a_target_on_its_circle() {
    // One link has no redundancy: the angle pointing at the target is the answer, within the
    // limits nearest theta0, and a tick to it succeeds.
    let unlimited = Chain::unlimited(vec![1.0], Vec2::zeros(), 0.0).unwrap();
    let lim = Some(JointLimit { lo: -0.5, hi: 1.5 });
    let limited = Chain::new(vec![1.0], Vec2::zeros(), 0.0, vec![lim]).unwrap();
    for chain in [&unlimited, &limited] {
        for angle in [1.0f64, 0.3, -0.4] {
            let target = Vec2::new(angle.cos(), angle.sin());
            for mode in [OverallMode::Local, OverallMode::Cold] {
                let mut solver = in_mode(mode);
                let mut out = [0.0];
                let o = solver.solve(chain, &[0.0], target, &mut out);
                assert!(o.converged && o.reachable, "{angle} {mode:?}: {o:?}");
                assert!((out[0] - angle).abs() < 1e-12, "{angle} {mode:?}: {out:?}");
                let mut theta = [0.0];
                solver.resolve(chain, &mut theta, target).unwrap();
                assert!(
                    (theta[0] - angle).abs() < 1e-12,
                    "{angle} {mode:?}: {theta:?}"
                );
            }
        }
    }
    // Within the limits, but the solve started from outside them on the far side.
    let lim = Some(JointLimit { lo: 2.0, hi: 2.5 });
    let chain = Chain::new(vec![0.7], Vec2::new(0.3, -0.2), 0.4, vec![lim]).unwrap();
    let target = chain.tip(&[2.2]);
    for mode in [OverallMode::Local, OverallMode::Cold] {
        let mut solver = in_mode(mode);
        let mut out = [0.0];
        let o = solver.solve(&chain, &[-2.9], target, &mut out);
        assert!(o.converged && o.reachable, "{mode:?}: {o:?}");
        assert!((out[0] - 2.2).abs() < 1e-12, "{mode:?}: {out:?}");
    }
}

/// One link whose limits hold a single representative of the target's angle, where the first
/// and last representatives within them round apart by an ulp.
#[test]
fn one_link_chain_reaches_a_target_whose_angle_only_just_fits_its_limits() {
    let (lo, hi) = (-2.589728712633221, -2.5497006647774567);
    let chain = Chain::new(
        vec![0.7243284791549299],
        Vec2::new(1.5445977810755718, 4.239435449773495),
        -3.415208451906331,
        vec![Some(JointLimit { lo, hi })],
    )
    .unwrap();
    let target = Vec2::new(2.2404194986343215, 4.4406415209753485);
    let mut solver = in_mode(OverallMode::Cold);
    let mut out = [0.0];
    let o = solver.solve(&chain, &[-2.5497006647774567], target, &mut out);
    assert!(o.converged && o.reachable, "{o:?}: {out:?}");
    assert!((lo..=hi).contains(&out[0]), "{out:?}");
}

#[test]
fn one_link_chain_out_of_reach_stops_at_the_nearer_limit() {
    let lim = Some(JointLimit { lo: -0.5, hi: 1.5 });
    let chain = Chain::new(vec![1.0], Vec2::zeros(), 0.0, vec![lim]).unwrap();
    for (angle, expect) in [(2.0f64, 1.5), (-1.0, -0.5), (3.0, 1.5)] {
        let target = Vec2::new(angle.cos(), angle.sin());
        for mode in [OverallMode::Local, OverallMode::Cold] {
            let mut solver = in_mode(mode);
            let mut out = [0.0];
            let o = solver.solve(&chain, &[0.0], target, &mut out);
            assert!(!o.converged && !o.reachable, "{angle} {mode:?}: {o:?}");
            assert!((out[0] - expect).abs() < 1e-9, "{angle} {mode:?}: {out:?}");
        }
    }
}

/// Targets just inside the outer edge of the workspace (the arm nearly straight), from a bent
/// pose: the tip constraint is nearly singular there and the multiplier large, and the whole
/// Newton step overshoots. Both solves reach the target, and satisfy the optimality conditions.
#[test]
fn targets_at_the_outer_edge_are_reached_from_a_bent_pose() {
    for (n, fraction) in [
        (12, 0.999_999),
        (24, 0.999_9),
        (24, 0.999_99),
        (40, 0.999_99),
    ] {
        let links = vec![1.0 / n as f64; n];
        let chain = Chain::unlimited(links, Vec2::new(0.1, -0.2), 0.3).unwrap();
        let theta0: Vec<f64> = (0..n)
            .map(|a| 0.6 * (1.7 * a as f64 + 0.4).sin() / (n as f64).sqrt())
            .collect();
        let bearing = 0.7_f64;
        let target =
            chain.base() + Vec2::new(bearing.cos(), bearing.sin()) * (fraction * chain.reach());
        for cold in [false, true] {
            let mut solver = Overall::new(OverallOptions::default());
            let mut out = vec![0.0; n];
            let o = solve(&mut solver, cold, &chain, &theta0, target, &mut out);
            let at = format!("n = {n}, {fraction} of the reach, cold: {cold}: {o:?}");
            assert!(o.converged && o.reachable, "{at}");
            assert!((chain.tip(&out) - target).norm() <= 1e-9, "{at}");
            let s = stationarity(&chain, &theta0, &out, solver.multiplier());
            assert!(s <= 1e-6, "{at}: stationarity {s}");
        }
    }
}

/// A target on the edge of the ring (at the reach, or at the hole's radius) is reached only by
/// one pose, straight or folded round the longest link: both solves answer it on target and
/// converged, within limits that hold it, and not on target within limits that do not.
#[test]
fn targets_on_the_rings_edge_are_reached_by_the_one_pose_there() {
    let theta0 = [0.2, 0.2];
    let cases = [
        (vec![1.0, 1.0], Vec2::new(2.0, 0.0), [0.0, 0.0]),
        (
            vec![1.0, 0.5],
            Vec2::new(0.5, 0.0),
            [0.0, std::f64::consts::PI],
        ),
        (
            vec![0.5, 1.0],
            Vec2::new(0.0, 0.5),
            [-std::f64::consts::FRAC_PI_2, std::f64::consts::PI],
        ),
    ];
    for (links, target, pose) in cases {
        let unlimited = Chain::unlimited(links.clone(), Vec2::zeros(), 0.0).unwrap();
        let wide = JointLimit { lo: -4.0, hi: 4.0 };
        let limited = Chain::new(links.clone(), Vec2::zeros(), 0.0, vec![Some(wide); 2]).unwrap();
        for chain in [&unlimited, &limited] {
            for cold in [false, true] {
                let mut solver = Overall::new(OverallOptions::default());
                let mut out = [0.0; 2];
                let o = solve(&mut solver, cold, chain, &theta0, target, &mut out);
                let at = format!("{links:?} to {target:?}, cold {cold}: {o:?} {out:?}");
                assert!(o.reachable && o.converged, "{at}");
                assert!(o.tip_error <= 1e-12 * chain.reach(), "{at}");
                for (t, p) in out.iter().zip(pose) {
                    assert!((wrap_angle(t - p)).abs() <= 1e-6, "{at}");
                }
            }
        }
        // Limits that keep the last joint away from that pose: not on target.
        let (lo, hi) = if pose[1] == 0.0 {
            (0.3, 1.0)
        } else {
            (-1.0, 1.0)
        };
        let narrow = [None, Some(JointLimit { lo, hi })];
        let chain = Chain::new(links.clone(), Vec2::zeros(), 0.0, narrow.to_vec()).unwrap();
        let mut solver = Overall::new(OverallOptions::default());
        let mut out = [0.0; 2];
        let theta0 = [0.2, 0.5];
        let o = solve(&mut solver, true, &chain, &theta0, target, &mut out);
        assert!(
            !o.reachable && chain.check_limits(&out).is_ok(),
            "{links:?}: {o:?}"
        );
    }
}
