//! Bad inputs that used to get a misleading answer, each now a clear one:
//! VTU files cut short (at 97 % of their length, or inside a closing tag) in the ASCII, inline
//! base64, zlib and raw appended encodings; a VTU file that is not UTF-8 outside its raw
//! appended data; a non-finite coordinate in a legacy VTK file (named by point, coordinate
//! and line, however the writer spelt it); a node list that names a node twice (accepted with
//! a note); a co-rotational snapshot interval or order the training cannot give.
//!
//! The VTU files are written here from `models/cantilever/cantilever.msh` (the mesh's
//! tetrahedra, 0-based point ids, `MaterialIds` = 1 on every cell).

#[path = "support/base64.rs"]
mod base64_support;
use base64_support::base64;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use crokf_compile::mesh::{read_mesh, read_mesh_bytes, Mesh};
use crokf_compile::scene::Scene;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace")
        .to_owned()
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn case_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("misleading_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    dir
}

fn read_err(bytes: &[u8], name: &str) -> String {
    match read_mesh_bytes(bytes, Path::new(name)) {
        Ok(m) => panic!("{name}: accepted ({} tetrahedra)", m.tetrahedra.len()),
        Err(e) => e.to_string(),
    }
}

fn cantilever() -> Mesh {
    read_mesh(&repo().join("models/cantilever/cantilever.msh")).expect("cantilever mesh")
}

// ---------------------------------------------------------------------------------------------
// VTU files written from the cantilever

#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    Ascii,
    /// Inline base64, uncompressed: base64(header + data) as one stream.
    Base64,
    /// Inline base64, zlib: base64([1, n, n, nc]) + base64(zlib stream).
    Zlib,
    /// Raw appended data, uncompressed.
    AppendedRaw,
}

const ENCODINGS: [Encoding; 4] = [
    Encoding::Ascii,
    Encoding::Base64,
    Encoding::Zlib,
    Encoding::AppendedRaw,
];

fn zlib(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(data).expect("compress");
    e.finish().expect("compress")
}

/// One data array: section, name, VTK type, components, ASCII values, little-endian bytes.
struct Array {
    section: &'static str,
    name: &'static str,
    vtk_type: &'static str,
    components: usize,
    ascii: Vec<String>,
    bytes: Vec<u8>,
}

fn arrays(mesh: &Mesh) -> Vec<Array> {
    let points: Vec<f64> = mesh.nodes.iter().flatten().copied().collect();
    let connectivity: Vec<i64> = mesh
        .tetrahedra
        .iter()
        .flat_map(|t| t.nodes.map(|n| n as i64))
        .collect();
    let cells = mesh.tetrahedra.len();
    let offsets: Vec<i64> = (1..=cells as i64).map(|k| 4 * k).collect();
    let ints = |name, vtk_type, section, v: &[i64]| Array {
        section,
        name,
        vtk_type,
        components: 1,
        ascii: v.iter().map(i64::to_string).collect(),
        bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect(),
    };
    vec![
        Array {
            section: "Points",
            name: "Points",
            vtk_type: "Float64",
            components: 3,
            ascii: points.iter().map(f64::to_string).collect(),
            bytes: points.iter().flat_map(|x| x.to_le_bytes()).collect(),
        },
        ints("connectivity", "Int64", "Cells", &connectivity),
        ints("offsets", "Int64", "Cells", &offsets),
        Array {
            section: "Cells",
            name: "types",
            vtk_type: "UInt8",
            components: 1,
            ascii: vec!["10".into(); cells],
            bytes: vec![10; cells],
        },
        Array {
            section: "CellData",
            name: "MaterialIds",
            vtk_type: "Int32",
            components: 1,
            ascii: vec!["1".into(); cells],
            bytes: (0..cells).flat_map(|_| 1i32.to_le_bytes()).collect(),
        },
    ]
}

