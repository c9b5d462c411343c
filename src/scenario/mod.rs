//! Flexible-object scenarios: a TOML file describing an initial curve, how its end is pulled and
//! which strategies to compare (the paper's experiments). Parsed raw (`deny_unknown_fields`
//! everywhere), then validated; every error names the file and the field. [`Scenario::run`]
//! simulates every strategy for every step count and returns the frames and metrics.
//!
//! ```toml
//! title = "Straight rope pulled sideways"
//! links = 20                       # n rigid links of equal chord length along the curve
//!
//! [curve]                          # line | sine | parabola | arc | parametric | polyline
//! kind = "line"
//! from_m = [1.0, 0.0]
//! to_m = [0.0, 0.0]
//! pulled = "end"                   # or "start"; default: the end at the larger parameter
//!
//! [pull]                           # straight | sine
//! kind = "straight"
//! displacement_m = [0.0, 0.5]
//! steps = [1, 20]                  # one column per value: 1 = single step
//!
//! [[strategy]]                     # tractrix | distance | overall
//! kind = "overall"
//! objective = "m3"                 # m1..m5, default m2
//! companion_weight = 0.5           # m3 and m5 only (and required there)
//!
//! [plot]                           # optional
//! intermediates = 10               # dotted intermediate configurations drawn, at most
//! loci = true                      # joint trajectories
//! ```
//!
//! Curve fields, by kind: `line`: `from_m`, `to_m`; `sine`: `x_range_m`, `amplitude_m`,
//! `wavelength_m`, `phase_rad` (default 0); `parabola`: `x_range_m`, `coefficient_per_m`
//! (`y = c x^2`); `arc`: `center_m`, `radius_m`, `from_deg`, `to_deg`; `parametric`: `x`, `y`
//! (expressions in `t`, see [`expr`]), `t_range`; `polyline`: `file` (CSV of `x,y` rows, an
//! optional header line, relative to the scenario file; read as a tip's path file is). Pull fields: `straight`: `displacement_m`;
//! `sine`: `displacement_m` (the overall advance), `amplitude_m` (sideways, to the left of the
//! advance), `periods`; both: `steps`. A sine path is split into `K` straight pieces of equal
//! parameter.

pub mod curve;
pub mod expr;
pub mod table;

use std::path::Path;

use serde::Deserialize;

use crate::chain::{wrap_angle, Vec2, MAX_MAGNITUDE};
use crate::metrics::{self, Metrics};
use crate::resolve::sequential::pull_free;
use crate::resolve::tractrix::Propagation;
use crate::rope::{Objective, RopeOptimizer};
use crate::textfile::{parse_points, read_text, MAX_TEXT_BYTES};
use crate::world::label_fault;

use curve::Curve;
use expr::Expr;

/// A refused scenario: the file, where in it for text that is not valid TOML or not of the
/// right type (`file:line:column`, as the config's errors), the field and what is wrong.
/// Displays on one line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}{}: {field}: {message}", at_text(*.at))]
pub struct ScenarioError {
    /// The scenario file.
    pub file: String,
    /// Line and column (from 1) of a TOML error, where the parser gave them.
    pub at: Option<(usize, usize)>,
    /// The field (`curve.amplitude_m`, `strategy[1].objective`, ...), or `input` for the whole.
    pub field: String,
    /// What is wrong, with the value.
    pub message: String,
}

