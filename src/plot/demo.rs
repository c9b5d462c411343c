//! The figures of `snakectl demo`, drawn from what a client of the daemon recorded: plain data
//! in ([`Record`]), SVG text out (rasterize it with [`super::png`]).
//!
//! - [`motion`]: one column per pictured phase (each strategy's figure eight, the path with its
//!   estop): on top the whole arm at a few moments, below a close-up of the tip, the reference
//!   against the measured tip.
//! - [`joints`]: every joint angle and the tracking error against time over the whole run, the
//!   phases shaded and the events (estop, reset) marked.
//!
//! A phase run among obstacles ([`Phase::world`]) has them drawn in both its panels: each
//! obstacle filled light grey with a dark outline, and dashed around it the line the links'
//! axes keep behind (the obstacle grown by `link_radius_m + clearance_m`).

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::outline;
use super::{axis, axis_label, draw_err, PlotError};
use crate::chain::{Chain, Vec2, MAX_MAGNITUDE};
use crate::world::World;

/// One telemetry sample.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sample {
    /// Daemon time, s.
    pub t_s: f64,
    /// Measured joint angles, rad.
    pub theta: Vec<f64>,
    /// The tip reference, m.
    pub tip_ref: [f64; 2],
    /// The measured tip, m.
    pub tip_meas: [f64; 2],
    /// `|tip_ref - tip_meas|`, m.
    pub tracking_error_m: f64,
}

/// A stretch of the run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Phase {
    /// Its name in the figures.
    pub label: String,
    /// Start, daemon time, s.
    pub t0: f64,
    /// End, daemon time, s.
    pub t1: f64,
    /// The curve the tip was meant to follow (empty: none), m.
    pub reference: Vec<[f64; 2]>,
    /// Whether it gets a column of its own in [`motion`] and a shade in [`joints`].
    pub pictured: bool,
    /// The obstacles in force during the phase, drawn in its panels of [`motion`] (`None`:
    /// none).
    pub world: Option<World>,
}

/// Something that happened at one moment (an estop, a reset).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Event {
    /// Its name in the figures.
    pub label: String,
    /// Daemon time, s.
    pub t_s: f64,
    /// The measured tip then, m.
    pub tip: [f64; 2],
}

/// What the figures are drawn from.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Record {
    /// The arm: its poses are drawn by its forward kinematics (`None`: no arm to draw).
    pub chain: Option<Chain>,
    /// Samples in time order.
    pub samples: Vec<Sample>,
    /// Phases in time order.
    pub phases: Vec<Phase>,
    /// Events in time order.
    pub events: Vec<Event>,
}

impl Record {
    /// The joint points, base to tip, of a pose (none without an arm, or for a pose that does
    /// not have one angle per joint).
    fn points(&self, theta: &[f64]) -> Vec<(f64, f64)> {
        self.chain
            .as_ref()
            .and_then(|chain| chain.checked_points(theta))
            .unwrap_or_default()
            .iter()
            .map(|p| (p.x, p.y))
            .collect()
    }

    /// The base point, m (the origin without an arm).
    fn base(&self) -> (f64, f64) {
        self.chain
            .as_ref()
            .map_or((0.0, 0.0), |chain| (chain.base().x, chain.base().y))
    }

    /// The first value to draw that no run records, if any: a time that is not finite, or an
    /// angle, a position or an error that is not finite or beyond [`MAX_MAGNITUDE`]. The
    /// figures' ranges are found from these values; such a value would make them infinite, or
    /// too wide for their ticks to be placed.
    fn check(&self) -> Result<(), PlotError> {
        let fault = |field: &'static str, at: &dyn Fn() -> String, value: f64, bound: f64| {
            if value.is_finite() && value.abs() <= bound {
                Ok(())
            } else {
                Err(PlotError::Unusable {
                    field,
                    at: at(),
                    value,
                    bound,
                })
            }
        };
        let (m, t) = (MAX_MAGNITUDE, f64::MAX);
        for (i, s) in self.samples.iter().enumerate() {
            let at = || format!("sample {i} of the telemetry");
            fault("t_s", &at, s.t_s, t)?;
            for &a in &s.theta {
                fault("theta_meas", &at, a, m)?;
            }
            for &x in &s.tip_meas {
                fault("tip_meas", &at, x, m)?;
            }
            fault("tracking_error_m", &at, s.tracking_error_m, m)?;
        }
        for p in &self.phases {
            let at = || format!("the phase \"{}\"", p.label);
            fault("its start (t0_s)", &at, p.t0, t)?;
            fault("its end (t1_s)", &at, p.t1, t)?;
            for &x in p.reference.iter().flatten() {
                fault("its reference", &at, x, m)?;
            }
        }
        for e in &self.events {
            let at = || format!("the event \"{}\"", e.label);
            fault("its time", &at, e.t_s, t)?;
            for &x in &e.tip {
                fault("its tip", &at, x, m)?;
            }
        }
        Ok(())
    }

    fn samples_in(&self, phase: &Phase) -> Vec<&Sample> {
        self.samples
            .iter()
            .filter(|s| s.t_s >= phase.t0 && s.t_s <= phase.t1)
            .collect()
    }
}

