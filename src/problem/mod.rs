//! The JSON problem format of `snakectl solve`: parsing, validation and the answer.
//!
//! A problem is a chain (links, base pose, limits), a start pose, a tip target and how to
//! resolve it. A free base (a rope) is resolved by default by the overall optimization of
//! [`crate::rope`] under an objective (`"m1"`..`"m5"`, default `"m2"`, the paper's);
//! `"m3"` and `"m5"` need a `companion_weight` (the weight of M1 added to them), which the
//! others refuse. Parsing is strict: unknown keys, wrong lengths, non-finite numbers, magnitudes
//! above [`MAX_MAGNITUDE`] and inconsistent limits are refused with a [`ProblemError`] naming the
//! field. Solving never fails: imperfect answers carry their flags and errors.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::chain::{Chain, ChainError, JointLimit, Vec2, MAX_MAGNITUDE};
use crate::metrics::{self, Metrics};
use crate::resolve::overall::{Overall, OverallMode, OverallOptions};
use crate::resolve::sequential::{pull_free, Sequential, SequentialOptions};
use crate::resolve::tractrix::Propagation;
use crate::resolve::{solve_steps, Resolver, Strategy};
use crate::rope::{Objective, RopeOptimizer, RopeReport};

/// A refused problem: the field at fault and what is wrong with it. Displays on one line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct ProblemError {
    /// The field, as written in the input (`links[3]`, `target`, ...), or `input` for the whole.
    pub field: String,
    /// What is wrong, with the value.
    pub message: String,
}

impl ProblemError {
    fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// Whether the base end of the chain is held (an arm) or free (a rope).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BaseMode {
    /// The base stays put: an arm.
    Fixed,
    /// The base end follows: a rope, a chain, a snake.
    Free,
}

/// The problem file as written. Every key is optional only where the format says so.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProblem {
    links: Vec<f64>,
    base: Vec<f64>,
    theta0: Vec<f64>,
    #[serde(default)]
    limits: Option<Vec<Option<Vec<f64>>>>,
    target: Vec<f64>,
    #[serde(default)]
    strategy: Option<String>,
    #[serde(default)]
    base_mode: Option<String>,
    #[serde(default)]
    propagation: Option<String>,
    #[serde(default)]
    steps: Option<u64>,
    #[serde(default)]
    objective: Option<String>,
    #[serde(default)]
    companion_weight: Option<f64>,
}

/// A validated problem, ready to solve.
#[derive(Debug, Clone)]
pub struct Problem {
    /// The chain, with its limits.
    pub chain: Chain,
    /// Start pose, relative angles, rad.
    pub theta0: Vec<f64>,
    /// Tip target, m.
    pub target: Vec2,
    /// Which strategy resolves the motion.
    pub strategy: Strategy,
    /// Fixed arm or free rope.
    pub base_mode: BaseMode,
    /// Elemental step of the sequential strategy.
    pub propagation: Propagation,
    /// Number of equal straight sub-moves of the tip.
    pub steps: usize,
    /// Objective of the overall strategy on a free base (ignored otherwise).
    pub objective: Objective,
}

/// Checks one number: finite and within [`MAX_MAGNITUDE`].
fn number(field: &str, value: f64) -> Result<f64, ProblemError> {
    if !value.is_finite() {
        return Err(ProblemError::new(
            field,
            format!("{value} is not a finite number"),
        ));
    }
    if value.abs() > MAX_MAGNITUDE {
        return Err(ProblemError::new(
            field,
            format!("{value} exceeds the largest accepted magnitude {MAX_MAGNITUDE:e}"),
        ));
    }
    Ok(value)
}

fn numbers(field: &str, values: &[f64]) -> Result<(), ProblemError> {
    for (i, &v) in values.iter().enumerate() {
        number(&format!("{field}[{i}]"), v)?;
    }
    Ok(())
}

fn exact_len(field: &str, values: &[f64], want: usize, what: &str) -> Result<(), ProblemError> {
    if values.len() != want {
        return Err(ProblemError::new(
            field,
            format!("expected {want} {what}, got {}", values.len()),
        ));
    }
    Ok(())
}

