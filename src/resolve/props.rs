//! Property tests of both resolvers against independent forward kinematics: the promises every
//! answer keeps on random chains, starts and targets, edge cases included, and the cold overall
//! optimum against the two elbows of a two-link chain.

#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

use std::f64::consts::{PI, TAU};

use proptest::prelude::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::overall::{Overall, OverallMode, OverallOptions};
use super::sequential::Sequential;
use super::{ResolveError, Resolver};
use crate::chain::{Chain, JointLimit, Vec2};

/// Forward kinematics written out here: base, heading, links and relative angles to the tip.
fn fk_tip(links: &[f64], base: Vec2, heading: f64, theta: &[f64]) -> Vec2 {
    let mut phi = heading;
    let (mut x, mut y) = (base.x, base.y);
    for (l, t) in links.iter().zip(theta) {
        phi += t;
        x += l * phi.cos();
        y += l * phi.sin();
    }
    Vec2::new(x, y)
}

fn tip_of(chain: &Chain, theta: &[f64]) -> Vec2 {
    fk_tip(chain.links(), chain.base(), chain.heading(), theta)
}

fn within(chain: &Chain, theta: &[f64]) -> bool {
    chain
        .limits()
        .iter()
        .zip(theta)
        .all(|(l, t)| t.is_finite() && l.is_none_or(|l| l.lo <= *t && *t <= l.hi))
}

fn scale(chain: &Chain) -> f64 {
    chain.reach() + chain.base().norm()
}

struct Case {
    chain: Chain,
    theta0: Vec<f64>,
    target: Vec2,
    /// A pose within the limits whose tip is the target, when one is known.
    witness: Option<Vec<f64>>,
}

fn random_case(seed: u64, n: usize, kind: u8) -> Case {
    let mut rng = StdRng::seed_from_u64(seed);
    let unit = [0.01, 0.3, 1.0, 5.0][rng.gen_range(0..4)];
    let mut links: Vec<f64> = (0..n).map(|_| unit * rng.gen_range(0.05..1.0)).collect();
    if rng.gen_bool(0.2) {
        let k = rng.gen_range(0..n);
        links[k] *= n as f64;
    }
    let base = Vec2::new(rng.gen_range(-5.0..5.0), rng.gen_range(-5.0..5.0));
    let heading = rng.gen_range(-10.0..10.0);
    let p_limit = [0.0, 0.5, 1.0][rng.gen_range(0..3)];
    let limits = random_limits(&mut rng, n, p_limit, 3.0, 0.01..3.5);
    let chain = Chain::new(links, base, heading, limits.clone()).unwrap();
    let inside = |rng: &mut StdRng| -> Vec<f64> {
        limits
            .iter()
            .map(|l| match l {
                Some(l) => match rng.gen_range(0..5) {
                    0 => l.lo,
                    1 => l.hi,
                    _ => rng.gen_range(l.lo..l.hi),
                },
                None => rng.gen_range(-PI..PI),
            })
            .collect()
    };
    let mut theta0 = inside(&mut rng);
    if rng.gen_bool(0.2) {
        // A start outside its limits.
        for t in theta0.iter_mut() {
            *t += rng.gen_range(-4.0..4.0);
        }
    }
    let b = chain.base();
    let r = chain.reach();
    let dir = rng.gen_range(-PI..PI);
    let u = Vec2::new(dir.cos(), dir.sin());
    let mut witness = None;
    let target = match kind % 9 {
        0 => {
            let w = inside(&mut rng);
            let t = tip_of(&chain, &w);
            witness = Some(w);
            t
        }
        1 => b,
        2 => b + u * r,
        3 => b + u * (r * rng.gen_range(1.0..3.0)),
        4 => b + u * (r * rng.gen_range(0.0f64..1.2).sqrt()),
        5 => {
            let t = tip_of(&chain, &theta0);
            if within(&chain, &theta0) {
                witness = Some(theta0.clone());
            }
            t
        }
        6 => {
            let mut w = inside(&mut rng);
            // Straight, within limits where that is possible.
            for (a, t) in w.iter_mut().enumerate() {
                *t = match chain.limits()[a] {
                    Some(l) if a > 0 => l.clamp(0.0),
                    _ if a > 0 => 0.0,
                    _ => *t,
                };
            }
            let t = tip_of(&chain, &w);
            witness = Some(w);
            t
        }
        7 => b + u * (r * 1e-9),
        _ => tip_of(&chain, &theta0) + u * (r * 1e-4),
    };
    Case {
        chain,
        theta0,
        target,
        witness,
    }
}

