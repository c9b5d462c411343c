//! Every file shipped in `config/` loads, and its chain matches its `[[joint]]` tables.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use snakectl::config::{Config, ConfigError};

/// The `.toml` files under `config/`, found at test time so a new file is tested too.
fn shipped_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .toml files in {}", dir.display());
    files
}

fn joint_tables(text: &str) -> usize {
    text.lines().filter(|l| l.trim() == "[[joint]]").count()
}

#[test]
fn every_shipped_file_loads() {
    for path in shipped_files() {
        let text = std::fs::read_to_string(&path).unwrap();
        let config = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let joints = joint_tables(&text);
        assert!(joints > 0, "{}: no [[joint]] tables", path.display());
        assert_eq!(config.chain().len(), joints, "{}", path.display());
        assert_eq!(config.joints().len(), joints, "{}", path.display());
        assert_eq!(config.home().len(), joints, "{}", path.display());
        config.chain().check_limits(config.home()).unwrap();
    }
}

#[test]
fn shipped_examples_are_what_the_docs_say() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config");
    let arm = Config::load(dir.join("arm.toml")).unwrap();
    assert_eq!(arm.chain().len(), 8);
    assert!(arm.home().iter().any(|&a| a != 0.0), "home should be bent");

    let sim = Config::load(dir.join("sim.toml")).unwrap();
    assert_eq!(sim.chain().len(), 12);
    let bus = sim.bus().unwrap();
    assert_eq!(bus.kind, snakectl::config::BusKind::Sim);
    assert_eq!(bus.baud, 1_000_000);
    assert_eq!(sim.arm().unwrap().settings().return_delay_us, 0);
    let ids: Vec<Option<u8>> = sim.joints().iter().map(|j| j.id).collect();
    assert_eq!(ids, (1..=12).map(Some).collect::<Vec<_>>());
    assert!(sim.sim().unwrap().faults.is_empty());
    assert!(sim.world().obstacles().is_empty());

    // The simulated arm among a post and a shelf, its home pose clear of both.
    let world = Config::load(dir.join("world.toml")).unwrap();
    assert_eq!(world.chain(), sim.chain());
    assert_eq!(world.home(), sim.home());
    let w = world.world();
    let ids: Vec<&str> = w.obstacles().iter().map(|o| o.id.as_str()).collect();
    assert_eq!(ids, ["post", "shelf"]);
    assert_eq!((w.link_radius_m(), w.clearance_m()), (0.012, 0.005));
    let least = w.pose_clearance(world.chain(), world.home()).unwrap();
    assert!(least.clearance_m > 0.05, "{least:?}");
    assert!(
        world.contact().is_none(),
        "contact detection is commented out"
    );
}

/// The commented fault examples in `sim.toml` are valid when uncommented.
#[test]
fn commented_sim_faults_parse() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/sim.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let start = text.find("# [[sim.fault]]").unwrap();
    let end = text[start..].find("\n\n").map_or(text.len(), |n| start + n);
    let uncommented: String = text[start..end]
        .lines()
        .map(|l| l.strip_prefix("# ").unwrap_or(l.trim_start_matches('#')))
        .collect::<Vec<_>>()
        .join("\n");
    // Put the faults right after [sim], before [control].
    let at = text.find("\n[control]").unwrap();
    let edited = format!("{}\n{}\n{}", &text[..at], uncommented, &text[at..]);
    let config = Config::from_str(&edited, &path).unwrap_or_else(|e| panic!("{e}"));
    let faults = &config.sim().unwrap().faults;
    assert_eq!(faults.len(), 7);
    assert!(faults
        .iter()
        .any(|f| f.kind == snakectl::config::FaultKind::Blocked && f.id == Some(3)));
    assert!(faults
        .iter()
        .any(|f| f.kind == snakectl::config::FaultKind::Disconnect && f.id.is_none()));
}

