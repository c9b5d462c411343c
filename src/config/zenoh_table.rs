//! The validated `[zenoh]` table: endpoints, the key prefix, the publishing rate, and the
//! refusal to take commands from a network other hosts can reach without access control.
//!
//! The table is checked in every build, with or without Zenoh compiled in, so a file means the
//! same everywhere; the daemon refuses `enabled = true` at start-up when Zenoh is not built.

use std::fmt;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::path::PathBuf;

pub use super::raw::ZenohMode;

use super::raw::{RawZenoh, DEFAULT_ZENOH_PUBLISH_HZ};
use super::{finite_within, Checker, ConfigError, FieldProblem};

/// The validated `[zenoh]` (defaults, and `enabled = false`, when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Zenoh {
    /// Whether the daemon joins the network.
    pub enabled: bool,
    /// Peer or client.
    pub mode: ZenohMode,
    /// Endpoints to connect to; port 0 is refused.
    pub connect: Vec<Endpoint>,
    /// Endpoints to listen on (port 0: any free port). Empty means none: the session must not
    /// fall back to Zenoh's own default of listening on every interface.
    pub listen: Vec<Endpoint>,
    /// Multicast scouting on.
    pub multicast: bool,
    /// The arm's namespace, the start of every key: one or more `/`-separated chunks of
    /// printable ASCII, none empty, with no wildcard or special character (`*`, `$`, `?`, `#`,
    /// `\`) and none starting with `@`.
    pub prefix: String,
    /// Publishing rate, Hz, positive and at most `control.rate_hz`.
    pub publish_hz: f64,
    /// Whether `cmd_vel`, `goal` and `reach` are taken from the network. When true, every
    /// endpoint is on loopback and multicast is off, unless `config_file` is set.
    pub accept_commands: bool,
    /// A Zenoh json5 config file for the session, resolved against the config file's
    /// directory (not read here).
    pub config_file: Option<PathBuf>,
    /// Whether the daemon is also a ROS 2 node on rmw_zenoh's keys (then `prefix` is a ROS 2
    /// namespace: letters, digits and `_` in each chunk, none starting with a digit).
    pub ros2: bool,
    /// The ROS 2 domain id, 0..=232.
    pub domain_id: u32,
}

impl Zenoh {
    /// An enabled peer on `connect` and `listen` (none: it listens nowhere), multicast off,
    /// under the default prefix and no commands: the table of a tool's own session.
    pub fn peer(connect: Vec<Endpoint>, listen: Vec<Endpoint>) -> Zenoh {
        Zenoh {
            enabled: true,
            mode: ZenohMode::Peer,
            connect,
            listen,
            multicast: false,
            prefix: super::raw::default_zenoh_prefix(),
            publish_hz: DEFAULT_ZENOH_PUBLISH_HZ,
            accept_commands: false,
            config_file: None,
            ros2: false,
            domain_id: 0,
        }
    }

    /// The keys of the arm: `<prefix>/<name>`.
    pub fn key(&self, name: &str) -> String {
        format!("{}/{name}", self.prefix)
    }
}

/// The largest ROS 2 domain id (ROS 2's own bound, from DDS's port arithmetic; rmw_zenoh
/// keeps it).
pub const MAX_DOMAIN_ID: u32 = 232;

/// A host of a Zenoh endpoint.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Host {
    /// An IPv4 or IPv6 address.
    Ip(IpAddr),
    /// A host name, resolved when the session starts.
    Name(String),
}

/// A validated Zenoh TCP endpoint, `tcp/HOST:PORT`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoint {
    /// The host.
    pub host: Host,
    /// The port; 0 (listen only) lets the system pick.
    pub port: u16,
}

impl Endpoint {
    /// Whether only this host can reach it: 127.0.0.0/8, `::1` or `localhost`.
    pub fn is_loopback(&self) -> bool {
        match &self.host {
            Host::Ip(ip) => ip.is_loopback(),
            Host::Name(name) => name.eq_ignore_ascii_case("localhost"),
        }
    }

    /// [`Endpoint::parse`], for an endpoint to connect to: port 0 is refused.
    pub fn parse_connect(text: &str) -> Result<Endpoint, String> {
        let endpoint = Endpoint::parse(text)?;
        match endpoint.port {
            0 => Err("port 0 cannot be connected to".to_owned()),
            _ => Ok(endpoint),
        }
    }

