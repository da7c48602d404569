"""Excitation for a payload's parameters: the regressor of the payload's inertial parameters on a
link of a known servicer (docs/theory/payload.md), for :func:`~spaceid.motion.design_excitation`.

The momentum's derivative with respect to the payload's standard parameters ``theta`` is the
servicer's minimal regressor times ``d pi / d theta`` (:class:`spaceid.identified.PayloadMap`), at
a nominal payload (none: the first-order problem). Its columns are scaled by a reference mass and
length, so that ``cond`` does not depend on units and ``crb`` bounds relative errors.
"""

from __future__ import annotations

import numpy as np

from ..dynamics import excitation_regressor
from ._criteria import whitened_regressor

__all__ = ["payload_regressor"]


def _reference_scale(pmap, theta) -> np.ndarray:
    """Scale ``(n,)`` of the payload unknowns: ``m, m l, m l^2`` per power of length, ``m`` and ``l``
    (the RMS distance of the mass from the frame origin) of the nominal payload, or of the
    holding body when the nominal has no mass."""
    std = pmap.standard(theta) if theta[0] > 0 else pmap.param.model.bodies[pmap.body].inertial
    m = float(std[0])
    length = np.sqrt(max(std[4] + std[6] + std[9], 0.0) / (2 * m)) or 1.0
    powers = np.array([0, 1, 1, 2] if pmap.planar else [0, 1, 1, 1, 2, 2, 2, 2, 2, 2])
    return m * length**powers


class payload_regressor:  # noqa: N801 - used like a function; a class so it pickles
    """Stacked regressor of a joint motion in a payload's (scaled) standard parameters.

    ``payload_regressor(pmap, momentum, noise, payload)(q, qd)`` with ``q, qd`` of shape
    ``(..., n_samples, n_joints)`` returns ``(..., n_samples * rows, n)``: the servicer's
    regressor (the base rate from momentum conservation with the nominal payload), whitened by the
    equation-error covariance when ``noise`` is given (:class:`whitened_regressor`), times
    ``d pi / d theta`` and the reference scale: its Gram matrix is then the Fisher information of
    ``theta / scale``.

    Parameters
    ----------
    pmap : spaceid.identified.PayloadMap
    momentum : array_like of shape (3,)
        Angular momentum [N m s].
    noise : Noise, optional
        Measurement noise (not all zero); None: the plain regressor.
    payload : array_like of shape (n,), optional
        Nominal payload (``pmap``'s unknowns); default none (zero mass).

    Attributes
    ----------
    scale : ndarray of shape (n,)
        The reference scale of the unknowns [kg, kg m, kg m^2].
    """

    def __init__(self, pmap, momentum, noise=None, payload=None):
        theta = np.zeros(pmap.n) if payload is None else np.asarray(payload, float)
        pi = pmap.pi(theta)
        if noise is None:
            self.base = excitation_regressor(pmap.param, pi, momentum)
        else:
            self.base = whitened_regressor(pmap.param, pi, momentum, noise, relative=False)
            self.fd_step = self.base.fd_step  # the design's step for whitened regressors
        self.scale = _reference_scale(pmap, theta)
        self.columns = pmap.columns(theta) * self.scale

    def __call__(self, q, qd):
        return self.base(q, qd) @ self.columns

    def crb(self, q, qd):
        """Cramer-Rao bound ``(n, n)`` of the unscaled unknowns for samples ``q, qd (n_samples,
        n_joints)`` (needs ``noise``)."""
        yw = self(q, qd)
        return np.linalg.inv(yw.T @ yw) * np.outer(self.scale, self.scale)
