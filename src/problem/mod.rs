//! The JSON problem format of `snakectl solve`: parsing, validation and the answer.
//!
//! A problem is a chain (links, base pose, limits), a start pose, a tip target and how to
//! resolve it. A free base (a rope) is resolved by default by the overall optimization of
//! [`crate::rope`] under an objective (`"m1"`..`"m5"`, default `"m2"`, the paper's);
//! `"m3"` and `"m5"` need a `companion_weight` (the weight of M1 added to them), which the
//! others refuse. Parsing is strict: unknown keys, wrong lengths, non-finite numbers, magnitudes
//! above [`MAX_MAGNITUDE`] and inconsistent limits are refused with a [`ProblemError`] naming the
//! field. Solving never fails: imperfect answers carry their flags and errors.
//!
//! A problem may hold a world of obstacles (the socket's shape, ids optional) with the links'
//! radius and the clearance to keep; the overall strategy of a fixed base keeps every link
//! clear of them, the others ignore them. Every answer reports the clearance of its pose and
//! of the start ([`Answer::min_clearance_m`]), computed by [`World::clearance`].

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::chain::{wrap_angle, Chain, ChainError, JointLimit, Num, Vec2, MAX_MAGNITUDE};
use crate::metrics::{self, Metrics};
use crate::resolve::overall::{Overall, OverallMode, OverallOptions};
use crate::resolve::overall::{CLEAR_SLACK, MAX_LINKS_AMONG_OBSTACLES};
use crate::resolve::sequential::{pull_free, Sequential, SequentialOptions};
use crate::resolve::tractrix::Propagation;
use crate::resolve::{solve_steps, Resolver, Strategy};
use crate::rope::{Objective, RopeOptimizer, RopeReport};
use crate::world::{Obstacle, Shape, World, WorldError};

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
#[serde(
    deny_unknown_fields,
    expecting = "a problem: a JSON object (docs/SOLVE.md)"
)]
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
    #[serde(default)]
    obstacles: Vec<RawObstacle>,
    #[serde(default)]
    link_radius_m: Option<f64>,
    #[serde(default)]
    clearance_m: Option<f64>,
}

/// One obstacle as written: `{"id": "post", "circle": {"center": [x, y], "radius": r}}` or
/// `{"polygon": {"points": [[x, y], ...]}}`.
#[derive(Debug, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = r#"an obstacle: {"id"?, "circle": {"center", "radius"}} or {"id"?, "polygon": {"points"}}"#
)]
struct RawObstacle {
    #[serde(default)]
    id: Option<String>,
    #[serde(default)]
    circle: Option<RawCircle>,
    #[serde(default)]
    polygon: Option<RawPolygon>,
}

