//! The control core's promises, checked tick by tick on the daemon's arm (12 links of 0.08 m,
//! limits +-2 rad, base at the origin heading up, home 0.1 rad each) and on smaller random
//! chains: joint-speed bound, limits, tip speed and acceleration, straight gotos on time, path
//! corners at rest, the deadman, jog at a limit, live strategy switches, freeze and reseed,
//! unreachable targets, refusals, and no goal pose whose links cross or touch.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::FRAC_PI_2;

use proptest::prelude::*;
use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::control::{Activity, Command, Controller, Finish, Limits, Refused, Tick};
use snakectl::resolve::Strategy as Strat;

const N: usize = 12;

fn daemon_chain() -> Chain {
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    Chain::new(vec![0.08; N], Vec2::zeros(), FRAC_PI_2, vec![lim; N]).unwrap()
}

fn daemon_limits() -> Limits {
    Limits {
        max_tip_speed_m_s: 0.1,
        max_tip_accel_m_s2: 0.5,
        max_joint_speed_rad_s: 2.0,
        deadman_s: 0.5,
    }
}

fn daemon(strategy: Strat, limits: Limits) -> Controller {
    let home = vec![0.1; N];
    Controller::new(daemon_chain(), limits, strategy, home.clone(), &home).unwrap()
}

/// A random chain of 2-8 links, limits between 1 and 2.5 rad, a gentle curl as home.
fn small_chain(n: usize, seed: u64) -> (Chain, Vec<f64>) {
    let mut rng = Lcg(seed);
    let links: Vec<f64> = (0..n).map(|_| 0.05 + 0.15 * rng.unit()).collect();
    let limits = (0..n)
        .map(|_| {
            let hi = 1.0 + 1.5 * rng.unit();
            Some(JointLimit { lo: -hi, hi })
        })
        .collect();
    let base = Vec2::new(rng.unit() - 0.5, rng.unit() - 0.5);
    let chain = Chain::new(links, base, 6.0 * rng.unit(), limits).unwrap();
    let home = (0..n).map(|_| 0.2 + 0.2 * rng.unit()).collect();
    (chain, home)
}

/// A small deterministic generator for per-tick `dt` and the like.
struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A tick length in [0.5 ms, 20 ms].
    fn dt(&mut self) -> f64 {
        0.0005 + 0.0195 * self.unit()
    }
}

/// Runs ticks and checks, on every one, what holds always: each goal within
/// `max_joint_speed * dt` of the last, inside the limits, finite, its links clear of each
/// other; the tip no faster than its limit unless the final clamp acted (while `tip_limited`:
/// a joint move or jog is bound by the joint speed limit alone); `tip` the tip of the goals;
/// `self_collision` only on a saturated tick.
struct Run {
    c: Controller,
    /// The active command moves the tip (not the joints), so the tip speed limit holds.
    tip_limited: bool,
    prev_theta: Vec<f64>,
    prev_tip: Vec2,
    time: f64,
    ticks: Vec<Record>,
}

#[derive(Debug, Clone, Copy)]
struct Record {
    tick: Tick,
    dt: f64,
    /// Time at the end of the tick, s.
    time: f64,
    /// Tip velocity over the tick, m/s.
    v: Vec2,
}

impl Run {
    /// How many ticks so far ended a command.
    fn finishes(&self) -> usize {
        self.ticks
            .iter()
            .filter(|r| r.tick.finished.is_some())
            .count()
    }

    fn new(c: Controller) -> Self {
        let prev_theta = c.theta().to_vec();
        let prev_tip = c.tip();
        Self {
            c,
            tip_limited: true,
            prev_theta,
            prev_tip,
            time: 0.0,
            ticks: Vec::new(),
        }
    }

    fn tick(&mut self, dt: f64) -> Record {
        let tick = self.c.tick(dt);
        let lim = *self.c.limits();
        let bound = lim.max_joint_speed_rad_s * dt + 1e-12;
        let theta = self.c.theta();
        for (i, (&t, &p)) in theta.iter().zip(&self.prev_theta).enumerate() {
            assert!(t.is_finite(), "joint {i} not finite: {t}");
            assert!(
                (t - p).abs() <= bound,
                "joint {i} stepped {} > {bound} (dt {dt}) at t = {}: {tick:?}",
                (t - p).abs(),
                self.time
            );
        }
        self.c.chain().check_limits(theta).unwrap();
        let points = self.c.chain().points(theta);
        assert_eq!(
            Chain::self_intersects(&points),
            None,
            "the goal pose self-intersects at t = {}: {theta:?}",
            self.time
        );
        assert!(!tick.self_collision || tick.saturated, "{tick:?}");
        let tip = self.c.chain().tip(theta);
        assert!((tip - tick.tip).norm() < 1e-12);
        let v = (tip - self.prev_tip) / dt;
        if !tick.clamped && self.tip_limited {
            assert!(
                v.norm() <= lim.max_tip_speed_m_s * (1.0 + 1e-9) + 1e-7,
                "tip speed {} above {} at t = {}: {tick:?}",
                v.norm(),
                lim.max_tip_speed_m_s,
                self.time
            );
        }
        if tick.finished.is_some() {
            assert_eq!(self.c.activity(), Activity::Holding);
        }
        let peak = theta
            .iter()
            .zip(&self.prev_theta)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!((tick.peak_joint_speed_rad_s - peak / dt).abs() <= 1e-9 * (1.0 + peak / dt));
        self.prev_theta.copy_from_slice(theta);
        self.prev_tip = tip;
        self.time += dt;
        let r = Record {
            tick,
            dt,
            time: self.time,
            v,
        };
        self.ticks.push(r);
        r
    }

