//! How rmw_zenoh, ROS 2's Zenoh middleware, lays a ROS 2 graph out on Zenoh: data keys,
//! liveliness tokens with their QoS strings, the GIDs, and the attachment every sample carries.
//! Pure formatting: strings and bytes in, strings and bytes out, no Zenoh types, so that the
//! bridge (`crate::daemon::bridge`, the `zenoh` feature) only declares what this module names.
//!
//! The layout, as rmw_zenoh 0.2.4 and later (Jazzy), Kilted and Rolling use it:
//! - a topic's data key is `<domain>/<topic without its leading '/'>/<DDS type>/RIHS01_<hash>`,
//!   the DDS type being `pkg::msg::dds_::Type_`;
//! - every node, publisher and subscription holds a liveliness token under `@ros2_lv/<domain>/`
//!   naming its session, ids, node, topic, type, hash and QoS, with every `/` inside a name
//!   written `%` (so an empty enclave or the root namespace is `%`);
//! - an entity's GID is the XXH3-128 of its token (low 64 bits first, each little-endian);
//! - every sample carries a 33-byte attachment: sequence number (i64 LE), source timestamp in
//!   ns since the Unix epoch (i64 LE), the GID's length 16 as one byte, the GID. A sample
//!   without it is dropped by rmw_zenoh.

use std::fmt::Write as _;

use super::{JointState, Message, PointStamped, Twist};

/// A message type with its REP-2016 type hash (RIHS01), as rmw_zenoh puts it in keys.
pub trait Typed: Message {
    /// The 64 hex digits of the RIHS01 hash of the type's description.
    const RIHS01: &'static str;
}

impl Typed for JointState {
    const RIHS01: &'static str = "a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e";
}

impl Typed for PointStamped {
    const RIHS01: &'static str = "4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897";
}

impl Typed for Twist {
    const RIHS01: &'static str = "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a";
}

/// The name of the snakectl node in the ROS 2 graph.
pub const NODE_NAME: &str = "snakectl";

/// Length of the attachment rmw_zenoh puts on every sample, bytes.
pub const ATTACHMENT_LEN: usize = 33;

/// The DDS name of a ROS 2 type: `sensor_msgs/msg/JointState` is
/// `sensor_msgs::msg::dds_::JointState_`.
pub fn dds_type_name(type_name: &str) -> String {
    match type_name.rsplit_once('/') {
        Some((package, name)) => format!("{}::dds_::{name}_", package.replace('/', "::")),
        None => format!("{type_name}_"),
    }
}

/// `RIHS01_<hex>`, the type hash as keys and tokens carry it.
pub fn type_hash<T: Typed>() -> String {
    format!("RIHS01_{}", T::RIHS01)
}

/// The full name of `topic` in the namespace `/<prefix>`: `/<prefix>/<topic>`.
pub fn topic_name(prefix: &str, topic: &str) -> String {
    format!("/{prefix}/{topic}")
}

/// The data key of topic `topic_name` (a full name, such as `/snakectl/joint_states`) of type
/// `T` in `domain`.
pub fn data_key<T: Typed>(domain: u32, topic_name: &str) -> String {
    format!(
        "{domain}/{}/{}/{}",
        topic_name.trim_matches('/'),
        dds_type_name(T::TYPE_NAME),
        type_hash::<T>()
    )
}

/// Why a prefix cannot be a ROS 2 namespace, if it cannot: each `/`-separated chunk must be
/// letters, digits and `_`, not starting with a digit (ROS 2's rule for names).
pub fn namespace_problem(prefix: &str) -> Option<&'static str> {
    for chunk in prefix.split('/') {
        if chunk.is_empty() {
            return Some("an empty chunk");
        }
        if !chunk
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_')
        {
            return Some("a ROS 2 name has only letters, digits and _ in each chunk");
        }
        if chunk.as_bytes()[0].is_ascii_digit() {
            return Some("a chunk of a ROS 2 name may not start with a digit");
        }
    }
    None
}

/// A name as a token chunk: every `/` as `%`, and the empty name as `%`.
fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".to_owned()
    } else {
        name.replace('/', "%")
    }
}

/// Delivery of a topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reliability {
    /// Every sample arrives (rmw's 1, rmw_zenoh's default).
    Reliable,
    /// Samples may be lost (rmw's 2).
    BestEffort,
}

/// Whether late joiners get the last samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Late joiners get the publisher's last `depth` samples (rmw's 1).
    TransientLocal,
    /// Late joiners get only what comes next (rmw's 2, rmw_zenoh's default).
    Volatile,
}

/// The QoS of a publisher or subscription: history is always keep-last, and deadline,
/// lifespan and liveliness are ROS 2's defaults (infinite, infinite, automatic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: Durability,
    /// Samples kept (keep-last depth).
    pub depth: u32,
}

impl Qos {
    /// ROS 2's default profile: reliable, volatile, keep last 10.
    pub const DEFAULT: Qos = Qos {
        reliability: Reliability::Reliable,
        durability: Durability::Volatile,
        depth: 10,
    };

    /// rmw_zenoh's depth when a profile does not set one; an unset field of the QoS string.
    const DEFAULT_DEPTH: u32 = 42;

