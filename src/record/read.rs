//! Reading a recording back: its channels and messages, its metadata records, the telemetry and
//! events in it, and the demo's figures' data ([`crate::plot::demo::Record`]) drawn from it.
//!
//! Any recording can be drawn: the arm comes from its description (`snakectl.describe`) or,
//! failing that, from the config it ran with (`snakectl.config`); the samples from the
//! telemetry; the estops and resets from the events, the obstacles from the `world` events.
//! The phases pictured are the recording's own (`snakectl.phase` records, which the demo
//! writes) or, in any other recording, its stretches of motion: at most
//! [`MAX_PICTURED`], a pause shorter than [`PAUSE_S`] not splitting one; a recording in which
//! the arm never moved is one phase, at rest.
//!
//! A file whose writer did not close it (the process killed) ends in the middle of a record:
//! what it holds up to there is read ([`Recording::cut`] says so), the rest is lost.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::sink::RecordError;
use crate::chain::Chain;
use crate::client::ArmInfo;
use crate::config::Config;
use crate::plot::demo::{Event as PlotEvent, Phase, Record, Sample};
use crate::protocol::{self, Describe, Event, ServerLine, State, Telemetry, What};
use crate::world::World;

/// Phases pictured at most when a recording has none of its own.
pub const MAX_PICTURED: usize = 4;

/// A pause in the motion shorter than this, s, does not split a phase.
pub const PAUSE_S: f64 = 1.0;

/// A phase shorter than this, s (a motion ended a few ticks after it began), is widened about
/// its middle to this, within the recording, so that its band and its tip's trace are seen.
pub const MIN_PHASE_S: f64 = 0.5;

/// One message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    /// When it was logged, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Its bytes.
    pub data: Vec<u8>,
}

/// One channel and its messages, in the file's order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    /// Its topic.
    pub topic: String,
    /// Its schema's name.
    pub schema_name: String,
    /// Its schema's encoding.
    pub schema_encoding: String,
    /// Its messages' encoding.
    pub message_encoding: String,
    /// Its messages.
    pub messages: Vec<Message>,
}

/// A recording, read whole.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The file.
    pub path: PathBuf,
    /// Channels by topic.
    pub channels: BTreeMap<String, Channel>,
    /// Metadata records (name, entries), in the file's order.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Why the file ended early, when it did (`None`: read whole): it ends in the middle of a
    /// record, its writer never having closed it. What is above was read up to there; whatever
    /// the writer had begun after the last complete record or chunk is lost.
    pub cut: Option<String>,
}

/// Whether `e` says the file of `file_len` bytes ends before its records do: in the middle of
/// one, or in a chunk the writer began and never finished (its lengths still the placeholders,
/// all ones, written first), or with a record longer than the whole file.
fn ends_early(e: &mcap::McapError, file_len: usize) -> bool {
    match e {
        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => true,
        mcap::McapError::RecordTooLarge { len, .. } => {
            usize::try_from(*len).map_or(true, |len| len > file_len)
        }
        _ => false,
    }
}