    /// Ticks of `dt` until the active command finishes (or `max_s` passes); the finish.
    fn until_finished(&mut self, dt: f64, max_s: f64) -> Option<Finish> {
        let end = self.time + max_s;
        while self.time < end {
            if let Some(f) = self.tick(dt).tick.finished {
                return Some(f);
            }
        }
        None
    }
}

/// Distance from `p` to the segment `a-b`.
fn segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    if l2 == 0.0 {
        return (p - a).norm();
    }
    let s = ((p - a).dot(&ab) / l2).clamp(0.0, 1.0);
    (p - (a + ab * s)).norm()
}

/// Time a trapezoid (or triangle) profile takes over `d` at `speed` and `accel`.
fn trapezoid_time(d: f64, speed: f64, accel: f64) -> f64 {
    if d >= speed * speed / accel {
        d / speed + speed / accel
    } else {
        2.0 * (d / accel).sqrt()
    }
}

fn strategy(overall: bool) -> Strat {
    if overall {
        Strat::Overall
    } else {
        Strat::Sequential
    }
}

/// The tip of `home` perturbed by up to `spread` rad per joint, kept inside the limits.
fn nearby_tip(chain: &Chain, home: &[f64], spread: f64, rng: &mut Lcg) -> Vec2 {
    let pose: Vec<f64> = home
        .iter()
        .zip(chain.limits())
        .map(|(h, l)| {
            let t = h + spread * (2.0 * rng.unit() - 1.0);
            l.map_or(t, |l| l.clamp(t))
        })
        .collect();
    chain.tip(&pose)
}

#[derive(Debug, Clone)]
enum Op {
    Goto { x: f64, y: f64, speed: Option<f64> },
    Path { pts: Vec<(f64, f64)> },
    Velocity { vx: f64, vy: f64 },
    Jog { joint: usize, factor: f64 },
    Joints { frac: Vec<f64> },
    Home,
    Stop,
    Switch,
    Freeze,
}

