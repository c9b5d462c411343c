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
//!    step lie inside its limits, so the clamped pose does too.
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
//! 5. The motion **follows** what was achieved: a shortened step moves the reference back onto
//!    the arm, with the velocity the arm really had, so it never runs ahead. A goto, path or
//!    joint move that makes no progress for [`crate::motion::STALL_TICKS`] saturated ticks
//!    ends with one [`Finish::Saturated`].
//!
//! A `GotoJoints` whose target pose itself self-intersects is refused
//! ([`Refused::SelfCollision`]): it could never arrive. So is a home pose that does, when the
//! controller is built.
//!
//! Goals jump only through [`Controller::reseed`] (goal := the measured pose, which moves no
//! servo). Once warm, `tick` allocates nothing, and it never panics: a bad `dt` (zero, negative,
//! non-finite) advances nothing, `dt` above [`MAX_DT_S`] counts as [`MAX_DT_S`], and commands
//! with non-finite or huge numbers are refused by [`Controller::command`].

use crate::chain::{Chain, Vec2, MAX_MAGNITUDE, SELF_CLEARANCE_M};
use crate::motion::{joint_accel, Achieved, Motion, MotionLimits, Reference};
use crate::resolve::overall::{Overall, OverallOptions};
use crate::resolve::sequential::Sequential;
use crate::resolve::{verdict, Resolver, Strategy};
use crate::world::World;

pub use crate::motion::{Activity, Finish, JOINT_ACCEL_TIME_S};

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
    /// Decelerate to rest at the acceleration limit, then hold.
    Stop,
}

/// Why a command (or a pose, or the limits) was refused. Carries the numbers; displays as a
/// sentence for a user (joints counted from 1).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Refused {
    /// A pose with a joint outside its limits.
    #[error("joint {j}: {value} rad is outside its limits [{lo}, {hi}]", j = .joint + 1)]
    OutsideLimits {
        /// Joint index, from 0.
        joint: usize,
        /// The angle asked for, rad.
        value: f64,
        /// Lower limit, rad.
        lo: f64,
        /// Upper limit, rad.
        hi: f64,
    },
    /// A joint index beyond the arm.
    #[error("joint {j} does not exist: the arm has {joints} joints", j = .joint + 1)]
    NoSuchJoint {
        /// Joint index asked for, from 0.
        joint: usize,
        /// Joints in the arm.
        joints: usize,
    },
    /// A pose with the wrong number of angles.
    #[error("{got} joint angles given for an arm of {expected} joints")]
    WrongLength {
        /// Angles given.
        got: usize,
        /// Joints in the arm.
        expected: usize,
    },
    /// A number that is NaN or infinite.
    #[error("the {what} is not a finite number")]
    NotFinite {
        /// What it was.
        what: &'static str,
    },
    /// A speed that is not a positive finite number.
    #[error("speed {value} m/s must be a positive, finite number")]
    BadSpeed {
        /// The speed given, m/s.
        value: f64,
    },
    /// A finite number too large to mean anything for an arm.
    #[error("the {what} {value} is larger in magnitude than {max}")]
    TooLarge {
        /// What it was.
        what: &'static str,
        /// The value given.
        value: f64,
        /// The largest magnitude accepted.
        max: f64,
    },
    /// A pose that brings two links within [`SELF_CLEARANCE_M`] of each other: the arm would
    /// fold onto itself.
    #[error("links {la} and {lb} of that pose cross or touch", la = .a + 1, lb = .b + 1)]
    SelfCollision {
        /// The first link of the pair, from 0 (link `i` is the one joint `i` turns).
        a: usize,
        /// The second link, from 0, `b > a`.
        b: usize,
    },
    /// A path without points.
    #[error("a path needs at least one point")]
    EmptyPath,
    /// A goto or path point where the tip can never be clear: inside an obstacle grown by the
    /// link radius and the clearance.
    #[error("the {what} ({x}, {y}) lies within {grown_m} m of obstacle \"{obstacle}\": the tip can never be clear there")]
    InsideObstacle {
        /// What it was ("target", "path point").
        what: &'static str,
        /// The point, m.
        x: f64,
        /// The point, m.
        y: f64,
        /// The obstacle's id.
        obstacle: String,
        /// `link_radius_m + clearance_m`, m.
        grown_m: f64,
    },
    /// A joint move whose straight way in joint space passes a pose that is not clear.
    #[error(
        "link {link} would come within {clearance_m:.4} m of obstacle \"{obstacle}\" \
         {percent:.0}% of the way there (the clearance to keep is {keep_m} m)",
        percent = .fraction * 100.0
    )]
    NotClearOnTheWay {
        /// The link, 1-based from the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
        /// How far along the move, 0..=1.
        fraction: f64,
        /// The clearance there, m.
        clearance_m: f64,
        /// The clearance to keep, m.
        keep_m: f64,
    },
    /// A limit that is not a positive finite number.
    #[error("the limit {what} = {value} must be a positive, finite number")]
    BadLimit {
        /// Which limit.
        what: &'static str,
        /// The value given.
        value: f64,
    },
}

