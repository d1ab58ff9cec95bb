"""crokf.identify on a small co-rotational beam (12x2x2 cells, the tier of tests/tests/tier.rs):
a recording whose tip force is a random walk of known sigma (0.5 N per step, the filter's
0.05 N) gives that sigma within twice its stated uncertainty, writes the scene with it, and
refusals raise IdentifyError without writing anything."""

import itertools

import numpy as np
import pytest

import crokf

TRUE_SIGMA = 0.5
FILTER_SIGMA = 0.05
STEPS = 1500

TIER = """[reduction]
model = "corotational"
[reduction.corotational]
ranges = { tip = 30.0 }
duration = 0.15
every = 2
order = 10
ecsw_tolerance = 1e-2
newton_tolerance = 1e-12
newton_iterations = 60
directions = "axes"
"""

SCENE = """# the identify test's beam
[mesh]
file = "beam.msh"
[[material]]
group = "body"
young_modulus = 1e6
poisson_ratio = 3e-1
density = 1e3
[damping]
alpha = 5e-1
beta = 1e-3
[[fixed]]
group = "xmin"
[[load]]
name = "tip"
group = "xmax"
force_noise_std = 5e-2
force_model = "random_walk"
[[sensor]]
name = "tip"
position = [9.9e-1, 5e-2, 1e-1]
noise_std = 1e-3
[[display]]
name = "end"
group = "xmax"
[time]
dt = 5e-3
""" + TIER


def box_msh(cells, lengths):
    """MSH 2.2 text of the structured box of crokf_compile::mesh::procedural::box_mesh: six
    tetrahedra per cell (Kuhn), groups xmin, xmax (end triangles) and body."""
    nx, ny, nz = cells

    def nid(i, j, k):
        return (k * (ny + 1) + j) * (nx + 1) + i

    nodes = [
        (lengths[0] * i / nx, lengths[1] * j / ny, lengths[2] * k / nz)
        for k in range(nz + 1)
        for j in range(ny + 1)
        for i in range(nx + 1)
    ]
    tets = []
    for k, j, i in itertools.product(range(nz), range(ny), range(nx)):
        for path in itertools.permutations(range(3)):
            c = [i, j, k]
            t = [nid(*c)]
            for axis in path:
                c[axis] += 1
                t.append(nid(*c))
            x = np.array([nodes[n] for n in t])
            if np.linalg.det(x[1:] - x[0]) < 0:
                t[2], t[3] = t[3], t[2]
            tets.append(t)

    def end(i):
        tris = []
        for k, j in itertools.product(range(nz), range(ny)):
            q = [nid(i, j, k), nid(i, j + 1, k), nid(i, j + 1, k + 1), nid(i, j, k + 1)]
            tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
        return tris

    lines = [f"2 2 1 1 {' '.join(str(n + 1) for n in t)}" for t in end(0)]
    lines += [f"2 2 2 2 {' '.join(str(n + 1) for n in t)}" for t in end(nx)]
    lines += [f"4 2 3 3 {' '.join(str(n + 1) for n in t)}" for t in tets]
    out = ["$MeshFormat", "2.2 0 8", "$EndMeshFormat", "$PhysicalNames", "3",
           '2 1 "xmin"', '2 2 "xmax"', '3 3 "body"', "$EndPhysicalNames", "$Nodes",
           str(len(nodes))]
    out += [f"{n + 1} {p[0]:.17e} {p[1]:.17e} {p[2]:.17e}" for n, p in enumerate(nodes)]
    out += ["$EndNodes", "$Elements", str(len(lines))]
    out += [f"{e + 1} {line}" for e, line in enumerate(lines)]
    out += ["$EndElements", ""]
    return "\n".join(out)


def recording(model, sigma, seed):
    """Markers of the tier driven open loop by a random-walk tip force of sigma per step,
    plus the scene's marker noise."""
    rng = np.random.default_rng(seed)
    est = crokf.Estimator(model)
    noise = np.sqrt(model.measurement_variance)
    force = np.zeros(3)
    rows = []
    for _ in range(STEPS):
        est.predict({"tip.x": force[0], "tip.y": force[1], "tip.z": force[2]})
        y = est.measurement_estimates()
        rows.append(y + noise * rng.standard_normal(len(y)))
        force += sigma * rng.standard_normal(3)
    return np.array(rows)


def write_csv(path, model, rows):
    header = "step," + ",".join(model.measurement_channels)
    lines = [header] + [
        f"{k + 1}," + ",".join(f"{v:.17e}" for v in row) for k, row in enumerate(rows)
    ]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def beam(tmp_path_factory):
    folder = tmp_path_factory.mktemp("identify")
    (folder / "beam.msh").write_text(box_msh((12, 2, 2), (1.0, 0.1, 0.1)))
    (folder / "scene.toml").write_text(SCENE)
    model, _ = crokf.compile(folder / "scene.toml", order=8, report=False)
    model.save(folder / "model.crokf")
    write_csv(folder / "walk.csv", model, recording(model, TRUE_SIGMA, 11))
    write_csv(folder / "held.csv", model, recording(model, 0.0, 12))
    return folder


