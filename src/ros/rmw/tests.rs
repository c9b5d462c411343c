//! Golden keys, tokens, GIDs and attachments, each written out from the rules in the module
//! docs (rmw_zenoh's layout) rather than from the code under test.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;

/// A session id as Zenoh prints one (32 hex digits), fixed for the goldens.
const ZID: &str = "2f0b8e1c9a4d4e5f8a7b6c5d4e3f2a1b";

const JOINT_STATE_HASH: &str =
    "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e";

#[test]
fn dds_type_names_follow_the_pkg_msg_dds_rule() {
    // pkg/msg/Type -> pkg::msg::dds_::Type_
    assert_eq!(
        dds_type_name("sensor_msgs/msg/JointState"),
        "sensor_msgs::msg::dds_::JointState_"
    );
    assert_eq!(
        dds_type_name("geometry_msgs/msg/Twist"),
        "geometry_msgs::msg::dds_::Twist_"
    );
}

#[test]
fn the_data_key_of_joint_states() {
    // <domain>/<topic without its leading '/'>/<DDS type>/RIHS01_<hash>; the topic keeps its
    // inner '/' (a key has chunks, the token does not).
    let topic = topic_name("snakectl", "joint_states");
    assert_eq!(topic, "/snakectl/joint_states");
    assert_eq!(
        data_key::<JointState>(0, &topic),
        format!("0/snakectl/joint_states/sensor_msgs::msg::dds_::JointState_/{JOINT_STATE_HASH}")
    );
    assert_eq!(
        data_key::<Twist>(42, &topic_name("lab/arm_1", "cmd_vel")),
        "42/lab/arm_1/cmd_vel/geometry_msgs::msg::dds_::Twist_/\
         RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
    );
}

#[test]
fn qos_strings_leave_rmw_zenohs_defaults_empty() {
    // Reliable (default: empty) : volatile (default: empty) : keep last (empty) , depth 10 :
    // deadline "," : lifespan "," : liveliness ",," -- six ':'-separated fields.
    assert_eq!(Qos::DEFAULT.token_string(), "::,10:,:,:,,");
    // Best effort is rmw's 2, transient local its 1, depth 1.
    let sensor = Qos {
        reliability: Reliability::BestEffort,
        durability: Durability::TransientLocal,
        depth: 1,
    };
    assert_eq!(sensor.token_string(), "2:1:,1:,:,:,,");
    // Depth 42 is rmw_zenoh's own default: left empty too.
    let deep = Qos {
        depth: 42,
        ..Qos::DEFAULT
    };
    assert_eq!(deep.token_string(), "::,:,:,:,,");
}

#[test]
fn the_node_token() {
    // @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<name>, with "/" (the
    // empty enclave) as "%" and "/snakectl" as "%snakectl".
    let node = Node::snakectl(0, ZID, "snakectl");
    assert_eq!(
        node.token(),
        format!("@ros2_lv/0/{ZID}/0/0/NN/%/%snakectl/snakectl")
    );
    // A prefix with a '/' is one chunk of the token.
    let node = Node::snakectl(3, ZID, "lab/arm_1");
    assert_eq!(
        node.token(),
        format!("@ros2_lv/3/{ZID}/0/0/NN/%/%lab%arm_1/snakectl")
    );
    // An empty enclave is "%" as well as the root "/".
    let mut node = Node::snakectl(0, ZID, "snakectl");
    node.enclave = String::new();
    assert_eq!(
        node.token(),
        format!("@ros2_lv/0/{ZID}/0/0/NN/%/%snakectl/snakectl")
    );
}

#[test]
fn publisher_and_subscription_tokens() {
    let node = Node::snakectl(0, ZID, "snakectl");
    // ... /<eid>/MP/<enclave>/<ns>/<node>/<topic, '/' as '%'>/<DDS type>/<hash>/<qos>
    let publisher = node.entity_token::<JointState>(
        1,
        EntityKind::Publisher,
        "/snakectl/joint_states",
        &Qos::DEFAULT,
    );
    assert_eq!(
        publisher,
        format!(
            "@ros2_lv/0/{ZID}/0/1/MP/%/%snakectl/snakectl/%snakectl%joint_states/\
             sensor_msgs::msg::dds_::JointState_/{JOINT_STATE_HASH}/::,10:,:,:,,"
        )
    );
    let subscription = node.entity_token::<Twist>(
        5,
        EntityKind::Subscription,
        "/snakectl/cmd_vel",
        &Qos::DEFAULT,
    );
    assert_eq!(
        subscription,
        format!(
            "@ros2_lv/0/{ZID}/0/5/MS/%/%snakectl/snakectl/%snakectl%cmd_vel/\
             geometry_msgs::msg::dds_::Twist_/\
             RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a/::,10:,:,:,,"
        )
    );
}

