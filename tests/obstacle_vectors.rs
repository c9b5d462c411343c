//! The world's exact link-to-obstacle distance against reference answers worked out outside the
//! project: overall (metric 3) among circular obstacles, `tests/data/vectors/obstacles_*` (their
//! README says how they were found).
//!
//! Each reference's best clear optimum must be clear by this crate's own measure, with the
//! least clearance the reference reports (to 1e-9 m) and its tip on target; and the optimum
//! the overall solver finds without the obstacles must collide, as the reference says it does:
//! so the geometry agrees with an independent computation on both sides of contact. The vectors
//! are part of the repository: a missing or incomplete set fails the test.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use serde::Deserialize;
use snakectl::chain::{Chain, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::world::{Obstacle, Shape, World};

#[derive(Deserialize)]
struct ProblemFile {
    links: Vec<f64>,
    base: [f64; 3],
    theta0: Vec<f64>,
    target: [f64; 2],
    obstacles: Vec<ObstacleFile>,
    link_radius_m: f64,
    clearance_m: f64,
}

#[derive(Deserialize)]
struct ObstacleFile {
    circle: CircleFile,
}

#[derive(Deserialize)]
struct CircleFile {
    center: [f64; 2],
    radius: f64,
}

#[derive(Deserialize)]
struct ExpectedFile {
    theta: Vec<f64>,
    metric3: f64,
    min_clearance_m: f64,
    unconstrained_metric3: f64,
    unconstrained_collides: bool,
}

/// Fewest obstacle vectors the directory must hold.
const MIN_VECTORS: usize = 7;

fn problems() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/vectors");
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| {
        panic!(
            "reference vectors missing: cannot read {}: {e}",
            dir.display()
        )
    });
    let mut names: Vec<PathBuf> = entries
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            name.starts_with("obstacles_") && name.ends_with(".problem.json")
        })
        .collect();
    names.sort();
    assert!(
        names.len() >= MIN_VECTORS,
        "{} holds {} obstacle vectors; at least {MIN_VECTORS} expected",
        dir.display(),
        names.len()
    );
    names
}

fn expected_path(problem: &Path) -> PathBuf {
    let name = problem.file_name().unwrap().to_string_lossy();
    problem.with_file_name(name.replace(".problem.json", ".expected.json"))
}

fn load(path: &Path) -> (ProblemFile, ExpectedFile) {
    let problem = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let expected = std::fs::read_to_string(expected_path(path))
        .unwrap_or_else(|e| panic!("{} has no expected answer: {e}", path.display()));
    (problem, serde_json::from_str(&expected).unwrap())
}

fn chain_and_world(p: &ProblemFile) -> (Chain, World) {
    let chain = Chain::new(
        p.links.clone(),
        Vec2::new(p.base[0], p.base[1]),
        p.base[2],
        Vec::new(),
    )
    .unwrap();
    let obstacles = p
        .obstacles
        .iter()
        .enumerate()
        .map(|(i, o)| Obstacle {
            id: format!("c{i}"),
            shape: Shape::Circle {
                center: Vec2::new(o.circle.center[0], o.circle.center[1]),
                radius_m: o.circle.radius,
            },
        })
        .collect();
    (
        chain,
        World::new(p.link_radius_m, p.clearance_m, obstacles).unwrap(),
    )
}

fn metric3(theta: &[f64], theta0: &[f64]) -> f64 {
    theta
        .iter()
        .zip(theta0)
        .map(|(a, b)| (a - b) * (a - b))
        .sum()
}

