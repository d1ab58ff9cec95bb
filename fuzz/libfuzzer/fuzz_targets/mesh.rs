//! Mesh bytes (any format the reader recognises) → an accepted mesh must keep the invariants
//! of `crokf_fuzz::mesh`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(v) = crokf_fuzz::mesh(data, "fuzz.msh") {
        panic!("invariant: {}", v.0);
    }
});
