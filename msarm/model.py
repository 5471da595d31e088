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
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import pinocchio
from numpy.typing import NDArray

from msarm.errors import ModelError, ModelWarning
from msarm.muscle.hill import MAX_FIBRE_LENGTH, HillMuscles, MuscleParameters

if TYPE_CHECKING:
    from msarm.muscle.geometry import CableGeometry

__all__ = [
    "ARM_MODEL_PATH",
    "HAND_SITE",
    "HILL_COLUMNS",
    "MODELS_DIR",
    "RobotData",
    "RobotModel",
    "hand_site_id",
    "has_hand_site",
    "load_arm",
    "load_robot",
    "mujoco_model_name",
]


def _models_dir(package: Path) -> Path:
    """The shipped models: inside the package in a wheel, else the repository's ``models/``."""
    inside = package / "models"
    return inside if inside.is_dir() else package.parent / "models"


#: Folder of the robot models shipped with msarm (``models/`` of a source checkout or an
#: editable install; ``msarm/models`` of an installed wheel).
MODELS_DIR = _models_dir(Path(__file__).resolve().parent)
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
#: The end-effector site: the tracking metrics' hand position (final error, settle error)
#: and the diagnosis's hand error of the replay are this site's position. An arm model
#: (:func:`load_arm`) needs it; a model for the diagnosis alone may leave it out.
HAND_SITE = "hand_center"
_SUPPORTED_JOINTS = {mujoco.mjtJoint.mjJNT_HINGE: "hinge", mujoco.mjtJoint.mjJNT_SLIDE: "slide"}
#: Largest allowed disagreement between the engines' body positions [m] and masses [kg].
_ENGINE_TOLERANCE = 1e-9
#: Relative tolerance of the engines' mass matrices and bias forces: loose enough for an
#: orientation written to 7 digits (0.7071068), tight against a body the parser reads
#: otherwise (differences of 1e-3 and more).
_DYNAMICS_TOLERANCE = 1e-6


def has_hand_site(model: RobotModel) -> bool:
    """Whether the model has the end-effector site :data:`HAND_SITE`."""
    site = mujoco.mj_name2id(model.mj_model, mujoco.mjtObj.mjOBJ_SITE, HAND_SITE)
    return bool(site >= 0)


