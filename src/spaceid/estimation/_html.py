"""What an identification shows in a notebook (``_repr_html_``): the setting in one line, the
diagnostics a reader judges it by, and the parameter table (scrollable at 150+ parameters)."""

from __future__ import annotations

from html import escape

import numpy as np

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
        t = d.drift_test
        text = f"p = {_number(t.p_value)}" if t.run else f"not run: {t.reason}"
        rows.append(("drift test", text, bool(t.run and t.p_value is not None and t.p_value < t.alpha)))
    rows += [("noise model", d.noise_model_warning, True)] if d.noise_model_warning else []
    rows += [("plausibility", d.plausibility, not d.plausibility.startswith("no "))] if d.plausibility else []
    info = d.estimator_info
    if info.get("fallback"):
        rows.append(("estimator", f"fell back to {info['fallback']}", True))
    elif info.get("held"):
        rows.append(("estimator", f"maximum likelihood {info['held']}", False))
    return rows


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
