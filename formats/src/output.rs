//! Writing output files without losing or half-writing anything, shared by the command-line
//! tools (`crokf-compile`, `crokf-run`, `crokf-verify`).
//!
//! - [`check_paths`]: before any work, refuse an output that is one of the inputs, and two
//!   outputs on one path. Paths are compared canonicalised (symbolic links, `..`, relative
//!   paths resolved); an output that does not exist yet is its parent's canonical path joined
//!   with its file name, and that parent must exist and be a folder. An
//!   [`OutputKind::ExistingFolder`] must exist itself. [`check_folder_inputs`] refuses a folder
//!   output whose files would replace an input.
//! - [`AtomicFile`] / [`write_atomically`]: the bytes go to a temporary file in the target's
//!   own folder (same file system), are flushed and synced, and are renamed over the target
//!   only on [`AtomicFile::commit`]. Dropped without a commit (an error, a panic), the
//!   temporary file is removed and the old target is untouched.
//! - [`StagedDir`]: the same for a set of files going into one folder (a VTU series, the
//!   exported matrices): written into a hidden staging folder, then moved in by
//!   [`StagedDir::commit`] as one transaction: a folder that does not exist yet appears by one
//!   rename, whole; in an existing folder, each file the set replaces (and, for
//!   [`StagedDir::create_owning`], each old file of the set that the new set does not rewrite)
//!   is first moved aside, and a failure at any file moves everything back, so the folder holds
//!   either the whole new set or exactly what it held before. Other files in the folder are
//!   never touched.
//! - Interrupts: every temporary file and staging folder is registered while it lives;
//!   [`remove_temporaries`] removes them all (commits hold the same lock, so it never runs
//!   in the middle of one), and with the `signals` feature `install_interrupt_cleanup` makes
//!   SIGINT and SIGTERM do that and exit (status 128 + signal). [`sweep_stale_temporaries`]
//!   removes, before a command writes, the temporaries that a process no longer running (one
//!   killed by SIGKILL, say) left next to its outputs, and names each one it removes.
//!
//! Temporaries are named `.NAME.tmp-PID-N` (NAME the target's file name, PID the writing
//! process): next to a file output, inside an existing folder output (the same file system as
//! its files), or next to a folder output that does not exist yet.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// Why an output cannot be (or was not) written. Messages name the paths and their roles.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// An output path resolves to one of the inputs.
    #[error(
        "{output_role} {output} is the {input_role} ({input}): refusing to overwrite an input"
    )]
    OutputIsInput {
        /// The output's role, e.g. `--out`.
        output_role: String,
        /// The output path as given.
        output: PathBuf,
        /// The input's role, e.g. `model`.
        input_role: String,
        /// The input path as given.
        input: PathBuf,
    },
    /// Two outputs resolve to one path.
    #[error(
        "{first_role} and {second_role} are the same file ({path}): give them different paths"
    )]
    SameOutput {
        /// Role of the first.
        first_role: String,
        /// Role of the second.
        second_role: String,
        /// The path as given for the second.
        path: PathBuf,
    },
    /// The folder an output goes into does not exist (or is not a folder).
    #[error("{role} {path}: the folder {folder} does not exist or is not a folder")]
    NoFolder {
        /// The output's role.
        role: String,
        /// The output path.
        path: PathBuf,
        /// Its parent folder.
        folder: PathBuf,
    },
    /// A folder output that must exist does not.
    #[error("{role} {path}: the folder does not exist; create it first")]
    MissingFolder {
        /// The output's role.
        role: String,
        /// The folder.
        path: PathBuf,
    },
    /// An output that must be a file is a folder, or one that must be a folder is a file.
    #[error("{role} {path}: {message}")]
    WrongKind {
        /// The output's role.
        role: String,
        /// The output path.
        path: PathBuf,
        /// What is wrong.
        message: &'static str,
    },
    /// A commit into an existing folder failed and could not be rolled back completely.
    #[error(
        "cannot write {path}: {source}; moving the old files back failed as well \
        ({rollback}): the previous files are kept in {kept}"
    )]
    RolledBackPartly {
        /// The folder.
        path: PathBuf,
        /// The first failure.
        source: io::Error,
        /// What failed while rolling back.
        rollback: String,
        /// The staging folder holding the files that could not be moved back.
        kept: PathBuf,
    },
    /// Resolving, writing, syncing or renaming failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
}