/// `:line:column`, or nothing.
fn at_text(at: Option<(usize, usize)>) -> String {
    at.map(|(line, column)| format!(":{line}:{column}"))
        .unwrap_or_default()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenario {
    #[serde(default)]
    title: Option<String>,
    links: i64,
    curve: RawCurve,
    pull: RawPull,
    strategy: Vec<RawStrategy>,
    #[serde(default)]
    plot: Option<RawPlot>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCurve {
    kind: String,
    #[serde(default)]
    pulled: Option<String>,
    from_m: Option<Vec<f64>>,
    to_m: Option<Vec<f64>>,
    x_range_m: Option<Vec<f64>>,
    amplitude_m: Option<f64>,
    wavelength_m: Option<f64>,
    phase_rad: Option<f64>,
    coefficient_per_m: Option<f64>,
    center_m: Option<Vec<f64>>,
    radius_m: Option<f64>,
    from_deg: Option<f64>,
    to_deg: Option<f64>,
    x: Option<String>,
    y: Option<String>,
    t_range: Option<Vec<f64>>,
    file: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPull {
    kind: String,
    displacement_m: Vec<f64>,
    amplitude_m: Option<f64>,
    periods: Option<f64>,
    steps: Vec<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStrategy {
    kind: String,
    objective: Option<String>,
    companion_weight: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlot {
    intermediates: Option<i64>,
    loci: Option<bool>,
}

/// How the pulled end moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Pull {
    /// A straight displacement.
    Straight {
        /// Displacement, m.
        displacement: Vec2,
    },
    /// Advance by `displacement` while swinging sideways by `amplitude sin(2 pi periods s)`.
    Sine {
        /// Overall advance, m.
        displacement: Vec2,
        /// Sideways amplitude (to the left of the advance), m.
        amplitude: f64,
        /// Number of periods over the pull.
        periods: f64,
    },
}

impl Pull {
    /// The pulled end's position at path parameter `s` in [0, 1], from `start`.
    pub fn at(&self, start: Vec2, s: f64) -> Vec2 {
        match self {
            Pull::Straight { displacement } => start + displacement * s,
            Pull::Sine {
                displacement,
                amplitude,
                periods,
            } => {
                let normal = Vec2::new(-displacement.y, displacement.x) / displacement.norm();
                start
                    + displacement * s
                    + normal * (amplitude * (2.0 * std::f64::consts::PI * periods * s).sin())
            }
        }
    }
}

/// A strategy to run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StrategySpec {
    /// Sequential, with the given elemental step.
    Sequential(Propagation),
    /// The overall optimization of the free rope.
    Overall(Objective),
}

impl StrategySpec {
    /// Short label: `tractrix`, `distance`, `overall m2`, `overall m3+0.5m1`.
    pub fn label(&self) -> String {
        match self {
            StrategySpec::Sequential(p) => format!("sequential {}", p.name()),
            StrategySpec::Overall(o) => match o.companion_weight() {
                Some(w) => format!("overall {}+{w}m1", o.name()),
                None => format!("overall {}", o.name()),
            },
        }
    }
}

/// Plot options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotSpec {
    /// Dotted intermediate configurations drawn, at most.
    pub intermediates: usize,
    /// Whether to draw joint trajectories.
    pub loci: bool,
}

/// A validated scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Title for figures and tables.
    pub title: String,
    /// Initial points, the free end first, the pulled end last.
    pub points: Vec<Vec2>,
    /// Link lengths (equal chords, to round-off).
    pub links: Vec<f64>,
    /// The pull of the end.
    pub pull: Pull,
    /// Step counts, one column each.
    pub steps: Vec<usize>,
    /// Strategies, one row of figures each.
    pub strategies: Vec<StrategySpec>,
    /// Plot options.
    pub plot: PlotSpec,
}

/// One strategy run with one step count.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// The strategy.
    pub strategy: StrategySpec,
    /// Number of straight pieces of the pull.
    pub steps: usize,
    /// Configurations: the initial one, then one after each step.
    pub frames: Vec<Vec<Vec2>>,
    /// The five metrics between the initial and the final configuration.
    pub metrics: Metrics,
    /// Optimizer iterations (0 for the sequential strategies).
    pub iterations: usize,
    /// Whether every optimization met its stopping rule.
    pub converged: bool,
    /// Largest link length error over every frame, m.
    pub length_residual: f64,
}

impl Run {
    /// Column label: `sequential tractrix, K=1`.
    pub fn label(&self) -> String {
        format!("{}, K={}", self.strategy.label(), self.steps)
    }

    /// The final configuration.
    pub fn last(&self) -> &[Vec2] {
        self.frames.last().map_or(&[], |f| f.as_slice())
    }
}

