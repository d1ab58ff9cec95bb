#!/usr/bin/env python3
"""Generate the held-out bodies of models/bodies/ (needs the `gmsh` Python module:
`pip install gmsh`; runs headless).

    python3 scripts/gen_bodies.py [NAME ...]     # mesh the named bodies (default: all)
    python3 scripts/gen_bodies.py --check        # check the committed meshes only
    python3 scripts/gen_bodies.py horn --size 0.55 --out DIR
        # a finer mesh (element size × 0.55: 20,100 tetrahedra for the horn) in DIR/horn/,
        # for benchmarks; no bound on the count

Organic shapes (OpenCASCADE kernel, metres), each one volume named "body" and nothing else:
the scenes fix, load and measure them with geometric selections, as a user with a mesh from
elsewhere would. These bodies are measuring material for the estimation (docs/results/verification.md):
none of them was used to derive the filter's noise model.

- kidney:   a bean (five flattened spheres along an arc), held on its inner (hilum) side,
            pushed on its outer side.
- horn:     a tapered tube along a three-dimensional curve, fixed at its base, pushed at its tip.
- mushroom: a stem and an off-centre cap, fixed at the stem's foot, pushed at the cap's rim.
- arch:     a half ring of varying section standing on both feet, pushed at its crown.
- paddle:   a thin wavy blade on a handle, fixed at the handle's end, pushed at a corner.
- blob:     seven overlapping spheres (a liver-like lump), fixed on its flat bottom, pushed on
            its highest bump.

MSH 4.1 ASCII, linear tetrahedra, optimised; the checks (parsed here independently of gmsh):
every tetrahedron positively oriented, the count within its bound, the mesh volume within 3 %
of the CAD volume, the fixed and loaded patches holding boundary nodes.
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import read_msh41, tet_census  # noqa: E402

ROOT = os.path.dirname(HERE)
OUT = os.path.join(ROOT, "models", "bodies")
MAX_TETS = 6000


def chain(occ, path, radius, segments):
    """Truncated cones along `path(t)` with spheres at the joints (fuses robustly)."""
    parts = []
    for k in range(segments):
        t0, t1 = k / segments, (k + 1) / segments
        c0, c1 = path(t0), path(t1)
        r0, r1 = radius(t0), radius(t1)
        axis = [c1[i] - c0[i] for i in range(3)]
        parts.append((3, occ.addCone(*c0, *axis, r0, r1)))
        if k > 0:
            parts.append((3, occ.addSphere(*c0, r0)))
    return parts


def kidney(occ):
    parts = []
    for k in range(5):
        a = math.pi * (0.15 + 0.7 * k / 4)
        c = (0.05 * math.cos(a), 0.05 * math.sin(a), 0.0)
        s = occ.addSphere(*c, 1.0)
        r = 0.030 - 0.004 * abs(k - 2)
        occ.dilate([(3, s)], *c, r, r, 0.7 * r)
        parts.append((3, s))
    return parts, 0.0060


def horn_path(t):
    return (0.06 * math.sin(1.6 * t) * t, 0.05 * (1 - math.cos(2.2 * t)), 0.22 * t)


def horn(occ):
    parts = chain(occ, horn_path, lambda t: 0.022 - 0.014 * t, 10)
    end = horn_path(1.0)
    parts.append((3, occ.addSphere(*end, 0.010)))
    return parts, 0.0064


def mushroom(occ):
    stem = occ.addCylinder(0, 0, 0, 0.004, 0.0, 0.065, 0.014)
    cap = occ.addSphere(0.008, 0.0, 0.068, 1.0)
    occ.dilate([(3, cap)], 0.008, 0.0, 0.068, 0.048, 0.040, 0.020)
    foot = occ.addSphere(0, 0, 0, 0.02)
    return [(3, stem), (3, cap), (3, foot)], 0.0060


def arch(occ):
    ring = occ.addTorus(0, 0, 0, 0.13, 0.018, angle=math.pi)
    occ.rotate([(3, ring)], 0, 0, 0, 1, 0, 0, math.pi / 2)
    bulge = occ.addSphere(0.0, 0.0, 0.13, 0.026)
    feet = [occ.addSphere(x, 0.0, 0.0, 0.024) for x in (-0.13, 0.13)]
    return [(3, ring), (3, bulge)] + [(3, f) for f in feet], 0.0082


def paddle(occ):
    blade = occ.addSphere(0.12, 0.0, 0.0, 1.0)
    occ.dilate([(3, blade)], 0.12, 0.0, 0.0, 0.10, 0.055, 0.008)
    bump = occ.addSphere(0.16, 0.025, 0.004, 0.012)
    handle = occ.addCylinder(-0.06, 0.0, 0.0, 0.09, 0.0, 0.0, 0.010)
    return [(3, blade), (3, bump), (3, handle)], 0.0076


def blob(occ):
    centres = [
        (0.0, 0.0, 0.0, 0.045),
        (0.045, 0.01, 0.005, 0.032),
        (-0.04, 0.02, 0.0, 0.030),
        (0.01, -0.04, 0.01, 0.028),
        (0.015, 0.03, 0.035, 0.024),
        (-0.02, -0.015, 0.038, 0.022),
        (0.06, -0.02, 0.02, 0.018),
    ]
    return [(3, occ.addSphere(x, y, z, r)) for x, y, z, r in centres], 0.0092


BODIES = {
    "kidney": kidney,
    "horn": horn,
    "mushroom": mushroom,
    "arch": arch,
    "paddle": paddle,
    "blob": blob,
}

# Cuts (a box removed) giving the flat faces the scenes fix: (xmin, ymin, zmin, dx, dy, dz).
CUTS = {
    "horn": (-1, -1, -1, 2, 2, 1),
    "mushroom": (-1, -1, -1, 2, 2, 1),
    "arch": (-1, -1, -1, 2, 2, 1),
    "blob": (-1, -1, -1, 2, 2, 0.98),
    "kidney": (-1, -1, -1, 2, 0.5, 2),
    "paddle": (-1, -1, -1, 0.945, 2, 2),
}


def generate(name, scale=1.0):
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", int(os.environ.get("GMSH_VERBOSE", "0")))
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.model.add(name)
    occ = gmsh.model.occ
    parts, size = BODIES[name](occ)
    size *= scale
    if len(parts) > 1:
        fused, _ = occ.fuse(parts[:1], parts[1:])
    else:
        fused = parts
    cutter = occ.addBox(*CUTS[name])
    shape, _ = occ.cut(fused, [(3, cutter)])
    occ.synchronize()
    volumes = [t for d, t in shape if d == 3]
    if len(volumes) != 1:
        raise SystemExit(f"{name}: expected one fused volume, got {len(volumes)}")
    cad_volume = occ.getMass(3, volumes[0])
    gmsh.model.addPhysicalGroup(3, volumes, name="body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * size)
    gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 10)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("")
    gmsh.model.mesh.optimize("Netgen")
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    os.makedirs(os.path.join(OUT, name), exist_ok=True)
    gmsh.write(msh_path(name))
    gmsh.finalize()
    return cad_volume


def msh_path(name):
    return os.path.join(OUT, name, f"{name}.msh")


def check(name, cad_volume=None):
    mesh = read_msh41(msh_path(name))
    nodes, tets = mesh.nodes, mesh.tets
    ok = True
    total, worst, boundary = tet_census(nodes, tets)
    lo = [min(p[k] for p in nodes.values()) for k in range(3)]
    hi = [max(p[k] for p in nodes.values()) for k in range(3)]
    print(f"{name}: {len(tets)} tetrahedra, {len(nodes)} nodes, {len(boundary)} boundary nodes, "
          f"volume {total:.4e} m^3, extent {[round(x, 4) for x in lo]} .. "
          f"{[round(x, 4) for x in hi]} m, smallest signed volume {worst:.2e} m^3")
    if worst <= 0.0:
        print("FAIL: inverted or degenerate tetrahedron")
        ok = False
    if len(tets) > MAX_TETS:
        print(f"FAIL: more than {MAX_TETS} tetrahedra")
        ok = False
    if cad_volume is not None:
        rel = (total - cad_volume) / cad_volume
        print(f"  mesh volume / CAD volume - 1 = {rel:+.3%}")
        if abs(rel) > 0.03:
            print("FAIL: mesh volume more than 3 % off the CAD volume")
            ok = False
    return ok


def option(args, flag):
    """The value after `flag` in `args` (removed from `args` with it), or None."""
    if flag not in args:
        return None
    i = args.index(flag)
    if i + 1 >= len(args):
        raise SystemExit(f"{flag} needs a value")
    value = args[i + 1]
    del args[i:i + 2]
    return value


def main():
    global OUT, MAX_TETS
    args = sys.argv[1:]
    scale = option(args, "--size")
    out = option(args, "--out")
    if scale is not None:
        try:
            scale = float(scale)
        except ValueError:
            raise SystemExit(f"--size: expected a number, got '{scale}'")
        if not (0.05 <= scale <= 20):
            raise SystemExit(f"--size: expected a factor in [0.05, 20], got {scale}")
        if out is None:
            raise SystemExit("--size needs --out DIR (the committed meshes keep their size)")
        MAX_TETS = 10**7
    if out is not None:
        OUT = os.path.abspath(out)
    unknown = [a for a in args if a.startswith("--") and a != "--check"]
    if unknown:
        raise SystemExit(f"unknown option {unknown[0]} (--check, --size S, --out DIR)")
    names = [a for a in args if not a.startswith("--")] or list(BODIES)
    ok = True
    for name in names:
        if name not in BODIES:
            raise SystemExit(f"unknown body '{name}' (one of {', '.join(BODIES)})")
        cad = None if "--check" in args else generate(name, scale or 1.0)
        ok &= check(name, cad)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
