//! VTK files of a small box mesh in every encoding the readers take, with their claimed sizes
//! mutated (the `vtu` target): XML with ASCII arrays, inline base64 binary (uncompressed, zlib,
//! LZ4; header and data as one base64 stream or as two), appended raw or base64 data, UInt32 or
//! UInt64 headers, either byte order; legacy VTK in ASCII and big-endian binary. Mutations act on
//! what a file claims: a header integer (size, block count, block size, last block, compressed
//! size) or a count (`NumberOfPoints`, `POINTS n`, `CELLS n size`, …) replaced by a boundary
//! value (0, 1, the true value ± 1, 2³¹, 2³², 2⁴⁰, 2⁶², 2⁶⁴ − 1, a random one), and the bytes
//! that follow cut short, lengthened or flipped.

use crokf_compile::mesh::procedural::box_mesh;

use crate::Rng;

/// One data array: section, name, VTK type, components, little-endian bytes and its values
/// as text (for ASCII files).
#[derive(Clone, Debug)]
struct Array {
    section: &'static str,
    name: &'static str,
    vtk_type: &'static str,
    components: usize,
    /// Values as f64 (written in `vtk_type`).
    values: Vec<f64>,
}

impl Array {
    fn size(&self) -> usize {
        match self.vtk_type {
            "UInt8" => 1,
            "Int32" => 4,
            _ => 8,
        }
    }

    fn bytes(&self, big_endian: bool) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.values.len() * self.size());
        for &v in &self.values {
            let b: Vec<u8> = match (self.vtk_type, big_endian) {
                ("UInt8", _) => vec![v as u8],
                ("Int32", false) => (v as i32).to_le_bytes().to_vec(),
                ("Int32", true) => (v as i32).to_be_bytes().to_vec(),
                ("Int64", false) => (v as i64).to_le_bytes().to_vec(),
                ("Int64", true) => (v as i64).to_be_bytes().to_vec(),
                (_, false) => v.to_le_bytes().to_vec(),
                (_, true) => v.to_be_bytes().to_vec(),
            };
            out.extend(b);
        }
        out
    }

    fn text(&self) -> String {
        self.values
            .iter()
            .map(|v| {
                if self.vtk_type == "Float64" {
                    format!("{v:e}")
                } else {
                    format!("{}", *v as i64)
                }
            })
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// The 2 × 1 × 1 box (12 tetrahedra, 2 end triangles per face) as VTK arrays.
fn arrays() -> (usize, usize, Vec<Array>) {
    let mesh = box_mesh([2, 1, 1], [1.0, 0.5, 0.5]);
    let points: Vec<f64> = mesh.nodes.iter().flatten().copied().collect();
    let mut connectivity = Vec::new();
    let mut offsets = Vec::new();
    let mut types = Vec::new();
    let mut material = Vec::new();
    for (k, t) in mesh.tetrahedra.iter().enumerate() {
        connectivity.extend(t.nodes.iter().map(|&n| n as f64));
        offsets.push(connectivity.len() as f64);
        types.push(10.0);
        material.push(1.0 + (k % 2) as f64);
    }
    for t in &mesh.triangles {
        connectivity.extend(t.nodes.iter().map(|&n| n as f64));
        offsets.push(connectivity.len() as f64);
        types.push(5.0);
        material.push(7.0);
    }
    let cells = types.len();
    let quality: Vec<f64> = (0..cells).map(|k| 0.5 + 0.01 * k as f64).collect();
    let array = |section, name, vtk_type, components, values| Array {
        section,
        name,
        vtk_type,
        components,
        values,
    };
    (
        mesh.nodes.len(),
        cells,
        vec![
            array("Points", "Points", "Float64", 3, points),
            array("Cells", "connectivity", "Int64", 1, connectivity),
            array("Cells", "offsets", "Int64", 1, offsets),
            array("Cells", "types", "UInt8", 1, types),
            array("CellData", "MaterialIds", "Int32", 1, material),
            array("CellData", "Quality", "Float64", 1, quality),
        ],
    )
}

/// How the arrays are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Layout {
    Ascii,
    Binary,
    Zlib,
    Lz4,
    AppendedRaw,
    AppendedBase64,
    AppendedZlib,
    LegacyAscii,
    LegacyBinary,
}

