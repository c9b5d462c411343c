//! `snakectl world`: the obstacles the arm keeps clear of. Without a subcommand it prints the
//! daemon's world (a table, or with `--json` the `world` reply as one JSON object); `set FILE`
//! replaces every obstacle with a file's, `add ID --circle X Y R | --polygon X Y X Y X Y ...`
//! adds one, `remove ID` removes one, `clear` removes them all.
//!
//! A file is JSON in the socket's shape (`{"obstacles": [...]}`, what `world --json` prints)
//! or TOML in the config's (`[[world.obstacle]]` tables with `circle = { center_m, radius_m }`
//! or `polygon = { points_m }`), told apart by its extension (`.json`, `.toml`) or, failing
//! that, by whether it opens with `{`. In TOML, tables other than `[world]` are ignored, so a
//! daemon's whole config file may be given; in either, `link_radius_m` and `clearance_m` are
//! checked but not sent (the daemon keeps its own; a note says so when they differ). The
//! obstacles are checked here first as the daemon would (exit code 2, naming the file and the
//! field), then sent. Exit codes as the other clients': 0 done, 2 bad input, 1 refused.

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::{Args, Subcommand};
use serde::Deserialize;
use serde_json::Value;
use snakectl::chain::Vec2;
use snakectl::client::{Client, ClientError, WorldInfo};
use snakectl::config::{world_field, world_problem};
use snakectl::protocol::{
    parse_obstacles, strict_json, world_rejection, Cmd, Code, Reply, Wire, WorldChanged,
};
use snakectl::textfile::{read_text, MAX_TEXT_BYTES};
use snakectl::world::{CheckedObstacle, Obstacle, Obstacles, Shape, World};
use unicode_width::UnicodeWidthStr;

use super::client::{connect, refused, ConnectArgs};
use super::{outln, Failure};

/// `world`. (`--json` is refused beside a subcommand in [`run`], not by clap's
/// `args_conflicts_with_subcommands`, which would refuse the global connection options too.)
#[derive(Debug, Args)]
pub struct WorldArgs {
    #[command(subcommand)]
    pub action: Option<Action>,
    /// Print the `world` reply as one JSON object (what `world set` reads back).
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub connect: WorldConnectArgs,
}

/// [`ConnectArgs`] taken before or after the subcommand (`world --connect H:P clear` and `world
/// clear --connect H:P` alike): global to `world`'s subcommands rather than flattened into each.
#[derive(Debug, Args)]
pub struct WorldConnectArgs {
    /// The daemon's address, `host:port`.
    #[arg(long, value_name = "ADDR", default_value = snakectl::client::DEFAULT_ADDR, global = true)]
    pub connect: String,
    /// A file whose first line is the daemon's token (`[server] token_file`).
    #[arg(long, value_name = "FILE", global = true)]
    pub token_file: Option<PathBuf>,
}

impl WorldConnectArgs {
    fn args(&self) -> ConnectArgs {
        ConnectArgs {
            connect: self.connect.clone(),
            token_file: self.token_file.clone(),
        }
    }
}

/// What to do with the world.
#[derive(Debug, Subcommand)]
pub enum Action {
    /// Replace every obstacle with those of FILE (JSON in the socket's shape, or TOML in the
    /// config's).
    Set(SetArgs),
    /// Add one obstacle: a circle or a polygon.
    Add(AddArgs),
    /// Remove the obstacle ID.
    Remove(RemoveArgs),
    /// Remove every obstacle.
    Clear(ClearArgs),
}

impl Action {
    /// The subcommand's name.
    fn name(&self) -> &'static str {
        match self {
            Action::Set(_) => "set",
            Action::Add(_) => "add",
            Action::Remove(_) => "remove",
            Action::Clear(_) => "clear",
        }
    }
}

/// `world set FILE`.
#[derive(Debug, Args)]
pub struct SetArgs {
    /// `.json` (`{"obstacles": [...]}`) or `.toml` (`[[world.obstacle]]` tables).
    pub file: PathBuf,
}

