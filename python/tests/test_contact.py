"""The contact step from Python (docs/contact.md): the meniscus's touch scene pressed along the
bundled tool path (models/meniscus/touch_tool.csv)."""

import numpy as np
import pytest

import crokf


@pytest.fixture(scope="module")
def touch(repo):
    model, _ = crokf.compile(repo / "models" / "meniscus" / "scene_touch.toml", report=False)
    path = np.loadtxt(repo / "models" / "meniscus" / "touch_tool.csv", delimiter=",",
                      comments="#", skiprows=2)
    return model, path[:, 1:4]


def test_a_press_pushes_back_and_leaving_gives_zero(touch):
    model, path = touch
    est = crokf.Estimator(model)
    forces = []
    for c in path[:200]:  # the press, 1 mm over 200 steps
        est.step_with_tools(c)
        t = est.tool_contact(0)
        assert t["status"] in ("Free", "Touching")
        assert np.all(np.isfinite(t["force"])) and t["stiffness"].shape == (3, 3)
        forces.append(np.linalg.norm(t["force"]))
    assert forces[-1] > 0.02, forces[-1]  # tens of mN at 1 mm
    assert est.tool_contact(0)["status"] == "Touching" and est.tool_contact(0)["nodes"] >= 1
    # Two tools as an (n, 3) array: the second far away touches nothing.
    est.step_with_tools(np.array([path[199], path[199] + 1.0]))
    assert est.tool_contact(1)["status"] == "Free"
    assert est.tool_contact(2) is None
    # Lifted far off at once: zero at once.
    est.step_with_tools(path[199] + np.array([0.0, 0.0, 0.01]))
    t = est.tool_contact(0)
    assert t["status"] == "Free" and np.all(t["force"] == 0.0)


def test_bad_tools_are_refused_and_change_nothing(touch):
    model, path = touch
    est = crokf.Estimator(model)
    est.step_with_tools(path[0])
    before = est.state.copy()
    k = est.step_index
    for bad in ([np.nan, 0.0, 0.0], np.zeros((3, 3)), [1.0, 2.0]):
        with pytest.raises((crokf.EstimatorError, crokf.InputError)):
            est.step_with_tools(bad)
        assert est.step_index == k
        assert np.array_equal(est.state, before)


def test_a_model_without_contact_region_refuses_tools(meniscus_path):
    est = crokf.Estimator(crokf.Model.load(meniscus_path))
    with pytest.raises(crokf.EstimatorError, match="contact"):
        est.step_with_tools([0.0, 0.0, 0.0])


def test_a_grasp_holds_the_node_and_pulls_back(touch):
    model, path = touch
    est = crokf.Estimator(model)
    for c in path[:200]:  # pressed 1 mm
        est.step_with_tools(c)
    node = est.grasp(0)
    held, offset = est.grasped(0)
    assert held == node and offset.shape == (3,)
    # Pulled 1 mm back out past where the press began: the body holds the tool back.
    start, deepest = path[0], path[199]
    out = start + (start - deepest)
    for s in np.linspace(0.0, 1.0, 200):
        est.step_with_tools(deepest + s * (out - deepest))
        t = est.tool_contact(0)
        assert t["status"] == "Grasping" and t["nodes"] == 1
    pull = est.tool_contact(0)["force"]
    assert np.dot(pull, out - deepest) < 0.0, pull
    est.release(0)
    assert est.grasped(0) is None
    est.step_with_tools(out)
    assert np.all(est.tool_contact(0)["force"] == 0.0)
    # Far from the body there is nothing to grasp.
    est.step_with_tools(out + np.array([0.0, 0.0, 0.05]))
    with pytest.raises(crokf.EstimatorError, match="grasp"):
        est.grasp(0)
