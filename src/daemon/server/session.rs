//! One client from connect to close: its lines read as they come, its commands sent on at once,
//! its answers written in the order of its requests (but for one the loop keeps for later).
//!
//! Reading never waits for the loop. Each request line is parsed and, for the loop, submitted
//! the moment it arrives; what will answer it joins the connection's [`Answers`], a queue in
//! request order that the session moves to the writer as answers come in. So a `stop` or an
//! `estop` is in the loop's hands in the tick after its line arrives, whatever this client (or
//! any other) sent before it, and its reply still comes after the replies to the lines before
//! it. A command the loop answers only once its work beside the ticks is done (a `reach`, a
//! `goto` or `path` planned beside the loop, a `reboot`) steps out of that order when the loop
//! says so: the replies and events after it are written meanwhile, and its reply when it comes
//! (before the events about it, which the loop sends after it). What bounds a client:
//! - [`COMMANDS_IN_FLIGHT`] commands waiting for the loop (a `velocity` flood included): one
//!   more is answered `busy` at once. `stop` and `estop` do not count against it; they have a
//!   share of their own ([`STOPS_IN_FLIGHT`] of each, which a burst cannot exceed in a tick
//!   without the first ones having done their work already).
//! - [`ANSWERS_WAITING`] replies and events waiting to be written: more means the client does
//!   not read what it asked for, and it is disconnected (a `stop` or `estop` on the line that
//!   overflowed is still carried out).
//! - the first line, due within the `auth` deadline ([`super::AUTH_GRACE`]), token or not: a
//!   connection that says nothing is closed, so idle sockets cannot hold the places.

use std::collections::VecDeque;
use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::Poll;
use std::time::Instant;

use tokio::io::AsyncRead;
use tokio::net::TcpStream;
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::time;
use tracing::{debug, warn};

use super::lines::{Line, LineReader};
use super::writer::{write_loop, Viewer, SEND_BUFFER, SLOW_READER};
use super::{stopped, Shared};
use crate::protocol::{
    self, Admitted, Answer, ClientId, Cmd, Code, Event, Fields, LoopCmd, Rejection, Released,
    Reply, RequestId, Route, SessionCmd, Subscribed, TookControl, Unsubscribed, MAX_LINE,
};

/// Commands (other than `stop` and `estop`) one connection may have waiting for the loop at
/// once; one more is answered `busy`. A quarter of the loop's queue, so that one client's flood
/// leaves room for the others.
pub const COMMANDS_IN_FLIGHT: usize = super::COMMAND_QUEUE / 4;

/// `stop`s, and separately `estop`s, one connection may have waiting for the loop at once.
pub const STOPS_IN_FLIGHT: usize = 8;

/// Replies and events one connection may have waiting to be written (answers the loop keeps
/// for later among them); a client that lets more pile up does not read, and is disconnected.
pub const ANSWERS_WAITING: usize = 1024;