    /// Parses `tcp/HOST:PORT` (an IPv6 address in brackets); the error is the reason.
    pub fn parse(text: &str) -> Result<Endpoint, String> {
        let Some(address) = text.strip_prefix("tcp/") else {
            return Err(match text.split_once('/') {
                Some((scheme, _)) => format!(
                    "the {scheme:?} transport is not available: only tcp is built into snakectl"
                ),
                None => "no transport: write tcp/ then host:port".to_owned(),
            });
        };
        if address.contains(['?', '#']) {
            return Err(
                "endpoint metadata (?) and options (#) are not taken here: put them \
                        in config_file"
                    .to_owned(),
            );
        }
        let (host, port) = if let Some(rest) = address.strip_prefix('[') {
            let (ip, port) = rest
                .split_once("]:")
                .ok_or("an IPv6 address is written [address]:port")?;
            let ip: Ipv6Addr = ip
                .parse()
                .map_err(|_| format!("{ip:?} is not an IPv6 address"))?;
            (Host::Ip(IpAddr::V6(ip)), port)
        } else {
            let (host, port) = address.rsplit_once(':').ok_or("no :port")?;
            if host.contains(':') {
                return Err("an IPv6 address is written in brackets, [address]:port".to_owned());
            }
            (parse_host(host)?, port)
        };
        let port = port
            .parse::<u16>()
            .map_err(|_| format!("port {port:?} is not a number in 0..=65535"))?;
        Ok(Endpoint { host, port })
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.host {
            Host::Ip(IpAddr::V6(ip)) => write!(f, "tcp/[{ip}]:{}", self.port),
            Host::Ip(IpAddr::V4(ip)) => write!(f, "tcp/{ip}:{}", self.port),
            Host::Name(name) => write!(f, "tcp/{name}:{}", self.port),
        }
    }
}

/// An IPv4 address or a DNS host name.
fn parse_host(host: &str) -> Result<Host, String> {
    if let Ok(ip) = host.parse::<Ipv4Addr>() {
        return Ok(Host::Ip(IpAddr::V4(ip)));
    }
    let label_ok = |l: &str| {
        !l.is_empty()
            && l.len() <= 63
            && !l.starts_with('-')
            && !l.ends_with('-')
            && l.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
    };
    let labels: Vec<&str> = host.split('.').collect();
    let numeric_tail = labels
        .last()
        .is_some_and(|l| l.bytes().all(|b| b.is_ascii_digit()));
    if host.is_empty() || host.len() > 253 || !labels.iter().all(|l| label_ok(l)) || numeric_tail {
        return Err(format!(
            "{host:?} is neither an IPv4 address nor a host name"
        ));
    }
    Ok(Host::Name(host.to_owned()))
}

/// Why `prefix` is not a plain key expression, if it is not.
fn prefix_problem(prefix: &str) -> Option<&'static str> {
    if prefix.is_empty() {
        Some("empty")
    } else if !prefix.bytes().all(|b| b.is_ascii_graphic()) {
        Some("only printable ASCII: no space, control character or other character")
    } else if prefix.contains('\\') {
        Some("no \\: shells, logs and other tools read it as an escape")
    } else if prefix.contains(['*', '$', '?', '#']) {
        Some("*, $, ? and # are Zenoh's wildcards and separators")
    } else if prefix.starts_with('/') || prefix.ends_with('/') {
        Some("no leading or trailing /")
    } else if prefix.contains("//") {
        Some("an empty chunk between two /")
    } else if prefix.split('/').any(|chunk| chunk.starts_with('@')) {
        Some("a chunk starting with @ is reserved by Zenoh")
    } else {
        None
    }
}

