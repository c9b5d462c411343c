//! The JSON-lines TCP server: the socket side of the daemon.
//!
//! [`serve`] accepts clients until its shutdown future resolves, then stops them, lets each flush
//! what it owes for a moment, and returns. Each client gets one task that reads its request
//! lines as they come (`session`) and, beside it, a writer that sends its replies and events in
//! order and its telemetry (`writer`):
//!
//! - A client's first line is due within [`AUTH_GRACE`]; with a token
//!   ([`ServerOptions::token`]) it must be `auth` with it, and anything else is answered
//!   `unauthorized` and the connection closed.
//! - Where a command goes is [`Cmd::route`]'s to say: a `SessionCmd` (`describe`,
//!   `subscribe`, `unsubscribe`, `take_control`, `release`, `auth`) is answered here; a
//!   [`LoopCmd`] is first put to the [`Arbiter`] (one controller at a time; a command that needs
//!   control from anyone else is answered `not_in_control`), then goes to the loop at once
//!   without waiting for room (full: `busy`): `stop` and `estop` through [`Handle::stops`], the
//!   rest through [`Handle::commands`]. Its reply is written when the loop answers, after the
//!   replies to the client's earlier requests.
//! - Events from [`Handle::events`] meant for this client, or for everyone, and every change of
//!   controller (a `control` event), are written as event lines between replies, all written
//!   by [`protocol::event_line`].
//! - Telemetry is not queued: the writer reads the latest snapshot from [`Handle::telemetry`] at
//!   the subscribed rate and skips it when nothing changed, so a slow reader sees fewer samples,
//!   never a backlog. Telemetry lines and `status` replies are a [`Status`]: the snapshot with
//!   `controller` (the holder's client id, or `null`) and `in_control` (whether it is this
//!   client), filled in here: the loop does not know.
//! - At `max_clients`, one more connection is still heard for a `stop` or an `estop`
//!   (`over_the_limit`); anything else is answered `too_many_clients`.
//!
//! Nothing here ever waits on the loop's room, and only a client's own task waits on the
//! client: one that does not read for [`SLOW_READER`] while lines wait for it is disconnected;
//! the loop and the other clients go on.

mod lines;
mod session;
mod writer;

use std::future::Future;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc::error::TrySendError;
use tokio::sync::{broadcast, oneshot, watch, Notify, OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinSet;
use tokio::time;
use tracing::{debug, error, warn};

use self::lines::{Line, LineReader};
pub use self::session::{ANSWERS_WAITING, COMMANDS_IN_FLIGHT, STOPS_IN_FLIGHT};
pub use self::writer::{SEND_BUFFER, SLOW_READER};
use super::access::Token;
use super::arbiter::{Arbiter, Change};
use super::link::{Answer, Envelope, Handle, COMMAND_QUEUE, STOP_QUEUE};
use crate::protocol::{
    self, ClientId, Cmd, Code, Describe, Event, Fields, LoopCmd, Rejection, Reply, RequestId,
    Route, Status, Telemetry,
};

/// Lines one client's writer holds ready to send (replies and events; telemetry is not queued).
pub const CLIENT_QUEUE: usize = 256;

/// How long a closing connection may take to send what it has queued.
pub const FLUSH_GRACE: Duration = Duration::from_millis(500);

/// How long a client may take to send its first line (its `auth` line when a token is set): a
/// connection that says nothing must not hold one of the `max_clients` places for long.
pub const AUTH_GRACE: Duration = Duration::from_secs(10);

/// Connections over `max_clients` heard at once for a `stop` or `estop`
/// ([`over_the_limit`]); past them a connection is answered `too_many_clients` at once.
const SPARE_CONNECTIONS: usize = 8;

/// `control` events the broadcast holds for a client that is behind (it then misses the
/// oldest; `status` still says who is in control).
const CONTROL_QUEUE: usize = 64;

/// Consecutive failed accepts (with a growing pause between them, up to a second) before
/// [`serve`] gives up and returns the error.
const MAX_ACCEPT_FAILURES: u32 = 20;

/// How the server is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerOptions {
    /// The token a client's first line must carry (`[server] token_file`); `None`: no `auth`
    /// needed (an `auth` line is then answered ok).
    pub token: Option<Token>,
    /// How long a client may take to send its `auth` line ([`AUTH_GRACE`]).
    pub auth_grace: Duration,
    /// The arm's joint count, against which requests are checked.
    pub joints: usize,
    /// Clients served at once; one more is answered `too_many_clients` and closed.
    pub max_clients: usize,
    /// Lines each client's writer holds ready ([`CLIENT_QUEUE`]).
    pub client_queue: usize,
    /// How long a closing connection may take to flush ([`FLUSH_GRACE`]).
    pub flush_grace: Duration,
}

