//! The README's examples run and say what the README says they do.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod cli_support;

use cli_support::snakectl;

fn readme() -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap()
}

/// The first fenced block of `lang` after `marker`.
fn block(text: &str, marker: &str, lang: &str) -> String {
    let start = text.find(marker).expect("marker present");
    let rest = &text[start..];
    let open = rest.find(&format!("```{lang}\n")).unwrap() + lang.len() + 4;
    let close = rest[open..].find("```").unwrap();
    rest[open..open + close].to_string()
}

fn run_solve(stdin: &str) -> std::process::Output {
    snakectl(&["solve", "-"], stdin)
}

#[test]
fn the_problem_example_solves() {
    let problem = block(&readme(), "<!-- readme-example: problem -->", "json");
    let out = run_solve(&problem);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let answer: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(answer["strategy"], "overall");
    assert_eq!(answer["converged"], true);
    assert_eq!(answer["within_limits"], true);
    assert!(answer["tip_error"].as_f64().unwrap() < 1e-9);
}

#[test]
fn the_error_example_prints_what_the_readme_shows() {
    let console = block(&readme(), "Exit codes:", "console");
    let mut lines = console.lines();
    let command = lines.next().unwrap();
    let expected = lines.next().unwrap();
    let json = command.split('\'').nth(1).unwrap();
    let out = run_solve(json);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(String::from_utf8_lossy(&out.stderr).trim_end(), expected);
}
