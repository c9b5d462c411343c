//! Commands as the loop applies them, at the start of a tick in arrival order: each checked
//! against the supervisor's mode, handed to the controller, entered in the ledger, and answered
//! once this tick's telemetry is out (a `reboot`, or a command planned beside the loop, when
//! that work ends).

use std::time::Duration;

use tokio::sync::oneshot;

use crate::chain::Vec2;
use crate::control::{self, Accepted, Activity, NotStarted, PlanRequest, Refused};
use crate::protocol::{
    world_rejection, Answer, Applied, ClientId, CmdName, Code, LoopCmd, Motion, PoseNotClear,
    Rebooted, Rejection, Reply, RequestId, Status, StopReason, TorqueOff, Unconfirmed, What,
    WorldChanged, WorldInfo,
};
use crate::reach::ReachError;
use crate::servo::arm::{self, BringUpOptions, OnExit};
use crate::servo::clock::Clock;
use crate::servo::ServoBus;
use crate::world::Obstacles;

use super::ledger::Renewal;
use super::link::{Envelope, COMMAND_QUEUE, STOP_QUEUE};
use super::planner::{tick_route_work, Polled, MAX_REPLANS};
use super::supervisor::Blocked;
use super::{Cycle, Pending};

fn refuse(code: Code, message: impl Into<String>) -> Pending {
    Pending::Ready(Err(Rejection {
        code,
        message: message.into(),
    }))
}

fn applied(tick: u64) -> Pending {
    Pending::Ready(Ok(Reply::Applied(Applied { tick }).into()))
}

/// A command the controller refused: `unreachable` where no pose, route or way gets there,
/// else `bad_arg`.
fn refusal(r: Refused) -> Pending {
    match r {
        Refused::Reach(ReachError::BadInput(_)) => refuse(Code::BadArg, r.to_string()),
        Refused::OutsideLimits { .. }
        | Refused::Reach(_)
        | Refused::SelfCollision { .. }
        | Refused::InsideObstacle { .. }
        | Refused::NotClearOnTheWay { .. }
        | Refused::GoalNotClearAsSent { .. }
        | Refused::NoRoute { .. } => refuse(Code::Unreachable, r.to_string()),
        r => refuse(Code::BadArg, r.to_string()),
    }
}

impl<B: ServoBus, C: Clock> Cycle<B, C> {
    /// The commands queued since the last tick, applied in the order their lines arrived;
    /// their answers wait for this tick's telemetry. Every `stop` and `estop` queued is taken,
    /// so none waits behind other commands: each is applied after the commands whose lines came
    /// before it, which it therefore overrides.
    pub(super) fn apply_commands(&mut self) {
        let mut stops = std::mem::take(&mut self.stops);
        // Bounded per tick by the queues' capacities: a flood waits for the next tick.
        while stops.len() < STOP_QUEUE {
            match self.ends.stops.try_recv() {
                Ok(envelope) => stops.push_back(envelope),
                Err(_) => break,
            }
        }
        for _ in 0..COMMAND_QUEUE {
            let Ok(envelope) = self.ends.commands.try_recv() else {
                break;
            };
            while stops
                .front()
                .is_some_and(|s| s.received <= envelope.received)
            {
                if let Some(stop) = stops.pop_front() {
                    self.take(stop);
                }
            }
            self.take(envelope);
        }
        while let Some(stop) = stops.pop_front() {
            self.take(stop);
        }
        self.stops = stops;
    }

    /// One command applied; its answer waits for this tick's telemetry, or for the reboot or
    /// the planning it began (its sender told so).
    fn take(&mut self, envelope: Envelope) {
        let pending = self.apply(&envelope);
        self.received.push(envelope.received);
        let kept = match (pending, self.rebooting.as_mut(), self.planning.as_mut()) {
            // Answered when its servos are back (`tend_reboot`).
            (Pending::Rebooting, Some(job), _) => &mut job.reply,
            // Answered when its routes are planned (`tend_planning`).
            (Pending::Planning, _, Some(job)) => &mut job.reply,
            (pending, _, _) => return self.pending.push((envelope.reply, pending)),
        };
        *kept = Some(envelope.reply);
        if let Some(later) = envelope.later {
            // A sender gone is not an error.
            let _ = later.send(());
        }
    }

    /// The answer of a command the loop kept for later (a reboot, a planning), sent now:
    /// before the events about it that this tick sends, so that its sender, whose connection
    /// writes the answer as it comes, reads them in that order.
    fn answer_kept(&mut self, reply: oneshot::Sender<Answer>, answer: Pending) {
        match answer {
            // A client gone is not an error.
            Pending::Ready(answer) => {
                let _ = reply.send(answer);
            }
            other => self.pending.push((reply, other)),
        }
    }

