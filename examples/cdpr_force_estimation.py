"""Cable force without a load cell, measured on a simulated run of the default CDPR plant.

Runs HC-e along triangle-12 on the default plant (friction of paper 000, sensor noise), then
estimates every cable's tension from the run's log alone (motor torque, following error,
encoder cable length; the speed is the encoder length differentiated) with
``msarm.cdpr.force_estimation`` and compares it with the plant's platform-side tension (the
run's ground truth). Prints max / RMS / mean error [N] per estimate, for cables moving
faster than v_L = 0.25 m/min and slower (where the eq. 6 friction blend is steep); the README's
numbers come from here.

    python examples/cdpr_force_estimation.py [--seconds S] [--controller hc-e]

(``--seconds``: how much of the trajectory to run, at most its 11.347 s; the whole of it by
default.) The table's ``subset`` column says which samples a row covers: ``moving``, ``slow``
or ``all``. The following-error rows need cables on pure-P drives (HC-e's first four, every
cable of HC-e-all); with another controller a note says why they are absent.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from msarm.cdpr import force_from_following_error, force_from_motor_torque
from msarm.cdpr.robot_model import load_cable_robot
from msarm.control.cdpr_controllers import CDPR_CONTROLLERS, DRIVE_P, make_cdpr_controller
from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT
from msarm.tasks.cdpr_runner import run_cdpr
from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

START_UP = 0.05
"""Left out: the drives' start-up after the reset [s] (the drum accelerates; a = 0 here)."""


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n samples along axis 0 (edges: shorter windows)."""
    kernel = np.ones(n)
    counts = np.convolve(np.ones(len(x)), kernel, mode="same")
    return np.column_stack([np.convolve(c, kernel, mode="same") for c in x.T]) / counts[:, None]


def main(argv: Sequence[str] | None = None) -> None:
    """Run the example from the command line (``argv``: its arguments, else ``sys.argv``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seconds", type=float, default=None, help="simulate only this long (default: all)"
    )
    parser.add_argument("--controller", default="hc-e", help="hc-e, hc-e-all, hc-tau, ...")
    args = parser.parse_args(argv)
    if args.controller not in CDPR_CONTROLLERS:
        parser.error(
            f"--controller: unknown controller {args.controller!r}; expected one of "
            f"{', '.join(CDPR_CONTROLLERS)}"
        )
    if args.seconds is not None and not 2 * START_UP < args.seconds < math.inf:
        parser.error(
            f"--seconds: expected a finite time of more than {2 * START_UP:g} s (the first "
            f"{START_UP:g} s are left out of the errors), got {args.seconds:g}"
        )

    trajectory = get_cdpr_trajectory("triangle-12")
    length = float(trajectory.t[-1])
    if args.seconds is not None and args.seconds > length + trajectory.dt / 2:
        parser.error(
            f"--seconds: triangle-12 is {length:.3f} s long; expected at most that, got "
            f"{args.seconds:g} (omit --seconds to run all of it)"
        )
    robot = load_cable_robot()
    if args.seconds is not None:
        n = int(round(args.seconds / trajectory.dt)) + 1
        trajectory = replace(
            trajectory,
            t=trajectory.t[:n],
            position=trajectory.position[:n],
            velocity=trajectory.velocity[:n],
            acceleration=trajectory.acceleration[:n],
        )
    run = run_cdpr(robot, DEFAULT_CDPR_PLANT, args.controller, trajectory)
    names = robot.cable_names

    def columns(quantity: str, source: dict) -> np.ndarray:
        return np.column_stack([source[f"{quantity}.{c}"] for c in names])

    t = run.columns["t"]
    length = columns("cable_length", run.columns)
    torque = columns("motor_torque", run.columns)
    fe = columns("following_error", run.columns)
    truth = columns("tension", run.truth)
    v = np.gradient(length, t, axis=0)  # cable speed from the encoder [m/s]
    controller = make_cdpr_controller(args.controller, robot)
    modes = getattr(controller, "drive_mode", None)
    p_drive = [i for i, mode in enumerate(modes or ()) if mode == DRIVE_P]
    # msarm's controllers send the IK cable speed as velocity feedforward (paper 000's PLC
    # does not, and its following error then carries eq. 9's c_v v): say which, as the
    # estimate must
    feedforward = bool(controller.velocity_feedforward)

    estimates = {
        "motor torque, friction model": (force_from_motor_torque(torque, v), range(len(names))),
        "motor torque, 20 ms average": (
            force_from_motor_torque(moving_average(torque, 21), v),
            range(len(names)),
        ),
        "motor torque / r_D (no tau_F)": (
            force_from_motor_torque(torque, v, friction_model=False),
            range(len(names)),
        ),
    }
    if p_drive:
        estimates["following error, friction model"] = (
            force_from_following_error(
                fe[:, p_drive], v[:, p_drive], velocity_feedforward=feedforward
            ),
            p_drive,
        )
        estimates["following error, no tau_F"] = (
            force_from_following_error(
                fe[:, p_drive],
                v[:, p_drive],
                friction_model=False,
                velocity_feedforward=feedforward,
            ),
            p_drive,
        )
    v_low = DEFAULT_CDPR_PLANT.friction.model().v_low
    after = (t >= START_UP)[:, None]
    print(
        f"{args.controller} on triangle-12, {t[-1]:.3f} s, default plant; error [N] against "
        f"the platform-side tension ({truth.min():.1f}-{truth.max():.1f} N), t >= {START_UP} s; "
        f"moving: |v| >= v_L = {v_low:.3g} m/s (0.25 m/min), slow: |v| < v_L"
    )
    print(f"{'estimate':34s} {'cables':7s} {'subset':8s} {'max':>7s} {'rms':>7s} {'mean':>7s}")
    for label, (estimate, cables) in estimates.items():
        cables = list(cables)
        error = estimate - truth[:, cables]
        speed = np.abs(v[:, cables])
        masks = {"moving": after & (speed >= v_low), "slow": after & (speed < v_low)}
        masks["all"] = np.broadcast_to(after, error.shape)
        for which, mask in masks.items():
            if not mask.any():
                continue
            e = error[mask]
            print(
                f"{label:34s} {min(cables)}-{max(cables):<5d} {which:8s} {np.abs(e).max():7.3f} "
                f"{np.sqrt(np.mean(e**2)):7.3f} {e.mean():7.3f}"
            )
    if not p_drive:
        print(no_following_error_note(args.controller, modes))


def no_following_error_note(controller: str, modes: tuple[str, ...] | None) -> str:
    """Why the table has no following-error rows: no cable of ``controller`` on a P drive."""
    drives = "every cable on a PI drive" if modes else "it states no drive modes"
    return (
        f"no following-error estimates: {controller} has no cable on a pure-P drive "
        f"({drives}); the following error gives the force only there (a PI drive integrates "
        "it away)"
    )


if __name__ == "__main__":
    main()
