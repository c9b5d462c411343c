//! Figures of a scenario in the paper's style, written as SVG with `plotters` (SVG backend only)
//! and rasterized to PNG with `resvg` (pure Rust: no system library). Text in the PNG uses the
//! system's fonts, found at run time (DejaVu Sans preferred); without any font the PNG is still
//! written, without text.
//!
//! - [`motion`]: one panel per strategy (rows) and step count (columns): the initial curve
//!   (black), the pull as a chain line (blue, dash-dot), intermediate configurations dotted
//!   (grey), the final configuration (red), and optionally the joint loci (green).
//! - [`rotations`]: the paper's Fig. 6: the length-weighted joint rotations `sigma_i |dtheta_i|`
//!   along the curve (`sigma_i` the arc length from the pulled end), one panel per step count,
//!   one line per strategy.
//! - [`demo`]: the figures of `snakectl demo`, obstacles included; [`outline`]: obstacles as
//!   lines to draw (boundaries, clearance margins, clipping to a view).

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::chain::{Num, Vec2};
use crate::scenario::{rotations as joint_rotations, Run, Scenario};

pub mod demo;
pub mod outline;

/// Why a figure could not be produced.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// The drawing backend failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// The SVG could not be parsed back for rasterization.
    #[error("SVG parse failed: {0}")]
    Svg(String),
    /// The PNG could not be produced.
    #[error("PNG encoding failed: {0}")]
    Png(String),
    /// Nothing to draw.
    #[error("no runs to draw")]
    Empty,
    /// A value to draw that no run records: not finite, or beyond the largest magnitude drawn
    /// (the recording is damaged).
    #[error(
        "{field} is {} in {at}: not a finite value within +-{}, as every run records; the \
         recording is damaged",
        Num(*value),
        Num(*bound)
    )]
    Unusable {
        /// The value's name, as the telemetry or the recording names it.
        field: &'static str,
        /// Where: which sample, phase or event.
        at: String,
        /// The value.
        value: f64,
        /// The largest magnitude drawn.
        bound: f64,
    },
    /// An axis whose ends are not finite, or too close together for their magnitude to be
    /// marked with ticks.
    #[error("the {axis} axis cannot be drawn from {} to {}", Num(*lo), Num(*hi))]
    Axis {
        /// Which axis.
        axis: &'static str,
        /// Its lower end.
        lo: f64,
        /// Its upper end.
        hi: f64,
    },
}

/// Ranges narrower than this fraction of their ends' magnitude are refused: below it the
/// spacing of `f64` values is too coarse for the ticks plotters searches for (its search would
/// not end).
const LEAST_RELATIVE_SPAN: f64 = 1e-12;

/// `lo..hi` as an axis range, once both ends are finite, their span too, and wide enough for
/// their magnitude ([`LEAST_RELATIVE_SPAN`]): what plotters needs to place its ticks in a
/// bounded number of steps.
pub(crate) fn axis(
    axis: &'static str,
    lo: f64,
    hi: f64,
) -> Result<std::ops::Range<f64>, PlotError> {
    let span = hi - lo;
    let magnitude = lo.abs().max(hi.abs());
    if span.is_finite() && span > 0.0 && span >= LEAST_RELATIVE_SPAN * magnitude {
        Ok(lo..hi)
    } else {
        Err(PlotError::Axis { axis, lo, hi })
    }
}

/// An axis label as plotters writes an `f64` key point, except that a key point at zero up to
/// the round-off of stepping to it (-2.8e-17) reads "0.0", not "-0.0".
pub(crate) fn axis_label(v: &f64) -> String {
    use plotters::coord::ranged1d::ValueFormatter;
    use plotters::coord::types::RangedCoordf64;
    let v = if v.abs() < 1e-12 { 0.0 } else { *v };
    RangedCoordf64::format(&v)
}

fn draw_err<E: std::fmt::Debug>(e: E) -> PlotError {
    PlotError::Draw(format!("{e:?}"))
}

const PANEL_W: u32 = 460;
const TITLE_H: u32 = 40;
const INITIAL: RGBColor = RGBColor(0, 0, 0);
const FINAL: RGBColor = RGBColor(200, 30, 30);
const PULL: RGBColor = RGBColor(30, 90, 200);
const INTER: RGBColor = RGBColor(120, 120, 120);
const LOCI: RGBColor = RGBColor(60, 160, 80);

fn xy(p: &Vec2) -> (f64, f64) {
    (p.x, p.y)
}

