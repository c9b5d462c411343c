//! The map of the crate holds: the math core (`chain`, `metrics`, `resolve`, `motion`,
//! `control`, `rope` for free flexible objects, `world` for obstacles and `reach` for ways among them) imports no I/O, time, threads, tokio, serde or tracing, and nothing of the crate
//! outside the math core; the simulator crate imports nothing of the controller.
//!
//! Production code only: a file's `#[cfg(test)]` module and files named `tests.rs` may read
//! reference data.

#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

/// The math core's modules, as directories under `src/`.
const MATH_CORE: [&str; 8] = [
    "chain", "metrics", "resolve", "motion", "control", "rope", "world", "reach",
];

/// What the math core must never name.
const FORBIDDEN: [&str; 16] = [
    "std::io",
    "std::fs",
    "std::net",
    "std::time",
    "std::thread",
    "std::process",
    "std::env",
    "std::sync::mpsc",
    "Instant",
    "SystemTime",
    "tokio",
    "serde",
    "tracing",
    "println!",
    "eprintln!",
    "dynamixel2",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    if dir.extension().is_some_and(|e| e == "rs") {
        out.push(dir.to_path_buf());
        return;
    }
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The production part of a source file: up to its first `#[cfg(test)]`, none of a `tests.rs`.
fn production(path: &Path) -> String {
    if path.file_name().is_some_and(|n| n == "tests.rs") {
        return String::new();
    }
    let text = std::fs::read_to_string(path).unwrap();
    let end = text.find("#[cfg(test)]").unwrap_or(text.len());
    // Comments may name anything.
    text[..end]
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

fn files_of(dirs: &[&str]) -> Vec<PathBuf> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    for d in dirs {
        let dir = src.join(d);
        if dir.is_dir() {
            rust_files(&dir, &mut files);
        } else {
            rust_files(&dir.with_extension("rs"), &mut files);
        }
    }
    files
}

#[test]
fn the_math_core_imports_no_io_time_threads_or_frameworks() {
    let files = files_of(&MATH_CORE);
    assert!(files.len() >= 10, "found only {} files", files.len());
    let mut offences = Vec::new();
    for path in &files {
        let code = production(path);
        for word in FORBIDDEN {
            if code.contains(word) {
                offences.push(format!("{} names {word}", path.display()));
            }
        }
    }
    assert!(offences.is_empty(), "{offences:#?}");
}

#[test]
fn the_math_core_uses_only_the_math_core() {
    let mut offences = Vec::new();
    for path in files_of(&MATH_CORE) {
        let code = production(&path);
        for (i, _) in code.match_indices("crate::") {
            let module: String = code[i + "crate::".len()..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !MATH_CORE.contains(&module.as_str()) {
                offences.push(format!("{} uses crate::{module}", path.display()));
            }
        }
        if code.contains("super::super::super") {
            offences.push(format!("{} climbs out of its module", path.display()));
        }
    }
    assert!(offences.is_empty(), "{offences:#?}");
}

#[test]
fn the_simulator_crate_knows_nothing_of_the_controller() {
    let mut files = Vec::new();
    rust_files(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("sim/src"),
        &mut files,
    );
    assert!(!files.is_empty());
    for path in files {
        let code = std::fs::read_to_string(&path).unwrap();
        assert!(
            !code.contains("snakectl::"),
            "{} uses snakectl",
            path.display()
        );
    }
    let manifest =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("sim/Cargo.toml"))
            .unwrap();
    let deps = manifest.split("[dependencies]").nth(1).unwrap_or("");
    assert!(!deps.contains("snakectl"), "sim depends on snakectl");
}

#[test]
fn the_check_sees_a_forbidden_import() {
    // The scan itself: a planted import is found, a comment is not.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("x.rs");
    std::fs::write(
        &file,
        "// std::time in a comment\nuse std::time::Instant;\n",
    )
    .unwrap();
    let code = production(&file);
    assert!(code.contains("std::time::Instant"));
    assert!(!code.contains("comment"));
    std::fs::write(
        &file,
        "fn f() {}\n#[cfg(test)]\nmod tests { use std::fs; }\n",
    )
    .unwrap();
    assert!(!production(&file).contains("std::fs"));
}
