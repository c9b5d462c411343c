//! Fault injection (seeded, reproducible) and wire timing, on the core with a manual clock.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::{Duration, Instant};

use common::*;
use snakectl_sim::protocol::{self, error, instruction as ins, Frame, Parser, BROADCAST_ID};
use snakectl_sim::table::addr;
use snakectl_sim::{Fault, Model, ServoSpec, SimConfig, SimError};

fn sync_read_params(ids: &[u8]) -> Vec<u8> {
    let mut p = read_params(addr::PRESENT_POSITION, 4);
    p.extend_from_slice(ids);
    p
}

fn config(ids: &[u8], faults: Vec<Fault>) -> SimConfig {
    SimConfig {
        servos: xl430(ids),
        faults,
        ..SimConfig::default()
    }
}

/// Ids of the servos that answer a sync read addressed to 3, 2, 1, in reply order.
fn answering(s: &mut snakectl_sim::Simulator) -> Vec<u8> {
    send(
        s,
        BROADCAST_ID,
        ins::SYNC_READ,
        &sync_read_params(&[3, 2, 1]),
    )
    .iter()
    .map(|r| r.id)
    .collect()
}

#[test]
fn dropped_replies_leave_the_others() {
    let (mut s, _) = sim_with(config(
        &[1, 2, 3],
        vec![Fault::DropReplies {
            id: Some(2),
            fraction: 1.0,
        }],
    ));
    let r = send(
        &mut s,
        BROADCAST_ID,
        ins::SYNC_READ,
        &sync_read_params(&[1, 2, 3]),
    );
    assert_eq!(r.iter().map(|r| r.id).collect::<Vec<_>>(), [1, 3]);
    // The write itself still happened: only the reply is lost.
    assert!(send(&mut s, 2, ins::WRITE, &write_params(addr::LED, &[1])).is_empty());
    assert_eq!(s.servo(2).and_then(|x| x.value(addr::LED)), Some(1));
    assert_eq!(s.stats().dropped, 2);
}

fn drop_pattern(seed: u64) -> Vec<bool> {
    let mut cfg = config(
        &[1],
        vec![Fault::DropReplies {
            id: None,
            fraction: 0.5,
        }],
    );
    cfg.seed = seed;
    let (mut s, _) = sim_with(cfg);
    (0..400)
        .map(|_| send(&mut s, 1, ins::PING, &[]).is_empty())
        .collect()
}

#[test]
fn random_faults_are_reproducible_from_the_seed() {
    let a = drop_pattern(42);
    assert_eq!(a, drop_pattern(42));
    assert_ne!(a, drop_pattern(43));
    let dropped = a.iter().filter(|&&d| d).count();
    assert!((150..250).contains(&dropped), "{dropped} of 400");
}

#[test]
fn corrupted_replies_fail_their_crc() {
    let (mut s, _) = sim_with(config(
        &[1],
        vec![Fault::CorruptReplies {
            id: None,
            fraction: 1.0,
        }],
    ));
    let clean = protocol::encode_status(1, 0, &[0x24, 0x04, 48]);
    for _ in 0..20 {
        let r = send(&mut s, 1, ins::PING, &[]);
        assert_eq!(r[0].bytes.len(), clean.len());
        assert_ne!(r[0].bytes, clean);
        let frames = Parser::default().feed(&r[0].bytes, Instant::now());
        assert!(
            frames.is_empty() || matches!(frames[0].frame, Frame::BadCrc { .. }),
            "{frames:?}"
        );
    }
}

#[test]
fn extra_latency_delays_the_reply() {
    let (mut s, clock) = sim_with(config(
        &[1, 2],
        vec![Fault::ExtraLatency {
            id: Some(2),
            latency: Duration::from_millis(7),
        }],
    ));
    let now = snakectl_sim::Clock::now(&clock);
    assert_eq!(send(&mut s, 1, ins::PING, &[])[0].at, now);
    assert_eq!(
        send(&mut s, 2, ins::PING, &[])[0].at,
        now + Duration::from_millis(7)
    );
}

