//! The servo rules and the motor model, checked on the core with a manual clock: the error code a
//! client sees for each refused write, shutdown errors, the bus watchdog, Status Return Level,
//! REG WRITE/ACTION, reboot and factory reset, motion under the profile.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::Duration;

use common::*;
use snakectl_sim::protocol::{error, instruction as ins, BROADCAST_ID};
use snakectl_sim::table::{addr, hw};
use snakectl_sim::{Fault, HardwareErrorKind, Model, ServoSpec, SimConfig, DEFAULT_BOOT_TIME};

/// A write that must be taken (no error in the status).
fn set(s: &mut snakectl_sim::Simulator, id: u8, address: u16, data: &[u8]) {
    assert_eq!(
        write(s, id, address, data),
        0,
        "write of {data:?} to {address} on {id}"
    );
}

const ACCESS: u8 = error::ACCESS;

#[test]
fn eeprom_is_writable_only_with_torque_off() {
    let (mut s, _) = sim(xl430(&[1]));
    set(&mut s, 1, addr::MAX_POSITION_LIMIT, &3000u32.to_le_bytes());
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    assert_eq!(
        write(&mut s, 1, addr::MAX_POSITION_LIMIT, &3500u32.to_le_bytes()),
        ACCESS
    );
    assert_eq!(write(&mut s, 1, addr::ID, &[9]), ACCESS);
    assert_eq!(read(&mut s, 1, addr::MAX_POSITION_LIMIT, 4), (0, 3000));
    set(&mut s, 1, addr::TORQUE_ENABLE, &[0]);
    set(&mut s, 1, addr::MAX_POSITION_LIMIT, &3500u32.to_le_bytes());
    // A new id takes effect at once, the status of that write already carries it.
    assert_eq!(
        one(&mut s, 1, ins::WRITE, &write_params(addr::ID, &[9])).id,
        9
    );
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty());
    assert_eq!(one(&mut s, 9, ins::PING, &[]).error, 0);
}

#[test]
fn out_of_range_values_are_data_range_errors() {
    let (mut s, _) = sim(vec![
        ServoSpec::new(1, Model::Xl430W250),
        ServoSpec::new(2, Model::Xl330M288),
    ]);
    assert_eq!(write(&mut s, 1, addr::LED, &[2]), error::DATA_RANGE);
    assert_eq!(
        write(&mut s, 1, addr::STATUS_RETURN_LEVEL, &[3]),
        error::DATA_RANGE
    );
    assert_eq!(
        write(&mut s, 1, addr::RETURN_DELAY_TIME, &[255]),
        error::DATA_RANGE
    );
    // XL430 has no current-based modes; the XL330 has.
    assert_eq!(
        write(&mut s, 1, addr::OPERATING_MODE, &[5]),
        error::DATA_RANGE
    );
    set(&mut s, 2, addr::OPERATING_MODE, &[5]);
    assert_eq!(
        write(&mut s, 1, addr::PROFILE_VELOCITY, &40000u32.to_le_bytes()),
        error::DATA_RANGE
    );
    assert_eq!(
        write(&mut s, 1, addr::BUS_WATCHDOG, &[128]),
        error::DATA_RANGE
    );
    assert_eq!(
        write(&mut s, 2, addr::MAX_VOLTAGE_LIMIT, &80u16.to_le_bytes()),
        error::DATA_RANGE
    );
    // Nothing was written.
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 0));
}

#[test]
fn goals_beyond_limit_items_are_data_limit_errors() {
    let mut spec = ServoSpec::new(1, Model::Xm430W350);
    spec.min_position_ticks = Some(1000);
    spec.max_position_ticks = Some(3000);
    let (mut s, _) = sim(vec![spec]);
    assert_eq!(
        write(&mut s, 1, addr::GOAL_POSITION, &3001i32.to_le_bytes()),
        error::DATA_LIMIT
    );
    assert_eq!(
        write(&mut s, 1, addr::GOAL_POSITION, &999i32.to_le_bytes()),
        error::DATA_LIMIT
    );
    set(&mut s, 1, addr::GOAL_POSITION, &3000i32.to_le_bytes());
    // Goal velocity beyond Velocity Limit (200 on the XM430), goal current beyond Current Limit.
    assert_eq!(
        write(&mut s, 1, addr::GOAL_VELOCITY, &201i32.to_le_bytes()),
        error::DATA_LIMIT
    );
    set(&mut s, 1, addr::GOAL_VELOCITY, &(-200i32).to_le_bytes());
    assert_eq!(
        write(&mut s, 1, addr::GOAL_CURRENT, &(-1194i16).to_le_bytes()),
        error::DATA_LIMIT
    );
    // Extended position mode: the multi-turn range applies instead of the limits.
    set(&mut s, 1, addr::OPERATING_MODE, &[4]);
    set(&mut s, 1, addr::GOAL_POSITION, &9000i32.to_le_bytes());
    assert_eq!(
        write(&mut s, 1, addr::GOAL_POSITION, &2_000_000i32.to_le_bytes()),
        error::DATA_RANGE
    );
}

