//! Bad bytes never panic the simulator and never stop it from answering a good packet.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::Duration;

use common::*;
use snakectl_sim::protocol::{self, instruction as ins};
use snakectl_sim::rng::SplitMix64;

#[test]
fn random_and_mutated_traffic_is_survived() {
    let (mut s, clock) = sim(xl430(&[1, 2, 3]));
    let mut rng = SplitMix64::new(2024);
    let templates = [
        protocol::encode_instruction(1, ins::READ, &read_params(132, 4)),
        protocol::encode_instruction(2, ins::WRITE, &write_params(116, &[0, 8, 0, 0])),
        protocol::encode_instruction(0xFE, ins::SYNC_READ, &[132, 0, 4, 0, 1, 2, 3]),
        protocol::encode_instruction(0xFE, ins::BULK_READ, &[1, 132, 0, 4, 0, 2, 0, 0, 2, 0]),
        protocol::encode_instruction(0xFE, ins::BULK_WRITE, &[3, 65, 0, 1, 0, 1]),
        protocol::encode_instruction(3, ins::FACTORY_RESET, &[0x02]),
        protocol::encode_instruction(1, ins::REG_WRITE, &write_params(65, &[1])),
    ];
    for round in 0..3000 {
        let mut bytes = match rng.below(3) {
            0 => (0..rng.below(40)).map(|_| rng.next_u64() as u8).collect(),
            1 => {
                let mut t = templates[rng.below(templates.len())].clone();
                let k = rng.below(t.len());
                t[k] ^= 1 << rng.below(8);
                t
            }
            _ => {
                let t = &templates[rng.below(templates.len())];
                t[..rng.below(t.len())].to_vec()
            }
        };
        if round % 7 == 0 {
            bytes.extend_from_slice(&[0xFF, 0xFF, 0xFD, 0x00]);
        }
        s.handle_bytes(&bytes);
        clock.advance(Duration::from_millis(1 + rng.below(80) as u64));
    }
    // After the noise, with a pause longer than the inter-byte timeout, a ping is answered.
    clock.advance(Duration::from_millis(100));
    let r = send(&mut s, 1, ins::PING, &[]);
    assert_eq!(r.len(), 1);
    assert!(s.stats().crc_errors > 0);
}
