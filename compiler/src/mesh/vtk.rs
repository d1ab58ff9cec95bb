//! VTK unstructured grids through `vtkio` 0.7: XML (`.vtu`: ASCII, base64 binary or appended
//! raw/base64 data, zlib or LZ4 compressed) and legacy (`.vtk`: ASCII or big-endian binary, as
//! VTK writes it; legacy 5.1 files with OFFSETS/CONNECTIVITY are not read by vtkio).
//!
//! vtkio 0.7 decodes appended data only when it is base64-encoded; raw appended data (what
//! ParaView and VTK write by default) is re-encoded as base64 here first (`raw_to_base64`):
//! every block keeps its bytes, only the encoding and the `offset` attributes change.
//!
//! - Node tags are the 0-based point ids and element tags the 0-based cell ids (over all pieces,
//!   in file order), as ParaView's spreadsheet view shows them.
//! - Cells: VTK_TETRA (10) become tetrahedra, VTK_TRIANGLE (5) triangles; VTK_VERTEX (1) and
//!   VTK_LINE (3) are ignored; any other cell type is an error that counts them by type.
//! - Groups: every cell-data array with one integer component (an XML `DataArray` of an integer
//!   type, a legacy `SCALARS` or `FIELD` array of an integer type), say `MaterialIds`, gives one
//!   volume group per value v taken on tetrahedra, named `"MaterialIds:v"`, and one surface group
//!   per value taken on triangles, named `"MaterialIds:v:faces"`. Floating-point arrays are not
//!   groups (a region id written as float is ambiguous). meshio's conversion of a gmsh file
//!   stores the physical tags as `gmsh:physical`, so its groups are `"gmsh:physical:<tag>"`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use vtkio::model::{Attribute, CellType, DataSet, IOBuffer, Piece, VertexNumbers};

use super::{MeshError, RawElement, RawMesh};

fn vtk_error(path: &Path, message: impl Into<String>) -> MeshError {
    MeshError::Vtk {
        path: path.to_owned(),
        message: message.into(),
    }
}

/// Reads a VTK XML file (a `.vtu`); `bytes` start at `<?xml` or `<VTKFile`.
pub(super) fn read_xml(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let converted = raw_to_base64(bytes).map_err(|m| vtk_error(path, m))?;
    let bytes = converted.as_deref().unwrap_or(bytes);
    let parsed = std::panic::catch_unwind(|| vtkio::Vtk::parse_xml(bytes));
    match parsed {
        Ok(Ok(vtk)) => convert(vtk.data, path),
        Ok(Err(e)) => Err(vtk_error(
            path,
            format!("cannot read it as a VTK XML file (vtkio: {e})"),
        )),
        Err(_) => Err(vtk_error(
            path,
            "cannot read it as a VTK XML file (the vtkio parser failed; its message is above)",
        )),
    }
}

/// Reads a legacy VTK file; `bytes` start at `# vtk DataFile`.
pub(super) fn read_legacy(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let parsed = std::panic::catch_unwind(|| vtkio::Vtk::parse_legacy_be(bytes));
    match parsed {
        Ok(Ok(vtk)) => convert(vtk.data, path),
        Ok(Err(e)) => Err(vtk_error(
            path,
            format!(
                "cannot read it as a legacy VTK file (vtkio: {e}); legacy files of version \
                 5.1 (OFFSETS/CONNECTIVITY) are not read: save as .vtu instead"
            ),
        )),
        Err(_) => Err(vtk_error(
            path,
            "cannot read it as a legacy VTK file (the vtkio parser failed; its message is above)",
        )),
    }
}

/// gmsh element type of a VTK cell type crokf keeps or ignores; `None` for unsupported ones.
fn gmsh_kind(cell: CellType) -> Option<u32> {
    match cell {
        CellType::Tetra => Some(4),
        CellType::Triangle => Some(2),
        CellType::Line => Some(1),
        CellType::Vertex => Some(15),
        _ => None,
    }
}

/// A flat connectivity array and each cell's (offset, length) in it.
type CellRanges = (Vec<u64>, Vec<(usize, usize)>);

