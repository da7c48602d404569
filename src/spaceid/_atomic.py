"""Atomic output: a reader never sees a half-written file or report folder, a failure or an
interrupt leaves none, and no output goes over an input or over files spaceid did not write.

A report folder is written as a temporary sibling, then renamed into place; it holds a manifest,
``spaceid-manifest.json``, naming the files spaceid wrote there and the command. A folder whose
files the manifest lists (or an empty one) is spaceid's, and a later run replaces it whole; any
other existing folder is refused unless the user asks to write beside its files (``overwrite``).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import json
import os
import shutil
import tempfile
from pathlib import Path

from ._errors import SpaceidError, shown_name

__all__ = ["MANIFEST", "atomic_folder", "atomic_path", "check_output_file", "check_output_folder",
           "write_text_atomic"]

MANIFEST = "spaceid-manifest.json"
"""The file in every report folder that names the files spaceid wrote there."""


def _ordinary_permissions(path, mode) -> None:
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)  # mkstemp and mkdtemp make them private


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    On an exception (or an interrupt) the temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    _ordinary_permissions(tmp, 0o666)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


# --- checks before a command starts ------------------------------------------------------------


def _is_input(path: Path, inputs) -> str | None:
    """The label of the input that ``path`` is (the same file, through links), or None."""
    for label, source in inputs:
        with contextlib.suppress(OSError):
            if os.path.samefile(path, source):
                return label
    return None


def _check_writable(path: Path, option: str) -> None:
    """Raise unless the nearest existing folder above ``path`` lets this process create files."""
    parent = Path(os.path.abspath(path)).parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise SpaceidError(f"{option} {shown_name(path)}: cannot write into {shown_name(parent)} (not a writable "
                           "folder): choose another place")


def check_output_file(path, option: str, inputs=()) -> None:
    """Raise a SpaceidError unless ``path`` can take an output file: not a folder, not one of
    ``inputs`` (pairs ``(label, path)``: compared as files, through symbolic and hard links), in
    a writable folder."""
    path = Path(path)
    if path.is_dir():
        raise SpaceidError(f"{option} {shown_name(path)} is a folder: give a file name")
    label = _is_input(path, inputs) if path.exists() else None
    if label is not None:
        raise SpaceidError(f"{option} {shown_name(path)} is the input {label}; choose another output file")
    _check_writable(path, option)


def _files_under(folder: Path) -> list:
    """Paths of the files under ``folder``, relative, POSIX style, sorted; the manifest left out."""
    files = [p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir()]
    return sorted(f for f in files if f != MANIFEST)


def _manifest_files(folder: Path) -> set:
    """The files ``folder``'s manifest lists (none without a readable manifest)."""
    try:
        files = json.loads((folder / MANIFEST).read_text(encoding="utf-8")).get("files", [])
    except (OSError, ValueError, AttributeError):
        return set()
    return {f for f in files if isinstance(f, str)}


def _foreign_files(folder: Path) -> list:
    """Files under ``folder`` that its manifest does not list: ones spaceid did not write."""
    listed = _manifest_files(folder)
    return [f for f in _files_under(folder) if f not in listed]


def check_output_folder(path, option: str, *, overwrite: bool = False, inputs=()) -> None:
    """Raise a SpaceidError unless ``path`` can take a report folder: absent, or a writable
    folder that holds only files spaceid wrote (any others with ``overwrite``), and none of
    ``inputs`` (pairs ``(label, path)``) inside a folder that the report will replace."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SpaceidError(f"{option} {shown_name(path)} is an existing file: give a folder name")
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise SpaceidError(f"{option} {shown_name(path)} is a read-only folder: choose another folder")
        foreign = _foreign_files(path)
        if foreign and not overwrite:
            listed = ", ".join(shown_name(f) for f in foreign[:3]) + (", ..." if len(foreign) > 3 else "")
            raise SpaceidError(f"{option} {shown_name(path)} holds files spaceid did not write ({listed}): choose "
                               "another folder, or pass `overwrite` to write beside them")
        real = os.path.realpath(path)
        for label, source in inputs if not foreign else ():
            if os.path.commonpath([real, os.path.realpath(source)]) == real:
                raise SpaceidError(f"{option} {shown_name(path)} holds the input {label} ({shown_name(source)}), "
                                   "which the new report would replace: choose another folder")
    _check_writable(path, option)


# --- the report folder ---------------------------------------------------------------------------


@contextlib.contextmanager
def _locked(folder: Path):
    """An exclusive lock on ``folder`` (the parent of report folders) among processes that take
    it: concurrent runs install their folders one at a time."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


_RENAME_EXCHANGE = 2  # renameat2 flag (Linux >= 3.15)
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap the folders ``a`` and ``b`` in one atomic step; False where the system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    return renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _install(tmp: Path, target: Path, files: list, record: dict, *, overwrite: bool, inputs) -> None:
    """Put the finished folder ``tmp`` in the place of ``target`` (see :func:`atomic_folder`)."""
    if not target.exists():
        os.rename(tmp, target)
        return
    foreign = _foreign_files(target)
    if not foreign:  # spaceid's: replaced whole, in one step where the system allows
        if not _exchange(tmp, target):
            trash = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.rename(target, trash / target.name)
            os.rename(tmp, target)
            tmp = trash
        shutil.rmtree(tmp)
        return
    if not overwrite:  # foreign files appeared since the check
        raise SpaceidError(f"{shown_name(target)} now holds files spaceid did not write: choose another folder, or "
                           "pass `overwrite`")
    for name in files:  # beside the user's files: each one replaced atomically, the inputs never
        label = _is_input(target / name, inputs)
        if label is not None:
            raise SpaceidError(f"{shown_name(target / name)} is the input {label}; choose another folder")
    written = sorted(_manifest_files(target) | set(files))
    for name in files:
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / name, target / name)
    write_text_atomic(target / MANIFEST, _manifest_text(written, record))
    shutil.rmtree(tmp)


def _manifest_text(files, record) -> str:
    return json.dumps({**record, "files": list(files)}, indent=2) + "\n"


@contextlib.contextmanager
def atomic_folder(path, *, command: str, overwrite: bool = False, inputs=()):
    """Yield a temporary folder beside ``path`` to write a report into; on success it takes
    ``path``'s place with a manifest (:data:`MANIFEST`: ``command`` and the files written).

    ``path`` absent: the folder is renamed into place. ``path`` a folder of spaceid's (every
    file listed by its manifest, or none): replaced whole. Otherwise (``overwrite``, see
    :func:`check_output_folder`): each new file replaces its namesake there, atomically, and the
    other files stay; a new file that is one of ``inputs`` (pairs ``(label, path)``) is refused.
    On an exception or an interrupt the temporary folder is removed and ``path`` is as it was.
    Concurrent runs into one folder install one after another: the last one's report stays.
    """
    target = Path(os.path.realpath(path))  # a link to a folder: the folder it names
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    _ordinary_permissions(tmp, 0o777)
    try:
        yield tmp
        files, record = _files_under(tmp), {"written_by": "spaceid", "command": command}
        (tmp / MANIFEST).write_text(_manifest_text(files, record), encoding="utf-8")
        with _locked(target.parent):
            _install(tmp, target, files, record, overwrite=overwrite, inputs=inputs)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