/// Colour of the `i`-th pictured phase.
const PHASE_COLOURS: [RGBColor; 4] = [
    RGBColor(30, 90, 200),
    RGBColor(230, 120, 20),
    RGBColor(40, 150, 80),
    RGBColor(140, 60, 170),
];
const EVENT: RGBColor = RGBColor(210, 30, 30);
const OBSTACLE_FILL: RGBColor = RGBColor(214, 214, 214);
const OBSTACLE_EDGE: RGBColor = RGBColor(90, 90, 90);
const MARGIN: RGBColor = RGBColor(130, 130, 130);
const REFERENCE: RGBColor = RGBColor(40, 40, 40);
const FONT: &str = "sans-serif";

/// Arms drawn per column of [`motion`].
const SNAPSHOTS: usize = 6;
const COL_W: u32 = 440;
const ARM_H: u32 = 440;
const ZOOM_H: u32 = 330;
const TITLE_H: u32 = 44;
/// Room a chart takes around its plotting area: margins, caption, label areas (w, h), px.
const CHART_EXTRA: (u32, u32) = (2 * 10 + 56, 2 * 10 + 26 + 40);

/// The least span of a view, m: a tip that barely moved is drawn in a view whose axis labels
/// still read apart.
const MIN_VIEW_M: f64 = 1e-3;

/// Ranges of equal scale on both axes holding `(x0, x1, y0, y1)`, padded, for a plotting area
/// of `w` by `h` pixels, at least [`MIN_VIEW_M`] across.
fn equal_ranges(
    (x0, x1, y0, y1): (f64, f64, f64, f64),
    w: f64,
    h: f64,
    pad: f64,
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let span = (x1 - x0).max(y1 - y0).max(1e-6);
    let (x0, x1, y0, y1) = (
        x0 - pad * span,
        x1 + pad * span,
        y0 - pad * span,
        y1 + pad * span,
    );
    let scale = (w / (x1 - x0).max(MIN_VIEW_M)).min(h / (y1 - y0).max(MIN_VIEW_M));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (hx, hy) = (0.5 * w / scale, 0.5 * h / scale);
    ((cx - hx)..(cx + hx), (cy - hy)..(cy + hy))
}

/// The bounding box `(x0, x1, y0, y1)` of some points.
fn bbox<'a>(points: impl IntoIterator<Item = &'a (f64, f64)>) -> (f64, f64, f64, f64) {
    let mut b = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in points {
        b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
    }
    if b.0 > b.1 {
        (0.0, 1.0, 0.0, 1.0)
    } else {
        b
    }
}

fn xy(p: [f64; 2]) -> (f64, f64) {
    (p[0], p[1])
}

/// Most phases [`motion`] gives a column: the figure widens with each, and a recording of
/// many moves (or a crafted one) would otherwise ask for an image too wide to draw. The
/// first ones are pictured.
pub const MAX_PICTURED: usize = 12;

impl Record {
    /// The phases [`motion`] gives a column: the first [`MAX_PICTURED`] pictured ones.
    pub fn pictured(&self) -> impl Iterator<Item = &Phase> {
        self.phases.iter().filter(|p| p.pictured).take(MAX_PICTURED)
    }
}

