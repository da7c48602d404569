"""The interactive (plotly) figures of the HTML reports: an identification's parameters and singular
values, a validation's measured and predicted base motion with its residuals, a Monte Carlo
study's errors and efficiency, and a monitor's statistic, events and parameter changes. The static
figures (:mod:`spaceid.studies._figures`) show the same for print; these zoom and hover, and read
at hundreds of parameters (hover names each point; zoom spreads the ticks).

Every figure is Plotly's plain dict (:func:`_column`, Plotly's documented fast path): none imports
Plotly's graph objects, which took 0.2 to 0.3 s of a first page.
"""

from __future__ import annotations

import functools
import json

import numpy as np

from ..data import Log
from ..estimation import Identification
from ._figures import _base_signals, _check_same_motion
from ._validate import predicted_label
from ._html_page import ANCHOR, LIMIT, MEASURED, MODEL, REFERENCE, TRUE, downsample, thinning_note

__all__ = ["parameter_figure", "singular_value_figure", "validation_figure", "montecarlo_figures", "monitor_figures"]

_FONT = {"family": "system-ui, Helvetica, Arial, sans-serif", "size": 12}
_HOVER_DEFINITION = 140  # characters of a parameter's definition shown on hover
_X_AXIS = {"showline": True, "linecolor": "#999", "mirror": False, "zeroline": False}
_Y_AXIS = {"showline": True, "linecolor": "#999", "zeroline": False, "exponentformat": "e"}


def _house(title: str, height: int) -> dict:
    """The house layout but its template: white, light grid, legend above the plot, the title on the left."""
    return {"font": _FONT, "height": height, "hovermode": "closest",
            "title": {"text": title, "x": 0.01, "xanchor": "left", "font": {"size": 14, "color": "#222"}},
            "legend": {"orientation": "h", "yanchor": "bottom", "y": 1.02, "x": 0, "xanchor": "left"},
            "margin": {"l": 70, "r": 20, "t": 95, "b": 60}}  # fmt: skip


@functools.cache
def _white_template() -> str:
    """Plotly's ``plotly_white`` template, the JSON text of the file Plotly ships it in (through
    ``plotly.io.templates`` it imports Plotly's graph objects: 0.08 s of a first ``identify``'s page)."""
    from importlib.resources import files

    return (files("plotly") / "package_data" / "templates" / "plotly_white.json").read_text("utf-8")


def _plain_layout(title: str, height: int) -> dict:
    """The house layout (:func:`_house`, template ``plotly_white``) of a figure written as Plotly's plain dict."""
    return {"template": json.loads(_white_template()), **_house(title, height)}


def _column(panels, xaxis: dict, title: str, height: int) -> dict:
    """A figure as Plotly's plain dict, a column of panels sharing their x axis (``xaxis``, under the
    last), in the house layout: Plotly's documented fast path, written unvalidated by :meth:`Page.figure`
    (as graph objects, building, validating and copying the two figures took half of the servicer's
    identification page: 0.22 s of CPU in a fresh process, 0.11 s as dicts).

    Parameters
    ----------
    panels : sequence of (list of dict, list of dict, dict)
        From the top, each panel's traces, its shapes (spanning its width) and its y axis.
    """
    n = len(panels)
    layout = {**_plain_layout(title, height), "shapes": []}
    if n > 1:  # plotly.js lays out the panels: a gap of 0.06 of the figure's height (ygap: of a panel and its gap)
        layout["grid"] = {"rows": n, "columns": 1, "pattern": "independent", "ygap": 0.06 * n / 1.06}
    data = []
    for i, (traces, shapes, yaxis) in enumerate(panels, start=1):
        key = "" if i == 1 else str(i)
        data += [{**t, "xaxis": f"x{key}", "yaxis": f"y{key}"} for t in traces]
        layout["shapes"] += [{**s, "xref": f"x{key} domain", "x0": 0, "x1": 1, "yref": f"y{key}"} for s in shapes]
        layout[f"xaxis{key}"] = {**_X_AXIS, **(xaxis if i == n else {"matches": f"x{n}", "showticklabels": False})}
        layout[f"yaxis{key}"] = {**_Y_AXIS, **yaxis}
    return {"data": data, "layout": layout}


