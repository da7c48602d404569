"""Regenerate the worked-example URDF files in this folder.

Writes ``satellite-7dof.urdf``, ``servicer-dual.urdf`` and ``servicer-captured.urdf``
next to this script (or into the folder given as the first argument)::

    python src/spaceid/models/presets/make_examples.py

The URDF files are committed; this script is their provenance. The free and the captured
servicer come from the same definitions below, so they cannot drift apart: the captured
one is the free one plus a target rigidly attached to the left end effector. The output is
deterministic (no randomness, fixed number formatting), so rerunning it changes nothing
unless the numbers here change.

All numbers are plausible engineering values chosen for illustration (they are not any
real spacecraft):

* link inertias come from second moments of mass ``S = diag(Sxx, Syy, Szz)`` of a slightly
  elliptic solid cylinder (housings and booms), a scaled box (buses, target) or a thin
  plate (solar array), turned by a few degrees so the tensor has products of inertia.
  ``I = tr(S) 1 - S`` then is positive definite and obeys the triangle inequality by
  construction;
* every link frame sits on its joint axis with ``z`` along the arm at the zero
  configuration (arm straight out of the bus face); roll joints turn about ``z``,
  pitch joints about ``y`` (KUKA LBR / ERA-like roll-pitch-roll-pitch-roll-pitch-roll).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# ------------------------------------------------------------------ arm definition --------
#: Per link: length to the next joint along z [m], cross-section semi-axes a, b [m] of the
#: housing / boom (as a solid elliptic cylinder), joint axis, position limit [rad],
#: velocity [rad/s], effort [N m]. Link 7 ends at the tool flange.
ARM_GEOMETRY = (
    # length  a     b     axis  limit  vel   effort
    (0.25, 0.120, 0.105, "z", 2.967, 0.30, 250.0),  # 1 shoulder roll
    (0.60, 0.100, 0.090, "y", 2.094, 0.30, 250.0),  # 2 shoulder pitch
    (0.80, 0.085, 0.080, "z", 2.967, 0.40, 150.0),  # 3 upper-arm roll (boom)
    (0.60, 0.090, 0.080, "y", 2.356, 0.40, 150.0),  # 4 elbow pitch
    (0.70, 0.075, 0.070, "z", 2.967, 0.50, 80.0),   # 5 forearm roll (boom)
    (0.20, 0.070, 0.065, "y", 2.094, 0.50, 60.0),   # 6 wrist pitch
    (0.15, 0.060, 0.055, "z", 3.054, 0.60, 40.0),   # 7 wrist roll, ends at the flange
)

#: Joint acceleration limits [rad/s^2], joints 1..7. URDF has no acceleration field, so they go
#: into an extra ``acceleration`` attribute of ``<limit>``: URDF parsers (Pinocchio's included)
#: ignore attributes they do not know, and spaceid's loader reads it, so the file stays a
#: plain URDF and a model loaded from its path gets the same limits as the preset.
#: Rule: half the joint torque over the largest inertia the joint drives (base held, the
#: outboard arm stretched across its axis: about 240 kg m^2 at the shoulder, 48 at the elbow,
#: 1.1 at the wrist), at most 1 rad/s^2 so that no joint reaches full speed in much under half a
#: second (space-arm servo ramps); the half leaves torque for friction and the base reaction.
ARM_ACCELERATION = (0.5, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0)
#: The left arm holding the 150 kg target, by the same rule (about 2,440 kg m^2 at the shoulder,
#: 940 at the elbow, 205 at the wrist, 15 at the last roll): a controller slows down after capture.
ARM_ACCELERATION_CAPTURED = (0.05, 0.05, 0.08, 0.08, 0.15, 0.15, 1.0)

#: Nominal arm: per link mass [kg], CoM (x, y off the axis; z as a fraction of the length)
#: and the small tilt (rx, ry, rz) [deg] of the principal axes.
ARM_NOMINAL = (
    (18.0, (0.012, -0.008, 0.45), (2.0, -1.5, 4.0)),
    (12.0, (-0.010, 0.015, 0.40), (-1.0, 2.5, -3.0)),
    (15.0, (0.006, 0.004, 0.50), (1.5, 1.0, 6.0)),
    (10.0, (0.014, -0.011, 0.38), (-2.0, -1.0, 2.0)),
    (12.0, (-0.005, 0.007, 0.52), (1.0, -2.0, -5.0)),
    (7.0, (0.009, 0.012, 0.42), (2.5, 1.5, 3.0)),
    (5.0, (-0.004, -0.006, 0.55), (-1.5, 2.0, 8.0)),
)

#: The servicer's right arm: nominally the same hardware, slightly different as built.
ARM_RIGHT = (
    (18.4, (0.010, 0.009, 0.46), (-2.0, -1.0, 3.0)),
    (11.7, (-0.012, -0.013, 0.41), (1.0, 2.0, -4.0)),
    (15.3, (0.008, -0.005, 0.49), (-1.5, 1.5, 5.0)),
    (9.8, (0.011, 0.013, 0.37), (2.0, -1.5, 1.0)),
    (12.2, (-0.006, -0.008, 0.53), (-1.0, -2.5, -6.0)),
    (6.9, (0.007, -0.010, 0.44), (-2.0, 1.0, 2.0)),
    (5.1, (-0.005, 0.005, 0.54), (1.5, 2.5, 7.0)),
)

# ------------------------------------------------------------------ helpers ---------------


def _fmt(x: float, exact: bool = False) -> str:
    """Six significant digits, or the shortest exact form (angles such as pi/2)."""
    if abs(x) < 1e-12:
        return "0"
    return repr(float(x)) if exact else f"{x:.6g}"


def _vec(v, exact: bool = False) -> str:
    return " ".join(_fmt(x, exact) for x in v)


def _rot(rx: float, ry: float, rz: float):
    """R = Rz Ry Rx, angles in degrees."""
    cx, sx = math.cos(math.radians(rx)), math.sin(math.radians(rx))
    cy, sy = math.cos(math.radians(ry)), math.sin(math.radians(ry))
    cz, sz = math.cos(math.radians(rz)), math.sin(math.radians(rz))
    return (
        (cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx),
        (sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx),
        (-sy, cy * sx, cy * cx),
    )


def inertia_from_second_moments(sxx, syy, szz, tilt=(0.0, 0.0, 0.0)):
    """Inertia about the CoM (ixx, ixy, ixz, iyy, iyz, izz) from principal second moments
    of mass [kg m^2], principal axes turned by ``tilt`` (degrees about x, y, z)."""
    s = (sxx, syy, szz)
    trace = sum(s)
    r = _rot(*tilt)
    i = [[sum(r[a][k] * r[b][k] * (trace - s[k]) for k in range(3)) for b in range(3)] for a in range(3)]
    return i[0][0], i[0][1], i[0][2], i[1][1], i[1][2], i[2][2]


def cylinder(mass, length, a, b, tilt=(0.0, 0.0, 0.0)):
    """Solid elliptic cylinder along z (semi-axes a along x, b along y)."""
    return inertia_from_second_moments(mass * a * a / 4, mass * b * b / 4, mass * length * length / 12, tilt)


def box(mass, dx, dy, dz, tilt=(0.0, 0.0, 0.0), concentration=1.0):
    """Box of edge lengths dx, dy, dz; ``concentration`` < 1 pulls the mass towards the
    centre (tanks, reaction wheels and avionics sit inside, not on the panels)."""
    k = concentration / 12
    return inertia_from_second_moments(k * mass * dx * dx, k * mass * dy * dy, k * mass * dz * dz, tilt)


def link(name, mass, com, inertia, visual=None, color="grey"):
    ixx, ixy, ixz, iyy, iyz, izz = inertia
    out = [f'  <link name="{name}">']
    out.append("    <inertial>")
    out.append(f'      <origin xyz="{_vec(com)}" rpy="0 0 0"/>')
    out.append(f'      <mass value="{_fmt(mass)}"/>')
    out.append(
        f'      <inertia ixx="{_fmt(ixx)}" ixy="{_fmt(ixy)}" ixz="{_fmt(ixz)}" '
        f'iyy="{_fmt(iyy)}" iyz="{_fmt(iyz)}" izz="{_fmt(izz)}"/>'
    )
    out.append("    </inertial>")
    if visual is not None:
        xyz, geometry = visual
        for tag in ("visual", "collision"):
            out.append(f"    <{tag}>")
            out.append(f'      <origin xyz="{_vec(xyz)}" rpy="0 0 0"/>')
            out.append(f"      <geometry>{geometry}</geometry>")
            if tag == "visual":
                out.append(f'      <material name="{color}"/>')
            out.append(f"    </{tag}>")
    out.append("  </link>")
    return out


def joint(name, jtype, parent, child, xyz, rpy=(0.0, 0.0, 0.0), axis=None, limit=None):
    out = [f'  <joint name="{name}" type="{jtype}">']
    out.append(f'    <parent link="{parent}"/>')
    out.append(f'    <child link="{child}"/>')
    out.append(f'    <origin xyz="{_vec(xyz)}" rpy="{_vec(rpy, exact=True)}"/>')
    if axis is not None:
        out.append(f'    <axis xyz="{_vec(axis)}"/>')
    if limit is not None:
        lo, hi, vel, eff, acc = limit
        out.append(f'    <limit lower="{_fmt(lo)}" upper="{_fmt(hi)}" velocity="{_fmt(vel)}" effort="{_fmt(eff)}" '
                   f'acceleration="{_fmt(acc)}"/>')
    out.append("  </joint>")
    return out


MATERIALS = (
    '  <material name="gold"><color rgba="0.85 0.65 0.13 1"/></material>',
    '  <material name="grey"><color rgba="0.6 0.6 0.62 1"/></material>',
    '  <material name="white"><color rgba="0.92 0.92 0.92 1"/></material>',
    '  <material name="blue"><color rgba="0.1 0.2 0.55 1"/></material>',
    '  <material name="dark"><color rgba="0.2 0.2 0.2 1"/></material>',
)


def arm(prefix, parent, mount_xyz, mount_rpy, spec, ee_mass, acceleration=ARM_ACCELERATION):
    """Links and joints of one 7-DOF arm plus its end effector on a fixed joint."""
    out = []
    prev = parent
    xyz, rpy = mount_xyz, mount_rpy
    links = zip(ARM_GEOMETRY, spec, acceleration)
    for i, ((length, a, b, axis, lim, vel, eff), (mass, (cx, cy, fz), tilt), acc) in enumerate(links, 1):
        name = f"{prefix}_link{i}"
        axis_vec = (0.0, 0.0, 1.0) if axis == "z" else (0.0, 1.0, 0.0)
        out += joint(f"{prefix}_joint{i}", "revolute", prev, name, xyz, rpy, axis_vec, (-lim, lim, vel, eff, acc))
        geom = f'<cylinder radius="{_fmt(max(a, b))}" length="{_fmt(length)}"/>'
        out += link(name, mass, (cx, cy, fz * length), cylinder(mass, length, a, b, tilt),
                    ((0.0, 0.0, length / 2), geom), "white" if i % 2 else "grey")
        prev, xyz, rpy = name, (0.0, 0.0, length), (0.0, 0.0, 0.0)
    ee = f"{prefix}_ee"
    out += joint(ee, "fixed", prev, ee, xyz)  # the tool flange
    geom = '<cylinder radius="0.07" length="0.16"/>'
    out += link(ee, ee_mass, (0.004, -0.003, 0.07), cylinder(ee_mass, 0.16, 0.07, 0.065, (1.0, -1.0, 10.0)),
                ((0.0, 0.0, 0.08), geom), "dark")
    return out


def document(name, header, body):
    lines = ['<?xml version="1.0"?>', "<!--", *[f"  {h}" if h else "" for h in header], "-->"]
    lines.append(f'<robot name="{name}">')
    lines += MATERIALS
    lines += body
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


COMMON_NOTE = (
    "Illustrative model: plausible engineering values chosen for spaceid's worked examples,",
    "not a real spacecraft. Generated by make_examples.py (its docstring explains how the",
    "inertias are built); edit that script and rerun it rather than editing this file.",
    "Units: m, kg, kg m^2, rad, rad/s, N m. Inertias are about the link CoM. The root link",
    "is the floating base (the loader adds the free-flyer joint).",
)

ARM_NOTE = (
    "Arm: 7 revolute joints, roll-pitch-roll-pitch-roll-pitch-roll (z, y, z, y, z, y, z in",
    "the link frames, KUKA LBR / ERA-like), straight out of the bus face at q = 0; 3.3 m",
    "from the shoulder to the tool flange (3.05 m from the shoulder pitch axis). Links are",
    "5 to 18 kg, with CoMs a few mm to 15 mm off the joint axis and principal axes turned",
    "a few degrees. Space-arm joint rates (0.3 to 0.6 rad/s) and torques (40 to 250 N m);",
    "joint accelerations (0.5 to 1 rad/s^2) in an extra 'acceleration' attribute of <limit>",
    "(not standard URDF: other parsers ignore it; spaceid reads it).",
)

# ------------------------------------------------------------------ the three models ------

SAT_BUS_MASS = 500.0
SAT_EE_MASS = 3.0


def satellite_7dof() -> str:
    body = link("bus", SAT_BUS_MASS, (0.021, -0.014, -0.048),
                box(SAT_BUS_MASS, 1.2, 1.2, 1.5, (3.0, -2.0, 5.0), concentration=0.8),
                ((0.0, 0.0, 0.0), '<box size="1.2 1.2 1.5"/>'), "gold")
    body += arm("arm", "bus", (0.6, 0.25, 0.40), (0.0, math.pi / 2, 0.0), ARM_NOMINAL, SAT_EE_MASS)
    arm_mass = sum(m for m, _, _ in ARM_NOMINAL)
    header = (
        "satellite-7dof: a free-floating satellite with one 7-DOF manipulator.",
        "",
        *COMMON_NOTE,
        "",
        f"Bus: {SAT_BUS_MASS:g} kg, 1.2 x 1.2 x 1.5 m (frame at the geometric centre), CoM offset",
        "(21, -14, -48) mm; inertia of a box with the mass drawn 20 % towards the centre, axes",
        "turned a few degrees (products of inertia). The arm is mounted on the +x face at",
        "(0.6, 0.25, 0.40) m, pointing along +x.",
        *ARM_NOTE,
        f"End effector 'arm_ee' ({SAT_EE_MASS:g} kg tool) on a fixed joint at the flange.",
        f"Total mass {SAT_BUS_MASS + arm_mass + SAT_EE_MASS:g} kg.",
    )
    return document("satellite_7dof", header, body)


SERV_BUS_MASS = 800.0
SOLAR_ARRAY_MASS = 30.0
ANTENNA_MASS = 12.0
LEFT_EE_MASS = 4.0
RIGHT_EE_MASS = 3.5
TARGET_MASS = 150.0
ARM_SPLAY = 0.15  # rad: each arm turned outwards about the bus z axis


def _servicer_body(left_acceleration=ARM_ACCELERATION):
    body = link("bus", SERV_BUS_MASS, (0.032, 0.018, -0.061),
                box(SERV_BUS_MASS, 1.6, 1.6, 2.0, (-2.0, 3.0, 7.0), concentration=0.75),
                ((0.0, 0.0, 0.0), '<box size="1.6 1.6 2.0"/>'), "gold")
    # one solar-array wing on -y, drive locked: a fixed appendage merged into the bus
    body += joint("solar_array_mount", "fixed", "bus", "solar_array", (0.0, -0.8, 0.2))
    body += link("solar_array", SOLAR_ARRAY_MASS, (0.0, -1.9, 0.0),
                 inertia_from_second_moments(SOLAR_ARRAY_MASS * 1.0**2 / 12, SOLAR_ARRAY_MASS * 3.0**2 / 12,
                                             SOLAR_ARRAY_MASS * 0.03**2 / 12),
                 ((0.0, -1.9, 0.0), '<box size="1.0 3.0 0.03"/>'), "blue")
    # high-gain antenna on a short mast on the +z face
    body += joint("antenna_mount", "fixed", "bus", "antenna", (-0.4, 0.35, 1.0))
    body += link("antenna", ANTENNA_MASS, (0.0, 0.0, 0.30),
                 inertia_from_second_moments(ANTENNA_MASS * 0.4**2 / 4, ANTENNA_MASS * 0.4**2 / 4,
                                             ANTENNA_MASS * 0.05**2),
                 ((0.0, 0.0, 0.30), '<cylinder radius="0.4" length="0.1"/>'), "white")
    body += arm("left", "bus", (0.8, 0.45, 0.55), (0.0, math.pi / 2, ARM_SPLAY), ARM_NOMINAL, LEFT_EE_MASS,
                left_acceleration)
    body += arm("right", "bus", (0.8, -0.45, 0.55), (0.0, math.pi / 2, -ARM_SPLAY), ARM_RIGHT, RIGHT_EE_MASS)
    return body


def _servicer_mass():
    return (SERV_BUS_MASS + SOLAR_ARRAY_MASS + ANTENNA_MASS + sum(m for m, _, _ in ARM_NOMINAL)
            + LEFT_EE_MASS + sum(m for m, _, _ in ARM_RIGHT) + RIGHT_EE_MASS)


def _servicer_header(title):
    return (
        title,
        "",
        *COMMON_NOTE,
        "",
        f"Bus: {SERV_BUS_MASS:g} kg, 1.6 x 1.6 x 2.0 m (frame at the geometric centre), CoM offset",
        "(32, 18, -61) mm, box inertia with the mass drawn 25 % towards the centre, axes turned a",
        f"few degrees. Fixed appendages merged into the bus: a {SOLAR_ARRAY_MASS:g} kg solar-array wing",
        f"(1.0 x 3.0 m, drive locked) on the -y face and a {ANTENNA_MASS:g} kg high-gain antenna on the",
        "+z face. Two arms on the +x face at y = +0.45 m (left) and -0.45 m (right), each",
        f"splayed {ARM_SPLAY:g} rad outwards: mirror-symmetric mounts, but the right arm's links",
        "differ by a few percent in mass and CoM (as built), so the problem is generic.",
        *ARM_NOTE,
        f"End effectors on fixed joints: 'left_ee' {LEFT_EE_MASS:g} kg, 'right_ee' {RIGHT_EE_MASS:g} kg.",
    )


def servicer_dual() -> str:
    header = (*_servicer_header("servicer-dual: a dual-arm on-orbit servicer, both arms free."),
              f"Total mass {_servicer_mass():g} kg.")
    return document("servicer_dual", header, _servicer_body())


def servicer_captured() -> str:
    body = _servicer_body(ARM_ACCELERATION_CAPTURED)
    # a defunct small satellite grasped at its launch-adapter ring, rigidly held
    body += joint("capture", "fixed", "left_ee", "target", (0.0, 0.0, 0.20), (0.0, 0.0, 0.35))
    body += link("target", TARGET_MASS, (0.035, -0.022, 0.56),
                 box(TARGET_MASS, 0.8, 0.8, 1.0, (9.0, -6.0, 14.0), concentration=0.9),
                 ((0.0, 0.0, 0.55), '<box size="0.8 0.8 1.0"/>'), "gold")
    header = (
        *_servicer_header("servicer-captured: servicer-dual after rigidly capturing a target with the left arm."),
        "",
        f"Target: a defunct {TARGET_MASS:g} kg small satellite (0.8 x 0.8 x 1.0 m), held by the left",
        "gripper 0.20 m beyond the flange (fixed joint 'capture' from 'left_ee'); its CoM is",
        "(35, -22, 560) mm in its frame, its inertia a full tensor (products of inertia) from",
        "a box whose principal axes are turned by 9, -6 and 14 degrees. The left arm's",
        "acceleration limits are lower (0.05 to 0.15 rad/s^2, 1 at the last roll): the same",
        "torques now move the target. Everything else is identical to servicer-dual.urdf",
        "(same script).",
        f"Total mass {_servicer_mass() + TARGET_MASS:g} kg.",
    )
    return document("servicer_captured", header, body)


FILES = {
    "satellite-7dof.urdf": satellite_7dof,
    "servicer-dual.urdf": servicer_dual,
    "servicer-captured.urdf": servicer_captured,
}


def main(outdir=None) -> list[Path]:
    """Write the example URDF files into ``outdir`` (default: this folder)."""
    outdir = Path(outdir) if outdir is not None else HERE
    written = []
    for name, make in FILES.items():
        path = outdir / name
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            f.write(make())
        written.append(path)
    return written


if __name__ == "__main__":
    for p in main(sys.argv[1] if len(sys.argv) > 1 else None):
        print(p)
