"""Logs, joint trajectories and results on disk: CSV and JSON, validated on the way in.

A log CSV has a header row and one row per sample; column order is free and columns that are
not needed are ignored. Units are SI and angles are radians:

- ``t`` [s], strictly increasing;
- planar: ``base_yaw`` [rad] and ``base_wz`` [rad/s];
- spatial: ``base_qw, base_qx, base_qy, base_qz``, the scalar-first unit quaternion of the
  base-to-inertial rotation, and ``base_wx, base_wy, base_wz`` [rad/s] in base axes;
- for every model joint ``J``: ``q_J`` [rad or m] and ``qd_J`` [rad/s or m/s];
- optional, the base position (origin of the base frame, inertial frame) [m]: planar
  ``base_x, base_y``, spatial ``base_px, base_py, base_pz`` (all of them or none);
- optional, the joint efforts ``tau_J`` [N m or N] (every joint or none).

Readers turn every defect into a one-line :class:`~spaceid.SpaceidError` that names the file,
the column and line where relevant, and the fix. Writers replace files atomically, so a failed
write leaves the old file (or none) and never a partial one.

Unit heuristics (a log in degrees is the commonest mistake, and silently wrong in radians):

- an angle column (``base_yaw`` or ``q_J``) with a magnitude above ``20*pi`` (ten turns) is
  taken to be in degrees and is an error; reaction wheels (``wheels=``) are exempt since their
  angle grows without bound;
- a rate above 100 rad/s (1000 rad/s for a reaction wheel, which may spin at ~300 rad/s) only
  warns, as fast rates are unusual rather than impossible; above 1e6 rad/s it is an error.

Plausibility checks (:func:`spaceid.data._signal_checks.plausibility_warnings`) then compare each
angle's change with its rate's integral: stamps in ms, rates in deg/s, swapped columns or a
quaternion stored x, y, z, w give a warning naming the columns (stamps in ns an error).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from .._atomic import atomic_path, write_text_atomic
from .._errors import SpaceidError
from .._json import json_text
from . import _bags as bags
from ._tables import (_read_text, _read_csv, _check_joint_columns, _require, _column, _check_time, _check_angles,
                      _check_rates, _unit_quaternions, _stack, _is_rate, _PLANAR_BASE, _SPATIAL_BASE)
from ._signal_checks import plausibility_warnings
from ._timeseries import Log, yaw_to_quat

__all__ = ["read_log", "write_log", "read_joint_trajectory", "write_json", "read_json"]

def read_log(path, *, joints, planar, require_rates=True, wheels=(), bag_options=None) -> Log:
    """Read and validate a log CSV, or a ROS bag (``.bag``, ``.mcap``, a ROS 2 bag folder).

    Parameters
    ----------
    path : str or Path
        The CSV file (layout in the module docstring). It is only read.
    joints : sequence of str
        Model joint names, in the order of the columns of ``q`` and ``qd``.
    planar : bool
        Read ``base_yaw, base_wz`` (True) or the base quaternion and 3 rates (False).
    require_rates : bool, default True
        When False, missing ``qd_J`` and base-rate columns are allowed; the missing arrays are
        filled with NaN (for differentiation later) and ``meta["rates"]`` is ``"missing"``.
    wheels : sequence of str, default ()
        Reaction-wheel joints (``model.wheels``), exempt from the degrees check on angles.
    bag_options : dict, optional
        For a bag (:func:`spaceid.data.is_bag`), keywords of :func:`spaceid.data.read_bag_log`
        (``joint_topic``, ``pose_topic``, ``mapping``, alignment and differentiator settings;
        None values are ignored): the bag is time-aligned and its rates computed there, so
        ``require_rates`` does not apply. For a CSV, topics or a mapping are an error.

    Returns
    -------
    Log
        ``t`` of shape (n_samples,) [s]; ``q``, ``qd`` of shape (n_samples, n_joints);
        ``base_quat`` (n_samples, 4) scalar first; ``base_w`` (n_samples, 3) [rad/s] in base
        axes (``[0, 0, wz]`` for a planar log, all NaN if the base rate is missing).
        ``meta`` holds ``source`` (the path), ``columns`` (the header), ``plausibility`` (the
        warnings of :func:`spaceid.data._signal_checks.plausibility_warnings`, also issued) and,
        when rates are missing, ``rates = "missing"`` and ``missing_rates`` (the absent columns).

    Raises
    ------
    SpaceidError
        Missing or unreadable file; a CSV beyond ``MAX_TABLE_BYTES`` or whose cells (8 bytes each
        as floats, ``TABLE_COPIES`` copies: :mod:`spaceid.data._tables`, parsed in blocks of rows)
        would not fit in the available memory; empty file or no data rows; missing required columns;
        a ``q_X``/``qd_X`` column for a joint X the model lacks; non-numeric, NaN or infinite
        cells; time stamps not strictly increasing; angles apparently in degrees; a base
        quaternion whose norm departs from 1 by more than 1e-2; a median time step above a day
        (stamps in ns or us).

    Warns
    -----
    UserWarning
        A base quaternion whose norm departs from 1 by more than 1e-6 (it is normalised),
        implausibly fast rates, or a plausibility warning: stamps that look like milliseconds, an
        angle column that does not follow its rate column (swapped or mislabelled columns, a
        quaternion stored x, y, z, w) or follows it only after a telling factor (deg/s, degrees).
    """
    if bags.is_bag(path):
        return bags.read_bag_log(path, joints=joints, planar=planar, wheels=wheels, **(bag_options or {}))
    given = [k for k in ("joint_topic", "pose_topic", "mapping", "base_rate", "window")
             if (bag_options or {}).get(k) is not None]
    if given and not Path(path).is_dir():  # a folder gets the message of what it lacks to be a bag
        raise SpaceidError(
            f"{path}: {', '.join(given)} apply to ROS bags, but this is a CSV log: drop them or give a bag "
            "(.bag, .mcap or a ROS 2 bag folder)"
        )
    return _table_log(_read_csv(path, what="log"), tuple(joints), planar, require_rates, wheels)


def _table_log(table, joints: tuple, planar: bool, require_rates: bool, wheels) -> Log:
    """The :class:`Log` of a log CSV's ``table``, every column checked (see :func:`read_log`)."""
    path = table.path
    _check_joint_columns(table, joints)
    base_angles, base_rates = _PLANAR_BASE if planar else _SPATIAL_BASE
    angles = ("t", *base_angles, *(f"q_{j}" for j in joints))
    rates = (*base_rates, *(f"qd_{j}" for j in joints))
    _require(table, angles + rates if require_rates else angles, planar=planar)

    values = {name: _column(table, name) for name in angles + rates if name in table.header}
    _check_time(table, values["t"])
    _check_angles(table, values, ("base_yaw", *(f"q_{j}" for j in joints if j not in wheels)))
    _check_rates(table, values, base_rates, joints, wheels)

    n = len(values["t"])
    nan = np.full(n, np.nan)
    meta = {"source": str(path), "columns": list(table.header)}
    missing = [name for name in rates if name not in values]
    if missing:
        meta.update(rates="missing", missing_rates=missing)

    if planar:
        base_quat = yaw_to_quat(values["base_yaw"])
        if "base_wz" in values:
            base_w = np.zeros((n, 3))
            base_w[:, 2] = values["base_wz"]
        else:  # an unknown wz leaves the whole vector unknown, not half-filled with zeros
            base_w = np.full((n, 3), np.nan)
    else:
        base_quat = _unit_quaternions(table, _stack(values, base_angles, n))
        base_w = _stack(values, base_rates, n, fill=nan)
    log = Log(
        **_optional_columns(table, joints, planar, n),
        t=values["t"].copy(),  # the other columns are copied by _stack
        joints=joints,
        q=_stack(values, [f"q_{j}" for j in joints], n),
        qd=_stack(values, [f"qd_{j}" for j in joints], n, fill=nan),
        base_quat=base_quat,
        base_w=base_w,
        planar=bool(planar),
        meta=meta,
    )
    meta["plausibility"] = plausibility_warnings(log, str(path), wheels)
    for text in meta["plausibility"]:
        warnings.warn(text, stacklevel=2)
    return log