def _hover_texts(result: Identification, true) -> list:
    """Per parameter: its name, unit, estimate, std, truth and (shortened) definition, for hovering."""
    units = list(result.units or [""] * len(result.names))
    texts = []
    for i, (name, d) in enumerate(zip(result.names, result.definitions)):
        d = d if len(d) <= _HOVER_DEFINITION else d[:_HOVER_DEFINITION] + "..."
        truth = "" if true is None else f"<br>true {true[i]:.6g}"
        texts.append(f"<b>{name}</b> [{units[i]}]<br>estimate {result.values[i]:.6g} +/- {result.std[i]:.3g}"
                     f"{truth}<br>= {d}")
    return texts


def _anchored(result: Identification) -> np.ndarray:
    names = {a["name"] for a in result.settings.get("anchors", ())}
    return np.array([n in names for n in result.names], bool)


def _sizes(result: Identification, x) -> tuple:
    """``x`` (errors or stds of the parameters) as the momentum they cause [% H], or relative to the
    values [%] for a result without a momentum scale; and the axis label's unit."""
    if result.scale is not None:
        return 100 * result.scale.scaled(x), f"% of H = {result.scale.momentum:.3g} N m s"
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100 * np.asarray(x, float) / np.abs(result.values), "% of |estimate|"


def parameter_figure(result: Identification, true=None):
    """Every parameter's estimate with its 2-sigma bar: with the truth, the z-score ``(estimate - true)
    / std`` (the 2-sigma band shaded) over the error as the momentum it causes, with bars; without,
    the 2-sigma interval as the momentum it causes. Anchored (known) parameters are marked apart.

    Returns
    -------
    (dict, str)
        The figure (Plotly's plain dict: :func:`_column`) and its caption.
    """
    k = len(result.names)
    names, hover = list(result.names), _hover_texts(result, true)
    anchored = _anchored(result)
    free = ~anchored & (result.std > 0)
    size = 6 if k <= 60 else 4
    panels = []
    if true is not None:
        z = np.where(free, (result.values - true) / np.where(free, result.std, 1), np.nan)
        panels.append(([{"type": "scatter", "x": names, "y": z, "mode": "markers",
                         "marker": {"color": MEASURED, "size": size},
                         "name": "z = (estimate - true) / std  (shaded: |z| <= 2)", "text": hover,
                         "hovertemplate": "%{text}<br>z = %{y:.3g}<extra></extra>"}],
                       [{"type": "rect", "y0": -2, "y1": 2, "fillcolor": TRUE, "opacity": 0.12, "line": {"width": 0}}],
                       {"title": {"text": "z-score [-]"}}))  # fmt: skip
        error, unit = _sizes(result, result.values - true)
    else:
        error, unit = np.zeros(k), None
    bar, unit = _sizes(result, 2 * result.std)
    traces = [{"type": "scatter", "x": [n for n, f in zip(names, free) if f], "y": error[free], "mode": "markers",
               "error_y": {"type": "data", "array": np.abs(bar[free]), "color": MEASURED, "thickness": 1},
               "marker": {"color": MEASURED, "size": size}, "text": [h for h, f in zip(hover, free) if f],
               "name": "error +/- 2 std" if true is not None else "+/- 2 std about the estimate (truth unknown)",
               "hovertemplate": "%{text}<br>%{y:.3g} +/- %{error_y.array:.3g}<extra></extra>"}]  # fmt: skip
    if anchored.any():
        traces.append({"type": "scatter", "x": [n for n, a in zip(names, anchored) if a],
                       "y": np.zeros(int(anchored.sum())), "mode": "markers",
                       "marker": {"symbol": "square-open", "size": 10, "color": ANCHOR},
                       "name": "anchored: known, not estimated", "text": [h for h, a in zip(hover, anchored) if a],
                       "hovertemplate": "%{text}<extra>anchored</extra>"})  # fmt: skip
    zero = {"type": "line", "y0": 0, "y1": 0, "line": {"color": TRUE if true is not None else REFERENCE, "width": 1}}
    panels.append((traces, [zero], {"title": {"text": ("error" if true is not None else "2 std") + f" [{unit}]"}}))
    xaxis = {"title": {"text": f"minimal parameter ({k}; hover for its definition, drag to zoom)"},
             "tickangle": -90 if k > 12 else 0, "automargin": True}
    title = (f"{result.estimator.upper()} estimates of the {k} minimal parameters, N = {result.n_samples} samples, "
             f"cond = {result.condition_number:.4g}")
    caption = ("Parameter estimates. " + ("Top: each estimate's error in its standard errors (z); bottom: the error "
               "with its 2-sigma bar" if true is not None else "The 2-sigma interval of each estimate")
               + (", as the momentum it causes over the log (a fraction of the momentum scale H, so that near-zero "
                  "parameters do not dominate)." if result.scale is not None else ", relative to the estimate."))
    return _column(panels, xaxis, title, 330 + 230 * len(panels)), caption