fn io_err(path: &Path) -> impl FnOnce(io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The folder a path lives in (`.` for a bare file name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The canonical form of `path`: `fs::canonicalize` if it exists, else the canonical parent
/// joined with the file name (the parent must exist). `None` if neither resolves.
pub fn canonical(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = fs::canonicalize(path) {
        return Some(p);
    }
    let name = path.file_name()?;
    fs::canonicalize(parent_of(path))
        .ok()
        .map(|dir| dir.join(name))
}

/// Whether an output is one file or a folder of files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A single file: must not be a folder; its parent folder must exist.
    File,
    /// A folder (created if missing): must not be a file; its parent folder must exist.
    Folder,
    /// A folder that must exist already (refused otherwise, naming it).
    ExistingFolder,
}

/// One output of a command: its role in messages (`--out`), its path and kind.
#[derive(Clone, Copy, Debug)]
pub struct Output<'a> {
    /// How the user named it, e.g. `--out`.
    pub role: &'a str,
    /// The path as given.
    pub path: &'a Path,
    /// File or folder.
    pub kind: OutputKind,
}

/// Refuses, before any work: an output whose canonical path is an input's; two outputs with
/// one canonical path; a file output that is a folder or a folder output that is a file; an
/// output whose parent folder does not exist. `inputs` are `(role, path)`; inputs that do not
/// resolve are skipped here (reading them reports the error).
pub fn check_paths(inputs: &[(&str, &Path)], outputs: &[Output<'_>]) -> Result<(), OutputError> {
    let inputs: Vec<(&str, &Path, PathBuf)> = inputs
        .iter()
        .filter_map(|&(role, path)| canonical(path).map(|c| (role, path, c)))
        .collect();
    let mut seen: Vec<(&str, PathBuf)> = Vec::new();
    for out in outputs {
        let role = out.role.to_owned();
        match (out.kind, fs::metadata(out.path)) {
            (OutputKind::File, Ok(m)) if m.is_dir() => {
                return Err(OutputError::WrongKind {
                    role,
                    path: out.path.to_path_buf(),
                    message: "is a folder, expected a file path",
                })
            }
            (OutputKind::Folder | OutputKind::ExistingFolder, Ok(m)) if !m.is_dir() => {
                return Err(OutputError::WrongKind {
                    role,
                    path: out.path.to_path_buf(),
                    message: "exists and is not a folder",
                })
            }
            (OutputKind::ExistingFolder, Err(_)) => {
                return Err(OutputError::MissingFolder {
                    role,
                    path: out.path.to_path_buf(),
                })
            }
            _ => {}
        }
        let folder = parent_of(out.path);
        let Some(canon) = canonical(out.path).filter(|_| folder.is_dir()) else {
            return Err(OutputError::NoFolder {
                role,
                path: out.path.to_path_buf(),
                folder: folder.to_path_buf(),
            });
        };
        if let Some((input_role, input, _)) = inputs.iter().find(|(_, _, c)| *c == canon) {
            return Err(OutputError::OutputIsInput {
                output_role: role,
                output: out.path.to_path_buf(),
                input_role: (*input_role).to_owned(),
                input: input.to_path_buf(),
            });
        }
        if let Some((first, _)) = seen.iter().find(|(_, c)| *c == canon) {
            return Err(OutputError::SameOutput {
                first_role: (*first).to_owned(),
                second_role: role,
                path: out.path.to_path_buf(),
            });
        }
        seen.push((out.role, canon));
    }
    Ok(())
}

/// Refuses a folder output `dir` whose files named by `owns` would replace one of `inputs`
/// (compared canonicalised, as in [`check_paths`]); the error names the input and the file.
pub fn check_folder_inputs(
    inputs: &[(&str, &Path)],
    role: &str,
    dir: &Path,
    owns: impl Fn(&str) -> bool,
) -> Result<(), OutputError> {
    let Some(dir_canon) = canonical(dir) else {
        return Ok(());
    };
    for &(input_role, input) in inputs {
        let Some(c) = canonical(input) else {
            continue;
        };
        let Some(name) = c.file_name().map(|n| n.to_string_lossy().into_owned()) else {
            continue;
        };
        if c.parent() == Some(dir_canon.as_path()) && owns(&name) {
            return Err(OutputError::OutputIsInput {
                output_role: role.to_owned(),
                output: dir.join(&name),
                input_role: input_role.to_owned(),
                input: input.to_path_buf(),
            });
        }
    }
    Ok(())
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// `.NAME.tmp-` for a target's file name.
fn temporary_prefix(path: &Path) -> String {
    let name = path
        .file_name()
        .map_or_else(|| "output".into(), |n| n.to_string_lossy().into_owned());
    format!(".{name}.tmp-")
}

/// A hidden temporary `.NAME.tmp-PID-N` for `target`, in `folder`.
fn temporary_in(folder: &Path, target: &Path) -> PathBuf {
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    folder.join(format!(
        "{}{}-{n}",
        temporary_prefix(target),
        std::process::id()
    ))
}

/// A hidden sibling name: `.NAME.tmp-PID-N` in the same folder as `path`.
fn temporary_sibling(path: &Path) -> PathBuf {
    temporary_in(parent_of(path), path)
}

/// The temporaries of this process that exist right now (path, is a folder), by id.
static LIVE: Mutex<Vec<(u64, PathBuf, bool)>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

fn live() -> MutexGuard<'static, Vec<(u64, PathBuf, bool)>> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

fn register(list: &mut Vec<(u64, PathBuf, bool)>, path: &Path, folder: bool) -> u64 {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    list.push((id, path.to_path_buf(), folder));
    id
}

fn unregister(list: &mut Vec<(u64, PathBuf, bool)>, id: u64) {
    list.retain(|(i, _, _)| *i != id);
}

fn remove_all(list: &mut Vec<(u64, PathBuf, bool)>) -> usize {
    let mut removed = 0;
    for (_, path, folder) in list.drain(..) {
        let done = if folder {
            fs::remove_dir_all(&path)
        } else {
            fs::remove_file(&path)
        };
        if done.is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Holds the registry of temporaries: while it lives, no writer of this process can create,
/// commit or remove a temporary.
pub struct TemporariesHeld {
    _list: MutexGuard<'static, Vec<(u64, PathBuf, bool)>>,
}

/// Removes every temporary file and staging folder this process has open (an interrupted
/// command's unfinished outputs) and returns how many it removed. Waits for a commit in
/// progress to finish first; afterwards no writer of this process can register a new one
/// until the returned guard is dropped (the interrupt handler exits while holding it).
pub fn remove_temporaries() -> (usize, TemporariesHeld) {
    let mut list = live();
    let n = remove_all(&mut list);
    (n, TemporariesHeld { _list: list })
}

/// A file written through a temporary sibling and renamed over the target on
/// [`AtomicFile::commit`]; dropped uncommitted, the temporary is removed.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temporary: PathBuf,
    file: Option<BufWriter<File>>,
    id: u64,
}

impl AtomicFile {
    /// Creates the temporary file next to `target` (nothing happens to `target` yet).
    pub fn create(target: &Path) -> Result<AtomicFile, OutputError> {
        let temporary = temporary_sibling(target);
        let mut list = live();
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&temporary)
            .map_err(io_err(target))?;
        let id = register(&mut list, &temporary, false);
        Ok(AtomicFile {
            target: target.to_path_buf(),
            temporary,
            file: Some(BufWriter::new(file)),
            id,
        })
    }

    /// The final path.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Flushes, syncs and renames the temporary over the target.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let target = self.target.clone();
        let Some(writer) = self.file.take() else {
            return Ok(());
        };
        let result = writer
            .into_inner()
            .map_err(|e| io_err(&target)(e.into_error()))
            .and_then(|file| file.sync_all().map_err(io_err(&target)));
        let mut list = live();
        let result =
            result.and_then(|()| fs::rename(&self.temporary, &target).map_err(io_err(&target)));
        if result.is_err() {
            let _ = fs::remove_file(&self.temporary);
        }
        unregister(&mut list, self.id);
        result
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match &mut self.file {
            Some(f) => f.write(buf),
            None => Err(io::Error::other("file already committed")),
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        match &mut self.file {
            Some(f) => f.flush(),
            None => Ok(()),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let mut list = live();
            let _ = fs::remove_file(&self.temporary);
            unregister(&mut list, self.id);
        }
    }
}

/// Writes `bytes` to `path` through a temporary sibling and a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes).map_err(io_err(path))?;
    f.commit()
}

/// Files bound for one folder, written into a hidden staging folder first and moved in by
/// [`StagedDir::commit`] as one transaction (module documentation). Dropped uncommitted, the
/// staging folder is removed and the target folder is untouched.
#[derive(Debug)]
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    /// The target existed at creation: the staging folder is inside it.
    existing: bool,
    files: Vec<String>,
    owns: Option<fn(&str) -> bool>,
    /// Removed on drop (false once committed, or kept after a failed rollback).
    remove: bool,
    id: u64,
}