/// Checks a tip target: two finite numbers within [`MAX_MAGNITUDE`].
pub fn check_target(field: &str, values: &[f64]) -> Result<Vec2, ProblemError> {
    exact_len(field, values, 2, "numbers [x, y]")?;
    numbers(field, values)?;
    Ok(Vec2::new(values[0], values[1]))
}

/// Parses a strategy name.
pub fn parse_strategy(name: &str) -> Result<Strategy, ProblemError> {
    match name {
        "sequential" => Ok(Strategy::Sequential),
        "overall" => Ok(Strategy::Overall),
        other => Err(ProblemError::new(
            "strategy",
            format!("unknown strategy {other:?} (expected \"overall\" or \"sequential\")"),
        )),
    }
}

/// Parses a propagation name.
pub fn parse_propagation(name: &str) -> Result<Propagation, ProblemError> {
    match name {
        "tractrix" => Ok(Propagation::Tractrix),
        "distance" => Ok(Propagation::Distance),
        other => Err(ProblemError::new(
            "propagation",
            format!("unknown propagation {other:?} (expected \"tractrix\" or \"distance\")"),
        )),
    }
}

/// Parses a base mode name.
pub fn parse_base_mode(name: &str) -> Result<BaseMode, ProblemError> {
    match name {
        "fixed" => Ok(BaseMode::Fixed),
        "free" => Ok(BaseMode::Free),
        other => Err(ProblemError::new(
            "base_mode",
            format!("unknown base mode {other:?} (expected \"fixed\" or \"free\")"),
        )),
    }
}

/// Checks a step count: at least one.
pub fn parse_steps(steps: u64) -> Result<usize, ProblemError> {
    if steps == 0 {
        return Err(ProblemError::new("steps", "must be at least 1"));
    }
    usize::try_from(steps)
        .ok()
        .filter(|&s| s <= 1_000_000)
        .ok_or_else(|| ProblemError::new("steps", format!("{steps} exceeds 1000000")))
}

/// Refuses combinations the strategies do not offer: a propagation with the overall strategy.
pub fn check_combination(
    strategy: Strategy,
    _base_mode: BaseMode,
    propagation_given: bool,
) -> Result<(), ProblemError> {
    if strategy == Strategy::Overall && propagation_given {
        return Err(ProblemError::new(
            "propagation",
            "applies to the sequential strategy only",
        ));
    }
    Ok(())
}

/// Parses the objective and its companion weight. Only the overall strategy on a free base
/// takes them (the fixed-base overall strategy minimizes metric 3); the default is M2, the
/// paper's. M3 and M5 require `companion_weight`; the others refuse it.
pub fn parse_objective(
    name: Option<&str>,
    companion_weight: Option<f64>,
    strategy: Strategy,
    base_mode: BaseMode,
) -> Result<Objective, ProblemError> {
    let free_overall = strategy == Strategy::Overall && base_mode == BaseMode::Free;
    if !free_overall {
        if name.is_some() {
            return Err(ProblemError::new(
                "objective",
                "applies to the overall strategy with base_mode \"free\" only (the fixed-base \
                 overall strategy minimizes m3)",
            ));
        }
        if companion_weight.is_some() {
            return Err(ProblemError::new(
                "companion_weight",
                "applies to the objectives \"m3\" and \"m5\" of a free base only",
            ));
        }
        return Ok(Objective::M2);
    }
    if let Some(w) = companion_weight {
        number("companion_weight", w)?;
    }
    let name = name.unwrap_or("m2");
    Objective::from_name(name, companion_weight).map_err(|e| {
        use crate::rope::ObjectiveError as E;
        let field = match e {
            E::Unknown { .. } => "objective",
            _ => "companion_weight",
        };
        ProblemError::new(field, e.to_string())
    })
}

