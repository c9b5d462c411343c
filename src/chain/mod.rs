//! The planar serial chain: links, a fixed base pose, relative joint angles and joint limits.
//!
//! Conventions (used everywhere in the crate): links `L_1..L_n` run from the base to the tip;
//! joint `i` turns link `i` relative to link `i-1` (joint 1 relative to the base heading `h`) and
//! sits at point `p_{i-1}`. Absolute angle `phi_i = h + theta_1 + .. + theta_i`, points
//! `p_0 = base`, `p_i = p_{i-1} + L_i (cos phi_i, sin phi_i)`, tip `p_n`.
//!
//! The state of an arm is its angles, so link lengths are exact by construction. Everything here
//! is pure and allocation-free on the `_into` paths, so a control loop can call it every tick.
//! [`Chain::self_intersects`] tells whether two links of a pose cross or touch.

mod collide;
mod workspace;

use std::f64::consts::PI;

use nalgebra::{Matrix2xX, Vector2};

pub use collide::{cross, point_segment, SELF_CLEARANCE_M};
pub use workspace::{Reachability, Workspace};

/// A point or vector in the plane, in metres.
pub type Vec2 = Vector2<f64>;

/// Largest magnitude accepted for any length, angle or coordinate: beyond it `f64` round-off
/// swamps the 1e-9 m tolerances the resolvers promise.
pub const MAX_MAGNITUDE: f64 = 1e6;

/// A number for a message: as Rust writes it up to 1e15 in magnitude, in exponent form beyond
/// (a value such as 1e300 would otherwise print as 301 digits).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let tiny = self.0 != 0.0 && self.0.abs() < 1e-6;
        if (self.0.abs() < 1e15 && !tiny) || !self.0.is_finite() {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// Why a chain description was refused. Each variant names the offending item (1-based, as a
/// user counts joints) and carries the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ChainError {
    /// No links at all.
    #[error("the chain has no links")]
    Empty,
    /// A link length that is zero, negative, non-finite or absurdly large.
    #[error("link {link}: length {} m must be finite, positive and at most {MAX_MAGNITUDE}", Num(*.value))]
    BadLink {
        /// 1-based link index.
        link: usize,
        /// The length given.
        value: f64,
    },
    /// A base coordinate or heading that is non-finite or absurdly large.
    #[error("base: {} must be finite and at most {MAX_MAGNITUDE} in magnitude", Num(*.value))]
    BadBase {
        /// The offending value.
        value: f64,
    },
    /// The limit list does not have one entry per joint.
    #[error("limits: {got} entries for {joints} joints")]
    LimitCount {
        /// Entries given.
        got: usize,
        /// Joints in the chain.
        joints: usize,
    },
    /// A limit pair with `lo >= hi` or a non-finite bound.
    #[error("joint {joint}: limits [{lo}, {hi}] must be finite with lo < hi")]
    BadLimit {
        /// 1-based joint index.
        joint: usize,
        /// Lower bound, rad.
        lo: f64,
        /// Upper bound, rad.
        hi: f64,
    },
}

/// A joint angle outside its limits.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("joint {joint}: {} rad outside its limits [{lo}, {hi}]", Num(*.value))]
pub struct LimitViolation {
    /// 1-based joint index.
    pub joint: usize,
    /// The angle, rad.
    pub value: f64,
    /// Lower limit, rad.
    pub lo: f64,
    /// Upper limit, rad.
    pub hi: f64,
}

/// Closed interval of allowed relative angles for one joint, in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimit {
    /// Lower bound, rad.
    pub lo: f64,
    /// Upper bound, rad.
    pub hi: f64,
}

impl JointLimit {
    /// Whether `value` lies inside the closed interval.
    pub fn contains(&self, value: f64) -> bool {
        self.lo <= value && value <= self.hi
    }

    /// `value` moved into the interval.
    pub fn clamp(&self, value: f64) -> f64 {
        value.clamp(self.lo, self.hi)
    }
}

