//! The overall strategy: one optimization over the whole arm.
//!
//! ```text
//! minimize   1/2 sum_i (theta_i - theta0_i)^2        (half of metric 3)
//! subject to tip(theta) = target,   lo_i <= theta_i <= hi_i
//! ```
//!
//! Method (every iteration is O(n); nothing is allocated once the scratch is sized for n):
//! - **SQP step.** The linearized subproblem, with the identity as Hessian, is solved through
//!   its two-variable dual `theta(mu) = clip(theta0 + J^T mu, lo, hi)` by semismooth Newton
//!   (module `dual`); without limits that is the minimum-norm step with the 2 x 2 Schur complement
//!   `J J^T`. When the linearized constraint cannot be met inside the box (or `J` loses rank)
//!   the elastic form with a penalized constraint is solved instead (the stiffest of a few
//!   weights whose dual settles; its dual steps to the exact maximum along each Newton
//!   direction, a few evaluations per solve). The step is globalized by an Armijo line search on the merit
//!   `1/2 |theta - theta0|^2 + nu |tip - target|`, with `nu` raised above the multiplier norm
//!   whenever needed and, after an exact step, brought back down when it is more than ten times
//!   what that step's multiplier needs: an elastic step's multiplier can be huge, and a `nu`
//!   kept from it would leave the line search accepting only tiny steps.
//! - **Newton step.** Near the solution, exact Newton on the optimality conditions
//!   `theta = clip(theta0 + J^T mu)`, `tip = target`: the multiplier picks the active set (a
//!   joint is held at a bound when `theta0 + J^T mu` lies on or beyond it, else free), the held
//!   joints move onto their bounds, and the free ones take the Newton step with the Lagrangian
//!   Hessian `I + G`, `G_ab = g_max(a,b)`, solved in O(n) through prefix sums (module
//!   `hessian`), clipped into the box. It is taken only when the Hessian's inertia says the
//!   point is a local minimum on the constraint's tangent and the residual of the optimality
//!   conditions at least halves; otherwise the SQP step is used. With the active set read from
//!   the multiplier, a joint that reaches or leaves a limit near the optimum does not stop
//!   Newton, so limited solves converge as fast as unlimited ones.
//! - **Stopping rule.** A local solve has converged when the tip is within the tip tolerance
//!   and the optimality conditions hold within the stationarity tolerance. It gives up (not
//!   converged) at the iteration cap, when no step decreases the merit, or when ten elastic
//!   steps in a row cut the tip error by less than 1%: the box then holds no way to the target
//!   from that start (a cold start in the wrong piece of the feasible set, or an unreachable
//!   target, which goes on to the closest-tip search).
//! - **Limits** are met exactly: every iterate is clipped into the box by construction.
//! - **Straight (singular) poses.** If the iteration stalls at a pose whose Jacobian has lost
//!   rank while the target is not met, the joints after the base are bent by a small angle with
//!   a deterministic sign: that of the last solved pose's total bend, else positive.
//! - **Unreachable targets.** The pose whose tip is closest to the target is found by projected
//!   Levenberg-Marquardt on the squared tip distance, then metric 3 is minimized among the poses
//!   reaching that closest point; an unlimited chain outside its ring has the closed form (the
//!   arm straight toward the target, or folded around its longest link).
//!
//! Two modes ([`OverallMode`]): **local** continues from the current pose and the stored
//! multiplier (one control tick), **cold** ([`Overall::solve_cold`]) runs its own deterministic
//! set of starts and keeps the best optimum by metric 3; a random start whose iterate comes
//! within 1e-4 rad of the best optimum on target so far (tip within 1e-6 of the scale) stops
//! there, as it would only find that optimum again.

mod dual;
mod hessian;

use crate::chain::{nearest_representative, Chain, Reachability, Vec2};
use crate::resolve::{check_input, Outcome, Resolver, Strategy};

use dual::Dual;

/// Which starts a solve uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverallMode {
    /// Continue from the current pose and the stored multiplier: one local solve (a control
    /// tick; the optimum wanted is the one continued from the current pose).
    Local,
    /// Several deterministic starts (see [`Overall::solve_cold`]); the best optimum wins.
    Cold,
}

/// Tuning of the overall solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OverallOptions {
    /// Tip tolerance relative to the chain's scale (`reach + |base|`): the tip is on target when
    /// `|tip - target| <= tip_tolerance * scale`.
    pub tip_tolerance: f64,
    /// Tolerance on the optimality conditions, rad: `|theta - clip(theta0 + J^T mu)|` per joint.
    pub stationarity_tolerance: f64,
    /// Iteration cap of one local solve (SQP and Newton steps both count).
    pub max_iterations: usize,
    /// What [`Resolver::solve`] and [`Resolver::resolve`] do.
    pub mode: OverallMode,
    /// Cold solves: the number of intermediate targets of each continuation start (0 disables
    /// the continuation starts).
    pub continuation_stages: usize,
    /// Cold solves: how many of the distinct optima found are mirrored and solved again.
    pub mirror_starts: usize,
    /// Cold solves: seeded pseudo-random starts tried when the chain has limits (limits split
    /// the feasible set into pieces the other starts may not reach) and a limit comes near
    /// enough to `theta0` to touch a better pose, and once more when no start so far has
    /// reached the target.
    pub random_starts: usize,
    /// Seed of those starts: the same seed gives the same answer.
    pub seed: u64,
}

impl Default for OverallOptions {
    fn default() -> Self {
        Self {
            tip_tolerance: 1e-12,
            stationarity_tolerance: 1e-11,
            max_iterations: 200,
            mode: OverallMode::Local,
            continuation_stages: 4,
            mirror_starts: 2,
            random_starts: 8,
            seed: 0x0005_eed0_fa11,
        }
    }
}

