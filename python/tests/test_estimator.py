"""The estimator against dense NumPy computations with the model's own matrices."""

import math

import numpy as np
import pytest

import crokf


@pytest.fixture()
def meniscus(meniscus_path):
    return crokf.Model.load(meniscus_path)


def test_first_predict_is_g_u(meniscus):
    # From rest the load group's rotation is zero, so R(0)^T f = f exactly: x1 = G u.
    est = crokf.Estimator(meniscus)
    u = np.array([0.01, -0.02, -0.3])
    est.predict(u)
    np.testing.assert_allclose(est.state, meniscus.input_matrix @ u, rtol=1e-12, atol=0)
    # Named inputs give the same state.
    named = crokf.Estimator(meniscus)
    named.predict({"probe.x": 0.01, "probe.y": -0.02, "probe.z": -0.3})
    np.testing.assert_array_equal(named.state, est.state)


def test_update_from_rest_is_k_y(meniscus):
    # x- = 0 (zero input from rest), no rotation: y_lin = y and x = K_p y over phase p's channels.
    est = crokf.Estimator(meniscus)
    q = len(meniscus.measurement_channels)
    y = np.linspace(-1e-4, 1e-4, q)
    est.predict(None)
    used = est.update(y)
    phase = meniscus.kalman_phase(est.step_index % meniscus.kalman_period)
    active = phase["measured"]
    assert used == len(active)
    np.testing.assert_allclose(est.state, phase["gain"] @ y[active], rtol=1e-12, atol=1e-300)


def test_missing_values_none_and_nan_agree(meniscus):
    q = len(meniscus.measurement_channels)
    y = [1e-5] * q
    y_none = list(y)
    y_none[0] = None
    y_nan = np.array(y)
    y_nan[0] = np.nan
    a, b = crokf.Estimator(meniscus), crokf.Estimator(meniscus)
    assert a.step([0, 0, -0.1], y_none) == q - 1
    assert b.step([0, 0, -0.1], y_nan) == q - 1
    np.testing.assert_array_equal(a.state, b.state)
    # All missing: the update leaves the prediction unchanged.
    c = crokf.Estimator(meniscus)
    c.predict([0, 0, -0.1])
    prior = c.state
    assert c.update(None) == 0
    np.testing.assert_array_equal(c.state, prior)
    d = crokf.Estimator(meniscus)
    d.predict([0, 0, -0.1])
    assert d.update({meniscus.measurement_channels[2]: 1e-5}) == 1


def test_readouts_small_state_match_linear_rows(meniscus):
    # For a small state the warp is the identity to first order: u = C x + O(|x|^2).
    est = crokf.Estimator(meniscus)
    rng = np.random.default_rng(1)
    x = 1e-6 * rng.standard_normal(meniscus.order)
    est.state = x
    for k, name in enumerate(meniscus.sensors):
        c = meniscus.sensor_rows(name)["displacement_rows"]
        np.testing.assert_allclose(est.sensor_displacements()[k], c @ x, rtol=1e-5, atol=1e-15)
    surface = meniscus.node_set("surface")
    disp = est.node_displacements("surface")
    np.testing.assert_allclose(est.node_positions("surface"), surface["rest_positions"] + disp, rtol=0, atol=1e-15)
    assert est.node_std("surface").shape == disp.shape
    assert (est.node_std(0) >= 0).all()


def test_run_matches_step_loop_and_shapes(meniscus):
    steps = 120
    t = np.arange(1, steps + 1) * meniscus.dt
    inputs = np.zeros((steps, 3))
    inputs[:, 2] = -0.5 * np.minimum(t / 0.05, 1.0)
    q = len(meniscus.measurement_channels)
    rng = np.random.default_rng(7)
    meas = 1e-4 * rng.standard_normal((steps, q))
    meas[::3, 1] = np.nan
    est = crokf.Estimator(meniscus)
    out = est.run(inputs, meas, node_set="surface")
    s = len(meniscus.sensors)
    n = len(meniscus.node_set("surface")["node_tags"])
    assert out["measurements"].shape == (steps, q)
    assert out["sensors"].shape == (steps, s, 3)
    assert out["sensor_std"].shape == (steps, s, 3)
    assert out["node_positions"].shape == (steps, n, 3)
    np.testing.assert_allclose(out["time"], t, rtol=1e-12)
    loop = crokf.Estimator(meniscus)
    for k in range(steps):
        loop.step(inputs[k], [None if math.isnan(v) else v for v in meas[k]])
    np.testing.assert_array_equal(loop.state, est.state)
    np.testing.assert_array_equal(loop.sensor_displacements(), out["sensors"][-1])
    np.testing.assert_array_equal(loop.measurement_estimates(), out["measurements"][-1])
    assert est.step_index == steps


def test_errors_carry_the_runtime_message(meniscus):
    est = crokf.Estimator(meniscus)
    with pytest.raises(crokf.EstimatorError, match="update called without a preceding predict"):
        est.update(None)
    with pytest.raises(crokf.EstimatorError, match="expected length 3, got 2"):
        est.predict([0.0, 1.0])
    with pytest.raises(crokf.EstimatorError, match="input 'probe.z' is not finite"):
        est.predict([0.0, 0.0, math.inf])
    with pytest.raises(KeyError, match="probe.x"):
        est.predict({"push.x": 1.0})
    with pytest.raises(ValueError, match=r"expected shape \(T, 3\)"):
        est.run(np.zeros((4, 2)))
    bad = np.zeros((5, 3))
    bad[3, 1] = np.inf
    with pytest.raises(crokf.EstimatorError, match="row 3 .*input 'probe.y' is not finite"):
        crokf.Estimator(meniscus).run(bad)