/// `world add ID --circle X Y R` or `--polygon X Y X Y X Y ...`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct AddArgs {
    /// The obstacle's id.
    pub id: String,
    /// A circle: centre x, y and radius, m.
    #[arg(long, num_args = 3, value_names = ["X", "Y", "R"], conflicts_with = "polygon", required_unless_present = "polygon")]
    pub circle: Option<Vec<f64>>,
    /// A polygon: its corners' x and y in turn, m (at least three corners).
    #[arg(long, num_args = 6.., value_name = "X Y")]
    pub polygon: Option<Vec<f64>>,
}

/// `world remove ID`.
#[derive(Debug, Args)]
pub struct RemoveArgs {
    /// The obstacle's id.
    pub id: String,
}

/// `world clear`.
#[derive(Debug, Args)]
pub struct ClearArgs {}

/// `snakectl world`.
pub fn run(args: WorldArgs) -> Result<(), Failure> {
    let connect = args.connect.args();
    if let (true, Some(action)) = (args.json, &args.action) {
        return Err(Failure::bad_input(anyhow!(
            "--json goes with `snakectl world` alone (it prints the world), not with `world {}`",
            action.name()
        )));
    }
    match args.action {
        None => show(&connect, args.json),
        Some(Action::Set(a)) => set(a, &connect),
        Some(Action::Add(a)) => add(a, &connect),
        Some(Action::Remove(a)) => {
            let cmd = Cmd::RemoveObstacle { id: a.id.clone() };
            send(&connect, &cmd, &format!("removed obstacle {:?}", a.id))
        }
        Some(Action::Clear(ClearArgs {})) => {
            let cmd = Cmd::SetWorld {
                obstacles: Obstacles::default(),
            };
            send(&connect, &cmd, "cleared every obstacle")
        }
    }
}

/// Prints the daemon's world.
fn show(connect_args: &ConnectArgs, json: bool) -> Result<(), Failure> {
    let mut client = connect(connect_args)?;
    let world = client.world().map_err(refused)?;
    if json {
        let value = serde_json::to_value(&world)
            .map_err(|e| Failure::other(anyhow!("writing the world as JSON: {e}")))?;
        return outln!("{value}");
    }
    for line in table(&world) {
        outln!("{line}")?;
    }
    Ok(())
}

/// The world as a table for a person: a heading line, then one line per obstacle.
fn table(world: &WorldInfo) -> Vec<String> {
    let n = world.obstacles.len();
    let mut lines = vec![format!(
        "link radius {} m, clearance {} m, {n} obstacle{}",
        world.link_radius_m,
        world.clearance_m,
        if n == 1 { "" } else { "s" }
    )];
    if n == 0 {
        return lines;
    }
    // Ids are padded by the columns they take on a terminal, not by their chars: a CJK
    // character or an emoji takes two, a combining mark none.
    let width = world
        .obstacles
        .iter()
        .map(|o| o.id.width())
        .max()
        .unwrap_or(0)
        .max(2);
    lines.push(format!(
        "{}  {:<7}  where (m)",
        padded("id", width),
        "shape"
    ));
    for o in &world.obstacles {
        let (shape, at) = match &o.shape {
            Shape::Circle { center, radius_m } => (
                "circle",
                format!(
                    "center ({:.4}, {:.4}), radius {radius_m:.4}",
                    center.x, center.y
                ),
            ),
            Shape::Polygon { points } => {
                let corners: Vec<String> = points
                    .iter()
                    .map(|p| format!("({:.4}, {:.4})", p.x, p.y))
                    .collect();
                (
                    "polygon",
                    format!("{} points: {}", points.len(), corners.join(" ")),
                )
            }
        };
        lines.push(format!("{}  {shape:<7}  {at}", padded(&o.id, width)));
    }
    lines
}

/// `text` followed by spaces up to `columns` columns on a terminal.
fn padded(text: &str, columns: usize) -> String {
    let pad = columns.saturating_sub(text.width());
    format!("{text}{:pad$}", "")
}