/// Every promise an answer makes, checked against the independent kinematics.
fn check_answer(
    name: &str,
    case: &Case,
    o: &super::Outcome,
    out: &[f64],
    tol: f64,
    limits_promised: bool,
) -> Result<(), TestCaseError> {
    let chain = &case.chain;
    prop_assert!(out.iter().all(|t| t.is_finite()), "{name}: {out:?}");
    let miss = (tip_of(chain, out) - case.target).norm();
    prop_assert!(o.tip_error.is_finite(), "{name}: {o:?}");
    prop_assert!(
        (o.tip_error - miss).abs() <= 1e-12 * scale(chain) + 1e-9 * miss,
        "{name}: reported {} measured {miss}",
        o.tip_error
    );
    if o.converged {
        prop_assert!(o.reachable, "{name}: {o:?}");
        prop_assert!(
            miss <= tol + 1e-14 * scale(chain),
            "{name}: converged with the tip {miss} m off (tolerance {tol}): {o:?}"
        );
        if limits_promised {
            prop_assert!(
                within(chain, out),
                "{name}: converged outside limits {out:?}"
            );
        }
    }
    if limits_promised {
        prop_assert!(within(chain, out), "{name}: answer outside limits {out:?}");
    }
    // Never closer than any pose can be: the unlimited ring bounds the tip's distance.
    let d = (case.target - chain.base()).norm();
    let longest = chain.links().iter().cloned().fold(0.0, f64::max);
    let floor = (d - chain.reach())
        .max(2.0 * longest - chain.reach() - d)
        .max(0.0);
    prop_assert!(
        miss >= floor - 1e-9 * scale(chain),
        "{name}: {miss} < {floor}"
    );
    Ok(())
}

fn check_resolve<R: Resolver>(
    name: &str,
    r: &mut R,
    case: &Case,
    tol: f64,
) -> Result<(), TestCaseError> {
    let chain = &case.chain;
    let mut theta = case.theta0.clone();
    match r.resolve(chain, &mut theta, case.target) {
        Ok(o) => {
            prop_assert!(
                within(chain, &theta),
                "{name}: resolved outside limits {theta:?}"
            );
            let miss = (tip_of(chain, &theta) - case.target).norm();
            prop_assert!(
                miss <= tol + 1e-14 * scale(chain),
                "{name}: resolved with the tip {miss} off: {o:?}"
            );
        }
        Err(e) => {
            prop_assert_eq!(&theta, &case.theta0, "{}: {}", name, e);
            if let ResolveError::Limit(v) = &e {
                prop_assert!(v.joint >= 1 && v.joint <= chain.len());
            }
        }
    }
    Ok(())
}

