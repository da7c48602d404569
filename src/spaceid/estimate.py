"""Least-squares identification of the minimal parameters from a measured motion (Eq. 11).

References
----------
.. [1] Papadopoulos et al., Eq. 4 (stacked equations) and Eq. 11 (least squares).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scipy.linalg import cho_factor, cho_solve

from ._errors import SpaceidError
from .regressor import Parameterization
from .timeseries import Log, quat_to_matrix

__all__ = ["Identification", "stack", "identify", "compare", "momentum_in_base", "parse_momentum"]


def parse_momentum(value, *, planar: bool) -> np.ndarray:
    """Inertial angular momentum as a 3-vector [N m s] from a number or ``"hx,hy,hz"``.

    A planar system takes a scalar ``h`` (about the inertial z axis).
    """
    try:
        parts = [float(v) for v in str(value).split(",")] if not np.ndim(value) else [float(v) for v in value]
    except ValueError:
        raise SpaceidError(f"--momentum: '{value}' is not a number or a list hx,hy,hz [N m s]") from None
    if len(parts) == 1 and planar:
        parts = [0.0, 0.0, parts[0]]
    if len(parts) != 3 or not np.all(np.isfinite(parts)):
        raise SpaceidError(f"--momentum: expected {'h or ' if planar else ''}hx,hy,hz (finite, N m s), got '{value}'")
    return np.array(parts)


def momentum_in_base(log: Log, momentum) -> np.ndarray:
    """The constant inertial momentum ``(3,)`` expressed in base axes at every sample ``(N, 3)``."""
    rot = quat_to_matrix(log.base_quat)
    return np.einsum("nji,j->ni", rot, np.asarray(momentum, float))


def stack(param: Parameterization, log: Log, momentum):
    """Stacked regressor and right-hand side of Eq. 4.

    Returns
    -------
    Y : ndarray of shape (n_samples * rows, k)
    h : ndarray of shape (n_samples * rows,)
        Known momentum in base axes (z only for planar systems) [N m s].
    """
    y = param.regressor(log.q, log.qd, log.base_w)
    h = momentum_in_base(log, momentum)
    if param.model.planar:
        h = h[:, 2:3]
    return y.reshape(-1, param.n_params), h.reshape(-1)


def _unexcited(y: np.ndarray, names, tol: float) -> list:
    """Names of the parameters that dominate the (near-)null space of ``y``."""
    scaled = y / np.maximum(np.linalg.norm(y, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(scaled, full_matrices=False)
    null = vt[s < tol * s[0]]
    weight = np.abs(null).max(axis=0) if len(null) else np.zeros(len(names))
    return [n for n, w in zip(names, weight) if w > 0.3]


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
                {"name": n, "definition": d, "value": float(v), "std": float(s)}
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


def identify(param: Parameterization, log: Log, momentum, *, where: str = "log", cond_limit: float = 1e10) -> Identification:
    """Ordinary least squares with known momentum (Eq. 11).

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model (geometry only is used).
    log : Log
        Measured motion; joint columns in ``param.model.joints`` order.
    momentum : array_like of shape (3,)
        Inertial angular momentum [N m s]; a nonzero value fixes the scale.
    where : str
        Name of the data source, for error messages.
    cond_limit : float
        Condition numbers of the column-scaled regressor above this mean some parameters are
        not excited: an error names them.

    Returns
    -------
    Identification
    """
    momentum = np.asarray(momentum, float)
    k = param.n_params
    if log.n_samples * param.rows < k + 1:
        raise SpaceidError(
            f"{where}: {log.n_samples} samples give {log.n_samples * param.rows} equations for {k} parameters: "
            f"record at least {-(-(k + 1) // param.rows)} samples"
        )
    if not np.linalg.norm(momentum) > 0:
        raise SpaceidError(
            f"{where}: the momentum is zero, so the equations are homogeneous and fix the parameters only up to "
            "scale: give the nonzero momentum of the run (--momentum)"
        )
    y, h = stack(param, log, momentum)
    # Columns scaled to unit norm: the scaled condition number decides excitation (it does
    # not depend on units), and the semi-normal equations with one refinement step solve the
    # least-squares problem to LSQR accuracy at the cost of one Gram matrix (fast for 10^4 samples).
    scale = np.linalg.norm(y, axis=0)
    scale[scale == 0] = 1.0
    ys = y / scale
    gram = ys.T @ ys
    eig = np.linalg.eigvalsh(gram)
    cond_scaled = float(np.sqrt(eig[-1] / eig[0])) if eig[0] > 0 else np.inf
    if cond_scaled > 1e6:  # near the precision limit of the Gram matrix: decide on the SVD
        sv = np.linalg.svd(ys, compute_uv=False)
        cond_scaled = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    if not cond_scaled < cond_limit:
        bad = _unexcited(y, param.names, 1e-8)
        raise SpaceidError(
            f"{where}: the regressor is rank-deficient (scaled cond {cond_scaled:.3g}); not excited: "
            f"{', '.join(bad) or 'unclear'}: use an exciting trajectory (spaceid design) that moves every joint"
        )
    factor = cho_factor(gram)
    x = cho_solve(factor, ys.T @ h)
    x += cho_solve(factor, ys.T @ (h - ys @ x))  # one refinement step
    values = x / scale
    resid = y @ values - h
    dof = max(len(h) - k, 1)
    sigma2 = float(resid @ resid) / dof
    cov = sigma2 * cho_solve(factor, np.eye(k)) / np.outer(scale, scale)
    # singular values of the unscaled regressor (the paper's condition number), from its Gram
    # matrix: accurate to eps * s_max, ample for the condition numbers of exciting motions
    s = np.sqrt(np.clip(np.linalg.eigvalsh(gram * np.outer(scale, scale)), 0, None))[::-1]
    cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
    return Identification(
        param.names,
        param.definitions,
        values,
        np.sqrt(np.diag(cov)),
        cov,
        cond,
        s,
        float(np.sqrt(np.mean(resid**2))),
        log.n_samples,
        "ols",
        momentum,
        param.model.source or param.model.name,
        param.model.planar,
        {"parameterization": param.to_dict(), "log": dict(log.meta), "condition_number_scaled": cond_scaled},
    )


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
