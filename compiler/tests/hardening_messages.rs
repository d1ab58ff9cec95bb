//! Messages of the mesh and scene readers that name what is wrong: a node beyond the coordinate
//! limit, a legacy VTK coordinate that is not a number or is missing (line and point), a
//! `[[fixed]]` entry that fixes nothing, a node-list tag listed twice, and `--help` naming the
//! formats read.

use std::path::Path;
use std::process::Command;

use crokf_compile::mesh::read_mesh_bytes;

#[path = "support/hardening.rs"]
mod support;
use support::{case_dir, compile, fixture, scene_for};

fn read_err(bytes: &[u8], name: &str) -> String {
    match read_mesh_bytes(bytes, Path::new(name)) {
        Ok(m) => panic!("{name}: accepted ({} tetrahedra)", m.tetrahedra.len()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_node_beyond_the_coordinate_limit_is_named() {
    let text = std::fs::read_to_string(fixture("cube_ascii.vtu")).expect("fixture");
    let at = "NumberOfComponents=\"3\" format=\"ascii\">\n0.00000000000e+00\n0.00000000000e+00\n";
    let bad = text.replacen(
        at,
        "NumberOfComponents=\"3\" format=\"ascii\">\n0.00000000000e+00\n1e300\n",
        1,
    );
    assert_ne!(bad, text);
    let msg = read_err(bad.as_bytes(), "far.vtu");
    assert!(
        msg.contains("far.vtu")
            && msg.contains("node 0 has a coordinate out of range")
            && msg.contains("1e9"),
        "{msg}"
    );
    // The same in gmsh format, and the limit itself is accepted.
    let msh = std::fs::read_to_string(fixture("cube_22_ascii.msh")).expect("fixture");
    assert!(msh.contains("\n5 0 0 1\n"));
    let msg = read_err(
        msh.replacen("\n5 0 0 1\n", "\n5 0 -2e9 1\n", 1).as_bytes(),
        "far.msh",
    );
    assert!(
        msg.contains("node 5 has a coordinate out of range"),
        "{msg}"
    );
    read_mesh_bytes(
        msh.replacen("\n5 0 0 1\n", "\n5 0 0 1e9\n", 1).as_bytes(),
        Path::new("edge.msh"),
    )
    .expect("|x| = 1e9 is within the limit");
}

#[test]
fn legacy_vtk_with_nan_or_truncated_points_names_line_and_point() {
    let text = std::fs::read_to_string(fixture("cube_ascii.vtk")).expect("fixture");
    let line6 = text.lines().nth(5).expect("points line");
    let mut tokens: Vec<&str> = line6.split_ascii_whitespace().collect();
    tokens[10] = "nan";
    let bad = text.replacen(line6, &tokens.join(" "), 1);
    let msg = read_err(bad.as_bytes(), "nan.vtk");
    assert!(
        msg.contains("nan.vtk")
            && msg.contains("line 6")
            && msg.contains("point 3")
            && msg.contains("y coordinate"),
        "{msg}"
    );
    assert!(!msg.contains("5.1") && !msg.contains("Digit"), "{msg}");
    // The last two points cut off.
    let tokens: Vec<&str> = line6.split_ascii_whitespace().collect();
    let cut = tokens[..18].join(" ");
    let bad = text.replacen(line6, &cut, 1);
    let msg = read_err(bad.as_bytes(), "cut.vtk");
    assert!(
        msg.contains("declares 8 points")
            && msg.contains("after 18 values")
            && msg.contains("point 6")
            && msg.contains("line 7"),
        "{msg}"
    );
    assert!(!msg.contains("5.1"), "{msg}");
    // Truncated inside the points at the end of the file.
    let end = text.find(line6).expect("line") + 30;
    let msg = read_err(&text.as_bytes()[..end], "end.vtk");
    assert!(msg.contains("file ends after"), "{msg}");
}

#[test]
fn fixed_with_no_components_is_refused_naming_the_group() {
    let text = "[mesh]\nfile = \"cube.msh\"\n[[material]]\ngroup = \"body\"\n\
        young_modulus = 1.0e6\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\n\
        group = \"bottom\"\ncomponents = []\n[time]\ndt = 0.01\n";
    let e = crokf_compile::scene::Scene::parse(text, Path::new("s.toml"))
        .expect_err("components = [] accepted")
        .to_string();
    assert!(
        e.contains("s.toml") && e.contains("fixed 'bottom'") && e.contains("components = []"),
        "{e}"
    );
}

#[test]
fn a_node_list_tag_listed_twice_is_used_once_with_a_warning() {
    let dir = case_dir("duplicate_tags");
    let scene = scene_for(&dir, "cube.msh");
    let text = std::fs::read_to_string(&scene).expect("scene").replace(
        "select = [{ box = { min = [-1, -1, -0.01], max = [2, 2, 0.01] }, nodes = \"all\" }]",
        "select = [{ node_list = \"base.txt\" }]",
    );
    std::fs::write(&scene, text).expect("scene");
    std::fs::write(dir.join("base.txt"), "1 2\n3 # third\n4, 2\n").expect("list");
    // The fixture's scene has no mode its inputs and outputs see, so it stops at the matrices;
    // the warning's wording is asserted in tests/misleading_inputs.rs on a full compile.
    let (code, err) = compile(&[&scene, &"--export-matrices", &dir]);
    assert_eq!(code, Some(0), "{err}");
    assert!(dir.join("dofs.csv").is_file(), "{err}");
}

#[test]
fn help_names_the_formats_read() {
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg("--help")
        .output()
        .expect("run");
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(
        help.contains(".vtu") && help.contains(".vtk") && help.contains(".msh"),
        "{help}"
    );
    assert!(!help.contains("gmsh mesh into"), "{help}");
}