/// The same cases on every run: a wider search (`with_cases` raised by hand) is how the rare
/// misses named on each test were found.
fn fixed(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(fixed(300, 1))]

    #[test]
    fn every_answer_keeps_its_promises(
        seed in 0u64..u64::MAX, n in 1usize..=64, kind in 0u8..9,
    ) {
        let case = random_case(seed, n, kind);
        let chain = &case.chain;
        let s = scale(chain);
        let otol = 1e-12 * s;
        let mut out = vec![0.0; n];
        for mode in [OverallMode::Local, OverallMode::Cold] {
            let mut solver = Overall::new(OverallOptions { mode, ..OverallOptions::default() });
            let o = solver.solve(chain, &case.theta0, case.target, &mut out);
            check_answer(&format!("overall {mode:?}"), &case, &o, &out, otol, true)?;
            // A straight witness sits on the edge of the workspace, where no multiplier exists
            // and the tip closes in slowly: only the promises above are asked of it.
            if mode == OverallMode::Cold && case.witness.is_some() && kind % 9 != 6 {
                prop_assert!(o.reachable && o.converged,
                    "cold missed a target within the limits: {:?} witness {:?}", o, case.witness);
            }
            check_resolve(&format!("overall {mode:?} resolve"), &mut solver, &case, otol)?;
        }
        let mut seq = Sequential::default();
        let stol = 2.0 * 1e-11f64.max(16.0 * f64::EPSILON
            * (chain.base().norm() + chain.reach() + case.target.norm()));
        let o = seq.solve(chain, &case.theta0, case.target, &mut out);
        check_answer("sequential", &case, &o, &out, stol, false)?;
        check_resolve("sequential resolve", &mut seq, &case, stol)?;
    }
}

/// The least metric 3 over the poses of a two-link chain with the tip on `target`, the
/// representative of each angle within its limits nearest `theta0`; `None` when no pose is
/// on target within the limits.
fn wrap_near(a: f64, lim: Option<JointLimit>, near: f64) -> Option<f64> {
    // Representatives a + 2 pi k within the limits; the nearest to `near`.
    let base = near + (a - near).rem_euclid(TAU);
    let mut best: Option<f64> = None;
    for k in -3i32..=3 {
        let v = base + TAU * f64::from(k);
        if lim.is_some_and(|l| !l.contains(v)) {
            continue;
        }
        if best.is_none_or(|b| (v - near).abs() < (b - near).abs()) {
            best = Some(v);
        }
    }
    if best.is_none() {
        if let Some(l) = lim {
            // Wide limits far from `near`: search around them.
            let base = l.lo + (a - l.lo).rem_euclid(TAU);
            if l.contains(base) {
                best = Some(base);
            }
        }
    }
    best
}

/// Two-link inverse kinematics in absolute terms: the absolute angles of both links for each
/// elbow, from the base point `b` to `target`.
fn two_link(b: Vec2, l1: f64, l2: f64, target: Vec2) -> Vec<(f64, f64)> {
    let d = target - b;
    let r2 = d.norm_squared();
    let r = r2.sqrt();
    if r > l1 + l2 || r < (l1 - l2).abs() || r == 0.0 {
        return Vec::new();
    }
    let c = ((r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)).clamp(-1.0, 1.0);
    let q2 = c.acos();
    let bearing = d.y.atan2(d.x);
    let mut v = Vec::new();
    for q in [q2, -q2] {
        let q1 = bearing - (l2 * q.sin()).atan2(l1 + l2 * q.cos());
        v.push((q1, q1 + q));
    }
    v
}

/// The best metric 3 over the poses of a two-link chain on target (its two elbows), each
/// angle the representative within its limits nearest `theta0`.
fn best_on_target(chain: &Chain, theta0: &[f64], target: Vec2) -> f64 {
    let links = chain.links();
    let lim = chain.limits();
    let h = chain.heading();
    let mut best = f64::INFINITY;
    for (a1, a2) in two_link(chain.base(), links[0], links[1], target) {
        let mut prev = h;
        let mut m = 0.0;
        let mut within = true;
        for (a, abs) in [a1, a2].into_iter().enumerate() {
            let Some(t) = wrap_near(abs - prev, lim[a], theta0[a]) else {
                within = false;
                break;
            };
            m += (t - theta0[a]).powi(2);
            prev = abs;
        }
        if within {
            best = best.min(m);
        }
    }
    best
}

