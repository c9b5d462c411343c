//! What the controller refuses, and what it warns of: [`Refused`] for a command, a pose or the
//! limits, [`SelfContact`] and [`NotClear`] for a commanded pose the arm must first get out of.
//! Each carries its numbers and displays as a sentence for a user, links and joints counted
//! from 1.

use crate::chain::Num;
use crate::reach::ReachError;

/// Why a command (or a pose, or the limits) was refused. Carries the numbers; displays as a
/// sentence for a user (joints counted from 1).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Refused {
    /// A pose with a joint outside its limits.
    #[error("joint {j}: {} rad is outside its limits [{lo}, {hi}]", Num(*.value), j = .joint + 1)]
    OutsideLimits {
        /// Joint index, from 0.
        joint: usize,
        /// The angle asked for, rad.
        value: f64,
        /// Lower limit, rad.
        lo: f64,
        /// Upper limit, rad.
        hi: f64,
    },
    /// A joint index beyond the arm.
    #[error("joint {j} does not exist: the arm has {joints} joints", j = .joint + 1)]
    NoSuchJoint {
        /// Joint index asked for, from 0.
        joint: usize,
        /// Joints in the arm.
        joints: usize,
    },
    /// A pose with the wrong number of angles.
    #[error("{got} joint angles given for an arm of {expected} joints")]
    WrongLength {
        /// Angles given.
        got: usize,
        /// Joints in the arm.
        expected: usize,
    },
    /// A number that is NaN or infinite.
    #[error("the {what} is not a finite number")]
    NotFinite {
        /// What it was.
        what: &'static str,
    },
    /// A speed that is not a positive finite number.
    #[error("speed {} m/s must be a positive, finite number", Num(*.value))]
    BadSpeed {
        /// The speed given, m/s.
        value: f64,
    },
    /// A finite number too large to mean anything for an arm.
    #[error("the {what} {} is larger in magnitude than {max}", Num(*.value))]
    TooLarge {
        /// What it was.
        what: &'static str,
        /// The value given.
        value: f64,
        /// The largest magnitude accepted.
        max: f64,
    },
    /// A pose that brings two links within [`SELF_CLEARANCE_M`](crate::chain::SELF_CLEARANCE_M) of each other: the arm would
    /// fold onto itself.
    #[error("links {la} and {lb} of that pose cross or touch", la = .a + 1, lb = .b + 1)]
    SelfCollision {
        /// The first link of the pair, from 0 (link `i` is the one joint `i` turns).
        a: usize,
        /// The second link, from 0, `b > a`.
        b: usize,
    },
    /// A path without points.
    #[error("a path needs at least one point")]
    EmptyPath,
    /// A goto or path point where the tip cannot be kept clear: inside an obstacle grown by the
    /// link radius, the clearance and what rounding the joints to whole servo ticks may take
    /// (the clearance the controller plans with).
    #[error(
        "the {what} ({x}, {y}) is {}, closer than the {grown_m:.4} m the tip keeps ({}): the \
         tip cannot be kept clear there",
        crate::world::standing(*distance_m, obstacle),
        keep_parts(*link_radius_m, *grown_m - *link_radius_m - *rounding_m, *rounding_m)
    )]
    InsideObstacle {
        /// What it was ("target", "path point").
        what: &'static str,
        /// The point, m.
        x: f64,
        /// The point, m.
        y: f64,
        /// The obstacle's id.
        obstacle: String,
        /// The point's distance from the obstacle, m (negative inside it).
        distance_m: f64,
        /// What the tip keeps: `link_radius_m + clearance_m + rounding_m`, m.
        grown_m: f64,
        /// The arm's link radius, m.
        link_radius_m: f64,
        /// The most rounding the joints to whole servo ticks moves a point, m (0 for exact).
        rounding_m: f64,
    },
    /// A joint move whose straight way in joint space passes a pose that is not clear: below
    /// the clearance to keep or, for a link not clear now, closer than it is (its floor). Names
    /// the deepest pose of the way (the least clearance of any link there) and where the way
    /// first loses clearance.
    #[error(
        "link {link} would be {}, {percent:.0}% of the way there (the way loses its clearance \
         from {from_percent:.0}% of it; {})",
        way_words(*clearance_m, obstacle),
        floor_words(*keep_m, *floor_m),
        percent = .fraction * 100.0,
        from_percent = .from_fraction * 100.0
    )]
    NotClearOnTheWay {
        /// The link at the deepest pose, 1-based from the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
        /// How far along the move the deepest pose is, 0..=1.
        fraction: f64,
        /// How far along the move the way first loses clearance, 0..=1.
        from_fraction: f64,
        /// The link's clearance at the deepest pose, m (negative inside the obstacle).
        clearance_m: f64,
        /// The clearance to keep, m.
        keep_m: f64,
        /// What this link may not come closer than: `keep_m`, or, for a link not clear since
        /// the world or the pose changed, the best clearance it has had since, m.
        floor_m: f64,
    },
    /// A joint move whose goal is clear, but not as the servos receive it: each joint rounded
    /// to a whole tick of its servo (see [`Controller::set_joint_resolution`](super::Controller::set_joint_resolution)).
    #[error(
        "link {link} of the goal, each joint rounded to a whole tick as the servos take it, \
         would come within {clearance_m:.6} m of obstacle \"{obstacle}\" (the clearance to \
         keep is {keep_m} m)"
    )]
    GoalNotClearAsSent {
        /// The link, 1-based from the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
        /// The clearance of the rounded goal, m.
        clearance_m: f64,
        /// The clearance to keep, m.
        keep_m: f64,
    },
    /// A goto or path point no route reaches: the obstacles, grown by the link radius and the
    /// clearance, close it off.
    #[error(
        "no route keeps the tip {needed_m} m clear of the obstacles: the {what} is closed off"
    )]
    NoRoute {
        /// What it was ("target", "path point").
        what: &'static str,
        /// The distance the tip's route keeps from the obstacles, m.
        needed_m: f64,
    },
    /// A `reach` that found no clear way, or whose request was not one of this arm.
    #[error("{0}")]
    Reach(#[from] ReachError),
    /// A goto or path whose routes need more work to find than a command may spend
    /// ([`MAX_ROUTE_WORK`](crate::world::MAX_ROUTE_WORK), shared by a path's legs).
    #[error(
        "finding the route to the {what} ({x}, {y}) needs more than the {limit} segment checks a \
         command may spend: give fewer path points, or obstacles of fewer polygon points"
    )]
    RouteTooLong {
        /// What it was ("target", "path point").
        what: &'static str,
        /// The point, m.
        x: f64,
        /// The point, m.
        y: f64,
        /// The work a command may spend, in checks of a segment against an edge or a circle.
        limit: u64,
    },
    /// Joint resolutions that are not finite and not negative, or not one per joint.
    #[error("joint resolutions must be one finite, non-negative angle per joint")]
    BadResolution,
    /// A limit that is not a positive finite number.
    #[error("the limit {what} = {} must be a positive, finite number", Num(*.value))]
    BadLimit {
        /// Which limit.
        what: &'static str,
        /// The value given.
        value: f64,
    },
}

