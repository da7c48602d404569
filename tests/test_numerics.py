"""Numerics of identification: noise-free recovery at high scaled condition numbers (orthogonal
factorisation, not normal equations), and one-line errors instead of tracebacks at any conditioning.

The attainable accuracy. The regressor and the logged rates are rounded to double precision, so
even the exact least-squares solution of the rounded data is off by about ``eps cond`` (relative,
on the largest parameter) in the least excited direction. The bound used below is 1e-10 at a
scaled condition number of 1e6 and grows in proportion above it; the factorisation reaches
about 1 % of ``eps cond`` (e.g. 8e-9 at 1.2e9), the normal equations ``eps cond^2`` (3e-5 at 1.3e6).
"""

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import random_tree
from scipy.linalg import cho_factor, cho_solve

from spaceid import SpaceidError
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import ESTIMATORS, Noise, identify
from spaceid.estimation._equations import _equations, _split
from spaceid.models._model import _validate
from spaceid.motion import simulate

H_SPATIAL = np.array([0.3, -0.2, 0.5])
H_PLANAR = np.array([0.0, 0.0, 0.5])


def _motion(n_joints, amplitude):
    """Two-tone joint motion of ``amplitude`` [rad]: small amplitudes excite weakly."""
    w = np.array([1.1, 1.7, 0.9, 1.3, 2.3, 0.7, 1.9, 0.6])[:n_joints]

    def motion(t):
        t = np.asarray(t)[:, None]
        return amplitude * (np.sin(w * t + 0.3) + 0.3 * np.sin(2.9 * w * t)), amplitude * (
            w * np.cos(w * t + 0.3) + 0.87 * w * np.cos(2.9 * w * t)
        )

    return motion


def _tiny_chain(size=0.01, n=6):
    """A planar six-body chain whose two distal links are ``size`` times smaller (lengths, first
    moments by ``size``, inertias by ``size**2``)."""
    tree = random_tree(np.random.default_rng(3), list(range(n - 1)), planar=True)
    factor = np.r_[1.0, [size] * 3, [size**2] * 6]
    bodies = [b if i < n - 2 else dataclasses.replace(b, translation=b.translation * size, inertial=b.inertial * factor)
              for i, b in enumerate(tree.bodies)]  # fmt: skip
    return _validate(dataclasses.replace(tree, bodies=tuple(bodies)))


@pytest.fixture(scope="module")
def dual_arm():
    """A random spatial base with two arms of two links (66 minimal parameters)."""
    return minimal_parameters(random_tree(np.random.default_rng(7), [0, 1, 0, 3], planar=False))


@pytest.fixture(scope="module")
def chain():
    return minimal_parameters(_tiny_chain())


def _spatial_log(param, amplitude, duration, n=300):
    return simulate(param, param.true_values, _motion(len(param.model.joints), amplitude), np.linspace(0, duration, n),
                    H_SPATIAL, initial_quat=[0.8, 0.6, 0, 0])  # fmt: skip


def _planar_log(param, amplitude):
    return simulate(param, param.true_values, _motion(len(param.model.joints), amplitude), np.linspace(0, 20, 400),
                    H_PLANAR)  # fmt: skip


# (system, motion amplitude [rad], duration [s] or None, target scaled condition number)
CASES = [("spatial", 0.5, 20, 1e6), ("spatial", 0.15, 5, 1e9), ("planar", 0.01, None, 1e6),
         ("planar", 3.2e-4, None, 1e9)]  # fmt: skip


def _case(system, amplitude, duration, dual_arm, chain):
    if system == "spatial":
        return dual_arm, _spatial_log(dual_arm, amplitude, duration), H_SPATIAL
    return chain, _planar_log(chain, amplitude), H_PLANAR


def _relative_error(param, values):
    return np.abs(values - param.true_values).max() / np.abs(param.true_values).max()


@pytest.mark.parametrize(("system", "amplitude", "duration", "target"), CASES)
def test_noise_free_recovery_at_high_condition_numbers(dual_arm, chain, system, amplitude, duration, target):
    param, log, h = _case(system, amplitude, duration, dual_arm, chain)
    ident = identify(param, log, h, estimator="ols")
    cond = ident.diagnostics.condition_number_scaled
    assert target / 5 < cond < target * 5
    assert _relative_error(param, ident.values) <= 1e-10 * max(1.0, cond / 1e6)


