//! Limits on what a mesh file may claim (docs/limits.md): every size read from a file is checked
//! against the bytes that actually follow it, or against what a compressor can produce from
//! them, and against a stated cap, before anything of that size is allocated.

/// Total decoded bytes of the binary data arrays of one VTK XML file (4 GiB: about 30 million
/// tetrahedra with their points, far beyond what the compiler's dense reduction handles).
pub const VTU_DECODED_BYTES: u64 = 1 << 32;

/// Largest expansion of a zlib (deflate) stream: 258 bytes from a 2-bit code at best, about
/// 1032 : 1; a block header claiming more than `ZLIB_RATIO` × its compressed size is refused.
pub const ZLIB_RATIO: u64 = 1032;

/// Largest expansion of an LZ4 block (255 match bytes per extra length byte), rounded up.
pub const LZ4_RATIO: u64 = 256;

/// Largest coordinate magnitude of a mesh node, mesh units (the scene's limit on every
/// coordinate: `crate::scene::limits::COORDINATE`).
pub const COORDINATE: f64 = crate::scene::limits::COORDINATE;
