#!/usr/bin/env python3
"""Regenerate the committed gmsh meshes (needs the `gmsh` Python module: `pip install gmsh`).

    python3 scripts/gen_meshes.py            # everything
    python3 scripts/gen_meshes.py fixtures   # compiler/tests/fixtures/cube_*.msh only
    python3 scripts/gen_meshes.py cantilever # models/cantilever/cantilever.msh only

Fixtures: the unit cube [0,1]^3 split into the 6 Kuhn tetrahedra (all share the diagonal
(0,0,0)-(1,1,1), each of volume 1/6), written as MSH 4.1 ASCII, MSH 4.1 binary and MSH 2.2 ASCII
from the same gmsh model, so the three files describe the same mesh. Physical groups:
  dim 3 tag 1 "body"      all 6 tets
  dim 2 tag 2 "bottom"    the 2 triangles on z = 0
  dim 2 tag 3 "top"       the 2 triangles on z = 1
  dim 2 tag 4 "boundary"  all 12 boundary triangles (shares the bottom/top entities)
  dim 1 tag 5 "edge"      the line element (0,0,0)-(1,0,0)
  dim 0 tag 6 "corner"    the point element at (0,0,0)
  dim 2 tag 7 (no name)   the 8 side triangles, to exercise the "<dim>:<tag>" fallback name

Cantilever: runs models/cantilever/cantilever.geo and saves MSH 4.1 ASCII.
"""

import itertools
import os
import sys

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import kuhn_cube  # noqa: E402

ROOT = os.path.dirname(HERE)
FIXTURES = os.path.join(ROOT, "compiler", "tests", "fixtures")
CANTILEVER = os.path.join(ROOT, "models", "cantilever")


def cube_tets():
    """Node tags 1..8 of the cube corners (tag = 1 + i + 2j + 4k) and the 6 Kuhn tets."""
    coords, tets = kuhn_cube()
    return coords, [[t + 1 for t in tet] for tet in tets]


def boundary_faces(coords, tets):
    """Faces used by exactly one tet, as sorted node-tag triples."""
    count = {}
    for t in tets:
        for f in itertools.combinations(t, 3):
            key = tuple(sorted(f))
            count[key] = count.get(key, 0) + 1
    return [f for f, c in sorted(count.items()) if c == 1]


def write_fixtures():
    os.makedirs(FIXTURES, exist_ok=True)
    write_cube("cube", lambda t: t, reverse=False, outputs=(
        ("cube_41_ascii.msh", 4.1, 0),
        ("cube_41_binary.msh", 4.1, 1),
        ("cube_22_ascii.msh", 2.2, 0),
    ))
    # Sparse node tags (10, 20, ..., 80): mshio keeps the tags.
    write_cube("sparse", lambda t: 10 * t, reverse=False, outputs=(
        ("cube_41_sparse_ascii.msh", 4.1, 0),
    ))
    # Contiguous tags listed in reverse order (8, 7, ..., 1): mshio drops the tags, the reader
    # must take them from the file rather than assume 1, 2, ....
    write_cube("reversed", lambda t: t, reverse=True, outputs=(
        ("cube_41_reversed_ascii.msh", 4.1, 0),
        ("cube_41_reversed_binary.msh", 4.1, 1),
    ))


def write_cube(model, retag, reverse, outputs):
    coords, tets = cube_tets()
    faces = boundary_faces(coords, tets)

    def on_plane(f, axis, value):
        return all(coords[t - 1][axis] == value for t in f)

    bottom = [f for f in faces if on_plane(f, 2, 0.0)]
    top = [f for f in faces if on_plane(f, 2, 1.0)]
    sides = [f for f in faces if f not in bottom and f not in top]
    assert len(faces) == 12 and len(bottom) == 2 and len(top) == 2

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add(model)
    # Discrete entities: point 1, curve 1, surfaces 1 (bottom), 2 (top), 3 (sides), volume 1.
    gmsh.model.addDiscreteEntity(0, 1)
    gmsh.model.addDiscreteEntity(1, 1)
    for s in (1, 2, 3):
        gmsh.model.addDiscreteEntity(2, s)
    gmsh.model.addDiscreteEntity(3, 1)
    # All nodes on the volume entity (classification does not matter for the reader).
    order = list(range(1, 9))
    if reverse:
        order.reverse()
    gmsh.model.mesh.addNodes(
        3, 1, [retag(t) for t in order], [c for t in order for c in coords[t - 1]]
    )
    etag = 1
    gmsh.model.mesh.addElementsByType(1, 15, [etag], [retag(1)])
    etag += 1
    gmsh.model.mesh.addElementsByType(1, 1, [etag], [retag(1), retag(2)])
    etag += 1
    for s, fs in ((1, bottom), (2, top), (3, sides)):
        tags = list(range(etag, etag + len(fs)))
        etag += len(fs)
        gmsh.model.mesh.addElementsByType(s, 2, tags, [retag(t) for f in fs for t in f])
    gmsh.model.mesh.addElementsByType(
        1, 4, list(range(etag, etag + len(tets))), [retag(t) for tet in tets for t in tet]
    )
    gmsh.model.addPhysicalGroup(3, [1], 1, "body")
    gmsh.model.addPhysicalGroup(2, [1], 2, "bottom")
    gmsh.model.addPhysicalGroup(2, [2], 3, "top")
    gmsh.model.addPhysicalGroup(2, [1, 2, 3], 4, "boundary")
    gmsh.model.addPhysicalGroup(1, [1], 5, "edge")
    gmsh.model.addPhysicalGroup(0, [1], 6, "corner")
    gmsh.model.addPhysicalGroup(2, [3], 7)

    for name, version, binary in outputs:
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.option.setNumber("Mesh.Binary", binary)
        gmsh.write(os.path.join(FIXTURES, name))
    gmsh.finalize()


def write_cantilever():
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.open(os.path.join(CANTILEVER, "cantilever.geo"))
    gmsh.model.mesh.generate(3)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.write(os.path.join(CANTILEVER, "cantilever.msh"))
    types, tags, _ = gmsh.model.mesh.getElements(3)
    n = sum(len(t) for t in tags)
    print(f"cantilever: {n} tetrahedra, {len(gmsh.model.mesh.getNodes()[0])} nodes")
    gmsh.finalize()


if __name__ == "__main__":
    what = sys.argv[1:] or ["fixtures", "cantilever"]
    if "fixtures" in what:
        write_fixtures()
    if "cantilever" in what:
        write_cantilever()