/// A key no table knows is refused, naming the key and the line, in every table of every
/// shipped file.
#[test]
fn unknown_key_in_any_table_is_refused() {
    const KEY: &str = "surplus_key";
    for path in shipped_files() {
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let headers = lines
            .iter()
            .enumerate()
            .filter(|(_, l)| l.starts_with('['))
            .map(|(i, _)| i);
        let mut tried = 0;
        for header in headers {
            let mut edited = lines.clone();
            let extra = format!("{KEY} = 1");
            edited.insert(header + 1, &extra);
            let err = Config::from_str(&edited.join("\n"), &path).unwrap_err();
            let msg = err.to_string();
            assert!(matches!(err, ConfigError::Syntax { .. }), "{msg}");
            assert!(msg.contains(KEY), "{msg}");
            assert!(msg.starts_with(&path.display().to_string()), "{msg}");
            // The table's header or the key itself is the line named.
            let named = format!(":{}:", header + 1);
            let named_key = format!(":{}:", header + 2);
            assert!(
                msg.contains(&named) || msg.contains(&named_key),
                "line {} expected in: {msg}",
                header + 2
            );
            tried += 1;
        }
        assert!(tried >= 2, "{}: too few tables", path.display());
    }
}

/// The commented `[zenoh]` table of each shipped file, uncommented, is valid and says what the
/// defaults are.
#[test]
fn commented_zenoh_tables_show_the_defaults() {
    for name in ["sim.toml", "arm.toml"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("config")
            .join(name);
        let text = std::fs::read_to_string(&path).unwrap();
        let start = text
            .find("\n# [zenoh]\n")
            .unwrap_or_else(|| panic!("{name}: no [zenoh]"));
        let end = text[start + 1..]
            .find("\n\n")
            .map_or(text.len(), |n| start + 1 + n);
        let uncommented: String = text[start..end]
            .lines()
            .filter(|l| !l.starts_with("#  "))
            .map(|l| l.strip_prefix("# ").unwrap_or(l))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(
            uncommented.contains("\n[zenoh]\nenabled = false"),
            "{uncommented}"
        );
        let edited = format!("{text}\n{uncommented}\n");
        let with_table = Config::from_str(&edited, &path).unwrap_or_else(|e| panic!("{e}"));
        let without = Config::load(&path).unwrap();
        assert_eq!(with_table.zenoh(), without.zenoh(), "{name}");
        assert!(!without.zenoh().enabled);
    }
}

/// The commented contact detection of `world.toml`, uncommented, turns it on as it says.
#[test]
fn commented_contact_detection_parses() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/world.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut edited = text.clone();
    for key in ["contact_load", "contact_ms"] {
        let commented = format!("# {key} = ");
        assert!(edited.contains(&commented), "no `{commented}` line");
        edited = edited.replacen(&commented, &format!("{key} = "), 1);
    }
    let config = Config::from_str(&edited, &path).unwrap_or_else(|e| panic!("{e}"));
    let contact = config.contact().unwrap();
    assert_eq!(contact.load, vec![60.0; 12]);
    assert_eq!(contact.hold, std::time::Duration::from_millis(200));
}

/// The commented `[foxglove]` table of each shipped file, uncommented, is valid: the view on
/// loopback port 8765 at the default rate, taking no commands.
#[test]
fn commented_foxglove_tables_serve_on_loopback() {
    for name in ["sim.toml", "arm.toml"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("config")
            .join(name);
        let text = std::fs::read_to_string(&path).unwrap();
        let start = text
            .find("\n# [foxglove]\n")
            .unwrap_or_else(|| panic!("{name}: no [foxglove]"));
        let end = text[start + 1..]
            .find("\n\n")
            .map_or(text.len(), |n| start + 1 + n);
        let uncommented: String = text[start..end]
            .lines()
            .map(|l| l.strip_prefix("# ").unwrap_or(l))
            .collect::<Vec<_>>()
            .join("\n");
        let edited = format!("{text}\n{uncommented}\n");
        let config = Config::from_str(&edited, &path).unwrap_or_else(|e| panic!("{e}"));
        let view = config.foxglove();
        assert_eq!(
            view.listen,
            Some("127.0.0.1:8765".parse().unwrap()),
            "{name}"
        );
        assert_eq!(view.publish_hz, 30.0, "{name}");
        assert!(!view.accept_commands, "{name}");
        assert_eq!(
            Config::load(&path).unwrap().foxglove().listen,
            None,
            "{name}: off as shipped"
        );
    }
}