/// A planar serial chain with a fixed base pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    links: Vec<f64>,
    base: Vec2,
    heading: f64,
    limits: Vec<Option<JointLimit>>,
    reach: f64,
    workspace: Workspace,
    ring: Workspace,
}

fn finite_within(value: f64) -> bool {
    value.is_finite() && value.abs() <= MAX_MAGNITUDE
}

impl Chain {
    /// Builds a chain, checking every length and limit.
    ///
    /// `limits` holds one entry per joint (`None` = unlimited) or is empty for an unlimited chain.
    pub fn new(
        links: Vec<f64>,
        base: Vec2,
        heading: f64,
        limits: Vec<Option<JointLimit>>,
    ) -> Result<Self, ChainError> {
        if links.is_empty() {
            return Err(ChainError::Empty);
        }
        for (i, &l) in links.iter().enumerate() {
            if !(finite_within(l) && l > 0.0) {
                return Err(ChainError::BadLink {
                    link: i + 1,
                    value: l,
                });
            }
        }
        for v in [base.x, base.y, heading] {
            if !finite_within(v) {
                return Err(ChainError::BadBase { value: v });
            }
        }
        let limits = if limits.is_empty() {
            vec![None; links.len()]
        } else {
            limits
        };
        if limits.len() != links.len() {
            return Err(ChainError::LimitCount {
                got: limits.len(),
                joints: links.len(),
            });
        }
        for (i, lim) in limits.iter().enumerate() {
            if let Some(l) = lim {
                if !(finite_within(l.lo) && finite_within(l.hi) && l.lo < l.hi) {
                    return Err(ChainError::BadLimit {
                        joint: i + 1,
                        lo: l.lo,
                        hi: l.hi,
                    });
                }
            }
        }
        let reach: f64 = links.iter().sum();
        let workspace = workspace::bound(&links, &limits, heading);
        let longest = links.iter().cloned().fold(0.0, f64::max);
        let ring = Workspace {
            r_min: (2.0 * longest - reach).max(0.0),
            r_max: reach,
            bearing: None,
            exact: true,
        };
        Ok(Self {
            links,
            base,
            heading,
            limits,
            reach,
            workspace,
            ring,
        })
    }

    /// An unlimited chain: convenient for ropes and tests.
    pub fn unlimited(links: Vec<f64>, base: Vec2, heading: f64) -> Result<Self, ChainError> {
        Self::new(links, base, heading, Vec::new())
    }

    /// Number of joints (= number of links).
    pub fn len(&self) -> usize {
        self.links.len()
    }

    /// Always false: a chain has at least one link.
    pub fn is_empty(&self) -> bool {
        self.links.is_empty()
    }

    /// Link lengths, base to tip, metres.
    pub fn links(&self) -> &[f64] {
        &self.links
    }

    /// Base point `p_0`.
    pub fn base(&self) -> Vec2 {
        self.base
    }

    /// Base heading `h`, rad: the direction of link 1 when `theta_1 = 0`.
    pub fn heading(&self) -> f64 {
        self.heading
    }

    /// Per-joint limits (`None` = unlimited).
    pub fn limits(&self) -> &[Option<JointLimit>] {
        &self.limits
    }

    /// True when at least one joint has limits.
    pub fn is_limited(&self) -> bool {
        self.limits.iter().any(Option::is_some)
    }

    /// Total length `R = sum L`.
    pub fn reach(&self) -> f64 {
        self.reach
    }

    /// The first joint whose angle lies outside its limits, if any. Non-finite angles count as
    /// violations of any limit.
    pub fn check_limits(&self, theta: &[f64]) -> Result<(), LimitViolation> {
        for (i, (lim, &t)) in self.limits.iter().zip(theta).enumerate() {
            if let Some(l) = lim {
                if !l.contains(t) {
                    return Err(LimitViolation {
                        joint: i + 1,
                        value: t,
                        lo: l.lo,
                        hi: l.hi,
                    });
                }
            }
        }
        Ok(())
    }