#[test]
fn read_only_undefined_and_short_writes() {
    let (mut s, _) = sim(xl430(&[1]));
    assert_eq!(
        write(&mut s, 1, addr::PRESENT_POSITION, &[0, 0, 0, 0]),
        ACCESS
    );
    assert_eq!(write(&mut s, 1, addr::MODEL_NUMBER, &[0, 0]), ACCESS);
    assert_eq!(write(&mut s, 1, addr::HARDWARE_ERROR_STATUS, &[0]), ACCESS);
    assert_eq!(write(&mut s, 1, 66, &[0]), ACCESS); // reserved
    assert_eq!(write(&mut s, 1, 118, &[0, 0]), ACCESS); // middle of Goal Position
    assert_eq!(write(&mut s, 1, addr::CURRENT_LIMIT, &[0, 0]), ACCESS); // not on the XL430
    assert_eq!(
        write(&mut s, 1, addr::GOAL_POSITION, &[0, 8]),
        error::DATA_LENGTH
    );
    assert_eq!(write(&mut s, 1, 700, &[0]), ACCESS); // past the table
    let r = one(&mut s, 1, ins::READ, &read_params(600, 100));
    assert_eq!((r.error, r.data.len()), (ACCESS, 0));
    // Reading across items and reserved bytes is fine.
    let r = one(&mut s, 1, ins::READ, &read_params(64, 8));
    assert_eq!((r.error, r.data.len()), (0, 8));
    // One write may span several items: Profile Velocity then Goal Position.
    let mut block = 100u32.to_le_bytes().to_vec();
    block.extend_from_slice(&1500i32.to_le_bytes());
    set(&mut s, 1, addr::PROFILE_VELOCITY, &block);
    assert_eq!(read(&mut s, 1, addr::GOAL_POSITION, 4), (0, 1500));
    // Malformed instructions.
    assert_eq!(
        one(&mut s, 1, ins::READ, &[0x84, 0x00]).error,
        error::DATA_LENGTH
    );
    assert_eq!(one(&mut s, 1, 0x42, &[]).error, error::INSTRUCTION);
    assert_eq!(
        one(&mut s, 1, ins::CLEAR, &[1, 2, 3]).error,
        error::DATA_RANGE
    );
}

#[test]
fn shutdown_error_switches_torque_off_until_reboot() {
    let (mut s, clock) = sim_with(SimConfig {
        servos: xl430(&[1, 2]),
        faults: vec![Fault::HardwareError {
            id: 1,
            at: Duration::from_millis(300),
            kind: HardwareErrorKind::Overload,
        }],
        ..SimConfig::default()
    });
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &4095i32.to_le_bytes());
    clock.advance(Duration::from_millis(500));
    // The alert bit flags every reply; the error itself is in Hardware Error Status.
    let (e, hw) = read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1);
    assert_eq!((e, hw as u8), (error::ALERT, 0x20));
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (error::ALERT, 0));
    assert_eq!(read(&mut s, 2, addr::HARDWARE_ERROR_STATUS, 1), (0, 0));
    // It stopped where the error caught it.
    let stopped = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    assert!(stopped > 2048 && stopped < 4095, "{stopped}");
    clock.advance(Duration::from_secs(1));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, stopped);
    // Torque cannot come back before a reboot.
    assert_eq!(
        write(&mut s, 1, addr::TORQUE_ENABLE, &[1]),
        error::RESULT_FAIL | error::ALERT
    );
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, error::ALERT);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1), (0, 0));
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
}

#[test]
fn clearing_shutdown_after_the_error_does_not_bring_torque_back_before_a_reboot() {
    let (mut s, clock) = sim_with(SimConfig {
        servos: xl430(&[1]),
        faults: vec![Fault::HardwareError {
            id: 1,
            at: Duration::from_millis(100),
            kind: HardwareErrorKind::Overheating,
        }],
        ..SimConfig::default()
    });
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    clock.advance(Duration::from_millis(200));
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (error::ALERT, 0));
    // Shutdown (EEPROM, torque off) no longer selects the error: the shutdown still holds.
    assert_eq!(write(&mut s, 1, addr::SHUTDOWN, &[0]), error::ALERT);
    assert_eq!(
        write(&mut s, 1, addr::TORQUE_ENABLE, &[1]),
        error::RESULT_FAIL | error::ALERT
    );
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (error::ALERT, 0));
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, error::ALERT);
    clock.advance(DEFAULT_BOOT_TIME);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
}

#[test]
fn errors_outside_shutdown_only_raise_the_alert() {
    let (mut s, clock) = sim_with(SimConfig {
        servos: xl430(&[1]),
        faults: vec![Fault::HardwareError {
            id: 1,
            at: Duration::from_millis(100),
            kind: HardwareErrorKind::InputVoltage,
        }],
        ..SimConfig::default()
    });
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    clock.advance(Duration::from_millis(200));
    // Input voltage is not in the XL430's default Shutdown (52): torque stays on.
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (error::ALERT, 1));
    let (_, volts) = read(&mut s, 1, addr::PRESENT_INPUT_VOLTAGE, 2);
    assert!(volts < 60, "{volts}");
}

