//! VTK unstructured grids: XML (`.vtu`: ASCII, base64 binary or appended raw/base64 data,
//! zlib or LZ4 compressed) by `super::vtu`, legacy (`.vtk`: ASCII or big-endian binary, as
//! VTK writes it; legacy 5.1 files with OFFSETS/CONNECTIVITY are not read) through `vtkio` 0.7.
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
//!
//! The legacy reader's input is checked first where vtkio would give no useful message: an
//! ASCII `POINTS` section with a coordinate that is not a finite number (however a C library
//! spelt the NaN or infinity: `nan(ind)`, `1.#QNAN`, ...), or with fewer coordinates than it
//! declares, is refused naming the line, the point (0-based) and the axis; in a binary file, a
//! non-finite coordinate is named by its point, axis and byte offset. A panic inside
//! vtkio is caught (`super::guard`) and reported as a parse error.

use std::collections::BTreeMap;
use std::path::Path;

use vtkio::model::{Attribute, DataSet, IOBuffer, Piece, VertexNumbers};

use super::vtu::{self, GridPiece};
use super::{guard, MeshError, RawElement, RawMesh};

fn vtk_error(path: &Path, message: impl Into<String>) -> MeshError {
    MeshError::Vtk {
        path: path.to_owned(),
        message: message.into(),
    }
}

/// Reads a VTK XML file (a `.vtu`): the file's bytes `file`, whose `<?xml` or `<VTKFile`
/// starts at byte `start` (after a byte-order mark and blank lines).
pub(super) fn read_xml(file: &[u8], start: usize, path: &Path) -> Result<RawMesh, MeshError> {
    let start = start.min(file.len());
    let origin = vtu::Origin {
        offset: start,
        lines: file[..start].iter().filter(|&&b| b == b'\n').count(),
    };
    let pieces = vtu::read(&file[start..], origin).map_err(|m| {
        vtk_error(
            path,
            format!("cannot read it as a VTK XML unstructured grid: {m}"),
        )
    })?;
    assemble_pieces(pieces, path)
}

/// Reads a legacy VTK file; `bytes` start at `# vtk DataFile`.
pub(super) fn read_legacy(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    if let Some(problem) = legacy_points_problem(bytes) {
        return Err(vtk_error(
            path,
            format!("cannot read it as a legacy VTK file: {problem}"),
        ));
    }
    let parsed = guard::quietly(|| vtkio::Vtk::parse_legacy_be(bytes));
    let version_hint = if legacy_version_5(bytes) {
        "; legacy files of version 5.1 (OFFSETS/CONNECTIVITY) are not read: save as .vtu instead"
    } else {
        ""
    };
    match parsed {
        Ok(Ok(vtk)) => assemble_pieces(legacy_pieces(vtk.data, path)?, path),
        Ok(Err(e)) => Err(vtk_error(
            path,
            format!("cannot read it as a legacy VTK file (vtkio: {e}){version_hint}"),
        )),
        Err(()) => Err(vtk_error(
            path,
            format!(
                "cannot read it as a legacy VTK file: its content is malformed (the vtkio \
                 parser gave up){version_hint}"
            ),
        )),
    }
}

/// Whether the header line says version 5.x, or the file uses the 5.1 cell layout.
fn legacy_version_5(bytes: &[u8]) -> bool {
    let first = bytes.split(|&b| b == b'\n').next().unwrap_or(b"");
    let first = String::from_utf8_lossy(first);
    first.contains("Version 5") || bytes.windows(7).any(|w| w == b"OFFSETS")
}

/// Whether `token` is how a C library spells a NaN or an infinity that Rust's parser does not
/// read: `nan(ind)`, `-nan(0x8000)`, `nanq`, `nans` (glibc, MinGW) or `1.#QNAN`, `-1.#IND`,
/// `1.#INF`, `1.#SNAN` (older MSVC), in any case (`nan`, `inf`, `infinity` parse as such).
fn non_finite_spelling(token: &str) -> bool {
    let t = token.trim_start_matches(['+', '-']).to_ascii_lowercase();
    if t.starts_with("nan(") || t == "nanq" || t == "nans" {
        return true;
    }
    match t.split_once(".#") {
        Some((digits, kind)) => {
            !digits.is_empty()
                && digits.bytes().all(|b| b.is_ascii_digit())
                && ["qnan", "snan", "ind", "inf"]
                    .iter()
                    .any(|k| kind.starts_with(k))
        }
        None => false,
    }
}

