//! The cold solve: a deterministic sequence of starts ([`Start`], in the order of
//! [`Schedule`]), each run to a local optimum, the best by metric 3 kept ([`Podium`]). The
//! fixed starts are the pose given (clipped into the limits), the same with the base joint
//! turned toward the target, two continuations along the tip's way to the target (straight,
//! and polar about the base: a few loose local solves to targets on the way), and the mirror
//! images of the best optima so far; then seeded random poses, within the ball of poses no
//! worse than the best so far. Among obstacles module `clear` runs its own sequence with the
//! same parts.

use crate::chain::{nearest_representative, wrap_angle, Chain, Vec2};
use crate::resolve::Outcome;

use super::{bearing, half_metric, max_abs_diff, Exit, Overall, OverallOptions, Problem};

/// Tip tolerance of a continuation stage, relative to the scale: an intermediate target only
/// guides the next stage, so a loose solve is enough.
const STAGE_TIP_TOLERANCE: f64 = 1e-6;
/// Stationarity tolerance of a continuation stage, rad: loose for the same reason.
const STAGE_STATIONARITY_TOLERANCE: f64 = 1e-6;
/// Two optima are the same when their metric 3 agrees within this relative amount (the
/// round-off of two converged solves)...
const SAME_OPTIMUM_METRIC: f64 = 1e-9;
/// ...and their poses within this many rad (far below the distance between distinct optima).
const SAME_OPTIMUM_POSE: f64 = 1e-6;
/// Times a cold start's optimum is turned back toward `theta0` by whole turns and solved again.
const MAX_TURN_BACKS: usize = 3;
/// Bisections of the scaled start's factor: 2^-60 is below its round-off.
const SCALED_BISECTIONS: usize = 60;
/// Half-width of the range of a random start's unlimited joint around `theta0`, rad: half a
/// turn either way covers every angle once (a quarter turn left the other elbow of a joint bent
/// the wrong way out of reach when a limited joint had to swing across).
const UNLIMITED_START_SPREAD: f64 = std::f64::consts::PI;
/// Random starts are also tried, limits or not, when the best optimum so far turns the joints
/// by at least this much (the root of metric 3, rad): with a quarter turn and more, optima
/// around the other side of a joint's turn lie within that radius, and the fixed and mirrored
/// starts miss some of them (unlimited three-link chains with targets anywhere: 46 of 2,000
/// missed without these starts, 7 with them).
const RANDOM_START_RADIUS: f64 = std::f64::consts::FRAC_PI_2;

/// The intermediate problems of a continuation start whose tip is at `tip0` (see
/// [`Overall::continuation`]): `count` targets equally spaced on the way to `p`'s, straight or
/// (`polar`) with radius and bearing around the base interpolated linearly, each with loose
/// tolerances.
pub(super) fn stages<'a>(
    p: &Problem<'a>,
    tip0: Vec2,
    polar: bool,
    count: usize,
) -> impl Iterator<Item = Problem<'a>> {
    let p = *p;
    let b = p.chain.base();
    let (r0, a0) = ((tip0 - b).norm(), bearing(tip0 - b));
    let (r1, a1) = ((p.target - b).norm(), bearing(p.target - b));
    let da = wrap_angle(a1 - a0);
    (1..=count).map(move |k| {
        let s = k as f64 / (count + 1) as f64;
        let target = if polar {
            let r = r0 + (r1 - r0) * s;
            let a = a0 + da * s;
            b + Vec2::new(r * a.cos(), r * a.sin())
        } else {
            tip0 + (p.target - tip0) * s
        };
        Problem {
            target,
            tol: STAGE_TIP_TOLERANCE * p.scale,
            stol: STAGE_STATIONARITY_TOLERANCE,
            ..p
        }
    })
}

/// splitmix64: a tiny deterministic generator for the seeded cold starts.
pub(crate) struct SplitMix(pub(crate) u64);