impl Recording {
    /// Reads the MCAP file at `path`. A file that ends in the middle of a record (its writer
    /// did not close it) is read up to there, [`Recording::cut`] saying so, unless nothing at
    /// all could be read from it.
    pub fn open(path: &Path) -> Result<Recording, RecordError> {
        let failed = |message: String| RecordError::Read {
            path: path.to_path_buf(),
            message,
        };
        let bytes = std::fs::read(path).map_err(|e| failed(e.to_string()))?;
        // A file its writer closed ends with a footer: one that ends early in spite of it is
        // damaged, not cut short.
        let closed = mcap::read::footer(&bytes).is_ok();
        // An error that ends the reading where the file ends early: why, to keep reading what
        // came before it; any other, or one in a file its writer closed, refuses the file.
        let cut_short = |e: mcap::McapError| -> Result<String, RecordError> {
            match (ends_early(&e, bytes.len()), closed) {
                (true, false) => Ok(e.to_string()),
                (true, true) => Err(failed(format!(
                    "{e}, in a file its writer closed (it has its footer): the file is damaged"
                ))),
                (false, _) => Err(failed(e.to_string())),
            }
        };
        let mut channels: BTreeMap<String, Channel> = BTreeMap::new();
        let mut cut = None;
        let stream = mcap::MessageStream::new(&bytes).map_err(|e| failed(e.to_string()))?;
        for message in stream {
            let message = match message {
                Ok(m) => m,
                Err(e) => {
                    cut = Some(cut_short(e)?);
                    break;
                }
            };
            let c = &message.channel;
            let channel = channels.entry(c.topic.clone()).or_insert_with(|| Channel {
                topic: c.topic.clone(),
                schema_name: c
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                schema_encoding: c
                    .schema
                    .as_ref()
                    .map(|s| s.encoding.clone())
                    .unwrap_or_default(),
                message_encoding: c.message_encoding.clone(),
                messages: Vec::new(),
            });
            channel.messages.push(Message {
                log_time_ns: message.log_time,
                data: message.data.into_owned(),
            });
        }
        let mut metadata = Vec::new();
        let reader = mcap::read::LinearReader::new(&bytes).map_err(|e| failed(e.to_string()))?;
        for record in reader {
            match record {
                Ok(mcap::records::Record::Metadata(m)) => metadata.push((m.name, m.metadata)),
                Ok(_) => {}
                Err(e) => {
                    let reason = cut_short(e)?;
                    cut.get_or_insert(reason);
                    break;
                }
            }
        }
        if let (Some(reason), true) = (&cut, channels.is_empty() && metadata.is_empty()) {
            return Err(failed(format!(
                "{reason}, before any message: the writer did not close the file (killed?); \
                 `mcap recover` (the MCAP command-line tool) may rebuild it"
            )));
        }
        Ok(Recording {
            path: path.to_path_buf(),
            channels,
            metadata,
            cut,
        })
    }

    /// The messages read, over every channel.
    pub fn message_count(&self) -> usize {
        self.channels.values().map(|c| c.messages.len()).sum()
    }