    /// Sends the answers of the commands applied in this tick.
    pub(super) fn answer(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let mut status: Option<Answer> = None;
        for (reply, pending) in self.pending.drain(..) {
            let answer = match pending {
                Pending::Ready(a) => a,
                Pending::Status => status
                    .get_or_insert_with(|| {
                        let t = self.ends.telemetry.borrow().clone();
                        Ok(Reply::Status(Box::new(Status::of(t))).into())
                    })
                    .clone(),
                // `take` keeps these with their reboot or route; none reaches here.
                Pending::Rebooting => Err(Rejection {
                    code: Code::Fault,
                    message: "the reboot is no longer under way".into(),
                }),
                Pending::Planning => Err(Rejection {
                    code: Code::Fault,
                    message: "the route is no longer being planned".into(),
                }),
            };
            // A client gone before its answer is not an error.
            let _ = reply.send(answer);
        }
    }

    /// Commands still queued when the loop ends are answered, not dropped silently.
    pub(super) fn answer_queued_for_exit(&mut self) {
        self.ends.commands.close();
        self.ends.stops.close();
        let stops = std::iter::from_fn(|| self.ends.stops.try_recv().ok());
        let queued: Vec<Envelope> = stops
            .chain(std::iter::from_fn(|| self.ends.commands.try_recv().ok()))
            .collect();
        for e in queued {
            let _ = e.reply.send(Err(Rejection {
                code: Code::ShuttingDown,
                message: "the daemon is stopping".into(),
            }));
        }
        self.answer();
    }

    fn ok(&self) -> Pending {
        applied(self.tick)
    }

    fn apply(&mut self, e: &Envelope) -> Pending {
        let stops = matches!(
            e.cmd,
            LoopCmd::Status | LoopCmd::Stop | LoopCmd::Estop | LoopCmd::World
        );
        if self.supervisor.exiting() && !stops {
            return refuse(Code::ShuttingDown, "the daemon is stopping");
        }
        if let Some(job) = &self.rebooting {
            let waits = matches!(
                e.cmd,
                LoopCmd::Reset
                    | LoopCmd::Torque { .. }
                    | LoopCmd::Reboot { .. }
                    | LoopCmd::Motion(_)
            );
            if waits {
                return refuse(
                    Code::Busy,
                    format!(
                        "servos {:?} are rebooting: send again once the reboot has answered",
                        job.reboots.ids()
                    ),
                );
            }
        }
        match &e.cmd {
            LoopCmd::Status => Pending::Status,
            LoopCmd::Stop => self.stop(e),
            LoopCmd::Estop => self.estop(e),
            LoopCmd::Reset => self.reset(e),
            LoopCmd::Strategy { name } => {
                self.controller.set_strategy(*name);
                tracing::info!(strategy = name.name(), "strategy switched");
                self.ok()
            }
            LoopCmd::ResetStats => {
                self.stats.reset(self.clock.now(), self.tick);
                self.ok()
            }
            LoopCmd::Torque { on } => self.torque(*on),
            LoopCmd::Reboot { ids } => self.reboot(ids.as_deref()),
            LoopCmd::World => Pending::Ready(Ok(Reply::World(Box::new(WorldInfo::of(
                self.controller.world(),
            )))
            .into())),
            LoopCmd::SetWorld { obstacles } => self.change_world(e, obstacles.clone(), None),
            LoopCmd::AddObstacle { obstacle } => {
                let now = self.controller.world().checked_obstacles();
                let added = now.len();
                match now.with(obstacle) {
                    Ok(obstacles) => self.change_world(e, obstacles, Some(added)),
                    Err(err) => Pending::Ready(Err(world_rejection(&err, Some(added)))),
                }
            }
            LoopCmd::RemoveObstacle { id } => {
                let world = self.controller.world();
                let Some((k, _)) = world.find(id) else {
                    return refuse(
                        Code::BadArg,
                        format!(
                            "`obstacle`: no obstacle has the id {id:?} (the obstacles: {})",
                            crate::protocol::world_ids(world)
                        ),
                    );
                };
                let obstacles = world.checked_obstacles().without(k);
                self.change_world(e, obstacles, None)
            }
            LoopCmd::Motion(Motion::Velocity { .. }) if self.stale(e) => refuse(
                Code::Stale,
                format!(
                    "this `velocity` waited {:.0} ms for the loop, longer than the deadman ({} ms): \
                     not applied; send a fresh one",
                    self.waited(e).as_secs_f64() * 1e3,
                    self.schedule.deadman.as_millis()
                ),
            ),
            LoopCmd::Motion(motion) => match self.motion(motion) {
                Some(command) => self.move_arm(e, command),
                None => refuse(Code::BadArg, "`joint` counts from 1"),
            },
        }
    }

    /// How long `e` waited between its line's arrival and now.
    fn waited(&self, e: &Envelope) -> std::time::Duration {
        self.clock.now().saturating_duration_since(e.received)
    }

    /// Whether `e` waited longer than the deadman: a renewal that old would move the arm on a
    /// wish the deadman has already given up on.
    fn stale(&self, e: &Envelope) -> bool {
        self.waited(e) > self.schedule.deadman
    }

