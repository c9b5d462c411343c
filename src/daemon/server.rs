//! The JSON-lines TCP server: the socket side of the daemon.
//!
//! [`serve`] accepts clients until its shutdown future resolves, then stops them, lets each flush
//! what it has queued for a moment, and returns. Each client gets one task that reads its request
//! lines in order and, beside it, a writer that drains the client's outgoing queue and sends its
//! telemetry:
//!
//! - With a token ([`ServerOptions::token`]) a client's first line must be `auth` with it, within
//!   [`AUTH_GRACE`]; anything else is answered `unauthorized` and the connection closed.
//! - Where a command goes is [`Cmd::route`]'s to say: a [`SessionCmd`] (`describe`,
//!   `subscribe`, `unsubscribe`, `take_control`, `release`, `auth`) is answered here; a
//!   [`LoopCmd`] is first put to the [`Arbiter`] (one controller at a time; a command that needs
//!   control from anyone else is answered `not_in_control`), then goes to the loop through
//!   [`Handle::commands`] without waiting for room (full: `busy`), and its reply is written when
//!   the loop answers, so a client's replies keep the order of its requests.
//! - Events from [`Handle::events`] meant for this client, or for everyone, and every change of
//!   controller (a `control` event), are queued as event lines between replies, all written by
//!   [`protocol::event_line`].
//! - Telemetry is not queued: the writer reads the latest snapshot from [`Handle::telemetry`] at
//!   the subscribed rate and skips it when nothing changed, so a slow reader sees fewer samples,
//!   never a backlog. Telemetry lines and `status` replies are a [`Status`]: the snapshot with
//!   `controller` (the holder's client id, or `null`) and `in_control` (whether it is this
//!   client), filled in here: the loop does not know.
//!
//! Nothing here ever waits on the loop's room, and only a client's own task waits on it: a client
//! whose outgoing queue stays full is disconnected; the loop and the other clients go on.

