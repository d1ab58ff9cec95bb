//! VTU (ASCII, zlib-compressed base64, raw appended), legacy VTK (ASCII, binary) and MSH 1.0
//! readers against the MSH 4.1 fixture cube; integer cell-data arrays as groups; format-level
//! messages (non-finite coordinates, unsupported VTK cells, byte-order mark, orphan nodes).
//!
//! Fixtures (`tests/fixtures/cube_*.vtu`, `.vtk`, `cube_10.msh`, from
//! `scripts/gen_vtk_fixtures.py`, written by meshio, gmsh and a hand-written appended-data
//! writer): the unit cube split into 6 Kuhn tetrahedra (volume 1/6 each) and the 2 bottom
//! triangles; VTK point id k sits where gmsh node tag k + 1 does. Cell data `MaterialIds`:
//! tetrahedra 0–2 → 1, 3–5 → 2, triangles → 7.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crokf_compile::mesh::{read_mesh, read_mesh_bytes, Mesh, MeshError};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn read(name: &str) -> Mesh {
    read_mesh(&fixture(name)).unwrap_or_else(|e| panic!("{e}"))
}

/// Tetrahedra as sets of corner coordinates, so meshes with different numberings compare.
fn tet_corners(m: &Mesh) -> BTreeSet<Vec<[i64; 3]>> {
    m.tetrahedra
        .iter()
        .map(|t| {
            let mut c: Vec<[i64; 3]> = t
                .nodes
                .iter()
                .map(|&n| m.nodes[n].map(|v| (v * 1e6).round() as i64))
                .collect();
            c.sort_unstable();
            c
        })
        .collect()
}

fn total_volume(m: &Mesh) -> f64 {
    (0..m.tetrahedra.len()).map(|i| m.signed_volume(i)).sum()
}

#[test]
fn vtu_and_vtk_encodings_read_the_cube() {
    let reference = read("cube_41_ascii.msh");
    for name in [
        "cube_ascii.vtu",
        "cube_zlib.vtu",
        "cube_appended.vtu",
        "cube_ascii.vtk",
        "cube_binary.vtk",
    ] {
        let m = read(name);
        assert_eq!(m.nodes.len(), 8, "{name}");
        assert_eq!(m.tetrahedra.len(), 6, "{name}");
        assert_eq!(m.triangles.len(), 2, "{name}");
        // Node tags are the 0-based point ids; point k sits where gmsh tag k + 1 does.
        for (k, (&tag, p)) in m.node_tags.iter().zip(&m.nodes).enumerate() {
            assert_eq!(tag, k as u64, "{name}");
            let i = reference.node_tags.iter().position(|&t| t == tag + 1);
            assert_eq!(Some(*p), i.map(|i| reference.nodes[i]), "{name}: point {k}");
        }
        assert_eq!(tet_corners(&m), tet_corners(&reference), "{name}");
        for i in 0..6 {
            assert!(
                (m.signed_volume(i) - 1.0 / 6.0).abs() < 1e-15,
                "{name}: tet {i}"
            );
        }
        // Element tags are the 0-based cell ids.
        let tags: Vec<u64> = m.tetrahedra.iter().map(|t| t.tag).collect();
        assert_eq!(tags, vec![0, 1, 2, 3, 4, 5], "{name}");
        // Integer cell data: one volume group per value on tetrahedra, faces separately;
        // the Float64 "Quality" array is not a group.
        let g1 = m.group("MaterialIds:1").expect("MaterialIds:1");
        let g2 = m.group("MaterialIds:2").expect("MaterialIds:2");
        assert_eq!((g1.dim, g1.elements.clone()), (3, vec![0, 1, 2]), "{name}");
        assert_eq!((g2.dim, g2.elements.clone()), (3, vec![3, 4, 5]), "{name}");
        let faces = m.group("MaterialIds:7:faces").expect("faces group");
        assert_eq!((faces.dim, faces.elements.len()), (2, 2), "{name}");
        assert_eq!(faces.nodes, vec![0, 1, 2, 3], "{name}: bottom corners");
        assert!(
            m.groups.iter().all(|g| !g.name.starts_with("Quality")),
            "{name}"
        );
        assert_eq!(m.groups.len(), 3, "{name}: {:?}", m.group_names());
    }
}

#[test]
fn msh10_reads_like_msh41_with_unnamed_groups() {
    let reference = read("cube_41_ascii.msh");
    let m = read("cube_10.msh");
    assert_eq!(m.node_tags, reference.node_tags);
    assert_eq!(m.nodes, reference.nodes);
    assert_eq!(tet_corners(&m), tet_corners(&reference));
    assert!((total_volume(&m) - 1.0).abs() < 1e-14);
    // gmsh writes a triangle once per physical group; the copies are merged: 12 triangles.
    assert_eq!(m.triangles.len(), 12);
    // MSH 1.0 has no names: the physical groups are "dim:tag" with the 4.1 file's contents.
    for g in &reference.groups {
        let unnamed = format!("{}:{}", g.dim, g.tag);
        let h = m.group(&unnamed).unwrap_or_else(|| panic!("{unnamed}"));
        assert_eq!(h.nodes, g.nodes, "{unnamed}");
        assert_eq!(h.elements.len(), g.elements.len(), "{unnamed}");
    }
}

