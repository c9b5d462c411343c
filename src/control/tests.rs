//! Tests of the controller on the daemon's arm (12 links of 0.08 m, limits +-2 rad, base at
//! the origin heading up): repeated path points, joint moves at the joint speed limit, and a
//! tangled start pose.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::FRAC_PI_2;

use super::*;
use crate::chain::JointLimit;

const N: usize = 12;

fn chain() -> Chain {
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    Chain::new(vec![0.08; N], Vec2::zeros(), FRAC_PI_2, vec![lim; N]).unwrap()
}

fn limits() -> Limits {
    Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 2.0,
        deadman_s: 0.5,
    }
}

/// A controller holding `theta`, home 0.1 rad at every joint.
fn holding(limits: Limits, theta: &[f64]) -> Controller {
    Controller::new(chain(), limits, Strategy::Overall, vec![0.1; N], theta).unwrap()
}

/// Ticks of `dt` until the active command finishes (at most `max`): the finish and the ticks.
fn run(c: &mut Controller, dt: f64, max: usize) -> (Option<Finish>, usize) {
    for k in 1..=max {
        if let Some(f) = c.tick(dt).finished {
            return (Some(f), k);
        }
    }
    (None, max)
}

#[test]
fn repeated_path_points_cost_no_ticks() {
    let home = vec![0.1; N];
    let tip = chain().tip(&home);
    let a = tip + Vec2::new(0.01, 0.0);
    let b = a + Vec2::new(0.0, 0.01);
    let c = b + Vec2::new(-0.01, 0.005);
    let plain = vec![a, b, c];
    // Each point repeated, exactly or within a hair, and the start repeated at the end.
    let hair = Vec2::new(3e-10, -4e-10);
    let repeated = vec![a, a, a + hair, b, b, b - hair, b, c, c, c + hair];
    let mut ticks = Vec::new();
    for points in [plain, repeated] {
        let mut ctl = holding(limits(), &home);
        ctl.command(Command::Path {
            points,
            speed: None,
        })
        .unwrap();
        let (finish, k) = run(&mut ctl, 0.01, 2000);
        assert_eq!(finish, Some(Finish::Arrived));
        assert!((ctl.tip() - c).norm() < 1e-6, "{:?}", ctl.tip());
        ticks.push(k);
    }
    assert!(ticks[1] <= ticks[0], "ticks {ticks:?}");
}

#[test]
fn repeated_points_are_one_corner_but_distinct_ones_stay() {
    // Points a micrometre apart are two corners: only those the tip cannot tell apart merge.
    let home = vec![0.1; N];
    let a = chain().tip(&home) + Vec2::new(0.01, 0.0);
    let b = a + Vec2::new(1e-6, 0.0);
    let mut ticks = Vec::new();
    for points in [vec![a], vec![a, a], vec![a, b]] {
        let mut ctl = holding(limits(), &home);
        ctl.command(Command::Path {
            points,
            speed: None,
        })
        .unwrap();
        let (finish, k) = run(&mut ctl, 0.01, 2000);
        assert_eq!(finish, Some(Finish::Arrived));
        ticks.push(k);
    }
    assert_eq!(ticks[0], ticks[1], "ticks {ticks:?}");
    assert!(ticks[2] > ticks[0], "ticks {ticks:?}");
}

