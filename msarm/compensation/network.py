"""The feedforward compensator's network: a small MLP and its reproducible, resumable training.

Paper 003 (§2.2, eq. 9) fits the joint-torque error of the arm with a three-layer network,
``y = W2ᵀ φ(S1ᵀ x + S0) + W0``: the features ``x`` (42 in the paper), one hidden layer of 150
units and the 4 joint-torque errors ``y`` [N·m]. :class:`NetworkConfig` defaults to that shape;
``hidden`` may name more (or no) hidden layers.

Units: the network works in *normalised* units. A :class:`Normalizer` fitted on the training
inputs maps each input column to zero mean and unit standard deviation, one fitted on the
training targets does the same for the targets, and predictions are mapped back to the
targets' units (N·m for torque errors). The loss is the mean squared error in normalised
units, averaged over samples and target columns (an untrained network that predicts the mean
scores about 1).

Precision: float64 throughout (weights, data, optimiser). The network is tiny (about 4,500 weights
with the 25 default inputs, 7,000 with paper 003's 42), so training time is spent on per-step
overhead rather than arithmetic and float32 would gain little; float64 keeps the 250 Hz fast path
(:mod:`msarm.compensation.fast`, numpy float64) equal to torch to round-off, and matches the rest of
msarm.

Reproducibility: :func:`train_network` seeds the initial weights from ``config.seed`` (inside a
forked RNG, so the caller's global torch RNG is left as it was), shuffles mini-batches with its
own seeded ``torch.Generator``, runs with ``config.threads`` intra-op threads and deterministic
algorithms (both restored afterwards). The same inputs and config give the same weights, bit for
bit, on one machine. A training checkpoint holds everything needed to continue (weights,
optimiser state, best weights, early-stopping state, generator state, history): a resumed run
ends with the same weights as an uninterrupted one, and only the code that wrote it resumes it
(its :func:`~msarm.io.code_version.code_fingerprint`: an upgrade of msarm or torch between the
interruption and the resume would continue another training).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import math
import numbers
import reprlib
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError, MsarmWarning
from msarm.io.atomic import atomic_path
from msarm.io.code_version import code_fingerprint
from msarm.io.config import config_to_dict

if TYPE_CHECKING:
    from msarm.compensation.checkpoint import Compensator

__all__ = [
    "ACTIVATIONS",
    "DTYPE",
    "EpochRecord",
    "NetworkConfig",
    "Normalizer",
    "TrainingResult",
    "build_mlp",
    "check_finite",
    "train_network",
]

FloatArray = NDArray[np.float64]

#: The torch dtype of every network msarm builds (see the module docstring).
DTYPE = torch.float64
#: Hidden-layer activations by name.
ACTIVATIONS: dict[str, type[torch.nn.Module]] = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}
#: Format tag and version of a training checkpoint (the file ``resume`` reads).
TRAINING_CHECKPOINT_FORMAT = "msarm.compensation.training_checkpoint"
TRAINING_CHECKPOINT_VERSION = 1
#: Config fields that may change when a run is resumed (everything else must match;
#: ``max_epochs`` not below the epochs already run).
_RESUMABLE_CHANGES = ("max_epochs", "threads")
#: Rows evaluated at once when computing a loss without gradients.
_EVAL_CHUNK = 65536
#: Largest ``NetworkConfig.seed``: ``torch.manual_seed`` and ``torch.Generator.manual_seed``
#: take an unsigned 64-bit integer (a larger one fails with "Overflow when unpacking long long").
MAX_SEED = 2**64 - 1


@dataclass(frozen=True)
class NetworkConfig:
    """Shape and training settings of the compensator network.

    Attributes:
        hidden: Width of each hidden layer, input side first; ``(150,)`` is paper 003's single
            hidden layer of 150 units. ``()`` gives a linear (affine) model.
        activation: Hidden-layer activation, ``"tanh"`` or ``"relu"``.
        learning_rate: Adam step size.
        batch_size: Samples per mini-batch (the last batch of an epoch may be smaller).
        max_epochs: Most passes over the training set.
        patience: Epochs without a new best validation loss after which training stops.
        weight_decay: L2 penalty added to the gradient by Adam (``torch.optim.Adam``'s
            ``weight_decay``, not decoupled AdamW); 0 disables it.
        seed: Seed of the initial weights and of the mini-batch shuffling, an integer in
            ``[0, 2**64 - 1]`` (what ``torch.manual_seed`` takes).
        threads: Torch intra-op threads used while training (the caller's setting is restored
            afterwards). Bit-for-bit reproducibility holds for a fixed thread count.

    Raises:
        InputError: A setting of the wrong type or out of its range (named, with the value
            given): ``hidden`` not a list of positive integers (``hidden=150`` for
            ``[150]``), an unknown activation, a non-finite or non-positive learning rate, a
            seed outside ``[0, 2**64 - 1]``.
    """

    hidden: tuple[int, ...] = (150,)
    activation: str = "tanh"
    learning_rate: float = 1e-3
    batch_size: int = 256
    max_epochs: int = 200
    patience: int = 20
    weight_decay: float = 0.0
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.hidden, str | bytes) or not isinstance(self.hidden, Iterable):
            raise InputError(
                f"hidden must be a list of layer sizes, got {type(self.hidden).__name__} "
                f"{self.hidden!r}; expected e.g. [150] (one hidden layer of 150 units) or [] "
                "(a linear model)"
            )
        hidden = tuple(self.hidden)
        object.__setattr__(self, "hidden", hidden)
        for i, width in enumerate(hidden):
            if isinstance(width, bool) or not isinstance(width, int) or width < 1:
                raise InputError(f"hidden[{i}] must be a positive integer, got {width!r}")
        if self.activation not in ACTIVATIONS:
            raise InputError(
                f"activation must be one of {', '.join(map(repr, ACTIVATIONS))}, "
                f"got {self.activation!r}"
            )
        for name in ("learning_rate", "weight_decay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise InputError(f"{name} must be a number, got {value!r}")
        if not (math.isfinite(self.learning_rate) and self.learning_rate > 0):
            raise InputError(f"learning_rate must be > 0, got {self.learning_rate!r}")
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0):
            raise InputError(f"weight_decay must be >= 0, got {self.weight_decay!r}")
        for name in ("batch_size", "max_epochs", "patience", "threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if (
            isinstance(self.seed, bool)
            or not isinstance(self.seed, int)
            or not 0 <= self.seed <= MAX_SEED
        ):
            raise InputError(
                f"seed must be an integer in [0, 2**64 - 1] (what torch.manual_seed takes), "
                f"got {self.seed!r}"
            )


@dataclass(frozen=True, eq=False)
class Normalizer:
    """Per-column affine map to zero mean and unit standard deviation.

    ``normalize(v) = (v - mean) / std`` and ``denormalize(z) = z * std + mean``, column by
    column. A column whose standard deviation is below ``min_std`` (constant in the data it was
    fitted on) gets ``std = 1``: it is only centred, so that a small change of it at inference
    time is not blown up by a tiny divisor.

    Attributes:
        mean: Column means, shape ``(k,)``, in the columns' units.
        std: Column standard deviations (population, ``ddof=0``), shape ``(k,)``, > 0.
    """

    mean: FloatArray
    std: FloatArray

    def __post_init__(self) -> None:
        mean = np.array(self.mean, dtype=np.float64, copy=True)
        std = np.array(self.std, dtype=np.float64, copy=True)
        if mean.ndim != 1 or std.shape != mean.shape:
            raise InputError(
                f"Normalizer needs mean and std of one shape (k,), got {mean.shape} and {std.shape}"
            )
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise InputError("Normalizer needs finite means and finite standard deviations > 0")
        mean.flags.writeable = False
        std.flags.writeable = False
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)

    @classmethod
    def fit(cls, data: ArrayLike, min_std: float = 1e-8) -> Normalizer:
        """Fit the column means and standard deviations of ``data``.

        Args:
            data: Samples, shape ``(N, k)`` with ``N >= 1``, finite.
            min_std: Standard deviations below this (in the columns' units) are replaced by 1.

        Returns:
            The normalizer of the ``k`` columns.

        Raises:
            InputError: ``data`` is not of shape ``(N, k)`` with ``N >= 1``, or holds a NaN or
                an infinity (non-finite mean or standard deviation).
        """
        array = np.asarray(data, dtype=np.float64)
        if array.ndim != 2 or array.shape[0] < 1:
            raise InputError(f"Normalizer.fit needs an array of shape (N>=1, k), got {array.shape}")
        mean = array.mean(axis=0)
        std = array.std(axis=0)
        std = np.where(std < min_std, 1.0, std)
        return cls(mean, std)

    @property
    def size(self) -> int:
        """Number of columns ``k``."""
        return int(self.mean.shape[0])

    def normalize(self, values: ArrayLike) -> FloatArray:
        """Map values to normalised units: shape ``(..., k)`` to ``(..., k)``.

        Args:
            values: Values in the columns' units, shape ``(..., k)``.

        Returns:
            ``(values - mean) / std`` [-], shape ``(..., k)``, float64.
        """
        return (np.asarray(values, dtype=np.float64) - self.mean) / self.std

    def denormalize(self, values: ArrayLike) -> FloatArray:
        """Map normalised values back to the columns' units: ``(..., k)`` to ``(..., k)``.

        Args:
            values: Normalised values [-], shape ``(..., k)``.

        Returns:
            ``values * std + mean`` in the columns' units, shape ``(..., k)``, float64.
        """
        return np.asarray(values, dtype=np.float64) * self.std + self.mean

    def to_dict(self) -> dict[str, torch.Tensor]:
        """Plain form for a checkpoint: ``{"mean": tensor, "std": tensor}`` (float64).

        Returns:
            ``mean`` and ``std`` as float64 tensors of shape ``(k,)`` (copies).
        """
        return {
            "mean": torch.from_numpy(self.mean.copy()),
            "std": torch.from_numpy(self.std.copy()),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Normalizer:
        """Inverse of :meth:`to_dict` (accepts tensors, arrays or lists).

        Args:
            data: Mapping with ``"mean"`` and ``"std"``, each of shape ``(k,)`` (tensors,
                arrays or lists).

        Returns:
            The normalizer of the ``k`` columns.

        Raises:
            KeyError: ``"mean"`` or ``"std"`` is missing.
            InputError: Shapes differ or are not ``(k,)``, non-finite values, or a
                standard deviation ``<= 0``.
        """
        return cls(_as_numpy(data["mean"]), _as_numpy(data["std"]))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Normalizer):
            return NotImplemented
        return bool(np.array_equal(self.mean, other.mean) and np.array_equal(self.std, other.std))

    __hash__ = None  # type: ignore[assignment]


class EpochRecord(NamedTuple):
    """Losses of one training epoch (normalised units, dimensionless).

    Attributes:
        epoch: Epoch number, from 1.
        train_loss: Mean of the mini-batch MSE losses over the epoch, weighted by batch size
            (the weights change during the epoch).
        val_loss: MSE on the validation set with the weights at the end of the epoch.
    """

    epoch: int
    train_loss: float
    val_loss: float


@dataclass(frozen=True)
class TrainingResult:
    """Outcome of :func:`train_network`.

    Attributes:
        compensator: The trained model, with the weights of the best validation epoch.
        history: One record per epoch run, in order.
        initial_val_loss: Validation loss of the initial (untrained) weights.
        best_val_loss: Lowest validation loss (``initial_val_loss`` if no epoch improved).
        best_epoch: Epoch whose weights were kept (0: the initial weights).
        epochs_run: Epochs completed (over all resumed sessions).
        train_time_s: Wall-clock training time [s], summed over resumed sessions.
        stopped_early: Whether training stopped because ``patience`` epochs in a row did not
            improve the validation loss (rather than reaching ``max_epochs``).
    """

    compensator: Compensator
    history: tuple[EpochRecord, ...]
    initial_val_loss: float
    best_val_loss: float
    best_epoch: int
    epochs_run: int
    train_time_s: float
    stopped_early: bool


ProgressCallback = Callable[[int, int, float, float], None]


def build_mlp(d: int, n: int, config: NetworkConfig) -> torch.nn.Sequential:
    """Build the compensator's multilayer perceptron (float64, default torch initialisation).

    Layers: ``Linear(d, h1), act, Linear(h1, h2), act, ..., Linear(h_last, n)``; no activation
    on the output. The initial weights come from torch's global RNG: seed it (as
    :func:`train_network` does) for reproducible weights.

    Args:
        d: Number of inputs (features).
        n: Number of outputs (targets).
        config: Hidden widths and activation.

    Returns:
        The network, mapping ``(B, d)`` float64 tensors to ``(B, n)``.

    Raises:
        InputError: ``d`` or ``n`` is not a positive integer.
    """
    for name, value in (("d", d), ("n", n)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise InputError(f"build_mlp: {name} must be a positive integer, got {value!r}")
    widths = [int(d), *config.hidden, int(n)]
    layers: list[torch.nn.Module] = []
    for i in range(len(widths) - 1):
        layers.append(torch.nn.Linear(widths[i], widths[i + 1], dtype=DTYPE))
        if i < len(widths) - 2:
            layers.append(ACTIVATIONS[config.activation]())
    return torch.nn.Sequential(*layers)


def as_feature_array(x: ArrayLike, shape: str = "(d,) or (N, d)") -> FloatArray:
    """Features as float64, or an InputError for values that are not real numbers.

    Args:
        x: Features, any shape.
        shape: The shape the caller expects, for the message about a ragged sequence
            (e.g. ``"(43,) or (N, 43)"``).

    Returns:
        ``x`` as a float64 array (no copy when it already is one).

    Raises:
        InputError: ``x`` holds text, None, or complex values (whose imaginary part would be
            lost), or is a ragged sequence (rows of different lengths; ``shape`` named).
    """
    if x is None:
        raise InputError("x: expected features as real numbers, got None")
    try:
        complex_values = x.dtype.kind == "c" if isinstance(x, np.ndarray) else np.iscomplexobj(x)
        if not complex_values:
            return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        if "inhomogeneous" in str(exc):  # numpy's words for a ragged nested sequence
            raise InputError(
                f"x: expected features as an array of shape {shape}, got a ragged sequence "
                f"(rows of different lengths): {reprlib.repr(x)}"
            ) from None
        raise InputError(f"x: expected features as real numbers, got {x!r}") from None
    raise InputError("x: expected features as real numbers, got complex values")


def check_finite(
    name: str,
    array: ArrayLike,
    row_labels: Sequence[str] | None = None,
    column_names: Sequence[str] | None = None,
) -> None:
    """Raise if an array holds a NaN or an infinity, naming where the first one is.

    Args:
        name: Name of the array in the message (``"x_train"``).
        array: Array of shape ``(N, k)`` (or ``(N,)``).
        row_labels: Optional label of each row (``N`` strings, e.g. ``"run_03.parquet:t=1.2"``)
            used in the message next to the row index.
        column_names: Optional name of each column (``k`` strings, e.g. ``"q.elbow"``).

    Raises:
        InputError: The array has non-finite values; the message gives their count and the row
            and column index (and label/name) of the first one. Also labels or names whose
            count is not the array's rows or columns.
    """
    values = np.asarray(array)
    for labels, size, what in (
        (row_labels, values.shape[0] if values.ndim else 0, "row_labels"),
        (column_names, values.shape[1] if values.ndim >= 2 else None, "column_names"),
    ):
        if labels is not None and size is not None and len(labels) != size:
            raise InputError(f"{what}: {len(labels)} given for {size} of {name}'s")
    if values.dtype.kind not in "fc":
        return
    bad = ~np.isfinite(values)
    if not bad.any():
        return
    count = int(bad.sum())
    first = np.argwhere(bad)[0]
    row = int(first[0])
    where = f"row {row}"
    if row_labels is not None and row < len(row_labels):
        where += f" ({row_labels[row]})"
    if values.ndim >= 2:
        col = int(first[1])
        where += f", column {col}"
        if column_names is not None and col < len(column_names):
            where += f" ({column_names[col]!r})"
    raise InputError(
        f"{name} has {count} non-finite value{'s' if count != 1 else ''} (NaN or inf); "
        f"first at {where}: {values[tuple(first)].item()!r}"
    )


def train_network(
    x_train: ArrayLike,
    y_train: ArrayLike,
    x_val: ArrayLike,
    y_val: ArrayLike,
    config: NetworkConfig | None = None,
    checkpoint_path: str | Path | None = None,
    resume: bool = False,
    progress: ProgressCallback | None = None,
    metadata: Mapping[str, Any] | None = None,
    *,
    checkpoint_every: int = 1,
    column_names: Sequence[str] | None = None,
    target_names: Sequence[str] | None = None,
    train_row_labels: Sequence[str] | None = None,
    val_row_labels: Sequence[str] | None = None,
) -> TrainingResult:
    """Train the compensator network with Adam and early stopping on the validation loss.

    Normalizers are fitted on the training inputs and targets; the network learns in normalised
    units with the MSE loss, on mini-batches shuffled every epoch by a generator seeded from
    ``config.seed``. After every epoch the validation loss is computed; the weights with the
    lowest one are kept, and training stops after ``config.patience`` epochs in a row without a
    strictly lower validation loss, or after ``config.max_epochs`` epochs.

    Args:
        x_train: Training inputs, shape ``(N, d)``, finite.
        y_train: Training targets, shape ``(N, n)`` (joint-torque errors [N·m]), finite.
        x_val: Validation inputs, shape ``(M, d)``, finite.
        y_val: Validation targets, shape ``(M, n)``, finite.
        config: Network and training settings (default: :class:`NetworkConfig()`).
        checkpoint_path: If given, a training checkpoint is written there atomically every
            ``checkpoint_every`` epochs and at the end (the file ``resume`` reads; not a
            :class:`~msarm.compensation.checkpoint.Compensator` file).
        resume: Continue from the checkpoint at ``checkpoint_path`` (which must exist, and must
            have been written for the same data and the same config, except ``max_epochs``
            and ``threads``). A resumed run reaches the same weights as an uninterrupted one.
            A finished run (early-stopped, or at ``max_epochs``) is returned as it is.
        progress: Called after every epoch as ``progress(epoch, max_epochs, train_loss,
            val_loss)`` (after the checkpoint of that epoch is written).
        metadata: Copied into the returned compensator's ``metadata`` (plain data: model hash,
            feature spec, ...) and into the training checkpoint.
        checkpoint_every: Epochs between two checkpoint writes (>= 1).
        column_names: Optional names of the ``d`` input columns (features), for error
            messages.
        target_names: Optional names of the ``n`` target columns, for error messages.
        train_row_labels: Optional labels of the ``N`` training rows, for error messages.
        val_row_labels: Optional labels of the ``M`` validation rows, for error messages.

    Returns:
        The trained compensator (best weights) with the loss history.

    Raises:
        InputError: Wrong shapes, a NaN or inf in an array (array, row and column named), or
            ``resume`` without a ``checkpoint_path``.
        CheckpointError: The checkpoint to resume from is missing, unreadable, or was written
            for other data or another config.
    """
    from msarm.compensation.checkpoint import CheckpointError, Compensator

    config = NetworkConfig() if config is None else config
    if not isinstance(config, NetworkConfig):
        raise InputError(f"config must be a NetworkConfig, got {type(config).__name__}")
    if isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int):
        raise InputError(f"checkpoint_every must be a positive integer, got {checkpoint_every!r}")
    if checkpoint_every < 1:
        raise InputError(f"checkpoint_every must be a positive integer, got {checkpoint_every!r}")
    if resume and checkpoint_path is None:
        raise InputError("resume=True needs a checkpoint_path to resume from")
    xt, yt, xv, yv = _validated_arrays(
        x_train,
        y_train,
        x_val,
        y_val,
        column_names,
        target_names,
        train_row_labels,
        val_row_labels,
    )
    d, n = xt.shape[1], yt.shape[1]
    meta = _plain_copy(dict(metadata) if metadata is not None else {}, "metadata")
    data_sha = _data_sha256(xt, yt, xv, yv)
    in_norm = Normalizer.fit(xt)
    out_norm = Normalizer.fit(yt)
    x_tr = torch.from_numpy(in_norm.normalize(xt))
    y_tr = torch.from_numpy(out_norm.normalize(yt))
    x_va = torch.from_numpy(in_norm.normalize(xv))
    y_va = torch.from_numpy(out_norm.normalize(yv))
    path = Path(checkpoint_path) if checkpoint_path is not None else None

    with _training_context(config.threads):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            model = build_mlp(d, n, config)
        optimizer = torch.optim.Adam(
            model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
        )
        generator = torch.Generator().manual_seed(config.seed)
        state = _TrainState(
            epoch=0,
            best_state=_clone_state(model.state_dict()),
            best_val_loss=_loss(model, x_va, y_va),
            best_epoch=0,
            bad_epochs=0,
            history=[],
            stopped_early=False,
            train_time_s=0.0,
        )
        state.initial_val_loss = state.best_val_loss
        if resume:
            assert path is not None
            saved = _read_training_checkpoint(path, CheckpointError)
            _check_resumable(saved, config, data_sha, d, n, path, CheckpointError)
            model.load_state_dict(saved["model"])
            optimizer.load_state_dict(saved["optimizer"])
            generator.set_state(saved["generator_state"])
            state = _TrainState.from_checkpoint(saved)

        def save_checkpoint() -> None:
            if path is None:
                return
            payload = {
                "format": TRAINING_CHECKPOINT_FORMAT,
                "format_version": TRAINING_CHECKPOINT_VERSION,
                "config": config_to_dict(config),
                "data_sha256": data_sha,
                "code": code_fingerprint("simulation"),
                "input_dim": d,
                "output_dim": n,
                "model": _clone_state(model.state_dict()),
                "optimizer": copy.deepcopy(optimizer.state_dict()),
                "generator_state": generator.get_state(),
                "input_normalizer": in_norm.to_dict(),
                "output_normalizer": out_norm.to_dict(),
                "metadata": meta,
                **state.to_checkpoint(),
            }
            _atomic_torch_save(payload, path)

        finished = state.stopped_early or state.epoch >= config.max_epochs
        start = time.perf_counter()
        elapsed_before = state.train_time_s
        n_rows = x_tr.shape[0]
        while not finished:
            model.train()
            order = torch.randperm(n_rows, generator=generator)
            total = 0.0
            for lo in range(0, n_rows, config.batch_size):
                idx = order[lo : lo + config.batch_size]
                xb, yb = x_tr[idx], y_tr[idx]
                optimizer.zero_grad(set_to_none=True)
                loss = torch.nn.functional.mse_loss(model(xb), yb)
                loss.backward()
                optimizer.step()
                total += float(loss.detach()) * idx.shape[0]
            train_loss = total / n_rows
            val_loss = _loss(model, x_va, y_va)
            state.epoch += 1
            state.history.append(EpochRecord(state.epoch, train_loss, val_loss))
            if val_loss < state.best_val_loss:
                state.best_val_loss = val_loss
                state.best_epoch = state.epoch
                state.best_state = _clone_state(model.state_dict())
                state.bad_epochs = 0
            else:
                state.bad_epochs += 1
            state.stopped_early = state.bad_epochs >= config.patience
            finished = state.stopped_early or state.epoch >= config.max_epochs
            state.train_time_s = elapsed_before + (time.perf_counter() - start)
            if finished or state.epoch % checkpoint_every == 0:
                save_checkpoint()
            if progress is not None:
                progress(state.epoch, config.max_epochs, train_loss, val_loss)

    if state.best_epoch == 0 and state.epoch > 0:
        warnings.warn(
            f"train_network: no epoch of {state.epoch} lowered the validation loss below the "
            f"untrained network's ({state.initial_val_loss:.4g}); the compensator keeps the "
            "initial (random) weights, so its output is not learned. Expected more data, "
            "more epochs or a smaller learning rate",
            MsarmWarning,
            stacklevel=2,
        )
    compensator = Compensator(state.best_state, in_norm, out_norm, config, metadata=meta)
    return TrainingResult(
        compensator=compensator,
        history=tuple(state.history),
        initial_val_loss=state.initial_val_loss,
        best_val_loss=state.best_val_loss,
        best_epoch=state.best_epoch,
        epochs_run=state.epoch,
        train_time_s=state.train_time_s,
        stopped_early=state.stopped_early,
    )


# --- helpers --------------------------------------------------------------------------------


@dataclass
class _TrainState:
    """Mutable early-stopping and bookkeeping state of a training run."""

    epoch: int
    best_state: dict[str, torch.Tensor]
    best_val_loss: float
    best_epoch: int
    bad_epochs: int
    history: list[EpochRecord]
    stopped_early: bool
    train_time_s: float
    initial_val_loss: float = math.nan

    def to_checkpoint(self) -> dict[str, Any]:
        return {
            "epoch": self.epoch,
            "best_state": _clone_state(self.best_state),
            "best_val_loss": self.best_val_loss,
            "best_epoch": self.best_epoch,
            "bad_epochs": self.bad_epochs,
            "history": [list(r) for r in self.history],
            "stopped_early": self.stopped_early,
            "train_time_s": self.train_time_s,
            "initial_val_loss": self.initial_val_loss,
        }

    @classmethod
    def from_checkpoint(cls, saved: Mapping[str, Any]) -> _TrainState:
        return cls(
            epoch=int(saved["epoch"]),
            best_state=_clone_state(saved["best_state"]),
            best_val_loss=float(saved["best_val_loss"]),
            best_epoch=int(saved["best_epoch"]),
            bad_epochs=int(saved["bad_epochs"]),
            history=[EpochRecord(int(e), float(t), float(v)) for e, t, v in saved["history"]],
            stopped_early=bool(saved["stopped_early"]),
            train_time_s=float(saved["train_time_s"]),
            initial_val_loss=float(saved["initial_val_loss"]),
        )


_TRAINING_CHECKPOINT_KEYS = (
    "format", "format_version", "config", "data_sha256", "input_dim", "output_dim", "model",
    "optimizer", "generator_state", "input_normalizer", "output_normalizer", "metadata",
    "epoch", "best_state", "best_val_loss", "best_epoch", "bad_epochs", "history",
    "stopped_early", "train_time_s", "initial_val_loss",
)  # fmt: skip


@contextlib.contextmanager
def _training_context(threads: int) -> Iterator[None]:
    """Set the thread count and deterministic algorithms; restore the caller's afterwards."""
    old_threads = torch.get_num_threads()
    old_deterministic = torch.are_deterministic_algorithms_enabled()
    old_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(old_deterministic, warn_only=old_warn_only)
        torch.set_num_threads(old_threads)