/// `world set FILE`.
fn set(args: SetArgs, connect_args: &ConnectArgs) -> Result<(), Failure> {
    let file = &args.file;
    let text = read_text(file, MAX_TEXT_BYTES)
        .map_err(|e| Failure::bad_input(anyhow!("{}: cannot read it: {e}", file.display())))?;
    let read = read_file(file, &text)
        .map_err(|e| Failure::bad_input(anyhow!("{}: {e}", file.display())))?;
    let mut client = connect(connect_args)?;
    note_fixed(&mut client, file, &read)?;
    let n = read.obstacles.len();
    let cmd = Cmd::SetWorld {
        obstacles: read.obstacles,
    };
    // What only the daemon can check (an obstacle on its arm's base) is refused there; the
    // refusal names the file, and the field as the file spells it.
    let toml = !is_json(file, &text);
    let fields = client.request(&cmd).map_err(|e| match e {
        ClientError::Refused { rejection, .. } if rejection.code == Code::BadArg => {
            let why = if toml {
                in_toml_terms(&rejection.message)
            } else {
                rejection.message
            };
            Failure::other(anyhow!(
                "{}: `set_world` refused: bad_arg: {why}",
                file.display()
            ))
        }
        e => refused(e),
    })?;
    outln!(
        "ok: set_world with {n} obstacle{} at tick {}",
        if n == 1 { "" } else { "s" },
        fields.reply.tick().unwrap_or(0)
    )
}

/// A note on stderr when the file's link radius or clearance differ from the daemon's, which
/// stay.
fn note_fixed(client: &mut Client, file: &Path, read: &FileWorld) -> Result<(), Failure> {
    if read.link_radius_m.is_none() && read.clearance_m.is_none() {
        return Ok(());
    }
    let daemon = client.world().map_err(refused)?;
    for (name, given, kept) in [
        ("link_radius_m", read.link_radius_m, daemon.link_radius_m),
        ("clearance_m", read.clearance_m, daemon.clearance_m),
    ] {
        if let Some(given) = given.filter(|&g| g != kept) {
            eprintln!(
                "snakectl: note: {}: {name} = {given} is not sent: the daemon keeps its own, {kept}",
                file.display()
            );
        }
    }
    Ok(())
}

/// `world add`.
fn add(args: AddArgs, connect_args: &ConnectArgs) -> Result<(), Failure> {
    let shape = match (&args.circle, &args.polygon) {
        (Some(c), _) => Shape::Circle {
            center: Vec2::new(c[0], c[1]),
            radius_m: c[2],
        },
        (None, Some(p)) => {
            if p.len() % 2 != 0 {
                return Err(Failure::bad_input(anyhow!(
                    "--polygon takes x and y of each corner in turn: {} numbers is not pairs",
                    p.len()
                )));
            }
            Shape::Polygon {
                points: p.chunks_exact(2).map(|q| Vec2::new(q[0], q[1])).collect(),
            }
        }
        (None, None) => {
            return Err(Failure::bad_input(anyhow!(
                "give the shape: --circle X Y R or --polygon X Y X Y X Y ..."
            )))
        }
    };
    let obstacle = CheckedObstacle::new(Obstacle { id: args.id, shape })
        .map_err(|e| Failure::bad_input(anyhow!("{}", world_rejection(&e, None).message)))?;
    let done = format!(
        "added obstacle {}",
        serde_json::to_string(&Wire(&obstacle)).unwrap_or_default()
    );
    send(connect_args, &Cmd::AddObstacle { obstacle }, &done)
}

/// Sends `cmd`, prints `ok: DONE at tick N`; a note on stderr when the new world leaves the
/// arm's pose not clear (the change stands: the arm holds).
fn send(connect_args: &ConnectArgs, cmd: &Cmd, done: &str) -> Result<(), Failure> {
    let mut client = connect(connect_args)?;
    let fields = client.request(cmd).map_err(refused)?;
    outln!("ok: {done} at tick {}", fields.reply.tick().unwrap_or(0))?;
    if let Reply::WorldChanged(WorldChanged {
        not_clear: Some(nc),
        ..
    }) = &fields.reply
    {
        eprintln!(
            "snakectl: note: the arm is not clear of the new world: link {} is {} (the \
             clearance to keep is {} m); it holds, and moves only where no link's clearance \
             shrinks",
            nc.link,
            snakectl::world::standing(nc.clearance_m, &nc.obstacle),
            nc.keep_m
        );
    }
    Ok(())
}

/// What a file says: the obstacles, and the link radius and clearance when it gives them.
#[derive(Debug, PartialEq)]
struct FileWorld {
    obstacles: Obstacles,
    link_radius_m: Option<f64>,
    clearance_m: Option<f64>,
}

