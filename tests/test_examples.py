"""The worked-example URDFs in spaceid/presets: they load, are physical, agree with Pinocchio,
and the captured servicer is the free one plus the target."""

from pathlib import Path

import defusedxml.ElementTree as ET
import numpy as np
import pinocchio as pin
import pytest

import spaceid
from spaceid.models.presets import make_examples

PRESETS = Path(spaceid.__file__).parent / "models" / "presets"

ARM = 18.0 + 12.0 + 15.0 + 10.0 + 12.0 + 7.0 + 5.0  # nominal arm links (left / single arm)
ARM_RIGHT = 18.4 + 11.7 + 15.3 + 9.8 + 12.2 + 6.9 + 5.1
SATELLITE = 500.0 + ARM + 3.0  # bus, arm, tool
SERVICER = 800.0 + 30.0 + 12.0 + ARM + 4.0 + ARM_RIGHT + 3.5  # bus, array, antenna, arms, tools
TARGET = 150.0


def arm_joints(prefix):
    return tuple(f"{prefix}_joint{i}" for i in range(1, 8))


EXAMPLES = {
    "satellite-7dof.urdf": (SATELLITE, arm_joints("arm")),
    "servicer-dual.urdf": (SERVICER, arm_joints("left") + arm_joints("right")),
    "servicer-captured.urdf": (SERVICER + TARGET, arm_joints("left") + arm_joints("right")),
}


@pytest.fixture(scope="module")
def models():
    return {name: spaceid.load_model(PRESETS / name) for name in EXAMPLES}


@pytest.mark.parametrize("name", EXAMPLES)
def test_loads_spatial_and_matches_pinocchio(name, models):
    total, joints = EXAMPLES[name]
    path = PRESETS / name
    model = models[name]
    assert model.bodies[0].joint_type == "base" and model.bodies[0].parent == -1
    assert model.bodies[0].name == "bus" and not model.planar
    assert model.joints == joints and model.n_joints == len(joints)
    assert all(b.joint_type == "revolute" for b in model.bodies[1:])
    assert model.mass == pytest.approx(total, abs=1e-9)
    for kind in ("lower", "upper", "velocity", "acceleration"):  # what 'spaceid design' needs
        assert np.all(np.isfinite(model.joint_limits(kind)))
    assert np.all(model.joint_limits("acceleration") > 0)
    preset = spaceid.load_model(name.removesuffix(".urdf"))  # the preset reads the same file
    np.testing.assert_array_equal(preset.joint_limits("acceleration"), model.joint_limits("acceleration"))
    with pytest.raises(spaceid.SpaceidError, match="planar"):
        spaceid.load_model(path, planar=True)

    ref = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())  # independent of our conversion
    assert ref.joints[1].shortname() == "JointModelFreeFlyer"
    assert ref.nv == 6 + len(joints) and ref.nq == 7 + len(joints)
    assert pin.computeTotalMass(ref) == pytest.approx(total, abs=1e-9)


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_link_is_physical(name):
    text = (PRESETS / name).read_text()
    assert "<!DOCTYPE" not in text and "<!ENTITY" not in text
    root = ET.fromstring(text)
    for link in root.findall("link"):
        mass = float(link.find("inertial/mass").get("value"))
        attrs = link.find("inertial/inertia").attrib
        ixx, ixy, ixz, iyy, iyz, izz = (float(attrs[k]) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
        eig = np.sort(np.linalg.eigvalsh([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
        assert mass > 0 and eig[0] > 0, link.get("name")
        assert eig[0] + eig[1] >= eig[2], link.get("name")  # triangle inequality
        assert link.find("visual/geometry") is not None
    for joint in root.findall("joint"):
        if joint.get("type") == "revolute":
            limit = joint.find("limit").attrib
            assert float(limit["lower"]) < 0 < float(limit["upper"])
            assert float(limit["velocity"]) > 0 and float(limit["effort"]) > 0
            assert 0 < float(limit["acceleration"]) <= 1.0  # rad/s^2: a space arm's servo ramp


@pytest.mark.parametrize("name, prefixes", [("satellite-7dof.urdf", ["arm"]), ("servicer-dual.urdf", ["left", "right"])])
def test_reach_about_three_metres(name, prefixes):
    ref = pin.buildModelFromUrdf(str(PRESETS / name), pin.JointModelFreeFlyer())
    data = ref.createData()
    pin.framesForwardKinematics(ref, data, pin.neutral(ref))
    for prefix in prefixes:
        shoulder = data.oMi[ref.getJointId(f"{prefix}_joint1")].translation
        flange = data.oMf[ref.getFrameId(f"{prefix}_ee", pin.FrameType.BODY)].translation
        assert np.linalg.norm(flange - shoulder) == pytest.approx(3.3)


def test_captured_is_free_servicer_plus_target(models):
    free, captured = models["servicer-dual.urdf"], models["servicer-captured.urdf"]
    assert captured.mass - free.mass == pytest.approx(TARGET)
    # the fixed appendages are merged into the bus
    assert free.bodies[0].mass == pytest.approx(800.0 + 30.0 + 12.0)
    # left_ee and the target sit on fixed joints: merged into the last left-arm body
    i = captured.joints.index("left_joint7") + 1
    assert captured.bodies[i].name == free.bodies[i].name == "left_link7"
    assert captured.bodies[i].mass == pytest.approx(5.0 + 4.0 + TARGET)
    assert captured.bodies[i].mass - free.bodies[i].mass == pytest.approx(TARGET)
    assert np.linalg.norm(captured.bodies[i].com - free.bodies[i].com) > 0.3  # the target moves the CoM out
    for j, (a, b) in enumerate(zip(free.bodies, captured.bodies)):
        if j != i:  # everything else identical
            assert a.name == b.name and a.joint == b.joint
            np.testing.assert_array_equal(a.inertial, b.inertial)
            np.testing.assert_array_equal(a.translation, b.translation)
            np.testing.assert_array_equal(a.rotation, b.rotation)


def test_arms_are_mirrored_but_not_identical(models):
    free = models["servicer-dual.urdf"]
    left = [b for b in free.bodies if b.name.startswith("left_")]
    right = [b for b in free.bodies if b.name.startswith("right_")]
    assert len(left) == len(right) == 7
    np.testing.assert_allclose(left[0].translation * [1, -1, 1], right[0].translation)
    assert all(abs(a.mass - b.mass) > 0.05 for a, b in zip(left, right))


def test_script_regenerates_the_committed_files(tmp_path):
    written = make_examples.main(tmp_path)
    assert sorted(p.name for p in written) == sorted(EXAMPLES)
    for path in written:
        assert path.read_text() == (PRESETS / path.name).read_text(), path.name
