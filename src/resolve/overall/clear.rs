//! The overall problem among obstacles: metric 3 with every link kept clear.
//!
//! ```text
//! minimize   1/2 |theta - theta0|^2
//! subject to tip(theta) = target,   lo <= theta <= hi,
//!            c_j(theta) >= clearance_m   for every (link, obstacle) pair j
//! ```
//!
//! `c_j` is the exact capsule clearance of [`World`] (the signed distance from the link's axis to
//! the obstacle minus the link radius). Only the pairs near contact enter (`select`): those
//! whose clearance is within a margin of `clearance_m`, the margin one and a half times the
//! larger of the tip correction wanted and the last step's largest point move, that at most a
//! mean link length (plus a floor of a twentieth of it), at most [`MAX_PAIRS`] of them, least
//! clearance first; a pair whose contact point and obstacle repeat one already taken (a joint
//! touching an obstacle is the end of one link and the start of the next) is the same
//! constraint and is left out. Pairs further away are checked by the line
//! search's merit, which measures the exact least clearance of every trial pose. Both searches
//! read a list of candidate pairs found with some slack and kept while the pose stays within
//! it (`Candidates`: exact, as a link's clearance moves no more than its ends), so that most
//! iterations, and most ticks of a warm run, search the whole world only once in a while.
//!
//! Method, one local solve (`ClearWork::local`):
//! - **SQP step**. The subproblem `min 1/2 |x - theta0|^2` subject to `J (x - theta) = c`, the
//!   box, and `g_j . (x - theta) >= clearance_m - c_j` for the selected pairs (with `g_j` the
//!   pair's gradient) is solved by a dual active-set method (module `active`: from the
//!   unconstrained minimum, the most violated constraint taken one at a time, a constraint
//!   whose multiplier would turn negative dropped), which gives the tip multiplier and one
//!   `nu_j >= 0` per pair. When the linearized constraints cannot all be met inside the box
//!   (the method proves it), the elastic form penalizes their violation quadratically
//!   instead (the stiffest of a few weights that solves). The step is globalized by an
//!   Armijo line search on the merit `1/2 |theta - theta0|^2 + nu_t |tip - target| + nu_c
//!   max(0, clearance_m - clearance)`, the weights kept above the multipliers' norms (tip:
//!   Euclidean, pairs: the sum, the dual of the max). A start that is not clear is handled the
//!   same way: the linearized constraints ask every pair in contact to move out.
//! - **Newton step** (`ClearWork::try_newton`), once an exact SQP step is taken whole or the
//!   tip is near: Newton on the optimality conditions with the active set the multipliers
//!   predict (joints held at a bound where `theta0 + A^T lambda` lies beyond it; pairs with
//!   `nu_j > 0` or not clear as equalities), with the Lagrangian Hessian `I + G - sum nu_j
//!   H_j`: `G` the tip's (module `hessian`), `H_j` each active pair's from its link's two
//!   ends (module `newton`, which also solves the KKT system through that structure in
//!   O(n) per constraint). Kept only when the optimality residual at least
//!   halves and no pair's multiplier turns negative. Dense: used up to [`NEWTON_MAX_JOINTS`]
//!   joints, beyond which the SQP steps alone finish (linear convergence).
//! - **Kept factors**. The factors of a Newton step's KKT system are kept, and the next step
//!   solves with them instead of its own when the free joints and the active pairs are the same
//!   and no point moved more than [`REUSE_MOVE`] of the scale since (a chord step, for the
//!   multipliers' change: the residual is always today's). One that does not contract is
//!   taken again with fresh factors. A control tick after one that leaned starts with such a
//!   step (the last tick's factors were built at its answer, where this tick starts) instead of
//!   an SQP step; a typical leaning tick so factorizes once, not twice, and solves no
//!   subproblem. Its evaluations before a Newton step take the pairs within
//!   [`NEWTON_MARGIN`] only, and the pairs of an evaluation at the same points and margin as
//!   the last are not looked up again (a tick starts where the last ended).
//! - **Stop**: converged when the tip is within the tolerance, the least clearance within the
//!   tip tolerance of `clearance_m`, and stationarity and complementarity (`nu_j` times the
//!   pair's slack) within the stationarity tolerance; not converged at the iteration cap, when
//!   no step decreases the merit, when elastic steps stall (as without obstacles), or when
//!   the optimality residual has not fallen by 1% in [`TICK_STALL_STEPS`] iterations of a
//!   local solve (a control tick), [`STALL_STEPS`] of a cold solve's fixed start, or
//!   [`SEARCH_STALL_STEPS`] of a flip or random one or of a continuation start's intermediate
//!   target (a body caught on an obstacle, whose exact and elastic steps alternate, each tiny).
//!
//! **Cold solve** (`Overall::cold_with`; the list is [`Overall::solve_cold`]'s): when the
//! optimum without obstacles is not clear, one local solve from each start, in order:
//! 1. the fixed starts: `clip(theta0)`, that optimum, the two continuations, the mirror images
//!    of the two best clear optima and of that optimum;
//! 2. the flip starts (module `flip`; `Overall::flip_starts`). The distinct clear optima
//!    differ mainly in which side of each obstacle each part of the body passes, and a local
//!    solve keeps the side it starts on; a flip start carries the point of the body nearest
//!    one obstacle to its far side, the tip kept on target and the rest of the pose close.
//!    First across each obstacle the optimum without obstacles collides with, then across each
//!    obstacle the best clear optimum touches, again from each better one found, at most
//!    [`FLIP_CAP`] in all. They come before the random starts, which then draw from the
//!    smaller ball of poses no worse than the better optimum they may have found;
//! 3. the random starts, within that ball.
//!
//! A flip or random start stops as soon as it runs into the best optimum so far.
//!
//! **Floors.** A control tick from a pose an obstacle was put onto may let a pair keep less than
//! `clearance_m` ([`Overall::set_floors`]: a link not clear need only come no closer). The solve
//! then sees each pair's clearance raised by how far its floor is below `clearance_m`, so that
//! every constraint above reads the same; a raised clearance is never below the pair's own, so
//! the searches for the pairs within a margin stay exact.
//!
//! The answer a caller gets is checked once more with [`World::clearance`] (exact, all pairs):
//! `converged` needs it to be at least `clearance_m - 1e-9` m ([`CLEAR_SLACK`]), the round-off
//! of a distance on an arm of some metres. A control tick whose last evaluation was of its
//! answer and found a pair within its margin takes that evaluation's least clearance instead
//! (exact too, by the candidates' bound); the controller checks the goal against the world
//! before it sends it.

// The loops walk several per-joint (or per-row) arrays in step; indices read best there.
#![allow(clippy::needless_range_loop)]

use std::ops::ControlFlow;

use super::cold::{mirror_pose, stages, Candidate, Podium, SplitMix};
use super::{half_metric, max_abs_diff, ElasticStall, Overall, Problem, ARMIJO, MAX_HALVINGS};
use crate::chain::{Chain, Vec2};
use crate::resolve::Outcome;
use crate::world::clearance::pair_gradient;
use crate::world::{Pair, World};

/// A solve without obstacles: local or cold.
type FreeSolve = fn(&mut Overall, &Chain, &[f64], Vec2, &mut [f64]) -> Outcome;
/// The same among the obstacles of a world.
type WorldSolve = fn(&mut Overall, &World, &Chain, &[f64], Vec2, &mut [f64]) -> Outcome;

/// Most (link, obstacle) pairs entering one subproblem: the pairs of least clearance are kept.
/// Bounds the dual's size (and the Newton system's) whatever the world.
pub const MAX_PAIRS: usize = 32;
/// Largest chain for the dense Newton phase; longer chains finish with SQP steps alone.
pub const NEWTON_MAX_JOINTS: usize = 96;
/// Most links a chain may have to be solved among obstacles: each clear solve factors the
/// subproblem's active constraints in a dense square of `(links + MAX_PAIRS + 2)²` numbers,
/// 34 MiB at this count (at 60,000 links it would be 29 GB). Problems and configs with
/// obstacles and more links are refused where they are read.
pub const MAX_LINKS_AMONG_OBSTACLES: usize = 2048;
/// An answer counts as clear when its least clearance is at least `clearance_m` less this, m:
/// the round-off of an exact distance on an arm of some metres.
pub const CLEAR_SLACK: f64 = 1e-9;