#[test]
fn overheating_shows_in_the_temperature() {
    let (mut s, clock) = sim_with(SimConfig {
        servos: vec![ServoSpec::new(3, Model::Xl330M288)],
        faults: vec![Fault::HardwareError {
            id: 3,
            at: Duration::from_millis(10),
            kind: HardwareErrorKind::Overheating,
        }],
        ..SimConfig::default()
    });
    assert_eq!(read(&mut s, 3, addr::PRESENT_TEMPERATURE, 1), (0, 30));
    clock.advance(Duration::from_millis(20));
    let (e, t) = read(&mut s, 3, addr::PRESENT_TEMPERATURE, 1);
    assert_eq!(e, error::ALERT);
    assert!(t > 70);
}

#[test]
fn bus_watchdog_fires_refuses_goals_and_clears() {
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::BUS_WATCHDOG, &[5]); // 100 ms
    set(&mut s, 1, addr::GOAL_POSITION, &4000i32.to_le_bytes());
    // Traffic every 80 ms keeps it quiet.
    for _ in 0..5 {
        clock.advance(Duration::from_millis(80));
        assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, 5));
    }
    // Silence for longer than 100 ms: it fires, reads -1, and the servo stops.
    clock.advance(Duration::from_millis(150));
    assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, -1));
    let stopped = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    assert!(stopped < 4000);
    assert_eq!(read(&mut s, 1, addr::GOAL_POSITION, 4).1, stopped);
    clock.advance(Duration::from_millis(500));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, stopped);
    assert_eq!(read(&mut s, 1, addr::MOVING, 1).1, 0);
    // Goals are refused until 0 is written.
    assert_eq!(
        write(&mut s, 1, addr::GOAL_POSITION, &1000i32.to_le_bytes()),
        error::DATA_RANGE
    );
    assert_eq!(
        write(&mut s, 1, addr::GOAL_VELOCITY, &0i32.to_le_bytes()),
        error::DATA_RANGE
    );
    set(&mut s, 1, addr::BUS_WATCHDOG, &[0]);
    set(&mut s, 1, addr::GOAL_POSITION, &1000i32.to_le_bytes());
    // Disarmed: no more firing.
    clock.advance(Duration::from_secs(5));
    assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, 0));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 1000);
}

#[test]
fn bus_watchdog_stops_a_servo_turning_in_velocity_mode() {
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::OPERATING_MODE, &[1]);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_VELOCITY, &50i32.to_le_bytes());
    set(&mut s, 1, addr::BUS_WATCHDOG, &[5]); // 100 ms
    clock.advance(Duration::from_millis(80));
    assert_eq!(read(&mut s, 1, addr::PRESENT_VELOCITY, 4), (0, 50));
    // Silent for 300 ms: it fires 100 ms after the last packet and the servo stops turning.
    clock.advance(Duration::from_millis(300));
    assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, -1));
    assert_eq!(read(&mut s, 1, addr::PRESENT_VELOCITY, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::GOAL_VELOCITY, 4), (0, 0));
    let stopped = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    clock.advance(Duration::from_millis(500));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, stopped);
    assert_eq!(read(&mut s, 1, addr::MOVING, 1).1, 0);
    // Cleared, it stays stopped until a new goal comes.
    set(&mut s, 1, addr::BUS_WATCHDOG, &[0]);
    clock.advance(Duration::from_millis(500));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, stopped);
    set(&mut s, 1, addr::GOAL_VELOCITY, &(-30i32).to_le_bytes());
    clock.advance(Duration::from_millis(500));
    assert_eq!(read(&mut s, 1, addr::PRESENT_VELOCITY, 4), (0, -30));
}

#[test]
fn motion_follows_the_profile() {
    let (mut s, clock) = sim(vec![ServoSpec::new(1, Model::Xm430W350)]);
    // 100 units = 22.9 rev/min = 1563 ticks/s; acceleration 50 units = 12207 ticks/s^2.
    set(&mut s, 1, addr::PROFILE_VELOCITY, &100u32.to_le_bytes());
    set(&mut s, 1, addr::PROFILE_ACCELERATION, &50u32.to_le_bytes());
    set(&mut s, 1, addr::GOAL_POSITION, &3048i32.to_le_bytes());
    // Torque off: nothing moves.
    clock.advance(Duration::from_millis(200));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 2048);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    clock.advance(Duration::from_millis(300));
    let (_, v) = read(&mut s, 1, addr::PRESENT_VELOCITY, 4);
    assert_eq!(v, 100, "cruising at the profile velocity");
    assert_eq!(read(&mut s, 1, addr::MOVING, 1).1, 1);
    let p = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    // Ramp of 0.128 s (100 ticks), then 0.172 s at 1563 ticks/s (269 ticks): about 2417.
    assert!((p - 2417).abs() <= 3, "{p}");
    let (_, current) = read(&mut s, 1, addr::PRESENT_LOAD_OR_CURRENT, 2);
    assert!(current > 0 && current < 1193, "{current}");
    clock.advance(Duration::from_secs(1));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 3048);
    assert_eq!(read(&mut s, 1, addr::PRESENT_VELOCITY, 4).1, 0);
    assert_eq!(read(&mut s, 1, addr::MOVING, 1).1, 0);
    // Holding: steady readings.
    let volts = read(&mut s, 1, addr::PRESENT_INPUT_VOLTAGE, 2).1;
    let temp = read(&mut s, 1, addr::PRESENT_TEMPERATURE, 1).1;
    let cur = read(&mut s, 1, addr::PRESENT_LOAD_OR_CURRENT, 2).1;
    clock.advance(Duration::from_secs(3));
    assert_eq!(read(&mut s, 1, addr::PRESENT_INPUT_VOLTAGE, 2).1, volts);
    assert_eq!(read(&mut s, 1, addr::PRESENT_TEMPERATURE, 1).1, temp);
    assert_eq!(read(&mut s, 1, addr::PRESENT_LOAD_OR_CURRENT, 2).1, cur);
    assert_eq!((volts, temp), (120, 30));
}