/// The motion figure as SVG text.
pub fn motion(record: &Record, title: &str) -> Result<String, PlotError> {
    let phases: Vec<&Phase> = record.pictured().collect();
    if phases.is_empty() || record.samples.is_empty() {
        return Err(PlotError::Empty);
    }
    record.check()?;
    let per_phase: Vec<Vec<&Sample>> = phases.iter().map(|p| record.samples_in(p)).collect();
    // One view of the whole arm, the same in every column: the base and every pose drawn.
    let mut arm_points = vec![record.base()];
    for samples in &per_phase {
        for s in samples {
            arm_points.extend(record.points(&s.theta));
        }
    }
    // The obstacles near the arm in view too: those far away only as far as half the arm's
    // span beyond it.
    let (x0, x1, y0, y1) = bbox(&arm_points);
    let reach = 0.5 * (x1 - x0).max(y1 - y0);
    let mut seen = Vec::new();
    for world in phases.iter().filter_map(|p| p.world.as_ref()) {
        let grow = world.link_radius_m() + world.clearance_m();
        for o in world.obstacles() {
            let (lo, hi) = o.shape.bounds();
            for (x, y) in [(lo.x - grow, lo.y - grow), (hi.x + grow, hi.y + grow)] {
                seen.push((
                    x.clamp(x0 - reach, x1 + reach),
                    y.clamp(y0 - reach, y1 + reach),
                ));
            }
        }
    }
    arm_points.extend(seen);
    let plot_w = f64::from(COL_W - CHART_EXTRA.0);
    let arm_view = equal_ranges(
        bbox(&arm_points),
        plot_w,
        f64::from(ARM_H - CHART_EXTRA.1),
        0.06,
    );
    let width = COL_W * phases.len() as u32;
    let height = TITLE_H + ARM_H + ZOOM_H;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root.titled(title, (FONT, 22)).map_err(draw_err)?;
        let (top, bottom) = root.split_vertically(ARM_H);
        let tops = top.split_evenly((1, phases.len()));
        let bottoms = bottom.split_evenly((1, phases.len()));
        for (i, (phase, samples)) in phases.iter().zip(&per_phase).enumerate() {
            let colour = PHASE_COLOURS[i % PHASE_COLOURS.len()];
            let events: Vec<&Event> = record
                .events
                .iter()
                .filter(|e| e.t_s >= phase.t0 && e.t_s <= phase.t1)
                .collect();
            arm_panel(
                &tops[i],
                record,
                phase,
                samples,
                &events,
                colour,
                arm_view.clone(),
            )?;
            zoom_panel(&bottoms[i], phase, samples, &events, colour)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Indices of `count` samples spread evenly over `len`, first and last included.
fn spread(len: usize, count: usize) -> Vec<usize> {
    match (len, count) {
        (0, _) | (_, 0) => Vec::new(),
        (_, 1) => vec![len - 1],
        _ => {
            let mut v: Vec<usize> = (0..count).map(|k| k * (len - 1) / (count - 1)).collect();
            v.dedup();
            v
        }
    }
}

fn arm_panel(
    area: &DrawingArea<SVGBackend, Shift>,
    record: &Record,
    phase: &Phase,
    samples: &[&Sample],
    events: &[&Event],
    colour: RGBColor,
    (xr, yr): (std::ops::Range<f64>, std::ops::Range<f64>),
) -> Result<(), PlotError> {
    let (xr, yr) = (
        axis("arm's x", xr.start, xr.end)?,
        axis("arm's y", yr.start, yr.end)?,
    );
    let (xr_view, yr_view) = (xr.clone(), yr.clone());
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{}: the arm", phase.label), (FONT, 17))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(xr, yr)
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_label_formatter(&axis_label)
        .y_label_formatter(&axis_label)
        .light_line_style(TRANSPARENT)
        .bold_line_style(BLACK.mix(0.08))
        .x_desc("x (m)")
        .y_desc("y (m)")
        .x_labels(6)
        .y_labels(6)
        .draw()
        .map_err(draw_err)?;
    if let Some(world) = &phase.world {
        draw_world(&mut chart, world, (&xr_view, &yr_view))?;
    }
    let picks = spread(samples.len(), SNAPSHOTS);
    for (k, &i) in picks.iter().enumerate() {
        // Early poses pale, the last one full.
        let strength = 0.25 + 0.75 * (k + 1) as f64 / picks.len() as f64;
        let points = record.points(&samples[i].theta);
        let style = colour.mix(strength).stroke_width(2);
        chart
            .draw_series(LineSeries::new(points.iter().copied(), style))
            .map_err(draw_err)?;
        chart
            .draw_series(
                points
                    .iter()
                    .map(|&p| Circle::new(p, 2, colour.mix(strength).filled())),
            )
            .map_err(draw_err)?;
    }
    // The base.
    let base = record.base();
    chart
        .draw_series(std::iter::once(TriangleMarker::new(
            base,
            7,
            BLACK.filled(),
        )))
        .map_err(draw_err)?
        .label("base")
        .legend(|(x, y)| TriangleMarker::new((x + 9, y), 5, BLACK.filled()));
    chart
        .draw_series(LineSeries::new(
            samples.iter().map(|s| xy(s.tip_meas)),
            BLACK.stroke_width(1),
        ))
        .map_err(draw_err)?
        .label("tip, measured")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(1)));
    chart
        .draw_series(std::iter::once(PathElement::new(
            Vec::<(f64, f64)>::new(),
            colour.stroke_width(2),
        )))
        .map_err(draw_err)?
        .label(format!("arm at {} moments, pale first", picks.len()))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    mark_events(&mut chart, events, false)?;
    legend_box(&mut chart, SeriesLabelPosition::LowerLeft)?;
    Ok(())
}

/// A cross at each event; named beside it when `labels`, else once in the legend.
fn mark_events(
    chart: &mut Chart<'_, '_>,
    events: &[&Event],
    labels: bool,
) -> Result<(), PlotError> {
    for (k, e) in events.iter().enumerate() {
        let at = xy(e.tip);
        let cross = chart
            .draw_series(std::iter::once(Cross::new(at, 7, EVENT.stroke_width(3))))
            .map_err(draw_err)?;
        if !labels {
            if k == 0 {
                let names: Vec<&str> = events.iter().map(|e| e.label.as_str()).collect();
                cross
                    .label(names.join(", "))
                    .legend(|(x, y)| Cross::new((x + 9, y), 5, EVENT.stroke_width(2)));
            }
            continue;
        }
        // Events at nearly one place keep their names apart: above, then below.
        let v = if k % 2 == 0 { VPos::Bottom } else { VPos::Top };
        chart
            .draw_series(std::iter::once(Text::new(
                format!("   {}", e.label),
                at,
                (FONT, 14)
                    .into_font()
                    .color(&EVENT)
                    .pos(Pos::new(HPos::Left, v)),
            )))
            .map_err(draw_err)?;
    }
    Ok(())
}