def _normal_equations(A, b):
    """The former solve: Cholesky of the column-scaled normal equations, one refinement step."""
    scale = np.linalg.norm(A, axis=0)
    factor = cho_factor((A.T @ A) / np.outer(scale, scale))
    rhs = (A.T @ b) / scale
    x = cho_solve(factor, rhs)
    x += cho_solve(factor, rhs - (A.T @ (A @ (x / scale))) / scale)
    return x / scale


@pytest.mark.parametrize("system", ["spatial", "planar"])
def test_orthogonal_factorisation_beats_the_normal_equations(dual_arm, chain, system):
    param, log, h = _case(*{"spatial": ("spatial", 1.0, 5), "planar": ("planar", 0.01, None)}[system], dual_arm, chain)
    eq, _ = _equations(param, log, h, None, "log")
    old = _relative_error(param, _normal_equations(*_split(eq.phi(eq.signals(log)))))
    ident = identify(param, log, h, estimator="ols")
    new = _relative_error(param, ident.values)
    assert ident.diagnostics.condition_number_scaled > 1e6
    assert new <= 1e-10 and old > 1e-7 and new < 1e-3 * old


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("amplitude", [*(pytest.param(a, marks=pytest.mark.slow) for a in (0.09, 0.03)),
                                       1e-4])  # fast: the nearest to singular
def test_no_traceback_at_any_conditioning(dual_arm, estimator, amplitude):
    """Scaled condition numbers ~5e9, ~2e11 and ~1e16 (the check switched off: the estimators see
    the nearly singular systems themselves): a result or a one-line SpaceidError, nothing else."""
    log = _spatial_log(dual_arm, amplitude, 5, n=200)
    noise = Noise(angle=1e-3, rate=1e-3, base_rate=1e-3)
    for cond_limit in (1e10, np.inf):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. maximum likelihood not converging
            try:
                ident = identify(dual_arm, log, H_SPATIAL, estimator=estimator, noise=noise, cond_limit=cond_limit)
            except SpaceidError as exc:
                assert "\n" not in str(exc) and str(exc).startswith("log: ")
            else:
                assert np.all(np.isfinite(ident.values))


def test_unexcited_directions_are_named(dual_arm):
    with pytest.raises(SpaceidError, match=r"rank-deficient \(scaled cond .*\); not excited: pi\d+"):
        identify(dual_arm, _spatial_log(dual_arm, 0.03, 5, n=200), H_SPATIAL, estimator="ols")


@pytest.mark.parametrize(("amplitude", "duration", "cholesky"), [(0.5, 20, True), (0.15, 5, False)])
def test_cholesky_factor_with_refinement_agrees_with_householder(dual_arm, amplitude, duration, cholesky):
    """Scaled cond ~1e6: the factor comes from the Gram matrix's Cholesky factor, its solution
    refined on the data, and agrees with blocked Householder QR (solution, Gram matrix), with and
    without residuals; cond ~1e9 (beyond GRAM_COND): the Cholesky path declines."""
    from spaceid.estimation import _linalg as linalg

    eq, _ = _equations(dual_arm, _spatial_log(dual_arm, amplitude, duration), H_SPATIAL, None, "log")
    A, b = _split(eq.phi(eq.signals(_spatial_log(dual_arm, amplitude, duration))))
    scale = linalg._column_scale(A)
    if not cholesky:
        assert linalg._gram_factor(A, b, scale) is None
        return
    for rhs in (b, b + 1e-3 * np.random.default_rng(0).standard_normal(len(b)) * np.abs(b).max()):
        R = linalg._gram_factor(A, rhs, scale)
        householder = linalg._factor_of_rows(A, rhs, scale)
        x, x_h = linalg._solve_factor(R, scale)[0], linalg._solve_factor(householder, scale)[0]
        assert np.abs(x - x_h).max() <= 1e-9 * np.abs(x_h).max()
        gram, gram_h = R[:-1, :-1].T @ R[:-1, :-1], householder[:-1, :-1].T @ householder[:-1, :-1]
        assert np.abs(gram - gram_h).max() < 1e-13 * np.abs(gram_h).max()
        assert abs(R[-1, -1]) == pytest.approx(abs(householder[-1, -1]), rel=1e-6, abs=1e-12 * np.linalg.norm(b))