#[test]
fn every_reference_optimum_is_clear_by_the_worlds_exact_distance() {
    for path in problems() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let (problem, expected) = load(&path);
        let (chain, world) = chain_and_world(&problem);
        let target = Vec2::new(problem.target[0], problem.target[1]);
        assert!(
            (chain.tip(&expected.theta) - target).norm() < 1e-9,
            "{name}"
        );
        let rel =
            (metric3(&expected.theta, &problem.theta0) - expected.metric3).abs() / expected.metric3;
        assert!(
            rel < 1e-9,
            "{name}: metric 3 of the reference pose, rel {rel:.1e}"
        );
        let worst = world.pose_clearance(&chain, &expected.theta).unwrap();
        println!(
            "{name}: least clearance {:.3e} m (reference {:.3e}), link {} and {}",
            worst.clearance_m,
            expected.min_clearance_m,
            worst.link,
            worst.id(&world)
        );
        assert!(
            worst.clearance_m >= world.clearance_m() - 1e-9,
            "{name}: the reference optimum is not clear by our measure: {:.3e} m at link {}",
            worst.clearance_m,
            worst.link
        );
        assert!(
            (worst.clearance_m - expected.min_clearance_m).abs() < 1e-9,
            "{name}: least clearance {:.15e}, the reference says {:.15e}",
            worst.clearance_m,
            expected.min_clearance_m
        );
    }
}

#[test]
fn the_optimum_without_obstacles_collides_where_the_reference_says_it_does() {
    let mut solver = Overall::new(OverallOptions::default());
    for path in problems() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let (problem, expected) = load(&path);
        let (chain, world) = chain_and_world(&problem);
        let target = Vec2::new(problem.target[0], problem.target[1]);
        let mut free = vec![0.0; chain.len()];
        let outcome = solver.solve_cold(&chain, &problem.theta0, target, &mut free);
        assert!(outcome.converged, "{name}: {outcome:?}");
        let m3 = metric3(&free, &problem.theta0);
        let rel = (m3 - expected.unconstrained_metric3).abs() / expected.unconstrained_metric3;
        assert!(
            rel < 1e-9,
            "{name}: the optimum without obstacles {m3:.15e}, the reference's {:.15e}",
            expected.unconstrained_metric3
        );
        let worst = world.pose_clearance(&chain, &free).unwrap();
        assert_eq!(
            worst.clearance_m < world.clearance_m(),
            expected.unconstrained_collides,
            "{name}: least clearance of the free optimum {:.3e} m",
            worst.clearance_m
        );
        // The obstacles cost something: the clear optimum is worse than the free one.
        assert!(expected.metric3 > m3, "{name}");
    }
}

#[test]
fn the_cold_solve_among_the_obstacles_reaches_every_reference_optimum() {
    let mut solver = Overall::new(OverallOptions::default());
    let mut failures = Vec::new();
    for path in problems() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let (problem, expected) = load(&path);
        let (chain, world) = chain_and_world(&problem);
        let cm = world.clearance_m();
        let target = Vec2::new(problem.target[0], problem.target[1]);
        solver.set_world(Some(world.clone()));
        let mut out = vec![0.0; chain.len()];
        let t = std::time::Instant::now();
        let outcome = solver.solve_cold(&chain, &problem.theta0, target, &mut out);
        let elapsed = t.elapsed();
        let m3 = metric3(&out, &problem.theta0);
        let rel = (m3 - expected.metric3) / expected.metric3;
        // Independent of the solver's own report: the exact clearance and the tip.
        let least = world.pose_clearance(&chain, &out).unwrap().clearance_m;
        let tip = (chain.tip(&out) - target).norm();
        println!(
            "{name}: metric 3 {m3:.12e} (reference {:.12e}, rel {rel:+.1e}), clearance {least:.3e}, \
             tip {tip:.1e}, {} iterations, {elapsed:?}",
            expected.metric3, outcome.iterations
        );
        assert_eq!(solver.last_clearance(), Some(least), "{name}");
        let ok = outcome.converged && tip <= 1e-9 && least >= cm - 1e-9 && rel <= 1e-6;
        if !ok {
            failures.push(format!(
                "{name}: {outcome:?}, rel {rel:.2e}, clearance {least:.3e}"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
