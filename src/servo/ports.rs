//! Several serial ports as one bus: [`Ports`] implements [`ServoBus`] over one bus per port,
//! each carrying its own servos, so the arm, its bring-up and the control loop see one chain.
//!
//! With one port every call goes straight to it. With several, each port's bus lives on a
//! thread of its own and the calls that concern every servo (Sync Write of the goals, Sync
//! Read, Sync Write, scan) are split by port, sent to every port at once and awaited together:
//! a tick costs its slowest port, not their sum. A call for one servo goes to its port alone.
//! Each port takes one request at a time and answers it before the next (channels of one
//! place), so nothing queues; the buffers of the control loop's calls travel to the port's
//! thread and back, and a warm tick allocates nothing.
//!
//! An error of the port itself ([`ErrorClass::Bus`]) names it
//! ([`ServoError::OnPort`]); every servo's own outcome stays its own.

use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;
use std::time::Duration;

use super::wire::Adapter;
use super::{
    Ack, ErrorClass, Goal, PingInfo, ReadKind, Register, ServoBus, ServoError, SyncReadBuf, Value,
    MAX_ID,
};

/// A call for one port's bus, run on its thread.
type Call<B> = Box<dyn FnOnce(&mut B) + Send>;

/// What a port's thread is asked to do.
enum Job<B> {
    /// Write these goals (one Sync Write); the vector comes back.
    Goals(Vec<Goal>),
    /// Sync Read these ids into the buffer; both come back.
    Read {
        ids: Vec<u8>,
        address: u16,
        len: u16,
        timeout: Duration,
        buf: SyncReadBuf,
    },
    /// Anything else.
    Call(Call<B>),
}

/// What a port's thread answers.
enum Done {
    Goals(Vec<Goal>, Result<(), ServoError>),
    Read(Vec<u8>, SyncReadBuf, Result<(), ServoError>),
    Call,
}

/// One port on its own thread.
struct Worker<B> {
    /// Its path, for the errors.
    name: String,
    jobs: SyncSender<Job<B>>,
    done: Receiver<Done>,
    thread: Option<JoinHandle<()>>,
    /// This tick's goals, ids and read buffer for this port, reused.
    goals: Vec<Goal>,
    ids: Vec<u8>,
    buf: SyncReadBuf,
    /// For each of `ids`, its index in the caller's list.
    slots: Vec<usize>,
    /// A job was sent and its answer not yet taken.
    busy: bool,
    /// The port itself failed (an error of [`ErrorClass::Bus`]): it stays failed until
    /// [`Ports::reopen_failed`] opens it again.
    failed: bool,
}

