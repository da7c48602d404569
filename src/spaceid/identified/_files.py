"""The exported model as a file: URDF (the prior's own file with new ``<inertial>`` elements, or a
URDF written from the model), spaceid's YAML model or a free-floating MuJoCo model (MJCF)
(:func:`urdf_text`, :func:`yaml_text`, :func:`mjcf_text`, :func:`write_export`)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._constants import EXPORT_FORMATS as FORMATS
from .._errors import SpaceidError, shown
from ..models import PRESETS, Model
from ._export import Export, unphysical_bodies

__all__ = ["FORMATS", "mjcf_text", "urdf_text", "write_export", "yaml_text"]

NOTE = "inertial parameters identified by spaceid export"


def _num(x: float) -> str:
    """Shortest exact form: the file reproduces the parameters to the last bit."""
    return repr(float(x)) if x != 0 else "0"


def _attr(text: str) -> str:
    """``text`` safe inside a double-quoted XML attribute."""
    from xml.sax.saxutils import escape  # here: it imports urllib.request, http and ssl (15 ms of every command)

    return escape(str(text), {'"': "&quot;"})


def _comment(note: str) -> str:
    """An XML comment of ``note`` (which must not hold ``--``)."""
    return f"<!-- {note.replace('--', '- -')} -->"


def _vec(v) -> str:
    return " ".join(_num(x) for x in v)


def _about_com(inertial):
    """Mass [kg], CoM (3,) [m] and inertia about the CoM (3, 3) [kg m^2] of standard parameters."""
    m, c = inertial[0], inertial[1:4] / inertial[0]
    i_o = np.array([[inertial[4], inertial[5], inertial[7]], [inertial[5], inertial[6], inertial[8]],
                    [inertial[7], inertial[8], inertial[9]]])  # fmt: skip
    return m, c, i_o - m * (c @ c * np.eye(3) - np.outer(c, c))


_ENTRIES = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}


def _inertial_xml(inertial, indent: str) -> str:
    """``<inertial>`` of a body's standard parameters (about its frame origin, ``INERTIAL_NAMES``
    order) as URDF gives it: mass, CoM, inertia about the CoM in the link axes."""
    m, c, i_c = _about_com(inertial)
    entries = " ".join(f'{k}="{_num(i_c[a, b])}"' for k, (a, b) in _ENTRIES.items())
    inner = indent + "  "
    return (f'<inertial>\n{inner}<origin xyz="{_vec(c)}" rpy="0 0 0"/>\n{inner}<mass value="{_num(m)}"/>\n'
            f"{inner}<inertia {entries}/>\n{indent}</inertial>")


def _prior_urdf(prior: Model) -> str | None:
    """The text of the prior's URDF file (a URDF preset or path), None for a YAML model."""
    source = prior.source or prior.name
    if source in PRESETS:
        file = resources.files("spaceid.models.presets").joinpath(f"{source}.urdf")
        return file.read_text() if file.is_file() else None
    path = Path(source)
    if not path.is_file():
        return None
    text = path.read_text()
    return text if path.suffix.lower() == ".urdf" or text.lstrip().startswith("<") else None


def _rewrite(text: str, model: Model, note: str) -> str:
    """``text`` (a URDF) with every body's ``<inertial>`` replaced by the model's and those of the
    links merged into a body through fixed joints removed (the body's inertial holds them).
    Comments inside ``<robot>`` stay; those before it go (they describe the prior)."""
    import xml.etree.ElementTree as ET

    from defusedxml.ElementTree import DefusedXMLParser

    parser = DefusedXMLParser(target=ET.TreeBuilder(insert_comments=True))
    parser.feed(text)
    root = parser.close()
    bodies = {b.name: b for b in model.bodies}
    for link in root.findall("link"):
        old = link.find("inertial")
        if link.get("name") in bodies:
            indent = (link.text or "").rsplit("\n", 1)[-1] if len(link) else ""
            new = ET.fromstring(_inertial_xml(bodies[link.get("name")].inertial, indent or "    "))
        elif old is not None:
            new = ET.Comment(" inertial merged into the link of its body (fixed joint) by spaceid export ")
        else:
            continue
        if old is not None:
            new.tail = old.tail
            link[list(link).index(old)] = new
        else:
            new.tail = link.text if len(link) else "\n  "
            link.text = "\n" + (indent or "    ")
            link.insert(0, new)
    return f'<?xml version="1.0"?>\n{_comment(note)}\n{ET.tostring(root, encoding="unicode")}\n'


