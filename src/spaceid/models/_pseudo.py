"""Pseudo-inertias and the standard parameters ``theta`` of a model, for the programs over
physically consistent models (the export of :mod:`spaceid.identified`, the CAD prior of
:mod:`spaceid.estimation`): a body's pseudo-inertia ``J = [[Sigma, h], [h^T, m]]`` is positive
definite exactly when the body is physical, and ``J_b = L_b X_b L_b^T`` (``L_b`` the Cholesky factor
of a reference body's) whitens it so that the reference sits at ``X_b = 1``.
"""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError
from ._model import INERTIAL_NAMES, Model

SPREAD = 1e-6
"""A reference body whose pseudo-inertia has an eigenvalue below this fraction of its largest (a
plate, a rod) is measured against a copy with ``SPREAD tr(Sigma)`` of isotropic second moment added."""
MARGIN = 1e-6
"""Every pseudo-inertia of a program's solution satisfies ``J - MARGIN J_ref`` positive semidefinite:
strictly physical, by a margin relative to the reference's own mass distribution (free of units)."""
def pseudo_inertia(inertial) -> np.ndarray:
    """Pseudo-inertia (second moments of mass) of a body, shape (4, 4).

    Parameters
    ----------
    inertial : array_like of shape (10,)
        ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``, inertia about the frame origin.

    Returns
    -------
    ndarray of shape (4, 4)
        ``[[Sigma, h], [h^T, m]]`` with ``Sigma = tr(I)/2 1 - I`` [kg m^2] and ``h = m c`` [kg m].
        Positive definite exactly when the mass is positive, the inertia about the CoM positive
        definite and its principal moments obey the triangle inequality (strictly).
    """
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(inertial, float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = np.empty((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = hx, hy, hz
    out[3, 3] = m
    return out


def inertial_from_pseudo(pseudo) -> np.ndarray:
    """Inverse of :func:`pseudo_inertia`: the standard parameters (10,) of a (4, 4) pseudo-inertia
    (its symmetric part)."""
    j = 0.5 * (np.asarray(pseudo, float) + np.asarray(pseudo, float).T)
    inertia = np.trace(j[:3, :3]) * np.eye(3) - j[:3, :3]
    return np.array([j[3, 3], *j[:3, 3], inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2],
                     inertia[1, 2], inertia[2, 2]])  # fmt: skip


def reference_pseudo(inertial, where: str, name: str) -> np.ndarray:
    """The pseudo-inertia of a reference (prior) body, positive definite: a degenerate one (a
    plate such as a reaction-wheel disc with ``Izz = Ixx + Iyy``, or a rod) gets the isotropic
    second moment ``SPREAD tr(Sigma)`` added; a point mass is refused."""
    pseudo = pseudo_inertia(inertial)
    eig = np.linalg.eigvalsh(pseudo)
    if eig[0] > SPREAD * eig[-1]:
        return pseudo
    spread = SPREAD * np.trace(pseudo[:3, :3])
    pseudo[:3, :3] += spread * np.eye(3)
    if not np.linalg.eigvalsh(pseudo)[0] > 0.1 * spread > 0:
        raise SpaceidError(f"{where}: body '{name}' of the prior is a point mass or not physical (pseudo-inertia "
                           "not positive definite): give it a plausible inertia")
    return pseudo


def theta_slots(model: Model) -> list:
    """``(body, index into INERTIAL_NAMES)`` of each standard parameter in ``theta``, the order of
    ``full_parameter_names`` (declared zeros left out)."""
    return [(b, k) for b, body in enumerate(model.bodies)
            for k, n in enumerate(INERTIAL_NAMES) if n not in body.known_zero]  # fmt: skip


def with_theta(model: Model, theta) -> Model:
    """``model`` with the standard parameters ``theta`` (:func:`theta_slots` order; declared zeros zero)."""
    inertials = np.zeros((len(model.bodies), 10))
    for (b, k), value in zip(theta_slots(model), theta):
        inertials[b, k] = value
    return model.with_inertials(inertials)


def pseudo_whitening(reference: Model, where: str) -> tuple:
    """The linear maps of the stacked ``vec(X_b)`` (column-major) to ``theta`` and to the declared
    zeros, ``G (n_theta, 16 nb)`` and ``Z (n_zero, 16 nb)``, where ``J_b = L_b X_b L_b^T`` with
    ``L_b`` the Cholesky factor of the reference's pseudo-inertia (the reference is at ``X_b = 1``)."""
    factors = [np.linalg.cholesky(reference_pseudo(b.inertial, where, b.name)) for b in reference.bodies]
    nb = len(reference.bodies)
    full = np.zeros((10 * nb, 16 * nb))
    for b, low in enumerate(factors):
        for col in range(16):
            unit = np.zeros(16)
            unit[col] = 1.0
            full[10 * b : 10 * b + 10, 16 * b + col] = inertial_from_pseudo(low @ unit.reshape(4, 4, order="F") @ low.T)
    slots = [10 * b + k for b, k in theta_slots(reference)]
    zeros = np.setdiff1d(np.arange(10 * nb), slots)
    return full[slots], full[zeros]


def whitened_physical(g, theta) -> bool:
    """Whether every body's whitened pseudo-inertia ``X_b`` (``theta = G vec X``, the reference at the
    identity) is positive definite: mass, inertia about the CoM and triangle inequalities."""
    x = np.linalg.lstsq(g, theta, rcond=None)[0]
    return all(np.linalg.eigvalsh(0.5 * (b + b.T)).min() > 0
               for b in x.reshape(-1, 4, 4).transpose(0, 2, 1))  # column-major vec per body
