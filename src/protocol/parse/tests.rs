//! Tests of request parsing: every code, the field each message names, and properties over
//! arbitrary input.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use proptest::prelude::{
    any, prop, prop_assert, prop_assert_eq, prop_assert_ne, prop_oneof, proptest, Just,
    TestCaseError,
};
use proptest::strategy::Strategy as _;
use serde_json::{json, Number};

use super::*;
use crate::protocol::COMMANDS;

const JOINTS: usize = 4;

fn ok(line: &str) -> Request {
    match parse(line.as_bytes(), JOINTS) {
        Ok(req) => req,
        Err((_, why)) => panic!("{line} was refused: {why}"),
    }
}

fn refused(line: &str) -> (Option<RequestId>, Rejection) {
    match parse(line.as_bytes(), JOINTS) {
        Ok(req) => panic!("{line} was accepted as {req:?}"),
        Err(err) => err,
    }
}

/// Refused with `code`, the message containing each of `words`.
fn refused_with(line: &str, code: Code, words: &[&str]) {
    let (_, why) = refused(line);
    assert_eq!(why.code, code, "{line}: {why}");
    for word in words {
        assert!(why.message.contains(word), "{line}: {why} lacks {word:?}");
    }
}

#[test]
fn every_command_parses() {
    let cases = [
        (r#"{"cmd":"describe"}"#, Cmd::Describe),
        (r#"{"cmd":"status"}"#, Cmd::Status),
        (
            r#"{"cmd":"goto","target":[0.1,-0.2]}"#,
            Cmd::Goto {
                target: [0.1, -0.2],
                speed: None,
            },
        ),
        (
            r#"{"cmd":"goto","target":[1,2],"speed":0.05}"#,
            Cmd::Goto {
                target: [1.0, 2.0],
                speed: Some(0.05),
            },
        ),
        (
            r#"{"cmd":"goto","target":[1,2],"speed":null}"#,
            Cmd::Goto {
                target: [1.0, 2.0],
                speed: None,
            },
        ),
        (
            r#"{"cmd":"reach","target":[-0.3,0.45]}"#,
            Cmd::Reach {
                target: [-0.3, 0.45],
            },
        ),
        (
            r#"{"cmd":"goto_joints","theta":[0,0.5,-0.5,1]}"#,
            Cmd::GotoJoints {
                theta: vec![0.0, 0.5, -0.5, 1.0],
            },
        ),
        (
            r#"{"cmd":"path","points":[[0,1],[2,3]],"speed":1}"#,
            Cmd::Path {
                points: vec![[0.0, 1.0], [2.0, 3.0]],
                speed: Some(1.0),
            },
        ),
        (
            r#"{"cmd":"velocity","v":[0.01,0]}"#,
            Cmd::Velocity { v: [0.01, 0.0] },
        ),
        (
            r#"{"cmd":"jog","joint":4,"rad_s":-0.3}"#,
            Cmd::Jog {
                joint: 4,
                rad_s: -0.3,
            },
        ),
        // As an encoder that holds every number as a double writes it.
        (
            r#"{"cmd":"jog","joint":4.0,"rad_s":-0.3}"#,
            Cmd::Jog {
                joint: 4,
                rad_s: -0.3,
            },
        ),
        (r#"{"cmd":"stop"}"#, Cmd::Stop),
        (r#"{"cmd":"estop"}"#, Cmd::Estop),
        (r#"{"cmd":"reset"}"#, Cmd::Reset),
        (r#"{"cmd":"home"}"#, Cmd::Home),
        (
            r#"{"cmd":"strategy","name":"sequential"}"#,
            Cmd::Strategy {
                name: Strategy::Sequential,
            },
        ),
        (
            r#"{"cmd":"strategy","name":"overall"}"#,
            Cmd::Strategy {
                name: Strategy::Overall,
            },
        ),
        (
            r#"{"cmd":"subscribe","rate_hz":20}"#,
            Cmd::Subscribe { rate_hz: 20.0 },
        ),
        (r#"{"cmd":"unsubscribe"}"#, Cmd::Unsubscribe),
        (r#"{"cmd":"reset_stats"}"#, Cmd::ResetStats),
        (r#"{"cmd":"take_control"}"#, Cmd::TakeControl),
        (r#"{"cmd":"release"}"#, Cmd::Release),
        (
            r#"{"cmd":"auth","token":"s3cret \u00e9"}"#,
            Cmd::Auth {
                token: "s3cret é".into(),
            },
        ),
        (
            r#"{"cmd":"auth","token":""}"#,
            Cmd::Auth { token: "".into() },
        ),
        (r#"{"cmd":"torque","on":true}"#, Cmd::Torque { on: true }),
        (r#"{"cmd":"torque","on":false}"#, Cmd::Torque { on: false }),
        (r#"{"cmd":"reboot"}"#, Cmd::Reboot { ids: None }),
        (r#"{"cmd":"reboot","ids":null}"#, Cmd::Reboot { ids: None }),
        (
            r#"{"cmd":"reboot","ids":[3,0,252]}"#,
            Cmd::Reboot {
                ids: Some(vec![3, 0, 252]),
            },
        ),
    ];
    for (line, cmd) in cases {
        assert_eq!(ok(line), Request { id: None, cmd }, "{line}");
    }
    let mut named: Vec<&str> = COMMANDS.to_vec();
    named.sort_unstable();
    named.dedup();
    assert_eq!(named.len(), COMMANDS.len());
}

#[test]
fn ids_of_any_kind_are_kept_and_null_is_none() {
    for id in [
        json!(7),
        json!(-1.5),
        json!("a b"),
        json!({"k": [1, 2]}),
        json!([]),
    ] {
        let line = json!({"cmd": "status", "id": id}).to_string();
        assert_eq!(ok(&line).id.as_deref(), Some(&id));
    }
    assert_eq!(ok(r#"{"cmd":"status","id":null}"#).id, None);
}

#[test]
fn the_id_is_echoed_when_the_rest_is_bad() {
    let (id, why) = refused(r#"{"id":"q1","cmd":"nope"}"#);
    assert_eq!(why.code, Code::UnknownCmd);
    assert_eq!(id.as_deref(), Some(&json!("q1")));
    let (id, why) = refused(r#"{"id":{"seq":3},"cmd":"goto","target":[1]}"#);
    assert_eq!(why.code, Code::BadArg);
    assert_eq!(id.as_deref(), Some(&json!({"seq": 3})));
    let (id, _) = refused(r#"{"id":5}"#);
    assert_eq!(id.as_deref(), Some(&json!(5)));
}

#[test]
fn bad_json_for_text_that_is_not_an_object() {
    for line in [
        "",
        "{",
        "goto",
        r#"{"cmd":"status",}"#,
        "[1,2]",
        "17",
        r#""status""#,
        "null",
    ] {
        let (id, why) = refused(line);
        assert_eq!(why.code, Code::BadJson, "{line}: {why}");
        assert_eq!(id, None);
    }
    let (_, why) = parse(b"{\"cmd\":\"st\xffatus\"}", JOINTS).unwrap_err();
    assert_eq!(why.code, Code::BadJson);
}

#[test]
fn bad_json_for_a_number_json_cannot_hold() {
    refused_with(
        r#"{"cmd":"goto","id":1,"target":[1e999,0]}"#,
        Code::BadJson,
        &["out of range"],
    );
    refused_with(
        r#"{"cmd":"subscribe","rate_hz":-1e400}"#,
        Code::BadJson,
        &[],
    );
}

#[test]
fn a_key_given_twice_is_bad_json_naming_it_at_any_depth() {
    let cases = [
        (
            r#"{"cmd":"goto","target":[0.1,0.2],"speed":0.01,"speed":5}"#,
            "\"speed\"",
        ),
        (r#"{"cmd":"status","cmd":"estop"}"#, "\"cmd\""),
        (r#"{"id":1,"cmd":"status","id":2}"#, "\"id\""),
        (r#"{"id":{"seq":1,"seq":2},"cmd":"status"}"#, "\"seq\""),
        (
            r#"{"cmd":"goto","target":[{"x":1,"y":2,"x":3},0]}"#,
            "\"x\"",
        ),
        (r#"{"cmd":"status","params":{"a":{"b":1,"b":1}}}"#, "\"b\""),
    ];
    for (line, key) in cases {
        let (id, why) = refused(line);
        assert_eq!(why.code, Code::BadJson, "{line}: {why}");
        assert!(why.message.contains("duplicate key"), "{line}: {why}");
        assert!(why.message.contains(key), "{line}: {why} lacks {key}");
        assert_eq!(id, None, "{line}");
    }
    // Equal keys in different objects are no duplicates.
    let req = ok(r#"{"id":{"x":1,"y":{"x":2}},"cmd":"goto","target":[0.1,0.2]}"#);
    assert_eq!(req.id.as_deref(), Some(&json!({"x": 1, "y": {"x": 2}})));
    // A key differing only in case, or escaped differently but equal, is told apart or not
    // as JSON says: "sp\u0065ed" is "speed".
    refused_with(
        r#"{"cmd":"goto","target":[0,0],"speed":1,"sp\u0065ed":2}"#,
        Code::BadJson,
        &["duplicate key", "\"speed\""],
    );
    refused_with(
        r#"{"cmd":"goto","target":[0,0],"speed":1,"Speed":2}"#,
        Code::BadArg,
        &["`Speed`"],
    );
}

/// The longest path the parser takes fits in one request line, written compactly (as
/// `request_line` writes it) or with a space after every separator, every coordinate at full
/// precision and as long as a double gets.
#[test]
fn the_longest_path_fits_in_one_line() {
    let widest = [
        -1.234_567_890_123_456_7e-300,
        -0.000_012_345_678_901_234_567,
    ];
    for x in widest {
        assert_eq!(serde_json::to_string(&x).unwrap().len(), 24, "{x}");
    }
    let points: Vec<[f64; 2]> = (0..MAX_PATH_POINTS)
        .map(|i| [widest[i % 2], widest[(i + 1) % 2]])
        .collect();
    let cmd = Cmd::Path {
        points: points.clone(),
        // The widest speed allowed (at least MIN_SPEED_M_S).
        speed: Some(-widest[1]),
    };
    let compact = crate::protocol::request_line(Some(&json!(u64::MAX)), &cmd);
    let spaced = compact.replace(',', ", ").replace(':', ": ");
    for line in [compact.trim_end(), spaced.trim_end()] {
        assert!(
            line.len() <= crate::protocol::MAX_LINE,
            "{} bytes over {}",
            line.len(),
            crate::protocol::MAX_LINE
        );
        assert!(matches!(
            ok(line).cmd,
            Cmd::Path { points: ref got, .. } if *got == points
        ));
    }
}

#[test]
fn unknown_cmd_lists_the_known_ones() {
    let (_, why) = refused(r#"{"cmd":"fly"}"#);
    assert_eq!(why.code, Code::UnknownCmd);
    assert!(why.message.contains("\"fly\""), "{why}");
    for name in COMMANDS {
        assert!(why.message.contains(name), "{why} lacks {name}");
    }
    refused_with(r#"{"id":1}"#, Code::UnknownCmd, &["missing `cmd`"]);
    refused_with(r#"{"cmd":null}"#, Code::UnknownCmd, &["missing `cmd`"]);
    refused_with(r#"{"cmd":3}"#, Code::UnknownCmd, &["string", "3"]);
    refused_with(r#"{"cmd":"GOTO"}"#, Code::UnknownCmd, &["GOTO"]);
}

/// A huge number is shown short in the refusal, not as its 301 digits.
#[test]
fn a_huge_number_is_named_in_a_short_message() {
    for line in [
        r#"{"cmd":"goto","target":[1e300,0]}"#,
        r#"{"cmd":"add_obstacle","obstacle":{"id":"a","circle":{"center":[0,0],"radius":-1e300}}}"#,
    ] {
        let (_, why) = refused(line);
        assert_eq!(why.code, Code::BadArg, "{why}");
        assert!(why.message.contains("e300 is over"), "{why}");
        assert!(why.message.len() < 120, "{why}");
    }
    refused_with(
        r#"{"cmd":"goto","target":[0,2000000]}"#,
        Code::BadArg,
        &["`target[1]`: 2000000 is over 1000000 in magnitude"],
    );
}

#[test]
fn bad_arg_names_the_field_and_the_value() {
    let cases: &[(&str, &[&str])] = &[
        (r#"{"cmd":"goto"}"#, &["`target`", "missing"]),
        (r#"{"cmd":"goto","target":null}"#, &["`target`", "missing"]),
        (
            r#"{"cmd":"goto","target":[0,"a"]}"#,
            &["`target[1]`", "\"a\""],
        ),
        (
            r#"{"cmd":"goto","target":[0,1,2]}"#,
            &["`target`", "2", "3"],
        ),
        (
            r#"{"cmd":"goto","target":"here"}"#,
            &["`target`", "\"here\""],
        ),
        (
            r#"{"cmd":"goto","target":[2e6,0]}"#,
            &["`target[0]`", "2000000"],
        ),
        (
            r#"{"cmd":"goto","target":[0,-1000001]}"#,
            &["`target[1]`", "-1000001"],
        ),
        (
            r#"{"cmd":"goto","target":[0,0],"speed":0}"#,
            &["`speed`", "positive", "0"],
        ),
        (
            r#"{"cmd":"goto","target":[0,0],"speed":-2}"#,
            &["`speed`", "-2"],
        ),
        (
            r#"{"cmd":"path","points":[[0,0]],"speed":1e-12}"#,
            &["`speed`", "1e-12 m/s is below the least, 1e-6 m/s"],
        ),
        (
            r#"{"cmd":"goto","target":[0,0],"speed":true}"#,
            &["`speed`", "true"],
        ),
        (
            r#"{"cmd":"goto","target":[0,0],"sped":1}"#,
            &["`sped`", "unknown", "target, speed"],
        ),
        (
            r#"{"cmd":"goto_joints","theta":[0,0,0]}"#,
            &["`theta`", "4", "3"],
        ),
        (
            r#"{"cmd":"goto_joints","theta":[0,0,{},0]}"#,
            &["`theta[2]`", "{}"],
        ),
        (r#"{"cmd":"path","points":[]}"#, &["`points`", "0"]),
        (
            r#"{"cmd":"path","points":[[0,0],[1]]}"#,
            &["`points[1]`", "1"],
        ),
        (
            r#"{"cmd":"path","points":[[0,0],[1,[]]]}"#,
            &["`points[1][1]`", "[]"],
        ),
        (
            r#"{"cmd":"path","points":{"x":1}}"#,
            &["`points`", "{\"x\":1}"],
        ),
        (r#"{"cmd":"velocity","v":[0]}"#, &["`v`"]),
        (r#"{"cmd":"velocity","v":[1e7,0]}"#, &["`v[0]`", "10000000"]),
        (
            r#"{"cmd":"jog","joint":0,"rad_s":1}"#,
            &["`joint`", "0", "1..=4"],
        ),
        (
            r#"{"cmd":"jog","joint":5,"rad_s":1}"#,
            &["`joint`", "5", "1..=4"],
        ),
        (r#"{"cmd":"jog","joint":-1,"rad_s":1}"#, &["`joint`", "-1"]),
        (
            r#"{"cmd":"jog","joint":5.0,"rad_s":1}"#,
            &["`joint`", "5.0", "1..=4"],
        ),
        (
            r#"{"cmd":"jog","joint":-1.0,"rad_s":1}"#,
            &["`joint`", "-1.0"],
        ),
        (
            r#"{"cmd":"jog","joint":1e300,"rad_s":1}"#,
            &["`joint`", "out of range 1..=4"],
        ),
        (
            r#"{"cmd":"jog","joint":1.5,"rad_s":1}"#,
            &["`joint`", "1.5", "integer"],
        ),
        (
            r#"{"cmd":"jog","joint":"2","rad_s":1}"#,
            &["`joint`", "\"2\""],
        ),
        (r#"{"cmd":"jog","joint":2}"#, &["`rad_s`", "missing"]),
        (
            r#"{"cmd":"strategy","name":"fast"}"#,
            &["`name`", "\"fast\"", "overall"],
        ),
        (
            r#"{"cmd":"subscribe","rate_hz":0}"#,
            &["`rate_hz`", "positive"],
        ),
        (r#"{"cmd":"subscribe","rate_hz":-5}"#, &["`rate_hz`", "-5"]),
        (
            r#"{"cmd":"subscribe","rate_hz":"10"}"#,
            &["`rate_hz`", "\"10\""],
        ),
        (r#"{"cmd":"subscribe","rate_hz":1e7}"#, &["`rate_hz`"]),
        (r#"{"cmd":"stop","now":true}"#, &["`now`", "no arguments"]),
        (
            r#"{"cmd":"take_control","force":true}"#,
            &["`force`", "no arguments"],
        ),
        (r#"{"cmd":"release","x":1}"#, &["`x`", "no arguments"]),
        (r#"{"cmd":"auth"}"#, &["`token`", "missing"]),
        (r#"{"cmd":"auth","token":17}"#, &["`token`", "string", "17"]),
        (
            r#"{"cmd":"auth","token":"t","user":"me"}"#,
            &["`user`", "unknown", "token"],
        ),
        (r#"{"cmd":"torque"}"#, &["`on`", "missing"]),
        (
            r#"{"cmd":"torque","on":1}"#,
            &["`on`", "true or false", "1"],
        ),
        (r#"{"cmd":"torque","on":"off"}"#, &["`on`", "\"off\""]),
        (r#"{"cmd":"reboot","ids":[]}"#, &["`ids`", "1 to 253", "0"]),
        (r#"{"cmd":"reboot","ids":3}"#, &["`ids`", "array", "3"]),
        (
            r#"{"cmd":"reboot","ids":[1,253]}"#,
            &["`ids[1]`", "253", "0..=252"],
        ),
        (
            r#"{"cmd":"reboot","ids":[-1]}"#,
            &["`ids[0]`", "-1", "0..=252"],
        ),
        (
            r#"{"cmd":"reboot","ids":[1,2.5]}"#,
            &["`ids[1]`", "2.5", "integer"],
        ),
        (r#"{"cmd":"reboot","ids":["1"]}"#, &["`ids[0]`", "\"1\""]),
        (
            r#"{"cmd":"reboot","ids":[4,5,4]}"#,
            &["`ids[2]`", "4", "twice"],
        ),
        (
            r#"{"cmd":"reboot","ids":[1e300]}"#,
            &["`ids[0]`", "integer"],
        ),
    ];
    for (line, words) in cases {
        refused_with(line, Code::BadArg, words);
    }
}

#[test]
fn path_length_is_bounded() {
    let points = |n: usize| json!({"cmd": "path", "points": vec![[0.0, 0.0]; n]}).to_string();
    assert!(matches!(ok(&points(1)).cmd, Cmd::Path { ref points, .. } if points.len() == 1));
    assert!(matches!(
        ok(&points(MAX_PATH_POINTS)).cmd,
        Cmd::Path { ref points, .. } if points.len() == MAX_PATH_POINTS
    ));
    refused_with(
        &points(MAX_PATH_POINTS + 1),
        Code::BadArg,
        &["`points`", "10001"],
    );
}

#[test]
fn reboot_ids_are_bounded_and_distinct() {
    let all: Vec<u8> = (0..=252).collect();
    let line = json!({"cmd": "reboot", "ids": all}).to_string();
    assert_eq!(ok(&line).cmd, Cmd::Reboot { ids: Some(all) });
    let mut over: Vec<u32> = (0..=252).collect();
    over.push(7);
    let line = json!({"cmd": "reboot", "ids": over}).to_string();
    refused_with(&line, Code::BadArg, &["`ids`", "254"]);
    let line = json!({"cmd": "reboot", "ids": [u64::MAX]}).to_string();
    refused_with(&line, Code::BadArg, &["`ids[0]`", "out of range"]);
}

#[test]
fn the_limit_itself_is_accepted() {
    let req = ok(r#"{"cmd":"goto","target":[1e6,-1e6]}"#);
    assert_eq!(
        req.cmd,
        Cmd::Goto {
            target: [MAX_ARG, -MAX_ARG],
            speed: None
        }
    );
}

#[test]
fn a_long_value_is_cut_short_in_the_message() {
    let long = "x".repeat(10_000);
    let line = json!({"cmd": "strategy", "name": long}).to_string();
    let (_, why) = refused(&line);
    assert_eq!(why.code, Code::BadArg);
    assert!(why.message.len() < 200, "{} bytes", why.message.len());
    let line = json!({"cmd": "strategy", "name": "é".repeat(100)}).to_string();
    assert_eq!(refused(&line).1.code, Code::BadArg);
}

fn json_value() -> impl proptest::strategy::Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        any::<f64>().prop_filter_map("finite", |x| Number::from_f64(x).map(Value::Number)),
        (-2e6..2e6f64).prop_filter_map("finite", |x| Number::from_f64(x).map(Value::Number)),
        "[a-z_]{0,12}".prop_map(Value::String),
    ];
    leaf.prop_recursive(4, 48, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_]{0,8}", inner, 0..6)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// An object with a known `cmd` and keys a request may carry, holding arbitrary values.
fn request_like() -> impl proptest::strategy::Strategy<Value = (String, Value)> {
    let keys = prop::sample::select(vec![
        "target",
        "speed",
        "theta",
        "points",
        "v",
        "joint",
        "rad_s",
        "name",
        "rate_hz",
        "id",
        "extra",
        "token",
        "on",
        "ids",
        "obstacles",
        "obstacle",
    ]);
    (
        prop::sample::select(COMMANDS.to_vec()),
        prop::collection::btree_map(keys, json_value(), 0..4),
    )
        .prop_map(|(cmd, args)| {
            let mut map: Map<String, Value> =
                args.into_iter().map(|(k, v)| (k.to_owned(), v)).collect();
            map.insert("cmd".into(), json!(cmd));
            (cmd.to_owned(), Value::Object(map))
        })
}

fn number_arg() -> impl proptest::strategy::Strategy<Value = f64> {
    prop_oneof![
        -MAX_ARG..=MAX_ARG,
        Just(0.0),
        Just(MAX_ARG),
        Just(-MAX_ARG),
        -1.0..1.0f64
    ]
}

fn positive_arg() -> impl proptest::strategy::Strategy<Value = f64> {
    prop_oneof![f64::MIN_POSITIVE..=MAX_ARG, Just(MAX_ARG), 1e-9..10.0f64]
}

fn valid_cmd(joints: usize) -> impl proptest::strategy::Strategy<Value = Cmd> {
    let point = || [number_arg(), number_arg()];
    prop_oneof![
        Just(Cmd::Describe),
        Just(Cmd::Status),
        (point(), prop::option::of(positive_arg()))
            .prop_map(|(target, speed)| Cmd::Goto { target, speed }),
        prop::collection::vec(number_arg(), joints).prop_map(|theta| Cmd::GotoJoints { theta }),
        point().prop_map(|target| Cmd::Reach { target }),
        (
            prop::collection::vec(point(), 1..20),
            prop::option::of(positive_arg())
        )
            .prop_map(|(points, speed)| Cmd::Path { points, speed }),
        point().prop_map(|v| Cmd::Velocity { v }),
        (1..=joints, number_arg()).prop_map(|(joint, rad_s)| Cmd::Jog { joint, rad_s }),
        Just(Cmd::Stop),
        Just(Cmd::Estop),
        Just(Cmd::Reset),
        Just(Cmd::Home),
        prop::sample::select(vec![Strategy::Overall, Strategy::Sequential])
            .prop_map(|name| Cmd::Strategy { name }),
        positive_arg().prop_map(|rate_hz| Cmd::Subscribe { rate_hz }),
        Just(Cmd::Unsubscribe),
        Just(Cmd::ResetStats),
        Just(Cmd::TakeControl),
        Just(Cmd::Release),
        any::<String>().prop_map(|token| Cmd::Auth { token }),
        any::<bool>().prop_map(|on| Cmd::Torque { on }),
        prop::option::of(
            prop::sample::subsequence((0..=252u8).collect::<Vec<_>>(), 1..=253).prop_shuffle()
        )
        .prop_map(|ids| Cmd::Reboot { ids }),
        Just(Cmd::World),
        obstacles().prop_map(|obstacles| Cmd::SetWorld { obstacles }),
        obstacle().prop_map(|o| Cmd::AddObstacle {
            obstacle: CheckedObstacle::new(o).unwrap()
        }),
        any::<String>().prop_map(|id| Cmd::RemoveObstacle { id }),
    ]
}

/// An obstacle as the parser takes it: any id, a circle or a polygon of any numbers in range
/// (whether it makes a world is the loop's to say).
/// An obstacle a world takes: an id without control characters, a circle of positive radius
/// or a convex polygon (a regular one, turned), numbers anywhere the wire allows.
fn obstacle() -> impl proptest::strategy::Strategy<Value = crate::world::Obstacle> {
    use crate::chain::Vec2;
    use crate::world::{Obstacle, Shape};
    let circle =
        (number_arg(), number_arg(), positive_arg()).prop_map(|(x, y, radius_m)| Shape::Circle {
            center: Vec2::new(x, y),
            radius_m,
        });
    let polygon = (
        -1e5..1e5f64,
        -1e5..1e5f64,
        1e-3..1e3f64,
        3..9usize,
        0.0..std::f64::consts::PI,
    )
        .prop_map(|(x, y, r, n, turn)| Shape::Polygon {
            points: (0..n)
                .map(|k| {
                    let a = turn + std::f64::consts::TAU * k as f64 / n as f64;
                    Vec2::new(x + r * a.cos(), y + r * a.sin())
                })
                .collect(),
        });
    ("[^\\p{Cc}]{1,40}", prop_oneof![circle, polygon])
        .prop_map(|(id, shape)| Obstacle { id, shape })
}

/// Up to four obstacles with ids of their own (each led by its place).
fn obstacles() -> impl proptest::strategy::Strategy<Value = crate::world::Obstacles> {
    prop::collection::vec(obstacle(), 0..5).prop_map(|mut list| {
        for (k, o) in list.iter_mut().enumerate() {
            o.id = format!("{k}:{}", o.id);
        }
        crate::world::Obstacles::new(list).unwrap()
    })
}

/// The same obstacles, numbers within an ulp (see [`close`]).
fn same_obstacles(a: &[crate::world::Obstacle], b: &[crate::world::Obstacle]) -> bool {
    use crate::world::Shape;
    let p = |a: &crate::chain::Vec2, b: &crate::chain::Vec2| close(a.x, b.x) && close(a.y, b.y);
    a.len() == b.len()
        && a.iter().zip(b).all(|(a, b)| {
            a.id == b.id
                && match (&a.shape, &b.shape) {
                    (
                        Shape::Circle {
                            center: c,
                            radius_m: r,
                        },
                        Shape::Circle {
                            center: d,
                            radius_m: s,
                        },
                    ) => p(c, d) && close(*r, *s),
                    (Shape::Polygon { points: u }, Shape::Polygon { points: v }) => {
                        u.len() == v.len() && u.iter().zip(v).all(|(u, v)| p(u, v))
                    }
                    _ => false,
                }
        })
}

/// serde_json reads floats back to within an ulp without its `float_roundtrip` feature
/// (relative, or absolute among the subnormals).
fn close(a: f64, b: f64) -> bool {
    let d = (a - b).abs();
    a == b || d <= 2.0 * f64::EPSILON * a.abs().max(b.abs()) || d <= f64::MIN_POSITIVE
}

fn same_cmd(a: &Cmd, b: &Cmd) -> bool {
    let all =
        |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y));
    let opt = |a: &Option<f64>, b: &Option<f64>| match (a, b) {
        (Some(a), Some(b)) => close(*a, *b),
        (None, None) => true,
        _ => false,
    };
    match (a, b) {
        (
            Cmd::Goto {
                target: t,
                speed: s,
            },
            Cmd::Goto {
                target: u,
                speed: r,
            },
        ) => all(t, u) && opt(s, r),
        (Cmd::GotoJoints { theta: t }, Cmd::GotoJoints { theta: u }) => all(t, u),
        (Cmd::Reach { target: t }, Cmd::Reach { target: u }) => all(t, u),
        (
            Cmd::Path {
                points: p,
                speed: s,
            },
            Cmd::Path {
                points: q,
                speed: r,
            },
        ) => p.len() == q.len() && p.iter().zip(q).all(|(p, q)| all(p, q)) && opt(s, r),
        (Cmd::Velocity { v }, Cmd::Velocity { v: w }) => all(v, w),
        (Cmd::Jog { joint: j, rad_s: r }, Cmd::Jog { joint: k, rad_s: s }) => {
            j == k && close(*r, *s)
        }
        (Cmd::Subscribe { rate_hz: r }, Cmd::Subscribe { rate_hz: s }) => close(*r, *s),
        (Cmd::SetWorld { obstacles: o }, Cmd::SetWorld { obstacles: q }) => same_obstacles(o, q),
        (Cmd::AddObstacle { obstacle: o }, Cmd::AddObstacle { obstacle: q }) => {
            same_obstacles(std::slice::from_ref(o), std::slice::from_ref(q))
        }
        _ => a == b,
    }
}

/// Equal JSON, numbers within an ulp (see [`close`]).
fn same_json(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) if x.is_f64() || y.is_f64() => {
            matches!((x.as_f64(), y.as_f64()), (Some(x), Some(y)) if close(x, y))
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same_json(x, y))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .zip(y)
                    .all(|((k, x), (l, y))| k == l && same_json(x, y))
        }
        _ => a == b,
    }
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        let _ = parse(&bytes, JOINTS);
    }

    #[test]
    fn arbitrary_json_never_panics_and_objects_keep_their_id(value in json_value(), joints in 0..6usize) {
        let bytes = serde_json::to_vec(&value).unwrap();
        match parse(&bytes, joints) {
            Ok(req) => prop_assert!(value.get("cmd").is_some(), "{value} accepted as {req:?}"),
            Err((id, why)) => {
                if !value.is_object() {
                    prop_assert_eq!(why.code, Code::BadJson);
                    prop_assert_eq!(id, None);
                } else {
                    let sent = value.get("id").filter(|id| !id.is_null());
                    prop_assert_eq!(id.as_deref(), sent);
                    prop_assert_ne!(why.code, Code::BadJson);
                }
            }
        }
    }

    #[test]
    fn request_shaped_json_is_that_command_or_a_bad_arg((cmd, value) in request_like(), joints in 0..6usize) {
        let bytes = serde_json::to_vec(&value).unwrap();
        match parse(&bytes, joints) {
            Ok(req) => prop_assert_eq!(req.cmd.name(), cmd.as_str()),
            Err((_, why)) => {
                prop_assert_eq!(why.code, Code::BadArg, "{}", why);
                prop_assert!(why.message.starts_with('`'), "{}", why);
            }
        }
    }

    #[test]
    fn valid_commands_round_trip(
        (joints, cmd) in (1..8usize).prop_flat_map(|n| (Just(n), valid_cmd(n))),
        id in prop::option::of(json_value().prop_filter("not null", |v| !v.is_null())),
    ) {
        let line = crate::protocol::request_line(id.as_ref(), &cmd);
        prop_assert!(line.ends_with('\n'));
        let req = parse(line.trim_end().as_bytes(), joints)
            .map_err(|(_, why)| TestCaseError::fail(format!("{line}: {why}")))?;
        prop_assert!(same_cmd(&req.cmd, &cmd), "{:?} read back as {:?}", cmd, req.cmd);
        match (req.id.as_deref(), id.as_ref()) {
            (Some(back), Some(sent)) => prop_assert!(same_json(back, sent), "{} read back as {}", sent, back),
            (back, sent) => prop_assert_eq!(back, sent),
        }
    }
}

mod world {
    use super::*;
    use crate::chain::Vec2;
    use crate::protocol::world_rejection;
    use crate::world::{Obstacle, Shape, World};

    fn post() -> Obstacle {
        Obstacle {
            id: "post".into(),
            shape: Shape::Circle {
                center: Vec2::new(0.15, 0.6),
                radius_m: 0.04,
            },
        }
    }

    fn shelf() -> Obstacle {
        Obstacle {
            id: "shelf".into(),
            shape: Shape::Polygon {
                points: vec![
                    Vec2::new(-0.6, 0.3),
                    Vec2::new(-0.4, 0.3),
                    Vec2::new(-0.4, 0.34),
                ],
            },
        }
    }

    const POST: &str = r#"{"id": "post", "circle": {"center": [0.15, 0.6], "radius": 0.04}}"#;
    const SHELF: &str =
        r#"{"id": "shelf", "polygon": {"points": [[-0.6, 0.3], [-0.4, 0.3], [-0.4, 0.34]]}}"#;

    #[test]
    fn every_world_command_and_shape_parses() {
        assert_eq!(ok(r#"{"cmd": "world"}"#).cmd, Cmd::World);
        assert_eq!(
            ok(&format!(
                r#"{{"cmd": "set_world", "obstacles": [{POST}, {SHELF}]}}"#
            ))
            .cmd,
            Cmd::SetWorld {
                obstacles: Obstacles::new(vec![post(), shelf()]).unwrap()
            }
        );
        assert_eq!(
            ok(r#"{"cmd": "set_world", "obstacles": []}"#).cmd,
            Cmd::SetWorld {
                obstacles: Obstacles::default()
            }
        );
        assert_eq!(
            ok(&format!(
                r#"{{"cmd": "add_obstacle", "obstacle": {SHELF}}}"#
            ))
            .cmd,
            Cmd::AddObstacle {
                obstacle: CheckedObstacle::new(shelf()).unwrap()
            }
        );
        // The request's `id` is its own; the obstacle's id is `obstacle`.
        let req = ok(r#"{"cmd": "remove_obstacle", "id": 3, "obstacle": "post"}"#);
        assert_eq!(req.cmd, Cmd::RemoveObstacle { id: "post".into() });
        assert_eq!(req.id.as_deref(), Some(&json!(3)));
        // An optional shape given as null counts as absent.
        let line = r#"{"cmd": "add_obstacle", "obstacle": {"id": "p", "polygon": null,
            "circle": {"center": [0, 0], "radius": 1}}}"#;
        assert!(matches!(ok(line).cmd, Cmd::AddObstacle { .. }));
    }

    #[test]
    fn a_bad_obstacle_is_bad_arg_naming_its_field() {
        let set = |obstacle: &str| {
            format!(r#"{{"cmd": "set_world", "obstacles": [{POST}, {obstacle}]}}"#)
        };
        let add = |obstacle: &str| format!(r#"{{"cmd": "add_obstacle", "obstacle": {obstacle}}}"#);
        let cases: &[(&str, &str)] = &[
            // Not an object, no id, an id of the wrong type.
            ("7", "`obstacles[1]`: expected an object, got 7"),
            (
                r#"{"circle": {"center": [0, 0], "radius": 1}}"#,
                "`obstacles[1].id`: missing",
            ),
            (
                r#"{"id": 5, "circle": {"center": [0, 0], "radius": 1}}"#,
                "`obstacles[1].id`: expected a string",
            ),
            // The shape: neither, both, unknown keys at each level.
            (r#"{"id": "a"}"#, "`obstacles[1]`: missing its shape"),
            (
                r#"{"id": "a", "circle": {"center": [0, 0], "radius": 1}, "polygon": {"points": []}}"#,
                "`obstacles[1]`: give `circle` or `polygon`, not both",
            ),
            (
                r#"{"id": "a", "disc": {}}"#,
                "`obstacles[1].disc`: unknown key",
            ),
            (
                r#"{"id": "a", "circle": {"centre": [0, 0], "radius": 1}}"#,
                "`obstacles[1].circle.centre`: unknown key",
            ),
            (
                r#"{"id": "a", "polygon": {"points": [[0, 0], [1, 0], [0, 1]], "closed": true}}"#,
                "`obstacles[1].polygon.closed`: unknown key",
            ),
            (
                r#"{"id": "a", "circle": 3}"#,
                "`obstacles[1].circle`: expected an object",
            ),
            // A circle's fields.
            (
                r#"{"id": "a", "circle": {"radius": 1}}"#,
                "`obstacles[1].circle.center`: missing",
            ),
            (
                r#"{"id": "a", "circle": {"center": [0, 0]}}"#,
                "`obstacles[1].circle.radius`: missing",
            ),
            (
                r#"{"id": "a", "circle": {"center": [0], "radius": 1}}"#,
                "`obstacles[1].circle.center`: expected 2 entries",
            ),
            (
                r#"{"id": "a", "circle": {"center": [0, "y"], "radius": 1}}"#,
                "`obstacles[1].circle.center[1]`: expected a number",
            ),
            (
                r#"{"id": "a", "circle": {"center": [0, 2e6], "radius": 1}}"#,
                "`obstacles[1].circle.center[1]`: 2000000 is over",
            ),
            (
                r#"{"id": "a", "circle": {"center": [0, 0], "radius": "1"}}"#,
                "`obstacles[1].circle.radius`: expected a number",
            ),
            // A polygon's fields.
            (
                r#"{"id": "a", "polygon": {}}"#,
                "`obstacles[1].polygon.points`: missing",
            ),
            (
                r#"{"id": "a", "polygon": {"points": 4}}"#,
                "`obstacles[1].polygon.points`: expected an array",
            ),
            (
                r#"{"id": "a", "polygon": {"points": [[0, 0], [1, 0], [0, -1e7]]}}"#,
                "`obstacles[1].polygon.points[2][1]`: -10000000 is over",
            ),
            (
                r#"{"id": "a", "polygon": {"points": [[0, 0], [1, 0], [0, 1, 2]]}}"#,
                "`obstacles[1].polygon.points[2]`: expected 2 entries",
            ),
            // Read whole, and not a shape: refused where the line is read, as the loop would.
            (
                r#"{"id": "a", "circle": {"center": [0, 0], "radius": 0}}"#,
                "`obstacles[1].circle.radius`: 0 m must be positive",
            ),
            (
                r#"{"id": "a", "polygon": {"points": [[0, 0], [1, 0]]}}"#,
                "`obstacles[1].polygon.points`: 2 points, a polygon needs at least 3",
            ),
            (
                r#"{"id": "a", "polygon": {"points": [[0, 0], [1, 1], [1, 0], [0, 1]]}}"#,
                "`obstacles[1].polygon.points`: edges 0 and 2 touch or cross",
            ),
            (
                r#"{"id": "", "circle": {"center": [0, 0], "radius": 1}}"#,
                "`obstacles[1].id`: an obstacle needs a non-empty id",
            ),
        ];
        for (obstacle, message) in cases {
            let (_, why) = refused(&set(obstacle));
            assert_eq!(why.code, Code::BadArg, "{obstacle}: {why}");
            assert!(why.message.starts_with(message), "{obstacle}: {why}");
            let (_, why) = refused(&add(obstacle));
            let message = message.replacen("obstacles[1]", "obstacle", 1);
            assert!(why.message.starts_with(&message), "{obstacle}: {why}");
        }
        // Two obstacles of one id make no world; one alone is checked without the world's.
        let twice = set(r#"{"id": "post", "circle": {"center": [1, 1], "radius": 0.1}}"#);
        refused_with(
            &twice,
            Code::BadArg,
            &["`obstacles[1].id`: id \"post\" is already used by obstacles[0]"],
        );
        assert!(matches!(
            ok(&add(POST)).cmd,
            Cmd::AddObstacle { obstacle } if obstacle.id == "post"
        ));
        refused_with(
            r#"{"cmd": "set_world"}"#,
            Code::BadArg,
            &["`obstacles`: missing"],
        );
        refused_with(
            r#"{"cmd": "set_world", "obstacles": {}}"#,
            Code::BadArg,
            &["`obstacles`: expected an array"],
        );
        refused_with(
            r#"{"cmd": "set_world", "obstacles": [], "link_radius_m": 1}"#,
            Code::BadArg,
            &["`link_radius_m`: unknown argument of set_world"],
        );
        refused_with(
            r#"{"cmd": "remove_obstacle", "obstacle": 4}"#,
            Code::BadArg,
            &["`obstacle`: expected a string"],
        );
        refused_with(
            r#"{"cmd": "remove_obstacle"}"#,
            Code::BadArg,
            &["`obstacle`: missing"],
        );
        refused_with(
            r#"{"cmd": "world", "obstacles": []}"#,
            Code::BadArg,
            &["`obstacles`: unknown argument of world"],
        );
    }

    /// What the parser lets through and the loop's [`World::new`] refuses, worded for the wire.
    #[test]
    fn a_world_that_is_not_one_is_refused_naming_the_field_as_the_request_spells_it() {
        let refusal = |obstacles: Vec<Obstacle>, added: Option<usize>| {
            let e = World::new(0.01, 0.005, obstacles).unwrap_err();
            world_rejection(&e, added)
        };
        let circle = |id: &str, r: f64| Obstacle {
            id: id.into(),
            shape: Shape::Circle {
                center: Vec2::new(1.0, 1.0),
                radius_m: r,
            },
        };
        let polygon = |id: &str, points: &[[f64; 2]]| Obstacle {
            id: id.into(),
            shape: Shape::Polygon {
                points: points.iter().map(|p| Vec2::new(p[0], p[1])).collect(),
            },
        };
        let cases = [
            (
                vec![post(), circle("a", 0.0)],
                None,
                "`obstacles[1].circle.radius`: 0 m must be positive",
            ),
            (
                vec![post(), circle("a", -1.0)],
                Some(1),
                "`obstacle.circle.radius`: -1 m must be positive",
            ),
            (
                vec![post(), circle("post", 1.0)],
                None,
                "`obstacles[1].id`: id \"post\" is already used by obstacles[0]",
            ),
            (
                vec![post(), circle("post", 1.0)],
                Some(1),
                "`obstacle.id`: id \"post\" is already used by obstacles[0]",
            ),
            (
                vec![circle("", 1.0)],
                None,
                "`obstacles[0].id`: an obstacle needs a non-empty id",
            ),
            (
                vec![polygon("p", &[[0.0, 0.0], [1.0, 0.0]])],
                None,
                "`obstacles[0].polygon.points`: 2 points, a polygon needs at least 3",
            ),
            (
                vec![
                    post(),
                    polygon("bow", &[[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]),
                ],
                None,
                "`obstacles[1].polygon.points`: edges 0 and 2 touch or cross",
            ),
            (
                vec![polygon(
                    "p",
                    &[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 0.0]],
                )],
                None,
                "`obstacles[0].polygon.points[3]`: point (1, 0) repeats points[1]",
            ),
            (
                (0..65).map(|i| circle(&format!("c{i}"), 0.1)).collect(),
                None,
                "`obstacles`: 65 obstacles, at most 64 allowed",
            ),
            (
                (0..65).map(|i| circle(&format!("c{i}"), 0.1)).collect(),
                Some(64),
                "`obstacle`: adding it would make 65 obstacles, at most 64 allowed",
            ),
            (
                vec![polygon(
                    "big",
                    &(0..1025)
                        .map(|k| {
                            let a = k as f64 / 1025.0 * std::f64::consts::TAU;
                            [a.cos(), a.sin()]
                        })
                        .collect::<Vec<_>>(),
                )],
                None,
                "`obstacles`: 1025 polygon points in all, at most 1024 allowed",
            ),
        ];
        for (obstacles, added, message) in cases {
            let why = refusal(obstacles, added);
            assert_eq!(why.code, Code::BadArg);
            assert!(why.message.starts_with(message), "{why}");
        }
    }
}