impl StagedDir {
    /// Creates the staging folder: inside `target` when it is an existing folder, next to it
    /// otherwise. On commit, the files written replace those of the same names.
    pub fn create(target: &Path) -> Result<StagedDir, OutputError> {
        Self::create_with(target, None)
    }

    /// As [`StagedDir::create`]; on commit, also every old file of the target for which
    /// `owns(name)` holds and that the new set does not rewrite is removed (the target then
    /// holds exactly the new set among the files `owns` names: no step of an older, longer
    /// series stays behind).
    pub fn create_owning(target: &Path, owns: fn(&str) -> bool) -> Result<StagedDir, OutputError> {
        Self::create_with(target, Some(owns))
    }

    fn create_with(
        target: &Path,
        owns: Option<fn(&str) -> bool>,
    ) -> Result<StagedDir, OutputError> {
        let existing = target.is_dir();
        let staging = if existing {
            temporary_in(target, target)
        } else {
            temporary_sibling(target)
        };
        let mut list = live();
        fs::create_dir(&staging).map_err(io_err(target))?;
        let id = register(&mut list, &staging, true);
        Ok(StagedDir {
            target: target.to_path_buf(),
            staging,
            existing,
            files: Vec::new(),
            owns,
            remove: true,
            id,
        })
    }

