//! Commands as the loop applies them, at the start of a tick in arrival order: each checked
//! against the supervisor's mode, handed to the controller, entered in the ledger, and answered
//! once this tick's telemetry is out.

use crate::chain::Vec2;
use crate::control::{self, Refused};
use crate::protocol::{
    world_rejection, Answer, Applied, Code, LoopCmd, Motion, Rebooted, Rejection, Reply, Status,
    StopReason, What, WorldInfo,
};
use crate::servo::arm::{self, BringUpOptions, OnExit, Retry};
use crate::servo::clock::Clock;
use crate::servo::ServoBus;
use crate::world::{Obstacle, World};

use super::ledger::Renewal;
use super::link::{Envelope, COMMAND_QUEUE, STOP_QUEUE};
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

    /// One command applied; its answer waits for this tick's telemetry.
    fn take(&mut self, envelope: Envelope) {
        let pending = self.apply(&envelope);
        self.received.push(envelope.received);
        self.pending.push((envelope.reply, pending));
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
        match &e.cmd {
            LoopCmd::Status => Pending::Status,
            LoopCmd::Stop => self.stop(e),
            LoopCmd::Estop => {
                self.estop(e);
                self.ok()
            }
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
                let mut obstacles = self.controller.world().obstacles().to_vec();
                let added = obstacles.len();
                obstacles.push(obstacle.clone());
                self.change_world(e, obstacles, Some(added))
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
                let mut obstacles = world.obstacles().to_vec();
                obstacles.remove(k);
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
        match self.controller.command(command) {
            Ok(()) => {
                self.begin(e);
                self.ok()
            }
            Err(
                r @ (Refused::OutsideLimits { .. }
                | Refused::SelfCollision { .. }
                | Refused::InsideObstacle { .. }
                | Refused::NotClearOnTheWay { .. }
                | Refused::NoRoute { .. }),
            ) => refuse(Code::Unreachable, r.to_string()),
            Err(r) => refuse(Code::BadArg, r.to_string()),
        }
    }

    /// `set_world`, `add_obstacle`, `remove_obstacle`: `obstacles` with the link radius and
    /// the clearance in force, validated as a world (refused `bad_arg` naming the field; for
    /// `add_obstacle`, `added` is the new one's index), in force from the next tick. Every
    /// client is told the new world, and whether the commanded pose is clear of it.
    fn change_world(
        &mut self,
        e: &Envelope,
        obstacles: Vec<Obstacle>,
        added: Option<usize>,
    ) -> Pending {
        let now = self.controller.world();
        let world = match World::new(now.link_radius_m(), now.clearance_m(), obstacles) {
            Ok(world) => world,
            Err(err) => return Pending::Ready(Err(world_rejection(&err, added))),
        };
        let info = Box::new(WorldInfo::of(&world));
        let not_clear = self.controller.set_world(world);
        self.decided.min_clearance_m = self.controller.min_clearance();
        tracing::info!(
            client = e.client,
            obstacles = self.controller.world().obstacles().len(),
            min_clearance_m = ?self.decided.min_clearance_m,
            "the world changed"
        );
        let by = e.client;
        self.event(None, e.id.clone(), |_| What::World { by, world: info });
        self.look_clear_after(e.id.clone(), not_clear);
        self.ok()
    }

    /// A command accepted by the controller becomes the active one (a velocity, or the same
    /// joint's jog, from the same client renews it).
    fn begin(&mut self, e: &Envelope) {
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
    /// waited on, and named in the log).
    fn estop(&mut self, e: &Envelope) {
        let torque_off = self.on_exit == OnExit::TorqueOff;
        if self.supervisor.estopped() {
            // A latch that kept torque on (a contact's) is no estop's: torque off all the same.
            if torque_off && self.supervisor.torque() {
                tracing::warn!("estop under the latch: torque off");
                self.supervisor.estop(true);
                self.torque_off_all("estop");
            }
            return;
        }
        self.controller.freeze();
        self.ledger.estop();
        tracing::warn!("estop: goals frozen");
        self.supervisor.estop(torque_off);
        if torque_off {
            self.torque_off_all("estop");
        }
        self.event(None, e.id.clone(), |tip| What::Estop { tip });
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
    /// watchdogs cleared, goals := the measured pose, torque on (within this tick), any
    /// `power_loss` fault cleared. Refused with `fault`, naming the servos, while the pose
    /// cannot be read or torque cannot be switched on; the latch then stays.
    fn reset(&mut self, e: &Envelope) -> Pending {
        if !self.supervisor.estopped() {
            return self.ok();
        }
        if let Some(why) = self.pose_unreadable() {
            return refuse(Code::Fault, format!("reset: {why}; the latch stays"));
        }
        if let Err(err) = self.clear_watchdogs() {
            return refuse(Code::Fault, format!("reset: {err}; the latch stays"));
        }
        if let Err(err) = self.measure_pose() {
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
            if let Err(err) = self.recover() {
                self.supervisor = before;
                return refuse(Code::Fault, format!("torque on: {err}"));
            }
            tracing::info!("torque on, holding the measured pose");
        } else {
            self.torque_off_all("torque off");
            self.supervisor.set_torque(false);
            self.controller.freeze();
            let ended = self.ledger.interrupt(StopReason::Torque);
            self.owe(ended);
            tracing::info!("torque off");
        }
        self.ok()
    }

    /// `reboot`: reboot `ids` (default: the servos in hardware error, else all), bring the arm
    /// up again where it stands (settings, watchdog, goal := present, torque on), goals := that
    /// pose; every joint fault clears.
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
        // Under a latch that switched torque off, torque stays off until `reset`.
        let latched_off = self.supervisor.estopped() && !self.supervisor.torque();
        if let Err(refusal) = self.reboot_and_bring_up(&targets) {
            return refusal;
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
        Pending::Ready(Ok(Reply::Rebooted(Rebooted {
            tick: self.tick,
            rebooted: targets,
        })
        .into()))
    }

    /// The reboots, then the bring-up where the arm stands; goals := that pose, torque on.
    fn reboot_and_bring_up(&mut self, targets: &[u8]) -> Result<(), Pending> {
        let timeout = self.schedule.reply_timeout;
        let mut retry = Retry::default();
        // All at once: their boots overlap, so the loop stands still for one boot, not one per
        // servo (a few seconds for a whole arm).
        arm::reboot_all_and_wait(self.port.bus(), targets, timeout, &self.clock, &mut retry)
            .map_err(|err| {
                let which = match targets {
                    [id] => format!("servo {id}"),
                    ids => format!("servos {ids:?}"),
                };
                refuse(Code::Fault, format!("reboot of {which}: {err}"))
            })?;
        let brought = self
            .arm
            .bring_up_with_clock(self.port.bus(), BringUpOptions::default(), &self.clock)
            .map_err(|err| refuse(Code::Fault, format!("bring-up after the reboot: {err}")))?;
        self.stats.counters.retries += u64::from(retry.retries + brought.retries);
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

fn v2(p: &[f64; 2]) -> Vec2 {
    Vec2::new(p[0], p[1])
}
