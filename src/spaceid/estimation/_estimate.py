"""Identification of the minimal parameters from a measured motion (Eq. 4, Eq. 11 and beyond).

The momentum equations of sample n, ``Y(x_n) pi = R0(x_n)^T h``, are built from measured
signals ``x_n = [q, qd, w0, attitude]``: an errors-in-variables problem (MATH.md section 6).
Five estimators (``ESTIMATORS``) solve them:

``ols``
    Ordinary least squares (the paper's Eq. 11). Biased by O(sigma^2) as the regressor is
    noisy, and not efficient: every equation counts the same however noisy it is. Needs no noise
    model: its covariance is the heteroscedasticity-consistent one from the residuals, and it is
    the fast choice for long logs of large systems (10,000 samples of a 496-parameter servicer
    in about a second).
``wls``
    Weighted least squares, each sample weighted by the inverse first-order covariance of its
    equation error, ``S_n = J_n Sigma J_n^T`` (:mod:`spaceid.estimation`), iterated twice. Efficient
    to first order; keeps an O(sigma^2) bias.
``tls``
    Total least squares on the column-scaled system (errors in every column, of the size the
    noise model predicts). Consistent only when the regressor's entry errors are independent
    and alike after scaling, which they are not here (columns share the same noisy signals):
    offered for comparison with the literature.
``iv``
    Instrumental variables: instruments are the regressor rebuilt from signals that do not
    share the measurement noise: the commanded joint trajectory (``instruments=``) with the
    base rate the current estimate predicts, or, without one, the measured joint signals with
    the predicted base rate (removes the base-rate noise, the largest on a motion-capture
    table, but not the joint noise). Iterated twice.
``ml`` (default)
    Maximum likelihood for Gaussian signal noise of known levels: alternates the projection of
    the signals onto the momentum constraint and the fundamental-numerical-scheme update of pi
    (the stationarity condition of the Sampson cost, derivative of the weights included), so
    that at convergence the corrected signals satisfy the equations exactly and pi minimises
    the whitened signal corrections. Unbiased to first order and efficient: its covariance is
    the Cramer-Rao bound of the errors-in-variables model (:func:`cramer_rao`). Costs about
    ``3 n_joints + 6`` regressor evaluations per sample and iteration.

Scale. A known nonzero momentum fixes pi absolutely. With zero or unknown momentum (its inertial
components then estimated with pi) the equations are homogeneous and need an anchor: known
parameter values (``known=``), or the spin momentum of reaction wheels, whose rotor-inertia
parameter the model gives (CAD) and whose columns therefore move to the right-hand side.

Uncertainty. Every estimator's covariance is its first-order sandwich with the equation-error
covariances of the noise model. Given noise levels are trusted and ``chi2_dof`` checks them
against the residuals; levels estimated from the log fix only the relative weights, and the
residuals fix the overall scale (the covariance is multiplied by ``chi2_dof``). Rates that come
from a differentiator have errors correlated over its window, which no white-noise model
describes: the covariance is then the Newey-West (heteroscedasticity and autocorrelation
consistent) estimate from the residuals, with the window as bandwidth.

References
----------
.. [1] Papadopoulos et al., Eq. 4 (stacked equations) and Eq. 11 (least squares).
.. [2] W. Chojnacki, M. J. Brooks, A. van den Hengel, D. Gawley, "On the fitting of surfaces to
   data with covariances", IEEE TPAMI 22(11), 2000 (the fundamental numerical scheme).
.. [3] K. Kanatani, "Statistical Optimization for Geometric Computation", 1996 (the KCR bound).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import brentq

from .._errors import SpaceidError
from .._threads import one_blas_thread
from ..dynamics import skew
from ._noise import FD_STEP, Noise, equation_covariance, noise_from_log, signal_jacobian, signal_sigma
from ..dynamics import Parameterization
from ..data import read_json, Log, quat_to_matrix

__all__ = [
    "ESTIMATORS", "Identification", "identify", "cramer_rao", "compare", "load_result",
]  # fmt: skip

ESTIMATORS = ("ml", "wls", "iv", "tls", "ols")
Z95 = 1.959963984540054  # two-sided 95 % normal quantile, for confidence intervals


def _symbols(definition: str) -> set:
    return set(re.findall(r"[A-Za-z_][A-Za-z_0-9]*", definition))


def _anchors(param: Parameterization, known: dict, where: str) -> dict:
    """Known minimal parameters ``{index: (value, source)}``: reaction-wheel rotor inertias from
    the model, then the user's ``known`` (by minimal name, or by the physical symbol that a
    minimal parameter equals alone)."""
    out = {}
    for joint in param.model.wheels:
        body = next(b.name for b in param.model.bodies if b.joint == joint)
        for i, d in enumerate(param.definitions):
            if all(s.endswith(f"_{body}") for s in _symbols(d)):
                out[i] = (float(param.true_values[i]), f"reaction wheel {joint} (model)")
    alone = {d.strip(): i for i, d in enumerate(param.definitions) if re.fullmatch(r"\s*[A-Za-z_][A-Za-z_0-9]*\s*", d)}
    for name, value in known.items():
        i = param.names.index(name) if name in param.names else alone.get(name)
        if i is None:
            hint = ", ".join(f"{param.names[j]} = {d}" for d, j in alone.items()) or "none"
            raise SpaceidError(
                f"{where}: --known {name}: not a minimal parameter ({param.names[0]}..{param.names[-1]}) nor a physical "
                f"parameter that one equals alone (those are: {hint}); see 'spaceid model' for the definitions"
            )
        out[i] = (float(value), "given")
    return out


def _rotvec_matrix(v):
    """Rotation matrices ``(n, 3, 3)`` of rotation vectors ``(n, 3)`` (Rodrigues)."""
    angle = np.linalg.norm(v, axis=-1)[:, None, None]
    k = skew(v)
    a = np.where(angle > 1e-8, np.sin(angle) / np.where(angle > 0, angle, 1), 1 - angle**2 / 6)
    b = np.where(angle > 1e-8, (1 - np.cos(angle)) / np.where(angle > 0, angle, 1) ** 2, 0.5 - angle**2 / 24)
    return np.eye(3) + a * k + b * (k @ k)


@dataclass(frozen=True)
class _Equations:
    """The momentum equations of a log as ``Phi_n(x) [theta; 1] = 0``, sample by sample.

    ``theta`` holds the free minimal parameters and, when the momentum is unknown, its inertial
    components (z only for planar systems). ``x (n, n_x)`` are the signals
    ``[q, qd, w0 (z only if planar), dtheta (spatial)]``, ``dtheta`` a small rotation of the
    measured attitude in base axes (``R0 = R0_meas exp([dtheta]x)``).
    """

    param: Parameterization
    rot: np.ndarray  # (n, 3, 3) measured base-to-inertial rotations
    free: np.ndarray  # indices of the estimated minimal parameters
    known: np.ndarray  # indices of the known ones ...
    known_values: np.ndarray  # ... and their values
    momentum: np.ndarray | None  # (3,) inertial [N m s], None when estimated

    @property
    def planar(self):
        return self.param.model.planar

    @property
    def axes(self):
        return [2] if self.planar else [0, 1, 2]

    @property
    def n_h(self):
        return 0 if self.momentum is not None else len(self.axes)

    @property
    def p(self):
        return len(self.free) + self.n_h

    def names(self):
        h = [f"h_{'xyz'[a]}" for a in self.axes] if self.n_h else []
        return [self.param.names[i] for i in self.free] + h

    def signals(self, log: Log) -> np.ndarray:
        att = np.zeros((log.n_samples, 0 if self.planar else 3))
        return np.hstack([log.q, log.qd, log.base_w[:, self.axes], att])

    def unpack(self, x):
        nj = len(self.param.model.joints)
        w = np.zeros((len(x), 3))
        w[:, self.axes] = x[:, 2 * nj : 2 * nj + len(self.axes)]
        rot = self.rot if self.planar else self.rot @ _rotvec_matrix(x[:, 2 * nj + 3 :])
        return x[:, :nj], x[:, nj : 2 * nj], w, rot

    def full(self, theta):
        """All minimal parameters ``(k,)`` and the inertial momentum ``(3,)`` of ``theta``."""
        pi = np.empty(self.param.n_params)
        pi[self.known], pi[self.free] = self.known_values, theta[: len(self.free)]
        h = self.momentum
        if h is None:
            h = np.zeros(3)
            h[self.axes] = theta[len(self.free) :]
        return pi, h

    def phi(self, x) -> np.ndarray:
        """``[A | -b]`` of every sample: ``(n, rows, p + 1)``."""
        q, qd, w, rot = self.unpack(x)
        y = self.param.regressor(q, qd, w)
        rows = slice(2, 3) if self.planar else slice(None)
        rot_t = np.swapaxes(rot, -1, -2)[:, rows]  # R0^T, the rows of the equations
        out = np.empty(y.shape[:-1] + (self.p + 1,))
        # the free columns as contiguous runs: slice copies, several times faster than a gather
        runs = np.split(self.free, np.flatnonzero(np.diff(self.free) > 1) + 1)
        at = 0
        for run in runs:
            if len(run):
                out[..., at : at + len(run)] = y[..., run[0] : run[-1] + 1]
                at += len(run)
        b = -(y[..., self.known] @ self.known_values)
        if self.momentum is None:
            out[..., at:-1] = -rot_t[..., self.axes]
        else:
            b = b + rot_t @ self.momentum
        out[..., -1] = -b
        return out

    def dphi(self, x, v) -> np.ndarray:
        """Directional derivative of :meth:`phi` along ``v (n, n_x)``, by central differences
        with a step of ``FD_STEP`` in the largest component of each sample's ``v``."""
        scale = np.max(np.abs(v), axis=1, keepdims=True)
        step = FD_STEP / np.where(scale > 0, scale, 1.0)
        return (self.phi(x + step * v) - self.phi(x - step * v)) / (2 * step[..., None])

    def jacobian(self, x, theta) -> np.ndarray:
        """``d(Phi theta_bar)/dx``: ``(n, rows, n_x)`` (see :func:`spaceid.estimation.signal_jacobian`)."""
        q, qd, w, rot = self.unpack(x)
        pi, h = self.full(theta)
        return signal_jacobian(self.param, pi, q, qd, w, np.einsum("nji,j->ni", rot, h))