    /// The QoS chunk of a token:
    /// `reliability:durability:history,depth:deadline_s,deadline_ns:lifespan_s,lifespan_ns:liveliness,lease_s,lease_ns`,
    /// each field empty where it equals rmw_zenoh's default (reliable, volatile, keep last,
    /// depth 42, infinite times, automatic).
    pub fn token_string(&self) -> String {
        let reliability = match self.reliability {
            Reliability::Reliable => "",
            Reliability::BestEffort => "2",
        };
        let durability = match self.durability {
            Durability::TransientLocal => "1",
            Durability::Volatile => "",
        };
        let depth = if self.depth == Self::DEFAULT_DEPTH {
            String::new()
        } else {
            self.depth.to_string()
        };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// Publisher or subscription.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// A publisher (`MP`).
    Publisher,
    /// A subscription (`MS`).
    Subscription,
}

impl EntityKind {
    fn code(self) -> &'static str {
        match self {
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        }
    }
}

/// A node as the graph names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Node {
    /// The ROS 2 domain id.
    pub domain: u32,
    /// The Zenoh session id as Zenoh prints it.
    pub zid: String,
    /// The node's id, unique in the session.
    pub id: u64,
    /// The security enclave; `/` (or empty) for none.
    pub enclave: String,
    /// The namespace, `/`-led (`/snakectl`).
    pub namespace: String,
    /// The node's name.
    pub name: String,
}

impl Node {
    /// The snakectl node of session `zid` in `domain`: id 0, no enclave, namespace
    /// `/<prefix>`, name [`NODE_NAME`].
    pub fn snakectl(domain: u32, zid: &str, prefix: &str) -> Node {
        Node {
            domain,
            zid: zid.to_owned(),
            id: 0,
            enclave: "/".to_owned(),
            namespace: format!("/{prefix}"),
            name: NODE_NAME.to_owned(),
        }
    }

    /// `@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<name>`.
    fn head(&self, entity_id: u64, code: &str) -> String {
        format!(
            "@ros2_lv/{}/{}/{}/{entity_id}/{code}/{}/{}/{}",
            self.domain,
            self.zid,
            self.id,
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.name)
        )
    }

    /// The node's liveliness token.
    pub fn token(&self) -> String {
        self.head(self.id, "NN")
    }

    /// The liveliness token of entity `id` of this node: a publisher or subscription of
    /// `topic_name` (a full name) of type `T` with `qos`.
    pub fn entity_token<T: Typed>(
        &self,
        id: u64,
        kind: EntityKind,
        topic_name: &str,
        qos: &Qos,
    ) -> String {
        let mut token = self.head(id, kind.code());
        // Writing to a String cannot fail.
        let _ = write!(
            token,
            "/{}/{}/{}/{}",
            mangle(topic_name),
            mangle(&dds_type_name(T::TYPE_NAME)),
            type_hash::<T>(),
            qos.token_string()
        );
        token
    }
}

/// The GID of the entity whose liveliness token is `token`: its XXH3-128 (seed 0), the low
/// 64 bits then the high 64 bits, each little-endian.
pub fn gid(token: &str) -> [u8; 16] {
    let hash = xxhash_rust::xxh3::xxh3_128(token.as_bytes());
    let mut out = [0; 16];
    out[..8].copy_from_slice(&(hash as u64).to_le_bytes());
    out[8..].copy_from_slice(&((hash >> 64) as u64).to_le_bytes());
    out
}

/// The attachment of one sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's count of samples, from 1.
    pub sequence: i64,
    /// When it was published, ns since the Unix epoch.
    pub source_timestamp_ns: i64,
    /// The publisher's GID.
    pub gid: [u8; 16],
}

/// Why an attachment is not rmw_zenoh's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AttachmentError {
    /// None at all, or too short.
    #[error("an attachment of {len} bytes, not rmw_zenoh's {ATTACHMENT_LEN}")]
    Short {
        /// Bytes received.
        len: usize,
    },
    /// The GID's length byte is not 16.
    #[error("the GID length byte is {found}, not 16")]
    GidLength {
        /// The byte found.
        found: u8,
    },
}

impl Attachment {
    /// The 33 bytes: sequence (i64 LE), timestamp (i64 LE), 0x10, the GID.
    pub fn encode(&self) -> [u8; ATTACHMENT_LEN] {
        let mut out = [0; ATTACHMENT_LEN];
        out[..8].copy_from_slice(&self.sequence.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_timestamp_ns.to_le_bytes());
        out[16] = 16;
        out[17..].copy_from_slice(&self.gid);
        out
    }

    /// Reads what [`Attachment::encode`] writes; bytes after the 33rd are ignored.
    pub fn decode(bytes: &[u8]) -> Result<Attachment, AttachmentError> {
        let short = || AttachmentError::Short { len: bytes.len() };
        let word = |at: usize| -> Result<i64, AttachmentError> {
            let b: [u8; 8] = bytes
                .get(at..at + 8)
                .and_then(|b| b.try_into().ok())
                .ok_or_else(short)?;
            Ok(i64::from_le_bytes(b))
        };
        let sequence = word(0)?;
        let source_timestamp_ns = word(8)?;
        let found = *bytes.get(16).ok_or_else(short)?;
        if found != 16 {
            return Err(AttachmentError::GidLength { found });
        }
        let gid: [u8; 16] = bytes
            .get(17..ATTACHMENT_LEN)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(short)?;
        Ok(Attachment {
            sequence,
            source_timestamp_ns,
            gid,
        })
    }
}

#[cfg(test)]
mod tests;
