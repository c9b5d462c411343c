//! The sending side of one client: its queued lines (replies and events, in order) and, while it
//! is subscribed, its telemetry, latest wins.
//!
//! A client that does not read is found here: every write must make progress within
//! [`SLOW_READER`], or the connection ends. The socket's send buffer is kept small
//! ([`SEND_BUFFER`]), so the kernel does not hide a stalled reader behind megabytes of stale
//! lines.

use std::io;
use std::time::Duration;

use tokio::io::{AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::{self, Interval, MissedTickBehavior};

use super::Shared;
use crate::protocol::{self, ClientId, Telemetry};

/// How long one write to a client may wait for it to read: a client that leaves lines waiting
/// longer is disconnected.
pub const SLOW_READER: Duration = Duration::from_secs(2);

/// The send buffer asked of the kernel for every client's socket, bytes (Linux doubles it for
/// its own bookkeeping). Small, so that what waits for a stalled client stays small: with the
/// client's own receive buffer, a few hundred kilobytes at most.
pub const SEND_BUFFER: usize = 32 * 1024;

/// Who reads a telemetry line: it says who is in control, and whether that is this client.
pub(super) struct Viewer<'a> {
    pub(super) id: ClientId,
    pub(super) shared: &'a Shared,
}

impl Viewer<'_> {
    /// The telemetry line of the latest telemetry for this client. The snapshot is taken, and
    /// the telemetry let go, before who is in control is looked up: the loop's next publication
    /// waits for every borrow of the telemetry to end, and new borrows wait behind it, so a
    /// borrow held while waiting for the arbiter (whose holder may be borrowing the telemetry to
    /// announce a change of control) would stop the loop for good.
    fn line(&self, telemetry: &mut watch::Receiver<Telemetry>) -> String {
        let snapshot = telemetry.borrow_and_update().clone();
        protocol::telemetry_line(&self.shared.status(&snapshot, self.id))
    }
}

/// Writes `bytes` and flushes them, or fails with `TimedOut` when the client has taken nothing
/// for `patience`: each step of the write must make progress within it, not the whole, so a
/// client that reads steadily, however slowly, is not cut off.
async fn send<W: AsyncWrite + Unpin>(
    sink: &mut W,
    bytes: &[u8],
    patience: Duration,
) -> io::Result<()> {
    let stalled = || {
        io::Error::new(
            io::ErrorKind::TimedOut,
            format!(
                "the client has not read for {} s while lines wait for it",
                patience.as_secs_f64()
            ),
        )
    };
    let mut rest = bytes;
    while !rest.is_empty() {
        let written = time::timeout(patience, sink.write(rest))
            .await
            .map_err(|_| stalled())??;
        if written == 0 {
            return Err(io::ErrorKind::WriteZero.into());
        }
        rest = &rest[written..];
    }
    time::timeout(patience, sink.flush())
        .await
        .map_err(|_| stalled())?
}

/// Sends a client's queued lines and, while subscribed, its telemetry, until the queue closes
/// and is empty; then closes the connection's sending side. Each write that waits longer than
/// `patience` for the client to read ends it with a `TimedOut` error.
pub(super) async fn write_loop<W: AsyncWrite + Unpin>(
    mut sink: W,
    mut lines: mpsc::Receiver<String>,
    mut telemetry: watch::Receiver<Telemetry>,
    mut rate: watch::Receiver<Option<f64>>,
    viewer: Viewer<'_>,
    patience: Duration,
) -> io::Result<()> {
    let mut ticker: Option<Interval> = None;
    // Send the next snapshot even if unchanged: the first after a subscribe.
    let mut fresh = false;
    let mut rate_open = true;
    // Lines waiting together go out in one write.
    let mut batch = String::new();
    loop {
        tokio::select! {
            biased;
            line = lines.recv() => {
                let Some(line) = line else { break };
                batch.clear();
                batch.push_str(&line);
                while batch.len() < 64 * 1024 {
                    let Ok(line) = lines.try_recv() else { break };
                    batch.push_str(&line);
                }
                send(&mut sink, batch.as_bytes(), patience).await?;
            }
            changed = rate.changed(), if rate_open => {
                if changed.is_err() {
                    rate_open = false;
                    ticker = None;
                } else {
                    ticker = rate.borrow_and_update().map(interval_at);
                    fresh = true;
                }
            }
            () = next_tick(&mut ticker), if ticker.is_some() => {
                if fresh || telemetry.has_changed().unwrap_or(false) {
                    fresh = false;
                    let line = viewer.line(&mut telemetry);
                    send(&mut sink, line.as_bytes(), patience).await?;
                }
            }
        }
    }
    time::timeout(patience, sink.shutdown())
        .await
        .unwrap_or(Ok(()))
}

