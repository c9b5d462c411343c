//! One control tick (pure): motion -> resolve -> joint-speed limit -> the goal pose.
//!
//! [`Controller`] owns the chain, the active command ([`crate::motion::Motion`]), both
//! resolvers (one [`Overall`] and one [`Sequential`], so switching strategy costs nothing) and
//! every scratch buffer. Each [`Controller::tick`]:
//!
//! 1. **Motion** steps the reference by `dt`: a tip point (goto, path, velocity: at most the
//!    tip speed limit), or a joint pose for goto_joints, home and jog (whose tip is reported as
//!    `tip_ref`; at most the joint speed limit, whatever speed the tip then has).
//! 2. **Resolve** a tip reference with the active strategy, warm from the last commanded pose.
//!    A reference the resolver cannot reach (outside the workspace, not converged, refused
//!    for the joint limits, or folding the arm onto itself) is not sent: the farthest
//!    fraction of this tick's step that resolves is found by [`BISECTION_ROUNDS`] rounds of
//!    bisection, and the tick is `saturated` (and `self_collision` where links would have
//!    touched). A joint reference is taken as it is: joint-space motion is bounded by the
//!    joint speed limit alone, not by the tip speed limit.
//! 3. **Joint-speed limit.** No goal moves more than `max_joint_speed_rad_s * dt` from the last
//!    one. A resolved step that would is shortened in proportion and re-resolved (up to
//!    [`SLOWDOWN_ROUNDS`] times, `slowed`); a final per-joint clamp guarantees the bound
//!    (`clamped`). The bound wins over the tip acceleration limit. Both ends of every joint's
//!    step lie inside its limits, so the clamped pose does too. A tip motion's clamped pose is
//!    no longer the resolver's answer (a body leaving an obstacle put onto it can ask every
//!    joint to turn its fastest), so it is moved back along its joint step until the tip moves
//!    no faster than the tip speed limit (`keep_tip_speed`).
//! 4. **Self-collision.** No goal pose brings two links within [`SELF_CLEARANCE_M`] of each
//!    other ([`Chain::self_intersects`]). The final pose is checked once more (a clamped step
//!    or a joint reference was not checked yet); if it touches, the tick takes the farthest
//!    fraction of its joint step (theta -> pose, a straight line in joint space, so the bound
//!    and the limits still hold) that stays clear, by [`BISECTION_ROUNDS`] rounds of
//!    bisection, and flags `saturated` and `self_collision`. A commanded pose with links
//!    already in contact (only a measured pose, from [`Controller::new`] or
//!    [`Controller::reseed`], can be; [`Controller::self_contact`] names the pair) is
//!    **tangled**: it may move as long as it gets no worse
//!    ([`Chain::worse_self_intersection`]: no more pairs crossing, and no contact but where
//!    one was or on the next link of the chain), so a joint move such as `home` slides a
//!    crossing off the arm; once clear, no pair may touch again. Only the poses of the ticks
//!    are checked: links are joined end to end, so two that begin to cross within a tick
//!    still cross at its end and are caught then, unless the arm's two free ends (the tip and
//!    the base end of link 1) slip past each other within one tick's travel.
//! 5. **Obstacles** ([`Controller::set_world`]). No goal pose loses clearance: each link keeps
//!    its floor, the world's `clearance_m` (or, for a link not clear when the world was set
//!    or the pose reseeded, the best clearance it has had since, so that it may only get
//!    clearer), to [`CLEARANCE_ROUNDOFF_M`] (lost once: a floor never sinks); with
//!    the joints' resolutions set ([`Controller::set_joint_resolution`]) the pose rounded to
//!    them (what the servos receive, in whole ticks) keeps it too, and the controller plans
//!    with the clearance raised by the most that rounding can move the arm. The check runs on every
//!    resolver answer (a step that fails it is bisected like one out of reach) and on the
//!    final pose and the way to it, every [`JOINT_WAY_STEP_M`] of the arm's motion (cut back
//!    along its joint step, like a self-collision), and the tick reports
//!    the link and obstacle that held it back (`blocked`). The overall solver keeps the
//!    clearance itself (plus what rounding can take away), so it goes round; from a pose not
//!    clear, a link nearer than that need only come no closer in the solve
//!    ([`Overall::set_floors`]), so that a body deep in an obstacle can slide out; the sequential
//!    strategy's tractrix body does not look ahead, and is cut short where it would touch.
//!    Goto and path run the tip along the world's route ([`World::route`]: the straight line
//!    when clear, else the shortest way round the obstacles grown by the link radius and the
//!    clearance), one speed trapezoid per leg; a target the tip can never reach clear is
//!    refused ([`Refused::InsideObstacle`], [`Refused::NoRoute`]). A tip velocity slides:
//!    its reference is pushed out of the grown obstacles, which removes the part of the step
//!    into them. A joint move whose straight way passes a pose that would lose clearance is
//!    refused ([`Refused::NotClearOnTheWay`]). A goto, path or joint move that stalls against
//!    an obstacle, or whose tip advances less than [`HEADWAY_M`] in [`HEADWAY_S`], ends
//!    [`Finish::Blocked`].
//! 6. The motion **follows** what was achieved: a shortened step moves the reference back onto
//!    the arm, with the velocity the arm really had, so it never runs ahead. A goto or path
//!    among obstacles goes on along its route from the arm's tip, however far off its way a
//!    clamped or cut step left it. Every tick's tip reference thus starts on the arm and asks
//!    it to move at most the tip speed limit. A stop never speeds up: what the arm did
//!    takes over its reference only up to the speed the stop had come down to, and once that
//!    is zero the stop ends, met exactly or not (a body not clear of an obstacle, whose
//!    ticks may be held back for ever, holds where it got). A goto, path or joint move that makes no
//!    progress for [`crate::motion::STALL_TICKS`] saturated ticks ends with one
//!    [`Finish::Saturated`].
//!
//! A `GotoJoints` whose target pose itself self-intersects is refused
//! ([`Refused::SelfCollision`]): it could never arrive. So is a home pose that does, when the
//! controller is built.
//!
//! Goals jump only through [`Controller::reseed`] (goal := the measured pose, which moves no
//! servo). Once warm, `tick` allocates nothing, and it never panics: a bad `dt` (zero, negative,
//! non-finite) advances nothing, `dt` above [`MAX_DT_S`] counts as [`MAX_DT_S`], and commands
//! with non-finite or huge numbers are refused by [`Controller::command`].

use std::collections::VecDeque;

use crate::chain::{round_to, Chain, Vec2, MAX_MAGNITUDE, SELF_CLEARANCE_M};
use crate::motion::{joint_accel, Achieved, Motion, MotionLimits, Reference};
use crate::reach::Way;
use crate::resolve::overall::{Overall, OverallOptions};
use crate::resolve::sequential::Sequential;
use crate::resolve::{verdict, Resolver, Strategy};
use crate::world::{Pair, World, MAX_ROUTE_WORK};

pub use crate::motion::{Activity, Finish, JOINT_ACCEL_TIME_S};
pub use planning::{
    plan, plan_route, Accepted, NotStarted, PlanRequest, Planned, PlannedRoute, ReachJob, Replan,
    RouteRequest,
};
pub use refused::{NotClear, Refused, SelfContact};

mod planning;
mod refused;

/// Bisection rounds on the fraction of a step whose end is out of reach: the achieved step is
/// within `1 / 2^BISECTION_ROUNDS` of the farthest that resolves.
pub const BISECTION_ROUNDS: usize = 6;

/// Re-solves of a step shortened for the joint-speed bound before the final clamp.
pub const SLOWDOWN_ROUNDS: usize = 2;

/// The longest tick taken at face value, s; a longer `dt` counts as this.
pub const MAX_DT_S: f64 = 1.0;

/// Margin under the exact ratio when a step is shortened, so that the re-solved step usually
/// fits at once despite the nonlinearity.
const SHORTEN_MARGIN: f64 = 0.98;

