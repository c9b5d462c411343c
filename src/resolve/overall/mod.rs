//! The overall strategy: one optimization over the whole arm.
//!
//! ```text
//! minimize   1/2 sum_i (theta_i - theta0_i)^2        (half of metric 3)
//! subject to tip(theta) = target,   lo_i <= theta_i <= hi_i
//! ```
//!
//! Method (every iteration is O(n); nothing is allocated once the scratch is sized for n). One
//! local solve is the loop of `Overall::local`: evaluate the pose (`eval`), apply the stopping
//! rule (`stop_rule`), then take a Newton step when one is due (`try_newton`), else an SQP step
//! (`sqp_step`).
//! - **SQP step** (`sqp_step`). The linearized subproblem, with the identity as Hessian, is
//!   solved through its two-variable dual `theta(mu) = clip(theta0 + J^T mu, lo, hi)` by
//!   semismooth Newton (`sqp_subproblem`, module `dual`); without limits that is the
//!   minimum-norm step with the 2 x 2 Schur complement `J J^T`. When the linearized constraint
//!   cannot be met inside the box (or `J` loses rank) the elastic form with a penalized
//!   constraint is solved instead (`solve_elastic`: the stiffest of a few weights whose dual
//!   settles; its dual steps to the exact maximum along each Newton direction, a few evaluations
//!   per solve). The step is globalized by an Armijo line search (`line_search`) on the merit
//!   `1/2 |theta - theta0|^2 + nu |tip - target|`, with `nu` (`merit_weight`) raised above the
//!   multiplier norm whenever needed and, after an exact step, brought back down when it is
//!   more than ten times what that step's multiplier needs: an elastic step's multiplier can be
//!   huge, and a `nu` kept from it would leave the line search accepting only tiny steps.
//! - **Newton step** (`try_newton`, `newton`). Near the solution, exact Newton on the
//!   optimality conditions `theta = clip(theta0 + J^T mu)`, `tip = target`: the multiplier
//!   picks the active set (`predict_active_set`: a joint is held at a bound when
//!   `theta0 + J^T mu` lies on or beyond it, else free), the held joints move onto their bounds,
//!   and the free ones take the Newton step with the Lagrangian Hessian `I + G`,
//!   `G_ab = g_max(a,b)` (`newton_rows`), solved in O(n) through prefix sums (module `hessian`)
//!   and a 2 x 2 Schur complement (`Schur`), clipped into the box (`newton_pose`). It is taken
//!   only when the Hessian's inertia says the point is a local minimum on the constraint's
//!   tangent and the residual of the optimality conditions at least halves; otherwise the SQP
//!   step is used. With the active set read from the multiplier, a joint that reaches or leaves
//!   a limit near the optimum does not stop Newton, so limited solves converge as fast as
//!   unlimited ones.
//! - **Stopping rule** (`stop_rule`; `Exit` names every way out). A local solve has converged
//!   when the tip is within the tip tolerance and the optimality conditions hold within the
//!   stationarity tolerance. It gives up (not converged) at the iteration cap, when no step
//!   decreases the merit, or when ten elastic steps in a row cut the tip error by less than 1%
//!   (`ElasticStall`): the box then holds no way to the target from that start (a cold start in
//!   the wrong piece of the feasible set, or an unreachable target, which goes on to the
//!   closest-tip search).
//! - **Limits** are met exactly: every iterate is clipped into the box by construction.
//! - **Straight (singular) poses** (`singular`, `kick`). If the iteration stalls at a pose
//!   whose Jacobian has lost rank while the target is not met, the joints after the base are
//!   bent by a small angle with a deterministic sign: that of the last solved pose's total
//!   bend, else positive.
//! - **Unreachable targets** (`closest`, `closed_form_outside`). The pose whose tip is closest
//!   to the target is found by projected Levenberg-Marquardt on the squared tip distance
//!   (`closest_step`: the free joints and gradient from `lm_free_set`, the damped step from
//!   `lm_trial`), then metric 3 is minimized among the poses reaching that closest point; an
//!   unlimited chain outside its ring has the closed form (the arm straight toward the target,
//!   or folded around its longest link).
//!
//! Two modes ([`OverallMode`]): **local** ([`Overall::solve_local`]) continues from the current
//! pose and the stored multiplier (one control tick), **cold** ([`Overall::solve_cold`]) runs
//! its own deterministic set of starts (module `cold`: `Start`, in the order of `Schedule`) and keeps the best
//! optimum by metric 3 (`Podium`); a random start whose iterate comes within 1e-4 rad of the
//! best optimum on target so far (tip within 1e-6 of the scale) stops there, as it would only
//! find that optimum again.
//!
//! **Among obstacles** ([`Overall::set_world`] with a [`World`] that has obstacles) every link
//! also keeps `clearance_m` from every obstacle, by the world's exact capsule distance:
//!
//! ```text
//! minimize 1/2 |theta - theta0|^2  s.t.  tip = target, lo <= theta <= hi,
//!                                        clearance(link i, obstacle k) >= clearance_m
//! ```
//!
//! solved by module `clear` (its doc has the method: SQP whose subproblem adds the pairs near
//! contact as linearized inequalities, solved through its dual by projected Newton, elastic
//! when infeasible, an exact-penalty line search that measures the exact least clearance, then
//! dense Newton on the KKT system with the active pairs as equalities). A local solve first
//! tries the solve without obstacles when the last answer leaned on none, and keeps it when it
//! is clear (a clear local optimum of the problem without obstacles is one with them); a cold
//! solve keeps the best optimum without obstacles when it is clear, else searches its own
//! starts (see [`Overall::solve_cold`]). `converged` is true only for an answer on target,
//! within limits and clear (least clearance at least `clearance_m` less [`CLEAR_SLACK`], the
//! round-off of a distance), and [`Overall::last_clearance`] reports that least clearance: a
//! start that is not clear is allowed, and the caller sees whether the answer got out. A
//! failed solve's answer is its last iterate, which need not be clear. `None`, or a world
//! without obstacles, leaves every solve exactly as without a world.

mod clear;
mod cold;
mod dual;
mod hessian;

use std::ops::ControlFlow;

use crate::chain::{nearest_representative, wrap_angle, Chain, Reachability, Vec2};
use crate::resolve::{check_input, Outcome, Resolver, Strategy};
use crate::world::World;

pub use clear::{CLEAR_SLACK, MAX_LINKS_AMONG_OBSTACLES, MAX_PAIRS, NEWTON_MAX_JOINTS};

use cold::mirror_pose;
pub(crate) use cold::SplitMix;
use dual::Dual;

// Cold solves.