/// The global optimum of metric 3 on target within the limits, of a two-link chain: the
/// better of its two elbows.
fn brute_force_optimum(chain: &Chain, theta0: &[f64], target: Vec2) -> f64 {
    assert_eq!(chain.len(), 2, "two links");
    best_on_target(chain, theta0, target)
}

/// `n` joint limits, each drawn with probability `p`: its centre within `±centre`, its
/// half-width in `half_width`.
fn random_limits(
    rng: &mut StdRng,
    n: usize,
    p: f64,
    centre: f64,
    half_width: std::ops::Range<f64>,
) -> Vec<Option<JointLimit>> {
    (0..n)
        .map(|_| {
            rng.gen_bool(p).then(|| {
                let c = rng.gen_range(-centre..centre);
                let w = rng.gen_range(half_width.clone());
                JointLimit {
                    lo: c - w,
                    hi: c + w,
                }
            })
        })
        .collect()
}

/// A random chain of `n` links (each joint limited with probability 0.7 when `limited`), a
/// start and a goal pose within the limits (anywhere for an unlimited joint).
fn random_pose_case(seed: u64, n: usize, limited: bool) -> (Chain, Vec<f64>, Vec<f64>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.2..1.0)).collect();
    let base = Vec2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
    let heading = rng.gen_range(-4.0..4.0);
    let limits = if limited {
        random_limits(&mut rng, n, 0.7, 2.5, 0.2..2.5)
    } else {
        vec![None; n]
    };
    let chain = Chain::new(links, base, heading, limits.clone()).unwrap();
    let pose = |rng: &mut StdRng| -> Vec<f64> {
        limits
            .iter()
            .map(|l| match l {
                Some(l) => rng.gen_range(l.lo..l.hi),
                None => rng.gen_range(-PI..PI),
            })
            .collect()
    };
    let theta0 = pose(&mut rng);
    let goal = pose(&mut rng);
    (chain, theta0, goal)
}

proptest! {
    #![proptest_config(fixed(200, 2))]

    /// Two-link chains, unlimited and limited (each joint limited with probability 0.7), goal
    /// poses anywhere within the limits. A wide search (`cold_optimum_miss_counts`: 100,000
    /// cases of each) finds 5 unlimited and 6 limited misses where the goal's elbow is within
    /// 2.3e-4 rad of straight or of folded back (the edge of the workspace): both elbows nearly
    /// coincide there, the Jacobian nearly loses rank and the multiplier grows as its inverse,
    /// so the stationarity tolerance (1e-11 rad) is below the round-off of `J^T mu` and the
    /// solve stops 5e-12 to 6e-8 m off the target, not converged, or (once) converges at the
    /// other elbow, 7e-4 above the optimum.
    #[test]
    fn cold_solve_finds_the_global_optimum_of_two_links(
        seed in 0u64..u64::MAX, n in 2usize..=2, limited in proptest::bool::ANY,
    ) {
        let (chain, theta0, goal) = random_pose_case(seed, n, limited);
        let target = tip_of(&chain, &goal);
        let (o, out, m) = cold_solve(&chain, &theta0, target);
        let brute = brute_force_optimum(&chain, &theta0, target);
        prop_assert!(brute.is_finite(), "the goal pose is on target: {goal:?}");
        prop_assert!(o.converged, "{o:?}");
        prop_assert!(within(&chain, &out));
        prop_assert!((tip_of(&chain, &out) - target).norm() <= 1e-11);
        prop_assert!(
            m <= brute * (1.0 + 1e-6) + 1e-9,
            "cold metric 3 {m} above the optimum {brute}: theta0 {theta0:?} target {target:?} \
             out {out:?} chain {chain:?}"
        );
    }
}