/// Round-off a pose's clearance may lose against its floor, m: a pose whose every link keeps
/// its floor within this counts as keeping it (a solver's constraint met to round-off).
pub const CLEARANCE_ROUNDOFF_M: f64 = 1e-9;

/// Headway of a goto or path among obstacles: the tip must advance at least this far (or half
/// what its cruise speed covers in [`HEADWAY_S`], if less) within [`HEADWAY_S`], m...
pub const HEADWAY_M: f64 = 1e-3;

/// ...or the command ends [`Finish::Blocked`], s.
pub const HEADWAY_S: f64 = 0.5;

/// The poses of a joint move's way checked against the world are this close, m: no point of
/// the arm moves farther between two of them.
pub const JOINT_WAY_STEP_M: f64 = 1e-3;

/// Most poses of a joint move's way checked against the world.
const MAX_JOINT_WAY_SAMPLES: usize = 20_000;

/// What a free sweep ([`World::free_sweep`]) is shortened by before samples are passed over on
/// its strength, m: round-off in the distances and the sweep.
const SWEEP_SLACK_M: f64 = 1e-9;

/// Relative excess over the joint-speed bound that counts as round-off, not as a clamp (the
/// goal is still put exactly on the bound).
const CLAMP_ROUNDOFF: f64 = 1e-9;

/// The motion limits of the arm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Fastest tip speed, m/s.
    pub max_tip_speed_m_s: f64,
    /// Fastest change of the tip velocity, m/s².
    pub max_tip_accel_m_s2: f64,
    /// Fastest joint speed, rad/s: no goal moves more than this times `dt` in a tick.
    pub max_joint_speed_rad_s: f64,
    /// How long a velocity or jog command lasts after it was last sent, s.
    pub deadman_s: f64,
}

impl Limits {
    /// The joint acceleration of joint moves and jog, rad/s²: `max_joint_speed_rad_s /`
    /// [`JOINT_ACCEL_TIME_S`].
    pub fn joint_accel_rad_s2(&self) -> f64 {
        joint_accel(self.max_joint_speed_rad_s)
    }

    fn motion(&self) -> MotionLimits {
        MotionLimits {
            tip_speed: self.max_tip_speed_m_s,
            tip_accel: self.max_tip_accel_m_s2,
            joint_speed: self.max_joint_speed_rad_s,
            joint_accel: self.joint_accel_rad_s2(),
            deadman: self.deadman_s,
        }
    }
}

/// A motion command. Joints are numbered from 0.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// The tip along a straight line (from rest) to `target`, m, at `speed` m/s (default and
    /// most: the tip speed limit).
    Goto {
        /// Target tip position, m.
        target: Vec2,
        /// Cruise speed, m/s.
        speed: Option<f64>,
    },
    /// The tip through `points` in turn, coming to rest at each.
    Path {
        /// Corners, m (at least one).
        points: Vec<Vec2>,
        /// Cruise speed, m/s.
        speed: Option<f64>,
    },
    /// A tip velocity, m/s (magnitude clamped to the limit), lasting `deadman_s` after the
    /// last one sent; then the tip decelerates to rest.
    Velocity {
        /// Tip velocity, m/s.
        v: Vec2,
    },
    /// One joint at a rate, rad/s (clamped to the limit), with the same deadman; it comes to
    /// rest at the joint's limit instead of hitting it.
    Jog {
        /// Joint index, from 0.
        joint: usize,
        /// Rate, rad/s.
        rad_s: f64,
    },
    /// A joint-space move to a pose inside the limits.
    GotoJoints {
        /// Target pose, rad, one angle per joint.
        theta: Vec<f64>,
    },
    /// A joint-space move to the home pose.
    Home,
    /// The tip to `target` by a clear way in joint space ([`crate::reach`]): the best clear
    /// pose with the tip there, reached in straight joint-space legs round the obstacles, each
    /// at the joint speed limit from rest to rest. [`Controller::command_within`] hands it back
    /// to be planned elsewhere ([`Accepted::Plan`]); [`Controller::command`] plans it in place.
    Reach {
        /// Target tip position, m.
        target: Vec2,
    },
    /// Decelerate to rest at the acceleration limit, then hold.
    Stop,
}

/// A tick cut short to keep the clearance: the link held back and the obstacle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Blocked {
    /// The link, 1-based from the base.
    pub link: usize,
    /// The obstacle's index in [`Controller::world`].
    pub obstacle: usize,
}

/// What one tick did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tick {
    /// This tick's motion reference (for a joint reference: its tip), m.
    pub tip_ref: Vec2,
    /// Tip of the new commanded pose, m.
    pub tip: Vec2,
    /// The reference (or part of the step) was out of reach, refused for the limits, or would
    /// have made the arm self-intersect.
    pub saturated: bool,
    /// The step was cut short because two links would have come within [`SELF_CLEARANCE_M`]
    /// of each other (`saturated` is then set too).
    pub self_collision: bool,
    /// The step was cut short to keep every link clear of the obstacles (or, from a pose not
    /// clear, to shrink no link's clearance): which link and obstacle held it back.
    pub blocked: Option<Blocked>,
    /// The clearance of the new commanded pose, m; `None` when the world has no obstacles.
    pub min_clearance_m: Option<f64>,
    /// The step was shortened and re-resolved to keep within the joint-speed bound.
    pub slowed: bool,
    /// The final per-joint clamp had to shorten a joint's step.
    pub clamped: bool,
    /// The active command ended in this tick (the controller is then holding).
    pub finished: Option<Finish>,
    /// `max_i |dtheta_i| / dt` this tick, rad/s.
    pub peak_joint_speed_rad_s: f64,
    /// `sum_i dtheta_i^2` this tick, rad².
    pub m3_rad2: f64,
    /// Resolver iterations spent, summed over bisection and re-solves.
    pub iterations: usize,
}

/// The control core: the commanded pose and everything that moves it.
#[derive(Debug)]
pub struct Controller {
    chain: Chain,
    limits: Limits,
    strategy: Strategy,
    overall: Overall,
    sequential: Sequential,
    home: Vec<f64>,
    motion: Motion,
    /// The commanded pose (this tick's goals).
    theta: Vec<f64>,
    /// Its tip.
    tip: Vec2,
    /// The pose to commit.
    cand: Vec<f64>,
    /// A resolver's answer.
    trial: Vec<f64>,
    /// The self-collision check, with the points of the commanded pose.
    guard: Guard,
    /// The obstacles every link keeps clear of.
    world: World,
    /// Each joint's resolution, rad (empty: exact): goals sent as whole servo ticks are checked
    /// rounded to it too.
    quanta: Vec<f64>,
    /// How far rounding to the resolutions can move any point of the arm, m.
    rounding_m: f64,
    /// The world planned in: the clearance raised by `rounding_m`, so that a goal rounded to
    /// whole servo ticks keeps the world's own. The overall solver keeps it, the tip's routes
    /// go round it, a velocity slides along it.
    plan: World,
    /// Headway of a goto or path among obstacles: where the tip was and how long ago.
    anchor: Option<(Vec2, f64)>,
    /// The `reach` under way: its target, and its legs still to go.
    reach: Option<Reaching>,
}

/// A `reach` under way.
#[derive(Debug)]
struct Reaching {
    /// Where the tip ends, m.
    target: Vec2,
    /// The legs still to go, each a joint-space move begun when the one before arrives.
    legs: VecDeque<Vec<f64>>,
}

