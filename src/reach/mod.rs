//! A clear way in joint space to a target, for where the tip's route cannot pull the body.
//!
//! A `goto` leads the tip along its route and lets the strategy move the body the least it can
//! each tick. Round an obstacle that least motion can wrap the body on the side the route led
//! it to, while the clear poses with the tip on the target lie round the other side: the arm
//! ends `blocked` (docs/WORLD.md measures how often, and why no other tick gets out). Here
//! the arm goes there as a whole instead:
//!
//! 1. **The goal**: the best clear pose with the tip on the target, the overall strategy's
//!    cold solve among the obstacles from the current pose (metric 3 from it), its clearance
//!    raised by the larger of [`ReachOptions::margin_m`] and what rounding each joint to the
//!    servos' resolution may take (what the overall strategy keeps); so rounded it must keep
//!    `clearance_m`, as the controller sends it.
//! 2. **The way**: straight legs in joint space from the current pose to the goal, found by a
//!    bidirectional rapidly-exploring random tree (RRT-Connect, Kuffner and LaValle, 2000):
//!    poses drawn at random within the limits, each tree grown toward them by steps of at most
//!    [`ReachOptions::step_rad`] and the other tree pulled straight toward what grew, until the
//!    two meet. Every pose a tree keeps is clear by `clearance_m + margin_m`.
//! 3. **Shorter**: legs whose ends can be joined straight are joined
//!    ([`ReachOptions::shortcuts`] tries), since the arm comes to rest at each leg's end.
//!
//! **A leg is clear** when every pose along it keeps [`LEG_KEEP_M`] more than `clearance_m`
//! from every obstacle, stays within the limits (a box: straight legs between poses within it
//! stay within it), and keeps its links more than [`SELF_CLEARANCE_M`] from each other. It is
//! checked by a conservative bound, not by samples that could step over a corner: along a leg
//! from `a` to `b` no point of the arm moves more than the leg's sweep, `sum_i |b_i - a_i| L_i`
//! (`L_i` the length joint `i` carries), times the fraction walked; so from a pose of clearance
//! `c` the next `c - keep` of sweep needs no look (at least [`MIN_ADVANCE_M`] is taken, which
//! [`LEG_KEEP_M`] covers). The links' gaps to each other are checked at each pose looked at
//! with twice the step to the next added. Where the clearance is within rounding's reach of
//! `clearance_m` (each joint rounded to a whole servo tick moves a point by up to the sum of
//! half a tick times the length each joint carries), the poses as sent are looked at as well,
//! every one the leg passes (the rounded pose changes only where a joint crosses half a tick):
//! the controller holds each goal as sent to the clearance, and would cut the leg short where
//! one is not clear. An arm caught leaning on the clearance starts there.
//!
//! Pure and deterministic: the same request gives the same way (a splitmix64 generator seeded
//! with [`ReachOptions::seed`]), and nothing is read from a clock: the work is bounded by
//! [`ReachOptions::max_checks`] poses looked at.

use crate::chain::{round_to, Chain, Reachability, Vec2, SELF_CLEARANCE_M};
use crate::resolve::overall::{Overall, OverallOptions, SplitMix};
use crate::world::{Pair, World};

mod escape;

/// What a leg keeps beyond `clearance_m`, m (less when the arm starts closer than that, down
/// to `clearance_m` itself): room for round-off and for the least step along a leg
/// ([`MIN_ADVANCE_M`]), so that the controller's own check of each leg (samples a millimetre of
/// motion apart, each against `clearance_m`) passes wherever its samples fall.
pub const LEG_KEEP_M: f64 = 1e-4;

/// How far from the target a goal's tip may be, m: a cold solve that stopped short of its
/// optimality tolerance is taken when its tip is this close (and the pose clear).
pub const GOAL_TIP_M: f64 = 1e-9;

/// The tip's step between two local solves of [`goal_along`], m: a few control ticks' worth.
const ALONG_STEP_M: f64 = 0.005;

