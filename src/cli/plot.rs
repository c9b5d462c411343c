//! `snakectl plot FILE.mcap --out DIR`: the demo's figures (the arm's motion; joint angles and
//! tracking error against time) drawn from any recording, as SVG and PNG.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use clap::Args;

use snakectl::plot;
use snakectl::plot::demo::Record;
use snakectl::record::Recording;

use super::{outln, Failure};

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The recording (`snakectl run --record`, `snakectl teleop --sim ... --record`, the
    /// demo's `run.mcap`).
    #[arg(value_name = "FILE.mcap")]
    file: PathBuf,
    /// Where to write `motion.svg`, `motion.png`, `joints.svg` and `joints.png`.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

/// Reads the recording and writes the figures.
pub fn run(args: PlotArgs) -> Result<(), Failure> {
    let recording = Recording::open(&args.file).map_err(Failure::bad_input)?;
    let record = recording.plot_record();
    if record.samples.is_empty() {
        return Err(Failure::bad_input(anyhow!(
            "{}: no telemetry in the recording",
            args.file.display()
        )));
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))
        .map_err(Failure::other)?;
    let name = args.file.file_name().map_or_else(
        || "the recording".into(),
        |n| n.to_string_lossy().into_owned(),
    );
    let written = figures(
        &record,
        &args.out,
        &format!("{name}: the arm's motion"),
        &format!("{name}: joint angles and tracking error"),
    )?;
    outln!(
        "{}: {} samples, {} phase(s) pictured; written to {}:",
        args.file.display(),
        record.samples.len(),
        record.phases.iter().filter(|p| p.pictured).count(),
        args.out.display()
    )?;
    for path in written {
        outln!("  {}", path.display())?;
    }
    Ok(())
}

/// Writes `bytes` to the file `name` in `out`; its path.
pub fn write_file(out: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf, Failure> {
    let path = out.join(name);
    std::fs::write(&path, bytes)
        .with_context(|| format!("writing {}", path.display()))
        .map_err(Failure::other)?;
    Ok(path)
}

/// Writes `motion` and `joints`, each as SVG and PNG, into `out`; the files written. Warns on
/// stderr when no font was found for the PNGs' text.
pub fn figures(
    record: &Record,
    out: &Path,
    motion_title: &str,
    joints_title: &str,
) -> Result<Vec<PathBuf>, Failure> {
    let write = |name: &str, bytes: &[u8]| write_file(out, name, bytes);
    let drawn = [
        ("motion", plot::demo::motion(record, motion_title)),
        ("joints", plot::demo::joints(record, joints_title)),
    ];
    let mut written = Vec::new();
    let mut fonts = true;
    for (name, svg) in drawn {
        let svg = svg.map_err(Failure::other)?;
        written.push(write(&format!("{name}.svg"), svg.as_bytes())?);
        let (png, found) = plot::png(&svg).map_err(Failure::other)?;
        fonts &= found;
        written.push(write(&format!("{name}.png"), &png)?);
    }
    if !fonts {
        eprintln!("snakectl: no system font found: the PNG figures have no text");
    }
    Ok(written)
}
