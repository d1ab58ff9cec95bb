//! Hostile VTU files: claimed sizes checked before any allocation (a zlib bomb is an error, not
//! an abort, in the library and in `crokf-compile`), and no dependency's panic text in a
//! message: malformed blocks are errors naming the file, the block and the `DataArray`.
//!
//! The VTU files are built here from the cube fixture (`tests/fixtures/cube_ascii.vtu`: 8
//! points, 6 tetrahedra, 2 triangles, `MaterialIds`) in the encodings VTK and meshio write:
//! inline base64 binary (header and data encoded as two chunks), uncompressed or zlib (stored
//! deflate blocks, written by hand), and raw appended data.

#[path = "support/base64.rs"]
mod base64_support;
use base64_support::base64;
use std::path::Path;

use crokf_compile::mesh::read_mesh_bytes;

#[path = "support/hardening.rs"]
mod support;
use support::{assert_no_panic_text, case_dir, compile, fixture, scene_for};

// ---------------------------------------------------------------------------------------------
// VTU files built from the cube fixture

/// A zlib stream of stored (uncompressed) deflate blocks.
fn zlib_stored(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0x78, 0x01];
    let chunks: Vec<&[u8]> = if data.is_empty() {
        vec![&[]]
    } else {
        data.chunks(65535).collect()
    };
    for (i, c) in chunks.iter().enumerate() {
        out.push(u8::from(i + 1 == chunks.len()));
        let len = c.len() as u16;
        out.extend(len.to_le_bytes());
        out.extend((!len).to_le_bytes());
        out.extend_from_slice(c);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in data {
        a = (a + u32::from(x)) % 65521;
        b = (b + a) % 65521;
    }
    out.extend(((b << 16) | a).to_be_bytes());
    out
}

/// One data array of the cube: section, name, VTK type, components, little-endian bytes.
struct Array {
    section: &'static str,
    name: &'static str,
    vtk_type: &'static str,
    components: u32,
    bytes: Vec<u8>,
}

/// The cube fixture's arrays, parsed from its ASCII VTU.
fn cube_arrays() -> Vec<Array> {
    let text = std::fs::read_to_string(fixture("cube_ascii.vtu")).expect("fixture");
    let values = |name: &str| -> Vec<&str> {
        let start = text.find(&format!("Name=\"{name}\"")).expect(name);
        let open = start + text[start..].find('>').expect(">") + 1;
        let close = open + text[open..].find("</DataArray>").expect("close");
        text[open..close].split_ascii_whitespace().collect()
    };
    let f64s = |name| -> Vec<u8> {
        values(name)
            .iter()
            .flat_map(|v| v.parse::<f64>().expect("f64").to_le_bytes())
            .collect()
    };
    let i64s = |name| -> Vec<u8> {
        values(name)
            .iter()
            .flat_map(|v| v.parse::<i64>().expect("i64").to_le_bytes())
            .collect()
    };
    let i32s = |name| -> Vec<u8> {
        values(name)
            .iter()
            .flat_map(|v| v.parse::<i32>().expect("i32").to_le_bytes())
            .collect()
    };
    vec![
        Array {
            section: "Points",
            name: "Points",
            vtk_type: "Float64",
            components: 3,
            bytes: f64s("Points"),
        },
        Array {
            section: "Cells",
            name: "connectivity",
            vtk_type: "Int64",
            components: 1,
            bytes: i64s("connectivity"),
        },
        Array {
            section: "Cells",
            name: "offsets",
            vtk_type: "Int64",
            components: 1,
            bytes: i64s("offsets"),
        },
        Array {
            section: "Cells",
            name: "types",
            vtk_type: "Int64",
            components: 1,
            bytes: i64s("types"),
        },
        Array {
            section: "CellData",
            name: "MaterialIds",
            vtk_type: "Int32",
            components: 1,
            bytes: i32s("MaterialIds"),
        },
    ]
}

#[derive(Clone, Copy, PartialEq)]
enum Layout {
    /// Inline base64, no compression: base64(header) + base64(data).
    Binary,
    /// Inline base64, zlib: base64([1, n, n, nc]) + base64(zlib stream).
    Zlib,
    /// Raw appended data, no compression.
    AppendedRaw,
}

/// The content of one array: (header integers, data bytes); `edit` may change both (and the
/// whole inline text through `text`).
type EditFn = dyn Fn(&str, &mut Vec<u64>, &mut Vec<u8>, &mut Option<String>);
type Edit<'a> = &'a EditFn;