/// The least step along a leg, m of sweep: a pose whose slack is below it is looked at again
/// this far on (only a leg that grazes the clearance takes such steps).
pub const MIN_ADVANCE_M: f64 = 1e-5;

/// The most sweep between two looks at the links' gaps to each other, as a share of the
/// shortest link: the gap looked for, twice the step, stays well within a link's length (two
/// neighbouring links count as touching only when folded back within it).
const SELF_STEP_LINKS: f64 = 0.25;

/// How a way is sought.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReachOptions {
    /// What the goal and every pose the trees keep hold beyond `clearance_m`, m: room for the
    /// legs between them, and for rounding each joint to a whole servo tick.
    pub margin_m: f64,
    /// The longest step a tree grows by, rad (Euclidean, over all joints).
    pub step_rad: f64,
    /// The most poses drawn at random before giving up.
    pub max_samples: usize,
    /// The most poses looked at (clearance and self-contact) before giving up: bounds the work.
    pub max_checks: usize,
    /// Tries at joining two legs' ends straight.
    pub shortcuts: usize,
    /// Seed of the random poses and shortcuts.
    pub seed: u64,
}

impl Default for ReachOptions {
    fn default() -> Self {
        Self {
            margin_m: 2e-3,
            step_rad: 0.25,
            max_samples: 20_000,
            max_checks: 4_000_000,
            shortcuts: 200,
            seed: 0x5eed,
        }
    }
}

/// What to reach, from where, among what.
#[derive(Debug, Clone, Copy)]
pub struct ReachRequest<'a> {
    /// The arm.
    pub chain: &'a Chain,
    /// The obstacles and the clearance to keep.
    pub world: &'a World,
    /// The pose the arm is at (commanded), rad.
    pub from: &'a [f64],
    /// Where the tip should end, m.
    pub target: Vec2,
    /// Each joint's resolution, rad (what the servos take: the goal rounded to it must be
    /// clear); empty for exact joints.
    pub quanta: &'a [f64],
}

/// A way found: the legs' ends in order, the last the goal.
#[derive(Debug, Clone, PartialEq)]
pub struct Way {
    /// Each leg's end pose, rad; the arm goes straight (in joint space) from one to the next,
    /// starting at the request's `from`.
    pub legs: Vec<Vec<f64>>,
    /// Poses looked at, in all.
    pub checks: usize,
    /// Poses the two trees held when they met (0 when the straight leg was clear).
    pub nodes: usize,
}