/// The pair margin is this multiple of the expected move (tip correction or last step).
const MARGIN_MOVES: f64 = 1.5;
/// ...plus this fraction of the mean link length.
const MARGIN_FLOOR: f64 = 0.05;
/// The margin of the evaluation that precedes a Newton step of a control tick, as a fraction
/// of the mean link length: that step takes no pair beyond contact (the subproblem of an SQP
/// step does, before they are reached), so the pairs near contact are enough: those leaning,
/// and those a step brought within it (the least clearance, exact whatever the margin, tells
/// the step's judge). A cold solve keeps the full margin: its Newton steps start further from
/// their answer, and on one reference case the lean margin led a start to a worse optimum.
const NEWTON_MARGIN: f64 = 0.005;
/// Two selected pairs with the same obstacle whose contact points are this close (relative to
/// the scale) are the same constraint.
const SAME_CONTACT: f64 = 1e-9;
/// A start of a cold solve whose optimality residual has not fallen by 1% in this many
/// iterations is stuck (a body caught on an obstacle: exact and elastic steps alternating,
/// each tiny).
pub const STALL_STEPS: usize = 10;
/// The same for a local solve (a control tick), which starts next to its answer: a tick that
/// makes no progress for this many iterations is caught, and the controller holds it. Fewer
/// than a cold start's: a caught tick is the longest tick the loop runs among obstacles (on the
/// benchmark's walks as many ticks converge with 4 as with 10, and a cold start with 4 was
/// seen to give up on a case it solves with 10).
pub const TICK_STALL_STEPS: usize = 4;
/// The same for a cold solve's random and flip starts, and for the intermediate targets of a
/// continuation start (whose answers only lead to the next). With 16 obstacles near the arm, 69
/// to 77% of the random starts end without reaching the target clear, most of them after
/// making no progress for ten iterations, and they took 72% of a cold solve's time. Fewer than
/// a fixed start's, enough that the benchmark's cases and the reference answers reach the
/// optima they reach with ten (with four, one case at n = 24 ended at a worse one).
pub const SEARCH_STALL_STEPS: usize = 6;
/// Forward-difference step for the pairs' Hessians, as a fraction of the problem's scale.
const FD_STEP: f64 = 1e-7;
/// A Newton multiplier of a pair below `-this * (1 + |nu|)` means the active set is wrong.
const NEGATIVE_NU: f64 = 1e-9;
/// A Newton step solves with the factors of the last one when the free joints and the active
/// pairs are the same and no point has moved more than this fraction of the scale since they
/// were built (a chord step, whose error is about this times the step's where a fresh Newton
/// step's is the step's square). A chord step that does not contract as a Newton step must is
/// taken again with fresh factors.
const REUSE_MOVE: f64 = 1e-4;
/// Cold solves: random starts among obstacles, in multiples of `random_starts`.
const RANDOM_FACTOR: usize = 3;
/// Most flip starts of one cold solve: as many as its random starts by default. Bounds their
/// cost in a crowded world, where the optimum without obstacles may collide with many
/// obstacles and each better optimum found starts a round of its own (the figures in
/// docs/BENCHMARKS.md were measured with this cap).
const FLIP_CAP: usize = 24;
/// The best clear optimum touches an obstacle whose clearance is within this fraction of the
/// scale of `clearance_m`: it leans on it (its clearance is `clearance_m` up to the solve's
/// tolerance, far below this), and a flip across it may find a better optimum.
const FLIP_TOUCH: f64 = 1e-6;

/// Scratch and warm state of the solver among obstacles, sized once per joint count and world.
#[derive(Debug, Default)]
pub(super) struct ClearWork {
    n: usize,
    obstacles: usize,
    pts: Vec<Vec2>,
    trial_pts: Vec<Vec2>,
    jx: Vec<f64>,
    jy: Vec<f64>,
    trial: Vec<f64>,
    fd_theta: Vec<f64>,
    qp_x: Vec<f64>,
    /// The rows of the SQP subproblem (see `Qp::rows`).
    qp_rows: Vec<f64>,
    all: Vec<Pair>,
    order: Vec<usize>,
    /// Candidate pairs (see `Candidates`), kept across iterations and ticks.
    cand: Candidates,
    /// Per pair of link and obstacle (`(link - 1) * obstacles + k`), how far below
    /// `clearance_m` the pair may be, m (a link that need only come no closer: see
    /// [`Overall::set_floors`]); empty for none.
    allow: Vec<f64>,
    /// Pairs found by a search of the world while some pair has an allowance.
    spare: Vec<Pair>,
    /// Selected pairs: count, keys (link, obstacle), clearance, contact point, gradient rows.
    k: usize,
    key: Vec<(usize, usize)>,
    clr: Vec<f64>,
    contact: Vec<Vec2>,
    grad: Vec<f64>,
    /// The current multipliers of the selected pairs.
    nu: Vec<f64>,
    /// Multipliers carried by key to the next selection (and the next tick).
    prev_k: usize,
    prev_key: Vec<(usize, usize)>,
    prev_nu: Vec<f64>,
    /// The carried multipliers saved while a Newton step is judged.
    backup_k: usize,
    backup_key: Vec<(usize, usize)>,
    backup_nu: Vec<f64>,
    /// Subproblem right-hand side and dual scratch.
    r: Vec<f64>,
    lam: Vec<f64>,
    ds: active::ActiveScratch,
    /// Newton scratch: the structured Hessian and its KKT solves.
    newton: newton::Newton,
    /// What the factors kept in `newton` were built for: the free joints, the active pairs'
    /// keys, the points (see `REUSE_MOVE`).
    fact_free: Vec<usize>,
    fact_keys: Vec<(usize, usize)>,
    fact_pts: Vec<Vec2>,
    /// The next local solve starts with a Newton step (a warm tick after one that leaned).
    newton_first: bool,
    /// A control tick is being solved (not a cold solve).
    tick: bool,
    /// What the pairs (`all`) and their selection were found for: the points, the margin and
    /// the scale; `evaluated` false when none stands (a new world or problem).
    eval_pts: Vec<Vec2>,
    eval_margin: f64,
    eval_scale: f64,
    evaluated: bool,
    /// The pose of the last evaluation, when it was made in the solve under way.
    eval_theta: Vec<f64>,
    eval_current: bool,
    rhs: Vec<f64>,
    free: Vec<usize>,
    held_move: Vec<f64>,
    active: Vec<usize>,
    gp: Vec<f64>,
    /// Largest point move of the last accepted step, m.
    last_move: f64,
    /// Cold solves: watch for the best optimum so far (`best`), and the optima's poses.
    pub watch_best: bool,
    pub best: Vec<f64>,
    pub second: Vec<f64>,
    pub free_opt: Vec<f64>,
    /// Flip starts: the pose they start from, its points, the obstacles to carry it across.
    flip_src: Vec<f64>,
    flip_pts: Vec<Vec2>,
    flip_mark: Vec<bool>,
    /// The last answer leaned on an obstacle (some pair's multiplier positive): the next local
    /// solve goes straight to the constrained form.
    pub engaged: bool,
}

/// How one local solve among obstacles ended.
#[derive(Debug, Clone, Copy)]
pub(super) struct ClearLocal {
    pub converged: bool,
    pub joined_best: bool,
    pub tip_error: f64,
    pub iterations: usize,
}

/// An evaluated iterate.
#[derive(Debug, Clone, Copy)]
struct At {
    c: Vec2,
    cn: f64,
    /// Stationarity residual with the current multipliers, rad.
    s: f64,
    /// `max(0, clearance_m - least clearance)`, m.
    viol: f64,
    /// Largest `nu_j * (c_j - clearance_m)` over pairs with positive slack, rad.
    comp: f64,
}

impl At {
    fn residual(&self, scale: f64) -> f64 {
        (self.cn + self.viol) / scale + self.s + self.comp
    }
}

/// The linearized subproblem's data (rows: the two of `J`, then one per selected pair).
struct Qp<'a> {
    n: usize,
    k2: usize,
    /// The rows, `n` each: the two of `J`, then the pairs' gradients.
    rows: &'a [f64],
    theta0: &'a [f64],
    theta: &'a [f64],
    lo: &'a [f64],
    hi: &'a [f64],
    r: &'a [f64],
    rho_inv: f64,
}

impl Qp<'_> {
    fn row(&self, i: usize) -> &[f64] {
        &self.rows[i * self.n..(i + 1) * self.n]
    }
}

