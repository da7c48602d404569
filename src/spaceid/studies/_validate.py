"""Prediction with an identified model, or a model as it is, and validation against a measured
log (paper Fig. 6).

The identified ``pi`` is enough to re-simulate the base motion for the measured joint motion
and momentum; the base angular velocity and attitude it predicts are compared with the log. A
model file (a CAD model: URDF or YAML) gives ``pi`` from its own standard parameters.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from ..dynamics import Parameterization, minimal_parameters
from ..estimation import Identification, load_result
from ..models import Model, load_model
from ..data import Log, check_time_units, log_fingerprint

__all__ = ["Predictor", "Validation", "attitude_error_angle", "predict", "predictor", "validate",
           "validation_metrics"]


@dataclass(frozen=True)
class Predictor:
    """What predicts a base motion: an identification's ``pi``, or a model's own (:func:`predictor`).

    Attributes
    ----------
    param : Parameterization
        The minimal parameter set.
    values : ndarray of shape (k,)
        Its ``pi``: the estimate, or the model's standard parameters mapped to the minimal set.
    momentum : ndarray of shape (3,) or None
        The identification's momentum [N m s]; None for a model (it has none: give one).
    drift : dict
        The identification's drift terms (empty for a model).
    kind : {"identification", "model"}
    source : str
        The result file, or the model's preset name or path.
    identification : Identification or None
        The identification, None for a model.
    """

    param: Parameterization
    values: np.ndarray
    momentum: np.ndarray | None
    drift: dict
    kind: str
    source: str
    identification: Identification | None = None

    @property
    def label(self) -> str:
        """What predicted, for reports: ``identification X`` or ``model X as it is (...)``."""
        if self.kind == "model":
            return f"model {self.source} as it is (its standard parameters, not identified)"
        return f"identification {self.source}"


def predictor(source, *, planar: bool | None = None, where: str = "result") -> Predictor:
    """The :class:`Predictor` of an identification or of a model as it is.

    Parameters
    ----------
    source : Predictor, Identification, IdentifiedModel, Model, str or Path
        A predictor (returned as it is), an identification (a record, or a RESULT.json path: a ``.json`` file), or a model (a
        :class:`~spaceid.models.Model`, a preset name, a URDF or YAML path: a CAD model whose
        standard parameters are known), predicted with its own parameters.
    planar : bool, optional
        For a model: force planar or spatial mode (as :func:`spaceid.models.load_model`).
    where : str
        Name of the source, for error messages.
    """
    from ..identified import IdentifiedModel, parameterization_of  # (not at import: reports need only labels)

    if isinstance(source, Predictor):
        return source
    if isinstance(source, (str, Path)) and Path(source).suffix.lower() == ".json":
        source, where = load_result(source), str(source)
    if isinstance(source, (Identification, IdentifiedModel)):
        ident = source.identification if isinstance(source, IdentifiedModel) else source
        return Predictor(parameterization_of(source, where=where), np.asarray(source.values, float),
                         np.asarray(source.momentum, float), source.drift_terms(), "identification", where, ident)
    if not isinstance(source, (Model, str, Path)):
        raise SpaceidError(f"`result`: {type(source).__name__} is neither an identification nor a model: give a "
                           "RESULT.json, an Identification, or a model (preset, URDF or YAML)")
    model = load_model(source, planar=planar)
    param = minimal_parameters(model)
    return Predictor(param, param.true_values, None, {}, "model", model.source or model.name)


@deprecated_alias(old="ident", new="result")
def predict(result, t, q, qd, *, momentum=None, initial_quat=None, where: str = "result", drift=None,
            planar: bool | None = None) -> Log:
    """Base motion of an identified model, or of a model as it is, for a joint motion.

    Parameters
    ----------
    result : Identification, IdentifiedModel, Model, str or Path
        What predicts (:func:`predictor`): an identification, or a model whose standard
        parameters are known (a CAD model), without a result file. ``meta["predicted_by"]`` of
        the output says which (:attr:`Predictor.label`).
    t : array_like of shape (n,)
        Time stamps [s].
    q, qd : array_like of shape (n, n_joints)
        Joint angles [rad] and rates [rad/s]; interpolated between samples (cubic Hermite).
    momentum : array_like of shape (3,), optional
        Inertial momentum [N m s] (default: the one of the identification; required for a model).
    initial_quat : array_like of shape (4,), optional
        Base attitude at ``t[0]``.
    drift : dict, optional
        Drift terms (as :func:`spaceid.motion.simulate` takes them) that replace the
        identification's own (``result.drift``, used by default): the momentum at ``t[0]`` is
        ``momentum`` and changes by the external torque.
    planar : bool, optional
        For a model: force planar or spatial mode.

    Raises
    ------
    SpaceidError
        A model without ``momentum``; parameters whose locked inertia is not positive definite
        along the motion (physically impossible ones: refused before integrating, naming the time,
        the direction and the parameters; :func:`spaceid.motion.simulate`).
    """
    from ..motion import hermite_motion, simulate

    source = result if isinstance(result, Predictor) else predictor(result, planar=planar, where=where)
    h = source.momentum if momentum is None else np.asarray(momentum, float)
    if h is None:
        raise SpaceidError(f"`momentum`: {source.source} is a model, which has no momentum of its own: give the "
                           "inertial angular momentum [N m s]")
    terms = {**source.drift, **dict(drift or {})}
    log = simulate(source.param, source.values, hermite_motion(t, q, qd), t, h, initial_quat=initial_quat,
                   drift=terms, where=f"{source.source}: its parameters")
    return replace(log, meta={**log.meta, "predicted_by": source.label})


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
    predicted_by : str
        What predicted (:attr:`Predictor.label`): an identification, or a model as it is.
    """

    measured: Log
    predicted: Log
    metrics: dict
    predicted_by: str = ""

    def plot(self, fig=None, *, title: str | None = None):
        """Draw the measured base motion against the predicted one, with the residuals (the paper's
        Fig. 6, :func:`spaceid.studies.plot_validation`), and return the :class:`matplotlib.figure.Figure`.

        Parameters
        ----------
        fig : matplotlib.figure.Figure or SubFigure, optional
            Draw into it (two rows of panels); default: a new figure.
        title : str, optional
            Figure title; default names what is compared (:func:`validation_title`).
        """
        from ._figures import _draw_validation  # the figures read this module

        return _draw_validation(self.measured, self.predicted, title, fig)

    def to_dict(self) -> dict:
        """JSON-ready: the ``metrics``, ``predicted_by``, and the log's ``source``, ``n_samples``, ``start``
        and ``end`` [s], ``joints`` and ``planar`` flag (the logs themselves are written as log CSV files)."""
        return {"metrics": dict(self.metrics), "predicted_by": self.predicted_by,
                "source": self.measured.meta.get("source"),
                "n_samples": int(self.measured.n_samples), "start": float(self.measured.t[0]),
                "end": float(self.measured.t[-1]), "joints": list(self.measured.joints),
                "planar": bool(self.measured.planar)}


