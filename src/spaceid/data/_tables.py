"""CSV tables and the checks shared by the log readers (CSV files and ROS bags).

Each check turns a defect into a one-line :class:`~spaceid.SpaceidError` that names the file, the
line or column, and the fix.
"""

from __future__ import annotations

import csv
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import SpaceidError, shown
from .._inputs import MiB, count_input_lines, read_input_text
from .._memory import require_memory
from ._timeseries import first_unordered

_MAX_ANGLE = 20 * math.pi  # [rad]; ten turns over a run means the column is in degrees
_MAX_RATE = 100.0  # [rad/s]; arm joints and the base; above it the column is likely deg/s
_GAP = 10.0  # a step this many times the median one is a gap (dropped samples), worth a warning
_MAX_WHEEL_RATE = 1000.0  # [rad/s]; reaction wheels spin at a few hundred rad/s
_IMPOSSIBLE_RATE = 1e6  # [rad/s or m/s]; beyond any rotor or actuator: an error
_QUAT_WARN = 1e-6  # |norm - 1| above which a quaternion is renormalised, with a warning
_QUAT_FAIL = 1e-2  # |norm - 1| above which it is not a unit quaternion at all

MAX_TABLE_BYTES = 4096 * MiB
"""Largest CSV table read [bytes]: 10^8 cells of 40 characters."""
TABLE_COPIES = 8
"""Float copies of a CSV table's cells that reading a log holds at its peak (the table, the log's
arrays, their checks), 8 bytes each: the memory asked of the machine before a table is read
(measured: 11 million rows of 7 columns peaked at 4.8 GB, about 8 copies)."""
BLOCK_ROWS = 4096
"""Rows of a CSV table parsed at a time: only their text is held (~11 MB for 36 columns of 17 digits)."""
MAX_TEXT_BYTES = 256 * MiB
"""Largest other text input read [bytes] (JSON results and trajectories, mapping files)."""

_PLANAR_BASE = (("base_yaw",), ("base_wz",))
_SPATIAL_BASE = (("base_qw", "base_qx", "base_qy", "base_qz"), ("base_wx", "base_wy", "base_wz"))



@dataclass(frozen=True)
class _Table:
    """A rectangular CSV: its header names, its cells as floats, the file line of each row, and
    the first cell of each column that is not a number.

    Attributes
    ----------
    path : str
    header : list of str
        Column names, shape (n_cols,).
    values : ndarray of shape (n_cols, n_rows)
        The cells, one column a row (contiguous); not to be used in a column with an entry in ``text``.
    lines : ndarray of int, shape (n_rows,)
        The file line of each row (1 for the first line of the file).
    text : dict
        Column index -> (row index, cell) of the column's first cell that is not a number.
    """

    path: str
    header: list
    values: np.ndarray
    lines: np.ndarray
    text: dict


def _folder_hint(path):
    """For messages on a folder given as a file: what it holds, when it looks like a damaged ROS 2 bag."""
    folder = Path(path)
    if not folder.is_dir():
        return ""
    try:
        storage = next((f for f in folder.iterdir() if f.suffix.lower() in (".db3", ".mcap")), None)
    except OSError:
        storage = None
    return (f": it holds {storage.name} but no metadata.yaml, which a ROS 2 bag folder needs: restore it "
            "(`ros2 bag reindex` rebuilds it)" if storage else
            ": give the file itself, or a ROS 2 bag folder (with metadata.yaml)")


def _read_text(path, what, max_bytes=None):
    """The text of a user file within bounds (:func:`~spaceid._inputs.read_input_text`); a folder
    without ``metadata.yaml`` gets a hint when it looks like a damaged ROS 2 bag."""
    return read_input_text(path, what, MAX_TEXT_BYTES if max_bytes is None else max_bytes,
                           folder_hint=_folder_hint(path))


