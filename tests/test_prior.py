"""The CAD prior (``identify(..., prior=...)``): the MAP over physically consistent models against
known truth, on presets and random robots."""

import json
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2
from random_robots import perturbed_prior, random_robot
from test_prior_random_robots import check_prior
from test_random_pipeline import Flown

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.data import write_log
from spaceid.dynamics import full_values, full_values_jacobian, minimal_parameters
from spaceid.estimation import Identification, Noise, PriorRecord, identify, prior_deviations
from spaceid.estimation._prior import attribution
from spaceid.identified import pseudo_inertia, unphysical_bodies
from spaceid.models import inertial_vector
from spaceid.models.internal import with_theta
from spaceid.motion import FourierTrajectory, add_noise, sample_times, simulate
from spaceid.studies import attitude_error_angle, predict

H = np.array([0.3, -0.2, 0.5])


def random_motion(joints, duration, seed, amplitude=0.05, harmonics=3):
    """An undesigned motion: random Fourier coefficients of the joint rates [rad/s]."""
    rng = np.random.default_rng(seed)
    a, b = (rng.normal(0, amplitude, (len(joints), harmonics)) for _ in range(2))
    return FourierTrajectory(joints, duration, a, b, meta={"source": f"random {seed}"})


def cad_prior(model, off, seed):
    """Every mass and every body's principal moments off by ``off`` (relative, random signs)."""
    rng = np.random.default_rng(seed)
    rows = []
    for b in model.bodies:
        i_c = pseudo_inertia(b.inertial)[:3, :3] - b.mass * np.outer(b.com, b.com)
        w, v = np.linalg.eigh(np.trace(i_c) * np.eye(3) - i_c)
        f = 1 + off * rng.choice([-1.0, 1.0])
        rows.append(inertial_vector(b.mass * (1 + off * rng.choice([-1.0, 1.0])), b.com, v @ np.diag(w * f) @ v.T))
    return model.with_inertials(rows)


def flown(true, duration, rate_hz, seed, *, noise=(1e-4, 1e-5), amplitude=0.05, h=H):
    param = minimal_parameters(true)
    h = h[2:] * np.r_[0, 0, 1] if true.planar else h
    t = np.linspace(0, duration, int(duration * rate_hz) + 1)
    log = simulate(param, param.true_values, random_motion(true.joints, duration, seed, amplitude), t, h, model=true)
    return param, add_noise(log, angle=noise[0], rate=noise[1], seed=seed + 1), h


def held_out_error(result, true, h, seed, duration=30.0):
    param = minimal_parameters(true)
    motion = random_motion(true.joints, duration, seed + 100, 0.1)
    t = np.linspace(0, duration, 151)
    truth = simulate(param, param.true_values, motion, t, h, model=true)
    q, qd, _ = motion.evaluate(t)
    return float(attitude_error_angle(predict(result, t, q, qd).base_quat, truth.base_quat).max())


def as_result(param, values, h):
    """A bare result with ``values`` (the prior's own prediction)."""
    k = len(values)
    return Identification(param.names, param.definitions, values, np.zeros(k), np.zeros((k, k)), 1.0, np.ones(1), 0.0,
                          0, "prior", h, str(param.model.source or param.model.name), param.model.planar,
                          {"parameterization": param.to_dict()})


def map_model(res, prior):
    return with_theta(prior, res.prior.theta["map"])


@pytest.fixture(scope="module")
def cepheus():
    return spaceid.load_model("cepheus", planar=True)


def test_prior_deviations_follow_the_documented_scales():
    body = inertial_vector(2.0, [0.0, 0.0, 0.0], np.diag([0.1, 0.2, 0.25]))
    model = spaceid.load_model("cepheus", planar=True).with_inertials([body] * 3)
    s = prior_deviations(model, 0.1)[:10]
    radius = np.sqrt(0.55 / 4)  # sqrt(tr(I_c) / 2m)
    assert s[0] == pytest.approx(0.2)  # 10 % of the mass
    assert s[1] == pytest.approx(2.0 * 0.1 * radius)  # m L at the CoM, L = 10 % of the radius of gyration
    assert s[4] == pytest.approx(np.hypot(0.01, 2.0 * (0.1 * radius) ** 2))  # Ixx: 10 % and the CoM's m L^2


