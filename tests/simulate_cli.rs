//! `snakectl simulate` as a user runs it: the files it writes, exit codes and one-line errors
//! naming the file and the field.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::{Command, Output};

fn snakectl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

/// `snakectl simulate` of `scenario` into `out`, SVG figures only.
fn simulate_svg(scenario: &std::path::Path, out: &std::path::Path) -> Output {
    snakectl(&[
        "simulate",
        "--scenario",
        scenario.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-png",
    ])
}

/// Asserts that a run exited 0, showing its error output if not.
fn succeeded(o: &Output) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
}

#[test]
fn a_scenario_writes_figures_and_tables() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("straight");
    let o = snakectl(&[
        "simulate",
        "--scenario",
        "scenarios/straight_sideways.toml",
        "--out",
        out.to_str().unwrap(),
    ]);
    succeeded(&o);
    for name in [
        "motion.svg",
        "motion.png",
        "rotations.svg",
        "rotations.png",
        "metrics.csv",
        "metrics.md",
        "metrics.json",
    ] {
        let bytes = std::fs::read(out.join(name)).unwrap();
        assert!(bytes.len() > 100, "{name}");
        if name.ends_with(".png") {
            assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{name}");
        }
        if name.ends_with(".svg") {
            assert!(String::from_utf8(bytes).unwrap().contains("<svg"), "{name}");
        }
    }
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(
        header.starts_with("metric,unit,\"sequential tractrix, K=1\""),
        "{header}"
    );
    assert_eq!(csv.lines().count(), 6);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("overall m2, K=20"), "{stdout}");
}

#[test]
fn bad_scenarios_exit_two_naming_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/sine.toml"),
    )
    .unwrap()
    .replace("amplitude_m = 0.1", "amplitude_m = \"big\"");
    std::fs::write(&file, text).unwrap();
    let o = simulate_svg(&file, &dir.path().join("o"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml") && err.contains("curve"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let o = snakectl(&["simulate", "--scenario", "nowhere.toml", "--out", "x"]);
    assert_eq!(o.status.code(), Some(2));
}

/// A scenario that is not valid TOML is refused on one line naming the file, line and column,
/// as a config file is.
#[test]
fn a_syntax_error_names_its_line_and_column_on_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/sine.toml"),
    )
    .unwrap();
    let line = 1 + text.lines().position(|l| l == "amplitude_m = 0.1").unwrap();
    std::fs::write(
        &file,
        text.replace("amplitude_m = 0.1", "amplitude_m = [0.1,, 0.2]"),
    )
    .unwrap();
    let o = simulate_svg(&file, &dir.path().join("o"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    // The second comma, after `amplitude_m = [0.1,`.
    let at = format!("bad.toml:{line}:20: curve.amplitude_m: invalid array");
    assert!(err.contains(&at), "not `{at}`: {err}");
}

/// An `--out` that cannot be made is refused before the scenario is computed, naming `--out`.
#[test]
fn an_unwritable_out_fails_before_the_computation() {
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("a-file");
    std::fs::write(&blocker, b"").unwrap();
    let out = blocker.join("o");
    let o = snakectl(&[
        "simulate",
        "--scenario",
        "scenarios/straight_sideways.toml",
        "--out",
        out.to_str().unwrap(),
        "--no-png",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--out"), "{err}");
    assert!(o.stdout.is_empty());
}

/// A scenario that would keep too many configurations exits 2 naming the fields and the cap.
#[test]
fn an_oversized_scenario_exits_two_naming_the_cap() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("big.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/straight_sideways.toml"),
    )
    .unwrap()
    .replace("links = 20", "links = 4000")
    .replace("steps = [1, 20]", "steps = [20000]");
    std::fs::write(&file, text).unwrap();
    let o = simulate_svg(&file, &dir.path().join("o"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("links, pull.steps") && err.contains("2000000"),
        "{err}"
    );
    assert!(!dir.path().join("o").exists());
}

/// A title the figures cannot show is refused before anything is written, naming `title`: a
/// control character (not allowed in the SVG's XML) or more than 200 characters (laying out a
/// long title takes minutes). A title of 200 characters is fine.
#[test]
fn a_bad_title_exits_two_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/straight_sideways.toml"),
    )
    .unwrap()
    .replace("links = 20", "links = 4")
    .replace("steps = [1, 20]", "steps = [1]");
    let given = "title = \"Straight rope pulled sideways\"";
    assert!(base.contains(given), "{base}");
    let titled = |title: &str| base.replace(given, &format!("title = {title}"));
    let long = "t".repeat(201);
    for (title, says) in [
        ("\"x\\u0001y\"", "control character '\\u{1}'"),
        ("\"tab\\there\"", "control character '\\t'"),
        (
            &format!("\"{long}\"") as &str,
            "201 characters, at most 200",
        ),
    ] {
        let file = dir.path().join("bad.toml");
        std::fs::write(&file, titled(title)).unwrap();
        let out = dir.path().join("o");
        let o = simulate_svg(&file, &out);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{title}: {err}");
        assert!(
            err.contains(&format!("{}: title: ", file.display())) && err.contains(says),
            "{title}: {err}"
        );
        assert!(!out.exists(), "{title}");
    }
    let file = dir.path().join("ok.toml");
    std::fs::write(&file, titled(&format!("\"{}\"", "t".repeat(200)))).unwrap();
    let out = dir.path().join("ok");
    let o = simulate_svg(&file, &out);
    succeeded(&o);
}

