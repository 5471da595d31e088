"""A folder of finished cable-robot runs, so that an interrupted grid resumes where it stopped.

:func:`msarm.tasks.cdpr_compare.compare_cdpr` runs up to 81 simulations (8 minutes on a 2-core
machine). Each finished run is kept here as one ``.npz`` file holding what the comparison
reads of it (its metrics, the log columns ``t``, ``marker.*``, ``r_ref.*``, ``f_desired.*``,
``h.*`` and the ground-truth cable forces) and the key it was run with: the controller, the
trajectory, the controller's options, the noise seed, the resolved plant, the SHA-256 of
the robot model file and the fingerprint of the code
(:func:`msarm.io.code_version.code_fingerprint`: msarm's sources and the libraries'
versions). A run is reused only when its stored key is the key asked for, bit for bit (a
changed plant, option, model file or msarm version runs it again); a file that cannot be
read is run again too. A run that diverged is not kept. Files are written atomically.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from msarm.cdpr.robot_model import CableRobotModel
from msarm.io.atomic import atomic_path
from msarm.io.code_version import code_fingerprint
from msarm.io.config import config_to_dict
from msarm.plant.cdpr_config import CdprPlantConfig
from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun

__all__ = ["KEPT_QUANTITIES", "CdprRunCache"]

#: Log quantities a cached run keeps (with ``t``): what the comparison's plots and its
#: repeatability read.
KEPT_QUANTITIES = ("marker", "r_ref", "f_desired", "h")
#: Version of the cache files (a file of another version is run again).
_FORMAT = 1


class CdprRunCache:
    """Finished runs of one robot model and plant in a folder (see the module docstring).

    Args:
        folder: Where the runs are kept (created when the first one is saved), or None for
            no cache (nothing is loaded or kept).
        model: The cable robot the runs are of.
        plant_config: The plant they ran on.
    """

    def __init__(
        self, folder: Path | None, model: CableRobotModel, plant_config: CdprPlantConfig
    ) -> None:
        self.folder = None if folder is None else Path(folder)
        self._common = {
            "format": _FORMAT,
            "model_sha256": model.sha256.lower(),
            "plant": config_to_dict(plant_config),
            "code": code_fingerprint("simulation"),
        }

    def _key(self, controller: str, trajectory: str, seed: int, options: Mapping[str, Any]) -> str:
        key = {
            **self._common,
            "controller": controller,
            "trajectory": trajectory,
            "seed": int(seed),
            "options": dict(options),
        }
        return json.dumps(key, sort_keys=True)

    def path(self, name: str, seed: int) -> Path | None:
        """The file of run ``name`` (a test id, ``/`` allowed) with ``seed``, or None."""
        if self.folder is None:
            return None
        safe = name.replace("/", "_").replace("=", "-")
        return self.folder / f"{safe}-s{int(seed)}.npz"

    def load(
        self,
        name: str,
        controller: str,
        trajectory: str,
        seed: int,
        options: Mapping[str, Any] | None = None,
    ) -> CdprRun | None:
        """The kept run asked for, or None when there is none with this exact key.

        Args:
            name: The run's name (the test id).
            controller: Controller name.
            trajectory: Trajectory name.
            seed: Noise seed.
            options: The controller's keyword options.

        Returns:
            The run (its columns and truth limited to what the cache keeps), or None.
        """
        path = self.path(name, seed)
        if path is None or not path.is_file():
            return None
        try:
            # np.load on an open file: a file it cannot read is closed all the same
            with path.open("rb") as file, np.load(file, allow_pickle=False) as stored:
                if str(stored["key"]) != self._key(controller, trajectory, seed, options or {}):
                    return None
                metrics = json.loads(str(stored["metrics"]))
                columns = {k[4:]: stored[k] for k in stored.files if k.startswith("col:")}
                truth = {k[6:]: stored[k] for k in stored.files if k.startswith("truth:")}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):  # run it again
            return None
        values = {k: math.nan if v is None else v for k, v in metrics.items()}
        return CdprRun(controller, trajectory, columns, truth, CdprMetrics(**values))

    def save(
        self,
        name: str,
        run: CdprRun,
        seed: int,
        options: Mapping[str, Any] | None = None,
        quantities: tuple[str, ...] = KEPT_QUANTITIES,
        truth: bool = True,
    ) -> Path | None:
        """Keep a finished run (a diverged one is not kept); returns its file or None.

        Args:
            name: The run's name (the test id).
            run: The run.
            seed: Its noise seed.
            options: The controller's keyword options it ran with.
            quantities: The log quantities kept (with ``t``): :data:`KEPT_QUANTITIES` for a
                run that is plotted, ``("marker",)`` for one whose path error is all that is
                read (about 0.4 MB a run instead of 2.8 MB).
            truth: Keep the ground-truth columns (the plotted cable forces) too.
        """
        path = self.path(name, seed)
        if path is None or run.error is not None:
            return None
        kept = {
            f"col:{k}": np.asarray(v)
            for k, v in run.columns.items()
            if k == "t" or k.split(".", 1)[0] in quantities
        }
        if truth:
            kept.update({f"truth:{k}": np.asarray(v) for k, v in run.truth.items()})
        key = self._key(run.controller, run.trajectory, seed, options or {})
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(
                fh, key=np.array(key), metrics=np.array(json.dumps(run.metrics.as_dict())), **kept
            )
        return path
