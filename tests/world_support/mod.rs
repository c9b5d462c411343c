//! An exact distance from the arm's links to the obstacles written apart from the library's
//! own, so that the tests among obstacles check the controller against an independent measure.
#![allow(dead_code)]

use std::f64::consts::FRAC_PI_2;

use rand::{Rng, SeedableRng};
use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::world::{Obstacle, Shape, World};

/// The daemon's arm: 12 links of 0.08 m, limits +-2 rad, base at the origin heading up.
pub fn arm() -> Chain {
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    Chain::new(vec![0.08; 12], Vec2::zeros(), FRAC_PI_2, vec![lim; 12])
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Distance from `p` to the segment `a..b`.
pub fn point_segment(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    let d = b - a;
    let t = if d.norm_squared() > 0.0 {
        ((p - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + d * t)).norm()
}

/// Whether the segments `a..b` and `c..d` cross or touch.
pub fn segments_meet(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let orient = |p: Vec2, q: Vec2, r: Vec2| (q - p).perp(&(r - p));
    let (d1, d2) = (orient(c, d, a), orient(c, d, b));
    let (d3, d4) = (orient(a, b, c), orient(a, b, d));
    d1 * d2 <= 0.0 && d3 * d4 <= 0.0
}

/// Even-odd inside test.
pub fn inside(p: Vec2, poly: &[Vec2]) -> bool {
    let mut odd = false;
    for k in 0..poly.len() {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        if (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x) {
            odd = !odd;
        }
    }
    odd
}

/// The unsigned distance from the segment `a..b` to an obstacle (0 when they meet).
pub fn segment_distance(a: Vec2, b: Vec2, shape: &Shape) -> f64 {
    match shape {
        Shape::Circle { center, radius_m } => (point_segment(*center, a, b) - radius_m).max(0.0),
        Shape::Polygon { points } => {
            if inside(a, points) || inside(b, points) {
                return 0.0;
            }
            let mut best = f64::INFINITY;
            for k in 0..points.len() {
                let (c, d) = (points[k], points[(k + 1) % points.len()]);
                if segments_meet(a, b, c, d) {
                    return 0.0;
                }
                best = best
                    .min(point_segment(a, c, d))
                    .min(point_segment(b, c, d))
                    .min(point_segment(c, a, b))
                    .min(point_segment(d, a, b));
            }
            best
        }
    }
}

/// The least clearance of the pose `theta` of `chain`: every link against every obstacle, less
/// the world's link radius (infinite with no obstacles).
pub fn clearance(chain: &Chain, w: &World, theta: &[f64]) -> f64 {
    let p = chain.points(theta);
    let mut least = f64::INFINITY;
    for link in 1..p.len() {
        for o in w.obstacles() {
            least = least.min(segment_distance(p[link - 1], p[link], &o.shape) - w.link_radius_m());
        }
    }
    least
}

/// The daemon's home pose: 0.1 rad at every joint (the tip at about (-0.547, 0.720)).
pub fn home() -> Vec<f64> {
    vec![0.1; 12]
}

/// Seeded worlds (link radius 10 mm, clearance 5 mm) of one to six discs near the home pose's
/// tip, and a target below them: each world clear of the home pose by 10 mm, the target 30 mm
/// from every disc and within 0.9 of the reach. The moves where a `goto`'s body is caught, and
/// a `reach` has to go round, come from such worlds.
pub fn caught_moves(count: usize) -> Vec<(World, Vec2)> {
    let c = arm();
    let tip = c.tip(&home());
    let mut rng = rand::rngs::StdRng::seed_from_u64(22);
    let mut out = Vec::new();
    while out.len() < count {
        let obstacles = (0..rng.gen_range(1..=6))
            .map(|k| {
                let at = tip + Vec2::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.1));
                Obstacle {
                    id: format!("o{k}"),
                    shape: Shape::Circle {
                        center: at,
                        radius_m: rng.gen_range(0.01..0.04),
                    },
                }
            })
            .collect();
        let world = World::new(0.01, 0.005, obstacles).unwrap_or_else(|e| panic!("{e}"));
        let target = tip + Vec2::new(rng.gen_range(-0.35..0.35), rng.gen_range(-0.4..-0.1));
        let far = world.point_distance(target).is_some_and(|(d, _)| d > 0.03);
        if clearance(&c, &world, &home()) > 0.01 && far && target.norm() < 0.9 * c.reach() {
            out.push((world, target));
        }
    }
    out
}

/// Each pair of link and disc's clearance in the pose `theta` of `chain`, signed (negative
/// inside: the centre's distance to the link's axis less the radius and the link radius), at
/// `(link - 1) * discs + k`. Discs only.
pub fn disc_pairs(chain: &Chain, w: &World, theta: &[f64]) -> Vec<f64> {
    let p = chain.points(theta);
    let mut out = Vec::new();
    for link in 1..p.len() {
        for o in w.obstacles() {
            let Shape::Circle { center, radius_m } = o.shape else {
                panic!("discs only");
            };
            out.push(point_segment(center, p[link - 1], p[link]) - radius_m - w.link_radius_m());
        }
    }
    out
}

/// Seeded worlds (link radius 10 mm, clearance 5 mm) of one disc put onto the home pose's arm
/// (on a link from 3 to 12, its centre up to 5 mm beyond the link's capsule on either side, so
/// some are deep and some graze it), and a target 30 mm from the disc within 0.9 of the reach:
/// what a `reach` from a pose not clear starts from.
pub fn dropped_onto(count: usize) -> Vec<(World, Vec2)> {
    let c = arm();
    let pts = c.points(&home());
    let tip = c.tip(&home());
    let mut rng = rand::rngs::StdRng::seed_from_u64(51);
    let mut out = Vec::new();
    while out.len() < count {
        let link = rng.gen_range(3..=12);
        let (a, b) = (pts[link - 1], pts[link]);
        let r = rng.gen_range(0.01..0.04);
        let normal = Vec2::new(a.y - b.y, b.x - a.x).normalize();
        let off = rng.gen_range(-1.0..1.0) * (r + 0.015);
        let centre = a + (b - a) * rng.gen_range(0.1..0.9) + normal * off;
        let target = tip + Vec2::new(rng.gen_range(-0.25..0.25), rng.gen_range(-0.3..0.1));
        let drop = Obstacle {
            id: "drop".into(),
            shape: Shape::Circle {
                center: centre,
                radius_m: r,
            },
        };
        let world = World::new(0.01, 0.005, vec![drop]).unwrap_or_else(|e| panic!("{e}"));
        let far = world.point_distance(target).is_some_and(|(d, _)| d > 0.03);
        if far && clearance(&c, &world, &home()) < 0.005 && target.norm() < 0.9 * c.reach() {
            out.push((world, target));
        }
    }
    out
}
