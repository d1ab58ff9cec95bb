//! Writing output files without losing or half-writing anything (issue 14 item 1), shared by
//! the command-line tools (`crokf-run` now; `crokf-compile` and `crokf-verify` can use the
//! same calls).
//!
//! - [`check_paths`]: before any work, refuse an output that is one of the inputs, and two
//!   outputs on one path. Paths are compared canonicalised (symbolic links, `..`, relative
//!   paths resolved); an output that does not exist yet is its parent's canonical path joined
//!   with its file name, and that parent must exist and be a folder.
//! - [`AtomicFile`] / [`write_atomically`]: the bytes go to a temporary file in the target's
//!   own folder (same file system), are flushed and synced, and are renamed over the target
//!   only on [`AtomicFile::commit`]. Dropped without a commit (an error, a panic), the
//!   temporary file is removed and the old target is untouched.
//! - [`StagedDir`]: the same for a set of files going into one folder (VTU series): written to
//!   a hidden sibling folder, moved into the target folder one rename at a time on commit.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

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
            (OutputKind::Folder, Ok(m)) if !m.is_dir() => {
                return Err(OutputError::WrongKind {
                    role,
                    path: out.path.to_path_buf(),
                    message: "exists and is not a folder",
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

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// A hidden sibling name: `.NAME.tmp-PID-N` in the same folder as `path`.
fn temporary_sibling(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "output".into(), |n| n.to_string_lossy().into_owned());
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    parent_of(path).join(format!(".{name}.tmp-{}-{n}", std::process::id()))
}

/// A file written through a temporary sibling and renamed over the target on
/// [`AtomicFile::commit`]; dropped uncommitted, the temporary is removed.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temporary: PathBuf,
    file: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates the temporary file next to `target` (nothing happens to `target` yet).
    pub fn create(target: &Path) -> Result<AtomicFile, OutputError> {
        let temporary = temporary_sibling(target);
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&temporary)
            .map_err(io_err(target))?;
        Ok(AtomicFile {
            target: target.to_path_buf(),
            temporary,
            file: Some(BufWriter::new(file)),
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
        let file = writer
            .into_inner()
            .map_err(|e| io_err(&target)(e.into_error()))?;
        file.sync_all().map_err(io_err(&target))?;
        drop(file);
        fs::rename(&self.temporary, &target).map_err(io_err(&target))
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
            let _ = fs::remove_file(&self.temporary);
        }
    }
}

/// Writes `bytes` to `path` through a temporary sibling and a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes).map_err(io_err(path))?;
    f.commit()
}

/// Files bound for one folder, written into a hidden sibling folder first; on
/// [`StagedDir::commit`] the target folder is created if needed and the files are renamed into
/// it in the order they were added. Dropped uncommitted, the staging folder is removed and the
/// target folder is untouched.
#[derive(Debug)]
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    files: Vec<String>,
    committed: bool,
}

impl StagedDir {
    /// Creates the staging folder next to `target`.
    pub fn create(target: &Path) -> Result<StagedDir, OutputError> {
        let staging = temporary_sibling(target);
        fs::create_dir(&staging).map_err(io_err(target))?;
        Ok(StagedDir {
            target: target.to_path_buf(),
            staging,
            files: Vec::new(),
            committed: false,
        })
    }

    /// The final folder.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Writes file `name` (a plain file name) into the staging folder.
    pub fn write(&mut self, name: &str, bytes: &[u8]) -> Result<(), OutputError> {
        let path = self.staging.join(name);
        fs::write(&path, bytes).map_err(io_err(&self.target.join(name)))?;
        self.files.push(name.to_owned());
        Ok(())
    }

    /// Moves every staged file into the target folder (created if missing), in order.
    pub fn commit(mut self) -> Result<(), OutputError> {
        fs::create_dir_all(&self.target).map_err(io_err(&self.target))?;
        for name in &self.files {
            let to = self.target.join(name);
            fs::rename(self.staging.join(name), &to).map_err(io_err(&to))?;
        }
        self.committed = true;
        fs::remove_dir_all(&self.staging).map_err(io_err(&self.staging))
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}
