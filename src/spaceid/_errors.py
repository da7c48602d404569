"""The one exception type that the command line turns into a one-line message, the check of
numeric array fields that raises it, and the short form of a value that messages quote."""

import reprlib
import unicodedata

import numpy as np

__all__ = ["SpaceidError", "finite_array", "one_line", "shown", "shown_name"]


class SpaceidError(ValueError):
    """Bad input or an ill-posed problem, with a message that says what to fix.

    Library code raises it; only the CLI turns it into ``error: <message>`` and exit code 2.
    The message names the file or field, or the Python argument, what was expected, what arrived
    and how to fix it. A Python argument is named in backquotes, as in ``"`drift`: 'wind' is not
    a drift kind"``: the command line shows each such name as its option (``--drift``) through
    one table (:func:`spaceid.cli.for_the_command_line`), so a library message never names a
    command-line option itself.
    """


_SHOWN = reprlib.Repr()
_SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlevel = 60, 60, 3
_SHOWN_CHARS = 80  # [characters]; a message quotes at most this much of a value


def shown(value) -> str:
    """A bounded, one-line ``repr`` of ``value`` for messages (at most ~80 characters, nesting
    cut at 3 levels): a hostile input is never expanded or repr()'d whole into a message."""
    text = _SHOWN.repr(value).replace("\n", " ")
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


_UNSAFE = {"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp", "So"}  # controls, format, unassigned, separators, emoji


def shown_name(name) -> str:
    """A user-given name (file, joint, topic) as it is echoed: itself when every character
    is an ordinary letter, digit, mark, punctuation, symbol or space, else its ``ascii()`` repr
    (a newline, a terminal escape or an emoji never reaches the terminal raw)."""
    text = str(name)
    return text if all(unicodedata.category(c) not in _UNSAFE for c in text) else ascii(text)


def one_line(text: str) -> str:
    """``text`` with its control characters (newlines, escapes) shown as escapes: one line."""
    return "".join(c if c.isprintable() or c == " " else ascii(c)[1:-1] for c in str(text))


def _has_bool(value) -> bool:
    """Whether a nested list or tuple holds a boolean (``np.array`` would take it as 0 or 1)."""
    stack = [value]  # iterative: a deeply nested input must not exhaust the recursion limit
    while stack:
        item = stack.pop()
        if isinstance(item, (bool, np.bool_)):
            return True
        if isinstance(item, (list, tuple)):
            stack.extend(item)
    return False


def finite_array(value, shape, name, source):
    """``value`` as a finite, read-only float array, or a SpaceidError naming the field.

    ``shape`` is the expected shape, or an int: the expected number of dimensions. Booleans
    are refused (``true`` is not the number 1).
    """
    if _has_bool(value):
        raise SpaceidError(f"{source}: field '{name}' holds true/false where numbers are expected: give numbers")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise SpaceidError(
            f"{source}: field '{name}' must be a rectangular array of numbers, "
            f"got {shown(value)}"
        ) from None
    if arr.shape != shape if isinstance(shape, tuple) else arr.ndim != shape:
        expected = shape if isinstance(shape, tuple) else f"{shape} dimensions"
        raise SpaceidError(f"{source}: field '{name}' must have shape {expected}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SpaceidError(f"{source}: field '{name}' contains NaN or infinite values")
    arr.setflags(write=False)
    return arr