/// Bounding box of every frame and the pull path, padded, as (x0, x1, y0, y1).
fn bounds(scenario: &Scenario, runs: &[Run]) -> (f64, f64, f64, f64) {
    let mut b = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut add = |p: &Vec2| {
        b.0 = b.0.min(p.x);
        b.1 = b.1.max(p.x);
        b.2 = b.2.min(p.y);
        b.3 = b.3.max(p.y);
    };
    for r in runs {
        for f in &r.frames {
            f.iter().for_each(&mut add);
        }
    }
    let start = scenario.points[scenario.links.len()];
    for i in 0..=200 {
        add(&scenario.pull.at(start, i as f64 / 200.0));
    }
    let pad = 0.06 * (b.1 - b.0).max(b.3 - b.2).max(1e-9);
    (b.0 - pad, b.1 + pad, b.2 - pad, b.3 + pad)
}

/// The most dash patterns a chain line is split into: a longer path gets longer dashes.
const MAX_DASH_PATTERNS: f64 = 2000.0;

/// Splits a polyline into the pieces of a chain line (long dash, gap, dot, gap), at most
/// [`MAX_DASH_PATTERNS`] patterns of them; a path of no finite length is one piece.
fn chain_line(path: &[Vec2], unit: f64) -> Vec<Vec<(f64, f64)>> {
    let total: f64 = path.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    if !total.is_finite() || !unit.is_finite() || unit <= 0.0 {
        return vec![path.iter().map(xy).collect()];
    }
    let unit = unit.max(total / (11.0 * MAX_DASH_PATTERNS));
    let pattern = [
        (true, 6.0 * unit),
        (false, 2.0 * unit),
        (true, unit),
        (false, 2.0 * unit),
    ];
    let mut pieces = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    let (mut k, mut left) = (0, pattern[0].1);
    for w in path.windows(2) {
        let (a, b) = (w[0], w[1]);
        let len = (b - a).norm();
        let mut s = 0.0;
        while len - s > 0.0 {
            let take = left.min(len - s);
            let p0 = a + (b - a) * (s / len.max(f64::MIN_POSITIVE));
            s += take;
            left -= take;
            let p1 = a + (b - a) * (s / len.max(f64::MIN_POSITIVE));
            if pattern[k].0 {
                if current.is_empty() {
                    current.push(xy(&p0));
                }
                current.push(xy(&p1));
            }
            if left <= 0.0 {
                if !current.is_empty() {
                    pieces.push(std::mem::take(&mut current));
                }
                k = (k + 1) % pattern.len();
                left = pattern[k].1;
            }
        }
    }
    if current.len() > 1 {
        pieces.push(current);
    }
    pieces
}

/// Indices of at most `count` intermediate frames (excluding the first and the last), evenly
/// spread.
fn intermediates(frames: usize, count: usize) -> Vec<usize> {
    let inner = frames.saturating_sub(2);
    if inner == 0 || count == 0 {
        return Vec::new();
    }
    let take = count.min(inner);
    let mut v: Vec<usize> = (1..=take)
        .map(|i| 1 + (i * inner) / (take + 1).max(1))
        .map(|i| i.min(frames - 2))
        .collect();
    v.dedup();
    v
}

