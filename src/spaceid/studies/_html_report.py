"""The interactive HTML reports (``report.html``, docs/formats/report-html.md): the content of the
Markdown report (settings, diagnostics and warnings, the sortable parameter table, validation,
further sections) with interactive figures, for an identification, a validation, a Monte Carlo
study and a monitor run. Each page is self-contained (:mod:`spaceid.studies._html_page`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from ..estimation import Identification
from ..estimation.internal import diagnostic_rows, per_parameter
from ._html_figures import (montecarlo_figures, monitor_figures, parameter_figure, singular_value_figure,
                            validation_figure)
from ._html_page import Page, number
from ._validate import validation_title
from ._tables import SCALED_ERROR, SCALED_STD, _columns, drift_rows, scale_note

__all__ = ["write_html_report", "write_validation_html", "write_montecarlo_html", "write_monitor_html"]

REPORT_HTML = "report.html"


def _plain(text: str) -> str:
    """A Markdown line of spaceid's reports as plain text: escapes, code marks and emphasis dropped."""
    text = re.sub(r"\\(.)", r"\1", text)
    return re.sub(r"(?<![\w*])[*_](\S(?:.*?\S)?)[*_](?![\w*])", r"\1", text.replace("`", ""))


def _markdown_blocks(page: Page, lines) -> None:
    """Lines of a Markdown section (paragraphs, bullet lists, pipe tables) as page blocks."""
    i, lines = 0, list(lines)
    while i < len(lines):
        line = lines[i].strip()
        if line.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                cells = [_plain(c.strip()) for c in re.split(r"(?<!\\)\|", lines[i].strip())[1:-1]]
                if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                    rows.append(cells)
                i += 1
            page.table(rows[0], [[_numeric(c) for c in r] for r in rows[1:]], text_columns=1)
            continue
        if line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].strip().startswith("- "):
                items.append(_plain(lines[i].strip()[2:]))
                i += 1
            page.bullets(items)
            continue
        if line:
            page.text(_plain(line))
        i += 1


def _numeric(cell: str):
    """A table cell's text, with its number for sorting when it is one."""
    try:
        return (cell, float(cell))
    except ValueError:
        return cell


def _diagnostics(page: Page, result: Identification) -> None:
    """The fit quality and the diagnostics, each warning set apart."""
    d = result.diagnostics
    facts = [f"Estimator {result.estimator}, {result.n_samples} samples, momentum "
             f"[{', '.join(f'{h:.6g}' for h in result.momentum)}] N m s.",
             f"Condition number of the stacked regressor: {result.condition_number:.4g}",
             f"Residual RMS: {result.residual_rms:.3g} N m s"]  # fmt: skip
    page.bullets(facts + [f"{label}: {text}" for label, text, warn in diagnostic_rows(result) if not warn])
    for label, text, warn in diagnostic_rows(result):
        if warn:
            page.text(f"{label}: {text}", warning=True)
    if d.undetermined:
        page.text(f"{len(d.undetermined)} of {len(result.names)} directions of parameter space are not determined by "
                  "the data (the regressor's noise at least as large as its signal): the estimates along them are "
                  "pulled towards zero and their standard errors do not hold. Excite them with a designed motion, or "
                  "give a prior.", warning=True)  # fmt: skip
        page.table(["direction", "noise / signal", "leading parameters"],
                   [(str(i + 1), u["noise_to_signal"], ", ".join(u["parameters"]))
                    for i, u in enumerate(d.undetermined)], text_columns=1)  # fmt: skip


def _parameter_rows(result: Identification, true, reference, reference_label, reference_true) -> tuple:
    """The report's parameter table (the Markdown one's columns), numbers sortable by value."""
    header, rows = _columns(result, true, reference, reference_label, reference_true)
    text = {"parameter", "definition", "unit"}
    out = [[c if h in text else _numeric(c) if c != "-" else (c, None) for h, c in zip(header, row)] for row in rows]
    return header, out


