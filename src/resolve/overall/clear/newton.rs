//! The Newton step's linear algebra among obstacles: the Lagrangian Hessian in structured form,
//! and the KKT system solved through it.
//!
//! A pair's clearance depends on the pose only through its link's two ends `P = p_{L-1}` and
//! `Q = p_L`: `c(theta) = phi(P(theta), Q(theta))`. By the chain rule its Hessian is
//!
//! ```text
//! H_c = J_X^T (d2 phi / dX2) J_X + sum_i (d phi / dX_i) d2 X_i / dtheta2,   X = (P, Q) in R^4.
//! ```
//!
//! The second term has the tip's shape (module `hessian`): a point `X` moved by joints `a, b`
//! has `d2 X / dtheta_a dtheta_b = -(X - p_max(a,b))`, and `d phi / dP = (1 - s) n`,
//! `d phi / dQ = s n` (the contact's unit normal `n`, at `s` along the link), so together the
//! entry is `g_max(a,b)` with `g_m = -n . (q - p_m)` for `m < L` (`q` the contact point) and 0
//! beyond. The first term has rank at most 4: the columns of `J_X` (how `P` and `Q` move with
//! each joint) and the 4 x 4 Hessian of `phi`, which forward differences of `(1 - s) n, s n`
//! give from four contact evaluations. The Lagrangian's Hessian is then
//!
//! ```text
//! H = I + G(g) + V C V^T
//! ```
//!
//! with `g` the tip's term plus `nu_j` times each pair's, `V` the pairs' `J_X^T` columns and
//! `C` block diagonal (`-nu_j` times each pair's 4 x 4). `I + G(g)` restricted to the free
//! joints solves in O(n) (module `hessian`); the low-rank part enters by the Woodbury identity
//! in the form that needs no inverse of `C`:
//!
//! ```text
//! H^-1 = H0^-1 - H0^-1 V (I + C V^T H0^-1 V)^-1 C V^T H0^-1,   H0 = I + G(g),
//! ```
//!
//! and the KKT system `H d - A^T lambda = r1`, `A d = r2` by its Schur complement
//! `A H^-1 A^T lambda = r2 - A H^-1 r1`. That route costs about `r^2 m` operations for `r`
//! low-rank columns and `m` free joints, against `(m + rows)^3 / 3` for the whole KKT matrix
//! assembled dense and factorized: a short chain leaning on a few obstacles is cheaper dense, a
//! long one structured. `solve_kkt` takes the cheaper by that count (an operation of the
//! structured route weighed as two, for its shorter loops), and the dense one where `H0` is too
//! near singular for its solve.

use super::super::hessian;
use crate::chain::Vec2;
use crate::world::World;

/// Columns of `V` one pair brings (how `P` and `Q` move, x and y of each).
pub(super) const RANK: usize = 4;

/// One operation of the structured route costs about this many of the dense one (shorter loops,
/// more of them): measured on warm ticks of 12 and 24 joints.
const STRUCTURED_WEIGHT: usize = 2;

/// A pivot below this fraction of the largest entry ends a dense solve.
const PIVOT_FLOOR: f64 = 1e-13;

/// The structured Lagrangian Hessian and the scratch of its solves, grown on demand.
#[derive(Debug, Default)]
pub(super) struct Newton {
    n: usize,
    /// `g` of `G(g)`, one entry per joint.
    pub g: Vec<f64>,
    /// Low-rank columns: `cols` of them, `n` entries each.
    v: Vec<f64>,
    cols: usize,
    /// `C`, `RANK x RANK` per pair, row-major, the blocks one after the other.
    c: Vec<f64>,
    // Scratch of the structured solve (sized for `m` free joints and `rows` constraints).
    g_free: Vec<f64>,
    piv: Vec<f64>,
    sol: Vec<f64>,
    tmp: Vec<f64>,
    v_free: Vec<f64>,
    w: Vec<f64>,
    s_mat: Vec<f64>,
    s_perm: Vec<usize>,
    t: Vec<f64>,
    z: Vec<f64>,
    k_mat: Vec<f64>,
    k_perm: Vec<usize>,
    lam: Vec<f64>,
    /// The dense KKT matrix, its pivots, and `V C` over the free joints (`RANK` per block).
    dense: Vec<f64>,
    dense_perm: Vec<usize>,
    vc: Vec<f64>,
    /// The constraint rows on the free joints (structured route).
    a_free: Vec<f64>,
    /// The factors the last successful KKT solve (either route) left, for
    /// [`Newton::solve_again`]; each route drops them first.
    factors: Option<Factors>,
}