/// A mirrored answer replaces a local answer only when it lowers metric 3 by this relative
/// margin: a mirror-symmetric tie (equal up to round-off) keeps the tie-break's side.
const MIRROR_GAIN: f64 = 1e-9;
/// A random start joins the best optimum once its tip is on target within this fraction of the
/// scale (well inside the Newton phase's reach)...
const JOIN_BEST_TIP: f64 = 1e-6;
/// ...and its pose within this many rad of that optimum: from there it can only converge to it.
const JOIN_BEST_POSE: f64 = 1e-4;

// The local solve.

/// A Newton step is kept when the optimality residual at least shrinks by this factor: a step
/// that does less is no better than the SQP step it replaces.
const NEWTON_CONTRACTION: f64 = 0.5;
/// A Newton step that does not contract so is tried at this many halvings of its length (in
/// the pose and the multiplier both)...
const NEWTON_HALVINGS: usize = 5;
/// ...and a fraction `alpha` of it kept when the optimality residual falls by at least
/// `this * alpha` of itself. Near the outer edge of the workspace the tip multiplier is
/// large and the optimality conditions bend sharply, so the whole Newton step overshoots while
/// a fraction of it still makes the fast progress an SQP step there does not.
const NEWTON_DAMPED_DECREASE: f64 = 0.25;
/// Newton is tried after an exact SQP step taken whole, or once the tip is within this fraction
/// of the scale (the active set has settled there).
const NEWTON_RANGE: f64 = 1e-3;
/// A Newton step that moves any joint by more than this (rad) is not local: its quadratic
/// model is not trusted.
const NEWTON_MAX_MOVE: f64 = 0.5;
/// Rows of the tip constraint: the 2 x 2 Schur complement can carry at most this many negative
/// eigenvalues of the Hessian, so more rule out a local minimum at once.
const TIP_ROWS: usize = 2;
/// The Schur complement `J H^-1 J^T` counts as singular when its determinant is below this
/// fraction of its squared size (near round-off of its entries).
const SCHUR_SINGULAR: f64 = 1e-14;
/// The subproblem's dual is solved to this fraction of the tip tolerance, so that its error
/// does not limit the outer solve...
const QP_TOLERANCE: f64 = 1e-3;
/// ...but not below the round-off of a tip position, relative to the scale.
const QP_TOLERANCE_FLOOR: f64 = 1e-15;
/// Largest multiplier (times the scale) of the exact subproblem: beyond it the dual is running
/// away, the linearized constraint being (numerically) infeasible in the box.
const MU_CAP: f64 = 1e12;
/// Inverse penalty weights of the elastic form relative to `scale^2`, stiffest first: the
/// first whose dual settles is used (a very stiff one can leave semismooth Newton crawling
/// over clipped joints).
const ELASTIC_WEIGHTS: [f64; 3] = [1e-6, 1e-3, 1.0];
/// Stall rule: a run of this many elastic steps...
const ELASTIC_STALL_STEPS: usize = 10;
/// ...must bring the tip error below this fraction of where the run began (a 1% cut), or the
/// box holds no way to the target from here.
const ELASTIC_STALL_RATIO: f64 = 0.99;
/// A step whose largest joint move is below this fraction of `1 + max |theta|` is round-off:
/// no step is left.
const STEP_FLOOR: f64 = 1e-15;
/// Stationarity reachable through round-off alone, rad: where no step is left, a residual
/// below it still counts as optimal.
const ROUND_OFF_STATIONARITY: f64 = 1e-9;
/// The merit's weight is set to this multiple of the multiplier norm (an exact penalty needs
/// more than the norm; twice keeps a clear margin)...
const MERIT_WEIGHT_FACTOR: f64 = 2.0;
/// ...plus this much over the scale, so that a zero multiplier still weights the tip error.
const MERIT_WEIGHT_FLOOR: f64 = 1e-6;
/// The weight is raised once it falls below this multiple of the multiplier norm (the exact
/// penalty's bound, with a little margin)...
const MERIT_WEIGHT_MARGIN: f64 = 1.1;
/// ...and, after an exact step, lowered once it exceeds this multiple of what that step needs.
const MERIT_WEIGHT_EXCESS: f64 = 10.0;
/// Armijo's sufficient-decrease fraction (the customary value).
const ARMIJO: f64 = 1e-4;
/// Halvings before the line search gives up: `2^-50` of a step is below its round-off.
const MAX_HALVINGS: usize = 50;
/// Tie-breaks at singular poses per local solve: more would only circle around the same pose.
const MAX_KICKS: usize = 3;
/// Size of a tie-break's bend, rad (its joint vector has about this Euclidean norm, each joint
/// `KICK_ANGLE / sqrt(n)`): far above round-off, small enough to keep the pose near.
const KICK_ANGLE: f64 = 0.02;
/// Relative shift that keeps `J J^T` invertible in the tie-break's projection (it is rank
/// deficient at the poses the tie-break is for).
const KICK_REGULARIZATION: f64 = 1e-12;
/// The Jacobian has lost rank when `det(J J^T)` is below this times `trace^2` (singular values
/// 1e-10 apart, relative).
const RANK_LOSS: f64 = 1e-20;

/// A failed solve among obstacles whose answer has a link within this of the clearance it
/// keeps, m, was held back by that obstacle ([`Resolver::held_by_obstacle`]).
const HELD_MARGIN_M: f64 = 1e-4;

// The closest-tip search.

/// Initial Levenberg-Marquardt damping relative to `scale^2`: a cautious first step.
const LM_DAMPING_START: f64 = 1e-3;
/// Largest damping relative to `scale^2`: beyond it the step is below round-off.
const LM_DAMPING_MAX: f64 = 1e14;
/// Smallest damping relative to `scale^2`, so that the model stays regularized.
const LM_DAMPING_MIN: f64 = 1e-12;
/// Damping growth after a rejected step.
const LM_DAMPING_UP: f64 = 4.0;
/// Damping decrease after an accepted step (slower than the growth, against oscillation).
const LM_DAMPING_DOWN: f64 = 3.0;
/// The search has converged when the projected gradient is below this fraction of
/// `scale * distance` (round-off of the gradient).
const LM_GRADIENT_FLOOR: f64 = 1e-14;
/// A rejected step whose largest joint move (rad) is below this cannot be refined further.
const LM_STEP_FLOOR: f64 = 1e-16;
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
    /// Cold solves: seeded pseudo-random starts tried when a limit comes near enough to
    /// `theta0` to touch a better pose (limits split the feasible set into pieces the other
    /// starts may not reach) or the best optimum turns the joints by a quarter turn or more
    /// (other optima may lie around the other side), and once more when no start so far has
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

