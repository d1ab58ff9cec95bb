//! gmsh readers: MSH 4.1 ASCII/binary (mshio) and MSH 2.2 ASCII give the same mesh; groups,
//! names, boundary faces and the committed cantilever mesh; clear errors on bad input.
//!
//! Fixtures (`tests/fixtures/cube_*.msh`, from `scripts/gen_meshes.py`): the unit cube split
//! into its 6 Kuhn tetrahedra. Node tag t sits at corner (i, j, k) with t = 1 + i + 2j + 4k
//! (×10 in the "sparse" fixture), every tetrahedron has volume 1/6.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crokf_compile::mesh::{read_mesh, read_mesh_bytes, Mesh, MeshError};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn cantilever_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/cantilever/cantilever.msh")
}

fn read(name: &str) -> Mesh {
    let p = fixture(name);
    read_mesh(&p).unwrap_or_else(|e| panic!("{e}"))
}

/// Corner of the unit cube for node tag `t` (t = 1 + i + 2j + 4k).
fn corner(t: u64) -> [f64; 3] {
    let i = t - 1;
    [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64]
}

/// A file with `text` in a fresh temporary directory; returns its path.
fn temp_file(name: &str, bytes: &[u8]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("crokf-mesh-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn err_of(name: &str, bytes: &[u8]) -> (PathBuf, MeshError, String) {
    let p = temp_file(name, bytes);
    let e = read_mesh(&p).expect_err("malformed mesh was accepted");
    let msg = e.to_string();
    assert!(msg.contains(&p.display().to_string()), "{msg}");
    (p, e, msg)
}

fn text(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).unwrap()
}

fn tet_nodes(m: &Mesh) -> Vec<[usize; 4]> {
    m.tetrahedra.iter().map(|t| t.nodes).collect()
}

fn tri_nodes(m: &Mesh) -> Vec<[usize; 3]> {
    m.triangles.iter().map(|t| t.nodes).collect()
}

#[test]
fn three_formats_give_identical_meshes() {
    let a = read("cube_41_ascii.msh");
    let b = read("cube_41_binary.msh");
    let c = read("cube_22_ascii.msh");
    for m in [&b, &c] {
        assert_eq!(m.node_tags, a.node_tags);
        assert_eq!(m.nodes, a.nodes);
        assert_eq!(tet_nodes(m), tet_nodes(&a));
        assert_eq!(tri_nodes(m), tri_nodes(&a));
        assert_eq!(m.groups, a.groups);
    }
    // 4.1 ASCII and binary also agree on element tags; 2.2 renumbers (one copy per group).
    assert_eq!(b.tetrahedra, a.tetrahedra);
    assert_eq!(b.triangles, a.triangles);
    assert_eq!(a.tetrahedra.len(), 6);
    assert_eq!(a.triangles.len(), 12);
    assert_eq!(c.triangles.len(), 12, "2.2 per-group copies must be merged");
}

#[test]
fn node_tags_match_coordinates_in_every_fixture() {
    for (name, scale) in [
        ("cube_41_ascii.msh", 1),
        ("cube_41_binary.msh", 1),
        ("cube_22_ascii.msh", 1),
        ("cube_41_sparse_ascii.msh", 10),
        ("cube_41_reversed_ascii.msh", 1),
        ("cube_41_reversed_binary.msh", 1),
    ] {
        let m = read(name);
        assert_eq!(m.nodes.len(), 8, "{name}");
        for (t, x) in m.node_tags.iter().zip(&m.nodes) {
            assert_eq!(t % scale, 0, "{name}: tag {t}");
            assert_eq!(*x, corner(t / scale), "{name}: node {t}");
        }
        for i in 0..m.tetrahedra.len() {
            let v = m.signed_volume(i);
            assert!((v - 1.0 / 6.0).abs() < 1e-15, "{name}: tet {i} volume {v}");
        }
        assert_eq!(m.group_names(), read("cube_41_ascii.msh").group_names());
    }
    // The reversed fixtures list tags 8, 7, ..., 1 (contiguous, so mshio drops them).
    assert_eq!(
        read("cube_41_reversed_binary.msh").node_tags,
        vec![8, 7, 6, 5, 4, 3, 2, 1]
    );
    assert_eq!(
        read("cube_41_reversed_ascii.msh").node_tags,
        vec![8, 7, 6, 5, 4, 3, 2, 1]
    );
}

