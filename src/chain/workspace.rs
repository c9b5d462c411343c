//! Where the tip can be: a conservative bound computed once per chain, exact without limits.
//!
//! Working from the tip to the base, the set of tip positions relative to joint `i` (in the frame
//! of link `i - 1`) is enclosed in an annular sector: radii `[r_lo, r_hi]` around the joint and
//! bearings `[lo, hi]` (or every bearing). Adding link `i` translates the sector by `L_i` along
//! the link; the radii of the translated sector follow in closed form (the distance from the
//! origin to a point of it is `sqrt(L^2 + rho^2 + 2 L rho cos phi)`), its bearings by walking its
//! boundary with the bearing unwrapped (corners, the tangent points of its arcs, and arcs whose
//! circle holds the origin, which carry the bearing the long way round). Turning joint `i`
//! through its limits widens the bearings by the limit interval. Each step encloses a superset of
//! the true set, so the result never excludes a reachable point; without limits every bearing is
//! allowed at each step, annuli add exactly, and the ring `max(0, 2 max L - R) <= r <= R` comes
//! out exact.

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use super::{nearest_representative, JointLimit, Vec2};

/// The reachable set of the tip, as far as a quick test can tell without solving.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Workspace {
    /// Inner radius around the base: no pose puts the tip closer.
    pub r_min: f64,
    /// Outer radius: no pose puts the tip farther.
    pub r_max: f64,
    /// World-frame bearings `[lo, hi]` from the base that contain every tip position, when they
    /// do not cover the whole circle (`hi - lo < 2 pi`).
    pub bearing: Option<(f64, f64)>,
    /// True when the ring is exactly the reachable set (every joint unlimited). With limits the
    /// bounds still hold, but a target inside them may be out of reach.
    pub exact: bool,
}

/// What a quick workspace test says about a target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reachability {
    /// Certainly reachable.
    Inside,
    /// Certainly unreachable.
    Outside,
    /// Within the bounds of a limited chain: only a solver can tell.
    Unknown,
}

impl Workspace {
    /// Classifies a target given its offset from the base. `Outside` and `Inside` are certain up
    /// to a round-off margin (1e-12 of the reach), so that a reachable point on the edge is never
    /// called `Outside`; a limited chain answers `Unknown` within its bounds.
    pub fn classify(&self, offset: Vec2) -> Reachability {
        let d = offset.norm();
        let margin = 1e-12 * (1.0 + self.r_max);
        if d > self.r_max + margin || d < self.r_min - margin {
            return Reachability::Outside;
        }
        if self.exact {
            return Reachability::Inside;
        }
        if let Some((lo, hi)) = self.bearing {
            if d > margin {
                let phi = nearest_representative(offset.y.atan2(offset.x), 0.5 * (lo + hi));
                let slack = 1e-12 + margin / d;
                if phi < lo - slack || phi > hi + slack {
                    return Reachability::Outside;
                }
            }
        }
        Reachability::Unknown
    }
}

/// An annular sector around a joint: radii and, unless every bearing is possible, bearings.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sector {
    r_lo: f64,
    r_hi: f64,
    bearing: Option<(f64, f64)>,
}

/// Largest and smallest `cos phi` over `phi` in `[lo, hi]` (every bearing when `None`).
fn cos_range(bearing: Option<(f64, f64)>) -> (f64, f64) {
    let Some((lo, hi)) = bearing else {
        return (-1.0, 1.0);
    };
    let contains = |target: f64| {
        // Is some target + 2 pi k inside [lo, hi]?
        let k = ((lo - target) / TAU).ceil();
        target + k * TAU <= hi
    };
    let c_max = if contains(0.0) {
        1.0
    } else {
        lo.cos().max(hi.cos())
    };
    let c_min = if contains(PI) {
        -1.0
    } else {
        lo.cos().min(hi.cos())
    };
    (c_min, c_max)
}

/// Distance from the origin of `L + rho e^{i phi}` with `cos phi = c`.
fn reach(len: f64, rho: f64, c: f64) -> f64 {
    (len * len + rho * rho + 2.0 * len * rho * c)
        .max(0.0)
        .sqrt()
}

/// The sector seen from one joint further back: `sector` translated by `len` along +x.
fn translate(len: f64, s: Sector) -> Sector {
    let (c_min, c_max) = cos_range(s.bearing);
    let r_hi = reach(len, s.r_lo, c_max).max(reach(len, s.r_hi, c_max));
    let r_lo = reach(len, (-len * c_min).clamp(s.r_lo, s.r_hi), c_min);
    Sector {
        r_lo,
        r_hi,
        bearing: translated_bearing(len, s, r_lo),
    }
}