impl<B: ServoBus + Send + 'static> Worker<B> {
    fn spawn(name: String, mut bus: B) -> Result<Self, ServoError> {
        let (jobs, inbox) = sync_channel::<Job<B>>(1);
        let (outbox, done) = sync_channel::<Done>(1);
        let thread = std::thread::Builder::new()
            .name(format!("port {name}"))
            .spawn(move || {
                super::clock::sharp_timers();
                // Ends when the bus is dropped (the sender goes) or the answer has nowhere to go.
                while let Ok(job) = inbox.recv() {
                    let answer = match job {
                        Job::Goals(goals) => {
                            let r = bus.write_goals(&goals);
                            Done::Goals(goals, r)
                        }
                        Job::Read {
                            ids,
                            address,
                            len,
                            timeout,
                            mut buf,
                        } => {
                            let r = bus.sync_read_into(&ids, address, len, timeout, &mut buf);
                            Done::Read(ids, buf, r)
                        }
                        Job::Call(call) => {
                            call(&mut bus);
                            Done::Call
                        }
                    };
                    if outbox.send(answer).is_err() {
                        break;
                    }
                }
            })
            .map_err(ServoError::Io)?;
        Ok(Self {
            name,
            jobs,
            done,
            thread: Some(thread),
            goals: Vec::new(),
            ids: Vec::new(),
            buf: SyncReadBuf::new(),
            slots: Vec::new(),
            busy: false,
            failed: false,
        })
    }

    /// The port's thread is gone: an error naming the port, which counts as failed.
    fn gone(&mut self) -> ServoError {
        self.failed = true;
        ServoError::OnPort {
            port: self.name.clone(),
            source: Box::new(ServoError::Io(std::io::Error::new(
                std::io::ErrorKind::BrokenPipe,
                "the port's thread has stopped",
            ))),
        }
    }

    fn send(&mut self, job: Job<B>) -> Result<(), ServoError> {
        if self.jobs.send(job).is_err() {
            return Err(self.gone());
        }
        self.busy = true;
        Ok(())
    }

    fn wait(&mut self) -> Result<Done, ServoError> {
        self.busy = false;
        match self.done.recv() {
            Ok(done) => Ok(done),
            Err(_) => Err(self.gone()),
        }
    }

    /// `f` on the port's bus, awaited.
    fn call<R: Send + 'static>(
        &mut self,
        f: impl FnOnce(&mut B) -> R + Send + 'static,
    ) -> Result<R, ServoError> {
        let rx = self.start(f)?;
        self.finish(rx)
    }

    /// `f` sent to the port's bus; [`Worker::finish`] takes its result.
    fn start<R: Send + 'static>(
        &mut self,
        f: impl FnOnce(&mut B) -> R + Send + 'static,
    ) -> Result<Receiver<R>, ServoError> {
        let (tx, rx) = sync_channel(1);
        self.send(Job::Call(Box::new(move |bus: &mut B| {
            // The caller waits for it; if it is gone, nobody needs the result.
            let _ = tx.send(f(bus));
        })))?;
        Ok(rx)
    }

    fn finish<R>(&mut self, rx: Receiver<R>) -> Result<R, ServoError> {
        self.wait()?;
        match rx.recv() {
            Ok(r) => Ok(r),
            Err(_) => Err(self.gone()),
        }
    }

    /// A port error of this port's bus names it and marks the port failed; a servo's error
    /// stays as it is.
    fn named(&mut self, e: ServoError) -> ServoError {
        let e = name_port(&self.name, e);
        if e.class() == ErrorClass::Bus {
            self.failed = true;
        }
        e
    }
}

impl<B> Drop for Worker<B> {
    fn drop(&mut self) {
        // Dropping the sender ends the thread once its exchange in flight is over (each is
        // bounded by its timeout); the bus, and its port lock, go with it.
        let (jobs, _) = sync_channel(1);
        drop(std::mem::replace(&mut self.jobs, jobs));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// `e`, naming port `name` when it is an error of the port itself.
fn name_port(name: &str, e: ServoError) -> ServoError {
    match e {
        e @ ServoError::OnPort { .. } => e,
        e if e.class() == ErrorClass::Bus => ServoError::OnPort {
            port: name.to_owned(),
            source: Box::new(e),
        },
        e => e,
    }
}

/// Why [`Ports::reopen_failed`] could not open a failed port again.
#[derive(Debug, thiserror::Error)]
pub enum ReopenPortError<E> {
    /// Opening its device failed.
    #[error(transparent)]
    Open(E),
    /// Its thread could not be started.
    #[error("the reopened port's thread could not start: {0}")]
    Thread(ServoError),
}

enum Inner<B> {
    /// One port: called directly.
    One(B),
    /// Several ports, each on its thread.
    Many(Vec<Worker<B>>),
}

/// The buses of several ports as one ([module docs](self)).
pub struct Ports<B> {
    inner: Inner<B>,
    /// Each id's port (index into the ports), `u8::MAX` for an id on none.
    route: Vec<u8>,
    baud: u32,
    /// Each port's read (several ports), in port order.
    reads: Vec<ReadKind>,
    /// Each port's adapter, as its bus told before its thread took it (several ports).
    adapters: Vec<Option<Adapter>>,
}

impl<B> std::fmt::Debug for Ports<B> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ports: Vec<&str> = match &self.inner {
            Inner::One(_) => vec!["(one)"],
            Inner::Many(w) => w.iter().map(|w| w.name.as_str()).collect(),
        };
        f.debug_struct("Ports")
            .field("ports", &ports)
            .field("baud", &self.baud)
            .finish_non_exhaustive()
    }
}

const NO_PORT: u8 = u8::MAX;

