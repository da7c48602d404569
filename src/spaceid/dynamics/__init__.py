"""Free-floating kinematics and angular momentum: the direct rigid-body momentum, the momentum
regressor and its minimal parameter set, the base rate that momentum conservation implies, the system centre of mass,
the momentum's analytic derivative in the state.
"""

from . import _kinematics, _momentum, _regressor, _base_rate, _com, _momentum_jacobian
from ._kinematics import *  # noqa: F403
from ._momentum import *  # noqa: F403
from ._regressor import *  # noqa: F403
from ._base_rate import *  # noqa: F403
from ._com import *  # noqa: F403
from ._momentum_jacobian import *  # noqa: F403

__all__ = (_kinematics.__all__ + _momentum.__all__ + _regressor.__all__ + _base_rate.__all__ + _com.__all__
           + _momentum_jacobian.__all__)