/// Scratch buffers, sized once per joint count. Vectors named `*_free` hold one entry per free
/// joint of the current Newton or Levenberg-Marquardt step (the first `free.len()` entries).
#[derive(Debug, Default)]
struct Work {
    /// The joint count the buffers are sized for.
    n: usize,
    /// Joint positions of the last evaluated pose, base first, tip last.
    pts: Vec<Vec2>,
    /// First row of the tip Jacobian at the last evaluated pose.
    jx: Vec<f64>,
    /// Second row of the tip Jacobian at the last evaluated pose.
    jy: Vec<f64>,
    /// Lower bounds (`-inf` when unlimited).
    lo: Vec<f64>,
    /// Upper bounds (`+inf` when unlimited).
    hi: Vec<f64>,
    /// The current iterate.
    theta: Vec<f64>,
    /// A candidate pose: line-search trial, Newton or Levenberg-Marquardt step, mirror image.
    trial: Vec<f64>,
    /// The whole Newton step's pose while fractions of it are tried.
    newton_end: Vec<f64>,
    /// Solution of the linearized subproblem (the SQP step's end point).
    qp_x: Vec<f64>,
    /// Clipping state of each joint in the subproblem's dual.
    state: Vec<i8>,
    /// Kinks of the elastic dual along a line, two per joint.
    brk: Vec<(f64, f64)>,
    /// Cold solves: `best` holds an optimum on target, and a local solve whose iterate comes
    /// next to it stops there ([`Exit::JoinedBest`]; it would only find that optimum again).
    watch_best: bool,
    /// The free joints of the current Newton or Levenberg-Marquardt step, in order.
    free: Vec<usize>,
    /// `g` of the free joints: the Hessian's `G_ab = g_max(a,b)`.
    g_free: Vec<f64>,
    /// Pivots of the factorization of the free joints' Hessian.
    piv: Vec<f64>,
    /// Prefix sums, scratch of [`hessian::solve`].
    prefix: Vec<f64>,
    /// First Jacobian row at the free joints.
    jx_free: Vec<f64>,
    /// Second Jacobian row at the free joints.
    jy_free: Vec<f64>,
    /// Right-hand side at the free joints: the Newton residual of their rows, or the negative
    /// gradient of the squared tip distance.
    rhs_free: Vec<f64>,
    /// The Hessian's inverse applied to `jx_free`.
    hinv_jx: Vec<f64>,
    /// The Hessian's inverse applied to `jy_free`.
    hinv_jy: Vec<f64>,
    /// The Hessian's inverse applied to `rhs_free`.
    hinv_rhs: Vec<f64>,
    /// Newton step, per joint: the move of a held joint onto its bound (0 for a free joint).
    held_move: Vec<f64>,
    /// Newton step, per joint: `sum_{b > a} g_b held_move_b`, the coupling of row `a` to the
    /// held joints after it.
    coupling: Vec<f64>,
    /// Levenberg-Marquardt step, per joint: the gradient of the squared tip distance.
    grad: Vec<f64>,
    /// Cold solves: the pose of the best optimum so far (other solves: a saved pose).
    best: Vec<f64>,
    /// Cold solves: the pose of the second-best optimum so far.
    second: Vec<f64>,
    /// Cold solves: a converged pose kept while it is solved again turned toward `theta0`.
    turned: Vec<f64>,
    /// The pose lent out by [`Resolver::scratch_pose`].
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
            &mut self.newton_end,
            &mut self.qp_x,
            &mut self.g_free,
            &mut self.piv,
            &mut self.prefix,
            &mut self.jx_free,
            &mut self.jy_free,
            &mut self.rhs_free,
            &mut self.hinv_jx,
            &mut self.hinv_jy,
            &mut self.hinv_rhs,
            &mut self.held_move,
            &mut self.coupling,
            &mut self.grad,
            &mut self.best,
            &mut self.second,
            &mut self.turned,
            &mut self.stage,
        ] {
            *v = vec![0.0; n];
        }
        self.state = vec![0; n];
        self.brk = vec![(0.0, 0.0); 2 * n];
        self.free = Vec::with_capacity(n);
    }

    /// Applies the inverse of the free joints' Hessian, factorized into `piv[..m]`, to
    /// `jx_free`, `jy_free` and `rhs_free`, giving `hinv_jx`, `hinv_jy` and `hinv_rhs`.
    fn solve_free(&mut self, m: usize) {
        let (piv, prefix) = (&self.piv[..m], &mut self.prefix[..m]);
        hessian::solve(piv, &self.jx_free[..m], prefix, &mut self.hinv_jx[..m]);
        hessian::solve(piv, &self.jy_free[..m], prefix, &mut self.hinv_jy[..m]);
        hessian::solve(piv, &self.rhs_free[..m], prefix, &mut self.hinv_rhs[..m]);
    }
}

/// The fixed data of one problem.
#[derive(Clone, Copy)]
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

/// Why a local solve stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Exit {
    /// Tip within the tolerance and the optimality conditions within theirs.
    Converged,
    /// Cold solves: on target next to the best optimum so far ([`Work::watch_best`]).
    JoinedBest,
    /// The iteration cap was reached.
    IterationCap,
    /// A run of elastic steps stopped cutting the tip error ([`ElasticStall`]).
    ElasticStall,
    /// Not even the elastic form of the subproblem could be solved.
    ElasticFailed,
    /// The SQP step vanished (on target: optimal up to round-off).
    NoStep,
    /// No step along the SQP direction decreases the merit.
    NoDescent,
}

/// How one local solve ended.
#[derive(Debug, Clone, Copy)]
struct Local {
    exit: Exit,
    converged: bool,
    tip_error: f64,
    iterations: usize,
}

impl Local {
    /// The end of a local solve at the evaluated iterate `at`. Converged when the stopping rule
    /// says so, or when no step is left on target with the optimality conditions met up to
    /// round-off.
    fn stopped(exit: Exit, p: &Problem, at: &Iterate, tol: f64, iterations: usize) -> Self {
        let converged = match exit {
            Exit::Converged => true,
            Exit::NoStep | Exit::NoDescent => {
                at.cn <= tol && at.s <= p.stol.max(ROUND_OFF_STATIONARITY)
            }
            Exit::JoinedBest | Exit::IterationCap | Exit::ElasticStall | Exit::ElasticFailed => {
                false
            }
        };
        Self {
            exit,
            converged,
            tip_error: at.cn,
            iterations,
        }
    }
}

/// An evaluated iterate.
#[derive(Debug, Clone, Copy)]
struct Iterate {
    /// Tip correction wanted, `target - tip`.
    c: Vec2,
    /// Its norm, the tip error.
    cn: f64,
    /// Stationarity residual `max |theta - clip(theta0 + J^T mu)|`.
    s: f64,
}