#[test]
fn position_mode_stays_within_the_position_limits_whatever_the_goal_register_holds() {
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::GOAL_POSITION, &3000i32.to_le_bytes());
    // Limits narrowed afterwards (torque off): the goal register keeps 3000.
    set(&mut s, 1, addr::MAX_POSITION_LIMIT, &2500u32.to_le_bytes());
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    clock.advance(Duration::from_secs(2));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 2500);
    assert_eq!(read(&mut s, 1, addr::MOVING, 1).1, 0);
}

#[test]
fn velocity_limit_caps_an_unprofiled_move() {
    let (mut s, clock) = sim(xl430(&[1]));
    // Velocity Limit 265 units (60.7 rev/min) is above the XL430's 57 rev/min no-load speed:
    // lower it to 50 units, profile velocity 0 (= as fast as allowed).
    set(&mut s, 1, addr::VELOCITY_LIMIT, &50u32.to_le_bytes());
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &0i32.to_le_bytes());
    clock.advance(Duration::from_millis(500));
    assert_eq!(read(&mut s, 1, addr::PRESENT_VELOCITY, 4).1, -50);
}

#[test]
fn goal_pwm_limits_the_output_in_position_and_velocity_modes() {
    let (mut s, clock) = sim(xl430(&[1, 2]));
    // Servo 1 may not drive its motor at all: it stays where it is.
    set(&mut s, 1, addr::GOAL_PWM, &0i16.to_le_bytes());
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &3000i32.to_le_bytes());
    clock.advance(Duration::from_secs(1));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 2048);
    assert_eq!(read(&mut s, 1, addr::PRESENT_PWM, 2).1, 0);
    // Servo 2 at half its PWM turns at about half its no-load speed (57 rev/min: 124 units).
    set(&mut s, 2, addr::OPERATING_MODE, &[1]);
    set(&mut s, 2, addr::GOAL_PWM, &(-442i16).to_le_bytes());
    set(&mut s, 2, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 2, addr::GOAL_VELOCITY, &200i32.to_le_bytes());
    clock.advance(Duration::from_secs(1));
    let (_, v) = read(&mut s, 2, addr::PRESENT_VELOCITY, 4);
    assert!((v - 124).abs() <= 1, "{v}");
}

#[test]
fn status_return_level_selects_the_replies() {
    let (mut s, clock) = sim(xl430(&[1]));
    // The write that changes the level is still answered under the old one.
    set(&mut s, 1, addr::STATUS_RETURN_LEVEL, &[1]);
    assert!(send(&mut s, 1, ins::WRITE, &write_params(addr::LED, &[1])).is_empty());
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 1));
    assert!(send(
        &mut s,
        1,
        ins::WRITE,
        &write_params(addr::STATUS_RETURN_LEVEL, &[0])
    )
    .is_empty());
    assert_eq!(s.servo(1).map(|x| x.status_return_level()), Some(0));
    assert!(send(&mut s, 1, ins::READ, &read_params(addr::LED, 1)).is_empty());
    assert!(send(&mut s, BROADCAST_ID, ins::SYNC_READ, &[65, 0, 1, 0, 1]).is_empty());
    assert_eq!(one(&mut s, 1, ins::PING, &[]).error, 0);
    // Errors are not reported either.
    assert!(send(&mut s, 1, ins::WRITE, &write_params(addr::LED, &[7])).is_empty());
    // Reboot restores the RAM default (2).
    assert!(send(&mut s, 1, ins::REBOOT, &[]).is_empty());
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 0));
}

#[test]
fn reg_write_waits_for_action() {
    let (mut s, _) = sim(xl430(&[1, 2]));
    let params = write_params(addr::LED, &[1]);
    assert_eq!(one(&mut s, 1, ins::REG_WRITE, &params).error, 0);
    assert_eq!(one(&mut s, 2, ins::REG_WRITE, &params).error, 0);
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 0));
    assert_eq!(read(&mut s, 1, addr::REGISTERED_INSTRUCTION, 1), (0, 1));
    assert!(send(&mut s, BROADCAST_ID, ins::ACTION, &[]).is_empty());
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 1));
    assert_eq!(read(&mut s, 2, addr::LED, 1), (0, 1));
    assert_eq!(read(&mut s, 1, addr::REGISTERED_INSTRUCTION, 1), (0, 0));
    assert_eq!(one(&mut s, 1, ins::ACTION, &[]).error, error::INSTRUCTION);
    // A registered write is checked when registered.
    assert_eq!(
        one(&mut s, 1, ins::REG_WRITE, &write_params(addr::LED, &[9])).error,
        error::DATA_RANGE
    );
}

