//! The `ServoBus` trait through a real pseudo-terminal against the simulated chain (or real
//! servos with `--features hardware`, see `servo_support`): every call, calibration round trips,
//! each simulator fault and the error the caller sees, a silent servo in a sync read, hardware
//! error then reboot, watchdog expiry.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::servo_support;

use std::time::{Duration, Instant};

use servo_support::{rig, sim_rig, xl430, TIMEOUT};
use snakectl::chain::JointLimit;
use snakectl::servo::arm::{reboot_and_wait, Arm, JointServo, Retry, Settings, REBOOT_WAIT};
use snakectl::servo::units::{Calibration, TICKS_PER_TURN};
use snakectl::servo::{
    Fields, Goal, HardwareErrors, Layout, Register, ServoBus, ServoError, ServoModel, States,
};
use snakectl_sim::{Fault, HardwareErrorKind, SimConfig};

#[test]
fn every_trait_call_round_trips() {
    let mut rig = rig();
    let ids = rig.ids.clone();
    let wait = rig.wait_clock();
    let bus = &mut rig.bus;

    for &id in &ids {
        let p = bus.ping(id, TIMEOUT).unwrap();
        assert_eq!(p.id, id);
        assert!(
            snakectl::servo::model_name(p.model).is_some(),
            "model {}",
            p.model
        );
    }
    let found: Vec<u8> = bus.scan(TIMEOUT).unwrap().iter().map(|p| p.id).collect();
    for id in &ids {
        assert!(found.contains(id), "scan found {found:?}");
    }

    let id = ids[0];
    let model = bus.read(id, Register::ModelNumber, TIMEOUT).unwrap().value;
    assert_eq!(model, i64::from(bus.ping(id, TIMEOUT).unwrap().model));
    bus.write(id, Register::Led, 1, TIMEOUT).unwrap();
    assert_eq!(bus.read(id, Register::Led, TIMEOUT).unwrap().value, 1);
    bus.write(id, Register::Led, 0, TIMEOUT).unwrap();
    assert_eq!(bus.hardware_errors(id, TIMEOUT).unwrap(), HardwareErrors(0));

    // Small moves around the present pose, torque on, one Sync Write, one Sync Read.
    let states = bus.read_states(&ids, Fields::ALL, TIMEOUT).unwrap();
    let start: Vec<i32> = states
        .iter()
        .map(|s| s.as_ref().unwrap().position_ticks)
        .collect();
    for s in &states {
        let s = s.as_ref().unwrap();
        assert!(s.velocity.is_some() && s.current.is_some());
        assert!(s.voltage_dv.unwrap() > 40 && s.temperature_c.unwrap() > 0);
    }
    for &id in &ids {
        bus.set_torque(id, true, TIMEOUT).unwrap();
    }
    let goals: Vec<Goal> = ids
        .iter()
        .zip(&start)
        .enumerate()
        .map(|(i, (&id, &p))| Goal {
            id,
            ticks: p + 20 + i as i32,
        })
        .collect();
    bus.write_goals(&goals).unwrap();
    rig.settle(Duration::from_millis(500));
    let bus = &mut rig.bus;
    let states = bus.read_states(&ids, Fields::POSITION, TIMEOUT).unwrap();
    for (s, g) in states.iter().zip(&goals) {
        let s = s.as_ref().unwrap();
        assert_eq!(s.id, g.id);
        assert!((s.position_ticks - g.ticks).abs() <= 2, "{s:?} vs {g:?}");
        assert_eq!(
            bus.read(g.id, Register::GoalPosition, TIMEOUT)
                .unwrap()
                .value,
            i64::from(g.ticks)
        );
    }
    for &id in &ids {
        bus.set_torque(id, false, TIMEOUT).unwrap();
        assert_eq!(
            bus.read(id, Register::TorqueEnable, TIMEOUT).unwrap().value,
            0
        );
    }
    let ack = bus.reboot(id, TIMEOUT).unwrap();
    assert_eq!(ack.id, id);
    // It boots, then answers again; the wait reboots it once more and sees it back.
    let deadline = wait.now() + REBOOT_WAIT;
    while bus.ping(id, TIMEOUT).is_err() {
        assert!(wait.now() < deadline, "servo {id} did not come back");
        wait.sleep(Duration::from_millis(10));
    }
    reboot_and_wait(bus, id, TIMEOUT, &*wait, &mut Retry::default()).unwrap();
    assert_eq!(bus.ping(id, TIMEOUT).unwrap().id, id);
}