/// The GIDs below are XXH3-128 (seed 0) of the token strings, computed outside this crate by
/// the reference C library (libxxhash 0.8.1, `XXH3_128bits`), laid out as rmw_zenoh copies
/// them: `low64` little-endian, then `high64` little-endian. The tokens cover the hash's
/// length classes: 0, 17..=128, 129..=240 and over 240 bytes.
#[test]
fn gids_are_xxh3_128_of_the_token() {
    // The empty input: XXH3-128 = 0x99aa06d3014798d8_6001c324468d497f (xxHash's own vector).
    assert_eq!(
        gid(""),
        [
            0x7f, 0x49, 0x8d, 0x46, 0x24, 0xc3, 0x01, 0x60, 0xd8, 0x98, 0x47, 0x01, 0xd3, 0x06,
            0xaa, 0x99
        ]
    );
    let node = Node::snakectl(0, ZID, "snakectl");
    // 71 bytes: low 0x448d4effda5f993c, high 0xd97d151911f3faad.
    assert_eq!(node.token().len(), 71);
    assert_eq!(
        gid(&node.token()),
        [
            0x3c, 0x99, 0x5f, 0xda, 0xff, 0x4e, 0x8d, 0x44, 0xad, 0xfa, 0xf3, 0x11, 0x19, 0x15,
            0x7d, 0xd9
        ]
    );
    // 215 bytes: low 0x23257de8e0e471d5, high 0xec344068b12b6eca.
    let publisher = node.entity_token::<JointState>(
        1,
        EntityKind::Publisher,
        "/snakectl/joint_states",
        &Qos::DEFAULT,
    );
    assert_eq!(publisher.len(), 215);
    assert_eq!(
        gid(&publisher),
        [
            0xd5, 0x71, 0xe4, 0xe0, 0xe8, 0x7d, 0x25, 0x23, 0xca, 0x6e, 0x2b, 0xb1, 0x68, 0x40,
            0x34, 0xec
        ]
    );
    // 257 bytes: low 0x783dedd3e88ead49, high 0x2cc93bdf5fcadb04.
    let long = Node::snakectl(7, ZID, "lab/left_arm_of_the_bench_rig")
        .entity_token::<PointStamped>(
            3,
            EntityKind::Publisher,
            "/lab/left_arm_of_the_bench_rig/tip_meas",
            &Qos::DEFAULT,
        );
    assert_eq!(long.len(), 257);
    assert_eq!(
        gid(&long),
        [
            0x49, 0xad, 0x8e, 0xe8, 0xd3, 0xed, 0x3d, 0x78, 0x04, 0xdb, 0xca, 0x5f, 0xdf, 0x3b,
            0xc9, 0x2c
        ]
    );
}

#[test]
fn the_attachment_bytes() {
    let attachment = Attachment {
        sequence: 1,
        // 1.5 s after the epoch: 1_500_000_000 ns = 0x5968_2F00.
        source_timestamp_ns: 1_500_000_000,
        gid: [
            0x3c, 0x99, 0x5f, 0xda, 0xff, 0x4e, 0x8d, 0x44, 0xad, 0xfa, 0xf3, 0x11, 0x19, 0x15,
            0x7d, 0xd9,
        ],
    };
    let bytes = attachment.encode();
    let golden: Vec<u8> = [
        &[1, 0, 0, 0, 0, 0, 0, 0][..],         // sequence number 1, i64 LE
        &[0x00, 0x2F, 0x68, 0x59, 0, 0, 0, 0], // 1_500_000_000 ns, i64 LE
        &[0x10],                               // the GID's length, 16
        &[
            0x3c, 0x99, 0x5f, 0xda, 0xff, 0x4e, 0x8d, 0x44, // the GID
            0xad, 0xfa, 0xf3, 0x11, 0x19, 0x15, 0x7d, 0xd9,
        ],
    ]
    .concat();
    assert_eq!(bytes.len(), 33);
    assert_eq!(bytes.to_vec(), golden);
    assert_eq!(Attachment::decode(&bytes), Ok(attachment));
    // A negative sequence and a time before the epoch survive too (two's complement).
    let odd = Attachment {
        sequence: -2,
        source_timestamp_ns: -1,
        gid: [0xAB; 16],
    };
    assert_eq!(
        &odd.encode()[..16],
        &[
            0xFE, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, // -2
            0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, // -1
        ]
    );
    assert_eq!(Attachment::decode(&odd.encode()), Ok(odd));
}

#[test]
fn attachments_rmw_zenoh_would_drop_are_refused() {
    let good = Attachment {
        sequence: 7,
        source_timestamp_ns: 9,
        gid: [1; 16],
    }
    .encode();
    assert_eq!(
        Attachment::decode(&[]),
        Err(AttachmentError::Short { len: 0 })
    );
    assert_eq!(
        Attachment::decode(&good[..32]),
        Err(AttachmentError::Short { len: 32 })
    );
    let mut bad_length = good;
    bad_length[16] = 15;
    assert_eq!(
        Attachment::decode(&bad_length),
        Err(AttachmentError::GidLength { found: 15 })
    );
    // The keyed form of rmw_zenoh before Jazzy's 0.2.4 starts with the string
    // "sequence_number" (its length 15 as one byte, then the text): not this layout.
    let mut keyed = vec![15u8];
    keyed.extend_from_slice(b"sequence_number");
    keyed.extend_from_slice(&7i64.to_le_bytes());
    keyed.extend_from_slice(&[0; 30]);
    assert!(Attachment::decode(&keyed).is_err());
    // Trailing bytes are ignored.
    let mut longer = good.to_vec();
    longer.push(0);
    assert!(Attachment::decode(&longer).is_ok());
}

#[test]
fn ros_namespaces() {
    assert_eq!(namespace_problem("snakectl"), None);
    assert_eq!(namespace_problem("lab/arm_1"), None);
    assert!(namespace_problem("lab/arm-1").is_some());
    assert!(namespace_problem("lab/1arm").is_some());
    assert!(namespace_problem("lab//arm").is_some());
}
