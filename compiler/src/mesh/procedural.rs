//! Structured tetrahedral box meshes, for tests, convergence studies and benchmarks at a chosen
//! size (a 200k-tetrahedron mesh is generated, not committed).
//!
//! The box [0, lx] × [0, ly] × [0, lz] is split into nx × ny × nz cells and every cell into six
//! tetrahedra along its main diagonal (Kuhn subdivision), which is conforming across cells.
//! Physical groups: volume `body`; surfaces `xmin` and `xmax` (the end faces, as triangles);
//! `surface` is not a group: use the display keyword.

use super::{Mesh, PhysicalGroup, Tetrahedron, Triangle};

/// A structured box mesh with 6·nx·ny·nz tetrahedra; lengths in mesh units.
pub fn box_mesh(cells: [usize; 3], lengths: [f64; 3]) -> Mesh {
    let [nx, ny, nz] = cells;
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([
                    lengths[0] * i as f64 / nx as f64,
                    lengths[1] * j as f64 / ny as f64,
                    lengths[2] * k as f64 / nz as f64,
                ]);
            }
        }
    }
    const PATHS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tetrahedra = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for path in PATHS {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]), 0, 0, 0];
                    for (s, &axis) in path.iter().enumerate() {
                        c[axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    // Orient positively.
                    let x = t.map(|n| nodes[n]);
                    let e = |a: usize| [x[a][0] - x[0][0], x[a][1] - x[0][1], x[a][2] - x[0][2]];
                    let det = super::geometry::det3(e(1), e(2), e(3));
                    if det < 0.0 {
                        t.swap(2, 3);
                    }
                    tetrahedra.push(Tetrahedron {
                        tag: tetrahedra.len() as u64 + 1,
                        nodes: t,
                    });
                }
            }
        }
    }
    let mut triangles = Vec::new();
    let mut end_group = |i: usize, name: &str, tag: i32, groups: &mut Vec<PhysicalGroup>| {
        let first = triangles.len();
        for k in 0..nz {
            for j in 0..ny {
                let q = [
                    id(i, j, k),
                    id(i, j + 1, k),
                    id(i, j + 1, k + 1),
                    id(i, j, k + 1),
                ];
                for tri in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                    triangles.push(Triangle {
                        tag: (tetrahedra.len() + triangles.len()) as u64 + 1,
                        nodes: tri,
                    });
                }
            }
        }
        let elements: Vec<usize> = (first..triangles.len()).collect();
        let mut group_nodes: Vec<usize> =
            elements.iter().flat_map(|&t| triangles[t].nodes).collect();
        group_nodes.sort_unstable();
        group_nodes.dedup();
        groups.push(PhysicalGroup {
            dim: 2,
            tag,
            name: name.into(),
            nodes: group_nodes,
            elements,
        });
    };
    let mut groups = Vec::new();
    end_group(0, "xmin", 1, &mut groups);
    end_group(nx, "xmax", 2, &mut groups);
    groups.push(PhysicalGroup {
        dim: 3,
        tag: 3,
        name: "body".into(),
        nodes: (0..nodes.len()).collect(),
        elements: (0..tetrahedra.len()).collect(),
    });
    Mesh {
        source: format!("box_{nx}x{ny}x{nz}").into(),
        node_tags: (1..=nodes.len() as u64).collect(),
        nodes,
        tetrahedra,
        triangles,
        groups,
    }
}

/// Writes a mesh as gmsh MSH 2.2 ASCII (tetrahedra, triangles and named physical groups).
/// Elements in several groups are written once per group, as gmsh does.
pub fn write_msh22(mesh: &Mesh, path: &std::path::Path) -> std::io::Result<()> {
    use std::io::Write;
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "$MeshFormat\n2.2 0 8\n$EndMeshFormat")?;
    writeln!(w, "$PhysicalNames\n{}", mesh.groups.len())?;
    for g in &mesh.groups {
        writeln!(w, "{} {} \"{}\"", g.dim, g.tag, g.name)?;
    }
    writeln!(w, "$EndPhysicalNames\n$Nodes\n{}", mesh.nodes.len())?;
    for (tag, p) in mesh.node_tags.iter().zip(&mesh.nodes) {
        writeln!(w, "{tag} {:.17e} {:.17e} {:.17e}", p[0], p[1], p[2])?;
    }
    writeln!(w, "$EndNodes")?;
    let mut lines = Vec::new();
    for g in &mesh.groups {
        for &e in &g.elements {
            let (kind, nodes): (u8, Vec<usize>) = match g.dim {
                3 => (4, mesh.tetrahedra[e].nodes.to_vec()),
                2 => (2, mesh.triangles[e].nodes.to_vec()),
                _ => continue,
            };
            let tags: Vec<String> = nodes
                .iter()
                .map(|&n| mesh.node_tags[n].to_string())
                .collect();
            lines.push(format!("{kind} 2 {} {} {}", g.tag, g.tag, tags.join(" ")));
        }
    }
    writeln!(w, "$Elements\n{}", lines.len())?;
    for (i, line) in lines.iter().enumerate() {
        writeln!(w, "{} {line}", i + 1)?;
    }
    writeln!(w, "$EndElements")?;
    w.flush()
}