/// One client from connect to close.
pub(super) async fn client(
    id: ClientId,
    stream: TcpStream,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<()>,
) {
    prepare(id, &stream);
    // However the client ends, control it holds is freed (and everyone told).
    let _seat = Seat {
        id,
        shared: &shared,
    };
    let (read, write) = stream.into_split();
    let mut lines = LineReader::new(read);
    let (out_tx, out_rx) = mpsc::channel(shared.client_queue);
    let (rate_tx, rate_rx) = watch::channel(None);
    let writer = write_loop(
        tokio::io::BufWriter::new(write),
        out_rx,
        shared.handle.telemetry.clone(),
        rate_rx,
        Viewer {
            id,
            shared: &shared,
        },
        SLOW_READER,
    );
    tokio::pin!(writer);
    let mut session = Session {
        id,
        shared: &shared,
        out: out_tx,
        rate: rate_tx,
        answers: Answers::default(),
    };
    let end = tokio::select! {
        end = session.run(&mut lines, &mut stop) => end,
        written = &mut writer => {
            match written {
                Ok(()) => debug!(client = id, "client disconnected"),
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                    warn!(client = id, "client disconnected: {e}");
                }
                Err(e) => debug!(client = id, error = %e, "client disconnected: write failed"),
            }
            return;
        }
    };
    let unauthorized = matches!(end, End::Unauthorized);
    match end {
        End::Overflow => {
            warn!(
                client = id,
                waiting = ANSWERS_WAITING,
                "client disconnected: it does not read what it is sent"
            );
            return;
        }
        End::Eof => debug!(client = id, "client disconnected"),
        End::Stop => debug!(client = id, "closing client: the server stops"),
        End::WriterGone => debug!(client = id, "client disconnected: write failed"),
        End::ReadFailed(e) => debug!(client = id, error = %e, "client disconnected: read failed"),
        End::Unauthorized => debug!(client = id, "closing client: unauthorized"),
        End::Silent => debug!(
            client = id,
            "closing client: no line within {} s of connecting",
            shared.auth_grace.as_secs_f64()
        ),
    }
    // What was asked is answered before the connection closes: a client that sent its lines
    // and closed its side still gets every reply.
    let flushed = time::timeout(shared.flush_grace, async {
        session.flush().await;
        drop(session);
        (&mut writer).await
    })
    .await;
    if flushed.is_err() {
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

/// Socket options every client gets: no Nagle delay, and a small send buffer (see
/// [`SEND_BUFFER`]).
pub(super) fn prepare(id: ClientId, stream: &TcpStream) {
    if let Err(e) = stream.set_nodelay(true) {
        debug!(client = id, error = %e, "TCP_NODELAY not set");
    }
    if let Err(e) = socket2::SockRef::from(stream).set_send_buffer_size(SEND_BUFFER) {
        debug!(client = id, error = %e, "SO_SNDBUF not set");
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
    /// More than [`ANSWERS_WAITING`] answers waited to be written.
    Overflow,
    /// The writer stopped (the connection broke, or the client stopped reading).
    WriterGone,
    /// Reading failed.
    ReadFailed(io::Error),
    /// No `auth` line with the right token where one is needed; the client was told.
    Unauthorized,
    /// No line at all within the first-line deadline.
    Silent,
}

/// What a request waits on in the loop, for the per-connection shares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Flight {
    Command,
    Stop,
    Estop,
}

/// One answer owed to the client, in request order.
enum Owed {
    /// A line ready to write.
    Line(String),
    /// The `subscribed` reply: once it is written, telemetry starts at `rate_hz`.
    Subscribed { line: String, rate_hz: f64 },
    /// The `unsubscribed` reply: telemetry stops as it is written (not before the replies
    /// owed ahead of it, a `subscribe`'s among them).
    Unsubscribed(String),
    /// The loop's answer to come.
    Loop {
        id: Option<RequestId>,
        flight: Flight,
        answer: oneshot::Receiver<Answer>,
        /// Told if the loop keeps the answer for later; `None` once the loop has taken the
        /// command without saying so (its answer then comes in that tick).
        later: Option<oneshot::Receiver<()>>,
    },
}

/// An answer the loop keeps for later, out of the order of the requests.
struct Later {
    id: Option<RequestId>,
    answer: oneshot::Receiver<Answer>,
}

/// What became of the loop's answer to the first request.
enum Front {
    /// In.
    Answered(Answer),
    /// The loop keeps it for later.
    Later,
    /// The loop took the command without keeping its answer: it comes in that tick.
    InTick,
}

/// The answers a connection owes, in the order of its requests, and how many of them wait on
/// the loop.
#[derive(Default)]
struct Answers {
    owed: VecDeque<Owed>,
    /// The answers the loop keeps for later, each written as it comes. Few: the loop keeps
    /// one planning and one reboot at a time, and answers the one a new one replaces.
    later: Vec<Later>,
    commands: usize,
    stops: usize,
    estops: usize,
}

impl Answers {
    fn waiting(&mut self, flight: Flight) -> &mut usize {
        match flight {
            Flight::Command => &mut self.commands,
            Flight::Stop => &mut self.stops,
            Flight::Estop => &mut self.estops,
        }
    }

    /// Whether the first answer waits on the loop.
    fn front_waits(&self) -> bool {
        matches!(self.owed.front(), Some(Owed::Loop { .. }))
    }

    /// Whether the first answer is ready to write.
    fn front_ready(&self) -> bool {
        matches!(
            self.owed.front(),
            Some(Owed::Line(_) | Owed::Subscribed { .. } | Owed::Unsubscribed(_))
        )
    }

    /// Puts in their places the loop's answers already in, wherever they wait in the queue,
    /// so that only commands the loop has not answered count against the shares.
    fn settle_answered(&mut self, fill: impl Fn(Option<RequestId>, Answer) -> String) {
        let (mut commands, mut stops, mut estops) = (0, 0, 0);
        for owed in &mut self.owed {
            let Owed::Loop { answer, flight, .. } = owed else {
                continue;
            };
            let answer = match answer.try_recv() {
                Ok(answer) => answer,
                Err(oneshot::error::TryRecvError::Empty) => continue,
                Err(oneshot::error::TryRecvError::Closed) => Err(stopped()),
            };
            match flight {
                Flight::Command => commands += 1,
                Flight::Stop => stops += 1,
                Flight::Estop => estops += 1,
            }
            if let Owed::Loop { id, .. } = std::mem::replace(owed, Owed::Line(String::new())) {
                *owed = Owed::Line(fill(id, answer));
            }
        }
        self.commands -= commands;
        self.stops -= stops;
        self.estops -= estops;
    }

    /// Waits for the next of the loop's answers this connection waits on, and puts its line in
    /// place: one kept for later first among those owed, as it comes (so before the answers
    /// owed after its request: a `stop` that ended it, say); the first request's in its place.
    /// When the loop keeps the first request's answer for later, sets the request aside
    /// ([`Answers::later`]), so that the ones after it are written meanwhile. Cancel-safe:
    /// nothing is taken until an answer or the loop's word is in. `fill` turns an answer into
    /// its line. Waits for ever when nothing waits on the loop.
    async fn settle(&mut self, fill: impl FnOnce(Option<RequestId>, Answer) -> String) {
        enum Got {
            Kept(usize, Answer),
            Front(Front),
        }
        let answered = |a: Result<Answer, _>| a.unwrap_or_else(|_| Err(stopped()));
        let got = std::future::poll_fn(|cx| {
            for (k, l) in self.later.iter_mut().enumerate() {
                if let Poll::Ready(a) = Pin::new(&mut l.answer).poll(cx) {
                    return Poll::Ready(Got::Kept(k, answered(a)));
                }
            }
            if let Some(Owed::Loop { answer, later, .. }) = self.owed.front_mut() {
                if let Poll::Ready(a) = Pin::new(answer).poll(cx) {
                    return Poll::Ready(Got::Front(Front::Answered(answered(a))));
                }
                if let Some(word) = later {
                    if let Poll::Ready(told) = Pin::new(word).poll(cx) {
                        let front = if told.is_ok() {
                            Front::Later
                        } else {
                            Front::InTick
                        };
                        return Poll::Ready(Got::Front(front));
                    }
                }
            }
            Poll::Pending
        })
        .await;
        let front = match got {
            Got::Kept(k, answer) => {
                let l = self.later.remove(k);
                return self.owed.push_front(Owed::Line(fill(l.id, answer)));
            }
            Got::Front(Front::InTick) => {
                if let Some(Owed::Loop { later, .. }) = self.owed.front_mut() {
                    *later = None;
                }
                return;
            }
            Got::Front(front) => front,
        };
        let Some(Owed::Loop {
            id, flight, answer, ..
        }) = self.owed.pop_front()
        else {
            return;
        };
        *self.waiting(flight) -= 1;
        match front {
            Front::Answered(a) => self.owed.push_front(Owed::Line(fill(id, a))),
            _ => self.later.push(Later { id, answer }),
        }
    }

    /// Puts first among those owed the lines of the answers kept for later that are in
    /// already: before an event about one of them, which the loop sends after its answer.
    fn take_later(&mut self, fill: impl Fn(Option<RequestId>, Answer) -> String) {
        let mut k = self.later.len();
        while k > 0 {
            k -= 1;
            let answer = match self.later[k].answer.try_recv() {
                Ok(answer) => answer,
                Err(oneshot::error::TryRecvError::Empty) => continue,
                Err(oneshot::error::TryRecvError::Closed) => Err(stopped()),
            };
            let l = self.later.remove(k);
            self.owed.push_front(Owed::Line(fill(l.id, answer)));
        }
    }

    /// How many answers are owed, those kept for later included.
    fn len(&self) -> usize {
        self.owed.len() + self.later.len()
    }
}

/// The reading side of one client.
struct Session<'a> {
    id: ClientId,
    shared: &'a Shared,
    /// Replies and events, in the order written.
    out: mpsc::Sender<String>,
    /// The telemetry rate, Hz, or `None` when not subscribed.
    rate: watch::Sender<Option<f64>>,
    answers: Answers,
}