def singular_value_figure(result: Identification):
    """The singular values of the stacked regressor relative to the largest (log scale); with its
    caption. The figure is Plotly's plain dict (:func:`_column`)."""
    s = np.asarray(result.singular_values, float)
    trace = {"type": "scatter", "x": np.arange(1, s.size + 1), "y": s / s[0], "mode": "lines+markers",
             "name": "sigma_i / sigma_1", "line": {"color": MEASURED}, "marker": {"size": 5},
             "hovertemplate": "i = %{x}<br>sigma_i / sigma_1 = %{y:.3g}<extra></extra>"}  # fmt: skip
    yaxis = {"type": "log", "title": {"text": "sigma_i / sigma_1 [-]"}, "exponentformat": "power"}
    fig = _column([([trace], [], yaxis)], {"title": {"text": "index i (decreasing order)"}},
                  f"Singular values of the stacked regressor (N = {result.n_samples}): cond = "
                  f"{result.condition_number:.4g}", 400)
    return fig, "Singular values of the regressor, relative to the largest; the smallest is 1 / cond."


def validation_figure(measured: Log, predicted: Log, title: str):
    """Measured against predicted base motion, a column per signal (base angular velocity per axis,
    attitude), the residual below each with its RMS; long logs thinned (:func:`downsample`). With its
    caption. The figure is Plotly's plain dict, as :func:`_column`'s (as graph objects, in subplots, it took
    0.16 s of a Cepheus validation's 0.8 s)."""
    _check_same_motion(measured, predicted)
    signals = _base_signals(measured, predicted)
    n, gap = len(signals), 0.08
    width, tops = (1 - gap * (n - 1)) / n, (0.64 * (1 - gap), 0.36 * (1 - gap))  # columns' widths, rows' heights
    rows = ((1 - tops[0], 1.0), (0.0, tops[1]))  # the rows' vertical domains, measured and predicted above
    layout = {**_plain_layout(title, 580), "hovermode": "x unified", "shapes": [], "annotations": [],
              "legend": {"orientation": "h", "x": 0, "xanchor": "left", "y": -0.13, "yanchor": "top"}}
    layout["margin"] = {**layout["margin"], "b": 90}
    data, shown = [], measured.n_samples
    for c, (label, _, unit, y_meas, y_pred, residual, residual_label) in enumerate(signals):
        rms = np.sqrt(np.mean(residual**2))  # of every sample
        t_r, residual, _ = downsample(measured.t, residual)  # each thinned keeping its own extremes
        t, y_meas, y_pred, _ = downsample(measured.t, y_meas, y_pred)
        shown, first, x = t.size, c == 0, (c * (width + gap), c * (width + gap) + width)
        top, bottom = str(c + 1) if c else "", str(n + c + 1)  # the axes' numbers, row by row
        trace = {"type": "scatter", "showlegend": first}
        data += [{**trace, "x": t, "y": y_meas, "name": "measured", "legendgroup": "m",
                  "line": {"color": MEASURED, "width": 1.5}, "xaxis": f"x{top}", "yaxis": f"y{top}"},
                 {**trace, "x": t, "y": y_pred, "name": predicted_label(predicted), "legendgroup": "p",
                  "line": {"color": MODEL, "width": 1.5, "dash": "dash"}, "xaxis": f"x{top}", "yaxis": f"y{top}"},
                 {**trace, "x": t_r, "y": residual, "name": "residual", "legendgroup": "r",
                  "line": {"color": MODEL, "width": 1}, "xaxis": f"x{bottom}", "yaxis": f"y{bottom}"}]
        words = "error angle " if "angle" in residual_label else "pred. - meas. " if first else ""
        layout[f"xaxis{top}"] = {**_X_AXIS, "anchor": f"y{top}", "domain": x, "matches": f"x{bottom}",
                                 "showticklabels": False}
        layout[f"xaxis{bottom}"] = {**_X_AXIS, "anchor": f"y{bottom}", "domain": x, "title": {"text": "time t [s]"}}
        layout[f"yaxis{top}"] = {**_Y_AXIS, "anchor": f"x{top}", "domain": rows[0],
                                 "title": {"text": f"[{unit}]" if c else f"measured, predicted [{unit}]"}}
        layout[f"yaxis{bottom}"] = {**_Y_AXIS, "anchor": f"x{bottom}", "domain": rows[1],
                                    "title": {"text": f"{words}[{unit}]"}}
        layout["shapes"].append({"type": "line", "line": {"color": REFERENCE, "width": 0.8}, "x0": 0, "x1": 1,
                                 "xref": f"x{bottom} domain", "y0": 0, "y1": 0, "yref": f"y{bottom}"})
        for text, (_, y) in ((label, rows[0]), (f"residual, RMS {rms:.2g} {unit}", rows[1])):  # the panels' titles
            layout["annotations"].append({"text": text, "font": {"size": 13}, "showarrow": False, "x": sum(x) / 2,
                                          "xanchor": "center", "xref": "paper", "y": y, "yanchor": "bottom",
                                          "yref": "paper"})
    caption = ("Validation: the base motion measured against the motion predicted from the joint motion, with the "
               "residual below." + thinning_note(measured.n_samples, shown))
    return {"data": data, "layout": layout}, caption


