"""Model loading, verification, names and compile, against the committed model files."""

import numpy as np
import pytest

import crokf


def test_load_names_and_shapes(cantilever_path):
    model = crokf.Model.load(cantilever_path)
    assert model.dt > 0
    r = model.order
    m = len(model.inputs)
    q = len(model.measurement_channels)
    assert model.transition.shape == (r, r)
    assert model.input_matrix.shape == (r, m)
    assert model.measurement_matrix.shape == (q, r)
    # Labels follow the model file: one "sensor.c" per channel, sensors named in the scene.
    for label in model.measurement_channels:
        sensor, component = label.rsplit(".", 1)
        assert sensor in model.sensors and component in ("x", "y", "z")
    assert model.sensor_positions.shape == (len(model.sensors), 3)
    assert model.measurement_variance.shape == (q,)
    assert model.tier == "warped_linear"


def test_meniscus_node_sets(meniscus_path):
    model = crokf.Model.load(meniscus_path)
    assert model.node_sets == ["surface", "upper"]
    assert model.loads == ["probe"]
    assert model.inputs == ["probe.x", "probe.y", "probe.z"]
    surface = model.node_set("surface")
    n = len(surface["node_tags"])
    assert surface["rest_positions"].shape == (n, 3)
    tri = surface["triangles"]
    assert tri.shape[1] == 3 and tri.min() >= 0 and tri.max() < n
    # Closed boundary surface of a tetrahedral mesh: Euler characteristic V - E + F = 2.
    edges = {tuple(sorted(e)) for t in tri.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[0], t[2]))}
    assert n - len(edges) + len(tri) == 2
    # Rest positions in metres: the crescent spans a few centimetres.
    extent = surface["rest_positions"].max(axis=0) - surface["rest_positions"].min(axis=0)
    assert 0.005 < extent.max() < 0.1
    with pytest.raises(KeyError, match="surface"):
        model.node_set("nope")


def test_report_dict(cantilever_path):
    report = crokf.Model.load(cantilever_path).report
    hsv = report["hankel_singular_values"]
    assert all(a >= b for a, b in zip(hsv, hsv[1:]))
    # report["order"] is the balanced order; the model's order adds the 3 random-walk force states.
    assert report["order"] + 3 == crokf.Model.load(cantilever_path).order


def test_round_trip_bytes(cantilever_path, tmp_path):
    model = crokf.Model.load(cantilever_path)
    out = tmp_path / "copy.crokf"
    model.save(out)
    assert out.read_bytes() == cantilever_path.read_bytes()
    again = crokf.Model.from_bytes(model.to_bytes())
    np.testing.assert_array_equal(again.transition, model.transition)


def test_bad_files_raise_with_the_runtime_message(tmp_path, cantilever_path):
    missing = tmp_path / "missing.crokf"
    with pytest.raises(crokf.ModelFileError, match="cannot read model file .*missing.crokf"):
        crokf.Model.load(missing)
    corrupt = tmp_path / "corrupt.crokf"
    data = bytearray(cantilever_path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    corrupt.write_bytes(bytes(data))
    with pytest.raises(crokf.ModelFileError, match="corrupt.crokf"):
        crokf.Model.load(corrupt)
    assert issubclass(crokf.ModelFileError, crokf.CrokfError)


def test_compile_reproduces_the_committed_model(repo, cantilever_path):
    # The compiler is deterministic: compiling the committed scene in process must give the
    # committed model file byte for byte (the test suite's --check does the same from Rust).
    model, report = crokf.compile(repo / "models" / "cantilever" / "scene.toml")
    assert model.to_bytes() == cantilever_path.read_bytes()
    # model.order counts the 3 random-walk force states of the tip load after the balanced ones.
    assert report["reduction"]["order"] + 3 == model.order
    assert report["measured_errors"]


def test_compile_order_and_errors(repo, tmp_path):
    model, report = crokf.compile(repo / "models" / "cantilever" / "scene.toml", order=6, report=False)
    assert model.order == 6 + 3  # 6 balanced states + 3 random-walk force states
    assert report["reduction"]["order"] == 6
    assert not report["measured_errors"]
    with pytest.raises(crokf.CompileError, match="nothing.toml"):
        crokf.compile(tmp_path / "nothing.toml")


def test_a_tier_that_failed_its_check_warns_on_loading(repo, tmp_path, cantilever_path):
    # A passing model says nothing; the example cantilever's tier with four sampled elements
    # fails its own check, and written all the same (accept_failed_check) the file says why.
    assert crokf.Model.load(cantilever_path).tier_failed_check is None
    text = (repo / "models" / "cantilever" / "scene_corotational.toml").read_text()
    text = text.replace('file = "cantilever.msh"', f'file = "{repo / "models" / "cantilever" / "cantilever.msh"}"')
    head, _, _ = text.partition("[reduction.corotational]")
    scene = tmp_path / "failed.toml"
    scene.write_text(
        head
        + "[reduction.corotational]\nduration = 0.15\nevery = 2\norder = 10\n"
        + 'directions = "axes"\necsw_tolerance = 1e-6\necsw_max_elements = 4\n'
        + "accept_failed_check = true\n"
    )
    model, _ = crokf.compile(scene, order=6, report=False)
    why = model.tier_failed_check
    assert why is not None and "fails its check" in why
    path = tmp_path / "failed.crokf"
    model.save(path)
    with pytest.warns(UserWarning, match="failed the compiler's own check") as caught:
        loaded = crokf.Model.load(path)
    assert why in str(caught[0].message)
    assert loaded.tier_failed_check == why
