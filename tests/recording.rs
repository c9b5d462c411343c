//! A recorded run read back: a daemon on the simulator records while a client moves the arm
//! (a goto, then `velocity`), then shuts down; the file is read with the `mcap` crate alone.
//! Each channel holds what the loop offered minus what was dropped, its times increase, a
//! `JointState` decodes to the angles of the telemetry logged with it, the metadata holds the
//! config and the account, and `snakectl plot` draws the figures from it; it draws a run in
//! which the arm never moved, and one cut short as a killed writer leaves it.
#![allow(clippy::unwrap_used)]

mod daemon_support;

use std::collections::BTreeMap;
use std::process::Command;

use daemon_support::{sim_config, sim_config_with, xy, Daemon};
use foxglove::schemas::SceneUpdate;
use foxglove::Decode;
use serde_json::{json, Value};
use snakectl::record::recorder::SCENE_HZ;
use snakectl::record::RecordOptions;
use snakectl::ros::{self, JointState, PointStamped};

/// Per topic: (log time, bytes) in the file's order.
type Messages = BTreeMap<String, Vec<(u64, Vec<u8>)>>;
/// Metadata records by name.
type Metadata = BTreeMap<String, BTreeMap<String, String>>;
/// Per topic: schema name, schema encoding, message encoding.
type Kinds = BTreeMap<String, (String, String, String)>;

fn read(bytes: &[u8]) -> (Messages, Metadata, Kinds) {
    let mut messages: Messages = BTreeMap::new();
    let mut kinds = BTreeMap::new();
    for m in mcap::MessageStream::new(bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        kinds.insert(
            m.channel.topic.clone(),
            (
                schema.name.clone(),
                schema.encoding.clone(),
                m.channel.message_encoding.clone(),
            ),
        );
        messages
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, m.data.into_owned()));
    }
    let mut metadata = BTreeMap::new();
    for record in mcap::read::LinearReader::new(bytes).unwrap() {
        if let mcap::records::Record::Metadata(m) = record.unwrap() {
            metadata.insert(m.name, m.metadata);
        }
    }
    (messages, metadata, kinds)
}

