//! ASCII VTK XML writers shared by `crokf-run` (estimates per step) and `crokf-verify`
//! (reference trajectories): one UnstructuredGrid piece (`.vtu`) and a time collection
//! (`.pvd`), VTK file format version 1.0 with UInt64 headers.
//!
//! Hand-written rather than through `vtkio` (which the compiler uses to *read* meshes): the
//! two documents are fixed, a few dozen lines, and keep the serde/quick-xml stack out of
//! `crokf-run`; the output is read back by `vtkio` in `verify/tests/vtk_roundtrip.rs`, an
//! independent reader, so a malformed document fails a test.

use std::fmt::Write as _;

/// The values of one data array.
#[derive(Clone, Copy, Debug)]
pub enum Values<'a> {
    /// Float64, written in the shortest form that reads back exactly (`{:e}`).
    F64(&'a [f64]),
    /// UInt64.
    U64(&'a [u64]),
    /// UInt32.
    U32(&'a [u32]),
    /// UInt8.
    U8(&'a [u8]),
}

/// A named data array with `components` values per point or cell.
#[derive(Clone, Copy, Debug)]
pub struct DataArray<'a> {
    pub name: &'a str,
    pub components: usize,
    pub values: Values<'a>,
}

/// VTK cell types used here.
pub const VTK_VERTEX: u8 = 1;
/// VTK cell types used here.
pub const VTK_TRIANGLE: u8 = 5;
/// VTK cell types used here.
pub const VTK_TETRA: u8 = 10;

/// One unstructured grid: `points` (3 per point, m), cells as VTK's three arrays
/// (`connectivity`, `offsets` = end of each cell in `connectivity`, `types`), point and cell
/// data. The first 3-component point array is marked as the `Vectors` attribute (ParaView's
/// "Warp By Vector" picks it).
#[derive(Clone, Copy, Debug)]
pub struct UnstructuredGrid<'a> {
    pub points: &'a [f64],
    pub connectivity: &'a [u64],
    pub offsets: &'a [u64],
    pub types: &'a [u8],
    pub point_data: &'a [DataArray<'a>],
    pub cell_data: &'a [DataArray<'a>],
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn data_array(s: &mut String, name: Option<&str>, components: usize, values: Values) {
    let kind = match values {
        Values::F64(_) => "Float64",
        Values::U64(_) => "UInt64",
        Values::U32(_) => "UInt32",
        Values::U8(_) => "UInt8",
    };
    s.push_str("<DataArray type=\"");
    s.push_str(kind);
    s.push('"');
    if let Some(name) = name {
        let _ = write!(s, " Name=\"{}\"", xml_escape(name));
    }
    if components != 1 {
        let _ = write!(s, " NumberOfComponents=\"{components}\"");
    }
    s.push_str(" format=\"ascii\">\n");
    let per_line = components.max(1);
    let line = |k: usize, s: &mut String| {
        s.push(if (k + 1).is_multiple_of(per_line) {
            '\n'
        } else {
            ' '
        });
    };
    match values {
        Values::F64(v) => v.iter().enumerate().for_each(|(k, x)| {
            let _ = write!(s, "{x:e}");
            line(k, s)
        }),
        Values::U64(v) => v.iter().enumerate().for_each(|(k, x)| {
            let _ = write!(s, "{x}");
            line(k, s)
        }),
        Values::U32(v) => v.iter().enumerate().for_each(|(k, x)| {
            let _ = write!(s, "{x}");
            line(k, s)
        }),
        Values::U8(v) => v.iter().enumerate().for_each(|(k, x)| {
            let _ = write!(s, "{x}");
            line(k, s)
        }),
    }
    s.push_str("</DataArray>\n");
}

impl UnstructuredGrid<'_> {
    /// The `.vtu` document.
    pub fn to_xml(&self) -> String {
        let mut s = String::with_capacity(40 * self.points.len() + 16 * self.connectivity.len());
        s.push_str(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" \
             byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n",
        );
        let _ = writeln!(
            s,
            "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
            self.points.len() / 3,
            self.types.len()
        );
        match self.point_data.iter().find(|a| a.components == 3) {
            Some(v) => {
                let _ = writeln!(s, "<PointData Vectors=\"{}\">", xml_escape(v.name));
            }
            None => s.push_str("<PointData>\n"),
        }
        for a in self.point_data {
            data_array(&mut s, Some(a.name), a.components, a.values);
        }
        s.push_str("</PointData>\n<CellData>\n");
        for a in self.cell_data {
            data_array(&mut s, Some(a.name), a.components, a.values);
        }
        s.push_str("</CellData>\n<Points>\n");
        data_array(&mut s, None, 3, Values::F64(self.points));
        s.push_str("</Points>\n<Cells>\n");
        data_array(
            &mut s,
            Some("connectivity"),
            1,
            Values::U64(self.connectivity),
        );
        data_array(&mut s, Some("offsets"), 1, Values::U64(self.offsets));
        data_array(&mut s, Some("types"), 1, Values::U8(self.types));
        s.push_str("</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
        s
    }
}

/// A `.pvd` collection of (time in s, file path relative to the collection file).
pub fn collection(entries: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"1.0\" \
         byte_order=\"LittleEndian\">\n<Collection>\n",
    );
    for (t, file) in entries {
        let _ = writeln!(
            s,
            "<DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{}\"/>",
            xml_escape(file)
        );
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    s
}
