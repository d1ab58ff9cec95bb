//! The scene's input and output operators on the free DOFs: load groups (3 world components
//! each), gravity, process-noise channels, point sensors and displayed node sets.

use crate::fem::{FemError, FemModel};
use crate::mesh::selection::{Selected, Selections};
use crate::mesh::Mesh;
use crate::scene::{Component, LoadDistribution, Scene, Selector, Target};

/// A sparse row over the free DOFs: (DOF index, coefficient).
pub type SparseRow = Vec<(usize, f64)>;

/// What an input channel is.
#[derive(Clone, Debug, PartialEq)]
pub enum InputKind {
    /// World component `component` (0..3) of the total force on load group `load`, N.
    Load {
        /// Index into [`Operators::loads`].
        load: usize,
        /// 0, 1, 2 for x, y, z.
        component: usize,
    },
    /// Gravity as declared in the scene (input value 1 = the declared acceleration).
    Gravity,
    /// Unit-variance process noise (the column carries the standard deviation): force noise on
    /// load group `load` (index into [`Operators::loads`]), or distributed force noise (`None`).
    Noise {
        /// The load group whose force noise this is, if any.
        load: Option<usize>,
    },
}

/// One input channel: a load vector over the free DOFs.
#[derive(Clone, Debug, PartialEq)]
pub struct InputChannel {
    /// Label, e.g. `tip.x`, `gravity`, `noise:tip.x`.
    pub label: String,
    /// Kind.
    pub kind: InputKind,
    /// Load vector b (n, N per unit input).
    pub column: Vec<f64>,
}

/// A load group: node weights summing to 1 over the group.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadGroup {
    /// Name from the scene.
    pub name: String,
    /// Node indices and their share of the total force.
    pub weights: Vec<(usize, f64)>,
}

/// A point sensor located in a tetrahedron.
#[derive(Clone, Debug, PartialEq)]
pub struct PointSensor {
    /// Name.
    pub name: String,
    /// Position, m.
    pub position: [f64; 3],
    /// Containing element index.
    pub element: usize,
    /// Nodes of that element and the barycentric weights of the point.
    pub weights: [(usize, f64); 4],
    /// Measured components.
    pub components: Vec<Component>,
    /// Noise standard deviation per world component, m.
    pub noise_std: [f64; 3],
    /// A measurement every k steps.
    pub every: u32,
}

/// A displayed node set.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeSet {
    /// Name.
    pub name: String,
    /// Node indices, sorted.
    pub nodes: Vec<usize>,
    /// Triangles in local node indices (into `nodes`), for display.
    pub triangles: Vec<[u32; 3]>,
}

