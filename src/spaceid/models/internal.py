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
``zero_rotations``
    The orientation of every body's frame in base axes at the zero configuration.
``add_to_body``
    A model with inertial parameters added to one body, unchecked (a trial or zero payload too).
``pseudo_inertia``, ``inertial_from_pseudo``, ``reference_pseudo``
    A body's pseudo-inertia from its ten standard parameters and back; a reference (prior) body's,
    made positive definite (a plate or a rod spread a little).
``theta_slots``, ``with_theta``
    The standard parameters ``theta`` of a model (declared zeros left out) and a model with others.
``pseudo_whitening``, ``whitened_physical``
    The maps of the whitened pseudo-inertias ``X_b`` (a reference at the identity) to ``theta`` and to
    the declared zeros; whether a ``theta`` is physical in them.
``MARGIN``, ``SPREAD``, ``CLARABEL_TOLERANCES``, ``solved_tightly``, ``solver_panicked``
    The physical margin of a program's solution, the spread of a degenerate reference body, the
    solver's tolerances, a program solved at them, and whether an exception is the solver's panic.
"""

from ._model import add_to_body, inertia_matrix, symbol_suffix, zero_rotations
from ._pseudo import (CLARABEL_TOLERANCES, MARGIN, SPREAD, inertial_from_pseudo, pseudo_inertia, pseudo_whitening,
                      reference_pseudo, solved_tightly, solver_panicked, theta_slots, whitened_physical, with_theta)

__all__ = ["inertia_matrix", "symbol_suffix", "zero_rotations", "add_to_body", "pseudo_inertia", "inertial_from_pseudo",
           "reference_pseudo", "theta_slots", "with_theta", "pseudo_whitening", "whitened_physical", "MARGIN",
           "SPREAD", "CLARABEL_TOLERANCES", "solved_tightly", "solver_panicked"]