/// What a local solve carries from one iteration to the next.
#[derive(Debug)]
struct LocalRun {
    /// Iterations so far (SQP and Newton steps).
    iterations: usize,
    /// Weight of the tip error in the merit.
    nu: f64,
    /// Try a Newton step next: the last SQP step was exact and taken whole, or near the target.
    newton_ready: bool,
    /// Tie-breaks spent at singular poses.
    kicks: usize,
    /// Multiplier of the last subproblem solved.
    mu_q: [f64; 2],
    /// The stall rule's run of elastic steps.
    stall: ElasticStall,
}

impl LocalRun {
    fn new(mu: [f64; 2]) -> Self {
        Self {
            iterations: 0,
            nu: 0.0,
            newton_ready: false,
            kicks: 0,
            mu_q: mu,
            stall: ElasticStall::default(),
        }
    }
}

/// The stall rule: a run of elastic steps (the linearized constraint cannot be met inside the
/// limits) that does not cut the tip error by 1% in 10 iterations means the box holds no way to
/// the target from here.
#[derive(Debug, Default)]
struct ElasticStall {
    /// Elastic steps in the current run.
    run: usize,
    /// Tip error where the run (or its last window) began.
    reference: f64,
}

impl ElasticStall {
    /// An exact step ends the run.
    fn exact(&mut self) {
        self.run = 0;
    }

    /// Counts an elastic step at tip error `cn`; true when the run has stalled.
    fn elastic(&mut self, cn: f64) -> bool {
        self.run += 1;
        if self.run == 1 {
            self.reference = cn;
        } else if self.run > ELASTIC_STALL_STEPS {
            if cn > ELASTIC_STALL_RATIO * self.reference {
                return true;
            }
            self.run = 1;
            self.reference = cn;
        }
        false
    }
}

/// How the subproblem of one SQP iteration came out.
enum Subproblem {
    /// `w.qp_x` and the run's `mu_q` hold its solution; `elastic` when only the elastic form
    /// could be solved.
    Solved { elastic: bool },
    /// A singular pose was bent instead (the next iteration starts from there).
    Kicked,
    /// The local solve stops.
    Stop(Exit),
}

/// The SQP direction `d = w.qp_x - w.theta`, summarized for the line search.
struct Direction {
    /// Largest joint move, rad.
    largest: f64,
    /// `1 + max |theta|`, the size a move is round-off against.
    pose_size: f64,
    /// Derivative of the half metric along `d`.
    metric_slope: f64,
    /// Tip move the linearization predicts, `J d`.
    tip_move: Vec2,
}

/// The symmetric 2 x 2 Schur complement `S = J H^-1 J^T` of the free joints and `J H^-1 r`
/// for their Newton residual `r`.
struct Schur {
    s00: f64,
    s01: f64,
    s11: f64,
    e0: f64,
    e1: f64,
}

impl Schur {
    /// The multiplier step that meets the linearized tip constraint (with the tip correction
    /// `c` left for the free joints), or `None` when `S` is singular or the KKT matrix's
    /// inertia is not that of a local minimum: that holds exactly when `S` has as many negative
    /// eigenvalues as the Hessian (`negative`) and the rest positive.
    fn multiplier_step(&self, c: Vec2, negative: usize) -> Option<[f64; 2]> {
        let Self {
            s00,
            s01,
            s11,
            e0,
            e1,
        } = *self;
        let det = s00 * s11 - s01 * s01;
        let tr = s00 + s11;
        let scale = s00.abs() + s11.abs() + s01.abs();
        if det.is_nan() || det.abs() <= SCHUR_SINGULAR * scale * scale {
            return None;
        }
        let neg_s = if det < 0.0 {
            1
        } else if tr < 0.0 {
            2
        } else {
            0
        };
        if neg_s != negative {
            return None;
        }
        let rhs = [c.x + e0, c.y + e1];
        Some([
            (s11 * rhs[0] - s01 * rhs[1]) / det,
            (s00 * rhs[1] - s01 * rhs[0]) / det,
        ])
    }
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
    /// The obstacles every answer keeps clear of.
    world: Option<World>,
    /// Scratch and warm state of the solve among obstacles.
    clear: clear::ClearWork,
    /// Least clearance of the last answer among obstacles.
    last_clearance: Option<f64>,
}

/// Half of metric 3.
fn half_metric(theta: &[f64], theta0: &[f64]) -> f64 {
    0.5 * theta
        .iter()
        .zip(theta0)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
}

/// The largest difference between two poses, rad.
fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The direction of `v` as an angle from the x axis.
fn bearing(v: Vec2) -> f64 {
    v.y.atan2(v.x)
}

