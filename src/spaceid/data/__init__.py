"""Measured and simulated time series: the log record, CSV/JSON files, ROS bags and MCAP,
recordings, differentiation of sampled signals.
"""

from . import _timeseries, _recording, _signal_checks, _signal_noise, _signals, _files, _follow
from . import _bag_format, _bag_write, _bag_read, _bag_to_log, _bags
from ._timeseries import *  # noqa: F403
from ._recording import *  # noqa: F403
from ._signal_checks import *  # noqa: F403
from ._signal_noise import *  # noqa: F403
from ._signals import *  # noqa: F403
from ._files import *  # noqa: F403
from ._follow import *  # noqa: F403
from ._bag_format import *  # noqa: F403
from ._bag_write import *  # noqa: F403
from ._bag_read import *  # noqa: F403
from ._bag_to_log import *  # noqa: F403
from ._bags import *  # noqa: F403

__all__ = (
    _timeseries.__all__ + _recording.__all__ + _signal_checks.__all__ + _signal_noise.__all__ + _signals.__all__
    + _files.__all__
    + _bag_format.__all__ + _bag_write.__all__ + _bag_read.__all__ + _bag_to_log.__all__ + _bags.__all__
    + _follow.__all__
)
