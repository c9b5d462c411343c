//! Reading a text file a user named (a config, a token, a world, a path, a problem, a
//! scenario): a regular file only, and of bounded size; and the points CSV that a tip's path
//! and a scenario's polyline share ([`parse_points`]).
//!
//! `std::fs::read_to_string` reads whatever the path opens: `/dev/urandom` until memory runs
//! out, a FIFO with no writer never (opening it blocks). [`read_text`] looks at the path
//! before opening it (a device is never opened: opening some, a serial port, has effects),
//! opens it without blocking, checks again what was opened (the path may have changed in
//! between), and reads at most `cap + 1` bytes, so a file that grows while it is read cannot
//! beat the limit.

use std::fs::{File, FileType, OpenOptions};
use std::io::Read;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// The most bytes a text file may hold: 1 MiB, far more than any config, token, world, path
/// or problem file needs.
pub const MAX_TEXT_BYTES: u64 = 1 << 20;

/// Why a text file was not read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TextFileError {
    /// The operating system refused to open or read it.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// Not a regular file: a directory, a device, a FIFO or a socket.
    #[error("{what}, not a regular file")]
    NotRegular {
        /// What it is, e.g. "a character device".
        what: &'static str,
    },
    /// Longer than the limit.
    #[error("larger than {cap} bytes, the most such a file may hold")]
    TooLarge {
        /// The limit, bytes.
        cap: u64,
    },
    /// Not UTF-8 text.
    #[error("not UTF-8 text (the first bad byte is at offset {valid_up_to})")]
    NotUtf8 {
        /// How many bytes from the start are valid UTF-8.
        valid_up_to: usize,
    },
}

/// What a file that is not a regular one is, in words.
fn what(t: FileType) -> &'static str {
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "something else"
    }
}

/// The text of the regular file at `path`, at most `cap` bytes (see the module's
/// description): [`TextFileError::NotRegular`] for anything else, checked before it is opened
/// and again once it is; [`TextFileError::TooLarge`] beyond `cap`.
pub fn read_text(path: &Path, cap: u64) -> Result<String, TextFileError> {
    read_capped(open_regular(path)?, cap)
}

/// The regular file at `path`, opened for reading: [`TextFileError::NotRegular`] for anything
/// else, checked before it is opened (a device is never opened) and again once it is (the
/// path may have changed in between); opening never blocks.
pub fn open_regular(path: &Path) -> Result<File, TextFileError> {
    let regular = |t: FileType| {
        if t.is_file() {
            Ok(())
        } else {
            Err(TextFileError::NotRegular { what: what(t) })
        }
    };
    regular(std::fs::metadata(path)?.file_type())?;
    // Not blocking: a FIFO put in the file's place since would block the open. No
    // controlling terminal either, should it be a terminal by then.
    let flags = rustix::fs::OFlags::NONBLOCK | rustix::fs::OFlags::NOCTTY;
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(flags.bits() as i32)
        .open(path)?;
    regular(file.metadata()?.file_type())?;
    Ok(file)
}

/// At most `cap` bytes of UTF-8 text from `reader` (standard input, say), read through
/// `take(cap + 1)`.
pub fn read_capped(reader: impl Read, cap: u64) -> Result<String, TextFileError> {
    let mut bytes = Vec::new();
    reader.take(cap.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        return Err(TextFileError::TooLarge { cap });
    }
    String::from_utf8(bytes).map_err(|e| TextFileError::NotUtf8 {
        valid_up_to: e.utf8_error().valid_up_to(),
    })
}

/// The first line of `text` (from 1) that holds more than whitespace, if any: what a token
/// file whose first line is blank has further down.
pub fn first_text_line(text: &str) -> Option<usize> {
    text.lines()
        .position(|l| !l.trim().is_empty())
        .map(|i| i + 1)
}

/// Why a line of a points CSV is not a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RowError {
    /// Not two comma-separated fields.
    #[error("expected two fields `x,y`, got {0}")]
    Fields(usize),
    /// A field that is no number.
    #[error("`{0}` is not a number")]
    NotNumber(String),
    /// A number that is not finite.
    #[error("`{0}` is not a finite number")]
    NotFinite(String),
}

/// Why a points CSV was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PointsError {
    /// A line that is not a point.
    #[error("line {line}: {row}")]
    Row {
        /// The line, from 1.
        line: usize,
        /// What is wrong with it.
        row: RowError,
    },
    /// No point at all.
    #[error("no points: expected lines `x,y` in metres")]
    Empty,
}

impl PointsError {
    /// The error after the file's name, as compilers place it: `corners.csv:3: what`, or
    /// `corners.csv: what` for the file as a whole.
    pub fn in_file(&self, file: impl std::fmt::Display) -> String {
        match self {
            Self::Row { line, row } => format!("{file}:{line}: {row}"),
            Self::Empty => format!("{file}: {self}"),
        }
    }
}