/// Two links of the commanded pose in contact ([`Controller::self_contact`]). Displays as a
/// warning for a user (links counted from 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SelfContact {
    /// The first link of the pair, from 0.
    pub a: usize,
    /// The second link, from 0, `b > a`.
    pub b: usize,
    /// The two cross (rather than come within [`SELF_CLEARANCE_M`] of each other).
    pub crossing: bool,
}

impl std::fmt::Display for SelfContact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "links {} and {} of the arm's pose {}: until they are clear, the arm moves only \
             where that tangles it no further (`home`, or a `goto_joints` to a clear pose, \
             untangles it)",
            self.a + 1,
            self.b + 1,
            if self.crossing { "cross" } else { "touch" }
        )
    }
}

/// The commanded pose is not clear of an obstacle ([`Controller::set_world`] put one onto
/// the arm): until it is, only motion that reduces no link's clearance is carried out.
#[derive(Debug, Clone, PartialEq)]
pub struct NotClear {
    /// The link of least clearance, 1-based from the base.
    pub link: usize,
    /// The obstacle's id.
    pub obstacle: String,
    /// The link's clearance, m (negative: inside, by that depth).
    pub clearance_m: f64,
    /// The clearance to keep, m.
    pub keep_m: f64,
}

impl std::fmt::Display for NotClear {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "link {} is {:.4} m from obstacle \"{}\" (the clearance to keep is {} m): the arm \
             holds, and moves only where no link's clearance shrinks",
            self.link, self.clearance_m, self.obstacle, self.keep_m
        )
    }
}

/// A tick cut short to keep the clearance: the link held back and the obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
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
}

impl Guard {
    fn new(chain: &Chain, theta: &[f64]) -> Self {
        let n = chain.len();
        let mut g = Self {
            now: vec![Vec2::zeros(); n + 1],
            scratch: vec![Vec2::zeros(); n + 1],
            tangled: false,
        };
        g.commit(chain, theta);
        g
    }

