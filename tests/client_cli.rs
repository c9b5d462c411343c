//! The one-shot client commands (`status`, `describe`, `goto`, `reach`, `path`, `home`, `stop`,
//! `estop`, `reset`, `reboot`, `strategy`, `watch`) as a user runs them: the built binary against a
//! daemon on simulated servos started in this process. Exit codes, what is printed, and what
//! the daemon did afterwards.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use daemon_support::{dist, sim_config, sim_config_with, xy, Daemon, DEADLINE};
use serde_json::{json, Value};

/// Where the shipped simulator's tip rests at home, m.
const HOME_TIP: [f64; 2] = [-0.547, 0.720];

/// The tests of this file run one at a time: each has its own daemon and simulator, and a
/// loaded machine keeps their loops on time better one by one.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// A finished `snakectl` run.
struct Run {
    code: i32,
    stdout: String,
    stderr: String,
}

/// `snakectl ARGS` started from the repository root, stdout and stderr piped.
fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits up to [`DEADLINE`] for `child` to end (killing it past that) and collects its output
/// (stdout: what is left of it, if the test has not taken it).
fn finish(mut child: Child) -> Run {
    let out = child.stdout.take();
    let mut err = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(mut out) = out {
            out.read_to_string(&mut s).unwrap();
        }
        s
    });
    let err = std::thread::spawn(move || {
        let mut s = String::new();
        err.read_to_string(&mut s).unwrap();
        s
    });
    let deadline = Instant::now() + DEADLINE;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("snakectl still ran after {DEADLINE:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    Run {
        code: status.code().expect("exited, not killed by a signal"),
        stdout: out.join().unwrap(),
        stderr: err.join().unwrap(),
    }
}

/// Runs `snakectl ARGS` to its end.
fn snakectl(args: &[&str]) -> Run {
    finish(spawn(args))
}

/// Runs `snakectl ARGS --connect ADDR` to its end.
fn at(d: &Daemon, args: &[&str]) -> Run {
    let addr = d.addr.to_string();
    let mut all = args.to_vec();
    all.extend(["--connect", &addr]);
    snakectl(&all)
}

/// An address where nothing listens (bound, then let go).
fn closed_port() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().to_string()
}

/// Asserts the run ended with `code` and `needle` in its stderr.
fn assert_fails(run: &Run, code: i32, needle: &str) {
    assert_eq!(
        run.code, code,
        "exit code; stdout {:?} stderr {:?}",
        run.stdout, run.stderr
    );
    assert!(
        run.stderr.contains(needle),
        "stderr lacks {needle:?}: {:?}",
        run.stderr
    );
}

/// The one JSON object a run printed.
fn object(run: &Run) -> Value {
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert_eq!(run.stdout.lines().count(), 1, "one line: {:?}", run.stdout);
    let v: Value = serde_json::from_str(&run.stdout).unwrap();
    assert!(v.is_object(), "{v}");
    v
}

/// Waits until the daemon reports an active command of `kind`.
fn wait_active(d: &Daemon, kind: &str) {
    let mut c = d.client();
    c.wait_status(&format!("{kind} active"), |s| {
        s["command"]["kind"] == kind && s["command"]["outcome"] == "active"
    });
}

/// A temporary file holding `text`; removed with the returned directory.
fn file_with(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("path.csv");
    std::fs::write(&path, text).unwrap();
    (dir, path)
}

fn text(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Asserts `run` succeeded with the `ok: NAME at tick N` line.
fn assert_ok(run: &Run, name: &str) {
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    let expected = format!("ok: {name} at tick ");
    assert!(run.stdout.starts_with(&expected), "{:?}", run.stdout);
}

/// Starts a waiting `goto` of 7.7 cm at 2 cm/s (still moving seconds later) and returns once
/// the daemon runs it.
fn slow_goto(d: &Daemon, addr: &str) -> Child {
    let child = spawn(&[
        "goto",
        "-0.50",
        "0.66",
        "--speed",
        "0.02",
        "--connect",
        addr,
    ]);
    wait_active(d, "goto");
    child
}

#[test]
fn status_and_describe_print_one_json_object_each() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let status = object(&at(&d, &["status"]));
    assert_eq!(status["state"], "holding", "{status}");
    assert_eq!(
        status["theta_cmd"].as_array().unwrap().len(),
        12,
        "{status}"
    );
    assert!(status.get("ok").is_none() && status.get("id").is_none());
    let tip = xy(&status["tip"]);
    assert!(dist(tip, HOME_TIP) < 2e-3, "home tip {tip:?}");

    let describe = object(&at(&d, &["describe"]));
    assert_eq!(describe["links_m"].as_array().unwrap().len(), 12);
    assert_eq!(describe["strategies"], json!(["overall", "sequential"]));
}