/// Reads a world file, JSON or TOML (by the extension, else by a leading `{`), its obstacles
/// checked as the daemon checks them. The error names the field.
fn read_file(path: &Path, text: &str) -> Result<FileWorld, String> {
    if is_json(path, text) {
        read_json(text)
    } else {
        read_toml(text)
    }
}

/// Whether a world file is JSON: by its extension, else by a leading `{`.
fn is_json(path: &Path, text: &str) -> bool {
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("json") => true,
        Some(e) if e.eq_ignore_ascii_case("toml") => false,
        _ => text.trim_start().starts_with('{'),
    }
}

/// `{"obstacles": [...], "link_radius_m"?: r, "clearance_m"?: c}`, the obstacles in the
/// socket's shape.
fn read_json(text: &str) -> Result<FileWorld, String> {
    // An object with the same key twice is refused, as the daemon refuses such a line: a file
    // that says two things is read as neither.
    let value: Value = strict_json(text.as_bytes()).map_err(|e| {
        if e.is_data() {
            e.to_string()
        } else {
            format!("not JSON: {e}")
        }
    })?;
    let Value::Object(map) = value else {
        return Err(r#"expected a JSON object {"obstacles": [...]}"#.into());
    };
    if let Some(key) = map
        .keys()
        .find(|k| !matches!(k.as_str(), "obstacles" | "link_radius_m" | "clearance_m"))
    {
        return Err(format!(
            "`{key}`: unknown key (a world file has obstacles, link_radius_m, clearance_m)"
        ));
    }
    let number = |key: &str| -> Result<Option<f64>, String> {
        match map.get(key) {
            None | Some(Value::Null) => Ok(None),
            Some(v) => v
                .as_f64()
                .map(Some)
                .ok_or_else(|| format!("`{key}`: expected a number of metres, got {v}")),
        }
    };
    let (link_radius_m, clearance_m) = (number("link_radius_m")?, number("clearance_m")?);
    let list = map
        .get("obstacles")
        .ok_or("`obstacles`: missing (an empty world is `{\"obstacles\": []}`)")?;
    let obstacles = parse_obstacles(list).map_err(|r| r.message)?;
    // The radius and clearance are not sent, but a file that gives bad ones is a bad file.
    let (r, c) = (link_radius_m.unwrap_or(0.0), clearance_m.unwrap_or(0.0));
    let world = World::new(r, c, obstacles).map_err(|e| world_rejection(&e, None).message)?;
    Ok(FileWorld {
        obstacles: world.checked_obstacles().clone(),
        link_radius_m,
        clearance_m,
    })
}

/// A TOML file in the config's shape: only `[world]` is read.
#[derive(Debug, Deserialize)]
struct TomlFile {
    world: Option<TomlWorld>,
}

/// `[world]`: the obstacles; the other keys the config takes are accepted, not sent.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlWorld {
    #[serde(default)]
    obstacle: Vec<TomlObstacle>,
    link_radius_m: Option<f64>,
    clearance_m: Option<f64>,
    #[allow(dead_code)]
    contact_load: Option<toml::Value>,
    #[allow(dead_code)]
    contact_ms: Option<toml::Value>,
}

/// `[[world.obstacle]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlObstacle {
    id: String,
    circle: Option<TomlCircle>,
    polygon: Option<TomlPolygon>,
}

/// `circle = { center_m = [x, y], radius_m = r }`, read as the config reads it: a point is
/// exactly two numbers.
type TomlCircle = snakectl::config::raw::RawCircle;

/// `polygon = { points_m = [[x, y], ...] }`, read as the config reads it.
type TomlPolygon = snakectl::config::raw::RawPolygon;

