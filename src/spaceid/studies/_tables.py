"""Terminal tables (rich) of an identification and of a Monte Carlo study."""

from __future__ import annotations


import numpy as np
from rich.console import Group
from rich.table import Table
from rich.text import Text

from .._deprecation import deprecated_alias
from ..estimation import LARGE_SHARE, Identification
from ..estimation.internal import per_parameter, relative_errors


__all__ = ["parameter_table", "montecarlo_table", "drift_lines"]


# --- figures ----------------------------------------------------------------------------------



SCALED_STD, SCALED_ERROR = "std [% H]", "error [% H]"
"""Headers of the standard deviation and the error as the momentum they cause, in percent of the
log's momentum scale H (:class:`~spaceid.estimation.MomentumScale`)."""


def scale_note(ident: Identification, true=None) -> str:
    """The sentence that says what the ``% H`` columns and the dashes mean (empty without a scale)."""
    if ident.scale is None:
        return ""
    return (f"% H: the momentum a parameter's std or error alone causes over the log, in percent of its momentum "
            f"scale H = {ident.scale.momentum:.3g} N m s" + ("; rel. error shown for the large parameters (a "
            f"nominal share of H of at least {100 * LARGE_SHARE:g} %), '-' for the others" if true is not None else ""))


def _columns(ident: Identification, true, reference, reference_label, reference_true=None):
    """Header and formatted rows shared by the rich and the Markdown tables: name, definition,
    then the unit (when the result records units) and the numbers."""
    header = ["parameter", "definition"]
    cols = [ident.names, ident.definitions]
    if ident.units:
        header.append("unit")
        cols.append(ident.units)
    if true is not None:
        header.append("true")
        cols.append([f"{v:.6g}" for v in true])
    if reference_true is not None:
        header.append(f"{reference_label} true")
        cols.append([f"{v:.4g}" for v in reference_true])
    header += ["estimate", "std"]
    cols += [[f"{v:.6g}" for v in ident.values], [f"{s:.3g}" for s in ident.std]]
    scale = ident.scale
    if scale is not None:
        header.append(SCALED_STD)
        cols.append([f"{v:.3g}" for v in 100 * scale.scaled(ident.std)])
    if true is not None:
        rel, _ = relative_errors(ident, true)
        shown = np.isfinite(rel) & (scale.large if scale is not None else True)  # near-zero ones: not meaningful
        header.append("rel. error [%]")
        cols.append([f"{100 * e:.3g}" if ok else "-" for e, ok in zip(rel, shown)])
        if scale is not None:
            header.append(SCALED_ERROR)
            cols.append([f"{v:.3g}" for v in 100 * scale.scaled(ident.values - true)])
    if reference is not None:
        header.append(f"{reference_label} rel. error [%]")
        cols.append([f"{v:.4g}" for v in reference])
    return header, list(zip(*cols))


def drift_rows(ident: Identification) -> list:
    """``(name, unit, value, std)`` strings of each drift coefficient of ``ident`` (none without drift)."""
    return [(d["name"], d["unit"], f"{d['value']:.6g}", f"{d['std']:.3g}") for d in ident.drift]


@deprecated_alias(old="ident", new="result")
def drift_lines(result: Identification) -> list:
    """One line per drift coefficient, ``drift: torque_z = 1e-4 +/- 2e-6 N m``, for the terminal."""
    return [f"drift: {n} = {v} +/- {s} {u}" for n, u, v, s in drift_rows(result)]


DEFINITIONS_SHOWN = 30
"""Up to this many parameters the table lists their definitions; larger systems (the servicer's
496, many of them hundreds of characters long) point to ``spaceid model`` and the result file."""


