"""The one exception type that the command line turns into a one-line message, and the check
of numeric array fields that raises it."""

import reprlib

import numpy as np

__all__ = ["SpaceidError", "finite_array"]


class SpaceidError(ValueError):
    """Bad input or an ill-posed problem, with a message that says what to fix.

    Library code raises it; only the CLI turns it into ``error: <message>`` and exit code 2.
    The message names the file or field, what was expected, what arrived and how to fix it.
    """


def finite_array(value, shape, name, source):
    """``value`` as a finite, read-only float array, or a SpaceidError naming the field.

    ``shape`` is the expected shape, or an int: the expected number of dimensions.
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise SpaceidError(
            f"{source}: field '{name}' must be a rectangular array of numbers, "
            f"got {reprlib.repr(value)}"
        ) from None
    if arr.shape != shape if isinstance(shape, tuple) else arr.ndim != shape:
        expected = shape if isinstance(shape, tuple) else f"{shape} dimensions"
        raise SpaceidError(f"{source}: field '{name}' must have shape {expected}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SpaceidError(f"{source}: field '{name}' contains NaN or infinite values")
    arr.setflags(write=False)
    return arr