def identification_section(page: Page, result: Identification, *, true=None, reference=None, reference_true=None,
                           reference_label="paper") -> None:
    """An identification's blocks: the parameter table (sortable), its drift terms and gyro bias,
    the fit quality and diagnostics, and the figures of its parameters and singular values."""
    true = per_parameter(true, result, "`true`")
    header, rows = _parameter_rows(result, true, per_parameter(reference, result, "`reference`"), reference_label,
                                   per_parameter(reference_true, result, "`reference_true`"))  # fmt: skip
    page.heading("Identified parameters")
    page.text("Click a column header to sort by it (again to reverse). std: one standard deviation"
              + (f"; {SCALED_STD}, {SCALED_ERROR}: {scale_note(result, true)}" if result.scale is not None else "")
              + ".")
    page.table(header, rows, text_columns=2, wide_columns=(1,))
    if result.drift:
        page.text("Drift terms, estimated with the parameters (the momentum at the first sample and its change by "
                  "the external torque):")
        page.table(["drift term", "unit", "estimate", "std"], [(n, u, _numeric(v), _numeric(s))
                                                              for n, u, v, s in drift_rows(result)], text_columns=2)
    if result.gyro_bias:
        page.text("Gyro bias, estimated with the parameters (base axes):")
        page.table(["gyro bias", "unit", "estimate", "std"], [(g["name"], g["unit"], g["value"], g["std"])
                                                             for g in result.gyro_bias], text_columns=2)
    page.heading("Fit quality and diagnostics")
    _diagnostics(page, result)
    if result.prior is not None:
        page.text(result.prior.summary() + ".")
    page.figure(*parameter_figure(result, true))
    if len(result.singular_values):
        page.figure(*singular_value_figure(result))


def _settings(page: Page, settings: dict) -> None:
    if not settings:
        return
    page.heading("Settings")
    page.table(["setting", "value"], [(str(k), number(v)) for k, v in settings.items()], sortable=False,
               text_columns=2)


def write_html_report(out, *, title: str, result: Identification, settings: dict, figures: dict, true=None,
                      reference=None, metrics: dict | None = None, reference_true=None, reference_label: str = "paper",
                      sections: dict | None = None, validations=(), name: str = REPORT_HTML) -> Path:
    """Write ``out/report.html`` (or ``out/name``): the content of :func:`write_markdown_report`'s ``report.md`` (same
    arguments) with interactive figures.

    Parameters
    ----------
    out, title, result, settings, true, reference, metrics, reference_true, reference_label, sections
        As for :func:`spaceid.studies.write_markdown_report`.
    figures : dict of str to path-like
        Caption -> PNG (relative to ``out`` or absolute) of the figures with no interactive form
        here, embedded as images.
    validations : sequence of (Log, Log, str)
        ``(measured, predicted, title)``: drawn interactively, measured against predicted.
    name : str
        The page's file name in ``out``.

    Returns
    -------
    Path
        The written ``report.html``.
    """
    from ._report import metric_label

    folder = Path(out)
    page = Page(title, f"{result.model}: {len(result.names)} minimal parameters from {result.n_samples} samples")
    _settings(page, settings)
    identification_section(page, result, true=true, reference=reference, reference_true=reference_true,
                           reference_label=reference_label)
    if metrics:
        page.heading("Validation")
        page.table(["metric", "value"], [(metric_label(k), v) for k, v in metrics.items()], text_columns=1)
    for measured, predicted, caption in validations:
        page.figure(*validation_figure(measured, predicted, caption))
    for heading, body in (sections or {}).items():
        page.heading(heading)
        _markdown_blocks(page, body)
    if figures:
        page.heading("Further figures")
        for caption, path in figures.items():
            full = folder / path
            if not full.is_file():
                raise SpaceidError(f"figures['{caption}']: '{path}' not found (looked at {full}): draw the figure "
                                   "first")
            page.image(full, caption)
    return page.write(folder / name)