/// Per interior point `i = 1..n-1` of the initial curve: the arc length from the pulled end
/// `sigma_i` and the rotation there between `old` and `new` (wrapped), rad.
pub fn rotations(old: &[Vec2], new: &[Vec2]) -> Vec<(f64, f64)> {
    let n = old.len() - 1;
    let mut sigma = vec![0.0; n + 1];
    metrics::arc_to_tip(old, &mut sigma);
    let heading = |p: &[Vec2], i: usize| (p[i + 1] - p[i]).y.atan2((p[i + 1] - p[i]).x);
    (1..n)
        .map(|i| {
            let before = heading(old, i) - heading(old, i - 1);
            let after = heading(new, i) - heading(new, i - 1);
            (sigma[i], wrap_angle(after - before))
        })
        .collect()
}

/// The longest title a scenario may have, in characters: it heads every figure (the time to
/// lay out a title's text grows faster than its length) and the tables.
pub const MAX_TITLE_CHARS: usize = 200;

/// The most points a scenario may keep: every run (strategy × step count) keeps its `steps + 1`
/// configurations of `links + 1` points each, for the figures (16 bytes a point: 32 MB).
pub const MAX_STORED_POINTS: usize = 2_000_000;

/// The points a scenario of `links` links keeps over its runs: `strategies` times the sum over
/// the step counts `K` of `(K + 1) (links + 1)`. Saturates rather than overflows.
pub fn stored_points(links: usize, steps: &[usize], strategies: usize) -> usize {
    steps
        .iter()
        .fold(0usize, |acc, &k| {
            acc.saturating_add(k.saturating_add(1).saturating_mul(links.saturating_add(1)))
        })
        .saturating_mul(strategies)
}

struct Ctx<'a> {
    file: &'a str,
}

impl Ctx<'_> {
    fn err(&self, field: impl Into<String>, message: impl Into<String>) -> ScenarioError {
        ScenarioError {
            file: self.file.to_string(),
            at: None,
            field: field.into(),
            message: message.into(),
        }
    }

    fn number(&self, field: &str, v: f64) -> Result<f64, ScenarioError> {
        if v.is_finite() && v.abs() <= MAX_MAGNITUDE {
            Ok(v)
        } else {
            Err(self.err(
                field,
                format!("{v} must be finite and at most {MAX_MAGNITUDE:e} in magnitude"),
            ))
        }
    }

    fn positive(&self, field: &str, v: f64) -> Result<f64, ScenarioError> {
        let v = self.number(field, v)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(field, format!("{v} must be positive")))
        }
    }

    fn required<T: Clone>(&self, field: &str, v: &Option<T>) -> Result<T, ScenarioError> {
        v.clone()
            .ok_or_else(|| self.err(field, "missing (required for this kind)"))
    }

    fn pair(&self, field: &str, v: &[f64]) -> Result<[f64; 2], ScenarioError> {
        if v.len() != 2 {
            return Err(self.err(field, format!("expected 2 numbers, got {}", v.len())));
        }
        Ok([
            self.number(&format!("{field}[0]"), v[0])?,
            self.number(&format!("{field}[1]"), v[1])?,
        ])
    }

    fn range(&self, field: &str, v: &[f64]) -> Result<[f64; 2], ScenarioError> {
        let r = self.pair(field, v)?;
        if r[0] == r[1] {
            return Err(self.err(field, "the range is empty"));
        }
        Ok(r)
    }
}

