"""Figures of a validation, a trajectory, its tracking, a Monte Carlo study and a capture; those of an
identification (:mod:`spaceid.estimation._plots`) and of a payload (:mod:`spaceid.identified._plots`)
are drawn in their own layers, which these ``plot_*`` functions call.

Every ``plot_*`` returns the :class:`matplotlib.figure.Figure` it drew: on its own figure with the
Agg canvas (no pyplot state, no GUI), or on the axes (``ax``, one-panel figures) or into the
figure or subfigure (``fig``, several panels) it is given, in one style
(:mod:`spaceid._figure_style`), and writes it atomically as a 150 dpi PNG only when given a
``path``. Figures read result objects only; the records draw themselves the same way
(``Identification.plot``, ``Validation.plot``, ``MonteCarloResult.plot``, ``PayloadEstimate.plot``).
Matplotlib is imported when a figure is drawn, not with this module: commands that draw none
(``spaceid identify``) do not pay its import (0.3-0.6 s).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from .._figure_style import (COLOR_ANCHOR, COLOR_LIMIT, COLOR_MEASURED, COLOR_MODEL, COLOR_REFERENCE, COLOR_TRUE,
                             LABELLED, MANY, RANKED_SIZE, canvas, figure_legend, finish_figure, mark_worst, rms,
                             styled, tex_name)
from ..data import Log
from ..estimation import Identification
from ..estimation.internal import draw_parameters, draw_singular_values
from ._validate import attitude_error_angle, predicted_label, validation_title

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_montecarlo", "plot_parameters", "plot_singular_values", "plot_tracking", "plot_trajectory",
           "plot_validation", "plot_capture_monitor", "plot_payload", "plot_attitude_errors"]


# --- validation (the paper's Fig. 6) -----------------------------------------------------------



def _check_same_motion(measured: Log, predicted: Log) -> None:
    """Raise unless the logs have the same joints, planar flag and time stamps."""
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


def _base_signals(measured: Log, predicted: Log) -> list:
    """The base signals the validation figure compares, one column each: ``(title, symbol,
    unit, measured, predicted, residual, residual axis label)``, arrays of shape (n,).

    Base angular velocity (planar ``w_z``; spatial x, y, z in base axes) and attitude (planar:
    the yaw; spatial: the angle turned from the measured start, the residual the attitude
    error angle, as the difference of two such angles is not the error)."""
    axes = [2] if measured.planar else [0, 1, 2]
    rates = [("base angular velocity" + ("" if measured.planar else f", {'xyz'[i]}"), rf"$\omega_{{0{'xyz'[i]}}}$",
              "rad/s", measured.base_w[:, i], predicted.base_w[:, i], predicted.base_w[:, i] - measured.base_w[:, i],
              "pred. $-$ meas.") for i in axes]  # fmt: skip
    if measured.planar:
        yaw_m, yaw_p = measured.base_yaw, predicted.base_yaw
        return rates + [("base attitude: yaw", r"$\theta_0$", "rad", yaw_m, yaw_p, yaw_p - yaw_m,
                         "pred. $-$ meas.")]
    start = measured.base_quat[0]
    turned = [attitude_error_angle(start, log.base_quat) for log in (measured, predicted)]
    error = attitude_error_angle(measured.base_quat, predicted.base_quat)
    return rates + [("base attitude: rotation angle", r"angle from start $\phi_0$", "rad", *turned, error,
                     "error angle")]


@styled
def _draw_validation(measured: Log, predicted: Log, title: str | None = None, fig=None) -> Figure:
    """The figure of :func:`plot_validation`, into ``fig`` when given."""
    _check_same_motion(measured, predicted)
    signals = _base_signals(measured, predicted)
    marker = {"marker": "o", "linestyle": "none", "markersize": 3} if measured.n_samples <= 120 else {}
    fig = canvas(fig, (7.2 if measured.planar else 11.0, 4.6))
    axes = fig.subplots(2, len(signals), sharex=True, gridspec_kw={"height_ratios": [2, 1]}, squeeze=False)
    for c, (panel_title, symbol, unit, y_meas, y_pred, residual, residual_label) in enumerate(signals):
        top, bottom = axes[0, c], axes[1, c]
        top.plot(measured.t, y_meas, color=COLOR_MEASURED, label="measured", **marker)
        top.plot(predicted.t, y_pred, color=COLOR_MODEL, linestyle="--", label=predicted_label(predicted))
        top.set_title(panel_title, loc="left")
        top.set_ylabel(f"{symbol} [{unit}]")
        top.tick_params(labelbottom=False)
        bottom.axhline(0, color=COLOR_REFERENCE, linewidth=0.8)
        bottom.plot(measured.t, residual, color=COLOR_MODEL, linewidth=1.0, label="residual")
        bottom.set_title(f"residual, RMS {rms(residual):.2g} {unit}", loc="left", fontsize=8, color="0.35")
        bottom.set_ylabel(f"{residual_label} [{unit}]")
        bottom.set_xlabel("time $t$ [s]")
    figure_legend(fig, list(axes.flat))
    fig.suptitle(title or validation_title(predicted))
    return fig


def plot_validation(measured: Log, predicted: Log, path=None, *, title=None, fig=None) -> Figure:
    """Measured base motion vs the identified model's prediction (the paper's Fig. 6).

    What the model predicts, one column each: the base angular velocity in base axes (planar
    ``w_z``; spatial x, y, z) and the base attitude (planar: the yaw; spatial: the angle turned
    from the measured start), measured against predicted, with the residual below (spatial
    attitude: the attitude error angle) and its RMS. The joint motion is not shown: it drives
    the prediction, so it matches by construction.

    Parameters
    ----------
    measured, predicted : Log
        Same joints, planar flag and time stamps (``predicted`` is typically
        ``spaceid.studies.predict`` on ``measured``'s joint motion).
    path : path-like, optional
        Output PNG; none: nothing is written.
    title : str, optional
        Figure title; default names what is compared.
    fig : Figure or SubFigure, optional
        Draw into it (two rows of panels) instead of a new figure.

    Returns
    -------
    Figure
        The figure drawn (``fig`` when given). :meth:`spaceid.studies.Validation.plot` draws the same.
    """
    return finish_figure(_draw_validation(measured, predicted, title, fig), path)


# --- parameters and singular values (drawn by spaceid.estimation._plots) --------------------------


@deprecated_alias(old="ident", new="result")
def plot_parameters(result: Identification, path=None, *, true=None, reference=None, reference_label="paper",
                    ax=None) -> Figure:
    """Estimates with 2-sigma error bars on one relative axis (parameters of different units).

    With the truth, the signed relative error ``(estimate - true) / |true|`` [%] with bars
    ``2 std / |true|``; without it (a real recording), the bars ``2 std / |estimate|`` [%] about
    the estimate. Parameters the identification fixed (``settings["anchors"]``, e.g. a
    reaction wheel's rotor inertia) are marked apart; ``result.units``, when the result has them,
    label the ticks (or the axis, when they are all the same). Linear axis, symmetric about
    zero; a zero true value gives no point.

    Parameters
    ----------
    result : Identification
    path : path-like, optional
        Output PNG; none: nothing is written.
    true : array_like of shape (k,), optional
        True parameter values.
    reference : array_like of shape (k,), optional
        Reference relative errors **in percent**, magnitudes (e.g. the paper's Table 3): drawn
        at plus and minus beside ours.
    reference_label : str
        Legend name of ``reference``.
    ax : Axes, optional
        Draw on it (its legend on it too) instead of a new figure.

    Returns
    -------
    Figure
        The figure drawn (the one that holds ``ax`` when given). ``ident.plot()`` draws the same.
    """
    return finish_figure(draw_parameters(result, true, reference, reference_label, ax), path)


@deprecated_alias(old="ident", new="result")
def plot_singular_values(result: Identification, path=None, *, ax=None) -> Figure:
    """Singular values of the stacked regressor relative to the largest, on a log scale.

    Relative, as the regressor's columns carry the units of momentum over those of their
    parameters; the smallest is ``1 / cond``, the condition number in the title.

    Parameters
    ----------
    ident : Identification
    path : path-like, optional
        Output PNG; none: nothing is written.
    ax : Axes, optional
        Draw on it instead of a new figure.

    Returns
    -------
    Figure
        The figure drawn. ``ident.plot(kind="singular_values")`` draws the same.
    """
    return finish_figure(draw_singular_values(result, ax), path)


# --- trajectory ---------------------------------------------------------------------------------


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


@styled
def _draw_trajectory(t, q, qd, qdd, joints, limits=None, samples=None, title=None, fig=None) -> Figure:
    """The figure of :func:`plot_trajectory`, into ``fig`` when given."""
    t = np.asarray(t, float)
    rows = [("q", "rad", q), ("qd", "rad/s", qd), ("qdd", "rad/s$^2$", qdd)]
    rows = [(key, unit, np.asarray(y, float).reshape(t.size, -1)) for key, unit, y in rows]
    nj = len(joints)
    if any(y.shape[1] != nj for *_, y in rows):
        raise SpaceidError(f"plot_trajectory: q, qd, qdd need one column per joint ({nj}: {', '.join(joints)})")
    limits = dict(limits or {})
    if set(limits) - {"q", "qd", "qdd"}:
        raise SpaceidError(f"plot_trajectory: unknown limit kinds {sorted(set(limits) - {'q', 'qd', 'qdd'})}: "
                           "use 'q', 'qd', 'qdd'")  # fmt: skip
    bands = {key: _limit_band(value, nj, key) for key, value in limits.items() if value is not None}
    ts = None if samples is None else np.asarray(samples, float)
    symbols = {"q": "q", "qd": r"\dot q", "qdd": r"\ddot q"}
    fig = canvas(fig, (3.4 * nj + 0.6, 6.7))
    axes = fig.subplots(3, nj, sharex=True, squeeze=False)
    for r, (key, unit, y) in enumerate(rows):
        for j in range(nj):
            ax = axes[r, j]
            ax.plot(t, y[:, j], color=COLOR_MEASURED, label="trajectory")
            if key in bands:
                for bound in bands[key][j][np.isfinite(bands[key][j])]:
                    ax.axhline(bound, color=COLOR_LIMIT, linestyle=":", linewidth=1.2, label="limit")
            if ts is not None:
                ax.plot(ts, np.interp(ts, t, y[:, j]), "o", color=COLOR_MODEL, markersize=3,
                        label=f"sample instants (N = {ts.size})")  # fmt: skip
            ax.set_ylabel(rf"${symbols[key]}_{{{j + 1}}}$ [{unit}]")
    for j, name in enumerate(joints):
        axes[0, j].set_title(name)
        axes[-1, j].set_xlabel("time $t$ [s]")
    figure_legend(fig, axes.flat)
    default = (f"Exciting trajectory over {t[-1] - t[0]:.3g} s" + (": " if nj > 1 else ":\n")  # narrow: two lines
               + "angle, rate and acceleration of each joint")
    fig.suptitle(title or default)
    return fig


@deprecated_alias(old="samples", new="times")
def plot_trajectory(t, q, qd, qdd, joints, path=None, *, limits=None, times=None, title=None, fig=None) -> Figure:
    """The exciting trajectory: position, rate and acceleration of each joint.

    Parameters
    ----------
    t : array_like of shape (n,)
        Fine time grid [s].
    q, qd, qdd : array_like of shape (n, n_joints)
        Joint positions [rad], rates [rad/s] and accelerations [rad/s^2] on ``t``.
    joints : sequence of str
        Joint names (columns).
    path : path-like, optional
        Output PNG; none: nothing is written.
    limits : dict, optional
        ``{"q": ..., "qd": ..., "qdd": ...}`` (any subset), each a magnitude ``|x| <= limit``
        (scalar or one per joint) or ``(n_joints, 2)`` lower/upper pairs; NaN means none.
    times : array_like of shape (N,), optional
        Sample instants [s] used for identification, marked on every curve.
    title : str, optional
        Figure title; default names the duration and the rows.
    fig : Figure or SubFigure, optional
        Draw into it (three rows of panels) instead of a new figure.

    Returns
    -------
    Figure
    """
    return finish_figure(_draw_trajectory(t, q, qd, qdd, joints, limits, times, title, fig), path)


# --- Monte Carlo --------------------------------------------------------------------------------

# one colour per estimator in the Monte Carlo figures (the ML estimate takes the model's colour)
_ESTIMATOR_COLOURS = {"ml": COLOR_MODEL, "wls": "tab:blue", "iv": "tab:purple", "tls": "tab:brown", "ols": "0.45"}


def _number(v: float) -> str:
    """``1e-4`` rather than ``0.0001``: compact for a title."""
    if v == 0 or 0.01 <= abs(v) < 1000:
        return f"{v:.3g}"
    return np.format_float_scientific(v, precision=2, trim="-", exp_digits=1)


def _noise_text(settings: dict) -> str:
    """The simulated noise levels of a Monte Carlo study (std of white Gaussian noise), with units."""
    n = {key: _number(value) for key, value in settings["noise"].items() if key != "source"}
    if settings.get("angles_only"):
        return f"noise std: angle {n['angle']} rad, attitude {n['attitude']} rad; rates differentiated from them"
    return (f"noise std: angle {n['angle']} rad, rate {n['rate']} rad/s, base rate {n['base_rate']} rad/s, "
            f"attitude {n['attitude']} rad")  # fmt: skip


def _monte_carlo_ratios(result, estimator) -> tuple:
    """``(ratio, half, label)`` of ``estimator``: RMSE / CRB of every parameter ``(k,)``, the half-width of its
    Monte Carlo uncertainty (over R runs an RMSE has a relative standard error of about ``1 / sqrt(2 R)``;
    +-2 of it) and the legend label naming R."""
    ratio = np.asarray(result.stats[estimator]["rmse_crb"], float)
    runs_ok = result.summary(estimator)["runs_ok"]
    return ratio, 2 * ratio / np.sqrt(2 * max(runs_ok, 1)), f"{estimator.upper()} (R = {runs_ok} runs)"


SE_LABEL = r"$\pm 2$ s.e. of a Monte Carlo RMSE, $\approx 2/\sqrt{2R}$ relative"
"""Legend label of the Monte Carlo uncertainty of the RMSE / CRB ratios."""


def _efficiency_axis(ax, top: float, crb_label: str) -> None:
    """The line of an efficient estimator, the y scale (log when a ratio ``top`` beyond 10 would flatten the
    others) and the y label of an RMSE / CRB panel."""
    ax.axhline(1.0, color=COLOR_MEASURED, linewidth=0.9, label=f"RMSE = {crb_label} (efficient)")
    if top > 10:
        ax.set_yscale("log")  # a badly biased estimator would flatten the others
    else:
        ax.set_ylim(0, 1.08 * top)
    ax.set_ylabel(f"RMSE / {crb_label} [-]")


def _rmse_crb_bars(ax, result, colours, crb_label) -> None:
    """RMSE / CRB of every parameter and estimator as bars, each with its Monte Carlo uncertainty
    (:func:`_monte_carlo_ratios`); above :data:`~spaceid._figure_style.MANY` parameters ranked instead
    (:func:`_rmse_crb_ranked`)."""
    if len(result.names) > MANY:
        return _rmse_crb_ranked(ax, result, colours, crb_label)
    ests, k = result.estimators, len(result.names)
    x = np.arange(k)
    width = 0.8 / len(ests)
    xs, ratios, errors = [], [], []
    for j, (e, colour) in enumerate(zip(ests, colours)):
        ratio, half, label = _monte_carlo_ratios(result, e)
        xs.append(x + (j - (len(ests) - 1) / 2) * width)
        ratios.append(ratio)
        errors.append(half)
        ax.bar(xs[-1], ratio, width, color=colour, alpha=0.8, label=label)
    xs, ratios, errors = (np.concatenate(a) for a in (xs, ratios, errors))
    ax.errorbar(xs, ratios, yerr=errors, fmt="none", ecolor="black", elinewidth=0.9, capsize=2, label=SE_LABEL)
    _efficiency_axis(ax, np.nanmax(np.append(ratios + errors, 1.0)), crb_label)
    ax.set_xticks(x, [tex_name(n) for n in result.names])
    ax.set_xlabel("minimal parameter")
    ax.set_title(f"Efficiency: RMSE over the runs / {crb_label} std of each parameter", loc="left")


def _rmse_crb_ranked(ax, result, colours, crb_label) -> None:
    """RMSE / CRB of many parameters, ranked by the first estimator's (largest first; parameters without a
    ratio last): every estimator's at the same parameter's rank, with its Monte Carlo uncertainty, and the
    first estimator's worst :data:`~spaceid._figure_style.LABELLED` named. A bar and a tick per parameter
    would make the figure a foot wide per 25 parameters (the servicer's 496: 37,575 pixels, 9 s to draw)."""
    ests, k = result.estimators, len(result.names)
    first = _monte_carlo_ratios(result, ests[0])[0]
    order = np.argsort(-np.nan_to_num(first, nan=-np.inf), kind="stable")
    rank = np.arange(1, k + 1)
    tops = [1.0]
    for e, colour in zip(ests, colours):
        ratio, half, label = _monte_carlo_ratios(result, e)
        ratio, half = ratio[order], half[order]
        ax.plot(rank, ratio, "o", markersize=2.5, color=colour, alpha=0.8, label=label)
        ax.errorbar(rank, ratio, yerr=half, fmt="none", ecolor=colour, elinewidth=0.5, capsize=0, alpha=0.5,
                    label=SE_LABEL)  # (one legend entry: the figure's legend keeps the first)
        tops.append(np.nanmax(np.append(ratio + half, 1.0)))
    _efficiency_axis(ax, max(tops), crb_label)
    mark_worst(ax, rank, first[order], [result.names[i] for i in order], np.arange(min(LABELLED, k)), "",
               "upper right")
    ax.set_xlabel(f"rank of the {k} minimal parameters by {ests[0].upper()}'s RMSE / {crb_label}, largest first")
    ax.set_title(f"Efficiency: RMSE over the runs / {crb_label} std of each parameter, ranked", loc="left")


@styled
def _draw_montecarlo(result, max_panels: int = 12, fig=None) -> Figure:
    """The figure of :func:`plot_montecarlo`, into ``fig`` when given."""
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
    colours = [_ESTIMATOR_COLOURS.get(e, COLOR_MEASURED) for e in ests]
    crb_label = "white-noise-equivalent CRB" if result.settings.get("angles_only") else "CRB"
    width = 0.5 * k + 2.5 if k <= MANY else RANKED_SIZE[0]  # a bar per parameter, or ranked (_rmse_crb_bars)
    fig = canvas(fig, (max(7.0, 2.1 * ncols + 0.6, width), 1.9 * nrows + 3.9))  # 7 in: the title
    axes = fig.subplot_mosaic(mosaic, height_ratios=[1] * nrows + [1.35])
    for p, i in enumerate(shown):
        ax = axes[f"p{p}"]
        data = [(result.estimates[e][:, i] - true[i]) / scale[i] for e in ests]
        data = [d[np.isfinite(d)] for d in data]
        if np.isfinite(band[i]):
            ax.axhspan(-band[i], band[i], color=COLOR_TRUE, alpha=0.15, linewidth=0,
                       label=rf"{crb_label} $\pm 2\sigma$")
        ax.axhline(0, color=COLOR_REFERENCE, linewidth=0.8)
        boxes = ax.boxplot(data, widths=0.6, patch_artist=True, flierprops={"markersize": 2, "alpha": 0.5},
                           medianprops={"color": "black", "linewidth": 1.0})  # fmt: skip
        for patch, colour in zip(boxes["boxes"], colours):
            patch.set(facecolor=colour, alpha=0.45, edgecolor=colour)
        ax.set_xticks(np.arange(1, len(ests) + 1), [e.upper() for e in ests])
        ax.set_title(tex_name(names[i]), loc="left")
        if p % ncols == 0:
            ax.set_ylabel("signed rel. error [%]")
    _rmse_crb_bars(axes["bars"], result, colours, crb_label)
    figure_legend(fig, [axes["p0"], axes["bars"]])
    s = result.settings
    fig.suptitle(f"Monte Carlo study: {s['runs']} runs, N = {s['n_samples']} samples, seed {s['seed']}\n"
                 f"{_noise_text(s)}\nboxes: errors in % of |true| (quartiles, whiskers 1.5 IQR)"
                 + (f", {len(shown)} of {k} parameters" if len(shown) < k else ""), x=0.02, ha="left")  # fmt: skip
    return fig


def plot_montecarlo(result, path=None, *, max_panels: int = 12, fig=None) -> Figure:
    """Monte Carlo errors: per parameter the relative errors of each estimator (box plots) in
    the Cramer-Rao band, and RMSE / CRB of every parameter and estimator (bars, with their Monte
    Carlo uncertainty, about ``1 / sqrt(2 R)`` relative over R successful runs); the noise
    levels in the title.

    Parameters
    ----------
    result : spaceid.studies.MonteCarloResult
    path : path-like, optional
        Output PNG; none: nothing is written.
    max_panels : int
        Parameters with a box-plot panel at most; beyond, those with the largest relative RMSE
        of the first estimator (the bars show all).
    fig : Figure or SubFigure, optional
        Draw into it instead of a new figure.

    Returns
    -------
    Figure
        The figure drawn. ``result.plot()`` draws the same.
    """
    return finish_figure(_draw_montecarlo(result, max_panels, fig), path)


# --- tracking: the excitation as designed and as executed ---------------------------------------


@styled
def _draw_tracking(t, designed, executed, joints, samples=None, title=None, fig=None) -> Figure:
    """The figure of :func:`plot_tracking`, into ``fig`` when given."""
    t = np.asarray(t, float)
    nj = len(joints)
    designed, executed = (np.asarray(y, float).reshape(t.size, -1) for y in (designed, executed))
    if designed.shape[1] != nj or executed.shape[1] != nj:
        raise SpaceidError(f"plot_tracking: designed and executed need one column per joint "
                           f"({nj}: {', '.join(joints)})")
    error = 1e3 * (executed - designed)  # [mrad]
    fig = canvas(fig, (3.4 * nj + 0.6, 4.9))
    axes = fig.subplots(2, nj, sharex=True, squeeze=False, height_ratios=[1.6, 1])
    for j, name in enumerate(joints):
        top, bottom = axes[0, j], axes[1, j]
        top.plot(t, designed[:, j], color=COLOR_REFERENCE, linewidth=2.2, label="designed (commanded)")
        top.plot(t, executed[:, j], color=COLOR_MEASURED, linestyle="--", label="executed (encoders)")
        bottom.axhline(0, color=COLOR_REFERENCE, linewidth=0.8)
        bottom.plot(t, error[:, j], color=COLOR_MODEL, label="executed - designed")
        if samples is not None:
            ts = np.asarray(samples, float)
            top.plot(ts, np.interp(ts, t, executed[:, j]), "o", color=COLOR_MODEL, markersize=3,
                     label=f"identification samples (N = {ts.size})")  # fmt: skip
        top.set_title(name, loc="left")
        bottom.set_title(f"RMS {rms(error[:, j]):.3g} mrad", loc="right", fontsize=8, color="0.35")
        top.set_ylabel(f"$q_{{{j + 1}}}$ [rad]")
        bottom.set_ylabel(rf"$\Delta q_{{{j + 1}}}$ [mrad]")
        bottom.set_xlabel("time since the start of the excitation $t$ [s]")
    figure_legend(fig, axes.flat)
    fig.suptitle(title or "Tracking: the arm's designed (commanded) and executed motion")
    return fig


@deprecated_alias(old="samples", new="times")
def plot_tracking(t, designed, executed, joints, path=None, *, times=None, title=None, fig=None) -> Figure:
    """The exciting trajectory as designed against the motion executed, joint by joint.

    Top row: the designed angle of each joint and the executed one; bottom row: their
    difference [mrad] with its RMS. A loosely tracked trajectory is a less exciting one: the
    regressor is built from the executed motion.

    Parameters
    ----------
    t : array_like of shape (n,)
        Time since the start of the excitation [s].
    designed, executed : array_like of shape (n, n_joints)
        Designed (commanded) and executed (e.g. encoder) joint angles [rad] at ``t``.
    joints : sequence of str
        Joint names (columns).
    path : path-like, optional
        Output PNG; none: nothing is written.
    times : array_like of shape (N,), optional
        Sample instants identification uses [s], marked on the executed motion.
    title : str, optional
        Figure title; default names what is compared.
    fig : Figure or SubFigure, optional
        Draw into it (two rows of panels) instead of a new figure.

    Returns
    -------
    Figure
    """
    return finish_figure(_draw_tracking(t, designed, executed, joints, times, title, fig), path)


@styled
def _draw_attitude_errors(t, errors: dict, title=None, fig=None) -> Figure:
    """The figure of :func:`plot_attitude_errors`, into ``fig`` when given."""
    fig = canvas(fig, (7.5, 3.6))
    ax = fig.subplots()
    colours = [COLOR_MODEL, COLOR_REFERENCE, COLOR_MEASURED, COLOR_TRUE]
    for (label, error), colour in zip(errors.items(), colours):
        error = np.asarray(error, float)
        ax.semilogy(t, np.maximum(error, 1e-12), color=colour, label=f"{label} (at the end {error[-1]:.3g} rad)")
    ax.set_xlabel("time since the start of the held-out motion $t$ [s]")
    ax.set_ylabel("attitude error angle [rad]")
    ax.grid(True, which="both", alpha=0.3)
    figure_legend(fig, [ax])
    fig.suptitle(title or "Predicted base attitude against the measured one")
    return fig


def plot_attitude_errors(t, errors: dict, path=None, *, title=None, fig=None) -> Figure:
    """Attitude error angles of predictions over a motion, one curve per model, log scale.

    Parameters
    ----------
    t : array_like of shape (n,)
        Time [s].
    errors : dict of str to array_like of shape (n,)
        Label (e.g. "identified", "CAD prior") to the error angle [rad]
        (:func:`spaceid.studies.attitude_error_angle`) at ``t``.
    path : path-like, optional
        Output PNG; none: nothing is written.
    title : str, optional
    fig : Figure or SubFigure, optional

    Returns
    -------
    Figure
    """
    return finish_figure(_draw_attitude_errors(np.asarray(t, float), errors, title, fig), path)


# --- capture: change detection and the payload ---------------------------------------------------


@styled
def _draw_capture_monitor(log: Log, scores, joints, fig=None) -> Figure:
    """The figure of :func:`plot_capture_monitor`, into ``fig`` when given."""
    grasp = scores.grasp_time
    t = log.t - grasp
    arm = list(joints)
    fig = canvas(fig, (7.2, 5.2))
    top, bottom = fig.subplots(2, 1, sharex=True)
    for j, name in enumerate(arm):
        top.plot(t, log.q[:, log.joints.index(name)], color=(COLOR_MEASURED, COLOR_ANCHOR)[j % 2],
                 label=f"{name} (encoders)")
    bottom.plot(t, log.base_w[:, -1], color=COLOR_MEASURED, label="base yaw rate (motion capture)")
    detected = scores.detected_change_time
    for ax in (top, bottom):
        ax.axvline(0.0, color=COLOR_TRUE, linewidth=2.0, label="grasp (twin's truth)")
        if detected is not None:
            ax.axvline(detected - grasp, color=COLOR_MODEL, linestyle="--", label="detected change")
            ax.axvline(scores.detected_at - grasp, color=COLOR_LIMIT, linestyle=":",
                       label="alarm (threshold crossed)")  # fmt: skip
    top.set_ylabel("joint angle $q$ [rad]")
    bottom.set_ylabel(r"base yaw rate $\omega_z$ [rad/s]")
    bottom.set_xlabel("time since the grasp $t - t_g$ [s]")
    entries = {}
    for ax in (top, bottom):
        entries.update(zip(*reversed(ax.get_legend_handles_labels())))
    fig.legend(entries.values(), entries.keys(), loc="outside lower center", ncols=3)
    found = "no change detected" if detected is None else (
        f"change at {scores.change_time_error:+.3g} s from the grasp "
        f"({scores.change_time_error_samples:+g} samples), alarm at "
        f"{scores.detected_at - grasp:+.3g} s")
    fig.suptitle(f"Change detection over the servicing recording (held-out motion, grasp, post-capture "
                 f"excitation)\n{found}")
    return fig


def plot_capture_monitor(log: Log, scores, path=None, *, joints, fig=None) -> Figure:
    """The servicing recording with the grasp, the detected change and the alarm marked.

    Parameters
    ----------
    log : Log
        The recording (held-out motion, grasp, post-capture excitation).
    scores : ServicingScores
        Its ``grasp_time``, ``detected_change_time``, ``detected_at``, ``change_time_error`` and
        ``change_time_error_samples`` (None: no change found), times on ``log``'s clock.
    path : path-like, optional
        Output PNG; none: nothing is written.
    joints : sequence of str
        The joints whose angles are drawn (the arm's).
    fig : Figure or SubFigure, optional
        Draw into it (two panels) instead of a new figure.

    Returns
    -------
    Figure
    """
    return finish_figure(_draw_capture_monitor(log, scores, joints, fig), path)


def plot_payload(rows, path=None, *, link: str, fig=None, truth_label: str = "truth") -> Figure:
    """The payload's parameters, estimate with one standard error against the truth, a panel each.

    Parameters
    ----------
    rows : list of dict
        Per parameter ``name``, ``estimate``, ``std`` [kg, m, kg m^2], ``true`` and ``z`` (None: no
        truth).
    path : path-like, optional
        Output PNG; none: nothing is written.
    link : str
        The link that holds the payload (the frame of the CoM and inertia).
    fig : Figure or SubFigure, optional
        Draw into it instead of a new figure.
    truth_label : str
        The true values' name in the legend.

    Returns
    -------
    Figure
        The figure drawn. :meth:`spaceid.identified.PayloadEstimate.plot` draws the same.
    """
    from ..identified.internal import draw_payload

    return finish_figure(draw_payload(rows, link, fig, truth_label), path)
