//! The documentation's examples run and say what the text around them says, and its links lead
//! somewhere: the README and each chapter under `docs/`, every example read from the file where
//! it lives.
//!
//! - The problem and the error of `snakectl solve` run as shown.
//! - Every JSON and TOML example parses; a `[zenoh]`, `[foxglove]`, `[bus]` or `[control]` table
//!   is a valid config table, and a scenario is a valid scenario that runs.
//! - Every `snakectl` command shown (in a code block, or inline) names a real subcommand and only
//!   options that subcommand has; every `cargo` command names tests, benches, examples and
//!   features that exist.
//! - Every relative link and image resolves from the file that holds it, anchors included.
//!
//! [`DOCS`] lists the files with the least each holds, so a file is never skipped and none passes
//! on nothing found.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use cli_support::snakectl;
use snakectl::config::Config;
use snakectl::scenario::Scenario;

/// One Markdown file of the documentation and the least it holds.
struct Doc {
    /// Relative to the repository root.
    path: &'static str,
    /// Fenced code blocks.
    blocks: usize,
    /// `snakectl` and `cargo` commands, in code blocks and inline.
    commands: usize,
    /// Relative links and images.
    links: usize,
}

/// Every Markdown file of the documentation. A chapter added under `docs/` must be added here
/// (`every_chapter_is_listed` says so).
const DOCS: &[Doc] = &[
    // file, least: code blocks, commands, relative links
    doc("README.md", 1, 25, 23),
    doc("docs/BENCHMARKS.md", 0, 9, 9),
    doc("docs/CLIENTS.md", 2, 30, 3),
    doc("docs/CONFIG.md", 4, 1, 2),
    doc("docs/CONNECT.md", 0, 3, 0),
    doc("docs/DAEMON.md", 3, 3, 5),
    doc("docs/DEMO.md", 1, 6, 2),
    doc("docs/FAULTS.md", 0, 1, 1),
    doc("docs/FLEXIBLE-OBJECTS.md", 2, 6, 10),
    doc("docs/FOXGLOVE.md", 4, 6, 3),
    doc("docs/HARDWARE.md", 4, 14, 0),
    doc("docs/PROTOCOL.md", 2, 2, 3),
    doc("docs/ROS2.md", 5, 5, 3),
    doc("docs/RECORDING.md", 4, 5, 3),
    doc("docs/SIMULATOR.md", 2, 6, 2),
    doc("docs/SOLVE.md", 3, 5, 3),
    doc("docs/STRATEGIES.md", 0, 3, 0),
    doc("docs/TELEOP.md", 2, 6, 1),
    doc("docs/TESTING.md", 0, 8, 2),
    doc("docs/WORLD.md", 2, 9, 7),
    doc("docs/ZENOH.md", 5, 13, 5),
];

