//! Fast Sync Read over a pseudo-terminal against the simulated chain: every servo read in one
//! packet; a silent servo in the middle, a damaged block, each costing that servo alone (also
//! on a timed wire, where the read sleeps toward the reply it has learnt to expect); mixed
//! firmware falling back to Sync Read under `read = "auto"` and refused, naming the servo,
//! under `read = "fast"`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::servo_support;

use std::time::Duration;

use servo_support::{realtime_rig, sim_rig, xl430, TIMEOUT};
use snakectl::config::Config;
use snakectl::servo::arm::{BringUpError, BringUpOptions, Refusal};
use snakectl::servo::limits::LimitPolicy;
use snakectl::servo::{Fields, ReadKind, Register, ServoBus, ServoError, SyncReadBuf};
use snakectl_sim::{Fault, SimConfig};

const IDS: [u8; 12] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];

/// Twelve servos, each at its own position (1000 + 10 × id).
fn chain(faults: Vec<Fault>) -> SimConfig {
    let mut config = xl430(&IDS);
    for s in &mut config.servos {
        s.initial_position_ticks = Some(1000 + 10 * i32::from(s.id));
    }
    config.faults = faults;
    config
}

/// Present Position of every servo by one Fast Sync Read: the value, or the error.
fn fast_positions(rig: &mut servo_support::Rig) -> Vec<Result<i64, ServoError>> {
    let mut out = SyncReadBuf::new();
    rig.bus
        .fast_sync_read_into(&IDS, 132, 4, TIMEOUT, &mut out)
        .unwrap();
    (0..IDS.len())
        .map(|i| match out.get(i) {
            Ok((data, _)) => Ok(Register::PresentPosition.decode(data).unwrap()),
            Err(e) => Err(match e {
                ServoError::Timeout { id, waited } => ServoError::Timeout {
                    id: *id,
                    waited: *waited,
                },
                ServoError::Checksum {
                    id,
                    received,
                    computed,
                } => ServoError::Checksum {
                    id: *id,
                    received: *received,
                    computed: *computed,
                },
                other => panic!("servo {}: {other}", IDS[i]),
            }),
        })
        .collect()
}

fn expected(id: u8) -> i64 {
    1000 + 10 * i64::from(id)
}

#[test]
fn every_servo_is_read_in_one_packet() {
    let mut rig = sim_rig(chain(Vec::new()));
    let got = fast_positions(&mut rig);
    for (&id, value) in IDS.iter().zip(&got) {
        assert_eq!(value.as_ref().ok(), Some(&expected(id)), "servo {id}");
    }
    // The simulator answered one packet, not twelve.
    assert_eq!(rig.sim().with_sim(|s| s.stats().replies), 1);
    // And a bus set to Fast reads the loop's states through it.
    rig.bus.set_read_kind(ReadKind::Fast).unwrap();
    assert_eq!(rig.bus.read_kind(), ReadKind::Fast);
    let states = rig.bus.read_states(&IDS, Fields::ALL, TIMEOUT).unwrap();
    for (&id, s) in IDS.iter().zip(&states) {
        let s = s.as_ref().unwrap();
        assert_eq!(i64::from(s.position_ticks), expected(id));
        assert!(s.voltage_dv.is_some() && s.temperature_c.is_some());
    }
    assert_eq!(rig.sim().with_sim(|s| s.stats().replies), 2);
}

#[test]
fn a_silent_servo_in_the_middle_costs_only_its_own_reading() {
    let mut rig = sim_rig(chain(vec![Fault::Silent {
        id: 6,
        at: Duration::ZERO,
    }]));
    let got = fast_positions(&mut rig);
    for (&id, value) in IDS.iter().zip(&got) {
        if id == 6 {
            assert!(
                matches!(value, Err(ServoError::Timeout { id: 6, .. })),
                "{value:?}"
            );
        } else {
            assert_eq!(value.as_ref().ok(), Some(&expected(id)), "servo {id}");
        }
    }
    // One Fast reply (servos 1 to 5), then servos 7 to 12 asked again by Sync Read.
    assert_eq!(rig.sim().with_sim(|s| s.stats().replies), 1 + 6);
}

#[test]
fn a_damaged_block_costs_only_that_servos_reading() {
    let mut rig = sim_rig(chain(vec![Fault::CorruptReplies {
        id: Some(4),
        fraction: 1.0,
    }]));
    let got = fast_positions(&mut rig);
    for (&id, value) in IDS.iter().zip(&got) {
        if id == 4 {
            assert!(
                matches!(value, Err(ServoError::Checksum { id: 4, .. })),
                "{value:?}"
            );
        } else {
            assert_eq!(value.as_ref().ok(), Some(&expected(id)), "servo {id}");
        }
    }
}

