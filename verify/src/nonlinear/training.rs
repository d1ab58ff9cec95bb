//! Training runs of the co-rotational tier: the compiler's driver
//! (`crokf_compile::nonlinear::training`, docs/design.md §10 item 2), re-exported so the
//! verification drivers and examples use the same runs as `crokf-compile`.

pub use crokf_compile::nonlinear::training::*;