impl Session<'_> {
    /// Asks for the token when there is one (else waits for a first line), then reads and
    /// answers requests and queues this client's events, until the connection or the server
    /// ends.
    async fn run<R: AsyncRead + Unpin>(
        &mut self,
        lines: &mut LineReader<R>,
        stop: &mut watch::Receiver<()>,
    ) -> End {
        let mut spoken = false;
        if self.shared.token.is_some() {
            if let Err(end) = self.authenticate(lines, stop).await {
                return end;
            }
            spoken = true;
        }
        let silent_after = time::Instant::now() + self.shared.auth_grace;
        // Only an admitted client hears events.
        let mut events = self.shared.handle.events.subscribe();
        let mut control = self.shared.control.subscribe();
        let mut events_open = true;
        let mut control_open = true;
        loop {
            let waits = self.answers.front_waits();
            let ready = self.answers.front_ready();
            let kept = !self.answers.later.is_empty();
            let out = self.out.clone();
            let (shared, me) = (self.shared, self.id);
            let step = tokio::select! {
                biased;
                _ = stop.changed() => {
                    self.drain_events(&mut events, &mut control);
                    return End::Stop;
                }
                () = self.answers.settle(|id, answer| reply(shared, me, id, answer)), if waits || kept => Ok(()),
                permit = out.reserve_owned(), if ready => match permit {
                    Ok(permit) => {
                        self.write_front(permit);
                        Ok(())
                    }
                    Err(_) => Err(End::WriterGone),
                },
                line = lines.next() => {
                    spoken = true;
                    match line {
                        Ok(Line::Complete(line)) => self.request(line),
                        Ok(Line::TooLong) => {
                            let why = Rejection::new(
                                Code::LineTooLong,
                                format!("a request line is at most {MAX_LINE} bytes; it was discarded"),
                            );
                            self.owe(Owed::Line(protocol::error_line(None, &why)))
                        }
                        Ok(Line::Eof) => return End::Eof,
                        Err(e) => return End::ReadFailed(e),
                    }
                }
                event = events.recv(), if events_open => match event {
                    Ok(event) => self.event(&event),
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
                    Ok(event) => self.event(&event),
                    Err(RecvError::Lagged(missed)) => {
                        debug!(client = self.id, missed, "client fell behind the control events");
                        Ok(())
                    }
                    Err(RecvError::Closed) => {
                        control_open = false;
                        Ok(())
                    }
                },
                () = time::sleep_until(silent_after), if !spoken => return End::Silent,
            };
            if let Err(end) = step {
                return end;
            }
        }
    }

    /// Moves the first answer, ready, to the writer (`permit`: room for it).
    fn write_front(&mut self, permit: mpsc::OwnedPermit<String>) {
        match self.answers.owed.pop_front() {
            Some(Owed::Line(line)) => {
                permit.send(line);
            }
            Some(Owed::Subscribed { line, rate_hz }) => {
                // The reply goes to the writer before the writer learns the rate, and the
                // writer sends queued lines first: the reply precedes the first telemetry line.
                permit.send(line);
                self.rate.send_replace(Some(rate_hz));
            }
            Some(Owed::Unsubscribed(line)) => {
                // The other way round: no telemetry line follows the reply.
                self.rate.send_replace(None);
                permit.send(line);
            }
            Some(owed @ Owed::Loop { .. }) => self.answers.owed.push_front(owed),
            None => {}
        }
    }

    /// Every answer still owed, written (the loop's within the caller's grace), the events
    /// already broadcast included.
    async fn flush(&mut self) {
        let (shared, me) = (self.shared, self.id);
        while self.answers.len() > 0 {
            if self.answers.owed.is_empty() || self.answers.front_waits() {
                self.answers
                    .settle(|id, answer| reply(shared, me, id, answer))
                    .await;
                continue;
            }
            match self.out.clone().reserve_owned().await {
                Ok(permit) => self.write_front(permit),
                Err(_) => return,
            }
        }
    }

    /// The events already broadcast, queued (at shut-down, so that the last ones are told).
    fn drain_events(
        &mut self,
        events: &mut broadcast::Receiver<Event>,
        control: &mut broadcast::Receiver<Event>,
    ) {
        while let Ok(event) = events.try_recv() {
            let _ = self.event(&event);
        }
        while let Ok(event) = control.try_recv() {
            let _ = self.event(&event);
        }
    }

    /// Waits for the first request line (blank lines aside), which must be `auth` with the
    /// token, for at most `auth_grace`. Anything else is answered `unauthorized`, and ends the
    /// client.
    async fn authenticate<R: AsyncRead + Unpin>(
        &mut self,
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
                        Cmd::Auth { token } => match self.shared.admits(&token) {
                            true => {
                                let reply = protocol::ok_line(request.id.as_deref(), &self.me());
                                return self.owe(Owed::Line(reply));
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
            return Err(self.unauthorized(id.as_deref(), why));
        }
    }

    /// Owes an `unauthorized` line; the client ends after it.
    fn unauthorized(&mut self, id: Option<&serde_json::Value>, why: String) -> End {
        let line = protocol::error_line(id, &Rejection::new(Code::Unauthorized, why));
        match self.owe(Owed::Line(line)) {
            Ok(()) => End::Unauthorized,
            Err(end) => end,
        }
    }

    /// Owes an event line when the event is this client's or everyone's, after the answers
    /// kept for later that are in (the loop sends one before the events about its command).
    fn event(&mut self, event: &Event) -> Result<(), End> {
        match event.owner {
            Some(owner) if owner != self.id => Ok(()),
            _ => {
                let (shared, me) = (self.shared, self.id);
                self.answers
                    .take_later(|id, answer| reply(shared, me, id, answer));
                self.owe(Owed::Line(protocol::event_line(event)))
            }
        }
    }

    /// `{"client": ID}`: this client's id, as the `control` events name it.
    fn me(&self) -> Fields {
        Reply::Admitted(Admitted { client: self.id }).into()
    }

    /// Adds an answer to those owed; too many owed ends the client.
    fn owe(&mut self, owed: Owed) -> Result<(), End> {
        if self.answers.len() >= ANSWERS_WAITING {
            return Err(End::Overflow);
        }
        self.answers.owed.push_back(owed);
        Ok(())
    }

    /// Answers one request line, or sends it on to the loop: nothing here waits.
    fn request(&mut self, line: &[u8]) -> Result<(), End> {
        let received = Instant::now();
        if line.iter().all(u8::is_ascii_whitespace) {
            return Ok(());
        }
        let request = match protocol::parse(line, self.shared.joints) {
            Ok(request) => request,
            Err((id, why)) => {
                return self.owe(Owed::Line(protocol::error_line(id.as_deref(), &why)))
            }
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
                    let line = protocol::ok_line(id.as_deref(), &reply);
                    return self.owe(Owed::Subscribed { line, rate_hz });
                }
                SessionCmd::Unsubscribe => {
                    let reply = Reply::Unsubscribed(Unsubscribed {}).into();
                    let line = protocol::ok_line(id.as_deref(), &reply);
                    return self.owe(Owed::Unsubscribed(line));
                }
                SessionCmd::TakeControl => Ok(self.take_control(id.as_ref())),
                SessionCmd::Release => Ok(self.release(id.as_ref())),
                SessionCmd::Auth { token } => {
                    if !self.shared.admits(&token) {
                        return Err(self.unauthorized(id.as_deref(), "wrong token".into()));
                    }
                    Ok(self.me())
                }
            },
            Route::Loop(cmd) => return self.send_on(id, cmd, received),
        };
        self.owe(Owed::Line(protocol::reply_line(id.as_deref(), &answer)))
    }

    fn take_control(&self, id: Option<&RequestId>) -> Fields {
        let (holder, previous) = {
            let mut arbiter = self.shared.arbiter();
            let previous = arbiter.holder();
            if let Some(change) = arbiter.take(self.id) {
                self.shared.announce(&change, id);
            }
            (arbiter.holder(), previous)
        };
        Reply::TookControl(TookControl {
            client: self.id,
            holder,
            previous,
        })
        .into()
    }

    fn release(&self, id: Option<&RequestId>) -> Fields {
        let holder = {
            let mut arbiter = self.shared.arbiter();
            if let Some(change) = arbiter.release(self.id) {
                self.shared.announce(&change, id);
            }
            arbiter.holder()
        };
        Reply::Released(Released {
            client: self.id,
            holder,
        })
        .into()
    }

    /// Puts a command to the arbiter and hands it to the loop, within this connection's share;
    /// its answer is owed in its place.
    fn send_on(
        &mut self,
        id: Option<RequestId>,
        cmd: LoopCmd,
        received: Instant,
    ) -> Result<(), End> {
        let flight = match cmd {
            LoopCmd::Stop => Flight::Stop,
            LoopCmd::Estop => Flight::Estop,
            _ => Flight::Command,
        };
        let (share, what) = match flight {
            Flight::Command => (COMMANDS_IN_FLIGHT, "commands"),
            Flight::Stop => (STOPS_IN_FLIGHT, "`stop`s"),
            Flight::Estop => (STOPS_IN_FLIGHT, "`estop`s"),
        };
        if *self.answers.waiting(flight) >= share {
            let (shared, me) = (self.shared, self.id);
            self.answers
                .settle_answered(|id, answer| reply(shared, me, id, answer));
        }
        let refused = if *self.answers.waiting(flight) >= share {
            Rejection::new(
                Code::Busy,
                format!(
                    "this connection already has {share} {what} waiting for the loop (a tick at \
                     most); send again"
                ),
            )
        } else {
            let (tell, later) = oneshot::channel();
            match self
                .shared
                .submit(self.id, id.clone(), cmd, received, Some(tell))
            {
                Ok(answer) => {
                    *self.answers.waiting(flight) += 1;
                    // Sent on even when the answer cannot be owed: a `stop` still stops.
                    let later = Some(later);
                    return self.owe(Owed::Loop {
                        id,
                        flight,
                        answer,
                        later,
                    });
                }
                Err(why) => why,
            }
        };
        self.owe(Owed::Line(protocol::error_line(id.as_deref(), &refused)))
    }
}

/// The reply line to the loop's `answer`, with who is in control filled in for a `status`.
fn reply(shared: &Shared, me: ClientId, id: Option<RequestId>, answer: Answer) -> String {
    let answer = answer.map(|mut fields| {
        shared.add_control(&mut fields, me);
        fields
    });
    protocol::reply_line(id.as_deref(), &answer)
}
