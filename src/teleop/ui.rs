//! The teleop screen: the arm drawn from `describe` and telemetry, its state beside it, a
//! key-help line; onto any ratatui backend.
//!
//! The canvas is in world coordinates with the same scale on both axes (a terminal cell is
//! about twice as tall as wide, a braille cell 2x4 dots), so the arm keeps its shape and a
//! click on the canvas maps back to the point under it ([`click_to_world`]).
//!
//! Among obstacles ([`Scene`], set with [`Panel::set_world`]) the canvas shades each obstacle,
//! outlines it, dots the clearance margin (the obstacle grown by `link_radius_m +
//! clearance_m`: where the links' axes keep behind), and, when the commanded pose comes within
//! twice `clearance_m` of an obstacle, draws the nearest link-obstacle pair as a line between
//! their closest points (yellow, red when the pose is not clear).

use std::collections::VecDeque;

use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::canvas::{Canvas, Circle, Context, Line as Segment, Points};
use ratatui::widgets::{Block, Borders, Paragraph, Wrap};
use ratatui::Frame;

use crate::chain::Vec2;
use crate::client::{ArmInfo, State, Status as Snapshot};
use crate::plot::outline;
use crate::world::{Pair, World};

/// Width of the state panel, columns (less on a narrow terminal).
const PANEL_WIDTH: u16 = 44;

/// Margin around the reachable ring, as a fraction of the reach.
const MARGIN: f64 = 0.06;

/// A joint within this fraction of its range from a limit is drawn as near it.
pub const NEAR_LIMIT: f64 = 0.10;

/// The key-help line.
pub const HELP: &str = "q quit  arrows/wasd move  +/- speed  click goto, right-click reach  space \
                        stop  e estop  r reset  h home  tab strategy  t torque  c control";

/// The measured tips drawn behind the arm, oldest first; bounded.
#[derive(Debug, Clone)]
pub struct Trail {
    points: VecDeque<[f64; 2]>,
    capacity: usize,
}

impl Trail {
    /// Points closer than this to the last one kept are not kept, m.
    pub const MIN_STEP_M: f64 = 0.001;

    /// Keeps at most `capacity` points.
    pub fn new(capacity: usize) -> Self {
        Self {
            points: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Adds a measured tip, dropping the oldest beyond the capacity; a tip within
    /// [`Trail::MIN_STEP_M`] of the last one kept is skipped.
    pub fn push(&mut self, tip: [f64; 2]) {
        if self.capacity == 0 || !tip.iter().all(|c| c.is_finite()) {
            return;
        }
        if let Some(last) = self.points.back() {
            if (last[0] - tip[0]).hypot(last[1] - tip[1]) < Self::MIN_STEP_M {
                return;
            }
        }
        if self.points.len() == self.capacity {
            self.points.pop_front();
        }
        self.points.push_back(tip);
    }

    /// Forgets every point.
    pub fn clear(&mut self) {
        self.points.clear();
    }

    /// The points, oldest first.
    pub fn points(&self) -> impl Iterator<Item = [f64; 2]> + '_ {
        self.points.iter().copied()
    }

    /// How many points are kept.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no point is kept.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// Spacing of the points kept for an obstacle's outline and margin, m (the canvas thins them
/// to its dots).
const OUTLINE_STEP_M: f64 = 0.002;

/// The obstacles as the canvas draws them: the world, with each obstacle's outline and
/// clearance margin worked out once, when the world changes.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    world: World,
    /// Each obstacle's boundary, closed (the first point repeated last), m.
    outlines: Vec<Vec<(f64, f64)>>,
    /// The pieces of the obstacles' boundaries grown by `link_radius_m + clearance_m`, m.
    margins: Vec<Vec<(f64, f64)>>,
}

impl Scene {
    /// The scene of `world`.
    pub fn new(world: World) -> Self {
        let grow = world.link_radius_m() + world.clearance_m();
        let pair = |p: &Vec2| (p.x, p.y);
        let mut outlines = Vec::with_capacity(world.obstacles().len());
        let mut margins = Vec::new();
        for o in world.obstacles() {
            let mut ring: Vec<(f64, f64)> = outline::boundary(&o.shape, OUTLINE_STEP_M)
                .iter()
                .map(pair)
                .collect();
            if let Some(&first) = ring.first() {
                ring.push(first);
            }
            outlines.push(ring);
            if grow > 0.0 {
                margins.extend(
                    outline::grown(&o.shape, grow, OUTLINE_STEP_M)
                        .iter()
                        .map(|run| run.iter().map(pair).collect()),
                );
            }
        }
        Self {
            world,
            outlines,
            margins,
        }
    }

