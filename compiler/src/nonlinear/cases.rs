//! The training as independent cases (docs/design.md §10, training as cases): each run of a
//! [`TrainingPlan`] is a case with a content identity, and its result (snapshots, Newton
//! counters, or why it failed) is a file in a cache folder. A compile given a cache uses the
//! cases it finds there and runs and stores the rest, so an interrupted compile resumes and
//! loses only the cases in flight; cases can also be computed elsewhere (a job array, Dask
//! workers: `crokf.distributed`) and gathered into the folder before the compile.
//!
//! A case's identity is SHA-256 over: the compiler source digest (`build.rs`: any edit of the
//! source is a new identity), the scene's input digest (scene text and node lists, mesh bytes,
//! compiler version), the time step, the plan's settings (ranges, histories, duration,
//! snapshot interval, Newton options; not the thread count, which does not change results),
//! the case's index and its run (label, loaded groups and directions, history). Editing the
//! scene in any way therefore invalidates its cases.
//!
//! Case file (`<identity>.case`, little-endian):
//!
//! ```text
//! "CROKFCASE\0"  u32 version  64 bytes identity (ASCII hex)
//! u8 status: 0 = ran, 1 = failed
//!   ran:    u64 snapshots  u64 dofs  snapshots·dofs f64
//!           u64 steps, solves, unconverged, fallbacks, factorisations
//!           f64 worst increment, assembly s, factor s, solve s
//!   failed: u64 length  UTF-8 message
//! 32 bytes SHA-256 of everything before
//! ```
//!
//! A file that does not decode (truncated, another identity, wrong sizes, checksum) is never
//! used: the case is run again and the file replaced.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::full_order::FullOrder;
use crate::stepping::NewtonStats;

use super::training::{run_case, train_each, RunResult, Training, TrainingPlan};
use super::NonlinearError;

/// Version of the case file layout.
pub const CASE_FILE_VERSION: u32 = 1;

/// File name extension of a case file.
pub const CASE_EXTENSION: &str = "case";

/// Digest of the compiler source the training is computed by (`build.rs`).
pub const TRAINING_SOURCE: &str = env!("CROKF_TRAINING_SOURCE");

const MAGIC: &[u8; 10] = b"CROKFCASE\0";

/// One training run as a case: its index in [`TrainingPlan::runs`], its identity and label.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Case {
    /// Index in the plan's run order.
    pub index: usize,
    /// SHA-256 of the case's inputs (module doc), 64 hex digits.
    pub id: String,
    /// The run's label, e.g. `tip (+0, +0, -1) ramp 1.25×`.
    pub label: String,
}

/// A case's result: the snapshots (each n, m) and Newton counters, or why the run failed.
pub type CaseResult = RunResult;

/// The cases of `plan` on the scene `full` was built from, in run order.
pub fn cases(full: &FullOrder, plan: &TrainingPlan) -> Vec<Case> {
    let digest = full.digest();
    let mut settings = plan.clone();
    settings.threads = 1;
    let common = format!(
        "crokf training case\0source {TRAINING_SOURCE}\0scene {}\0mesh {}\0{}\0dt {:?}\0plan {settings:?}",
        digest.scene_sha256, digest.mesh_sha256, digest.compiler_version, full.wilson.dt
    );
    plan.runs()
        .into_iter()
        .enumerate()
        .map(|(index, run)| {
            let mut h = Sha256::new();
            h.update(common.as_bytes());
            h.update(format!("\0case {index}\0{run:?}").as_bytes());
            Case {
                index,
                id: hex(&h.finalize()),
                label: run.label,
            }
        })
        .collect()
}

