//! Work a command needs done before it starts, more than a control tick can spare: a `goto`'s
//! or a `path`'s routes for the tip round the obstacles, and a `reach`'s way in joint space.
//! Pure; the daemon runs [`plan()`] beside its loop and hands the answer back to
//! [`Controller::start_planned`](super::Controller::start_planned).

use crate::chain::{Chain, Vec2};
use crate::reach::{ReachOptions, ReachRequest, Way};
use crate::world::{RouteEnd, RouteError, World, MAX_ROUTE_WORK};

use super::Refused;

/// How [`Controller::command_within`](super::Controller::command_within) took a command.
#[derive(Debug, Clone, PartialEq)]
pub enum Accepted {
    /// In force from the next tick.
    Now,
    /// A `goto` or `path` among obstacles whose routes need more work than was given, or a
    /// `reach`: nothing changed; plan it with [`plan()`] and start it with
    /// [`Controller::start_planned`](super::Controller::start_planned).
    Plan(PlanRequest),
}

/// Work a command needs done before it starts, more than a control tick can spare.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanRequest {
    /// A `goto`'s or a `path`'s routes for the tip.
    Routes(RouteRequest),
    /// A `reach`'s way in joint space.
    Reach(Box<ReachJob>),
}

impl PlanRequest {
    /// Where the command goes: a `goto`'s target or a `path`'s last point, a `reach`'s target.
    pub fn target(&self) -> Option<Vec2> {
        match self {
            PlanRequest::Routes(r) => r.points.last().copied(),
            PlanRequest::Reach(job) => Some(job.target),
        }
    }
}

/// What a `reach` asks for: a way from the pose the arm holds to the best clear pose with the
/// tip on `target` ([`crate::reach::plan`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ReachJob {
    /// The arm.
    pub chain: Chain,
    /// The world in force (not the one raised for rounding: the planner checks the rounded
    /// goals itself).
    pub world: World,
    /// The commanded pose at rest, rad.
    pub from: Vec<f64>,
    /// Where the tip should end, m.
    pub target: Vec2,
    /// Each joint's resolution, rad (empty: exact).
    pub quanta: Vec<f64>,
}

/// A [`PlanRequest`] done.
#[derive(Debug, Clone, PartialEq)]
pub enum Planned {
    /// The tip's routes.
    Routes(PlannedRoute),
    /// The joint-space legs.
    Way(Way),
}

/// Does the work of `request` (the routes with at most `route_work`, see [`plan_route`]).
pub fn plan(request: &PlanRequest, route_work: u64) -> Result<Planned, Refused> {
    match request {
        PlanRequest::Routes(r) => plan_route(r, route_work).map(Planned::Routes),
        PlanRequest::Reach(job) => {
            let req = ReachRequest {
                chain: &job.chain,
                world: &job.world,
                from: &job.from,
                target: job.target,
                quanta: &job.quanta,
            };
            Ok(Planned::Way(crate::reach::plan(
                &req,
                &ReachOptions::default(),
            )?))
        }
    }
}

/// The routes a `goto` or `path` asks for: from `from` through `points` in turn, in `world`
/// (the world the controller plans in, its clearance raised for the joints' resolution).
#[derive(Debug, Clone, PartialEq)]
pub struct RouteRequest {
    /// Where the tip was, m.
    pub from: Vec2,
    /// The way the body trails from the tip there: the direction from the tip to the last
    /// joint (zero: none). The first leg prefers to round its first obstacle on that side
    /// ([`World::route_trailed`]).
    pub trailing: Vec2,
    /// The command's points (a `goto`'s one target), m.
    pub points: Vec<Vec2>,
    /// What they are, for messages ("target", "path point").
    pub what: &'static str,
    /// The command's speed, m/s.
    pub speed: f64,
    /// The world planned in.
    pub world: World,
    /// What rounding the joints to whole servo ticks may take, m: the part of the planned
    /// world's clearance that is not the world's own (for messages).
    pub rounding_m: f64,
}

/// Planned routes: the tip's way from the request's `from` through its points, and whether it
/// comes to rest at each waypoint (at the command's points, not at the corners between them).
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedRoute {
    pub(super) way: Vec<Vec2>,
    pub(super) rest: Vec<bool>,
}

impl PlannedRoute {
    /// The waypoints, the first the request's `from`.
    pub fn waypoints(&self) -> &[Vec2] {
        &self.way
    }
}

/// Why [`Controller::start_planned`](super::Controller::start_planned) did not start what was planned.
#[derive(Debug, Clone, PartialEq)]
pub enum NotStarted {
    /// The plan no longer fits where the arm is or the world it was made in: plan again
    /// ([`Controller::replan_request`](super::Controller::replan_request)).
    Replan,
    /// Its first leg is refused as a joint move would be.
    Refused(Refused),
}

/// A route planned for a tip or a world that is no longer the controller's: plan again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the route was planned from another tip or in another world")]
pub struct Replan;

/// The routes of `request` with at most `work` (checks of a segment against an edge or a
/// circle; a `path`'s legs share it): each leg the shortest that keeps the tip clear
/// ([`World::route`]), at rest at each point; the first round its first obstacle on the side
/// the body trails when that is at most a little longer ([`World::route_trailed`]). Pure: the
/// daemon runs it beside its loop for a command whose routes take longer than a tick can
/// spare.
///
/// A point inside a grown obstacle is refused; so is one closed off. From a start already
/// too near an obstacle (a world changed under the tip) the first leg is the straight line,
/// which the clearance check in each tick still guards; its point is refused all the same
/// when the tip can never be clear there. Over `work`: [`Refused::RouteTooLong`], naming
/// [`MAX_ROUTE_WORK`], the most a command may spend.
pub fn plan_route(request: &RouteRequest, work: u64) -> Result<PlannedRoute, Refused> {
    let what = request.what;
    let mut way = vec![request.from];
    let mut rest = vec![true];
    let mut from = request.from;
    let mut left = work;
    let mut trailing = request.trailing;
    for &p in &request.points {
        // Only the first leg knows how the body lies when it sets out.
        let leg = request.world.route_trailed(from, p, trailing, &mut left);
        trailing = Vec2::zeros();
        match leg {
            Ok(r) => {
                let n = r.waypoints.len();
                for (k, w) in r.waypoints.into_iter().enumerate().skip(1) {
                    way.push(w);
                    rest.push(k + 1 == n);
                }
            }
            Err(RouteError::Inside {
                end: RouteEnd::Start,
                ..
            }) => {
                way.push(p);
                rest.push(true);
            }
            Err(RouteError::Inside {
                end: RouteEnd::Goal,
                id,
                needed_m,
                distance_m,
                ..
            }) => {
                return Err(Refused::InsideObstacle {
                    what,
                    x: p.x,
                    y: p.y,
                    obstacle: id,
                    distance_m,
                    grown_m: needed_m,
                    link_radius_m: request.world.link_radius_m(),
                    rounding_m: request.rounding_m,
                })
            }
            Err(RouteError::NoRoute { needed_m }) => {
                return Err(Refused::NoRoute { what, needed_m })
            }
            // The leg was given what the legs before it left: name the command's whole.
            Err(RouteError::TooMuchWork { .. }) => {
                return Err(Refused::RouteTooLong {
                    what,
                    x: p.x,
                    y: p.y,
                    limit: MAX_ROUTE_WORK,
                })
            }
            Err(_) => return Err(Refused::NotFinite { what }),
        }
        from = p;
    }
    Ok(PlannedRoute { way, rest })
}
