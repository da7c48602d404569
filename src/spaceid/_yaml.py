"""Safe YAML loading with one-line errors (models and bag mappings)."""

import yaml

from ._errors import SpaceidError

__all__ = ["parse_yaml"]


def parse_yaml(text: str, where: str, fix: str = "fix the syntax"):
    """``yaml.safe_load`` of ``text``; a syntax error names ``where`` and its line."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" at line {mark.line + 1}" if mark else ""
        raise SpaceidError(f"{where}: not valid YAML{line}: {fix}") from None
