"""Robot description of a free-floating system: a tree of rigid bodies on a floating base.

A :class:`Model` is immutable. It is loaded from URDF (parsed by Pinocchio; its root link is
the floating base and fixed joints are merged), from a compact YAML description, or from a
built-in preset (``cepheus``, ``cepheus-rw``). Inertial parameters follow Pinocchio's order
``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` with the inertia about the body frame
origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from .._yaml import parse_yaml

__all__ = [
    "INERTIAL_NAMES",
    "Body",
    "Model",
    "PRESETS",
    "load_model",
    "inertial_vector",
    "to_pinocchio",
]

INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
PRESETS = ("cepheus", "cepheus-rw", "satellite-7dof", "servicer-dual", "servicer-captured")
"""Built-in models: the paper's emulator (YAML) and the worked spatial examples (URDF)."""
_PLANAR_TOL = 1e-9


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
        for b in self.bodies[1:]:
            axis = _axis_in_base(self, b)
            if b.joint_type == "revolute" and np.linalg.norm(np.cross(axis, [0, 0, 1])) > _PLANAR_TOL:
                raise SpaceidError(
                    f"{self.source or self.name}: joint '{b.joint}' has axis {np.round(axis, 6).tolist()} "
                    "in base axes, not parallel to the base z axis: planar mode needs every revolute "
                    "axis along z (drop --planar to treat the system as spatial)"
                )
            if b.joint_type == "prismatic" and abs(axis[2]) > _PLANAR_TOL:
                raise SpaceidError(
                    f"{self.source or self.name}: prismatic joint '{b.joint}' moves out of the base "
                    "x-y plane: planar mode needs in-plane motion (drop --planar)"
                )
        return replace(self, planar=True)


def _axis_in_base(model: Model, body: Body) -> np.ndarray:
    """Joint axis of ``body`` in base axes at the zero configuration."""
    rot = body.rotation
    parent = body.parent
    while parent > 0:
        rot = model.bodies[parent].rotation @ rot
        parent = model.bodies[parent].parent
    # Every rotation on the path is about an axis parallel to z in planar mode, so the
    # zero configuration is representative; ``as_planar`` checks exactly this.
    return rot @ body.axis


def _validate(model: Model) -> Model:
    where = model.source or model.name
    seen = set()
    for i, b in enumerate(model.bodies):
        if b.name in seen:
            raise SpaceidError(f"{where}: body name '{b.name}' appears twice: body names must be unique")
        seen.add(b.name)
        if not np.all(np.isfinite(b.inertial)):
            raise SpaceidError(f"{where}: body '{b.name}' has non-finite inertial values: give numbers")
        if b.mass <= 0:
            raise SpaceidError(
                f"{where}: body '{b.name}' has mass {b.mass:g} kg: every body needs a positive mass "
                "(merge massless frames into their parent with a fixed joint)"
            )
        i_com = _inertia_matrix(b.inertial) - b.mass * _skew(b.com).T @ _skew(b.com)
        eig = np.linalg.eigvalsh(i_com)
        scale = max(abs(eig).max(), 1e-300)
        if eig.min() < -1e-9 * scale:
            raise SpaceidError(
                f"{where}: body '{b.name}' has an inertia tensor about its CoM that is not positive "
                f"(semi-)definite (eigenvalues {np.round(eig, 9).tolist()}): check ixx..izz and their signs"
            )
        e = np.sort(eig)
        if e[0] + e[1] < e[2] * (1 - 1e-6) - 1e-12 * scale:
            raise SpaceidError(
                f"{where}: body '{b.name}' violates the triangle inequality of principal inertias "
                f"({np.round(e, 9).tolist()}): no rigid body has this inertia; check the values"
            )
        if i > 0:
            if not 0 <= b.parent < i:
                raise SpaceidError(f"{where}: body '{b.name}' must come after its parent")
            if b.joint_type not in ("revolute", "prismatic"):
                raise SpaceidError(
                    f"{where}: joint '{b.joint}' has type '{b.joint_type}': only revolute, continuous, "
                    "prismatic and fixed joints can sit below the floating base"
                )
    return model


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _inertia_matrix(p):
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


