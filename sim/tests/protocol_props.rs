//! Properties of the Protocol 2.0 framing on arbitrary bytes: the parser never panics and
//! reports every frame inside the chunk that completed it; encoded packets come back as they
//! were, however the stream is split; a packet behind garbage, or behind a packet cut short,
//! is still found (the parser resyncs on the next header).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use proptest::prelude::*;
use snakectl_sim::protocol::{
    crc16, encode_instruction, encode_status, stuff, unstuff, Frame, Packet, Parser, HEADER, STATUS,
};

/// Bytes with the framing bytes (FF, FD, 00) and whole headers common, so the parser's header,
/// length and stuffing paths are hit often.
fn wire_bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    let byte = prop_oneof![
        4 => any::<u8>(),
        2 => Just(0xFF),
        1 => Just(0xFD),
        1 => Just(0x00),
    ];
    let piece = prop_oneof![
        8 => byte.prop_map(|b| vec![b]),
        1 => Just(HEADER.to_vec()),
        1 => Just(vec![0xFF, 0xFF, 0xFD, 0xFD]),
    ];
    prop::collection::vec(piece, 0..max).prop_map(|p| p.concat())
}

/// Parameters with the byte sequences that need stuffing common.
fn params() -> impl Strategy<Value = Vec<u8>> {
    wire_bytes(80)
}

/// Feed `stream` split at `cuts` (fractions of its length), all at one instant; return every
/// frame, checking each reported end lies inside its chunk.
fn feed_split(parser: &mut Parser, stream: &[u8], cuts: &[f64], now: Instant) -> Vec<Frame> {
    let mut at: Vec<usize> = cuts
        .iter()
        .map(|c| ((stream.len() as f64) * c) as usize)
        .collect();
    at.push(0);
    at.push(stream.len());
    at.sort_unstable();
    let mut frames = Vec::new();
    for w in at.windows(2) {
        let chunk = &stream[w[0]..w[1]];
        for p in parser.feed(chunk, now) {
            assert!(p.end_in_chunk < chunk.len().max(1), "{p:?} in {chunk:02X?}");
            frames.push(p.frame);
        }
    }
    frames
}

fn first_header(bytes: &[u8]) -> Option<usize> {
    bytes.windows(HEADER.len()).position(|w| w == HEADER)
}

proptest! {
    #[test]
    fn arbitrary_chunks_at_arbitrary_times_never_panic(
        chunks in prop::collection::vec((wire_bytes(48), 0u64..120), 0..24),
    ) {
        let mut parser = Parser::default();
        let mut now = Instant::now();
        let mut fed = 0u64;
        for (chunk, gap_ms) in &chunks {
            now += Duration::from_millis(*gap_ms);
            for p in parser.feed(chunk, now) {
                prop_assert!(p.end_in_chunk < chunk.len(), "{:?} in {:02X?}", p, chunk);
            }
            fed += chunk.len() as u64;
            prop_assert!(parser.pending() as u64 + parser.skipped_bytes() <= fed);
        }
    }

    #[test]
    fn stuffing_round_trips_and_never_leaves_a_header_in_the_body(data in wire_bytes(120)) {
        let stuffed = stuff(&data);
        prop_assert_eq!(unstuff(&stuffed), data);
        prop_assert_eq!(first_header(&stuffed), None);
    }

    #[test]
    fn an_instruction_packet_round_trips_however_it_is_split(
        id in 0u8..=0xFE,
        instruction in any::<u8>(),
        params in params(),
        cuts in prop::collection::vec(0.0f64..1.0, 0..6),
    ) {
        let bytes = encode_instruction(id, instruction, &params);
        let mut parser = Parser::default();
        let frames = feed_split(&mut parser, &bytes, &cuts, Instant::now());
        prop_assert_eq!(frames, vec![Frame::Packet(Packet { id, instruction, params })]);
        prop_assert_eq!(parser.pending(), 0);
    }

    #[test]
    fn a_status_packet_round_trips_with_its_error_byte_first(
        id in 0u8..=0xFD,
        error in any::<u8>(),
        data in params(),
    ) {
        let bytes = encode_status(id, error, &data);
        let frames = Parser::default().feed(&bytes, Instant::now());
        let mut want = vec![error];
        want.extend_from_slice(&data);
        prop_assert_eq!(frames.len(), 1);
        prop_assert_eq!(
            &frames[0].frame,
            &Frame::Packet(Packet { id, instruction: STATUS, params: want })
        );
    }

    #[test]
    fn a_packet_behind_garbage_is_found(
        garbage in wire_bytes(60),
        trailing in wire_bytes(20),
        id in 0u8..=0xFE,
        instruction in any::<u8>(),
        params in params(),
        cuts in prop::collection::vec(0.0f64..1.0, 0..6),
    ) {
        let packet = encode_instruction(id, instruction, &params);
        let mut stream = garbage.clone();
        stream.extend_from_slice(&packet);
        // Garbage that itself opens a header is the next property's case: break every header
        // that starts inside it (FE is no header byte, so none appears in its place).
        while let Some(i) = first_header(&stream).filter(|&i| i < garbage.len()) {
            stream[i] = 0xFE;
        }
        stream.extend_from_slice(&trailing);
        let frames = feed_split(&mut Parser::default(), &stream, &cuts, Instant::now());
        prop_assert_eq!(
            frames.first(),
            Some(&Frame::Packet(Packet { id, instruction, params }))
        );
    }

    #[test]
    fn a_packet_behind_one_cut_short_is_found_once_the_frame_length_has_passed(
        cut_params in params(),
        missing in 4usize..40,
        id in 0u8..=0xFE,
        instruction in any::<u8>(),
        params in params(),
        cuts in prop::collection::vec(0.0f64..1.0, 0..6),
    ) {
        // A packet that broke off at least a header's length before its end...
        let cut = encode_instruction(7, 0x03, &cut_params);
        prop_assume!(cut.len() > 7 + missing);
        let cut = &cut[..cut.len() - missing];
        let packet = encode_instruction(id, instruction, &params);
        let mut stream = cut.to_vec();
        stream.extend_from_slice(&packet);
        // ...then enough quiet bytes for its declared length to be reached.
        stream.extend(std::iter::repeat_n(0u8, missing));
        prop_assume!(first_header(&stream[1..]).map(|i| i + 1) == Some(cut.len()));
        // The broken frame could, by a 1 in 65536 chance, carry a matching CRC.
        let total = cut.len() + missing;
        let crc = u16::from_le_bytes([stream[total - 2], stream[total - 1]]);
        prop_assume!(crc != crc16(&stream[..total - 2]));
        let frames = feed_split(&mut Parser::default(), &stream, &cuts, Instant::now());
        prop_assert_eq!(
            frames.first(),
            Some(&Frame::Packet(Packet { id, instruction, params }))
        );
    }
}
