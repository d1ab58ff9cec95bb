#!/usr/bin/env python3
"""Regenerate and check models/meniscus/meniscus.msh (needs the `gmsh` Python module only).

    python3 scripts/gen_meniscus.py            # mesh, write, check
    python3 scripts/gen_meniscus.py --check    # check the committed mesh and scene only

Meshing: gmsh opens models/meniscus/meniscus.geo, generates the 3D mesh, optimizes it and writes
MSH 4.1 ASCII with Mesh.SaveAll = 0 (only elements of physical groups).

Checks, on the written file, parsed here independently of gmsh (plain Python, no numpy):
  - every tetrahedron positively oriented (det[x1-x0, x2-x0, x3-x0] > 0);
  - every physical group the scenes name present and non-empty;
  - total volume and the areas of the horn faces, the probe patch and the upper surface against
    closed forms of the revolved wedge (Pappus);
  - the "surface" group is exactly the boundary of the tetrahedral mesh (faces used once);
  - horn nodes lie on the planes at -+Arc/2;
  - every sensor position of scene.toml and scene_supported.toml lies inside a tetrahedron (barycentric coordinates >= 0),
    and is reported with its depth below the analytic upper surface.
Exit status 1 on any failed check.
"""

import math
import os
import sys
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
from mesh_common import read_msh41  # noqa: E402

ROOT = os.path.dirname(HERE)
MODEL = os.path.join(ROOT, "models", "meniscus")
GEO = os.path.join(MODEL, "meniscus.geo")
MSH = os.path.join(MODEL, "meniscus.msh")
SCENES = [os.path.join(MODEL, f) for f in ("scene.toml", "scene_supported.toml")]

# Must match meniscus.geo (mm, degrees).
RI, RO, HI, HO, ARC = 14.0, 25.0, 1.0, 7.0, 190.0
RP, WP = 20.0, 3.0


def generate():
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.open(GEO)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("")
    _, tags, _ = gmsh.model.mesh.getElements(3)
    q = gmsh.model.mesh.getElementQualities(list(tags[0]), "gamma")
    print(f"gmsh: {len(q)} tetrahedra, quality gamma min {min(q):.3f}, mean {sum(q) / len(q):.3f}")
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    gmsh.write(MSH)
    gmsh.finalize()


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def det3(a, b, c):
    return dot(a, cross(b, c))


def tri_area(x0, x1, x2):
    c = cross(sub(x1, x0), sub(x2, x0))
    return 0.5 * math.sqrt(dot(c, c))


def barycentric(p, x):
    """Barycentric coordinates of p in the tetrahedron x[0..3]."""
    d = det3(sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0]))
    l1 = det3(sub(p, x[0]), sub(x[2], x[0]), sub(x[3], x[0])) / d
    l2 = det3(sub(x[1], x[0]), sub(p, x[0]), sub(x[3], x[0])) / d
    l3 = det3(sub(x[1], x[0]), sub(x[2], x[0]), sub(p, x[0])) / d
    return (1.0 - l1 - l2 - l3, l1, l2, l3)


def z_upper(r):
    """Height of the upper (femoral) surface at radius r, mm."""
    return HI + (HO - HI) * (r - RI) / (RO - RI)


