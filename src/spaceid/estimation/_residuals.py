"""The residual test for an unmodelled drift of the momentum (docs/theory/drift.md).

After an identification without drift terms, the equation residuals of a log whose momentum
drifted follow the drift: a trend against time (a constant external torque) and against the
attitude change (base friction), and they are correlated from sample to sample. The test:

- trend: the whitened equations are refitted with the ``torque`` and ``viscous`` drift columns
  added (:mod:`spaceid.estimation._drift`), and a Wald test asks whether their coefficients are
  zero, with the heteroscedasticity-consistent covariance of the residuals scaled by their
  leverage (the jackknife's, HC3; Newey-West over the differentiator's window when rates were
  differentiated, whose errors are correlated) and the F distribution of ``Wald / q`` for ``q``
  coefficients and the residual degrees of freedom; it decides, at the significance level
  ``DRIFT_ALPHA``, and only when the fitted drift also changes the momentum by more than
  ``DRIFT_FLOOR`` of the right-hand side (round-off of a noise-free log is not a drift);
- whiteness: the lag-1 autocorrelation ``rho`` of the whitened residuals in time order, with
  the Durbin-Watson statistic (about ``2 (1 - rho)``: 2 for white residuals) and the one-sided
  p-value of ``rho sqrt(n)`` (normal under white residuals), recorded as supporting evidence
  (differentiated rates make residuals correlated without any drift, so it does not decide).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

from .._distributions import f_sf, norm_sf

from ._differentiated import differentiated_series, propagated_covariance
from ._determined import UNDETERMINED, equation_noise, noise_to_signal, widened
from ._drift import drift_basis, drift_names
from ._linalg import _equation_whitener, _solve_factor, lower_inverse
from ._stream import _chunks, _streamed_factor
from .._threads import one_blas_thread
from ._uncertainty import _hac, correlation_length, larger_of

DRIFT_ALPHA = 1e-3
"""Significance level of the drift test: the probability that it warns on a log without drift."""

DRIFT_FLOOR = 1e-6
"""Smallest fitted momentum drift, relative to the RMS right-hand side, that the test reports."""

CONFOUNDED = 0.01
"""Largest share of a drift coefficient's variance from directions the data do not determine for which
the test decides: beyond it a drift cannot be told from those parameters, and the test stays silent
(the identification's diagnostics name the directions). Small, because what those directions leave
in the residuals is of the size of the parameters along them, not of the noise: on a random spatial
robot's undesigned log (39 such directions) a share of 7 % made the test fire at p = 3e-7. The share
counts the errors-in-variables allowance's spread too (:func:`_confounded`)."""

_CANDIDATES = ("torque", "viscous")


def _serial_sums(white, before) -> np.ndarray:
    """``sum r_n^2``, ``sum r_n r_(n-1)`` and ``sum (r_n - r_(n-1))^2`` (rows pooled) of the residuals
    ``white (k, rows)`` of a chunk in time order, ``before (rows,)`` the previous chunk's last (None for
    the first): the lag-1 autocorrelation and the Durbin-Watson statistic are ratios of their totals."""
    w = white if before is None else np.vstack([before, white])
    return np.array([np.sum(white**2), np.sum(w[1:] * w[:-1]), np.sum(np.diff(w, axis=0) ** 2)])


LEVERAGE_SKETCH = 32
"""Columns of the Gaussian sketch by which the leverages of a fit of more than :data:`LEVERAGE_SKETCHED`
unknowns are estimated (a Johnson-Lindenstrauss estimate, relative error about ``sqrt(2 / 32)`` = 25 % of
each leverage, the HC3 factor's ``h / (1 - h)`` of it: 0.5 % on a 10,000-sample servicer log, whose leverages
are about 0.02); the samples estimated above :data:`LEVERAGE_EXACT` are recomputed exactly. Exact ones
cost as much as the fit's factorisation again (``n rows p^2``), the sketch ``n rows p 32``: its product is
most of the drift test's time (64 columns: 0.02 s more of the servicer's 0.14 s, for 18 % of each leverage)."""

LEVERAGE_SKETCHED = 256
"""Unknowns above which the leverages are sketched (:data:`LEVERAGE_SKETCH`): exact up to it."""

LEVERAGE_EXACT = 0.1
"""Largest estimated leverage (trace of a sample's block) that is kept from the sketch."""

LEVERAGE_SEED = 0
"""Seed of the sketch: the test is a deterministic function of the log."""


def _leverage_root(factor) -> tuple:
    """``(B (c, k), exact)``: ``B B^T`` the inverse Gram matrix of the fit whose column-scaled factor is
    ``factor = (scale (c,), R (c + 1, c + 1))`` (``B = diag(1 / scale) R^-1``, ``k = c``), or its sketch
    (``B Omega / sqrt(k)``, ``Omega (c, k)`` Gaussian, ``k`` = :data:`LEVERAGE_SKETCH`) when ``c`` exceeds
    :data:`LEVERAGE_SKETCHED`; ``exact`` whether it is the root itself."""
    scale, R = factor
    c = len(scale)
    exact = c <= LEVERAGE_SKETCHED
    omega = np.eye(c) if exact else np.random.default_rng(LEVERAGE_SEED).standard_normal((c, LEVERAGE_SKETCH))
    with one_blas_thread():
        root = solve_triangular(R[:c, :c], omega) / scale[:, None]
    return (root, True) if exact else (root / np.sqrt(LEVERAGE_SKETCH), False)


def _leverage_adjusted(M, root, ginv, r, W=None):
    """Residuals ``r (n, rows)`` of the least-squares fit of ``M (n, rows, c)`` divided by one minus their
    leverage, ``(I - H_n)^-1 r_n`` with ``H_n = M_n ginv M_n^T`` (``ginv`` the fit's inverse Gram matrix):
    the scores of these make White's covariance the jackknife's (HC3), whose tests keep their level on
    short logs, where each sample's own fit shrinks its residual (35 samples for 10 unknowns: 6 of 400
    clean logs fired at 1e-3 with the plain residuals, 1 with these). ``H_n = W_n W_n^T`` with
    ``W = M B`` (given, or formed here), ``root = (B, exact)`` of :func:`_leverage_root`; from a sketch, the
    samples whose leverage comes out above :data:`LEVERAGE_EXACT` recomputed with ``ginv``. ``M`` may be
    :class:`_Columns`."""
    B, exact = root
    with one_blas_thread():
        if W is None:  # one GEMM (batched: 4x slower)
            W = M @ B if isinstance(M, _Columns) else (M.reshape(-1, M.shape[-1]) @ B).reshape(*M.shape[:2], -1)
        H = np.einsum("nrk,nsk->nrs", W, W)
        if not exact:
            high = np.flatnonzero(np.trace(H, axis1=1, axis2=2) > LEVERAGE_EXACT)
            Mh = M[high]
            H[high] = np.einsum("nrp,pq,nsq->nrs", Mh, ginv, Mh, optimize=True)
    rest = np.eye(r.shape[1]) - H  # eigenvalues in [0, 1]: the determinant bounds the smallest
    # solved where rest's condition number is at most 1e6 (its smallest eigenvalue at least the determinant:
    # a twentieth of pinv's time); pinv elsewhere (a sample fitted exactly: rest singular)
    adjusted, near = np.empty_like(r), np.linalg.det(rest) < 1e-6
    adjusted[~near] = np.linalg.solve(rest[~near], r[~near][..., None])[..., 0]
    adjusted[near] = np.einsum("nrs,ns->nr", np.linalg.pinv(rest[near]), r[near])
    return adjusted


class _Columns:
    """The columns ``M = L^-1 [A | C] (k, rows, p + q)`` of a chunk of the drift test's refit, kept as built:
    the equations ``E = [A | -b] (k, rows, p + 1)``, the candidates ``C (k, rows, q)`` and the whitener's
    inverses ``inverse = L^-1 (k, rows, rows)`` (None: not whitened), so that the regressor is neither copied
    nor whitened whole: ``M @ X`` (``X (p + q,)`` or ``(p + q, m)``) whitens the product, ``M[rows]`` (an
    array) as for the array itself. (A whitened copy of 10,000 servicer samples took 0.35 s.)"""

    def __init__(self, E, C, inverse=None):
        self.E, self.C, self.inverse = E, C, inverse
        self.shape = (*E.shape[:2], E.shape[-1] - 1 + C.shape[-1])

    def _white(self, Y):  # L^-1 Y sample by sample, Y (k, rows, ...)
        if self.inverse is None:
            return Y
        return (self.inverse @ Y) if Y.ndim == 3 else np.einsum("nrs,ns->nr", self.inverse, Y)

    def _product(self, X, rhs):  # [A | C] X, plus rhs times -b (rhs 0, 1 or one per column), unwhitened: one GEMM
        p = self.E.shape[-1] - 1
        E, C = self.E.reshape(-1, p + 1), self.C.reshape(-1, self.C.shape[-1])
        top = np.concatenate([X[:p], np.broadcast_to(rhs, (1, *X.shape[1:]))])
        # several columns: OpenBLAS forms the tall product 1.4x faster transposed (measured: 0.066 s against 0.047
        # for the servicer's 30,000 x 498 by 72, the copy back included)
        out = E @ top if X.ndim == 1 else np.ascontiguousarray((top.T @ E.T).T)
        out += C @ X[p:]
        return out.reshape(*self.shape[:2], *X.shape[1:])

    def __matmul__(self, X):
        return self._white(self._product(X, 0.0))

    def residual(self, v):
        """``M v - L^-1 b`` ``(k, rows)`` (the equations' rows are ``[A | -b]``)."""
        return self._white(self._product(v, 1.0))

    def with_residual(self, X, v):
        """``(M @ X, residual(v))`` from one pass over the regressor (``X (p + q, m)``, ``v (p + q,)``)."""
        both = self._white(self._product(np.column_stack([X, v]), np.append(np.zeros(X.shape[1]), 1.0)))
        return both[..., :-1], both[..., -1]

    def candidates(self):
        """``L^-1 C`` ``(k rows, q)``."""
        return self._white(self.C).reshape(-1, self.C.shape[-1])

    def cross(self, Y):
        """``(L^-1 A)^T Y`` ``(p, m)`` for ``Y (k, rows, m)``: ``A^T (L^-T Y)``, the regressor as built."""
        back = Y if self.inverse is None else np.swapaxes(self.inverse, -1, -2) @ Y
        p = self.E.shape[-1] - 1  # Y^T E, transposed: twice as fast as E^T Y for few columns (measured)
        return (back.reshape(-1, Y.shape[-1]).T @ self.E.reshape(-1, p + 1))[:, :-1].T

    def __getitem__(self, rows):
        joined = np.concatenate([self.E[rows, :, :-1], self.C[rows]], -1)
        return joined if self.inverse is None else self.inverse[rows] @ joined

    def whole(self):
        """``M`` as one array (a copy)."""
        return self[slice(None)]


def _drift_equations(phi, cols, L) -> tuple:
    """The equations of ``phi = [A | -b] (k, rows, p + 1)`` with the candidate columns ``C (k, rows, q)``:
    ``[A | C]`` as :class:`_Columns`, whitened by ``L (k, rows, rows)`` (None: as they are), ``C`` and ``|b|^2``."""
    return _Columns(phi, cols, None if L is None else lower_inverse(L)), cols, float(np.sum(phi[..., -1] ** 2))


def _completed_gram(gram, residuals) -> np.ndarray:
    """The Gram matrix ``(p + q + 1, p + q + 1)`` of the refit's ``[A | C | -r]`` (:func:`drift_test`) from that
    of ``A``, ``gram (p, p)`` (the estimator's own factorisation), ``residuals`` giving each chunk's columns
    (:class:`_Columns`) and residuals ``r (k, rows)`` of the estimate: only the products with ``[C | -r]`` are
    formed, ``q + 1`` columns, not ``p + q + 1`` (the regressor's Gram matrix cost as much as the estimate's
    factorisation again: 0.2 s of 10,000 servicer samples)."""
    cross, inner = 0.0, 0.0
    with one_blas_thread():
        for M, white in residuals:
            Y = np.hstack([M.candidates(), -white.reshape(-1, 1)])
            cross, inner = cross + M.cross(Y.reshape(*white.shape, -1)), inner + Y.T @ Y
    return np.block([[gram, cross], [cross.T, inner]])


def candidate_basis(log) -> np.ndarray:
    """The momentum change per unit coefficient of the drift test's candidates, ``torque`` and ``viscous``,
    ``(n, q, 3)`` in inertial axes (:func:`~spaceid.estimation._drift.drift_basis`, a quadrature of the base
    rate): formed once per identification for :func:`drift_columns` and :func:`drift_test`."""
    return drift_basis(log, _CANDIDATES)


def drift_columns(eq, log, basis=None):
    """The drift test's candidate columns as :func:`~spaceid.estimation._determined.equation_noise` takes
    them, ``columns(part, signals, rows)`` ``(m, rows, q)``: the momentum change per unit ``torque`` and
    ``viscous`` coefficient, in base axes at the signals' attitude (``basis``: :func:`candidate_basis`, if
    formed)."""
    basis = candidate_basis(log) if basis is None else basis

    def columns(part, signals, rows):
        rot_t = np.swapaxes(part.unpack(signals)[3], -1, -2)[:, slice(2, 3) if eq.planar else slice(None)]
        return -np.einsum("nri,nki->nrk", rot_t, basis[rows])

    return columns


def _confounded(noise, R, p, slope, values, cdd) -> float:
    """The largest share of a drift coefficient's variance that comes from directions of ``[A | C]`` the
    data do not determine (:mod:`spaceid.estimation._determined`: the regressor's noise as large as its
    signal), directly or through the errors-in-variables allowance (:func:`_errors_in_variables`).
    ``R (p + q, p + q)`` is the triangular factor of the whitened ``[A | C]``, ``noise`` the noise Gram
    matrix of ``[A | C | -b]`` (:func:`~spaceid.estimation._determined.equation_noise`), ``p`` the columns of
    ``A``, ``slope (q, p)`` the allowance's change per unit of the estimate (:func:`_errors_in_variables`),
    ``values`` the estimate and the model's own values of the unknowns (``(p,)`` each) and ``cdd (q, q)`` the
    drift coefficients' covariance as tested.

    Along such directions the estimate is pulled towards zero, and the drift columns, which carry no
    noise of their own beyond the attitude's, take up the momentum they leave: the test would read a
    parameter the log does not determine as a drift (on the 7-DOF satellite's undesigned conserved
    log 57 of 153 directions were noise, and 92-97 % of each drift coefficient's first-order variance
    theirs). The allowance is linear in the estimate, and the estimate's coordinates along them are known
    only to their scale (:func:`~spaceid.estimation._determined.widened`'s): the allowance moves with them.
    At zero momentum, with a parameter anchored, that carried the test: on conserved logs of random robots
    the first-order variance share was under a hundredth where the drift coefficients came out 24 times
    the allowance (p down to 4e-55), and the allowance's own spread was 97 % or more of theirs."""
    mu, directions = noise_to_signal(R, noise[:-1, :-1], UNDETERMINED)  # (empty when none is undetermined)
    d = directions[p:]
    share = float(np.max(np.sum(d[:, mu >= UNDETERMINED] ** 2, 1) / np.maximum(np.sum(d**2, 1), 1e-300)))
    if share == 0.0:
        return share
    q = len(d)
    spread = widened(np.zeros((p + q, p + q)), mu, directions, *(np.append(v[:p], np.zeros(q)) for v in values))
    pulled = np.einsum("ij,jk,ik->i", slope, spread[:p, :p], slope)
    return max(share, float(np.max(pulled / np.maximum(pulled + np.diag(cdd), 1e-300))))


def _errors_in_variables(noise, ginv, theta, p) -> tuple:
    """``(allowance (q,), slope (q, p))``: the drift coefficients that the refit takes up from the regressor's
    own noise, and their change per unit of ``theta`` (the allowance is linear in it): its
    first-order errors-in-variables bias ``-[G^-1 N [theta; 0; 1]]_d`` (``N`` the noise Gram matrix of
    ``[A | C | -b]``, ``ginv = G^-1`` the refit's, ``p`` the columns of ``A``). Noise in the regressor
    correlates with it (``E[A^T dA] = N``), and the drift columns, which carry none, take up what it
    pulls out of ``theta``: on a designed motion with rates differentiated from noisy angles the
    drift coefficients sat three of their standard errors from zero in the direction this predicts,
    seed after seed. The right-hand side shares the columns' noise where parameters are anchored (their
    columns move into ``b``): an anchor's share of the bias is its column's, as if it were estimated."""
    slope = -(ginv[p:] @ noise[:-1, :p])
    return slope @ theta[:p] - ginv[p:] @ noise[:-1, -1], slope


def drift_test(eq, x, phi, sigma, theta, estimator, log, whitener=None, chunk=None, candidates=None,
               noise=None, gram=None, basis=None, residuals=None, nominal=None) -> dict:
    """Whether the residuals of a drift-free identification show an unmodelled drift.

    Parameters
    ----------
    eq : Equations
        The equations identified (without drift terms).
    x, phi : ndarray
        Their signals ``(n, n_x)`` and stacked ``[A | -b]`` ``(n, rows, p + 1)``; ``phi`` None: built
        a chunk at a time.
    sigma : ndarray of shape (n_x,)
        Signal noise levels (whitening; unused for ``ols``).
    theta : ndarray of shape (p,)
        The estimate.
    estimator : str
    log : Log
    whitener : ndarray of shape (n, rows, rows), optional
        Cholesky factors of the equation-error covariances to whiten by (the estimator's own: ML's at
        the corrected signals); default: at the measured signals and ``theta``.
    chunk : int, optional
        With ``phi`` None: samples per chunk (:mod:`spaceid.estimation._stream`). The test is two passes
        either way, the sums being the same: the Gram matrix of the equations with the drift columns
        and their correlation with the residuals of ``theta``, whose least squares is the refit's
        correction to ``theta`` (as accurate as one refinement step from the refined ``theta``: no
        passes to refine it), then the scores and the fitted drift.
    candidates : tuple, optional
        Other columns to test instead of the drift's: ``(names, columns)``, ``columns(rows)`` those of
        the samples ``rows`` (a slice), ``(k, rows, q)`` (the gyro bias's:
        :func:`spaceid.estimation._gyro_bias.bias_test`).
    noise : ndarray of shape (p + q + 1, p + q + 1) or callable, optional
        The noise Gram matrix of the equations with the drift columns and ``-b`` last (:func:`drift_columns`,
        :func:`~spaceid.estimation._determined.equation_noise` with ``rhs``) if already formed, or a function that
        returns it (formed beside the test: called once the test needs it).
    gram : ndarray of shape (p, p), optional
        The Gram matrix of the equations' columns ``A`` whitened as here (by ``whitener``; as they are for
        ``ols``), if already formed (the estimate's factorisation): the refit's is completed from it by the
        candidate columns and the residuals alone (:func:`_completed_gram`).
    basis : ndarray of shape (n, q, 3), optional
        :func:`candidate_basis` of ``log``, if already formed.
    residuals : ndarray of shape (n, rows), optional
        ``phi [theta; 1]``, the residuals of ``theta``, if already formed (``ols`` in memory: its covariance's).
    nominal : ndarray of shape (p,), optional
        The model's own values of the unknowns (the URDF's inertias), a second scale of the estimate's
        coordinates that the data do not determine (:func:`_confounded`); default ``theta``'s alone.

    Returns
    -------
    dict
        ``alpha``, ``terms`` (the drift coefficients tried), ``trend`` (their fitted values),
        ``wald``, ``dof``, ``p_value``, ``relative_drift`` (largest fitted momentum change /
        RMS right-hand side), ``lag1_autocorrelation``, ``durbin_watson``, ``whiteness_p_value``
        and ``drift`` (True when the test rejects: the caller warns); ``span_residual``: the
        smallest part of a candidate column outside the span of the equations' (relative to its norm;
        not recorded).
    """
    testing_drift = candidates is None
    if testing_drift:
        rot_t = np.swapaxes(eq.rot, -1, -2)[:, slice(2, 3) if eq.planar else slice(None)]
        basis = candidate_basis(log) if basis is None else basis
        candidates = (drift_names(_CANDIDATES, eq.planar)[0],
                      lambda sl: -np.einsum("nri,nki->nrk", rot_t[sl], basis[sl]))  # the momentum change, base axes
    names, columns = candidates
    n, p, q = len(x), eq.p, len(names)

    def parts():  # the chunks' rows, equations, signals and whiteners
        for sl, e, xc in [(slice(None), eq, x)] if phi is not None else _chunks(eq, x, chunk):
            yield sl, e, xc, None if estimator == "ols" else whitener[sl] if whitener is not None else \
                _equation_whitener(e, xc, theta, sigma)

    def chunks():  # :func:`_drift_equations` of each chunk, after its rows
        for sl, e, xc, L in parts():
            yield sl, *_drift_equations(e.phi(xc) if phi is None else phi, columns(sl), L)

    if phi is not None:  # in memory: built once for both passes
        built = list(chunks())
        chunks = lambda: iter(built)  # noqa: E731
    sums = {"b2": 0.0, "serial": np.zeros(3), "last": None, "done": False}  # of b and the whitened residuals of theta

    def residual_chunks():  # the columns and the whitened residuals of theta, chunk by chunk; the sums in the first pass
        first = not sums["done"]
        for _, M, _, b2 in chunks():
            given = residuals is not None and phi is not None and M.inverse is None  # (in memory, not whitened)
            white = residuals if given else M.residual(np.append(theta, np.zeros(q)))
            if first:
                sums["b2"], sums["serial"] = sums["b2"] + b2, sums["serial"] + _serial_sums(white, sums["last"])
                sums["last"] = white[-1]
            yield M, white
        sums["done"] = True

    def corrections():  # the refit as a correction of theta: [A | C] (delta, d) = -white, in least squares
        for M, white in residual_chunks():
            yield M.whole().reshape(-1, p + q), -white.ravel()

    if gram is not None:
        gram = _completed_gram(gram, residual_chunks())
    # From the Gram matrix without refinement passes: its rounding, eps cond^2, is relative to the correction
    # (of the size of the noise), not to theta, whose refined accuracy it keeps (see the docstring).
    factor = _streamed_factor(corrections, p + q, refined=False, gram=gram)
    step, ginv = _solve_factor(*factor[::-1])
    root = _leverage_root(factor)
    # each candidate column's part outside the equations' span, relative to its norm (the factor is column-scaled)
    beyond = np.linalg.norm(factor[1][p : p + q, p : p + q], axis=0)
    est, d = np.append(theta, np.zeros(q)) + step, step[p:]
    change = []
    # the leverages' root and ginv's drift columns side by side: W = M B and K = M ginv[:, p:] in one product
    mapped = np.hstack([root[0], ginv[:, p:]])

    def scores():  # the leverage-adjusted scores of the fit with the drift columns, mapped by ginv's drift rows
        for _, M, cols, _ in chunks():
            change.append(float(np.abs(cols @ d).max()))
            with one_blas_thread():
                both, residual = M.with_residual(mapped, est)
            adjusted = _leverage_adjusted(M, root, ginv, residual, both[..., : -q])
            yield np.einsum("nrq,nr->nq", both[..., -q:], adjusted)  # ginv[p:] M_n^T e_n

    bandwidth = correlation_length(log)
    # only the drift block of the sandwich is tested: its q rows of ginv, not all p + q (q^2, not (p + q)^2, a lag)
    cdd = _hac(scores(), bandwidth, q, dof_scale=False)
    series = differentiated_series(log, attitude=True)
    if series is not None:  # the differentiators' own correlation, where it is larger than the residuals show
        scored = ((sl, M.whole() if L is None else np.swapaxes(lower_inverse(L), -1, -2) @ M.whole(), e.jacobian(xc, theta))
                  for (sl, e, xc, L), (_, M, *_) in zip(parts(), chunks()))  # fmt: skip
        cdd = larger_of(propagated_covariance(series, log.t, scored, ginv[p:], sigma), cdd)[0]
    if callable(noise):
        noise = noise()
    if testing_drift and noise is None:  # (another candidate's columns: the drift test decided before)
        noise = equation_noise(eq, x, sigma, theta, estimator, log, whitener, drift_columns(eq, log, basis),
                               None if phi is not None else chunk, rhs=True)
    eiv, slope = _errors_in_variables(noise, ginv, theta, p) if testing_drift else (np.zeros(q), None)
    cdd = cdd + np.outer(eiv, eiv)
    wald = float(d @ np.linalg.lstsq(cdd, d, rcond=None)[0]) if np.any(cdd) else 0.0
    size = n * eq.param.rows
    values = (theta, theta if nominal is None else nominal)
    confounded = _confounded(noise, factor[1][:-1, :-1] * factor[0], p, slope, values, cdd) if testing_drift else None
    p_value = float(f_sf(wald / q, q, max(size - p - q, 1)))
    change = max(change) / max(float(np.sqrt(sums["b2"] / size)), 1e-300)
    square, lagged, differences = sums["serial"]
    rho = float(lagged / square) if square > 0 else 0.0
    return {
        "alpha": DRIFT_ALPHA,
        "terms": list(names),
        "trend": dict(zip(names, d.tolist())),
        "wald": wald,
        "dof": q,
        "p_value": p_value,
        "relative_drift": float(change),
        "lag1_autocorrelation": rho,
        "durbin_watson": float(differences / max(square, 1e-300)),
        "whiteness_p_value": float(norm_sf(rho * np.sqrt(n))),
        "bandwidth": bandwidth,
        "confounded": confounded,
        "errors_in_variables": eiv.tolist() if testing_drift else None,
        "drift": bool(p_value < DRIFT_ALPHA and change > DRIFT_FLOOR and (confounded or 0.0) < CONFOUNDED),
        "span_residual": float(beyond.min()),
    }