#[derive(Debug, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = r#"a circle: {"center": [x, y], "radius": r}"#
)]
struct RawCircle {
    center: Vec<f64>,
    radius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = r#"a polygon: {"points": [[x, y], ...]}"#
)]
struct RawPolygon {
    points: Vec<Vec<f64>>,
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
    /// The obstacles, the links' radius and the clearance to keep (no obstacles: none).
    pub world: World,
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
            format!(
                "{} exceeds the largest accepted magnitude {MAX_MAGNITUDE:e}",
                Num(value)
            ),
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

/// The most sub-moves a problem may ask: each is a full solve, so the time grows with them (a
/// million took minutes); far more than a path needs.
pub const MAX_STEPS: usize = 10_000;

/// Checks a step count: 1 to [`MAX_STEPS`].
pub fn parse_steps(steps: u64) -> Result<usize, ProblemError> {
    if steps == 0 {
        return Err(ProblemError::new("steps", "must be at least 1"));
    }
    usize::try_from(steps)
        .ok()
        .filter(|&s| s <= MAX_STEPS)
        .ok_or_else(|| ProblemError::new("steps", format!("{steps} exceeds {MAX_STEPS}")))
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

/// Refuses a chain of more than [`MAX_LINKS_AMONG_OBSTACLES`] links in a world with
/// obstacles: the clear solve's scratch grows as the square of the links.
pub fn check_links_among(chain: &Chain, world: &World) -> Result<(), ProblemError> {
    let n = chain.len();
    if n > MAX_LINKS_AMONG_OBSTACLES && !world.obstacles().is_empty() {
        return Err(ProblemError::new(
            "links",
            format!(
                "{n} links among obstacles, at most {MAX_LINKS_AMONG_OBSTACLES}: keeping clear \
                 of obstacles takes memory growing as the square of the links (without \
                 obstacles, any number)"
            ),
        ));
    }
    Ok(())
}

/// Maps a world's refusal onto the problem's field names (`obstacles[0].circle.radius`,
/// `obstacles[1].polygon.points[3]`, `link_radius_m`, ...).
fn world_error(e: WorldError) -> ProblemError {
    let text = e.to_string();
    let field = match &e {
        WorldError::NotFinite { field, .. }
        | WorldError::NotPositive { field, .. }
        | WorldError::Negative { field, .. }
        | WorldError::EmptyId { field }
        | WorldError::BadId { field, .. }
        | WorldError::DuplicateId { field, .. }
        | WorldError::TooFewPoints { field, .. }
        | WorldError::RepeatedPoint { field, .. }
        | WorldError::SelfIntersecting { field, .. }
        | WorldError::ZeroArea { field } => field.clone(),
        _ => "obstacles".to_string(),
    };
    let message = text
        .strip_prefix(&format!("{field}: "))
        .unwrap_or(&text)
        .to_string();
    let field = field
        .replace(".circle.radius_m", ".circle.radius")
        .replace(".circle.center.x", ".circle.center[0]")
        .replace(".circle.center.y", ".circle.center[1]");
    ProblemError::new(field, message)
}

/// Reads the obstacles (an obstacle without an `id` is `obstacle_K`, K its place from 1), the
/// links' radius and the clearance (both default 0) into a validated [`World`].
fn parse_world(
    raw: &[RawObstacle],
    link_radius_m: Option<f64>,
    clearance_m: Option<f64>,
) -> Result<World, ProblemError> {
    let link_radius_m = number("link_radius_m", link_radius_m.unwrap_or(0.0))?;
    let clearance_m = number("clearance_m", clearance_m.unwrap_or(0.0))?;
    let mut obstacles = Vec::with_capacity(raw.len());
    for (i, o) in raw.iter().enumerate() {
        let at = format!("obstacles[{i}]");
        let shape = match (&o.circle, &o.polygon) {
            (Some(c), None) => {
                let center = check_target(&format!("{at}.circle.center"), &c.center)?;
                let radius_m = number(&format!("{at}.circle.radius"), c.radius)?;
                Shape::Circle { center, radius_m }
            }
            (None, Some(p)) => {
                let points = p
                    .points
                    .iter()
                    .enumerate()
                    .map(|(j, q)| check_target(&format!("{at}.polygon.points[{j}]"), q))
                    .collect::<Result<Vec<_>, _>>()?;
                Shape::Polygon { points }
            }
            (Some(_), Some(_)) => {
                return Err(ProblemError::new(
                    at,
                    "give either \"circle\" or \"polygon\", not both",
                ))
            }
            (None, None) => {
                return Err(ProblemError::new(at, "needs a \"circle\" or a \"polygon\""))
            }
        };
        let id =
            o.id.clone()
                .unwrap_or_else(|| format!("obstacle_{}", i + 1));
        obstacles.push(Obstacle { id, shape });
    }
    World::new(link_radius_m, clearance_m, obstacles).map_err(|e| {
        let named = match &e {
            WorldError::DuplicateId { first, .. } => {
                raw.get(*first).is_some_and(|o| o.id.is_none())
            }
            _ => false,
        };
        let mut refused = world_error(e);
        if named {
            refused.message += ", which has no `id` of its own and is named by its place: give \
                                it one, or this one another";
        }
        refused
    })
}

/// Maps a chain construction error onto the problem's field names.
fn chain_error(e: ChainError) -> ProblemError {
    match e {
        ChainError::Empty => ProblemError::new("links", "the chain has no links"),
        ChainError::BadLink { link, value } => ProblemError::new(
            format!("links[{}]", link - 1),
            format!("{} must be a positive length", Num(value)),
        ),
        ChainError::BadBase { value } => ProblemError::new(
            "base",
            format!("{} is not an accepted coordinate", Num(value)),
        ),
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
        // A byte order mark, as some editors write, is skipped (a config's TOML takes it too).
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        // Serde would read an array as the fields in order, and name its elements.
        if text.trim_start().starts_with('[') {
            return Err(ProblemError::new(
                "input",
                "a problem is a JSON object (docs/SOLVE.md), not an array",
            ));
        }
        // The path of a value of the wrong shape names the field, as every other refusal does.
        let de = &mut serde_json::Deserializer::from_str(text);
        let raw: RawProblem = serde_path_to_error::deserialize(&mut *de).map_err(|e| {
            let path = e.path().to_string();
            // `.` is the whole; `?` a place the parser could not name (text that is not JSON).
            let field = if path == "." || path.contains('?') {
                "input".to_owned()
            } else {
                path
            };
            let inner = e.into_inner();
            let message = match inner.classify() {
                serde_json::error::Category::Syntax | serde_json::error::Category::Eof => {
                    format!("not JSON ({inner})")
                }
                _ => inner.to_string(),
            };
            ProblemError::new(field, message)
        })?;
        // One problem a file: text after it (a second problem, a stray word) is refused, not
        // left unread.
        de.end()
            .map_err(|e| ProblemError::new("input", format!("not JSON ({e})")))?;
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
        // The heading's representative in (-pi, pi]: the same arm, and the joints' trigonometry
        // keeps its precision (at 3e5 rad an angle's last bit is 6e-11 rad).
        let heading = wrap_angle(raw.base[2]);
        let chain = Chain::new(raw.links, base, heading, limits).map_err(chain_error)?;
        check_pose(&chain, "theta0", &raw.theta0)?;
        let base_mode = parse_base_mode(raw.base_mode.as_deref().unwrap_or("fixed"))?;
        if base_mode == BaseMode::Free {
            if let Some(i) = chain.limits().iter().position(Option::is_some) {
                return Err(ProblemError::new(
                    format!("limits[{i}]"),
                    "applies to base_mode \"fixed\" only: a free base (a rope) is pulled with \
                     no joint limits, by either strategy; give null or leave limits out",
                ));
            }
        }
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
        let world = parse_world(&raw.obstacles, raw.link_radius_m, raw.clearance_m)?;
        check_links_among(&chain, &world)?;
        Ok(Self {
            chain,
            theta0: raw.theta0,
            target,
            strategy,
            base_mode,
            propagation,
            steps,
            objective,
            world,
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
            Strategy::Overall => {
                let mut overall = Overall::new(OverallOptions {
                    mode: OverallMode::Cold,
                    ..OverallOptions::default()
                });
                if !self.world.obstacles().is_empty() {
                    overall.set_world(Some(self.world.clone()));
                }
                Box::new(overall)
            }
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
        let clearance = ClearanceOut::of(&self.world, &chain.points(&self.theta0), &points);
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
            collision_free: clearance.collision_free,
            min_clearance_m: clearance.min_clearance_m,
            nearest: clearance.nearest,
            start_min_clearance_m: clearance.start_min_clearance_m,
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
        let clearance = ClearanceOut::of(&self.world, &old, &points);
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
            collision_free: clearance.collision_free,
            min_clearance_m: clearance.min_clearance_m,
            nearest: clearance.nearest,
            start_min_clearance_m: clearance.start_min_clearance_m,
        }
    }
}

fn xy(p: Vec2) -> [f64; 2] {
    [p.x, p.y]
}

/// The link and the obstacle of a pose's least clearance, as the answer names them.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct NearestOut {
    /// The link, 1-based from the base.
    pub link: usize,
    /// The obstacle's id.
    pub obstacle: String,
}

/// The clearance fields of an answer.
struct ClearanceOut {
    collision_free: bool,
    min_clearance_m: Option<f64>,
    nearest: Option<NearestOut>,
    start_min_clearance_m: Option<f64>,
}

impl ClearanceOut {
    /// The clearance of the answer's pose `end` and of the start `start` among `world`.
    fn of(world: &World, start: &[Vec2], end: &[Vec2]) -> Self {
        let least = world.clearance(end);
        Self {
            // Clear to the round-off of a distance, as the solver counts it.
            collision_free: least
                .is_none_or(|p| p.clearance_m >= world.clearance_m() - CLEAR_SLACK),
            min_clearance_m: least.map(|p| p.clearance_m),
            nearest: least.map(|p| NearestOut {
                link: p.link,
                obstacle: p.id(world).to_string(),
            }),
            start_min_clearance_m: world.clearance(start).map(|p| p.clearance_m),
        }
    }
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
    /// Relative joint angles, rad. Fixed base: each sub-move's answer is the representative
    /// nearest the joint's angle before it, so over several sub-moves the joint's path is
    /// followed (unwrapped; it may end more than pi from `theta0`). Free base: the final pose's
    /// representative nearest `theta0`.
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
    /// Whether the answer's pose is clear: every link at least `clearance_m` from every
    /// obstacle, to the round-off of a distance (`CLEAR_SLACK`, 1e-9 m; true without
    /// obstacles).
    pub collision_free: bool,
    /// The answer's clearance: the least gap between a link (of radius `link_radius_m`) and an
    /// obstacle, m, negative when they overlap; `None` (null) without obstacles.
    pub min_clearance_m: Option<f64>,
    /// Where that least gap is; `None` (null) without obstacles.
    pub nearest: Option<NearestOut>,
    /// The start pose's clearance, m (a start that is not clear is allowed; `collision_free`
    /// says whether the answer got out); `None` (null) without obstacles.
    pub start_min_clearance_m: Option<f64>,
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
    fn an_id_clashing_with_one_named_by_its_place_says_so() {
        let e = err(&with(
            r#""obstacles":[{"circle":{"center":[5,5],"radius":0.1}},
                {"id":"obstacle_1","circle":{"center":[-5,5],"radius":0.1}}]"#,
        ));
        assert_eq!(e.field, "obstacles[1].id");
        assert!(
            e.message
                .contains("obstacles[0], which has no `id` of its own"),
            "{}",
            e.message
        );
        // Two given ids that clash: no word about places.
        let e = err(&with(
            r#""obstacles":[{"id":"a","circle":{"center":[5,5],"radius":0.1}},
                {"id":"a","circle":{"center":[-5,5],"radius":0.1}}]"#,
        ));
        assert!(!e.message.contains("place"), "{}", e.message);
    }