impl SplitMix {
    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The kinds of start of a cold solve, in the order they are tried (see
/// [`Overall::solve_cold`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Start {
    /// `clip(theta0)`.
    Clipped,
    /// `clip(theta0)` with the base joint turned so that the tip points toward the target.
    Turned,
    /// Continuation along the straight tip path to the target.
    StraightPath,
    /// Continuation along the polar path around the base.
    PolarPath,
    /// The mirror image of the optimum of this rank so far (0 the best, 1 the second; no
    /// further ones are kept, so later ranks are skipped).
    Mirror(usize),
    /// A seeded pseudo-random pose; `first` for the first of the call, which decides whether
    /// random starts are needed at all.
    Random { first: bool },
    /// Last, when no start has reached the target: the mirror image of the answer that came
    /// closest (it often ends on a limit, on the side of the elbow the limits rule out).
    MirrorMiss,
    /// When no start of the first round has reached the target: the pose on target shaped
    /// like `theta0` ([`Overall::start_scaled`]), for targets near the outer edge.
    Scaled,
}

impl Start {
    /// The deterministic starts before the mirrored ones.
    pub(super) const FIXED: usize = 4;

    /// The start at `index` of a cold solve with `mirrors` mirrored starts.
    pub(super) fn at(index: usize, mirrors: usize) -> Self {
        match index {
            0 => Self::Clipped,
            1 => Self::Turned,
            2 => Self::StraightPath,
            3 => Self::PolarPath,
            k if k < Self::FIXED + mirrors => Self::Mirror(k - Self::FIXED),
            k => Self::Random {
                first: k == Self::FIXED + mirrors,
            },
        }
    }
}

/// The sequence of starts of one cold solve: the fixed and mirrored starts, the random ones
/// (the first decides whether they are needed), when no start so far has reached the target
/// the scaled start and then one more round of random starts, and last the mirror image of the best optimum when a random start found it (the
/// mirrored starts came before it, often before any optimum was known), or, when no start has
/// reached the target, of the closest miss.
pub(super) struct Schedule {
    next: usize,
    end: usize,
    mirrors: usize,
    random: usize,
    second_round: bool,
    /// A random start has found a new best optimum, not mirrored yet.
    mirror_again: bool,
    /// The closest miss has been mirrored.
    mirrored_miss: bool,
    /// The scaled start has been tried.
    scaled: bool,
}

impl Schedule {
    pub(super) fn new(opts: &OverallOptions) -> Self {
        let end = Start::FIXED + opts.mirror_starts + opts.random_starts;
        Self {
            next: 0,
            end,
            mirrors: opts.mirror_starts,
            random: opts.random_starts,
            second_round: false,
            mirror_again: false,
            mirrored_miss: false,
            scaled: false,
        }
    }

    /// Asks for the mirror image of the best optimum at the end (a random start found it).
    pub(super) fn mirror_best_again(&mut self) {
        self.mirror_again = self.mirrors > 0;
    }

    /// The next start, or `None` when done; `reached` says whether a start has reached the
    /// target so far.
    pub(super) fn next(&mut self, reached: bool) -> Option<Start> {
        if self.next >= self.end {
            if !reached && !self.scaled {
                self.scaled = true;
                return Some(Start::Scaled);
            }
            if reached || self.second_round || self.random == 0 {
                if reached && self.mirror_again {
                    self.mirror_again = false;
                    return Some(Start::Mirror(0));
                }
                if !reached && self.mirrors > 0 && !self.mirrored_miss {
                    self.mirrored_miss = true;
                    return Some(Start::MirrorMiss);
                }
                return None;
            }
            self.second_round = true;
            self.end += self.random;
        }
        let index = self.next;
        self.next += 1;
        Some(Start::at(index, self.mirrors))
    }
}

/// What a start of a cold solve produced (its pose lives in the scratch).
#[derive(Debug, Clone, Copy)]
pub(super) struct Candidate {
    pub(super) half_metric: f64,
    /// How far the answer is from what was asked, m: its tip error, plus (among obstacles) the
    /// clearance it lacks. Ranks the answers that are not on target.
    pub(super) miss: f64,
    /// Converged with the tip on target.
    pub(super) on_target: bool,
    pub(super) mu: [f64; 2],
}

impl Candidate {
    /// Whether this answer is better than `other`: on target beats off target, then the lower
    /// metric 3 (on target) or the lower tip error (off target); a tie keeps `other`.
    pub(super) fn beats(&self, other: Option<&Candidate>) -> bool {
        match other {
            None => true,
            Some(o) if self.on_target != o.on_target => self.on_target,
            Some(o) if self.on_target => self.half_metric < o.half_metric,
            Some(o) => self.miss < o.miss,
        }
    }
}

/// The best and second-best distinct answers of a cold solve; their poses are `Work::best` and
/// `Work::second`.
#[derive(Debug, Default)]
pub(super) struct Podium {
    pub(super) best: Option<Candidate>,
    pub(super) second: Option<Candidate>,
}

impl Podium {
    /// Whether some start has reached the target.
    pub(super) fn reached(&self) -> bool {
        self.best.is_some_and(|b| b.on_target)
    }

