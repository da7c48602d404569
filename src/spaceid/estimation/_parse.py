"""Command-line values of the estimation: momentum and known (anchor) parameters."""

from __future__ import annotations


import numpy as np

from .._errors import SpaceidError

__all__ = ["parse_momentum", "parse_known"]


def parse_momentum(value, *, planar: bool):
    """Inertial angular momentum as a 3-vector [N m s] from a number or ``"hx,hy,hz"``.

    A planar system takes a scalar ``h`` (about the inertial z axis); a spatial one takes
    ``0`` for ``0,0,0`` (a system that started at rest). ``"unknown"`` (or None) gives None: a
    constant momentum estimated with the parameters.
    """
    if value is None or str(value).strip().lower() == "unknown":
        return None
    try:
        parts = [float(v) for v in str(value).split(",")] if not np.ndim(value) else [float(v) for v in value]
    except ValueError:
        raise SpaceidError(f"--momentum: '{value}' is not a number or a list hx,hy,hz [N m s]") from None
    if len(parts) == 1 and (planar or parts[0] == 0):
        parts = [0.0, 0.0, parts[0]]
    if len(parts) != 3 or not np.all(np.isfinite(parts)):
        single = "h or " if planar else "0 or "
        raise SpaceidError(f"--momentum: expected {single}hx,hy,hz (finite, N m s), got '{value}'")
    return np.array(parts)


def parse_known(items) -> dict:
    """``NAME=VALUE`` strings (``--known``) as ``{name: value}``."""
    known = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        try:
            number = float(value)
        except ValueError:
            number = np.nan
        if not sep or not name.strip() or not np.isfinite(number):
            raise SpaceidError(f"--known: '{item}' is not NAME=VALUE with a finite number (e.g. Iczz_wheel=0.00197)")
        known[name.strip()] = number
    return known