/// The self-collision check of candidate poses against the commanded one.
#[derive(Debug)]
struct Guard {
    /// Points of the commanded pose.
    now: Vec<Vec2>,
    /// Points of the pose under test.
    scratch: Vec<Vec2>,
    /// Two links of the commanded pose are in contact.
    tangled: bool,
    /// Per pair of link and obstacle (`(link - 1) * obstacles + k`), the least clearance a new
    /// pose must keep: `best` less round-off.
    floors: Vec<f64>,
    /// Per pair, the best of [`World::link_floors`] of the commanded poses since the floors
    /// were last anchored ([`Guard::anchor`]): a floor never sinks, so the round-off a pose
    /// may lose against it is lost once, not a tick at a time.
    best: Vec<f64>,
    /// The commanded pose keeps the world's clearance on every link, and so does its goal as
    /// sent (rounded to the joints' resolutions, when set).
    clear: bool,
    /// Points of the commanded pose's goal as sent (rounded to the joints' resolutions), when
    /// they are set.
    sent: Vec<Vec2>,
    /// A pose rounded to the joints' resolutions.
    rounded: Vec<f64>,
    /// Per pair, what the overall solver is asked to keep from a pose within the clearance it
    /// plans with ([`Guard::solve_floors`]).
    solve: Vec<f64>,
    /// The least clearance of the commanded pose, m (`None` without obstacles): measured once
    /// a commit, read by telemetry and by the next tick's [`Guard::solve_floors`].
    least_m: Option<f64>,
}

impl Guard {
    fn new(chain: &Chain, theta: &[f64]) -> Self {
        let n = chain.len();
        let mut g = Self {
            now: vec![Vec2::zeros(); n + 1],
            scratch: vec![Vec2::zeros(); n + 1],
            tangled: false,
            floors: vec![f64::NEG_INFINITY; n],
            best: vec![f64::NEG_INFINITY; n],
            clear: true,
            sent: vec![Vec2::zeros(); n + 1],
            rounded: vec![0.0; n],
            solve: Vec::new(),
            least_m: None,
        };
        g.anchor(chain, &World::default(), &[], theta);
        g
    }

    /// The commanded pose is now `theta`, set from outside the checked ticks (a measured pose,
    /// a new world): the floors start again from its clearance. Returns its tip.
    fn anchor(&mut self, chain: &Chain, world: &World, quanta: &[f64], theta: &[f64]) -> Vec2 {
        // One floor per pair of link and obstacle.
        let pairs = chain.len() * world.obstacles().len().max(1);
        self.floors.resize(pairs, f64::NEG_INFINITY);
        self.best.resize(pairs, f64::NEG_INFINITY);
        self.solve.reserve(pairs);
        self.best.fill(f64::NEG_INFINITY);
        self.commit(chain, world, quanta, theta)
    }

    /// The commanded pose is now `theta`, a tick's checked step from the last; returns its tip.
    /// `quanta`: the joints' resolutions (empty for exact).
    fn commit(&mut self, chain: &Chain, world: &World, quanta: &[f64], theta: &[f64]) -> Vec2 {
        chain.points_into(theta, &mut self.now);
        self.tangled = Chain::self_intersects(&self.now).is_some();
        self.least_m = world.clearance(&self.now).map(|p| p.clearance_m);
        if world.obstacles().is_empty() {
            self.clear = true;
        } else {
            let keep = world.clearance_m();
            world.link_floors(&self.now, keep, &mut self.floors);
            self.clear = self.floors.iter().all(|&f| f >= keep);
            for (f, best) in self.floors.iter_mut().zip(&mut self.best) {
                *best = best.max(*f);
                *f = *best - CLEARANCE_ROUNDOFF_M;
            }
            if self.clear && !quanta.is_empty() {
                // An obstacle put between the goal as sent and the commanded pose is on the
                // arm as the servos hold it.
                round_to(theta, quanta, &mut self.rounded);
                chain.points_into(&self.rounded, &mut self.sent);
                self.clear = world.below_floors(&self.sent, &self.floors).is_none();
            }
        }
        self.now[chain.len()]
    }

    /// Per pair, the least clearance the overall solver must keep in a tick from the commanded
    /// pose against `plan` (the world planned in, the same obstacles): nothing (empty) from a
    /// pose that keeps `plan`'s clearance, else `plan`'s clearance, or for a pair below it where
    /// the pair is now (no closer), never below its floor. A clear pose can lie within the
    /// margin `plan` adds for rounding (a tip a few millimetres from an obstacle): asked for
    /// the whole of `plan`'s clearance, every solve from there failed and the arm froze, even
    /// moving away. Allocation-free once sized.
    fn solve_floors(&mut self, plan: &World) -> &[f64] {
        self.solve.clear();
        if plan.obstacles().is_empty() {
            return &self.solve;
        }
        // `plan` has the world's obstacles and link radius: the same clearances.
        let keeps_plan = self.least_m.is_none_or(|c| c >= plan.clearance_m());
        if self.clear && keeps_plan {
            return &self.solve;
        }
        self.solve.resize(self.best.len(), 0.0);
        plan.link_floors(&self.now, plan.clearance_m(), &mut self.solve);
        for (s, &b) in self.solve.iter_mut().zip(&self.best) {
            *s = s.max(b);
        }
        &self.solve
    }

    /// The first link of `pose` (and, from a clear pose, of `pose` rounded to `quanta`) below
    /// its floor, with the obstacle: a pose that would lose clearance.
    fn obstacle(
        &mut self,
        chain: &Chain,
        world: &World,
        quanta: &[f64],
        pose: &[f64],
    ) -> Option<Blocked> {
        if world.obstacles().is_empty() {
            return None;
        }
        chain.points_into(pose, &mut self.scratch);
        let mut hit = world.below_floors(&self.scratch, &self.floors);
        if hit.is_none() && self.clear && !quanta.is_empty() {
            round_to(pose, quanta, &mut self.rounded);
            chain.points_into(&self.rounded, &mut self.scratch);
            hit = world.below_floors(&self.scratch, &self.floors);
        }
        hit.map(|p| Blocked {
            link: p.link,
            obstacle: p.obstacle,
        })
    }

    /// The first pair of links that `pose` brings into contact and the commanded pose does not
    /// have in contact; from a tangled pose, the first pair that makes it worse.
    fn contact(&mut self, chain: &Chain, pose: &[f64]) -> Option<(usize, usize)> {
        chain.points_into(pose, &mut self.scratch);
        if self.tangled {
            Chain::worse_self_intersection(&self.scratch, &self.now, SELF_CLEARANCE_M)
        } else {
            Chain::new_self_intersection(&self.scratch, &self.now, SELF_CLEARANCE_M)
        }
    }
}

/// The first pair of links of the pose `theta` within [`SELF_CLEARANCE_M`] of each other, as a
/// refusal.
fn check_clear(chain: &Chain, theta: &[f64]) -> Result<(), Refused> {
    match Chain::self_intersects(&chain.points(theta)) {
        Some((a, b)) => Err(Refused::SelfCollision { a, b }),
        None => Ok(()),
    }
}

/// Checks a pose: length, finite, inside the limits.
fn check_pose(chain: &Chain, theta: &[f64], what: &'static str) -> Result<(), Refused> {
    if theta.len() != chain.len() {
        return Err(Refused::WrongLength {
            got: theta.len(),
            expected: chain.len(),
        });
    }
    for (joint, (&value, lim)) in theta.iter().zip(chain.limits()).enumerate() {
        check_number(value, what)?;
        if let Some(l) = lim {
            if !l.contains(value) {
                return Err(Refused::OutsideLimits {
                    joint,
                    value,
                    lo: l.lo,
                    hi: l.hi,
                });
            }
        }
    }
    Ok(())
}

fn check_number(value: f64, what: &'static str) -> Result<f64, Refused> {
    if !value.is_finite() {
        return Err(Refused::NotFinite { what });
    }
    if value.abs() > MAX_MAGNITUDE {
        return Err(Refused::TooLarge {
            what,
            value,
            max: MAX_MAGNITUDE,
        });
    }
    Ok(value)
}

fn check_point(p: Vec2, what: &'static str) -> Result<Vec2, Refused> {
    check_number(p.x, what)?;
    check_number(p.y, what)?;
    Ok(p)
}

