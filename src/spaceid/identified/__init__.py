"""The identified model made controller-ready: the free-floating dynamics (reduced joint inertia,
kinetic energy, forward dynamics, base rate) that the minimal parameters and their covariance fix,
and what they do not fix.
"""

from . import _dynamics
from ._dynamics import *  # noqa: F403

__all__ = [*_dynamics.__all__]
