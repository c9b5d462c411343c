//! The serial port as the loop holds it: the bus (limited to the joint limits), the way to
//! open it again when it vanishes, and the Bus Watchdog's view of the loop's contact with the
//! servos. Generic over the bus, so the loop's logic runs on an in-memory bus in tests.

use std::time::{Duration, Instant};

use crate::connect::ConnectError;
use crate::protocol::FaultInfo;
use crate::servo::arm::Arm;
use crate::servo::limits::Limited;
use crate::servo::ports::ReopenPortError;
use crate::servo::ServoBus;

/// How often a lost port is reopened, and a failed recovery tried again.
pub const RETRY_EVERY: Duration = Duration::from_secs(1);

/// Opens the lost port again in the bus, limited as at start: on a bus of several ports only
/// the ports that failed, so the others stay open and locked (and their servos reachable).
pub type Opener<B> = Box<dyn FnMut(&Arm, &mut Limited<B>) -> Result<(), ReopenError>>;

/// Why reopening the port failed.
#[derive(Debug, thiserror::Error)]
pub enum ReopenError {
    /// Nothing says which port to open.
    #[error("no port to reopen is known")]
    NoPath,
    /// Opening it failed.
    #[error(transparent)]
    Open(#[from] ConnectError),
    /// Opening a failed port of several failed.
    #[error(transparent)]
    Ports(#[from] ReopenPortError<ConnectError>),
    /// It opened, but the arm did not recover.
    #[error("the port opened, but the arm did not recover: {0}")]
    Recover(String),
}

/// The port failed at tick `since`; it is reopened every [`RETRY_EVERY`].
#[derive(Debug, Clone)]
struct Lost {
    since: u64,
    /// The port that failed, when the bus has several (`None`: the one port, [`Port::name`]).
    which: Option<String>,
    next_try: Instant,
    detail: String,
    /// When it was opened again, the arm still to recover on it.
    reopened: Option<Instant>,
    /// Other ports of the bus that failed since, each with its own fault (the tick and why).
    also: Vec<(String, u64, String)>,
    /// A recovery on the reopened port failed already (logged once at WARN).
    recovery_failed: bool,
}

/// The bus and what keeps it.
pub struct Port<B: ServoBus> {
    bus: Limited<B>,
    opener: Opener<B>,
    lost: Option<Lost>,
    /// The last instruction that reached every servo (a Sync Write or Sync Read sent).
    last_contact: Instant,
    /// The Bus Watchdog's period, when armed.
    watchdog: Option<Duration>,
    /// The port's path, for the reports (`None`: not known).
    name: Option<String>,
    /// A stall whose recovery is still to be done, and how long it was: the goals written since
    /// renew the contact, so the gap alone would not show it again.
    stall_left: Option<Duration>,
    /// The bus has several ports: one lost leaves the others to be written.
    several: bool,
}

impl<B: ServoBus> Port<B> {
    /// `bus` on the port at path `name`, just brought up at `now`; `opener` opens it again; the
    /// servos' Bus Watchdog runs with `watchdog` (`None`: off).
    pub fn new(
        bus: Limited<B>,
        name: Option<String>,
        opener: Opener<B>,
        watchdog: Option<Duration>,
        now: Instant,
    ) -> Self {
        let several = bus.read_kinds().len() > 1;
        Self {
            bus,
            opener,
            lost: None,
            last_contact: now,
            watchdog,
            name,
            stall_left: None,
            several,
        }
    }

    /// The bus has several ports, so a lost one leaves others open.
    pub fn several(&self) -> bool {
        self.several
    }

    /// The port's path, when known.
    pub fn name(&self) -> Option<&str> {
        self.name.as_deref()
    }

    /// The bus.
    pub fn bus(&mut self) -> &mut Limited<B> {
        &mut self.bus
    }

    /// The port is lost.
    pub fn is_lost(&self) -> bool {
        self.lost.is_some()
    }

    /// An instruction reached every servo at `now`.
    pub fn contact(&mut self, now: Instant) {
        self.last_contact = now;
    }

    /// The port failed with `why` at `tick` (`which` of several, when the error says): the
    /// fault to report, `None` if it already was. A bus of several ports is one arm: it holds
    /// while one is lost, and only the ports that failed are reopened.
    pub fn lose(
        &mut self,
        tick: u64,
        now: Instant,
        which: Option<&str>,
        why: &dyn std::fmt::Display,
    ) -> Option<FaultInfo> {
        let detail = |port: &str| {
            format!(
                "the serial port {port} failed ({why}); the arm holds, that port reopened every \
                 second, the others kept open"
            )
        };
        if let Some(lost) = self.lost.as_mut() {
            // Another port of several failing meanwhile is a fault of its own.
            let other = which.filter(|&p| {
                lost.which.as_deref() != Some(p) && lost.also.iter().all(|(q, ..)| q != p)
            })?;
            lost.also.push((other.to_owned(), tick, detail(other)));
            return Some(FaultInfo::port(Some(other.to_owned()), tick, detail(other)));
        }
        let detail = match which {
            Some(port) => detail(port),
            None => format!("the serial port failed ({why}); reopening it every second"),
        };
        self.lost = Some(Lost {
            since: tick,
            which: which.map(str::to_owned),
            next_try: now + RETRY_EVERY,
            detail,
            reopened: None,
            also: Vec::new(),
            recovery_failed: false,
        });
        self.faults().into_iter().next()
    }

    /// The ports' faults as listed, while lost: the first port that failed, then any other of
    /// several that failed since.
    pub fn faults(&self) -> Vec<FaultInfo> {
        let Some(l) = &self.lost else {
            return Vec::new();
        };
        let name = l.which.clone().or_else(|| self.name.clone());
        let mut faults = vec![FaultInfo::port(name, l.since, l.detail.clone())];
        faults.extend(l.also.iter().map(|(port, since, detail)| {
            FaultInfo::port(Some(port.clone()), *since, detail.clone())
        }));
        faults
    }

    /// A lost port whose next try is due at `now`.
    pub fn reopen_due(&self, now: Instant) -> bool {
        self.lost.as_ref().is_some_and(|l| now >= l.next_try)
    }

    /// Open the port again at `now`; the arm is to recover on it from the next tick on, with
    /// that tick's time to itself (opening and bring-up may have spent this one's), each tick
    /// for a [`RETRY_EVERY`] (see [`Port::recovery_failed`]). The opener closes the failed
    /// port first, so its lock is free for this process to take again, and leaves the other
    /// ports of the bus open. The bus reads as it did (the read bring-up chose from the same
    /// servos).
    pub fn reopen(&mut self, arm: &Arm, now: Instant) -> Result<(), ReopenError> {
        let reads = self.bus.read_kinds();
        (self.opener)(arm, &mut self.bus)?;
        if self.bus.read_kinds() != reads {
            if let Err(e) = self.bus.set_read_kinds(&reads) {
                tracing::warn!(?reads, "the reopened port keeps Sync Read: {e}");
            }
        }
        if let Some(lost) = self.lost.as_mut() {
            lost.reopened = Some(now);
            lost.next_try = now;
        }
        Ok(())
    }

    /// The port was opened again and the arm is still to recover on it.
    pub fn reopened(&self) -> bool {
        self.lost.as_ref().is_some_and(|l| l.reopened.is_some())
    }

    /// The recovery on the reopened port failed at `now` (a busy machine can leave a tick too
    /// little time for it): tried again on the next tick, until a [`RETRY_EVERY`] after the
    /// opening; then the port is opened afresh.
    pub fn recovery_failed(&mut self, now: Instant) {
        if let Some(lost) = self.lost.as_mut() {
            lost.next_try = now;
            if lost.reopened.is_some_and(|at| now >= at + RETRY_EVERY) {
                lost.reopened = None;
            }
        }
    }

    /// Whether this is the first recovery on a reopened port that failed since the port was
    /// lost (the cycle logs that one at WARN, the others at DEBUG). Marks it.
    pub fn first_recovery_failure(&mut self) -> bool {
        self.lost
            .as_mut()
            .is_some_and(|l| !std::mem::replace(&mut l.recovery_failed, true))
    }

    /// The ports are back: each fault's clearing to report.
    pub fn found(&mut self) -> Vec<FaultInfo> {
        let Some(lost) = self.lost.take() else {
            return Vec::new();
        };
        let back = || "the port is open again; goals := measured pose".to_owned();
        let mut cleared = vec![FaultInfo::port(
            lost.which.or_else(|| self.name.clone()),
            lost.since,
            back(),
        )];
        cleared.extend(
            lost.also
                .into_iter()
                .map(|(port, since, _)| FaultInfo::port(Some(port), since, back())),
        );
        cleared
    }

    /// A reopening failed at `now`: the next try one [`RETRY_EVERY`] later.
    pub fn retry_later(&mut self, now: Instant) {
        if let Some(lost) = self.lost.as_mut() {
            lost.next_try = now + RETRY_EVERY;
            lost.reopened = None;
        }
    }

    /// The loop went quiet at least as long as the Bus Watchdog (the process was stopped, the
    /// machine stalled), or such a stall is still to be recovered from: the gap and the
    /// watchdog's period.
    pub fn stalled(&self, now: Instant) -> Option<(Duration, Duration)> {
        let watchdog = self.watchdog?;
        if let Some(gap) = self.stall_left {
            return Some((gap, watchdog));
        }
        let gap = now.saturating_duration_since(self.last_contact);
        (gap >= watchdog).then_some((gap, watchdog))
    }

    /// A stall of `gap` could not be recovered from this tick: the next tick's check sees it
    /// again.
    pub fn stall_again(&mut self, gap: Duration) {
        if self.watchdog.is_some() {
            self.stall_left = Some(gap);
        }
    }

    /// The stall is dealt with.
    pub fn stall_handled(&mut self) {
        self.stall_left = None;
    }
}
