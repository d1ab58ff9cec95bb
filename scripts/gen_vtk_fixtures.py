#!/usr/bin/env python3
"""Regenerate the VTK and MSH 1.0 test fixtures (compiler/tests/fixtures/cube_*.vtu, .vtk and
cube_10.msh). Needs `pip install meshio gmsh`.

    python3 scripts/gen_vtk_fixtures.py

The mesh is the fixture cube of scripts/gen_meshes.py: the unit cube split into its 6 Kuhn
tetrahedra, point id k (0-based) at corner (i, j, k) with k = i + 2j + 4k', every tetrahedron of
volume 1/6, plus the 2 bottom triangles (z = 0). Cell data "MaterialIds" (Int32): tetrahedra 0-2
take 1, tetrahedra 3-5 take 2, the triangles 7; "Quality" (Float64) is not a group.

Files (all the same mesh):
  cube_ascii.vtu      meshio, ASCII data arrays
  cube_zlib.vtu       meshio, base64 binary, zlib compressed
  cube_appended.vtu   written here: raw appended data (UInt64 headers), no compression
  cube_ascii.vtk      meshio, legacy VTK 4.2 ASCII (cell data as a FIELD)
  cube_binary.vtk     meshio, legacy VTK 4.2 binary (big-endian)
  cube_10.msh         gmsh, MSH 1.0, from cube_41_ascii.msh (physical tags, no names)
"""

import os
import struct
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import kuhn_cube  # noqa: E402

ROOT = os.path.dirname(HERE)
FIXTURES = os.path.join(ROOT, "compiler", "tests", "fixtures")


def cube():
    coords, tets = kuhn_cube()
    bottom = [[0, 1, 3], [0, 3, 2]]
    return np.array(coords), np.array(tets), np.array(bottom)


def write_meshio(points, tets, tris):
    import meshio

    mesh = meshio.Mesh(
        points,
        [("tetra", tets), ("triangle", tris)],
        cell_data={
            "MaterialIds": [np.array([1, 1, 1, 2, 2, 2], dtype=np.int32),
                            np.array([7, 7], dtype=np.int32)],
            "Quality": [np.linspace(0.5, 1.0, 6), np.array([1.0, 1.0])],
        },
    )
    meshio.write(os.path.join(FIXTURES, "cube_ascii.vtu"), mesh, binary=False)
    meshio.write(os.path.join(FIXTURES, "cube_zlib.vtu"), mesh, binary=True, compression="zlib")
    meshio.vtk.write(os.path.join(FIXTURES, "cube_ascii.vtk"), mesh, binary=False,
                     fmt_version="4.2")
    meshio.vtk.write(os.path.join(FIXTURES, "cube_binary.vtk"), mesh, binary=True,
                     fmt_version="4.2")


def write_appended(points, tets, tris):
    """A VTU with raw appended data: each block is a UInt64 byte count then the values."""
    conn = np.concatenate([tets.ravel(), tris.ravel()]).astype(np.int64)
    offsets = np.cumsum([4] * len(tets) + [3] * len(tris)).astype(np.int64)
    types = np.array([10] * len(tets) + [5] * len(tris), dtype=np.uint8)
    ids = np.array([1, 1, 1, 2, 2, 2, 7, 7], dtype=np.int32)
    arrays = [
        ("Points", "Float64", 3, points.astype("<f8").tobytes()),
        ("connectivity", "Int64", 1, conn.astype("<i8").tobytes()),
        ("offsets", "Int64", 1, offsets.astype("<i8").tobytes()),
        ("types", "UInt8", 1, types.tobytes()),
        ("MaterialIds", "Int32", 1, ids.astype("<i4").tobytes()),
    ]
    offset = 0
    tags = {}
    blob = b""
    for name, _, _, data in arrays:
        tags[name] = offset
        block = struct.pack("<Q", len(data)) + data
        blob += block
        offset += len(block)

    def da(name, typ, comps):
        return (f'<DataArray type="{typ}" Name="{name}" NumberOfComponents="{comps}" '
                f'format="appended" offset="{tags[name]}"/>')

    xml = f"""<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">
<UnstructuredGrid>
<Piece NumberOfPoints="{len(points)}" NumberOfCells="{len(tets) + len(tris)}">
<Points>
{da("Points", "Float64", 3)}
</Points>
<Cells>
{da("connectivity", "Int64", 1)}
{da("offsets", "Int64", 1)}
{da("types", "UInt8", 1)}
</Cells>
<CellData>
{da("MaterialIds", "Int32", 1)}
</CellData>
</Piece>
</UnstructuredGrid>
<AppendedData encoding="raw">
_"""
    with open(os.path.join(FIXTURES, "cube_appended.vtu"), "wb") as f:
        f.write(xml.encode() + blob + b"\n</AppendedData>\n</VTKFile>\n")


def write_msh1():
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.open(os.path.join(FIXTURES, "cube_41_ascii.msh"))
    gmsh.option.setNumber("Mesh.MshFileVersion", 1.0)
    gmsh.write(os.path.join(FIXTURES, "cube_10.msh"))
    gmsh.finalize()


def main():
    points, tets, tris = cube()
    write_meshio(points, tets, tris)
    write_appended(points, tets, tris)
    write_msh1()
    for f in sorted(os.listdir(FIXTURES)):
        if f.startswith("cube_") and not f.startswith("cube_4") and not f.startswith("cube_22"):
            print(f, os.path.getsize(os.path.join(FIXTURES, f)), "bytes")


if __name__ == "__main__":
    main()