fn zoom_panel(
    area: &DrawingArea<SVGBackend, Shift>,
    phase: &Phase,
    samples: &[&Sample],
    events: &[&Event],
    colour: RGBColor,
) -> Result<(), PlotError> {
    let reference: Vec<(f64, f64)> = phase.reference.iter().map(|&p| xy(p)).collect();
    let trace: Vec<(f64, f64)> = samples.iter().map(|s| xy(s.tip_meas)).collect();
    // Room above the curve for the legend: a fifth of the curve's height a row (obstacles and
    // their margin add two rows to reference, tip and start).
    let rows = if phase.world.is_some() { 5.0 } else { 3.0 };
    let (x0, x1, y0, y1) = bbox(reference.iter().chain(&trace));
    let view = equal_ranges(
        (
            x0,
            x1,
            y0,
            y1 + 0.15 * rows * (y1 - y0).max(0.3 * (x1 - x0)),
        ),
        f64::from(COL_W - CHART_EXTRA.0),
        f64::from(ZOOM_H - CHART_EXTRA.1),
        0.12,
    );
    let view = (
        axis("tip's x", view.0.start, view.0.end)?,
        axis("tip's y", view.1.start, view.1.end)?,
    );
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{}: the tip", phase.label), (FONT, 17))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(view.0.clone(), view.1.clone())
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_label_formatter(&axis_label)
        .y_label_formatter(&axis_label)
        .light_line_style(TRANSPARENT)
        .bold_line_style(BLACK.mix(0.08))
        .x_desc("x (m)")
        .y_desc("y (m)")
        .x_labels(5)
        .y_labels(5)
        .draw()
        .map_err(draw_err)?;
    if let Some(world) = &phase.world {
        draw_world(&mut chart, world, (&view.0, &view.1))?;
    }
    if !reference.is_empty() {
        // A pale band under the measured line, so that both show where they agree.
        chart
            .draw_series(LineSeries::new(
                reference.iter().copied(),
                REFERENCE.mix(0.18).stroke_width(8),
            ))
            .map_err(draw_err)?
            .label("reference")
            .legend(|(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 18, y)],
                    REFERENCE.mix(0.18).stroke_width(8),
                )
            });
    }
    chart
        .draw_series(LineSeries::new(
            trace.iter().copied(),
            colour.stroke_width(2),
        ))
        .map_err(draw_err)?
        .label("tip, measured")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    if let Some(&start) = trace.first() {
        chart
            .draw_series(std::iter::once(Circle::new(start, 4, BLACK.filled())))
            .map_err(draw_err)?
            .label("start")
            .legend(|(x, y)| Circle::new((x + 9, y), 4, BLACK.filled()));
    }
    mark_events(&mut chart, events, true)?;
    legend_box(&mut chart, SeriesLabelPosition::UpperRight)?;
    Ok(())
}

/// Draws the obstacles of `world` clipped to the view `(xr, yr)`: each filled and outlined,
/// and dashed around it the obstacle grown by `link_radius_m + clearance_m`; named once in
/// the legend.
fn draw_world(
    chart: &mut Chart<'_, '_>,
    world: &World,
    (xr, yr): (&std::ops::Range<f64>, &std::ops::Range<f64>),
) -> Result<(), PlotError> {
    let (lo, hi) = (Vec2::new(xr.start, yr.start), Vec2::new(xr.end, yr.end));
    // About a pixel and a half: fine enough for round shapes, few points.
    let step = (hi.x - lo.x).max(hi.y - lo.y) / 300.0;
    let grow = world.link_radius_m() + world.clearance_m();
    let xy = |p: &Vec2| (p.x, p.y);
    let mut named = (false, false);
    for o in world.obstacles() {
        let mut ring = outline::boundary(&o.shape, step);
        let fill = outline::clip_polygon(&ring, lo, hi);
        if !fill.is_empty() {
            let series = chart
                .draw_series(std::iter::once(Polygon::new(
                    fill.iter().map(xy).collect::<Vec<_>>(),
                    OBSTACLE_FILL.filled(),
                )))
                .map_err(draw_err)?;
            if !named.0 {
                named.0 = true;
                series.label("obstacle").legend(|(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 18, y + 5)], OBSTACLE_FILL.filled())
                });
            }
        }
        if let Some(&first) = ring.first() {
            ring.push(first);
        }
        for piece in outline::clip_polyline(&ring, lo, hi) {
            chart
                .draw_series(LineSeries::new(
                    piece.iter().map(xy),
                    OBSTACLE_EDGE.stroke_width(1),
                ))
                .map_err(draw_err)?;
        }
        if grow <= 0.0 {
            continue;
        }
        for run in outline::grown(&o.shape, grow, step) {
            for piece in outline::clip_polyline(&run, lo, hi) {
                let series = chart
                    .draw_series(DashedLineSeries::new(
                        piece.iter().map(xy),
                        4,
                        3,
                        MARGIN.stroke_width(1),
                    ))
                    .map_err(draw_err)?;
                if !named.1 {
                    named.1 = true;
                    series.label("clearance margin").legend(|(x, y)| {
                        plotters::element::DashedPathElement::new(
                            vec![(x, y), (x + 18, y)],
                            4,
                            3,
                            MARGIN.stroke_width(1),
                        )
                    });
                }
            }
        }
    }
    Ok(())
}

/// Colour of joint `j` of `n`: from deep blue at the base through green to amber at the tip.
fn joint_colour(j: usize, n: usize) -> RGBColor {
    const STOPS: [(f64, f64, f64); 4] = [
        (40.0, 50.0, 150.0),
        (30.0, 140.0, 160.0),
        (90.0, 170.0, 70.0),
        (230.0, 160.0, 20.0),
    ];
    let s = if n > 1 {
        j as f64 / (n - 1) as f64
    } else {
        0.0
    } * (STOPS.len() - 1) as f64;
    let k = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - k as f64;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    let mix = |x: f64, y: f64| (x + (y - x) * f).round().clamp(0.0, 255.0) as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

const TIME_W: u32 = 1200;
const ANGLES_H: u32 = 420;
const ERROR_H: u32 = 280;
const LEGEND_W: u32 = 120;

/// The time figure as SVG text: joint angles, then the tracking error, against time.
pub fn joints(record: &Record, title: &str) -> Result<String, PlotError> {
    let first = record.samples.first().ok_or(PlotError::Empty)?;
    let last = record.samples.last().ok_or(PlotError::Empty)?;
    record.check()?;
    let n = first.theta.len();
    let (t0, t1) = (first.t_s, last.t_s.max(first.t_s + 1e-3));
    let angles = record.samples.iter().flat_map(|s| s.theta.iter().copied());
    let (lo, hi) = angles
        .fold(None, |b: Option<(f64, f64)>, a| {
            Some(b.map_or((a, a), |(lo, hi)| (lo.min(a), hi.max(a))))
        })
        // No angle in any sample: an empty chart, one radian each side of zero.
        .unwrap_or((-1.0, 1.0));
    let pad = 0.08 * (hi - lo).max(0.05);
    let (lo, hi) = (lo - pad, hi + 2.5 * pad);
    let err_max = record
        .samples
        .iter()
        .map(|s| s.tracking_error_m * 1e3)
        .fold(0.0, f64::max)
        .max(0.1)
        * 1.15;
    let (time, angle, error) = (
        axis("time", t0, t1)?,
        axis("angle", lo, hi)?,
        axis("error", 0.0, err_max)?,
    );
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (TIME_W, TITLE_H + ANGLES_H + ERROR_H))
            .into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root.titled(title, (FONT, 22)).map_err(draw_err)?;
        let (top, bottom) = root.split_vertically(ANGLES_H);
        let (angles_area, legend_area) = top.split_horizontally(TIME_W - LEGEND_W);
        let (error_area, _) = bottom.split_horizontally(TIME_W - LEGEND_W);

        let mut chart = ChartBuilder::on(&angles_area)
            .caption("measured joint angles", (FONT, 17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(time.clone(), angle)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_label_formatter(&axis_label)
            .y_label_formatter(&axis_label)
            .light_line_style(TRANSPARENT)
            .bold_line_style(BLACK.mix(0.08))
            .x_desc("time (s)")
            .y_desc("angle (rad)")
            .draw()
            .map_err(draw_err)?;
        shade_phases(&mut chart, record, (lo, hi), true)?;
        for j in 0..n {
            let colour = joint_colour(j, n);
            chart
                .draw_series(LineSeries::new(
                    record
                        .samples
                        .iter()
                        .filter_map(|s| s.theta.get(j).map(|&a| (s.t_s, a))),
                    colour.stroke_width(2),
                ))
                .map_err(draw_err)?;
        }
        mark_times(&mut chart, record, (lo, hi), true)?;
        joint_legend(&legend_area, n)?;

        let mut chart = ChartBuilder::on(&error_area)
            .caption("tracking error |tip_ref - tip_meas|", (FONT, 17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(time, error)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_label_formatter(&axis_label)
            .y_label_formatter(&axis_label)
            .light_line_style(TRANSPARENT)
            .bold_line_style(BLACK.mix(0.08))
            .x_desc("time (s)")
            .y_desc("error (mm)")
            .draw()
            .map_err(draw_err)?;
        shade_phases(&mut chart, record, (0.0, err_max), false)?;
        let errors: Vec<f64> = record
            .samples
            .iter()
            .map(|s| s.tracking_error_m * 1e3)
            .collect();
        let times = record.samples.iter().map(|s| s.t_s);
        chart
            .draw_series(LineSeries::new(
                times.clone().zip(errors.iter().copied()),
                BLACK.mix(0.3).stroke_width(1),
            ))
            .map_err(draw_err)?
            .label("each sample")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.mix(0.3)));
        chart
            .draw_series(LineSeries::new(
                times.zip(rolling_median(&errors, MEDIAN_HALF)),
                BLACK.stroke_width(2),
            ))
            .map_err(draw_err)?
            .label(format!("median of {} samples", 2 * MEDIAN_HALF + 1))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(2)));
        mark_times(&mut chart, record, (0.0, err_max), false)?;
        legend_box(&mut chart, SeriesLabelPosition::UpperLeft)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Draws a chart's legend at `position`, in the one style every panel uses.
fn legend_box<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), PlotError> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FONT, 13))
        .draw()
        .map_err(draw_err)
}

/// Samples each side of the tracking error's running median.
const MEDIAN_HALF: usize = 12;

/// The median of each value and the `half` values each side of it (fewer at the ends).
fn rolling_median(values: &[f64], half: usize) -> Vec<f64> {
    let mut window = Vec::with_capacity(2 * half + 1);
    (0..values.len())
        .map(|i| {
            window.clear();
            window.extend_from_slice(
                &values[i.saturating_sub(half)..(i + half + 1).min(values.len())],
            );
            window.sort_by(f64::total_cmp);
            window[window.len() / 2]
        })
        .collect()
}

type Chart<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Pale bands under the pictured phases, named at the top when `labels`.
fn shade_phases(
    chart: &mut Chart<'_, '_>,
    record: &Record,
    (lo, hi): (f64, f64),
    labels: bool,
) -> Result<(), PlotError> {
    for (i, phase) in record.pictured().enumerate() {
        let colour = PHASE_COLOURS[i % PHASE_COLOURS.len()];
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(phase.t0, lo), (phase.t1, hi)],
                colour.mix(0.10).filled(),
            )))
            .map_err(draw_err)?;
        if labels {
            chart
                .draw_series(std::iter::once(Text::new(
                    phase.label.clone(),
                    (phase.t0, hi),
                    (FONT, 14)
                        .into_font()
                        .color(&colour)
                        .pos(Pos::new(HPos::Left, VPos::Top)),
                )))
                .map_err(draw_err)?;
        }
    }
    Ok(())
}

/// A dashed vertical line at each event, named near the top when `labels`.
fn mark_times(
    chart: &mut Chart<'_, '_>,
    record: &Record,
    (lo, hi): (f64, f64),
    labels: bool,
) -> Result<(), PlotError> {
    for (k, e) in record.events.iter().enumerate() {
        chart
            .draw_series(DashedLineSeries::new(
                [(e.t_s, lo), (e.t_s, hi)],
                5,
                4,
                EVENT.stroke_width(2),
            ))
            .map_err(draw_err)?;
        if labels {
            // Staggered, so that events close in time keep their names apart.
            let y = hi - (0.14 + 0.06 * (k % 2) as f64) * (hi - lo);
            chart
                .draw_series(std::iter::once(Text::new(
                    format!(" {}", e.label),
                    (e.t_s, y),
                    (FONT, 14)
                        .into_font()
                        .color(&EVENT)
                        .pos(Pos::new(HPos::Left, VPos::Center)),
                )))
                .map_err(draw_err)?;
        }
    }
    Ok(())
}

