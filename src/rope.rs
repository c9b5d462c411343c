//! Overall optimization of a free rope (DESIGN 3.6): the pulled end `p_n` is put on its target,
//! the free end `p_0` follows, every link keeps its length exactly, and one objective chosen
//! among the paper's metrics is minimized over the whole rope.
//!
//! # Formulation
//! The state is the pulled end plus the absolute link angles `phi_1..phi_n`:
//! `p_n = target`, `p_{k-1} = p_k - L_k (cos phi_k, sin phi_k)`. Lengths and the tip constraint
//! hold by construction (to one rounding of the coordinates), so the problem is unconstrained in
//! `phi`; there is nothing to renormalize and no multiplier to estimate. The objectives:
//! - `M1`, `M4`: sums of weighted squared displacements (smooth);
//! - `M2 = sum ds_j |p_j - q_j|`, which is not differentiable where a point does not move. It is
//!   replaced by `M2_eps = sum ds_j (sqrt(|p_j - q_j|^2 + eps^2) - eps)`, with
//!   `M2_eps <= M2 <= M2_eps + eps * Lambda` (`Lambda` the rope's length), minimized for a
//!   decreasing sequence of `eps` (each stage warm-started from the last) down to
//!   [`RopeOptions::smoothing_final`] times the pulled end's displacement;
//! - `M3 + w M1`, `M5 + w M1`: joint rotations need a positional companion, since any rigid
//!   motion that puts the tip on target (translate, then turn about the tip) scores 0 in `M3`
//!   and `M5`: a one-parameter family of minimizers, a singular Hessian, and a rope that just
//!   translates. Rotations enter unwrapped (continuous from the seed); the reported metrics wrap
//!   them, which agrees while every joint turns by less than pi.
//!
//! # Method
//! Damped Newton with the exact Hessian. Seen from the pulled end the rope is a discrete-time
//! system (state `p_k`, control `phi_k`), so the Newton system is an LQ problem whose Riccati
//! recursion eliminates one angle per link with 4 x 4 algebra: O(n) per iteration. Its pivots
//! are those of the LDL^T factorization of `H + lambda I`, so a non-positive pivot proves the
//! Hessian indefinite and raises the damping `lambda` (Levenberg-Marquardt); damping falls back
//! to 0 near the minimum, where the convergence is quadratic. An Armijo backtracking line
//! search on the objective makes every accepted step a descent step.
//!
//! The seed is the better of the two sequential motions (closed-form tractrix and the paper's
//! distance step) under the chosen objective; the better of the seed and the optimum (by the
//! exact metric) is returned, so the answer is never worse than either sequential one.
//!
//! # Stopping rule
//! A stage stops when the Newton decrement `-g . dx` (twice the predicted decrease) falls below
//! [`RopeOptions::decrement_tolerance`] times the seed's objective, or when the line search can
//! no longer lower the objective (round-off) while the decrement is below 1e3 times that
//! tolerance; hitting [`RopeOptions::max_iterations`] in a stage flags the answer as not
//! converged. [`RopeReport`] carries the residuals.

use crate::chain::{nearest_representative, Vec2};
use crate::metrics::{self, Metrics};
use crate::resolve::sequential::sweep;
use crate::resolve::tractrix::Propagation;

/// The objective of the overall rope optimization.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Objective {
    /// Sum of squared point displacements.
    M1,
    /// The paper's area functional (smoothed, with a vanishing smoothing parameter).
    M2,
    /// Squared joint rotations plus `companion_weight` times M1.
    M3 {
        /// Weight of M1, rad^2/m^2; positive.
        companion_weight: f64,
    },
    /// Squared displacements weighted by arc length from the tip.
    M4,
    /// Length-weighted squared joint rotations plus `companion_weight` times M1.
    M5 {
        /// Weight of M1, rad^2/m; positive.
        companion_weight: f64,
    },
}

impl Objective {
    /// The paper's metric number 1..=5.
    pub fn number(self) -> usize {
        match self {
            Objective::M1 => 1,
            Objective::M2 => 2,
            Objective::M3 { .. } => 3,
            Objective::M4 => 4,
            Objective::M5 { .. } => 5,
        }
    }

