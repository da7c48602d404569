"""Identification of the minimal parameters from a measured motion (the paper's Eq. 4 and Eq. 11
and beyond): :func:`identify`.

The steps: the stacked momentum equations of the log and their scale anchors
(:mod:`spaceid.estimation._equations`), checks that they determine the parameters (enough
samples, a nonzero right-hand side, every parameter excited), the noise model, the estimator
(:mod:`spaceid.estimation._estimators` describes the five), its covariance
(:mod:`spaceid.estimation._uncertainty`) and the :class:`~spaceid.estimation.Identification`
that records all of it.

References
----------
.. [1] Papadopoulos et al., Eq. 4 (stacked equations) and Eq. 11 (least squares).
"""

from __future__ import annotations

import warnings

import numpy as np

from .._errors import SpaceidError
from .._threads import one_blas_thread
from ..data import Log
from ..dynamics import Parameterization
from ._equations import _equations, _split
from ._estimators import _KERNELS, ESTIMATORS, _ols, _scaled_gram
from ._noise import Noise, noise_from_log, signal_sigma
from ._result import Identification
from ._uncertainty import _reported_covariance

__all__ = ["identify"]


def _check_sample_count(eq, log: Log, where: str) -> None:
    """Raise unless the log gives more equations than unknowns."""
    rows = eq.param.rows
    if log.n_samples * rows < eq.p + 1:
        raise SpaceidError(
            f"{where}: {log.n_samples} samples give {log.n_samples * rows} equations for {eq.p} unknowns: "
            f"record at least {-(-(eq.p + 1) // rows)} samples"
        )


def _unexcited(y: np.ndarray, names, tol: float) -> list:
    """Names of the parameters that dominate the (near-)null space of ``y``."""
    scaled = y / np.maximum(np.linalg.norm(y, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(scaled, full_matrices=False)
    null = vt[s < tol * s[0]]
    weight = np.abs(null).max(axis=0) if len(null) else np.zeros(len(names))
    return [n for n, w in zip(names, weight) if w > 0.3]


def _check_excitation(phi, names, cond_limit: float, where: str) -> tuple:
    """The Gram matrix ``A^T A (p, p)`` of the stacked equations ``phi (n, rows, p + 1)`` and the
    condition number of the column-scaled regressor; raises when the right-hand side vanishes
    or the condition number reaches ``cond_limit`` (naming the parameters not excited)."""
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
    return gram, cond_scaled


def _instrument_context(log: Log, instruments, where: str) -> dict:
    """The joint signals ``(q, qd)`` the ``iv`` instruments are built from, and their description."""
    ref = (log.q, log.qd) if instruments is None else tuple(np.asarray(a, float) for a in instruments)
    if ref[0].shape != log.q.shape or ref[1].shape != log.q.shape:
        raise SpaceidError(f"{where}: instruments must be joint angles and rates of shape {log.q.shape}")
    return {"reference": ref, "instruments": "measured joints, predicted base rate" if instruments is None
            else "commanded joints, predicted base rate"}  # fmt: skip


def _full_covariance(eq, cov_t, k: int) -> tuple:
    """The covariance ``(k, k)`` of all minimal parameters (known ones with zero variance) and
    the standard errors ``(3,)`` of the inertial momentum [N m s] (zero when it was given)."""
    cov = np.zeros((k, k))
    cov[np.ix_(eq.free, eq.free)] = cov_t[: len(eq.free), : len(eq.free)]
    h_std = np.zeros(3)
    if eq.n_h:
        h_std[eq.axes] = np.sqrt(np.diag(cov_t)[len(eq.free) :])
    return cov, h_std


def _singular_values(gram) -> np.ndarray:
    """Singular values of the unscaled regressor (the paper's condition number), largest first,
    from its Gram matrix: accurate to eps * s_max, ample for the condition numbers of exciting
    motions."""
    with one_blas_thread():
        return np.sqrt(np.clip(np.linalg.eigvalsh(gram), 0, None))[::-1]


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
        Maximum likelihood (efficient, the default), weighted, instrumental-variables, total or
        ordinary least squares; ``spaceid.estimation._estimators`` describes each one's
        assumptions and cost.
    known : dict, optional
        Known parameter values ``{name: value}``, by minimal-parameter name or by the physical
        parameter a minimal one equals alone (e.g. ``{"Iczz_wheel": 0.00197}``): they move to
        the right-hand side and anchor the scale (see :func:`spaceid.estimation.resolve_anchors`).
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
    _check_sample_count(eq, log, where)
    x = eq.signals(log)
    phi = eq.phi(x)
    gram, cond_scaled = _check_excitation(phi, eq.names(), cond_limit, where)
    estimated = noise is None and estimator != "ols"  # ols needs no noise model
    noise = noise_from_log(log) if estimated else (noise or Noise(source="not used (ols)"))
    sigma = signal_sigma(param, noise)
    ctx = {"phi": phi, "gram": gram}
    theta, start = _ols(eq, x, sigma, None, ctx)
    if estimator == "iv":
        ctx |= _instrument_context(log, instruments, where)
    theta, info = (theta, start) if estimator == "ols" else _KERNELS[estimator](eq, x, sigma, theta, ctx)
    if info.get("converged") is False:
        warnings.warn(f"{where}: maximum likelihood did not converge in {info['iterations']} iterations", stacklevel=2)
    cov_t, rms, uncertainty = _reported_covariance(eq, x, phi, sigma, theta, estimator, info, log, estimated)
    info.pop("corrected", None)
    pi, h = eq.full(theta)
    cov, h_std = _full_covariance(eq, cov_t, param.n_params)
    s = _singular_values(gram)
    settings = {
        "parameterization": param.to_dict(),
        "log": dict(log.meta),
        "condition_number_scaled": cond_scaled,
        "anchors": anchors,
        "momentum_estimated": momentum is None,
        "momentum_std": h_std.tolist(),
        "noise": noise.to_dict(),
        **uncertainty,
        "estimator_info": {k: v for k, v in info.items() if np.isscalar(v) or isinstance(v, (str, list))},
    }
    return Identification(
        names=param.names, definitions=param.definitions, values=pi, std=np.sqrt(np.diag(cov)), cov=cov,
        condition_number=float(s[0] / s[-1]) if s[-1] > 0 else np.inf, singular_values=s, residual_rms=rms,
        n_samples=log.n_samples, estimator=estimator, momentum=h, model=param.model.source or param.model.name,
        planar=param.model.planar, settings=settings, units=param.units,
    )