def _joint_kind(body) -> str:
    """URDF joint type: a revolute joint without position limits is continuous."""
    if body.joint_type == "revolute" and not {"lower", "upper"} <= set(body.limits):
        return "continuous"
    return body.joint_type


def _joint_xml(model: Model, body) -> str:
    import pinocchio as pin

    limits, kind = body.limits, _joint_kind(body)
    attrs = [f'{k}="{_num(limits[k])}"' for k in ("lower", "upper") if kind != "continuous" and k in limits]
    if kind == "prismatic" and not attrs:
        attrs = ['lower="0"', 'upper="0"']  # URDF needs them; spaceid reads 0, 0 as none
    attrs += [f'{k}="{_num(limits.get(k, 0.0))}"' for k in ("effort", "velocity")]
    attrs += [f'acceleration="{_num(limits["acceleration"])}"'] if "acceleration" in limits else []
    rpy = pin.rpy.matrixToRpy(body.rotation)
    return (f'  <joint name="{_attr(body.joint)}" type="{kind}">\n'
            f'    <parent link="{_attr(model.bodies[body.parent].name)}"/>\n    <child link="{_attr(body.name)}"/>\n'
            f'    <origin xyz="{_vec(body.translation)}" rpy="{_vec(rpy)}"/>\n'
            f'    <axis xyz="{_vec(body.axis)}"/>\n    <limit {" ".join(attrs)}/>\n  </joint>\n')


def _generate(model: Model, note: str) -> str:
    """A URDF of ``model`` (root link the floating base; no visuals: the model has none)."""
    out = [f'<?xml version="1.0"?>\n{_comment(note)}\n<robot name="{_attr(model.name)}">\n']
    for body in model.bodies:
        out.append(f'  <link name="{_attr(body.name)}">\n    {_inertial_xml(body.inertial, "    ")}\n  </link>\n')
        if body.parent >= 0:
            out.append(_joint_xml(model, body))
    return "".join(out) + "</robot>\n"


def urdf_text(export: Export, note: str = NOTE) -> str:
    """The exported model as URDF text.

    A URDF prior keeps everything (kinematics, names, limits, visuals, comments) but its
    ``<inertial>`` elements: each body's link gets the exported one; the links merged into a
    body through fixed joints lose theirs (the body's holds the merged inertia). A YAML prior is
    written out as a URDF of its model (joints, limits with the ``acceleration`` attribute
    spaceid reads). ``note`` goes into a comment at the top. Planar mode, reaction wheels and
    declared zeros are not URDF: load the file with ``planar=True`` for a planar model, or
    write YAML (:func:`yaml_text`).
    """
    prior = _prior_urdf(export.prior)
    return _generate(export.model, note) if prior is None else _rewrite(prior, export.model, note)


def yaml_text(export: Export, note: str = NOTE) -> str:
    """The exported model as spaceid's YAML model (docs/formats/yaml-model.md): the prior's
    kinematics, planar flag, reaction wheels and declared zeros with the exported inertials
    (no visuals: YAML has none). ``note`` goes into a comment at the top."""
    import pinocchio as pin
    import yaml

    model = export.model
    bodies = []
    for b in model.bodies:
        m, c, i_c = _about_com(b.inertial)
        spec = {"name": b.name}
        if b.parent >= 0:
            joint = {"name": b.joint, "type": _joint_kind(b), "xyz": b.translation.tolist(),
                     "rpy": np.asarray(pin.rpy.matrixToRpy(b.rotation)).tolist(), "axis": b.axis.tolist()}
            spec |= {"parent": model.bodies[b.parent].name, "joint": joint | ({"limit": b.limits} if b.limits else {})}
        inertia = {k: float(i_c[r, s]) for k, (r, s) in _ENTRIES.items()}
        spec |= {"mass": float(m), "com": c.tolist(), "inertia": inertia}
        bodies.append(spec | ({"known_zero": sorted(b.known_zero)} if b.known_zero else {}))
    doc = {"name": model.name, "planar": model.planar} | ({"wheels": list(model.wheels)} if model.wheels else {})
    return f"# {note}\n" + yaml.safe_dump(doc | {"bodies": bodies}, sort_keys=False, default_flow_style=None, width=120)