    /// The name used in files: `m1`..`m5`.
    pub fn name(self) -> &'static str {
        ["m1", "m2", "m3", "m4", "m5"][self.number() - 1]
    }

    /// The M1 weight of M3/M5, `None` for the positional objectives.
    pub fn companion_weight(self) -> Option<f64> {
        match self {
            Objective::M3 { companion_weight } | Objective::M5 { companion_weight } => {
                Some(companion_weight)
            }
            _ => None,
        }
    }

    /// Builds an objective from its name and companion weight, which M3 and M5 require and the
    /// others refuse.
    pub fn from_name(name: &str, companion_weight: Option<f64>) -> Result<Self, ObjectiveError> {
        let needs = matches!(name, "m3" | "m5");
        let weight = match (needs, companion_weight) {
            (true, None) => {
                return Err(ObjectiveError::MissingWeight {
                    objective: name.into(),
                })
            }
            (false, Some(w)) => {
                return Err(ObjectiveError::UnexpectedWeight {
                    objective: name.into(),
                    weight: w,
                })
            }
            (true, Some(w)) if !(MIN_COMPANION_WEIGHT..=MAX_COMPANION_WEIGHT).contains(&w) => {
                return Err(ObjectiveError::BadWeight { weight: w })
            }
            (_, w) => w.unwrap_or(0.0),
        };
        match name {
            "m1" => Ok(Objective::M1),
            "m2" => Ok(Objective::M2),
            "m3" => Ok(Objective::M3 {
                companion_weight: weight,
            }),
            "m4" => Ok(Objective::M4),
            "m5" => Ok(Objective::M5 {
                companion_weight: weight,
            }),
            other => Err(ObjectiveError::Unknown { name: other.into() }),
        }
    }

    /// The exact value of this objective from the five metrics of a motion.
    pub fn value(self, m: &Metrics) -> f64 {
        match self {
            Objective::M1 => m.m1,
            Objective::M2 => m.m2,
            Objective::M3 { companion_weight } => m.m3 + companion_weight * m.m1,
            Objective::M4 => m.m4,
            Objective::M5 { companion_weight } => m.m5 + companion_weight * m.m1,
        }
    }
}

/// The smallest companion weight: below it M1 is lost in the round-off of M3 or M5 and the
/// objective is as degenerate as without a companion.
pub const MIN_COMPANION_WEIGHT: f64 = 1e-6;
/// The largest companion weight: above it M3 or M5 is lost in the round-off of M1.
pub const MAX_COMPANION_WEIGHT: f64 = 1e6;

/// A refused objective specification.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ObjectiveError {
    /// Not one of `m1`..`m5`.
    #[error("unknown objective {name:?} (expected \"m1\", \"m2\", \"m3\", \"m4\" or \"m5\")")]
    Unknown {
        /// The name given.
        name: String,
    },
    /// M3 or M5 without the weight of its positional companion.
    #[error(
        "{objective} needs a companion weight: a rigid motion scores 0, so {objective} alone \
         has no unique minimum"
    )]
    MissingWeight {
        /// The objective.
        objective: String,
    },
    /// A companion weight given to an objective that takes none.
    #[error("{objective} takes no companion weight (got {weight:?})")]
    UnexpectedWeight {
        /// The objective.
        objective: String,
        /// The weight given.
        weight: f64,
    },
    /// A weight outside [`MIN_COMPANION_WEIGHT`, `MAX_COMPANION_WEIGHT`].
    #[error(
        "companion weight {weight:?} must be from {MIN_COMPANION_WEIGHT:e} to \
         {MAX_COMPANION_WEIGHT:e}"
    )]
    BadWeight {
        /// The weight given.
        weight: f64,
    },
}

/// Why the optimizer refused to run or gave up. Bad input leaves the output untouched.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RopeError {
    /// The point list does not have one more entry than the link list, or is empty.
    #[error("{points} points for {links} links (need links + 1, at least 2)")]
    Shape {
        /// Points given.
        points: usize,
        /// Links given.
        links: usize,
    },
    /// A coordinate or target that is not finite.
    #[error("point {index} or the target is not finite")]
    NotFinite {
        /// Index of the first bad point (`points.len()` for the target).
        index: usize,
    },
    /// A link that is not positive and finite, or whose old points disagree with its length.
    #[error("link {link}: length {length} m, old points {measured} m apart")]
    BadLink {
        /// 1-based link index.
        link: usize,
        /// Length given.
        length: f64,
        /// Distance between the old points.
        measured: f64,
    },
    /// The iteration cap was reached before the stopping rule was met.
    #[error(
        "not converged after {iterations} iterations: gradient {gradient:.3e}, \
         Newton decrement {decrement:.3e}"
    )]
    NotConverged {
        /// Iterations spent.
        iterations: usize,
        /// Largest gradient component at the answer.
        gradient: f64,
        /// Newton decrement at the answer.
        decrement: f64,
    },
}

