"""Terminal tables (rich) of an identification and of a Monte Carlo study."""

from __future__ import annotations


import numpy as np
from rich.console import Group
from rich.table import Table
from rich.text import Text

from .._deprecation import deprecated_alias
from ..estimation import Identification
from ..estimation.internal import per_parameter, relative_errors


__all__ = ["parameter_table", "montecarlo_table", "drift_lines"]


# --- figures ----------------------------------------------------------------------------------



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
    if true is not None:
        rel, _ = relative_errors(ident, true)
        header.append("rel. error [%]")
        cols.append([f"{100 * e:.3g}" if np.isfinite(e) else "-" for e in rel])
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
                    reference_label="paper") -> Group:
    """The estimates as a rich table, with the definitions listed below it.

    The definitions (often long SymPy expressions) go under the table so that the numbers stay
    readable in an 80-column terminal; beyond ``DEFINITIONS_SHOWN`` parameters a line says where
    they are instead.

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
    """
    true = per_parameter(true, result, "`true`")
    reference = per_parameter(reference, result, "`reference`")
    reference_true = per_parameter(reference_true, result, "`reference_true`")
    header, rows = _columns(result, true, reference, reference_label, reference_true)
    # one unit for all (every planar-basis pi is in kg m^2) goes in the caption, and the paper's
    # seven columns still fit 80
    shown = [i for i, name in enumerate(header)
             if name != "definition" and (name != "unit" or len(set(result.units)) > 1)]
    same_unit = f"; all in {result.units[0]}" if result.units and len(set(result.units)) == 1 else ""
    # under the table, not its caption: a caption wraps at the (often narrow) table's width
    note = Text(f"cond(Y) {result.condition_number:.4g}, N = {result.n_samples}{same_unit}")
    table = Table(title=f"{result.estimator.upper()} estimates", title_justify="left")
    short = {"parameter": "", "rel. error [%]": "err [%]", f"{reference_label} true": reference_label,
             f"{reference_label} rel. error [%]": f"{reference_label} err [%]"}  # fits 80 columns
    for i in shown:
        table.add_column(short.get(header[i], header[i]), justify="left" if header[i] in ("parameter", "unit")
                         else "right", no_wrap=True)
    for row in rows:
        table.add_row(*(row[i] for i in shown))
    if len(result.names) > DEFINITIONS_SHOWN:
        return Group(table, note, f"{len(result.names)} parameters: their definitions are in the result file "
                                  f"and in 'spaceid model {result.model}'")
    definitions = Table.grid(padding=(0, 1))
    definitions.add_column(no_wrap=True)
    definitions.add_column(overflow="fold")
    for name, definition in zip(result.names, result.definitions):
        definitions.add_row(f"{name} =", definition)
    return Group(table, note, definitions)


def montecarlo_table(result) -> Group:
    """Monte Carlo statistics as a rich table, one section per estimator, and a line on the
    seed and noise under it.

    Columns per parameter: bias / std, relative RMSE [%], the relative Cramer-Rao std [%],
    mean predicted std / actual std (1: honest standard errors) and RMSE / CRB (1: efficient).

    Parameters
    ----------
    result : spaceid.studies.MonteCarloResult
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
    for e in result.estimators:
        st = result.stats[e]
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_crb = np.where(st["true"] != 0, st["crb_std"] / np.abs(st["true"]), np.nan)
            honest = st["predicted_std"] / st["std"]
        for i, name in enumerate(result.names):
            table.add_row(e.upper() if i == 0 else "", name, fmt(st["bias_std"][i], "+.2f"),
                          fmt(100 * st["relative_rmse"][i], ".3g"), fmt(100 * rel_crb[i], ".3g"),
                          fmt(honest[i], ".2f"), fmt(st["rmse_crb"][i], ".2f"),
                          end_section=i == len(result.names) - 1)  # fmt: skip
    return Group(table, note)


