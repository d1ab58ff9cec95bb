//! Progress of a long step on stderr: `PREFIX: WHAT: done/total UNITS done, ELAPSED elapsed,
//! about LEFT left`, redrawn in place on one line. Silent when stderr is not a terminal (logs
//! and pipes get nothing, so no carriage returns end up in them).
//!
//! The estimate is linear: the time left is the elapsed time per unit done times the units
//! left; it is shown once a unit is done. A step whose total may still grow (an eigen-solve
//! whose wanted count doubles while every mode found is below a cut-off) says so: `12/32+ modes
//! done, …, about 9 s left for 32`; when its total changes, the rate restarts from there (the
//! units toward the new total are timed on their own). A line can wait (`Progress::after`): a
//! step that ends sooner prints nothing.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// The prefix of the lines this library writes to stderr: the running crokf binary's name
/// (`crokf-compile`, `crokf-verify`, …), or `crokf` inside another program (Python).
pub fn program() -> String {
    executable_stem()
        .filter(|name| name.starts_with("crokf-"))
        .unwrap_or_else(|| "crokf".to_owned())
}

/// The running executable's file stem (`tier_scale` for `target/release/examples/tier_scale`);
/// None when the OS gives no (or an empty) name.
pub fn executable_stem() -> Option<String> {
    std::env::args_os()
        .next()
        .and_then(|a| {
            std::path::Path::new(&a)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
        })
        .filter(|name| !name.is_empty())
}

/// Shortest interval between two redraws (the last unit is always drawn).
const REDRAW: Duration = Duration::from_millis(200);

/// One long step's progress line.
#[derive(Debug)]
pub struct Progress {
    label: String,
    units: String,
    total: usize,
    /// Whether `total` may still grow.
    open: bool,
    started: Instant,
    /// When the total was last changed and the units done then: the estimate's rate is timed
    /// from there.
    base: (Instant, usize),
    /// Nothing is drawn before this much time has passed since `started`.
    delay: Duration,
    shown: Option<Instant>,
    terminal: bool,
}

