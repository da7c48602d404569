"""Internal interface of :mod:`spaceid.estimation` for the later stages (:mod:`spaceid.identified`):
stable within the package, not public API.

The payload and grasp estimators of :mod:`spaceid.identified` solve momentum equations of their own
with the machinery of this stage. They take it from here, never from this subpackage's private
modules: a change to a name below is a change to an interface between subpackages, to be made with
its callers. ``tests/test_layout.py`` enforces that other subpackages import only through
``spaceid.estimation`` (its ``__all__``) or this module (its ``__all__``).

``Equations``
    The stacked momentum equations of a log, ``Phi_n(x) [theta; 1] = 0``, sample by sample.
``drift_basis_at``
    The drift basis of a log, or integrated over a longer history and taken at the log's stamps.
``check_drift_kinds``
    The drift kinds of a ``--drift`` value, checked and in canonical order.
``check_excitation``
    The triangular factor of the column-scaled equations and the scaled condition number; raises
    when the parameters are not excited.
``correlation_length``
    Samples over which the errors of differentiated rates are correlated (0: not differentiated).
``window_spans``
    Every differentiator window recorded in a log's differentiation record.
``newey_west_covariance``, ``larger_of``
    The Bartlett-weighted (Newey-West) sandwich covariance from the residuals; the larger of two covariances in
    every direction of parameter space.
``residual_checks``, ``noise_model_warning``, ``SIGNIFICANCE``, ``CONTRADICTED``
    The tests of whitened residuals against the noise model (chi-square, Ljung-Box), what a rejected one means in
    words, the tests' significance level, and how a covariance taken from the residuals then is described.
``ratios_of_columns``, ``undetermined``, ``widened``, ``WIDENED``, ``undetermined_warning``, ``signal_levels``
    The directions of parameter space a log does not determine (the regressor's noise as large as its signal) of
    equations of another shape, who leads them, the covariance widened along them, how its description and the
    warning say so; the noise levels they are judged by.
``differentiated_series``, ``at_given_levels``, ``propagated_covariance``
    The raw angle series behind differentiated rates, those series with their raw levels at least the ones given,
    and the covariance of an estimate with their noise carried through the differentiating filters.
``enough_samples_for_knots``, ``automatic_knot_spacing``
    Whether a log's stamps are dense enough for the ``angles`` estimator's spline knots, and the knot spacing
    of a spatial ``angles`` fit when none is given.
``draw_parameters``, ``draw_singular_values``
    The figures of an identification (``Identification.plot``), which :mod:`spaceid.studies`
    saves (``plot_parameters``, ``plot_singular_values``).
``diagnostic_rows``
    The diagnostics of an identification worth a line, each flagged when it is a warning: shared by
    its notebook view and the HTML report.
``per_parameter``, ``relative_errors``
    Values given per parameter checked against an identification, and its relative errors and
    their standard deviations against a truth: shared by its figure and the report's tables.
"""

from ._angle_path import automatic_knot_spacing, enough_samples_for_knots
from ._determined import WIDENED, ratios_of_columns, signal_levels, undetermined, undetermined_warning, widened
from ._differentiated import at_given_levels, differentiated_series, propagated_covariance
from ._drift import check_drift_kinds
from ._equations import Equations, drift_basis_at
from ._html import diagnostic_rows
from ._identify import check_excitation
from ._plots import draw_parameters, draw_singular_values, per_parameter, relative_errors
from ._uncertainty import (CONTRADICTED, SIGNIFICANCE, correlation_length, larger_of, newey_west_covariance,
                           noise_model_warning, residual_checks, window_spans)

__all__ = [
    "Equations",
    "drift_basis_at",
    "check_drift_kinds",
    "check_excitation",
    "correlation_length",
    "window_spans",
    "newey_west_covariance",
    "larger_of",
    "residual_checks",
    "noise_model_warning",
    "SIGNIFICANCE",
    "CONTRADICTED",
    "ratios_of_columns",
    "undetermined",
    "widened",
    "WIDENED",
    "undetermined_warning",
    "signal_levels",
    "differentiated_series",
    "at_given_levels",
    "propagated_covariance",
    "enough_samples_for_knots",
    "automatic_knot_spacing",
    "draw_parameters",
    "draw_singular_values",
    "diagnostic_rows",
    "per_parameter",
    "relative_errors",
]
