//! `snakectl demo` as a user runs it: the real binary, in its short mode, writing into a
//! temporary directory; and a bad `--config` refused with the file named.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;
use snakectl::chain::Vec2;

/// `max_joint_speed_rad_s` and `max_tip_speed_m_s` of the shipped config/sim.toml.
const JOINT_SPEED_LIMIT: f64 = 2.0;
const TIP_SPEED_LIMIT: f64 = 0.10;

/// Largest tracking error accepted, m. The XL430's encoder step (2π/4096 = 1.5 mrad) moves the
/// tip by up to 1.4 mm for the base joint, 0.9 m away; the rounding of all twelve joints and a
/// tick or two of servo lag at the eight's 6 cm/s stay within about 5 mm. A client that lost
/// the curve, or a loop that stalled, is off by more than 1 cm.
const TRACKING_BOUND_M: f64 = 0.01;

fn demo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("demo")
        .args(args)
        .output()
        .unwrap()
}

fn number(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("`{key}` is not a number in {v}"))
}

fn assert_png(path: &Path) {
    let bytes = std::fs::read(path).unwrap();
    assert!(
        bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
        "{} is not a PNG",
        path.display()
    );
}

fn assert_svg(path: &Path) {
    let text = std::fs::read_to_string(path).unwrap();
    let head = text.trim_start();
    assert!(
        head.starts_with("<svg") || head.starts_with("<?xml"),
        "{} does not start as SVG: {:?}",
        path.display(),
        &head[..head.len().min(40)]
    );
}

#[test]
fn the_short_demo_drives_both_strategies_and_writes_its_figures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // The shipped arm, but a servo is declared silent only after 30 missed reads instead of 5:
    // the simulated servos answer from a real-time thread on the cores the tests load.
    let shipped =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    assert!(
        shipped.contains("\n[control]\n"),
        "config/sim.toml has a [control] table"
    );
    let config = dir.path().join("sim.toml");
    std::fs::write(
        &config,
        shipped.replace("\n[control]\n", "\n[control]\nmax_silence_ms = 300\n"),
    )
    .unwrap();
    let output = demo(&[
        "--seconds",
        "3",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr),
    );
    assert!(
        output.status.success(),
        "exit {:?}\nstdout:\n{stdout}\nstderr:\n{stderr}",
        output.status
    );
    // The table, the estop shown as it happened, and where the files went.
    for name in ["overall", "sequential"] {
        assert!(stdout.contains(name), "no {name} row:\n{stdout}");
    }
    assert!(
        stderr.contains("ESTOP"),
        "no estop in the progress:\n{stderr}"
    );
    assert!(
        stdout.contains(out.to_str().unwrap()),
        "the output directory is not named:\n{stdout}"
    );

    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let limit = number(&summary, "max_joint_speed_rad_s");
    assert_eq!(limit, JOINT_SPEED_LIMIT);
    let strategies = summary["strategies"].as_array().unwrap();
    let names: Vec<&str> = strategies
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["overall", "sequential"]);
    for s in strategies {
        let name = s["name"].as_str().unwrap();
        let peak = number(s, "peak_joint_speed_rad_s");
        assert!(
            peak > 0.0 && peak <= limit + 1e-9,
            "{name}: peak joint speed {peak}"
        );
        assert!(number(s, "m3_rad2") > 0.0, "{name}: no metric 3 travelled");
        let (p50, max) = (
            number(s, "tracking_error_p50_m"),
            number(s, "tracking_error_max_m"),
        );
        assert!(
            p50.is_finite() && max.is_finite() && p50 <= max && max < TRACKING_BOUND_M,
            "{name}: tracking error p50 {p50} m, max {max} m"
        );
        // The rate it held is the machine's business (a loaded machine holds less); that it
        // reports one, and never more than it was asked for, is the demo's.
        let hz = number(s, "loop_hz");
        assert!(hz > 0.0 && hz <= 105.0, "{name}: loop at {hz} Hz");
        for key in ["tick_p99_us", "solve_us_p50", "solve_us_p99"] {
            let v = number(s, key);
            assert!(v.is_finite() && v > 0.0, "{name}: {key} = {v}");
        }
        assert!(number(s, "solve_us_p50") <= number(s, "solve_us_p99"));
        let tip_speed = number(s, "peak_tip_speed_m_s");
        assert!(
            tip_speed > 0.0 && tip_speed < TIP_SPEED_LIMIT,
            "{name}: tip reference at {tip_speed} m/s"
        );
    }
    // Metric 3 is what `overall` minimizes.
    assert!(number(&strategies[0], "m3_rad2") < number(&strategies[1], "m3_rad2"));
    assert_eq!(summary["path"]["refused_while_latched"], "estopped");
    // Among obstacles: in and back round the post, never closer than the clearance.
    let world = &summary["world"];
    assert_eq!(world["arrived"], true, "{world}");
    assert_eq!(world["obstacles"], serde_json::json!(["post", "shelf"]));
    let kept = number(world, "clearance_m");
    assert!(number(world, "min_clearance_m") >= kept - 1e-9, "{world}");
    assert!(
        number(world, "route_in_m") > number(world, "straight_m"),
        "the straight way is blocked: {world}"
    );

    for name in ["motion", "joints"] {
        assert_png(&out.join(format!("{name}.png")));
        assert_svg(&out.join(format!("{name}.svg")));
    }

    // The run is recorded, with the demo's phases; the figures are drawn from it.
    let recording = snakectl::record::Recording::open(&out.join("run.mcap")).unwrap();
    let record = recording.plot_record();
    let pictured: Vec<&str> = record
        .phases
        .iter()
        .filter(|p| p.pictured)
        .map(|p| p.label.as_str())
        .collect();
    assert_eq!(
        pictured,
        [
            "overall: eight",
            "sequential: eight",
            "path, estop",
            "among obstacles"
        ]
    );
    let marks: Vec<&str> = record.events.iter().map(|e| e.label.as_str()).collect();
    assert_eq!(marks, ["estop", "reset"]);
    // Its reference is the daemon's route round the post, not the blocked straight line: every
    // point keeps the tip's clearance (the obstacles grown by the link's radius and the gap).
    let last = record.phases.last().unwrap();
    let world = last
        .world
        .as_ref()
        .expect("the obstacles of the last phase");
    let grown = world.link_radius_m() + world.clearance_m();
    assert!(last.reference.len() > 10, "{:?}", last.reference);
    for p in &last.reference {
        let (d, _) = world.point_distance(Vec2::new(p[0], p[1])).unwrap();
        assert!(
            d >= grown - 1e-6,
            "the route at {p:?} is {d} m from an obstacle"
        );
    }
    assert!(
        record.samples.len() > 500,
        "{} samples",
        record.samples.len()
    );
}

