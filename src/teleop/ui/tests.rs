//! The screen drawn onto a test backend and read back as text.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use ratatui::backend::TestBackend;
use ratatui::buffer::Buffer;
use ratatui::style::Color;
use ratatui::Terminal;

use super::*;
use crate::client::{Describe, FaultInfo, FaultKind, Telemetry};
use crate::protocol::STRATEGIES;
use crate::resolve::Strategy;
use crate::world::{Obstacle, Shape, World};

const COLS: u16 = 120;
const ROWS: u16 = 40;

/// The shipped simulator's arm: 12 links of 0.08 m, base at the origin pointing up.
fn sim_arm() -> ArmInfo {
    ArmInfo::new(Describe {
        links_m: vec![0.08; 12],
        base: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        min_rad: vec![-2.0; 12],
        max_rad: vec![2.0; 12],
        ids: (1..=12).collect(),
        models: vec!["XL430-W250".into(); 12],
        home_rad: vec![0.1; 12],
        rate_hz: 100.0,
        strategies: STRATEGIES.to_vec(),
        protocol_version: 1,
        ..Describe::default()
    })
    .unwrap()
}

/// The arm at `theta`, holding, this client in control.
fn snapshot_at(arm: &ArmInfo, theta: &[f64]) -> Snapshot {
    let points = arm.points(theta);
    let tip = *points.last().unwrap();
    Snapshot {
        telemetry: Telemetry {
            state: State::Holding,
            strategy: Strategy::Overall,
            tip,
            tip_meas: tip,
            tip_ref: tip,
            theta_cmd: theta.to_vec(),
            theta_meas: theta.to_vec(),
            loop_hz: 100.0,
            solve_us: 42.0,
            torque: true,
            ..Telemetry::default()
        },
        controller: Some(1),
        in_control: true,
    }
}

fn status() -> Panel {
    Panel {
        addr: "127.0.0.1:40404".into(),
        link: Contact::Connected,
        speed_m_s: 0.05,
        joystick: None,
        notice: None,
        scene: Scene::default(),
    }
}

fn render(view: &View<'_>) -> Buffer {
    let mut terminal = Terminal::new(TestBackend::new(COLS, ROWS)).unwrap();
    terminal.draw(|frame| draw(frame, view)).unwrap();
    terminal.backend().buffer().clone()
}

/// Renders `arm` with `snapshot` and `status`, and an empty trail.
fn render_arm<'a>(
    arm: impl Into<Option<&'a ArmInfo>>,
    snapshot: Option<&Snapshot>,
    status: &Panel,
) -> Buffer {
    let trail = Trail::new(10);
    render(&View {
        arm: arm.into(),
        snapshot,
        trail: &trail,
        status,
    })
}

fn lines(buffer: &Buffer) -> Vec<String> {
    (0..buffer.area.height)
        .map(|y| {
            (0..buffer.area.width)
                .map(|x| buffer[(x, y)].symbol())
                .collect()
        })
        .collect()
}

fn screen() -> Rect {
    Rect::new(0, 0, COLS, ROWS)
}

fn is_braille(symbol: &str) -> bool {
    symbol
        .chars()
        .next()
        .is_some_and(|c| ('\u{2801}'..='\u{28ff}').contains(&c))
}

/// The cell a world point falls in, as the canvas places labels.
fn cell_of(arm: &ArmInfo, p: [f64; 2]) -> (u16, u16) {
    let inner = canvas_inner(areas(screen()).canvas);
    let (xs, ys) = world_bounds(arm, inner);
    let col = (p[0] - xs[0]) / (xs[1] - xs[0]) * f64::from(inner.width - 1);
    let row = (ys[1] - p[1]) / (ys[1] - ys[0]) * f64::from(inner.height - 1);
    (inner.x + col as u16, inner.y + row as u16)
}

/// The cell whose braille dots show a world point.
fn dot_cell_of(arm: &ArmInfo, p: [f64; 2]) -> (u16, u16) {
    let inner = canvas_inner(areas(screen()).canvas);
    let (xs, ys) = world_bounds(arm, inner);
    let dot_x = (p[0] - xs[0]) / (xs[1] - xs[0]) * f64::from(2 * inner.width - 1);
    let dot_y = (ys[1] - p[1]) / (ys[1] - ys[0]) * f64::from(4 * inner.height - 1);
    (inner.x + dot_x as u16 / 2, inner.y + dot_y as u16 / 4)
}

