"""Figures of an identification: its parameter estimates and the singular values of its regressor
(:meth:`Identification.plot`; ``spaceid.studies.plot_parameters`` and ``plot_singular_values``
write them). In the house style of :mod:`spaceid._figure_style`; matplotlib is imported when a
figure is drawn.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .._errors import SpaceidError
from .._figure_style import (COLOR_ANCHOR, COLOR_MEASURED, COLOR_REFERENCE, COLOR_TRUE, new_axes, figure_legend,
                             styled, tex_name, tex_unit)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ._result import Identification


def per_parameter(values, ident: Identification, name: str):
    """``values`` as a float array of shape ``(k,)``, or None; a clear error on a wrong length."""
    if values is None:
        return None
    arr = np.asarray(values, float).reshape(-1)
    if arr.shape != (len(ident.names),):
        raise SpaceidError(
            f"{name}: expected one value per parameter ({len(ident.names)}: {', '.join(ident.names)}), "
            f"got {arr.size}: pass them in the order of the identification's names"
        )
    return arr


def relative_errors(ident: Identification, true):
    """``|estimate - true| / |true|`` and ``std / |true|`` as fractions; NaN where ``true`` is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(true != 0, np.abs(true), np.nan)
        return np.abs(ident.values - true) / scale, ident.std / scale


def _units(ident: Identification) -> tuple | None:
    """The parameters' units (``ident.units``, e.g. ``"kg m^2"``); None for results written without them."""
    units = tuple(ident.units or ())
    if units and len(units) != len(ident.names):
        raise SpaceidError(f"plot_parameters: the result has {len(units)} units for {len(ident.names)} parameters: "
                           "identify again to rebuild it")  # fmt: skip
    return units or None


def _anchored(ident: Identification) -> np.ndarray:
    """Mask of the parameters the identification fixed (``settings["anchors"]``) instead of estimating."""
    names = {a["name"] for a in ident.settings.get("anchors", ())}
    return np.array([n in names for n in ident.names], bool)


def _percent_errors(ident: Identification, true):
    """``(y, half, label)``: the signed error ``(estimate - true) / |true|`` and ``2 std / |true|`` [%];
    without the truth, 0 and ``2 std / |estimate|`` [%] (the truth's interval about the estimate)."""
    if true is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            half = 200 * ident.std / np.where(ident.values != 0, np.abs(ident.values), np.nan)
        return np.zeros(len(ident.names)), half, r"about the estimate, $(\pi_i - \hat\pi_i)\,/\,|\hat\pi_i|$ [%]"
    rel, rel_std = relative_errors(ident, true)
    signed = 100 * np.sign(ident.values - true) * rel
    return signed, 200 * rel_std, r"signed error $(\hat\pi_i - \pi_i)\,/\,|\pi_i|$ [%]"


@styled
def draw_parameters(ident: Identification, true=None, reference=None, reference_label="paper", ax=None) -> Figure:
    """The figure of :func:`spaceid.studies.plot_parameters`, on ``ax`` when given (the legend then on
    ``ax``), else on a new figure (the legend below the axes)."""
    true = per_parameter(true, ident, "`true`")
    reference = per_parameter(reference, ident, "`reference`")
    units = _units(ident)
    per_tick = units is not None and len(set(units)) > 1  # else one unit for the axis label
    anchored = _anchored(ident)
    y, half, ylabel = _percent_errors(ident, true)
    k = len(ident.names)
    x = np.arange(k)
    dx = 0.15 if reference is not None else 0.0
    own = ax is None
    fig, ax = new_axes(ax, (max(6.0, 0.6 * k + 2.5), 3.9 if per_tick else 3.6))
    ax.axhline(0, color=COLOR_TRUE if true is not None else COLOR_REFERENCE, linewidth=1.0,
               label="true value (zero error)" if true is not None else None)  # fmt: skip
    free = ~anchored
    ax.errorbar(x[free] - dx, y[free], yerr=half[free], fmt="o", color=COLOR_MEASURED,
                label=r"estimate $\pm 2\sigma$" + ("" if true is not None else " (truth unknown)"))  # fmt: skip
    if anchored.any():
        ax.plot(x[anchored] - dx, y[anchored], "s", markersize=7, markerfacecolor="none", markeredgecolor=COLOR_ANCHOR,
                markeredgewidth=1.5, label="anchored: known, not estimated")  # fmt: skip
    if reference is not None:  # magnitudes: both signs, beside ours
        ax.plot(np.repeat(x + dx, 2), np.stack([reference, -reference], axis=1).ravel(), "D", markersize=4,
                markerfacecolor="none", color=COLOR_REFERENCE, label=rf"{reference_label}: $\pm$|error|")  # fmt: skip
    reach = np.concatenate([np.abs(y) + np.nan_to_num(half), [] if reference is None else np.abs(reference)])
    reach = reach[np.isfinite(reach)]
    if reach.size and reach.max() > 0:
        ax.set_ylim(-1.15 * reach.max(), 1.15 * reach.max())  # symmetric: over- and underestimates alike
    ax.set_ylabel(ylabel)
    labels = [tex_name(n) for n in ident.names]
    if per_tick:
        labels = [f"{name}\n[{tex_unit(u)}]" for name, u in zip(labels, units)]
    ax.set_xticks(x, labels)
    common = f" (all in {tex_unit(units[0])})" if units else ""
    ax.set_xlabel("minimal parameter" + (" [unit]" if per_tick else common))
    for tick, fixed in zip(ax.get_xticklabels(), anchored):
        if fixed:
            tick.set_color(COLOR_ANCHOR)
    worst = f", max |error| {np.nanmax(np.abs(y[free])):.2g} %" if true is not None and free.any() else ""
    ax.set_title(f"{ident.estimator.upper()} estimates of the {k} minimal parameters\n"
                 f"N = {ident.n_samples} samples, cond = {ident.condition_number:.4g}{worst}", loc="left")  # fmt: skip
    if own:
        figure_legend(fig, [ax])
    else:
        ax.legend()
    return fig


@styled
def draw_singular_values(ident: Identification, ax=None) -> Figure:
    """The figure of :func:`spaceid.studies.plot_singular_values`, on ``ax`` when given."""
    s = np.asarray(ident.singular_values, float)
    if s.size == 0:
        raise SpaceidError("plot_singular_values: the result has no singular values: identify again (spaceid identify)")
    i = np.arange(1, s.size + 1)
    fig, ax = new_axes(ax, (5.0, 3.2))
    ax.semilogy(i, s / s[0], "o-", color=COLOR_MEASURED)
    ax.set_xticks(i)
    ax.set_xlabel("index $i$ (decreasing order)")
    ax.set_ylabel(r"$\sigma_i / \sigma_1$ of $\hat Y$ [-]")
    ax.set_title(rf"Singular values of the stacked regressor $\hat Y$ (N = {ident.n_samples}):" "\n"
                 rf"cond$(\hat Y) = \sigma_1/\sigma_k$ = {ident.condition_number:.4g}")  # fmt: skip
    return fig