/// Scratch buffers, sized once per joint count.
#[derive(Debug, Default)]
struct Work {
    n: usize,
    pts: Vec<Vec2>,
    jx: Vec<f64>,
    jy: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    theta: Vec<f64>,
    trial: Vec<f64>,
    qp_x: Vec<f64>,
    state: Vec<i8>,
    /// Kinks of the elastic dual along a line, two per joint.
    brk: Vec<(f64, f64)>,
    /// Cold solves: `best` holds an optimum on target, and a local solve whose iterate comes
    /// next to it stops there (it would only find that optimum again).
    watch_best: bool,
    /// Set by a local solve that stopped next to `best`.
    joined_best: bool,
    free: Vec<usize>,
    g: Vec<f64>,
    piv: Vec<f64>,
    s: Vec<f64>,
    rf: Vec<f64>,
    jxf: Vec<f64>,
    jyf: Vec<f64>,
    y1: Vec<f64>,
    y2: Vec<f64>,
    y3: Vec<f64>,
    y4: Vec<f64>,
    best: Vec<f64>,
    second: Vec<f64>,
    stage: Vec<f64>,
}

impl Work {
    fn resize(&mut self, n: usize) {
        if self.n == n && self.pts.len() == n + 1 {
            return;
        }
        self.n = n;
        self.pts = vec![Vec2::zeros(); n + 1];
        for v in [
            &mut self.jx,
            &mut self.jy,
            &mut self.lo,
            &mut self.hi,
            &mut self.theta,
            &mut self.trial,
            &mut self.qp_x,
            &mut self.g,
            &mut self.piv,
            &mut self.s,
            &mut self.rf,
            &mut self.jxf,
            &mut self.jyf,
            &mut self.y1,
            &mut self.y2,
            &mut self.y3,
            &mut self.y4,
            &mut self.best,
            &mut self.second,
            &mut self.stage,
        ] {
            *v = vec![0.0; n];
        }
        self.state = vec![0; n];
        self.brk = vec![(0.0, 0.0); 2 * n];
        self.free = Vec::with_capacity(n);
    }
}

/// The fixed data of one problem.
struct Problem<'a> {
    chain: &'a Chain,
    theta0: &'a [f64],
    target: Vec2,
    /// Length scale `reach + |base|`, m.
    scale: f64,
    /// Absolute tip tolerance, m.
    tol: f64,
    /// Stationarity tolerance, rad.
    stol: f64,
}

/// How one local solve ended.
#[derive(Debug, Clone, Copy)]
struct Local {
    converged: bool,
    tip_error: f64,
    iterations: usize,
}

/// The overall (metric-3) resolver. Holds its scratch, the last multiplier (warm start of the
/// next local solve) and the sign used to break the tie at straight poses.
#[derive(Debug)]
pub struct Overall {
    opts: OverallOptions,
    w: Work,
    mu: [f64; 2],
    mu_joints: usize,
    bend_sign: f64,
}

/// splitmix64: a tiny deterministic generator for the seeded cold starts.
struct SplitMix(u64);

