//! The Foxglove view's only way in: the address `[foxglove] listen` names, where each client is
//! checked before the WebSocket handshake and then served by the view itself (`hub`).
//!
//! A client beyond `max_clients` connected at once is answered `503` and closed as soon as it
//! is accepted, its request not waited for. Another's request head is read (within
//! [`GATE_WAIT`], at most [`GATE_HEAD`] bytes); with a `[server]` token, a head whose URL does
//! not carry `?token=<token>` (percent-encoded, compared in constant time) is answered `401`;
//! one that does not ask for the subprotocol `foxglove.sdk.v1`, or is no WebSocket upgrade,
//! `400`. The rest are answered `101` and served. Every client's socket has a small send buffer
//! ([`SEND_BUFFER`]): what waits for a slow client waits in its bounded outbox, where stale
//! data is dropped, not in the kernel.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio::time;
use tokio_tungstenite::tungstenite::handshake::machine::TryParse;
use tokio_tungstenite::tungstenite::handshake::server::{create_response, write_response, Request};
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::protocol::{Role, WebSocketConfig};
use tokio_tungstenite::WebSocketStream;
use tracing::{debug, warn};

use super::access::Token;
use super::hub::{self, Hub, SUBPROTOCOL};
use super::server::SEND_BUFFER;
use super::view::Commands;

/// Longest HTTP request head the gate reads before it refuses a client.
const GATE_HEAD: usize = 8192;

/// How long the gate waits after a failed accept before the next.
const GATE_RETRY: Duration = Duration::from_millis(100);

/// How long a client has to send its request head.
pub(super) const GATE_WAIT: Duration = Duration::from_secs(5);

/// The largest message a client may send, bytes (what it publishes is a few hundred): a larger
/// one ends its connection with a close of code 1009 (`hub::serve`).
const MAX_CLIENT_MESSAGE: usize = 64 * 1024;

/// Who may come in and what they are served.
pub(super) struct Gate {
    /// The `[server]` token every client presents in its URL; `None`: none asked for.
    pub(super) token: Option<Token>,
    /// Most clients connected at once.
    pub(super) max_clients: u32,
    pub(super) hub: Arc<Hub>,
    /// Where what clients publish goes; `None`: they may publish nothing.
    pub(super) commands: Option<Arc<Commands>>,
}

/// Takes clients on `listener` for as long as it runs.
pub(super) async fn keep(listener: TcpListener, gate: Gate) {
    let gate = Arc::new(gate);
    let seats = Arc::new(Semaphore::new(gate.max_clients as usize));
    loop {
        let (client, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // Out of descriptors, say: wait before trying again rather than spin.
                warn!(error = %e, "the Foxglove gate could not accept a client");
                time::sleep(GATE_RETRY).await;
                continue;
            }
        };
        if let Err(e) = socket2::SockRef::from(&client).set_send_buffer_size(SEND_BUFFER) {
            debug!(%peer, error = %e, "SO_SNDBUF not set");
        }
        // Taken before the head is read, so that clients that never send one count too.
        let seat = Arc::clone(&seats).try_acquire_owned().ok();
        let gate = Arc::clone(&gate);
        tokio::spawn(async move {
            if seat.is_none() {
                // Its request is not waited for: a client that is refused anyway holds nothing,
                // not even its descriptor, while it takes its time to send one.
                let why = "[foxglove] max_clients are connected already";
                let _ = refuse(client, "503 Service Unavailable", why).await;
                debug!(%peer, "a Foxglove client turned away: {why}");
                return;
            }
            match pass(client, &gate).await {
                Ok(ws) => {
                    hub::serve(Arc::clone(&gate.hub), ws, peer, gate.commands.clone()).await;
                }
                Err(e) => debug!(%peer, error = %e, "a Foxglove client turned away"),
            }
            drop(seat);
        });
    }
}

/// A client's request head read and checked, and the handshake answered: its WebSocket.
async fn pass(mut client: TcpStream, gate: &Gate) -> std::io::Result<WebSocketStream<TcpStream>> {
    let mut head = Vec::with_capacity(1024);
    let mut buf = [0u8; 1024];
    let read_head = async {
        while !head.windows(4).any(|w| w == b"\r\n\r\n") {
            if head.len() > GATE_HEAD {
                return Err(std::io::Error::other("a request head too long"));
            }
            let got = client.read(&mut buf).await?;
            if got == 0 {
                return Err(std::io::Error::other("closed before its request"));
            }
            head.extend_from_slice(buf.get(..got).unwrap_or_default());
        }
        Ok(())
    };
    time::timeout(GATE_WAIT, read_head)
        .await
        .map_err(|_| std::io::Error::other("no request in time"))??;
    if let Some(token) = &gate.token {
        if !url_token(&head).is_some_and(|given| token.matches(&given)) {
            return Err(refuse(client, "401 Unauthorized", "no token, or the wrong one").await);
        }
    }
    let (size, request) = match Request::try_parse(&head) {
        Ok(Some(parsed)) => parsed,
        Ok(None) => return Err(refuse(client, "400 Bad Request", "a request cut short").await),
        Err(e) => return Err(refuse(client, "400 Bad Request", &e.to_string()).await),
    };
    let asked = request
        .headers()
        .get_all("sec-websocket-protocol")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|p| p.trim() == SUBPROTOCOL);
    if !asked {
        let why = format!("the subprotocol {SUBPROTOCOL} was not asked for");
        return Err(refuse(client, "400 Bad Request", &why).await);
    }
    let mut response = match create_response(&request) {
        Ok(response) => response,
        Err(e) => return Err(refuse(client, "400 Bad Request", &e.to_string()).await),
    };
    response.headers_mut().insert(
        "sec-websocket-protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    let mut answer = Vec::new();
    write_response(&mut answer, &response).map_err(std::io::Error::other)?;
    client.write_all(&answer).await?;
    let config = WebSocketConfig::default()
        .max_message_size(Some(MAX_CLIENT_MESSAGE))
        .max_frame_size(Some(MAX_CLIENT_MESSAGE));
    // What the client sent after its head (it may not wait for the answer) is its first frame.
    let rest = head.get(size..).unwrap_or_default().to_vec();
    Ok(WebSocketStream::from_partially_read(client, rest, Role::Server, Some(config)).await)
}