fn vtu(layout: Layout, header64: bool, edit: Edit<'_>) -> Vec<u8> {
    let arrays = cube_arrays();
    let int = |v: u64| -> Vec<u8> {
        if header64 {
            v.to_le_bytes().to_vec()
        } else {
            (v as u32).to_le_bytes().to_vec()
        }
    };
    let mut appended: Vec<u8> = Vec::new();
    let mut sections: Vec<(&str, String)> = Vec::new();
    for a in &arrays {
        let (mut header, mut data) = match layout {
            Layout::Zlib => {
                let z = zlib_stored(&a.bytes);
                let n = a.bytes.len() as u64;
                (vec![1, n, n, z.len() as u64], z)
            }
            _ => (vec![a.bytes.len() as u64], a.bytes.clone()),
        };
        let mut text = None;
        edit(a.name, &mut header, &mut data, &mut text);
        let head: Vec<u8> = header.iter().flat_map(|&v| int(v)).collect();
        let element = match layout {
            Layout::AppendedRaw => {
                let offset = appended.len();
                appended.extend(&head);
                appended.extend(&data);
                format!(
                    "<DataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\" \
                     format=\"appended\" offset=\"{offset}\"/>\n",
                    a.vtk_type, a.name, a.components
                )
            }
            _ => format!(
                "<DataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"binary\">\n\
                 {}\n</DataArray>\n",
                a.vtk_type,
                a.name,
                a.components,
                text.unwrap_or_else(|| base64(&head) + &base64(&data))
            ),
        };
        match sections.iter_mut().find(|(s, _)| *s == a.section) {
            Some((_, body)) => body.push_str(&element),
            None => sections.push((a.section, element)),
        }
    }
    let compressor = if layout == Layout::Zlib {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let header_type = if header64 { "UInt64" } else { "UInt32" };
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"{header_type}\"{compressor}>\n\
         <UnstructuredGrid>\n<Piece NumberOfPoints=\"8\" NumberOfCells=\"8\">\n"
    );
    for (section, body) in sections {
        out.push_str(&format!("<{section}>\n{body}</{section}>\n"));
    }
    out.push_str("</Piece>\n</UnstructuredGrid>\n");
    let mut bytes = out.into_bytes();
    if layout == Layout::AppendedRaw {
        bytes.extend(b"<AppendedData encoding=\"raw\">\n_");
        bytes.extend(&appended);
        bytes.extend(b"\n</AppendedData>\n");
    }
    bytes.extend(b"</VTKFile>\n");
    bytes
}

fn no_edit(_: &str, _: &mut Vec<u64>, _: &mut Vec<u8>, _: &mut Option<String>) {}