impl<B: ServoBus + Send + 'static> Ports<B> {
    /// One port: every call goes straight to `bus`, whatever the id.
    pub fn one(bus: B) -> Self {
        Self {
            baud: bus.baud(),
            inner: Inner::One(bus),
            route: vec![0; usize::from(MAX_ID) + 1],
            reads: Vec::new(),
            adapters: Vec::new(),
        }
    }

    /// Several ports, each `(name, bus, ids)`: the servos `ids` are on `bus`, at path `name`.
    /// An id listed twice belongs to its first port. One port is [`Ports::one`].
    pub fn new(mut ports: Vec<(String, B, Vec<u8>)>) -> Result<Self, ServoError> {
        let mut route = vec![NO_PORT; usize::from(MAX_ID) + 1];
        for (k, (_, _, ids)) in ports.iter().enumerate() {
            for &id in ids {
                if let Some(slot) = route.get_mut(usize::from(id)) {
                    if *slot == NO_PORT {
                        *slot = u8::try_from(k).unwrap_or(NO_PORT);
                    }
                }
            }
        }
        if ports.len() == 1 {
            if let Some((_, bus, _)) = ports.pop() {
                let mut one = Self::one(bus);
                one.route = route;
                return Ok(one);
            }
        }
        let baud = ports.first().map_or(0, |(_, b, _)| b.baud());
        let reads = vec![ReadKind::Sync; ports.len()];
        let adapters = ports
            .iter()
            .map(|(_, bus, _)| bus.adapters().first().copied().flatten())
            .collect();
        let workers = ports
            .into_iter()
            .map(|(name, bus, _)| Worker::spawn(name, bus))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            inner: Inner::Many(workers),
            route,
            baud,
            reads,
            adapters,
        })
    }

    /// How many ports.
    pub fn len(&self) -> usize {
        match &self.inner {
            Inner::One(_) => 1,
            Inner::Many(w) => w.len(),
        }
    }

    /// Never: a bus has at least one port.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The paths of the ports that failed (an error of [`ErrorClass::Bus`] came from them) and
    /// were not opened again since; empty with one port, whose failures its caller sees.
    pub fn failed(&self) -> Vec<&str> {
        match &self.inner {
            Inner::One(_) => Vec::new(),
            Inner::Many(w) => w
                .iter()
                .filter(|w| w.failed)
                .map(|w| w.name.as_str())
                .collect(),
        }
    }

    /// Open again the ports that failed, each with `open(index)` (its index in the order the
    /// ports were given), after closing it so that its lock is free: the others stay open,
    /// locked and untouched. A reopened port reads as before. With one port, that port is
    /// closed and opened again. Every failed port is tried; the first error is returned, and a
    /// port whose opening failed stays failed (closed) for the next try.
    pub fn reopen_failed<E>(
        &mut self,
        mut open: impl FnMut(usize) -> Result<B, E>,
    ) -> Result<(), ReopenPortError<E>> {
        let workers = match &mut self.inner {
            Inner::One(bus) => {
                bus.close();
                *bus = open(0).map_err(ReopenPortError::Open)?;
                return Ok(());
            }
            Inner::Many(workers) => workers,
        };
        let mut first_error = None;
        for (k, w) in workers.iter_mut().enumerate().filter(|(_, w)| w.failed) {
            // A port whose thread is gone has nothing left to close.
            let _ = w.call(|bus: &mut B| bus.close());
            let bus = match open(k) {
                Ok(bus) => bus,
                Err(e) => {
                    first_error.get_or_insert(ReopenPortError::Open(e));
                    continue;
                }
            };
            if let Some(slot) = self.adapters.get_mut(k) {
                *slot = bus.adapters().first().copied().flatten();
            }
            let mut fresh = match Worker::spawn(w.name.clone(), bus) {
                Ok(fresh) => fresh,
                Err(e) => {
                    first_error.get_or_insert(ReopenPortError::Thread(e));
                    continue;
                }
            };
            let kind = self.reads.get(k).copied().unwrap_or(ReadKind::Sync);
            let set = fresh
                .call(move |bus: &mut B| bus.set_read_kind(kind))
                .and_then(|r| r);
            if let Err(e) = set {
                tracing::warn!(port = %fresh.name, ?kind, "the reopened port keeps Sync Read: {e}");
                if let Some(slot) = self.reads.get_mut(k) {
                    *slot = ReadKind::Sync;
                }
            }
            // The failed worker goes (its thread joined, its bus dropped).
            *w = fresh;
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The port (index) servo `id` is on.
    fn port_of(&self, id: u8) -> Result<usize, ServoError> {
        match self.route.get(usize::from(id)) {
            Some(&p) if p != NO_PORT => Ok(usize::from(p)),
            _ => Err(ServoError::BadId {
                id,
                what: "is on none of the bus's ports",
            }),
        }
    }

    /// `f` on servo `id`'s port.
    fn on<R: Send + 'static>(
        &mut self,
        id: u8,
        f: impl FnOnce(&mut B) -> Result<R, ServoError> + Send + 'static,
    ) -> Result<R, ServoError> {
        if let Inner::One(bus) = &mut self.inner {
            return f(bus);
        }
        let port = self.port_of(id)?;
        match &mut self.inner {
            Inner::One(bus) => f(bus),
            Inner::Many(workers) => {
                let w = &mut workers[port];
                let r = w.call(f)?;
                r.map_err(|e| w.named(e))
            }
        }
    }

    /// `f` on every port at once; the results in port order.
    fn every<R: Send + 'static>(
        &mut self,
        f: impl Fn(&mut B) -> Result<R, ServoError> + Send + Sync + Clone + 'static,
    ) -> Result<Vec<R>, ServoError> {
        match &mut self.inner {
            Inner::One(bus) => Ok(vec![f(bus)?]),
            Inner::Many(workers) => {
                let mut pending = Vec::with_capacity(workers.len());
                let mut first_error = None;
                for w in workers.iter_mut() {
                    match w.start(f.clone()) {
                        Ok(rx) => pending.push(Some(rx)),
                        Err(e) => {
                            first_error.get_or_insert(e);
                            pending.push(None);
                        }
                    }
                }
                let mut out = Vec::with_capacity(workers.len());
                for (w, rx) in workers.iter_mut().zip(pending) {
                    let Some(rx) = rx else { continue };
                    match w.finish(rx).and_then(|r| r.map_err(|e| w.named(e))) {
                        Ok(r) => out.push(r),
                        Err(e) => {
                            first_error.get_or_insert(e);
                        }
                    }
                }
                match first_error {
                    Some(e) => Err(e),
                    None => Ok(out),
                }
            }
        }
    }

    /// `per_port` items of every port, split from `items` by the id `id_of` gives: the ports
    /// with work, in port order.
    fn split<T: Copy>(
        route: &[u8],
        workers: &mut [Worker<B>],
        items: &[T],
        id_of: impl Fn(&T) -> u8,
        fill: impl Fn(&mut Worker<B>, usize, T),
    ) -> Result<(), ServoError> {
        for (i, item) in items.iter().enumerate() {
            let id = id_of(item);
            match route.get(usize::from(id)) {
                Some(&p) if p != NO_PORT => {
                    if let Some(w) = workers.get_mut(usize::from(p)) {
                        fill(w, i, *item);
                    }
                }
                _ => {
                    return Err(ServoError::BadId {
                        id,
                        what: "is on none of the bus's ports",
                    })
                }
            }
        }
        Ok(())
    }
}

