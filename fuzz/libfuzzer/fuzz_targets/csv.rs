//! The same bytes as an inputs and as a measurements CSV of the committed cantilever model.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

static FIXTURES: OnceLock<crokf_fuzz::Fixtures> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let f = FIXTURES.get_or_init(|| crokf_fuzz::Fixtures::load().expect("fixtures"));
    if let Err(v) = crokf_fuzz::csv(data, data, &f.model) {
        panic!("invariant: {}", v.0);
    }
});
