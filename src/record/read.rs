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
//!
//! Only a regular file is read (a device or a FIFO is refused unopened), and at most the bytes
//! it holds when opened. Its records' framing (an opcode byte and a little-endian `u64` length
//! each, and inside an uncompressed chunk the same) is walked before the `mcap` crate sees the
//! file (`framing`), so that a length the file cannot hold is a cut or damaged file, never a
//! length the crate computes with. Chunks must be uncompressed, as snakectl writes them: this
//! build has no zstd or lz4.

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

/// The 8 bytes an MCAP file begins and ends with.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
/// Opcode and length before each record, bytes.
const RECORD_HEAD: usize = 9;
/// The chunk record's opcode.
const OP_CHUNK: u8 = 0x06;
/// The footer record's opcode: the last record of a file.
const OP_FOOTER: u8 = 0x02;
/// A chunk's header up to its compression's name: start and end times, uncompressed size and
/// CRC, the name's length; then, after the name, the size of its records (`u64`).
const CHUNK_HEAD: usize = 8 + 8 + 8 + 4 + 4;

/// What walking the records of a file found ([`framing`]).
#[derive(Debug, Clone, PartialEq, Eq)]
enum Framing {
    /// Every record lies within the file, up to its footer.
    Whole,
    /// The file ends before its records do, at the record that begins at byte `at`: the bytes
    /// before it are whole records.
    EndsEarly {
        /// Where the first incomplete record begins.
        at: usize,
        /// What is missing.
        reason: String,
    },
    /// A whole record whose own lengths contradict each other, or not an MCAP file.
    Damaged(String),
    /// A chunk compressed (zstd, lz4): not readable by this build.
    Compressed {
        /// Where the chunk begins.
        at: usize,
        /// Its compression, as the file names it.
        compression: String,
    },
}

/// A little-endian `u64` at `at` in `bytes` (`None` past their end).
fn u64_at(bytes: &[u8], at: usize) -> Option<u64> {
    let b = bytes.get(at..at.checked_add(8)?)?;
    Some(u64::from_le_bytes(b.try_into().ok()?))
}

/// A little-endian `u32` at `at` in `bytes` (`None` past their end).
fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes(b.try_into().ok()?))
}

/// Walks the records of an MCAP file (`bytes`, whole) from its magic to its footer, checking
/// that each record's length fits in what remains of the file and, in an uncompressed chunk,
/// that its records fill it exactly. The `mcap` crate is then given only bytes whose framing
/// holds (it would compute with any length, `u64::MAX` included).
fn framing(bytes: &[u8]) -> Framing {
    if bytes.len() < MAGIC.len() {
        return if MAGIC.starts_with(bytes) {
            Framing::EndsEarly {
                at: 0,
                reason: format!("the file ends within its first 8 bytes ({})", bytes.len()),
            }
        } else {
            Framing::Damaged("not an MCAP file (it does not begin with the MCAP magic)".into())
        };
    }
    if !bytes.starts_with(MAGIC) {
        return Framing::Damaged("not an MCAP file (it does not begin with the MCAP magic)".into());
    }
    let mut at = MAGIC.len();
    loop {
        let rest = bytes.len() - at;
        if rest == 0 {
            return Framing::EndsEarly {
                at,
                reason: format!("the file ends after its record at byte {at} without its footer"),
            };
        }
        let (Some(&opcode), Some(len)) = (bytes.get(at), u64_at(bytes, at + 1)) else {
            return Framing::EndsEarly {
                at,
                reason: format!("the record at byte {at} is cut in its opcode and length"),
            };
        };
        let room = (rest - RECORD_HEAD) as u64;
        if len > room {
            // A chunk cut short is read up to its last whole record.
            let whole = match opcode {
                OP_CHUNK => match cut_chunk(&bytes[at + RECORD_HEAD..], at) {
                    Ok(end) => end,
                    Err(fault) => return fault,
                },
                _ => at,
            };
            return Framing::EndsEarly {
                at: whole,
                reason: format!(
                    "the record at byte {at} (opcode 0x{opcode:02x}) claims {len} bytes, \
                     {room} remain in the file"
                ),
            };
        }
        // `len <= room`, which is a `usize`.
        let body = &bytes[at + RECORD_HEAD..at + RECORD_HEAD + len as usize];
        match opcode {
            OP_FOOTER => return Framing::Whole,
            OP_CHUNK => {
                if let Some(fault) = chunk_framing(body, at) {
                    return fault;
                }
            }
            _ => {}
        }
        at += RECORD_HEAD + body.len();
    }
}

