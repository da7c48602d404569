"""Robot description of a free-floating system: a tree of rigid bodies on a floating base.

A :class:`Model` is immutable. It is loaded from URDF (parsed by Pinocchio; its root link is
the floating base and fixed joints are merged), from a compact YAML description, or from a
built-in preset (``cepheus``, ``cepheus-rw``). Inertial parameters follow Pinocchio's order
``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` with the inertia about the body frame
origin.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import hashlib
import math
import os
import re
import sys
import tempfile
import warnings
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np

from .._cache import cache_key, read_cached, source_digest, stored_strings, stored_text, write_cached
from .._errors import SpaceidError, shown
from .._inputs import MiB, read_input_text
from .._yaml import parse_yaml

__all__ = [
    "INERTIAL_NAMES",
    "Body",
    "Model",
    "PRESETS",
    "load_model",
    "inertial_vector",
    "to_pinocchio",
    "attach_payload",
    "body_index",
    "link_frame",
    "check_rigid_inertia",
    "perturbed_model",
]

INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
PRESETS = ("cepheus", "cepheus-rw", "satellite-7dof", "servicer-dual", "servicer-captured")
"""Built-in models: the paper's emulator (YAML) and the worked spatial examples (URDF)."""
_PLANAR_TOL = 1e-9
MAX_MODEL_BYTES = 16 * MiB
"""Largest model file read [bytes] (a 1000-link URDF chain is ~0.4 MB)."""


def inertial_vector(mass, com, inertia_com):
    """Standard inertial parameters of a body, about its frame origin.

    Parameters
    ----------
    mass : float
        Mass [kg].
    com : array_like of shape (3,)
        Centre of mass in the body frame [m].
    inertia_com : array_like of shape (3, 3)
        Inertia tensor about the centre of mass, body axes [kg m^2].

    Returns
    -------
    ndarray of shape (10,)
        ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (inertia about the origin).
    """
    c = np.asarray(com, dtype=float)
    i_o = np.asarray(inertia_com, dtype=float) + mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array(
        [mass, *(mass * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]]
    )


@dataclass(frozen=True)
class Body:
    """One rigid body and the joint that attaches it to its parent.

    Attributes
    ----------
    name : str
        Link name.
    parent : int
        Index of the parent body, -1 for the base.
    joint : str or None
        Name of the joint to the parent (None for the base).
    joint_type : {"base", "revolute", "prismatic"}
        Continuous joints are revolute joints without position limits.
    axis : ndarray of shape (3,)
        Unit joint axis in the joint frame.
    rotation, translation : ndarray of shape (3, 3) and (3,)
        Placement of the joint frame in the parent body frame (at zero joint position).
    inertial : ndarray of shape (10,)
        Standard inertial parameters about the body frame origin (see ``INERTIAL_NAMES``).
    limits : dict
        ``lower``, ``upper`` [rad or m], ``velocity`` [rad/s or m/s], ``acceleration``
        [rad/s^2 or m/s^2], ``effort`` [N m or N]; absent if unknown. URDF files give the
        acceleration in an extra ``acceleration`` attribute of ``<limit>``.
    known_zero : frozenset of str
        Inertial parameter names known to be zero by construction (structural zeros).
    """

    name: str
    parent: int
    joint: str | None
    joint_type: str
    axis: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    inertial: np.ndarray
    limits: dict = field(default_factory=dict)
    known_zero: frozenset = frozenset()

    @property
    def mass(self) -> float:
        return float(self.inertial[0])

    @property
    def com(self) -> np.ndarray:
        return self.inertial[1:4] / self.inertial[0]


@dataclass(frozen=True)
class Model:
    """A free-floating tree: ``bodies[0]`` is the base, parents come before children.

    Attributes
    ----------
    name : str
    bodies : tuple of Body
    planar : bool
        True when the base moves in its x-y plane and every joint axis is parallel to the
        base z axis (revolute) or lies in that plane (prismatic).
    wheels : tuple of str
        Joints marked as reaction wheels (a rotor with known inertia about its axis).
    source : str
        Where the model came from (preset name or path).
    """

    name: str
    bodies: tuple
    planar: bool = False
    wheels: tuple = ()
    source: str = ""

    @property
    def joints(self) -> tuple:
        """Names of the moving joints, in the order of the columns of ``q``."""
        return tuple(b.joint for b in self.bodies[1:])

    @property
    def n_joints(self) -> int:
        return len(self.bodies) - 1

    @property
    def mass(self) -> float:
        return float(sum(b.mass for b in self.bodies))

    def joint_limits(self, kind: str) -> np.ndarray:
        """Limits of one ``kind`` (``lower``, ``upper``, ``velocity``, ``acceleration``) per
        joint, shape ``(n_joints,)``, NaN where the model gives none."""
        return np.array([b.limits.get(kind, np.nan) for b in self.bodies[1:]], dtype=float)

    def with_inertials(self, inertials) -> "Model":
        """A copy with new standard inertial parameters, ``inertials`` of shape (n_bodies, 10)."""
        return replace(
            self,
            bodies=tuple(replace(b, inertial=np.asarray(p, float)) for b, p in zip(self.bodies, inertials)),
        )

    def as_planar(self) -> "Model":
        """This model in planar mode; a clear error names the first joint that is not planar."""
        for b, axis in zip(self.bodies[1:], _axes_in_base(self)):
            if b.joint_type == "revolute" and np.linalg.norm(np.cross(axis, [0, 0, 1])) > _PLANAR_TOL:
                raise SpaceidError(
                    f"{self.source or self.name}: joint '{b.joint}' has axis {np.round(axis, 6).tolist()} "
                    "in base axes, not parallel to the base z axis: planar mode needs every revolute "
                    "axis along z (drop `planar` to treat the system as spatial)"
                )
            if b.joint_type == "prismatic" and abs(axis[2]) > _PLANAR_TOL:
                raise SpaceidError(
                    f"{self.source or self.name}: prismatic joint '{b.joint}' moves out of the base "
                    "x-y plane: planar mode needs in-plane motion (drop `planar` to treat the system as spatial)"
                )
        return replace(self, planar=True)


