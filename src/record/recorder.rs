//! The recorder: a thread of its own that takes what the loop hands over ([`super::tap`]) and
//! writes it to a [`Sink`], so that a slow disk costs the loop nothing.
//!
//! Each tick's snapshot becomes, at the tick's time, a `JointState` (`joint_states`), the
//! commanded and the measured tip (`tip_cmd`, `tip_meas`, `PointStamped` in the frame `base`),
//! the target while there is one (`target`), and the telemetry object (`telemetry`); each
//! event becomes an event object (`events`). The 3-D scene of the live view (`scene`, see
//! [`crate::view`]) is drawn from the ticks taken, at most [`SCENE_HZ`] a second, its world
//! following the `world` events. Times are the loop's: tick `n` is logged at tick
//! 0's time on the wall clock (ns since the Unix epoch) plus `n` nominal periods, so they
//! increase with the ticks and match the telemetry's `t_s`.
//!
//! The config the run used is a metadata record (`snakectl.config`: `path`, `toml`) at the
//! start. On close the recorder writes the notes it was given (such as the arm's description,
//! `snakectl.describe`), then `snakectl.recording`: per channel, what the loop offered, what
//! was written and what was dropped; and it says the same in a log line. A message counts as
//! written once a flush of the sink after it has succeeded: one every [`FLUSH_BYTES`] of
//! messages, or sooner once they span [`FLUSH_AGE`] of log time; one when the loop has offered
//! nothing for [`tap::DRAIN_AT_LEAST_EVERY`] (it stalled); and one at the close. A write that
//! fails stops the recording, never the loop: what was not flushed yet, and the rest, count as
//! dropped.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use super::schema::{self, ChannelSpec};
use super::sink::{McapSink, RecordError, Sink};
use super::tap::{self, now_ns, Closer, Counts, Drain, Item, Tap};
use crate::chain::Chain;
use crate::config::Config;
use crate::protocol::{self, Event, Status, Telemetry, What};
use crate::ros;
use crate::view::{self, Topic, Trail};
use crate::world::World;

/// Most scenes a second a recording holds: the 3-D scene is written every
/// `ceil(rate_hz / SCENE_HZ)` ticks.
pub const SCENE_HZ: f64 = 30.0;

/// The frame the tips and the target are in: the arm's base frame.
pub const FRAME_ID: &str = "base";

/// Most bytes of messages the recorder writes between two flushes of its sink: an MCAP file's
/// chunk at the most (about 2 s at 100 Hz with 12 joints; [`FLUSH_AGE`] ends most chunks
/// before). Messages count as written only once a flush after them has succeeded; what a
/// failed write or flush leaves unflushed counts as dropped, even if part of it reached the
/// file, so the count never claims a message the file lacks.
pub const FLUSH_BYTES: usize = 1 << 20;

/// The longest span of log time the messages written since the last flush cover: once the
/// newest is this much younger than the oldest unflushed one, the sink is flushed. A process
/// killed (or a power loss) loses what was not flushed, and readers stop at the last whole
/// chunk, so without it a slow loop (10 Hz, a few joints) would take tens of seconds to fill
/// [`FLUSH_BYTES`] and a kill in that time would lose the whole recording. It is measured in
/// the recording's own time (the ticks'), not the wall clock's, so that the chunks follow the
/// loop whatever the recorder's thread is given of the processor.
pub const FLUSH_AGE: Duration = Duration::from_secs(1);

/// The longest a recording's close waits for its thread (the rest of the queue, the account,
/// the summary): a disk that does not answer (a stalled network file system, say) must not
/// keep the daemon from exiting. Past it the thread is left to the process's exit.
pub const CLOSE_WAIT: Duration = Duration::from_secs(1);

/// What a recording needs to know of the run.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The topics' prefix (`[zenoh] prefix`, `snakectl` by default).
    pub prefix: String,
    /// The loop's nominal period: tick `n` is logged `n` periods after tick 0.
    pub period: Duration,
    /// The config file's path.
    pub config_path: PathBuf,
    /// The config's TOML text.
    pub config_text: String,
    /// Joints, to size the hand-over's buffers.
    pub joints: usize,
    /// Items the hand-over holds.
    pub queue: usize,
    /// The arm, for the 3-D scene.
    pub chain: Chain,
    /// The world at start (the scene follows the `world` events after it).
    pub world: World,
    /// The scene is written on ticks that are a multiple of this.
    pub scene_every: u64,
}

impl Setup {
    /// The recording of a run of `config`, starting now.
    pub fn of(config: &Config) -> Setup {
        Setup {
            prefix: config.zenoh().prefix.clone(),
            period: Duration::from_secs_f64(1.0 / config.control().rate_hz),
            config_path: config.path().to_path_buf(),
            config_text: config.text().to_owned(),
            joints: config.chain().len(),
            queue: tap::RECORD_QUEUE,
            chain: config.chain().clone(),
            world: config.world().clone(),
            scene_every: (config.control().rate_hz / SCENE_HZ).ceil().max(1.0) as u64,
        }
    }

    /// Tick `tick`'s time after tick 0, ns.
    fn since_start_ns(&self, tick: u64) -> u64 {
        let period = u64::try_from(self.period.as_nanos()).unwrap_or(u64::MAX);
        tick.saturating_mul(period)
    }
}

/// The loop's time base on the wall clock: tick 0's time, from when the loop made its first
/// offer (the recorder takes it up to a batch later, or up to a second below 32 Hz).
#[derive(Debug, Clone, Copy, Default)]
struct Epoch {
    tick0_ns: Option<u64>,
}

