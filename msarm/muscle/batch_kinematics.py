"""Cable kinematics of many postures at once: l(q), J_c(q) and the wrap angles, compiled.

The diagnosis and the compensator's target need the cable lengths, the muscle Jacobian and
the wrap angles at every logged posture: 5000 postures for a 20 s run at 250 Hz. Posture by
posture from Python (:func:`msarm.muscle.geometry.cable_kinematics` and
:func:`~msarm.muscle.geometry.wrap_angles`) that costs about 90 us a posture on the development
machine, mostly the interpreter around four MuJoCo calls and the numpy work on a few dozen
path points. :func:`cable_kinematics_batch` runs the same MuJoCo functions (``mj_kinematics``,
``mj_comPos``, ``mj_tendon``, called through their addresses, see :mod:`msarm.mujoco_c`) and
the same arithmetic in one compiled loop over the postures. Where MuJoCo's library cannot be
found it falls back to the Python functions; both give the same values (tested: lengths and
Jacobians bit for bit; wrap angles to round-off, about 1e-15 rad: the order in which
numpy's einsum sums a cosine's three products depends on the CPU features it finds). The arm
plant refreshes its wrap angles with :func:`current_wrap_angles`; the diagnosis's replay takes
its Jacobians from :class:`JacobianAt`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError
from msarm.mujoco_c import call_model_data, function_addresses
from msarm.muscle.geometry import _PULLEY, cable_kinematics, wrap_angles
from msarm.numba_cache import drop_stale_kernels

if TYPE_CHECKING:
    import mujoco

    from msarm.model import RobotData, RobotModel


drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = [
    "KINEMATICS_FUNCTIONS",
    "CableKinematics",
    "JacobianAt",
    "cable_kinematics_batch",
    "current_wrap_angles",
    "jacobian_at",
    "wrap_angles_into",
]

FloatArray = NDArray[np.float64]

#: MuJoCo's position stage as far as the tendons need it, in its order.
_FUNCTIONS = ("mj_kinematics", "mj_comPos", "mj_tendon")
KINEMATICS_FUNCTIONS = _FUNCTIONS
"""The MuJoCo functions :func:`jacobian_at` calls, by name."""


class CableKinematics:
    """Cable kinematics of ``T`` postures.

    Attributes:
        lengths: Cable lengths l(q) [m], ``(T, m)``.
        jacobian: Muscle Jacobians ``J_c = dl/dq`` [m/rad], ``(T, m, n)``.
        wrap_angles: Wrap angles Theta(q) [rad], ``(T, m)`` (NaN when not asked for).
    """

    def __init__(self, lengths: FloatArray, jacobian: FloatArray, wrap: FloatArray) -> None:
        self.lengths = lengths
        self.jacobian = jacobian
        self.wrap_angles = wrap


def cable_kinematics_batch(
    model: RobotModel, q: ArrayLike, with_wrap_angles: bool = True, compiled: bool = True
) -> CableKinematics:
    """Cable lengths, muscle Jacobians and wrap angles at every posture of ``q``.

    Args:
        model: The robot (:class:`msarm.model.RobotModel`); a work space of its own is used.
        q: Joint coordinates [rad], ``(T, n)``.
        with_wrap_angles: Also compute the wrap angles (NaN otherwise).
        compiled: Run the compiled loop where MuJoCo's library is found (False: the Python
            functions posture by posture, the reference).

    Returns:
        The kinematics of the ``T`` postures.

    Raises:
        InputError: ``q`` is not a finite ``(T, n)`` array.
    """
    q = np.asarray(q, dtype=float)
    n = model.n_joints
    if q.ndim != 2 or q.shape[1] != n:
        raise InputError(f"q must have shape (T, {n}), got {q.shape}")
    if not np.all(np.isfinite(q)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(q))[0])
        raise InputError(f"q must be finite, got {q[bad]} at index {bad}")
    m_model = model.mj_model
    m_data = model.create_data().mj
    T, m = len(q), m_model.ntendon
    lengths = np.empty((T, m))
    jacobian = np.zeros((T, m, m_model.nv))
    wrap = np.full((T, m), np.nan)
    addresses = function_addresses(*_FUNCTIONS) if compiled else None
    if addresses is None:
        for k in range(T):
            lengths[k] = cable_kinematics(m_model, m_data, q[k], jacobian[k])
            if with_wrap_angles:
                wrap[k] = wrap_angles(m_model, m_data)
        return CableKinematics(lengths, jacobian, wrap)
    _kinematics_loop(
        np.array(addresses, dtype=np.intp),
        m_model._address,
        m_data._address,
        q,
        m_data.qpos,
        m_data.ten_length,
        m_data.ten_J,
        m_model.ten_J_rownnz,
        m_model.ten_J_rowadr,
        m_model.ten_J_colind,
        m_data.wrap_xpos.reshape(-1, 3),
        m_data.wrap_obj.reshape(-1),
        m_data.ten_wrapadr,
        m_data.ten_wrapnum,
        with_wrap_angles,
        lengths,
        jacobian,
        wrap,
    )
    return CableKinematics(lengths, jacobian, wrap)


class JacobianAt:
    """The muscle Jacobian at one posture after another, compiled (a replay's inner loop).

    Args:
        model: The robot (:class:`msarm.model.RobotModel`).
        data: A work space of ``model`` (:meth:`~msarm.model.RobotModel.create_data`); its
            MuJoCo data is overwritten at every call.
    """

    def __init__(self, model: RobotModel, data: RobotData) -> None:
        m_model, m_data = model.mj_model, data.mj
        self.model = model
        self._m_model, self._m_data = m_model, m_data
        self.jacobian = np.zeros((m_model.ntendon, m_model.nv))
        addresses = function_addresses(*_FUNCTIONS)
        self._args = (
            None
            if addresses is None
            else (
                np.array(addresses, dtype=np.intp),
                m_model._address,
                m_data._address,
            )
        )
        self._views = (
            m_data.qpos,
            m_data.ten_J,
            m_model.ten_J_rownnz,
            m_model.ten_J_rowadr,
            m_model.ten_J_colind,
            self.jacobian,
        )

    def __call__(self, q: FloatArray) -> FloatArray:
        """``J_c(q)`` [m/rad], ``(m, n)``, of the posture ``q`` [rad], ``(n,)`` (a shared buffer).

        The same bits as :func:`msarm.muscle.geometry.cable_kinematics`; ``q`` is not checked.
        """
        if self._args is None:
            cable_kinematics(self._m_model, self._m_data, q, self.jacobian)
        else:
            jacobian_at(*self._args, q, *self._views)
        return self.jacobian

    def many(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """``J_c`` of several postures, the same bits as calling this object on each.

        Args:
            q: Postures [rad], ``(W, n)`` (not checked).
            out: Where to write, ``(W, m, n)``; a new array when None.

        Returns:
            The Jacobians [m/rad], ``(W, m, n)``.
        """
        if out is None:
            out = np.empty((len(q), *self.jacobian.shape))
        if self._args is None:
            for w in range(len(q)):
                out[w] = self(q[w])
        else:
            _jacobians_at(*self._args, q, *self._views, out)
        return out


@numba.njit(cache=True)
def jacobian_at(
    functions, model, data, q, qpos, ten_j, rownnz, rowadr, colind, jacobian
):  # pragma: no cover - compiled
    """Set ``qpos = q``, run :data:`KINEMATICS_FUNCTIONS`, densify the tendon Jacobian.

    Compiled, also for compiled callers: ``functions`` holds the functions' addresses
    (:func:`msarm.mujoco_c.function_addresses`), ``model`` and ``data`` the addresses of the
    ``mjModel``/``mjData`` whose ``qpos`` and ``ten_J`` the arrays view; ``J_c`` is written
    into ``jacobian`` ``(m, n)`` and the cable lengths are then in MuJoCo's ``ten_length``.
    """
    for j in range(q.shape[0]):
        qpos[j] = q[j]
    for function in functions:
        call_model_data(function, model, data)
    _dense_jacobian(ten_j, rownnz, rowadr, colind, jacobian)


@numba.njit(cache=True)
def _jacobians_at(
    functions, model, data, q, qpos, ten_j, rownnz, rowadr, colind, jacobian, out
):  # pragma: no cover - compiled
    """:func:`jacobian_at` posture after posture, each Jacobian copied into ``out[w]``."""
    for w in range(q.shape[0]):
        jacobian_at(functions, model, data, q[w], qpos, ten_j, rownnz, rowadr, colind, jacobian)
        for i in range(jacobian.shape[0]):
            for j in range(jacobian.shape[1]):
                out[w, i, j] = jacobian[i, j]


@numba.njit(cache=True)
def _dense_jacobian(ten_j, rownnz, rowadr, colind, jacobian):  # pragma: no cover - compiled
    """MuJoCo's sparse tendon Jacobian into ``jacobian`` ``(m, n)`` (``mju_sparse2dense``)."""
    for i in range(jacobian.shape[0]):
        for j in range(jacobian.shape[1]):
            jacobian[i, j] = 0.0
        start = rowadr[i]
        for p in range(rownnz[i]):
            jacobian[i, colind[start + p]] = ten_j[start + p]


def current_wrap_angles(m_model: mujoco.MjModel, m_data: mujoco.MjData) -> FloatArray:
    """Wrap angles of the path ``mj_tendon`` last computed on ``m_data`` [rad], ``(m,)``.

    The compiled form of :func:`msarm.muscle.geometry.wrap_angles` (the same values to
    round-off), for a control loop that needs them every tick.
    """
    out = np.empty(m_model.ntendon)
    wrap_angles_into(
        m_data.wrap_xpos.reshape(-1, 3),
        m_data.wrap_obj.reshape(-1),
        m_data.ten_wrapadr,
        m_data.ten_wrapnum,
        out,
    )
    return out


@numba.njit(cache=True)
def _kinematics_loop(
    functions,
    model,
    data,
    q,
    qpos,
    ten_length,
    ten_j,
    rownnz,
    rowadr,
    colind,
    wrap_xpos,
    wrap_obj,
    wrapadr,
    wrapnum,
    with_wrap,
    lengths,
    jacobian,
    wrap,
):  # pragma: no cover - compiled
    """For each posture: set ``qpos``, run the three MuJoCo functions, read the tendons."""
    for t in range(q.shape[0]):
        for j in range(q.shape[1]):
            qpos[j] = q[t, j]
        for function in functions:
            call_model_data(function, model, data)
        for i in range(lengths.shape[1]):
            lengths[t, i] = ten_length[i]
        _dense_jacobian(ten_j, rownnz, rowadr, colind, jacobian[t])
        if with_wrap:
            wrap_angles_into(wrap_xpos, wrap_obj, wrapadr, wrapnum, wrap[t])


@numba.njit(cache=True)
def wrap_angles_into(points, objects, wrapadr, wrapnum, out):  # pragma: no cover - compiled
    """:func:`msarm.muscle.geometry.wrap_angles`, one cable at a time (same arithmetic).

    Compiled, also for compiled callers: ``points`` is ``wrap_xpos`` as ``(k, 3)``,
    ``objects`` ``wrap_obj`` flat, then ``ten_wrapadr``, ``ten_wrapnum``; writes ``out``
    ``(m,)`` [rad].
    """
    for i in range(out.shape[0]):
        first, count = wrapadr[i], wrapnum[i]
        total = 0.0
        have_previous = False  # the last segment of nonzero length in this branch
        ux = uy = uz = 0.0
        for p in range(first, first + count - 1):  # the segment from point p to p + 1
            if objects[p] == _PULLEY or objects[p + 1] == _PULLEY:
                have_previous = False  # no turn is counted across a pulley
                continue
            ax = points[p + 1, 0] - points[p, 0]
            ay = points[p + 1, 1] - points[p, 1]
            az = points[p + 1, 2] - points[p, 2]
            norm = math.sqrt(ax * ax + ay * ay + az * az)
            if not norm > 1e-12:
                continue  # two sites at one point: the turn is taken across it
            vx, vy, vz = ax / norm, ay / norm, az / norm
            if have_previous:
                # summed as numpy's einsum sums three products on some x86-64 builds (x and z
                # first): bit for bit there, to round-off where it picks another order
                cosine = (ux * vx + uz * vz) + uy * vy
                total += math.acos(min(1.0, max(-1.0, cosine)))
            ux, uy, uz = vx, vy, vz
            have_previous = True
        out[i] = total