/// The merit's weight for a multiplier of norm `norm`, from the current weight `w` (as
/// without obstacles: raised below the exact penalty's bound, lowered after an exact step when
/// far above it).
fn weight(w: f64, norm: f64, elastic: bool, scale: f64) -> f64 {
    let wanted = 2.0 * norm + 1e-6 / scale;
    if w < 1.1 * norm || (!elastic && w > 10.0 * wanted) {
        wanted
    } else {
        w
    }
}

/// The (link, obstacle) pairs that can be near contact while the pose stays near the one they
/// were found at: every pair whose clearance was at most `reach` at the points `pts`. A link's
/// clearance moves by at most the largest move of its two ends, so while every point is within
/// `d` of `pts`, a pair whose clearance is now at most `reach - d` is among them: a search of a
/// margin `m` with `m + d <= reach` reads the candidates alone, exactly, and only a pose that
/// strayed further searches the world again (with [`CANDIDATE_SLACK`] to spare). Each
/// candidate keeps the clearance it was last measured at and its link's ends then, so that
/// by the same bound only those that can have come within the margin since are measured again.
#[derive(Debug, Default)]
struct Candidates {
    keys: Vec<CandidatePair>,
    pts: Vec<Vec2>,
    reach: f64,
}

/// One candidate pair and where it was last measured.
#[derive(Debug, Clone, Copy)]
struct CandidatePair {
    link: usize,
    obstacle: usize,
    /// Its clearance when last measured, m...
    was: f64,
    /// ...with its link's two ends there.
    ends: [Vec2; 2],
}

impl CandidatePair {
    fn of(q: &Pair, pts: &[Vec2]) -> Self {
        Self {
            link: q.link,
            obstacle: q.obstacle,
            was: q.clearance_m,
            ends: [pts[q.link - 1], pts[q.link]],
        }
    }

    /// Whether its clearance at `pts` can be at most `margin_m`: its link's ends moved at
    /// least `was - margin_m` since it was measured (the bound of [`Candidates`]).
    fn may_be_within(&self, pts: &[Vec2], margin_m: f64) -> bool {
        let gap = self.was - margin_m;
        // A NaN (margin or clearance) is measured too.
        if gap.is_nan() || gap <= 0.0 {
            return true;
        }
        let g2 = gap * gap;
        (pts[self.link - 1] - self.ends[0]).norm_squared() >= g2
            || (pts[self.link] - self.ends[1]).norm_squared() >= g2
    }

    /// Measures it at `pts`, and remembers where.
    fn measure(&mut self, world: &World, pts: &[Vec2]) -> Pair {
        let q = world.pair(pts, self.link, self.obstacle);
        self.was = q.clearance_m;
        self.ends = [pts[self.link - 1], pts[self.link]];
        q
    }
}

/// The candidates are found with this fraction of the mean link length beyond the margin asked.
const CANDIDATE_SLACK: f64 = 0.1;

/// What the solve sees of a pair's clearance: its own, raised by how far below `clearance_m`
/// the pair may be (see [`Overall::set_floors`]), so that every constraint reads
/// `clearance_m` whatever its floor. Never lower than the pair's own, so that a search for
/// the pairs whose clearance is within a margin finds every pair the solve sees within it.
#[derive(Debug, Clone, Copy)]
struct Allowance<'a> {
    per_pair: &'a [f64],
    obstacles: usize,
}

impl Allowance<'_> {
    /// Whether no pair has one: the solve sees the clearances as they are.
    fn none(&self) -> bool {
        self.per_pair.is_empty()
    }

    /// The clearance the solve sees of `q`, m.
    fn seen(&self, q: &Pair) -> f64 {
        let raise = q
            .link
            .checked_sub(1)
            .and_then(|l| self.per_pair.get(l * self.obstacles + q.obstacle))
            .copied()
            .unwrap_or(0.0);
        q.clearance_m + raise
    }
}

impl Candidates {
    /// Largest move of a point of `pts` from where the candidates were found; infinite for
    /// points of another chain.
    fn stray(&self, pts: &[Vec2]) -> f64 {
        if pts.len() != self.pts.len() {
            return f64::INFINITY;
        }
        self.pts
            .iter()
            .zip(pts)
            .fold(0.0_f64, |most, (a, b)| most.max((a - b).norm()))
    }

    /// [`World::near_pairs`] of `pts` for `margin_m`, in the same order, through the candidates
    /// (found again first when `pts` strayed too far).
    fn near_pairs(
        &mut self,
        world: &World,
        pts: &[Vec2],
        margin_m: f64,
        mean_link: f64,
        allow: Allowance,
        out: &mut Vec<Pair>,
    ) {
        let strayed = self.stray(pts);
        // False for a NaN too: the world is then searched.
        let covered = margin_m + strayed <= self.reach;
        if !covered {
            self.reach = margin_m + CANDIDATE_SLACK * mean_link;
            world.near_pairs(pts, self.reach, out);
            self.keys.clear();
            self.keys
                .extend(out.iter().map(|q| CandidatePair::of(q, pts)));
            self.pts.clone_from_slice(pts);
        } else {
            out.clear();
            for key in &mut self.keys {
                if key.may_be_within(pts, margin_m) {
                    out.push(key.measure(world, pts));
                }
            }
        }
        if !allow.none() {
            for q in out.iter_mut() {
                q.clearance_m = allow.seen(q);
            }
        }
        out.retain(|q| q.clearance_m <= margin_m);
    }

    /// The least clearance (as `allow` has the solve see it) of `pts` when below `floor_m`,
    /// else infinity: through the candidates when they cover it, else a search of the world
    /// (into `spare` when some pair has an allowance).
    fn least_below(
        &mut self,
        world: &World,
        pts: &[Vec2],
        floor_m: f64,
        allow: Allowance,
        spare: &mut Vec<Pair>,
    ) -> f64 {
        let strayed = self.stray(pts);
        if floor_m + strayed <= self.reach {
            let least = self
                .keys
                .iter_mut()
                .filter(|key| key.may_be_within(pts, floor_m))
                .map(|key| allow.seen(&key.measure(world, pts)))
                .fold(f64::INFINITY, f64::min);
            if least < floor_m {
                least
            } else {
                f64::INFINITY
            }
        } else if allow.none() {
            world
                .clearance_below(pts, floor_m)
                .map_or(f64::INFINITY, |q| q.clearance_m)
        } else {
            world.near_pairs(pts, floor_m, spare);
            let least = spare
                .iter()
                .map(|q| allow.seen(q))
                .fold(f64::INFINITY, f64::min);
            if least < floor_m {
                least
            } else {
                f64::INFINITY
            }
        }
    }
}

impl ClearWork {
    /// Sizes the buffers for `n` joints among `obstacles` obstacles.
    pub fn resize(&mut self, n: usize, obstacles: usize) {
        if self.n == n && self.obstacles == obstacles && self.pts.len() == n + 1 {
            return;
        }
        self.n = n;
        self.obstacles = obstacles;
        for v in [&mut self.pts, &mut self.trial_pts] {
            *v = vec![Vec2::zeros(); n + 1];
        }
        for v in [
            &mut self.jx,
            &mut self.jy,
            &mut self.trial,
            &mut self.fd_theta,
            &mut self.qp_x,
            &mut self.held_move,
            &mut self.gp,
            &mut self.best,
            &mut self.second,
            &mut self.free_opt,
            &mut self.flip_src,
        ] {
            *v = vec![0.0; n];
        }
        let pairs = (n * obstacles).max(1);
        // The floors in force are kept (set for this world before its first solve).
        self.allow.reserve(pairs.saturating_sub(self.allow.len()));
        self.spare = Vec::with_capacity(pairs);
        self.all = Vec::with_capacity(pairs);
        self.order = Vec::with_capacity(pairs);
        self.cand = Candidates {
            keys: Vec::with_capacity(pairs),
            pts: vec![Vec2::zeros(); n + 1],
            reach: f64::NEG_INFINITY,
        };
        self.key = vec![(0, 0); MAX_PAIRS];
        self.prev_key = vec![(0, 0); MAX_PAIRS];
        self.clr = vec![0.0; MAX_PAIRS];
        self.contact = vec![Vec2::zeros(); MAX_PAIRS];
        self.grad = vec![0.0; MAX_PAIRS * n];
        self.qp_rows = vec![0.0; (MAX_PAIRS + 2) * n];
        self.nu = vec![0.0; MAX_PAIRS];
        self.prev_nu = vec![0.0; MAX_PAIRS];
        self.backup_key = vec![(0, 0); MAX_PAIRS];
        self.backup_nu = vec![0.0; MAX_PAIRS];
        self.prev_k = 0;
        let k2 = MAX_PAIRS + 2;
        self.r = vec![0.0; k2];
        self.lam = vec![0.0; k2];
        self.ds = active::ActiveScratch::new(n, k2);
        self.rhs = vec![0.0; n + k2];
        if n <= NEWTON_MAX_JOINTS {
            self.newton.reserve(n, MAX_PAIRS);
        }
        self.free = Vec::with_capacity(n);
        self.active = Vec::with_capacity(MAX_PAIRS);
        self.fact_free = Vec::with_capacity(n);
        self.fact_keys = Vec::with_capacity(MAX_PAIRS);
        self.fact_pts = vec![Vec2::zeros(); n + 1];
        self.flip_pts = vec![Vec2::zeros(); n + 1];
        self.flip_mark = vec![false; obstacles];
        self.eval_pts = vec![Vec2::zeros(); n + 1];
        self.evaluated = false;
        self.eval_theta = vec![0.0; n];
        self.eval_current = false;
        self.newton.forget();
        self.engaged = false;
    }