/// The fault in the framing of the chunk whose record begins at byte `at` and whose body is
/// `body`, if any: its header longer than its body, its records' size beyond what follows the
/// header, a record in it that runs past the chunk's records.
fn chunk_framing(body: &[u8], at: usize) -> Option<Framing> {
    let damaged = |what: String| Some(Framing::Damaged(format!("the chunk at byte {at}: {what}")));
    let Some(name_len) = u32_at(body, CHUNK_HEAD - 4) else {
        return damaged(format!(
            "{} bytes, too short for a chunk's header",
            body.len()
        ));
    };
    let name_end = CHUNK_HEAD.saturating_add(name_len as usize);
    let (Some(name), Some(size)) = (body.get(CHUNK_HEAD..name_end), u64_at(body, name_end)) else {
        return damaged(format!(
            "its compression's name of {name_len} bytes runs past its {} bytes",
            body.len()
        ));
    };
    let records_at = name_end + 8;
    let room = (body.len() - records_at) as u64;
    if size > room {
        return damaged(format!(
            "its records claim {size} bytes, {room} follow its header"
        ));
    }
    if !name.is_empty() {
        return Some(Framing::Compressed {
            at,
            compression: String::from_utf8_lossy(name).into_owned(),
        });
    }
    // `size <= room`, which is a `usize`.
    let records = &body[records_at..records_at + size as usize];
    let mut k = 0;
    while k < records.len() {
        let rest = records.len() - k;
        let Some(len) = u64_at(records, k + 1) else {
            return damaged(format!(
                "a record {k} bytes into its records is cut in its opcode and length"
            ));
        };
        let room = (rest - RECORD_HEAD) as u64;
        if len > room {
            return damaged(format!(
                "a record {k} bytes into its records claims {len} bytes, {room} remain in the \
                 chunk"
            ));
        }
        k += RECORD_HEAD + len as usize;
    }
    None
}

/// Where the whole records of the chunk at byte `at`, cut short by the end of the file, end
/// (`body`: the part of its body the file holds): the chunk's own start when not even its
/// header is there, or when it is compressed; a record that runs past the chunk's own size of
/// records is damage.
fn cut_chunk(body: &[u8], at: usize) -> Result<usize, Framing> {
    let records_at = match u32_at(body, CHUNK_HEAD - 4) {
        Some(0) => CHUNK_HEAD + 8,
        _ => return Ok(at),
    };
    let Some(size) = u64_at(body, CHUNK_HEAD) else {
        return Ok(at);
    };
    let present = &body[records_at.min(body.len())..];
    let start = at + RECORD_HEAD + records_at;
    let mut k = 0usize;
    loop {
        if k as u64 >= size {
            return Ok(start + k);
        }
        let Some(len) = u64_at(present, k + 1) else {
            return Ok(start + k);
        };
        let declared = size - k as u64;
        if declared < RECORD_HEAD as u64 || len > declared - RECORD_HEAD as u64 {
            return Err(Framing::Damaged(format!(
                "the chunk at byte {at}: a record {k} bytes into its records claims {len} \
                 bytes, {} remain in the chunk",
                declared.saturating_sub(RECORD_HEAD as u64)
            )));
        }
        if len > (present.len() - k - RECORD_HEAD) as u64 {
            return Ok(start + k);
        }
        k += RECORD_HEAD + len as usize;
    }
}

