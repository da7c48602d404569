"""Model loading (URDF through Pinocchio, YAML, presets) and its bad inputs."""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import pinocchio_momentum, random_states

import spaceid
from spaceid.dynamics import angular_momentum
from spaceid.dynamics import minimal_parameters

DATA = Path(__file__).parent / "data"


def test_presets():
    cepheus = spaceid.load_model("cepheus")
    assert cepheus.planar and cepheus.joints == ("left_shoulder", "left_elbow")
    assert cepheus.mass == pytest.approx(9.951 + 0.083 + 0.187)
    rw = spaceid.load_model("cepheus-rw")
    assert rw.wheels == ("reaction_wheel_joint",) and rw.mass == pytest.approx(cepheus.mass)
    assert minimal_parameters(rw).n_params == 9  # the paper's 8 and the rotor inertia


def test_urdf_with_fixed_joint_matches_pinocchio(rng):
    path = DATA / "planar_arm_fixed.urdf"
    model = spaceid.load_model(path, planar=True)
    assert model.joints == ("shoulder", "elbow") and [b.name for b in model.bodies] == ["base", "link1", "link2"]
    assert model.bodies[1].limits["upper"] == 2 and "upper" not in model.bodies[2].limits
    ref_model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())  # independent of our conversion
    q, qd, w0 = random_states(rng, model, 30)
    ref = pinocchio_momentum(ref_model, q, qd, w0)
    direct = angular_momentum(model, q, qd, w0)
    np.testing.assert_allclose(direct, ref, atol=1e-13)
    param = minimal_parameters(model)
    np.testing.assert_allclose(param.regressor(q, qd, w0)[:, 0] @ param.true_values, ref[:, 2], atol=1e-13)
    assert param.n_params == 9  # 3 bodies, CoMs free: 3 spin + 3 pairs x (cos, sin)


URDF_HEAD = '<?xml version="1.0"?>\n'


def _link(name, mass="1.0", inertia='ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"'):
    return f'<link name="{name}"><inertial><mass value="{mass}"/><inertia {inertia}/></inertial></link>'


def _joint(name, parent, child, jtype="revolute", axis="0 0 1"):
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<axis xyz="{axis}"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>')


BAD_URDFS = {
    "loop": (_link("a") + _link("b") + _link("c") + _joint("j1", "a", "b") + _joint("j2", "b", "c") + _joint("j3", "a", "c"), "closed kinematic loops"),
    "floating": (_link("a") + _link("b") + _joint("j1", "a", "b", "floating"), "below the root"),
    "zero mass": (_link("a") + _link("b", mass="0") + _joint("j1", "a", "b"), "masses must be positive"),
    "not pd": (_link("a") + _link("b", inertia='ixx="-0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"') + _joint("j1", "a", "b"), "positive"),
    "malformed": (_link("a") + "<joint", "not well-formed"),
    "entity": ('<!DOCTYPE robot [<!ENTITY x "boom">]>', "entities"),
}


@pytest.mark.parametrize("name", BAD_URDFS)
def test_bad_urdf(tmp_path, name):
    body, message = BAD_URDFS[name]
    if name == "entity":
        text = URDF_HEAD + body + f'<robot name="r">{_link("a")}</robot>'
    else:
        text = URDF_HEAD + f'<robot name="r">{body}</robot>'
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(spaceid.SpaceidError, match=message) as info:
        spaceid.load_model(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_urdf_acceleration_limits(tmp_path):
    """URDF has no acceleration limit: spaceid reads an extra ``acceleration`` attribute of
    <limit>, which Pinocchio ignores; joints without one have none (NaN)."""
    joints = _joint("j1", "a", "b").replace('effort="1"', 'effort="1" acceleration="0.7"') + _joint("j2", "b", "c")
    path = tmp_path / "acc.urdf"
    path.write_text(URDF_HEAD + f'<robot name="r">{_link("a")}{_link("b")}{_link("c")}{joints}</robot>')
    limits = spaceid.load_model(path).joint_limits("acceleration")
    assert limits[0] == 0.7 and np.isnan(limits[1])
    path.write_text(path.read_text().replace('acceleration="0.7"', 'acceleration="-1"'))
    with pytest.raises(spaceid.SpaceidError, match="joint 'j1' has acceleration limit '-1'"):
        spaceid.load_model(path)


def test_non_planar_joint_is_named(tmp_path):
    path = tmp_path / "tilted.urdf"
    path.write_text(URDF_HEAD + f'<robot name="r">{_link("a")}{_link("b")}{_joint("wrist", "a", "b", axis="1 0 0")}</robot>')
    assert not spaceid.load_model(path).planar
    with pytest.raises(spaceid.SpaceidError, match="joint 'wrist'.*not parallel to the base z axis"):
        spaceid.load_model(path, planar=True)


@pytest.mark.parametrize(
    "text, message",
    [
        ("bodies: [", "not valid YAML"),
        ("name: x\n", "needs a 'bodies' list"),
        ("bodies:\n  - {name: base}\n", "has no 'mass'"),
        ("bodies:\n  - {name: base, mass: 1}\n  - {name: l, parent: nowhere, mass: 1}\n", "not listed before it"),
        ("bodies:\n  - {name: base, mass: 1, com: [0, 0]}\n", "list of 3 numbers"),
        ("bodies:\n  - {name: base, mass: .nan}\n", "non-finite"),
        ("bodies:\n  - {name: base, mass: 1, known_zero: [mass]}\n", "unknown known_zero"),
        ("!!python/object/apply:os.system ['true']\n", "not valid YAML"),
    ],
)
def test_bad_yaml(tmp_path, text, message):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    with pytest.raises(spaceid.SpaceidError, match=message):
        spaceid.load_model(path)


def test_missing_model_file(tmp_path):
    with pytest.raises(spaceid.SpaceidError, match="no such model file"):
        spaceid.load_model(tmp_path / "none.urdf")