#[test]
fn a_recorded_run_reads_back_whole_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let config = sim_config(&[]);
    let d = Daemon::start_with(config.clone(), Some(RecordOptions::to(&path)));
    let mut c = d.client();
    c.ok(json!({"cmd": "take_control"}));
    let tip = xy(&c.status()["tip"]);
    let target = [tip[0] + 0.03, tip[1] - 0.02];
    let id = c.send(json!({"cmd": "goto", "target": target}));
    c.event("arrived", Some(id));
    for _ in 0..20 {
        c.ok(json!({"cmd": "velocity", "v": [0.02, 0.0]}));
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    c.ok(json!({"cmd": "stop"}));
    c.wait_status("holding", |s| s["state"] == "holding");
    drop(c);
    let summary = d.stop().unwrap();

    let bytes = std::fs::read(&path).unwrap();
    let (messages, metadata, kinds) = read(&bytes);

    // The channels, as the ROS 2 profile and the JSON schemas name them.
    let cdr = |name: &str| (name.to_owned(), "ros2msg".to_owned(), "cdr".to_owned());
    assert_eq!(
        kinds["/snakectl/joint_states"],
        cdr("sensor_msgs/msg/JointState")
    );
    for topic in ["tip_cmd", "tip_meas", "target"] {
        assert_eq!(
            kinds[&format!("/snakectl/{topic}")],
            cdr("geometry_msgs/msg/PointStamped")
        );
    }
    let json_kind = |name: &str| (name.to_owned(), "jsonschema".to_owned(), "json".to_owned());
    assert_eq!(
        kinds["/snakectl/telemetry"],
        json_kind("snakectl.Telemetry")
    );
    assert_eq!(kinds["/snakectl/events"], json_kind("snakectl.Event"));
    let protobuf = "protobuf".to_owned();
    assert_eq!(
        kinds["/snakectl/scene"],
        (
            "foxglove.SceneUpdate".to_owned(),
            protobuf.clone(),
            protobuf
        )
    );

    // Every tick was offered (tick 0 and each tick run), and what was not dropped is there.
    let account = &metadata["snakectl.recording"];
    for (topic, list) in &messages {
        let row: Value = serde_json::from_str(&account[topic]).unwrap();
        let (offered, written, dropped) = (
            row["offered"].as_u64().unwrap(),
            row["written"].as_u64().unwrap(),
            row["dropped"].as_u64().unwrap(),
        );
        assert_eq!(list.len() as u64, written, "{topic}");
        assert_eq!(written, offered - dropped, "{topic}: {row}");
        if topic == "/snakectl/scene" {
            // Every `every`th tick of those taken (none was dropped at this rate).
            let every = (config.control().rate_hz / SCENE_HZ).ceil() as u64;
            assert_eq!(offered, summary.ticks / every + 1, "{topic}: {row}");
        } else if topic != "/snakectl/target" && topic != "/snakectl/events" {
            assert_eq!(
                offered,
                summary.ticks + 1,
                "{topic}: the loop ran {} ticks",
                summary.ticks
            );
        }
        // Times increase with the ticks (events of one tick share its time).
        let strictly = topic != "/snakectl/events";
        for w in list.windows(2) {
            assert!(
                w[1].0 > w[0].0 || (!strictly && w[1].0 == w[0].0),
                "{topic}: {} then {}",
                w[0].0,
                w[1].0
            );
        }
    }
    assert!(messages["/snakectl/target"].len() > 10, "the goto's target");
    // The last scene draws the measured arm ending at its tick's measured tip.
    let (at, last_scene) = messages["/snakectl/scene"].last().unwrap();
    let scene = SceneUpdate::decode(&last_scene[..]).unwrap();
    let arm = scene.entities.iter().find(|e| e.id == "arm_meas").unwrap();
    let end = arm.lines[0].points.last().unwrap();
    // Every entity is stamped with its message's log time, to the nanosecond.
    for e in &scene.entities {
        let stamp = e.timestamp.unwrap();
        assert_eq!(stamp.total_nanos(), *at, "{}", e.id);
    }
    let (_, same_tick) = messages["/snakectl/telemetry"]
        .iter()
        .find(|(t, _)| t == at)
        .unwrap();
    let same_tick: Value = serde_json::from_slice(same_tick).unwrap();
    let tip = xy(&same_tick["tip_meas"]);
    assert!(
        (end.x - tip[0]).hypot(end.y - tip[1]) < 1e-9,
        "{end:?} vs {tip:?}"
    );
    let events: Vec<Value> = messages["/snakectl/events"]
        .iter()
        .map(|(_, b)| serde_json::from_slice(b).unwrap())
        .collect();
    assert!(events.iter().any(|e| e["event"] == "arrived"), "{events:?}");
    assert!(
        events.iter().any(|e| e["event"] == "shutting_down"),
        "{events:?}"
    );

    // A JointState decodes to the angles of the telemetry logged at its time.
    let telemetry: BTreeMap<u64, Value> = messages["/snakectl/telemetry"]
        .iter()
        .map(|(t, b)| (*t, serde_json::from_slice(b).unwrap()))
        .collect();
    let (t, bytes) =
        &messages["/snakectl/joint_states"][messages["/snakectl/joint_states"].len() / 2];
    let joints: JointState = ros::decode(bytes).unwrap();
    let line = &telemetry[t];
    let theta: Vec<f64> = line["theta_meas"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(joints.position, theta);
    assert_eq!(joints.name, ros::joint_names(theta.len()));
    let stamp_ns = u64::try_from(joints.header.stamp.sec).unwrap() * 1_000_000_000
        + u64::from(joints.header.stamp.nanosec);
    assert_eq!(stamp_ns, *t, "the header's stamp is the log time");
    let (_, tip) = messages["/snakectl/tip_meas"]
        .iter()
        .find(|(time, _)| time == t)
        .unwrap();
    let tip: PointStamped = ros::decode(tip).unwrap();
    assert_eq!([tip.point.x, tip.point.y], xy(&line["tip_meas"]));
    assert_eq!(tip.header.frame_id, "base");

    // The config the run used, as its text and path.
    let recorded = &metadata["snakectl.config"];
    assert_eq!(recorded["toml"], config.text());
    assert_eq!(recorded["path"], config.path().display().to_string());
    assert!(metadata.contains_key("snakectl.describe"));

    // `snakectl plot` draws the figures from it.
    let out = dir.path().join("figures");
    let plotted = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("plot")
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(plotted.status.success(), "{plotted:?}");
    for name in ["motion", "joints"] {
        let svg = std::fs::read_to_string(out.join(format!("{name}.svg"))).unwrap();
        assert!(svg.contains("<svg"), "{name}.svg");
        let png = std::fs::read(out.join(format!("{name}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{name}.png");
    }
}

#[test]
fn a_recording_that_cannot_be_created_refuses_start_up_before_the_arm_moves() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no/such/dir/run.mcap");
    let d = Daemon::start_with(sim_config(&[]), Some(RecordOptions::to(&path)));
    let e = d.stop().unwrap_err();
    assert!(matches!(e, snakectl::daemon::DaemonError::Record(_)), "{e}");
    assert!(e.to_string().contains("run.mcap"), "{e}");
}

/// Runs `snakectl plot FILE --out OUT`.
fn plot(file: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("plot")
        .arg(file)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// A run in which the arm never moved draws (the arm at rest, flat joint angles); `--out` naming
/// a file is refused as not a directory.
#[test]
fn a_recording_of_an_arm_at_rest_plots() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("idle.mcap");
    let d = Daemon::start_with(sim_config(&[]), Some(RecordOptions::to(&path)));
    std::thread::sleep(std::time::Duration::from_millis(300));
    d.stop().unwrap();

    let out = dir.path().join("figures");
    let plotted = plot(&path, &out);
    assert!(plotted.status.success(), "{plotted:?}");
    let said = String::from_utf8_lossy(&plotted.stdout);
    assert!(said.contains("1 phase(s) pictured"), "{said}");
    for name in ["motion.svg", "motion.png", "joints.svg", "joints.png"] {
        assert!(out.join(name).is_file(), "{name}");
    }

    let refused = plot(&path, &path);
    assert_eq!(refused.status.code(), Some(2), "{refused:?}");
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(said.contains("not a directory"), "{said}");
}

/// A recording whose writer was killed (the file cut in the middle of a chunk, without its
/// summary) still draws from what it holds, and the warning names `mcap recover`.
#[test]
fn a_recording_cut_short_plots_what_it_holds() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let d = Daemon::start_with(sim_config(&[]), Some(RecordOptions::to(&path)));
    let mut c = d.client();
    c.ok(json!({"cmd": "take_control"}));
    for _ in 0..100 {
        c.ok(json!({"cmd": "velocity", "v": [0.02, 0.0]}));
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    c.ok(json!({"cmd": "stop"}));
    drop(c);
    d.stop().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    // Halfway through the data section, most likely in a chunk: cut anywhere, what is before
    // the cut still reads.
    let data_end = mcap::read::footer(&bytes).unwrap().summary_start as usize;
    assert!(data_end > 1000, "{data_end}");
    std::fs::write(&cut, &bytes[..data_end / 2]).unwrap();

    let out = dir.path().join("figures");
    let plotted = plot(&cut, &out);
    assert!(plotted.status.success(), "{plotted:?}");
    let said = String::from_utf8_lossy(&plotted.stderr);
    assert!(said.contains("ends in the middle of a record"), "{said}");
    assert!(said.contains("`mcap recover`"), "{said}");
    assert!(out.join("motion.svg").is_file());
}

/// A file that exists is never replaced unasked: refused naming it, kept as it was; with
/// `overwrite` it is replaced, but not while another recording is being written to it.
#[test]
fn a_recording_replaces_a_file_only_when_asked_and_never_one_being_written() {
    let dir = tempfile::tempdir().unwrap();
    let kept = dir.path().join("kept.mcap");
    std::fs::write(&kept, "a file worth keeping").unwrap();
    let d = Daemon::start_with(sim_config(&[]), Some(RecordOptions::to(&kept)));
    let e = d.stop().unwrap_err();
    assert!(e.to_string().contains("kept.mcap exists already"), "{e}");
    assert_eq!(
        std::fs::read_to_string(&kept).unwrap(),
        "a file worth keeping"
    );

    let first = Daemon::start_with(
        sim_config(&[]),
        Some(RecordOptions::to(&kept).overwriting(true)),
    );
    // Up, so its recording is made before the second daemon starts.
    first.client().status();
    let second = Daemon::start_with(
        sim_config(&[]),
        Some(RecordOptions::to(&kept).overwriting(true)),
    );
    let e = second.stop().unwrap_err();
    assert!(
        e.to_string()
            .contains("kept.mcap is being written by another process"),
        "{e}"
    );
    first.stop().unwrap();
    let recording = snakectl::record::Recording::open(&kept).unwrap();
    assert!(
        !recording.channels.is_empty(),
        "the first daemon's recording was spoilt"
    );
}

/// The config given as the recording is refused from the command line, exit 2, and kept.
#[test]
fn snakectl_run_never_records_over_its_own_config() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("arm.toml");
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    std::fs::write(&config, &text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .arg("--record")
        .arg(&config)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("arm.toml exists already"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&config).unwrap(), text);
}

/// A start-up refused after the recording was created (a servo that does not answer) leaves no
/// file behind.
#[test]
fn a_refused_start_up_leaves_no_recording_behind() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let config = sim_config_with(
        &[],
        "[[sim.fault]]\nkind = \"silent\"\nid = 5\nat_s = 0.0\n",
    );
    let d = Daemon::start_with(config, Some(RecordOptions::to(&path)));
    let e = d.stop().unwrap_err();
    assert!(e.to_string().contains("servo 5"), "{e}");
    assert!(
        !path.exists(),
        "a recording left behind by a refused start-up"
    );
}