/// Cells as (offset, length) into a flat connectivity array.
fn cell_ranges(cells: VertexNumbers, path: &Path) -> Result<CellRanges, MeshError> {
    let bad = || {
        vtk_error(
            path,
            "the cell connectivity is inconsistent (offsets out of range)",
        )
    };
    match cells {
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            let mut ranges = Vec::with_capacity(offsets.len());
            let mut start = 0usize;
            for off in offsets {
                let end = usize::try_from(off).map_err(|_| bad())?;
                if end < start || end > connectivity.len() {
                    return Err(bad());
                }
                ranges.push((start, end - start));
                start = end;
            }
            Ok((connectivity, ranges))
        }
        VertexNumbers::Legacy { vertices, .. } => {
            let mut connectivity = Vec::with_capacity(vertices.len());
            let mut ranges = Vec::new();
            let mut i = 0usize;
            while i < vertices.len() {
                let n = vertices[i] as usize;
                let verts = vertices.get(i + 1..i + 1 + n).ok_or_else(bad)?;
                ranges.push((connectivity.len(), n));
                connectivity.extend(verts.iter().map(|&v| u64::from(v)));
                i += 1 + n;
            }
            Ok((connectivity, ranges))
        }
    }
}

/// One integer component per cell, or None for anything else.
fn integer_values(data: IOBuffer) -> Option<Vec<i64>> {
    match data {
        IOBuffer::F32(_) | IOBuffer::F64(_) | IOBuffer::Bit(_) => None,
        other => other.cast_into::<i64>(),
    }
}

fn convert(data: DataSet, path: &Path) -> Result<RawMesh, MeshError> {
    let DataSet::UnstructuredGrid { pieces, .. } = data else {
        return Err(vtk_error(
            path,
            format!(
                "the file holds a {} data set; crokf reads unstructured grids \
                 (<UnstructuredGrid>, DATASET UNSTRUCTURED_GRID) of tetrahedra",
                data_set_name(&data)
            ),
        ));
    };
    let mut raw = RawMesh::default();
    // Per array name: per cell (global id) its value, or None where the array is absent.
    let mut arrays: BTreeMap<String, Vec<Option<i64>>> = BTreeMap::new();
    let mut kinds: Vec<u32> = Vec::new();
    let mut unsupported: BTreeMap<String, usize> = BTreeMap::new();
    for (k, piece) in pieces.into_iter().enumerate() {
        let piece = match piece {
            Piece::Inline(p) => *p,
            Piece::Source(file, _) => {
                return Err(vtk_error(
                    path,
                    format!(
                        "piece {} is stored in another file ({file}): parallel (.pvtu) data sets \
                         are not read; merge the pieces into one .vtu (ParaView: Merge Blocks, \
                         then Save Data)",
                        k + 1
                    ),
                ))
            }
            Piece::Loaded(_) => {
                return Err(vtk_error(path, format!("piece {}: nested data set", k + 1)))
            }
        };
        let first_point = raw.nodes.len() as u64;
        let first_cell = kinds.len();
        let coords = piece
            .points
            .cast_into::<f64>()
            .ok_or_else(|| vtk_error(path, format!("piece {}: points are not numbers", k + 1)))?;
        if coords.len() % 3 != 0 {
            return Err(vtk_error(
                path,
                format!(
                    "piece {}: {} point coordinates, not a multiple of 3",
                    k + 1,
                    coords.len()
                ),
            ));
        }
        for (i, p) in coords.chunks_exact(3).enumerate() {
            raw.node_tags.push(first_point + i as u64);
            raw.nodes.push([p[0], p[1], p[2]]);
        }
        let types = piece.cells.types;
        let (connectivity, ranges) = cell_ranges(piece.cells.cell_verts, path)?;
        if ranges.len() != types.len() {
            return Err(vtk_error(
                path,
                format!(
                    "piece {}: {} cells in the connectivity but {} cell types",
                    k + 1,
                    ranges.len(),
                    types.len()
                ),
            ));
        }
        for (c, (&cell, &(start, len))) in types.iter().zip(&ranges).enumerate() {
            let tag = (first_cell + c) as u64;
            let Some(kind) = gmsh_kind(cell) else {
                *unsupported
                    .entry(format!("{cell:?} ({})", cell as u8))
                    .or_default() += 1;
                kinds.push(0);
                continue;
            };
            kinds.push(kind);
            let nodes: Vec<u64> = connectivity[start..start + len]
                .iter()
                .map(|&v| first_point + v)
                .collect();
            raw.elements.push(RawElement {
                tag,
                kind,
                physical: Vec::new(),
                nodes,
            });
        }
        let n_cells = types.len();
        for attribute in piece.data.cell {
            let candidates: Vec<(String, IOBuffer)> = match attribute {
                Attribute::DataArray(a) => {
                    let one = match a.elem {
                        vtkio::model::ElementType::Scalars { num_comp, .. } => num_comp == 1,
                        vtkio::model::ElementType::Generic(n) => n == 1,
                        _ => false,
                    };
                    if one {
                        vec![(a.name, a.data)]
                    } else {
                        Vec::new()
                    }
                }
                Attribute::Field { data_array, .. } => data_array
                    .into_iter()
                    .filter(|f| f.elem == 1)
                    .map(|f| (f.name, f.data))
                    .collect(),
            };
            for (name, data) in candidates {
                let Some(values) = integer_values(data) else {
                    continue;
                };
                if values.len() != n_cells {
                    continue;
                }
                let column = arrays.entry(name).or_default();
                column.resize(first_cell, None);
                column.extend(values.into_iter().map(Some));
            }
        }
    }
    if !unsupported.is_empty() {
        let list: Vec<String> = unsupported
            .iter()
            .map(|(t, n)| format!("{n} cell(s) of type {t}"))
            .collect();
        return Err(vtk_error(
            path,
            format!(
                "unsupported cells: {}; crokf needs linear tetrahedra (VTK_TETRA, type 10; \
                 triangles, lines and vertices are accepted): tetrahedralise the grid first \
                 (e.g. ParaView's Tetrahedralize filter, or re-mesh the volume with gmsh)",
                list.join(", ")
            ),
        ));
    }
    // Groups: (array, value) pairs in sorted order get tags 1, 2, ... per dimension.
    let total = kinds.len();
    let mut element_of_cell: Vec<Option<usize>> = vec![None; total];
    for (i, e) in raw.elements.iter().enumerate() {
        if let Some(slot) = usize::try_from(e.tag)
            .ok()
            .and_then(|t| element_of_cell.get_mut(t))
        {
            *slot = Some(i);
        }
    }
    let mut next_tag = 0i32;
    for (name, mut column) in arrays {
        column.resize(total, None);
        for (dim, kind, suffix) in [(3u8, 4u32, ""), (2, 2, ":faces")] {
            let values: BTreeSet<i64> = column
                .iter()
                .zip(&kinds)
                .filter(|(_, &k)| k == kind)
                .filter_map(|(v, _)| *v)
                .collect();
            for v in values {
                next_tag += 1;
                raw.names
                    .insert((dim, next_tag), format!("{name}:{v}{suffix}"));
                for (cell, value) in column.iter().enumerate() {
                    if *value == Some(v) && kinds[cell] == kind {
                        if let Some(i) = element_of_cell[cell] {
                            raw.elements[i].physical.push(next_tag);
                        }
                    }
                }
            }
        }
    }
    Ok(raw)
}

