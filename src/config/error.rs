//! Why a config file was refused: always the file, then the line or the field, then the value.

use std::path::PathBuf;

use crate::chain::{ChainError, Num, MAX_MAGNITUDE};

/// A config file that could not be read, parsed or accepted.
///
/// Displays as `FILE: FIELD: PROBLEM` (for example
/// `config/arm.toml: joint[3].link_m: -0.1 must be finite and positive, at most 1000000`) or, for
/// TOML syntax and type errors, `FILE:LINE:COLUMN: MESSAGE`. Joints are counted from 1, base to
/// tip, as everywhere in snakectl: `joint[1]` is the first `[[joint]]` table.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why: what the operating system said, or not a regular file, or larger than
        /// [`crate::textfile::MAX_TEXT_BYTES`].
        source: crate::textfile::TextFileError,
    },
    /// Not valid TOML, or a key or value of the wrong shape (unknown key, missing key, wrong
    /// type, unknown enumeration value).
    #[error("{}:{line}:{column}: {message}", path.display())]
    Syntax {
        /// The file.
        path: PathBuf,
        /// 1-based line of the offending text (0 when the parser gave no position).
        line: usize,
        /// 1-based column, in characters.
        column: usize,
        /// The parser's message, which names the key where it applies, after the field's path
        /// where the error concerns one (`sim.fault[2].fraction: invalid type: ...`).
        message: String,
    },
    /// Well-formed, but a value is not acceptable.
    #[error("{}: {field}: {problem}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted path of the field, e.g. `joint[3].link_m` or `arm.home_rad[2]`.
        field: String,
        /// What is wrong, with the value.
        problem: FieldProblem,
    },
    /// The chain model refused the geometry (a check the config module missed).
    #[error("{}: {source}", path.display())]
    Chain {
        /// The file.
        path: PathBuf,
        /// The chain's reason.
        source: ChainError,
    },
}

