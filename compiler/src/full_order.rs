//! The full-order model: the front end of the pipeline (scene → mesh → FEM → operators), built
//! once and shared by `compile`, `check`, the reduction at several orders and `crokf-verify`.

use std::path::Path;

use crokf_formats as fmt;

use crate::dynamics::WilsonTheta;
use crate::error::CompileError;
use crate::fem::operators::Operators;
use crate::fem::FemModel;
use crate::mesh::{read_mesh_bytes, Mesh};
use crate::noise::{ForceSigma, ForceStatement, NoiseError, NoiseModel, NoiseSpec};
use crate::scene::{Scene, SceneFile, DEFAULT_MODEL_ERROR_SCALE};
use crate::timer::StageTimer;

/// The compiler's version string, part of every model's input digest.
pub const COMPILER_VERSION: &str = concat!("crokf-compile ", env!("CARGO_PKG_VERSION"));

/// Everything the front end produces: the scene, its mesh, the assembled FEM model with its
/// operators, and the Wilson-θ scheme of the scene's `[time]` table.
pub struct FullOrder {
    /// The scene.
    pub scene: SceneFile,
    /// The mesh.
    pub mesh: Mesh,
    /// Raw mesh bytes (for the digest).
    pub mesh_bytes: Vec<u8>,
    /// The scene's `node_list` files and their bytes, in scene order (for the digest).
    pub node_lists: Vec<(std::path::PathBuf, Vec<u8>)>,
    /// Assembled K, M, DOF map.
    pub fem: FemModel,
    /// Loads, sensors, node sets.
    pub operators: Operators,
    /// Δt and θ (docs/design.md §2), from the scene's time spec.
    pub wilson: WilsonTheta,
    /// What the scene states of its filters' noise ([`noise_spec`]), built once with the rest.
    pub noise: NoiseSpec,
}

/// What `scene` states of its filters' noise (docs/design.md §11.4, §11.8–11.9): per estimated
/// load group in scene order (each load with `force_model = "random_walk"`, the default), its
/// force σ stated by `force_noise_std` > 0 or derived from its range (`range`, else the tier's
/// `ranges` entry) and `rise_time`, with its rate σ (`force_rate_noise_std`, 0: no rate
/// states); and the factor on the tier's model error (`[reduction.corotational]
/// model_error_scale`, [`crate::scene::DEFAULT_MODEL_ERROR_SCALE`] when not stated or without
/// a tier section). One value for the warped tier's force states and the co-rotational tier's
/// filter. The scene's checks guarantee a range where σ is derived.
pub fn noise_spec(scene: &Scene) -> NoiseSpec {
    let forces = scene
        .loads
        .iter()
        .enumerate()
        .filter(|(_, l)| l.is_estimated())
        .filter_map(|(i, l)| {
            let sigma = if l.force_noise_std > 0.0 {
                ForceSigma::Stated(l.force_noise_std)
            } else {
                ForceSigma::Derived {
                    range: scene.load_range(l)?,
                    rise_time: l.rise_time(),
                }
            };
            Some(ForceStatement {
                load: i,
                sigma,
                rate_sigma: l.force_rate_noise_std,
                rise_time: l.rise_time(),
            })
        })
        .collect();
    let model_error_scale = scene
        .reduction
        .corotational
        .as_ref()
        .map_or(DEFAULT_MODEL_ERROR_SCALE, |c| c.model_error_scale());
    NoiseSpec {
        forces,
        model_error_scale,
    }
}

impl FullOrder {
    /// The scene's noise model ([`FullOrder::noise`] on its operators), derived σ not yet
    /// fixed ([`NoiseModel::derive`]).
    pub fn noise_model(&self) -> Result<NoiseModel, NoiseError> {
        NoiseModel::new(&self.noise, &self.operators, self.wilson.dt)
    }

    /// Reads the scene and mesh, assembles K and M and builds the operators; stage costs go to
    /// `timer` ("mesh", "assembly", "operators").
    pub fn build(scene_path: &Path, timer: &mut StageTimer) -> Result<Self, CompileError> {
        let scene = SceneFile::read(scene_path)?;
        let mesh_path = scene.mesh_path();
        let (mesh, mesh_bytes) = timer.stage("mesh", || -> Result<_, CompileError> {
            let bytes = std::fs::read(&mesh_path).map_err(|source| CompileError::Io {
                path: mesh_path.clone(),
                source,
            })?;
            Ok((read_mesh_bytes(&bytes, &mesh_path)?, bytes))
        })?;
        let unit = scene.scene.mesh.units.to_metres();
        let fem_err = |source| CompileError::Fem {
            path: scene_path.to_owned(),
            source,
        };
        let fem = timer
            .stage("assembly", || FemModel::assemble(&mesh, &scene.scene, unit))
            .map_err(fem_err)?;
        let operators = timer
            .stage("operators", || {
                Operators::build(&mesh, &scene.scene, &fem, unit)
            })
            .map_err(fem_err)?;
        let wilson = WilsonTheta::from(&scene.scene.time);
        let node_lists = scene
            .scene
            .node_list_files()
            .into_iter()
            .map(|path| {
                std::fs::read(path)
                    .map(|bytes| (path.to_owned(), bytes))
                    .map_err(|source| CompileError::Io {
                        path: path.to_owned(),
                        source,
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let noise = noise_spec(&scene.scene);
        Ok(FullOrder {
            noise,
            scene,
            mesh,
            mesh_bytes,
            node_lists,
            fem,
            operators,
            wilson,
        })
    }

    /// Digest of the inputs: mesh bytes, scene bytes, compiler version. The scene's digest
    /// covers the `node_list` files it names: SHA-256 of the scene text alone when it names
    /// none, else of the scene text followed, per file in scene order, by a NUL and the file's
    /// bytes (the names are in the scene text; the resolved paths would depend on the folder
    /// the compiler ran in), so `--check` sees a node list change.
    pub fn digest(&self) -> fmt::InputsDigest {
        let mut scene = self.scene.text.as_bytes().to_vec();
        for (_, bytes) in &self.node_lists {
            scene.push(0);
            scene.extend_from_slice(bytes);
        }
        fmt::InputsDigest {
            mesh_sha256: fmt::sha256_hex(&self.mesh_bytes),
            scene_sha256: fmt::sha256_hex(&scene),
            compiler_version: COMPILER_VERSION.to_owned(),
        }
    }

    /// Scene path (for messages).
    pub fn scene_path(&self) -> &Path {
        &self.scene.path
    }
}
