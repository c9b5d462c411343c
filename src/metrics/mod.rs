//! The paper's five motion metrics between an old configuration `q` and a new one `p`
//! (DESIGN 3.5). Points run `p_0..p_n`, `p_n` the moved tip; `p_0` is the base of an arm or the
//! free end of a rope.
//!
//! With `delta_i = |p_i - q_i|`, segment lengths `ds_i = |q_{i+1} - q_i|` and the arc length
//! from the tip `sigma_i = ds_i + .. + ds_{n-1}` (`sigma_n = 0`):
//! - `M1 = sum_{i=0..n} delta_i^2` (m^2), every point including the tip;
//! - `M2 = sum_{i=0..n-1} delta_i ds_i` (m^2), the paper's discretized area functional (its eq. 8);
//! - `M3`, joint rotations squared (rad^2): for an arm every joint, `sum (theta_i - theta0_i)^2`,
//!   unwrapped (servo angles are continuous); for a rope the interior points only, the change of
//!   the angle between consecutive links wrapped to (-pi, pi];
//! - `M4 = sum_{i=0..n} sigma_i delta_i^2` (m^3);
//! - `M5`, rotations weighted by the arc length to the tip (m rad^2): for an arm
//!   `sum sigma_{i-1} (theta_i - theta0_i)^2` (joint i sits at `p_{i-1}`); for a rope
//!   `sum_{i=1..n-1} sigma_i dtheta_i^2`, `dtheta_i` the rotation at `p_i`.
//!
//! Weights grow away from the pulled tip, as the paper's text defines them.

use crate::chain::{wrap_angle, Chain, Vec2};

/// The five metrics of one motion.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Metrics {
    /// Sum of squared point displacements, m^2.
    pub m1: f64,
    /// Displacements weighted by segment length (the paper's area functional), m^2.
    pub m2: f64,
    /// Sum of squared joint rotations, rad^2.
    pub m3: f64,
    /// Squared displacements weighted by arc length from the tip, m^3.
    pub m4: f64,
    /// Squared joint rotations weighted by arc length from the tip, m rad^2.
    pub m5: f64,
}

impl Metrics {
    /// The metric by its number 1..=5 (the paper's numbering).
    pub fn get(&self, number: usize) -> Option<f64> {
        match number {
            1 => Some(self.m1),
            2 => Some(self.m2),
            3 => Some(self.m3),
            4 => Some(self.m4),
            5 => Some(self.m5),
            _ => None,
        }
    }
}

/// The arc length from the tip to every point of `old` (`sigma_0..sigma_n`), written to `out`.
pub fn arc_to_tip(old: &[Vec2], out: &mut [f64]) {
    let n = old.len() - 1;
    out[n] = 0.0;
    for i in (0..n).rev() {
        out[i] = out[i + 1] + (old[i + 1] - old[i]).norm();
    }
}

/// The positional metrics M1, M2, M4, which arms and ropes share.
fn positional(old: &[Vec2], new: &[Vec2], sigma: &[f64]) -> (f64, f64, f64) {
    let n = old.len() - 1;
    let (mut m1, mut m2, mut m4) = (0.0, 0.0, 0.0);
    for i in 0..=n {
        let d = (new[i] - old[i]).norm();
        m1 += d * d;
        m4 += sigma[i] * d * d;
        if i < n {
            m2 += d * (old[i + 1] - old[i]).norm();
        }
    }
    (m1, m2, m4)
}

/// Metrics of an arm moving from the pose `theta0` to `theta`.
///
/// # Panics
/// If the angle slices do not have one entry per joint.
pub fn arm(chain: &Chain, theta0: &[f64], theta: &[f64]) -> Metrics {
    let old = chain.points(theta0);
    let new = chain.points(theta);
    let mut sigma = vec![0.0; old.len()];
    arc_to_tip(&old, &mut sigma);
    let (m1, m2, m4) = positional(&old, &new, &sigma);
    let (mut m3, mut m5) = (0.0, 0.0);
    for (i, (t, t0)) in theta.iter().zip(theta0).enumerate() {
        let r = (t - t0) * (t - t0);
        m3 += r;
        m5 += sigma[i] * r;
    }
    Metrics { m1, m2, m3, m4, m5 }
}

