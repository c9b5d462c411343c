//! Motion generation: the reference of one control tick from the active command (pure).
//!
//! The tip is a point mass `(p, v)`. Every tick its velocity moves toward a desired velocity by
//! at most `max_tip_accel * dt` (never more), then `p += v dt`. A goto asks for the velocity
//! pointing at the target with the speed [`approach_speed`] allows: the cruise speed, the
//! discrete braking speed (from which decelerating by `a dt` per tick ends on the target), and
//! no more than the remaining distance per tick. From rest every velocity is then parallel to
//! the line to the target, so the tip follows the straight line; a goto that preempts a moving
//! tip bends smoothly onto its target. Once within [`SNAP_M`] of the target with a velocity the
//! accel limit can cancel in one tick, the reference snaps onto the target exactly, at rest.
//!
//! Joint-space moves (goto_joints, home) and jog use the same law per joint with the joint
//! acceleration [`joint_accel`] (`max_joint_speed / JOINT_ACCEL_TIME_S`). A joint move scales
//! each joint's speed and acceleration by its share of the largest joint distance, so from rest
//! all joints move in proportion (a straight line in joint space) and arrive together. A jog
//! brakes toward its joint's limit as toward a target and sits there; the reference never
//! leaves the limits.
//!
//! After each tick the controller reports what the arm achieved ([`Achieved`]): when it fell
//! short of the reference (out of reach, slowed for the joint-speed bound, clamped), the state
//! follows the achieved pose and velocity, so the reference never runs ahead of the arm. A
//! route goes on from the arm too, however far off its way the arm ended: the segment it was
//! on starts at the arm's tip instead. Every tick's tip reference therefore starts on the arm
//! and moves at most the tip speed limit from it. A goto or path whose reference keeps being
//! out of reach with no progress ends [`Finish::Saturated`] after [`STALL_TICKS`] such ticks;
//! so does a joint move (goto_joints, home) that keeps being cut short (by a pose on its way
//! that the controller will not send).
//!
//! Nothing here allocates after [`Motion::new`] (a path's points are moved in, not copied), and
//! nothing reads a clock: time enters as `dt`.

use crate::chain::{JointLimit, Vec2};

/// Joint acceleration time: a joint reaches its speed limit from rest in this long. The joint
/// acceleration of joint moves and jog is `max_joint_speed_rad_s / JOINT_ACCEL_TIME_S`.
pub const JOINT_ACCEL_TIME_S: f64 = 0.25;

/// The joint acceleration, rad/s², used for joint moves and jog: `max_joint_speed /`
/// [`JOINT_ACCEL_TIME_S`].
pub fn joint_accel(max_joint_speed_rad_s: f64) -> f64 {
    max_joint_speed_rad_s / JOINT_ACCEL_TIME_S
}

/// Distance, m, within which a tip reference that can stop in one tick snaps onto its target.
pub const SNAP_M: f64 = 1e-9;

/// Distance, m, within which consecutive path points are merged into one corner
/// ([`Motion::path`]): the snap distance, so two points the tip cannot tell apart cost one
/// stop, not two.
pub const PATH_MERGE_M: f64 = SNAP_M;

/// Angle, rad, within which a joint reference that can stop in one tick snaps onto its target.
pub const SNAP_RAD: f64 = 1e-9;

/// Consecutive saturated ticks without progress (less than a quarter of the step asked for)
/// after which a goto, path or joint move gives up with [`Finish::Saturated`].
pub const STALL_TICKS: u32 = 3;

/// Speed and acceleration limits of the motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionLimits {
    /// Fastest tip speed, m/s.
    pub tip_speed: f64,
    /// Fastest change of the tip velocity, m/s².
    pub tip_accel: f64,
    /// Fastest joint speed, rad/s.
    pub joint_speed: f64,
    /// Fastest change of a joint's speed, rad/s² (see [`joint_accel`]).
    pub joint_accel: f64,
    /// How long a velocity or jog command lasts after its last renewal, s.
    pub deadman: f64,
}

/// How the active command ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Finish {
    /// Goto, path, goto_joints or home: on the target, at rest.
    Arrived,
    /// Goto or path: the tip stopped short of the target, out of reach or held by a joint at
    /// its limit (the sequential strategy's tractrix can fold a joint onto its limit well
    /// inside the workspace) or by the arm's own links. Joint move: a pose on the way could not
    /// be sent (it would self-intersect); the arm stopped short.
    Saturated,
    /// Goto or path: the body could not follow the tip without losing its clearance from an
    /// obstacle, or the tip made no headway; the arm holds, clear.
    Blocked {
        /// The link held back, 1-based from the base.
        link: usize,
        /// The obstacle's index in the world in force.
        obstacle: usize,
    },
    /// At rest after a stop (`deadman: false`) or after a velocity or jog lapsed (`true`).
    Stopped {
        /// The velocity or jog was not renewed within the deadman.
        deadman: bool,
    },
}

/// What the arm is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activity {
    /// A goto, path, velocity, jog or joint move is active.
    Moving,
    /// At rest, holding the last commanded pose.
    Holding,
    /// Decelerating to rest after a stop or a lapsed velocity or jog.
    Stopping,
}

/// This tick's reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reference {
    /// Nothing moves: keep the last pose.
    Hold,
    /// A tip position, m.
    Tip(Vec2),
    /// A joint pose: [`Motion::joint_reference`].
    Joints,
}

/// What the arm achieved in a tick, reported back with [`Motion::follow`].
#[derive(Debug, Clone, Copy)]
pub struct Achieved<'a> {
    /// Tip of the new commanded pose, m (for a tip reference: the point the resolver reached).
    pub tip: Vec2,
    /// The new commanded pose, rad.
    pub theta: &'a [f64],
    /// The tick's length, s.
    pub dt: f64,
    /// The reference was met as given (not bisected, slowed or clamped).
    pub exact: bool,
    /// The reference (or part of the step) was out of reach, or could not be sent.
    pub saturated: bool,
}

