//! `snakectl teleop` on a real pseudo-terminal, its screen read back through a terminal
//! emulator: with `--sim` the arm appears, an arrow key moves the tip for one hold and then it
//! rests, a click sends it to the point under the mouse, `q` quits with the terminal given
//! back as it was; on a terminal with the kitty keyboard protocol a held arrow moves the tip
//! until its release; with `--connect` it names another
//! client in control, takes control back on `c`, outlives its daemon and finds a new one; a
//! SIGTERM or SIGHUP stops the arm and gives the terminal back, as `q` does, the first SIGTERM
//! ending it even while its terminal takes no output; a daemon fallen
//! silent (played by the test) shows as such until its telemetry comes again; after a
//! reconnection it claims no control until the new daemon's telemetry grants it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::unix::fs::OpenOptionsExt as _;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use portable_pty::{native_pty_system, Child, CommandBuilder, MasterPty, PtySize};
use snakectl::client::{ArmInfo, Client, Describe, State, Status, Telemetry, WorldInfo};
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{Embedded, RunOptions};
use snakectl::protocol::{self, Applied, Cmd, Fields, Reply, Subscribed, TookControl};
use snakectl::teleop::ui;
use snakectl::world::World;
use snakectl_sim::{RealClock, SimHandle};

/// Bound on waiting for anything; reached only when the test fails.
const DEADLINE: Duration = Duration::from_secs(30);
const ROWS: u16 = 40;
const COLS: u16 = 120;

/// Mode sequences kept per run, at most.
const MODES_KEPT: usize = 1024;

/// Linux's `c_lflag` bits (asm-generic/termbits.h).
const ICANON: u32 = 0o000002;
const ECHO: u32 = 0o000010;

