"""The identified model as a whole robot: physically consistent standard parameters that reproduce
an identification, exported as a robot description.
"""

from ._export import *  # noqa: F403
from ._files import *  # noqa: F403

# one line a module above; the public names are those they export
__all__ = sorted(name for name in dir() if not name.startswith("_"))