def write_export(export: Export, path, *, fmt: str = "urdf", inputs=(), note: str = NOTE) -> None:
    """Write the exported model to ``path`` atomically as ``fmt`` (``FORMATS``: :func:`urdf_text`,
    :func:`yaml_text` or :func:`mjcf_text`), never over one of the ``inputs`` files.

    Raises
    ------
    SpaceidError
        An unknown format, ``path`` one of ``inputs``, or a path that cannot be written.
    """
    if fmt not in FORMATS:
        raise SpaceidError(f"`fmt`: {shown(fmt)} is not one of {', '.join(FORMATS)}")
    path = Path(path)
    for source in inputs:
        if Path(source).is_file() and path.resolve() == Path(source).resolve():
            raise SpaceidError(f"{path}: that is an input file ({source}): give another file name")
    bad = unphysical_bodies(export.model)
    if bad:  # checked here too: whatever reaches a file is physically consistent
        raise SpaceidError(f"{path}: not written: the bodies {', '.join(bad)} of the exported model are not "
                           "physically consistent (a mass, an inertia about the CoM or a triangle inequality)")
    text = {"urdf": urdf_text, "yaml": yaml_text, "mjcf": mjcf_text}[fmt](export, note)
    try:
        write_text_atomic(path, text)
    except OSError as err:
        raise SpaceidError(f"{path}: cannot write ({err.strerror or err}): check the path is writable") from None


def _mjcf_inertial(inertial, indent: str) -> str:
    """``<inertial>`` of a body's standard parameters: mass, CoM and the inertia about the CoM in the
    body axes (MuJoCo's ``fullinertia`` order: xx yy zz xy xz yz)."""
    m, c, i_c = _about_com(inertial)
    full = _vec([i_c[0, 0], i_c[1, 1], i_c[2, 2], i_c[0, 1], i_c[0, 2], i_c[1, 2]])
    return f'{indent}<inertial pos="{_vec(c)}" mass="{_num(m)}" fullinertia="{full}"/>\n'


def _mjcf_joint(body, indent: str) -> str:
    kind = "slide" if body.joint_type == "prismatic" else "hinge"
    limits = body.limits
    span = (f' range="{_num(limits["lower"])} {_num(limits["upper"])}"'
            if {"lower", "upper"} <= set(limits) and limits["lower"] < limits["upper"] else "")
    return f'{indent}<joint name="{_attr(body.joint)}" type="{kind}" axis="{_vec(body.axis)}"{span}/>\n'


def _mjcf_body(model: Model, index: int, children: dict, depth: int) -> str:
    import pinocchio as pin

    body, indent = model.bodies[index], "  " * depth
    inner = indent + "  "
    if body.parent < 0:
        # the floating base: a free joint, or on an air bearing (planar) x, y and the yaw
        joints = (f'{inner}<freejoint name="{_attr(body.name)}_free"/>\n' if not model.planar else
                  "".join(f'{inner}<joint name="{_attr(body.name)}_{n}" type="{k}" axis="{a}"/>\n'
                          for n, k, a in (("x", "slide", "1 0 0"), ("y", "slide", "0 1 0"), ("yaw", "hinge", "0 0 1"))))
        head = f'{indent}<body name="{_attr(body.name)}">\n{joints}'
    else:
        quat = pin.Quaternion(body.rotation).coeffs()  # x y z w
        head = (f'{indent}<body name="{_attr(body.name)}" pos="{_vec(body.translation)}" '
                f'quat="{_vec([quat[3], quat[0], quat[1], quat[2]])}">\n{_mjcf_joint(body, inner)}')
    nested = "".join(_mjcf_body(model, k, children, depth + 1) for k in children.get(index, []))
    return f"{head}{_mjcf_inertial(body.inertial, inner)}{nested}{indent}</body>\n"


def mjcf_text(export: Export, note: str = NOTE) -> str:
    """The exported model as a free-floating MuJoCo model (MJCF).

    The base carries a free joint (a planar model: two slides and a hinge about z, the air
    bearing's degrees of freedom), gravity is zero and the integrator RK4; every body has the
    exported inertial (mass, CoM, full inertia about the CoM) and the prior's joint placements,
    axes and position limits (``range``). No geometry: the model is for dynamics (add visuals
    from the URDF if wanted). A URDF compiled by MuJoCo instead fixes its root link to the world.
    """
    model = export.model
    children: dict = {}
    for k, body in enumerate(model.bodies):
        children.setdefault(body.parent, []).append(k)
    (root,) = children[-1]
    return (f'<?xml version="1.0"?>\n{_comment(note)}\n<mujoco model="{_attr(model.name)}">\n'
            '  <compiler angle="radian" autolimits="true"/>\n'
            '  <option gravity="0 0 0" integrator="RK4"/>\n  <worldbody>\n'
            f"{_mjcf_body(model, root, children, 2)}  </worldbody>\n</mujoco>\n")