impl Epoch {
    /// When `tick` ran, ns since the Unix epoch; `first` is the first offer's tick and time
    /// (now, without one).
    fn time_ns(&mut self, setup: &Setup, first: Option<(u64, u64)>, tick: u64) -> u64 {
        let tick0 = *self.tick0_ns.get_or_insert_with(|| {
            let (tick, at) = first.unwrap_or_else(|| (tick, now_ns()));
            at.saturating_sub(setup.since_start_ns(tick))
        });
        tick0.saturating_add(setup.since_start_ns(tick))
    }
}

/// A ROS time from ns since the epoch (seconds saturate past 2038).
fn stamp(ns: u64) -> ros::Time {
    ros::Time {
        sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
        // Below 10^9, which fits.
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

/// Metadata records to write when the recording closes (what the program around the daemon
/// knows of the run: the arm's description, a demo's phases). Cloned handles share them.
#[derive(Debug, Clone, Default)]
pub struct Notes(Arc<Mutex<Vec<Note>>>);

/// A metadata record: its name and entries.
pub type Note = (String, BTreeMap<String, String>);

impl Notes {
    /// No notes yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// A metadata record `name` with `entries`, written on close.
    pub fn add(&self, name: &str, entries: BTreeMap<String, String>) {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((name.to_owned(), entries));
    }

    fn take(&self) -> Vec<Note> {
        std::mem::take(&mut *self.0.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// Where and how a daemon records its run.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The MCAP file to write.
    pub path: PathBuf,
    /// Metadata records to add on close.
    pub notes: Notes,
    /// Replace the file if it exists (else that is refused).
    pub overwrite: bool,
}

impl RecordOptions {
    /// A recording to `path`, which must not exist yet, with no notes yet.
    pub fn to(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            notes: Notes::new(),
            overwrite: false,
        }
    }

    /// These options, replacing the file if `overwrite`.
    pub fn overwriting(self, overwrite: bool) -> Self {
        Self { overwrite, ..self }
    }
}

/// One channel's account.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelCount {
    /// Its topic.
    pub topic: String,
    /// Messages the loop offered.
    pub offered: u64,
    /// Messages written: in the file, flushed (see [`FLUSH_BYTES`]).
    pub written: u64,
    /// Messages dropped: the queue was full, the recording had stopped, or a failed write
    /// found them not yet flushed.
    pub dropped: u64,
}

/// What a recording wrote.
#[derive(Debug)]
pub struct RecordSummary {
    /// Per channel, in the order they were added.
    pub channels: Vec<ChannelCount>,
    /// Why the recording stopped early, if it did.
    pub error: Option<RecordError>,
}

impl RecordSummary {
    /// Messages dropped, all channels.
    pub fn dropped(&self) -> u64 {
        self.channels.iter().map(|c| c.dropped).sum()
    }

    /// Messages written, all channels.
    pub fn written(&self) -> u64 {
        self.channels.iter().map(|c| c.written).sum()
    }
}

/// A recording in progress: the thread that writes it.
#[derive(Debug)]
pub struct Recorder {
    closer: Closer,
    notes: Notes,
    thread: Option<JoinHandle<()>>,
    /// The thread's account, sent as it ends.
    done: mpsc::Receiver<RecordSummary>,
    what: String,
    /// The file it writes, when [`Recorder::create`] made it (it did not exist before).
    file: Option<PathBuf>,
}

impl Recorder {
    /// Creates the MCAP file `options` name ([`McapSink::create`]) and starts recording into
    /// it; the loop's end of the hand-over.
    pub fn create(options: &RecordOptions, setup: Setup) -> Result<(Recorder, Tap), RecordError> {
        let sink = McapSink::create(&options.path, options.overwrite)?;
        let made = sink.made_file();
        let what = options.path.display().to_string();
        let (mut recorder, tap) = Self::start(Box::new(sink), setup, options.notes.clone(), what)?;
        recorder.file = made.then(|| options.path.clone());
        Ok((recorder, tap))
    }

    /// A start-up that was refused leaves no recording behind: the thread ends and the file
    /// it created (header and channels, not a message) is removed; a file that was there
    /// before (`--overwrite`) is left.
    pub fn discard(mut self) {
        let (file, what) = (self.file.take(), std::mem::take(&mut self.what));
        // Dropped, its thread ends, as for any recorder not closed.
        drop(self);
        if let Some(file) = file {
            match std::fs::remove_file(&file) {
                Ok(()) => tracing::info!("start-up refused: the recording {what} removed"),
                Err(e) => tracing::warn!("removing the recording {what}: {e}"),
            }
        }
    }

    /// Starts recording into `sink` (`what` names it in the log).
    pub fn start(
        sink: Box<dyn Sink>,
        setup: Setup,
        notes: Notes,
        what: String,
    ) -> Result<(Recorder, Tap), RecordError> {
        Self::start_draining(sink, setup, notes, what, tap::DRAIN_AT_LEAST_EVERY)
    }

    /// [`Recorder::start`], the thread waiting at most `every` for the loop's items.
    fn start_draining(
        sink: Box<dyn Sink>,
        setup: Setup,
        notes: Notes,
        what: String,
        every: Duration,
    ) -> Result<(Recorder, Tap), RecordError> {
        let (tap, drain) = tap::channel(setup.queue, setup.joints);
        let closer = drain.closer();
        let thread_notes = notes.clone();
        let (done_tx, done) = mpsc::sync_channel(1);
        let thread = std::thread::Builder::new()
            .name("snakectl-record".into())
            .spawn(move || {
                crate::beside::step_aside();
                let _ = done_tx.send(record(sink, &drain, &setup, &thread_notes, every));
            })
            .map_err(|e| RecordError::Thread(e.to_string()))?;
        Ok((
            Recorder {
                closer,
                notes,
                thread: Some(thread),
                done,
                what,
                file: None,
            },
            tap,
        ))
    }

    /// A metadata record written on close.
    pub fn note(&self, name: &str, entries: BTreeMap<String, String>) {
        self.notes.add(name, entries);
    }

    /// Writes what is still queued, the notes and the account, ends the file, and says in the
    /// log what was written and dropped. Call it once the loop offers nothing more.
    /// Waits at most [`CLOSE_WAIT`] for a disk that does not answer: then the recording is
    /// left unfinished ([`RecordError::Stalled`], logged as a warning).
    pub fn close(self) -> RecordSummary {
        self.close_within(CLOSE_WAIT)
    }

    /// [`Recorder::close`], waiting at most `wait` for the thread.
    fn close_within(mut self, wait: Duration) -> RecordSummary {
        let summary = self.finish(wait);
        match &summary.error {
            Some(e @ RecordError::Stalled { .. }) => {
                tracing::warn!(file = %self.what, "the recording could not be finished: {e}")
            }
            None => tracing::info!(
                file = %self.what,
                written = summary.written(),
                dropped = summary.dropped(),
                "recording closed: {} messages written, {} dropped",
                summary.written(),
                summary.dropped()
            ),
            Some(e) => tracing::error!(
                file = %self.what,
                written = summary.written(),
                dropped = summary.dropped(),
                "recording stopped early: {e}"
            ),
        }
        summary
    }

    /// Ends the thread, waiting at most `wait` for it; its account.
    fn finish(&mut self, wait: Duration) -> RecordSummary {
        self.closer.close();
        let failed = |error| RecordSummary {
            channels: Vec::new(),
            error: Some(error),
        };
        let Some(thread) = self.thread.take() else {
            return failed(RecordError::Thread("it was ended already".into()));
        };
        match self.done.recv_timeout(wait) {
            Ok(summary) => {
                let _ = thread.join();
                summary
            }
            // Left blocked in the disk: the process's exit ends it.
            Err(RecvTimeoutError::Timeout) => failed(RecordError::Stalled {
                waited_ms: u64::try_from(wait.as_millis()).unwrap_or(u64::MAX),
            }),
            Err(RecvTimeoutError::Disconnected) => {
                let _ = thread.join();
                failed(RecordError::Thread("it panicked".into()))
            }
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.finish(CLOSE_WAIT);
        }
    }
}

/// The channels the recorder writes, by their ids in the sink.
struct Channels {
    joint_states: u16,
    tip_cmd: u16,
    tip_meas: u16,
    target: u16,
    telemetry: u16,
    events: u16,
    scene: u16,
}

/// Per channel, in the order of [`channel_specs`]: a count of messages.
type PerChannel = [u64; 7];

/// The index of each channel in [`channel_specs`].
const JOINT_STATES: usize = 0;
const TIP_CMD: usize = 1;
const TIP_MEAS: usize = 2;
const TARGET: usize = 3;
const TELEMETRY: usize = 4;
const EVENTS: usize = 5;
const SCENE: usize = 6;

/// The channels a recording of `prefix` holds, in order.
pub fn channel_specs(prefix: &str) -> Vec<ChannelSpec> {
    vec![
        schema::joint_states(prefix),
        schema::point(prefix, "tip_cmd"),
        schema::point(prefix, "tip_meas"),
        schema::point(prefix, "target"),
        schema::telemetry(prefix),
        schema::events(prefix),
        scene_spec(prefix),
    ]
}

/// The 3-D scene's channel, as the live view declares it.
fn scene_spec(prefix: &str) -> ChannelSpec {
    let spec = Topic::Scene.channel(prefix);
    ChannelSpec {
        topic: spec.topic,
        schema_name: spec.schema.name.clone(),
        schema_encoding: spec.schema.encoding.clone(),
        schema: spec.schema.data.to_vec(),
        message_encoding: spec.message_encoding.to_owned(),
        metadata: BTreeMap::new(),
    }
}

/// What the recorder keeps to draw the scene: the tip's trail and the world in force.
struct SceneState {
    trail: Trail,
    world: World,
}

/// The sink and its account: what reached it whole (flushed), and what was written to it since
/// its last flush, which a failure may still lose.
struct Out {
    sink: Box<dyn Sink>,
    /// Messages flushed, per channel.
    flushed: PerChannel,
    /// Messages written since the last flush, per channel.
    unflushed: PerChannel,
    /// Their bytes.
    unflushed_bytes: usize,
    /// The log time of the oldest of them, and of the newest, ns; `None` when there are none.
    unflushed_span: Option<(u64, u64)>,
}

impl Out {
    fn new(sink: Box<dyn Sink>) -> Self {
        Out {
            sink,
            flushed: [0; 7],
            unflushed: [0; 7],
            unflushed_bytes: 0,
            unflushed_span: None,
        }
    }

    /// One message on the channel of index `k` (sink id `channel`).
    fn write(&mut self, k: usize, channel: u16, ns: u64, data: &[u8]) -> Result<(), RecordError> {
        self.sink.write(channel, ns, data)?;
        self.unflushed[k] += 1;
        self.unflushed_bytes = self.unflushed_bytes.saturating_add(data.len());
        let (oldest, newest) = self.unflushed_span.get_or_insert((ns, ns));
        (*oldest, *newest) = ((*oldest).min(ns), (*newest).max(ns));
        Ok(())
    }

    /// Whether messages were written since the last flush.
    fn has_unflushed(&self) -> bool {
        self.unflushed_span.is_some()
    }

    /// Flushes the sink once [`FLUSH_BYTES`] wait, or once they span [`FLUSH_AGE`] of log
    /// time.
    fn flush_when_due(&mut self) -> Result<(), RecordError> {
        let age = u64::try_from(FLUSH_AGE.as_nanos()).unwrap_or(u64::MAX);
        let aged = self
            .unflushed_span
            .is_some_and(|(oldest, newest)| newest.saturating_sub(oldest) >= age);
        if aged || self.unflushed_bytes >= FLUSH_BYTES {
            self.flush()?;
        }
        Ok(())
    }

    /// Flushes the sink: what was written counts as flushed.
    fn flush(&mut self) -> Result<(), RecordError> {
        self.sink.flush()?;
        for (flushed, unflushed) in self.flushed.iter_mut().zip(&mut self.unflushed) {
            *flushed += std::mem::take(unflushed);
        }
        self.unflushed_bytes = 0;
        self.unflushed_span = None;
        Ok(())
    }

    /// After a failure: what was not flushed is added to `lost`.
    fn lose_unflushed(&mut self, lost: &mut PerChannel) {
        for (lost, unflushed) in lost.iter_mut().zip(&mut self.unflushed) {
            *lost += std::mem::take(unflushed);
        }
        self.unflushed_bytes = 0;
        self.unflushed_span = None;
    }
}

/// After a failed write or flush: says so, counts what was not flushed as lost, and takes
/// nothing more from the loop; the error.
fn stop(out: &mut Out, lost: &mut PerChannel, drain: &Drain, e: RecordError) -> RecordError {
    tracing::error!("recording stopped: {e}; the arm goes on, the rest is dropped");
    out.lose_unflushed(lost);
    drain.stop();
    e
}

/// The recorder's thread: set up, write until closed, account. It waits at most `every` for
/// the loop's items ([`tap::DRAIN_AT_LEAST_EVERY`]).
fn record(
    sink: Box<dyn Sink>,
    drain: &Drain,
    setup: &Setup,
    notes: &Notes,
    every: Duration,
) -> RecordSummary {
    let specs = channel_specs(&setup.prefix);
    let mut out = Out::new(sink);
    // Messages taken but not in the file: their write failed, or a failure came before their
    // flush.
    let mut lost: PerChannel = [0; 7];
    let mut scene = SceneState {
        trail: Trail::new(view::scene::TRAIL_POINTS),
        world: setup.world.clone(),
    };
    let mut epoch = Epoch::default();
    let begun = begin(out.sink.as_mut(), &specs, setup);
    let mut error = None;
    let channels = match begun {
        Ok(channels) => Some(channels),
        Err(e) => {
            tracing::error!("recording: {e}");
            error = Some(e);
            drain.stop();
            None
        }
    };
    while !drain.is_done() {
        let Some(item) = drain.next(every) else {
            // Nothing offered for `every`: the loop has stalled. What was taken goes to the
            // file now, not whenever the loop goes on (the log-time rule waits for a next
            // message).
            if error.is_none() && out.has_unflushed() {
                if let Err(e) = out.flush() {
                    error = Some(stop(&mut out, &mut lost, drain, e));
                }
            }
            continue;
        };
        let Some(ch) = channels.as_ref().filter(|_| error.is_none()) else {
            if let Item::Tick(buffer) = item {
                drain.recycle(buffer);
            }
            continue;
        };
        let result = match item {
            Item::Tick(t) => {
                let ns = epoch.time_ns(setup, drain.first_offer(), t.tick);
                let before = out.unflushed;
                let r = write_tick(&mut out, ch, ns, &t);
                let r = r.and_then(|()| write_scene(&mut out, ch, setup, &mut scene, ns, &t));
                if r.is_err() {
                    // The tick's messages that did not get out.
                    for k in [JOINT_STATES, TIP_CMD, TIP_MEAS, TARGET, TELEMETRY, SCENE] {
                        let owed = match k {
                            TARGET => t.target.is_some(),
                            SCENE => t.tick % setup.scene_every == 0,
                            _ => true,
                        };
                        if owed && out.unflushed[k] == before[k] {
                            lost[k] += 1;
                        }
                    }
                }
                drain.recycle(t);
                r
            }
            Item::Event(e) => {
                if let What::World { world, .. } = &e.what {
                    match world.to_world() {
                        Ok(w) => scene.world = w,
                        Err(e) => tracing::warn!("a world event the scene cannot draw: {e}"),
                    }
                }
                let ns = epoch.time_ns(setup, drain.first_offer(), e.tick);
                let r = write_event(&mut out, ch, ns, &e);
                lost[EVENTS] += u64::from(r.is_err());
                r
            }
        };
        if let Err(e) = result.and_then(|()| out.flush_when_due()) {
            error = Some(stop(&mut out, &mut lost, drain, e));
        }
    }
    if error.is_none() {
        if let Err(e) = out.flush() {
            tracing::error!("recording stopped: {e}; the rest is dropped");
            out.lose_unflushed(&mut lost);
            error = Some(e);
        }
    }
    let counts = drain.counts();
    let summary = account(&specs, counts, out.flushed, lost);
    if error.is_none() {
        if let Err(e) = end(out.sink.as_mut(), notes, &summary) {
            error = Some(e);
        }
    }
    RecordSummary {
        channels: summary,
        error,
    }
}

/// The channels added and the config written.
fn begin(
    sink: &mut dyn Sink,
    specs: &[ChannelSpec],
    setup: &Setup,
) -> Result<Channels, RecordError> {
    let mut ids = Vec::with_capacity(specs.len());
    for spec in specs {
        ids.push(sink.add_channel(spec)?);
    }
    let [joint_states, tip_cmd, tip_meas, target, telemetry, events, scene] = ids[..] else {
        return Err(RecordError::Write("the recorder's channels".into()));
    };
    sink.metadata(
        "snakectl.config",
        &BTreeMap::from([
            ("path".to_owned(), setup.config_path.display().to_string()),
            ("toml".to_owned(), setup.config_text.clone()),
        ]),
    )?;
    Ok(Channels {
        joint_states,
        tip_cmd,
        tip_meas,
        target,
        telemetry,
        events,
        scene,
    })
}

/// One tick's messages.
fn write_tick(out: &mut Out, ch: &Channels, ns: u64, t: &Telemetry) -> Result<(), RecordError> {
    let cdr = |bytes: Result<Vec<u8>, ros::RosError>| {
        bytes.map_err(|e| RecordError::Write(format!("a ROS message: {e}")))
    };
    let mut joints = ros::joint_state(t, 0.0);
    joints.header.stamp = stamp(ns);
    out.write(
        JOINT_STATES,
        ch.joint_states,
        ns,
        &cdr(ros::encode(&joints))?,
    )?;
    let point = |p: [f64; 2]| {
        let mut point = ros::point_stamped(p, 0.0, FRAME_ID);
        point.header.stamp = stamp(ns);
        cdr(ros::encode(&point))
    };
    out.write(TIP_CMD, ch.tip_cmd, ns, &point(t.tip)?)?;
    out.write(TIP_MEAS, ch.tip_meas, ns, &point(t.tip_meas)?)?;
    if let Some(target) = t.target {
        out.write(TARGET, ch.target, ns, &point(target)?)?;
    }
    let line = protocol::telemetry_line(&Status::of(t));
    out.write(TELEMETRY, ch.telemetry, ns, line.trim_end().as_bytes())?;
    // Further channels built from the same snapshot (the 3-D scene) are written here, through
    // `Sink::add_channel` in `begin` and `Sink::write`.
    Ok(())
}

/// The 3-D scene of a tick, on every `scene_every`th tick (the trail takes every tick).
fn write_scene(
    out: &mut Out,
    ch: &Channels,
    setup: &Setup,
    scene: &mut SceneState,
    ns: u64,
    t: &Telemetry,
) -> Result<(), RecordError> {
    if t.theta_meas.len() == setup.chain.len() {
        scene.trail.push(t.tip_meas);
    }
    if t.tick % setup.scene_every != 0 {
        return Ok(());
    }
    let stamp = view::timestamp_ns(ns);
    let update = view::scene(&setup.chain, &scene.world, t, &scene.trail, stamp);
    let bytes = view::encode(&update).map_err(|e| RecordError::Write(format!("the scene: {e}")))?;
    out.write(SCENE, ch.scene, ns, &bytes)
}

/// One event's message.
fn write_event(out: &mut Out, ch: &Channels, ns: u64, e: &Event) -> Result<(), RecordError> {
    let line = protocol::event_line(e);
    out.write(EVENTS, ch.events, ns, line.trim_end().as_bytes())
}

/// Per channel: offered, written, dropped (by the hand-over, or taken and not written).
fn account(
    specs: &[ChannelSpec],
    c: Counts,
    written: PerChannel,
    lost: PerChannel,
) -> Vec<ChannelCount> {
    let of_kind = |k: usize| match k {
        TARGET => c.targets,
        EVENTS => c.events,
        _ => c.ticks,
    };
    // The scene is made here, not offered by the loop: what was made is what was written or
    // lost.
    let scene = |k: usize| (k == SCENE).then(|| written[k] + lost[k]);
    specs
        .iter()
        .enumerate()
        .map(|(k, spec)| ChannelCount {
            topic: spec.topic.clone(),
            offered: scene(k).unwrap_or(of_kind(k).offered),
            written: written[k],
            dropped: if k == SCENE {
                lost[k]
            } else {
                of_kind(k).dropped + lost[k]
            },
        })
        .collect()
}

/// The notes, the account, the end of the file.
fn end(sink: &mut dyn Sink, notes: &Notes, channels: &[ChannelCount]) -> Result<(), RecordError> {
    for (name, entries) in notes.take() {
        sink.metadata(&name, &entries)?;
    }
    let mut entries = BTreeMap::new();
    for c in channels {
        entries.insert(
            c.topic.clone(),
            serde_json::json!({
                "offered": c.offered,
                "written": c.written,
                "dropped": c.dropped,
            })
            .to_string(),
        );
    }
    sink.metadata("snakectl.recording", &entries)?;
    sink.finish()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::record::read::Recording;

    /// A disk that fills up: writes fail after `room` messages.
    struct Filling {
        room: usize,
        channels: u16,
    }

    impl Sink for Filling {
        fn add_channel(&mut self, _: &ChannelSpec) -> Result<u16, RecordError> {
            self.channels += 1;
            Ok(self.channels)
        }

        fn write(&mut self, _: u16, _: u64, _: &[u8]) -> Result<(), RecordError> {
            if self.room == 0 {
                return Err(RecordError::Write("No space left on device".into()));
            }
            self.room -= 1;
            Ok(())
        }

        fn metadata(&mut self, _: &str, _: &BTreeMap<String, String>) -> Result<(), RecordError> {
            Ok(())
        }

        fn flush(&mut self) -> Result<(), RecordError> {
            Ok(())
        }

        fn finish(&mut self) -> Result<(), RecordError> {
            Ok(())
        }
    }

    /// The recording stopped for the disk that filled up, and says so.
    fn assert_out_of_space(summary: &RecordSummary) {
        assert!(
            summary
                .error
                .as_ref()
                .is_some_and(|e| e.to_string().contains("No space left")),
            "{:?}",
            summary.error
        );
    }

    fn setup() -> Setup {
        Setup {
            prefix: "arm7".into(),
            period: Duration::from_millis(10),
            config_path: "arm.toml".into(),
            config_text: String::new(),
            joints: 2,
            queue: 4096,
            chain: Chain::unlimited(vec![0.5, 0.5], crate::chain::Vec2::zeros(), 0.0).unwrap(),
            world: World::default(),
            // A scene at tick 0 only.
            scene_every: u64::MAX,
        }
    }

    #[test]
    fn a_full_disk_stops_the_recording_says_why_and_counts_the_rest_as_dropped() {
        let sink = Filling {
            room: 4 * 100 + 2,
            channels: 0,
        };
        // The thread takes the items only when woken, here by the close: a pause of the test
        // between two offers cannot pass for a loop that stalled, and flush.
        let (recorder, tap) = Recorder::start_draining(
            Box::new(sink),
            setup(),
            Notes::new(),
            "full".into(),
            Duration::from_secs(3600),
        )
        .unwrap();
        for tick in 0..1000 {
            let t = Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                ..Telemetry::default()
            };
            tap.offer_tick(&t);
        }
        let summary = recorder.close();
        assert_out_of_space(&summary);
        let joint_states = &summary.channels[0];
        assert_eq!(joint_states.topic, "/arm7/joint_states");
        assert_eq!(joint_states.offered, 1000);
        // 100 whole ticks, then one that found the disk full: less than a flush's worth (they
        // span 0.99 s of log time, under FLUSH_AGE, and far less than FLUSH_BYTES), so none of
        // them counts as written.
        assert_eq!(joint_states.written, 0, "{joint_states:?}");
        assert_eq!(joint_states.dropped, 1000, "{joint_states:?}");
        for c in &summary.channels {
            assert_eq!(c.written + c.dropped, c.offered, "{c:?}");
        }
        // The offers after the failure are taken, counted and dropped.
        tap.offer_tick(&Telemetry::default());
        assert_eq!(tap.counts().ticks.dropped, 900);
    }

    /// A file on a disk with room for `room` bytes: a write past it stores what fits, and the
    /// next fails, as on a full disk.
    struct Disk {
        bytes: Arc<Mutex<Vec<u8>>>,
        room: usize,
        at: usize,
    }

    impl std::io::Write for Disk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            let n = buf.len().min(self.room.saturating_sub(self.at));
            if n == 0 && !buf.is_empty() {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::StorageFull,
                    "No space left on device",
                ));
            }
            let mut bytes = self.bytes.lock().unwrap();
            let end = self.at + n;
            if bytes.len() < end {
                bytes.resize(end, 0);
            }
            bytes[self.at..end].copy_from_slice(&buf[..n]);
            self.at = end;
            Ok(n)
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl std::io::Seek for Disk {
        fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
            let len = self.bytes.lock().unwrap().len() as i64;
            let at = match to {
                std::io::SeekFrom::Start(at) => at as i64,
                std::io::SeekFrom::End(by) => len + by,
                std::io::SeekFrom::Current(by) => self.at as i64 + by,
            };
            self.at = usize::try_from(at).map_err(std::io::Error::other)?;
            Ok(self.at as u64)
        }
    }

    /// Messages per topic in an MCAP file, read up to where it breaks off.
    fn messages_in(file: &[u8]) -> BTreeMap<String, u64> {
        let mut counts = BTreeMap::new();
        let stream =
            mcap::MessageStream::new_with_options(file, mcap::read::Options::IgnoreEndMagic.into())
                .unwrap();
        for message in stream.map_while(Result::ok) {
            *counts.entry(message.channel.topic.clone()).or_insert(0) += 1;
        }
        counts
    }

    #[test]
    fn after_a_full_disk_the_messages_counted_written_are_those_in_the_file() {
        // Whole chunks fit (a second of ticks each, FLUSH_AGE, with their records and index),
        // then one is cut short in its messages.
        let bytes = Arc::new(Mutex::new(Vec::new()));
        let disk = Disk {
            bytes: Arc::clone(&bytes),
            room: 3 * FLUSH_BYTES,
            at: 0,
        };
        let sink = McapSink::new(std::io::BufWriter::new(disk)).unwrap();
        // Room for every tick offered: nothing is dropped before the disk fills, so the file's
        // layout, and where it breaks off, are the same in every run.
        const TICKS: u64 = 6000;
        let setup = Setup {
            queue: TICKS as usize,
            ..setup()
        };
        let (recorder, tap) =
            Recorder::start(Box::new(sink), setup, Notes::new(), "disk".into()).unwrap();
        for tick in 0..TICKS {
            tap.offer_tick(&Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                target: Some([0.3, 0.4]),
                ..Telemetry::default()
            });
        }
        let summary = recorder.close();
        assert_out_of_space(&summary);
        let in_file = messages_in(&bytes.lock().unwrap());
        for c in &summary.channels {
            assert_eq!(
                c.written,
                in_file.get(&c.topic).copied().unwrap_or(0),
                "{c:?}: the file holds {in_file:?}"
            );
            assert_eq!(c.written + c.dropped, c.offered, "{c:?}");
        }
        let joint_states = &summary.channels[JOINT_STATES];
        assert!(
            joint_states.written > 0 && joint_states.dropped > 0,
            "whole chunks in the file, then the disk full: {joint_states:?}"
        );
    }

    #[test]
    fn a_file_that_fails_from_the_start_stops_the_recording_and_is_accounted() {
        // The header fits in the buffer; the first chunk's start finds the disk full.
        let disk = Disk {
            bytes: Arc::new(Mutex::new(Vec::new())),
            room: 0,
            at: 0,
        };
        let sink = McapSink::new(std::io::BufWriter::new(disk)).unwrap();
        let (recorder, tap) =
            Recorder::start(Box::new(sink), setup(), Notes::new(), "full".into()).unwrap();
        for tick in 0..100 {
            tap.offer_tick(&Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                ..Telemetry::default()
            });
        }
        let summary = recorder.close();
        assert_eq!(
            summary.error.as_ref().map(ToString::to_string).as_deref(),
            Some("writing the recording: No space left on device")
        );
        let joint_states = &summary.channels[JOINT_STATES];
        assert_eq!(
            (
                joint_states.offered,
                joint_states.written,
                joint_states.dropped
            ),
            (100, 0, 100),
            "{joint_states:?}"
        );
    }

    /// A sink that keeps the log time of every message, and holds the recorder in its first
    /// `add_channel` until `hold` is sent to.
    struct Times {
        times: Arc<Mutex<Vec<u64>>>,
        hold: Option<std::sync::mpsc::Receiver<()>>,
    }

    impl Sink for Times {
        fn add_channel(&mut self, _: &ChannelSpec) -> Result<u16, RecordError> {
            if let Some(hold) = self.hold.take() {
                hold.recv().unwrap();
            }
            Ok(0)
        }

        fn write(&mut self, _: u16, log_time_ns: u64, _: &[u8]) -> Result<(), RecordError> {
            self.times.lock().unwrap().push(log_time_ns);
            Ok(())
        }

        fn metadata(&mut self, _: &str, _: &BTreeMap<String, String>) -> Result<(), RecordError> {
            Ok(())
        }

        fn flush(&mut self) -> Result<(), RecordError> {
            Ok(())
        }

        fn finish(&mut self) -> Result<(), RecordError> {
            Ok(())
        }
    }

    #[test]
    fn tick_0_is_logged_when_the_loop_offered_it_not_when_the_recorder_took_it() {
        let times = Arc::new(Mutex::new(Vec::new()));
        let (release, hold) = std::sync::mpsc::channel();
        let sink = Times {
            times: Arc::clone(&times),
            hold: Some(hold),
        };
        let (recorder, tap) =
            Recorder::start(Box::new(sink), setup(), Notes::new(), "times".into()).unwrap();
        let before = now_ns();
        tap.offer_tick(&Telemetry {
            theta_meas: vec![0.1, 0.2],
            ..Telemetry::default()
        });
        let after = now_ns();
        // The recorder takes it 100 ms later, as it takes a batch's first tick up to 32 ticks
        // after the loop offered it (a second, below 32 Hz).
        std::thread::sleep(Duration::from_millis(100));
        release.send(()).unwrap();
        let summary = recorder.close();
        assert!(summary.error.is_none(), "{:?}", summary.error);
        let times = times.lock().unwrap();
        assert!(!times.is_empty());
        for &t in times.iter() {
            assert!(
                (before..=after).contains(&t),
                "tick 0 offered within {before}..={after}, logged at {t} ({} ms late)",
                t.saturating_sub(after) / 1_000_000
            );
        }
    }

    /// A disk that stops answering: every write blocks until `release` is sent to or dropped.
    struct Stalled {
        release: Arc<Mutex<std::sync::mpsc::Receiver<()>>>,
    }

    impl Sink for Stalled {
        fn add_channel(&mut self, _: &ChannelSpec) -> Result<u16, RecordError> {
            Ok(0)
        }

        fn write(&mut self, _: u16, _: u64, _: &[u8]) -> Result<(), RecordError> {
            let _ = self.release.lock().unwrap().recv();
            Ok(())
        }

        fn metadata(&mut self, _: &str, _: &BTreeMap<String, String>) -> Result<(), RecordError> {
            Ok(())
        }

        fn flush(&mut self) -> Result<(), RecordError> {
            Ok(())
        }

        fn finish(&mut self) -> Result<(), RecordError> {
            Ok(())
        }
    }

    #[test]
    fn a_close_waits_for_a_stalled_disk_only_so_long_and_says_so() {
        let (release, held) = std::sync::mpsc::channel();
        let sink = Stalled {
            release: Arc::new(Mutex::new(held)),
        };
        let (recorder, tap) =
            Recorder::start(Box::new(sink), setup(), Notes::new(), "stalled".into()).unwrap();
        for tick in 0..100 {
            tap.offer_tick(&Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                ..Telemetry::default()
            });
        }
        // Closed on a thread of its own: a close that waited for the disk would never return,
        // and the test fails instead of hanging.
        let (closed_tx, closed) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = closed_tx.send(recorder.close_within(Duration::from_millis(50)));
        });
        let summary = closed
            .recv_timeout(Duration::from_secs(20))
            .unwrap_or_else(|_| panic!("the close waited for a disk that never answered"));
        assert!(
            matches!(summary.error, Some(RecordError::Stalled { waited_ms: 50 })),
            "{:?}",
            summary.error
        );
        assert_eq!(
            summary.error.map(|e| e.to_string()).as_deref(),
            Some(
                "the disk did not answer within 50 ms; the file may lack its summary \
                 (`mcap recover` rebuilds it)"
            )
        );
        // The disk answers again: the thread left behind ends.
        drop(release);
    }

    #[test]
    fn ticks_are_logged_whole_periods_after_tick_0() {
        let setup = setup();
        let mut epoch = Epoch::default();
        let t0 = epoch.time_ns(&setup, None, 0);
        assert_eq!(epoch.time_ns(&setup, None, 250) - t0, 2_500_000_000);
        assert_eq!(
            stamp(1_700_000_000_123_456_789),
            ros::Time {
                sec: 1_700_000_000,
                nanosec: 123_456_789
            }
        );
    }

    /// What a kill left: the log time of the last tick written whole, and the file's bytes.
    type Kill = (u64, Vec<u8>);

    /// A recording file that the test "kills" before each tick: before the first message of
    /// each new log time it keeps what the file on disk holds, as a process killed there would
    /// leave it (what sits in the writer's buffer is lost).
    struct Killed {
        inner: McapSink<std::io::BufWriter<std::fs::File>>,
        path: PathBuf,
        last: Option<u64>,
        kills: Arc<Mutex<Vec<Kill>>>,
    }

    impl Sink for Killed {
        fn add_channel(&mut self, spec: &ChannelSpec) -> Result<u16, RecordError> {
            self.inner.add_channel(spec)
        }

        fn write(&mut self, channel: u16, ns: u64, data: &[u8]) -> Result<(), RecordError> {
            if let Some(last) = self.last.filter(|&last| last != ns) {
                let on_disk = std::fs::read(&self.path).unwrap();
                self.kills.lock().unwrap().push((last, on_disk));
            }
            self.last = Some(ns);
            self.inner.write(channel, ns, data)
        }

        fn metadata(
            &mut self,
            name: &str,
            entries: &BTreeMap<String, String>,
        ) -> Result<(), RecordError> {
            self.inner.metadata(name, entries)
        }

        fn flush(&mut self) -> Result<(), RecordError> {
            self.inner.flush()
        }

        fn finish(&mut self) -> Result<(), RecordError> {
            self.inner.finish()
        }
    }

    /// A loop at 10 Hz with two joints writes far less than a chunk's [`FLUSH_BYTES`] in the
    /// 10 s of this run: a kill at any tick from the first second on still leaves a file that
    /// reads back every tick up to [`FLUSH_AGE`] before the last one written.
    #[test]
    fn at_10_hz_a_kill_loses_at_most_the_last_second_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let kills = Arc::new(Mutex::new(Vec::new()));
        let sink = Killed {
            inner: McapSink::create(&path, false).unwrap(),
            path: path.clone(),
            last: None,
            kills: Arc::clone(&kills),
        };
        let period = Duration::from_millis(100);
        const TICKS: u64 = 100;
        let setup = Setup {
            period,
            queue: TICKS as usize,
            // Below 30 Hz every tick draws the scene.
            scene_every: 1,
            ..setup()
        };
        let (recorder, tap) =
            Recorder::start(Box::new(sink), setup, Notes::new(), "killed".into()).unwrap();
        for tick in 0..TICKS {
            tap.offer_tick(&Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                ..Telemetry::default()
            });
        }
        let summary = recorder.close();
        assert!(summary.error.is_none(), "{:?}", summary.error);
        let whole = Recording::open(&path).unwrap();
        let t0 = whole.channels["/arm7/joint_states"].messages[0].log_time_ns;
        let kills = kills.lock().unwrap();
        assert_eq!(kills.len() as u64, TICKS - 1);
        let (age, period) = (FLUSH_AGE.as_nanos() as u64, period.as_nanos() as u64);
        let cut = dir.path().join("cut.mcap");
        for (last, on_disk) in kills.iter().filter(|(last, _)| last - t0 >= age) {
            let ticks = (last - t0) / period + 1;
            std::fs::write(&cut, on_disk).unwrap();
            let r =
                Recording::open(&cut).unwrap_or_else(|e| panic!("killed after {ticks} ticks: {e}"));
            let times: Vec<u64> = r
                .channels
                .get("/arm7/joint_states")
                .map(|c| c.messages.iter().map(|m| m.log_time_ns).collect())
                .unwrap_or_default();
            let kept = times.len() as u64;
            // Every tick from the first, in order, none missing.
            assert_eq!(
                times,
                (0..kept).map(|n| t0 + n * period).collect::<Vec<_>>()
            );
            assert!(
                times.last().is_some_and(|&t| last - t <= age),
                "killed after {ticks} ticks: the file holds {kept}, not up to FLUSH_AGE before"
            );
        }
    }

    /// A sink that says on `flushes` how many messages were written before each flush.
    struct Flushes {
        written: usize,
        flushes: std::sync::mpsc::Sender<usize>,
    }

    impl Sink for Flushes {
        fn add_channel(&mut self, _: &ChannelSpec) -> Result<u16, RecordError> {
            Ok(0)
        }

        fn write(&mut self, _: u16, _: u64, _: &[u8]) -> Result<(), RecordError> {
            self.written += 1;
            Ok(())
        }

        fn metadata(&mut self, _: &str, _: &BTreeMap<String, String>) -> Result<(), RecordError> {
            Ok(())
        }

        fn flush(&mut self) -> Result<(), RecordError> {
            let _ = self.flushes.send(self.written);
            Ok(())
        }

        fn finish(&mut self) -> Result<(), RecordError> {
            Ok(())
        }
    }

    /// A loop that stops offering (stalled) has what the recorder took flushed after one wait
    /// for more, though those messages span far less than [`FLUSH_AGE`] and [`FLUSH_BYTES`].
    #[test]
    fn what_was_taken_is_flushed_when_the_loop_stops_offering() {
        let (flushes_tx, flushes) = std::sync::mpsc::channel();
        let sink = Flushes {
            written: 0,
            flushes: flushes_tx,
        };
        // The thread waits 10 ms for items, not a second, to keep the test short.
        let (recorder, tap) = Recorder::start_draining(
            Box::new(sink),
            setup(),
            Notes::new(),
            "stalled loop".into(),
            Duration::from_millis(10),
        )
        .unwrap();
        // Three ticks (fewer than a batch: the recorder is not woken for them), then nothing.
        for tick in 0..3 {
            tap.offer_tick(&Telemetry {
                tick,
                theta_meas: vec![0.1, 0.2],
                ..Telemetry::default()
            });
        }
        // Each tick's four messages and tick 0's scene.
        let written = 3 * 4 + 1;
        // A guard against hanging, not a measure of speed: it takes two waits of 10 ms.
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        let flushed = loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match flushes.recv_timeout(left) {
                Ok(n) if n == written => break true,
                Ok(_) => {}
                Err(_) => break false,
            }
        };
        let _ = recorder.close();
        assert!(flushed, "the three ticks were not flushed before the close");
    }
}