/// The mesh as a VTU file in `encoding`, laid out as VTK writes it.
fn vtu(mesh: &Mesh, encoding: Encoding) -> Vec<u8> {
    let mut appended: Vec<u8> = Vec::new();
    let mut sections: Vec<(&str, String)> = Vec::new();
    for a in arrays(mesh) {
        let head = format!(
            "        <DataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\"",
            a.vtk_type, a.name, a.components
        );
        let n = a.bytes.len() as u32;
        let element = match encoding {
            Encoding::Ascii => {
                let lines: Vec<String> = a
                    .ascii
                    .chunks(6)
                    .map(|c| format!("          {}\n", c.join(" ")))
                    .collect();
                format!(
                    "{head} format=\"ascii\">\n{}        </DataArray>\n",
                    lines.concat()
                )
            }
            Encoding::Base64 => {
                let mut all = n.to_le_bytes().to_vec();
                all.extend(&a.bytes);
                format!(
                    "{head} format=\"binary\">\n          {}\n        </DataArray>\n",
                    base64(&all)
                )
            }
            Encoding::Zlib => {
                let z = zlib(&a.bytes);
                let header: Vec<u8> = [1, n, n, z.len() as u32]
                    .iter()
                    .flat_map(|v| v.to_le_bytes())
                    .collect();
                format!(
                    "{head} format=\"binary\">\n          {}{}\n        </DataArray>\n",
                    base64(&header),
                    base64(&z)
                )
            }
            Encoding::AppendedRaw => {
                let offset = appended.len();
                appended.extend(n.to_le_bytes());
                appended.extend(&a.bytes);
                format!("{head} format=\"appended\" offset=\"{offset}\"/>\n")
            }
        };
        match sections.iter_mut().find(|(s, _)| *s == a.section) {
            Some((_, body)) => body.push_str(&element),
            None => sections.push((a.section, element)),
        }
    }
    let compressor = if encoding == Encoding::Zlib {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"UInt32\"{compressor}>\n  <UnstructuredGrid>\n    \
         <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n",
        mesh.nodes.len(),
        mesh.tetrahedra.len()
    );
    for (section, body) in sections {
        out.push_str(&format!("      <{section}>\n{body}      </{section}>\n"));
    }
    out.push_str("    </Piece>\n  </UnstructuredGrid>\n");
    let mut bytes = out.into_bytes();
    if encoding == Encoding::AppendedRaw {
        bytes.extend(b"  <AppendedData encoding=\"raw\">\n   _");
        bytes.extend(&appended);
        bytes.extend(b"\n  </AppendedData>\n");
    }
    bytes.extend(b"</VTKFile>\n");
    bytes
}

fn name_of(encoding: Encoding) -> String {
    format!("{encoding:?}").to_lowercase()
}

#[test]
fn well_formed_vtu_files_read_like_the_msh_file() {
    let mesh = cantilever();
    for encoding in ENCODINGS {
        let name = format!("beam_{}.vtu", name_of(encoding));
        let m = read_mesh_bytes(&vtu(&mesh, encoding), Path::new(&name))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.nodes, mesh.nodes, "{name}");
        let tets: Vec<[usize; 4]> = m.tetrahedra.iter().map(|t| t.nodes).collect();
        let want: Vec<[usize; 4]> = mesh.tetrahedra.iter().map(|t| t.nodes).collect();
        assert_eq!(tets, want, "{name}");
        let group = m.group("MaterialIds:1").expect("MaterialIds:1");
        assert_eq!(group.elements.len(), mesh.tetrahedra.len(), "{name}");
    }
}

#[test]
fn a_vtu_file_cut_at_97_percent_is_refused_naming_what_is_missing() {
    let mesh = cantilever();
    for encoding in ENCODINGS {
        let full = vtu(&mesh, encoding);
        let cut = &full[..full.len() * 97 / 100];
        let name = format!("cut_{}.vtu", name_of(encoding));
        let msg = read_err(cut, &name);
        assert!(
            msg.contains(&name) && msg.contains("cut short"),
            "{encoding:?}: {msg}"
        );
        if encoding == Encoding::AppendedRaw {
            // The cut falls in the appended data: its closing tag is missing, and the array
            // that runs past the end is named.
            assert!(
                msg.contains("ends inside <AppendedData>")
                    && msg.contains("</AppendedData>")
                    && msg.contains("DataArray 'MaterialIds'"),
                "{msg}"
            );
        } else {
            // The cut falls in an array (the last one, uncompressed).
            let array = if encoding == Encoding::Zlib {
                "ends inside DataArray '"
            } else {
                "ends inside DataArray 'MaterialIds'"
            };
            assert!(
                msg.contains(array) && msg.contains("</DataArray>") && msg.contains("</VTKFile>"),
                "{encoding:?}: {msg}"
            );
        }
        if encoding == Encoding::Ascii {
            let have = msg
                .split("has ")
                .nth(1)
                .and_then(|s| s.split(' ').next())
                .and_then(|s| s.parse::<usize>().ok())
                .unwrap_or_else(|| panic!("no count in {msg}"));
            assert!(
                have < mesh.tetrahedra.len()
                    && msg.contains(&format!(
                        "has {have} of its {} values",
                        mesh.tetrahedra.len()
                    )),
                "{msg}"
            );
        }
    }
}