fn read_err(bytes: &[u8], name: &str) -> String {
    match read_mesh_bytes(bytes, Path::new(name)) {
        Ok(m) => panic!("{name}: accepted ({} tetrahedra)", m.tetrahedra.len()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn built_vtu_files_read_like_the_fixture() {
    let reference = read_mesh_bytes(
        &std::fs::read(fixture("cube_ascii.vtu")).expect("fixture"),
        Path::new("cube.vtu"),
    )
    .expect("fixture");
    for layout in [Layout::Binary, Layout::Zlib, Layout::AppendedRaw] {
        for header64 in [false, true] {
            let m = read_mesh_bytes(&vtu(layout, header64, &no_edit), Path::new("built.vtu"))
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(m.nodes, reference.nodes);
            assert_eq!(m.tetrahedra, reference.tetrahedra);
            assert_eq!(m.groups, reference.groups);
        }
    }
    // A zlib array whose size is a whole number of blocks: VTK writes np = 0 for a full last
    // block (the points, 192 bytes, in 3 blocks of 64).
    let edit = |name: &str, h: &mut Vec<u64>, d: &mut Vec<u8>, _: &mut Option<String>| {
        if name == "Points" {
            let raw = cube_arrays().remove(0).bytes;
            let blocks: Vec<Vec<u8>> = raw.chunks(64).map(zlib_stored).collect();
            *h = vec![3, 64, 0];
            h.extend(blocks.iter().map(|b| b.len() as u64));
            *d = blocks.concat();
        }
    };
    let m = read_mesh_bytes(&vtu(Layout::Zlib, false, &edit), Path::new("full.vtu"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.nodes, reference.nodes);
}

/// A 45 KB VTU whose Points block claims 1 TiB uncompressed.
fn bomb() -> Vec<u8> {
    let edit = |name: &str, h: &mut Vec<u64>, d: &mut Vec<u8>, _: &mut Option<String>| {
        if name == "Points" {
            *d = zlib_stored(&[0u8; 45_000]);
            *h = vec![1, 1 << 40, 1 << 40, d.len() as u64];
        }
    };
    vtu(Layout::Zlib, true, &edit)
}
#[test]
fn a_zlib_bomb_is_an_error_not_an_abort() {
    let dir = case_dir("bomb");
    let bytes = bomb();
    assert!(bytes.len() < 64_000, "{} bytes", bytes.len());
    std::fs::write(dir.join("bomb.vtu"), &bytes).expect("write");
    let scene = scene_for(&dir, "bomb.vtu");
    let (code, err) = compile(&[&scene, &"-o", &dir.join("m.crokf")]);
    assert_eq!(code, Some(1), "exit status (a signal gives None): {err}");
    assert!(
        err.contains("bomb.vtu")
            && err.contains("DataArray 'Points'")
            && err.contains("1099511627776 bytes uncompressed")
            && err.contains("1032:1"),
        "{err}"
    );
    assert_no_panic_text(&err);
    // The same through the library, and the cap on a file's total.
    let msg = read_err(&bytes, "bomb.vtu");
    assert!(
        msg.contains("block 1 of 1 claims 1099511627776 bytes"),
        "{msg}"
    );
    let edit = |name: &str, h: &mut Vec<u64>, d: &mut Vec<u8>, _: &mut Option<String>| {
        if name == "Points" {
            // 5 GiB claimed from 5.3 MB: within zlib's ratio, beyond the 4 GiB cap.
            *d = zlib_stored(&vec![0u8; 5_300_000]);
            *h = vec![1, 5 << 30, 5 << 30, d.len() as u64];
        }
    };
    let msg = read_err(&vtu(Layout::Zlib, true, &edit), "big.vtu");
    assert!(
        msg.contains("more than 4294967296 bytes") && msg.contains("docs/limits.md"),
        "{msg}"
    );
}

/// The block headers that made vtkio panic, each with the phrase its error must contain.
fn bad_blocks() -> Vec<(&'static str, Layout, bool, Box<EditFn>, &'static str)> {
    fn points(f: fn(&mut Vec<u64>, &mut Vec<u8>, &mut Option<String>)) -> Box<EditFn> {
        Box::new(
            move |name: &str, h: &mut Vec<u64>, d: &mut Vec<u8>, t: &mut Option<String>| {
                if name == "Points" {
                    f(h, d, t)
                }
            },
        )
    }
    vec![
        (
            "zero block size",
            Layout::Zlib,
            false,
            points(|h, _, _| {
                h[1] = 0;
                h[2] = 0;
            }),
            "block size of 0 bytes",
        ),
        (
            "zero blocks",
            Layout::Zlib,
            false,
            points(|h, d, _| {
                *h = vec![0, 0, 0];
                d.clear();
            }),
            "0 values, expected 24",
        ),
        (
            "zero uncompressed size",
            Layout::Binary,
            false,
            points(|h, _, _| h[0] = 0),
            "0 values, expected 24",
        ),
        (
            "block count overflowing",
            Layout::Zlib,
            true,
            points(|h, _, _| h[0] = 1 << 62),
            "claims 4611686018427387904 blocks",
        ),
        (
            "huge range end",
            Layout::Zlib,
            true,
            points(|h, _, _| h[3] = 1 << 40),
            "claims 1099511627776 compressed bytes",
        ),
        (
            "huge uncompressed size",
            Layout::AppendedRaw,
            true,
            points(|h, _, _| h[0] = u64::MAX),
            "claims 18446744073709551615 bytes",
        ),
        (
            "too-short base64 header",
            Layout::Binary,
            false,
            points(|_, _, t| *t = Some("AAA=".into())),
            "block header is cut short",
        ),
        (
            "empty base64 payload",
            Layout::Binary,
            false,
            points(|_, _, t| *t = Some(String::new())),
            "binary data array without data",
        ),
        (
            "not base64",
            Layout::Binary,
            false,
            points(|_, _, t| *t = Some("AAAA#AAA".into())),
            "is not base64",
        ),
    ]
}

#[test]
fn malformed_blocks_are_errors_naming_the_file_and_the_array() {
    for (what, layout, header64, edit, phrase) in bad_blocks() {
        let msg = read_err(&vtu(layout, header64, edit.as_ref()), "bad.vtu");
        assert!(
            msg.contains("bad.vtu") && msg.contains("DataArray 'Points'") && msg.contains(phrase),
            "{what}: {msg}"
        );
        assert_no_panic_text(&msg);
    }
    // A compressed block that decompresses to less than it claims.
    let edit = |name: &str, h: &mut Vec<u64>, _: &mut Vec<u8>, _: &mut Option<String>| {
        if name == "Points" {
            h[1] += 8;
            h[2] += 8;
        }
    };
    let msg = read_err(&vtu(Layout::Zlib, false, &edit), "short.vtu");
    assert!(
        msg.contains("block 1 of 1 decompresses to 192 bytes, the header claims 200"),
        "{msg}"
    );
}

#[test]
fn crokf_compile_shows_no_panic_text_for_malformed_blocks() {
    let dir = case_dir("no_panic_text");
    for (k, (what, layout, header64, edit, phrase)) in bad_blocks().into_iter().enumerate() {
        let name = format!("bad{k}.vtu");
        std::fs::write(dir.join(&name), vtu(layout, header64, edit.as_ref())).expect("write");
        let scene = scene_for(&dir, &name);
        let (code, err) = compile(&[&scene, &"-o", &dir.join("m.crokf")]);
        assert_eq!(code, Some(1), "{what}: {err}");
        assert!(err.contains(&name) && err.contains(phrase), "{what}: {err}");
        assert_no_panic_text(&err);
    }
}
