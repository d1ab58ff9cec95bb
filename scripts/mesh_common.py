"""Mesh helpers shared by the scripts in this folder (plain Python, no numpy, no gmsh).

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # in a script of scripts/
    from mesh_common import read_msh41, tet_census, kuhn_cube

- read_msh41(path): a gmsh MSH 4.1 ASCII file, parsed independently of gmsh (the generators
  check what gmsh wrote with it). It reads the node coordinates of $Nodes, the elements of
  $Elements, the names of $PhysicalNames and, through the physical tags of $Entities, the
  elements of each physical group; it ignores every other section ($PartitionedEntities,
  $Periodic, $NodeData, ...) and parametric node coordinates are not supported.
  It refuses (SystemExit naming the file) a file that is not UTF-8 text (MSH 4.1 binary), has
  no $MeshFormat (MSH 1.0) or another version than 4.1 ASCII (MSH 2.2, 4.0), has a section
  without its $End line, or has no $Nodes or no $Elements. A file without $PhysicalNames or $Entities
  (gmsh writes every element then) reads with no names and no groups.
- tet_census(nodes, tets): total and smallest signed volume, and the boundary nodes.
- kuhn_cube(): the unit cube split into its 6 Kuhn tetrahedra (the test fixtures' cube).

Not to be confused with the Rust crate `mshio` the compiler reads meshes with.
"""

import itertools
from typing import NamedTuple


class Msh41(NamedTuple):
    nodes: dict   # {node tag: (x, y, z)}, in file order
    tets: list    # [(n0, n1, n2, n3)]: every linear tetrahedron (element type 4), in file order
    names: dict   # {(dim, physical tag): name} of $PhysicalNames, in file order
    groups: dict  # {name: (dim, element type of its first block, [node-tag tuples])}; a
                  # physical group without a name is named "<dim>:<tag>"


def read_msh41(path):
    """Nodes, tetrahedra, physical names and physical groups of an MSH 4.1 ASCII file."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = [l.strip() for l in f]
    except UnicodeDecodeError:
        raise SystemExit(f"{path}: not a text file (MSH 4.1 binary?); expected MSH 4.1 ASCII")
    if "$MeshFormat" not in lines:
        raise SystemExit(f"{path}: no $MeshFormat (MSH 1.0?); expected MSH 4.1 ASCII")
    sections = {}
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("$") and not line.startswith("$End"):
            name = line[1:]
            try:
                j = lines.index("$End" + name, i)
            except ValueError:
                raise SystemExit(f"{path}: ${name} without $End{name}")
            sections[name] = lines[i + 1:j]
            i = j
        i += 1
    fmt = (sections.get("MeshFormat") or [""])[0].split()
    if fmt[:2] != ["4.1", "0"]:
        raise SystemExit(f"{path}: expected MSH 4.1 ASCII, got {fmt}")
    for name in ("Nodes", "Elements"):
        if name not in sections:
            raise SystemExit(f"{path}: no ${name} section")

    names = {}
    for line in sections.get("PhysicalNames", [])[1:]:
        dim, tag, name = line.split(maxsplit=2)
        names[(int(dim), int(tag))] = name.strip('"')

    # $Entities: physical tags of each (dim, entity tag).
    phys = {}
    ent = sections.get("Entities")
    if ent:
        counts = [int(v) for v in ent[0].split()]
        row = 1
        for dim in range(4):
            for _ in range(counts[dim]):
                v = ent[row].split()
                row += 1
                tag = int(v[0])
                k = 4 if dim == 0 else 7  # point: tag x y z; others: tag + bounding box
                nphys = int(v[k])
                phys[(dim, tag)] = [int(t) for t in v[k + 1:k + 1 + nphys]]

    nodes = {}
    nd = sections["Nodes"]
    nblocks = int(nd[0].split()[0])
    row = 1
    for _ in range(nblocks):
        _, _, _, n = (int(v) for v in nd[row].split())
        row += 1
        tags = [int(nd[row + k]) for k in range(n)]
        row += n
        for k in range(n):
            nodes[tags[k]] = tuple(float(v) for v in nd[row + k].split())
        row += n

    tets = []
    groups = {}
    el = sections["Elements"]
    nblocks = int(el[0].split()[0])
    row = 1
    for _ in range(nblocks):
        dim, etag, etype, n = (int(v) for v in el[row].split())
        row += 1
        conn = [tuple(int(v) for v in el[row + k].split()[1:]) for k in range(n)]
        row += n
        if etype == 4:
            tets.extend(conn)
        for p in phys.get((dim, etag), []):
            name = names.get((dim, p), f"{dim}:{p}")
            groups.setdefault(name, (dim, etype, []))[2].extend(conn)
    return Msh41(nodes, tets, names, groups)


def tet_census(nodes, tets):
    """(total signed volume, smallest signed volume, boundary node tags) of tetrahedra given by
    node tags: a signed volume is det[x1-x0, x2-x0, x3-x0] / 6, a boundary node one of a face
    that only one tetrahedron has."""
    total, worst = 0.0, float("inf")
    faces = {}
    for t in tets:
        a, b, c, d = (nodes[n] for n in t)
        u = [b[k] - a[k] for k in range(3)]
        v = [c[k] - a[k] for k in range(3)]
        w = [d[k] - a[k] for k in range(3)]
        det = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
               + u[2] * (v[0] * w[1] - v[1] * w[0]))
        total += det / 6.0
        worst = min(worst, det / 6.0)
        for f in ((t[0], t[1], t[2]), (t[0], t[1], t[3]), (t[0], t[2], t[3]), (t[1], t[2], t[3])):
            key = tuple(sorted(f))
            faces[key] = faces.get(key, 0) + 1
    boundary = {n for f, k in faces.items() if k == 1 for n in f}
    return total, worst, boundary


def kuhn_cube():
    """The unit cube [0,1]^3 split into its 6 Kuhn tetrahedra (all share the diagonal
    (0,0,0)-(1,1,1), each of volume 1/6): the corner coordinates, corner p = i + 2j + 4k at
    (i, j, k), and the tetrahedra as lists of 0-based corner indices, each positively oriented
    (det[x1-x0, x2-x0, x3-x0] > 0)."""
    coords = []
    for k in (0, 1):
        for j in (0, 1):
            for i in (0, 1):
                coords.append((float(i), float(j), float(k)))

    def corner(p):
        return p[0] + 2 * p[1] + 4 * p[2]

    tets = []
    for perm in itertools.permutations(range(3)):
        p = [0, 0, 0]
        path = [corner(p)]
        for axis in perm:
            p[axis] = 1
            path.append(corner(p))
        x = [coords[t] for t in path]
        d = [[x[r][c] - x[0][c] for c in range(3)] for r in (1, 2, 3)]
        det = (
            d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1])
            - d[0][1] * (d[1][0] * d[2][2] - d[1][2] * d[2][0])
            + d[0][2] * (d[1][0] * d[2][1] - d[1][1] * d[2][0])
        )
        if det < 0:
            path[2], path[3] = path[3], path[2]
        tets.append(path)
    return coords, tets
