"""Figures of an identification: its parameter estimates and the singular values of its regressor
(:meth:`Identification.plot`; ``spaceid.studies.plot_parameters`` and ``plot_singular_values``
write them). In the house style of :mod:`spaceid._figure_style`; matplotlib is imported when a
figure is drawn.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .._errors import SpaceidError
from .._figure_style import (COLOR_ANCHOR, COLOR_MEASURED, COLOR_REFERENCE, COLOR_TRUE, MANY, RANKED_SIZE,
                             figure_legend, mark_worst, new_axes, new_figure, styled, tex_name, tex_unit)

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
    ``ax``), else on a new figure (the legend below the axes). Above :data:`~spaceid._figure_style.MANY`
    parameters, the ranked figure of :func:`_draw_ranked` (``reference`` is not drawn there)."""
    true = per_parameter(true, ident, "`true`")
    reference = per_parameter(reference, ident, "`reference`")
    if len(ident.names) > MANY:
        return _draw_ranked(ident, true, ax)
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
    ax.semilogy(i, s / s[0], "o-", color=COLOR_MEASURED, markersize=4 if s.size <= MANY else 2)
    if s.size <= MANY:
        ax.set_xticks(i)
    else:  # a tick per index would overlap (the servicer's 496): matplotlib's integer ticks
        from matplotlib.ticker import MaxNLocator

        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("index $i$ (decreasing order)")
    ax.set_ylabel(r"$\sigma_i / \sigma_1$ of $\hat Y$ [-]")
    ax.set_title(rf"Singular values of the stacked regressor $\hat Y$ (N = {ident.n_samples}):" "\n"
                 rf"cond$(\hat Y) = \sigma_1/\sigma_k$ = {ident.condition_number:.4g}")  # fmt: skip
    return fig


def _draw_ranked(ident: Identification, true, ax) -> Figure:
    """Many parameters ranked, at a fixed size: with ``true``, their z-scores ``(estimate - true) /
    std`` sorted (the 2-sigma band marked) over their errors as the momentum they cause (a fraction of
    the momentum scale, :class:`~spaceid.estimation.MomentumScale`), sorted; without, the standard
    deviations so scaled (relative to the estimate for results without a scale). The worst
    :data:`~spaceid._figure_style.LABELLED` are named."""
    free = np.flatnonzero(~_anchored(ident) & (ident.std > 0))
    names = list(ident.names)
    panels = 2 if true is not None else 1
    if ax is not None:
        fig, axes = ax.figure, [ax]
        panels = 1
    else:
        fig = new_figure(RANKED_SIZE if panels == 2 else (RANKED_SIZE[0], RANKED_SIZE[1] / 2 + 0.4))
        axes = list(np.atleast_1d(fig.subplots(panels, 1)))
    k = len(names)
    title = f"{ident.estimator.upper()} estimates of the {k} minimal parameters (N = {ident.n_samples} samples, " \
            f"cond = {ident.condition_number:.4g}), ranked"
    if true is not None:
        z = (ident.values[free] - true[free]) / ident.std[free]
        order = np.argsort(z)
        rank = np.arange(1, len(z) + 1)
        top = axes[0]
        top.axhspan(-2, 2, color=COLOR_TRUE, alpha=0.12, label=r"$|z| \leq 2$")
        top.plot(rank, z[order], "o", color=COLOR_MEASURED, markersize=3,
                 label=r"$z = (\hat\pi_i - \pi_i)\,/\,\sigma_i$, sorted")  # fmt: skip
        worst = np.argsort(-np.abs(z[order]))
        mark_worst(top, rank, z[order], [names[i] for i in free[order]], worst, "", "lower right")
        within = np.mean(np.abs(z) <= 2)
        top.set_ylabel("z-score [-]")
        top.set_xlabel(f"rank of the {len(z)} estimated parameters (anchored ones left out)")
        top.set_title(f"{title}\n{100 * within:.0f} % within 2 sigma, max |z| {np.abs(z).max():.3g}", loc="left")
        top.legend(loc="upper left")
    if ax is not None and true is not None:
        return fig
    bottom = axes[-1]
    values, label = _ranked_sizes(ident, true, free)
    order = np.argsort(-values)
    rank = np.arange(1, len(values) + 1)
    bottom.semilogy(rank, values[order], "o", color=COLOR_MEASURED, markersize=3, label=label)
    mark_worst(bottom, rank, values[order], [names[i] for i in free[order]], np.arange(len(values)), " %",
                "upper right")
    bottom.set_xlabel(f"rank of the {len(values)} estimated parameters, largest first")
    bottom.set_ylabel(label.split(":")[0])
    if true is None:
        bottom.set_title(title, loc="left")
    bottom.legend(loc="lower left")
    return fig


def _ranked_sizes(ident: Identification, true, free) -> tuple:
    """``(values, label)`` of the lower ranked panel: errors (with ``true``) or 2-sigma half-widths,
    as the momentum they cause over the log (percent of the momentum scale), or for results without a
    scale relative to the estimate."""
    size = np.abs(ident.values - true) if true is not None else 2 * ident.std
    what = "|error|" if true is not None else r"2$\sigma$"
    if ident.scale is not None:
        label = f"{what} as momentum [% of the scale]: " r"$e_i\,r_i / H$, sorted"
        return 100 * ident.scale.scaled(size)[free], label
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = 100 * size[free] / np.abs(ident.values[free])
    return np.where(np.isfinite(rel), rel, np.nan), f"{what} relative to the estimate [%]: sorted"
