"""Digital twin of the Cepheus air-bearing emulator: torque-driven plant, controllers, sensors and
effects.
"""

from . import _twin
from ._twin import *  # noqa: F403

__all__ = _twin.__all__
