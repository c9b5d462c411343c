//! The administrative procedures of `servo::admin` (and the reboot wait of `servo::arm`)
//! against the simulated chain over a pseudo-terminal, its time on a manual clock: new id, new
//! baud rate, Return Delay Time, clearing the calibration registers, reading a servo's settings,
//! finding a servo at its baud rate. Expected register values are the XL430-W250 e-manual's
//! (Baud Rate index 1 = 57600, 3 = 1 Mbps; Return Delay Time in 2 µs units; Drive Mode bit 0 =
//! reverse, bit 2 = time-based profile; Model Number 1060).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::servo_support;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use servo_support::{sim_rig, xl430, Rig, TIMEOUT, WAIT_STEP};
use snakectl::servo::admin::{self, AdminError, Info};
use snakectl::servo::arm::{reboot_and_wait, Retry, REBOOT_WAIT};
use snakectl::servo::clock::{Clock, ManualClock};
use snakectl::servo::{HardwareErrors, ServoBus, ServoError};
use snakectl_sim::table::addr;
use snakectl_sim::{Fault, Model, ServoSpec, SimConfig, SimHandle, DEFAULT_BOOT_TIME};

/// The register at `address` of servo `id`, as the simulator holds it.
fn held(rig: &Rig, id: u8, address: u16) -> i64 {
    rig.sim()
        .with_servo(id, |s| s.value(address))
        .flatten()
        .unwrap_or_else(|| panic!("servo {id} has no register {address}"))
}

/// Whether servo `id` answers a ping at the bus's present rate.
fn answers(rig: &mut Rig, id: u8) -> bool {
    match rig.bus.ping(id, TIMEOUT) {
        Ok(p) => {
            assert_eq!(p.id, id);
            true
        }
        Err(e) => {
            assert!(e.is_timeout(), "ping {id}: {e}");
            false
        }
    }
}

/// Time on the simulator's clock since it started.
fn sim_elapsed(sim: &SimHandle) -> Duration {
    sim.with_sim(|s| s.clock().now() - s.start())
}

#[test]
fn set_id_moves_the_servo_to_its_new_id() {
    let mut rig = sim_rig(xl430(&[1, 2, 3]));
    assert!(admin::set_id(&mut rig.bus, 3, 20, TIMEOUT).unwrap().value);
    assert!(answers(&mut rig, 20));
    assert!(!answers(&mut rig, 3));
    assert_eq!(held(&rig, 20, addr::ID), 20);
    assert!(rig.sim().with_servo(3, |_| ()).is_none());
    // The others are untouched.
    assert!(answers(&mut rig, 1) && answers(&mut rig, 2));
}

#[test]
fn set_id_refuses_an_id_another_servo_has() {
    let mut rig = sim_rig(xl430(&[1, 2, 3]));
    match admin::set_id(&mut rig.bus, 1, 2, TIMEOUT) {
        Err(AdminError::IdTaken { id: 2, baud }) => assert_eq!(baud, 1_000_000),
        other => panic!("expected IdTaken, got {other:?}"),
    }
    // Both servos keep their ids.
    assert_eq!(held(&rig, 1, addr::ID), 1);
    assert_eq!(held(&rig, 2, addr::ID), 2);
    assert!(answers(&mut rig, 1) && answers(&mut rig, 2));
}

#[test]
fn set_id_to_the_same_id_or_out_of_range_changes_nothing() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    assert!(!admin::set_id(&mut rig.bus, 2, 2, TIMEOUT).unwrap().value);
    assert!(answers(&mut rig, 2));
    assert!(matches!(
        admin::set_id(&mut rig.bus, 2, 253, TIMEOUT),
        Err(AdminError::BadId(253))
    ));
    assert_eq!(held(&rig, 2, addr::ID), 2);
}