#[test]
fn reboot_and_factory_reset() {
    let mut spec = ServoSpec::new(4, Model::Xl430W250);
    spec.max_position_ticks = Some(3000);
    let (mut s, clock) = sim(vec![spec]);
    set(&mut s, 4, addr::LED, &[1]);
    set(&mut s, 4, addr::POSITION_P_GAIN, &900u16.to_le_bytes());
    assert_eq!(one(&mut s, 4, ins::REBOOT, &[]).error, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 4, addr::LED, 1), (0, 0));
    assert_eq!(read(&mut s, 4, addr::POSITION_P_GAIN, 2), (0, 640));
    assert_eq!(read(&mut s, 4, addr::MAX_POSITION_LIMIT, 4), (0, 3000));
    // Reset all but id and baud: EEPROM back to factory values, still reachable.
    assert_eq!(one(&mut s, 4, ins::FACTORY_RESET, &[0x02]).error, 0);
    // A factory reset reboots the servo: it boots as after REBOOT.
    assert!(send(&mut s, 4, ins::PING, &[]).is_empty());
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 4, addr::MAX_POSITION_LIMIT, 4), (0, 4095));
    assert_eq!(read(&mut s, 4, addr::RETURN_DELAY_TIME, 1), (0, 250));
    assert_eq!(
        one(&mut s, 4, ins::FACTORY_RESET, &[0x07]).error,
        error::DATA_RANGE
    );
    // Broadcast reset-all is not carried out.
    assert!(send(&mut s, BROADCAST_ID, ins::FACTORY_RESET, &[0xFF]).is_empty());
    assert_eq!(one(&mut s, 4, ins::PING, &[]).error, 0);
    // Reset all: id back to 1, factory baud (57600): gone from a 1 Mbps bus.
    assert_eq!(one(&mut s, 4, ins::FACTORY_RESET, &[0xFF]).id, 4);
    clock.advance(DEFAULT_BOOT_TIME);
    assert!(send(&mut s, BROADCAST_ID, ins::PING, &[]).is_empty());
    assert_eq!(s.servo(1).map(|x| x.baud_index()), Some(1));
}

#[test]
fn a_rebooted_servo_neither_hears_nor_answers_until_it_has_booted() {
    let (mut s, clock) = sim(xl430(&[1, 2, 3]));
    set(&mut s, 1, addr::LED, &[1]);
    // The reboot itself is answered, then the servo boots.
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty());
    // Deaf as well as mute: a write sent meanwhile is not carried out.
    assert!(send(&mut s, 1, ins::WRITE, &write_params(addr::LED, &[1])).is_empty());
    // The others answer around it.
    let ids = |r: Vec<snakectl_sim::Reply>| r.iter().map(|r| r.id).collect::<Vec<u8>>();
    assert_eq!(ids(send(&mut s, BROADCAST_ID, ins::PING, &[])), [2, 3]);
    let sync = [65, 0, 1, 0, 1, 2, 3];
    assert_eq!(
        ids(send(&mut s, BROADCAST_ID, ins::SYNC_READ, &sync)),
        [2, 3]
    );
    // Still booting just before the time is up, back on the bus when it is.
    clock.advance(DEFAULT_BOOT_TIME - Duration::from_millis(1));
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty());
    clock.advance(Duration::from_millis(1));
    assert_eq!(one(&mut s, 1, ins::PING, &[]).error, 0);
    assert_eq!(
        ids(send(&mut s, BROADCAST_ID, ins::SYNC_READ, &sync)),
        [1, 2, 3]
    );
    // Its RAM came back at the defaults, the write sent while it booted lost.
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 0));
}

#[test]
fn the_boot_time_is_configured_zero_for_none() {
    let config = |boot_time| SimConfig {
        servos: xl430(&[1]),
        boot_time,
        ..SimConfig::default()
    };
    let (mut s, clock) = sim_with(config(Duration::from_millis(50)));
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    clock.advance(Duration::from_millis(49));
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty());
    clock.advance(Duration::from_millis(1));
    assert_eq!(one(&mut s, 1, ins::PING, &[]).error, 0);
    let (mut s, _) = sim_with(config(Duration::ZERO));
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    assert_eq!(one(&mut s, 1, ins::PING, &[]).error, 0);
    assert!(matches!(
        config(Duration::from_secs(61)).validate(),
        Err(snakectl_sim::SimError::BootTime(_))
    ));
}

#[test]
fn clear_multi_turn() {
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::OPERATING_MODE, &[4]);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &9000i32.to_le_bytes());
    clock.advance(Duration::from_millis(100));
    let clear = [0x01, 0x44, 0x58, 0x4C, 0x22];
    assert_eq!(one(&mut s, 1, ins::CLEAR, &clear).error, error::RESULT_FAIL);
    clock.advance(Duration::from_secs(10));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 9000);
    assert_eq!(one(&mut s, 1, ins::CLEAR, &clear).error, 0);
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 9000 % 4096);
}