def write_log(path, log: Log) -> None:
    """Write ``log`` as a CSV that :func:`read_log` reads back, atomically.

    Columns: ``t``, then ``base_yaw, base_wz`` (planar; the yaw unwrapped, continuous) or
    ``base_qw, base_qx, base_qy, base_qz, base_wx, base_wy, base_wz`` (spatial), then ``q_J``
    and ``qd_J`` for every joint, then the base position and ``tau_J`` when the log has them.
    Values are written with 17 significant digits, so every float
    reads back bit for bit. Rate columns that are entirely NaN (rates not yet known) are left
    out, so the file reads back with ``require_rates=False``.

    Raises
    ------
    SpaceidError
        The log holds NaN or infinite values elsewhere, or the file cannot be written.
    """
    if log.planar:
        base = {"base_yaw": log.base_yaw, "base_wz": log.base_w[:, 2]}
    else:
        base = {f"base_q{c}": log.base_quat[:, i] for i, c in enumerate("wxyz")}
        base |= {f"base_w{c}": log.base_w[:, i] for i, c in enumerate("xyz")}
    columns = {"t": log.t, **base}
    columns |= {f"q_{j}": log.q[:, k] for k, j in enumerate(log.joints)}
    columns |= {f"qd_{j}": log.qd[:, k] for k, j in enumerate(log.joints)}
    columns |= _optional_values(log)
    columns = {
        name: np.asarray(x, dtype=float)
        for name, x in columns.items()
        if not (_is_rate(name) and np.isnan(x).all() and len(x))
    }
    bad = [name for name, x in columns.items() if not np.isfinite(x).all()]
    if bad:
        raise SpaceidError(
            f"{path}: the log holds NaN or infinite values in {', '.join(bad)}: "
            "a log CSV must be finite; fill or drop those samples before writing"
        )
    data = np.column_stack(list(columns.values()))
    try:
        with atomic_path(path) as tmp:
            np.savetxt(tmp, data, fmt="%.17g", delimiter=",", header=",".join(columns), comments="")
    except OSError as err:
        raise SpaceidError(
            f"{path}: cannot write the log ({err.strerror or err}): check the path is writable"
        ) from None