/// The merit's weight on the tip error for a step with the multiplier `mu_q`, from the
/// current weight `nu`: raised when below the exact penalty's bound, and after an exact step
/// (not `elastic`) lowered when far above what that step needs, since a weight kept from an
/// elastic step's huge multiplier would leave the line search accepting only tiny steps.
fn merit_weight(nu: f64, mu_q: [f64; 2], elastic: bool, scale: f64) -> f64 {
    let mu_norm = mu_q[0].hypot(mu_q[1]);
    let wanted = MERIT_WEIGHT_FACTOR * mu_norm + MERIT_WEIGHT_FLOOR / scale;
    if nu < MERIT_WEIGHT_MARGIN * mu_norm || (!elastic && nu > MERIT_WEIGHT_EXCESS * wanted) {
        wanted
    } else {
        nu
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
            world: None,
            clear: clear::ClearWork::default(),
            last_clearance: None,
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
        if let Some(o) = self.closed_form_outside(&p, out) {
            return Err(o);
        }
        match self.closed_form_one_link(&p, out) {
            Some(o) => Err(o),
            None => Ok(p),
        }
    }

    /// Best effort from the current pose `theta0` and the stored multipliers (one control
    /// tick). Among obstacles ([`Overall::set_world`]) the answer also keeps every link clear
    /// (`converged` only when it is: tip on target, within limits and clear), and a start that
    /// is not clear is moved out where the solve can ([`Overall::last_clearance`] says whether
    /// it did).
    pub fn solve_local(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        if self.among_obstacles() {
            self.local_among(chain, theta0, target, out)
        } else {
            self.free_local(chain, theta0, target, out)
        }
    }

    /// [`Overall::solve_local`] without obstacles.
    fn free_local(
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
        self.start_clipped(&p);
        let mut mu = self.mu;
        let local = self.local(&p, &mut mu, p.tol);
        let mut iterations = local.iterations;
        let mut converged = local.converged;
        if !local.converged {
            let (its, scaled) = self.solve_from_scaled(&p);
            iterations += its;
            if let Some(scaled_mu) = scaled {
                mu = scaled_mu;
                converged = true;
            }
        }
        if converged {
            iterations += self.try_mirror(&p, &mut mu);
        } else {
            let (its, conv) = self.closest(&p, &mut mu);
            iterations += its;
            converged = conv;
        }
        self.finish(&p, mu, iterations, converged, out)
    }

    /// After a local solve that failed, with its answer in `w.theta`: a local solve from the
    /// scaled start ([`Overall::start_scaled`], for targets near the outer edge of the
    /// workspace), kept when it converges (with its multiplier); else `w.theta` is restored.
    /// Returns the iterations spent.
    fn solve_from_scaled(&mut self, p: &Problem) -> (usize, Option<[f64; 2]>) {
        self.w.best.copy_from_slice(&self.w.theta);
        if !self.start_scaled(p) {
            self.w.theta.copy_from_slice(&self.w.best);
            return (0, None);
        }
        let mut mu = [0.0; 2];
        let l = self.local(p, &mut mu, p.tol);
        if l.converged && l.tip_error <= p.tol {
            return (l.iterations, Some(mu));
        }
        self.w.theta.copy_from_slice(&self.w.best);
        (l.iterations, None)
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
        let goal = current * (1.0 - MIRROR_GAIN);
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
    ///
    /// A target on the ring's edge (within the tip tolerance of the reach, or of the hole's
    /// radius when there is a hole) is answered the same way, limited chain or not, when that
    /// pose is within the limits: it is the only pose that reaches such a target, and the
    /// iteration, whose Jacobian loses rank there, would crawl toward it (the tip error falls
    /// with the square of the angles' error) and stop short of its tolerance.
    fn closed_form_outside(&mut self, p: &Problem, out: &mut [f64]) -> Option<Outcome> {
        let chain = p.chain;
        let d = p.target - chain.base();
        let dist = d.norm();
        let ws = chain.workspace();
        let on_edge = dist >= ws.r_max - p.tol || (ws.r_min > 0.0 && dist <= ws.r_min + p.tol);
        let outside = !chain.is_limited() && chain.classify(p.target) == Reachability::Outside;
        if !outside && !on_edge {
            return None;
        }
        let n = chain.len();
        let bearing = if dist > 0.0 {
            d.y.atan2(d.x)
        } else {
            chain.heading() + p.theta0[0]
        };
        let h = chain.heading();
        if 2.0 * dist > ws.r_max + ws.r_min {
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
        if outside {
            return Some(self.finish(p, [0.0; 2], 0, false, out));
        }
        // On the edge: the pose must be within the limits and reach the target, else the
        // iteration (or the closest-tip search) answers.
        let fits = self
            .w
            .theta
            .iter()
            .enumerate()
            .all(|(a, &t)| (self.w.lo[a]..=self.w.hi[a]).contains(&t));
        if !fits || (chain.tip(&self.w.theta) - p.target).norm() > p.tol {
            return None;
        }
        Some(self.finish(p, [0.0; 2], 0, true, out))
    }

    /// A one-link chain has no redundancy: its tip is on target only at the angle pointing at
    /// it, and the answer is that angle's representative within the limits nearest `theta0`;
    /// when none lies within them, the limit whose tip is closer (the nearer to `theta0` on a
    /// tie); a target on the base, `clip(theta0)`. The iterative solve cannot tell such a pose
    /// optimal (two tip rows for one joint leave no multiplier within the stationarity
    /// tolerance), so it is answered here. `None` for longer chains.
    fn closed_form_one_link(&mut self, p: &Problem, out: &mut [f64]) -> Option<Outcome> {
        let chain = p.chain;
        if chain.len() != 1 {
            return None;
        }
        let d = p.target - chain.base();
        let (lo, hi) = (self.w.lo[0], self.w.hi[0]);
        let t0 = p.theta0[0];
        let theta = if d.norm() == 0.0 {
            t0.clamp(lo, hi)
        } else {
            let psi = bearing(d) - chain.heading();
            if !(lo.is_finite() && hi.is_finite()) {
                nearest_representative(psi, t0)
            } else {
                let tau = 2.0 * std::f64::consts::PI;
                // The representatives within the limits run from `first` to `last`.
                let first = lo + (psi - lo).rem_euclid(tau);
                let last = hi - (hi - psi).rem_euclid(tau);
                // (`last` may round below `first` when a single representative lies within.)
                if first <= hi {
                    nearest_representative(psi, t0.clamp(first, last.max(first))).clamp(lo, hi)
                } else {
                    let (off_lo, off_hi) = (wrap_angle(lo - psi).abs(), wrap_angle(hi - psi).abs());
                    if off_lo < off_hi || (off_lo == off_hi && (lo - t0).abs() <= (hi - t0).abs()) {
                        lo
                    } else {
                        hi
                    }
                }
            }
        };
        self.w.theta[0] = theta;
        Some(self.finish(p, [0.0; 2], 0, true, out))
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
    /// `w.theta`, its multiplier in `mu`. The driver: each iteration evaluates the pose,
    /// applies the stopping rule, then takes a Newton step when one is due and succeeds, else
    /// an SQP step; either may end the solve ([`Exit`]).
    fn local(&mut self, p: &Problem, mu: &mut [f64; 2], tol: f64) -> Local {
        let mut run = LocalRun::new(*mu);
        loop {
            let (c, s) = self.eval(p, *mu);
            let at = Iterate { c, cn: c.norm(), s };
            if let Some(exit) = self.stop_rule(p, &at, tol, run.iterations) {
                return Local::stopped(exit, p, &at, tol, run.iterations);
            }
            run.iterations += 1;
            if run.newton_ready {
                if self.try_newton(p, mu, &at, tol) {
                    continue;
                }
                run.newton_ready = false;
            }
            if let ControlFlow::Break(exit) = self.sqp_step(p, mu, &at, tol, &mut run) {
                return Local::stopped(exit, p, &at, tol, run.iterations);
            }
        }
    }

    /// The exits checked before every step: next to the best optimum of a cold solve (when
    /// watched), converged, or out of iterations.
    fn stop_rule(&self, p: &Problem, at: &Iterate, tol: f64, iterations: usize) -> Option<Exit> {
        if self.w.watch_best
            && at.cn <= JOIN_BEST_TIP * p.scale
            && max_abs_diff(&self.w.theta, &self.w.best) <= JOIN_BEST_POSE
        {
            return Some(Exit::JoinedBest);
        }
        if at.cn <= tol && at.s <= p.stol {
            return Some(Exit::Converged);
        }
        if iterations >= self.opts.max_iterations {
            return Some(Exit::IterationCap);
        }
        None
    }

    /// Takes the Newton step from the evaluated iterate `at` when it is trusted and the
    /// optimality residual at least halves (or the solve converges there), else the longest of
    /// [`NEWTON_HALVINGS`] halvings of it that cuts the residual enough
    /// ([`NEWTON_DAMPED_DECREASE`]); true when taken, with `w.theta` and `mu` updated. When not
    /// taken, the evaluation at `w.theta` is restored for the SQP step.
    fn try_newton(&mut self, p: &Problem, mu: &mut [f64; 2], at: &Iterate, tol: f64) -> bool {
        let residual = at.cn / p.scale + at.s;
        let Some(mu_n) = self.newton(p, *mu, at.c) else {
            return false;
        };
        std::mem::swap(&mut self.w.theta, &mut self.w.trial);
        let (c2, s2) = self.eval(p, mu_n);
        let cn2 = c2.norm();
        if cn2 / p.scale + s2 <= NEWTON_CONTRACTION * residual || (cn2 <= tol && s2 <= p.stol) {
            *mu = mu_n;
            return true;
        }
        // `w.trial` holds the pose the step started from.
        std::mem::swap(&mut self.w.theta, &mut self.w.newton_end);
        let mut alpha = 1.0;
        for _ in 0..NEWTON_HALVINGS {
            alpha *= 0.5;
            let w = &mut self.w;
            for ((t, &from), &to) in w.theta.iter_mut().zip(&w.trial).zip(&w.newton_end) {
                *t = from + alpha * (to - from);
            }
            let mu_a = [
                mu[0] + alpha * (mu_n[0] - mu[0]),
                mu[1] + alpha * (mu_n[1] - mu[1]),
            ];
            let (c3, s3) = self.eval(p, mu_a);
            if c3.norm() / p.scale + s3 <= (1.0 - NEWTON_DAMPED_DECREASE * alpha) * residual {
                *mu = mu_a;
                return true;
            }
        }
        std::mem::swap(&mut self.w.theta, &mut self.w.trial);
        self.eval(p, *mu);
        false
    }

    /// One SQP iteration from the evaluated iterate `at`: solve the subproblem, then take the
    /// largest step toward its solution that the line search accepts, updating `w.theta` and
    /// `mu`. A singular pose may be bent instead. Breaks with the exit when no step is left or
    /// none decreases the merit.
    fn sqp_step(
        &mut self,
        p: &Problem,
        mu: &mut [f64; 2],
        at: &Iterate,
        tol: f64,
        run: &mut LocalRun,
    ) -> ControlFlow<Exit> {
        let elastic = match self.sqp_subproblem(p, *mu, at, tol, run) {
            Subproblem::Solved { elastic } => elastic,
            Subproblem::Kicked => return ControlFlow::Continue(()),
            Subproblem::Stop(exit) => return ControlFlow::Break(exit),
        };
        let dir = self.direction(p);
        if dir.largest <= STEP_FLOOR * dir.pose_size {
            if self.kick_if_singular(at, tol, &mut run.kicks) {
                return ControlFlow::Continue(());
            }
            if at.cn <= tol && *mu != run.mu_q {
                // On target and no step left: optimal up to round-off, with the subproblem's
                // multiplier. The residual `at` was measured with the old one (zero at a cold
                // start that is already an optimum), so the stopping rule looks again.
                *mu = run.mu_q;
                return ControlFlow::Continue(());
            }
            return ControlFlow::Break(Exit::NoStep);
        }
        run.nu = merit_weight(run.nu, run.mu_q, elastic, p.scale);
        let Some(alpha) = self.line_search(p, at, run.nu, &dir) else {
            if self.kick_if_singular(at, tol, &mut run.kicks) {
                return ControlFlow::Continue(());
            }
            return ControlFlow::Break(Exit::NoDescent);
        };
        std::mem::swap(&mut self.w.theta, &mut self.w.trial);
        *mu = run.mu_q;
        run.newton_ready = !elastic && (alpha == 1.0 || at.cn < NEWTON_RANGE * p.scale);
        ControlFlow::Continue(())
    }

    /// The subproblem of an SQP iteration at the evaluated iterate `at`, warm-started from `mu`:
    /// the exact form, else (after bending a singular pose off target, and unless the run of
    /// elastic steps has stalled) the elastic form. The solution goes to `w.qp_x`, its
    /// multiplier to `run.mu_q`.
    fn sqp_subproblem(
        &mut self,
        p: &Problem,
        mu: [f64; 2],
        at: &Iterate,
        tol: f64,
        run: &mut LocalRun,
    ) -> Subproblem {
        let qp_tol = (QP_TOLERANCE * tol).max(QP_TOLERANCE_FLOOR * p.scale);
        run.mu_q = if run.mu_q[0].is_finite() && run.mu_q[1].is_finite() {
            mu
        } else {
            [0.0; 2]
        };
        if self.solve_dual(p, at.c, 0.0, &mut run.mu_q, qp_tol, MU_CAP / p.scale) {
            run.stall.exact();
            return Subproblem::Solved { elastic: false };
        }
        if self.kick_if_singular(at, tol, &mut run.kicks) {
            return Subproblem::Kicked;
        }
        if run.stall.elastic(at.cn) {
            return Subproblem::Stop(Exit::ElasticStall);
        }
        if self.solve_elastic(p, at.c, &mut run.mu_q, qp_tol) {
            Subproblem::Solved { elastic: true }
        } else {
            Subproblem::Stop(Exit::ElasticFailed)
        }
    }

    /// The elastic form of the subproblem with an adaptive weight: the stiffest penalty of
    /// [`ELASTIC_WEIGHTS`] whose dual settles, each tried from a zero multiplier.
    fn solve_elastic(&mut self, p: &Problem, c: Vec2, mu_q: &mut [f64; 2], qp_tol: f64) -> bool {
        for weight in ELASTIC_WEIGHTS {
            *mu_q = [0.0; 2];
            let rho_inv = weight * p.scale * p.scale;
            if self.solve_dual(p, c, rho_inv, mu_q, qp_tol, f64::MAX) {
                return true;
            }
        }
        false
    }

    /// Solves the subproblem at the evaluated pose (tip correction `c`) through its dual,
    /// exact (`rho_inv = 0`) or elastic, from the multiplier `mu_q`; see [`Dual::solve`].
    fn solve_dual(
        &mut self,
        p: &Problem,
        c: Vec2,
        rho_inv: f64,
        mu_q: &mut [f64; 2],
        qp_tol: f64,
        mu_cap: f64,
    ) -> bool {
        let w = &mut self.w;
        let d = Dual {
            jx: &w.jx,
            jy: &w.jy,
            z: p.theta0,
            theta: &w.theta,
            lo: &w.lo,
            hi: &w.hi,
            c,
            rho_inv,
        };
        d.solve(mu_q, &mut w.qp_x, &mut w.state, qp_tol, mu_cap, &mut w.brk)
    }

    /// The SQP direction from `w.theta` to `w.qp_x` at the evaluated pose.
    fn direction(&self, p: &Problem) -> Direction {
        let w = &self.w;
        let mut largest = 0.0_f64;
        let mut metric_slope = 0.0;
        let mut tip_move = Vec2::zeros();
        for a in 0..w.n {
            let d = w.qp_x[a] - w.theta[a];
            largest = largest.max(d.abs());
            metric_slope += (w.theta[a] - p.theta0[a]) * d;
            tip_move.x += w.jx[a] * d;
            tip_move.y += w.jy[a] * d;
        }
        let pose_size = 1.0 + w.theta.iter().fold(0.0_f64, |m, t| m.max(t.abs()));
        Direction {
            largest,
            pose_size,
            metric_slope,
            tip_move,
        }
    }

    /// Armijo backtracking on the merit `1/2 |theta - theta0|^2 + nu |tip - target|` along
    /// `dir`, halving from the full step; the accepted pose is left in `w.trial`. Returns the
    /// step fraction taken, or `None` when no fraction decreases the merit enough.
    fn line_search(&mut self, p: &Problem, at: &Iterate, nu: f64, dir: &Direction) -> Option<f64> {
        let w = &mut self.w;
        // Directional derivative of the merit; the tip term's from the linearized tip move.
        let slope = dir.metric_slope + nu * ((at.c - dir.tip_move).norm() - at.cn);
        let merit0 = half_metric(&w.theta, p.theta0) + nu * at.cn;
        let mut alpha = 1.0;
        for _ in 0..MAX_HALVINGS {
            for a in 0..w.n {
                w.trial[a] = w.theta[a] + alpha * (w.qp_x[a] - w.theta[a]);
            }
            if alpha == 1.0 {
                w.trial.copy_from_slice(&w.qp_x);
            }
            let m =
                half_metric(&w.trial, p.theta0) + nu * (p.chain.tip(&w.trial) - p.target).norm();
            if m <= merit0 + ARMIJO * alpha * slope.min(0.0) {
                return Some(alpha);
            }
            alpha *= 0.5;
        }
        None
    }

    /// At a singular pose off target, bends it ([`Self::kick`], at most [`MAX_KICKS`] times
    /// per local solve); true when it did.
    fn kick_if_singular(&mut self, at: &Iterate, tol: f64, kicks: &mut usize) -> bool {
        if at.cn > tol && *kicks < MAX_KICKS && self.singular() {
            *kicks += 1;
            self.kick();
            true
        } else {
            false
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
        tr <= 0.0 || a * c - b * b <= RANK_LOSS * tr * tr
    }

    /// The deterministic tie-break at a singular pose: bend the joints after the base by a
    /// small angle in the direction of the remembered bend sign, projected onto the null space
    /// of the Jacobian so that the tip does not move sideways to first order (and the sum of
    /// the bends keeps that sign), then clipped into the limits.
    fn kick(&mut self) {
        let w = &mut self.w;
        let n = w.n;
        let first = usize::from(n >= 2);
        let amount = KICK_ANGLE / (n as f64).sqrt();
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
        let eps = KICK_REGULARIZATION * (a + c) + f64::MIN_POSITIVE;
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
        let c_free = self.predict_active_set(p, mu, c);
        let m = self.w.free.len();
        if m < 2 {
            return None;
        }
        self.newton_rows(p, mu);
        let w = &mut self.w;
        let f = hessian::factor(&w.g_free[..m], &mut w.piv[..m])?;
        if f.negative > TIP_ROWS {
            return None;
        }
        w.solve_free(m);
        let dmu = w.schur(m).multiplier_step(c_free, f.negative)?;
        let largest = self.newton_pose(dmu);
        if largest.is_nan() || largest > NEWTON_MAX_MOVE {
            return None;
        }
        Some([mu[0] + dmu[0], mu[1] + dmu[1]])
    }

    /// The active set the multiplier predicts: joint `a` is held at a bound when
    /// `theta0_a + J_a^T mu` lies on or beyond it (the generalized derivative of
    /// `theta = clip(theta0 + J^T mu)`), else free. Fills `w.free` and `w.held_move` (the move of
    /// each held joint onto its bound) and returns the tip correction `c` less what those moves
    /// make, which is left for the free joints.
    fn predict_active_set(&mut self, p: &Problem, mu: [f64; 2], c: Vec2) -> Vec2 {
        let w = &mut self.w;
        w.free.clear();
        let mut c_free = c;
        for a in 0..w.n {
            let u = p.theta0[a] + w.jx[a] * mu[0] + w.jy[a] * mu[1];
            let d = if u <= w.lo[a] {
                w.lo[a] - w.theta[a]
            } else if u >= w.hi[a] {
                w.hi[a] - w.theta[a]
            } else {
                w.free.push(a);
                0.0
            };
            w.held_move[a] = d;
            c_free.x -= w.jx[a] * d;
            c_free.y -= w.jy[a] * d;
        }
        c_free
    }

    /// The Newton system of the free joints: their `g` (the Lagrangian Hessian `I + G`
    /// restricted to them), their Jacobian columns, and their rows' residual
    /// `theta - theta0 - J^T mu` plus the held joints' moves coupled through `G`: for row `a`,
    /// `sum_b g_max(a,b) d_b` over held `b`, `= g_a * (moves before a) + sum_{b > a} g_b d_b`,
    /// from one backward and one forward pass.
    fn newton_rows(&mut self, p: &Problem, mu: [f64; 2]) {
        let w = &mut self.w;
        let n = w.n;
        let m = w.free.len();
        let tip = w.pts[n];
        let mut after = 0.0;
        for a in (0..n).rev() {
            let r = tip - w.pts[a];
            let g = mu[0] * r.x + mu[1] * r.y;
            w.coupling[a] = after;
            after += g * w.held_move[a];
        }
        let mut before = 0.0;
        let mut k = 0;
        for a in 0..n {
            if k < m && w.free[k] == a {
                let r = tip - w.pts[a];
                let g = mu[0] * r.x + mu[1] * r.y;
                w.g_free[k] = g;
                w.jx_free[k] = w.jx[a];
                w.jy_free[k] = w.jy[a];
                w.rhs_free[k] = w.theta[a] - p.theta0[a] - (w.jx[a] * mu[0] + w.jy[a] * mu[1])
                    + g * before
                    + w.coupling[a];
                k += 1;
            } else {
                before += w.held_move[a];
            }
        }
    }

    /// Writes the Newton pose into `w.trial`: held joints onto their bounds, free joints moved by
    /// the step for the multiplier step `dmu` and clipped into the box. Returns the largest joint
    /// move before clipping.
    fn newton_pose(&mut self, dmu: [f64; 2]) -> f64 {
        let w = &mut self.w;
        let mut largest: f64 = 0.0;
        for a in 0..w.n {
            largest = largest.max(w.held_move[a].abs());
            w.trial[a] = w.theta[a] + w.held_move[a];
        }
        for (k, &a) in w.free.iter().enumerate() {
            let d = w.hinv_jx[k] * dmu[0] + w.hinv_jy[k] * dmu[1] - w.hinv_rhs[k];
            largest = largest.max(d.abs());
            // Projected: a free joint that would cross a bound stops there (the next step's
            // active set holds it if the multiplier agrees).
            w.trial[a] = (w.theta[a] + d).clamp(w.lo[a], w.hi[a]);
        }
        largest
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
        let mut lambda = LM_DAMPING_START * s2;
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
    /// from the evaluated pose (residual `c`, its norm `cn`): the damping `lambda` grows until a
    /// step decreases the distance, and shrinks after it. False when no step decreases the
    /// distance any more (converged or stuck).
    fn closest_step(&mut self, p: &Problem, c: Vec2, cn: f64, lambda: &mut f64) -> bool {
        if !self.lm_free_set(p, c, cn) {
            return false;
        }
        let s2 = p.scale * p.scale;
        while *lambda <= LM_DAMPING_MAX * s2 {
            let Some(step) = self.lm_trial(c, *lambda) else {
                *lambda *= LM_DAMPING_UP;
                continue;
            };
            let w = &mut self.w;
            let d_new = (p.chain.tip(&w.trial) - p.target).norm();
            if d_new < cn && step.is_finite() {
                std::mem::swap(&mut w.theta, &mut w.trial);
                *lambda = (*lambda / LM_DAMPING_DOWN).max(LM_DAMPING_MIN * s2);
                return true;
            }
            if step <= LM_STEP_FLOOR {
                return false;
            }
            *lambda *= LM_DAMPING_UP;
        }
        false
    }

    /// The gradient of the squared tip distance at the evaluated pose (residual `c`) and the
    /// free joints: all but those at a limit that the gradient pushes outward. Fills `w.free`,
    /// the free Jacobian columns and `w.rhs_free` (the negative gradient there). False when the
    /// projected gradient vanishes (relative to `scale * cn`) or no joint is free.
    fn lm_free_set(&mut self, p: &Problem, c: Vec2, cn: f64) -> bool {
        let w = &mut self.w;
        let mut pg: f64 = 0.0;
        w.free.clear();
        for a in 0..w.n {
            let grad = -(w.jx[a] * c.x + w.jy[a] * c.y);
            w.grad[a] = grad;
            let moved = (w.theta[a] - grad).clamp(w.lo[a], w.hi[a]);
            pg = pg.max((moved - w.theta[a]).abs());
            let held =
                (w.theta[a] <= w.lo[a] && grad > 0.0) || (w.theta[a] >= w.hi[a] && grad < 0.0);
            if !held {
                w.free.push(a);
            }
        }
        if pg <= LM_GRADIENT_FLOOR * p.scale * cn || w.free.is_empty() {
            return false;
        }
        for (k, &a) in w.free.iter().enumerate() {
            w.jx_free[k] = w.jx[a];
            w.jy_free[k] = w.jy[a];
            w.rhs_free[k] = -w.grad[a];
        }
        true
    }

    /// The damped step of the free joints for the damping `lambda`, written (clipped into the
    /// box) into `w.trial`: `(lambda I + G + J^T J)^-1` applied to the negative gradient, with
    /// `lambda I + G` solved by [`hessian`] and `J^T J` by a 2 x 2 Woodbury correction. Returns
    /// the largest joint move, or `None` when the model is not positive definite at this
    /// damping.
    fn lm_trial(&mut self, c: Vec2, lambda: f64) -> Option<f64> {
        let w = &mut self.w;
        let tip = w.pts[w.n];
        let m = w.free.len();
        for (k, &a) in w.free.iter().enumerate() {
            let r = tip - w.pts[a];
            w.g_free[k] = (c.x * r.x + c.y * r.y) / lambda;
        }
        let positive =
            hessian::factor(&w.g_free[..m], &mut w.piv[..m]).is_some_and(|f| f.negative == 0);
        if !positive {
            return None;
        }
        // u = A^-1 v with A = lambda (I + G / lambda); the 1 / lambda is applied below.
        w.solve_free(m);
        let inv = 1.0 / lambda;
        let (mut s00, mut s01, mut s11, mut e0, mut e1) = (1.0, 0.0, 1.0, 0.0, 0.0);
        for k in 0..m {
            s00 += w.jx_free[k] * w.hinv_jx[k] * inv;
            s01 += 0.5 * (w.jx_free[k] * w.hinv_jy[k] + w.jy_free[k] * w.hinv_jx[k]) * inv;
            s11 += w.jy_free[k] * w.hinv_jy[k] * inv;
            e0 += w.jx_free[k] * w.hinv_rhs[k] * inv;
            e1 += w.jy_free[k] * w.hinv_rhs[k] * inv;
        }
        let det = s00 * s11 - s01 * s01;
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        let z0 = (s11 * e0 - s01 * e1) / det;
        let z1 = (s00 * e1 - s01 * e0) / det;
        w.trial.copy_from_slice(&w.theta);
        let mut step: f64 = 0.0;
        for (k, &a) in w.free.iter().enumerate() {
            let d = (w.hinv_rhs[k] - w.hinv_jx[k] * z0 - w.hinv_jy[k] * z1) * inv;
            let v = (w.theta[a] + d).clamp(w.lo[a], w.hi[a]);
            step = step.max((v - w.theta[a]).abs());
            w.trial[a] = v;
        }
        Some(step)
    }
}

impl Work {
    /// The Schur complement of the free joints' Newton system, from [`Work::solve_free`]'s
    /// results.
    fn schur(&self, m: usize) -> Schur {
        let (mut s00, mut s01, mut s10, mut s11, mut e0, mut e1) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for k in 0..m {
            s00 += self.jx_free[k] * self.hinv_jx[k];
            s01 += self.jx_free[k] * self.hinv_jy[k];
            s10 += self.jy_free[k] * self.hinv_jx[k];
            s11 += self.jy_free[k] * self.hinv_jy[k];
            e0 += self.jx_free[k] * self.hinv_rhs[k];
            e1 += self.jy_free[k] * self.hinv_rhs[k];
        }
        Schur {
            s00,
            s01: 0.5 * (s01 + s10),
            s11,
            e0,
            e1,
        }
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

    fn held_by_obstacle(&self) -> bool {
        match (&self.world, self.last_clearance) {
            (Some(w), Some(c)) => !w.obstacles().is_empty() && c <= w.clearance_m() + HELD_MARGIN_M,
            _ => false,
        }
    }

    fn scratch_pose(&mut self) -> &mut Vec<f64> {
        &mut self.w.stage
    }
}

#[cfg(test)]
mod tests;