/// Bearings of the translated sector, or `None` when they may cover the whole circle.
fn translated_bearing(len: f64, s: Sector, r_lo: f64) -> Option<(f64, f64)> {
    if r_lo <= 1e-12 * len {
        return None;
    }
    // Whatever the bearings of the sector, it lies in the disk of radius r_hi: seen from the
    // origin at distance len from its centre, that disk spans +-asin(r_hi / len).
    let disk = (s.r_hi < len).then(|| {
        let half = (s.r_hi / len).asin();
        (-half, half)
    });
    let Some((lo, hi)) = s.bearing.filter(|(lo, hi)| hi - lo <= FRAC_PI_2) else {
        return disk;
    };
    // Extreme bearings lie on the boundary. Walk it (the outer arc from `lo` to `hi`, the edge
    // at `hi` inward, the inner arc back, the edge at `lo` outward) with the bearing unwrapped:
    // an arc whose circle holds the origin may carry the bearing more than half a turn, the
    // long way round, which no folding of the corners' bearings can tell.
    let point = |rho: f64, phi: f64| Vec2::new(len + rho * phi.cos(), rho * phi.sin());
    let bearing_of = |p: Vec2| p.y.atan2(p.x);
    let mut walk = Unwrapped::from(bearing_of(point(s.r_lo, lo)));
    // Along the arc of radius `rho` from where the walk is to `point(rho, to)`.
    let arc = |walk: &mut Unwrapped, rho: f64, from: f64, to: f64| {
        let end = bearing_of(point(rho, to));
        if rho >= len {
            // The origin is inside (or on) the circle: the bearing turns the way phi does (at
            // least half as fast), by less than a full turn.
            if from != to {
                let turn = (end - walk.at).rem_euclid(TAU);
                walk.go(walk.at + if to > from { turn } else { turn - TAU });
            }
        } else {
            // Outside the circle: the arc is seen within less than half a turn, its extremes
            // at the ends or where the line of sight touches it.
            if rho > 0.0 {
                let t = (-rho / len).acos();
                for tangent in [t, -t] {
                    let phi = nearest_representative(tangent, 0.5 * (lo + hi));
                    if phi >= lo && phi <= hi {
                        walk.pass(nearest_representative(bearing_of(point(rho, phi)), walk.at));
                    }
                }
            }
            walk.step(end);
        }
    };
    // A radial edge is a segment that misses the origin: less than half a turn, monotone.
    walk.step(bearing_of(point(s.r_hi, lo)));
    arc(&mut walk, s.r_hi, lo, hi);
    walk.step(bearing_of(point(s.r_lo, hi)));
    arc(&mut walk, s.r_lo, hi, lo);
    let Unwrapped {
        at,
        min,
        max,
        first,
    } = walk;
    if (at - first).abs() > PI {
        // The boundary winds around the origin.
        return None;
    }
    if max - min >= TAU {
        return None;
    }
    // Over half a turn only when the origin is inside an arc's circle, and then there is no
    // disk bound.
    let reference = 0.5 * (min + max);
    match disk {
        // Both bounds hold; keep the tighter one on each side.
        Some((dlo, dhi)) => {
            let shift = nearest_representative(0.0, reference);
            Some((min.max(dlo + shift), max.min(dhi + shift)))
        }
        None => Some((min, max)),
    }
}

/// A bearing followed along a path, unwrapped (it may run past +-pi), with its extremes.
struct Unwrapped {
    first: f64,
    at: f64,
    min: f64,
    max: f64,
}

impl From<f64> for Unwrapped {
    fn from(first: f64) -> Self {
        Self {
            first,
            at: first,
            min: first,
            max: first,
        }
    }
}

impl Unwrapped {
    /// Moves on to bearing `a`.
    fn go(&mut self, a: f64) {
        self.at = a;
        self.pass(a);
    }

    /// Moves on to bearing `a`, less than half a turn away.
    fn step(&mut self, a: f64) {
        self.go(nearest_representative(a, self.at));
    }

    /// Passes bearing `a` on the way (an extreme between two points).
    fn pass(&mut self, a: f64) {
        self.min = self.min.min(a);
        self.max = self.max.max(a);
    }
}

/// The sector turned by a joint through its limits (any angle when unlimited).
fn rotate(s: Sector, limit: Option<JointLimit>) -> Sector {
    let bearing = match (s.bearing, limit) {
        (Some((lo, hi)), Some(l)) if (hi + l.hi) - (lo + l.lo) < TAU => {
            Some((lo + l.lo, hi + l.hi))
        }
        _ => None,
    };
    Sector { bearing, ..s }
}

