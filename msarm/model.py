"""Load a cable-driven robot: one MJCF file, two engines.

MuJoCo simulates the file (the plant) and gives the cable (tendon) kinematics; Pinocchio loads
the same file with ``pinocchio.buildModelFromMJCF`` and is the controller's nominal model.
:func:`load_robot` loads both, checks that they describe the same mechanism and reads the
names of joints and cables and the Hill parameters of every cable muscle.

Coordinates: both engines order joint coordinates depth first through the kinematic tree, so
for the hinge and slide joints msarm supports the two coordinate vectors are the same vector;
:attr:`RobotModel.pin_q_index` states that mapping explicitly (``q_pin = q_mj[pin_q_index]``)
and :func:`load_robot` verifies it by comparing body positions of both engines at a test
posture. Traps of Pinocchio's MJCF parser that are checked here: it reads only the first child
of ``<worldbody>``, turns several hinges of one body into one composite joint, and ignores
tendons, actuators and sensors (those are read from MuJoCo).

Model and data are separate, as in both engines: a :class:`RobotModel` is immutable;
:meth:`RobotModel.create_data` gives the mutable work space that computations write into.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import pinocchio
from numpy.typing import NDArray

from msarm.errors import ModelError
from msarm.muscle.hill import HillMuscles, MuscleParameters

if TYPE_CHECKING:
    from msarm.muscle.geometry import CableGeometry

__all__ = [
    "ARM_MODEL_PATH",
    "HILL_COLUMNS",
    "MODELS_DIR",
    "RobotData",
    "RobotModel",
    "load_arm",
    "load_robot",
    "mujoco_model_name",
]

#: Folder of the robot models shipped with msarm.
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
#: The musculoskeletal arm of paper 003.
ARM_MODEL_PATH = MODELS_DIR / "msarm_arm.xml"
#: Column order of the ``hill/<cable>`` numerics in a model's ``<custom>`` section.
HILL_COLUMNS = (
    "max_isometric_force_N",
    "optimal_fiber_length_m",
    "tendon_slack_length_m",
    "max_contraction_velocity_lopt_per_s",
    "pennation_at_optimal_rad",
)
_SUPPORTED_JOINTS = {mujoco.mjtJoint.mjJNT_HINGE: "hinge", mujoco.mjtJoint.mjJNT_SLIDE: "slide"}
#: Largest allowed disagreement between the engines' body positions [m] and masses [kg].
_ENGINE_TOLERANCE = 1e-9


def mujoco_model_name(mj_model: mujoco.MjModel) -> str:
    """The model's name: the ``model`` attribute of the file's ``<mujoco>`` element."""
    return mj_model.names[: mj_model.names.index(b"\0")].decode()


@dataclass
class RobotData:
    """Mutable work space of one :class:`RobotModel` (one per thread or loop).

    Attributes:
        mj: MuJoCo data of the model.
        pin: Pinocchio data of the model.
    """

    mj: mujoco.MjData
    pin: pinocchio.Data


@dataclass(frozen=True)
class RobotModel:
    """A robot loaded from one MJCF file into MuJoCo and Pinocchio (immutable description).

    Attributes:
        path: The MJCF file.
        sha256: SHA-256 of the file's bytes (hex); logs and checkpoints carry it.
        mj_model: The MuJoCo model.
        pin_model: The Pinocchio model of the same file.
        joint_names: Names of the joints, in MuJoCo order (the order of every joint-space
            array in msarm), shape ``(n,)``.
        cable_names: Names of the cables (MuJoCo tendons), in file order, shape ``(m,)``.
        joint_lower: Lower joint limits [rad or m], shape ``(n,)``.
        joint_upper: Upper joint limits [rad or m], shape ``(n,)``.
        pin_q_index: Index array with ``q_pin = q_mj[pin_q_index]``, shape ``(n,)``.
        muscles: Hill-type muscles of the cables, or ``None`` when the file has no
            ``hill/<cable>`` parameters (a cable robot, say).
    """

    path: Path
    sha256: str
    mj_model: mujoco.MjModel
    pin_model: pinocchio.Model
    joint_names: tuple[str, ...]
    cable_names: tuple[str, ...]
    joint_lower: NDArray[np.float64]
    joint_upper: NDArray[np.float64]
    pin_q_index: NDArray[np.intp]
    muscles: HillMuscles | None
    _scratch: list[RobotData] = field(default_factory=list, repr=False, compare=False)

    @property
    def name(self) -> str:
        """The model's name (the ``model`` attribute of ``<mujoco>``)."""
        return mujoco_model_name(self.mj_model)

    @property
    def n_joints(self) -> int:
        """Number of joint coordinates ``n``."""
        return len(self.joint_names)

    @property
    def n_cables(self) -> int:
        """Number of cables ``m``."""
        return len(self.cable_names)

    def create_data(self) -> RobotData:
        """Return a fresh work space for computations on this model.

        Returns:
            New MuJoCo and Pinocchio data of this model, owned by the caller.
        """
        return RobotData(mj=mujoco.MjData(self.mj_model), pin=self.pin_model.createData())

    def scratch_data(self) -> RobotData:
        """Return this model's shared work space for one-off calls (not thread-safe).

        Returns:
            The same :class:`RobotData` on every call, created on the first; any call may
            overwrite it.
        """
        if not self._scratch:
            self._scratch.append(self.create_data())
        return self._scratch[0]

    def to_pinocchio(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Map MuJoCo joint coordinates, shape ``(..., n)``, to Pinocchio's order.

        Args:
            q: Joint coordinates in MuJoCo order [rad or m], shape ``(..., n)``.

        Returns:
            The same coordinates in Pinocchio order (``q[..., pin_q_index]``, a new float
            array), shape ``(..., n)``.
        """
        return np.asarray(q, dtype=float)[..., self.pin_q_index]

    def geometry(
        self,
        q: NDArray[np.float64],
        qdot: NDArray[np.float64] | None = None,
        with_wrap_angles: bool = True,
    ) -> CableGeometry:
        """Cable lengths, muscle Jacobian and wrap angles at posture ``q`` (scratch data).

        Args:
            q: Joint coordinates [rad], shape ``(n,)``. Any finite posture is computed (callers
                evaluate the range's edges and beyond), but the model's guarantees hold only
                inside the joint range ``[joint_lower, joint_upper]``: there the Jacobian has
                full column rank and the cables span every joint torque with positive tensions
                (tested on a grid, ``tests/test_geometry.py``); outside it they may not, and
                the Hill model may find a muscle too short. The plant and the task runner
                refuse postures outside the range.
            qdot: Joint velocities [rad/s], shape ``(n,)``; zero if omitted.
            with_wrap_angles: Compute the wrap angles (NaN if False; about 3/4 of the cost).

        Returns:
            A :class:`msarm.muscle.geometry.CableGeometry`.

        Raises:
            InputError: ``q`` or ``qdot`` of the wrong shape or not finite.
        """
        from msarm.muscle.geometry import cable_geometry

        return cable_geometry(self, self.scratch_data(), q, qdot, with_wrap_angles)


def load_arm(path: str | Path | None = None) -> RobotModel:
    """Load the musculoskeletal arm (``models/msarm_arm.xml`` unless ``path`` is given).

    Args:
        path: The MJCF file; :data:`ARM_MODEL_PATH` when ``None``.

    Returns:
        The loaded model, with :attr:`RobotModel.muscles` set.

    Raises:
        ModelError: The file cannot be loaded (see :func:`load_robot`), or it has no Hill
            parameters ``hill/<cable>`` in ``<custom>``.
    """
    model = load_robot(ARM_MODEL_PATH if path is None else path)
    if model.muscles is None:
        raise ModelError(
            f"{model.path}: an arm model needs Hill parameters 'hill/<cable>' in <custom> "
            f"for every cable ({', '.join(model.cable_names)})"
        )
    return model


def load_robot(path: str | Path) -> RobotModel:
    """Load an MJCF file into MuJoCo and Pinocchio and check that both agree.

    Args:
        path: The MJCF file.

    Returns:
        The loaded model.

    Raises:
        ModelError: The file is missing or malformed, has no tendons, uses joints msarm does
            not support, or the Pinocchio view differs from the MuJoCo view (for example
            several root bodies, of which the parser reads only the first).
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path} (expected an MJCF .xml file)")
    raw = path.read_bytes()
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise ModelError(f"{path}: MuJoCo cannot load the file: {exc}") from exc
    if mj_model.ntendon == 0:
        raise ModelError(
            f"{path}: the model has no tendons; msarm needs one <spatial> tendon per cable"
        )
    joint_names = _joint_names(mj_model, path)
    _check_single_root(mj_model, path)
    try:
        pin_model = pinocchio.buildModelFromMJCF(str(path))
    except Exception as exc:  # the parser raises bare RuntimeErrors and ValueErrors
        raise ModelError(f"{path}: Pinocchio cannot load the file: {exc}") from exc
    pin_q_index = np.arange(mj_model.nq, dtype=np.intp)
    _check_engines_agree(mj_model, pin_model, pin_q_index, path)
    cable_names = tuple(mj_model.tendon(i).name for i in range(mj_model.ntendon))
    if any(not name for name in cable_names):
        raise ModelError(f"{path}: every tendon needs a name (the cable's name)")
    lower, upper = _joint_limits(mj_model)
    return RobotModel(
        path=path,
        sha256=hashlib.sha256(raw).hexdigest(),
        mj_model=mj_model,
        pin_model=pin_model,
        joint_names=joint_names,
        cable_names=cable_names,
        joint_lower=lower,
        joint_upper=upper,
        pin_q_index=pin_q_index,
        muscles=_read_hill_parameters(mj_model, cable_names, path),
    )


def _joint_names(mj_model: mujoco.MjModel, path: Path) -> tuple[str, ...]:
    names = []
    for j in range(mj_model.njnt):
        joint = mj_model.joint(j)
        kind = int(mj_model.jnt_type[j])
        if kind not in _SUPPORTED_JOINTS:
            raise ModelError(
                f"{path}: joint '{joint.name}' is of type {mujoco.mjtJoint(kind).name}; msarm "
                f"supports {' and '.join(_SUPPORTED_JOINTS.values())} joints only"
            )
        if not joint.name:
            raise ModelError(f"{path}: joint {j} has no name; every joint needs one")
        names.append(joint.name)
    if not names:
        raise ModelError(f"{path}: the model has no joints")
    return tuple(names)


def _check_single_root(mj_model: mujoco.MjModel, path: Path) -> None:
    roots = [
        mj_model.body(b).name for b in range(1, mj_model.nbody) if mj_model.body_parentid[b] == 0
    ]
    if len(roots) != 1:
        raise ModelError(
            f"{path}: <worldbody> has {len(roots)} root bodies ({', '.join(roots)}); "
            "Pinocchio's MJCF parser reads only the first, so the two engines would disagree. "
            "Put every body under one root body."
        )


def _check_engines_agree(
    mj_model: mujoco.MjModel, pin_model: pinocchio.Model, pin_q_index: NDArray[np.intp], path: Path
) -> None:
    if (pin_model.nq, pin_model.nv) != (mj_model.nq, mj_model.nv):
        raise ModelError(
            f"{path}: Pinocchio sees nq={pin_model.nq}, nv={pin_model.nv} but MuJoCo "
            f"nq={mj_model.nq}, nv={mj_model.nv}"
        )
    mj_mass = float(mj_model.body_subtreemass[0])
    pin_mass = float(sum(inertia.mass for inertia in pin_model.inertias))
    if abs(mj_mass - pin_mass) > _ENGINE_TOLERANCE * max(1.0, mj_mass):
        raise ModelError(
            f"{path}: total mass differs between MuJoCo ({mj_mass:.6g} kg) and Pinocchio "
            f"({pin_mass:.6g} kg)"
        )
    # Body positions at a test posture inside the joint range must agree body by body.
    lower, upper = _joint_limits(mj_model)
    q = lower + (upper - lower) * np.linspace(0.3, 0.7, mj_model.nq)
    mj_data = mujoco.MjData(mj_model)
    mj_data.qpos[:] = q
    mujoco.mj_kinematics(mj_model, mj_data)
    pin_data = pin_model.createData()
    pinocchio.framesForwardKinematics(pin_model, pin_data, q[pin_q_index])
    for b in range(1, mj_model.nbody):
        name = mj_model.body(b).name
        if not pin_model.existFrame(name):
            raise ModelError(f"{path}: body '{name}' is missing from Pinocchio's model")
        pin_pos = pin_data.oMf[pin_model.getFrameId(name)].translation
        if np.abs(pin_pos - mj_data.xpos[b]).max() > _ENGINE_TOLERANCE:
            raise ModelError(
                f"{path}: body '{name}' is at {np.round(mj_data.xpos[b], 6)} in MuJoCo but at "
                f"{np.round(pin_pos, 6)} in Pinocchio at q={np.round(q, 4)}"
            )


def _joint_limits(mj_model: mujoco.MjModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    limited = mj_model.jnt_limited.astype(bool)
    lower = np.where(limited, mj_model.jnt_range[:, 0], -np.pi)
    upper = np.where(limited, mj_model.jnt_range[:, 1], np.pi)
    return lower.astype(float), upper.astype(float)


def _read_hill_parameters(
    mj_model: mujoco.MjModel, cable_names: tuple[str, ...], path: Path
) -> HillMuscles | None:
    numerics = {mj_model.numeric(i).name: i for i in range(mj_model.nnumeric)}
    wanted = {name: f"hill/{name}" for name in cable_names}
    present = [key for key in wanted.values() if key in numerics]
    if not present:
        return None
    missing = [key for key in wanted.values() if key not in numerics]
    if missing:
        raise ModelError(f"{path}: Hill parameters missing in <custom>: {', '.join(missing)}")
    params = []
    for name, key in wanted.items():
        values = np.asarray(mj_model.numeric(numerics[key]).data, dtype=float)
        if values.shape != (len(HILL_COLUMNS),):
            raise ModelError(
                f"{path}: numeric '{key}' has {values.size} values; expected "
                f"{len(HILL_COLUMNS)}: {' '.join(HILL_COLUMNS)}"
            )
        try:
            params.append(MuscleParameters(name, *values))
        except ValueError as exc:
            raise ModelError(f"{path}: numeric '{key}': {exc}") from exc
    return HillMuscles(params)
