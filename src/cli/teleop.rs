//! `snakectl teleop`: steer the tip from the keyboard or a joystick, the arm drawn live.
//!
//! One loop owns the terminal: it reads keys and clicks, turns them (and the joystick's
//! events) into requests through `teleop::input`, sends them without waiting for replies,
//! and redraws from the latest telemetry at most ~30 times a second. Connecting happens on a
//! thread of its own, so the screen stays alive (and `q` quits) while the daemon is away.

use std::fs::File;
use std::io::{IsTerminal as _, Write};
use std::os::fd::AsFd as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use clap::Args;
use crossterm::event::{
    self, DisableBracketedPaste, DisableMouseCapture, EnableBracketedPaste, EnableMouseCapture,
    Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers, KeyboardEnhancementFlags, MouseButton,
    MouseEventKind, PopKeyboardEnhancementFlags, PushKeyboardEnhancementFlags,
};
use crossterm::terminal::{self, EnterAlternateScreen, LeaveAlternateScreen};
use ratatui::backend::CrosstermBackend;
use ratatui::layout::Rect;
use ratatui::Terminal;

use snakectl::client::{self, ArmInfo, Client, ClientError, Incoming, Replied, Status as Snapshot};
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{Embedded, RunOptions};
use snakectl::protocol::{Cmd, CmdName, Reply, State, What};
use snakectl::record::RecordOptions;
use snakectl::resolve::Strategy;
use snakectl::teleop::input::{Action, Key, KeyKind, Keyboard, DEFAULT_SPEED_M_S};
use snakectl::teleop::joystick::{self, Device, Stick, StickEvent};
use snakectl::teleop::ui::{self, Contact, Panel, Trail, View};
use snakectl::world::World;
use snakectl_sim::RealClock;

use super::signals::Signals;
use super::term_out::TermOut;
use super::Failure;

#[derive(Debug, Args)]
pub struct TeleopArgs {
    /// The daemon's address, `host:port` (default: `--sim`'s `[server] listen`, else
    /// 127.0.0.1:7878).
    #[arg(long, value_name = "ADDR")]
    pub connect: Option<String>,
    /// Start the simulator and the daemon in this process on CONFIG, listening on its
    /// `[server] listen`, and steer that.
    #[arg(long, value_name = "CONFIG", conflicts_with = "connect")]
    pub sim: Option<PathBuf>,
    /// A joystick device (`/dev/input/js0`, `/dev/input/event5`), or `auto` for the first
    /// `/dev/input/js*`.
    #[arg(long, value_name = "DEV|auto")]
    pub joystick: Option<String>,
    /// The joystick button that must be held for the stick to move the tip.
    #[arg(long, default_value_t = 4)]
    pub deadman_button: u8,
    /// A file whose first line is the daemon's token (`[server] token_file`).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// With `--sim`: record the run to this MCAP file (see docs/RECORDING.md).
    #[arg(long, value_name = "FILE.mcap", requires = "sim")]
    pub record: Option<PathBuf>,
    /// Replace the `--record` file if it exists (else that is refused, and the file kept).
    #[arg(long, requires = "record")]
    pub overwrite: bool,
}

/// Telemetry lines a second the UI asks for.
const TELEMETRY_HZ: f64 = 30.0;

/// The shortest time between two frames.
const FRAME: Duration = Duration::from_millis(33);

/// The longest wait for input: the loop looks at telemetry and replies at least this often.
const MAX_POLL: Duration = Duration::from_millis(50);

/// Terminal events handled in one wait at most, so that a flood of input (a paste into a
/// terminal that does not mark pastes) cannot keep the loop from the daemon and the screen.
const EVENTS_PER_WAIT: usize = 64;

/// A `stop` this soon after one sent with nothing between is not sent again.
const STOP_AGAIN: Duration = Duration::from_millis(100);

/// The wait that takes the terminal's input already come, without waiting for more.
const DRAIN_WAIT: Duration = Duration::from_micros(1);

/// How often a lost daemon is tried again.
const RETRY: Duration = Duration::from_secs(1);

/// The longest a request waits for the daemon to take it: the screen (and `q`) wait with it,
/// and a daemon that reads nothing for this long is taken as gone.
const SEND_WAIT: Duration = Duration::from_millis(500);

/// How long a notice stays on screen.
const NOTICE_FOR: Duration = Duration::from_secs(5);

/// The longest the terminal's modes wait to be given back to a terminal that takes no output:
/// past it the UI ends all the same (raw mode is left in any case: that needs no output).
const RESTORE_WAIT: Duration = Duration::from_millis(500);

/// Measured tips kept for the trail.
const TRAIL_POINTS: usize = 2000;

/// Joystick events waiting for the loop.
const STICK_QUEUE: usize = 256;

/// Replies and events read in one pass of the loop, at most.
const DRAIN: usize = 1024;