/// The joints' colours, base to tip, in a column beside the angle chart.
fn joint_legend(area: &DrawingArea<SVGBackend, Shift>, n: usize) -> Result<(), PlotError> {
    let font = TextStyle::from((FONT, 13).into_font());
    let (x, mut y) = (8, 46);
    for j in 0..n {
        let colour = joint_colour(j, n);
        area.draw(&PathElement::new(
            vec![(x, y), (x + 22, y)],
            colour.stroke_width(3),
        ))
        .map_err(draw_err)?;
        let name = match j {
            0 => format!("joint {} (base)", j + 1),
            _ if j + 1 == n => format!("joint {} (tip)", j + 1),
            _ => format!("joint {}", j + 1),
        };
        area.draw(&Text::new(
            name,
            (x + 28, y),
            font.clone().pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(draw_err)?;
        y += 22;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn spread_keeps_both_ends_and_never_repeats() {
        assert_eq!(spread(0, 6), Vec::<usize>::new());
        assert_eq!(spread(1, 6), vec![0]);
        assert_eq!(spread(3, 6), vec![0, 1, 2]);
        assert_eq!(spread(101, 5), vec![0, 25, 50, 75, 100]);
    }

    #[test]
    fn a_view_of_a_tip_that_barely_moved_is_a_millimetre_across() {
        let (x, y) = equal_ranges(
            (0.27448, 0.27448 + 2e-7, 0.32976, 0.32976),
            300.0,
            300.0,
            0.0,
        );
        assert!((x.end - x.start - MIN_VIEW_M).abs() < 1e-12, "{x:?}");
        assert!((y.end - y.start - MIN_VIEW_M).abs() < 1e-12, "{y:?}");
    }

    #[test]
    fn equal_ranges_give_both_axes_one_scale() {
        let (x, y) = equal_ranges((0.0, 2.0, 0.0, 1.0), 400.0, 100.0, 0.0);
        let (sx, sy) = (400.0 / (x.end - x.start), 100.0 / (y.end - y.start));
        assert!((sx - sy).abs() < 1e-9, "{sx} vs {sy}");
        assert!(x.start <= 0.0 && x.end >= 2.0 && y.start <= 0.0 && y.end >= 1.0);
    }

    #[test]
    fn the_running_median_ignores_single_spikes() {
        let v = [1.0, 1.0, 9.0, 1.0, 1.0, 2.0, 2.0];
        assert_eq!(
            rolling_median(&v, 1),
            vec![1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 2.0]
        );
        assert!(rolling_median(&[], 3).is_empty());
    }

    use crate::world::{Obstacle, Shape};

    /// A three-link arm swinging up once, in one pictured phase, among `world`.
    fn swing(world: Option<World>) -> Record {
        let chain = Chain::unlimited(vec![0.2, 0.15, 0.1], Vec2::zeros(), 0.0).unwrap();
        let samples: Vec<Sample> = (0..=20)
            .map(|k| {
                let theta = vec![0.05 * k as f64, 0.3, 0.2];
                let tip = chain.tip(&theta);
                Sample {
                    t_s: 0.1 * k as f64,
                    theta,
                    tip_ref: [tip.x, tip.y],
                    tip_meas: [tip.x, tip.y],
                    tracking_error_m: 0.0,
                }
            })
            .collect();
        Record {
            chain: Some(chain),
            phases: vec![Phase {
                label: "among obstacles".into(),
                t0: 0.0,
                t1: 2.0,
                reference: Vec::new(),
                pictured: true,
                world,
            }],
            samples,
            events: Vec::new(),
        }
    }

    /// The point lists of the SVG's polygons filled with `colour`, in pixels, in order.
    fn filled_polygons(svg: &str, colour: RGBColor) -> Vec<Vec<(f64, f64)>> {
        let fill = format!("fill=\"#{:02X}{:02X}{:02X}\"", colour.0, colour.1, colour.2);
        svg.split("<polygon")
            .skip(1)
            .filter(|tag| tag.split("/>").next().unwrap().contains(&fill))
            .map(|tag| {
                let points = tag.split("points=\"").nth(1).unwrap();
                points[..points.find('"').unwrap()]
                    .split_whitespace()
                    .map(|xy| {
                        let (x, y) = xy.split_once(',').unwrap();
                        (x.parse().unwrap(), y.parse().unwrap())
                    })
                    .collect()
            })
            .collect()
    }

    /// A recording of thousands of pictured phases draws the first [`MAX_PICTURED`], as wide
    /// as a recording of only those.
    #[test]
    fn only_the_first_phases_get_a_column() {
        let mut many = swing(None);
        let one = many.phases[0].clone();
        many.phases = (0..5000)
            .map(|k| Phase {
                label: format!("phase {k}"),
                t0: k as f64 * 1e-4,
                t1: 2.0,
                ..one.clone()
            })
            .collect();
        let mut first = many.clone();
        first.phases.truncate(MAX_PICTURED);
        assert_eq!(motion(&many, "t").unwrap(), motion(&first, "t").unwrap());
        assert_eq!(many.pictured().count(), MAX_PICTURED);
    }

    #[test]
    fn the_obstacles_of_a_phase_are_drawn_where_they_are() {
        let (center, radius) = ((0.05, 0.3), 0.04);
        let shelf = [(-0.15, 0.1), (-0.05, 0.1), (-0.05, 0.13), (-0.15, 0.13)];
        let world = World::new(
            0.01,
            0.005,
            vec![
                Obstacle {
                    id: "post".into(),
                    shape: Shape::Circle {
                        center: Vec2::new(center.0, center.1),
                        radius_m: radius,
                    },
                },
                Obstacle {
                    id: "shelf".into(),
                    shape: Shape::Polygon {
                        points: shelf.iter().map(|&(x, y)| Vec2::new(x, y)).collect(),
                    },
                },
            ],
        )
        .unwrap();
        let svg = motion(&swing(Some(world)), "t").unwrap();
        let shapes = filled_polygons(&svg, OBSTACLE_FILL);
        assert!(shapes.len() >= 2, "{} obstacle fills", shapes.len());
        // The arm's panel first: the post, a ring of pixels round its centre.
        let post = &shapes[0];
        let n = post.len() as f64;
        let c = (
            post.iter().map(|p| p.0).sum::<f64>() / n,
            post.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let r_px = post
            .iter()
            .map(|p| (p.0 - c.0).hypot(p.1 - c.1))
            .sum::<f64>()
            / n;
        assert!(r_px > 5.0, "{r_px}");
        for p in post {
            assert!(((p.0 - c.0).hypot(p.1 - c.1) - r_px).abs() < 1.0, "{p:?}");
        }
        // One scale on both axes: the shelf's corners lie where the post's pixels say.
        let scale = r_px / radius;
        let drawn = &shapes[1];
        assert_eq!(drawn.len(), shelf.len());
        for (&(x, y), &(px, py)) in shelf.iter().zip(drawn) {
            let want = (c.0 + scale * (x - center.0), c.1 - scale * (y - center.1));
            assert!(
                (px - want.0).abs() < 1.5 && (py - want.1).abs() < 1.5,
                "({x}, {y}) at ({px}, {py}), expected {want:?}"
            );
        }
        // The clearance margin is drawn dashed, and named in the legend.
        assert!(svg.contains("clearance margin") && svg.contains("obstacle"));
        let margin = format!("#{:02X}{:02X}{:02X}", MARGIN.0, MARGIN.1, MARGIN.2);
        assert!(svg.matches(&margin).count() > 10);
        // Without a world, none of it.
        let plain = motion(&swing(None), "t").unwrap();
        assert!(filled_polygons(&plain, OBSTACLE_FILL).is_empty());
        assert!(!plain.contains(&margin) && !plain.contains("clearance margin"));
    }

    /// The axes of the demo's arm (base at the origin, the arm leaning left of it) are labelled
    /// without a "-0.0" where an axis crosses zero.
    #[test]
    fn no_axis_label_reads_negative_zero() {
        assert_eq!(axis_label(&-2.8e-17), "0.0");
        assert_eq!(axis_label(&-0.0), "0.0");
        assert_eq!(axis_label(&-0.2), "-0.2");
        assert_eq!(axis_label(&0.25), "0.25");
        let mut record = swing(None);
        let chain = Chain::unlimited(
            vec![0.2, 0.15, 0.1],
            Vec2::zeros(),
            std::f64::consts::FRAC_PI_2,
        )
        .unwrap();
        for s in &mut record.samples {
            let tip = chain.tip(&s.theta);
            s.tip_ref = [tip.x, tip.y];
            s.tip_meas = [tip.x, tip.y];
        }
        record.chain = Some(chain);
        let svg = motion(&record, "t").unwrap();
        let labels: Vec<&str> = svg
            .split("</text>")
            .filter_map(|piece| piece.rsplit('>').next())
            .map(str::trim)
            .collect();
        assert!(labels.contains(&"0.0"), "no label at zero: {labels:?}");
        assert!(!labels.contains(&"-0.0"), "{labels:?}");
    }

    /// `f()`, run on a thread of its own and waited for at most a minute: a bound on a test
    /// that would otherwise never end, not a speed asked for.
    fn ends<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        rx.recv_timeout(std::time::Duration::from_secs(60))
            .expect("drawing did not end")
    }

    #[test]
    fn an_axis_must_be_finite_and_wide_enough_for_its_ticks() {
        assert_eq!(axis("x", -0.5, 2.0), Ok(-0.5..2.0));
        assert_eq!(axis("x", 1e6, 1e6 + 1e-3), Ok(1e6..1e6 + 1e-3));
        assert_eq!(axis("x", 0.0, 1e300), Ok(0.0..1e300));
        for (lo, hi) in [
            (0.0, f64::INFINITY),
            (f64::NAN, 1.0),
            // Finite ends, an infinite span.
            (-1e308, 1e308),
            // Ends that round to one value, or nearly.
            (1e308, 1e308),
            (1e16, 1e16 + 2.0),
            (1.0, 0.0),
        ] {
            assert!(
                matches!(axis("x", lo, hi), Err(PlotError::Axis { axis: "x", .. })),
                "{lo}..{hi}"
            );
        }
    }

    /// Values no run records (a tip at 1e308 m, a tracking error of 1e307 m, a time without
    /// end) are refused naming the field; a run without joint angles draws. None of them
    /// makes a figure's drawing run without end.
    #[test]
    fn values_no_run_records_are_refused_and_drawing_always_ends() {
        type Spoil = fn(&mut Sample);
        let cases: [(&str, Spoil); 4] = [
            ("tip_meas", |s| s.tip_meas = [1e308, 1e308]),
            ("tip_meas", |s| s.tip_meas = [-1e308, 1e308]),
            ("tracking_error_m", |s| s.tracking_error_m = 1e307),
            ("t_s", |s| s.t_s = f64::INFINITY),
        ];
        for (field, spoil) in cases {
            let mut record = swing(None);
            record.samples.iter_mut().for_each(spoil);
            let (m, j) = ends(move || (motion(&record, "t"), joints(&record, "t")));
            for e in [m.unwrap_err(), j.unwrap_err()] {
                assert!(
                    matches!(&e, PlotError::Unusable { field: f, .. } if *f == field),
                    "{e}"
                );
                assert!(e.to_string().contains("the recording is damaged"), "{e}");
            }
        }
        let mut record = swing(None);
        record.samples.iter_mut().for_each(|s| s.theta.clear());
        let (m, j) = ends(move || (motion(&record, "t"), joints(&record, "t")));
        assert!(m.is_ok() && j.is_ok(), "{m:?} {j:?}");
    }

    #[test]
    fn an_empty_record_is_refused() {
        let record = Record::default();
        assert_eq!(motion(&record, "t"), Err(PlotError::Empty));
        assert_eq!(joints(&record, "t"), Err(PlotError::Empty));
    }
}
