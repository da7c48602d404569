"""Joint motions: Fourier-plus-quintic trajectories, optimal excitation design, free-floating
simulation of a prescribed joint motion.
"""

from . import _trajectory, _simulate, _criteria, _design, _design_payload
from ._trajectory import *  # noqa: F403
from ._simulate import *  # noqa: F403
from ._criteria import *  # noqa: F403
from ._design import *  # noqa: F403
from ._design_payload import *  # noqa: F403

__all__ = _trajectory.__all__ + _simulate.__all__ + _criteria.__all__ + _design.__all__ + _design_payload.__all__
