"""The identified model as a whole robot: physically consistent standard parameters that reproduce
an identification, exported as a robot description.
"""

from ._export import *  # noqa: F403
from ._urdf import *  # noqa: F403

__all__ = sorted(name for name in dir() if not name.startswith("_"))