#[test]
fn a_new_operating_mode_resets_profiles_gains_and_goal_pwm() {
    let (mut s, _) = sim(vec![ServoSpec::new(1, Model::Xm430W350)]);
    set(&mut s, 1, addr::PROFILE_VELOCITY, &100u32.to_le_bytes());
    set(&mut s, 1, addr::PROFILE_ACCELERATION, &50u32.to_le_bytes());
    set(&mut s, 1, addr::POSITION_P_GAIN, &1000u16.to_le_bytes());
    set(&mut s, 1, addr::VELOCITY_I_GAIN, &1000u16.to_le_bytes());
    set(&mut s, 1, addr::GOAL_PWM, &500i16.to_le_bytes());
    set(&mut s, 1, addr::GOAL_CURRENT, &100i16.to_le_bytes());
    // The same mode written again changes nothing.
    set(&mut s, 1, addr::OPERATING_MODE, &[3]);
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 100));
    assert_eq!(read(&mut s, 1, addr::POSITION_P_GAIN, 2), (0, 1000));
    // Another mode: profiles 0, gains at their defaults, Goal PWM at PWM Limit.
    set(&mut s, 1, addr::OPERATING_MODE, &[4]);
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::PROFILE_ACCELERATION, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::POSITION_P_GAIN, 2), (0, 800));
    assert_eq!(read(&mut s, 1, addr::VELOCITY_I_GAIN, 2), (0, 1920));
    assert_eq!(read(&mut s, 1, addr::GOAL_PWM, 2), (0, 885));
    assert_eq!(read(&mut s, 1, addr::GOAL_CURRENT, 2), (0, 1193));
}

#[test]
fn present_position_comes_back_within_one_turn_on_reboot_and_in_position_mode() {
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::OPERATING_MODE, &[4]);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &9000i32.to_le_bytes());
    clock.advance(Duration::from_secs(10));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 9000);
    // A reboot: the encoder's absolute position within one turn, the goal with it.
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 9000 % 4096);
    assert_eq!(read(&mut s, 1, addr::GOAL_POSITION, 4).1, 9000 % 4096);
    // Multi-turn again (still in extended position mode), then back to position mode.
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::GOAL_POSITION, &(-3000i32).to_le_bytes());
    clock.advance(Duration::from_secs(10));
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, -3000);
    set(&mut s, 1, addr::TORQUE_ENABLE, &[0]);
    set(&mut s, 1, addr::OPERATING_MODE, &[3]);
    assert_eq!(read(&mut s, 1, addr::PRESENT_POSITION, 4).1, 4096 - 3000);
}

#[test]
fn indirect_data_follows_indirect_address() {
    let (mut s, _) = sim(xl430(&[1]));
    // Map Indirect Data 1..4 (224..227) onto Goal Position (116..119), Data 5 onto LED.
    for (k, target) in [116u16, 117, 118, 119, 65].iter().enumerate() {
        let slot = addr::INDIRECT_ADDRESS_1 + 2 * k as u16;
        set(&mut s, 1, slot, &target.to_le_bytes());
    }
    let mut block = 1234i32.to_le_bytes().to_vec();
    block.push(1);
    set(&mut s, 1, 224, &block);
    assert_eq!(read(&mut s, 1, addr::GOAL_POSITION, 4), (0, 1234));
    assert_eq!(read(&mut s, 1, addr::LED, 1), (0, 1));
    assert_eq!(read(&mut s, 1, 224, 4), (0, 1234));
    // The target's rules apply through the indirection.
    assert_eq!(write(&mut s, 1, 228, &[5]), error::DATA_RANGE);
}

#[test]
fn a_servo_that_loses_power_answers_again_with_its_ram_reset_and_its_eeprom_kept() {
    let (mut s, clock) = sim(xl430(&[1, 2]));
    set(&mut s, 1, addr::MAX_POSITION_LIMIT, &3000i32.to_le_bytes());
    set(&mut s, 1, addr::PROFILE_VELOCITY, &[50, 0, 0, 0]);
    set(&mut s, 1, addr::BUS_WATCHDOG, &[5]);
    set(&mut s, 1, addr::GOAL_POSITION, &2500i32.to_le_bytes());
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    clock.advance(Duration::from_secs(2));
    let held = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    assert!(s.lose_power(1));
    // Off the bus while unpowered; the other servo answers.
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty());
    assert_eq!(read(&mut s, 2, addr::TORQUE_ENABLE, 1), (0, 0));
    clock.advance(Duration::from_millis(500));
    assert!(s.restore_power(1));
    // RAM at the defaults: no torque, no watchdog, no profile; goal := where it rests.
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (0, 0));
    assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, 0));
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::STATUS_RETURN_LEVEL, 1), (0, 2));
    let present = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    assert!((present - held).abs() <= 1, "{present} after {held}");
    assert_eq!(read(&mut s, 1, addr::GOAL_POSITION, 4).1, present);
    // EEPROM kept.
    assert_eq!(read(&mut s, 1, addr::MAX_POSITION_LIMIT, 4), (0, 3000));
    assert!(!s.lose_power(9) && !s.restore_power(9), "no servo 9");
}