    #[test]
    fn text_that_is_not_json_is_told_so() {
        let e = Problem::from_json("not json").unwrap_err();
        assert_eq!(e.field, "input");
        assert!(
            e.message.starts_with("not JSON (expected ident"),
            "{}",
            e.message
        );
    }

    #[test]
    fn text_after_the_problem_is_refused_not_left_unread() {
        for tail in [" trailing", r#" {"links":[1]}"#] {
            let e = Problem::from_json(&format!("{GOOD}{tail}")).unwrap_err();
            assert_eq!(e.field, "input");
            assert!(
                e.message.starts_with("not JSON (trailing characters"),
                "{}",
                e.message
            );
        }
        // White space after it is not text.
        assert!(Problem::from_json(&format!("{GOOD}\n\n")).is_ok());
    }

    #[test]
    fn every_bad_input_names_its_field() {
        let cases: Vec<(String, &str)> = vec![
            ("{".into(), "input"),
            ("[1,2]".into(), "input"),
            (with(r#""colour":1"#), "colour"),
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
            (
                with(r#""base_mode":"free","limits":[null,[-3,3],null]"#),
                "limits[1]",
            ),
            (
                with(r#""base_mode":"free","strategy":"sequential","limits":[[-3,3],null,null]"#),
                "limits[0]",
            ),
            (with(r#""steps":10001"#), "steps"),
            (with(r#""steps":1000000"#), "steps"),
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
            (with(r#""steps":-1"#), "steps"),
            (GOOD.replace("[1.5,1.0]", "[1.5,1e999]"), "target[1]"),
            (GOOD.replace("[1.5,1.0]", "[1.5,\"1\"]"), "target[1]"),
            (with(r#""link_radius_m":-0.01"#), "link_radius_m"),
            (with(r#""clearance_m":2e6"#), "clearance_m"),
            (with(r#""obstacles":[{"id":"a"}]"#), "obstacles[0]"),
            (
                with(
                    r#""obstacles":[{"circle":{"center":[0,0],"radius":1},"polygon":{"points":[]}}]"#,
                ),
                "obstacles[0]",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,0],"radius_m":1}}]"#),
                "obstacles[0].circle.radius_m",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,0],"radius":1},"kind":"post"}]"#),
                "obstacles[0].kind",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,0],"radius":"1"}}]"#),
                "obstacles[0].circle.radius",
            ),
            (with(r#""obstacles":[1]"#), "obstacles[0]"),
            (
                with(r#""obstacles":[{"id":3,"circle":{"center":[0,0],"radius":1}}]"#),
                "obstacles[0].id",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,0,0],"radius":1}}]"#),
                "obstacles[0].circle.center",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,3e6],"radius":1}}]"#),
                "obstacles[0].circle.center[1]",
            ),
            (
                with(r#""obstacles":[{"circle":{"center":[0,0],"radius":0}}]"#),
                "obstacles[0].circle.radius",
            ),
            (
                with(r#""obstacles":[{"id":"","circle":{"center":[0,0],"radius":1}}]"#),
                "obstacles[0].id",
            ),
            (
                with(
                    r#""obstacles":[{"circle":{"center":[0,0],"radius":1}},
                    {"id":"obstacle_1","circle":{"center":[3,0],"radius":1}}]"#,
                ),
                "obstacles[1].id",
            ),
            (
                with(r#""obstacles":[{"polygon":{"points":[[0,0],[1,0]]}}]"#),
                "obstacles[0].polygon.points",
            ),
            (
                with(r#""obstacles":[{"polygon":{"points":[[0,0],[1,0],[1]]}}]"#),
                "obstacles[0].polygon.points[2]",
            ),
            (
                with(r#""obstacles":[{"polygon":{"points":[[0,0],[1,1],[1,0],[0,1]]}}]"#),
                "obstacles[0].polygon.points",
            ),
            (
                with(r#""obstacles":[{"polygon":{"points":[[0,0],[1,0],[1,1],[1,0]]}}]"#),
                "obstacles[0].polygon.points[3]",
            ),
            (
                with(&format!(
                    r#""obstacles":[{}]"#,
                    vec![r#"{"circle":{"center":[5,5],"radius":0.1}}"#; 65].join(",")
                )),
                "obstacles",
            ),
        ];
        for (text, field) in cases {
            let e = err(&text);
            assert_eq!(e.field, field, "{text} -> {e}");
            assert!(!e.to_string().contains('\n'), "one line: {e}");
        }
        assert!(err(&with(r#""colour":1"#)).to_string().contains("colour"));
    }

    /// Distance from `c` to the segment `a..b`, worked out here on its own.
    fn to_segment(c: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let t = (((c[0] - a[0]) * dx + (c[1] - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        (c[0] - a[0] - t * dx).hypot(c[1] - a[1] - t * dy)
    }

    /// The least clearance of the pose `points` from a disc, and its link (1-based).
    fn disc_clearance(points: &[[f64; 2]], c: [f64; 2], r: f64, link_r: f64) -> (f64, usize) {
        (1..points.len())
            .map(|i| (to_segment(c, points[i - 1], points[i]) - r - link_r, i))
            .fold(
                (f64::INFINITY, 0),
                |best, x| if x.0 < best.0 { x } else { best },
            )
    }

    /// A world of a disc `post` at `c` of radius `r` and a far square without an id.
    fn world_keys(c: [f64; 2], r: f64) -> String {
        format!(
            r#""link_radius_m":0.02,"clearance_m":0.01,"obstacles":[
            {{"id":"post","circle":{{"center":[{},{}],"radius":{r}}}}},
            {{"polygon":{{"points":[[10,10],[11,10],[11,11],[10,11]]}}}}]"#,
            c[0], c[1]
        )
    }

    #[test]
    fn obstacles_are_read_with_ids_by_place_and_zero_defaults() {
        let p = Problem::from_json(&with(&world_keys([0.5, 0.5], 0.1))).unwrap();
        let ids: Vec<&str> = p.world.obstacles().iter().map(|o| o.id.as_str()).collect();
        assert_eq!(ids, ["post", "obstacle_2"]);
        assert_eq!(
            (p.world.link_radius_m(), p.world.clearance_m()),
            (0.02, 0.01)
        );
        assert_eq!(
            p.world.obstacles()[0].shape,
            Shape::Circle {
                center: Vec2::new(0.5, 0.5),
                radius_m: 0.1
            }
        );
        let p = Problem::from_json(&with(
            r#""obstacles":[{"polygon":{"points":[[2,2],[3,2],[3,3]]}}]"#,
        ))
        .unwrap();
        assert_eq!((p.world.link_radius_m(), p.world.clearance_m()), (0.0, 0.0));
        assert_eq!(p.world.obstacles()[0].id, "obstacle_1");
    }

    #[test]
    fn without_obstacles_the_answer_is_free_and_its_clearance_null() {
        let a = Problem::from_json(GOOD).unwrap().solve();
        assert!(a.collision_free);
        assert_eq!((a.min_clearance_m, a.start_min_clearance_m), (None, None));
        let json = serde_json::to_value(&a).unwrap();
        for key in ["min_clearance_m", "start_min_clearance_m", "nearest"] {
            assert_eq!(json[key], serde_json::Value::Null, "{key}");
        }
        assert_eq!(json["collision_free"], true);
    }

    #[test]
    fn strategies_that_ignore_obstacles_answer_as_before_and_report_honestly() {
        for extra in [
            r#""strategy":"sequential","steps":3"#,
            r#""strategy":"sequential","base_mode":"free""#,
            r#""base_mode":"free","steps":2"#,
        ] {
            let plain = Problem::from_json(&with(extra)).unwrap().solve();
            // A post on the middle of the answer's second link.
            let (a, b) = (plain.points[1], plain.points[2]);
            let post = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
            let text = with(&format!("{extra},{}", world_keys(post, 0.1)));
            let p = Problem::from_json(&text).unwrap();
            let answer = p.solve();
            assert_eq!(answer.theta, plain.theta, "{extra}");
            assert_eq!(answer.points, plain.points, "{extra}");
            let (least, link) = disc_clearance(&answer.points, post, 0.1, 0.02);
            let got = answer.min_clearance_m.unwrap();
            assert!((got - least).abs() < 1e-12, "{extra}: {got} vs {least}");
            assert!(got < 0.0, "{extra}: the post is on the answer");
            assert!(!answer.collision_free, "{extra}");
            let nearest = answer.nearest.unwrap();
            assert_eq!((nearest.link, nearest.obstacle.as_str()), (link, "post"));
            let start: Vec<[f64; 2]> = p
                .chain
                .points(&p.theta0)
                .iter()
                .map(|q| [q.x, q.y])
                .collect();
            let (least, _) = disc_clearance(&start, post, 0.1, 0.02);
            let got = answer.start_min_clearance_m.unwrap();
            assert!((got - least).abs() < 1e-12, "{extra}: {got} vs {least}");
        }
    }

    #[test]
    fn the_overall_answer_reports_the_clearance_of_its_own_pose() {
        // A post beside the way, and one on the start pose's first link: a start that is not
        // clear is allowed.
        for post in [[1.2, 0.6], [0.5, 0.1]] {
            let text = with(&world_keys(post, 0.1));
            let p = Problem::from_json(&text).unwrap();
            let a = p.solve();
            let (least, link) = disc_clearance(&a.points, post, 0.1, 0.02);
            let got = a.min_clearance_m.unwrap();
            assert!((got - least).abs() < 1e-12, "{got} vs {least}");
            assert_eq!(a.collision_free, got >= 0.01 - CLEAR_SLACK);
            assert_eq!(a.nearest.unwrap().link, link);
            let start: Vec<[f64; 2]> = p
                .chain
                .points(&p.theta0)
                .iter()
                .map(|q| [q.x, q.y])
                .collect();
            let (least, _) = disc_clearance(&start, post, 0.1, 0.02);
            assert!((a.start_min_clearance_m.unwrap() - least).abs() < 1e-12);
        }
        let inside = with(&world_keys([0.5, 0.1], 0.1));
        let a = Problem::from_json(&inside).unwrap().solve();
        assert!(a.start_min_clearance_m.unwrap() < 0.0);
    }

    #[test]
    fn overall_keeps_every_link_clear_of_a_post_on_its_free_answer() {
        let free = Problem::from_json(GOOD).unwrap().solve();
        // A post just beside the middle of the unconstrained answer's second link.
        let (a, b) = (free.points[1], free.points[2]);
        let post = [(a[0] + b[0]) / 2.0 + 0.05, (a[1] + b[1]) / 2.0];
        let p = Problem::from_json(&with(&world_keys(post, 0.1))).unwrap();
        let start: Vec<[f64; 2]> = p
            .chain
            .points(&p.theta0)
            .iter()
            .map(|q| [q.x, q.y])
            .collect();
        assert!(
            disc_clearance(&start, post, 0.1, 0.02).0 > 0.01,
            "a clear start"
        );
        assert!(disc_clearance(&free.points, post, 0.1, 0.02).0 < 0.01);
        let a = p.solve();
        assert!(a.collision_free && a.converged && a.reachable);
        assert!(a.tip_error < 1e-9, "{}", a.tip_error);
        let (least, _) = disc_clearance(&a.points, post, 0.1, 0.02);
        assert!(least >= 0.01 - CLEAR_SLACK, "{least}");
    }

    /// Among obstacles, an overall answer that stops short of its target is still given as
    /// each angle's representative nearest `theta0`, as every fixed-base answer of one step is.
    #[test]
    fn an_answer_short_of_its_target_among_obstacles_stays_within_pi_of_the_start() {
        let text = r#"{"links": [0.44348092498976616, 0.2009056707700177, 0.31810893703394494,
            0.2477183857452233, 0.45240352765372494],
          "base": [0.7898459431468499, -0.6749988123740032, 3.107614643679282],
          "theta0": [0.0445374751780026, 0.6259109146117867, -0.5785104654255017,
            -0.3649942686907977, -0.5900106771802387],
          "target": [2.937070446904192, -1.2687730672511583],
          "limits": [null, [0.26884403431864656, 1.5805863130776836], null, null, null],
          "obstacles": [
            {"polygon": {"points": [[0.6945594443585652, -0.6993796649047612],
              [0.7452711351026411, -0.6489265132229916], [0.8200069775154937, -0.6929378838978271],
              [0.8103656693398216, -0.7480519135937216], [0.7784207895899732, -0.8187755222089821],
              [0.7031380889709349, -0.8129460276053749], [0.6578658066281141, -0.7432256331101853]]}},
            {"circle": {"center": [2.251067963706579, -1.1335724581898896], "radius": 0.1273871994949151}},
            {"circle": {"center": [0.15810420419708787, -0.6448379325199328], "radius": 0.030913462261369616}},
            {"circle": {"center": [0.5860237509092744, -0.8465843777103518], "radius": 0.060595274049024046}}],
          "link_radius_m": 0.012, "clearance_m": 0.005}"#;
        let p = Problem::from_json(text).unwrap();
        let a = p.solve();
        assert!(!a.reachable && !a.converged);
        for (i, (t, t0)) in a.theta.iter().zip(&p.theta0).enumerate() {
            assert!(
                (t - t0).abs() <= std::f64::consts::PI,
                "joint {i}: {t} from {t0}"
            );
        }
        let m3: f64 = a
            .theta
            .iter()
            .zip(&p.theta0)
            .map(|(t, t0)| (t - t0).powi(2))
            .sum();
        assert!(
            (a.metrics.m3 - m3).abs() < 1e-12,
            "{} vs {m3}",
            a.metrics.m3
        );
    }

    /// A free base is pulled with no joint limits: limits given with it are refused (above),
    /// all-null limits say nothing and are accepted.
    #[test]
    fn free_base_accepts_only_null_limits() {
        let p = Problem::from_json(&with(r#""base_mode":"free","limits":[null,null,null]"#));
        assert!(p.unwrap().solve().within_limits);
        let e = err(&with(r#""base_mode":"free","limits":[null,null,[-3,3]]"#));
        assert!(e.to_string().contains("fixed"), "{e}");
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

    /// A heading of many turns is the same arm as its representative, and is solved as
    /// precisely: both strategies converge on the target, with the same joint angles.
    #[test]
    fn a_heading_of_many_turns_is_solved_as_its_representative() {
        let tau = 2.0 * std::f64::consts::PI;
        let turns = 3e5 / tau;
        let far = format!("{}", 0.2 + turns.round() * tau);
        for strategy in ["overall", "sequential"] {
            let problem = |heading: &str| {
                GOOD.replace("[0,0,0]", &format!("[0,0,{heading}]"))
                    .replace("}", &format!(r#","strategy":"{strategy}"}}"#))
            };
            let near = Problem::from_json(&problem("0.2")).unwrap().solve();
            let a = Problem::from_json(&problem(&far)).unwrap().solve();
            assert!(a.converged && a.reachable, "{strategy}: {a:?}");
            assert!(a.tip_error <= 1e-11, "{strategy}: {}", a.tip_error);
            for (x, y) in a.theta.iter().zip(&near.theta) {
                assert!(
                    (x - y).abs() <= 1e-9,
                    "{strategy}: {:?} {:?}",
                    a.theta,
                    near.theta
                );
            }
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