def check():
    ok = True

    def expect(cond, msg):
        nonlocal ok
        print(("ok    " if cond else "FAIL  ") + msg)
        ok = ok and cond

    mesh = read_msh41(MSH)
    nodes, groups = mesh.nodes, mesh.groups
    needed = {"meniscus", "anterior_horn", "posterior_horn", "probe", "upper", "surface", "lower"}
    sensors = {}
    for path in SCENES:
        with open(path, "rb") as f:
            scene = tomllib.load(f)
        for key in ("material", "fixed", "load", "display"):
            needed |= {g["group"] for g in scene.get(key, [])}
        for s in scene.get("sensor", []):
            sensors[(s["name"], tuple(s["position"]))] = s
    for name in sorted(needed):
        n = len(groups[name][2]) if name in groups else 0
        expect(n > 0, f"group '{name}': {n} elements")
    if not ok:
        return False

    tets = groups["meniscus"][2]
    vols = [det3(*(sub(nodes[t[k]], nodes[t[0]]) for k in (1, 2, 3))) / 6.0 for t in tets]
    expect(min(vols) > 0.0, f"{len(tets)} tetrahedra, {len(nodes)} nodes, min volume "
           f"{min(vols):.4g} mm³, max {max(vols):.4g} mm³ (all must be > 0)")
    expect(3000 <= len(tets) <= 8000, f"tetrahedron count {len(tets)} in [3000, 8000]")

    # Closed forms (Pappus): section area A, centroid radius rc, arc angle phi.
    phi = math.radians(ARC)
    area = (RO - RI) * (HI + HO) / 2.0
    rc = RI + (RO - RI) * (HI + 2.0 * HO) / (3.0 * (HI + HO))
    v_exact = area * rc * phi
    v_mesh = sum(vols)
    expect(abs(v_mesh / v_exact - 1.0) < 2e-3,
           f"volume {v_mesh:.2f} mm³ vs Pappus {v_exact:.2f} mm³ "
           f"({100 * (v_mesh / v_exact - 1):+.3f} %)")

    def group_area(name):
        return sum(tri_area(*(nodes[t] for t in tri)) for tri in groups[name][2])

    slant = math.hypot(RO - RI, HO - HI)
    exact = {
        "anterior_horn": area,
        "posterior_horn": area,
        # Cone patch: slant width WP * slant / (RO - RI), arc WP at its centre radius RP.
        "probe": WP * slant / (RO - RI) * WP,
        "upper": slant * (RI + RO) / 2.0 * phi,
        "lower": (RO**2 - RI**2) / 2.0 * phi,
    }
    for name, a in exact.items():
        m = group_area(name)
        expect(abs(m / a - 1.0) < 5e-3, f"area '{name}' {m:.3f} mm² vs exact {a:.3f} mm² "
               f"({100 * (m / a - 1):+.3f} %), {len(groups[name][2])} triangles")

    # "surface" = boundary of the tet mesh.
    count = {}
    for t in tets:
        for f in ((t[0], t[1], t[2]), (t[0], t[1], t[3]), (t[0], t[2], t[3]), (t[1], t[2], t[3])):
            key = tuple(sorted(f))
            count[key] = count.get(key, 0) + 1
    boundary = {f for f, c in count.items() if c == 1}
    surface = {tuple(sorted(f)) for f in groups["surface"][2]}
    expect(boundary == surface, f"'surface' = tet boundary ({len(boundary)} faces, "
           f"{len(surface)} in group)")

    # Horn nodes on the planes at -+ARC/2: distance |n . x| with n the plane normal.
    for name, s in (("anterior_horn", 1.0), ("posterior_horn", -1.0)):
        a = s * phi / 2.0
        n = (-math.sin(a), math.cos(a), 0.0)
        ids = {v for tri in groups[name][2] for v in tri}
        dist = max(abs(dot(n, nodes[v])) for v in ids)
        expect(dist < 1e-6, f"'{name}': {len(ids)} nodes, max distance to plane {dist:.2e} mm")
    probe_ids = {v for tri in groups["probe"][2] for v in tri}
    upper_ids = {v for tri in groups["upper"][2] for v in tri}
    expect(probe_ids <= upper_ids, f"'probe' ({len(probe_ids)} nodes) is part of 'upper'")

    # Sensors: containing tetrahedron by barycentric coordinates (brute force: ~5k tets).
    for s in sensors.values():
        p = tuple(s["position"])
        best = max(
            (min(barycentric(p, [nodes[v] for v in t])), i) for i, t in enumerate(tets)
        )
        r = math.hypot(p[0], p[1])
        ang = math.degrees(math.atan2(p[1], p[0]))
        expect(best[0] >= 0.0, f"sensor '{s['name']}' at r = {r:.2f} mm, angle {ang:+.1f}°: "
               f"in tet #{best[1]} (min barycentric {best[0]:.3f}), "
               f"{z_upper(r) - p[2]:.2f} mm below the upper surface")
    return ok


if __name__ == "__main__":
    if "--check" not in sys.argv[1:]:
        generate()
    sys.exit(0 if check() else 1)