/// The speed, >= 0, to ask for with `distance` left so that decelerating by `accel * dt` per
/// tick ends exactly on the spot, capped by `max_speed`.
///
/// With `delta = accel * dt` and a speed `u = (m + f) delta` (integer `m >= 0`, `f` in [0, 1)),
/// the ticks from this one on run at `u, u - delta, .., f delta` and then stop, covering
/// `dt delta (m + 1) (m / 2 + f)`. Setting that equal to `distance` gives the largest such
/// `u`: `m` the largest integer with `m (m + 1) / 2 <= x = distance / (accel dt^2)`, then
/// `f = x / (m + 1) - m / 2`. The next tick (same `dt`) finds exactly `u - delta`, and the last
/// one lands on the spot, so the braking profile is exact in discrete time, not just in the
/// limit of small ticks.
pub fn approach_speed(distance: f64, max_speed: f64, accel: f64, dt: f64) -> f64 {
    if !(distance > 0.0 && max_speed > 0.0 && accel > 0.0 && dt > 0.0) {
        return 0.0;
    }
    let delta = accel * dt;
    let x = distance / (delta * dt);
    if !x.is_finite() {
        return max_speed;
    }
    let mut m = (0.5 * ((8.0 * x + 1.0).sqrt() - 1.0)).floor().max(0.0);
    // Round-off of the square root: make sure m (m + 1) / 2 <= x < (m + 1) (m + 2) / 2.
    if m * (m + 1.0) * 0.5 > x {
        m -= 1.0;
    } else if (m + 1.0) * (m + 2.0) * 0.5 <= x {
        m += 1.0;
    }
    let f = (x / (m + 1.0) - 0.5 * m).clamp(0.0, 1.0);
    ((m + f) * delta).min(max_speed)
}

/// A point of the plane with a velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointMass {
    /// Position, m.
    pub p: Vec2,
    /// Velocity, m/s.
    pub v: Vec2,
}

impl PointMass {
    /// At `p`, at rest.
    pub fn at_rest(p: Vec2) -> Self {
        Self {
            p,
            v: Vec2::zeros(),
        }
    }

    /// Moves the velocity toward `v_des` by at most `accel * dt`, then the position by `v dt`.
    pub fn drive(&mut self, v_des: Vec2, accel: f64, dt: f64) {
        let dv = v_des - self.v;
        let room = accel * dt;
        let n = dv.norm();
        self.v += if n > room { dv * (room / n) } else { dv };
        self.p += self.v * dt;
    }

    /// One tick toward `target` at no more than `speed`. Returns true when the point is on the
    /// target at rest (snapped onto it exactly).
    pub fn approach(&mut self, target: Vec2, speed: f64, accel: f64, dt: f64) -> bool {
        let e = target - self.p;
        let d = e.norm();
        if d <= SNAP_M && self.v.norm() <= accel * dt {
            self.p = target;
            self.v = Vec2::zeros();
            return true;
        }
        let u = approach_speed(d, speed, accel, dt);
        let v_des = if d > 0.0 { e * (u / d) } else { Vec2::zeros() };
        self.drive(v_des, accel, dt);
        false
    }
}

/// One joint's reference: an angle with a rate.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Axis {
    q: f64,
    v: f64,
}

impl Axis {
    fn drive(&mut self, v_des: f64, accel: f64, dt: f64) {
        let room = accel * dt;
        self.v += (v_des - self.v).clamp(-room, room);
        self.q += self.v * dt;
    }

    /// As [`PointMass::approach`], in one dimension.
    fn approach(&mut self, target: f64, speed: f64, accel: f64, dt: f64) -> bool {
        let e = target - self.q;
        if e.abs() <= SNAP_RAD && self.v.abs() <= accel * dt {
            self.q = target;
            self.v = 0.0;
            return true;
        }
        let u = approach_speed(e.abs(), speed, accel, dt);
        self.drive(u.copysign(e), accel, dt);
        false
    }

    /// Keeps the reference inside the limit, stopping it there.
    fn confine(&mut self, limit: Option<JointLimit>) {
        if let Some(l) = limit {
            if !l.contains(self.q) {
                self.q = l.clamp(self.q);
                self.v = 0.0;
            }
        }
    }
}

/// What a reference met exactly leads to.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Pending {
    /// A path corner, at rest: on to the next one.
    Corner,
    /// A route's stop, at rest: on to the next leg.
    Leg,
    /// The command ends.
    Finish(Finish),
}

/// Which space a stop decelerates in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Space {
    Tip,
    Joint,
}

/// The active command.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Hold,
    Goto {
        target: Vec2,
        speed: f64,
    },
    /// Toward `points[next]`, stopping at each corner.
    Path {
        next: usize,
        speed: f64,
    },
    /// Along the polyline `path` by arc length `s`: on segment `seg`, toward the stop `end`.
    Route {
        seg: usize,
        end: usize,
        speed: f64,
    },
    Velocity {
        v: Vec2,
    },
    Jog {
        joint: usize,
        rate: f64,
    },
    Joints,
    Stop {
        space: Space,
        deadman: bool,
    },
}

/// The motion state machine: the active command and the tip and joint references.
#[derive(Debug, Clone)]
pub struct Motion {
    limits: MotionLimits,
    joint_limits: Vec<Option<JointLimit>>,
    mode: Mode,
    tip: PointMass,
    axes: Vec<Axis>,
    /// Goal of a joint move.
    goal: Vec<f64>,
    /// Each joint's share of a joint move (scales its speed and acceleration).
    share: Vec<f64>,
    /// The joint reference as angles (what [`Motion::joint_reference`] returns).
    q: Vec<f64>,
    path: Vec<Vec2>,
    /// A route: whether the tip comes to rest at each point of `path`.
    rest: Vec<bool>,
    /// A route: arc length from its start to each point of `path`, m.
    cum: Vec<f64>,
    /// A route: the arc length reached and its rate.
    s: Axis,
    /// `s` before this tick's step.
    s_before: Axis,
    /// Time since the velocity or jog was last renewed, s.
    since_renewal: f64,
    /// Where this tick's reference leads, if the arm achieves it.
    pending: Option<Pending>,
    /// The joint reference before this tick's step (the last commanded pose).
    prior: Vec<f64>,
    /// Tip state before this tick's step (to measure progress).
    before: PointMass,
    stalled: u32,
    /// A route that preempted a tip moving off its way: the tip comes to rest first.
    settling: bool,
}

