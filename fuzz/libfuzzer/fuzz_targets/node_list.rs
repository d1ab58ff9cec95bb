//! Node-list bytes → a `[[fixed]]` selection on the small box mesh: an accepted list fixes
//! exactly its tags, a valid list is accepted (`crokf_fuzz::node_list`).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

static MESH: OnceLock<crokf_fuzz::MeshFixture> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let mesh = MESH.get_or_init(crokf_fuzz::scene_mesh);
    if let Err(v) = crokf_fuzz::node_list(data, mesh) {
        panic!("invariant: {}", v.0);
    }
});