def _validated_arrays(
    x_train: ArrayLike,
    y_train: ArrayLike,
    x_val: ArrayLike,
    y_val: ArrayLike,
    column_names: Sequence[str] | None,
    target_names: Sequence[str] | None,
    train_row_labels: Sequence[str] | None,
    val_row_labels: Sequence[str] | None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Convert to C-contiguous float64 and check shapes, agreement and finiteness."""
    arrays = {}
    for name, value in (
        ("x_train", x_train), ("y_train", y_train), ("x_val", x_val), ("y_val", y_val),
    ):  # fmt: skip
        try:
            array = np.ascontiguousarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be a numeric array: {exc}") from None
        if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
            raise InputError(f"{name} must have shape (rows>=1, columns>=1), got {array.shape}")
        arrays[name] = array
    xt, yt, xv, yv = arrays["x_train"], arrays["y_train"], arrays["x_val"], arrays["y_val"]
    if yt.shape[0] != xt.shape[0]:
        raise InputError(f"x_train has {xt.shape[0]} rows but y_train has {yt.shape[0]}")
    if yv.shape[0] != xv.shape[0]:
        raise InputError(f"x_val has {xv.shape[0]} rows but y_val has {yv.shape[0]}")
    if xv.shape[1] != xt.shape[1]:
        raise InputError(f"x_val has {xv.shape[1]} columns but x_train has {xt.shape[1]}")
    if yv.shape[1] != yt.shape[1]:
        raise InputError(f"y_val has {yv.shape[1]} columns but y_train has {yt.shape[1]}")
    for label, names, size in (
        ("column_names", column_names, xt.shape[1]),
        ("target_names", target_names, yt.shape[1]),
        ("train_row_labels", train_row_labels, xt.shape[0]),
        ("val_row_labels", val_row_labels, xv.shape[0]),
    ):
        if names is not None and len(names) != size:
            raise InputError(f"{label} has {len(names)} entries, expected {size}")
    check_finite("x_train", xt, train_row_labels, column_names)
    check_finite("y_train", yt, train_row_labels, target_names)
    check_finite("x_val", xv, val_row_labels, column_names)
    check_finite("y_val", yv, val_row_labels, target_names)
    return xt, yt, xv, yv


def _loss(model: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> float:
    """MSE of ``model`` on ``(x, y)`` (normalised units), without gradients, in chunks."""
    model.eval()
    total = 0.0
    with torch.no_grad():
        for lo in range(0, x.shape[0], _EVAL_CHUNK):
            xb, yb = x[lo : lo + _EVAL_CHUNK], y[lo : lo + _EVAL_CHUNK]
            total += float(torch.sum((model(xb) - yb) ** 2))
    return total / (x.shape[0] * y.shape[1])


def _clone_state(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in state.items()}


def _as_numpy(value: Any) -> FloatArray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy().astype(np.float64)
    return np.asarray(value, dtype=np.float64)


def _data_sha256(*arrays: FloatArray) -> str:
    """SHA-256 over the shapes and bytes of the (C-contiguous float64) arrays."""
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(repr(array.shape).encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _plain_copy(value: Any, key: str) -> Any:
    """Deep copy of plain data (what ``torch.load(weights_only=True)`` can read back).

    Dicts (string keys), lists, tuples, str, int, float, bool and None are kept; numpy arrays
    become lists and numpy scalars Python numbers; paths become strings; tensors are cloned.

    Raises:
        InputError: A value has no plain form (its key path is named).
    """
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise InputError(f"{key}: keys must be strings, got {type(k).__name__} {k!r}")
            out[k] = _plain_copy(v, f"{key}.{k}")
        return out
    if isinstance(value, list | tuple):
        items = [_plain_copy(v, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if isinstance(value, tuple) else items
    if isinstance(value, np.ndarray):
        return _plain_copy(value.tolist(), key)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, torch.Tensor):
        return value.detach().clone()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain_copy(config_to_dict(value), key)
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise InputError(
        f"{key}: a {type(value).__name__} cannot be stored in a checkpoint; use plain data "
        "(dict, list, str, numbers, bool, None)"
    )


def _atomic_torch_save(payload: Mapping[str, Any], path: Path) -> None:
    """``torch.save`` to ``path`` atomically (:func:`msarm.io.atomic.atomic_path`)."""
    with atomic_path(path) as tmp:
        torch.save(dict(payload), tmp)


def _read_training_checkpoint(path: Path, error: type[Exception]) -> dict[str, Any]:
    """Load and shape-check a training checkpoint, raising ``error`` with the reason."""
    if not path.is_file():
        raise error(f"{path}: no training checkpoint to resume from (file not found)")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any failure to unpickle means an unreadable file
        raise error(f"{path}: not a readable training checkpoint ({exc})") from None
    if not isinstance(saved, dict) or saved.get("format") != TRAINING_CHECKPOINT_FORMAT:
        found = saved.get("format") if isinstance(saved, dict) else type(saved).__name__
        raise error(
            f"{path}: not an msarm training checkpoint (format {found!r}, expected "
            f"{TRAINING_CHECKPOINT_FORMAT!r})"
        )
    if saved.get("format_version") != TRAINING_CHECKPOINT_VERSION:
        raise error(
            f"{path}: training checkpoint format version {saved.get('format_version')!r}, this "
            f"msarm reads version {TRAINING_CHECKPOINT_VERSION}"
        )
    missing = [k for k in _TRAINING_CHECKPOINT_KEYS if k not in saved]
    if missing:
        raise error(f"{path}: training checkpoint is missing keys: {', '.join(missing)}")
    return saved


def _check_resumable(
    saved: Mapping[str, Any],
    config: NetworkConfig,
    data_sha: str,
    d: int,
    n: int,
    path: Path,
    error: type[Exception],
) -> None:
    """Refuse to resume a checkpoint made for other data, shapes, settings or code."""
    code, written_by = code_fingerprint("simulation"), saved.get("code")
    if written_by != code:
        recorded = f"{written_by[:12]}…" if isinstance(written_by, str) else "not recorded"
        raise error(
            f"{path}: checkpoint was written by other code (code fingerprint {recorded}, the "
            f"code in use {code[:12]}…: msarm's sources or the libraries' versions changed "
            "since); resume needs the same code"
        )
    if (saved["input_dim"], saved["output_dim"]) != (d, n):
        raise error(
            f"{path}: checkpoint was trained with {saved['input_dim']} inputs and "
            f"{saved['output_dim']} outputs, the data has {d} and {n}"
        )
    if saved["data_sha256"] != data_sha:
        raise error(
            f"{path}: checkpoint was trained on other data (data SHA-256 {saved['data_sha256']}, "
            f"this data {data_sha}); resume needs the same training and validation arrays"
        )
    now = config_to_dict(config)
    before = dict(saved["config"])
    differ = [
        f"{k}: checkpoint {before.get(k)!r}, now {now.get(k)!r}"
        for k in now
        if k not in _RESUMABLE_CHANGES and _comparable(before.get(k)) != _comparable(now.get(k))
    ]
    if differ:
        raise error(
            f"{path}: checkpoint was trained with another config ({'; '.join(differ)}); only "
            f"{', '.join(_RESUMABLE_CHANGES)} may change on resume"
        )
    if int(saved["epoch"]) > config.max_epochs:
        # its weights and best epoch may come from epochs a run of max_epochs never reaches
        raise error(
            f"{path}: checkpoint has run {int(saved['epoch'])} epochs, more than max_epochs "
            f"{config.max_epochs} now; resume needs max_epochs >= the epochs already run"
        )


def _comparable(value: Any) -> Any:
    if isinstance(value, list | tuple):
        return [_comparable(v) for v in value]
    return value