/// Maps a chain construction error onto the problem's field names.
fn chain_error(e: ChainError) -> ProblemError {
    match e {
        ChainError::Empty => ProblemError::new("links", "the chain has no links"),
        ChainError::BadLink { link, value } => ProblemError::new(
            format!("links[{}]", link - 1),
            format!("{value} must be a positive length"),
        ),
        ChainError::BadBase { value } => {
            ProblemError::new("base", format!("{value} is not an accepted coordinate"))
        }
        ChainError::LimitCount { got, joints } => ProblemError::new(
            "limits",
            format!("expected {joints} entries (one per joint), got {got}"),
        ),
        ChainError::BadLimit { joint, lo, hi } => ProblemError::new(
            format!("limits[{}]", joint - 1),
            format!("[{lo}, {hi}] must satisfy lo < hi"),
        ),
    }
}

/// Checks that a start pose has one angle per joint, each finite and inside its limits.
pub fn check_pose(chain: &Chain, field: &str, theta: &[f64]) -> Result<(), ProblemError> {
    exact_len(field, theta, chain.len(), "angles (one per link)")?;
    numbers(field, theta)?;
    chain.check_limits(theta).map_err(|v| {
        ProblemError::new(
            format!("{field}[{}]", v.joint - 1),
            format!(
                "{} rad is outside the joint's limits [{}, {}]",
                v.value, v.lo, v.hi
            ),
        )
    })
}

impl Problem {
    /// Parses and validates a problem from JSON text.
    pub fn from_json(text: &str) -> Result<Self, ProblemError> {
        let raw: RawProblem =
            serde_json::from_str(text).map_err(|e| ProblemError::new("input", format!("{e}")))?;
        Self::from_raw(raw)
    }

    fn from_raw(raw: RawProblem) -> Result<Self, ProblemError> {
        if raw.links.is_empty() {
            return Err(ProblemError::new("links", "the chain has no links"));
        }
        numbers("links", &raw.links)?;
        exact_len("base", &raw.base, 3, "numbers [x, y, heading]")?;
        numbers("base", &raw.base)?;
        let target = check_target("target", &raw.target)?;
        let n = raw.links.len();
        let mut limits = Vec::new();
        if let Some(raw_limits) = &raw.limits {
            if raw_limits.len() != n {
                return Err(ProblemError::new(
                    "limits",
                    format!(
                        "expected {n} entries (one per joint), got {}",
                        raw_limits.len()
                    ),
                ));
            }
            for (i, l) in raw_limits.iter().enumerate() {
                let field = format!("limits[{i}]");
                limits.push(match l {
                    None => None,
                    Some(pair) => {
                        exact_len(&field, pair, 2, "numbers [lo, hi] or null")?;
                        numbers(&field, pair)?;
                        Some(JointLimit {
                            lo: pair[0],
                            hi: pair[1],
                        })
                    }
                });
            }
        }
        let base = Vec2::new(raw.base[0], raw.base[1]);
        let chain = Chain::new(raw.links, base, raw.base[2], limits).map_err(chain_error)?;
        check_pose(&chain, "theta0", &raw.theta0)?;
        let base_mode = parse_base_mode(raw.base_mode.as_deref().unwrap_or("fixed"))?;
        let strategy = parse_strategy(raw.strategy.as_deref().unwrap_or("overall"))?;
        let propagation = parse_propagation(raw.propagation.as_deref().unwrap_or("tractrix"))?;
        check_combination(strategy, base_mode, raw.propagation.is_some())?;
        let steps = parse_steps(raw.steps.unwrap_or(1))?;
        let objective = parse_objective(
            raw.objective.as_deref(),
            raw.companion_weight,
            strategy,
            base_mode,
        )?;
        Ok(Self {
            chain,
            theta0: raw.theta0,
            target,
            strategy,
            base_mode,
            propagation,
            steps,
            objective,
        })
    }

    /// Solves the problem. Never fails: an unreachable or unconverged answer says so in its
    /// flags, with the best pose found.
    pub fn solve(&self) -> Answer {
        match self.base_mode {
            BaseMode::Fixed => self.solve_fixed(),
            BaseMode::Free => self.solve_free(),
        }
    }