/// Under wire timing a servo answers a broadcast ping in its own slot, 3 ms for every silent id
/// before it: id 252 of this chain answers about 745 ms after the ping. The scan must listen
/// that long, not only for the wire time of the replies.
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_scan_finds_servos_with_high_ids_under_wire_timing() {
    let ids = [3, 200, 201, 203, 252];
    let mut rig = servo_support::realtime_rig(SimConfig {
        wire_timing: true,
        ..xl430(&ids)
    });
    let found: Vec<u8> = rig
        .bus
        .scan(TIMEOUT)
        .unwrap()
        .iter()
        .map(|p| p.id)
        .collect();
    assert_eq!(found, ids);
}

/// Each joint with its own offset and direction: a pose written in radians reads back within a
/// tick.
#[test]
fn calibration_round_trips() {
    let mut rig = rig();
    let ids = rig.ids.clone();
    let joints = ids
        .iter()
        .enumerate()
        .map(|(i, &id)| {
            let calibration = Calibration {
                offset_ticks: 37 * i as i32 - 200,
                reverse: i % 3 == 1,
            };
            let limit = JointLimit { lo: -1.5, hi: 1.5 };
            JointServo::new(
                i + 1,
                id,
                ServoModel::from_name("XL430-W250").unwrap(),
                calibration,
                limit,
            )
        })
        .collect();
    let settings = Settings {
        reply_timeout: TIMEOUT,
        ..Settings::default()
    };
    let arm = Arm::new(joints, settings);
    let bus = &mut rig.bus;
    // Whole ticks from each joint's zero, by the definition (2048 at the centre, plus the
    // offset; 4096 ticks a turn; reversed joints count down): a few ticks from where it is.
    let sign = |i: usize| if i % 3 == 1 { -1 } else { 1 };
    let offset = |i: usize| 37 * i as i64 - 200;
    let steps: Vec<i64> = bus
        .read_states(&ids, Fields::POSITION, TIMEOUT)
        .unwrap()
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let ticks = i64::from(s.as_ref().unwrap().position_ticks);
            sign(i) * (ticks - 2048 - offset(i)) + 3 * (i as i64 - 5)
        })
        .collect();
    for &id in &ids {
        bus.set_torque(id, true, TIMEOUT).unwrap();
    }
    let pose: Vec<f64> = steps
        .iter()
        .map(|&q| q as f64 * std::f64::consts::TAU / 4096.0)
        .collect();
    arm.write_pose(bus, &pose).unwrap();
    rig.settle(Duration::from_millis(500));
    let back = arm.read_pose(&mut rig.bus).unwrap();
    let tick = std::f64::consts::TAU / TICKS_PER_TURN;
    for (b, p) in back.iter().zip(&pose) {
        assert!(
            (b.as_ref().unwrap() - p).abs() <= 1.5 * tick,
            "{b:?} vs {p}"
        );
    }
    // Each goal is its angle's whole ticks from the joint's zero.
    for (i, (j, q)) in arm.joints().iter().zip(&steps).enumerate() {
        let goal = rig
            .bus
            .read(j.id, Register::GoalPosition, TIMEOUT)
            .unwrap()
            .value;
        assert_eq!(goal, 2048 + offset(i) + sign(i) * q, "servo {}", j.id);
    }
    // A non-finite angle: nothing is written.
    let mut bad = pose.clone();
    bad[4] = f64::NAN;
    let err = arm.write_pose(&mut rig.bus, &bad).unwrap_err();
    assert!(
        matches!(err, ServoError::NotFinite { joint: 5, .. }),
        "{err}"
    );
    for &id in &ids {
        rig.bus.set_torque(id, false, TIMEOUT).unwrap();
    }
}