    /// Forgets the pairs' multipliers and the kept Newton factors (a new problem, or a start
    /// of a cold solve).
    pub fn forget(&mut self) {
        self.prev_k = 0;
        self.newton.forget();
        self.evaluated = false;
    }

    /// The pair (link, obstacle) of least clearance among those the last evaluation found
    /// near contact, if any.
    fn nearest(&self) -> Option<(usize, usize)> {
        self.all
            .iter()
            .min_by(|a, b| a.clearance_m.total_cmp(&b.clearance_m))
            .map(|q| (q.link, q.obstacle))
    }

    /// The least clearance among the pairs the last evaluation found within its margin
    /// (infinite when none).
    fn least_found(&self) -> f64 {
        self.all
            .iter()
            .fold(f64::INFINITY, |m, q| m.min(q.clearance_m))
    }

    /// Whether some pair carried a positive multiplier out of the last solve.
    fn leaning(&self) -> bool {
        self.prev_nu[..self.prev_k].iter().any(|&v| v > 0.0)
    }

    /// The selected pairs whose multiplier is not zero (the first of the count): the others
    /// add nothing to `theta0 + A^T lambda`, and most pairs near contact do not lean.
    fn nonzero_nu(&self) -> ([usize; MAX_PAIRS], usize) {
        let mut leaning = [0; MAX_PAIRS];
        let mut count = 0;
        for j in 0..self.k {
            if self.nu[j] != 0.0 {
                leaning[count] = j;
                count += 1;
            }
        }
        (leaning, count)
    }

    /// Keeps the selected pairs' multipliers `nu[..k]` for the next selection.
    fn remember(&mut self) {
        self.prev_k = self.k;
        self.prev_key[..self.k].copy_from_slice(&self.key[..self.k]);
        self.prev_nu[..self.k].copy_from_slice(&self.nu[..self.k]);
    }

    /// Evaluates `theta`: points, tip Jacobian, the selected pairs with their multipliers
    /// (carried by key), and the residuals for the tip multiplier `mu`; `newton` when a Newton
    /// step comes next (see [`NEWTON_MARGIN`]).
    #[allow(clippy::too_many_arguments)]
    fn eval(
        &mut self,
        p: &Problem,
        world: &World,
        theta: &[f64],
        lo: &[f64],
        hi: &[f64],
        mu: [f64; 2],
        newton: bool,
    ) -> At {
        let n = self.n;
        p.chain.points_into(theta, &mut self.pts);
        let tip = self.pts[n];
        for a in 0..n {
            let r = tip - self.pts[a];
            self.jx[a] = -r.y;
            self.jy[a] = r.x;
        }
        let c = p.target - tip;
        let cm = world.clearance_m();
        let mean_link = p.chain.reach() / n.max(1) as f64;
        let moves = c.norm().max(self.last_move).min(mean_link);
        let margin = if newton && self.tick {
            cm + NEWTON_MARGIN * mean_link
        } else {
            cm + MARGIN_MOVES * moves + MARGIN_FLOOR * mean_link
        };
        // The pairs and their selection depend on the points and the margin alone: those of
        // the last evaluation stand for the same (a tick's start is the last tick's answer).
        let same = self.evaluated
            && margin == self.eval_margin
            && p.scale == self.eval_scale
            && self.eval_pts == self.pts;
        if !same {
            let allow = Allowance {
                per_pair: &self.allow,
                obstacles: self.obstacles,
            };
            self.cand
                .near_pairs(world, &self.pts, margin, mean_link, allow, &mut self.all);
            self.select(p.scale);
            self.eval_pts.clone_from(&self.pts);
            (self.eval_margin, self.eval_scale) = (margin, p.scale);
            self.evaluated = true;
        }
        self.eval_theta.copy_from_slice(theta);
        self.eval_current = true;
        let least = self.least_found();
        // Multipliers by key.
        for j in 0..self.k {
            self.nu[j] = (0..self.prev_k)
                .find(|&i| self.prev_key[i] == self.key[j])
                .map_or(0.0, |i| self.prev_nu[i]);
        }
        let mut s: f64 = 0.0;
        let (leaning, count) = self.nonzero_nu();
        for a in 0..n {
            let mut u = p.theta0[a] + self.jx[a] * mu[0] + self.jy[a] * mu[1];
            for &j in &leaning[..count] {
                u += self.nu[j] * self.grad[j * n + a];
            }
            s = s.max((theta[a] - u.clamp(lo[a], hi[a])).abs());
        }
        let comp = (0..self.k).fold(0.0_f64, |m, j| {
            m.max(self.nu[j] * (self.clr[j] - cm).max(0.0))
        });
        At {
            c,
            cn: c.norm(),
            s,
            viol: (cm - least).max(0.0),
            comp,
        }
    }

    /// Picks the pairs of `all` that enter the subproblem (see the module doc).
    fn select(&mut self, scale: f64) {
        let n = self.n;
        self.order.clear();
        self.order.extend(0..self.all.len());
        let pairs = &self.all;
        if self.order.len() > MAX_PAIRS {
            self.order.select_nth_unstable_by(MAX_PAIRS - 1, |&a, &b| {
                pairs[a].clearance_m.total_cmp(&pairs[b].clearance_m)
            });
            self.order.truncate(MAX_PAIRS);
        }
        self.k = 0;
        for &i in &self.order {
            let q = &pairs[i];
            let same = (0..self.k).any(|j| {
                self.key[j].1 == q.obstacle
                    && (self.contact[j] - q.contact.on_segment).norm() <= SAME_CONTACT * scale
            });
            if same {
                continue;
            }
            let j = self.k;
            self.key[j] = (q.link, q.obstacle);
            self.clr[j] = q.clearance_m;
            self.contact[j] = q.contact.on_segment;
            pair_gradient(&self.pts, q, &mut self.grad[j * n..(j + 1) * n]);
            self.k += 1;
        }
    }