/// The shipped simulator config on a free port, with a reply timeout a busy machine meets.
fn config(dir: &Path) -> PathBuf {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(shipped).unwrap();
    for (old, new) in [
        ("listen = \"127.0.0.1:7878\"", "listen = \"127.0.0.1:0\""),
        ("reply_timeout_ms = 20 ", "reply_timeout_ms = 100 "),
    ] {
        assert!(text.contains(old), "config/sim.toml has no `{old}`");
        text = text.replace(old, new);
    }
    let path = dir.join("sim.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The UI on a pseudo-terminal: its screen as an emulator shows it, its keyboard.
struct Ui {
    child: Box<dyn Child + Send + Sync>,
    master: Box<dyn MasterPty + Send>,
    writer: Arc<Mutex<Box<dyn Write + Send>>>,
    screen: Arc<Mutex<vt100::Parser>>,
    /// The screen and keyboard mode sequences it wrote (see [`Csi::is_mode`]).
    modes: Arc<Mutex<Vec<Csi>>>,
    reader_done: mpsc::Receiver<()>,
}

impl Ui {
    /// `snakectl teleop ARGS` on a plain VT100.
    fn start(args: &[&std::ffi::OsStr]) -> Ui {
        Ui::start_on(Answers::Vt100, args)
    }

    /// `snakectl teleop ARGS` on a terminal that answers queries as `answers` says.
    fn start_on(answers: Answers, args: &[&std::ffi::OsStr]) -> Ui {
        let pair = native_pty_system()
            .openpty(PtySize {
                rows: ROWS,
                cols: COLS,
                pixel_width: 0,
                pixel_height: 0,
            })
            .unwrap();
        let mut cmd = CommandBuilder::new(env!("CARGO_BIN_EXE_snakectl"));
        cmd.arg("teleop");
        cmd.args(args);
        cmd.cwd(env!("CARGO_MANIFEST_DIR"));
        cmd.env("TERM", "xterm-256color");
        let child = pair.slave.spawn_command(cmd).unwrap();
        // Only the child holds the terminal's side now: its exit ends the reader.
        drop(pair.slave);
        let writer = Arc::new(Mutex::new(pair.master.take_writer().unwrap()));
        let screen = Arc::new(Mutex::new(vt100::Parser::new(ROWS, COLS, 0)));
        let modes = Arc::new(Mutex::new(Vec::new()));
        let (done, reader_done) = mpsc::channel();
        let mut reader = pair.master.try_clone_reader().unwrap();
        {
            let screen = Arc::clone(&screen);
            let writer = Arc::clone(&writer);
            let modes = Arc::clone(&modes);
            std::thread::spawn(move || {
                let mut buf = [0u8; 8192];
                let mut scanner = CsiScanner::default();
                loop {
                    let n = match reader.read(&mut buf) {
                        Ok(0) | Err(_) => break,
                        Ok(n) => n,
                    };
                    // Sequences first: whatever the screen shows, its modes are recorded.
                    scanner.feed(&buf[..n], |csi| {
                        // Answered at once, so the UI need not wait for its query to time out.
                        if let Some(reply) = answers.reply(&csi) {
                            let _ = writer.lock().unwrap().write_all(reply);
                        }
                        let mut modes = modes.lock().unwrap();
                        if csi.is_mode() && modes.len() < MODES_KEPT {
                            modes.push(csi);
                        }
                    });
                    screen.lock().unwrap().process(&buf[..n]);
                }
                let _ = done.send(());
            });
        }
        Ui {
            child,
            master: pair.master,
            writer,
            screen,
            modes,
            reader_done,
        }
    }

    /// The mode changes the UI wrote so far, in order.
    fn modes(&self) -> Vec<Csi> {
        self.modes.lock().unwrap().clone()
    }

    fn send(&self, bytes: &[u8]) {
        let mut writer = self.writer.lock().unwrap();
        writer.write_all(bytes).unwrap();
        writer.flush().unwrap();
    }

    fn contents(&self) -> String {
        self.screen.lock().unwrap().screen().contents()
    }

    /// Polls the screen until `ready` holds; its contents then.
    fn wait_for(&mut self, what: &str, ready: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + DEADLINE;
        loop {
            let text = self.contents();
            if ready(&text) {
                return text;
            }
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!("teleop exited ({status:?}) before {what}:\n{text}");
            }
            assert!(
                Instant::now() < deadline,
                "no {what} within {DEADLINE:?}:\n{text}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Polls until the arm is at rest: holding, and the tip shown unchanged for half a
    /// second; that tip.
    fn wait_rest(&mut self) -> [f64; 2] {
        let deadline = Instant::now() + DEADLINE;
        let mut last = (tip(&self.contents()), Instant::now());
        loop {
            let text = self.contents();
            let now = tip(&text);
            if now != last.0 {
                last = (now, Instant::now());
            } else if field(&text, "state") == Some("holding")
                && last.1.elapsed() >= Duration::from_millis(500)
            {
                if let Some(tip) = now {
                    return tip;
                }
            }
            assert!(
                Instant::now() < deadline,
                "the tip never came to rest:\n{text}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The terminal's local mode flags (`c_lflag`).
    fn local_flags(&self) -> u32 {
        let termios = self.master.get_termios().expect("the pty's termios");
        termios.local_flags.bits()
    }
}

impl Drop for Ui {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// The measured tip the panel shows (`tip  -0.547  +0.720 m`).
fn tip(text: &str) -> Option<[f64; 2]> {
    let line = text
        .lines()
        .find_map(|l| l.split_once("tip  ").map(|(_, r)| r))?;
    let mut numbers = line.split_whitespace().map(|w| w.parse::<f64>());
    let x = numbers.next()?.ok()?;
    let y = numbers.next()?.ok()?;
    Some([x, y])
}

/// A panel row's value (`state     holding` -> `holding`).
fn field<'a>(text: &'a str, label: &str) -> Option<&'a str> {
    text.lines().find_map(|l| {
        let (_, rest) = l.split_once(&format!("│{label} "))?;
        rest.split('│').next().map(str::trim)
    })
}

/// How the terminal on the far side of the pty answers the UI's start-up queries.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Answers {
    /// A plain VT100: device attributes only, the kitty keyboard query ignored.
    Vt100,
    /// A terminal with the kitty keyboard protocol: its flags (none set yet), then its device
    /// attributes.
    Kitty,
}

impl Answers {
    /// What this terminal sends back for `csi`, if anything.
    fn reply(self, csi: &Csi) -> Option<&'static [u8]> {
        match (self, csi.params.as_str(), csi.end) {
            // Primary device attributes.
            (Answers::Vt100, "", 'c') => Some(b"\x1b[?1;2c"),
            (Answers::Kitty, "", 'c') => Some(b"\x1b[?62;c"),
            // The progressive keyboard enhancement flags in effect.
            (Answers::Kitty, "?", 'u') => Some(b"\x1b[?0u"),
            _ => None,
        }
    }
}

/// A control sequence from the UI: `ESC [`, `params` (private marker included), `end`.
#[derive(Debug, Clone, PartialEq)]
struct Csi {
    params: String,
    end: char,
}

/// The kitty keyboard flag that asks for repeat and release events.
const REPORT_EVENT_TYPES: u32 = 0b10;

impl Csi {
    /// The alternate screen switched on or off, or a kitty keyboard sequence.
    fn is_mode(&self) -> bool {
        self.end == 'u' || (self.params == "?1049" && matches!(self.end, 'h' | 'l'))
    }

    /// `ESC [ > flags u`: the flags pushed.
    fn pushed(&self) -> Option<u32> {
        let flags = self.params.strip_prefix('>').filter(|_| self.end == 'u')?;
        if flags.is_empty() {
            return Some(0);
        }
        flags.parse().ok()
    }

    /// `ESC [ < n u`: how many entries are popped.
    fn popped(&self) -> Option<u32> {
        let n = self.params.strip_prefix('<').filter(|_| self.end == 'u')?;
        if n.is_empty() {
            return Some(1);
        }
        n.parse().ok()
    }
}

/// Where [`CsiScanner`] is in the byte stream.
#[derive(Debug, Default)]
enum Scan {
    #[default]
    Text,
    Escape,
    Csi(Vec<u8>),
}

/// Picks control sequences out of the terminal's output, across reads.
#[derive(Debug, Default)]
struct CsiScanner {
    state: Scan,
}

impl CsiScanner {
    /// Feeds `bytes`; `found` gets each sequence they complete.
    fn feed(&mut self, bytes: &[u8], mut found: impl FnMut(Csi)) {
        for &b in bytes {
            self.state = match std::mem::take(&mut self.state) {
                _ if b == 0x1b => Scan::Escape,
                Scan::Escape if b == b'[' => Scan::Csi(Vec::new()),
                // Parameter and intermediate bytes (a runaway one is dropped).
                Scan::Csi(mut params) if (0x20..0x40).contains(&b) && params.len() < 64 => {
                    params.push(b);
                    Scan::Csi(params)
                }
                Scan::Csi(params) if (0x40..0x7f).contains(&b) => {
                    found(Csi {
                        params: String::from_utf8_lossy(&params).into_owned(),
                        end: char::from(b),
                    });
                    Scan::Text
                }
                _ => Scan::Text,
            };
        }
    }
}

/// Asserts the daemon holds with its measured tip where the screen shows it (within 1.5 mm:
/// the screen rounds to a millimetre).
fn assert_daemon_holds_at(client: &mut Client, end: [f64; 2]) {
    let status = client.status().unwrap();
    assert_eq!(status.state, "holding");
    for k in 0..2 {
        assert!(
            (status.tip_meas[k] - end[k]).abs() < 0.0015,
            "screen {end:?}, daemon {:?}",
            status.tip_meas
        );
    }
}

#[test]
fn an_arrow_and_a_click_move_the_tip_and_q_gives_the_terminal_back() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let mut ui = Ui::start(&["--sim".as_ref(), config.as_os_str()]);
    let text = ui.wait_for("the arm at rest, in control", |t| {
        field(t, "state") == Some("holding")
            && field(t, "control") == Some("you")
            && tip(t).is_some()
            && t.chars().any(|c| ('\u{2801}'..='\u{28ff}').contains(&c))
    });
    assert!(text.contains("q quit"), "no key help:\n{text}");
    let addr = field(&text, "daemon").unwrap().to_owned();
    let start = tip(&text).unwrap();
    // Near the shipped home pose's tip.
    assert!(
        (start[0] + 0.547).abs() < 0.01 && (start[1] - 0.720).abs() < 0.01,
        "{start:?}"
    );
    // The UI has the terminal in raw mode; a terminal without the kitty protocol gets no
    // keyboard flags.
    assert_eq!(ui.local_flags() & (ICANON | ECHO), 0, "not in raw mode");
    let modes = ui.modes();
    assert!(
        modes.iter().all(|c| c.pushed().is_none()),
        "keyboard flags pushed to a VT100: {modes:?}"
    );

    // One press of Right: held for 0.6 s at 0.05 m/s, then one zero.
    ui.send(b"\x1b[C");
    ui.wait_for("the tip moving right", |t| {
        tip(t).is_some_and(|p| p[0] > start[0] + 0.005)
    });
    let end = ui.wait_rest();
    let dx = end[0] - start[0];
    assert!(
        (0.01..0.04).contains(&dx),
        "one hold moved the tip {dx} m in x (expected about 0.05 m/s for 0.6 s)"
    );
    assert!((end[1] - start[1]).abs() < 0.005, "{start:?} -> {end:?}");

    // A second witness: the daemon the screen names agrees.
    let mut client = Client::connect(&addr, None).unwrap();
    assert_daemon_holds_at(&mut client, end);

    // A click on the canvas sends the tip to the point under it (an SGR mouse press and
    // release, as a terminal reports them with mouse capture on).
    let arm = client.describe().unwrap();
    let screen = ratatui::layout::Rect::new(0, 0, COLS, ROWS);
    let (col, row) = (30, 12);
    let target = ui::click_to_world(&arm, screen, col, row).unwrap();
    assert!(
        (target[0] - end[0]).hypot(target[1] - end[1]) > 0.1,
        "{target:?} is too close to the tip"
    );
    click_and_arrive(&mut ui, &mut client, (col, row), target);
    drop(client);

    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// Clicks the canvas at `(col, row)` (an SGR mouse press and release, as a terminal reports
/// them with mouse capture on), then waits for the tip at `target`, on the screen and at the
/// daemon.
fn click_and_arrive(ui: &mut Ui, client: &mut Client, (col, row): (u16, u16), target: [f64; 2]) {
    ui.send(
        format!(
            "\x1b[<0;{};{}M\x1b[<0;{};{}m",
            col + 1,
            row + 1,
            col + 1,
            row + 1
        )
        .as_bytes(),
    );
    let text = ui.wait_for("the tip at the clicked point", |t| {
        field(t, "state") == Some("holding")
            && tip(t).is_some_and(|p| (p[0] - target[0]).hypot(p[1] - target[1]) < 0.005)
    });
    let status = client.status().unwrap();
    assert!(
        (status.tip_meas[0] - target[0]).hypot(status.tip_meas[1] - target[1]) < 0.005,
        "clicked {target:?}, the daemon has the tip at {:?}\n{text}",
        status.tip_meas
    );
}

/// Sleeps until `when` (for holding a key that long, not for waiting on a condition).
fn sleep_until(when: Instant) {
    std::thread::sleep(when.saturating_duration_since(Instant::now()));
}

/// The daemon's measured tip.
fn daemon_tip(client: &mut Client) -> [f64; 2] {
    client.status().unwrap().tip_meas
}

#[test]
fn on_a_kitty_terminal_a_held_arrow_moves_the_tip_until_its_release() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let mut ui = Ui::start_on(Answers::Kitty, &["--sim".as_ref(), config.as_os_str()]);
    let text = ui.wait_for("the arm at rest, in control", |t| {
        field(t, "state") == Some("holding")
            && field(t, "control") == Some("you")
            && tip(t).is_some()
    });
    let start = tip(&text).unwrap();
    let mut client = Client::connect(field(&text, "daemon").unwrap(), None).unwrap();

    // Asked for key event types, on the alternate screen (kitty keeps a stack per screen).
    let modes = ui.modes();
    let alternate = modes
        .iter()
        .position(|c| c.params == "?1049" && c.end == 'h')
        .unwrap_or_else(|| panic!("no alternate screen: {modes:?}"));
    let push = modes
        .iter()
        .position(|c| c.pushed().is_some())
        .unwrap_or_else(|| panic!("no keyboard flags pushed: {modes:?}"));
    assert!(
        alternate < push,
        "flags pushed before the alternate screen: {modes:?}"
    );
    let flags = modes[push].pushed().unwrap();
    assert_eq!(
        flags & REPORT_EVENT_TYPES,
        REPORT_EVENT_TYPES,
        "pushed flags {flags:#b} ask for no releases"
    );

    // Right pressed (`CSI 1;1:1 C`) and held for 1.2 s, with no repeats: timing alone would
    // end the hold 0.6 s after the press.
    ui.send(b"\x1b[1;1:1C");
    let pressed = Instant::now();
    ui.wait_for("the tip moving right", |t| {
        tip(t).is_some_and(|p| p[0] > start[0] + 0.002)
    });
    let moving = Instant::now();
    sleep_until(moving + Duration::from_millis(900));
    let late = daemon_tip(&mut client);
    sleep_until(moving + Duration::from_millis(1200));
    let held = daemon_tip(&mut client);
    ui.send(b"\x1b[1;1:3C");
    let released = Instant::now();
    // 0.3 s at 0.05 m/s is 0.015 m; a hold ended by timing would be at rest by then.
    assert!(
        held[0] - late[0] > 0.005,
        "the tip stopped before the release: x {} at 0.9 s, {} at 1.2 s",
        late[0],
        held[0]
    );

    // The release stops it: at rest and holding, after at most a deadman's worth of travel
    // (0.5 s at 0.05 m/s) and the braking (0.0025 m at 0.5 m/s²).
    let end = ui.wait_rest();
    assert!(
        end[0] - held[0] < 0.03,
        "the tip went on {} m after the release",
        end[0] - held[0]
    );
    let dx = end[0] - start[0];
    // One timed hold moves it 0.03 m at most; 1.2 s at 0.05 m/s, less the start's ramp, 0.0575.
    assert!(dx > 0.045, "the hold moved the tip only {dx} m");
    let bound = 0.05 * released.duration_since(pressed).as_secs_f64() + 0.03;
    assert!(dx < bound, "the hold moved the tip {dx} m, over {bound} m");
    assert!((end[1] - start[1]).abs() < 0.005, "{start:?} -> {end:?}");
    assert_daemon_holds_at(&mut client, end);
    drop(client);

    // `q` (a text key: kitty sends it plain) quits, the flags popped before the alternate
    // screen is left.
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
    let modes = ui.modes();
    let pop = modes
        .iter()
        .rposition(|c| c.popped().is_some())
        .unwrap_or_else(|| panic!("the keyboard flags were not popped: {modes:?}"));
    assert!(pop > push, "{modes:?}");
    let pushes = modes.iter().filter(|c| c.pushed().is_some()).count();
    let popped: u32 = modes.iter().filter_map(Csi::popped).sum();
    assert!(
        popped as usize >= pushes,
        "{pushes} pushes, {popped} popped: {modes:?}"
    );
    let leave = modes
        .iter()
        .rposition(|c| c.params == "?1049" && c.end == 'l')
        .unwrap_or_else(|| panic!("the alternate screen was not left: {modes:?}"));
    assert!(
        pop < leave,
        "flags popped after leaving the alternate screen: {modes:?}"
    );
}

impl Ui {
    /// Waits for the process to end with status 0, and checks the terminal is as before.
    fn quits_giving_the_terminal_back(&mut self, after: &str) {
        let status = self.ends_giving_the_terminal_back(after);
        assert!(
            status.success(),
            "teleop exited with {status:?} after {after}"
        );
    }

    /// Waits for the process to end, checks the terminal is as before (main screen, cursor
    /// shown, no mouse capture, canonical mode and echo); its exit status.
    fn ends_giving_the_terminal_back(&mut self, after: &str) -> portable_pty::ExitStatus {
        let deadline = Instant::now() + DEADLINE;
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            assert!(
                Instant::now() < deadline,
                "teleop still runs after {after}:\n{}",
                self.contents()
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        self.reader_done
            .recv_timeout(DEADLINE)
            .expect("the terminal's output ends with the process");
        let parser = self.screen.lock().unwrap();
        assert!(
            !parser.screen().alternate_screen(),
            "still on the alternate screen after {after} ({status:?})"
        );
        assert!(
            !parser.screen().hide_cursor(),
            "the cursor is still hidden after {after}"
        );
        assert_eq!(
            parser.screen().mouse_protocol_mode(),
            vt100::MouseProtocolMode::None,
            "the mouse is still captured after {after}"
        );
        drop(parser);
        let flags = self.local_flags();
        assert_eq!(
            flags & ICANON,
            ICANON,
            "not canonical again after {after}: {flags:o}"
        );
        assert_eq!(flags & ECHO, ECHO, "no echo again after {after}: {flags:o}");
        status
    }
}

/// A simulator and a daemon in this process, on `listen`.
struct LocalDaemon {
    daemon: Embedded,
    _sim: SimHandle,
}

impl LocalDaemon {
    fn start(config: &Path, listen: SocketAddr) -> LocalDaemon {
        let config = Config::load(config).unwrap();
        let sim = connect::spawn_sim(&config, Arc::new(RealClock)).unwrap();
        let options = RunOptions::port(sim.path().to_path_buf());
        let daemon = Embedded::start(config, listen, options).unwrap();
        LocalDaemon { daemon, _sim: sim }
    }
}

#[test]
fn the_ui_outlives_its_daemon_and_takes_control_back_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let first = LocalDaemon::start(&config, SocketAddr::from(([127, 0, 0, 1], 0)));
    let addr = first.daemon.addr();
    let addr_text = addr.to_string();
    let mut ui = Ui::start(&["--connect".as_ref(), addr_text.as_ref()]);
    ui.wait_for("control taken at start", |t| {
        field(t, "control") == Some("you") && field(t, "state") == Some("holding")
    });

    // Another client takes control: the UI names it and says how to take it back.
    let mut other = Client::connect(&addr_text, None).unwrap();
    let fields = other.request(&Cmd::TakeControl).unwrap();
    let other_id = fields.reply.client().unwrap();
    let hint = format!("client {other_id} is in control: press c to take it");
    ui.wait_for("the other client named", |t| {
        field(t, "control") == Some(format!("client {other_id}").as_str()) && t.contains(&hint)
    });
    ui.send(b"c");
    ui.wait_for("control back after c", |t| {
        field(t, "control") == Some("you")
    });
    drop(other);

    // The daemon goes: the UI says so and stays up; a daemon back on the address is found.
    first.daemon.stop().unwrap();
    let gone = format!("daemon at {addr} gone: retrying");
    ui.wait_for("the daemon reported gone", |t| t.contains(&gone));
    let _second = LocalDaemon::start(&config, addr);
    ui.wait_for("the new daemon connected, in control", |t| {
        field(t, "link") == Some("connected")
            && field(t, "control") == Some("you")
            && !t.contains(&gone)
    });

    // Ctrl-C (a key in raw mode) quits as q does.
    ui.send(b"\x03");
    ui.quits_giving_the_terminal_back("Ctrl-C");
}

/// One Linux `js_event`: time (ms), value, type (1 button, 2 axis, | 0x80 initial state),
/// number.
fn js_event(time_ms: u32, value: i16, kind: u8, number: u8) -> [u8; 8] {
    let mut bytes = [0u8; 8];
    bytes[..4].copy_from_slice(&time_ms.to_le_bytes());
    bytes[4..6].copy_from_slice(&value.to_le_bytes());
    bytes[6] = kind;
    bytes[7] = number;
    bytes
}

#[test]
fn the_stick_moves_the_tip_only_while_the_deadman_is_held() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    // A FIFO named like a joystick device stands in for one.
    let device = dir.path().join("js0");
    let made = std::process::Command::new("mkfifo")
        .arg(&device)
        .status()
        .unwrap();
    assert!(made.success(), "mkfifo failed");
    let mut ui = Ui::start(&[
        "--sim".as_ref(),
        config.as_os_str(),
        "--joystick".as_ref(),
        device.as_os_str(),
        "--deadman-button".as_ref(),
        "5".as_ref(),
    ]);
    let mut pad = open_pad(&device);
    let mut write = |events: &[[u8; 8]]| {
        for event in events {
            pad.write_all(event).unwrap();
        }
        pad.flush().unwrap();
    };
    let text = ui.wait_for("the stick connected, the arm at rest, in control", |t| {
        t.contains("connected (js0), deadman 5")
            && field(t, "state") == Some("holding")
            && field(t, "control") == Some("you")
    });
    let start = tip(&text).unwrap();

    // The stick pushed full right, then the deadman pressed: the tip goes right.
    write(&[js_event(100, 32767, 2, 0)]);
    write(&[js_event(900, 1, 1, 5)]);
    ui.wait_for("the tip moving right", |t| {
        tip(t).is_some_and(|p| p[0] > start[0] + 0.01)
    });
    // Released: it stops, though the stick is still pushed.
    write(&[js_event(1500, 0, 1, 5)]);
    let stopped = ui.wait_rest();
    assert!(stopped[0] > start[0] + 0.01, "{start:?} -> {stopped:?}");
    assert!(
        (stopped[1] - start[1]).abs() < 0.01,
        "{start:?} -> {stopped:?}"
    );

    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// A FIFO named like a joystick device in `dir`, standing in for one.
fn fake_pad(dir: &Path) -> PathBuf {
    let device = dir.join("js0");
    let made = std::process::Command::new("mkfifo")
        .arg(&device)
        .status()
        .unwrap();
    assert!(made.success(), "mkfifo failed");
    device
}

/// The writing end of `device`, once the UI has opened it (on a thread, so a reader that never
/// opens fails the test instead of hanging it); the state on open written: buttons up, stick
/// centred.
fn open_pad(device: &Path) -> std::fs::File {
    let (opened, pad) = mpsc::channel();
    {
        let device = device.to_path_buf();
        std::thread::spawn(move || {
            let _ = opened.send(std::fs::OpenOptions::new().write(true).open(device));
        });
    }
    let mut pad = pad
        .recv_timeout(DEADLINE)
        .expect("teleop opens the device")
        .unwrap();
    let mut init: Vec<[u8; 8]> = (0..8).map(|b| js_event(0, 0, 0x81, b)).collect();
    init.extend([js_event(0, 0, 0x82, 0), js_event(0, 0, 0x82, 1)]);
    for event in init {
        pad.write_all(&event).unwrap();
    }
    pad.flush().unwrap();
    pad
}

#[test]
fn q_during_a_stick_motion_stops_the_arm_before_quitting() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    // A daemon that outlives the UI: what the arm does after `q` is the UI's doing.
    let local = LocalDaemon::start(&config, SocketAddr::from(([127, 0, 0, 1], 0)));
    let addr = local.daemon.addr().to_string();
    let device = fake_pad(dir.path());
    let mut ui = Ui::start(&[
        "--connect".as_ref(),
        addr.as_ref(),
        "--joystick".as_ref(),
        device.as_os_str(),
        "--deadman-button".as_ref(),
        "5".as_ref(),
    ]);
    let mut pad = open_pad(&device);
    let text = ui.wait_for("the stick connected, the arm at rest, in control", |t| {
        t.contains("connected (js0), deadman 5")
            && field(t, "state") == Some("holding")
            && field(t, "control") == Some("you")
    });
    let start = tip(&text).unwrap();
    let mut client = Client::connect(&addr, None).unwrap();

    // Full right with the deadman held, and held on through `q`.
    pad.write_all(&js_event(100, 32767, 2, 0)).unwrap();
    pad.write_all(&js_event(200, 1, 1, 5)).unwrap();
    pad.flush().unwrap();
    ui.wait_for("the tip moving right", |t| {
        tip(t).is_some_and(|p| p[0] > start[0] + 0.01)
    });
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
    let at_quit = client.status().unwrap().tip;

    // Stopped at once, the tip goes on by the braking only (0.0025 m from 0.05 m/s at
    // 0.5 m/s²), not for the rest of the deadman (up to 0.025 m).
    let deadline = Instant::now() + DEADLINE;
    let end = loop {
        let status = client.status().unwrap();
        if status.state == "holding" {
            break status.tip;
        }
        assert!(Instant::now() < deadline, "the arm never came to rest");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(
        end[0] - at_quit[0] < 0.006,
        "the tip went on {} m after teleop quit",
        end[0] - at_quit[0]
    );
}

#[test]
fn a_click_during_a_key_hold_sends_the_tip_to_the_point() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let mut ui = Ui::start(&["--sim".as_ref(), config.as_os_str()]);
    let text = ui.wait_for("the arm at rest, in control", |t| {
        field(t, "state") == Some("holding") && field(t, "control") == Some("you")
    });
    let addr = field(&text, "daemon").unwrap().to_owned();
    let mut client = Client::connect(&addr, None).unwrap();
    let arm = client.describe().unwrap();
    let screen = ratatui::layout::Rect::new(0, 0, COLS, ROWS);
    let (col, row) = (30, 12);
    let target = ui::click_to_world(&arm, screen, col, row).unwrap();

    // Right (a hold of 0.6 s on a VT100), then at once a click: the click's `goto` wins.
    ui.send(b"\x1b[C");
    click_and_arrive(&mut ui, &mut client, (col, row), target);
    drop(client);
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// Holds Right on a kitty terminal (a hold that lasts until its release), sends `signal` to
/// teleop mid-motion, and checks it gives the terminal back, exits with 128 plus the signal's
/// number, and has stopped the arm as `q` does: the tip goes on by the braking only, not for
/// the rest of the daemon's deadman.
fn a_signal_stops_the_arm_and_gives_the_terminal_back(signal: rustix::process::Signal) {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    // A daemon that outlives the UI: what the arm does after the signal is the UI's doing.
    let local = LocalDaemon::start(&config, SocketAddr::from(([127, 0, 0, 1], 0)));
    let addr = local.daemon.addr().to_string();
    let mut ui = Ui::start_on(Answers::Kitty, &["--connect".as_ref(), addr.as_ref()]);
    let text = ui.wait_for("the arm at rest, in control", |t| {
        field(t, "state") == Some("holding") && field(t, "control") == Some("you")
    });
    let start = tip(&text).unwrap();
    let mut client = Client::connect(&addr, None).unwrap();
    ui.send(b"\x1b[1;1:1C");
    ui.wait_for("the tip moving right", |t| {
        tip(t).is_some_and(|p| p[0] > start[0] + 0.005)
    });

    let pid = ui.child.process_id().unwrap();
    let pid = rustix::process::Pid::from_raw(i32::try_from(pid).unwrap()).unwrap();
    rustix::process::kill_process(pid, signal).unwrap();
    let name = format!("{signal:?}");
    let status = ui.ends_giving_the_terminal_back(&name);
    let expected = 128 + u32::try_from(signal.as_raw()).unwrap();
    assert_eq!(
        status.exit_code(),
        expected,
        "teleop ended with {status:?} on {name}"
    );
    let modes = ui.modes();
    let pushes = modes.iter().filter(|c| c.pushed().is_some()).count();
    let popped: u32 = modes.iter().filter_map(Csi::popped).sum();
    assert!(
        pushes > 0 && popped as usize >= pushes,
        "{pushes} pushes, {popped} popped: {modes:?}"
    );

    // Stopped at once, the tip goes on by the braking only (0.0025 m from 0.05 m/s at
    // 0.5 m/s²), not for the rest of the deadman (up to 0.025 m).
    let at_exit = client.status().unwrap().tip;
    let deadline = Instant::now() + DEADLINE;
    let end = loop {
        let status = client.status().unwrap();
        if status.state == "holding" {
            break status.tip;
        }
        assert!(Instant::now() < deadline, "the arm never came to rest");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(
        end[0] - at_exit[0] < 0.006,
        "the tip went on {} m after teleop ended on {name}",
        end[0] - at_exit[0]
    );
}

#[test]
fn sigterm_stops_the_arm_and_gives_the_terminal_back() {
    a_signal_stops_the_arm_and_gives_the_terminal_back(rustix::process::Signal::TERM);
}

#[test]
fn sighup_stops_the_arm_and_gives_the_terminal_back() {
    a_signal_stops_the_arm_and_gives_the_terminal_back(rustix::process::Signal::HUP);
}

/// A paste drives nothing (it comes as one event, said on screen), and a flood of keys from a
/// terminal that does not mark pastes is read through to its end: the estop typed after it is
/// carried out.
#[test]
fn a_paste_moves_nothing_and_keys_after_a_flood_still_count() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let mut ui = Ui::start(&["--sim".as_ref(), config.as_os_str()]);
    let text = ui.wait_for("the arm at rest, in control", |t| {
        field(t, "state") == Some("holding") && field(t, "control") == Some("you")
    });
    let start = tip(&text).unwrap();
    // A marked paste of motion keys.
    ui.send(b"\x1b[200~dddddddd\x1b[201~");
    ui.wait_for("the paste's notice", |t| {
        t.contains("a paste of 8 characters ignored")
    });
    std::thread::sleep(Duration::from_millis(300));
    let tip_now = tip(&ui.contents()).unwrap();
    assert!(
        (tip_now[0] - start[0]).abs() < 1e-3,
        "a paste moved the tip: {start:?} -> {tip_now:?}"
    );
    // 3000 unmarked bytes (each a key that stops), then `e`.
    ui.send(&[b'x'; 3000]);
    ui.send(b"e");
    ui.wait_for("the estop after the flood", |t| {
        field(t, "state") == Some("estop")
    });
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// A terminal closed under teleop ends it as a SIGHUP does, even where none comes (teleop here
/// is not in the terminal's session): exit status 129, the daemon it started stopped, within
/// moments rather than spinning on a terminal that reads nothing.
#[test]
fn a_terminal_closed_under_it_ends_teleop_without_a_signal() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let (master, _, slave) = open_pty();
    let mut child = teleop_on(&config, &slave, std::process::Stdio::piped());
    // The terminal is the child's alone: closing the master closes it.
    drop(slave);
    let child = &mut child.0;
    let mut master = std::fs::File::from(master);
    let text = read_until_in_control(&mut master, child);
    let addr = field(&text, "daemon").unwrap().to_owned();
    drop(master);
    let status = exit_within_deadline(child, "after its terminal closed");
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert_eq!(status.code(), Some(129), "{status:?}: {err}");
    assert!(err.contains("the terminal hung up"), "{err}");
    // The daemon teleop started has stopped with it.
    assert!(
        TcpStream::connect(&addr).is_err(),
        "the daemon at {addr} still listens"
    );
}

/// A pseudo-terminal of [`ROWS`] by [`COLS`], made no process's controlling terminal: its
/// master (non-blocking, close-on-exec: a master left open in teleop would keep its own
/// terminal from hanging up), its slave's path, and the slave opened.
fn open_pty() -> (rustix::fd::OwnedFd, PathBuf, std::fs::File) {
    use rustix::pty::{grantpt, openpt, ptsname, unlockpt, OpenptFlags};
    let master = openpt(OpenptFlags::RDWR | OpenptFlags::NOCTTY | OpenptFlags::CLOEXEC).unwrap();
    grantpt(&master).unwrap();
    unlockpt(&master).unwrap();
    let name = ptsname(&master, Vec::new()).unwrap();
    let size = rustix::termios::Winsize {
        ws_row: ROWS,
        ws_col: COLS,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    rustix::termios::tcsetwinsize(&master, size).unwrap();
    let path = PathBuf::from(
        <std::ffi::OsStr as std::os::unix::ffi::OsStrExt>::from_bytes(name.to_bytes()),
    );
    let slave = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&path)
        .unwrap();
    let flags = rustix::fs::fcntl_getfl(&master).unwrap();
    rustix::fs::fcntl_setfl(&master, flags | rustix::fs::OFlags::NONBLOCK).unwrap();
    (master, path, slave)
}

/// Reads teleop's screen from `master` up to the arm at rest under its control (answering the
/// terminal query a VT100 answers); the screen's text then.
fn read_until_in_control(master: &mut std::fs::File, child: &mut std::process::Child) -> String {
    let mut screen = vt100::Parser::new(ROWS, COLS, 0);
    let deadline = Instant::now() + DEADLINE;
    loop {
        let text = screen.screen().contents();
        if field(&text, "state") == Some("holding") && field(&text, "control") == Some("you") {
            return text;
        }
        let mut buf = [0u8; 8192];
        match master.read(&mut buf) {
            Ok(n) => {
                if contains(&buf[..n], b"\x1b[c") {
                    master.write_all(b"\x1b[?62;22c").unwrap();
                }
                screen.process(&buf[..n]);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(10));
            }
            Err(e) => panic!("reading the terminal: {e}"),
        }
        if let Some(status) = child.try_wait().unwrap() {
            panic!("teleop exited ({status:?}) before the arm showed");
        }
        assert!(Instant::now() < deadline, "the arm never showed:\n{text}");
    }
}

/// A terminal that takes no more output (the program on its other side stopped reading it)
/// blocks teleop's writes to it. The first SIGTERM ends teleop all the same, with status 143,
/// raw mode given back, though the terminal takes none of the escape sequences nor the last
/// line: teleop waits for them only so long.
#[test]
fn the_first_sigterm_ends_teleop_while_its_terminal_takes_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let (master, path, slave) = open_pty();
    let mut child = teleop_on(&config, &slave, slave.try_clone().unwrap().into());
    let child = &mut child.0;
    let mut master = std::fs::File::from(master);
    read_until_in_control(&mut master, child);

    // The master is read no more: the terminal's buffers fill until a write to it blocks.
    // The test fills them itself, through a description of the slave of its own that does not
    // block, up to where it takes nothing more: until, a moment after it was full (the kernel
    // moves what the terminal holds between its buffers on its own time), not a byte more
    // goes in.
    let filler = std::fs::OpenOptions::new()
        .write(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(&path)
        .unwrap();
    let mut filled = 0usize;
    loop {
        let before = filled;
        loop {
            match (&filler).write(&[b'.'; 4096]) {
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                Err(e) => panic!("filling the terminal: {e}"),
            }
            assert!(
                filled < 64 << 20,
                "the terminal took {filled} bytes and more"
            );
        }
        if filled == before {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // A key that changes the screen (the speed shown), should the telemetry not: teleop draws
    // a frame (within 33 ms), which the terminal cannot take. The pause only lets the frame
    // begin, so that the signal finds the write under way; were it to come first, teleop would
    // still have to give the terminal back through that full buffer.
    master.write_all(b"+").unwrap();
    std::thread::sleep(Duration::from_millis(300));

    let pid = rustix::process::Pid::from_raw(i32::try_from(child.id()).unwrap()).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    let status = exit_within_deadline(child, "after one SIGTERM, its terminal taking no output");
    assert_eq!(status.code(), Some(143), "{status:?}");
    let local = rustix::termios::tcgetattr(&master).unwrap().local_modes;
    assert!(
        local.contains(rustix::termios::LocalModes::ICANON | rustix::termios::LocalModes::ECHO),
        "raw mode not left: {local:?}"
    );
}

/// A child process killed if the test fails before it ends.
/// `snakectl teleop --sim CONFIG` with the terminal `slave` as its input and output, its
/// standard error as given.
fn teleop_on(config: &Path, slave: &std::fs::File, stderr: std::process::Stdio) -> Reaped {
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["teleop", "--sim"])
        .arg(config)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("TERM", "xterm-256color")
        .stdin(slave.try_clone().unwrap())
        .stdout(slave.try_clone().unwrap())
        .stderr(stderr)
        .spawn()
        .unwrap();
    Reaped(child)
}

struct Reaped(std::process::Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

/// A daemon played by the test: it answers every request at once (`describe` with a 12-link
/// arm, an empty `world`, control granted, any other with an ok) and sends telemetry only when
/// the test says, so the test decides when it falls silent.
struct FakeDaemon {
    addr: String,
    accepted: mpsc::Receiver<FakeLink>,
}

/// One connection to a [`FakeDaemon`]: the requests it got, in order, and its sending side.
struct FakeLink {
    out: Arc<Mutex<TcpStream>>,
    requests: mpsc::Receiver<Cmd>,
    arm: ArmInfo,
}

/// The arm the fake daemon describes: 12 links of 0.08 m, as the shipped simulator's.
fn fake_arm() -> Describe {
    Describe {
        links_m: vec![0.08; 12],
        base: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        min_rad: vec![-2.0; 12],
        max_rad: vec![2.0; 12],
        ids: (1..=12).collect(),
        models: vec!["XL430-W250".into(); 12],
        home_rad: vec![0.1; 12],
        rate_hz: 100.0,
        strategies: protocol::STRATEGIES.to_vec(),
        protocol_version: protocol::PROTOCOL_VERSION,
        ..Describe::default()
    }
}

impl FakeDaemon {
    fn start() -> FakeDaemon {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let (tx, accepted) = mpsc::channel();
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                let Ok(stream) = stream else { return };
                let out = Arc::new(Mutex::new(stream.try_clone().unwrap()));
                let (requests_tx, requests) = mpsc::channel();
                {
                    let out = Arc::clone(&out);
                    std::thread::spawn(move || serve_fake(stream, &out, &requests_tx));
                }
                let link = FakeLink {
                    out,
                    requests,
                    arm: ArmInfo::new(fake_arm()).unwrap(),
                };
                if tx.send(link).is_err() {
                    return;
                }
            }
        });
        FakeDaemon { addr, accepted }
    }

    /// The next connection teleop makes.
    fn accept(&self) -> FakeLink {
        self.accepted
            .recv_timeout(DEADLINE)
            .expect("teleop connects to the daemon")
    }
}

/// Answers each request line on `stream` and hands the request on, until the connection ends.
fn serve_fake(stream: TcpStream, out: &Mutex<TcpStream>, requests: &mpsc::Sender<Cmd>) {
    for line in BufReader::new(stream).lines() {
        let Ok(line) = line else { return };
        let request = protocol::parse(line.as_bytes(), 12).unwrap();
        let reply = match &request.cmd {
            Cmd::Describe => Reply::Describe(Arc::new(fake_arm())),
            Cmd::World => Reply::World(Box::new(WorldInfo::of(&World::default()))),
            Cmd::Subscribe { rate_hz } => Reply::Subscribed(Subscribed { rate_hz: *rate_hz }),
            Cmd::TakeControl => Reply::TookControl(TookControl {
                client: 1,
                holder: Some(1),
                previous: None,
            }),
            _ => Reply::Applied(Applied { tick: 1 }),
        };
        let line = protocol::ok_line(request.id.as_deref(), &Fields::from(reply));
        if out.lock().unwrap().write_all(line.as_bytes()).is_err() {
            return;
        }
        let _ = requests.send(request.cmd);
    }
}

impl FakeLink {
    /// Waits for a request `wanted` picks; the ones before it.
    fn wait_request(&self, what: &str, wanted: impl Fn(&Cmd) -> bool) -> Vec<Cmd> {
        let mut before = Vec::new();
        loop {
            let cmd = self
                .requests
                .recv_timeout(DEADLINE)
                .unwrap_or_else(|_| panic!("no {what} from teleop; before it: {before:?}"));
            if wanted(&cmd) {
                return before;
            }
            before.push(cmd);
        }
    }

    /// One telemetry line: the arm holding at home, `controller` in control (this client, by
    /// `in_control`).
    fn telemetry(&self, controller: Option<u64>, in_control: bool) {
        let theta = fake_arm().home_rad;
        let tip = *self.arm.points(&theta).last().unwrap();
        let status = Status {
            telemetry: Telemetry {
                state: State::Holding,
                tip,
                tip_meas: tip,
                tip_ref: tip,
                theta_cmd: theta.clone(),
                theta_meas: theta,
                loop_hz: 100.0,
                torque: true,
                ..Telemetry::default()
            },
            controller,
            in_control,
        };
        let line = protocol::telemetry_line(&status);
        self.out.lock().unwrap().write_all(line.as_bytes()).unwrap();
    }

    /// Closes the connection, as a daemon that stops does.
    fn close(&self) {
        let _ = self.out.lock().unwrap().shutdown(Shutdown::Both);
    }
}

#[test]
fn a_daemon_fallen_silent_shows_so_until_its_telemetry_comes_again() {
    let daemon = FakeDaemon::start();
    let mut ui = Ui::start(&["--connect".as_ref(), daemon.addr.as_ref()]);
    let link = daemon.accept();
    link.wait_request("subscribe", |c| matches!(c, Cmd::Subscribe { .. }));
    link.telemetry(Some(1), true);
    ui.wait_for("connected, the arm holding, in control", |t| {
        field(t, "link") == Some("connected")
            && field(t, "state") == Some("holding")
            && field(t, "control") == Some("you")
    });

    // The connection stays open, and nothing comes on it: silent from a second on, the last
    // pose still shown.
    let text = ui.wait_for("the link silent", |t| {
        field(t, "link").is_some_and(|l| l.starts_with("no telemetry for "))
    });
    assert!(tip(&text).is_some(), "the last pose is gone:\n{text}");

    // Telemetry again: connected.
    link.telemetry(Some(1), true);
    ui.wait_for("connected again", |t| field(t, "link") == Some("connected"));
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

#[test]
fn after_a_reconnection_no_control_is_claimed_before_the_daemon_grants_it() {
    let daemon = FakeDaemon::start();
    let mut ui = Ui::start(&["--connect".as_ref(), daemon.addr.as_ref()]);
    let first = daemon.accept();
    first.wait_request("subscribe", |c| matches!(c, Cmd::Subscribe { .. }));
    first.telemetry(Some(1), true);
    ui.wait_for("in control", |t| field(t, "control") == Some("you"));

    // The daemon goes and one comes back on the address, which sends no telemetry yet.
    first.close();
    let second = daemon.accept();
    second.wait_request("subscribe", |c| matches!(c, Cmd::Subscribe { .. }));
    let text = ui.wait_for("connected again", |t| {
        field(t, "link").is_some_and(|l| l != "gone: retrying") && !t.contains("gone: retrying")
    });
    assert_ne!(
        field(&text, "control"),
        Some("you"),
        "control claimed before the new daemon said so:\n{text}"
    );
    assert!(text.contains("waiting for telemetry"), "{text}");
    // An arrow moves nothing without control; Space (a stop, sent with or without control)
    // comes after it, so anything the arrow sent comes before the stop.
    ui.send(b"\x1b[C ");
    let before = second.wait_request("stop", |c| *c == Cmd::Stop);
    assert!(
        !before.iter().any(|c| matches!(c, Cmd::Velocity { .. })),
        "an arrow sent a velocity without control: {before:?}"
    );

    // The new daemon's telemetry names another client in control: so the screen says.
    second.telemetry(Some(7), false);
    ui.wait_for("the other client named", |t| {
        field(t, "control") == Some("client 7")
    });
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// A right-click on the arm's canvas sends a `reach` to the point under it (a way round the
/// obstacles, planned by the daemon), and a `blocked` event tells of that way out.
#[test]
fn a_right_click_reaches_for_the_point_and_a_blocked_goto_says_so() {
    let daemon = FakeDaemon::start();
    let mut ui = Ui::start(&["--connect".as_ref(), daemon.addr.as_ref()]);
    let link = daemon.accept();
    link.wait_request("subscribe", |c| matches!(c, Cmd::Subscribe { .. }));
    link.telemetry(Some(1), true);
    ui.wait_for("in control", |t| field(t, "control") == Some("you"));

    let event = protocol::Event {
        owner: None,
        cmd_id: None,
        tick: 2,
        what: protocol::What::Blocked {
            tip: [-0.5, 0.6],
            link: 9,
            obstacle: "post".into(),
        },
    };
    let line = protocol::event_line(&event);
    link.out.lock().unwrap().write_all(line.as_bytes()).unwrap();
    ui.wait_for("the blocked notice", |t| {
        t.contains("blocked: link 9 against \"post\"") && t.contains("right-click")
    });

    let screen = ratatui::layout::Rect::new(0, 0, COLS, ROWS);
    let (col, row) = (30, 12);
    let target = ui::click_to_world(&link.arm, screen, col, row).unwrap();
    // An SGR report of the right button (2) pressed and released.
    ui.send(format!("\x1b[<2;{0};{1}M\x1b[<2;{0};{1}m", col + 1, row + 1).as_bytes());
    let before = link.wait_request("reach", |c| {
        matches!(c, Cmd::Reach { target: t }
            if (t[0] - target[0]).abs() < 1e-9 && (t[1] - target[1]).abs() < 1e-9)
    });
    assert!(
        !before.iter().any(|c| matches!(c, Cmd::Goto { .. })),
        "a right-click sent a goto: {before:?}"
    );
    ui.send(b"q");
    ui.quits_giving_the_terminal_back("q");
}

/// Waits for `child` to exit, at most [`DEADLINE`]; `what` says what should have ended it.
fn exit_within_deadline(child: &mut std::process::Child, what: &str) -> std::process::ExitStatus {
    let from = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        assert!(
            from.elapsed() < DEADLINE,
            "teleop still runs {DEADLINE:?} {what}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}
