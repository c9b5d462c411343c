//! Self-intersection of a planar chain: do two of its links cross or touch?
//!
//! Links are the segments `p_a..p_{a+1}` of a pose's points (link `a` from 0, as the joint
//! that turns it). Two links **touch** when they come within a clearance of each other:
//!
//! - **Non-adjacent** links (`b >= a + 2`): the distance between the two segments is at most
//!   the clearance (crossing segments are at distance 0).
//! - **Adjacent** links (`b = a + 1`) always meet at their shared joint, so they touch only
//!   when they fold back onto each other: the joint between them is turned by more than 90
//!   degrees and the far end of one comes within the clearance of the other. At a joint angle
//!   of exactly +-pi the two overlap.
//!
//! A chain whose middle link is shorter than the clearance always has its neighbours touching:
//! the clearance is meant to be small against every link (a millimetre against centimetres).
//!
//! Every pair is tested (O(n²), a bounding-box test first), nothing is allocated, and the
//! first pair found, in order of `a` then `b`, is reported. Points are taken as given: they
//! must be finite (a non-finite point never counts as touching).

use super::{Chain, Vec2};

/// The clearance, m, within which two links of the commanded pose count as touching: the
/// controller never sends a pose that brings two links closer than this.
pub const SELF_CLEARANCE_M: f64 = 1e-3;