/// A joint move is bounded by the joint speed limit alone: with a tip speed limit of 1 mm/s,
/// a 0.6 rad move of every joint still cruises at 2 rad/s and takes the joint profile's time,
/// its tip far faster than the tip limit.
#[test]
fn a_joint_move_runs_at_the_joint_speed_limit_whatever_the_tip_limit() {
    let slow_tip = Limits {
        max_tip_speed_m_s: 0.001,
        ..limits()
    };
    let home = vec![0.1; N];
    let mut c = holding(slow_tip, &home);
    let target = vec![-0.5; N];
    c.command(Command::GotoJoints {
        theta: target.clone(),
    })
    .unwrap();
    let dt = 0.01;
    let (mut peak, mut tip_speed) = (0.0f64, 0.0f64);
    let mut finish = None;
    let mut ticks = 0;
    let mut tip = c.tip();
    while finish.is_none() && ticks < 1000 {
        let t = c.tick(dt);
        ticks += 1;
        assert!(!t.slowed && !t.clamped && !t.saturated, "{t:?}");
        peak = peak.max(t.peak_joint_speed_rad_s);
        tip_speed = tip_speed.max((t.tip - tip).norm() / dt);
        tip = t.tip;
        finish = t.finished;
    }
    assert_eq!(finish, Some(Finish::Arrived));
    assert_eq!(c.theta(), &target[..]);
    assert!((peak - 2.0).abs() < 1e-9, "peak joint speed {peak} rad/s");
    // A trapezoid: 0.6 rad at 2 rad/s, 0.25 s to reach it: 0.3 + 0.25 s, plus a tick or two.
    let time = ticks as f64 * dt;
    assert!((0.55..=0.58).contains(&time), "{time} s");
    assert!(tip_speed > 0.1, "tip at most {tip_speed} m/s");

    // `home` back, and a jog, likewise.
    c.command(Command::Home).unwrap();
    let (finish, ticks) = run(&mut c, dt, 1000);
    assert_eq!(finish, Some(Finish::Arrived));
    assert!((ticks as f64 * dt) <= 0.58, "{ticks} ticks");
    c.command(Command::Jog {
        joint: 0,
        rad_s: 2.0,
    })
    .unwrap();
    let peak = (0..30)
        .map(|_| c.tick(dt).peak_joint_speed_rad_s)
        .fold(0.0, f64::max);
    assert!((peak - 2.0).abs() < 1e-9, "jog peak {peak} rad/s");
}

/// The first eight joints turned by 0.9 rad each: the curl's end crosses its start (three
/// pairs of links cross).
fn crossed() -> Vec<f64> {
    (0..N).map(|i| if i < 8 { 0.9 } else { 0.0 }).collect()
}

#[test]
fn a_crossed_start_pose_is_told_and_home_untangles_it() {
    let start = crossed();
    let ch = chain();
    let first = Chain::crossings(&ch.points(&start));
    assert_eq!(first, 3);
    let mut c = holding(limits(), &start);
    let contact = c.self_contact().expect("a tangled start");
    assert!(contact.crossing, "{contact:?}");
    assert!(Chain::links_cross(&ch.points(&start), contact.a, contact.b));
    let told = contact.to_string();
    let pair = format!(
        "links {} and {} of the arm's pose cross",
        contact.a + 1,
        contact.b + 1
    );
    assert!(told.starts_with(&pair), "{told}");
    assert!(told.contains("`home`"), "{told}");

    c.command(Command::Home).unwrap();
    let mut finish = None;
    let mut crossings = first;
    for _ in 0..1000 {
        let t = c.tick(0.01);
        // Never worse: no more crossings than the tick before.
        let now = Chain::crossings(&ch.points(c.theta()));
        assert!(now <= crossings, "{crossings} -> {now} crossings: {t:?}");
        crossings = now;
        if t.finished.is_some() {
            finish = t.finished;
            break;
        }
    }
    assert_eq!(finish, Some(Finish::Arrived));
    assert_eq!(c.theta(), &[0.1; N][..]);
    assert_eq!(c.self_contact(), None);
}

#[test]
fn a_tangled_arm_is_not_tangled_further() {
    // From the crossed pose, jog each joint either way: whatever the jog, no tick crosses more
    // links than the pose before it.
    let start = crossed();
    let ch = chain();
    for joint in 0..N {
        for rad_s in [-1.0, 1.0] {
            let mut c = holding(limits(), &start);
            let mut crossings = Chain::crossings(&ch.points(&start));
            c.command(Command::Jog { joint, rad_s }).unwrap();
            for _ in 0..50 {
                let t = c.tick(0.01);
                let now = Chain::crossings(&ch.points(c.theta()));
                assert!(
                    now <= crossings,
                    "jog {joint} at {rad_s}: {crossings} -> {now}"
                );
                crossings = now;
                assert!(!t.self_collision || t.saturated, "{t:?}");
            }
        }
    }
}

#[test]
fn a_clear_start_pose_has_no_contact() {
    assert_eq!(holding(limits(), &[0.1; N]).self_contact(), None);
}