    /// The final folder.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Writes file `name` (a plain file name, not hidden) into the staging folder.
    pub fn write(&mut self, name: &str, bytes: &[u8]) -> Result<(), OutputError> {
        let plain = !name.is_empty()
            && !name.starts_with('.')
            && Path::new(name).file_name() == Some(name.as_ref());
        if !plain {
            return Err(OutputError::Io {
                path: self.target.join(name),
                source: io::Error::new(
                    io::ErrorKind::InvalidInput,
                    "not a plain, visible file name",
                ),
            });
        }
        let path = self.staging.join(name);
        // Under the registry lock: an interrupt never removes the folder mid-write.
        let _list = live();
        fs::write(&path, bytes).map_err(io_err(&self.target.join(name)))?;
        if !self.files.iter().any(|f| f == name) {
            self.files.push(name.to_owned());
        }
        Ok(())
    }

    /// Moves the staged files into the target folder as one transaction (module
    /// documentation): a new folder appears by one rename; in an existing one, every file is
    /// in place or, on a failure, everything is as it was.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let mut list = live();
        let result = if self.existing {
            self.commit_into_existing()
        } else {
            fs::rename(&self.staging, &self.target).map_err(io_err(&self.target))
        };
        match &result {
            Ok(()) if !self.existing => self.remove = false,
            Err(OutputError::RolledBackPartly { .. }) => self.remove = false,
            _ => {}
        }
        if self.remove {
            let _ = fs::remove_dir_all(&self.staging);
            self.remove = false;
        }
        unregister(&mut list, self.id);
        result
    }

    fn commit_into_existing(&self) -> Result<(), OutputError> {
        let backup = self.staging.join(".old");
        fs::create_dir(&backup).map_err(io_err(&self.target))?;
        let mut stale: Vec<String> = Vec::new();
        if let Some(owns) = self.owns {
            let entries = fs::read_dir(&self.target).map_err(io_err(&self.target))?;
            for entry in entries {
                let entry = entry.map_err(io_err(&self.target))?;
                let name = entry.file_name().to_string_lossy().into_owned();
                if owns(&name) && !self.files.contains(&name) && entry.path().is_file() {
                    stale.push(name);
                }
            }
            stale.sort();
        }
        let mut backed_up: Vec<&str> = Vec::new();
        let mut moved_in: Vec<&str> = Vec::new();
        let mut step = || -> Result<(), (PathBuf, io::Error)> {
            for name in &stale {
                let from = self.target.join(name);
                fs::rename(&from, backup.join(name)).map_err(|e| (from, e))?;
                backed_up.push(name);
            }
            for name in &self.files {
                let to = self.target.join(name);
                match fs::symlink_metadata(&to) {
                    Ok(m) if m.is_dir() => {
                        return Err((to, io::Error::other("a folder of that name is in the way")))
                    }
                    Ok(_) => {
                        fs::rename(&to, backup.join(name)).map_err(|e| (to.clone(), e))?;
                        backed_up.push(name);
                    }
                    Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                    Err(e) => return Err((to, e)),
                }
                fs::rename(self.staging.join(name), &to).map_err(|e| (to.clone(), e))?;
                moved_in.push(name);
            }
            Ok(())
        };
        let Err((path, source)) = step() else {
            return Ok(());
        };
        // Roll back: the new files out, the old ones in, last first.
        let mut failed = Vec::new();
        for name in moved_in.iter().rev() {
            if let Err(e) = fs::rename(self.target.join(name), self.staging.join(name)) {
                failed.push(format!("{name}: {e}"));
            }
        }
        for name in backed_up.iter().rev() {
            if let Err(e) = fs::rename(backup.join(name), self.target.join(name)) {
                failed.push(format!("{name}: {e}"));
            }
        }
        if failed.is_empty() {
            Err(OutputError::Io { path, source })
        } else {
            Err(OutputError::RolledBackPartly {
                path,
                source,
                rollback: failed.join("; "),
                kept: self.staging.clone(),
            })
        }
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if self.remove {
            let mut list = live();
            let _ = fs::remove_dir_all(&self.staging);
            unregister(&mut list, self.id);
        }
    }
}