use std::future::Future;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncReadExt, AsyncWriteExt, BufReader, BufWriter};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::mpsc::error::{SendTimeoutError, TrySendError};
use tokio::sync::{broadcast, mpsc, oneshot, watch, OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinSet;
use tokio::time::{self, Interval, MissedTickBehavior};
use tracing::{debug, error, warn};

use super::access::Token;
use super::arbiter::{Arbiter, Change};
use super::link::{Answer, Envelope, Handle, COMMAND_QUEUE};
use crate::protocol::{
    self, Admitted, ClientId, Cmd, Code, Describe, Event, Fields, LoopCmd, Rejection, Released,
    Reply, RequestId, Route, SessionCmd, Status, Subscribed, Telemetry, TookControl, Unsubscribed,
    MAX_LINE,
};

/// Lines one client's outgoing queue holds (replies and events; telemetry is not queued). A client
/// that leaves it full for [`STALL_GRACE`], by not reading, is disconnected.
pub const CLIENT_QUEUE: usize = 256;

/// How long a client's full outgoing queue may wait for room before the client is disconnected:
/// long enough for a burst (the event broadcast alone holds as many lines as the queue) to drain
/// into a connection that is read, short enough not to hold a stuck one for long.
pub const STALL_GRACE: Duration = Duration::from_secs(1);

/// How long a closing connection may take to send what it has queued.
pub const FLUSH_GRACE: Duration = Duration::from_millis(500);

/// How long a client may take to send its `auth` line when a token is set: a connection that
/// says nothing must not hold one of the `max_clients` places for long.
pub const AUTH_GRACE: Duration = Duration::from_secs(10);

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
    /// Lines each client's outgoing queue holds ([`CLIENT_QUEUE`]).
    pub client_queue: usize,
    /// How long a full outgoing queue may wait for room ([`STALL_GRACE`]).
    pub stall_grace: Duration,
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
            stall_grace: STALL_GRACE,
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
            stall_grace: options.stall_grace,
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
                                let client = client(id, stream, Arc::clone(&shared), stop_rx.clone());
                                tasks.spawn(async move {
                                    client.await;
                                    drop::<OwnedSemaphorePermit>(permit);
                                });
                            }
                            Err(_) => {
                                debug!(%peer, max = shared.max_clients, "client refused: too many");
                                tasks.spawn(refuse(stream, shared.max_clients, shared.flush_grace));
                            }
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
            Route::Loop(cmd) => self.shared.submit(self.id, None, cmd, Instant::now()),
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
    stall_grace: Duration,
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
    /// waiting for room (full: `busy`, and control taken for it is given back).
    fn submit(
        &self,
        who: ClientId,
        id: Option<RequestId>,
        cmd: LoopCmd,
        received: Instant,
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
        };
        let sent = self.handle.commands.try_send(envelope);
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
            Err(TrySendError::Full(_)) => Err(Rejection::new(
                Code::Busy,
                format!("the loop's command queue is full ({COMMAND_QUEUE}); send again"),
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

/// One client from connect to close.
async fn client(
    id: ClientId,
    stream: TcpStream,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<()>,
) {
    if let Err(e) = stream.set_nodelay(true) {
        debug!(client = id, error = %e, "TCP_NODELAY not set");
    }
    // However the client ends, control it holds is freed (and everyone told).
    let _seat = Seat {
        id,
        shared: &shared,
    };
    let (read, write) = stream.into_split();
    let mut lines = LineReader::new(read);
    // Bounded: full for `stall_grace` means the client does not read, and it is disconnected.
    let (out_tx, out_rx) = mpsc::channel(shared.client_queue);
    let (rate_tx, rate_rx) = watch::channel(None);
    let writer = write_loop(
        BufWriter::new(write),
        out_rx,
        shared.handle.telemetry.clone(),
        rate_rx,
        Viewer {
            id,
            shared: &shared,
        },
    );
    tokio::pin!(writer);
    let mut session = Session {
        id,
        shared: &shared,
        out: out_tx,
        rate: rate_tx,
    };
    let end = tokio::select! {
        end = session.run(&mut lines, &mut stop) => end,
        written = &mut writer => {
            match written {
                Ok(()) => debug!(client = id, "client disconnected"),
                Err(e) => debug!(client = id, error = %e, "client disconnected: write failed"),
            }
            return;
        }
    };
    // Closing the queue lets the writer finish once it has sent what is in it.
    drop(session);
    let unauthorized = matches!(end, End::Unauthorized);
    match end {
        End::Overflow => {
            warn!(
                client = id,
                queued = shared.client_queue,
                "client disconnected: it does not read what it is sent"
            );
            return;
        }
        End::Eof => debug!(client = id, "client disconnected"),
        End::Stop => debug!(client = id, "closing client: the server stops"),
        End::WriterGone => debug!(client = id, "client disconnected: write failed"),
        End::ReadFailed(e) => debug!(client = id, error = %e, "client disconnected: read failed"),
        End::Unauthorized => debug!(client = id, "closing client: unauthorized"),
    }
    if time::timeout(shared.flush_grace, writer).await.is_err() {
        debug!(
            client = id,
            "client closed before its replies were all sent"
        );
    }
    if unauthorized {
        // Read (and drop) what the client still sends for a moment, so that closing does not
        // reset the connection before it read its `unauthorized` line.
        let _ = time::timeout(shared.flush_grace, async {
            while matches!(lines.next().await, Ok(Line::Complete(_) | Line::TooLong)) {}
        })
        .await;
    }
}

/// A connected client's place: when it goes, for whatever reason, control it held is freed.
struct Seat<'a> {
    id: ClientId,
    shared: &'a Shared,
}

impl Drop for Seat<'_> {
    fn drop(&mut self) {
        let mut arbiter = self.shared.arbiter();
        if let Some(change) = arbiter.release(self.id) {
            self.shared.announce(&change, None);
        }
    }
}

/// Why a client's reading stopped.
#[derive(Debug)]
enum End {
    /// The client closed its side.
    Eof,
    /// The server stops.
    Stop,
    /// The outgoing queue stayed full.
    Overflow,
    /// The writer stopped (the connection broke).
    WriterGone,
    /// Reading failed.
    ReadFailed(io::Error),
    /// No `auth` line with the right token where one is needed; the client was told.
    Unauthorized,
}

