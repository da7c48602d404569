"""JSON text of results and records: NumPy values made plain, containers indented, a list of numbers
on one line (a matrix one row a line)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import orjson

__all__ = ["json_line", "json_text", "json_values"]


def json_text(obj) -> str:
    """JSON text of ``obj`` (:func:`json_values` first): containers indented by two spaces, a list of
    scalars on one line, so a 496-parameter covariance reads row by row."""
    return _indented(json_values(obj))


def json_line(obj) -> str:
    """Compact JSON text of ``obj`` on one line (:func:`json_values` first)."""
    return _line(json_values(obj))


def _indented(obj, level: int = 0) -> str:
    """JSON text of plain ``obj`` (:func:`json_values`'s: its only containers are ``dict`` and ``list``):
    containers indented by two spaces, a list of scalars on one line (:func:`_line`: the indenting encoder
    is pure Python)."""
    pad, inner = "  " * level, "  " * (level + 1)
    if isinstance(obj, dict) and obj:
        items = (f"{inner}{_line(k)}: {_indented(v, level + 1)}" for k, v in obj.items())
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(obj, list) and not set(map(type, obj)).isdisjoint((dict, list)):  # types at C speed: rows of 496
        return "[\n" + ",\n".join(inner + _indented(v, level + 1) for v in obj) + f"\n{pad}]"
    return _line(obj)


def _line(obj) -> str:
    """Compact JSON text of plain ``obj`` (a scalar, a row of numbers): orjson's (a 496-parameter covariance in 0.007 s,
    ``json.dumps`` 0.12 s), ``json.dumps``'s for an integer beyond 64 bits (a seed's entropy), which
    orjson refuses."""
    try:
        return orjson.dumps(obj).decode()
    except TypeError:
        return json.dumps(obj, allow_nan=False)


def json_values(obj):
    """``obj`` with NumPy types, paths and non-finite floats turned into JSON values. Arrays of finite
    numbers and lists of finite floats are taken whole (a value at a time, the 496-parameter
    servicer's covariance took 0.2 s of CPU)."""
    if isinstance(obj, dict):
        return {str(k): json_values(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        whole = obj.dtype.kind in "iub" or (obj.dtype.kind == "f" and bool(np.isfinite(obj).all()))
        return obj.tolist() if whole else json_values(obj.tolist())
    if type(obj) is list and set(map(type, obj)) <= {float} and all(map(math.isfinite, obj)):
        return list(obj)
    if isinstance(obj, (list, tuple)):
        return [json_values(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj
