"""spaceid: identify free-floating space manipulators from angular-momentum conservation."""

from ._errors import SpaceidError
from .data import Log
from .models import Model, load_model

__all__ = ["SpaceidError", "Model", "load_model", "Log"]
__version__ = "0.1.0"
