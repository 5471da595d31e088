"""A tour of the musculoskeletal arm: what `make demo` runs.

Loads models/msarm_arm.xml into MuJoCo and Pinocchio, prints its joints and its nine cable
muscles (Hill parameters, lengths, wrap angles and moment arms) and writes PNG plots of the
moment arms over the joint range, the Hill curves and the controllability margin.

    python examples/arm_tour.py --out runs/demo
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pinocchio

from msarm.cli.arm import show_arm
from msarm.model import load_arm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="folder for plots")
    args = parser.parse_args()

    arm = load_arm()
    print(f"model {arm.path} (sha256 {arm.sha256[:12]}…)")
    show_arm(arm, args.out)

    # The nominal model: gravity torque and the cable forces that hold a Table I posture.
    q = np.array([0.0, 0.4363, -0.5236, -1.2217])  # paper 003, Table I, target 1
    gravity = pinocchio.computeGeneralizedGravity(arm.pin_model, arm.pin_model.createData(), q)
    geometry = arm.geometry(q)
    forces, *_ = np.linalg.lstsq(-geometry.jacobian.T, gravity, rcond=None)
    print(f"\nTable I target 1, q = {q} rad")
    print(f"  gravity torque (Pinocchio) [N m]: {np.round(gravity, 3)}")
    print("  minimum-norm cable forces for it [N] (may be negative: the allocation core")
    print(f"  of the next layer keeps them within the muscles' capacity): {np.round(forces, 1)}")


if __name__ == "__main__":
    main()
