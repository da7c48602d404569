"""Renamed keyword arguments: for one release the old keyword still works, with a
DeprecationWarning that names the new one (docs/api/conventions.md lists the renames)."""

from __future__ import annotations

import functools
import warnings

__all__ = ["deprecated_alias"]


def deprecated_alias(*, old: str, new: str):
    """Decorator: the keyword argument ``old`` of the function is now ``new``.

    A call that gives ``old`` runs with it as ``new`` and warns (``DeprecationWarning``, pointing
    at the caller); one that gives both raises ``TypeError``, as Python does for an argument given
    twice. Positional calls are unchanged. Stack one decorator per renamed argument.
    """

    def wrap(function):
        @functools.wraps(function)
        def call(*args, **kwargs):
            if old in kwargs:
                if new in kwargs:
                    raise TypeError(f"{function.__name__}() got `{new}` and its old name `{old}`: give `{new}` only")
                warnings.warn(f"{function.__name__}(): `{old}` is now called `{new}`; the old name goes in the next "
                              "release", DeprecationWarning, stacklevel=2)
                kwargs[new] = kwargs.pop(old)
            return function(*args, **kwargs)

        call.renamed = {**getattr(function, "renamed", {}), old: new}  # the renames, for the docs and tests
        return call

    return wrap