#[test]
fn cold_optimum_is_not_left_whole_turns_away_from_the_start() {
    // Two links, unlimited: the optimum is one of the two elbows with each angle the
    // representative nearest theta0. Local paths from the cold starts end whole turns away.
    let links = [0.21016946090124958, 0.9580344792097548];
    let chain = Chain::unlimited(
        links.to_vec(),
        Vec2::new(0.48355884935939963, -0.11416052361941986),
        3.536199169747956,
    )
    .unwrap();
    let theta0 = [0.025726353255837164, -2.6767362512547574];
    let target = Vec2::new(1.5663513710286951, -0.552432346057645);
    let best = brute_force_optimum(&chain, &theta0, target);
    let (o, out, m) = cold_solve(&chain, &theta0, target);
    assert!(o.converged, "{o:?}");
    assert!(
        m <= best * (1.0 + 1e-9),
        "metric 3 {m} above the optimum {best}: {out:?}"
    );
    for (a, b) in out.iter().zip(&theta0) {
        assert!((a - b).abs() <= PI + 1e-9, "{out:?}");
    }
}

/// A cold solve from a fresh solver (its tie-break at straight poses remembers the last
/// answer): the outcome, the pose and its metric 3.
fn cold_solve(chain: &Chain, theta0: &[f64], target: Vec2) -> (super::Outcome, Vec<f64>, f64) {
    let mut solver = Overall::new(OverallOptions {
        mode: OverallMode::Cold,
        ..OverallOptions::default()
    });
    let mut out = vec![0.0; chain.len()];
    let o = solver.solve(chain, theta0, target, &mut out);
    let m = out.iter().zip(theta0).map(|(a, b)| (a - b).powi(2)).sum();
    (o, out, m)
}

/// A cold solve on a two-link `chain` from `theta0` to `target`: the answer and its metric 3,
/// which must be on target within the limits and within 1e-9 of `best`.
fn assert_cold_reaches(chain: &Chain, theta0: &[f64], target: Vec2, best: f64) {
    let (o, out, m) = cold_solve(chain, theta0, target);
    assert!(o.converged, "{o:?} {out:?}");
    assert!(within(chain, &out), "{out:?}");
    assert!(
        m <= best * (1.0 + 1e-9),
        "metric 3 {m} above the optimum {best}: {out:?}"
    );
}

#[test]
fn cold_solve_reaches_a_target_only_one_elbow_can_reach() {
    // The other elbow's shoulder or elbow angle lies beyond a limit. Every start ended on that
    // limit, on the side of the elbow ruled out, 4e-3 to 0.26 m off; twice the reachable elbow
    // is within 0.04 rad of its own limit, a narrow window for a random start. The mirror image
    // of the closest miss lands on the other side. (Cases of `cold_optimum_miss_counts`.)
    let limit = |lo, hi| Some(JointLimit { lo, hi });
    let cases = [
        (
            [0.6272589528614549, 0.6393401044228386],
            Vec2::new(-0.7041077933679394, 0.5190478779086294),
            -1.5187716610481647,
            [
                limit(-0.8214084669125696, 0.32772510337469885),
                limit(-4.028986864177028, 0.1942619709204234),
            ],
            [0.20928443784254647, -2.818511218194696],
            Vec2::new(-0.24646139689922042, -0.6576768329759818),
        ),
        (
            [0.9282433903825194, 0.5377478141815137],
            Vec2::new(0.3293700395415229, -0.41298746754754756),
            -0.9443041319172547,
            [None, limit(-1.6425563052578043, 3.1603391176559943)],
            [-2.823180608586845, -0.24351071416144032],
            Vec2::new(1.0493912691799514, -0.10408623686575724),
        ),
        (
            [0.9144365395285099, 0.943873900523331],
            Vec2::new(0.9088617982776621, 0.8916082112679606),
            0.5601010237975537,
            [
                limit(-1.6846842256363015, 2.4134230441802984),
                limit(-3.424318424373187, 0.14888783647341008),
            ],
            [-1.2888115952925432, -0.43067124218442343],
            Vec2::new(-0.9118108584488316, 1.240975191612414),
        ),
    ];
    for (links, base, heading, limits, theta0, target) in cases {
        let chain = Chain::new(links.to_vec(), base, heading, limits.to_vec()).unwrap();
        let best = brute_force_optimum(&chain, &theta0, target);
        assert!(best.is_finite(), "reachable");
        assert_cold_reaches(&chain, &theta0, target, best);
    }
}