const LAYOUTS: [Layout; 9] = [
    Layout::Ascii,
    Layout::Binary,
    Layout::Zlib,
    Layout::Lz4,
    Layout::AppendedRaw,
    Layout::AppendedBase64,
    Layout::AppendedZlib,
    Layout::LegacyAscii,
    Layout::LegacyBinary,
];

/// A replacement for a claimed size: boundary values around `actual`.
fn claim(rng: &mut Rng, actual: u64) -> u64 {
    match rng.below(12) {
        0 => 0,
        1 => 1,
        2 => actual.wrapping_sub(1),
        3 => actual.wrapping_add(1),
        4 => 1 << 31,
        5 => (1 << 32) - 1,
        6 => 1 << 32,
        7 => 1 << 40,
        8 => 1 << 62,
        9 => u64::MAX,
        10 => actual.wrapping_mul(2),
        _ => rng.next_u64() >> rng.below(64),
    }
}

fn base64(data: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for c in data.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            out.push(if k <= c.len() {
                char::from(A[((n >> (18 - 6 * k)) & 63) as usize])
            } else {
                '='
            });
        }
    }
    out
}

fn zlib(data: &[u8]) -> Vec<u8> {
    use std::io::Write as _;
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    let _ = e.write_all(data);
    e.finish().unwrap_or_default()
}

/// An LZ4 block of literals only (a valid block any LZ4 decoder reads).
fn lz4_literals(data: &[u8]) -> Vec<u8> {
    let n = data.len();
    let mut out = Vec::with_capacity(n + n / 255 + 2);
    if n < 15 {
        out.push((n as u8) << 4);
    } else {
        out.push(0xF0);
        let mut rest = n - 15;
        while rest >= 255 {
            out.push(255);
            rest -= 255;
        }
        out.push(rest as u8);
    }
    out.extend_from_slice(data);
    out
}

/// One binary array: header integers and the bytes after the header.
struct Block {
    header: Vec<u64>,
    data: Vec<u8>,
}

/// A block compressor of a layout.
type Compress = fn(&[u8]) -> Vec<u8>;

fn block(layout: Layout, bytes: &[u8], block_size: usize) -> Block {
    let compress: Option<Compress> = match layout {
        Layout::Zlib | Layout::AppendedZlib => Some(zlib),
        Layout::Lz4 => Some(lz4_literals),
        _ => None,
    };
    let Some(compress) = compress else {
        return Block {
            header: vec![bytes.len() as u64],
            data: bytes.to_vec(),
        };
    };
    let chunks: Vec<&[u8]> = bytes.chunks(block_size).collect();
    let last = chunks.last().map_or(0, |c| c.len());
    let mut header = vec![
        chunks.len() as u64,
        block_size as u64,
        if last == block_size { 0 } else { last as u64 },
    ];
    let mut data = Vec::new();
    for c in chunks {
        let z = compress(c);
        header.push(z.len() as u64);
        data.extend(z);
    }
    Block { header, data }
}

/// Mutates what a block claims, or the bytes that follow its header.
fn mutate_block(b: &mut Block, rng: &mut Rng) {
    match rng.below(6) {
        0..=2 if !b.header.is_empty() => {
            let i = rng.below(b.header.len());
            b.header[i] = claim(rng, b.header[i]);
        }
        3 => {
            let keep = rng.below(b.data.len() + 1);
            b.data.truncate(keep);
        }
        4 => {
            let extra = 1 + rng.below(64);
            for _ in 0..extra {
                b.data.push((rng.next_u64() & 0xff) as u8);
            }
        }
        5 if !b.data.is_empty() => {
            let at = rng.below(b.data.len());
            b.data[at] ^= 1 << rng.below(8);
        }
        _ => {
            // The header one integer short (or, once empty, one long again).
            if b.header.pop().is_none() {
                b.header.push(claim(rng, 0));
            }
        }
    }
}

