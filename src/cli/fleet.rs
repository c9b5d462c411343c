//! `snakectl fleet`: the arms up on a Zenoh network, one line each (found by their liveliness
//! tokens, then asked for their status). Needs a build with the `zenoh` feature.

use std::path::PathBuf;

use anyhow::anyhow;
#[cfg(feature = "zenoh")]
use snakectl::config::{Config, Endpoint, Host, Zenoh};

use super::Failure;

/// `snakectl fleet`.
#[derive(Debug, clap::Args)]
pub struct FleetArgs {
    /// A Zenoh endpoint to reach the network through, `tcp/HOST:PORT` (an arm's `listen`, or a
    /// router); repeat it for several.
    #[arg(long, value_name = "ENDPOINT", conflicts_with = "config")]
    pub connect: Vec<String>,
    /// Join the network as this config's `[zenoh]` table says: its mode, multicast and
    /// `config_file`, connecting to its `connect` and `listen` endpoints (never listening).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// How long to look for arms and wait for each one's status, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    pub wait_ms: u64,
    /// One JSON object per line (`prefix` and the `status` reply) instead of columns.
    #[arg(long)]
    pub json: bool,
}

/// `snakectl fleet` in a build without Zenoh.
#[cfg(not(feature = "zenoh"))]
pub fn run(_args: FleetArgs) -> Result<(), Failure> {
    Err(Failure::bad_input(anyhow!(
        "this snakectl was built without Zenoh: build it with `cargo build --release --features \
         zenoh`"
    )))
}

/// `snakectl fleet`.
#[cfg(feature = "zenoh")]
pub fn run(args: FleetArgs) -> Result<(), Failure> {
    use snakectl::daemon::bridge::{self, Peer};
    use std::time::Duration;

    let table = table(&args)?;
    let wait = Duration::from_millis(args.wait_ms.max(1));
    let peer = Peer::with_table(&table).map_err(Failure::other)?;
    let arms = bridge::fleet(&peer, wait).map_err(Failure::other)?;
    if arms.is_empty() {
        let via: Vec<String> = table.connect.iter().map(ToString::to_string).collect();
        return Err(Failure::other(anyhow!(
            "no arm seen within {} ms through {}",
            args.wait_ms,
            if via.is_empty() {
                "multicast scouting".to_owned()
            } else {
                via.join(", ")
            }
        )));
    }
    let width = arms.iter().map(|a| a.prefix.len()).max().unwrap_or(0);
    for arm in &arms {
        if args.json {
            let line = serde_json::json!({ "prefix": arm.prefix, "status": arm.status });
            super::outln!("{line}")?;
        } else {
            super::outln!("{}", line(arm, width))?;
        }
    }
    Ok(())
}

/// One arm in columns: prefix, state, measured tip, strategy, controller, faults.
#[cfg(feature = "zenoh")]
fn line(arm: &snakectl::daemon::bridge::ArmSeen, width: usize) -> String {
    let prefix = &arm.prefix;
    let Some(status) = arm.read_status() else {
        return format!("{prefix:<width$}  up, no status answer");
    };
    let [x, y] = status.tip_meas;
    let controller = match status.controller {
        Some(n) => format!("controller {n}"),
        None => "no controller".to_owned(),
    };
    format!(
        "{prefix:<width$}  {:<8}  tip ({x:+.3}, {y:+.3}) m  {}  {controller}  faults {}",
        status.state.as_str(),
        status.strategy.name(),
        status.faults.len(),
    )
}

/// The session's settings: `--connect`'s endpoints as a peer, or the config's table turned
/// into a client of what the daemon listens on and connects to.
#[cfg(feature = "zenoh")]
fn table(args: &FleetArgs) -> Result<Zenoh, Failure> {
    let mut table = match &args.config {
        Some(path) => {
            let config = Config::load(path).map_err(Failure::bad_input)?;
            let mut table = config.zenoh().clone();
            // What the daemon listens on, this tool connects to (a wildcard address through
            // loopback); port 0 cannot be reached.
            let listened = table.listen.iter().filter(|e| e.port != 0).map(|e| {
                let host = match e.host {
                    Host::Ip(ip) if ip.is_unspecified() && ip.is_ipv4() => {
                        Host::Ip(std::net::Ipv4Addr::LOCALHOST.into())
                    }
                    Host::Ip(ip) if ip.is_unspecified() => {
                        Host::Ip(std::net::Ipv6Addr::LOCALHOST.into())
                    }
                    ref host => host.clone(),
                };
                Endpoint { host, port: e.port }
            });
            let mut connect: Vec<Endpoint> = listened.collect();
            connect.extend(table.connect.iter().cloned());
            table.connect = connect;
            table
        }
        None => {
            if args.connect.is_empty() {
                return Err(Failure::bad_input(anyhow!(
                    "say where the network is: --connect tcp/HOST:PORT (an arm's listen \
                     endpoint, or a router), or --config FILE"
                )));
            }
            let connect = args
                .connect
                .iter()
                .map(|text| {
                    Endpoint::parse_connect(text)
                        .map_err(|why| anyhow!("--connect {text:?}: {why}"))
                })
                .collect::<Result<Vec<_>, _>>()
                .map_err(Failure::bad_input)?;
            Zenoh::peer(connect, Vec::new())
        }
    };
    table.listen.clear();
    Ok(table)
}
