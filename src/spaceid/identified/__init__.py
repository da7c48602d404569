"""The identified model put to use: the free-floating dynamics that the minimal parameters and
their covariance fix (reduced joint inertia, kinetic energy, forward dynamics, base rate) and what
they do not fix; the system CM from a logged base position, and with it the generalized Jacobian;
and physically consistent standard parameters that reproduce an identification, exported as a
robot description.
"""

from . import _com, _dynamics, _export, _files, _grasp, _payload
from ._com import *  # noqa: F403
from ._dynamics import *  # noqa: F403
from ._export import *  # noqa: F403
from ._files import *  # noqa: F403
from ._grasp import *  # noqa: F403
from ._payload import *  # noqa: F403

__all__ = [*_com.__all__, *_dynamics.__all__, *_export.__all__, *_files.__all__, *_grasp.__all__, *_payload.__all__]
