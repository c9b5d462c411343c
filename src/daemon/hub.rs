//! The server side of the Foxglove WebSocket protocol (subprotocol `foxglove.sdk.v1`), for the
//! clients the gate (`gate`) let in.
//!
//! The [`Hub`] is a [`foxglove::Sink`] on the view's own [`foxglove::Context`]: every channel
//! the view declares is advertised to every client, and every message the view logs reaches it
//! already encoded, and is queued as message data for each client subscribed to its channel, in
//! that client's [`Outbox`] (bounded; its oldest message data dropped). Logging never waits on
//! a client. Each client's [`serve`] writes its outbox out and reads what it sends: subscriptions,
//! and, with `accept_commands`, the channels it advertises and the messages it publishes on them,
//! handed to [`Commands`]. What it sends that the view does not take is answered with one status
//! message and counted, and logged once, with the count, when it leaves. A message over the
//! gate's size limit ends that client's connection alone: it is sent a close with code 1009
//! (Message Too Big) naming the limit, and logged once.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use base64::Engine;
use foxglove::{ChannelId, FoxgloveError, Metadata, RawChannel, Sink, SinkId};
use futures_util::{SinkExt, StreamExt};
use serde::Deserialize;
use serde_json::{json, Value};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::Notify;
use tokio_tungstenite::tungstenite::error::CapacityError;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};
use tokio_tungstenite::WebSocketStream;
use tracing::{debug, info, warn};

use super::outbox::Outbox;
use super::view::Commands;

/// The subprotocol the view speaks, the one current Foxglove apps ask for.
pub(super) const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// The binary op of message data, from the server and from a client alike.
const MESSAGE_DATA: u8 = 1;

/// The level of a status message that says something was refused.
const STATUS_ERROR: u8 = 2;

/// How long a client sent a message over the limit has to take its close and hang up, before
/// its connection is dropped anyway.
const TOO_BIG_WAIT: Duration = Duration::from_secs(2);

/// Every client's state, shared by the view's logging (through [`Sink`]) and the clients'
/// tasks, all on the view's thread.
#[derive(Debug)]
pub(super) struct Hub {
    sink: SinkId,
    /// The `serverInfo` every client is sent first.
    info: Message,
    state: Mutex<State>,
    /// Notified when a client leaves.
    left: Notify,
}

#[derive(Debug, Default)]
struct State {
    /// The channels advertised, by id.
    channels: BTreeMap<u64, Arc<RawChannel>>,
    clients: BTreeMap<u64, Slot>,
    next_client: u64,
    /// The view is closing: each client is sent what waits but message data, then its close.
    closing: bool,
}

/// One client's part of the hub.
#[derive(Debug)]
struct Slot {
    /// Subscription id to channel id.
    subscriptions: BTreeMap<u32, u64>,
    outbox: Outbox,
    /// Wakes the client's task: something to write, or the close.
    wake: Arc<Notify>,
    /// Its outbox overflowed with messages that cannot be dropped: it is cut off.
    cut: bool,
    peer: SocketAddr,
}

impl Slot {
    /// Queues `message` and wakes the client's task.
    fn push(&mut self, message: Message, droppable: bool) {
        let before = self.outbox.dropped();
        if self.outbox.push(message, droppable).is_err() {
            self.cut = true;
        }
        if before == 0 && self.outbox.dropped() > 0 {
            info!(peer = %self.peer, "a Foxglove client reads slower than the view sends: its oldest messages are dropped");
        }
        self.wake.notify_one();
    }
}

/// What a client's task does next.
enum Next {
    Write(Message),
    Wait,
    Close,
    Cut,
}