/// Runs the UI until `q` (or Ctrl-C), or until SIGTERM, SIGHUP or SIGINT: exit status 128 plus
/// the signal's number then.
pub fn run(args: TeleopArgs) -> Result<(), Failure> {
    // Nothing is logged: a log line would garble the screen.
    // Before anything starts: without a terminal there is nothing to steer from.
    let tty = Tty::open().map_err(Failure::bad_input)?;
    let signals = Signals::catch()
        .context("installing the signal handlers")
        .map_err(Failure::other)?;
    let mut local = None;
    let (addr, token_file) = match &args.sim {
        Some(path) => {
            let config = Config::load(path).map_err(Failure::bad_input)?;
            let sim =
                connect::spawn_sim(&config, Arc::new(RealClock)).map_err(Failure::bad_input)?;
            let listen = config.server().listen;
            let token_file = args
                .token_file
                .clone()
                .or_else(|| config.server().token_file.clone());
            // Said here, before the screen takes the terminal; the daemon then writes over
            // the file made here.
            let made = match &args.record {
                Some(path) => snakectl::record::McapSink::create(path, args.overwrite)
                    .map_err(Failure::bad_input)?
                    .made_file()
                    .then_some(path),
                None => None,
            };
            let options = RunOptions::port(sim.path().to_path_buf()).recorded(
                args.record
                    .clone()
                    .map(|path| RecordOptions::to(path).overwriting(true)),
            );
            let embedded = Embedded::start(config, listen, options)
                .with_context(|| format!("starting the daemon on {listen}"))
                .map_err(|e| {
                    // The daemon leaves a file that was there before it: this one was not.
                    if let Some(path) = made {
                        let _ = std::fs::remove_file(path);
                    }
                    Failure::other(e)
                })?;
            let addr = embedded.addr().to_string();
            local = Some((embedded, sim));
            (addr, token_file)
        }
        None => (
            args.connect
                .clone()
                .unwrap_or_else(|| client::DEFAULT_ADDR.to_owned()),
            args.token_file.clone(),
        ),
    };
    let stick = match &args.joystick {
        Some(name) => {
            let device = if name == "auto" {
                Device::Auto
            } else {
                Device::Path(PathBuf::from(name))
            };
            let (tx, rx) = mpsc::sync_channel(STICK_QUEUE);
            joystick::spawn(device, tx)
                .context("starting the joystick reader")
                .map_err(Failure::other)?;
            // The panel is narrow: the device's file name says enough.
            let short = std::path::Path::new(name)
                .file_name()
                .map_or_else(|| name.clone(), |f| f.to_string_lossy().into_owned());
            Some((short, rx))
        }
        None => None,
    };
    let outcome = {
        let embedded = local.as_ref().map(|(embedded, _)| embedded);
        let screen_out = ScreenOut::new(signals.clone());
        let mut app = App::new(addr, token_file, args.deadman_button, stick, signals, tty);
        match Screen::enter(screen_out) {
            Ok(mut screen) => {
                app.keyboard.set_releases_reported(screen.releases_reported);
                app.run(&mut screen, embedded)
            }
            Err(e) => {
                // Whatever part of the set-up was done is undone.
                restore_terminal();
                Err(e)
            }
        }
        // The screen is restored here, before the daemon is stopped.
    };
    if let Some((embedded, sim)) = local {
        // Brings the arm to rest and leaves the servos as `[bus] on_exit` says.
        let stopped = embedded.stop();
        drop(sim);
        match (&outcome, stopped) {
            (_, Ok(_)) => {}
            (Ok(_), Err(e)) => {
                return Err(Failure::other(
                    anyhow::Error::new(e).context("stopping the daemon"),
                ))
            }
            // Why the daemon stopped is the news, not that the UI noticed it.
            (Err(noticed), Err(e)) => {
                return Err(Failure::other(
                    anyhow::Error::new(e).context(noticed.to_string()),
                ))
            }
        }
    }
    match outcome {
        Ok(Quit::Asked) => Ok(()),
        Ok(Quit::Signal(signal)) => Err(super::signals::stopped_by(signal)),
        Ok(Quit::HungUp) => Err(Failure {
            code: u8::try_from(128 + signal_hook::consts::SIGHUP).unwrap_or(1),
            error: anyhow::anyhow!("stopped: the terminal hung up"),
        }),
        Err(e) => Err(Failure::other(e)),
    }
}

/// How the UI ended, when it did not fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Quit {
    /// `q` or Ctrl-C.
    Asked,
    /// One of [`super::signals::QUIT_SIGNALS`].
    Signal(i32),
    /// The terminal hung up without a SIGHUP reaching this process: ends as one does.
    HungUp,
}

/// The terminal the UI reads (standard input, or `/dev/tty` when that is not a terminal, as
/// the terminal library chooses), watched for a hang-up: a terminal closed without a SIGHUP
/// reaching this process (it is not in the terminal's foreground) ends the UI all the same.
struct Tty {
    dev_tty: Option<File>,
}

