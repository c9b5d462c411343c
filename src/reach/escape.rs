//! The way out of an obstacle put onto the arm, before a `reach` plans its way round.
//!
//! Where an obstacle was put onto the arm, the controller carries out only motion that takes no
//! link closer to any obstacle than it has been since (each pair of link and obstacle below the
//! clearance may only gain, a pair at or above it must keep it), and once the arm is clear, its
//! goals as sent keep the clearance too. The way out keeps the first rule at every pose along
//! it. The second it keeps from where the pose is clear by what rounding may take
//! (`Chain::rounding_m`): nearer the clearance, almost every step rounds some goal back
//! within it, so no way out would be found; the controller looks at its ticks' goals only,
//! which seldom meet those, and one that did would end the reach `blocked`, clear.
//!
//! 1. **Steps** ([`STEP_M`] of sweep at most): each the least joint motion (least squares,
//!    damped) that raises every pair below the aim to it, to first order, while the pairs above
//!    it are held from falling below it; joints clamped to their limits. The aim: the larger of
//!    a tree node's clearance and what rounding may take, plus [`BEYOND_M`]. A step whose
//!    straight way breaks the rule is halved, down to [`MIN_STEP_FRACTION`].
//! 2. **Legs**: steps are joined into one straight leg (one step further, two, four, ...) while
//!    that leg keeps the rule, since the arm comes to rest at each leg's end. The last leg ends
//!    where the pose is clear by the margin, as a tree node (the way round starts there).
//!
//! The rule is checked at poses every [`LOOK_M`] of sweep, each pair against the best it has had
//! so far along the way out (less [`ROUNDOFF_M`]).

use nalgebra::{DMatrix, DVector};

use super::{Looker, ReachError, ReachRequest};
use crate::chain::Chain;
use crate::world::ActivePairs;

/// The most any point of the arm moves in one step, m: short enough that each pair's clearance
/// changes as its gradient says.
const STEP_M: f64 = 0.005;

/// How far beyond a tree node's clearance the steps aim, m: the last step lands clear of it.
const BEYOND_M: f64 = 5e-4;

/// Spacing of the looks along a leg out, m of sweep: far finer than a control tick's motion
/// near an obstacle.
const LOOK_M: f64 = 1e-4;

/// How much a pair may lose against the best it has had between two looks, m: round-off only
/// (the controller allows ten times this).
const ROUNDOFF_M: f64 = 1e-10;

/// The most steps before giving up.
const MAX_STEPS: usize = 400;

/// The least share of a step tried before giving up.
const MIN_STEP_FRACTION: f64 = 1.0 / 64.0;

/// Damping of the least-squares step, m^2: keeps it finite where two pairs pull alike.
const DAMPING: f64 = 1e-8;

/// What the rule remembers along the way out.
#[derive(Debug, Clone)]
struct Rule {
    /// Per pair (`(link - 1) * obstacles + k`), the best of `min(clearance_m, the pair's
    /// clearance)` so far.
    best: Vec<f64>,
    /// The arm has been clear by what rounding may take (`Chain::rounding_m`) at a pose
    /// looked at: from there on the poses as sent keep the clearance as well.
    held: bool,
    /// Scratch: the floors of the pose looked at.
    now: Vec<f64>,
}

/// The legs out of the obstacles from `req.from` (not clear): each leg's end, the last clear by
/// the margin ([`Looker::node`]). [`ReachError::NotClearNow`] when none is found within
/// [`MAX_STEPS`] steps, naming the pair that is deepest where the arm stands.
pub(super) fn way_out(look: &mut Looker, req: &ReachRequest) -> Result<Vec<Vec<f64>>, ReachError> {
    let chain = req.chain;
    let world = req.world;
    let keep = world.clearance_m();
    let m = world.obstacles().len();
    let points = chain.points(req.from);
    let mut start = Rule {
        best: vec![keep; chain.len() * m],
        held: false,
        now: vec![keep; chain.len() * m],
    };
    world.link_floors(&points, keep, &mut start.best);
    let refused = || {
        let p = world.clearance(&points);
        ReachError::NotClearNow {
            link: p.map_or(chain.len(), |p| p.link),
            obstacle: p.map_or(String::new(), |p| p.id(world).to_string()),
            clearance_m: p.map_or(f64::NAN, |p| p.clearance_m),
            keep_m: keep,
        }
    };

    // 1. Steps, each checked. They go out as far as rounding may take, so that the goals as
    //    sent are held to the clearance before the way round starts.
    let aim = look.node_keep.max(keep + look.rounding_m) + BEYOND_M;
    let mut rule = start.clone();
    let mut steps = vec![req.from.to_vec()];
    let mut pairs = ActivePairs::new();
    let mut here = req.from.to_vec();
    let mut next = here.clone();
    loop {
        if look.node(&here) {
            break;
        }
        if steps.len() > MAX_STEPS || look.out_of_work() {
            return Err(refused());
        }
        let Some(d) = step(chain, world, &here, aim, &mut pairs) else {
            return Err(refused());
        };
        let mut share = 1.0;
        loop {
            for (((x, &h), &dx), lim) in next.iter_mut().zip(&here).zip(&d).zip(chain.limits()) {
                *x = h + share * dx;
                if let Some(l) = lim {
                    *x = x.clamp(l.lo, l.hi);
                }
            }
            let mut tried = rule.clone();
            if next != here && keeps_rule(look, &here, &next, &mut tried) {
                rule = tried;
                break;
            }
            share *= 0.5;
            if share < MIN_STEP_FRACTION {
                return Err(refused());
            }
        }
        here.clone_from(&next);
        steps.push(here.clone());
    }

    // 2. Legs: the longest straight runs that keep the rule; the steps themselves where a run
    //    joined before changes what a later one must keep.
    let mut legs = Vec::new();
    let mut rule = start;
    let mut at = 0;
    while at + 1 < steps.len() {
        // Galloping: one step further, two, four, ... while the run keeps the rule.
        let (mut end, mut kept) = (None, None);
        let mut stride = 1;
        while at + stride < steps.len() {
            let j = at + stride;
            let mut tried = rule.clone();
            if !keeps_rule(look, &steps[at], &steps[j], &mut tried) {
                break;
            }
            (end, kept) = (Some(j), Some(tried));
            stride = if j + 1 == steps.len() {
                break;
            } else {
                (2 * stride).min(steps.len() - 1 - at)
            };
        }
        let (Some(j), Some(r)) = (end, kept) else {
            return Ok(steps.split_off(1));
        };
        legs.push(steps[j].clone());
        rule = r;
        at = j;
    }
    Ok(legs)
}