impl Hub {
    /// A hub whose `serverInfo` names the server `name` and, with `accept_commands`, offers
    /// client publishing in JSON and CDR.
    pub(super) fn new(name: &str, accept_commands: bool) -> Hub {
        let info = if accept_commands {
            json!({"op": "serverInfo", "name": name, "capabilities": ["clientPublish"],
                   "supportedEncodings": ["json", "cdr"], "metadata": {}})
        } else {
            json!({"op": "serverInfo", "name": name, "capabilities": [], "metadata": {}})
        };
        Hub {
            sink: SinkId::next(),
            info: Message::text(info.to_string()),
            state: Mutex::new(State::default()),
            left: Notify::new(),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // Nothing done under the lock panics; were it poisoned, the state is still whole.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Adds a client: its outbox holds the server's info and the channels' advertisement.
    fn join(&self, peer: SocketAddr) -> (u64, Arc<Notify>) {
        let mut state = self.state();
        let id = state.next_client;
        state.next_client += 1;
        let wake = Arc::new(Notify::new());
        let mut slot = Slot {
            subscriptions: BTreeMap::new(),
            outbox: Outbox::default(),
            wake: Arc::clone(&wake),
            cut: false,
            peer,
        };
        slot.push(self.info.clone(), false);
        if !state.channels.is_empty() {
            slot.push(advertise(state.channels.values()), false);
        }
        state.clients.insert(id, slot);
        (id, wake)
    }

    /// Removes client `id`; the message data dropped for it.
    fn leave(&self, id: u64) -> u64 {
        let dropped = self
            .state()
            .clients
            .remove(&id)
            .map_or(0, |slot| slot.outbox.dropped());
        self.left.notify_waiters();
        dropped
    }

    fn next(&self, id: u64) -> Next {
        let mut state = self.state();
        let closing = state.closing;
        let Some(slot) = state.clients.get_mut(&id) else {
            return Next::Cut;
        };
        if slot.cut {
            return Next::Cut;
        }
        if closing {
            slot.outbox.drop_data();
        }
        match slot.outbox.pop() {
            Some(message) => Next::Write(message),
            None if closing => Next::Close,
            None => Next::Wait,
        }
    }

    /// Queues `message` for client `id` (never dropped).
    fn reply(&self, id: u64, message: Message) {
        if let Some(slot) = self.state().clients.get_mut(&id) {
            slot.push(message, false);
        }
    }

    /// Subscribes client `id` to `channel` as `subscription`.
    fn subscribe(&self, id: u64, subscription: u32, channel: u64) -> Result<(), String> {
        let mut state = self.state();
        if !state.channels.contains_key(&channel) {
            return Err(format!("no channel {channel}"));
        }
        let slot = state.clients.get_mut(&id).ok_or("not connected")?;
        if slot.subscriptions.contains_key(&subscription) {
            return Err(format!("subscription {subscription} is taken"));
        }
        if slot.subscriptions.values().any(|&c| c == channel) {
            return Err(format!("channel {channel} is subscribed to already"));
        }
        slot.subscriptions.insert(subscription, channel);
        Ok(())
    }

    /// Ends client `id`'s `subscription`.
    fn unsubscribe(&self, id: u64, subscription: u32) -> Result<(), String> {
        self.state()
            .clients
            .get_mut(&id)
            .and_then(|slot| slot.subscriptions.remove(&subscription))
            .map(|_| ())
            .ok_or_else(|| format!("no subscription {subscription}"))
    }

    /// Sends every client its close (after what waits for it but message data) and waits for
    /// them to leave; `false` when some were still there when `wait` passed.
    pub(super) async fn close(&self, wait: std::time::Duration) -> bool {
        {
            let mut state = self.state();
            state.closing = true;
            for slot in state.clients.values() {
                slot.wake.notify_one();
            }
        }
        tokio::time::timeout(wait, async {
            loop {
                let left = self.left.notified();
                if self.state().clients.is_empty() {
                    return;
                }
                left.await;
            }
        })
        .await
        .is_ok()
    }
}

impl Sink for Hub {
    fn id(&self) -> SinkId {
        self.sink
    }

    fn log(
        &self,
        channel: &RawChannel,
        msg: &[u8],
        metadata: &Metadata,
    ) -> Result<(), FoxgloveError> {
        let channel = u64::from(channel.id());
        let mut state = self.state();
        for slot in state.clients.values_mut() {
            let subscribed = slot
                .subscriptions
                .iter()
                .find_map(|(&sub, &c)| (c == channel).then_some(sub));
            if let Some(subscription) = subscribed {
                let mut frame = Vec::with_capacity(13 + msg.len());
                frame.push(MESSAGE_DATA);
                frame.extend_from_slice(&subscription.to_le_bytes());
                frame.extend_from_slice(&metadata.log_time.to_le_bytes());
                frame.extend_from_slice(msg);
                slot.push(Message::binary(frame), true);
            }
        }
        Ok(())
    }

    fn add_channels(&self, channels: &[&Arc<RawChannel>]) -> Option<Vec<ChannelId>> {
        let mut state = self.state();
        for &channel in channels {
            state
                .channels
                .insert(u64::from(channel.id()), Arc::clone(channel));
        }
        if !channels.is_empty() {
            let message = advertise(channels.iter().copied());
            for slot in state.clients.values_mut() {
                slot.push(message.clone(), false);
            }
        }
        None
    }

    fn remove_channel(&self, channel: &RawChannel) {
        let id = u64::from(channel.id());
        let mut state = self.state();
        state.channels.remove(&id);
        let message = Message::text(json!({"op": "unadvertise", "channelIds": [id]}).to_string());
        for slot in state.clients.values_mut() {
            slot.subscriptions.retain(|_, c| *c != id);
            slot.push(message.clone(), false);
        }
    }
}

/// The `advertise` message of `channels`: each with its encoding and schema (binary schemas
/// base64-encoded, as the protocol carries them in JSON).
fn advertise<'a>(channels: impl IntoIterator<Item = &'a Arc<RawChannel>>) -> Message {
    let channels: Vec<Value> = channels
        .into_iter()
        .map(|c| {
            let mut v = json!({"id": u64::from(c.id()), "topic": c.topic(),
                               "encoding": c.message_encoding(), "schemaName": "", "schema": ""});
            if let Some(schema) = c.schema() {
                let data = if matches!(schema.encoding.as_str(), "protobuf" | "flatbuffer") {
                    base64::engine::general_purpose::STANDARD.encode(&schema.data)
                } else {
                    String::from_utf8_lossy(&schema.data).into_owned()
                };
                v["schemaName"] = json!(schema.name);
                v["schemaEncoding"] = json!(schema.encoding);
                v["schema"] = json!(data);
            }
            v
        })
        .collect();
    Message::text(json!({"op": "advertise", "channels": channels}).to_string())
}

/// What a client sent that the view does not take: counted, answered once, logged once.
#[derive(Debug, Default)]
struct Untaken {
    count: u64,
    first: Option<String>,
}

/// A control message from a client.
#[derive(Debug, Deserialize)]
#[serde(tag = "op", rename_all = "camelCase")]
enum FromClient {
    Subscribe {
        subscriptions: Vec<Subscription>,
    },
    Unsubscribe {
        #[serde(rename = "subscriptionIds")]
        subscription_ids: Vec<u32>,
    },
    Advertise {
        channels: Vec<ClientChannel>,
    },
    Unadvertise {
        #[serde(rename = "channelIds")]
        channel_ids: Vec<u32>,
    },
}

#[derive(Debug, Deserialize)]
struct Subscription {
    id: u32,
    #[serde(rename = "channelId")]
    channel_id: u64,
}

/// A channel a client publishes on.
#[derive(Debug, Deserialize)]
struct ClientChannel {
    id: u32,
    topic: String,
    encoding: String,
}

/// One client, its WebSocket open: its outbox written out, what it sends read, until either
/// side closes (or the hub closes it). `commands`: where what it publishes goes; `None`: it may
/// publish nothing.
pub(super) async fn serve<S>(
    hub: Arc<Hub>,
    ws: WebSocketStream<S>,
    peer: SocketAddr,
    commands: Option<Arc<Commands>>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (id, wake) = hub.join(peer);
    let (mut tx, mut rx) = ws.split();
    let write = async {
        loop {
            match hub.next(id) {
                Next::Write(message) => tx.send(message).await?,
                Next::Wait => wake.notified().await,
                Next::Close => return tx.send(Message::Close(None)).await,
                Next::Cut => {
                    warn!(%peer, "a Foxglove client let the server's own messages pile up: cut off");
                    return Ok(());
                }
            }
        }
    };
    let mut untaken = Untaken::default();
    let mut channels: BTreeMap<u32, ClientChannel> = BTreeMap::new();
    let read = async {
        while let Some(message) = rx.next().await {
            let message = match message {
                // A message over the gate's limit, not read: the connection ends (its size as
                // the client gave it, and the limit).
                Err(WsError::Capacity(CapacityError::MessageTooLong { size, max_size })) => {
                    return Ok(Some((size, max_size)));
                }
                other => other?,
            };
            let taken = match message {
                Message::Text(text) => control(&hub, id, &text, commands.is_some(), &mut channels),
                Message::Binary(bytes) => publish(&bytes, commands.as_deref(), &channels),
                Message::Close(_) => break,
                _ => Ok(()),
            };
            if let Err(why) = taken {
                untaken.count += 1;
                if untaken.first.is_none() {
                    let status = json!({"op": "status", "level": STATUS_ERROR, "message": why});
                    hub.reply(id, Message::text(status.to_string()));
                    untaken.first = Some(why);
                }
            }
        }
        Ok::<_, WsError>(None)
    };
    let ended = tokio::select! {
        written = write => written.map(|()| None),
        read = read => read,
    };
    let dropped = hub.leave(id);
    match ended {
        Ok(None) => {}
        Ok(Some((size, limit))) => {
            warn!(%peer, size, limit, "a Foxglove client sent a message over the size limit: closed with 1009 (Message Too Big)");
            if let Ok(ws) = rx.reunite(tx) {
                close_too_big(ws, peer, limit).await;
            }
        }
        Err(e) => debug!(%peer, error = %e, "a Foxglove connection ended"),
    }
    if dropped > 0 {
        debug!(%peer, dropped, "a Foxglove client that fell behind left");
    }
    if let Some(first) = untaken.first {
        warn!(%peer, count = untaken.count, first = %first, "a Foxglove client sent messages the view does not take");
    }
}

/// Closes `ws`, whose client sent a message over `limit` bytes: a close frame with code 1009
/// (Message Too Big) and the limit, then the end of what the server sends. What the client
/// still sends is read and dropped until it hangs up (within [`TOO_BIG_WAIT`]), so that
/// closing a socket with unread data in it does not reset the connection under the close.
async fn close_too_big<S>(mut ws: WebSocketStream<S>, peer: SocketAddr, limit: usize)
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let close = CloseFrame {
        code: CloseCode::Size,
        reason: format!("a message over the limit of {limit} bytes").into(),
    };
    let hang_up = async {
        ws.close(Some(close)).await.map_err(std::io::Error::other)?;
        // The rest is read from the socket itself: the WebSocket's reader would gather the
        // oversized message.
        let socket = ws.get_mut();
        socket.shutdown().await?;
        let mut unread = [0u8; 4096];
        while socket.read(&mut unread).await? > 0 {}
        Ok::<_, std::io::Error>(())
    };
    if let Ok(Err(e)) = tokio::time::timeout(TOO_BIG_WAIT, hang_up).await {
        debug!(%peer, error = %e, "a Foxglove client sent a message over the size limit hung up");
    }
}