#[test]
fn a_servo_goes_silent_at_its_time() {
    let (mut s, clock) = sim_with(config(
        &[1, 2, 3],
        vec![Fault::Silent {
            id: 3,
            at: Duration::from_millis(500),
        }],
    ));
    assert_eq!(answering(&mut s), [3, 2, 1]);
    clock.advance(Duration::from_millis(499));
    assert_eq!(answering(&mut s), [3, 2, 1]);
    clock.advance(Duration::from_millis(1));
    assert_eq!(answering(&mut s), [2, 1]);
    // Silent means deaf too: a write to it is not carried out.
    send(
        &mut s,
        BROADCAST_ID,
        ins::WRITE,
        &write_params(addr::LED, &[1]),
    );
    assert_eq!(s.servos()[2].value(addr::LED), Some(0));
    assert_eq!(s.servos()[0].value(addr::LED), Some(1));
}

#[test]
fn timed_faults_follow_the_configured_servo_when_a_client_renumbers_it() {
    let (mut s, clock) = sim_with(config(
        &[1, 2, 3],
        vec![
            Fault::Silent { id: 3, at: ms(100) },
            Fault::HardwareError {
                id: 2,
                at: ms(100),
                kind: snakectl_sim::HardwareErrorKind::Encoder,
            },
        ],
    ));
    // Servo 3 becomes 7, servo 2 becomes 3, before the faults' time.
    assert_eq!(write(&mut s, 3, addr::ID, &[7]), 0);
    assert_eq!(write(&mut s, 2, addr::ID, &[3]), 0);
    clock.advance(ms(200));
    // The servo configured as 3 (now 7) went silent; the one configured as 2 (now 3) latched
    // the error, and only it.
    assert!(send(&mut s, 7, ins::PING, &[]).is_empty());
    assert_eq!(
        read(&mut s, 3, addr::HARDWARE_ERROR_STATUS, 1),
        (error::ALERT, 8)
    );
    assert_eq!(read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1), (0, 0));
}

#[test]
fn wire_timing_of_one_reply() {
    let (mut s, clock) = sim_with(SimConfig {
        servos: xl430(&[1]),
        baud: 57_600,
        return_delay_us: 500,
        wire_timing: true,
        ..SimConfig::default()
    });
    let t0 = snakectl_sim::Clock::now(&clock);
    let bt = Duration::from_nanos(10_000_000_000 / 57_600);
    let r = send(&mut s, 1, ins::PING, &[]);
    // 10 bytes in, 500 µs return delay, 14 bytes out.
    assert_eq!(r[0].at, t0 + bt * 10 + Duration::from_micros(500) + bt * 14);
}

/// The slot a broadcast ping gives each id: 3 ms (ROBOTIS' own Protocol 2.0 device firmware
/// counts the ids in steps of 3 ms; their SDK waits 3 ms an id for the replies).
const SLOT: Duration = Duration::from_millis(3);

/// A broadcast ping to servos configured as `ids` (out of id order, with gaps) at `baud`, with
/// a return delay of 100 µs: the replies, and the wire time of one byte.
fn broadcast_ping(ids: &[u8], baud: u32) -> (Vec<snakectl_sim::Reply>, Instant, Duration) {
    let (mut s, clock) = sim_with(SimConfig {
        servos: xl430(ids),
        baud,
        return_delay_us: 100,
        wire_timing: true,
        ..SimConfig::default()
    });
    let t0 = snakectl_sim::Clock::now(&clock);
    let r = send(&mut s, BROADCAST_ID, ins::PING, &[]);
    let byte = Duration::from_nanos(10_000_000_000 / u64::from(baud));
    (r, t0, byte)
}

