"""The sensors' white noise in a log, and the residual energy it alone makes (the noise floor).

A plant that differs from the nominal model by sensor noise alone still has a residual, and
that residual does not spread evenly: the joint-torque residual ``T_f`` (:mod:`msarm.diagnose
.residuals`) carries the joint encoders' noise through the Savitzky-Golay accelerations and the
mass matrix, ``-M(q) S2 n_q``, and the load cells' noise through ideal cables and the parallel
filter, ``-S_F J_c(q)^T n_F``. With the arm nearly straight (the home posture, where the tasks
start with a hold) the shoulder's inertia is several times that of a flexed arm: 1e-4 rad of
encoder noise gives about 0.025 N m there against 0.005 N m at a flexed posture, so the noise
energy itself concentrates by posture. The "where" breakdown
(:func:`msarm.diagnose.where.break_down`) takes the energy the noise alone would put in each
row off before it names hot spots; this module estimates it, from the log alone.

**Noise levels.** Each sensor's white-noise standard deviation is estimated from its own
signal: the median absolute value of the signal's third differences (within each stretch of
the log without a time gap), times 1.4826 (MAD to standard deviation for a Gaussian) over
``sqrt(20)`` (a third difference of white noise has the variance ``C(6, 3) sigma^2 = 20
sigma^2``). The differences leave almost nothing of the motion: on msarm's simulated arm the
noise-free joint angles' third differences are 1e-6-2e-6 rad (robust sigma), against
encoders of 1e-4 rad, where the residual of a 25-sample cubic Savitzky-Golay fit kept
1e-5-2e-5 rad of the motion and made the estimate 3-11 % high; the third differences gave
the configured 1e-4 rad within 1-3 % on 22 noise-only logs. The median keeps the estimate
from the rare steps and spikes of a real signal. For the load cells the same estimate of the
tension itself counts the tension's real fast part (the controller's answer to the encoders'
noise, up to 0.7 N on msarm's arm against 0.3 N of load-cell noise), so where the log has the
commanded tensions the smaller of that and the estimate from the drive residual ``F - F_cmd``
(the nominal drive renders each command: on a plant without drive effects it is the load
cells' noise) is taken; a drive effect or a fast real tension can only make the estimate
larger, and the floor with it (fewer hot spots, never more).

**Propagation** (:func:`joint_torque_noise`). For white noise of ``sigma_q`` per joint and
``sigma_F`` per cable, independent, the expected square of joint ``j``'s residual at sample
``i`` is

``E[T_f,ij^2] = g_q[i] sum_k M_jk(q_i)^2 sigma_q,k^2 + g_F[i] sum_c J_c,cj(q_i)^2 sigma_F,c^2``

with ``g_q[i] = sum_k S2[i, k]^2`` [1/s^4] the noise gain of the Savitzky-Golay second
derivative at sample ``i`` (``sum d^2 / dt^4``, ``d`` the filter's coefficients, in the
interior; larger over the half window at each end of a stretch, where the filter fits the
window's edge: 34 times at the first sample for 25 samples, cubic) and ``g_F[i]`` the gain of
the delivered torque's parallel filter (:func:`msarm.compensation.target.delivered_torque`:
0.057 in the interior at 25 samples, cubic; 1 without smoothing), both taken from the filters
themselves (their response to unit impulses). Left out, because they are far smaller: the
noise of the filtered velocities through the Coriolis terms (1.7e-3 rad/s of velocity noise
at 1e-4 rad) and of the smoothed angles through gravity and the cable Jacobians (3e-5 rad),
and the change of ``M`` and ``J_c`` over a filter window (0.1 s): against the full covariance
of 130 samples in motion (whole filter matrices, MuJoCo's mass matrix, the Jacobian at each
input sample) the expected energies agree within 0.05 %. The load cells' part is about a
third of the floor on msarm's arm (0.3 N of noise; 1e-4 rad on the encoders). The same
covariance gives the variance of a noise energy summed over samples (:class:`NoiseFloor`), so
that a row's energy can be judged against the scatter of its noise energy.

Checked on 22 noise-only logs of msarm's arm (four 20 s random tasks and the benchmark's 18
null-plant runs of 10 s): the measured residual energy was 0.93 times the expected one (0.78-
1.13 per log; 0.95 with the sensors' true noise levels from the sidecars), and 0.95 on
average over the posture cells and motion phases of 100 samples or more (10th-90th
percentile 0.75-1.15). With the noise drawn again, 40 times, on the noise-free signals of one
20 s log, the energy came out at 1.01-1.02 times the expected one per joint and 0.94-1.10
per phase and posture cell, with a scatter 0.6-1.6 times the standard deviation expected.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from math import comb

import numpy as np
import pinocchio
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from msarm.compensation.target import TargetSpec, delivered_torque
from msarm.diagnose.residuals import Residuals, gap_starts
from msarm.errors import InputError
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import cable_kinematics_batch

__all__ = [
    "DIFFERENCE_ORDER",
    "NOISE_FLOOR_KINDS",
    "FilterGains",
    "NoiseFloor",
    "SensorNoise",
    "filter_noise_gains",
    "joint_torque_noise",
    "sensor_noise",
    "stretches",
    "white_noise_std",
]

FloatArray = NDArray[np.float64]

#: Order of the differences the white-noise level is estimated from.
DIFFERENCE_ORDER = 3
#: Residual kinds that get a noise floor. ``drive`` (``F - F_cmd``) carries the load cells'
#: noise as it is, white and with one level per cable at every sample: it cannot make a phase
#: or posture denser than another, and an estimate from the residual's fast part would count
#: a fast drive effect (a command delay's ``F_k - F_k-1``) as noise. ``cable_length``: the
#: encoders' white noise makes about 1 µm (``r sigma_theta`` = 0.3 µm, ``J_c sigma_q`` about
#: 1 µm) of a residual the diagnosis resolves from 50 µm; what the noise-only plants show
#: there (about 30 µm, in motion) follows the cable velocity and is no white noise.
NOISE_FLOOR_KINDS = ("joint_torque",)
#: MAD of a Gaussian to its standard deviation.
_MAD_TO_STD = 1.4826


def stretches(residuals: Residuals) -> list[tuple[int, int]]:
    """The stretches ``[start, stop)`` of valid samples without a time gap, in order.

    Each is one segment the residuals were filtered over (:func:`~msarm.diagnose.residuals
    .residuals_from_log` filters each stretch between time gaps alone, and marks stretches
    too short for the filter invalid).
    """
    valid = np.asarray(residuals.valid, dtype=bool)
    cuts = np.zeros(len(valid) + 1, dtype=bool)
    cuts[gap_starts(residuals.t, residuals.sample_rate_hz)] = True
    out = []
    start = None
    for k in range(len(valid) + 1):
        inside = k < len(valid) and bool(valid[k])
        if start is not None and (not inside or cuts[k]):
            out.append((start, k))
            start = None
        if inside and start is None:
            start = k
    return out


def white_noise_std(
    x: FloatArray, parts: list[tuple[int, int]] | None = None, order: int = DIFFERENCE_ORDER
) -> FloatArray:
    """Standard deviation of the white noise on each column of a sampled signal.

    ``1.4826 * median(|diff(x, order)|) / sqrt(C(2 order, order))``, the differences taken
    within each part and pooled: robust (a median) and nearly blind to a smooth signal.

    Args:
        x: The signal, ``(T, k)`` (any unit).
        parts: Stretches ``[start, stop)`` to difference separately (time gaps between them);
            default the whole signal. Parts with ``order`` samples or fewer are left out.
        order: Order of the differences, >= 1.

    Returns:
        The noise standard deviation of each column, ``(k,)``, in ``x``'s unit; NaN for a
        column without a difference (too few samples).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        raise InputError(f"x must have shape (T, k), got {x.shape}")
    if order < 1:
        raise InputError(f"order must be >= 1, got {order}")
    parts = [(0, len(x))] if parts is None else parts
    pieces = [np.diff(x[a:b], order, axis=0) for a, b in parts if b - a > order]
    if not pieces:
        return np.full(x.shape[1], np.nan)
    differences = np.concatenate(pieces)
    return _MAD_TO_STD * np.median(np.abs(differences), axis=0) / np.sqrt(comb(2 * order, order))


