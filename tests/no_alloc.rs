//! A control loop calls the resolvers every tick and talks to the bus every tick: once warmed
//! up, neither strategy may allocate, and neither may a whole read -> resolve -> write cycle on
//! the simulated chain. A counting global allocator checks it, per thread (the simulator's own
//! thread allocates as it likes).
#![allow(clippy::unwrap_used)]

use crate::alloc_support;

use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::resolve::sequential::Sequential;
use snakectl::resolve::Resolver;
use std::time::Duration;

use alloc_support::during as allocations;

/// Runs 200 ticks of 1 mm along a 5 mm circle through `resolver::resolve` after one warm-up tick.
fn ticks(resolver: &mut dyn Resolver, chain: &Chain) -> usize {
    let n = chain.len();
    let mut theta: Vec<f64> = (0..n).map(|i| 0.3 * ((i as f64) * 0.7).sin()).collect();
    let centre = chain.tip(&theta) - Vec2::new(0.005, 0.0);
    let target = |k: usize| {
        let a = k as f64 * 0.2;
        centre + Vec2::new(0.005 * a.cos(), 0.005 * a.sin())
    };
    resolver.resolve(chain, &mut theta, target(1)).unwrap();
    allocations(|| {
        for k in 2..200 {
            resolver.resolve(chain, &mut theta, target(k)).unwrap();
        }
    })
}

#[test]
fn warm_ticks_allocate_nothing() {
    for n in [8, 64] {
        let lim = Some(JointLimit { lo: -3.0, hi: 3.0 });
        let chain = Chain::new(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0, vec![lim; n]).unwrap();
        let mut sequential = Sequential::default();
        assert_eq!(ticks(&mut sequential, &chain), 0, "sequential, n = {n}");
        let mut overall = Overall::new(OverallOptions::default());
        assert_eq!(ticks(&mut overall, &chain), 0, "overall, n = {n}");
    }
}

/// One control cycle as the daemon's loop runs it: read positions and velocities (one Sync
/// Read), resolve the next tip target from the measured pose, write the goals (one Sync Write
/// through the limits wrapper).
#[test]
fn a_warm_read_resolve_write_cycle_allocates_nothing() {
    use snakectl::config::Config;
    use snakectl::connect::{self, Options};
    use snakectl::servo::arm::BringUpOptions;
    use snakectl::servo::{Fields, Goal, ServoBus, States};

    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    // A reply timeout a loaded test machine keeps (the file's 5 ms suits an idle one).
    let text = std::fs::read_to_string(path)
        .unwrap()
        .replace("reply_timeout_ms = 20 ", "reply_timeout_ms = 200");
    let config = Config::from_str(&text, path).unwrap();
    assert_eq!(
        config.arm().unwrap().settings().reply_timeout,
        Duration::from_millis(200)
    );
    let mut link = connect::open(&config, Options::default()).unwrap();
    let arm = link.arm.clone();
    arm.bring_up(&mut link.bus, BringUpOptions::default())
        .unwrap();
    let chain = config.chain();
    let ids = arm.ids();
    let fields = Fields {
        velocity: true,
        ..Fields::POSITION
    };
    let mut states = States::new();
    // The resolver continues from the last commanded pose (as the loop does); the measured
    // pose is read into its own buffer.
    let mut theta = config.home().to_vec();
    let mut measured = vec![0.0; theta.len()];
    let mut goals = vec![Goal { id: 0, ticks: 0 }; ids.len()];
    let mut overall = Overall::new(OverallOptions::default());
    let start = chain.tip(&theta);
    let mut cycle = |k: usize, theta: &mut Vec<f64>, measured: &mut Vec<f64>| {
        arm.read_states_into(&mut link.bus, &ids, fields, &mut states)
            .unwrap();
        for (i, (slot, reading)) in measured.iter_mut().zip(states.readings()).enumerate() {
            let measured = reading.as_ref().unwrap();
            *slot = arm.angle(i, measured.position_ticks).unwrap();
        }
        let a = k as f64 * 0.05;
        let target = start + Vec2::new(0.01 * a.sin(), 0.01 * (1.0 - a.cos()));
        overall.resolve(chain, theta, target).unwrap();
        arm.goals_into(theta, &mut goals).unwrap();
        link.bus.write_goals(&goals).unwrap();
    };
    for k in 0..3 {
        cycle(k, &mut theta, &mut measured);
    }
    let n = allocations(|| {
        for k in 3..103 {
            cycle(k, &mut theta, &mut measured);
        }
    });
    assert_eq!(n, 0, "allocations in 100 warm cycles");
    // The servos follow: the measured pose is within a few degrees of the commanded one.
    for (m, t) in measured.iter().zip(&theta) {
        assert!((m - t).abs() < 0.1, "measured {m} vs commanded {t}");
    }
    // The cycles did reach the servos: the goals were taken.
    let taken = link
        .bus
        .read(
            ids[0],
            snakectl::servo::Register::GoalPosition,
            Duration::from_millis(200),
        )
        .unwrap();
    assert_eq!(taken.value, i64::from(goals[0].ticks));
}
