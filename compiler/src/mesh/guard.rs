//! The last line of defence around the third-party parsers (`mshio`, `vtkio`'s legacy reader):
//! their input is validated before they see it, and a panic that still happens inside one is
//! caught here and becomes a typed error of the reader. Nothing of the panic (its message, the
//! path into the dependency's source) is printed: the process-wide panic hook is chained once
//! with a hook that stays silent while the current thread is inside [`quietly`] and defers to
//! the previous hook everywhere else.
//!
//! [`caught_panics`] counts the panics caught here since the process started, so that the fuzz
//! driver can tell a reader that refused an input from one that only survived it.

use std::cell::Cell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Once;

thread_local! {
    /// Depth of nested [`quietly`] calls on this thread.
    static GUARDED: Cell<u32> = const { Cell::new(0) };
}

static HOOK: Once = Once::new();
static CAUGHT: AtomicU64 = AtomicU64::new(0);

fn install_hook() {
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if GUARDED.with(Cell::get) == 0 {
                previous(info);
            }
        }));
    });
}

/// Runs `f`; a panic inside it is caught, counted and returned as `Err(())` without anything
/// printed.
pub(crate) fn quietly<T>(f: impl FnOnce() -> T) -> Result<T, ()> {
    install_hook();
    GUARDED.with(|g| g.set(g.get() + 1));
    let result = catch_unwind(AssertUnwindSafe(f));
    GUARDED.with(|g| g.set(g.get().saturating_sub(1)));
    result.map_err(|_| {
        CAUGHT.fetch_add(1, Ordering::Relaxed);
    })
}

/// Panics of a third-party parser caught by the mesh readers since the process started (a
/// correct pre-validation keeps this at 0; the fuzz driver reports every increase).
pub fn caught_panics() -> u64 {
    CAUGHT.load(Ordering::Relaxed)
}
