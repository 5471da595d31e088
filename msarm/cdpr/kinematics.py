"""Geometry of a cable-driven parallel robot (CDPR): inverse kinematics and structure matrix.

Notation of paper 000, Sec. 2.1. The frame coordinate system K_0 is fixed, the platform
pose is its position ``r`` [m] and rotation matrix ``R`` (K_p in K_0). Cable ``i`` leaves the
frame at ``a_i`` (in K_0) and is attached to the platform at ``b_i`` (in K_p). With massless
straight cables (eq. 1)::

    d_i = a_i - r - R b_i,   l_i = ||d_i||,   u_i = d_i / l_i

so ``u_i`` is the unit vector from the platform anchor towards the frame anchor. A cable
tension ``f_i >= 0`` pulls the platform along ``u_i``; with the external wrench ``w``
(force [N], moment about the platform origin [N m], both in K_0) acting on the platform,
equilibrium reads (eq. 2)::

    A^T f + w = 0,   A^T = [[u_1, ..., u_m], [R b_1 x u_1, ..., R b_m x u_m]]   (6 x m)

Every function accepts one pose (``r`` of shape (3,), ``R`` of shape (3, 3)) or a batch of
``N`` poses (``r`` of shape (N, 3), ``R`` of shape (3, 3) shared or (N, 3, 3)); results then
carry a leading axis of length ``N``.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = ["CableKinematics", "CableRobot"]


@dataclass(frozen=True)
class CableKinematics:
    """Inverse kinematics of one pose, or of a batch of poses.

    Attributes:
        lengths: Cable lengths l_i [m], shape (m,) or (N, m).
        unit_vectors: Unit vectors u_i from platform anchor to frame anchor [-],
            shape (m, 3) or (N, m, 3).
        platform_anchors_world: Platform anchors rotated into K_0, R b_i [m],
            shape (m, 3) or (N, m, 3) (the lever arms of the cable forces about r).
    """

    lengths: FloatArray
    unit_vectors: FloatArray
    platform_anchors_world: FloatArray


_KINDS = {"b": "booleans", "c": "complex numbers", "U": "strings", "S": "bytes", "O": "objects"}


def _anchor_array(value: ArrayLike, name: str) -> FloatArray:
    """A read-only float copy of anchors; raise InputError unless (m, 3) real finite numbers."""
    expected = f"{name} must be an array of shape (m, 3) of real numbers [m]"
    try:
        raw = np.asarray(value)
    except ValueError:  # numpy refuses ragged nested sequences
        raise InputError(
            f"{expected}, got rows of different lengths: {reprlib.repr(value)}"
        ) from None
    if raw.dtype.kind not in "iuf":
        kind = _KINDS.get(raw.dtype.kind, f"{raw.dtype} values")
        raise InputError(f"{expected}, got {kind} of shape {raw.shape}")
    array = np.array(raw, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] < 1:
        raise InputError(f"{name} must have shape (m, 3) [m], got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise InputError(f"{name} must be finite, got {array}")
    array.setflags(write=False)
    return array


def _one_pose_ok(r: FloatArray, R: FloatArray) -> bool:
    """Whether one pose surely passes :meth:`CableRobot._pose`'s checks (scalar arithmetic).

    Conservative: True only if ``r`` and ``R`` are finite, ``|R R^T - I|`` is below half of
    ``_pose``'s 1e-6 (round-off between this sum and its matrix product cannot cross the
    limit) and ``det R > 0`` (R is then within 1e-6 of a rotation, whose det is +1). A pose
    this rejects goes through ``_pose``'s own checks, which raise their errors or let it pass.

    Args:
        r: Platform position [m], shape (3,).
        R: Rotation matrix [-], shape (3, 3).

    Returns:
        Whether the pose is finite and R a rotation matrix.
    """
    x, y, z = r.tolist()
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    if not all(map(math.isfinite, (x, y, z, a, b, c, d, e, f, g, h, i))):
        return False
    orth = max(
        abs(a * a + b * b + c * c - 1.0),
        abs(d * d + e * e + f * f - 1.0),
        abs(g * g + h * h + i * i - 1.0),
        abs(a * d + b * e + c * f),
        abs(a * g + b * h + c * i),
        abs(d * g + e * h + f * i),
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return orth < 5e-7 and det > 0.0


class CableRobot:
    """A CDPR with ``m`` straight massless cables and a 6-DOF platform.

    Args:
        frame_anchors: a_i, the cable exit points on the frame in K_0 [m], shape (m, 3).
        platform_anchors: b_i, the cable attachment points on the platform in K_p [m],
            shape (m, 3), in the same cable order.

    Raises:
        InputError: If the anchors have the wrong shape (ragged rows included), differ in
            count, are not finite or not real numbers (complex, boolean, strings).

    Example:
        A 2 m cube of frame anchors and a 0.2 m cube of platform anchors turned 90 degrees
        about z (a scaled copy of the frame, such as ``0.1 * corners``, would make all
        cables meet in one point at every pose: A^T of rank 3, the rotation not held):

        >>> corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 2)])
        >>> plate = 0.1 * np.column_stack([-corners[:, 1], corners[:, 0], corners[:, 2] - 1])
        >>> robot = CableRobot(corners, plate)  # frame and platform anchors [m]
        >>> At = robot.structure_matrix(np.array([0.0, 0.0, 1.0]), np.eye(3))  # A^T, (6, m)
        >>> At.shape, int(np.linalg.matrix_rank(At))
        ((6, 8), 6)
    """

    def __init__(self, frame_anchors: ArrayLike, platform_anchors: ArrayLike) -> None:
        self._a = _anchor_array(frame_anchors, "frame_anchors")
        self._b = _anchor_array(platform_anchors, "platform_anchors")
        if self._a.shape != self._b.shape:
            raise InputError(
                f"frame_anchors {self._a.shape} and platform_anchors {self._b.shape} must "
                "have the same shape (m, 3), one row per cable"
            )

    @property
    def n_cables(self) -> int:
        """Number of cables m."""
        return self._a.shape[0]

    @property
    def n_dof(self) -> int:
        """Degrees of freedom of the platform (6)."""
        return 6

    @property
    def frame_anchors(self) -> FloatArray:
        """a_i in K_0 [m], shape (m, 3), read-only."""
        return self._a

    @property
    def platform_anchors(self) -> FloatArray:
        """b_i in K_p [m], shape (m, 3), read-only."""
        return self._b

    def __repr__(self) -> str:
        return f"CableRobot(n_cables={self.n_cables})"

    def _pose(self, r: ArrayLike, R: ArrayLike) -> tuple[FloatArray, FloatArray, bool]:
        """Validate a pose or a batch of poses; return (r (N,3), R (N,3,3), batched)."""
        r_arr = np.asarray(r, dtype=np.float64)
        R_arr = np.asarray(R, dtype=np.float64)
        if r_arr.shape == (3,) and R_arr.shape == (3, 3) and _one_pose_ok(r_arr, R_arr):
            # one valid pose (the per-tick case): the checks below would all pass
            return r_arr[None, :], R_arr[None, :, :], False
        if r_arr.ndim == 1 and r_arr.shape == (3,):
            batched = False
            r_arr = r_arr[None, :]
        elif r_arr.ndim == 2 and r_arr.shape[1] == 3:
            batched = True
        else:
            raise InputError(f"r must have shape (3,) or (N, 3) [m], got {r_arr.shape}")
        n_poses = r_arr.shape[0]
        if R_arr.shape == (3, 3):
            R_arr = np.broadcast_to(R_arr, (n_poses, 3, 3))
        elif not (batched and R_arr.shape == (n_poses, 3, 3)):
            expected = "(3, 3)" if not batched else f"(3, 3) or ({n_poses}, 3, 3)"
            raise InputError(f"R must have shape {expected}, got {R_arr.shape}")
        if not np.all(np.isfinite(r_arr)):
            raise InputError("r must be finite")
        if not np.all(np.isfinite(R_arr)):
            raise InputError("R must be finite")
        orth = np.abs(R_arr @ R_arr.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0)
        if orth > 1e-6 or np.any(np.linalg.det(R_arr) < 0.0):
            raise InputError(
                f"R must be a rotation matrix (orthonormal, det +1); |R R^T - I| = {orth:.3g}"
            )
        return r_arr, R_arr, batched

    def inverse_kinematics(self, r: ArrayLike, R: ArrayLike) -> CableKinematics:
        """Cable lengths and directions at a pose (paper 000, eq. 1).

        Args:
            r: Platform position in K_0 [m], shape (3,) or (N, 3).
            R: Platform rotation matrix, shape (3, 3) or (N, 3, 3).

        Returns:
            The lengths l_i [m], unit vectors u_i and rotated anchors R b_i; with a leading
            axis N for a batch of poses.

        Raises:
            InputError: On wrong shapes, non-finite values, a non-rotation ``R``, or a
                cable of zero length (platform anchor on its frame anchor).
        """
        r_arr, R_arr, batched = self._pose(r, R)
        rb = np.einsum("nij,mj->nmi", R_arr, self._b)  # R b_i, (N, m, 3)
        d = self._a[None, :, :] - r_arr[:, None, :] - rb
        lengths = np.sqrt(np.add.reduce(d * d, axis=2))  # np.linalg.norm's own expression
        if (lengths <= 0.0).any():
            pose, cable = np.argwhere(lengths <= 0.0)[0]
            raise InputError(f"cable {cable} has zero length at pose {pose}: u is undefined")
        u = d / lengths[:, :, None]
        if not batched:
            return CableKinematics(lengths[0], u[0], rb[0])
        return CableKinematics(lengths, u, rb)

    def cable_lengths(self, r: ArrayLike, R: ArrayLike) -> FloatArray:
        """Cable lengths l_i = ||a_i - r - R b_i|| [m], shape (m,) or (N, m).

        Args:
            r: Platform position in K_0 [m], shape (3,) or (N, 3).
            R: Platform rotation matrix [-], shape (3, 3) or (N, 3, 3).

        Returns:
            The lengths [m], shape (m,) for one pose or (N, m) for a batch.

        Raises:
            InputError: On wrong shapes, non-finite values, a non-rotation ``R``, or a
                cable of zero length.
        """
        return self.inverse_kinematics(r, R).lengths

    def structure_matrix(self, r: ArrayLike, R: ArrayLike) -> FloatArray:
        """Structure matrix A^T of paper 000, eq. 2: columns [u_i; (R b_i) x u_i].

        Equilibrium of the platform under cable tensions f [N] and external wrench w is
        ``A^T f + w = 0``; so for the allocation core ``M = A^T`` and ``b = -w``.

        Args:
            r: Platform position in K_0 [m], shape (3,) or (N, 3).
            R: Platform rotation matrix, shape (3, 3) or (N, 3, 3).

        Returns:
            A^T, shape (6, m) or (N, 6, m): rows 0-2 unitless (force per unit tension),
            rows 3-5 in m (moment about r per unit tension).
        """
        kin = self.inverse_kinematics(r, R)
        u = kin.unit_vectors
        moment = np.cross(kin.platform_anchors_world, u)
        return np.concatenate([u, moment], axis=-1).swapaxes(-1, -2).copy()