impl Motion {
    /// At rest at the pose `theta` whose tip is `tip`, holding. `joint_limits` has one entry per
    /// joint (`None` = unlimited).
    pub fn new(
        limits: MotionLimits,
        joint_limits: &[Option<JointLimit>],
        tip: Vec2,
        theta: &[f64],
    ) -> Self {
        let n = theta.len();
        let mut m = Self {
            limits,
            joint_limits: joint_limits.to_vec(),
            mode: Mode::Hold,
            tip: PointMass::at_rest(tip),
            axes: vec![Axis { q: 0.0, v: 0.0 }; n],
            goal: vec![0.0; n],
            share: vec![0.0; n],
            q: vec![0.0; n],
            path: Vec::new(),
            rest: Vec::new(),
            cum: Vec::new(),
            s: Axis { q: 0.0, v: 0.0 },
            s_before: Axis { q: 0.0, v: 0.0 },
            since_renewal: 0.0,
            pending: None,
            prior: theta.to_vec(),
            before: PointMass::at_rest(tip),
            stalled: 0,
            settling: false,
        };
        m.hold_at(tip, theta);
        m
    }

    /// The limits in use.
    pub fn limits(&self) -> &MotionLimits {
        &self.limits
    }

    /// Drops the command and puts both references at rest on the pose `theta` (tip `tip`).
    pub fn hold_at(&mut self, tip: Vec2, theta: &[f64]) {
        self.mode = Mode::Hold;
        self.tip = PointMass::at_rest(tip);
        for (a, &t) in self.axes.iter_mut().zip(theta) {
            *a = Axis { q: t, v: 0.0 };
        }
        self.pending = None;
        self.stalled = 0;
        self.settling = false;
    }

    fn start(&mut self, mode: Mode) {
        self.mode = mode;
        self.pending = None;
        self.stalled = 0;
        self.settling = false;
    }

    /// A straight line to `target` at `speed` (clamped to the tip speed limit).
    pub fn goto(&mut self, target: Vec2, speed: f64) {
        let speed = speed.min(self.limits.tip_speed);
        self.start(Mode::Goto { target, speed });
    }

    /// Through `points` in turn (at least one), each corner at rest. The points are moved in.
    ///
    /// Consecutive points within [`PATH_MERGE_M`] of each other are one corner (the first of
    /// them is kept): a repeated point would otherwise cost a tick at rest on the spot.
    pub fn path(&mut self, mut points: Vec<Vec2>, speed: f64) {
        if points.is_empty() {
            return;
        }
        points.dedup_by(|p, kept| (*p - *kept).norm() <= PATH_MERGE_M);
        self.path = points;
        let speed = speed.min(self.limits.tip_speed);
        self.start(Mode::Path { next: 0, speed });
    }

    /// Along the polyline `points` (moved in; the first is where the tip starts), at `speed`
    /// along the way, coming to rest at each point whose `rest` flag is set and at the last.
    /// One trapezoid of speed runs along the arc length of each stretch between rests, so the
    /// tip does not slow at the polyline's other corners: for a route around obstacles, whose
    /// corners turn by small angles. A tip moving along the first segment keeps its speed (too
    /// fast to stop on the first stop, it passes it on the same line and comes back); one
    /// moving any other way (across the segment, back along it, or off a route of one point)
    /// cannot join the way within the acceleration limit: it comes to rest first, at that limit,
    /// then goes back the way it came to the route's start, at rest there, and on.
    pub fn route(&mut self, mut points: Vec<Vec2>, mut rest: Vec<bool>, speed: f64) {
        if points.is_empty() || rest.len() != points.len() {
            return;
        }
        // Merge repeated points, keeping a rest where either had one.
        let mut kept = 0;
        for k in 1..points.len() {
            if (points[k] - points[kept]).norm() <= PATH_MERGE_M {
                rest[kept] |= rest[k];
            } else {
                kept += 1;
                points[kept] = points[k];
                rest[kept] = rest[k];
            }
        }
        points.truncate(kept + 1);
        rest.truncate(kept + 1);
        if let Some(last) = rest.last_mut() {
            *last = true;
        }
        let first = match points.get(1) {
            Some(&p1) if p1 != points[0] => (p1 - points[0]).normalize(),
            _ => Vec2::zeros(),
        };
        let along = self.tip.v.dot(&first).max(0.0);
        // Round-off of a velocity already along the way is no reason to stop.
        let settle = (self.tip.v - first * along).norm() > 1e-9 * self.limits.tip_speed;
        if settle {
            // The start twice: the first becomes where the tip comes to rest.
            points.insert(0, points[0]);
            rest.insert(0, true);
        }
        self.cum.clear();
        let mut total = 0.0;
        for k in 0..points.len() {
            if k > 0 {
                total += (points[k] - points[k - 1]).norm();
            }
            self.cum.push(total);
        }
        self.s = Axis {
            q: 0.0,
            v: if settle { 0.0 } else { along },
        };
        let end = (1..points.len()).find(|&k| rest[k]).unwrap_or(0);
        self.path = points;
        self.rest = rest;
        let speed = speed.min(self.limits.tip_speed);
        self.start(Mode::Route { seg: 0, end, speed });
        self.settling = settle;
    }

    /// A settling route's tip at rest at `at`: the route starts there.
    fn settled(&mut self, at: Vec2) {
        self.settling = false;
        if let Some(p) = self.path.first_mut() {
            *p = at;
        }
        let mut total = 0.0;
        for k in 0..self.path.len().min(self.cum.len()) {
            if k > 0 {
                total += (self.path[k] - self.path[k - 1]).norm();
            }
            self.cum[k] = total;
        }
        self.s = Axis { q: 0.0, v: 0.0 };
        if let Mode::Route { end, speed, .. } = self.mode {
            self.mode = Mode::Route { seg: 0, end, speed };
        }
    }

    /// The point at arc length `s` of the route and the unit tangent there, searching forward
    /// from segment `seg` (updated) but not past `end`. Beyond the stop `end` (a tip that came
    /// too fast to stop on it) the point runs on along the line of the last segment, so that
    /// the tip passes the stop and comes back, as a goto's does, rather than stopping dead.
    fn route_point(&self, seg: &mut usize, end: usize, s: f64) -> (Vec2, Vec2) {
        while *seg + 1 < end && s > self.cum[*seg + 1] {
            *seg += 1;
        }
        while *seg > 0 && s < self.cum[*seg] {
            *seg -= 1;
        }
        let (Some(&a), Some(&b)) = (self.path.get(*seg), self.path.get(*seg + 1)) else {
            return (self.tip.p, Vec2::zeros());
        };
        let len = self.cum[*seg + 1] - self.cum[*seg];
        if len <= 0.0 {
            return (b, Vec2::zeros());
        }
        let dir = (b - a) / len;
        let along = s - self.cum[*seg];
        let along = if *seg + 1 >= end {
            along.max(0.0)
        } else {
            along.clamp(0.0, len)
        };
        (a + dir * along, dir)
    }

