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
``MARGIN``, ``SPREAD``, ``CLARABEL_TOLERANCES``
    The physical margin of a program's solution, the spread of a degenerate reference body, the
    solver's tolerances.
``triangle``, ``cone``, ``conic_solution``, ``solved_tightly``, ``Unknowns``, ``duplication``, ``physical_rows``
    Convex programs stated to Clarabel in its own form: the entries of a symmetric matrix in its
    semidefinite cone, a cone, a program's solution at given settings, and at the tolerances (once
    more with the cones whole when the solver fails); a program's unknowns in named blocks, ``vec X``
    from the upper triangles of the whitened pseudo-inertias, and the rows that keep them physical.
"""

from ._model import add_to_body, inertia_matrix, symbol_suffix, zero_rotations
from ._conic import (CLARABEL_TOLERANCES, Unknowns, cone, conic_solution, duplication, physical_rows, solved_tightly,
                     triangle)
from ._pseudo import (MARGIN, SPREAD, inertial_from_pseudo, pseudo_inertia, pseudo_whitening, reference_pseudo,
                      theta_slots, whitened_physical, with_theta)

__all__ = ["inertia_matrix", "symbol_suffix", "zero_rotations", "add_to_body", "pseudo_inertia", "inertial_from_pseudo",
           "reference_pseudo", "theta_slots", "with_theta", "pseudo_whitening", "whitened_physical", "MARGIN",
           "SPREAD", "CLARABEL_TOLERANCES", "triangle", "cone", "conic_solution", "solved_tightly",
           "Unknowns", "duplication", "physical_rows"]
