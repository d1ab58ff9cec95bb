#!/usr/bin/env python3
"""Generate models/quickstart/: the bring-your-own-mesh example of the README (needs the `gmsh`
Python module: `pip install gmsh`; runs headless).

    python3 scripts/gen_quickstart.py mesh       # mesh the finger, write finger.msh, check it
    python3 scripts/gen_quickstart.py --check    # check the committed mesh only
    python3 scripts/gen_quickstart.py data BIN   # write inputs.csv and measurements.csv, BIN
                                                 # the folder holding crokf-verify

The body (OpenCASCADE kernel, millimetres, as a CAD export often is): a soft finger standing
on a flattened foot, three phalanges of decreasing radius (8.5, 7.5, 6.5 mm) along a path that
rises 70 mm and bends towards +x, a rounded tip. The file has NO physical groups (gmsh then
writes every element: points, lines, triangles and tetrahedra, tagged by their geometric
entities): the scene takes the material, the clamped foot, the pushed tip and the displayed
sets with geometric selections, as it would for a mesh from elsewhere. MSH 4.1 ASCII, linear
tetrahedra, optimised (gmsh's optimiser plus Netgen).

`data` makes the recording the quickstart replays: the full-order co-rotational FEM of the
scene through scenario.toml (`crokf-verify simulate --model corotational`) stands in for the
real finger; measurements.csv holds its marker displacements plus Gaussian noise of the
scene's σ (fixed seed), inputs.csv zeros (the push is not told to the runtime: the filter
estimates it from the markers).

Checks on the written mesh (parsed here independently of gmsh): no physical group, every
tetrahedron positively oriented, fewer than 3,000 tetrahedra, the volume within 5 % of the CAD
volume (a coarse mesh of a curved body is a few per cent smaller), boundary nodes on the foot plane z = 0 and on the tip's sphere.
"""

import csv
import math
import os
import random
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import read_msh41, tet_census  # noqa: E402

ROOT = os.path.dirname(HERE)
MODEL = os.path.join(ROOT, "models", "quickstart")
MSH = os.path.join(MODEL, "finger.msh")
MAX_TETS = 3000

# Geometry, millimetres.
FOOT = (16.0, 13.0, 6.0)              # semi-axes of the foot ellipsoid at the origin (cut at z = 0)
PHALANGES = [(0.0, 0.3, 8.5), (0.3, 0.65, 7.5), (0.65, 1.0, 6.5)]   # t0, t1, radius
TIP_R = 6.5
MESH_SIZE = 5.0                       # target edge length, mm
NOISE_SEED = 27


def finger_path(t):
    """Centre line of the finger at t in [0, 1], mm: rises from the foot, bends towards +x."""
    return (22.0 * t * t, 0.0, 70.0 * t - 6.0 * t * t + 2.0)


def generate():
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", int(os.environ.get("GMSH_VERBOSE", "0")))
    gmsh.model.add("finger")
    occ = gmsh.model.occ

    foot = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, foot)], 0, 0, 0, *FOOT)
    parts = []
    for t0, t1, r in PHALANGES:
        # Each phalanx: a slightly waisted segment (two cones) with a knuckle sphere at its start.
        tm = 0.5 * (t0 + t1)
        for a, b, ra, rb in ((t0, tm, r, 0.88 * r), (tm, t1, 0.88 * r, r)):
            c0, c1 = finger_path(a), finger_path(b)
            axis = [c1[i] - c0[i] for i in range(3)]
            parts.append((3, occ.addCone(*c0, *axis, ra, rb)))
        parts.append((3, occ.addSphere(*finger_path(t0), r)))
    parts.append((3, occ.addSphere(*finger_path(1.0), TIP_R)))
    fused, _ = occ.fuse([(3, foot)], parts)
    cutter = occ.addBox(-100, -100, -100, 200, 200, 100)     # keep z >= 0: the flat foot
    shape, _ = occ.cut(fused, [(3, cutter)])
    occ.synchronize()
    volumes = [t for d, t in shape if d == 3]
    if len(volumes) != 1:
        raise SystemExit(f"expected one fused volume, got {len(volumes)}")
    cad_volume = occ.getMass(3, volumes[0])
    # No physical group: the point of this example.

    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.6 * MESH_SIZE)
    gmsh.option.setNumber("Mesh.MeshSizeMax", MESH_SIZE)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 12)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("")
    gmsh.model.mesh.optimize("Netgen")
    _, tags, _ = gmsh.model.mesh.getElements(3)
    q = gmsh.model.mesh.getElementQualities(list(tags[0]), "gamma")
    print(f"gmsh: {len(q)} tetrahedra, quality gamma min {min(q):.3f}, mean {sum(q) / len(q):.3f}")
    print(f"CAD volume {cad_volume:.1f} mm^3")
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    os.makedirs(MODEL, exist_ok=True)
    gmsh.write(MSH)
    gmsh.finalize()
    return cad_volume