def test_a_known_random_walk_is_recovered_and_written(beam):
    out = beam / "identified.toml"
    found = crokf.identify(beam / "scene.toml", beam / "model.crokf", beam / "walk.csv",
                           out=out, lags=20, skip=100)
    load = found["loads"][0]
    assert load["name"] == "tip"
    assert load["scene_sigma"] == FILTER_SIGMA and load["stated"]
    assert len(load["blocks"]) == found["blocks"] == 4
    assert found["block_bounds"] == [100, 450, 800, 1150, 1500]
    assert abs(load["value"] - TRUE_SIGMA) <= 2 * load["uncertainty"], load
    assert 0 < load["uncertainty"] < 0.2 * TRUE_SIGMA, load
    assert abs(found["markers_factor"]["value"] - 1) < 0.15, found["markers_factor"]
    assert "verdict: IDENTIFIED" in found["report"]
    assert found["written"] == str(out)
    text = out.read_text()
    written = [line for line in text.splitlines() if line.startswith("force_noise_std = ")]
    assert len(written) == 1
    assert abs(float(written[0].split("=")[1]) / load["value"] - 1) < 5e-4
    # Everything else as in the scene: drop the comment, restore the value.
    kept = [
        "force_noise_std = 5e-2" if line.startswith("force_noise_std = ") else line
        for line in text.splitlines()
        if not line.startswith("# identified by crokf-compile identify from walk.csv")
    ]
    assert "\n".join(kept) + "\n" == SCENE


def test_refusals_raise_identify_error_and_write_nothing(beam):
    out = beam / "refused.toml"
    with pytest.raises(crokf.IdentifyError, match="not exciting enough") as e:
        crokf.identify(beam / "scene.toml", beam / "model.crokf", beam / "held.csv",
                       out=out, lags=20, skip=100)
    assert isinstance(e.value, crokf.CrokfError)
    with pytest.raises(crokf.IdentifyError, match="too short"):
        crokf.identify(beam / "scene.toml", beam / "model.crokf", beam / "walk.csv",
                       out=out, skip=1250)
    with pytest.raises(crokf.IdentifyError, match="refusing to overwrite an input"):
        crokf.identify(beam / "scene.toml", beam / "model.crokf", beam / "walk.csv",
                       out=beam / "scene.toml")
    with pytest.raises(TypeError):
        crokf.identify(beam / "scene.toml", beam / "model.crokf", beam / "walk.csv",
                       lag=20)
    assert not out.exists()


def test_the_force_level_is_reported_and_can_be_held(beam, cantilever_path):
    """The beam's tier stores force-sigma levels: a new estimator is at the designed sigma; with
    the load told and markers equal to its own estimates (zero innovations) it goes below the
    designed sigma; with the load not told it stays at the designed sigma; held, it is back at
    the designed sigma and stays there. A model with one level reports None."""
    model = crokf.Model.load(beam / "model.crokf")
    est = crokf.Estimator(model)
    assert est.force_level == {"level": 0, "factor": 1.0, "statistic": 0.0, "adapting": True}
    told = np.zeros(len(model.inputs))
    told[model.inputs.index("tip.z")] = -1.0

    def calm(inputs, steps=100):
        for _ in range(steps):
            est.predict(inputs)
            est.update(est.measurement_estimates())

    calm(told)
    level = est.force_level
    assert level["factor"] < 1.0 and level["adapting"], level
    est.reset()
    calm(np.zeros(len(model.inputs)))
    assert est.force_level["factor"] == 1.0
    est.set_force_adaptation(False)
    calm(told)
    assert est.force_level == {"level": 0, "factor": 1.0, "statistic": 0.0, "adapting": False}
    assert crokf.Estimator(crokf.Model.load(cantilever_path)).force_level is None


def test_a_missing_marker_gives_the_filters_own_covariance(beam):
    """The beam's tier: with every marker present the stored covariances are in use (None); from
    an update with the markers missing the filter carries its own covariance, symmetric, and the
    tip sigma `sensor_std` reads grows while they are away; switched off, the stored covariances
    again."""
    model = crokf.Model.load(beam / "model.crokf")
    est = crokf.Estimator(model)
    u = np.zeros(len(model.inputs))
    est.predict(u)
    est.update(est.measurement_estimates())
    assert est.tier_covariance is None
    sigma = []
    for _ in range(10):
        est.predict(u)
        est.update()
        p = est.tier_covariance
        n = len(est.state)
        assert p.shape == (n, n) and np.allclose(p, p.T)
        sigma.append(np.linalg.norm(est.sensor_std()[0]))
    assert all(b > a for a, b in zip(sigma, sigma[1:])), sigma
    est.set_covariance_recursion(False)
    assert est.tier_covariance is None
