"""Hostile input to the readers and model builders (issue 12): each case names the input and the
one-line SpaceidError it gets (or the correct behaviour), and property tests feed the CSV, JSON,
YAML, URDF and bag readers random and mutated inputs, which must parse or raise SpaceidError."""

import json
import os
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import spaceid
from spaceid import SpaceidError
from spaceid.data import read_json, read_log, read_mapping, read_recording
from spaceid import _memory
from spaceid.data import _tables
from spaceid.dynamics import minimal_parameters
from spaceid.models import load_model
from spaceid.motion import load_trajectory

PRESETS = Path(spaceid.__file__).parent / "models" / "presets"
JOINTS = ("left_shoulder", "left_elbow")


def _one_line_error(call, message):
    """``call()`` raises a SpaceidError matching ``message`` on one line; returns the text."""
    with pytest.raises(SpaceidError, match=message) as info:
        call()
    text = str(info.value)
    assert "\n" not in text and len(text) < 600, text
    return text


# --- URDF ------------------------------------------------------------------------------------


def _link(name, extra=""):
    return (f'<link name="{name}"><inertial><mass value="1.0"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" '
            f'iyz="0" izz="0.1"/></inertial>{extra}</link>')


def _joint(name, parent, child, jtype="revolute", axis="0 0 1", extra="",
           limit='<limit lower="-1" upper="1" velocity="1" effort="1"/>'):
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<axis xyz="{axis}"/>{limit}{extra}</joint>')


def _urdf(tmp_path, body, name="m.urdf"):
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?>\n<robot name="r">{body}</robot>')
    return path


ARM = _link("a") + _link("b") + _joint("j1", "a", "b")
BAD_URDFS = {
    # a cycle beside a valid tree: Pinocchio builds the tree and drops the cycle without a word
    "cycle beside the tree": (
        ARM + _link("c") + _link("d") + _joint("j2", "c", "d") + _joint("j3", "d", "c"),
        r"joints 'j2', 'j3' form a cycle \(links 'c', 'd'\), apart from the tree of root link 'a'",
    ),
    "several roots": (ARM + _link("c") + _link("e"),
                      r"3 root links \('a', 'c', 'e'\): the floating base must be the only"),
    # Pinocchio's motion subspace of a zero axis is a translation: the joint became prismatic
    "zero revolute axis": (_link("a") + _link("b") + _joint("j1", "a", "b", axis="0 0 0"),
                           r"joint 'j1': axis xyz='0 0 0' is zero: give the direction"),
    "axis not numbers": (_link("a") + _link("b") + _joint("j1", "a", "b", axis="x y"),
                         r"axis xyz='x y' is not 3 numbers"),
    "unknown joint type": (_link("a") + _link("b") + _joint("j1", "a", "b", jtype="spherical"),
                           r"joint 'j1' has unknown type 'spherical': use revolute, continuous, prismatic or fixed"),
    "two joints named alike": (ARM + _link("c") + _joint("j1", "b", "c"), r"joint name 'j1' appears twice"),
    "links colliding as symbols": (_link("l-1") + _link("l_1") + _joint("j1", "l-1", "l_1"),
                                   r"body names 'l-1' and 'l_1' both become 'l_1' in parameter names.*rename one"),
    "mass abc": (_link("a").replace('value="1.0"', 'value="abc"') + _link("b") + _joint("j1", "a", "b"),
                 r"link 'a' has mass 'abc': masses must be positive numbers"),
    "child not a link": (_link("a") + _joint("j1", "a", "zz"), r"joint 'j1': child link 'zz' is not a <link>"),
    "revolute without limit": (_link("a") + _link("b") + _joint("j1", "a", "b", limit=""),
                               r"joint 'j1' \(revolute\) has no <limit>: URDF requires"),
    "limits upside down": (_link("a") + _link("b") + _joint("j1", "a", "b", limit='<limit lower="1" upper="-1" '
                                                             'velocity="1" effort="1"/>'),
                           r"limit lower = 1 is above upper = -1: swap them"),
    # urdfdom prints two lines, drops the <inertial> and goes on: a body of zero mass
    "unreadable inertial": (_link("a") + _link("b").replace("<mass", '<origin xyz="q w e"/><mass')
                            + _joint("j1", "a", "b"),
                            r"the URDF parser refused the file \(Error: Unable to parse component \[q\]"),
}


