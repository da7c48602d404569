"""Prediction with an identified model and validation against a measured log (paper Fig. 6).

The identified ``pi`` is enough to re-simulate the base motion for the measured joint motion
and momentum; the base angular velocity and attitude it predicts are compared with the log.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .._deprecation import deprecated_alias
from ..estimation import Identification
from ..identified import parameterization_of
from ..motion import hermite_motion, simulate
from ..data import Log, check_time_units, log_fingerprint

__all__ = ["Validation", "attitude_error_angle", "predict", "validate", "validation_metrics"]


@deprecated_alias(old="ident", new="result")
def predict(result: Identification, t, q, qd, *, momentum=None, initial_quat=None, where: str = "result",
            drift=None) -> Log:
    """Base motion of the identified model for a joint motion.

    Parameters
    ----------
    result : Identification or IdentifiedModel
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
        identification's own (``result.drift``, used by default): the momentum at ``t[0]`` is
        ``momentum`` and changes by the external torque.
    """
    param = parameterization_of(result, where=where)
    h = result.momentum if momentum is None else np.asarray(momentum, float)
    terms = {**result.drift_terms(), **dict(drift or {})}
    return simulate(param, result.values, hermite_motion(t, q, qd), t, h, initial_quat=initial_quat, drift=terms)


def attitude_error_angle(a, b) -> np.ndarray:
    """Angle [rad] of the rotation between attitudes ``a`` and ``b`` (unit quaternions, scalar
    first, shape (n, 4) or (4,)), in [0, pi]; ``q`` and ``-q`` are the same attitude.

    From ``a^* b = [c, v]`` as ``2 atan2(|v|, |c|)``, accurate for small angles too (``arccos``
    of the scalar part loses half the digits there). Returns shape (n,)."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    c = np.sum(a * b, axis=1)
    v = a[:, :1] * b[:, 1:] - b[:, :1] * a[:, 1:] - np.cross(a[:, 1:], b[:, 1:])
    return 2 * np.arctan2(np.linalg.norm(v, axis=1), np.abs(c))


POOR_VALIDATION = 0.5
"""A normalised base-rate RMS error (``base_w_nrms``) above this warns: the model does not predict
the log (validations of a right model stay at a few per cent)."""


def validation_metrics(measured: Log, predicted: Log) -> dict:
    """RMS, normalised RMS and largest errors of the predicted base motion.

    Returns
    -------
    dict
        ``base_w_rms`` [rad/s] (norm over axes), ``base_w_nrms`` (RMS error / RMS of the
        measured rate), ``base_w_max`` [rad/s], and for planar logs ``base_yaw_rms`` and
        ``base_yaw_max`` [rad], for spatial ones ``base_attitude_rms`` and
        ``base_attitude_max`` [rad] (:func:`attitude_error_angle`).
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
    else:
        angle = attitude_error_angle(measured.base_quat, predicted.base_quat)
        out.update(base_attitude_rms=float(np.sqrt(np.mean(angle**2))), base_attitude_max=float(angle.max()))
    return out


def _warn_if_fitting_log(ident: Identification, log: Log, where: str) -> None:
    """Warn when ``log`` has the time stamps and joint angles ``ident`` was identified from."""
    if ident.settings.get("log_fingerprint") == log_fingerprint(log):
        warnings.warn(
            f"{where}: the log to validate on is the one the model was identified from (same time stamps and joint "
            "angles): validation on the fitting log cannot fail; record a different motion and validate on it",
            UserWarning, stacklevel=3,
        )


@dataclass(frozen=True)
class Validation:
    """An identified model's prediction against a measured log (:func:`validate`).

    Attributes
    ----------
    measured : Log
        The log validated on.
    predicted : Log
        The identified model's base motion for its joint motion, at its time stamps.
    metrics : dict of str to float
        :func:`validation_metrics` of the two: ``base_w_rms``, ``base_w_nrms``, ``base_w_max``
        and the yaw's (planar) or attitude's (spatial) errors.
    """

    measured: Log
    predicted: Log
    metrics: dict

    def plot(self, fig=None, *, title: str | None = None):
        """Draw the measured base motion against the predicted one, with the residuals (the paper's
        Fig. 6, :func:`spaceid.studies.plot_validation`), and return the :class:`matplotlib.figure.Figure`.

        Parameters
        ----------
        fig : matplotlib.figure.Figure or SubFigure, optional
            Draw into it (two rows of panels); default: a new figure.
        title : str, optional
            Figure title; default names what is compared.
        """
        from ._figures import _draw_validation  # the figures read this module

        return _draw_validation(self.measured, self.predicted, title, fig)

    def to_dict(self) -> dict:
        """JSON-ready: the ``metrics``, and the log's ``source``, ``n_samples``, ``start`` and ``end`` [s],
        ``joints`` and ``planar`` flag (the logs themselves are written as log CSV files)."""
        return {"metrics": dict(self.metrics), "source": self.measured.meta.get("source"),
                "n_samples": int(self.measured.n_samples), "start": float(self.measured.t[0]),
                "end": float(self.measured.t[-1]), "joints": list(self.measured.joints),
                "planar": bool(self.measured.planar)}


@deprecated_alias(old="ident", new="result")
def validate(result: Identification, log: Log, *, momentum=None, where: str = "result", drift=None) -> Validation:
    """Re-simulate ``result`` with the log's joint motion and initial attitude (and its drift
    terms, or ``drift``: see :func:`predict`); compare.

    A ``UserWarning`` when ``log`` is the log ``result`` was identified from (its
    ``settings["log_fingerprint"]``, :func:`spaceid.data.log_fingerprint`): a fit follows its own
    data, so only a different motion tests the model; another when the base-rate error exceeds
    :data:`POOR_VALIDATION` of the measured rate (the model does not predict the log).

    Returns
    -------
    Validation
        ``measured`` (the log), ``predicted`` and ``metrics`` (see :func:`validation_metrics`).
    """
    _warn_if_fitting_log(result, log, where)
    check_time_units(log, log.meta.get("source", "log"))  # re-simulated in time: stamps in ms would mislead
    predicted = predict(result, log.t, log.q, log.qd, momentum=momentum, initial_quat=log.base_quat[0], where=where,
                        drift=drift)
    metrics = validation_metrics(log, predicted)
    if metrics["base_w_nrms"] > POOR_VALIDATION:
        warnings.warn(
            f"{where}: the predicted base rate misses the measured one by {100 * metrics['base_w_nrms']:.3g} % "
            f"(RMS, above {100 * POOR_VALIDATION:.0f} %): the model does not predict this log: a result of another "
            "robot or payload, a wrong `momentum`, or a unit error in the log or the model (parameters 1000 times "
            "off give ~100 %)", UserWarning, stacklevel=2)
    return Validation(log, predicted, metrics)
