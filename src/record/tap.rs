//! The hand-over from the control loop to the recorder: a bounded queue, drop-oldest and
//! counted, that never blocks the loop and allocates nothing once made.
//!
//! The loop offers one telemetry snapshot per tick ([`Tap::offer_tick`]) and each event it
//! emits ([`Tap::offer_event`]). A snapshot is copied into one of a fixed set of buffers made
//! up front and recycled by the recorder, so a tick allocates nothing. When the queue is full
//! the oldest item is dropped to make room, and the drop is counted per kind: what the
//! recorder writes plus what was dropped is what the loop offered. The lock is held only to
//! move an item in or out (the recorder writes outside it), so the loop never waits on the
//! disk. The recorder is not woken per item: once an offer brings the queue to [`WAKE_AT`]
//! items, the loop wakes it after that tick's work ([`Tap::wake`]), so that it encodes and
//! writes in the idle rest of the loop's period rather than across the next tick.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::protocol::{Event, FaultInfo, Telemetry};

/// Items the queue holds by default: 10 s of ticks at 100 Hz, about 1 kB each for 12 joints.
pub const RECORD_QUEUE: usize = 1024;

/// Items queued when the loop wakes the recorder (half the queue, if that is fewer): the
/// offer that brings the queue to it marks a wake-up, which the loop makes after its tick
/// ([`Tap::wake`]), so the recorder's burst (about a quarter of a millisecond here) falls in
/// the loop's idle time, not across a tick. At 1 kHz that is one wake-up, one system call of
/// the loop, in 32 ticks; waking it every tick would put a thread switch on the loop's cores
/// every tick.
pub const WAKE_AT: usize = 32;

/// How long the recorder waits for a wake-up before it drains what is queued anyway: the
/// bound on how long an item waits when the loop offers fewer than [`WAKE_AT`] in that time
/// (below 32 Hz). Draining on its own clock lands at any phase of the loop's period, which is
/// why it is only the fallback.
pub const DRAIN_AT_LEAST_EVERY: Duration = Duration::from_secs(1);

/// What the loop offered of one kind, and how much of it the full queue dropped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Count {
    /// Offered by the loop.
    pub offered: u64,
    /// Dropped before the recorder took it (the queue was full, or the recording had
    /// stopped).
    pub dropped: u64,
}

/// The hand-over's counts, per kind of item.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Telemetry snapshots (one per tick): each is a `JointState`, two tips and a telemetry
    /// message.
    pub ticks: Count,
    /// The snapshots that had a target (each is also a `target` message).
    pub targets: Count,
    /// Events.
    pub events: Count,
}

/// One item on its way to the recorder.
#[derive(Debug)]
pub enum Item {
    /// A tick's telemetry, in a buffer to give back with [`Drain::recycle`].
    Tick(Box<Telemetry>),
    /// An event.
    Event(Event),
}

#[derive(Debug)]
struct Queue {
    items: VecDeque<Item>,
    capacity: usize,
    /// Buffers for snapshots, made up front; boxed, so that they move between the queue, the
    /// spares and the recorder as a pointer, not as the snapshot's hundreds of bytes.
    #[allow(clippy::vec_box)]
    spare: Vec<Box<Telemetry>>,
    counts: Counts,
    /// The recorder takes nothing more: everything offered from now on is dropped.
    stopped: bool,
    /// The recorder is to finish once the queue is empty.
    closing: bool,
    /// The first offer: its tick and when it was made, ns since the Unix epoch (the loop's
    /// time base on the wall clock, whenever the recorder takes it).
    first: Option<(u64, u64)>,
}

#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    /// Signalled when a batch is whole (after the loop's tick), or the hand-over closes.
    ready: Condvar,
    /// A batch is whole and the recorder not yet woken for it.
    wake: AtomicBool,
}