/// All operators the scene defines.
#[derive(Clone, Debug, PartialEq)]
pub struct Operators {
    /// Load groups, scene order.
    pub loads: Vec<LoadGroup>,
    /// Deterministic input channels: each load × (x, y, z), then gravity if declared.
    pub inputs: Vec<InputChannel>,
    /// Process-noise channels (unit variance; columns scaled by their standard deviation).
    pub noise: Vec<InputChannel>,
    /// Sensors, scene order.
    pub sensors: Vec<PointSensor>,
    /// Displayed node sets, scene order.
    pub node_sets: Vec<NodeSet>,
    /// What each `select` took (one line per selection), for the wiring to print.
    pub notes: Vec<String>,
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl Operators {
    /// Builds the operators; `unit` converts scene positions to metres.
    pub fn build(mesh: &Mesh, scene: &Scene, fem: &FemModel, unit: f64) -> Result<Self, FemError> {
        let n = fem.dof_count();
        let mut loads = Vec::new();
        let mut inputs = Vec::new();
        let mut noise = Vec::new();
        let mut notes = Vec::new();
        let mut selections = Selections::new(mesh);
        let mut select = |list: &[Selector], context: &str| -> Result<Selected, FemError> {
            let (s, note) = selections.nodes(list, context)?;
            notes.push(note);
            Ok(s)
        };
        for (li, load) in scene.loads.iter().enumerate() {
            let context = format!("load '{}'", load.name);
            let weights = match load.target() {
                Target::Group(g) => node_weights(mesh, fem, g, load.distribution, &context)?,
                Target::Select(list) => {
                    let s = select(list, &context)?;
                    selection_weights(fem, &s, load.distribution, &context)?
                }
            };
            for c in 0..3 {
                let column = spread(fem, &weights, c, 1.0, n);
                if load.force_noise_std > 0.0 {
                    noise.push(InputChannel {
                        label: format!("noise:{}.{}", load.name, AXES[c]),
                        kind: InputKind::Noise { load: Some(li) },
                        column: column.iter().map(|v| v * load.force_noise_std).collect(),
                    });
                }
                inputs.push(InputChannel {
                    label: format!("{}.{}", load.name, AXES[c]),
                    kind: InputKind::Load {
                        load: li,
                        component: c,
                    },
                    column,
                });
            }
            loads.push(LoadGroup {
                name: load.name.clone(),
                weights,
            });
        }
        if let Some(g) = scene.gravity {
            let mut column = vec![0.0; n];
            for e in &fem.elements {
                let rho = fem.materials[e.material].density;
                let share = rho * e.geometry.volume / 4.0;
                for &node in &e.nodes {
                    for (c, gc) in g.iter().enumerate() {
                        if let Some(d) = fem.dofs.index[node][c] {
                            column[d] += share * gc;
                        }
                    }
                }
            }
            inputs.push(InputChannel {
                label: "gravity".into(),
                kind: InputKind::Gravity,
                column,
            });
        }
        for fnoise in &scene.force_noise {
            let context = format!("force_noise '{}'", fnoise.name);
            let weights = match fnoise.target() {
                Target::Group(g) => node_weights(mesh, fem, g, fnoise.distribution, &context)?,
                Target::Select(list) => {
                    let s = select(list, &context)?;
                    selection_weights(fem, &s, fnoise.distribution, &context)?
                }
            };
            for c in 0..3 {
                noise.push(InputChannel {
                    label: format!("noise:{}.{}", fnoise.name, AXES[c]),
                    kind: InputKind::Noise { load: None },
                    column: spread(fem, &weights, c, fnoise.std, n),
                });
            }
        }

        let sensors = scene
            .sensors
            .iter()
            .map(|s| {
                let position = s.position.map(|v| v * unit);
                let (element, bary) = locate(fem, position).ok_or_else(|| {
                    let (nearest, distance) = nearest_node(fem, position);
                    FemError::SensorOutside {
                        name: s.name.clone(),
                        position,
                        nearest_tag: fem.node_tags[nearest],
                        distance,
                    }
                })?;
                let nodes = fem.elements[element].nodes;
                Ok(PointSensor {
                    name: s.name.clone(),
                    position,
                    element,
                    weights: std::array::from_fn(|a| (nodes[a], bary[a])),
                    components: s.components.clone(),
                    noise_std: [Component::X, Component::Y, Component::Z]
                        .map(|c| s.noise_std.of(c)),
                    every: s.every,
                })
            })
            .collect::<Result<Vec<_>, FemError>>()?;

        let mut node_sets = Vec::new();
        for d in &scene.display {
            let (triangles_global, nodes, what): (Vec<[usize; 3]>, Vec<usize>, String) =
                match d.target() {
                    Target::Group(g) => {
                        let (t, n) = display_group(mesh, fem, g, &d.name)?;
                        (t, n, format!("group '{g}'"))
                    }
                    Target::Select(list) => {
                        let s = select(list, &format!("display '{}'", d.name))?;
                        (s.faces, s.nodes, "its selection".to_owned())
                    }
                };
            if nodes.is_empty() {
                return Err(FemError::Scene(format!(
                    "display '{}': {what} has no nodes of the tetrahedral mesh",
                    d.name
                )));
            }
            let local = |g: usize| nodes.binary_search(&g).ok().map(|i| i as u32);
            let triangles = triangles_global
                .iter()
                .filter_map(|t| Some([local(t[0])?, local(t[1])?, local(t[2])?]))
                .collect();
            node_sets.push(NodeSet {
                name: d.name.clone(),
                nodes,
                triangles,
            });
        }

        Ok(Operators {
            loads,
            inputs,
            noise,
            sensors,
            node_sets,
            notes,
        })
    }

    /// Displacement rows (x, y, z) of a sensor: barycentric interpolation of nodal values.
    pub fn sensor_rows(fem: &FemModel, sensor: &PointSensor) -> [SparseRow; 3] {
        interpolate_rows(&sensor.weights, |node| displacement_rows(fem, node))
    }
}

/// Triangles and nodes of a display given by group name (or the keyword `"surface"`).
fn display_group(
    mesh: &Mesh,
    fem: &FemModel,
    group_name: &str,
    display: &str,
) -> Result<(Vec<[usize; 3]>, Vec<usize>), FemError> {
    let context = format!("display '{display}'");
    let triangles_global: Vec<[usize; 3]> = if group_name == "surface" {
        mesh.surface_triangles()
    } else {
        let group = mesh.find_group(group_name, &context)?;
        if group.dim == 2 {
            group
                .elements
                .iter()
                .map(|&t| mesh.triangles[t].nodes)
                .collect()
        } else {
            Vec::new()
        }
    };
    let nodes: Vec<usize> = if group_name == "surface" {
        let set: std::collections::BTreeSet<usize> =
            triangles_global.iter().flatten().copied().collect();
        set.into_iter().collect()
    } else {
        let used = fem.used_nodes();
        let group = mesh.find_group(group_name, &context)?;
        group
            .nodes
            .iter()
            .copied()
            .filter(|n| used.contains(n))
            .collect()
    };
    Ok((triangles_global, nodes))
}

/// Node weights (summing to 1) of a selection: equal shares (`uniform`) or a third of the area
/// of every selected face per face node (`area`, consistent with a uniform traction).
fn selection_weights(
    fem: &FemModel,
    selected: &Selected,
    distribution: LoadDistribution,
    context: &str,
) -> Result<Vec<(usize, f64)>, FemError> {
    let mut weights: Vec<(usize, f64)> = match distribution {
        LoadDistribution::Uniform => selected.nodes.iter().map(|&n| (n, 1.0)).collect(),
        LoadDistribution::Area => {
            let mut w = std::collections::BTreeMap::new();
            for tri in &selected.faces {
                let area = triangle_area(tri.map(|i| fem.positions[i]));
                for &node in tri {
                    *w.entry(node).or_insert(0.0) += area / 3.0;
                }
            }
            w.into_iter().collect()
        }
    };
    let total: f64 = weights.iter().map(|(_, w)| w).sum();
    if total.is_nan() || total <= 0.0 {
        return Err(FemError::Scene(format!(
            "{context}: the selection has no boundary face (three selected boundary nodes) to \
             spread the force by area; select a boundary patch (nodes = \"boundary\") or use \
             distribution = \"uniform\""
        )));
    }
    for (_, w) in &mut weights {
        *w /= total;
    }
    if !weights
        .iter()
        .any(|&(n, _)| fem.dofs.index[n].iter().any(Option::is_some))
    {
        return Err(FemError::Scene(format!(
            "{context}: every selected node is fixed, so the load cannot act"
        )));
    }
    Ok(weights)
}

fn triangle_area(p: [[f64; 3]; 3]) -> f64 {
    let e1 = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
    let e2 = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
    let c = crate::fem::element::cross(e1, e2);
    0.5 * crate::fem::element::dot(c, c).sqrt()
}

/// Displacement rows (x, y, z) of one node over the free DOFs (empty where fixed).
pub fn displacement_rows(fem: &FemModel, node: usize) -> [SparseRow; 3] {
    std::array::from_fn(|c| match fem.dofs.index[node][c] {
        Some(d) => vec![(d, 1.0)],
        None => Vec::new(),
    })
}

/// Σ wₐ rows(nodeₐ), merging equal DOFs.
pub fn interpolate_rows(
    weights: &[(usize, f64)],
    rows: impl Fn(usize) -> [SparseRow; 3],
) -> [SparseRow; 3] {
    let mut out: [SparseRow; 3] = Default::default();
    for &(node, w) in weights {
        let r = rows(node);
        for c in 0..3 {
            out[c].extend(r[c].iter().map(|&(d, v)| (d, w * v)));
        }
    }
    out.map(merge)
}

/// Sorts a sparse row by DOF and sums duplicates.
pub fn merge(mut row: SparseRow) -> SparseRow {
    row.sort_by_key(|&(d, _)| d);
    let mut out: SparseRow = Vec::with_capacity(row.len());
    for (d, v) in row {
        match out.last_mut() {
            Some(last) if last.0 == d => last.1 += v,
            _ => out.push((d, v)),
        }
    }
    out
}

/// Node weights (summing to 1) of a load or noise group.
fn node_weights(
    mesh: &Mesh,
    fem: &FemModel,
    group_name: &str,
    distribution: LoadDistribution,
    context: &str,
) -> Result<Vec<(usize, f64)>, FemError> {
    let group = mesh.find_group(group_name, context)?;
    let used = fem.used_nodes();
    let mut weights: Vec<(usize, f64)> = match distribution {
        LoadDistribution::Uniform => group
            .nodes
            .iter()
            .filter(|n| used.contains(n))
            .map(|&n| (n, 1.0))
            .collect(),
        LoadDistribution::Area => {
            if group.dim != 2 {
                return Err(FemError::Scene(format!(
                    "{context}: distribution = \"area\" needs a surface (2-D) group, but '{group_name}' \
                     is {}-dimensional; use distribution = \"uniform\"",
                    group.dim
                )));
            }
            let mut w = std::collections::BTreeMap::new();
            for &t in &group.elements {
                let tri = mesh.triangles[t].nodes;
                let p = tri.map(|i| fem.positions[i]);
                let e1 = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
                let e2 = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
                let c = crate::fem::element::cross(e1, e2);
                let area = 0.5 * crate::fem::element::dot(c, c).sqrt();
                for &node in &tri {
                    *w.entry(node).or_insert(0.0) += area / 3.0;
                }
            }
            w.into_iter().filter(|(n, _)| used.contains(n)).collect()
        }
    };
    let total: f64 = weights.iter().map(|(_, w)| w).sum();
    if total.is_nan() || total <= 0.0 {
        return Err(FemError::Scene(format!(
            "{context}: group '{group_name}' has no nodes (or zero area) in the tetrahedral mesh"
        )));
    }
    for (_, w) in &mut weights {
        *w /= total;
    }
    let free = weights
        .iter()
        .any(|&(n, _)| fem.dofs.index[n].iter().any(Option::is_some));
    if !free {
        return Err(FemError::Scene(format!(
            "{context}: every node of group '{group_name}' is fixed, so the load cannot act"
        )));
    }
    Ok(weights)
}

/// Load vector of a unit total force along `component`, scaled by `scale`.
fn spread(
    fem: &FemModel,
    weights: &[(usize, f64)],
    component: usize,
    scale: f64,
    n: usize,
) -> Vec<f64> {
    let mut column = vec![0.0; n];
    for &(node, w) in weights {
        if let Some(d) = fem.dofs.index[node][component] {
            column[d] += scale * w;
        }
    }
    column
}

/// The element containing `p` and its barycentric coordinates (tolerance 1e-9).
fn locate(fem: &FemModel, p: [f64; 3]) -> Option<(usize, [f64; 4])> {
    let mut best: Option<(usize, [f64; 4], f64)> = None;
    for (i, e) in fem.elements.iter().enumerate() {
        let bary = e.geometry.barycentric(fem.positions[e.nodes[0]], p);
        let worst = bary.iter().copied().fold(f64::INFINITY, f64::min);
        if worst >= -1e-9 && best.as_ref().is_none_or(|b| worst > b.2) {
            best = Some((i, bary, worst));
        }
    }
    best.map(|(i, b, _)| (i, b))
}

fn nearest_node(fem: &FemModel, p: [f64; 3]) -> (usize, f64) {
    fem.used_nodes()
        .into_iter()
        .map(|n| {
            let q = fem.positions[n];
            let d = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
            (n, d)
        })
        .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
}
