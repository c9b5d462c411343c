//! Where a recording goes: the [`Sink`] trait (channels, messages, metadata records, flushes),
//! and [`McapSink`], an MCAP file through the `mcap` crate, uncompressed (its compressors are C
//! code), chunked (a chunk ends at each flush) and indexed so that Foxglove and `ros2 bag` seek
//! in it.
//!
//! Any channel can be added by its topic, schema and encodings ([`ChannelSpec`]): the
//! recorder's own and, from the same writer, whatever else the daemon publishes (the 3-D
//! scene, say).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use super::schema::ChannelSpec;

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// The file could not be created.
    #[error("creating the recording {}: {source}", path.display())]
    Create {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Writing failed (the disk full, the file system gone, ...).
    #[error("writing the recording: {0}")]
    Write(String),
    /// Written to after it was finished.
    #[error("the recording is finished")]
    Finished,
    /// A message for a channel this sink did not add.
    #[error("no channel {0} in the recording")]
    NoChannel(u16),
    /// The recorder's thread could not be started, or it panicked.
    #[error("the recorder's thread: {0}")]
    Thread(String),
    /// A recording could not be read back.
    #[error("reading the recording {}: {message}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

impl From<mcap::McapError> for RecordError {
    fn from(e: mcap::McapError) -> Self {
        match e {
            // The system's reason ("No space left on device"), not only that I/O failed.
            mcap::McapError::Io(e) => RecordError::Write(e.to_string()),
            e => RecordError::Write(e.to_string()),
        }
    }
}

/// Where recorded channels, messages and metadata go.
pub trait Sink: Send {
    /// Adds a channel (and its schema); its id for [`Sink::write`].
    fn add_channel(&mut self, spec: &ChannelSpec) -> Result<u16, RecordError>;
    /// One message on `channel`, logged at `log_time_ns` (ns since the Unix epoch).
    fn write(&mut self, channel: u16, log_time_ns: u64, data: &[u8]) -> Result<(), RecordError>;
    /// A metadata record: a name and string pairs.
    fn metadata(
        &mut self,
        name: &str,
        entries: &BTreeMap<String, String>,
    ) -> Result<(), RecordError>;
    /// Pushes everything written so far to where the recording goes (an MCAP file: the chunk in
    /// progress ended and handed to the operating system). Until a flush after it succeeds, a
    /// message may still sit in a buffer, and a failure loses it.
    fn flush(&mut self) -> Result<(), RecordError>;
    /// Ends the recording (the summary and index); nothing may be written after.
    fn finish(&mut self) -> Result<(), RecordError>;
}

/// An MCAP file (or any seekable writer).
pub struct McapSink<W: Write + Seek> {
    /// `None` once finished.
    writer: Option<mcap::Writer<W>>,
    /// Each channel's next sequence number, by channel id.
    sequences: BTreeMap<u16, u32>,
}

impl<W: Write + Seek> std::fmt::Debug for McapSink<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapSink")
            .field("channels", &self.sequences.len())
            .finish_non_exhaustive()
    }
}

/// The library string in the file's header.
const LIBRARY: &str = concat!("snakectl ", env!("CARGO_PKG_VERSION"));

impl McapSink<BufWriter<File>> {
    /// Creates (or truncates) the file at `path`.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Create {
            path: path.to_path_buf(),
            source,
        })?;
        McapSink::new(BufWriter::new(file))
    }
}

impl<W: Write + Seek> McapSink<W> {
    /// A recording written to `w`.
    pub fn new(w: W) -> Result<Self, RecordError> {
        // Chunks end only at a flush (or a metadata record, or the end), so that whoever
        // flushes knows which messages are in the file.
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(None)
            .library(LIBRARY)
            .create(w)?;
        Ok(McapSink {
            writer: Some(writer),
            sequences: BTreeMap::new(),
        })
    }
}

impl<W: Write + Seek + Send> Sink for McapSink<W> {
    fn add_channel(&mut self, spec: &ChannelSpec) -> Result<u16, RecordError> {
        let writer = self.writer.as_mut().ok_or(RecordError::Finished)?;
        let schema = writer.add_schema(&spec.schema_name, &spec.schema_encoding, &spec.schema)?;
        let id = writer.add_channel(schema, &spec.topic, &spec.message_encoding, &spec.metadata)?;
        self.sequences.entry(id).or_insert(0);
        Ok(id)
    }

    fn write(&mut self, channel: u16, log_time_ns: u64, data: &[u8]) -> Result<(), RecordError> {
        let sequence = self
            .sequences
            .get_mut(&channel)
            .ok_or(RecordError::NoChannel(channel))?;
        *sequence = sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: *sequence,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        self.writer
            .as_mut()
            .ok_or(RecordError::Finished)?
            .write_to_known_channel(&header, data)?;
        Ok(())
    }

    fn metadata(
        &mut self,
        name: &str,
        entries: &BTreeMap<String, String>,
    ) -> Result<(), RecordError> {
        let writer = self.writer.as_mut().ok_or(RecordError::Finished)?;
        writer.write_metadata(&mcap::records::Metadata {
            name: name.to_owned(),
            metadata: entries.clone(),
        })?;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), RecordError> {
        self.writer.as_mut().ok_or(RecordError::Finished)?.flush()?;
        Ok(())
    }

    fn finish(&mut self) -> Result<(), RecordError> {
        let mut writer = self.writer.take().ok_or(RecordError::Finished)?;
        writer.finish()?;
        // What the buffer still holds reaches the file here, its error with it.
        writer
            .into_inner()
            .flush()
            .map_err(|e| RecordError::Write(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A file whose every write fails for `why`.
    struct Broken {
        why: &'static str,
    }

    impl Write for Broken {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::other(self.why))
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Err(std::io::Error::other(self.why))
        }
    }

    impl Seek for Broken {
        fn seek(&mut self, _: std::io::SeekFrom) -> std::io::Result<u64> {
            Ok(0)
        }
    }

    #[test]
    fn a_failed_write_says_the_systems_reason() {
        let e = McapSink::new(Broken {
            why: "No space left on device",
        })
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "writing the recording: No space left on device"
        );
    }
}