/// A polyline CSV is read by the rule of a path file: only its first line may be a header, so
/// rows in the wrong format are an error naming the scenario, `curve.file`, the CSV and the
/// line, never silently dropped from the curve's start.
#[test]
fn a_polyline_row_in_the_wrong_format_is_refused_by_line() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("pm.toml");
    std::fs::write(
        &scenario,
        "title = \"t\"\nlinks = 10\n[curve]\nkind = \"polyline\"\nfile = \"lead.csv\"\n\
         [pull]\nkind = \"straight\"\ndisplacement_m = [0.0, 0.5]\nsteps = [1]\n\
         [[strategy]]\nkind = \"tractrix\"\n",
    )
    .unwrap();
    let csv = dir.path().join("lead.csv");
    let run = |rows: &str| {
        std::fs::write(&csv, rows).unwrap();
        simulate_svg(&scenario, &dir.path().join("o"))
    };
    for (rows, says) in [
        (
            "0;0\n0.2;0.1\n0.5,0.3\n1,0\n",
            ":2: expected two fields `x,y`, got 1",
        ),
        (
            "0;0\n0.5;0.3\n1;0\n",
            ":2: expected two fields `x,y`, got 1",
        ),
        ("x,y\n0,0\n1,oops\n", ":3: `oops` is not a number"),
    ] {
        let o = run(rows);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{rows:?}: {err}");
        let want = format!(
            "{}: curve.file: {}{says}",
            scenario.display(),
            csv.display()
        );
        assert!(err.contains(&want), "{rows:?}: {err}\nwanted {want}");
    }
    // A header, a comment and the rows: the curve starts at the first row.
    let o = run("x,y\n# the shape\n0,0\n0.5,0.3\n1,0\n");
    succeeded(&o);
}

/// An `--out` that is not a directory (`/dev/null`, a file) is refused as bad input, as
/// `plot` refuses it, before the scenario is read or run.
#[test]
fn an_out_that_is_not_a_directory_exits_two() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"keep").unwrap();
    for (out, what) in [
        ("/dev/null", "a device or other special file"),
        (file.to_str().unwrap(), "a file"),
    ] {
        let o = snakectl(&[
            "simulate",
            "--scenario",
            "scenarios/straight_sideways.toml",
            "--out",
            out,
            "--no-png",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{out}: {err}");
        assert!(
            err.contains(&format!("--out {out}: not a directory (it is {what}")),
            "{err}"
        );
        assert!(o.stdout.is_empty());
    }
    assert_eq!(std::fs::read(&file).unwrap(), b"keep");
}