#[test]
fn set_baud_leaves_the_servo_answering_only_at_the_new_rate() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    let clock = ManualClock::new();
    admin::set_baud(&mut rig.bus, 2, 57_600, TIMEOUT, &clock).unwrap();
    // The switch-over wait went on the injected clock, not the wall.
    assert!(clock.elapsed() > Duration::ZERO);
    // Baud Rate index 1 selects 57600; the port follows.
    assert_eq!(held(&rig, 2, addr::BAUD_RATE), 1);
    assert_eq!(rig.bus.baud(), 57_600);
    assert!(answers(&mut rig, 2));
    assert!(!answers(&mut rig, 1));
    // Back at 1 Mbps: servo 1 answers, servo 2 no longer does.
    rig.bus.set_baud(1_000_000).unwrap();
    assert!(answers(&mut rig, 1));
    assert!(!answers(&mut rig, 2));
    assert_eq!(held(&rig, 1, addr::BAUD_RATE), 3);
}

#[test]
fn set_baud_refuses_a_rate_where_its_id_answers_already() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    // Servo 2 at 57600 as id 1: back at 1 Mbps it would share id 1 with servo 1.
    rig.sim().with_servo(2, |s| {
        s.poke(addr::BAUD_RATE, 1);
        s.poke(addr::ID, 1);
    });
    rig.bus.set_baud(57_600).unwrap();
    let clock = ManualClock::new();
    match admin::set_baud(&mut rig.bus, 1, 1_000_000, TIMEOUT, &clock) {
        Err(AdminError::IdTaken { id: 1, baud }) => assert_eq!(baud, 1_000_000),
        other => panic!("expected IdTaken, got {other:?}"),
    }
    // Nothing written; the port back at the servo's rate.
    assert_eq!(rig.bus.baud(), 57_600);
    assert!(answers(&mut rig, 1));
    rig.bus.set_baud(1_000_000).unwrap();
    assert_eq!(rig.bus.ping_counted(1, TIMEOUT).unwrap().1, 1);
}

#[test]
fn set_id_and_set_baud_refuse_an_id_servos_share() {
    let mut rig = sim_rig(xl430(&[1, 2, 3]));
    rig.sim().with_servo(2, |s| s.poke(addr::ID, 1));
    let (p, replies) = rig.bus.ping_counted(1, TIMEOUT).unwrap();
    assert_eq!((p.id, replies), (1, 2));
    assert_eq!(rig.bus.ping_counted(3, TIMEOUT).unwrap().1, 1);
    match admin::set_id(&mut rig.bus, 1, 9, TIMEOUT) {
        Err(AdminError::Shared {
            id: 1, answers: 2, ..
        }) => {}
        other => panic!("expected Shared, got {other:?}"),
    }
    let clock = ManualClock::new();
    match admin::set_baud(&mut rig.bus, 1, 57_600, TIMEOUT, &clock) {
        Err(AdminError::Shared {
            id: 1, answers: 2, ..
        }) => {}
        other => panic!("expected Shared, got {other:?}"),
    }
    assert!(!answers(&mut rig, 9));
    assert_eq!(held(&rig, 1, addr::BAUD_RATE), 3);
}

#[test]
fn set_baud_refuses_a_rate_the_servos_do_not_have() {
    let mut rig = sim_rig(xl430(&[1]));
    let clock = ManualClock::new();
    match admin::set_baud(&mut rig.bus, 1, 12_345, TIMEOUT, &clock) {
        Err(AdminError::Servo(ServoError::Baud(12_345))) => {}
        other => panic!("expected a refused baud rate, got {other:?}"),
    }
    assert_eq!(held(&rig, 1, addr::BAUD_RATE), 3);
    assert!(answers(&mut rig, 1));
}