/// Takes a control message of client `id`.
fn control(
    hub: &Hub,
    id: u64,
    text: &str,
    publishing: bool,
    channels: &mut BTreeMap<u32, ClientChannel>,
) -> Result<(), String> {
    let message: FromClient =
        serde_json::from_str(text).map_err(|e| format!("a message not taken: {e}"))?;
    match message {
        FromClient::Subscribe { subscriptions } => {
            let mut refused = Ok(());
            for s in subscriptions {
                if let Err(e) = hub.subscribe(id, s.id, s.channel_id) {
                    refused = Err(e);
                }
            }
            refused
        }
        FromClient::Unsubscribe { subscription_ids } => {
            let mut refused = Ok(());
            for s in subscription_ids {
                if let Err(e) = hub.unsubscribe(id, s) {
                    refused = Err(e);
                }
            }
            refused
        }
        FromClient::Advertise { channels: new } if publishing => {
            for c in new {
                debug!(topic = %c.topic, encoding = %c.encoding, "a Foxglove client advertised");
                channels.insert(c.id, c);
            }
            Ok(())
        }
        FromClient::Advertise { .. } => {
            Err("this server takes no publishing (accept_commands = false)".to_owned())
        }
        FromClient::Unadvertise { channel_ids } => {
            for c in channel_ids {
                channels.remove(&c);
            }
            Ok(())
        }
    }
}