impl Tty {
    fn open() -> anyhow::Result<Self> {
        if std::io::stdin().is_terminal() {
            return Ok(Self { dev_tty: None });
        }
        let dev_tty = File::options()
            .read(true)
            .write(true)
            .open("/dev/tty")
            .context("teleop needs a terminal: standard input is not one, nor is there /dev/tty")?;
        Ok(Self {
            dev_tty: Some(dev_tty),
        })
    }

    /// Whether the terminal has hung up (its other side closed).
    fn hung_up(&self) -> bool {
        use rustix::event::{poll, PollFd, PollFlags, Timespec};
        let stdin = std::io::stdin();
        let fd = match &self.dev_tty {
            Some(file) => file.as_fd(),
            None => stdin.as_fd(),
        };
        let mut fds = [PollFd::from_borrowed_fd(fd, PollFlags::IN)];
        let now = Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        poll(&mut fds, Some(&now)).is_ok()
            && fds[0]
                .revents()
                .intersects(PollFlags::HUP | PollFlags::ERR | PollFlags::NVAL)
    }
}

/// Whether the terminal is in the UI's modes, for the panic hook and the guard.
static ACTIVE: AtomicBool = AtomicBool::new(false);
/// Whether keyboard enhancement flags were pushed.
static ENHANCED: AtomicBool = AtomicBool::new(false);

/// Leaves raw mode, the alternate screen, mouse capture and the kitty flags, and shows the
/// cursor; once, however often it is called. Raw mode goes first: it takes no output, so the
/// terminal gets it back even when it takes none of the rest, which is given up on after
/// [`RESTORE_WAIT`].
fn restore_terminal() {
    if !ACTIVE.swap(false, Ordering::SeqCst) {
        return;
    }
    let _ = terminal::disable_raw_mode();
    let mut bytes = Vec::new();
    if ENHANCED.swap(false, Ordering::SeqCst) {
        let _ = crossterm::queue!(bytes, PopKeyboardEnhancementFlags);
    }
    let _ = crossterm::queue!(
        bytes,
        DisableBracketedPaste,
        DisableMouseCapture,
        LeaveAlternateScreen,
        crossterm::cursor::Show
    );
    match TermOut::reopen(std::io::stdout()) {
        Some(term) => {
            let _ = term.write_all_by(&bytes, Instant::now() + RESTORE_WAIT);
        }
        None => {
            let mut out = std::io::stdout().lock();
            let _ = out.write_all(&bytes).and_then(|()| out.flush());
        }
    }
}

/// The screen's output. What a frame writes is kept, and written at its end
/// ([`Write::flush`]) through [`TermOut`], so that a terminal that takes no output (the
/// program on its other side stopped reading, or flow control) holds the UI only until a
/// signal comes: what is left of the frame is then dropped, and the UI ends on the signal at
/// its next turn. A hung-up terminal takes whatever is written (`EIO`, the error a write to one
/// gets, counts as written). Neither is an error: the screen's library prints to standard
/// error (which may be that terminal), and so panics or blocks, when it cannot show the cursor
/// again as it is dropped.
struct ScreenOut {
    pending: Vec<u8>,
    /// The terminal opened again without blocking; `None` (standard output not a terminal, or
    /// not to be opened again): standard output itself.
    term: Option<TermOut>,
    signals: Signals,
}

impl ScreenOut {
    fn new(signals: Signals) -> Self {
        Self {
            pending: Vec::new(),
            term: TermOut::reopen(std::io::stdout()),
            signals,
        }
    }
}

impl Write for ScreenOut {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.pending.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let mut pending = std::mem::take(&mut self.pending);
        let signals = &self.signals;
        let written = match &self.term {
            Some(term) => term.write_all(&pending, || {
                signals.received().map(|signal| {
                    std::io::Error::other(format!(
                        "signal {signal} came while the terminal took no output"
                    ))
                })
            }),
            None => {
                let mut out = std::io::stdout().lock();
                out.write_all(&pending).and_then(|()| out.flush())
            }
        };
        pending.clear();
        self.pending = pending;
        match written {
            Err(e) if hung_up_error(&e) || self.signals.received().is_some() => Ok(()),
            other => other,
        }
    }
}

/// Whether `e` is what a hung-up terminal answers a write with.
fn hung_up_error(e: &std::io::Error) -> bool {
    e.raw_os_error() == Some(rustix::io::Errno::IO.raw_os_error())
}

/// The terminal in the UI's modes; restored when dropped (also on an error return), and by
/// the panic hook before a panic's message is printed.
struct Screen {
    terminal: Terminal<CrosstermBackend<ScreenOut>>,
    releases_reported: bool,
}