#[test]
fn goto_with_negative_numbers_arrives_and_home_returns() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let run = at(&d, &["goto", "-0.53", "0.70", "--speed", "0.1"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(run.stdout.starts_with("arrived at ("), "{:?}", run.stdout);
    let tip = xy(&d.client().status()["tip"]);
    assert!(dist(tip, [-0.53, 0.70]) < 1e-3, "tip {tip:?}");

    let run = at(&d, &["home"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(run.stdout.starts_with("arrived at ("), "{:?}", run.stdout);
    let tip = xy(&d.client().status()["tip"]);
    assert!(dist(tip, HOME_TIP) < 2e-3, "tip {tip:?}");
}

#[test]
fn reach_arrives_and_says_where() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let run = at(&d, &["reach", "-0.45", "0.62"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(run.stdout.starts_with("arrived at ("), "{:?}", run.stdout);
    let tip = xy(&d.client().status()["tip"]);
    assert!(dist(tip, [-0.45, 0.62]) < 1e-6, "tip {tip:?}");
    let addr = closed_port();
    let run = snakectl(&["reach", "-0.5", "inf", "--connect", &addr]);
    assert_fails(&run, 2, "finite");
}

/// A `goto` whose body is caught between two discs fails `blocked`, saying which `reach` to
/// send; that `reach` gets there.
#[test]
fn a_caught_goto_says_which_reach_gets_round_and_it_does() {
    let _one = one_at_a_time();
    let radius = "max_clients = 4\n\n[world]\nlink_radius_m = 0.01";
    let d = Daemon::start(sim_config(&[("max_clients = 4", radius)]));
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("discs.json");
    let discs = json!({"obstacles": [
        {"id": "upper", "circle": {"center": [-0.3001, 0.7139], "radius": 0.0127}},
        {"id": "lower", "circle": {"center": [-0.5183, 0.5435], "radius": 0.0148}},
    ]});
    std::fs::write(&file, discs.to_string()).unwrap();
    let run = at(&d, &["world", "set", file.to_str().unwrap()]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);

    let run = at(&d, &["goto", "-0.6656", "0.4673"]);
    assert_fails(&run, 1, "blocked: link");
    assert!(
        run.stderr
            .contains("`snakectl reach -0.6656 0.4673` plans a way round the obstacles"),
        "{:?}",
        run.stderr
    );
    assert_eq!(run.stderr.trim_end().lines().count(), 1, "{:?}", run.stderr);
    let run = at(&d, &["reach", "-0.6656", "0.4673"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(run.stdout.starts_with("arrived at ("), "{:?}", run.stdout);
    let tip = xy(&d.client().status()["tip"]);
    assert!(dist(tip, [-0.6656, 0.4673]) < 1e-6, "tip {tip:?}");
}

/// `world add` of an obstacle onto the arm is done (exit 0) and says on stderr that the arm is
/// not clear of it, naming the link; one off the arm says nothing more.
#[test]
fn world_add_onto_the_arm_notes_the_link_it_is_on() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let run = at(
        &d,
        &["world", "add", "far", "--circle", "2.0", "2.0", "0.05"],
    );
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert_eq!(run.stderr, "", "{:?}", run.stderr);
    let tip = xy(&d.client().status()["tip"]);
    let (x, y) = (tip[0].to_string(), tip[1].to_string());
    let run = at(&d, &["world", "add", "onto", "--circle", &x, &y, "0.01"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(
        run.stdout.starts_with("ok: added obstacle"),
        "{:?}",
        run.stdout
    );
    assert!(
        run.stderr
            .contains("not clear of the new world: link 12 is inside obstacle \"onto\""),
        "{:?}",
        run.stderr
    );
}

#[test]
fn goto_no_wait_returns_while_the_arm_moves() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let run = at(
        &d,
        &["goto", "-0.50", "0.66", "--speed", "0.02", "--no-wait"],
    );
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(
        run.stdout.starts_with("ok: goto accepted at tick "),
        "{:?}",
        run.stdout
    );
    // The move goes on after the client left: 7.7 cm at 2 cm/s.
    let s = d.client().status();
    assert_eq!(s["command"]["kind"], "goto", "{s}");
    assert_eq!(s["command"]["outcome"], "active", "{s}");
}

#[test]
fn goto_out_of_reach_fails_saying_saturated() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    // 1.14 m from the base; the arm reaches 0.96 m.
    let run = at(&d, &["goto", "-0.7", "0.9", "--speed", "0.1"]);
    assert_fails(&run, 1, "saturated");
    assert_eq!(run.stdout, "");
}

#[test]
fn a_goto_held_by_a_joint_limit_is_not_called_out_of_reach() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[(
        "strategy = \"overall\"",
        "strategy = \"sequential\"",
    )]));
    // 0.78 m from the base, well inside the 0.96 m the arm reaches; the sequential tractrix
    // swinging the tip this way from home folds the last joint onto its limit, 2 rad.
    let run = at(&d, &["goto", "0.2", "0.75"]);
    assert_fails(&run, 1, "saturated");
    assert!(
        run.stderr.contains("a joint at its limit"),
        "{:?}",
        run.stderr
    );
    assert!(
        !run.stderr.contains("the target is out of reach;"),
        "{:?}",
        run.stderr
    );
    let s = d.client().status();
    let last = s["theta_cmd"][11].as_f64().unwrap();
    assert!((last - 2.0).abs() < 0.01, "joint 12 at {last} rad: {s}");
}

#[test]
fn bad_goto_numbers_are_refused_before_connecting() {
    let addr = closed_port();
    let run = snakectl(&["goto", "nan", "0.7", "--connect", &addr]);
    assert_fails(&run, 2, "finite");
    let run = snakectl(&["goto", "-0.5", "0.7", "--speed", "-1", "--connect", &addr]);
    assert_fails(&run, 2, "--speed");
}

/// A `--connect` that is no address (a socket path, a host without its port) is bad input,
/// exit 2, saying what the flag takes.
#[test]
fn a_connect_that_is_no_address_exits_2_saying_host_port() {
    for addr in ["/tmp/snakectl.sock", "127.0.0.1", "127.0.0.1:99999", ""] {
        let run = snakectl(&["status", "--connect", addr]);
        assert_fails(&run, 2, "give host:port");
    }
}

#[test]
fn goto_while_another_client_holds_control_is_refused_naming_it() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut holder = d.client();
    let taken = holder.ok(json!({"cmd": "take_control"}));
    let id = taken["client"].as_u64().unwrap();
    let run = at(&d, &["goto", "-0.55", "0.70"]);
    assert_fails(&run, 1, "not_in_control");
    assert!(
        run.stderr.contains(&format!("client {id}")),
        "{:?}",
        run.stderr
    );
    // Not taken over: the holder still holds it, and the arm did not move.
    let s = holder.status();
    assert_eq!(s["controller"], json!(id), "{s}");
    assert_eq!(s["command"], Value::Null, "{s}");
}

#[test]
fn a_waiting_goto_interrupted_by_an_estop_fails_saying_estop() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();
    let child = slow_goto(&d, &addr);
    let run = at(&d, &["estop"]);
    assert_ok(&run, "estop");
    let run = finish(child);
    assert_fails(&run, 1, "estop");

    // Latched: a new goto is refused with the daemon's code until `reset`.
    assert_fails(&at(&d, &["goto", "-0.55", "0.70"]), 1, "estopped");
    let run = at(&d, &["reset"]);
    assert_ok(&run, "reset");
}

