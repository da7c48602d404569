"""Safe YAML loading with one-line errors (models and bag mappings).

Model and mapping files are short, hand-written descriptions: aliases (``*name``) are refused,
since a few hundred bytes of nested aliases expand to gigabytes (a "billion laughs" file), and
so are Python tags (safe loading), files beyond :data:`MAX_YAML_CHARS` and brackets nested
deeper than :data:`MAX_YAML_DEPTH` (PyYAML's scanner takes time quadratic in that depth: 5 s for
50,000 levels, hours for a megabyte of ``[``). Aliases are found in the parser's events, before
anything is composed.
"""

import re

import numpy as np
import yaml

from ._errors import SpaceidError

__all__ = ["parse_yaml", "MAX_YAML_CHARS", "MAX_YAML_DEPTH"]

MAX_YAML_CHARS = 1_000_000
"""Longest YAML text read [characters]: a model of a thousand bodies takes ~400 kB."""
MAX_YAML_DEPTH = 100
"""Deepest nesting of flow brackets (``[``, ``{``) read; a model needs 3."""


class _Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """The safe loader (libyaml's when built: 4x faster on a 1 MB model), numbers in exponent
    form read as floats: YAML 1.1 reads 1e-5 (no decimal point) as a string, YAML 1.2 as a number."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def parse_yaml(text: str, where: str, fix: str = "fix the syntax"):
    """``yaml.safe_load`` of ``text`` without aliases; every failure is a one-line SpaceidError
    naming ``where`` (and the line where YAML knows it), ending in ``fix``."""
    if len(text) > MAX_YAML_CHARS:
        raise SpaceidError(
            f"{where}: {len(text)} characters of YAML, beyond the {MAX_YAML_CHARS} a model or mapping file may "
            "have: is this the right file?"
        )
    depth = _bracket_depth(text)
    if depth > MAX_YAML_DEPTH:
        raise SpaceidError(f"{where}: brackets nested {depth} deep, beyond {MAX_YAML_DEPTH}: {fix}")
    alias = _first_alias(text, where, fix)
    if alias is not None:
        raise SpaceidError(
            f"{where}: line {alias.start_mark.line + 1}: YAML alias '*{str(alias.anchor)[:40]}' refused (aliases "
            "can expand without bound): write the value out in full"
        )
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        raise _invalid(exc, where, fix) from None
    except RecursionError:
        raise SpaceidError(f"{where}: YAML nested too deeply to read: {fix}") from None
    except (ValueError, OverflowError) as exc:  # e.g. an integer of 5000 digits, a date 2001-13-45
        raise SpaceidError(f"{where}: a YAML value cannot be read ({str(exc).splitlines()[0][:80]}): {fix}") from None


def _first_alias(text, where, fix):
    """The first alias event of ``text``, or None: the events only, nothing composed or expanded."""
    try:
        return next((e for e in yaml.parse(text, Loader=_Loader) if isinstance(e, yaml.AliasEvent)), None)
    except yaml.YAMLError as exc:
        raise _invalid(exc, where, fix) from None


def _invalid(exc, where, fix):
    mark = getattr(exc, "problem_mark", None)
    line = f" at line {mark.line + 1}" if mark else ""
    return SpaceidError(f"{where}: not valid YAML{line}: {fix}")


def _bracket_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in ``text`` (quotes and comments not told apart: an upper
    bound of the flow depth), in one vectorised pass."""
    raw = np.frombuffer(text.encode("utf-8", "replace"), dtype=np.uint8)
    step = np.isin(raw, (ord("["), ord("{"))).astype(np.int64) - np.isin(raw, (ord("]"), ord("}")))
    return int(np.cumsum(step).max(initial=0))