/// Which factors of a KKT system are kept, and its shape.
#[derive(Debug, Clone, Copy)]
enum Factors {
    /// The whole matrix's LU (`size` = free joints + rows).
    Dense { size: usize },
    /// `H0`'s, `S`'s and `K`'s, with `H^-1 A^T` in `z`.
    Structured { m: usize, rows: usize },
}

fn grow<T: Clone + Default>(v: &mut Vec<T>, len: usize) {
    if v.len() < len {
        v.resize(len, T::default());
    }
}

impl Newton {
    /// Sizes every buffer for `n` joints and up to `pairs` pairs, so that no solve allocates.
    pub fn reserve(&mut self, n: usize, pairs: usize) {
        let r = (RANK * pairs).min(2 * n);
        let rows = pairs + 2;
        grow(&mut self.g, n);
        grow(&mut self.v, RANK * pairs * n);
        grow(&mut self.c, RANK * RANK * pairs);
        for v in [&mut self.g_free, &mut self.piv, &mut self.sol] {
            grow(v, n);
        }
        grow(&mut self.tmp, r.max(n));
        grow(&mut self.v_free, r * n);
        grow(&mut self.w, r * n);
        grow(&mut self.s_mat, r * r);
        grow(&mut self.s_perm, r);
        grow(&mut self.t, 2 * r);
        grow(&mut self.z, (r * r).max((rows + 1) * n));
        grow(&mut self.k_mat, rows * rows);
        grow(&mut self.k_perm, rows);
        grow(&mut self.lam, rows);
        let size = n + rows;
        grow(&mut self.dense, size * size);
        grow(&mut self.dense_perm, size);
        grow(&mut self.vc, RANK * n);
        grow(&mut self.a_free, rows * n);
    }

    /// Starts `H = I + G(g)` with the tip's term: `g_m = mu . (tip - p_m)`.
    pub fn begin(&mut self, pts: &[Vec2], mu: [f64; 2]) {
        let n = pts.len() - 1;
        self.n = n;
        grow(&mut self.g, n);
        let tip = pts[n];
        for m in 0..n {
            let r = tip - pts[m];
            self.g[m] = mu[0] * r.x + mu[1] * r.y;
        }
        self.cols = 0;
        self.factors = None;
    }

    /// Drops the kept factors (the matrix they factor belongs to another problem).
    pub fn forget(&mut self) {
        self.factors = None;
    }

    /// Whether [`Newton::solve_again`] has factors to use.
    pub fn has_factors(&self) -> bool {
        self.factors.is_some()
    }

