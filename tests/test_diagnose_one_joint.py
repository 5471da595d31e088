"""A user's own model: one hinge, two cables (a one-jaw surgical tool), diagnosed end to end.

The model is written here (a minimal MJCF: no Hill parameters, which the diagnosis does not
need) with its joint named like its body, as MJCF files often do. The logs are made by hand:
the jaw moves along a slow sine, and the two antagonist cables' tensions deliver the nominal
inverse dynamics plus a known Coulomb friction torque (and a slowly varying pretension), so
the diagnosis must name that friction.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pinocchio
import pytest
from conftest import run_msarm

from msarm.diagnose.bench_parameters import parameter_errors
from msarm.diagnose.effects import InertiaError
from msarm.diagnose.residuals import DiagnosisWarning
from msarm.diagnose.select import diagnose
from msarm.errors import InputError, ModelError
from msarm.io.logs import LogMetadata, RunLog, read_log, write_log
from msarm.model import load_arm, load_robot
from msarm.muscle.batch_kinematics import cable_kinematics_batch
from msarm.tasks.evaluate import hand_position

RATE = 250.0
#: The logs' Coulomb friction of the jaw [N m] (smoothed sign, the library's eps).
COULOMB = 0.01
EPS = 0.01
#: Drum radius of the motor angles [m] (the diagnosis's default).
DRUM = 0.003

_MODEL = """<mujoco model="{name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.001" gravity="0 0 -9.81"/>
  <worldbody>
    <body name="base">
      <inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>
      <site name="open_motor" pos="-0.1 {w} {h}"/>
      <site name="close_motor" pos="-0.1 {mw} {mh}"/>
      <site name="open_origin" pos="-0.01 {w} {h}"/>
      <site name="close_origin" pos="-0.01 {mw} {mh}"/>
      <body name="jaw">
        <joint name="jaw" type="hinge" axis="{axis}" range="-0.8 0.8"/>
        <inertial pos="0.02 0 0" mass="0.05" diaginertia="1e-5 2e-5 2e-5"/>
        <geom type="capsule" fromto="0 0 0 0.04 0 0" size="0.003" contype="0" conaffinity="0"/>
        <site name="open_insertion" pos="0.005 {iw} {ih}"/>
        <site name="close_insertion" pos="0.005 {miw} {mih}"/>
        {hand}
      </body>
    </body>
  </worldbody>
  <tendon>
    <spatial name="open">
      <site site="open_motor"/><site site="open_origin"/><site site="open_insertion"/>
    </spatial>
    <spatial name="close">
      <site site="close_motor"/><site site="close_origin"/><site site="close_insertion"/>
    </spatial>
  </tendon>
</mujoco>
"""


def write_jaw_model(path, vertical=False, hand=True):
    """Write the one-jaw model: a hinge about y (gravity acts) or z (it does not)."""
    # the cables run in the plane normal to the hinge axis, one each side of it
    h, w = (0.0, 0.01) if vertical else (0.01, 0.0)
    text = _MODEL.format(
        name=path.stem,
        axis="0 0 1" if vertical else "0 1 0",
        h=h,
        w=w,
        mh=-h,
        mw=-w,
        ih=0.6 * h,
        iw=0.6 * w,
        mih=-0.6 * h,
        miw=-0.6 * w,
        hand='<site name="hand_center" pos="0.04 0 0"/>' if hand else "",
    )
    path.write_text(text)
    return path


def jaw_log(model, seed, duration=4.0):
    """A hand-made run of the jaw: a slow sine, tensions that deliver the nominal inverse
    dynamics plus Coulomb friction (a positive joint residual ``c tanh(qd / eps)``)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * RATE)) / RATE
    amplitude, omega = 0.4 + 0.1 * rng.random(), 2 * np.pi * (0.1 + 0.05 * rng.random())
    phase = rng.uniform(0, 2 * np.pi)
    q = (amplitude * np.sin(omega * t + phase))[:, None]
    qd = (amplitude * omega * np.cos(omega * t + phase))[:, None]
    qdd = (-amplitude * omega**2 * np.sin(omega * t + phase))[:, None]
    data = model.pin_model.createData()
    torque = np.array(
        [pinocchio.rnea(model.pin_model, data, q[k], qd[k], qdd[k]) for k in range(len(t))]
    )
    torque = torque + COULOMB * np.tanh(qd / EPS)
    kinematics = cable_kinematics_batch(model, q, with_wrap_angles=False)
    per_newton = -kinematics.jacobian[:, :, 0]  # torque of 1 N in each cable, (T, 2)
    pretension = (10.0 + 15.0 * seed) * (1.0 + 0.5 * np.sin(2 * np.pi * 0.3 * t + seed))
    tension = pretension[:, None] * np.ones(2)
    short = torque[:, 0] - np.sum(per_newton * tension, axis=1)
    tension += per_newton * (short / np.sum(per_newton**2, axis=1))[:, None]
    assert tension.min() > 1.0  # both cables taut
    tension += 1e-3 * rng.normal(size=tension.shape)
    command = np.vstack([tension[1:], tension[-1:]])  # each tension answers the last command
    motor = -(kinematics.lengths - kinematics.lengths[0]) / DRUM  # rigid cables
    return RunLog.from_quantities(
        t,
        {
            "q": (model.joint_names, q + 1e-5 * rng.normal(size=q.shape)),
            "q_ref": (model.joint_names, q),
            "tension_motor": (model.cable_names, tension),
            "tension_cmd": (model.cable_names, command),
            "motor_angle": (model.cable_names, motor),
        },
        LogMetadata.for_model(model, RATE),
    )