impl ServerOptions {
    /// The options for an arm of `joints` joints and at most `max_clients` clients, no token,
    /// the rest at their defaults.
    pub fn new(joints: usize, max_clients: usize) -> Self {
        ServerOptions {
            token: None,
            auth_grace: AUTH_GRACE,
            joints,
            max_clients,
            client_queue: CLIENT_QUEUE,
            flush_grace: FLUSH_GRACE,
        }
    }

    /// These options with clients asked for `token` first (none when `None`).
    pub fn with_token(self, token: Option<Token>) -> Self {
        ServerOptions { token, ..self }
    }
}

/// Serves JSON-lines clients on `listener` until `shutdown` resolves, on the tokio runtime that
/// polls it.
///
/// # Behavior
/// Clients are numbered from 1 in accept order; the number is also the client's id as a
/// controller (see [`Arbiter`]). At most `options.max_clients` are served at once
/// (a semaphore); one more receives a `too_many_clients` error line and is closed. When `shutdown`
/// resolves the server stops accepting, tells every client task to stop, gives each
/// [`ServerOptions::flush_grace`] to send what it has queued, closes what is still open after
/// twice that, and returns.
///
/// # Returns
/// `Ok(())` after a shutdown; the error of `accept` after 20 failures in a row
/// (each logged; a pause that doubles from 10 ms to 1 s between them).
pub async fn serve(
    listener: TcpListener,
    handle: Handle,
    options: ServerOptions,
    shutdown: impl Future<Output = ()>,
) -> io::Result<()> {
    Server::new(handle, options).serve(listener, shutdown).await
}

/// The server before it serves: [`Server::door`] hands out ways in for sources of commands
/// other than its socket clients, then [`Server::serve`] runs it as [`serve`] does.
pub struct Server {
    shared: Arc<Shared>,
}

impl Server {
    /// A server for the loop behind `handle`.
    pub fn new(handle: Handle, options: ServerOptions) -> Server {
        let shared = Arc::new(Shared {
            loop_rate_hz: handle.describe.rate_hz,
            handle,
            joints: options.joints,
            max_clients: options.max_clients,
            client_queue: options.client_queue.max(1),
            flush_grace: options.flush_grace,
            token: options.token,
            auth_grace: options.auth_grace,
            arbiter: Mutex::new(Arbiter::new()),
            control: broadcast::channel(CONTROL_QUEUE).0,
            next_id: AtomicU64::new(1),
        });
        Server { shared }
    }

    /// A way in for commands that do not come from a socket client (the Zenoh bridge): it
    /// takes the next controller id, so the arbiter, the queue and the loop treat it as one
    /// more client.
    pub fn door(&self) -> Door {
        Door {
            id: self.shared.take_id(),
            shared: Arc::clone(&self.shared),
        }
    }

    /// Serves clients on `listener` until `shutdown` resolves (see [`serve`]).
    pub async fn serve(
        self,
        listener: TcpListener,
        shutdown: impl Future<Output = ()>,
    ) -> io::Result<()> {
        let shared = self.shared;
        // Accepted connections hold a permit; none left means `too_many_clients`.
        let limit = Arc::new(Semaphore::new(
            shared.max_clients.min(Semaphore::MAX_PERMITS),
        ));
        // Connections beyond the limit, heard for one `stop` or `estop` before they close.
        let spare = Arc::new(Semaphore::new(SPARE_CONNECTIONS));
        // Dropped at shutdown: every client task's receiver then resolves and the task stops.
        let (stop_tx, stop_rx) = watch::channel(());
        let mut tasks = JoinSet::new();
        let mut failures = 0u32;
        let mut pause = Duration::from_millis(10);
        tokio::pin!(shutdown);

        let result = loop {
            tokio::select! {
                () = &mut shutdown => break Ok(()),
                Some(done) = tasks.join_next(), if !tasks.is_empty() => report_panic(done),
                accepted = listener.accept() => match accepted {
                    Ok((stream, peer)) => {
                        failures = 0;
                        pause = Duration::from_millis(10);
                        match Arc::clone(&limit).try_acquire_owned() {
                            Ok(permit) => {
                                let id = shared.take_id();
                                debug!(client = id, %peer, "client connected");
                                let client = session::client(id, stream, Arc::clone(&shared), stop_rx.clone());
                                tasks.spawn(async move {
                                    client.await;
                                    drop::<OwnedSemaphorePermit>(permit);
                                });
                            }
                            Err(_) => match Arc::clone(&spare).try_acquire_owned() {
                                Ok(permit) => {
                                    let id = shared.take_id();
                                    debug!(client = id, %peer, max = shared.max_clients, "over the limit: heard for a stop only");
                                    let over = over_the_limit(id, stream, Arc::clone(&shared), stop_rx.clone());
                                    tasks.spawn(async move {
                                        over.await;
                                        drop::<OwnedSemaphorePermit>(permit);
                                    });
                                }
                                Err(_) => {
                                    debug!(%peer, max = shared.max_clients, "client refused: too many");
                                    tasks.spawn(refuse(stream, shared.max_clients, shared.flush_grace));
                                }
                            },
                        }
                    }
                    Err(e) => {
                        failures += 1;
                        if failures >= MAX_ACCEPT_FAILURES {
                            error!(error = %e, failures, "accept keeps failing; the server stops");
                            break Err(e);
                        }
                        warn!(error = %e, pause_ms = pause.as_millis(), "accept failed");
                        time::sleep(pause).await;
                        pause = (pause * 2).min(Duration::from_secs(1));
                    }
                },
            }
        };

        drop(listener);
        drop(stop_tx);
        let drained = time::timeout(2 * shared.flush_grace, async {
            while let Some(done) = tasks.join_next().await {
                report_panic(done);
            }
        })
        .await;
        if drained.is_err() {
            warn!(
                open = tasks.len(),
                "connections still open at shutdown; closing them"
            );
            tasks.shutdown().await;
        }
        debug!("server stopped");
        result
    }
}