/// Tuning of the optimizer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RopeOptions {
    /// Iteration cap per stage (one stage for smooth objectives; one per smoothing level for M2).
    pub max_iterations: usize,
    /// A stage stops when the Newton decrement is below this times the seed's objective.
    pub decrement_tolerance: f64,
    /// M2: first smoothing parameter, relative to the pulled end's displacement.
    pub smoothing_start: f64,
    /// M2: last smoothing parameter, relative to the pulled end's displacement.
    pub smoothing_final: f64,
    /// M2: ratio between consecutive smoothing parameters (below 1).
    pub smoothing_ratio: f64,
}

impl Default for RopeOptions {
    fn default() -> Self {
        Self {
            max_iterations: 200,
            decrement_tolerance: 1e-12,
            smoothing_start: 0.1,
            smoothing_final: 1e-9,
            smoothing_ratio: 0.1,
        }
    }
}

/// What one optimization achieved. Residuals are measured on the returned points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RopeReport {
    /// The exact objective (metrics as in [`crate::metrics::rope`]) of the answer.
    pub objective: f64,
    /// The exact objective of the seed: the better of the two sequential motions.
    pub seed_objective: f64,
    /// Newton iterations over all stages.
    pub iterations: usize,
    /// Smoothing stages (1 for smooth objectives).
    pub stages: usize,
    /// Largest gradient component of the (last smoothed) objective at the optimum, per rad.
    pub gradient: f64,
    /// Newton decrement `-g . dx` at the optimum.
    pub decrement: f64,
    /// Last smoothing parameter of M2, m (0 for the smooth objectives).
    pub smoothing: f64,
    /// Bound on the gap between M2 and its smoothed form: `smoothing * Lambda`, m^2.
    pub smoothing_gap: f64,
    /// Largest `| |p_k - p_{k-1}| - L_k |` of the answer, m.
    pub length_residual: f64,
    /// Distance from the answer's pulled end to the target, m.
    pub tip_residual: f64,
    /// Whether every stage met the stopping rule.
    pub converged: bool,
    /// True when the seed was kept because the optimum did not beat it (round-off, smoothing).
    pub kept_seed: bool,
}

impl RopeReport {
    /// `Ok` when converged, else the [`RopeError::NotConverged`] with the numbers.
    pub fn check(&self) -> Result<(), RopeError> {
        if self.converged {
            Ok(())
        } else {
            Err(RopeError::NotConverged {
                iterations: self.iterations,
                gradient: self.gradient,
                decrement: self.decrement,
            })
        }
    }
}

/// Largest length error and the tip error of a rope configuration.
pub fn residuals(points: &[Vec2], links: &[f64], target: Vec2) -> (f64, f64) {
    let lengths = links
        .iter()
        .enumerate()
        .map(|(k, l)| ((points[k + 1] - points[k]).norm() - l).abs())
        .fold(0.0, f64::max);
    (lengths, (points[links.len()] - target).norm())
}

/// The overall free-rope optimizer. Owns the scratch buffers of its iterations, sized once for
/// a rope; a solve still allocates a few vectors of the rope's length once per call (arc
/// lengths, the rolled-out answer, the metrics that judge it against its seed).
#[derive(Debug, Clone, Default)]
pub struct RopeOptimizer {
    options: RopeOptions,
    w: Work,
}

/// Per-rope data and scratch.
#[derive(Debug, Clone, Default)]
struct Work {
    /// Old points `q`.
    q: Vec<Vec2>,
    /// Old segment lengths `ds_j = |q_{j+1} - q_j|`.
    ds: Vec<f64>,
    /// Positional weight per point (M1: 1, M4: sigma, M3/M5: w).
    pos: Vec<f64>,
    /// Rotation weight per point (M3: 1, M5: sigma), index = point.
    rot: Vec<f64>,
    /// Old absolute angles.
    phi0: Vec<f64>,
    phi: Vec<f64>,
    trial: Vec<f64>,
    step: Vec<f64>,
    grad: Vec<f64>,
    curv: Vec<f64>,
    p: Vec<Vec2>,
    mu: Vec<Vec2>,
    /// Per-point Hessian blocks of the stage cost (symmetric 2x2: xx, xy, yy).
    c: Vec<[f64; 3]>,
    /// Feedback gains and feedforward of the Riccati recursion.
    gain: Vec<[f64; 3]>,
    ff: Vec<f64>,
    links: Vec<f64>,
    /// Smoothing parameter of M2 (0 for the smooth objectives).
    eps: f64,
    m2: bool,
}