#[test]
fn a_vtu_file_cut_inside_a_closing_tag_is_refused_naming_the_tag() {
    let mesh = cantilever();
    for encoding in ENCODINGS {
        let full = vtu(&mesh, encoding);
        let mut tags = vec!["</Piece>", "</UnstructuredGrid>", "</VTKFile>"];
        tags.push(if encoding == Encoding::AppendedRaw {
            "</AppendedData>"
        } else {
            "</DataArray>"
        });
        for tag in tags {
            let at = full
                .windows(tag.len())
                .rposition(|w| w == tag.as_bytes())
                .expect("tag");
            for keep in [0, 2, tag.len() - 1] {
                let cut = &full[..at + keep];
                let name = format!("cut_{}.vtu", name_of(encoding));
                let msg = read_err(cut, &name);
                assert!(
                    msg.contains(&name) && msg.contains("cut short") && msg.contains(tag),
                    "{encoding:?}, {tag} cut after {keep}: {msg}"
                );
                if tag == "</VTKFile>" {
                    assert!(msg.contains("ends inside <VTKFile>"), "{msg}");
                }
            }
        }
        // A trailing newline or comment after the last tag is still fine.
        let mut more = full.clone();
        more.extend(b"<!-- written by hand -->\n\n");
        read_mesh_bytes(&more, Path::new("more.vtu")).expect("a comment after </VTKFile>");
    }
}

/// `bytes` with `insert` after its second line (the `<VTKFile ...>` tag).
fn after_root_tag(bytes: &[u8], insert: &[u8]) -> (Vec<u8>, usize) {
    let first = bytes.iter().position(|&b| b == b'\n').expect("line 1");
    let at = first
        + 1
        + bytes[first + 1..]
            .iter()
            .position(|&b| b == b'\n')
            .expect("line 2")
        + 1;
    let mut out = bytes[..at].to_vec();
    out.extend(insert);
    out.extend(&bytes[at..]);
    (out, at)
}

#[test]
fn a_vtu_file_that_is_not_utf8_is_refused_naming_the_byte() {
    let mesh = cantilever();
    // A comment in Latin-1 ("Fichier créé", é = 0xE9: not UTF-8): read as if it were text.
    let comment = b"<!-- Fichier cr\xE9\xE9 par un script -->\n";
    for encoding in ENCODINGS {
        let (bytes, at) = after_root_tag(&vtu(&mesh, encoding), comment);
        let bad = at + 15;
        assert_eq!(bytes[bad], 0xE9);
        let name = format!("latin1_{}.vtu", name_of(encoding));
        let msg = read_err(&bytes, &name);
        assert!(
            msg.contains(&name)
                && msg.contains("not UTF-8")
                && msg.contains(&format!("byte {bad} "))
                && msg.contains("line 3")
                && msg.contains("0xE9"),
            "{encoding:?}: {msg}"
        );
        // The offset and the line count in the file, byte-order mark and blank lines first.
        let mut prefixed = b"\xEF\xBB\xBF\n\n".to_vec();
        prefixed.extend(&bytes);
        let msg = read_err(&prefixed, &name);
        assert!(
            msg.contains(&format!("byte {} ", bad + 5)) && msg.contains("line 5"),
            "{msg}"
        );
    }
    // A Latin-1 array name, with the encoding declared: refused the same way, saying so.
    let text = vtu(&mesh, Encoding::Ascii);
    let mut bytes = text.replacen_bytes(
        b"<?xml version=\"1.0\"?>",
        b"<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?>",
    );
    let at = bytes
        .windows(b"Name=\"MaterialIds\"".len())
        .position(|w| w == b"Name=\"MaterialIds\"")
        .expect("name")
        + 9;
    bytes[at] = 0xE9;
    let msg = read_err(&bytes, "declared.vtu");
    assert!(
        msg.contains(&format!("byte {at} "))
            && msg.contains("encoding=\"ISO-8859-1\"")
            && msg.contains("iconv"),
        "{msg}"
    );
    // Raw appended data is binary: the file is read (its XML part is UTF-8).
    let bytes = vtu(&mesh, Encoding::AppendedRaw);
    assert!(
        std::str::from_utf8(&bytes).is_err(),
        "the raw data is UTF-8"
    );
    read_mesh_bytes(&bytes, Path::new("raw.vtu")).expect("raw appended data");
    // ... but not a stray byte after it.
    let mut bad = bytes.clone();
    bad.truncate(bad.len() - "</VTKFile>\n".len());
    bad.extend(b"<!-- \xFF -->\n</VTKFile>\n");
    let at = bad.iter().rposition(|&b| b == 0xFF).expect("0xFF");
    let msg = read_err(&bad, "raw.vtu");
    assert!(
        msg.contains("raw.vtu") && msg.contains(&format!("byte {at} ")),
        "{msg}"
    );
}

