"""The servicer twin (spaceid.twin.run_servicer) and the spatial experiment, against known truth:
momentum conserved by an independent formula, the plant against MuJoCo (an engine nobody on the
project wrote) given the same joint torques, the sensors' statistics against their settings, the
protocol end to end, the command line's refusals."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mujoco_flight import _joints, _model
from random_robots import random_robot

import spaceid
from spaceid.cli import main
from spaceid.data import quat_multiply, quat_to_matrix
from spaceid.motion import FourierTrajectory, simulate
from spaceid.studies import attitude_error_angle, run_spatial_experiment
from spaceid.twin import (Gyro, JointControl, JointEncoders, ServicerSettings, ServicerState, StarTracker,
                          run_servicer, servicer_log)  # fmt: skip


def _robot(tmp_path, seed=5):
    """A small random spatial robot (4 joints for seed 5) and its URDF."""
    robot = random_robot(seed, planar=False, max_arms=2, max_joints=3)
    return robot.load(tmp_path), tmp_path / f"robot{seed}.urdf"


def _reference(joints, duration, seed, amplitude=0.2) -> FourierTrajectory:
    """An undesigned motion: random Fourier coefficients of the joint rates [rad/s]."""
    rng = np.random.default_rng(seed)
    shape = (len(joints), 3)
    return FourierTrajectory(joints, duration, amplitude * rng.standard_normal(shape),
                             amplitude * rng.standard_normal(shape))  # fmt: skip


def test_momentum_is_conserved_and_starts_where_asked(tmp_path):
    """The angular momentum of the true states (spaceid.dynamics.angular_momentum, a formula
    independent of Pinocchio's dynamics) stays the one the start state asked for, to the
    integrator's error, while the controllers move the joints."""
    model, _ = _robot(tmp_path)
    h0 = np.array([0.02, -0.01, 0.03])
    run = run_servicer(_reference(model.joints, 4.0, 1), duration=4.0, settings=ServicerSettings(model=model),
                       state=ServicerState(momentum=h0), seed=2)  # fmt: skip
    truth = run.truth
    h = spaceid.dynamics.angular_momentum(model, truth.q, truth.qd, truth.base_w, truth.base_quat)
    assert np.abs(h - h0).max() < 1e-9 * run.meta["momentum_scale"]
    assert run.meta["momentum_drift_relative"] < 1e-9
    assert np.abs(truth.qd).max() > 0.05 and np.ptp(truth.base_quat, axis=0).max() > 1e-3  # it did move


def test_a_phase_continues_from_the_state(tmp_path):
    """Two phases from a run's state give the motion of one phase (the state carries the base,
    the joints and the controllers' last reading)."""
    model, _ = _robot(tmp_path)
    settings = ServicerSettings(model=model).without_noise()
    ref = _reference(model.joints, 2.0, 3)
    whole = run_servicer(ref, duration=2.0, settings=settings, state=ServicerState(momentum=(0.01, 0, 0)))
    first = run_servicer(ref, duration=1.0, settings=settings, state=ServicerState(momentum=(0.01, 0, 0)))
    shifted = lambda t: tuple(x for x in ref.evaluate(np.minimum(t + 1.0, 2.0)))  # noqa: E731
    second = run_servicer(shifted, duration=1.0, settings=settings, state=first.state)
    assert np.allclose(second.truth.q[-1], whole.truth.q[-1], atol=1e-10)
    assert attitude_error_angle(second.truth.base_quat[-1], whole.truth.base_quat[-1])[0] < 1e-10


def test_plant_agrees_with_mujoco(tmp_path):
    """The same joint torques (the twin's applied efforts, held over each control period) in
    MuJoCo from the same state give the same motion to the integrators' error: Pinocchio's
    free-floating dynamics, the embedded RK4 and the quaternion kinematics against another
    engine's."""
    model, urdf = _robot(tmp_path, seed=7)
    control = JointControl(rate=100.0, substeps=10)  # 1 ms steps, as MuJoCo's below
    settings = ServicerSettings(model=model, control=control).without_noise()
    run = run_servicer(_reference(model.joints, 3.0, 4, amplitude=0.3), duration=3.0, settings=settings,
                       state=ServicerState(momentum=(0.02, 0.01, -0.02)), seed=0)  # fmt: skip
    m = _model(urdf, 1e-3)
    d = mujoco.MjData(m)
    qa, va = _joints(m, model.joints)
    truth = run.truth
    d.qpos[:3], d.qpos[3:7], d.qpos[qa] = truth.base_position[0], truth.base_quat[0], truth.q[0]
    d.qvel[:3] = quat_to_matrix(truth.base_quat[0]) @ run.base_velocity[0]  # MuJoCo: world-frame linear velocity
    d.qvel[3:6], d.qvel[va] = truth.base_w[0], truth.qd[0]
    q, quat = [d.qpos[qa].copy()], [d.qpos[3:7].copy()]
    for k in range(len(truth.t) - 1):
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[va] = run.effort[k]
        for _ in range(10):
            mujoco.mj_step(m, d)
        q.append(d.qpos[qa].copy())
        quat.append(d.qpos[3:7].copy())
    assert np.abs(np.array(q) - truth.q).max() < 1e-7
    assert attitude_error_angle(np.array(quat), truth.base_quat).max() < 1e-7
    assert np.ptp(truth.q, axis=0).max() > 0.1  # a real motion


# fast representatives: test_the_lab_reads_the_sensors, test_twin.py::test_encoders_quantise_and_publish_at_50_hz
@pytest.mark.slow
def test_sensors_have_the_statistics_of_their_settings(tmp_path):
    """Encoders (white noise, no quantisation), star tracker (noise per axis, latency, lost
    frames), gyro (bias, white noise) measured against the truth over a long enough phase."""
    model, _ = _robot(tmp_path)
    bias = (1e-3, -2e-3, 5e-4)
    settings = ServicerSettings(
        model=model, encoders=JointEncoders(noise=1e-3, counts_per_rev=None, rate=50.0),
        star_tracker=StarTracker(rate=20.0, noise=1e-3, latency=0.013, drop_probability=0.2),
        gyro=Gyro(noise=1e-4, bias=bias, walk=0.0),
    )  # fmt: skip
    run = run_servicer(_reference(model.joints, 40.0, 5, amplitude=0.05), duration=40.0, settings=settings,
                       state=ServicerState(momentum=(0.01, 0.0, 0.02)), seed=9)  # fmt: skip
    truth, js, frames = run.truth, run.recording.joints, run.recording.base
    at = np.rint((js.t - truth.t[0]) * 100).astype(int)  # joint stamps on the 100 Hz ticks
    assert js.velocity is None and len(js.t) == 2000  # no joint-rate sensor; 50 Hz over [0, 40)
    err = js.position - truth.q[at]
    assert abs(err.std() / 1e-3 - 1) < 0.05 and abs(err.mean()) < 4e-3 / np.sqrt(err.size)
    # the star tracker: stamps = capture + latency on the 20 Hz grid; lost frames; noise per axis
    capture = frames.t - 0.013
    assert np.allclose(capture * 20, np.rint(capture * 20), atol=1e-6)
    n = run.meta["star_tracker_frames"]
    assert n == 800 and len(frames.t) == n - run.meta["star_tracker_dropped"]
    assert abs(run.meta["star_tracker_dropped"] / n - 0.2) < 4 * np.sqrt(0.2 * 0.8 / n)
    true_q = truth.base_quat[np.rint((capture - truth.t[0]) * 100).astype(int)]
    delta = quat_multiply(true_q * [1, -1, -1, -1], frames.quat)  # true^-1 measured
    delta *= np.sign(delta[:, :1])
    rotation = 2 * delta[:, 1:]  # small angles
    assert np.all(np.abs(rotation.std(axis=0) / 1e-3 - 1) < 0.1)
    # the gyro: bias plus white noise
    g = run.gyro - truth.base_w[at]
    assert np.all(np.abs(g.mean(axis=0) - bias) < 4e-4 / np.sqrt(len(g)))
    assert np.all(np.abs(g.std(axis=0) / 1e-4 - 1) < 0.1)


# fast representatives: test_the_lab_reads_the_sensors, test_twin.py::test_encoders_quantise_and_publish_at_50_hz
@pytest.mark.slow
def test_quantisation_and_the_random_walk(tmp_path):
    """Encoder readings are whole counts within half a count of the truth; the gyro bias's random
    walk has increments of variance walk^2 dt."""
    model, _ = _robot(tmp_path)
    settings = ServicerSettings(model=model, encoders=JointEncoders(noise=0.0, counts_per_rev=1000),
                                gyro=Gyro(noise=0.0, bias=(0, 0, 0), walk=1e-4))  # fmt: skip
    run = run_servicer(_reference(model.joints, 20.0, 6), duration=20.0, settings=settings, seed=4)
    js, truth = run.recording.joints, run.truth
    count = 2 * np.pi / 1000
    assert np.allclose(js.position / count, np.rint(js.position / count), atol=1e-9)
    at = np.rint((js.t - truth.t[0]) * 100).astype(int)
    assert np.abs(js.position - truth.q[at]).max() <= count / 2 + 1e-12
    steps = np.diff(run.gyro - truth.base_w[at], axis=0)
    assert abs(steps.std() / (1e-4 * np.sqrt(0.02)) - 1) < 0.05


def test_the_lab_reads_the_sensors(tmp_path):
    """servicer_log: the base rate is the gyro's, the joint rates differentiated (the recording
    has none), the attitude the star tracker's read back at the joint stamps (latency removed)."""
    model, _ = _robot(tmp_path)
    settings = ServicerSettings(model=model, gyro=Gyro(noise=0.0, bias=(0, 0, 0), walk=0.0))
    run = run_servicer(_reference(model.joints, 10.0, 2, amplitude=0.1), duration=10.0, settings=settings,
                       state=ServicerState(momentum=(0.01, 0.02, 0.0)), seed=1)  # fmt: skip
    log = servicer_log(run, settings)
    at = np.rint((log.t - run.truth.t[0]) * 100).astype(int)
    assert np.allclose(log.base_w, run.truth.base_w[at], atol=1e-15)
    # 5e-5 rad per axis (8.7e-5 of rotation), smoothed over 7 frames of 10 Hz (1.1e-4 at most over the 496
    # samples; a latency left in would be the rate times it, 1e-3 and more)
    assert attitude_error_angle(log.base_quat, run.truth.base_quat[at]).max() < 1.5e-4
    assert np.abs(log.qd - run.truth.qd[at]).max() < 0.02 and log.meta["base_rate"] == "gyro"
    # the gyro's rate is measured, not differentiated: identification models its noise, not the
    # attitude's derivative (which made the bars too narrow with a prior), and may estimate its bias
    assert set(log.meta["differentiation"]) == {"joints"}
    assert set(servicer_log(run, settings, base_rate="attitude").meta["differentiation"]) == {"joints", "base"}


def test_settings_refuse_bad_values():
    with pytest.raises(spaceid.SpaceidError, match="star_tracker.drop_probability"):
        StarTracker(drop_probability=1.0)
    with pytest.raises(spaceid.SpaceidError, match="gyro.bias"):
        Gyro(bias=(1.0, 2.0))
    with pytest.raises(spaceid.SpaceidError, match="control.model_error"):
        JointControl(model_error=1.5)
    with pytest.raises(spaceid.SpaceidError, match="is planar"):
        run_servicer(None, duration=1.0, settings=ServicerSettings(model="cepheus"))
    with pytest.raises(spaceid.SpaceidError, match="encoders.rate"):
        run_servicer(None, duration=1.0, settings=ServicerSettings(encoders=JointEncoders(rate=30.0)))


def _checked_experiment(res, model):
    """What every run of the protocol must satisfy, whatever its estimates."""
    m = res.metrics
    assert max(m["momentum drift relative to the joints' momentum"]) < 1e-9
    assert m["coverage"]["n_large"] > 0 and 0 <= m["coverage"]["within_2_sigma"] <= 1
    # the pipeline itself: driven by the measured joints, the true model predicts the held-out
    # attitude 20 times better than the 15 %-off CAD prior (seen: 200 times on the random robot,
    # 1.3e-3 against 0.26 rad on the servicer over 60 s)
    held = res.validation_log
    param = spaceid.minimal_parameters(model)
    exact = simulate(param, param.true_values, spaceid.motion.hermite_motion(held.t, held.q, held.qd), held.t,
                     np.array(res.settings["momentum (known) [N m s]"]), initial_quat=held.base_quat[0])  # fmt: skip
    assert attitude_error_angle(exact.base_quat, held.base_quat).max() < m["held-out attitude error, CAD prior [rad]"]["max"] / 20
    for name in ("report.md", "experiment.json", "result.json", "log.csv", "validation_log.csv", "parameters.png"):
        assert (res.folder / name).is_file()


@pytest.mark.slow
def test_experiment_on_a_random_robot(tmp_path):
    """The spatial protocol end to end on a small random robot with a very short design budget."""
    model, _ = _robot(tmp_path)
    res = run_spatial_experiment(settings=ServicerSettings(model=model), duration=15.0, validation_duration=6.0,
                                 harmonics=3, samples=150, time_budget=None, max_steps=10, seed=1,
                                 out=tmp_path / "report", limits={"q_max": 1.0, "qd_max": 0.5, "qdd_max": 0.5})  # fmt: skip
    _checked_experiment(res, model)
    m = res.metrics
    print(m["coverage"], m["held-out attitude error, identified [rad]"], m["held-out attitude error, CAD prior [rad]"])
    assert res.ident.prior is not None and res.ident.n_samples == res.log.n_samples
    assert m["CAD prior / identified, largest attitude error"] > 1  # never worse than the prior it started from


@pytest.mark.soak
@pytest.mark.slow
def test_experiment_on_the_dual_arm_servicer(tmp_path):
    """The spatial protocol on servicer-dual with its defaults (a deterministic design): end to end,
    the identified model with the CAD prior predicts the held-out motion at least 20 times better
    than the prior alone (bench_spatial: 300 to 900 times over 20 seeds)."""
    res = run_spatial_experiment(out=tmp_path / "report", seed=0, time_budget=None, max_steps=20)
    _checked_experiment(res, spaceid.load_model("servicer-dual"))
    m = res.metrics
    assert m["held-out attitude error, CAD prior [rad]"]["max"] > 1e-3  # 15 % off shows
    assert m["CAD prior / identified, largest attitude error"] > 20


@pytest.mark.parametrize("args, line", [
    (["servicer-dual", "--wheel-speed", "100"], ("error: --wheel-speed: options of the Cepheus experiment; "
                                                 "servicer-dual is spatial (the servicer twin): drop them")),
    *[(["cepheus", *given], ("error: --duration, --time-budget, --max-steps, --no-prior and the limits (--q-max, "
                             "--qd-max, --qdd-max) are options of the spatial protocol: give a spatial MODEL (e.g. "
                             "servicer-dual), or drop them")) for given in (["--time-budget", "5"], ["--no-prior"],
                                                                            ["--q-max", "1"])],
])  # fmt: skip
def test_cli_refuses_with_one_line(tmp_path, capsys, args, line):
    assert main(["experiment", *args, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == line, err
    assert not (tmp_path / "out").exists()


def test_cli_refuses_a_bad_budget(tmp_path, capsys):
    assert main(["experiment", "servicer-dual", "--time-budget", "-1", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--time-budget" in err


@pytest.mark.slow
def test_a_model_no_rigid_body_has_is_not_predicted(tmp_path):
    """The held-out prediction refuses a model whose locked inertia is not positive definite (its
    simulation would blow up or crawl) and names why; the true model passes."""
    from spaceid.studies._spatial_experiment import _predictions

    model, _ = _robot(tmp_path)
    settings = ServicerSettings(model=model).without_noise()
    run = run_servicer(_reference(model.joints, 2.0, 8), duration=2.0, settings=settings,
                       state=ServicerState(momentum=(0.01, 0.0, 0.0)))  # fmt: skip
    param = spaceid.minimal_parameters(model)
    predicted, refused = _predictions(param, {"true": param.true_values, "negated": -param.true_values},
                                      run.truth, np.array([0.01, 0.0, 0.0]))  # fmt: skip
    assert set(predicted) == {"true"} and "not positive definite" in refused["negated"]
    assert attitude_error_angle(predicted["true"].base_quat, run.truth.base_quat).max() < 1e-6


@pytest.mark.slow
def test_cli_runs_the_spatial_protocol_on_a_urdf(tmp_path, capsys):
    """`spaceid experiment ROBOT.urdf` with the design's limits and a step budget: identified with the
    CAD prior from every sample, which predicts the held-out motion better than the prior alone."""
    import json

    _, urdf = _robot(tmp_path)
    args = ["experiment", str(urdf), "--duration", "15", "--max-steps", "10", "--samples", "150", "--q-max", "1",
            "--qd-max", "0.5", "--qdd-max", "0.5", "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "with the CAD prior (the data set" in out and "report written to" in out
    done = json.loads((tmp_path / "out" / "experiment.json").read_text())
    assert done["settings"]["prior"] == "the CAD model" and done["settings"]["design steps"] == 10
    assert done["metrics"]["CAD prior / identified, largest attitude error"] > 1


def test_coverage_whitens_correlated_errors():
    """Errors drawn from a strongly correlated covariance: each run's RMS z strays far from 1 (the
    z move together), the whitened RMS stays near it; a covariance 2 times too narrow doubles it."""
    from types import SimpleNamespace

    from spaceid.studies import coverage

    rng = np.random.default_rng(3)
    a = rng.standard_normal((30, 30)) @ np.diag(np.geomspace(1, 1e-3, 30))
    cov = a @ a.T + 0.98 * np.outer(np.diag(a @ a.T) ** 0.5, np.diag(a @ a.T) ** 0.5)
    L, large = np.linalg.cholesky(cov), np.arange(0, 30, 2)
    runs = []
    for _ in range(200):
        values = L @ rng.standard_normal(30)
        result = SimpleNamespace(values=values, std=np.sqrt(np.diag(cov)), cov=cov, names=[f"p{i}" for i in range(30)])
        narrow = SimpleNamespace(**{**vars(result), "std": result.std / 2, "cov": cov / 4})
        runs.append((coverage(result, np.zeros(30), large), coverage(narrow, np.zeros(30), large)))
    rms = np.array([c["rms_z"] for c, _ in runs])
    whitened = np.array([c["whitened_rms"] for c, _ in runs])
    assert rms.min() < 0.5 and rms.max() > 1.5  # one run's marginal z says little
    assert abs(np.sqrt(np.mean(whitened**2)) - 1) < 0.05 and abs(np.median([n["whitened_rms"] for _, n in runs]) /
                                                                  np.median(whitened) - 2) < 1e-9