/// [`train`](super::training::train) with a case cache: a run whose case file is in `cache`
/// is read from it, the others are run and stored as each finishes (so an interrupted compile
/// loses only the runs in flight). The snapshots are bit for bit those of `train`;
/// [`Training::cached`] counts the runs read, [`Training::cache_notes`] names the files that
/// could not be used or stored.
pub fn train_cached(
    full: &FullOrder,
    plan: &TrainingPlan,
    cache: &CaseCache,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Training, NonlinearError> {
    let list = cases(full, plan);
    let snapshots = plan.snapshot_count(full.wilson.dt);
    let dofs = full.fem.dof_count();
    let (mut training, extra) = train_each(full, plan, progress, |k, compute| {
        let case = &list[k];
        let mut notes = Vec::new();
        match cache.lookup(case, dofs, snapshots) {
            Lookup::Found(result) => return (result, (true, notes)),
            Lookup::Missing => {}
            Lookup::Unusable(why) => notes.push(format!("{why}; case run again")),
        }
        let result = compute();
        if let Err(e) = cache.store(case, &result) {
            notes.push(format!(
                "training case '{}' not stored in the cache: {e}",
                case.label
            ));
        }
        (result, (false, notes))
    })?;
    for (from_cache, notes) in extra.into_iter().flatten() {
        training.cached += usize::from(from_cache);
        training.cache_notes.extend(notes);
    }
    Ok(training)
}

/// The training plan of the scene `full` was built from and its cases; `Err` (a message)
/// when the scene has no `[reduction.corotational]` table.
pub fn scene_cases(full: &FullOrder) -> Result<(TrainingPlan, Vec<Case>), String> {
    let plan = TrainingPlan::of_scene(full).ok_or_else(|| {
        format!(
            "{}: no training cases: the scene has no [reduction.corotational] table (the cases \
             are the co-rotational tier's training runs)",
            full.scene_path().display()
        )
    })?;
    let cases = cases(full, &plan);
    Ok((plan, cases))
}

/// Computes case `index` of `plan` into `cache` unless the cache holds it already: `Ok(true)`
/// when it ran, `Ok(false)` when its file was there and usable.
pub fn run_into(
    full: &FullOrder,
    plan: &TrainingPlan,
    cases: &[Case],
    index: usize,
    cache: &CaseCache,
) -> Result<bool, String> {
    let Some(case) = cases.get(index) else {
        return Err(format!(
            "training case {index}: the scene has {} cases (0 to {})",
            cases.len(),
            cases.len().saturating_sub(1)
        ));
    };
    let snapshots = plan.snapshot_count(full.wilson.dt);
    if let Lookup::Found(_) = cache.lookup(case, full.fem.dof_count(), snapshots) {
        return Ok(false);
    }
    let result = run_case(full, plan, index).map_err(|e| e.to_string())?;
    cache.store(case, &result)?;
    Ok(true)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The case file of `case` holding `result` (module doc).
pub fn encode(case: &Case, result: &CaseResult) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&CASE_FILE_VERSION.to_le_bytes());
    out.extend_from_slice(case.id.as_bytes());
    let u64le = |out: &mut Vec<u8>, v: usize| out.extend_from_slice(&(v as u64).to_le_bytes());
    match result {
        Ok((frames, stats)) => {
            out.push(0);
            u64le(&mut out, frames.len());
            u64le(&mut out, frames.first().map_or(0, Vec::len));
            for frame in frames {
                for v in frame {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
            for v in [
                stats.steps,
                stats.solves,
                stats.unconverged,
                stats.fallbacks,
                stats.factorisations,
            ] {
                u64le(&mut out, v);
            }
            for v in [
                stats.worst_increment,
                stats.assembly_seconds,
                stats.factor_seconds,
                stats.solve_seconds,
            ] {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        Err(why) => {
            out.push(1);
            u64le(&mut out, why.len());
            out.extend_from_slice(why.as_bytes());
        }
    }
    let sum = Sha256::digest(&out);
    out.extend_from_slice(&sum);
    out
}

/// Reads a little-endian stream, failing with what was expected where it ends.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(format!("ends inside {what} (byte {})", self.at));
        };
        let slice = &self.bytes[self.at..end];
        self.at = end;
        Ok(slice)
    }

    fn u64(&mut self, what: &str) -> Result<usize, String> {
        let b = self.take(8, what)?;
        let v = u64::from_le_bytes(b.try_into().map_err(|_| what.to_owned())?);
        usize::try_from(v).map_err(|_| format!("{what} {v} is too large"))
    }

    fn f64(&mut self, what: &str) -> Result<f64, String> {
        let b = self.take(8, what)?;
        Ok(f64::from_le_bytes(
            b.try_into().map_err(|_| what.to_owned())?,
        ))
    }
}

/// The result stored in a case file for `case`, whose snapshots must each have `dofs` entries
/// and number `snapshots`; `Err` says why the file cannot be used.
pub fn decode(
    case: &Case,
    dofs: usize,
    snapshots: usize,
    bytes: &[u8],
) -> Result<CaseResult, String> {
    if bytes.len() < MAGIC.len() + 4 + 64 + 1 + 32 {
        return Err(format!("{} bytes, too short for a case file", bytes.len()));
    }
    let (body, sum) = bytes.split_at(bytes.len() - 32);
    if !body.starts_with(MAGIC) {
        return Err("not a crokf case file".to_owned());
    }
    if Sha256::digest(body)[..] != sum[..] {
        return Err("checksum mismatch (truncated or damaged)".to_owned());
    }
    let mut r = Reader {
        bytes: body,
        at: MAGIC.len(),
    };
    let version = u32::from_le_bytes(
        r.take(4, "the version")?
            .try_into()
            .map_err(|_| "version".to_owned())?,
    );
    if version != CASE_FILE_VERSION {
        return Err(format!(
            "case file version {version}, this compiler writes {CASE_FILE_VERSION}"
        ));
    }
    if r.take(64, "the identity")? != case.id.as_bytes() {
        return Err("holds another case".to_owned());
    }
    let status = r.take(1, "the status")?[0];
    let result = match status {
        0 => {
            let count = r.u64("the snapshot count")?;
            let n = r.u64("the snapshot length")?;
            if count != snapshots || (count > 0 && n != dofs) {
                return Err(format!(
                    "{count} snapshots of {n} values, expected {snapshots} of {dofs}"
                ));
            }
            let mut frames = Vec::with_capacity(count);
            for _ in 0..count {
                let raw = r.take(8 * n, "a snapshot")?;
                frames.push(
                    raw.chunks_exact(8)
                        .map(|c| {
                            f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]])
                        })
                        .collect(),
                );
            }
            let stats = NewtonStats {
                steps: r.u64("the step count")?,
                solves: r.u64("the solve count")?,
                unconverged: r.u64("the unconverged count")?,
                fallbacks: r.u64("the fallback count")?,
                factorisations: r.u64("the factorisation count")?,
                worst_increment: r.f64("the worst increment")?,
                assembly_seconds: r.f64("the assembly time")?,
                factor_seconds: r.f64("the factorisation time")?,
                solve_seconds: r.f64("the solve time")?,
            };
            Ok((frames, stats))
        }
        1 => {
            let n = r.u64("the message length")?;
            let text = r.take(n, "the message")?;
            Err(String::from_utf8(text.to_vec()).map_err(|_| "message is not UTF-8".to_owned())?)
        }
        other => return Err(format!("unknown status {other}")),
    };
    if r.at != body.len() {
        return Err(format!("{} bytes after the result", body.len() - r.at));
    }
    Ok(result)
}

