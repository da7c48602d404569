"""A log CSV that is still being written: its rows as they are appended (``spaceid monitor --follow``)."""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from ._files import _table_log
from ._tables import BLOCK_ROWS, _blocks, _malformed, _names

__all__ = ["follow_log"]

READ_BYTES = 1 << 20
"""Most bytes read from the file at a time: bounds the memory however fast the file grows."""


def _wait(f, timeout: float, poll: float) -> str:
    """The next text of ``f`` (at most ``READ_BYTES``), waiting up to ``timeout`` seconds; ``""`` when none came."""
    deadline = time.monotonic() + timeout
    while True:
        text = f.read(READ_BYTES)
        if text or time.monotonic() >= deadline:
            return text
        time.sleep(poll)


def follow_log(path, *, joints, planar, wheels=(), timeout: float = 10.0, poll: float = 0.05):
    """Yield the rows of a log CSV as they are appended, until none came for ``timeout`` seconds.

    The file may start empty or hold only part of its header; a row counts once its line ends.
    Each yield is a :class:`~spaceid.data.Log` of the rows complete so far (one or more), checked
    as :func:`read_log` checks a whole file (rates are required), stamps increasing across yields.

    Parameters
    ----------
    path : str or Path
        The CSV file being written (layout as for :func:`read_log`).
    joints : sequence of str
        Model joint names, the column order of ``q`` and ``qd``.
    planar : bool
        Planar (``base_yaw``, ``base_wz``) or spatial columns.
    wheels : sequence of str
        Reaction-wheel joints, exempt from the degrees check on angles.
    timeout : float
        Seconds without a new row after which the log counts as finished.
    poll : float
        Seconds between looks at the file.

    Yields
    ------
    Log
        The newly appended rows, each ``Log`` of shape ``(n_new, ...)``.

    Raises
    ------
    SpaceidError
        The file does not appear within ``timeout``; a bad header, row or value (as :func:`read_log`,
        naming the line); stamps that do not increase from one yield to the next.
    """
    joints, path = tuple(joints), Path(path)
    deadline = time.monotonic() + timeout
    while not path.is_file():
        if time.monotonic() >= deadline:
            raise SpaceidError(f"{path}: no such file after waiting {timeout:g} s (`timeout`): start the "
                               "recording first or give the right path")
        time.sleep(poll)
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as f:
        header, pending, line, last = None, "", 0, -np.inf
        while True:
            text = _wait(f, timeout, poll)
            if not text:
                if header is None:
                    raise SpaceidError(f"{path}: no header row within {timeout:g} s (`timeout`): the log must "
                                       "start with a header naming the columns")
                return
            complete, newline, pending = (pending + text).rpartition("\n")
            if not newline:  # no line complete yet: all of it is pending
                continue
            reader = csv.reader(io.StringIO(complete + newline, newline=""))
            try:
                if header is None:  # blank lines may come first
                    row = next((row for row in reader if row), None)
                    header = _names(path, row) if row else None
                for table in _blocks(path, reader, header, BLOCK_ROWS, line) if header else ():
                    log = _table_log(table, joints, planar, True, wheels)
                    if not log.t[0] > last:
                        raise SpaceidError(f"{path}: time stamps must increase strictly, but t = {log.t[0]!r} at line "
                                           f"{table.lines[0]} follows t = {last!r}: the writer went back in time")
                    last = float(log.t[-1])
                    yield log
            except csv.Error as err:
                raise _malformed(path, line + reader.line_num, err) from None
            line += reader.line_num