/// A servo's hardware error holds the arm through `reset` (a note says so, and what clears
/// it); `snakectl reboot` clears it, naming the servo, and the arm moves again.
#[test]
fn reset_tells_of_a_hardware_error_and_reboot_clears_it() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config_with(
        &[],
        "[[sim.fault]]\nkind = \"hardware_error\"\nid = 9\nat_s = 0.5\nerror = \"overload\"\n",
    ));
    let mut c = d.client();
    let deadline = Instant::now() + DEADLINE;
    while c.status()["state"] != "fault" {
        assert!(Instant::now() < deadline, "no hardware error raised");
        std::thread::sleep(Duration::from_millis(20));
    }
    let run = at(&d, &["reset"]);
    assert_ok(&run, "reset");
    assert!(
        run.stderr.contains(
            "a hardware error still holds the arm (servo 9); `snakectl reboot` clears it"
        ),
        "{:?}",
        run.stderr
    );
    let run = at(&d, &["reboot"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(
        run.stdout.starts_with("ok: rebooted [9] at tick "),
        "{:?}",
        run.stdout
    );
    assert_eq!(c.status()["state"], "holding");
    let run = at(&d, &["reset"]);
    assert_ok(&run, "reset");
    assert!(run.stderr.is_empty(), "{:?}", run.stderr);
    let run = at(&d, &["goto", "-0.55", "0.70"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
}

#[test]
fn a_waiting_goto_replaced_by_a_stop_fails_saying_why() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();
    let child = slow_goto(&d, &addr);
    let run = at(&d, &["stop"]);
    assert_ok(&run, "stop");
    assert_fails(&finish(child), 1, "preempted by `stop`");
}

#[test]
fn path_from_a_csv_with_a_header_and_blank_lines_arrives() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let (_dir, file) = file_with("x,y\n-0.54,0.71\n\n  -0.53 , 0.70\n\n");
    let run = at(&d, &["path", text(&file), "--speed", "0.1"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(run.stdout.starts_with("arrived at ("), "{:?}", run.stdout);
    let tip = xy(&d.client().status()["tip"]);
    assert!(dist(tip, [-0.53, 0.70]) < 1e-3, "tip {tip:?}");
}

/// The longest path a daemon takes, every coordinate written at full precision (far over the
/// 64 KiB a request line once was), goes through as one request: the daemon holds it, its
/// last point the target.
#[test]
fn a_path_of_the_most_points_at_full_precision_is_accepted() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let n = snakectl::protocol::MAX_PATH_POINTS;
    let mut csv = String::from("x,y\n");
    let mut last = [0.0; 2];
    for i in 0..n {
        // A millimetre circle around the home tip, at 17 significant digits.
        let a = i as f64 * 0.618_033_988_749_894_9;
        last = [HOME_TIP[0] + 1e-3 * a.cos(), HOME_TIP[1] + 1e-3 * a.sin()];
        csv.push_str(&format!("{:?},{:?}\n", last[0], last[1]));
    }
    assert!(csv.len() > 2 * 64 * 1024, "{} bytes", csv.len());
    let (_dir, file) = file_with(&csv);
    let run = at(&d, &["path", text(&file), "--no-wait"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(
        run.stdout.starts_with("ok: path accepted at tick "),
        "{:?}",
        run.stdout
    );
    let status = d.client().status();
    assert_eq!(status["target"], json!(last), "{status}");
    assert_ok(&at(&d, &["stop"]), "stop");
}

#[test]
fn bad_csv_files_exit_2_naming_the_line() {
    // Checked before connecting: nothing listens at this address.
    let addr = closed_port();
    let cases = [
        (
            "x,y\n-0.5,0.7\n\n-0.5\n",
            ":4: expected two fields `x,y`, got 1",
        ),
        (
            "-0.5,0.7\n-0.5,0.7,0.1\n",
            ":2: expected two fields `x,y`, got 3",
        ),
        ("-0.5,0.7\n-0.5,abc\n", ":2: `abc` is not a number"),
        (
            "x,y\n-0.5,0.7\ninf,0.7\n",
            ":3: `inf` is not a finite number",
        ),
        ("-0.5,y\n", ":1: `y` is not a number"),
        ("x,y\n\n", ": no points"),
    ];
    for (csv, needle) in cases {
        let (_dir, file) = file_with(csv);
        let run = snakectl(&["path", text(&file), "--connect", &addr]);
        assert_fails(&run, 2, &format!("{}{needle}", text(&file)));
    }
    let too_many = "-0.5,0.7\n".repeat(snakectl::protocol::MAX_PATH_POINTS + 1);
    let (_dir, file) = file_with(&too_many);
    let run = snakectl(&["path", text(&file), "--connect", &addr]);
    assert_fails(
        &run,
        2,
        &format!(
            "{}: 10001 points, over the limit of 10000 points a path may have",
            text(&file)
        ),
    );
    let run = snakectl(&["path", "/nonexistent/path.csv", "--connect", &addr]);
    assert_fails(&run, 2, "/nonexistent/path.csv");
}

#[test]
fn strategy_is_checked_locally_and_switched_live() {
    let run = snakectl(&["strategy", "greedy", "--connect", &closed_port()]);
    assert_fails(&run, 2, "`overall` and `sequential`");

    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let run = at(&d, &["strategy", "sequential"]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert!(
        run.stdout.starts_with("ok: strategy sequential at tick "),
        "{:?}",
        run.stdout
    );
    assert_eq!(object(&at(&d, &["status"]))["strategy"], "sequential");
}

/// A child's stdout line by line, read on its own thread.
fn lines_of(stdout: ChildStdout) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::sync_channel(64);
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { return };
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    rx
}

#[test]
fn watch_prints_telemetry_lines_and_ends_quietly_on_a_closed_pipe() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();
    let mut child = spawn(&["watch", "--rate-hz", "50", "--connect", &addr]);
    let stdout = child.stdout.take().unwrap();
    let mut reader = BufReader::new(stdout);
    let mut ticks = Vec::new();
    for _ in 0..3 {
        let mut line = String::new();
        reader.read_line(&mut line).unwrap();
        let v: Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}"));
        assert_eq!(v["type"], "telemetry", "{v}");
        assert_eq!(v["theta_meas"].as_array().unwrap().len(), 12, "{v}");
        ticks.push(v["tick"].as_u64().unwrap());
    }
    assert!(ticks.windows(2).all(|w| w[0] < w[1]), "ticks {ticks:?}");
    // As `| head -3` does: the reader goes; the next line written ends watch with exit 0.
    drop(reader);
    let run = finish(child);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);
    assert_eq!(run.stderr, "");
}

#[test]
fn watch_ends_with_0_on_ctrl_c_and_with_1_when_the_daemon_goes() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();

    let mut child = spawn(&["watch", "--connect", &addr]);
    let lines = lines_of(child.stdout.take().unwrap());
    lines.recv_timeout(DEADLINE).expect("a telemetry line");
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let run = finish(child);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);

    let mut child = spawn(&["watch", "--connect", &addr]);
    let lines = lines_of(child.stdout.take().unwrap());
    lines.recv_timeout(DEADLINE).expect("a telemetry line");
    d.stop().unwrap();
    let run = finish(child);
    assert_fails(&run, 1, "the daemon went away");
}

