"""Command-line values of the estimation: momentum, known (anchor) parameters and drift terms."""

from __future__ import annotations


import numpy as np

from .._errors import SpaceidError
from ._drift import DRIFT_KINDS, check_drift_kinds, drift_terms

__all__ = ["parse_momentum", "parse_known", "parse_drift"]


def parse_momentum(value, *, planar: bool):
    """Inertial angular momentum as a 3-vector [N m s] from a number or ``"hx,hy,hz"``.

    A planar system takes a scalar ``h`` (about the inertial z axis; ``0,0,h`` too, but nonzero
    ``hx, hy`` are refused, as its equations cannot use them); a spatial one takes ``0`` for
    ``0,0,0`` (a system that started at rest). ``"unknown"`` (or None) gives None: a
    constant momentum estimated with the parameters.
    """
    if value is None or str(value).strip().lower() == "unknown":
        return None
    try:
        parts = [float(v) for v in str(value).split(",")] if not np.ndim(value) else [float(v) for v in value]
    except ValueError:
        raise SpaceidError(f"`momentum`: '{value}' is not a number or a list hx,hy,hz [N m s]") from None
    if len(parts) == 1 and (planar or parts[0] == 0):
        parts = [0.0, 0.0, parts[0]]
    if len(parts) != 3 or not np.all(np.isfinite(parts)):
        single = "h or " if planar else "0 or "
        raise SpaceidError(f"`momentum`: expected {single}hx,hy,hz (finite, N m s), got '{value}'")
    if planar and any(parts[:2]):  # they would be ignored by the equations, yet kept in the result
        raise SpaceidError(f"`momentum`: '{value}' has in-plane components hx, hy, but a planar model carries only "
                           f"the momentum about z: give `momentum` {parts[2]:g}")
    return np.array(parts)


def parse_known(items) -> dict:
    """``NAME=VALUE`` strings (the command line's ``--known``) as ``{name: value}``; a name given twice is refused."""
    known = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        try:
            number = float(value)
        except ValueError:
            number = np.nan
        if not sep or not name.strip() or not np.isfinite(number):
            raise SpaceidError(f"`known`: '{item}' is not NAME=VALUE with a finite number (e.g. Iczz_wheel=0.00197)")
        if name.strip() in known:
            raise SpaceidError(f"`known`: {name.strip()} is given twice ({known[name.strip()]:g} and {number:g}): "
                               "give each anchor once")
        known[name.strip()] = number
    return known


_EXAMPLES = {"torque": "1e-4", "viscous": "5e-4", "coulomb": "1e-3"}
"""A value of each drift kind for the examples of the messages (spatial torque: ``0:0:1e-4``)."""


def parse_drift(value, *, planar: bool, values: bool, command: str = "this command"):
    """``--drift``: one comma list for every command, where a bare ``KIND`` is a drift term to
    estimate and ``KIND=VALUE`` one set to that value; ``none`` alone: no drift terms.

    ``values=False`` (a command that estimates the drift: identify, payload, monitor, experiment)
    returns the kinds as :func:`spaceid.estimation.identify` takes them (``()`` for ``none``);
    ``values=True`` (one that sets it: simulate, predict, validate) returns the terms as
    :func:`spaceid.motion.simulate` takes them (``none``: every term zero, which replaces a
    result's own). The form ``command`` cannot use is refused, naming it and the fix. A spatial
    torque is ``torque=TX:TY:TZ`` [N m] (or ``torque_x=..`` per axis); empty or None gives ``()``
    or ``{}``."""
    if value is None or not str(value).strip():
        return {} if values else ()
    items = [item.strip() for item in str(value).split(",") if item.strip()]
    if [item.lower() for item in items] == ["none"]:
        return drift_terms(dict.fromkeys(DRIFT_KINDS, 0.0), planar) if values else ()
    bare = [item for item in items if "=" not in item]
    if values and bare:
        kinds = check_drift_kinds(bare)
        example = ",".join(f"{k}={'0:0:' if k == 'torque' and not planar else ''}{_EXAMPLES[k]}" for k in kinds)
        raise SpaceidError(f"`drift`: '{','.join(bare)}' gives no value: {command} needs one, e.g. `drift` {example}")
    if not values:
        given = [item for item in items if "=" in item]
        if given:
            names = [item.partition("=")[0].strip().lower() for item in items]
            kinds = ",".join(dict.fromkeys("torque" if n.startswith("torque_") else n for n in names))
            raise SpaceidError(f"`drift`: '{','.join(given)}' gives a value: {command} estimates the drift terms and "
                               f"cannot hold them fixed: give the kind alone, e.g. `drift` {kinds}")
        return check_drift_kinds(items)
    terms = {}
    for item in items:
        name, _, number = item.partition("=")
        try:
            parsed = [float(v) for v in number.split(":")]
        except ValueError:
            parsed = []
        if not name.strip() or not parsed:
            raise SpaceidError(f"`drift`: '{item}' is not KIND=VALUE with a number (e.g. `drift` torque=1e-4,"
                               "viscous=5e-5; a spatial torque as torque=TX:TY:TZ)")
        terms[name.strip()] = parsed[0] if len(parsed) == 1 else parsed
    return drift_terms(terms, planar, where="`drift`")