impl Scenario {
    /// Reads and validates a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let file = path.display().to_string();
        let text = read_text(path, MAX_TEXT_BYTES).map_err(|e| ScenarioError {
            file: file.clone(),
            at: None,
            field: "input".into(),
            message: format!("cannot read the file: {e}"),
        })?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::from_toml(&text, &file, &dir)
    }

    /// Parses and validates scenario text; `file` names it in errors, `dir` resolves the CSV a
    /// polyline curve names.
    pub fn from_toml(text: &str, file: &str, dir: &Path) -> Result<Self, ScenarioError> {
        let cx = Ctx { file };
        let raw: RawScenario = toml::from_str(text).map_err(|e| {
            let (line, column, message) = crate::config::toml_where(text, &e);
            let table = e
                .span()
                .map(|s| table_at(text, s.start))
                .unwrap_or_default();
            let key = e
                .span()
                .and_then(|s| key_at(text, s.start))
                .filter(|_| unknown_field(&message).is_none());
            // An unknown table's span is its own `[header]`, which `table_at` already counts.
            let on_header = e.span().is_some_and(|s| {
                let at = s.start.min(text.len());
                let start = text[..at].rfind('\n').map_or(0, |i| i + 1);
                text[start..].trim_start().starts_with('[')
            });
            let field = match (unknown_field(&message).or(key), table.is_empty()) {
                (Some(f), false) if on_header && table.split('.').next_back() == Some(&*f) => table,
                (Some(f), true) => f,
                (Some(f), false) => format!("{table}.{f}"),
                (None, false) => table,
                (None, true) => "input".into(),
            };
            let message = if message.starts_with("unknown field") && !field.contains(['.', '[']) {
                format!(
                    "{message}: a top-level key or table no scenario has; is this a scenario \
                     file?"
                )
            } else {
                message
            };
            ScenarioError {
                at: (line > 0).then_some((line, column)),
                ..cx.err(field, message)
            }
        })?;
        if let Some(why) = raw
            .title
            .as_deref()
            .and_then(|t| label_fault("title", t, MAX_TITLE_CHARS))
        {
            return Err(cx.err("title", why));
        }
        let n = usize::try_from(raw.links)
            .ok()
            .filter(|&n| (1..=100_000).contains(&n))
            .ok_or_else(|| cx.err("links", format!("{} must be 1..=100000", raw.links)))?;
        let (curve, reverse) = curve_of(&cx, &raw.curve, dir)?;
        let mut points =
            curve::discretize(&curve, n).map_err(|e| cx.err("curve", e.to_string()))?;
        if reverse {
            points.reverse();
        }
        let links = points.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
        let pull = pull_of(&cx, &raw.pull)?;
        let mut steps = Vec::new();
        if raw.pull.steps.is_empty() {
            return Err(cx.err("pull.steps", "give at least one step count"));
        }
        for (i, &k) in raw.pull.steps.iter().enumerate() {
            let k = usize::try_from(k)
                .ok()
                .filter(|&k| (1..=100_000).contains(&k))
                .ok_or_else(|| {
                    cx.err(
                        format!("pull.steps[{i}]"),
                        format!("{k} must be 1..=100000"),
                    )
                })?;
            if let Some(j) = steps.iter().position(|&s| s == k) {
                return Err(cx.err(
                    format!("pull.steps[{i}]"),
                    format!("{k} repeats pull.steps[{j}]: each step count once"),
                ));
            }
            steps.push(k);
        }
        if raw.strategy.is_empty() {
            return Err(cx.err("strategy", "give at least one [[strategy]]"));
        }
        let mut strategies: Vec<StrategySpec> = Vec::new();
        for (i, s) in raw.strategy.iter().enumerate() {
            let spec = strategy_of(&cx, i, s)?;
            if let Some(j) = strategies.iter().position(|&t| t == spec) {
                return Err(cx.err(
                    format!("strategy[{i}]"),
                    format!(
                        "repeats strategy[{j}] ({}): each strategy once",
                        spec.label()
                    ),
                ));
            }
            strategies.push(spec);
        }
        let stored = stored_points(n, &steps, strategies.len());
        if stored > MAX_STORED_POINTS {
            return Err(cx.err(
                "links, pull.steps",
                format!(
                    "links = {n} with pull.steps = {steps:?} and {} strategies keeps {stored} \
                     points (every configuration of every run, for the figures); at most \
                     {MAX_STORED_POINTS}: lower links, pull.steps or the number of strategies",
                    strategies.len()
                ),
            ));
        }
        let plot = match &raw.plot {
            None => PlotSpec {
                intermediates: 10,
                loci: false,
            },
            Some(p) => PlotSpec {
                intermediates: match p.intermediates {
                    None => 10,
                    Some(k) => usize::try_from(k)
                        .ok()
                        .filter(|&k| k <= 1000)
                        .ok_or_else(|| {
                            cx.err("plot.intermediates", format!("{k} must be 0..=1000"))
                        })?,
                },
                loci: p.loci.unwrap_or(false),
            },
        };
        Ok(Self {
            title: raw.title.unwrap_or_else(|| default_title(file)),
            points,
            links,
            pull,
            steps,
            strategies,
            plot,
        })
    }

    /// Runs every strategy with every step count: strategies outer, step counts inner.
    pub fn run(&self) -> Vec<Run> {
        let mut runs = Vec::new();
        for &strategy in &self.strategies {
            for &steps in &self.steps {
                runs.push(self.run_one(strategy, steps));
            }
        }
        runs
    }

    /// One strategy with one step count.
    pub fn run_one(&self, strategy: StrategySpec, steps: usize) -> Run {
        let n = self.links.len();
        let start = self.points[n];
        let mut current = self.points.clone();
        let mut next = current.clone();
        let mut frames = vec![current.clone()];
        let mut scratch = Vec::new();
        let mut optimizer = RopeOptimizer::default();
        let mut iterations = 0;
        let mut converged = true;
        let mut length_residual: f64 = 0.0;
        for k in 1..=steps {
            let target = self.pull.at(start, k as f64 / steps as f64);
            match strategy {
                StrategySpec::Sequential(p) => {
                    pull_free(&mut current, &self.links, target, 1, p, &mut scratch);
                }
                StrategySpec::Overall(o) => {
                    match optimizer.solve(&current, &self.links, target, o, &mut next) {
                        Ok(r) => {
                            iterations += r.iterations;
                            converged &= r.converged;
                            current.copy_from_slice(&next);
                        }
                        Err(_) => converged = false,
                    }
                }
            }
            let (l, _) = crate::rope::residuals(&current, &self.links, target);
            length_residual = length_residual.max(l);
            frames.push(current.clone());
        }
        Run {
            strategy,
            steps,
            metrics: metrics::rope(&self.points, &current),
            frames,
            iterations,
            converged,
            length_residual,
        }
    }
}