    /// The world drawn.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The pair of least clearance of the arm's commanded pose (`theta_cmd`; the measured one
    /// when telemetry has no commanded pose of the arm's size); `None` without obstacles.
    pub fn nearest(&self, arm: &ArmInfo, snapshot: &Snapshot) -> Option<Pair> {
        if self.world.obstacles().is_empty() {
            return None;
        }
        let joints = arm.chain().len();
        let theta = if snapshot.theta_cmd.len() == joints {
            &snapshot.theta_cmd
        } else {
            &snapshot.theta_meas
        };
        let points: Vec<Vec2> = arm
            .points(theta)
            .iter()
            .map(|p| Vec2::new(p[0], p[1]))
            .collect();
        if points.len() != joints + 1 {
            return None;
        }
        self.world.clearance(&points)
    }

    /// Whether the pair is near enough to be shown: within twice the world's clearance.
    pub fn shows(&self, pair: &Pair) -> bool {
        pair.clearance_m <= 2.0 * self.world.clearance_m()
    }
}

/// How long a live connection may go without telemetry before it shows as
/// [`Contact::Silent`], s: a daemon sends it at least 30 times a second, so a second without
/// any means it (or the way to it) is gone or stuck, though no one closed the connection.
pub const SILENT_AFTER_S: f64 = 1.0;

/// The connection to the daemon, as the panel shows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contact {
    /// Connecting (or waiting for the first reply).
    Connecting,
    /// Connected, telemetry coming.
    Connected,
    /// Connected, but no telemetry for `for_s` whole seconds (at least [`SILENT_AFTER_S`]).
    Silent {
        /// Whole seconds since telemetry last came (or since the connection was made).
        for_s: u64,
    },
    /// The daemon went away; the UI tries again every second.
    Gone,
}

impl Contact {
    /// A live connection, `quiet_s` seconds after telemetry last came on it (or after it was
    /// made, before any came): connected, or silent from [`SILENT_AFTER_S`] on.
    pub fn live(quiet_s: f64) -> Contact {
        if quiet_s >= SILENT_AFTER_S {
            Contact::Silent {
                for_s: quiet_s as u64,
            }
        } else {
            Contact::Connected
        }
    }
}

/// What the UI knows besides the arm and its telemetry.
#[derive(Debug, Clone)]
pub struct Panel {
    /// The daemon's address, `host:port`.
    pub addr: String,
    /// The connection's state.
    pub link: Contact,
    /// The speed the keys move the tip at, m/s.
    pub speed_m_s: f64,
    /// The joystick's state for a person (`None`: no joystick asked for).
    pub joystick: Option<String>,
    /// The last thing worth telling (a refusal, the daemon gone).
    pub notice: Option<String>,
    /// The obstacles the daemon keeps the arm clear of (none until it tells).
    pub scene: Scene,
}

impl Panel {
    /// Takes the daemon's world: from the next frame on, the canvas draws it.
    pub fn set_world(&mut self, world: World) {
        self.scene = Scene::new(world);
    }
}

/// Everything one frame shows.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// The arm (`None` before the first `describe`).
    pub arm: Option<&'a ArmInfo>,
    /// The latest telemetry, if any came.
    pub snapshot: Option<&'a Snapshot>,
    /// The measured tips so far.
    pub trail: &'a Trail,
    /// The UI's own state.
    pub status: &'a Panel,
}

/// Where the frame's parts go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Areas {
    /// The arm's canvas, with its border.
    pub canvas: Rect,
    /// The state panel, with its border.
    pub panel: Rect,
    /// The key-help line.
    pub help: Rect,
}

