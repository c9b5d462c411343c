//! The elemental link motions of the sequential strategy: the closed-form tractrix step and the
//! paper's distance-minimization step, each with its 2x2 derivative with respect to the new
//! head position (used by the fixed-base correction).
//!
//! A rigid link of length `L` has head `P` and tail `T`; the head moves in a straight line to
//! `Q`. Under the tractrix the tail's velocity always points along the link, which integrates in
//! closed form (DESIGN 3.2). With `d = |Q - P|`, `u = (Q - P)/d`, `v = (P - T)/|P - T|`,
//! `k = exp(-d/L)`:
//!
//! ```text
//! T' = Q - (L/D) [ (1-k)(s + k(2-s)) u + 2k v ],   D = s + k^2 (2-s),   s = 1 + u.v
//! ```
//!
//! which is the design's `(1-k^2) + c0 (1-k)^2` and `(1+k^2) + c0 (1-k^2)` rewritten around
//! `s = 1 + c0 = |u + v|^2 / 2`. Computing `s` from `|u + v|` rather than `1 + u.v` keeps full
//! relative precision for a near head-on push, where `D` is the difference of nearly equal
//! numbers; `s` is clamped to `[0, 2]` (the clamp of `c0` to `[-1, 1]`).
//!
//! Numerical edge cases:
//! - `d = 0`: no motion, the tail stays.
//! - Exact head-on push (`s = 0`, the head moves straight toward the tail): the link translates
//!   rigidly. This equilibrium is unstable (a sideways offset `e` grows like `e exp(d/L)`), so the
//!   tie-break is stated: keep the link's direction.
//! - Long moves: `k` underflows to 0 for `d/L` beyond ~745. Then `D = s` and the tail trails
//!   straight behind the head (`T' = Q - L u`) unless `s = 0`, the tie-break above.

use nalgebra::Matrix2;

use crate::chain::Vec2;

/// Below this fraction of the link length a head motion counts as infinitesimal for derivatives.
const TINY_MOTION: f64 = 1e-12;

/// How each link's tail follows its head.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Propagation {
    /// The closed-form tractrix (exact for a straight head path).
    #[default]
    Tractrix,
    /// The paper's elemental distance minimization: the tail goes to the point at distance `L`
    /// from the new head on the line toward the old tail (also FABRIK's reaching step). Agrees
    /// with the tractrix to first order in `d/L`.
    Distance,
}

impl Propagation {
    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Propagation::Tractrix => "tractrix",
            Propagation::Distance => "distance",
        }
    }

    /// New tail position when the head of the link `head`-`tail` (length `len`) moves to
    /// `new_head`.
    pub fn step(self, head: Vec2, tail: Vec2, len: f64, new_head: Vec2) -> Vec2 {
        match self {
            Propagation::Tractrix => tractrix_step(head, tail, len, new_head),
            Propagation::Distance => distance_step(head, tail, len, new_head),
        }
    }

    /// The step and its derivative `dT'/dQ` (2x2) with respect to the new head position.
    pub fn step_with_derivative(
        self,
        head: Vec2,
        tail: Vec2,
        len: f64,
        new_head: Vec2,
    ) -> (Vec2, Matrix2<f64>) {
        match self {
            Propagation::Tractrix => tractrix_step_with_derivative(head, tail, len, new_head),
            Propagation::Distance => distance_step_with_derivative(head, tail, len, new_head),
        }
    }
}

/// Unit vector along the link from tail to head; `fallback` when the two coincide.
fn link_direction(head: Vec2, tail: Vec2) -> Vec2 {
    let a = head - tail;
    let n = a.norm();
    if n > 0.0 {
        a / n
    } else {
        Vec2::x()
    }
}

/// The closed-form tractrix step (see the module doc). Returns the new tail.
pub fn tractrix_step(head: Vec2, tail: Vec2, len: f64, new_head: Vec2) -> Vec2 {
    let m = new_head - head;
    let d = m.norm();
    let v = link_direction(head, tail);
    if d == 0.0 {
        return new_head - len * v;
    }
    let u = m / d;
    let s = ((u + v).norm_squared() * 0.5).clamp(0.0, 2.0);
    if s == 0.0 {
        // Exact head-on push: rigid translation (documented tie-break).
        return new_head - len * v;
    }
    let k = (-d / len).exp();
    let den = s + k * k * (2.0 - s);
    let a = (1.0 - k) * (s + k * (2.0 - s));
    new_head - (len / den) * (a * u + 2.0 * k * v)
}

