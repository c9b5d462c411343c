//! What the Foxglove gate forwards from the server to one client: the server's answer to the
//! upgrade, then its WebSocket frames, whole, through a bounded [`Outbox`].
//!
//! The server is read as fast as it writes, whatever the client takes, so nothing waits for a
//! slow client in the server's socket or the gate's (megabytes on loopback, where the kernel
//! sizes the buffers for 64 kB segments). What waits is in the outbox: at most
//! [`CLIENT_FRAMES`] bytes. Beyond them the oldest message data is dropped, as the server's own
//! queue drops it: a client that stops reading sees fresh data soon after it reads again, not
//! seconds of the past. Other frames (the server's JSON messages, pings, the close) are never
//! dropped; a client that lets more than [`CLIENT_FRAMES`] of them wait is cut off, as the
//! server cuts off one whose control queue is full.

use std::collections::VecDeque;
use std::io;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// Bytes of frames the gate holds for a client that reads slower than the server sends (the
/// frame being written besides): about a third of a second of every channel at the default
/// `publish_hz` with a full trail (a scene is then about 25 kB).
const CLIENT_FRAMES: usize = 256 * 1024;

/// The largest frame the gate takes from the server (its messages are far smaller).
const MAX_FRAME: u64 = 16 * 1024 * 1024;

/// Longest HTTP response head the gate takes from the server.
const MAX_HEAD: usize = 8192;

/// Bytes read from the server at a time.
const READ_CHUNK: usize = 64 * 1024;

/// One piece of what the server sends, forwarded whole or not at all.
#[derive(Debug)]
struct Frame {
    bytes: Vec<u8>,
    /// Message data (a binary frame, op 1), which may be dropped.
    droppable: bool,
}

/// The server's bytes cut into what the gate forwards: first the HTTP response head, then whole
/// WebSocket frames (after any answer but `101`, the bytes as they come).
#[derive(Debug, Default)]
struct Cutter {
    buf: Vec<u8>,
    /// Where the bytes not cut yet start in `buf`.
    start: usize,
    head_done: bool,
    /// The server did not switch to WebSocket: no frames to find.
    opaque: bool,
}

impl Cutter {
    /// Adds bytes from the server.
    fn extend(&mut self, bytes: &[u8]) {
        // What was cut goes first, once per read rather than once per frame.
        self.buf.drain(..self.start);
        self.start = 0;
        self.buf.extend_from_slice(bytes);
    }

    /// The next whole piece, if the bytes so far hold one.
    fn next(&mut self) -> io::Result<Option<Frame>> {
        let rest = self.buf.get(self.start..).unwrap_or_default();
        let (size, droppable) = if !self.head_done {
            let Some(end) = rest.windows(4).position(|w| w == b"\r\n\r\n") else {
                if rest.len() > MAX_HEAD {
                    return Err(io::Error::other("the server's response head is too long"));
                }
                return Ok(None);
            };
            self.head_done = true;
            self.opaque = !rest.starts_with(b"HTTP/1.1 101 ");
            (end + 4, false)
        } else if self.opaque {
            (rest.len(), false)
        } else {
            match frame_size(rest)? {
                Some((size, droppable)) => (size, droppable),
                None => return Ok(None),
            }
        };
        if size == 0 {
            return Ok(None);
        }
        let bytes = rest.get(..size).unwrap_or_default().to_vec();
        self.start += size;
        Ok(Some(Frame { bytes, droppable }))
    }

    /// What is left when the server has closed: a cut piece, forwarded as it is.
    fn rest(&mut self) -> Option<Frame> {
        let rest = self.buf.get(self.start..).unwrap_or_default();
        let frame = (!rest.is_empty()).then(|| Frame {
            bytes: rest.to_vec(),
            droppable: false,
        });
        self.buf.clear();
        self.start = 0;
        frame
    }
}

/// The size of the frame `bytes` starts with, and whether it is message data (final, binary,
/// unmasked, its first byte the op `MessageData`); `None` until `bytes` hold all of it.
fn frame_size(bytes: &[u8]) -> io::Result<Option<(usize, bool)>> {
    let Some(&[first, second]) = bytes.get(..2) else {
        return Ok(None);
    };
    let masked = second & 0x80 != 0;
    let (len, at) = match second & 0x7f {
        126 => {
            let Some(be) = bytes.get(2..4).and_then(|b| <[u8; 2]>::try_from(b).ok()) else {
                return Ok(None);
            };
            (u64::from(u16::from_be_bytes(be)), 4)
        }
        127 => {
            let Some(be) = bytes.get(2..10).and_then(|b| <[u8; 8]>::try_from(b).ok()) else {
                return Ok(None);
            };
            (u64::from_be_bytes(be), 10)
        }
        n => (u64::from(n), 2),
    };
    if len > MAX_FRAME {
        return Err(io::Error::other(format!(
            "a frame of {len} bytes from the server"
        )));
    }
    let header = at + if masked { 4 } else { 0 };
    // At most MAX_FRAME plus 14, which fits.
    let size = header + len as usize;
    if bytes.len() < size {
        return Ok(None);
    }
    let droppable = first == 0x82 && !masked && bytes.get(header) == Some(&1);
    Ok(Some((size, droppable)))
}

