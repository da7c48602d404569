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


def test_a_strided_output_compiles_no_second_kernel():
    """The regressor written into a strided view of a larger array (as the identification does)
    gives the values of a fresh output, bit for bit, and the kernels keep their one signature with a
    contiguous output: another layout would compile them again, seconds of a command's first run."""
    import numpy as np

    import spaceid
    from spaceid.dynamics import _kernels
    from spaceid.dynamics._regressor import _random_states

    param = spaceid.minimal_parameters(spaceid.load_model("satellite-7dof"))
    q, qd, w0 = _random_states(param.model, 300, seed=3)
    direction = _random_states(param.model, 300, seed=4)
    wide = np.full((300, 3, param.n_params + 2), np.nan)
    view = wide[:, :, 1:-1]
    assert not view.flags.c_contiguous
    param.regressor(q, qd, w0, out=view)
    np.testing.assert_array_equal(view, param.regressor(q, qd, w0))
    assert np.isnan(wide[:, :, [0, -1]]).all()  # nothing written outside the view
    first = np.full((300, 3, param.n_params + 2), np.nan)  # the first columns of each row (the equations' A)
    param.regressor(q, qd, w0, out=first[:, :, : param.n_params])
    np.testing.assert_array_equal(first[:, :, : param.n_params], view)
    assert np.isnan(first[:, :, param.n_params :]).all()  # written through the rows, the last columns untouched
    param.linearized_regressor(q, qd, w0, direction, step=1e-6, out=view)
    np.testing.assert_array_equal(view, param.linearized_regressor(q, qd, w0, direction, step=1e-6))
    for compiled in (_kernels._columns_of_states, _kernels._tangent_columns):
        assert {sig[-1].layout for sig in compiled.signatures} == {"C"}