/// [`tractrix_step`] with its derivative with respect to the new head position.
pub fn tractrix_step_with_derivative(
    head: Vec2,
    tail: Vec2,
    len: f64,
    new_head: Vec2,
) -> (Vec2, Matrix2<f64>) {
    let m = new_head - head;
    let d = m.norm();
    let v = link_direction(head, tail);
    if d <= TINY_MOTION * len {
        // Infinitesimal motion: the tail moves by the head's motion projected on the link.
        return (tractrix_step(head, tail, len, new_head), v * v.transpose());
    }
    let u = m / d;
    let s = ((u + v).norm_squared() * 0.5).clamp(0.0, 2.0);
    if s == 0.0 {
        return (new_head - len * v, v * v.transpose());
    }
    let k = (-d / len).exp();
    let c0 = s - 1.0;
    let den = s + k * k * (2.0 - s);
    let a = (1.0 - k) * (s + k * (2.0 - s));
    let b = 2.0 * k;
    let sum = a * u + b * v;
    let tail_new = new_head - (len / den) * sum;

    // Row-vector gradients with respect to Q.
    let pu = (Matrix2::identity() - u * u.transpose()) / d; // du/dQ
    let gk = u.transpose() * (-k / len); // dk/dQ
    let gc = v.transpose() * pu; // dc0/dQ
    let a_k = -2.0 * k - 2.0 * c0 * (1.0 - k);
    let a_c = (1.0 - k) * (1.0 - k);
    let d_k = 2.0 * k * (1.0 - c0);
    let d_c = 1.0 - k * k;
    let ga = gk * a_k + gc * a_c;
    let gd = gk * d_k + gc * d_c;
    let dsum = u * ga + pu * a + v * (gk * 2.0);
    let deriv = Matrix2::identity() - (dsum / den - sum * gd / (den * den)) * len;
    (tail_new, deriv)
}

/// The distance-minimization step: the tail on the segment from the new head toward the old
/// tail, at distance `len`. When the new head lands exactly on the old tail the direction is
/// undefined and the link keeps its direction.
pub fn distance_step(head: Vec2, tail: Vec2, len: f64, new_head: Vec2) -> Vec2 {
    let r = tail - new_head;
    let n = r.norm();
    if n == 0.0 {
        return new_head - len * link_direction(head, tail);
    }
    new_head + r * (len / n)
}