/// The frames waiting for one client, oldest first, at most [`CLIENT_FRAMES`] bytes of them
/// beside the one being written.
#[derive(Debug, Default)]
struct Outbox {
    frames: VecDeque<Frame>,
    /// Bytes in `frames`.
    bytes: usize,
    /// Bytes of the first frame written already: it goes out whole, so it is no longer dropped.
    written: usize,
    /// Message data frames dropped.
    dropped: u64,
}

impl Outbox {
    /// Queues `frame`, dropping the oldest message data beyond [`CLIENT_FRAMES`]; an error when
    /// the frames that cannot be dropped pass it.
    fn push(&mut self, frame: Frame) -> io::Result<()> {
        self.bytes += frame.bytes.len();
        self.frames.push_back(frame);
        let mut k = usize::from(self.written > 0);
        while self.bytes > CLIENT_FRAMES && k < self.frames.len() {
            if self.frames[k].droppable {
                if let Some(dropped) = self.frames.remove(k) {
                    self.bytes -= dropped.bytes.len();
                    self.dropped += 1;
                }
            } else {
                k += 1;
            }
        }
        // One frame larger than the bound alone is let through.
        let waiting = self.frames.len() - usize::from(self.written > 0);
        if self.bytes > CLIENT_FRAMES && waiting > 1 {
            return Err(io::Error::other(format!(
                "the client lets more than {CLIENT_FRAMES} bytes of the server's messages wait"
            )));
        }
        Ok(())
    }

    /// What to write next.
    fn pending(&self) -> &[u8] {
        self.frames
            .front()
            .and_then(|f| f.bytes.get(self.written..))
            .unwrap_or_default()
    }

    /// `n` bytes of [`Outbox::pending`] were written.
    fn wrote(&mut self, n: usize) {
        self.written += n;
        if let Some(first) = self.frames.front() {
            if self.written >= first.bytes.len() {
                self.bytes -= first.bytes.len();
                self.frames.pop_front();
                self.written = 0;
            }
        }
    }

    fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

/// What a relay did.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub(super) struct Relayed {
    /// Message data frames dropped because the client fell behind.
    pub(super) dropped: u64,
}

/// Forwards `server` to `client` until the server closes and all that waits is written, then
/// shuts `client` down. `on_first_drop` is called when the client first falls behind.
pub(super) async fn forward<R, W>(
    mut server: R,
    mut client: W,
    on_first_drop: impl FnOnce(),
) -> io::Result<Relayed>
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
{
    let mut cutter = Cutter::default();
    let mut outbox = Outbox::default();
    let mut chunk = vec![0u8; READ_CHUNK];
    let mut open = true;
    let mut on_first_drop = Some(on_first_drop);
    loop {
        if !open && outbox.is_empty() {
            client.shutdown().await?;
            return Ok(Relayed {
                dropped: outbox.dropped,
            });
        }
        let step = {
            let pending = outbox.pending();
            tokio::select! {
                got = server.read(&mut chunk), if open => Step::Read(got?),
                wrote = client.write(pending), if !pending.is_empty() => Step::Wrote(wrote?),
            }
        };
        match step {
            Step::Read(0) => {
                open = false;
                if let Some(rest) = cutter.rest() {
                    outbox.push(rest)?;
                }
            }
            Step::Read(got) => {
                cutter.extend(chunk.get(..got).unwrap_or_default());
                while let Some(frame) = cutter.next()? {
                    outbox.push(frame)?;
                }
                if outbox.dropped > 0 {
                    if let Some(said) = on_first_drop.take() {
                        said();
                    }
                }
            }
            Step::Wrote(0) => return Err(io::ErrorKind::WriteZero.into()),
            Step::Wrote(n) => outbox.wrote(n),
        }
    }
}

/// One turn of [`forward`]: bytes read from the server, or written to the client.
enum Step {
    Read(usize),
    Wrote(usize),
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use std::time::Duration;

    use tokio::time;

    use super::*;

    /// A frame as a server sends it: final, `opcode`, unmasked.
    fn frame(opcode: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![0x80 | opcode];
        match payload.len() {
            n if n < 126 => f.push(n as u8),
            n if n <= 0xffff => {
                f.push(126);
                f.extend_from_slice(&(n as u16).to_be_bytes());
            }
            n => {
                f.push(127);
                f.extend_from_slice(&(n as u64).to_be_bytes());
            }
        }
        f.extend_from_slice(payload);
        f
    }

    /// Message data number `k` (op 1, subscription 1, log time `k`), 10 kB.
    fn message(k: u64) -> Vec<u8> {
        let mut payload = vec![1u8];
        payload.extend_from_slice(&1u32.to_le_bytes());
        payload.extend_from_slice(&k.to_le_bytes());
        payload.resize(10_000, 0);
        frame(2, &payload)
    }

    const HEAD: &[u8] = b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n\r\n";

