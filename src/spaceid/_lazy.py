"""Names of a package imported from their modules on first use (PEP 562), so that importing the package
imports none of them: ``spaceid`` (its stages) and ``spaceid.studies`` (its studies, whose reports a command
needs one at a time)."""

from __future__ import annotations

import importlib

__all__ = ["lazy_names"]


def lazy_names(package: str, namespace: dict, home: dict) -> tuple:
    """``(__getattr__, __dir__)`` for the package ``package`` whose module globals are ``namespace``: ``home`` maps
    each public name to the submodule that defines it, or to ``(submodule, its name there)``, and each submodule's
    own name (a key with a ``None`` value) to itself. A name looked up once is kept in ``namespace``."""

    def __getattr__(name):
        if name not in home:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        where = home[name]
        module, attr = (name, None) if where is None else where if isinstance(where, tuple) else (where, name)
        value = importlib.import_module(f".{module}", package)
        value = value if attr is None else getattr(value, attr)
        namespace[name] = value  # later look-ups skip this function
        return value

    def __dir__():
        return sorted(set(namespace) | set(namespace["__all__"]))

    return __getattr__, __dir__