def _axes_in_base(model: Model) -> list:
    """Joint axes of the bodies after the base, in base axes at the zero configuration, each (3,)."""
    # Every rotation on the path is about an axis parallel to z in planar mode, so the
    # zero configuration is representative; ``as_planar`` checks exactly this.
    return [r @ b.axis for r, b in zip(zero_rotations(model)[1:], model.bodies[1:])]


def zero_rotations(model: Model) -> list:
    """Orientation of every body's frame in base axes at the zero configuration, each (3, 3), the base's the
    identity; one pass down the tree (parents come first)."""
    rot = [np.eye(3)]
    for b in model.bodies[1:]:
        rot.append(rot[b.parent] @ b.rotation)
    return rot


def symbol_suffix(name: str) -> str:
    """A body or joint name as the suffix of a parameter or symbol name (non-word characters
    become ``_``), so that every definition stays a valid SymPy expression."""
    return re.sub(r"\W", "_", name)


def _check_names(model: Model, where: str):
    """Body names and joint names must be unique, also once made symbol suffixes (``l-1`` and
    ``l_1`` would both be ``m_l_1`` in the parameter names)."""
    for kind, names in (("body", [b.name for b in model.bodies]), ("joint", list(model.joints))):
        seen: dict = {}  # symbol suffix -> the name that gave it
        exact: set = set()
        for name in names:
            if name in exact:
                raise SpaceidError(f"{where}: {kind} name '{name}' appears twice: {kind} names must be unique")
            exact.add(name)
            other = seen.setdefault(symbol_suffix(name), name)
            if other != name:
                raise SpaceidError(
                    f"{where}: {kind} names '{other}' and '{name}' both become '{symbol_suffix(name)}' in parameter "
                    f"names (characters other than letters, digits and _ read as _): rename one"
                )


def _validate(model: Model) -> Model:
    where = model.source or model.name
    _check_names(model, where)
    for i, b in enumerate(model.bodies):
        if not np.all(np.isfinite(b.inertial)):
            raise SpaceidError(f"{where}: body '{b.name}' has non-finite inertial values: give numbers")
        if b.mass <= 0:
            raise SpaceidError(
                f"{where}: body '{b.name}' has mass {b.mass:g} kg: every body needs a positive mass "
                "(merge massless frames into their parent with a fixed joint)"
            )
        i_com = inertia_matrix(b.inertial) - b.mass * _skew(b.com).T @ _skew(b.com)
        check_rigid_inertia(f"{where}: body '{b.name}'", i_com)
        if i > 0:
            if not 0 <= b.parent < i:
                raise SpaceidError(f"{where}: body '{b.name}' must come after its parent")
            if b.joint_type not in ("revolute", "prismatic"):
                raise SpaceidError(
                    f"{where}: joint '{b.joint}' has type '{b.joint_type}': only revolute, continuous, "
                    "prismatic and fixed joints can sit below the floating base"
                )
    return model


def check_rigid_inertia(what: str, inertia_com):
    """Refuse an inertia about the CoM (3, 3) [kg m^2] that no rigid body has: not positive
    semi-definite, or principal moments that violate the triangle inequality; the SpaceidError
    starts with ``what`` (the body or setting)."""
    eig = np.linalg.eigvalsh(np.asarray(inertia_com, float))
    scale = max(abs(eig).max(), 1e-300)
    if eig.min() < -1e-9 * scale:
        raise SpaceidError(
            f"{what} has an inertia tensor about its CoM that is not positive "
            f"(semi-)definite (eigenvalues {np.round(eig, 9).tolist()}): check ixx..izz and their signs"
        )
    e = np.sort(eig)
    if e[0] + e[1] < e[2] * (1 - 1e-6) - 1e-12 * scale:
        raise SpaceidError(
            f"{what} violates the triangle inequality of principal inertias "
            f"({np.round(e, 9).tolist()}): no rigid body has this inertia; check the values"
        )