#[test]
fn the_measured_arm_is_drawn_inside_the_canvas_and_nowhere_else() {
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let status = status();
    let buffer = render_arm(&arm, Some(&snapshot), &status);
    let parts = areas(screen());
    let inner = canvas_inner(parts.canvas);
    // Every link's midpoint lies on a drawn cell.
    let points = arm.points(&snapshot.theta_meas);
    for (i, pair) in points.windows(2).enumerate() {
        let mid = [
            (pair[0][0] + pair[1][0]) / 2.0,
            (pair[0][1] + pair[1][1]) / 2.0,
        ];
        let (x, y) = dot_cell_of(&arm, mid);
        let symbol = buffer[(x, y)].symbol();
        assert!(
            is_braille(symbol),
            "link {} is not drawn at ({x}, {y}): {symbol:?}\n{}",
            i + 1,
            lines(&buffer).join("\n")
        );
    }
    for y in 0..ROWS {
        for x in 0..COLS {
            let inside = x >= inner.x
                && x < inner.x + inner.width
                && y >= inner.y
                && y < inner.y + inner.height;
            if !inside {
                assert!(!is_braille(buffer[(x, y)].symbol()), "dots at ({x}, {y})");
            }
        }
    }
    // The measured tip's marker sits on the tip.
    let (x, y) = cell_of(&arm, snapshot.tip_meas);
    assert_eq!(buffer[(x, y)].symbol(), "@");
}

#[test]
fn the_canvas_keeps_one_scale_on_both_axes() {
    let arm = sim_arm();
    for (cols, rows) in [(120, 40), (80, 24), (200, 30), (60, 60)] {
        let inner = canvas_inner(areas(Rect::new(0, 0, cols, rows)).canvas);
        let (xs, ys) = world_bounds(&arm, inner);
        let per_col = (xs[1] - xs[0]) / f64::from(inner.width);
        let per_row = (ys[1] - ys[0]) / f64::from(inner.height);
        assert!(
            (per_row - 2.0 * per_col).abs() < 1e-9,
            "{cols}x{rows}: {per_col} m a column, {per_row} m a row"
        );
        // The whole reachable ring is in view.
        assert!(xs[0] <= -arm.reach() && xs[1] >= arm.reach(), "{xs:?}");
        assert!(ys[0] <= -arm.reach() && ys[1] >= arm.reach(), "{ys:?}");
    }
}

#[test]
fn the_panel_shows_address_state_control_and_the_measured_tip() {
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let status = status();
    let text = lines(&render_arm(&arm, Some(&snapshot), &status)).join("\n");
    for expected in [
        "127.0.0.1:40404",
        "holding",
        "overall",
        "control   you",
        "tip  -0.547  +0.720 m",
        "0.050 m/s",
        "faults    none",
        "torque    on",
        "100.0 Hz",
        "q quit",
    ] {
        assert!(text.contains(expected), "no {expected:?} in\n{text}");
    }
}

#[test]
fn the_key_help_is_whole_on_a_hundred_columns_and_kept_to_three_rows() {
    let entries: Vec<&str> = HELP.split("  ").collect();
    for width in [100u16, 80, 60] {
        let lines = help_lines(width);
        assert!(lines.len() <= usize::from(HELP_ROWS), "{width}: {lines:?}");
        assert!(
            lines
                .iter()
                .all(|l| l.chars().count() <= usize::from(width)),
            "{width}: {lines:?}"
        );
        assert_eq!(lines.join("  ").split("  ").collect::<Vec<_>>(), entries);
    }
    assert_eq!(help_lines(200), [HELP]);
    // The canvas gives up the rows the help takes.
    let screen = Rect::new(0, 0, 100, 32);
    assert_eq!(areas(screen).help.height, 2);
    assert_eq!(areas(screen).canvas.height, 30);
}

#[test]
fn a_fault_is_named_by_its_servo() {
    let arm = sim_arm();
    let mut snapshot = snapshot_at(&arm, &arm.home_rad);
    snapshot.state = State::Fault;
    snapshot.faults.push(FaultInfo {
        id: Some(5),
        joint: Some(5),
        port: None,
        kind: FaultKind::Silent,
        since_tick: 200,
        detail: "no status".into(),
    });
    let status = status();
    let text = lines(&render_arm(&arm, Some(&snapshot), &status)).join("\n");
    assert!(text.contains("servo 5 (joint 5): silent"), "{text}");
    assert!(text.contains("fault"), "{text}");
}