/// A point of a points CSV and the line it is on (from 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CsvPoint {
    /// The line, from 1.
    pub line: usize,
    /// `x, y`, finite.
    pub xy: [f64; 2],
}

/// One row `x,y`.
fn parse_row(line: &str) -> Result<[f64; 2], RowError> {
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    let [x, y] = fields[..] else {
        return Err(RowError::Fields(fields.len()));
    };
    let number = |s: &str| match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(RowError::NotFinite(s.to_owned())),
        Err(_) => Err(RowError::NotNumber(s.to_owned())),
    };
    Ok([number(x)?, number(y)?])
}

/// The points of a CSV of `x,y` rows (a tip's path, a scenario's polyline), in order: blank
/// lines and lines starting with `#` skipped, the first other line a header when none of its
/// fields is a number; every other line must be a point, or the file is refused naming it.
pub fn parse_points(text: &str) -> Result<Vec<CsvPoint>, PointsError> {
    let mut points = Vec::new();
    let mut first = true;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim_start_matches('\u{feff}').trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let header = first && line.split(',').all(|f| f.trim().parse::<f64>().is_err());
        first = false;
        if header {
            continue;
        }
        let xy = parse_row(line).map_err(|row| PointsError::Row { line: i + 1, row })?;
        points.push(CsvPoint { line: i + 1, xy });
    }
    if points.is_empty() {
        return Err(PointsError::Empty);
    }
    Ok(points)
}

/// Makes a FIFO at `path` (replacing what is there), for the tests of readers that must refuse
/// one without blocking.
#[cfg(test)]
pub(crate) fn make_fifo(path: &Path) {
    let _ = std::fs::remove_file(path);
    if let Err(e) = rustix::fs::mknodat(
        rustix::fs::CWD,
        path,
        rustix::fs::FileType::Fifo,
        rustix::fs::Mode::from_raw_mode(0o600),
        0,
    ) {
        panic!("making a FIFO at {}: {e}", path.display());
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn dir() -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("snakectl-textfile-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_regular_file_is_read() {
        let f = dir().join("ok.txt");
        std::fs::write(&f, "hello\n").unwrap();
        assert_eq!(read_text(&f, MAX_TEXT_BYTES).unwrap(), "hello\n");
    }

    #[test]
    fn devices_and_directories_are_refused_unopened() {
        let e = read_text(Path::new("/dev/zero"), MAX_TEXT_BYTES).unwrap_err();
        assert!(
            matches!(
                e,
                TextFileError::NotRegular {
                    what: "a character device"
                }
            ),
            "{e}"
        );
        let e = read_text(&dir(), MAX_TEXT_BYTES).unwrap_err();
        assert_eq!(e.to_string(), "a directory, not a regular file");
    }

    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let f = dir().join("fifo");
        make_fifo(&f);
        let e = read_text(&f, MAX_TEXT_BYTES).unwrap_err();
        assert_eq!(e.to_string(), "a FIFO (named pipe), not a regular file");
    }

    #[test]
    fn the_cap_holds_and_is_said() {
        let f = dir().join("big.txt");
        std::fs::write(&f, "x".repeat(11)).unwrap();
        assert_eq!(read_text(&f, 11).unwrap().len(), 11);
        let e = read_text(&f, 10).unwrap_err();
        assert!(matches!(e, TextFileError::TooLarge { cap: 10 }), "{e}");
        assert!(e.to_string().contains("10 bytes"), "{e}");
        // A source without end stops at the cap.
        let e = read_capped(std::io::repeat(b'x'), 1000).unwrap_err();
        assert!(matches!(e, TextFileError::TooLarge { cap: 1000 }), "{e}");
    }

    #[test]
    fn only_the_first_line_may_be_a_header() {
        let xy = |p: &[CsvPoint]| p.iter().map(|p| (p.line, p.xy)).collect::<Vec<_>>();
        let p = parse_points("\u{feff}x,y\n# a comment\n\n1,2\n 3 , 4 \n").unwrap();
        assert_eq!(xy(&p), [(4, [1.0, 2.0]), (5, [3.0, 4.0])]);
        // A second line in the wrong format is an error naming it, not another header.
        let e = parse_points("0;0\n0.2;0.1\n0.5,0.3\n1,0\n").unwrap_err();
        assert_eq!(
            e.in_file("a.csv"),
            "a.csv:2: expected two fields `x,y`, got 1"
        );
        assert_eq!(
            parse_points("x,y\n\n").unwrap_err().in_file("a.csv"),
            "a.csv: no points: expected lines `x,y` in metres"
        );
    }

    #[test]
    fn non_utf8_is_refused() {
        let e = read_capped(&b"ab\xffcd"[..], 100).unwrap_err();
        assert!(
            matches!(e, TextFileError::NotUtf8 { valid_up_to: 2 }),
            "{e}"
        );
    }
}