def perturbed_model(model: Model, seed: int, *, mass: float = 0.15, moments: float = 0.15, com: float = 0.0,
                    exact: bool = False) -> Model:
    """A CAD-like model of ``model``: every body's mass and principal moments about its CoM off
    by up to ``mass``/``moments`` (relative), its CoM moved by up to ``com`` [m] per axis, each
    body still physically consistent (principal moments with a triangle-inequality slack over
    1 %, as a CAD model's are; the geometry unchanged).

    Parameters
    ----------
    model : Model
    seed : int
        Seed of every draw (``numpy.random.default_rng``).
    mass, moments : float
        Largest relative error of each mass and of each principal moment, in [0, 1).
    com : float
        Largest CoM shift per axis [m].
    exact : bool
        False: each factor uniform in ``[1 - e, 1 + e]``; True: exactly ``1 - e`` or ``1 + e``, the
        sign drawn (a model that is off by ``e`` everywhere).

    Returns
    -------
    Model
        A copy with the perturbed inertial parameters.
    """
    for name, value in (("mass", mass), ("moments", moments)):
        if not 0.0 <= float(value) < 1.0:
            raise SpaceidError(f"`{name}`: a relative error must be in [0, 1), got {value!r}")
    if not float(com) >= 0.0:
        raise SpaceidError(f"`com`: a CoM shift must be a length >= 0 [m], got {com!r}")
    rng = np.random.default_rng(seed)

    def factors(e, n):
        return 1.0 + e * (rng.choice([-1.0, 1.0], n) if exact else rng.uniform(-1.0, 1.0, n))

    rows = []
    for b in model.bodies:
        c = np.asarray(b.com, float)
        i_c = inertia_matrix(b.inertial) - b.mass * (c @ c * np.eye(3) - np.outer(c, c))
        w, v = np.linalg.eigh(i_c)  # principal moments about the CoM
        for _ in range(1000):
            new = np.sort(w * factors(moments, 3))
            if new[0] + new[1] > 1.01 * new[2]:
                break
        else:
            new = np.sort(w)
        shift = rng.uniform(-com, com, 3)
        rows.append(inertial_vector(b.mass * factors(mass, 1)[0], c + shift, v @ np.diag(new) @ v.T))
    return model.with_inertials(rows)


def body_index(model: Model, name: str, where: str = "link") -> int:
    """Index in ``model.bodies`` of the body ``name``, or a SpaceidError naming ``where``."""
    return link_frame(model, name, where, tool_links=False)[0]


def link_frame(model: Model, name: str, where: str = "link", *, tool_links: bool = True) -> tuple:
    """The body that carries the link ``name`` and the link frame's placement in it.

    A body of the model is its own frame. With ``tool_links``, a link on fixed joints below a
    body (a tool or gripper link, merged into that body when the model was read) is looked up in
    the URDF the model came from (a URDF preset or file).

    Returns
    -------
    (int, ndarray of shape (3, 3), ndarray of shape (3,))
        Index in ``model.bodies``, rotation and translation [m] of the link frame in the body frame.

    Raises
    ------
    SpaceidError
        ``name`` is none of these; the message names ``where`` and lists the bodies.
    """
    names = [b.name for b in model.bodies]
    if name in names:
        return names.index(name), np.eye(3), np.zeros(3)
    text = _urdf_text(model) if tool_links else None
    if text is not None:
        import pinocchio as pin

        pmodel = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        for frame in pmodel.frames:
            if frame.name == name and str(frame.type) == "BODY":  # a model body is joint j's, body j - 1
                return frame.parentJoint - 1, np.array(frame.placement.rotation), np.array(frame.placement.translation)
    tools = " (a URDF model also accepts links on fixed joints below them)" if tool_links else ""
    raise SpaceidError(f"{where} names '{name}', which is not a body of model {model.name} "
                       f"(bodies: {', '.join(names)}{tools}): use one of these names")  # fmt: skip


def _urdf_text(model: Model) -> str | None:
    """The URDF text of ``model``'s source (a preset or a file), or None for YAML models."""
    source = str(model.source)
    if source in PRESETS:
        file = resources.files("spaceid.models.presets").joinpath(f"{source}.urdf")
        return file.read_text() if file.is_file() else None
    path = Path(source)
    return path.read_text() if path.suffix.lower() == ".urdf" and path.is_file() else None


def attach_payload(model: Model, link: str, inertial, *, where: str = "link") -> Model:
    """``model`` with a payload rigidly fixed to its body ``link`` (a grasped or docked object).

    Inertial parameters of rigidly joined bodies add when taken about the same point in the same
    axes, so the body's parameters become its own plus the payload's.

    Parameters
    ----------
    model : Model
    link : str
        Name of the body that holds the payload.
    inertial : array_like of shape (10,)
        The payload's standard inertial parameters about the origin of ``link``, in its axes
        (:func:`inertial_vector` of its mass, its CoM in that frame and its inertia about the CoM
        in those axes).
    where : str
        What names ``link`` in an error (an option or setting).

    Returns
    -------
    Model
        The copy; the structural zeros (``known_zero``) of ``link`` that the payload makes nonzero
        are dropped.
    """
    i = body_index(model, link, where)
    payload = np.asarray(inertial, float)
    if payload.shape != (10,) or not np.all(np.isfinite(payload)) or payload[0] <= 0:
        raise SpaceidError(
            f"{where}: the payload needs 10 finite inertial parameters with a positive mass, got {shown(inertial)}"
        )
    return add_to_body(model, i, payload)


def add_to_body(model: Model, index: int, inertial) -> Model:
    """``model`` with ``inertial`` (10,) added to the parameters of body ``index``, unchecked (a
    trial or zero payload too, as an estimator needs): :func:`attach_payload` without its checks.
    The structural zeros (``known_zero``) that it makes nonzero are dropped."""
    body = model.bodies[index]
    broken = {n for n, value in zip(INERTIAL_NAMES, inertial) if value != 0}
    new = replace(body, inertial=body.inertial + inertial, known_zero=frozenset(body.known_zero - broken))
    return replace(model, bodies=model.bodies[:index] + (new,) + model.bodies[index + 1 :])


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def inertia_matrix(p):
    """Inertia about the body origin as a 3x3 matrix from the standard parameters ``p``."""
    return np.array([[p[4], p[5], p[7]], [p[5], p[6], p[8]], [p[7], p[8], p[9]]])