/// `[[world.obstacle]]` tables, as the config writes them.
fn read_toml(text: &str) -> Result<FileWorld, String> {
    let file: TomlFile = toml::from_str(text).map_err(|e| {
        let (line, column, message) = snakectl::config::toml_where(text, &e);
        format!("not a world: line {line}, column {column}: {message}")
    })?;
    let world = file
        .world
        .ok_or("no [world] table: obstacles are [[world.obstacle]] tables")?;
    let mut obstacles = Vec::with_capacity(world.obstacle.len());
    for (i, o) in world.obstacle.into_iter().enumerate() {
        let at = format!("world.obstacle[{}]", i + 1);
        let shape = match (o.circle, o.polygon) {
            (Some(c), None) => Shape::Circle {
                center: Vec2::new(c.center_m[0], c.center_m[1]),
                radius_m: c.radius_m,
            },
            (None, Some(p)) => Shape::Polygon {
                points: p.points_m.iter().map(|q| Vec2::new(q[0], q[1])).collect(),
            },
            (Some(_), Some(_)) => return Err(format!("{at}: give circle or polygon, not both")),
            (None, None) => return Err(format!("{at}: missing its shape: circle or polygon")),
        };
        obstacles.push(Obstacle { id: o.id, shape });
    }
    let (r, c) = (world.link_radius_m, world.clearance_m);
    let checked = World::new(r.unwrap_or(0.0), c.unwrap_or(0.0), obstacles).map_err(|e| {
        let (field, problem) = world_problem(e);
        format!("{field}: {problem}")
    })?;
    Ok(FileWorld {
        obstacles: checked.checked_obstacles().clone(),
        link_radius_m: world.link_radius_m,
        clearance_m: world.clearance_m,
    })
}