#[test]
fn a_joint_near_its_limit_is_marked_in_red() {
    let arm = sim_arm();
    let mut theta = arm.home_rad.clone();
    // 0.15 rad from +2: inside 10 % of the 4 rad range.
    theta[2] = 1.85;
    let snapshot = snapshot_at(&arm, &theta);
    let status = status();
    let buffer = render_arm(&arm, Some(&snapshot), &status);
    let text = lines(&buffer).join("\n");
    assert!(text.contains("joint 3 near a limit"), "{text}");
    let joint = arm.points(&theta)[2];
    let (x, y) = cell_of(&arm, joint);
    assert_eq!(buffer[(x, y)].symbol(), "!");
    assert_eq!(buffer[(x, y)].fg, Color::Red);
    // A joint mid-range is not marked.
    assert!(!near_limit(&arm, 0, 0.1));
    assert!(near_limit(&arm, 0, -1.7));
}

#[test]
fn a_joint_without_limits_is_never_near_one() {
    // The protocol writes a joint without limits as the lowest and highest f64.
    let mut describe = sim_arm().describe().clone();
    describe.min_rad[0] = f64::MIN;
    describe.max_rad[0] = f64::MAX;
    let arm = ArmInfo::new(describe).unwrap();
    assert_eq!(arm.chain().limits()[0], None);
    for theta in [0.0, 3.0, -100.0] {
        assert!(!near_limit(&arm, 0, theta), "{theta}");
    }
    assert!(near_limit(&arm, 1, 1.9), "a limited joint still is");
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let text = lines(&render_arm(&arm, Some(&snapshot), &status())).join("\n");
    assert!(!text.contains("near a limit"), "{text}");
}

#[test]
fn another_client_in_control_is_named_with_the_way_to_take_over() {
    let arm = sim_arm();
    let mut snapshot = snapshot_at(&arm, &arm.home_rad);
    snapshot.in_control = false;
    snapshot.controller = Some(3);
    let status = status();
    let text = lines(&render_arm(&arm, Some(&snapshot), &status)).join("\n");
    assert!(text.contains("control   client 3"), "{text}");
    assert!(
        text.contains("client 3 is in control: press c to take it"),
        "{text}"
    );
    snapshot.controller = None;
    assert_eq!(controller_text(&snapshot), "nobody");
}

#[test]
fn a_gone_daemon_is_told_and_the_last_pose_stays_drawn() {
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let mut status = status();
    status.link = Contact::Gone;
    status.notice = Some("daemon at 127.0.0.1:40404 gone: retrying".into());
    let buffer = render_arm(&arm, Some(&snapshot), &status);
    let text = lines(&buffer).join("\n");
    assert!(
        text.contains("daemon at 127.0.0.1:40404 gone: retrying"),
        "{text}"
    );
    // Its control went with it; the state shown is the last one seen.
    assert!(
        text.contains("control   none: the daemon is gone"),
        "{text}"
    );
    assert!(!text.contains("control   you"), "{text}");
    assert!(text.contains("state     holding (last seen)"), "{text}");
    let (x, y) = cell_of(&arm, snapshot.tip_meas);
    assert_eq!(buffer[(x, y)].symbol(), "@");
}

#[test]
fn a_link_without_telemetry_for_a_second_shows_silent_and_connected_again_after() {
    assert_eq!(Contact::live(0.0), Contact::Connected);
    assert_eq!(Contact::live(0.999), Contact::Connected);
    assert_eq!(Contact::live(1.0), Contact::Silent { for_s: 1 });
    assert_eq!(Contact::live(2.7), Contact::Silent { for_s: 2 });
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let mut status = status();
    status.link = Contact::live(3.2);
    let buffer = render_arm(&arm, Some(&snapshot), &status);
    let text = lines(&buffer).join("\n");
    assert!(text.contains("link      no telemetry for 3 s"), "{text}");
    assert!(!text.contains("connected"), "{text}");
    assert!(text.contains("(last seen)"), "{text}");
    // The last pose stays drawn.
    let (x, y) = cell_of(&arm, snapshot.tip_meas);
    assert_eq!(buffer[(x, y)].symbol(), "@");
    // Telemetry again: connected.
    status.link = Contact::live(0.02);
    let text = lines(&render_arm(&arm, Some(&snapshot), &status)).join("\n");
    assert!(text.contains("link      connected"), "{text}");
}

#[test]
fn before_any_telemetry_the_screen_says_it_waits() {
    let mut status = status();
    status.link = Contact::Connecting;
    let text = lines(&render_arm(None, None, &status)).join("\n");
    assert!(text.contains("waiting for telemetry"), "{text}");
    assert!(text.contains("connecting"), "{text}");
}

