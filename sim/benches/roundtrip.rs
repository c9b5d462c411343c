//! Sync write + sync read round trips for 12 servos over the pseudo-terminal through the
//! `dynamixel2` client, without wire timing and with wire timing at 1 Mbps; and a single ping
//! with wire timing at the factory settings (57600 baud, 500 µs Return Delay Time).
//!
//! Run: `cargo bench -p snakectl-sim --bench roundtrip`. Throughput is in round trips per
//! second ("elem/s"). With wire timing the expected cycle is `(28 + 21 N) * 10 / baud + N * RDT`
//! = 2.8 ms for N = 12, RDT = 0 at 1 Mbps; the ping is `24 * 10 / 57600 + 500 µs` = 4.67 ms.
//! The tests assert only that replies never come earlier than these formulas; how close to
//! them the simulator keeps is measured here, where a busy machine cannot fail a build.

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use dynamixel2::instructions::SyncWriteData;
use dynamixel2::Bus;
use snakectl_sim::{spawn_pty, Model, RealClock, ServoSpec, SimConfig, SimHandle, Simulator};

const N: u8 = 12;
const BAUD: u32 = 1_000_000;
const GOAL_POSITION: u16 = 116;
const PRESENT_POSITION: u16 = 132;

type Client = Bus<Vec<u8>, Vec<u8>>;

fn start(wire_timing: bool) -> (SimHandle, Client) {
    let config = SimConfig {
        servos: (1..=N)
            .map(|id| ServoSpec::new(id, Model::Xl430W250))
            .collect(),
        baud: BAUD,
        return_delay_us: 0,
        wire_timing,
        ..SimConfig::default()
    };
    let sim = Simulator::new(config, Arc::new(RealClock)).expect("config");
    let handle = spawn_pty(sim).expect("pty");
    let bus = Bus::open_with_buffers(handle.path(), BAUD, vec![0; 1024], vec![0; 1024])
        .expect("open pty");
    (handle, bus)
}

/// One control cycle: goals out, positions back. Replies are matched by id (DESIGN 4).
fn cycle(bus: &mut Client, ids: &[u8], goal: u32) -> usize {
    bus.sync_write_u32(
        GOAL_POSITION,
        ids.iter().map(|&id| SyncWriteData {
            motor_id: id,
            data: goal,
        }),
    )
    .expect("sync write");
    bus.write_instruction(0xFE, 0x82, 4 + ids.len(), |buf| {
        buf[..2].copy_from_slice(&PRESENT_POSITION.to_le_bytes());
        buf[2..4].copy_from_slice(&4u16.to_le_bytes());
        buf[4..].copy_from_slice(ids);
    })
    .expect("sync read");
    let mut got = 0;
    for &id in ids {
        let p = bus
            .read_status_response_deadline(Instant::now() + Duration::from_millis(50))
            .expect("reply");
        assert_eq!(p.packet_id(), id);
        got += 1;
    }
    got
}

fn roundtrip(c: &mut Criterion) {
    let ids: Vec<u8> = (1..=N).collect();
    let expected =
        Duration::from_secs_f64(f64::from((28 + 21 * u32::from(N)) * 10) / f64::from(BAUD));
    let mut group = c.benchmark_group("sync_write_sync_read_12");
    group.throughput(Throughput::Elements(1));
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for (name, wire) in [("no_wire_timing", false), ("wire_timing_1mbps", true)] {
        let (handle, mut bus) = start(wire);
        let mut k = 0u32;
        group.bench_function(name, |b| {
            b.iter(|| {
                k = k.wrapping_add(1);
                cycle(&mut bus, &ids, 1000 + (k % 2) * 1000)
            })
        });
        // A plain figure next to criterion's, and the formula for the wire-timed case.
        let rounds = if wire { 300 } else { 2000 };
        let t0 = Instant::now();
        for i in 0..rounds {
            cycle(&mut bus, &ids, 1000 + (i % 2) * 1000);
        }
        let per = t0.elapsed() / rounds;
        println!(
            "{name}: {:.3} ms per round trip, {:.0} round trips/s{}",
            per.as_secs_f64() * 1e3,
            1.0 / per.as_secs_f64(),
            if wire {
                format!(
                    " (formula {:.3} ms, {:+.1}%)",
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

/// A ping at the factory settings with wire timing: the reply's lateness over the formula.
fn ping_factory(c: &mut Criterion) {
    let config = SimConfig {
        servos: vec![ServoSpec::new(1, Model::Xl430W250)],
        baud: 57_600,
        return_delay_us: 500,
        wire_timing: true,
        ..SimConfig::default()
    };
    let sim = Simulator::new(config, Arc::new(RealClock)).expect("config");
    let handle = spawn_pty(sim).expect("pty");
    let mut bus: Client = Bus::open_with_buffers(handle.path(), 57_600, vec![0; 256], vec![0; 256])
        .expect("open pty");
    let expected = Duration::from_secs_f64(24.0 * 10.0 / 57_600.0) + Duration::from_micros(500);
    let mut group = c.benchmark_group("ping_57600_rdt500");
    group.throughput(Throughput::Elements(1));
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    group.bench_function("wire_timing", |b| b.iter(|| bus.ping(1).expect("ping")));
    group.finish();
    let rounds = 200u32;
    let mut worst = Duration::ZERO;
    let t0 = Instant::now();
    for _ in 0..rounds {
        let t = Instant::now();
        bus.ping(1).expect("ping");
        worst = worst.max(t.elapsed());
    }
    let per = t0.elapsed() / rounds;
    println!(
        "ping at 57600 baud: {:.3} ms mean, {:.3} ms worst (formula {:.3} ms, mean {:+.1}%)",
        per.as_secs_f64() * 1e3,
        worst.as_secs_f64() * 1e3,
        expected.as_secs_f64() * 1e3,
        (per.as_secs_f64() / expected.as_secs_f64() - 1.0) * 100.0
    );
    drop(bus);
    handle.stop().expect("stop");
}

criterion_group!(benches, roundtrip, ping_factory);
criterion_main!(benches);
