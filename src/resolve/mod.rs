//! Redundancy resolution: from a commanded tip target to joint angles.
//!
//! Two strategies from Banerjee, Menon, Ananthasuresh and Ghosal (2011):
//! - [`sequential`]: the tip moves in a straight line and each link's tail follows the tractrix
//!   of its head ([`tractrix`]), propagated from the tip to the base; a fixed base is restored by
//!   a correction scheme.
//! - `overall`: one optimization over the whole arm minimizing metric 3, the sum of squared joint
//!   rotations, subject to the tip on target and the joint limits, and, given a world of
//!   obstacles ([`overall::Overall::set_world`]), every link keeping its clearance from them.
//!
//! Both implement [`Resolver`], which a control loop calls every tick with the current pose and
//! the next tip target. [`solve_steps`] splits a long move into straight sub-moves for either.

pub mod overall;
pub mod sequential;
pub mod tractrix;

#[cfg(test)]
mod props;

use crate::chain::{Chain, LimitViolation, Vec2};

/// Which strategy resolves the redundancy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Strategy {
    /// Tractrix (or distance-minimization) propagation from tip to base.
    Sequential,
    /// Minimum metric 3 over the whole arm.
    Overall,
}

impl Strategy {
    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Sequential => "sequential",
            Strategy::Overall => "overall",
        }
    }
}

/// How good a resolved pose is. Returned with every answer, including the imperfect ones.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Distance from the tip of the returned pose to the target, m.
    pub tip_error: f64,
    /// Distance from the base of the returned pose to the chain's base, m (0 for a pose given as
    /// angles, where the base is fixed by construction).
    pub base_error: f64,
    /// Whether the target is reachable (as far as the resolver could establish).
    pub reachable: bool,
    /// Whether the resolver met its tolerance before its iteration cap.
    pub converged: bool,
    /// Correction rounds (sequential) or solver iterations (overall).
    pub iterations: usize,
}

/// Why a resolver refused to move the pose. The caller's pose is untouched whenever one of these
/// is returned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ResolveError {
    /// The target lies outside the workspace; the tip would stop `distance` m short of it.
    #[error("target unreachable: the closest pose found leaves the tip {tip_error:.3e} m away")]
    Unreachable {
        /// Tip error of the closest pose found, m.
        tip_error: f64,
    },
    /// The iteration cap was hit before the tolerance was met.
    #[error(
        "not converged after {iterations} iterations: tip error {tip_error:.3e} m, \
         base error {base_error:.3e} m"
    )]
    NotConverged {
        /// Iterations spent.
        iterations: usize,
        /// Tip error of the best pose found, m.
        tip_error: f64,
        /// Base error of the best pose found, m.
        base_error: f64,
    },
    /// The resolved pose would leave a joint outside its limits.
    #[error("resolved pose rejected: {0}")]
    Limit(#[from] LimitViolation),
    /// A target or pose that is not a finite number, or a pose of the wrong length.
    #[error("bad input: {0}")]
    BadInput(String),
}

/// A redundancy-resolution strategy a control loop can call every tick.
pub trait Resolver {
    /// The strategy this resolver implements.
    fn strategy(&self) -> Strategy;

    /// Best effort: writes into `out` the best pose found for moving the tip of `chain` from the
    /// pose `theta0` to `target`, and says how good it is. Never fails; the flags say when the
    /// answer is imperfect. `out` has one entry per joint.
    fn solve(&mut self, chain: &Chain, theta0: &[f64], target: Vec2, out: &mut [f64]) -> Outcome;

    /// Control-loop form: moves `theta` to a pose whose tip is on `target`, or returns an error
    /// and leaves `theta` untouched (bad input, unreachable, not converged, limits violated).
    fn resolve(
        &mut self,
        chain: &Chain,
        theta: &mut [f64],
        target: Vec2,
    ) -> Result<Outcome, ResolveError> {
        check_input(chain, theta, target)?;
        let mut candidate = std::mem::take(self.scratch_pose());
        candidate.resize(chain.len(), 0.0);
        let outcome = self.solve(chain, theta, target, &mut candidate);
        let result = verdict(chain, &candidate, outcome);
        if result.is_ok() {
            theta.copy_from_slice(&candidate);
        }
        *self.scratch_pose() = candidate;
        result
    }

    /// Whether the last solve failed for want of clearance: it ended with a link at the
    /// clearance it must keep from an obstacle (the body caught), not for the target's reach.
    /// Only a resolver that keeps clear of obstacles says so.
    fn held_by_obstacle(&self) -> bool {
        false
    }

    /// Where [`Resolver::resolve`] keeps the candidate pose between ticks, so a control loop
    /// allocates nothing once warmed up.
    fn scratch_pose(&mut self) -> &mut Vec<f64>;
}

/// Checks the arguments every resolver receives: one finite angle per joint, a finite target.
pub fn check_input(chain: &Chain, theta: &[f64], target: Vec2) -> Result<(), ResolveError> {
    if theta.len() != chain.len() {
        return Err(ResolveError::BadInput(format!(
            "{} angles for {} joints",
            theta.len(),
            chain.len()
        )));
    }
    if let Some(i) = theta.iter().position(|t| !t.is_finite()) {
        return Err(ResolveError::BadInput(format!(
            "joint {} angle is not finite",
            i + 1
        )));
    }
    if !(target.x.is_finite() && target.y.is_finite()) {
        return Err(ResolveError::BadInput("target is not finite".into()));
    }
    Ok(())
}

/// Turns a best-effort [`Outcome`] into the control-loop verdict: `Ok` only when the pose is on
/// target, converged and within the limits.
pub fn verdict(chain: &Chain, pose: &[f64], outcome: Outcome) -> Result<Outcome, ResolveError> {
    if !outcome.reachable {
        return Err(ResolveError::Unreachable {
            tip_error: outcome.tip_error,
        });
    }
    if !outcome.converged {
        return Err(ResolveError::NotConverged {
            iterations: outcome.iterations,
            tip_error: outcome.tip_error,
            base_error: outcome.base_error,
        });
    }
    chain.check_limits(pose)?;
    Ok(outcome)
}

/// Moves the tip from its position at `theta0` to `target` in `steps` equal straight sub-moves,
/// each resolved from the previous one's answer. The final pose is written to `out`; iterations
/// are summed, the flags are those of the last sub-move (an earlier miss is carried as
/// `converged = false`).
///
/// # Panics
/// If `steps == 0` or the slice lengths differ from the chain's joint count.
pub fn solve_steps<R: Resolver + ?Sized>(
    resolver: &mut R,
    chain: &Chain,
    theta0: &[f64],
    target: Vec2,
    steps: usize,
    out: &mut [f64],
) -> Outcome {
    assert!(steps > 0, "at least one step");
    let start = chain.tip(theta0);
    let mut current = theta0.to_vec();
    let mut iterations = 0;
    let mut all_converged = true;
    let mut last = None;
    for k in 1..=steps {
        let sub = start + (target - start) * (k as f64 / steps as f64);
        let o = resolver.solve(chain, &current, sub, out);
        iterations += o.iterations;
        all_converged &= o.converged;
        current.copy_from_slice(out);
        last = Some(o);
    }
    let mut o = last.unwrap_or(Outcome {
        tip_error: (start - target).norm(),
        base_error: 0.0,
        reachable: false,
        converged: false,
        iterations: 0,
    });
    o.iterations = iterations;
    o.converged = all_converged && o.converged;
    o
}
