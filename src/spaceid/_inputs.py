"""Reading an input file's text within bounds: a regular file, at most a stated size, UTF-8.

Every reader of user files (models, logs, JSON, mappings) goes through :func:`read_input_text`
(a log CSV, parsed in blocks, through :func:`count_input_lines` first), so that ``/dev/zero``, a
folder or a file of gigabytes is refused with one line before anything is parsed, instead of
hanging or ending in MemoryError.
"""

from __future__ import annotations

import codecs
import os
import stat
from ._errors import SpaceidError

__all__ = ["read_input_text", "input_size", "count_input_lines", "MiB"]

MiB = 1 << 20
READ_BLOCK = MiB
"""Bytes read at a time by :func:`count_input_lines`."""


def input_size(path, what: str, max_bytes: int, *, folder_hint: str = "") -> int:
    """The size [bytes] of the regular file ``path``, checked to be at most ``max_bytes``.

    Parameters are those of :func:`read_input_text`, which states the errors (but UTF-8).
    """
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise SpaceidError(f"{path}: no such file (expected a {what}): check the path") from None
    except OSError as err:
        raise SpaceidError(f"{path}: cannot read the {what} ({err.strerror or err}): check the path") from None
    if stat.S_ISDIR(info.st_mode):
        raise SpaceidError(f"{path}: is a folder, not a {what} file{folder_hint or ': give the file inside it'}")
    if not stat.S_ISREG(info.st_mode):
        raise SpaceidError(f"{path}: not a regular file (a device or pipe): give the {what} as a file")
    if info.st_size > max_bytes:
        raise SpaceidError(
            f"{path}: {info.st_size / MiB:.1f} MiB, beyond the {max_bytes / MiB:.0f} MiB a {what} may have: "
            "is this the right file? (split or downsample it)"
        )
    return info.st_size


def read_input_text(path, what: str, max_bytes: int, *, folder_hint: str = "") -> str:
    """The text of the regular file ``path`` (UTF-8, a leading byte-order mark dropped).

    Parameters
    ----------
    path : str or Path
    what : str
        What the file should be ("log", "model file"), for messages.
    max_bytes : int
        Largest size accepted [bytes]; larger files are refused before reading.
    folder_hint : str
        Appended to the message when ``path`` is a folder (say what such a folder lacks).

    Raises
    ------
    SpaceidError
        Missing, a folder, not a regular file (a device, a pipe), beyond ``max_bytes``,
        unreadable or not UTF-8; the message names ``path`` and the fix.
    """
    input_size(path, what, max_bytes, folder_hint=folder_hint)
    try:
        with open(path, "rb") as handle:
            data = handle.read(max_bytes + 1)  # the file may have grown since stat
    except OSError as err:
        raise _unreadable(path, what, err) from None
    if len(data) > max_bytes:
        raise _grown_beyond(path, what, max_bytes)
    try:
        # utf-8-sig: spreadsheet exports often start with a byte-order mark.
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise _not_utf8(path, what, err.start) from None


def count_input_lines(path, what: str, max_bytes: int, *, folder_hint: str = "") -> tuple:
    """The line ends of the file ``path``, read in blocks of ``READ_BLOCK`` bytes, checked as
    :func:`read_input_text` checks it (the byte that is not UTF-8 counted from the file's start).

    Returns
    -------
    (int, int)
        The numbers of ``"\\n"`` and of ``"\\r"`` characters.
    """
    input_size(path, what, max_bytes, folder_hint=folder_hint)
    decoder = codecs.getincrementaldecoder("utf-8")()
    n_lf = n_cr = done = 0
    try:
        with open(path, "rb") as handle:
            while block := handle.read(READ_BLOCK):
                held = len(decoder.getstate()[0])  # bytes of a character cut by the previous block
                try:
                    decoder.decode(block)
                except UnicodeDecodeError as err:
                    raise _not_utf8(path, what, done - held + err.start) from None
                n_lf, n_cr, done = n_lf + block.count(b"\n"), n_cr + block.count(b"\r"), done + len(block)
                if done > max_bytes:
                    raise _grown_beyond(path, what, max_bytes)
    except OSError as err:
        raise _unreadable(path, what, err) from None
    try:
        decoder.decode(b"", final=True)
    except UnicodeDecodeError:
        raise _not_utf8(path, what, done - len(decoder.getstate()[0])) from None
    return n_lf, n_cr


def _unreadable(path, what, err):
    return SpaceidError(f"{path}: cannot read the {what} ({err.strerror or err}): check the path and permissions")


def _grown_beyond(path, what, max_bytes):
    return SpaceidError(f"{path}: beyond the {max_bytes / MiB:.0f} MiB a {what} may have: is this the right file?")


def _not_utf8(path, what, at):
    return SpaceidError(f"{path}: not a UTF-8 text file (byte {at} cannot be decoded): expected a {what}")
