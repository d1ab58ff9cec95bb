//! Stage costs of a compile: wall-clock time and peak resident memory per stage, recorded by
//! every stage from the front end ([`crate::full_order`]) on and written by [`crate::report`].

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

/// Wall-clock time and peak resident memory of one stage.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct StageCost {
    /// Wall-clock time, s.
    pub seconds: f64,
    /// Peak resident set size during the stage, MiB (Linux `VmHWM`, reset per stage when the
    /// kernel allows; otherwise the peak since the process started). NaN where unavailable.
    pub peak_memory_mib: f64,
}

/// Times stages and records their peak memory.
#[derive(Debug, Default)]
pub struct StageTimer {
    /// Stage name → cost, in insertion order of names (BTreeMap: sorted by name).
    pub stages: BTreeMap<String, StageCost>,
    /// Stage names in the order they ran.
    pub order: Vec<String>,
}

impl StageTimer {
    /// Runs `f` as stage `name`.
    pub fn stage<T>(&mut self, name: &str, f: impl FnOnce() -> T) -> T {
        reset_peak_memory();
        let start = Instant::now();
        let out = f();
        let cost = StageCost {
            seconds: start.elapsed().as_secs_f64(),
            peak_memory_mib: peak_memory_mib(),
        };
        self.order.push(name.to_owned());
        self.stages.insert(name.to_owned(), cost);
        out
    }

    /// Total wall-clock time, s.
    pub fn total_seconds(&self) -> f64 {
        self.stages.values().map(|c| c.seconds).sum()
    }

    /// Largest per-stage peak, MiB.
    pub fn peak_memory_mib(&self) -> f64 {
        self.stages
            .values()
            .map(|c| c.peak_memory_mib)
            .fold(f64::NAN, f64::max)
    }
}

/// Resets the kernel's peak-RSS counter of this process (Linux ≥ 4.0; no-op elsewhere).
fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident set size (VmHWM) in MiB, NaN when unavailable.
pub fn peak_memory_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