/// Messages per topic in an MCAP file, read up to where it breaks off (a file without its
/// summary, or cut in a chunk).
fn messages_in(bytes: &[u8]) -> BTreeMap<String, u64> {
    let mut counts = BTreeMap::new();
    let stream =
        mcap::MessageStream::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into())
            .unwrap();
    for message in stream.map_while(Result::ok) {
        *counts.entry(message.channel.topic.clone()).or_insert(0) += 1;
    }
    counts
}

/// `written=N` in a log line.
fn written_in(line: &str) -> u64 {
    let at = line.find("written=").unwrap() + "written=".len();
    let digits: String = line[at..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().unwrap()
}

/// Under a file-size limit (`ulimit -f`) the write past it fails (EFBIG) instead of SIGXFSZ
/// killing the daemon: the recording stops, says so, and holds what it counted written; the
/// arm goes on and the daemon stops cleanly on SIGTERM.
#[test]
fn a_file_size_limit_stops_the_recording_not_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("arm.toml");
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    // Faster ticks fill the limit sooner.
    let text = text.replace("rate_hz = 100.0", "rate_hz = 250.0");
    std::fs::write(&config, text).unwrap();
    let path = dir.path().join("run.mcap");
    // 1536 KiB (bash counts `ulimit -f` in KiB): one chunk of about 1.3 MB fits, the next
    // does not.
    let child = Command::new("bash")
        .arg("-c")
        .arg("ulimit -f 1536 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .arg("--record")
        .arg(&path)
        .env("RUST_LOG", "info")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut d = daemon_support::child::DaemonChild::from_child(child);
    let addr = d.address();
    let stopped = d.logged("recording stopped", daemon_support::DEADLINE);
    assert!(stopped.is_some(), "the recording never stopped");
    // The arm goes on: the daemon still answers.
    let mut c = daemon_support::Client::connect(addr);
    assert_eq!(c.status()["state"], "holding");
    drop(c);
    d.signal("-TERM");
    let (status, log) = d.wait();
    assert_eq!(status.code(), Some(0), "{status:?}\n{log}");
    let line = log
        .lines()
        .find(|l| l.contains("recording stopped early"))
        .unwrap_or_else(|| panic!("no account of the stopped recording in\n{log}"));
    assert!(line.contains("File too large"), "{line}");
    let in_file: u64 = messages_in(&std::fs::read(&path).unwrap()).values().sum();
    assert!(written_in(line) > 0, "{line}");
    assert_eq!(written_in(line), in_file, "{line}");
}

/// A FIFO given as the recording is refused before it is opened (opening it would wait for a
/// reader, deaf to signals), with `--overwrite` or not: exit 2 at once, the path named.
#[test]
fn a_recording_that_is_not_a_regular_file_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("rec.fifo");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    for overwrite in [false, true] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["run", "--listen", "127.0.0.1:0", "--config"])
            .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"))
            .arg("--record")
            .arg(&fifo)
            .args(overwrite.then_some("--overwrite"))
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let status = daemon_support::child::wait_within(&mut child, "snakectl run --record FIFO");
        let mut stderr = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
        assert_eq!(status.code(), Some(2), "--overwrite {overwrite}: {stderr}");
        assert!(
            stderr.contains("rec.fifo is not a regular file"),
            "--overwrite {overwrite}: {stderr}"
        );
    }
}

