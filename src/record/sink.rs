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
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

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
    /// The file exists, and replacing it was not asked for.
    #[error(
        "the recording {} exists already: `--overwrite` replaces it, or give another file",
        path.display()
    )]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// The path is not a regular file (a FIFO, a device, a directory), symbolic links followed.
    #[error(
        "the recording {} is not a regular file: give the path of a file to create (or, with \
         `--overwrite`, of one to replace)",
        path.display()
    )]
    NotAFile {
        /// The path.
        path: PathBuf,
    },
    /// Another recording (of this process or another) is being written to the file.
    #[error("the recording {} is being written by another process", path.display())]
    Busy {
        /// The file.
        path: PathBuf,
    },
    /// Writing failed (the disk full, the file system gone, ...).
    #[error("writing the recording: {0}")]
    Write(String),
    /// The recorder's thread did not end within the time allowed at close: the disk did not
    /// answer. The file may lack its summary (`mcap recover` rebuilds it).
    #[error(
        "the disk did not answer within {waited_ms} ms; the file may lack its summary \
         (`mcap recover` rebuilds it)"
    )]
    Stalled {
        /// How long the close waited, ms.
        waited_ms: u64,
    },
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
    writer: Option<mcap::Writer<Guarded<W>>>,
    /// The file's first I/O error, reported by every call from then on.
    error: Arc<OnceLock<String>>,
    /// Each channel's next sequence number, by channel id.
    sequences: BTreeMap<u16, u32>,
    /// [`McapSink::create`] made the file: it did not exist before.
    made: bool,
}

/// The file under the `mcap` writer: it keeps the first I/O error and from then on takes every
/// write and writes nothing, so that the writer never sees a failure (one while it starts a
/// chunk leaves `mcap` 0.25's writer unable to drop without a panic). [`McapSink`] reports the
/// kept error after each call instead.
struct Guarded<W> {
    inner: W,
    error: Arc<OnceLock<String>>,
    /// Where the next byte goes, and the end of what was written: kept after a failure too, so
    /// that the writer's offsets stay consistent.
    at: u64,
    end: u64,
}

impl<W> Guarded<W> {
    fn failed(&self) -> bool {
        self.error.get().is_some()
    }

    fn fail(&mut self, e: &std::io::Error) {
        // Only the first error is kept: the others follow from it.
        let _ = self.error.set(e.to_string());
    }

    fn moved_to(&mut self, at: u64) {
        self.at = at;
        self.end = self.end.max(at);
    }
}

impl<W: Write> Write for Guarded<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if !self.failed() {
            match self.inner.write(buf) {
                Ok(n) => {
                    self.moved_to(self.at.saturating_add(n as u64));
                    return Ok(n);
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Err(e),
                Err(e) => self.fail(&e),
            }
        }
        self.moved_to(self.at.saturating_add(buf.len() as u64));
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if !self.failed() {
            if let Err(e) = self.inner.flush() {
                self.fail(&e);
            }
        }
        Ok(())
    }
}

impl<W: Seek> Seek for Guarded<W> {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        if !self.failed() {
            match self.inner.seek(to) {
                Ok(at) => {
                    self.moved_to(at);
                    return Ok(at);
                }
                Err(e) => self.fail(&e),
            }
        }
        let at = match to {
            SeekFrom::Start(at) => at,
            SeekFrom::Current(by) => self.at.saturating_add_signed(by),
            SeekFrom::End(by) => self.end.saturating_add_signed(by),
        };
        self.moved_to(at);
        Ok(at)
    }
}

impl<W: Write + Seek> std::fmt::Debug for McapSink<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapSink")
            .field("channels", &self.sequences.len())
            .finish_non_exhaustive()
    }
}

/// `O_NONBLOCK`, for `open(2)`: a FIFO without a reader fails at once instead of waiting.
const NONBLOCK: i32 = rustix::fs::OFlags::NONBLOCK.bits() as i32;

/// The library string in the file's header.
const LIBRARY: &str = concat!("snakectl ", env!("CARGO_PKG_VERSION"));

