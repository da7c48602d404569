"""What an identification shows in a notebook (``_repr_html_``): the setting in one line, the
diagnostics a reader judges it by, and the parameter table (scrollable at 150+ parameters)."""

from __future__ import annotations

from html import escape

import numpy as np

from ._residuals import CONFOUNDED, DRIFT_FLOOR

__all__ = ["identification_html"]

_STYLE = ("<style>.spaceid-id table{border-collapse:collapse;font-size:12px}"
          ".spaceid-id td,.spaceid-id th{padding:1px 8px;text-align:right}"
          ".spaceid-id td:first-child,.spaceid-id th:first-child{text-align:left}"
          ".spaceid-id .warn{color:#b35806}</style>")


def _number(x) -> str:
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.4g}"


def diagnostic_rows(result) -> list:
    """(label, text, warning?) of the diagnostics worth a line."""
    d = result.diagnostics
    rows = [("scaled condition number", _number(d.condition_number_scaled), False),
            ("chi2 / dof", _number(d.chi2_dof), bool(d.noise_model_warning)),
            ("covariance", d.covariance or d.covariance_method or "–", False)]
    if d.drift_test is not None:
        rows.append(("drift test", *_drift_row(d.drift_test)))
    rows += [("noise model", d.noise_model_warning, True)] if d.noise_model_warning else []
    rows += [("plausibility", d.plausibility, not d.plausibility.startswith("no "))] if d.plausibility else []
    info = d.estimator_info
    if info.get("fallback"):
        rows.append(("estimator", f"fell back to {info['fallback']}", True))
    elif info.get("held"):
        rows.append(("estimator", f"maximum likelihood {info['held']}", False))
    return rows


def _drift_row(t) -> tuple:
    """(text, warning?) of the drift test: its p-value and what it decided, a warning only when it warned. A
    p-value under its level without a warning says why the test did not decide (on an undesigned spatial log,
    the directions the data do not determine; :mod:`spaceid.estimation._residuals`)."""
    if not t.run:
        return f"not run: {t.reason}", False
    text = f"p = {_number(t.p_value)}"
    if t.drift:
        cause = f"a gyro bias of {', '.join(f'{b:.3g}' for b in t.gyro_bias)} rad/s" if t.gyro_bias else \
            f"a momentum drift of {100 * t.relative_drift:.2g} % of its RMS"
        return f"{text} < {t.alpha:g}: {cause}", True
    if t.p_value is None or t.p_value >= t.alpha:
        return f"{text}: no drift", False
    if t.confounded is not None and t.confounded >= CONFOUNDED:
        return (f"{text} < {t.alpha:g}, not decided: {100 * t.confounded:.3g} % of a drift coefficient's variance "
                "comes from directions the data do not determine"), False
    return f"{text} < {t.alpha:g}, not decided: the fitted drift is round-off (below {DRIFT_FLOOR:g} of the RMS)", False


def identification_html(result) -> str:
    """HTML of an :class:`~spaceid.estimation.Identification`: setting, diagnostics, parameters."""
    head = (f"<b>{escape(result.model)}</b>: {len(result.values)} minimal parameters from {result.n_samples} "
            f"samples, estimator <code>{escape(result.estimator)}</code>")
    diag = "".join(f'<tr><td>{escape(k)}</td><td{" class=warn" if w else ""} style="text-align:left">'
                   f"{escape(str(v))}</td></tr>" for k, v, w in diagnostic_rows(result))
    # std as the momentum it causes (near-zero parameters do not dominate; docs/theory/momentum-scale.md),
    # relative to the value for results written before the scale
    scaled = result.scale is not None
    rel = result.scaled_std if scaled else np.abs(result.std) / np.maximum(np.abs(result.values), 1e-300)
    rows = "".join(f"<tr><td>{escape(n)}</td><td>{v:.6g}</td><td>{s:.3g}</td><td>{100 * r:.3g}</td>"
                   f"<td>{escape(u)}</td></tr>"
                   for n, v, s, r, u in zip(result.names, result.values, result.std, rel,
                                            result.units or [""] * len(result.values)))  # fmt: skip
    table = ("<div style='max-height:24em;overflow:auto'><table><thead><tr><th>parameter</th><th>value</th>"
             f"<th>std</th><th>{'std [% H]' if scaled else 'std [%]'}</th><th>unit</th></tr></thead><tbody>{rows}"
             "</tbody></table></div>")
    return (f"{_STYLE}<div class='spaceid-id'><p>{head}</p><table>{diag}</table>"
            f"<details open><summary>parameters</summary>{table}</details></div>")