/// A cruise speed: positive and finite; above the limit it is clamped (by the motion).
fn check_speed(speed: Option<f64>, max: f64) -> Result<f64, Refused> {
    match speed {
        None => Ok(max),
        Some(s) if s.is_finite() && s > 0.0 => Ok(s.min(max)),
        Some(value) => Err(Refused::BadSpeed { value }),
    }
}

/// What a pose is checked against: itself (the guard) and the world.
struct Checks<'a> {
    guard: &'a mut Guard,
    world: &'a World,
    quanta: &'a [f64],
}

/// What one resolver attempt gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    /// On target, converged, inside the limits, finite and clear of itself: may be sent.
    Sendable,
    /// Out of reach, not converged, outside the limits or not finite.
    Refused,
    /// Fine but for two links in contact.
    Collides,
    /// Fine but for a link that would lose its clearance from an obstacle.
    Blocked(Blocked),
    /// The resolver found no clear pose on target: the body is caught on an obstacle.
    Caught(Blocked),
}

/// One resolver attempt at `target` from `theta`, the answer in `out`. Returns whether it may
/// be sent and the iterations spent.
fn attempt(
    resolver: &mut dyn Resolver,
    chain: &Chain,
    check: &mut Checks,
    theta: &[f64],
    target: Vec2,
    out: &mut [f64],
) -> (Verdict, usize) {
    if !(target.x.is_finite() && target.y.is_finite()) {
        return (Verdict::Refused, 0);
    }
    let outcome = resolver.solve(chain, theta, target, out);
    let v = if !(out.iter().all(|t| t.is_finite()) && verdict(chain, out, outcome).is_ok()) {
        // A solve that failed with the body caught on an obstacle is held by it.
        match check.world.clearance(&check.guard.now) {
            Some(p) if resolver.held_by_obstacle() => Verdict::Caught(Blocked {
                link: p.link,
                obstacle: p.obstacle,
            }),
            _ => Verdict::Refused,
        }
    } else if check.guard.contact(chain, out).is_some() {
        Verdict::Collides
    } else if let Some(b) = check.guard.obstacle(chain, check.world, check.quanta, out) {
        Verdict::Blocked(b)
    } else {
        Verdict::Sendable
    };
    (v, outcome.iterations)
}

