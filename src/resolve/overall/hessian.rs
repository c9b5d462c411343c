//! The Lagrangian Hessian of the overall problem and its O(n) solve.
//!
//! For `L(theta, mu) = 1/2 |theta - theta0|^2 - mu . (tip(theta) - target)` the second
//! derivative of the tip along joints `a` and `b` is `-(tip - p_{m-1})` with `m = max(a, b)`
//! (a rotation of the Jacobian column, whose derivative is a second rotation). Hence
//!
//! ```text
//! H = I + G,   G_ab = g_max(a,b),   g_m = mu . (tip - p_{m-1}).
//! ```
//!
//! Restricting `H` to any increasing subsequence of joints (the free joints) keeps the same
//! shape, with `g` read at those joints. To solve `H x = y`, write `S_a = x_1 + .. + x_a`
//! (prefix sums, `S_0 = 0`). Row `a` reads `x_a + g_a S_a + sum_{b > a} g_b x_b = y_a`;
//! subtracting row `a + 1` from row `a` removes the suffix sum and leaves, for `a < m`,
//!
//! ```text
//! -S_{a-1} + (2 + g_a - g_{a+1}) S_a - S_{a+1} = y_a - y_{a+1},
//! ```
//!
//! and the last row `-S_{m-1} + (1 + g_m) S_m = y_m`. That is a symmetric tridiagonal system
//! `T S = U^{-1} y` with `H = U T U^T` (`U` the upper triangle of ones), so `H` and `T` have the
//! same inertia: the signs of the pivots of an `LDL^T` factorization of `T` count the negative
//! eigenvalues of `H`, which the second-order check of the solver needs.

/// A pivot below this fraction of its row's size (`2 + |g_a| + |g_a+1|`) is round-off: `H` is
/// then too near singular for its solve, or its inertia, to be trusted.
const PIVOT_FLOOR: f64 = 1e-13;

/// An `LDL^T` factorization of the tridiagonal `T` for a given `g` (pivots only: the
/// off-diagonal is -1, so the unit factor is `l_a = -1 / piv_{a-1}`).
pub(crate) struct Factor {
    /// Number of negative pivots: the number of negative eigenvalues of `H`.
    pub negative: usize,
}

/// Factorizes `T` for `g` (one entry per free joint) into `piv` (same length), which holds
/// the pivots' reciprocals: the solves multiply where they would divide.
///
/// Returns `None` when a pivot is too small for the solve to be trusted (`H` near singular).
pub(crate) fn factor(g: &[f64], piv: &mut [f64]) -> Option<Factor> {
    let m = g.len();
    let mut negative = 0;
    let mut prev = 0.0_f64;
    for a in 0..m {
        let diag = if a + 1 < m {
            2.0 + g[a] - g[a + 1]
        } else {
            1.0 + g[a]
        };
        let p = if a == 0 { diag } else { diag - prev };
        let scale = 2.0 + g[a].abs() + if a + 1 < m { g[a + 1].abs() } else { 0.0 };
        if !p.is_finite() || p.abs() <= PIVOT_FLOOR * scale {
            return None;
        }
        if p < 0.0 {
            negative += 1;
        }
        piv[a] = 1.0 / p;
        prev = piv[a];
    }
    Some(Factor { negative })
}

/// Solves `H x = y` with the pivots from [`factor`]; `s` is scratch of the same length.
pub(crate) fn solve(piv: &[f64], y: &[f64], s: &mut [f64], x: &mut [f64]) {
    let m = piv.len();
    if m == 0 {
        return;
    }
    // Forward: L z = U^{-1} y, then divide by the pivots (z kept in s).
    let mut z_prev = 0.0;
    for a in 0..m {
        let rhs = if a + 1 < m { y[a] - y[a + 1] } else { y[a] };
        let z = if a == 0 {
            rhs
        } else {
            rhs + z_prev * piv[a - 1]
        };
        s[a] = z;
        z_prev = z;
    }
    // Backward: L^T S = D^{-1} z.
    let mut next = 0.0;
    for a in (0..m).rev() {
        let v = if a + 1 < m {
            (s[a] + next) * piv[a]
        } else {
            s[a] * piv[a]
        };
        s[a] = v;
        next = v;
    }
    // x_a = S_a - S_{a-1}.
    let mut before = 0.0;
    for a in 0..m {
        x[a] = s[a] - before;
        before = s[a];
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use nalgebra::{DMatrix, DVector};

    fn dense(g: &[f64]) -> DMatrix<f64> {
        let m = g.len();
        DMatrix::from_fn(m, m, |a, b| {
            let d = if a == b { 1.0 } else { 0.0 };
            d + g[a.max(b)]
        })
    }

    #[test]
    fn structured_solve_matches_dense() {
        // A small deterministic generator keeps the test free of external seeds.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for m in [1usize, 2, 3, 5, 17, 64] {
            for _ in 0..20 {
                let g: Vec<f64> = (0..m).map(|_| 0.8 * next()).collect();
                let y: Vec<f64> = (0..m).map(|_| next()).collect();
                let mut piv = vec![0.0; m];
                let Some(f) = factor(&g, &mut piv) else {
                    continue;
                };
                let mut s = vec![0.0; m];
                let mut x = vec![0.0; m];
                solve(&piv, &y, &mut s, &mut x);
                let h = dense(&g);
                let want = h.clone().lu().solve(&DVector::from_vec(y.clone())).unwrap();
                let err = (DVector::from_vec(x) - &want).amax();
                assert!(err < 1e-9 * (1.0 + want.amax()), "m {m}: {err}");
                let neg = h
                    .symmetric_eigenvalues()
                    .iter()
                    .filter(|&&e| e < 0.0)
                    .count();
                assert_eq!(neg, f.negative, "inertia, m {m}");
            }
        }
    }

    #[test]
    fn singular_hessian_is_refused() {
        // g = -1 on a single joint gives H = 0.
        let mut piv = [0.0];
        assert!(factor(&[-1.0], &mut piv).is_none());
    }
}
