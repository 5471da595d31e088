"""The target's parallel filtering against exact double integrals of the tension's timing.

:func:`msarm.compensation.target.delivered_torque` integrates the delivered torque twice
over time before the Savitzky-Golay filter differentiates it twice. The references here
integrate it independently: in closed form, as the convolution
``x(t_K) = int_0^t_K (t_K - s) tau(s) ds`` of the torque that the load cells' timing
(:attr:`TargetSpec.tension_timing`) says was there between samples, cross-checked against a
fine-grid numerical integration.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid
from scipy.signal import savgol_filter

from msarm.compensation.target import TargetSpec, delivered_torque, torque_error
from msarm.io.logs import LogMetadata, RunLog

DT = 0.004
SAMPLES = 40


def exact_travel(torque: np.ndarray, dt: float, timing: str) -> np.ndarray:
    """Double time integral of a sampled torque, from rest at the first sample, in closed form.

    ``x(t_K) = sum_j w_Kj tau_j`` with ``w_Kj = int_0^t_K (t_K - s) phi_j(s) ds`` for the
    shape ``phi_j`` that sample ``j`` has between samples: for ``"instant"`` the hat of linear
    interpolation (half hats at both ends), for ``"period"`` the indicator of the period
    ``(t_j - dt, t_j]`` that ends at the sample.

    Args:
        torque: Torque samples, ``(T, n)``.
        dt: Sample period [s].
        timing: ``"instant"`` or ``"period"``.

    Returns:
        The double integral at each sample time, ``(T, n)``.
    """
    t = np.arange(len(torque)) * dt
    travel = np.zeros_like(torque)
    for k in range(1, len(torque)):
        if timing == "instant":
            weights = dt * (t[k] - t[: k + 1])  # interior hats: mass dt at their centre
            weights[0] = t[k] * dt / 2.0 - dt * dt / 6.0  # half hat on [0, dt]
            weights[k] = dt * dt / 6.0  # half hat on [t_k - dt, t_k]
            travel[k] = weights @ torque[: k + 1]
        else:
            weights = dt * (t[k] - t[1 : k + 1] + dt / 2.0)  # period centre t_j - dt / 2
            travel[k] = weights @ torque[1 : k + 1]
    return travel


def fine_grid_travel(torque: np.ndarray, dt: float, timing: str, refine: int) -> np.ndarray:
    """The same double integral on a grid ``refine`` times finer, numerically, at the samples.

    Args:
        torque: Torque samples, ``(T, n)``.
        dt: Sample period [s].
        timing: ``"instant"`` or ``"period"``.
        refine: Sub-steps per sample period.

    Returns:
        The double integral at each sample time, ``(T, n)``.
    """
    h = dt / refine
    fine = np.arange((len(torque) - 1) * refine + 1) * h
    if timing == "instant":
        signal = np.stack(
            [np.interp(fine, np.arange(len(torque)) * dt, col) for col in torque.T], axis=1
        )
        speed = cumulative_trapezoid(signal, dx=h, axis=0, initial=0.0)
    else:  # each sub-step takes the sample at the end of its period: rectangles are exact
        held = np.repeat(torque[1:], refine, axis=0)
        speed = np.concatenate([np.zeros((1, torque.shape[1])), np.cumsum(h * held, axis=0)])
    travel = cumulative_trapezoid(speed, dx=h, axis=0, initial=0.0)
    return travel[::refine]


def random_case(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Posture-dependent Jacobians, tensions and the torque they deliver, looped by hand.

    Args:
        seed: Random seed.

    Returns:
        Jacobians ``(T, 9, 4)``, tensions ``(T, 9)`` [N] and ``-J^T F`` ``(T, 4)`` [N m].
    """
    rng = np.random.default_rng(seed)
    jacobians = rng.normal(scale=0.02, size=(SAMPLES, 9, 4))
    tension = rng.uniform(5.0, 50.0, size=(SAMPLES, 9))
    torque = np.array([-jacobians[k].T @ tension[k] for k in range(SAMPLES)])
    return jacobians, tension, torque


@pytest.mark.parametrize("timing", ["instant", "period"])
def test_the_closed_form_reference_is_the_fine_grid_double_integral(timing):
    """The closed-form reference agrees with a 400-times finer numerical integration."""
    torque = random_case(11)[2]
    exact = exact_travel(torque, DT, timing)
    numeric = fine_grid_travel(torque, DT, timing, refine=400)
    scale = np.max(np.abs(exact))
    np.testing.assert_allclose(numeric, exact, rtol=0.0, atol=1e-7 * scale)


@pytest.mark.parametrize("timing", ["instant", "period"])
@pytest.mark.parametrize(("window", "polyorder"), [(5, 3), (25, 3), (9, 2)])
def test_the_delivered_torque_is_the_filter_of_the_exact_double_integral(timing, window, polyorder):
    """Parallel filtering integrates the torque exactly as the tension's timing says.

    A torque of random samples (linear between them for ``"instant"``, held over the period
    ending at each for ``"period"``), integrated twice in closed form and differentiated
    twice by the spec's Savitzky-Golay filter, is what :func:`delivered_torque` returns. A
    linear torque would not do: its double integral is a cubic that the filter's second
    derivative takes back alike for weights 1/3, 1/6 and 1/6, 1/3.
    """
    jacobians, tension, torque = random_case(5)
    spec = TargetSpec(window=window, polyorder=polyorder, tension_timing=timing)
    expected = savgol_filter(
        exact_travel(torque, DT, timing), window, polyorder, deriv=2, delta=DT, axis=0
    )
    got = delivered_torque(jacobians, tension, spec, DT)
    np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-9 * np.max(np.abs(torque)))


def test_the_target_moves_with_the_tension_timing_as_the_exact_integrals_do(arm):
    """``torque_error``'s instant and period targets differ as the two references do.

    The inverse dynamics of the motion is common to both timings, so the difference of the
    targets is the difference of the filtered exact double integrals of the delivered torque
    of the tension less its feedforward.
    """
    jacobians, tension, _ = random_case(7)
    rng = np.random.default_rng(8)
    feedforward = rng.uniform(-3.0, 3.0, size=tension.shape)
    t = np.arange(SAMPLES) * DT
    q = np.array([0.1, 0.2, -0.1, -0.5]) + 0.05 * np.sin(2.0 * np.pi * t)[:, None]
    channels = {
        "q": (arm.joint_names, q),
        "tension_motor": (arm.cable_names, tension),
        "tension_ff": (arm.cable_names, feedforward),
    }
    log = RunLog.from_quantities(t, channels, LogMetadata.for_model(arm, 1.0 / DT))
    spec = TargetSpec(window=9, polyorder=3, tension_timing="instant")
    instant = torque_error(arm, log, spec, jacobians=jacobians)
    period = torque_error(arm, log, replace(spec, tension_timing="period"), jacobians=jacobians)
    torque = -np.einsum("tmn,tm->tn", jacobians, tension - feedforward)
    expected = savgol_filter(
        exact_travel(torque, DT, "instant") - exact_travel(torque, DT, "period"),
        9,
        3,
        deriv=2,
        delta=DT,
        axis=0,
    )
    assert np.max(np.abs(expected)) > 0.1  # the timings differ visibly on this torque
    np.testing.assert_allclose(
        instant - period, expected, rtol=0.0, atol=1e-9 * np.max(np.abs(torque))
    )