/// Whether process `pid` is running (`None`: cannot tell on this platform).
fn process_alive(pid: u32) -> Option<bool> {
    #[cfg(all(unix, feature = "signals"))]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else {
            return Some(false);
        };
        // SAFETY: kill with signal 0 only checks that the process exists.
        let r = unsafe { libc::kill(pid, 0) };
        let eperm = io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
        Some(r == 0 || eperm)
    }
    #[cfg(not(all(unix, feature = "signals")))]
    {
        let proc = Path::new("/proc");
        proc.is_dir().then(|| proc.join(pid.to_string()).exists())
    }
}

/// Before a command writes: removes the temporaries (`.NAME.tmp-PID-N`, see the module
/// documentation) of its outputs that a process no longer running left behind, and returns
/// one line per temporary it removed or kept (an interrupted folder commit's staging folder,
/// which holds the previous files in `.old`, is kept and named; so is one whose process cannot
/// be checked). Temporaries of running processes (another command writing the same output)
/// are left alone.
pub fn sweep_stale_temporaries(outputs: &[Output<'_>]) -> Vec<String> {
    let own = std::process::id();
    let mut notes = Vec::new();
    let mut seen: Vec<PathBuf> = Vec::new();
    for out in outputs {
        let prefix = temporary_prefix(out.path);
        let mut folders = vec![parent_of(out.path).to_path_buf()];
        if out.kind != OutputKind::File && out.path.is_dir() {
            folders.push(out.path.to_path_buf());
        }
        for folder in folders {
            let Ok(entries) = fs::read_dir(&folder) else {
                continue;
            };
            for entry in entries.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                let Some(rest) = name.strip_prefix(&prefix) else {
                    continue;
                };
                let mut parts = rest.splitn(2, '-');
                let pid = parts.next().and_then(|p| p.parse::<u32>().ok());
                let counter = parts.next().and_then(|n| n.parse::<u64>().ok());
                let (Some(pid), Some(_)) = (pid, counter) else {
                    continue;
                };
                let path = entry.path();
                if pid == own || seen.contains(&path) {
                    continue;
                }
                seen.push(path.clone());
                match process_alive(pid) {
                    Some(true) => continue,
                    None => {
                        notes.push(format!(
                            "found {} left by process {pid}: remove it if no crokf command is \
                             running",
                            path.display()
                        ));
                        continue;
                    }
                    Some(false) => {}
                }
                let is_dir = path.is_dir();
                if is_dir && path.join(".old").is_dir() {
                    notes.push(format!(
                        "kept {}: process {pid} was stopped while moving files into {}; the \
                         files it had replaced are in {}",
                        path.display(),
                        folder.display(),
                        path.join(".old").display()
                    ));
                    continue;
                }
                let removed = if is_dir {
                    fs::remove_dir_all(&path)
                } else {
                    fs::remove_file(&path)
                };
                notes.push(match removed {
                    Ok(()) => format!(
                        "removed {}, an unfinished output of process {pid} (no longer running)",
                        path.display()
                    ),
                    Err(e) => format!(
                        "cannot remove {}, an unfinished output of process {pid}: {e}",
                        path.display()
                    ),
                });
            }
        }
    }
    notes
}

