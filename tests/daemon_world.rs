//! The world through the socket, end to end on the simulator: `world`, `set_world`,
//! `add_obstacle` and `remove_obstacle`, the `world`, `not_clear` and `clear` events reaching
//! every client, the clearance in telemetry checked against the world's own exact distance,
//! every bad world command refused with its code, and `snakectl world` as a user runs it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::process::Command;
use std::time::Duration;

use daemon_support::{dist, floats, sim_config, xy, Client, Daemon};
use serde_json::{json, Value};
use snakectl::chain::Vec2;
use snakectl::protocol::parse_obstacles;
use snakectl::world::World;

/// The tests of this file run one at a time: each has its own daemon and simulator, and a
/// loaded machine keeps their loops on time better one by one.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// A circle obstacle in the socket's shape.
fn circle(id: &str, center: [f64; 2], radius: f64) -> Value {
    json!({"id": id, "circle": {"center": center, "radius": radius}})
}

/// A polygon obstacle in the socket's shape.
fn polygon(id: &str, points: &[[f64; 2]]) -> Value {
    json!({"id": id, "polygon": {"points": points}})
}

/// Far from the shipped arm (base at the origin, reach 0.96 m).
fn far_post() -> Value {
    circle("post", [2.0, 2.0], 0.05)
}

fn far_shelf() -> Value {
    polygon(
        "shelf",
        &[[-2.0, 1.5], [-1.8, 1.5], [-1.8, 1.55], [-2.0, 1.55]],
    )
}

/// The joint points of the commanded pose in `status` (or a telemetry line).
fn points(d: &Daemon, s: &Value) -> Vec<Vec2> {
    d.config.chain().points(&floats(&s["theta_cmd"]))
}

/// The world the `world` reply describes, built by the world's own validation.
fn world_of(reply: &Value) -> World {
    World::new(
        reply["link_radius_m"].as_f64().unwrap(),
        reply["clearance_m"].as_f64().unwrap(),
        parse_obstacles(&reply["obstacles"]).unwrap(),
    )
    .unwrap()
}

/// This client's id, from `take_control`.
fn take_control(c: &mut Client) -> u64 {
    c.ok(json!({"cmd": "take_control"}))["client"]
        .as_u64()
        .unwrap()
}

#[test]
fn the_world_is_set_added_to_and_removed_from_and_every_client_is_told() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut a = d.client();
    let mut b = d.client();
    let w = a.ok(json!({"cmd": "world"}));
    assert_eq!(w["obstacles"], json!([]), "{w}");
    let describe = b.ok(json!({"cmd": "describe"}));
    assert_eq!(describe["link_radius_m"], w["link_radius_m"], "{describe}");
    assert_eq!(describe["clearance_m"], w["clearance_m"], "{describe}");
    assert!(w["link_radius_m"].as_f64().unwrap() >= 0.0);
    assert!(w["clearance_m"].as_f64().unwrap() >= 0.0);

    let me = take_control(&mut a);
    let id = a.send(json!({"cmd": "set_world", "obstacles": [far_post(), far_shelf()]}));
    let reply = a.reply(&json!(id));
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert!(reply["tick"].as_u64().is_some(), "{reply}");
    // The other client is told the whole new world, and who changed it.
    let event = b.event("world", Some(id));
    assert_eq!(event["by"], json!(me), "{event}");
    assert_eq!(
        event["obstacles"],
        json!([far_post(), far_shelf()]),
        "{event}"
    );
    assert_eq!(event["link_radius_m"], w["link_radius_m"]);
    assert_eq!(event["clearance_m"], w["clearance_m"]);
    // The sender is told too, and reads the same world back.
    a.event("world", Some(id));
    let now = b.ok(json!({"cmd": "world"}));
    assert_eq!(now["obstacles"], json!([far_post(), far_shelf()]), "{now}");
    assert_eq!(
        now["link_radius_m"], w["link_radius_m"],
        "the link radius stays"
    );

    let disc = circle("disc", [1.5, -1.5], 0.1);
    let id = a.send(json!({"cmd": "add_obstacle", "obstacle": disc}));
    assert_eq!(a.reply(&json!(id))["ok"], json!(true));
    let event = b.event("world", Some(id));
    assert_eq!(event["obstacles"], json!([far_post(), far_shelf(), disc]));

    let id = a.send(json!({"cmd": "remove_obstacle", "obstacle": "post"}));
    assert_eq!(a.reply(&json!(id))["ok"], json!(true));
    let event = b.event("world", Some(id));
    assert_eq!(event["obstacles"], json!([far_shelf(), disc]));
    assert_eq!(
        b.ok(json!({"cmd": "world"}))["obstacles"],
        json!([far_shelf(), disc])
    );

    // Far obstacles leave the arm clear: no `not_clear` came.
    let events = b.drain_events(Duration::from_millis(100));
    assert!(
        events.iter().all(|e| e["event"] != "not_clear"),
        "{events:?}"
    );
    a.ok(json!({"cmd": "set_world", "obstacles": []}));
    assert_eq!(b.ok(json!({"cmd": "world"}))["obstacles"], json!([]));
}

