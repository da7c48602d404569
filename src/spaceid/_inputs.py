"""Reading an input file's text within bounds: a regular file, at most a stated size, UTF-8.

Every reader of user files (models, logs, JSON, mappings) goes through :func:`read_input_text`,
so that ``/dev/zero``, a folder or a file of gigabytes is refused with one line before anything
is read, instead of hanging or ending in MemoryError.
"""

from __future__ import annotations

import os
import stat
from ._errors import SpaceidError

__all__ = ["read_input_text", "MiB"]

MiB = 1 << 20


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
    try:
        with open(path, "rb") as handle:
            data = handle.read(max_bytes + 1)  # the file may have grown since stat
    except OSError as err:
        raise SpaceidError(
            f"{path}: cannot read the {what} ({err.strerror or err}): check the path and permissions"
        ) from None
    if len(data) > max_bytes:
        raise SpaceidError(f"{path}: beyond the {max_bytes / MiB:.0f} MiB a {what} may have: is this the right file?")
    try:
        # utf-8-sig: spreadsheet exports often start with a byte-order mark.
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise SpaceidError(
            f"{path}: not a UTF-8 text file (byte {err.start} cannot be decoded): expected a {what}"
        ) from None