#[test]
fn cold_start_already_at_the_optimum_is_kept() {
    // Two links, unlimited: the mirror start is exactly the better elbow, on target with no step
    // left. Its residual was measured with the zero multiplier it started from, so it was
    // turned back as not optimal and the worse elbow (metric 3 4.64 against 1.40) kept.
    let chain = Chain::unlimited(
        vec![0.5842065032977075, 0.7040829998560236],
        Vec2::new(0.6972098916719593, 0.8712848582714168),
        -3.33136343218629,
    )
    .unwrap();
    let theta0 = [1.3388683897857865, 3.0080512028532675];
    let target = Vec2::new(0.22829073076011996, 0.6294604793326883);
    let best = brute_force_optimum(&chain, &theta0, target);
    assert_cold_reaches(&chain, &theta0, target, best);
}

fn limit(lo: f64, hi: f64) -> Option<JointLimit> {
    Some(JointLimit { lo, hi })
}

#[test]
fn cold_mirror_takes_the_turn_within_the_limits() {
    // The better elbow's base angle lies a whole turn below the representative nearest theta0,
    // which is beyond the upper limit: clipped there, the mirror start never reached it.
    let chain = Chain::new(
        vec![0.8710881022031791, 0.3429572737705746],
        Vec2::new(-0.5774769731817666, 0.8058704924031774),
        -1.709618353706313,
        vec![
            limit(-3.466779250309605, 1.484346881271742),
            limit(-1.241060401754937, 3.3496742677568507),
        ],
    )
    .unwrap();
    let theta0 = [0.4318154836861825, 2.6693425389902394];
    let target = Vec2::new(-1.0997053941511568, 1.7090333976252354);
    let best = brute_force_optimum(&chain, &theta0, target);
    assert_cold_reaches(&chain, &theta0, target, best);
}

#[test]
fn cold_mirrors_an_optimum_a_random_start_found() {
    // No fixed start reaches the target; a random start finds one elbow, and the other (the
    // better) is its mirror image, which the mirrored starts (tried before any optimum was
    // known) never saw.
    let chain = Chain::new(
        vec![0.24000636830579103, 0.4680773947348149],
        Vec2::new(0.5674114589812134, 0.7308411891415849),
        0.009957666007553101,
        vec![
            limit(-2.3808810170475905, 1.4740140396192103),
            limit(-0.17508806708740265, 1.8074023942968276),
        ],
    )
    .unwrap();
    let theta0 = [1.241474879072435, 0.3284122887777823];
    let target = Vec2::new(0.35514795058598037, 0.05643549735147518);
    let best = brute_force_optimum(&chain, &theta0, target);
    assert_cold_reaches(&chain, &theta0, target, best);
}

#[test]
fn cold_pose_short_of_its_optimum_is_turned_back_by_whole_turns() {
    // A target 1.4e-4 rad of bend from the edge of the workspace: no start meets the
    // stationarity tolerance there, and the pose kept stood two whole turns away from theta0
    // (metric 3 186 against 10.5). Turned back, the tip stays and the metric drops.
    let chain = Chain::unlimited(
        vec![0.6346737297568141, 0.9284745564865431],
        Vec2::new(-0.12135531223594187, 0.5431458130368654),
        -0.1369745485444991,
    )
    .unwrap();
    let theta0 = [-1.1939472542587293, -2.087121004398766];
    let target = Vec2::new(0.5253185558027738, 1.9662570041825325);
    let best = brute_force_optimum(&chain, &theta0, target);
    let (o, out, m) = cold_solve(&chain, &theta0, target);
    assert!(o.tip_error <= 1e-7, "{o:?}");
    for (a, b) in out.iter().zip(&theta0) {
        assert!((a - b).abs() <= PI + 1e-9, "{out:?}");
    }
    assert!(
        m <= best * (1.0 + 1e-3),
        "metric 3 {m} against {best}: {out:?}"
    );
}