#[test]
fn telemetry_reports_the_clearance_of_the_commanded_pose() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let s = c.status();
    assert_eq!(s["min_clearance_m"], Value::Null, "no obstacles: {s}");
    assert_eq!(s["blocked"], json!(false), "{s}");

    // A post 6 cm to the side of link 6's middle.
    let p = points(&d, &s);
    let (a, b) = (p[5], p[6]);
    let mid = (a + b) / 2.0;
    let along = (b - a).normalize();
    let side = Vec2::new(-along.y, along.x);
    let center = mid + side * 0.06;
    let post = circle("post", [center.x, center.y], 0.02);
    c.ok(json!({"cmd": "set_world", "obstacles": [post]}));
    let world = world_of(&c.ok(json!({"cmd": "world"})));

    let s = c.status();
    let got = s["min_clearance_m"].as_f64().unwrap();
    let want = world.clearance(&points(&d, &s)).unwrap();
    assert!((got - want.clearance_m).abs() < 1e-12, "{got} vs {want:?}");
    assert!(
        (got - (0.06 - 0.02 - world.link_radius_m())).abs() < 0.01,
        "about the gap placed: {got}"
    );
    assert_eq!(want.link, 6);
    assert_eq!(s["blocked"], json!(false), "{s}");

    // Telemetry lines carry the same, each of its own pose.
    c.ok(json!({"cmd": "subscribe", "rate_hz": 50.0}));
    for t in c.telemetry_until({
        let mut n = 0;
        move |_| {
            n += 1;
            n == 3
        }
    }) {
        let got = t["min_clearance_m"].as_f64().unwrap();
        let want = world.clearance(&points(&d, &t)).unwrap().clearance_m;
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }

    // While the estop latch freezes the controller, the clearance is still that of the pose
    // (here after the world moved), and after `reset` of the measured pose it holds.
    let same = |c: &mut Client, world: &World| {
        let s = c.status();
        let got = s["min_clearance_m"].as_f64().unwrap();
        let want = world.clearance(&points(&d, &s)).unwrap().clearance_m;
        assert!((got - want).abs() < 1e-12, "{got} vs {want}: {s}");
        s
    };
    c.ok(json!({"cmd": "estop"}));
    let nearer = circle(
        "post",
        [center.x - side.x * 0.01, center.y - side.y * 0.01],
        0.02,
    );
    c.ok(json!({"cmd": "set_world", "obstacles": [nearer]}));
    let world = world_of(&c.ok(json!({"cmd": "world"})));
    let s = same(&mut c, &world);
    assert_eq!(s["state"], "estop", "{s}");
    c.ok(json!({"cmd": "reset"}));
    same(&mut c, &world);

    // No obstacles again: null again.
    c.ok(json!({"cmd": "set_world", "obstacles": []}));
    assert_eq!(c.status()["min_clearance_m"], Value::Null);
}

#[test]
fn an_obstacle_put_onto_the_arm_is_told_to_everyone_and_the_arm_holds() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut a = d.client();
    let mut b = d.client();
    let before = a.status();
    b.status();
    let p = points(&d, &before);
    let mid = (p[4] + p[5]) / 2.0;
    let onto = circle("onto", [mid.x, mid.y], 0.01);
    let id = a.send(json!({"cmd": "set_world", "obstacles": [far_post(), onto]}));
    let reply = a.reply(&json!(id));
    assert_eq!(reply["ok"], json!(true));

    let told = b.event("not_clear", None);
    // The sender's reply says it too, as the event does.
    for field in ["link", "obstacle", "clearance_m", "keep_m"] {
        assert_eq!(reply["not_clear"][field], told[field], "{reply} {told}");
    }
    assert_eq!(told["link"], json!(5), "{told}");
    assert_eq!(told["obstacle"], json!("onto"), "{told}");
    let depth = told["clearance_m"].as_f64().unwrap();
    assert!(
        depth < -0.01 + 1e-9,
        "inside by its radius at least: {told}"
    );
    let world = world_of(&a.ok(json!({"cmd": "world"})));
    assert_eq!(told["keep_m"].as_f64().unwrap(), world.clearance_m());
    assert_eq!(told["cmd_id"], json!(id), "the change that caused it");
    a.event("not_clear", None);

    // The arm holds where it was, and telemetry says how deep.
    let s = a.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["theta_cmd"], before["theta_cmd"]);
    let got = s["min_clearance_m"].as_f64().unwrap();
    assert!((got - depth).abs() < 1e-12, "{got} vs {depth}");

    // Taken away: clear again, told to everyone.
    a.ok(json!({"cmd": "remove_obstacle", "obstacle": "onto"}));
    let clear = b.event("clear", None);
    let left = clear["min_clearance_m"].as_f64().unwrap();
    assert!(left >= world.clearance_m(), "{clear}");
    a.event("clear", None);
}

