//! Inputs that were once accepted and did harm, or changed a value silently: a device or FIFO
//! named as the file, a watchdog or silence budget the loop's own rate defeats, a removed key,
//! servo ids spelt twice, a later fault's errors, profile values beyond their register.

use super::*;

fn dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("snakectl-config-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_device_is_refused_unread_naming_the_path_and_what_it_is() {
    let err = Config::load("/dev/zero").unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, ConfigError::Read { .. }), "{msg}");
    assert!(msg.starts_with("/dev/zero: "), "{msg}");
    assert!(
        msg.contains("a character device, not a regular file"),
        "{msg}"
    );
    let msg = Config::load(dir()).unwrap_err().to_string();
    assert!(msg.contains("a directory, not a regular file"), "{msg}");
}

#[test]
fn a_fifo_is_refused_without_blocking() {
    let fifo = dir().join("config.toml");
    crate::textfile::make_fifo(&fifo);
    // On a thread, so that a load that blocks fails the test instead of hanging it.
    let (tx, rx) = std::sync::mpsc::channel();
    let path = fifo.clone();
    std::thread::spawn(move || {
        let _ = tx.send(Config::load(&path).map(|_| ()).map_err(|e| e.to_string()));
    });
    let msg = rx
        .recv_timeout(std::time::Duration::from_secs(10))
        .expect("loading a FIFO blocked")
        .unwrap_err();
    assert!(msg.starts_with(&fifo.display().to_string()), "{msg}");
    assert!(
        msg.contains("a FIFO (named pipe), not a regular file"),
        "{msg}"
    );
}

#[test]
fn a_file_beyond_one_mebibyte_is_refused_saying_the_limit() {
    let big = dir().join("big.toml");
    let text = base_text();
    let pad = "#".repeat(crate::textfile::MAX_TEXT_BYTES as usize - text.len() - 1) + "\n";
    std::fs::write(&big, format!("{text}{pad}")).unwrap();
    assert!(Config::load(&big).is_ok(), "exactly 1 MiB loads");
    std::fs::write(&big, format!("{text}#{pad}")).unwrap();
    let msg = Config::load(&big).unwrap_err().to_string();
    assert!(msg.starts_with(&big.display().to_string()), "{msg}");
    assert!(msg.contains("larger than 1048576 bytes"), "{msg}");
}

#[test]
fn a_watchdog_that_does_not_cover_two_ticks_is_refused_naming_both_fields() {
    // The default 100 ms at 5 Hz (a tick of 200 ms): the servos' watchdog fired every tick.
    let text = with("rate_hz = 100.0", "rate_hz = 5.0\nmax_silence_ms = 1000")
        .replacen("publish_hz = 25.0\n", "", 1)
        .replacen("watchdog_ms = 100\n", "", 1);
    let msg = refused(
        &text,
        &[
            "bus.watchdog_ms",
            "100 ms (the default)",
            "control.rate_hz = 5 Hz",
            "400.0 ms",
            "at least 400 ms",
        ],
    );
    assert!(msg.contains("0 (off)"), "{msg}");
    // Given, at 10 Hz: 100 ms is one tick, not two.
    let at_10 = with("rate_hz = 100.0", "rate_hz = 10.0\nmax_silence_ms = 1000").replacen(
        "publish_hz = 25.0\n",
        "",
        1,
    );
    refused(
        &at_10,
        &["bus.watchdog_ms: 100 ms does not", "at least 200 ms"],
    );
    assert!(load(&at_10.replacen("watchdog_ms = 100", "watchdog_ms = 200", 1)).is_ok());
    assert!(load(&at_10.replacen("watchdog_ms = 100", "watchdog_ms = 0", 1)).is_ok());
    // The rule holds only where there are servos to watch.
    let no_bus = "[arm]\n[[joint]]\nlink_m = 0.5\nmin_rad = -1\nmax_rad = 1\n\
                  [control]\nrate_hz = 5.0\nmax_silence_ms = 1000\n";
    assert!(load(no_bus).is_ok());
}

