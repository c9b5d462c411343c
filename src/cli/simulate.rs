//! `snakectl simulate`: run a flexible-object scenario (or every scenario of a directory) and
//! write its figures (SVG and PNG) and metrics table (CSV, Markdown, JSON).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;

use snakectl::plot;
use snakectl::scenario::table::Table;
use snakectl::scenario::Scenario;

use super::{outln, Failure};

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Scenario file (TOML, see docs/FLEXIBLE-OBJECTS.md).
    #[arg(long, conflicts_with = "all", required_unless_present = "all")]
    scenario: Option<PathBuf>,
    /// Run every `*.toml` of this directory, each into `OUT/<file stem>/`.
    #[arg(long, value_name = "DIR")]
    all: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Write SVG only (skip the PNG rasterization).
    #[arg(long)]
    no_png: bool,
}

/// Runs `snakectl simulate`.
pub fn run(args: SimulateArgs) -> Result<(), Failure> {
    super::check_out_dir(&args.out)?;
    match (&args.scenario, &args.all) {
        (Some(file), _) => one(file, &args.out, !args.no_png),
        (None, Some(dir)) => {
            let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
                .with_context(|| format!("{}", dir.display()))
                .map_err(Failure::bad_input)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(Failure::bad_input(anyhow::anyhow!(
                    "{}: no *.toml scenario files",
                    dir.display()
                )));
            }
            for file in files {
                let stem = file.file_stem().map(PathBuf::from).unwrap_or_default();
                one(&file, &args.out.join(stem), !args.no_png)?;
            }
            Ok(())
        }
        (None, None) => Err(Failure::bad_input(anyhow::anyhow!(
            "give --scenario FILE or --all DIR"
        ))),
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    std::fs::write(path, bytes)
        .with_context(|| format!("writing {}", path.display()))
        .map_err(Failure::other)
}

fn one(file: &Path, out: &Path, png: bool) -> Result<(), Failure> {
    let scenario = Scenario::load(file).map_err(Failure::bad_input)?;
    // The output directory is made (and a file written there) before the computation, which can
    // take long, so an unwritable `--out` fails at once.
    std::fs::create_dir_all(out)
        .with_context(|| format!("--out: creating {}", out.display()))
        .map_err(Failure::other)?;
    let probe = out.join(".snakectl-write-test");
    std::fs::write(&probe, b"")
        .and_then(|()| std::fs::remove_file(&probe))
        .with_context(|| format!("--out: {} is not writable", out.display()))
        .map_err(Failure::other)?;
    let runs = scenario.run();
    let table = Table::new(&scenario.title, &runs);
    write(&out.join("metrics.csv"), table.csv().as_bytes())?;
    write(&out.join("metrics.md"), table.markdown().as_bytes())?;
    let json = table.json().map_err(Failure::other)?;
    write(&out.join("metrics.json"), json.as_bytes())?;
    let figures = [
        ("motion", plot::motion(&scenario, &runs)),
        ("rotations", plot::rotations(&scenario, &runs)),
    ];
    let mut fonts = true;
    for (name, svg) in figures {
        let svg = svg.map_err(Failure::other)?;
        write(&out.join(format!("{name}.svg")), svg.as_bytes())?;
        if png {
            let (bytes, found) = plot::png(&svg).map_err(Failure::other)?;
            fonts &= found;
            write(&out.join(format!("{name}.png")), &bytes)?;
        }
    }
    if png && !fonts {
        eprintln!("snakectl: no system font found: the PNG figures have no text");
    }
    outln!(
        "{}: {} -> {}",
        file.display(),
        scenario.title,
        out.display()
    )?;
    for r in &runs {
        outln!(
            "  {:<34} M1 {:.4e}  M2 {:.4e}  M3 {:.4e}  M4 {:.4e}  M5 {:.4e}  iterations {}{}",
            r.label(),
            r.metrics.m1,
            r.metrics.m2,
            r.metrics.m3,
            r.metrics.m4,
            r.metrics.m5,
            r.iterations,
            if r.converged { "" } else { "  NOT CONVERGED" }
        )?;
    }
    Ok(())
}
