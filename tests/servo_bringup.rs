//! Bring-up and shut-down of a configured arm over a pseudo-terminal against the simulated
//! chain: the order of the steps as the servos see them, each refusal (missing servo, wrong
//! model, hardware error, joint outside its limits), a fired watchdog cleared, the limits
//! wrapper on the real bus.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod servo_support;

use std::time::Duration;

use servo_support::{sim_rig, Rig, TIMEOUT};
use snakectl::config::Config;
use snakectl::servo::arm::{Arm, BringUpError, BringUpOptions, Refusal};
use snakectl::servo::limits::Strategy;
use snakectl::servo::units;
use snakectl::servo::{Register, ServoBus, ServoError};
use snakectl_sim::table::addr;
use snakectl_sim::{Fault, HardwareErrorKind, Model, SimConfig};

const HOME: [f64; 4] = [0.3, -0.2, 0.1, 0.5];

/// A four-joint arm of XL430s; joint 2 is limited to [-1, 1] rad and reversed, joint 4 has an
/// offset.
fn config(on_exit: &str) -> Config {
    let mut text = String::from(
        "[arm]\nbase_x_m = 0.0\nbase_y_m = 0.0\nbase_heading_rad = 0.0\nhome_rad = [0.3, -0.2, 0.1, 0.5]\n",
    );
    for (id, (lo, hi, offset, reverse)) in [
        (-2.0, 2.0, 0, false),
        (-1.0, 1.0, 0, true),
        (-2.0, 2.0, 0, false),
        (-2.0, 2.0, 40, false),
    ]
    .into_iter()
    .enumerate()
    {
        text += &format!(
            "[[joint]]\nlink_m = 0.1\nmin_rad = {lo:?}\nmax_rad = {hi:?}\nid = {}\nmodel = \"XL430-W250\"\noffset_ticks = {offset}\nreverse = {reverse}\n",
            id + 1
        );
    }
    text += &format!(
        "[bus]\nkind = \"sim\"\nbaud = 1000000\nreturn_delay_us = 0\nprofile_velocity_rad_s = 3.0\nprofile_acceleration_rad_s2 = 20.0\non_exit = \"{on_exit}\"\nwatchdog_ms = 100\nreply_timeout_ms = 200\n"
    );
    Config::from_str(&text, "arm.toml").unwrap()
}

/// The simulated chain of `config` (servos at the home pose), changed by `edit`.
fn rig(config: &Config, edit: impl FnOnce(&mut SimConfig)) -> Rig {
    let mut sim = snakectl::simbus::sim_config(config).unwrap();
    edit(&mut sim);
    sim_rig(sim)
}

/// Every joint's servo reads Torque Enable = `expected`.
fn assert_torque(rig: &mut Rig, arm: &Arm, expected: i64) {
    for id in arm.ids() {
        let torque = rig.bus.read(id, Register::TorqueEnable, TIMEOUT).unwrap();
        assert_eq!(torque.value, expected, "servo {id}");
    }
}

fn refusals(err: BringUpError) -> Vec<Refusal> {
    match err {
        BringUpError::Refused(r) => r,
        other => panic!("expected a refusal, got {other}"),
    }
}

#[test]
fn bring_up_holds_the_present_pose_then_arms_the_watchdog_and_torques_on() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |_| {});
    let sim = rig.sim.take().unwrap();
    // Factory Return Delay Time on servo 1, Status Return Level 1 on servo 2, servo 3 already
    // torqued with factory limits (its EEPROM must be written with torque off).
    sim.with_servo(1, |s| s.poke(addr::RETURN_DELAY_TIME, 250));
    sim.with_servo(2, |s| s.poke(addr::STATUS_RETURN_LEVEL, 1));
    sim.with_servo(3, |s| {
        s.poke(addr::MAX_POSITION_LIMIT, 4095);
        s.poke(addr::TORQUE_ENABLE, 1);
    });
    rig.sim = Some(sim);

    let up = arm
        .bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap();
    assert_eq!(up.servos.len(), 4);
    assert!(up.rebooted.is_empty());
    let tick = std::f64::consts::TAU / units::TICKS_PER_TURN;
    for (got, want) in up.pose.iter().zip(HOME) {
        assert!((got - want).abs() <= tick, "{got} vs {want}");
    }
    for j in arm.joints() {
        let sim = rig.sim();
        let v = |a: u16| sim.with_servo(j.id, |s| s.value(a)).flatten().unwrap();
        assert_eq!(v(addr::TORQUE_ENABLE), 1, "servo {}", j.id);
        assert_eq!(
            v(addr::GOAL_POSITION),
            v(addr::PRESENT_POSITION),
            "servo {}",
            j.id
        );
        assert_eq!(v(addr::BUS_WATCHDOG), 5);
        assert_eq!(v(addr::RETURN_DELAY_TIME), 0);
        assert_eq!(v(addr::STATUS_RETURN_LEVEL), 2);
        assert_eq!(v(addr::OPERATING_MODE), 3);
        assert_eq!(v(addr::MIN_POSITION_LIMIT), i64::from(j.ticks.min));
        assert_eq!(v(addr::MAX_POSITION_LIMIT), i64::from(j.ticks.max));
        assert_eq!(v(addr::PROFILE_VELOCITY), units::profile_velocity(3.0));
        assert_eq!(
            v(addr::PROFILE_ACCELERATION),
            units::profile_acceleration(20.0)
        );
    }
    // Nothing moves: the goals are the pose it was found in.
    rig.settle(Duration::from_millis(50));
    let pose: Vec<f64> = arm
        .read_pose(&mut rig.bus)
        .unwrap()
        .into_iter()
        .map(Result::unwrap)
        .collect();
    for (got, want) in pose.iter().zip(&up.pose) {
        assert!((got - want).abs() < 1e-12);
    }
    arm.shut_down(&mut rig.bus).unwrap();
    assert_torque(&mut rig, &arm, 0);
}