/// A source of commands beside the socket's clients, under one controller id of its own
/// ([`Server::door`]): its commands meet the same [`Arbiter`] and the same bounded queue as a
/// client's, so it cannot pass an estop, a limit or another client's control. Nothing here
/// waits: a full queue is `busy`. Dropping it gives back control it holds.
pub struct Door {
    id: ClientId,
    shared: Arc<Shared>,
}

impl Door {
    /// Its controller id (what `status` and `control` events name when it holds control).
    pub fn id(&self) -> ClientId {
        self.id
    }

    /// Who holds control.
    pub fn holder(&self) -> Option<ClientId> {
        self.shared.holder()
    }

    /// Puts `cmd` to the arbiter and, admitted, queues it for the loop; the loop's answer
    /// arrives on the returned receiver. Refused at once: `not_in_control`, `busy`, or the loop
    /// gone. What the server answers itself (`describe`, `subscribe`, `take_control`, ...) is
    /// refused `bad_arg`: a door moves, stops and asks for status, nothing else.
    pub fn send(&self, cmd: Cmd) -> Result<oneshot::Receiver<Answer>, Rejection> {
        match cmd.route() {
            Route::Loop(cmd) => self.shared.submit(self.id, None, cmd, Instant::now(), None),
            Route::Session(cmd) => Err(Rejection::new(
                Code::BadArg,
                format!("`{}` is not taken through this door", cmd.name()),
            )),
        }
    }

    /// Lets go of control if this door holds it (everyone is told); whether it did.
    pub fn release(&self) -> bool {
        let mut arbiter = self.shared.arbiter();
        match arbiter.release(self.id) {
            Some(change) => {
                self.shared.announce(&change, None);
                true
            }
            None => false,
        }
    }

    /// The loop's latest telemetry (latest wins: reading it never holds the loop up).
    pub fn telemetry(&self) -> watch::Receiver<Telemetry> {
        self.shared.handle.telemetry.clone()
    }

    /// Notified each time a tick's work is done: what publishes in the loop's idle time waits
    /// for it (the loop wakes it outside its tick).
    pub fn tick_done(&self) -> Arc<Notify> {
        Arc::clone(&self.shared.handle.tick_done)
    }

    /// The loop's events, from now on.
    pub fn events(&self) -> broadcast::Receiver<Event> {
        self.shared.handle.events.subscribe()
    }

    /// The arm's description: the `describe` reply.
    pub fn describe(&self) -> &Arc<Describe> {
        &self.shared.handle.describe
    }

    /// `telemetry` as the socket's telemetry line, with `controller` and `in_control` (whether
    /// this door holds control).
    pub fn telemetry_line(&self, telemetry: &Telemetry) -> String {
        protocol::telemetry_line(&self.shared.status(telemetry, self.id))
    }

    /// `telemetry` as the socket's `status` reply (id null), with `controller` and
    /// `in_control`.
    pub fn status_line(&self, telemetry: &Telemetry) -> String {
        let status = self.shared.status(telemetry.clone(), self.id);
        protocol::ok_line(None, &Reply::Status(Box::new(status)).into())
    }