    /// Adds `-nu` times the Hessian of the clearance of (`link`, `obstacle`) at `pts`; `h` is
    /// the forward-difference step of the contact's end points, m.
    pub fn add_pair(
        &mut self,
        world: &World,
        pts: &[Vec2],
        link: usize,
        obstacle: usize,
        nu: f64,
        h: f64,
    ) {
        let n = self.n;
        let shape = &world.obstacles()[obstacle].shape;
        let (p, q_end) = (pts[link - 1], pts[link]);
        let base = shape.segment_contact(p, q_end);
        let q = base.on_segment;
        let nrm = base.normal;
        for m in 0..link {
            let r = q - pts[m];
            self.g[m] += nu * (nrm.x * r.x + nrm.y * r.y);
        }
        // d phi / dX at the contact, and its forward differences along each coordinate.
        let grad = |s: f64, nrm: Vec2| [(1.0 - s) * nrm.x, (1.0 - s) * nrm.y, s * nrm.x, s * nrm.y];
        let g0 = grad(base.s, nrm);
        let mut hess = [[0.0; RANK]; RANK];
        for (k, column) in hess.iter_mut().enumerate() {
            let (mut a, mut b) = (p, q_end);
            match k {
                0 => a.x += h,
                1 => a.y += h,
                2 => b.x += h,
                _ => b.y += h,
            }
            let moved = shape.segment_contact(a, b);
            let gk = grad(moved.s, moved.normal);
            for i in 0..RANK {
                column[i] = (gk[i] - g0[i]) / h;
            }
        }
        let block = self.cols / RANK;
        grow(&mut self.c, (block + 1) * RANK * RANK);
        for i in 0..RANK {
            for k in 0..RANK {
                self.c[block * RANK * RANK + i * RANK + k] = -nu * 0.5 * (hess[i][k] + hess[k][i]);
            }
        }
        // The columns of J_X^T: P moves with joints before link - 1, Q with those before link.
        grow(&mut self.v, (self.cols + RANK) * n);
        for (k, (end, moved_by)) in [(p, link - 1), (q_end, link)].into_iter().enumerate() {
            let (cx, cy) = (self.cols + 2 * k, self.cols + 2 * k + 1);
            for a in 0..n {
                let (x, y) = if a < moved_by {
                    let r = end - pts[a];
                    (-r.y, r.x)
                } else {
                    (0.0, 0.0)
                };
                self.v[cx * n + a] = x;
                self.v[cy * n + a] = y;
            }
        }
        self.cols += RANK;
    }

    /// `out = H x` over all joints.
    pub fn apply(&self, x: &[f64], out: &mut [f64]) {
        let n = self.n;
        // G(g) x: g_a times the prefix sum through a, plus the suffix sum of g_b x_b after a.
        let mut suffix = 0.0;
        for a in (0..n).rev() {
            out[a] = x[a] + suffix;
            suffix += self.g[a] * x[a];
        }
        let mut prefix = 0.0;
        for a in 0..n {
            prefix += x[a];
            out[a] += self.g[a] * prefix;
        }
        self.add_low_rank(x, out, n, |i| i, n);
    }

    /// Adds `V C V^T x` to `out`, `V` read at the joints `at(0..len)` (of the `stride` rows).
    fn add_low_rank(
        &self,
        x: &[f64],
        out: &mut [f64],
        len: usize,
        at: impl Fn(usize) -> usize,
        stride: usize,
    ) {
        for block in 0..self.cols / RANK {
            let mut vx = [0.0; RANK];
            for (k, s) in vx.iter_mut().enumerate() {
                let col = &self.v[(block * RANK + k) * stride..];
                *s = (0..len).map(|i| col[at(i)] * x[i]).sum();
            }
            let c = &self.c[block * RANK * RANK..(block + 1) * RANK * RANK];
            for k in 0..RANK {
                let ck: f64 = (0..RANK).map(|e| c[k * RANK + e] * vx[e]).sum();
                if ck != 0.0 {
                    let col = &self.v[(block * RANK + k) * stride..];
                    for i in 0..len {
                        out[i] += col[at(i)] * ck;
                    }
                }
            }
        }
    }

    /// Entry `(a, b)` of `H` (the tests' reference).
    #[cfg(test)]
    pub fn entry(&self, a: usize, b: usize) -> f64 {
        let n = self.n;
        let mut h = f64::from(u8::from(a == b)) + self.g[a.max(b)];
        for block in 0..self.cols / RANK {
            let c = &self.c[block * RANK * RANK..(block + 1) * RANK * RANK];
            for i in 0..RANK {
                let va = self.v[(block * RANK + i) * n + a];
                if va == 0.0 {
                    continue;
                }
                for k in 0..RANK {
                    h += va * c[i * RANK + k] * self.v[(block * RANK + k) * n + b];
                }
            }
        }
        h
    }