@pytest.mark.parametrize("case", BAD_URDFS)
def test_bad_urdf_is_one_line(tmp_path, capfd, case):
    body, message = BAD_URDFS[case]
    path = _urdf(tmp_path, body)
    _one_line_error(lambda: load_model(path), message)
    assert capfd.readouterr().err == ""  # urdfdom's printed lines are captured, not shown


def test_urdf_negative_range_keeps_its_upper_limit_and_design_refuses_it(tmp_path):
    """[-2, -0.5] rad lost its upper limit (only positive values were kept), so design moved the
    joint over [-2, 2]; now the limits reach the design's bounds, and a range without q = 0 is
    refused since designed trajectories move about q = 0."""
    from spaceid.motion._design import _model_limits

    limit = '<limit lower="{}" upper="{}" velocity="1.5" effort="1" acceleration="3"/>'
    path = _urdf(tmp_path, _link("a") + _link("b") + _joint("j1", "a", "b", limit=limit.format(-2, -0.5)))
    model = load_model(path)
    assert model.joint_limits("lower")[0] == -2 and model.joint_limits("upper")[0] == -0.5
    none = dict(q_max=None, qd_max=None, qdd_max=None)
    _one_line_error(lambda: _model_limits(model, none),
                    r"joint 'j1' has the range \[-2, -0.5\], which does not hold q = 0")
    path.write_text(path.read_text().replace('upper="-0.5"', 'upper="0.3"'))
    limits = _model_limits(load_model(path), none)
    assert limits["q_max"].tolist() == [0.3] and limits["qd_max"].tolist() == [1.5]
    assert limits["qdd_max"].tolist() == [3]


def test_urdf_mimic_joint_is_an_independent_joint_with_a_warning(tmp_path):
    path = _urdf(tmp_path, ARM + _link("c") + _joint("j2", "b", "c", extra='<mimic joint="j1" multiplier="2"/>'))
    with pytest.warns(UserWarning, match="joint 'j2' mimics 'j1': it is treated as an independent joint"):
        model = load_model(path)
    assert model.joints == ("j1", "j2")


def test_urdf_missing_meshes_are_not_needed(tmp_path):
    mesh = '<visual><geometry><mesh filename="package://nowhere/base.stl"/></geometry></visual>'
    model = load_model(_urdf(tmp_path, _link("a", mesh) + _link("b", mesh.replace("visual", "collision")) +
                             _joint("j1", "a", "b")))
    assert model.joints == ("j1",) and model.bodies[1].joint_type == "revolute"


# --- YAML models -------------------------------------------------------------------------------

BASE = "  - {name: base, mass: 10, inertia: {izz: 0.1, ixx: 0.1, iyy: 0.1}}\n"
LINK = "  - {name: link, parent: base, mass: 1, joint: {name: j1, limit: {lower: -1, upper: 1}}}\n"
BOMB = 'a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]\n' + "".join(
    f"{x}: &{x} [{', '.join([f'*{p}'] * 9)}]\n" for p, x in zip("abcdefgh", "bcdefghi"))  # 9^9 strings

