//! The runtime's shared library and a C program built against it, for the tests of the C ABI
//! (runtime/tests/capi_c.rs, header.rs and, through `#[path]`, tests/tests/contact.rs).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The freshest `libcrokf_runtime.so` next to this test binary (…/deps or its parent), or
/// `$CROKF_RUNTIME_LIB`.
pub fn find_cdylib() -> PathBuf {
    if let Some(p) = std::env::var_os("CROKF_RUNTIME_LIB") {
        return PathBuf::from(p);
    }
    let name = format!(
        "{}crokf_runtime{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    let exe = std::env::current_exe().expect("the test binary path");
    let mut candidates: Vec<PathBuf> = exe
        .ancestors()
        .skip(1)
        .take(3)
        .map(|d| d.join(&name))
        .filter(|p| p.is_file())
        .collect();
    candidates.sort_by_key(|p| std::fs::metadata(p).and_then(|m| m.modified()).ok());
    candidates.pop().unwrap_or_else(|| {
        panic!(
            "{name} not found near {}; build the runtime crate first",
            exe.display()
        )
    })
}

/// Compiles the C program `source` against `runtime/include` and the shared library into
/// `exe` with `$CC` (default `cc`), warnings as errors; panics with the compiler's output.
#[allow(dead_code)]
pub fn compile_c(source: &Path, exe: &Path) {
    let include = Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime/include");
    let lib = find_cdylib();
    let lib_dir = lib.parent().expect("the library's folder");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let out = Command::new(&cc)
        .arg(source)
        .arg("-I")
        .arg(include)
        .arg("-Wall")
        .arg("-Werror")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib_dir.display()))
        .arg("-o")
        .arg(exe)
        .output()
        .expect("C compiler runs");
    assert!(
        out.status.success(),
        "{cc} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