def _write_logs(model, folder, count=4):
    folder.mkdir()
    return [write_log(folder / f"run{k}.parquet", jaw_log(model, k)) for k in range(count)]


@pytest.fixture(scope="module")
def jaw(tmp_path_factory):
    """The one-jaw model (hinge about y, hand site) and four logs of it."""
    root = tmp_path_factory.mktemp("jaw")
    path = write_jaw_model(root / "jaw.xml")
    model = load_robot(path)
    return path, model, _write_logs(model, root / "logs")


def test_a_joint_named_like_its_body_loads(jaw):
    """Pinocchio has a body frame and a joint frame 'jaw': the engines are compared on the
    body's (a look-up by name alone raised "Several frames match the filter")."""
    _, model, _ = jaw
    assert model.joint_names == ("jaw",) and model.cable_names == ("open", "close")
    assert model.muscles is None  # no Hill parameters needed
    frames = [f.type for f in model.pin_model.frames if f.name == "jaw"]
    assert pinocchio.FrameType.BODY in frames and pinocchio.FrameType.JOINT in frames


def test_the_mass_error_term_works_with_one_joint(jaw):
    """Pinocchio's regressor of a one-joint model is a vector: kept as one row."""
    _, model, _ = jaw
    term = InertiaError(model, subset="all")
    assert term.n_parameters > 0 and term.why_no_parameters == ""
    rng = np.random.default_rng(3)
    data = model.pin_model.createData()
    inertias = model.pin_model.inertias
    dynamic = np.concatenate([inertias[j].toDynamicParameters() for j in range(1, len(inertias))])
    for _ in range(5):
        q, qd, qdd = rng.uniform(-0.8, 0.8, 1), rng.normal(size=1), rng.normal(size=1)
        regressor = term._regressor(q, qd, qdd)
        assert regressor.shape == (1, 10)
        expected = pinocchio.rnea(model.pin_model, data, q, qd, qdd)
        np.testing.assert_allclose(regressor @ dynamic, expected, rtol=1e-12, atol=1e-15)


def test_diagnose_names_the_jaws_friction_end_to_end(jaw, tmp_path, monkeypatch, capsys):
    path, model, logs = jaw
    out = tmp_path / "report"
    train = [str(p) for p in logs[:3]]
    code, stdout, err = run_msarm(
        monkeypatch, capsys, "diagnose", *train, "--holdout", str(logs[3]),
        "--model", str(path), "--boot", "0", "--json", "--out", str(out),
    )  # fmt: skip
    assert code == 0, err
    payload = json.loads(stdout)
    first = payload["selected"][0]
    # the friction put in: a Coulomb level. A Stribeck term nests it and, on the
    # filter-smoothed reversals, can score the same to 1e-4: the friction it says is compared
    # as the benchmark compares it, its steady curve at 0.05-0.5 rad/s
    assert first["name"] in ("coulomb", "stribeck") and first["groups"] == ["joint"]
    row = {
        "effects": ["joint_friction"],
        "parameters": {"joint_friction": {"coulomb": COULOMB, "viscous": 0.0}},
        "msarm": {"parameters": {s["name"]: s["parameters"] for s in payload["selected"]}},
    }
    assert parameter_errors(row)["friction_curve"] < 0.03
    assert payload["gap"]["joint"]["shrink"] > 0.9  # the held-out joint gap, nearly all of it
    # the replay with the hand site: both metrics
    replay = payload["replay"]
    assert all(isinstance(replay[k], float) for k in ("joint_rmse_before", "hand_error_end_before"))
    # the posture breakdown of one joint: the joint's bins, not a grid of it against itself
    posture = payload["where"]["joint_torque"]["posture"]
    assert posture["joints"] == ["jaw", "jaw"]
    rows = [r["where"] for r in payload["where"]["joint_torque"]["rows"] if r["group"] == "posture"]
    assert rows and all(" x " not in where and where.startswith("jaw [") for where in rows)
    assert (out / "report.md").is_file() and (out / "where-joint_torque.png").is_file()