#[test]
fn a_broadcast_ping_is_answered_in_id_order_each_servo_in_its_own_slot() {
    let (r, t0, byte) = broadcast_ping(&[7, 1, 3, 4], 57_600);
    assert_eq!(r.iter().map(|r| r.id).collect::<Vec<_>>(), [1, 3, 4, 7]);
    // Each reply: its servo's return delay, then 14 bytes.
    let reply = Duration::from_micros(100) + byte * 14;
    // Id 1 answers once the instruction's 10 bytes are in; id 3 one empty slot (id 2) after id
    // 1's reply; id 4 right after id 3's; id 7 two empty slots (5, 6) after id 4's.
    let at1 = byte * 10 + reply;
    let at3 = at1 + SLOT + reply;
    let at4 = at3 + reply;
    let at7 = at4 + SLOT * 2 + reply;
    let ends: Vec<Duration> = r.iter().map(|r| r.at - t0).collect();
    assert_eq!(ends, [at1, at3, at4, at7]);
}

#[test]
fn broadcast_ping_replies_never_overlap_even_when_one_outlasts_a_slot() {
    // At 9600 baud a 14-byte reply takes 14.6 ms, longer than a slot.
    for baud in [9_600, 57_600, 1_000_000] {
        let (r, _, byte) = broadcast_ping(&[2, 1, 3, 9, 10, 30], baud);
        assert_eq!(
            r.iter().map(|r| r.id).collect::<Vec<_>>(),
            [1, 2, 3, 9, 10, 30]
        );
        for w in r.windows(2) {
            let starts = w[1].at - byte * 14;
            assert!(starts > w[0].at, "{baud} Bd: id {} overlaps", w[1].id);
        }
    }
}

#[test]
fn wire_timing_of_a_sync_cycle_matches_the_formula() {
    for n in [1u8, 4, 12] {
        let ids: Vec<u8> = (1..=n).collect();
        let rdt_us = 20;
        let (mut s, clock) = sim_with(SimConfig {
            servos: xl430(&ids),
            baud: 1_000_000,
            return_delay_us: rdt_us,
            wire_timing: true,
            ..SimConfig::default()
        });
        let t0 = snakectl_sim::Clock::now(&clock);
        // Sync write of 4-byte goals and sync read of 4-byte positions, sent back to back.
        let mut sw = read_params(addr::GOAL_POSITION, 4);
        for &id in &ids {
            sw.push(id);
            sw.extend_from_slice(&2000i32.to_le_bytes());
        }
        let mut bytes = protocol::encode_instruction(BROADCAST_ID, ins::SYNC_WRITE, &sw);
        bytes.extend(protocol::encode_instruction(
            BROADCAST_ID,
            ins::SYNC_READ,
            &sync_read_params(&ids),
        ));
        let r = s.handle_bytes(&bytes);
        assert_eq!(r.len(), usize::from(n));
        let n = u32::from(n);
        let expected = Duration::from_micros(u64::from((28 + 21 * n) * 10))
            + Duration::from_micros(u64::from(rdt_us * n));
        let last = r.last().map(|r| r.at).unwrap_or(t0);
        assert_eq!(last - t0, expected, "n = {n}");
        // Replies are spaced by return delay plus their own 15 bytes.
        for w in r.windows(2) {
            assert_eq!(
                w[1].at - w[0].at,
                Duration::from_micros(u64::from(rdt_us) + 150)
            );
        }
    }
}

#[test]
fn configuration_is_validated() {
    let bad = |cfg: SimConfig| {
        snakectl_sim::Simulator::new(cfg, std::sync::Arc::new(snakectl_sim::RealClock))
            .err()
            .map(|e| e.to_string())
    };
    let mut c = config(&[1, 1], vec![]);
    assert!(matches!(
        snakectl_sim::Simulator::new(c.clone(), std::sync::Arc::new(snakectl_sim::RealClock)),
        Err(SimError::DuplicateId(1))
    ));
    c = config(&[1], vec![]);
    c.baud = 12345;
    assert!(bad(c).is_some_and(|e| e.contains("12345")));
    let mut c = config(
        &[1],
        vec![Fault::Silent {
            id: 9,
            at: Duration::ZERO,
        }],
    );
    assert!(bad(c.clone()).is_some_and(|e| e.contains("servo 9")));
    c.faults = vec![Fault::DropReplies {
        id: None,
        fraction: 1.5,
    }];
    assert!(bad(c.clone()).is_some());
    c.faults.clear();
    c.return_delay_us = 601;
    assert!(bad(c.clone()).is_some());
    let mut spec = ServoSpec::new(1, Model::Xl330M288);
    spec.min_position_ticks = Some(3000);
    spec.max_position_ticks = Some(1000);
    c = SimConfig {
        servos: vec![spec],
        ..SimConfig::default()
    };
    assert!(bad(c).is_some_and(|e| e.contains("position limits")));
}