impl Shared {
    /// The queue; a panic elsewhere while it was held leaves it usable (its state is always
    /// whole between two statements).
    fn lock(&self) -> MutexGuard<'_, Queue> {
        self.queue.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The loop's end.
#[derive(Debug)]
pub struct Tap {
    shared: Arc<Shared>,
}

/// The recorder's end.
#[derive(Debug)]
pub struct Drain {
    shared: Arc<Shared>,
}

/// A hand-over of `capacity` items (at least 1), its snapshot buffers sized for `joints`.
pub fn channel(capacity: usize, joints: usize) -> (Tap, Drain) {
    let capacity = capacity.max(1);
    // The queue's worth, one the recorder holds, one to spare.
    let spare = (0..capacity + 2).map(|_| Box::new(sized(joints))).collect();
    let shared = Arc::new(Shared {
        queue: Mutex::new(Queue {
            items: VecDeque::with_capacity(capacity),
            capacity,
            spare,
            counts: Counts::default(),
            stopped: false,
            closing: false,
            first: None,
        }),
        ready: Condvar::new(),
        wake: AtomicBool::new(false),
    });
    (
        Tap {
            shared: Arc::clone(&shared),
        },
        Drain { shared },
    )
}

/// A snapshot whose lists hold `joints` entries without growing.
fn sized(joints: usize) -> Telemetry {
    let v = || Vec::with_capacity(joints);
    Telemetry {
        theta_cmd: v(),
        theta_meas: v(),
        omega_meas: v(),
        temperature_c: v(),
        voltage_v: v(),
        load: v(),
        load_unit: Vec::with_capacity(joints),
        ..Telemetry::default()
    }
}

impl Tap {
    /// Offers this tick's snapshot: copied into a spare buffer (the oldest item dropped when
    /// the queue is full). Never waits but for the lock, which the recorder holds only to move
    /// an item.
    pub fn offer_tick(&self, telemetry: &Telemetry) {
        let target = telemetry.target.is_some();
        let mut q = self.shared.lock();
        q.note_first(telemetry.tick);
        q.counts.ticks.offered += 1;
        if target {
            q.counts.targets.offered += 1;
        }
        let buffer = if q.stopped {
            None
        } else if q.items.len() >= q.capacity {
            match q.evict() {
                Some(buffer) => Some(buffer),
                None => q.spare.pop(),
            }
        } else {
            q.spare.pop()
        };
        let Some(mut buffer) = buffer else {
            // Stopped (or, never expected, no buffer free): counted, not kept.
            q.counts.ticks.dropped += 1;
            if target {
                q.counts.targets.dropped += 1;
            }
            return;
        };
        copy_into(&mut buffer, telemetry);
        q.items.push_back(Item::Tick(buffer));
        if q.wakes_recorder() {
            self.shared.wake.store(true, Ordering::Relaxed);
        }
    }

    /// Offers an event (the oldest item dropped when the queue is full).
    pub fn offer_event(&self, event: &Event) {
        let mut q = self.shared.lock();
        q.note_first(event.tick);
        q.counts.events.offered += 1;
        if q.stopped {
            q.counts.events.dropped += 1;
            return;
        }
        if q.items.len() >= q.capacity {
            if let Some(buffer) = q.evict() {
                q.spare.push(buffer);
            }
        }
        q.items.push_back(Item::Event(event.clone()));
        if q.wakes_recorder() {
            self.shared.wake.store(true, Ordering::Relaxed);
        }
    }

    /// Wakes the recorder if an offer since the last call completed a batch: called by the
    /// loop after its tick's work, so the wake-up's system call and the recorder's burst stay
    /// out of the tick.
    pub fn wake(&self) {
        if self.shared.wake.swap(false, Ordering::Relaxed) {
            self.shared.ready.notify_one();
        }
    }

    /// The counts so far.
    pub fn counts(&self) -> Counts {
        self.shared.lock().counts
    }
}

impl Queue {
    /// Notes the time of the first offer (one clock read, then nothing).
    fn note_first(&mut self, tick: u64) {
        if self.first.is_none() {
            self.first = Some((tick, now_ns()));
        }
    }

    /// The queue has just reached [`WAKE_AT`] items (or half its capacity): the one offer of
    /// the batch that asks for a wake-up, so the loop makes no system call and wakes no thread
    /// on the other ticks.
    fn wakes_recorder(&self) -> bool {
        self.items.len() == (self.capacity / 2).clamp(1, WAKE_AT)
    }

    /// Drops the oldest item, counted; its buffer, if it was a snapshot.
    fn evict(&mut self) -> Option<Box<Telemetry>> {
        match self.items.pop_front()? {
            Item::Tick(buffer) => {
                self.counts.ticks.dropped += 1;
                if buffer.target.is_some() {
                    self.counts.targets.dropped += 1;
                }
                Some(buffer)
            }
            Item::Event(_) => {
                self.counts.events.dropped += 1;
                None
            }
        }
    }
}

impl Drain {
    /// The oldest item, waiting up to `wait` for one; `None` when there was none (or the
    /// hand-over is closing and empty).
    pub fn next(&self, wait: Duration) -> Option<Item> {
        let mut q = self.shared.lock();
        if q.items.is_empty() && !q.closing {
            q = match self.shared.ready.wait_timeout(q, wait) {
                Ok((q, _)) => q,
                Err(e) => e.into_inner().0,
            };
        }
        q.items.pop_front()
    }

    /// Gives a snapshot's buffer back for the loop's next offer.
    pub fn recycle(&self, buffer: Box<Telemetry>) {
        let mut q = self.shared.lock();
        if q.spare.len() < q.capacity + 2 {
            q.spare.push(buffer);
        }
    }