    /// One local solve from `theta` (updated in place) with the tip multiplier `mu` and the
    /// pairs' multipliers remembered by key.
    #[allow(clippy::too_many_arguments)]
    pub fn local(
        &mut self,
        p: &Problem,
        world: &World,
        lo: &[f64],
        hi: &[f64],
        theta: &mut [f64],
        mu: &mut [f64; 2],
        tol: f64,
        max_iterations: usize,
        stall_steps: usize,
    ) -> ClearLocal {
        let mut iterations = 0;
        let mut newton_ready = std::mem::take(&mut self.newton_first);
        let mut stall = ElasticStall::default();
        let (mut nu_t, mut nu_c) = (0.0, 0.0);
        self.last_move = 0.0;
        // The least optimality residual so far and the iterations since it last fell by 1%.
        let (mut best_residual, mut since) = (f64::INFINITY, 0);
        // The evaluation a taken Newton step already made of the pose it reached.
        let mut evaluated: Option<At> = None;
        loop {
            let at = match evaluated.take() {
                Some(at) => at,
                None => self.eval(p, world, theta, lo, hi, *mu, newton_ready),
            };
            let residual = at.residual(p.scale);
            if residual < super::ELASTIC_STALL_RATIO * best_residual {
                (best_residual, since) = (residual, 0);
            } else {
                since += 1;
            }
            let ctol = tol;
            let converged = at.cn <= tol && at.viol <= ctol && at.s <= p.stol && at.comp <= p.stol;
            let stop = |converged: bool, joined: bool, iterations: usize| ClearLocal {
                converged,
                joined_best: joined,
                tip_error: at.cn,
                iterations,
            };
            if self.watch_best
                && at.cn <= super::JOIN_BEST_TIP * p.scale
                && at.viol <= super::JOIN_BEST_TIP * p.scale
                && max_abs_diff(theta, &self.best) <= super::JOIN_BEST_POSE
            {
                return stop(false, true, iterations);
            }
            if converged {
                return stop(true, false, iterations);
            }
            if iterations >= max_iterations || since > stall_steps {
                return stop(false, false, iterations);
            }
            iterations += 1;
            if newton_ready && self.n <= NEWTON_MAX_JOINTS {
                // With the kept factors when they fit, then (if that step was refused) fresh.
                // After a refused step the scratch holds the refused pose's evaluation: back to
                // `theta`'s before anything else reads it.
                let (mut next, reused) =
                    self.try_newton(p, world, lo, hi, theta, mu, &at, tol, true);
                if next.is_none() && reused {
                    self.eval(p, world, theta, lo, hi, *mu, false);
                    next = self
                        .try_newton(p, world, lo, hi, theta, mu, &at, tol, false)
                        .0;
                }
                if let Some(next) = next {
                    evaluated = Some(next);
                    continue;
                }
                self.eval(p, world, theta, lo, hi, *mu, false);
            }
            let round_off = |at: &At| {
                at.cn <= tol
                    && at.viol <= ctol
                    && at.s.max(at.comp) <= p.stol.max(super::ROUND_OFF_STATIONARITY)
            };
            match self.sqp_step(
                p, world, lo, hi, theta, mu, &at, tol, &mut stall, &mut nu_t, &mut nu_c,
            ) {
                ControlFlow::Continue(full) => {
                    newton_ready = full || at.cn < super::NEWTON_RANGE * p.scale
                }
                ControlFlow::Break(()) => {
                    // With the multipliers of the last subproblem (no step left: optimal up
                    // to round-off when the conditions hold with them).
                    let last = self.eval(p, world, theta, lo, hi, *mu, false);
                    return ClearLocal {
                        converged: round_off(&last),
                        joined_best: false,
                        tip_error: last.cn,
                        iterations,
                    };
                }
            }
        }
    }

    /// One SQP iteration; `Continue(true)` after an exact step taken whole, `Break` when no
    /// step is left or none decreases the merit.
    #[allow(clippy::too_many_arguments)]
    fn sqp_step(
        &mut self,
        p: &Problem,
        world: &World,
        lo: &[f64],
        hi: &[f64],
        theta: &mut [f64],
        mu: &mut [f64; 2],
        at: &At,
        tol: f64,
        stall: &mut ElasticStall,
        nu_t: &mut f64,
        nu_c: &mut f64,
    ) -> ControlFlow<(), bool> {
        let n = self.n;
        let k2 = self.k + 2;
        let cm = world.clearance_m();
        self.r[0] = at.c.x;
        self.r[1] = at.c.y;
        for j in 0..self.k {
            self.r[2 + j] = cm - self.clr[j];
        }
        let qp_tol = (super::QP_TOLERANCE * tol).max(super::QP_TOLERANCE_FLOOR * p.scale);
        // The subproblem's rows in one block (read row by row in its inner loops).
        self.qp_rows[..n].copy_from_slice(&self.jx);
        self.qp_rows[n..2 * n].copy_from_slice(&self.jy);
        self.qp_rows[2 * n..k2 * n].copy_from_slice(&self.grad[..self.k * n]);
        let mut elastic = false;
        let mut solved = false;
        for (attempt, rho) in [0.0]
            .iter()
            .chain(super::ELASTIC_WEIGHTS.iter())
            .enumerate()
        {
            if attempt == 0 {
                self.lam[0] = mu[0];
                self.lam[1] = mu[1];
                self.lam[2..k2].copy_from_slice(&self.nu[..self.k]);
            } else {
                if attempt == 1 && stall.elastic(at.cn + at.viol) {
                    return ControlFlow::Break(());
                }
                self.lam[..k2].iter_mut().for_each(|l| *l = 0.0);
            }
            let qp = Qp {
                n,
                k2,
                rows: &self.qp_rows,
                theta0: p.theta0,
                theta,
                lo,
                hi,
                r: &self.r,
                rho_inv: rho * p.scale * p.scale,
            };
            let cap = if attempt == 0 {
                super::MU_CAP / p.scale
            } else {
                f64::MAX
            };
            if qp.solve_active(&mut self.lam, &mut self.qp_x, &mut self.ds, qp_tol, cap) {
                elastic = attempt > 0;
                solved = true;
                break;
            }
        }
        if !solved {
            return ControlFlow::Break(());
        }
        if !elastic {
            stall.exact();
        }
        // Direction and its predicted effects.
        let mut largest: f64 = 0.0;
        let mut metric_slope = 0.0;
        let mut tip_move = Vec2::zeros();
        for a in 0..n {
            let d = self.qp_x[a] - theta[a];
            largest = largest.max(d.abs());
            metric_slope += (theta[a] - p.theta0[a]) * d;
            tip_move.x += self.jx[a] * d;
            tip_move.y += self.jy[a] * d;
        }
        let pose_size = 1.0 + theta.iter().fold(0.0_f64, |m, t| m.max(t.abs()));
        if largest <= super::STEP_FLOOR * pose_size {
            *mu = [self.lam[0], self.lam[1]];
            self.nu[..self.k].copy_from_slice(&self.lam[2..k2]);
            self.remember();
            return ControlFlow::Break(());
        }
        let mut lin_least = f64::INFINITY;
        for j in 0..self.k {
            let g = &self.grad[j * n..(j + 1) * n];
            let gd: f64 = g
                .iter()
                .zip(&self.qp_x)
                .zip(theta.iter())
                .map(|((g, x), t)| g * (x - t))
                .sum();
            lin_least = lin_least.min(self.clr[j] + gd);
        }
        let lin_viol = (cm - lin_least).max(0.0);
        let nu_sum: f64 = self.lam[2..k2].iter().sum();
        *nu_t = weight(*nu_t, self.lam[0].hypot(self.lam[1]), elastic, p.scale);
        *nu_c = weight(*nu_c, nu_sum, elastic, p.scale);
        let slope = metric_slope
            + *nu_t * ((at.c - tip_move).norm() - at.cn)
            + *nu_c * (lin_viol - at.viol);
        let merit0 = half_metric(theta, p.theta0) + *nu_t * at.cn + *nu_c * at.viol;
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            for a in 0..n {
                self.trial[a] = if alpha == 1.0 {
                    self.qp_x[a]
                } else {
                    theta[a] + alpha * (self.qp_x[a] - theta[a])
                };
            }
            p.chain.points_into(&self.trial, &mut self.trial_pts);
            let tip_err = (self.trial_pts[n] - p.target).norm();
            // Only a clearance below `clearance_m` counts in the merit.
            let allow = Allowance {
                per_pair: &self.allow,
                obstacles: self.obstacles,
            };
            let least = self
                .cand
                .least_below(world, &self.trial_pts, cm, allow, &mut self.spare);
            let m = half_metric(&self.trial, p.theta0)
                + *nu_t * tip_err
                + *nu_c * (cm - least).max(0.0);
            if m <= merit0 + ARMIJO * alpha * slope.min(0.0) {
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            return ControlFlow::Break(());
        }
        self.last_move = self
            .pts
            .iter()
            .zip(&self.trial_pts)
            .fold(0.0_f64, |m, (a, b)| m.max((a - b).norm()));
        theta.copy_from_slice(&self.trial);
        *mu = [self.lam[0], self.lam[1]];
        self.nu[..self.k].copy_from_slice(&self.lam[2..k2]);
        self.remember();
        ControlFlow::Continue(!elastic && alpha == 1.0)
    }