def test_prior_only_returns_the_prior_with_its_covariance(cepheus):
    """A log at rest (momentum zero, no anchor): the data say nothing; the MAP is the prior."""
    param = minimal_parameters(cepheus)
    prior = cad_prior(cepheus, 0.15, 1)
    t = np.linspace(0, 5, 51)
    rest = simulate(param, param.true_values, lambda t: (np.full((len(t), 2), 0.3), np.zeros((len(t), 2))), t,
                    np.zeros(3), model=cepheus)
    res = identify(param, add_noise(rest, angle=1e-4, rate=1e-4, seed=3), np.zeros(3), prior=prior)
    np.testing.assert_allclose(res.values, param.projection @ full_values(prior), rtol=1e-6)
    np.testing.assert_allclose(res.std, res.prior.prior_std_values, rtol=1e-3)
    assert res.prior.n_data == 0 and res.prior.data_term == "equations" and not res.prior.active


@pytest.mark.parametrize("name, planar", [("cepheus", True),
                                         pytest.param("satellite-7dof", False, marks=pytest.mark.slow)])
def test_rich_data_return_the_data_estimate(name, planar):
    """Informative data and a wide prior: the MAP is the data's estimate on the models that exist.

    The minimal parameters are dependent functions of the standard ones (Cepheus: 8 of rank 7; the
    satellite: 153 of rank 59), so the MAP is the data's estimate projected onto them in the data's
    metric: its distance there is chi-square with ``k - rank`` degrees of freedom, its standard errors
    are at most the data's, it covers the truth, and the data set exactly ``rank`` directions."""
    true = spaceid.load_model(name, planar=planar)
    param, log, h = flown(true, 20.0, 20.0, 4, noise=(1e-5, 1e-5), amplitude=0.4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = identify(param, log, h, estimator="wls")
        res = identify(param, log, h, estimator="wls", prior=cad_prior(true, 0.15, 2), prior_std=1.0)
    assert res.prior.data_term == "estimator"
    rank = np.linalg.matrix_rank(param.projection @ full_values_jacobian(true), tol=1e-9)
    change = res.values - data.values
    assert change @ np.linalg.pinv(data.cov) @ change < chi2.ppf(0.999, param.n_params - rank)
    assert np.all(res.std <= 1.01 * data.std)
    assert np.sqrt(np.mean(((res.values - param.true_values) / res.std) ** 2)) < 1.5
    assert res.prior.n_data == rank


def test_the_attribution_names_who_set_each_direction():
    """A constructed case: the data know the first variable 9 times better than the prior, the second
    half as well; a prior that is not the identity is accounted for. The information is given by
    square roots (``data_root^T data_root``)."""
    prior = np.diag(np.sqrt([4.0, 1.0, 2.0]))
    data = np.diag(np.sqrt([36.0, 0.5, 0.0]))
    out = attribution(data, prior, ["a", "b", "c"])
    assert [d["set_by"] for d in out] == ["data", "prior", "prior"]
    np.testing.assert_allclose([d["ratio"] for d in out], [9.0, 0.5, 0.0], atol=1e-12)
    assert [d["leading"][0][0] for d in out] == ["a", "b", "c"]
    assert out[0]["data_share"] == pytest.approx(0.9)
    rot = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]  # a rotated case: the same ratios
    out = attribution(data @ rot.T, prior @ rot.T, ["a", "b", "c"])
    np.testing.assert_allclose([d["ratio"] for d in out], [9.0, 0.5, 0.0], atol=1e-10)


def _weak_case(seed, planar, tmp_path):
    true = random_robot(seed, planar=planar, max_arms=2, max_joints=3).load(tmp_path)
    param, log, h = flown(true, 6.0, 5.0, seed)  # short, slow, undesigned: the data alone do not determine pi
    prior = cad_prior(true, 0.15, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, log, h, estimator="wls", prior=prior)
    return true, param, prior, res, h


