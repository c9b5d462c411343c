//! `snakectl solve` as a user runs it: exit codes, one JSON object on stdout, one-line errors
//! naming the field on stderr.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::process::Output;

use cli_support::snakectl;

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap()
}

const ARM: &str = r#"{"links":[0.3,0.3,0.2,0.2],"base":[0,0,0],"theta0":[0.2,0.2,0.2,0.2],
    "target":[0.5,0.4]}"#;

#[test]
fn a_reachable_target_is_solved_from_stdin() {
    let out = snakectl(&["solve", "-"], ARM);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let a = json(&out);
    for key in [
        "strategy",
        "theta",
        "points",
        "tip",
        "tip_error",
        "base_error",
        "reachable",
        "converged",
        "iterations",
        "metrics",
        "solve_us",
        "collision_free",
    ] {
        assert!(a.get(key).is_some(), "missing {key}");
    }
    // No obstacles: nothing in the way, no clearance to tell.
    assert_eq!(a["collision_free"], true);
    for key in ["min_clearance_m", "nearest", "start_min_clearance_m"] {
        assert_eq!(a[key], serde_json::Value::Null, "{key}");
    }
    assert_eq!(a["points"].as_array().unwrap().len(), 5);
    assert!(a["tip_error"].as_f64().unwrap() < 1e-9);
    assert_eq!(a["converged"], true);
    for m in ["m1", "m2", "m3", "m4", "m5"] {
        assert!(a["metrics"][m].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn an_unreachable_target_exits_zero_with_honest_flags() {
    let text = ARM.replace("[0.5,0.4]", "[3.0,0.0]");
    let out = snakectl(&["solve", "-"], &text);
    assert_eq!(out.status.code(), Some(0));
    let a = json(&out);
    assert_eq!(a["reachable"], false);
    assert_eq!(a["converged"], false);
    let err = a["tip_error"].as_f64().unwrap();
    assert!(
        (err - 2.0).abs() < 1e-6,
        "a straight arm stops 2 m short: {err}"
    );
}

#[test]
fn free_mode_reports_the_base_displacement() {
    let text = ARM.replacen('{', r#"{"base_mode":"free","steps":3,"#, 1);
    let a = json(&snakectl(&["solve", "-"], &text));
    assert!(a.get("base_error").is_none());
    assert!(a["base_displacement"].as_f64().unwrap() > 0.0);
    assert_eq!(a["tip"], serde_json::json!([0.5, 0.4]));
}

#[test]
fn bad_input_exits_two_with_one_line_naming_the_field() {
    let cases = [
        ("not json", "input"),
        (&*ARM.replacen('{', r#"{"speed":1,"#, 1), "speed"),
        (
            &*ARM.replace("[0.3,0.3,0.2,0.2]", "[0.3,0.3,0.2]"),
            "theta0",
        ),
        (
            &*ARM.replace("[0.3,0.3,0.2,0.2]", "[0.3,0,0.2,0.2]"),
            "links[1]",
        ),
        (&*ARM.replace("[0.3,0.3,0.2,0.2]", "[]"), "links"),
        (&*ARM.replace("[0.5,0.4]", "[0.5,2e6]"), "target[1]"),
        (
            &*ARM.replace("[0.5,0.4]", "[0.5,1e400]"),
            "number out of range",
        ),
        (
            &*ARM.replacen('{', r#"{"limits":[[1,0],null,null,null],"#, 1),
            "limits[0]",
        ),
        (
            &*ARM.replacen('{', r#"{"limits":[null,null,null,[-0.1,0.1]],"#, 1),
            "theta0[3]",
        ),
        (
            &*ARM.replacen('{', r#"{"strategy":"greedy","#, 1),
            "strategy",
        ),
        (&*ARM.replacen('{', r#"{"steps":0,"#, 1), "steps"),
        (&*ARM.replacen('{', r#"{"steps":1000000,"#, 1), "steps"),
        (
            &*ARM.replacen(
                '{',
                r#"{"base_mode":"free","limits":[[-1,1],null,null,null],"#,
                1,
            ),
            "limits[0]",
        ),
        (
            &*ARM.replacen(
                '{',
                r#"{"obstacles":[{"circle":{"center":[1,1],"radius":0}}],"#,
                1,
            ),
            "obstacles[0].circle.radius",
        ),
        (
            &*ARM.replacen(
                '{',
                r#"{"obstacles":[{"id":"post","circle":{"center":[1,1],"radius":0.1}},
                {"id":"shelf","polygon":{"points":[[0,0],[1,1],[1,0],[0,1]]}}],"#,
                1,
            ),
            "obstacles[1].polygon.points",
        ),
        (
            &*ARM.replacen('{', r#"{"clearance_m":-0.01,"#, 1),
            "clearance_m",
        ),
    ];
    for (text, needle) in cases {
        let out = snakectl(&["solve", "-"], text);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{text}: {err}");
        assert!(out.stdout.is_empty());
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(needle), "{text}: {err}");
        assert!(!err.contains("panicked"));
    }
}

/// Distance from `c` to the segment `a..b`.
fn to_segment(c: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let t = (((c[0] - a[0]) * dx + (c[1] - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
    (c[0] - a[0] - t * dx).hypot(c[1] - a[1] - t * dy)
}

fn points(value: &serde_json::Value) -> Vec<[f64; 2]> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
        .collect()
}

#[test]
fn the_sequential_answer_among_obstacles_tells_its_clearance_honestly() {
    let plain = ARM.replacen('{', r#"{"strategy":"sequential","#, 1);
    let before = json(&snakectl(&["solve", "-"], &plain));
    // A post on the answer's third link, and an unnamed shelf far away.
    let answer = points(&before["points"]);
    let (a, b) = (answer[2], answer[3]);
    let post = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
    let text = plain.replacen(
        '{',
        &format!(
            r#"{{"link_radius_m":0.01,"clearance_m":0.005,"obstacles":[
            {{"id":"post","circle":{{"center":[{},{}],"radius":0.03}}}},
            {{"polygon":{{"points":[[3,3],[4,3],[4,4]]}}}}],"#,
            post[0], post[1]
        ),
        1,
    );
    let out = snakectl(&["solve", "-"], &text);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let after = json(&out);
    // The tractrix does not know of obstacles: the same answer, said not to be clear.
    assert_eq!(after["theta"], before["theta"]);
    assert_eq!(after["collision_free"], false);
    let clearance = |pose: &[[f64; 2]]| {
        (1..pose.len())
            .map(|i| to_segment(post, pose[i - 1], pose[i]) - 0.03 - 0.01)
            .fold(f64::INFINITY, f64::min)
    };
    let least = after["min_clearance_m"].as_f64().unwrap();
    assert!((least - clearance(&answer)).abs() < 1e-12, "{least}");
    assert!(least < 0.0);
    assert_eq!(
        after["nearest"],
        serde_json::json!({"link": 3, "obstacle": "post"})
    );
    // The start, worked out from the angles.
    let (mut x, mut y, mut heading) = (0.0, 0.0, 0.0);
    let mut start = vec![[0.0, 0.0]];
    for (len, t) in [0.3, 0.3, 0.2, 0.2].iter().zip([0.2; 4]) {
        heading += t;
        x += len * f64::cos(heading);
        y += len * f64::sin(heading);
        start.push([x, y]);
    }
    let got = after["start_min_clearance_m"].as_f64().unwrap();
    assert!((got - clearance(&start)).abs() < 1e-12, "{got}");
}

#[test]
fn the_chapters_example_among_obstacles_is_answered_with_its_clearance() {
    let chapter = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/SOLVE.md"),
    )
    .unwrap();
    let after = chapter.split("<!-- example: obstacles -->").nth(1).unwrap();
    let problem = after
        .split("```json")
        .nth(1)
        .unwrap()
        .split("```")
        .next()
        .unwrap();
    let out = snakectl(&["solve", "-"], problem);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let a = json(&out);
    assert!(a["tip_error"].as_f64().unwrap() < 1e-9);
    let least = a["min_clearance_m"].as_f64().unwrap();
    // Clear to the round-off of a distance, as the solver counts it.
    assert_eq!(a["collision_free"], least >= 0.005 - 1e-9);
    // No more than the post's own, worked out here.
    let pose = points(&a["points"]);
    let post = (1..pose.len())
        .map(|i| to_segment([0.43, -0.03], pose[i - 1], pose[i]) - 0.04 - 0.01)
        .fold(f64::INFINITY, f64::min);
    assert!(least <= post + 1e-12, "{least} vs {post}");
    let nearest = a["nearest"]["obstacle"].as_str().unwrap();
    assert!(["post", "shelf"].contains(&nearest), "{nearest}");
    assert!(a["start_min_clearance_m"].as_f64().unwrap() > 0.005);
}

#[test]
fn a_config_file_and_a_target_work_too() {
    let out = snakectl(
        &[
            "solve",
            "--config",
            "config/arm.toml",
            "--target",
            "0.5,0.3",
        ],
        "",
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let a = json(&out);
    assert_eq!(a["theta"].as_array().unwrap().len(), 8);
    let out = snakectl(
        &[
            "solve",
            "--config",
            "config/arm.toml",
            "--target",
            "0.5,0.3",
            "--from",
            "0,0",
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--from"));
    // Every flag is named as typed, with its dashes.
    for (flag, value) in [
        ("--strategy", "fastest"),
        ("--propagation", "magic"),
        ("--steps", "0"),
    ] {
        let mut args = vec![
            "solve",
            "--config",
            "config/arm.toml",
            "--target",
            "0.5,0.3",
        ];
        if flag != "--strategy" {
            args.extend(["--strategy", "sequential"]);
        }
        args.extend([flag, value]);
        let out = snakectl(&args, "");
        assert_eq!(out.status.code(), Some(2), "{flag}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(&format!("{flag}:")), "{flag}: {err}");
    }
    let out = snakectl(
        &[
            "solve",
            "--config",
            "config/missing.toml",
            "--target",
            "0,0",
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("config/missing.toml"));
}

#[test]
fn a_reader_that_closes_the_pipe_early_ends_the_command_quietly() {
    // An answer far larger than a pipe buffer, read one byte of.
    let n = 3000;
    let problem = format!(
        r#"{{"links":{:?},"base":[0,0,0],"theta0":{:?},"target":[0.5,0.5],"strategy":"sequential"}}"#,
        vec![1.0 / n as f64; n],
        vec![0.0; n]
    );
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("big.json");
    std::fs::write(&file, problem).unwrap();
    let out = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!(
            "set -o pipefail; '{}' solve --pretty '{}' | head -c 1 >/dev/null",
            env!("CARGO_BIN_EXE_snakectl"),
            file.display()
        ))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(0), "{err}");
}

/// A target inside a cage whose slit (1 cm) no link (2 cm thick) can pass: the tip is put on it,
/// so `reachable`, but through the cage's wall, so neither `converged` nor `collision_free`
/// (docs/SOLVE.md: `reachable` says nothing of obstacles).
#[test]
fn a_target_the_body_cannot_get_to_clear_is_reachable_but_neither_converged_nor_clear() {
    let problem = r#"{"links":[0.3,0.3,0.2,0.2],"base":[0,0,0],"theta0":[0.2,0.2,0.2,0.2],
        "target":[0.6,0.0],"link_radius_m":0.01,"clearance_m":0.005,
        "obstacles":[{"id":"cage","polygon":{"points":[[0.5,-0.1],[0.7,-0.1],[0.7,0.1],
            [0.5,0.1],[0.5,0.005],[0.52,0.005],[0.52,0.08],[0.68,0.08],[0.68,-0.08],
            [0.52,-0.08],[0.52,-0.005],[0.5,-0.005]]}}]}"#;
    let out = snakectl(&["solve", "-"], problem);
    assert_eq!(out.status.code(), Some(0));
    let a = json(&out);
    assert!(a["tip_error"].as_f64().unwrap() < 1e-9, "{a}");
    assert_eq!(
        (&a["reachable"], &a["converged"], &a["collision_free"]),
        (&true.into(), &false.into(), &false.into()),
        "{a}"
    );
    assert!(a["min_clearance_m"].as_f64().unwrap() < 0.0, "{a}");
}

/// `n` links of `link` m along x with one circle off to the side, as a problem file.
fn long_problem(n: usize, link: f64, obstacle: bool) -> String {
    let links = vec![format!("{link:e}"); n].join(",");
    let zeros = vec!["0"; n].join(",");
    let world = if obstacle {
        r#","obstacles":[{"circle":{"center":[0.5,0.5],"radius":0.1}}]"#
    } else {
        ""
    };
    format!(r#"{{"links":[{links}],"base":[0,0,0],"theta0":[{zeros}],"target":[0.3,0.4]{world}}}"#)
}

/// Keeping clear of obstacles takes memory growing as the square of the links (60,000 links
/// asked for 29 GB and aborted): among obstacles a chain may have at most 2048 links, refused
/// by name beyond, in a problem file and in a config alike. Without obstacles there is no cap.
#[test]
fn a_chain_too_long_to_keep_clear_is_refused_naming_links() {
    use snakectl::problem::Problem;
    use snakectl::resolve::overall::MAX_LINKS_AMONG_OBSTACLES;
    assert_eq!(MAX_LINKS_AMONG_OBSTACLES, 2048);
    let out = snakectl(&["solve", "-"], &long_problem(60_000, 1e-5, true));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("links: 60000 links among obstacles, at most 2048"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(out.stdout.is_empty());
    // The cap itself is fine, and so is any length without obstacles.
    Problem::from_json(&long_problem(2048, 1e-4, true)).unwrap();
    Problem::from_json(&long_problem(2049, 1e-4, false)).unwrap();
    let e = Problem::from_json(&long_problem(2049, 1e-4, true)).unwrap_err();
    assert_eq!(e.field, "links", "{e}");

    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("long.toml");
    let joints = "[[joint]]\nlink_m = 1e-4\nmin_rad = -1\nmax_rad = 1\n".repeat(2049);
    std::fs::write(
        &config,
        format!("[arm]\n{joints}[world]\n[[world.obstacle]]\nid = \"post\"\ncircle = {{ center_m = [0.5, 0.5], radius_m = 0.1 }}\n"),
    )
    .unwrap();
    let out = snakectl(
        &[
            "solve",
            "--config",
            config.to_str().unwrap(),
            "--target",
            "0.1,0.1",
        ],
        "",
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("long.toml: joint: 2049 joints with [world] obstacles, at most 2048"),
        "{err}"
    );
}

/// A problem file that starts with a byte order mark, as some editors write, is read as
/// without it (a config's TOML takes one too).
#[test]
fn a_byte_order_mark_is_skipped() {
    let out = snakectl(&["solve", "-"], &format!("\u{feff}{ARM}"));
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(json(&out)["theta"].as_array().unwrap().len(), 4);
}