    /// Solves the KKT system over the free joints `free` (increasing): `H_ff d - A^T lambda =
    /// r1`, `A d = r2`, the rows of `A` given by `row(i, joint)` for `i < rows`, `out[..m]`
    /// holding `r1` and `out[m..m + rows]` `r2` on entry. On success (true) `out[..m]` holds
    /// `d` and `out[m..m + rows]` `lambda`; false when the system is singular. Takes the route
    /// of fewer operations (see the module doc).
    pub fn solve_kkt(
        &mut self,
        free: &[usize],
        rows: usize,
        row: impl Fn(usize, usize) -> f64 + Copy,
        out: &mut [f64],
    ) -> bool {
        let (m, r) = (free.len(), self.cols);
        let size = m + rows;
        let structured =
            r * r * m + r * r * r / 3 + (rows + 1) * (2 * r * m + r * r) + rows * rows * m;
        let dense = size * size * size / 3 + m * m * (r + 1);
        if r <= 2 * m && STRUCTURED_WEIGHT * structured < dense {
            if let Some(ok) = self.solve_structured(free, rows, row, out) {
                return ok;
            }
        }
        self.solve_dense(free, rows, row, out)
    }

    /// Solves the system the last successful KKT solve solved (by either route; the same free
    /// joints and rows) for another right-hand side in `out`, with its factors: a few
    /// operations per entry of the matrix instead of a factorization. False without factors
    /// (none kept since the last [`Newton::begin`]) or with a non-finite answer.
    pub fn solve_again(&mut self, out: &mut [f64]) -> bool {
        match self.factors {
            None => false,
            Some(Factors::Dense { size }) => {
                lu_apply(&self.dense, &self.dense_perm, size, &mut out[..size]);
                out[..size].iter().all(|v| v.is_finite())
            }
            Some(Factors::Structured { m, rows }) => {
                // z1 = H^-1 r1, then K lambda = r2 - A z1 and d = z1 + Z lambda.
                self.tmp[..m].copy_from_slice(&out[..m]);
                self.apply_inverse(rows, m);
                self.finish_structured(m, rows, out);
                out[..m + rows].iter().all(|v| v.is_finite())
            }
        }
    }

    /// [`Newton::solve_kkt`] with the whole KKT matrix assembled and factorized.
    pub(super) fn solve_dense(
        &mut self,
        free: &[usize],
        rows: usize,
        row: impl Fn(usize, usize) -> f64,
        out: &mut [f64],
    ) -> bool {
        self.factors = None;
        let (m, n) = (free.len(), self.n);
        let size = m + rows;
        grow(&mut self.dense, size * size);
        grow(&mut self.dense_perm, size);
        grow(&mut self.vc, RANK * m);
        let kkt = &mut self.dense[..size * size];
        // I + G(g) on the free joints, then the constraint borders.
        for (i, &a) in free.iter().enumerate() {
            for (j, &b) in free.iter().enumerate() {
                kkt[i * size + j] = f64::from(u8::from(i == j)) + self.g[a.max(b)];
            }
            for l in 0..rows {
                let g = row(l, a);
                kkt[i * size + m + l] = -g;
                kkt[(m + l) * size + i] = g;
            }
        }
        for i in m..size {
            kkt[i * size + m..(i + 1) * size]
                .iter_mut()
                .for_each(|v| *v = 0.0);
        }
        // V C V^T a block at a time: the block's four columns of V on the free joints, then
        // row by row (V C)_i times them.
        for block in 0..self.cols / RANK {
            let c = &self.c[block * RANK * RANK..(block + 1) * RANK * RANK];
            for k in 0..RANK {
                let col = &self.v[(block * RANK + k) * n..(block * RANK + k + 1) * n];
                for (dst, &b) in self.vc[k * m..(k + 1) * m].iter_mut().zip(free) {
                    *dst = col[b];
                }
            }
            let (v0, rest) = self.vc[..RANK * m].split_at(m);
            let (v1, rest) = rest.split_at(m);
            let (v2, v3) = rest.split_at(m);
            for (i, row) in kkt.chunks_exact_mut(size).take(m).enumerate() {
                let vi = [v0[i], v1[i], v2[i], v3[i]];
                let w: [f64; RANK] =
                    std::array::from_fn(|k| (0..RANK).map(|e| vi[e] * c[e * RANK + k]).sum());
                if w.iter().all(|&x| x == 0.0) {
                    continue;
                }
                for ((((h, a), b), cc), d) in row[..m].iter_mut().zip(v0).zip(v1).zip(v2).zip(v3) {
                    *h += w[0] * a + w[1] * b + w[2] * cc + w[3] * d;
                }
            }
        }
        let perm = &mut self.dense_perm[..size];
        if !lu_factor(kkt, perm, size) {
            return false;
        }
        lu_apply(kkt, perm, size, &mut out[..size]);
        let ok = out[..size].iter().all(|v| v.is_finite());
        if ok {
            self.factors = Some(Factors::Dense { size });
        }
        ok
    }