#[test]
fn set_return_delay_writes_two_microsecond_units_and_refuses_what_does_not_fit() {
    let mut rig = sim_rig(xl430(&[1]));
    assert_eq!(
        admin::set_return_delay(&mut rig.bus, 1, 100, TIMEOUT)
            .unwrap()
            .value,
        100
    );
    assert_eq!(held(&rig, 1, addr::RETURN_DELAY_TIME), 50);
    assert_eq!(
        admin::set_return_delay(&mut rig.bus, 1, 508, TIMEOUT)
            .unwrap()
            .value,
        508
    );
    assert_eq!(held(&rig, 1, addr::RETURN_DELAY_TIME), 254);
    assert_eq!(
        admin::set_return_delay(&mut rig.bus, 1, 0, TIMEOUT)
            .unwrap()
            .value,
        0
    );
    assert_eq!(held(&rig, 1, addr::RETURN_DELAY_TIME), 0);
    for bad in [3, 509, 510] {
        match admin::set_return_delay(&mut rig.bus, 1, bad, TIMEOUT) {
            Err(AdminError::BadReturnDelay(us)) => assert_eq!(us, bad),
            other => panic!("{bad} µs: expected BadReturnDelay, got {other:?}"),
        }
    }
    assert_eq!(held(&rig, 1, addr::RETURN_DELAY_TIME), 0);
}

#[test]
fn clear_calibration_zeroes_the_offset_and_only_the_reverse_bit() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    rig.sim().with_servo(1, |s| {
        s.poke(addr::HOMING_OFFSET, -300);
        // Reverse (bit 0) and time-based profile (bit 2).
        s.poke(addr::DRIVE_MODE, 0b101);
        // Torque on: EEPROM items cannot be written until it is switched off.
        s.poke(addr::TORQUE_ENABLE, 1);
    });
    assert_eq!(
        admin::clear_calibration(&mut rig.bus, 1, TIMEOUT).unwrap(),
        admin::Written {
            value: (-300, 0b101),
            torque_was_on: true
        }
    );
    assert_eq!(held(&rig, 1, addr::HOMING_OFFSET), 0);
    assert_eq!(held(&rig, 1, addr::DRIVE_MODE), 0b100);
    assert_eq!(held(&rig, 1, addr::TORQUE_ENABLE), 0);
    // Servo 2 untouched.
    assert_eq!(held(&rig, 2, addr::DRIVE_MODE), 0);
    // Cleared already: reported as found, nothing changes.
    assert_eq!(
        admin::clear_calibration(&mut rig.bus, 1, TIMEOUT).unwrap(),
        admin::Written {
            value: (0, 0b100),
            torque_was_on: false
        }
    );
    assert_eq!(held(&rig, 1, addr::DRIVE_MODE), 0b100);
}

#[test]
fn clear_calibration_with_only_the_reverse_bit_set_keeps_the_offset_register_at_zero() {
    let mut rig = sim_rig(xl430(&[1]));
    rig.sim().with_servo(1, |s| s.poke(addr::DRIVE_MODE, 0b001));
    assert_eq!(
        admin::clear_calibration(&mut rig.bus, 1, TIMEOUT)
            .unwrap()
            .value,
        (0, 1)
    );
    assert_eq!(held(&rig, 1, addr::DRIVE_MODE), 0);
    assert_eq!(held(&rig, 1, addr::HOMING_OFFSET), 0);
}

#[test]
fn info_reports_what_the_servo_holds() {
    let mut spec = ServoSpec::new(4, Model::Xl430W250);
    spec.min_position_ticks = Some(1024);
    spec.max_position_ticks = Some(3072);
    spec.initial_position_ticks = Some(2100);
    let mut rig = sim_rig(SimConfig {
        servos: vec![spec],
        ..SimConfig::default()
    });
    rig.sim().with_servo(4, |s| {
        s.poke(addr::RETURN_DELAY_TIME, 25);
        s.poke(addr::HOMING_OFFSET, 64);
        s.poke(addr::DRIVE_MODE, 0b100);
        s.poke(addr::BUS_WATCHDOG, 10);
        s.poke(addr::TORQUE_ENABLE, 1);
        // Overload (bit 5) and overheating (bit 2).
        s.poke(addr::HARDWARE_ERROR_STATUS, 0x24);
    });
    let info = admin::info(&mut rig.bus, 4, TIMEOUT).unwrap();
    assert_eq!(
        info,
        Info {
            position: 2100,
            baud_register: 3,
            return_delay_us: 50,
            operating_mode: 3,
            limits: (1024, 3072),
            homing_offset: 64,
            drive_mode: 0b100,
            torque: true,
            watchdog: 10,
            errors: HardwareErrors(0x24),
        }
    );
}