/// Why no way was found. Each names the numbers that tell why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReachError {
    /// The pose or the target is not one of this arm (wrong length, not finite, outside the
    /// limits).
    #[error("{0}")]
    BadInput(String),
    /// The target lies where no pose of the arm puts the tip (beyond its reach around the base,
    /// inside the hole its links leave, or outside the bearings its limits allow).
    #[error(
        "the target ({:.4}, {:.4}) m is out of the arm's reach: {distance_m:.4} m from the base, \
         where the tip can be from {r_min_m:.4} to {r_max_m:.4} m{}",
        target.x,
        target.y,
        if *bearing { " (and not at that bearing, within the joint limits)" } else { "" }
    )]
    OutOfReach {
        /// The target, m.
        target: Vec2,
        /// Its distance from the base, m.
        distance_m: f64,
        /// The nearest and farthest the tip can be from the base, m.
        r_min_m: f64,
        /// See `r_min_m`.
        r_max_m: f64,
        /// Whether it is within those radii but at a bearing the limits rule out.
        bearing: bool,
    },
    /// The arm is not clear where it stands, and no way out was found that takes no link
    /// closer to an obstacle (see the module doc).
    #[error(
        "the arm is not clear where it stands: link {link} is {} (the clearance to keep is \
         {keep_m} m), and no way out was found that takes no link closer to an obstacle; move \
         it out first",
        crate::world::standing(*clearance_m, obstacle)
    )]
    NotClearNow {
        /// The link, 1-based from the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
        /// The link's clearance, m.
        clearance_m: f64,
        /// The clearance to keep, m.
        keep_m: f64,
    },
    /// The arm's links touch each other where it stands.
    #[error("links {a} and {b} touch where the arm stands (1-based); untangle it first")]
    TangledNow {
        /// The first link, 1-based.
        a: usize,
        /// The second link, 1-based.
        b: usize,
    },
    /// No pose with the tip on the target keeps the clearance and the margin (the cold solve
    /// found none).
    #[error(
        "no pose found with the tip on ({:.4}, {:.4}) m that keeps {keep_m} m from every \
         obstacle (the cold solve ended {tip_error_m:.2e} m from it after {iterations} \
         iterations)",
        target.x, target.y
    )]
    NoClearPose {
        /// The target, m.
        target: Vec2,
        /// The clearance asked, m (`clearance_m + margin_m`).
        keep_m: f64,
        /// How far the best pose found left the tip, m.
        tip_error_m: f64,
        /// Solver iterations, over all its starts.
        iterations: usize,
    },
    /// The goal is clear but not once each joint is rounded to its resolution.
    #[error(
        "the best pose with the tip on the target is not clear as the servos take it (each \
         joint rounded to a whole tick): {what}"
    )]
    GoalNotClear {
        /// What is wrong with it, in words.
        what: String,
    },
    /// The goal's links touch each other once each joint is rounded to its resolution: a
    /// target at (or within a rounding of) the base, where the tip meets the first link.
    #[error(
        "the best pose with the tip on the target folds the arm onto itself: links {a} and {b} \
         touch as the servos take it (each joint rounded to a whole tick)"
    )]
    GoalFolded {
        /// The first link, 1-based.
        a: usize,
        /// The second link, 1-based.
        b: usize,
    },
    /// The trees did not meet within the work allowed.
    #[error(
        "no clear way found in joint space: {samples} random poses drawn and {checks} looked \
         at, the trees holding {nodes} poses"
    )]
    NoWay {
        /// Poses drawn.
        samples: usize,
        /// Poses looked at.
        checks: usize,
        /// Poses the two trees held.
        nodes: usize,
    },
}

/// Finds a clear way from `req.from` to the best clear pose with the tip on `req.target` (see
/// the module doc).
pub fn plan(req: &ReachRequest, opts: &ReachOptions) -> Result<Way, ReachError> {
    let n = req.chain.len();
    check_pose(req.chain, req.from, "the arm's pose")?;
    if !(req.target.x.is_finite() && req.target.y.is_finite()) {
        return Err(ReachError::BadInput(format!(
            "the target ({}, {}) is not a finite point",
            req.target.x, req.target.y
        )));
    }
    if !(req.quanta.is_empty() || req.quanta.len() == n)
        || !req.quanta.iter().all(|q| q.is_finite() && *q >= 0.0)
    {
        return Err(ReachError::BadInput(format!(
            "{} joint resolutions for {n} joints, or one not a finite angle of at least 0",
            req.quanta.len()
        )));
    }
    if !(opts.margin_m.is_finite() && opts.margin_m >= 2.0 * LEG_KEEP_M) {
        return Err(ReachError::BadInput(format!(
            "margin_m {} is below {} m",
            opts.margin_m,
            2.0 * LEG_KEEP_M
        )));
    }
    let ring = req.chain.ring();
    let offset = req.target - req.chain.base();
    if ring.classify(offset) == Reachability::Outside {
        let d = offset.norm();
        return Err(ReachError::OutOfReach {
            target: req.target,
            distance_m: d,
            r_min_m: ring.r_min,
            r_max_m: ring.r_max,
            bearing: d >= ring.r_min && d <= ring.r_max,
        });
    }
    let mut look = Looker::new(req, opts);
    let keep_m = req.world.clearance_m();
    let now = req.chain.points(req.from);
    if let Some((a, b)) = Chain::self_intersects(&now) {
        return Err(ReachError::TangledNow { a: a + 1, b: b + 1 });
    }
    let start = req.world.clearance(&now);
    if let Some(p) = start {
        // An arm caught on an obstacle leans on it at the clearance itself: its legs keep that
        // much, and the margin above it only as far as the start has it (an arm not clear gets
        // out first, clear by the margin).
        look.leg_keep = keep_m + (p.clearance_m - keep_m).clamp(0.0, LEG_KEEP_M);
    }
    // An arm an obstacle was put onto first gets out ([`escape`]); the way round starts there.
    let out = if start.is_some_and(|p| p.clearance_m < keep_m) {
        look.leg_keep = keep_m + LEG_KEEP_M;
        escape::way_out(&mut look, req)?
    } else {
        Vec::new()
    };
    // The goal is the least motion from where the way round starts: out on the side it got
    // out on, not across the obstacle.
    let from = out.last().map_or(req.from, |p| p.as_slice());
    let round = ReachRequest { from, ..*req };
    // The cold solve can stop short where the tip's straight way gets there (a target on the
    // edge of the reach, where the arm is straight): that goal then.
    // The goal the tip's straight way leads to, looked for once whichever asks first.
    let along = std::cell::OnceCell::new();
    let straight = || along.get_or_init(|| goal_along(&round, opts)).clone();
    let goal = match goal_pose(&round, opts) {
        Err(none @ ReachError::NoClearPose { .. }) => {
            edge_pose(&round, opts).or_else(straight).ok_or(none)?
        }
        found => found?,
    };
    let mut rng = SplitMix(opts.seed);
    let (mut legs, nodes) = match way_to(&mut look, &round, &goal, opts, &mut rng) {
        // The best goal may lie where the trees cannot get (across an obstacle the arm would
        // have to fold away from): the goal the tip's straight way leads to, when another.
        Err(no @ ReachError::NoWay { .. }) => match straight() {
            Some(g) if g != goal => {
                way_to(&mut look, &round, &g, opts, &mut rng).map_err(|_| no)?
            }
            _ => return Err(no),
        },
        found => found?,
    };
    shorten(&mut look, &mut legs, opts.shortcuts, &mut rng);
    legs.remove(0);
    Ok(Way {
        legs: out.into_iter().chain(legs).collect(),
        checks: look.checks,
        nodes,
    })
}