    /// [`Newton::solve_kkt`] by the structure; `None` when it cannot be used (`H0` near
    /// singular, or the low-rank part more than twice as wide as the free joints).
    pub(super) fn solve_structured(
        &mut self,
        free: &[usize],
        rows: usize,
        row: impl Fn(usize, usize) -> f64,
        out: &mut [f64],
    ) -> Option<bool> {
        self.factors = None;
        let m = free.len();
        let r = self.cols;
        if r > 2 * m {
            return None;
        }
        grow(&mut self.g_free, m);
        grow(&mut self.piv, m);
        for (i, &a) in free.iter().enumerate() {
            self.g_free[i] = self.g[a];
        }
        hessian::factor(&self.g_free[..m], &mut self.piv[..m])?;
        // V restricted to the free joints, and W = H0^-1 V.
        grow(&mut self.v_free, r * m);
        grow(&mut self.w, r * m);
        grow(&mut self.sol, m);
        for col in 0..r {
            for (i, &a) in free.iter().enumerate() {
                self.v_free[col * m + i] = self.v[col * self.n + a];
            }
            hessian::solve(
                &self.piv[..m],
                &self.v_free[col * m..(col + 1) * m],
                &mut self.sol[..m],
                &mut self.w[col * m..(col + 1) * m],
            );
        }
        // S = I + C (V^T W), factorized once; V^T W first (in `z`, free until the next step).
        grow(&mut self.s_mat, r * r);
        grow(&mut self.s_perm, r);
        grow(&mut self.tmp, r.max(m));
        grow(&mut self.z, r * r);
        // (symmetric, as H0 is: the upper triangle mirrored)
        for e in 0..r {
            let ve = &self.v_free[e * m..(e + 1) * m];
            for b in e..r {
                let wb = &self.w[b * m..(b + 1) * m];
                let d = ve.iter().zip(wb).map(|(v, w)| v * w).sum();
                self.z[e * r + b] = d;
                self.z[b * r + e] = d;
            }
        }
        for a in 0..r {
            let block = a / RANK;
            let c = &self.c[block * RANK * RANK + (a % RANK) * RANK..][..RANK];
            for b in 0..r {
                let mut s = f64::from(u8::from(a == b));
                for (k, &ck) in c.iter().enumerate() {
                    s += ck * self.z[(block * RANK + k) * r + b];
                }
                self.s_mat[a * r + b] = s;
            }
        }
        if !lu_factor(&mut self.s_mat[..r * r], &mut self.s_perm[..r], r) {
            return None;
        }
        // A on the free joints, a row at a time.
        grow(&mut self.a_free, rows * m);
        for (l, dst) in self.a_free.chunks_exact_mut(m).take(rows).enumerate() {
            for (d, &a) in dst.iter_mut().zip(free) {
                *d = row(l, a);
            }
        }
        // Z = H^-1 [A^T, r1]: the constraint columns first, r1 (in out[..m]) last.
        let cols = rows + 1;
        grow(&mut self.z, cols * m);
        for l in 0..cols {
            let src = if l < rows {
                &self.a_free[l * m..(l + 1) * m]
            } else {
                &out[..m]
            };
            self.tmp[..m].copy_from_slice(src);
            self.apply_inverse(l, m);
        }
        // K = A Z, factorized.
        grow(&mut self.k_mat, rows * rows);
        grow(&mut self.k_perm, rows);
        grow(&mut self.lam, rows);
        for i in 0..rows {
            let ai = &self.a_free[i * m..(i + 1) * m];
            for l in 0..rows {
                self.k_mat[i * rows + l] = dot(ai, &self.z[l * m..(l + 1) * m]);
            }
        }
        if !lu_factor(
            &mut self.k_mat[..rows * rows],
            &mut self.k_perm[..rows],
            rows,
        ) {
            return Some(false);
        }
        self.finish_structured(m, rows, out);
        let ok = out[..m + rows].iter().all(|v| v.is_finite());
        if ok {
            self.factors = Some(Factors::Structured { m, rows });
        }
        Some(ok)
    }