fn op() -> impl Strategy<Value = Op> {
    let p = -1.3f64..1.3;
    prop_oneof![
        3 => (p.clone(), p.clone(), proptest::option::of(0.01f64..2.0))
            .prop_map(|(x, y, speed)| Op::Goto { x, y, speed }),
        1 => proptest::collection::vec((p.clone(), p.clone()), 1..4)
            .prop_map(|pts| Op::Path { pts }),
        2 => (-0.6f64..0.6, -0.6f64..0.6).prop_map(|(vx, vy)| Op::Velocity { vx, vy }),
        2 => (0usize..N, -10.0f64..10.0).prop_map(|(joint, factor)| Op::Jog { joint, factor }),
        1 => proptest::collection::vec(-1.0f64..1.0, N).prop_map(|frac| Op::Joints { frac }),
        1 => Just(Op::Home),
        1 => Just(Op::Stop),
        1 => Just(Op::Switch),
        1 => Just(Op::Freeze),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Under any sequence of commands (gotos anywhere, unreachable ones included, velocities,
    /// jogs asking up to 10x the joint speed limit, paths, stops, joint moves, strategy
    /// switches and freezes mid-motion) and random tick lengths, every goal stays within the
    /// joint-speed bound, inside the limits and finite; the tip stays under its speed limit
    /// while a tip command moves it;
    /// and where nothing was saturated, slowed or clamped, the tip velocity changes by no more
    /// than the acceleration limit allows.
    #[test]
    fn bounds_hold_under_random_commands(
        ops in proptest::collection::vec((op(), 1usize..300), 1..12),
        small in proptest::option::of((2usize..8, 0u64..1000)),
        overall in proptest::bool::ANY,
        speed in 0.05f64..0.5, accel in 0.2f64..5.0, joint_speed in 0.3f64..3.0,
        deadman in 0.05f64..0.5, seed in 0u64..1_000_000,
    ) {
        let limits = Limits {
            max_tip_speed_m_s: speed,
            max_tip_accel_m_s2: accel,
            max_joint_speed_rad_s: joint_speed,
            deadman_s: deadman,
        };
        let (chain, home) = match small {
            Some((n, s)) => small_chain(n, s),
            None => (daemon_chain(), vec![0.1; N]),
        };
        let n = chain.len();
        let scale = chain.reach();
        let base = chain.base();
        let c = Controller::new(chain, limits, strategy(overall), home.clone(), &home).unwrap();
        let mut run = Run::new(c);
        let mut rng = Lcg(seed);
        // Whether the active command (or the stop that follows it) moves the tip, and whether
        // the last tick did.
        let mut tip_space = true;
        let mut last_tip_space = true;
        for (op, ticks) in ops {
            let mut fresh = false;
            match op {
                Op::Goto { x, y, speed } => {
                    let target = base + Vec2::new(x, y) * scale;
                    run.c.command(Command::Goto { target, speed }).unwrap();
                    tip_space = true;
                }
                Op::Path { pts } => {
                    let points = pts.iter().map(|&(x, y)| base + Vec2::new(x, y) * scale).collect();
                    run.c.command(Command::Path { points, speed: None }).unwrap();
                    tip_space = true;
                }
                Op::Velocity { vx, vy } => {
                    run.c.command(Command::Velocity { v: Vec2::new(vx, vy) }).unwrap();
                    tip_space = true;
                }
                Op::Jog { joint, factor } => {
                    let rad_s = factor * joint_speed;
                    run.c.command(Command::Jog { joint: joint % n, rad_s }).unwrap();
                    tip_space = false;
                }
                Op::Joints { frac } => {
                    let theta: Vec<f64> = run.c.chain().limits().iter().zip(&frac)
                        .map(|(l, f)| l.map_or(*f, |l| 0.5 * (l.lo + l.hi) + f * 0.5 * (l.hi - l.lo)))
                        .collect();
                    // A target that folds the arm onto itself is refused, naming a touching
                    // pair; the active command goes on.
                    let clash = Chain::self_intersects(&run.c.chain().points(&theta));
                    match run.c.command(Command::GotoJoints { theta }) {
                        Ok(()) => {
                            prop_assert_eq!(clash, None);
                            tip_space = false;
                        }
                        Err(Refused::SelfCollision { a, b }) => {
                            prop_assert_eq!(clash, Some((a, b)));
                        }
                        Err(e) => prop_assert!(false, "refused: {}", e),
                    }
                }
                Op::Home => {
                    run.c.command(Command::Home).unwrap();
                    tip_space = false;
                }
                Op::Stop => run.c.command(Command::Stop).unwrap(),
                Op::Switch => {
                    let s = match run.c.strategy() {
                        Strat::Overall => Strat::Sequential,
                        Strat::Sequential => Strat::Overall,
                    };
                    run.c.set_strategy(s);
                }
                Op::Freeze => {
                    let before = run.c.theta().to_vec();
                    run.c.freeze();
                    prop_assert_eq!(run.c.activity(), Activity::Holding);
                    let r = run.tick(rng.dt());
                    prop_assert_eq!(run.c.theta(), &before[..]);
                    prop_assert!(r.tick.finished.is_none());
                    fresh = true;
                }
            }
            run.tip_limited = tip_space;
            for _ in 0..ticks {
                let r = run.tick(rng.dt());
                let k = run.ticks.len();
                // A tip command preempting a joint move starts from the tip speed limit at
                // most, not from the joint move's tip velocity.
                if tip_space && last_tip_space && !fresh && k >= 2 {
                    let p = run.ticks[k - 2];
                    let quiet = |t: &Tick| !(t.saturated || t.slowed || t.clamped);
                    if quiet(&r.tick) && quiet(&p.tick) {
                        let dv = (r.v - p.v).norm();
                        prop_assert!(
                            dv <= accel * r.dt * (1.0 + 1e-9) + 1e-7,
                            "tip velocity changed by {} > {} at t = {}",
                            dv, accel * r.dt, r.time
                        );
                    }
                }
                fresh = false;
                last_tip_space = tip_space;
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// A reachable goto from rest arrives with the commanded tip on the target (1e-9 m), in the
    /// time the trapezoid profile predicts (when nothing slowed it), along the straight line.
    #[test]
    fn reachable_goto_arrives_on_time_along_the_line(
        small in proptest::option::of((2usize..8, 0u64..1000)),
        overall in proptest::bool::ANY,
        speed in 0.03f64..0.3, accel in 0.2f64..3.0, cruise in proptest::option::of(0.01f64..1.0),
        dt in 0.0005f64..0.02, seed in 0u64..1_000_000,
    ) {
        let limits = Limits { max_tip_speed_m_s: speed, max_tip_accel_m_s2: accel,
            max_joint_speed_rad_s: 3.0, deadman_s: 0.5 };
        let (chain, home) = match small {
            Some((n, s)) => small_chain(n, s),
            None => (daemon_chain(), vec![0.1; N]),
        };
        let mut rng = Lcg(seed);
        // The sequential strategy ignores the limits as it moves (each link follows its leader),
        // so a long move can fold a joint onto its limit, where the move saturates: it gets
        // shorter moves.
        let spread = if overall { 0.4 } else { 0.1 };
        let target = nearby_tip(&chain, &home, spread, &mut rng);
        let c = Controller::new(chain, limits, strategy(overall), home.clone(), &home).unwrap();
        let start = c.tip();
        let mut run = Run::new(c);
        run.c.command(Command::Goto { target, speed: cruise }).unwrap();
        prop_assert_eq!(run.c.target(), Some(target));
        let cruise = cruise.map_or(speed, |c| c.min(speed));
        let expected = trapezoid_time((target - start).norm(), cruise, accel);
        let finish = run.until_finished(dt, 3.0 * expected + 1.0);
        if !overall && finish == Some(Finish::Saturated) {
            // The sequential strategy does not steer around the limits: a move can fold a joint
            // onto its limit on the way (the spread above makes it rare, not impossible). Then,
            // and only then, it may stop short: on the line, with a joint within one tick's
            // joint motion of its limit.
            let theta = run.c.theta().to_vec();
            let near = limits.max_joint_speed_rad_s * dt + 1e-9;
            let at_limit = theta.iter().zip(run.c.chain().limits()).any(|(t, l)| {
                l.is_some_and(|l| (t - l.lo).abs() < near || (t - l.hi).abs() < near)
            });
            prop_assert!(at_limit, "stopped short with no joint at a limit: {:?}", theta);
            let off = segment_distance(run.c.tip(), start, target);
            prop_assert!(off < 1e-6, "stopped {off} m off the line");
            return Ok(());
        }
        prop_assert_eq!(finish, Some(Finish::Arrived));
        prop_assert!((run.c.tip() - target).norm() <= 1e-9, "off by {}", (run.c.tip() - target).norm());
        prop_assert_eq!(run.c.target(), None);
        let clamped = run.ticks.iter().any(|r| r.tick.clamped);
        let slowed = run.ticks.iter().any(|r| r.tick.slowed || r.tick.saturated);
        if !clamped {
            let off = run.ticks.iter().map(|r| segment_distance(r.tick.tip, start, target))
                .fold(0.0, f64::max);
            prop_assert!(off < 1e-6, "{off} m off the line");
        }
        if !(clamped || slowed) {
            prop_assert!(run.time >= expected - 2.0 * dt && run.time <= expected + 3.0 * dt,
                "took {} s, the trapezoid {} s (dt {})", run.time, expected, dt);
        }
        // Holding afterwards: nothing moves.
        let held = run.c.theta().to_vec();
        run.tick(dt);
        prop_assert_eq!(run.c.theta(), &held[..]);
    }

    /// A path comes to rest on each corner in turn (within 1e-9 m, for at least two ticks),
    /// straight between them, and ends `Arrived` on its last point.
    #[test]
    fn path_takes_its_corners_at_rest(
        small in proptest::option::of((2usize..8, 0u64..1000)),
        overall in proptest::bool::ANY, corners in 1usize..5,
        dt in 0.0005f64..0.02, seed in 0u64..1_000_000,
    ) {
        let (chain, home) = match small {
            Some((n, s)) => small_chain(n, s),
            None => (daemon_chain(), vec![0.1; N]),
        };
        let mut rng = Lcg(seed);
        let spread = if overall { 0.3 } else { 0.05 };
        let points: Vec<Vec2> = (0..corners).map(|_| nearby_tip(&chain, &home, spread, &mut rng)).collect();
        let mut limits = daemon_limits();
        limits.max_joint_speed_rad_s = 3.0;
        let c = Controller::new(chain, limits, strategy(overall), home.clone(), &home).unwrap();
        let mut run = Run::new(c);
        let start = run.c.tip();
        run.c.command(Command::Path { points: points.clone(), speed: None }).unwrap();
        prop_assert_eq!(run.c.target(), points.last().copied());
        let finish = run.until_finished(dt, 60.0);
        prop_assert_eq!(finish, Some(Finish::Arrived));
        run.tick(dt);
        let tips: Vec<Vec2> = run.ticks.iter().map(|r| r.tick.tip).collect();
        let clamped = run.ticks.iter().any(|r| r.tick.clamped);
        let mut from = 0;
        let mut last = start;
        for (k, &corner) in points.iter().enumerate() {
            let at = (from..tips.len() - 1).find(|&i| {
                (tips[i] - corner).norm() <= 1e-9 && (tips[i + 1] - corner).norm() <= 1e-9
            });
            prop_assert!(at.is_some(), "corner {k} at {corner:?} never reached at rest");
            let at = at.unwrap();
            if !clamped {
                for &p in &tips[from..=at] {
                    prop_assert!(segment_distance(p, last, corner) < 1e-6, "off segment {k}");
                }
            }
            from = at + 1;
            last = corner;
        }
    }

    /// After the last `Velocity` command the tip keeps its velocity until the deadman, then is
    /// at rest no later than `deadman + |v| / a` plus one tick, and the command ends once with
    /// `Stopped { deadman: true }`.
    #[test]
    fn velocity_stops_within_the_deadman(
        // Anywhere from the base's side of the home tip to across it: never into the edge of
        // the workspace, which the home tip is 6 cm inside.
        turn in -1.5f64..1.5, speed in 0.01f64..0.1, deadman in 0.05f64..0.3,
        renewals in proptest::collection::vec(0.0f64..1.0, 1..4), seed in 0u64..1_000_000,
    ) {
        let mut limits = daemon_limits();
        limits.deadman_s = deadman;
        let mut run = Run::new(daemon(Strat::Overall, limits));
        let mut rng = Lcg(seed);
        let inward = -run.c.tip();
        let angle = inward.y.atan2(inward.x) + turn;
        let v = Vec2::new(angle.cos(), angle.sin()) * speed;
        let mut max_dt: f64 = 0.0;
        let mut last = 0.0;
        for (k, wait) in renewals.iter().enumerate() {
            run.c.command(Command::Velocity { v }).unwrap();
            last = run.time;
            // Renew before the deadman (except after the last one).
            let until = if k + 1 < renewals.len() { last + wait * deadman } else { last + deadman + 1.0 };
            while run.time < until {
                let dt = rng.dt();
                max_dt = max_dt.max(dt);
                run.tick(dt);
            }
        }
        let ticks = &run.ticks;
        prop_assert!(ticks.iter().all(|r| !(r.tick.saturated || r.tick.clamped)));
        let stops: Vec<_> = ticks.iter().filter_map(|r| r.tick.finished).collect();
        prop_assert_eq!(stops, vec![Finish::Stopped { deadman: true }]);
        // At rest from the end of the first tick whose tip did not move, for good.
        let still = ticks.iter().rposition(|r| r.v.norm() > 0.0).map_or(0, |i| i + 1);
        prop_assert!(still < ticks.len());
        let rest_at = ticks[still].time - ticks[still].dt;
        let bound = last + deadman + speed / limits.max_tip_accel_m_s2 + max_dt;
        prop_assert!(rest_at <= bound + 1e-9, "at rest at {rest_at} s, later than {bound} s");
        // And not before the deadman: the full velocity until then.
        for r in ticks.iter().filter(|r| r.time > last + speed / limits.max_tip_accel_m_s2 + max_dt
            && r.time <= last + deadman - max_dt) {
            prop_assert!((r.v - v).norm() < 1e-6, "velocity {:?} at {} s", r.v, r.time);
        }
    }

    /// A jog toward a limit, even asking 10x the joint speed limit, keeps the joint-speed bound,
    /// comes to rest exactly on the limit and never beyond it, moves no other joint, and
    /// lapses with `Stopped { deadman: true }` once no longer renewed.
    #[test]
    fn jog_stops_at_its_limit(
        joint in 0usize..N, up in proptest::bool::ANY, factor in 1.0f64..10.0, seed in 0u64..1_000_000,
    ) {
        let limits = daemon_limits();
        let mut run = Run::new(daemon(Strat::Overall, limits));
        run.tip_limited = false;
        let start = run.c.theta().to_vec();
        let mut rng = Lcg(seed);
        let end: f64 = if up { 2.0 } else { -2.0 };
        let rad_s = factor * limits.max_joint_speed_rad_s * end.signum();
        let mut resting = 0;
        while resting < 20 && run.time < 30.0 {
            run.c.command(Command::Jog { joint, rad_s }).unwrap();
            let until = run.time + 0.2;
            while run.time < until {
                let r = run.tick(rng.dt());
                prop_assert!(r.tick.finished.is_none());
                let q = run.c.theta()[joint];
                prop_assert!(q.abs() <= 2.0);
                if q == end { resting += 1 }
            }
        }
        prop_assert!(resting >= 20, "joint {} at {} after {} s", joint, run.c.theta()[joint], run.time);
        prop_assert_eq!(run.c.activity(), Activity::Moving);
        let finish = run.until_finished(0.01, 1.0);
        prop_assert_eq!(finish, Some(Finish::Stopped { deadman: true }));
        prop_assert_eq!(run.c.theta()[joint], end);
        for (i, (&t, &s)) in run.c.theta().iter().zip(&start).enumerate() {
            if i != joint {
                prop_assert_eq!(t, s, "joint {} moved", i);
            }
        }
    }

    /// Switching strategy mid-motion, as often as every tick: no step beyond the joint-speed
    /// bound, the tip stays on its line, and the goto still arrives.
    #[test]
    fn strategy_switch_mid_motion_keeps_the_line(
        every in 1usize..30, first in proptest::bool::ANY, dt in 0.002f64..0.02,
        seed in 0u64..1_000_000,
    ) {
        let mut rng = Lcg(seed);
        let home = vec![0.1; N];
        let target = nearby_tip(&daemon_chain(), &home, 0.1, &mut rng);
        let mut run = Run::new(daemon(strategy(first), daemon_limits()));
        let start = run.c.tip();
        run.c.command(Command::Goto { target, speed: None }).unwrap();
        let mut finish = None;
        let mut k = 0;
        while finish.is_none() && run.time < 60.0 {
            k += 1;
            if k % every == 0 {
                let s = if run.c.strategy() == Strat::Overall { Strat::Sequential } else { Strat::Overall };
                run.c.set_strategy(s);
                prop_assert_eq!(run.c.strategy(), s);
            }
            finish = run.tick(dt).tick.finished;
        }
        prop_assert_eq!(finish, Some(Finish::Arrived));
        if !run.ticks.iter().any(|r| r.tick.clamped) {
            for r in &run.ticks {
                prop_assert!(segment_distance(r.tick.tip, start, target) < 1e-6);
            }
        }
    }

    /// A joint move goes in proportion on every joint (a straight line in joint space, all
    /// arriving together) and ends exactly on its pose, `Arrived`, unless its target folds the
    /// arm onto itself (refused) or a pose on its line would (it stops short, `Saturated`).
    #[test]
    fn joint_moves_arrive_on_the_pose(
        frac in proptest::collection::vec(-1.0f64..1.0, N), home_after in proptest::bool::ANY,
        dt in 0.0005f64..0.02,
    ) {
        let mut limits = daemon_limits();
        limits.max_tip_speed_m_s = 10.0; // joint speeds alone limit the move
        let mut run = Run::new(daemon(Strat::Sequential, limits));
        let goal: Vec<f64> = frac.iter().map(|f| 1.9 * f).collect();
        let start = run.c.theta().to_vec();
        if let Err(e) = run.c.command(Command::GotoJoints { theta: goal.clone() }) {
            let clash = Chain::self_intersects(&run.c.chain().points(&goal));
            prop_assert!(matches!(e, Refused::SelfCollision { a, b } if clash == Some((a, b))), "{}", e);
            return Ok(());
        }
        let finish = run.until_finished(dt, 30.0);
        let blocked = run.ticks.iter().any(|r| r.tick.self_collision);
        if blocked {
            prop_assert_eq!(finish, Some(Finish::Saturated));
        } else {
            prop_assert_eq!(finish, Some(Finish::Arrived));
            prop_assert_eq!(run.c.theta(), &goal[..]);
        }
        // In proportion: every joint the same fraction of its way at every tick.
        let far = goal.iter().zip(&start).map(|(g, s)| (g - s).abs()).fold(0.0, f64::max);
        let mut theta = start.clone();
        let mut replay = Run::new(daemon(Strat::Sequential, limits));
        replay.c.command(Command::GotoJoints { theta: goal.clone() }).unwrap();
        for _ in 0..run.ticks.len() {
            replay.tick(dt);
            theta.copy_from_slice(replay.c.theta());
            let (i, _) = goal.iter().zip(&start).enumerate()
                .map(|(i, (g, s))| (i, (g - s).abs())).fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
            let s = (theta[i] - start[i]) / (goal[i] - start[i]);
            for j in 0..N {
                let expect = start[j] + s * (goal[j] - start[j]);
                prop_assert!((theta[j] - expect).abs() <= 1e-9 * (1.0 + far), "joint {j} off the line");
            }
        }
        if home_after && !blocked {
            run.c.command(Command::Home).unwrap();
            prop_assert_eq!(run.until_finished(dt, 30.0), Some(Finish::Arrived));
            prop_assert_eq!(run.c.theta(), run.c.home());
        }
    }
}

#[test]
fn freeze_keeps_the_goals_and_drops_the_command() {
    for s in [Strat::Overall, Strat::Sequential] {
        let mut run = Run::new(daemon(s, daemon_limits()));
        let target = run.c.tip() + Vec2::new(0.05, -0.05);
        run.c
            .command(Command::Goto {
                target,
                speed: None,
            })
            .unwrap();
        for _ in 0..30 {
            run.tick(0.01);
        }
        assert!(
            run.ticks.last().unwrap().v.norm() > 0.01,
            "moving before the freeze"
        );
        let goals = run.c.theta().to_vec();
        run.c.freeze();
        assert_eq!(run.c.activity(), Activity::Holding);
        assert_eq!(run.c.target(), None);
        for _ in 0..10 {
            let r = run.tick(0.01);
            assert_eq!(run.c.theta(), &goals[..]);
            assert_eq!(r.tick.finished, None);
            assert_eq!(r.tick.peak_joint_speed_rad_s, 0.0);
        }
        // A new command starts from rest where the arm is.
        run.c
            .command(Command::Goto {
                target,
                speed: None,
            })
            .unwrap();
        let r = run.tick(0.01);
        assert!(r.v.norm() <= daemon_limits().max_tip_accel_m_s2 * 0.01 + 1e-9);
    }
}

#[test]
fn reseed_takes_the_measured_pose_and_holds() {
    let mut run = Run::new(daemon(Strat::Overall, daemon_limits()));
    run.c
        .command(Command::Velocity {
            v: Vec2::new(0.05, 0.0),
        })
        .unwrap();
    for _ in 0..20 {
        run.tick(0.01);
    }
    let measured: Vec<f64> = (0..N).map(|i| 0.2 - 0.03 * i as f64).collect();
    run.c.reseed(&measured).unwrap();
    assert_eq!(run.c.theta(), &measured[..]);
    assert_eq!(run.c.activity(), Activity::Holding);
    assert!((run.c.tip() - run.c.chain().tip(&measured)).norm() == 0.0);
    run.prev_theta.copy_from_slice(&measured);
    run.prev_tip = run.c.tip();
    for _ in 0..5 {
        run.tick(0.01);
        assert_eq!(run.c.theta(), &measured[..]);
    }
    // A pose outside the limits is refused with its numbers, and nothing changes.
    let mut outside = measured.clone();
    outside[7] = -2.5;
    assert_eq!(
        run.c.reseed(&outside),
        Err(Refused::OutsideLimits {
            joint: 7,
            value: -2.5,
            lo: -2.0,
            hi: 2.0
        })
    );
    assert_eq!(run.c.theta(), &measured[..]);
    assert_eq!(
        run.c.reseed(&measured[..3]),
        Err(Refused::WrongLength {
            got: 3,
            expected: N
        })
    );
}

#[test]
fn unreachable_goto_ends_saturated_once_short_of_the_target() {
    for s in [Strat::Overall, Strat::Sequential] {
        for target in [
            Vec2::new(0.0, 1.5),
            Vec2::new(-1.2, 0.4),
            Vec2::new(0.7, -0.9),
        ] {
            let mut run = Run::new(daemon(s, daemon_limits()));
            let start = run.c.tip();
            run.c
                .command(Command::Goto {
                    target,
                    speed: None,
                })
                .unwrap();
            let finish = run.until_finished(0.01, 40.0);
            assert_eq!(finish, Some(Finish::Saturated), "{s:?} toward {target:?}");
            assert_eq!(run.finishes(), 1, "one finish, not more");
            assert!(run.ticks.iter().any(|r| r.tick.saturated));
            let gap = (run.c.tip() - target).norm();
            assert!(
                gap > 0.01,
                "{s:?}: the tip reached an unreachable target? gap {gap}"
            );
            assert!(
                gap < (start - target).norm(),
                "{s:?}: no progress toward {target:?}"
            );
            assert_eq!(run.c.activity(), Activity::Holding);
            assert_eq!(run.c.target(), None);
            let held = run.c.theta().to_vec();
            for _ in 0..10 {
                assert_eq!(run.tick(0.01).tick.finished, None);
            }
            assert_eq!(run.c.theta(), &held[..]);
        }
    }
}

#[test]
fn refusals_carry_the_numbers_and_change_nothing() {
    let mut c = daemon(Strat::Overall, daemon_limits());
    let target = c.tip() + Vec2::new(0.01, 0.0);
    c.command(Command::Goto {
        target,
        speed: None,
    })
    .unwrap();
    let mut pose = vec![0.0; N];
    pose[3] = 2.5;
    let e = c.command(Command::GotoJoints { theta: pose }).unwrap_err();
    assert_eq!(
        e,
        Refused::OutsideLimits {
            joint: 3,
            value: 2.5,
            lo: -2.0,
            hi: 2.0
        }
    );
    assert_eq!(
        e.to_string(),
        "joint 4: 2.5 rad is outside its limits [-2, 2]"
    );
    let e = c
        .command(Command::Jog {
            joint: 12,
            rad_s: 0.1,
        })
        .unwrap_err();
    assert_eq!(
        e,
        Refused::NoSuchJoint {
            joint: 12,
            joints: 12
        }
    );
    assert!(e.to_string().contains("joint 13"), "{e}");
    let e = c
        .command(Command::GotoJoints {
            theta: vec![0.0; 3],
        })
        .unwrap_err();
    assert_eq!(
        e,
        Refused::WrongLength {
            got: 3,
            expected: 12
        }
    );
    let nan = Vec2::new(f64::NAN, 0.0);
    assert_eq!(
        c.command(Command::Goto {
            target: nan,
            speed: None
        }),
        Err(Refused::NotFinite { what: "target" })
    );
    assert_eq!(
        c.command(Command::Velocity {
            v: Vec2::new(0.0, f64::INFINITY)
        }),
        Err(Refused::NotFinite { what: "velocity" })
    );
    assert_eq!(
        c.command(Command::Jog {
            joint: 0,
            rad_s: f64::NAN
        }),
        Err(Refused::NotFinite { what: "jog rate" })
    );
    for bad in [0.0, -0.1, f64::NAN, f64::INFINITY] {
        let e = c
            .command(Command::Goto {
                target,
                speed: Some(bad),
            })
            .unwrap_err();
        assert!(matches!(e, Refused::BadSpeed { value } if value.to_bits() == bad.to_bits()));
    }
    let huge = Vec2::new(1e300, 0.0);
    assert_eq!(
        c.command(Command::Path {
            points: vec![target, huge],
            speed: None
        }),
        Err(Refused::TooLarge {
            what: "path point",
            value: 1e300,
            max: 1e6
        })
    );
    assert_eq!(
        c.command(Command::Path {
            points: vec![],
            speed: None
        }),
        Err(Refused::EmptyPath)
    );
    let mut pose = vec![0.0; N];
    pose[5] = f64::NAN;
    assert_eq!(
        c.command(Command::GotoJoints { theta: pose }),
        Err(Refused::NotFinite {
            what: "joint angle"
        })
    );
    // The goto is still the active command.
    assert_eq!(c.target(), Some(target));
    assert_eq!(c.activity(), Activity::Moving);

    let mut limits = daemon_limits();
    limits.max_tip_accel_m_s2 = 0.0;
    let home = vec![0.1; N];
    let e =
        Controller::new(daemon_chain(), limits, Strat::Overall, home.clone(), &home).unwrap_err();
    assert_eq!(
        e,
        Refused::BadLimit {
            what: "max_tip_accel_m_s2",
            value: 0.0
        }
    );
    let mut bad_home = home.clone();
    bad_home[0] = 3.0;
    let e = Controller::new(
        daemon_chain(),
        daemon_limits(),
        Strat::Overall,
        bad_home,
        &home,
    )
    .unwrap_err();
    assert_eq!(
        e,
        Refused::OutsideLimits {
            joint: 0,
            value: 3.0,
            lo: -2.0,
            hi: 2.0
        }
    );
}

#[test]
fn a_speed_above_the_limit_is_clamped() {
    let mut run = Run::new(daemon(Strat::Overall, daemon_limits()));
    let target = run.c.tip() + Vec2::new(0.0, -0.08);
    run.c
        .command(Command::Goto {
            target,
            speed: Some(5.0),
        })
        .unwrap();
    assert_eq!(run.until_finished(0.01, 10.0), Some(Finish::Arrived));
    let top = run.ticks.iter().map(|r| r.v.norm()).fold(0.0, f64::max);
    assert!((top - 0.1).abs() < 1e-9, "cruise at {top} m/s");
}

#[test]
fn a_bad_dt_advances_nothing() {
    let mut c = daemon(Strat::Overall, daemon_limits());
    c.command(Command::Velocity {
        v: Vec2::new(0.05, 0.0),
    })
    .unwrap();
    let goals = c.theta().to_vec();
    for dt in [0.0, -0.01, f64::NAN, f64::INFINITY] {
        let t = c.tick(dt);
        assert_eq!(c.theta(), &goals[..]);
        assert_eq!(t.finished, None);
    }
    c.tick(0.01);
    assert_ne!(c.theta(), &goals[..]);
}

#[test]
fn stop_decelerates_at_the_limit_and_holds() {
    let mut run = Run::new(daemon(Strat::Overall, daemon_limits()));
    let target = run.c.tip() + Vec2::new(-0.3, -0.1);
    run.c
        .command(Command::Goto {
            target,
            speed: None,
        })
        .unwrap();
    for _ in 0..100 {
        run.tick(0.01);
    }
    let v0 = run.ticks.last().unwrap().v.norm();
    assert!((v0 - 0.1).abs() < 1e-9);
    run.c.command(Command::Stop).unwrap();
    assert_eq!(run.c.activity(), Activity::Stopping);
    let t0 = run.time;
    assert_eq!(
        run.until_finished(0.01, 5.0),
        Some(Finish::Stopped { deadman: false })
    );
    // 0.1 m/s at 0.5 m/s²: 0.2 s, plus the tick that finds it at rest.
    assert!(
        run.time - t0 <= 0.2 + 0.01 + 1e-9,
        "took {} s",
        run.time - t0
    );
    assert_eq!(run.c.activity(), Activity::Holding);
}

/// The daemon's arm driven along a path that loops down beside the base and then straight
/// across it: following it exactly would carry the tip through the arm's first links. Both
/// strategies stop short where two links would touch, flag `self_collision`, never send a pose
/// that self-intersects, and end the path `Saturated` once.
#[test]
fn a_path_folding_the_arm_onto_itself_stops_short() {
    let across = Vec2::new(0.1, 0.04);
    for s in [Strat::Overall, Strat::Sequential] {
        let mut run = Run::new(daemon(s, daemon_limits()));
        let points = vec![Vec2::new(-0.2, 0.2), Vec2::new(-0.1, 0.04), across];
        run.c
            .command(Command::Path {
                points,
                speed: None,
            })
            .unwrap();
        let finish = run.until_finished(0.01, 60.0);
        assert_eq!(finish, Some(Finish::Saturated), "{s:?}");
        assert_eq!(run.finishes(), 1, "one finish, not more");
        assert!(
            run.ticks.iter().any(|r| r.tick.self_collision),
            "{s:?}: never flagged"
        );
        let gap = (run.c.tip() - across).norm();
        assert!(
            gap > 0.05,
            "{s:?}: the tip got across, {gap} m from the corner"
        );
        // It stopped at the contact, not somewhere else: within 3 mm two links touch.
        let points = run.c.chain().points(run.c.theta());
        assert!(
            Chain::self_intersects_within(&points, 3e-3).is_some(),
            "{s:?}: stopped clear of any contact"
        );
        // Holding: nothing moves, nothing is flagged.
        let held = run.c.theta().to_vec();
        for _ in 0..10 {
            let r = run.tick(0.01);
            assert!(!r.tick.self_collision && r.tick.finished.is_none());
        }
        assert_eq!(run.c.theta(), &held[..]);
    }
}

/// A jog that curls the arm tighter stops where two links would touch, flagged every tick it
/// is held back there, and the arm never passes through itself.
#[test]
fn a_jog_stops_short_of_a_self_collision() {
    let mut curl = vec![0.45; N];
    curl[0] = 0.0;
    assert_eq!(Chain::self_intersects(&daemon_chain().points(&curl)), None);
    let c = Controller::new(
        daemon_chain(),
        daemon_limits(),
        Strat::Overall,
        vec![0.1; N],
        &curl,
    )
    .unwrap();
    let mut run = Run::new(c);
    run.tip_limited = false;
    for _ in 0..40 {
        run.c
            .command(Command::Jog {
                joint: 5,
                rad_s: 1.0,
            })
            .unwrap();
        for _ in 0..10 {
            run.tick(0.01);
        }
    }
    // Held back there for the last half second while the jog kept pushing.
    let k = run.ticks.len();
    assert!(run.ticks[k - 50..].iter().all(|r| r.tick.self_collision));
    let q = run.c.theta()[5];
    assert!(q < 2.0, "joint 6 went to its limit: {q}");
    let points = run.c.chain().points(run.c.theta());
    assert!(Chain::self_intersects_within(&points, 3e-3).is_some());
}

/// A joint move whose straight line in joint space passes through a self-intersecting pose
/// (found by sampling the line finely) though its target is clear stops short on the line,
/// just before the contact, and ends `Saturated`.
#[test]
fn a_joint_move_through_a_self_collision_stops_short() {
    let chain = daemon_chain();
    let home = vec![0.1; N];
    let mut rng = Lcg(7);
    let crosses = |goal: &[f64]| {
        (0..=2000).any(|k| {
            let s = k as f64 / 2000.0;
            let pose: Vec<f64> = home
                .iter()
                .zip(goal)
                .map(|(h, g)| h + s * (g - h))
                .collect();
            Chain::self_intersects(&chain.points(&pose)).is_some()
        })
    };
    let goal = (0..10_000)
        .map(|_| {
            (0..N)
                .map(|_| 1.9 * (2.0 * rng.unit() - 1.0))
                .collect::<Vec<f64>>()
        })
        .find(|g| Chain::self_intersects(&chain.points(g)).is_none() && crosses(g))
        .expect("a goal whose line crosses a self-intersecting pose");
    let mut limits = daemon_limits();
    limits.max_tip_speed_m_s = 10.0;
    let mut run = Run::new(daemon(Strat::Sequential, limits));
    run.c
        .command(Command::GotoJoints {
            theta: goal.clone(),
        })
        .unwrap();
    let dt = 0.01;
    assert_eq!(run.until_finished(dt, 30.0), Some(Finish::Saturated));
    assert!(run.ticks.iter().any(|r| r.tick.self_collision));
    // On the line, short of the goal, and one tick's step further on it would touch.
    let theta = run.c.theta().to_vec();
    let (i, far) = goal
        .iter()
        .zip(&home)
        .map(|(g, h)| (g - h).abs())
        .enumerate()
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let s = (theta[i] - home[i]) / (goal[i] - home[i]);
    assert!(s < 1.0 - 1e-6, "arrived? s = {s}");
    for j in 0..N {
        let on = home[j] + s * (goal[j] - home[j]);
        assert!((theta[j] - on).abs() < 1e-9, "joint {j} off the line");
    }
    let ahead = (s + limits.max_joint_speed_rad_s * dt / far).min(1.0);
    let next: Vec<f64> = home
        .iter()
        .zip(&goal)
        .map(|(h, g)| h + ahead * (g - h))
        .collect();
    assert!(Chain::self_intersects(&chain.points(&next)).is_some());
}

/// A measured pose may already have two links in contact (the model's links have no width):
/// the controller takes it, may move those links apart, and brings no other pair into
/// contact. A home pose that self-intersects is refused with the pair.
#[test]
fn a_measured_pose_in_contact_can_move_out() {
    // Six links closing into a hexagon: links 1 and 6 meet at the base.
    let lim = Some(JointLimit { lo: -2.0, hi: 2.0 });
    let chain = Chain::new(vec![0.1; 6], Vec2::zeros(), 0.0, vec![lim; 6]).unwrap();
    let k = std::f64::consts::FRAC_PI_3;
    let closed = [0.0, k, k, k, k, k];
    assert_eq!(Chain::self_intersects(&chain.points(&closed)), Some((0, 5)));
    let e = Controller::new(
        chain.clone(),
        daemon_limits(),
        Strat::Overall,
        closed.to_vec(),
        &closed,
    )
    .unwrap_err();
    assert_eq!(e, Refused::SelfCollision { a: 0, b: 5 });
    assert_eq!(e.to_string(), "links 1 and 6 of that pose cross or touch");
    let home = vec![0.3; 6];
    let mut c = Controller::new(chain, daemon_limits(), Strat::Overall, home, &closed).unwrap();
    c.command(Command::Home).unwrap();
    let mut finish = None;
    let mut prev = c.chain().points(c.theta());
    for _ in 0..1000 {
        let t = c.tick(0.01);
        let points = c.chain().points(c.theta());
        assert_eq!(
            Chain::new_self_intersection(&points, &prev, snakectl::chain::SELF_CLEARANCE_M),
            None
        );
        prev = points;
        if t.finished.is_some() {
            finish = t.finished;
            break;
        }
    }
    assert_eq!(finish, Some(Finish::Arrived));
    assert_eq!(Chain::self_intersects(&prev), None);
}