/// The step from `theta` (see the module doc), scaled to at most [`STEP_M`] of sweep; `None`
/// when no pair is below `aim` (nothing to gain) or it is not finite.
fn step(
    chain: &Chain,
    world: &crate::world::World,
    theta: &[f64],
    aim: f64,
    pairs: &mut ActivePairs,
) -> Option<Vec<f64>> {
    let n = chain.len();
    let points = chain.points(theta);
    world.active_pairs(&points, aim + STEP_M, pairs);
    // Rows: every pair below `aim` (to be raised to it), then each pair above it that the step
    // would take below it (held at it), in rounds.
    let mut rows: Vec<(usize, f64)> = pairs
        .pairs()
        .iter()
        .enumerate()
        .filter(|(_, p)| p.clearance_m < aim)
        .map(|(k, p)| (k, aim - p.clearance_m))
        .collect();
    if rows.is_empty() {
        return None;
    }
    let mut d = DVector::zeros(n);
    for _ in 0..4 {
        let g = DMatrix::from_fn(rows.len(), n, |r, j| pairs.gradient(rows[r].0)[j]);
        let want = DVector::from_iterator(rows.len(), rows.iter().map(|&(_, w)| w));
        let gram = &g * g.transpose() + DMatrix::identity(rows.len(), rows.len()) * DAMPING;
        let y = gram.cholesky()?.solve(&want);
        d = g.transpose() * y;
        let before = rows.len();
        for (k, p) in pairs.pairs().iter().enumerate() {
            let gain: f64 = pairs
                .gradient(k)
                .iter()
                .zip(d.iter())
                .map(|(a, b)| a * b)
                .sum();
            if p.clearance_m >= aim
                && p.clearance_m + gain < aim
                && !rows.iter().any(|&(r, _)| r == k)
            {
                rows.push((k, aim - p.clearance_m));
            }
        }
        if rows.len() == before {
            break;
        }
    }
    let mut d: Vec<f64> = d.iter().copied().collect();
    let to: Vec<f64> = theta.iter().zip(&d).map(|(t, x)| t + x).collect();
    let sweep = chain.sweep(theta, &to);
    if !sweep.is_finite() || sweep <= 0.0 {
        return None;
    }
    if sweep > STEP_M {
        d.iter_mut().for_each(|x| *x *= STEP_M / sweep);
    }
    Some(d)
}

/// Whether the straight leg from `a` to `b` keeps the rule (see the module doc), which it
/// carries on in `rule`; false, too, when the work allowed runs out.
fn keeps_rule(look: &mut Looker, a: &[f64], b: &[f64], rule: &mut Rule) -> bool {
    let world = look.world;
    let keep = world.clearance_m();
    let looks = ((look.chain.sweep(a, b) / LOOK_M).ceil() as usize).max(1);
    let mut last = 0.0;
    for k in 1..=looks {
        if look.out_of_work() {
            return false;
        }
        look.checks += 1;
        let f = k as f64 / looks as f64;
        for ((x, &p), &q) in look.pose.iter_mut().zip(a).zip(b) {
            *x = p + f * (q - p);
        }
        look.chain.points_into(&look.pose, &mut look.points);
        if Chain::self_intersects(&look.points).is_some() {
            return false;
        }
        world.link_floors(&look.points, keep, &mut rule.now);
        for (best, &now) in rule.best.iter_mut().zip(&rule.now) {
            if now < *best - ROUNDOFF_M {
                return false;
            }
            *best = best.max(now);
        }
        let least = world
            .clearance(&look.points)
            .map_or(f64::INFINITY, |p| p.clearance_m);
        let near = least < keep + look.rounding_m;
        if rule.held && near && !look.quanta.is_empty() && !look.sent_clear(a, b, last, f) {
            return false;
        }
        rule.held |= !near;
        last = f;
    }
    true
}