def _rpy_matrix(rpy):
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


# ---------------------------------------------------------------- YAML ---------------------


_MODEL_KEYS = ("name", "planar", "wheels", "bodies")
_BODY_KEYS = ("name", "parent", "joint", "mass", "com", "inertia", "known_zero")
_JOINT_KEYS = ("name", "type", "xyz", "rpy", "axis", "limit")
_LIMIT_UNITS = {"lower": "rad or m", "upper": "rad or m", "velocity": "rad/s or m/s",
                "acceleration": "rad/s^2 or m/s^2", "effort": "N m or N"}
_LIMIT_KEYS = tuple(_LIMIT_UNITS)
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


def _known_keys(where, spec, known, what):
    """Refuse keys of the mapping ``spec`` not in ``known`` (a typo would be silently ignored,
    e.g. ``inertial:`` leaving a body without inertia), suggesting the closest known key."""
    for key in spec:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise SpaceidError(f"{where}: unknown key {shown(key)} in {what}: {hint}the keys are {', '.join(known)}")


def _yaml_mapping(where, value, key, known):
    """``value`` checked to be a mapping with keys among ``known`` (None reads as empty)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SpaceidError(f"{where}: '{key}' must be a mapping with keys among {', '.join(known)}, got {shown(value)}")
    _known_keys(where, value, known, f"'{key}'")
    return value


def _yaml_number(where, value, key, unit):
    """``value`` as a finite float; booleans, strings and lists are refused with the key named."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpaceidError(f"{where}: '{key}' must be a number [{unit}], got {shown(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise SpaceidError(f"{where}: '{key}' is non-finite ({value}): give a finite number [{unit}]")
    return number


def _yaml_vector(where, value, n, key, unit="m"):
    if not isinstance(value, list) or len(value) != n:
        raise SpaceidError(f"{where}: '{key}' must be a list of {n} numbers, got {shown(value)}")
    return np.array([_yaml_number(where, v, key, unit) for v in value])


def _yaml_inertia(where, spec, key):
    """Inertia about the CoM from ``{izz: ..}`` style mappings or a 6-list ixx ixy ixz iyy iyz izz."""
    if isinstance(spec, dict):
        _known_keys(where, spec, _INERTIA_KEYS, f"'{key}'")
        v = [_yaml_number(where, spec.get(k, 0.0), f"{key}.{k}", "kg m^2") for k in _INERTIA_KEYS]
    else:
        v = _yaml_vector(where, spec, 6, key, "kg m^2")
    ixx, ixy, ixz, iyy, iyz, izz = v
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _yaml_known_zero(here, value):
    if not isinstance(value, list) or not all(isinstance(k, str) for k in value):
        raise SpaceidError(
            f"{here}: 'known_zero' must be a list of parameter names ({', '.join(INERTIAL_NAMES)}), got {shown(value)}"
        )
    bad = set(value) - set(INERTIAL_NAMES)
    if bad:
        raise SpaceidError(f"{here}: unknown known_zero name(s) {shown(sorted(bad))}: use {', '.join(INERTIAL_NAMES)}")
    return frozenset(value)


def _yaml_limits(here, joint):
    """The joint's limits: numbers, lower <= upper, rates and effort positive."""
    spec = _yaml_mapping(here, joint.get("limit"), "joint.limit", _LIMIT_KEYS)
    limits = {k: _yaml_number(here, v, f"joint.limit.{k}", _LIMIT_UNITS[k]) for k, v in spec.items()}
    if limits.get("lower", -math.inf) > limits.get("upper", math.inf):
        raise SpaceidError(
            f"{here}: joint limit lower = {limits['lower']:g} is above upper = {limits['upper']:g}: swap them"
        )
    for k in ("velocity", "acceleration", "effort"):
        if k in limits and limits[k] <= 0:
            raise SpaceidError(f"{here}: joint.limit.{k} is {limits[k]:g}: give a positive limit or leave it out")
    return limits


def _yaml_body(where, spec, names):
    name = spec.get("name")
    if not isinstance(name, str) or not name:
        raise SpaceidError(f"{where}: every body needs a 'name' (a string), got {shown(name)}")
    here = f"{where}: body '{shown(name)[1:-1]}'"
    _known_keys(here, spec, _BODY_KEYS, "the body")
    if "mass" not in spec:
        raise SpaceidError(f"{here} has no 'mass': give it in kg")
    mass = _yaml_number(here, spec["mass"], "mass", "kg")
    com = _yaml_vector(here, spec.get("com", [0, 0, 0]), 3, "com")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused by _validate, by name
        inertial = inertial_vector(mass, com, _yaml_inertia(here, spec.get("inertia", {}), "inertia"))
    known_zero = _yaml_known_zero(here, spec.get("known_zero", []))
    for k in known_zero:
        if abs(inertial[INERTIAL_NAMES.index(k)]) > 1e-12 * max(1.0, abs(inertial).max()):
            raise SpaceidError(f"{here} declares {k} known to be zero but its value is not zero")
    if "parent" not in spec:
        if "joint" in spec:
            raise SpaceidError(f"{here} has a 'joint' but no 'parent': give the parent body, or drop the joint")
        return Body(name, -1, None, "base", np.zeros(3), np.eye(3), np.zeros(3), inertial, {}, known_zero)
    parent = spec["parent"]
    if not isinstance(parent, str) or parent not in names:
        raise SpaceidError(
            f"{here} has parent {shown(parent)}, which is not listed before it: list every body after its parent"
        )
    joint = _yaml_mapping(here, spec.get("joint"), "joint", _JOINT_KEYS)
    jtype = joint.get("type", "revolute")
    if jtype not in ("revolute", "continuous", "prismatic"):
        raise SpaceidError(f"{here}: joint type {shown(jtype)} is not one of revolute, continuous, prismatic")
    joint_name = joint.get("name", f"{name}_joint")
    if not isinstance(joint_name, str) or not joint_name:
        raise SpaceidError(f"{here}: 'joint.name' must be a string, got {shown(joint_name)}")
    axis = _yaml_vector(here, joint.get("axis", [0, 0, 1]), 3, "joint.axis", "a direction")
    if np.linalg.norm(axis) == 0:
        raise SpaceidError(f"{here}: joint axis is zero: give a direction such as [0, 0, 1]")
    limits = _yaml_limits(here, joint)
    if jtype == "continuous":
        limits.pop("lower", None), limits.pop("upper", None)
    return Body(
        name,
        names[parent],
        joint_name,
        "prismatic" if jtype == "prismatic" else "revolute",
        axis / np.linalg.norm(axis),
        _rpy_matrix(_yaml_vector(here, joint.get("rpy", [0, 0, 0]), 3, "joint.rpy", "rad")),
        _yaml_vector(here, joint.get("xyz", [0, 0, 0]), 3, "joint.xyz"),
        inertial,
        limits,
        known_zero,
    )


def _model_from_yaml(text: str, where: str) -> Model:
    spec = parse_yaml(text, where)
    if not isinstance(spec, dict) or not isinstance(spec.get("bodies"), list) or not spec["bodies"]:
        raise SpaceidError(f"{where}: a YAML model needs a 'bodies' list, the base first")
    _known_keys(where, spec, _MODEL_KEYS, "the model")
    names: dict = {}
    bodies = []
    for entry in spec["bodies"]:
        if not isinstance(entry, dict):
            raise SpaceidError(f"{where}: every entry of 'bodies' must be a mapping, got {shown(entry)}")
        body = _yaml_body(where, entry, names)
        if (body.parent < 0) != (not bodies):
            raise SpaceidError(
                f"{where}: exactly the first body (the base) has no parent; body '{body.name}' breaks this"
            )
        if body.name in names:
            raise SpaceidError(f"{where}: body name '{body.name}' appears twice: body names must be unique")
        names[body.name] = len(bodies)
        bodies.append(body)
    wheels = spec.get("wheels", [])
    if not isinstance(wheels, list) or not all(isinstance(w, str) for w in wheels):
        raise SpaceidError(f"{where}: 'wheels' must be a list of joint names, got {shown(wheels)}")
    planar = spec.get("planar", False)
    if not isinstance(planar, bool):
        raise SpaceidError(f"{where}: 'planar' must be true or false, got {shown(planar)}")
    name = spec.get("name", Path(where).stem)
    if not isinstance(name, (str, int, float)) or isinstance(name, bool):
        raise SpaceidError(f"{where}: 'name' must be a string, got {shown(name)}")
    model = _validate(Model(str(name), tuple(bodies), False, tuple(wheels), where))
    unknown = set(model.wheels) - set(model.joints)
    if unknown:
        raise SpaceidError(
            f"{where}: 'wheels' names unknown joint(s) {shown(sorted(unknown))}: use {', '.join(model.joints)}"
        )
    return model.as_planar() if planar else model


# ---------------------------------------------------------------- URDF ---------------------


_URDF_MOVING = ("revolute", "continuous", "prismatic")


def _check_urdf_tree(text: str, where: str):
    """Reject unsafe or malformed XML and tree errors with messages Pinocchio does not give
    (or gives wrongly: a cycle beside the tree is dropped, a zero axis makes a revolute joint
    prismatic); return the parsed root element."""
    import defusedxml.ElementTree as ET
    from defusedxml import DefusedXmlException

    try:
        root = ET.fromstring(text)
    except DefusedXmlException:
        raise SpaceidError(f"{where}: the URDF declares XML entities or a DTD, which are refused for safety: "
                           "remove them") from None
    except ET.ParseError as exc:
        raise SpaceidError(f"{where}: not well-formed XML ({exc}): fix the URDF") from None
    if root.tag != "robot":
        raise SpaceidError(f"{where}: the root element is <{shown(root.tag)[1:-1]}>, not <robot>: is this a URDF?")
    links = [link.get("name") for link in root.findall("link")]
    _urdf_unique(where, "link", links)
    _urdf_unique(where, "joint", [joint.get("name") for joint in root.findall("joint")])
    parent_of = {}
    for joint in root.findall("joint"):
        name, jtype = joint.get("name"), joint.get("type")
        _urdf_joint(where, joint, name, jtype, set(links))
        child_name = joint.find("child").get("link")
        if child_name in parent_of:
            raise SpaceidError(
                f"{where}: link '{child_name}' has two parent joints ('{parent_of[child_name][0]}' and "
                f"'{name}'): closed kinematic loops are not supported; cut the loop"
            )
        parent_of[child_name] = (name, joint.find("parent").get("link"))
    roots = [name for name in links if name not in parent_of]
    if len(roots) > 1:
        raise SpaceidError(
            f"{where}: {len(roots)} root links ({shown(roots)[1:-1]}): the floating base must be the only link "
            "without a parent joint; attach the others with joints (fixed if rigid) or remove them"
        )
    _urdf_cycle(where, links, parent_of, roots)
    for link in root.findall("link"):
        mass = link.find("inertial/mass")
        value = None if mass is None else _urdf_float(mass.get("value"))
        if mass is not None and not value > 0:
            raise SpaceidError(f"{where}: link '{link.get('name')}' has mass {shown(mass.get('value'))}: masses "
                               "must be positive numbers [kg]")
    return root


def _urdf_float(text):
    """``text`` as a float, NaN when it is missing or not a number."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _urdf_unique(where, kind, names):
    seen = set()
    for name in names:
        if not name:
            raise SpaceidError(f"{where}: a <{kind}> has no name: give every {kind} a name attribute")
        if name in seen:
            raise SpaceidError(f"{where}: {kind} name '{name}' appears twice: {kind} names must be unique")
        seen.add(name)


def _urdf_joint(where, joint, name, jtype, links):
    """One <joint>: a supported type, existing parent and child links, a non-zero numeric axis
    and the limits URDF requires, ordered."""
    here = f"{where}: joint '{name}'"
    if jtype in ("floating", "planar"):
        raise SpaceidError(
            f"{here} is of type '{jtype}' below the root: only the root link floats; "
            "make it fixed, revolute, continuous or prismatic"
        )
    if jtype not in (*_URDF_MOVING, "fixed"):
        raise SpaceidError(f"{here} has unknown type {shown(jtype)}: use revolute, continuous, prismatic or fixed")
    for tag in ("parent", "child"):
        element = joint.find(tag)
        if element is None:
            raise SpaceidError(f"{here} lacks a <{tag}> element")
        if element.get("link") not in links:
            raise SpaceidError(f"{here}: {tag} link {shown(element.get('link'))} is not a <link> of the URDF")
    if jtype == "fixed":
        return
    axis_element = joint.find("axis")
    text = "1 0 0" if axis_element is None else axis_element.get("xyz", "")  # URDF's default axis is x
    axis = [_urdf_float(v) for v in text.split()]
    if len(axis) != 3 or not np.all(np.isfinite(axis)):
        raise SpaceidError(f"{here}: axis xyz={shown(text)} is not 3 numbers: give a direction such as '0 0 1'")
    if not np.any(axis):
        raise SpaceidError(f"{here}: axis xyz='{text}' is zero: give the direction of the joint, such as '0 0 1'")
    limit = joint.find("limit")
    if limit is None:
        if jtype != "continuous":
            raise SpaceidError(
                f"{here} ({jtype}) has no <limit>: URDF requires lower, upper, velocity and effort; "
                "add one, or make the joint continuous"
            )
        return
    values = {k: _urdf_float(limit.get(k, "0")) for k in ("lower", "upper", "velocity", "effort")}
    bad = [k for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise SpaceidError(f"{here}: <limit> {bad[0]}={shown(limit.get(bad[0]))} is not a finite number: fix it")
    if jtype != "continuous" and values["lower"] > values["upper"]:
        raise SpaceidError(
            f"{here}: limit lower = {values['lower']:g} is above upper = {values['upper']:g}: swap them"
        )
    if joint.find("mimic") is not None:
        warnings.warn(
            f"{here} mimics '{joint.find('mimic').get('joint')}': it is treated as an independent joint, so "
            "its angles must be in the logs, and excitation design does not keep the coupling",
            stacklevel=5,
        )


def _urdf_cycle(where, links, parent_of, roots):
    """Every link must hang below the root; one that does not sits on (or below) a cycle of
    joints, which Pinocchio would silently drop: name the joints of that cycle."""
    below = set(roots)
    children: dict = {}
    for child, (_, parent) in parent_of.items():
        children.setdefault(parent, []).append(child)
    stack = list(roots)
    while stack:
        for child in children.get(stack.pop(), []):
            if child not in below:
                below.add(child)
                stack.append(child)
    detached = [name for name in links if name not in below]
    if not detached:
        return
    path, link = [], detached[0]
    while link not in path:  # walk up the parents: every detached link leads into a cycle
        path.append(link)
        link = parent_of[link][1]
    cycle = path[path.index(link):][::-1]  # parent before child
    joints = [parent_of[name][0] for name in cycle]
    parents = [parent_of[name][1] for name in cycle]
    raise SpaceidError(
        f"{where}: joints {shown(joints)[1:-1]} form a cycle (links {shown(parents)[1:-1]}), apart from the tree "
        f"of root link '{roots[0] if roots else '?'}': closed loops are not supported; cut the loop and attach it"
    )


def _urdf_accelerations(root, where: str) -> dict:
    """``{joint: acceleration limit}`` from the ``acceleration`` attribute of ``<limit>``.

    URDF has no acceleration limit; this extra attribute (which Pinocchio and other URDF
    parsers ignore) keeps the limit in the file, so the preset and the same file loaded by path
    agree. Units: rad/s^2 (revolute) or m/s^2 (prismatic)."""
    out = {}
    for joint in root.findall("joint"):
        limit = joint.find("limit")
        value = None if limit is None else limit.get("acceleration")
        if value is None:
            continue
        try:
            number = float(value)
        except ValueError:
            number = np.nan
        if not number > 0 or not np.isfinite(number):
            raise SpaceidError(f"{where}: joint '{joint.get('name')}' has acceleration limit '{value}': give a "
                               "positive number [rad/s^2 or m/s^2]")
        out[joint.get("name")] = number
    return out


def _model_from_urdf(text: str, where: str) -> Model:
    """The model of the URDF ``text`` (named after ``where``): from the on-disk cache (:mod:`spaceid._cache`) when it
    holds this text's, else parsed by Pinocchio (:func:`_parsed_urdf`) and stored there. A cached read takes a
    millisecond where Pinocchio's import alone takes 0.06 s of every command on a URDF model (the servicer's parse:
    0.01 s more); a URDF that is refused is never stored, nor one that warns (a mimic joint: said at every load)."""
    if "<mimic" in text:
        return _parsed_urdf(text, where)
    key = cache_key(hashlib.sha256(text.encode()).hexdigest(), *_converter())
    stored = read_cached(_URDF_KIND, key)
    if stored is not None:
        with contextlib.suppress(KeyError, ValueError, IndexError):  # an entry of another layout: parse again
            return _validate(_model_from_stored(stored, where))  # (checked again: an entry is a file like any)
    model = _parsed_urdf(text, where)
    write_cached(_URDF_KIND, key, _model_to_stored(model))
    return model


_URDF_KIND = "urdf-model"
_LIMIT_KINDS = ("velocity", "effort", "lower", "upper", "acceleration")
"""A body's limits as :func:`from_pinocchio` and :func:`_parsed_urdf` insert them (a cached model keeps the order)."""


@functools.cache
def _converter() -> tuple:
    """What a parsed model depends on besides the text, once a process: the installed Pinocchio's version, read from
    its metadata (importing it is what the cache saves), and the hash of this module's code."""
    from importlib import metadata

    try:
        version = metadata.version("pin")
    except metadata.PackageNotFoundError:  # installed another way: its name as the conda package's
        version = metadata.version("pinocchio")
    return version, source_digest(__file__)


def _model_to_stored(model: Model) -> dict:
    """The arrays that rebuild a URDF's ``model`` (:func:`_model_from_stored`): its parsed bodies; the name of the
    robot (the URDF's, for a model read from text alone) and its source are the caller's."""
    bodies = model.bodies
    return {"names": stored_text([b.name for b in bodies]), "joints": stored_text([b.joint or "" for b in bodies]),
            "kinds": stored_text([b.joint_type for b in bodies]), "robot": stored_text([model.name]),
            "parents": np.array([b.parent for b in bodies]), "axes": np.array([b.axis for b in bodies]),
            "rotations": np.array([b.rotation for b in bodies]),
            "translations": np.array([b.translation for b in bodies]),
            "inertials": np.array([b.inertial for b in bodies]),
            "limits": np.array([[b.limits.get(k, np.nan) for k in _LIMIT_KINDS] for b in bodies])}  # fmt: skip


def _model_from_stored(stored: dict, where: str) -> Model:
    """The model of :func:`_model_to_stored`'s arrays, read from ``where`` (its name: the file's stem)."""
    names, joints, kinds = (stored_strings(stored[k]) for k in ("names", "joints", "kinds"))
    bodies = tuple(
        Body(name, int(parent), joint or None, kind, axis, rotation, translation, inertial,
             {k: float(v) for k, v in zip(_LIMIT_KINDS, limits) if not np.isnan(v)})
        for name, parent, joint, kind, axis, rotation, translation, inertial, limits in zip(
            names, stored["parents"], joints, kinds, stored["axes"], stored["rotations"], stored["translations"],
            stored["inertials"], stored["limits"], strict=True))  # fmt: skip
    return Model(Path(where).stem if where else stored_strings(stored["robot"])[0], bodies, False, (), where)


def _parsed_urdf(text: str, where: str) -> Model:
    """The model of the URDF ``text``, parsed by Pinocchio (its tree checked first: a clear error for what its
    parser would accept or misread)."""
    import pinocchio as pin

    accelerations = _urdf_accelerations(_check_urdf_tree(text, where), where)
    pmodel, failure = None, ""
    with _captured_stderr() as printed:
        try:
            pmodel = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        except (RuntimeError, ValueError) as exc:
            failure = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    # urdfdom prints its errors, and for some (an unreadable <inertial>) drops the element and goes on
    errors = [" ".join(line.split()) for line in printed() if line.lstrip().startswith("Error")]
    if pmodel is None or errors:
        said = "; ".join([*errors[:2], failure] if failure else errors[:2])
        raise SpaceidError(f"{where}: the URDF parser refused the file ({said}): fix the element it names")
    model = from_pinocchio(pmodel, where)
    bodies = tuple(replace(b, limits={**b.limits, "acceleration": accelerations[b.joint]})
                   if b.joint in accelerations else b for b in model.bodies)
    return _validate(replace(model, bodies=bodies))


@contextlib.contextmanager
def _captured_stderr():
    """Capture what C++ code (urdfdom) prints on file descriptor 2 inside the block, so that a
    library call prints nothing; yields a function returning the captured non-empty lines."""
    lines: list = []
    sys.stderr.flush()
    with tempfile.TemporaryFile(mode="w+b") as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            yield lambda: lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read(4096).decode("utf-8", "replace")
            lines[:] = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("at line")]