BAD_YAMLS = {
    "inertial typo": ("bodies:\n  - {name: base, mass: 10, inertial: {izz: 0.1}}\n",
                      r"body 'base': unknown key 'inertial' in the body: did you mean 'inertia'\? the keys are name, "),
    "comm typo": ("bodies:\n  - {name: base, mass: 10, comm: [0, 0, 0]}\n",
                  r"unknown key 'comm'.*did you mean 'com'\?"),
    "top-level typo": ("bodys: []\nbodies:\n" + BASE, r"unknown key 'bodys' in the model: did you mean 'bodies'\?"),
    "mass true": ("bodies:\n  - {name: base, mass: true}\n", r"body 'base': 'mass' must be a number \[kg\], got True"),
    "mass abc": ("bodies:\n  - {name: base, mass: abc}\n", r"'mass' must be a number \[kg\], got 'abc'"),
    "com with a boolean": ("bodies:\n  - {name: base, mass: 1, com: [true, 0, 0]}\n", r"'com' must be a number"),
    "known_zero 5": ("bodies:\n  - {name: base, mass: 1, known_zero: 5}\n",
                     r"'known_zero' must be a list of parameter names \(m, mcx, .*\), got 5"),
    "joint as a string": ("bodies:\n" + BASE + "  - {name: link, parent: base, mass: 1, joint: revolute}\n",
                          r"body 'link': 'joint' must be a mapping with keys among name, type, xyz, rpy, axis, limit"),
    "limit as a list": ("bodies:\n" + BASE + "  - {name: link, parent: base, mass: 1, joint: {limit: [-1, 1]}}\n",
                        r"'joint.limit' must be a mapping with keys among lower, upper, velocity, acceleration"),
    "limit upside down": ("bodies:\n" + BASE
                          + "  - {name: link, parent: base, mass: 1, joint: {limit: {lower: 1, upper: -1}}}\n",
                          r"joint limit lower = 1 is above upper = -1"),
    "wheels 5": ("wheels: 5\nbodies:\n" + BASE, r"'wheels' must be a list of joint names, got 5"),
    "two joints named alike": ("bodies:\n" + BASE + LINK + LINK.replace("name: link", "name: link2"),
                               r"joint name 'j1' appears twice"),
    "planar yes": ("planar: 'yes'\nbodies:\n" + BASE, r"'planar' must be true or false, got 'yes'"),
    "alias bomb as the name": (BOMB + "name: *i\nbodies:\n" + BASE, r"line 2: YAML alias '\*a' refused"),
    "alias bomb as a com": (BOMB + "bodies:\n  - {name: base, mass: 1, com: *i}\n", r"YAML alias '\*a' refused"),
    "deep nesting": ("bodies: " + "[" * 900_000, r"brackets nested 900000 deep, beyond 100"),
    "deep block nesting": ("".join(" " * i + "a:\n" for i in range(1100)),
                           r"not valid YAML at line 1000|YAML nested too deeply to read"),
    "integer of 5000 digits": ("bodies:\n  - {name: base, mass: " + "9" * 5000 + "}\n", r"a YAML value cannot be read"),
    "python tag": ("!!python/object/apply:os.system ['true']\n", r"not valid YAML"),
    "huge value quoted briefly": ("bodies:\n  - {name: base, mass: 1, com: [" + ", ".join(["1"] * 1000) + "]}\n",
                                  r"'com' must be a list of 3 numbers, got \[1, 1, 1, 1, 1, 1, \.\.\.\]"),
}


def _peak_mib(call):
    """Peak memory traced while ``call()`` runs [MiB] (NumPy's allocations included)."""
    tracemalloc.start()
    try:
        call()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak / 2**20


@pytest.mark.parametrize("case", BAD_YAMLS)
def test_bad_yaml_model_is_one_line(tmp_path, case):
    text, message = BAD_YAMLS[case]
    path = tmp_path / "m.yaml"
    path.write_text(text)
    peak = _peak_mib(lambda: _one_line_error(lambda: load_model(path), message))
    assert peak < 100  # the alias bomb expands to 9^9 strings (gigabytes) if read


def test_yaml_numbers_in_exponent_form_are_numbers(tmp_path):
    """YAML 1.1 reads 1e-5 (no decimal point) as a string, which the strict reader refuses."""
    path = tmp_path / "m.yaml"
    path.write_text("bodies:\n  - {name: base, mass: 2e1, inertia: {ixx: 1e-3, iyy: 1E-3, izz: +2e-3}}\n")
    assert load_model(path).bodies[0].inertial[[0, 4, 9]].tolist() == [20.0, 1e-3, 2e-3]


