//! The daemon started inside another program: on a thread of its own with its own single-threaded
//! runtime, listening on a socket bound before it returns, stopped on request. Tests, the
//! measurement examples and a one-command demo drive it as any client would.

use std::net::{SocketAddr, TcpListener};
use std::thread::JoinHandle;

use tokio::sync::oneshot;

use crate::config::Config;

use super::{run, DaemonError, RunOptions, Summary};

/// A daemon running in this process. Dropping it stops it too (waiting for the arm to come to
/// rest and the servos to be left as `[bus] on_exit` says).
#[derive(Debug)]
pub struct Embedded {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    thread: Option<JoinHandle<Result<Summary, DaemonError>>>,
}

impl Embedded {
    /// Binds `listen` (port 0 picks a free one) and starts the daemon on `config` behind it.
    /// Returns once the socket listens; a client's first reply waits for bring-up, and a
    /// start-up failure comes back from [`Embedded::stop`].
    pub fn start(
        config: Config,
        listen: SocketAddr,
        options: RunOptions,
    ) -> Result<Self, DaemonError> {
        let listener = TcpListener::bind(listen).map_err(DaemonError::Socket)?;
        listener
            .set_nonblocking(true)
            .map_err(DaemonError::Socket)?;
        let addr = listener.local_addr().map_err(DaemonError::Socket)?;
        let (stop, stopped) = oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("snakectl-daemon".into())
            .spawn(move || {
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .map_err(DaemonError::Thread)?;
                runtime.block_on(async move {
                    let listener =
                        tokio::net::TcpListener::from_std(listener).map_err(DaemonError::Socket)?;
                    // A dropped sender stops the daemon as a sent one does.
                    let shutdown = async {
                        let _ = stopped.await;
                    };
                    run(config, listener, options, shutdown).await
                })
            })
            .map_err(DaemonError::Thread)?;
        Ok(Self {
            addr,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Whether it still runs (it ends by itself only when start-up fails or the loop dies).
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Stops it and waits for `run` to return.
    pub fn stop(mut self) -> Result<Summary, DaemonError> {
        self.finish()
    }

    fn finish(&mut self) -> Result<Summary, DaemonError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        match self.thread.take() {
            Some(thread) => thread.join().unwrap_or(Err(DaemonError::LoopPanicked)),
            None => Err(DaemonError::LoopPanicked),
        }
    }
}

impl Drop for Embedded {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.finish();
        }
    }
}