@pytest.mark.parametrize("seed, planar", [(1, True),
                                          *(pytest.param(s, True, marks=pytest.mark.slow) for s in (10, 16)),
                                          *(pytest.param(s, False, marks=pytest.mark.slow) for s in (2, 5, 13, 15))])
def test_weak_data_predict_no_worse_than_the_prior(seed, planar, tmp_path):
    """Undesigned weak motion, a prior 15 % off: the MAP is physical, its covariance positive
    definite, and it predicts a held-out motion's attitude no worse than the prior."""
    true, param, prior, res, h = _weak_case(seed, planar, tmp_path)
    assert not unphysical_bodies(map_model(res, prior))
    assert np.linalg.eigvalsh(res.cov).min() > -1e-12 * np.abs(res.cov).max()
    ours = held_out_error(res, true, h, seed)
    theirs = held_out_error(as_result(param, param.projection @ full_values(prior), h), true, h, seed)
    assert ours <= theirs


def test_a_known_body_or_total_mass_anchors_the_scale_with_a_prior(cepheus):
    param, log, _ = flown(cepheus, 10.0, 10.0, 7, amplitude=0.3)
    prior = cad_prior(cepheus, 0.15, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, log, None, estimator="wls", prior=prior, known={"m_base": 11.5})
        total = identify(param, log, None, estimator="wls", prior=prior, known={"m_total": cepheus.mass})
    assert map_model(res, prior).bodies[0].mass == pytest.approx(11.5, rel=1e-5)
    assert map_model(total, prior).mass == pytest.approx(cepheus.mass, rel=1e-5)
    assert res.prior.known == {"m_base": 11.5}
    with pytest.raises(SpaceidError, match=r"`known` m_base: not a minimal parameter.*combinations.*`prior`"):
        identify(param, log, None, estimator="wls", known={"m_base": 11.5})


def test_result_json_keeps_the_prior_and_old_files_load(cepheus):
    param, log, h = flown(cepheus, 6.0, 5.0, 8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, log, h, estimator="wls", prior=cad_prior(cepheus, 0.15, 4))
    back = Identification.from_dict(json.loads(json.dumps(res.to_dict())))
    assert isinstance(back.prior, PriorRecord) and back.prior.directions == res.prior.directions
    np.testing.assert_allclose(back.prior.prior_values, res.prior.prior_values)
    old = res.to_dict()
    del old["prior"]
    assert Identification.from_dict(old).prior is None


@pytest.fixture(scope="module")
def cli_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("prior_cli")
    true = spaceid.load_model("cepheus", planar=True)
    _, log, _ = flown(true, 6.0, 5.0, 9)
    write_log(folder / "log.csv", log)
    return folder


def test_cli_identify_with_a_prior_prints_the_attribution(cli_log, capsys):
    code = main(["identify", "cepheus", str(cli_log / "log.csv"), "--momentum", "0.5", "--estimator", "wls",
                 "--prior", "cepheus", "--prior-std", "0.3", "-o", str(cli_log / "r.json")])
    assert code == 0
    assert "prior cepheus at 30 %: the data set" in capsys.readouterr().out
    assert json.loads((cli_log / "r.json").read_text())["prior"]["prior_std"] == 0.3