#[test]
fn a_bad_config_fails_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let missing = dir.path().join("no-such-arm.toml");
    let broken = dir.path().join("broken-arm.toml");
    std::fs::write(&broken, "[arm\nbase_x_m = 0.0\n").unwrap();
    for config in [&missing, &broken] {
        let output = demo(&[
            "--config",
            config.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "stderr:\n{stderr}");
        assert!(
            stderr.contains(config.to_str().unwrap()),
            "the message does not name {}:\n{stderr}",
            config.display()
        );
    }
    assert!(!out.join("summary.json").exists());
}

/// Ctrl-C stops the run as a failure does: the arm brought to rest, the recording closed whole
/// (it plots without a word of being cut short), exit status 130 with the reason; the last
/// run's outputs are gone rather than left beside this run's partial one.
#[test]
fn an_interrupted_demo_stops_cleanly_and_leaves_no_stale_outputs() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for stale in ["summary.json", "motion.png", "joints.svg"] {
        std::fs::write(out.join(stale), "from the last run").unwrap();
    }
    let shipped =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let config = dir.path().join("sim.toml");
    std::fs::write(
        &config,
        shipped.replace("\n[control]\n", "\n[control]\nmax_silence_ms = 300\n"),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["demo", "--seconds", "3", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = String::new();
    // Interrupted during the first figure eight.
    for line in lines.by_ref() {
        let line = line.unwrap();
        seen.push_str(&line);
        seen.push('\n');
        if line.contains("figure eight") {
            break;
        }
    }
    assert!(
        seen.contains("figure eight"),
        "the demo ended early:\n{seen}"
    );
    let pid = rustix::process::Pid::from_raw(i32::try_from(child.id()).unwrap()).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::INT).unwrap();
    for line in lines {
        seen.push_str(&line.unwrap());
        seen.push('\n');
    }
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{seen}");
    assert!(
        seen.contains("the demo was interrupted") && seen.contains("stopped by SIGINT"),
        "{seen}"
    );
    for stale in ["summary.json", "motion.png", "joints.svg"] {
        assert!(!out.join(stale).exists(), "{stale} of the last run is left");
    }
    let plotted = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("plot")
        .arg(out.join("run.mcap"))
        .arg("--out")
        .arg(dir.path().join("replot"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&plotted.stderr);
    assert!(plotted.status.success(), "{stderr}");
    assert!(!stderr.contains("ends in the middle"), "{stderr}");
}