/// Splits the screen `area` into canvas, panel and help line.
pub fn areas(area: Rect) -> Areas {
    let rows = u16::try_from(help_lines(area.width).len()).unwrap_or(HELP_ROWS);
    let [main, help] = Layout::vertical([Constraint::Min(3), Constraint::Length(rows)]).areas(area);
    let panel_width = PANEL_WIDTH.min(main.width / 2);
    let [canvas, panel] =
        Layout::horizontal([Constraint::Min(3), Constraint::Length(panel_width)]).areas(main);
    Areas {
        canvas,
        panel,
        help,
    }
}

/// The world rectangle a canvas of `inner` (inside its border) shows, m:
/// `([x_min, x_max], [y_min, y_max])`, centred on the base, the whole reachable ring inside,
/// one scale on both axes (a cell taken as twice as tall as wide). Without an arm, 1 m around
/// the origin.
pub fn world_bounds<'a>(arm: impl Into<Option<&'a ArmInfo>>, inner: Rect) -> ([f64; 2], [f64; 2]) {
    let arm = arm.into();
    let reach = arm.map_or(0.0, ArmInfo::reach);
    let radius = if reach > 0.0 { reach } else { 1.0 } * (1.0 + MARGIN);
    let cols = f64::from(inner.width.max(1));
    let rows = f64::from(inner.height.max(1));
    // Metres per column; a row is two columns tall.
    let scale = (2.0 * radius / cols).max(2.0 * radius / (2.0 * rows));
    let half_w = scale * cols / 2.0;
    let half_h = scale * rows;
    let [bx, by, _] = arm.map_or([0.0; 3], |arm| arm.base);
    ([bx - half_w, bx + half_w], [by - half_h, by + half_h])
}

/// The canvas's area inside its border.
fn canvas_inner(canvas: Rect) -> Rect {
    Block::default().borders(Borders::ALL).inner(canvas)
}

/// The world point (m) under the cell at (`column`, `row`) of a screen of `screen`'s size,
/// where [`draw`] drew the canvas; `None` outside the canvas.
pub fn click_to_world(arm: &ArmInfo, screen: Rect, column: u16, row: u16) -> Option<[f64; 2]> {
    let inner = canvas_inner(areas(screen).canvas);
    if inner.width == 0
        || inner.height == 0
        || column < inner.x
        || row < inner.y
        || column >= inner.x + inner.width
        || row >= inner.y + inner.height
    {
        return None;
    }
    let (xs, ys) = world_bounds(arm, inner);
    // The centre of the cell's braille dots (2 across, 4 down), as the canvas places them.
    // In u32: four dots a row overflow a u16 from 16384 rows on.
    let dots = |cell: u16, per: u32| f64::from(per * u32::from(cell));
    let fx = (dots(column - inner.x, 2) + 1.0) / (dots(inner.width, 2) - 1.0);
    let fy = (dots(row - inner.y, 4) + 2.0) / (dots(inner.height, 4) - 1.0);
    Some([xs[0] + fx * (xs[1] - xs[0]), ys[1] - fy * (ys[1] - ys[0])])
}

/// Whether joint `i` at `theta` is within [`NEAR_LIMIT`] of its range from a limit (never, for
/// a joint without limits).
pub fn near_limit(arm: &ArmInfo, i: usize, theta: f64) -> bool {
    // The chain's limits: `describe` writes a joint without any as the extreme f64s, whose
    // range does not fit in one.
    let Some(Some(limit)) = arm.chain().limits().get(i) else {
        return false;
    };
    let margin = NEAR_LIMIT * (limit.hi - limit.lo);
    theta - limit.lo < margin || limit.hi - theta < margin
}

/// The most rows the key help takes.
pub const HELP_ROWS: u16 = 3;

/// [`HELP`] in lines of at most `width` columns, broken between its entries (two spaces
/// apart), in at most [`HELP_ROWS`] lines (the last cut when even they are too few).
pub fn help_lines(width: u16) -> Vec<String> {
    let width = usize::from(width.max(1));
    let mut lines: Vec<String> = Vec::new();
    for entry in HELP.split("  ") {
        let full = usize::from(HELP_ROWS) <= lines.len();
        match lines.last_mut() {
            Some(line) if full || line.chars().count() + 2 + entry.chars().count() <= width => {
                line.push_str("  ");
                line.push_str(entry);
            }
            _ => lines.push(entry.to_owned()),
        }
    }
    lines
}