/// The motion figure as SVG text.
pub fn motion(scenario: &Scenario, runs: &[Run]) -> Result<String, PlotError> {
    if runs.is_empty() {
        return Err(PlotError::Empty);
    }
    let cols = scenario.steps.len().max(1);
    let rows = runs.len().div_ceil(cols);
    let (x0, x1, y0, y1) = bounds(scenario, runs);
    // Plot area inside a panel: margins, caption and label areas.
    let (extra_w, extra_h) = (16 + 50, 16 + 24 + 36);
    let inner_w = (PANEL_W - extra_w) as f64;
    let aspect = ((y1 - y0) / (x1 - x0)).clamp(0.35, 1.4);
    let inner_h = inner_w * aspect;
    let panel_h = inner_h as u32 + extra_h;
    // Equal scale: widen the tighter range.
    let scale = (inner_w / (x1 - x0)).min(inner_h / (y1 - y0));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (hx, hy) = (0.5 * inner_w / scale, 0.5 * inner_h / scale);
    let (xr, yr) = ((cx - hx)..(cx + hx), (cy - hy)..(cy + hy));
    let width = PANEL_W * cols as u32;
    let height = panel_h * rows as u32 + TITLE_H;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root
            .titled(&scenario.title, ("sans-serif", 22))
            .map_err(draw_err)?;
        let panels = root.split_evenly((rows, cols));
        let start = scenario.points[scenario.links.len()];
        for (i, run) in runs.iter().enumerate() {
            let path: Vec<Vec2> = (0..=200.max(4 * run.steps))
                .map(|k| {
                    let s = k as f64 / 200.max(4 * run.steps) as f64;
                    // A K-step pull follows the straight pieces between the K + 1 path points.
                    let piece = (s * run.steps as f64).floor().min(run.steps as f64 - 1.0);
                    let a = scenario.pull.at(start, piece / run.steps as f64);
                    let b = scenario.pull.at(start, (piece + 1.0) / run.steps as f64);
                    a + (b - a) * (s * run.steps as f64 - piece)
                })
                .collect();
            draw_panel(
                &panels[i],
                scenario,
                run,
                &path,
                (xr.clone(), yr.clone()),
                3.0 / scale,
                i == 0,
            )?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

fn draw_panel(
    area: &DrawingArea<SVGBackend, Shift>,
    scenario: &Scenario,
    run: &Run,
    path: &[Vec2],
    (xr, yr): (std::ops::Range<f64>, std::ops::Range<f64>),
    unit: f64,
    legend: bool,
) -> Result<(), PlotError> {
    let mut chart = ChartBuilder::on(area)
        .caption(run.label(), ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d(xr, yr)
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_label_formatter(&axis_label)
        .y_label_formatter(&axis_label)
        .disable_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .x_labels(6)
        .y_labels(6)
        .draw()
        .map_err(draw_err)?;
    let frames = &run.frames;
    if scenario.plot.loci && frames.len() > 2 {
        let n = scenario.links.len();
        let every = n.div_ceil(30).max(1);
        for j in (0..=n).step_by(every) {
            chart
                .draw_series(LineSeries::new(
                    frames.iter().map(|f| xy(&f[j])),
                    LOCI.mix(0.6).stroke_width(1),
                ))
                .map_err(draw_err)?;
        }
    }
    for i in intermediates(frames.len(), scenario.plot.intermediates) {
        chart
            .draw_series(DashedLineSeries::new(
                frames[i].iter().map(xy),
                2,
                3,
                INTER.stroke_width(1),
            ))
            .map_err(draw_err)?;
    }
    let initial = &frames[0];
    let last = run.last();
    let series = chart
        .draw_series(LineSeries::new(
            initial.iter().map(xy),
            INITIAL.stroke_width(2),
        ))
        .map_err(draw_err)?;
    if legend {
        series
            .label("initial")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], INITIAL.stroke_width(2)));
    }
    chart
        .draw_series(
            initial
                .iter()
                .map(|p| Circle::new(xy(p), 2, INITIAL.filled())),
        )
        .map_err(draw_err)?;
    for (k, piece) in chain_line(path, unit).into_iter().enumerate() {
        let s = chart
            .draw_series(LineSeries::new(piece, PULL.stroke_width(2)))
            .map_err(draw_err)?;
        if legend && k == 0 {
            s.label("pull")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], PULL.stroke_width(2)));
        }
    }
    let series = chart
        .draw_series(LineSeries::new(last.iter().map(xy), FINAL.stroke_width(2)))
        .map_err(draw_err)?;
    if legend {
        series
            .label("final")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], FINAL.stroke_width(2)));
    }
    chart
        .draw_series(last.iter().map(|p| Circle::new(xy(p), 2, FINAL.filled())))
        .map_err(draw_err)?;
    if legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(draw_err)?;
    }
    Ok(())
}

/// Line colours of the rotation figure, one per strategy.
const SERIES: [RGBColor; 6] = [
    RGBColor(30, 90, 200),
    RGBColor(230, 120, 20),
    RGBColor(200, 30, 30),
    RGBColor(60, 160, 80),
    RGBColor(140, 60, 170),
    RGBColor(90, 90, 90),
];