    /// The first metadata record named `name`.
    pub fn metadata(&self, name: &str) -> Option<&BTreeMap<String, String>> {
        self.metadata
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, entries)| entries)
    }

    /// The channel whose schema is `schema_name` (the first, by topic).
    pub fn channel_of(&self, schema_name: &str) -> Option<&Channel> {
        self.channels
            .values()
            .find(|c| c.schema_name == schema_name)
    }

    /// The telemetry snapshots, in order (lines that cannot be read are skipped).
    pub fn telemetry(&self) -> Vec<Telemetry> {
        self.lines("snakectl.Telemetry")
            .filter_map(|line| match line {
                ServerLine::Telemetry(status) => Some(status.telemetry),
                _ => None,
            })
            .collect()
    }

    /// The events, in order (lines that cannot be read are skipped).
    pub fn events(&self) -> Vec<Event> {
        self.lines("snakectl.Event")
            .filter_map(|line| match line {
                ServerLine::Event(e) => Some(e),
                _ => None,
            })
            .collect()
    }

    fn lines(&self, schema_name: &str) -> impl Iterator<Item = ServerLine> + '_ {
        self.channel_of(schema_name)
            .into_iter()
            .flat_map(|c| &c.messages)
            .filter_map(|m| std::str::from_utf8(&m.data).ok())
            .filter_map(|text| protocol::read_line(text).ok())
    }

    /// The arm, from its description or else from the config the run used.
    pub fn chain(&self) -> Option<Chain> {
        let described = self
            .metadata("snakectl.describe")
            .and_then(|m| m.get("describe"))
            .and_then(|json| serde_json::from_str::<Describe>(json).ok())
            .and_then(|d| ArmInfo::new(d).ok())
            .map(|arm| arm.chain().clone());
        described.or_else(|| {
            let config = self.metadata("snakectl.config")?;
            let text = config.get("toml")?;
            let path = config.get("path").map_or("recording", String::as_str);
            Config::from_str(text, path).ok().map(|c| c.chain().clone())
        })
    }

    /// What the demo's figures draw, from this recording; times from its first sample.
    pub fn plot_record(&self) -> Record {
        let telemetry = self.telemetry();
        let events = self.events();
        let t0 = telemetry.first().map_or(0.0, |t| t.t_s);
        let rate_hz = rate_of(&telemetry);
        let samples: Vec<Sample> = telemetry
            .iter()
            .map(|t| Sample {
                t_s: t.t_s - t0,
                theta: t.theta_meas.clone(),
                tip_ref: t.tip_ref,
                tip_meas: t.tip_meas,
                tracking_error_m: t.tracking_error_m,
            })
            .collect();
        let tip_at = |t_s: f64| {
            samples
                .iter()
                .find(|s| s.t_s >= t_s)
                .or(samples.last())
                .map_or([0.0; 2], |s| s.tip_meas)
        };
        let marks = events
            .iter()
            .filter_map(|e| {
                let label = match e.what {
                    What::Estop { .. } => "estop",
                    What::Reset { .. } => "reset",
                    _ => return None,
                };
                let t_s = e.tick as f64 / rate_hz - t0;
                Some(PlotEvent {
                    label: label.into(),
                    t_s,
                    tip: tip_at(t_s),
                })
            })
            .collect();
        let worlds: Vec<(f64, Option<World>)> = events
            .iter()
            .filter_map(|e| match &e.what {
                What::World { world, .. } => Some((
                    e.tick as f64 / rate_hz - t0,
                    world.to_world().ok().filter(|w| !w.obstacles().is_empty()),
                )),
                _ => None,
            })
            .collect();
        let mut phases = self.own_phases(t0);
        if phases.is_empty() {
            phases = moving_phases(&telemetry, t0);
        }
        for phase in &mut phases {
            // The obstacles in force at the phase's end.
            phase.world = worlds
                .iter()
                .rev()
                .find(|(t, _)| *t <= phase.t1)
                .and_then(|(_, w)| w.clone());
        }
        Record {
            chain: self.chain(),
            samples,
            phases,
            events: marks,
        }
    }

    /// The phases the recording names (`snakectl.phase`), times from `t0`.
    fn own_phases(&self, t0: f64) -> Vec<Phase> {
        self.metadata
            .iter()
            .filter(|(name, _)| name == "snakectl.phase")
            .filter_map(|(_, m)| {
                let number = |key: &str| m.get(key)?.parse::<f64>().ok();
                Some(Phase {
                    label: m.get("label")?.clone(),
                    t0: number("t0_s")? - t0,
                    t1: number("t1_s")? - t0,
                    reference: m
                        .get("reference")
                        .and_then(|r| serde_json::from_str(r).ok())
                        .unwrap_or_default(),
                    pictured: m.get("pictured").is_some_and(|p| p == "true"),
                    world: None,
                })
            })
            .collect()
    }
}

/// The metadata record of a phase, as [`Recording::plot_record`] reads it (times in the
/// daemon's `t_s`).
pub fn phase_note(phase: &Phase) -> BTreeMap<String, String> {
    BTreeMap::from([
        ("label".to_owned(), phase.label.clone()),
        ("t0_s".to_owned(), format!("{:?}", phase.t0)),
        ("t1_s".to_owned(), format!("{:?}", phase.t1)),
        (
            "reference".to_owned(),
            serde_json::to_string(&phase.reference).unwrap_or_else(|_| "[]".into()),
        ),
        ("pictured".to_owned(), phase.pictured.to_string()),
    ])
}

/// The loop's rate, from the ticks and times of the snapshots (100 Hz when they do not say).
fn rate_of(telemetry: &[Telemetry]) -> f64 {
    telemetry
        .iter()
        .rev()
        .find(|t| t.tick > 0 && t.t_s > 0.0)
        .map_or(100.0, |t| t.tick as f64 / t.t_s)
}