    /// Ranks the answer `found`, whose pose is `theta`, keeping the poses of the best and the
    /// second in `best` and `second`; the same optimum as the best is dropped.
    pub(super) fn offer(
        &mut self,
        theta: &[f64],
        best: &mut [f64],
        second: &mut [f64],
        found: Candidate,
    ) {
        let m = found.half_metric;
        let same_as_best = self.best.is_some_and(|b| {
            (b.half_metric - m).abs() <= SAME_OPTIMUM_METRIC * (1.0 + m)
                && max_abs_diff(best, theta) < SAME_OPTIMUM_POSE
        });
        if same_as_best {
            return;
        }
        if found.beats(self.best.as_ref()) {
            if self.best.is_some() {
                second.copy_from_slice(best);
                self.second = self.best;
            }
            best.copy_from_slice(theta);
            self.best = Some(found);
        } else if found.beats(self.second.as_ref()) {
            second.copy_from_slice(theta);
            self.second = Some(found);
        }
    }
}

/// What preparing a start of a cold solve decided.
pub(super) enum Loaded {
    /// `w.theta` holds the start; `iterations` were spent preparing it.
    Ready { iterations: usize },
    /// This start does not apply; go on with the next.
    Skip,
    /// No further start can find a better optimum.
    Done,
}

/// The mirror image of the pose `src` across the line from the base through the target (same
/// tip for an unlimited chain), written to `out`: absolute angles `phi -> 2 line - phi`, so
/// `theta_1 -> 2 (line - h) - theta_1` and every later relative angle changes sign. Each angle is
/// taken as the representative within `[lo, hi]` nearest `theta0` (clipped into them when none
/// lies within).
pub(super) fn mirror_pose(p: &Problem, src: &[f64], lo: &[f64], hi: &[f64], out: &mut [f64]) {
    let line = bearing(p.target - p.chain.base());
    for a in 0..out.len() {
        let m = if a == 0 {
            2.0 * (line - p.chain.heading()) - src[0]
        } else {
            -src[a]
        };
        out[a] = representative_within(m, p.theta0[a], lo[a], hi[a]);
    }
}

/// The angle equal to `t` modulo 2 pi within `[lo, hi]` nearest `t0`; when none lies within,
/// the nearest representative clipped into the limits.
pub(super) fn representative_within(t: f64, t0: f64, lo: f64, hi: f64) -> f64 {
    let tau = 2.0 * std::f64::consts::PI;
    let nearest = nearest_representative(t, t0);
    let c = if nearest < lo {
        lo + (t - lo).rem_euclid(tau)
    } else if nearest > hi {
        hi - (hi - t).rem_euclid(tau)
    } else {
        nearest
    };
    if lo <= c && c <= hi {
        c
    } else {
        nearest.clamp(lo, hi)
    }
}

impl Overall {
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
    ///    mirror image across the line from the base to the target (same tip; each angle the
    ///    representative within its limits nearest `theta0`, clipped into them when none lies
    ///    within).
    ///
    /// 6. up to [`OverallOptions::random_starts`] pseudo-random poses from a splitmix64
    ///    generator seeded with [`OverallOptions::seed`] at every call. Any pose better than
    ///    the best optimum so far (metric 3 = `r^2`) lies within `r` of `theta0`, so the starts
    ///    are drawn there: each joint uniform over its limits within `+-r` of `clip(theta0)`,
    ///    pulled onto the ball of radius `r` when outside it (`r` shrinks as better optima are
    ///    found). They are skipped when no limit comes within `r` of `theta0` (the limits cannot
    ///    touch a better pose) and `r` is below a quarter turn (the other starts find the
    ///    optimum of that problem; with larger turns they miss some, on the other side of a
    ///    joint's turn). When no start so far has reached the target, the pose on target
    ///    shaped like `theta0` (every joint after the base scaled by one factor, the base
    ///    turned onto the target: near the outer edge of the workspace the other starts crawl), and if that does not reach it either, the same
    ///    number of random starts again, uniform inside the limits (an unlimited joint: `theta0 +- pi`). A random start stops
    ///    as soon as its iterate is on target within 1e-6 of the scale and within 1e-4 rad of
    ///    the best optimum so far (it would converge to that optimum);
    /// 7. when a random start found the best optimum, its mirror image as in 5; when no start
    ///    reached the target, the mirror image of the answer that came closest (limits that
    ///    rule out one elbow leave the others on a limit, on that elbow's side).
    ///
    /// Nothing here uses the stored multiplier or any other strategy. If no start reaches the
    /// target, the closest reachable tip is sought from the start that came closest.
    /// `iterations` in the outcome is the sum over all starts.
    ///
    /// Among obstacles ([`Overall::set_world`]): the best optimum without them, when it is
    /// clear, is the answer (the clear poses are a part of all poses). Otherwise the best clear
    /// optimum over, in order:
    /// 1. the starts `clip(theta0)`, the optimum without obstacles (which the solve pushes out
    ///    of the obstacles to the nearer side), the two continuations, the mirror images of the
    ///    two best clear optima and of the optimum without obstacles;
    /// 2. the flip starts: the optimum without obstacles with the point of its body nearest an
    ///    obstacle it collides with carried to that obstacle's far side (the tip kept on
    ///    target, the rest of the pose close), one start per such obstacle; then the same from
    ///    the best clear optimum so far, across each obstacle it touches, and again from each
    ///    better optimum one of them finds; at most 24 in all (the clear optima differ mainly
    ///    in which side of each obstacle the body passes, which a local solve keeps);
    /// 3. three times [`OverallOptions::random_starts`] seeded random poses (within
    ///    `sqrt(metric 3)` of `theta0` of the best so far).
    ///
    /// The flip and random starts stop when they run into the best optimum so far, as above,
    /// and give up sooner than the fixed ones when they make no progress.
    pub fn solve_cold(
        &mut self,
        chain: &Chain,
        theta0: &[f64],
        target: Vec2,
        out: &mut [f64],
    ) -> Outcome {
        if self.among_obstacles() {
            self.cold_among(chain, theta0, target, out)
        } else {
            self.free_cold(chain, theta0, target, out)
        }
    }

