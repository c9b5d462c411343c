//! The linearized subproblem of one SQP iteration, solved through its two-variable dual.
//!
//! Primal: minimize `1/2 |x - z|^2` over the box `lo <= x <= hi` subject to the linearized tip
//! constraint `J (x - theta) = c`, or, in elastic form, with the constraint replaced by the
//! penalty `1/(2 rho_inv) |J (x - theta) - c|^2`. For a multiplier `mu` in the plane the
//! minimizing `x` is the clipped point `x(mu) = clip(z + J^T mu, lo, hi)`, and the dual
//! function `q(mu)` is concave and piecewise quadratic with gradient `-F(mu)`,
//!
//! ```text
//! F(mu) = J (x(mu) - theta) - c + rho_inv mu.
//! ```
//!
//! Semismooth Newton uses the generalized Jacobian `J_F J_F^T + rho_inv I` over the joints not
//! clipped at `mu`. In exact form a backtracking line search on `q` makes every step an ascent
//! step. In elastic form `q` is strictly concave along every line, and the step goes to the
//! exact maximum along the Newton direction, found by walking the kinks where joints enter or
//! leave their box (O(n log n)): when fewer than two joints are free the Newton matrix is
//! nearly singular, its full step crosses many kinks, and backtracking from it zigzags for
//! tens of evaluations per solve. Each evaluation is one pass over the joints.

use crate::chain::Vec2;

/// Most semismooth Newton steps of one solve: a solve settles in a handful, the cap only bounds
/// a pathological one.
const MAX_STEPS: usize = 60;
/// Relative shift of the Newton matrix's diagonal that keeps the direction defined when the
/// free columns are parallel (the line search keeps it an ascent step either way).
const REGULARIZATION: f64 = 1e-14;
/// Halvings of an exact-form step before it fails: `2^-40` of a step is below its round-off.
const MAX_HALVINGS: usize = 40;
/// Armijo's sufficient-increase fraction for the dual (the customary value).
const ARMIJO: f64 = 1e-4;
/// A full step that keeps the clipping pattern has solved the dual once `|F|` fell by this
/// factor: the dual is a quadratic there, so what is left is round-off.
const FULL_STEP_SOLVED: f64 = 1e-9;
/// Elastic form: `|F|` within this fraction of the correction wanted counts as settled (its
/// multiplier can be huge, which puts a round-off floor under `F`).
const ELASTIC_SETTLED: f64 = 1e-6;

/// The data of one linearized subproblem (all slices have one entry per joint).
pub(crate) struct Dual<'a> {
    /// First row of the tip Jacobian.
    pub jx: &'a [f64],
    /// Second row of the tip Jacobian.
    pub jy: &'a [f64],
    /// Centre of the proximity term (`theta0`: the SQP step measures metric 3 from it).
    pub z: &'a [f64],
    /// Linearization point.
    pub theta: &'a [f64],
    /// Lower bounds (`-inf` when unlimited).
    pub lo: &'a [f64],
    /// Upper bounds (`+inf` when unlimited).
    pub hi: &'a [f64],
    /// Tip correction wanted, `target - tip(theta)`.
    pub c: Vec2,
    /// Inverse penalty weight of the elastic form, m^2; 0 for the exact constraint.
    pub rho_inv: f64,
}

/// One evaluation of the dual at a multiplier.
struct Eval {
    /// `F(mu)`, the negative gradient of the dual.
    f: Vec2,
    /// The generalized Jacobian of `F`, symmetric: entries (0,0), (0,1), (1,1).
    m: [f64; 3],
    /// The dual function's value.
    q: f64,
    /// Whether any joint changed its clipping state.
    changed: bool,
}

/// How one backtracking step of the exact form ended.
enum Ascent {
    /// The multiplier moved.
    Moved,
    /// A full step kept the clipping pattern: the dual is solved.
    Solved,
    /// The solve ends with this answer.
    Done(bool),
}