impl Checker<'_> {
    /// Checks `[zenoh]`; `rate_hz` is the validated loop rate.
    pub(super) fn zenoh(&self, raw: RawZenoh, rate_hz: f64) -> Result<Zenoh, ConfigError> {
        let endpoints = |name: &'static str, list: &[String]| {
            let parsed = list
                .iter()
                .enumerate()
                .map(|(i, text)| {
                    let field = format!("zenoh.{name}[{}]", i + 1);
                    let bad = |reason: String| {
                        self.invalid(
                            field.clone(),
                            FieldProblem::BadEndpoint {
                                value: text.clone(),
                                reason,
                            },
                        )
                    };
                    match name {
                        "connect" => Endpoint::parse_connect(text),
                        _ => Endpoint::parse(text),
                    }
                    .map_err(bad)
                })
                .collect::<Result<Vec<_>, _>>()?;
            // Listening twice on one endpoint would fail as the session opens; connecting
            // twice says nothing more. Port 0 picks a new port each time.
            for (i, endpoint) in parsed.iter().enumerate() {
                let twice = parsed[..i].iter().position(|e| e == endpoint);
                if let Some(other) = twice.filter(|_| endpoint.port != 0) {
                    return Err(self.invalid(
                        format!("zenoh.{name}[{}]", i + 1),
                        FieldProblem::DuplicateEndpoint {
                            value: endpoint.to_string(),
                            list: name,
                            other: other + 1,
                        },
                    ));
                }
            }
            Ok(parsed)
        };
        let connect = endpoints("connect", &raw.connect)?;
        let listen = endpoints("listen", &raw.listen)?;
        if let Some(reason) = prefix_problem(&raw.prefix) {
            return Err(self.invalid(
                "zenoh.prefix",
                FieldProblem::BadPrefix {
                    value: raw.prefix,
                    reason,
                },
            ));
        }
        if raw.ros2 {
            if let Some(reason) = crate::ros::rmw::namespace_problem(&raw.prefix) {
                return Err(self.invalid(
                    "zenoh.prefix",
                    FieldProblem::BadPrefix {
                        value: raw.prefix,
                        reason,
                    },
                ));
            }
        }
        if raw.domain_id > MAX_DOMAIN_ID {
            return Err(self.invalid(
                "zenoh.domain_id",
                FieldProblem::OutOfRange {
                    value: i64::from(raw.domain_id),
                    expected: "is not a ROS 2 domain id: 0..=232",
                },
            ));
        }
        let publish_hz = match raw.publish_hz {
            None => DEFAULT_ZENOH_PUBLISH_HZ.min(rate_hz),
            Some(value) if finite_within(value) && value > 0.0 && value <= rate_hz => value,
            Some(value) => {
                return Err(self.invalid(
                    "zenoh.publish_hz",
                    FieldProblem::AboveLoopRate { value, rate_hz },
                ))
            }
        };
        let config_file = raw.config_file.map(|f| self.relative_to_file(f));
        if raw.accept_commands && config_file.is_none() {
            let open = |name: &str, list: &[Endpoint]| {
                list.iter()
                    .position(|e| !e.is_loopback())
                    .map(|i| format!("zenoh.{name}[{}] = \"{}\" is not loopback", i + 1, list[i]))
            };
            let exposure = if raw.multicast {
                Some("multicast scouting is on".to_owned())
            } else {
                open("listen", &listen).or_else(|| open("connect", &connect))
            };
            if let Some(exposure) = exposure {
                return Err(self.invalid(
                    "zenoh.accept_commands",
                    FieldProblem::CommandsExposed { exposure },
                ));
            }
        }
        if raw.enabled && config_file.is_none() && !raw.multicast {
            match raw.mode {
                ZenohMode::Client if connect.is_empty() => {
                    return Err(self.invalid(
                        "zenoh.connect",
                        FieldProblem::Missing {
                            why: "mode = \"client\" needs a router to connect to (or multicast \
                                  = true to scout for one)",
                        },
                    ))
                }
                ZenohMode::Peer if connect.is_empty() && listen.is_empty() => {
                    return Err(self.invalid(
                        "zenoh.listen",
                        FieldProblem::Missing {
                            why: "with no listen, no connect and multicast = false, no other \
                                  session could reach the arm",
                        },
                    ))
                }
                _ => {}
            }
        }
        Ok(Zenoh {
            enabled: raw.enabled,
            mode: raw.mode,
            connect,
            listen,
            multicast: raw.multicast,
            prefix: raw.prefix,
            publish_hz,
            accept_commands: raw.accept_commands,
            config_file,
            ros2: raw.ros2,
            domain_id: raw.domain_id,
        })
    }
}