/// The z part of the cross product.
pub fn cross(a: Vec2, b: Vec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// The point of the segment `a..b` nearest `p`, and its parameter (0 at `a`).
pub fn point_segment(p: Vec2, a: Vec2, b: Vec2) -> (Vec2, f64) {
    let ab = b - a;
    let l2 = ab.norm_squared();
    let s = if l2 > 0.0 {
        ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * s, s)
}

/// Squared distance from `p` to the segment `a..b`.
fn point_segment_distance2(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    (p - point_segment(p, a, b).0).norm_squared()
}

/// Whether the segments `a0..a1` and `b0..b1` cross properly: each one's ends strictly on
/// both sides of the other's line (an end on the other segment is no proper crossing).
fn segments_cross(a0: Vec2, a1: Vec2, b0: Vec2, b1: Vec2) -> bool {
    let (da, db) = (a1 - a0, b1 - b0);
    let (s0, s1) = (cross(db, a0 - b0), cross(db, a1 - b0));
    let (t0, t1) = (cross(da, b0 - a0), cross(da, b1 - a0));
    s0 * s1 < 0.0 && t0 * t1 < 0.0
}

/// Whether the segments `a0..a1` and `b0..b1` come within `c` (>= 0) of each other.
fn segments_within(a0: Vec2, a1: Vec2, b0: Vec2, b1: Vec2, c: f64) -> bool {
    // Bounding boxes grown by the clearance: most pairs of a chain end here.
    if a0.x.max(a1.x) + c < b0.x.min(b1.x)
        || b0.x.max(b1.x) + c < a0.x.min(a1.x)
        || a0.y.max(a1.y) + c < b0.y.min(b1.y)
        || b0.y.max(b1.y) + c < a0.y.min(a1.y)
    {
        return false;
    }
    // Touching and collinear overlaps put an end on the other segment (distance 0), which the
    // end-point distances below catch.
    if segments_cross(a0, a1, b0, b1) {
        return true;
    }
    let c2 = c * c;
    point_segment_distance2(a0, b0, b1) <= c2
        || point_segment_distance2(a1, b0, b1) <= c2
        || point_segment_distance2(b0, a0, a1) <= c2
        || point_segment_distance2(b1, a0, a1) <= c2
}

impl Chain {
    /// Whether links `a` and `b` (from 0, `a < b`, both below `points.len() - 1`) of the pose
    /// whose points are `points` (`p_0..p_n`) come within `clearance` m of each other (see the
    /// module doc for adjacent links). A negative clearance counts as 0.
    ///
    /// # Panics
    /// If `a >= b` or `b + 1 >= points.len()` (a programming error).
    pub fn links_touch(points: &[Vec2], a: usize, b: usize, clearance: f64) -> bool {
        assert!(
            a < b && b + 1 < points.len(),
            "two distinct links of the pose"
        );
        let c = clearance.max(0.0);
        if b == a + 1 {
            let (tail, joint, head) = (points[a], points[a + 1], points[a + 2]);
            // Folded by more than 90 degrees, then the far ends against the other link.
            if (tail - joint).dot(&(head - joint)) <= 0.0 {
                return false;
            }
            let c2 = c * c;
            point_segment_distance2(head, tail, joint) <= c2
                || point_segment_distance2(tail, joint, head) <= c2
        } else {
            segments_within(points[a], points[a + 1], points[b], points[b + 1], c)
        }
    }

    /// The first pair of links `(a, b)` (from 0, `a < b`) of the pose whose points are
    /// `points` that come within [`SELF_CLEARANCE_M`] of each other, or `None` when the pose is
    /// clear. Allocation-free, O(n²).
    ///
    /// ```
    /// use snakectl::chain::{Chain, Vec2};
    /// let c = Chain::unlimited(vec![1.0; 4], Vec2::zeros(), 0.0).unwrap();
    /// // A square: link 3 ends where link 0 starts, so they touch.
    /// let h = std::f64::consts::FRAC_PI_2;
    /// assert_eq!(Chain::self_intersects(&c.points(&[0.0, h, h, h])), Some((0, 3)));
    /// assert_eq!(Chain::self_intersects(&c.points(&[0.0, h, h, 0.0])), None);
    /// ```
    pub fn self_intersects(points: &[Vec2]) -> Option<(usize, usize)> {
        Self::self_intersects_within(points, SELF_CLEARANCE_M)
    }

    /// As [`Chain::self_intersects`], with the clearance given, m.
    pub fn self_intersects_within(points: &[Vec2], clearance: f64) -> Option<(usize, usize)> {
        let links = points.len().saturating_sub(1);
        for a in 0..links {
            for b in a + 1..links {
                if Self::links_touch(points, a, b, clearance) {
                    return Some((a, b));
                }
            }
        }
        None
    }

    /// The first pair of links that touch (within `clearance`) in the pose `points` but not in
    /// the pose `before` (same length), or `None`. A pose that already touches somewhere (a
    /// measured one, say) may then move on, as long as it brings no other pair into contact.
    ///
    /// # Panics
    /// If the two poses differ in length (a programming error).
    pub fn new_self_intersection(
        points: &[Vec2],
        before: &[Vec2],
        clearance: f64,
    ) -> Option<(usize, usize)> {
        assert_eq!(points.len(), before.len(), "two poses of one chain");
        let links = points.len().saturating_sub(1);
        for a in 0..links {
            for b in a + 1..links {
                if Self::links_touch(points, a, b, clearance)
                    && !Self::links_touch(before, a, b, clearance)
                {
                    return Some((a, b));
                }
            }
        }
        None
    }

    /// Whether links `a` and `b` (from 0, `a < b`) of the pose `points` cross properly: each
    /// one's ends strictly on both sides of the other's line. Adjacent links never do.
    ///
    /// # Panics
    /// If `b + 1 >= points.len()` (a programming error).
    pub fn links_cross(points: &[Vec2], a: usize, b: usize) -> bool {
        b > a + 1 && segments_cross(points[a], points[a + 1], points[b], points[b + 1])
    }

    /// How many pairs of non-adjacent links of the pose `points` cross properly (each link's
    /// ends strictly on both sides of the other's line). Allocation-free, O(n²).
    pub fn crossings(points: &[Vec2]) -> usize {
        let links = points.len().saturating_sub(1);
        let mut n = 0;
        for a in 0..links {
            for b in a + 2..links {
                let (a0, a1, b0, b1) = (points[a], points[a + 1], points[b], points[b + 1]);
                if a0.x.max(a1.x) < b0.x.min(b1.x)
                    || b0.x.max(b1.x) < a0.x.min(a1.x)
                    || a0.y.max(a1.y) < b0.y.min(b1.y)
                    || b0.y.max(b1.y) < a0.y.min(a1.y)
                {
                    continue;
                }
                n += usize::from(segments_cross(a0, a1, b0, b1));
            }
        }
        n
    }

    /// As [`Chain::new_self_intersection`], for a pose `before` that is tangled (two links in
    /// contact) and is to be untangled: the first pair that makes `points` worse than
    /// `before`, or `None`. Worse is:
    ///
    /// - a pair in contact that was not, and is no neighbour of a pair that was (`(a, b)`
    ///   neighbours `(a, b +- 1)` and `(a +- 1, b)`): a crossing may slide from one link onto
    ///   the next through the joint between them, nothing may touch anywhere else;
    /// - more pairs crossing than in `before` (the pair reported is then the first that
    ///   crosses in `points` and did not in `before`).
    ///
    /// So a tangled arm may move while its crossings slide toward a free end and fall off it,
    /// never gaining one. For a `before` clear of itself this is
    /// [`Chain::new_self_intersection`] but for pairs that cross without touching first (which
    /// a continuous motion cannot do).
    ///
    /// # Panics
    /// If the two poses differ in length (a programming error).
    pub fn worse_self_intersection(
        points: &[Vec2],
        before: &[Vec2],
        clearance: f64,
    ) -> Option<(usize, usize)> {
        assert_eq!(points.len(), before.len(), "two poses of one chain");
        let links = points.len().saturating_sub(1);
        let touched =
            |a: usize, b: usize| a < b && b < links && Self::links_touch(before, a, b, clearance);
        for a in 0..links {
            for b in a + 1..links {
                if !Self::links_touch(points, a, b, clearance) || touched(a, b) {
                    continue;
                }
                let neighbour = touched(a, b + 1)
                    || (b > 0 && touched(a, b - 1))
                    || touched(a + 1, b)
                    || (a > 0 && touched(a - 1, b));
                if !neighbour {
                    return Some((a, b));
                }
            }
        }
        if Self::crossings(points) > Self::crossings(before) {
            for a in 0..links {
                for b in a + 2..links {
                    if Self::links_cross(points, a, b) && !Self::links_cross(before, a, b) {
                        return Some((a, b));
                    }
                }
            }
        }
        None
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::f64::consts::{FRAC_PI_2, PI};

    use super::*;

    fn unit_chain(n: usize) -> Chain {
        Chain::unlimited(vec![1.0; n], Vec2::zeros(), 0.0).unwrap()
    }

    /// Brute force: the smallest distance between two segments, sampled finely.
    fn sampled_distance(a0: Vec2, a1: Vec2, b0: Vec2, b1: Vec2) -> f64 {
        let k = 400;
        let mut best = f64::INFINITY;
        for i in 0..=k {
            let p = a0 + (a1 - a0) * (i as f64 / k as f64);
            best = best.min(point_segment_distance2(p, b0, b1).sqrt());
            let q = b0 + (b1 - b0) * (i as f64 / k as f64);
            best = best.min(point_segment_distance2(q, a0, a1).sqrt());
        }
        best
    }

    #[test]
    fn crossing_touching_and_near_segments() {
        let v = |x, y| Vec2::new(x, y);
        // An X crosses.
        assert!(segments_within(
            v(0., 0.),
            v(1., 1.),
            v(0., 1.),
            v(1., 0.),
            0.0
        ));
        // A T touches at a point: within any clearance, even 0.
        assert!(segments_within(
            v(0., 0.),
            v(2., 0.),
            v(1., 0.),
            v(1., 1.),
            0.0
        ));
        // Collinear and overlapping.
        assert!(segments_within(
            v(0., 0.),
            v(2., 0.),
            v(1., 0.),
            v(3., 0.),
            0.0
        ));
        // Collinear with a gap of 0.5.
        assert!(!segments_within(
            v(0., 0.),
            v(1., 0.),
            v(1.5, 0.),
            v(3., 0.),
            0.4
        ));
        assert!(segments_within(
            v(0., 0.),
            v(1., 0.),
            v(1.5, 0.),
            v(3., 0.),
            0.5
        ));
        // Parallel 1 mm apart against a clearance of 0.9 and 1.1 mm.
        assert!(!segments_within(
            v(0., 0.),
            v(1., 0.),
            v(0., 1e-3),
            v(1., 1e-3),
            0.9e-3
        ));
        assert!(segments_within(
            v(0., 0.),
            v(1., 0.),
            v(0., 1e-3),
            v(1., 1e-3),
            1.1e-3
        ));
    }

    #[test]
    fn segment_test_agrees_with_brute_force() {
        // A small deterministic generator.
        let mut s = 12345u64;
        let mut unit = || {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut both = [0, 0];
        for _ in 0..3000 {
            let mut p = || Vec2::new(unit(), unit());
            let (a0, a1, b0, b1) = (p(), p(), p(), p());
            let c = 0.2 * unit();
            let d = sampled_distance(a0, a1, b0, b1);
            // The sampled distance is an upper bound, within 1/400 of a segment of the truth.
            if d > c + 0.01 {
                assert!(
                    !segments_within(a0, a1, b0, b1, c),
                    "{a0:?} {a1:?} {b0:?} {b1:?} {c}"
                );
                both[0] += 1;
            } else if d <= c {
                assert!(
                    segments_within(a0, a1, b0, b1, c),
                    "{a0:?} {a1:?} {b0:?} {b1:?} {c}"
                );
                both[1] += 1;
            }
        }
        assert!(both[0] > 100 && both[1] > 100, "{both:?}");
    }

    #[test]
    fn adjacent_links_touch_only_when_folded_back() {
        let c = unit_chain(2);
        for theta in [0.0, 1.0, -1.0, FRAC_PI_2, 3.0, -3.0] {
            assert_eq!(
                Chain::self_intersects(&c.points(&[0.3, theta])),
                None,
                "{theta}"
            );
        }
        for theta in [PI, -PI, PI - 1e-4, -PI + 1e-4] {
            assert_eq!(
                Chain::self_intersects(&c.points(&[0.3, theta])),
                Some((0, 1)),
                "{theta}"
            );
        }
        // Folded to within the clearance: asin(1 mm / 1 m) off pi.
        let edge = (SELF_CLEARANCE_M).asin();
        assert!(Chain::self_intersects(&c.points(&[0.0, PI - 0.99 * edge])).is_some());
        assert!(Chain::self_intersects(&c.points(&[0.0, PI - 1.01 * edge])).is_none());
        // A short link folded back lies along the long one.
        let c = Chain::unlimited(vec![1.0, 0.3], Vec2::zeros(), 0.0).unwrap();
        assert_eq!(Chain::self_intersects(&c.points(&[0.0, PI])), Some((0, 1)));
    }

    #[test]
    fn a_curl_touches_when_it_closes() {
        // Six unit links turning by the same angle: a hexagon closes at 60 degrees, where
        // link 5 ends on link 0's start; a tighter curl crosses, a looser one is clear.
        let c = unit_chain(6);
        let curl = |k: f64| c.points(&[0.0, k, k, k, k, k]);
        let hex = PI / 3.0;
        assert_eq!(Chain::self_intersects(&curl(hex)), Some((0, 5)));
        assert!(Chain::self_intersects(&curl(hex + 0.05)).is_some());
        assert_eq!(Chain::self_intersects(&curl(hex - 0.05)), None);
        assert_eq!(Chain::self_intersects(&curl(0.0)), None);
        // Only the new pair counts against a pose that already touches.
        let before = curl(hex);
        assert_eq!(
            Chain::new_self_intersection(&curl(hex + 0.01), &before, SELF_CLEARANCE_M),
            None
        );
        assert_eq!(
            Chain::new_self_intersection(&curl(hex), &curl(0.5), SELF_CLEARANCE_M),
            Some((0, 5))
        );
    }

    #[test]
    fn a_tangled_pose_may_move_while_it_gets_no_worse() {
        let v = Vec2::new;
        let c = SELF_CLEARANCE_M;
        // Link 3 (x = 2, downward) crosses link 0 (the x axis from 0 to 4).
        let before = [
            v(0., 0.),
            v(4., 0.),
            v(4., 2.),
            v(2., 2.),
            v(2., -1.),
            v(3., -1.),
        ];
        assert_eq!(Chain::self_intersects(&before), Some((0, 3)));
        assert_eq!(Chain::crossings(&before), 1);
        assert!(Chain::links_cross(&before, 0, 3));
        assert!(!Chain::links_cross(&before, 0, 1));
        // The joint between links 3 and 4 passes over link 0: the crossing slides onto link 4.
        let slid = [
            v(0., 0.),
            v(4., 0.),
            v(4., 2.),
            v(2., 2.),
            v(2., 0.5),
            v(3., -1.),
        ];
        assert!(Chain::links_cross(&slid, 0, 4));
        assert_eq!(Chain::worse_self_intersection(&slid, &before, c), None);
        // Which the rule for a clear pose would have stopped.
        assert_eq!(
            Chain::new_self_intersection(&slid, &before, c),
            Some((0, 4))
        );
        // Link 4 swung up across link 0 too: two crossings where there was one.
        let more = [
            v(0., 0.),
            v(4., 0.),
            v(4., 2.),
            v(2., 2.),
            v(2., -1.),
            v(3., 1.),
        ];
        assert_eq!(Chain::crossings(&more), 2);
        assert_eq!(
            Chain::worse_self_intersection(&more, &before, c),
            Some((0, 4))
        );
        // Link 4's end against link 1, far along the chain from the crossing.
        let elsewhere = [
            v(0., 0.),
            v(4., 0.),
            v(4., 2.),
            v(2., 2.),
            v(2., -1.),
            v(4., -5e-4),
        ];
        assert_eq!(
            Chain::worse_self_intersection(&elsewhere, &before, c),
            Some((1, 4))
        );
        // Untangled.
        let clear = [
            v(0., 0.),
            v(4., 0.),
            v(4., 2.),
            v(2., 2.),
            v(2., 1.),
            v(3., 1.),
        ];
        assert_eq!(Chain::self_intersects(&clear), None);
        assert_eq!(Chain::worse_self_intersection(&clear, &before, c), None);
    }

    #[test]
    fn one_link_and_a_straight_chain_are_clear() {
        let c = unit_chain(1);
        assert_eq!(Chain::self_intersects(&c.points(&[2.0])), None);
        let c = unit_chain(64);
        assert_eq!(Chain::self_intersects(&c.points(&[0.0; 64])), None);
        assert_eq!(Chain::self_intersects(&[]), None);
    }
}