def test_model_file_bounds(tmp_path):
    _one_line_error(lambda: load_model("/dev/zero"), r"/dev/zero: not a regular file \(a device or pipe\)")
    _one_line_error(lambda: load_model(tmp_path), r"is a folder, not a model file")
    big = tmp_path / "big.yaml"
    with open(big, "wb") as f:
        f.truncate(17 << 20)
    _one_line_error(lambda: load_model(big), r"big\.yaml: 17\.0 MiB, beyond the 16 MiB a model file may have")


def test_long_chain_is_refused_before_allocating():
    """A 100-link spatial chain asked for 102 GiB (the full regressor of 82820 columns): the
    minimal set is refused with the numbers before anything is built."""
    from conftest import random_tree

    model = random_tree(np.random.default_rng(0), list(range(100)), planar=False, name="chain100")
    message = r"chain100: 101 bodies give 82820 full parameters, whose minimal set would take 307 GiB \(at most 2 GiB\)"
    assert _peak_mib(lambda: _one_line_error(lambda: minimal_parameters(model), message)) < 1  # from the counts


@pytest.mark.slow
def test_larger_planar_tree_gets_the_columns_basis():
    """Beyond PLANAR_SYMBOLIC_BODIES the SymPy definitions took tens of seconds (33 s for an
    11-body chain); the columns basis has the same rank and reproduces the momentum."""
    from conftest import random_states, random_tree
    from spaceid.dynamics import angular_momentum

    rng = np.random.default_rng(1)
    model = random_tree(rng, list(range(7)))
    param = minimal_parameters(model)
    n = len(model.bodies)
    assert param.basis == "columns" and param.n_params == n + n * (n - 1)
    q, qd, w0 = random_states(rng, model, 50)
    direct = angular_momentum(model, q, qd, w0)[:, 2]
    np.testing.assert_allclose(param.regressor(q, qd, w0)[:, 0] @ param.true_values, direct,
                               atol=1e-10 * np.abs(direct).max())


# --- logs, JSON, trajectories, mappings, bags ----------------------------------------------------

HEADER = "t,base_yaw,base_wz,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow"
ROWS = ["0,0.1,0.01,0.2,-0.3,0.5,-0.5", "0.1,0.2,0.02,0.25,-0.35,0.5,-0.5", "0.2,0.3,0.03,0.3,-0.4,0.5,-0.5"]
CSV = "\n".join([HEADER, *ROWS]) + "\n"


def _read_csv_log(path):
    return read_log(path, joints=JOINTS, planar=True)


def test_log_bounds(tmp_path, monkeypatch):
    _one_line_error(lambda: _read_csv_log("/dev/zero"), r"/dev/zero: not a regular file")
    big = tmp_path / "big.csv"
    big.write_text(CSV)
    monkeypatch.setattr(_memory, "available_memory", lambda: 10.0)  # stands for a machine's GiB
    _one_line_error(lambda: _read_csv_log(big), r"big\.csv: 4 lines of \d+ columns would need about .* GiB of memory")
    monkeypatch.setattr(_tables, "MAX_TABLE_BYTES", 100)  # and for its 128 MiB
    _one_line_error(lambda: _read_csv_log(big), r"big\.csv: 0\.0 MiB, beyond the 0 MiB a log may have")


def test_bag_folder_without_metadata_says_what_is_missing(tmp_path):
    """A ROS 2 bag folder that lost its metadata.yaml said "Is a directory"."""
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run_0.db3").write_bytes(b"SQLite format 3\x00")
    _one_line_error(lambda: _read_csv_log(tmp_path / "run"),
                    r"run: is a folder, not a log file: it holds run_0\.db3 but no metadata\.yaml, which a ROS 2 bag")