    /// [`Overall::solve_cold`] without obstacles.
    pub(super) fn free_cold(
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
        let mut podium = Podium::default();
        let mut schedule = Schedule::new(&self.opts);
        let mut rng = SplitMix(self.opts.seed);
        while let Some(start) = schedule.next(podium.reached()) {
            let mut mu = [0.0; 2];
            match self.load_start(&p, start, &podium, &mut rng, &mut mu) {
                Loaded::Ready { iterations } => total += iterations,
                Loaded::Skip => continue,
                Loaded::Done => break,
            }
            // A random start that runs into the best optimum so far is not followed further.
            self.w.watch_best = matches!(start, Start::Random { .. }) && podium.reached();
            let mut l = self.local(&p, &mut mu, p.tol);
            total += l.iterations;
            // A local path can end whole turns away from theta0: the same tip, a larger metric 3.
            // Turned back, the pose is on target but no longer stationary; solved again from
            // there, it settles on an optimum no farther from theta0.
            for _ in 0..MAX_TURN_BACKS {
                if !l.converged {
                    break;
                }
                self.w.turned.copy_from_slice(&self.w.theta);
                let converged_mu = mu;
                if !self.nearest_turns(&p) {
                    break;
                }
                mu = [0.0; 2];
                let again = self.local(&p, &mut mu, p.tol);
                total += again.iterations;
                if !again.converged {
                    self.w.theta.copy_from_slice(&self.w.turned);
                    mu = converged_mu;
                    break;
                }
                l = again;
            }
            // A pose the solve left short of an optimum keeps its tip when turned back by whole
            // turns; its metric 3 only drops.
            if !l.converged && l.exit != Exit::JoinedBest && self.nearest_turns(&p) {
                l.tip_error = (p.chain.tip(&self.w.theta) - p.target).norm();
            }
            self.w.watch_best = false;
            if l.exit == Exit::JoinedBest {
                continue;
            }
            let found = Candidate {
                half_metric: half_metric(&self.w.theta, p.theta0),
                miss: l.tip_error,
                on_target: l.converged && l.tip_error <= p.tol,
                mu,
            };
            let w = &mut self.w;
            let new_best = found.on_target && found.beats(podium.best.as_ref());
            podium.offer(&w.theta, &mut w.best, &mut w.second, found);
            if new_best && matches!(start, Start::Random { .. }) {
                schedule.mirror_best_again();
            }
        }
        let Some(best) = podium.best else {
            return self.finish(&p, [0.0; 2], total, false, out);
        };
        self.w.theta.copy_from_slice(&self.w.best);
        let mut mu = best.mu;
        let mut converged = best.on_target;
        if !best.on_target {
            let (its, conv) = self.closest(&p, &mut mu);
            total += its;
            converged = conv;
        }
        self.finish(&p, mu, total, converged, out)
    }