#[test]
fn with_no_daemon_every_command_says_how_to_start_one() {
    let addr = closed_port();
    for args in [
        &["status"][..],
        &["goto", "-0.5", "0.7"],
        &["watch"],
        &["estop"],
    ] {
        let mut all = args.to_vec();
        all.extend(["--connect", &addr]);
        let run = snakectl(&all);
        assert_fails(&run, 1, &format!("no daemon is listening on {addr}"));
        assert!(
            run.stderr.contains("snakectl run --config"),
            "{:?}",
            run.stderr
        );
    }
}

#[test]
fn a_daemon_with_a_token_admits_token_file_and_refuses_without_it() {
    let _one = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let token = dir.path().join("token");
    std::fs::write(&token, "correct horse\n").unwrap();
    let line = format!("max_clients = 4\ntoken_file = {:?}", text(&token));
    let d = Daemon::start(sim_config(&[("max_clients = 4", &line)]));

    let run = at(&d, &["status"]);
    assert_fails(&run, 1, "unauthorized");
    assert!(run.stderr.contains("--token-file"), "{:?}", run.stderr);
    let run = at(&d, &["goto", "-0.55", "0.70"]);
    assert_fails(&run, 1, "unauthorized");

    let status = object(&at(&d, &["status", "--token-file", text(&token)]));
    assert_eq!(status["state"], "holding", "{status}");
    let run = at(&d, &["goto", "-0.54", "0.71", "--token-file", text(&token)]);
    assert_eq!(run.code, 0, "stderr {:?}", run.stderr);

    // A token file that cannot be read is bad input, found before connecting.
    let missing = dir.path().join("missing");
    let run = at(&d, &["status", "--token-file", text(&missing)]);
    assert_fails(
        &run,
        2,
        &format!("{}: cannot read the token file", text(&missing)),
    );

    let wrong = dir.path().join("wrong");
    std::fs::write(&wrong, "battery staple\n").unwrap();
    let run = at(&d, &["status", "--token-file", text(&wrong)]);
    assert_fails(&run, 1, "unauthorized");
    // The token was passed: the error names its file, and asks for no --token-file.
    assert_fails(
        &run,
        1,
        &format!("the daemon refused the token in {}", text(&wrong)),
    );
    assert!(
        !run.stderr.contains("pass --token-file"),
        "{:?}",
        run.stderr
    );
}

