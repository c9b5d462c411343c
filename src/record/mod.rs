//! Recordings of a run, as MCAP: what `snakectl run --record FILE.mcap` writes, Foxglove opens
//! and `ros2 bag` reads.
//!
//! - [`schema`]: the channels: topics, ROS 2 message definitions (`ros2msg`), JSON Schemas.
//! - [`tap`]: the hand-over from the control loop: bounded, drop-oldest, counted, never
//!   blocking the loop, allocating nothing per tick.
//! - [`sink`]: where a recording goes: any channel by topic, schema and encodings, messages,
//!   metadata; an MCAP file through the `mcap` crate.
//! - [`recorder`]: the thread that writes what the loop hands over: one `JointState`, two tips,
//!   the target and the telemetry per tick, each event, the config, and on close the account of
//!   what was offered, written and dropped.
//! - [`read`]: a recording read back: messages, metadata, telemetry, events, and the demo's
//!   figures drawn from any recording with uncompressed chunks (as snakectl writes them).
//!
//! The recording rate is the loop's: every tick is offered, so "messages written = ticks run
//! minus the counted drops" holds per channel.

pub mod read;
pub mod recorder;
pub mod schema;
pub mod sink;
pub mod tap;

pub use read::Recording;
pub use recorder::{Notes, RecordOptions, RecordSummary, Recorder, Setup};
pub use sink::{McapSink, RecordError, Sink};
pub use tap::Tap;
