//! The one VTK XML writer (`crokf_formats::vtk`, used by `crokf-run --vtu` and the reference
//! series of `crokf-verify`) read back by an independent reader, `vtkio`: points, cells and
//! every data array come back exactly.

use crokf_formats::vtk::{self, DataArray, UnstructuredGrid, Values};
use vtkio::model::{Attribute, CellType, DataSet, IOBuffer, Piece, VertexNumbers};

fn parse(xml: &str) -> vtkio::model::UnstructuredGridPiece {
    let vtk = vtkio::Vtk::parse_xml(xml.as_bytes()).expect("vtkio reads the document");
    let DataSet::UnstructuredGrid { mut pieces, .. } = vtk.data else {
        panic!("not an unstructured grid")
    };
    assert_eq!(pieces.len(), 1);
    match pieces.remove(0) {
        Piece::Inline(p) => *p,
        _ => panic!("piece not inline"),
    }
}

fn array(attributes: &[Attribute], name: &str) -> IOBuffer {
    attributes
        .iter()
        .find_map(|a| match a {
            Attribute::DataArray(d) if d.name == name => Some(d.data.clone()),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no array {name}"))
}

#[test]
fn tetrahedra_with_displacement_read_back_exactly() {
    // Values that need all 17 significant digits, and a negative zero.
    let points = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.1, 0.2, 1.0 / 3.0],
        [1.0, 1.0, 1.0],
    ];
    let tets = [[0, 1, 2, 3], [1, 2, 3, 4]];
    let d: Vec<[f64; 3]> = (0..5)
        .map(|i| [1e-7 * i as f64, -0.0, std::f64::consts::PI * i as f64])
        .collect();
    let xml = crokf_verify::vtu::vtu(&points, &tets, &d);
    let p = parse(&xml);
    let IOBuffer::F64(coords) = p.points else {
        panic!("points not f64")
    };
    assert_eq!(coords, points.iter().flatten().copied().collect::<Vec<_>>());
    assert_eq!(p.cells.types, vec![CellType::Tetra; 2]);
    match p.cells.cell_verts {
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            assert_eq!(connectivity, vec![0, 1, 2, 3, 1, 2, 3, 4]);
            assert_eq!(offsets, vec![4, 8]);
        }
        other => panic!("{other:?}"),
    }
    let IOBuffer::F64(u) = array(&p.data.point, "displacement") else {
        panic!("f64")
    };
    assert_eq!(u, d.iter().flatten().copied().collect::<Vec<_>>());
}

#[test]
fn triangles_vertices_and_integer_arrays_read_back_exactly() {
    let points: Vec<f64> = (0..12).map(|i| i as f64 * 0.25).collect();
    let (conn, offsets, types) = (
        [0u64, 1, 2, 3],
        [3u64, 4],
        [vtk::VTK_TRIANGLE, vtk::VTK_VERTEX],
    );
    let (tags, sets, cell_sets) = ([7u64, 8, 9, u64::MAX], [0u32, 0, 0, 1], [0u32, 1]);
    let xml = UnstructuredGrid {
        points: &points,
        connectivity: &conn,
        offsets: &offsets,
        types: &types,
        point_data: &[
            DataArray {
                name: "node_tag",
                components: 1,
                values: Values::U64(&tags),
            },
            DataArray {
                name: "node_set",
                components: 1,
                values: Values::U32(&sets),
            },
        ],
        cell_data: &[DataArray {
            name: "node_set & <set>",
            components: 1,
            values: Values::U32(&cell_sets),
        }],
    }
    .to_xml();
    let p = parse(&xml);
    assert_eq!(p.cells.types, vec![CellType::Triangle, CellType::Vertex]);
    assert!(matches!(array(&p.data.point, "node_tag"), IOBuffer::U64(v) if v == tags));
    assert!(matches!(array(&p.data.point, "node_set"), IOBuffer::U32(v) if v == sets));
    assert!(matches!(array(&p.data.cell, "node_set & <set>"), IOBuffer::U32(v) if v == cell_sets));
}

#[test]
fn the_collection_lists_every_file_with_its_time() {
    let xml = vtk::collection(&[
        (0.0, "step_000000.vtu".into()),
        (0.005, "a&b \"c\".vtu".into()),
    ]);
    assert!(
        xml.contains("<DataSet timestep=\"0e0\" group=\"\" part=\"0\" file=\"step_000000.vtu\"/>")
    );
    assert!(xml.contains("timestep=\"5e-3\""));
    assert!(xml.contains("file=\"a&amp;b &quot;c&quot;.vtu\""));
}
