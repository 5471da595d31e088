"""A tour of the musculoskeletal arm: what `make tour` runs.

Loads models/msarm_arm.xml into MuJoCo and Pinocchio, prints its joints and its nine cable
muscles (Hill parameters, lengths, wrap angles and moment arms) and writes PNG plots of the
moment arms over the joint range, the Hill curves and the controllability margin.

    python examples/arm_tour.py --out runs/tour
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pinocchio

from msarm.allocation import make_allocator
from msarm.cli.arm import show_arm
from msarm.cli.common import output_folder, run_script
from msarm.errors import InputError
from msarm.model import load_arm


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit status (143 on SIGTERM)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/tour"), help="folder for plots")
    args = parser.parse_args(argv)
    try:
        output_folder(args.out)  # up front: a path under a file is refused before any work
    except InputError as exc:
        parser.error(str(exc))
    # SIGTERM unwinds: a plot's temporary file is removed
    return run_script(parser.prog, lambda: tour(args.out))


def tour(out: Path) -> None:
    """Print the arm's tables and a posture held against gravity; write the plots to ``out``."""
    arm = load_arm()
    print(f"model {arm.path} (sha256 {arm.sha256[:12]}…)")
    show_arm(arm, out)

    # The nominal model and the allocation core: the muscle forces that hold a Table I
    # posture against gravity, within each muscle's capacity, minimising squared activations.
    q = np.array([0.0, 0.4363, -0.5236, -1.2217])  # paper 003, Table I, target 1
    gravity = pinocchio.computeGeneralizedGravity(arm.pin_model, arm.pin_model.createData(), q)
    geometry = arm.geometry(q)
    f_min, f_max = arm.muscles.force_capacity(geometry.lengths, np.zeros(arm.n_cables))
    allocator = make_allocator(
        arm.n_cables, arm.n_joints, "fast", weights=1.0 / arm.muscles.max_isometric_force
    )
    result = allocator.solve(-geometry.jacobian.T, gravity, np.maximum(f_min, 5.0), f_max)
    activation, _ = arm.muscles.activation_for_force(result.f, geometry.lengths, np.zeros(9))
    print(f"\nTable I target 1, q = {q} rad")
    print(f"  gravity torque (Pinocchio) [N m]: {np.round(gravity, 3)}")
    print(f"  muscle forces holding it [N] ({result.status}, residual {result.residual:.1e}):")
    for name, force, act in zip(arm.cable_names, result.f, activation, strict=True):
        print(f"    {name:18s} {force:7.1f} N   activation {act:.3f}")


if __name__ == "__main__":
    sys.exit(main())