def _estimator_colour(e: str) -> str:
    return {"ml": MODEL, "wls": ANCHOR, "iv": "#9467bd", "tls": "#8c564b", "ols": "#737373"}.get(e, MEASURED)


def montecarlo_figures(result) -> list:
    """A Monte Carlo study's figures: per parameter and estimator the signed errors over the runs
    (box plots, in % of |true|, with the Cramer-Rao 2-sigma marked), and RMSE / CRB with the Monte
    Carlo uncertainty of each ratio (about ``1 / sqrt(2 R)`` relative). Pairs ``(figure, caption)``, each
    figure Plotly's plain dict (:func:`_column`; as graph objects they took 0.3 s of a first study's page)."""
    names, true = list(result.names), np.asarray(result.true, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(true != 0, np.abs(true), np.nan) / 100
    band = 2 * result.crb_std / scale
    xaxis = {"title": {"text": "minimal parameter"}, "tickangle": -90 if len(names) > 12 else 0}
    traces = [{"type": "scatter", "x": names + names, "y": np.concatenate([band, -band]), "mode": "markers",
               "name": "CRB +/- 2 sigma", "marker": {"symbol": "line-ew-open", "size": 14, "color": TRUE,
                                                     "line": {"width": 2}},
               "hovertemplate": "%{x}: CRB 2 sigma %{y:.3g} %<extra></extra>"}]  # fmt: skip
    for e in result.estimators:
        err = (result.estimates[e] - true) / scale  # (runs, k)
        ok = np.isfinite(err)
        x = np.broadcast_to(np.arange(len(names)), err.shape)[ok]
        traces.append({"type": "box", "x": [names[i] for i in x], "y": err[ok], "name": e.upper(),
                       "marker": {"color": _estimator_colour(e), "size": 3}, "boxpoints": "outliers",
                       "line": {"width": 1}})  # fmt: skip
    s = result.settings
    boxes = _column([(traces, [], {"title": {"text": "signed error (estimate - true) / |true| [%]"}})], xaxis,
                    f"Monte Carlo errors: {s['runs']} runs, N = {s['n_samples']} samples, seed {s['seed']}", 520)
    boxes["layout"]["boxmode"] = "group"
    traces = []
    for e in result.estimators:
        ratio = np.asarray(result.stats[e]["rmse_crb"], float)
        runs_ok = result.summary(e)["runs_ok"]
        traces.append({"type": "bar", "x": names, "y": ratio, "name": f"{e.upper()} (R = {runs_ok} runs)",
                       "marker": {"color": _estimator_colour(e), "opacity": 0.85},
                       "error_y": {"type": "data", "array": 2 * ratio / np.sqrt(2 * max(runs_ok, 1)), "color": "black",
                                   "thickness": 1}})  # fmt: skip
    top = max(np.nanmax(np.asarray(result.stats[e]["rmse_crb"], float)) for e in result.estimators)
    efficient = {"type": "line", "y0": 1, "y1": 1, "line": {"color": MEASURED, "width": 1}}
    yaxis = {"title": {"text": "RMSE / CRB [-]"}, "type": "log" if top > 10 else "linear"}
    bars = _column([(traces, [efficient], yaxis)], xaxis, "Efficiency: RMSE over the runs / Cramer-Rao std of each "
                   "parameter", 460)
    bars["layout"] |= {"barmode": "group", "annotations": [
        {"text": "RMSE = CRB (efficient)", "showarrow": False, "x": 0, "xanchor": "left", "xref": "x domain", "y": 1,
         "yanchor": "bottom", "yref": "y"}]}  # fmt: skip
    return [(boxes, "Errors of each estimator over the runs, in percent of |true| (boxes: quartiles, whiskers 1.5 "
                    "IQR, outliers as points); the green marks are the Cramer-Rao bound's +/- 2 sigma."),
            (bars, "RMSE / CRB per parameter and estimator (1: efficient); the bars are +/- 2 standard errors of a "
                   "Monte Carlo RMSE, about 2 / sqrt(2 R) relative over R runs.")]


def _event_shapes(events) -> list:
    """Each event's estimated change (dashed; its lead shaded) and its detection (dotted): Plotly shapes
    spanning the plot's height, at their times on its x axis."""
    span = {"xref": "x", "y0": 0, "y1": 1, "yref": "y domain"}
    shapes = []
    for e in events:
        shapes.append({**span, "type": "line", "x0": e.time, "x1": e.time,
                       "line": {"color": MEASURED, "dash": "dash", "width": 1}})
        if e.lead:
            shapes.append({**span, "type": "rect", "x0": e.time, "x1": e.time + e.lead, "fillcolor": MEASURED,
                           "opacity": 0.12, "line": {"width": 0}})
        shapes.append({**span, "type": "line", "x0": e.detected_at, "x1": e.detected_at,
                       "line": {"color": LIMIT, "dash": "dot", "width": 1.5}})
    return shapes


def _statistic_figure(record):
    """The CUSUM statistic over the run against its threshold, the events marked: Plotly's plain dict
    (:func:`_column`)."""
    t, g = record.statistic
    threshold = record.settings["threshold"]
    traces = [{"type": "scatter", "x": t, "y": g, "mode": "lines", "name": "CUSUM statistic g",
               "line": {"color": MEASURED, "width": 1},
               "hovertemplate": "t = %{x:.4g} s<br>g = %{y:.4g}<extra></extra>"}]  # fmt: skip
    traces += [{"type": "scatter", "x": [e.time, e.detected_at], "y": [0, threshold], "mode": "markers",
                "marker": {"color": [MEASURED, LIMIT], "size": 9, "symbol": ["triangle-up", "x"]},
                "name": f"change {e.index}: at {e.time:.4g} s, alarm {e.detected_at:.4g} s",
                "hovertemplate": "%{x:.4g} s<extra></extra>"} for e in record.events]  # legend entries of the lines
    line = {"type": "line", "y0": threshold, "y1": threshold, "line": {"color": MODEL, "dash": "dash", "width": 1.5}}
    yaxis = {"title": {"text": "log-likelihood ratio g [-]"}}
    notes = [{"text": f"threshold {threshold:.4g}", "showarrow": False, "x": 0, "xanchor": "left", "xref": "x domain",
              "y": threshold, "yanchor": "bottom", "yref": "y"}]  # fmt: skip
    if g.size and g.max() > 4 * threshold:  # a large change would flatten the rest: its peak named instead
        yaxis["range"] = [0, 3 * threshold]
        notes += [{"x": e.detected_at, "y": 3 * threshold, "text": f"peak {e.statistic:.3g}", "showarrow": True,
                   "arrowhead": 2, "ax": 30, "ay": -18, "font": {"size": 11}} for e in record.events]  # fmt: skip
    fig = _column([(traces, [line], yaxis)], {"title": {"text": "time t [s]"}},
                  f"Change detection: {len(record.events)} change(s) in {record.n_samples} samples "
                  f"({record.n_tested} tested)", 440)
    fig["layout"]["shapes"] += _event_shapes(record.events)
    fig["layout"]["annotations"] = notes
    return fig, ("The CUSUM statistic of the normalised innovations (the axis ends at 3 thresholds when a peak is far "
                 "larger: double-click to see all; each point the largest over its run of samples "
                 "when the run is long; no test during each segment's warm-up); dashed: each estimated change time "
                 "(shaded: how much later it can be, differentiated rates), dotted orange: the alarm.")


def _segments_figure(record):
    """Each identified segment's parameters against the first's in combined standard errors: Plotly's plain dict
    (:func:`_column`; a graph object per parameter took 0.11 to 0.24 s of the satellite's 153, this 3 ms)."""
    t, z = record.z_over_time()
    names = record.settings["parameter_names"]
    z_changed = record.settings.get("z_changed", 3.0)
    traces = []
    for name, zk in zip(names, z.T):
        changed = np.nanmax(np.abs(np.nan_to_num(zk)), initial=0.0) > z_changed
        traces.append({"type": "scatter", "x": t, "y": zk, "mode": "lines", "name": name, "showlegend": bool(changed),
                       "connectgaps": False, "line": {"width": 2.2 if changed else 0.8, "color": None if changed else
                                                      "#b0b0b0"},
                       "hovertemplate": f"{name}<br>z = %{{y:.3g}}<extra></extra>"})  # fmt: skip
    band = {"type": "rect", "y0": -z_changed, "y1": z_changed, "fillcolor": REFERENCE, "opacity": 0.15,
            "line": {"width": 0}, "layer": "below"}
    fig = _column([(traces, [band], {"title": {"text": "change from the first segment [std. errors]"},
                                     "type": "linear"})],
                  {"title": {"text": "time t [s]"}},
                  f"Segments' parameters against the first segment's ({len(record.segments)} segment(s))", 460)
    fig["layout"]["shapes"] += _event_shapes(record.events)
    return fig, (f"Each segment's batch estimate against the first segment's, in combined standard errors, over its "
                 f"time span (grey band: |z| < {z_changed:g}; parameters beyond it named in colour, hover for the "
                 "others).")


_EVENT_COLOURS = (MODEL, ANCHOR, LIMIT, "#9467bd")


def _event_figure(record):
    """Per event, each parameter's change (new segment's warm-up against the segment before) in
    combined standard errors: Plotly's plain dict (:func:`_column`)."""
    z_changed = record.settings.get("z_changed", 3.0)
    traces = [{"type": "bar", "x": [p["name"] for p in e.parameters], "y": [p["z"] for p in e.parameters],
               "name": f"change {e.index} at {e.time:.4g} s", "marker": {"color": _EVENT_COLOURS[e.index % 4]},
               "customdata": [[p["before"], p["after"], 100 * p["relative_change"]] for p in e.parameters],
               "hovertemplate": "%{x}: z = %{y:.3g}<br>before %{customdata[0]:.5g}, after %{customdata[1]:.5g} "
                                "(%{customdata[2]:+.3g} %)<extra></extra>"}
              for e in record.events if e.parameters]  # fmt: skip
    band = {"type": "rect", "y0": -z_changed, "y1": z_changed, "fillcolor": REFERENCE, "opacity": 0.15,
            "line": {"width": 0}, "layer": "below"}
    tickangle = -90 if len(record.settings["parameter_names"]) > 12 else 0
    fig = _column([(traces, [band], {"title": {"text": "change / combined std [-]"}})],
                  {"title": {"text": "minimal parameter"}, "tickangle": tickangle},
                  "The parameters' change at each detected change", 440)
    fig["layout"]["barmode"] = "group"
    return fig, (f"At each change: every parameter's change from the segment before to the new segment's warm-up, "
                 f"in combined standard errors (grey band: |z| < {z_changed:g}, not counted as changed).")


def monitor_figures(record) -> list:
    """A monitor run's figures: the statistic with its threshold and the events, the segments'
    parameters against the first's, and each event's parameter changes; pairs ``(figure, caption)``
    (those with nothing to show left out)."""
    figures = []
    if record.statistic is not None and record.statistic[0].size:
        figures.append(_statistic_figure(record))
    if len([s for s in record.segments if s.identification is not None]) > 0:
        figures.append(_segments_figure(record))
    if any(e.parameters for e in record.events):
        figures.append(_event_figure(record))
    return figures