#[test]
fn a_silence_budget_within_one_read_interval_is_refused_naming_the_fields() {
    // A read every 100 ticks of 10 ms (1 s) and a budget of 50 ms: one missed reply faulted.
    let msg = refused(
        &with(
            "rate_hz = 100.0",
            "rate_hz = 100.0\nread_every = 100\nmax_silence_ms = 50",
        ),
        &[
            "control.max_silence_ms: 50 ms is not longer",
            "control.read_every = 100",
            "control.rate_hz = 100 Hz",
            "1000.0 ms",
        ],
    );
    assert!(!msg.contains("default"), "{msg}");
    // The default budget, 50 ms, at 20 Hz: a read every 50 ms, so one miss would fault.
    refused(
        &with("rate_hz = 100.0", "rate_hz = 20.0").replacen("publish_hz = 25.0\n", "", 1),
        &["control.max_silence_ms: 50 ms (the default)", "50.0 ms"],
    );
    // Just over one interval is the least accepted.
    assert!(load(&with(
        "rate_hz = 100.0",
        "rate_hz = 100.0\nread_every = 5\nmax_silence_ms = 51"
    ))
    .is_ok());
    refused(
        &with(
            "rate_hz = 100.0",
            "rate_hz = 100.0\nread_every = 5\nmax_silence_ms = 50",
        ),
        &["control.max_silence_ms", "50.0 ms"],
    );
}

#[test]
fn substeps_is_refused_as_removed() {
    for value in ["1", "4", "0"] {
        refused(
            &with(
                "rate_hz = 100.0",
                &format!("rate_hz = 100.0\nsubsteps = {value}"),
            ),
            &["control.substeps: removed", "delete the line"],
        );
    }
}

#[test]
fn firmware_by_id_keys_are_plain_digits_so_no_servo_is_given_twice() {
    let fw = |keys: &str| {
        with(
            "seed = 7",
            &format!("seed = 7\n[sim.firmware_by_id]\n{keys}"),
        )
    };
    assert_eq!(
        load(&fw("3 = 44\n2 = 48"))
            .unwrap()
            .sim()
            .unwrap()
            .firmware_by_id,
        vec![(2, 48), (3, 44)]
    );
    refused(
        &fw("3 = 44\n03 = 48"),
        &[
            "sim.firmware_by_id.03: \"03\" is servo id 3 spelt otherwise",
            "write it 3",
        ],
    );
    refused(
        &fw("\"+3\" = 44"),
        &["sim.firmware_by_id.\"+3\"", "servo id 3"],
    );
    refused(
        &fw("\" 3 \" = 44"),
        &["sim.firmware_by_id.\" 3 \"", "servo id 3"],
    );
    refused(&fw("x = 44"), &["\"x\" is not a servo id"]);
    refused(
        &fw("9 = 44"),
        &["sim.firmware_by_id.9", "not the id of any"],
    );
}

/// `base_text` with faults: the first a valid one, `second` the second.
fn second_fault(second: &str) -> String {
    with(
        "seed = 7",
        &format!(
            "seed = 7\n\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\n\n\
             [[sim.fault]]\n{second}\n"
        ),
    )
}

/// The line of `text` that holds `needle`, from 1.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

#[test]
fn a_later_fault_s_errors_point_at_its_line_and_name_its_field() {
    // A wrong type, at its line.
    let text = second_fault("kind = \"corrupt\"\nfraction = \"half\"");
    let line = line_of(&text, "fraction = \"half\"");
    refused(
        &text,
        &[
            &format!("{FILE}:{line}:"),
            "sim.fault[2].fraction: invalid type",
        ],
    );
    // A key no fault has, at its line.
    let text = second_fault("kind = \"drop\"\nfraction = 0.5\nfractoin = 0.5");
    let line = line_of(&text, "fractoin");
    refused(
        &text,
        &[
            &format!("{FILE}:{line}:"),
            "sim.fault[2]",
            "unknown field `fractoin`",
        ],
    );
    // An unknown kind, at its line.
    let text = second_fault("kind = \"melt\"");
    let line = line_of(&text, "melt");
    refused(
        &text,
        &[&format!("{FILE}:{line}:"), "sim.fault[2].kind", "melt"],
    );
    // A key of another kind, and a key the kind needs, named.
    refused(
        &second_fault("kind = \"silent\"\nid = 2\nat_s = 1.0\nfraction = 0.5"),
        &[
            "sim.fault[2].fraction: not a key of a kind = \"silent\" fault",
            "id, at_s, until_s",
        ],
    );
    refused(
        &second_fault("kind = \"drop\"\nid = 2"),
        &["sim.fault[2].fraction: missing: a kind = \"drop\" fault needs it"],
    );
    refused(
        &second_fault("kind = \"hardware_error\"\nid = 2\nat_s = 1.0"),
        &["sim.fault[2].error: missing"],
    );
    refused(
        &second_fault("kind = \"disconnect\"\nat_s = 1.0\nid = 2"),
        &["sim.fault[2].id: not a key of a kind = \"disconnect\" fault"],
    );
    refused(
        &second_fault(
            "kind = \"hardware_error\"\nid = 2\nat_s = 1.0\nerror = \"encoder\"\nuntil_s = 2.0",
        ),
        &["sim.fault[2].until_s: not a key"],
    );
}