/// Who is in control, as the panel says it.
pub fn controller_text(snapshot: &Snapshot) -> String {
    match (snapshot.in_control, snapshot.controller) {
        (true, _) => "you".to_owned(),
        (false, Some(n)) => format!("client {n}"),
        (false, None) => "nobody".to_owned(),
    }
}

/// The notice line: the UI's own notice, else a hint when another client is in control.
pub fn notice_text(view: &View<'_>) -> Option<String> {
    if let Some(notice) = &view.status.notice {
        return Some(notice.clone());
    }
    let snapshot = view.snapshot?;
    match (snapshot.in_control, snapshot.controller) {
        (false, Some(n)) if view.status.link == Contact::Connected => {
            Some(format!("client {n} is in control: press c to take it"))
        }
        _ => None,
    }
}

/// Draws the whole screen.
pub fn draw(frame: &mut Frame<'_>, view: &View<'_>) {
    let parts = areas(frame.area());
    draw_canvas(frame, parts.canvas, view);
    draw_panel(frame, parts.panel, view);
    let style = Style::default().fg(Color::DarkGray);
    let lines: Vec<Line<'_>> = help_lines(parts.help.width)
        .into_iter()
        .map(|line| Line::from(Span::styled(line, style)))
        .collect();
    frame.render_widget(Paragraph::new(lines), parts.help);
}

fn draw_canvas(frame: &mut Frame<'_>, area: Rect, view: &View<'_>) {
    let block = Block::default().borders(Borders::ALL).title(" arm ");
    let inner = block.inner(area);
    let (x_bounds, y_bounds) = world_bounds(view.arm, inner);
    let trail: Vec<(f64, f64)> = view.trail.points().map(|[x, y]| (x, y)).collect();
    // Braille: 2 dots a column, 4 a row; the canvas spreads them over the bounds.
    let dots = Dots {
        x0: x_bounds[0],
        y0: y_bounds[0],
        step: (x_bounds[1] - x_bounds[0]) / f64::from((2 * u32::from(inner.width)).max(2) - 1),
        step_y: (y_bounds[1] - y_bounds[0]) / f64::from((4 * u32::from(inner.height)).max(2) - 1),
        across: 2 * usize::from(inner.width),
        down: 4 * usize::from(inner.height),
    };
    let canvas = Canvas::default()
        .block(block)
        .marker(Marker::Braille)
        .x_bounds(x_bounds)
        .y_bounds(y_bounds)
        .paint(|ctx| {
            paint_scene(ctx, &view.status.scene, &dots);
            paint_arm(ctx, view, &trail);
        });
    frame.render_widget(canvas, area);
}

/// Where the canvas's dots fall, in the world.
struct Dots {
    /// The world point of dot (0, 0) (bottom left), m.
    x0: f64,
    y0: f64,
    /// From one dot to the next across and up, m.
    step: f64,
    step_y: f64,
    /// Dots across and up.
    across: usize,
    down: usize,
}

/// The obstacles, under everything else: each shaded (every other dot inside) and outlined,
/// then its clearance margin dotted.
fn paint_scene(ctx: &mut Context<'_>, scene: &Scene, dots: &Dots) {
    if scene.world.obstacles().is_empty() || dots.step <= 0.0 || dots.step_y <= 0.0 {
        return;
    }
    let mut shade = Vec::new();
    for o in scene.world.obstacles() {
        let (lo, hi) = o.shape.bounds();
        let range = |lo: f64, hi: f64, origin: f64, step: f64, count: usize| {
            let first = ((lo - origin) / step).ceil().max(0.0) as usize;
            let last = (((hi - origin) / step).floor().max(-1.0) + 1.0) as usize;
            first..last.min(count)
        };
        for j in range(lo.y, hi.y, dots.y0, dots.step_y, dots.down) {
            for i in range(lo.x, hi.x, dots.x0, dots.step, dots.across) {
                let p = Vec2::new(
                    dots.x0 + i as f64 * dots.step,
                    dots.y0 + j as f64 * dots.step_y,
                );
                if (i + j) % 2 == 0 && o.shape.point_distance(p) < 0.0 {
                    shade.push((p.x, p.y));
                }
            }
        }
    }
    ctx.draw(&Points {
        coords: &shade,
        color: Color::DarkGray,
    });
    ctx.layer();
    for ring in &scene.outlines {
        for w in ring.windows(2) {
            ctx.draw(&Segment::new(w[0].0, w[0].1, w[1].0, w[1].1, Color::Gray));
        }
    }
    // The margin dotted: a point every second dot along it.
    let mut dotted = Vec::new();
    for run in &scene.margins {
        let mut since = f64::INFINITY;
        let mut last: Option<(f64, f64)> = None;
        for &p in run {
            if let Some(q) = last {
                since += (p.0 - q.0).hypot(p.1 - q.1);
            }
            last = Some(p);
            if since >= 2.0 * dots.step {
                dotted.push(p);
                since = 0.0;
            }
        }
    }
    ctx.draw(&Points {
        coords: &dotted,
        color: Color::Gray,
    });
    ctx.layer();
}

