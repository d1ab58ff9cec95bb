"""Hostile calls from Python: a zlib bomb is a CompileError (not a killed interpreter),
Estimator.run is all or nothing, an implausible state is refused, values that are not real
numbers raise InputError, unknown channels raise ChannelError, and Model.tier tells the
co-rotational tier apart."""

import base64
import re
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

import crokf

@pytest.fixture(scope="module")
def cantilever(cantilever_path):
    return crokf.Model.load(cantilever_path)


# --------------------------------------------------------------------------------------------
# A zlib bomb through crokf.compile


def bomb_vtu(repo):
    """The cube fixture with its Points array replaced by a 45 KB zlib block claiming 1 TiB."""
    text = (repo / "compiler" / "tests" / "fixtures" / "cube_ascii.vtu").read_text()
    stream = zlib.compress(bytes(45_000), 0)
    header = struct.pack("<4Q", 1, 1 << 40, 1 << 40, len(stream))
    points = (
        '<DataArray type="Float64" Name="Points" NumberOfComponents="3" format="binary">\n'
        + base64.b64encode(header).decode()
        + base64.b64encode(stream).decode()
        + "\n</DataArray>"
    )
    text = re.sub(
        r'<DataArray type="Float64" Name="Points".*?</DataArray>', points, text, count=1, flags=re.S
    )
    return text.replace(
        'byte_order="LittleEndian">',
        'byte_order="LittleEndian" header_type="UInt64" compressor="vtkZLibDataCompressor">',
        1,
    )