/// The title of a scenario that gives none: its file's name, control characters shown as
/// U+FFFD and cut to [`MAX_TITLE_CHARS`], as a given title must be.
fn default_title(file: &str) -> String {
    file.chars()
        .map(|c| if c.is_control() { '\u{fffd}' } else { c })
        .take(MAX_TITLE_CHARS)
        .collect()
}

/// The field a serde "unknown field" or "missing field" message names.
fn unknown_field(message: &str) -> Option<String> {
    let rest = message
        .split("unknown field `")
        .nth(1)
        .or_else(|| message.split("missing field `").nth(1))?;
    Some(rest.split('`').next()?.to_string())
}

/// The key of the `key = value` line holding byte `offset` of `text`, if any.
fn key_at(text: &str, offset: usize) -> Option<String> {
    let start = text[..offset.min(text.len())]
        .rfind('\n')
        .map_or(0, |i| i + 1);
    let line = text[start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    (!key.is_empty() && !key.starts_with('[')).then(|| key.to_string())
}

/// The table (`curve`, `strategy[1]`) whose body holds byte `offset` of `text`; empty at the top
/// level.
fn table_at(text: &str, offset: usize) -> String {
    let mut table = String::new();
    let mut counts: Vec<(String, usize)> = Vec::new();
    let mut pos = 0;
    for line in text.split_inclusive('\n') {
        if pos > offset {
            break;
        }
        let t = line.trim();
        if let Some(name) = t.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = name.trim().to_string();
            let k = match counts.iter_mut().find(|(n, _)| *n == name) {
                Some((_, c)) => {
                    *c += 1;
                    *c
                }
                None => {
                    counts.push((name.clone(), 0));
                    0
                }
            };
            table = format!("{name}[{k}]");
        } else if let Some(name) = t.strip_prefix('[').and_then(|r| r.split(']').next()) {
            table = name.trim().to_string();
        }
        pos += line.len();
    }
    table
}

