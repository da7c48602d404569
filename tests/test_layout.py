"""The package layout: imports only go down the pipeline, every public name is importable, and the
subpackages (the rooms of the pipeline) meet only at their front doors.

A subpackage is entered from another through the subpackage itself (its ``__all__``) or through a
documented non-underscore module of it, its internal interface (``spaceid.estimation.internal``:
stable within the package, not public API), never through its private modules or private names.
spaceid's own top-level modules (``spaceid._errors``, ``spaceid._threads``, ...) are the shared
utilities under every stage: any module may import their non-underscore names. Within one
subpackage (and among spaceid's top-level modules) the modules import each other freely, private
names too, but without a cycle.
"""

import ast
import functools
import importlib
from pathlib import Path

import pytest

import spaceid

SRC = Path(spaceid.__file__).parent
# Lowest first: a module may import from its own layer or a lower one, never a higher one.
LAYERS = ["_utilities", "models", "data", "dynamics", "estimation", "identified", "motion", "twin", "studies", "ros",
          "cli"]


def _layer(parts):
    """The layer of a module given as its path parts under spaceid."""
    head = parts[0]
    if head in LAYERS:
        return head
    return "_utilities" if head.startswith("_") else head


def _room(parts):
    """The subpackage that a module (path parts under spaceid) belongs to; "" for spaceid's own
    top-level modules (the utilities, the CLI)."""
    return parts[0] if parts and (SRC / parts[0]).is_dir() else ""


def _is_module(parts):
    """Whether ``parts`` under spaceid name a module or a package (not a name inside one)."""
    return bool(parts) and (SRC.joinpath(*parts).with_suffix(".py").is_file()
                            or (SRC.joinpath(*parts) / "__init__.py").is_file())  # fmt: skip


