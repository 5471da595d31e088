"""Add your own effect to the arm plant: a pulley that loses a fixed share of the tension.

An effect subclasses ``msarm.plant.Effect`` and overrides the hooks it needs (see the
docstring of ``msarm.plant.effects``). This one scales what reaches the insertion:

    T_insertion = (1 - loss) * T_motor        (hook: transmission)

and reports its parameter for the ground-truth sidecar (hook: parameters). The example runs
the Table I task 1 on the ideal plant with and without it and prints the joint RMSE and
final error of each.

    python examples/custom_effect.py [--loss 0.2]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.model import load_arm
from msarm.plant import IDEAL_PLANT, ArmPlant, CableState, Effect
from msarm.tasks.evaluate import evaluate_run
from msarm.tasks.registry import get_task
from msarm.tasks.runner import run_tracking


class PulleyLoss(Effect):
    """A lossy pulley at each insertion: ``T_insertion = (1 - loss) T_motor``."""

    name = "pulley_loss"

    def __init__(self, loss: float) -> None:
        if not 0 <= loss < 1:
            raise ValueError(f"loss must be in [0, 1), got {loss}")
        self.loss = loss

    def transmission(self, state: CableState) -> np.ndarray:
        return np.full(state.lengths.shape, 1.0 - self.loss)

    def parameters(self) -> dict:
        return {"loss": self.loss}


def main(argv: Sequence[str] | None = None) -> None:
    """Run the example from the command line (``argv``: its arguments, else ``sys.argv``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--loss", type=float, default=0.2, help="share of tension lost (default 0.2)"
    )
    args = parser.parse_args(argv)
    if not 0 <= args.loss < 1:
        parser.error(f"--loss: expected a share of the tension in [0, 1), got {args.loss:g}")
    arm = load_arm()
    task = get_task("table1-1", arm)
    gains = ArmControllerConfig()
    for label, effects in [("ideal plant", []), ("with PulleyLoss", [PulleyLoss(args.loss)])]:
        plant = ArmPlant(arm, IDEAL_PLANT, seed=0, extra_effects=effects)
        run = run_tracking(plant, MuscleSpaceController(arm, gains), task)
        metrics = evaluate_run(
            arm,
            run.columns,
            task.home,
            task.target,
            IDEAL_PLANT.winch.drum_radius,
            gains.min_tension,
        )
        rmse = 1000 * np.array(metrics.joint_rmse)
        print(
            f"{label:16s} joint RMSE {np.round(rmse, 1)} mrad, "
            f"final error {1000 * metrics.final_error_mm:7.1f} um, effects {run.effects}"
        )


if __name__ == "__main__":
    main()