fn max_step(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

impl Controller {
    /// A controller holding the measured pose `theta` (the first goals are it), with `home` as
    /// the home pose. Refuses limits that are not positive and finite, and poses of the wrong
    /// length, non-finite or outside the joint limits, and a home pose that self-intersects
    /// ([`Refused::SelfCollision`]). The measured pose may self-intersect (a real arm's links
    /// have width, the model's do not): the pairs of links in contact in it are then free to
    /// move apart, and no other pair may touch.
    pub fn new(
        chain: Chain,
        limits: Limits,
        strategy: Strategy,
        home: Vec<f64>,
        theta: &[f64],
    ) -> Result<Self, Refused> {
        for (what, value) in [
            ("max_tip_speed_m_s", limits.max_tip_speed_m_s),
            ("max_tip_accel_m_s2", limits.max_tip_accel_m_s2),
            ("max_joint_speed_rad_s", limits.max_joint_speed_rad_s),
            ("deadman_s", limits.deadman_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(Refused::BadLimit { what, value });
            }
        }
        check_pose(&chain, &home, "home joint angle")?;
        check_clear(&chain, &home)?;
        check_pose(&chain, theta, "measured joint angle")?;
        let n = chain.len();
        let guard = Guard::new(&chain, theta);
        let tip = chain.tip(theta);
        let motion = Motion::new(limits.motion(), chain.limits(), tip, theta);
        let mut c = Self {
            chain,
            limits,
            strategy,
            overall: Overall::new(OverallOptions::default()),
            sequential: Sequential::default(),
            home,
            motion,
            theta: theta.to_vec(),
            tip,
            cand: vec![0.0; n],
            trial: vec![0.0; n],
            guard,
            world: World::default(),
            quanta: Vec::new(),
            rounding_m: 0.0,
            plan: World::default(),
            anchor: None,
            reach: None,
        };
        // Size both resolvers' scratch now, so that even the first tick allocates nothing.
        let (theta, trial) = (c.theta.clone(), &mut c.trial);
        c.overall.solve(&c.chain, &theta, tip, trial);
        c.sequential.solve(&c.chain, &theta, tip, trial);
        c.overall.reset();
        Ok(c)
    }

    /// Replaces the active command. On an error nothing changes.
    ///
    /// A `GotoJoints` target must be a pose inside the limits whose links stay clear of each
    /// other; one that self-intersects is refused with [`Refused::SelfCollision`] (it could
    /// never arrive). Its way there may still be blocked by a pose in between that would
    /// touch: the move then stops short and ends [`Finish::Saturated`].
    ///
    /// A `Reach` is planned here, before this returns ([`crate::reach`]: tens to hundreds of
    /// milliseconds among a few obstacles); [`Controller::command_within`] hands it back
    /// instead, to be planned elsewhere.
    pub fn command(&mut self, cmd: Command) -> Result<(), Refused> {
        match self.command_within(cmd, MAX_ROUTE_WORK)? {
            Accepted::Now => Ok(()),
            // The whole budget was given: a route over it is refused, never handed back.
            Accepted::Plan(PlanRequest::Routes(r)) => Err(Refused::RouteTooLong {
                what: r.what,
                x: r.points.last().map_or(f64::NAN, |p| p.x),
                y: r.points.last().map_or(f64::NAN, |p| p.y),
                limit: MAX_ROUTE_WORK,
            }),
            // Planned here, in the caller's time (the daemon plans it beside its loop).
            Accepted::Plan(PlanRequest::Reach(job)) => {
                let target = job.target;
                match plan(&PlanRequest::Reach(job), 0)? {
                    Planned::Way(way) => self.start_way(target, way),
                    Planned::Routes(_) => Ok(()),
                }
            }
        }
    }

    /// [`Controller::command`], spending at most `route_work` on the routes of a `goto` or
    /// `path` among obstacles (checks of a segment against an edge or a circle). When they need
    /// more (and less than [`MAX_ROUTE_WORK`]), nothing changes and the command comes back as
    /// [`Accepted::Plan`]: its routes planned elsewhere with [`plan_route`], then started with
    /// [`Controller::start_route`], so that the control loop never plans longer than it can
    /// spare in a tick.
    pub fn command_within(&mut self, cmd: Command, route_work: u64) -> Result<Accepted, Refused> {
        let max_speed = self.limits.max_tip_speed_m_s;
        let among = !self.world.obstacles().is_empty();
        match cmd {
            Command::Goto { target, speed } => {
                let target = check_point(target, "target")?;
                let speed = check_speed(speed, max_speed)?;
                if among {
                    return self.route(vec![target], "target", speed, route_work);
                } else {
                    self.motion.goto(target, speed);
                }
            }
            Command::Path { points, speed } => {
                if points.is_empty() {
                    return Err(Refused::EmptyPath);
                }
                for &p in &points {
                    check_point(p, "path point")?;
                }
                let speed = check_speed(speed, max_speed)?;
                if among {
                    return self.route(points, "path point", speed, route_work);
                } else {
                    self.motion.path(points, speed);
                }
            }
            Command::Velocity { v } => {
                let v = check_point(v, "velocity")?;
                self.motion.velocity(v);
            }
            Command::Jog { joint, rad_s } => {
                if joint >= self.chain.len() {
                    return Err(Refused::NoSuchJoint {
                        joint,
                        joints: self.chain.len(),
                    });
                }
                let rate = check_number(rad_s, "jog rate")?;
                self.motion.jog(joint, rate);
            }
            Command::GotoJoints { theta } => {
                check_pose(&self.chain, &theta, "joint angle")?;
                check_clear(&self.chain, &theta)?;
                self.check_joint_way(&theta)?;
                self.motion.joints(&theta);
            }
            Command::Home => {
                self.check_joint_way(&self.home)?;
                self.motion.joints(&self.home);
            }
            Command::Reach { target } => {
                let target = check_point(target, "target")?;
                return Ok(Accepted::Plan(self.reach_job(target)));
            }
            Command::Stop => self.motion.stop(),
        }
        self.anchor = None;
        self.reach = None;
        Ok(Accepted::Now)
    }

    /// Among obstacles: the tip's route through `points` from where it is ([`plan_route`]),
    /// started at once when it takes at most `work`, else handed back to be planned elsewhere.
    fn route(
        &mut self,
        points: Vec<Vec2>,
        what: &'static str,
        speed: f64,
        work: u64,
    ) -> Result<Accepted, Refused> {
        let request = RouteRequest {
            from: self.tip,
            trailing: self.trailing(),
            points,
            what,
            speed,
            world: self.plan.clone(),
            rounding_m: self.rounding_m,
        };
        match plan_route(&request, work) {
            Ok(route) => {
                self.motion.route(route.way, route.rest, speed);
                self.anchor = None;
                self.reach = None;
                Ok(Accepted::Now)
            }
            Err(Refused::RouteTooLong { .. }) if work < MAX_ROUTE_WORK => {
                Ok(Accepted::Plan(PlanRequest::Routes(request)))
            }
            Err(r) => Err(r),
        }
    }

    /// Starts a route planned elsewhere for `request` (see [`Controller::command_within`]),
    /// as the command would have started it. Refused with [`Replan`], nothing changed, when the
    /// route no longer fits: the tip has moved from where it was planned, or the world planned
    /// in (obstacles, clearance) has changed.
    pub fn start_route(
        &mut self,
        request: &RouteRequest,
        route: PlannedRoute,
    ) -> Result<(), Replan> {
        if self.tip != request.from || self.plan != request.world {
            return Err(Replan);
        }
        self.motion.route(route.way, route.rest, request.speed);
        self.anchor = None;
        self.reach = None;
        Ok(())
    }

    /// Starts what was planned elsewhere for `request` ([`plan`]), as the command would have
    /// started it: a route as [`Controller::start_route`]; a `reach`'s way from its first leg
    /// (each next leg when the one before arrives, its straight way checked against the world
    /// then in force). Refused with [`NotStarted::Replan`], nothing changed, when the plan no
    /// longer fits (the tip or the pose has moved, or the world has changed); with
    /// [`NotStarted::Refused`] when the first leg's way is not clear after all.
    pub fn start_planned(
        &mut self,
        request: &PlanRequest,
        planned: Planned,
    ) -> Result<(), NotStarted> {
        match (request, planned) {
            (PlanRequest::Routes(r), Planned::Routes(route)) => self
                .start_route(r, route)
                .map_err(|Replan| NotStarted::Replan),
            (PlanRequest::Reach(job), Planned::Way(way)) => {
                if !self.fits(request) {
                    return Err(NotStarted::Replan);
                }
                self.start_way(job.target, way).map_err(NotStarted::Refused)
            }
            _ => Err(NotStarted::Replan),
        }
    }

    /// Starts a `reach`'s way planned from the commanded pose: its first leg now, the others
    /// as each arrives.
    fn start_way(&mut self, target: Vec2, way: Way) -> Result<(), Refused> {
        let mut legs: VecDeque<Vec<f64>> = way.legs.into();
        let Some(first) = legs.pop_front() else {
            return Ok(());
        };
        self.check_joint_way(&first)?;
        self.motion.joints(&first);
        self.anchor = None;
        self.reach = Some(Reaching { target, legs });
        Ok(())
    }

    /// Whether `request` was made from where the arm is now (the tip for routes, the pose for
    /// a `reach`'s way) and in the world in force: what is planned for it, or refused, holds
    /// now; otherwise it is to be planned again ([`Controller::replan_request`]).
    pub fn fits(&self, request: &PlanRequest) -> bool {
        match request {
            PlanRequest::Routes(r) => self.tip == r.from && self.plan == r.world,
            PlanRequest::Reach(job) => self.theta == job.from && self.world == job.world,
        }
    }

    /// The same request from where the arm is now, in the world in force: what
    /// [`Controller::start_planned`] takes after it asked for a replan.
    pub fn replan_request(&self, request: &PlanRequest) -> PlanRequest {
        match request {
            PlanRequest::Routes(r) => PlanRequest::Routes(self.replan(r)),
            PlanRequest::Reach(job) => self.reach_job(job.target),
        }
    }

    /// A `reach` to `target` from the commanded pose, in the world in force.
    fn reach_job(&self, target: Vec2) -> PlanRequest {
        PlanRequest::Reach(Box::new(ReachJob {
            chain: self.chain.clone(),
            world: self.world.clone(),
            from: self.theta.clone(),
            target,
            quanta: self.quanta.clone(),
        }))
    }

    /// The direction from the commanded tip back along the last link: how the body trails.
    fn trailing(&self) -> Vec2 {
        let phi = self.chain.heading() + self.theta.iter().sum::<f64>();
        -Vec2::new(phi.cos(), phi.sin())
    }

    /// A route request for the same points from where the tip is now, in the world in force:
    /// what [`Controller::start_route`] takes after it asked for a [`Replan`].
    pub fn replan(&self, request: &RouteRequest) -> RouteRequest {
        RouteRequest {
            from: self.tip,
            trailing: self.trailing(),
            points: request.points.clone(),
            what: request.what,
            speed: request.speed,
            world: self.plan.clone(),
            rounding_m: self.rounding_m,
        }
    }

    /// Among obstacles: refuses a joint move whose straight way in joint space passes a pose
    /// that would lose clearance (checked every [`JOINT_WAY_STEP_M`] of the arm's motion).
    fn check_joint_way(&self, goal: &[f64]) -> Result<(), Refused> {
        if self.world.obstacles().is_empty() || goal.len() != self.theta.len() {
            return Ok(());
        }
        // No point moves farther than the sum of each joint's turn times what it carries.
        let sweep = self.chain.sweep(&self.theta, goal);
        let steps = ((sweep / JOINT_WAY_STEP_M).ceil() as usize).clamp(1, MAX_JOINT_WAY_SAMPLES);
        let mut pose = self.theta.clone();
        let mut points = self.chain.points(&pose);
        // Where the way first loses clearance, and its deepest pose: the whole way is read, so
        // that a way which only grazes the clearance is told from one through an obstacle.
        let mut from = None;
        let mut deepest: Option<(Pair, f64)> = None;
        // Samples within the free sweep of one looked at keep their floors (no point moves
        // farther than its share of the sweep), so they are passed over: far from every
        // obstacle a long way costs a few looks, and what is found is what every sample finds.
        let spacing = sweep / steps as f64;
        let mut k = 0;
        while k <= steps {
            let f = k as f64 / steps as f64;
            for ((x, &a), &b) in pose.iter_mut().zip(&self.theta).zip(goal) {
                *x = a + f * (b - a);
            }
            self.chain.points_into(&pose, &mut points);
            let left = (steps - k) as f64 * spacing;
            let free = self.world.free_sweep(&points, &self.guard.floors, left) - SWEEP_SLACK_M;
            if free > 0.0 {
                k += 1 + (free / spacing) as usize;
                continue;
            }
            let below = (k > 0)
                .then(|| self.world.deepest_below_floors(&points, &self.guard.floors))
                .flatten();
            if let Some(p) = below {
                from.get_or_insert(f);
                if deepest
                    .as_ref()
                    .is_none_or(|(d, _)| p.clearance_m < d.clearance_m)
                {
                    deepest = Some((p, f));
                }
            }
            k += 1;
        }
        if let (Some(from), Some((p, f))) = (from, deepest) {
            let m = self.world.obstacles().len();
            let keep_m = self.world.clearance_m();
            let floor_m = self
                .guard
                .floors
                .get((p.link - 1) * m + p.obstacle)
                .map_or(keep_m, |&f| f.min(keep_m));
            return Err(Refused::NotClearOnTheWay {
                link: p.link,
                obstacle: p.id(&self.world).to_string(),
                fraction: f,
                from_fraction: from,
                clearance_m: p.clearance_m,
                keep_m,
                floor_m,
            });
        }
        // Each tick's check holds the goal as the servos receive it to the floors as well
        // (from a clear pose): a goal clear only before rounding would end blocked short of it.
        if self.guard.clear && !self.quanta.is_empty() {
            round_to(goal, &self.quanta, &mut pose);
            self.chain.points_into(&pose, &mut points);
            if let Some(p) = self.world.below_floors(&points, &self.guard.floors) {
                return Err(Refused::GoalNotClearAsSent {
                    link: p.link,
                    obstacle: p.id(&self.world).to_string(),
                    clearance_m: p.clearance_m,
                    keep_m: self.world.clearance_m(),
                });
            }
        }
        Ok(())
    }

    /// Switches the strategy live: the next tick resolves with it from the current commanded
    /// pose, so nothing jumps. Switching to overall forgets its old warm-start multiplier.
    pub fn set_strategy(&mut self, s: Strategy) {
        if s != self.strategy && s == Strategy::Overall {
            self.overall.reset();
        }
        self.strategy = s;
    }

    /// The active strategy.
    pub fn strategy(&self) -> Strategy {
        self.strategy
    }

    /// Emergency stop: drops the command and zeroes all motion at once; the goals stay where
    /// they are.
    pub fn freeze(&mut self) {
        self.motion.hold_at(self.tip, &self.theta);
        self.reach = None;
    }

    /// Goal := the measured pose `theta` (after a reset or a recovery): motion at rest, holding.
    /// The only way goals jump. Refused (nothing changed) for a pose of the wrong length,
    /// non-finite or outside the limits. A pose that self-intersects is taken (see
    /// [`Controller::new`]).
    pub fn reseed(&mut self, theta: &[f64]) -> Result<(), Refused> {
        check_pose(&self.chain, theta, "measured joint angle")?;
        self.theta.copy_from_slice(theta);
        self.tip = self
            .guard
            .anchor(&self.chain, &self.world, &self.quanta, theta);
        self.overall.reset();
        self.motion.hold_at(self.tip, &self.theta);
        self.reach = None;
        Ok(())
    }

    /// The commanded pose: this tick's goals, rad.
    pub fn theta(&self) -> &[f64] {
        &self.theta
    }

    /// Tip of the commanded pose, m.
    pub fn tip(&self) -> Vec2 {
        self.tip
    }

    /// What the arm is doing.
    pub fn activity(&self) -> Activity {
        self.motion.activity()
    }

    /// The final target of a goto or path (a path's last point), or of the reach under way,
    /// else `None`.
    pub fn target(&self) -> Option<Vec2> {
        self.motion
            .target()
            .or_else(|| self.reach.as_ref().map(|r| r.target))
    }

    /// The chain.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The limits.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The home pose, rad.
    pub fn home(&self) -> &[f64] {
        &self.home
    }

    /// The obstacles the arm keeps clear of.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Replaces the world, in force from the next tick. Returns what is wrong when the
    /// commanded pose is not clear of it: the arm then holds, and moves only where no link's
    /// clearance shrinks, until it is clear again.
    ///
    /// A command under way keeps its route, planned in the old world; every tick is still
    /// checked against the new one. When the pose is not clear the command is stopped (it
    /// decelerates as far as no link's clearance shrinks).
    pub fn set_world(&mut self, world: World) -> Option<NotClear> {
        self.world = world;
        self.plan = self.planned_world();
        let solver = (!self.plan.obstacles().is_empty()).then(|| self.plan.clone());
        self.overall.set_world(solver);
        self.guard
            .anchor(&self.chain, &self.world, &self.quanta, &self.theta);
        let not_clear = self.not_clear();
        if not_clear.is_some() && self.motion.activity() == Activity::Moving {
            self.motion.stop();
        }
        not_clear
    }

    /// Each joint's resolution, rad (a servo's tick; 0 for exact), one per joint: the goal
    /// pose rounded to it (what reaches the servos) must be clear as well. Rounding turns
    /// joint `i` by at most half its resolution, which moves a point by at most that times the
    /// length joint `i` carries; the sum over the joints (4.8 mm for twelve 0.08 m links of
    /// 4096-tick servos) is added to the clearance the controller plans with: the overall
    /// solver keeps it, the tip's routes and a sliding velocity go round it, so that every
    /// goal as sent keeps the world's clearance.
    pub fn set_joint_resolution(&mut self, quanta: &[f64]) -> Result<(), Refused> {
        if quanta.len() != self.chain.len() || !quanta.iter().all(|q| q.is_finite() && *q >= 0.0) {
            return Err(Refused::BadResolution);
        }
        self.rounding_m = self.chain.rounding_m(quanta);
        self.quanta = if quanta.iter().all(|&q| q == 0.0) {
            Vec::new()
        } else {
            quanta.to_vec()
        };
        self.plan = self.planned_world();
        let solver = (!self.plan.obstacles().is_empty()).then(|| self.plan.clone());
        self.overall.set_world(solver);
        // Whether the goal as sent is clear, at the new resolution.
        self.guard
            .commit(&self.chain, &self.world, &self.quanta, &self.theta);
        Ok(())
    }

    /// The world planned in: the clearance raised by what rounding to the joints'
    /// resolutions can take away.
    fn planned_world(&self) -> World {
        if self.rounding_m == 0.0 || self.world.obstacles().is_empty() {
            return self.world.clone();
        }
        self.world
            .with_clearance(self.world.clearance_m() + self.rounding_m)
            .unwrap_or_else(|_| self.world.clone())
    }

    /// The clearance of the commanded pose, m (from its points, kept by the controller);
    /// `None` when the world has no obstacles. Allocation-free.
    pub fn min_clearance(&self) -> Option<f64> {
        self.guard.least_m
    }

    /// The link and obstacle of least clearance when the commanded pose is not clear, or else
    /// when its goal as sent (rounded to the joints' resolutions) is not.
    pub fn not_clear(&self) -> Option<NotClear> {
        if self.guard.clear {
            return None;
        }
        let keep_m = self.world.clearance_m();
        let p = self.world.clearance(&self.guard.now)?;
        let (p, as_sent) = if p.clearance_m < keep_m {
            (p, false)
        } else {
            (self.world.clearance(&self.guard.sent)?, true)
        };
        Some(NotClear {
            link: p.link,
            obstacle: p.id(&self.world).to_string(),
            clearance_m: p.clearance_m,
            keep_m,
            as_sent,
        })
    }

    /// Whether the commanded pose, and its goal as sent (rounded to the joints' resolutions),
    /// keep the world's clearance on every link: what [`Controller::not_clear`] says of it.
    pub fn is_clear(&self) -> bool {
        self.guard.clear
    }

    /// The first pair of links of the commanded pose in contact, when there is one (a measured
    /// pose taken by [`Controller::new`] or [`Controller::reseed`]): the arm is tangled, and
    /// moves only as long as that gets no worse (see the module doc). Worth a warning.
    pub fn self_contact(&self) -> Option<SelfContact> {
        let p = &self.guard.now;
        let n = self.chain.len();
        // A crossing pair first: it is what a user must untangle.
        let mut pairs = (0..n).flat_map(|a| (a + 2..n).map(move |b| (a, b)));
        if let Some((a, b)) = pairs.find(|&(a, b)| Chain::links_cross(p, a, b)) {
            return Some(SelfContact {
                a,
                b,
                crossing: true,
            });
        }
        let (a, b) = Chain::self_intersects(p)?;
        Some(SelfContact {
            a,
            b,
            crossing: false,
        })
    }

    /// One tick of `dt` seconds: steps the motion, resolves, limits the joint speeds and
    /// commits the new goals (see the module doc).
    pub fn tick(&mut self, dt: f64) -> Tick {
        let mut t = Tick {
            tip_ref: self.tip,
            tip: self.tip,
            saturated: false,
            self_collision: false,
            slowed: false,
            clamped: false,
            blocked: None,
            min_clearance_m: None,
            finished: None,
            peak_joint_speed_rad_s: 0.0,
            m3_rad2: 0.0,
            iterations: 0,
        };
        if !(dt > 0.0 && dt.is_finite()) {
            t.min_clearance_m = self.min_clearance();
            return t;
        }
        let dt = dt.min(MAX_DT_S);
        let from = self.tip;
        // The point the step reached, as the resolver was asked for it (exact on the line).
        let mut reached = from;
        let mut pushed = false;
        let mut tip_space = false;
        match self.motion.step(dt) {
            Reference::Hold => self.cand.copy_from_slice(&self.theta),
            Reference::Tip(r) => {
                tip_space = true;
                // A tip velocity (or its stop) slides along an obstacle: the part of its step
                // into it is removed.
                let r = match self.motion.target() {
                    None if !self.world.obstacles().is_empty() => {
                        let g = self.plan.route_radius_m() + self.plan.route_margin_m();
                        match self.plan.push_out(r, g) {
                            Some((q, _)) => {
                                pushed = true;
                                // The push moves the tip no faster than its limit either.
                                let step = q - from;
                                let most = self.limits.max_tip_speed_m_s * dt;
                                let n = step.norm();
                                if n > most {
                                    from + step * (most / n)
                                } else {
                                    q
                                }
                            }
                            None => r,
                        }
                    }
                    _ => r,
                };
                t.tip_ref = r;
                if self.strategy == Strategy::Overall {
                    // From a pose not clear, the links need only come no closer.
                    let floors = self.guard.solve_floors(&self.plan);
                    self.overall.set_floors(floors);
                }
                reached = self.resolve_step(from, r, dt, &mut t);
            }
            Reference::Joints => {
                self.cand.copy_from_slice(self.motion.joint_reference());
                t.tip_ref = self.chain.tip(&self.cand);
                reached = t.tip_ref;
            }
        }
        t.clamped = self.clamp_joint_steps(dt);
        if t.clamped && tip_space {
            self.keep_tip_speed(from, dt, false);
        }
        let (cut, cut_by) = self.keep_clear();
        if tip_space && (cut || cut_by.is_some()) {
            // A step cut back along its joint path is no longer the resolver's either.
            self.keep_tip_speed(from, dt, true);
        }
        if cut {
            t.saturated = true;
            t.self_collision = true;
        }
        if cut_by.is_some() {
            t.blocked = cut_by;
        }
        // Commit.
        let mut peak: f64 = 0.0;
        let mut m3 = 0.0;
        for (goal, &c) in self.theta.iter_mut().zip(&self.cand) {
            let d = c - *goal;
            peak = peak.max(d.abs());
            m3 += d * d;
            *goal = c;
        }
        self.tip = self
            .guard
            .commit(&self.chain, &self.world, &self.quanta, &self.theta);
        if t.clamped || cut || cut_by.is_some() {
            reached = self.tip;
        }
        t.tip = self.tip;
        t.min_clearance_m = self.min_clearance();
        t.peak_joint_speed_rad_s = peak / dt;
        t.m3_rad2 = m3;
        let held = t.blocked.is_some();
        t.finished = self.motion.follow(Achieved {
            tip: reached,
            theta: &self.theta,
            dt,
            exact: !(t.saturated || t.slowed || t.clamped || held || pushed),
            saturated: t.saturated || held,
        });
        if let (Some(Finish::Saturated), Some(b)) = (t.finished, t.blocked) {
            t.finished = Some(Finish::Blocked {
                link: b.link,
                obstacle: b.obstacle,
            });
        }
        self.next_leg(&mut t);
        self.headway(dt, &mut t);
        t
    }

    /// A `reach` whose leg arrived goes on with the next, its straight way checked against
    /// the world in force; one not clear (the world changed meanwhile) ends the move
    /// [`Finish::Blocked`], naming the link and obstacle of the way's deepest pose. Any other ending drops
    /// the legs left.
    fn next_leg(&mut self, t: &mut Tick) {
        match t.finished {
            Some(Finish::Arrived) => {}
            Some(_) => {
                self.reach = None;
                return;
            }
            None => return,
        }
        let Some(next) = self.reach.as_mut().and_then(|r| r.legs.pop_front()) else {
            // The last leg arrived: the reach is done.
            self.reach = None;
            return;
        };
        match self.check_joint_way(&next) {
            Ok(()) => {
                self.motion.joints(&next);
                t.finished = None;
            }
            Err(refused) => {
                self.reach = None;
                // What held the way back, else the pair of least clearance now.
                let held = match &refused {
                    Refused::NotClearOnTheWay { link, obstacle, .. }
                    | Refused::GoalNotClearAsSent { link, obstacle, .. } => {
                        self.world.find(obstacle).map(|(k, _)| (*link, k))
                    }
                    _ => None,
                };
                let (link, obstacle) = held.unwrap_or_else(|| {
                    self.world
                        .clearance(&self.guard.now)
                        .map_or((self.chain.len(), 0), |p| (p.link, p.obstacle))
                });
                t.finished = Some(Finish::Blocked { link, obstacle });
            }
        }
    }

    /// Among obstacles, a goto or path whose tip advances less than [`HEADWAY_M`] (or half what
    /// its cruise speed covers, if less) in [`HEADWAY_S`] ends [`Finish::Blocked`], naming the
    /// link that held it back or else the pair of least clearance.
    fn headway(&mut self, dt: f64, t: &mut Tick) {
        let speed = match self.motion.cruise_speed() {
            Some(s) if t.finished.is_none() && !self.world.obstacles().is_empty() => s,
            _ => {
                self.anchor = None;
                return;
            }
        };
        let need = HEADWAY_M.min(0.5 * speed * HEADWAY_S);
        let Some((at, since)) = self.anchor else {
            self.anchor = Some((self.tip, 0.0));
            return;
        };
        if (self.tip - at).norm() >= need {
            self.anchor = Some((self.tip, 0.0));
        } else if since + dt < HEADWAY_S {
            self.anchor = Some((at, since + dt));
        } else {
            let nearest = self.world.clearance(&self.guard.now);
            let (link, obstacle) = match (t.blocked, nearest) {
                (Some(b), _) => (b.link, b.obstacle),
                (None, Some(p)) => (p.link, p.obstacle),
                (None, None) => (self.chain.len(), 0),
            };
            self.motion.hold_at(self.tip, &self.theta);
            t.finished = Some(Finish::Blocked { link, obstacle });
            self.anchor = None;
        }
    }

    /// Resolves the tip step `from -> r` into `self.cand`: bisected when out of reach, shortened
    /// when too fast for the joints. Returns the point reached.
    fn resolve_step(&mut self, from: Vec2, r: Vec2, dt: f64, t: &mut Tick) -> Vec2 {
        let Self {
            chain,
            strategy,
            overall,
            sequential,
            theta,
            cand,
            trial,
            limits,
            guard,
            world,
            quanta,
            ..
        } = self;
        let mut check = Checks {
            guard,
            world,
            quanta,
        };
        let resolver: &mut dyn Resolver = match strategy {
            Strategy::Overall => overall,
            Strategy::Sequential => sequential,
        };
        let (v, its) = attempt(resolver, chain, &mut check, theta, r, trial);
        t.iterations += its;
        t.self_collision |= v == Verdict::Collides;
        let mut reached = r;
        if let Verdict::Caught(b) = v {
            // A failed solve among obstacles is the dearest there is, and one at a shorter step
            // would fail the same way: the arm holds this tick.
            t.blocked = Some(b);
            cand.copy_from_slice(theta);
            return from;
        }
        if v == Verdict::Sendable {
            cand.copy_from_slice(trial);
        } else {
            // Held back by an obstacle alone is `blocked`; anything else is `saturated`.
            match v {
                Verdict::Blocked(b) => t.blocked = Some(b),
                _ => t.saturated = true,
            }
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..BISECTION_ROUNDS {
                let mid = 0.5 * (lo + hi);
                let target = from + (r - from) * mid;
                let (v, its) = attempt(resolver, chain, &mut check, theta, target, trial);
                t.iterations += its;
                if v == Verdict::Collides {
                    // A step held back by a contact of links is `saturated` whatever held the
                    // whole step back.
                    t.self_collision = true;
                    t.saturated = true;
                }
                if let (Verdict::Blocked(b) | Verdict::Caught(b), None) = (v, t.blocked) {
                    t.blocked = Some(b);
                }
                if v == Verdict::Sendable {
                    lo = mid;
                    cand.copy_from_slice(trial);
                } else {
                    hi = mid;
                }
            }
            if lo > 0.0 {
                reached = from + (r - from) * lo;
            } else {
                cand.copy_from_slice(theta);
                reached = from;
            }
        }
        let bound = limits.max_joint_speed_rad_s * dt;
        for _ in 0..SLOWDOWN_ROUNDS {
            let m = max_step(cand, theta);
            if m <= bound {
                break;
            }
            t.slowed = true;
            let shorter = from + (reached - from) * (SHORTEN_MARGIN * bound / m);
            let (v, its) = attempt(resolver, chain, &mut check, theta, shorter, trial);
            t.iterations += its;
            if v != Verdict::Sendable {
                break;
            }
            cand.copy_from_slice(trial);
            reached = shorter;
        }
        reached
    }

    /// The final guarantee: every goal within `max_joint_speed * dt` of the last one, finite and
    /// inside its limits. Returns whether a step had to be shortened.
    fn clamp_joint_steps(&mut self, dt: f64) -> bool {
        let bound = self.limits.max_joint_speed_rad_s * dt;
        let mut clamped = false;
        for ((c, &t), lim) in self
            .cand
            .iter_mut()
            .zip(&self.theta)
            .zip(self.chain.limits())
        {
            let d = *c - t;
            if !d.is_finite() {
                *c = t;
                clamped = true;
            } else if d.abs() > bound {
                *c = t + bound.copysign(d);
                // Round-off of `v dt` (a joint reference at the speed limit) is not a clamp.
                clamped |= d.abs() > bound * (1.0 + CLAMP_ROUNDOFF);
            }
            if let Some(l) = lim {
                *c = l.clamp(*c);
            }
        }
        clamped
    }

    /// A tip motion's step clamped for the joints' speed, or cut back along its joint path to
    /// keep clear, is no longer the resolver's (its tip is off the reference: a body leaving
    /// an obstacle it was put into can ask every joint to turn its fastest, and a long step's
    /// joint path can swing the tip far off the line of its ends), and may move the tip faster
    /// than its limit: it is then moved back along the joint step `theta -> cand` to the
    /// farthest fraction found, by [`BISECTION_ROUNDS`] rounds of bisection, to keep the tip
    /// within `max_tip_speed * dt` of `from`, the last goal's tip; with `clear`, a fraction
    /// whose pose keeps clear as well ([`Controller::trial_clear`]).
    fn keep_tip_speed(&mut self, from: Vec2, dt: f64, clear: bool) {
        let most = self.limits.max_tip_speed_m_s * dt * (1.0 + CLAMP_ROUNDOFF);
        if (self.chain.tip(&self.cand) - from).norm() <= most {
            return;
        }
        self.cut_back(0.0, 1.0, |c| {
            (c.chain.tip(&c.trial) - from).norm() <= most && (!clear || c.trial_clear())
        });
    }

    /// Moves `cand` back along the joint step `theta -> cand` to the farthest fraction between
    /// `lo` (whose pose keeps) and `hi` (whose pose does not) found by [`BISECTION_ROUNDS`]
    /// rounds of bisection to keep (`keeps` of the pose in `trial`); the last goal at worst. A
    /// fraction of the step keeps within the joint-speed bound and the limits.
    fn cut_back(&mut self, mut lo: f64, mut hi: f64, mut keeps: impl FnMut(&mut Self) -> bool) {
        for _ in 0..BISECTION_ROUNDS {
            let mid = 0.5 * (lo + hi);
            self.trial_at(mid);
            if keeps(self) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        for ((c, &t), lim) in self
            .cand
            .iter_mut()
            .zip(&self.theta)
            .zip(self.chain.limits())
        {
            *c = if lo > 0.0 { t + lo * (*c - t) } else { t };
            if let Some(l) = lim {
                *c = l.clamp(*c);
            }
        }
    }

    /// `trial` := the pose a fraction `f` of the way from the last goal to the candidate (a
    /// straight line in joint space, as the servos take it).
    fn trial_at(&mut self, f: f64) {
        for ((x, &c), &t) in self.trial.iter_mut().zip(&self.cand).zip(&self.theta) {
            *x = t + f * (c - t);
        }
    }

    /// `trial` touches no link and keeps every floor against the world.
    fn trial_clear(&mut self) -> bool {
        self.guard.contact(&self.chain, &self.trial).is_none()
            && self
                .guard
                .obstacle(&self.chain, &self.world, &self.quanta, &self.trial)
                .is_none()
    }

    /// The last check: if the pose `cand` brings two links into contact, or a link below its
    /// floor near an obstacle, it is moved back along the joint step `theta -> cand` to the
    /// farthest fraction found clear by [`BISECTION_ROUNDS`] rounds of bisection (the
    /// commanded pose itself at worst). A fraction of the step keeps within the joint-speed
    /// bound and the limits. Returns whether it had to for a contact of links, and the link and
    /// obstacle when a link would have lost clearance.
    fn keep_clear(&mut self) -> (bool, Option<Blocked>) {
        let mut touches = self.guard.contact(&self.chain, &self.cand).is_some();
        let mut blocked = if touches {
            None
        } else {
            self.guard
                .obstacle(&self.chain, &self.world, &self.quanta, &self.cand)
        };
        let (mut lo, mut hi) = (0.0, 1.0);
        if !self.world.obstacles().is_empty() {
            // The servos pass every pose between the last goal and this one: the way there is
            // checked every [`JOINT_WAY_STEP_M`] of the arm's motion, so that no link passes
            // through an obstacle between two clear goals.
            let sweep = self.chain.sweep(&self.theta, &self.cand);
            let steps =
                ((sweep / JOINT_WAY_STEP_M).ceil() as usize).clamp(1, MAX_JOINT_WAY_SAMPLES);
            for k in 1..steps {
                let f = k as f64 / steps as f64;
                self.trial_at(f);
                // A pose between two goals need keep its floors only to within the samples'
                // spacing (a straight line in joint space may bow in by round-off against a
                // link sliding along an obstacle): enough that none passes through one.
                self.chain.points_into(&self.trial, &mut self.guard.scratch);
                let hit = self.world.below_floors_by(
                    &self.guard.scratch,
                    &self.guard.floors,
                    0.5 * JOINT_WAY_STEP_M,
                );
                if let Some(p) = hit {
                    (touches, blocked) = (
                        false,
                        Some(Blocked {
                            link: p.link,
                            obstacle: p.obstacle,
                        }),
                    );
                    hi = f;
                    // Bisect after the last sample before it that keeps its floors exactly.
                    for j in (1..k).rev() {
                        let g = j as f64 / steps as f64;
                        self.trial_at(g);
                        if self.trial_clear() {
                            lo = g;
                            break;
                        }
                    }
                    break;
                }
            }
        }
        if !touches && blocked.is_none() {
            return (false, None);
        }
        self.cut_back(lo, hi, Self::trial_clear);
        (touches, blocked)
    }
}

#[cfg(test)]
mod tests;