const fn doc(path: &'static str, blocks: usize, commands: usize, links: usize) -> Doc {
    Doc {
        path,
        blocks,
        commands,
        links,
    }
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(path: &str) -> String {
    std::fs::read_to_string(root().join(path)).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// A fenced code block: its language (empty when none) and its text.
struct Block {
    lang: String,
    text: String,
}

/// The fenced code blocks of a Markdown text, and the text with them blanked out (line for line,
/// so that what is left is prose).
fn split_blocks(text: &str) -> (Vec<Block>, String) {
    let mut blocks = Vec::new();
    let mut prose = String::new();
    let mut open: Option<Block> = None;
    for line in text.lines() {
        let fence = line.trim_start().strip_prefix("```");
        match (&mut open, fence) {
            (None, Some(lang)) => {
                open = Some(Block {
                    lang: lang.trim().to_string(),
                    text: String::new(),
                })
            }
            (Some(_), Some(_)) => blocks.push(open.take().unwrap()),
            (Some(block), None) => {
                block.text.push_str(line.trim_start());
                block.text.push('\n');
            }
            (None, None) => prose.push_str(line),
        }
        prose.push('\n');
    }
    assert!(open.is_none(), "a code block is never closed");
    (blocks, prose)
}

/// The inline code spans of prose (`` `a` ``, ``` `` `b` `` ```), and the prose without them.
fn split_spans(prose: &str) -> (Vec<String>, String) {
    let mut spans = Vec::new();
    let mut rest = String::new();
    let mut s = prose;
    while let Some(start) = s.find('`') {
        rest.push_str(&s[..start]);
        let ticks = s[start..].len() - s[start..].trim_start_matches('`').len();
        let body = &s[start + ticks..];
        // The closing run has exactly as many backticks.
        let mut at = 0;
        let close = loop {
            match body[at..].find(&"`".repeat(ticks)) {
                None => break None,
                Some(i) => {
                    let i = at + i;
                    let run = body[i..].len() - body[i..].trim_start_matches('`').len();
                    if run == ticks {
                        break Some(i);
                    }
                    at = i + run;
                }
            }
        };
        match close {
            Some(end) => {
                spans.push(body[..end].trim().replace('\n', " "));
                s = &body[end + ticks..];
            }
            None => {
                rest.push_str(&s[start..start + ticks]);
                s = body;
            }
        }
    }
    rest.push_str(s);
    (spans, rest)
}

/// The example after `marker` in `path`: the first fenced block of `lang` that follows it. The
/// marker must be in that file, once.
fn example(path: &str, marker: &str, lang: &str) -> String {
    let text = read(path);
    let found: Vec<&str> = DOCS
        .iter()
        .filter(|d| read(d.path).contains(marker))
        .map(|d| d.path)
        .collect();
    assert_eq!(
        text.matches(marker).count(),
        1,
        "{path} must hold `{marker}` once; the files that hold it: {found:?}"
    );
    let (blocks, _) = split_blocks(&text[text.find(marker).unwrap()..]);
    blocks
        .into_iter()
        .find(|b| b.lang == lang)
        .unwrap_or_else(|| panic!("{path}: no ```{lang} block after `{marker}`"))
        .text
}

fn run_solve(stdin: &str) -> std::process::Output {
    snakectl(&["solve", "-"], stdin)
}

#[test]
fn the_problem_example_solves() {
    let problem = example("docs/SOLVE.md", "<!-- example: problem -->", "json");
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
fn the_error_example_prints_what_the_chapter_shows() {
    let console = example("docs/SOLVE.md", "<!-- example: solve-error -->", "console");
    let mut lines = console.lines();
    let command = lines.next().unwrap();
    let expected = lines.next().unwrap();
    let json = command.split('\'').nth(1).unwrap();
    let out = run_solve(json);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(String::from_utf8_lossy(&out.stderr).trim_end(), expected);
}

#[test]
fn the_readme_opens_with_the_two_commands() {
    let readme = read("README.md");
    let (blocks, prose) = split_blocks(&readme);
    let before: Vec<&str> = prose
        .lines()
        .take_while(|l| l.trim().is_empty() || l.starts_with("# "))
        .collect();
    assert_eq!(
        before.iter().filter(|l| !l.trim().is_empty()).count(),
        1,
        "only the title comes before the commands"
    );
    let first = &blocks[0];
    assert_eq!(first.lang, "sh");
    let commands: Vec<&str> = first
        .text
        .lines()
        .map(|l| l.split('#').next().unwrap().trim())
        .collect();
    assert_eq!(
        commands,
        ["cargo run --release", "cargo test --workspace --release"]
    );
}

#[test]
fn every_chapter_is_listed() {
    let listed: BTreeSet<String> = DOCS.iter().map(|d| d.path.to_string()).collect();
    let mut found = BTreeSet::from(["README.md".to_string()]);
    for entry in std::fs::read_dir(root().join("docs")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".md") {
            found.insert(format!("docs/{name}"));
        }
    }
    assert_eq!(
        found, listed,
        "the chapters on disk and the ones DOCS lists"
    );
    // The README names every chapter.
    let readme = read("README.md");
    for doc in DOCS.iter().filter(|d| d.path != "README.md") {
        assert!(
            readme.contains(&format!("]({})", doc.path)),
            "the README does not link {}",
            doc.path
        );
    }
}

#[test]
fn json_and_toml_examples_parse() {
    let sim = read("config/sim.toml");
    let mut seen = BTreeMap::new();
    for doc in DOCS {
        let (blocks, _) = split_blocks(&read(doc.path));
        assert!(
            blocks.len() >= doc.blocks,
            "{}: {} code blocks, at least {} expected",
            doc.path,
            blocks.len(),
            doc.blocks
        );
        for block in blocks {
            let what = format!("{}: ```{} block\n{}", doc.path, block.lang, block.text);
            match block.lang.as_str() {
                "json" => {
                    serde_json::from_str::<serde_json::Value>(&block.text)
                        .unwrap_or_else(|e| panic!("{what}: {e}"));
                }
                "toml" => {
                    let table: toml::Table =
                        toml::from_str(&block.text).unwrap_or_else(|e| panic!("{what}: {e}"));
                    if table.contains_key("zenoh") || table.contains_key("foxglove") {
                        // A `[zenoh]` or `[foxglove]` table, checked as part of a whole config
                        // file.
                        let config = format!("{sim}\n{}", block.text);
                        Config::from_str(&config, root().join("config/sim.toml"))
                            .unwrap_or_else(|e| panic!("{what}: {e}"));
                    } else if table.contains_key("bus") {
                        // A `[bus]` table, checked in place of the shipped one.
                        let (head, rest) = sim.split_at(sim.find("[bus]").unwrap());
                        let tail = &rest[rest.find("[sim]").unwrap()..];
                        let config = format!("{head}{}\n{tail}", block.text);
                        Config::from_str(&config, root().join("config/sim.toml"))
                            .unwrap_or_else(|e| panic!("{what}: {e}"));
                    } else if table.contains_key("control") {
                        // A `[control]` table, checked in place of the shipped one.
                        let at = sim.find("[control]").unwrap();
                        let end = at + sim[at..].find("\n[").unwrap() + 1;
                        let config = format!("{}{}\n{}", &sim[..at], block.text, &sim[end..]);
                        Config::from_str(&config, root().join("config/sim.toml"))
                            .unwrap_or_else(|e| panic!("{what}: {e}"));
                    } else if table.contains_key("curve") {
                        let scenario =
                            Scenario::from_toml(&block.text, doc.path, &root().join("scenarios"))
                                .unwrap_or_else(|e| panic!("{what}: {e}"));
                        assert!(!scenario.run().is_empty(), "{what}: no runs");
                    } else {
                        panic!(
                            "{what}: neither a [zenoh], [foxglove], [bus] or [control] table nor a \
                             scenario; say how to check it"
                        );
                    }
                }
                _ => continue,
            }
            *seen.entry(block.lang).or_insert(0) += 1;
        }
    }
    assert_eq!(seen.get("json"), Some(&2), "{seen:?}");
    assert_eq!(seen.get("toml"), Some(&7), "{seen:?}");
}

/// A command the documentation shows: the file it is in, and its words.
struct Command {
    path: &'static str,
    words: Vec<String>,
}

/// The `snakectl` and `cargo` commands of one file: every line of an `sh` block, the `$ ` lines
/// of `console` and `text` blocks, and every inline code span that starts with a command; each
/// split at ` | `, `;` and `&`, comments and environment variables left out.
fn commands(doc: &'static Doc) -> Vec<Command> {
    let (blocks, prose) = split_blocks(&read(doc.path));
    let (spans, _) = split_spans(&prose);
    let mut lines: Vec<String> = spans;
    for block in blocks {
        let text = block.text.replace("\\\n", " ");
        for line in text.lines() {
            match block.lang.as_str() {
                // A synopsis goes on over lines that start with an option.
                "sh" if line.starts_with(['[', '-']) && !lines.is_empty() => {
                    let last = lines.len() - 1;
                    lines[last] = format!("{} {line}", lines[last]);
                }
                "sh" => lines.push(line.to_string()),
                "console" | "text" => {
                    if let Some(command) = line.strip_prefix("$ ") {
                        lines.push(command.to_string());
                    }
                }
                _ => {}
            }
        }
    }
    let mut out = Vec::new();
    for line in lines {
        let line = line.split(" #").next().unwrap();
        for part in line.split(" | ").flat_map(|p| p.split([';', '&'])) {
            let words: Vec<String> = part
                .split_whitespace()
                .skip_while(|w| w.contains('=') && !w.starts_with('-'))
                .map(str::to_string)
                .collect();
            let Some(first) = words.first() else { continue };
            if first == "snakectl" || first.ends_with("/snakectl") || first == "cargo" {
                out.push(Command {
                    path: doc.path,
                    words,
                });
            }
        }
    }
    out
}

/// The options a word list names: `--name`, from `--name`, `[--name`, `--name=value`.
fn options(words: &[String]) -> Vec<String> {
    words
        .iter()
        .map(|w| w.trim_start_matches('['))
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| w.split(['=', ']', ',']).next().unwrap().to_string())
        .collect()
}

/// Whether `help` lists `option` (`--speed` is not `--speed-limit`).
fn lists(help: &str, option: &str) -> bool {
    help.match_indices(option).any(|(i, _)| {
        !help[i + option.len()..]
            .chars()
            .next()
            .is_some_and(|c| c.is_alphanumeric() || c == '-' || c == '_')
    })
}

#[test]
fn every_command_shown_exists() {
    let features = read("Cargo.toml");
    // subcommand -> options the documentation gives it, with where
    let mut uses: BTreeMap<String, BTreeSet<(String, &str)>> = BTreeMap::new();
    for doc in DOCS {
        let found = commands(doc);
        assert!(
            found.len() >= doc.commands,
            "{}: {} commands, at least {} expected",
            doc.path,
            found.len(),
            doc.commands
        );
        for Command { path, words } in found {
            let shown = words.join(" ");
            let snakectl_args: Option<&[String]> = if words[0] == "cargo" {
                let named = |flag: &str| -> Vec<String> {
                    words
                        .windows(2)
                        .filter(|w| w[0] == flag)
                        .map(|w| w[1].clone())
                        .collect()
                };
                for name in named("--test") {
                    assert!(
                        root().join(format!("tests/{name}.rs")).exists(),
                        "{path}: `{shown}`: no tests/{name}.rs"
                    );
                }
                for name in named("--bench") {
                    assert!(
                        root().join(format!("benches/{name}.rs")).exists()
                            || root().join(format!("sim/benches/{name}.rs")).exists(),
                        "{path}: `{shown}`: no bench {name}"
                    );
                }
                for name in named("--example") {
                    assert!(
                        root().join(format!("examples/{name}.rs")).exists(),
                        "{path}: `{shown}`: no examples/{name}.rs"
                    );
                }
                for name in named("--features") {
                    assert!(
                        features.contains(&format!("\n{name} = ")),
                        "{path}: `{shown}`: no feature {name}"
                    );
                }
                // `cargo run --release -- ARGS` is `snakectl ARGS`; bare, it is the demo.
                let run = words.get(1).is_some_and(|w| w == "run")
                    && !words.iter().any(|w| w == "--example" || w == "-p");
                match words.iter().position(|w| w == "--") {
                    Some(i) if run => Some(&words[i + 1..]),
                    None if run => Some(&[]),
                    _ => None,
                }
            } else {
                Some(&words[1..])
            };
            let Some(args) = snakectl_args else { continue };
            let sub = args
                .first()
                .filter(|w| !w.starts_with('-'))
                .cloned()
                .unwrap_or_else(|| "demo".to_string());
            let entry = uses.entry(sub).or_default();
            entry.insert((String::new(), path));
            for option in options(args) {
                entry.insert((option, path));
            }
        }
    }
    for sub in [
        "demo", "solve", "simulate", "run", "sim", "teleop", "goto", "servo",
    ] {
        assert!(
            uses.contains_key(sub),
            "no `snakectl {sub}` shown: {:?}",
            uses.keys()
        );
    }
    for (sub, options) in &uses {
        let out = snakectl(&[sub, "--help"], "");
        let help = String::from_utf8_lossy(&out.stdout);
        let wheres: BTreeSet<&str> = options.iter().map(|(_, p)| *p).collect();
        assert_eq!(
            out.status.code(),
            Some(0),
            "`snakectl {sub}` (in {wheres:?}) is not a subcommand"
        );
        for (option, path) in options.iter().filter(|(o, _)| !o.is_empty()) {
            assert!(
                lists(&help, option),
                "{path}: `snakectl {sub}` has no option {option}:\n{help}"
            );
        }
    }
}

/// GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_'))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown file's headings, repeats numbered as GitHub does (`a`, `a-1`, ...).
fn anchors(text: &str) -> BTreeSet<String> {
    let (_, prose) = split_blocks(text);
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    for line in prose.lines() {
        let hashes = line.len() - line.trim_start_matches('#').len();
        if hashes == 0 || hashes > 6 || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slug(&line[hashes..]);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        });
        *n += 1;
    }
    out
}