    /// The `describe` reply (id null).
    pub fn describe_line(&self) -> String {
        let describe = Arc::clone(self.describe());
        protocol::ok_line(None, &Reply::Describe(describe).into())
    }
}

impl std::fmt::Debug for Door {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Door").field("id", &self.id).finish()
    }
}

impl Drop for Door {
    fn drop(&mut self) {
        self.release();
    }
}

fn report_panic(done: Result<(), tokio::task::JoinError>) {
    if let Err(e) = done {
        if e.is_panic() {
            error!(error = %e, "a client task panicked");
        }
    }
}

/// What every client task reads.
struct Shared {
    handle: Handle,
    loop_rate_hz: f64,
    joints: usize,
    max_clients: usize,
    client_queue: usize,
    flush_grace: Duration,
    token: Option<Token>,
    auth_grace: Duration,
    /// Who is in control. Locked briefly, never across an await.
    arbiter: Mutex<Arbiter>,
    /// `control` events, for every client.
    control: broadcast::Sender<Event>,
    /// The next controller id to hand out (clients and doors share the space).
    next_id: AtomicU64,
}

impl Shared {
    fn arbiter(&self) -> MutexGuard<'_, Arbiter> {
        // The arbiter's state is one field, whole after any panic.
        self.arbiter.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The client in control.
    fn holder(&self) -> Option<ClientId> {
        self.arbiter().holder()
    }

    /// `telemetry` as `me` sees it: with the holder of control, and whether that is `me`.
    fn status<T>(&self, telemetry: T, me: ClientId) -> Status<T> {
        let holder = self.holder();
        Status {
            telemetry,
            controller: holder,
            in_control: holder == Some(me),
        }
    }

    /// Fills in who is in control, as `me` sees it, when the loop's answer is a `status`.
    fn add_control(&self, fields: &mut Fields, me: ClientId) {
        if let Reply::Status(status) = &mut fields.reply {
            let holder = self.holder();
            status.controller = holder;
            status.in_control = holder == Some(me);
        }
    }

    fn take_id(&self) -> ClientId {
        self.next_id.fetch_add(1, AtomicOrdering::Relaxed)
    }

    /// Puts `cmd` from `who` to the arbiter and, admitted, queues it for the loop without
    /// waiting for room (full: `busy`, and control taken for it is given back). `later` is
    /// told if the loop keeps the answer past the tick that takes the command.
    fn submit(
        &self,
        who: ClientId,
        id: Option<RequestId>,
        cmd: LoopCmd,
        received: Instant,
        later: Option<oneshot::Sender<()>>,
    ) -> Result<oneshot::Receiver<Answer>, Rejection> {
        let (reply, answer) = oneshot::channel();
        // Admission and queueing under one lock: once a `take_control` is answered, no
        // command of the previous holder's enters the queue.
        let mut arbiter = self.arbiter();
        let change = arbiter.admit(who, &cmd)?;
        let envelope = Envelope {
            client: who,
            id: id.clone(),
            cmd,
            received,
            reply,
            later,
        };
        let queue = match envelope.cmd {
            LoopCmd::Stop | LoopCmd::Estop => &self.handle.stops,
            _ => &self.handle.commands,
        };
        let sent = queue.try_send(envelope);
        if sent.is_err() && change.is_some() {
            // Not taken after all: the command that would have taken it never went.
            arbiter.release(who);
        }
        match sent {
            Ok(()) => {
                if let Some(change) = change {
                    self.announce(&change, id.as_ref());
                }
                Ok(answer)
            }
            Err(TrySendError::Full(e)) => Err(Rejection::new(
                Code::Busy,
                match e.cmd {
                    LoopCmd::Stop | LoopCmd::Estop => {
                        format!("the loop's stop queue is full ({STOP_QUEUE}); send again")
                    }
                    _ => format!("the loop's command queue is full ({COMMAND_QUEUE}); send again"),
                },
            )),
            Err(TrySendError::Closed(_)) => Err(stopped()),
        }
    }

    /// Tells every client of `change` (called with the arbiter locked, so that announcements
    /// keep the order of the changes).
    fn announce(&self, change: &Change, cmd_id: Option<&RequestId>) {
        let tick = self.handle.telemetry.borrow().tick;
        debug!(holder = ?change.holder, previous = ?change.previous, "control changed");
        // No receiver (no client left to tell) is not an error.
        let _ = self.control.send(change.event(cmd_id.cloned(), tick));
    }

    /// Whether `token` is the one asked for (any, when none is).
    fn admits(&self, token: &str) -> bool {
        self.token
            .as_ref()
            .is_none_or(|t| t.matches(token.as_bytes()))
    }