impl Screen {
    /// The terminal in the UI's modes, the screen written through `out`.
    fn enter(out: ScreenOut) -> anyhow::Result<Self> {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            restore_terminal();
            previous(info);
        }));
        terminal::enable_raw_mode().context("putting the terminal in raw mode")?;
        ACTIVE.store(true, Ordering::SeqCst);
        // From here on an early return drops the screen, which restores the terminal.
        let mut screen = Screen {
            terminal: Terminal::new(CrosstermBackend::new(out)).context("opening the terminal")?,
            releases_reported: false,
        };
        crossterm::execute!(
            screen.terminal.backend_mut(),
            EnterAlternateScreen,
            EnableMouseCapture,
            // A paste comes as one event, not as keys (it would drive the arm).
            EnableBracketedPaste,
            crossterm::cursor::Hide
        )
        .context("setting up the terminal")?;
        // No answer within its wait (2 s) counts as no.
        if terminal::supports_keyboard_enhancement().unwrap_or(false) {
            crossterm::execute!(
                screen.terminal.backend_mut(),
                PushKeyboardEnhancementFlags(KeyboardEnhancementFlags::REPORT_EVENT_TYPES)
            )
            .context("setting up the terminal")?;
            ENHANCED.store(true, Ordering::SeqCst);
            screen.releases_reported = true;
        }
        screen.terminal.clear().context("clearing the screen")?;
        Ok(screen)
    }
}

impl Drop for Screen {
    fn drop(&mut self) {
        restore_terminal();
    }
}

/// A connection being made on its own thread: the client, subscribed, the arm and its world.
type Connecting = Receiver<Result<(Client, ArmInfo, World), ClientError>>;

/// Connects, describes and subscribes on a thread, so that the loop never waits for it.
fn start_connecting(addr: &str, token_file: Option<PathBuf>) -> Connecting {
    let (tx, rx) = mpsc::sync_channel(1);
    let addr = addr.to_owned();
    let spawned = std::thread::Builder::new()
        .name("snakectl-teleop-connect".into())
        .spawn({
            let tx = tx.clone();
            move || {
                let attempt = || -> Result<(Client, ArmInfo, World), ClientError> {
                    let mut client = Client::connect_with(&addr, token_file.as_deref())?;
                    client.set_write_timeout(SEND_WAIT);
                    let arm = client.describe()?;
                    // A world the daemon sends is valid; one that is not is drawn as none.
                    let world = client.world()?.to_world().unwrap_or_default();
                    client.request(&Cmd::Subscribe {
                        rate_hz: TELEMETRY_HZ,
                    })?;
                    Ok((client, arm, world))
                };
                let _ = tx.send(attempt());
            }
        });
    if let Err(source) = spawned {
        let _ = tx.send(Err(ClientError::Connect {
            addr: "a new thread".into(),
            source,
        }));
    }
    rx
}

/// What a click on the arm's canvas asks for at the point under it.
#[derive(Debug, Clone, Copy)]
enum Click {
    /// Left: the tip along its route there.
    Goto,
    /// Right: a way round the obstacles in joint space, planned by the daemon.
    Reach,
}

/// The UI's state between frames.
struct App {
    addr: String,
    token_file: Option<PathBuf>,
    started: Instant,
    arm: Option<ArmInfo>,
    snapshot: Option<Snapshot>,
    trail: Trail,
    status: Panel,
    /// Until when the notice shows (`None`: while the condition lasts).
    notice_until: Option<Instant>,
    keyboard: Keyboard,
    stick: Stick,
    stick_events: Option<(String, Receiver<StickEvent>)>,
    client: Option<Client>,
    connecting: Option<Connecting>,
    next_attempt: Instant,
    /// Whether the daemon was ever reached (a lost one is "gone", a missing one "not there").
    was_connected: bool,
    my_id: Option<u64>,
    last_take: Option<Instant>,
    /// When telemetry last came on this connection (or it was made, before any came).
    heard: Instant,
    screen_area: Rect,
    dirty: bool,
    last_frame: Option<Instant>,
    actions: Vec<Action>,
    signals: Signals,
    tty: Tty,
    /// When a `stop` was the last request sent, its time.
    last_stop: Option<Instant>,
    /// The notice is the estop's (`Some`), and whether telemetry has shown the latch since:
    /// it goes once the arm is out of it (another client may reset it).
    estop_notice: Option<bool>,
}

impl App {
    fn new(
        addr: String,
        token_file: Option<PathBuf>,
        deadman_button: u8,
        stick_events: Option<(String, Receiver<StickEvent>)>,
        signals: Signals,
        tty: Tty,
    ) -> Self {
        let joystick = stick_events
            .as_ref()
            .map(|(name, _)| format!("opening {name}"));
        let now = Instant::now();
        Self {
            status: Panel {
                addr: addr.clone(),
                link: Contact::Connecting,
                speed_m_s: DEFAULT_SPEED_M_S,
                joystick,
                notice: None,
                scene: ui::Scene::default(),
            },
            addr,
            token_file,
            started: now,
            arm: None,
            snapshot: None,
            trail: Trail::new(TRAIL_POINTS),
            notice_until: None,
            keyboard: Keyboard::new(DEFAULT_SPEED_M_S),
            stick: Stick::new(deadman_button),
            stick_events,
            client: None,
            connecting: None,
            next_attempt: now,
            was_connected: false,
            my_id: None,
            last_take: None,
            heard: now,
            screen_area: Rect::default(),
            dirty: true,
            last_frame: None,
            actions: Vec::new(),
            signals,
            tty,
            last_stop: None,
            estop_notice: None,
        }
    }