/// The request's pose checked: one finite angle per joint, within the limits.
fn check_pose(chain: &Chain, theta: &[f64], what: &str) -> Result<(), ReachError> {
    if theta.len() != chain.len() {
        return Err(ReachError::BadInput(format!(
            "{what} has {} angles for {} joints",
            theta.len(),
            chain.len()
        )));
    }
    if let Some(i) = theta.iter().position(|t| !t.is_finite()) {
        return Err(ReachError::BadInput(format!(
            "{what}: joint {} is {}, not a finite angle",
            i + 1,
            theta[i]
        )));
    }
    chain
        .check_limits(theta)
        .map_err(|e| ReachError::BadInput(format!("{what}: {e}")))
}

/// The way from `req.from` to `goal`: the straight leg when it is clear, else the trees'. Both
/// ends included; the poses the trees held (0 for the straight leg).
fn way_to(
    look: &mut Looker,
    req: &ReachRequest,
    goal: &[f64],
    opts: &ReachOptions,
    rng: &mut SplitMix,
) -> Result<(Vec<Vec<f64>>, usize), ReachError> {
    if look.leg(req.from, goal) {
        Ok((vec![req.from.to_vec(), goal.to_vec()], 0))
    } else {
        connect(look, req, goal, opts, rng)
    }
}

/// What the goal keeps, m: `clearance_m` and the larger of the margin and what rounding the
/// joints to their resolutions may take. The controller's overall strategy keeps the latter
/// (the world it plans in), so a tip command after the reach starts from a pose it would keep,
/// the body still.
fn goal_keep(req: &ReachRequest, opts: &ReachOptions) -> f64 {
    req.world.clearance_m() + opts.margin_m.max(req.chain.rounding_m(req.quanta))
}