#[test]
fn the_trail_is_drawn_and_bounded() {
    let arm = sim_arm();
    let mut trail = Trail::new(100);
    for i in 0..1000 {
        trail.push([f64::from(i) * 0.002 - 1.5, 0.3]);
    }
    assert_eq!(trail.len(), 100);
    let first = trail.points().next().unwrap();
    assert!(
        (first[0] - (900.0 * 0.002 - 1.5)).abs() < 1e-12,
        "{first:?}"
    );
    // A tip that did not move is not kept twice.
    let last = trail.points().last().unwrap();
    trail.push([last[0] + 0.0001, last[1]]);
    assert_eq!(trail.points().last().unwrap(), last);

    let status = status();
    let view = View {
        arm: Some(&arm),
        snapshot: None,
        trail: &trail,
        status: &status,
    };
    let buffer = render(&view);
    let (x, y) = dot_cell_of(&arm, [0.4, 0.3]);
    assert!(
        is_braille(buffer[(x, y)].symbol()),
        "no trail at ({x}, {y})"
    );
    assert_eq!(buffer[(x, y)].fg, Color::Blue);
}

#[test]
fn a_click_on_the_canvas_maps_back_to_the_point_drawn_there() {
    let arm = sim_arm();
    let inner = canvas_inner(areas(screen()).canvas);
    let (xs, _) = world_bounds(&arm, inner);
    let cell_m = (xs[1] - xs[0]) / f64::from(inner.width);
    for p in [[-0.547, 0.720], [0.3, -0.2], [0.0, 0.0], [0.9, 0.1]] {
        let (col, row) = dot_cell_of(&arm, p);
        let back = click_to_world(&arm, screen(), col, row).unwrap();
        // Within a cell: one column wide, one row (two columns) tall.
        assert!((back[0] - p[0]).abs() <= cell_m, "{p:?} -> {back:?}");
        assert!((back[1] - p[1]).abs() <= 2.0 * cell_m, "{p:?} -> {back:?}");
    }
    let parts = areas(screen());
    // The border, the panel and the help line are not the canvas.
    assert_eq!(click_to_world(&arm, screen(), 0, 5), None);
    assert_eq!(click_to_world(&arm, screen(), parts.panel.x + 3, 5), None);
    assert_eq!(click_to_world(&arm, screen(), 10, parts.help.y), None);
}

#[test]
fn a_click_on_a_huge_terminal_maps_to_the_world_without_overflow() {
    let arm = sim_arm();
    // A pty may be set to any size (`stty rows 20000 cols 40000`): a click anywhere maps.
    for screen in [
        Rect::new(0, 0, 120, 20_000),
        Rect::new(0, 0, 40_000, 40),
        Rect::new(0, 0, u16::MAX, u16::MAX),
    ] {
        let parts = areas(screen);
        let inner = canvas_inner(parts.canvas);
        let (xs, ys) = world_bounds(&arm, inner);
        for (col, row) in [
            (inner.x, inner.y),
            (inner.x + inner.width - 1, inner.y + inner.height - 1),
        ] {
            let p = click_to_world(&arm, screen, col, row)
                .unwrap_or_else(|| panic!("{screen:?}: ({col}, {row}) is on the canvas"));
            assert!(
                (xs[0]..=xs[1]).contains(&p[0]) && (ys[0]..=ys[1]).contains(&p[1]),
                "{screen:?}: ({col}, {row}) -> {p:?}"
            );
        }
    }
}

/// A panel whose world is one disc `post` at `center`, radius `radius_m`.
fn among_post(center: [f64; 2], radius_m: f64, link_radius_m: f64, clearance_m: f64) -> Panel {
    let mut panel = status();
    let post = Obstacle {
        id: "post".into(),
        shape: Shape::Circle {
            center: Vec2::new(center[0], center[1]),
            radius_m,
        },
    };
    panel.set_world(World::new(link_radius_m, clearance_m, vec![post]).unwrap());
    panel
}

/// The canvas's braille cells drawn in `colour`.
fn braille_cells(buffer: &Buffer, colour: Color) -> Vec<(u16, u16)> {
    let inner = canvas_inner(areas(screen()).canvas);
    let mut cells = Vec::new();
    for y in inner.y..inner.y + inner.height {
        for x in inner.x..inner.x + inner.width {
            if is_braille(buffer[(x, y)].symbol()) && buffer[(x, y)].fg == colour {
                cells.push((x, y));
            }
        }
    }
    cells
}