/// A folder of case files.
#[derive(Clone, Debug)]
pub struct CaseCache {
    dir: PathBuf,
}

/// What looking a case up in a cache found.
#[derive(Debug)]
pub enum Lookup {
    /// The case's stored result.
    Found(CaseResult),
    /// No file for the case.
    Missing,
    /// A file that cannot be used, and why (the case is run again).
    Unusable(String),
}

impl CaseCache {
    /// The cache in `dir`, created (with its parents) when missing; refuses a path that is a
    /// file.
    pub fn open(dir: &Path) -> Result<Self, String> {
        if dir.exists() && !dir.is_dir() {
            return Err(format!(
                "training cache {}: is a file, not a folder",
                dir.display()
            ));
        }
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("training cache {}: {e}", dir.display()))?;
        Ok(CaseCache {
            dir: dir.to_path_buf(),
        })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file of `case`.
    pub fn path(&self, case: &Case) -> PathBuf {
        self.dir.join(format!("{}.{CASE_EXTENSION}", case.id))
    }

    /// The stored result of `case` (snapshot shape as for [`decode`]).
    pub fn lookup(&self, case: &Case, dofs: usize, snapshots: usize) -> Lookup {
        let path = self.path(case);
        match std::fs::read(&path) {
            Ok(bytes) => match decode(case, dofs, snapshots, &bytes) {
                Ok(result) => Lookup::Found(result),
                Err(why) => Lookup::Unusable(format!("{}: {why}", path.display())),
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Lookup::Missing,
            Err(e) => Lookup::Unusable(format!("{}: {e}", path.display())),
        }
    }

    /// Stores `result` as the file of `case`, replacing any old one in one step (written to a
    /// temporary sibling, then renamed: a reader never sees half a file).
    pub fn store(&self, case: &Case, result: &CaseResult) -> Result<(), String> {
        crokf_formats::output::write_atomically(&self.path(case), &encode(case, result))
            .map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn case() -> Case {
        Case {
            index: 3,
            id: "ab".repeat(32),
            label: "tip (+1, +0, +0) ramp 1.25×".to_owned(),
        }
    }

    /// A case file decodes to exactly what was encoded; every truncation, a flipped byte,
    /// another identity and another shape are refused with a reason.
    #[test]
    fn case_files_round_trip_and_refuse_damage() {
        let stats = NewtonStats {
            steps: 7,
            solves: 11,
            unconverged: 1,
            fallbacks: 0,
            factorisations: 4,
            worst_increment: 3.5e-9,
            assembly_seconds: 0.25,
            factor_seconds: 0.5,
            solve_seconds: 0.125,
        };
        let frames = vec![vec![1.0, -2.5e-3, f64::MIN_POSITIVE], vec![0.0, 4.0, -0.0]];
        let ok: CaseResult = Ok((frames.clone(), stats));
        let bytes = encode(&case(), &ok);
        match decode(&case(), 3, 2, &bytes) {
            Ok(Ok((f, s))) => {
                assert_eq!(s, stats);
                for (a, b) in f.iter().flatten().zip(frames.iter().flatten()) {
                    assert_eq!(a.to_bits(), b.to_bits());
                }
            }
            other => panic!("{other:?}"),
        }
        let failed: CaseResult = Err("Newton failed at step 3".to_owned());
        let fb = encode(&case(), &failed);
        assert_eq!(decode(&case(), 3, 2, &fb), Ok(failed));

        for cut in 0..bytes.len() {
            assert!(
                decode(&case(), 3, 2, &bytes[..cut]).is_err(),
                "cut at {cut}"
            );
        }
        let mut flipped = bytes.clone();
        flipped[40] ^= 1;
        assert!(decode(&case(), 3, 2, &flipped)
            .unwrap_err()
            .contains("checksum"));
        let other = Case {
            id: "cd".repeat(32),
            ..case()
        };
        assert!(decode(&other, 3, 2, &bytes)
            .unwrap_err()
            .contains("another case"));
        assert!(decode(&case(), 4, 2, &bytes)
            .unwrap_err()
            .contains("expected 2 of 4"));
        assert!(decode(&case(), 3, 5, &bytes).is_err());
    }
}
