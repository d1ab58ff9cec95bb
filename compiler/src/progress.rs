//! Progress of a long step on stderr: `PREFIX: WHAT: done/total UNITS done, ELAPSED elapsed,
//! about LEFT left`, redrawn in place on one line. Silent when stderr is not a terminal (logs
//! and pipes get nothing, so no carriage returns end up in them).
//!
//! The estimate is linear: the time left is the elapsed time per unit done times the units
//! left; it is shown once a unit is done.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// The prefix of the lines this library writes to stderr: the running crokf binary's name
/// (`crokf-compile`, `crokf-verify`, …), or `crokf` inside another program (Python).
pub fn program() -> String {
    std::env::args_os()
        .next()
        .and_then(|a| {
            std::path::Path::new(&a)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
        })
        .filter(|name| name.starts_with("crokf-"))
        .unwrap_or_else(|| "crokf".to_owned())
}

/// Shortest interval between two redraws (the last unit is always drawn).
const REDRAW: Duration = Duration::from_millis(200);

/// One long step's progress line.
#[derive(Debug)]
pub struct Progress {
    label: String,
    units: String,
    total: usize,
    started: Instant,
    shown: Option<Instant>,
    terminal: bool,
}

impl Progress {
    /// A progress line `label: done/total units done, …` (e.g. label `crokf-compile:
    /// co-rotational training`, units `runs`), drawn only when stderr is a terminal.
    pub fn new(label: &str, units: &str, total: usize) -> Self {
        Progress {
            label: label.to_owned(),
            units: units.to_owned(),
            total,
            started: Instant::now(),
            shown: None,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    /// Redraws the line with `done` units done (at most every 0.2 s, and always at the total).
    pub fn update(&mut self, done: usize) {
        if !self.terminal {
            return;
        }
        let now = Instant::now();
        if done < self.total && self.shown.is_some_and(|t| now - t < REDRAW) {
            return;
        }
        self.shown = Some(now);
        let text = line(
            &self.label,
            &self.units,
            done,
            self.total,
            self.started.elapsed(),
        );
        // "\r" returns to the line's start, "\x1b[K" clears the rest of a longer earlier line.
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r{text}\x1b[K");
        let _ = err.flush();
    }

    /// Draws the line with every unit done and ends it.
    pub fn finish(&mut self) {
        if !self.terminal {
            return;
        }
        self.update(self.total);
        eprintln!();
        self.terminal = false;
    }
}

/// The progress text: `label: done/total units done, ELAPSED elapsed, about LEFT left` (`, time
/// left not yet known` before the first unit; no time left at the total).
pub fn line(label: &str, units: &str, done: usize, total: usize, elapsed: Duration) -> String {
    let head = format!(
        "{label}: {done}/{total} {units} done, {} elapsed",
        duration(elapsed)
    );
    if done >= total {
        return head;
    }
    match time_left(done, total, elapsed) {
        Some(left) => format!("{head}, about {} left", duration(left)),
        None => format!("{head}, time left not yet known"),
    }
}

/// Linear estimate of the time left: elapsed / done × (total − done); `None` before the first
/// unit is done.
pub fn time_left(done: usize, total: usize, elapsed: Duration) -> Option<Duration> {
    if done == 0 {
        return None;
    }
    let left = total.saturating_sub(done) as f64;
    Some(elapsed.mul_f64(left / done as f64))
}

/// `42 s`, `3 min 05 s`, `2 h 07 min` (seconds rounded down).
pub fn duration(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, s % 3600 / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_program_that_is_not_a_crokf_binary_is_named_crokf() {
        // The test harness's executable is `crokf_compile-HASH`, not a `crokf-` binary.
        assert_eq!(program(), "crokf");
    }

    #[test]
    fn durations_read_as_seconds_minutes_hours() {
        assert_eq!(duration(Duration::from_millis(900)), "0 s");
        assert_eq!(duration(Duration::from_secs(59)), "59 s");
        assert_eq!(duration(Duration::from_secs(185)), "3 min 05 s");
        assert_eq!(duration(Duration::from_secs(7620)), "2 h 07 min");
    }

    #[test]
    fn the_time_left_is_the_elapsed_time_per_unit_times_the_units_left() {
        assert_eq!(time_left(0, 10, Duration::from_secs(5)), None);
        assert_eq!(
            time_left(4, 10, Duration::from_secs(20)),
            Some(Duration::from_secs(30))
        );
        assert_eq!(
            time_left(10, 10, Duration::from_secs(20)),
            Some(Duration::ZERO)
        );
        assert_eq!(
            time_left(12, 10, Duration::from_secs(20)),
            Some(Duration::ZERO)
        );
    }

    #[test]
    fn the_line_states_done_total_elapsed_and_left() {
        let at = |done, secs| {
            line(
                "tool: training",
                "runs",
                done,
                40,
                Duration::from_secs(secs),
            )
        };
        assert_eq!(
            at(0, 3),
            "tool: training: 0/40 runs done, 3 s elapsed, time left not yet known"
        );
        assert_eq!(
            at(10, 75),
            "tool: training: 10/40 runs done, 1 min 15 s elapsed, about 3 min 45 s left"
        );
        assert_eq!(
            at(40, 300),
            "tool: training: 40/40 runs done, 5 min 00 s elapsed"
        );
    }
}
