//! Structure-aware mutation of model files: a valid model's MessagePack
//! payload is mutated (bit flips, MessagePack markers, IEEE-754 specials written over 8 bytes —
//! which lands in matrix data, stored as raw little-endian doubles —, truncation, deleted or
//! repeated chunks) and re-hashed, so that decoding gets past the SHA-256 check and exercises
//! the MessagePack structure and `Model::validate`. Shared by `tests/mutate.rs` (a few thousand
//! cases) and `examples/mutate.rs` (≥ 10⁶ cases), which both declare `mod model` (the fixture,
//! `support/model.rs`) beside `mod mutate`.

use crokf_formats::synthetic::SplitMix64 as Rng;
use crokf_formats::*;

/// The valid model the mutations start from: the tests' fixture (`support/model.rs`).
pub fn seed_model() -> Model {
    crate::model::small_model()
}

const MARKERS: [u8; 12] = [
    0x00, 0x7f, 0x80, 0x90, 0xa0, 0xc0, 0xc2, 0xc4, 0xcb, 0xcf, 0xdc, 0xff,
];
const SPECIALS: [f64; 5] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e308, -0.0];

/// Where the structure is: the start and length of every matrix's `data` bytes, and the
/// offset of every positive-fixint value that follows a key (`rows`, `cols`, `state_dim`,
/// `period`, indices…).
pub struct Landmarks {
    data: Vec<(usize, usize)>,
    small_ints: Vec<usize>,
}

impl Landmarks {
    pub fn of(payload: &[u8]) -> Landmarks {
        let mut data = Vec::new();
        let mut small_ints = Vec::new();
        for i in 0..payload.len() {
            if payload[i..].starts_with(b"\xa4data") {
                let at = i + 5;
                match payload.get(at) {
                    Some(0xc4) => data.push((at + 2, payload[at + 1] as usize)),
                    Some(0xc5) => data.push((
                        at + 3,
                        u16::from_be_bytes([payload[at + 1], payload[at + 2]]) as usize,
                    )),
                    _ => {}
                }
            }
            // A fixstr key (0xa0..0xbf) followed by a positive fixint.
            if (0xa1..=0xbf).contains(&payload[i]) {
                let end = i + 1 + (payload[i] - 0xa0) as usize;
                if end < payload.len()
                    && payload[i + 1..end]
                        .iter()
                        .all(|b| b.is_ascii_lowercase() || *b == b'_')
                    && payload[end] < 0x80
                {
                    small_ints.push(end);
                }
            }
        }
        Landmarks { data, small_ints }
    }
}

/// One mutation of `payload` in place: half of them aimed at the landmarks of the original
/// payload (a NaN/inf/huge double in a matrix's data, a changed small integer), the rest blind.
pub fn mutate(payload: &mut Vec<u8>, marks: &Landmarks, rng: &mut Rng) {
    let n = payload.len();
    if n == 0 {
        payload.push(MARKERS[rng.below(MARKERS.len())]);
        return;
    }
    match rng.below(10) {
        6 | 7 if !marks.data.is_empty() => {
            let (start, len) = marks.data[rng.below(marks.data.len())];
            if len >= 8 && start + len <= n {
                let at = start + 8 * rng.below(len / 8);
                let v = SPECIALS[rng.below(SPECIALS.len())];
                payload[at..at + 8].copy_from_slice(&v.to_le_bytes());
            }
        }
        8 | 9 if !marks.small_ints.is_empty() => {
            let at = marks.small_ints[rng.below(marks.small_ints.len())];
            if at < n {
                payload[at] = rng.below(8) as u8;
            }
        }
        _ => mutate_blind(payload, rng),
    }
}

fn mutate_blind(payload: &mut Vec<u8>, rng: &mut Rng) {
    let n = payload.len();
    match rng.below(6) {
        0 => payload[rng.below(n)] ^= 1 << rng.below(8),
        1 => payload[rng.below(n)] = MARKERS[rng.below(MARKERS.len())],
        2 if n >= 8 => {
            let at = rng.below(n - 7);
            let v = SPECIALS[rng.below(SPECIALS.len())];
            payload[at..at + 8].copy_from_slice(&v.to_le_bytes());
        }
        3 => payload.truncate(rng.below(n)),
        4 => {
            let at = rng.below(n);
            let len = 1 + rng.below(16.min(n - at));
            payload.drain(at..at + len);
        }
        _ => {
            let at = rng.below(n);
            let len = 1 + rng.below(16.min(n - at));
            let chunk: Vec<u8> = payload[at..at + len].to_vec();
            let to = rng.below(n);
            payload.splice(to..to, chunk);
        }
    }
}

/// Outcome counts.
#[derive(Debug, Default)]
pub struct Tally {
    pub cases: u64,
    pub accepted: u64,
    pub non_finite: u64,
    pub invalid: u64,
    pub message_pack: u64,
    pub other: u64,
}

/// Decodes `cases` mutated, re-hashed payloads; panics (test failure) if a decode panics or an
/// accepted model is not valid, finite and stable under re-encoding.
pub fn run(cases: u64, seed: u64) -> Tally {
    let base = encode_payload(&seed_model());
    let marks = Landmarks::of(&base);
    let mut rng = Rng(seed);
    let mut tally = Tally::default();
    for _ in 0..cases {
        let mut payload = base.clone();
        for _ in 0..1 + rng.below(2) {
            mutate(&mut payload, &marks, &mut rng);
        }
        let file = wrap_payload(&payload);
        let result = std::panic::catch_unwind(|| decode(&file));
        let Ok(result) = result else {
            panic!("decode panicked on payload {payload:02x?}");
        };
        tally.cases += 1;
        match result {
            Ok(model) => {
                tally.accepted += 1;
                assert!(model.validate().is_ok());
                let again = decode(&encode(&model)).expect("re-encoded model decodes");
                assert_eq!(again, model);
            }
            Err(FormatError::NonFinite { .. }) => tally.non_finite += 1,
            Err(
                FormatError::Invalid { .. }
                | FormatError::Shape { .. }
                | FormatError::DataLength { .. },
            ) => tally.invalid += 1,
            Err(FormatError::MessagePack(_)) => tally.message_pack += 1,
            Err(_) => tally.other += 1,
        }
    }
    tally
}