    /// Loads the pose of `start` into `w.theta` (a continuation start solves its stages into
    /// `mu`, which the final local solve continues from).
    pub(super) fn load_start(
        &mut self,
        p: &Problem,
        start: Start,
        podium: &Podium,
        rng: &mut SplitMix,
        mu: &mut [f64; 2],
    ) -> Loaded {
        match start {
            Start::Clipped => self.start_clipped(p),
            Start::Turned => self.start_turned(p),
            Start::StraightPath | Start::PolarPath => {
                self.start_clipped(p);
                if self.opts.continuation_stages == 0 {
                    return Loaded::Skip;
                }
                let polar = matches!(start, Start::PolarPath);
                let iterations = self.continuation(p, polar, mu);
                return Loaded::Ready { iterations };
            }
            Start::Mirror(rank) => {
                let source = match rank {
                    0 => podium.best,
                    1 => podium.second,
                    _ => None,
                };
                if !source.is_some_and(|s| s.on_target) {
                    return Loaded::Skip;
                }
                let w = &mut self.w;
                let src = if rank == 0 { &w.best } else { &w.second };
                mirror_pose(p, src, &w.lo, &w.hi, &mut w.theta);
            }
            Start::Scaled => {
                if !self.start_scaled(p) {
                    return Loaded::Skip;
                }
            }
            Start::MirrorMiss => {
                if podium.best.is_none() {
                    return Loaded::Skip;
                }
                let w = &mut self.w;
                mirror_pose(p, &w.best, &w.lo, &w.hi, &mut w.theta);
            }
            Start::Random { first } => {
                // Any pose better than the best optimum so far lies within the ball of
                // radius sqrt(metric 3) around theta0. Neither a limit within it nor a quarter
                // turn: the other starts have found the optimum.
                let radius = podium
                    .best
                    .filter(|b| b.on_target)
                    .map(|b| (2.0 * b.half_metric).sqrt());
                match radius {
                    Some(r)
                        if first && !self.limits_reach_ball(p, r) && r < RANDOM_START_RADIUS =>
                    {
                        return Loaded::Done
                    }
                    Some(r) => self.start_in_ball(p, r, rng),
                    None => self.start_in_box(p, rng),
                }
            }
        }
        Loaded::Ready { iterations: 0 }
    }

    /// Moves each joint of `w.theta` by whole turns to the value within its limits nearest
    /// `theta0` (the tip stays where it is); true when some joint moved.
    pub(super) fn nearest_turns(&mut self, p: &Problem) -> bool {
        let w = &mut self.w;
        let mut moved = false;
        for a in 0..w.n {
            let (t, t0) = (w.theta[a], p.theta0[a]);
            let c = representative_within(t, t0, w.lo[a], w.hi[a]);
            // Only whole turns count: a move of round-off is not one.
            if (c - t).abs() > std::f64::consts::PI && (c - t0).abs() < (t - t0).abs() {
                w.theta[a] = c;
                moved = true;
            }
        }
        moved
    }

    /// Loads `clip(theta0)` as the current iterate.
    pub(super) fn start_clipped(&mut self, p: &Problem) {
        for a in 0..p.theta0.len() {
            self.w.theta[a] = p.theta0[a].clamp(self.w.lo[a], self.w.hi[a]);
        }
    }

    /// Loads `clip(theta0)` with the base joint turned so that the tip points from the base
    /// toward the target (clipped into the base joint's limits).
    pub(super) fn start_turned(&mut self, p: &Problem) {
        self.start_clipped(p);
        let base = p.chain.base();
        let from = bearing(p.chain.tip(&self.w.theta) - base);
        let to = bearing(p.target - base);
        let turn = wrap_angle(to - from);
        self.w.theta[0] = (self.w.theta[0] + turn).clamp(self.w.lo[0], self.w.hi[0]);
    }