def _read_csv(path, *, what, block_rows=None):
    """The :class:`_Table` of the CSV file ``path``, parsed ``block_rows`` rows at a time
    (default :data:`BLOCK_ROWS`) into float arrays sized from a first count of the lines, so that
    only one block's text is held.

    Defects of the structure (malformed CSV, a header naming a column twice, a row whose fields do
    not match the header) are reported at the first in the file; cells that are not numbers when
    their column is read (:func:`_column`).
    """
    n_lf, n_cr = count_input_lines(path, what, MAX_TABLE_BYTES, folder_hint=_folder_hint(path))
    n_lines = max(n_lf, n_cr)  # "\r\n", "\n" or "\r" ends
    # errors="replace": the bytes were checked to be UTF-8 above; a file changed since reads as not numbers
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as f:
        reader = csv.reader(f)
        try:
            row = next((row for row in reader if row), None)  # blank lines carry no sample
            if row is None:
                raise SpaceidError(f"{path}: the {what} file is empty: expected a header row and data rows")
            header = _names(path, row)
            # no cap on the rows (a 1 kHz log of three hours has 1.1e7): what the machine can hold
            require_memory(8.0 * TABLE_COPIES * n_lines * len(header), f"{path}: {n_lines} lines of {len(header)} "
                           "columns", "split the run, downsample it or drop columns")
            # an upper bound of the rows whatever the line ends; pages never filled are never resident
            values, lines = np.empty((len(header), n_lf + n_cr + 1)), np.empty(n_lf + n_cr + 1, dtype=np.int64)
            n, text = 0, {}
            for block in _blocks(path, reader, header, block_rows or BLOCK_ROWS):
                k = len(block.lines)
                if n + k > len(lines):
                    raise SpaceidError(f"{path}: the {what} grew while it was read: read it once it is complete")
                values[:, n : n + k], lines[n : n + k] = block.values, block.lines
                text |= {j: (n + i, cell) for j, (i, cell) in block.text.items() if j not in text}
                n += k
        except csv.Error as err:
            raise _malformed(path, reader.line_num, err) from None
    if not n:
        raise SpaceidError(f"{path}: the {what} has a header but no data rows: give at least one sample")
    return _Table(str(path), header, values[:, :n], lines[:n], text)


def _names(path, row):
    """The column names of the header ``row``, each once."""
    header = [name.strip() for name in row]  # cells keep theirs: float() ignores it
    seen = set()
    for name in header:
        if name in seen:
            raise SpaceidError(f"{path}: column {shown(name)} appears twice in the header: rename or drop one")
        seen.add(name)
    return header


def _malformed(path, line, err):
    return SpaceidError(f"{path}: line {line}: malformed CSV ({err}): fix the file")


def _blocks(path, reader, header, size, first_line=0):
    """:class:`_Table` blocks of at most ``size`` rows of the csv ``reader`` after the header,
    blank lines skipped; a row whose fields do not match the header is an error. Line numbers
    count from ``first_line`` (the lines read before ``reader``'s)."""
    while True:
        rows, lines = [], []
        for row in reader:
            if not row:
                continue
            if len(row) != len(header):
                raise SpaceidError(
                    f"{path}: line {first_line + reader.line_num} has {len(row)} fields but the header has "
                    f"{len(header)}: give one value per column on every row"
                )
            rows.append(row)
            lines.append(first_line + reader.line_num)
            if len(rows) == size:
                break
        if not rows:
            return
        values, text = _floats(rows, len(header))
        yield _Table(str(path), header, values.T, np.array(lines, dtype=np.int64), text)


def _floats(rows, n_cols):
    """The cells of ``rows`` (lists of ``n_cols`` strings) as floats (n_rows, n_cols), NaN down a
    column with a cell that is not a number, and the first such cell of each, {column: (row, cell)}."""
    try:
        return np.array(rows, dtype=float), {}
    except ValueError:  # a text column (ignored unless needed) or a defect: column by column
        pass
    values, text = np.empty((len(rows), n_cols)), {}
    for j in range(n_cols):
        cells = [row[j] for row in rows]
        try:
            values[:, j] = np.array(cells, dtype=float)
        except ValueError:
            i = next((i for i, cell in enumerate(cells) if not _is_float(cell)), 0)
            values[:, j], text[j] = np.nan, (i, cells[i])
    return values, text


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
    """The column ``name`` as finite floats, shape (n_rows,): a view into the table (copy what is kept,
    or the whole table stays in memory)."""
    j = table.header.index(name)
    if j in table.text:
        i, cell = table.text[j]
        raise SpaceidError(
            f"{table.path}: line {table.lines[i]}, column '{name}': {shown(cell.strip())} is not a number: "
            "give plain decimal numbers"
        )
    x = table.values[j]
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
            f"{table.path}: a gap of {steps[i - 1]:.3g} s before line {table.lines[i]} "
            f"({steps[i - 1] / np.median(steps):.0f} "
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
    out = np.empty((n, len(names)))  # filled column by column: one copy of the data, not two
    for k, name in enumerate(names):
        out[:, k] = values[name] if name in values else fill
    return out


def _is_rate(name):
    return name.startswith(("qd_", "base_w"))


def _is_float(text):
    try:
        float(text)
    except ValueError:
        return False
    return True