def check(cad_volume=None):
    mesh = read_msh41(MSH)
    nodes, tets = mesh.nodes, mesh.tets
    # The physical names as the lines of $PhysicalNames ('3 1 "tissue"'), for the message.
    names = [f'{dim} {tag} "{name}"' for (dim, tag), name in mesh.names.items()]
    ok = True
    total, worst, boundary = tet_census(nodes, tets)
    print(f"{len(tets)} tetrahedra, {len(nodes)} nodes, {len(boundary)} boundary nodes, "
          f"volume {total:.1f} mm^3, smallest signed volume {worst:.3e} mm^3")
    if names:
        print(f"FAIL: the mesh has physical names {names}; the example is a mesh without them")
        ok = False
    if worst <= 0.0:
        print("FAIL: inverted or degenerate tetrahedron")
        ok = False
    if len(tets) >= MAX_TETS:
        print(f"FAIL: {MAX_TETS} tetrahedra or more")
        ok = False
    if cad_volume is not None:
        rel = (total - cad_volume) / cad_volume
        print(f"mesh volume / CAD volume - 1 = {rel:+.3%}")
        if abs(rel) > 0.05:
            print("FAIL: mesh volume more than 5 % off the CAD volume")
            ok = False
    foot = [n for n in boundary if abs(nodes[n][2]) < 1e-9]
    end = finger_path(1.0)
    tip = [n for n in boundary if math.dist(nodes[n], end) < TIP_R * 1.05]
    xs = [p[0] for p in nodes.values()]
    zs = [p[2] for p in nodes.values()]
    print(f"foot (z = 0) boundary nodes: {len(foot)}; tip boundary nodes: {len(tip)}; "
          f"extent x [{min(xs):.1f}, {max(xs):.1f}] z [{min(zs):.1f}, {max(zs):.1f}] mm")
    if not foot or not tip:
        print("FAIL: the foot plane or the tip has no boundary nodes")
        ok = False
    return ok


def scene_sensors():
    """(name, components, σ in m, every) of the scene's sensors, read from scene.toml."""
    import tomllib

    with open(os.path.join(MODEL, "scene.toml"), "rb") as f:
        scene = tomllib.load(f)
    out = []
    for s in scene["sensor"]:
        sigma = s["noise_std"]
        sigmas = sigma if isinstance(sigma, list) else [sigma] * 3
        comps = s.get("components", ["x", "y", "z"])
        out.append((s["name"], comps, sigmas, s.get("every", 1)))
    loads = [l["name"] for l in scene.get("load", [])]
    return out, loads


def data(bin_dir):
    """inputs.csv (zeros: the push is withheld) and measurements.csv (the co-rotational
    reference's markers + noise of the scene's σ)."""
    sensors, loads = scene_sensors()
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [os.path.join(bin_dir, "crokf-verify"), "simulate",
             os.path.join(MODEL, "scene.toml"), os.path.join(MODEL, "scenario.toml"),
             "--model", "corotational", "--out", tmp],
            check=True,
        )
        with open(os.path.join(tmp, "trajectories.csv")) as f:
            rows = list(csv.DictReader(f))
    rng = random.Random(NOISE_SEED)
    axes = ["x", "y", "z"]
    header = ["step"]
    for name, comps, _, _ in sensors:
        header += [f"{name}.{c}" for c in comps]
    steps = [r for r in rows if int(r["step"]) >= 1]
    with open(os.path.join(MODEL, "measurements.csv"), "w", newline="") as f:
        f.write("# Synthetic marker recording (m, world frame): the full-order co-rotational FEM\n"
                "# through scenario.toml plus Gaussian noise of the scene's noise_std;\n"
                "# scripts/gen_quickstart.py data. Columns: docs/csv.md.\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for r in steps:
            k = int(r["step"])
            row = [k]
            for name, comps, sigmas, every in sensors:
                for c in comps:
                    if k % every:
                        row.append("")
                        continue
                    u = float(r[f"{name}.u{c}"])
                    row.append(f"{u + rng.gauss(0.0, sigmas[axes.index(c)]):.6e}")
            w.writerow(row)
    with open(os.path.join(MODEL, "inputs.csv"), "w", newline="") as f:
        f.write("# Known forces on the load groups (N, world frame): none here, the filter\n"
                "# estimates the push from the markers. Columns: docs/csv.md.\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["step"] + [f"{l}.{c}" for l in loads for c in axes])
        for r in steps:
            w.writerow([int(r["step"])] + [0] * (3 * len(loads)))
    print(f"wrote {len(steps)} steps to inputs.csv and measurements.csv")


def main():
    args = sys.argv[1:]
    if args[:1] == ["--check"]:
        sys.exit(0 if check() else 1)
    if args[:1] == ["mesh"]:
        sys.exit(0 if check(generate()) else 1)
    if args[:1] == ["data"] and len(args) == 2:
        data(args[1])
        return
    sys.exit(__doc__)


if __name__ == "__main__":
    main()
