"""Estimating the minimal parameters from logs: least squares and errors-in-variables estimators,
the signal noise model, the Cramer-Rao bound.
"""

from . import _noise, _estimate, _parse
from ._noise import *  # noqa: F403
from ._estimate import *  # noqa: F403
from ._parse import *  # noqa: F403

__all__ = _noise.__all__ + _estimate.__all__ + _parse.__all__
