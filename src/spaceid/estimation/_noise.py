"""The errors-in-variables noise model of the momentum equations (docs/theory/noise.md).

The regressor is built from measured signals ``x = [q, qd, w0, dtheta]`` (joint angles, joint
rates, base rate, and for spatial systems a small rotation of the measured attitude), each
carrying independent zero-mean noise of a given standard deviation. To first order the
equation error of sample n, ``g_n = Y(x_n) pi - R0(x_n)^T h``, then has covariance
``S_n = J_n Sigma J_n^T`` with ``J_n = dg_n/dx``: what weighted and maximum-likelihood
estimators weight by, what the Cramer-Rao bound is built from, and what noise-aware excitation
design whitens with.

Planar systems carry only the base rate about z and no attitude variable (a yaw does not
change ``h_z``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .._errors import SpaceidError
from ..dynamics import Parameterization, momentum_jacobian, skew

__all__ = ["Noise", "noise_from_log", "signal_sigma", "signal_jacobian", "equation_covariance", "FD_STEP"]

FD_STEP = 1e-5  # [rad]: central differences of the kinematics; truncation ~1e-10, round-off ~1e-11 relative


@dataclass(frozen=True)
class Noise:
    """Standard deviations of the measurement noise, per component.

    Attributes
    ----------
    angle : float
        Joint angles [rad or m].
    rate : float
        Joint rates [rad/s or m/s].
    base_rate : float
        Base angular velocity, per axis [rad/s].
    attitude : float
        Base attitude, small rotation per axis [rad]; for planar systems the yaw, which only the
        angles estimator uses (a yaw does not change ``h_z``).
    source : str
        Where the values come from (``"given"``, ``"estimated"``, ...), for the record.
    """

    angle: float = 0.0
    rate: float = 0.0
    base_rate: float = 0.0
    attitude: float = 0.0
    source: str = "given"

    def __post_init__(self):
        for name in ("angle", "rate", "base_rate", "attitude"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise SpaceidError(f"`noise.{name}`: {value!r} must be a finite standard deviation >= 0")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def is_zero(self) -> bool:
        return self.angle == self.rate == self.base_rate == self.attitude == 0


def _axes(param: Parameterization):
    """Base-rate components that enter the equations: z only for planar systems."""
    return [2] if param.model.planar else [0, 1, 2]


def signal_sigma(param: Parameterization, noise: Noise) -> np.ndarray:
    """Noise standard deviations of the signal vector ``x = [q, qd, w0, dtheta]``, shape ``(n_x,)``."""
    nj = len(param.model.joints)
    n_att = 0 if param.model.planar else 3
    return np.concatenate([
        np.full(nj, noise.angle), np.full(nj, noise.rate),
        np.full(len(_axes(param)), noise.base_rate), np.full(n_att, noise.attitude),
    ])  # fmt: skip


def signal_jacobian(param: Parameterization, pi, q, qd, w0, h_base=None) -> np.ndarray:
    """Derivative of the equation error ``g = Y(q, qd, w0) pi - h_base`` w.r.t. the signals.

    Parameters
    ----------
    param : Parameterization
    pi : array_like of shape (k,)
        All minimal parameters (known ones included).
    q, qd : array_like of shape (n, n_joints)
    w0 : array_like of shape (n, 3)
        Base angular velocity in base axes [rad/s].
    h_base : array_like of shape (n, 3), optional
        Momentum in base axes [N m s]; its change with the attitude enters the attitude
        columns (spatial systems; zero when omitted).

    Returns
    -------
    ndarray of shape (n, rows, n_x)
        Columns ordered as :func:`signal_sigma`. Analytic
        (:func:`spaceid.dynamics.momentum_jacobian`: one kinematics evaluation per sample).
    """
    q = np.asarray(q, float)
    jac = momentum_jacobian(param, q, qd, w0, pi)
    if not param.model.planar:
        n = len(q)
        hb = np.zeros((n, 3)) if h_base is None else np.broadcast_to(np.asarray(h_base, float), (n, 3))
        # R0 -> R0 exp([d]x) turns R0^T h into hb + hb x d, so dg/dd = -[hb]x
        jac = np.concatenate([jac, -skew(hb)], -1)
    return jac


def equation_covariance(jac: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """First-order covariance of the equation errors, ``S_n = J_n diag(sigma^2) J_n^T``.

    Parameters
    ----------
    jac : ndarray of shape (n, rows, n_x)
    sigma : ndarray of shape (n_x,)

    Returns
    -------
    ndarray of shape (n, rows, rows)
    """
    js = jac * sigma
    return js @ np.swapaxes(js, -1, -2)


def noise_from_log(log) -> Noise:
    """Noise levels estimated from a log's own samples (:func:`spaceid.data.estimate_noise`).

    Each category pools its channels by RMS. Rates that were computed by differentiating the
    angles are smooth, and their sample-to-sample noise is no longer white: the estimate then
    understates their error, which the result records (``source``).
    """
    from ..data import estimate_noise, quat_to_yaw

    def pooled(x):
        if not x.size or np.isnan(x).all():  # no such channel (rate columns missing: an angles-only log)
            return 0.0
        return float(np.sqrt(np.mean(estimate_noise(log.t, x)[0] ** 2)))

    axes = [2] if log.planar else [0, 1, 2]
    if log.planar:  # the yaw: only the angles estimator weights by it
        attitude = pooled(np.unwrap(quat_to_yaw(log.base_quat))[:, None])
    else:
        attitude = 2 * pooled(log.base_quat[:, 1:])  # dq ~ d(theta) / 2
    source = "estimated from the log (sixth-order differences)"
    if "differentiation" in log.meta:
        source += "; rates were differentiated, so their error is understated"
    return Noise(pooled(log.q), pooled(log.qd), pooled(log.base_w[:, axes]), attitude, source)