/// [`distance_step`] with its derivative with respect to the new head position.
pub fn distance_step_with_derivative(
    head: Vec2,
    tail: Vec2,
    len: f64,
    new_head: Vec2,
) -> (Vec2, Matrix2<f64>) {
    let r = tail - new_head;
    let n = r.norm();
    if n <= TINY_MOTION * len {
        let v = link_direction(head, tail);
        return (distance_step(head, tail, len, new_head), v * v.transpose());
    }
    let e = r / n;
    let deriv = Matrix2::identity() - (Matrix2::identity() - e * e.transpose()) * (len / n);
    (new_head + e * len, deriv)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Integrates the tractrix ODE (tail velocity along the link, head on a straight line) with
    /// classical RK4: the reference the closed form must match.
    fn rk4_tractrix(head: Vec2, tail: Vec2, new_head: Vec2, n: usize) -> Vec2 {
        let m = new_head - head;
        let f = |s: f64, t: Vec2| -> Vec2 {
            let h = head + m * s;
            let w = (h - t) / (h - t).norm();
            w * w.dot(&m)
        };
        let mut t = tail;
        let ds = 1.0 / n as f64;
        for i in 0..n {
            let s = i as f64 * ds;
            let k1 = f(s, t);
            let k2 = f(s + ds / 2.0, t + k1 * (ds / 2.0));
            let k3 = f(s + ds / 2.0, t + k2 * (ds / 2.0));
            let k4 = f(s + ds, t + k3 * ds);
            t += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (ds / 6.0);
        }
        t
    }

    fn polar(r: f64, a: f64) -> Vec2 {
        Vec2::new(r * a.cos(), r * a.sin())
    }

    proptest! {
        #[test]
        fn closed_form_matches_integrated_tractrix(
            link_angle in -3.2f64..3.2, move_angle in -3.2f64..3.2,
            len in 0.1f64..3.0, d_over_l in 0.0f64..3.0,
        ) {
            let head = Vec2::new(0.3, -0.2);
            let tail = head - polar(len, link_angle);
            let q = head + polar(d_over_l * len, move_angle);
            // Skip near head-on pushes, where the ODE itself is ill-conditioned.
            let c0 = polar(1.0, move_angle).dot(&polar(1.0, link_angle));
            prop_assume!(c0 > -0.99);
            let closed = tractrix_step(head, tail, len, q);
            let reference = rk4_tractrix(head, tail, q, 2000);
            prop_assert!((closed - reference).norm() < 1e-9 * len.max(1.0),
                "closed {closed:?} rk4 {reference:?}");
            prop_assert!(((closed - q).norm() - len).abs() < 1e-12 * len.max(1.0));
        }

        #[test]
        fn derivatives_match_finite_differences(
            link_angle in -3.2f64..3.2, move_angle in -3.2f64..3.2,
            len in 0.2f64..2.0, d_over_l in 0.05f64..3.0, distance in proptest::bool::ANY,
        ) {
            let prop = if distance { Propagation::Distance } else { Propagation::Tractrix };
            let head = Vec2::new(0.1, 0.4);
            let tail = head - polar(len, link_angle);
            let q = head + polar(d_over_l * len, move_angle);
            let c0 = polar(1.0, move_angle).dot(&polar(1.0, link_angle));
            prop_assume!(c0 > -0.95);
            prop_assume!((tail - q).norm() > 0.05 * len);
            let (_, jac) = prop.step_with_derivative(head, tail, len, q);
            let h = 1e-6 * len;
            for axis in 0..2 {
                let mut e = Vec2::zeros();
                e[axis] = h;
                let fd = (prop.step(head, tail, len, q + e) - prop.step(head, tail, len, q - e))
                    / (2.0 * h);
                prop_assert!((fd - jac.column(axis)).norm() < 1e-5 * (1.0 + jac.norm()),
                    "axis {axis}: fd {fd:?} analytic {:?}", jac.column(axis));
            }
        }
    }

    #[test]
    fn no_motion_keeps_the_tail() {
        let head = Vec2::new(1.0, 1.0);
        let tail = Vec2::new(0.0, 1.0);
        assert!((tractrix_step(head, tail, 1.0, head) - tail).norm() < 1e-15);
    }

    #[test]
    fn pulled_straight_away_translates_rigidly() {
        let head = Vec2::new(1.0, 0.0);
        let tail = Vec2::zeros();
        let t = tractrix_step(head, tail, 1.0, Vec2::new(3.5, 0.0));
        assert!((t - Vec2::new(2.5, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn head_on_push_translates_rigidly_even_when_k_underflows() {
        let head = Vec2::new(1.0, 0.0);
        let tail = Vec2::zeros();
        for d in [0.5, 30.0, 800.0, 1e5] {
            let t = tractrix_step(head, tail, 1.0, Vec2::new(1.0 - d, 0.0));
            assert!(t.x.is_finite() && t.y.is_finite(), "d = {d}");
            assert!(
                (t - Vec2::new(-d, 0.0)).norm() < 1e-9 * d.max(1.0),
                "d = {d}: {t:?}"
            );
        }
    }

    #[test]
    fn long_sideways_pull_trails_straight_behind() {
        let head = Vec2::new(1.0, 0.0);
        let tail = Vec2::zeros();
        let q = Vec2::new(1.0, 1000.0); // d/L = 1000: k underflows to 0
        let t = tractrix_step(head, tail, 1.0, q);
        assert!((t - Vec2::new(1.0, 999.0)).norm() < 1e-12, "{t:?}");
    }

    #[test]
    fn near_head_on_push_flips_over_a_long_move() {
        // A tiny sideways offset grows like exp(d/L): after a long push the link trails behind.
        let head = Vec2::new(1.0, 0.0);
        let tail = Vec2::zeros();
        let q = Vec2::new(-59.0, 1e-9);
        let t = tractrix_step(head, tail, 1.0, q);
        assert!(t.x.is_finite() && t.y.is_finite());
        assert!(((t - q).norm() - 1.0).abs() < 1e-9);
        assert!(t.x > q.x, "the tail now trails behind the head: {t:?}");
    }

    #[test]
    fn tractrix_is_the_limit_of_distance_substeps() {
        // Gap between m distance sub-steps and one tractrix step shrinks like 1/m.
        let head = Vec2::new(1.0, 0.0);
        let tail = Vec2::zeros();
        let q = Vec2::new(1.5, 0.8);
        let exact = tractrix_step(head, tail, 1.0, q);
        let mut gaps = Vec::new();
        for m in [10usize, 20, 40, 80, 160] {
            let (mut h, mut t) = (head, tail);
            for j in 1..=m {
                let nh = head + (q - head) * (j as f64 / m as f64);
                t = distance_step(h, t, 1.0, nh);
                h = nh;
            }
            gaps.push((t - exact).norm());
        }
        for w in gaps.windows(2) {
            let ratio = w[0] / w[1];
            assert!((1.8..2.2).contains(&ratio), "gaps {gaps:?}");
        }
    }
}
