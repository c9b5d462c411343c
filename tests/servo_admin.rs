//! The one-time servo settings (`servo::admin`, what `snakectl servo` runs) against the
//! simulated chain over a pseudo-terminal: new id, new baud rate, Return Delay Time, settings
//! read back, finding a servo at its baud rate. Waits run on a step clock, not wall time.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod servo_support;

use servo_support::{sim_rig, xl430, TIMEOUT};
use snakectl::servo::admin::{self, AdminError};
use snakectl::servo::clock::{Clock, StepClock};
use snakectl::servo::{Register, ServoBus};
use snakectl_sim::table::addr;

#[test]
fn set_id_moves_the_servo_and_refuses_a_taken_id() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    let bus = &mut rig.bus;
    let err = admin::set_id(bus, 1, 2, TIMEOUT).unwrap_err();
    assert!(
        matches!(
            err,
            AdminError::IdTaken {
                id: 2,
                baud: 1_000_000
            }
        ),
        "{err}"
    );
    assert!(
        !admin::set_id(bus, 1, 1, TIMEOUT).unwrap(),
        "same id: nothing to do"
    );
    assert!(admin::set_id(bus, 1, 7, TIMEOUT).unwrap());
    assert_eq!(bus.ping(7, TIMEOUT).unwrap().model, 1060);
    assert!(
        bus.ping(1, TIMEOUT).unwrap_err().is_timeout(),
        "the old id is free"
    );
    assert!(matches!(
        admin::set_id(bus, 7, 253, TIMEOUT),
        Err(AdminError::BadId(253))
    ));
}

#[test]
fn set_baud_leaves_the_servo_answering_at_the_new_rate_only() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    let clock = StepClock::new();
    // The simulated chain starts at 1 Mbps.
    admin::set_baud(&mut rig.bus, 2, 57_600, TIMEOUT, &clock).unwrap();
    assert_eq!(rig.bus.baud(), 57_600);
    // The switch-over wait ran on the step clock.
    assert_eq!(clock.elapsed(), std::time::Duration::from_millis(50));
    assert_eq!(rig.bus.ping(2, TIMEOUT).unwrap().id, 2);
    assert!(
        rig.bus.ping(1, TIMEOUT).is_err(),
        "servo 1 still listens at 1 Mbps"
    );
    // Baud Rate register 1 is 57600 in the e-manual's table.
    let reg = rig
        .sim()
        .with_servo(2, |s| s.value(addr::BAUD_RATE))
        .flatten();
    assert_eq!(reg, Some(1));
    rig.bus.set_baud(1_000_000).unwrap();
    assert_eq!(rig.bus.ping(1, TIMEOUT).unwrap().id, 1);
}

#[test]
fn find_tries_the_rates_in_turn_and_names_them_when_the_servo_is_absent() {
    let mut config = xl430(&[4]);
    config.baud = 2_000_000;
    let mut rig = sim_rig(config);
    let info = admin::find(&mut rig.bus, 4, &[57_600, 1_000_000, 2_000_000], TIMEOUT).unwrap();
    assert_eq!((info.id, rig.bus.baud()), (4, 2_000_000));
    let err = admin::find(&mut rig.bus, 9, &[57_600, 2_000_000], TIMEOUT).unwrap_err();
    assert_eq!(
        err.to_string(),
        "servo 9 does not answer at 57600, 2000000 baud"
    );
}

#[test]
fn return_delay_is_written_in_two_microsecond_units() {
    let mut rig = sim_rig(xl430(&[1]));
    assert_eq!(
        admin::set_return_delay(&mut rig.bus, 1, 120, TIMEOUT).unwrap(),
        120
    );
    let reg = rig
        .sim()
        .with_servo(1, |s| s.value(addr::RETURN_DELAY_TIME))
        .flatten();
    assert_eq!(reg, Some(60));
    for bad in [121, 510] {
        let err = admin::set_return_delay(&mut rig.bus, 1, bad, TIMEOUT).unwrap_err();
        assert!(
            matches!(err, AdminError::BadReturnDelay(b) if b == bad),
            "{err}"
        );
    }
}

#[test]
fn info_reads_what_the_servo_holds() {
    let mut rig = sim_rig(xl430(&[1]));
    rig.sim().with_servo(1, |s| {
        s.poke(addr::HOMING_OFFSET, 12);
        s.poke(addr::DRIVE_MODE, 1);
        s.poke(addr::MIN_POSITION_LIMIT, 100);
    });
    let i = admin::info(&mut rig.bus, 1, TIMEOUT).unwrap();
    assert_eq!(i.homing_offset, 12);
    assert_eq!(i.drive_mode, 1);
    assert_eq!(i.limits.0, 100);
    assert_eq!(i.baud_register, 3, "1 Mbps is register value 3");
    assert!(!i.torque);
    assert!(i.errors.is_empty());
    // Cleared, both read neutral.
    assert_eq!(
        admin::clear_calibration(&mut rig.bus, 1, TIMEOUT).unwrap(),
        (12, 1)
    );
    assert_eq!(
        rig.bus
            .read(1, Register::HomingOffset, TIMEOUT)
            .unwrap()
            .value,
        0
    );
    assert_eq!(
        rig.bus.read(1, Register::DriveMode, TIMEOUT).unwrap().value,
        0
    );
}
