"""Estimating the minimal parameters from logs: least squares and errors-in-variables estimators,
the signal noise model, the Cramer-Rao bounds (rate and angle measurements).
"""

from . import (_noise, _drift, _equations, _estimators, _angles, _uncertainty, _residuals, _diagnostics, _result,
               _stream, _identify, _parse, _monitor)
from ._noise import *  # noqa: F403
from ._drift import *  # noqa: F403
from ._equations import *  # noqa: F403
from ._estimators import *  # noqa: F403
from ._angles import *  # noqa: F403
from ._uncertainty import *  # noqa: F403
from ._diagnostics import *  # noqa: F403
from ._result import *  # noqa: F403
from ._stream import *  # noqa: F403
from ._identify import *  # noqa: F403
from ._parse import *  # noqa: F403
from ._monitor import *  # noqa: F403

__all__ = (
    _noise.__all__ + _drift.__all__ + _equations.__all__ + _estimators.__all__ + _angles.__all__ + _uncertainty.__all__
    + _diagnostics.__all__ + _result.__all__ + _stream.__all__ + _identify.__all__ + _parse.__all__ + _monitor.__all__
)  # fmt: skip