#[test]
fn cold_random_starts_bend_unlimited_joints_either_way() {
    // The limited base joint must swing to its other side and the unlimited elbow bend the
    // other way (+1.28 from -1.54). Random starts drew that joint within a quarter turn of
    // theta0 only, and every start stalled at the upper limit 0.032 m off the target.
    let chain = Chain::new(
        vec![0.8530056202377494, 0.4053990963294705],
        Vec2::new(-0.028332236673888733, 0.9600877474715608),
        0.25206106632522207,
        vec![limit(-0.3753935311398394, 0.44254486166841545), None],
    )
    .unwrap();
    let theta0 = [0.29512406904577837, -1.535240983269761];
    let target = Vec2::new(0.9505165443053782, 1.3203144935200224);
    let best = brute_force_optimum(&chain, &theta0, target);
    assert!(best.is_finite());
    assert_cold_reaches(&chain, &theta0, target, best);
}

/// The least metric 3 over the poses of an unlimited three-link chain with the tip on
/// `target`: a dense search over the first link's absolute angle (the other two links then
/// have their two elbows, each angle the representative nearest `theta0`), refined by golden
/// section around the best grid points.
fn three_link_optimum(chain: &Chain, theta0: &[f64], target: Vec2) -> f64 {
    assert!(chain.len() == 3 && !chain.is_limited());
    let (l, h, b) = (chain.links(), chain.heading(), chain.base());
    let metric = |phi1: f64, elbow: usize| -> f64 {
        let p1 = b + Vec2::new(l[0] * phi1.cos(), l[0] * phi1.sin());
        let Some(&(a2, a3)) = two_link(p1, l[1], l[2], target).get(elbow) else {
            return f64::INFINITY;
        };
        [phi1 - h, a2 - phi1, a3 - a2]
            .iter()
            .zip(theta0)
            .map(|(t, t0)| (crate::chain::nearest_representative(*t, *t0) - t0).powi(2))
            .sum()
    };
    let steps = 20_000;
    let step = TAU / f64::from(steps);
    let mut grid: Vec<(f64, f64, usize)> = (0..2)
        .flat_map(|e| (0..steps).map(move |k| (-PI + step * f64::from(k), e)))
        .map(|(phi, e)| (metric(phi, e), phi, e))
        .filter(|g| g.0.is_finite())
        .collect();
    grid.sort_by(|a, b| a.0.total_cmp(&b.0));
    let golden = (5f64.sqrt() - 1.0) / 2.0;
    let mut best = f64::INFINITY;
    for &(m, phi, e) in grid.iter().take(40) {
        let (mut lo, mut hi) = (phi - step, phi + step);
        for _ in 0..100 {
            let x1 = hi - golden * (hi - lo);
            let x2 = lo + golden * (hi - lo);
            if metric(x1, e) < metric(x2, e) {
                hi = x2;
            } else {
                lo = x1;
            }
        }
        best = best.min(m).min(metric(0.5 * (lo + hi), e));
    }
    best
}

#[test]
fn cold_solve_finds_the_optimum_around_the_other_side_of_the_base() {
    // Three links, unlimited: the optimum turns the base 2.57 rad one way; every fixed and
    // mirrored start ends at an optimum turning it 3.0 rad the other (metric 3 10.23 against
    // 8.92). The random starts within the ball of that optimum find it.
    let chain = Chain::unlimited(
        vec![0.7312225251689728, 0.8652988525159617, 0.5208500661364126],
        Vec2::new(0.9871635132366099, 0.933783861330614),
        -2.337533269042771,
    )
    .unwrap();
    let theta0 = [2.1573890502421076, 2.2344638976755347, -1.3861804108559752];
    let target = Vec2::new(-0.5266827251500594, 0.12010821193344279);
    let best = three_link_optimum(&chain, &theta0, target);
    assert!((best - 8.923699688868947).abs() < 1e-6, "{best}");
    assert_cold_reaches(&chain, &theta0, target, best * (1.0 + 1e-9));
}