type Sym3 = [[f64; 3]; 3];

impl Work {
    fn size(&mut self, n: usize) {
        for v in [
            &mut self.ds,
            &mut self.phi0,
            &mut self.phi,
            &mut self.trial,
            &mut self.step,
            &mut self.grad,
            &mut self.curv,
            &mut self.ff,
        ] {
            v.resize(n, 0.0);
        }
        for v in [&mut self.pos, &mut self.rot] {
            v.resize(n + 1, 0.0);
        }
        for v in [&mut self.q, &mut self.p, &mut self.mu] {
            v.resize(n + 1, Vec2::zeros());
        }
        self.c.resize(n + 1, [0.0; 3]);
        self.gain.resize(n, [0.0; 3]);
    }

    /// Points of the angles `phi` with the pulled end on `target`, written to `out`.
    fn rollout(links: &[f64], phi: &[f64], target: Vec2, out: &mut [Vec2]) {
        let n = links.len();
        out[n] = target;
        for k in (0..n).rev() {
            let (s, c) = phi[k].sin_cos();
            out[k] = out[k + 1] - Vec2::new(c, s) * links[k];
        }
    }

    /// The (smoothed) objective of `phi`; leaves the points in `self.p`.
    fn value(&mut self, use_trial: bool, target: Vec2) -> f64 {
        let phi = if use_trial { &self.trial } else { &self.phi };
        Self::rollout(&self.links, phi, target, &mut self.p);
        let n = self.links.len();
        let mut f = 0.0;
        for j in 0..n {
            let r = self.p[j] - self.q[j];
            let r2 = r.norm_squared();
            if self.m2 {
                if r2 > 0.0 {
                    f += self.ds[j] * (r2 / ((r2 + self.eps * self.eps).sqrt() + self.eps));
                }
            } else {
                f += self.pos[j] * r2;
            }
        }
        for j in 1..n {
            let d = phi[j] - phi[j - 1] - (self.phi0[j] - self.phi0[j - 1]);
            f += self.rot[j] * d * d;
        }
        f
    }

    /// Gradient, per-point Hessian blocks and curvature terms at `self.phi` (whose points must
    /// be in `self.p`). Returns the largest gradient component.
    fn derivatives(&mut self) -> f64 {
        let n = self.links.len();
        let mut acc = Vec2::zeros();
        for j in 0..n {
            let r = self.p[j] - self.q[j];
            let (g, h) = if self.m2 {
                let rho = (r.norm_squared() + self.eps * self.eps).sqrt();
                if rho == 0.0 {
                    (Vec2::zeros(), [0.0; 3])
                } else {
                    let a = self.ds[j] / rho;
                    let b = a / (rho * rho);
                    (
                        r * a,
                        [a - b * r.x * r.x, -b * r.x * r.y, a - b * r.y * r.y],
                    )
                }
            } else {
                let a = 2.0 * self.pos[j];
                (r * a, [a, 0.0, a])
            };
            acc += g;
            self.mu[j] = acc;
            self.c[j] = h;
        }
        for k in 0..n {
            let (s, c) = self.phi[k].sin_cos();
            let l = self.links[k];
            // dp_j/dphi_k = L (sin, -cos) for j <= k; its derivative is L (cos, sin).
            self.grad[k] = l * (self.mu[k].x * s - self.mu[k].y * c);
            self.curv[k] = l * (self.mu[k].x * c + self.mu[k].y * s);
        }
        for j in 1..n {
            let d = self.phi[j] - self.phi[j - 1] - (self.phi0[j] - self.phi0[j - 1]);
            let g = 2.0 * self.rot[j] * d;
            self.grad[j] += g;
            self.grad[j - 1] -= g;
        }
        self.grad.iter().fold(0.0, |m, g| m.max(g.abs()))
    }