/// The `POINTS n type` section of a binary legacy file: the first coordinate that is NaN or
/// infinite, named by its point (0-based), its axis and its byte offset in the file; `None`
/// when all are finite, or the section cannot be located (vtkio then reports the problem).
fn binary_points_problem(bytes: &[u8]) -> Option<String> {
    const KEY: &[u8] = b"\nPOINTS ";
    let at = bytes.windows(KEY.len()).position(|w| w == KEY)? + 1;
    let eol = at + bytes[at..].iter().position(|&b| b == b'\n')?;
    let header = String::from_utf8_lossy(&bytes[at..eol]).into_owned();
    let mut words = header.split_ascii_whitespace().skip(1);
    let n: u64 = words.next()?.parse().ok()?;
    let kind = words.next()?.to_ascii_lowercase();
    let width = match kind.as_str() {
        "float" => 4,
        "double" => 8,
        _ => return None,
    };
    let start = eol + 1;
    let line = super::line_of(bytes, at);
    // Big-endian, as VTK writes legacy binary files (and vtkio reads them here).
    let values = bytes[start..]
        .chunks_exact(width)
        .take(usize::try_from(n.saturating_mul(3)).ok()?);
    for (k, chunk) in values.enumerate() {
        let v = if width == 4 {
            f64::from(f32::from_be_bytes(chunk.try_into().ok()?))
        } else {
            f64::from_be_bytes(chunk.try_into().ok()?)
        };
        if !v.is_finite() {
            return Some(format!(
                "POINTS (line {line}, binary {kind}): point {} (0-based) has a non-finite {} \
                 coordinate ({v}) at byte {} of the file; every coordinate must be a finite \
                 number",
                k / 3,
                ["x", "y", "z"][k % 3],
                start + k * width
            ));
        }
    }
    None
}

/// In a legacy file: the first `POINTS n type` section whose coordinates are not 3n finite
/// numbers, described with the line (binary: the byte) and the point; `None` when the points
/// look right (or the file has no `POINTS` line: vtkio then reports the problem).
fn legacy_points_problem(bytes: &[u8]) -> Option<String> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines = text.lines().enumerate();
    // Line 3 says ASCII or BINARY.
    let third = text.lines().nth(2).map(str::trim);
    if third.is_some_and(|l| l.eq_ignore_ascii_case("binary")) {
        return binary_points_problem(bytes);
    }
    if !third.is_some_and(|l| l.eq_ignore_ascii_case("ascii")) {
        return None;
    }
    let (points_line, declared) = lines.find_map(|(i, l)| {
        let mut words = l.split_ascii_whitespace();
        (words.next()? == "POINTS").then(|| (i + 1, words.next().map(str::to_owned)))
    })?;
    let Some(declared) = declared else {
        return Some(format!("line {points_line}: POINTS without a count"));
    };
    let Ok(n) = declared.parse::<u64>() else {
        return Some(format!(
            "line {points_line}: POINTS count {declared:?} is not a non-negative integer"
        ));
    };
    let want = n.saturating_mul(3);
    let mut got = 0u64;
    for (i, l) in lines {
        for tok in l.split_ascii_whitespace() {
            if got == want {
                return None;
            }
            let point = got / 3;
            let axis = ["x", "y", "z"][(got % 3) as usize];
            let non_finite = || {
                format!(
                    "line {}: point {point} (0-based) has a non-finite {axis} coordinate \
                     ({tok}); every coordinate must be a finite number",
                    i + 1
                )
            };
            match tok.parse::<f64>() {
                Ok(v) if v.is_finite() => got += 1,
                Ok(_) => return Some(non_finite()),
                Err(_) if non_finite_spelling(tok) => return Some(non_finite()),
                Err(_) if tok.chars().next().is_some_and(|c| c.is_ascii_alphabetic()) => {
                    return Some(format!(
                        "line {}: POINTS (line {points_line}) declares {n} points but the \
                         coordinates end after {got} values, inside point {point}, where \
                         {tok:?} begins",
                        i + 1
                    ))
                }
                Err(_) => {
                    return Some(format!(
                        "line {}: the {axis} coordinate of point {point}, {tok:?}, is not a \
                         number",
                        i + 1
                    ))
                }
            }
        }
    }
    (got < want).then(|| {
        format!(
            "POINTS (line {points_line}) declares {n} points but the file ends after {got} \
             coordinates, inside point {}",
            got / 3
        )
    })
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