/// The overall solver among `req.world` with its clearance raised as the goal keeps it.
fn raised_solver(req: &ReachRequest, opts: &ReachOptions) -> Result<Overall, ReachError> {
    let w = req.world;
    let raised = World::new(
        w.link_radius_m(),
        goal_keep(req, opts),
        w.obstacles().to_vec(),
    )
    .map_err(|e| ReachError::BadInput(format!("the world with the margin: {e}")))?;
    let mut solver = Overall::new(OverallOptions::default());
    solver.set_world(Some(raised));
    Ok(solver)
}

/// The best clear pose with the tip on the target, its clearance raised as [`goal_keep`] says; checked
/// as the servos take it.
fn goal_pose(req: &ReachRequest, opts: &ReachOptions) -> Result<Vec<f64>, ReachError> {
    let keep_m = goal_keep(req, opts);
    let mut goal = vec![0.0; req.chain.len()];
    let o = raised_solver(req, opts)?.solve_cold(req.chain, req.from, req.target, &mut goal);
    // A pose on the target that keeps the clearance asked will do, optimal or not (a cold solve
    // among many obstacles can stop short of its optimality tolerance with the tip there).
    if !(o.converged || on_target_clear(req, opts, &goal)) {
        return Err(ReachError::NoClearPose {
            target: req.target,
            keep_m,
            tip_error_m: o.tip_error,
            iterations: o.iterations,
        });
    }
    checked_as_sent(req, goal)
}

/// The pose the tip's straight way from `req.from` to the target leads to: a local solve every
/// [`ALONG_STEP_M`] of it, as control ticks would take it, each clear by the margin; `None`
/// where the body is caught on the way, or the pose is not clear as the servos take it.
fn goal_along(req: &ReachRequest, opts: &ReachOptions) -> Option<Vec<f64>> {
    let mut solver = raised_solver(req, opts).ok()?;
    let start = req.chain.tip(req.from);
    let steps = ((req.target - start).norm() / ALONG_STEP_M).ceil().max(1.0) as usize;
    let (mut at, mut next) = (req.from.to_vec(), req.from.to_vec());
    for k in 1..=steps {
        let t = start + (req.target - start) * (k as f64 / steps as f64);
        if !solver.solve_local(req.chain, &at, t, &mut next).converged {
            return None;
        }
        std::mem::swap(&mut at, &mut next);
    }
    on_target_clear(req, opts, &at)
        .then(|| checked_as_sent(req, at).ok())
        .flatten()
}

/// On the outer edge of the reach the only pose is the arm straight toward the target, where
/// the solvers' steps are singular and stop short: that pose, when it is within the limits,
/// on the target and clear as the goal must be.
fn edge_pose(req: &ReachRequest, opts: &ReachOptions) -> Option<Vec<f64>> {
    let offset = req.target - req.chain.base();
    if (offset.norm() - req.chain.ring().r_max).abs() > GOAL_TIP_M {
        return None;
    }
    let mut straight = vec![0.0; req.chain.len()];
    let turn = offset.y.atan2(offset.x) - req.chain.heading();
    // The turn of joint 1 within a half turn either way of 0, as its limits count it.
    straight[0] = turn - std::f64::consts::TAU * (turn / std::f64::consts::TAU).round();
    (req.chain.check_limits(&straight).is_ok() && on_target_clear(req, opts, &straight))
        .then(|| checked_as_sent(req, straight).ok())
        .flatten()
}

/// Whether `goal` has the tip on the target and keeps the clearance and the margin.
fn on_target_clear(req: &ReachRequest, opts: &ReachOptions, goal: &[f64]) -> bool {
    let keep_m = goal_keep(req, opts);
    (req.chain.tip(goal) - req.target).norm() <= GOAL_TIP_M
        && req
            .world
            .clearance(&req.chain.points(goal))
            .is_none_or(|p| p.clearance_m >= keep_m - LEG_KEEP_M)
}