    /// The controller's command for a motion (`None`: a jog of joint 0, which the parser
    /// refuses before it gets here).
    fn motion(&self, cmd: &Motion) -> Option<control::Command> {
        Some(match cmd {
            Motion::Goto { target, speed } => control::Command::Goto {
                target: v2(target),
                speed: *speed,
            },
            Motion::GotoJoints { theta } => control::Command::GotoJoints {
                theta: theta.clone(),
            },
            Motion::Reach { target } => control::Command::Reach { target: v2(target) },
            Motion::Path { points, speed } => control::Command::Path {
                points: points.iter().map(v2).collect(),
                speed: *speed,
            },
            Motion::Velocity { v } => control::Command::Velocity { v: v2(v) },
            Motion::Jog { joint, rad_s } => control::Command::Jog {
                joint: joint.checked_sub(1)?,
                rad_s: *rad_s,
            },
            Motion::Home => control::Command::GotoJoints {
                theta: self.home.clone(),
            },
        })
    }

    /// `stop`: decelerate to rest and hold (nothing to do under the estop latch or a fault,
    /// which hold the arm already: the recovery holds the measured pose).
    fn stop(&mut self, e: &Envelope) -> Pending {
        if self.supervisor.moves() {
            if let Err(r) = self.controller.command(control::Command::Stop) {
                return refuse(Code::BadArg, r.to_string());
            }
            self.begin(e);
        }
        self.ok()
    }

    /// A command that moves the arm: refused while the supervisor holds it, else handed to the
    /// controller and entered in the ledger.
    fn move_arm(&mut self, e: &Envelope, command: control::Command) -> Pending {
        if let Some(blocked) = self.supervisor.blocked() {
            return self.blocked(blocked, "send `reset` before moving");
        }
        match self
            .controller
            .command_within(command, tick_route_work(self.schedule.period))
        {
            Ok(Accepted::Now) => {
                self.begin(e);
                self.ok()
            }
            Ok(Accepted::Plan(request)) => self.plan_beside(e, request),
            Err(r) => refusal(r),
        }
    }

    /// `set_world`, `add_obstacle`, `remove_obstacle`: `obstacles` with the link radius and
    /// the clearance in force, validated as a world (refused `bad_arg` naming the field; for
    /// `add_obstacle`, `added` is the new one's index), in force from the next tick. Every
    /// client is told the new world, and whether the commanded pose is clear of it.
    fn change_world(
        &mut self,
        e: &Envelope,
        obstacles: Obstacles,
        added: Option<usize>,
    ) -> Pending {
        // Checked where the request was read: only the base is left to ask about.
        let world = self.controller.world().with_obstacles(obstacles);
        // As at start-up: link 1 starts at the base whatever the pose, so no pose could keep
        // clear of an obstacle that close.
        let keep_m = world.link_radius_m() + world.clearance_m();
        let base = self.controller.chain().base();
        if let Some((distance_m, k)) = world.point_distance(base) {
            if distance_m < keep_m {
                let field = match added {
                    Some(a) if a == k => "obstacle".to_owned(),
                    _ => format!("obstacles[{k}]"),
                };
                return refuse(
                    Code::BadArg,
                    format!(
                        "`{field}`: obstacle {:?} {}, where link 1 starts, closer than \
                         link_radius_m + clearance_m = {keep_m:.4} m: no pose keeps clear of it",
                        world.obstacles()[k].id,
                        crate::world::over_point(distance_m, "the base point"),
                    ),
                );
            }
        }
        let info = Box::new(WorldInfo::of(&world));
        let not_clear = self.controller.set_world(world);
        if not_clear.is_some() {
            // The controller brings a moving arm to rest and holds it.
            self.ledger.stopping(StopReason::NotClear);
        }
        self.decided.min_clearance_m = self.controller.min_clearance();
        tracing::info!(
            client = e.client,
            obstacles = self.controller.world().obstacles().len(),
            min_clearance_m = ?self.decided.min_clearance_m,
            "the world changed"
        );
        let by = e.client;
        self.event(None, e.id.clone(), |_| What::World { by, world: info });
        let told = not_clear.as_ref().map(|nc| PoseNotClear {
            link: nc.link,
            obstacle: nc.obstacle.clone(),
            clearance_m: nc.clearance_m,
            keep_m: nc.keep_m,
        });
        self.look_clear_after(e.id.clone(), not_clear);
        Pending::Ready(Ok(Reply::WorldChanged(WorldChanged {
            tick: self.tick,
            not_clear: told,
        })
        .into()))
    }

    /// A command accepted by the controller becomes the active one (a velocity, or the same
    /// joint's jog, from the same client renews it).
    fn begin(&mut self, e: &Envelope) {
        // One whose routes are still being planned was taken before it, and is preempted.
        self.settle_planning(e.cmd.name());
        let renewal = match e.cmd {
            LoopCmd::Motion(Motion::Velocity { .. }) => Renewal::Velocity,
            LoopCmd::Motion(Motion::Jog { joint, .. }) => Renewal::Jog(joint),
            _ => Renewal::None,
        };
        let ended = self
            .ledger
            .begin(e.client, e.id.clone(), e.cmd.name(), renewal);
        self.owe(ended);
    }

