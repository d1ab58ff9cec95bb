//! Scene selections (`select = [...]`) against closed-form counts on a structured mesh, and the
//! scene's range checks and warnings.
//!
//! Mesh: the unit cube [0, 1]³ cut into n = 4 cells per side, each cell into its 6 Kuhn
//! tetrahedra (384 tetrahedra, 125 nodes, node (i, j, k) at (i, j, k)/4 with tag
//! 1 + i + 5j + 25k), one volume group "3:1" (no physical names). Closed forms: a face of the cube
//! has (n + 1)² = 25 nodes and 2n² = 32 boundary triangles; the boundary has
//! 6n² + 2 = 98 nodes.

use std::path::{Path, PathBuf};

use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::{FemError, FemModel};
use crokf_compile::mesh::{Mesh, PhysicalGroup, Tetrahedron};
use crokf_compile::scene::{Scene, SceneFile};

const N: usize = 4;

fn cube_mesh() -> Mesh {
    let id = |i: usize, j: usize, k: usize| i + (N + 1) * j + (N + 1) * (N + 1) * k;
    let mut nodes = Vec::new();
    for k in 0..=N {
        for j in 0..=N {
            for i in 0..=N {
                nodes.push([i as f64, j as f64, k as f64].map(|v| v / N as f64));
            }
        }
    }
    let mut tetrahedra = Vec::new();
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                for perm in [
                    [0, 1, 2],
                    [0, 2, 1],
                    [1, 0, 2],
                    [1, 2, 0],
                    [2, 0, 1],
                    [2, 1, 0],
                ] {
                    let mut p = [i, j, k];
                    let mut path = vec![id(p[0], p[1], p[2])];
                    for axis in perm {
                        p[axis] += 1;
                        path.push(id(p[0], p[1], p[2]));
                    }
                    let mut t = [path[0], path[1], path[2], path[3]];
                    let x = t.map(|n| nodes[n]);
                    let d = |a: usize| [0, 1, 2].map(|c| x[a][c] - x[0][c]);
                    let (a, b, c) = (d(1), d(2), d(3));
                    let det = a[0] * (b[1] * c[2] - b[2] * c[1])
                        - a[1] * (b[0] * c[2] - b[2] * c[0])
                        + a[2] * (b[0] * c[1] - b[1] * c[0]);
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
    let groups = vec![PhysicalGroup {
        dim: 3,
        tag: 1,
        name: "3:1".into(),
        nodes: (0..nodes.len()).collect(),
        elements: (0..tetrahedra.len()).collect(),
    }];
    Mesh {
        source: "cube".into(),
        node_tags: (1..=nodes.len() as u64).collect(),
        nodes,
        tetrahedra,
        triangles: Vec::new(),
        groups,
    }
}

const BASE: &str = r#"
[mesh]
file = "cube.msh"
[[material]]
group = "3:1"
young_modulus = 1e6
poisson_ratio = 0.3
density = 1000.0
[time]
dt = 0.01
"#;

fn scene(extra: &str) -> Scene {
    Scene::parse(&format!("{BASE}\n{extra}"), Path::new("scene.toml"))
        .unwrap_or_else(|e| panic!("{e}"))
}

fn scene_err(text: &str) -> String {
    Scene::parse(text, Path::new("scene.toml"))
        .expect_err("accepted")
        .to_string()
}

const FIX_BOTTOM: &str = r#"
[[fixed]]
select = [{ box = { min = [-1.0, -1.0, -1.0], max = [2.0, 2.0, 0.0] }, nodes = "boundary" }]
"#;

fn build(extra: &str) -> (FemModel, Operators) {
    let mesh = cube_mesh();
    let s = scene(&format!("{FIX_BOTTOM}\n{extra}"));
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap_or_else(|e| panic!("{e}"));
    let ops = Operators::build(&mesh, &s, &fem, 1.0).unwrap_or_else(|e| panic!("{e}"));
    (fem, ops)
}

fn fixed_nodes(fem: &FemModel) -> usize {
    fem.dofs
        .index
        .iter()
        .filter(|d| d.iter().all(Option::is_none))
        .count()
}

#[test]
fn box_on_boundary_fixes_one_face_and_notes_the_count() {
    let (fem, _) = build("");
    // 25 nodes on z = 0, all three components fixed: 3 × (125 − 25) free DOFs.
    assert_eq!(fixed_nodes(&fem), 25);
    assert_eq!(fem.dof_count(), 3 * 100);
    assert!(
        fem.notes
            .iter()
            .any(|n| n.starts_with("fixed 1: selection took 25 nodes and 32 faces")),
        "{:?}",
        fem.notes
    );
}

#[test]
fn half_space_sphere_and_union_counts_match_closed_forms() {
    let (_, ops) = build(
        r#"
[[display]]
name = "lower_half"
select = [{ half_space = { point = [0.0, 0.0, 0.5], normal = [0.0, 0.0, -1.0] }, nodes = "all" }]
[[display]]
name = "corner_ball"
select = [{ sphere = { center = [0.0, 0.0, 0.0], radius = 0.3 }, nodes = "boundary" }]
[[display]]
name = "top_and_bottom"
select = [
  { box = { min = [0.0, 0.0, 1.0], max = [1.0, 1.0, 1.0] }, nodes = "boundary" },
  { half_space = { point = [0.0, 0.0, 0.0], normal = [0.0, 0.0, -1.0] }, nodes = "boundary" },
]
[[display]]
name = "skin"
select = [{ everything = true, nodes = "boundary" }]
"#,
    );
    let count = |name: &str| {
        let s = ops.node_sets.iter().find(|s| s.name == name).expect(name);
        (s.nodes.len(), s.triangles.len())
    };
    // z ≤ 0.5: 3 layers of 25 nodes; the faces of the boundary below: bottom 32, sides 4 × 2 × 2 × 4.
    assert_eq!(count("lower_half"), (75, 32 + 4 * 16));
    // |x| ≤ 0.3 on the boundary: the corner and its three neighbours at 0.25 (0.354 is out).
    assert_eq!(count("corner_ball").0, 4);
    assert_eq!(count("top_and_bottom"), (50, 64));
    assert_eq!(count("skin"), (98, 6 * 32));
    let note = ops
        .notes
        .iter()
        .find(|n| n.starts_with("display 'top_and_bottom'"))
        .expect("note");
    assert!(
        note.contains("50 nodes and 64 faces") && note.contains("25 nodes, 32 faces"),
        "{note}"
    );
}

#[test]
fn area_load_on_a_selected_face_has_the_face_centroid_as_first_moment() {
    let (fem, ops) = build(
        r#"
[[load]]
name = "top"
force_model = "white"
select = [{ box = { min = [0.0, 0.0, 0.99], max = [1.0, 1.0, 1.01] }, nodes = "boundary" }]
distribution = "area"
"#,
    );
    let w = &ops.loads[0].weights;
    assert_eq!(w.len(), 25);
    let total: f64 = w.iter().map(|(_, v)| v).sum();
    assert!((total - 1.0).abs() < 1e-14);
    // A uniform traction on the unit square: first moment = its centroid (0.5, 0.5, 1).
    for c in 0..3 {
        let m: f64 = w.iter().map(|&(n, v)| v * fem.positions[n][c]).sum();
        assert!((m - [0.5, 0.5, 1.0][c]).abs() < 1e-14, "component {c}: {m}");
    }
    // Corner node of the top face: 1 or 2 triangles of area 1/32, a third each.
    let corner = fem
        .positions
        .iter()
        .position(|p| *p == [0.0, 0.0, 1.0])
        .expect("corner");
    let wc = w
        .iter()
        .find(|(n, _)| *n == corner)
        .map(|(_, v)| *v)
        .expect("weight");
    assert!(
        (wc - 1.0 / 96.0).abs() < 1e-14 || (wc - 2.0 / 96.0).abs() < 1e-14,
        "{wc}"
    );
}

#[test]
fn material_selection_takes_tetrahedra_by_centroid() {
    let mesh = cube_mesh();
    let text = BASE.replace(
        "group = \"3:1\"",
        "select = [{ half_space = { point = [0.5, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] } }]",
    ) + r#"
[[material]]
select = [{ half_space = { point = [0.5, 0.0, 0.0], normal = [1.0, 0.0, 0.0] } }]
young_modulus = 2e6
poisson_ratio = 0.3
density = 1000.0
"# + FIX_BOTTOM;
    let s = Scene::parse(&text, Path::new("scene.toml")).unwrap_or_else(|e| panic!("{e}"));
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap_or_else(|e| panic!("{e}"));
    // No centroid lies on x = 0.5: each half takes exactly half of the 384 tetrahedra.
    let stiff = fem.elements.iter().filter(|e| e.material == 1).count();
    assert_eq!(stiff, 192);
    assert!(fem
        .elements
        .iter()
        .all(|e| (e.material == 1) == (e.geometry.volume > 0.0 && centroid_x(&fem, e) > 0.5)));
    assert!(
        fem.notes
            .iter()
            .any(|n| n.starts_with("material 2: selection took 192 tetrahedra")),
        "{:?}",
        fem.notes
    );
}

fn centroid_x(fem: &FemModel, e: &crokf_compile::fem::Element) -> f64 {
    e.nodes.iter().map(|&n| fem.positions[n][0]).sum::<f64>() / 4.0
}

#[test]
fn same_group_by_name_or_by_select_gives_identical_operators() {
    let mesh = cube_mesh();
    let by_name = scene(&format!(
        "{FIX_BOTTOM}\n[[load]]\nname = \"all\"\ngroup = \"3:1\"\ndistribution = \"uniform\"\n\
         force_model = \"white\"\n"
    ));
    let by_select = scene(&format!(
        "{FIX_BOTTOM}\n[[load]]\nname = \"all\"\nselect = [{{ group = \"3:1\" }}]\nforce_model = \"white\"\n\
         distribution = \"uniform\"\n"
    ));
    let fem = FemModel::assemble(&mesh, &by_name, 1.0).unwrap();
    let a = Operators::build(&mesh, &by_name, &fem, 1.0).unwrap();
    let b = Operators::build(&mesh, &by_select, &fem, 1.0).unwrap();
    assert_eq!(a.loads, b.loads);
    assert_eq!(a.inputs, b.inputs);
}

#[test]
fn node_list_file_selects_by_tag_and_names_bad_lines() {
    let dir = std::env::temp_dir().join(format!("crokf-selection-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Tags 1..=5: the row j = 0, k = 0 (x = 0, 0.25, ..., 1).
    std::fs::write(
        dir.join("row.txt"),
        "# bottom front row\n1, 2 3\n4\n5 # last\n",
    )
    .unwrap();
    std::fs::write(dir.join("bad.txt"), "1\n2\n999\n").unwrap();
    let mesh = cube_mesh();
    let text = |file: &str| format!("{BASE}\n[[fixed]]\nselect = [{{ node_list = \"{file}\" }}]\n");
    let path = dir.join("scene.toml");
    let s = Scene::parse(&text("row.txt"), &path).unwrap_or_else(|e| panic!("{e}"));
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(fixed_nodes(&fem), 5);
    let s = Scene::parse(&text("bad.txt"), &path).unwrap();
    let e = FemModel::assemble(&mesh, &s, 1.0).unwrap_err().to_string();
    assert!(
        e.contains("bad.txt") && e.contains("line 3") && e.contains("node 999"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn empty_selection_is_refused_naming_selector_and_extent() {
    let mesh = cube_mesh();
    let s = scene(
        "[[fixed]]\nselect = [{ sphere = { center = [5.0, 5.0, 5.0], radius = 0.1 }, nodes = \"all\" }]",
    );
    let e = FemModel::assemble(&mesh, &s, 1.0).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, FemError::Selection(_)), "{msg}");
    assert!(
        msg.contains(
            "fixed 1: select[0] (sphere at (5, 5, 5) r = 0.1 on all nodes) takes no nodes"
        ) && msg.contains("x [0.000000e0, 1.000000e0]"),
        "{msg}"
    );
}

#[test]
fn unnamed_groups_are_listed_with_sizes_and_a_way_forward() {
    let mesh = cube_mesh();
    let s = scene("[[fixed]]\ngroup = \"base\"");
    let msg = FemModel::assemble(&mesh, &s, 1.0).unwrap_err().to_string();
    assert!(
        msg.contains("'3:1' (3-D, 384 tetrahedra)")
            && msg.contains("no physical names")
            && msg.contains("box"),
        "{msg}"
    );
}

#[test]
fn selector_schema_errors_name_the_entry() {
    let with = |entry: &str| format!("{BASE}\n{entry}");
    let e = scene_err(&with(
        "[[fixed]]\nselect = [{ box = { min = [0.0, 0.0, 0.0], max = [1.0, 1.0, 0.0] } }]",
    ));
    assert!(
        e.contains("fixed 1: select[0]") && e.contains("nodes = \"boundary\""),
        "{e}"
    );
    let e = scene_err(&with(
        "[[fixed]]\nselect = [{ sphere = { center = [0.0, 0.0, 0.0], radius = 1.0 }, group = \"a\" }]",
    ));
    assert!(e.contains("exactly one of"), "{e}");
    let e = scene_err(&with(
        "[[fixed]]\ngroup = \"a\"\nselect = [{ group = \"b\" }]",
    ));
    assert!(e.contains("either `group` or `select`"), "{e}");
    let e = scene_err(&with(
        "[[fixed]]\nselect = [{ box = { min = [1.0, 0.0, 0.0], max = [0.0, 1.0, 1.0] }, nodes = \"all\" }]",
    ));
    assert!(e.contains("box.min"), "{e}");
    let e = scene_err(&with(
        "[[fixed]]\nselect = [{ boxx = { min = [0.0, 0.0, 0.0] } }]",
    ));
    assert!(e.contains("boxx"), "{e}");
}

#[test]
fn physical_fields_are_range_checked_naming_field_and_range() {
    for (from, to, needles) in [
        (
            "young_modulus = 1e6",
            "young_modulus = 1e300",
            ["young_modulus", "1e13"],
        ),
        (
            "young_modulus = 1e6",
            "young_modulus = 1e-300",
            ["young_modulus", "1e0"],
        ),
        ("density = 1000.0", "density = 1e300", ["density", "kg/m³"]),
        ("dt = 0.01", "dt = 1e6", ["time.dt", "1e1"]),
        ("dt = 0.01", "dt = 0.01\ntheta = 50.0", ["time.theta", "10"]),
    ] {
        let e = scene_err(&BASE.replace(from, to));
        for n in needles {
            assert!(e.contains(n), "{to}: '{n}' not in {e}");
        }
    }
    let e = scene_err(&format!(
        "{BASE}\n[[sensor]]\nname = \"m\"\nposition = [0.5, 0.5, 0.5]\nnoise_std = 1e300\n"
    ));
    assert!(
        e.contains("sensor 'm': noise_std") && e.contains("1e3"),
        "{e}"
    );
    let e = scene_err(&format!(
        "{BASE}\n[[load]]\nname = \"p\"\ngroup = \"3:1\"\nforce_noise_std = 1e300\n"
    ));
    assert!(
        e.contains("load 'p': force_noise_std") && e.contains("1e9"),
        "{e}"
    );
    let e = scene_err(&format!(
        "{BASE}\n[[sensor]]\nname = \"m\"\nposition = [1e300, 0.5, 0.5]\nnoise_std = 1e-3\n"
    ));
    assert!(
        e.contains("sensor 'm': position") && e.contains("1e9"),
        "{e}"
    );
}

#[test]
fn warnings_for_near_incompressible_material_and_wrong_unit() {
    let s = scene("");
    assert!(s.warnings().is_empty());
    let s = Scene::parse(&BASE.replace("0.3", "0.495"), Path::new("scene.toml")).unwrap();
    let w = s.warnings();
    assert!(
        w.len() == 1 && w[0].contains("poisson_ratio = 0.495") && w[0].contains("lock"),
        "{w:?}"
    );
    // The unit cube declared in millimetres spans 1.7 mm: suspect.
    let mesh = cube_mesh();
    let notes = crokf_compile::fem::mesh_notes(&mesh, 1e-3);
    assert!(
        notes.iter().any(|n| n.contains("mesh.units = \"m\"")),
        "{notes:?}"
    );
    assert!(crokf_compile::fem::mesh_notes(&mesh, 1.0).is_empty());
    let notes = crokf_compile::fem::mesh_notes(&mesh, 1e3);
    assert!(notes.iter().any(|n| n.contains("\"mm\"")), "{notes:?}");
}

#[test]
fn scene_file_with_bom_reads_and_a_directory_mesh_is_named() {
    let dir = std::env::temp_dir().join(format!("crokf-scene-bom-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path: PathBuf = dir.join("scene.toml");
    std::fs::write(&path, format!("\u{feff}{BASE}")).unwrap();
    let s = SceneFile::read(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        s.text.starts_with('\u{feff}'),
        "the digest covers the file as it is"
    );
    std::fs::write(&path, BASE.replace("cube.msh", ".")).unwrap();
    let e = SceneFile::read(&path).unwrap_err().to_string();
    assert!(
        e.contains("mesh.file") && e.contains("is a directory"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn every_inverted_tetrahedron_is_counted_and_the_first_ten_listed() {
    let mut mesh = cube_mesh();
    // Invert 12 tetrahedra (every 32nd): each has volume 1/(6·4³) = 2.604e-3.
    for i in (0..384).step_by(32) {
        mesh.tetrahedra[i].nodes.swap(0, 1);
    }
    let s = scene(FIX_BOTTOM);
    let msg = FemModel::assemble(&mesh, &s, 1.0).unwrap_err().to_string();
    let listed: Vec<String> = (0..10)
        .map(|k| format!("{}: -2.604e-3", 32 * k + 1))
        .collect();
    assert!(
        msg.contains("12 tetrahedra are inverted or degenerate")
            && msg.contains(&listed.join(", "))
            && !msg.contains("321: "),
        "{msg}"
    );
}