/// A VTK file of the box in a random layout with up to three claims mutated.
pub fn case(rng: &mut Rng) -> Vec<u8> {
    let (points, cells, arrays) = arrays();
    let layout = *rng.pick(&LAYOUTS);
    let mutations = rng.below(4);
    // Counts claimed by the XML attributes or the legacy keywords.
    let mut counts = vec![points as u64, cells as u64];
    let legacy = matches!(layout, Layout::LegacyAscii | Layout::LegacyBinary);
    if legacy {
        let size = arrays[1].values.len() + cells;
        counts = vec![
            points as u64,
            cells as u64,
            size as u64,
            cells as u64,
            cells as u64,
        ];
    }
    let header64 = rng.below(2) == 0;
    let big_endian = legacy || rng.below(4) == 0;
    let block_size = *rng.pick(&[7usize, 64, 32768]);
    let mut blocks: Vec<Block> = arrays
        .iter()
        .map(|a| block(layout, &a.bytes(big_endian), block_size))
        .collect();
    let split_base64 = rng.below(2) == 0;
    for _ in 0..mutations {
        if rng.below(4) == 0 {
            let i = rng.below(counts.len());
            counts[i] = claim(rng, counts[i]);
        } else {
            let i = rng.below(blocks.len());
            mutate_block(&mut blocks[i], rng);
        }
    }
    if legacy {
        return legacy_file(layout, &arrays, &blocks, &counts);
    }
    let int = |v: u64| -> Vec<u8> {
        match (header64, big_endian) {
            (true, false) => v.to_le_bytes().to_vec(),
            (true, true) => v.to_be_bytes().to_vec(),
            (false, false) => (v as u32).to_le_bytes().to_vec(),
            (false, true) => (v as u32).to_be_bytes().to_vec(),
        }
    };
    let compressed = matches!(layout, Layout::Zlib | Layout::Lz4 | Layout::AppendedZlib);
    let mut appended: Vec<u8> = Vec::new();
    let mut appended_text = String::new();
    let mut sections: Vec<(&str, String)> = Vec::new();
    for (a, b) in arrays.iter().zip(&blocks) {
        let head: Vec<u8> = b.header.iter().flat_map(|&v| int(v)).collect();
        let attrs = format!(
            "type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\"",
            a.vtk_type, a.name, a.components
        );
        let element = match layout {
            Layout::Ascii => format!(
                "<DataArray {attrs} format=\"ascii\">\n{}\n</DataArray>\n",
                a.text()
            ),
            Layout::Binary | Layout::Zlib | Layout::Lz4 => {
                let text = if split_base64 || compressed {
                    base64(&head) + &base64(&b.data)
                } else {
                    base64(&[head.as_slice(), &b.data].concat())
                };
                format!("<DataArray {attrs} format=\"binary\">\n{text}\n</DataArray>\n")
            }
            Layout::AppendedRaw => {
                let offset = appended.len();
                appended.extend(&head);
                appended.extend(&b.data);
                format!("<DataArray {attrs} format=\"appended\" offset=\"{offset}\"/>\n")
            }
            _ => {
                let offset = appended_text.len();
                if split_base64 || compressed {
                    appended_text.push_str(&base64(&head));
                    appended_text.push_str(&base64(&b.data));
                } else {
                    appended_text.push_str(&base64(&[head.as_slice(), &b.data].concat()));
                }
                format!("<DataArray {attrs} format=\"appended\" offset=\"{offset}\"/>\n")
            }
        };
        match sections.iter_mut().find(|(s, _)| *s == a.section) {
            Some((_, body)) => body.push_str(&element),
            None => sections.push((a.section, element)),
        }
    }
    let compressor = match layout {
        Layout::Zlib | Layout::AppendedZlib => " compressor=\"vtkZLibDataCompressor\"",
        Layout::Lz4 => " compressor=\"vtkLZ4DataCompressor\"",
        _ => "",
    };
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" \
         byte_order=\"{}\" header_type=\"{}\"{compressor}>\n<UnstructuredGrid>\n\
         <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n",
        if big_endian {
            "BigEndian"
        } else {
            "LittleEndian"
        },
        if header64 { "UInt64" } else { "UInt32" },
        counts[0],
        counts[1]
    );
    for (section, body) in sections {
        out.push_str(&format!("<{section}>\n{body}</{section}>\n"));
    }
    out.push_str("</Piece>\n</UnstructuredGrid>\n");
    let mut bytes = out.into_bytes();
    match layout {
        Layout::AppendedRaw => {
            bytes.extend(b"<AppendedData encoding=\"raw\">\n_");
            bytes.extend(&appended);
            bytes.extend(b"\n</AppendedData>\n");
        }
        Layout::AppendedBase64 | Layout::AppendedZlib => {
            bytes.extend(b"<AppendedData encoding=\"base64\">\n_");
            bytes.extend(appended_text.as_bytes());
            bytes.extend(b"\n</AppendedData>\n");
        }
        _ => {}
    }
    bytes.extend(b"</VTKFile>\n");
    bytes
}