    /// The Newton step on the optimality conditions (see the module doc); when taken, the
    /// evaluation of the pose it reached, with `theta`, `mu` and the pairs' multipliers
    /// updated (the scratch holds that pose). With `reuse`, solves with the kept factors
    /// when they fit (see [`REUSE_MOVE`]); the second value says whether it did.
    #[allow(clippy::too_many_arguments)]
    fn try_newton(
        &mut self,
        p: &Problem,
        world: &World,
        lo: &[f64],
        hi: &[f64],
        theta: &mut [f64],
        mu: &mut [f64; 2],
        at: &At,
        tol: f64,
        reuse: bool,
    ) -> (Option<At>, bool) {
        let n = self.n;
        let cm = world.clearance_m();
        // Active set: joints held at bounds, pairs leaning or not clear.
        self.free.clear();
        let (leaning, count) = self.nonzero_nu();
        for a in 0..n {
            let mut u = p.theta0[a] + self.jx[a] * mu[0] + self.jy[a] * mu[1];
            for &j in &leaning[..count] {
                u += self.nu[j] * self.grad[j * n + a];
            }
            self.held_move[a] = if u <= lo[a] {
                lo[a] - theta[a]
            } else if u >= hi[a] {
                hi[a] - theta[a]
            } else {
                self.free.push(a);
                0.0
            };
        }
        self.active.clear();
        for j in 0..self.k {
            if self.nu[j] > 0.0 || self.clr[j] < cm {
                self.active.push(j);
            }
        }
        let m = self.free.len();
        let ka = self.active.len();
        if m < 2 {
            return (None, false);
        }
        let reused = reuse && self.factors_fit(p.scale);
        if !reused {
            // Lagrangian Hessian I + G - sum nu_j H_j in structured form (module `newton`).
            let pts = &self.pts[..=n];
            self.newton.begin(pts, *mu);
            for &j in &self.active {
                let (link, obstacle) = self.key[j];
                if self.nu[j] != 0.0 {
                    let h = FD_STEP * p.scale;
                    self.newton
                        .add_pair(world, pts, link, obstacle, self.nu[j], h);
                }
            }
        }
        // Right-hand side: the free rows, then the tip's two and one per active pair.
        let size = m + 2 + ka;
        if self.held_move.iter().any(|&v| v != 0.0) {
            self.newton.apply(&self.held_move, &mut self.gp);
        } else {
            self.gp.iter_mut().for_each(|v| *v = 0.0);
        }
        for (r, &a) in self.free.iter().enumerate() {
            self.rhs[r] = -(theta[a] - p.theta0[a]) - self.gp[a];
        }
        let (mut hx, mut hy) = (0.0, 0.0);
        for b in 0..n {
            hx += self.jx[b] * self.held_move[b];
            hy += self.jy[b] * self.held_move[b];
        }
        self.rhs[m] = at.c.x - hx;
        self.rhs[m + 1] = at.c.y - hy;
        for (i, &j) in self.active.iter().enumerate() {
            let g = &self.grad[j * n..(j + 1) * n];
            let gh: f64 = g.iter().zip(&self.held_move).map(|(g, d)| g * d).sum();
            self.rhs[m + 2 + i] = cm - self.clr[j] - gh;
        }
        let solved = if reused {
            // The factors' constraint rows are those of another pose: solve for the
            // multipliers' change, the stationarity residual taken with today's rows and
            // multipliers (the fresh step's absolute form would carry the rows' change
            // times the multipliers into the answer).
            for (r, &a) in self.free.iter().enumerate() {
                let mut at_lambda = self.jx[a] * mu[0] + self.jy[a] * mu[1];
                for &j in &self.active {
                    at_lambda += self.grad[j * n + a] * self.nu[j];
                }
                self.rhs[r] += at_lambda;
            }
            let ok = self.newton.solve_again(&mut self.rhs[..size]);
            self.rhs[m] += mu[0];
            self.rhs[m + 1] += mu[1];
            for (i, &j) in self.active.iter().enumerate() {
                self.rhs[m + 2 + i] += self.nu[j];
            }
            ok
        } else {
            let (jx, jy, grad, active) = (&self.jx, &self.jy, &self.grad, &self.active);
            let row = |i: usize, a: usize| match i {
                0 => jx[a],
                1 => jy[a],
                _ => grad[active[i - 2] * n + a],
            };
            let ok = self
                .newton
                .solve_kkt(&self.free, 2 + ka, row, &mut self.rhs[..size]);
            // What the factors just kept were built for.
            self.fact_free.clone_from(&self.free);
            self.fact_keys.clear();
            self.fact_keys
                .extend(self.active.iter().map(|&j| self.key[j]));
            self.fact_pts.copy_from_slice(&self.pts[..=n]);
            ok
        };
        if !solved {
            return (None, reused);
        }
        // New multipliers: none of a pair may turn negative.
        for (i, &j) in self.active.iter().enumerate() {
            let v = self.rhs[m + 2 + i];
            if v < -NEGATIVE_NU * (1.0 + self.nu[j].abs()) {
                return (None, reused);
            }
        }
        let mut largest: f64 = 0.0;
        for a in 0..n {
            largest = largest.max(self.held_move[a].abs());
            self.trial[a] = theta[a] + self.held_move[a];
        }
        for (r, &a) in self.free.iter().enumerate() {
            let d = self.rhs[r];
            largest = largest.max(d.abs());
            self.trial[a] = (theta[a] + d).clamp(lo[a], hi[a]);
        }
        if largest.is_nan() || largest > super::NEWTON_MAX_MOVE {
            return (None, reused);
        }
        let mu_n = [self.rhs[m], self.rhs[m + 1]];
        // Carry the new multipliers by key (the old ones kept to restore), then judge the step
        // at the new pose.
        self.backup_k = self.prev_k;
        self.backup_key[..self.prev_k].copy_from_slice(&self.prev_key[..self.prev_k]);
        self.backup_nu[..self.prev_k].copy_from_slice(&self.prev_nu[..self.prev_k]);
        self.nu[..self.k].iter_mut().for_each(|v| *v = 0.0);
        for (i, &j) in self.active.iter().enumerate() {
            self.nu[j] = self.rhs[m + 2 + i].max(0.0);
        }
        self.remember();
        self.fd_theta.copy_from_slice(theta);
        theta.copy_from_slice(&self.trial);
        let next = self.eval(p, world, theta, lo, hi, mu_n, true);
        let converged =
            next.cn <= tol && next.viol <= tol && next.s <= p.stol && next.comp <= p.stol;
        if converged || next.residual(p.scale) <= super::NEWTON_CONTRACTION * at.residual(p.scale) {
            *mu = mu_n;
            return (Some(next), reused);
        }
        theta.copy_from_slice(&self.fd_theta);
        self.prev_k = self.backup_k;
        self.prev_key[..self.prev_k].copy_from_slice(&self.backup_key[..self.prev_k]);
        self.prev_nu[..self.prev_k].copy_from_slice(&self.backup_nu[..self.prev_k]);
        (None, reused)
    }

    /// Whether the kept factors fit the Newton step about to be taken: built for the same
    /// free joints and active pairs, at points within [`REUSE_MOVE`] of these.
    fn factors_fit(&self, scale: f64) -> bool {
        self.newton.has_factors()
            && self.fact_free == self.free
            && self.fact_keys.len() == self.active.len()
            && self
                .fact_keys
                .iter()
                .zip(&self.active)
                .all(|(key, &j)| *key == self.key[j])
            && self
                .fact_pts
                .iter()
                .zip(&self.pts)
                .all(|(a, b)| (a - b).norm() <= REUSE_MOVE * scale)
    }
}

/// The kinds of start of a cold solve among obstacles, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ClearStart {
    Clipped,
    FreeOptimum,
    StraightPath,
    PolarPath,
    Mirror(usize),
    MirrorFree,
    /// The flip starts (`Overall::flip_starts`), all at this place in the order.
    Flips,
    Random,
}

impl ClearStart {
    fn at(index: usize) -> Self {
        match index {
            0 => Self::Clipped,
            1 => Self::FreeOptimum,
            2 => Self::StraightPath,
            3 => Self::PolarPath,
            4 => Self::Mirror(0),
            5 => Self::Mirror(1),
            6 => Self::MirrorFree,
            7 => Self::Flips,
            _ => Self::Random,
        }
    }
    /// The fixed starts, before the flips.
    const FIXED: usize = 7;
}