fn paint_arm(ctx: &mut Context<'_>, view: &View<'_>, trail: &[(f64, f64)]) {
    let Some(arm) = view.arm else {
        ctx.draw(&Points {
            coords: trail,
            color: Color::Blue,
        });
        return;
    };
    let [bx, by, _] = arm.base;
    let reach = arm.reach();
    if reach > 0.0 {
        ctx.draw(&Circle {
            x: bx,
            y: by,
            radius: reach,
            color: Color::DarkGray,
        });
        let inner = arm.inner_radius();
        if inner > 0.0 {
            ctx.draw(&Circle {
                x: bx,
                y: by,
                radius: inner,
                color: Color::DarkGray,
            });
        }
    }
    ctx.draw(&Points {
        coords: trail,
        color: Color::Blue,
    });
    let Some(snapshot) = view.snapshot else {
        return;
    };
    let points = arm.points(&snapshot.theta_meas);
    ctx.layer();
    for pair in points.windows(2) {
        ctx.draw(&Segment::new(
            pair[0][0],
            pair[0][1],
            pair[1][0],
            pair[1][1],
            Color::White,
        ));
    }
    ctx.layer();
    // Joint i turns at point i; the last point is the tip.
    let joints = points.len().saturating_sub(1);
    let (near, fine): (Vec<usize>, Vec<usize>) = (0..joints)
        .filter(|&i| snapshot.theta_meas.get(i).is_some())
        .partition(|&i| near_limit(arm, i, snapshot.theta_meas[i]));
    let coords = |set: &[usize]| -> Vec<(f64, f64)> {
        set.iter().map(|&i| (points[i][0], points[i][1])).collect()
    };
    for (set, color) in [(&fine, Color::Green), (&near, Color::Red)] {
        for (x, y) in coords(set) {
            ctx.draw(&Circle {
                x,
                y,
                radius: 0.006,
                color,
            });
        }
    }
    for (x, y) in coords(&near) {
        ctx.print(
            x,
            y,
            Span::styled(
                "!",
                Style::default().fg(Color::Red).add_modifier(Modifier::BOLD),
            ),
        );
    }
    if let Some(pair) = view.status.scene.nearest(arm, snapshot) {
        if view.status.scene.shows(&pair) {
            ctx.layer();
            let (a, b) = (pair.contact.on_segment, pair.contact.on_obstacle);
            ctx.draw(&Segment::new(
                a.x,
                a.y,
                b.x,
                b.y,
                pair_colour(&view.status.scene, &pair),
            ));
        }
    }
    if let Some([tx, ty]) = snapshot.target {
        ctx.print(
            tx,
            ty,
            Span::styled("X", Style::default().fg(Color::Magenta)),
        );
    }
    let [cx, cy] = snapshot.tip;
    ctx.print(cx, cy, Span::styled("+", Style::default().fg(Color::Cyan)));
    let [mx, my] = snapshot.tip_meas;
    ctx.print(
        mx,
        my,
        Span::styled(
            "@",
            Style::default()
                .fg(Color::Yellow)
                .add_modifier(Modifier::BOLD),
        ),
    );
}