impl McapSink<BufWriter<File>> {
    /// Creates the file at `path`, its header written through: a file that takes nothing (a
    /// full disk) is refused here, before anything is recorded, not found out at the first
    /// chunk. A file that exists is refused unless `overwrite`; one that another recording is
    /// being written to is refused even then (an exclusive `flock`, held while this sink
    /// lives), and left as it was. Anything but a regular file (a FIFO, a device), symbolic
    /// links followed, is refused either way, before it is opened: opening a FIFO waits for a
    /// reader, deaf to signals. A file this call made and then could not start is removed.
    pub fn create(path: &Path, overwrite: bool) -> Result<Self, RecordError> {
        Self::create_over(path, overwrite, BufWriter::new)
    }
}

impl<W: Write + Seek> McapSink<W> {
    /// [`McapSink::create`], the file written through `over(file)`.
    fn create_over(
        path: &Path,
        overwrite: bool,
        over: impl FnOnce(File) -> W,
    ) -> Result<Self, RecordError> {
        let not_a_file = || RecordError::NotAFile {
            path: path.to_path_buf(),
        };
        let created = |source| RecordError::Create {
            path: path.to_path_buf(),
            source,
        };
        if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
            return Err(not_a_file());
        }
        // Without blocking, should the path have become a FIFO since: no reader, it fails.
        let open = |new: bool| {
            use std::os::unix::fs::OpenOptionsExt as _;
            File::options()
                .write(true)
                .create_new(new)
                .custom_flags(NONBLOCK)
                .open(path)
        };
        let (file, made) = match open(true) {
            Ok(file) => (file, true),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && !overwrite => {
                return Err(RecordError::Exists {
                    path: path.to_path_buf(),
                })
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                (open(false).map_err(created)?, false)
            }
            Err(e) => return Err(created(e)),
        };
        if !file.metadata().map_err(created)?.is_file() {
            return Err(not_a_file());
        }
        match rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
            Ok(()) => {}
            // Another recording's file: never removed, even if this call made it.
            Err(rustix::io::Errno::WOULDBLOCK) => {
                return Err(RecordError::Busy {
                    path: path.to_path_buf(),
                })
            }
            Err(e) => return Err(created(e.into())),
        }
        let started = Self::start_file(path, file, over);
        if started.is_err() && made {
            // No empty recording left behind to block the next run; never a file that was
            // there before.
            if let Err(e) = std::fs::remove_file(path) {
                tracing::warn!("removing the recording {}: {e}", path.display());
            }
        }
        let mut sink = started?;
        sink.made = made;
        Ok(sink)
    }

    /// The locked `file` emptied, its header written and flushed through `over(file)`.
    fn start_file(
        path: &Path,
        file: File,
        over: impl FnOnce(File) -> W,
    ) -> Result<Self, RecordError> {
        let created = |source| RecordError::Create {
            path: path.to_path_buf(),
            source,
        };
        // Emptied only once it is this sink's alone.
        file.set_len(0).map_err(created)?;
        let named = |e| match e {
            RecordError::Write(why) => RecordError::Create {
                path: path.to_path_buf(),
                source: std::io::Error::other(why),
            },
            other => other,
        };
        let mut sink = McapSink::new(over(file)).map_err(named)?;
        sink.with_writer(mcap::Writer::flush).map_err(named)?;
        Ok(sink)
    }

    /// Whether [`McapSink::create`] made the file (it did not exist before).
    pub fn made_file(&self) -> bool {
        self.made
    }

    /// A recording written to `w`.
    pub fn new(mut w: W) -> Result<Self, RecordError> {
        let at = w
            .stream_position()
            .map_err(|e| RecordError::Write(e.to_string()))?;
        let error = Arc::new(OnceLock::new());
        let file = Guarded {
            inner: w,
            error: Arc::clone(&error),
            at,
            end: at,
        };
        // Chunks end only at a flush (or a metadata record, or the end), so that whoever
        // flushes knows which messages are in the file.
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(None)
            .library(LIBRARY)
            .create(file)?;
        let sink = McapSink {
            writer: Some(writer),
            error,
            sequences: BTreeMap::new(),
            made: false,
        };
        sink.failed()?;
        Ok(sink)
    }

    /// The file's first I/O error, if it had one.
    fn failed(&self) -> Result<(), RecordError> {
        match self.error.get() {
            Some(e) => Err(RecordError::Write(e.clone())),
            None => Ok(()),
        }
    }

    /// Runs `op` on the writer; then the file's error, if it had one.
    fn with_writer<T>(
        &mut self,
        op: impl FnOnce(&mut mcap::Writer<Guarded<W>>) -> mcap::McapResult<T>,
    ) -> Result<T, RecordError> {
        self.failed()?;
        let out = op(self.writer.as_mut().ok_or(RecordError::Finished)?)?;
        self.failed()?;
        Ok(out)
    }
}

