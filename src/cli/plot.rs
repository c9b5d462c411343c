//! `snakectl plot FILE.mcap --out DIR`: the demo's figures (the arm's motion; joint angles and
//! tracking error against time) drawn from a recording (uncompressed, as snakectl writes it), as
//! SVG and PNG.

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

/// Reads the recording and writes the figures. The figures are drawn before `--out` is created,
/// so that a recording that cannot be drawn leaves nothing behind.
pub fn run(args: PlotArgs) -> Result<(), Failure> {
    super::check_out_dir(&args.out)?;
    let recording = Recording::open(&args.file).map_err(Failure::bad_input)?;
    if let Some(reason) = &recording.cut {
        let telemetry = recording.telemetry();
        let last_s = match (telemetry.first(), telemetry.last()) {
            (Some(first), Some(last)) => last.t_s - first.t_s,
            _ => 0.0,
        };
        eprintln!(
            "snakectl: {} ends in the middle of a record ({reason}): its writer did not close it \
             (killed?). Drawn from the {} messages read before that ({last_s:.1} s of \
             telemetry); what was written after the last complete chunk is lost. `mcap recover` \
             (the MCAP command-line tool) rebuilds the file and may save more of it.",
            args.file.display(),
            recording.message_count(),
        );
    }
    let record = recording.plot_record();
    if record.samples.is_empty() {
        return Err(Failure::bad_input(anyhow!(
            "{}: no telemetry in the recording",
            args.file.display()
        )));
    }
    let name = args.file.file_name().map_or_else(
        || "the recording".into(),
        |n| n.to_string_lossy().into_owned(),
    );
    let drawn = render(
        &record,
        &format!("{name}: the arm's motion"),
        &format!("{name}: joint angles and tracking error"),
    )
    .map_err(|e| Failure::bad_input(e.context(format!("drawing {}", args.file.display()))))?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))
        .map_err(Failure::other)?;
    let written = write_all(&args.out, &drawn)?;
    let (pictured, all) = (
        record.pictured().count(),
        record.phases.iter().filter(|p| p.pictured).count(),
    );
    let of = if all > pictured {
        format!(" (the first {pictured} of {all})")
    } else {
        String::new()
    };
    outln!(
        "{}: {} samples, {pictured} phase(s) pictured{of}; written to {}:",
        args.file.display(),
        record.samples.len(),
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
    let drawn = render(record, motion_title, joints_title).map_err(Failure::other)?;
    write_all(out, &drawn)
}

/// `motion` and `joints`, each as SVG and PNG: (file name, bytes). Warns on stderr when no font
/// was found for the PNGs' text.
fn render(
    record: &Record,
    motion_title: &str,
    joints_title: &str,
) -> anyhow::Result<Vec<(String, Vec<u8>)>> {
    let drawn = [
        ("motion", plot::demo::motion(record, motion_title)),
        ("joints", plot::demo::joints(record, joints_title)),
    ];
    let mut files = Vec::new();
    let mut fonts = true;
    for (name, svg) in drawn {
        let svg = svg.with_context(|| format!("the {name} figure"))?;
        let (png, found) = plot::png(&svg)?;
        fonts &= found;
        files.push((format!("{name}.svg"), svg.into_bytes()));
        files.push((format!("{name}.png"), png));
    }
    if !fonts {
        eprintln!("snakectl: no system font found: the PNG figures have no text");
    }
    Ok(files)
}

/// Writes each (file name, bytes) into `out`; their paths.
fn write_all(out: &Path, files: &[(String, Vec<u8>)]) -> Result<Vec<PathBuf>, Failure> {
    files
        .iter()
        .map(|(name, bytes)| write_file(out, name, bytes))
        .collect()
}