    /// A tip velocity (its magnitude clamped to the tip speed limit) for the deadman time.
    pub fn velocity(&mut self, v: Vec2) {
        let s = v.x.hypot(v.y);
        let max = self.limits.tip_speed;
        let v = if s > max { v * (max / s) } else { v };
        self.since_renewal = 0.0;
        self.start(Mode::Velocity { v });
    }

    /// Joint `joint` at `rate` (clamped to the joint speed limit) for the deadman time; the
    /// other joints come to rest. Ignored for a joint that does not exist.
    pub fn jog(&mut self, joint: usize, rate: f64) {
        if joint >= self.axes.len() {
            return;
        }
        let w = self.limits.joint_speed;
        self.since_renewal = 0.0;
        self.start(Mode::Jog {
            joint,
            rate: rate.clamp(-w, w),
        });
    }

    /// A joint-space move to `theta` (one angle per joint, inside the limits; a wrong length is
    /// ignored). From rest every joint moves in proportion and all arrive together.
    pub fn joints(&mut self, theta: &[f64]) {
        if theta.len() != self.axes.len() {
            return;
        }
        self.goal.copy_from_slice(theta);
        let w = self.limits.joint_speed;
        let far = self
            .axes
            .iter()
            .zip(theta)
            .map(|(a, g)| (g - a.q).abs())
            .fold(0.0, f64::max);
        for ((s, a), g) in self.share.iter_mut().zip(&self.axes).zip(theta) {
            let distance = if far > 0.0 {
                (g - a.q).abs() / far
            } else {
                0.0
            };
            // A joint still moving keeps the authority to stop itself.
            *s = distance.max(a.v.abs() / w).min(1.0);
        }
        self.start(Mode::Joints);
    }

    /// Decelerate to rest (in the space of the active command) and hold.
    pub fn stop(&mut self) {
        let space = self.space();
        self.start(Mode::Stop {
            space,
            deadman: false,
        });
    }

    fn space(&self) -> Space {
        match self.mode {
            Mode::Jog { .. } | Mode::Joints => Space::Joint,
            Mode::Stop { space, .. } => space,
            _ => Space::Tip,
        }
    }

    /// What the arm is doing.
    pub fn activity(&self) -> Activity {
        match self.mode {
            Mode::Hold => Activity::Holding,
            Mode::Stop { .. } => Activity::Stopping,
            _ => Activity::Moving,
        }
    }

    /// The final target of a goto or path (a path's last point).
    pub fn target(&self) -> Option<Vec2> {
        match self.mode {
            Mode::Goto { target, .. } => Some(target),
            Mode::Path { .. } | Mode::Route { .. } => self.path.last().copied(),
            _ => None,
        }
    }

    /// The cruise speed of a goto, path or route, m/s.
    pub fn cruise_speed(&self) -> Option<f64> {
        match self.mode {
            Mode::Goto { speed, .. } | Mode::Path { speed, .. } | Mode::Route { speed, .. } => {
                Some(speed)
            }
            _ => None,
        }
    }

    /// The tip reference state.
    pub fn tip(&self) -> &PointMass {
        &self.tip
    }

    /// The joint reference of this tick (meaningful after a [`Reference::Joints`] step).
    pub fn joint_reference(&self) -> &[f64] {
        &self.q
    }

    /// The target the tip is heading for now (a path's current corner).
    fn tip_goal(&self) -> Option<Vec2> {
        match self.mode {
            Mode::Goto { target, .. } => Some(target),
            Mode::Path { next, .. } => self.path.get(next).copied(),
            Mode::Route { end, .. } => self.path.get(end).copied(),
            _ => None,
        }
    }