    /// Loads a pose on target shaped like `theta0`: every joint after the base scaled by the
    /// one factor `s` in `[0, 1]` that puts the tip at the target's distance from the base
    /// (found by bisection: `s = 0` is the straight arm, at the full reach, `s = 1` is `theta0`
    /// clipped), then the base joint turned to point the tip at the target. Near the outer edge
    /// of the workspace the local path from `theta0` crawls (the tip constraint is nearly
    /// singular there); this start lies on the thin set of poses that reach the target. False,
    /// with `w.theta` unspecified, when the target is not between the two distances, or the
    /// base joint's limits keep the tip off the target's bearing.
    pub(super) fn start_scaled(&mut self, p: &Problem) -> bool {
        let base = p.chain.base();
        let want = (p.target - base).norm();
        let at = |s: f64, w: &mut super::Work| {
            w.theta[0] = p.theta0[0].clamp(w.lo[0], w.hi[0]);
            for a in 1..p.theta0.len() {
                w.theta[a] = (s * p.theta0[a]).clamp(w.lo[a], w.hi[a]);
            }
            (p.chain.tip(&w.theta) - base).norm()
        };
        let (mut lo_s, mut hi_s) = (0.0, 1.0);
        let (d_lo, d_hi) = (at(lo_s, &mut self.w), at(hi_s, &mut self.w));
        if !(d_hi <= want && want <= d_lo) {
            return false;
        }
        for _ in 0..SCALED_BISECTIONS {
            let mid = 0.5 * (lo_s + hi_s);
            if at(mid, &mut self.w) >= want {
                lo_s = mid;
            } else {
                hi_s = mid;
            }
        }
        at(lo_s, &mut self.w);
        let from = bearing(p.chain.tip(&self.w.theta) - base);
        let turned = self.w.theta[0] + wrap_angle(bearing(p.target - base) - from);
        let t = representative_within(turned, p.theta0[0], self.w.lo[0], self.w.hi[0]);
        self.w.theta[0] = t;
        wrap_angle(t - turned).abs() < 1e-12
    }

    /// A continuation start from the pose in `w.theta`: solves
    /// [`OverallOptions::continuation_stages`] equally spaced intermediate targets on the path
    /// from its tip to the target, straight or (`polar`) with radius and bearing around the base
    /// interpolated linearly, each from the previous answer and with loose tolerances. Returns
    /// the iterations spent.
    pub(super) fn continuation(&mut self, p: &Problem, polar: bool, mu: &mut [f64; 2]) -> usize {
        let tip0 = p.chain.tip(&self.w.theta);
        let mut iterations = 0;
        for sub in stages(p, tip0, polar, self.opts.continuation_stages) {
            iterations += self.local(&sub, mu, sub.tol).iterations;
        }
        iterations
    }

    /// Whether some limit comes within `r` of `theta0` (or `theta0` lies outside its limits):
    /// only then can a limit touch a pose with metric 3 below `r^2`.
    pub(super) fn limits_reach_ball(&self, p: &Problem, r: f64) -> bool {
        (0..p.theta0.len()).any(|a| {
            let t = p.theta0[a];
            !(self.w.lo[a] < t - r && t + r < self.w.hi[a])
        })
    }

    /// A pseudo-random start inside the limits and within `r` of `clip(theta0)` (where every
    /// pose with metric 3 below `r^2` lies): each joint uniform over its limits within
    /// `+-r`, then pulled toward `clip(theta0)` onto the ball if outside it.
    pub(super) fn start_in_ball(&mut self, p: &Problem, r: f64, rng: &mut SplitMix) {
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

    /// A pseudo-random start uniform inside the limits (an unlimited joint: `theta0 +- pi`),
    /// for when no start has reached the target yet.
    pub(super) fn start_in_box(&mut self, p: &Problem, rng: &mut SplitMix) {
        for a in 0..p.theta0.len() {
            let u = rng.unit();
            let (lo, hi) = (self.w.lo[a], self.w.hi[a]);
            self.w.theta[a] = if lo.is_finite() && hi.is_finite() {
                lo + (hi - lo) * u
            } else {
                (p.theta0[a] + UNLIMITED_START_SPREAD * (2.0 * u - 1.0)).clamp(lo, hi)
            };
        }
    }
}