    /// The structured solve's last part, with `K` factorized and `z1 = H^-1 r1` in `z` after
    /// the constraint columns: `K lambda = r2 - A z1`, `d = z1 + Z lambda`, into `out`.
    fn finish_structured(&mut self, m: usize, rows: usize, out: &mut [f64]) {
        let z1 = rows * m;
        for i in 0..rows {
            let ai = &self.a_free[i * m..(i + 1) * m];
            self.lam[i] = out[m + i] - dot(ai, &self.z[z1..z1 + m]);
        }
        lu_apply(
            &self.k_mat[..rows * rows],
            &self.k_perm[..rows],
            rows,
            &mut self.lam[..rows],
        );
        for e in 0..m {
            let mut d = self.z[z1 + e];
            for l in 0..rows {
                d += self.lam[l] * self.z[l * m + e];
            }
            out[e] = d;
        }
        out[m..m + rows].copy_from_slice(&self.lam[..rows]);
    }

    /// `z[l] = H_ff^-1 tmp[..m]` by Woodbury, with the factors of `solve_kkt`.
    fn apply_inverse(&mut self, l: usize, m: usize) {
        let r = self.cols;
        let (piv, sol) = (&self.piv[..m], &mut self.sol[..m]);
        let z = &mut self.z[l * m..(l + 1) * m];
        hessian::solve(piv, &self.tmp[..m], sol, z);
        if r == 0 {
            return;
        }
        // t = C V^T z, then S u = t, then z -= W u.
        grow(&mut self.t, 2 * r);
        let (t, vz) = self.t.split_at_mut(r);
        for (v, col) in vz[..r].iter_mut().zip(self.v_free[..r * m].chunks_exact(m)) {
            *v = col.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
        }
        for a in 0..r {
            let block = a / RANK;
            t[a] = (block * RANK..(block + 1) * RANK)
                .map(|e| self.c[block * RANK * RANK + (a % RANK) * RANK + e % RANK] * vz[e])
                .sum();
        }
        lu_apply(&self.s_mat[..r * r], &self.s_perm[..r], r, t);
        for (&u, col) in t.iter().zip(self.w[..r * m].chunks_exact(m)) {
            for (x, w) in z.iter_mut().zip(col) {
                *x -= w * u;
            }
        }
    }
}

fn dot(x: &[f64], y: &[f64]) -> f64 {
    x.iter().zip(y).map(|(a, b)| a * b).sum()
}

/// LU factorization with partial pivoting in place (row-major, `size x size`), the row
/// permutation in `perm`; false when a pivot is below [`PIVOT_FLOOR`] of the largest entry.
pub(super) fn lu_factor(mat: &mut [f64], perm: &mut [usize], size: usize) -> bool {
    let mat = &mut mat[..size * size];
    let big = mat.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    if !(big > 0.0 && big.is_finite()) {
        return false;
    }
    for col in 0..size {
        let piv = (col..size).fold(col, |p, r| {
            if mat[r * size + col].abs() > mat[p * size + col].abs() {
                r
            } else {
                p
            }
        });
        perm[col] = piv;
        if mat[piv * size + col].abs() <= PIVOT_FLOOR * big {
            return false;
        }
        if piv != col {
            let (upper, lower) = mat.split_at_mut(piv * size);
            upper[col * size..(col + 1) * size].swap_with_slice(&mut lower[..size]);
        }
        // Eliminate below the pivot, a row slice at a time (no index checks in the loop).
        let (upper, lower) = mat.split_at_mut((col + 1) * size);
        let pivot_row = &upper[col * size + col..(col + 1) * size];
        let (p, right) = (pivot_row[0], &pivot_row[1..]);
        for row in lower.chunks_exact_mut(size) {
            let f = row[col] / p;
            row[col] = f;
            if f != 0.0 {
                for (x, &y) in row[col + 1..].iter_mut().zip(right) {
                    *x -= f * y;
                }
            }
        }
    }
    true
}