    fn solve_fixed(&self) -> Answer {
        let chain = &self.chain;
        // A one-off solve: the overall strategy runs its cold starts for every step.
        let mut resolver: Box<dyn Resolver> = match self.strategy {
            Strategy::Sequential => Box::new(Sequential::new(SequentialOptions {
                propagation: self.propagation,
                ..SequentialOptions::default()
            })),
            Strategy::Overall => Box::new(Overall::new(OverallOptions {
                mode: OverallMode::Cold,
                ..OverallOptions::default()
            })),
        };
        let mut theta = vec![0.0; chain.len()];
        let clock = Instant::now();
        let outcome = solve_steps(
            resolver.as_mut(),
            chain,
            &self.theta0,
            self.target,
            self.steps,
            &mut theta,
        );
        let solve_us = clock.elapsed().as_secs_f64() * 1e6;
        let points = chain.points(&theta);
        Answer {
            strategy: self.strategy.name(),
            tip: xy(points[chain.len()]),
            points: points.iter().copied().map(xy).collect(),
            tip_error: outcome.tip_error,
            base_error: Some((points[0] - chain.base()).norm()),
            base_displacement: None,
            reachable: outcome.reachable,
            converged: outcome.converged,
            within_limits: chain.check_limits(&theta).is_ok(),
            iterations: outcome.iterations,
            objective: None,
            companion_weight: None,
            optimizer: None,
            metrics: MetricsOut::from(metrics::arm(chain, &self.theta0, &theta)),
            solve_us,
            theta,
        }
    }

    fn solve_free(&self) -> Answer {
        let chain = &self.chain;
        let old = chain.points(&self.theta0);
        let mut points = old.clone();
        let mut scratch = Vec::with_capacity(points.len());
        let clock = Instant::now();
        let mut report = None;
        let mut refused = false;
        match self.strategy {
            Strategy::Sequential => pull_free(
                &mut points,
                chain.links(),
                self.target,
                self.steps,
                self.propagation,
                &mut scratch,
            ),
            Strategy::Overall => {
                // Bad input cannot reach here (the chain is validated); if the optimizer still
                // refuses, the start is returned flagged as not converged.
                match RopeOptimizer::default().pull(
                    &mut points,
                    chain.links(),
                    self.target,
                    self.steps,
                    self.objective,
                ) {
                    Ok(r) => report = Some(r),
                    Err(_) => refused = true,
                }
            }
        }
        let solve_us = clock.elapsed().as_secs_f64() * 1e6;
        let mut theta = vec![0.0; chain.len()];
        Chain::angles_from_points(chain.heading(), &points, &self.theta0, &mut theta);
        let n = chain.len();
        Answer {
            strategy: self.strategy.name(),
            tip: xy(points[n]),
            tip_error: (points[n] - self.target).norm(),
            base_error: None,
            base_displacement: Some((points[0] - old[0]).norm()),
            reachable: true,
            converged: !refused && report.is_none_or(|r| r.converged),
            within_limits: chain.check_limits(&theta).is_ok(),
            iterations: report.map_or(0, |r| r.iterations),
            objective: report.map(|_| self.objective.name()),
            companion_weight: report.and_then(|_| self.objective.companion_weight()),
            optimizer: report.map(OptimizerOut::from),
            metrics: MetricsOut::from(metrics::rope(&old, &points)),
            solve_us,
            points: points.iter().copied().map(xy).collect(),
            theta,
        }
    }
}

fn xy(p: Vec2) -> [f64; 2] {
    [p.x, p.y]
}

/// The metrics as they appear in the answer.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct MetricsOut {
    /// Sum of squared point displacements, m^2.
    pub m1: f64,
    /// Displacements weighted by segment length, m^2.
    pub m2: f64,
    /// Sum of squared joint rotations, rad^2.
    pub m3: f64,
    /// Squared displacements weighted by arc length to the tip, m^3.
    pub m4: f64,
    /// Squared rotations weighted by arc length to the tip, m rad^2.
    pub m5: f64,
}

impl From<Metrics> for MetricsOut {
    fn from(m: Metrics) -> Self {
        Self {
            m1: m.m1,
            m2: m.m2,
            m3: m.m3,
            m4: m.m4,
            m5: m.m5,
        }
    }
}

