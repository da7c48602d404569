"""The figure of a payload estimate (:meth:`PayloadEstimate.plot`; ``spaceid.studies.plot_payload``
writes it): a panel per parameter, the estimate with one standard error, against the truth when
known. In the house style of :mod:`spaceid._figure_style`; matplotlib is imported when drawn.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._figure_style import COLOR_MODEL, COLOR_TRUE, canvas, figure_legend, styled, tex_name, tex_unit

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_UNITS = {"m": "kg", "cx": "m", "cy": "m", "cz": "m"}
"""Units of the payload's parameters; the rest (the inertia's) kg m^2."""


def _rows(estimate, true=None) -> list:
    """The rows of :func:`draw_payload` of a :class:`~spaceid.identified.PayloadEstimate`: per parameter
    ``name``, ``estimate``, ``std``, ``true`` (None: unknown) and ``z`` (``(estimate - true) / std``, or None);
    ``true`` a mapping of names or a sequence in ``estimate.names`` order."""
    if true is None:
        known = [None] * len(estimate.names)
    elif isinstance(true, dict):
        known = [true.get(n) for n in estimate.names]
    else:
        known = list(true)
    rows = []
    for name, value, std, t in zip(estimate.names, estimate.values, estimate.std, known):
        t = None if t is None else float(t)
        z = float((value - t) / std) if t is not None and std > 0 else None
        rows.append({"name": name, "estimate": float(value), "std": float(std), "true": t, "z": z})
    return rows


@styled
def draw_payload(rows, link: str, fig=None, truth_label: str = "truth") -> Figure:
    """The figure of :func:`spaceid.studies.plot_payload`, into ``fig`` (a figure or subfigure) when given;
    ``truth_label`` names the true values in the legend."""
    fig = canvas(fig, (2.0 * len(rows) + 0.6, 3.0))
    axes = fig.subplots(1, len(rows), squeeze=False)[0]
    truth = any(row.get("true") is not None for row in rows)
    for ax, row in zip(axes, rows):
        ax.errorbar([0], [row["estimate"]], yerr=[row["std"]], fmt="o", color=COLOR_MODEL, label="estimate, 1 std")
        if row.get("true") is not None:
            ax.axhline(row["true"], color=COLOR_TRUE, label=truth_label)
        ax.set_xticks([])
        ax.set_xlim(-1, 1)
        ax.set_title(f"{tex_name(row['name'])} [{tex_unit(_UNITS.get(row['name'], 'kg m^2'))}]", loc="left")
        if row.get("z") is not None:
            ax.set_title(f"z = {row['z']:+.2f}", loc="right", fontsize=8, color="0.35")
    figure_legend(fig, axes)
    against = "estimate against truth" if truth else "estimate with one standard error"
    fig.suptitle(f"The payload held by {link}: {against} (CoM and inertia in {link}'s frame)")
    return fig
