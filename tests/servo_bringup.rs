//! Bring-up and shut-down of a configured arm over a pseudo-terminal against the simulated
//! chain: the instructions in the order the servos receive them, each refusal (missing servo,
//! wrong model, hardware error, calibration registers, joint outside its limits), retries on a
//! lossy bus, a fired watchdog cleared and recovered, the limits wrapper on the real bus.
//! Expected register values are computed by hand from the e-manual's units.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::servo_support;

use std::time::Duration;

use servo_support::{sim_rig, Rig, TIMEOUT};
use snakectl::config::Config;
use snakectl::servo::arm::{Arm, BringUpError, BringUpOptions, Refusal, Within};
use snakectl::servo::limits::{LimitPolicy, Limited};
use snakectl::servo::record::{Instruction, Recording};
use snakectl::servo::units;
use snakectl::servo::{Register, ServoBus, ServoError};
use snakectl_sim::table::addr;
use snakectl_sim::{Fault, HardwareErrorKind, Model, SimConfig};

/// Two seconds of wall time for a job on a running arm, each reply waited for [`TIMEOUT`].
fn within() -> Within<'static> {
    Within::wall(Duration::from_secs(2), TIMEOUT)
}

const HOME: [f64; 4] = [0.3, -0.2, 0.1, 0.5];

/// A four-joint arm of XL430s; joint 2 is limited to [-1, 1] rad and reversed, joint 4 has an
/// offset of 40 ticks.
fn config_text(on_exit: &str) -> String {
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
    text
}

fn config(on_exit: &str) -> Config {
    Config::from_str(&config_text(on_exit), "arm.toml").unwrap()
}

fn arm_of(config: &Config) -> Arm {
    config.arm().unwrap().clone()
}

/// Goal Position limits of the four joints, by hand: 4096 / 2 pi = 651.899 ticks a radian
/// around 2048 (+ the offset), rounded inward.
const TICK_LIMITS: [(i64, i64); 4] = [(745, 3351), (1397, 2699), (745, 3351), (785, 3391)];

/// The simulated chain of `config` (servos at the home pose), changed by `edit`.
fn rig(config: &Config, edit: impl FnOnce(&mut SimConfig)) -> Rig {
    let mut sim = snakectl::connect::sim_config(config).unwrap();
    edit(&mut sim);
    sim_rig(sim)
}

/// The rig's bus, limited to `arm`'s joint limits.
fn limited<'a>(
    rig: &'a mut Rig,
    arm: &Arm,
) -> Limited<&'a mut snakectl::servo::dynamixel::DynamixelBus> {
    arm.limited(&mut rig.bus, LimitPolicy::Clamp)
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
    let arm = arm_of(&config);
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
        .bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap();
    assert_eq!(up.servos.len(), 4);
    assert!(up.rebooted.is_empty());
    assert_eq!(up.retries, 0, "a clean bus needs no retry");
    let tick = std::f64::consts::TAU / units::TICKS_PER_TURN;
    for (got, want) in up.pose.iter().zip(HOME) {
        assert!((got - want).abs() <= tick, "{got} vs {want}");
    }
    for (j, (min, max)) in arm.joints().iter().zip(TICK_LIMITS) {
        let sim = rig.sim();
        let v = |a: u16| sim.with_servo(j.id, |s| s.value(a)).flatten().unwrap();
        assert_eq!(v(addr::TORQUE_ENABLE), 1, "servo {}", j.id);
        assert_eq!(
            v(addr::GOAL_POSITION),
            v(addr::PRESENT_POSITION),
            "servo {}",
            j.id
        );
        // 100 ms in units of 20 ms.
        assert_eq!(v(addr::BUS_WATCHDOG), 5);
        assert_eq!(v(addr::RETURN_DELAY_TIME), 0);
        assert_eq!(v(addr::STATUS_RETURN_LEVEL), 2);
        assert_eq!(v(addr::OPERATING_MODE), 3);
        assert_eq!(v(addr::MIN_POSITION_LIMIT), min, "servo {}", j.id);
        assert_eq!(v(addr::MAX_POSITION_LIMIT), max, "servo {}", j.id);
        // 3 rad/s over 0.229 rev/min = 0.023981 rad/s: 125.1 units.
        assert_eq!(v(addr::PROFILE_VELOCITY), 125);
        // 20 rad/s^2 over 214.577 rev/min^2 = 0.374507 rad/s^2: 53.4 units.
        assert_eq!(v(addr::PROFILE_ACCELERATION), 53);
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
    arm.shut_down(&mut rig.bus, &[], &within()).unwrap();
    assert_torque(&mut rig, &arm, 0);
}