proptest! {
    #![proptest_config(fixed(100, 3))]

    /// Unlimited three-link chains, start and goal poses anywhere, against the dense search.
    /// A wide search (2,000 cases) finds the cold solve above the optimum in 7 (by 1% to 46%):
    /// optima that turn the joints by 1.4 to 2.9 rad (root of metric 3), around the other side
    /// of a joint's turn from the optimum every fixed start reached. In 6 the eight random
    /// starts drawn within that optimum's ball all ran into it; in one the optimum found turned
    /// the joints by less than a quarter turn, so no random start was tried (46 of 2,000 missed
    /// without the random starts).
    #[test]
    fn cold_solve_finds_the_global_optimum_of_three_unlimited_links(seed in 0u64..u64::MAX) {
        let (chain, theta0, goal) = random_pose_case(seed, 3, false);
        let target = tip_of(&chain, &goal);
        let (o, out, m) = cold_solve(&chain, &theta0, target);
        prop_assert!(o.converged, "{o:?}");
        let best = three_link_optimum(&chain, &theta0, target);
        prop_assert!(
            m <= best * (1.0 + 1e-6) + 1e-9,
            "cold metric 3 {m} above the optimum {best}: theta0 {theta0:?} target {target:?} \
             out {out:?} chain {chain:?}"
        );
    }
}

/// How often the cold solve misses the optimum over many seeded cases of the property tests'
/// generator (two links unlimited and limited, 100,000 each; three unlimited links, 2,000):
/// `cargo test --release --lib cold_optimum_miss_counts -- --ignored` fails, listing every
/// miss, when a set misses more than it did when last measured (5, 6 and 7: the causes are on
/// the tests above; set a bound to 0 to list that set's misses). A miss: not converged, the
/// tip more than 1e-11 m off, or metric 3 above the optimum by more than 1e-6 relative. Too
/// slow for every run (20 s): a check by hand after a change to the cold solve.
#[test]
#[ignore]
fn cold_optimum_miss_counts() {
    for (n, limited, cases, measured) in [
        (2, false, 100_000u64, 5),
        (2, true, 100_000, 6),
        (3, false, 2_000, 7),
    ] {
        let mut misses = Vec::new();
        for i in 0..cases {
            // splitmix64's finalizer spreads the case numbers over the seeds.
            let mut z = i
                .wrapping_add(0x9e37_79b9_7f4a_7c15)
                .wrapping_mul(0x0123_4567);
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            let (chain, theta0, goal) = random_pose_case(z ^ (z >> 31), n, limited);
            let target = tip_of(&chain, &goal);
            let (o, out, m) = cold_solve(&chain, &theta0, target);
            let best = if n == 2 {
                brute_force_optimum(&chain, &theta0, target)
            } else {
                three_link_optimum(&chain, &theta0, target)
            };
            let tip = (tip_of(&chain, &out) - target).norm();
            if !o.converged
                || tip > 1e-11
                || !within(&chain, &out)
                || m > best * (1.0 + 1e-6) + 1e-9
            {
                misses.push(format!(
                    "case {i}: converged {} tip {tip:e} m off, metric 3 {m} optimum {best}, \
                     goal {goal:?} out {out:?}",
                    o.converged
                ));
            }
        }
        assert!(
            misses.len() <= measured,
            "{n} links, limited {limited}: {} of {cases} missed, {measured} when last \
             measured:\n{}",
            misses.len(),
            misses.join("\n")
        );
    }
}