    /// Advances the references by `dt` (> 0) and says what to aim at this tick.
    pub fn step(&mut self, dt: f64) -> Reference {
        let lim = self.limits;
        self.pending = None;
        self.before = self.tip;
        self.s_before = self.s;
        for (p, a) in self.prior.iter_mut().zip(&self.axes) {
            *p = a.q;
        }
        if let Mode::Velocity { .. } | Mode::Jog { .. } = self.mode {
            // The command covers `deadman` after its renewal: a tick reaching past that
            // already decelerates.
            if self.since_renewal + dt > lim.deadman {
                self.mode = Mode::Stop {
                    space: self.space(),
                    deadman: true,
                };
            }
            self.since_renewal += dt;
        }
        match self.mode {
            Mode::Hold => Reference::Hold,
            Mode::Goto { target, speed } => {
                if self.tip.approach(target, speed, lim.tip_accel, dt) {
                    self.pending = Some(Pending::Finish(Finish::Arrived));
                }
                Reference::Tip(self.tip.p)
            }
            Mode::Path { next, speed } => {
                let corner = self.path.get(next).copied().unwrap_or(self.tip.p);
                if self.tip.approach(corner, speed, lim.tip_accel, dt) {
                    self.pending = Some(if next + 1 < self.path.len() {
                        Pending::Corner
                    } else {
                        Pending::Finish(Finish::Arrived)
                    });
                }
                Reference::Tip(self.tip.p)
            }
            Mode::Route { .. } if self.settling => {
                self.tip.drive(Vec2::zeros(), lim.tip_accel, dt);
                if self.tip.v == Vec2::zeros() {
                    self.settled(self.tip.p);
                }
                Reference::Tip(self.tip.p)
            }
            Mode::Route {
                mut seg,
                end,
                speed,
            } => {
                let goal = self.cum.get(end).copied().unwrap_or(self.s.q);
                let arrived = self.s.approach(goal, speed, lim.tip_accel, dt);
                let (p, dir) = self.route_point(&mut seg, end, self.s.q);
                self.tip.p = if arrived {
                    self.path.get(end).copied().unwrap_or(p)
                } else {
                    p
                };
                self.tip.v = dir * self.s.v;
                if arrived {
                    self.pending = Some(if end + 1 < self.path.len() {
                        Pending::Leg
                    } else {
                        Pending::Finish(Finish::Arrived)
                    });
                }
                self.mode = Mode::Route { seg, end, speed };
                Reference::Tip(self.tip.p)
            }
            Mode::Velocity { v } => {
                self.tip.drive(v, lim.tip_accel, dt);
                Reference::Tip(self.tip.p)
            }
            Mode::Stop {
                space: Space::Tip,
                deadman,
            } => {
                self.tip.drive(Vec2::zeros(), lim.tip_accel, dt);
                if self.tip.v == Vec2::zeros() {
                    self.pending = Some(Pending::Finish(Finish::Stopped { deadman }));
                }
                Reference::Tip(self.tip.p)
            }
            Mode::Stop {
                space: Space::Joint,
                deadman,
            } => {
                let mut rest = true;
                for (a, l) in self.axes.iter_mut().zip(&self.joint_limits) {
                    a.drive(0.0, lim.joint_accel, dt);
                    a.confine(*l);
                    rest &= a.v == 0.0;
                }
                if rest {
                    self.pending = Some(Pending::Finish(Finish::Stopped { deadman }));
                }
                self.load_q()
            }
            Mode::Jog { joint, rate } => {
                for (i, (a, l)) in self.axes.iter_mut().zip(&self.joint_limits).enumerate() {
                    if i != joint {
                        a.drive(0.0, lim.joint_accel, dt);
                    } else {
                        // Brake toward the limit ahead as toward a target, and sit on it.
                        let end = match l {
                            Some(l) if rate > 0.0 => Some(l.hi),
                            Some(l) if rate < 0.0 => Some(l.lo),
                            _ => None,
                        };
                        match end {
                            Some(end) => {
                                a.approach(end, rate.abs(), lim.joint_accel, dt);
                            }
                            None => a.drive(rate, lim.joint_accel, dt),
                        }
                    }
                    a.confine(*l);
                }
                self.load_q()
            }
            Mode::Joints => {
                let mut all = true;
                for ((a, l), (g, s)) in self
                    .axes
                    .iter_mut()
                    .zip(&self.joint_limits)
                    .zip(self.goal.iter().zip(&self.share))
                {
                    all &= a.approach(*g, lim.joint_speed * s, lim.joint_accel * s, dt);
                    a.confine(*l);
                }
                if all {
                    self.pending = Some(Pending::Finish(Finish::Arrived));
                }
                self.load_q()
            }
        }
    }

    fn load_q(&mut self) -> Reference {
        for (q, a) in self.q.iter_mut().zip(&self.axes) {
            *q = a.q;
        }
        Reference::Joints
    }

    /// A route whose arm fell short of (or off) its reference goes on from where the arm is:
    /// the segment `seg` (toward the stop `end`) starts at the arm's tip `tip` instead, the
    /// arc lengths of the points after it follow, and the route's arc length and its rate are
    /// the arm's: at the segment's start, at the arm's speed along it (`step` over `dt`, none
    /// backward, at most the tip speed limit). The reference is then on the arm, so the next
    /// tick's step starts there and keeps the tip speed limit however far the arm left the
    /// route (a joint step clamped to the joint speed bound, or cut short for a clearance,
    /// can take it far off).
    fn rejoin(&mut self, seg: usize, end: usize, tip: Vec2, step: Vec2, dt: f64) {
        if seg >= end {
            return;
        }
        let (Some(&next), Some(&at), Some(&then)) = (
            self.path.get(seg + 1),
            self.cum.get(seg),
            self.cum.get(seg + 1),
        ) else {
            return;
        };
        let len = (next - tip).norm();
        let shift = len - (then - at);
        self.path[seg] = tip;
        for c in &mut self.cum[seg + 1..] {
            *c += shift;
        }
        self.s.q = at;
        let along = if len > 0.0 {
            step.dot(&((next - tip) / len)) / dt
        } else {
            0.0
        };
        self.s.v = along.clamp(0.0, self.limits.tip_speed);
    }