/// Position of the first instruction matching `want` in the log.
fn at(log: &[Instruction], want: impl Fn(&Instruction) -> bool) -> usize {
    log.iter()
        .position(want)
        .unwrap_or_else(|| panic!("not sent: {log:#?}"))
}

#[test]
fn bring_up_sends_its_instructions_in_the_safe_order() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |_| {});
    let mut rec = Recording::new(&mut rig.bus);
    arm.bring_up(
        &mut arm.limited(&mut rec, LimitPolicy::Clamp),
        BringUpOptions::default(),
    )
    .unwrap();
    let log = rec.log().to_vec();
    for (j, id) in arm.ids().into_iter().enumerate() {
        let ping = at(&log, |i| *i == Instruction::Ping(id));
        let offset = at(&log, |i| {
            *i == Instruction::Read(id, Register::HomingOffset)
        });
        let drive = at(&log, |i| *i == Instruction::Read(id, Register::DriveMode));
        let pose = at(&log, |i| {
            matches!(i, Instruction::SyncRead { address: 132, .. })
        });
        let cleared = at(&log, |i| {
            *i == Instruction::Write(id, Register::BusWatchdog, 0)
        });
        let hold = at(
            &log,
            |i| matches!(i, Instruction::Write(s, Register::GoalPosition, _) if *s == id),
        );
        let armed = at(&log, |i| {
            *i == Instruction::Write(id, Register::BusWatchdog, 5)
        });
        let torque = at(&log, |i| {
            *i == Instruction::Write(id, Register::TorqueEnable, 1)
        });
        assert!(
            ping < offset && offset < pose && drive < pose,
            "servo {id}: checks before the pose is read"
        );
        assert!(
            pose < cleared,
            "servo {id}: pose read before anything is written"
        );
        assert!(
            cleared < hold,
            "servo {id}: watchdog cleared before the goal is written"
        );
        assert!(
            hold < armed,
            "servo {id}: goal = present before the watchdog is armed"
        );
        assert!(armed < torque, "servo {id}: torque on last");
        // The goal written is the position read, in ticks, for this joint.
        let Instruction::Write(_, _, goal) = log[hold] else {
            unreachable!()
        };
        let (min, max) = TICK_LIMITS[j];
        assert!((min..=max).contains(&goal), "servo {id}: goal {goal}");
    }
    // Nothing but the goal writes reaches Goal Position, and no goal is sent by Sync Write.
    assert!(!log
        .iter()
        .any(|i| matches!(i, Instruction::SyncWrite(Register::GoalPosition, _))));
}

#[test]
fn bring_up_refuses_a_missing_servo_naming_it() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |s| s.servos.retain(|s| s.id != 3));
    let err = arm
        .bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
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
    assert_torque(
        &mut rig,
        &Arm::new(arm.joints()[..2].to_vec(), arm.settings().clone()),
        0,
    );
}

#[test]
fn bring_up_refuses_a_servo_of_the_wrong_model() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |s| s.servos[1].model = Model::Xm430W350);
    let err = arm
        .bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "refusing to start: joint 2: servo 2 is a XM430-W350 (model 1020), the config says XL430-W250"
    );
}

#[test]
fn bring_up_refuses_a_servo_with_its_own_offset_or_direction() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |_| {});
    rig.sim()
        .with_servo(2, |s| s.poke(addr::HOMING_OFFSET, 300));
    // Reverse bit set, with the time-based profile bit (4) beside it.
    rig.sim().with_servo(4, |s| s.poke(addr::DRIVE_MODE, 5));
    let err = arm
        .bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("joint 2: servo 2 has HomingOffset = 300, expected 0"),
        "{text}"
    );
    assert!(
        text.contains("joint 4: servo 4 has DriveMode = 5, expected 4"),
        "{text}"
    );
    assert!(text.contains("clear-calibration"), "{text}");
    assert_torque(&mut rig, &arm, 0);
    // Cleared by the administrative procedure, bring-up goes through.
    for id in [2, 4] {
        snakectl::servo::admin::clear_calibration(&mut rig.bus, id, TIMEOUT).unwrap();
    }
    assert_eq!(
        rig.bus.read(4, Register::DriveMode, TIMEOUT).unwrap().value,
        4,
        "the other Drive Mode bits are kept"
    );
    arm.bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap();
}