@pytest.mark.parametrize("threads", [1, 2])
def test_gram_matrix_of_the_rows_as_they_are_is_that_of_the_scaled_rows(monkeypatch, threads):
    """The blockwise Gram matrix of ``[A / scale | b]``, formed from the rows as they are (views of the stacked
    ``[A | -b]``, several blocks, on one or two threads) and scaled once: each entry as the product of the scaled
    copy's columns to 1e-13 of ``sqrt(G_ii G_jj)`` (its rounding), the right-hand side's sign and the scale's
    placement included; columns of very different norms (1e-6 to 1e6)."""
    from spaceid.estimation import _linalg

    monkeypatch.setattr(_linalg, "threads_for", lambda tasks: min(tasks, threads))
    rng = np.random.default_rng(5)
    phi = rng.standard_normal((3 * _linalg.ROW_BLOCK + 17, 3, 9)) * np.logspace(-6, 6, 9)
    A, b = _split(phi)  # A: a view with a row stride of 9 columns, b = -phi[..., -1]
    scale = _linalg._column_scale(A)
    G = _linalg._gram_of_rows(A, b, scale)
    scaled = np.column_stack([A / scale, b])
    exact = scaled.T @ scaled
    size = np.sqrt(np.outer(np.diag(exact), np.diag(exact)))
    assert np.max(np.abs(G - exact) / size) < 1e-13
    assert np.allclose(np.diag(G)[:-1], 1.0, rtol=1e-13, atol=0)  # unit-norm columns


@pytest.mark.parametrize("rows", [1, 2, 3])
def test_lower_inverse_of_the_whiteners_is_their_inverse(rows):
    """The batched inverse of lower-triangular whiteners by forward substitution: lower triangular, and
    ``L_n^-1 L_n = 1`` to ``eps cond(L_n)`` for factors whose scales span twelve decades."""
    from spaceid.estimation._linalg import _whiten, lower_inverse

    rng = np.random.default_rng(rows)
    J = rng.standard_normal((500, rows, rows)) * np.logspace(-6, 6, 500)[:, None, None]
    L = _whiten(J @ np.swapaxes(J, -1, -2))
    inverse = lower_inverse(L)
    assert not np.any(np.triu(inverse, 1))
    cond = np.linalg.cond(L)
    error = np.abs(inverse @ L - np.eye(rows)).max(axis=(1, 2))
    assert np.all(error <= 50 * np.finfo(float).eps * cond), (error / cond).max()
    reference = np.linalg.inv(L)  # LAPACK's LU of each, as accurate
    gap = np.abs(inverse - reference).max(axis=(1, 2)) / np.abs(reference).max(axis=(1, 2))
    assert np.all(gap <= 50 * np.finfo(float).eps * cond), (gap / cond).max()


def test_an_svd_lapack_does_not_converge_on_is_taken_by_qr_iteration(monkeypatch):
    """Where NumPy's SVD (LAPACK's divide and conquer) raises "did not converge" on a finite matrix (an export's
    conditions on spatial random robot 1307800870, an ``@example`` in ``test_random_robots``), ``spaceid._svd.svd``
    decomposes it by QR iteration: the same factors (of single and stacked matrices, with and without the vectors); a
    matrix with a NaN still raises NumPy's error."""
    from spaceid import _svd

    rng = np.random.default_rng(3)
    stacked = rng.standard_normal((3, 7, 5)) * np.logspace(0, -40, 5)  # singular values over 40 decades
    expected = [np.linalg.svd(stacked, full_matrices=False), np.linalg.svd(stacked[0]),
                np.linalg.svd(stacked, compute_uv=False)]  # fmt: skip

    def diverges(*args, **kwargs):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(_svd.np.linalg, "svd", diverges)
    got = [_svd.svd(stacked, full_matrices=False), _svd.svd(stacked[0]), _svd.svd(stacked, compute_uv=False)]
    for (u, s, vt), (u_, s_, vt_) in zip(got[:2], expected[:2]):
        assert u.shape == u_.shape and vt.shape == vt_.shape
        np.testing.assert_allclose(s, s_, rtol=1e-12, atol=1e-15 * s_.max())
        k = s.shape[-1]
        np.testing.assert_allclose(u[..., :k] * s[..., None, :] @ vt[..., :k, :], stacked[0] if s.ndim == 1 else
                                   stacked, atol=1e-13)  # fmt: skip
    np.testing.assert_allclose(got[2], expected[2], rtol=1e-12, atol=1e-15)
    with pytest.raises(np.linalg.LinAlgError):
        _svd.svd(np.array([[np.nan, 1.0], [0.0, 1.0]]))
