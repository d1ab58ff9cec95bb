//! A model file's payload without the hash (so validation, not the hash check, is exercised):
//! decoding must refuse or return a model that passes validation; never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = crokf_formats::decode_payload(data);
});
