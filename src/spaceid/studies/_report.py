"""The Markdown report of an identification: settings, figures, parameters and metrics."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from ..estimation import Identification


from ._tables import _columns, per_parameter, drift_rows
from ._torque_validation import TORQUE_METRIC_LABELS

__all__ = ["write_markdown_report", "metric_label", "servicing_label"]


def _md(text) -> str:
    """Plain text safe inside a Markdown table cell."""
    text = str(text).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")
    return text.replace("*", "\\*").replace("_", "\\_")


def _md_value(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple, np.ndarray)):
        return ", ".join(_md_value(v) for v in np.asarray(value).reshape(-1).tolist())
    return _md(value)


def _md_table(header, rows) -> list:
    # the first two columns (text) left-aligned, the numbers right-aligned
    rule = "|" + "|".join("---" if i < 2 else "---:" for i in range(len(header))) + "|"
    lines = ["| " + " | ".join(header) + " |", rule]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


# readable names for spaceid.studies.validation_metrics; other keys are shown as given
_METRIC_LABELS = {
    "base_w_rms": "base angular velocity, RMS error [rad/s]",
    "base_w_nrms": "base angular velocity, RMS error / RMS value",
    "base_w_max": "base angular velocity, largest error [rad/s]",
    "base_yaw_rms": "base yaw, RMS error [rad]",
    "base_yaw_max": "base yaw, largest error [rad]",
    "base_attitude_rms": "base attitude, RMS error angle [rad]",
    "base_attitude_max": "base attitude, largest error angle [rad]",
}


SERVICING_LABELS = {
    "grasp_time": ("grasp time", "s"),
    "detected_change_time": ("detected change time", "s"),
    "detected_at": ("detected at", "s"),
    "change_time_error": ("change time error", "s"),
    "change_time_error_samples": ("change time error", "samples"),
    "change_time_lead": ("change time lead", "s"),
    "alarm_time_from_grasp": ("alarm time from the grasp", "s"),
    "false_alarms": ("events before the grasp (false alarms)", None),
    "events": ("events", None),
    "monitor_drift_terms": ("monitor drift terms", None),
    "sample_period": ("sample period", "s"),
    "payload_window": ("payload window", "s"),
    "payload_window_start_after_grasp": ("payload window start after the grasp", "s"),
    "payload_motion": ("payload velocity, rate at the grasp", "m/s, rad/s"),
    "momentum_before_grasp": ("momentum before the grasp", "N m s"),
    "momentum_before_grasp_std": ("momentum before the grasp std", "N m s"),
    "momentum_from": ("momentum from", "s"),
    "phase_seed": ("phase seed", None),
    "not_identifiable": ("not identifiable", None),
}
"""Readable name and unit (None: none) of each :class:`spaceid.studies.ServicingScores` key, as the report and
the command line show them."""


def servicing_label(key: str) -> str:
    """Readable name, with its unit, of a :class:`spaceid.studies.ServicingScores` key (``grasp_time`` ->
    ``grasp time [s]``; other keys are returned as given)."""
    label, unit = SERVICING_LABELS.get(key, (key, None))
    return label if unit is None else f"{label} [{unit}]"


def metric_label(key: str) -> str:
    """Readable name, with its unit, of a :func:`spaceid.studies.validation_metrics` or
    :func:`spaceid.studies.torque_metrics` key (other keys are returned as given)."""
    return _METRIC_LABELS.get(key) or TORQUE_METRIC_LABELS.get(key, key)


@deprecated_alias(old="folder", new="out")
@deprecated_alias(old="ident", new="result")
def write_markdown_report(
    out,
    *,
    title: str,
    result: Identification,
    settings: dict,
    figures: dict,
    true=None,
    reference=None,
    metrics: dict | None = None,
    reference_true=None,
    reference_label: str = "paper",
    sections: dict | None = None,
) -> Path:
    """Write ``out/report.md``: settings, parameter table, fit quality, validation, further
    sections, figures.

    Parameters
    ----------
    out : path-like
        Report folder (created if needed).
    title : str
    result : Identification
    settings : dict
        Run settings shown as given (model, trajectory, momentum, samples, noise, seed,
        estimator, rank tolerance, ...), in insertion order.
    figures : dict of str to path-like
        Caption -> PNG, relative to ``out`` (as linked from the report) or absolute.
    true, reference, reference_true, reference_label
        As in :func:`parameter_table`.
    metrics : dict, optional
        Validation metrics, e.g. from ``spaceid.studies.validation_metrics``.
    sections : dict of str to list of str, optional
        Further sections before the figures: heading -> Markdown lines.

    Returns
    -------
    Path
        The written ``report.md``.
    """
    folder = Path(out)
    true = per_parameter(true, result, "`true`")
    reference = per_parameter(reference, result, "`reference`")
    reference_true = per_parameter(reference_true, result, "`reference_true`")
    links = []
    for caption, fig_path in figures.items():
        full = folder / fig_path  # an absolute fig_path stays as it is
        if not full.is_file():
            raise SpaceidError(
                f"figures['{caption}']: '{fig_path}' not found (looked at {full}): give a PNG path relative to the "
                "report folder or absolute, and draw the figure first"
            )
        links.append((caption, Path(os.path.relpath(full, folder)).as_posix().replace(" ", "%20")))

    header, rows = _columns(result, true, reference, reference_label, reference_true)
    rows = [(_md(r[0]), "`" + r[1].replace("|", "\\|").replace("`", "'") + "`", *r[2:]) for r in rows]
    lines = [f"# {title}", "", "## Settings", ""]
    lines += _md_table(["setting", "value"], [(_md(k), _md_value(v)) for k, v in settings.items()])
    lines += ["", "## Identified parameters", ""]
    lines += _md_table([_md(h) for h in header], rows)
    if result.drift:
        lines += ["", ("Drift terms, estimated with the parameters (the momentum at the first sample and its change "
                       "by the external torque):"), ""]
        lines += _md_table(["drift term", "unit", "estimate", "std"], [tuple(map(_md, r)) for r in drift_rows(result)])
    lines += [
        "",
        f"Estimator {_md(result.estimator)}, {result.n_samples} samples, momentum "
        f"[{', '.join(f'{h:.6g}' for h in result.momentum)}] N m s; std: one standard deviation"
        + ("; relative error: abs(estimate - true) / abs(true)." if true is not None else "."),
        "",
        f"- Condition number of the stacked regressor: {result.condition_number:.4g}",
        f"- Residual RMS: {result.residual_rms:.3g} N m s",
    ]
    d = result.diagnostics  # how well the data agreed with the model (empty for a bare record)
    if d.chi2_dof is not None:
        lines.append(f"- chi2/dof: {d.chi2_dof:.3g}")
    if d.covariance:
        lines.append(f"- Covariance: {_md(d.covariance)}")
    if metrics:
        lines += ["", "## Validation", ""]
        lines += _md_table(["metric", "value"], [(_md(metric_label(k)), _md_value(v)) for k, v in metrics.items()])
    for heading, body in (sections or {}).items():
        lines += ["", f"## {_md(heading)}", "", *body]
    if links:
        lines += ["", "## Figures"]
        for caption, link in links:
            lines += ["", f"![{_md(caption)}]({link})", "", f"*{_md(caption)}*"]
    path = folder / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