def _model_source(predicted: Log) -> str | None:
    """The model a predicted log came from as it is (``meta["predicted_by"]``), None for an identification's."""
    by = predicted.meta.get("predicted_by", "")
    return Path(by.split(" as it is")[0].removeprefix("model ")).name if by.startswith("model ") else None


def validation_title(predicted: Log) -> str:
    """The validation figure's default title: what predicted (``predicted.meta["predicted_by"]``,
    :attr:`Predictor.label`) against the measured motion."""
    model = _model_source(predicted)
    if model is not None:
        return (f"Validation: measured base motion vs model {model} as it is (its standard parameters,\n"
                "not identified), driven by the measured joint motion")
    return "Validation: measured base motion vs the identified model driven by the measured joint motion"


def predicted_label(predicted: Log) -> str:
    """The legend entry of the predicted motion: the identified model's, or the model's as it is."""
    model = _model_source(predicted)
    return "identified model (predicted)" if model is None else f"model {model} (predicted)"


@deprecated_alias(old="ident", new="result")
def validate(result, log: Log, *, momentum=None, where: str = "result", drift=None,
             planar: bool | None = None) -> Validation:
    """Re-simulate ``result`` with the log's joint motion and initial attitude (and its drift
    terms, or ``drift``: see :func:`predict`); compare.

    ``result`` is an identification or a model as it is (a CAD model: preset, URDF or YAML path, or
    :class:`~spaceid.models.Model`; ``momentum`` then required), as :func:`predict` takes it;
    ``Validation.predicted_by`` says which.

    A ``UserWarning`` when ``log`` is the log ``result`` was identified from (its
    ``settings["log_fingerprint"]``, :func:`spaceid.data.log_fingerprint`): a fit follows its own
    data, so only a different motion tests the model; another when the base-rate error exceeds
    :data:`POOR_VALIDATION` of the measured rate (the model does not predict the log).

    Returns
    -------
    Validation
        ``measured`` (the log), ``predicted`` and ``metrics`` (see :func:`validation_metrics`).
    """
    source = predictor(result, planar=planar, where=where)
    if source.identification is not None:
        _warn_if_fitting_log(source.identification, log, where)
    check_time_units(log, log.meta.get("source", "log"))  # re-simulated in time: stamps in ms would mislead
    predicted = predict(source, log.t, log.q, log.qd, momentum=momentum, initial_quat=log.base_quat[0], drift=drift)
    metrics = validation_metrics(log, predicted)
    if metrics["base_w_nrms"] > POOR_VALIDATION:
        warnings.warn(
            f"{where}: the predicted base rate misses the measured one by {100 * metrics['base_w_nrms']:.3g} % "
            f"(RMS, above {100 * POOR_VALIDATION:.0f} %): the model does not predict this log: a result of another "
            "robot or payload, a wrong `momentum`, or a unit error in the log or the model (parameters 1000 times "
            "off give ~100 %)", UserWarning, stacklevel=2)
    return Validation(log, predicted, metrics, source.label)