/// The nearest pair's colour: red when the pose is not clear, yellow when it is (but within
/// twice the clearance).
fn pair_colour(scene: &Scene, pair: &Pair) -> Color {
    if pair.clearance_m < scene.world.clearance_m() {
        Color::Red
    } else {
        Color::Yellow
    }
}

/// The joints of the measured pose near a limit.
fn near_ids(arm: &ArmInfo, snapshot: &Snapshot) -> Vec<usize> {
    snapshot
        .theta_meas
        .iter()
        .enumerate()
        .filter(|&(i, &theta)| near_limit(arm, i, theta))
        .map(|(i, _)| i)
        .collect()
}

fn row<'a>(label: &'a str, value: String, style: Style) -> Line<'a> {
    Line::from(vec![
        Span::styled(format!("{label:<10}"), Style::default().fg(Color::DarkGray)),
        Span::styled(value, style),
    ])
}

fn state_style(state: State) -> Style {
    let color = match state {
        State::Holding => Color::Green,
        State::Moving => Color::Cyan,
        State::Stopping | State::TorqueOff => Color::Yellow,
        State::Estop | State::Fault => Color::Red,
    };
    Style::default().fg(color).add_modifier(Modifier::BOLD)
}

/// The panel's lines.
pub fn panel_lines(view: &View<'_>) -> Vec<Line<'static>> {
    let plain = Style::default();
    let status = view.status;
    let mut lines = vec![row("daemon", status.addr.clone(), plain)];
    let (link, link_style) = match status.link {
        Contact::Connecting => ("connecting".to_owned(), Style::default().fg(Color::Yellow)),
        Contact::Connected => ("connected".to_owned(), Style::default().fg(Color::Green)),
        Contact::Silent { for_s } => (
            format!("no telemetry for {for_s} s"),
            Style::default().fg(Color::Red),
        ),
        Contact::Gone => ("gone: retrying".to_owned(), Style::default().fg(Color::Red)),
    };
    lines.push(row("link", link, link_style));
    match view.snapshot {
        None => lines.push(Line::from("waiting for telemetry")),
        Some(s) => snapshot_lines(view.arm, &status.scene, s, status.link, &mut lines),
    }
    lines.push(row("speed", format!("{:.3} m/s", status.speed_m_s), plain));
    lines.push(row(
        "joystick",
        status.joystick.clone().unwrap_or_else(|| "none".to_owned()),
        plain,
    ));
    lines.push(Line::from(""));
    lines.push(Line::from(vec![
        Span::styled("@", Style::default().fg(Color::Yellow)),
        Span::raw(" tip  "),
        Span::styled("+", Style::default().fg(Color::Cyan)),
        Span::raw(" commanded  "),
        Span::styled("X", Style::default().fg(Color::Magenta)),
        Span::raw(" target  "),
        Span::styled("!", Style::default().fg(Color::Red)),
        Span::raw(" limit"),
    ]));
    if let Some(notice) = notice_text(view) {
        lines.push(Line::from(""));
        lines.push(Line::from(Span::styled(
            notice,
            Style::default()
                .fg(Color::Yellow)
                .add_modifier(Modifier::BOLD),
        )));
    }
    lines
}

/// The commanded pose's clearance among obstacles (`clear  12.3 mm  link 5, post`): green
/// beyond twice `clearance_m`, yellow within it, red below `clearance_m`; `None` without
/// obstacles.
fn clearance_line(scene: &Scene, arm: &ArmInfo, s: &Snapshot) -> Option<Line<'static>> {
    let pair = scene.nearest(arm, s)?;
    let colour = if scene.shows(&pair) {
        pair_colour(scene, &pair)
    } else {
        Color::Green
    };
    Some(row(
        "clearance",
        format!(
            "{:.1} mm  link {}, {}",
            pair.clearance_m * 1000.0,
            pair.link,
            pair.id(&scene.world)
        ),
        Style::default().fg(colour),
    ))
}

