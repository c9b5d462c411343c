//! Warm ticks of the overall strategy among obstacles allocate nothing once warmed up, whether
//! the answer of the solve without obstacles stands or the body leans on an obstacle (checked
//! with a counting global allocator).
#![allow(clippy::unwrap_used)]

use crate::alloc_support;

use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::resolve::Resolver;
use snakectl::world::{Obstacle, Shape, World};

#[test]
fn warm_ticks_among_obstacles_allocate_nothing() {
    for n in [8, 24] {
        let lim = Some(JointLimit { lo: -3.0, hi: 3.0 });
        let chain = Chain::new(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0, vec![lim; n]).unwrap();
        let mut theta: Vec<f64> = (0..n).map(|i| 0.3 * ((i as f64) * 0.7).sin()).collect();
        let pts = chain.points(&theta);
        // Discs beside every third link, 3 mm beyond the clearance, sides alternating.
        let obstacles = (1..=n)
            .step_by(3)
            .enumerate()
            .map(|(k, link)| {
                let (a, b) = (pts[link - 1], pts[link]);
                let d = (b - a).normalize();
                let side = if k % 2 == 0 { 1.0 } else { -1.0 };
                let normal = Vec2::new(-d.y, d.x) * side;
                Obstacle {
                    id: format!("d{k}"),
                    shape: Shape::Circle {
                        center: (a + b) * 0.5 + normal * (0.02 + 0.01 + 0.005 + 0.003),
                        radius_m: 0.02,
                    },
                }
            })
            .collect();
        let world = World::new(0.01, 0.005, obstacles).unwrap();
        let mut overall = Overall::new(OverallOptions::default());
        overall.set_world(Some(world));
        let centre = chain.tip(&theta) - Vec2::new(0.02, 0.0);
        let target = |k: usize| {
            let a = k as f64 * 0.05;
            centre + Vec2::new(0.02 * a.cos(), 0.02 * a.sin())
        };
        let mut leaned = 0;
        let tick = |theta: &mut Vec<f64>, k: usize, overall: &mut Overall| {
            let ok = overall.resolve(&chain, theta, target(k)).is_ok();
            ok && overall.last_clearance().unwrap() < 0.005 + 1e-9
        };
        for k in 1..130 {
            tick(&mut theta, k, &mut overall);
        }
        let allocations = alloc_support::during(|| {
            for k in 130..390 {
                leaned += usize::from(tick(&mut theta, k, &mut overall));
            }
        });
        assert_eq!(allocations, 0, "n = {n}");
        assert!(leaned > 0, "n = {n}: the body never leaned on a disc");
    }
}