/// Refused instructions come back as status errors naming the servo and the code's meaning.
#[test]
fn status_errors_name_the_servo_and_the_code() {
    let mut rig = rig();
    let id = rig.ids[1];
    let bus = &mut rig.bus;
    let err = bus.write(id, Register::Led, 2, TIMEOUT).unwrap_err();
    assert!(
        matches!(err, ServoError::Status { id: i, code: 4, alert: false } if i == id),
        "{err}"
    );
    bus.set_torque(id, true, TIMEOUT).unwrap();
    let err = bus
        .write(id, Register::ReturnDelayTime, 0, TIMEOUT)
        .unwrap_err();
    assert!(matches!(err, ServoError::Status { code: 7, .. }), "{err}");
    let text = err.to_string();
    assert!(
        text.starts_with(&format!("servo {id}: status error 7")),
        "{text}"
    );
    assert!(text.contains("EEPROM written with torque on"), "{text}");
    bus.set_torque(id, false, TIMEOUT).unwrap();
    // Values that do not fit a register never reach the wire.
    let err = bus
        .write(id, Register::TorqueEnable, 256, TIMEOUT)
        .unwrap_err();
    assert!(matches!(err, ServoError::ValueRange { .. }), "{err}");
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_goal_beyond_the_position_limits_is_a_data_limit_error() {
    let mut config = xl430(&[1]);
    config.servos[0].max_position_ticks = Some(3000);
    let mut rig = sim_rig(config);
    let err = rig
        .bus
        .write(1, Register::GoalPosition, 3001, TIMEOUT)
        .unwrap_err();
    assert!(
        matches!(err, ServoError::Status { id: 1, code: 6, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("data limit"), "{err}");
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_dropped_reply_is_a_timeout_naming_the_servo() {
    let mut config = xl430(&[1, 2, 3, 4]);
    config.faults = vec![Fault::DropReplies {
        id: Some(3),
        fraction: 1.0,
    }];
    let mut rig = sim_rig(config);
    let t0 = Instant::now();
    let err = rig.bus.ping(3, TIMEOUT).unwrap_err();
    assert!(matches!(err, ServoError::Timeout { id: 3, .. }), "{err}");
    assert!(t0.elapsed() >= TIMEOUT, "{:?}", t0.elapsed());
    assert!(
        err.to_string().starts_with("servo 3: no reply within"),
        "{err}"
    );
    // The instruction was still carried out.
    let _ = rig.bus.write(3, Register::Led, 1, TIMEOUT);
    assert_eq!(rig.sim().with_servo(3, |s| s.value(65)).flatten(), Some(1));
    let states = rig
        .bus
        .read_states(&[1, 2, 3, 4], Fields::POSITION, TIMEOUT)
        .unwrap();
    assert!(matches!(states[2], Err(ServoError::Timeout { id: 3, .. })));
    for i in [0, 1, 3] {
        assert!(states[i].is_ok(), "{:?}", states[i]);
    }
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_corrupt_reply_is_a_checksum_error_naming_the_servo() {
    let mut config = xl430(&[1, 2, 3]);
    config.faults = vec![Fault::CorruptReplies {
        id: Some(2),
        fraction: 1.0,
    }];
    let mut rig = sim_rig(config);
    let err = rig.bus.ping(2, TIMEOUT).unwrap_err();
    assert!(matches!(err, ServoError::Checksum { id: 2, .. }), "{err}");
    assert!(
        err.to_string().starts_with("servo 2: damaged reply (CRC"),
        "{err}"
    );
    let states = rig
        .bus
        .read_states(&[1, 2, 3], Fields::ALL, TIMEOUT)
        .unwrap();
    assert!(states[0].is_ok() && states[2].is_ok(), "{states:?}");
    assert!(
        matches!(states[1], Err(ServoError::Checksum { id: 2, .. })),
        "{states:?}"
    );
}

/// Once the simulator has received `packets` instructions, let `dt` pass on its clock: replies
/// held back by a latency fault then leave, in the order they were produced.
fn release_after(
    rig: &servo_support::Rig,
    packets: u64,
    dt: Duration,
) -> std::thread::JoinHandle<()> {
    let sim = rig.sim().simulator();
    let clock = rig.clock.clone().expect("a manual clock");
    std::thread::spawn(move || {
        let give_up = Instant::now() + Duration::from_secs(20);
        while sim.lock().unwrap().stats().packets < packets {
            assert!(Instant::now() < give_up, "the instruction never arrived");
            std::thread::yield_now();
        }
        clock.advance(dt);
        sim.lock().unwrap().advance();
    })
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_late_reply_of_the_same_servo_is_not_taken_for_the_next_one() {
    let mut config = xl430(&[1, 2]);
    config.faults = vec![Fault::ExtraLatency {
        id: Some(2),
        latency: Duration::from_millis(30),
    }];
    let mut rig = sim_rig(config);
    // 30 ms of latency on the simulator's clock, which does not move: a timeout.
    let err = rig
        .bus
        .read(2, Register::PresentPosition, Duration::from_millis(10))
        .unwrap_err();
    assert!(matches!(err, ServoError::Timeout { id: 2, .. }), "{err}");
    rig.sim().with_servo(2, |s| s.poke(65, 1));
    // The next read is sent first; then both replies leave: the late 4-byte position, then
    // the 1-byte LED. The position must not be taken for the LED.
    let before = rig.sim().with_sim(|s| s.stats().packets);
    let release = release_after(&rig, before + 1, Duration::from_millis(30));
    let led = rig
        .bus
        .read(2, Register::Led, Duration::from_secs(10))
        .unwrap();
    release.join().unwrap();
    assert_eq!(led.value, 1);
    assert_eq!(rig.bus.ping(1, TIMEOUT).unwrap().id, 1);
}

/// Regression: a reply that missed its deadline arrived during the next exchange and was taken
/// for the next servo's ("reply came from servo 1" on a loaded machine).
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_late_reply_of_another_servo_is_skipped() {
    let mut config = xl430(&[1, 2]);
    config.faults = vec![Fault::ExtraLatency {
        id: None,
        latency: Duration::from_millis(30),
    }];
    let mut rig = sim_rig(config);
    let err = rig.bus.ping(2, Duration::from_millis(5)).unwrap_err();
    assert!(matches!(err, ServoError::Timeout { id: 2, .. }), "{err}");
    // Held until the ping of servo 1 is in: servo 2's reply comes in first, then servo 1's.
    let before = rig.sim().with_sim(|s| s.stats().packets);
    let release = release_after(&rig, before + 1, Duration::from_millis(30));
    let p = rig.bus.ping(1, Duration::from_secs(10)).unwrap();
    release.join().unwrap();
    assert_eq!(p.id, 1);
}

/// A servo that goes silent mid-chain costs nothing beyond the others' replies: the 11 other
/// values arrive well within the deadline (`sync_read_u32` of dynamixel2 would wait 34 ms and
/// hide which servo is missing).
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_silent_servo_mid_sync_read_leaves_the_other_eleven() {
    let ids: Vec<u8> = (1..=12).collect();
    let mut config = xl430(&ids);
    config.faults = vec![Fault::Silent {
        id: 6,
        at: Duration::ZERO,
    }];
    let mut rig = sim_rig(config);
    // A long deadline: the read ends before it, since the servos after the silent one answer
    // (waiting for the silent one would take the whole deadline).
    let deadline = Duration::from_secs(8);
    let t0 = Instant::now();
    let states = rig.bus.read_states(&ids, Fields::ALL, deadline).unwrap();
    let elapsed = t0.elapsed();
    assert!(elapsed < deadline, "took {elapsed:?}");
    let ok: Vec<u8> = states
        .iter()
        .filter_map(|s| s.as_ref().ok())
        .map(|s| s.id)
        .collect();
    assert_eq!(ok, [1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]);
    let err = states[5].as_ref().unwrap_err();
    assert!(matches!(err, ServoError::Timeout { id: 6, .. }), "{err}");
}

/// The last servo silent: the sync read ends one reply timeout after the others.
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_silent_last_servo_costs_one_reply_timeout() {
    let ids: Vec<u8> = (1..=12).collect();
    let mut config = xl430(&ids);
    config.faults = vec![Fault::Silent {
        id: 12,
        at: Duration::ZERO,
    }];
    let mut rig = sim_rig(config);
    let t0 = Instant::now();
    let states = rig
        .bus
        .read_states(&ids, Fields::POSITION, TIMEOUT)
        .unwrap();
    let elapsed = t0.elapsed();
    // It waited for the last servo (an upper bound would be wall-clock luck).
    assert!(elapsed >= TIMEOUT, "{elapsed:?}");
    assert_eq!(states.iter().filter(|s| s.is_ok()).count(), 11);
    assert!(matches!(
        states[11],
        Err(ServoError::Timeout { id: 12, .. })
    ));
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_hardware_error_sets_the_alert_flag_until_a_reboot() {
    let mut config = xl430(&[1, 2, 3]);
    config.faults = vec![Fault::HardwareError {
        id: 2,
        at: Duration::from_millis(100),
        kind: HardwareErrorKind::Overload,
    }];
    let mut rig = sim_rig(config);
    rig.bus.set_torque(2, true, TIMEOUT).unwrap();
    rig.settle(Duration::from_millis(150));
    let wait = rig.wait_clock();
    let bus = &mut rig.bus;
    let ping = bus.ping(2, TIMEOUT).unwrap();
    assert!(ping.alert, "the alert flag comes with a successful reply");
    let errors = bus.hardware_errors(2, TIMEOUT).unwrap();
    assert_eq!(errors, HardwareErrors(HardwareErrors::OVERLOAD));
    assert_eq!(errors.to_string(), "overload (0x20)");
    assert_eq!(
        bus.read(2, Register::TorqueEnable, TIMEOUT).unwrap().value,
        0
    );
    let states = bus
        .read_states(&[1, 2, 3], Fields::POSITION, TIMEOUT)
        .unwrap();
    assert!(!states[0].as_ref().unwrap().alert && states[1].as_ref().unwrap().alert);
    // Torque cannot come back while the error is latched.
    let err = bus.set_torque(2, true, TIMEOUT).unwrap_err();
    assert!(
        matches!(
            err,
            ServoError::Status {
                id: 2,
                code: 1,
                alert: true
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("alert flag set"), "{err}");
    reboot_and_wait(bus, 2, TIMEOUT, &*wait, &mut Retry::default()).unwrap();
    // The class a caller matches on: a refusal with the alert flag is a hardware fault.
    assert_eq!(err.class(), snakectl::servo::ErrorClass::Hardware);
    assert!(bus.hardware_errors(2, TIMEOUT).unwrap().is_empty());
    assert!(!bus.set_torque(2, true, TIMEOUT).unwrap().alert);
}

#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn an_expired_watchdog_stops_the_servo_and_refuses_goals_until_cleared() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    let bus = &mut rig.bus;
    for id in [1, 2] {
        bus.write(id, Register::BusWatchdog, 5, TIMEOUT).unwrap(); // 100 ms
        bus.set_torque(id, true, TIMEOUT).unwrap();
    }
    bus.write_goals(&[Goal { id: 1, ticks: 3000 }, Goal { id: 2, ticks: 1000 }])
        .unwrap();
    rig.settle(Duration::from_millis(150)); // silence: the watchdog fires mid-move
    let bus = &mut rig.bus;
    assert_eq!(
        bus.read(1, Register::BusWatchdog, TIMEOUT).unwrap().value,
        -1
    );
    let stopped = bus.read_states(&[1], Fields::POSITION, TIMEOUT).unwrap()[0]
        .as_ref()
        .unwrap()
        .position_ticks;
    assert!(stopped > 2048 && stopped < 3000, "stopped at {stopped}");
    let err = bus
        .write(1, Register::GoalPosition, 2500, TIMEOUT)
        .unwrap_err();
    assert!(
        matches!(err, ServoError::Status { id: 1, code: 4, .. }),
        "{err}"
    );
    bus.write(1, Register::BusWatchdog, 0, TIMEOUT).unwrap();
    bus.write(1, Register::GoalPosition, 2500, TIMEOUT).unwrap();
}

/// The buffers hold one instruction for 64 servos (dynamixel2's default 128 bytes stop at 22).
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn sixty_four_servos_fit_one_sync_write_and_one_sync_read() {
    let ids: Vec<u8> = (1..=64).collect();
    let mut rig = sim_rig(xl430(&ids));
    let goals: Vec<Goal> = ids
        .iter()
        .map(|&id| Goal {
            id,
            ticks: 1000 + i32::from(id),
        })
        .collect();
    rig.bus.write_goals(&goals).unwrap();
    let states = rig.bus.read_states(&ids, Fields::ALL, TIMEOUT).unwrap();
    assert_eq!(states.iter().filter(|s| s.is_ok()).count(), 64);
    let blocks = rig
        .bus
        .sync_read(&ids, Register::GoalPosition.address(), 4, TIMEOUT)
        .unwrap();
    for (b, g) in blocks.iter().zip(&goals) {
        let b = b.as_ref().unwrap();
        assert_eq!(
            Register::GoalPosition.decode(&b.data),
            Some(i64::from(g.ticks))
        );
    }
}

/// Writes sent back to back queue in the port and go out at the baud rate: at 57600 baud a
/// dozen Sync Writes of twelve goals are about 0.15 s of wire. A read after them waits for its
/// reply from when its instruction is out, not from when it was handed to the port, so a
/// short timeout still finds every servo.
#[test]
#[cfg_attr(feature = "hardware", ignore = "simulator only")]
fn a_read_behind_a_burst_of_writes_waits_for_them_to_leave() {
    let ids: Vec<u8> = (1..=12).collect();
    let mut rig = servo_support::realtime_rig(SimConfig {
        wire_timing: true,
        baud: 57_600,
        ..xl430(&ids)
    });
    let short = Duration::from_millis(5);
    let goals = |k: i32| -> Vec<Goal> {
        ids.iter()
            .map(|&id| Goal {
                id,
                ticks: 1000 + 10 * k + i32::from(id),
            })
            .collect()
    };
    for k in 0..12 {
        rig.bus.write_goals(&goals(k)).unwrap();
    }
    let last = goals(11);
    let one = rig.bus.read(12, Register::GoalPosition, short).unwrap();
    assert_eq!(one.value, i64::from(last[11].ticks));
    for k in 0..12 {
        rig.bus.write_goals(&goals(k)).unwrap();
    }
    let blocks = rig
        .bus
        .sync_read(&ids, Register::GoalPosition.address(), 4, short)
        .unwrap();
    for (b, g) in blocks.iter().zip(&last) {
        let b = b.as_ref().unwrap();
        assert_eq!(
            Register::GoalPosition.decode(&b.data),
            Some(i64::from(g.ticks))
        );
    }
}

/// Through Indirect Address one read of 13 bytes a servo brings what the registers themselves
/// hold; a servo that lost its RAM (here, rebooted) reads unmapped until mapped again.
#[test]
fn the_indirect_block_reads_the_registers_and_a_reboot_unmaps_it() {
    let mut rig = rig();
    let ids = rig.ids.clone();
    let joints = ids
        .iter()
        .enumerate()
        .map(|(i, &id)| {
            JointServo::new(
                i + 1,
                id,
                ServoModel::from_name("XL430-W250").unwrap(),
                Calibration::default(),
                JointLimit { lo: -1.5, hi: 1.5 },
            )
        })
        .collect();
    let arm = Arm::new(joints, Settings::default());
    let layout = arm.layout();
    assert_eq!(
        layout,
        Layout::Indirect {
            data: 224,
            watchdog: false
        }
    );
    let wait = rig.wait_clock();
    let bus = &mut rig.bus;
    let mut retry = Retry::default();
    arm.map_indirect(bus, &ids, TIMEOUT, &mut retry).unwrap();
    let mut block = States::new();
    bus.read_block_into(&ids, layout, TIMEOUT, &mut block)
        .unwrap();
    let direct = bus.read_states(&ids, Fields::ALL, TIMEOUT).unwrap();
    for (indirect, direct) in block.readings().iter().zip(&direct) {
        let (indirect, direct) = (indirect.as_ref().unwrap(), direct.as_ref().unwrap());
        assert_eq!(indirect, direct);
        assert!(indirect.voltage_dv.is_some_and(|v| v > 0), "{indirect:?}");
    }
    let first = ids[0];
    reboot_and_wait(bus, first, TIMEOUT, &*wait, &mut retry).unwrap();
    bus.read_block_into(&ids, layout, TIMEOUT, &mut block)
        .unwrap();
    assert!(
        matches!(block.readings()[0], Err(ServoError::Unmapped { id }) if id == first),
        "{:?}",
        block.readings()[0]
    );
    assert!(block.readings()[1..].iter().all(Result::is_ok));
    arm.map_indirect(bus, &[first], TIMEOUT, &mut retry)
        .unwrap();
    bus.read_block_into(&ids, layout, TIMEOUT, &mut block)
        .unwrap();
    assert!(block.readings().iter().all(Result::is_ok));
}