impl Progress {
    /// A progress line `label: done/total units done, …` (e.g. label `crokf-compile:
    /// co-rotational training`, units `runs`), drawn only when stderr is a terminal.
    pub fn new(label: &str, units: &str, total: usize) -> Self {
        let started = Instant::now();
        Progress {
            label: label.to_owned(),
            units: units.to_owned(),
            total,
            open: false,
            started,
            base: (started, 0),
            delay: Duration::ZERO,
            shown: None,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    /// The same line drawn only once `delay` has passed since its start: a step that ends
    /// sooner prints nothing.
    pub fn after(mut self, delay: Duration) -> Self {
        self.delay = delay;
        self
    }

    /// Sets the total, and whether it may still grow (`done/total+`, the estimate `for total`),
    /// with `done` units done now. A changed total restarts the estimate's rate from here.
    pub fn set_total(&mut self, total: usize, open: bool, done: usize) {
        if total != self.total {
            self.base = (Instant::now(), done);
        }
        self.total = total;
        self.open = open;
    }

    /// Redraws the line with `done` units done (at most every 0.2 s, and always at the total).
    pub fn update(&mut self, done: usize) {
        if !self.terminal {
            return;
        }
        let now = Instant::now();
        let since_shown = self.shown.map(|t| now - t);
        if due(
            now - self.started,
            self.delay,
            since_shown,
            done >= self.total,
        ) {
            self.draw(done, now);
        }
    }

    /// Draws the line with every unit done and ends it.
    pub fn finish(&mut self) {
        self.finish_at(self.total);
    }

    /// Draws the line with `done` units done and ends it (nothing when it was never drawn and
    /// its delay has not passed).
    pub fn finish_at(&mut self, done: usize) {
        if !self.terminal {
            return;
        }
        let now = Instant::now();
        if self.shown.is_some() || now - self.started >= self.delay {
            self.draw(done, now);
            eprintln!();
        }
        self.terminal = false;
    }

    fn draw(&mut self, done: usize, now: Instant) {
        self.shown = Some(now);
        let (since, base_done) = self.base;
        let left = time_left_since(base_done, done, self.total, now - since);
        let text = text(
            &self.label,
            &self.units,
            (done, self.total, self.open && done < self.total),
            now - self.started,
            left,
        );
        // "\r" returns to the line's start, "\x1b[K" clears the rest of a longer earlier line.
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r{text}\x1b[K");
        let _ = err.flush();
    }
}

/// Whether a line is drawn now: not before its delay, then at most every 0.2 s (`since_shown`:
/// the time since the last drawing), always at the total.
fn due(elapsed: Duration, delay: Duration, since_shown: Option<Duration>, at_total: bool) -> bool {
    if since_shown.is_none() && elapsed < delay {
        return false;
    }
    at_total || since_shown.is_none_or(|t| t >= REDRAW)
}

/// The progress text: `label: done/total units done, ELAPSED elapsed, about LEFT left` (`, time
/// left not yet known` before the first unit; no time left at the total).
pub fn line(label: &str, units: &str, done: usize, total: usize, elapsed: Duration) -> String {
    let left = time_left(done, total, elapsed);
    text(label, units, (done, total, false), elapsed, left)
}

/// The text of `count` = (done, total, open): [`line`]'s, or for a total that may still grow
/// (`open`) `label: done/total+ units done, ELAPSED elapsed, about LEFT left for total` (the
/// estimate reaches the total so far, not beyond).
fn text(
    label: &str,
    units: &str,
    (done, total, open): (usize, usize, bool),
    elapsed: Duration,
    left: Option<Duration>,
) -> String {
    let plus = if open { "+" } else { "" };
    let head = format!(
        "{label}: {done}/{total}{plus} {units} done, {} elapsed",
        duration(elapsed)
    );
    if done >= total {
        return head;
    }
    let target = if open {
        format!(" for {total}")
    } else {
        String::new()
    };
    match left {
        Some(left) => format!("{head}, about {} left{target}", duration(left)),
        None => format!("{head}, time left not yet known"),
    }
}

/// [`time_left`] at the rate measured since the total last changed, when `base_done` units were
/// done `since` ago: that time per unit done since, times the units left; `None` until a unit
/// is done after the change.
pub fn time_left_since(
    base_done: usize,
    done: usize,
    total: usize,
    since: Duration,
) -> Option<Duration> {
    time_left(
        done.saturating_sub(base_done),
        total.saturating_sub(base_done),
        since,
    )
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
    fn a_delayed_line_waits_then_redraws_at_most_every_fifth_of_a_second() {
        let s = Duration::from_secs;
        let ms = Duration::from_millis;
        // Before the delay nothing is drawn, not even at the total.
        assert!(!due(ms(1500), s(2), None, false));
        assert!(!due(ms(1500), s(2), None, true));
        // From the delay on, the first drawing, then every 0.2 s, and always the total.
        assert!(due(s(2), s(2), None, false));
        assert!(!due(ms(2100), s(2), Some(ms(100)), false));
        assert!(due(ms(2100), s(2), Some(ms(100)), true));
        assert!(due(ms(2300), s(2), Some(ms(300)), false));
        // No delay: the first call draws.
        assert!(due(Duration::ZERO, Duration::ZERO, None, false));
    }

    #[test]
    fn a_total_that_may_grow_is_marked_and_the_estimate_names_it() {
        let at = |done, total, secs, left: Option<u64>| {
            text(
                "tool: eigen-solve",
                "modes",
                (done, total, true),
                Duration::from_secs(secs),
                left.map(Duration::from_secs),
            )
        };
        assert_eq!(
            at(0, 16, 2, None),
            "tool: eigen-solve: 0/16+ modes done, 2 s elapsed, time left not yet known"
        );
        assert_eq!(
            at(12, 32, 9, Some(15)),
            "tool: eigen-solve: 12/32+ modes done, 9 s elapsed, about 15 s left for 32"
        );
    }

    #[test]
    fn after_the_total_changes_the_rate_is_timed_from_the_change() {
        // The wanted count grew from 32 to 60 with 32 modes done; 8 more took 18 s: 20 left at
        // 2.25 s each (the rate since the start, 53 s for 40 modes, would say 26 s).
        assert_eq!(
            time_left_since(32, 40, 60, Duration::from_secs(18)),
            Some(Duration::from_secs(45))
        );
        // Nothing done since the change: not yet known.
        assert_eq!(time_left_since(32, 32, 60, Duration::from_secs(5)), None);
        // From the start (base 0) it is the plain linear estimate.
        assert_eq!(
            time_left_since(0, 4, 10, Duration::from_secs(20)),
            time_left(4, 10, Duration::from_secs(20))
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