impl<W: Write + Seek + Send> Sink for McapSink<W> {
    fn add_channel(&mut self, spec: &ChannelSpec) -> Result<u16, RecordError> {
        let id = self.with_writer(|writer| {
            let schema =
                writer.add_schema(&spec.schema_name, &spec.schema_encoding, &spec.schema)?;
            writer.add_channel(schema, &spec.topic, &spec.message_encoding, &spec.metadata)
        })?;
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
        self.with_writer(|writer| writer.write_to_known_channel(&header, data))
    }

    fn metadata(
        &mut self,
        name: &str,
        entries: &BTreeMap<String, String>,
    ) -> Result<(), RecordError> {
        self.with_writer(|writer| {
            writer.write_metadata(&mcap::records::Metadata {
                name: name.to_owned(),
                metadata: entries.clone(),
            })
        })
    }

    fn flush(&mut self) -> Result<(), RecordError> {
        self.with_writer(mcap::Writer::flush)
    }

    fn finish(&mut self) -> Result<(), RecordError> {
        self.with_writer(|writer| writer.finish().map(drop))?;
        let writer = self.writer.take().ok_or(RecordError::Finished)?;
        // What the buffer still holds reaches the file here, its error with it.
        writer
            .into_inner()
            .flush()
            .map_err(|e| RecordError::Write(e.to_string()))?;
        self.failed()
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

    /// A file that opens but takes no byte: every write fails as on a full disk.
    struct Full(#[allow(dead_code)] File);

    impl Write for Full {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::from_raw_os_error(28))
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Seek for Full {
        fn seek(&mut self, _: SeekFrom) -> std::io::Result<u64> {
            Ok(0)
        }
    }

    /// A disk full from the start refuses the recording at creation, behind the buffer that
    /// would have hidden it until the first chunk, and leaves no file behind to block the
    /// next run.
    #[test]
    fn a_recording_on_a_full_disk_is_refused_when_created_and_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let e = McapSink::create_over(&path, false, |f| BufWriter::new(Full(f))).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "creating the recording {}: No space left on device (os error 28)",
                path.display()
            )
        );
        assert!(!path.exists(), "an empty recording left behind");
    }

    /// With `overwrite`, a file that was there before is never removed, start-up failing or
    /// not.
    #[test]
    fn a_failed_creation_over_a_file_that_was_there_leaves_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        std::fs::write(&path, "before").unwrap();
        McapSink::create_over(&path, true, |f| BufWriter::new(Full(f))).unwrap_err();
        assert!(path.is_file());
        let made = McapSink::create(&path, true).unwrap();
        assert!(!made.made_file());
        let fresh = dir.path().join("fresh.mcap");
        assert!(McapSink::create(&fresh, true).unwrap().made_file());
    }

    /// Anything but a regular file is refused before it is opened, with `overwrite` or not:
    /// a character device (Linux's full device), a directory.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_recording_that_is_not_a_regular_file_is_refused() {
        for overwrite in [false, true] {
            let Err(e) = McapSink::create(Path::new("/dev/full"), overwrite) else {
                panic!("/dev/full was taken for a recording");
            };
            assert!(matches!(e, RecordError::NotAFile { .. }), "{e}");
            assert!(
                e.to_string()
                    .starts_with("the recording /dev/full is not a regular file"),
                "{e}"
            );
            let dir = tempfile::tempdir().unwrap();
            let e = McapSink::create(dir.path(), overwrite).unwrap_err();
            assert!(matches!(e, RecordError::NotAFile { .. }), "{e}");
        }
    }
}