/// The beam scene shared by tests and benchmarks (one fixture instead of copies): a box of
/// [`box_mesh`] (groups `body`, `xmin`, `xmax`) clamped at `xmin`, a load group `tip` on `xmax`
/// spread by area. Values in SI units; [`BeamScene::toml`] gives the scene file's text.
#[derive(Clone, Debug, PartialEq)]
pub struct BeamScene {
    /// `mesh.file`, relative to the scene file.
    pub mesh_file: String,
    /// E, Pa.
    pub young_modulus: f64,
    /// ν.
    pub poisson_ratio: f64,
    /// ρ, kg/m³.
    pub density: f64,
    /// Rayleigh α, 1/s.
    pub alpha: f64,
    /// Rayleigh β, s.
    pub beta: f64,
    /// Force-noise σ of the tip load, N (none: no process noise).
    pub force_noise_std: Option<f64>,
    /// `force_model` of the tip load (`"white"` or `"random_walk"`; none: the scene default,
    /// `"random_walk"`, which needs a range or `force_noise_std`).
    pub force_model: Option<String>,
    /// Sensors: name and position, m (all three components).
    pub sensors: Vec<(String, [f64; 3])>,
    /// Sensor noise σ, m.
    pub sensor_noise_std: f64,
    /// Displayed node sets: name and group (or the keyword `surface`).
    pub displays: Vec<(String, String)>,
    /// Δt, s.
    pub dt: f64,
}

impl Default for BeamScene {
    /// The benchmark beam: E = 1 MPa, ν = 0.3, ρ = 1000 kg/m³, α = 0.5 1/s, β = 1e-3 s, a tip
    /// load the runtime is told with 0.01 N white force noise, a `tip` sensor, the surface
    /// displayed, Δt = 1 ms.
    fn default() -> Self {
        BeamScene {
            mesh_file: "beam.msh".into(),
            young_modulus: 1.0e6,
            poisson_ratio: 0.3,
            density: 1000.0,
            alpha: 0.5,
            beta: 1.0e-3,
            force_noise_std: Some(0.01),
            force_model: Some("white".into()),
            sensors: vec![("tip".into(), [0.99, 0.05, 0.1])],
            sensor_noise_std: 1.0e-3,
            displays: vec![("surface".into(), "surface".into())],
            dt: 1.0e-3,
        }
    }
}

impl BeamScene {
    /// The scene file's text (TOML).
    pub fn toml(&self) -> String {
        use std::fmt::Write as _;
        let mut s = format!(
            "[mesh]\nfile = \"{}\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = {:e}\n\
             poisson_ratio = {:e}\ndensity = {:e}\n[damping]\nalpha = {:e}\nbeta = {:e}\n\
             [[fixed]]\ngroup = \"xmin\"\n[[load]]\nname = \"tip\"\ngroup = \"xmax\"\n",
            self.mesh_file,
            self.young_modulus,
            self.poisson_ratio,
            self.density,
            self.alpha,
            self.beta
        );
        if let Some(sigma) = self.force_noise_std {
            let _ = writeln!(s, "force_noise_std = {sigma:e}");
        }
        if let Some(model) = &self.force_model {
            let _ = writeln!(s, "force_model = \"{model}\"");
        }
        for (name, p) in &self.sensors {
            let _ = writeln!(
                s,
                "[[sensor]]\nname = \"{name}\"\nposition = [{:e}, {:e}, {:e}]\nnoise_std = {:e}",
                p[0], p[1], p[2], self.sensor_noise_std
            );
        }
        for (name, group) in &self.displays {
            let _ = writeln!(s, "[[display]]\nname = \"{name}\"\ngroup = \"{group}\"");
        }
        let _ = writeln!(s, "[time]\ndt = {:e}", self.dt);
        s
    }
}
