//! The files of one identification: reading the scene, the model and the recording, checking
//! the output path before any work, and writing the identified scene atomically.

use std::path::{Path, PathBuf};

use crokf_formats::output::{check_paths, write_atomically, Output, OutputKind};

use crate::full_order::FullOrder;
use crate::scene::SceneFile;

use super::identification::{identify, Identification, IdentifyError, IdentifyOptions, Recording};
use super::scene_edit::identified_scene;

/// Writes `text` (from [`identified_scene`]) to `out`, atomically. Refused: `out` equal to
/// one of `inputs`, or in another folder than the scene's (its relative paths, the mesh and
/// node lists, resolve from the scene's folder).
pub fn write_scene(
    scene: &Path,
    out: &Path,
    inputs: &[(&str, &Path)],
    text: &str,
) -> Result<(), IdentifyError> {
    check_output(scene, out, inputs)?;
    write_atomically(out, text.as_bytes()).map_err(|e| IdentifyError::Failed(e.to_string()))
}

/// The checks of [`write_scene`], before any work.
pub fn check_output(
    scene: &Path,
    out: &Path,
    inputs: &[(&str, &Path)],
) -> Result<(), IdentifyError> {
    let outputs = [Output {
        role: "-o",
        path: out,
        kind: OutputKind::File,
    }];
    check_paths(inputs, &outputs).map_err(|e| IdentifyError::Usage(e.to_string()))?;
    let folder = |p: &Path| {
        crokf_formats::output::canonical(p).and_then(|c| c.parent().map(Path::to_path_buf))
    };
    let (a, b): (Option<PathBuf>, Option<PathBuf>) = (folder(scene), folder(out));
    if a.is_none() || a != b {
        return Err(IdentifyError::Usage(format!(
            "-o {}: write the identified scene into the scene's folder ({}): its relative \
             paths (mesh file, node lists) resolve from there",
            out.display(),
            scene
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .display()
        )));
    }
    Ok(())
}

/// The files of one identification (the command's arguments).
#[derive(Clone, Debug)]
pub struct Files<'a> {
    /// The scene the model was compiled from.
    pub scene: &'a Path,
    /// The model file, with a co-rotational tier.
    pub model: &'a Path,
    /// The recorded markers (`crokf-run`'s measurements CSV).
    pub measurements: &'a Path,
    /// The recorded inputs (`crokf-run`'s inputs CSV); `None`: every input 0.
    pub inputs: Option<&'a Path>,
    /// Where the scene with the identified σ goes (the scene's folder).
    pub out: Option<&'a Path>,
}

/// A refusal, with the identification when there was one (its report says why).
#[derive(Debug)]
pub struct Refusal {
    /// Why.
    pub error: IdentifyError,
    /// The identification refused by its verdict (not excited, markers unexplained).
    pub found: Option<Box<Identification>>,
}

impl From<IdentifyError> for Refusal {
    fn from(error: IdentifyError) -> Refusal {
        Refusal { error, found: None }
    }
}

/// `crokf-compile identify` (and `crokf.identify`): reads the files, refuses an output over an
/// input or outside the scene's folder before any work, identifies, checks the verdict and
/// writes the scene with the identified σ to `files.out` (nothing written on a refusal).
pub fn identify_files(
    files: &Files<'_>,
    options: &IdentifyOptions,
) -> Result<Identification, Refusal> {
    let failed = |e: &dyn std::fmt::Display| IdentifyError::Failed(e.to_string());
    let scene = SceneFile::read(files.scene).map_err(|e| failed(&e))?;
    let read = scene.input_files();
    let mut inputs: Vec<(&str, &Path)> = vec![
        ("scene", files.scene),
        ("model", files.model),
        ("--measurements", files.measurements),
    ];
    if let Some(i) = files.inputs {
        inputs.push(("--inputs", i));
    }
    inputs.extend(read.iter().map(|(role, p)| (*role, p.as_path())));
    if let Some(out) = files.out {
        check_output(files.scene, out, &inputs)?;
    }
    let model = crokf_runtime::load_model(files.model).map_err(|e| failed(&e))?;
    let recording = Recording::read(&model, files.measurements, files.inputs)?;
    let full = FullOrder::build(files.scene, &mut crate::report::StageTimer::default())
        .map_err(|e| failed(&e))?;
    let found = identify(&full, &model, &recording, options)?;
    if let Err(error) = found.check() {
        return Err(Refusal {
            error,
            found: Some(Box::new(found)),
        });
    }
    if let Some(out) = files.out {
        let text = identified_scene(&full.scene, &found)?;
        write_scene(files.scene, out, &inputs, &text)?;
    }
    Ok(found)
}