def test_deeply_nested_json_is_one_line(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 200_000 + "]" * 200_000)
    _one_line_error(lambda: read_json(path, what="result"), r"deep\.json: the result is nested too deeply to read")
    _one_line_error(lambda: load_trajectory(path), r"deep\.json: the JSON trajectory is nested too deeply")
    path.write_text("[" + "9" * 5000 + "]")
    _one_line_error(lambda: read_json(path, what="result"), r"a value of the result cannot be read")
    _one_line_error(lambda: read_json("/dev/zero", what="result"), r"not a regular file")


def _trajectory(tmp_path, **changes):
    data = load_trajectory("paper-table2").to_dict() | changes
    path = tmp_path / "traj.json"
    path.write_text(json.dumps(data))
    return path


def test_trajectory_booleans_are_not_numbers(tmp_path):
    """``"duration": true`` was one second."""
    _one_line_error(lambda: load_trajectory(_trajectory(tmp_path, duration=True)),
                    r"traj\.json: field 'duration' must be a positive number of seconds, got True")
    _one_line_error(lambda: load_trajectory(_trajectory(tmp_path, a=[[True, 0, 0], [0, 0, 0]])),
                    r"field 'a' holds true/false where numbers are expected")
    _one_line_error(lambda: load_trajectory(_trajectory(tmp_path, b=[[float("nan"), 0, 0], [0, 0, 0]])),
                    r"field 'b' contains NaN or infinite values")
    _one_line_error(lambda: load_trajectory(_trajectory(tmp_path, joints=["a", "b"]), joints=JOINTS),
                    r"trajectory drives joints \(a, b\) but the model has \(left_shoulder, left_elbow\)")


def test_mapping_alias_bomb_and_long_values(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text(BOMB + "joint_topic: *i\n")
    _one_line_error(lambda: read_mapping(path), r"map\.yaml: line 2: YAML alias '\*a' refused")
    path.write_text("joint_topic: [" + ", ".join(["x" * 50] * 1000) + "]\n")
    text = _one_line_error(lambda: read_mapping(path), r"'joint_topic' is \['xxx.*\.\.\.: expected a topic name")
    assert len(text) < 300
    path.write_text("rate: 50\nmax_gapp: 1\n")
    _one_line_error(lambda: read_mapping(path), r"unknown key 'max_gapp': did you mean 'max_gap'\?")


def test_ros2_metadata_alias_bomb_is_refused(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "metadata.yaml").write_text(BOMB + "rosbag2_bagfile_information: *i\n")
    _one_line_error(lambda: read_recording(tmp_path / "run"), r"metadata\.yaml: line 2: YAML alias '\*a' refused")


# --- fuzzed readers (issue 12, point 5) -----------------------------------------------------------

HOSTILE = ["", "\x00", "\ufeff", "\n", ",", '"', "'", "[", "]", "{", "}", ":", "- ", "&a ", "*a", "<<: *a",
           "!!python/name:os.system",
           "1e999", "-1e999", "nan", ".nan", "inf", "-0", "true", "null", "9" * 5000, "0x1F", "1_000", "\t", "\r\n",
           "[" * 2000, "<!DOCTYPE r [<!ENTITY x 'y'>]>", "&x;", "<", ">", "</link>", "<joint", 'type="', "é", "\udcff"]


@st.composite
def mutated(draw, text):
    """``text`` with a few mutations: truncated, a span replaced by hostile tokens or random
    characters, a span deleted or duplicated."""
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 40)))
        kind = draw(st.sampled_from(["truncate", "token", "random", "delete", "repeat"]))
        if kind == "truncate":
            text = text[:i]
        elif kind == "token":
            text = text[:i] + draw(st.sampled_from(HOSTILE)) + text[j:]
        elif kind == "random":
            text = text[:i] + draw(st.text(max_size=20)) + text[j:]
        elif kind == "delete":
            text = text[:i] + text[j:]
        else:
            text = text[:j] + text[i:j] * draw(st.integers(2, 50)) + text[j:]
    return text


def _write(path, text):
    path.write_bytes(text.encode("utf-8", "surrogatepass"))  # lone surrogates stay invalid UTF-8