@dataclass(frozen=True)
class FilterGains:
    """How the joint-torque residual's two filters pass white noise, sample by sample.

    For white noise of unit variance on a filter's input, ``K = S S^T`` is the covariance of
    its output (``S`` the filter's matrix: each row its response to unit impulses); the
    acceleration filter is the Savitzky-Golay second derivative, ``S2`` (joint angles [rad] to
    accelerations [rad/s^2]), the tension filter the delivered torque's
    (:func:`~msarm.compensation.target.delivered_torque`, torque to torque). Every array is
    ``(length,)``, one value per sample of the stretch, edges included.

    Attributes:
        acceleration: ``K2[i, i]``, the variance gain [1/s^4].
        tension: ``KF[i, i]`` [-].
        acceleration_pairs: ``sum_k K2[i, k]^2`` [1/s^8] (for the variance of an energy sum).
        cross_pairs: ``sum_k K2[i, k] KF[i, k]`` [1/s^4].
        tension_pairs: ``sum_k KF[i, k]^2`` [-].
    """

    acceleration: FloatArray
    tension: FloatArray
    acceleration_pairs: FloatArray
    cross_pairs: FloatArray
    tension_pairs: FloatArray


def filter_noise_gains(length: int, target: TargetSpec, dt: float) -> FilterGains:
    """The noise gains of the joint-torque residual's two filters at each sample of a stretch.

    Taken from the filters themselves (their responses to unit impulses): in the interior
    ``sum d^2 / dt^4`` for the Savitzky-Golay second derivative (``d`` its coefficients), and
    larger over the half window at each end, where the filter fits the window's edge.

    Args:
        length: Samples in the stretch, >= ``target.window``.
        target: The filter (:class:`~msarm.compensation.target.TargetSpec`).
        dt: Sample period [s].

    Returns:
        The gains of each sample (:class:`FilterGains`).
    """
    if length < target.window:
        raise InputError(f"length must be >= the filter's {target.window} samples, got {length}")
    # the filters are shift-invariant away from the edges: a stretch of four windows and a
    # sample holds two whole windows at each end unaffected by the other, and the interior
    window = target.window
    size = min(length, 4 * window + 1)
    values = list(_gains(size, target, float(dt)))
    if size < length:
        edge = 2 * window
        stretched = []
        for value in values:
            full = np.full(length, value[size // 2])
            full[:edge] = value[:edge]
            full[length - edge :] = value[size - edge :]
            stretched.append(full)
        values = stretched
    return FilterGains(*values)


@lru_cache(maxsize=64)
def _gains(size: int, target: TargetSpec, dt: float) -> tuple[FloatArray, ...]:
    """:class:`FilterGains`' arrays for a stretch of ``size`` samples (read-only)."""
    second = savgol_filter(np.eye(size), target.window, target.polyorder, deriv=2, delta=dt, axis=0)
    jacobians = np.zeros((size, 1, size))
    jacobians[np.arange(size), 0, np.arange(size)] = -1.0  # delivered torque = unit impulses
    smoothed = delivered_torque(jacobians, np.ones((size, 1)), target, dt)
    k2, kf = second @ second.T, smoothed @ smoothed.T
    values = (
        np.diag(k2).copy(),
        np.diag(kf).copy(),
        np.sum(k2**2, axis=1),
        np.sum(k2 * kf, axis=1),
        np.sum(kf**2, axis=1),
    )
    for value in values:
        value.setflags(write=False)
    return values


@dataclass(frozen=True)
class SensorNoise:
    """White-noise levels of a log's sensors, estimated from the log.

    Attributes:
        joint: Joint encoders' noise std per joint [rad], ``(n,)``.
        tension: Load cells' noise std per cable [N], ``(m,)``.
        samples: Valid samples the estimate is from.
    """

    joint: FloatArray
    tension: FloatArray
    samples: int


def sensor_noise(residuals: Residuals) -> SensorNoise:
    """The joint encoders' and load cells' white-noise levels of one log.

    :func:`white_noise_std` of the logged joint angles, and the smaller of that of the logged
    tensions and that of the drive residual ``F - F_cmd`` (when the log has commands), over
    the valid samples, stretch by stretch (see the module docstring).
    """
    parts = stretches(residuals)
    joint = white_noise_std(residuals.q, parts)
    tension = white_noise_std(residuals.tension, parts)
    if residuals.drive is not None:
        tension = np.fmin(tension, white_noise_std(residuals.drive, parts))
    return SensorNoise(joint=joint, tension=tension, samples=int(sum(b - a for a, b in parts)))


@dataclass(frozen=True)
class NoiseFloor:
    """What the sensors' white noise alone is expected to make of one log's residual.

    Attributes:
        energy: Expected square of the residual, per sample and channel [unit^2], ``(T, k)``;
            NaN at invalid samples.
        variance: Each sample's share of the variance of a noise energy summed over samples
            and channels [unit^4], ``(T,)`` (``2 sum_k sum_jl C[i j, k l]^2``, ``C`` the noise's
            covariance between samples ``i``, ``k`` and channels ``j``, ``l``): the variance of
            a row's noise energy is at most the sum over its samples (exactly that for a row
            of whole stretches; less for one of scattered samples, whose neighbours are not in
            it); NaN at invalid samples.
        channel_variance: The same for each channel's energy alone [unit^4], ``(T, k)``.
        edge: Whether each sample lies within the filter's half window of an end of its
            stretch, ``(T,)`` (False at invalid samples): there the filters fit the window's
            edge, and the noise alone makes a residual up to 34 times larger (first sample,
            25 samples, cubic), which a handful of noise values decide.
    """

    energy: FloatArray
    variance: FloatArray
    channel_variance: FloatArray
    edge: NDArray[np.bool_]


def joint_torque_noise(
    model: RobotModel, residuals: Residuals, noise: SensorNoise | None = None
) -> NoiseFloor:
    """The joint-torque residual that the sensors' white noise alone makes, expected.

    ``E[T_f,ij^2] = g_q[i] sum_k M_jk(q_i)^2 sigma_q,k^2 + g_F[i] sum_c J_c,cj(q_i)^2
    sigma_F,c^2`` at each sample ``i`` and joint ``j`` (the module docstring says what is left
    out), with the filter the residuals were made with (``residuals.target``; the default
    :class:`~msarm.compensation.target.TargetSpec` when it is None). The noise's covariance
    between samples ``i`` and ``k`` is ``A K2[i, k] + B KF[i, k]`` with ``A = M Sigma_q M``
    and ``B = J_c^T Sigma_F J_c`` (taken at sample ``i``: they change little over a window), so
    each sample's share of the variance of an energy sum is
    ``2 (|A|^2 sum_k K2^2 + 2 tr(A B) sum_k K2 KF + |B|^2 sum_k KF^2)``
    (:class:`FilterGains`; ``|.|`` the Frobenius norm).

    Args:
        model: The nominal robot model (same joints and cables as the log).
        residuals: One log's residuals.
        noise: The noise levels; default :func:`sensor_noise` of ``residuals``.

    Returns:
        The expected noise energy [N^2 m^2] and its variance [N^4 m^4]
        (:class:`NoiseFloor`).

    Raises:
        InputError: The model's joints or cables are not the log's.
    """
    if tuple(model.joint_names) != tuple(residuals.joint_names) or tuple(
        model.cable_names
    ) != tuple(residuals.cable_names):
        raise InputError(
            f"{residuals.source}: the model's joints and cables ({', '.join(model.joint_names)};"
            f" {', '.join(model.cable_names)}) are not the log's"
        )
    noise = noise or sensor_noise(residuals)
    target = residuals.target or TargetSpec()
    dt = 1.0 / residuals.sample_rate_hz
    energy = np.full(residuals.joint_torque.shape, np.nan)
    variance = np.full(len(residuals.joint_torque), np.nan)
    channel_variance = np.full(residuals.joint_torque.shape, np.nan)
    edge = np.zeros(len(residuals.joint_torque), dtype=bool)
    half = target.window // 2
    data = model.create_data()
    index = np.asarray(model.pin_q_index)
    inverse = np.argsort(index)
    joint_var = np.nan_to_num(noise.joint) ** 2
    tension_var = np.nan_to_num(noise.tension) ** 2
    for start, stop in stretches(residuals):
        q = np.asarray(residuals.q[start:stop], dtype=float)
        gains = filter_noise_gains(stop - start, target, dt)
        edge[start : start + half] = True
        edge[stop - half : stop] = True
        upper = np.array([pinocchio.crba(model.pin_model, data.pin, p) for p in q[:, index]])
        upper = np.triu(upper)  # crba fills the upper triangle
        inertia = (upper + np.triu(upper, 1).transpose(0, 2, 1))[:, inverse][:, :, inverse]
        jacobian = cable_kinematics_batch(model, q, with_wrap_angles=False).jacobian
        # covariances of the two parts at lag 0 before filtering: (T, n, n)
        a = np.einsum("tjk,k,tlk->tjl", inertia, joint_var, inertia)
        b = np.einsum("tcj,c,tcl->tjl", jacobian, tension_var, jacobian)
        diag_a = np.einsum("tjj->tj", a)
        diag_b = np.einsum("tjj->tj", b)
        energy[start:stop] = gains.acceleration[:, None] * diag_a + gains.tension[:, None] * diag_b
        variance[start:stop] = 2.0 * (
            gains.acceleration_pairs * np.einsum("tjl,tjl->t", a, a)
            + 2.0 * gains.cross_pairs * np.einsum("tjl,tjl->t", a, b)
            + gains.tension_pairs * np.einsum("tjl,tjl->t", b, b)
        )
        channel_variance[start:stop] = 2.0 * (
            gains.acceleration_pairs[:, None] * diag_a**2
            + 2.0 * gains.cross_pairs[:, None] * diag_a * diag_b
            + gains.tension_pairs[:, None] * diag_b**2
        )
    return NoiseFloor(
        energy=energy, variance=variance, channel_variance=channel_variance, edge=edge
    )
