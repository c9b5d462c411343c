//! A thread beside the loop that serves what the loop publishes to another network (the
//! Foxglove view; the Zenoh bridge with the `zenoh` feature): opened before anything moves,
//! so that a port taken or a router missing stops start-up; handed the way in to the loop
//! (a [`Door`]) once the daemon serves; told to stop, then waited for.

use std::thread::JoinHandle;

use tokio::sync::oneshot;

use super::server::Door;

/// What the thread's body gets: where to say it is open (or why not), then the way in, then
/// the word to stop.
pub struct SideEnds<T, E> {
    /// Sent once: open (with what the opener should know, such as a bound address) or why not.
    pub opened: oneshot::Sender<Result<T, E>>,
    /// The way in, once the daemon serves (dropped unanswered if it never does).
    pub start: oneshot::Receiver<Door>,
    /// Resolves when the thread is to close.
    pub stop: oneshot::Receiver<()>,
}

/// The opener's end of such a thread.
#[derive(Debug)]
pub struct Side {
    start: Option<oneshot::Sender<Door>>,
    stop: Option<oneshot::Sender<()>>,
    done: Option<oneshot::Receiver<()>>,
    thread: Option<JoinHandle<()>>,
}

impl Side {
    /// Starts the thread `name` running `body` and waits until it says it is open; `lost`
    /// names the error of a thread that could not start or ended before it said.
    pub async fn open<T, E>(
        name: &str,
        body: impl FnOnce(SideEnds<T, E>) + Send + 'static,
        lost: impl Fn(String) -> E,
    ) -> Result<(Side, T), E>
    where
        T: Send + 'static,
        E: Send + 'static,
    {
        let (opened_tx, opened_rx) = oneshot::channel();
        let (start_tx, start_rx) = oneshot::channel();
        let (stop_tx, stop_rx) = oneshot::channel();
        let (done_tx, done_rx) = oneshot::channel();
        let ends = SideEnds {
            opened: opened_tx,
            start: start_rx,
            stop: stop_rx,
        };
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                crate::beside::step_aside();
                body(ends);
                let _ = done_tx.send(());
            })
            .map_err(|e| lost(e.to_string()))?;
        match opened_rx.await {
            Ok(Ok(value)) => Ok((
                Side {
                    start: Some(start_tx),
                    stop: Some(stop_tx),
                    done: Some(done_rx),
                    thread: Some(thread),
                },
                value,
            )),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => {
                let _ = thread.join();
                Err(lost("it ended before it was open".into()))
            }
        }
    }

    /// Hands the thread the way in to the loop.
    pub fn start(&mut self, door: Door) {
        if let Some(start) = self.start.take() {
            let _ = start.send(door);
        }
    }

    /// Tells the thread to close and waits for it.
    pub async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(done) = self.done.take() {
            let _ = done.await;
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for Side {
    fn drop(&mut self) {
        // Told to stop; the thread closes what it holds by itself.
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}