    /// No more items will be taken: what is queued is dropped and what comes is dropped,
    /// both counted (the recording failed).
    pub fn stop(&self) {
        let mut q = self.shared.lock();
        q.stopped = true;
        while let Some(buffer) = q.evict() {
            q.spare.push(buffer);
        }
    }

    /// Whether [`Closer::close`] was called and nothing is left.
    pub fn is_done(&self) -> bool {
        let q = self.shared.lock();
        q.closing && q.items.is_empty()
    }

    /// The counts so far.
    pub fn counts(&self) -> Counts {
        self.shared.lock().counts
    }

    /// The first offer's tick and when the loop made it (ns since the Unix epoch); `None`
    /// before any.
    pub fn first_offer(&self) -> Option<(u64, u64)> {
        self.shared.lock().first
    }

    /// A handle that closes the hand-over from another thread.
    pub fn closer(&self) -> Closer {
        Closer {
            shared: Arc::clone(&self.shared),
        }
    }
}

/// Closes a hand-over from outside the recorder's thread.
#[derive(Debug, Clone)]
pub struct Closer {
    shared: Arc<Shared>,
}

impl Closer {
    /// The recorder is to finish once the queue is empty: [`Drain::next`] waits no more then.
    pub fn close(&self) {
        self.shared.lock().closing = true;
        self.shared.ready.notify_all();
    }