fn data_set_name(d: &DataSet) -> &'static str {
    match d {
        DataSet::ImageData { .. } => "image data (structured points)",
        DataSet::StructuredGrid { .. } => "structured grid",
        DataSet::RectilinearGrid { .. } => "rectilinear grid",
        DataSet::UnstructuredGrid { .. } => "unstructured grid",
        DataSet::PolyData { .. } => "poly data (surface)",
        DataSet::Field { .. } => "field data",
    }
}

/// Standard base64 with padding.
fn base64(data: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[((n >> (18 - 6 * k)) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn attribute<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let start = tag.find(&key)? + key.len();
    let end = tag[start..].find('"')? + start;
    Some(&tag[start..end])
}

/// Re-encodes raw appended data as base64 (VTK XML layout: an uncompressed block is a header
/// integer n then n bytes, encoded as one base64 chunk; a compressed block is the header
/// `[blocks, block size, last size, compressed sizes...]`, then the compressed bytes, encoded as
/// two chunks). Returns `None` when the file has no raw appended data.
pub(super) fn raw_to_base64(bytes: &[u8]) -> Result<Option<Vec<u8>>, String> {
    const OPEN: &[u8] = b"<AppendedData";
    let Some(open) = bytes.windows(OPEN.len()).position(|w| w == OPEN) else {
        return Ok(None);
    };
    let Some(tag_end) = bytes[open..]
        .iter()
        .position(|&b| b == b'>')
        .map(|p| open + p)
    else {
        return Err("unterminated <AppendedData> tag".into());
    };
    let tag = String::from_utf8_lossy(&bytes[open..tag_end]).into_owned();
    if attribute(&tag, "encoding") != Some("raw") {
        return Ok(None);
    }
    let Some(underscore) = bytes[tag_end..].iter().position(|&b| b == b'_') else {
        return Err("raw appended data without its leading `_`".into());
    };
    let data_start = tag_end + underscore + 1;
    const CLOSE: &[u8] = b"</AppendedData>";
    let data_end = bytes
        .windows(CLOSE.len())
        .rposition(|w| w == CLOSE)
        .filter(|&e| e >= data_start)
        .ok_or("raw appended data without </AppendedData>")?;
    let data = &bytes[data_start..data_end];
    let head = std::str::from_utf8(&bytes[..open])
        .map_err(|_| "the XML before <AppendedData> is not UTF-8".to_string())?;
    let file_tag = head
        .find("<VTKFile")
        .and_then(|i| head[i..].find('>').map(|e| &head[i..i + e]))
        .ok_or("no <VTKFile> tag")?;
    let header = match attribute(file_tag, "header_type") {
        Some("UInt64") => 8usize,
        Some("UInt32") | None => 4,
        Some(other) => return Err(format!("header_type {other:?} is not UInt32 or UInt64")),
    };
    let big_endian = attribute(file_tag, "byte_order") == Some("BigEndian");
    let compressed = attribute(file_tag, "compressor").is_some_and(|c| !c.is_empty());
    let read_int = |at: usize| -> Result<usize, String> {
        let b = data
            .get(at..at + header)
            .ok_or_else(|| format!("appended data ends inside a header at byte {at}"))?;
        let mut v: u64 = 0;
        for k in 0..header {
            let byte = if big_endian { b[k] } else { b[header - 1 - k] };
            v = (v << 8) | u64::from(byte);
        }
        usize::try_from(v).map_err(|_| format!("block size {v} out of range"))
    };
    // Offsets of the data arrays, in the order they appear.
    let mut offsets = std::collections::BTreeMap::new();
    let mut rest = head;
    while let Some(i) = rest.find(" offset=\"") {
        rest = &rest[i + 9..];
        let end = rest.find('"').ok_or("unterminated offset attribute")?;
        let v: usize = rest[..end]
            .trim()
            .parse()
            .map_err(|_| format!("offset {:?} is not a number", &rest[..end]))?;
        offsets.insert(v, 0usize);
    }
    let mut encoded = String::new();
    for (&old, new) in offsets.iter_mut() {
        *new = encoded.len();
        if compressed {
            let blocks = read_int(old)?;
            let head_len = header * (3 + blocks);
            let mut total = 0usize;
            for k in 0..blocks {
                total += read_int(old + header * (3 + k))?;
            }
            let h = data
                .get(old..old + head_len)
                .ok_or("appended data truncated")?;
            let body = data
                .get(old + head_len..old + head_len + total)
                .ok_or("appended data truncated")?;
            encoded.push_str(&base64(h));
            encoded.push_str(&base64(body));
        } else {
            let n = read_int(old)?;
            let block = data
                .get(old..old + header + n)
                .ok_or("appended data truncated")?;
            encoded.push_str(&base64(block));
        }
    }
    // Rewrite the head with the new offsets.
    let mut out = String::with_capacity(head.len() + encoded.len() + 64);
    let mut rest = head;
    while let Some(i) = rest.find(" offset=\"") {
        out.push_str(&rest[..i + 9]);
        rest = &rest[i + 9..];
        let end = rest.find('"').ok_or("unterminated offset attribute")?;
        let old: usize = rest[..end]
            .trim()
            .parse()
            .map_err(|_| "bad offset".to_string())?;
        out.push_str(&offsets.get(&old).copied().unwrap_or(0).to_string());
        rest = &rest[end..];
    }
    out.push_str(rest);
    out.push_str(&tag.replace("\"raw\"", "\"base64\""));
    out.push_str(">\n_");
    out.push_str(&encoded);
    out.push('\n');
    let mut bytes_out = out.into_bytes();
    bytes_out.extend_from_slice(&bytes[data_end..]);
    Ok(Some(bytes_out))
}