    /// A subscription's rate: the one asked for, at most the loop's.
    fn telemetry_rate(&self, asked_hz: f64) -> f64 {
        if self.loop_rate_hz.is_finite() && self.loop_rate_hz > 0.0 {
            asked_hz.min(self.loop_rate_hz)
        } else {
            asked_hz
        }
    }
}

/// Answers a connection over the limit and closes it. The client's own bytes are read (and
/// dropped) for a moment so that closing does not reset the connection before it read the line.
async fn refuse(mut stream: TcpStream, max_clients: usize, grace: Duration) {
    let why = Rejection::new(
        Code::TooManyClients,
        format!("the daemon serves at most {max_clients} clients at once"),
    );
    let line = protocol::error_line(None, &why);
    let _ = time::timeout(grace, async {
        stream.write_all(line.as_bytes()).await?;
        stream.shutdown().await?;
        let mut sink = [0u8; 1024];
        while stream.read(&mut sink).await? > 0 {}
        io::Result::Ok(())
    })
    .await;
}

/// A connection beyond `max_clients`, heard for one request before it closes: a `stop` or an
/// `estop` (after `auth` where a token is set) is carried out and answered; anything else is
/// answered `too_many_clients`, as is silence past the first-line deadline. So a full house
/// never keeps an emergency stop out.
async fn over_the_limit(
    id: ClientId,
    stream: TcpStream,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<()>,
) {
    session::prepare(id, &stream);
    let (read, mut write) = stream.into_split();
    let mut lines = LineReader::new(read);
    let full = || {
        Rejection::new(
            Code::TooManyClients,
            format!(
                "the daemon serves at most {} clients at once; over that, only `stop` and \
                 `estop` are taken",
                shared.max_clients
            ),
        )
    };
    let deadline = time::Instant::now() + shared.auth_grace;
    let mut admitted = shared.token.is_none();
    let reply = loop {
        let line = tokio::select! {
            biased;
            _ = stop.changed() => return,
            line = time::timeout_at(deadline, lines.next()) => line,
        };
        let line = match line {
            Ok(Ok(Line::Complete(line))) => line,
            Ok(Ok(Line::TooLong)) => break protocol::error_line(None, &full()),
            Ok(Ok(Line::Eof) | Err(_)) => return,
            Err(_) => break protocol::error_line(None, &full()),
        };
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        let request = match protocol::parse(line, shared.joints) {
            Ok(request) => request,
            Err((id, _)) => break protocol::error_line(id.as_deref(), &full()),
        };
        let rid = request.id;
        match request.cmd {
            Cmd::Auth { token } if shared.admits(&token) => {
                admitted = true;
                let me = Reply::Admitted(protocol::Admitted { client: id }).into();
                let ok = protocol::ok_line(rid.as_deref(), &me);
                if write.write_all(ok.as_bytes()).await.is_err() {
                    return;
                }
            }
            Cmd::Auth { .. } => {
                let why = Rejection::new(Code::Unauthorized, "wrong token");
                break protocol::error_line(rid.as_deref(), &why);
            }
            Cmd::Stop | Cmd::Estop if admitted => {
                let Route::Loop(cmd) = request.cmd.route() else {
                    return;
                };
                let answer = match shared.submit(id, rid.clone(), cmd, Instant::now(), None) {
                    Ok(answer) => answer.await.unwrap_or_else(|_| Err(stopped())),
                    Err(why) => Err(why),
                };
                break protocol::reply_line(rid.as_deref(), &answer);
            }
            Cmd::Stop | Cmd::Estop => {
                let why = Rejection::new(
                    Code::Unauthorized,
                    "this daemon asks for a token: the first line must be `auth`",
                );
                break protocol::error_line(rid.as_deref(), &why);
            }
            _ => break protocol::error_line(rid.as_deref(), &full()),
        }
    };
    let _ = time::timeout(shared.flush_grace, async {
        write.write_all(reply.as_bytes()).await?;
        write.shutdown().await?;
        // Read (and drop) what the client still sends for a moment, so that closing does not
        // reset the connection before it read the line.
        while matches!(lines.next().await, Ok(Line::Complete(_) | Line::TooLong)) {}
        io::Result::Ok(())
    })
    .await;
}

fn stopped() -> Rejection {
    Rejection::new(Code::ShuttingDown, "the control loop has stopped")
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::daemon::link;

    /// A server's shared state over a loop nobody runs.
    pub(in crate::daemon::server) fn shared() -> Arc<Shared> {
        let (handle, _ends) = link::channel(Describe::default(), Telemetry::default());
        Server::new(handle, ServerOptions::new(2, 1)).shared
    }
}