    /// Writes `p_0..p_n` into `out` (length n + 1).
    ///
    /// # Panics
    /// If `theta.len() != n` or `out.len() != n + 1` (a programming error, not bad input).
    pub fn points_into(&self, theta: &[f64], out: &mut [Vec2]) {
        assert_eq!(theta.len(), self.len(), "one angle per joint");
        assert_eq!(out.len(), self.len() + 1, "n + 1 points");
        let mut phi = self.heading;
        let mut p = self.base;
        out[0] = p;
        for (i, (&l, &t)) in self.links.iter().zip(theta).enumerate() {
            phi += t;
            let (s, c) = phi.sin_cos();
            p += Vec2::new(l * c, l * s);
            out[i + 1] = p;
        }
    }

    /// `p_0..p_n` for the pose `theta`.
    pub fn points(&self, theta: &[f64]) -> Vec<Vec2> {
        let mut out = vec![Vec2::zeros(); self.len() + 1];
        self.points_into(theta, &mut out);
        out
    }

    /// `p_0..p_n` for a pose that came from elsewhere (a daemon's telemetry, a record):
    /// `None`, rather than a panic, when it does not have one angle per joint.
    pub fn checked_points(&self, theta: &[f64]) -> Option<Vec<Vec2>> {
        (theta.len() == self.len()).then(|| self.points(theta))
    }

    /// The most any point of the arm moves along the straight joint-space way from `a` to `b`,
    /// m: joint `i` turning by `|b_i - a_i|` moves a point by at most that times the length it
    /// carries (its link and every link after it).
    pub fn sweep(&self, a: &[f64], b: &[f64]) -> f64 {
        let (mut carried, mut sweep) = (0.0, 0.0);
        for ((&l, x), y) in self.links.iter().zip(a).zip(b).rev() {
            carried += l;
            sweep += (y - x).abs() * carried;
        }
        sweep
    }

    /// The most rounding each joint to its resolution (`quanta`, rad, one per joint) moves any
    /// point of the arm, m: half a tick of each joint times the length it carries.
    pub fn rounding_m(&self, quanta: &[f64]) -> f64 {
        let links = &self.links;
        quanta
            .iter()
            .enumerate()
            .map(|(i, q)| 0.5 * q * links[i.min(links.len())..].iter().sum::<f64>())
            .sum()
    }

    /// The tip `p_n` for the pose `theta`.
    pub fn tip(&self, theta: &[f64]) -> Vec2 {
        let mut phi = self.heading;
        let mut p = self.base;
        for (&l, &t) in self.links.iter().zip(theta) {
            phi += t;
            let (s, c) = phi.sin_cos();
            p += Vec2::new(l * c, l * s);
        }
        p
    }

    /// The 2 x n tip Jacobian from the points of a pose: column `i` is the tip's velocity per
    /// unit rate of joint `i`, the 90-degree rotation of `tip - p_{i-1}`.
    pub fn jacobian_from_points(points: &[Vec2], out: &mut Matrix2xX<f64>) {
        let n = points.len() - 1;
        let tip = points[n];
        for i in 0..n {
            let r = tip - points[i];
            out[(0, i)] = -r.y;
            out[(1, i)] = r.x;
        }
    }

    /// The 2 x n tip Jacobian at `theta`.
    pub fn jacobian(&self, theta: &[f64]) -> Matrix2xX<f64> {
        let pts = self.points(theta);
        let mut j = Matrix2xX::zeros(self.len());
        Self::jacobian_from_points(&pts, &mut j);
        j
    }

    /// Where the tip can be, computed once when the chain is built (see [`Workspace`]).
    ///
    /// Unlimited: exactly the ring `max(0, 2 max L - R) <= |t - b| <= R` (`exact = true`). With
    /// limits a conservative bound (`exact = false`): radii and, when the limits confine them,
    /// bearings that no pose within the limits leaves; a target inside them may still be out of
    /// reach, which only a solver can tell.
    pub fn workspace(&self) -> Workspace {
        self.workspace
    }

