#!/usr/bin/env python3
"""Generate models/tentacle/tentacle.msh, the irregular example (needs the `gmsh` Python module:
`pip install gmsh`; runs headless).

    python3 scripts/gen_tentacle.py            # build the shape, mesh, write, check
    python3 scripts/gen_tentacle.py --check    # check the committed mesh only

Shape (OpenCASCADE kernel, metres): a soft dome-shaped body (half ellipsoid, semi-axes
40 x 35 x 30 mm, flat base on z = 0) with two side lobes (spheres of radius 17 mm) and a curved,
tapered limb (truncated cones and joint spheres, radius 13 mm down to 7 mm, along a bent path
rising out of the top of the body and curving towards +x) ending in a knob (sphere of radius 11 mm). Everything is
fused into one volume.

The mesh has one physical group only, the volume "tissue": the scene fixes the base and loads the
knob with geometric selections (half-space and sphere), not with named surface groups.
MSH 4.1 ASCII, Mesh.SaveAll = 0, linear tetrahedra, optimised (gmsh's default tetrahedral
optimiser plus Netgen).

Checks on the written file (parsed here independently of gmsh): every tetrahedron positively
oriented, the number of tetrahedra (<= 6,000), the volume against the gmsh-reported volume of the
CAD solid (a mesh of a curved body is a little smaller), and that the base plane z = 0 and the
knob's sphere both contain boundary nodes. Exit status 1 on any failed check.
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import read_msh41, tet_census  # noqa: E402

ROOT = os.path.dirname(HERE)
MODEL = os.path.join(ROOT, "models", "tentacle")
MSH = os.path.join(MODEL, "tentacle.msh")

# Geometry, metres.
BODY = (0.040, 0.035, 0.030)          # semi-axes of the body ellipsoid, centred at the origin
LOBE_R = 0.017
LOBES = [(0.0, 0.032, 0.010), (0.0, -0.032, 0.010)]
LIMB_R0, LIMB_R1 = 0.013, 0.007       # limb radius at its root and at its end
KNOB_R = 0.011
MESH_SIZE = 0.0062                    # target edge length, m
MAX_TETS = 6000


def limb_path(t):
    """Centre of the limb's section at t in [0, 1]: rises from inside the body, bends to +x."""
    x = 0.085 * t * t
    z = 0.018 + 0.085 * t - 0.030 * t * t
    return (x, 0.0, z)


def generate():
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", int(os.environ.get("GMSH_VERBOSE", "0")))
    gmsh.model.add("tentacle")
    occ = gmsh.model.occ

    body = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, body)], 0, 0, 0, *BODY)
    lobes = [occ.addSphere(*c, LOBE_R) for c in LOBES]

    # The limb: a chain of truncated cones along the path, with a sphere at every joint (a loft
    # of circles self-intersected in OCC's boundary recovery; primitives fuse robustly).
    limb = []
    segments = 8
    for k in range(segments):
        t0, t1 = k / segments, (k + 1) / segments
        c0, c1 = limb_path(t0), limb_path(t1)
        r0 = LIMB_R0 + (LIMB_R1 - LIMB_R0) * t0
        r1 = LIMB_R0 + (LIMB_R1 - LIMB_R0) * t1
        axis = [c1[i] - c0[i] for i in range(3)]
        limb.append((3, occ.addCone(*c0, *axis, r0, r1)))
        if k > 0:
            limb.append((3, occ.addSphere(*c0, r0)))
    end = limb_path(1.0)
    knob = occ.addSphere(*end, KNOB_R)

    tools = [(3, t) for t in lobes] + limb + [(3, knob)]
    fused, _ = occ.fuse([(3, body)], tools)
    # Flat base: keep z >= 0.
    cutter = occ.addBox(-1, -1, -1, 2, 2, 1)
    shape, _ = occ.cut(fused, [(3, cutter)])
    occ.synchronize()
    volumes = [t for d, t in shape if d == 3]
    if len(volumes) != 1:
        raise SystemExit(f"expected one fused volume, got {len(volumes)}")
    cad_volume = occ.getMass(3, volumes[0])
    gmsh.model.addPhysicalGroup(3, volumes, name="tissue")

    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * MESH_SIZE)
    gmsh.option.setNumber("Mesh.MeshSizeMax", MESH_SIZE)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 12)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("")
    gmsh.model.mesh.optimize("Netgen")
    _, tags, _ = gmsh.model.mesh.getElements(3)
    q = gmsh.model.mesh.getElementQualities(list(tags[0]), "gamma")
    print(f"gmsh: {len(q)} tetrahedra, quality gamma min {min(q):.3f}, mean {sum(q) / len(q):.3f}")
    print(f"CAD volume {cad_volume:.6e} m^3")
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    os.makedirs(MODEL, exist_ok=True)
    gmsh.write(MSH)
    gmsh.finalize()
    return cad_volume


def check(cad_volume=None):
    mesh = read_msh41(MSH)
    nodes, tets = mesh.nodes, mesh.tets
    ok = True
    total, worst, boundary = tet_census(nodes, tets)
    print(f"{len(tets)} tetrahedra, {len(nodes)} nodes, {len(boundary)} boundary nodes, "
          f"volume {total:.6e} m^3, smallest signed volume {worst:.3e} m^3")
    if worst <= 0.0:
        print("FAIL: inverted or degenerate tetrahedron")
        ok = False
    if len(tets) > MAX_TETS:
        print(f"FAIL: more than {MAX_TETS} tetrahedra")
        ok = False
    if cad_volume is not None:
        rel = (total - cad_volume) / cad_volume
        print(f"mesh volume / CAD volume - 1 = {rel:+.3%}")
        if abs(rel) > 0.02:
            print("FAIL: mesh volume more than 2 % off the CAD volume")
            ok = False
    base = [n for n in boundary if abs(nodes[n][2]) < 1e-9]
    end = limb_path(1.0)
    knob = [n for n in boundary
            if math.dist(nodes[n], end) < KNOB_R * 1.05 and nodes[n][0] > end[0]]
    xs = [p[0] for p in nodes.values()]
    zs = [p[2] for p in nodes.values()]
    print(f"base (z = 0) boundary nodes: {len(base)}; knob (outer half) boundary nodes: "
          f"{len(knob)}; extent x [{min(xs):.4f}, {max(xs):.4f}] z [{min(zs):.4f}, {max(zs):.4f}] m")
    if not base or not knob:
        print("FAIL: the base plane or the knob has no boundary nodes")
        ok = False
    return ok


def main():
    cad = None
    if "--check" not in sys.argv[1:]:
        cad = generate()
    sys.exit(0 if check(cad) else 1)


if __name__ == "__main__":
    main()
