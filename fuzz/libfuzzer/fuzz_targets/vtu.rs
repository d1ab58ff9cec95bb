//! VTK bytes (XML or legacy) → an accepted mesh must keep the invariants of `crokf_fuzz::mesh`,
//! and no third-party parser may panic (even when the reader catches it).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(v) = crokf_fuzz::vtu(data) {
        panic!("invariant: {}", v.0);
    }
});