/// The link and image targets in prose (code left out): what follows `](`, up to `)`.
fn targets(prose: &str) -> Vec<String> {
    prose
        .match_indices("](")
        .map(|(i, _)| {
            let rest = &prose[i + 2..];
            rest[..rest.find(')').expect("a link target is closed")].to_string()
        })
        .collect()
}

#[test]
fn every_link_and_image_resolves() {
    let repo = root().canonicalize().unwrap();
    for doc in DOCS {
        let text = read(doc.path);
        let (_, prose) = split_blocks(&text);
        let (_, prose) = split_spans(&prose);
        let dir = Path::new(doc.path).parent().unwrap();
        let mut relative = 0;
        for target in targets(&prose) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            relative += 1;
            let (file, anchor) = target.split_once('#').unwrap_or((&target, ""));
            let path: PathBuf = if file.is_empty() {
                PathBuf::from(doc.path)
            } else {
                dir.join(file)
            };
            let full = root().join(&path);
            let real = full.canonicalize().unwrap_or_else(|_| {
                panic!(
                    "{}: `{target}`: {} does not exist",
                    doc.path,
                    path.display()
                )
            });
            assert!(
                real.starts_with(&repo),
                "{}: `{target}` leaves the repository",
                doc.path
            );
            if !anchor.is_empty() {
                assert!(
                    file.is_empty() || file.ends_with(".md"),
                    "{}: `{target}`: an anchor into a file that is not Markdown",
                    doc.path
                );
                let known = anchors(&std::fs::read_to_string(&real).unwrap());
                assert!(
                    known.contains(anchor),
                    "{}: `{target}`: no heading `#{anchor}` in {}; it has {known:?}",
                    doc.path,
                    path.display()
                );
            }
        }
        assert!(
            relative >= doc.links,
            "{}: {relative} relative links, at least {} expected",
            doc.path,
            doc.links
        );
    }
}