/// The stretches in which the arm moved (a pause shorter than [`PAUSE_S`] joins two), at most
/// [`MAX_PICTURED`] (the nearest stretches merged), each pictured and labelled with its times
/// and strategies; when it never moved, the whole recording, labelled "at rest".
fn moving_phases(telemetry: &[Telemetry], t0: f64) -> Vec<Phase> {
    let mut stretches: Vec<(usize, usize)> = Vec::new();
    for (i, t) in telemetry.iter().enumerate() {
        if !matches!(t.state, State::Moving | State::Stopping) {
            continue;
        }
        match stretches.last_mut() {
            Some((_, end)) if t.t_s - telemetry[*end].t_s < PAUSE_S => *end = i,
            _ => stretches.push((i, i)),
        }
    }
    if let (true, Some(last)) = (stretches.is_empty(), telemetry.last()) {
        // The arm never moved: the whole recording is one phase, so that the figures still show
        // the arm (at rest) and its flat joint angles.
        let (t_a, t_b) = (telemetry[0].t_s - t0, last.t_s - t0);
        return vec![Phase {
            label: format!("{t_a:.1}-{t_b:.1} s, at rest"),
            t0: t_a,
            t1: t_b,
            reference: Vec::new(),
            pictured: true,
            world: None,
        }];
    }
    while stretches.len() > MAX_PICTURED {
        // Merge the pair with the shortest pause between them.
        let k = (0..stretches.len() - 1)
            .min_by(|&a, &b| {
                let gap =
                    |k: usize| telemetry[stretches[k + 1].0].t_s - telemetry[stretches[k].1].t_s;
                gap(a).total_cmp(&gap(b))
            })
            .unwrap_or(0);
        stretches[k].1 = stretches[k + 1].1;
        stretches.remove(k + 1);
    }
    stretches
        .into_iter()
        .map(|(a, b)| {
            let mut strategies: Vec<&str> = Vec::new();
            for t in &telemetry[a..=b] {
                let name = t.strategy.name();
                if !strategies.contains(&name) {
                    strategies.push(name);
                }
            }
            let (t_a, t_b) = widened(
                (telemetry[a].t_s - t0, telemetry[b].t_s - t0),
                (
                    telemetry[0].t_s - t0,
                    telemetry[telemetry.len() - 1].t_s - t0,
                ),
            );
            Phase {
                label: format!("{t_a:.1}-{t_b:.1} s, {}", strategies.join(", ")),
                t0: t_a,
                t1: t_b,
                reference: Vec::new(),
                pictured: true,
                world: None,
            }
        })
        .collect()
}