/// The daemon's refusal of a TOML file's world with the field as the file spells it: the
/// socket's `` `obstacles[0].circle.radius` `` is `world.obstacle[1].circle.radius_m`.
fn in_toml_terms(message: &str) -> String {
    let Some((field, rest)) = message
        .strip_prefix('`')
        .and_then(|m| m.split_once("`: "))
        .filter(|(f, _)| f.starts_with("obstacles"))
    else {
        return message.to_owned();
    };
    let field = field
        .replace(".circle.radius", ".circle.radius_m")
        .replace(".circle.center[0]", ".circle.center.x")
        .replace(".circle.center[1]", ".circle.center.y");
    format!("{}: {rest}", world_field(&field))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn toml_of(body: &str) -> Result<FileWorld, String> {
        read_file(Path::new("w.toml"), body)
    }

    #[test]
    fn a_toml_world_reads_as_the_config_writes_it() {
        let read = toml_of(
            r#"
            [bus]
            port = "/dev/null"

            [world]
            link_radius_m = 0.012
            contact_ms = 100

            [[world.obstacle]]
            id = "post"
            circle = { center_m = [0.15, 0.60], radius_m = 0.04 }

            [[world.obstacle]]
            id = "shelf"
            polygon = { points_m = [[-0.6, 0.3], [-0.4, 0.3], [-0.4, 0.34], [-0.6, 0.34]] }
            "#,
        )
        .unwrap();
        assert_eq!(read.link_radius_m, Some(0.012));
        assert_eq!(read.clearance_m, None);
        assert_eq!(read.obstacles.len(), 2);
        assert_eq!(
            read.obstacles[0],
            Obstacle {
                id: "post".into(),
                shape: Shape::Circle {
                    center: Vec2::new(0.15, 0.60),
                    radius_m: 0.04
                }
            }
        );
        match &read.obstacles[1].shape {
            Shape::Polygon { points } => assert_eq!(points[2], Vec2::new(-0.4, 0.34)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_bad_toml_world_names_the_field_as_the_config_spells_it() {
        let e = toml_of(
            "[[world.obstacle]]\nid = \"a\"\ncircle = { center_m = [0, 0], radius_m = 0.1 }\n\
             [[world.obstacle]]\nid = \"b\"\ncircle = { center_m = [1, 0], radius_m = -0.1 }\n",
        )
        .unwrap_err();
        assert!(e.starts_with("world.obstacle[2].circle.radius_m: "), "{e}");
        let e =
            toml_of("[[world.obstacle]]\nid = \"a\"\npolygon = { points_m = [[0, 0], [1, 0]] }\n")
                .unwrap_err();
        assert!(e.starts_with("world.obstacle[1].polygon.points_m: "), "{e}");
        let e =
            toml_of("[[world.obstacle]]\nid = \"a\"\ncircle = { center = [0, 0], radius_m = 1 }\n")
                .unwrap_err();
        assert!(e.contains("unknown field `center`"), "{e}");
        let e = toml_of("[[world.obstacles]]\nid = \"a\"\n").unwrap_err();
        assert!(e.contains("unknown field `obstacles`"), "{e}");
        let e = toml_of("[bus]\nport = \"x\"\n").unwrap_err();
        assert!(e.contains("no [world] table"), "{e}");
        let e = toml_of("[[world.obstacle]]\nid = \"a\"\n").unwrap_err();
        assert!(e.starts_with("world.obstacle[1]: missing its shape"), "{e}");
        // Not TOML at all: where, on one line.
        let e = toml_of("[world]\nclearance_m = abc\n").unwrap_err();
        assert!(e.starts_with("not a world: line 2, column 15: "), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }

    #[test]
    fn a_toml_world_names_a_bad_field_as_loading_the_config_does() {
        // The shipped world with its post's radius, then the post's centre x, then the shelf's
        // fourth point made bad: `snakectl run` and `snakectl world set` on the same file must
        // name the same field.
        let shipped = include_str!("../../config/world.toml");
        for (from, to) in [
            ("radius_m = 0.04 }", "radius_m = -0.04 }"),
            ("center_m = [0.15, 0.60]", "center_m = [inf, 0.60]"),
            ("[-0.6, 0.34]]", "[-0.6, 0.3]]"),
            ("id = \"shelf\"", "id = \"post\""),
        ] {
            assert!(shipped.contains(from), "{from}");
            let text = shipped.replacen(from, to, 1);
            let loaded = snakectl::config::Config::from_str(&text, "w.toml")
                .unwrap_err()
                .to_string();
            let said = loaded
                .strip_prefix("w.toml: ")
                .unwrap_or_else(|| panic!("{loaded}"));
            // The same field and the same words (obstacles and edges counted from 1).
            assert_eq!(toml_of(&text).unwrap_err(), said);
        }
        let e = toml_of(
            "[[world.obstacle]]\nid = \"a\"\ncircle = { center_m = [0, 0], radius_m = 0.1 }\n\
             [[world.obstacle]]\nid = \"b\"\n",
        )
        .unwrap_err();
        assert!(e.starts_with("world.obstacle[2]: missing its shape"), "{e}");
    }

    #[test]
    fn a_point_of_three_numbers_is_refused_as_the_config_refuses_it_not_cut() {
        let shipped = include_str!("../../config/world.toml");
        for (from, to) in [
            ("center_m = [0.15, 0.60]", "center_m = [0.15, 0.60, 99.0]"),
            ("[-0.6, 0.34]]", "[-0.6, 0.34, 1.0]]"),
            ("center_m = [0.15, 0.60]", "center_m = [0.15]"),
        ] {
            assert!(shipped.contains(from), "{from}");
            let text = shipped.replacen(from, to, 1);
            let e = toml_of(&text).unwrap_err();
            assert!(e.contains("expected a point [x, y] in metres"), "{e}");
            let loaded = snakectl::config::Config::from_str(&text, "w.toml")
                .unwrap_err()
                .to_string();
            // The same words as loading the config, after where it is.
            let (_, said) = e.split_once(": ").unwrap();
            let (_, said) = said.split_once(": ").unwrap();
            assert!(loaded.ends_with(said), "{loaded} / {e}");
        }
    }

    #[test]
    fn a_json_world_reads_in_the_sockets_shape_and_names_the_field() {
        let read = read_file(
            Path::new("w"),
            r#"{"link_radius_m": 0.01, "clearance_m": 0.005, "obstacles": [
                {"id": "post", "circle": {"center": [0.15, 0.6], "radius": 0.04}}]}"#,
        )
        .unwrap();
        assert_eq!(read.obstacles[0].id, "post");
        assert_eq!(read.clearance_m, Some(0.005));
        let bad = |body: &str| read_file(Path::new("w.json"), body).unwrap_err();
        let e = bad(r#"{"obstacles": [{"id": "p", "circle": {"center": [0, 0], "radius": 0}}]}"#);
        assert!(e.starts_with("`obstacles[0].circle.radius`: "), "{e}");
        let e = bad(r#"{"obstacles": [{"id": "p", "circle": {"center": [0, 0]}}]}"#);
        assert!(
            e.starts_with("`obstacles[0].circle.radius`: missing"),
            "{e}"
        );
        // A key twice is refused, as the daemon refuses it, not read as the last.
        let e = bad(
            r#"{"obstacles": [{"id": "x", "circle": {"center": [1, 1], "radius": 1}, "id": "y"}]}"#,
        );
        assert!(e.starts_with("duplicate key \"id\""), "{e}");
        let e = bad(
            r#"{"obstacles": [{"id": "x", "circle": {"center": [1, 1], "radius": 1, "radius": 2}}]}"#,
        );
        assert!(e.starts_with("duplicate key \"radius\""), "{e}");
        let e = bad(r#"{"obstacle": []}"#);
        assert!(e.starts_with("`obstacle`: unknown key"), "{e}");
        let e = bad(r#"{}"#);
        assert!(e.starts_with("`obstacles`: missing"), "{e}");
        // Not sent, but checked: a bad one is a bad file.
        let e = bad(r#"{"clearance_m": -1, "obstacles": []}"#);
        assert_eq!(e, "`clearance_m`: -1 m must not be negative");
        let e = toml_of("[world]\nlink_radius_m = nan\n").unwrap_err();
        assert!(
            e.starts_with("world.link_radius_m: NaN must be finite"),
            "{e}"
        );
    }

    #[test]
    fn the_daemons_refusal_of_a_toml_file_names_the_field_as_the_file_does() {
        for (said, meant) in [
            (
                "`obstacles[0]`: obstacle \"post\" touches the base",
                "world.obstacle[1]: obstacle \"post\" touches the base",
            ),
            (
                "`obstacles[2].circle.radius`: 0 m must be positive",
                "world.obstacle[3].circle.radius_m: 0 m must be positive",
            ),
            (
                "`obstacles[1].circle.center[1]`: NaN must be finite",
                "world.obstacle[2].circle.center_m[2]: NaN must be finite",
            ),
            ("not in control", "not in control"),
        ] {
            assert_eq!(in_toml_terms(said), meant);
        }
    }

    #[test]
    fn the_table_names_every_obstacle_and_its_shape() {
        let world = WorldInfo {
            link_radius_m: 0.012,
            clearance_m: 0.005,
            obstacles: vec![
                Obstacle {
                    id: "post".into(),
                    shape: Shape::Circle {
                        center: Vec2::new(0.15, 0.6),
                        radius_m: 0.04,
                    },
                },
                Obstacle {
                    id: "tri".into(),
                    shape: Shape::Polygon {
                        points: vec![
                            Vec2::new(0.0, 0.0),
                            Vec2::new(1.0, 0.0),
                            Vec2::new(0.0, 1.0),
                        ],
                    },
                },
            ],
        };
        let lines = table(&world);
        assert_eq!(
            lines[0],
            "link radius 0.012 m, clearance 0.005 m, 2 obstacles"
        );
        assert!(lines[2].starts_with("post  circle "), "{}", lines[2]);
        assert!(lines[2].contains("center (0.1500, 0.6000), radius 0.0400"));
        assert!(lines[3].contains("3 points: (0.0000, 0.0000) (1.0000, 0.0000) (0.0000, 1.0000)"));
    }

    #[test]
    fn the_table_lines_up_ids_of_wide_characters_and_combining_marks() {
        let circle = |id: &str| Obstacle {
            id: id.into(),
            shape: Shape::Circle {
                center: Vec2::new(0.15, 0.6),
                radius_m: 0.04,
            },
        };
        let world = WorldInfo {
            link_radius_m: 0.012,
            clearance_m: 0.005,
            // Two columns for 柱 and for 🚧, none for the combining acute accent.
            obstacles: ["post", "柱", "🚧 post", "e\u{301}"]
                .into_iter()
                .map(circle)
                .collect(),
        };
        let lines = table(&world);
        // "🚧 post" is the widest id: 7 columns, then two spaces.
        let (shape_at, where_at) = (9, 9 + 7 + 2);
        for line in &lines[1..] {
            let (shape, place) = if line.starts_with("id ") {
                ("shape", "where (m)")
            } else {
                ("circle", "center (")
            };
            let columns = |word: &str| line[..line.find(word).unwrap()].width();
            assert_eq!(columns(shape), shape_at, "{line:?}");
            assert_eq!(columns(place), where_at, "{line:?}");
        }
        assert_eq!(lines.len(), 2 + 4);
    }
}