    /// The commanded pose is now `theta`; returns its tip.
    fn commit(&mut self, chain: &Chain, theta: &[f64]) -> Vec2 {
        chain.points_into(theta, &mut self.now);
        self.tangled = Chain::self_intersects(&self.now).is_some();
        self.now[chain.len()]
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

/// What one resolver attempt gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    /// On target, converged, inside the limits, finite and clear of itself: may be sent.
    Sendable,
    /// Out of reach, not converged, outside the limits or not finite.
    Refused,
    /// Fine but for two links in contact.
    Collides,
}

/// One resolver attempt at `target` from `theta`, the answer in `out`. Returns whether it may
/// be sent and the iterations spent.
fn attempt(
    resolver: &mut dyn Resolver,
    chain: &Chain,
    guard: &mut Guard,
    theta: &[f64],
    target: Vec2,
    out: &mut [f64],
) -> (Verdict, usize) {
    if !(target.x.is_finite() && target.y.is_finite()) {
        return (Verdict::Refused, 0);
    }
    let outcome = resolver.solve(chain, theta, target, out);
    let v = if !(out.iter().all(|t| t.is_finite()) && verdict(chain, out, outcome).is_ok()) {
        Verdict::Refused
    } else if guard.contact(chain, out).is_some() {
        Verdict::Collides
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
    pub fn command(&mut self, cmd: Command) -> Result<(), Refused> {
        let max_speed = self.limits.max_tip_speed_m_s;
        match cmd {
            Command::Goto { target, speed } => {
                let target = check_point(target, "target")?;
                let speed = check_speed(speed, max_speed)?;
                self.motion.goto(target, speed);
            }
            Command::Path { points, speed } => {
                if points.is_empty() {
                    return Err(Refused::EmptyPath);
                }
                for &p in &points {
                    check_point(p, "path point")?;
                }
                let speed = check_speed(speed, max_speed)?;
                self.motion.path(points, speed);
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
                self.motion.joints(&theta);
            }
            Command::Home => self.motion.joints(&self.home),
            Command::Stop => self.motion.stop(),
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
    }

    /// Goal := the measured pose `theta` (after a reset or a recovery): motion at rest, holding.
    /// The only way goals jump. Refused (nothing changed) for a pose of the wrong length,
    /// non-finite or outside the limits. A pose that self-intersects is taken (see
    /// [`Controller::new`]).
    pub fn reseed(&mut self, theta: &[f64]) -> Result<(), Refused> {
        check_pose(&self.chain, theta, "measured joint angle")?;
        self.theta.copy_from_slice(theta);
        self.tip = self.guard.commit(&self.chain, theta);
        self.overall.reset();
        self.motion.hold_at(self.tip, &self.theta);
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

    /// The final target of a goto or path (a path's last point), else `None`.
    pub fn target(&self) -> Option<Vec2> {
        self.motion.target()
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
    pub fn set_world(&mut self, world: World) -> Option<NotClear> {
        self.world = world;
        let o = if self.world.obstacles().is_empty() {
            None
        } else {
            Some(self.world.clone())
        };
        self.overall.set_world(o);
        self.not_clear()
    }

    /// The link and obstacle of least clearance when the commanded pose is not clear.
    pub fn not_clear(&self) -> Option<NotClear> {
        let p = self.world.clearance(&self.guard.now)?;
        (p.clearance_m < self.world.clearance_m()).then(|| NotClear {
            link: p.link,
            obstacle: p.id(&self.world).to_string(),
            clearance_m: p.clearance_m,
            keep_m: self.world.clearance_m(),
        })
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
            return t;
        }
        let dt = dt.min(MAX_DT_S);
        let from = self.tip;
        // The point the step reached, as the resolver was asked for it (exact on the line).
        let mut reached = from;
        match self.motion.step(dt) {
            Reference::Hold => self.cand.copy_from_slice(&self.theta),
            Reference::Tip(r) => {
                t.tip_ref = r;
                reached = self.resolve_step(from, r, dt, &mut t);
            }
            Reference::Joints => {
                self.cand.copy_from_slice(self.motion.joint_reference());
                t.tip_ref = self.chain.tip(&self.cand);
                reached = t.tip_ref;
            }
        }
        t.clamped = self.clamp_joint_steps(dt);
        let cut = self.keep_clear();
        if cut {
            t.saturated = true;
            t.self_collision = true;
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
        self.tip = self.guard.commit(&self.chain, &self.theta);
        if t.clamped || cut {
            reached = self.tip;
        }
        t.tip = self.tip;
        t.min_clearance_m = self.world.clearance(&self.guard.now).map(|p| p.clearance_m);
        t.peak_joint_speed_rad_s = peak / dt;
        t.m3_rad2 = m3;
        t.finished = self.motion.follow(Achieved {
            tip: reached,
            theta: &self.theta,
            dt,
            exact: !(t.saturated || t.slowed || t.clamped),
            saturated: t.saturated,
        });
        t
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
            ..
        } = self;
        let resolver: &mut dyn Resolver = match strategy {
            Strategy::Overall => overall,
            Strategy::Sequential => sequential,
        };
        let (v, its) = attempt(resolver, chain, guard, theta, r, trial);
        t.iterations += its;
        t.self_collision |= v == Verdict::Collides;
        let mut reached = r;
        if v == Verdict::Sendable {
            cand.copy_from_slice(trial);
        } else {
            t.saturated = true;
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..BISECTION_ROUNDS {
                let mid = 0.5 * (lo + hi);
                let target = from + (r - from) * mid;
                let (v, its) = attempt(resolver, chain, guard, theta, target, trial);
                t.iterations += its;
                t.self_collision |= v == Verdict::Collides;
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
            let (v, its) = attempt(resolver, chain, guard, theta, shorter, trial);
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

    /// The last check: if the pose `cand` brings two links into contact, it is moved back
    /// along the joint step `theta -> cand` to the farthest fraction found clear by
    /// [`BISECTION_ROUNDS`] rounds of bisection (the commanded pose itself at worst). A
    /// fraction of the step keeps within the joint-speed bound and the limits. Returns whether
    /// it had to.
    fn keep_clear(&mut self) -> bool {
        if self.guard.contact(&self.chain, &self.cand).is_none() {
            return false;
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..BISECTION_ROUNDS {
            let mid = 0.5 * (lo + hi);
            for ((x, &c), &t) in self.trial.iter_mut().zip(&self.cand).zip(&self.theta) {
                *x = t + mid * (c - t);
            }
            if self.guard.contact(&self.chain, &self.trial).is_none() {
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
        true
    }
}

#[cfg(test)]
mod tests;