/// `(t_a, t_b)` widened about its middle to at least [`MIN_PHASE_S`], kept within `(lo, hi)`
/// (shifted rather than cut where it can be).
fn widened((t_a, t_b): (f64, f64), (lo, hi): (f64, f64)) -> (f64, f64) {
    let short = MIN_PHASE_S - (t_b - t_a);
    if short <= 0.0 {
        return (t_a, t_b);
    }
    let (mut a, mut b) = (t_a - 0.5 * short, t_b + 0.5 * short);
    if a < lo {
        (a, b) = (lo, b + (lo - a));
    }
    if b > hi {
        (a, b) = ((a - (b - hi)).max(lo), hi);
    }
    (a, b)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::record::schema::ChannelSpec;

    #[test]
    fn a_phase_of_a_few_ticks_is_widened_within_the_recording() {
        assert_eq!(widened((18.90, 18.93), (0.0, 40.0)), (18.665, 19.165));
        // At the start of the recording it is shifted, not cut.
        assert_eq!(widened((0.0, 0.1), (0.0, 40.0)), (0.0, 0.5));
        // A recording shorter than the least phase gives all it has.
        assert_eq!(widened((0.1, 0.2), (0.0, 0.3)), (0.0, 0.3));
        // A phase long enough stays as it is.
        assert_eq!(widened((3.0, 9.0), (0.0, 40.0)), (3.0, 9.0));
    }
    use crate::record::sink::{McapSink, Sink};

    fn spec() -> ChannelSpec {
        ChannelSpec {
            topic: "/t".into(),
            schema_name: "s".into(),
            schema_encoding: "jsonschema".into(),
            schema: b"{}".to_vec(),
            message_encoding: "json".into(),
            metadata: BTreeMap::new(),
        }
    }

    /// Writes 30 messages on one channel, a flush (the chunk ended) after each 10, straight to
    /// the file (no buffer, as a killed process leaves it), and abandons the writer with the
    /// fourth chunk begun: its header still holds the placeholder lengths.
    fn killed_writer(path: &Path) {
        let mut sink = McapSink::new(std::fs::File::create(path).unwrap()).unwrap();
        sink.metadata("note", &BTreeMap::from([("k".into(), "v".into())]))
            .unwrap();
        let channel = sink.add_channel(&spec()).unwrap();
        for i in 0..35u64 {
            sink.write(channel, i, b"{}").unwrap();
            if i % 10 == 9 {
                sink.flush().unwrap();
            }
        }
        std::mem::forget(sink);
    }

    #[test]
    fn a_file_its_writer_never_closed_is_read_up_to_its_last_whole_chunk() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("killed.mcap");
        killed_writer(&path);
        let r = Recording::open(&path).unwrap();
        assert_eq!(r.message_count(), 30);
        assert!(r.cut.is_some());
        assert_eq!(r.metadata("note").unwrap()["k"], "v");
        // Cut anywhere in its last chunk: the same.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let r = Recording::open(&path).unwrap();
        assert_eq!(r.message_count(), 30);
        assert!(r.cut.is_some());
    }

    #[test]
    fn a_file_cut_before_any_message_is_refused_naming_mcap_recover() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cut.mcap");
        killed_writer(&path);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..12]).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(e.contains("did not close the file"), "{e}");
        assert!(e.contains("`mcap recover`"), "{e}");
    }

    /// A recording in which the arm never moved is one phase, at rest, and both figures draw.
    #[test]
    fn an_arm_at_rest_is_one_phase_and_draws() {
        let telemetry: Vec<Telemetry> = (0..400)
            .map(|i| Telemetry {
                tick: i,
                t_s: 5.0 + i as f64 * 0.01,
                theta_meas: vec![0.1, -0.2, 0.3],
                ..Telemetry::default()
            })
            .collect();
        let phases = moving_phases(&telemetry, 5.0);
        assert_eq!(phases.len(), 1);
        let phase = &phases[0];
        assert!(phase.pictured);
        assert_eq!(
            (phase.t0, phase.label.as_str()),
            (0.0, "0.0-4.0 s, at rest")
        );
        assert!((phase.t1 - 3.99).abs() < 1e-9);
        let record = Record {
            chain: None,
            samples: telemetry
                .iter()
                .map(|t| Sample {
                    t_s: t.t_s - 5.0,
                    theta: t.theta_meas.clone(),
                    ..Sample::default()
                })
                .collect(),
            phases,
            events: Vec::new(),
        };
        assert!(crate::plot::demo::motion(&record, "t").is_ok());
        assert!(crate::plot::demo::joints(&record, "t").is_ok());
    }

    /// A closed file (its footer there) that ends a record early in the middle is damaged:
    /// refused, not read in part.
    #[test]
    fn a_closed_file_damaged_inside_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("damaged.mcap");
        let mut sink = McapSink::create(&path, false).unwrap();
        let channel = sink.add_channel(&spec()).unwrap();
        for i in 0..20 {
            sink.write(channel, i, b"{}").unwrap();
            if i % 10 == 9 {
                sink.flush().unwrap();
            }
        }
        sink.finish().unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        // The second chunk's record length made far longer than the file: records are an
        // opcode (a chunk's is 6) and a length after the 8 magic bytes.
        let (mut at, mut chunks) = (8, 0);
        loop {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            if bytes[at] == 6 {
                chunks += 1;
                if chunks == 2 {
                    break;
                }
            }
            at += 9 + len;
        }
        bytes[at + 1..at + 9].copy_from_slice(&(1u64 << 40).to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(e.contains("the file is damaged"), "{e}");
    }

    #[test]
    fn a_whole_file_is_not_cut() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("whole.mcap");
        let mut sink = McapSink::create(&path, false).unwrap();
        let channel = sink.add_channel(&spec()).unwrap();
        sink.write(channel, 1, b"{}").unwrap();
        sink.finish().unwrap();
        let r = Recording::open(&path).unwrap();
        assert_eq!((r.message_count(), r.cut), (1, None));
    }
}