#[test]
fn physical_groups_have_names_nodes_and_elements() {
    let m = read("cube_41_binary.msh");
    let summary: Vec<(u8, i32, &str)> = m
        .groups
        .iter()
        .map(|g| (g.dim, g.tag, g.name.as_str()))
        .collect();
    assert_eq!(
        summary,
        vec![
            (0, 6, "corner"),
            (1, 5, "edge"),
            (2, 2, "bottom"),
            (2, 3, "top"),
            (2, 4, "boundary"),
            (2, 7, "2:7"),
            (3, 1, "body"),
        ]
    );
    let nodes_at = |g: &str| -> Vec<[f64; 3]> {
        let g = m.group(g).unwrap();
        assert!(g.nodes.windows(2).all(|w| w[0] < w[1]), "sorted unique");
        g.nodes.iter().map(|&n| m.nodes[n]).collect()
    };
    assert_eq!(nodes_at("corner"), vec![[0.0, 0.0, 0.0]]);
    assert_eq!(nodes_at("edge"), vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
    assert!(nodes_at("bottom").iter().all(|x| x[2] == 0.0));
    assert_eq!(nodes_at("bottom").len(), 4);
    assert!(nodes_at("top").iter().all(|x| x[2] == 1.0));
    assert_eq!(nodes_at("body").len(), 8);
    assert_eq!(nodes_at("boundary").len(), 8);
    let elements = |g: &str| m.group(g).unwrap().elements.clone();
    assert_eq!(elements("body"), (0..6).collect::<Vec<_>>());
    assert_eq!(elements("boundary"), (0..12).collect::<Vec<_>>());
    assert_eq!(elements("bottom").len(), 2);
    assert_eq!(elements("2:7").len(), 8);
    assert!(elements("corner").is_empty() && elements("edge").is_empty());
    for &t in &elements("top") {
        assert!(m.triangles[t].nodes.iter().all(|&n| m.nodes[n][2] == 1.0));
    }
}

/// Σ_faces x₀·((x₁−x₀)×(x₂−x₀))/6 over a closed outward-oriented surface is the enclosed
/// volume (divergence theorem with F = x/3); Σ ½|n| is the area.
fn surface_volume_and_area(m: &Mesh, faces: &[[usize; 3]]) -> (f64, f64) {
    let (mut vol, mut area) = (0.0, 0.0);
    for f in faces {
        let [a, b, c] = f.map(|n| m.nodes[n]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        vol += (a[0] * n[0] + a[1] * n[1] + a[2] * n[2]) / 6.0;
        area += 0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    }
    (vol, area)
}

fn sorted_keys(faces: impl IntoIterator<Item = [usize; 3]>) -> BTreeSet<[usize; 3]> {
    faces
        .into_iter()
        .map(|mut f| {
            f.sort_unstable();
            f
        })
        .collect()
}

#[test]
fn surface_triangles_are_the_outward_boundary() {
    let mut m = read("cube_41_ascii.msh");
    let s = m.surface_triangles();
    assert_eq!(s.len(), 12);
    let (vol, area) = surface_volume_and_area(&m, &s);
    assert!((vol - 1.0).abs() < 1e-14, "enclosed volume {vol}");
    assert!((area - 6.0).abs() < 1e-14, "area {area}");
    // Same faces as gmsh's boundary triangles (independent: written by the mesher).
    let boundary = m.group("boundary").unwrap();
    let from_file = boundary.elements.iter().map(|&t| m.triangles[t].nodes);
    assert_eq!(sorted_keys(s.iter().copied()), sorted_keys(from_file));
    // Deterministic form: each triple starts at its smallest index, the list is sorted.
    assert!(s.iter().all(|f| f[0] < f[1] && f[0] < f[2]));
    assert!(s.windows(2).all(|w| w[0] < w[1]));
    // Independent of the tetrahedra's own orientation.
    for t in &mut m.tetrahedra {
        t.nodes.swap(0, 1);
    }
    assert_eq!(m.surface_triangles(), s);
}

#[test]
fn committed_cantilever_mesh() {
    let m = read_mesh(&cantilever_path()).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        (1500..=3000).contains(&m.tetrahedra.len()),
        "{} tets",
        m.tetrahedra.len()
    );
    let mut names = m.group_names();
    names.sort();
    assert_eq!(names, ["beam", "clamp", "surface", "tip"]);
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for x in &m.nodes {
        for k in 0..3 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    for (k, len) in [1.0, 0.1, 0.1].into_iter().enumerate() {
        assert!(
            lo[k].abs() < 1e-12 && (hi[k] - len).abs() < 1e-12,
            "{lo:?} {hi:?}"
        );
    }
    let mut total = 0.0;
    for i in 0..m.tetrahedra.len() {
        let v = m.signed_volume(i);
        assert!(v > 0.0, "tet {} has volume {v}", m.tetrahedra[i].tag);
        total += v;
    }
    assert!((total - 0.01 * 1.0).abs() < 1e-12, "volume {total}");
    assert_eq!(m.group("beam").unwrap().elements.len(), m.tetrahedra.len());
    for (g, x) in [("clamp", 0.0), ("tip", 1.0)] {
        let g = m.group(g).unwrap();
        assert_eq!(g.dim, 2);
        assert!(g.nodes.iter().all(|&n| (m.nodes[n][0] - x).abs() < 1e-12));
        let faces: Vec<_> = g.elements.iter().map(|&t| m.triangles[t].nodes).collect();
        let (_, area) = surface_volume_and_area(&m, &faces);
        assert!((area - 0.01).abs() < 1e-12, "{} area {area}", g.name);
    }
    let s = m.surface_triangles();
    let (vol, area) = surface_volume_and_area(&m, &s);
    assert!((vol - 0.01).abs() < 1e-12, "enclosed volume {vol}");
    assert!((area - 0.42).abs() < 1e-12, "surface area {area}");
    let surface = m.group("surface").unwrap();
    let from_file = surface.elements.iter().map(|&t| m.triangles[t].nodes);
    assert_eq!(sorted_keys(s.iter().copied()), sorted_keys(from_file));
}

#[test]
fn cantilever_scene_parses() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/cantilever/scene.toml");
    let s = crokf_compile::scene::SceneFile::read(&p).unwrap_or_else(|e| panic!("{e}"));
    let m = read_mesh(&s.mesh_path()).unwrap_or_else(|e| panic!("{e}"));
    let name = |g: &Option<String>| g.clone().expect("the cantilever names its groups");
    for name in s.scene.materials.iter().map(|x| name(&x.group)) {
        assert_eq!(m.group(&name).map(|g| g.dim), Some(3), "{name}");
    }
    for name in s.scene.fixed.iter().map(|x| name(&x.group)) {
        assert!(m.group(&name).is_some(), "{name}");
    }
    for name in s.scene.loads.iter().map(|x| name(&x.group)) {
        assert_eq!(m.group(&name).map(|g| g.dim), Some(2), "{name}");
    }
    for d in s.scene.display.iter().map(|x| name(&x.group)) {
        assert!(d == "surface" || m.group(&d).is_some(), "{d}");
    }
    // Sensors lie inside the beam.
    for sensor in &s.scene.sensors {
        let [x, y, z] = sensor.position;
        assert!((0.0..=1.0).contains(&x) && (0.0..=0.1).contains(&y) && (0.0..=0.1).contains(&z));
    }
}

#[test]
fn missing_file_names_the_path() {
    let p = fixture("does_not_exist.msh");
    let msg = read_mesh(&p).unwrap_err().to_string();
    assert!(
        msg.contains("does_not_exist.msh") && msg.contains("cannot read"),
        "{msg}"
    );
}

#[test]
fn unsupported_versions_name_version_and_conversion() {
    let body = "$EndMeshFormat\n$Nodes\n0\n$EndNodes\n";
    for (header, version, encoding) in [
        ("4.0 0 8", "4.0", "ASCII"),
        ("3.0 0 8", "3.0", "ASCII"),
        ("2.2 1 8", "2.2", "binary"),
    ] {
        let mut bytes = format!("$MeshFormat\n{header}\n").into_bytes();
        if encoding == "binary" {
            bytes.extend_from_slice(&1i32.to_le_bytes());
            bytes.push(b'\n');
        }
        bytes.extend_from_slice(body.as_bytes());
        let (_, e, msg) = err_of(&format!("v{version}{encoding}.msh"), &bytes);
        assert!(matches!(e, MeshError::UnsupportedVersion { .. }), "{msg}");
        assert!(
            msg.contains(&format!("MSH version {version} {encoding}")),
            "{msg}"
        );
        // The command was checked with gmsh 4.15 on MSH 4.0, 3.0 and 2.2 binary files.
        assert!(
            msg.contains(&format!("gmsh {} -save -format msh41", p_of(&e))),
            "{msg}"
        );
    }
}

fn p_of_any(e: &MeshError) -> String {
    match e {
        MeshError::NotGmsh { path, .. } => path.display().to_string(),
        _ => String::new(),
    }
}

fn p_of(e: &MeshError) -> String {
    match e {
        MeshError::UnsupportedVersion { path, .. } => path.display().to_string(),
        _ => String::new(),
    }
}

#[test]
fn non_gmsh_files_are_refused() {
    let (_, e, msg) = err_of("garbage.msh", b"\x00\x9f\x92\x96 binary junk\xff\n\x01\x02");
    assert!(matches!(e, MeshError::NotGmsh { .. }), "{msg}");
    assert!(
        msg.contains("not a mesh format crokf recognises")
            && msg.contains(&format!("meshio convert {} out.vtu", p_of_any(&e))),
        "{msg}"
    );
    // A truncated legacy VTK file is recognised as VTK and refused by the VTK reader.
    let (_, e, msg) = err_of("cube.vtk", b"# vtk DataFile Version 3.0\ncube\nASCII\n");
    assert!(matches!(e, MeshError::Vtk { .. }), "{msg}");
    assert!(msg.contains("legacy VTK"), "{msg}");
    let (_, _, msg) = err_of("empty.msh", b"");
    assert!(msg.contains("not a mesh format crokf recognises"), "{msg}");
}

#[test]
fn tet10_elements_are_refused_with_type_and_count() {
    // 4.1 (mshio path): one tet10 element in place of the six tet4.
    let t = text("cube_41_ascii.msh");
    let start = t.find("3 1 4 6\n").unwrap();
    let end = t.find("$EndElements").unwrap();
    let tet10 = "3 1 11 2\n15 1 2 3 5 2 3 4 6 7 8\n16 2 4 3 6 1 2 3 4 5 6\n";
    let t41 = format!("{}{tet10}{}", &t[..start], &t[end..]).replace("6 20 1 20", "6 16 1 16");
    let (_, e, msg) = err_of("tet10_41.msh", t41.as_bytes());
    assert!(matches!(e, MeshError::UnsupportedElements { .. }), "{msg}");
    assert!(msg.contains("2 element(s) of type 11 (tet10"), "{msg}");
    assert!(msg.contains("-order 1"), "{msg}");
    // 2.2 (own reader): a hexahedron and a tet10.
    let t = text("cube_22_ascii.msh")
        .replace("32\n1 15", "34\n1 15")
        .replace(
            "$EndElements",
            "33 5 2 1 1 1 2 3 4 5 6 7 8\n34 11 2 1 1 1 2 3 5 2 3 4 6 7 8\n$EndElements",
        );
    let (_, _, msg) = err_of("tet10_22.msh", t.as_bytes());
    assert!(msg.contains("1 element(s) of type 5 (hex8"), "{msg}");
    assert!(msg.contains("1 element(s) of type 11 (tet10"), "{msg}");
}

#[test]
fn unknown_node_names_element_and_node() {
    let t = text("cube_22_ascii.msh").replace("27 4 2 1 1 1 2 4 8", "27 4 2 1 1 1 2 4 99");
    let (_, e, msg) = err_of("unknown_node_22.msh", t.as_bytes());
    assert!(matches!(e, MeshError::UnknownNode { .. }), "{msg}");
    assert!(msg.contains("element 27 references node 99"), "{msg}");
    let t = text("cube_41_ascii.msh").replace("15 1 2 4 8", "15 1 2 4 99");
    let (_, _, msg) = err_of("unknown_node_41.msh", t.as_bytes());
    assert!(msg.contains("element 15 references node 99"), "{msg}");
}

#[test]
fn syntax_errors_name_the_line() {
    let t = text("cube_22_ascii.msh").replace("6 1 0 1", "6 1 zero 1");
    let (_, e, msg) = err_of("bad_coordinate_22.msh", t.as_bytes());
    assert!(matches!(e, MeshError::Syntax { .. }), "{msg}");
    let line = 1 + t.lines().position(|l| l == "6 1 zero 1").unwrap();
    assert!(
        msg.contains(&format!("line {line}")) && msg.contains("\"zero\""),
        "{msg}"
    );
    let t = text("cube_41_ascii.msh").replace("1 0 1\n", "1 zero 1\n");
    let (_, _, msg) = err_of("bad_coordinate_41.msh", t.as_bytes());
    assert!(msg.contains("line ") && msg.contains("node"), "{msg}");
}

#[test]
fn truncated_files_are_errors_not_panics() {
    for name in [
        "cube_41_ascii.msh",
        "cube_41_binary.msh",
        "cube_22_ascii.msh",
        "cube_41_reversed_binary.msh",
    ] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let path = Path::new(name);
        // Every cut short of the final newline loses part of `$EndElements` or more.
        for len in 0..bytes.len() - 1 {
            let r = read_mesh_bytes(&bytes[..len], path);
            let e = r
                .err()
                .unwrap_or_else(|| panic!("{name} cut at {len} was accepted"));
            assert!(e.to_string().contains(name), "{e}");
        }
        assert!(read_mesh_bytes(&bytes[..bytes.len() - 1], path).is_ok());
    }
}

#[test]
fn inputs_that_panic_inside_mshio_are_errors() {
    // mshio 0.4 computes `num_elements - 1` on u64: an empty element section with nonzero
    // tags overflows (a panic in debug builds). The reader must turn that into an error.
    let t = text("cube_41_ascii.msh");
    let start = t.find("$Elements").unwrap();
    let bad = format!("{}$Elements\n0 0 1 1\n$EndElements\n", &t[..start]);
    let r = std::panic::catch_unwind(|| {
        read_mesh_bytes(bad.as_bytes(), Path::new("empty_elements.msh"))
    });
    let e = r.expect("no panic may reach the caller").unwrap_err();
    assert!(matches!(e, MeshError::NoTetrahedra { .. }), "{e}");
    assert!(e.to_string().contains("empty_elements.msh"), "{e}");
    // Nodes only, no elements at all: no tetrahedra.
    let nodes_only = &t[..start];
    let e = read_mesh_bytes(nodes_only.as_bytes(), Path::new("nodes_only.msh")).unwrap_err();
    assert!(matches!(e, MeshError::NoTetrahedra { .. }), "{e}");
}
