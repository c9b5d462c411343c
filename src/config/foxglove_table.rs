//! The validated `[foxglove]` table: where the live view serves, how often it publishes, and
//! whether it takes commands.
//!
//! The table is checked in every build. The view follows the socket's rule: it listens beyond
//! loopback only with a `[server] token_file`, and with one every Foxglove client presents the
//! token in its URL (`ws://HOST:PORT/?token=...`; the daemon checks it before the WebSocket
//! handshake).

use std::net::SocketAddr;

use super::raw::{RawFoxglove, DEFAULT_FOXGLOVE_MAX_CLIENTS, DEFAULT_FOXGLOVE_PUBLISH_HZ};
use super::{finite_within, Checker, ConfigError, FieldProblem, Server};

/// The validated `[foxglove]` (no server when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Foxglove {
    /// Where the WebSocket server listens (beyond loopback only with a token; port 0 picks a
    /// free one); `None`: no server.
    pub listen: Option<SocketAddr>,
    /// Publishing rate, Hz, positive and at most `control.rate_hz`.
    pub publish_hz: f64,
    /// Whether a Foxglove client's `Twist` on `cmd_vel` becomes `velocity`, and a `PointStamped`
    /// on `goal` or `reach` a `goto` or a `reach`.
    pub accept_commands: bool,
    /// Most clients connected at once (at least 1); the next is answered `503` and closed.
    pub max_clients: u32,
}

impl Checker<'_> {
    /// Checks `[foxglove]`; `rate_hz` is the validated loop rate, `server` the validated
    /// `[server]` (its token rule applies).
    pub(super) fn foxglove(
        &self,
        raw: RawFoxglove,
        rate_hz: f64,
        server: &Server,
    ) -> Result<Foxglove, ConfigError> {
        let listen = match raw.listen {
            None => None,
            Some(text) => {
                let addr = text.parse::<SocketAddr>().map_err(|e| {
                    self.invalid(
                        "foxglove.listen",
                        FieldProblem::BadAddress {
                            value: text.clone(),
                            reason: e.to_string(),
                        },
                    )
                })?;
                if !addr.ip().to_canonical().is_loopback() && server.token_file.is_none() {
                    return Err(self.invalid("foxglove.listen", FieldProblem::NotLoopback { addr }));
                }
                Some(addr)
            }
        };
        let publish_hz = match raw.publish_hz {
            None => DEFAULT_FOXGLOVE_PUBLISH_HZ.min(rate_hz),
            Some(value) if finite_within(value) && value > 0.0 && value <= rate_hz => value,
            Some(value) => {
                return Err(self.invalid(
                    "foxglove.publish_hz",
                    FieldProblem::AboveLoopRate { value, rate_hz },
                ))
            }
        };
        let max_clients = raw.max_clients.unwrap_or(DEFAULT_FOXGLOVE_MAX_CLIENTS);
        if max_clients == 0 {
            return Err(self.invalid(
                "foxglove.max_clients",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            ));
        }
        if raw.accept_commands && listen.is_none() {
            tracing::warn!(
                "{}: foxglove.accept_commands = true has no effect: without foxglove.listen no \
                 live view is served, so no Foxglove client can connect (set listen, e.g. \
                 \"127.0.0.1:8765\", to take commands from one)",
                self.path.display()
            );
        }
        Ok(Foxglove {
            listen,
            publish_hz,
            accept_commands: raw.accept_commands,
            max_clients,
        })
    }
}
