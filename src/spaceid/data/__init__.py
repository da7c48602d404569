"""Measured and simulated time series: the log record, CSV/JSON files, ROS bags and MCAP,
recordings, differentiation of sampled signals.
"""

from . import _timeseries, _recording, _signals, _files, _bags
from ._timeseries import *  # noqa: F403
from ._recording import *  # noqa: F403
from ._signals import *  # noqa: F403
from ._files import *  # noqa: F403
from ._bags import *  # noqa: F403

__all__ = _timeseries.__all__ + _recording.__all__ + _signals.__all__ + _files.__all__ + _bags.__all__
