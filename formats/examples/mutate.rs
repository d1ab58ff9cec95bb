//! The long structure-aware mutation run of the model-file decoder:
//! `cargo run --release -p crokf-formats --example mutate -- [CASES] [SEED]` (default 10⁶).
//! Prints the case count, the outcomes and the time; a panic or an accepted invalid model
//! aborts with the payload.

#[path = "../tests/support/model.rs"]
mod model;
#[path = "../tests/support/mutate.rs"]
mod mutate;

fn main() {
    let mut args = std::env::args().skip(1);
    let cases = args
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or(1_000_000u64);
    let seed = args.next().and_then(|a| a.parse().ok()).unwrap_or(1u64);
    let start = std::time::Instant::now();
    let t = mutate::run(cases, seed);
    println!(
        "{} mutated, re-hashed model files in {:.1} s: {} accepted (valid, finite, round-trip), {} non-finite refused, {} invalid refused, {} MessagePack errors, {} other",
        t.cases,
        start.elapsed().as_secs_f64(),
        t.accepted,
        t.non_finite,
        t.invalid,
        t.message_pack,
        t.other
    );
}
