"""Random free-floating robots as a user would write them: URDF trees that nobody on the project
designed, for the property tests of every stage.

A robot is a base with 1-4 arms of 1-7 joints each (revolute, continuous or prismatic), joint
frames with offsets and rotations, inertial frames rotated against the link frame, fixed tool
links at some arm ends (merged into their parent when loaded), and masses spanning three orders
of magnitude. Planar robots keep every revolute axis along the base z axis, every prismatic axis
in the plane and every frame rotation about z, as a planar air-bearing robot has them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import spaceid


@dataclass(frozen=True)
class RandomRobot:
    """A drawn robot: its URDF text and how it was drawn (the seed regenerates it)."""

    urdf: str
    planar: bool
    seed: int
    arms: tuple  # joints per arm

    def load(self, folder):
        """The robot loaded by spaceid from a file in ``folder``."""
        path = folder / f"robot{self.seed}.urdf"
        path.write_text(self.urdf)
        return spaceid.load_model(path, planar=self.planar)


def _rotation(rng, planar):
    """A random rotation (about z for a planar robot) as roll-pitch-yaw [rad]."""
    return np.r_[0.0, 0.0, rng.uniform(-np.pi, np.pi)] if planar else rng.uniform(-np.pi, np.pi, 3)


def _inertial(rng, mass, planar):
    """A URDF inertial element: a CoM off the link origin, principal moments of a body of a size
    between 5 and 50 cm that obey the triangle inequality with slack, in a rotated frame."""
    size = rng.uniform(0.05, 0.5)
    moments = mass * size**2 * rng.uniform(0.2, 1.0, 3)
    moments[2] = rng.uniform(abs(moments[0] - moments[1]) + 0.05 * moments.min(), moments[0] + moments[1])
    com = rng.uniform(-0.3, 0.3, 3) * (1.0 if not planar else np.r_[1.0, 1.0, 0.2])
    rpy = rng.uniform(-np.pi, np.pi, 3)  # the principal axes need not be in the plane
    return (f'<inertial><origin xyz="{_f(com)}" rpy="{_f(rpy)}"/><mass value="{mass:.17g}"/>'
            f'<inertia ixx="{moments[0]:.17g}" ixy="0" ixz="0" iyy="{moments[1]:.17g}" iyz="0" '
            f'izz="{moments[2]:.17g}"/></inertial>')


def _f(values) -> str:
    return " ".join(f"{v:.17g}" for v in values)


def _axis(rng, planar, prismatic):
    if planar:
        if prismatic:
            a = np.r_[rng.standard_normal(2), 0.0]
            return a / np.linalg.norm(a)
        return np.r_[0.0, 0.0, rng.choice([-1.0, 1.0])]
    if rng.uniform() < 0.5:  # aligned with a frame axis, as most real joints are
        a = np.zeros(3)
        a[rng.integers(3)] = rng.choice([-1.0, 1.0])
        return a
    a = rng.standard_normal(3)
    return a / np.linalg.norm(a)


def random_robot(seed: int, *, planar: bool, max_arms: int = 4, max_joints: int = 7,
                 base_scale: float = 1.0) -> RandomRobot:
    """A random robot drawn from ``seed`` (see the module docstring); ``base_scale`` multiplies the
    base's mass and moments (a heavy base: a servicer's), the draws otherwise the same."""
    rng = np.random.default_rng(seed)
    arms = tuple(int(rng.integers(1, max_joints + 1)) for _ in range(rng.integers(1, max_arms + 1)))
    links = [f'<link name="base">{_inertial(rng, base_scale * 10 ** rng.uniform(1.0, 2.5), planar)}</link>']
    joints = []
    for a, n in enumerate(arms):
        parent = "base"
        for j in range(n):
            name = f"arm{a}_link{j + 1}"
            prismatic = rng.uniform() < 0.15
            kind = "prismatic" if prismatic else rng.choice(["revolute", "continuous"], p=[0.8, 0.2])
            xyz = rng.uniform(-0.5, 0.5, 3) * (np.r_[1.0, 1.0, 0.2] if planar else 1.0)
            limit = '<limit lower="-0.4" upper="0.4" velocity="0.5" effort="10"/>' if prismatic else (
                '<limit lower="-2.5" upper="2.5" velocity="1.5" effort="10"/>' if kind == "revolute" else "")
            links.append(f'<link name="{name}">{_inertial(rng, 10 ** rng.uniform(-1.0, 1.0), planar)}</link>')
            joints.append(f'<joint name="arm{a}_joint{j + 1}" type="{kind}"><parent link="{parent}"/>'
                          f'<child link="{name}"/><origin xyz="{_f(xyz)}" rpy="{_f(_rotation(rng, planar))}"/>'
                          f'<axis xyz="{_f(_axis(rng, planar, prismatic))}"/>{limit}</joint>')
            parent = name
        if rng.uniform() < 0.4:  # a fixed tool at the arm's end, merged into its last link when loaded
            tool = f"arm{a}_tool"
            links.append(f'<link name="{tool}">{_inertial(rng, 10 ** rng.uniform(-1.0, 0.5), planar)}</link>')
            joints.append(f'<joint name="arm{a}_tool_joint" type="fixed"><parent link="{parent}"/>'
                          f'<child link="{tool}"/><origin xyz="{_f(rng.uniform(-0.2, 0.2, 3) * (np.r_[1, 1, 0] if planar else 1))}" '
                          f'rpy="{_f(_rotation(rng, planar))}"/></joint>')
    urdf = f'<?xml version="1.0"?>\n<robot name="random{seed}">\n' + "\n".join(links + joints) + "\n</robot>\n"
    return RandomRobot(urdf, planar, seed, arms)


def perturbed_prior(model, seed: int, *, mass=0.2, moments=0.2, com=0.01):
    """A CAD-like prior of ``model``: every mass and principal moment about the CoM within
    ``+-mass``/``+-moments`` (relative), every CoM within ``+-com`` [m] per axis, each body still
    physically consistent with a triangle-inequality slack over 1 % (as a CAD model is)."""
    from spaceid.models import perturbed_model

    return perturbed_model(model, seed, mass=mass, moments=moments, com=com)