def _unexcited(y: np.ndarray, names, tol: float) -> list:
    """Names of the parameters that dominate the (near-)null space of ``y``."""
    scaled = y / np.maximum(np.linalg.norm(y, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(scaled, full_matrices=False)
    null = vt[s < tol * s[0]]
    weight = np.abs(null).max(axis=0) if len(null) else np.zeros(len(names))
    return [n for n, w in zip(names, weight) if w > 0.3]


def _split(phi):
    """``A (n rows, p)`` and ``b (n rows,)`` of stacked ``[A | -b]``."""
    flat = phi.reshape(-1, phi.shape[-1])
    return flat[:, :-1], -flat[:, -1]


def _whiten(S):
    """Cholesky factors ``L (n, rows, rows)`` of the equation covariances, ``S = L L^T``; a
    floor of 1e-12 of the mean variance keeps noise-free channels finite."""
    mean = np.trace(S, axis1=-2, axis2=-1).mean() / S.shape[-1]
    eye = np.eye(S.shape[-1])
    return np.linalg.cholesky(S + (1e-12 * mean if mean > 0 else 1.0) * eye)


def _whitened(L, phi):
    return np.linalg.solve(L, phi)


def _scaled_gram(A, gram=None):
    """Column norms ``(p,)`` of ``A (rows, p)`` (zero columns: 1) and the Gram matrix of the
    columns scaled to unit norm, from ``gram = A^T A`` when given (no scaled copy of ``A``)."""
    gram = A.T @ A if gram is None else gram
    scale = np.sqrt(np.diag(gram)).copy()
    scale[scale == 0] = 1.0
    return scale, gram / np.outer(scale, scale)


def _solve(A, b, extra=None, gram=None):
    """Least squares on column-scaled normal equations with one refinement step.

    ``extra (p,)`` is added to the right-hand side ``A^T b`` (the FNS correction); ``gram``
    is ``A^T A`` if already formed. Returns the solution and the inverse Gram matrix
    ``(A^T A)^{-1}``.
    """
    scale, gram_s = _scaled_gram(A, gram)
    rhs = (A.T @ b + (0 if extra is None else extra)) / scale
    with one_blas_thread():
        factor = cho_factor(gram_s)
        x = cho_solve(factor, rhs)
        x += cho_solve(factor, rhs - (A.T @ (A @ (x / scale))) / scale)
        return x / scale, cho_solve(factor, np.eye(len(scale))) / np.outer(scale, scale)


def _sandwich(bread, Z, S_half):
    """``bread Z^T S Z bread^T`` with ``S = blockdiag(L L^T)``, ``Z (n, rows, p)``."""
    zl = (np.swapaxes(Z, -1, -2) @ S_half).transpose(1, 0, 2).reshape(Z.shape[-1], -1)  # Z_n^T L_n, side by side
    meat = zl @ zl.T
    with one_blas_thread():
        return bread @ meat @ bread.T


def _ols(eq, x, sigma, theta, ctx):
    A, b = _split(ctx["phi"])
    theta, ginv = _solve(A, b, gram=ctx.get("gram"))
    return theta, {"ginv": ginv}  # reused by the covariance


def _wls(eq, x, sigma, theta, ctx, iterations=2):
    phi = ctx["phi"]
    for _ in range(iterations):
        L = _whiten(equation_covariance(eq.jacobian(x, theta), sigma))
        theta, _ = _solve(*_split(_whitened(L, phi)))
    return theta, {"iterations": iterations}


def _column_noise(eq, x, sigma):
    """RMS noise of each column of ``[A | -b]`` [per entry], propagated from the signal noise."""
    total = np.zeros(eq.p + 1)
    for i in np.flatnonzero(sigma):
        e = np.zeros(x.shape[1])
        e[i] = FD_STEP
        d = (eq.phi(x + e) - eq.phi(x - e)) / (2 * FD_STEP)
        total += sigma[i] ** 2 * np.sum(d**2, axis=(0, 1))
    return np.sqrt(total / (len(x) * eq.param.rows))


def _tls(eq, x, sigma, theta, ctx):
    A, b = _split(ctx["phi"])
    noise = _column_noise(eq, x, sigma)
    d_a = np.where(noise[:-1] > 0, noise[:-1], np.linalg.norm(A, axis=0) * 1e-12 + 1e-300)
    As = A / d_a
    # minimise |As y - b|^2 / (|y|^2 + d_b^2): (As^T As - lam I) y = As^T b, lam the root of the
    # secular equation sum c_i^2 / (mu_i - lam) + lam d_b^2 - |b|^2 = 0 below the smallest mu
    U, sv, Vt = np.linalg.svd(As, full_matrices=False)  # not the Gram matrix: keeps cond(A), not its square
    mu, c = sv**2, sv * (U.T @ b)
    secular = lambda lam: np.sum(c**2 / (mu - lam)) + lam * noise[-1] ** 2 - b @ b  # noqa: E731
    lam = 0.0
    if secular(0.0) < 0:
        hi = mu[-1] * (1 - 1e-12)
        lam = brentq(secular, 0.0, hi, xtol=1e-14 * mu[-1], rtol=1e-14) if secular(hi) > 0 else hi
    return Vt.T @ (c / (mu - lam)) / d_a, {"lambda": float(lam), "column_noise": noise.tolist()}


def _iv(eq, x, sigma, theta, ctx, iterations=2):
    from ..dynamics import base_rate

    A, b = _split(ctx["phi"])
    ref = ctx["reference"]  # (q, qd) the instruments are built from
    nj = len(eq.param.model.joints)
    for _ in range(iterations):
        pi, h = eq.full(theta)
        xz = x.copy()
        xz[:, : 2 * nj] = np.hstack(ref)
        w = base_rate(eq.param, pi, ref[0], ref[1], np.einsum("nji,j->ni", eq.rot, h))
        xz[:, 2 * nj : 2 * nj + len(eq.axes)] = w[:, eq.axes]
        Z, _ = _split(eq.phi(xz))
        # (Z^T A) theta = Z^T b, solved as least squares in the instruments' orthonormal basis:
        # conditioned like A, not like A^T Z
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        basis = np.linalg.qr(Z / scale)[0]
        theta = np.linalg.lstsq(basis.T @ (A / scale), basis.T @ b, rcond=None)[0] / scale
    return theta, {"iterations": iterations, "instruments": ctx["instruments"], "Z": Z}


def _ml(eq, x, sigma, theta, ctx, max_iter=50, tol=1e-4):
    """FNS update of theta and projection of the signals, alternated to their joint fixed point.

    Converged when a step changes no parameter by more than ``tol`` of its standard error (or
    1e-9 relative: the finite differences in the signals leave a jitter of ~1e-10). The
    iteration contracts linearly (by ~0.1 a step on the servicer at 1e-3 noise), so the last
    step bounds the remaining iteration error to about ``tol`` standard errors: far below the
    statistical error, and each step costs ~3 n_joints + 6 regressor evaluations."""
    xh = x.copy()
    converged = False
    for it in range(1, max_iter + 1):
        phi = eq.phi(xh)
        d = x - xh
        phit = phi + eq.dphi(xh, d) if np.any(d) else phi  # linearised at xh, evaluated at x
        J = eq.jacobian(xh, theta)
        L = _whiten(equation_covariance(J, sigma))
        Aw, bw = _split(_whitened(L, phit))
        tbar = np.append(theta, 1.0)
        r = phit @ tbar
        u = np.linalg.solve(np.swapaxes(L, -1, -2), np.linalg.solve(L, r[..., None]))[..., 0]  # S^{-1} r
        v = sigma**2 * np.einsum("nrx,nr->nx", J, u)
        T = eq.dphi(xh, v)[..., :-1] if np.any(v) else np.zeros_like(phi[..., :-1])
        new, ginv = _solve(Aw, bw, np.einsum("nrp,nr->p", T, u))
        # project the measured signals onto the constraint linearised at xh
        r_new = phit @ np.append(new, 1.0)
        u_new = np.linalg.solve(np.swapaxes(L, -1, -2), np.linalg.solve(L, r_new[..., None]))[..., 0]
        xh = x - sigma**2 * np.einsum("nrx,nr->nx", J, u_new)
        step = np.abs(new - theta) / np.sqrt(np.maximum(np.diag(ginv), 1e-300))
        small = np.abs(new - theta).max() <= 1e-9 * np.abs(new).max()
        theta = new
        if step.max() < tol or small:
            converged = True
            break
    return theta, {"iterations": it, "converged": converged, "corrected": xh}


_KERNELS = {"ols": _ols, "wls": _wls, "tls": _tls, "iv": _iv, "ml": _ml}


def _covariance(eq, x, phi, sigma, theta, estimator, info, bandwidth=0):
    """First-order covariance of ``theta`` for ``estimator``, the chi-square per degree of
    freedom of the residuals under the noise model, and the RMS residual.

    Every estimator is, to first order, ``theta - theta_0 = bread sum_n M_n^T e_n`` with ``e_n``
    the equation errors: ``M_n = S_n^-1 A_n`` (wls, ml), ``Z_n`` (iv), ``A_n`` (ols, tls). With
    independent samples the covariance is ``bread (sum_n M_n^T S_n M_n) bread^T``; with errors
    correlated over ``bandwidth`` samples (rates from a differentiator's window) it is the
    Newey-West estimate from the residuals' scores ``g_n = M_n^T r_n`` with Bartlett weights.
    """
    xl = info.get("corrected", x)
    if "corrected" in info:  # ML: linearised at the corrected signals, evaluated at the measured
        phi = eq.phi(xl) + eq.dphi(xl, x - xl)
    A = phi[..., :-1]
    r = phi @ np.append(theta, 1.0)
    if estimator == "ols":  # no noise model: heteroscedasticity-consistent, from the residuals
        bread = info.pop("ginv")
        return _newey_west(bread, A, r, bandwidth, eq.p), None, float(np.sqrt(np.mean(r**2)))
    L = _whiten(equation_covariance(eq.jacobian(xl, theta), sigma))
    if estimator in ("wls", "ml"):
        M = np.linalg.solve(np.swapaxes(L, -1, -2), _whitened(L, A))
        bread = _solve(*_split(_whitened(L, phi)))[1]
    elif estimator == "iv":
        M = info.pop("Z").reshape(A.shape)
        with one_blas_thread():
            bread = np.linalg.inv(np.einsum("nrp,nrq->pq", M, A))
    else:
        M = A
        bread = _solve(A.reshape(-1, A.shape[-1]), np.zeros(A.shape[0] * A.shape[1]))[1]
    if bandwidth > 0:
        cov = _newey_west(bread, M, r, bandwidth, eq.p)
    else:
        cov = _sandwich(bread, M, L)
    white = np.linalg.solve(L, r[..., None])[..., 0]
    dof = max(r.size - eq.p, 1)
    return cov, float(np.sum(white**2) / dof), float(np.sqrt(np.mean(r**2)))


def _newey_west(bread, M, r, bandwidth, p):
    """``bread Omega bread^T`` with ``Omega`` the Bartlett-weighted autocovariance of the scores
    ``g_n = M_n^T r_n`` up to lag ``bandwidth`` (0: White's heteroscedasticity-consistent form),
    scaled by ``n / (n - p)``."""
    g = np.einsum("nrp,nr->np", M, r)
    meat = g.T @ g
    for lag in range(1, min(bandwidth, len(g) - 1) + 1):
        c = g[lag:].T @ g[:-lag]
        meat += (1 - lag / (bandwidth + 1)) * (c + c.T)
    with one_blas_thread():
        return bread @ meat @ bread.T * len(g) / max(len(g) - p, 1)


def _correlation_length(log: Log) -> int:
    """Samples over which the errors of differentiated rates are correlated: the longest
    differentiator window recorded in ``log.meta`` (0 when nothing was differentiated)."""
    info = log.meta.get("differentiation")
    if not info or log.n_samples < 2:
        return 0
    spans = []

    def walk(node):
        if isinstance(node, dict):
            for key, value in node.items():
                if key == "window_s" and value is not None:
                    spans.extend(np.ravel(value).tolist())
                else:
                    walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    walk(info)
    step = float(np.median(np.diff(log.t)))
    if not spans:  # e.g. smoothing splines: the Newey-West rule of thumb
        return int(np.floor(4 * (log.n_samples / 100) ** (2 / 9)))
    return int(np.ceil(max(spans) / step))


@dataclass(frozen=True)
class Identification:
    """Result of an identification.

    Attributes
    ----------
    names, definitions : tuple of str
    values, std : ndarray of shape (k,)
        Estimates and their standard errors.
    cov : ndarray of shape (k, k)
    condition_number : float
        2-norm condition number of the stacked regressor.
    singular_values : ndarray of shape (k,)
    residual_rms : float
        RMS of ``Y pi - h`` [N m s].
    n_samples : int
    estimator : str
    momentum : ndarray of shape (3,)
        Inertial momentum used [N m s].
    model : str
        Model source (preset name or path) and planar flag, to rebuild the regressor.
    planar : bool
    settings : dict
        Rank tolerance, seeds, log provenance: everything needed to reproduce the result.
    """

    names: tuple
    definitions: tuple
    values: np.ndarray
    std: np.ndarray
    cov: np.ndarray
    condition_number: float
    singular_values: np.ndarray
    residual_rms: float
    n_samples: int
    estimator: str
    momentum: np.ndarray
    model: str
    planar: bool
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "planar": self.planar,
            "estimator": self.estimator,
            "momentum": self.momentum.tolist(),
            "parameters": [
                {"name": n, "definition": d, "value": float(v), "std": float(s),
                 "ci95": [float(v - Z95 * s), float(v + Z95 * s)]}
                for n, d, v, s in zip(self.names, self.definitions, self.values, self.std)
            ],
            "covariance": self.cov.tolist(),
            "condition_number": self.condition_number,
            "singular_values": self.singular_values.tolist(),
            "residual_rms": self.residual_rms,
            "n_samples": self.n_samples,
            "settings": self.settings,
        }

    @classmethod
    def from_dict(cls, data: dict, where: str = "result") -> "Identification":
        try:
            params = data["parameters"]
            k = len(params)
            cov = np.asarray(data.get("covariance", np.diag([p["std"] ** 2 for p in params])), float).reshape(k, k)
            return cls(
                tuple(p["name"] for p in params),
                tuple(p["definition"] for p in params),
                np.array([p["value"] for p in params], float),
                np.array([p["std"] for p in params], float),
                cov,
                float(data["condition_number"]),
                np.asarray(data.get("singular_values", []), float),
                float(data.get("residual_rms", np.nan)),
                int(data.get("n_samples", 0)),
                str(data.get("estimator", "ols")),
                np.asarray(data["momentum"], float).reshape(3),
                str(data["model"]),
                bool(data["planar"]),
                dict(data.get("settings", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise SpaceidError(f"{where}: not a spaceid result file (bad or missing field {exc}): use a file written by 'spaceid identify'") from None


def load_result(path) -> Identification:
    """An identification saved as RESULT.json (by ``spaceid identify`` or
    :meth:`Identification.to_dict`), back as an :class:`Identification`.

    Parameters
    ----------
    path : str or Path
        The JSON file.

    Raises
    ------
    SpaceidError
        The file is missing, not JSON, or not a result; the message names the file and field.
    """
    return Identification.from_dict(read_json(path, what="result file"), where=str(path))


def _equations(param, log, momentum, known, where) -> tuple:
    """The equations of ``log`` and the anchors used (see :func:`identify`)."""
    anchors = _anchors(param, dict(known or {}), where)
    homogeneous = momentum is None or not np.linalg.norm(momentum) > 0
    if homogeneous and not anchors:
        state = "unknown" if momentum is None else "zero"
        raise SpaceidError(
            f"{where}: the momentum is {state}, so the equations are homogeneous and fix the parameters only up to "
            "scale: give the nonzero momentum of the run (--momentum), or anchor the scale with a known parameter "
            "(--known NAME=VALUE, e.g. a reaction-wheel rotor inertia)"
        )
    idx = np.array(sorted(anchors), int)
    free = np.setdiff1d(np.arange(param.n_params), idx)
    values = np.array([anchors[i][0] for i in idx], float)
    eq = _Equations(param, quat_to_matrix(log.base_quat), free, idx, values, momentum)
    return eq, [{"name": param.names[i], "definition": param.definitions[i], "value": anchors[i][0],
                 "source": anchors[i][1]} for i in idx]  # fmt: skip


def identify(
    param: Parameterization,
    log: Log,
    momentum,
    *,
    estimator: str = "ml",
    known: dict | None = None,
    noise: Noise | None = None,
    instruments=None,
    where: str = "log",
    cond_limit: float = 1e10,
) -> Identification:
    """Estimate the minimal parameters from a measured motion.

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model (geometry only is used, and the rotor inertias of
        reaction wheels).
    log : Log
        Measured motion; joint columns in ``param.model.joints`` order.
    momentum : array_like of shape (3,) or None
        Inertial angular momentum of the whole system [N m s]; None: a constant unknown
        momentum, estimated with the parameters.
    estimator : {"ml", "wls", "iv", "tls", "ols"}
        See the module docstring.
    known : dict, optional
        Known parameter values ``{name: value}``, by minimal-parameter name or by the physical
        parameter a minimal one equals alone (e.g. ``{"Izz_wheel": 0.00197}``): they move to
        the right-hand side and anchor the scale.
    noise : Noise, optional
        Measurement noise levels; estimated from the log when omitted.
    instruments : tuple of ndarray (n_samples, n_joints), optional
        Commanded joint angles and rates at the log's stamps, for ``iv`` (default: the
        measured ones, with the base rate the model predicts).
    where : str
        Name of the data source, for error messages.
    cond_limit : float
        Condition numbers of the column-scaled regressor above this mean some parameters are
        not excited: an error names them.

    Returns
    -------
    Identification
        ``values``/``std``/``cov`` over all minimal parameters (known ones with zero
        variance); the estimated momentum, anchors, noise model, ``chi2_dof`` and the
        estimator's iterations in ``settings``.
    """
    if estimator not in ESTIMATORS:
        raise SpaceidError(f"--estimator: '{estimator}' is not one of {', '.join(ESTIMATORS)}")
    momentum = None if momentum is None else np.asarray(momentum, float)
    eq, anchors = _equations(param, log, momentum, known, where)
    names = eq.names()
    if log.n_samples * param.rows < eq.p + 1:
        raise SpaceidError(
            f"{where}: {log.n_samples} samples give {log.n_samples * param.rows} equations for {eq.p} unknowns: "
            f"record at least {-(-(eq.p + 1) // param.rows)} samples"
        )
    x = eq.signals(log)
    phi = eq.phi(x)
    A, b = _split(phi)
    if not np.any(b):
        raise SpaceidError(f"{where}: the right-hand side is zero (no momentum and the anchored parameters' columns "
                           "vanish, e.g. a reaction wheel at rest): spin the wheel or give the momentum")
    # Columns scaled to unit norm: the scaled condition number decides excitation (it does not
    # depend on units).
    gram = A.T @ A  # formed once: excitation check, singular values and the OLS solution
    scale, gram_s = _scaled_gram(A, gram)
    with one_blas_thread():
        eig = np.linalg.eigvalsh(gram_s)
    cond_scaled = float(np.sqrt(eig[-1] / eig[0])) if eig[0] > 0 else np.inf
    if cond_scaled > 1e6:  # near the precision limit of the Gram matrix: decide on the SVD
        sv = np.linalg.svd(A / scale, compute_uv=False)
        cond_scaled = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    if not cond_scaled < cond_limit:
        bad = _unexcited(A, names, 1e-8)
        raise SpaceidError(
            f"{where}: the regressor is rank-deficient (scaled cond {cond_scaled:.3g}); not excited: "
            f"{', '.join(bad) or 'unclear'}: use an exciting trajectory (spaceid design) that moves every joint"
        )
    estimated = noise is None and estimator != "ols"  # ols needs no noise model
    noise = noise_from_log(log) if estimated else (noise or Noise(source="not used (ols)"))
    sigma = signal_sigma(param, noise)
    ctx = {"phi": phi, "gram": gram}
    theta, start = _ols(eq, x, sigma, None, ctx)
    if estimator == "iv":
        ref = (log.q, log.qd) if instruments is None else tuple(np.asarray(a, float) for a in instruments)
        if ref[0].shape != log.q.shape or ref[1].shape != log.q.shape:
            raise SpaceidError(f"{where}: instruments must be joint angles and rates of shape {log.q.shape}")
        ctx |= {"reference": ref, "instruments": "measured joints, predicted base rate" if instruments is None
               else "commanded joints, predicted base rate"}  # fmt: skip
    theta, info = (theta, start) if estimator == "ols" else _KERNELS[estimator](eq, x, sigma, theta, ctx)
    if info.get("converged") is False:
        warnings.warn(f"{where}: maximum likelihood did not converge in {info['iterations']} iterations", stacklevel=2)
    bandwidth = _correlation_length(log)
    cov_t, chi2, rms = _covariance(eq, x, phi, sigma, theta, estimator, info, bandwidth)
    if bandwidth:
        how = f"Newey-West from the residuals, Bartlett weights over {bandwidth} samples (differentiated rates)"
    elif estimator == "ols":
        how = "heteroscedasticity-consistent (White) from the residuals"
    elif estimated:  # levels from the log are rough (sparse logs mix signal into them): let the
        cov_t = cov_t * chi2  # residuals set the overall scale (a posteriori variance factor)
        how = "noise model (levels estimated from the log) times the variance factor chi2_dof"
    else:
        how = "noise model (levels given)"
    info.pop("corrected", None)
    pi, h = eq.full(theta)
    k = param.n_params
    cov = np.zeros((k, k))
    cov[np.ix_(eq.free, eq.free)] = cov_t[: len(eq.free), : len(eq.free)]
    h_std = np.zeros(3)
    if eq.n_h:
        h_std[eq.axes] = np.sqrt(np.diag(cov_t)[len(eq.free) :])
    # singular values of the unscaled regressor (the paper's condition number), from its Gram
    # matrix: accurate to eps * s_max, ample for the condition numbers of exciting motions
    with one_blas_thread():
        s = np.sqrt(np.clip(np.linalg.eigvalsh(gram), 0, None))[::-1]
    return Identification(
        param.names,
        param.definitions,
        pi,
        np.sqrt(np.diag(cov)),
        cov,
        float(s[0] / s[-1]) if s[-1] > 0 else np.inf,
        s,
        rms,
        log.n_samples,
        estimator,
        h,
        param.model.source or param.model.name,
        param.model.planar,
        {
            "parameterization": param.to_dict(),
            "log": dict(log.meta),
            "condition_number_scaled": cond_scaled,
            "anchors": anchors,
            "momentum_estimated": momentum is None,
            "momentum_std": h_std.tolist(),
            "noise": noise.to_dict(),
            "chi2_dof": chi2,
            "variance_factor": chi2 if estimated and not bandwidth else 1.0,  # None for ols
            "covariance": how,
            "estimator_info": {k: v for k, v in info.items() if np.isscalar(v) or isinstance(v, (str, list))},
        },
    )


def cramer_rao(param: Parameterization, log: Log, momentum, noise: Noise, *, known=None, estimate_momentum=False):
    """Cramer-Rao bound of the errors-in-variables model for a motion and noise levels.

    With Gaussian noise on the signals and the momentum equations holding exactly for the true
    signals, the bound on the unknowns is ``(sum_n A_n^T S_n^{-1} A_n)^{-1}`` (Kanatani's KCR
    bound), ``A_n`` the regressor rows and ``S_n`` the equation-error covariance, both at the
    true signals and parameters.

    Parameters
    ----------
    param : Parameterization
        Its ``true_values`` are the true parameters.
    log : Log
        The noise-free motion.
    momentum : array_like of shape (3,)
        True inertial momentum [N m s].
    noise : Noise
    known : dict, optional
        Known parameters, as for :func:`identify` (reaction wheels count as known).
    estimate_momentum : bool
        Whether the momentum is among the unknowns.

    Returns
    -------
    names : list of str
        The unknowns (free parameters, then ``h_*`` if estimated).
    cov : ndarray of shape (p, p)
    """
    momentum = np.asarray(momentum, float)
    eq, _ = _equations(param, log, None if estimate_momentum else momentum, known, "cramer_rao")
    theta = np.concatenate([param.true_values[eq.free], momentum[eq.axes] if estimate_momentum else []])
    x = eq.signals(log)
    L = _whiten(equation_covariance(eq.jacobian(x, theta), signal_sigma(param, noise)))
    Aw, _ = _split(_whitened(L, eq.phi(x)))
    return eq.names(), _solve(Aw, np.zeros(len(Aw)))[1]


def compare(before: Identification, after: Identification, *, where: str = "results") -> dict:
    """How the parameters changed between two identifications of the same structure.

    For the on-orbit servicing case: identify before and after a capture (or a fuel burn) and
    see which combinations moved, with a z-score ``change / sqrt(std_before^2 + std_after^2)``
    that says whether the change stands out from the estimation noise.

    Returns
    -------
    dict
        ``parameters``: per parameter ``name``, ``definition``, ``before``, ``after``,
        ``change``, ``relative_change`` and ``z``.
    """
    if before.names != after.names or before.definitions != after.definitions:
        raise SpaceidError(
            f"{where}: the two results have different parameter sets ({len(before.names)} vs {len(after.names)}): "
            "compare identifications of the same kinematic structure"
        )
    change = after.values - before.values
    noise = np.hypot(before.std, after.std)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(before.values != 0, change / np.abs(before.values), np.inf)
        z = np.where(noise > 0, change / noise, np.inf * np.sign(change))
    return {
        "parameters": [
            {"name": n, "definition": d, "before": float(b), "after": float(a), "change": float(c),
             "relative_change": float(r), "z": float(s)}
            for n, d, b, a, c, r, s in zip(before.names, before.definitions, before.values, after.values, change, rel, z)
        ]
    }