/// A move under way when a world change puts an obstacle onto the arm comes to rest, and its
/// sender is told why (`not_clear`), not as if someone had sent `stop`.
#[test]
fn a_move_an_obstacle_is_put_onto_stops_saying_why() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    take_control(&mut c);
    let s = c.status();
    let tip = xy(&s["tip"]);
    let id = c.send(json!({"cmd": "goto", "target": [tip[0] + 0.1, tip[1]], "speed": 0.02}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let s = c.wait_status("moving", |s| s["state"] == "moving");
    let p = points(&d, &s);
    let mid = (p[4] + p[5]) / 2.0;
    c.ok(json!({"cmd": "set_world", "obstacles": [circle("onto", [mid.x, mid.y], 0.01)]}));
    let stopped = c.event("stopped", None);
    assert_eq!(stopped["cmd_id"], json!(id), "{stopped}");
    assert_eq!(stopped["reason"], "not_clear", "{stopped}");
}

/// A goto away from an obstacle put deep onto the arm takes the arm out under overall (the
/// shipped strategy): the links not clear need only come no closer, and none does on the way.
/// The arm 12 mm in radius, as in `config/world.toml`: the disc below is 28 mm deep (when the
/// solver asked the whole clearance of every link, the goto ended `blocked` at once).
#[test]
fn a_goto_away_from_an_obstacle_put_deep_onto_the_arm_arrives() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    let s = c.status();
    let p = points(&d, &s);
    // A disc of 20 mm radius 4 mm beside the middle of link 6.
    let mid = (p[5] + p[6]) / 2.0;
    let onto = circle("onto", [mid.x, mid.y + 0.004], 0.02);
    c.ok(json!({"cmd": "set_world", "obstacles": [onto]}));
    let told = c.event("not_clear", None);
    assert_eq!(told["link"], json!(6), "{told}");
    let depth = told["clearance_m"].as_f64().unwrap();
    assert!(depth < -0.028, "{told}");
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let tip = xy(&s["tip"]);
    let id = c.send(json!({"cmd": "goto", "target": [tip[0] + 0.08, tip[1]]}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let lines = c.telemetry_until(|t| {
        t["command"]["outcome"] != "active" && t["command"]["id"] == json!(id)
    });
    for t in &lines {
        let now = t["min_clearance_m"].as_f64().unwrap();
        assert!(now >= depth - 1e-9, "closer than {depth} m: {t}");
    }
    let last = lines.last().unwrap();
    assert_eq!(last["command"]["outcome"], "arrived", "{last}");
}

/// A `reach` from a pose an obstacle was put deep onto takes the arm out (the least clearance
/// never below the depth it started at), then round to its target, and arrives there clear.
#[test]
fn a_reach_from_an_obstacle_put_deep_onto_the_arm_gets_out_and_arrives() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    let s = c.status();
    let p = points(&d, &s);
    // A disc of 20 mm radius 4 mm beside the middle of link 6.
    let mid = (p[5] + p[6]) / 2.0;
    let onto = circle("onto", [mid.x, mid.y + 0.004], 0.02);
    c.ok(json!({"cmd": "set_world", "obstacles": [onto]}));
    let depth = c.event("not_clear", None)["clearance_m"].as_f64().unwrap();
    let world = world_of(&c.ok(json!({"cmd": "world"})));
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let tip = xy(&s["tip"]);
    let target = [tip[0] + 0.15, tip[1] - 0.1];
    let id = c.send(json!({"cmd": "reach", "target": target}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let lines = c.telemetry_until(|t| {
        t["command"]["outcome"] != "active" && t["command"]["id"] == json!(id)
    });
    let mut best = depth;
    for t in &lines {
        let now = t["min_clearance_m"].as_f64().unwrap();
        assert!(
            now >= best.min(world.clearance_m()) - 1e-9,
            "closer than {best} m: {t}"
        );
        best = best.max(now);
    }
    c.event("clear", None);
    let last = lines.last().unwrap();
    assert_eq!(last["command"]["outcome"], "arrived", "{last}");
    let s = rests_on(&mut c, &d, target);
    assert!(
        measured_clearance(&d, &world, &s) >= world.clearance_m() - 1e-4,
        "{s}"
    );
}

/// Waits for the arm to hold, then checks that the measured tip is on `target` within what
/// whole servo ticks allow; the status it held in.
fn rests_on(c: &mut Client, d: &Daemon, target: [f64; 2]) -> Value {
    let s = c.wait_status("at rest", |s| s["state"] == "holding");
    let bound = daemon_support::rounding_bound(&d.config, &floats(&s["theta_meas"]));
    let off = dist(xy(&s["tip_meas"]), target);
    assert!(
        off <= bound,
        "the tip {off} m from the target (ticks allow {bound})"
    );
    s
}

/// The measured pose's clearance in a telemetry line, by the world's exact distance.
fn measured_clearance(d: &Daemon, world: &World, t: &Value) -> f64 {
    let p = d.config.chain().points(&floats(&t["theta_meas"]));
    world.clearance(&p).unwrap().clearance_m
}

/// Every telemetry line's measured pose keeps the clearance but for the tracking error.
fn measured_clear(d: &Daemon, world: &World, lines: &[Value]) {
    for t in lines {
        let measured = measured_clearance(d, world, t);
        let tracking = t["tracking_error_m"].as_f64().unwrap();
        assert!(
            measured >= world.clearance_m() - tracking - 1e-4,
            "measured {measured} m with a tracking error of {tracking} m: {t}"
        );
    }
}

/// A daemon on the shipped simulator whose links are `radius` m in radius.
fn with_link_radius(radius: &str) -> Daemon {
    let world = format!("max_clients = 4\n\n[world]\nlink_radius_m = {radius}");
    Daemon::start(sim_config(&[("max_clients = 4", world.as_str())]))
}

#[test]
fn a_goto_behind_a_post_goes_round_it_and_arrives_clear() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    take_control(&mut c);
    let s = c.status();
    let tip = xy(&s["tip"]);
    // The post stands on the straight line from the tip to the target.
    let target = [tip[0], tip[1] - 0.2];
    let post = circle("post", [tip[0], tip[1] - 0.1], 0.055);
    c.ok(json!({"cmd": "set_world", "obstacles": [post]}));
    let world = world_of(&c.ok(json!({"cmd": "world"})));
    assert!(
        world
            .route(Vec2::new(tip[0], tip[1]), Vec2::new(target[0], target[1]))
            .unwrap()
            .waypoints
            .len()
            > 2
    );
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let id = c.send(json!({"cmd": "goto", "target": target, "speed": 0.05}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let mut least = f64::INFINITY;
    let mut farthest: f64 = 0.0;
    let lines = c.telemetry_until(|t| {
        t["command"]["outcome"] != "active" && t["command"]["id"] == json!(id)
    });
    measured_clear(&d, &world, &lines);
    for t in &lines {
        least = least.min(t["min_clearance_m"].as_f64().unwrap());
        farthest = farthest.max(dist(xy(&t["tip"]), [tip[0], tip[1] - 0.1]));
    }
    let last = lines.last().unwrap();
    assert_eq!(last["command"]["outcome"], "arrived", "{last}");
    assert!(least >= world.clearance_m() - 1e-9, "{least}");
    // Once at rest, the measured tip is on the target within what whole ticks allow.
    rests_on(&mut c, &d, target);
}

/// Two discs between the arm and a target down and to its left: the tip's route clears them,
/// but the body, turning the least each tick, wraps round the lower disc and is caught there
/// (`goto` ends `blocked`). A `reach` plans a way in joint space beside the loop, takes the body
/// round the other side leg by leg, and arrives; the measured pose keeps the clearance but for
/// the tracking error all the way.
#[test]
fn a_reach_gets_round_where_a_goto_is_caught() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.01");
    let mut c = d.client();
    take_control(&mut c);
    let discs = [
        circle("upper", [-0.3001, 0.7139], 0.0127),
        circle("lower", [-0.5183, 0.5435], 0.0148),
    ];
    c.ok(json!({"cmd": "set_world", "obstacles": discs}));
    let world = world_of(&c.ok(json!({"cmd": "world"})));
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let target = [-0.6656, 0.4673];
    let id = c.send(json!({"cmd": "goto", "target": target}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let lines = c.telemetry_until(|t| {
        t["command"]["outcome"] != "active" && t["command"]["id"] == json!(id)
    });
    let last = lines.last().unwrap();
    assert_eq!(last["command"]["outcome"], "blocked", "{last}");
    let id = c.send(json!({"cmd": "reach", "target": target}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    let lines = c.telemetry_until(|t| {
        t["command"]["outcome"] != "active" && t["command"]["id"] == json!(id)
    });
    measured_clear(&d, &world, &lines);
    for t in &lines {
        let commanded = t["min_clearance_m"].as_f64().unwrap();
        assert!(commanded >= world.clearance_m() - 1e-9, "{t}");
    }
    let last = lines.last().unwrap();
    assert_eq!(last["command"]["kind"], "reach", "{last}");
    assert_eq!(last["command"]["outcome"], "arrived", "{last}");
    rests_on(&mut c, &d, target);
    // A target inside a disc has no clear pose: refused in words, nothing moves.
    let refused = c.request(json!({"cmd": "reach", "target": [-0.5183, 0.5435]}));
    assert_eq!(refused["error"]["code"], "unreachable", "{refused}");
    let message = refused["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("no pose found with the tip on"),
        "{message}"
    );
}

/// The post and the shelf of `config/world.toml`.
fn post_and_shelf() -> [Value; 2] {
    [
        circle("post", [0.15, 0.60], 0.04),
        polygon(
            "shelf",
            &[[-0.6, 0.3], [-0.4, 0.3], [-0.4, 0.34], [-0.6, 0.34]],
        ),
    ]
}

/// Two long thin walls either side of the base, forming a slot the arm points out of: the
/// planner finds no clear way down below them, after 0.6 s or so of work.
fn slot() -> [Value; 2] {
    [
        polygon(
            "right",
            &[[0.06, 0.0], [1.2, 0.0], [1.2, 0.01], [0.06, 0.01]],
        ),
        polygon(
            "left",
            &[[-0.06, 0.0], [-1.2, 0.0], [-1.2, 0.01], [-0.06, 0.01]],
        ),
    ]
}

/// `requests` in one write, each with a fresh id; their ids.
fn send_at_once(c: &mut Client, requests: &[Value]) -> Vec<u64> {
    let mut bytes = Vec::new();
    let ids = (0..requests.len() as u64)
        .map(|k| 1000 + k)
        .collect::<Vec<_>>();
    for (request, id) in requests.iter().zip(&ids) {
        let mut request = request.clone();
        request["id"] = json!(id);
        bytes.extend(serde_json::to_vec(&request).unwrap());
        bytes.push(b'\n');
    }
    c.write_raw(&bytes);
    ids
}

/// The replies to `ids` and the events naming them, in the order they come, until `done` says
/// so of them (within [`daemon_support::DEADLINE`]); other lines are dropped.
fn lines_about(c: &mut Client, ids: &[u64], mut done: impl FnMut(&[Value]) -> bool) -> Vec<Value> {
    let mut lines = Vec::new();
    let ours = |l: &Value| {
        let id = if l["type"] == "event" {
            &l["cmd_id"]
        } else {
            &l["id"]
        };
        l["type"] != "telemetry" && ids.iter().any(|i| id == &json!(i))
    };
    while !done(&lines) {
        let line = c
            .next_matching(daemon_support::DEADLINE, ours)
            .unwrap_or_else(|| panic!("not done within the deadline: {lines:?}"));
        lines.push(line);
    }
    lines
}

/// The reply to `id` among `lines`.
fn reply_in(lines: &[Value], id: u64) -> Option<&Value> {
    lines
        .iter()
        .find(|l| l.get("type").is_none() && l["id"] == json!(id))
}

/// Regression: a `reach` the planner could not take (`busy`) preempted the one taken before
/// it, so that nothing moved. Six in one write, more than the planner's queue of two takes
/// before its thread has run: each refused one changes nothing, each taken one preempts the
/// one before, and the last one taken arrives.
#[test]
fn a_reach_refused_busy_leaves_the_one_taken_to_run() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    c.ok(json!({"cmd": "set_world", "obstacles": post_and_shelf()}));
    let targets = [
        [0.3, 0.6],
        [0.0, 0.5],
        [-0.3, 0.6],
        [0.5, 0.2],
        [0.0, 0.5],
        [0.3, 0.6],
    ];
    let reaches: Vec<Value> = targets
        .iter()
        .map(|t| json!({"cmd": "reach", "target": t}))
        .collect();
    let ids = send_at_once(&mut c, &reaches);
    // Every reply, then every event about the reaches until the last one taken ends.
    let lines = lines_about(&mut c, &ids, |lines| {
        let Some(replies) = ids
            .iter()
            .map(|&id| reply_in(lines, id))
            .collect::<Option<Vec<_>>>()
        else {
            return false;
        };
        let Some(last) = ids
            .iter()
            .zip(&replies)
            .rfind(|(_, r)| r["ok"] == json!(true))
        else {
            return true;
        };
        lines.iter().any(|l| {
            l["type"] == "event" && l["cmd_id"] == json!(last.0) && l["event"] != "preempted"
        })
    });
    let (taken, refused): (Vec<u64>, Vec<u64>) = ids
        .iter()
        .partition(|&&id| reply_in(&lines, id).unwrap()["ok"] == json!(true));
    for id in &refused {
        let reply = reply_in(&lines, *id).unwrap();
        assert_eq!(reply["error"]["code"], "busy", "{reply}");
    }
    assert!(!refused.is_empty(), "the planner took all six");
    let last = *taken.last().expect("the planner took none");
    let events: Vec<&Value> = lines.iter().filter(|l| l["type"] == "event").collect();
    assert!(
        events
            .iter()
            .any(|e| e["cmd_id"] == json!(last) && e["event"] == "arrived"),
        "the last reach taken, {last}, did not arrive: {events:?}"
    );
    for id in &taken[..taken.len() - 1] {
        assert!(
            events.iter().any(|e| e["cmd_id"] == json!(id)
                && e["event"] == "preempted"
                && e["reason"] == "reach"),
            "reach {id} was taken, then not preempted: {events:?}"
        );
    }
    for id in &refused {
        assert!(
            events.iter().all(|e| e["cmd_id"] != json!(id)),
            "reach {id} was refused, yet told of: {events:?}"
        );
    }
    let s = c.status();
    assert_eq!(s["command"]["id"], json!(last), "{s}");
    assert_eq!(s["command"]["outcome"], "arrived", "{s}");
}

/// Regression: a `reach` whose way the planner did not find in a world changed meanwhile was
/// refused `unreachable` in the world no longer in force. Sent in one write with the world
/// that clears the slot, it is planned again in the world in force, and arrives.
#[test]
fn a_reach_refused_in_a_world_changed_meanwhile_is_planned_again() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    c.ok(json!({"cmd": "set_world", "obstacles": slot()}));
    let target = [0.5, -0.2];
    let ids = send_at_once(
        &mut c,
        &[
            json!({"cmd": "reach", "target": target}),
            json!({"cmd": "set_world", "obstacles": []}),
        ],
    );
    // Both replies, and the reach's ending when it is taken.
    let lines = lines_about(&mut c, &ids, |lines| {
        reply_in(lines, ids[1]).is_some()
            && (reply_in(lines, ids[0]).is_some_and(|r| r["ok"] == json!(false))
                || lines
                    .iter()
                    .any(|l| l["type"] == "event" && l["cmd_id"] == json!(ids[0])))
    });
    let reply = reply_in(&lines, ids[0]).unwrap();
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert_eq!(reply_in(&lines, ids[1]).unwrap()["ok"], json!(true));
    let ending = lines.last().unwrap();
    assert_eq!(ending["event"], "arrived", "{ending}");
    rests_on(&mut c, &d, target);
}

/// While a `reach` is planned beside the loop, telemetry's `target` is already its target;
/// once it is refused, nothing is.
#[test]
fn a_reach_being_planned_shows_its_target() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    c.ok(json!({"cmd": "set_world", "obstacles": slot()}));
    let mut watcher = d.client();
    let id = c.send(json!({"cmd": "reach", "target": [0.5, -0.2]}));
    watcher.wait_status("the reach's target", |s| s["target"] == json!([0.5, -0.2]));
    let refused = c.reply(&json!(id));
    assert_eq!(refused["error"]["code"], "unreachable", "{refused}");
    assert_eq!(watcher.status()["target"], Value::Null);
}

/// Regression: while a `reach` was planned (0.6 s in the slot), every other reply and event to
/// its connection waited for its answer. The lines sent after it are answered meanwhile, and
/// so is another client's taking of control told; the reach's own reply comes when its
/// planning ends.
#[test]
fn a_connection_is_served_while_its_reach_is_planned() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    c.ok(json!({"cmd": "set_world", "obstacles": slot()}));
    let ids = send_at_once(
        &mut c,
        &[
            json!({"cmd": "reach", "target": [0.5, -0.2]}),
            json!({"cmd": "describe"}),
            json!({"cmd": "world"}),
            json!({"cmd": "status"}),
        ],
    );
    let mut seen = Vec::new();
    let mut next = |seen: &mut Vec<Value>| {
        let line = c
            .read_line(daemon_support::DEADLINE)
            .expect("a line within the deadline");
        seen.push(line);
    };
    while ids[1..].iter().any(|&id| reply_in(&seen, id).is_none()) {
        next(&mut seen);
    }
    assert!(
        reply_in(&seen, ids[0]).is_none(),
        "the others waited for the reach: {seen:?}"
    );
    let mut other = d.client();
    let holder = take_control(&mut other);
    while !seen
        .iter()
        .any(|l| l["event"] == "control" && l["holder"] == json!(holder))
    {
        next(&mut seen);
    }
    assert!(
        reply_in(&seen, ids[0]).is_none(),
        "the control event waited for the reach: {seen:?}"
    );
    while reply_in(&seen, ids[0]).is_none() {
        next(&mut seen);
    }
    let reply = reply_in(&seen, ids[0]).unwrap();
    assert_eq!(reply["error"]["code"], "unreachable", "{reply}");
}

/// A `preempted` event carries the tick its command ended in, the tick that took the command
/// replacing it, not the one that took its own: a `goto` under way ended by a `reach` (taken
/// with a `status` in one write), and that `reach`, still being planned, ended by a `stop`
/// some ticks on, answered then with the stop's tick.
#[test]
fn a_preempted_event_carries_the_tick_that_ended_its_command() {
    let _one = one_at_a_time();
    let d = with_link_radius("0.012");
    let mut c = d.client();
    take_control(&mut c);
    c.ok(json!({"cmd": "set_world", "obstacles": slot()}));
    let tip = xy(&c.status()["tip"]);
    let goto = c.send(json!({"cmd": "goto", "target": [tip[0] + 0.05, tip[1]], "speed": 0.01}));
    let began = c.reply(&json!(goto))["tick"].as_u64().unwrap();
    let ids = send_at_once(
        &mut c,
        &[
            json!({"cmd": "reach", "target": [0.5, -0.2]}),
            json!({"cmd": "status"}),
        ],
    );
    let taken = c.reply(&json!(ids[1]))["tick"].as_u64().unwrap();
    let ended = c.event("preempted", Some(goto));
    assert_eq!(ended["reason"], "reach", "{ended}");
    let at = ended["tick"].as_u64().unwrap();
    assert!(began < at && at <= taken, "{began} < {at} <= {taken}");
    // A few ticks on, the reach still being planned.
    let later = c.wait_status("ticks on", |s| s["tick"].as_u64().unwrap() >= taken + 5);
    assert_eq!(
        later["command"]["id"],
        json!(goto),
        "the reach began: {later}"
    );
    let stop = c.send(json!({"cmd": "stop"}));
    let lines = lines_about(&mut c, &[ids[0], stop], |lines| {
        reply_in(lines, stop).is_some()
            && lines
                .iter()
                .any(|l| l["event"] == "preempted" && l["cmd_id"] == json!(ids[0]))
    });
    let stopped = reply_in(&lines, stop).unwrap()["tick"].as_u64().unwrap();
    let reach = reply_in(&lines, ids[0]).unwrap();
    assert_eq!(reach["tick"], json!(stopped), "{reach}");
    let ended = lines.iter().find(|l| l["event"] == "preempted").unwrap();
    assert_eq!(ended["reason"], "stop", "{ended}");
    assert_eq!(ended["tick"], json!(stopped), "{ended}");
    assert!(stopped > taken + 4, "{stopped} after {taken}");
}

#[test]
fn a_velocity_into_a_wall_slides_along_it() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    take_control(&mut c);
    let s = c.status();
    let tip = xy(&s["tip"]);
    let top = tip[1] - 0.12;
    let wall = polygon(
        "wall",
        &[
            [-1.0, top - 0.02],
            [tip[0] + 0.03, top - 0.02],
            [tip[0] + 0.03, top],
            [-1.0, top],
        ],
    );
    c.ok(json!({"cmd": "set_world", "obstacles": [wall]}));
    let world = world_of(&c.ok(json!({"cmd": "world"})));
    // Down and to the left, renewed at 20 Hz for 4 s.
    for _ in 0..80 {
        c.send(json!({"cmd": "velocity", "v": [-0.03, -0.06]}));
        std::thread::sleep(Duration::from_millis(50));
        let s = c.status();
        let p = xy(&s["tip"]);
        assert!(
            p[1] - top >= world.route_radius_m() - 1e-9,
            "the commanded tip {} m above the wall: {s}",
            p[1] - top
        );
        assert!(s["min_clearance_m"].as_f64().unwrap() >= world.clearance_m() - 1e-9);
    }
    let s = c.status();
    let p = xy(&s["tip"]);
    // On the wall (within a centimetre of its top) and well to the left of where it met it.
    assert!(p[1] - top < 0.03, "{s}");
    assert!(p[0] < tip[0] - 0.08, "slid only to {p:?} from {tip:?}");
}

#[test]
fn every_bad_world_command_gets_its_code() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut a = d.client();
    let mut b = d.client();
    take_control(&mut a);
    a.ok(json!({"cmd": "set_world", "obstacles": [far_post()]}));

    let refused = |c: &mut Client, request: Value, code: &str, words: &[&str]| {
        let reply = c.request(request.clone());
        assert_eq!(reply["ok"], json!(false), "{request} -> {reply}");
        assert_eq!(reply["error"]["code"], json!(code), "{request} -> {reply}");
        let message = reply["error"]["message"].as_str().unwrap();
        for w in words {
            assert!(message.contains(w), "{request} -> {message} lacks {w:?}");
        }
    };
    let set = |list: Vec<Value>| json!({"cmd": "set_world", "obstacles": list});
    // What the parser refuses.
    refused(
        &mut a,
        set(vec![
            far_post(),
            json!({"id": "x", "circle": {"center": [0, 1], "radius": 0.1, "r": 1}}),
        ]),
        "bad_arg",
        &["`obstacles[1].circle.r`", "unknown key"],
    );
    refused(
        &mut a,
        set(vec![
            json!({"id": "x", "circle": {"center": [0, 2e6], "radius": 0.1}}),
        ]),
        "bad_arg",
        &["`obstacles[0].circle.center[1]`"],
    );
    refused(
        &mut a,
        set(vec![json!({"id": "x"})]),
        "bad_arg",
        &["`obstacles[0]`", "circle", "polygon"],
    );
    refused(
        &mut a,
        json!({"cmd": "add_obstacle", "obstacle": {"id": "x", "polygon": {"points": [[0, 1], "a"]}}}),
        "bad_arg",
        &["`obstacle.polygon.points[1]`"],
    );
    // Read whole and no world: refused as the line is read (an added obstacle's id, which
    // only the world in force can tell taken, by the loop).
    refused(
        &mut a,
        set(vec![far_post(), circle("x", [0.5, 0.5], 0.0)]),
        "bad_arg",
        &["`obstacles[1].circle.radius`", "positive"],
    );
    refused(
        &mut a,
        set(vec![
            far_post(),
            far_shelf(),
            circle("post", [0.5, 0.5], 0.1),
        ]),
        "bad_arg",
        &["`obstacles[2].id`", "\"post\"", "obstacles[0]"],
    );
    refused(
        &mut a,
        set(vec![polygon("two", &[[1.0, 1.0], [1.2, 1.0]])]),
        "bad_arg",
        &["`obstacles[0].polygon.points`", "at least 3"],
    );
    refused(
        &mut a,
        set(vec![polygon(
            "bow",
            &[[1.0, 1.0], [1.2, 1.2], [1.2, 1.0], [1.0, 1.2]],
        )]),
        "bad_arg",
        &["`obstacles[0].polygon.points`", "cross"],
    );
    let many: Vec<Value> = (0..65)
        .map(|i| circle(&format!("c{i}"), [2.0 + f64::from(i), 2.0], 0.1))
        .collect();
    refused(&mut a, set(many), "bad_arg", &["65 obstacles", "64"]);
    let big: Vec<[f64; 2]> = (0..1025)
        .map(|k| {
            let t = f64::from(k) / 1025.0 * std::f64::consts::TAU;
            [3.0 + t.cos(), 3.0 + t.sin()]
        })
        .collect();
    refused(
        &mut a,
        set(vec![polygon("big", &big)]),
        "bad_arg",
        &["1025 polygon points", "1024"],
    );
    refused(
        &mut a,
        json!({"cmd": "add_obstacle", "obstacle": circle("post", [1.0, -1.0], 0.1)}),
        "bad_arg",
        &["`obstacle.id`", "\"post\""],
    );
    refused(
        &mut a,
        json!({"cmd": "remove_obstacle", "obstacle": "nope"}),
        "bad_arg",
        &["`obstacle`", "\"nope\"", "\"post\""],
    );
    // JSON cannot hold a non-finite number: the line is refused as such (its id unread).
    a.write_raw(
        b"{\"id\": 99, \"cmd\": \"add_obstacle\", \"obstacle\": {\"id\": \"x\", \"circle\": {\"center\": [0, 1e999], \"radius\": 1}}}\n",
    );
    assert_eq!(a.reply(&Value::Null)["error"]["code"], json!("bad_json"));
    // Not in control: refused whatever the world.
    for request in [
        set(vec![]),
        json!({"cmd": "add_obstacle", "obstacle": circle("x", [1.0, -1.0], 0.1)}),
        json!({"cmd": "remove_obstacle", "obstacle": "post"}),
    ] {
        refused(&mut b, request, "not_in_control", &[]);
    }
    // Reading it needs nothing, and nothing above changed it.
    assert_eq!(
        b.ok(json!({"cmd": "world"}))["obstacles"],
        json!([far_post()])
    );
}

/// `snakectl ARGS` against the daemon at `addr`, run to its end: exit code, stdout, stderr.
fn snakectl(addr: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .args(["--connect", addr])
        .output()
        .unwrap();
    (
        out.status.code().unwrap(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

/// `snakectl world --connect ADDR SUBCOMMAND ...`: the connection given before the subcommand.
fn snakectl_before(addr: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["world", "--connect", addr])
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

/// `--connect` (and `--token-file`) may come before `world`'s subcommand as well as after it;
/// the subcommands' usage shows them optional.
#[test]
fn world_subcommands_take_the_connection_before_them_too() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();
    let mut c = d.client();
    let ids = |c: &mut Client| -> Vec<String> {
        c.ok(json!({"cmd": "world"}))["obstacles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["id"].as_str().unwrap().to_owned())
            .collect()
    };
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("w.json");
    std::fs::write(&file, json!({"obstacles": [far_post()]}).to_string()).unwrap();

    let (code, _, err) = snakectl_before(&addr, &["set", file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(ids(&mut c).len(), 1);
    let (code, _, err) =
        snakectl_before(&addr, &["add", "dot", "--circle", "-1.5", "-1.5", "0.05"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(ids(&mut c).last().map(String::as_str), Some("dot"));
    let (code, _, err) = snakectl_before(&addr, &["remove", "dot"]);
    assert_eq!(code, 0, "{err}");
    assert!(!ids(&mut c).contains(&"dot".to_owned()));
    let (code, out, err) = snakectl_before(&addr, &["clear"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("cleared every obstacle"), "{out}");
    assert!(ids(&mut c).is_empty());
    // The token file too (this daemon asks for none: an unreadable one is refused, as input).
    let (code, _, err) = snakectl_before(&addr, &["--token-file", "/nonexistent/token", "clear"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("/nonexistent/token"), "{err}");

    let (code, _, err) = snakectl_before(&addr, &["--json", "clear"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--json goes with `snakectl world` alone"),
        "{err}"
    );

    for sub in ["set", "add", "remove", "clear"] {
        let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["world", sub, "--help"])
            .output()
            .unwrap();
        let help = String::from_utf8(out.stdout).unwrap();
        let usage = help.lines().find(|l| l.starts_with("Usage:")).unwrap();
        assert!(!usage.contains("--connect"), "{sub}: {usage}");
        assert!(help.contains("--connect <ADDR>"), "{sub}: {help}");
    }
}

#[test]
fn snakectl_world_prints_it_and_sets_it_from_json_and_toml() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let addr = d.addr.to_string();
    let mut c = d.client();
    c.status();
    let dir = tempfile::tempdir().unwrap();

    let (code, out, err) = snakectl(&addr, &["world"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("link radius "), "{out}");
    assert!(out.contains(", 0 obstacles"), "{out}");

    // JSON in the socket's shape.
    let json_file = dir.path().join("w.json");
    std::fs::write(
        &json_file,
        json!({"obstacles": [far_post(), far_shelf()]}).to_string(),
    )
    .unwrap();
    let (code, out, err) = snakectl(&addr, &["world", "set", json_file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.starts_with("ok: set_world with 2 obstacles at tick "),
        "{out}"
    );
    assert_eq!(
        c.ok(json!({"cmd": "world"}))["obstacles"],
        json!([far_post(), far_shelf()])
    );
    let (code, out, _) = snakectl(&addr, &["world"]);
    assert_eq!(code, 0);
    let lines: Vec<&str> = out.lines().collect();
    assert!(lines[0].ends_with(", 2 obstacles"), "{out}");
    assert!(
        lines[2].starts_with("post   circle   center (2.0000, 2.0000), radius 0.0500"),
        "{out}"
    );
    assert!(
        lines[3].starts_with("shelf  polygon  4 points: (-2.0000, 1.5000)"),
        "{out}"
    );
    // `--json` prints what `world set` reads back.
    let (code, out, _) = snakectl(&addr, &["world", "--json"]);
    assert_eq!(code, 0);
    let printed: Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(printed["obstacles"], json!([far_post(), far_shelf()]));
    let again = dir.path().join("again.json");
    std::fs::write(&again, &out).unwrap();
    let (code, _, err) = snakectl(&addr, &["world", "set", again.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.is_empty(),
        "the same radius and clearance: no note: {err}"
    );

    // TOML in the config's shape, other tables ignored.
    let toml_file = dir.path().join("w.toml");
    std::fs::write(
        &toml_file,
        "[control]\nrate_hz = 100.0\n\n[world]\nclearance_m = 0.25\n\n\
         [[world.obstacle]]\nid = \"pillar\"\ncircle = { center_m = [1.5, 1.5], radius_m = 0.04 }\n\n\
         [[world.obstacle]]\nid = \"ledge\"\n\
         polygon = { points_m = [[-1.6, 0.3], [-1.4, 0.3], [-1.4, 0.34], [-1.6, 0.34]] }\n",
    )
    .unwrap();
    let (code, out, err) = snakectl(&addr, &["world", "set", toml_file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("ok: set_world with 2 obstacles"), "{out}");
    assert!(err.contains("clearance_m = 0.25 is not sent"), "{err}");
    let w = c.ok(json!({"cmd": "world"}));
    assert_eq!(
        w["obstacles"],
        json!([
            circle("pillar", [1.5, 1.5], 0.04),
            polygon(
                "ledge",
                &[[-1.6, 0.3], [-1.4, 0.3], [-1.4, 0.34], [-1.6, 0.34]]
            )
        ])
    );
    assert_ne!(w["clearance_m"], json!(0.25));

    // Add and remove one.
    let (code, out, err) = snakectl(
        &addr,
        &["world", "add", "dot", "--circle", "-1.5", "-1.5", "0.05"],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("ok: added obstacle"), "{out}");
    let (code, _, err) = snakectl(
        &addr,
        &[
            "world",
            "add",
            "tri",
            "--polygon",
            "1.5",
            "-1",
            "1.7",
            "-1",
            "1.6",
            "-0.8",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = snakectl(
        &addr,
        &[
            "world",
            "add",
            "odd",
            "--polygon",
            "1",
            "2",
            "3",
            "4",
            "5",
            "6",
            "7",
        ],
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("7 numbers"), "{err}");
    let (code, _, err) = snakectl(&addr, &["world", "remove", "pillar"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        c.ok(json!({"cmd": "world"}))["obstacles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["id"].as_str().unwrap())
            .collect::<Vec<_>>(),
        ["ledge", "dot", "tri"]
    );
    assert_eq!(
        c.ok(json!({"cmd": "world"}))["obstacles"][2],
        polygon("tri", &[[1.5, -1.0], [1.7, -1.0], [1.6, -0.8]])
    );

    // Bad input is found before connecting (exit 2, the field named); the daemon's refusals
    // exit 1.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[[world.obstacle]]\nid = \"p\"\ncircle = { center_m = [1.5, 1.5], radius_m = 0 }\n",
    )
    .unwrap();
    let (code, _, err) = snakectl(&addr, &["world", "set", bad.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("world.obstacle[1].circle.radius_m"), "{err}");
    let (code, _, err) = snakectl(&addr, &["world", "remove", "nope"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("bad_arg") && err.contains("\"nope\""), "{err}");
    let (code, _, _) = snakectl(&addr, &["world", "clear"]);
    assert_eq!(code, 0);
    assert_eq!(c.ok(json!({"cmd": "world"}))["obstacles"], json!([]));
}