    /// `estop`: goals frozen, the latch set, torque off where `[bus] on_exit` says so: one Sync
    /// Write, confirmed within this tick by the servos that answer (the silent ones are not
    /// waited on). The reply names the servos whose torque off was not confirmed.
    fn estop(&mut self, e: &Envelope) -> Pending {
        self.settle_planning(CmdName::Estop);
        let torque_off = self.on_exit == OnExit::TorqueOff;
        if self.supervisor.estopped() {
            // A latch that kept torque on (a contact's) is no estop's: torque off all the same.
            // Servos not yet confirmed off are asked again, and the reply says how they stand.
            if torque_off && (self.supervisor.torque() || !self.torque_off_pending.is_empty()) {
                tracing::warn!("estop under the latch: torque off");
                self.supervisor.estop(true);
                let unconfirmed = self.torque_off_all("estop");
                return self.torque_off_reply(unconfirmed);
            }
            return self.torque_off_reply(Vec::new());
        }
        self.controller.freeze();
        self.ledger.estop();
        tracing::warn!("estop: goals frozen");
        self.supervisor.estop(torque_off);
        let unconfirmed = if torque_off {
            self.torque_off_all("estop")
        } else {
            Vec::new()
        };
        self.event(None, e.id.clone(), |tip| What::Estop { tip });
        self.torque_off_reply(unconfirmed)
    }

    /// The reply to `estop` and `torque`: the tick, and the servos not confirmed off.
    fn torque_off_reply(&self, unconfirmed: Vec<Unconfirmed>) -> Pending {
        Pending::Ready(Ok(Reply::TorqueOff(TorqueOff {
            tick: self.tick,
            unconfirmed,
        })
        .into()))
    }