#[test]
fn indirect_addresses_take_ram_targets_with_torque_on_and_reset_on_reboot() {
    // XL330-M288: Indirect Address 1..20 at 168, Indirect Data 1..20 at 208, range 64..=227.
    let (mut s, clock) = sim(vec![ServoSpec::new(1, Model::Xl330M288)]);
    let slot = addr::INDIRECT_ADDRESS_1;
    assert_eq!(
        read(&mut s, 1, slot, 2),
        (0, 208),
        "the default: Data 1 itself"
    );
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    // RAM: written with torque on; an EEPROM target or one past the table is refused.
    assert_eq!(
        write(&mut s, 1, slot, &63u16.to_le_bytes()),
        error::DATA_RANGE
    );
    assert_eq!(
        write(&mut s, 1, slot, &228u16.to_le_bytes()),
        error::DATA_RANGE
    );
    set(&mut s, 1, slot, &227u16.to_le_bytes());
    // Present Position (132..135) and Input Voltage (144, 145) read as one block of 6.
    for (k, target) in [132u16, 133, 134, 135, 144, 145].iter().enumerate() {
        set(&mut s, 1, slot + 2 * k as u16, &target.to_le_bytes());
    }
    let position = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    assert_eq!(read(&mut s, 1, 208, 4), (0, position));
    assert_eq!(read(&mut s, 1, 212, 2), (0, 50), "5.0 V");
    // A read-only target stays read-only through its Indirect Data.
    assert_eq!(write(&mut s, 1, 208, &[0, 0, 0, 0]), error::ACCESS);
    // Reboot: the mapping is RAM, back at its defaults; the Data reads 0.
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, slot, 2), (0, 208));
    assert_eq!(read(&mut s, 1, 208, 4), (0, 0));
}

#[test]
fn a_bus_watchdog_that_fires_zeroes_the_profiles() {
    // The e-manual's Bus Watchdog example: "When it stops, the Profile Acceleration(108) and
    // Profile Velocity(112) are set to '0'". A client that clears the watchdog and sends the next
    // goal without writing its profiles again gets a move as fast as the servo can make it.
    let (mut s, clock) = sim(xl430(&[1]));
    let four = |v: i32| v.to_le_bytes();
    set(&mut s, 1, addr::PROFILE_ACCELERATION, &four(20));
    set(&mut s, 1, addr::PROFILE_VELOCITY, &four(30));
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    set(&mut s, 1, addr::BUS_WATCHDOG, &[5]); // 100 ms
    clock.advance(Duration::from_millis(80));
    // Not fired yet: the profiles stand.
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 30));
    clock.advance(Duration::from_millis(150));
    assert_eq!(read(&mut s, 1, addr::BUS_WATCHDOG, 1), (0, -1));
    assert_eq!(read(&mut s, 1, addr::PROFILE_ACCELERATION, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 0));
    // Cleared, the next goal runs unprofiled: the shaft covers 1000 ticks in 400 ms, where the
    // profile of 30 units (about 470 ticks/s) would have taken over 2 s.
    set(&mut s, 1, addr::BUS_WATCHDOG, &[0]);
    let start = read(&mut s, 1, addr::PRESENT_POSITION, 4).1;
    let goal = i32::try_from(start + 1000).unwrap();
    set(&mut s, 1, addr::GOAL_POSITION, &four(goal));
    clock.advance(Duration::from_millis(400));
    assert_eq!(
        read(&mut s, 1, addr::PRESENT_POSITION, 4).1,
        i64::from(goal)
    );
}

#[test]
fn control_table_backup_stores_and_restores_the_eeprom() {
    // The e-manual's Control Table Backup (0x20, X430 from firmware 45): 0x01 stores the
    // control table and sets Backup Ready (147); 0x02 brings the EEPROM area back and reboots.
    // Both are refused with result fail while torque is on.
    let (mut s, clock) = sim(xl430(&[1]));
    let store = [0x01, 0x43, 0x54, 0x52, 0x4C];
    let restore = [0x02, 0x43, 0x54, 0x52, 0x4C];
    let backup = |s: &mut snakectl_sim::Simulator, params: &[u8]| {
        one(s, 1, ins::CONTROL_TABLE_BACKUP, params).error
    };
    assert_eq!(read(&mut s, 1, addr::BACKUP_READY, 1), (0, 0));
    assert_eq!(
        backup(&mut s, &restore),
        error::RESULT_FAIL,
        "nothing stored"
    );
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);
    assert_eq!(backup(&mut s, &store), error::RESULT_FAIL, "torque on");
    set(&mut s, 1, addr::TORQUE_ENABLE, &[0]);
    assert_eq!(backup(&mut s, &[0x01, 0, 0, 0, 0]), error::DATA_RANGE);
    set(&mut s, 1, addr::VELOCITY_LIMIT, &100i32.to_le_bytes());
    set(&mut s, 1, addr::PROFILE_VELOCITY, &77i32.to_le_bytes());
    assert_eq!(backup(&mut s, &store), 0);
    assert_eq!(read(&mut s, 1, addr::BACKUP_READY, 1), (0, 1));
    // Changed since, then restored: the EEPROM comes back, after a reboot.
    set(&mut s, 1, addr::VELOCITY_LIMIT, &200i32.to_le_bytes());
    set(&mut s, 1, addr::RETURN_DELAY_TIME, &[9]);
    assert_eq!(backup(&mut s, &restore), 0);
    assert!(send(&mut s, 1, ins::PING, &[]).is_empty(), "rebooting");
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::VELOCITY_LIMIT, 4), (0, 100));
    assert_eq!(read(&mut s, 1, addr::RETURN_DELAY_TIME, 1), (0, 0));
    // RAM is as after any reboot; the backup stays.
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 0));
    assert_eq!(read(&mut s, 1, addr::BACKUP_READY, 1), (0, 1));
}