impl<B: ServoBus + Send + 'static> ServoBus for Ports<B> {
    fn baud(&self) -> u32 {
        match &self.inner {
            Inner::One(bus) => bus.baud(),
            Inner::Many(_) => self.baud,
        }
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        self.every(move |bus| bus.set_baud(baud))?;
        self.baud = baud;
        Ok(())
    }

    /// Several ports: Fast Sync Read when every port reads with it, else Sync Read (some port
    /// does); [`ServoBus::read_kinds`] tells each.
    fn read_kind(&self) -> ReadKind {
        match &self.inner {
            Inner::One(bus) => bus.read_kind(),
            Inner::Many(_) => ReadKind::of_ports(&self.reads),
        }
    }

    /// Every port reads with `kind`.
    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        self.every(move |bus| bus.set_read_kind(kind))?;
        self.reads.iter_mut().for_each(|k| *k = kind);
        Ok(())
    }

    fn port_index(&self, id: u8) -> usize {
        self.port_of(id).unwrap_or(0)
    }

    fn port_failed(&self, port: usize) -> bool {
        match &self.inner {
            Inner::One(_) => false,
            Inner::Many(workers) => workers.get(port).is_some_and(|w| w.failed),
        }
    }

    fn adapters(&self) -> Vec<Option<Adapter>> {
        match &self.inner {
            Inner::One(bus) => bus.adapters(),
            Inner::Many(_) => self.adapters.clone(),
        }
    }

    fn read_kinds(&self) -> Vec<ReadKind> {
        match &self.inner {
            Inner::One(bus) => vec![bus.read_kind()],
            Inner::Many(_) => self.reads.clone(),
        }
    }

    /// Each port reads with its own kind (bring-up chose each from its servos).
    fn set_read_kinds(&mut self, kinds: &[ReadKind]) -> Result<(), ServoError> {
        let workers = match &mut self.inner {
            Inner::One(bus) => return bus.set_read_kinds(kinds),
            Inner::Many(workers) => workers,
        };
        if kinds.len() != workers.len() {
            return Err(ServoError::Unsupported {
                what: "one read kind is needed per port",
            });
        }
        for (k, (w, &kind)) in workers.iter_mut().zip(kinds).enumerate() {
            w.call(move |bus| bus.set_read_kind(kind))?
                .map_err(|e| w.named(e))?;
            self.reads[k] = kind;
        }
        Ok(())
    }

    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        self.on(id, move |bus| bus.ping(id, timeout))
    }

    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        self.on(id, move |bus| bus.ping_counted(id, timeout))
    }

    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        let mut found: Vec<PingInfo> = self
            .every(move |bus| bus.scan(timeout))?
            .into_iter()
            .flatten()
            .collect();
        found.sort_by_key(|p| p.id);
        Ok(found)
    }

    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError> {
        self.on(id, move |bus| bus.read(id, register, timeout))
    }

    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError> {
        self.on(id, move |bus| bus.write(id, register, value, timeout))
    }

    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        let workers = match &mut self.inner {
            Inner::One(bus) => return bus.sync_read_into(ids, address, len, timeout, out),
            Inner::Many(workers) => workers,
        };
        out.reset(ids, len, timeout);
        for w in workers.iter_mut() {
            w.ids.clear();
            w.slots.clear();
        }
        Self::split(
            &self.route,
            workers,
            ids,
            |&id| id,
            |w, i, id| {
                w.ids.push(id);
                w.slots.push(i);
            },
        )?;
        let mut first_error = None;
        for w in workers.iter_mut().filter(|w| !w.ids.is_empty()) {
            let job = Job::Read {
                ids: std::mem::take(&mut w.ids),
                address,
                len,
                timeout,
                buf: std::mem::take(&mut w.buf),
            };
            if let Err(e) = w.send(job) {
                first_error.get_or_insert(e);
            }
        }
        for w in workers.iter_mut().filter(|w| w.busy) {
            match w.wait() {
                Ok(Done::Read(ids, mut buf, result)) => {
                    match result {
                        Ok(()) => {
                            for (k, &i) in w.slots.iter().enumerate() {
                                match buf.take_error(k) {
                                    Some(e) => out.fail(i, e),
                                    None => {
                                        if let Ok((data, alert)) = buf.get(k) {
                                            out.set(i, data, alert);
                                        }
                                    }
                                }
                            }
                        }
                        Err(e) => {
                            first_error.get_or_insert(w.named(e));
                        }
                    }
                    w.ids = ids;
                    w.buf = buf;
                }
                Ok(_) => {
                    first_error.get_or_insert(w.gone());
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        if let Inner::One(bus) = &mut self.inner {
            return bus.sync_write(register, values);
        }
        let mut by_port: Vec<Vec<(u8, i64)>> = vec![Vec::new(); self.len()];
        for &(id, v) in values {
            by_port[self.port_of(id)?].push((id, v));
        }
        match &mut self.inner {
            Inner::One(bus) => bus.sync_write(register, values),
            Inner::Many(workers) => {
                let mut pending = Vec::with_capacity(workers.len());
                let mut first_error = None;
                for (w, part) in workers.iter_mut().zip(by_port) {
                    if part.is_empty() {
                        pending.push(None);
                        continue;
                    }
                    // A port that cannot take it is reported once the others have answered:
                    // returning at once would leave their answers to be taken by their next
                    // calls, one answer behind from then on.
                    match w.start(move |bus: &mut B| bus.sync_write(register, &part)) {
                        Ok(rx) => pending.push(Some(rx)),
                        Err(e) => {
                            first_error.get_or_insert(e);
                            pending.push(None);
                        }
                    }
                }
                for (w, rx) in workers.iter_mut().zip(pending) {
                    let Some(rx) = rx else { continue };
                    if let Err(e) = w.finish(rx).and_then(|r| r.map_err(|e| w.named(e))) {
                        first_error.get_or_insert(e);
                    }
                }
                match first_error {
                    Some(e) => Err(e),
                    None => Ok(()),
                }
            }
        }
    }

    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        let workers = match &mut self.inner {
            Inner::One(bus) => return bus.write_goals(goals),
            Inner::Many(workers) => workers,
        };
        for w in workers.iter_mut() {
            w.goals.clear();
        }
        Self::split(
            &self.route,
            workers,
            goals,
            |g| g.id,
            |w, _, g| {
                w.goals.push(g);
            },
        )?;
        let mut first_error = None;
        for w in workers.iter_mut().filter(|w| !w.goals.is_empty()) {
            let goals = std::mem::take(&mut w.goals);
            if let Err(e) = w.send(Job::Goals(goals)) {
                first_error.get_or_insert(e);
            }
        }
        for w in workers.iter_mut().filter(|w| w.busy) {
            match w.wait() {
                Ok(Done::Goals(goals, result)) => {
                    w.goals = goals;
                    if let Err(e) = result {
                        first_error.get_or_insert(w.named(e));
                    }
                }
                Ok(_) => {
                    first_error.get_or_insert(w.gone());
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        self.on(id, move |bus| bus.reboot(id, timeout))
    }

    fn close(&mut self) {
        match &mut self.inner {
            Inner::One(bus) => bus.close(),
            Inner::Many(workers) => {
                for w in workers.iter_mut() {
                    // A port whose thread is gone has nothing left to close.
                    let _ = w.call(|bus: &mut B| bus.close());
                }
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::collections::BTreeMap;
    use std::sync::{Arc, Mutex};

    use super::*;
    use crate::servo::{Fields, States};

    /// A port in memory: its servos' positions, what it was sent, and whether it is gone.
    #[derive(Debug, Default)]
    struct Wire {
        positions: BTreeMap<u8, i32>,
        silent: Vec<u8>,
        gone: bool,
        /// The next call panics (its port's thread stops).
        boom: bool,
        goal_writes: usize,
    }

    #[derive(Debug, Clone, Default)]
    struct Memory(Arc<Mutex<Wire>>);

    impl Memory {
        fn with(ids: &[u8]) -> Self {
            let m = Memory::default();
            for &id in ids {
                m.0.lock()
                    .unwrap()
                    .positions
                    .insert(id, 1000 + i32::from(id));
            }
            m
        }
        fn check(&self) -> Result<(), ServoError> {
            let boom = self.0.lock().unwrap().boom;
            assert!(!boom, "the bus panics");
            if self.0.lock().unwrap().gone {
                return Err(ServoError::Io(std::io::Error::new(
                    std::io::ErrorKind::BrokenPipe,
                    "unplugged",
                )));
            }
            Ok(())
        }
    }

    impl ServoBus for Memory {
        fn baud(&self) -> u32 {
            1_000_000
        }
        fn set_baud(&mut self, _: u32) -> Result<(), ServoError> {
            self.check()
        }
        fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
            self.check()?;
            let w = self.0.lock().unwrap();
            match w.positions.get(&id) {
                Some(_) if !w.silent.contains(&id) => Ok(PingInfo {
                    id,
                    model: 1060,
                    firmware: 46,
                    alert: false,
                }),
                _ => Err(ServoError::Timeout {
                    id,
                    waited: timeout,
                }),
            }
        }
        fn scan(&mut self, t: Duration) -> Result<Vec<PingInfo>, ServoError> {
            let ids: Vec<u8> = self.0.lock().unwrap().positions.keys().copied().collect();
            Ok(ids
                .into_iter()
                .filter_map(|id| self.ping(id, t).ok())
                .collect())
        }
        fn read(&mut self, id: u8, _: Register, t: Duration) -> Result<Value, ServoError> {
            self.ping(id, t)?;
            Ok(Value {
                value: i64::from(id),
                alert: false,
            })
        }
        fn write(&mut self, id: u8, _: Register, _: i64, t: Duration) -> Result<Ack, ServoError> {
            self.ping(id, t)?;
            Ok(Ack { id, alert: false })
        }
        fn sync_read_into(
            &mut self,
            ids: &[u8],
            _address: u16,
            len: u16,
            timeout: Duration,
            out: &mut SyncReadBuf,
        ) -> Result<(), ServoError> {
            self.check()?;
            out.reset(ids, len, timeout);
            let w = self.0.lock().unwrap();
            for (i, id) in ids.iter().enumerate() {
                if let (Some(p), false) = (w.positions.get(id), w.silent.contains(id)) {
                    let mut data = vec![0u8; usize::from(len)];
                    let n = data.len();
                    // A position where it fits; a shorter register (Torque Enable) reads 0.
                    if n >= 4 {
                        data[n - 4..].copy_from_slice(&p.to_le_bytes());
                    }
                    out.set(i, &data, false);
                }
            }
            Ok(())
        }
        fn sync_write(&mut self, _: Register, _: &[(u8, i64)]) -> Result<(), ServoError> {
            self.check()
        }
        fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
            self.check()?;
            let mut w = self.0.lock().unwrap();
            w.goal_writes += 1;
            for g in goals {
                assert!(
                    w.positions.contains_key(&g.id),
                    "goal of {} sent to the wrong port",
                    g.id
                );
                w.positions.insert(g.id, g.ticks);
            }
            Ok(())
        }
        fn reboot(&mut self, id: u8, t: Duration) -> Result<Ack, ServoError> {
            self.write(id, Register::TorqueEnable, 0, t)
        }
    }

    const T: Duration = Duration::from_millis(5);

    fn two() -> (Ports<Memory>, Memory, Memory) {
        let (a, b) = (Memory::with(&[1, 2, 3]), Memory::with(&[4, 5, 6]));
        let ports = Ports::new(vec![
            ("/dev/ttyUSB0".into(), a.clone(), vec![1, 2, 3]),
            ("/dev/ttyUSB1".into(), b.clone(), vec![4, 5, 6]),
        ])
        .unwrap();
        (ports, a, b)
    }

    #[test]
    fn goals_go_to_each_servos_port_in_one_write_per_port() {
        let (mut ports, a, b) = two();
        let goals: Vec<Goal> = [6, 1, 4, 2, 5, 3]
            .iter()
            .map(|&id| Goal {
                id,
                ticks: 2000 + i32::from(id),
            })
            .collect();
        ports.write_goals(&goals).unwrap();
        assert_eq!(a.0.lock().unwrap().goal_writes, 1);
        assert_eq!(b.0.lock().unwrap().goal_writes, 1);
        assert_eq!(a.0.lock().unwrap().positions[&2], 2002);
        assert_eq!(b.0.lock().unwrap().positions[&6], 2006);
    }

    #[test]
    fn a_read_across_ports_keeps_the_callers_order_and_each_servos_outcome() {
        let (mut ports, _a, b) = two();
        b.0.lock().unwrap().silent.push(5);
        let mut states = States::new();
        let ids = [5, 1, 6, 2];
        ports
            .read_states_into(&ids, Fields::POSITION, T, &mut states)
            .unwrap();
        let r = states.readings();
        assert!(r[0].as_ref().unwrap_err().is_timeout(), "{:?}", r[0]);
        assert_eq!(r[1].as_ref().unwrap().position_ticks, 1001);
        assert_eq!(r[2].as_ref().unwrap().position_ticks, 1006);
        assert_eq!(r[3].as_ref().unwrap().position_ticks, 1002);
        // Again, into the same buffers.
        b.0.lock().unwrap().silent.clear();
        ports
            .read_states_into(&ids, Fields::POSITION, T, &mut states)
            .unwrap();
        assert_eq!(states.readings()[0].as_ref().unwrap().position_ticks, 1005);
    }

    #[test]
    fn a_vanished_port_is_named_and_single_servo_calls_go_to_their_port() {
        let (mut ports, _a, b) = two();
        assert_eq!(ports.ping(2, T).unwrap().id, 2);
        assert_eq!(ports.read(6, Register::Moving, T).unwrap().value, 6);
        assert_eq!(ports.scan(T).unwrap().len(), 6);
        b.0.lock().unwrap().gone = true;
        let e = ports.read_states(&[1, 4], Fields::POSITION, T).unwrap_err();
        assert_eq!(e.class(), ErrorClass::Bus);
        assert!(e.to_string().contains("/dev/ttyUSB1"), "{e}");
        assert_eq!(e.port(), Some("/dev/ttyUSB1"));
        let e = ports.write_goals(&[Goal { id: 5, ticks: 0 }]).unwrap_err();
        assert_eq!(e.port(), Some("/dev/ttyUSB1"));
        // The other port still answers its servos.
        assert_eq!(ports.ping(3, T).unwrap().id, 3);
        assert!(matches!(
            ports.ping(9, T),
            Err(ServoError::BadId { id: 9, .. })
        ));
    }

    #[test]
    fn a_sync_write_refused_by_a_stopped_port_leaves_the_other_ports_in_step() {
        let (mut ports, a, b) = two();
        // Port B's thread stops (its bus panicked).
        b.0.lock().unwrap().boom = true;
        assert_eq!(ports.ping(4, T).unwrap_err().port(), Some("/dev/ttyUSB1"));
        let e = ports
            .sync_write(Register::TorqueEnable, &[(1, 0), (4, 0)])
            .unwrap_err();
        assert_eq!(e.port(), Some("/dev/ttyUSB1"));
        // Port A is sound: its next calls are answered, each with its own answer.
        ports.write_goals(&[Goal { id: 1, ticks: 2000 }]).unwrap();
        assert_eq!(a.0.lock().unwrap().positions[&1], 2000);
        let r = ports.read_states(&[2], Fields::POSITION, T).unwrap();
        assert_eq!(r[0].as_ref().unwrap().position_ticks, 1002);
    }

    #[test]
    fn only_a_failed_port_is_opened_again_and_the_other_keeps_its_bus() {
        let (mut ports, a, b) = two();
        b.0.lock().unwrap().gone = true;
        let goals = |ticks| [Goal { id: 1, ticks }, Goal { id: 4, ticks }];
        assert_eq!(
            ports.write_goals(&goals(2000)).unwrap_err().port(),
            Some("/dev/ttyUSB1")
        );
        assert_eq!(ports.failed(), ["/dev/ttyUSB1"]);
        // Opening it fails: it stays failed, the other untouched.
        let e = ports.reopen_failed(|_| Err("not there yet")).unwrap_err();
        assert!(matches!(e, ReopenPortError::Open("not there yet")), "{e:?}");
        assert_eq!(ports.failed(), ["/dev/ttyUSB1"]);
        let fresh = Memory::with(&[4, 5, 6]);
        let mut opened = Vec::new();
        ports
            .reopen_failed(|k| {
                opened.push(k);
                Ok::<_, ServoError>(fresh.clone())
            })
            .unwrap();
        assert_eq!(opened, [1]);
        assert!(ports.failed().is_empty());
        ports.write_goals(&goals(2100)).unwrap();
        // Port A kept its bus throughout: both writes reached it.
        assert_eq!(a.0.lock().unwrap().goal_writes, 2);
        assert_eq!(a.0.lock().unwrap().positions[&1], 2100);
        assert_eq!(fresh.0.lock().unwrap().positions[&4], 2100);
    }

    #[test]
    fn a_torque_off_with_one_port_gone_reaches_the_other_and_names_each_servos_own_port() {
        use crate::chain::JointLimit;
        use crate::servo::arm::{Arm, JointServo, Settings, Within};
        use crate::servo::clock::{Clock, ManualClock};
        use crate::servo::model::ServoModel;
        use crate::servo::units::Calibration;
        let (mut ports, _a, b) = two();
        b.0.lock().unwrap().gone = true;
        let joints = (1..=6)
            .map(|id| {
                JointServo::new(
                    usize::from(id),
                    id,
                    ServoModel::from_name("XL430-W250").unwrap(),
                    Calibration::default(),
                    JointLimit { lo: -1.5, hi: 1.5 },
                )
            })
            .collect();
        let arm = Arm::new(joints, Settings::default());
        let clock = ManualClock::new();
        let within = Within::new(&clock, clock.now() + Duration::from_millis(50), T);
        let unreached = arm.torque_off(&mut ports, &[], &within).unwrap_err();
        let ids: Vec<u8> = unreached.iter().map(|u| u.id).collect();
        assert_eq!(ids, [4, 5, 6], "{unreached:?}");
        for u in &unreached {
            assert!(u.why.contains("/dev/ttyUSB1"), "{u}");
            assert!(!u.why.contains("/dev/ttyUSB0"), "{u}");
        }
    }

    #[test]
    fn one_port_is_the_bus_itself() {
        let a = Memory::with(&[1, 2]);
        let mut ports = Ports::new(vec![("/dev/ttyUSB0".into(), a.clone(), vec![1, 2])]).unwrap();
        assert_eq!(ports.len(), 1);
        a.0.lock().unwrap().gone = true;
        let e = ports.write_goals(&[Goal { id: 1, ticks: 0 }]).unwrap_err();
        assert!(matches!(e, ServoError::Io(_)), "{e:?}");
    }
}