#[test]
fn find_tries_each_rate_and_stays_at_the_one_that_answered() {
    let mut rig = sim_rig(SimConfig {
        baud: 115_200,
        ..xl430(&[1, 2])
    });
    // Servo 2 listens at 57600 (index 1), servo 1 at 115200.
    rig.sim().with_servo(2, |s| s.poke(addr::BAUD_RATE, 1));
    let bauds = [1_000_000, 115_200, 57_600];
    let p = admin::find(&mut rig.bus, 2, &bauds, TIMEOUT).unwrap();
    assert_eq!((p.id, p.model), (2, 1060));
    assert_eq!(rig.bus.baud(), 57_600);
    let p = admin::find(&mut rig.bus, 1, &bauds, TIMEOUT).unwrap();
    assert_eq!((p.id, p.model), (1, 1060));
    assert_eq!(rig.bus.baud(), 115_200);
}

#[test]
fn find_names_the_rates_it_tried_when_nothing_answers() {
    let mut rig = sim_rig(xl430(&[1]));
    match admin::find(&mut rig.bus, 9, &[57_600, 1_000_000], TIMEOUT) {
        Err(e @ AdminError::NotFound { .. }) => {
            assert_eq!(
                e.to_string(),
                "servo 9 does not answer at 57600, 1000000 baud"
            );
            let AdminError::NotFound { id, bauds } = e else {
                unreachable!()
            };
            assert_eq!((id, bauds), (9, vec![57_600, 1_000_000]));
        }
        other => panic!("expected NotFound, got {other:?}"),
    }
    // Servo 1 answers at 1 Mbps but not at 57600: only the rate it listens at finds it.
    assert!(matches!(
        admin::find(&mut rig.bus, 1, &[57_600], TIMEOUT),
        Err(AdminError::NotFound { id: 1, .. })
    ));
    assert!(matches!(
        admin::find(&mut rig.bus, 253, &[1_000_000], TIMEOUT),
        Err(AdminError::BadId(253))
    ));
}

/// A step clock that takes servo `id` off the bus the first time the wait reads it, that is
/// once the reboot instruction has been answered: a servo that does not come back.
#[derive(Debug)]
struct NeverBack<'a> {
    step: ManualClock,
    sim: &'a SimHandle,
    id: u8,
    gone: AtomicBool,
}

impl Clock for NeverBack<'_> {
    fn now(&self) -> std::time::Instant {
        if !self.gone.swap(true, Ordering::SeqCst) {
            self.sim.with_servo(self.id, |s| s.set_silent(true));
        }
        self.step.now()
    }
    fn sleep(&self, d: Duration) {
        self.step.sleep(d);
    }
}

#[test]
fn reboot_wait_gives_up_on_the_injected_clock_when_the_servo_never_answers() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    let sim = rig.sim.as_ref().unwrap();
    let clock = NeverBack {
        step: ManualClock::new(),
        sim,
        id: 2,
        gone: AtomicBool::new(false),
    };
    // Each ping of the silent servo waits its reply deadline on the wall; keep it short.
    let timeout = Duration::from_millis(10);
    let r = reboot_and_wait(&mut rig.bus, 2, timeout, &clock, &mut Retry::default());
    match r {
        Err(ServoError::Timeout { id: 2, .. }) => {}
        other => panic!("expected a timeout from servo 2, got {other:?}"),
    }
    // Gave up once the whole wait (3 s) had passed on the step clock, and promptly.
    let waited = clock.step.elapsed();
    assert_eq!(REBOOT_WAIT, Duration::from_secs(3));
    assert!(
        waited >= Duration::from_secs(3) && waited < Duration::from_millis(3100),
        "waited {waited:?}"
    );
    // The simulator's own clock never moved: the waiting was all on the step clock.
    assert_eq!(sim_elapsed(sim), Duration::ZERO);
    assert!(answers(&mut rig, 1));
}

