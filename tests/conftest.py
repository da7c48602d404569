"""Shared fixtures: random trees with known truth, and Pinocchio as the independent reference."""

import os
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from spaceid.models._model import Body, Model, _validate, inertial_vector

sys.path.insert(0, str(Path(__file__).parent))  # test helper modules

# Module fixtures that take seconds to build (a design, a twin run, a simulated campaign): a test
# that needs one is slow, so the fast subset (-m "not slow") never builds them.
SLOW_FIXTURES = {"workdir", "noisy_designs", "short_run", "ideal", "examples", "spatial_run", "chain"}


FAST_SUBSET = "SPACEID_FAST_SUBSET"
"""Set (to 1) while the run leaves the slow tests out (``-m "not slow"``): property tests then draw
:func:`examples`' fast count, the full run (CI) their full count."""


def pytest_configure(config):
    markexpr = config.getoption("markexpr", "") or ""
    if "not slow" in markexpr.replace("(", " ").replace(")", " "):
        os.environ[FAST_SUBSET] = "1"
    else:
        os.environ.pop(FAST_SUBSET, None)


def examples(full: int, fast: int) -> int:
    """Hypothesis examples of a property test: ``fast`` in the fast subset, ``full`` otherwise (the same
    property over more cases: the full run is where a rare case is found)."""
    return fast if os.environ.get(FAST_SUBSET) else full


def pytest_collection_modifyitems(items):
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def random_inertia(rng, planar_com=False):
    """Random physical inertia tensor about the CoM (principal values obey the triangle rule)."""
    d = rng.uniform(0.05, 1.0, 3)
    d[2] = rng.uniform(abs(d[0] - d[1]), d[0] + d[1])
    a = rng.standard_normal((3, 3))
    q, _ = np.linalg.qr(a)
    return q @ np.diag(d) @ q.T


def random_tree(rng, parents, *, planar=True, prismatic=(), name="tree"):
    """A random free-floating tree; ``parents[i]`` is the parent of body ``i + 1``.

    Planar trees have joint axes along z (random sign), in-plane offsets and a placement
    rotation about z; spatial ones random axes, offsets and rotations.
    """
    bodies = []
    for i, parent in enumerate([-1, *parents]):
        mass = rng.uniform(0.2, 5.0) * (10 if i == 0 else 1)
        com = rng.uniform(-0.3, 0.3, 3)
        inertial = inertial_vector(mass, com, random_inertia(rng))
        if parent < 0:
            bodies.append(Body("base", -1, None, "base", np.zeros(3), np.eye(3), np.zeros(3), inertial))
            continue
        if planar:
            axis = np.array([0, 0, rng.choice([-1.0, 1.0])])
            rot = _rot_z(rng.uniform(-np.pi, np.pi))
            xyz = np.r_[rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.1, 0.1)]
            if i in prismatic:
                axis = np.r_[rng.standard_normal(2), 0.0]
                axis /= np.linalg.norm(axis)
        else:
            axis = rng.standard_normal(3)
            axis /= np.linalg.norm(axis)
            rot, _ = np.linalg.qr(rng.standard_normal((3, 3)))
            rot *= np.sign(np.linalg.det(rot))
            xyz = rng.uniform(-0.5, 0.5, 3)
        kind = "prismatic" if i in prismatic else "revolute"
        bodies.append(Body(f"b{i}", parent, f"j{i}", kind, axis, rot, xyz, inertial, {"lower": -0.5, "upper": 0.5} if kind == "prismatic" else {}))
    model = _validate(Model(name, tuple(bodies), False, (), name))
    return model.as_planar() if planar else model


def random_states(rng, model, n):
    q = rng.uniform(-np.pi, np.pi, (n, model.n_joints))
    qd = rng.standard_normal((n, model.n_joints))
    w0 = rng.standard_normal((n, 3))
    if model.planar:
        w0[:, :2] = 0
    return q, qd, w0


def pinocchio_momentum(pmodel, q, qd, w0):
    """Angular momentum about the CM with zero linear momentum, from Pinocchio's centroidal
    momentum matrix (base at identity, so world axes are base axes)."""
    data = pmodel.createData()
    out = []
    for qi, qdi, wi in zip(q, qd, w0):
        config = pin.neutral(pmodel)
        for joint, angle in zip(pmodel.joints[2:], qi):  # continuous joints store (cos, sin)
            config[joint.idx_q : joint.idx_q + joint.nq] = [np.cos(angle), np.sin(angle)] if joint.nq == 2 else angle
        v = np.r_[np.zeros(3), wi, qdi]
        ag = pin.ccrba(pmodel, data, config, v)
        v[:3] = np.linalg.solve(ag[:3, :3], -ag[:3, 3:] @ v[3:])
        out.append(ag[3:] @ v)
    return np.array(out)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True, scope="session")
def _cache_dir(tmp_path_factory):
    """The on-disk cache of minimal sets in a fresh directory (not the user's), for every test and
    the CLI runs they start."""
    import os

    os.environ["SPACEID_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