/// The paper's Fig. 6 as SVG text: `sigma_i |dtheta_i|` against `sigma_i`, one panel per step
/// count.
pub fn rotations(scenario: &Scenario, runs: &[Run]) -> Result<String, PlotError> {
    if runs.is_empty() {
        return Err(PlotError::Empty);
    }
    let cols = scenario.steps.len().max(1);
    let width = PANEL_W * cols as u32;
    let height = 360 + TITLE_H;
    let data: Vec<Vec<(f64, f64)>> = runs
        .iter()
        .map(|r| {
            joint_rotations(&r.frames[0], r.last())
                .into_iter()
                .map(|(s, a)| (s, s * a.abs()))
                .collect()
        })
        .collect();
    let xmax = scenario.links.iter().sum::<f64>();
    let ymax = data
        .iter()
        .flatten()
        .fold(0.0f64, |m, p| m.max(p.1))
        .max(1e-12)
        * 1.08;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!("{}: length-weighted joint rotations", scenario.title);
        let root = root.titled(&title, ("sans-serif", 20)).map_err(draw_err)?;
        let panels = root.split_evenly((1, cols));
        for (c, &steps) in scenario.steps.iter().enumerate() {
            let mut chart = ChartBuilder::on(&panels[c])
                .caption(format!("K={steps}"), ("sans-serif", 16))
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..xmax, 0.0..ymax)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_label_formatter(&axis_label)
                .y_label_formatter(&axis_label)
                .light_line_style(TRANSPARENT)
                .bold_line_style(BLACK.mix(0.12))
                .x_desc("arc length from the pulled end (m)")
                .y_desc("sigma |rotation| (m rad)")
                .draw()
                .map_err(draw_err)?;
            for (i, (run, pts)) in runs.iter().zip(&data).enumerate() {
                if run.steps != steps {
                    continue;
                }
                let color = SERIES[(i / cols) % SERIES.len()];
                chart
                    .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))
                    .map_err(draw_err)?
                    .label(run.strategy.label())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                    });
                chart
                    .draw_series(pts.iter().map(|p| Circle::new(*p, 2, color.filled())))
                    .map_err(draw_err)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 13))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Fonts for rasterizing: the system's, loaded once per call. Returns whether any was found.
fn font_options() -> (resvg::usvg::Options<'static>, bool) {
    let mut opt = resvg::usvg::Options::default();
    let db = opt.fontdb_mut();
    db.load_system_fonts();
    let family = db
        .faces()
        .flat_map(|f| f.families.iter().map(|(name, _)| name.clone()))
        .find(|name| name == "DejaVu Sans")
        .or_else(|| {
            db.faces()
                .next()
                .and_then(|f| f.families.first().map(|(n, _)| n.clone()))
        });
    let found = family.is_some();
    if let Some(name) = family {
        db.set_sans_serif_family(name.clone());
        opt.font_family = name;
    }
    (opt, found)
}

/// Rasterizes SVG text into PNG bytes. The flag says whether a font was found for the text
/// (without one the PNG has no text).
pub fn png(svg: &str) -> Result<(Vec<u8>, bool), PlotError> {
    let (opt, fonts) = font_options();
    let tree = resvg::usvg::Tree::from_str(svg, &opt).map_err(|e| PlotError::Svg(e.to_string()))?;
    let size = tree.size().to_int_size();
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height())
        .ok_or_else(|| PlotError::Png(format!("bad size {}x{}", size.width(), size.height())))?;
    pixmap.fill(resvg::tiny_skia::Color::WHITE);
    resvg::render(
        &tree,
        resvg::tiny_skia::Transform::default(),
        &mut pixmap.as_mut(),
    );
    let bytes = pixmap
        .encode_png()
        .map_err(|e| PlotError::Png(e.to_string()))?;
    Ok((bytes, fonts))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chain_line_alternates_dashes_and_dots() {
        let path = [Vec2::zeros(), Vec2::new(22.0, 0.0)];
        let pieces = chain_line(&path, 1.0);
        // 6 on, 2 off, 1 on, 2 off, 6 on, 2 off, 1 on, 2 off: four pieces in 22 units.
        let lengths: Vec<f64> = pieces.iter().map(|p| p[p.len() - 1].0 - p[0].0).collect();
        assert_eq!(lengths, vec![6.0, 1.0, 6.0, 1.0]);
    }

    #[test]
    fn a_long_or_endless_path_gets_a_bounded_number_of_dashes() {
        let long = [Vec2::zeros(), Vec2::new(1e12, 0.0)];
        let pieces = chain_line(&long, 1.0);
        assert!(
            pieces.len() <= 2 * MAX_DASH_PATTERNS as usize,
            "{}",
            pieces.len()
        );
        assert!(
            pieces.len() >= MAX_DASH_PATTERNS as usize,
            "{}",
            pieces.len()
        );
        let endless = [Vec2::zeros(), Vec2::new(f64::INFINITY, 0.0)];
        assert_eq!(chain_line(&endless, 1.0).len(), 1);
    }

    #[test]
    fn intermediates_are_spread_and_exclude_the_ends() {
        assert_eq!(intermediates(2, 5), Vec::<usize>::new());
        assert_eq!(intermediates(6, 10), vec![1, 2, 3, 4]);
        let v = intermediates(41, 4);
        assert_eq!(v.len(), 4);
        assert!(v.iter().all(|&i| (1..40).contains(&i)));
    }
}