def from_pinocchio(pmodel, source: str = "") -> Model:
    """Convert a Pinocchio model whose joint 1 is a free flyer into a :class:`Model`."""
    body_names = {}
    for frame in pmodel.frames:
        if str(frame.type) == "BODY" and frame.parentJoint not in body_names:
            body_names[frame.parentJoint] = frame.name
    import pinocchio as pin

    neutral = pin.neutral(pmodel)
    bodies = []
    for j in range(1, pmodel.njoints):
        jm = pmodel.joints[j]
        short = jm.shortname()
        inertial = np.asarray(pmodel.inertias[j].toDynamicParameters(), float)
        name = body_names.get(j, pmodel.names[j])
        if j == 1:
            if "FreeFlyer" not in short:
                raise SpaceidError(f"{source}: the root joint must be a free flyer, got {short}")
            bodies.append(Body(name, -1, None, "base", np.zeros(3), np.eye(3), np.zeros(3), inertial))
            continue
        if jm.nv != 1:
            raise SpaceidError(f"{source}: joint '{pmodel.names[j]}' ({short}) has {jm.nv} degrees of freedom: "
                               "only 1-DOF joints are supported")
        # the motion subspace gives the axis for every 1-DOF joint kind (aligned or not)
        jdata = jm.createData()
        jm.calc(jdata, neutral)
        motion = np.asarray(jdata.S, float).ravel()
        kind = "revolute" if np.linalg.norm(motion[3:]) > 0.5 else "prismatic"
        axis = motion[3:] if kind == "revolute" else motion[:3]
        placement = pmodel.jointPlacements[j]
        iq, iv = jm.idx_q, jm.idx_v
        limits = {"velocity": float(pmodel.velocityLimit[iv]), "effort": float(pmodel.effortLimit[iv])}
        if jm.nq == 1:  # continuous joints (nq = 2) have no position limits
            limits.update(lower=float(pmodel.lowerPositionLimit[iq]), upper=float(pmodel.upperPositionLimit[iq]))
        limits = {k: v for k, v in limits.items() if np.isfinite(v) and abs(v) < 1e10}
        if limits.get("lower") == 0 and limits.get("upper") == 0:
            limits.pop("lower"), limits.pop("upper")
        bodies.append(
            Body(
                name,
                pmodel.parents[j] - 1,
                pmodel.names[j],
                kind,
                axis,
                np.array(placement.rotation),
                np.array(placement.translation),
                inertial,
                # position limits of any sign ([-2, -0.5] rad keeps its upper limit); rates and effort > 0
                {k: v for k, v in limits.items() if v > 0 or k in ("lower", "upper")},
            )
        )
    return Model(Path(source).stem if source else pmodel.name, tuple(bodies), False, (), source)