#[test]
fn the_last_servo_silent_is_named_after_the_others_arrive() {
    let mut rig = sim_rig(chain(vec![Fault::Silent {
        id: 12,
        at: Duration::ZERO,
    }]));
    let got = fast_positions(&mut rig);
    assert_eq!(got.iter().filter(|v| v.is_ok()).count(), 11, "{got:?}");
    assert!(matches!(got[11], Err(ServoError::Timeout { id: 12, .. })));
    // Nobody after it to ask again: the one Fast reply was all.
    assert_eq!(rig.sim().with_sim(|s| s.stats().replies), 1);
}

#[test]
fn on_a_timed_wire_a_servo_falling_silent_after_reads_that_taught_the_timing_costs_its_reading() {
    // Wire time at 1 Mbps: after a few whole reads the read sleeps toward its reply. Servo 6
    // falls silent 300 ms in; every read before reads all twelve, every read after all but it.
    let mut config = chain(vec![Fault::Silent {
        id: 6,
        at: Duration::from_millis(300),
    }]);
    config.baud = 1_000_000;
    config.wire_timing = true;
    let mut rig = realtime_rig(config);
    let (mut whole, mut without_6) = (0, 0);
    while without_6 < 20 {
        let got = fast_positions(&mut rig);
        let missing: Vec<u8> = IDS
            .iter()
            .zip(&got)
            .filter(|(_, v)| v.is_err())
            .map(|(&id, _)| id)
            .collect();
        match missing.as_slice() {
            [] => {
                assert_eq!(without_6, 0, "servo 6 answered again after falling silent");
                whole += 1;
            }
            [6] => {
                assert!(matches!(got[5], Err(ServoError::Timeout { id: 6, .. })));
                without_6 += 1;
            }
            other => panic!("servos {other:?} unread after {whole} whole reads: {got:?}"),
        }
        for (&id, value) in IDS.iter().zip(&got).filter(|(&id, _)| id != 6) {
            assert_eq!(value.as_ref().ok(), Some(&expected(id)), "servo {id}");
        }
        assert!(whole < 1000, "servo 6 never fell silent");
    }
    assert!(whole >= 10, "only {whole} whole reads before the silence");
}

/// A four-joint arm of XL330s (Fast Sync Read from firmware 46) with `[bus] read = read`.
fn arm_config(read: &str) -> Config {
    let mut text = String::from(
        "[arm]\nbase_x_m = 0.0\nbase_y_m = 0.0\nbase_heading_rad = 0.0\nhome_rad = [0.0, 0.0, 0.0, 0.0]\n",
    );
    for id in 1..=4 {
        text += &format!(
            "[[joint]]\nlink_m = 0.1\nmin_rad = -2.0\nmax_rad = 2.0\nid = {id}\nmodel = \"XL330-M288\"\n"
        );
    }
    text += &format!("[bus]\nkind = \"sim\"\nreply_timeout_ms = 200\nread = \"{read}\"\n");
    text += "[sim]\n[sim.firmware_by_id]\n3 = 45\n";
    Config::from_str(&text, "arm.toml").unwrap()
}

fn bring_up(read: &str, firmware_3: Option<u8>) -> Result<ReadKind, BringUpError> {
    let config = arm_config(read);
    let arm = config.arm().unwrap().clone();
    let mut sim = snakectl::connect::sim_config(&config).unwrap();
    assert_eq!(
        sim.servos[2].firmware,
        Some(45),
        "the config's firmware reaches the simulator"
    );
    sim.servos[2].firmware = firmware_3;
    let mut rig = sim_rig(sim);
    let mut bus = arm.limited(&mut rig.bus, LimitPolicy::Clamp);
    let up = arm.bring_up(&mut bus, BringUpOptions::default())?;
    assert_eq!(bus.read_kind(), up.read());
    // Whatever the read, the arm reads its pose.
    let pose = arm.read_pose(&mut bus).unwrap();
    assert_eq!(pose.len(), 4);
    Ok(up.read())
}

#[test]
fn auto_reads_fast_where_every_servo_can_and_falls_back_to_sync_otherwise() {
    assert_eq!(bring_up("auto", None).unwrap(), ReadKind::Fast);
    assert_eq!(bring_up("auto", Some(45)).unwrap(), ReadKind::Sync);
    assert_eq!(bring_up("sync", None).unwrap(), ReadKind::Sync);
    assert_eq!(bring_up("fast", Some(46)).unwrap(), ReadKind::Fast);
}

#[test]
fn fast_with_a_servo_too_old_is_refused_naming_it() {
    let err = bring_up("fast", Some(45)).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("joint 3: servo 3 is a XL330-M288 with firmware 45")
            && text.contains("firmware 46 or later"),
        "{text}"
    );
    match err {
        BringUpError::Refused(r) => assert!(matches!(
            r[..],
            [Refusal::NoFastRead {
                joint: 3,
                id: 3,
                firmware: 45,
                ..
            }]
        )),
        other => panic!("{other}"),
    }
}
