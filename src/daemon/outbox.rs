//! What waits for one Foxglove client: the view's WebSocket messages for it, oldest first, at
//! most [`CLIENT_BYTES`] of them.
//!
//! The view never waits for a client: it queues here and goes on. Beyond the bound the oldest
//! message data is dropped, so that a client that stops reading sees fresh data soon after it
//! reads again, not seconds of the past. The other messages (the server's info, channel
//! advertisements, status) are never dropped; a client that lets more than [`CLIENT_BYTES`] of
//! them wait is cut off.

use std::collections::VecDeque;

use tokio_tungstenite::tungstenite::Message;

/// Bytes of messages held for a client that reads slower than the view sends (the message being
/// written besides): about a third of a second of every channel at the default `publish_hz`
/// with a full trail (a scene is then about 25 kB).
pub(super) const CLIENT_BYTES: usize = 256 * 1024;

/// A client let more than [`CLIENT_BYTES`] of messages that cannot be dropped wait.
#[derive(Debug, thiserror::Error)]
#[error("the client lets more than {CLIENT_BYTES} bytes of the server's messages wait")]
pub(super) struct Overfull;

/// One message waiting.
#[derive(Debug)]
struct Queued {
    message: Message,
    /// Message data, which may be dropped.
    droppable: bool,
}

/// The messages waiting for one client, oldest first.
#[derive(Debug, Default)]
pub(super) struct Outbox {
    queued: VecDeque<Queued>,
    /// Bytes in `queued`.
    bytes: usize,
    /// Message data dropped.
    dropped: u64,
}

impl Outbox {
    /// Queues `message` (`droppable`: message data), dropping the oldest message data beyond
    /// [`CLIENT_BYTES`]; an error when the messages that cannot be dropped pass it.
    pub(super) fn push(&mut self, message: Message, droppable: bool) -> Result<(), Overfull> {
        self.bytes += message.len();
        self.queued.push_back(Queued { message, droppable });
        let mut k = 0;
        while self.bytes > CLIENT_BYTES && k < self.queued.len() {
            if self.queued[k].droppable {
                if let Some(dropped) = self.queued.remove(k) {
                    self.bytes -= dropped.message.len();
                    self.dropped += 1;
                }
            } else {
                k += 1;
            }
        }
        // One message larger than the bound alone is let through.
        if self.bytes > CLIENT_BYTES && self.queued.len() > 1 {
            return Err(Overfull);
        }
        Ok(())
    }

    /// The oldest message, taken out to be written.
    pub(super) fn pop(&mut self) -> Option<Message> {
        let queued = self.queued.pop_front()?;
        self.bytes -= queued.message.len();
        Some(queued.message)
    }

    /// Drops the message data waiting (stale once the client is being closed).
    pub(super) fn drop_data(&mut self) {
        let before = self.queued.len();
        self.queued.retain(|q| !q.droppable);
        self.dropped += (before - self.queued.len()) as u64;
        self.bytes = self.queued.iter().map(|q| q.message.len()).sum();
    }

    /// Message data dropped so far.
    pub(super) fn dropped(&self) -> u64 {
        self.dropped
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    /// Message data number `k`, 10 kB.
    fn data(k: u64) -> Message {
        let mut payload = vec![1u8];
        payload.extend_from_slice(&1u32.to_le_bytes());
        payload.extend_from_slice(&k.to_le_bytes());
        payload.resize(10_000, 0);
        Message::binary(payload)
    }

    fn number(m: &Message) -> u64 {
        u64::from_le_bytes(m.clone().into_data()[5..13].try_into().unwrap())
    }

    #[test]
    fn a_client_that_reads_nothing_has_a_bounded_backlog_ending_with_the_newest_data() {
        let mut outbox = Outbox::default();
        outbox.push(Message::text("info"), false).unwrap();
        for k in 0..200 {
            outbox.push(data(k), true).unwrap();
        }
        outbox.push(Message::text("advertise"), false).unwrap();
        assert!(outbox.bytes <= CLIENT_BYTES);
        let mut got = Vec::new();
        while let Some(m) = outbox.pop() {
            got.push(m);
        }
        assert_eq!(got.first(), Some(&Message::text("info")));
        assert_eq!(got.last(), Some(&Message::text("advertise")));
        let numbers: Vec<u64> = got[1..got.len() - 1].iter().map(number).collect();
        assert!(numbers.windows(2).all(|w| w[0] < w[1]), "{numbers:?}");
        assert_eq!(numbers.last(), Some(&199), "the newest is kept");
        assert_eq!(outbox.dropped() + numbers.len() as u64, 200);
        assert_eq!(outbox.bytes, 0);
    }

    #[test]
    fn a_client_that_lets_more_than_the_bound_of_messages_that_cannot_be_dropped_wait_is_cut_off() {
        let mut outbox = Outbox::default();
        let control = || Message::text(" ".repeat(CLIENT_BYTES / 4));
        for _ in 0..4 {
            outbox.push(control(), false).unwrap();
        }
        assert!(outbox.push(control(), false).is_err());
        // One message larger than the bound alone is taken.
        let mut outbox = Outbox::default();
        outbox
            .push(Message::text(" ".repeat(2 * CLIENT_BYTES)), false)
            .unwrap();
    }

    #[test]
    fn at_close_the_data_goes_and_the_rest_stays() {
        let mut outbox = Outbox::default();
        outbox.push(data(0), true).unwrap();
        outbox.push(Message::text("advertise"), false).unwrap();
        outbox.push(data(1), true).unwrap();
        outbox.drop_data();
        assert_eq!(outbox.pop(), Some(Message::text("advertise")));
        assert_eq!(outbox.pop(), None);
        assert_eq!(outbox.dropped(), 2);
    }
}