    /// The Newton step for `H + lambda I` into `self.step` by the Riccati recursion. Returns
    /// `false` when a pivot is not positive (the damped Hessian is not positive definite).
    fn newton_step(&mut self, lambda: f64, floor: f64) -> bool {
        let n = self.links.len();
        // Value of the eliminated part as a quadratic in (s_k, dphi_k): P, h.
        let mut p: Sym3 = [[0.0; 3]; 3];
        let mut h = [0.0; 3];
        for k in 0..n {
            // Point k's cost acts on s_k.
            let c = self.c[k];
            p[0][0] += c[0];
            p[0][1] += c[1];
            p[1][0] += c[1];
            p[1][1] += c[2];
            // Substitute s_k = s_{k+1} + v_k dphi_k over y = (s_{k+1}, e = dphi_{k+1}, dphi_k).
            let (sn, cs) = self.phi[k].sin_cos();
            let v = [self.links[k] * sn, -self.links[k] * cs];
            // B maps y (4) to (s_k, dphi_k) (3): rows [1,0,0,vx], [0,1,0,vy], [0,0,0,1].
            let b = |row: usize, col: usize| -> f64 {
                match (row, col) {
                    (0, 0) | (1, 1) | (2, 3) => 1.0,
                    (0, 3) => v[0],
                    (1, 3) => v[1],
                    _ => 0.0,
                }
            };
            let mut m = [[0.0; 4]; 4];
            let mut lin = [0.0; 4];
            for (r, mrow) in m.iter_mut().enumerate() {
                for (col, mv) in mrow.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (a, prow) in p.iter().enumerate() {
                        let ba = b(a, r);
                        if ba == 0.0 {
                            continue;
                        }
                        for (bb, pv) in prow.iter().enumerate() {
                            acc += ba * pv * b(bb, col);
                        }
                    }
                    *mv = acc;
                }
                lin[r] = (0..3).map(|a| b(a, r) * h[a]).sum();
            }
            let rho = if k + 1 < n { self.rot[k + 1] } else { 0.0 };
            m[3][3] += self.curv[k] + lambda + 2.0 * rho;
            m[2][2] += 2.0 * rho;
            m[2][3] -= 2.0 * rho;
            m[3][2] -= 2.0 * rho;
            lin[3] += self.grad[k];
            let a = m[3][3];
            // A NaN pivot fails too.
            if a.is_nan() || a <= floor {
                return false;
            }
            self.gain[k] = [-m[3][0] / a, -m[3][1] / a, -m[3][2] / a];
            self.ff[k] = -lin[3] / a;
            for r in 0..3 {
                for col in 0..3 {
                    p[r][col] = m[r][col] - m[r][3] * m[3][col] / a;
                }
                h[r] = lin[r] - m[r][3] * lin[3] / a;
            }
        }
        // Forward pass from the pulled end: s_n = 0, no dphi_{n+1}.
        let mut s = Vec2::zeros();
        let mut e = 0.0;
        for k in (0..n).rev() {
            let g = self.gain[k];
            let d = g[0] * s.x + g[1] * s.y + g[2] * e + self.ff[k];
            if !d.is_finite() {
                return false;
            }
            self.step[k] = d;
            let (sn, cs) = self.phi[k].sin_cos();
            s += Vec2::new(sn, -cs) * (self.links[k] * d);
            e = d;
        }
        true
    }

    /// Scale of the Hessian's diagonal, for the damping and the pivot floor.
    fn hessian_scale(&self) -> f64 {
        let n = self.links.len();
        let lmax = self.links.iter().cloned().fold(0.0, f64::max);
        let csum: f64 = self.c[..n].iter().map(|c| c[0] + c[2]).sum();
        let rmax = self.rot.iter().cloned().fold(0.0, f64::max);
        let cmax = self.curv.iter().fold(0.0, |m: f64, c| m.max(c.abs()));
        lmax * lmax * csum + 4.0 * rmax + cmax + f64::MIN_POSITIVE
    }
}

/// Result of one stage.
struct Stage {
    iterations: usize,
    gradient: f64,
    decrement: f64,
    converged: bool,
}

impl RopeOptimizer {
    /// An optimizer with the given options.
    pub fn new(options: RopeOptions) -> Self {
        Self {
            options,
            w: Work::default(),
        }
    }

    /// The options in use.
    pub fn options(&self) -> &RopeOptions {
        &self.options
    }

