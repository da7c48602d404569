"""Internal interface of :mod:`spaceid.models` for the later stages (:mod:`spaceid.dynamics`,
:mod:`spaceid.identified`): stable within the package, not public API.

Other subpackages take these from here, never from this subpackage's private modules: a change to
a name below is a change to an interface between subpackages, to be made with its callers.
``tests/test_layout.py`` enforces that other subpackages import only through ``spaceid.models``
(its ``__all__``) or this module (its ``__all__``).

``inertia_matrix``
    A body's inertia about its origin as a 3x3 matrix from its ten standard parameters.
``symbol_suffix``
    A body or joint name as the suffix of a parameter or symbol name.
``add_to_body``
    A model with inertial parameters added to one body, unchecked (a trial or zero payload too).
"""

from ._model import add_to_body, inertia_matrix, symbol_suffix

__all__ = ["inertia_matrix", "symbol_suffix", "add_to_body"]
