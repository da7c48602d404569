"""The on-disk cache of derived data (the minimal parameter sets, the monitor's CUSUM thresholds): arrays
in ``.npz`` files named by a key, under ``$SPACEID_CACHE_DIR``, else ``$XDG_CACHE_HOME/spaceid``, else
``~/.cache/spaceid``.

An entry records its key: a file that does not load, or holds another key, is ignored (and the
caller's rewrite replaces it). Writes are atomic; a cache that cannot be written is skipped.
Deleting the directory clears it.
"""

from __future__ import annotations

import hashlib
import os
import zipfile
from pathlib import Path

import numpy as np

from ._atomic import atomic_path

__all__ = ["cache_dir", "cache_key", "read_cached", "source_digest", "stored_strings", "stored_text", "write_cached"]


def cache_dir() -> Path:
    """The cache directory (not created): ``$SPACEID_CACHE_DIR``, ``$XDG_CACHE_HOME/spaceid`` or
    ``~/.cache/spaceid``."""
    if os.environ.get("SPACEID_CACHE_DIR"):
        return Path(os.environ["SPACEID_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "spaceid"


def cache_key(*parts) -> str:
    """Hex SHA-256 of the ``repr`` of ``parts`` (give them in a deterministic form: no sets)."""
    return hashlib.sha256(repr(parts).encode()).hexdigest()


def source_digest(*paths) -> str:
    """Hash of the source files ``paths``: in an entry's key, a change to the code that derives it makes the entry
    stale."""
    return cache_key(*(hashlib.sha256(Path(path).read_bytes()).hexdigest() for path in paths))


def _path(kind: str, key: str) -> Path:
    return cache_dir() / kind / f"{key}.npz"


def read_cached(kind: str, key: str) -> dict | None:
    """The arrays stored under ``kind``/``key``, or None when there is no such entry, or it does
    not load or holds another key (corrupt or stale)."""
    try:
        with np.load(_path(kind, key), allow_pickle=False) as stored:
            arrays = {name: stored[name] for name in stored.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):  # absent, truncated, damaged
        return None
    return arrays if str(arrays.pop("_key", "")) == key else None


def write_cached(kind: str, key: str, arrays: dict) -> None:
    """Store ``arrays`` (name to array, no objects) under ``kind``/``key``, atomically; a cache
    that cannot be written (read-only home, full disk) is left alone."""
    try:
        with atomic_path(_path(kind, key)) as tmp, open(tmp, "wb") as out:
            np.savez(out, _key=np.array(key), **arrays)
    except OSError:
        pass


def stored_text(strings) -> np.ndarray:
    """Strings as one UTF-8 byte array, NUL-separated (no XML or YAML name holds one): a fixed-width string array
    would pad every string to the longest (10 MB for the servicer's parameter definitions)."""
    return np.frombuffer("\0".join(strings).encode(), np.uint8)


def stored_strings(text: np.ndarray) -> tuple:
    """The strings of :func:`stored_text` (none for an empty array)."""
    return tuple(text.tobytes().decode().split("\0")) if text.size else ()