/// What is wrong with one field. Each variant carries the offending value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FieldProblem {
    /// No `[[joint]]` table at all.
    #[error("no [[joint]] tables: an arm needs at least one joint")]
    NoJoints,
    /// A length or rate that must be finite and positive.
    #[error("{} must be finite and positive, at most {MAX_MAGNITUDE}", Num(*.value))]
    NotPositive {
        /// The value given.
        value: f64,
    },
    /// A value that must be finite and not negative.
    #[error("{} must be finite and not negative, at most {MAX_MAGNITUDE}", Num(*.value))]
    Negative {
        /// The value given.
        value: f64,
    },
    /// A coordinate or angle that must be finite and of sane magnitude.
    #[error("{} must be finite and at most {MAX_MAGNITUDE} in magnitude", Num(*.value))]
    NotFinite {
        /// The value given.
        value: f64,
    },
    /// A joint's limits are not an interval.
    #[error("limits [{min_rad}, {max_rad}] rad must be finite with min_rad < max_rad")]
    EmptyRange {
        /// Lower limit given, rad.
        min_rad: f64,
        /// Upper limit given, rad.
        max_rad: f64,
    },
    /// A joint limit the servo cannot reach: beyond its one turn, with the joint's
    /// `offset_ticks` and `reverse`.
    #[error(
        "{value} rad is servo position {ticks:.1} ticks (offset_ticks and reverse included), \
         beyond the servo's one turn 0..=4095"
    )]
    BeyondTurn {
        /// The limit, rad.
        value: f64,
        /// Where it falls, ticks.
        ticks: f64,
    },
    /// Limits so close that no whole servo tick lies between them.
    #[error(
        "limits [{min_rad}, {max_rad}] rad hold no whole servo tick (a tick is 0.0015 rad): \
         widen them"
    )]
    NoWholeTick {
        /// Lower limit, rad.
        min_rad: f64,
        /// Upper limit, rad.
        max_rad: f64,
    },
    /// A list with the wrong number of entries.
    #[error("{got} entries for {expected} joints: give one per [[joint]]")]
    Count {
        /// Entries given.
        got: usize,
        /// Entries expected.
        expected: usize,
    },
    /// A home angle outside its joint's limits.
    #[error("{} rad lies outside joint {joint}'s limits [{min_rad}, {max_rad}]", Num(*.value))]
    OutsideLimits {
        /// 1-based joint.
        joint: usize,
        /// The angle, rad.
        value: f64,
        /// Lower limit, rad.
        min_rad: f64,
        /// Upper limit, rad.
        max_rad: f64,
    },
    /// No home pose given, and zero is outside a joint's limits.
    #[error(
        "absent, so joint {joint} would start at 0 rad, outside its limits [{min_rad}, {max_rad}]: \
         give a home_rad inside the limits"
    )]
    ZeroOutsideLimits {
        /// 1-based joint.
        joint: usize,
        /// Lower limit, rad.
        min_rad: f64,
        /// Upper limit, rad.
        max_rad: f64,
    },
    /// A servo id outside 1..=252.
    #[error("{value} must be a servo id in 1..=252")]
    BadId {
        /// The id given.
        value: i64,
    },
    /// A table key that should be a servo id and is not a number.
    #[error("\"{key}\" is not a servo id: each key is one, e.g. `3 = 44`")]
    NotAnId {
        /// The key given.
        key: String,
    },
    /// Two joints with one servo id.
    #[error("{id} is already the id of joint[{other}]")]
    DuplicateId {
        /// The id.
        id: u8,
        /// 1-based joint that has it first.
        other: usize,
    },
    /// A servo id listed on two ports, or twice on one.
    #[error("{id} is already on bus.ports[{other}]")]
    IdOnTwoPorts {
        /// The id.
        id: u8,
        /// 1-based port that lists it first.
        other: usize,
    },
    /// A joint's servo on none of the `[[bus.ports]]`.
    #[error("{id} is on none of the [[bus.ports]]: list it in the ids of the port it is wired to")]
    IdOnNoPort {
        /// The id.
        id: u8,
    },
    /// `[bus] ports = []`: a list of no ports.
    #[error(
        "an empty list: give at least one [[bus.ports]] table, or leave `ports` out for one \
         port of every joint's servo"
    )]
    NoPorts,
    /// A `[[bus.ports]]` without servos.
    #[error("no servo ids: a port carries at least one servo")]
    EmptyPort,
    /// Two `[[bus.ports]]` naming one serial device.
    #[error("{path:?} is already the port of bus.ports[{other}]")]
    DuplicatePort {
        /// The path.
        path: String,
        /// 1-based port that names it first.
        other: usize,
    },
    /// A servo id that no joint has.
    #[error("{id} is not the id of any [[joint]]")]
    UnknownId {
        /// The id.
        id: u8,
    },
    /// A servo model this program does not know.
    #[error("\"{value}\" is not a known model ({known})")]
    UnknownModel {
        /// The name given.
        value: String,
        /// The known ones.
        known: String,
    },
    /// A key that must be present for the rest of the file to make sense.
    #[error("missing: {why}")]
    Missing {
        /// Why it is needed.
        why: &'static str,
    },
    /// An integer outside its allowed set.
    #[error("{value} {expected}")]
    OutOfRange {
        /// The value given.
        value: i64,
        /// What is allowed, phrased to follow the value (e.g. "must be even, at most 508").
        expected: &'static str,
    },
    /// A number outside a closed interval.
    #[error("{} must lie in [{lo}, {hi}]", Num(*.value))]
    Outside {
        /// The value given.
        value: f64,
        /// Lower bound.
        lo: f64,
        /// Upper bound.
        hi: f64,
    },
    /// A time window that ends before it starts.
    #[error("{until_s} s must be later than at_s = {at_s} s")]
    EndsBeforeStart {
        /// Start, s.
        at_s: f64,
        /// End, s.
        until_s: f64,
    },
    /// A listen address that is not `host:port`.
    #[error("\"{value}\" is not an address such as 127.0.0.1:7878 ({reason})")]
    BadAddress {
        /// The text given.
        value: String,
        /// The parser's reason.
        reason: String,
    },
    /// A Zenoh endpoint that is not `tcp/` + `host:port`.
    #[error("\"{value}\" is not a Zenoh endpoint such as tcp/127.0.0.1:7447 ({reason})")]
    BadEndpoint {
        /// The text given.
        value: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A Zenoh endpoint listed twice in one list.
    #[error("\"{value}\" is already zenoh.{list}[{other}]")]
    DuplicateEndpoint {
        /// The endpoint.
        value: String,
        /// The list: `listen` or `connect`.
        list: &'static str,
        /// 1-based entry that has it first.
        other: usize,
    },
    /// A key prefix that is not a plain Zenoh key expression.
    #[error("{value:?} is not a key prefix such as snakectl or lab/arm_1 ({reason})")]
    BadPrefix {
        /// The text given.
        value: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A rate above the control loop's, which has nothing new to give that often.
    #[error(
        "{value} Hz must be positive and at most control.rate_hz = {rate_hz} Hz: the loop has \
         nothing new to publish faster than it runs"
    )]
    AboveLoopRate {
        /// The rate given, Hz.
        value: f64,
        /// The loop's rate, Hz.
        rate_hz: f64,
    },
    /// A Bus Watchdog that does not cover two ticks of the loop, which renews it once a tick
    /// (its goals' Sync Write), at any point of the tick.
    #[error(
        "{watchdog_ms} ms{} does not cover two ticks of control.rate_hz = {} Hz \
         ({two_ticks_ms:.1} ms): the loop renews the servos' Bus Watchdog once a tick, and a late write \
         would let it fire and stop the servos every tick; give at least {min_ms} ms (a \
         multiple of 20, at most 2540), 0 (off), or a faster rate_hz",
        if *.given { "" } else { " (the default)" },
        Num(*.rate_hz)
    )]
    WatchdogShort {
        /// `bus.watchdog_ms`.
        watchdog_ms: u32,
        /// Whether the file gives it (else it is the default).
        given: bool,
        /// `control.rate_hz`.
        rate_hz: f64,
        /// Two periods of the loop, ms.
        two_ticks_ms: f64,
        /// The least watchdog that covers them, a multiple of 20 ms.
        min_ms: u32,
    },
    /// A silence budget no longer than the time between two reads: one missed reply would
    /// declare the servo silent.
    #[error(
        "{max_silence_ms} ms{} is not longer than the time between two reads, \
         control.read_every = {read_every} tick(s) at control.rate_hz = {} Hz \
         ({interval_ms:.1} ms): a single missed reply would declare a servo silent and fault \
         the arm; give a max_silence_ms above that, or read more often",
        if *.given { "" } else { " (the default)" },
        Num(*.rate_hz)
    )]
    SilenceWithinRead {
        /// `control.max_silence_ms`.
        max_silence_ms: u128,
        /// Whether the file gives it (else it is the default).
        given: bool,
        /// `control.read_every`.
        read_every: u32,
        /// `control.rate_hz`.
        rate_hz: f64,
        /// Time between two reads, ms.
        interval_ms: f64,
    },
    /// A profile speed or acceleration the servo's register cannot hold: below one of its
    /// units (it would be written as one) or beyond its largest.
    #[error(
        "{} {unit} must be 0 (no profile) or lie in [{lo}, {hi}] {unit}: the register holds \
         1 to 32767 of the servo's units of {step} {unit}, and a value beyond them would be \
         changed, not written",
        Num(*.value)
    )]
    ProfileOutside {
        /// The value given.
        value: f64,
        /// The least accepted (one unit, rounded up to the digits shown).
        lo: f64,
        /// The largest accepted (rounded down to the digits shown).
        hi: f64,
        /// One register unit.
        step: f64,
        /// "rad/s" or "rad/s²".
        unit: &'static str,
    },
    /// A `[[sim.fault]]` key its kind does not take.
    #[error("not a key of a kind = \"{kind}\" fault, which takes {takes}")]
    NotOfKind {
        /// The fault's kind.
        kind: &'static str,
        /// The keys it takes.
        takes: String,
    },
    /// A `[[sim.fault]]` key its kind needs, absent.
    #[error("missing: a kind = \"{kind}\" fault needs it (it takes {takes})")]
    KindNeeds {
        /// The fault's kind.
        kind: &'static str,
        /// The keys it takes.
        takes: String,
    },
    /// A servo id key spelt other than in plain digits (`03`, `+3`, ` 3 `): two spellings
    /// could name one servo twice.
    #[error("\"{key}\" is servo id {id} spelt otherwise: write it {id}")]
    NonCanonicalId {
        /// The key given.
        key: String,
        /// The id it reads as.
        id: u8,
    },
    /// A contact threshold that is not above 0, or above what the servo's load can read.
    #[error(
        "{} {unit} must be above 0 and at most {} {unit}: the |load| above which joint {joint} \
         is in contact, in the unit its servo reports (percent of the maximum torque for a \
         Present Load, amperes for a Present Current)",
        Num(*.value),
        Num(*.hi)
    )]
    ContactLoad {
        /// The value given.
        value: f64,
        /// 1-based joint.
        joint: usize,
        /// "%" or "A".
        unit: &'static str,
        /// The largest accepted.
        hi: f64,
    },
    /// A file name given empty.
    #[error("an empty file name: name the file, or leave the key out")]
    EmptyFileName,
    /// A key this version no longer reads.
    #[error("removed: {why}; delete the line")]
    Removed {
        /// Why, and what holds instead.
        why: &'static str,
    },
    /// Two keys that say the same thing, given together.
    #[error("given together with {other}, which it replaces: keep only {other}")]
    Replaced {
        /// The key that replaces this one.
        other: &'static str,
    },
    /// Commands taken from a network other hosts can reach, with no access control.
    #[error(
        "true, but {exposure}: any host that reaches the arm could move it; configure Zenoh's \
         access control in a Zenoh config file named by config_file, or keep every endpoint on \
         loopback with multicast = false"
    )]
    CommandsExposed {
        /// What opens the session to other hosts (an endpoint, or multicast scouting).
        exposure: String,
    },
    /// A Foxglove address other hosts can reach, and no token to ask its clients for.
    #[error(
        "{addr} is not a loopback address, and [server] token_file is not set: any host that \
         reaches it could watch (and with accept_commands move) the arm; set token_file (clients \
         then open ws://HOST:{port}/?token=...), listen on 127.0.0.1, or reach it through an SSH \
         tunnel (ssh -L {port}:127.0.0.1:{port} HOST)",
        port = addr.port()
    )]
    NotLoopback {
        /// The address given.
        addr: std::net::SocketAddr,
    },
    /// An obstacle with both shapes or neither.
    #[error("give exactly one of circle and polygon ({given})")]
    OneShape {
        /// What was given: "both" or "neither".
        given: &'static str,
    },
    /// A port's path given empty.
    #[error("an empty path: name the serial device, e.g. /dev/ttyUSB0")]
    EmptyPath,
    /// An obstacle with an empty id.
    #[error("an obstacle needs a non-empty id")]
    EmptyId,
    /// An obstacle id too long, or with a control character.
    #[error("{why}")]
    BadObstacleId {
        /// What is wrong with it.
        why: String,
    },
    /// Two obstacles with one id.
    #[error("{id:?} is already the id of world.obstacle[{other}]")]
    DuplicateObstacle {
        /// The id.
        id: String,
        /// 1-based obstacle that has it first.
        other: usize,
    },
    /// A polygon with fewer than 3 points.
    #[error("{count} points: a polygon needs at least 3")]
    TooFewPoints {
        /// Points given.
        count: usize,
    },
    /// A polygon point given twice.
    #[error("({x}, {y}) repeats points_m[{first}]")]
    RepeatedPoint {
        /// x, m.
        x: f64,
        /// y, m.
        y: f64,
        /// 1-based point that is the same.
        first: usize,
    },
    /// A polygon whose edges touch or cross. Edge `k` runs from `points_m[k]` to the next
    /// point (from the last back to the first for the closing edge).
    #[error(
        "edges {edge_a} and {edge_b} touch or cross near ({x}, {y}): a polygon must not \
         intersect itself (edge k runs from points_m[k] to the next point)"
    )]
    SelfIntersecting {
        /// 1-based first edge.
        edge_a: usize,
        /// 1-based second edge.
        edge_b: usize,
        /// Where, x m.
        x: f64,
        /// Where, y m.
        y: f64,
    },
    /// A polygon whose area computes to zero: its points too close together to tell which
    /// way it turns.
    #[error(
        "the polygon's area is zero as computed: its points are too close together to tell its \
         inside from its outside"
    )]
    ZeroArea,
    /// More joints than an arm among obstacles may have.
    #[error(
        "{count} joints with [world] obstacles, at most {max}: keeping clear of obstacles takes \
         memory growing as the square of the joints (without obstacles, any number)"
    )]
    TooManyJointsAmongObstacles {
        /// The joints given.
        count: usize,
        /// The limit, [`crate::resolve::overall::MAX_LINKS_AMONG_OBSTACLES`].
        max: usize,
    },
    /// More of something than the world may hold.
    #[error("{count} {what}, at most {max} allowed")]
    TooMany {
        /// What is counted.
        what: &'static str,
        /// How many were given.
        count: usize,
        /// The limit.
        max: usize,
    },
    /// An obstacle within reach of the base, where link 1 starts whatever the pose.
    #[error(
        "obstacle {id:?} {}, where link 1 starts, closer than link_radius_m + clearance_m = \
         {keep_m} m: no pose of the arm is clear of it",
        crate::world::over_point(*distance_m, "the base point")
    )]
    TouchesBase {
        /// The obstacle's id.
        id: String,
        /// Signed distance from the base point to the obstacle, m (negative: inside).
        distance_m: f64,
        /// `link_radius_m + clearance_m`, m.
        keep_m: f64,
    },
    /// The home pose folds the arm onto itself: two links cross or come within
    /// [`SELF_CLEARANCE_M`](crate::chain::SELF_CLEARANCE_M) of each other.
    #[error(
        "links {a} and {b} of the home pose cross or come within {} m of each other: the \
         controller never sends such a pose, so the arm could not start or go home; unfold it",
        crate::chain::SELF_CLEARANCE_M
    )]
    HomeSelfCollision {
        /// The first link of the pair, from 1.
        a: usize,
        /// The second link, from 1, `b > a`.
        b: usize,
    },
    /// The home pose is not clear of an obstacle, as given or rounded to the servos' ticks.
    #[error(
        "link {link} of the home pose (arm.home_rad){} is {}, short of clearance_m = {keep_m} \
         m: move the obstacle or the home pose",
        if *.rounded { ", each joint rounded to a whole tick as the servos take it," } else { "" },
        crate::world::standing(*clearance_m, id)
    )]
    HomeNotClear {
        /// The obstacle's id.
        id: String,
        /// 1-based link of least clearance.
        link: usize,
        /// The link's clearance, m (negative: inside the obstacle, by that depth).
        clearance_m: f64,
        /// `clearance_m`, m.
        keep_m: f64,
        /// The pose rounded to whole ticks is the one not clear (the pose as given is).
        rounded: bool,
    },
}