def _sources():
    """Every module of spaceid as ``(path, parts)``, the presets' generator script aside."""
    for path in sorted(SRC.rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        if not (parts[0] == "models" and "presets" in parts):
            yield path, parts


@functools.cache
def _tree(path):
    return ast.parse(path.read_text())


def _run_on_import(tree):
    """The nodes of ``tree`` that run when the module is imported: all but function bodies (the
    project imports inside functions for laziness: sympy, matplotlib, the later stages)."""
    for child in ast.iter_child_nodes(tree):
        if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            yield child
            yield from _run_on_import(child)


def _statements(path, on_import_only=False):
    """The imports of spaceid's modules in ``path``: ``(line, target, names)``, ``target`` the module
    imported (path parts under spaceid, ``()`` for spaceid itself) and ``names`` the names taken from
    it (empty when the module itself is imported: ``import spaceid.x``, ``from . import _x``).
    ``on_import_only``: only the imports that run when ``path`` is imported."""
    tree = _tree(path)
    package = path.relative_to(SRC).with_suffix("").parts[:-1]
    for node in _run_on_import(tree) if on_import_only else ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("spaceid."):
                    yield node.lineno, tuple(alias.name.split(".")[1:]), ()
            continue
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package[: len(package) - node.level + 1]
            target = base + (tuple(node.module.split(".")) if node.module else ())
        elif node.module == "spaceid" or (node.module or "").startswith("spaceid."):
            target = tuple(node.module.split(".")[1:])
        else:
            continue
        names = []
        for alias in node.names:
            if _is_module(target + (alias.name,)):  # from . import _noise: the module
                yield node.lineno, target + (alias.name,), ()
            else:
                names.append(alias.name)
        if names:
            yield node.lineno, target, tuple(names)


def _where(parts, line):
    return f"{'/'.join(parts)}.py:{line}"


def test_imports_go_down_the_pipeline():
    upward = []
    for path, parts in _sources():
        if parts == ("__init__",):
            continue
        mine = LAYERS.index(_layer(parts))
        for line, target, _ in _statements(path):
            if target and LAYERS.index(_layer(target)) > mine:
                upward.append(f"{_where(parts, line)} imports {'.'.join(target)}")
    assert not upward, "imports against the pipeline order:\n" + "\n".join(upward)


def _crossings():
    """Every import from another room: ``(where, target, names)``."""
    for path, parts in _sources():
        for line, target, names in _statements(path):
            if _room(target) != _room(parts):
                yield _where(parts, line), target, names


def test_no_private_name_is_imported_from_another_subpackage():
    """A name with a leading underscore is private to its subpackage (spaceid's own top-level
    modules count as one): no other imports it, whichever module it comes from."""
    private = [f"{where} imports {name} from {'.'.join(('spaceid',) + target)}"
               for where, target, names in _crossings() for name in names if name.startswith("_")]  # fmt: skip
    assert not private, ("private names imported across subpackages (export them from the subpackage, or from "
                         "its documented internal interface, without the underscore):\n" + "\n".join(private))


def test_other_subpackages_are_entered_through_their_front_doors():
    """Another subpackage is imported through the subpackage itself or a non-underscore module of it
    (its internal interface), never through a private module; and only names listed in that
    module's ``__all__``."""
    wrong = []
    for where, target, names in _crossings():
        if not _room(target):
            continue  # spaceid's own utilities (spaceid._errors, ...): the shared layer under every room
        shown = ".".join(("spaceid",) + target)
        private = [part for part in target[1:] if part.startswith("_")]
        if private:
            wrong.append(f"{where} imports from the private module {shown}")
            continue
        listed = importlib.import_module(shown).__dict__.get("__all__", ())
        wrong += [f"{where} imports {name} from {shown}, which does not list it in __all__"
                  for name in names if not name.startswith("_") and name not in listed]  # fmt: skip
    assert not wrong, ("imports that reach past a subpackage's front door (import from the subpackage, or from its "
                       "documented internal interface, e.g. spaceid.estimation.internal):\n" + "\n".join(wrong))


INTERNAL = sorted(path.relative_to(SRC).with_suffix("").parts for path in SRC.glob("*/[!_]*.py"))


def test_internal_interfaces_exist():
    assert ("estimation", "internal") in INTERNAL and ("models", "internal") in INTERNAL


@pytest.mark.parametrize("parts", INTERNAL, ids=".".join)
def test_internal_interfaces_are_documented(parts):
    """A subpackage's non-underscore module is its internal interface for the later stages: it says
    so, lists its names in ``__all__`` (none of them public) and documents each."""
    module = importlib.import_module(".".join(("spaceid",) + parts))
    package = importlib.import_module(f"spaceid.{parts[0]}")
    assert module.__doc__ and "not public API" in module.__doc__
    assert module.__all__ and len(set(module.__all__)) == len(module.__all__), "a name is exported twice"
    assert not set(module.__all__) & set(package.__all__), "a public name is exported as internal too"
    for name in module.__all__:
        obj = getattr(module, name)
        assert not name.startswith("_") and obj.__doc__, f"{module.__name__}.{name} has no docstring"


def _cycle(graph):
    """A cycle of ``graph`` (node -> set of nodes) as a list of nodes, first repeated last; None."""
    state, path = {}, []

    def visit(node):
        state[node] = "open"
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = "done"
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_import_cycle_within_a_subpackage():
    """The modules of a subpackage (and spaceid's own top-level modules) import each other without
    a cycle, counting the imports that run at import time: one inside a function runs later, when
    every module is loaded. A package name (``from . import x``) stands for its ``__init__``."""
    graphs = {}
    for path, parts in _sources():
        room = _room(parts)
        edges = graphs.setdefault(room, {}).setdefault(parts, set())
        for _, target, _ in _statements(path, on_import_only=True):
            if _room(target) != room or target == parts:
                continue
            node = target + ("__init__",) if (SRC.joinpath(*target) / "__init__.py").is_file() else target
            if node != parts:
                edges.add(node)
    cycles = [" -> ".join(".".join(node) for node in found) for room, graph in sorted(graphs.items())
              if (found := _cycle(graph))]  # fmt: skip
    message = "import cycles within a subpackage (move what the modules share to a module of its own):\n"
    assert not cycles, message + "\n".join(cycles)


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