    /// Moves the pulled end of the rope `old` (n + 1 points, the free end first) to `target` in
    /// one straight step, minimizing `objective` over the whole rope with every length kept.
    /// The answer is written to `out` (n + 1 points). Bad input is refused with `out` untouched;
    /// otherwise an answer is always written, and [`RopeReport::converged`] says whether the
    /// stopping rule was met (see [`RopeReport::check`]).
    pub fn solve(
        &mut self,
        old: &[Vec2],
        links: &[f64],
        target: Vec2,
        objective: Objective,
        out: &mut [Vec2],
    ) -> Result<RopeReport, RopeError> {
        check(old, links, target)?;
        if out.len() != old.len() {
            return Err(RopeError::Shape {
                points: out.len(),
                links: links.len(),
            });
        }
        let n = links.len();
        let w = &mut self.w;
        w.size(n);
        w.links.clear();
        w.links.extend_from_slice(links);
        w.q.copy_from_slice(old);
        let mut sigma = vec![0.0; n + 1];
        metrics::arc_to_tip(old, &mut sigma);
        let total = sigma[0];
        for j in 0..n {
            w.ds[j] = (old[j + 1] - old[j]).norm();
            let d = old[j + 1] - old[j];
            w.phi0[j] = d.y.atan2(d.x);
        }
        for (j, &sig) in sigma.iter().enumerate() {
            let (pos, rot) = match objective {
                Objective::M1 | Objective::M2 => (1.0, 0.0),
                Objective::M4 => (sig, 0.0),
                Objective::M3 { companion_weight } => (companion_weight, 1.0),
                Objective::M5 { companion_weight } => (companion_weight, sig),
            };
            w.pos[j] = pos;
            w.rot[j] = if j == 0 || j == n { 0.0 } else { rot };
        }
        w.m2 = objective == Objective::M2;

        // Seed: the better of the two sequential motions (tractrix, distance step).
        let mut seed_objective = f64::INFINITY;
        for propagation in [Propagation::Tractrix, Propagation::Distance] {
            sweep(old, links, target, propagation, &mut w.p);
            for k in 0..n {
                let d = w.p[k + 1] - w.p[k];
                w.trial[k] = nearest_representative(d.y.atan2(d.x), w.phi0[k]);
            }
            Work::rollout(links, &w.trial, target, &mut w.p);
            let value = objective.value(&metrics::rope(old, &w.p));
            if value < seed_objective {
                seed_objective = value;
                w.phi.copy_from_slice(&w.trial);
                out.copy_from_slice(&w.p);
            }
        }
        let move_m = (target - old[n]).norm();
        let mut report = RopeReport {
            objective: seed_objective,
            seed_objective,
            iterations: 0,
            stages: 0,
            gradient: 0.0,
            decrement: 0.0,
            smoothing: 0.0,
            smoothing_gap: 0.0,
            length_residual: 0.0,
            tip_residual: 0.0,
            converged: true,
            kept_seed: false,
        };
        if move_m > 0.0 {
            let mut eps = if w.m2 {
                self.options.smoothing_start * move_m
            } else {
                0.0
            };
            let last = self.options.smoothing_final * move_m;
            loop {
                w.eps = eps;
                let stage = run_stage(w, &self.options, target, seed_objective);
                report.iterations += stage.iterations;
                report.stages += 1;
                report.gradient = stage.gradient;
                report.decrement = stage.decrement;
                report.converged &= stage.converged;
                if eps <= last {
                    break;
                }
                eps = (eps * self.options.smoothing_ratio).max(last);
            }
            report.smoothing = eps;
            report.smoothing_gap = eps * total;
            let mut trial = vec![Vec2::zeros(); n + 1];
            Work::rollout(links, &w.phi, target, &mut trial);
            let value = objective.value(&metrics::rope(old, &trial));
            if value <= seed_objective {
                out.copy_from_slice(&trial);
                report.objective = value;
            } else {
                report.kept_seed = true;
            }
        }
        let (lengths, tip) = residuals(out, links, target);
        report.length_residual = lengths;
        report.tip_residual = tip;
        Ok(report)
    }

    /// Pulls the rope's end to `target` in `steps` equal straight moves, each optimized from the
    /// previous answer; `points` are updated in place. Iterations add up; the residuals and
    /// objective values are those of the last move; `converged` holds only if every move did.
    pub fn pull(
        &mut self,
        points: &mut [Vec2],
        links: &[f64],
        target: Vec2,
        steps: usize,
        objective: Objective,
    ) -> Result<RopeReport, RopeError> {
        check(points, links, target)?;
        let steps = steps.max(1);
        let start = points[links.len()];
        let mut next = points.to_vec();
        let mut total: Option<RopeReport> = None;
        for k in 1..=steps {
            let sub = start + (target - start) * (k as f64 / steps as f64);
            let r = self.solve(points, links, sub, objective, &mut next)?;
            points.copy_from_slice(&next);
            total = Some(match total {
                None => r,
                Some(t) => RopeReport {
                    iterations: t.iterations + r.iterations,
                    stages: t.stages + r.stages,
                    converged: t.converged && r.converged,
                    kept_seed: t.kept_seed || r.kept_seed,
                    ..r
                },
            });
        }
        total.ok_or(RopeError::Shape {
            points: points.len(),
            links: links.len(),
        })
    }
}

