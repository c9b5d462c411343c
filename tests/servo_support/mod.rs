//! The rig the servo integration tests run on: by default a simulated chain served in-process
//! on a pseudo-terminal (time on a manual clock the tests advance); with the `hardware` feature,
//! real servos on `SNAKECTL_PORT` (baud `SNAKECTL_BAUD`, default 1000000; ids `SNAKECTL_IDS`,
//! default 1..=12). The same test bodies run on both; tests that need the simulator's fault
//! injection or its clock are skipped on hardware.
#![allow(dead_code, missing_docs, clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;
use std::time::{Duration, Instant};

use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::ServoBus;
use snakectl_sim::{Clock, ManualClock, Model, RealClock, ServoSpec, SimConfig, SimHandle};

/// Reply timeout used by the tests: generous, so a loaded machine does not fail them.
pub const TIMEOUT: Duration = Duration::from_millis(200);

/// A bus and, on the simulator, its handle and clock.
pub struct Rig {
    pub bus: DynamixelBus,
    pub ids: Vec<u8>,
    pub sim: Option<SimHandle>,
    pub clock: Option<ManualClock>,
}

impl Rig {
    /// Let `dt` pass: advance the manual clock (simulator) or sleep (hardware).
    pub fn settle(&mut self, dt: Duration) {
        match (&self.sim, &self.clock) {
            (Some(sim), Some(clock)) => {
                // A round trip first: whatever was sent before (a sync write has no reply) is
                // then handled at the present time, before time moves on.
                let _ = self.bus.ping(self.ids[0], TIMEOUT);
                // In steps, so the motor model integrates finely.
                let step = Duration::from_millis(10);
                let mut left = dt;
                while !left.is_zero() {
                    let d = left.min(step);
                    clock.advance(d);
                    sim.with_sim(|s| s.advance());
                    left -= d;
                }
            }
            _ => std::thread::sleep(dt),
        }
    }

    /// The simulator; panics on hardware (callers are simulator-only tests).
    pub fn sim(&self) -> &SimHandle {
        self.sim.as_ref().expect("a simulator-only test")
    }

    /// The clock for the servo layer's waits (a rebooted servo booting): wall time on hardware;
    /// on the simulator its own clock, each sleep moving it on by at least [`WAIT_STEP`].
    pub fn wait_clock(&self) -> Box<dyn Clock> {
        match &self.clock {
            Some(clock) => Box::new(SimWait(clock.clone())),
            None => Box::new(RealClock),
        }
    }
}

/// The least a sleep of [`Rig::wait_clock`] moves the simulator's clock on: a wait that polls a
/// booting servo every 10 ms then sees it back in a few polls, each of them costing a reply
/// timeout of wall time, instead of one poll per 10 ms of the boot.
pub const WAIT_STEP: Duration = Duration::from_millis(100);

/// The simulator's manual clock, moved on by at least [`WAIT_STEP`] a sleep.
#[derive(Debug)]
struct SimWait(ManualClock);

impl Clock for SimWait {
    fn now(&self) -> Instant {
        self.0.now()
    }

    fn sleep(&self, d: Duration) {
        self.0.advance(d.max(WAIT_STEP));
    }
}

/// A chain of XL430-W250 with these ids.
pub fn xl430(ids: &[u8]) -> SimConfig {
    SimConfig {
        servos: ids
            .iter()
            .map(|&id| ServoSpec::new(id, Model::Xl430W250))
            .collect(),
        ..SimConfig::default()
    }
}

/// Serve `config` on a pty with a manual clock, and open a bus on it.
pub fn sim_rig(config: SimConfig) -> Rig {
    let clock = ManualClock::new();
    let ids = config.servos.iter().map(|s| s.id).collect();
    let handle = serve(config, Arc::new(clock.clone()));
    let bus = open(&handle);
    Rig {
        bus,
        ids,
        sim: Some(handle),
        clock: Some(clock),
    }
}

/// Serve `config` on a pty in real time (for faults that hold replies back).
pub fn realtime_rig(config: SimConfig) -> Rig {
    let ids = config.servos.iter().map(|s| s.id).collect();
    let handle = serve(config, Arc::new(RealClock));
    let bus = open(&handle);
    Rig {
        bus,
        ids,
        sim: Some(handle),
        clock: None,
    }
}

fn serve(config: SimConfig, clock: Arc<dyn Clock>) -> SimHandle {
    snakectl::connect::serve(config, clock).expect("simulator")
}

fn open(handle: &SimHandle) -> DynamixelBus {
    let baud = handle.with_sim(|s| s.config().baud);
    // A pseudo-terminal has no latency timer; an empty sysfs keeps the test off the real one.
    DynamixelBus::open_with_sysfs(handle.path(), baud, &Sysfs::new("/nonexistent")).expect("open")
}

/// The rig for tests that run on both: twelve simulated XL430s, or the hardware.
#[cfg(not(feature = "hardware"))]
pub fn rig() -> Rig {
    sim_rig(xl430(&(1..=12).collect::<Vec<_>>()))
}

/// The rig for tests that run on both: twelve simulated XL430s, or the hardware.
#[cfg(feature = "hardware")]
pub fn rig() -> Rig {
    let port = std::env::var("SNAKECTL_PORT").expect("set SNAKECTL_PORT to the servo port");
    let baud = std::env::var("SNAKECTL_BAUD")
        .ok()
        .map(|b| b.parse().expect("SNAKECTL_BAUD"))
        .unwrap_or(1_000_000);
    let ids = std::env::var("SNAKECTL_IDS")
        .ok()
        .map(|s| {
            s.split(',')
                .map(|i| i.trim().parse().expect("SNAKECTL_IDS"))
                .collect()
        })
        .unwrap_or_else(|| (1..=12).collect());
    Rig {
        bus: DynamixelBus::open(port, baud).expect("open the servo port"),
        ids,
        sim: None,
        clock: None,
    }
}