#[test]
fn bring_up_refuses_a_hardware_error_unless_asked_to_reboot() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let fault = |s: &mut SimConfig| {
        s.faults = vec![Fault::HardwareError {
            id: 4,
            at: Duration::ZERO,
            kind: HardwareErrorKind::Overheating,
        }]
    };
    let mut rig1 = rig(&config, fault);
    let err = arm
        .bring_up(&mut limited(&mut rig1, &arm), BringUpOptions::default())
        .unwrap_err();
    assert!(
        err.to_string().contains(
            "joint 4: servo 4 reports a hardware error: overheating (0x04) (reboot it: `snakectl servo reboot --id 4`)"
        ),
        "{err}"
    );
    let mut rig2 = rig(&config, fault);
    // The rebooted servo boots on the simulator's clock while bring-up waits for it.
    let wait = rig2.wait_clock();
    let up = arm
        .bring_up_with_clock(
            &mut limited(&mut rig2, &arm),
            BringUpOptions { reboot: true },
            &*wait,
        )
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
    let arm = arm_of(&config);
    // Joint 2 (limits [-1, 1] rad, reversed) turned by hand to 978 ticks above centre:
    // -978 / 651.9 = -1.50 rad.
    let mut rig = rig(&config, |s| {
        s.servos[1].initial_position_ticks = Some(2048 + 978)
    });
    let err = arm
        .bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap_err();
    let r = refusals(err);
    assert!(
        matches!(r[..], [Refusal::OutsideLimits { joint: 2, id: 2, angle_rad, .. }] if (angle_rad + 1.5002).abs() < 1e-3),
        "{r:?}"
    );
    assert!(r[0].to_string().contains("move it inside by hand"));
}

/// Let the bus stay silent beyond the watchdog's 100 ms.
fn go_quiet(rig: &mut Rig) {
    rig.settle(Duration::ZERO);
    if let Some(clock) = &rig.clock {
        clock.advance(Duration::from_millis(300));
    }
    rig.sim().with_sim(|s| s.advance());
}

