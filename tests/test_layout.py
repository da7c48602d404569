"""The package layout: imports only go down the pipeline, and every public name is importable."""

import ast
import importlib
from pathlib import Path

import pytest

import spaceid

SRC = Path(spaceid.__file__).parent
# Lowest first: a module may import from its own layer or a lower one, never a higher one.
LAYERS = ["_utilities", "models", "data", "dynamics", "estimation", "identified", "motion", "twin", "studies", "cli"]


def _layer(parts):
    """The layer of a module given as its path parts under spaceid."""
    head = parts[0]
    if head in LAYERS:
        return head
    return "_utilities" if head.startswith("_") else head


def _imports(path):
    """Modules under spaceid that ``path`` imports, as tuples of parts."""
    module = path.relative_to(SRC).with_suffix("").parts
    package = module[:-1] if path.name != "__init__.py" else module[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = base + tuple((node.module or "").split(".")) if node.module else base
                if not node.module:  # from . import x
                    for alias in node.names:
                        yield base + (alias.name,)
                    continue
                yield tuple(p for p in target if p)
            elif node.module and node.module.startswith("spaceid."):
                yield tuple(node.module.split(".")[1:])


def test_imports_go_down_the_pipeline():
    upward = []
    for path in SRC.rglob("*.py"):
        parts = path.relative_to(SRC).with_suffix("").parts
        if parts == ("__init__",) or parts[0] == "models" and "presets" in parts:
            continue
        mine = LAYERS.index(_layer(parts))
        for target in _imports(path):
            if target and LAYERS.index(_layer(target)) > mine:
                upward.append(f"{'/'.join(parts)} imports {'.'.join(target)}")
    assert not upward, "imports against the pipeline order:\n" + "\n".join(upward)


@pytest.mark.parametrize("package", LAYERS[1:-1])
def test_public_names_exist_and_are_documented(package):
    module = importlib.import_module(f"spaceid.{package}")
    assert module.__doc__
    assert len(set(module.__all__)) == len(module.__all__), "a name is exported twice"
    for name in module.__all__:
        obj = getattr(module, name)
        if callable(obj):
            assert obj.__doc__, f"spaceid.{package}.{name} has no docstring"


def test_top_level_api_resolves_to_the_subpackages():
    for name in spaceid.__all__:
        obj = getattr(spaceid, name)
        assert obj.__doc__, f"spaceid.{name} has no docstring"
    assert set(dir(spaceid)) >= set(spaceid.__all__)
    with pytest.raises(AttributeError, match="no attribute 'identfy'"):
        spaceid.identfy  # noqa: B018