#[test]
fn startup_configuration_restores_ram_and_turns_torque_on_at_power_on() {
    // Startup Configuration (60): bit 1 restores the backed-up RAM items (gains, profiles,
    // Indirect Addresses) at start-up, bit 0 turns torque on.
    let (mut s, clock) = sim(xl430(&[1]));
    set(&mut s, 1, addr::PROFILE_VELOCITY, &77i32.to_le_bytes());
    set(&mut s, 1, addr::POSITION_P_GAIN, &900u16.to_le_bytes());
    set(&mut s, 1, addr::INDIRECT_ADDRESS_1, &65u16.to_le_bytes());
    assert_eq!(
        one(
            &mut s,
            1,
            ins::CONTROL_TABLE_BACKUP,
            &[0x01, 0x43, 0x54, 0x52, 0x4C]
        )
        .error,
        0
    );
    set(&mut s, 1, addr::STARTUP_CONFIGURATION, &[0b11]);
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (0, 1));
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 77));
    assert_eq!(read(&mut s, 1, addr::POSITION_P_GAIN, 2), (0, 900));
    assert_eq!(read(&mut s, 1, addr::INDIRECT_ADDRESS_1, 2), (0, 65));
    // Holding where it stands, not jumping to an old goal.
    assert_eq!(
        read(&mut s, 1, addr::GOAL_POSITION, 4),
        read(&mut s, 1, addr::PRESENT_POSITION, 4)
    );
    // Torque on only: RAM at its initial values.
    set(&mut s, 1, addr::TORQUE_ENABLE, &[0]);
    set(&mut s, 1, addr::STARTUP_CONFIGURATION, &[0b01]);
    assert!(s.restore_power(1));
    assert_eq!(read(&mut s, 1, addr::TORQUE_ENABLE, 1), (0, 1));
    assert_eq!(read(&mut s, 1, addr::PROFILE_VELOCITY, 4), (0, 0));
}

#[test]
fn a_firmware_without_control_table_backup_answers_an_instruction_error() {
    let mut spec = ServoSpec::new(1, Model::Xl430W250);
    spec.firmware = Some(44);
    let (mut s, _clock) = sim(vec![spec]);
    assert_eq!(
        one(
            &mut s,
            1,
            ins::CONTROL_TABLE_BACKUP,
            &[0x01, 0x43, 0x54, 0x52, 0x4C]
        )
        .error,
        error::INSTRUCTION
    );
}

#[test]
fn limits_written_below_the_readings_latch_hardware_errors() {
    // The e-manual's Temperature Limit: Present Temperature above it sets the overheating bit
    // (in the default Shutdown: torque off until a reboot); Min/Max Voltage Limit: Present Input
    // Voltage outside them sets the input voltage bit (an alert only on an XL430, whose default
    // Shutdown leaves it out).
    let (mut s, clock) = sim(xl430(&[1, 2]));
    assert_eq!(read(&mut s, 1, addr::PRESENT_TEMPERATURE, 1), (0, 30));
    assert_eq!(write(&mut s, 1, addr::TEMPERATURE_LIMIT, &[25]) & 0x7F, 0);
    assert_eq!(
        read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1),
        (error::ALERT, i64::from(hw::OVERHEATING))
    );
    assert_eq!(
        write(&mut s, 1, addr::TORQUE_ENABLE, &[1]),
        error::ALERT | error::RESULT_FAIL
    );
    // Rebooted with the limit still below the reading, it latches again; with a sane limit it
    // comes back clean.
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error & 0x7F, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(
        read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1).1,
        i64::from(hw::OVERHEATING)
    );
    assert_eq!(
        write(&mut s, 1, addr::TEMPERATURE_LIMIT, &[72]),
        error::ALERT
    );
    assert_eq!(one(&mut s, 1, ins::REBOOT, &[]).error & 0x7F, 0);
    clock.advance(DEFAULT_BOOT_TIME);
    assert_eq!(read(&mut s, 1, addr::HARDWARE_ERROR_STATUS, 1), (0, 0));
    set(&mut s, 1, addr::TORQUE_ENABLE, &[1]);

    // 11.1 V above a 10.0 V Max Voltage Limit.
    assert_eq!(
        write(&mut s, 2, addr::MAX_VOLTAGE_LIMIT, &100u16.to_le_bytes()) & 0x7F,
        0
    );
    assert_eq!(
        read(&mut s, 2, addr::HARDWARE_ERROR_STATUS, 1),
        (error::ALERT, i64::from(hw::INPUT_VOLTAGE))
    );
    assert_eq!(write(&mut s, 2, addr::TORQUE_ENABLE, &[1]), error::ALERT);
}