#[test]
fn bring_up_clears_a_watchdog_that_fired() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap();
    // The controller dies: silence beyond the watchdog.
    go_quiet(&mut rig);
    assert_eq!(
        rig.bus
            .read(2, Register::BusWatchdog, TIMEOUT)
            .unwrap()
            .value,
        -1
    );
    // A new run brings it up again and goals are accepted.
    arm.bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
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
fn a_tripped_watchdog_is_found_and_recovered_without_a_jump() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap();
    assert!(arm
        .tripped_watchdogs(&mut rig.bus, &within())
        .unwrap()
        .is_empty());
    let profiles = |rig: &mut Rig, id: u8| {
        [Register::ProfileAcceleration, Register::ProfileVelocity]
            .map(|r| rig.bus.read(id, r, TIMEOUT).unwrap().value)
    };
    let written = profiles(&mut rig, 1);
    assert!(written.iter().all(|&v| v > 0), "{written:?}");
    go_quiet(&mut rig);
    assert_eq!(
        arm.tripped_watchdogs(&mut rig.bus, &within()).unwrap(),
        arm.ids()
    );
    // The watchdog that fired set the profiles to 0; that is not taken for a power loss.
    for &id in &arm.ids() {
        assert_eq!(profiles(&mut rig, id), [0, 0], "servo {id}");
        let lost = arm
            .ram_reset(&mut rig.bus, id, true, &Default::default(), &within())
            .unwrap();
        assert_eq!(lost, None, "servo {id}");
    }
    // A goal is refused by the servo while its watchdog reads -1.
    let goals = arm.goals(&[0.0, 0.0, 0.0, 0.0]).unwrap();
    let refused = rig
        .bus
        .write(
            1,
            Register::GoalPosition,
            i64::from(goals[0].ticks),
            TIMEOUT,
        )
        .unwrap_err();
    assert!(
        matches!(refused, ServoError::Status { id: 1, .. }),
        "{refused}"
    );
    let before: Vec<i64> = arm
        .ids()
        .iter()
        .map(|&id| {
            rig.bus
                .read(id, Register::PresentPosition, TIMEOUT)
                .unwrap()
                .value
        })
        .collect();

    let recovered = arm
        .recover_watchdog(
            &mut limited(&mut rig, &arm),
            &within(),
            &mut Default::default(),
        )
        .unwrap();
    assert_eq!(recovered, arm.ids());
    for (&id, present) in arm.ids().iter().zip(&before) {
        let mut read = |r| rig.bus.read(id, r, TIMEOUT).unwrap().value;
        assert_eq!(read(Register::BusWatchdog), 5, "servo {id}: armed again");
        assert_eq!(
            [
                read(Register::ProfileAcceleration),
                read(Register::ProfileVelocity)
            ],
            written,
            "servo {id}: its profiles written again"
        );
        assert_eq!(
            read(Register::GoalPosition),
            *present,
            "servo {id}: holds where it is"
        );
    }
    // Goals are accepted again: the servos take them.
    arm.write_pose(&mut limited(&mut rig, &arm), &[0.0, 0.0, 0.0, 0.0])
        .unwrap();
    rig.settle(Duration::ZERO);
    for (&id, g) in arm.ids().iter().zip(&goals) {
        let goal = rig
            .bus
            .read(id, Register::GoalPosition, TIMEOUT)
            .unwrap()
            .value;
        assert_eq!(goal, i64::from(g.ticks), "servo {id}");
    }
}

#[test]
fn hold_on_exit_keeps_torque_on_until_the_watchdog_stops_the_servos() {
    let mut rig_hold = rig(&config("hold"), |_| {});
    let arm = arm_of(&config("hold"));
    arm.bring_up(&mut limited(&mut rig_hold, &arm), BringUpOptions::default())
        .unwrap();
    arm.shut_down(&mut rig_hold.bus, &[], &within()).unwrap();
    assert_torque(&mut rig_hold, &arm, 1);
    // Once the bus is quiet the watchdog fires: the servos stop, torque stays on.
    go_quiet(&mut rig_hold);
    assert_eq!(
        arm.tripped_watchdogs(&mut rig_hold.bus, &within()).unwrap(),
        arm.ids()
    );
    assert_torque(&mut rig_hold, &arm, 1);

    // The same arm with torque_off goes limp at shut-down.
    let arm = arm_of(&config("torque_off"));
    let mut rig_off = rig(&config("torque_off"), |_| {});
    arm.bring_up(&mut limited(&mut rig_off, &arm), BringUpOptions::default())
        .unwrap();
    assert_torque(&mut rig_off, &arm, 1);
    arm.shut_down(&mut rig_off.bus, &[], &within()).unwrap();
    assert_torque(&mut rig_off, &arm, 0);
}

/// A twelve-joint arm of the shipped simulator config with 1 % of replies dropped and 1 %
/// damaged from power-on.
fn lossy_config(seed: u64) -> Config {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let text = std::fs::read_to_string(path).unwrap();
    // A reply timeout a loaded test machine keeps: a late reply is then a dropped one only.
    let text = text
        .replace("reply_timeout_ms = 20 ", "reply_timeout_ms = 100")
        .replace("seed = 1", &format!("seed = {seed}"))
        + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.01\n"
        + "\n[[sim.fault]]\nkind = \"corrupt\"\nfraction = 0.01\n";
    Config::from_str(&text, "lossy.toml").unwrap()
}