impl SplitMix {
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Half of metric 3.
fn half_metric(theta: &[f64], theta0: &[f64]) -> f64 {
    0.5 * theta
        .iter()
        .zip(theta0)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The mirror image of the pose `src` across the line from the base through the target (same
/// tip for an unlimited chain), written to `out`: absolute angles `phi -> 2 line - phi`, so
/// `theta_1 -> 2 (line - h) - theta_1` and every later relative angle changes sign. Each angle is
/// taken as the representative nearest `theta0` and clipped into `[lo, hi]`.
fn mirror_pose(p: &Problem, src: &[f64], lo: &[f64], hi: &[f64], out: &mut [f64]) {
    let to = p.target - p.chain.base();
    let line = to.y.atan2(to.x);
    for a in 0..out.len() {
        let m = if a == 0 {
            2.0 * (line - p.chain.heading()) - src[0]
        } else {
            -src[a]
        };
        out[a] = nearest_representative(m, p.theta0[a]).clamp(lo[a], hi[a]);
    }
}

impl Overall {
    /// A resolver with the given options and no warm-start history.
    pub fn new(opts: OverallOptions) -> Self {
        Self {
            opts,
            w: Work::default(),
            mu: [0.0; 2],
            mu_joints: 0,
            bend_sign: 1.0,
        }
    }

    /// The options in use.
    pub fn options(&self) -> &OverallOptions {
        &self.opts
    }

    /// The multiplier of the last solve (the tip force, rad/m), used to warm-start the next
    /// local solve.
    pub fn multiplier(&self) -> [f64; 2] {
        self.mu
    }

    /// Forgets the warm-start multiplier and the tie-break history.
    pub fn reset(&mut self) {
        self.mu = [0.0; 2];
        self.mu_joints = 0;
        self.bend_sign = 1.0;
    }

    fn problem<'a>(&self, chain: &'a Chain, theta0: &'a [f64], target: Vec2) -> Problem<'a> {
        let scale = chain.reach() + chain.base().norm();
        Problem {
            chain,
            theta0,
            target,
            scale,
            tol: self.opts.tip_tolerance * scale,
            stol: self.opts.stationarity_tolerance,
        }
    }

    /// Sizes the scratch and loads the bounds of `chain`.
    fn prepare(&mut self, chain: &Chain) {
        let n = chain.len();
        self.w.resize(n);
        for (a, lim) in chain.limits().iter().enumerate() {
            let (lo, hi) = lim.map_or((f64::NEG_INFINITY, f64::INFINITY), |l| (l.lo, l.hi));
            self.w.lo[a] = lo;
            self.w.hi[a] = hi;
        }
        if self.mu_joints != n {
            self.mu = [0.0; 2];
            self.mu_joints = n;
        }
    }

    /// What every solve does first: refuse bad input, size the scratch, and answer an unlimited
    /// chain's target outside its ring in closed form. `Err` holds the finished outcome.
    fn begin<'a>(
        &mut self,
        chain: &'a Chain,
        theta0: &'a [f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Result<Problem<'a>, Outcome> {
        if let Some(o) = self.refuse(chain, theta0, target, out) {
            return Err(o);
        }
        self.prepare(chain);
        let p = self.problem(chain, theta0, target);
        match self.closed_form_outside(&p, out) {
            Some(o) => Err(o),
            None => Ok(p),
        }
    }

    /// Best effort from the current pose `theta0` and the stored multiplier (one control tick).
    pub fn solve_local(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        let p = match self.begin(chain, theta0, target, out) {
            Ok(p) => p,
            Err(o) => return o,
        };
        for a in 0..p.theta0.len() {
            self.w.theta[a] = p.theta0[a].clamp(self.w.lo[a], self.w.hi[a]);
        }
        let mut mu = self.mu;
        let local = self.local(&p, &mut mu, p.tol);
        let mut iterations = local.iterations;
        let mut converged = local.converged;
        if !local.converged {
            let (its, conv) = self.closest(&p, &mut mu);
            iterations += its;
            converged = conv;
        } else {
            iterations += self.try_mirror(&p, &mut mu);
        }
        self.finish(&p, mu, iterations, converged, out)
    }

    /// After a converged local solve: the answer's mirror image across the base-target line
    /// reaches the same tip, and near a folded or straight pose it can move the joints less (a
    /// local path cannot cross that singularity). Checked in O(n); solved and kept only when it
    /// lowers metric 3. Returns the iterations spent.
    fn try_mirror(&mut self, p: &Problem, mu: &mut [f64; 2]) -> usize {
        let current = half_metric(&self.w.theta, p.theta0);
        {
            let w = &mut self.w;
            mirror_pose(p, &w.theta, &w.lo, &w.hi, &mut w.trial);
        }
        // A clear improvement only: a mirror-symmetric tie keeps the tie-break's side.
        let goal = current * (1.0 - 1e-9);
        if half_metric(&self.w.trial, p.theta0) >= goal {
            return 0;
        }
        self.w.best.copy_from_slice(&self.w.theta);
        self.w.theta.copy_from_slice(&self.w.trial);
        let mut mirror_mu = [0.0; 2];
        let l = self.local(p, &mut mirror_mu, p.tol);
        let better =
            l.converged && l.tip_error <= p.tol && half_metric(&self.w.theta, p.theta0) < current;
        if better {
            *mu = mirror_mu;
        } else {
            self.w.theta.copy_from_slice(&self.w.best);
        }
        l.iterations
    }

    /// Best effort from several deterministic starts of its own, keeping the best optimum by
    /// metric 3 (ties keep the earlier start). The starts, in order, each a local solve with
    /// the multiplier reset to zero:
    /// 1. `theta0` itself (clipped into the limits);
    /// 2. `theta0` with the base joint turned so that the tip points from the base toward the
    ///    target;
    /// 3. continuation along the straight tip path from `tip(theta0)` to the target through
    ///    [`OverallOptions::continuation_stages`] equally spaced intermediate targets, each
    ///    solved from the previous answer (metric 3 always measured from `theta0`);
    /// 4. the same continuation along the polar path around the base (radius and bearing
    ///    interpolated linearly);
    /// 5. for the best [`OverallOptions::mirror_starts`] distinct optima found by 1-4, their
    ///    mirror image across the line from the base to the target (same tip; angles taken as
    ///    the representatives nearest `theta0`, clipped into the limits).
    ///
    /// 6. when the chain has limits, up to [`OverallOptions::random_starts`] pseudo-random
    ///    poses from a splitmix64 generator seeded with [`OverallOptions::seed`] at every call.
    ///    Any pose better than the best optimum so far (metric 3 = `r^2`) lies within `r` of
    ///    `theta0`, so the starts are drawn there: each joint uniform over its limits within
    ///    `+-r` of `clip(theta0)`, pulled onto the ball of radius `r` when outside it (`r`
    ///    shrinks as better optima are found). When no limit comes within `r` of `theta0` the
    ///    limits cannot touch a better pose, the problem there is the unlimited one, and the
    ///    random starts are skipped. When no start so far has reached the target, the same
    ///    number again (limited or not), uniform inside the limits (an unlimited joint:
    ///    `theta0 +- pi/2`). A random start stops as soon as its iterate is on target within
    ///    1e-6 of the scale and within 1e-4 rad of the best optimum so far (it would converge
    ///    to that optimum).
    ///
    /// Nothing here uses the stored multiplier or any other strategy. If no start reaches the
    /// target, the closest reachable tip is sought from the start that came closest.
    /// `iterations` in the outcome is the sum over all starts.
    pub fn solve_cold(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        let p = match self.begin(chain, theta0, target, out) {
            Ok(p) => p,
            Err(o) => return o,
        };
        let mut total = 0;
        // Best and second-best optimum: (half metric, tip error, converged, mu).
        let mut best: Option<(f64, f64, bool, [f64; 2])> = None;
        let mut second: Option<(f64, f64, bool, [f64; 2])> = None;

        let mut starts = 0usize;
        let fixed = 4 + self.opts.mirror_starts;
        let mut kinds = fixed;
        if chain.is_limited() {
            kinds += self.opts.random_starts;
        }
        let mut second_round = false;
        let mut rng = SplitMix(self.opts.seed);
        loop {
            if starts >= kinds {
                let reached = best.is_some_and(|b| b.2);
                if reached || second_round || self.opts.random_starts == 0 {
                    break;
                }
                second_round = true;
                kinds += self.opts.random_starts;
            }
            let kind = starts;
            starts += 1;
            let mut mu = [0.0; 2];
            match kind {
                0 => self.start_clipped(&p),
                1 => {
                    self.start_clipped(&p);
                    let tip0 = chain.tip(&self.w.theta);
                    let from = (tip0 - chain.base()).y.atan2((tip0 - chain.base()).x);
                    let to = (target - chain.base()).y.atan2((target - chain.base()).x);
                    let turn = crate::chain::wrap_angle(to - from);
                    self.w.theta[0] = (self.w.theta[0] + turn).clamp(self.w.lo[0], self.w.hi[0]);
                }
                2 | 3 => {
                    self.start_clipped(&p);
                    let stages = self.opts.continuation_stages;
                    if stages == 0 {
                        continue;
                    }
                    let tip0 = chain.tip(&self.w.theta);
                    let b = chain.base();
                    let (r0, a0) = ((tip0 - b).norm(), (tip0 - b).y.atan2((tip0 - b).x));
                    let (r1, a1) = ((target - b).norm(), (target - b).y.atan2((target - b).x));
                    let da = crate::chain::wrap_angle(a1 - a0);
                    for k in 1..=stages {
                        let s = k as f64 / (stages + 1) as f64;
                        let t = if kind == 2 {
                            tip0 + (target - tip0) * s
                        } else {
                            let r = r0 + (r1 - r0) * s;
                            let a = a0 + da * s;
                            b + Vec2::new(r * a.cos(), r * a.sin())
                        };
                        let sub = Problem {
                            target: t,
                            tol: 1e-6 * p.scale,
                            stol: 1e-6,
                            ..p
                        };
                        let l = self.local(&sub, &mut mu, sub.tol);
                        total += l.iterations;
                    }
                }
                k if k >= fixed => {
                    // Any pose better than the best optimum so far lies within the ball of
                    // radius sqrt(metric 3) around theta0.
                    let radius = best.filter(|b| b.2).map(|b| (2.0 * b.0).sqrt());
                    match radius {
                        Some(r) if k == fixed && !self.limits_reach_ball(&p, r) => break,
                        Some(r) => self.start_in_ball(&p, r, &mut rng),
                        None => self.start_in_box(&p, &mut rng),
                    }
                }
                _ => {
                    let which = kind - 4;
                    match (which, &best, &second) {
                        (0, Some(b), _) if b.2 => {}
                        (1, _, Some(s)) if s.2 => {}
                        _ => continue,
                    }
                    let w = &mut self.w;
                    let src = if which == 0 { &w.best } else { &w.second };
                    mirror_pose(&p, src, &w.lo, &w.hi, &mut w.theta);
                }
            }
            // A random start that runs into the best optimum so far is not followed further.
            self.w.watch_best = kind >= fixed && best.is_some_and(|b| b.2);
            self.w.joined_best = false;
            let l = self.local(&p, &mut mu, p.tol);
            self.w.watch_best = false;
            total += l.iterations;
            if self.w.joined_best {
                continue;
            }
            let on = l.converged && l.tip_error <= p.tol;
            let m = half_metric(&self.w.theta, p.theta0);
            let better = |o: &Option<(f64, f64, bool, [f64; 2])>| match o {
                None => true,
                Some((bm, be, bc, _)) => {
                    if on != *bc {
                        on
                    } else if on {
                        m < *bm
                    } else {
                        l.tip_error < *be
                    }
                }
            };
            let same_as_best = best.is_some_and(|b| {
                (b.0 - m).abs() <= 1e-9 * (1.0 + m)
                    && max_abs_diff(&self.w.best, &self.w.theta) < 1e-6
            });
            if same_as_best {
                continue;
            }
            if better(&best) {
                if best.is_some() {
                    self.w.second.copy_from_slice(&self.w.best);
                    second = best;
                }
                self.w.best.copy_from_slice(&self.w.theta);
                best = Some((m, l.tip_error, on, mu));
            } else if better(&second) {
                self.w.second.copy_from_slice(&self.w.theta);
                second = Some((m, l.tip_error, on, mu));
            }
        }
        let Some((_, _, on, mut mu)) = best else {
            return self.finish(&p, [0.0; 2], total, false, out);
        };
        self.w.theta.copy_from_slice(&self.w.best);
        let mut converged = on;
        if !on {
            let (its, conv) = self.closest(&p, &mut mu);
            total += its;
            converged = conv;
        }
        self.finish(&p, mu, total, converged, out)
    }

    /// Whether some limit comes within `r` of `theta0` (or `theta0` lies outside its limits):
    /// only then can a limit touch a pose with metric 3 below `r^2`.
    fn limits_reach_ball(&self, p: &Problem, r: f64) -> bool {
        (0..p.theta0.len()).any(|a| {
            let t = p.theta0[a];
            !(self.w.lo[a] < t - r && t + r < self.w.hi[a])
        })
    }

    /// A pseudo-random start inside the limits and within `r` of `clip(theta0)` (where every
    /// pose with metric 3 below `r^2` lies): each joint uniform over its limits within
    /// `+-r`, then pulled toward `clip(theta0)` onto the ball if outside it.
    fn start_in_ball(&mut self, p: &Problem, r: f64, rng: &mut SplitMix) {
        let w = &mut self.w;
        let mut norm2 = 0.0;
        for a in 0..p.theta0.len() {
            let c = p.theta0[a].clamp(w.lo[a], w.hi[a]);
            let lo = w.lo[a].max(c - r);
            let hi = w.hi[a].min(c + r);
            w.theta[a] = lo + (hi - lo) * rng.unit();
            norm2 += (w.theta[a] - c) * (w.theta[a] - c);
        }
        let norm = norm2.sqrt();
        if norm > r {
            let k = r / norm;
            for a in 0..p.theta0.len() {
                let c = p.theta0[a].clamp(w.lo[a], w.hi[a]);
                w.theta[a] = c + (w.theta[a] - c) * k;
            }
        }
    }

    /// A pseudo-random start uniform inside the limits (an unlimited joint: `theta0 +- pi/2`),
    /// for when no start has reached the target yet.
    fn start_in_box(&mut self, p: &Problem, rng: &mut SplitMix) {
        for a in 0..p.theta0.len() {
            let u = rng.unit();
            let (lo, hi) = (self.w.lo[a], self.w.hi[a]);
            self.w.theta[a] = if lo.is_finite() && hi.is_finite() {
                lo + (hi - lo) * u
            } else {
                let half = std::f64::consts::FRAC_PI_2;
                (p.theta0[a] + half * (2.0 * u - 1.0)).clamp(lo, hi)
            };
        }
    }

    /// Loads `clip(theta0)` as the current iterate.
    fn start_clipped(&mut self, p: &Problem) {
        for a in 0..p.theta0.len() {
            self.w.theta[a] = p.theta0[a].clamp(self.w.lo[a], self.w.hi[a]);
        }
    }

    /// Bad input: copy what can be copied, report failure, touch nothing else.
    fn refuse(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Option<Outcome> {
        if check_input(chain, theta0, target).is_ok() && out.len() == chain.len() {
            return None;
        }
        if out.len() == theta0.len() {
            out.copy_from_slice(theta0);
        }
        let tip_error = if theta0.len() == chain.len() {
            (chain.tip(theta0) - target).norm()
        } else {
            f64::INFINITY
        };
        Some(Outcome {
            tip_error: if tip_error.is_finite() {
                tip_error
            } else {
                f64::MAX
            },
            base_error: 0.0,
            reachable: false,
            converged: false,
            iterations: 0,
        })
    }

    /// Writes the current iterate to `out`, updates the warm-start state, builds the outcome.
    fn finish(
        &mut self,
        p: &Problem,
        mu: [f64; 2],
        iterations: usize,
        converged: bool,
        out: &mut [f64],
    ) -> Outcome {
        out.copy_from_slice(&self.w.theta);
        let tip_error = (p.chain.tip(out) - p.target).norm();
        let reachable = tip_error <= p.tol;
        if mu[0].is_finite() && mu[1].is_finite() {
            self.mu = if reachable { mu } else { [0.0; 2] };
        }
        let bend: f64 = out.iter().skip(1).sum();
        if bend != 0.0 && bend.is_finite() {
            self.bend_sign = bend.signum();
        }
        Outcome {
            tip_error,
            base_error: 0.0,
            reachable,
            converged: converged && reachable,
            iterations,
        }
    }

    /// The closest pose for an unlimited chain whose target lies outside its ring: straight
    /// toward the target (beyond the reach) or folded back along the longest link (inside the
    /// hole). Angles are the representatives nearest `theta0`. `None` when not applicable.
    fn closed_form_outside(&mut self, p: &Problem, out: &mut [f64]) -> Option<Outcome> {
        let chain = p.chain;
        if chain.is_limited() || chain.classify(p.target) != Reachability::Outside {
            return None;
        }
        let n = chain.len();
        let d = p.target - chain.base();
        let dist = d.norm();
        let bearing = if dist > 0.0 {
            d.y.atan2(d.x)
        } else {
            chain.heading() + p.theta0[0]
        };
        let h = chain.heading();
        if dist > chain.reach() {
            self.w.theta[0] = nearest_representative(bearing - h, p.theta0[0]);
            for a in 1..n {
                self.w.theta[a] = nearest_representative(0.0, p.theta0[a]);
            }
        } else {
            // Inside the hole: the longest link points at the target, all others fold back.
            let links = chain.links();
            let mut k = 0;
            for (a, &l) in links.iter().enumerate() {
                if l > links[k] {
                    k = a;
                }
            }
            let pi = std::f64::consts::PI;
            let mut prev = h;
            for a in 0..n {
                let phi = if a == k { bearing } else { bearing + pi };
                self.w.theta[a] = nearest_representative(phi - prev, p.theta0[a]);
                prev = phi;
            }
        }
        Some(self.finish(p, [0.0; 2], 0, false, out))
    }

    /// Forward kinematics and Jacobian at `w.theta`; returns `target - tip` and the
    /// stationarity residual for the multiplier `mu`.
    fn eval(&mut self, p: &Problem, mu: [f64; 2]) -> (Vec2, f64) {
        let w = &mut self.w;
        p.chain.points_into(&w.theta, &mut w.pts);
        let n = w.n;
        let tip = w.pts[n];
        let mut s: f64 = 0.0;
        for a in 0..n {
            let r = tip - w.pts[a];
            w.jx[a] = -r.y;
            w.jy[a] = r.x;
            let u = p.theta0[a] + w.jx[a] * mu[0] + w.jy[a] * mu[1];
            let v = u.clamp(w.lo[a], w.hi[a]);
            s = s.max((w.theta[a] - v).abs());
        }
        (p.target - tip, s)
    }

    /// One local solve from `w.theta` with the multiplier `mu`; the answer is left in
    /// `w.theta`, its multiplier in `mu`.
    fn local(&mut self, p: &Problem, mu: &mut [f64; 2], tol: f64) -> Local {
        let n = self.w.n;
        let mut nu: f64 = 0.0;
        let mut newton_ready = false;
        let mut kicks = 0;
        let mut iterations = 0;
        let mut mu_q = *mu;
        // Stall rule: a run of elastic steps (the linearized constraint cannot be met inside
        // the limits) that does not cut the tip error by 1% in 10 iterations means the box
        // holds no way to the target from here.
        let (mut elastic_run, mut elastic_ref) = (0usize, 0.0_f64);
        loop {
            let (c, s) = self.eval(p, *mu);
            let cn = c.norm();
            if self.w.watch_best
                && cn <= 1e-6 * p.scale
                && max_abs_diff(&self.w.theta, &self.w.best) <= 1e-4
            {
                self.w.joined_best = true;
                return Local {
                    converged: false,
                    tip_error: cn,
                    iterations,
                };
            }
            if cn <= tol && s <= p.stol {
                return Local {
                    converged: true,
                    tip_error: cn,
                    iterations,
                };
            }
            if iterations >= self.opts.max_iterations {
                return Local {
                    converged: false,
                    tip_error: cn,
                    iterations,
                };
            }
            iterations += 1;
            let residual = cn / p.scale + s;
            if newton_ready {
                if let Some(mu_n) = self.newton(p, *mu, c) {
                    std::mem::swap(&mut self.w.theta, &mut self.w.trial);
                    let (c2, s2) = self.eval(p, mu_n);
                    let cn2 = c2.norm();
                    if cn2 / p.scale + s2 <= 0.5 * residual || (cn2 <= tol && s2 <= p.stol) {
                        *mu = mu_n;
                        continue;
                    }
                    std::mem::swap(&mut self.w.theta, &mut self.w.trial);
                    self.eval(p, *mu);
                }
                newton_ready = false;
            }
            // SQP step: exact linearized subproblem, else its elastic form.
            let qp_tol = (1e-3 * tol).max(1e-15 * p.scale);
            let mu_cap = 1e12 / p.scale;
            let mut elastic = false;
            mu_q = if mu_q[0].is_finite() && mu_q[1].is_finite() {
                *mu
            } else {
                [0.0; 2]
            };
            let exact_ok = {
                let w = &mut self.w;
                let d = Dual {
                    jx: &w.jx,
                    jy: &w.jy,
                    z: p.theta0,
                    theta: &w.theta,
                    lo: &w.lo,
                    hi: &w.hi,
                    c,
                    rho_inv: 0.0,
                };
                d.solve(
                    &mut mu_q,
                    &mut w.qp_x,
                    &mut w.state,
                    qp_tol,
                    mu_cap,
                    &mut w.brk,
                )
            };
            if !exact_ok && cn > tol && kicks < 3 && self.singular() {
                kicks += 1;
                self.kick();
                continue;
            }
            if exact_ok {
                elastic_run = 0;
            } else {
                elastic_run += 1;
                if elastic_run == 1 {
                    elastic_ref = cn;
                } else if elastic_run > 10 {
                    if cn > 0.99 * elastic_ref {
                        return Local {
                            converged: false,
                            tip_error: cn,
                            iterations,
                        };
                    }
                    elastic_run = 1;
                    elastic_ref = cn;
                }
            }
            if !exact_ok {
                // Elastic form with an adaptive weight: the stiffest penalty whose dual settles
                // (a very stiff one can leave semismooth Newton crawling over clipped joints).
                elastic = true;
                let mut solved = false;
                for weight in [1e-6, 1e-3, 1.0] {
                    mu_q = [0.0; 2];
                    let w = &mut self.w;
                    let d = Dual {
                        jx: &w.jx,
                        jy: &w.jy,
                        z: p.theta0,
                        theta: &w.theta,
                        lo: &w.lo,
                        hi: &w.hi,
                        c,
                        rho_inv: weight * p.scale * p.scale,
                    };
                    if d.solve(
                        &mut mu_q,
                        &mut w.qp_x,
                        &mut w.state,
                        qp_tol,
                        f64::MAX,
                        &mut w.brk,
                    ) {
                        solved = true;
                        break;
                    }
                }
                if !solved {
                    return Local {
                        converged: false,
                        tip_error: cn,
                        iterations,
                    };
                }
            }
            let w = &mut self.w;
            let mut step = 0.0_f64;
            let mut slope = 0.0;
            let mut jd = Vec2::zeros();
            for a in 0..n {
                let d = w.qp_x[a] - w.theta[a];
                step = step.max(d.abs());
                slope += (w.theta[a] - p.theta0[a]) * d;
                jd.x += w.jx[a] * d;
                jd.y += w.jy[a] * d;
            }
            let theta_scale = 1.0 + w.theta.iter().fold(0.0_f64, |m, t| m.max(t.abs()));
            if step <= 1e-15 * theta_scale {
                if cn > tol && kicks < 3 && self.singular() {
                    kicks += 1;
                    self.kick();
                    continue;
                }
                if cn <= tol {
                    // On target and no step left: optimal up to round-off.
                    *mu = mu_q;
                    return Local {
                        converged: s <= p.stol.max(1e-9),
                        tip_error: cn,
                        iterations,
                    };
                }
                return Local {
                    converged: false,
                    tip_error: cn,
                    iterations,
                };
            }
            let mu_norm = mu_q[0].hypot(mu_q[1]);
            let nu_wanted = 2.0 * mu_norm + 1e-6 / p.scale;
            if nu < 1.1 * mu_norm || (!elastic && nu > 10.0 * nu_wanted) {
                nu = nu_wanted;
            }
            let w = &mut self.w;
            slope += nu * ((c - jd).norm() - cn);
            let merit0 = half_metric(&w.theta, p.theta0) + nu * cn;
            let mut alpha = 1.0;
            let mut moved = false;
            for _ in 0..50 {
                for a in 0..n {
                    w.trial[a] = w.theta[a] + alpha * (w.qp_x[a] - w.theta[a]);
                }
                if alpha == 1.0 {
                    w.trial.copy_from_slice(&w.qp_x);
                }
                let m = half_metric(&w.trial, p.theta0)
                    + nu * (p.chain.tip(&w.trial) - p.target).norm();
                if m <= merit0 + 1e-4 * alpha * slope.min(0.0) {
                    moved = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !moved {
                if cn > tol && kicks < 3 && self.singular() {
                    kicks += 1;
                    self.kick();
                    continue;
                }
                return Local {
                    converged: cn <= tol && s <= p.stol.max(1e-9),
                    tip_error: cn,
                    iterations,
                };
            }
            std::mem::swap(&mut self.w.theta, &mut self.w.trial);
            *mu = mu_q;
            newton_ready = !elastic && (alpha == 1.0 || cn < 1e-3 * p.scale);
        }
    }

    /// Whether the Jacobian at the last evaluated pose has (numerically) lost rank.
    fn singular(&self) -> bool {
        let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
        for i in 0..self.w.n {
            a += self.w.jx[i] * self.w.jx[i];
            b += self.w.jx[i] * self.w.jy[i];
            c += self.w.jy[i] * self.w.jy[i];
        }
        let tr: f64 = a + c;
        tr <= 0.0 || a * c - b * b <= 1e-20 * tr * tr
    }

    /// The deterministic tie-break at a singular pose: bend the joints after the base by a
    /// small angle in the direction of the remembered bend sign, projected onto the null space
    /// of the Jacobian so that the tip does not move sideways to first order (and the sum of
    /// the bends keeps that sign), then clipped into the limits.
    fn kick(&mut self) {
        let w = &mut self.w;
        let n = w.n;
        let first = usize::from(n >= 2);
        let amount = 0.02 / (n as f64).sqrt();
        let mut bend: f64 = w.theta.iter().skip(1).sum();
        if bend == 0.0 || !bend.is_finite() {
            bend = self.bend_sign;
        }
        let sign = bend.signum();
        // v = (0, 1, .., 1); delta = v - J^T (J J^T + eps)^-1 J v.
        let (mut a, mut b, mut c, mut vx, mut vy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..n {
            a += w.jx[i] * w.jx[i];
            b += w.jx[i] * w.jy[i];
            c += w.jy[i] * w.jy[i];
            if i >= first {
                vx += w.jx[i];
                vy += w.jy[i];
            }
        }
        let eps = 1e-12 * (a + c) + f64::MIN_POSITIVE;
        let (a, c) = (a + eps, c + eps);
        let det = a * c - b * b;
        let (mx, my) = if det > 0.0 {
            ((c * vx - b * vy) / det, (a * vy - b * vx) / det)
        } else {
            (0.0, 0.0)
        };
        for i in 0..n {
            let v = if i >= first { 1.0 } else { 0.0 };
            let d = v - (w.jx[i] * mx + w.jy[i] * my);
            w.theta[i] = (w.theta[i] + sign * amount * d).clamp(w.lo[i], w.hi[i]);
        }
    }

    /// Exact Newton step on the optimality conditions with the active set the multiplier
    /// predicts: held joints go onto their bounds, free joints take the Newton step (clipped
    /// into the box). Writes the new pose into `w.trial` and returns the new multiplier, or
    /// `None` when the step is not trusted: fewer than two free joints, a near-singular
    /// Hessian, an inertia that is not that of a local minimum, or a step too large to be local.
    fn newton(&mut self, p: &Problem, mu: [f64; 2], c: Vec2) -> Option<[f64; 2]> {
        let w = &mut self.w;
        let n = w.n;
        let tip = w.pts[n];
        // The active set the multiplier predicts: joint a is held at a bound when
        // theta0_a + J_a^T mu lies on or beyond it (the generalized derivative of
        // theta = clip(theta0 + J^T mu)), else free. A held joint moves to its bound by d_a.
        w.free.clear();
        let mut c_free = c;
        for a in 0..n {
            let u = p.theta0[a] + w.jx[a] * mu[0] + w.jy[a] * mu[1];
            let d = if u <= w.lo[a] {
                w.lo[a] - w.theta[a]
            } else if u >= w.hi[a] {
                w.hi[a] - w.theta[a]
            } else {
                w.free.push(a);
                0.0
            };
            w.y4[a] = d;
            c_free.x -= w.jx[a] * d;
            c_free.y -= w.jy[a] * d;
        }
        let c = c_free;
        let m = w.free.len();
        if m < 2 {
            return None;
        }
        // Coupling of the free rows to the held joints' moves: sum_b g_max(a,b) d_b over held b,
        // = g_a * (moves before a) + sum_{b > a} g_b d_b, from one backward and one forward pass.
        let mut after = 0.0;
        for a in (0..n).rev() {
            let r = tip - w.pts[a];
            let g = mu[0] * r.x + mu[1] * r.y;
            w.trial[a] = after;
            after += g * w.y4[a];
        }
        let mut before = 0.0;
        let mut k = 0;
        for a in 0..n {
            if k < m && w.free[k] == a {
                let r = tip - w.pts[a];
                let g = mu[0] * r.x + mu[1] * r.y;
                w.g[k] = g;
                w.jxf[k] = w.jx[a];
                w.jyf[k] = w.jy[a];
                w.rf[k] = w.theta[a] - p.theta0[a] - (w.jx[a] * mu[0] + w.jy[a] * mu[1])
                    + g * before
                    + w.trial[a];
                k += 1;
            } else {
                before += w.y4[a];
            }
        }
        let f = hessian::factor(&w.g[..m], &mut w.piv[..m])?;
        if f.negative > 2 {
            return None;
        }
        hessian::solve(&w.piv[..m], &w.jxf[..m], &mut w.s[..m], &mut w.y1[..m]);
        hessian::solve(&w.piv[..m], &w.jyf[..m], &mut w.s[..m], &mut w.y2[..m]);
        hessian::solve(&w.piv[..m], &w.rf[..m], &mut w.s[..m], &mut w.y3[..m]);
        let (mut s00, mut s01, mut s10, mut s11, mut e0, mut e1) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for k in 0..m {
            s00 += w.jxf[k] * w.y1[k];
            s01 += w.jxf[k] * w.y2[k];
            s10 += w.jyf[k] * w.y1[k];
            s11 += w.jyf[k] * w.y2[k];
            e0 += w.jxf[k] * w.y3[k];
            e1 += w.jyf[k] * w.y3[k];
        }
        let s01 = 0.5 * (s01 + s10);
        // Second-order check: the KKT matrix has inertia (m, 2, 0) exactly when the Schur
        // complement S = J H^-1 J^T has as many negative eigenvalues as H and the rest positive.
        let det = s00 * s11 - s01 * s01;
        let tr = s00 + s11;
        let scale = s00.abs() + s11.abs() + s01.abs();
        if det.is_nan() || det.abs() <= 1e-14 * scale * scale {
            return None;
        }
        let neg_s = if det < 0.0 {
            1
        } else if tr < 0.0 {
            2
        } else {
            0
        };
        if neg_s != f.negative {
            return None;
        }
        let rhs = [c.x + e0, c.y + e1];
        let dmu = [
            (s11 * rhs[0] - s01 * rhs[1]) / det,
            (s00 * rhs[1] - s01 * rhs[0]) / det,
        ];
        let mut big: f64 = 0.0;
        for a in 0..n {
            big = big.max(w.y4[a].abs());
            w.trial[a] = w.theta[a] + w.y4[a];
        }
        for (k, &a) in w.free.iter().enumerate() {
            let d = w.y1[k] * dmu[0] + w.y2[k] * dmu[1] - w.y3[k];
            big = big.max(d.abs());
            // Projected: a free joint that would cross a bound stops there (the next step's
            // active set holds it if the multiplier agrees).
            w.trial[a] = (w.theta[a] + d).clamp(w.lo[a], w.hi[a]);
        }
        if big.is_nan() || big > 0.5 {
            return None;
        }
        Some([mu[0] + dmu[0], mu[1] + dmu[1]])
    }

    /// Closest reachable tip from `w.theta`: projected Levenberg-Marquardt on
    /// `D(theta) = 1/2 |tip - target|^2` inside the box, then metric 3 minimized among the poses
    /// that reach the closest point found. Returns the iterations and whether the final solve
    /// met the tip tolerance.
    ///
    /// The model Hessian is exact, `J^T J + G` with `G_ab = g_max(a,b)` built as in the
    /// Lagrangian with the residual `target - tip` in place of the multiplier (a large-residual
    /// problem, where Gauss-Newton alone crawls), plus `lambda I`. `lambda I + G` is solved in
    /// O(n) by [`hessian`] and the rank-2 term `J^T J` by a 2 x 2 Woodbury correction. Joints at
    /// a limit whose gradient pushes them outward are held; the step is clipped into the box.
    fn closest(&mut self, p: &Problem, mu: &mut [f64; 2]) -> (usize, bool) {
        let s2 = p.scale * p.scale;
        let mut lambda = 1e-3 * s2;
        let mut iterations = 0;
        let (mut c, _) = self.eval(p, [0.0; 2]);
        let mut cn = c.norm();
        while iterations < self.opts.max_iterations && cn > p.tol {
            iterations += 1;
            if !self.closest_step(p, c, cn, &mut lambda) {
                break;
            }
            let (c2, _) = self.eval(p, [0.0; 2]);
            c = c2;
            cn = c.norm();
        }
        if cn <= p.tol {
            let l = self.local(p, mu, p.tol);
            return (iterations + l.iterations, l.converged);
        }
        // Phase 2: metric 3 among the poses reaching the closest point found.
        let closest = p.chain.tip(&self.w.theta);
        self.w.best.copy_from_slice(&self.w.theta);
        let sub = Problem {
            target: closest,
            ..*p
        };
        let mut mu2 = [0.0; 2];
        let l = self.local(&sub, &mut mu2, p.tol);
        let d2 = (p.chain.tip(&self.w.theta) - p.target).norm();
        if !(l.converged && d2 <= cn + p.tol) {
            self.w.theta.copy_from_slice(&self.w.best);
        }
        *mu = [0.0; 2];
        (iterations + l.iterations, false)
    }

    /// One accepted step of the projected Levenberg-Marquardt iteration of [`Self::closest`]
    /// from the evaluated pose (residual `c`, its norm `cn`); false when no step decreases the
    /// distance any more (converged or stuck).
    fn closest_step(&mut self, p: &Problem, c: Vec2, cn: f64, lambda: &mut f64) -> bool {
        let s2 = p.scale * p.scale;
        let w = &mut self.w;
        let n = w.n;
        let tip = w.pts[n];
        let mut pg: f64 = 0.0;
        w.free.clear();
        for a in 0..n {
            let grad = -(w.jx[a] * c.x + w.jy[a] * c.y);
            w.rf[a] = grad;
            let moved = (w.theta[a] - grad).clamp(w.lo[a], w.hi[a]);
            pg = pg.max((moved - w.theta[a]).abs());
            let held =
                (w.theta[a] <= w.lo[a] && grad > 0.0) || (w.theta[a] >= w.hi[a] && grad < 0.0);
            if !held {
                w.free.push(a);
            }
        }
        if pg <= 1e-14 * p.scale * cn || w.free.is_empty() {
            return false;
        }
        let m = w.free.len();
        for (k, &a) in w.free.iter().enumerate() {
            w.jxf[k] = w.jx[a];
            w.jyf[k] = w.jy[a];
            w.y3[k] = -w.rf[a];
        }
        while *lambda <= 1e14 * s2 {
            for (k, &a) in w.free.iter().enumerate() {
                let r = tip - w.pts[a];
                w.g[k] = (c.x * r.x + c.y * r.y) / *lambda;
            }
            let positive =
                hessian::factor(&w.g[..m], &mut w.piv[..m]).is_some_and(|f| f.negative == 0);
            if !positive {
                *lambda *= 4.0;
                continue;
            }
            // u = A^-1 v with A = lambda (I + G / lambda); the 1 / lambda is applied below.
            hessian::solve(&w.piv[..m], &w.jxf[..m], &mut w.s[..m], &mut w.y1[..m]);
            hessian::solve(&w.piv[..m], &w.jyf[..m], &mut w.s[..m], &mut w.y2[..m]);
            hessian::solve(&w.piv[..m], &w.y3[..m], &mut w.s[..m], &mut w.y4[..m]);
            let inv = 1.0 / *lambda;
            let (mut s00, mut s01, mut s11, mut e0, mut e1) = (1.0, 0.0, 1.0, 0.0, 0.0);
            for k in 0..m {
                s00 += w.jxf[k] * w.y1[k] * inv;
                s01 += 0.5 * (w.jxf[k] * w.y2[k] + w.jyf[k] * w.y1[k]) * inv;
                s11 += w.jyf[k] * w.y2[k] * inv;
                e0 += w.jxf[k] * w.y4[k] * inv;
                e1 += w.jyf[k] * w.y4[k] * inv;
            }
            let det = s00 * s11 - s01 * s01;
            if det.is_nan() || det <= 0.0 {
                *lambda *= 4.0;
                continue;
            }
            let z0 = (s11 * e0 - s01 * e1) / det;
            let z1 = (s00 * e1 - s01 * e0) / det;
            w.trial.copy_from_slice(&w.theta);
            let mut step: f64 = 0.0;
            for (k, &a) in w.free.iter().enumerate() {
                let d = (w.y4[k] - w.y1[k] * z0 - w.y2[k] * z1) * inv;
                let v = (w.theta[a] + d).clamp(w.lo[a], w.hi[a]);
                step = step.max((v - w.theta[a]).abs());
                w.trial[a] = v;
            }
            let d_new = (p.chain.tip(&w.trial) - p.target).norm();
            if d_new < cn && step.is_finite() {
                std::mem::swap(&mut w.theta, &mut w.trial);
                *lambda = (*lambda / 3.0).max(1e-12 * s2);
                return true;
            }
            if step <= 1e-16 {
                return false;
            }
            *lambda *= 4.0;
        }
        false
    }
}

impl Resolver for Overall {
    fn strategy(&self) -> Strategy {
        Strategy::Overall
    }

    fn solve(&mut self, chain: &Chain, theta0: &[f64], target: Vec2, out: &mut [f64]) -> Outcome {
        match self.opts.mode {
            OverallMode::Local => self.solve_local(chain, theta0, target, out),
            OverallMode::Cold => self.solve_cold(chain, theta0, target, out),
        }
    }

    fn scratch_pose(&mut self) -> &mut Vec<f64> {
        &mut self.w.stage
    }
}

#[cfg(test)]
mod tests;