    /// Every piece `bytes` holds, fed to a cutter `step` bytes at a time.
    fn cut(bytes: &[u8], step: usize) -> Vec<Frame> {
        let mut cutter = Cutter::default();
        let mut out = Vec::new();
        for piece in bytes.chunks(step) {
            cutter.extend(piece);
            while let Some(frame) = cutter.next().unwrap() {
                out.push(frame);
            }
        }
        out.extend(cutter.rest());
        out
    }

    #[test]
    fn the_servers_bytes_are_cut_into_its_head_and_whole_frames() {
        let mut masked = vec![0x82, 0x80 | 3, 9, 9, 9, 9];
        masked.extend_from_slice(&[1, 2, 3]);
        let pieces = [
            HEAD.to_vec(),
            frame(1, br#"{"op":"serverInfo"}"#),
            message(0),
            frame(2, &vec![1u8; 70_000]),
            frame(2, &[2, 0, 0]),
            masked,
            frame(9, b""),
        ];
        let stream = pieces.concat();
        for step in [1, 7, 4096, stream.len()] {
            let frames = cut(&stream, step);
            let bytes: Vec<&[u8]> = frames.iter().map(|f| f.bytes.as_slice()).collect();
            let expected: Vec<&[u8]> = pieces.iter().map(Vec::as_slice).collect();
            assert_eq!(bytes, expected, "fed {step} bytes at a time");
            let droppable: Vec<bool> = frames.iter().map(|f| f.droppable).collect();
            // Only unmasked message data (op 1 in a binary frame).
            assert_eq!(
                droppable,
                [false, false, true, true, false, false, false],
                "{step}"
            );
        }
    }

    #[test]
    fn after_any_answer_but_101_the_bytes_pass_as_they_come() {
        let answer = b"HTTP/1.1 400 Bad Request\r\nContent-Length: 3\r\n\r\nno\n";
        let frames = cut(answer, 5);
        let bytes: Vec<u8> = frames.iter().flat_map(|f| f.bytes.clone()).collect();
        assert_eq!(bytes, answer);
        assert!(frames.iter().all(|f| !f.droppable));
    }

    #[test]
    fn a_client_that_lets_more_than_the_bound_of_frames_that_cannot_be_dropped_wait_is_cut_off() {
        let mut outbox = Outbox::default();
        let control = || Frame {
            bytes: vec![b' '; CLIENT_FRAMES / 4],
            droppable: false,
        };
        for _ in 0..4 {
            outbox.push(control()).unwrap();
        }
        assert!(outbox.push(control()).is_err());
        // One frame larger than the bound alone is taken.
        let mut outbox = Outbox::default();
        let big = Frame {
            bytes: vec![b' '; 2 * CLIENT_FRAMES],
            droppable: false,
        };
        outbox.push(big).unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_client_that_reads_nothing_has_a_bounded_backlog_and_gets_the_newest_data() {
        const PIPE: usize = 16 * 1024;
        const MESSAGES: u64 = 200;
        let (mut server, from_server) = tokio::io::duplex(PIPE);
        let (to_client, mut client) = tokio::io::duplex(PIPE);
        let relay = tokio::spawn(forward(from_server, to_client, || {}));
        let first = frame(1, br#"{"op":"serverInfo"}"#);
        let last = frame(1, br#"{"op":"advertise"}"#);
        // 2 MB while the client reads nothing. Were the server's writes held until it reads,
        // nothing could move, and paused time would jump to the deadline.
        let sent = time::timeout(Duration::from_secs(3600), async {
            server.write_all(HEAD).await?;
            server.write_all(&first).await?;
            for k in 0..MESSAGES {
                server.write_all(&message(k)).await?;
            }
            server.write_all(&last).await?;
            server.shutdown().await
        })
        .await;
        assert!(
            matches!(sent, Ok(Ok(()))),
            "the server was held by a client that reads nothing: {sent:?}"
        );
        // The client reads again: it gets what waited for it, then the end.
        let mut got = Vec::new();
        client.read_to_end(&mut got).await.unwrap();
        let relayed = relay.await.unwrap().unwrap();
        let frames = cut(&got, got.len());
        let head = frames.first().map(|f| f.bytes.as_slice());
        assert_eq!(head, Some(HEAD));
        assert_eq!(frames.get(1).map(|f| &f.bytes), Some(&first));
        assert_eq!(frames.last().map(|f| &f.bytes), Some(&last));
        let numbers: Vec<u64> = frames
            .iter()
            .filter(|f| f.droppable)
            .map(|f| u64::from_le_bytes(f.bytes[9..17].try_into().unwrap()))
            .collect();
        assert!(numbers.windows(2).all(|w| w[0] < w[1]), "{numbers:?}");
        assert_eq!(numbers.last(), Some(&(MESSAGES - 1)), "the newest arrives");
        assert!(relayed.dropped > 0);
        assert_eq!(relayed.dropped + numbers.len() as u64, MESSAGES);
        // What waited: the outbox, a frame being written, and what each pipe holds.
        let bound = CLIENT_FRAMES + 2 * PIPE + 2 * message(0).len() + HEAD.len() + first.len();
        assert!(
            got.len() <= bound,
            "{} bytes waited for the client, over {bound}",
            got.len()
        );
    }
}