#[test]
fn an_obstacle_is_shaded_outlined_and_ringed_by_its_margin_where_it_is() {
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    // Away from the arm, which curls up and to the left.
    let panel = among_post([0.5, -0.4], 0.06, 0.02, 0.05);
    let buffer = render_arm(&arm, Some(&snapshot), &panel);
    let text = lines(&buffer).join("\n");
    let centre = dot_cell_of(&arm, [0.5, -0.4]);
    assert!(
        is_braille(buffer[centre].symbol()),
        "no shade at {centre:?}\n{text}"
    );
    assert_eq!(buffer[centre].fg, Color::DarkGray);
    for edge in [[0.56, -0.4], [0.44, -0.4]] {
        let cell = dot_cell_of(&arm, edge);
        assert!(
            is_braille(buffer[cell].symbol()),
            "no outline at {cell:?}\n{text}"
        );
        assert_eq!(buffer[cell].fg, Color::Gray);
    }
    // The margin, 0.06 + 0.07 from the centre, beside the outline and apart from it.
    for side in [[0.63, -0.4], [0.37, -0.4]] {
        let cell = dot_cell_of(&arm, side);
        assert!(
            is_braille(buffer[cell].symbol()),
            "no margin at {cell:?}\n{text}"
        );
        assert_eq!(buffer[cell].fg, Color::Gray);
    }
    let outside = dot_cell_of(&arm, [0.5, -0.62]);
    assert_eq!(buffer[outside].symbol(), " ", "{outside:?}\n{text}");
    // Far from the arm: its clearance shown in green, and no nearest-pair line.
    assert!(text.contains("mm  link 1, post"), "{text}");
    assert!(braille_cells(&buffer, Color::Yellow).is_empty());
    // Without a world, nothing there.
    let buffer = render_arm(&arm, Some(&snapshot), &status());
    assert_eq!(buffer[centre].symbol(), " ");
    assert!(!lines(&buffer).join("\n").contains("clearance"));
}

#[test]
fn the_nearest_pair_is_drawn_only_within_twice_the_clearance() {
    let arm = sim_arm();
    let snapshot = snapshot_at(&arm, &arm.home_rad);
    let points = arm.points(&arm.home_rad);
    // A post on the outer side of link 6, `gap` from its middle; the clearance is 0.05.
    let (a, b) = (points[5], points[6]);
    let mid = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
    let len = (b[0] - a[0]).hypot(b[1] - a[1]);
    let out = [(b[1] - a[1]) / len, -(b[0] - a[0]) / len];
    let (radius, clearance) = (0.04, 0.05);
    let panel_at = |gap: f64| {
        let c = [
            mid[0] + out[0] * (gap + radius),
            mid[1] + out[1] * (gap + radius),
        ];
        among_post(c, radius, 0.0, clearance)
    };
    let halfway = |gap: f64| [mid[0] + out[0] * gap / 2.0, mid[1] + out[1] * gap / 2.0];

    // 0.08: clear, within twice the clearance: a yellow line from the link to the post.
    let panel = panel_at(0.08);
    let pair = panel.scene.nearest(&arm, &snapshot).unwrap();
    assert_eq!((pair.link, pair.id(panel.scene.world())), (6, "post"));
    assert!(
        (pair.clearance_m - 0.08).abs() < 1e-9,
        "{}",
        pair.clearance_m
    );
    let buffer = render_arm(&arm, Some(&snapshot), &panel);
    let text = lines(&buffer).join("\n");
    let cell = dot_cell_of(&arm, halfway(0.08));
    assert_eq!(buffer[cell].fg, Color::Yellow, "{cell:?}\n{text}");
    assert!(text.contains("clearance 80.0 mm  link 6, post"), "{text}");

    // 0.03: not clear: the line turns red.
    let buffer = render_arm(&arm, Some(&snapshot), &panel_at(0.03));
    assert!(!braille_cells(&buffer, Color::Red).is_empty());
    assert!(braille_cells(&buffer, Color::Yellow).is_empty());

    // 0.12, beyond twice the clearance: no line.
    let buffer = render_arm(&arm, Some(&snapshot), &panel_at(0.12));
    let text = lines(&buffer).join("\n");
    assert!(braille_cells(&buffer, Color::Yellow).is_empty(), "{text}");
    assert!(braille_cells(&buffer, Color::Red).is_empty(), "{text}");
    assert!(text.contains("clearance 120.0 mm  link 6, post"), "{text}");
}