/// `goal`, refused when rounded to the joints' resolutions its links touch or one loses the
/// clearance.
fn checked_as_sent(req: &ReachRequest, goal: Vec<f64>) -> Result<Vec<f64>, ReachError> {
    let w = req.world;
    let mut sent = goal.clone();
    round_to(&goal, req.quanta, &mut sent);
    let pts = req.chain.points(&sent);
    if let Some((a, b)) = Chain::self_intersects(&pts) {
        return Err(ReachError::GoalFolded { a: a + 1, b: b + 1 });
    }
    if let Some(p) = w
        .clearance(&pts)
        .filter(|p| p.clearance_m < w.clearance_m())
    {
        return Err(ReachError::GoalNotClear {
            what: format!(
                "link {} is {} (the clearance to keep is {} m)",
                p.link,
                crate::world::standing(p.clearance_m, p.id(w)),
                w.clearance_m()
            ),
        });
    }
    Ok(goal)
}

/// Looks at poses and legs, counting.
struct Looker<'a> {
    chain: &'a Chain,
    world: &'a World,
    /// What every pose along a leg keeps, m.
    leg_keep: f64,
    /// What every pose a tree keeps holds, m.
    node_keep: f64,
    /// Each joint's resolution, rad (empty: exact).
    quanta: &'a [f64],
    /// The most rounding each joint to its resolution moves any point, m.
    rounding_m: f64,
    /// The most sweep between two looks at the links' gaps, m ([`SELF_STEP_LINKS`]).
    self_step_m: f64,
    /// Where along a leg some joint crosses from one whole tick to the next (scratch).
    cuts: Vec<f64>,
    pose: Vec<f64>,
    /// `pose` as sent (rounded to `quanta`).
    sent: Vec<f64>,
    points: Vec<Vec2>,
    checks: usize,
    max_checks: usize,
}

impl<'a> Looker<'a> {
    fn new(req: &ReachRequest<'a>, opts: &ReachOptions) -> Self {
        let n = req.chain.len();
        let links = req.chain.links();
        let shortest = links.iter().copied().fold(f64::INFINITY, f64::min);
        Self {
            chain: req.chain,
            world: req.world,
            leg_keep: req.world.clearance_m() + LEG_KEEP_M,
            node_keep: req.world.clearance_m() + opts.margin_m,
            quanta: req.quanta,
            rounding_m: req.chain.rounding_m(req.quanta),
            self_step_m: SELF_STEP_LINKS * shortest,
            cuts: Vec::new(),
            pose: vec![0.0; n],
            sent: vec![0.0; n],
            points: vec![Vec2::zeros(); n + 1],
            checks: 0,
            max_checks: opts.max_checks,
        }
    }

    fn out_of_work(&self) -> bool {
        self.checks >= self.max_checks
    }

    /// The nearest pair of `self.points` (`None`: no obstacles).
    fn nearest(&mut self) -> Option<Pair> {
        self.checks += 1;
        self.world.clearance(&self.points)
    }

    /// Whether a pose a tree would keep is clear by the margin, with links apart, and clear
    /// once rounded to the joints' resolution (each leg's end is a goal the servos take).
    fn node(&mut self, theta: &[f64]) -> bool {
        self.chain.points_into(theta, &mut self.points);
        let clear = self
            .nearest()
            .is_none_or(|p| p.clearance_m >= self.node_keep);
        if !clear || Chain::self_intersects(&self.points).is_some() {
            return false;
        }
        if self.quanta.is_empty() {
            return true;
        }
        round_to(theta, self.quanta, &mut self.sent);
        self.chain.points_into(&self.sent, &mut self.points);
        self.nearest()
            .is_none_or(|p| p.clearance_m >= self.world.clearance_m())
            && Chain::self_intersects(&self.points).is_none()
    }

