"""Models as they are: predict and validate with a model's own parameters (a CAD model, no result
file), and parameters whose locked inertia is not positive definite refused before integrating,
naming the time, the direction and the parameters."""

import json
import re

import numpy as np
import pytest

import spaceid
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Identification
from spaceid.identified import identified_model
from spaceid.models import load_model
from spaceid.motion import FourierTrajectory, _simulate, simulate
from spaceid.studies import predict, predictor, validate

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _motion(model, seed=1, duration=10.0):
    rng = np.random.default_rng(seed)
    shape = (model.n_joints, 3)
    return FourierTrajectory(model.joints, duration, rng.uniform(-0.5, 0.5, shape), rng.uniform(-0.5, 0.5, shape))


def _result(param, pi, momentum):
    """An identification record of ``pi`` (as a result file with these values would give)."""
    k = param.n_params
    return Identification(names=param.names, definitions=param.definitions, values=pi, std=np.ones(k), cov=np.eye(k),
                          condition_number=1.0, singular_values=np.ones(k), residual_rms=0.0, n_samples=10,
                          estimator="ols", momentum=np.asarray(momentum, float), model=param.model.source,
                          planar=param.model.planar, settings={"parameterization": param.to_dict()}, units=param.units)


@pytest.fixture(scope="module")
def satellite():
    model = load_model("satellite-7dof")
    return model, minimal_parameters(model)


def test_indefinite_locked_inertia_refused_naming_time_direction_and_parameters(satellite):
    """Base Ixx-like pi1 made negative: refused before any integration; the eigenvalue and its
    direction reported agree with the locked inertia block of the generalized inertia from the
    kinetic energy (an independent route: IdentifiedModel.inertia), and pi1 is named first."""
    model, param = satellite
    pi = param.true_values.copy()
    pi[0] *= -1.0
    traj = _motion(model)
    calls = []
    original = _simulate.collocation_steps
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(_simulate, "collocation_steps", lambda *a: calls.append(1) or original(*a))
        with pytest.raises(spaceid.SpaceidError, match=r"not positive definite") as info:
            simulate(param, pi, traj, np.linspace(0, 10, 101), [0.1, 0.0, 0.0])
    assert not calls  # refused before the integrator ran
    text = str(info.value)
    assert "\n" not in text and text.startswith("`pi`:")
    t = float(re.search(r"at t = ([-\d.e+]+) s", text).group(1))
    eigenvalue = float(re.search(r"eigenvalue ([-\d.e+]+) kg m\^2", text).group(1))
    axis = np.array([float(x) for x in re.search(r"along base axes \(([^)]*)\)", text).group(1).split(",")])
    assert re.search(r"make it negative: pi1 \(", text)
    q = traj.evaluate(np.array([t]))[0][0]
    locked = identified_model(_result(param, pi, [0.1, 0, 0])).inertia(q)[model.n_joints:, model.n_joints:]
    eig, vec = np.linalg.eigh(locked)
    assert eig[0] < 0 and eigenvalue == pytest.approx(eig[0], rel=5e-3)  # 3 digits shown
    assert abs(axis @ vec[:, 0]) == pytest.approx(1.0, abs=5e-3)


def test_planar_indefinite_refused_about_z():
    model = load_model("cepheus")
    param = minimal_parameters(model)
    with pytest.raises(spaceid.SpaceidError, match=r"about the base z axis at t = "):
        simulate(param, -param.true_values, _motion(model), np.linspace(0, 10, 51), [0, 0, 0.05])


def test_predict_of_an_impossible_result_names_the_result(satellite):
    model, param = satellite
    pi = param.true_values.copy()
    pi[0] *= -0.5
    traj = _motion(model)
    t = np.linspace(0, 10, 101)
    q, qd, _ = traj.evaluate(t)
    with pytest.raises(spaceid.SpaceidError, match=r"^bad\.json: its parameters: the locked inertia .* pi1"):
        predict(_result(param, pi, [0.1, 0, 0]), t, q, qd, where="bad.json")


def test_integration_bounded(satellite, monkeypatch):
    """The attitude integration stops with an error past its evaluations, never runs on."""
    model, param = satellite
    monkeypatch.setattr(_simulate, "MAX_EVALUATIONS", (50, 0))
    with pytest.raises(spaceid.SpaceidError, match=r"too steep to integrate near t = .* \(50 evaluations\)"):
        simulate(param, param.true_values, _motion(model), np.linspace(0, 10, 101), [0.1, 0.0, 0.0])


def test_predict_and_validate_a_model_as_it_is(tmp_path):
    """A model predicts with its own standard parameters, as simulate does with them; validation
    against a log of that model is exact and says a model predicted, not an identification."""
    model = load_model("cepheus")
    param = minimal_parameters(model)
    t = np.linspace(0, 10, 201)
    log = simulate(param, param.true_values, _motion(model), t, [0, 0, 0.05])
    predicted = predict("cepheus", log.t, log.q, log.qd, momentum=[0, 0, 0.05])
    assert np.allclose(predicted.base_w, log.base_w, atol=1e-12)
    assert predicted.meta["predicted_by"].startswith("model cepheus as it is")
    check = validate(model, log, momentum=[0, 0, 0.05])
    assert check.metrics["base_w_nrms"] < 1e-9
    assert check.to_dict()["predicted_by"].startswith("model cepheus")
    fig = check.plot()
    assert "model cepheus as it is" in fig._suptitle.get_text()
    assert "model cepheus (predicted)" in fig.legends[0].get_texts()[1].get_text()
    assert predictor(_result(param, param.true_values, [0, 0, 0.05])).kind == "identification"
    with pytest.raises(spaceid.SpaceidError, match=r"^`momentum`: cepheus is a model"):
        predict("cepheus", log.t, log.q, log.qd)


@pytest.mark.slow  # fast representative: test_predict_and_validate_a_model_as_it_is
def test_cli_predict_and_validate_take_a_model(tmp_path, satellite):
    from spaceid.cli import main
    from spaceid.data import write_log

    model = load_model("cepheus")
    param = minimal_parameters(model)
    log = simulate(param, param.true_values, _motion(model), np.linspace(0, 10, 101), [0, 0, 0.05])
    write_log(tmp_path / "log.csv", log)
    assert main(["validate", "cepheus", str(tmp_path / "log.csv"), "--momentum", "0.05",
                 "--out", str(tmp_path / "v")]) == 0  # fmt: skip
    metrics = json.loads((tmp_path / "v" / "metrics.json").read_text())
    assert metrics["predicted_by"].startswith("model cepheus as it is") and metrics["base_w_nrms"] < 1e-9
    sat, sparam = satellite
    pi = sparam.true_values.copy()
    pi[0] *= -0.5
    (tmp_path / "bad.json").write_text(json.dumps(_result(sparam, pi, [0.1, 0, 0]).to_dict()))
    _motion(sat).save(tmp_path / "traj.json")
    assert main(["predict", str(tmp_path / "bad.json"), str(tmp_path / "traj.json"), "--momentum", "0.1,0,0",
                 "--samples", "101", "-o", str(tmp_path / "p.csv")]) == 2  # fmt: skip
    assert not (tmp_path / "p.csv").exists()