/// Runs `snakectl plot FILE --out OUT`, killed if it has not ended within a minute (a bound on
/// a test that would otherwise never end, not a speed asked for): its exit code and stderr.
fn plot_ending(file: &std::path::Path, out: &std::path::Path) -> (Option<i32>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("plot")
        .arg(file)
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("`snakectl plot {}` did not end", file.display());
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let output = child.wait_with_output().unwrap();
    (
        output.status.code(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// A closed recording of 50 telemetry snapshots of a still three-joint arm, each changed by
/// `spoil`.
fn telemetry_recording(path: &std::path::Path, spoil: fn(&mut snakectl::protocol::Telemetry)) {
    use snakectl::protocol::{telemetry_line, Status, Telemetry};
    use snakectl::record::{schema, McapSink, Sink};
    let mut sink = McapSink::create(path, false).unwrap();
    let channel = sink.add_channel(&schema::telemetry("snakectl")).unwrap();
    for tick in 0..50u64 {
        let mut t = Telemetry {
            tick,
            t_s: tick as f64 * 0.01,
            theta_meas: vec![0.1, 0.2, 0.3],
            tip_meas: [0.3, 0.2],
            ..Telemetry::default()
        };
        spoil(&mut t);
        let line = telemetry_line(&Status::of(&t));
        sink.write(channel, tick * 10_000_000, line.trim_end().as_bytes())
            .unwrap();
    }
    sink.finish().unwrap();
}

/// What `plot` cannot draw it refuses, exit 2, saying why, and writes nothing: a record length
/// of `u64::MAX` (which once panicked in the `mcap` crate), values no run records (which once
/// made the drawing run without end), a device and a FIFO (read without end, or never opened).
#[test]
fn plot_refuses_what_it_cannot_draw_with_exit_2_and_always_ends() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("figures");

    let tiny = dir.path().join("tiny.mcap");
    std::fs::write(&tiny, b"\x89MCAP0\r\n\x01\xff\xff\xff\xff\xff\xff\xff\xff").unwrap();
    let (code, said) = plot_ending(&tiny, &out);
    assert_eq!(code, Some(2), "{said}");
    assert!(said.contains("claims 18446744073709551615 bytes"), "{said}");
    assert!(!said.contains("panicked"), "{said}");

    type Spoil = fn(&mut snakectl::protocol::Telemetry);
    let cases: [(&str, Spoil); 2] = [
        ("tip_meas", |t| t.tip_meas = [1e308, 1e308]),
        ("tracking_error_m", |t| t.tracking_error_m = 1e307),
    ];
    for (field, spoil) in cases {
        let path = dir.path().join(format!("{field}.mcap"));
        telemetry_recording(&path, spoil);
        let (code, said) = plot_ending(&path, &out);
        assert_eq!(code, Some(2), "{said}");
        assert!(
            said.contains(&format!("{field} is ")) && said.contains("the recording is damaged"),
            "{said}"
        );
    }
    // The same recording unspoilt draws.
    let fine = dir.path().join("fine.mcap");
    telemetry_recording(&fine, |_| {});
    let (code, said) = plot_ending(&fine, &out);
    assert_eq!(code, Some(0), "{said}");
    std::fs::remove_dir_all(&out).unwrap();

    let (code, said) = plot_ending(std::path::Path::new("/dev/zero"), &out);
    assert_eq!(code, Some(2), "{said}");
    assert!(
        said.contains("a character device, not a regular file"),
        "{said}"
    );
    let fifo = dir.path().join("fifo.mcap");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let (code, said) = plot_ending(&fifo, &out);
    assert_eq!(code, Some(2), "{said}");
    assert!(
        said.contains("a FIFO (named pipe), not a regular file"),
        "{said}"
    );
    assert!(!out.exists(), "figures written from what was refused");
}