    /// Whether the straight leg from `a` to `b` is clear (see the module doc); false, too,
    /// when the work allowed runs out.
    fn leg(&mut self, a: &[f64], b: &[f64]) -> bool {
        let sweep = self.chain.sweep(a, b);
        let mut f = 0.0_f64;
        loop {
            if self.out_of_work() {
                return false;
            }
            for ((x, &p), &q) in self.pose.iter_mut().zip(a).zip(b) {
                *x = p + f * (q - p);
            }
            self.chain.points_into(&self.pose, &mut self.points);
            let clearance = self.nearest().map_or(f64::INFINITY, |p| p.clearance_m);
            let slack = clearance - self.leg_keep;
            if slack < 0.0 {
                return false;
            }
            if f >= 1.0 {
                return Chain::self_intersects(&self.points).is_none();
            }
            let left = (1.0 - f) * sweep;
            let mut advance = slack.min(self.self_step_m).max(MIN_ADVANCE_M).min(left);
            // Two links close by at most twice what each moves before the next look.
            while Chain::self_intersects_within(&self.points, SELF_CLEARANCE_M + 2.0 * advance)
                .is_some()
            {
                if advance <= MIN_ADVANCE_M {
                    return false;
                }
                advance = (0.25 * advance).max(MIN_ADVANCE_M);
            }
            let next = if advance >= left {
                1.0
            } else {
                f + advance / sweep
            };
            // Within rounding's reach of the clearance, the goals as sent (each joint rounded
            // to a whole tick) are looked at too: every one met between here and the next look.
            let near = clearance < self.world.clearance_m() + self.rounding_m;
            if near && !self.quanta.is_empty() && !self.sent_clear(a, b, f, next) {
                return false;
            }
            f = next;
        }
    }

    /// Whether every pose as sent (each joint rounded to its resolution) along the leg from
    /// `a` to `b` between fractions `f0` and `f1` keeps `clearance_m`: the rounded pose changes
    /// only where some joint crosses half a tick, so each piece between two such crossings is
    /// looked at once.
    fn sent_clear(&mut self, a: &[f64], b: &[f64], f0: f64, f1: f64) -> bool {
        /// More crossings than this in one stretch: not looked at one by one, refused.
        const MAX_CUTS: usize = 4096;
        self.cuts.clear();
        self.cuts.extend([f0, f1]);
        for ((&p, &r), &q) in a.iter().zip(b).zip(self.quanta) {
            let d = r - p;
            if q <= 0.0 || d == 0.0 {
                continue;
            }
            let (t0, t1) = (p + f0 * d, p + f1 * d);
            let (lo, hi) = (t0.min(t1), t0.max(t1));
            let first = (lo / q - 0.5).ceil();
            let last = (hi / q - 0.5).floor();
            if last - first > MAX_CUTS as f64 {
                return false;
            }
            let mut k = first;
            while k <= last {
                let cut = ((k + 0.5) * q - p) / d;
                if cut > f0 && cut < f1 {
                    self.cuts.push(cut);
                }
                k += 1.0;
            }
            if self.cuts.len() > MAX_CUTS {
                return false;
            }
        }
        self.cuts.sort_by(f64::total_cmp);
        for i in 1..self.cuts.len() {
            let (u, v) = (self.cuts[i - 1], self.cuts[i]);
            if v <= u {
                continue;
            }
            let mid = 0.5 * (u + v);
            for ((x, &p), &r) in self.pose.iter_mut().zip(a).zip(b) {
                *x = p + mid * (r - p);
            }
            round_to(&self.pose, self.quanta, &mut self.sent);
            self.chain.points_into(&self.sent, &mut self.points);
            if self
                .nearest()
                .is_some_and(|c| c.clearance_m < self.world.clearance_m())
            {
                return false;
            }
        }
        true
    }
}

/// One tree: its poses (flat, `n` a pose) and each one's parent (`usize::MAX` at the root).
struct Tree {
    n: usize,
    poses: Vec<f64>,
    parent: Vec<usize>,
}

impl Tree {
    fn new(root: &[f64]) -> Self {
        Self {
            n: root.len(),
            poses: root.to_vec(),
            parent: vec![usize::MAX],
        }
    }

    fn len(&self) -> usize {
        self.parent.len()
    }

    fn pose(&self, i: usize) -> &[f64] {
        &self.poses[i * self.n..(i + 1) * self.n]
    }

    fn push(&mut self, pose: &[f64], parent: usize) -> usize {
        self.poses.extend_from_slice(pose);
        self.parent.push(parent);
        self.len() - 1
    }

