//! Scene text → parse, range checks, selections, assembly and operators on a small box mesh;
//! an accepted scene must keep the invariants of `crokf_fuzz::scene`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

static MESH: OnceLock<crokf_fuzz::MeshFixture> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let mesh = MESH.get_or_init(crokf_fuzz::scene_mesh);
    if let Err(v) = crokf_fuzz::scene(data, mesh) {
        panic!("invariant: {}", v.0);
    }
});