/// A legacy VTK file (ASCII, or binary big-endian as VTK writes it) with the claimed counts
/// `[POINTS n, CELLS n, CELLS size, CELL_TYPES n, CELL_DATA n]`; a mutated binary block's data
/// length stands for a wrong byte count.
fn legacy_file(layout: Layout, arrays: &[Array], blocks: &[Block], counts: &[u64]) -> Vec<u8> {
    let binary = layout == Layout::LegacyBinary;
    let mut out = format!(
        "# vtk DataFile Version 4.2\nfuzz\n{}\nDATASET UNSTRUCTURED_GRID\nPOINTS {} double\n",
        if binary { "BINARY" } else { "ASCII" },
        counts[0]
    )
    .into_bytes();
    let data = |k: usize, out: &mut Vec<u8>| {
        if binary {
            out.extend(&blocks[k].data);
            out.push(b'\n');
        } else {
            out.extend(arrays[k].text().as_bytes());
            out.push(b'\n');
        }
    };
    data(0, &mut out);
    // CELLS: per cell its vertex count then the vertices (Int32 in binary files).
    out.extend(format!("CELLS {} {}\n", counts[1], counts[2]).as_bytes());
    let offsets: Vec<usize> = arrays[2].values.iter().map(|&v| v as usize).collect();
    let conn: Vec<i64> = arrays[1].values.iter().map(|&v| v as i64).collect();
    let mut start = 0;
    let mut cells: Vec<i32> = Vec::new();
    for &end in &offsets {
        cells.push((end - start) as i32);
        cells.extend(conn[start..end].iter().map(|&v| v as i32));
        start = end;
    }
    if binary {
        for v in &cells {
            out.extend(v.to_be_bytes());
        }
        out.push(b'\n');
    } else {
        let text: Vec<String> = cells.iter().map(i32::to_string).collect();
        out.extend(text.join(" ").as_bytes());
        out.push(b'\n');
    }
    out.extend(format!("CELL_TYPES {}\n", counts[3]).as_bytes());
    let types: Vec<i32> = arrays[3].values.iter().map(|&v| v as i32).collect();
    if binary {
        for v in &types {
            out.extend(v.to_be_bytes());
        }
        out.push(b'\n');
    } else {
        let text: Vec<String> = types.iter().map(i32::to_string).collect();
        out.extend(text.join(" ").as_bytes());
        out.push(b'\n');
    }
    out.extend(
        format!(
            "CELL_DATA {}\nFIELD FieldData 1\nMaterialIds 1 {} int\n",
            counts[4], counts[4]
        )
        .as_bytes(),
    );
    data(4, &mut out);
    out
}
