//! The step's subproblem solved by a dual active-set method (Goldfarb and Idnani, "A
//! numerically stable dual method for solving strictly convex quadratic programs", Math.
//! Programming 27, 1983), specialised to the identity Hessian of metric 3.
//!
//! ```text
//! minimize   1/2 |x - theta0|^2 + 1/2 |t|^2
//! subject to a_i . (x - theta) + sigma t_i  = r_i   (i = 0, 1: the tip)
//!            a_i . (x - theta) + sigma t_i >= r_i   (i >= 2: the pairs)
//!            lo <= x <= hi
//! ```
//!
//! `sigma = sqrt(rho_inv)` is the elastic form's slack weight (0: the exact subproblem, where
//! the slacks `t` vanish). The method starts at the unconstrained minimum `x = theta0` and adds
//! the most violated constraint, one at a time, moving the primal point and the multipliers so
//! that every constraint taken stays satisfied and every inequality's multiplier stays
//! non-negative, and drops a constraint whose multiplier would turn negative. Each iterate is
//! the optimum over the constraints taken, so it ends, after about as many steps as there are
//! active constraints, at the optimum or with a proof that the constraints cannot all hold
//! (a violated constraint that no drop can make room for).
//!
//! Why not the dual's projected Newton iteration (as without obstacles): with up to
//! [`super::MAX_PAIRS`] pairs the dual has more variables than the chain has joints, and on a
//! linearization that cannot be met it runs away slowly, each step a dense solve over every
//! row. Here the linear algebra is over the active constraints alone, at most one per joint in
//! the exact form: the factor of their Gram matrix grows by one row per constraint taken and is
//! rebuilt only when one is dropped.

use super::Qp;

/// A constraint whose component off the active ones is below this fraction of its length
/// depends on them.
const DEPENDENT: f64 = 1e-10;
/// A bound violated by less than this (rad, relative to `1 + |bound|`) holds.
const BOUND_TOL: f64 = 1e-12;

/// Scratch of the active-set solve, sized once for `n` joints and `k2` rows.
#[derive(Debug, Default)]
pub(super) struct ActiveScratch {
    /// Constraints taken: index (rows `0..k2`, lower bounds `k2 + a`, upper `k2 + n + a`).
    act: Vec<usize>,
    /// Whether each constraint (by index) is among those taken.
    taken: Vec<bool>,
    /// The sign each row was taken with (an equality is taken pointing at its violation).
    sign: Vec<f64>,
    /// Their multipliers.
    u: Vec<f64>,
    /// Lower Cholesky factor of the taken constraints' Gram matrix (stride `cap`).
    chol: Vec<f64>,
    /// `N^T n_p`, then the forward solve of it.
    w: Vec<f64>,
    /// The multipliers' change per unit step, `(N^T N)^-1 N^T n_p`.
    r: Vec<f64>,
    /// The primal point: joints and slacks.
    x: Vec<f64>,
    t: Vec<f64>,
    /// `x - theta` (joints), for the rows' values ([`Qp::difference`]).
    d: Vec<f64>,
    /// The primal direction.
    zx: Vec<f64>,
    zt: Vec<f64>,
    /// Inner products of the rows' normals (without the elastic term), computed on first use
    /// in each solve (NaN until then), and each row's length.
    gram: Vec<f64>,
    norm: Vec<f64>,
    k2: usize,
    cap: usize,
    /// Some bound of the subproblem under way is finite.
    bounded: bool,
}

impl ActiveScratch {
    /// Sizes the scratch for `n` joints and at most `k2` rows.
    pub fn new(n: usize, k2: usize) -> Self {
        let cap = n + k2;
        Self {
            act: Vec::with_capacity(cap),
            taken: vec![false; k2 + 2 * n],
            sign: Vec::with_capacity(cap),
            u: Vec::with_capacity(cap),
            chol: vec![0.0; cap * cap],
            w: vec![0.0; cap],
            r: vec![0.0; cap],
            x: vec![0.0; n],
            d: vec![0.0; n],
            t: vec![0.0; k2],
            zx: vec![0.0; n],
            zt: vec![0.0; k2],
            gram: vec![f64::NAN; k2 * k2],
            norm: vec![0.0; k2],
            k2,
            cap,
            bounded: true,
        }
    }
}

