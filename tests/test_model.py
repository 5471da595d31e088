"""msarm.model: one file, two engines that agree; clear errors on bad model files."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pinocchio
import pytest

from msarm.errors import ModelError, ModelWarning
from msarm.model import ARM_MODEL_PATH, load_arm, load_robot


def test_arm_has_the_joints_and_muscles_of_paper_003(arm):
    assert arm.joint_names == (
        "shoulder_abduction",
        "shoulder_flexion",
        "shoulder_rotation",
        "elbow",
    )
    assert arm.n_cables == 9
    assert arm.muscles is not None and arm.muscles.names == arm.cable_names
    assert len(arm.sha256) == 64
    # The Table I targets of paper 003 lie inside the joint range.
    table1 = np.array(
        [
            [0, 0.4363, -0.5236, -1.2217],
            [0, 0.3491, -0.6109, -0.9599],
            [0, 0.5236, -0.4363, -0.8727],
            [-0.0873, 0.3491, -0.4363, -0.6109],
        ]
    )
    assert np.all(table1 >= arm.joint_lower) and np.all(table1 <= arm.joint_upper)


def test_mass_matrix_and_bias_forces_agree_on_100_random_states(arm):
    rng = np.random.default_rng(20261121)
    m_model, pin_model = arm.mj_model, arm.pin_model
    m_data, pin_data = mujoco.MjData(m_model), pin_model.createData()
    mass_mj = np.zeros((m_model.nv, m_model.nv))
    worst_mass = worst_bias = 0.0
    for _ in range(100):
        q = rng.uniform(arm.joint_lower, arm.joint_upper)
        v = rng.normal(scale=2.0, size=m_model.nv)
        m_data.qpos[:] = q
        m_data.qvel[:] = v
        mujoco.mj_forward(m_model, m_data)
        mujoco.mj_fullM(m_model, m_data, mass_mj)
        q_pin = arm.to_pinocchio(q)
        mass_pin = pinocchio.crba(pin_model, pin_data, q_pin)
        mass_pin = np.triu(mass_pin) + np.triu(mass_pin, 1).T
        bias_pin = pinocchio.rnea(pin_model, pin_data, q_pin, v[arm.pin_q_index], np.zeros(4))
        worst_mass = max(worst_mass, np.abs(mass_mj - mass_pin).max())
        worst_bias = max(worst_bias, np.abs(m_data.qfrc_bias - bias_pin).max())
    assert worst_mass < 1e-9
    assert worst_bias < 1e-9


def test_hand_site_agrees_between_engines(arm):
    q = np.array([0.3, 0.5, -0.4, -1.0])
    m_data = mujoco.MjData(arm.mj_model)
    m_data.qpos[:] = q
    mujoco.mj_kinematics(arm.mj_model, m_data)
    pin_data = arm.pin_model.createData()
    pinocchio.framesForwardKinematics(arm.pin_model, pin_data, arm.to_pinocchio(q))
    frame = arm.pin_model.getFrameId("hand_center")
    np.testing.assert_allclose(
        pin_data.oMf[frame].translation, m_data.site("hand_center").xpos, atol=1e-12
    )


def _variant(tmp_path: Path, old: str, new: str, count: int = 1) -> Path:
    text = ARM_MODEL_PATH.read_text()
    assert old in text
    path = tmp_path / "variant.xml"
    path.write_text(text.replace(old, new, count))
    return path


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ModelError, match=r"not found.*nowhere.xml"):
        load_robot(tmp_path / "nowhere.xml")


def test_malformed_file_is_refused(tmp_path):
    path = tmp_path / "broken.xml"
    path.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(ModelError, match="MuJoCo cannot load") as info:
        load_robot(path)
    assert "\n" not in str(info.value)  # MuJoCo's reason spans lines; the error is one


def test_model_without_tendons_is_refused(tmp_path):
    text = re.sub(r"<tendon>.*</tendon>", "", ARM_MODEL_PATH.read_text(), flags=re.S)
    path = tmp_path / "no_tendons.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match="no tendons"):
        load_robot(path)


def test_several_root_bodies_are_refused(tmp_path):
    path = _variant(
        tmp_path,
        "  </worldbody>",
        '    <body name="table" pos="1 0 0"><geom type="box" size="0.1 0.1 0.1"/></body>\n'
        "  </worldbody>",
    )
    with pytest.raises(ModelError, match=r"2 root bodies.*torso, table"):
        load_robot(path)


def test_root_body_offset_that_pinocchio_drops_is_caught(tmp_path):
    path = _variant(tmp_path, '<body name="torso" pos="0 0 0">', '<body name="torso" pos="0 0 1">')
    with pytest.raises(ModelError, match="body 'torso' is at"):
        load_robot(path)


def test_unsupported_joint_type_is_named(tmp_path):
    path = _variant(
        tmp_path,
        '<joint name="elbow" type="hinge" axis="0 1 0" range="-2.3 0.05"/>',
        '<joint name="elbow" type="ball"/>',
    )
    with pytest.raises(ModelError, match=r"joint 'elbow'.*BALL"):
        load_robot(path)


def test_missing_hill_parameters_are_named(tmp_path):
    text = re.sub(r'\s*<numeric name="hill/biceps" data="[^"]*"/>', "", ARM_MODEL_PATH.read_text())
    path = tmp_path / "no_biceps.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match="hill/biceps"):
        load_arm(path)


def test_hill_parameters_of_no_cable_are_warned_about(tmp_path):
    text = ARM_MODEL_PATH.read_text()
    biceps = re.search(r'<numeric name="hill/biceps" data="[^"]*"/>', text).group(0)
    text = text.replace(biceps, biceps + biceps.replace("hill/biceps", "hill/bicep"))
    path = tmp_path / "stray_hill.xml"
    path.write_text(text)
    with pytest.warns(ModelWarning, match=r"hill/bicep name no cable of the model .*biceps"):
        arm = load_arm(path)
    assert arm.cable_names == load_arm().cable_names


def test_malformed_hill_parameters_are_named(tmp_path):
    text = re.sub(
        r'<numeric name="hill/triceps" data="[^"]*"/>',
        '<numeric name="hill/triceps" data="300 0.1"/>',
        ARM_MODEL_PATH.read_text(),
    )
    path = tmp_path / "short_triceps.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"hill/triceps.*2 values"):
        load_arm(path)


def test_gravity_switched_off_or_changed_in_the_file_reaches_pinocchio(tmp_path):
    """Pinocchio's parser ignores <option gravity>: the loader copies MuJoCo's (zero when off)."""
    option = '<option timestep="0.001" gravity="0 0 -9.81"/>'
    for new, expected in (
        ('<option timestep="0.001" gravity="0 0 -1.62"/>', [0.0, 0.0, -1.62]),
        ('<option timestep="0.001"><flag gravity="disable"/></option>', [0.0, 0.0, 0.0]),
    ):
        model = load_arm(_variant(tmp_path, option, new))
        np.testing.assert_array_equal(model.pin_model.gravity.linear, expected)
        q = np.array([0.5, 0.5, 0.0, -1.0])
        data = mujoco.MjData(model.mj_model)
        data.qpos[:] = q
        mujoco.mj_forward(model.mj_model, data)
        pin_gravity = pinocchio.computeGeneralizedGravity(
            model.pin_model, model.pin_model.createData(), q
        )
        np.testing.assert_allclose(pin_gravity, data.qfrc_bias, atol=1e-12)


def test_a_body_pinocchio_reads_otherwise_is_caught_by_the_dynamics(tmp_path):
    # MuJoCo normalises a body's axisangle axis; the parser takes it as written
    path = _variant(
        tmp_path,
        '<body name="hand" pos="0 0 -0.2555">',
        '<body name="hand" pos="0 0 -0.2555" axisangle="0 0 2 0.7">',
    )
    with pytest.raises(ModelError, match=r"mass matrix differs between MuJoCo and Pinocchio"):
        load_robot(path)


def test_a_fixed_tendon_and_a_range_in_degrees_are_refused(tmp_path):
    coupling = '<fixed name="coupling"><joint joint="elbow" coef="0.02"/></fixed>\n  </tendon>'
    with pytest.raises(ModelError, match="tendon 'coupling' is a <fixed> tendon"):
        load_robot(_variant(tmp_path, "</tendon>", coupling))
    degrees = '<joint name="elbow" type="hinge" axis="0 1 0" range="-132 3"/>'
    elbow = '<joint name="elbow" type="hinge" axis="0 1 0" range="-2.3 0.05"/>'
    with pytest.raises(ModelError, match=r"hinge 'elbow' has the range \[-132, 3\] rad"):
        load_robot(_variant(tmp_path, elbow, degrees))


def test_a_range_in_radians_read_as_degrees_is_warned_about(tmp_path, recwarn):
    # without <compiler angle="radian">, MuJoCo reads the arm's radian ranges as degrees
    compiler = '<compiler angle="radian" autolimits="true"/>'
    path = _variant(tmp_path, compiler, '<compiler autolimits="true"/>')
    with pytest.warns(ModelWarning, match=r"narrower than 5 degrees: 'shoulder_abduction'") as got:
        model = load_robot(path)
    assert len(got) == 1 and "'elbow' [-0.04014, 0.0008727]" in str(got[0].message)
    assert model.joint_upper[3] - model.joint_lower[3] == pytest.approx(np.deg2rad(2.35))
    load_robot(ARM_MODEL_PATH)  # the shipped model: no warning
    assert not [w for w in recwarn if issubclass(w.category, ModelWarning)]


def test_the_model_hash_covers_included_files_and_not_line_endings(tmp_path, arm):
    text = ARM_MODEL_PATH.read_text()
    crlf = tmp_path / "crlf.xml"
    crlf.write_bytes(text.replace("\n", "\r\n").encode())
    assert load_robot(crlf).sha256 == arm.sha256  # a Windows checkout of the same model
    start, stop = text.index("<tendon>"), text.index("</tendon>") + len("</tendon>")
    (tmp_path / "tendons.xml").write_text(f"<mujoco>{text[start:stop]}</mujoco>")
    split = tmp_path / "split.xml"
    split.write_text(text[:start] + '<include file="tendons.xml"/>' + text[stop:])
    first = load_robot(split)
    np.testing.assert_array_equal(first.mj_model.tendon_length0, arm.mj_model.tendon_length0)
    # a change in the included file alone (a cable's path) changes the hash
    tendons = (tmp_path / "tendons.xml").read_text()
    site = re.search(r'<site site="([^"]+)"/>', tendons).group(0)
    (tmp_path / "tendons.xml").write_text(tendons.replace(site, "", 1))
    second = load_robot(split)
    assert not np.array_equal(second.mj_model.tendon_length0, first.mj_model.tendon_length0)
    assert second.sha256 != first.sha256


def test_a_body_the_parser_drops_or_a_mass_from_geoms_is_named_with_its_cause(tmp_path):
    hand = '<body name="hand" pos="0 0 -0.2555">'
    text = ARM_MODEL_PATH.read_text()
    start = text.index(hand)
    end = text.index("</body>", start) + len("</body>")
    framed = text[:start] + '<frame pos="0 0 0">' + text[start:end] + "</frame>" + text[end:]
    path = tmp_path / "framed.xml"
    path.write_text(framed)
    with pytest.raises(ModelError, match=r"body 'hand' is missing from Pinocchio's model.*frame"):
        load_robot(path)
    inertial = re.search(r"<inertial[^>]*/>", text[start:end]).group(0)
    path.write_text(text[:start] + text[start:end].replace(inertial, "", 1) + text[end:])
    with pytest.raises(ModelError, match=r"total mass differs.*<inertial> element only"):
        load_robot(path)


def test_cable_lengths_that_do_not_fit_the_hill_parameters_are_refused(tmp_path, arm):
    """A model drawn in millimetres: the cables are 1000 times what the muscles can be."""
    text = ARM_MODEL_PATH.read_text()
    sites = re.findall(r'<site name="[^"]+" pos="([^"]+)"', text)
    assert sites
    scaled = text
    for pos in sorted(set(sites), key=len, reverse=True):
        millimetres = " ".join(f"{1000 * float(v):g}" for v in pos.split())
        scaled = scaled.replace(f'pos="{pos}"', f'pos="{millimetres}"')
    path = tmp_path / "millimetres.xml"
    path.write_text(scaled)
    with pytest.raises(ModelError, match=r"cable '.*' is .* m long at the reference posture"):
        load_arm(path)
    # the shipped arm sits well inside the range: 0.8-1.2 optimal lengths
    data = mujoco.MjData(arm.mj_model)
    mujoco.mj_forward(arm.mj_model, data)
    fibre = arm.muscles.fiber_state(data.ten_length, np.zeros(arm.n_cables)).length_norm
    assert np.all((fibre > 0.7) & (fibre < 1.3))


def test_size_muscles_resizes_a_model_load_arm_refuses(tmp_path, monkeypatch, capsys):
    """After a move that shortens a cable past its tendon slack length, load_arm refuses the
    model until the muscles are sized again; size_muscles.py used load_arm and could not."""
    import runpy
    import sys

    text = ARM_MODEL_PATH.read_text()
    text = re.sub(r'(name="teres_minor_motor" pos=")[^"]*"', r'\g<1>-0.04 -0.04 0.05"', text)
    text = re.sub(r'(name="teres_minor_sheath1" pos=")[^"]*"', r'\g<1>-0.10 -0.12 0.16"', text)
    moved = tmp_path / "moved.xml"
    moved.write_text(text)
    with pytest.raises(ModelError, match=r"teres_minor.*size the muscles again"):
        load_arm(moved)
    script = ARM_MODEL_PATH.parent / "size_muscles.py"
    monkeypatch.setattr(sys, "argv", [str(script), str(moved)])
    runpy.run_path(str(script), run_name="__main__")
    assert "teres_minor" in capsys.readouterr().out
    arm = load_arm(moved)  # sized again: the fibres are near their optimal length
    assert arm.muscles is not None


@pytest.mark.parametrize(
    "attribute, element, expected",
    [
        ('damping="0.5"', '<joint name="elbow"', "joint damping is set .* joint 'elbow'"),
        ('stiffness="2"', '<joint name="elbow"', "joint stiffness is set"),
        ('gravcomp="1"', '<body name="forearm"', r"gravity compensation \(gravcomp\) is set"),
    ],
)
def test_passive_forces_the_nominal_model_lacks_are_refused(tmp_path, attribute, element, expected):
    """MuJoCo applied them in the plant and Pinocchio's nominal model did not have them."""
    text = ARM_MODEL_PATH.read_text()
    assert element in text
    path = tmp_path / "passive.xml"
    path.write_text(text.replace(element, f"{element} {attribute}", 1))
    with pytest.raises(ModelError, match=expected):
        load_robot(path)