/// One smoothing level: damped Newton from `w.phi` until the stopping rule or the cap.
fn run_stage(w: &mut Work, options: &RopeOptions, target: Vec2, reference: f64) -> Stage {
    let n = w.links.len();
    let fref = reference.abs().max(f64::MIN_POSITIVE);
    let tol = options.decrement_tolerance * fref;
    let mut f = w.value(false, target);
    let mut lambda = 0.0;
    let mut stage = Stage {
        iterations: 0,
        gradient: f64::INFINITY,
        decrement: f64::INFINITY,
        converged: false,
    };
    while stage.iterations < options.max_iterations {
        w.value(false, target);
        stage.gradient = w.derivatives();
        let scale = w.hessian_scale();
        let floor = 1e-14 * scale;
        while !w.newton_step(lambda, floor) {
            lambda = if lambda == 0.0 {
                1e-10 * scale
            } else {
                lambda * 10.0
            };
            if !lambda.is_finite() || lambda > 1e20 * scale {
                return stage;
            }
        }
        stage.iterations += 1;
        let slope: f64 = w.grad.iter().zip(&w.step).map(|(g, d)| g * d).sum();
        stage.decrement = -slope;
        if stage.decrement <= tol && lambda == 0.0 {
            stage.converged = true;
            return stage;
        }
        // Armijo backtracking.
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..60 {
            for k in 0..n {
                w.trial[k] = w.phi[k] + alpha * w.step[k];
            }
            let ft = w.value(true, target);
            if ft.is_finite() && ft < f && ft <= f + 1e-4 * alpha * slope {
                std::mem::swap(&mut w.phi, &mut w.trial);
                f = ft;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // Round-off floor: the objective cannot be lowered any more.
            if stage.decrement <= 1e3 * tol {
                stage.converged = true;
                w.value(false, target);
                return stage;
            }
            lambda = if lambda == 0.0 {
                1e-6 * w.hessian_scale()
            } else {
                lambda * 10.0
            };
            continue;
        }
        // A full step returns to undamped Newton; a shortened one raises the damping.
        lambda = if alpha == 1.0 {
            0.0
        } else {
            lambda.max(1e-8 * w.hessian_scale()) * 4.0
        };
    }
    w.value(false, target);
    stage
}

/// Checks a rope and its target.
fn check(old: &[Vec2], links: &[f64], target: Vec2) -> Result<(), RopeError> {
    if links.is_empty() || old.len() != links.len() + 1 {
        return Err(RopeError::Shape {
            points: old.len(),
            links: links.len(),
        });
    }
    if let Some(i) = old
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(RopeError::NotFinite { index: i });
    }
    if !(target.x.is_finite() && target.y.is_finite()) {
        return Err(RopeError::NotFinite { index: old.len() });
    }
    for (k, &l) in links.iter().enumerate() {
        let measured = (old[k + 1] - old[k]).norm();
        if !(l.is_finite() && l > 0.0) || (measured - l).abs() > 1e-9 * l.max(1.0) {
            return Err(RopeError::BadLink {
                link: k + 1,
                length: l,
                measured,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn wavy(n: usize) -> (Vec<Vec2>, Vec<f64>) {
        let mut pts = vec![Vec2::zeros()];
        let mut links = Vec::new();
        for k in 0..n {
            let a = 0.6 * (k as f64 * 0.7).sin();
            let l = 0.1 + 0.02 * (k % 3) as f64;
            let p = pts[k] + Vec2::new(a.cos(), a.sin()) * l;
            pts.push(p);
            links.push(l);
        }
        (pts, links)
    }

    /// The Riccati step equals the dense Newton step built from finite differences of the
    /// objective.
    #[test]
    fn riccati_step_matches_dense_newton() {
        for objective in [
            Objective::M1,
            Objective::M2,
            Objective::M4,
            Objective::M3 {
                companion_weight: 0.7,
            },
            Objective::M5 {
                companion_weight: 2.0,
            },
        ] {
            let (old, links) = wavy(6);
            let n = links.len();
            let target = old[n] + Vec2::new(0.05, 0.12);
            let mut opt = RopeOptimizer::default();
            let mut out = vec![Vec2::zeros(); n + 1];
            // Size and fill the work area through a solve, then perturb the angles.
            opt.solve(&old, &links, target, objective, &mut out)
                .unwrap();
            let w = &mut opt.w;
            w.eps = if w.m2 { 0.01 } else { 0.0 };
            for k in 0..n {
                w.phi[k] += 0.1 * ((k as f64) * 1.3).cos();
            }
            let base = w.phi.clone();
            let f = |w: &mut Work, x: &[f64]| {
                w.trial.copy_from_slice(x);
                w.value(true, target)
            };
            let h = 1e-4;
            let mut hess = nalgebra::DMatrix::<f64>::zeros(n, n);
            let mut grad = nalgebra::DVector::<f64>::zeros(n);
            for a in 0..n {
                let mut xp = base.clone();
                let mut xm = base.clone();
                xp[a] += h;
                xm[a] -= h;
                grad[a] = (f(w, &xp) - f(w, &xm)) / (2.0 * h);
                for b in 0..n {
                    let mut x = [base.clone(), base.clone(), base.clone(), base.clone()];
                    x[0][a] += h;
                    x[0][b] += h;
                    x[1][a] += h;
                    x[1][b] -= h;
                    x[2][a] -= h;
                    x[2][b] += h;
                    x[3][a] -= h;
                    x[3][b] -= h;
                    let v: Vec<f64> = x.iter().map(|x| f(w, x)).collect();
                    hess[(a, b)] = (v[0] - v[1] - v[2] + v[3]) / (4.0 * h * h);
                }
            }
            w.value(false, target);
            w.derivatives();
            for a in 0..n {
                assert!(
                    (w.grad[a] - grad[a]).abs() < 1e-6 * (1.0 + grad.amax()),
                    "{objective:?} gradient {a}: {} vs {}",
                    w.grad[a],
                    grad[a]
                );
            }
            let lambda = 10.0 * hess.norm();
            assert!(w.newton_step(lambda, 0.0));
            let dense = (hess + nalgebra::DMatrix::identity(n, n) * lambda)
                .lu()
                .solve(&(-grad))
                .unwrap();
            for a in 0..n {
                assert!(
                    (w.step[a] - dense[a]).abs() < 1e-5 * (1.0 + dense.amax()),
                    "{objective:?} step {a}: {} vs {}",
                    w.step[a],
                    dense[a]
                );
            }
        }
    }

    #[test]
    fn objectives_parse_and_refuse() {
        assert_eq!(Objective::from_name("m2", None), Ok(Objective::M2));
        assert!(matches!(
            Objective::from_name("m3", None),
            Err(ObjectiveError::MissingWeight { .. })
        ));
        assert!(matches!(
            Objective::from_name("m1", Some(1.0)),
            Err(ObjectiveError::UnexpectedWeight { .. })
        ));
        assert!(matches!(
            Objective::from_name("m5", Some(-1.0)),
            Err(ObjectiveError::BadWeight { .. })
        ));
        assert!(matches!(
            Objective::from_name("m6", None),
            Err(ObjectiveError::Unknown { .. })
        ));
        let m = Metrics {
            m1: 1.0,
            m2: 2.0,
            m3: 3.0,
            m4: 4.0,
            m5: 5.0,
        };
        let o = Objective::from_name("m5", Some(0.5)).unwrap();
        assert_eq!(o.value(&m), 5.5);
        assert_eq!(o.name(), "m5");
    }

    #[test]
    fn bad_input_is_refused() {
        let (old, links) = wavy(4);
        let mut out = vec![Vec2::zeros(); 5];
        let mut opt = RopeOptimizer::default();
        let t = Vec2::new(1.0, 1.0);
        assert!(matches!(
            opt.solve(&old[..4], &links, t, Objective::M1, &mut out),
            Err(RopeError::Shape { .. })
        ));
        assert!(matches!(
            opt.solve(
                &old,
                &links,
                Vec2::new(f64::NAN, 0.0),
                Objective::M1,
                &mut out
            ),
            Err(RopeError::NotFinite { index: 5 })
        ));
        let mut bad = links.clone();
        bad[2] *= 1.5;
        assert!(matches!(
            opt.solve(&old, &bad, t, Objective::M1, &mut out),
            Err(RopeError::BadLink { link: 3, .. })
        ));
        assert!(out.iter().all(|p| *p == Vec2::zeros()));
    }
}