/// What a constraint index names.
#[derive(Clone, Copy)]
enum Con {
    Row(usize),
    Lower(usize),
    Upper(usize),
}

impl Qp<'_> {
    fn con(&self, c: usize) -> Con {
        if c < self.k2 {
            Con::Row(c)
        } else if c < self.k2 + self.n {
            Con::Lower(c - self.k2)
        } else {
            Con::Upper(c - self.k2 - self.n)
        }
    }

    /// The inner product of two constraints' normals (with their signs); the rows' products
    /// are kept in `gram` (stride `stride`) for the rest of the solve.
    fn dot(&self, gram: &mut [f64], stride: usize, a: usize, sa: f64, b: usize, sb: f64) -> f64 {
        let v = match (self.con(a), self.con(b)) {
            (Con::Row(i), Con::Row(j)) => {
                let mut d = gram[i * stride + j];
                if d.is_nan() {
                    d = self
                        .row(i)
                        .iter()
                        .zip(self.row(j))
                        .map(|(p, q)| p * q)
                        .sum();
                    gram[i * stride + j] = d;
                    gram[j * stride + i] = d;
                }
                if i == j {
                    d + self.rho_inv
                } else {
                    d
                }
            }
            (Con::Row(i), Con::Lower(k)) | (Con::Lower(k), Con::Row(i)) => self.row(i)[k],
            (Con::Row(i), Con::Upper(k)) | (Con::Upper(k), Con::Row(i)) => -self.row(i)[k],
            (Con::Lower(k), Con::Lower(l)) | (Con::Upper(k), Con::Upper(l)) => {
                f64::from(u8::from(k == l))
            }
            (Con::Lower(k), Con::Upper(l)) | (Con::Upper(k), Con::Lower(l)) => {
                -f64::from(u8::from(k == l))
            }
        };
        sa * sb * v
    }

    /// Forms `x - theta` at the scratch's point, which every row's value reads.
    fn difference(&self, s: &mut ActiveScratch) {
        for ((d, x), t) in s.d.iter_mut().zip(&s.x).zip(self.theta) {
            *d = x - t;
        }
    }

    /// Row `i`'s value at the scratch's point (positive: satisfied with room), unsigned, after
    /// [`Self::difference`].
    fn row_value(&self, i: usize, s: &ActiveScratch, sigma: f64) -> f64 {
        let ad: f64 = self.row(i).iter().zip(&s.d).map(|(a, d)| a * d).sum();
        ad + sigma * s.t[i] - self.r[i]
    }

    /// The inequality (a pair's row or a bound) most violated at the scratch's point, by its
    /// distance to the boundary, beyond `tol` (rows) or [`BOUND_TOL`] (bounds): its index,
    /// sign and value. In the order of the constraints' indices, the first of equals.
    /// After [`Self::difference`].
    fn most_violated(&self, s: &ActiveScratch, sigma: f64, tol: f64) -> Option<(usize, f64, f64)> {
        let (n, k2) = (self.n, self.k2);
        let mut worst = 0.0;
        let mut pick = None;
        let mut consider = |c: usize, v: f64, norm: f64, limit: f64| {
            if v < -limit && norm > 0.0 && v / norm < worst {
                worst = v / norm;
                pick = Some((c, 1.0, v));
            }
        };
        for i in 2..k2 {
            if s.taken[i] {
                continue;
            }
            consider(i, self.row_value(i, s, sigma), s.norm[i], tol);
        }
        if !s.bounded {
            return pick;
        }
        for k in 0..n {
            if !s.taken[k2 + k] {
                let limit = BOUND_TOL * (1.0 + self.lo[k].abs());
                consider(k2 + k, s.x[k] - self.lo[k], 1.0, limit);
            }
        }
        for k in 0..n {
            if !s.taken[k2 + n + k] {
                let limit = BOUND_TOL * (1.0 + self.hi[k].abs());
                consider(k2 + n + k, self.hi[k] - s.x[k], 1.0, limit);
            }
        }
        pick
    }

    /// Adds `sign * normal(c) * f` to the direction `(zx, zt)`.
    fn axpy(&self, c: usize, f: f64, sigma: f64, zx: &mut [f64], zt: &mut [f64]) {
        match self.con(c) {
            Con::Row(i) => {
                for (z, a) in zx.iter_mut().zip(self.row(i)) {
                    *z += f * a;
                }
                zt[i] += f * sigma;
            }
            Con::Lower(k) => zx[k] += f,
            Con::Upper(k) => zx[k] -= f,
        }
    }

    /// Rebuilds the Cholesky factor of the taken constraints' Gram matrix; false when it is
    /// not (numerically) positive definite.
    fn refactor(&self, s: &mut ActiveScratch) -> bool {
        let (m, cap) = (s.act.len(), s.cap);
        for i in 0..m {
            for j in 0..=i {
                let mut v = self.dot(&mut s.gram, s.k2, s.act[i], s.sign[i], s.act[j], s.sign[j]);
                for k in 0..j {
                    v -= s.chol[i * cap + k] * s.chol[j * cap + k];
                }
                if i == j {
                    if v.is_nan() || v <= 0.0 {
                        return false;
                    }
                    s.chol[i * cap + i] = v.sqrt();
                } else {
                    s.chol[i * cap + j] = v / s.chol[j * cap + j];
                }
            }
        }
        true
    }

    /// Solves the subproblem; `lam` gets the rows' multipliers (the pairs' non-negative; in
    /// the convention `x = clip(theta0 + A^T lam)`) and `x` the joints. False when the
    /// constraints cannot all hold (exact form), a multiplier exceeds `cap`, or the solve
    /// breaks down numerically.
    pub(super) fn solve_active(
        &self,
        lam: &mut [f64],
        x: &mut [f64],
        s: &mut ActiveScratch,
        tol: f64,
        cap: f64,
    ) -> bool {
        let (n, k2) = (self.n, self.k2);
        let sigma = self.rho_inv.sqrt();
        let total = k2 + 2 * n;
        s.act.clear();
        s.taken[..total].iter_mut().for_each(|t| *t = false);
        s.sign.clear();
        s.u.clear();
        s.x.copy_from_slice(&self.theta0[..n]);
        s.t[..k2].iter_mut().for_each(|t| *t = 0.0);
        s.gram[..s.k2 * s.k2].iter_mut().for_each(|g| *g = f64::NAN);
        // An infinite bound is never violated: with none finite, the bounds are not searched.
        s.bounded = self.lo[..n]
            .iter()
            .chain(&self.hi[..n])
            .any(|b| b.is_finite());
        for i in 0..k2 {
            s.norm[i] = (self.dot(&mut s.gram, s.k2, i, 1.0, i, 1.0)).sqrt();
        }
        let max_steps = 4 * total + 16;
        let mut steps = 0;
        // A tip row that depends on the other (a stretched-out arm) and already holds.
        let mut skipped = [false; 2];
        loop {
            // The constraint to take: an equality not yet taken, else the most violated
            // inequality, measured as the distance to its boundary.
            let mut pick: Option<(usize, f64, f64)> = None;
            self.difference(s);
            for i in 0..2.min(k2) {
                if !s.taken[i] && !skipped[i] {
                    let v = self.row_value(i, s, sigma);
                    pick = Some((i, if v > 0.0 { -1.0 } else { 1.0 }, -v.abs()));
                    break;
                }
            }
            if pick.is_none() {
                pick = self.most_violated(s, sigma, tol);
            }
            let Some((p, sp_sign, mut sp)) = pick else {
                break;
            };
            let np2 = self.dot(&mut s.gram, s.k2, p, sp_sign, p, sp_sign);
            let mut up = 0.0;
            // Take `p`: steps until it holds, dropping constraints on the way.
            loop {
                steps += 1;
                if steps > max_steps {
                    return false;
                }
                let (m, stride) = (s.act.len(), s.cap);
                for j in 0..m {
                    s.w[j] = self.dot(&mut s.gram, s.k2, s.act[j], s.sign[j], p, sp_sign);
                }
                // Forward: L l = w (kept in w); back: L^T r = l.
                for i in 0..m {
                    let mut v = s.w[i];
                    for k in 0..i {
                        v -= s.chol[i * stride + k] * s.w[k];
                    }
                    s.w[i] = v / s.chol[i * stride + i];
                }
                for i in (0..m).rev() {
                    let mut v = s.w[i];
                    for k in i + 1..m {
                        v -= s.chol[k * stride + i] * s.r[k];
                    }
                    s.r[i] = v / s.chol[i * stride + i];
                }
                let ll: f64 = s.w[..m].iter().map(|v| v * v).sum();
                let z2 = np2 - ll;
                let independent = z2 > DEPENDENT * np2;
                // The largest step that keeps the inequalities' multipliers non-negative.
                let mut t1 = f64::INFINITY;
                let mut drop = None;
                for j in 0..m {
                    if s.act[j] >= 2 && s.r[j] > 0.0 {
                        let t = s.u[j] / s.r[j];
                        if t < t1 {
                            t1 = t;
                            drop = Some(j);
                        }
                    }
                }
                let t2 = if independent { -sp / z2 } else { f64::INFINITY };
                if !t1.is_finite() && !t2.is_finite() {
                    if p < 2 && sp.abs() <= tol {
                        skipped[p] = true;
                        break;
                    }
                    // Nothing can be dropped and `p` lies in the span of those taken.
                    return false;
                }
                let step = t1.min(t2);
                if independent {
                    s.zx.iter_mut().for_each(|z| *z = 0.0);
                    s.zt.iter_mut().for_each(|z| *z = 0.0);
                    self.axpy(p, sp_sign, sigma, &mut s.zx, &mut s.zt);
                    for j in 0..m {
                        let f = -s.r[j] * s.sign[j];
                        self.axpy(s.act[j], f, sigma, &mut s.zx, &mut s.zt);
                    }
                    for (x, z) in s.x.iter_mut().zip(&s.zx) {
                        *x += step * z;
                    }
                    for (t, z) in s.t.iter_mut().zip(&s.zt) {
                        *t += step * z;
                    }
                    sp += step * z2;
                }
                for j in 0..m {
                    s.u[j] -= step * s.r[j];
                }
                up += step;
                if t2 <= t1 {
                    // `p` holds: append it to the factor.
                    let d = z2.sqrt();
                    if d.is_nan() || d <= 0.0 || m >= s.cap {
                        return false;
                    }
                    for k in 0..m {
                        s.chol[m * stride + k] = s.w[k];
                    }
                    s.chol[m * stride + m] = d;
                    s.act.push(p);
                    s.taken[p] = true;
                    s.sign.push(sp_sign);
                    s.u.push(up);
                    break;
                }
                let Some(j) = drop else {
                    return false;
                };
                s.taken[s.act[j]] = false;
                s.act.remove(j);
                s.sign.remove(j);
                s.u.remove(j);
                if !self.refactor(s) {
                    return false;
                }
            }
        }
        for a in 0..n {
            x[a] = s.x[a].clamp(self.lo[a], self.hi[a]);
        }
        lam[..k2].iter_mut().for_each(|l| *l = 0.0);
        for j in 0..s.act.len() {
            if s.act[j] < k2 {
                lam[s.act[j]] = s.sign[j] * s.u[j];
            }
        }
        lam[..k2].iter().all(|l| l.is_finite() && l.abs() <= cap)
    }
}
