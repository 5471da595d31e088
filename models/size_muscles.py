"""Recompute the fibre and tendon slack lengths of a model's cable muscles, in place.

Run after moving attachment points or sheath waypoints:

    python models/size_muscles.py models/msarm_arm.xml

Samples the joint range on a grid, sizes every muscle with
``msarm.muscle.sizing.size_fibres`` (fibres between 0.8 and 1.2 optimal lengths) and rewrites
the second and third numbers of each ``hill/<cable>`` numeric; the other numbers (max
isometric force, max contraction velocity, pennation) are kept.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from msarm.model import load_robot
from msarm.muscle.geometry import joint_grid
from msarm.muscle.sizing import size_fibres


def main() -> None:
    """Size the muscles of the model named on the command line and rewrite its file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path, help="MJCF file with hill/<cable> numerics")
    parser.add_argument("--points", type=int, default=9, help="grid points per joint")
    args = parser.parse_args()
    # load_robot, not load_arm: the arm's loader refuses fibres far from their optimal length
    # at the reference posture, which is what a moved attachment gives before this re-sizing
    arm = load_robot(args.model)
    if arm.muscles is None:
        raise SystemExit(f"{args.model}: no Hill parameters hill/<cable> in <custom> to resize")
    grid = joint_grid(arm.joint_lower, arm.joint_upper, args.points)
    lengths = np.array([arm.geometry(q).lengths for q in grid])
    optimal, slack = size_fibres(lengths, arm.muscles.pennation_at_optimal)
    text = args.model.read_text()
    for name, l_opt, l_slack in zip(arm.cable_names, optimal, slack, strict=True):
        pattern = rf'(<numeric name="hill/{name}" data=")(\S+) \S+ \S+ (\S+ \S+")'
        text, count = re.subn(pattern, rf"\g<1>\g<2> {l_opt:.4f} {l_slack:.4f} \g<3>", text)
        if count != 1:
            raise SystemExit(f"{args.model}: no single numeric hill/{name} to update")
        print(f"{name:18s} l_M0 = {l_opt:.4f} m, l_Ts = {l_slack:.4f} m")
    args.model.write_text(text)


if __name__ == "__main__":
    main()