/// Takes a binary message of a client: message data on a channel it advertised.
fn publish(
    bytes: &[u8],
    commands: Option<&Commands>,
    channels: &BTreeMap<u32, ClientChannel>,
) -> Result<(), String> {
    let Some((&MESSAGE_DATA, rest)) = bytes.split_first() else {
        return Err(format!(
            "a binary message of op {:?}: only message data (1) is taken",
            bytes.first()
        ));
    };
    let Some((id, payload)) = rest.split_first_chunk::<4>() else {
        return Err("message data cut short".to_owned());
    };
    let id = u32::from_le_bytes(*id);
    let (Some(commands), Some(channel)) = (commands, channels.get(&id)) else {
        return Err(format!("message data on channel {id}, not advertised"));
    };
    commands.take(&channel.topic, &channel.encoding, payload);
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use foxglove::{Context, Schema};

    use super::*;

    /// What waits for client `id`, taken out.
    fn waiting(hub: &Hub, id: u64) -> Vec<Message> {
        let mut out = Vec::new();
        while let Next::Write(message) = hub.next(id) {
            out.push(message);
        }
        out
    }

    fn op(message: &Message) -> Value {
        serde_json::from_str(message.to_text().unwrap()).unwrap()
    }

    #[test]
    fn a_client_gets_the_info_the_channels_and_the_data_it_subscribed_to_until_it_unsubscribes() {
        let hub = Hub::new("arm", false);
        let peer = SocketAddr::from(([127, 0, 0, 1], 1));
        let (id, _) = hub.join(peer);
        let context = Context::new();
        let schema = Schema::new("foxglove.Log", "protobuf", &b"\x01\x02\x03"[..]);
        let channel = context
            .channel_builder("/arm/log")
            .message_encoding("protobuf")
            .schema(schema)
            .build_raw()
            .unwrap();
        hub.add_channels(&[&channel]);
        let first = waiting(&hub, id);
        assert_eq!(op(&first[0])["op"], "serverInfo");
        assert_eq!(op(&first[0])["capabilities"], json!([]));
        let advertised = &op(&first[1])["channels"][0];
        assert_eq!(advertised["topic"], "/arm/log");
        assert_eq!(advertised["schemaEncoding"], "protobuf");
        assert_eq!(
            advertised["schema"], "AQID",
            "protobuf schemas go base64-encoded"
        );

        let channel_id = u64::from(channel.id());
        let meta = Metadata { log_time: 7 };
        hub.log(&channel, b"before", &meta).unwrap();
        assert!(waiting(&hub, id).is_empty(), "not subscribed yet");
        let subscribe =
            json!({"op": "subscribe", "subscriptions": [{"id": 3, "channelId": channel_id}]});
        let mut channels = BTreeMap::new();
        control(&hub, id, &subscribe.to_string(), false, &mut channels).unwrap();
        hub.log(&channel, b"after", &meta).unwrap();
        let data = waiting(&hub, id);
        let mut expected = vec![MESSAGE_DATA];
        expected.extend_from_slice(&3u32.to_le_bytes());
        expected.extend_from_slice(&7u64.to_le_bytes());
        expected.extend_from_slice(b"after");
        assert_eq!(data, [Message::binary(expected)]);

        let unsubscribe = json!({"op": "unsubscribe", "subscriptionIds": [3]});
        control(&hub, id, &unsubscribe.to_string(), false, &mut channels).unwrap();
        hub.log(&channel, b"later", &meta).unwrap();
        assert!(waiting(&hub, id).is_empty(), "unsubscribed");
        // Refused: a channel that is not there, publishing without accept_commands, garbage.
        let unknown = json!({"op": "subscribe", "subscriptions": [{"id": 4, "channelId": 999}]});
        assert!(control(&hub, id, &unknown.to_string(), false, &mut channels).is_err());
        let advertise = json!({"op": "advertise", "channels": [
            {"id": 1, "topic": "/arm/cmd_vel", "encoding": "json", "schemaName": "x"}]});
        assert!(control(&hub, id, &advertise.to_string(), false, &mut channels).is_err());
        assert!(channels.is_empty());
        assert!(control(&hub, id, "garbage", false, &mut channels).is_err());
        assert!(publish(b"\xff garbage", None, &channels).is_err());
        assert!(
            publish(b"\x01\x01\x00", None, &channels).is_err(),
            "cut short"
        );
        assert_eq!(hub.leave(id), 0);
    }
}