def test_a_zlib_bomb_is_a_compile_error(repo, tmp_path):
    (tmp_path / "bomb.vtu").write_text(bomb_vtu(repo))
    assert (tmp_path / "bomb.vtu").stat().st_size < 64_000
    scene = tmp_path / "scene.toml"
    scene.write_text(
        '[mesh]\nfile = "bomb.vtu"\n[[material]]\nselect = [{ everything = true }]\n'
        "young_modulus = 1.0e6\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\n"
        'group = "MaterialIds:7:faces"\n[time]\ndt = 0.01\n'
    )
    # In a child interpreter: on failure the allocation would kill it, not the test run.
    code = (
        "import crokf, sys\n"
        "try:\n"
        f"    crokf.compile({str(scene)!r})\n"
        "except crokf.CompileError as e:\n"
        "    print(e)\n"
        "    sys.exit(3)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 3, (out.returncode, out.stderr)
    assert "bomb.vtu" in out.stdout and "1099511627776 bytes" in out.stdout, out.stdout
    assert "1032:1" in out.stdout
    assert "panicked" not in out.stderr and "memory allocation" not in out.stderr


# --------------------------------------------------------------------------------------------
# Estimator


def test_run_is_all_or_nothing_and_names_the_row_once(cantilever):
    est = crokf.Estimator(cantilever)
    m = len(cantilever.inputs)
    est.run(np.full((10, m), 0.1))
    before = est.state.copy()
    assert est.step_index == 10
    inputs = np.full((100, m), 0.1)
    inputs[50, 0] = 1e300
    with pytest.raises(crokf.EstimatorError) as info:
        est.run(inputs)
    message = str(info.value)
    assert "row 50 of 100" in message, message
    assert message.count("row ") == 1, message
    # The runtime names the estimator's own step (10 taken before + 51), and no other.
    assert re.findall(r"step (\d+)", message) == ["61"], message
    assert est.step_index == 10
    assert est.state.tobytes() == before.tobytes()
    # The same history without the bad row runs from where it was.
    inputs[50, 0] = 0.1
    out = est.run(inputs)
    assert est.step_index == 110 and out["time"].shape == (100,)


def test_an_implausible_state_is_refused_and_the_estimator_keeps_working(cantilever):
    est = crokf.Estimator(cantilever)
    r = cantilever.order
    est.step(np.zeros(len(cantilever.inputs)))
    before = est.state.copy()
    with pytest.raises(crokf.EstimatorError, match="state"):
        est.state = np.full(r, 1e300)
    with pytest.raises(crokf.EstimatorError, match="plausibility bound"):
        est.state = np.full(r, 1e6)
    assert est.state.tobytes() == before.tobytes()
    est.step(np.zeros(len(cantilever.inputs)))  # every later call still works
    est.run(np.zeros((5, len(cantilever.inputs))))
    small = np.full(r, 1e-6)
    est.state = small
    assert np.array_equal(est.state, small)


def test_values_that_are_not_real_numbers_raise_input_error(cantilever):
    est = crokf.Estimator(cantilever)
    m = len(cantilever.inputs)
    q = len(cantilever.measurement_channels)
    bad_inputs = [
        np.array([1 + 2j] + [0] * (m - 1)),
        ["1"] * m,
        np.array(["0.1"] * m),
        [True] * m,
        {cantilever.inputs[0]: "1"},
        {cantilever.inputs[0]: 1j},
    ]
    for value in bad_inputs:
        with pytest.raises(crokf.InputError):
            est.predict(value)
    for value in [["0.1"] * q, np.full(q, 1j), {cantilever.measurement_channels[0]: "0"}]:
        est.predict(None)
        with pytest.raises(crokf.InputError):
            est.update(value)
    with pytest.raises(crokf.InputError, match="complex"):
        est.run(np.zeros((3, m), dtype=complex))
    with pytest.raises(crokf.InputError, match="strings"):
        est.run(np.zeros((3, m)), np.full((3, q), "0.1"))
    with pytest.raises(crokf.InputError):
        est.state = np.zeros(cantilever.order, dtype=complex)
    # InputError is a TypeError and a CrokfError; None and NaN still mean "missing".
    assert issubclass(crokf.InputError, TypeError) and issubclass(crokf.InputError, crokf.CrokfError)
    est.predict(None)
    assert est.update([None] * q) == 0


def test_an_unknown_channel_raises_a_crokf_error(cantilever, meniscus_path):
    est = crokf.Estimator(cantilever)
    assert issubclass(crokf.ChannelError, KeyError) and issubclass(crokf.ChannelError, crokf.CrokfError)
    with pytest.raises(crokf.ChannelError, match="no input channel 'nope'"):
        est.predict({"nope": 1.0})
    est.predict(None)
    with pytest.raises(crokf.ChannelError, match="no measurement channel"):
        est.update({"nope.x": 1.0})
    meniscus = crokf.Model.load(meniscus_path)
    with pytest.raises(crokf.ChannelError, match="node set 'nope'"):
        meniscus.node_set("nope")
    with pytest.raises(crokf.ChannelError, match="sensor 'nope'"):
        meniscus.sensor_rows("nope")
    with pytest.raises(crokf.ChannelError):
        crokf.Estimator(meniscus).node_positions("nope")


# --------------------------------------------------------------------------------------------
# Model.tier


def write_beam_msh(path, nx=6, ny=1, nz=1, lengths=(1.0, 0.1, 0.1)):
    """A structured box of 6 nx ny nz tetrahedra (gmsh MSH 2.2): volume 'body', end faces
    'xmin' and 'xmax' (as compiler/src/mesh/procedural.rs writes it)."""

    def node(i, j, k):
        return (k * (ny + 1) + j) * (nx + 1) + i

    nodes = [
        (lengths[0] * i / nx, lengths[1] * j / ny, lengths[2] * k / nz)
        for k in range(nz + 1)
        for j in range(ny + 1)
        for i in range(nx + 1)
    ]
    tets = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                for order in [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]:
                    c = [i, j, k]
                    t = [node(*c)]
                    for axis in order:
                        c[axis] += 1
                        t.append(node(*c))
                    x = [np.array(nodes[n]) for n in t]
                    if np.linalg.det(np.array([x[1] - x[0], x[2] - x[0], x[3] - x[0]])) < 0:
                        t[2], t[3] = t[3], t[2]
                    tets.append(t)
    lines = []
    for i, tag in [(0, 1), (nx, 2)]:
        for k in range(nz):
            for j in range(ny):
                q = [node(i, j, k), node(i, j + 1, k), node(i, j + 1, k + 1), node(i, j, k + 1)]
                for tri in ([q[0], q[1], q[2]], [q[0], q[2], q[3]]):
                    lines.append(f"2 2 {tag} {tag} " + " ".join(str(n + 1) for n in tri))
    lines += ["4 2 3 3 " + " ".join(str(n + 1) for n in t) for t in tets]
    text = '$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n3\n2 1 "xmin"\n2 2 "xmax"\n3 3 "body"\n'
    text += f"$EndPhysicalNames\n$Nodes\n{len(nodes)}\n"
    text += "".join(f"{n + 1} {x!r} {y!r} {z!r}\n" for n, (x, y, z) in enumerate(nodes))
    text += f"$EndNodes\n$Elements\n{len(lines)}\n"
    text += "".join(f"{e + 1} {line}\n" for e, line in enumerate(lines))
    path.write_text(text + "$EndElements\n")


def test_model_tier_names_the_corotational_tier(tmp_path, cantilever):
    assert cantilever.tier == "warped_linear"
    assert "corotational" in crokf.Model.tier.__doc__
    assert "not in the model format" not in crokf.Model.tier.__doc__
    write_beam_msh(tmp_path / "beam.msh")
    scene = tmp_path / "scene.toml"
    scene.write_text(
        '[mesh]\nfile = "beam.msh"\n[[material]]\ngroup = "body"\nyoung_modulus = 1.0e6\n'
        "poisson_ratio = 0.3\ndensity = 1000.0\n[damping]\nalpha = 0.5\nbeta = 1.0e-3\n"
        '[[fixed]]\ngroup = "xmin"\n[[load]]\nname = "tip"\ngroup = "xmax"\n'
        'force_model = "white"\nforce_noise_std = 0.01\n[[sensor]]\nname = "tip"\nposition = [0.99, 0.05, 0.1]\n'
        "noise_std = 1.0e-3\n[time]\ndt = 0.005\n"
        '[reduction]\nmodel = "corotational"\n[reduction.corotational]\n'
        "ranges = { tip = 30.0 }\nduration = 0.1\nevery = 2\norder = 6\necsw_tolerance = 1e-2\n"
        "accept_failed_check = true\n"
    )
    model, _ = crokf.compile(scene, report=False)
    assert model.tier == "corotational"
    loaded = crokf.Model.from_bytes(model.to_bytes())
    assert loaded.tier == "corotational"