    fn now_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Whether this client may command the arm now.
    fn in_control(&self) -> bool {
        self.client.is_some() && self.snapshot.as_ref().is_some_and(|s| s.in_control)
    }

    fn notice(&mut self, text: String) {
        self.estop_notice = None;
        self.status.notice = Some(text);
        self.notice_until = Some(Instant::now() + NOTICE_FOR);
        self.dirty = true;
    }

    /// Until `q` or a signal; `Err` when the terminal fails or the local daemon dies. However
    /// it ends, a motion in progress is stopped as `q` stops it.
    fn run(&mut self, screen: &mut Screen, embedded: Option<&Embedded>) -> anyhow::Result<Quit> {
        let ended = self.serve(screen, embedded);
        if let Ok(Quit::Asked) = ended {
            // `q` has stopped what moved.
            return ended;
        }
        self.halt();
        // A hung-up terminal may fail a read before its signal is seen: the signal is the news.
        match self.signals.received() {
            Some(signal) => Ok(Quit::Signal(signal)),
            None if self.tty.hung_up() => Ok(Quit::HungUp),
            None => ended,
        }
    }

    fn serve(&mut self, screen: &mut Screen, embedded: Option<&Embedded>) -> anyhow::Result<Quit> {
        loop {
            if let Some(signal) = self.signals.received() {
                return Ok(Quit::Signal(signal));
            }
            // A terminal closed under a process its SIGHUP does not reach: the same news.
            if self.tty.hung_up() {
                return Ok(Quit::HungUp);
            }
            if embedded.is_some_and(|e| !e.is_running()) {
                anyhow::bail!("the daemon this UI started has stopped");
            }
            self.keep_connected();
            self.read_daemon();
            self.read_stick();
            let now_s = self.now_s();
            let in_control = self.in_control();
            let mut actions = std::mem::take(&mut self.actions);
            self.keyboard.tick(now_s, in_control, &mut actions);
            let speed = self.keyboard.speed_m_s();
            self.stick.tick(now_s, speed, in_control, &mut actions);
            let quit = self.execute(&mut actions);
            self.actions = actions;
            if quit {
                return Ok(Quit::Asked);
            }
            self.expire_notice();
            self.draw(screen)?;
            if self.wait_input(screen)? {
                return Ok(Quit::Asked);
            }
        }
    }

    /// What `q` sends: a key's hold ended with one zero velocity, and the stick's motion too.
    fn halt(&mut self) {
        let mut actions = std::mem::take(&mut self.actions);
        let now_s = self.now_s();
        let in_control = self.in_control();
        self.keyboard.key(
            Key::Char('q'),
            KeyKind::Press,
            now_s,
            in_control,
            &mut actions,
        );
        self.execute(&mut actions);
        self.actions = actions;
    }

    fn draw(&mut self, screen: &mut Screen) -> anyhow::Result<()> {
        if !self.dirty || self.last_frame.is_some_and(|t| t.elapsed() < FRAME) {
            return Ok(());
        }
        self.status.speed_m_s = self.keyboard.speed_m_s();
        let view = View {
            arm: self.arm.as_ref(),
            snapshot: self.snapshot.as_ref(),
            trail: &self.trail,
            status: &self.status,
        };
        let mut area = self.screen_area;
        screen
            .terminal
            .draw(|frame| {
                area = frame.area();
                ui::draw(frame, &view);
            })
            .context("drawing the screen")?;
        self.screen_area = area;
        self.dirty = false;
        self.last_frame = Some(Instant::now());
        Ok(())
    }