/// The bytes of the regular file at `path`, at most as many as it holds when opened (a file
/// still growing is read up to there).
fn read_regular(path: &Path) -> Result<Vec<u8>, String> {
    let file = crate::textfile::open_regular(path).map_err(|e| e.to_string())?;
    let len = file.metadata().map_err(|e| e.to_string())?.len();
    let mut bytes = Vec::new();
    usize::try_from(len)
        .ok()
        .and_then(|n| bytes.try_reserve_exact(n).ok())
        .ok_or_else(|| format!("{len} bytes, more than can be held in memory here"))?;
    std::io::Read::read_to_end(&mut std::io::Read::take(file, len), &mut bytes)
        .map_err(|e| e.to_string())?;
    Ok(bytes)
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
        let bytes = read_regular(path).map_err(failed)?;
        // A file its writer closed ends with a footer: one that ends early in spite of it is
        // damaged, not cut short.
        let closed = mcap::read::footer(&bytes).is_ok();
        // The crate reads only the whole records, up to where a file cut short ends early.
        let (readable, mut cut) = match framing(&bytes) {
            Framing::Whole => (&bytes[..], None),
            Framing::EndsEarly { at, reason } if !closed => (&bytes[..at], Some(reason)),
            Framing::EndsEarly { reason, .. } => {
                return Err(failed(format!(
                    "{reason}, in a file its writer closed (it has its footer): the file is \
                     damaged"
                )))
            }
            Framing::Damaged(reason) => {
                return Err(failed(format!("{reason}: the file is damaged")))
            }
            Framing::Compressed { at, compression } => {
                return Err(failed(format!(
                    "its chunk at byte {at} is compressed ({compression}): only uncompressed \
                     recordings are read, as snakectl writes them (`mcap compress \
                     --compression none` makes one)"
                )))
            }
        };
        let bytes = readable;
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
        let stream = mcap::MessageStream::new(bytes).map_err(|e| failed(e.to_string()))?;
        for message in stream {
            let message = match message {
                Ok(m) => m,
                Err(e) => {
                    let reason = cut_short(e)?;
                    cut.get_or_insert(reason);
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
        let reader = mcap::read::LinearReader::new(bytes).map_err(|e| failed(e.to_string()))?;
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
                "{reason}, before any message: the file is damaged, or the writer did not \
                 close the file (killed?); `mcap recover` (the MCAP command-line tool) may \
                 rebuild it"
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
    #![allow(clippy::unwrap_used, clippy::expect_used)]
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

    /// The offsets of the chunk records of an MCAP file, in order.
    fn chunks_of(bytes: &[u8]) -> Vec<usize> {
        let (mut at, mut found) = (8, Vec::new());
        while bytes[at] != OP_FOOTER {
            if bytes[at] == OP_CHUNK {
                found.push(at);
            }
            at += 9 + u64_at(bytes, at + 1).unwrap() as usize;
        }
        found
    }

    /// A closed recording of three chunks of ten messages each.
    fn three_chunks(path: &Path) -> Vec<u8> {
        let mut sink = McapSink::create(path, true).unwrap();
        let channel = sink.add_channel(&spec()).unwrap();
        for i in 0..30 {
            sink.write(channel, i, b"{}").unwrap();
            if i % 10 == 9 {
                sink.flush().unwrap();
            }
        }
        sink.finish().unwrap();
        std::fs::read(path).unwrap()
    }

    /// A record length of `u64::MAX` (the `mcap` crate adds the 9 bytes of opcode and length
    /// to it, wrapping round) in a file of 17 bytes, in a closed recording, and inside a chunk
    /// whose CRC is 0 (not checked): each refused with the record named, no panic.
    #[test]
    fn a_record_length_beyond_the_file_is_refused_not_wrapped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.mcap");
        let mut tiny = MAGIC.to_vec();
        tiny.push(0x01);
        tiny.extend_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&path, &tiny).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(
            e.contains("the record at byte 8 (opcode 0x01) claims 18446744073709551615 bytes"),
            "{e}"
        );

        let whole = three_chunks(&path);
        // The second record (a schema or a channel, after the header) made endless.
        let mut bytes = whole.clone();
        let second = 8 + 9 + u64_at(&bytes, 9).unwrap() as usize;
        bytes[second + 1..second + 9].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(e.contains("claims 18446744073709551615 bytes"), "{e}");
        assert!(e.contains("the file is damaged"), "{e}");

        // Inside the second chunk: its CRC 0, its first record endless.
        let mut bytes = whole.clone();
        let chunk = chunks_of(&bytes)[1];
        let body = chunk + 9;
        bytes[body + 24..body + 28].copy_from_slice(&0u32.to_le_bytes());
        let name_len = u32_at(&bytes, body + 28).unwrap() as usize;
        let first = body + CHUNK_HEAD + name_len + 8;
        bytes[first + 1..first + 9].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(
            e.contains(&format!("the chunk at byte {chunk}")) && e.contains("the file is damaged"),
            "{e}"
        );
        assert!(e.contains("claims 18446744073709551615 bytes"), "{e}");
    }

    #[test]
    fn framing_tells_a_cut_file_from_a_damaged_one() {
        let dir = tempfile::tempdir().unwrap();
        let whole = three_chunks(&dir.path().join("f.mcap"));
        assert_eq!(framing(&whole), Framing::Whole);
        // Cut in the third chunk's header: whole records up to its start; in its records:
        // up to the last whole one.
        let third = chunks_of(&whole)[2];
        match framing(&whole[..third + 20]) {
            Framing::EndsEarly { at, .. } => assert_eq!(at, third),
            other => panic!("{other:?}"),
        }
        let records = third + 9 + CHUNK_HEAD + 8;
        let first_len = u64_at(&whole, records + 1).unwrap() as usize;
        let second = records + 9 + first_len;
        match framing(&whole[..second + 5]) {
            Framing::EndsEarly { at, .. } => assert_eq!(at, second),
            other => panic!("{other:?}"),
        }
        // Cut in a record's opcode and length, and at a record's end without a footer.
        assert!(matches!(
            framing(&whole[..third + 4]),
            Framing::EndsEarly { at, .. } if at == third
        ));
        assert!(matches!(
            framing(&whole[..third]),
            Framing::EndsEarly { at, .. } if at == third
        ));
        assert!(matches!(
            framing(&MAGIC[..5]),
            Framing::EndsEarly { at: 0, .. }
        ));
        assert!(matches!(framing(b"PK\x03\x04 a zip"), Framing::Damaged(_)));
        // A chunk whose records claim more than the chunk holds.
        let mut bytes = whole.clone();
        let body = chunks_of(&bytes)[0] + 9;
        let name_len = u32_at(&bytes, body + 28).unwrap() as usize;
        let size_at = body + CHUNK_HEAD + name_len;
        bytes[size_at..size_at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        assert!(matches!(framing(&bytes), Framing::Damaged(_)));
    }

    /// A chunk compressed (zstd, the default of other writers) is refused naming its
    /// compression and how to make an uncompressed copy.
    #[test]
    fn a_compressed_chunk_is_refused_saying_how_to_read_it() {
        let record = |op: u8, body: &[u8]| {
            let mut r = vec![op];
            r.extend_from_slice(&(body.len() as u64).to_le_bytes());
            r.extend_from_slice(body);
            r
        };
        let mut chunk = vec![0u8; 28];
        chunk.extend_from_slice(&4u32.to_le_bytes());
        chunk.extend_from_slice(b"zstd");
        chunk.extend_from_slice(&3u64.to_le_bytes());
        chunk.extend_from_slice(b"xyz");
        let mut bytes = MAGIC.to_vec();
        bytes.extend(record(0x01, &[0; 8]));
        bytes.extend(record(OP_CHUNK, &chunk));
        bytes.extend(record(OP_FOOTER, &[0; 20]));
        bytes.extend_from_slice(MAGIC);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("z.mcap");
        std::fs::write(&path, &bytes).unwrap();
        let e = Recording::open(&path).unwrap_err().to_string();
        assert!(e.contains("chunk at byte 25 is compressed (zstd)"), "{e}");
        assert!(e.contains("mcap compress"), "{e}");
    }

    /// What is not a regular file is refused unopened, or opened without blocking: a device
    /// (read whole before, `/dev/zero` without end), a FIFO (opening one blocked for ever).
    #[test]
    fn only_a_regular_file_is_read() {
        let e = Recording::open(Path::new("/dev/null"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a character device, not a regular file"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo.mcap");
        crate::textfile::make_fifo(&fifo);
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(
                Recording::open(&fifo)
                    .map(|_| ())
                    .map_err(|e| e.to_string()),
            );
        });
        // A bound on a test that would otherwise never end, not a speed asked for.
        let e = rx
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("opening a FIFO blocked")
            .unwrap_err();
        assert!(e.contains("a FIFO (named pipe), not a regular file"), "{e}");
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