impl Overall {
    /// Sets the obstacles every answer keeps clear of (`None`, or a world without obstacles:
    /// none, and every solve is exactly the one without a world). Forgets the pairs'
    /// multipliers carried from tick to tick, and the floors ([`Overall::set_floors`]).
    pub fn set_world(&mut self, world: Option<World>) {
        self.world = world;
        self.clear.allow.clear();
        self.clear.forget();
        self.clear.cand.reach = f64::NEG_INFINITY;
        self.clear.engaged = false;
        self.last_clearance = None;
    }

    /// The world in use, if any.
    pub fn world(&self) -> Option<&World> {
        self.world.as_ref()
    }

    /// The least clearance of the last answer (m; see [`World::clearance`]), or `None` when
    /// the world in use has no obstacles. Says whether a start that was not clear got out.
    /// With floors in force, the least the solve sees (see [`Overall::set_floors`]).
    pub fn last_clearance(&self) -> Option<f64> {
        self.last_clearance
    }

    /// Whether a world with obstacles is in use.
    pub(super) fn among_obstacles(&self) -> bool {
        self.world
            .as_ref()
            .is_some_and(|w| !w.obstacles().is_empty())
    }

    /// The exact least clearance of `pose` (obstacles present), over every pair of the world;
    /// the last evaluation's nearest pair looked at first, as a bound. With floors in force
    /// ([`Overall::set_floors`]), the least the solve sees, or a mean link length beyond
    /// `clearance_m` when no pair is within that.
    fn least_clearance(&mut self, world: &World, chain: &Chain, pose: &[f64]) -> f64 {
        let c = &mut self.clear;
        chain.points_into(pose, &mut c.pts);
        if c.allow.is_empty() {
            let hint = c.nearest();
            return world
                .clearance_from(&c.pts, hint)
                .map_or(f64::INFINITY, |q| q.clearance_m);
        }
        let reach = world.clearance_m() + chain.reach() / chain.len().max(1) as f64;
        world.near_pairs(&c.pts, reach, &mut c.spare);
        let allow = Allowance {
            per_pair: &c.allow,
            obstacles: c.obstacles,
        };
        c.spare.iter().map(|q| allow.seen(q)).fold(reach, f64::min)
    }

    /// Lets pairs of link and obstacle keep less than the world's clearance: the floor of link
    /// `l` (from 1) and obstacle `k`, `floors[(l - 1) * m + k]` with `m` obstacles, is the least
    /// clearance the pair must keep, m, and one at or above `clearance_m` changes nothing. For a control tick from a pose not clear (an
    /// obstacle put onto the arm), whose links need only come no closer: with the whole
    /// clearance asked of every link, a link deep inside an obstacle leaves the solve no pose
    /// near the last, and the arm could not move. Empty: every pair keeps `clearance_m`. In
    /// force until changed; a new world clears them. [`Overall::last_clearance`] is then the
    /// least clearance the solve sees, each pair's raised by how far its floor is below
    /// `clearance_m`.
    pub fn set_floors(&mut self, floors: &[f64]) {
        let c = &mut self.clear;
        if floors.is_empty() && c.allow.is_empty() {
            return;
        }
        let cm = self.world.as_ref().map_or(0.0, World::clearance_m);
        c.allow.clear();
        // A NaN floor allows nothing.
        c.allow.extend(floors.iter().map(|&f| (cm - f).max(0.0)));
        c.evaluated = false;
    }

    /// Records the answer's clearance and takes `converged` back unless it is clear.
    fn judge(&mut self, world: &World, chain: &Chain, out: &[f64], mut o: Outcome) -> Outcome {
        let least = self.least_clearance(world, chain, out);
        self.last_clearance = Some(least);
        o.converged &= least >= world.clearance_m() - CLEAR_SLACK;
        o
    }

    /// [`Overall::solve_local`] among obstacles.
    pub(super) fn local_among(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        self.among(
            Self::free_local,
            Self::local_with,
            chain,
            theta0,
            target,
            out,
        )
    }

    /// Runs `with` on the world in use (lent out for the call), or `free` without one.
    fn among(
        &mut self,
        free: FreeSolve,
        with: WorldSolve,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        let Some(world) = self.world.take() else {
            return free(self, chain, theta0, target, out);
        };
        let o = with(self, &world, chain, theta0, target, out);
        self.world = Some(world);
        o
    }

    fn local_with(
        &mut self,
        world: &World,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        let mut spent = 0;
        if !self.clear.engaged {
            // Nothing leaned on an obstacle last time: the answer without obstacles stands when
            // it is clear (a local optimum that is feasible is one of the constrained problem).
            let o = self.free_local(chain, theta0, target, out);
            if out.len() == chain.len() && theta0.len() == chain.len() {
                self.clear.resize(chain.len(), world.obstacles().len());
                let least = self.least_clearance(world, chain, out);
                if o.converged && least >= world.clearance_m() {
                    self.last_clearance = Some(least);
                    return o;
                }
            }
            spent = o.iterations;
        }
        let p = match self.begin(chain, theta0, target, out) {
            Ok(p) => p,
            Err(o) => return self.judge_checked(world, chain, out, o),
        };
        self.clear.resize(chain.len(), world.obstacles().len());
        self.start_clipped(&p);
        let mut mu = self.mu;
        self.clear.tick = true;
        // After a tick that leaned, the factors of its last Newton step were built at about
        // this pose: its first step is Newton's, with them.
        self.clear.newton_first = self.clear.engaged && self.clear.newton.has_factors();
        self.clear.eval_current = false;
        let l = self.clear_local(&p, world, &mut mu, TICK_STALL_STEPS);
        self.clear.engaged = self.clear.leaning();
        let o = self.finish(&p, mu, spent + l.iterations, l.converged, out);
        self.judge_tick(world, chain, out, o)
    }

    /// [`Self::judge`] for a control tick: when the solve's last evaluation was of the answer
    /// and found a pair within its margin, the least of those is the answer's least clearance
    /// (exact: every other pair is beyond the margin, by the candidates' bound), and the world
    /// is not searched again. The controller checks the goal it sends against the world
    /// itself.
    fn judge_tick(&mut self, world: &World, chain: &Chain, out: &[f64], mut o: Outcome) -> Outcome {
        let c = &self.clear;
        if !(c.eval_current && c.eval_theta == out) {
            return self.judge(world, chain, out, o);
        }
        let least = c.least_found();
        if !least.is_finite() {
            return self.judge(world, chain, out, o);
        }
        self.last_clearance = Some(least);
        o.converged &= least >= world.clearance_m() - CLEAR_SLACK;
        o
    }

    /// [`Self::judge`] for an answer that may be bad input (of the wrong length).
    fn judge_checked(&mut self, world: &World, chain: &Chain, out: &[f64], o: Outcome) -> Outcome {
        if out.len() == chain.len() && out.iter().all(|t| t.is_finite()) {
            self.clear.resize(chain.len(), world.obstacles().len());
            self.judge(world, chain, out, o)
        } else {
            self.last_clearance = None;
            o
        }
    }

    /// [`Overall::solve_cold`] among obstacles.
    pub(super) fn cold_among(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        self.among(Self::free_cold, Self::cold_with, chain, theta0, target, out)
    }