#[test]
fn fault_names_parse() {
    use snakectl_sim::HardwareErrorKind as K;
    assert_eq!("overload".parse::<K>(), Ok(K::Overload));
    assert_eq!("Input-Voltage".parse::<K>(), Ok(K::InputVoltage));
    assert_eq!("voltage".parse::<K>(), Ok(K::InputVoltage));
    assert!("melted".parse::<K>().is_err());
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

#[test]
fn a_drop_fault_acts_only_inside_its_window() {
    let (mut s, clock) = sim_with(config(
        &[1, 2],
        vec![Fault::DropReplies {
            id: Some(2),
            fraction: 1.0,
        }
        .during(ms(100), Some(ms(300)))],
    ));
    let pings = |s: &mut snakectl_sim::Simulator| {
        [1u8, 2]
            .iter()
            .flat_map(|&id| send(s, id, ins::PING, &[]))
            .map(|r| r.id)
            .collect::<Vec<_>>()
    };
    assert_eq!(pings(&mut s), [1, 2]);
    clock.advance(ms(99));
    assert_eq!(pings(&mut s), [1, 2]);
    // The window opens at 100 ms (inclusive) ...
    clock.advance(ms(1));
    assert_eq!(pings(&mut s), [1]);
    clock.advance(ms(199));
    assert_eq!(pings(&mut s), [1]);
    // ... and closes at 300 ms (exclusive).
    clock.advance(ms(1));
    assert_eq!(pings(&mut s), [1, 2]);
    clock.advance(Duration::from_secs(10));
    assert_eq!(pings(&mut s), [1, 2]);
    assert_eq!(s.stats().dropped, 2);
}

#[test]
fn a_windowed_fault_draws_nothing_outside_its_window() {
    // Same seed, same traffic inside the window: the same losses, whatever came before it.
    let pattern = |pings_before: usize| {
        let mut cfg = config(
            &[1],
            vec![Fault::DropReplies {
                id: None,
                fraction: 0.5,
            }
            .during(ms(10), None)],
        );
        cfg.seed = 42;
        let (mut s, clock) = sim_with(cfg);
        for _ in 0..pings_before {
            assert_eq!(send(&mut s, 1, ins::PING, &[]).len(), 1);
        }
        clock.advance(ms(10));
        (0..200)
            .map(|_| send(&mut s, 1, ins::PING, &[]).is_empty())
            .collect::<Vec<_>>()
    };
    let a = pattern(0);
    assert_eq!(a, pattern(37));
    assert!(a.iter().any(|&d| d) && a.iter().any(|&d| !d));
}

#[test]
fn corrupt_and_latency_faults_follow_their_windows() {
    let (mut s, clock) = sim_with(config(
        &[1],
        vec![
            Fault::CorruptReplies {
                id: Some(1),
                fraction: 1.0,
            }
            .during(Duration::ZERO, Some(ms(50))),
            Fault::ExtraLatency {
                id: None,
                latency: ms(7),
            }
            .during(ms(50), None),
        ],
    ));
    let good = protocol::encode_status(1, 0, &[0x24, 0x04, 48]);
    let r = send(&mut s, 1, ins::PING, &[]);
    let t0 = snakectl_sim::Clock::now(&clock);
    assert_ne!(r[0].bytes, good);
    assert_eq!(r[0].at, t0);
    clock.advance(ms(50));
    let r = send(&mut s, 1, ins::PING, &[]);
    assert_eq!(r[0].bytes, good);
    assert_eq!(r[0].at, t0 + ms(57));
}

#[test]
fn a_silent_servo_answers_again_after_its_window() {
    let (mut s, clock) = sim_with(config(
        &[1, 2, 3],
        vec![Fault::Silent { id: 3, at: ms(200) }.during(Duration::ZERO, Some(ms(700)))],
    ));
    assert_eq!(answering(&mut s), [3, 2, 1]);
    clock.advance(ms(200));
    assert_eq!(answering(&mut s), [2, 1]);
    assert_eq!(s.servo(3).map(|x| x.is_silent()), Some(true));
    // Deaf while silent: the broadcast write does not reach it.
    send(
        &mut s,
        BROADCAST_ID,
        ins::WRITE,
        &write_params(addr::LED, &[1]),
    );
    clock.advance(ms(499));
    assert_eq!(answering(&mut s), [2, 1]);
    clock.advance(ms(1));
    assert_eq!(answering(&mut s), [3, 2, 1]);
    assert_eq!(s.servo(3).and_then(|x| x.value(addr::LED)), Some(0));
    assert_eq!(s.servo(2).and_then(|x| x.value(addr::LED)), Some(1));
    // Back for good, and it hears writes again.
    send(
        &mut s,
        BROADCAST_ID,
        ins::WRITE,
        &write_params(addr::LED, &[1]),
    );
    assert_eq!(s.servo(3).and_then(|x| x.value(addr::LED)), Some(1));
    clock.advance(Duration::from_secs(60));
    assert_eq!(answering(&mut s), [3, 2, 1]);
}

#[test]
fn overlapping_silent_windows_keep_the_servo_silent_until_the_last_closes() {
    let silent = |from, to| Fault::Silent { id: 1, at: ms(0) }.during(ms(from), Some(ms(to)));
    let (mut s, clock) = sim_with(config(&[1], vec![silent(100, 300), silent(200, 400)]));
    let answers = |s: &mut snakectl_sim::Simulator| !send(s, 1, ins::PING, &[]).is_empty();
    let mut seen = Vec::new();
    for _ in 0..6 {
        seen.push(answers(&mut s));
        clock.advance(ms(100));
    }
    assert_eq!(seen, [true, false, false, false, true, true]);
}

#[test]
fn a_silent_fault_whose_window_closes_before_it_starts_never_fires() {
    let (mut s, clock) = sim_with(config(
        &[1],
        vec![Fault::Silent { id: 1, at: ms(500) }.during(Duration::ZERO, Some(ms(100)))],
    ));
    for _ in 0..10 {
        assert_eq!(send(&mut s, 1, ins::PING, &[]).len(), 1);
        clock.advance(ms(100));
    }
}

#[test]
fn fault_windows_are_validated() {
    let bad = |faults: Vec<Fault>| {
        snakectl_sim::Simulator::new(
            config(&[1], faults),
            std::sync::Arc::new(snakectl_sim::RealClock),
        )
        .err()
    };
    let drop = Fault::DropReplies {
        id: None,
        fraction: 0.5,
    };
    assert!(matches!(
        bad(vec![drop.clone().during(ms(5), Some(ms(5)))]),
        Some(SimError::Window { .. })
    ));
    // Nested windows are checked one by one, and the inner fault too.
    assert!(matches!(
        bad(vec![drop
            .clone()
            .during(ms(5), Some(ms(2)))
            .during(ms(0), None)]),
        Some(SimError::Window { .. })
    ));
    assert!(matches!(
        bad(vec![Fault::Silent { id: 9, at: ms(0) }.during(ms(0), None)]),
        Some(SimError::FaultId(9))
    ));
    assert!(matches!(
        bad(vec![Fault::HardwareError {
            id: 1,
            at: ms(0),
            kind: snakectl_sim::HardwareErrorKind::Overload,
        }
        .during(ms(0), Some(ms(10)))]),
        Some(SimError::WindowedHardwareError)
    ));
    assert!(bad(vec![drop.clone().during(ms(5), None)]).is_none());
    // Nested windows intersect.
    let nested = drop
        .during(ms(5), Some(ms(20)))
        .during(ms(10), Some(ms(30)));
    assert_eq!(
        nested.window().0,
        snakectl_sim::Window {
            start: ms(10),
            end: Some(ms(20))
        }
    );
}

/// Servo `id`'s Present Position and Present Load (XL430: 0.1 % units), advanced to now.
fn position_and_load(s: &mut snakectl_sim::Simulator, id: u8) -> (i64, i64) {
    s.advance();
    let servo = s.servo(id).unwrap();
    (
        servo.value(addr::PRESENT_POSITION).unwrap(),
        servo.value(addr::PRESENT_LOAD_OR_CURRENT).unwrap(),
    )
}

fn goal(s: &mut snakectl_sim::Simulator, id: u8, ticks: i32) {
    send(
        s,
        id,
        ins::WRITE,
        &write_params(addr::GOAL_POSITION, &ticks.to_le_bytes()),
    );
}

#[test]
fn a_blocked_servo_holds_its_shaft_and_its_load_rises_with_the_error_to_a_stall() {
    let (mut s, clock) = sim_with(config(
        &[1, 2],
        vec![Fault::Blocked { id: 2, at: ms(100) }.during(Duration::ZERO, Some(ms(1000)))],
    ));
    send(
        &mut s,
        BROADCAST_ID,
        ins::WRITE,
        &write_params(addr::TORQUE_ENABLE, &[1]),
    );
    goal(&mut s, 1, 3048);
    goal(&mut s, 2, 3048);
    clock.advance(ms(100));
    let (held, _) = position_and_load(&mut s, 2);
    assert_eq!(
        position_and_load(&mut s, 1).0,
        held,
        "both alike until the block"
    );
    assert!(
        held > 2100 && held < 3000,
        "on its way when blocked: {held}"
    );
    assert!(s.servo(2).unwrap().is_blocked());
    clock.advance(ms(200));
    let (p1, _) = position_and_load(&mut s, 1);
    let (p2, load) = position_and_load(&mut s, 2);
    assert!(p1 > held, "the free servo moves on: {p1}");
    assert_eq!(
        p2, held,
        "the blocked shaft stays where the block caught it"
    );
    assert_eq!(
        load, 1000,
        "hundreds of ticks short of its goal: stalled at full load"
    );
    // Proportional below the stall: Position P Gain 640 / 128 = 5 PWM units per tick of
    // error, out of 885 for full load.
    let expect = |error: i64| (5.0 * error as f64 / 885.0 * 1000.0).round() as i64;
    for error in [0, 20, 100, -100, 170] {
        goal(&mut s, 2, (held + error) as i32);
        clock.advance(ms(10));
        let (p, load) = position_and_load(&mut s, 2);
        assert_eq!(p, held);
        assert_eq!(load, expect(error), "error {error} ticks");
    }
    assert_eq!(expect(170), 960);
    goal(&mut s, 2, (held - 400) as i32);
    clock.advance(ms(10));
    assert_eq!(
        position_and_load(&mut s, 2).1,
        -1000,
        "stalled the other way"
    );
    // Torque off: no effort however far the goal.
    send(
        &mut s,
        2,
        ins::WRITE,
        &write_params(addr::TORQUE_ENABLE, &[0]),
    );
    assert_eq!(position_and_load(&mut s, 2).1, 0);
    send(
        &mut s,
        2,
        ins::WRITE,
        &write_params(addr::TORQUE_ENABLE, &[1]),
    );
    goal(&mut s, 2, 2500);
    // The window closes at 1 s: the shaft follows its goal again and comes to rest there.
    clock.advance(ms(1000));
    s.advance();
    assert!(!s.servo(2).unwrap().is_blocked());
    clock.advance(ms(500));
    assert_eq!(position_and_load(&mut s, 2), (2500, 0));
}

#[test]
fn a_blocked_fault_names_a_servo_on_the_bus() {
    let result = snakectl_sim::Simulator::new(
        config(&[1], vec![Fault::Blocked { id: 4, at: ms(0) }]),
        std::sync::Arc::new(snakectl_sim::RealClock),
    );
    assert!(matches!(result.err(), Some(SimError::FaultId(4))));
}
