//! Build script: a digest of the source this crate's training runs are computed by (this
//! crate's `src/` and the element kernels' `../kernel/src/`), exposed as
//! `CROKF_TRAINING_SOURCE` to `nonlinear::cases`. A cached training case carries it in its
//! identity, so a cache filled by another build of the compiler is never reused: any edit of
//! the source is a new identity (docs/design.md §10, training as cases).

use std::path::{Path, PathBuf};

/// FNV-1a, 64 bit: a change detector over the source files (not a cryptographic hash; the
/// case identity itself is SHA-256 over this digest and the case's inputs).
fn fnv1a(state: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(state, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

fn main() {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let mut digest = 0xcbf2_9ce4_8422_2325u64;
    for root in ["src", "../kernel/src"] {
        let dir = manifest.join(root);
        println!("cargo:rerun-if-changed={}", dir.display());
        let mut list = Vec::new();
        files(&dir, &mut list);
        // Sorted by the path below the root: the digest does not depend on where the tree
        // lies or on the order the file system lists it in.
        let mut named: Vec<(String, PathBuf)> = list
            .into_iter()
            .map(|p| {
                let name = p
                    .strip_prefix(&dir)
                    .unwrap_or(&p)
                    .to_string_lossy()
                    .into_owned();
                (format!("{root}/{name}"), p)
            })
            .collect();
        named.sort();
        for (name, path) in named {
            digest = fnv1a(digest, name.as_bytes());
            digest = fnv1a(digest, &[0]);
            digest = fnv1a(digest, &std::fs::read(&path).unwrap_or_default());
            digest = fnv1a(digest, &[0]);
        }
    }
    println!("cargo:rustc-env=CROKF_TRAINING_SOURCE={digest:016x}");
}