trait ReplaceBytes {
    fn replacen_bytes(&self, from: &[u8], to: &[u8]) -> Vec<u8>;
}

impl ReplaceBytes for Vec<u8> {
    fn replacen_bytes(&self, from: &[u8], to: &[u8]) -> Vec<u8> {
        let at = self
            .windows(from.len())
            .position(|w| w == from)
            .expect("pattern");
        let mut out = self[..at].to_vec();
        out.extend(to);
        out.extend(&self[at + from.len()..]);
        out
    }
}

// ---------------------------------------------------------------------------------------------
// Legacy VTK: a non-finite coordinate, however the writer spelt it

#[test]
fn a_non_finite_legacy_vtk_coordinate_names_the_point_the_coordinate_and_the_line() {
    let text = std::fs::read_to_string(fixture("cube_ascii.vtk")).expect("fixture");
    let line6 = text.lines().nth(5).expect("points line");
    // Point 3 is tokens 9, 10, 11: its y coordinate is token 10.
    for spelling in [
        "nan",
        "NaN",
        "-nan",
        "inf",
        "-Infinity",
        "nan(ind)",
        "-nan(ind)",
        "1.#QNAN",
        "-1.#IND",
        "1.#INF",
        "NAN",
    ] {
        let mut tokens: Vec<&str> = line6.split_ascii_whitespace().collect();
        tokens[10] = spelling;
        let bad = text.replacen(line6, &tokens.join(" "), 1);
        let msg = read_err(bad.as_bytes(), "nan.vtk");
        assert!(
            msg.contains("nan.vtk")
                && msg.contains("line 6")
                && msg.contains("point 3")
                && msg.contains("y coordinate")
                && msg.contains("finite"),
            "{spelling}: {msg}"
        );
    }
    // Binary: the point and the coordinate (binary files have no lines).
    let bytes = std::fs::read(fixture("cube_binary.vtk")).expect("fixture");
    let at = bytes
        .windows(7)
        .position(|w| w == b"POINTS ")
        .expect("POINTS");
    let data = at + bytes[at..].iter().position(|&b| b == b'\n').expect("eol") + 1;
    let mut bad = bytes.clone();
    // Point 3, z: the 12th coordinate (big-endian doubles or floats).
    let header = String::from_utf8_lossy(&bytes[at..data]).into_owned();
    let width = if header.contains("float") { 4 } else { 8 };
    let z = data + 11 * width;
    if width == 8 {
        bad[z..z + 8].copy_from_slice(&f64::NAN.to_be_bytes());
    } else {
        bad[z..z + 4].copy_from_slice(&f32::NAN.to_be_bytes());
    }
    let msg = read_err(&bad, "nan_binary.vtk");
    assert!(
        msg.contains("nan_binary.vtk")
            && msg.contains("point 3")
            && msg.contains("z coordinate")
            && msg.contains(&format!("at byte {z} "))
            && msg.contains("finite"),
        "{msg}"
    );
}

// ---------------------------------------------------------------------------------------------
// A node list that names a node twice: used once, with a note