def _parses_or_refuses(call):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            call()
        except SpaceidError as err:
            assert "\n" not in str(err) and len(str(err)) < 2000, str(err)


URDF_TEXT = (PRESETS / "satellite-7dof.urdf").read_text()[:4000].rsplit("</joint>", 1)[0] + "</joint></robot>"
YAML_TEXT = (PRESETS / "cepheus-rw.yaml").read_text()
MAPPING_TEXT = ("joint_topic: /joint_states\npose_topic: /pose\njoints: {shoulder: left_shoulder}\n"
                "rate: 50\nmax_gap: 0.1\n")
TRAJECTORY_TEXT = json.dumps(load_trajectory("paper-table2").to_dict())

READERS = {
    "csv": ("log.csv", CSV, _read_csv_log),
    "yaml model": ("m.yaml", YAML_TEXT, load_model),
    "urdf model": ("m.urdf", URDF_TEXT, load_model),
    "json": ("r.json", TRAJECTORY_TEXT, lambda p: read_json(p, what="result")),
    "trajectory": ("t.json", TRAJECTORY_TEXT, lambda p: load_trajectory(p, joints=JOINTS)),
    "mapping": ("map.yaml", MAPPING_TEXT, read_mapping),
}


def _fuzz(name, examples):
    filename, seed_text, reader = READERS[name]

    @settings(max_examples=examples, deadline=5000, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                            HealthCheck.too_slow])
    @given(text=st.one_of(mutated(seed_text), st.text(max_size=200)))
    def run(tmp_path, text):
        path = tmp_path / filename
        _write(path, text)
        _parses_or_refuses(lambda: reader(path))

    return run


@pytest.mark.parametrize("name", READERS)
def test_fuzzed_readers_smoke(tmp_path, name):
    _fuzz(name, 15)(tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", READERS)
def test_fuzzed_readers(tmp_path, name):
    _fuzz(name, 300)(tmp_path)


@pytest.mark.slow
@settings(max_examples=40, deadline=20_000,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzzed_bags(tmp_path_factory, data):
    """A small bag in each format, damaged byte by byte (truncated, overwritten, zeroed)."""
    path = _small_bag(tmp_path_factory, data.draw(st.sampled_from(["run.bag", "run.mcap"])))
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 3))):
        if not raw:
            break
        i = data.draw(st.integers(0, len(raw) - 1))
        kind = data.draw(st.sampled_from(["truncate", "overwrite", "zero"]))
        if kind == "truncate":
            raw = raw[:i]
        elif kind == "overwrite":
            raw[i:i + 8] = data.draw(st.binary(min_size=1, max_size=8))
        else:
            raw[i:i + 64] = bytes(len(raw[i:i + 64]))
    damaged = path.with_name("damaged" + path.suffix)
    damaged.write_bytes(bytes(raw))
    _parses_or_refuses(lambda: read_recording(damaged))


_BAGS = {}


def _small_bag(factory, name):
    """A 20-sample recording written once per format."""
    if name not in _BAGS:
        from spaceid.data import write_bag
        from spaceid.data._recording import JointStates, Poses, Recording

        t = np.arange(20) * 0.02
        quat = np.tile([1.0, 0, 0, 0], (20, 1))
        recording = Recording(JointStates(t, JOINTS, np.zeros((20, 2)), np.zeros((20, 2)), None),
                              Poses(t, np.zeros((20, 3)), quat, "mocap"), meta={})
        path = factory.mktemp("bags") / name
        write_bag(path, recording)
        _BAGS[name] = path
    return _BAGS[name]


def test_no_readers_leak_file_descriptors(tmp_path):
    """The stderr capture around the URDF parser restores descriptor 2 on failure too."""
    before = len(os.listdir("/proc/self/fd"))
    path = _urdf(tmp_path, BAD_URDFS["unreadable inertial"][0])
    for _ in range(20):
        with pytest.raises(SpaceidError):
            load_model(path)
    assert len(os.listdir("/proc/self/fd")) == before