#[test]
fn every_fault_kind_reads_as_documented() {
    let text = with(
        "seed = 7",
        "seed = 7\n\
         [[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\n\
         [[sim.fault]]\nkind = \"corrupt\"\nfraction = 0.2\nid = 2\nat_s = 1.0\nuntil_s = 2.0\n\
         [[sim.fault]]\nkind = \"latency\"\nextra_us = 300\n\
         [[sim.fault]]\nkind = \"silent\"\nid = 1\nat_s = 3.0\n\
         [[sim.fault]]\nkind = \"hardware_error\"\nid = 3\nat_s = 4.0\nerror = \"voltage\"\n\
         [[sim.fault]]\nkind = \"blocked\"\nid = 2\n\
         [[sim.fault]]\nkind = \"disconnect\"\nport = 1\nat_s = 5.0\nuntil_s = 6.0\n",
    );
    let c = load(&text).unwrap();
    let s = std::time::Duration::from_secs;
    let f = &c.sim().unwrap().faults;
    assert_eq!(f.len(), 7);
    assert_eq!(
        (f[0].kind, f[0].id, f[0].from),
        (FaultKind::Drop(0.1), None, s(0))
    );
    assert_eq!(
        (f[1].kind, f[1].id, f[1].from, f[1].until),
        (FaultKind::Corrupt(0.2), Some(2), s(1), Some(s(2)))
    );
    assert_eq!(
        f[2].kind,
        FaultKind::Latency(std::time::Duration::from_micros(300))
    );
    assert_eq!(
        (f[3].kind, f[3].id, f[3].from),
        (FaultKind::Silent, Some(1), s(3))
    );
    assert_eq!(
        f[4].kind,
        FaultKind::HardwareError(HardwareError::InputVoltage)
    );
    assert_eq!(
        (f[5].kind, f[5].id, f[5].from),
        (FaultKind::Blocked, Some(2), s(0))
    );
    assert_eq!(
        (f[6].kind, f[6].id, f[6].port, f[6].until),
        (FaultKind::Disconnect, None, Some(0), Some(s(6)))
    );
}

#[test]
fn profile_values_beyond_their_register_are_refused_not_clamped() {
    for (key, value, parts) in [
        (
            "profile_velocity_rad_s",
            "1e5",
            ["100000 rad/s", "[0.02399, 785.77] rad/s"],
        ),
        (
            "profile_velocity_rad_s",
            "0.001",
            ["0.001 rad/s", "[0.02399, 785.77] rad/s"],
        ),
        (
            "profile_acceleration_rad_s2",
            "20000",
            ["20000 rad/s²", "[0.37451, 12271.48] rad/s²"],
        ),
        (
            "profile_acceleration_rad_s2",
            "0.1",
            ["0.1 rad/s²", "[0.37451, 12271.48] rad/s²"],
        ),
    ] {
        let text = with(
            "watchdog_ms = 100",
            &format!("watchdog_ms = 100\n{key} = {value}"),
        );
        let field = format!("bus.{key}");
        refused(&text, &[&field, parts[0], parts[1], "0 (no profile)"]);
    }
    for (key, value) in [
        ("profile_velocity_rad_s", "0.02399"),
        ("profile_velocity_rad_s", "785.77"),
        ("profile_velocity_rad_s", "0"),
        ("profile_acceleration_rad_s2", "0.37451"),
        ("profile_acceleration_rad_s2", "12271.48"),
    ] {
        let text = with(
            "watchdog_ms = 100",
            &format!("watchdog_ms = 100\n{key} = {value}"),
        );
        assert!(load(&text).is_ok(), "{key} = {value}");
    }
}

#[test]
fn an_empty_token_file_name_is_refused_at_load() {
    for name in ["\"\"", "\"  \""] {
        refused(
            &with(
                "token_file = \"token.txt\"",
                &format!("token_file = {name}"),
            ),
            &["server.token_file: an empty file name"],
        );
    }
}

#[test]
fn a_link_shorter_than_a_micrometre_is_refused() {
    for bad in ["1e-300", "1e-7"] {
        refused(
            &with("link_m = 0.1", &format!("link_m = {bad}")),
            &["joint[1].link_m", "must lie in [0.000001, 1000000]"],
        );
    }
    assert!(load(&with("link_m = 0.1", "link_m = 1e-6")).is_ok());
}
