"""The on-disk cache of minimal parameter sets and parsed URDF models: where it lives, and that a cached entry is
the derived one."""

from dataclasses import replace

import numpy as np
import pytest

import spaceid
from spaceid import _cache
from spaceid.dynamics import _regressor
from spaceid.dynamics._kinematics import _Geometry

from conftest import random_states, random_tree


def test_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("SPACEID_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _cache.cache_dir() == tmp_path / "xdg" / "spaceid"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _cache.cache_dir() == tmp_path / "home" / ".cache" / "spaceid"
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path / "mine"))
    assert _cache.cache_dir() == tmp_path / "mine"


def _same(a, b, model, rng):
    """Two parameterizations alike in every field and in the regressor they evaluate."""
    assert (a.names, a.definitions, a.units, a.basis, a.rank_tol, a.seed, a.n_states) == (
        b.names, b.definitions, b.units, b.basis, b.rank_tol, b.seed, b.n_states)
    assert np.array_equal(a.projection, b.projection)
    q, qd, w0 = random_states(rng, model, 20)
    assert np.array_equal(a.regressor(q, qd, w0), b.regressor(q, qd, w0))


@pytest.mark.parametrize("planar", [pytest.param(True, marks=pytest.mark.slow), False])  # planar: SymPy definitions
def test_cached_set_is_the_derived_one(rng, monkeypatch, tmp_path, planar):
    """Written on the first derivation, read back (no derivation) identical to it, for the planar
    basis and the columns basis."""
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    model = random_tree(rng, [0, 1, 1], planar=planar)
    geometry = _Geometry(model)
    derived = _regressor._derive_minimal(geometry, 1e-9, 0)
    first = _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0)
    assert len(list((tmp_path / "minimal-set").glob("*.npz"))) == 1
    _same(first, derived, model, rng)

    def no_derivation(*args):
        raise AssertionError("derived although cached")

    monkeypatch.setattr(_regressor, "_derive_minimal", no_derivation)
    cached = _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0)
    assert cached.basis == ("planar" if planar else "columns")
    _same(cached, derived, model, rng)


def test_cache_keyed_by_geometry_not_inertia(rng):
    """Another mass: the same key; another joint axis, tolerance or seed: another key."""
    model = random_tree(rng, [0, 1], planar=False)
    key = _regressor._set_key(_Geometry(model), 1e-9, 0)
    inertials = np.array([b.inertial for b in model.bodies])
    heavier = model.with_inertials(inertials * 1.5)
    assert _regressor._set_key(_Geometry(heavier), 1e-9, 0) == key
    assert _regressor._set_key(_Geometry(model), 1e-8, 0) != key
    assert _regressor._set_key(_Geometry(model), 1e-9, 1) != key
    other = random_tree(np.random.default_rng(1), [0, 1], planar=False)
    assert _regressor._set_key(_Geometry(other), 1e-9, 0) != key