    /// The ring of the same links with every joint unlimited (what a strategy that ignores
    /// limits can reach).
    pub fn ring(&self) -> Workspace {
        self.ring
    }

    /// Quick reachability test of a tip target (see [`Chain::workspace`]).
    pub fn classify(&self, target: Vec2) -> Reachability {
        self.workspace.classify(target - self.base)
    }

    /// Relative angles of the polyline `points` (n + 1 points, `p_0` first), joint 1 measured
    /// from `heading`; each written as the representative nearest `near[i]` so angles move
    /// continuously and never jump by 2 pi.
    pub fn angles_from_points(heading: f64, points: &[Vec2], near: &[f64], out: &mut [f64]) {
        let mut prev = heading;
        for i in 0..out.len() {
            let d = points[i + 1] - points[i];
            let phi = d.y.atan2(d.x);
            out[i] = nearest_representative(phi - prev, near[i]);
            prev = phi;
        }
    }
}

/// `out` := `theta` with each joint rounded to a whole multiple of its resolution in `quanta`
/// (a joint of resolution 0 as it is): the pose as servos of that resolution take it.
pub fn round_to(theta: &[f64], quanta: &[f64], out: &mut [f64]) {
    for ((r, &t), &q) in out.iter_mut().zip(theta).zip(quanta) {
        *r = if q > 0.0 { (t / q).round() * q } else { t };
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI {
        w - 2.0 * PI
    } else {
        w
    }
}

/// The angle equal to `a` modulo 2 pi that is nearest `reference`.
pub fn nearest_representative(a: f64, reference: f64) -> f64 {
    reference + wrap_angle(a - reference)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {

    #[test]
    fn a_joint_move_sweeps_each_turn_times_what_it_carries_and_rounding_half_a_tick() {
        let c = Chain::unlimited(vec![0.08; 12], Vec2::zeros(), 0.0).unwrap();
        let a = [0.0; 12];
        let mut b = [0.0; 12];
        b[9] = 0.5;
        // Joint 10 carries the last three links.
        assert!((c.sweep(&a, &b) - 0.5 * 0.24).abs() < 1e-15);
        b[0] = -0.1;
        assert!((c.sweep(&a, &b) - (0.1 * 0.96 + 0.5 * 0.24)).abs() < 1e-15);
        // Twelve 4096-tick servos: 4.8 mm, the figure the controller plans with.
        let q = [std::f64::consts::TAU / 4096.0; 12];
        assert!(
            (c.rounding_m(&q) - 0.0048).abs() < 5e-5,
            "{}",
            c.rounding_m(&q)
        );
        let mut out = [0.0; 12];
        round_to(
            &[
                0.3 * q[0],
                0.6 * q[0],
                -1.6 * q[0],
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            &q,
            &mut out,
        );
        assert_eq!(&out[..3], &[0.0, q[0], -2.0 * q[0]]);
    }

    use super::*;

    fn chain3() -> Chain {
        Chain::unlimited(vec![1.0, 0.5, 0.25], Vec2::new(1.0, -2.0), 0.5).unwrap()
    }

    #[test]
    fn numbers_in_messages_stay_short() {
        let shown = |v: f64| Num(v).to_string();
        assert_eq!(shown(0.5), "0.5");
        assert_eq!(shown(-2.0), "-2");
        assert_eq!(shown(2e6), "2000000");
        assert_eq!(shown(1e15), "1e15");
        assert_eq!(shown(-1e300), "-1e300");
        assert_eq!(shown(f64::NAN), "NaN");
        assert_eq!(shown(f64::INFINITY), "inf");
    }

    #[test]
    fn forward_kinematics_hand_computed() {
        let c = Chain::unlimited(vec![1.0, 2.0], Vec2::new(1.0, 1.0), PI / 2.0).unwrap();
        let p = c.points(&[0.0, -PI / 2.0]);
        assert!((p[0] - Vec2::new(1.0, 1.0)).norm() < 1e-15);
        assert!((p[1] - Vec2::new(1.0, 2.0)).norm() < 1e-15);
        assert!((p[2] - Vec2::new(3.0, 2.0)).norm() < 1e-15);
        assert!((c.tip(&[0.0, -PI / 2.0]) - p[2]).norm() < 1e-15);
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let c = chain3();
        let theta = [0.3, -0.7, 1.1];
        let j = c.jacobian(&theta);
        for i in 0..3 {
            let h = 1e-6;
            let mut a = theta;
            let mut b = theta;
            a[i] += h;
            b[i] -= h;
            let fd = (c.tip(&a) - c.tip(&b)) / (2.0 * h);
            assert!((fd - j.column(i)).norm() < 1e-8, "column {i}");
        }
    }

    #[test]
    fn angles_round_trip_and_stay_near_reference() {
        let c = chain3();
        let theta = [0.3 + 2.0 * PI, -3.0, 3.1];
        let pts = c.points(&theta);
        let mut back = [0.0; 3];
        Chain::angles_from_points(c.heading(), &pts, &theta, &mut back);
        for (a, b) in theta.iter().zip(&back) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
    }

    #[test]
    fn workspace_ring_unlimited() {
        let c = Chain::unlimited(vec![3.0, 1.0, 0.5], Vec2::zeros(), 0.0).unwrap();
        let w = c.workspace();
        assert_eq!((w.r_min, w.r_max, w.exact), (1.5, 4.5, true));
        assert_eq!(c.classify(Vec2::new(1.0, 0.0)), Reachability::Outside);
        assert_eq!(c.classify(Vec2::new(2.0, 0.0)), Reachability::Inside);
        assert_eq!(c.classify(Vec2::new(4.6, 0.0)), Reachability::Outside);
    }

    #[test]
    fn limited_chain_is_not_claimed_reachable() {
        let lim = Some(JointLimit { lo: -0.1, hi: 0.1 });
        let c = Chain::new(vec![1.0, 1.0], Vec2::zeros(), 0.0, vec![lim, lim]).unwrap();
        assert_eq!(c.classify(c.tip(&[0.05, -0.07])), Reachability::Unknown);
        assert_eq!(c.classify(Vec2::new(1.99, 0.05)), Reachability::Outside); // too folded
        assert_eq!(c.classify(Vec2::new(0.0, 1.5)), Reachability::Outside);
        assert_eq!(c.classify(Vec2::new(0.0, 2.5)), Reachability::Outside);
        assert!(c.ring().exact && c.ring().r_max == 2.0 && c.ring().r_min == 0.0);
        assert_eq!(
            c.check_limits(&[0.0, 0.2]),
            Err(LimitViolation {
                joint: 2,
                value: 0.2,
                lo: -0.1,
                hi: 0.1
            })
        );
    }

    #[test]
    fn bad_chains_are_refused_with_the_item() {
        let z = Vec2::zeros();
        assert_eq!(Chain::unlimited(vec![], z, 0.0), Err(ChainError::Empty));
        assert!(matches!(
            Chain::unlimited(vec![1.0, 0.0], z, 0.0),
            Err(ChainError::BadLink { link: 2, .. })
        ));
        assert!(matches!(
            Chain::unlimited(vec![f64::NAN], z, 0.0),
            Err(ChainError::BadLink { link: 1, .. })
        ));
        let inverted = Some(JointLimit { lo: 1.0, hi: -1.0 });
        assert!(matches!(
            Chain::new(vec![1.0], z, 0.0, vec![inverted]),
            Err(ChainError::BadLimit { joint: 1, .. })
        ));
        assert!(matches!(
            Chain::unlimited(vec![1.0], Vec2::new(f64::INFINITY, 0.0), 0.0),
            Err(ChainError::BadBase { .. })
        ));
    }

    #[test]
    fn wrap_is_half_open() {
        assert!((wrap_angle(PI) - PI).abs() < 1e-15);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-15);
        assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-15);
        assert!((nearest_representative(0.1, 6.0) - (0.1 + 2.0 * PI)).abs() < 1e-12);
    }
}
