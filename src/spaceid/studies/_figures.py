"""Figures of an identification, a validation, a trajectory and a Monte Carlo study.

Every figure is drawn on its own :class:`matplotlib.figure.Figure` with the Agg canvas (no
pyplot state, no GUI), in one style, and written atomically as a 150 dpi PNG. Figures read
result objects only.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .._atomic import atomic_path
from .._errors import SpaceidError
from ..estimation import Identification
from ..data import Log

from ._tables import _per_param, _relative_errors
__all__ = ["plot_validation", "plot_parameters", "plot_singular_values", "plot_trajectory", "plot_montecarlo"]

DPI = 150
_STYLE = {
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "axes.axisbelow": True,
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
_MEASURED, _MODEL, _TRUE, _REF, _LIMIT = "0.15", "tab:red", "tab:green", "0.55", "tab:orange"


@contextlib.contextmanager
def _figure(path, size):
    """Yield a styled Agg figure of ``size`` [in]; on exit save it atomically as a PNG at ``path``."""
    with mpl.rc_context(_STYLE):
        fig = Figure(figsize=size, layout="constrained")
        FigureCanvasAgg(fig)
        yield fig
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=DPI)


def _tex_name(name: str) -> str:
    """``pi12`` -> ``$\\pi_{12}$`` for axis ticks; other names unchanged."""
    match = re.fullmatch(r"pi(\d+)", name)
    return rf"$\pi_{{{match.group(1)}}}$" if match else name


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def plot_validation(measured: Log, predicted: Log, path, *, title=None) -> Path:
    """Measured motion vs the identified model's prediction (the paper's Fig. 6).

    One row per joint (angle [rad], rate [rad/s]) and a last row with the base angular
    velocity in base axes (planar: ``w_z``; spatial: x, y, z). Every panel prints the RMS
    of ``predicted - measured``.

    Parameters
    ----------
    measured, predicted : Log
        Same joints, planar flag and time stamps (``predicted`` is typically
        ``spaceid.studies.predict`` on ``measured``'s joint motion).
    path : path-like
        Output PNG.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        ``path``.
    """
    if tuple(measured.joints) != tuple(predicted.joints) or measured.planar != predicted.planar:
        raise SpaceidError(
            f"plot_validation: the logs differ in joints ({list(measured.joints)} vs {list(predicted.joints)}) "
            f"or planar flag ({measured.planar} vs {predicted.planar}): predict with the measured log's joint motion"
        )
    if measured.t.shape != predicted.t.shape or not np.allclose(measured.t, predicted.t, rtol=0, atol=1e-9):
        raise SpaceidError(
            f"plot_validation: the logs have different time stamps ({measured.n_samples} vs {predicted.n_samples} "
            "samples): predict at the measured time stamps"
        )
    nj = len(measured.joints)
    axes_w = [2] if measured.planar else [0, 1, 2]
    # rows: (label, unit, measured, predicted, panel title); 6 mosaic columns fit 2 and 3 panels
    panels = []
    for j, name in enumerate(measured.joints):
        panels.append([(f"$q_{{{j + 1}}}$", "rad", measured.q[:, j], predicted.q[:, j], f"{name}: angle"),
                       (rf"$\dot q_{{{j + 1}}}$", "rad/s", measured.qd[:, j], predicted.qd[:, j], f"{name}: rate")])
    panels.append([(rf"$\omega_{{0{'xyz'[i]}}}$", "rad/s", measured.base_w[:, i], predicted.base_w[:, i],
                    "base angular velocity" if measured.planar else f"base, {'xyz'[i]}") for i in axes_w])
    mosaic = [[f"{r}.{c}" for c in range(len(row)) for _ in range(6 // len(row))] for r, row in enumerate(panels)]
    marker = {"marker": "o", "linestyle": "none", "markersize": 3} if measured.n_samples <= 120 else {}
    with _figure(path, (7.2 if measured.planar else 8.4, 1.9 * (nj + 1) + 0.5)) as fig:
        axes = fig.subplot_mosaic(mosaic, sharex=True)
        for r, row in enumerate(panels):
            for c, (label, unit, y_meas, y_pred, panel_title) in enumerate(row):
                ax = axes[f"{r}.{c}"]
                ax.plot(measured.t, y_meas, color=_MEASURED, label="measured", **marker)
                ax.plot(predicted.t, y_pred, color=_MODEL, linestyle="--", label="identified model")
                ax.set_title(panel_title, loc="left")
                ax.set_title(f"RMS {_rms(y_pred - y_meas):.3g} {unit}", loc="right", fontsize=8, color="0.35")
                ax.set_ylabel(f"{label} [{unit}]")
                if r == len(panels) - 1:
                    ax.set_xlabel("time $t$ [s]")
                else:
                    ax.tick_params(labelbottom=False)
        handles, labels = axes["0.0"].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncols=2)
        if title:
            fig.suptitle(title)
    return Path(path)


def plot_parameters(ident: Identification, path, *, true=None, reference=None, reference_label="paper") -> Path:
    """Estimates with 2-sigma error bars and, given the truth, their relative errors.

    Parameters
    ----------
    ident : Identification
    path : path-like
        Output PNG.
    true : array_like of shape (k,), optional
        True parameter values: adds them to the estimates panel and adds a panel of relative
        errors ``|estimate - true| / |true|`` [%] with error bars of ``std / |true|`` (1 sigma),
        on a log scale when they span more than a decade.
    reference : array_like of shape (k,), optional
        Reference relative errors **in percent** (e.g. the paper's Table 3), drawn beside ours.
    reference_label : str
        Legend name of ``reference``.

    Returns
    -------
    Path
    """
    true = _per_param(true, ident, "true")
    reference = _per_param(reference, ident, "reference")
    k = len(ident.names)
    x = np.arange(k)
    with_errors = true is not None or reference is not None
    with _figure(path, (max(6.0, 0.55 * k + 2.5), 5.6 if with_errors else 3.2)) as fig:
        axes = fig.subplots(2 if with_errors else 1, 1, sharex=True, squeeze=False)[:, 0]
        ax = axes[0]
        ax.errorbar(x, ident.values, yerr=2 * ident.std, fmt="o", color=_MEASURED, label=r"estimate $\pm 2\sigma$")
        if true is not None:
            ax.plot(x, true, "_", color=_TRUE, markersize=14, markeredgewidth=2, label="true")
        shown = np.concatenate([ident.values, [] if true is None else true])
        if np.all(shown > 0) and shown.max() / shown.min() > 20:
            ax.set_yscale("log")  # magnitudes spanning decades: small parameters stay visible
        ax.set_ylabel(r"parameter value $\pi_i$ [SI]")
        ax.set_title(f"{ident.estimator.upper()} estimates, N = {ident.n_samples}, cond = {ident.condition_number:.4g}", loc="left")
        ax.legend(loc="best")
        if with_errors:
            ax = axes[1]
            shown = []
            if true is not None:
                rel, rel_std = (100 * e for e in _relative_errors(ident, true))
                ax.errorbar(x - 0.12 * (reference is not None), rel, yerr=rel_std, fmt="o", color=_MEASURED,
                            label=r"this run $\pm 1\sigma$")
                shown += [rel, rel + rel_std]
            if reference is not None:
                ax.plot(x + 0.12 * (true is not None), reference, "D", color=_REF, label=reference_label)
                shown.append(reference)
            shown = np.concatenate(shown)
            shown = shown[np.isfinite(shown) & (shown > 0)]
            if shown.size and shown.max() / shown.min() > 10:
                ax.set_yscale("log")
                ax.set_ylim(shown.min() / 3, shown.max() * 3)  # bars reaching zero run off the bottom
            else:
                ax.set_ylim(bottom=0)
            ax.set_ylabel("relative error [%]")
            ax.legend(loc="best")
        axes[-1].set_xticks(x, [_tex_name(n) for n in ident.names])
        axes[-1].set_xlabel("parameter")
    return Path(path)


def plot_singular_values(ident: Identification, path) -> Path:
    """Singular values of the stacked regressor on a log scale, condition number in the title.

    Returns
    -------
    Path
    """
    s = np.asarray(ident.singular_values, float)
    if s.size == 0:
        raise SpaceidError("plot_singular_values: the result has no singular values: identify again (spaceid identify)")
    with _figure(path, (5.0, 3.2)) as fig:
        ax = fig.subplots()
        ax.semilogy(np.arange(1, s.size + 1), s, "o-", color=_MEASURED)
        ax.set_xticks(np.arange(1, s.size + 1))
        ax.set_xlabel("index $i$")
        ax.set_ylabel(r"singular value $\sigma_i$ of $\hat Y$")
        ax.set_title(rf"Stacked regressor: cond$(\hat Y) = \sigma_1/\sigma_k$ = {ident.condition_number:.4g}")
    return Path(path)


def _limit_band(value, n_joints: int, key: str) -> np.ndarray:
    """Limits of one kind as ``(n_joints, 2)`` (lower, upper): a magnitude (scalar or per joint) or pairs."""
    arr = np.asarray(value, float)
    if arr.ndim <= 1:
        mag = np.broadcast_to(np.abs(arr), (n_joints,)) if arr.size in (1, n_joints) else None
        if mag is not None:
            return np.stack([-mag, mag], axis=1)
    elif arr.shape == (n_joints, 2):
        return arr
    raise SpaceidError(
        f"limits['{key}']: expected a magnitude, {n_joints} magnitudes or ({n_joints}, 2) lower/upper pairs, "
        f"got shape {arr.shape}"
    )


def plot_trajectory(t, q, qd, qdd, joints, path, *, limits=None, samples=None) -> Path:
    """The exciting trajectory: position, rate and acceleration of each joint.

    Parameters
    ----------
    t : array_like of shape (n,)
        Fine time grid [s].
    q, qd, qdd : array_like of shape (n, n_joints)
        Joint positions [rad], rates [rad/s] and accelerations [rad/s^2] on ``t``.
    joints : sequence of str
        Joint names (columns).
    path : path-like
        Output PNG.
    limits : dict, optional
        ``{"q": ..., "qd": ..., "qdd": ...}`` (any subset), each a magnitude ``|x| <= limit``
        (scalar or one per joint) or ``(n_joints, 2)`` lower/upper pairs; NaN means none.
    samples : array_like of shape (N,), optional
        Sample instants [s] used for identification, marked on every curve.

    Returns
    -------
    Path
    """
    t = np.asarray(t, float)
    rows = [("q", "rad", q), ("qd", "rad/s", qd), ("qdd", "rad/s$^2$", qdd)]
    rows = [(key, unit, np.asarray(y, float).reshape(t.size, -1)) for key, unit, y in rows]
    nj = len(joints)
    if any(y.shape[1] != nj for *_, y in rows):
        raise SpaceidError(f"plot_trajectory: q, qd, qdd need one column per joint ({nj}: {', '.join(joints)})")
    limits = dict(limits or {})
    if set(limits) - {"q", "qd", "qdd"}:
        raise SpaceidError(f"plot_trajectory: unknown limit kinds {sorted(set(limits) - {'q', 'qd', 'qdd'})}: use 'q', 'qd', 'qdd'")
    bands = {key: _limit_band(value, nj, key) for key, value in limits.items() if value is not None}
    ts = None if samples is None else np.asarray(samples, float)
    symbols = {"q": "q", "qd": r"\dot q", "qdd": r"\ddot q"}
    with _figure(path, (3.4 * nj + 0.6, 6.4)) as fig:
        axes = fig.subplots(3, nj, sharex=True, squeeze=False)
        for r, (key, unit, y) in enumerate(rows):
            for j in range(nj):
                ax = axes[r, j]
                ax.plot(t, y[:, j], color=_MEASURED, label="trajectory")
                if key in bands:
                    for bound in bands[key][j][np.isfinite(bands[key][j])]:
                        ax.axhline(bound, color=_LIMIT, linestyle=":", linewidth=1.2, label="limit")
                if ts is not None:
                    ax.plot(ts, np.interp(ts, t, y[:, j]), "o", color=_MODEL, markersize=3, label=f"samples (N = {ts.size})")
                ax.set_ylabel(rf"${symbols[key]}_{{{j + 1}}}$ [{unit}]")
        for j, name in enumerate(joints):
            axes[0, j].set_title(name)
            axes[-1, j].set_xlabel("time $t$ [s]")
        legend = {}  # one entry per label, from whichever panel has it
        for ax in axes.flat:
            legend.update(zip(*reversed(ax.get_legend_handles_labels())))
        fig.legend(legend.values(), legend.keys(), loc="outside lower center", ncols=len(legend))
    return Path(path)


# one colour per estimator in the Monte Carlo figures (the ML estimate takes the model's colour)
_ESTIMATOR_COLOURS = {"ml": _MODEL, "wls": "tab:blue", "iv": "tab:purple", "tls": "tab:brown", "ols": "0.45"}


def plot_montecarlo(result, path, *, max_panels: int = 12) -> Path:
    """Monte Carlo errors: per parameter the relative errors of each estimator (box plots) in
    the Cramer-Rao band, and RMSE / CRB of every parameter and estimator (bars).

    Parameters
    ----------
    result : spaceid.studies.MonteCarloResult
    path : path-like
        Output PNG.
    max_panels : int
        Parameters with a box-plot panel at most; beyond, those with the largest relative RMSE
        of the first estimator (the bars show all).

    Returns
    -------
    Path
    """
    names, true, ests = result.names, np.asarray(result.true, float), result.estimators
    k = len(names)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(true != 0, np.abs(true), np.nan) / 100  # errors in percent of |true|
        band = 2 * result.crb_std / scale
    shown = np.arange(k)
    if k > max_panels:
        worst = np.nan_to_num(result.stats[ests[0]]["relative_rmse"], nan=-1.0)
        shown = np.sort(np.argsort(-worst, kind="stable")[:max_panels])
    ncols = min(4, len(shown))
    nrows = -(-len(shown) // ncols)
    mosaic = [[f"p{r * ncols + c}" if r * ncols + c < len(shown) else "." for c in range(ncols)] for r in range(nrows)]
    mosaic.append(["bars"] * ncols)
    colours = [_ESTIMATOR_COLOURS.get(e, _MEASURED) for e in ests]
    crb_label = "white-noise-equivalent CRB" if result.settings.get("angles_only") else "CRB"
    with _figure(path, (max(2.1 * ncols + 0.6, 0.5 * k + 2.5), 1.9 * nrows + 2.9)) as fig:
        axes = fig.subplot_mosaic(mosaic, height_ratios=[1] * nrows + [1.25])
        for p, i in enumerate(shown):
            ax = axes[f"p{p}"]
            data = [(result.estimates[e][:, i] - true[i]) / scale[i] for e in ests]
            data = [d[np.isfinite(d)] for d in data]
            if np.isfinite(band[i]):
                ax.axhspan(-band[i], band[i], color=_TRUE, alpha=0.15, linewidth=0, label=rf"{crb_label} $\pm 2\sigma$")
            ax.axhline(0, color=_REF, linewidth=0.8)
            boxes = ax.boxplot(data, widths=0.6, patch_artist=True, flierprops={"markersize": 2, "alpha": 0.5},
                               medianprops={"color": "black", "linewidth": 1.0})
            for patch, colour in zip(boxes["boxes"], colours):
                patch.set(facecolor=colour, alpha=0.45, edgecolor=colour)
            ax.set_xticks(np.arange(1, len(ests) + 1), [e.upper() for e in ests])
            ax.set_title(_tex_name(names[i]), loc="left")
            if p % ncols == 0:
                ax.set_ylabel("rel. error [%]")
        ax = axes["bars"]
        x = np.arange(k)
        width = 0.8 / len(ests)
        ratios = []
        for j, (e, colour) in enumerate(zip(ests, colours)):
            ratio = result.stats[e]["rmse_crb"]
            ax.bar(x + (j - (len(ests) - 1) / 2) * width, ratio, width, color=colour, alpha=0.8, label=e.upper())
            ratios.append(ratio)
        ax.axhline(1.0, color=_MEASURED, linewidth=0.8)
        ax.axhline(1.2, color=_LIMIT, linestyle=":", linewidth=1.2, label="1.2 (target)")
        ratios = np.concatenate(ratios)
        ratios = ratios[np.isfinite(ratios) & (ratios > 0)]
        if ratios.size and ratios.max() > 10:
            ax.set_yscale("log")  # a badly biased estimator would flatten the others
        else:
            ax.set_ylim(0, 1.35 * max(1.2, ratios.max() if ratios.size else 1.2))  # room for the legend
        ax.set_xticks(x, [_tex_name(n) for n in names])
        ax.set_ylabel(f"RMSE / {crb_label}")
        ax.legend(loc="upper left", ncols=len(ests) + 1)
        handles, labels = axes["p0"].get_legend_handles_labels()
        if handles:
            fig.legend(handles, labels, loc="outside upper right")
        s = result.settings
        fig.suptitle(f"Monte Carlo: {s['runs']} runs, N = {s['n_samples']}, seed {s['seed']}"
                     + (", angles only" if s.get("angles_only") else "")
                     + (f" ({len(shown)} of {k} parameters in boxes)" if len(shown) < k else "")
                     + "; boxes: quartiles, whiskers 1.5 IQR", x=0.02, ha="left")
    return Path(path)


# --- tables and the Markdown report ------------------------------------------------------------