/// SIGINT and SIGTERM: remove this process's temporaries ([`remove_temporaries`]), say so on
/// stderr as `PROGRAM: interrupted …` and exit with status 128 + signal. The signal handler
/// only writes the signal number to a pipe; a thread does the rest, so the removal never
/// interrupts a commit (it waits for it). Call once, early in `main`.
#[cfg(all(unix, feature = "signals"))]
pub fn install_interrupt_cleanup(program: &'static str) -> Result<(), io::Error> {
    use std::sync::atomic::AtomicI32;
    static WRITE_END: AtomicI32 = AtomicI32::new(-1);

    extern "C" fn on_signal(signal: libc::c_int) {
        let fd = WRITE_END.load(Ordering::Relaxed);
        let byte = signal as u8;
        // SAFETY: write(2) is async-signal-safe; the pipe is non-blocking.
        unsafe {
            libc::write(fd, (&byte as *const u8).cast(), 1);
        }
    }

    if WRITE_END.load(Ordering::Relaxed) >= 0 {
        return Ok(());
    }
    let mut fds = [0 as libc::c_int; 2];
    // SAFETY: pipe(2) fills the two descriptors.
    if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
        return Err(io::Error::last_os_error());
    }
    let [read_end, write_end] = fds;
    // SAFETY: fcntl on descriptors just created.
    unsafe {
        libc::fcntl(write_end, libc::F_SETFL, libc::O_NONBLOCK);
        libc::fcntl(read_end, libc::F_SETFD, libc::FD_CLOEXEC);
        libc::fcntl(write_end, libc::F_SETFD, libc::FD_CLOEXEC);
    }
    WRITE_END.store(write_end, Ordering::Relaxed);
    std::thread::Builder::new()
        .name("crokf-interrupt".into())
        .spawn(move || loop {
            let mut byte = 0u8;
            // SAFETY: reads one byte into a local.
            let n = unsafe { libc::read(read_end, (&mut byte as *mut u8).cast(), 1) };
            if n == 1 {
                let (removed, _hold) = remove_temporaries();
                let name = if i32::from(byte) == libc::SIGTERM {
                    "SIGTERM"
                } else {
                    "SIGINT"
                };
                eprintln!(
                    "{program}: interrupted ({name}): removed {removed} unfinished temporary \
                     file(s) or folder(s); outputs not yet written are left as they were"
                );
                std::process::exit(128 + i32::from(byte));
            }
            if n < 0 && io::Error::last_os_error().kind() != io::ErrorKind::Interrupted {
                return;
            }
        })?;
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: installs a handler that only calls write(2).
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            action.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            if libc::sigaction(signal, &action, std::ptr::null_mut()) != 0 {
                return Err(io::Error::last_os_error());
            }
        }
    }
    Ok(())
}