def to_pinocchio(model: Model):
    """A Pinocchio model (free-flyer root, one joint per body) equivalent to ``model``."""
    import pinocchio as pin

    pmodel = pin.Model()
    pmodel.name = model.name
    ids = []
    for b in model.bodies:
        if b.parent < 0:
            jid = pmodel.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root_joint")
        else:
            kind = pin.JointModelPrismaticUnaligned if b.joint_type == "prismatic" else pin.JointModelRevoluteUnaligned
            jm = kind(b.axis)
            jid = pmodel.addJoint(ids[b.parent], jm, pin.SE3(b.rotation, b.translation), b.joint)
        ids.append(jid)
        pmodel.appendBodyToJoint(jid, pin.Inertia.FromDynamicParameters(b.inertial), pin.SE3.Identity())
        pmodel.addBodyFrame(b.name, jid, pin.SE3.Identity(), 0)
    return pmodel


# ---------------------------------------------------------------- entry point --------------


def load_model(source, *, planar: bool | None = None) -> Model:
    """Load a model from a preset name, a ``.urdf`` file or a ``.yaml``/``.yml`` file.

    Parameters
    ----------
    source : str or Path or Model
        Preset name (see ``PRESETS``) or path.
    planar : bool, optional
        Force planar mode (True: every joint must be planar, else a clear error), spatial
        mode (False), or keep the file's own setting (None).
    """
    if isinstance(source, Model):
        model = source
    elif str(source) in PRESETS:
        files = resources.files("spaceid.models.presets")
        if files.joinpath(f"{source}.yaml").is_file():
            model = _model_from_yaml(files.joinpath(f"{source}.yaml").read_text(), str(source))
        else:
            model = _model_from_urdf(files.joinpath(f"{source}.urdf").read_text(), str(source))
        model = replace(model, name=str(source), source=str(source))
    else:
        path = Path(source)
        if not path.exists():
            raise SpaceidError(
                f"{path}: no such model file; give a URDF or YAML path or a preset ({', '.join(PRESETS)})"
            )
        text = read_input_text(path, "model file", MAX_MODEL_BYTES)
        suffix = path.suffix.lower()
        if suffix == ".urdf" or (suffix not in (".yaml", ".yml") and text.lstrip().startswith("<")):
            model = _model_from_urdf(text, str(path))
        else:
            model = _model_from_yaml(text, str(path))
        model = replace(model, source=str(path.resolve()))  # results name it from anywhere
    if planar is True:
        return model.as_planar()
    if planar is False:
        return replace(model, planar=False)
    return model