/// Answers `client` `status`, with `why` as the body, and closes; the error returned says
/// `why`. What the client has sent already is read first (without waiting for more), so that
/// the close does not reset the connection under the answer.
async fn refuse(mut client: TcpStream, status: &str, why: &str) -> std::io::Error {
    let answer = format!(
        "HTTP/1.1 {status}\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{why}\n",
        why.len() + 1
    );
    if let Err(e) = client.write_all(answer.as_bytes()).await {
        return e;
    }
    let mut unread = [0u8; 1024];
    while matches!(client.try_read(&mut unread), Ok(n) if n > 0) {}
    std::io::Error::other(why.to_owned())
}

/// The `token` of the query of a request head's target (`GET /?token=... HTTP/1.1`),
/// percent-decoded; `None` without one, or with a broken escape.
fn url_token(head: &[u8]) -> Option<Vec<u8>> {
    let line = head.split(|&b| b == b'\r').next()?;
    let target = line.split(|&b| b == b' ').nth(1)?;
    let query = target.splitn(2, |&b| b == b'?').nth(1)?;
    let raw = query
        .split(|&b| b == b'&')
        .find_map(|pair| pair.strip_prefix(b"token="))?;
    let mut out = Vec::with_capacity(raw.len());
    let mut bytes = raw.iter();
    while let Some(&b) = bytes.next() {
        if b == b'%' {
            let hex = [*bytes.next()?, *bytes.next()?];
            let hex = std::str::from_utf8(&hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
        } else {
            out.push(b);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use std::net::SocketAddr;

    use super::*;

    #[test]
    fn the_gate_reads_the_token_of_the_url_percent_decoded() {
        let head = |target: &str| format!("GET {target} HTTP/1.1\r\nHost: x\r\n\r\n");
        let token = |target: &str| url_token(head(target).as_bytes());
        assert_eq!(token("/?token=s3cret"), Some(b"s3cret".to_vec()));
        assert_eq!(
            token("/?a=1&token=correct%20horse&b=2"),
            Some(b"correct horse".to_vec())
        );
        assert_eq!(token("/"), None);
        assert_eq!(token("/?tok=s3cret"), None);
        assert_eq!(token("/?token=bad%2"), None, "a cut escape");
        assert_eq!(token("/?token=bad%zz"), None, "not hex");
    }

    /// A gate with `max_clients` seats on a port of its own, no token, nothing to publish.
    async fn gate(max_clients: u32) -> SocketAddr {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let gate = Gate {
            token: None,
            max_clients,
            hub: Arc::new(Hub::new("test", false)),
            commands: None,
        };
        tokio::spawn(keep(listener, gate));
        addr
    }

    const UPGRADE: &str =
        "GET / HTTP/1.1\r\nHost: x\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n\
        Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n";

    /// What the gate answers to `head`, up to the end of its head.
    async fn answer(stream: &mut TcpStream) -> String {
        let mut got = Vec::new();
        let mut byte = [0u8; 1];
        while !got.ends_with(b"\r\n\r\n") && stream.read(&mut byte).await.unwrap() == 1 {
            got.push(byte[0]);
        }
        String::from_utf8_lossy(&got).into_owned()
    }

    #[tokio::test]
    async fn beyond_max_clients_a_client_is_refused_without_waiting_for_its_request() {
        let addr = gate(1).await;
        // The seat taken by a client let through.
        let mut first = TcpStream::connect(addr).await.unwrap();
        let head = format!("{UPGRADE}Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n");
        first.write_all(head.as_bytes()).await.unwrap();
        let answered = answer(&mut first).await;
        assert!(answered.starts_with("HTTP/1.1 101 "), "{answered}");
        // From here no timer of the gate runs but one it starts for the next client: with time
        // paused, its clock jumps to that timer as soon as nothing else is left to do.
        time::pause();
        let paused = time::Instant::now();
        // A second client, which sends nothing.
        let mut second = TcpStream::connect(addr).await.unwrap();
        let mut answer = Vec::new();
        second.read_to_end(&mut answer).await.unwrap();
        let answer = String::from_utf8_lossy(&answer);
        assert!(
            answer.starts_with("HTTP/1.1 503 Service Unavailable\r\n")
                && answer.ends_with("max_clients are connected already\n"),
            "{answer}"
        );
        assert!(
            time::Instant::now() - paused < GATE_WAIT,
            "closed only when the wait for its request ran out"
        );
    }

    #[tokio::test]
    async fn a_request_without_the_subprotocol_or_no_upgrade_is_answered_400() {
        let addr = gate(4).await;
        for head in [
            format!("{UPGRADE}Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"),
            format!("{UPGRADE}\r\n"),
            format!("GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n"),
        ] {
            let mut client = TcpStream::connect(addr).await.unwrap();
            client.write_all(head.as_bytes()).await.unwrap();
            let answered = answer(&mut client).await;
            assert!(answered.starts_with("HTTP/1.1 400 "), "{head}: {answered}");
        }
    }
}