/// Servo 2 of a pair with a hardware error latched, and `fault` injected: the simulator's clock
/// stands still until the reboot wait moves it, so a fault open for its first millisecond hits
/// the first REBOOT alone.
fn latched_rig(fault: Fault) -> Rig {
    let mut config = xl430(&[1, 2]);
    config.faults = vec![fault.during(Duration::ZERO, Some(Duration::from_millis(1)))];
    let rig = sim_rig(config);
    rig.sim()
        .with_servo(2, |s| s.poke(addr::HARDWARE_ERROR_STATUS, 0x20));
    rig
}

#[test]
fn a_reboot_whose_acknowledgement_is_lost_is_waited_for_not_sent_again() {
    let mut rig = latched_rig(Fault::DropReplies {
        id: Some(2),
        fraction: 1.0,
    });
    let wait = rig.wait_clock();
    let mut retry = Retry::default();
    reboot_and_wait(&mut rig.bus, 2, TIMEOUT, &*wait, &mut retry).unwrap();
    // The acknowledgement was the one reply lost, and no REBOOT was sent again (one sent while
    // the servo booted would have been ignored, and counted).
    assert_eq!(rig.sim().with_sim(|s| s.stats().dropped), 1);
    assert_eq!(retry.retries, 0);
    // Back once it had booted, the error cleared.
    assert_back_from_boot(&mut rig, DEFAULT_BOOT_TIME);
}

/// Servo 2 answered again `after` (on the simulator's clock, within one wait step), its
/// hardware error cleared.
fn assert_back_from_boot(rig: &mut Rig, after: Duration) {
    let waited = sim_elapsed(rig.sim());
    assert!(
        waited >= after && waited < after + WAIT_STEP,
        "waited {waited:?}, {after:?} expected"
    );
    assert_eq!(
        rig.bus.hardware_errors(2, TIMEOUT).unwrap(),
        HardwareErrors(0)
    );
}

#[test]
fn a_reboot_the_servo_never_heard_is_sent_again_once_it_answers_with_its_error() {
    let mut rig = latched_rig(Fault::Silent {
        id: 2,
        at: Duration::ZERO,
    });
    let wait = rig.wait_clock();
    let mut retry = Retry::default();
    reboot_and_wait(&mut rig.bus, 2, TIMEOUT, &*wait, &mut retry).unwrap();
    assert_eq!(retry.retries, 1);
    // The second REBOOT went out once the servo answered, a wait step in; then it booted.
    assert_back_from_boot(&mut rig, WAIT_STEP + DEFAULT_BOOT_TIME);
}

#[test]
fn reboot_wait_pings_until_the_servo_has_booted_and_clears_the_error() {
    let mut rig = sim_rig(xl430(&[1, 2]));
    rig.sim()
        .with_servo(2, |s| s.poke(addr::HARDWARE_ERROR_STATUS, 0x20));
    assert_eq!(
        rig.bus.hardware_errors(2, TIMEOUT).unwrap(),
        HardwareErrors(0x20)
    );
    let wait = rig.wait_clock();
    reboot_and_wait(&mut rig.bus, 2, TIMEOUT, &*wait, &mut Retry::default()).unwrap();
    // Back once it had booted, on the simulator's clock, within one step of the wait.
    assert_back_from_boot(&mut rig, DEFAULT_BOOT_TIME);
    assert_eq!(held(&rig, 2, addr::TORQUE_ENABLE), 0);
}