fn curve_of(cx: &Ctx, c: &RawCurve, dir: &Path) -> Result<(Curve, bool), ScenarioError> {
    let reverse = match c.pulled.as_deref() {
        None | Some("end") => false,
        Some("start") => true,
        Some(other) => {
            return Err(cx.err(
                "curve.pulled",
                format!("{other:?} must be \"start\" or \"end\""),
            ))
        }
    };
    // Fields each kind accepts; any other field given is refused by name.
    let given: [(&str, bool); 15] = [
        ("from_m", c.from_m.is_some()),
        ("to_m", c.to_m.is_some()),
        ("x_range_m", c.x_range_m.is_some()),
        ("amplitude_m", c.amplitude_m.is_some()),
        ("wavelength_m", c.wavelength_m.is_some()),
        ("phase_rad", c.phase_rad.is_some()),
        ("coefficient_per_m", c.coefficient_per_m.is_some()),
        ("center_m", c.center_m.is_some()),
        ("radius_m", c.radius_m.is_some()),
        ("from_deg", c.from_deg.is_some()),
        ("to_deg", c.to_deg.is_some()),
        ("x", c.x.is_some()),
        ("y", c.y.is_some()),
        ("t_range", c.t_range.is_some()),
        ("file", c.file.is_some()),
    ];
    let accepted: &[&str] = match c.kind.as_str() {
        "line" => &["from_m", "to_m"],
        "sine" => &["x_range_m", "amplitude_m", "wavelength_m", "phase_rad"],
        "parabola" => &["x_range_m", "coefficient_per_m"],
        "arc" => &["center_m", "radius_m", "from_deg", "to_deg"],
        "parametric" => &["x", "y", "t_range"],
        "polyline" => &["file"],
        other => {
            return Err(cx.err(
                "curve.kind",
                format!(
                    "unknown kind {other:?} (expected line, sine, parabola, arc, parametric or \
                     polyline)"
                ),
            ))
        }
    };
    if let Some((name, _)) = given.iter().find(|(n, g)| *g && !accepted.contains(n)) {
        return Err(cx.err(
            format!("curve.{name}"),
            format!("does not apply to a {} curve", c.kind),
        ));
    }
    let f = |name: &str| format!("curve.{name}");
    let curve = match c.kind.as_str() {
        "line" => {
            let a = cx.pair(&f("from_m"), &cx.required(&f("from_m"), &c.from_m)?)?;
            let b = cx.pair(&f("to_m"), &cx.required(&f("to_m"), &c.to_m)?)?;
            if a == b {
                return Err(cx.err(f("to_m"), "equals from_m: the line has no length"));
            }
            Curve::Line {
                from: Vec2::new(a[0], a[1]),
                to: Vec2::new(b[0], b[1]),
            }
        }
        "sine" => Curve::Sine {
            x_range: cx.range(
                &f("x_range_m"),
                &cx.required(&f("x_range_m"), &c.x_range_m)?,
            )?,
            amplitude: cx.number(
                &f("amplitude_m"),
                cx.required(&f("amplitude_m"), &c.amplitude_m)?,
            )?,
            wavelength: cx.positive(
                &f("wavelength_m"),
                cx.required(&f("wavelength_m"), &c.wavelength_m)?,
            )?,
            phase: cx.number(&f("phase_rad"), c.phase_rad.unwrap_or(0.0))?,
        },
        "parabola" => Curve::Parabola {
            x_range: cx.range(
                &f("x_range_m"),
                &cx.required(&f("x_range_m"), &c.x_range_m)?,
            )?,
            coefficient: cx.number(
                &f("coefficient_per_m"),
                cx.required(&f("coefficient_per_m"), &c.coefficient_per_m)?,
            )?,
        },
        "arc" => {
            let center = cx.pair(&f("center_m"), &cx.required(&f("center_m"), &c.center_m)?)?;
            let from = cx.number(&f("from_deg"), cx.required(&f("from_deg"), &c.from_deg)?)?;
            let to = cx.number(&f("to_deg"), cx.required(&f("to_deg"), &c.to_deg)?)?;
            if from == to || (to - from).abs() > 360.0 {
                return Err(cx.err(
                    f("to_deg"),
                    format!("the arc from {from} to {to} degrees must span (0, 360] degrees"),
                ));
            }
            Curve::Arc {
                center: Vec2::new(center[0], center[1]),
                radius: cx.positive(&f("radius_m"), cx.required(&f("radius_m"), &c.radius_m)?)?,
                from_rad: from.to_radians(),
                to_rad: to.to_radians(),
            }
        }
        "parametric" => {
            let parse = |name: &str, v: &Option<String>| -> Result<Expr, ScenarioError> {
                let text = cx.required(&f(name), v)?;
                Expr::parse(&text).map_err(|e| cx.err(f(name), format!("{text:?}: {e}")))
            };
            Curve::Parametric {
                x: parse("x", &c.x)?,
                y: parse("y", &c.y)?,
                t_range: cx.range(&f("t_range"), &cx.required(&f("t_range"), &c.t_range)?)?,
            }
        }
        _ => {
            let name = cx.required(&f("file"), &c.file)?;
            let path = dir.join(&name);
            Curve::Polyline(read_polyline(cx, &path)?)
        }
    };
    Ok((curve, reverse))
}