/// Solves with the factors of [`lu_factor`], `b` in place.
pub(super) fn lu_apply(lu: &[f64], perm: &[usize], size: usize, b: &mut [f64]) {
    let (lu, b) = (&lu[..size * size], &mut b[..size]);
    // The rows were swapped whole while factoring: all the swaps first, then L.
    for col in 0..size {
        b.swap(col, perm[col]);
    }
    for (r, row) in lu.chunks_exact(size).enumerate() {
        let v: f64 = row[..r].iter().zip(&b[..r]).map(|(l, x)| l * x).sum();
        b[r] -= v;
    }
    for (r, row) in lu.chunks_exact(size).enumerate().rev() {
        let v: f64 = row[r + 1..]
            .iter()
            .zip(&b[r + 1..])
            .map(|(u, x)| u * x)
            .sum();
        b[r] = (b[r] - v) / row[r];
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use crate::chain::Chain;
    use crate::world::clearance::pair_gradient;
    use crate::world::{Obstacle, Shape};
    use nalgebra::{DMatrix, DVector};

    fn world() -> World {
        let obstacles = vec![
            Obstacle {
                id: "disc".into(),
                shape: Shape::Circle {
                    center: Vec2::new(0.35, 0.45),
                    radius_m: 0.05,
                },
            },
            Obstacle {
                id: "box".into(),
                shape: Shape::Polygon {
                    points: vec![
                        Vec2::new(0.55, -0.2),
                        Vec2::new(0.7, -0.2),
                        Vec2::new(0.7, -0.05),
                        Vec2::new(0.55, -0.05),
                    ],
                },
            },
        ];
        World::new(0.01, 0.005, obstacles).unwrap()
    }

    /// The clearance gradient of (link, obstacle) at `theta`.
    fn gradient(world: &World, chain: &Chain, theta: &[f64], link: usize, obs: usize) -> Vec<f64> {
        let mut pts = vec![Vec2::zeros(); theta.len() + 1];
        chain.points_into(theta, &mut pts);
        let pair = world.pair(&pts, link, obs);
        let mut g = vec![0.0; theta.len()];
        pair_gradient(&pts, &pair, &mut g);
        g
    }

    /// The tests' 8-joint arm of 0.125 m links, its pose, and the pose's points.
    const N: usize = 8;
    const THETA: [f64; N] = [0.9, -0.2, -0.25, -0.3, -0.2, -0.3, -0.35, -0.4];

    fn arm() -> (Chain, Vec<Vec2>) {
        let chain = Chain::unlimited(vec![0.125; N], Vec2::zeros(), 0.0).unwrap();
        let mut pts = vec![Vec2::zeros(); N + 1];
        chain.points_into(&THETA, &mut pts);
        (chain, pts)
    }

    /// The KKT systems' shape: the free joints (joint 3 held) and three made-up rows.
    const FREE: [usize; 7] = [0, 1, 2, 4, 5, 6, 7];
    const ROWS: usize = 3;

    fn a_row(i: usize, j: usize) -> f64 {
        ((i * 7 + j * 3) % 5) as f64 - 2.0 + 0.1 * j as f64
    }

    /// The Hessian with a tip term and two pairs, one on each obstacle.
    fn two_pairs(world: &World, pts: &[Vec2]) -> Newton {
        let mut newton = Newton::default();
        newton.begin(pts, [0.3, -0.2]);
        newton.add_pair(world, pts, 4, 0, 0.7, 1e-7);
        newton.add_pair(world, pts, 8, 1, 0.2, 1e-7);
        newton
    }

    /// The answer of the KKT system of `newton` for `rhs`, assembled from its entries and
    /// solved by nalgebra.
    fn reference_solve(newton: &Newton, rhs: &[f64]) -> DVector<f64> {
        let m = FREE.len();
        let size = m + ROWS;
        let dense = DMatrix::from_fn(size, size, |r, c| match (r < m, c < m) {
            (true, true) => newton.entry(FREE[r], FREE[c]),
            (true, false) => -a_row(c - m, FREE[r]),
            (false, true) => a_row(r - m, FREE[c]),
            (false, false) => 0.0,
        });
        dense.lu().solve(&DVector::from_column_slice(rhs)).unwrap()
    }

    #[test]
    fn pair_hessian_matches_differences_of_the_gradient() {
        let world = world();
        let (n, theta) = (N, THETA);
        let (chain, pts) = arm();
        for (link, obs) in [(4, 0), (5, 0), (7, 1), (8, 1)] {
            let pair = world.pair(&pts, link, obs);
            assert!(
                pair.contact.distance_m > 0.0,
                "link {link} apart from {obs}"
            );
            let mut newton = Newton::default();
            newton.begin(&pts, [0.0, 0.0]);
            newton.add_pair(&world, &pts, link, obs, -1.0, 1e-7);
            // With mu = 0 and nu = -1, H - I is the pair's Hessian.
            let g0 = gradient(&world, &chain, &theta, link, obs);
            let step = 1e-6;
            for b in 0..n {
                let mut moved = theta.to_vec();
                moved[b] += step;
                let gb = gradient(&world, &chain, &moved, link, obs);
                for a in 0..n {
                    let fd = (gb[a] - g0[a]) / step;
                    let h = newton.entry(a, b) - f64::from(u8::from(a == b));
                    assert!(
                        (h - fd).abs() < 1e-4 * (1.0 + fd.abs()),
                        "link {link}, obstacle {obs}, ({a}, {b}): {h} against {fd}"
                    );
                }
            }
        }
    }

    #[test]
    fn both_kkt_routes_match_a_reference_solve() {
        let world = world();
        let (_, pts) = arm();
        let mut newton = two_pairs(&world, &pts);
        let size = FREE.len() + ROWS;
        let rhs: Vec<f64> = (0..size).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut structured = rhs.clone();
        assert_eq!(
            newton.solve_structured(&FREE, ROWS, a_row, &mut structured),
            Some(true)
        );
        let mut dense_out = rhs.clone();
        assert!(newton.solve_dense(&FREE, ROWS, a_row, &mut dense_out));
        let mut picked = rhs.clone();
        assert!(newton.solve_kkt(&FREE, ROWS, a_row, &mut picked));
        let want = reference_solve(&newton, &rhs);
        for out in [&structured, &dense_out, &picked] {
            for i in 0..size {
                assert!(
                    (out[i] - want[i]).abs() < 1e-9 * (1.0 + want[i].abs()),
                    "{i}"
                );
            }
        }
        // H x by the structure against the entries.
        let x: Vec<f64> = (0..N).map(|i| (i as f64 * 0.7).cos()).collect();
        let mut hx = vec![0.0; N];
        newton.apply(&x, &mut hx);
        for a in 0..N {
            let want: f64 = (0..N).map(|b| newton.entry(a, b) * x[b]).sum();
            assert!((hx[a] - want).abs() < 1e-12 * (1.0 + want.abs()), "{a}");
        }
    }

    #[test]
    fn a_second_right_hand_side_solves_with_the_kept_factors_of_either_route() {
        let world = world();
        let (_, pts) = arm();
        let size = FREE.len() + ROWS;
        let first: Vec<f64> = (0..size).map(|i| (i as f64 * 0.37).sin()).collect();
        let second: Vec<f64> = (0..size).map(|i| (i as f64 * 1.3).cos()).collect();
        for structured in [false, true] {
            let mut newton = two_pairs(&world, &pts);
            let mut out = second.clone();
            assert!(!newton.solve_again(&mut out), "no factors before a solve");
            let mut out = first.clone();
            if structured {
                assert_eq!(
                    newton.solve_structured(&FREE, ROWS, a_row, &mut out),
                    Some(true)
                );
            } else {
                assert!(newton.solve_dense(&FREE, ROWS, a_row, &mut out));
            }
            let want = reference_solve(&newton, &second);
            let mut again = second.clone();
            assert!(newton.solve_again(&mut again));
            for i in 0..size {
                assert!(
                    (again[i] - want[i]).abs() < 1e-9 * (1.0 + want[i].abs()),
                    "structured {structured}, entry {i}: {} against {}",
                    again[i],
                    want[i]
                );
            }
            newton.begin(&pts, [0.3, -0.2]);
            assert!(!newton.solve_again(&mut again), "begin drops the factors");
        }
    }
}