@pytest.mark.parametrize("args, words", [
    (["--prior", "missing.urdf"], "missing.urdf"),
    (["--prior", "satellite-7dof"], "satellite-7dof"),
    (["--prior", "cepheus", "--prior-std", "-1"], "--prior-std"),
    (["--prior", "cepheus", "--prior-std", "nan"], "--prior-std"),
    (["--known", "m_base=11"], "--prior"),
    (["--prior", "cepheus", "--known", "m_base=-3"], "m_base"),
])  # fmt: skip
def test_cli_bad_prior_input_is_one_line_exit_2(cli_log, capsys, args, words):
    code = main(["identify", "cepheus", str(cli_log / "log.csv"), "--momentum", "0.5", "--estimator", "wls", *args,
                 "-o", str(cli_log / "bad.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and words in err[0]
    assert not (cli_log / "bad.json").exists()


def test_the_report_has_a_section_on_the_prior(cepheus, tmp_path):
    from spaceid.studies import write_markdown_report

    param, log, h = flown(cepheus, 6.0, 5.0, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, log, h, estimator="wls", prior=cad_prior(cepheus, 0.15, 6))
    text = write_markdown_report(tmp_path, title="t", result=res, settings={}, figures={}).read_text()
    assert "## CAD prior" in text and res.prior.summary() in text
    assert text.count("| prior |") + text.count("| data |") == min(len(res.prior.directions), 12)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 6))
def test_the_attribution_ratios_are_the_generalised_eigenvalues(seed, n):
    """Any prior and data information: the ratios are the eigenvalues of ``prior^-1 data``, and the
    data set exactly the directions where the ratio exceeds one."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(n, n)), rng.normal(size=(n, n - 1 if n > 1 else 1))
    data_scale = rng.uniform(0.01, 10)
    prior, data = a @ a.T + 0.1 * np.eye(n), b @ b.T * data_scale
    out = attribution(np.sqrt(data_scale) * b.T, np.linalg.cholesky(prior).T, [f"x{i}" for i in range(n)])
    expected = np.sort(np.linalg.eigvals(np.linalg.solve(prior, data)).real)[::-1]
    np.testing.assert_allclose([d["ratio"] for d in out], np.clip(expected, 0, None), atol=1e-8 * expected.max())
    assert all((d["set_by"] == "data") == (d["ratio"] > 1) for d in out)


@pytest.mark.slow
def test_the_prior_sets_what_an_undesigned_motion_leaves_undetermined(tmp_path):
    """A random 66-parameter robot on a random motion that leaves 5 directions undetermined, with a CAD
    prior 20 % off: the data enter as the momentum equations weighted at the prior (their information
    only where the signal stands out of the regressor's noise), the posterior's errors are within 3 of
    its standard errors and smaller than the prior's."""
    model = random_robot(110, planar=False, max_arms=2, max_joints=2).load(tmp_path)
    param = minimal_parameters(model)
    truth, h = param.true_values, np.array([0.3, -0.2, 0.1])
    a, b = 0.2 * np.random.default_rng(5).standard_normal((2, model.n_joints, 3))
    log = simulate(param, truth, FourierTrajectory(model.joints, 10.0, a, b), sample_times(10.0, 264), h, model=model)
    cad = perturbed_prior(model, 4, mass=0.2, moments=0.2, com=0.01)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = identify(param, add_noise(log, angle=1e-4, rate=1e-4, seed=0), h, noise=Noise(*[1e-4] * 4),
                          prior=cad, prior_std=0.2)
    assert result.prior.data_term == "equations" and "do not determine 5 directions" in result.prior.data_reason
    said = [str(w.message) for w in caught if "not determined by the data" in str(w.message)]
    assert said and all(m.endswith("the prior sets them") and "give a prior" not in m for m in said)
    assert (np.abs(result.values - truth) / result.std).max() < 3
    assert np.linalg.norm(result.values - truth) < 0.7 * np.linalg.norm(minimal_parameters(cad).true_values - truth)


@pytest.mark.parametrize("seed, planar, arms, joints", [  # fast: one spatial and one planar robot
    (1, False, 2, 2), *[pytest.param(*case, marks=pytest.mark.slow) for case in [(2, False, 2, 2), (3, False, 2, 2),
                                                                               (392, False, 2, 2), (105, True, 3, 4)]],
    (8352, True, 2, 2)])
def test_noise_free_data_with_a_prior_give_the_truth(seed, planar, arms, joints, tmp_path):
    """Noise-free data of a random robot on a random motion and a CAD prior 20 % / 1 cm off: the truth
    along the directions the log determines, the prior's values along the rest, standard errors that
    cover the error (``test_prior_random_robots.check_prior``). The data are then up to 1e17 times as
    informative as the prior; robots 1 to 3 failed with 'no physically consistent model ... near the
    prior' before the program was scaled, 392 with 'the MAP's convex step did not solve' and 8352
    with a bare LinAlgError (the posterior's information, formed in double precision, singular); 105 (3
    arms of up to 4 joints) stalled 1e-2 off the log's momentum (two bodies' constraints active)."""
    model = random_robot(seed, planar=planar, max_arms=arms, max_joints=joints).load(tmp_path)
    param = minimal_parameters(model)
    h = np.array([0.0, 0.0, 0.1]) if planar else np.array([0.3, -0.2, 0.1])
    a, b = 0.3 * np.random.default_rng(seed).standard_normal((2, model.n_joints, 3))
    motion = FourierTrajectory(model.joints, 10.0, a, b)
    log = simulate(param, param.true_values, motion, sample_times(10.0, 300), h, model=model)
    check_prior(Flown({"seed": seed, "planar": planar, "motion": "random"}, model, param, h, motion, log), noisy=False)


def test_a_map_that_does_not_solve_names_the_cause(cepheus, monkeypatch):
    """Where the convex step does not solve (here: made to fail), one line names the cause and the fix,
    and not anchored parameters (there are none); also when Clarabel's core panics."""
    import spaceid.estimation._prior as prior_module

    param, log, h = flown(cepheus, 6.0, 5.0, 8)
    monkeypatch.setattr(prior_module, "solved_tightly", lambda P, q, rows: None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SpaceidError) as caught:
            identify(param, log, h, estimator="wls", prior=cad_prior(cepheus, 0.15, 4))
    said = str(caught.value)
    assert "did not solve" in said and "identify without `prior`" in said and "anchored" not in said and "\n" not in said


def test_the_equations_data_term_carries_the_sandwich_of_correlated_errors():
    """Whitened equations of a smooth regressor whose errors are correlated over 21 samples (a moving
    average, as a differentiator's): the data term built with their score's covariance implies the
    estimate's actual spread over 300 draws (whitened RMS near 1); without it, the white-noise
    information claims about sqrt(21) times too little (what narrowed the servicer twin's posterior
    bars)."""
    from spaceid.estimation._prior import data_from_equations

    rng = np.random.default_rng(5)
    n, p, width = 1500, 3, 21
    t = np.arange(n)
    A = np.column_stack([np.sin(0.011 * t), 0.3 * np.cos(0.017 * t), 2.0 * np.sin(0.007 * t + 1.0)])  # smooth, as motion is
    theta = np.array([1.0, -2.0, 0.5])
    kernel = np.ones(width) / np.sqrt(width)  # unit variance per sample, correlated over the window
    band = np.zeros((n, n))
    for k in range(-(width - 1), width):  # covariance of a moving average: (width - |k|) / width
        band = band + np.eye(n, k=k) * (width - abs(k)) / width
    score = A.T @ band @ A
    N = 1e-8 * np.eye(p + 1)

    def term(e, with_sandwich):
        white = np.column_stack([A, -(A @ theta + e)])
        return data_from_equations(white, N, p, "test", {}, np.arange(p),
                                   (lambda bread: bread @ score @ bread.T) if with_sandwich else None)

    for with_sandwich, low, high in ((True, 0.8, 1.25), (False, 3.0, 6.0)):
        z = []
        for _ in range(300):
            e = np.convolve(rng.standard_normal(n + width - 1), kernel, mode="valid")
            d = term(e, with_sandwich)
            z.append(d.L @ theta - d.r)  # the data term's whitened error at the truth
        rms = np.sqrt(np.mean(np.square(z)))
        assert low < rms < high, (with_sandwich, rms)


def test_a_column_no_noisy_signal_enters_is_information_not_a_failure():
    """A parameter whose column carries none of the signals' noise (the base inertia's when the base rate is
    given as noise-free: the satellite's and servicer's presets with --noise-base-rate 0, where
    ``identify --prior`` ended in "SVD did not converge"): its noise scale had been 0 and 0 / 0 filled the noise
    root with NaN. It is now information, as with a vanishing noise: the same data term as with that column's
    noise 1e-12 of the others'."""
    from spaceid.estimation._prior import data_from_equations

    rng = np.random.default_rng(3)
    n, p = 400, 4
    A, theta = rng.standard_normal((n, p)), np.array([1.0, -2.0, 0.5, 3.0])
    white = np.column_stack([A, -(A @ theta + 1e-3 * rng.standard_normal(n))])
    M = 1e-3 * rng.standard_normal((50, p + 1))
    M[:, 2] = 0.0  # the third parameter's column: no noise
    terms = [data_from_equations(white, M.T @ M, p, "test", {}, np.arange(p))]
    M[:, 2] = 1e-15 * rng.standard_normal(50)
    terms.append(data_from_equations(white, M.T @ M, p, "test", {}, np.arange(p)))
    for d in terms:
        assert np.all(np.isfinite(d.L)) and np.all(np.isfinite(d.r)) and len(d.L) == p
    np.testing.assert_allclose(terms[0].L.T @ terms[0].L, terms[1].L.T @ terms[1].L, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.solve(terms[0].L, terms[0].r), np.linalg.solve(terms[1].L, terms[1].r),
                               rtol=1e-6)


def _least_squares(x0: float, infeasible: bool = False) -> tuple:
    """``min (x - x0)^2`` subject to ``x <= 10`` (and ``x >= 1``, ``x <= 0`` when ``infeasible``), in
    :func:`~spaceid.models.internal.solved_tightly`'s form: ``(P, q, rows)``."""
    from spaceid.models.internal import cone

    a, b = ([[1.0], [-1.0], [1.0]], [10.0, -1.0, 0.0]) if infeasible else ([[1.0]], [10.0])
    return 2.0 * np.eye(1), np.array([-2.0 * x0]), [(np.array(a), np.array(b), cone("nonnegative", len(b)))]


def _failing_solver(monkeypatch, fails):
    """Clarabel's solver made to fail on its first solves: ``fails`` a list of what each raises or returns instead
    (an exception, or a status name), then the real solver; the settings' ``chordal_decomposition_enable`` of each
    call is recorded in the list returned."""
    import clarabel

    real, calls = clarabel.DefaultSolver, []

    class Failing:
        def __init__(self, *args):
            self.args, self.solver = args, real(*args)
            calls.append(args[-1].chordal_decomposition_enable)

        def solve(self):
            if len(calls) > len(fails):
                return self.solver.solve()
            failure = fails[len(calls) - 1]
            if isinstance(failure, BaseException):
                raise failure
            return SimpleNamespace(status=failure, x=None)

    monkeypatch.setattr(clarabel, "DefaultSolver", Failing)
    return calls


def test_a_solver_panic_is_a_failed_solve(monkeypatch):
    """Clarabel's Rust core can panic (pyo3's PanicException, a BaseException): a failed solve, not a
    traceback; an interrupt still propagates."""
    from spaceid.models.internal import solved_tightly

    PanicException = type("PanicException", (BaseException,), {})
    _failing_solver(monkeypatch, [PanicException("Eigval error"), PanicException("Eigval error")])
    assert solved_tightly(*_least_squares(1.0)) is None
    _failing_solver(monkeypatch, [KeyboardInterrupt()])
    with pytest.raises(KeyboardInterrupt):
        solved_tightly(*_least_squares(1.0))


def test_a_failed_solve_is_tried_again_with_whole_cones(monkeypatch):
    """A program on which Clarabel fails (insufficient progress, a numerical error, or a panic) is solved once more
    with its positive semidefinite cones whole (planar random robot 311720's export stopped so at every step, and was
    refused although the true robot was inside its ellipsoid; the example in ``test_random_robots``); an infeasible
    program is not tried again."""
    from spaceid.models.internal import solved_tightly

    for failure in ("InsufficientProgress", "NumericalError", type("PanicException", (BaseException,), {})()):
        calls = _failing_solver(monkeypatch, [failure])
        assert solved_tightly(*_least_squares(1.0)) == pytest.approx([1.0]) and calls == [True, False]
    calls = _failing_solver(monkeypatch, [])
    assert solved_tightly(*_least_squares(1.0, infeasible=True)) is None and calls == [True]