    fn cold_with(
        &mut self,
        world: &World,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        self.clear.tick = false;
        // The best optimum without obstacles, when clear, is the best among them.
        let free = self.free_cold(chain, theta0, target, out);
        if out.len() != chain.len() || theta0.len() != chain.len() {
            return self.judge_checked(world, chain, out, free);
        }
        self.clear.resize(chain.len(), world.obstacles().len());
        self.clear.engaged = true;
        self.clear.forget();
        let least = self.least_clearance(world, chain, out);
        if free.converged && least >= world.clearance_m() {
            self.last_clearance = Some(least);
            return free;
        }
        let p = match self.begin(chain, theta0, target, out) {
            Ok(p) => p,
            Err(o) => return self.judge_checked(world, chain, out, o),
        };
        self.clear.free_opt.copy_from_slice(out);
        let free_on_target = free.reachable;
        let mut total = free.iterations;
        let mut podium = Podium::default();
        let mut rng = SplitMix(self.opts.seed);
        let randoms = RANDOM_FACTOR * self.opts.random_starts;
        for index in 0..ClearStart::FIXED + 1 + randoms {
            let start = ClearStart::at(index);
            let mut mu = [0.0; 2];
            self.clear.forget();
            match start {
                ClearStart::Clipped => self.start_clipped(&p),
                ClearStart::FreeOptimum => {
                    if !free_on_target {
                        continue;
                    }
                    self.w.theta.copy_from_slice(&self.clear.free_opt);
                }
                ClearStart::StraightPath | ClearStart::PolarPath => {
                    if self.opts.continuation_stages == 0 {
                        continue;
                    }
                    self.start_clipped(&p);
                    total +=
                        self.clear_continuation(world, &p, start == ClearStart::PolarPath, &mut mu);
                }
                ClearStart::Mirror(rank) => {
                    let source = if rank == 0 {
                        podium.best
                    } else {
                        podium.second
                    };
                    if !source.is_some_and(|s| s.on_target) {
                        continue;
                    }
                    let src = if rank == 0 {
                        &self.clear.best
                    } else {
                        &self.clear.second
                    };
                    mirror_pose(&p, src, &self.w.lo, &self.w.hi, &mut self.w.theta);
                }
                ClearStart::MirrorFree => {
                    if !free_on_target {
                        continue;
                    }
                    mirror_pose(
                        &p,
                        &self.clear.free_opt,
                        &self.w.lo,
                        &self.w.hi,
                        &mut self.w.theta,
                    );
                }
                ClearStart::Flips => {
                    total += self.flip_starts(&p, world, &mut podium, free_on_target);
                    continue;
                }
                ClearStart::Random => match podium.best.filter(|b| b.on_target) {
                    Some(b) => self.start_in_ball(&p, (2.0 * b.half_metric).sqrt(), &mut rng),
                    None => self.start_in_box(&p, &mut rng),
                },
            }
            let search = start == ClearStart::Random;
            total += self.run_start(&p, world, &mut podium, mu, search);
        }
        self.clear.forget();
        let Some(b) = podium.best else {
            self.w.theta.copy_from_slice(&self.clear.free_opt);
            let o = self.finish(&p, [0.0; 2], total, false, out);
            return self.judge(world, chain, out, o);
        };
        self.w.theta.copy_from_slice(&self.clear.best);
        let mut mu = b.mu;
        if !b.on_target {
            // A pose short of the target keeps its tip and its clearance when turned back by
            // whole turns: only its metric 3 drops (the answer within pi of theta0).
            self.nearest_turns(&p);
        }
        if b.on_target {
            // Once more from the answer (a step or two): its pairs' multipliers, which the
            // next local solve continues from.
            let l = self.clear_local(&p, world, &mut mu, STALL_STEPS);
            total += l.iterations;
            let Overall { w, clear, .. } = &mut *self;
            if !l.converged || half_metric(&w.theta, p.theta0) > b.half_metric * (1.0 + 1e-12) {
                w.theta.copy_from_slice(&clear.best);
                mu = b.mu;
                clear.forget();
            }
        }
        let o = self.finish(&p, mu, total, b.on_target, out);
        self.judge(world, chain, out, o)
    }

    /// Runs one start of a cold solve from `w.theta` (with the pairs' multipliers `mu`) and
    /// offers its answer to `podium`; `search` for a random or flip start, which stops when it
    /// runs into the best optimum so far and gives up sooner ([`SEARCH_STALL_STEPS`]). Returns
    /// the iterations spent.
    fn run_start(
        &mut self,
        p: &Problem,
        world: &World,
        podium: &mut Podium,
        mut mu: [f64; 2],
        search: bool,
    ) -> usize {
        self.clear.watch_best = search && podium.reached();
        let stall = if search {
            SEARCH_STALL_STEPS
        } else {
            STALL_STEPS
        };
        let l = self.clear_local(p, world, &mut mu, stall);
        self.clear.watch_best = false;
        if l.joined_best {
            return l.iterations;
        }
        let theta = std::mem::take(&mut self.w.theta);
        let least = self.least_clearance(world, p.chain, &theta);
        self.w.theta = theta;
        let clear_enough = least >= world.clearance_m() - CLEAR_SLACK;
        let found = Candidate {
            half_metric: half_metric(&self.w.theta, p.theta0),
            miss: l.tip_error + (world.clearance_m() - least).max(0.0),
            on_target: l.converged && l.tip_error <= p.tol && clear_enough,
            mu,
        };
        let clear = &mut self.clear;
        podium.offer(&self.w.theta, &mut clear.best, &mut clear.second, found);
        l.iterations
    }

    /// The flip starts of a cold solve ([`flip::flip_pose`]): the optimum without obstacles
    /// (when on target) carried across each obstacle it collides with, in turn; then the best
    /// clear optimum so far carried across each obstacle it touches (clearance within
    /// [`FLIP_TOUCH`] of the scale of `clearance_m`), a round that starts again from the new
    /// best as soon as one finds a better optimum; at most [`FLIP_CAP`] starts in all. Each is
    /// a search start (see `run_start`). Returns the iterations spent.
    fn flip_starts(
        &mut self,
        p: &Problem,
        world: &World,
        podium: &mut Podium,
        free_on_target: bool,
    ) -> usize {
        let mut total = 0;
        let mut starts = 0;
        if free_on_target {
            self.clear.flip_src.copy_from_slice(&self.clear.free_opt);
            total += self.flip_round(p, world, podium, world.clearance_m(), None, &mut starts);
        }
        let touch = world.clearance_m() + FLIP_TOUCH * p.scale;
        let mut last = None;
        while starts < FLIP_CAP {
            let Some(b) = podium.best.filter(|b| b.on_target) else {
                break;
            };
            if last == Some(b.half_metric) {
                break;
            }
            last = Some(b.half_metric);
            self.clear.flip_src.copy_from_slice(&self.clear.best);
            total += self.flip_round(p, world, podium, touch, last, &mut starts);
        }
        total
    }

    /// One round of flip starts from `clear.flip_src`: across each obstacle whose clearance
    /// from it is below `below`, while `starts` (counted up) is under [`FLIP_CAP`]; when `best`
    /// (half metric 3 of the best optimum the round starts from) is given, the round ends as
    /// soon as a start finds a better one. Returns the iterations spent.
    fn flip_round(
        &mut self,
        p: &Problem,
        world: &World,
        podium: &mut Podium,
        below: f64,
        best: Option<f64>,
        starts: &mut usize,
    ) -> usize {
        let c = &mut self.clear;
        p.chain.points_into(&c.flip_src, &mut c.flip_pts);
        for k in 0..c.flip_mark.len() {
            c.flip_mark[k] = flip::nearest_link(world, &c.flip_pts, k).1 < below;
        }
        let mut total = 0;
        for k in 0..self.clear.flip_mark.len() {
            if *starts >= FLIP_CAP {
                break;
            }
            if !self.clear.flip_mark[k] {
                continue;
            }
            *starts += 1;
            let c = &mut self.clear;
            flip::flip_pose(
                world,
                p,
                &c.flip_src,
                k,
                &self.w.lo,
                &self.w.hi,
                &mut c.flip_pts,
                &mut self.w.theta,
            );
            c.forget();
            total += self.run_start(p, world, podium, [0.0; 2], true);
            if best.is_some_and(|m| podium.best.is_some_and(|b| b.half_metric < m)) {
                break;
            }
        }
        total
    }

    /// A continuation start among obstacles from `w.theta` (see the cold solve without
    /// obstacles): the intermediate targets solved with the obstacles, loosely.
    fn clear_continuation(
        &mut self,
        world: &World,
        p: &Problem,
        polar: bool,
        mu: &mut [f64; 2],
    ) -> usize {
        let tip0 = p.chain.tip(&self.w.theta);
        let mut iterations = 0;
        for sub in stages(p, tip0, polar, self.opts.continuation_stages) {
            iterations += self
                .clear_local(&sub, world, mu, SEARCH_STALL_STEPS)
                .iterations;
        }
        iterations
    }

    /// [`ClearWork::local`] of `p` from the iterate in `w.theta`, to `p`'s tip tolerance,
    /// stuck after `stall_steps` iterations without progress.
    fn clear_local(
        &mut self,
        p: &Problem,
        world: &World,
        mu: &mut [f64; 2],
        stall_steps: usize,
    ) -> ClearLocal {
        let max_iterations = self.opts.max_iterations;
        let Overall { w, clear, .. } = self;
        clear.local(
            p,
            world,
            &w.lo,
            &w.hi,
            &mut w.theta,
            mu,
            p.tol,
            max_iterations,
            stall_steps,
        )
    }
}

mod active;
mod flip;
mod newton;
#[cfg(test)]
mod tests;