/// The workspace bound of a chain with these links, limits and base heading.
pub(super) fn bound(links: &[f64], limits: &[Option<JointLimit>], heading: f64) -> Workspace {
    let mut s = Sector {
        r_lo: 0.0,
        r_hi: 0.0,
        bearing: Some((0.0, 0.0)),
    };
    for (&len, &limit) in links.iter().zip(limits).rev() {
        s = rotate(translate(len, s), limit);
    }
    Workspace {
        r_min: s.r_lo,
        r_max: s.r_hi,
        bearing: s.bearing.map(|(lo, hi)| (lo + heading, hi + heading)),
        exact: limits.iter().all(Option::is_none),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::chain::Chain;
    use proptest::prelude::*;

    #[test]
    fn unlimited_chains_get_the_exact_ring() {
        for links in [
            vec![3.0, 1.0, 0.5],
            vec![1.0, 1.0],
            vec![0.2, 0.9, 0.3, 0.1],
        ] {
            let longest = links.iter().cloned().fold(0.0, f64::max);
            let total: f64 = links.iter().sum();
            let w = bound(&links, &vec![None; links.len()], 0.3);
            assert!((w.r_max - total).abs() < 1e-12, "{w:?}");
            assert!(
                (w.r_min - (2.0 * longest - total).max(0.0)).abs() < 1e-12,
                "{w:?}"
            );
            assert!(w.exact && w.bearing.is_none());
        }
    }

    #[test]
    fn a_folded_link_longer_than_the_one_before_is_seen_the_long_way_round() {
        // The second link is longer than the first and folds back: the circle its tip sweeps
        // around joint 2 holds joint 1, so from joint 1 the tip's bearing turns past the
        // backward direction, more than half a turn, over the second joint's range.
        let limits = vec![
            Some(JointLimit {
                lo: -3.03,
                hi: -0.84,
            }),
            Some(JointLimit { lo: 2.17, hi: 3.68 }),
        ];
        let chain = Chain::new(vec![0.52, 0.53], Vec2::new(0.3, -0.2), 0.0, limits).unwrap();
        let steps = 60;
        for i in 0..=steps {
            for j in 0..=steps {
                let theta = [
                    -3.03 + (3.03 - 0.84) * f64::from(i) / f64::from(steps),
                    2.17 + (3.68 - 2.17) * f64::from(j) / f64::from(steps),
                ];
                let tip = chain.tip(&theta);
                assert_ne!(
                    chain.classify(tip),
                    Reachability::Outside,
                    "{theta:?}: {:?}",
                    chain.workspace()
                );
            }
        }
        let (lo, hi) = chain.workspace().bearing.unwrap();
        assert!(hi - lo > PI && hi - lo < TAU, "{lo} {hi}");
    }

    #[test]
    fn tight_limits_exclude_folded_and_sideways_targets() {
        // Two unit links, every joint within +-0.1 rad, heading 0: the tip stays near (2, 0).
        let lim = Some(JointLimit { lo: -0.1, hi: 0.1 });
        let chain = Chain::new(vec![1.0, 1.0], Vec2::zeros(), 0.0, vec![lim, lim]).unwrap();
        let w = chain.workspace();
        assert!(
            (w.r_min - (2.0 + 2.0 * 0.1f64.cos()).sqrt()).abs() < 1e-12,
            "{w:?}"
        );
        let (lo, hi) = w.bearing.unwrap();
        assert!(lo >= -0.16 && hi <= 0.16, "{w:?}");
        assert_eq!(chain.classify(Vec2::new(1.5, 0.0)), Reachability::Outside);
        assert_eq!(chain.classify(Vec2::new(0.0, 1.999)), Reachability::Outside);
        assert_eq!(
            chain.classify(chain.tip(&[0.05, -0.07])),
            Reachability::Unknown
        );
    }

    proptest! {
        /// Soundness: no pose within the limits puts the tip where the bound says `Outside`.
        #[test]
        fn no_reachable_tip_is_called_outside(
            seed in 0u64..10_000, n in 1usize..10, heading in -4.0f64..4.0,
        ) {
            use rand::{Rng, SeedableRng};
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let links: Vec<f64> = (0..n).map(|_| rng.gen_range(0.1..2.0)).collect();
            let limits: Vec<Option<JointLimit>> = (0..n)
                .map(|_| {
                    if rng.gen_bool(0.2) {
                        return None;
                    }
                    let c = rng.gen_range(-3.0..3.0);
                    let w = rng.gen_range(0.01..2.5);
                    Some(JointLimit { lo: c - w, hi: c + w })
                })
                .collect();
            let chain = Chain::new(links, Vec2::new(0.3, -0.2), heading, limits.clone()).unwrap();
            for _ in 0..200 {
                // Corners of the box as well as interior points: extremes sit on limits.
                let theta: Vec<f64> = limits
                    .iter()
                    .map(|l| match l {
                        Some(l) => match rng.gen_range(0..4) {
                            0 => l.lo,
                            1 => l.hi,
                            _ => rng.gen_range(l.lo..l.hi),
                        },
                        None => rng.gen_range(-PI..PI),
                    })
                    .collect();
                let tip = chain.tip(&theta);
                prop_assert_ne!(
                    chain.classify(tip),
                    Reachability::Outside,
                    "pose {:?} tip {:?} bound {:?}", theta, tip, chain.workspace()
                );
            }
        }
    }
}
