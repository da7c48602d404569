"""Robot description of a free-floating system: bodies, joints, base; URDF and YAML loading; built-
in presets.
"""

from . import _model
from ._model import *  # noqa: F403

__all__ = _model.__all__