impl Dual<'_> {
    /// Whether a solve that cannot make progress any more has settled: within `tol`, or, in
    /// elastic form (whose multiplier can be huge, so that `F` has a round-off floor), within a
    /// millionth of the correction wanted; such a step is only a direction for the line search.
    fn settled(&self, f_norm: f64, tol: f64) -> bool {
        f_norm <= tol || (self.rho_inv > 0.0 && f_norm <= ELASTIC_SETTLED * self.c.norm())
    }

    /// Writes `x(mu)` and the clipping state, returns `F`, the generalized Jacobian, `q`, and
    /// whether any joint changed its clipping state.
    fn eval(&self, mu: [f64; 2], x: &mut [f64], state: &mut [i8]) -> Eval {
        let mut f = Vec2::zeros();
        let mut m = [0.0; 3];
        let mut q = 0.0;
        let mut changed = false;
        for a in 0..x.len() {
            let (jx, jy) = (self.jx[a], self.jy[a]);
            let jmu = jx * mu[0] + jy * mu[1];
            let u = self.z[a] + jmu;
            let (v, st) = if u <= self.lo[a] {
                (self.lo[a], -1)
            } else if u >= self.hi[a] {
                (self.hi[a], 1)
            } else {
                (u, 0)
            };
            if state[a] != st {
                changed = true;
                state[a] = st;
            }
            x[a] = v;
            let dx = v - self.theta[a];
            f.x += jx * dx;
            f.y += jy * dx;
            if st == 0 {
                m[0] += jx * jx;
                m[1] += jx * jy;
                m[2] += jy * jy;
            }
            let dz = v - self.z[a];
            q += 0.5 * dz * dz - jmu * dx;
        }
        f -= self.c;
        f.x += self.rho_inv * mu[0];
        f.y += self.rho_inv * mu[1];
        m[0] += self.rho_inv;
        m[2] += self.rho_inv;
        q += mu[0] * self.c.x + mu[1] * self.c.y
            - 0.5 * self.rho_inv * (mu[0] * mu[0] + mu[1] * mu[1]);
        Eval { f, m, q, changed }
    }

    /// The step `t > 0` that maximizes the dual along `mu + t d` (elastic form only), where
    /// `f = F(mu)`. Along the line `-q` has the piecewise linear, increasing derivative
    /// `d . F(mu + t d)`, whose slope changes by `(J_a . d)^2` where joint `a` enters or leaves
    /// its box; walking those kinks in order finds its zero exactly. `brk` is scratch for two
    /// kinks per joint.
    fn line_max(&self, mu: [f64; 2], d: [f64; 2], f: Vec2, brk: &mut [(f64, f64)]) -> f64 {
        let mut slope = self.rho_inv * (d[0] * d[0] + d[1] * d[1]);
        let mut k = 0;
        for a in 0..self.jx.len() {
            let g = self.jx[a] * d[0] + self.jy[a] * d[1];
            if g == 0.0 {
                continue;
            }
            let u = self.z[a] + self.jx[a] * mu[0] + self.jy[a] * mu[1];
            let (lo, hi) = (self.lo[a], self.hi[a]);
            let g2 = g * g;
            // Where u + t g meets the bound it moves toward, and the one it moves away from.
            let (t_lo, t_hi) = ((lo - u) / g, (hi - u) / g);
            let (t_in, t_out) = if g > 0.0 { (t_lo, t_hi) } else { (t_hi, t_lo) };
            // Free on (max(t_in, 0), t_out) when that is not empty.
            if t_out <= 0.0 {
                continue;
            }
            if t_in > 0.0 {
                brk[k] = (t_in, g2);
                k += 1;
            } else {
                slope += g2;
            }
            if t_out.is_finite() {
                brk[k] = (t_out, -g2);
                k += 1;
            }
        }
        let brk = &mut brk[..k];
        brk.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let mut t = 0.0;
        let mut v = f.x * d[0] + f.y * d[1];
        for &(tk, dg) in brk.iter() {
            if slope > 0.0 && v + slope * (tk - t) >= 0.0 {
                break;
            }
            v += slope * (tk - t);
            t = tk;
            slope += dg;
        }
        if slope > 0.0 {
            t - v / slope
        } else {
            t
        }
    }

    /// Solves the dual from the multiplier `mu` (updated in place); on success `x` holds the
    /// primal answer. Fails when the dual does not settle (an infeasible exact subproblem has an
    /// unbounded dual) or the multiplier grows beyond `mu_cap`.
    pub fn solve(
        &self,
        mu: &mut [f64; 2],
        x: &mut [f64],
        state: &mut [i8],
        tol: f64,
        mu_cap: f64,
        brk: &mut [(f64, f64)],
    ) -> bool {
        let bounded = |mu: &[f64; 2]| mu[0].abs() <= mu_cap && mu[1].abs() <= mu_cap;
        state.iter_mut().for_each(|s| *s = 2);
        let mut e = self.eval(*mu, x, state);
        for _ in 0..MAX_STEPS {
            if e.f.norm() <= tol {
                return true;
            }
            let Some(d) = Self::newton_direction(&e) else {
                return false;
            };
            if self.rho_inv > 0.0 {
                // Elastic form: the dual is strictly concave along every line, so the step goes
                // straight to the maximum along the Newton direction. With fewer than two
                // joints free the Newton matrix is nearly singular and its full step would
                // cross many kinks; backtracking from it would zigzag.
                let t = self.line_max(*mu, d, e.f, brk);
                let trial = [mu[0] + t * d[0], mu[1] + t * d[1]];
                let te = self.eval(trial, x, state);
                if t.is_nan() || t <= 0.0 || trial == *mu || te.q <= e.q {
                    // Round-off floor: the step no longer moves the multiplier or raises q.
                    let te = self.eval(*mu, x, state);
                    return self.settled(te.f.norm(), tol);
                }
                *mu = trial;
                e = te;
                continue;
            }
            match self.backtrack(mu, &mut e, d, x, state, tol) {
                Ascent::Moved if bounded(mu) => {}
                Ascent::Moved => return false,
                Ascent::Solved => return bounded(mu),
                Ascent::Done(ok) => return ok,
            }
        }
        e.f.norm() <= tol
    }

    /// The semismooth Newton direction `-(M + reg I)^-1 F` at `e`, with `M` the generalized
    /// Jacobian; `None` when `M` is not positive definite (no joint free in exact form, or
    /// round-off).
    fn newton_direction(e: &Eval) -> Option<[f64; 2]> {
        let tr = e.m[0] + e.m[2];
        if tr.is_nan() || tr <= 0.0 {
            return None;
        }
        let reg = REGULARIZATION * tr;
        let (m0, m1, m2) = (e.m[0] + reg, e.m[1], e.m[2] + reg);
        let det = m0 * m2 - m1 * m1;
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        Some([
            -(m2 * e.f.x - m1 * e.f.y) / det,
            -(m0 * e.f.y - m1 * e.f.x) / det,
        ])
    }

    /// Exact form: backtracking from the full Newton step `d` until the dual rises enough
    /// (Armijo), updating `mu` and `e` to the accepted step.
    fn backtrack(
        &self,
        mu: &mut [f64; 2],
        e: &mut Eval,
        d: [f64; 2],
        x: &mut [f64],
        state: &mut [i8],
        tol: f64,
    ) -> Ascent {
        let slope = -(e.f.x * d[0] + e.f.y * d[1]);
        let mut alpha = 1.0;
        for _ in 0..MAX_HALVINGS {
            let trial = [mu[0] + alpha * d[0], mu[1] + alpha * d[1]];
            let t = self.eval(trial, x, state);
            // Same clipping pattern before and after a full step: the dual is a quadratic
            // there, and unless the free columns are parallel the step solved it up to
            // round-off.
            let full_same = alpha == 1.0
                && !t.changed
                && (t.f.norm() <= tol || t.f.norm() <= FULL_STEP_SOLVED * e.f.norm());
            if t.q >= e.q + ARMIJO * alpha * slope || full_same {
                if trial == *mu || t.q <= e.q {
                    // Round-off floor: the step no longer moves the multiplier or raises q.
                    return Ascent::Done(self.settled(e.f.norm(), tol));
                }
                *mu = trial;
                *e = t;
                return if full_same {
                    Ascent::Solved
                } else {
                    Ascent::Moved
                };
            }
            alpha *= 0.5;
        }
        Ascent::Done(false)
    }
}