/// The reading side of one client.
struct Session<'a> {
    id: ClientId,
    shared: &'a Shared,
    /// Replies and events, in the order written.
    out: mpsc::Sender<String>,
    /// The telemetry rate, Hz, or `None` when not subscribed.
    rate: watch::Sender<Option<f64>>,
}

impl Session<'_> {
    /// Asks for the token when there is one, then reads and answers requests, one at a time,
    /// and queues this client's events, until the connection or the server ends.
    async fn run<R: AsyncRead + Unpin>(
        &mut self,
        lines: &mut LineReader<R>,
        stop: &mut watch::Receiver<()>,
    ) -> End {
        if self.shared.token.is_some() {
            if let Err(end) = self.authenticate(lines, stop).await {
                return end;
            }
        }
        // Only an admitted client hears events.
        let mut events = self.shared.handle.events.subscribe();
        let mut control = self.shared.control.subscribe();
        let mut events_open = true;
        let mut control_open = true;
        loop {
            let step = tokio::select! {
                biased;
                _ = stop.changed() => return End::Stop,
                event = events.recv(), if events_open => match event {
                    Ok(event) => self.event(&event).await,
                    Err(RecvError::Lagged(missed)) => {
                        debug!(client = self.id, missed, "client fell behind the events");
                        Ok(())
                    }
                    Err(RecvError::Closed) => {
                        events_open = false;
                        Ok(())
                    }
                },
                event = control.recv(), if control_open => match event {
                    Ok(event) => self.event(&event).await,
                    Err(RecvError::Lagged(missed)) => {
                        debug!(client = self.id, missed, "client fell behind the control events");
                        Ok(())
                    }
                    Err(RecvError::Closed) => {
                        control_open = false;
                        Ok(())
                    }
                },
                line = lines.next() => match line {
                    Ok(Line::Complete(line)) => self.request(line).await,
                    Ok(Line::TooLong) => {
                        let why = Rejection::new(
                            Code::LineTooLong,
                            format!("a request line is at most {MAX_LINE} bytes; it was discarded"),
                        );
                        self.push(protocol::error_line(None, &why)).await
                    }
                    Ok(Line::Eof) => return End::Eof,
                    Err(e) => return End::ReadFailed(e),
                },
            };
            if let Err(end) = step {
                return end;
            }
        }
    }

    /// Waits for the first request line (blank lines aside), which must be `auth` with the
    /// token, for at most `auth_grace`. Anything else is answered `unauthorized`, and ends the
    /// client.
    async fn authenticate<R: AsyncRead + Unpin>(
        &self,
        lines: &mut LineReader<R>,
        stop: &mut watch::Receiver<()>,
    ) -> Result<(), End> {
        let deadline = time::Instant::now() + self.shared.auth_grace;
        loop {
            let line = tokio::select! {
                biased;
                _ = stop.changed() => return Err(End::Stop),
                line = time::timeout_at(deadline, lines.next()) => line,
            };
            let (id, why) = match line {
                Err(_) => (
                    None,
                    format!(
                        "no `auth` line within {} s of connecting",
                        self.shared.auth_grace.as_secs_f64()
                    ),
                ),
                Ok(Err(e)) => return Err(End::ReadFailed(e)),
                Ok(Ok(Line::Eof)) => return Err(End::Eof),
                Ok(Ok(Line::TooLong)) => (None, "the first line must be `auth`".to_owned()),
                Ok(Ok(Line::Complete(line))) if line.iter().all(u8::is_ascii_whitespace) => {
                    continue
                }
                Ok(Ok(Line::Complete(line))) => match protocol::parse(line, self.shared.joints) {
                    Ok(request) => match request.cmd {
                        Cmd::Auth { token } => match self.admitted(&token) {
                            true => {
                                let reply = protocol::ok_line(request.id.as_deref(), &self.me());
                                return self.push(reply).await;
                            }
                            false => (request.id, "wrong token".to_owned()),
                        },
                        other => (
                            request.id,
                            format!(
                                "this daemon asks for a token: the first line must be `auth`, \
                                 not `{}`",
                                other.name()
                            ),
                        ),
                    },
                    Err((id, _)) => (id, "the first line must be `auth`".to_owned()),
                },
            };
            return Err(self.unauthorized(id.as_deref(), why).await);
        }
    }

    /// Whether `token` is the one asked for (any, when none is).
    fn admitted(&self, token: &str) -> bool {
        self.shared
            .token
            .as_ref()
            .is_none_or(|t| t.matches(token.as_bytes()))
    }

    /// Queues an `unauthorized` line; the client ends after it.
    async fn unauthorized(&self, id: Option<&serde_json::Value>, why: String) -> End {
        let line = protocol::error_line(id, &Rejection::new(Code::Unauthorized, why));
        match self.push(line).await {
            Ok(()) => End::Unauthorized,
            Err(end) => end,
        }
    }

    /// Queues an event line when the event is this client's or everyone's.
    async fn event(&self, event: &Event) -> Result<(), End> {
        match event.owner {
            Some(owner) if owner != self.id => Ok(()),
            _ => self.push(protocol::event_line(event)).await,
        }
    }

    /// `{"client": ID}`: this client's id, as the `control` events name it.
    fn me(&self) -> Fields {
        Reply::Admitted(Admitted { client: self.id }).into()
    }

    /// Answers one request line.
    async fn request(&self, line: &[u8]) -> Result<(), End> {
        let received = Instant::now();
        if line.iter().all(u8::is_ascii_whitespace) {
            return Ok(());
        }
        let request = match protocol::parse(line, self.shared.joints) {
            Ok(request) => request,
            Err((id, why)) => return self.push(protocol::error_line(id.as_deref(), &why)).await,
        };
        let id = request.id;
        let answer: Answer = match request.cmd.route() {
            Route::Session(cmd) => match cmd {
                SessionCmd::Describe => {
                    Ok(Reply::Describe(Arc::clone(&self.shared.handle.describe)).into())
                }
                SessionCmd::Subscribe { rate_hz } => {
                    let rate_hz = self.shared.telemetry_rate(rate_hz);
                    let reply = Reply::Subscribed(Subscribed { rate_hz }).into();
                    // The reply is queued before the writer learns the rate, and the writer
                    // sends queued lines first: the reply precedes the first telemetry line.
                    self.push(protocol::ok_line(id.as_deref(), &reply)).await?;
                    self.rate.send_replace(Some(rate_hz));
                    return Ok(());
                }
                SessionCmd::Unsubscribe => {
                    // The other way round: no telemetry line follows the reply.
                    self.rate.send_replace(None);
                    Ok(Reply::Unsubscribed(Unsubscribed {}).into())
                }
                SessionCmd::TakeControl => {
                    let (holder, previous) = {
                        let mut arbiter = self.shared.arbiter();
                        let previous = arbiter.holder();
                        if let Some(change) = arbiter.take(self.id) {
                            self.shared.announce(&change, id.as_ref());
                        }
                        (arbiter.holder(), previous)
                    };
                    Ok(Reply::TookControl(TookControl {
                        client: self.id,
                        holder,
                        previous,
                    })
                    .into())
                }
                SessionCmd::Release => {
                    let holder = {
                        let mut arbiter = self.shared.arbiter();
                        if let Some(change) = arbiter.release(self.id) {
                            self.shared.announce(&change, id.as_ref());
                        }
                        arbiter.holder()
                    };
                    Ok(Reply::Released(Released {
                        client: self.id,
                        holder,
                    })
                    .into())
                }
                SessionCmd::Auth { token } => {
                    if !self.admitted(&token) {
                        return Err(self.unauthorized(id.as_deref(), "wrong token".into()).await);
                    }
                    Ok(self.me())
                }
            },
            Route::Loop(cmd) => self
                .to_loop(id.clone(), cmd, received)
                .await
                .map(|mut fields| {
                    self.shared.add_control(&mut fields, self.id);
                    fields
                }),
        };
        self.push(protocol::reply_line(id.as_deref(), &answer))
            .await
    }

    /// Puts a command to the arbiter, hands it to the loop and waits for its answer.
    async fn to_loop(&self, id: Option<RequestId>, cmd: LoopCmd, received: Instant) -> Answer {
        let answer = self.shared.submit(self.id, id, cmd, received)?;
        answer.await.unwrap_or_else(|_| Err(stopped()))
    }

    /// Queues a line. A full queue waits for room up to `stall_grace` (only this client waits;
    /// its events meanwhile stay in the broadcast), then ends the client.
    async fn push(&self, line: String) -> Result<(), End> {
        let line = match self.out.try_send(line) {
            Ok(()) => return Ok(()),
            Err(TrySendError::Full(line)) => line,
            Err(TrySendError::Closed(_)) => return Err(End::WriterGone),
        };
        match self.out.send_timeout(line, self.shared.stall_grace).await {
            Ok(()) => Ok(()),
            Err(SendTimeoutError::Timeout(_)) => Err(End::Overflow),
            Err(SendTimeoutError::Closed(_)) => Err(End::WriterGone),
        }
    }
}

