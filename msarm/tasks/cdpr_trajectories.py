"""Reference trajectories of the CDPR experiments of paper 000 (Fig. 9), for a ~1 m robot.

Paper 000 runs five paths with its IPAnema 3 Mini (Sec. 4, Fig. 9, Table 3): a triangle and a
circle in the part of the workspace where the cable pair 1, 2 is force-controlled (the region
of Fig. 7a, sensitivity sigma_12 < 1.5 N), the same two in the region of pair 3, 4 (Fig. 7b),
and a rectangle that crosses the plane y = 0 so that the force-controlled pair must switch.
All are purely translational (R = I) and "the end-effector reaches a velocity of 4 m/min
after the first acceleration from a static position". The paper does not print the paths'
dimensions (only the plot of Fig. 9), so msarm chooses them for its own mini robot
(``models/ipanema_mini.xml``: frame 1.68 m x 1.20 m x 0.38 m, workspace box x -0.45..0.40,
y -0.25..0.30, z 0.05..0.18 m). msarm numbers cables from 0: the paper's pair 1, 2 is
``(0, 1)`` (the upper cables whose frame anchors lie at y > 0), its pair 3, 4 is ``(2, 3)``
(upper cables at y < 0).

Dimensions (all paths horizontal, at the workspace box's mid height z = 0.115 m, centred on
x = -0.025 m, the home position's x):

=====================  =============================================================  ========
name                   path [m]                                                       length
=====================  =============================================================  ========
``triangle-12``        vertices (-0.175, 0.05), (0.125, 0.05), (-0.025, 0.22)          0.656 m
``circle-12``          centre (-0.025, 0.13), radius 0.08                              0.503 m
``triangle-34``        ``triangle-12`` mirrored at y = 0                               0.656 m
``circle-34``          ``circle-12`` mirrored at y = 0                                 0.503 m
``rectangle-switch``   x -0.175..0.125, y -0.12..0.12 (crosses y = 0 twice)            1.046 m
=====================  =============================================================  ========

(lengths with the rounded corners). Why these sizes: paths of a few decimetres, like the
paper's on its mini robot, that stay inside the region where the named pair has
sigma < 1.5 N (computed with ``msarm.cdpr.sensitivity`` for this robot: at z = 0.115 m pair
(0, 1) is below 1.5 N for y >= -0.05 m over |x| <~ 0.25 m, pair (2, 3) for y <= 0.10 m) and
where the minimum-2-norm force distribution with the paper's 8-35 N bounds exists along the
whole motion (weight and inertia of the 0.25 kg platform).

Corners: a polygon's corners are rounded by circular arcs of radius 0.02 m so the platform
passes them at constant speed with a finite acceleration (v^2 / rho = 0.22 m/s^2 at 4 m/min);
a sharp corner at constant speed would need an infinite acceleration. Closed paths start and
end at the midpoint of their first edge (polygons) or at the lowest-y point (circles; the
highest for the mirrored ones) and run counter-clockwise seen from +z (clockwise for the
mirrored ``-34`` paths, the mirror image of the ``-12`` ones).

Timing: the platform holds still for ``hold`` (0.5 s) at the start point, accelerates along
the path, moves at ``speed`` = 4 m/min (1/15 m/s) and stops back at the start point, then
holds for ``hold`` again. The speed ramps (start and stop) last ``ramp_time`` (0.5 s) and
follow the quintic smoothstep ``v(t) = V (10 s^3 - 15 s^4 + 6 s^5)``, ``s = t / ramp_time``
(the minimum-jerk shape as a velocity profile): the acceleration along the path is continuous
and zero at both ends of a ramp (peak 1.875 V / ramp_time = 0.25 m/s^2), a ramp covers
``V ramp_time / 2``, and the motion lasts ``length / V + ramp_time``. Samples at 1 kHz.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "CDPR_TRAJECTORIES",
    "CENTER_X",
    "CORNER_RADIUS",
    "HOLD_TIME",
    "PATH_Z",
    "RAMP_TIME",
    "SAMPLE_TIME",
    "SPEED",
    "CdprTrajectory",
    "PathSegment",
    "circle_path",
    "get_cdpr_trajectory",
    "list_cdpr_trajectories",
    "polygon_path",
    "sample_path",
]

SPEED = 4.0 / 60.0
"""Cruise speed of the platform, 4 m/min [m/s] (paper 000, Sec. 4)."""
RAMP_TIME = 0.5
"""Duration of the start and stop speed ramps [s]."""
HOLD_TIME = 0.5
"""Rest at the start point before and after the motion [s]."""
SAMPLE_TIME = 1e-3
"""Sample time of the references [s] (1 kHz, the controllers' cycle)."""
PATH_Z = 0.115
"""Height of all paths [m]: mid height of the model's workspace box (0.05..0.18 m)."""
CENTER_X = -0.025
"""x of the paths' centres [m]: the home position's x."""
CORNER_RADIUS = 0.02
"""Radius of the arcs that round a polygon's corners [m]."""

_TRIANGLE_12 = ((CENTER_X - 0.15, 0.05), (CENTER_X + 0.15, 0.05), (CENTER_X, 0.22))
_CIRCLE_12 = ((CENTER_X, 0.13), 0.08)
_RECTANGLE = (
    (CENTER_X - 0.15, -0.12),
    (CENTER_X + 0.15, -0.12),
    (CENTER_X + 0.15, 0.12),
    (CENTER_X - 0.15, 0.12),
)


@dataclass(frozen=True)
class PathSegment:
    """One piece of a planar path at constant height: a straight line or a circular arc.

    A line goes from ``start`` to ``end``. An arc has ``center`` and ``radius`` and runs from
    the angle ``angle0`` over ``sweep`` (counter-clockwise when positive, seen from +z).

    Attributes:
        kind: ``"line"`` or ``"arc"``.
        length: Arc length of the segment [m], > 0.
        start: Line start (x, y) [m], shape (2,) (arcs: their start point).
        end: Line end (x, y) [m], shape (2,) (arcs: their end point).
        center: Arc centre (x, y) [m], shape (2,) (lines: zeros).
        radius: Arc radius [m] (lines: 0).
        angle0: Arc start angle [rad] (lines: 0).
        sweep: Signed arc angle [rad] (lines: 0).
    """

    kind: str
    length: float
    start: FloatArray
    end: FloatArray
    center: FloatArray
    radius: float = 0.0
    angle0: float = 0.0
    sweep: float = 0.0

    @classmethod
    def line(cls, start: ArrayLike, end: ArrayLike) -> PathSegment:
        """A straight segment from ``start`` to ``end`` (x, y) [m]."""
        p0 = np.asarray(start, dtype=np.float64)
        p1 = np.asarray(end, dtype=np.float64)
        length = float(np.linalg.norm(p1 - p0))
        if not length > 0.0:
            raise InputError(f"a path line needs two distinct points, got {p0} and {p1}")
        return cls("line", length, p0, p1, np.zeros(2))

    @classmethod
    def arc(cls, center: ArrayLike, radius: float, angle0: float, sweep: float) -> PathSegment:
        """A circular arc (centre (x, y) [m], radius [m], start angle and sweep [rad])."""
        c = np.asarray(center, dtype=np.float64)
        if not (radius > 0.0 and sweep != 0.0 and math.isfinite(radius * sweep)):
            raise InputError(f"a path arc needs radius > 0 and sweep != 0, got {radius}, {sweep}")
        p0 = c + radius * np.array([math.cos(angle0), math.sin(angle0)])
        a1 = angle0 + sweep
        p1 = c + radius * np.array([math.cos(a1), math.sin(a1)])
        return cls("arc", abs(sweep) * radius, p0, p1, c, float(radius), angle0, sweep)

    def evaluate(self, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Point, unit tangent and curvature vector at arc lengths ``s`` from the start.

        Args:
            s: Arc length within the segment [m], shape (k,), in [0, length].

        Returns:
            ``(point [m], tangent [-], curvature [1/m])``, each of shape (k, 2); the
            curvature vector points to the centre of curvature with magnitude 1 / radius
            (zero on a line).
        """
        if self.kind == "line":
            direction = (self.end - self.start) / self.length
            point = self.start + s[:, None] * direction
            tangent = np.broadcast_to(direction, point.shape).copy()
            return point, tangent, np.zeros_like(point)
        sign = 1.0 if self.sweep > 0.0 else -1.0
        angle = self.angle0 + sign * s / self.radius
        radial = np.stack([np.cos(angle), np.sin(angle)], axis=1)
        point = self.center + self.radius * radial
        tangent = sign * np.stack([-np.sin(angle), np.cos(angle)], axis=1)
        return point, tangent, -radial / self.radius


def polygon_path(vertices: ArrayLike, corner_radius: float = CORNER_RADIUS) -> list[PathSegment]:
    """A closed polygon with corners rounded by arcs, from the midpoint of its first edge.

    Args:
        vertices: Corners (x, y) [m] in the order of travel, shape (k, 2), k >= 3.
        corner_radius: Radius of the corner arcs [m], > 0; each edge must be long enough for
            the arcs at its two ends.

    Returns:
        Segments: half of edge 0, then (arc, edge) around, the last being the first half of
        edge 0; it ends where it starts.

    Raises:
        InputError: On a bad shape, repeated or collinear vertices, or a radius too large.
    """
    p = np.asarray(vertices, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3 or not np.isfinite(p).all():
        raise InputError(f"vertices must be finite with shape (k >= 3, 2) [m], got {p.shape}")
    if not corner_radius > 0.0:
        raise InputError(f"corner_radius must be > 0 m, got {corner_radius}")
    k = p.shape[0]
    edges = np.roll(p, -1, axis=0) - p  # edge i from p[i] to p[i+1]
    lengths = np.linalg.norm(edges, axis=1)
    if np.any(lengths <= 0.0):
        raise InputError("polygon vertices must be distinct neighbours")
    dirs = edges / lengths[:, None]
    # Corner i sits at vertex i + 1, between edge i and edge i + 1.
    trims = np.empty(k)
    arcs = []
    for i in range(k):
        d_in, d_out = dirs[i], dirs[(i + 1) % k]
        cross = d_in[0] * d_out[1] - d_in[1] * d_out[0]
        turn = math.atan2(cross, float(d_in @ d_out))
        if abs(turn) < 1e-12 or abs(abs(turn) - math.pi) < 1e-12:
            raise InputError(f"polygon corner {i + 1} is straight or a reversal")
        trim = corner_radius * math.tan(abs(turn) / 2.0)
        trims[i] = trim
        vertex = p[(i + 1) % k]
        entry = vertex - trim * d_in
        normal = np.array([-d_in[1], d_in[0]]) * (1.0 if turn > 0.0 else -1.0)
        center = entry + corner_radius * normal
        angle0 = math.atan2(entry[1] - center[1], entry[0] - center[0])
        arcs.append(PathSegment.arc(center, corner_radius, angle0, turn))
    if max(trims[0], trims[-1]) >= 0.5 * lengths[0]:
        raise InputError(
            f"corner_radius {corner_radius} m is too large for polygon edge 0 "
            f"({lengths[0]:.4g} m), where the path starts at the midpoint"
        )
    for i in range(k):
        if trims[i - 1] + trims[i] >= lengths[i]:
            raise InputError(
                f"corner_radius {corner_radius} m is too large for polygon edge {i} "
                f"({lengths[i]:.4g} m)"
            )
    mid0 = 0.5 * (p[0] + p[1])
    segments = [PathSegment.line(mid0, p[1] - trims[0] * dirs[0])]
    for i in range(k):
        segments.append(arcs[i])
        j = (i + 1) % k
        start = p[j] + trims[i] * dirs[j]
        end = mid0 if j == 0 else p[(j + 1) % k] - trims[j] * dirs[j]
        segments.append(PathSegment.line(start, end))
    return segments


def circle_path(
    center: ArrayLike,
    radius: float,
    angle0: float = -0.5 * math.pi,
    sweep: float = 2.0 * math.pi,
) -> list[PathSegment]:
    """A full circle (or an arc) as one segment.

    Args:
        center: Centre (x, y) [m], shape (2,).
        radius: Radius [m], > 0.
        angle0: Start angle [rad] (-pi/2: the lowest-y point).
        sweep: Signed angle travelled [rad] (2 pi: one counter-clockwise turn).

    Returns:
        One arc segment.
    """
    return [PathSegment.arc(center, radius, angle0, sweep)]


def _mirror_y(segments: list[PathSegment]) -> list[PathSegment]:
    """The mirror image of a path at the plane y = 0 (travel direction mirrored too)."""
    flip = np.array([1.0, -1.0])
    out = []
    for seg in segments:
        if seg.kind == "line":
            out.append(PathSegment.line(seg.start * flip, seg.end * flip))
        else:
            out.append(PathSegment.arc(seg.center * flip, seg.radius, -seg.angle0, -seg.sweep))
    return out


def _smoothstep(tau: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Integral, value and derivative of phi(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5."""
    t2 = tau * tau
    integral = t2 * t2 * (2.5 - 3.0 * tau + t2)
    value = t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2)
    slope = 30.0 * t2 * (1.0 - 2.0 * tau + t2)
    return integral, value, slope


def _arc_length_profile(
    t: FloatArray, length: float, speed: float, ramp: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Arc length s(t) [m], speed [m/s] and tangential acceleration [m/s^2] of the motion.

    ``t`` is measured from the start of the motion; before it s = 0, after it s = length.
    """
    duration = length / speed + ramp
    s = np.empty_like(t)
    sd = np.empty_like(t)
    sdd = np.empty_like(t)
    before, after = t <= 0.0, t >= duration
    start = ~before & (t < ramp)
    stop = ~after & (t > duration - ramp) & ~start
    cruise = ~(before | after | start | stop)
    s[before], sd[before], sdd[before] = 0.0, 0.0, 0.0
    s[after], sd[after], sdd[after] = length, 0.0, 0.0
    integral, value, slope = _smoothstep(t[start] / ramp)
    s[start], sd[start], sdd[start] = speed * ramp * integral, speed * value, speed / ramp * slope
    integral, value, slope = _smoothstep((duration - t[stop]) / ramp)
    s[stop] = length - speed * ramp * integral
    sd[stop], sdd[stop] = speed * value, -speed / ramp * slope
    s[cruise] = 0.5 * speed * ramp + speed * (t[cruise] - ramp)
    sd[cruise], sdd[cruise] = speed, 0.0
    return s, sd, sdd


@dataclass(frozen=True)
class CdprTrajectory:
    """A sampled translational platform trajectory (R constant).

    Attributes:
        name: Registry name (e.g. ``"triangle-12"``).
        t: Sample times [s], shape (N,), from 0 in steps of ``dt``.
        position: Platform position r in K_0 [m], shape (N, 3).
        velocity: dr/dt [m/s], shape (N, 3).
        acceleration: d^2r/dt^2 [m/s^2], shape (N, 3).
        rotation: Platform rotation matrix, constant (the registry's paths: identity), shape
            (3, 3).
        dt: Sample time [s].
        speed: Cruise speed [m/s].
        ramp_time: Duration of each speed ramp [s].
        motion_start: Time the motion starts [s] (after the initial hold).
        motion_end: Time the motion ends [s] (the final hold follows).
        path_length: Length of the path [m].
        force_controlled_pair: The cable pair (0-based) to force-control on this path, or
            None when the pair must switch along the path (``rectangle-switch``).
    """

    name: str
    t: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    rotation: FloatArray
    dt: float
    speed: float
    ramp_time: float
    motion_start: float
    motion_end: float
    path_length: float
    force_controlled_pair: tuple[int, int] | None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Time of the last sample [s]."""
        return float(self.t[-1])

    @property
    def cruise_mask(self) -> NDArray[np.bool_]:
        """Samples of the constant-speed part, shape (N,)."""
        lo = self.motion_start + self.ramp_time
        hi = self.motion_end - self.ramp_time
        return (self.t >= lo) & (self.t <= hi)


def sample_path(
    segments: list[PathSegment],
    *,
    name: str,
    z: float = PATH_Z,
    speed: float = SPEED,
    ramp_time: float = RAMP_TIME,
    hold: float = HOLD_TIME,
    dt: float = SAMPLE_TIME,
    force_controlled_pair: tuple[int, int] | None = None,
) -> CdprTrajectory:
    """Sample a planar path travelled with smooth start and stop (see the module docstring).

    Args:
        segments: The path, consecutive segments (each starting where the last ended).
        name: Name of the trajectory.
        z: Height of the path [m].
        speed: Cruise speed [m/s], > 0.
        ramp_time: Duration of the start and stop ramps [s], > 0, with
            ``speed * ramp_time <= length`` (the ramps cover half that each).
        hold: Rest before and after the motion [s], >= 0.
        dt: Sample time [s], > 0.
        force_controlled_pair: Recorded in the result (see :class:`CdprTrajectory`).

    Returns:
        The trajectory, sampled at ``t = k dt`` up to the end of the final hold.

    Raises:
        InputError: On invalid timing values or a path too short for the ramps.
    """
    for label, value in (("speed", speed), ("ramp_time", ramp_time), ("dt", dt)):
        if not (math.isfinite(value) and value > 0.0):
            raise InputError(f"{label} must be finite and > 0, got {value}")
    if not (math.isfinite(hold) and hold >= 0.0):
        raise InputError(f"hold must be finite and >= 0 s, got {hold}")
    if not segments:
        raise InputError("a path needs at least one segment")
    seg_lengths = np.array([seg.length for seg in segments])
    bounds = np.concatenate([[0.0], np.cumsum(seg_lengths)])
    length = float(bounds[-1])
    if speed * ramp_time > length:
        raise InputError(
            f"path of {length:.4g} m is too short for the ramps: speed * ramp_time = "
            f"{speed * ramp_time:.4g} m must not exceed it"
        )
    motion = length / speed + ramp_time
    n = int(round((2.0 * hold + motion) / dt)) + 1
    t = np.arange(n) * dt
    s, sd, sdd = _arc_length_profile(t - hold, length, speed, ramp_time)
    index = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(segments) - 1)
    point = np.empty((n, 2))
    tangent = np.empty((n, 2))
    curvature = np.empty((n, 2))
    for k, seg in enumerate(segments):
        sel = index == k
        if np.any(sel):
            local = np.clip(s[sel] - bounds[k], 0.0, seg.length)
            point[sel], tangent[sel], curvature[sel] = seg.evaluate(local)
    position = np.column_stack([point, np.full(n, float(z))])
    velocity = np.column_stack([sd[:, None] * tangent, np.zeros(n)])
    accel_xy = sdd[:, None] * tangent + (sd * sd)[:, None] * curvature
    acceleration = np.column_stack([accel_xy, np.zeros(n)])
    for array in (t, position, velocity, acceleration):
        array.setflags(write=False)
    rotation = np.eye(3)
    rotation.setflags(write=False)
    return CdprTrajectory(
        name=name,
        t=t,
        position=position,
        velocity=velocity,
        acceleration=acceleration,
        rotation=rotation,
        dt=float(dt),
        speed=float(speed),
        ramp_time=float(ramp_time),
        motion_start=float(hold),
        motion_end=float(hold + motion),
        path_length=length,
        force_controlled_pair=force_controlled_pair,
    )


def _triangle_12(**options: float) -> CdprTrajectory:
    segments = polygon_path(_TRIANGLE_12)
    return sample_path(segments, name="triangle-12", force_controlled_pair=(0, 1), **options)


def _circle_12(**options: float) -> CdprTrajectory:
    segments = circle_path(*_CIRCLE_12)
    return sample_path(segments, name="circle-12", force_controlled_pair=(0, 1), **options)


def _triangle_34(**options: float) -> CdprTrajectory:
    segments = _mirror_y(polygon_path(_TRIANGLE_12))
    return sample_path(segments, name="triangle-34", force_controlled_pair=(2, 3), **options)


def _circle_34(**options: float) -> CdprTrajectory:
    segments = _mirror_y(circle_path(*_CIRCLE_12))
    return sample_path(segments, name="circle-34", force_controlled_pair=(2, 3), **options)


def _rectangle_switch(**options: float) -> CdprTrajectory:
    segments = polygon_path(_RECTANGLE)
    return sample_path(segments, name="rectangle-switch", force_controlled_pair=None, **options)


CDPR_TRAJECTORIES: dict[str, Callable[..., CdprTrajectory]] = {
    "triangle-12": _triangle_12,
    "circle-12": _circle_12,
    "triangle-34": _triangle_34,
    "circle-34": _circle_34,
    "rectangle-switch": _rectangle_switch,
}
"""Builders of the Fig. 9 trajectories by name; each takes the keyword options of
:func:`sample_path` (``z``, ``speed``, ``ramp_time``, ``hold``, ``dt``)."""


def list_cdpr_trajectories() -> list[str]:
    """Names of the CDPR trajectories, in the order of paper 000's Table 3 (j = 1..5)."""
    return list(CDPR_TRAJECTORIES)


def get_cdpr_trajectory(name: str, **options: float) -> CdprTrajectory:
    """Build a named CDPR trajectory.

    Args:
        name: One of :func:`list_cdpr_trajectories`.
        **options: ``z``, ``speed``, ``ramp_time``, ``hold``, ``dt`` of :func:`sample_path`.

    Returns:
        The sampled trajectory.

    Raises:
        InputError: For an unknown name (the valid ones are listed) or invalid options.
    """
    if name not in CDPR_TRAJECTORIES:
        raise InputError(
            f"unknown CDPR trajectory {name!r}; valid names: {', '.join(CDPR_TRAJECTORIES)}"
        )
    allowed = {"z", "speed", "ramp_time", "hold", "dt"}
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise InputError(
            f"unknown option(s) {unknown} for CDPR trajectory {name!r}; valid: {sorted(allowed)}"
        )
    return CDPR_TRAJECTORIES[name](**options)