/// Runs `snakectl ARGS`, killed after 20 s: its exit status and stderr, or `None` if it had to
/// be killed.
fn snakectl_within(args: &[&str]) -> Option<(bool, String)> {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > std::time::Duration::from_secs(20) {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    Some((
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    ))
}

#[test]
fn a_device_or_fifo_named_as_an_input_file_is_refused_at_once_by_every_command() {
    let dir = std::env::temp_dir().join(format!("snakectl-config-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("input.fifo");
    let _ = std::fs::remove_file(&fifo);
    rustix::fs::mknodat(
        rustix::fs::CWD,
        &fifo,
        rustix::fs::FileType::Fifo,
        rustix::fs::Mode::from_raw_mode(0o600),
        0,
    )
    .unwrap();
    let fifo = fifo.to_str().unwrap().to_owned();
    for (file, what) in [
        ("/dev/zero", "a character device, not a regular file"),
        (fifo.as_str(), "a FIFO (named pipe), not a regular file"),
    ] {
        for args in [
            vec!["urdf", "--config", file],
            vec!["solve", file],
            vec!["world", "set", file],
            vec!["path", file],
        ] {
            let (ok, stderr) = snakectl_within(&args)
                .unwrap_or_else(|| panic!("`snakectl {}` did not end", args.join(" ")));
            assert!(!ok, "snakectl {}: {stderr}", args.join(" "));
            assert!(
                stderr.contains(file) && stderr.contains(what),
                "snakectl {}: {stderr}",
                args.join(" ")
            );
        }
    }
}

/// What CONFIG.md says of a few keys holds: `[arm]`, every key of which has a default, may be
/// left out; `[control] rate_hz` outside 1 to 2000 is refused with that range whatever the
/// value (0, NaN, negative, too high); `[bus] ports = []` is refused rather than taken for
/// one port.
#[test]
fn arm_rate_and_ports_are_as_documented() {
    let joint = "[[joint]]\nlink_m = 0.5\nmin_rad = -1\nmax_rad = 1\n";
    let c = Config::from_str(joint, "a.toml").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.home(), [0.0]);
    for rate in ["0.0", "nan", "-5.0", "0.5", "2001.0"] {
        let e = Config::from_str(&format!("{joint}[control]\nrate_hz = {rate}\n"), "a.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("control.rate_hz: ") && e.ends_with("must lie in [1, 2000]"),
            "{rate}: {e}"
        );
    }
    let bus = format!("{joint}id = 1\nmodel = \"XL430-W250\"\n[bus]\nkind = \"sim\"\n");
    let c = Config::from_str(&bus, "a.toml").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.bus().unwrap().ports.len(), 1);
    let e = Config::from_str(&format!("{bus}ports = []\n"), "a.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a.toml: bus.ports: an empty list: give at least one [[bus.ports]]"),
        "{e}"
    );
}

/// `snakectl run --config` on `text` (a `[bus] kind = "dynamixel"` on a device that does not
/// exist, so that it stops once the file is read): its stderr, the log of that start-up.
/// `more` follows on the command line.
fn start_up_log(name: &str, text: &str, more: &[&str]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, text).unwrap();
    let path = path.to_str().unwrap();
    let mut args = vec!["run", "--config", path, "--listen", "127.0.0.1:0"];
    args.extend(more);
    let (ok, stderr) = snakectl_within(&args)
        .unwrap_or_else(|| panic!("`snakectl run --config {name}` did not end"));
    assert!(!ok, "{name}: started on a missing device: {stderr}");
    stderr
}

