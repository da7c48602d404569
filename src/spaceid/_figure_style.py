"""The house style of spaceid's figures and the helpers every layer's drawing shares.

Figures are drawn on their own :class:`matplotlib.figure.Figure` with the Agg canvas (no pyplot
state, no GUI), or on the axes or (sub)figure a caller gives, in one style, and written as a
150 dpi PNG only when given a path (atomically). Matplotlib is imported when a figure is drawn,
not with this module: commands that draw none (``spaceid identify``) do not pay its import
(0.3-0.6 s).

The drawing code lives with the records it draws (``spaceid.estimation._plots`` for an
identification, ``spaceid.identified._plots`` for a payload, ``spaceid.studies._figures`` for the
rest), each layer using this module, so that a record's ``.plot()`` needs nothing above its layer.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure, FigureBase

DPI = 150
_STYLE = {
    "font.size": 9,
    "axes.titlesize": 9,
    "figure.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "axes.axisbelow": True,
    "axes.formatter.useoffset": False,  # an offset ("+1.7e2") lands on the panel title
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.3,
    "lines.markersize": 4,
    "errorbar.capsize": 3,
    "legend.frameon": False,
}
# one colour per role, the same in every figure
COLOR_MEASURED, COLOR_MODEL, COLOR_TRUE = "0.15", "tab:red", "tab:green"
COLOR_REFERENCE, COLOR_LIMIT, COLOR_ANCHOR = "0.55", "tab:orange", "tab:blue"


MANY = 40
"""Above this many parameters a figure ranks them instead of giving each a tick (an identification's estimates,
:func:`spaceid.estimation._plots._draw_ranked`; a Monte Carlo study's efficiency,
:func:`spaceid.studies._figures._rmse_crb_ranked`): a per-parameter axis grows with the count (11,175 pixels at
120) and is unreadable."""
LABELLED = 8
"""Parameters named on a ranked figure: the worst this many."""
RANKED_SIZE = (8.0, 6.2)
"""Size [in] of a ranked figure, whatever the number of parameters (1200 x 930 pixels at 150 dpi)."""


def styled(draw):
    """Run a ``_draw_*`` function under the house style (artists take their style when created)."""

    @functools.wraps(draw)
    def wrapper(*args, **kwargs) -> Figure:
        import matplotlib as mpl

        with mpl.rc_context(_STYLE):
            return draw(*args, **kwargs)

    return wrapper


def new_figure(size) -> Figure:
    """An empty constrained-layout figure of ``size`` [in] on an Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def canvas(fig: FigureBase | None, size) -> FigureBase:
    """``fig`` (a caller's figure or subfigure to draw a multi-panel figure into), or a new figure of ``size``."""
    return new_figure(size) if fig is None else fig


def new_axes(ax: Axes | None, size) -> tuple:
    """``(figure, axes)``: the caller's axes ``ax`` and the (sub)figure that holds it, or a new figure of
    ``size`` with one axes."""
    if ax is not None:
        return ax.figure, ax
    fig = new_figure(size)
    return fig, fig.subplots()


def save_figure(fig: FigureBase, path) -> Path:
    """Write ``fig`` (the whole figure that holds it) atomically as a PNG at ``path``; the style again,
    as ticks are made when drawn."""
    import matplotlib as mpl

    root = fig.figure  # a subfigure's figure; a figure's is itself
    with mpl.rc_context(_STYLE), atomic_path(path) as tmp:
        root.savefig(tmp, format="png", dpi=DPI)
    return Path(path)


def finish_figure(fig: FigureBase, path) -> FigureBase:
    """``fig``, written to ``path`` first when one is given (:func:`save_figure`); nothing is written without."""
    if path is not None:
        save_figure(fig, path)
    return fig


def _legend_columns(labels, width: float) -> int:
    """Most legend columns (filled column by column) whose estimated widths fit ``width`` [in]."""
    plain = [re.sub(r"\\[A-Za-z]+|[${}^_]", "", label) for label in labels]  # mathtext renders shorter
    size = [0.55 + 0.058 * len(text) for text in plain]  # handle and gaps + 8 pt characters [in]
    for ncols in range(len(labels), 1, -1):
        rows = -(-len(labels) // ncols)
        if sum(max(size[c * rows : (c + 1) * rows]) for c in range(-(-len(labels) // rows))) <= width - 0.3:
            return ncols
    return 1


def _figure_width(fig: FigureBase) -> float:
    """Width [in] of ``fig``, a figure or a subfigure (its share of its figure's)."""
    if fig.figure is fig:
        return fig.get_figwidth()
    return fig.figure.get_figwidth() * fig.bbox.width / fig.figure.bbox.width


def figure_legend(fig: FigureBase, axes) -> None:
    """One figure legend below the panels, one entry per label from whichever panel has it."""
    entries = {}
    for ax in axes:
        entries.update(zip(*reversed(ax.get_legend_handles_labels())))
    ncols = _legend_columns(list(entries), _figure_width(fig))
    fig.legend(entries.values(), entries.keys(), loc="outside lower center", ncols=ncols)


def tex_name(name: str) -> str:
    """``pi12`` -> ``$\\pi_{12}$`` for axis ticks; other names unchanged."""
    match = re.fullmatch(r"pi(\d+)", name)
    return rf"$\pi_{{{match.group(1)}}}$" if match else name


def tex_unit(unit: str) -> str:
    """``kg m^2`` -> ``kg m$^{2}$``: exponents raised, the rest as written."""
    return re.sub(r"\^\{?(-?\d+)\}?", r"$^{\1}$", unit)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def mark_worst(ax, x, y, names, order, unit: str, corner: str) -> None:
    """Mark the points ``order[:LABELLED]`` (the worst first) and list their names and values in a
    box at ``corner`` ("upper right", ...): labels beside crowded points would overlap."""
    worst = order[:LABELLED]
    ax.plot(x[worst], y[worst], "o", markersize=5, markerfacecolor="none", markeredgecolor=COLOR_MODEL,
            label=f"the worst {len(worst)}")  # fmt: skip
    lines = [f"{tex_name(names[i])}: {y[i]:.3g}{unit}" for i in worst]
    top, right = corner.startswith("upper"), corner.endswith("right")
    ax.text(0.99 if right else 0.01, 0.97 if top else 0.03, "worst\n" + "\n".join(lines), transform=ax.transAxes,
            ha="right" if right else "left", va="top" if top else "bottom", fontsize=7, color=COLOR_MODEL,
            bbox={"boxstyle": "round", "facecolor": "white", "edgecolor": "0.8", "alpha": 0.9})  # fmt: skip