def _position_names(planar):
    return ("base_x", "base_y") if planar else ("base_px", "base_py", "base_pz")


def _optional_columns(table, joints, planar, n) -> dict:
    """``base_position`` (n, 3) and ``tau`` (n, n_joints) from their optional columns, or None."""
    out = {}
    for key, names in (("base_position", _position_names(planar)), ("tau", [f"tau_{j}" for j in joints])):
        given = [name for name in names if name in table.header]
        if given and len(given) < len(names):
            missing = ", ".join(name for name in names if name not in given)
            raise SpaceidError(f"{table.path}: column(s) {', '.join(given)} without {missing}: give all of "
                               f"{', '.join(names)} or none")
        out[key] = _stack({name: _column(table, name) for name in given}, names, n) if given else None
    if out["base_position"] is not None and planar:
        out["base_position"] = np.column_stack([out["base_position"], np.zeros(n)])
    return out


def _optional_values(log: Log) -> dict:
    """The optional columns of ``log`` (base position, efforts) by CSV name."""
    out = {}
    if log.base_position is not None:
        out |= {name: log.base_position[:, i] for i, name in enumerate(_position_names(log.planar))}
    if log.tau is not None:
        out |= {f"tau_{j}": log.tau[:, k] for k, j in enumerate(log.joints)}
    return out


def read_joint_trajectory(path, *, joints, wheels=()):
    """Read a joint-trajectory CSV (columns ``t``, ``q_J``, ``qd_J``), e.g. for prediction.

    Validation is that of :func:`read_log`; other columns are ignored.

    Parameters
    ----------
    path : str or Path
    joints : sequence of str
        Model joint names, the column order of ``q`` and ``qd``.
    wheels : sequence of str, default ()
        Reaction-wheel joints, exempt from the degrees check on angles.

    Returns
    -------
    t : ndarray of shape (n_samples,)
        Time [s], strictly increasing.
    q : ndarray of shape (n_samples, n_joints)
        Joint positions [rad or m].
    qd : ndarray of shape (n_samples, n_joints)
        Joint rates [rad/s or m/s].
    """
    joints = tuple(joints)
    table = _read_csv(path, what="joint trajectory")
    _check_joint_columns(table, joints)
    q_names = [f"q_{j}" for j in joints]
    qd_names = [f"qd_{j}" for j in joints]
    _require(table, ["t", *q_names, *qd_names], planar=None)
    values = {name: _column(table, name) for name in ["t", *q_names, *qd_names]}
    _check_time(table, values["t"])
    _check_angles(table, values, [f"q_{j}" for j in joints if j not in wheels])
    _check_rates(table, values, (), joints, wheels)
    n = len(values["t"])
    return values["t"].copy(), _stack(values, q_names, n), _stack(values, qd_names, n)


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON, atomically.

    NumPy arrays become (nested) lists, NumPy scalars Python numbers, paths strings, and NaN or
    infinite floats ``null`` (JSON has no NaN). Lists of numbers stay on one line, a matrix
    one row a line (:func:`spaceid._json.json_text`).
    """
    try:
        write_text_atomic(path, json_text(obj) + "\n")
    except OSError as err:
        raise SpaceidError(
            f"{path}: cannot write ({err.strerror or err}): check the path is writable"
        ) from None


def read_json(path, *, what="JSON file"):
    """Read a JSON file; ``what`` names it in error messages (e.g. ``"result"``).

    Raises
    ------
    SpaceidError
        As :func:`~spaceid._inputs.read_input_text` (a file beyond 256 MiB, not a regular file),
        invalid JSON, nesting deeper than Python's recursion limit, or an integer too long to
        convert (over 4300 digits).
    """
    text = _read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise SpaceidError(
            f"{path}: not a valid {what} (line {err.lineno}, column {err.colno}: {err.msg}): "
            "fix the JSON or write the file again"
        ) from None
    except RecursionError:
        raise SpaceidError(f"{path}: the {what} is nested too deeply to read: is this the right file?") from None
    except ValueError as err:  # an integer of thousands of digits
        raise SpaceidError(f"{path}: a value of the {what} cannot be read ({str(err)[:80]}): fix the JSON") from None


