//! Assembly-level tests of the FEM stage on structured meshes.

use std::path::Path;

use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::{sparse_entries, sparse_mul, FemError, FemModel};
use crokf_compile::mesh::procedural::box_mesh;
use crokf_compile::mesh::Mesh;
use crokf_compile::scene::Scene;

fn scene(extra: &str) -> Scene {
    scene_with("", extra)
}

/// A scene with top-level keys `top` (before any table) and tables `extra`.
fn scene_with(top: &str, extra: &str) -> Scene {
    let text = format!(
        r#"
        {top}
        [mesh]
        file = "box.msh"
        [[material]]
        group = "body"
        young_modulus = 2.0e5
        poisson_ratio = 0.3
        density = 1100.0
        [time]
        dt = 0.01
        {extra}
        "#
    );
    Scene::parse(&text, Path::new("test.toml")).unwrap()
}

fn beam() -> Mesh {
    box_mesh([6, 2, 2], [1.0, 0.2, 0.1])
}

#[test]
fn mass_sums_to_rho_v_and_rigid_translation_is_force_free() {
    let mesh = beam();
    for lumped in [false, true] {
        let s = scene(&format!("[mass]\nlumped = {lumped}"));
        let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap();
        let total: f64 = sparse_entries(&fem.mass).map(|(_, _, v)| v).sum();
        let expected = 3.0 * 1100.0 * 0.02;
        assert!(
            (total - expected).abs() < 1e-10 * expected,
            "{total} vs {expected}"
        );
        // Rigid translation and small rigid rotation: K u = 0 (nothing is fixed here).
        let stiffness_scale = sparse_entries(&fem.stiffness)
            .map(|(_, _, v)| v.abs())
            .fold(0.0, f64::max);
        let translation: Vec<f64> = fem
            .dofs
            .dofs
            .iter()
            .map(|&(_, c)| [0.1, -0.2, 0.3][c])
            .collect();
        let omega = [0.01, -0.02, 0.015];
        let rotation: Vec<f64> = fem
            .dofs
            .dofs
            .iter()
            .map(|&(n, c)| crokf_compile::fem::element::cross(omega, fem.positions[n])[c])
            .collect();
        for u in [translation, rotation] {
            let f = sparse_mul(&fem.stiffness, &u);
            let worst = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(worst < 1e-12 * stiffness_scale, "force {worst}");
        }
    }
}

#[test]
fn stiffness_is_symmetric_and_dirichlet_nodes_are_eliminated() {
    let mesh = beam();
    let s = scene("[[fixed]]\ngroup = \"xmin\"");
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap();
    let fixed_nodes = mesh.group("xmin").unwrap().nodes.len();
    assert_eq!(fem.dof_count(), 3 * (mesh.nodes.len() - fixed_nodes));
    let dense = {
        let n = fem.dof_count();
        let mut d = vec![0.0; n * n];
        for (i, j, v) in sparse_entries(&fem.stiffness) {
            d[i * n + j] += v;
        }
        d
    };
    let n = fem.dof_count();
    for i in 0..n {
        for j in 0..n {
            assert!((dense[i * n + j] - dense[j * n + i]).abs() < 1e-9 * dense[i * n + i].abs());
        }
    }
}

#[test]
fn unknown_group_lists_the_groups_that_exist() {
    let s = scene("[[fixed]]\ngroup = \"clampp\"");
    let e = FemModel::assemble(&beam(), &s, 1.0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("clampp") && e.contains("xmin") && e.contains("body"),
        "{e}"
    );
}

#[test]
fn inverted_and_zero_volume_tetrahedra_are_named() {
    let mut mesh = beam();
    mesh.tetrahedra[7].nodes.swap(0, 1);
    let tag = mesh.tetrahedra[7].tag;
    let e = FemModel::assemble(&mesh, &scene(""), 1.0).unwrap_err();
    assert!(
        matches!(
            e,
            FemError::DegenerateElement {
                kind: "inverted",
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains(&format!("tetrahedron {tag}")), "{e}");

    let mut mesh = beam();
    let n = mesh.tetrahedra[3].nodes;
    // Move node 3 of the element onto the plane of the other three.
    let p: Vec<[f64; 3]> = n.iter().map(|&i| mesh.nodes[i]).collect();
    let mut tet = mesh.tetrahedra[3].clone();
    let extra = mesh.nodes.len();
    mesh.nodes.push([
        (p[0][0] + p[1][0] + p[2][0]) / 3.0,
        (p[0][1] + p[1][1] + p[2][1]) / 3.0,
        (p[0][2] + p[1][2] + p[2][2]) / 3.0,
    ]);
    mesh.node_tags.push(extra as u64 + 1);
    tet.nodes[3] = extra;
    mesh.tetrahedra[3] = tet;
    let e = FemModel::assemble(&mesh, &scene(""), 1.0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("zero volume") && e.contains(&format!("tetrahedron {}", mesh.tetrahedra[3].tag)),
        "{e}"
    );
}

#[test]
fn sensor_outside_the_mesh_is_refused_and_inside_interpolates() {
    let mesh = beam();
    let s = scene(
        r#"[[sensor]]
        name = "far"
        position = [2.0, 0.05, 0.05]
        noise_std = 1e-3"#,
    );
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap();
    let e = Operators::build(&mesh, &s, &fem, 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("far") && e.contains("outside"), "{e}");

    let s = scene(
        r#"[[sensor]]
        name = "in"
        position = [0.53, 0.07, 0.031]
        noise_std = 1e-3"#,
    );
    let ops = Operators::build(&mesh, &s, &fem, 1.0).unwrap();
    // A linear field u = A x is interpolated exactly.
    let u: Vec<f64> = fem
        .dofs
        .dofs
        .iter()
        .map(|&(n, c)| {
            let x = fem.positions[n];
            [x[0] + 2.0 * x[1], 3.0 * x[2] - x[0], x[1]][c]
        })
        .collect();
    let rows = Operators::sensor_rows(&fem, &ops.sensors[0]);
    let got: Vec<f64> = rows
        .iter()
        .map(|r| r.iter().map(|&(d, w)| w * u[d]).sum())
        .collect();
    let exact = [0.53 + 0.14, 0.093 - 0.53, 0.07];
    for c in 0..3 {
        assert!((got[c] - exact[c]).abs() < 1e-12, "{got:?}");
    }
}

#[test]
fn load_columns_carry_unit_total_force_and_gravity_carries_weight() {
    let mesh = beam();
    let s = scene_with(
        "gravity = [0.0, 0.0, -9.81]",
        r#"[[load]]
        name = "tip"
        group = "xmax"
        force_model = "white""#,
    );
    let fem = FemModel::assemble(&mesh, &s, 1.0).unwrap();
    let ops = Operators::build(&mesh, &s, &fem, 1.0).unwrap();
    assert_eq!(ops.inputs.len(), 4);
    for c in 0..3 {
        let sum: f64 = ops.inputs[c].column.iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "{sum}");
    }
    let weight: f64 = ops.inputs[3].column.iter().sum();
    assert!((weight + 9.81 * 1100.0 * 0.02).abs() < 1e-9, "{weight}");
}