def _yaml_vector(where, value, n, key):
    try:
        arr = np.asarray(value, dtype=float).reshape(n)
    except (TypeError, ValueError):
        raise SpaceidError(f"{where}: '{key}' must be a list of {n} numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise SpaceidError(f"{where}: '{key}' holds NaN or infinite values: give finite numbers")
    return arr


def _yaml_inertia(where, spec, key):
    """Inertia about the CoM from ``{izz: ..}`` style mappings or a 6-list ixx ixy ixz iyy iyz izz."""
    if isinstance(spec, dict):
        unknown = set(spec) - {"ixx", "ixy", "ixz", "iyy", "iyz", "izz"}
        if unknown:
            raise SpaceidError(f"{where}: unknown key(s) {sorted(unknown)} in '{key}': use ixx, ixy, ixz, iyy, iyz, izz")
        v = [float(spec.get(k, 0.0)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")]
    else:
        v = _yaml_vector(where, spec, 6, key)
    ixx, ixy, ixz, iyy, iyz, izz = v
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _yaml_body(where, spec, names):
    name = spec.get("name")
    if not isinstance(name, str):
        raise SpaceidError(f"{where}: every body needs a 'name'")
    here = f"{where}: body '{name}'"
    if "mass" not in spec:
        raise SpaceidError(f"{here} has no 'mass': give it in kg")
    mass = float(spec["mass"])
    com = _yaml_vector(here, spec.get("com", [0, 0, 0]), 3, "com")
    inertial = inertial_vector(mass, com, _yaml_inertia(here, spec.get("inertia", {}), "inertia"))
    known_zero = frozenset(spec.get("known_zero", ()))
    bad = known_zero - set(INERTIAL_NAMES)
    if bad:
        raise SpaceidError(f"{here}: unknown known_zero name(s) {sorted(bad)}: use {', '.join(INERTIAL_NAMES)}")
    for k in known_zero:
        if abs(inertial[INERTIAL_NAMES.index(k)]) > 1e-12 * max(1.0, abs(inertial).max()):
            raise SpaceidError(f"{here} declares {k} known to be zero but its value is not zero")
    if "parent" not in spec:
        return Body(name, -1, None, "base", np.zeros(3), np.eye(3), np.zeros(3), inertial, {}, known_zero)
    if spec["parent"] not in names:
        raise SpaceidError(f"{here} has parent '{spec['parent']}', which is not listed before it")
    joint = spec.get("joint") or {}
    jtype = joint.get("type", "revolute")
    if jtype not in ("revolute", "continuous", "prismatic"):
        raise SpaceidError(f"{here}: joint type '{jtype}' is not one of revolute, continuous, prismatic")
    axis = _yaml_vector(here, joint.get("axis", [0, 0, 1]), 3, "joint.axis")
    if np.linalg.norm(axis) == 0:
        raise SpaceidError(f"{here}: joint axis is zero: give a direction such as [0, 0, 1]")
    limits = {k: float(v) for k, v in (joint.get("limit") or {}).items()}
    if jtype == "continuous":
        limits.pop("lower", None), limits.pop("upper", None)
    return Body(
        name,
        names[spec["parent"]],
        str(joint.get("name", f"{name}_joint")),
        "prismatic" if jtype == "prismatic" else "revolute",
        axis / np.linalg.norm(axis),
        _rpy_matrix(_yaml_vector(here, joint.get("rpy", [0, 0, 0]), 3, "joint.rpy")),
        _yaml_vector(here, joint.get("xyz", [0, 0, 0]), 3, "joint.xyz"),
        inertial,
        limits,
        known_zero,
    )


def _model_from_yaml(text: str, where: str) -> Model:
    spec = parse_yaml(text, where)
    if not isinstance(spec, dict) or not isinstance(spec.get("bodies"), list) or not spec["bodies"]:
        raise SpaceidError(f"{where}: a YAML model needs a 'bodies' list, the base first")
    names: dict = {}
    bodies = []
    try:
        for entry in spec["bodies"]:
            if not isinstance(entry, dict):
                raise SpaceidError(f"{where}: every entry of 'bodies' must be a mapping")
            body = _yaml_body(where, entry, names)
            if (body.parent < 0) != (not bodies):
                raise SpaceidError(f"{where}: exactly the first body (the base) has no parent; body '{body.name}' breaks this")
            names[body.name] = len(bodies)
            bodies.append(body)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, SpaceidError):
            raise
        raise SpaceidError(f"{where}: a value could not be read as a number ({exc})") from None
    model = _validate(
        Model(str(spec.get("name", Path(where).stem)), tuple(bodies), False, tuple(spec.get("wheels", ())), where)
    )
    unknown = set(model.wheels) - set(model.joints)
    if unknown:
        raise SpaceidError(f"{where}: 'wheels' names unknown joint(s) {sorted(unknown)}")
    return model.as_planar() if spec.get("planar") else model


# ---------------------------------------------------------------- URDF ---------------------


def _check_urdf_tree(text: str, where: str):
    """Reject unsafe or malformed XML and tree errors with messages Pinocchio does not give;
    return the parsed root element."""
    import defusedxml.ElementTree as ET
    from defusedxml import DefusedXmlException

    try:
        root = ET.fromstring(text)
    except DefusedXmlException:
        raise SpaceidError(f"{where}: the URDF declares XML entities or a DTD, which are refused for safety: remove them") from None
    except ET.ParseError as exc:
        raise SpaceidError(f"{where}: not well-formed XML ({exc}): fix the URDF") from None
    if root.tag != "robot":
        raise SpaceidError(f"{where}: the root element is <{root.tag}>, not <robot>: is this a URDF?")
    links = [link.get("name") for link in root.findall("link")]
    parent_of = {}
    for joint in root.findall("joint"):
        name, jtype = joint.get("name"), joint.get("type")
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise SpaceidError(f"{where}: joint '{name}' lacks a <parent> or <child> element")
        child_name = child.get("link")
        if child_name in parent_of:
            raise SpaceidError(
                f"{where}: link '{child_name}' has two parent joints ('{parent_of[child_name][0]}' and "
                f"'{name}'): closed kinematic loops are not supported; cut the loop"
            )
        parent_of[child_name] = (name, jtype)
        if jtype in ("floating", "planar"):
            raise SpaceidError(
                f"{where}: joint '{name}' is of type '{jtype}' below the root: only the root link floats; "
                "make it fixed, revolute, continuous or prismatic"
            )
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise SpaceidError(f"{where}: expected one root link (the floating base), found {roots or 'none (a loop)'}")
    for link in root.findall("link"):
        mass = link.find("inertial/mass")
        if mass is not None and float(mass.get("value", "nan")) <= 0:
            raise SpaceidError(
                f"{where}: link '{link.get('name')}' has mass {mass.get('value')}: masses must be positive"
            )
    return root


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
    import pinocchio as pin

    accelerations = _urdf_accelerations(_check_urdf_tree(text, where), where)
    try:
        pmodel = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    except (RuntimeError, ValueError) as exc:
        raise SpaceidError(f"{where}: Pinocchio could not build the model ({str(exc).splitlines()[0]})") from None
    model = from_pinocchio(pmodel, where)
    bodies = tuple(replace(b, limits={**b.limits, "acceleration": accelerations[b.joint]})
                   if b.joint in accelerations else b for b in model.bodies)
    return _validate(replace(model, bodies=bodies))


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
            raise SpaceidError(f"{source}: joint '{pmodel.names[j]}' ({short}) has {jm.nv} degrees of freedom: only 1-DOF joints are supported")
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
                {k: v for k, v in limits.items() if v > 0 or k == "lower"},
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
            jm = (pin.JointModelPrismaticUnaligned if b.joint_type == "prismatic" else pin.JointModelRevoluteUnaligned)(b.axis)
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
        if not path.is_file():
            raise SpaceidError(
                f"{path}: no such model file; give a URDF or YAML path or a preset ({', '.join(PRESETS)})"
            )
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise SpaceidError(f"{path}: cannot be read ({exc})") from None
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