    /// The servos among `ids`, named with their joints.
    fn name_servos(&self, ids: &[u8]) -> String {
        ids.iter()
            .map(|&id| match self.ids.iter().position(|&x| x == id) {
                Some(i) => format!("servo {id} (joint {})", i + 1),
                None => format!("servo {id}"),
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Why the measured pose cannot be read now, without asking the bus: the port is lost, or
    /// servos are held silent. (A servo that only missed a read or two is asked, within the
    /// tick.)
    fn pose_unreadable(&self) -> Option<String> {
        if self.port.is_lost() {
            return Some("the serial port is lost: the measured pose cannot be read".into());
        }
        let silent = self.health.silent();
        (!silent.is_empty()).then(|| {
            format!(
                "{} {} not answer: the measured pose cannot be read",
                self.name_servos(&silent),
                if silent.len() == 1 { "does" } else { "do" }
            )
        })
    }

    /// `reset`: out of the estop latch, holding the measured pose with torque on: tripped
    /// watchdogs cleared, goals := the measured pose, torque on (with a recovery's time, see
    /// [`Cycle::stretched`]), any `power_loss` fault cleared. Refused with `fault`, naming the
    /// servos, while the pose cannot be read or torque cannot be switched on; the latch then
    /// stays.
    fn reset(&mut self, e: &Envelope) -> Pending {
        if !self.supervisor.estopped() {
            return self.ok();
        }
        self.stretched(|cycle| cycle.reset_now(e))
    }

    fn reset_now(&mut self, e: &Envelope) -> Pending {
        if let Some(why) = self.pose_unreadable() {
            return refuse(Code::Fault, format!("reset: {why}; the latch stays"));
        }
        if let Err(err) = self.clear_watchdogs() {
            return refuse(Code::Fault, format!("reset: {err}; the latch stays"));
        }
        // Torque kept on under the latch (`on_exit = "hold"`, a contact): the servos held.
        if let Err(err) = self.measure_pose(!self.supervisor.torque()) {
            return refuse(Code::Fault, format!("reset: {err}; the latch stays"));
        }
        if let Err(r) = self.controller.reseed(&self.measured.theta) {
            return refuse(Code::Unreachable, r.to_string());
        }
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        if let Err(err) = self.arm.torque_on(self.port.bus(), &[], &within) {
            if self.supervisor.torque() {
                // A failed torque on switches every servo off, those a latch kept on too (a
                // contact's): the latch stays with torque off, confirmed as for an estop.
                self.supervisor.set_torque(false);
                self.torque_off_all("reset failed");
            }
            return refuse(
                Code::Fault,
                format!("reset: torque on failed: {err}; the latch stays"),
            );
        }
        self.port.contact(self.clock.now());
        self.supervisor.set_torque(true);
        for id in self.health.power_lost() {
            if let Some(i) = self.health.index_of(id) {
                self.clear(i, "reset: torque on, holding the measured pose".into());
            }
        }
        self.sync_faulted();
        self.supervisor.reset();
        // A reset that completes is a recovery that completes: the watchdogs it (or a
        // recovery that failed before it) re-armed are told here, not by a later recovery.
        let watchdogs = std::mem::take(&mut self.rearmed);
        if watchdogs.is_empty() {
            tracing::info!("reset: holding the measured pose");
        } else {
            tracing::info!(
                "reset: holding the measured pose; bus watchdogs cleared on {}",
                self.name_servos(&watchdogs.into_iter().collect::<Vec<_>>())
            );
        }
        self.event(None, e.id.clone(), |tip| What::Reset { tip });
        self.ok()
    }

    /// The refusal for what holds the arm; `after_estop` says how to leave the latch.
    fn blocked(&self, blocked: Blocked, after_estop: &str) -> Pending {
        match blocked {
            Blocked::Estop => refuse(
                Code::Estopped,
                format!("the estop latch is set: {after_estop}"),
            ),
            Blocked::Fault => refuse(Code::Fault, self.fault_summary()),
            Blocked::TorqueOff => refuse(
                Code::Fault,
                "torque is off: send `torque` with `on: true` before moving",
            ),
        }
    }

    /// Why the arm holds for a fault, naming every fault.
    fn fault_summary(&self) -> String {
        let list: Vec<String> = self.lists.faults.iter().map(ToString::to_string).collect();
        format!(
            "the arm holds for a fault: {}; `status` lists the faults, `reboot` clears a hardware error",
            list.join("; ")
        )
    }

    /// `torque`: on = goals := the measured pose (tripped watchdogs cleared first), then
    /// torque on; refused with `fault` while a fault holds or a servo does not answer. Off =
    /// torque off (one Sync Write, confirmed within this tick by the servos that answer; one
    /// that does not is named in the log and switched off on its recovery), the controller
    /// frozen: never refused.
    fn torque(&mut self, on: bool) -> Pending {
        if on {
            match self.supervisor.blocked() {
                Some(Blocked::TorqueOff) | None => {}
                Some(blocked) => return self.blocked(blocked, "`reset` turns torque on"),
            }
            if let Some(why) = self.pose_unreadable() {
                return refuse(Code::Fault, format!("torque on: {why}"));
            }
            let before = self.supervisor;
            self.supervisor.set_torque(true);
            if let Err(err) = self.recover(!before.torque()) {
                self.supervisor = before;
                // Torque was off: the servos a torque on that half happened reached go off
                // again, as they were.
                self.torque_off_all("torque on failed");
                return refuse(Code::Fault, format!("torque on: {err}"));
            }
            tracing::info!("torque on, holding the measured pose");
            return self.torque_off_reply(Vec::new());
        }
        let unconfirmed = self.torque_off_all("torque off");
        self.supervisor.set_torque(false);
        self.controller.freeze();
        let ended = self.ledger.interrupt(StopReason::Torque);
        self.owe(ended);
        tracing::info!("torque off");
        self.torque_off_reply(unconfirmed)
    }

    /// `reboot`: reboot `ids` (default: the servos in hardware error, else all). The REBOOTs
    /// go out now; the servos boot while the loop ticks on ([`Rebooting`]), and once all are
    /// back the arm is brought up again where it stands (settings, watchdog, goal := present,
    /// torque on), goals := that pose, every joint fault cleared, and the reboot answered.
    fn reboot(&mut self, ids: Option<&[u8]>) -> Pending {
        if self.port.is_lost() {
            return refuse(
                Code::Fault,
                "the serial port is lost: no servo can be rebooted",
            );
        }
        let targets: Vec<u8> = match ids {
            Some(ids) => {
                if let Some(id) = ids.iter().find(|id| !self.ids.contains(id)) {
                    return refuse(
                        Code::BadArg,
                        format!("`ids`: servo {id} is not on this arm (ids {:?})", self.ids),
                    );
                }
                ids.to_vec()
            }
            None => Some(self.health.hardware_faulted())
                .filter(|h| !h.is_empty())
                .unwrap_or_else(|| self.ids.clone()),
        };
        self.controller.freeze();
        let ended = self.ledger.interrupt(StopReason::Reboot);
        self.owe(ended);
        let timeout = self.schedule.reply_timeout;
        let sent = arm::Reboots::send(self.port.bus(), &targets, timeout, self.clock.now());
        let reboots = match sent {
            Ok(reboots) => reboots,
            Err(err) => {
                return refuse(Code::Fault, format!("reboot of {}: {err}", which(&targets)))
            }
        };
        let mut reading = Vec::with_capacity(self.ids.len());
        let mut joints = Vec::with_capacity(self.ids.len());
        for (i, &id) in self.ids.iter().enumerate() {
            if targets.contains(&id) {
                // Not counted silent while it boots: it is not read.
                self.health.expect_silence(i);
            } else {
                reading.push(id);
                joints.push(i);
            }
        }
        tracing::info!(?targets, "rebooting; the loop ticks on while they boot");
        self.rebooting = Some(Rebooting {
            reboots,
            reply: None,
            reading,
            joints,
            abandoned: false,
        });
        Pending::Rebooting
    }

    /// A tick of the reboot under way: its servos pinged within the fault path's time; once
    /// all are back, the arm brought up and the reboot answered; a servo that never comes back
    /// (or a lost port) ends it with the error.
    pub(super) fn tend_reboot(&mut self) {
        let Some(job) = self.rebooting.as_mut() else {
            return;
        };
        if job.abandoned {
            return;
        }
        let polled = if self.port.is_lost() {
            Err("the serial port was lost while the servos booted".to_owned())
        } else {
            // A ping of a booting servo waits about its exchange's time, not a reply timeout,
            // and ends a millisecond (the port's resolution) short of the fault path's time.
            let bus = self.port.bus();
            let wait = arm::ping_wait(bus.baud(), self.arm.settings().return_delay_us)
                .min(self.schedule.reply_timeout);
            let until = self
                .fault_until
                .checked_sub(Duration::from_millis(1))
                .unwrap_or(self.fault_until);
            let within = Self::within(&self.clock, until, wait);
            match job.reboots.poll(bus, &within) {
                Ok(false) => return,
                Ok(true) => Ok(()),
                Err(err) => Err(format!("reboot of {}: {err}", which(job.reboots.ids()))),
            }
        };
        let Some(job) = self.rebooting.take() else {
            return;
        };
        self.stats.counters.retries += u64::from(job.reboots.retries());
        let targets = job.reboots.ids().to_vec();
        match polled {
            Ok(()) => self.rebooted(targets, job.reply),
            Err(message) => {
                if let Some(reply) = job.reply {
                    self.answer_kept(reply, refuse(Code::Fault, message));
                }
            }
        }
    }

    /// The shut-down began: a reboot under way is answered `shutting_down`; its servos are
    /// left booting (and the shut-down does not wait on them).
    pub(super) fn abandon_reboot(&mut self) {
        let Some(job) = self.rebooting.as_mut() else {
            return;
        };
        job.abandoned = true;
        if let Some(reply) = job.reply.take() {
            let answer = refuse(
                Code::ShuttingDown,
                "the daemon is stopping: the reboot was not completed",
            );
            self.answer_kept(reply, answer);
        }
    }

    /// Every rebooted servo answers: the arm brought up where it stands, the reboot answered
    /// (`reply`), then the faults cleared.
    fn rebooted(&mut self, targets: Vec<u8>, reply: Option<oneshot::Sender<Answer>>) {
        // Under a latch that switched torque off, torque stays off until `reset`.
        let latched_off = self.supervisor.estopped() && !self.supervisor.torque();
        if let Err(refusal) = self.bring_up_after_reboot() {
            if let Some(reply) = reply {
                self.answer_kept(reply, refusal);
            }
            return;
        }
        let torque = if latched_off {
            // Bring-up switched it on; the latch keeps it off.
            self.torque_off_all("reboot under the estop latch");
            self.supervisor.set_torque(false);
            "torque off under the estop latch"
        } else {
            "torque on"
        };
        tracing::info!(?targets, "rebooted; holding the measured pose");
        if let Some(reply) = reply {
            let answer = Reply::Rebooted(Rebooted {
                tick: self.tick,
                rebooted: targets.clone(),
            });
            self.answer_kept(reply, Pending::Ready(Ok(answer.into())));
        }
        for i in 0..self.health.len() {
            let id = self.ids.get(i).copied().unwrap_or_default();
            let detail = if targets.contains(&id) {
                format!("rebooted; goals := measured pose, {torque}")
            } else {
                format!("answers after the reboot; goals := measured pose, {torque}")
            };
            self.clear(i, detail);
        }
        self.sync_faulted();
    }

    /// The bring-up where the arm stands after a reboot; goals := that pose, torque on.
    fn bring_up_after_reboot(&mut self) -> Result<(), Pending> {
        let brought = self
            .arm
            .bring_up_with_clock(self.port.bus(), BringUpOptions::default(), &self.clock)
            .map_err(|err| refuse(Code::Fault, format!("bring-up after the reboot: {err}")))?;
        self.stats.counters.retries += u64::from(brought.retries);
        self.port.contact(self.clock.now());
        self.measured.theta.copy_from_slice(&brought.pose);
        self.controller
            .reseed(&brought.pose)
            .map_err(|r| refuse(Code::Fault, format!("after the reboot: {r}")))?;
        self.supervisor.set_torque(true);
        self.recover_after = None;
        Ok(())
    }
}

impl<B: ServoBus, C: Clock> Cycle<B, C> {
    /// A `goto` or `path` whose routes need more than a tick can spare, or a `reach`: the
    /// command it replaces ends (`preempted`), the arm comes to rest, and its routes (or its
    /// way) are planned beside the loop from where it stands; answered once they are
    /// (`tend_planning`). With the arm at rest the request is handed to the planner first: one
    /// it cannot take is refused `busy` with nothing changed, the command under way or the one
    /// waiting for its routes going on.
    fn plan_beside(&mut self, e: &Envelope, request: PlanRequest) -> Pending {
        let mut job = Planning {
            client: e.client,
            id: e.id.clone(),
            kind: e.cmd.name(),
            reply: None,
            request,
            serial: None,
            replans: 0,
            since: self.clock.now(),
        };
        if self.controller.activity() == Activity::Holding {
            job.request = self.controller.replan_request(&job.request);
            match self.planner.send(job.request.clone()) {
                Ok(serial) => job.serial = Some(serial),
                Err(why) => return refuse(Code::Busy, format!("{why}; send again")),
            }
            // Its job is the one waited for now: the planner skips the one it replaces.
            self.preempt_planning(e.cmd.name());
        } else {
            self.settle_planning(e.cmd.name());
        }
        let ended = self.ledger.preempt(e.cmd.name());
        self.owe(ended);
        if self.controller.activity() != Activity::Holding {
            if let Err(r) = self.controller.command(control::Command::Stop) {
                return refuse(Code::BadArg, r.to_string());
            }
        }
        tracing::info!(
            client = e.client,
            cmd = e.cmd.name().as_str(),
            "planning beside the loop"
        );
        self.planning = Some(job);
        Pending::Planning
    }

    /// Hands the planning's request to the planner once the arm is at rest (its routes start
    /// where the tip stands); `busy` when the planner cannot take it.
    fn send_plan(&mut self) -> Result<(), Pending> {
        let Some(job) = self.planning.as_mut() else {
            return Ok(());
        };
        if job.serial.is_some() || self.controller.activity() != Activity::Holding {
            return Ok(());
        }
        job.request = self.controller.replan_request(&job.request);
        let serial = self
            .planner
            .send(job.request.clone())
            .map_err(|why| refuse(Code::Busy, format!("{why}; send again")))?;
        job.serial = Some(serial);
        Ok(())
    }

    /// [`Cycle::send_plan`] from a tick: a refusal ends the planning.
    fn send_plan_or_end(&mut self) {
        if let Err(refused) = self.send_plan() {
            self.end_planning(refused);
        }
    }

    /// A tick of the planning under way: its routes started once planned, as the command
    /// would have started them then; planned again when the tip or the world moved meanwhile
    /// (whether the planner found routes or not: a refusal in a world no longer in force says
    /// nothing of this one); refused as the command would have been (a fault holding the arm,
    /// a refused route).
    pub(super) fn tend_planning(&mut self) {
        let Some(job) = self.planning.as_ref() else {
            return;
        };
        if let Some(blocked) = self.supervisor.blocked() {
            let answer = self.blocked(blocked, "send `reset` before moving");
            return self.end_planning(answer);
        }
        if let Some(reboot) = &self.rebooting {
            let message = format!(
                "servos {:?} began rebooting while the routes were planned: send again once \
                 the reboot has answered",
                reboot.reboots.ids()
            );
            return self.end_planning(refuse(Code::Busy, message));
        }
        let Some(serial) = job.serial else {
            return self.send_plan_or_end();
        };
        let route = match self.planner.poll(serial) {
            Polled::Waiting => return,
            Polled::Gone => {
                let message = "the planner stopped without an answer: send again";
                return self.end_planning(refuse(Code::Busy, message));
            }
            Polled::Done(Err(r)) if self.controller.fits(&job.request) => {
                return self.end_planning(refusal(r))
            }
            Polled::Done(Err(_)) => return self.plan_again(),
            Polled::Done(Ok(route)) => route,
        };
        let Some(job) = self.planning.as_ref() else {
            return;
        };
        match self.controller.start_planned(&job.request, route) {
            Ok(()) => {
                let Some(job) = self.planning.take() else {
                    return;
                };
                let took = self.clock.now().saturating_duration_since(job.since);
                tracing::info!(
                    cmd = job.kind.as_str(),
                    ms = took.as_secs_f64() * 1e3,
                    replans = job.replans,
                    "planned beside the loop; the command begins"
                );
                if let Some(reply) = job.reply {
                    self.answer_kept(reply, applied(self.tick));
                }
                let ended = self
                    .ledger
                    .begin(job.client, job.id.clone(), job.kind, Renewal::None);
                self.owe(ended);
            }
            Err(NotStarted::Refused(r)) => self.end_planning(refusal(r)),
            Err(NotStarted::Replan) => self.plan_again(),
        }
    }

    /// The planning's request made for a tip, a pose or a world no longer in force: handed to
    /// the planner again from where the arm is, in the world in force, up to [`MAX_REPLANS`]
    /// times; then refused `busy`.
    fn plan_again(&mut self) {
        let Some(job) = self.planning.as_mut() else {
            return;
        };
        if job.replans < MAX_REPLANS {
            job.replans += 1;
            job.serial = None;
            return self.send_plan_or_end();
        }
        let message = format!(
            "the arm or the world moved each of the {} times the command was planned: send again",
            MAX_REPLANS + 1
        );
        self.end_planning(refuse(Code::Busy, message));
    }

    /// A command came that preempts the one whose routes are being planned (`by`): that one
    /// is answered as taken and ends at once, `preempted`, as it would have had it begun.
    fn settle_planning(&mut self, by: CmdName) {
        if self.planning.is_some() {
            self.planner.cancel();
        }
        self.preempt_planning(by);
    }

    /// [`Cycle::settle_planning`] where a job handed to the planner since has taken the place
    /// of the one preempted (the planner no longer waits for it).
    fn preempt_planning(&mut self, by: CmdName) {
        let Some(job) = self.planning.take() else {
            return;
        };
        if let Some(reply) = job.reply {
            self.answer_kept(reply, applied(self.tick));
        }
        let _ = self
            .ledger
            .begin(job.client, job.id.clone(), job.kind, Renewal::None);
        let ended = self.ledger.preempt(by);
        self.owe(ended);
    }

    /// The planning ends without its command: answered `answer`.
    fn end_planning(&mut self, answer: Pending) {
        self.planner.cancel();
        if let Some(reply) = self.planning.take().and_then(|job| job.reply) {
            self.answer_kept(reply, answer);
        }
    }

    /// The shut-down began: a command whose routes are being planned is answered
    /// `shutting_down`.
    pub(super) fn abandon_planning(&mut self) {
        self.end_planning(refuse(
            Code::ShuttingDown,
            "the daemon is stopping: the command's routes were being planned",
        ));
    }
}

#[cfg(test)]
impl<B: ServoBus, C: Clock> Cycle<B, C> {
    /// Whether a command's routes are being planned beside the loop.
    pub(super) fn planning_routes(&self) -> bool {
        self.planning.is_some()
    }

    /// Blocks until the routes being planned have come (the planner works in real time, the
    /// tests' loop on a manual clock); `false` when none were handed to the planner.
    pub(super) fn wait_for_routes(&mut self) -> bool {
        let Some(serial) = self.planning.as_ref().and_then(|p| p.serial) else {
            return false;
        };
        self.planner.wait(serial, Duration::from_secs(120))
    }
}

/// A `goto` or `path` whose routes are planned beside the loop (see [`Cycle::plan_beside`]).
/// The loop ticks on meanwhile; a `stop`, `estop` or motion command taken preempts it (one
/// refused does not, as it would not preempt a command under way).
#[derive(Debug)]
pub(super) struct Planning {
    client: ClientId,
    id: Option<RequestId>,
    kind: CmdName,
    /// The sender's reply, once [`Cycle::take`] has handed it over.
    pub reply: Option<oneshot::Sender<Answer>>,
    request: PlanRequest,
    /// The planner's job (`None`: the arm is still coming to rest).
    serial: Option<u64>,
    /// How often the routes were planned again.
    replans: u32,
    /// When the command was taken.
    since: std::time::Instant,
}

impl Planning {
    /// Where the command being planned goes (telemetry's `target` meanwhile).
    pub(super) fn target(&self) -> Option<Vec2> {
        self.request.target()
    }
}

/// A `reboot` under way: its servos booting (deaf to the bus for a few hundred ms) while the
/// loop ticks on, serving `status`, `stop`, `estop` and the world; commands that would move
/// the arm or change its torque are answered `busy` meanwhile. Each tick's read leaves the
/// booting servos out (a servo back from its boot has its RAM at the defaults until the
/// bring-up writes it again, which the read would take for a power loss).
#[derive(Debug)]
pub(super) struct Rebooting {
    pub reboots: arm::Reboots,
    /// The sender's reply, once [`Cycle::take`] has handed it over.
    pub reply: Option<oneshot::Sender<Answer>>,
    /// The servos read meanwhile (the others), and their joint indices.
    pub reading: Vec<u8>,
    pub joints: Vec<usize>,
    /// The shut-down began: nothing more is done for it.
    pub abandoned: bool,
}

impl Rebooting {
    /// The servos that may still be booting.
    pub fn booting(&self) -> impl Iterator<Item = u8> + '_ {
        self.reboots.ids().iter().copied()
    }
}

/// The servos a tick reads, of the arm's `all`, with each one's joint index when it is not
/// its slot: while a port of several is lost, those on the other ports (`reachable`);
/// while servos reboot (`job`), the others; else all.
pub(super) fn read_set<'a>(
    reachable: Option<&'a Reachable>,
    job: Option<&'a Rebooting>,
    all: &'a [u8],
) -> (&'a [u8], Option<&'a [usize]>) {
    match (reachable, job) {
        (Some(r), _) => (&r.ids, Some(&r.joints)),
        (None, Some(j)) => (&j.reading, Some(&j.joints)),
        (None, None) => (all, None),
    }
}

/// The servos still reachable while a port of a bus of several is lost (those on the other
/// ports), and their joint indices: read every tick meanwhile, so their measured pose and
/// health stay current. Filled anew whenever a port fails, within its capacity.
#[derive(Debug, Default)]
pub(super) struct Reachable {
    pub ids: Vec<u8>,
    pub joints: Vec<usize>,
}

impl Reachable {
    /// Room for `n` servos, so that filling it never allocates in the loop.
    pub fn with_capacity(n: usize) -> Self {
        Reachable {
            ids: Vec::with_capacity(n),
            joints: Vec::with_capacity(n),
        }
    }

    /// The servos of `ids` (joint indices `joints`, else their slots) whose port has not
    /// failed.
    pub fn fill<B: ServoBus>(&mut self, bus: &B, ids: &[u8], joints: Option<&[usize]>) {
        self.ids.clear();
        self.joints.clear();
        for (slot, &id) in ids.iter().enumerate() {
            let joint = joints.map_or(Some(slot), |j| j.get(slot).copied());
            if let (Some(joint), false) = (joint, bus.port_failed(bus.port_index(id))) {
                self.ids.push(id);
                self.joints.push(joint);
            }
        }
    }
}

/// "servo 3" or "servos [3, 4]", for messages.
fn which(ids: &[u8]) -> String {
    match ids {
        [id] => format!("servo {id}"),
        ids => format!("servos {ids:?}"),
    }
}

fn v2(p: &[f64; 2]) -> Vec2 {
    Vec2::new(p[0], p[1])
}