/// Metrics of a free rope moving from the points `old` to `new` (n + 1 each, tip last).
///
/// # Panics
/// If the two point lists differ in length or are shorter than two points.
pub fn rope(old: &[Vec2], new: &[Vec2]) -> Metrics {
    assert_eq!(old.len(), new.len(), "same number of points");
    assert!(old.len() >= 2, "at least one link");
    let n = old.len() - 1;
    let mut sigma = vec![0.0; n + 1];
    arc_to_tip(old, &mut sigma);
    let (m1, m2, m4) = positional(old, new, &sigma);
    let heading = |pts: &[Vec2], i: usize| {
        let d = pts[i + 1] - pts[i];
        d.y.atan2(d.x)
    };
    let (mut m3, mut m5) = (0.0, 0.0);
    for (i, weight) in sigma.iter().enumerate().take(n).skip(1) {
        let before = heading(old, i) - heading(old, i - 1);
        let after = heading(new, i) - heading(new, i - 1);
        let r = wrap_angle(after - before);
        m3 += r * r;
        m5 += weight * r * r;
    }
    Metrics { m1, m2, m3, m4, m5 }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    /// Two unit links along +x from the origin; the arm swings its tip joint by 90 degrees.
    /// Old points (0,0) (1,0) (2,0); new (0,0) (1,0) (1,1).
    /// delta = 0, 0, sqrt(2); ds = 1, 1; sigma = 2, 1, 0.
    #[test]
    fn arm_hand_computed() {
        let chain = Chain::unlimited(vec![1.0, 1.0], Vec2::zeros(), 0.0).unwrap();
        let m = arm(&chain, &[0.0, 0.0], &[0.0, FRAC_PI_2]);
        assert!(close(m.m1, 2.0), "{m:?}"); // tip: |(1,1)-(2,0)|^2 = 2
        assert!(close(m.m2, 0.0), "{m:?}"); // tip excluded, others still
        assert!(close(m.m3, FRAC_PI_2 * FRAC_PI_2), "{m:?}");
        assert!(close(m.m4, 0.0), "{m:?}"); // sigma_n = 0 at the tip
        assert!(close(m.m5, 1.0 * FRAC_PI_2 * FRAC_PI_2), "{m:?}"); // joint 2 at p_1, sigma_1 = 1
    }

    /// The same arm turning its base joint by 90 degrees: new points (0,0) (0,1) (0,2).
    /// delta = 0, sqrt(2), sqrt(8); M1 = 0 + 2 + 8; M2 = 0*1 + sqrt(2)*1; M4 = 2*0 + 1*2 + 0;
    /// M3 = (pi/2)^2; M5 = sigma_0 (pi/2)^2 = 2 (pi/2)^2.
    #[test]
    fn arm_base_rotation_hand_computed() {
        let chain = Chain::unlimited(vec![1.0, 1.0], Vec2::zeros(), 0.0).unwrap();
        let m = arm(&chain, &[0.0, 0.0], &[FRAC_PI_2, 0.0]);
        assert!(close(m.m1, 10.0), "{m:?}");
        assert!(close(m.m2, 2f64.sqrt()), "{m:?}");
        assert!(close(m.m3, FRAC_PI_2.powi(2)), "{m:?}");
        assert!(close(m.m4, 2.0), "{m:?}");
        assert!(close(m.m5, 2.0 * FRAC_PI_2.powi(2)), "{m:?}");
    }

    /// A three-point rope: the free end moves and the interior angle opens.
    /// old (0,0) (1,0) (1,1) [a 90 degree left turn at p_1]; new (0,-1) (1,0) (1,1)...
    /// new link 1 heading 45 deg, link 2 heading 90 deg: interior angle 45 deg, change -45 deg.
    /// delta = 1, 0, 0; ds = 1, 1; sigma = 2, 1, 0.
    #[test]
    fn rope_hand_computed() {
        let old = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
        ];
        let s = 0.5f64.sqrt();
        let new = [
            Vec2::new(1.0 - s, -s),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
        ];
        let m = rope(&old, &new);
        let d0 = (new[0] - old[0]).norm_squared();
        let rot = std::f64::consts::FRAC_PI_4;
        assert!(close(m.m1, d0), "{m:?}");
        assert!(close(m.m2, d0.sqrt()), "{m:?}");
        assert!(close(m.m3, rot * rot), "{m:?}");
        assert!(close(m.m4, 2.0 * d0), "{m:?}");
        assert!(close(m.m5, rot * rot), "{m:?}"); // sigma_1 = 1
    }

    #[test]
    fn rope_rotations_are_wrapped_and_arm_rotations_are_not() {
        let chain = Chain::unlimited(vec![1.0, 1.0], Vec2::zeros(), 0.0).unwrap();
        let full = 2.0 * std::f64::consts::PI;
        let m = arm(&chain, &[0.0, 0.0], &[0.0, full]);
        assert!(close(m.m3, full * full));
        assert!(m.m1 < 1e-24);
        let pts = chain.points(&[0.0, 3.0]);
        let turned = chain.points(&[0.0, -3.0]);
        let m = rope(&pts, &turned);
        let wrapped = 2.0 * std::f64::consts::PI - 6.0;
        assert!(close(m.m3, wrapped * wrapped), "{m:?}");
    }

    #[test]
    fn no_motion_gives_zero() {
        let chain = Chain::unlimited(vec![0.3, 0.7, 0.2], Vec2::new(1.0, 2.0), 0.4).unwrap();
        let theta = [0.1, -0.5, 1.0];
        assert_eq!(arm(&chain, &theta, &theta), Metrics::default());
        let p = chain.points(&theta);
        let m = rope(&p, &p);
        assert!(m.m1 == 0.0 && m.m3 == 0.0 && m.m5 == 0.0);
        assert_eq!(m.get(6), None);
        assert_eq!(m.get(2), Some(m.m2));
    }
}