def test_a_model_without_the_hand_site_is_diagnosed_without_the_hand_error(tmp_path):
    path = write_jaw_model(tmp_path / "no_hand.xml", hand=False)
    model = load_robot(path)  # the diagnosis's loader does not need the site
    logs = _write_logs(model, tmp_path / "logs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DiagnosisWarning)
        result = diagnose(model, logs[:3], logs[3:], n_boot=0)
    replay = result.as_dict()["replay"]
    assert replay["hand_error_end_before"] is None and replay["hand_error_end_after"] is None
    assert replay["joint_rmse_before"] > 0 and np.isfinite(replay["joint_rmse_after"])
    text = result.to_markdown()
    assert "No hand error: the model has no `hand_center` site" in text
    assert "hand error at window end" not in text
    # asked for, the hand position is refused with the site named (a KeyError before)
    with pytest.raises(ModelError, match=r"no site 'hand_center'.*add <site"):
        hand_position(model, np.zeros(1))


def test_the_arm_loader_refuses_a_model_without_the_hand_site(tmp_path):
    from msarm.model import ARM_MODEL_PATH

    text = ARM_MODEL_PATH.read_text()
    line = next(x for x in text.splitlines(keepends=True) if '<site name="hand_center"' in x)
    path = tmp_path / "no_hand_arm.xml"
    path.write_text(text.replace(line, ""))
    with pytest.raises(ModelError, match=r"no_hand_arm.xml: the model has no site 'hand_center'"):
        load_arm(path)


def test_a_mass_error_with_nothing_to_fit_is_left_out_with_the_reason(tmp_path):
    """A vertical hinge: gravity does not act, so no mass or first moment changes the joint
    torque; the term is listed as not tried instead of failing the fit."""
    path = write_jaw_model(tmp_path / "vertical.xml", vertical=True)
    model = load_robot(path)
    term = InertiaError(model)
    assert term.n_parameters == 0 and "gravity does not act" in term.why_no_parameters
    logs = _write_logs(model, tmp_path / "logs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DiagnosisWarning)
        result = diagnose(model, logs[:3], logs[3:], n_boot=0)
    assert result.skipped["inertia"].startswith("has no parameter to fit on this model: none")
    assert "- inertia: has no parameter to fit" in result.to_markdown()
    assert result.selected[0].name in ("coulomb", "stribeck")
    # named by the user, it is an error that says why
    with pytest.raises(InputError, match=r"inertia cannot be fitted .* no parameter to fit"):
        diagnose(model, logs[:3], logs[3:], candidates=["coulomb", "inertia"], n_boot=0)


def test_log_import_with_the_one_joint_model(jaw, tmp_path, monkeypatch, capsys):
    path, model, logs = jaw
    log = read_log(logs[0])
    names = ["t", "q.jaw", "tension_motor.open", "tension_motor.close"]
    rows = np.stack([log.columns[n] for n in names], axis=1)
    csv = tmp_path / "jaw_run.csv"
    csv.write_text(
        ",".join(names) + "\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows)
    )
    code, stdout, err = run_msarm(
        monkeypatch, capsys, "log", "import", str(csv), "--model", str(path), "--json"
    )
    assert code == 0, err
    written = json.loads(stdout)["logs"][0]
    assert written["error"] is None and written["residuals"]["joint_torque"] is True
    imported = read_log(tmp_path / "jaw_run.parquet")
    assert imported.metadata.model_sha256 == model.sha256
    np.testing.assert_array_equal(imported.columns["q.jaw"], log.columns["q.jaw"])
