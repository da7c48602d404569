"""The compiled kernels' decorator."""

import numba

from spaceid._jit import kernel


class NoCacheDirectory:
    """A Numba cache locator that finds no writable directory (a read-only install and home)."""

    @classmethod
    def from_function(cls, py_func, source_path):
        return None


def test_kernels_compile_without_a_writable_cache(monkeypatch):
    """Where Numba can write no cache (a read-only package directory and user cache), a kernel
    is compiled in the process instead of failing at import (Numba raises a RuntimeError when
    asked to cache there)."""
    monkeypatch.setattr(numba.config, "CACHE_LOCATOR_CLASSES", f"{__name__}.NoCacheDirectory")

    def twice(x):
        return 2 * x

    compiled = kernel(twice)
    assert compiled(21) == 42
    assert type(compiled._cache).__name__ == "NullCache"