#[test]
fn byte_order_mark_is_accepted_in_every_format() {
    for name in [
        "cube_41_ascii.msh",
        "cube_22_ascii.msh",
        "cube_10.msh",
        "cube_ascii.vtu",
    ] {
        let mut bytes = b"\xEF\xBB\xBF".to_vec();
        bytes.extend(std::fs::read(fixture(name)).unwrap());
        let m = read_mesh_bytes(&bytes, Path::new(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(m.tetrahedra.len(), 6, "{name}");
    }
}

#[test]
fn non_finite_coordinates_are_named_as_such() {
    for (name, bad) in [
        ("cube_10.msh", ("5 0 0 1", "5 nan 0 1")),
        ("cube_22_ascii.msh", ("5 0 0 1", "5 0 inf 1")),
        (
            "cube_ascii.vtu",
            (
                "Name=\"Points\" NumberOfComponents=\"3\" format=\"ascii\">\n0.00000000000e+00",
                "Name=\"Points\" NumberOfComponents=\"3\" format=\"ascii\">\nNaN",
            ),
        ),
    ] {
        let text = std::fs::read_to_string(fixture(name)).unwrap();
        assert!(text.contains(bad.0), "{name}");
        let bytes = text.replacen(bad.0, bad.1, 1).into_bytes();
        let e = read_mesh_bytes(&bytes, Path::new(name)).expect_err("NaN accepted");
        let msg = e.to_string();
        assert!(
            matches!(e, MeshError::NonFiniteNode { .. }),
            "{name}: {msg}"
        );
        assert!(
            msg.contains("non-finite coordinate") && msg.contains(name),
            "{msg}"
        );
        let node = if name.ends_with(".vtu") {
            "node 0 "
        } else {
            "node 5 "
        };
        assert!(msg.contains(node), "{name}: {msg}");
    }
}

#[test]
fn unsupported_vtk_cells_are_counted_by_type() {
    // A hexahedron (VTK type 12) and a wedge (13).
    let text = "# vtk DataFile Version 4.2\nbad\nASCII\nDATASET UNSTRUCTURED_GRID\n\
        POINTS 8 double\n0 0 0 1 0 0 1 1 0 0 1 0 0 0 1 1 0 1 1 1 1 0 1 1\n\
        CELLS 2 16\n8 0 1 2 3 4 5 6 7\n6 0 1 2 4 5 6\nCELL_TYPES 2\n12\n13\n";
    let e = read_mesh_bytes(text.as_bytes(), Path::new("hex.vtk")).expect_err("hex accepted");
    let msg = e.to_string();
    assert!(
        msg.contains("1 cell(s) of type Hexahedron (12)")
            && msg.contains("1 cell(s) of type Wedge (13)")
            && msg.contains("VTK_TETRA"),
        "{msg}"
    );
    assert!(
        !msg.contains("meshio") && !msg.contains("`gmsh"),
        "no untested command: {msg}"
    );
}

#[test]
fn vtk_polydata_and_garbage_xml_are_refused_with_the_reason() {
    let poly = "# vtk DataFile Version 4.2\ntri\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n\
        0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";
    let msg = read_mesh_bytes(poly.as_bytes(), Path::new("tri.vtk"))
        .expect_err("poly data accepted")
        .to_string();
    assert!(
        msg.contains("poly data") && msg.contains("unstructured grid"),
        "{msg}"
    );
    let msg = read_mesh_bytes(
        b"<?xml version=\"1.0\"?>\n<VTKFile type=",
        Path::new("x.vtu"),
    )
    .expect_err("truncated XML accepted")
    .to_string();
    assert!(msg.contains("x.vtu") && msg.contains("VTK XML"), "{msg}");
}

#[test]
fn orphan_nodes_are_counted() {
    // Two extra nodes (tags 9 and 10) in the MSH 1.0 cube that no element uses.
    let text = std::fs::read_to_string(fixture("cube_10.msh")).unwrap();
    let text = text.replacen("$NOD\n8\n", "$NOD\n10\n", 1).replacen(
        "$ENDNOD",
        "9 5 5 5\n10 6 6 6\n$ENDNOD",
        1,
    );
    let m = read_mesh_bytes(text.as_bytes(), Path::new("orphans.msh")).unwrap();
    let orphans: Vec<u64> = m.orphan_nodes().iter().map(|&i| m.node_tags[i]).collect();
    assert_eq!(orphans, vec![9, 10]);
    // The extent counts nodes of tetrahedra only.
    assert_eq!(m.extent(), ([0.0; 3], [1.0; 3]));
    let notes = crokf_compile::fem::mesh_notes(&m, 1.0);
    assert!(
        notes
            .iter()
            .any(|n| n.contains("2 node(s) belong to no tetrahedron") && n.contains("9, 10")),
        "{notes:?}"
    );
}