/// Runs `crokf-compile` on `scene`, writing the model next to it: (exit code, stdout, stderr).
fn compile(scene: &Path) -> (Option<i32>, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg(scene)
        .arg("-o")
        .arg(scene.with_file_name("model.crokf"))
        .output()
        .expect("run crokf-compile");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_node_list_naming_a_node_twice_is_used_once_with_a_note() {
    let dir = case_dir("node_list_twice");
    std::fs::copy(fixture("cube_41_ascii.msh"), dir.join("cube.msh")).expect("mesh");
    let scene = |list: &str| {
        format!(
            "[mesh]\nfile = \"cube.msh\"\n[[material]]\ngroup = \"body\"\n\
             young_modulus = 1.0e6\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\n\
             select = [{{ node_list = \"{list}\" }}]\n[[load]]\nname = \"push\"\n\
             select = [{{ box = {{ min = [-1, -1, 0.99], max = [2, 2, 1.01] }}, nodes = \"all\" }}]\n\
             force_model = \"white\"\n[[sensor]]\nname = \"top\"\nposition = [1, 1, 1]\n\
             components = [\"x\", \"y\", \"z\"]\nnoise_std = 1.0e-3\n[time]\ndt = 0.01\n"
        )
    };
    // The bottom face (tags 1 to 4), as an export that repeats shared nodes writes it.
    std::fs::write(dir.join("base.txt"), "1 2\n3 # third\n4, 2\n2 3 3\n").expect("list");
    std::fs::write(dir.join("once.txt"), "1 2\n3 # third\n4\n").expect("list");
    std::fs::write(dir.join("twice.toml"), scene("base.txt")).expect("scene");
    std::fs::write(dir.join("once.toml"), scene("once.txt")).expect("scene");
    let (code, out, err) = compile(&dir.join("twice.toml"));
    assert_eq!(code, Some(0), "{err}");
    let note = err
        .lines()
        .find(|l| l.contains("fixed 1: selection took"))
        .unwrap_or_else(|| panic!("no selection note in {err}"));
    assert!(
        note.contains("selection took 4 nodes")
            && note.contains("warning")
            && note.contains("base.txt")
            && note.contains("lists 2 nodes more than once")
            && note.contains("node 2 (3 times: lines 1, 3 and 4)")
            && note.contains("node 3 (3 times: lines 2 and 4)")
            && note.contains("4 duplicate entries ignored"),
        "{note}"
    );
    // The same model as the list without repeats: the 4 bottom nodes fixed, 12 free DOFs.
    let mesh_line = |text: &str| {
        text.lines()
            .find(|l| l.starts_with("mesh:"))
            .unwrap_or("")
            .to_owned()
    };
    let twice = mesh_line(&format!("{out}{err}"));
    assert!(twice.contains("12 free DOFs"), "{out}{err}");
    let (code, out, err) = compile(&dir.join("once.toml"));
    assert_eq!(code, Some(0), "{err}");
    assert!(!err.contains("more than once"), "{err}");
    assert_eq!(mesh_line(&format!("{out}{err}")), twice);
}

// ---------------------------------------------------------------------------------------------
// Co-rotational training: a snapshot interval or an order the snapshots cannot give

/// A co-rotational scene with one load group trained along the default 10 directions × 2
/// histories (20 runs) of 1 s at Δt = 5 ms (200 steps each), and `extra` in its table.
fn tier_scene(extra: &str) -> String {
    format!(
        "[mesh]\nfile = \"m.msh\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = 1e6\n\
         poisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\ngroup = \"clamp\"\n[[load]]\n\
         name = \"tip\"\ngroup = \"tip\"\nrange = 20.0\n[time]\ndt = 0.005\n[reduction]\n\
         model = \"corotational\"\n[reduction.corotational]\nduration = 1.0\n{extra}\n"
    )
}

fn tier_err(extra: &str) -> String {
    match Scene::parse(&tier_scene(extra), Path::new("tier.toml")) {
        Ok(_) => panic!("accepted: {extra}"),
        Err(e) => e.to_string(),
    }
}

fn tier_ok(extra: &str) {
    if let Err(e) = Scene::parse(&tier_scene(extra), Path::new("tier.toml")) {
        panic!("{extra}: {e}");
    }
}

#[test]
fn a_snapshot_interval_longer_than_the_runs_is_refused() {
    let msg = tier_err("every = 1000000");
    assert!(
        msg.contains("tier.toml")
            && msg.contains("reduction.corotational.every = 1000000")
            && msg.contains("keeps 1 snapshot per training run")
            && msg.contains("1 s / 0.005 s = 200 steps")
            && msg.contains("20 snapshots in all from 20 runs")
            && msg.contains("use every < 200")
            && msg.contains("every = 5 keeps 40 per run, 800 in all"),
        "{msg}"
    );
    // every = N keeps the last step only; every = N − 1 keeps two per run.
    assert!(tier_err("every = 200").contains("keeps 1 snapshot per training run"));
    tier_ok("every = 199");
    tier_ok("every = 1");
    // The count is the training's own (TrainingPlan::snapshot_count).
    for every in [1usize, 3, 7, 199] {
        let scene = Scene::parse(
            &tier_scene(&format!("every = {every}")),
            Path::new("t.toml"),
        )
        .expect("scene");
        let spec = scene.reduction.corotational.as_ref().expect("table");
        let plan =
            crokf_compile::nonlinear::training::TrainingPlan::from_scene(spec, &["tip".to_owned()]);
        assert_eq!(plan.runs().len(), 20);
        assert_eq!(
            plan.snapshot_count(0.005),
            200usize.div_ceil(every),
            "{every}"
        );
    }
}

#[test]
fn an_order_above_the_snapshot_count_is_refused_and_an_exact_one_accepted() {
    // every = 100: 2 snapshots per run, 40 in all.
    let msg = tier_err("every = 100\norder = 41");
    assert!(
        msg.contains("reduction.corotational.order = 41")
            && msg.contains("20 runs × 2 snapshots per run = 40")
            && msg.contains("use order ≤ 40")
            && msg.contains("every = 99 keeps 3 per run, 60 in all"),
        "{msg}"
    );
    tier_ok("every = 100\norder = 40");
    tier_ok("every = 99\norder = 41");
    // More vectors than any interval gives: lengthen the runs.
    // (One run of 100 steps: directions [0, 1, 0], the step history only, 0.5 s.)
    let one_run = "ramp_multiple = 0\ndirections = [[0, 1, 0]]";
    let short = |extra: &str| tier_scene(extra).replace("duration = 1.0", "duration = 0.5");
    let msg = Scene::parse(
        &short(&format!("every = 5\norder = 150\n{one_run}")),
        Path::new("s.toml"),
    )
    .expect_err("order 150 of 100 snapshots")
    .to_string();
    assert!(
        msg.contains("1 run × 20 snapshots per run = 20")
            && msg.contains("even every = 1 keeps only 100 per run, 100 in all")
            && !msg.contains("keep more snapshots"),
        "{msg}"
    );
    // With basis_tolerance, `order` is the pooled POD size that comes first: the same bound,
    // and the default order when only the tolerance is stated.
    let axes = "every = 100\nramp_multiple = 0\ndirections = \"axes\"";
    let msg = tier_err(&format!("{axes}\nbasis_tolerance = 1e-2\norder = 13"));
    assert!(
        msg.contains("order = 13")
            && msg.contains("6 runs × 2 snapshots per run = 12")
            && msg.contains("basis_tolerance"),
        "{msg}"
    );
    tier_ok(&format!("{axes}\nbasis_tolerance = 1e-2\norder = 12"));
    tier_ok(&format!(
        "{axes}\nbasis_tolerance = 1e-2\norder = 12\nmax_order = 60"
    ));
    let msg = tier_err(&format!("{axes}\nbasis_tolerance = 1e-2"));
    assert!(
        msg.contains("not stated: the default 20") && msg.contains("use order ≤ 12"),
        "{msg}"
    );
    // Without a stated size the fidelity rule chooses from the snapshots there are.
    tier_ok(axes);
}

/// Every committed scene still passes the checks.
#[test]
fn committed_scenes_still_parse() {
    let mut scenes = Vec::new();
    let mut dirs = vec![repo().join("models")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("models").flatten() {
            let path = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if path.is_dir() {
                dirs.push(path);
            } else if name.starts_with("scene") && name.ends_with(".toml") {
                scenes.push(path);
            }
        }
    }
    assert!(scenes.len() >= 20, "{scenes:?}");
    for path in scenes {
        let text = std::fs::read_to_string(&path).expect("scene");
        if let Err(e) = Scene::parse(&text, &path) {
            panic!("{e}");
        }
    }
}