#[test]
fn bring_up_torque_and_shut_down_ride_out_a_lossy_bus() {
    let mut retries = 0;
    let mut exchanges = 0;
    for seed in 1..=6 {
        let config = lossy_config(seed);
        assert_eq!(
            config.sim().unwrap().seed,
            seed,
            "the seed reaches the simulator"
        );
        let arm = arm_of(&config);
        assert_eq!(arm.joints().len(), 12);
        let mut rig = rig(&config, |_| {});
        let mut rec = Recording::new(&mut rig.bus);
        let up = arm
            .bring_up(
                &mut arm.limited(&mut rec, LimitPolicy::Clamp),
                BringUpOptions::default(),
            )
            .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        exchanges += rec.log().len();
        retries += up.retries;
        let mut bus = arm.limited(&mut rec, LimitPolicy::Clamp);
        arm.torque_off(&mut bus, &[], &within()).unwrap();
        arm.torque_on(&mut bus, &[], &within()).unwrap();
        arm.shut_down(&mut bus, &[], &within()).unwrap();
        drop(bus);
        // Read inside the simulator: the bus itself still loses replies.
        for id in arm.ids() {
            let torque = rig.sim().with_servo(id, |s| s.value(addr::TORQUE_ENABLE));
            assert_eq!(torque.flatten(), Some(0), "seed {seed}, servo {id}");
        }
    }
    println!("6 lossy bring-ups: {exchanges} instructions, {retries} retries");
    // About 170 exchanges a bring-up at 2 % loss: without retries almost none would complete.
    assert!(exchanges > 6 * 150, "{exchanges} exchanges");
    assert!(retries >= 5, "the loss was felt: {retries} retries");
}

#[test]
fn the_limits_wrapper_clamps_or_refuses_on_the_real_bus() {
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut rig = rig(&config, |_| {});
    arm.bring_up(&mut limited(&mut rig, &arm), BringUpOptions::default())
        .unwrap();
    let goal = |rig: &Rig| {
        rig.sim()
            .with_servo(2, |s| s.value(addr::GOAL_POSITION))
            .flatten()
            .unwrap()
    };
    let before = goal(&rig);
    {
        let mut refuse = arm.limited(&mut rig.bus, LimitPolicy::Refuse);
        let err = arm
            .write_pose(&mut refuse, &[0.0, 1.4, 0.0, 0.0])
            .unwrap_err();
        assert!(
            matches!(err, ServoError::OutsideLimits { id: 2, .. }),
            "{err}"
        );
        // Nor can a raw write move the limits out of the way.
        let err = refuse
            .write(2, Register::MinPositionLimit, 0, TIMEOUT)
            .unwrap_err();
        assert!(matches!(err, ServoError::Protected { id: 2, .. }), "{err}");
    }
    rig.settle(Duration::ZERO);
    assert_eq!(goal(&rig), before, "a refused pose writes nothing");
    {
        let mut clamp = arm.limited(&mut rig.bus, LimitPolicy::Clamp);
        arm.write_pose(&mut clamp, &[0.0, 1.4, 0.0, 0.0]).unwrap();
        assert_eq!(clamp.clamped(), 1);
    }
    rig.settle(Duration::ZERO);
    // Reversed joint: +1 rad is the low tick limit, 2048 - 651.9 rounded up.
    assert_eq!(goal(&rig), 1397);
}

#[test]
fn a_servo_one_tick_past_its_limit_is_brought_up_on_the_limit_two_ticks_are_refused() {
    // A servo left one tick past joint 1's limit rounded inward (3351), as other software
    // rounding 2 rad to its nearest tick (3352) would leave it.
    let config = config("torque_off");
    let arm = arm_of(&config);
    let mut one_past = rig(&config, |s| s.servos[0].initial_position_ticks = Some(3352));
    let up = arm
        .bring_up(&mut limited(&mut one_past, &arm), BringUpOptions::default())
        .unwrap();
    assert_eq!(up.pose[0], 2.0, "held on the limit itself");
    let goal = one_past
        .bus
        .read(1, Register::GoalPosition, TIMEOUT)
        .unwrap()
        .value;
    assert_eq!(
        goal, TICK_LIMITS[0].1,
        "the goal written lies inside the limits"
    );

    let mut two_past = rig(&config, |s| s.servos[0].initial_position_ticks = Some(3353));
    let err = arm
        .bring_up(&mut limited(&mut two_past, &arm), BringUpOptions::default())
        .unwrap_err();
    let r = refusals(err);
    assert!(
        matches!(
            r[..],
            [Refusal::OutsideLimits {
                joint: 1,
                id: 1,
                ..
            }]
        ),
        "{r:?}"
    );
}