    /// Takes in what the arm achieved this tick (after [`Motion::step`]); returns how the
    /// active command ended, if it did (the motion then holds).
    ///
    /// An exact tick keeps the reference as stepped and confirms a pending finish; otherwise
    /// the reference of the active space jumps to what was achieved, with the velocity that
    /// took it there (a tip velocity at most the tip speed limit), and a route goes on from
    /// the arm's tip: its segment starts there. The other space's reference always follows
    /// the arm.
    pub fn follow(&mut self, got: Achieved) -> Option<Finish> {
        let dt = got.dt;
        let asked = (self.tip.p - self.before.p).norm();
        // A joint move's progress, in the largest joint distance to its goal.
        let joint_move = self.mode == Mode::Joints;
        let (asked_q, progress_q) = if joint_move {
            let gap = |pose: &mut dyn Iterator<Item = f64>| {
                pose.zip(&self.goal)
                    .map(|(q, g)| (g - q).abs())
                    .fold(0.0, f64::max)
            };
            let asked = self
                .axes
                .iter()
                .zip(&self.prior)
                .map(|(a, p)| (a.q - p).abs())
                .fold(0.0, f64::max);
            let before = gap(&mut self.prior.iter().copied());
            let after = gap(&mut got.theta.iter().copied());
            (asked, before - after)
        } else {
            (0.0, 0.0)
        };
        let joint_space = matches!(
            self.mode,
            Mode::Jog { .. }
                | Mode::Joints
                | Mode::Stop {
                    space: Space::Joint,
                    ..
                }
        );
        let holding = self.mode == Mode::Hold;
        // A stop never speeds up: what the arm did takes over its reference's velocity only
        // up to the speed the stop had come down to (a body leaving an obstacle it was put
        // into moves its tip as it must, and would otherwise keep the stop going).
        let stopping = matches!(self.mode, Mode::Stop { .. });
        // The tip: unless it is the exactly met reference, it is where the arm put it.
        if holding || joint_space || !got.exact {
            let most = if stopping && !joint_space {
                self.tip.v.norm().min(self.limits.tip_speed)
            } else {
                self.limits.tip_speed
            };
            self.tip.v = if holding {
                Vec2::zeros()
            } else {
                (got.tip - self.before.p) / dt
            };
            self.tip.p = got.tip;
            let s = self.tip.v.norm();
            if s > most {
                self.tip.v *= most / s;
            }
        }
        // The joints: likewise.
        if holding || !joint_space || !got.exact {
            for ((a, &t), &t0) in self.axes.iter_mut().zip(got.theta).zip(&self.prior) {
                let v = if holding { 0.0 } else { (t - t0) / dt };
                // (`max`/`min`, not `clamp`: no panic whatever the numbers.)
                let most = a.v.abs();
                a.v = if stopping && joint_space {
                    v.max(-most).min(most)
                } else {
                    v
                };
                a.q = t;
            }
        }
        // A route: the arm's progress is its step along the way; the way on starts at the arm.
        let mut along_route = 0.0;
        if let Mode::Route {
            mut seg,
            end,
            speed,
        } = self.mode
        {
            if !got.exact {
                let (_, dir) = self.route_point(&mut seg, end, self.s_before.q);
                let goal = self.cum.get(end).copied().unwrap_or(self.s_before.q);
                along_route = (got.tip - self.before.p)
                    .dot(&dir)
                    .max(0.0)
                    .min(goal - self.s_before.q);
                self.s.q = self.s_before.q + along_route;
                self.s.v = (along_route / dt).min(self.limits.tip_speed);
                let (_, _) = self.route_point(&mut seg, end, self.s.q);
                self.rejoin(seg, end, got.tip, got.tip - self.before.p, dt);
                self.mode = Mode::Route { seg, end, speed };
            }
        }
        // A goto, path or joint move whose reference cannot be met and that cannot get closer
        // gives up.
        let route = matches!(self.mode, Mode::Route { .. });
        let stalled = match (got.saturated, self.tip_goal()) {
            (true, Some(_)) if route => Some(along_route <= 0.25 * asked),
            (true, Some(goal)) => {
                let progress = (goal - self.before.p).norm() - (goal - got.tip).norm();
                Some(progress <= 0.25 * asked)
            }
            (true, None) if joint_move => Some(progress_q <= 0.25 * asked_q),
            _ => None,
        };
        match stalled {
            Some(true) => self.stalled += 1,
            _ => self.stalled = 0,
        }
        if self.stalled >= STALL_TICKS {
            self.hold_at(got.tip, got.theta);
            return Some(Finish::Saturated);
        }
        let pending = self.pending.take();
        if !got.exact {
            // A stop whose reference has come to rest ends even when the arm could not meet
            // it exactly (a body not clear of an obstacle, which may only get clearer, is held
            // back on every tick): the arm holds where it got, instead of stopping for ever.
            if let (Some(Pending::Finish(f)), Mode::Stop { .. }) = (pending, self.mode) {
                self.hold_at(got.tip, got.theta);
                return Some(f);
            }
            return None;
        }
        match pending? {
            Pending::Corner => {
                if let Mode::Path { next, speed } = self.mode {
                    self.mode = Mode::Path {
                        next: next + 1,
                        speed,
                    };
                }
                None
            }
            Pending::Leg => {
                if let Mode::Route { end, speed, .. } = self.mode {
                    let next = (end + 1..self.path.len())
                        .find(|&k| self.rest.get(k).copied().unwrap_or(true))
                        .unwrap_or(end);
                    self.s = Axis {
                        q: self.cum.get(end).copied().unwrap_or(self.s.q),
                        v: 0.0,
                    };
                    self.mode = Mode::Route {
                        seg: end,
                        end: next,
                        speed,
                    };
                }
                None
            }
            Pending::Finish(f) => {
                self.hold_at(got.tip, got.theta);
                Some(f)
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A tick that reached `tip` exactly, at `theta`.
    fn reached(tip: Vec2, theta: &[f64], dt: f64) -> Achieved<'_> {
        Achieved {
            tip,
            theta,
            dt,
            exact: true,
            saturated: false,
        }
    }

    fn limits() -> MotionLimits {
        MotionLimits {
            tip_speed: 0.1,
            tip_accel: 0.5,
            joint_speed: 2.0,
            joint_accel: joint_accel(2.0),
            deadman: 0.5,
        }
    }

    /// Runs `motion` with every reference met exactly; returns the finish and the ticks taken.
    fn run_exact(
        m: &mut Motion,
        theta: &mut [f64],
        dt: f64,
        max: usize,
    ) -> (Option<Finish>, usize) {
        for k in 1..=max {
            if m.step(dt) == Reference::Joints {
                theta.copy_from_slice(m.joint_reference());
            }
            let tip = m.tip().p;
            let got = reached(tip, theta, dt);
            if let Some(f) = m.follow(got) {
                return (Some(f), k);
            }
        }
        (None, max)
    }

    #[test]
    fn the_discrete_braking_profile_is_exact() {
        // From u = (m + f) a dt, the next tick at the same dt asks exactly a dt less.
        let (a, dt) = (0.7, 0.004);
        let mut d = 0.013;
        let mut u = approach_speed(d, 1e9, a, dt);
        let mut ticks = 0;
        while d > 0.0 {
            d -= u * dt;
            let next = approach_speed(d, 1e9, a, dt);
            assert!(
                next <= u && u - next <= a * dt * (1.0 + 1e-9),
                "{u} -> {next}"
            );
            u = next;
            ticks += 1;
            assert!(ticks < 1000);
        }
        assert!(d.abs() < 1e-15, "ends {d} off the spot");
        assert_eq!(approach_speed(0.0, 1.0, 1.0, 0.01), 0.0);
        assert_eq!(approach_speed(1.0, 0.2, 1.0, 0.01), 0.2);
    }

    proptest! {
        /// From rest the point stays on the straight line, never passes the target, never
        /// exceeds the speed, changes its velocity by at most `a dt` a tick, and comes to rest
        /// on the target exactly, about when the trapezoid profile says.
        #[test]
        fn a_goto_from_rest_is_a_straight_trapezoid(
            dx in -1.0f64..1.0, dy in -1.0f64..1.0, speed in 0.01f64..1.0,
            accel in 0.05f64..10.0, dt in 0.0005f64..0.02,
        ) {
            let target = Vec2::new(dx, dy);
            let d = target.norm();
            let mut pm = PointMass::at_rest(Vec2::zeros());
            let mut t = 0.0;
            loop {
                let v0 = pm.v;
                let arrived = pm.approach(target, speed, accel, dt);
                t += dt;
                prop_assert!((pm.v - v0).norm() <= accel * dt * (1.0 + 1e-12));
                prop_assert!(pm.v.norm() <= speed * (1.0 + 1e-12));
                let along = pm.p.dot(&target) / d.max(1e-300);
                prop_assert!(along <= d * (1.0 + 1e-12) + 1e-15, "passed the target");
                let off = (pm.p - target * (along / d.max(1e-300))).norm();
                prop_assert!(off <= 1e-12, "{off} off the line");
                if arrived {
                    break;
                }
                prop_assert!(t < 1000.0);
            }
            prop_assert_eq!(pm.p, target);
            let trapezoid = if d >= speed * speed / accel {
                d / speed + speed / accel
            } else {
                2.0 * (d / accel).sqrt()
            };
            prop_assert!(t >= trapezoid - 2.0 * dt && t <= trapezoid + 3.0 * dt,
                "{t} s against {trapezoid} s");
        }

        /// A goto that preempts a moving point still arrives, without exceeding the
        /// acceleration, even with the tick length changing every tick.
        #[test]
        fn a_preempting_goto_still_arrives(
            vx in -1.0f64..1.0, vy in -1.0f64..1.0, dx in -0.5f64..0.5, dy in -0.5f64..0.5,
            accel in 0.1f64..5.0, seed in 0u64..1000,
        ) {
            let speed = 1.0;
            let mut pm = PointMass { p: Vec2::zeros(), v: Vec2::new(vx, vy) * 0.7 };
            let target = Vec2::new(dx, dy);
            let mut state = seed;
            let mut t = 0.0;
            let bound = 4.0 * speed / accel + 4.0 * (1.0 + target.norm()) / speed + 1.0;
            loop {
                state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                let dt = 0.0005 + 0.0195 * ((state >> 11) as f64 / (1u64 << 53) as f64);
                let v0 = pm.v;
                let arrived = pm.approach(target, speed, accel, dt);
                prop_assert!((pm.v - v0).norm() <= accel * dt * (1.0 + 1e-12));
                t += dt;
                if arrived {
                    break;
                }
                prop_assert!(t < bound, "not there after {t} s");
            }
            prop_assert_eq!(pm.p, target);
        }
    }

    #[test]
    fn a_jog_sits_on_the_limit_and_lapses() {
        let lim = Some(JointLimit { lo: -1.0, hi: 0.5 });
        let mut m = Motion::new(limits(), &[lim, lim], Vec2::zeros(), &[0.0, 0.2]);
        let mut theta = [0.0, 0.2];
        let mut since = 0.0;
        let dt = 0.003;
        let mut at_limit = 0;
        while since < 3.0 {
            if (since * 10.0f64).fract() < 0.03 {
                m.jog(1, 50.0);
            }
            let _ = m.step(dt);
            theta.copy_from_slice(m.joint_reference());
            assert!(theta[1] <= 0.5 && theta[0] == 0.0);
            let got = reached(Vec2::zeros(), &theta, dt);
            assert_eq!(m.follow(got), None);
            if theta[1] == 0.5 {
                at_limit += 1;
            }
            since += dt;
        }
        assert!(at_limit > 100, "{at_limit} ticks on the limit");
        let (f, k) = run_exact(&mut m, &mut theta, dt, 1000);
        assert_eq!(f, Some(Finish::Stopped { deadman: true }));
        assert!(
            k as f64 * dt <= 0.5 + dt,
            "lapsed after {} s",
            k as f64 * dt
        );
        assert_eq!(theta[1], 0.5);
    }

    #[test]
    fn joint_moves_arrive_together_on_the_pose() {
        let mut m = Motion::new(limits(), &[None; 3], Vec2::zeros(), &[0.0, 0.0, 0.0]);
        let mut theta = [0.0; 3];
        let goal = [1.0, -0.5, 0.0];
        m.joints(&goal);
        let dt = 0.01;
        let (f, k) = run_exact(&mut m, &mut theta, dt, 10_000);
        assert_eq!(f, Some(Finish::Arrived));
        assert_eq!(theta, goal);
        // Joint 0 leads: 1 rad at 2 rad/s with 8 rad/s² is a triangle-free trapezoid of 0.75 s.
        let t = k as f64 * dt;
        assert!((t - 0.75).abs() <= 3.0 * dt, "{t} s");
        assert_eq!(m.activity(), Activity::Holding);
    }

    #[test]
    fn a_path_hands_over_at_each_corner() {
        let mut m = Motion::new(limits(), &[None], Vec2::zeros(), &[0.0]);
        let corners = vec![Vec2::new(0.01, 0.0), Vec2::new(0.01, 0.01), Vec2::zeros()];
        m.path(corners.clone(), 1.0);
        assert_eq!(m.target(), Some(Vec2::zeros()));
        let mut theta = [0.0];
        let mut visited = Vec::new();
        for _ in 0..10_000 {
            let _ = m.step(0.002);
            let p = m.tip().p;
            let got = reached(p, &theta, 0.002);
            let f = m.follow(got);
            if m.tip().v == Vec2::zeros() && corners.contains(&p) && visited.last() != Some(&p) {
                visited.push(p);
            }
            if f.is_some() {
                assert_eq!(f, Some(Finish::Arrived));
                break;
            }
            theta[0] = 0.0;
        }
        assert_eq!(visited, corners);
    }

    #[test]
    fn a_route_runs_one_trapezoid_per_leg_through_its_waypoints() {
        let lim = limits();
        let mut m = Motion::new(lim, &[None], Vec2::zeros(), &[0.0]);
        // Two legs: round a corner without stopping, rest at (0.02, 0.01), then back home.
        let points = vec![
            Vec2::zeros(),
            Vec2::new(0.01, 0.0),
            Vec2::new(0.02, 0.01),
            Vec2::new(0.0, 0.01),
            Vec2::zeros(),
        ];
        let rest = vec![true, false, true, false, true];
        m.route(points.clone(), rest, 1.0);
        assert_eq!(m.target(), Some(Vec2::zeros()));
        let theta = [0.0];
        let dt = 0.002;
        let (mut rests, mut prev_v) = (Vec::new(), Vec2::zeros());
        let mut finish = None;
        for _ in 0..10_000 {
            let _ = m.step(dt);
            let (p, v) = (m.tip().p, m.tip().v);
            // Along the polyline: on one of its segments, at no more than the speed limit.
            let on = points.windows(2).any(|w| {
                let (a, b) = (w[0], w[1]);
                let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
                (a + (b - a) * t - p).norm() < 1e-12
            });
            assert!(on, "{p:?} off the route");
            assert!(v.norm() <= lim.tip_speed * (1.0 + 1e-12));
            // The speed along the way changes by at most the acceleration limit.
            assert!((v.norm() - prev_v.norm()).abs() <= lim.tip_accel * dt * (1.0 + 1e-9));
            prev_v = v;
            if v == Vec2::zeros() && rests.last() != Some(&p) {
                rests.push(p);
            }
            let got = reached(p, &theta, dt);
            if let Some(f) = m.follow(got) {
                finish = Some(f);
                break;
            }
        }
        assert_eq!(finish, Some(Finish::Arrived));
        // At rest only at the leg ends: the corners in between are passed moving.
        assert_eq!(rests, vec![Vec2::new(0.02, 0.01), Vec2::zeros()]);
    }

    /// A route that preempts a tip moving at full speed keeps the acceleration and speed limits
    /// on every tick, whichever way it leaves (across, back, ahead, or a route of one point
    /// where the tip is), and still ends at rest on its goal.
    #[test]
    fn a_route_preempting_a_moving_tip_keeps_the_acceleration_limit() {
        let lim = limits();
        let dt = 0.002;
        for way in [
            Vec2::new(0.0, 0.05),
            Vec2::new(-0.05, 0.0),
            Vec2::new(0.03, 0.01),
            Vec2::new(0.05, 0.0),
            Vec2::new(0.001, 0.0),
            Vec2::zeros(),
        ] {
            let mut m = Motion::new(lim, &[None], Vec2::zeros(), &[0.0]);
            let theta = [0.0];
            let exact = |m: &Motion| reached(m.tip().p, &theta, dt);
            for _ in 0..200 {
                m.velocity(Vec2::new(lim.tip_speed, 0.0));
                let _ = m.step(dt);
                assert_eq!(m.follow(exact(&m)), None);
            }
            assert!((m.tip().v.norm() - lim.tip_speed).abs() < 1e-12);
            let start = m.tip().p;
            let goal = start + way;
            m.route(vec![start, goal], vec![true, true], 1.0);
            let mut prev = *m.tip();
            // The velocity the reference's positions show (the state's own may differ).
            let mut shown = prev.v;
            let mut finish = None;
            for k in 0..10_000 {
                let _ = m.step(dt);
                let now = *m.tip();
                let room = lim.tip_accel * dt * (1.0 + 1e-9);
                let dv = (now.v - prev.v).norm();
                assert!(
                    dv <= room,
                    "{way:?}, tick {k}: the velocity changed by {dv} m/s against {room} m/s",
                );
                let v = (now.p - prev.p) / dt;
                let dv = (v - shown).norm();
                assert!(
                    dv <= room + 1e-9,
                    "{way:?}, tick {k}: the positions' velocity changed by {dv} m/s against \
                     {room} m/s"
                );
                assert!(now.v.norm() <= lim.tip_speed * (1.0 + 1e-12));
                assert!(v.norm() <= lim.tip_speed * (1.0 + 1e-9));
                prev = now;
                shown = v;
                if let Some(f) = m.follow(exact(&m)) {
                    finish = Some(f);
                    break;
                }
            }
            assert_eq!(finish, Some(Finish::Arrived), "{way:?}");
            assert_eq!(m.tip().p, goal, "{way:?}");
        }
    }

    /// An arm put far off its route by a tick that fell short (a clamped joint step) goes on
    /// from where it is: the next reference starts on the arm, every step keeps the tip speed
    /// limit, and the route still ends on its stop.
    #[test]
    fn a_route_left_by_the_arm_goes_on_from_the_arm() {
        let lim = limits();
        let mut m = Motion::new(lim, &[None], Vec2::zeros(), &[0.0]);
        let goal = Vec2::new(0.05, 0.0);
        let points = vec![Vec2::zeros(), Vec2::new(0.02, 0.0), goal];
        m.route(points, vec![true, false, true], 1.0);
        let theta = [0.0];
        let dt = 0.01;
        for _ in 0..5 {
            let _ = m.step(dt);
            let got = reached(m.tip().p, &theta, dt);
            assert_eq!(m.follow(got), None);
        }
        // One tick falls short far off the way, and faster than the tip speed limit.
        let _ = m.step(dt);
        let off = Vec2::new(0.0, 0.03);
        let got = Achieved {
            tip: off,
            theta: &theta,
            dt,
            exact: false,
            saturated: true,
        };
        assert_eq!(m.follow(got), None);
        assert_eq!(m.tip().p, off);
        let mut arm = off;
        let mut finish = None;
        for k in 0..10_000 {
            let _ = m.step(dt);
            let p = m.tip().p;
            assert!(
                (p - arm).norm() <= lim.tip_speed * dt * (1.0 + 1e-12),
                "tick {k}: the reference {p:?} is {} from the arm {arm:?}",
                (p - arm).norm()
            );
            arm = p;
            let got = reached(p, &theta, dt);
            if let Some(f) = m.follow(got) {
                finish = Some(f);
                break;
            }
        }
        assert_eq!(finish, Some(Finish::Arrived));
        assert_eq!(arm, goal);
    }

    #[test]
    fn a_reference_out_of_reach_gives_up_after_the_stall_ticks() {
        let mut m = Motion::new(limits(), &[None], Vec2::zeros(), &[0.0]);
        m.goto(Vec2::new(1.0, 0.0), 0.1);
        let theta = [0.0];
        for k in 1..=STALL_TICKS {
            let _ = m.step(0.01);
            let got = Achieved {
                tip: Vec2::zeros(),
                theta: &theta,
                dt: 0.01,
                exact: false,
                saturated: true,
            };
            let f = m.follow(got);
            assert_eq!(f.is_some(), k == STALL_TICKS, "tick {k}");
            if let Some(f) = f {
                assert_eq!(f, Finish::Saturated);
            }
            // The reference follows the arm: it stays where the arm is, at rest.
            assert_eq!(m.tip().p, Vec2::zeros());
            assert_eq!(m.tip().v, Vec2::zeros());
        }
        assert_eq!(m.activity(), Activity::Holding);
    }
}