/// Two links of the commanded pose in contact ([`Controller::self_contact`](super::Controller::self_contact)). Displays as a
/// warning for a user (links counted from 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SelfContact {
    /// The first link of the pair, from 0.
    pub a: usize,
    /// The second link, from 0, `b > a`.
    pub b: usize,
    /// The two cross (rather than come within [`SELF_CLEARANCE_M`](crate::chain::SELF_CLEARANCE_M) of each other).
    pub crossing: bool,
}

impl std::fmt::Display for SelfContact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "links {} and {} of the arm's pose {}: until they are clear, the arm moves only \
             where that tangles it no further (`home`, or a `goto_joints` to a clear pose, \
             untangles it)",
            self.a + 1,
            self.b + 1,
            if self.crossing { "cross" } else { "touch" }
        )
    }
}

/// The commanded pose is not clear of an obstacle ([`Controller::set_world`](super::Controller::set_world) put one onto
/// the arm): until it is, only motion that reduces no link's clearance is carried out.
#[derive(Debug, Clone, PartialEq)]
pub struct NotClear {
    /// The link of least clearance, 1-based from the base.
    pub link: usize,
    /// The obstacle's id.
    pub obstacle: String,
    /// The link's clearance, m (negative: inside, by that depth).
    pub clearance_m: f64,
    /// The clearance to keep, m.
    pub keep_m: f64,
    /// The commanded pose is clear, its goal as sent (rounded to whole servo ticks) is not:
    /// `link` and `clearance_m` are the goal's.
    pub as_sent: bool,
}

impl std::fmt::Display for NotClear {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let whose = if self.as_sent {
            " (in the goal as sent, rounded to whole servo ticks)"
        } else {
            ""
        };
        write!(
            f,
            "link {}{whose} is {} (the clearance to keep is {} m): the arm holds, and moves only \
             where no link's clearance shrinks",
            self.link,
            crate::world::standing(self.clearance_m, &self.obstacle),
            self.keep_m
        )
    }
}

/// The rule a joint move's way broke, in words: the clearance to keep, or a link's floor below
/// it (a link not clear may only get clearer). A floor short of the clearance by less than the
/// six decimals it is shown with (a link that came out onto the clearance, short of it by a
/// solver's round-off) is not told apart: "not clear, at 0.005000 m" beside "0.005 m to keep"
/// would read as a contradiction.
pub(super) fn floor_words(keep_m: f64, floor_m: f64) -> String {
    if floor_m < keep_m - 5e-7 {
        format!(
            "the clearance to keep is {keep_m} m; the link is not clear, at {floor_m:.6} m at \
             best since the obstacle or the pose changed, and may not come closer until it is"
        )
    } else {
        format!("the clearance to keep is {keep_m} m")
    }
}

/// Where a joint move's way takes a link against obstacle `id`, from its clearance there (m,
/// negative inside): "within 0.004975 m of obstacle \"post\"" to the micrometre (a way that
/// only grazes the clearance reads so), "on the edge of ...", or "inside ..., 0.0363 m deep".
fn way_words(clearance_m: f64, id: &str) -> String {
    if clearance_m >= crate::world::ON_EDGE_M {
        format!("within {clearance_m:.6} m of obstacle {id:?}")
    } else {
        crate::world::standing(clearance_m, id)
    }
}

/// What the tip keeps from an obstacle, in words: the link radius, the clearance, and what
/// rounding may take when it may take anything.
fn keep_parts(link_radius_m: f64, clearance_m: f64, rounding_m: f64) -> String {
    let mut s = format!("link radius {link_radius_m} m, clearance {clearance_m:.4} m");
    if rounding_m > 0.0 {
        s += &format!(
            ", and {rounding_m:.4} m that rounding the joints to whole servo ticks may take"
        );
    }
    s
}