    /// Waits for input up to the next thing to do; handles what came. `true`: quit.
    fn wait_input(&mut self, screen: &mut Screen) -> anyhow::Result<bool> {
        let now_s = self.now_s();
        let mut timeout = MAX_POLL;
        for deadline in [self.keyboard.next_deadline(), self.stick.next_deadline()]
            .into_iter()
            .flatten()
        {
            let left = Duration::try_from_secs_f64((deadline - now_s).clamp(0.0, 1.0))
                .unwrap_or(Duration::ZERO);
            timeout = timeout.min(left);
        }
        if self.dirty {
            if let Some(last) = self.last_frame {
                timeout = timeout.min(FRAME.saturating_sub(last.elapsed()));
            }
        }
        // The terminal's input is read only in a wait that is not zero; after the first
        // event, a microsecond takes what has come already.
        let mut wait = timeout.max(DRAIN_WAIT);
        for _ in 0..EVENTS_PER_WAIT {
            if !event::poll(wait).context("reading the terminal")? {
                break;
            }
            wait = DRAIN_WAIT;
            let event = event::read().context("reading the terminal")?;
            if self.handle(event, screen) {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// One terminal event. `true`: quit.
    fn handle(&mut self, event: Event, screen: &mut Screen) -> bool {
        match event {
            Event::Key(key) => self.handle_key(key),
            Event::Mouse(mouse) => {
                match mouse.kind {
                    MouseEventKind::Down(MouseButton::Left) => {
                        self.click(mouse.column, mouse.row, Click::Goto);
                    }
                    MouseEventKind::Down(MouseButton::Right) => {
                        self.click(mouse.column, mouse.row, Click::Reach);
                    }
                    _ => {}
                }
                false
            }
            Event::Paste(text) => {
                self.notice(format!(
                    "a paste of {} characters ignored: keys steer one at a time",
                    text.chars().count()
                ));
                false
            }
            Event::Resize(cols, rows) => {
                self.screen_area = Rect::new(0, 0, cols, rows);
                let _ = screen.terminal.autoresize();
                self.dirty = true;
                false
            }
            _ => false,
        }
    }

    fn handle_key(&mut self, event: KeyEvent) -> bool {
        let ctrl_c = event.code == KeyCode::Char('c') && event.modifiers == KeyModifiers::CONTROL;
        let kind = match event.kind {
            KeyEventKind::Press => KeyKind::Press,
            KeyEventKind::Repeat => KeyKind::Repeat,
            KeyEventKind::Release => KeyKind::Release,
        };
        let key = if ctrl_c {
            Key::Char('q')
        } else {
            match event.code {
                KeyCode::Up | KeyCode::Char('w') => Key::Up,
                KeyCode::Down | KeyCode::Char('s') => Key::Down,
                KeyCode::Left | KeyCode::Char('a') => Key::Left,
                KeyCode::Right | KeyCode::Char('d') => Key::Right,
                KeyCode::Char(' ') => Key::Space,
                KeyCode::Tab => Key::Tab,
                KeyCode::Esc => Key::Esc,
                KeyCode::Char(c) => Key::Char(c),
                // A modifier on its own is no key.
                KeyCode::Modifier(_) => return false,
                _ => Key::Other,
            }
        };
        let motion = matches!(key, Key::Up | Key::Down | Key::Left | Key::Right);
        // Only a motion key's release means anything: it ends that key's hold.
        if kind == KeyKind::Release && !motion {
            return false;
        }
        let quit = key == Key::Char('q') && kind == KeyKind::Press;
        let mut actions = std::mem::take(&mut self.actions);
        let now_s = self.now_s();
        let in_control = self.in_control();
        self.keyboard
            .key(key, kind, now_s, in_control, &mut actions);
        let asked = self.execute(&mut actions);
        self.actions = actions;
        self.dirty = true;
        asked || quit
    }

    fn click(&mut self, column: u16, row: u16, click: Click) {
        let Some(arm) = &self.arm else {
            return;
        };
        let Some(target) = ui::click_to_world(arm, self.screen_area, column, row) else {
            return;
        };
        if self.in_control() {
            // A key's hold would stop the command with its zero, or replace it at its renewal.
            self.keyboard.give_way();
            self.send(&match click {
                Click::Goto => Cmd::Goto {
                    target,
                    speed: None,
                },
                Click::Reach => Cmd::Reach { target },
            });
        } else {
            self.notice("not in control: press c to take it".to_owned());
        }
    }

    /// Sends each action; `true` when one is Quit (after the ones before it went out, and the
    /// stick's motion ended).
    fn execute(&mut self, actions: &mut Vec<Action>) -> bool {
        let mut quit = false;
        let mut zero_sent = false;
        for action in actions.drain(..) {
            let cmd = match action {
                Action::Quit => {
                    // A stick motion would run on to the daemon's deadman: one zero ends it
                    // (unless a key's hold has just sent its own).
                    let mut halt = Vec::new();
                    self.stick.halt(self.in_control(), &mut halt);
                    if !halt.is_empty() && !zero_sent {
                        self.send(&Cmd::Velocity { v: [0.0, 0.0] });
                    }
                    quit = true;
                    break;
                }
                Action::Velocity(v) => Cmd::Velocity { v },
                Action::Stop => Cmd::Stop,
                Action::Estop => Cmd::Estop,
                Action::Reset => Cmd::Reset,
                Action::Home => Cmd::Home,
                Action::TakeControl => Cmd::TakeControl,
                Action::ToggleTorque => match &self.snapshot {
                    Some(s) => Cmd::Torque { on: !s.torque },
                    None => continue,
                },
                Action::NextStrategy => match self.next_strategy() {
                    Some(name) => Cmd::Strategy { name },
                    None => continue,
                },
            };
            zero_sent = matches!(cmd, Cmd::Velocity { v } if v == [0.0, 0.0]);
            self.send(&cmd);
            self.dirty = true;
        }
        actions.clear();
        quit
    }

    /// The strategy after the present one in `describe`'s list.
    fn next_strategy(&mut self) -> Option<Strategy> {
        let current = self.snapshot.as_ref().map(|s| s.strategy)?;
        let list = &self.arm.as_ref()?.strategies;
        let next = match list.iter().position(|&s| s == current) {
            Some(i) => list.get((i + 1) % list.len()),
            None => list.first(),
        };
        next.copied()
    }

    /// Sends `cmd` without waiting for its reply. A `stop` within [`STOP_AGAIN`] of one sent
    /// with nothing between is not sent again: every key without a meaning stops, and a
    /// flood of them (a paste into a terminal that does not mark pastes) would otherwise pile
    /// up more replies than the daemon keeps for a client, which it disconnects.
    fn send(&mut self, cmd: &Cmd) {
        let now = Instant::now();
        let is_stop = matches!(cmd, Cmd::Stop);
        if is_stop && self.last_stop.is_some_and(|at| now - at < STOP_AGAIN) {
            return;
        }
        let Some(client) = self.client.as_mut() else {
            if matches!(cmd, Cmd::Estop) {
                self.notice("estop not sent: no daemon connected".to_owned());
            }
            return;
        };
        self.last_stop = is_stop.then_some(now);
        if client.send(cmd).is_err() {
            self.lost();
            if matches!(cmd, Cmd::Estop) {
                self.notice("estop not sent: the daemon is gone".to_owned());
            }
        }
    }

    /// The connection is gone: tell, and try again in a second.
    fn lost(&mut self) {
        self.client = None;
        self.status.link = Contact::Gone;
        self.status.notice = Some(format!("daemon at {} gone: retrying", self.addr));
        self.notice_until = None;
        self.next_attempt = Instant::now() + RETRY;
        self.dirty = true;
    }

    /// Starts a connection when none is there or under way, and takes the one made.
    fn keep_connected(&mut self) {
        if self.client.is_some() {
            return;
        }
        if let Some(rx) = &self.connecting {
            let result = match rx.try_recv() {
                Ok(result) => result,
                Err(TryRecvError::Empty) => return,
                Err(TryRecvError::Disconnected) => Err(ClientError::Closed {
                    addr: self.addr.clone(),
                    reason: None,
                }),
            };
            self.connecting = None;
            match result {
                Ok((client, arm, world)) => {
                    self.client = Some(client);
                    self.arm = Some(arm);
                    // The last connection's telemetry, its control above all, says nothing
                    // of this one's: nothing is in control until this daemon says so.
                    self.snapshot = None;
                    self.status.set_world(world);
                    self.was_connected = true;
                    self.status.link = Contact::Connected;
                    self.heard = Instant::now();
                    self.status.notice = None;
                    self.notice_until = None;
                    self.my_id = None;
                    self.last_take = None;
                    self.dirty = true;
                }
                Err(e) => {
                    let away = matches!(
                        e,
                        ClientError::NoDaemon { .. }
                            | ClientError::Connect { .. }
                            | ClientError::Closed { reason: None, .. }
                    );
                    if self.was_connected && away {
                        self.lost();
                    } else {
                        let text = match &e {
                            ClientError::NoDaemon { .. } => {
                                format!("no daemon at {}: retrying", self.addr)
                            }
                            other => format!("{other}: retrying"),
                        };
                        self.status.notice = Some(text);
                        self.notice_until = None;
                        self.next_attempt = Instant::now() + RETRY;
                        self.dirty = true;
                    }
                }
            }
            return;
        }
        if Instant::now() >= self.next_attempt {
            self.connecting = Some(start_connecting(&self.addr, self.token_file.clone()));
        }
    }

    /// The newest telemetry, the replies and events that came; the link silent while no
    /// telemetry comes; takes control when nobody holds it.
    fn read_daemon(&mut self) {
        let Some(client) = self.client.as_mut() else {
            return;
        };
        if let Some(telemetry) = client.telemetry() {
            let snapshot = telemetry.status.clone();
            self.trail.push(snapshot.tip_meas);
            self.snapshot = Some(snapshot);
            self.heard = Instant::now();
            self.dirty = true;
        }
        let mut incoming = Vec::new();
        let mut unreadable = None;
        let mut gone = false;
        for _ in 0..DRAIN {
            match client.next(Duration::ZERO) {
                Ok(Some(one)) => incoming.push(one),
                Ok(None) => break,
                Err(e) if e.is_closed() => {
                    gone = true;
                    break;
                }
                // A line that does not read is told; the connection serves on.
                Err(e) => unreadable = Some(e),
            }
        }
        let closed = gone || client.is_closed();
        for one in incoming {
            self.take_incoming(one);
        }
        if let Some(e) = unreadable {
            self.notice(e.to_string());
        }
        if closed {
            self.lost();
            return;
        }
        // A daemon whose host is gone closes nothing: only its silence tells.
        let link = Contact::live(self.heard.elapsed().as_secs_f64());
        if link != self.status.link {
            self.status.link = link;
            self.dirty = true;
        }
        let nobody = self
            .snapshot
            .as_ref()
            .is_some_and(|s| s.controller.is_none());
        if nobody && self.last_take.is_none_or(|t| t.elapsed() >= RETRY) {
            self.last_take = Some(Instant::now());
            self.send(&Cmd::TakeControl);
        }
    }

    fn take_incoming(&mut self, incoming: Incoming) {
        match incoming {
            Incoming::Reply(Replied { cmd, result, .. }) => match result {
                Ok(fields) => {
                    if cmd == Some(CmdName::TakeControl) {
                        if let Some(me) = fields.reply.client() {
                            self.my_id = Some(me);
                        }
                    }
                    if let Reply::TorqueOff(off) = &fields.reply {
                        if !off.unconfirmed.is_empty() {
                            let ids: Vec<String> =
                                off.unconfirmed.iter().map(|u| u.id.to_string()).collect();
                            self.notice(format!(
                                "torque off not confirmed for servos {}",
                                ids.join(", ")
                            ));
                        }
                    }
                }
                Err(rejection) => {
                    let name = cmd.map_or("request", CmdName::as_str);
                    self.notice(format!("`{name}` refused: {rejection}"));
                }
            },
            Incoming::Event(event) => match event.what {
                What::Control { holder, previous } => {
                    let mine = self.my_id.is_some() && previous == self.my_id;
                    if mine && holder != self.my_id {
                        let text = match holder {
                            Some(n) => format!("client {n} took control: press c to take it"),
                            None => "control released".to_owned(),
                        };
                        self.notice(text);
                    }
                }
                What::Estop { .. } => {
                    self.notice("estop: press r to reset".to_owned());
                    self.estop_notice = Some(false);
                }
                What::World { world, .. } => {
                    self.status.set_world(world.to_world().unwrap_or_default());
                    self.dirty = true;
                }
                What::NotClear { link, obstacle, .. } => self.notice(format!(
                    "link {link} is not clear of \"{obstacle}\": moves that bring no link \
                     closer only"
                )),
                What::Blocked { link, obstacle, .. } => {
                    self.notice(format!(
                        "blocked: link {link} against \"{obstacle}\": a right-click on the \
                         target plans a way round"
                    ));
                }
                What::Fault { reason, fault, .. } => {
                    self.notice(format!("fault {reason}: {fault}"));
                }
                What::Warning { reason, fault, .. } => {
                    self.notice(format!("warning {reason}: {fault}"));
                }
                _ => {}
            },
        }
    }

    fn read_stick(&mut self) {
        let Some((name, rx)) = &self.stick_events else {
            return;
        };
        let name = name.clone();
        let mut events = Vec::new();
        let mut reader_gone = false;
        while events.len() < STICK_QUEUE {
            match rx.try_recv() {
                Ok(event) => events.push(event),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    reader_gone = true;
                    break;
                }
            }
        }
        if reader_gone {
            self.status.joystick = Some(format!("reader stopped ({name})"));
            self.stick_events = None;
            self.dirty = true;
        }
        let mut actions = std::mem::take(&mut self.actions);
        for event in events {
            match event {
                StickEvent::Connected => {
                    self.status.joystick = Some(format!(
                        "connected ({name}), deadman {}",
                        self.stick.deadman_button()
                    ));
                    self.dirty = true;
                }
                StickEvent::Disconnected => {
                    self.status.joystick = Some(format!("gone ({name}): retrying"));
                    self.dirty = true;
                }
                _ => {}
            }
            let now_s = self.now_s();
            let speed = self.keyboard.speed_m_s();
            let in_control = self.in_control();
            self.stick
                .event(event, now_s, speed, in_control, &mut actions);
        }
        // A stick asks for no quit; any that came is dropped.
        self.execute(&mut actions);
        self.actions = actions;
    }

    fn expire_notice(&mut self) {
        let latched = self.snapshot.as_ref().map(|s| s.state == State::Estop);
        let unlatched = match (self.estop_notice, latched) {
            (Some(false), Some(true)) => {
                self.estop_notice = Some(true);
                false
            }
            (Some(true), Some(false)) => true,
            _ => false,
        };
        if unlatched || self.notice_until.is_some_and(|t| Instant::now() >= t) {
            self.estop_notice = None;
            self.status.notice = None;
            self.notice_until = None;
            self.dirty = true;
        }
    }
}
