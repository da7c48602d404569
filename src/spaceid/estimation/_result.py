"""The result of an identification: :class:`Identification`, its RESULT.json form
(:meth:`Identification.to_dict`, :func:`load_result`) and the comparison of two (:func:`compare`,
:class:`Comparison`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import SpaceidError
from ..data import read_json
from ._diagnostics import Diagnostics
from ._drift import drift_terms

__all__ = ["Comparison", "Identification", "compare", "load_result"]

Z95 = 1.959963984540054  # two-sided 95 % normal quantile, for confidence intervals


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
        Provenance: the parameter set (rank tolerance, seed), the log, the anchors, the noise
        model: everything needed to reproduce the result.
    units : tuple of str
        Each parameter's unit (``kg``, ``kg m``, ``kg m^2``; see ``Parameterization.units``);
        empty for results written before units were recorded.
    drift : tuple of dict
        The drift coefficients estimated with the parameters (``identify(..., drift=...)``),
        each ``{name, value, std, unit}`` (``torque_z``, ``viscous``, ``coulomb``, ...); empty
        without drift terms. ``momentum`` is then the momentum at the log's first sample.
    com : dict or None
        The system-CM terms identified from the base position (``spaceid.identified.identify_com``:
        names, definitions, values, std, covariance, ...); None when not identified.
    momentum_std : ndarray of shape (3,) or None
        Standard errors of ``momentum`` [N m s]: zeros when it was given; None when not recorded.
    diagnostics : Diagnostics
        How well the data agreed with the model: ``chi2_dof``, the residual tests, the drift
        test, the plausibility of the estimates, how the covariance was obtained
        (:class:`~spaceid.estimation.Diagnostics`).
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
    units: tuple = ()
    drift: tuple = ()
    com: dict | None = None
    momentum_std: np.ndarray | None = None
    diagnostics: Diagnostics = field(default_factory=Diagnostics)

    def drift_terms(self) -> dict:
        """The drift coefficients as :func:`spaceid.motion.simulate` takes them (empty without drift)."""
        return drift_terms({d["name"]: d["value"] for d in self.drift}, self.planar, where="result drift",
                           physical=False)

    def plot(self, ax=None, *, kind: str = "parameters", true=None, reference=None, reference_label: str = "paper"):
        """Draw the identification and return the :class:`matplotlib.figure.Figure`.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Draw on it (its legend on it too); default: a new figure (no pyplot state: show it, or
            ``fig.savefig(path)``).
        kind : {"parameters", "singular_values"}
            The estimates with 2-sigma error bars on one relative axis
            (:func:`spaceid.studies.plot_parameters`), or the singular values of the stacked
            regressor (:func:`spaceid.studies.plot_singular_values`).
        true, reference, reference_label
            ``parameters`` only: the true values (errors relative to them) and reference relative
            errors in percent, as :func:`spaceid.studies.plot_parameters` takes them.

        Returns
        -------
        matplotlib.figure.Figure
            The figure drawn (the one that holds ``ax`` when given).
        """
        from ._plots import draw_parameters, draw_singular_values

        if kind == "parameters":
            return draw_parameters(self, true, reference, reference_label, ax)
        if kind == "singular_values":
            return draw_singular_values(self, ax)
        raise SpaceidError(f"plot: kind {kind!r} is not 'parameters' or 'singular_values'")

    def to_dict(self) -> dict:
        """JSON-ready RESULT.json form: parameters with 95 % confidence intervals, covariance,
        conditioning, residual, settings and diagnostics (read back by :meth:`from_dict`;
        docs/formats/result-json.md)."""
        return {
            "model": self.model,
            "planar": self.planar,
            "estimator": self.estimator,
            "momentum": self.momentum.tolist(),
            **({"momentum_std": np.asarray(self.momentum_std).tolist()} if self.momentum_std is not None else {}),
            "parameters": [
                {"name": n, "definition": d, "value": float(v), "std": float(s),
                 "ci95": [float(v - Z95 * s), float(v + Z95 * s)], **({"unit": self.units[i]} if self.units else {})}
                for i, (n, d, v, s) in enumerate(zip(self.names, self.definitions, self.values, self.std))
            ],
            "drift": [dict(d) for d in self.drift],
            "covariance": self.cov.tolist(),
            "condition_number": self.condition_number,
            "singular_values": self.singular_values.tolist(),
            "residual_rms": self.residual_rms,
            "n_samples": self.n_samples,
            "settings": self.settings,
            "diagnostics": self.diagnostics.to_dict(),
            **({"com": self.com} if self.com is not None else {}),
        }

    @classmethod
    def from_dict(cls, data: dict, where: str = "result") -> Identification:
        """The identification of a :meth:`to_dict` record; ``where`` names it in errors
        (:class:`~spaceid.SpaceidError` for a missing or bad field).

        Records written before ``diagnostics`` and ``momentum_std`` had their own places keep them in
        ``settings``: they are moved over (:data:`Diagnostics.KEYS`, ``momentum_std``)."""
        try:
            params = data["parameters"]
            settings = dict(data.get("settings", {}))
            diagnostics = data.get("diagnostics")
            if diagnostics is None:  # an older file: the diagnostics were settings
                diagnostics = {k: settings.pop(k) for k in Diagnostics.KEYS if k in settings}
            h_std = data.get("momentum_std", settings.pop("momentum_std", None))
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
                settings,
                tuple(p["unit"] for p in params) if all("unit" in p for p in params) else (),
                tuple({"name": str(d["name"]), "value": float(d["value"]), "std": float(d["std"]),
                       "unit": str(d["unit"])} for d in data.get("drift", [])),
                data.get("com"),
                None if h_std is None else np.asarray(h_std, float).reshape(3),
                Diagnostics.from_dict(diagnostics),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise SpaceidError(f"{where}: not a spaceid result file (bad or missing field {exc}): "
                               "use a file written by 'spaceid identify' or from Identification.to_dict") from None


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


@dataclass(frozen=True)
class Comparison:
    """How the parameters changed between two identifications of the same structure (:func:`compare`).

    Attributes
    ----------
    names, definitions : tuple of str
        The minimal parameters.
    before, after : ndarray of shape (k,)
        Their estimates in the first and the second identification.
    change : ndarray of shape (k,)
        ``after - before``.
    relative_change : ndarray of shape (k,)
        ``change / |before|`` (infinite where ``before`` is zero).
    z : ndarray of shape (k,)
        ``change / sqrt(std_before^2 + std_after^2)``: whether the change stands out from the
        estimation noise (infinite where both standard errors are zero).
    """

    names: tuple
    definitions: tuple
    before: np.ndarray
    after: np.ndarray
    change: np.ndarray
    relative_change: np.ndarray
    z: np.ndarray

    def changed(self, threshold: float = 3.0) -> tuple:
        """The names of the parameters whose ``|z|`` exceeds ``threshold``."""
        return tuple(n for n, z in zip(self.names, self.z) if abs(z) > threshold)

    def to_dict(self) -> dict:
        """JSON-ready (``spaceid compare --json``): ``parameters``, per parameter ``name``, ``definition``,
        ``before``, ``after``, ``change``, ``relative_change`` and ``z``."""
        return {
            "parameters": [
                {"name": n, "definition": d, "before": float(b), "after": float(a), "change": float(c),
                 "relative_change": float(r), "z": float(s)}
                for n, d, b, a, c, r, s in zip(self.names, self.definitions, self.before, self.after, self.change,
                                               self.relative_change, self.z)
            ]
        }


def compare(before: Identification, after: Identification, *, where: str = "results") -> Comparison:
    """How the parameters changed between two identifications of the same structure.

    For the on-orbit servicing case: identify before and after a capture (or a fuel burn) and
    see which combinations moved, with a z-score ``change / sqrt(std_before^2 + std_after^2)``
    that says whether the change stands out from the estimation noise.

    Returns
    -------
    Comparison
        Per parameter the estimates ``before`` and ``after``, the ``change``, the
        ``relative_change`` and ``z``; :meth:`Comparison.changed` names those beyond 3.
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
    return Comparison(tuple(before.names), tuple(before.definitions), np.array(before.values, float),
                      np.array(after.values, float), change, rel, z)