    /// The pose nearest `q` (Euclidean in joint space).
    fn nearest(&self, q: &[f64]) -> usize {
        let mut best = (f64::INFINITY, 0);
        for i in 0..self.len() {
            let d: f64 = self
                .pose(i)
                .iter()
                .zip(q)
                .map(|(a, b)| (a - b).powi(2))
                .sum();
            if d < best.0 {
                best = (d, i);
            }
        }
        best.1
    }

    /// The poses from `i` back to the root.
    fn to_root(&self, mut i: usize) -> Vec<Vec<f64>> {
        let mut out = Vec::new();
        while i != usize::MAX {
            out.push(self.pose(i).to_vec());
            i = self.parent[i];
        }
        out
    }
}

/// `out` := the pose at most `step` from `from` toward `to`; whether it is `to` itself.
fn toward(from: &[f64], to: &[f64], step: f64, out: &mut [f64]) -> bool {
    let d = from
        .iter()
        .zip(to)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    if d <= step {
        out.copy_from_slice(to);
        return true;
    }
    for ((o, a), b) in out.iter_mut().zip(from).zip(to) {
        *o = a + (b - a) * step / d;
    }
    false
}

/// RRT-Connect between `req.from` and `goal`: the way, both ends included, and the poses the
/// trees held.
fn connect(
    look: &mut Looker,
    req: &ReachRequest,
    goal: &[f64],
    opts: &ReachOptions,
    rng: &mut SplitMix,
) -> Result<(Vec<Vec<f64>>, usize), ReachError> {
    let n = goal.len();
    let mut trees = [Tree::new(req.from), Tree::new(goal)];
    let bounds: Vec<(f64, f64)> = req
        .chain
        .limits()
        .iter()
        .zip(req.from)
        .map(|(l, t)| match l {
            Some(l) => (l.lo, l.hi),
            None => (t - std::f64::consts::PI, t + std::f64::consts::PI),
        })
        .collect();
    let (mut q, mut grown, mut next) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let mut samples = 0;
    while samples < opts.max_samples && !look.out_of_work() {
        let s = samples % 2;
        samples += 1;
        for (x, (lo, hi)) in q.iter_mut().zip(&bounds) {
            *x = lo + (hi - lo) * rng.unit();
        }
        // Grow tree `s` one step toward the random pose.
        let near = trees[s].nearest(&q);
        toward(trees[s].pose(near), &q, opts.step_rad, &mut grown);
        if !(look.node(&grown) && look.leg(trees[s].pose(near), &grown)) {
            continue;
        }
        let added = trees[s].push(&grown, near);
        // Pull the other tree straight toward it, step by step.
        let o = 1 - s;
        let mut at = trees[o].nearest(&grown);
        loop {
            let reached = toward(trees[o].pose(at), &grown, opts.step_rad, &mut next);
            let ok = (reached || look.node(&next)) && look.leg(trees[o].pose(at), &next);
            if !ok {
                break;
            }
            at = trees[o].push(&next, at);
            if reached {
                let mut way = trees[s].to_root(added);
                way.reverse();
                way.extend(trees[o].to_root(at).into_iter().skip(1));
                if s == 1 {
                    way.reverse();
                }
                return Ok((way, trees[0].len() + trees[1].len()));
            }
        }
    }
    Err(ReachError::NoWay {
        samples,
        checks: look.checks,
        nodes: trees[0].len() + trees[1].len(),
    })
}

/// Joins legs' ends straight where the leg between them is clear, `tries` times at random
/// pairs; the ends stay.
fn shorten(look: &mut Looker, way: &mut Vec<Vec<f64>>, tries: usize, rng: &mut SplitMix) {
    for _ in 0..tries {
        if way.len() < 3 || look.out_of_work() {
            return;
        }
        let m = way.len();
        let i = ((rng.unit() * (m - 2) as f64) as usize).min(m - 3);
        let j = i + 2 + ((rng.unit() * (m - i - 2) as f64) as usize).min(m - i - 3);
        if look.leg(&way[i].clone(), &way[j].clone()) {
            way.drain(i + 1..j);
        }
    }
}