/// The free-rope optimizer's residuals as they appear in the answer (the last step's).
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct OptimizerOut {
    /// The objective of the answer (exact, M2 unsmoothed).
    pub objective_value: f64,
    /// The objective of the sequential seed.
    pub seed_value: f64,
    /// Largest gradient component at the optimum.
    pub gradient: f64,
    /// Newton decrement at the optimum.
    pub decrement: f64,
    /// Last smoothing parameter of M2, m (0 otherwise).
    pub smoothing_m: f64,
    /// Bound on the M2 smoothing gap, m^2.
    pub smoothing_gap: f64,
    /// Largest link length error, m.
    pub length_residual: f64,
}

impl From<RopeReport> for OptimizerOut {
    fn from(r: RopeReport) -> Self {
        Self {
            objective_value: r.objective,
            seed_value: r.seed_objective,
            gradient: r.gradient,
            decrement: r.decrement,
            smoothing_m: r.smoothing,
            smoothing_gap: r.smoothing_gap,
            length_residual: r.length_residual,
        }
    }
}

/// The answer `snakectl solve` prints: one JSON object.
#[derive(Debug, Clone, Serialize)]
pub struct Answer {
    /// The strategy that produced it.
    pub strategy: &'static str,
    /// Relative joint angles, each the representative nearest its start value, rad.
    pub theta: Vec<f64>,
    /// `p_0..p_n`, base (or free end) first, m.
    pub points: Vec<[f64; 2]>,
    /// The tip `p_n`, m.
    pub tip: [f64; 2],
    /// Distance from the tip to the target, m.
    pub tip_error: f64,
    /// Fixed base: distance from `p_0` to the base, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_error: Option<f64>,
    /// Free base: how far `p_0` moved, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_displacement: Option<f64>,
    /// Whether the target is reachable.
    pub reachable: bool,
    /// Whether the resolver met its tolerance.
    pub converged: bool,
    /// Whether every joint lies inside its limits.
    pub within_limits: bool,
    /// Correction rounds (sequential) or solver iterations (overall), summed over the steps.
    pub iterations: usize,
    /// Free base, overall strategy: the objective minimized (`m1`..`m5`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub objective: Option<&'static str>,
    /// Free base, overall strategy with `m3`/`m5`: the weight of M1 added.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub companion_weight: Option<f64>,
    /// Free base, overall strategy: the optimizer's residuals for the last step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub optimizer: Option<OptimizerOut>,
    /// The five metrics between the start and the answer.
    pub metrics: MetricsOut,
    /// The solver's own time, µs.
    pub solve_us: f64,
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    const GOOD: &str = r#"{"links":[1,1,1],"base":[0,0,0],"theta0":[0.1,0.2,0.3],
        "target":[1.5,1.0]}"#;

    fn err(text: &str) -> ProblemError {
        Problem::from_json(text).unwrap_err()
    }

    fn with(key_value: &str) -> String {
        GOOD.replacen('{', &format!("{{{key_value},"), 1)
    }

    #[test]
    fn a_good_problem_solves() {
        let p = Problem::from_json(GOOD).unwrap();
        assert_eq!(p.steps, 1);
        assert_eq!(p.strategy, Strategy::Overall);
        let a = p.solve();
        assert!(a.converged && a.reachable && a.within_limits);
        assert!(a.tip_error < 1e-9);
        assert_eq!(a.points.len(), 4);
    }

    #[test]
    fn every_bad_input_names_its_field() {
        let cases: Vec<(String, &str)> = vec![
            ("{".into(), "input"),
            ("[1,2]".into(), "input"),
            (with(r#""colour":1"#), "input"),
            (GOOD.replace("[1,1,1]", "[]"), "links"),
            (GOOD.replace("[1,1,1]", "[1,-1,1]"), "links[1]"),
            (GOOD.replace("[1,1,1]", "[1,0,1]"), "links[1]"),
            (GOOD.replace("[1,1,1]", "[1,1,2e6]"), "links[2]"),
            (GOOD.replace("[0,0,0]", "[0,0]"), "base"),
            (GOOD.replace("[0,0,0]", "[0,0,1e7]"), "base[2]"),
            (GOOD.replace("[0.1,0.2,0.3]", "[0.1,0.2]"), "theta0"),
            (GOOD.replace("[1.5,1.0]", "[1.5]"), "target"),
            (GOOD.replace("[1.5,1.0]", "[1.5,-3e6]"), "target[1]"),
            (with(r#""limits":[[1,-1],null,null]"#), "limits[0]"),
            (with(r#""limits":[null,null]"#), "limits"),
            (with(r#""limits":[[0,1,2],null,null]"#), "limits[0]"),
            (with(r#""limits":[null,null,[-0.1,0.1]]"#), "theta0[2]"),
            (with(r#""strategy":"fastest""#), "strategy"),
            (with(r#""base_mode":"floating""#), "base_mode"),
            (with(r#""propagation":"magic""#), "propagation"),
            (with(r#""steps":0"#), "steps"),
            (with(r#""base_mode":"free","objective":"m7""#), "objective"),
            (
                with(r#""base_mode":"free","objective":"m3""#),
                "companion_weight",
            ),
            (
                with(r#""base_mode":"free","objective":"m5","companion_weight":0"#),
                "companion_weight",
            ),
            (
                with(r#""base_mode":"free","objective":"m1","companion_weight":1"#),
                "companion_weight",
            ),
            (
                with(r#""base_mode":"free","companion_weight":1"#),
                "companion_weight",
            ),
            (with(r#""objective":"m2""#), "objective"),
            (
                with(r#""base_mode":"free","strategy":"sequential","objective":"m1""#),
                "objective",
            ),
            (with(r#""companion_weight":2"#), "companion_weight"),
            (
                with(r#""base_mode":"free","objective":"m3","companion_weight":1e7"#),
                "companion_weight",
            ),
            (
                with(r#""strategy":"overall","propagation":"distance""#),
                "propagation",
            ),
            (with(r#""steps":-1"#), "input"),
            (GOOD.replace("[1.5,1.0]", "[1.5,1e999]"), "input"),
        ];
        for (text, field) in cases {
            let e = err(&text);
            assert_eq!(e.field, field, "{text} -> {e}");
            assert!(!e.to_string().contains('\n'), "one line: {e}");
        }
        assert!(err(&with(r#""colour":1"#)).to_string().contains("colour"));
    }

    #[test]
    fn free_mode_moves_the_base_end_and_keeps_the_tip_exact() {
        for extra in [
            r#""base_mode":"free","steps":4,"strategy":"sequential""#,
            r#""base_mode":"free","steps":4"#,
            r#""base_mode":"free","objective":"m5","companion_weight":0.5"#,
        ] {
            let p = Problem::from_json(&with(extra)).unwrap();
            let a = p.solve();
            assert!(a.base_error.is_none());
            assert!(a.base_displacement.unwrap() > 0.0, "{extra}");
            assert_eq!(a.tip, [1.5, 1.0]);
            assert!(a.converged && a.reachable, "{extra}");
        }
    }

    #[test]
    fn free_base_defaults_to_overall_m2_and_beats_the_sequential_answer() {
        let p = Problem::from_json(&with(r#""base_mode":"free""#)).unwrap();
        assert_eq!(p.strategy, Strategy::Overall);
        assert_eq!(p.objective, Objective::M2);
        let a = p.solve();
        assert_eq!(a.objective, Some("m2"));
        let o = a.optimizer.unwrap();
        assert!(o.length_residual <= 1e-12 && a.tip_error <= 1e-12);
        assert!(o.objective_value <= o.seed_value);
        assert!((a.metrics.m2 - o.objective_value).abs() < 1e-15);
        let seq = Problem::from_json(&with(r#""base_mode":"free","strategy":"sequential""#))
            .unwrap()
            .solve();
        assert!(a.metrics.m2 <= seq.metrics.m2);
        let weighted = Problem::from_json(&with(
            r#""base_mode":"free","objective":"m3","companion_weight":2"#,
        ))
        .unwrap();
        assert_eq!(
            weighted.objective,
            Objective::M3 {
                companion_weight: 2.0
            }
        );
        assert_eq!(weighted.solve().companion_weight, Some(2.0));
    }
}