/// A ticker at `rate_hz` whose first tick is now; ticks missed while writing are skipped.
pub(super) fn interval_at(rate_hz: f64) -> Interval {
    let period = Duration::try_from_secs_f64(1.0 / rate_hz)
        .unwrap_or(Duration::MAX)
        .clamp(Duration::from_micros(1), Duration::from_secs(86_400));
    let mut ticker = time::interval(period);
    ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
    ticker
}

async fn next_tick(ticker: &mut Option<Interval>) {
    match ticker {
        Some(ticker) => {
            ticker.tick().await;
        }
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[tokio::test]
    async fn intervals_stay_within_sane_periods() {
        assert_eq!(interval_at(1e-300).period(), Duration::from_secs(86_400));
        assert_eq!(interval_at(1e9).period(), Duration::from_micros(1));
        assert_eq!(interval_at(50.0).period(), Duration::from_millis(20));
    }

    #[test]
    fn a_telemetry_line_waiting_for_the_arbiter_never_holds_up_the_loop() {
        use std::sync::mpsc as std_mpsc;

        // The writer builds a line while another task holds the arbiter (as one announcing a
        // change of control does); the loop publishes meanwhile. Were the writer's borrow of
        // the telemetry held while it waits for the arbiter, the publication would wait for it,
        // and the arbiter's holder, borrowing the telemetry next, behind the publication.
        let shared = super::super::tests::shared();
        let (publish, telemetry) = watch::channel(Telemetry::default());
        for round in 0..50u64 {
            let mut telemetry = telemetry.clone();
            let held = shared.arbiter();
            std::thread::scope(|s| {
                let (started, is_started) = std_mpsc::channel();
                let (shared, telemetry) = (&shared, &mut telemetry);
                let writer = s.spawn(move || {
                    let viewer = Viewer { id: 1, shared };
                    let _ = started.send(());
                    viewer.line(telemetry)
                });
                is_started.recv().unwrap();
                let (published, is_published) = std_mpsc::channel();
                let publish = &publish;
                s.spawn(move || {
                    publish.send_modify(|t| t.tick = round + 1);
                    let _ = published.send(());
                });
                let done = is_published.recv_timeout(Duration::from_secs(5));
                drop(held);
                assert!(
                    done.is_ok(),
                    "round {round}: the publication waited for the writer"
                );
                let line = writer.join().unwrap();
                assert!(line.contains("\"tick\""), "{line}");
            });
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_reader_that_takes_nothing_ends_the_writer_after_its_patience() {
        // A pipe of 64 bytes nobody reads: the second line cannot go.
        let (sink, _unread) = tokio::io::duplex(64);
        let (tx, rx) = mpsc::channel(4);
        let (_t, telemetry) = watch::channel(Telemetry::default());
        let (_r, rate) = watch::channel(None);
        let shared = super::super::tests::shared();
        let viewer = Viewer {
            id: 1,
            shared: &shared,
        };
        tx.send("x".repeat(60)).await.unwrap();
        tx.send("y".repeat(60)).await.unwrap();
        let started = time::Instant::now();
        let ended = write_loop(sink, rx, telemetry, rate, viewer, SLOW_READER).await;
        let e = ended.err().map(|e| e.kind());
        assert_eq!(e, Some(io::ErrorKind::TimedOut));
        assert_eq!(started.elapsed(), SLOW_READER);
    }

    #[tokio::test(start_paused = true)]
    async fn a_reader_that_keeps_reading_slowly_is_not_cut_off() {
        use tokio::io::AsyncReadExt;

        // A pipe of 4 KiB, read 4 KiB every 200 ms: never 2 s without reading, but 80 KB of
        // lines take 4 s to go through.
        let (sink, mut source) = tokio::io::duplex(4096);
        let reader = tokio::spawn(async move {
            let mut got = 0usize;
            let mut buf = [0u8; 4096];
            loop {
                time::sleep(Duration::from_millis(200)).await;
                match source.read(&mut buf).await {
                    Ok(0) | Err(_) => return got,
                    Ok(n) => got += n,
                }
            }
        });
        let (tx, rx) = mpsc::channel(4);
        let (_t, telemetry) = watch::channel(Telemetry::default());
        let (_r, rate) = watch::channel(None);
        let shared = super::super::tests::shared();
        let viewer = Viewer {
            id: 1,
            shared: &shared,
        };
        let line = format!("{}\n", "x".repeat(40_000 - 1));
        tx.send(line.clone()).await.unwrap();
        tx.send(line).await.unwrap();
        drop(tx);
        let ended = write_loop(sink, rx, telemetry, rate, viewer, SLOW_READER).await;
        assert!(ended.is_ok(), "{ended:?}");
        assert_eq!(reader.await.unwrap(), 80_000);
    }
}