/// A fake daemon on a loopback port: it reads a request line, sends `reply`, then holds the
/// connection until the client closes it.
fn fake_daemon(reply: Vec<u8>) -> String {
    use std::io::Write as _;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        let (stream, _) = listener.accept().unwrap();
        let mut lines = BufReader::new(stream.try_clone().unwrap());
        let mut line = String::new();
        let _ = lines.read_line(&mut line);
        let mut out = stream;
        // The client may close the connection before it has all of it.
        let _ = out.write_all(&reply);
        let _ = std::io::copy(&mut lines, &mut std::io::sink());
    });
    addr
}

/// `snakectl status` against a fake daemon sending `reply`: its exit code and stderr's bytes.
fn status_against(reply: Vec<u8>) -> (Option<i32>, Vec<u8>) {
    let addr = fake_daemon(reply);
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["status", "--connect", &addr])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = child.stderr.take().unwrap();
    let err = std::thread::spawn(move || {
        let mut bytes = Vec::new();
        err.read_to_end(&mut bytes).unwrap();
        bytes
    });
    let status = daemon_support::child::wait_within(&mut child, "snakectl status");
    (status.code(), err.join().unwrap())
}

/// A reply line past the client's cap fails the command with a clear message, the line not
/// held whole.
#[test]
fn a_reply_line_over_the_cap_fails_with_a_clear_message() {
    let _one = one_at_a_time();
    let mut reply = vec![b'A'; snakectl::client::MAX_REPLY_LINE + 1];
    reply.push(b'\n');
    let (code, stderr) = status_against(reply);
    let stderr = String::from_utf8_lossy(&stderr);
    assert_ne!(code, Some(0), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "sent a line over {} bytes (it begins: AAAA",
            snakectl::client::MAX_REPLY_LINE
        )),
        "{stderr}"
    );
    assert!(
        stderr.len() < 1000,
        "the message holds the whole line: {stderr}"
    );
}

/// Garbage from the daemon is quoted in the error with its control bytes escaped: nothing but
/// printable text reaches the terminal.
#[test]
fn garbage_from_the_daemon_is_quoted_escaped() {
    let _one = one_at_a_time();
    let (code, stderr) = status_against(b"\x00\xff\x1b[2J garbage not json }{\n".to_vec());
    assert_ne!(code, Some(0));
    assert!(
        !stderr.iter().any(|&b| b == 0 || b == 0x1b || b == 0xff),
        "raw bytes in {stderr:?}"
    );
    let stderr = String::from_utf8(stderr).unwrap();
    assert!(stderr.contains(r"\0"), "{stderr}");
    assert!(stderr.contains(r"\u{1b}[2J garbage not json"), "{stderr}");
}
