//! Request lines off a client's byte stream: at most [`MAX_LINE`] bytes held, an over-long line
//! dropped through its newline and reported, so one bad line never ends a connection.

use std::io;

use tokio::io::{AsyncBufReadExt, AsyncRead, BufReader};

use crate::protocol::MAX_LINE;

/// One read from a [`LineReader`].
#[derive(Debug, PartialEq)]
pub(super) enum Line<'a> {
    /// A line, without its newline (the last one may lack it).
    Complete(&'a [u8]),
    /// A line over [`MAX_LINE`] bytes, now discarded through its newline.
    TooLong,
    /// The peer closed its side.
    Eof,
}

/// Splits a byte stream into lines of at most [`MAX_LINE`] bytes, holding no more than that.
///
/// [`LineReader::next`] is cancel-safe: a partial line stays in the reader until the rest comes.
pub(super) struct LineReader<R> {
    inner: BufReader<R>,
    line: Vec<u8>,
    /// `line` holds a line already returned, to be cleared on the next call.
    returned: bool,
    /// Within a line over the limit, dropping bytes until its newline.
    discarding: bool,
}

impl<R: AsyncRead + Unpin> LineReader<R> {
    pub(super) fn new(inner: R) -> Self {
        LineReader {
            inner: BufReader::new(inner),
            line: Vec::new(),
            returned: false,
            discarding: false,
        }
    }

    pub(super) async fn next(&mut self) -> io::Result<Line<'_>> {
        if self.returned {
            self.line.clear();
            self.returned = false;
        }
        loop {
            let buf = self.inner.fill_buf().await?;
            if buf.is_empty() {
                if std::mem::take(&mut self.discarding) {
                    return Ok(Line::TooLong);
                }
                if self.line.is_empty() {
                    return Ok(Line::Eof);
                }
                self.returned = true;
                return Ok(Line::Complete(&self.line));
            }
            let newline = buf.iter().position(|&b| b == b'\n');
            let take = newline.unwrap_or(buf.len());
            let over = self.discarding || self.line.len() + take > MAX_LINE;
            if over {
                self.line.clear();
            } else {
                self.line.extend_from_slice(&buf[..take]);
            }
            let consumed = newline.map_or(take, |i| i + 1);
            self.inner.consume(consumed);
            match (newline, over) {
                (None, over) => self.discarding = over,
                (Some(_), true) => {
                    self.discarding = false;
                    return Ok(Line::TooLong);
                }
                (Some(_), false) => {
                    self.returned = true;
                    return Ok(Line::Complete(&self.line));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use tokio::io::AsyncWriteExt;

    use super::*;

    /// The lines a reader yields from `input` written in `chunk`-byte pieces.
    async fn lines_of(input: &[u8], chunk: usize) -> Vec<Result<Vec<u8>, &'static str>> {
        let (mut tx, rx) = tokio::io::duplex(1024);
        let input = input.to_vec();
        let feed = tokio::spawn(async move {
            for piece in input.chunks(chunk) {
                tx.write_all(piece).await.unwrap();
            }
        });
        let mut reader = LineReader::new(rx);
        let mut out = Vec::new();
        loop {
            match reader.next().await.unwrap() {
                Line::Complete(line) => out.push(Ok(line.to_vec())),
                Line::TooLong => out.push(Err("too long")),
                Line::Eof => break,
            }
        }
        feed.await.unwrap();
        out
    }

    #[tokio::test]
    async fn lines_split_at_newlines_whatever_the_chunks() {
        let input = b"{\"a\":1}\n\n{\"b\":2}\r\nlast";
        for chunk in [1, 3, 7, 1000] {
            assert_eq!(
                lines_of(input, chunk).await,
                vec![
                    Ok(b"{\"a\":1}".to_vec()),
                    Ok(Vec::new()),
                    Ok(b"{\"b\":2}\r".to_vec()),
                    Ok(b"last".to_vec()),
                ],
                "chunk {chunk}"
            );
        }
    }

    #[tokio::test]
    async fn an_over_long_line_is_dropped_through_its_newline_only() {
        let mut input = vec![b'x'; MAX_LINE + 1];
        input.extend_from_slice(b"\nok\n");
        input.extend(vec![b'y'; MAX_LINE]);
        input.extend_from_slice(b"\n");
        input.extend(vec![b'z'; 3 * MAX_LINE]);
        for chunk in [999, 8192, 100_000] {
            let lines = lines_of(&input, chunk).await;
            assert_eq!(lines.len(), 4, "chunk {chunk}");
            assert_eq!(lines[0], Err("too long"));
            assert_eq!(lines[1], Ok(b"ok".to_vec()));
            assert_eq!(
                lines[2],
                Ok(vec![b'y'; MAX_LINE]),
                "a line of exactly MAX_LINE"
            );
            assert_eq!(lines[3], Err("too long"), "unterminated at the end");
        }
    }
}