@pytest.mark.parametrize("damage", ["truncated", "garbage", "stale", "other layout"])
def test_damaged_or_stale_entry_is_ignored_and_rewritten(rng, monkeypatch, tmp_path, damage):
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    model = random_tree(rng, [0, 1], planar=False)
    geometry = _Geometry(model)
    derived = _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0)
    key = _regressor._set_key(geometry, 1e-9, 0)
    path = tmp_path / "minimal-set" / f"{key}.npz"
    good = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(good[: len(good) // 2])
    elif damage == "garbage":
        path.write_bytes(b"not a cache entry")
    elif damage == "stale":  # an entry written under another key (e.g. by other derivation code)
        _cache.write_cached("minimal-set", "another", _regressor._to_stored(derived))
        (tmp_path / "minimal-set" / "another.npz").replace(path)
    else:
        stored = _regressor._to_stored(derived)
        stored["projection_shape"] = np.array([3, 2])
        _cache.write_cached("minimal-set", key, stored)
    calls = []
    original = _regressor._derive_minimal
    monkeypatch.setattr(_regressor, "_derive_minimal", lambda *a: calls.append(1) or original(*a))
    again = _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0)
    assert calls == [1]  # derived again ...
    _same(again, derived, model, rng)
    rewritten = _cache.read_cached("minimal-set", key)  # ... and rewritten
    expected = _regressor._to_stored(derived)
    assert rewritten.keys() == expected.keys() and all(np.array_equal(rewritten[k], expected[k]) for k in expected)


def test_unwritable_cache_is_skipped(rng, monkeypatch, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the directory would be")
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(blocker))
    model = random_tree(rng, [0], planar=True)
    param = _regressor._minimal_cached.__wrapped__(_Geometry(model), 1e-9, 0)
    assert param.n_params > 0


def test_minimal_parameters_of_a_preset_from_the_cache(monkeypatch, tmp_path):
    """Through the public call: a preset's set, cached in one process and read in the next
    (simulated by clearing the in-memory cache), is the derived one."""
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    model = spaceid.load_model("cepheus")
    _regressor._minimal_cached.cache_clear()
    first = spaceid.minimal_parameters(model)
    _regressor._minimal_cached.cache_clear()
    second = spaceid.minimal_parameters(model)
    _same(first, second, model, np.random.default_rng(0))
    _regressor._minimal_cached.cache_clear()


def test_warmed_presets_are_read_not_derived(monkeypatch, tmp_path):
    """``warm_preset_sets`` (the end of ``spaceid demo``) leaves each preset's set and its parameters without effect
    on the momentum in the cache, and the sets of a payload on each body with declared zeros (cepheus-rw's wheel and
    two links): a later process (the in-memory cache cleared) reads them, deriving nothing. Two small presets here;
    the demo warms them all (test_demo.py::test_designed_demo_writes_report)."""
    from spaceid.identified import payload_map
    from spaceid.studies import warm_preset_sets

    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    _regressor._minimal_cached.cache_clear()
    warm_preset_sets(["cepheus-rw", "satellite-7dof"])
    assert len(list((tmp_path / "minimal-set").glob("*.npz"))) == 2 + 3
    _regressor._minimal_cached.cache_clear()

    def no_derivation(*args):
        raise AssertionError("derived although warmed")

    monkeypatch.setattr(_regressor, "_derive_minimal", no_derivation)
    monkeypatch.setattr(_regressor, "_no_effect", no_derivation)  # the export's parameters without effect
    for name in ("cepheus-rw", "satellite-7dof"):
        param = spaceid.minimal_parameters(spaceid.load_model(name))
        assert param.n_params > 0 and bool(_regressor.no_effect_parameters(param)) == param.model.planar
    assert payload_map("cepheus-rw", "link2").param.n_params > 0
    _regressor._minimal_cached.cache_clear()


@pytest.mark.parametrize("planar", [True, False])
def test_cached_no_effect_parameters_are_the_derived_ones(rng, monkeypatch, tmp_path, planar):
    """The export's parameters without effect on the momentum: written on the first call, read back (no regressor)
    equal to :func:`identifiability`'s; another tolerance is another entry. A planar tree has some (its out-of-plane
    moments), so an empty answer cannot pass for a right one."""
    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    param = spaceid.dynamics.minimal_parameters(random_tree(rng, [0, 1, 1], planar=planar))
    derived = _regressor._no_effect(param, param.rank_tol)
    assert bool(derived) == planar and not (tmp_path / "no-effect").exists()
    assert _regressor.no_effect_parameters(param) == derived
    assert len(list((tmp_path / "no-effect").glob("*.npz"))) == 1

    def no_regressor(*args):
        raise AssertionError("formed although cached")

    monkeypatch.setattr(_regressor, "_no_effect", no_regressor)
    assert _regressor.no_effect_parameters(param) == derived
    assert spaceid.dynamics.identifiability(param).no_effect == derived
    with pytest.raises(AssertionError, match="formed although cached"):
        _regressor.no_effect_parameters(param, tol=1e-6)


def _same_model(a, b):
    """Two models alike in every field, their bodies' arrays equal bit for bit."""
    assert (a.name, a.planar, a.wheels, a.source) == (b.name, b.planar, b.wheels, b.source)
    assert len(a.bodies) == len(b.bodies)
    for x, y in zip(a.bodies, b.bodies):
        assert (x.name, x.parent, x.joint, x.joint_type, x.limits, x.known_zero) == (
            y.name, y.parent, y.joint, y.joint_type, y.limits, y.known_zero)
        assert list(x.limits) == list(y.limits)  # in the same order
        for field in ("axis", "rotation", "translation", "inertial"):
            assert np.array_equal(getattr(x, field), getattr(y, field)), field


@pytest.mark.parametrize("source", ["satellite-7dof", "servicer-dual", "servicer-captured", 5, 12])
def test_a_urdf_model_read_from_the_cache_is_the_parsed_one(monkeypatch, tmp_path, source):
    """A URDF (a preset's, a random robot's file) is parsed by Pinocchio once and stored; loaded again it is read,
    not parsed, and is the parsed model in every field, for either planar setting; a random robot's file read under
    another name takes that name."""
    from spaceid.models import _model
    from random_robots import random_robot

    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    planar = None
    if isinstance(source, int):
        robot = random_robot(source, planar=source % 2 == 0)
        planar, source = robot.planar, tmp_path / "robot.urdf"
        source.write_text(robot.urdf)
    parsed = spaceid.load_model(source, planar=planar)
    assert len(list((tmp_path / "urdf-model").glob("*.npz"))) == 1
    monkeypatch.setattr(_model, "_parsed_urdf", lambda *a: pytest.fail("parsed although cached"))
    _same_model(spaceid.load_model(source, planar=planar), parsed)
    if planar is not None:
        other = tmp_path / "other.urdf"
        other.write_text(source.read_text())
        again = spaceid.load_model(other, planar=planar)
        assert (again.name, again.source) == ("other", str(other.resolve()))
        _same_model(again, replace(parsed, name="other", source=str(other.resolve())))


def test_a_urdf_that_warns_or_is_refused_is_never_stored(monkeypatch, tmp_path):
    """A mimic joint's warning is given at every load (its URDF parsed each time); a refused URDF leaves no entry."""
    from random_robots import random_robot

    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path))
    text = random_robot(3, planar=False).urdf
    joint = text.index("</joint>")
    mimic = tmp_path / "mimic.urdf"
    mimic.write_text(text[:joint] + '<mimic joint="none"/>' + text[joint:])
    for _ in range(2):
        with pytest.warns(UserWarning, match="mimics 'none'"):
            spaceid.load_model(mimic)
    broken = tmp_path / "broken.urdf"
    broken.write_text(text.replace('<mass value="', '<mass value="-', 1))
    with pytest.raises(spaceid.SpaceidError):
        spaceid.load_model(broken)
    assert not list(tmp_path.glob("urdf-model/*.npz"))