#[test]
fn bring_up_refuses_a_missing_servo_naming_it() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |s| s.servos.retain(|s| s.id != 3));
    let err = arm
        .bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap_err();
    let text = err.to_string();
    assert!(
        text.starts_with("refusing to start: joint 3: servo 3 does not answer (servo 3: no reply"),
        "{text}"
    );
    let r = refusals(err);
    assert!(matches!(
        r[..],
        [Refusal::Missing {
            joint: 3,
            id: 3,
            source: ServoError::Timeout { .. }
        }]
    ));
    // Nothing was touched: no torque anywhere.
    assert_eq!(
        rig.bus
            .read(1, Register::TorqueEnable, TIMEOUT)
            .unwrap()
            .value,
        0
    );
}

#[test]
fn bring_up_refuses_a_servo_of_the_wrong_model() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |s| s.servos[1].model = Model::Xm430W350);
    let err = arm
        .bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "refusing to start: joint 2: servo 2 is a XM430-W350 (model 1020), the config says XL430-W250"
    );
}

#[test]
fn bring_up_refuses_a_hardware_error_unless_asked_to_reboot() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let fault = |s: &mut SimConfig| {
        s.faults = vec![Fault::HardwareError {
            id: 4,
            at: Duration::ZERO,
            kind: HardwareErrorKind::Overheating,
        }]
    };
    let mut rig1 = rig(&config, fault);
    let err = arm
        .bring_up(&mut rig1.bus, BringUpOptions::default())
        .unwrap_err();
    assert!(
        err.to_string().contains(
            "joint 4: servo 4 reports a hardware error: overheating (0x04) (reboot it: `snakectl servo reboot --id 4`)"
        ),
        "{err}"
    );
    let mut rig2 = rig(&config, fault);
    let up = arm
        .bring_up(&mut rig2.bus, BringUpOptions { reboot: true })
        .unwrap();
    assert_eq!(up.rebooted, [4]);
    assert_eq!(
        rig2.bus
            .read(4, Register::TorqueEnable, TIMEOUT)
            .unwrap()
            .value,
        1
    );
}

#[test]
fn bring_up_refuses_a_joint_outside_its_limits() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    // Joint 2 (limits [-1, 1] rad, reversed) turned by hand to about -1.5 rad.
    let mut rig = rig(&config, |s| {
        s.servos[1].initial_position_ticks = Some(2048 + 978)
    });
    let err = arm
        .bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap_err();
    let r = refusals(err);
    assert!(
        matches!(r[..], [Refusal::OutsideLimits { joint: 2, id: 2, angle_rad, .. }] if angle_rad < -1.0),
        "{r:?}"
    );
    assert!(r[0].to_string().contains("move it inside by hand"));
}

#[test]
fn bring_up_clears_a_watchdog_that_fired() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap();
    // The controller dies: silence beyond the watchdog.
    rig.settle(Duration::ZERO);
    if let Some(clock) = &rig.clock {
        clock.advance(Duration::from_millis(300));
    }
    rig.sim().with_sim(|s| s.advance());
    assert_eq!(
        rig.bus
            .read(2, Register::BusWatchdog, TIMEOUT)
            .unwrap()
            .value,
        -1
    );
    // A new run brings it up again and goals are accepted.
    arm.bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap();
    assert_eq!(
        rig.bus
            .read(2, Register::BusWatchdog, TIMEOUT)
            .unwrap()
            .value,
        5
    );
    let goal = arm.goals(&[0.0, 0.0, 0.0, 0.0]).unwrap();
    rig.bus
        .write(2, Register::GoalPosition, i64::from(goal[1].ticks), TIMEOUT)
        .unwrap();
}

#[test]
fn hold_on_exit_keeps_torque_on() {
    let config = config("hold");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap();
    arm.shut_down(&mut rig.bus).unwrap();
    assert_torque(&mut rig, &arm, 1);
}

#[test]
fn the_limits_wrapper_clamps_or_refuses_on_the_real_bus() {
    let config = config("torque_off");
    let arm = Arm::from_config(&config).unwrap();
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut rig.bus, BringUpOptions::default())
        .unwrap();
    let j2 = arm.joints()[1].clone();
    let goal = |rig: &Rig| {
        rig.sim()
            .with_servo(2, |s| s.value(addr::GOAL_POSITION))
            .flatten()
            .unwrap()
    };
    let before = goal(&rig);
    {
        let mut refuse = arm.limited(&mut rig.bus, Strategy::Refuse);
        let err = arm
            .write_pose(&mut refuse, &[0.0, 1.4, 0.0, 0.0])
            .unwrap_err();
        assert!(
            matches!(err, ServoError::OutsideLimits { id: 2, .. }),
            "{err}"
        );
    }
    rig.settle(Duration::ZERO);
    assert_eq!(goal(&rig), before, "a refused pose writes nothing");
    {
        let mut clamp = arm.limited(&mut rig.bus, Strategy::Clamp);
        arm.write_pose(&mut clamp, &[0.0, 1.4, 0.0, 0.0]).unwrap();
        assert_eq!(clamp.clamped(), 1);
    }
    rig.settle(Duration::ZERO);
    // Reversed joint: +1 rad is the low tick limit.
    assert_eq!(goal(&rig), i64::from(j2.ticks.min));
    assert!((j2.calibration.radians(f64::from(j2.ticks.min)) - 1.0).abs() < 2e-3);
}