/// A serial device that is not there.
const MISSING: &str = "/nonexistent-snakectl-test/ttyUSB0";

/// A real arm's file: two joints on a device that is not there.
fn real_arm(port: &str, bus_extra: &str) -> String {
    format!(
        "[[joint]]\nlink_m = 0.1\nmin_rad = -1\nmax_rad = 1\nid = 1\nmodel = \"XL430-W250\"\n\
         [[joint]]\nlink_m = 0.1\nmin_rad = -1\nmax_rad = 1\nid = 2\nmodel = \"XL430-W250\"\n\
         [bus]\nkind = \"dynamixel\"\nport = \"{port}\"\n{bus_extra}"
    )
}

/// A Profile Velocity below `[control] max_joint_speed_rad_s` is accepted (a gentle profile on
/// purpose), with a start-up warning naming both keys and values: the servos lag behind the
/// goals the daemon sends.
#[test]
fn a_profile_slower_than_the_joint_speed_limit_is_warned_of() {
    let slow = real_arm(
        MISSING,
        "profile_velocity_rad_s = 0.5\n[control]\nmax_joint_speed_rad_s = 2.0\n",
    );
    Config::from_str(&slow, "slow.toml").unwrap_or_else(|e| panic!("{e}"));
    let log = start_up_log("slow.toml", &slow, &[]);
    assert!(
        log.contains("bus.profile_velocity_rad_s = 0.5")
            && log.contains("control.max_joint_speed_rad_s = 2")
            && log.contains("slow.toml"),
        "{log}"
    );
    // A profile as fast as the limit, or none, says nothing of it.
    for bus in [
        "profile_velocity_rad_s = 2.0\n",
        "profile_velocity_rad_s = 0\n",
    ] {
        let text = real_arm(
            MISSING,
            &format!("{bus}[control]\nmax_joint_speed_rad_s = 2.0\n"),
        );
        let log = start_up_log("fast.toml", &text, &[]);
        assert!(!log.contains("profile_velocity_rad_s"), "{bus}: {log}");
    }
}

/// `[sim]` and its faults in a file of real servos are not used, and the start-up log says so
/// (as it does of a `port` given to `kind = "sim"`); with `kind = "sim"` they are, and it says
/// nothing.
#[test]
fn a_sim_table_beside_real_servos_is_warned_of() {
    let sim = "[sim]\nwire_timing = true\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\n\
               [[sim.fault]]\nkind = \"corrupt\"\nfraction = 0.1\n";
    let real = format!("{}{sim}", real_arm(MISSING, ""));
    let log = start_up_log("real.toml", &real, &[]);
    assert!(
        log.contains("real.toml: [sim] is not used, nor its 2 [[sim.fault]] tables")
            && log.contains("kind = \"dynamixel\""),
        "{log}"
    );
    let simulated = real.replace(
        &format!("kind = \"dynamixel\"\nport = \"{MISSING}\""),
        "kind = \"sim\"",
    );
    let log = start_up_log("simulated.toml", &simulated, &["--port", MISSING]);
    assert!(!log.contains("[sim]"), "{log}");
}

/// `[foxglove] accept_commands = true` without `listen` serves nothing that could take a
/// command: accepted, with a warning saying so; with `listen`, no warning.
#[test]
fn foxglove_commands_without_a_view_are_warned_of() {
    let none = format!(
        "{}[foxglove]\naccept_commands = true\n",
        real_arm(MISSING, "")
    );
    let log = start_up_log("none.toml", &none, &[]);
    assert!(
        log.contains("none.toml: foxglove.accept_commands = true has no effect")
            && log.contains("foxglove.listen"),
        "{log}"
    );
    let served = format!("{none}listen = \"127.0.0.1:0\"\n");
    let log = start_up_log("served.toml", &served, &[]);
    assert!(!log.contains("accept_commands"), "{log}");
}
