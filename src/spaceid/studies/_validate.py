"""Prediction with an identified model and validation against a measured log (paper Fig. 6).

The identified ``pi`` is enough to re-simulate the base motion for the measured joint motion
and momentum; the base angular velocity and attitude it predicts are compared with the log.
"""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError
from ..estimation import Identification
from ..models import load_model
from ..dynamics import Parameterization, minimal_parameters
from ..motion import hermite_motion, simulate
from ..data import Log

__all__ = ["parameterization_of", "predict", "validate", "validation_metrics"]


def parameterization_of(ident: Identification, *, where: str = "result") -> Parameterization:
    """Rebuild the minimal parameter set that ``ident`` was identified with, and check it."""
    settings = ident.settings.get("parameterization", {})
    model = load_model(ident.model, planar=ident.planar)
    param = minimal_parameters(model, tol=settings.get("rank_tol", 1e-9), seed=settings.get("seed", 0))
    if param.names != ident.names or param.definitions != ident.definitions:
        raise SpaceidError(
            f"{where}: its parameters do not match model '{ident.model}' as loaded now "
            f"({len(ident.names)} vs {param.n_params}): identify again with this model"
        )
    return param


def predict(ident: Identification, t, q, qd, *, momentum=None, initial_quat=None, where: str = "result",
            drift=None) -> Log:
    """Base motion of the identified model for a joint motion.

    Parameters
    ----------
    ident : Identification
    t : array_like of shape (n,)
        Time stamps [s].
    q, qd : array_like of shape (n, n_joints)
        Joint angles [rad] and rates [rad/s]; interpolated between samples (cubic Hermite).
    momentum : array_like of shape (3,), optional
        Inertial momentum [N m s] (default: the one of the identification).
    initial_quat : array_like of shape (4,), optional
        Base attitude at ``t[0]``.
    drift : dict, optional
        Drift terms (as :func:`spaceid.motion.simulate` takes them) that replace the
        identification's own (``ident.drift``, used by default): the momentum at ``t[0]`` is
        ``momentum`` and changes by the external torque.
    """
    param = parameterization_of(ident, where=where)
    h = ident.momentum if momentum is None else np.asarray(momentum, float)
    terms = {**ident.drift_terms(), **dict(drift or {})}
    return simulate(param, ident.values, hermite_motion(t, q, qd), t, h, initial_quat=initial_quat, drift=terms)


def validation_metrics(measured: Log, predicted: Log) -> dict:
    """RMS, normalised RMS and largest errors of the predicted base motion.

    Returns
    -------
    dict
        ``base_w_rms`` [rad/s] (norm over axes), ``base_w_nrms`` (RMS error / RMS of the
        measured rate), ``base_w_max`` [rad/s], and for planar logs ``base_yaw_rms`` and
        ``base_yaw_max`` [rad].
    """
    err = predicted.base_w - measured.base_w
    out = {
        "base_w_rms": float(np.sqrt(np.mean(np.sum(err**2, axis=1)))),
        "base_w_nrms": float(np.sqrt(np.mean(np.sum(err**2, axis=1)) / np.mean(np.sum(measured.base_w**2, axis=1)))),
        "base_w_max": float(np.abs(err).max()),
    }
    if measured.planar:
        yaw_err = predicted.base_yaw - measured.base_yaw
        out.update(base_yaw_rms=float(np.sqrt(np.mean(yaw_err**2))), base_yaw_max=float(np.abs(yaw_err).max()))
    return out


def validate(ident: Identification, log: Log, *, momentum=None, where: str = "result", drift=None):
    """Re-simulate ``ident`` with the log's joint motion and initial attitude (and its drift
    terms, or ``drift``: see :func:`predict`); compare.

    Returns
    -------
    predicted : Log
    metrics : dict
        See :func:`validation_metrics`.
    """
    predicted = predict(ident, log.t, log.q, log.qd, momentum=momentum, initial_quat=log.base_quat[0], where=where,
                        drift=drift)
    return predicted, validation_metrics(log, predicted)
