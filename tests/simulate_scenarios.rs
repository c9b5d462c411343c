//! Scenarios end to end: the analytic tractrix at scenario level, the shipped scenarios (exact
//! lengths, convergence, the overall optimum no worse than the sequential answer, motion
//! concentrated near the pulled end), and scenario files with errors naming their field.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use snakectl::rope::Objective;
use snakectl::scenario::table::Table;
use snakectl::scenario::{rotations, Run, Scenario, StrategySpec};

fn shipped() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

/// A straight rope on the x axis, its end at the origin pulled along +y in 50 steps: the tail
/// of the pulled link traces y = L ln((L + sqrt(L^2 - x^2)) / x) - sqrt(L^2 - x^2).
#[test]
fn straight_rope_pulled_sideways_traces_the_analytic_tractrix() {
    let text = r#"
        links = 20
        [curve]
        kind = "line"
        from_m = [2.0, 0.0]
        to_m = [0.0, 0.0]
        [pull]
        kind = "straight"
        displacement_m = [0.0, 0.5]
        steps = [50]
        [[strategy]]
        kind = "tractrix"
    "#;
    let s = Scenario::from_toml(text, "inline.toml", Path::new(".")).unwrap();
    let n = s.links.len();
    let len = s.links[n - 1];
    assert!((len - 0.1).abs() < 1e-12);
    let runs = s.run();
    assert_eq!(runs[0].frames.len(), 51);
    for (k, f) in runs[0].frames.iter().enumerate().skip(1) {
        let (x, y) = (f[n - 1].x, f[n - 1].y);
        let w = (len * len - x * x).sqrt();
        let analytic = len * ((len + w) / x).ln() - w;
        assert!((y - analytic).abs() < 1e-9, "step {k}: {y} vs {analytic}");
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Path length travelled by every point over the run (sum of its displacements per step).
fn path_lengths(run: &Run) -> Vec<f64> {
    let n = run.frames[0].len();
    (0..n)
        .map(|i| {
            run.frames
                .windows(2)
                .map(|w| (w[1][i] - w[0][i]).norm())
                .sum()
        })
        .collect()
}

/// (mean displacement of the free-end third / displacement of the pulled end,
///  mean rotation of the free-end third / largest rotation).
fn concentration(run: &Run) -> (f64, f64) {
    let old = &run.frames[0];
    let new = run.last();
    let n = old.len() - 1;
    let disp: Vec<f64> = (0..=n).map(|i| (new[i] - old[i]).norm()).collect();
    let d = mean(&disp[..n / 3]) / disp[n];
    let rot: Vec<f64> = rotations(old, new).iter().map(|r| r.1.abs()).collect();
    let peak = rot.iter().cloned().fold(0.0, f64::max);
    (d, mean(&rot[..rot.len() / 3]) / peak)
}

#[test]
fn shipped_scenarios_run_exactly_and_concentrate_near_the_pulled_end() {
    let files = shipped();
    assert!(files.len() >= 4, "{files:?}");
    for file in files {
        let s = Scenario::load(&file).unwrap();
        let name = file.display();
        let runs = s.run();
        assert_eq!(runs.len(), s.strategies.len() * s.steps.len());
        for r in &runs {
            assert!(r.converged, "{name}: {}", r.label());
            assert!(r.length_residual <= 1e-12, "{name}: {}", r.label());
            let (d, rot) = concentration(r);
            // Every strategy: the free end's third moves less than the pulled end.
            assert!(d < 1.0, "{name}: {} displacement ratio {d}", r.label());
            if let StrategySpec::Sequential(_) = r.strategy {
                // Each tail travels no farther than its head: path lengths fall from the pulled
                // end to the free end, and the free end's third turns less than the peak.
                let p = path_lengths(r);
                for i in 0..p.len() - 1 {
                    assert!(p[i] <= p[i + 1] + 1e-12, "{name}: {} point {i}", r.label());
                }
                assert!(rot < 0.75, "{name}: {} rotation ratio {rot}", r.label());
            }
        }
        // Single step: the overall optimum is no worse than either sequential answer under its
        // own objective.
        let single: Vec<&Run> = runs.iter().filter(|r| r.steps == 1).collect();
        for o in &single {
            let StrategySpec::Overall(objective) = o.strategy else {
                continue;
            };
            for q in &single {
                if let StrategySpec::Sequential(_) = q.strategy {
                    let (a, b) = (objective.value(&o.metrics), objective.value(&q.metrics));
                    assert!(a <= b, "{name}: {} {a} > {} {b}", o.label(), q.label());
                }
            }
        }
        let table = Table::new(&s.title, &runs);
        assert_eq!(table.rows.len(), 5);
        assert_eq!(table.csv().lines().count(), 6);
        assert_eq!(table.markdown().lines().count(), 9);
        let json: serde_json::Value = serde_json::from_str(&table.json().unwrap()).unwrap();
        assert_eq!(json["columns"].as_array().unwrap().len(), runs.len());
    }
}

/// The largest link count a scenario allows, 100000, splits every shipped curve (the straight
/// line among them) into that many equal chords from end to end (with a single step, which keeps
/// the stored configurations under the cap).
#[test]
fn shipped_curves_split_at_the_largest_link_count() {
    for file in shipped() {
        let text = std::fs::read_to_string(&file).unwrap();
        let name = file.display();
        let at = text.find("\nlinks = ").expect("a links line") + 1;
        let eol = at + text[at..].find('\n').unwrap();
        let text = format!("{}links = 100000{}", &text[..at], &text[eol..]);
        let at = text.find("\nsteps = ").expect("a steps line") + 1;
        let eol = at + text[at..].find('\n').unwrap();
        let text = format!("{}steps = [1]{}", &text[..at], &text[eol..]);
        let s = Scenario::from_toml(&text, &name.to_string(), file.parent().unwrap())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(s.links.len(), 100_000, "{name}");
        let (mn, mx) = s
            .links
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
        assert!(mx - mn < 1e-10, "{name}: chords {mn} .. {mx}");
    }
}

/// Every objective in one scenario: each overall optimum is the best of all columns under its
/// own objective, single step.
#[test]
fn each_objective_wins_under_itself() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/objectives.toml");
    let s = Scenario::load(&file).unwrap();
    let runs: Vec<Run> = s.strategies.iter().map(|&st| s.run_one(st, 1)).collect();
    for r in &runs {
        let StrategySpec::Overall(objective) = r.strategy else {
            panic!("overall only");
        };
        let own = objective.value(&r.metrics);
        for other in &runs {
            let v = objective.value(&other.metrics);
            assert!(
                own <= v * (1.0 + 1e-9),
                "{:?}: {own} vs {} {v}",
                objective,
                other.label()
            );
        }
    }
    assert!(runs
        .iter()
        .any(|r| r.strategy == StrategySpec::Overall(Objective::M2)));
}

const GOOD: &str = r#"
title = "t"
links = 10
[curve]
kind = "sine"
x_range_m = [0.0, 1.0]
amplitude_m = 0.1
wavelength_m = 0.5
[pull]
kind = "straight"
displacement_m = [0.0, 0.3]
steps = [1, 5]
[[strategy]]
kind = "tractrix"
[[strategy]]
kind = "overall"
objective = "m2"
"#;

#[test]
fn scenario_errors_name_the_file_and_the_field() {
    assert!(Scenario::from_toml(GOOD, "good.toml", Path::new(".")).is_ok());
    let cases: Vec<(String, &str)> = vec![
        (GOOD.replace("links = 10", "links = 0"), "links"),
        (
            GOOD.replace("links = 10", "links = 10\ncolour = 1"),
            "colour",
        ),
        (
            GOOD.replace("amplitude_m = 0.1", "amplitude = 0.1"),
            "curve.amplitude",
        ),
        (GOOD.replace("amplitude_m = 0.1\n", ""), "curve.amplitude_m"),
        (
            GOOD.replace("wavelength_m = 0.5", "wavelength_m = -0.5"),
            "curve.wavelength_m",
        ),
        (
            GOOD.replace("kind = \"sine\"", "kind = \"spiral\""),
            "curve.kind",
        ),
        (
            GOOD.replace("wavelength_m = 0.5", "wavelength_m = 0.5\nradius_m = 1.0"),
            "curve.radius_m",
        ),
        (GOOD.replace("[0.0, 1.0]", "[1.0, 1.0]"), "curve.x_range_m"),
        (GOOD.replace("[0.0, 0.3]", "[0.0]"), "pull.displacement_m"),
        (
            GOOD.replace("steps = [1, 5]", "steps = [1, 0]"),
            "pull.steps[1]",
        ),
        (GOOD.replace("steps = [1, 5]", "steps = []"), "pull.steps"),
        (
            GOOD.replace("kind = \"straight\"", "kind = \"zigzag\""),
            "pull.kind",
        ),
        (
            GOOD.replace("kind = \"straight\"", "kind = \"sine\""),
            "pull.amplitude_m",
        ),
        (
            GOOD.replace("objective = \"m2\"", "objective = \"m9\""),
            "strategy[1].objective",
        ),
        (
            GOOD.replace("objective = \"m2\"", "objective = \"m3\""),
            "strategy[1].companion_weight",
        ),
        (
            GOOD.replace(
                "objective = \"m2\"",
                "objective = \"m1\"\ncompanion_weight = 1.0",
            ),
            "strategy[1].companion_weight",
        ),
        (
            GOOD.replace(
                "kind = \"tractrix\"",
                "kind = \"tractrix\"\nobjective = \"m1\"",
            ),
            "strategy[0].objective",
        ),
        (
            GOOD.replace("kind = \"tractrix\"", "kind = \"fabrik\""),
            "strategy[0].kind",
        ),
        (
            GOOD.replace("kind = \"tractrix\"", "kind = \"tractrix\"\nspeed = 2"),
            "strategy[0].speed",
        ),
        (
            GOOD.replace("kind = \"sine\"", "kind = \"sine\"\npulled = \"middle\""),
            "curve.pulled",
        ),
        (GOOD.replace("links = 10", "links = \"ten\""), "links"),
    ];
    for (text, field) in cases {
        let e = Scenario::from_toml(&text, "bad.toml", Path::new(".")).unwrap_err();
        assert_eq!(e.field, field, "{e}");
        let shown = e.to_string();
        assert!(shown.starts_with("bad.toml:"), "{shown}");
        assert!(!shown.contains('\n'), "one line: {shown}");
    }
}

#[test]
fn parametric_and_polyline_curves_report_their_errors() {
    let dir = tempfile::tempdir().unwrap();
    let parametric = GOOD.replace(
        "kind = \"sine\"\nx_range_m = [0.0, 1.0]\namplitude_m = 0.1\nwavelength_m = 0.5",
        "kind = \"parametric\"\nx = \"t\"\ny = \"0.2*sin(t\"\nt_range = [0.0, 1.0]",
    );
    let e = Scenario::from_toml(&parametric, "p.toml", dir.path()).unwrap_err();
    assert_eq!(e.field, "curve.y", "{e}");
    assert!(e.message.contains("character"), "{e}");
    // A character beyond ASCII is shown as itself, not as its first byte.
    let greek = parametric.replace("0.2*sin(t", "\u{3c0}*t");
    let e = Scenario::from_toml(&greek, "p.toml", dir.path()).unwrap_err();
    assert_eq!(e.field, "curve.y", "{e}");
    assert!(e.message.contains("unexpected '\u{3c0}'"), "{e}");

    let polyline = GOOD.replace(
        "kind = \"sine\"\nx_range_m = [0.0, 1.0]\namplitude_m = 0.1\nwavelength_m = 0.5",
        "kind = \"polyline\"\nfile = \"shape.csv\"",
    );
    std::fs::write(dir.path().join("shape.csv"), "x,y\n0,0\n1,0\n1,oops\n").unwrap();
    let e = Scenario::from_toml(&polyline, "p.toml", dir.path()).unwrap_err();
    assert_eq!((&*e.file, &*e.field), ("p.toml", "curve.file"), "{e}");
    assert!(
        e.message.ends_with("shape.csv:4: `oops` is not a number"),
        "{e}"
    );
    std::fs::write(dir.path().join("shape.csv"), "x,y\n0,0\n1,0\n1,1\n").unwrap();
    let s = Scenario::from_toml(&polyline, "p.toml", dir.path()).unwrap();
    assert_eq!(s.points.len(), 11);
    assert_eq!(s.points[10], snakectl::chain::Vec2::new(1.0, 1.0));
    let missing = polyline.replace("shape.csv", "nowhere.csv");
    let e = Scenario::from_toml(&missing, "p.toml", dir.path()).unwrap_err();
    assert_eq!((&*e.file, &*e.field), ("p.toml", "curve.file"), "{e}");
    assert!(e.message.contains("nowhere.csv: cannot read it"), "{e}");
}

/// What a scenario may ask is bounded: the configurations it keeps (links × steps × strategies,
/// which grew to an allocation failure), repeated step counts and strategies, the companion
/// weight; a file that is no scenario says so under its own table's name.
#[test]
fn scenario_bounds_refuse_by_field_with_the_numbers() {
    use snakectl::scenario::{stored_points, MAX_STORED_POINTS};
    let big = GOOD
        .replace("links = 10", "links = 4000")
        .replace("steps = [1, 5]", "steps = [20000]");
    let e = Scenario::from_toml(&big, "bad.toml", Path::new(".")).unwrap_err();
    assert_eq!(e.field, "links, pull.steps", "{e}");
    let kept = stored_points(4000, &[20000], 2).to_string();
    assert!(e.message.contains(&kept), "{e}");
    assert!(e.message.contains(&MAX_STORED_POINTS.to_string()), "{e}");
    // At the bounds of each field alone: 100000 links with one step, 100000 steps with few links.
    let wide = GOOD
        .replace("links = 10", "links = 100000")
        .replace("steps = [1, 5]", "steps = [1]");
    let s = Scenario::from_toml(&wide, "ok.toml", Path::new(".")).unwrap();
    assert_eq!(s.links.len(), 100_000);
    let long = GOOD
        .replace("links = 10", "links = 4")
        .replace("steps = [1, 5]", "steps = [100000]");
    assert!(Scenario::from_toml(&long, "ok.toml", Path::new(".")).is_ok());
    assert_eq!(stored_points(usize::MAX, &[usize::MAX], 3), usize::MAX);

    let cases: Vec<(String, &str)> = vec![
        (
            GOOD.replace("steps = [1, 5]", "steps = [3, 3]"),
            "pull.steps[1]",
        ),
        (
            GOOD.replace(
                "objective = \"m2\"",
                "objective = \"m2\"\n[[strategy]]\nkind = \"tractrix\"",
            ),
            "strategy[2]",
        ),
        (
            GOOD.replace(
                "objective = \"m2\"",
                "objective = \"m3\"\ncompanion_weight = 1e-300",
            ),
            "strategy[1].companion_weight",
        ),
        (
            GOOD.replace(
                "objective = \"m2\"",
                "objective = \"m3\"\ncompanion_weight = 1e9",
            ),
            "strategy[1].companion_weight",
        ),
        ("[arm]\nname = \"x\"\n".to_string(), "arm"),
        (format!("{GOOD}[arm]\nname = \"x\"\n"), "arm"),
    ];
    for (text, field) in cases {
        let e = Scenario::from_toml(&text, "bad.toml", Path::new(".")).unwrap_err();
        assert_eq!(e.field, field, "{e}");
        assert!(!e.to_string().contains('\n'), "one line: {e}");
    }
    let e = Scenario::from_toml("[arm]\nname = \"x\"\n", "arm.toml", Path::new(".")).unwrap_err();
    assert!(e.message.contains("is this a scenario file?"), "{e}");
    let tiny = GOOD.replace(
        "objective = \"m2\"",
        "objective = \"m3\"\ncompanion_weight = 1e-300",
    );
    let e = Scenario::from_toml(&tiny, "bad.toml", Path::new(".")).unwrap_err();
    assert!(e.message.contains("1e-300") && e.message.len() < 80, "{e}");
}
