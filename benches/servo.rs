//! One control-cycle exchange through the `ServoBus` trait: a Sync Write of 12 goals and a Sync
//! Read of 12 present positions, against the simulated chain on a pseudo-terminal, without and
//! with wire timing (1 Mbps, Return Delay Time 0).
//!
//! Run: `cargo bench --bench servo`. Throughput is in cycles per second ("elem/s"). The wire
//! bound with timing is `(28 + 21 N) * 10 / baud` = 2.8 ms for N = 12 at 1 Mbps; the simulator's
//! own bench (`cargo bench -p snakectl-sim --bench roundtrip`) measures the same exchange
//! straight through `dynamixel2`, so the difference is this layer's cost.

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::{Fields, Goal, ServoBus};
use snakectl_sim::{Model, RealClock, ServoSpec, SimConfig, SimHandle};

const N: u8 = 12;
const BAUD: u32 = 1_000_000;
const TIMEOUT: Duration = Duration::from_millis(20);

fn start(wire_timing: bool) -> (SimHandle, DynamixelBus) {
    let config = SimConfig {
        servos: (1..=N)
            .map(|id| ServoSpec::new(id, Model::Xl430W250))
            .collect(),
        baud: BAUD,
        return_delay_us: 0,
        wire_timing,
        ..SimConfig::default()
    };
    let handle = snakectl::connect::serve(config, Arc::new(RealClock)).expect("simulator");
    let bus = DynamixelBus::open_with_sysfs(handle.path(), BAUD, &Sysfs::new("/nonexistent"))
        .expect("open pty");
    (handle, bus)
}

/// One control cycle: goals out, positions back. Returns how many servos answered (on a
/// loaded machine a reply can miss its deadline; the plain loop below counts those).
fn cycle(bus: &mut DynamixelBus, ids: &[u8], goals: &[Goal]) -> usize {
    bus.write_goals(goals).expect("sync write");
    let states = bus
        .read_states(ids, Fields::POSITION, TIMEOUT)
        .expect("sync read");
    states.iter().filter(|s| s.is_ok()).count()
}

fn control_cycle(c: &mut Criterion) {
    let ids: Vec<u8> = (1..=N).collect();
    let goals = |k: u32| -> Vec<Goal> {
        ids.iter()
            .map(|&id| Goal {
                id,
                ticks: 1000 + (k % 2) as i32 * 1000,
            })
            .collect()
    };
    let expected =
        Duration::from_secs_f64(f64::from((28 + 21 * u32::from(N)) * 10) / f64::from(BAUD));
    let mut group = c.benchmark_group("servo_bus_cycle_12");
    group.throughput(Throughput::Elements(1));
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for (name, wire) in [("no_wire_timing", false), ("wire_timing_1mbps", true)] {
        let (handle, mut bus) = start(wire);
        let (a, b) = (goals(0), goals(1));
        let mut k = 0u32;
        group.bench_function(name, |bench| {
            bench.iter(|| {
                k = k.wrapping_add(1);
                cycle(&mut bus, &ids, if k % 2 == 0 { &a } else { &b })
            })
        });
        // A plain average beside criterion's figure.
        let rounds = if wire { 300 } else { 2000 };
        let t0 = Instant::now();
        let mut missed = 0;
        for i in 0..rounds {
            missed += ids.len() - cycle(&mut bus, &ids, if i % 2 == 0 { &a } else { &b });
        }
        let per = t0.elapsed() / rounds;
        println!(
            "{name}: {:.3} ms per cycle, {:.0} cycles/s, {missed} replies missed{}",
            per.as_secs_f64() * 1e3,
            1.0 / per.as_secs_f64(),
            if wire {
                format!(
                    " (wire bound {:.3} ms, {:+.1}%)",
                    expected.as_secs_f64() * 1e3,
                    (per.as_secs_f64() / expected.as_secs_f64() - 1.0) * 100.0
                )
            } else {
                String::new()
            }
        );
        drop(bus);
        handle.stop().expect("stop");
    }
    group.finish();
}

criterion_group!(benches, control_cycle);
criterion_main!(benches);