fn stopped() -> Rejection {
    Rejection::new(Code::ShuttingDown, "the control loop has stopped")
}

/// Who reads a telemetry line: it says who is in control, and whether that is this client.
struct Viewer<'a> {
    id: ClientId,
    shared: &'a Shared,
}

impl Viewer<'_> {
    /// The telemetry line of `telemetry` for this client.
    fn line(&self, telemetry: &Telemetry) -> String {
        protocol::telemetry_line(&self.shared.status(telemetry, self.id))
    }
}

/// Sends a client's queued lines and, while subscribed, its telemetry, until the queue closes
/// and is empty; then closes the connection's sending side.
async fn write_loop(
    mut sink: BufWriter<OwnedWriteHalf>,
    mut lines: mpsc::Receiver<String>,
    mut telemetry: watch::Receiver<Telemetry>,
    mut rate: watch::Receiver<Option<f64>>,
    viewer: Viewer<'_>,
) -> io::Result<()> {
    let mut ticker: Option<Interval> = None;
    // Send the next snapshot even if unchanged: the first after a subscribe.
    let mut fresh = false;
    let mut rate_open = true;
    loop {
        tokio::select! {
            biased;
            line = lines.recv() => {
                let Some(line) = line else { break };
                sink.write_all(line.as_bytes()).await?;
                while let Ok(line) = lines.try_recv() {
                    sink.write_all(line.as_bytes()).await?;
                }
                sink.flush().await?;
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
                    let line = viewer.line(&telemetry.borrow_and_update());
                    sink.write_all(line.as_bytes()).await?;
                    sink.flush().await?;
                }
            }
        }
    }
    sink.flush().await?;
    sink.shutdown().await
}

/// A ticker at `rate_hz` whose first tick is now; ticks missed while writing are skipped.
fn interval_at(rate_hz: f64) -> Interval {
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

/// One read from a [`LineReader`].
#[derive(Debug, PartialEq)]
enum Line<'a> {
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
struct LineReader<R> {
    inner: BufReader<R>,
    line: Vec<u8>,
    /// `line` holds a line already returned, to be cleared on the next call.
    returned: bool,
    /// Within a line over the limit, dropping bytes until its newline.
    discarding: bool,
}

impl<R: AsyncRead + Unpin> LineReader<R> {
    fn new(inner: R) -> Self {
        LineReader {
            inner: BufReader::new(inner),
            line: Vec::new(),
            returned: false,
            discarding: false,
        }
    }

    async fn next(&mut self) -> io::Result<Line<'_>> {
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

    #[tokio::test]
    async fn intervals_stay_within_sane_periods() {
        assert_eq!(interval_at(1e-300).period(), Duration::from_secs(86_400));
        assert_eq!(interval_at(1e9).period(), Duration::from_micros(1));
        assert_eq!(interval_at(50.0).period(), Duration::from_millis(20));
    }
}