/// The pieces of a legacy file's data set.
fn legacy_pieces(data: DataSet, path: &Path) -> Result<Vec<GridPiece>, MeshError> {
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
    let mut out = Vec::with_capacity(pieces.len());
    for (k, piece) in pieces.into_iter().enumerate() {
        let piece = match piece {
            Piece::Inline(p) => *p,
            Piece::Source(file, _) => {
                return Err(vtk_error(
                    path,
                    format!("piece {} is stored in another file ({file})", k + 1),
                ))
            }
            Piece::Loaded(_) => {
                return Err(vtk_error(path, format!("piece {}: nested data set", k + 1)))
            }
        };
        let points = piece
            .points
            .cast_into::<f64>()
            .ok_or_else(|| vtk_error(path, format!("piece {}: points are not numbers", k + 1)))?;
        let types: Vec<u8> = piece.cells.types.iter().map(|&c| c as u8).collect();
        let (connectivity, ranges) = cell_ranges(piece.cells.cell_verts, path)?;
        let n_points = (points.len() / 3) as u64;
        if let Some(&bad) = connectivity.iter().find(|&&v| v >= n_points) {
            return Err(vtk_error(
                path,
                format!(
                    "piece {}: a cell uses point {bad}, but there are {n_points} points",
                    k + 1
                ),
            ));
        }
        let mut arrays = Vec::new();
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
                if let Some(values) = integer_values(data) {
                    arrays.push((name, values));
                }
            }
        }
        out.push(GridPiece {
            points,
            connectivity,
            ranges,
            types,
            arrays,
        });
    }
    Ok(out)
}

/// gmsh element type of a VTK cell type crokf keeps or ignores; `None` for unsupported ones.
fn gmsh_kind(cell: u8) -> Option<u32> {
    match cell {
        10 => Some(4),
        5 => Some(2),
        3 => Some(1),
        1 => Some(15),
        _ => None,
    }
}

/// The mesh of a grid's pieces: points and cells numbered over all pieces in order, integer
/// cell-data arrays as groups.
pub(super) fn assemble_pieces(pieces: Vec<GridPiece>, path: &Path) -> Result<RawMesh, MeshError> {
    let mut raw = RawMesh::default();
    // Per array name: per cell (global id) its value, or None where the array is absent.
    let mut arrays: BTreeMap<String, Vec<Option<i64>>> = BTreeMap::new();
    let mut kinds: Vec<u32> = Vec::new();
    let mut unsupported: BTreeMap<(u8, &'static str), usize> = BTreeMap::new();
    for (k, piece) in pieces.into_iter().enumerate() {
        let first_point = raw.nodes.len() as u64;
        let first_cell = kinds.len();
        let coords = piece.points;
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
        let types = piece.types;
        let (connectivity, ranges) = (piece.connectivity, piece.ranges);
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
                *unsupported.entry((cell, cell_type_name(cell))).or_default() += 1;
                kinds.push(0);
                continue;
            };
            kinds.push(kind);
            let nodes: Vec<u64> = connectivity
                .get(start..start + len)
                .ok_or_else(|| {
                    vtk_error(
                        path,
                        format!("piece {}: cell {c} runs past the connectivity", k + 1),
                    )
                })?
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
        for (name, values) in piece.arrays {
            if values.len() != n_cells {
                continue;
            }
            let column = arrays.entry(name).or_default();
            column.resize(first_cell, None);
            column.extend(values.into_iter().map(Some));
        }
    }
    if !unsupported.is_empty() {
        let list: Vec<String> = unsupported
            .iter()
            .map(|((t, name), n)| format!("{n} cell(s) of type {name} ({t})"))
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
            let mut cells_of: BTreeMap<i64, Vec<usize>> = BTreeMap::new();
            for (cell, (value, &k)) in column.iter().zip(&kinds).enumerate() {
                if let (Some(v), true) = (value, k == kind) {
                    cells_of.entry(*v).or_default().push(cell);
                }
            }
            for (v, cells) in cells_of {
                next_tag += 1;
                raw.names
                    .insert((dim, next_tag), format!("{name}:{v}{suffix}"));
                for cell in cells {
                    if let Some(i) = element_of_cell[cell] {
                        raw.elements[i].physical.push(next_tag);
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

/// Name of a VTK cell type (as VTK's `vtkCellType.h` spells it, without `VTK_`).
fn cell_type_name(t: u8) -> &'static str {
    match t {
        1 => "Vertex",
        2 => "PolyVertex",
        3 => "Line",
        4 => "PolyLine",
        5 => "Triangle",
        6 => "TriangleStrip",
        7 => "Polygon",
        8 => "Pixel",
        9 => "Quad",
        10 => "Tetra",
        11 => "Voxel",
        12 => "Hexahedron",
        13 => "Wedge",
        14 => "Pyramid",
        21 => "QuadraticEdge",
        22 => "QuadraticTriangle",
        23 => "QuadraticQuad",
        24 => "QuadraticTetra",
        25 => "QuadraticHexahedron",
        26 => "QuadraticWedge",
        27 => "QuadraticPyramid",
        42 => "Polyhedron",
        68..=74 => "Lagrange cell",
        75..=81 => "Bezier cell",
        _ => "unknown cell type",
    }
}
