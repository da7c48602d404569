"""The momentum scale of the minimal parameters: errors and standard deviations as the momentum
they cause over a log, a measure that near-zero parameters cannot dominate
(docs/theory/noise.md, "Scales").

A parameter ``pi_k`` enters the momentum through its regressor column, ``h = sum_k Y_k(x) pi_k``.
Over the samples ``x_n`` of a log, ``r_k = RMS_n |Y_k(x_n)|`` [N m s per unit of ``pi_k``] is the
momentum one unit of ``pi_k`` causes, and ``H = sqrt(sum_k (r_k pi0_k)^2)`` [N m s], with the
model file's nominal (CAD) values ``pi0``, the momentum scale of the log: the root-sum-square of
the parameters' contributions (the momentum itself when they are uncorrelated; unlike ``RMS |h|``
it is not zero for a motion from rest). An error or standard deviation ``e_k`` of ``pi_k`` is
reported as ``e_k r_k / H``: the momentum it alone causes, as a fraction of the log's. The
share ``r_k |pi0_k| / H`` says how large a parameter is; where it is at least :data:`LARGE_SHARE`
the plain relative error ``e_k / |pi_k|`` is meaningful too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data import Log, differentiate_log

__all__ = ["LARGE_SHARE", "MomentumScale", "log_momentum_scale", "momentum_scale"]

LARGE_SHARE = 0.01
"""A parameter whose nominal contribution is at least this fraction of the momentum scale counts as
large: its relative error is shown beside the scaled one."""

SCALE_SAMPLES = 4096
"""Samples, evenly spaced over the log, that the RMS regressor columns are taken over: a scale,
not an estimate, so a long log need not be evaluated whole."""


@dataclass(frozen=True)
class MomentumScale:
    """The momentum scale of a log's parameters (module docstring).

    Attributes
    ----------
    per_unit : ndarray of shape (k,)
        ``r_k / H`` [1 / unit of ``pi_k``]: multiplies an error or standard deviation of ``pi_k``
        into the fraction of the log's momentum scale it causes.
    momentum : float
        ``H`` [N m s], the momentum scale.
    share : ndarray of shape (k,)
        ``r_k |pi0_k| / H``: each parameter's nominal contribution (dimensionless).
    """

    per_unit: np.ndarray
    momentum: float
    share: np.ndarray

    @property
    def large(self) -> np.ndarray:
        """Mask of the parameters whose share is at least :data:`LARGE_SHARE`, shape ``(k,)``."""
        return self.share >= LARGE_SHARE

    def scaled(self, x) -> np.ndarray:
        """Errors or standard deviations ``x (..., k)`` of ``pi`` as fractions of the momentum scale."""
        return np.asarray(x, float) * self.per_unit

    def to_dict(self) -> dict:
        return {"momentum": self.momentum, "per_unit": self.per_unit.tolist(), "share": self.share.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> MomentumScale:
        return cls(np.asarray(data["per_unit"], float), float(data["momentum"]), np.asarray(data["share"], float))


def momentum_scale(param, q, qd, w0, pi=None) -> MomentumScale:
    """The momentum scale of samples of a motion.

    Parameters
    ----------
    param : Parameterization
    q, qd : array_like of shape (n, n_joints)
        Joint angles [rad or m] and rates [rad/s or m/s].
    w0 : array_like of shape (n, 3)
        Base angular velocity in base axes [rad/s].
    pi : array_like of shape (k,), optional
        Nominal parameters (default: the model file's, ``param.true_values``).

    Returns
    -------
    MomentumScale
    """
    q, qd, w0 = (np.asarray(a, float) for a in (q, qd, w0))
    rows = _scale_rows(len(q))
    y = param.regressor(q[rows], qd[rows], w0[rows])  # (m, rows, k)
    return _regressor_scale(param, np.einsum("nrk,nrk->k", y, y) / len(rows), pi)


def _scale_rows(n: int) -> np.ndarray:
    """The samples ``(m,)`` of ``n`` that :func:`momentum_scale` takes."""
    return np.unique(np.linspace(0, n - 1, min(n, SCALE_SAMPLES)).astype(int))


def _regressor_scale(param, square, pi=None) -> MomentumScale:
    """:func:`momentum_scale` from the mean square ``(k,)`` over its samples of each regressor column."""
    r = np.sqrt(square)
    pi = param.true_values if pi is None else np.asarray(pi, float)
    total = float(np.sqrt(np.sum((r * pi) ** 2)))
    per_unit = r / total if total > 0 else np.full_like(r, np.nan)
    return MomentumScale(per_unit, total, per_unit * np.abs(pi))


def log_momentum_scale(param, log: Log, pi=None, regressor=None) -> MomentumScale:
    """:func:`momentum_scale` of a log's samples; rates it lacks (NaN: an angles-only log) from
    :func:`spaceid.data.differentiate_log`. ``regressor``: the regressor ``(n, rows, k)`` at every sample of
    the log (e.g. a view of the identification's equations), if built."""
    if regressor is not None:
        rows = _scale_rows(log.n_samples)
        square = sum(np.einsum("nrk,nrk->k", y, y) for y in (regressor[part] for part in np.array_split(
            rows, -(-len(rows) // 256))))  # a block at a time: no copy of the columns (a view of the equations)
        return _regressor_scale(param, square / len(rows), pi)
    if not (np.isfinite(log.qd).all() and np.isfinite(log.base_w).all()):
        log = differentiate_log(log)
    return momentum_scale(param, log.q, log.qd, log.base_w, pi)