@deprecated_alias(old="ident", new="result")
def parameter_table(result: Identification, *, true=None, reference=None, reference_true=None,
                    reference_label="paper", rows=None, rest="") -> Group:
    """The estimates as a rich table, with the definitions listed below it.

    The definitions (often long SymPy expressions) go under the table so that the numbers stay
    readable in an 80-column terminal; beyond ``DEFINITIONS_SHOWN`` parameters a line says where
    they are instead. With ``rows``, only the first ``rows`` parameters are listed, in order (the
    order of ``spaceid model``'s listing, so that the two read side by side; the conditioning and
    the momentum-scaled std, which judge the whole set, are in the line under the table), and a
    last line says how many more there are.

    Parameters
    ----------
    result : Identification
    true : array_like of shape (k,), optional
        True values: adds columns ``true`` and ``rel. error [%]``.
    reference : array_like of shape (k,), optional
        Reference relative errors in percent (e.g. the paper's Table 3).
    reference_true : array_like of shape (k,), optional
        Reference true values (e.g. the paper's Table 3).
    reference_label : str
        Name of the reference in its column headers.
    rows : int, optional
        List only the first ``rows`` parameters (default: all).
    rest : str
        With ``rows``: where the parameters not listed are, ending the last line (e.g.
        ``"--all lists them; result.json holds every one"``).
    """
    true = per_parameter(true, result, "`true`")
    reference = per_parameter(reference, result, "`reference`")
    reference_true = per_parameter(reference_true, result, "`reference_true`")
    header, table_rows = _columns(result, true, reference, reference_label, reference_true)
    # one unit for all (every planar-basis pi is in kg m^2) goes in the caption, and the paper's
    # seven columns still fit 80
    shown = [i for i, name in enumerate(header)
             if name != "definition" and (name != "unit" or len(set(result.units)) > 1)]
    same_unit = f"; all in {result.units[0]}" if result.units and len(set(result.units)) == 1 else ""
    # under the table, not its caption: a caption wraps at the (often narrow) table's width
    note = Text(f"cond(Y) {result.condition_number:.4g}, N = {result.n_samples}{same_unit}"
                + (f"; {scale_note(result, true)}" if reference is None and result.scale is not None else ""))
    table = Table(title=f"{result.estimator.upper()} estimates", title_justify="left")
    short = {"parameter": "", "rel. error [%]": "err [%]", f"{reference_label} true": reference_label,
             f"{reference_label} rel. error [%]": f"{reference_label} err [%]", SCALED_STD: "std%H",
             SCALED_ERROR: "err%H"}  # fits 80 columns
    # 80 columns: the paper's columns leave no room (its relative errors are the comparison); with the
    # truth the scaled error says more than the scaled std (the Markdown report has both)
    dropped = (SCALED_STD, SCALED_ERROR) if reference is not None else (SCALED_STD,) if true is not None else ()
    shown = [i for i in shown if header[i] not in dropped]
    for i in shown:
        table.add_column(short.get(header[i], header[i]), justify="left" if header[i] in ("parameter", "unit")
                         else "right", no_wrap=True)
    k = len(result.names)
    listed = k if rows is None else min(rows, k)
    for row in table_rows[:listed]:
        table.add_row(*(row[i] for i in shown))
    if k > DEFINITIONS_SHOWN:
        definitions = f"{k} parameters: their definitions are in the result file and in 'spaceid model {result.model}'"
    else:
        definitions = Table.grid(padding=(0, 1))
        definitions.add_column(no_wrap=True)
        definitions.add_column(overflow="fold")
        for name, definition in zip(result.names[:listed], result.definitions[:listed]):
            definitions.add_row(f"{name} =", definition)
    if listed == k:
        return Group(table, note, definitions)
    return Group(table, note, definitions, _rest_line(listed, k, rest))


def _rest_line(listed: int, k: int, rest: str, per: str = "") -> Text:
    """The last line of a table cut to its first ``listed`` of ``k`` parameters (``per``: e.g. each
    estimator's): how many more there are, then ``rest``, where they are."""
    return Text(f"the first {listed} of {k} parameters listed{per}, {k - listed} more" + (f": {rest}" if rest else ""))


def montecarlo_table(result, *, rows=None, rest="") -> Group:
    """Monte Carlo statistics as a rich table, one section per estimator, and a line on the
    seed and noise under it.

    Columns per parameter: bias / std, relative RMSE [%], the relative Cramer-Rao std [%],
    mean predicted std / actual std (1: honest standard errors) and RMSE / CRB (1: efficient).
    With ``rows``, each section lists the first ``rows`` parameters, in order, and a last line
    says how many more there are (as :func:`parameter_table`).

    Parameters
    ----------
    result : spaceid.studies.MonteCarloResult
    rows : int, optional
        List only the first ``rows`` parameters of each estimator (default: all).
    rest : str
        With ``rows``: where the parameters not listed are, ending the last line.
    """
    s = result.settings
    noise = s["noise"]
    table = Table(title=f"Monte Carlo: {s['runs']} runs, N = {s['n_samples']}")  # short: fits the table's width
    note = Text(
        f"seed {s['seed']}; "
        + (f"angles only, rates differentiated; noise: angle {noise['angle']:.3g} rad, attitude "
           f"{noise['attitude']:.3g} rad; CRB*: white-noise equivalent of the differentiated rates, not a bound"
           if s.get("angles_only") else
           f"noise: angle {noise['angle']:.3g} rad, rate {noise['rate']:.3g} rad/s, base rate "
           f"{noise['base_rate']:.3g} rad/s" + ("" if s.get("planar") else f", attitude {noise['attitude']:.3g} rad"))
        + (f"; {s['failures']['count']} failed identifications" if s["failures"]["count"] else "")
    )
    crb = "CRB*" if s.get("angles_only") else "CRB"
    for name in ("", "", "bias/std", "RMSE [%]", f"{crb} [%]", "pred/act std", f"RMSE/{crb}"):
        table.add_column(name, justify="left" if not name else "right", no_wrap=True)
    fmt = lambda v, spec: "-" if not np.isfinite(v) else format(v, spec)  # noqa: E731
    k = len(result.names)
    listed = k if rows is None else min(rows, k)
    for e in result.estimators:
        st = result.stats[e]
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_crb = np.where(st["true"] != 0, st["crb_std"] / np.abs(st["true"]), np.nan)
            honest = st["predicted_std"] / st["std"]
        for i, name in enumerate(result.names[:listed]):
            table.add_row(e.upper() if i == 0 else "", name, fmt(st["bias_std"][i], "+.2f"),
                          fmt(100 * st["relative_rmse"][i], ".3g"), fmt(100 * rel_crb[i], ".3g"),
                          fmt(honest[i], ".2f"), fmt(st["rmse_crb"][i], ".2f"),
                          end_section=i == listed - 1)  # fmt: skip
    return Group(table, note) if listed == k else Group(table, note, _rest_line(listed, k, rest, " per estimator"))