/// Reads the CSV of `x,y` rows a polyline curve names, by the rules of a tip's path file
/// ([`parse_points`]: only the first line may be a header). Errors name the scenario file and
/// `curve.file`, then the CSV and its line.
fn read_polyline(cx: &Ctx, path: &Path) -> Result<Vec<Vec2>, ScenarioError> {
    let csv = path.display();
    let err = |message: String| cx.err("curve.file", message);
    let text =
        read_text(path, MAX_TEXT_BYTES).map_err(|e| err(format!("{csv}: cannot read it: {e}")))?;
    let rows = parse_points(&text).map_err(|e| err(e.in_file(&csv)))?;
    let mut pts: Vec<Vec2> = Vec::new();
    for row in rows {
        let [x, y] = row.xy;
        if x.abs() > MAX_MAGNITUDE || y.abs() > MAX_MAGNITUDE {
            return Err(err(format!(
                "{csv}:{}: a coordinate beyond {MAX_MAGNITUDE:e} in magnitude",
                row.line
            )));
        }
        let p = Vec2::new(x, y);
        if pts.last() != Some(&p) {
            pts.push(p);
        }
    }
    if pts.len() < 2 {
        return Err(err(format!(
            "{csv}: {} distinct points; a polyline needs at least 2",
            pts.len()
        )));
    }
    Ok(pts)
}

fn pull_of(cx: &Ctx, p: &RawPull) -> Result<Pull, ScenarioError> {
    let d = cx.pair("pull.displacement_m", &p.displacement_m)?;
    let displacement = Vec2::new(d[0], d[1]);
    match p.kind.as_str() {
        "straight" => {
            for (name, given) in [
                ("amplitude_m", p.amplitude_m.is_some()),
                ("periods", p.periods.is_some()),
            ] {
                if given {
                    return Err(cx.err(format!("pull.{name}"), "does not apply to a straight pull"));
                }
            }
            Ok(Pull::Straight { displacement })
        }
        "sine" => {
            if displacement.norm() == 0.0 {
                return Err(cx.err(
                    "pull.displacement_m",
                    "a sine pull needs a non-zero advance to swing across",
                ));
            }
            Ok(Pull::Sine {
                displacement,
                amplitude: cx.number(
                    "pull.amplitude_m",
                    cx.required("pull.amplitude_m", &p.amplitude_m)?,
                )?,
                periods: cx.positive("pull.periods", cx.required("pull.periods", &p.periods)?)?,
            })
        }
        other => Err(cx.err(
            "pull.kind",
            format!("unknown kind {other:?} (expected straight or sine)"),
        )),
    }
}

fn strategy_of(cx: &Ctx, i: usize, s: &RawStrategy) -> Result<StrategySpec, ScenarioError> {
    let field = |name: &str| format!("strategy[{i}].{name}");
    let sequential = |p| {
        if s.objective.is_some() {
            return Err(cx.err(field("objective"), "applies to kind \"overall\" only"));
        }
        if s.companion_weight.is_some() {
            return Err(cx.err(
                field("companion_weight"),
                "applies to kind \"overall\" only",
            ));
        }
        Ok(StrategySpec::Sequential(p))
    };
    match s.kind.as_str() {
        "tractrix" => sequential(Propagation::Tractrix),
        "distance" => sequential(Propagation::Distance),
        "overall" => {
            let name = s.objective.as_deref().unwrap_or("m2");
            Objective::from_name(name, s.companion_weight)
                .map(StrategySpec::Overall)
                .map_err(|e| {
                    use crate::rope::ObjectiveError as E;
                    let name = match e {
                        E::Unknown { .. } => "objective",
                        _ => "companion_weight",
                    };
                    cx.err(field(name), e.to_string())
                })
        }
        other => Err(cx.err(
            field("kind"),
            format!("unknown kind {other:?} (expected tractrix, distance or overall)"),
        )),
    }
}