/// The snapshot's rows. Without telemetry (`link` silent or gone) the state is the last one
/// seen, and says so; with the daemon gone, so is its control.
fn snapshot_lines(
    arm: Option<&ArmInfo>,
    scene: &Scene,
    s: &Snapshot,
    link: Contact,
    lines: &mut Vec<Line<'static>>,
) {
    let plain = Style::default();
    let stale = Style::default().fg(Color::DarkGray);
    let signed = |p: [f64; 2]| format!("{:+.3}  {:+.3} m", p[0], p[1]);
    match link {
        Contact::Connecting | Contact::Connected => {
            lines.push(row("state", s.state.to_string(), state_style(s.state)));
        }
        Contact::Silent { .. } | Contact::Gone => {
            lines.push(row("state", format!("{} (last seen)", s.state), stale));
        }
    }
    lines.push(row("strategy", s.strategy.name().to_owned(), plain));
    let control_style = if s.in_control {
        Style::default().fg(Color::Green)
    } else {
        Style::default().fg(Color::Yellow)
    };
    if link == Contact::Gone {
        // The session ended with the connection: whatever control it held is gone with it.
        lines.push(row("control", "none: the daemon is gone".to_owned(), stale));
    } else {
        lines.push(row("control", controller_text(s), control_style));
    }
    lines.push(row(
        "loop",
        format!(
            "{:.1} Hz (of {:.0})",
            s.loop_hz,
            arm.map_or(0.0, |arm| arm.rate_hz)
        ),
        plain,
    ));
    lines.push(row(
        "solve",
        format!("{:.0} us (p99 tick {:.0} us)", s.solve_us, s.tick_p99_us),
        plain,
    ));
    lines.push(row(
        "error",
        format!("{:.1} mm", s.tracking_error_m * 1000.0),
        plain,
    ));
    // Read by the pty test: `tip  -0.547  +0.720 m`.
    lines.push(Line::from(format!("tip  {}", signed(s.tip_meas))));
    lines.push(Line::from(Span::styled(
        format!("cmd  {}", signed(s.tip)),
        Style::default().fg(Color::Cyan),
    )));
    if let Some(target) = s.target {
        lines.push(Line::from(Span::styled(
            format!("goal {}", signed(target)),
            Style::default().fg(Color::Magenta),
        )));
    }
    let mut flags = Vec::new();
    if s.saturated {
        flags.push("saturated");
    }
    if s.self_collision {
        flags.push("self-collision");
    }
    if !flags.is_empty() {
        lines.push(row(
            "flags",
            flags.join(", "),
            Style::default().fg(Color::Yellow),
        ));
    }
    if let Some(line) = arm.and_then(|arm| clearance_line(scene, arm, s)) {
        lines.push(line);
    }
    let (torque, torque_style) = if s.torque {
        ("on", Style::default().fg(Color::Green))
    } else {
        ("off", Style::default().fg(Color::Red))
    };
    lines.push(row("torque", torque.to_owned(), torque_style));
    let near = arm.map(|arm| near_ids(arm, s)).unwrap_or_default();
    if !near.is_empty() {
        let joints: Vec<String> = near.iter().map(|i| (i + 1).to_string()).collect();
        lines.push(row(
            "limits",
            format!("joint {} near a limit", joints.join(", ")),
            Style::default().fg(Color::Red),
        ));
    }
    if s.faults.is_empty() {
        lines.push(row("faults", "none".to_owned(), plain));
    } else {
        lines.push(row(
            "faults",
            s.faults.len().to_string(),
            Style::default().fg(Color::Red),
        ));
        for fault in &s.faults {
            lines.push(Line::from(Span::styled(
                fault.to_string(),
                Style::default().fg(Color::Red),
            )));
        }
    }
    if s.warnings.is_empty() {
        lines.push(row("warnings", "none".to_owned(), plain));
    } else {
        lines.push(row(
            "warnings",
            s.warnings.len().to_string(),
            Style::default().fg(Color::Yellow),
        ));
        for warning in &s.warnings {
            lines.push(Line::from(Span::styled(
                warning.to_string(),
                Style::default().fg(Color::Yellow),
            )));
        }
    }
}

fn draw_panel(frame: &mut Frame<'_>, area: Rect, view: &View<'_>) {
    let block = Block::default()
        .borders(Borders::ALL)
        .title(" snakectl teleop ");
    frame.render_widget(
        Paragraph::new(panel_lines(view))
            .block(block)
            .wrap(Wrap { trim: false }),
        area,
    );
}

#[cfg(test)]
mod tests;