def hand_site_id(model: RobotModel) -> int:
    """MuJoCo id of the end-effector site :data:`HAND_SITE`.

    Args:
        model: The robot.

    Returns:
        The site's id in ``model.mj_model``.

    Raises:
        ModelError: The model has no such site (file and site named).
    """
    if not has_hand_site(model):
        raise ModelError(
            f"{model.path}: the model has no site '{HAND_SITE}'; the hand position (tracking "
            f"metrics, the diagnosis's replay) is that site's: add <site name=\"{HAND_SITE}\"/> "
            "to the end effector's body"
        )
    return int(mujoco.mj_name2id(model.mj_model, mujoco.mjtObj.mjOBJ_SITE, HAND_SITE))


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
        sha256: SHA-256 of the model's text (hex; :func:`model_sha256`); logs and
            checkpoints carry it.
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
        ModelError: The file cannot be loaded (see :func:`load_robot`), it has no Hill
            parameters ``hill/<cable>`` in ``<custom>``, no end-effector site
            :data:`HAND_SITE` (the tracking metrics' hand position), or a cable's length at
            ``qpos0`` puts its fibre outside 0.25-2.5 optimal lengths (lengths and Hill
            parameters in different units, most likely).
    """
    model = load_robot(ARM_MODEL_PATH if path is None else path)
    if model.muscles is None:
        raise ModelError(
            f"{model.path}: an arm model needs Hill parameters 'hill/<cable>' in <custom> "
            f"for every cable ({', '.join(model.cable_names)})"
        )
    hand_site_id(model)  # the tracking runs' metrics need it: refused now, not after a run
    _check_fibre_lengths(model)
    return model


#: Normalised fibre lengths ``l_M / l_M0`` a muscle may have at the model's reference
#: posture (``qpos0``): a Hill muscle works near 1 (0.8-1.2 on msarm's arm); far outside,
#: the cable lengths and the Hill parameters are not in the same units.
_FIBRE_LENGTH_RANGE = (0.25, MAX_FIBRE_LENGTH)


def _check_fibre_lengths(model: RobotModel) -> None:
    """Refuse cable lengths that do not fit the Hill parameters (a unit mistake, say)."""
    muscles = model.muscles
    assert muscles is not None
    data = mujoco.MjData(model.mj_model)
    mujoco.mj_forward(model.mj_model, data)
    length = np.array(data.ten_length, dtype=float)
    slack = np.asarray(muscles.tendon_slack_length, dtype=float)
    optimal = np.asarray(muscles.optimal_fiber_length, dtype=float)
    low, high = _FIBRE_LENGTH_RANGE
    taut = length > slack  # a fibre exists (the Hill model refuses the others)
    # the Hill model's fibre length (HillMuscles.fiber_state), which refuses long fibres itself
    thickness = optimal * np.sin(np.asarray(muscles.pennation_at_optimal, dtype=float))
    fibre = np.hypot(length - slack, thickness) / optimal
    for i, name in enumerate(model.cable_names):
        if taut[i] and low <= fibre[i] <= high:
            continue
        said = (
            f"{fibre[i]:.3g} times its optimal length"
            if taut[i]
            else "shorter than its tendon slack length"
        )
        raise ModelError(
            f"{model.path}: cable '{name}' is {length[i]:.4g} m long at the reference posture "
            f"(qpos0): its fibre would be {said} (l_M0 {optimal[i]:.4g} m, l_Ts "
            f"{slack[i]:.4g} m); expected {low:g}-{high:g} times its optimal length. Are the "
            "model's lengths and the Hill parameters in the same unit (metres)? After moving "
            "an attachment point or a sheath waypoint, size the muscles again: python "
            "models/size_muscles.py <model.xml>"
        )


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
        from msarm.io.config import folder_instead_of_file

        folder = folder_instead_of_file(path, "an MJCF .xml model file")
        raise ModelError(folder or f"model file not found: {path} (expected an MJCF .xml file)")
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        reason = " ".join(str(exc).split())  # MuJoCo's text spans lines: one line here
        raise ModelError(f"{path}: MuJoCo cannot load the file: {reason}") from exc
    if mj_model.ntendon == 0:
        raise ModelError(
            f"{path}: the model has no tendons; msarm needs one <spatial> tendon per cable"
        )
    _check_spatial_tendons(mj_model, path)
    joint_names = _joint_names(mj_model, path)
    _check_joint_ranges(mj_model, path)
    _check_single_root(mj_model, path)
    try:
        pin_model = pinocchio.buildModelFromMJCF(str(path))
    except Exception as exc:  # the parser raises bare RuntimeErrors and ValueErrors
        raise ModelError(f"{path}: Pinocchio cannot load the file: {exc}") from exc
    pin_model.gravity.linear = model_gravity(mj_model)  # the parser ignores <option gravity>
    pin_q_index = np.arange(mj_model.nq, dtype=np.intp)
    _check_engines_agree(mj_model, pin_model, pin_q_index, path)
    check_no_passive_forces(mj_model, path)
    cable_names = tuple(mj_model.tendon(i).name for i in range(mj_model.ntendon))
    if any(not name for name in cable_names):
        raise ModelError(f"{path}: every tendon needs a name (the cable's name)")
    lower, upper = _joint_limits(mj_model)
    return RobotModel(
        path=path,
        sha256=model_sha256(path),
        mj_model=mj_model,
        pin_model=pin_model,
        joint_names=joint_names,
        cable_names=cable_names,
        joint_lower=lower,
        joint_upper=upper,
        pin_q_index=pin_q_index,
        muscles=_read_hill_parameters(mj_model, cable_names, path),
    )


def model_sha256(path: str | Path) -> str:
    r"""SHA-256 (hex) of an MJCF model's text: the file's and every file it ``<include>``s.

    Line endings are taken as ``\n`` (a Windows checkout of the same file has the same hash),
    and each included file's text is hashed after the main file's, in the order they are
    included (depth first), so that a change in an included file (a tendon's path, say)
    changes the hash. A file that includes nothing hashes as its bytes with ``\n`` endings.

    Args:
        path: The main MJCF file.

    Returns:
        The hexadecimal digest.

    Raises:
        ModelError: The file, or a file it includes, cannot be read or parsed.
    """
    import xml.etree.ElementTree as ElementTree

    digest = hashlib.sha256()
    main = Path(path)

    def add(file: Path, seen: tuple[Path, ...]) -> None:
        try:
            raw = file.read_bytes()
        except OSError as exc:
            raise ModelError(f"{main}: cannot read {file}: {exc.strerror}") from None
        digest.update(raw.replace(b"\r\n", b"\n"))
        if b"<include" not in raw:
            return
        try:
            root = ElementTree.fromstring(raw)
        except ElementTree.ParseError as exc:
            raise ModelError(f"{file}: not valid XML: {exc}") from None
        for element in root.iter("include"):
            name = element.get("file")
            if name is None:
                continue
            included = (main.parent / name).resolve()  # MuJoCo: relative to the main file
            if included in seen:
                continue
            add(included, (*seen, included))

    add(main, (main.resolve(),))
    return digest.hexdigest()


def model_gravity(mj_model: mujoco.MjModel) -> NDArray[np.float64]:
    """The gravity MuJoCo applies [m/s^2], shape ``(3,)``: zero when its flag is disabled.

    Pinocchio's MJCF parser ignores ``<option gravity>`` and ``<flag gravity="disable"/>``;
    the loaders copy this into the Pinocchio model.
    """
    if mj_model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY):
        return np.zeros(3)
    return np.array(mj_model.opt.gravity, dtype=float)


def _joint_names(mj_model: mujoco.MjModel, path: Path) -> tuple[str, ...]:
    names = []
    for j in range(mj_model.njnt):
        joint = mj_model.joint(j)
        kind = int(mj_model.jnt_type[j])
        if kind not in _SUPPORTED_JOINTS:
            free = kind == int(mujoco.mjtJoint.mjJNT_FREE)
            raise ModelError(
                f"{path}: joint '{joint.name}' is of type {mujoco.mjtJoint(kind).name}; msarm "
                f"supports {' and '.join(_SUPPORTED_JOINTS.values())} joints only in a "
                "cable-driven arm"
                + (
                    " (a cable-driven parallel robot, whose platform has a free joint, loads "
                    "with msarm.cdpr.robot_model.load_cable_robot)"
                    if free
                    else ""
                )
            )
        if not joint.name:
            raise ModelError(f"{path}: joint {j} has no name; every joint needs one")
        names.append(joint.name)
    if not names:
        raise ModelError(f"{path}: the model has no joints")
    return tuple(names)


def _check_spatial_tendons(mj_model: mujoco.MjModel, path: Path) -> None:
    """Refuse a fixed tendon (a joint coupling): a cable is a <spatial> tendon's path."""
    for i in range(mj_model.ntendon):
        start, count = int(mj_model.tendon_adr[i]), int(mj_model.tendon_num[i])
        kinds = {int(k) for k in mj_model.wrap_type[start : start + count]}
        if int(mujoco.mjtWrap.mjWRAP_JOINT) in kinds:
            name = mj_model.tendon(i).name or f"#{i}"
            raise ModelError(
                f"{path}: tendon '{name}' is a <fixed> tendon (a coupling of joints); msarm "
                "reads every tendon as a cable, a <spatial> tendon through sites (and wrap "
                "geoms). Remove it or model the cable as <spatial>"
            )


#: A limited hinge whose range is narrower than this [rad] (5 degrees) is warned about: most
#: likely a range written in radians in a model that MuJoCo reads in degrees (its default).
NARROW_HINGE_RANGE = np.deg2rad(5.0)


def _check_joint_ranges(mj_model: mujoco.MjModel, path: Path) -> None:
    """Check the limited hinges' ranges for the two unit slips of MJCF angles.

    A range wider than a turn is refused (degrees read as radians, most likely). A range
    narrower than :data:`NARROW_HINGE_RANGE` is warned about (:class:`ModelWarning`): radians
    read as degrees, most likely, as MuJoCo's ``<compiler angle>`` defaults to degrees. It
    is not refused, as a joint may be meant to barely move.
    """
    narrow = []
    for j in range(mj_model.njnt):
        if int(mj_model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE):
            continue
        if not mj_model.jnt_limited[j]:
            continue
        low, high = (float(v) for v in mj_model.jnt_range[j])
        name = mj_model.joint(j).name
        if high - low > 2 * np.pi:
            raise ModelError(
                f"{path}: hinge '{name}' has the range [{low:.4g}, "
                f"{high:.4g}] rad, wider than a turn; expected radians (a range in degrees "
                'needs <compiler angle="degree"/>, and is then converted)'
            )
        if high - low < NARROW_HINGE_RANGE:
            narrow.append(f"'{name}' [{low:.4g}, {high:.4g}]")
    if narrow:
        warnings.warn(
            f"{path}: hinge range narrower than {np.rad2deg(NARROW_HINGE_RANGE):.0f} degrees: "
            f"{', '.join(narrow)} rad; if the file gives ranges in radians, add "
            '<compiler angle="radian"/> (MuJoCo reads angles in degrees by default). '
            "Loaded as it is",
            ModelWarning,
            stacklevel=3,
        )


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
    for b in range(1, mj_model.nbody):  # a body the parser dropped, named before the mass
        name = mj_model.body(b).name
        if not pin_model.existFrame(name, pinocchio.FrameType.BODY):
            raise ModelError(
                f"{path}: body '{name}' is missing from Pinocchio's model; its MJCF parser "
                "drops bodies it cannot place (e.g. inside a <frame>, or from an <include>d "
                "file): write the body directly in the model"
            )
    mj_mass = float(mj_model.body_subtreemass[0])
    pin_mass = float(sum(inertia.mass for inertia in pin_model.inertias))
    if abs(mj_mass - pin_mass) > _ENGINE_TOLERANCE * max(1.0, mj_mass):
        raise ModelError(
            f"{path}: total mass differs between MuJoCo ({mj_mass:.6g} kg) and Pinocchio "
            f"({pin_mass:.6g} kg); Pinocchio's parser takes a body's mass from its <inertial> "
            "element only (MuJoCo infers it from the geoms otherwise): give every body one"
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
        # the body's own frame: a joint (or site) may share its name
        pin_pos = pin_data.oMf[pin_model.getFrameId(name, pinocchio.FrameType.BODY)].translation
        if np.abs(pin_pos - mj_data.xpos[b]).max() > _ENGINE_TOLERANCE:
            raise ModelError(
                f"{path}: body '{name}' is at {np.round(mj_data.xpos[b], 6)} in MuJoCo but at "
                f"{np.round(pin_pos, 6)} in Pinocchio at q={np.round(q, 4)}"
            )
    # The dynamics must agree too (an orientation or inertia the parser reads otherwise, an
    # armature it does not carry over, gravity): mass matrix and bias forces at that posture
    # with a velocity.
    v = np.linspace(-0.7, 0.7, mj_model.nv)
    mj_data.qvel[:] = v
    mujoco.mj_forward(mj_model, mj_data)
    mj_mass_matrix = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, mj_data, mj_mass_matrix)
    pin_mass_matrix = pinocchio.crba(pin_model, pin_data, q[pin_q_index])
    pin_mass_matrix = np.triu(pin_mass_matrix) + np.triu(pin_mass_matrix, 1).T
    pin_bias = pinocchio.rnea(pin_model, pin_data, q[pin_q_index], v[pin_q_index], 0 * v)
    inverse = np.argsort(pin_q_index)
    for what, mj_value, pin_value, unit in (
        ("mass matrix", mj_mass_matrix, pin_mass_matrix[np.ix_(inverse, inverse)], "kg m^2"),
        ("bias force (Coriolis and gravity)", mj_data.qfrc_bias, pin_bias[inverse], "N m"),
    ):
        gap = np.abs(mj_value - pin_value)
        if gap.max() > _DYNAMICS_TOLERANCE * max(1.0, float(np.abs(mj_value).max())):
            joint = mj_model.joint(
                int(mj_model.dof_jntid[np.unravel_index(gap.argmax(), gap.shape)[0]])
            ).name
            raise ModelError(
                f"{path}: the {what} differs between MuJoCo and Pinocchio by up to "
                f"{gap.max():.3g} {unit} (joint '{joint}') at q={np.round(q, 4)}; expected "
                "the two engines to agree. Pinocchio's MJCF parser does not read everything "
                "MuJoCo does: check the body orientations (a non-unit axisangle axis), "
                "<inertial> elements (give every body one), joint armature and "
                "<option gravity>"
            )


#: Passive forces an MJCF file may give that MuJoCo applies and the nominal model (Pinocchio's
#: dynamics, ideal cables) does not have: (what, MjModel field, element kind of its index).
_PASSIVE_FIELDS = (
    ("joint stiffness", "jnt_stiffness", "joint"),
    ("joint damping", "dof_damping", "dof"),
    ("joint frictionloss", "dof_frictionloss", "dof"),
    ("gravity compensation (gravcomp)", "body_gravcomp", "body"),
    ("tendon stiffness", "tendon_stiffness", "tendon"),
    ("tendon damping", "tendon_damping", "tendon"),
    ("tendon frictionloss", "tendon_frictionloss", "tendon"),
)


def check_no_passive_forces(
    mj_model: mujoco.MjModel,
    path: Path,
    hint: str = (
        "the plant's joint_friction and elasticity effects add friction, damping and cable "
        "stiffness"
    ),
) -> None:
    """Refuse springs, damping, friction or gravity compensation set in the model file.

    MuJoCo would apply them in the simulated plant, and the nominal model the controller and
    the diagnosis use would not have them: the "ideal" plant would no longer be the nominal
    model. The plant's effects (joint friction, cable elasticity) add such forces on purpose.

    Args:
        mj_model: The model read from ``path``.
        path: The model file (named in the error).
        hint: Where such forces belong instead (the end of the error).

    Raises:
        ModelError: One is set (named, with its value and element).
    """
    for what, attribute, kind in _PASSIVE_FIELDS:
        values = np.asarray(getattr(mj_model, attribute), dtype=float).reshape(-1)
        if not np.any(values != 0.0):
            continue
        k = int(np.flatnonzero(values != 0.0)[0])
        index = int(mj_model.dof_jntid[k]) if kind == "dof" else k
        element = {"dof": mj_model.joint, "joint": mj_model.joint, "body": mj_model.body}.get(
            kind, mj_model.tendon
        )(index)
        raise ModelError(
            f"{path}: {what} is set ({values[k]:g} on {'joint' if kind == 'dof' else kind} "
            f"'{element.name}'); the nominal model (Pinocchio's dynamics, ideal cables) has "
            "none, so the simulated plant would differ from it even with no effect switched "
            f"on: leave it out of the model file ({hint})"
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
    strays = sorted(
        key for key in numerics if key.startswith("hill/") and key not in wanted.values()
    )
    if strays:
        warnings.warn(
            f"{path}: <custom> numeric(s) {', '.join(strays)} name no cable of the model (its "
            f"cables: {', '.join(cable_names)}); they are not used (a misspelt or removed cable?)",
            ModelWarning,
            stacklevel=2,
        )
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
