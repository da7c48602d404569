"""Validation: the fitting log is recognised (it cannot fail there); attitude errors."""

import warnings

import numpy as np
import pytest

import spaceid
from spaceid.data import log_fingerprint, read_log, write_json, write_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify, load_result
from spaceid.motion import simulate
from spaceid.studies import attitude_error_angle, validate, validation_metrics

H = np.array([0.0, 0.0, 0.4934])


def _motion(scale):
    def motion(t):
        q = np.stack([0.8 * np.sin(1.3 * t), np.sin(2.1 * t + 0.4)], -1) * scale
        qd = np.stack([1.04 * np.cos(1.3 * t), 2.1 * np.cos(2.1 * t + 0.4)], -1) * scale
        return q, qd

    return motion


@pytest.fixture(scope="module")
def fitted():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    log = simulate(param, param.true_values, _motion(1.0), np.linspace(0, 5, 35), H, model=param.model)
    return param, log, identify(param, log, H)


def _no_warning(ident, log):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return validate(ident, log, momentum=H)


def test_validation_on_the_fitting_log_warns(fitted, tmp_path):
    param, log, ident = fitted
    assert ident.settings["log_fingerprint"] == log_fingerprint(log)
    with pytest.warns(UserWarning, match=r"demo.json: the log to validate on is the one the model was identified "
                      r"from .*cannot fail; record a different motion"):
        validate(ident, log, momentum=H, where="demo.json")
    # through files: the log CSV reads back bit for bit and the result keeps the fingerprint
    write_log(tmp_path / "log.csv", log)
    write_json(tmp_path / "result.json", ident.to_dict())
    back = read_log(tmp_path / "log.csv", joints=param.model.joints, planar=True)
    with pytest.warns(UserWarning, match="cannot fail"):
        validate(load_result(tmp_path / "result.json"), back, momentum=H)


def test_validation_on_another_motion_does_not_warn(fitted):
    param, log, ident = fitted
    other = simulate(param, param.true_values, _motion(0.7), np.linspace(0, 5, 35), H, model=param.model)
    metrics = _no_warning(ident, other).metrics
    assert metrics["base_w_nrms"] < 1e-9  # the true model, noise-free
    _no_warning(ident, log.select(slice(1, None)))  # other samples: not the fitting log itself
    assert log_fingerprint(other) != log_fingerprint(log)


def test_attitude_error_angle():
    axis = np.array([2.0, -1.0, 2.0]) / 3
    angles = np.array([0.0, 1e-9, 1e-4, 0.5, 3.0])
    quat = np.column_stack([np.cos(angles / 2), np.sin(angles / 2)[:, None] * axis])
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(attitude_error_angle(identity, quat), angles, rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(attitude_error_angle(quat, -quat), 0, atol=1e-15)  # q and -q: one attitude
    # the same relative rotation from a turned start
    start = np.array([np.cos(0.4), 0.0, np.sin(0.4), 0.0])
    w, v = start[0], start[1:]
    turned = np.column_stack([w * quat[:, 0] - quat[:, 1:] @ v,
                              w * quat[:, 1:] + quat[:, :1] * v + np.cross(v, quat[:, 1:])])
    np.testing.assert_allclose(attitude_error_angle(start, turned), angles, rtol=1e-9, atol=1e-15)


def test_spatial_metrics_give_the_attitude_error(fitted):
    _, log, _ = fitted
    spatial = spaceid.Log(log.t, log.joints, log.q, log.qd, log.base_quat, log.base_w, planar=False)
    turn = 1e-3 * log.t  # the prediction's yaw drifts by 1 mrad/s
    drifted = spaceid.Log(log.t, log.joints, log.q, log.qd, spaceid.data.yaw_to_quat(log.base_yaw + turn),
                          log.base_w, planar=False)
    metrics = validation_metrics(spatial, drifted)
    assert metrics["base_attitude_max"] == pytest.approx(turn.max(), rel=1e-9)
    assert metrics["base_attitude_rms"] == pytest.approx(np.sqrt(np.mean(turn**2)), rel=1e-9)
