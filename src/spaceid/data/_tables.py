"""CSV tables and the checks shared by the log readers (CSV files and ROS bags).

Each check turns a defect into a one-line :class:`~spaceid.SpaceidError` that names the file, the
line or column, and the fix.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import SpaceidError, shown
from .._inputs import MiB, read_input_text
from ._timeseries import first_unordered

_MAX_ANGLE = 20 * math.pi  # [rad]; ten turns over a run means the column is in degrees
_MAX_RATE = 100.0  # [rad/s]; arm joints and the base; above it the column is likely deg/s
_GAP = 10.0  # a step this many times the median one is a gap (dropped samples), worth a warning
_MAX_WHEEL_RATE = 1000.0  # [rad/s]; reaction wheels spin at a few hundred rad/s
_IMPOSSIBLE_RATE = 1e6  # [rad/s or m/s]; beyond any rotor or actuator: an error
_QUAT_WARN = 1e-6  # |norm - 1| above which a quaternion is renormalised, with a warning
_QUAT_FAIL = 1e-2  # |norm - 1| above which it is not a unit quaternion at all

MAX_TABLE_BYTES = 128 * MiB
"""Largest CSV table read [bytes]: ~16 min at 1 kHz with 7 columns of 17 digits (~2 GB of memory while read)."""
MAX_TABLE_ROWS = 1_000_000
"""Most rows of a CSV table (read whole: ~2 kB of memory a row while parsed)."""
MAX_TEXT_BYTES = 256 * MiB
"""Largest other text input read [bytes] (JSON results and trajectories, mapping files)."""

_PLANAR_BASE = (("base_yaw",), ("base_wz",))
_SPATIAL_BASE = (("base_qw", "base_qx", "base_qy", "base_qz"), ("base_wx", "base_wy", "base_wz"))



@dataclass(frozen=True)
class _Table:
    """A rectangular CSV: header names, cells as strings (n_rows, n_cols), file line per row."""

    path: str
    header: list
    cells: np.ndarray
    lines: list


def _read_text(path, what, max_bytes=None):
    """The text of a user file within bounds (:func:`~spaceid._inputs.read_input_text`); a folder
    without ``metadata.yaml`` gets a hint when it looks like a damaged ROS 2 bag."""
    folder, hint = Path(path), ""
    if folder.is_dir():
        try:
            storage = next((f for f in folder.iterdir() if f.suffix.lower() in (".db3", ".mcap")), None)
        except OSError:
            storage = None
        hint = (f": it holds {storage.name} but no metadata.yaml, which a ROS 2 bag folder needs: restore it "
                "(`ros2 bag reindex` rebuilds it)" if storage else
                ": give the file itself, or a ROS 2 bag folder (with metadata.yaml)")
    return read_input_text(path, what, MAX_TEXT_BYTES if max_bytes is None else max_bytes, folder_hint=hint)


def _read_csv(path, *, what):
    text = _read_text(path, what, MAX_TABLE_BYTES)
    rows_given = text.count("\n")
    if rows_given > MAX_TABLE_ROWS:
        raise SpaceidError(
            f"{path}: {rows_given} lines, beyond the {MAX_TABLE_ROWS} rows a {what} may have (it is read whole): "
            "split the run or downsample it"
        )
    reader = csv.reader(io.StringIO(text, newline=""))
    rows, lines = [], []
    try:
        for row in reader:
            if row:  # blank lines carry no sample
                rows.append(row)
                lines.append(reader.line_num)
    except csv.Error as err:
        raise SpaceidError(f"{path}: line {reader.line_num}: malformed CSV ({err}): fix the file") from None
    if not rows:
        raise SpaceidError(f"{path}: the {what} file is empty: expected a header row and data rows")
    header = [name.strip() for name in rows[0]]  # cells keep theirs: float() ignores it
    seen = set()
    for name in header:
        if name in seen:
            raise SpaceidError(f"{path}: column {shown(name)} appears twice in the header: rename or drop one")
        seen.add(name)
    if len(rows) == 1:
        raise SpaceidError(f"{path}: the {what} has a header but no data rows: give at least one sample")
    for row, line in zip(rows[1:], lines[1:]):
        if len(row) != len(header):
            raise SpaceidError(
                f"{path}: line {line} has {len(row)} fields but the header has {len(header)}: "
                "give one value per column on every row"
            )
    return _Table(str(path), header, np.array(rows[1:], dtype=str), lines[1:])


def _check_joint_columns(table, joints):
    for name in table.header:
        prefix = "q_" if name.startswith("q_") else "qd_" if name.startswith("qd_") else None
        if prefix and name[len(prefix):] not in joints:
            raise SpaceidError(
                f"{table.path}: joint {shown(name[len(prefix):])} in the log is not in the model "
                f"(joints: {', '.join(joints) or 'none'}): rename the column or use the matching model"
            )


def _require(table, names, *, planar):
    missing = [name for name in names if name not in table.header]
    if not missing:
        return
    hint = "; add them or correct the column names"
    if all(_is_float(name) for name in table.header):
        hint = "; the first line must be a header naming the columns"
    elif planar is True and "base_qw" in table.header:
        hint = "; the log looks spatial (base quaternion columns): use a spatial model"
    elif planar is False and "base_yaw" in table.header:
        hint = "; the log looks planar (base_yaw column): use a planar model"
    elif all(_is_rate(name) for name in missing):
        hint = "; give the rates or let spaceid differentiate the angles (require_rates=False)"
    raise SpaceidError(
        f"{table.path}: missing column(s) {', '.join(missing)} (header: {_listed(table.header)}){hint}"
    )


def _listed(names, most=20):
    """``names`` joined for a message, at most ``most`` of them (a hostile header has thousands)."""
    shown_names = [shown(n)[1:-1] for n in names[:most]]
    return ", ".join(shown_names) + (f", ... ({len(names)} in all)" if len(names) > most else "")


def _column(table, name):
    """The column ``name`` as finite floats, shape (n_rows,)."""
    raw = table.cells[:, table.header.index(name)]
    try:
        x = raw.astype(float)
    except ValueError:
        i = next((i for i, cell in enumerate(raw) if not _is_float(cell)), 0)
        raise SpaceidError(
            f"{table.path}: line {table.lines[i]}, column '{name}': {shown(str(raw[i]).strip())} is not a number: "
            "give plain decimal numbers"
        ) from None
    bad = ~np.isfinite(x)
    if bad.any():
        i = int(np.argmax(bad))
        raise SpaceidError(
            f"{table.path}: column '{name}' holds {x[i]} (first at line {table.lines[i]}): "
            "give finite numbers; fill or drop the gaps"
        )
    return x


def _check_time(table, t):
    unordered = first_unordered(t)
    if unordered:
        i = unordered[0]
        raise SpaceidError(
            f"{table.path}: time stamps must increase strictly, but t = {float(t[i])!r} at line "
            f"{table.lines[i]} follows t = {float(t[i - 1])!r}: sort the log or remove duplicate rows"
        )
    steps = np.diff(t)
    if steps.size and steps.max() > _GAP * np.median(steps):
        i = int(np.argmax(steps)) + 1
        warnings.warn(
            f"{table.path}: a gap of {steps[i - 1]:.3g} s before line {table.lines[i]} ({steps[i - 1] / np.median(steps):.0f} "
            "median steps): identification uses the samples as they are, but rates cannot be differentiated and "
            "validation re-simulates across it",
            stacklevel=3,
        )


def _check_angles(table, values, names):
    for name in names:
        peak = np.abs(values[name]).max() if name in values else 0.0
        if peak > _MAX_ANGLE:
            raise SpaceidError(
                f"{table.path}: column '{name}' reaches {peak:.4g}, beyond {_MAX_ANGLE:.4g} rad "
                "(ten turns): it seems to be in degrees; convert it to radians"
            )


def _check_rates(table, values, base_rates, joints, wheels):
    limits = {name: _MAX_RATE for name in base_rates}
    limits |= {f"qd_{j}": _MAX_WHEEL_RATE if j in wheels else _MAX_RATE for j in joints}
    for name, limit in limits.items():
        peak = np.abs(values[name]).max() if name in values else 0.0
        if peak > _IMPOSSIBLE_RATE:  # it would overflow the equations (inf noise levels, LinAlgError)
            raise SpaceidError(f"{table.path}: column '{name}' reaches {peak:.4g}, beyond the {_IMPOSSIBLE_RATE:g} "
                               "rad/s (or m/s) no robot reaches: check the column's units and values")
        if peak > limit:
            warnings.warn(
                f"{table.path}: column '{name}' reaches {peak:.4g} rad/s, "
                f"above {limit:g} rad/s: check that it is in rad/s, not deg/s",
                stacklevel=3,
            )


def _unit_quaternions(table, quat):
    """``quat`` (n, 4) checked to be unit and renormalised if slightly off."""
    norm = np.linalg.norm(quat, axis=1)
    error = np.abs(norm - 1)
    if error.max() > _QUAT_FAIL:
        i = int(np.argmax(error > _QUAT_FAIL))
        raise SpaceidError(
            f"{table.path}: line {table.lines[i]}: base quaternion (base_qw, base_qx, base_qy, "
            f"base_qz) has norm {norm[i]:.6g}, expected 1: give unit quaternions, scalar first"
        )
    if error.max() > _QUAT_WARN:
        warnings.warn(
            f"{table.path}: base quaternions depart from unit norm by up to {error.max():.2g}; "
            "normalised them",
            stacklevel=3,
        )
        return quat / norm[:, None]
    return quat


def _stack(values, names, n, fill=None):
    """Columns ``names`` of ``values`` side by side, shape (n, len(names)); absent -> ``fill``."""
    cols = [values[name] if name in values else fill for name in names]
    return np.ascontiguousarray(np.array(cols, dtype=float).reshape(len(names), n).T)


def _is_rate(name):
    return name.startswith(("qd_", "base_w"))


def _is_float(text):
    try:
        float(text)
    except ValueError:
        return False
    return True