#[test]
fn the_checks_see_what_they_should() {
    let (blocks, prose) = split_blocks("a\n```sh\nx\n  ```\nb `c` ``d ` e`` [f](g.md#h)\n");
    assert_eq!(blocks.len(), 1);
    assert_eq!(blocks[0].text, "x\n");
    let (spans, rest) = split_spans(&prose);
    assert_eq!(spans, ["c", "d ` e"]);
    assert_eq!(targets(&rest), ["g.md#h"]);
    assert_eq!(
        slug("The demo: `cargo run --release`"),
        "the-demo-cargo-run---release"
    );
    assert_eq!(
        slug("Real servos (U2D2 + X-series)"),
        "real-servos-u2d2--x-series"
    );
    assert_eq!(slug("The daemon's loop"), "the-daemons-loop");
    assert_eq!(
        anchors("# A\n## A\n```sh\n# A\n```\n### `b` c\n"),
        BTreeSet::from(["a".into(), "a-1".into(), "b-c".into()])
    );
    let words: Vec<String> = [
        "snakectl", "scan", "--port", "P", "[--baud", "B]", "--x=1", "-v",
    ]
    .map(String::from)
    .to_vec();
    assert_eq!(options(&words), ["--port", "--baud", "--x"]);
    assert!(lists("  --speed <V>\n", "--speed"));
    assert!(!lists("  --speed-limit <V>\n", "--speed"));
}