    /// The counts so far.
    pub fn counts(&self) -> Counts {
        self.shared.lock().counts
    }
}

/// Now, ns since the Unix epoch (0 before it).
pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// Copies `src` into `dst`, reusing `dst`'s lists and strings (no allocation once they are
/// large enough). Every field is named, so a new one cannot be forgotten.
pub fn copy_into(dst: &mut Telemetry, src: &Telemetry) {
    let Telemetry {
        tick,
        t_s,
        state,
        strategy,
        tip_ref,
        tip,
        tip_meas,
        target,
        theta_cmd,
        theta_meas,
        omega_meas,
        tracking_error_m,
        saturated,
        self_collision,
        min_clearance_m,
        blocked,
        command,
        solve_us,
        loop_hz,
        tick_p99_us,
        overruns,
        behind,
        peak_joint_speed_rad_s,
        m3_total_rad2,
        faults,
        warnings,
        torque,
        temperature_c,
        voltage_v,
        load,
        load_unit,
        health_tick,
        counters,
    } = src;
    dst.tick = *tick;
    dst.t_s = *t_s;
    dst.state = *state;
    dst.strategy = *strategy;
    dst.tip_ref = *tip_ref;
    dst.tip = *tip;
    dst.tip_meas = *tip_meas;
    dst.target = *target;
    dst.theta_cmd.clone_from(theta_cmd);
    dst.theta_meas.clone_from(theta_meas);
    dst.omega_meas.clone_from(omega_meas);
    dst.tracking_error_m = *tracking_error_m;
    dst.saturated = *saturated;
    dst.self_collision = *self_collision;
    dst.min_clearance_m = *min_clearance_m;
    dst.blocked = *blocked;
    // Its request id is shared (an `Arc`), not copied.
    dst.command.clone_from(command);
    dst.solve_us = *solve_us;
    dst.loop_hz = *loop_hz;
    dst.tick_p99_us = *tick_p99_us;
    dst.overruns = *overruns;
    dst.behind = *behind;
    dst.peak_joint_speed_rad_s = *peak_joint_speed_rad_s;
    dst.m3_total_rad2 = *m3_total_rad2;
    copy_faults(&mut dst.faults, faults);
    copy_faults(&mut dst.warnings, warnings);
    dst.torque = *torque;
    dst.temperature_c.clone_from(temperature_c);
    dst.voltage_v.clone_from(voltage_v);
    dst.load.clone_from(load);
    dst.load_unit.clone_from(load_unit);
    dst.health_tick = *health_tick;
    dst.counters = *counters;
}

/// Copies a fault list, reusing the strings of the entries already there.
fn copy_faults(dst: &mut Vec<FaultInfo>, src: &[FaultInfo]) {
    dst.truncate(src.len());
    let kept = dst.len();
    for (d, s) in dst.iter_mut().zip(src) {
        d.id = s.id;
        d.joint = s.joint;
        d.port.clone_from(&s.port);
        d.kind = s.kind;
        d.since_tick = s.since_tick;
        d.detail.clone_from(&s.detail);
    }
    dst.extend(src[kept..].iter().cloned());
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::protocol::{CommandInfo, FaultKind, Outcome, State, What};

    fn snapshot(tick: u64, target: bool) -> Telemetry {
        Telemetry {
            tick,
            t_s: tick as f64 * 0.01,
            state: State::Moving,
            target: target.then_some([0.1, 0.2]),
            theta_meas: vec![0.5; 3],
            theta_cmd: vec![0.4; 3],
            command: Some(CommandInfo {
                kind: crate::protocol::CmdName::Goto,
                id: Some(Arc::new(serde_json::json!(7))),
                outcome: Outcome::Active,
                peak_joint_speed_rad_s: 0.3,
                m3_rad2: 0.01,
            }),
            faults: vec![FaultInfo::servo(
                3,
                3,
                Some("/dev/ttyUSB0".into()),
                FaultKind::Silent,
                tick,
                "no reply".into(),
            )],
            ..Telemetry::default()
        }
    }

    fn event(tick: u64) -> Event {
        Event {
            owner: None,
            cmd_id: None,
            tick,
            what: What::Estop { tip: [0.0, 0.1] },
        }
    }

    #[test]
    fn a_copy_is_equal_to_its_source() {
        let mut dst = sized(3);
        let src = snapshot(5, true);
        copy_into(&mut dst, &src);
        assert_eq!(dst, src);
        // And again over a longer list: the copy shrinks it.
        let mut longer = src.clone();
        longer.faults.push(longer.faults[0].clone());
        copy_into(&mut dst, &longer);
        copy_into(&mut dst, &src);
        assert_eq!(dst, src);
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts_per_kind() {
        let (tap, drain) = channel(4, 3);
        for tick in 0..10 {
            tap.offer_tick(&snapshot(tick, tick % 2 == 0));
        }
        tap.offer_event(&event(10));
        let counts = tap.counts();
        assert_eq!(
            counts.ticks,
            Count {
                offered: 10,
                dropped: 7
            }
        );
        assert_eq!(
            counts.targets,
            Count {
                offered: 5,
                dropped: 4
            }
        );
        assert_eq!(
            counts.events,
            Count {
                offered: 1,
                dropped: 0
            }
        );
        // The newest are kept, oldest first.
        let mut kept = Vec::new();
        while let Some(item) = drain.next(Duration::ZERO) {
            match item {
                Item::Tick(t) => {
                    kept.push(t.tick);
                    drain.recycle(t);
                }
                Item::Event(e) => kept.push(100 + e.tick),
            }
        }
        assert_eq!(kept, [7, 8, 9, 110]);
    }

    #[test]
    fn the_recorder_is_woken_once_a_batch_by_the_offer_that_completes_it() {
        let (tap, drain) = channel(RECORD_QUEUE, 3);
        // Whether a wake-up is owed; `tap.wake()` makes it and clears it.
        let owed = |drain: &Drain| drain.shared.wake.load(Ordering::Relaxed);
        for tick in 0..WAKE_AT as u64 - 1 {
            tap.offer_tick(&snapshot(tick, false));
        }
        assert!(!owed(&drain), "no wake-up before the batch is whole");
        tap.offer_tick(&snapshot(99, false));
        assert!(owed(&drain), "marked for after the tick");
        tap.wake();
        assert!(!owed(&drain), "woken once");
        for tick in 0..10 {
            tap.offer_event(&event(tick));
        }
        assert!(
            !owed(&drain),
            "one wake-up per batch, however long it waits"
        );
        while let Some(item) = drain.next(Duration::ZERO) {
            if let Item::Tick(t) = item {
                drain.recycle(t);
            }
        }
        for tick in 0..WAKE_AT as u64 {
            tap.offer_tick(&snapshot(tick, false));
        }
        assert!(owed(&drain), "the next batch wakes it again");
        // A queue shorter than two batches wakes it at half its capacity.
        let (small, drain) = channel(4, 3);
        small.offer_tick(&snapshot(0, false));
        assert!(!owed(&drain));
        small.offer_tick(&snapshot(1, false));
        assert!(owed(&drain));
    }

    #[test]
    fn a_stopped_hand_over_drops_and_counts_everything() {
        let (tap, drain) = channel(4, 3);
        tap.offer_tick(&snapshot(0, false));
        drain.stop();
        tap.offer_tick(&snapshot(1, true));
        tap.offer_event(&event(1));
        let counts = tap.counts();
        assert_eq!(
            counts.ticks,
            Count {
                offered: 2,
                dropped: 2
            }
        );
        assert_eq!(
            counts.targets,
            Count {
                offered: 1,
                dropped: 1
            }
        );
        assert_eq!(
            counts.events,
            Count {
                offered: 1,
                dropped: 1
            }
        );
        assert!(drain.next(Duration::ZERO).is_none());
    }
}
