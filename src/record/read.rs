//! Reading a recording back: its channels and messages, its metadata records, the telemetry and
//! events in it, and the demo's figures' data ([`crate::plot::demo::Record`]) drawn from it.
//!
//! Any recording can be drawn: the arm comes from its description (`snakectl.describe`) or,
//! failing that, from the config it ran with (`snakectl.config`); the samples from the
//! telemetry; the estops and resets from the events, the obstacles from the `world` events.
//! The phases pictured are the recording's own (`snakectl.phase` records, which the demo
//! writes) or, in any other recording, its stretches of motion: at most
//! [`MAX_PICTURED`], a pause shorter than [`PAUSE_S`] not splitting one.

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
}

impl Recording {
    /// Reads the MCAP file at `path`.
    pub fn open(path: &Path) -> Result<Recording, RecordError> {
        let failed = |message: String| RecordError::Read {
            path: path.to_path_buf(),
            message,
        };
        let bytes = std::fs::read(path).map_err(|e| failed(e.to_string()))?;
        let mut channels: BTreeMap<String, Channel> = BTreeMap::new();
        let stream = mcap::MessageStream::new(&bytes).map_err(|e| failed(e.to_string()))?;
        for message in stream {
            let message = message.map_err(|e| failed(e.to_string()))?;
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
            if let mcap::records::Record::Metadata(m) = record.map_err(|e| failed(e.to_string()))? {
                metadata.push((m.name, m.metadata));
            }
        }
        Ok(Recording {
            path: path.to_path_buf(),
            channels,
            metadata,
        })
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
/// and strategies.
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
            let (t_a, t_b) = (telemetry[a].t_s - t0, telemetry[b].t_s - t0);
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