def write_validation_html(path, measured, predictions, metrics: dict, *, title: str, source: str,
                          torque_metrics: dict | None = None) -> Path:
    """Write a validation's HTML report: its metrics and, per prediction, measured against predicted.

    Parameters
    ----------
    path : path-like
        The page to write.
    measured : Log
    predictions : sequence of (Log, str or None)
        Each predicted log (at ``measured``'s stamps) with its figure's title (None: the default,
        naming what predicted).
    metrics : dict
        :func:`validation_metrics` of the prediction from the momentum.
    title, source : str
        The page's title and what predicted (e.g. "the identified model of RESULT.json").
    torque_metrics : dict, optional
        The torque-driven prediction's metrics (``validate --torques``).
    """
    from ._report import metric_label
    from ._torque_validation import TORQUE_METRIC_LABELS

    page = Page(title, f"predicted by {source}; {measured.n_samples} measured samples, "
                       f"{measured.t[-1] - measured.t[0]:.4g} s")
    page.heading("Metrics")
    rows = [(metric_label(k), v) for k, v in metrics.items()]
    rows += [(TORQUE_METRIC_LABELS.get(k, k), v) for k, v in (torque_metrics or {}).items()]
    page.table(["metric", "value"], rows)
    page.heading("Measured against predicted")
    for predicted, caption in predictions:
        page.figure(*validation_figure(measured, predicted, caption or validation_title(predicted).replace("\n", " ")))
    return page.write(path)


def write_montecarlo_html(result, path) -> Path:
    """Write a Monte Carlo study's HTML report: its settings, one sortable statistics table per
    estimator and the interactive figures of its errors and efficiency."""
    s = result.settings
    page = Page(f"Monte Carlo study: {s['runs']} runs on {s.get('model', '')}".rstrip(" on"),
                f"N = {s['n_samples']} samples, seed {s['seed']}, estimators {', '.join(result.estimators)}")
    _settings(page, {k: v for k, v in s.items() if not isinstance(v, (dict, list)) or k == "noise"})
    names = list(result.names)
    for e in result.estimators:
        st = result.stats[e]
        w = result.summary(e)
        page.heading(f"{e.upper()}: {w['runs_ok']} of {result.runs} runs")
        crb = "CRB*" if s.get("angles_only") else "CRB"
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_crb = np.where(st["true"] != 0, st["crb_std"] / np.abs(st["true"]), np.nan)
            honest = st["predicted_std"] / st["std"]
        columns = {"true": st["true"], "mean": st["mean"], "bias/std": st["bias_std"],
                   "RMSE [% |true|]": 100 * st["relative_rmse"], f"{crb} std [% |true|]": 100 * rel_crb,
                   "predicted / actual std": honest, f"RMSE / {crb}": st["rmse_crb"]}  # fmt: skip
        rows = [[n] + [float(c[i]) for c in columns.values()] for i, n in enumerate(names)]
        page.table(["parameter", *columns], rows)
        page.text(f"Worst over the parameters: RMSE {100 * w['relative_rmse']:.3g} %, RMSE/CRB {w['rmse_crb']:.2f}, "
                  f"|bias|/std {w['abs_bias_std']:.2f}.")
    page.heading("Figures")
    for fig, caption in montecarlo_figures(result):
        page.figure(fig, caption)
    return page.write(path)


def write_monitor_html(record, path, *, source: str) -> Path:
    """Write a monitor run's HTML report: its settings, events and segments (sortable tables) and
    the figures of its statistic and of the parameters' changes."""
    s = record.settings
    page = Page(f"Change detection on {source}", f"{record.model}: {len(record.events)} change(s) in "
                f"{record.n_samples} samples, {len(record.segments)} segment(s)")
    _settings(page, {k: s[k] for k in ("test", "false_alarm_rate", "change_ratio", "threshold", "expected_delay",
                                       "forgetting", "warmup", "estimator", "max_segment", "z_changed") if k in s})
    page.heading("Events")
    if record.events:
        page.table(["change", "time [s]", "lead [s]", "detected at [s]", "delay [samples]", "statistic", "threshold",
                    "changed parameters"],
                   [(str(e.index), e.time, e.lead, e.detected_at, e.delay, e.statistic, e.threshold,
                     ", ".join(e.changed) or "none beyond the threshold") for e in record.events])  # fmt: skip
    else:
        page.text("No change detected.")
    page.heading("Segments")
    page.table(["segment", "start [s]", "end [s]", "samples", "identified from", "chi2/dof"],
               [(str(g.index), _or_nan(g.start), _or_nan(g.end), g.n_samples, g.n_identified,
                 _or_nan(None if g.identification is None else g.identification.diagnostics.chi2_dof))
                for g in record.segments])  # fmt: skip
    for fig, caption in monitor_figures(record):
        page.figure(fig, caption)
    return page.write(path)


def _or_nan(x) -> float:
    return np.nan if x is None else float(x)
